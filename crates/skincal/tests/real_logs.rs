//! Logs as real robots write them, not as `record` does: a humanoid's leg dumped from its own ports
//! — joint states for the leg alone at 100 Hz from encoders whose last count flickers, skin boards
//! that send a fresh sample at 20 Hz which the port repeats in between, a dead board, and a hip
//! that returns 1° short of where it started. The truth is the humanoid description's static
//! readings at the encoders' true positions.

use std::f64::consts::PI;
use std::fmt::Write as _;
use std::path::Path;

use nalgebra::Vector3;
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use skincal::explore::{explore, DiagnosticKind, ExploreConfig};
use skincal::ingest::{ingest, IngestConfig};
use skincal::model::sensor::static_readings;
use skincal::model::{presets, Robot};

/// One count of the leg's encoders, rad (0.044°).
const COUNT: f64 = 0.044 * PI / 180.0;
/// The board that reads (-1, -1, -1) m/s² whatever happens.
const DEAD: &str = "r_shank_front";

/// The leg's DoFs and the SUs they move (the boards of the leg).
fn leg(robot: &Robot) -> (Vec<String>, Vec<String>) {
    let m = &robot.model;
    let dofs: Vec<String> = m
        .dof_names()
        .into_iter()
        .filter(|d| d.starts_with("r_hip") || d.starts_with("r_knee") || d.starts_with("r_ankle"))
        .collect();
    let hip = m.dof_index(&dofs[0]).unwrap();
    let sus = m
        .su_names()
        .into_iter()
        .filter(|s| m.moves_su(hip, m.su_index(s).unwrap()))
        .collect();
    (dofs, sus)
}

/// The hip pitch's path: 12° for 8 s, a quintic move to 52.6° over 3 s, held 10 s, back over 3 s
/// to 11.0° (1° short), held to the end (33 s in all).
fn hip_pitch(t: f64) -> f64 {
    let quintic = |a: f64, b: f64, u: f64| {
        let u = u.clamp(0.0, 1.0);
        a + (b - a) * u * u * u * (10.0 - 15.0 * u + 6.0 * u * u)
    };
    let deg = if t < 8.0 {
        12.0
    } else if t < 11.0 {
        quintic(12.0, 52.6, (t - 8.0) / 3.0)
    } else if t < 21.0 {
        52.6
    } else {
        quintic(52.6, 11.0, (t - 21.0) / 3.0)
    };
    deg.to_radians()
}

/// Writes the leg's log as skincal's CSV log into `dir`; returns the leg's DoFs and boards.
fn leg_log(robot: &Robot, dir: &Path, seed: u64) -> (Vec<String>, Vec<String>) {
    let (dofs, sus) = leg(robot);
    let m = &robot.model;
    let pitch = dofs.iter().position(|d| d == "r_hip_pitch").unwrap();
    let mut rng = ChaCha8Rng::seed_from_u64(seed);
    let rest: Vec<f64> = dofs.iter().map(|_| rng.random_range(-0.3..0.3)).collect();
    let g = Vector3::new(0.0, 0.0, -9.81);
    let (mut joints, mut imu) = (String::new(), String::new());
    writeln!(joints, "stamp,{}", dofs.join(",")).unwrap();
    writeln!(imu, "stamp,frame_id,ax,ay,az").unwrap();
    let mut held: Vec<Vector3<f64>> = vec![Vector3::zeros(); sus.len()];
    let start = 1_700_000_000.0;
    for i in 0..3300 {
        let t = i as f64 * 0.01;
        // The port's clock jitters by a few hundred microseconds.
        let stamp = start + t + rng.random_range(-3e-4..3e-4);
        let mut q = rest.clone();
        q[pitch] = hip_pitch(t);
        // Encoders: whole counts, the last of which flickers.
        let read: Vec<String> = q
            .iter()
            .map(|x| {
                let flicker = f64::from(rng.random_range(-1i32..=1));
                format!("{:.9}", ((x / COUNT).round() + flicker) * COUNT)
            })
            .collect();
        writeln!(joints, "{stamp:.6},{}", read.join(",")).unwrap();
        let mut full = vec![0.0; m.dofs().len()];
        for (d, x) in dofs.iter().zip(&q) {
            full[m.dof_index(d).unwrap()] = *x;
        }
        let truth = static_readings(m, &robot.parameters, &full, &g);
        for (k, su) in sus.iter().enumerate() {
            // Each board sends a fresh sample every 50 ms; the port repeats the last in between.
            if i % 5 == 0 {
                let noise = Vector3::from_fn(|_, _| rng.random_range(-0.098..0.098));
                held[k] = truth[m.su_index(su).unwrap()] + noise;
            }
            let a = if su == DEAD {
                Vector3::new(-1.0, -1.0, -1.0)
            } else {
                held[k]
            };
            writeln!(imu, "{stamp:.6},{su},{:.5},{:.5},{:.5}", a.x, a.y, a.z).unwrap();
        }
    }
    std::fs::create_dir_all(dir).unwrap();
    std::fs::write(dir.join("joint_states.csv"), joints).unwrap();
    std::fs::write(dir.join("imu.csv"), imu).unwrap();
    (dofs, sus)
}

#[test]
fn a_real_legs_dump_ingests_with_default_options_and_the_move_moves_every_live_board() {
    let robot = presets::find("humanoid").unwrap().robot().unwrap();
    let dir = tempfile::tempdir().unwrap();
    let (dofs, sus) = leg_log(&robot, &dir.path().join("leg"), 1);
    let ingested = ingest(
        &[dir.path().join("leg")],
        &IngestConfig::default(),
        &mut |_, _, _| {},
    )
    .unwrap_or_else(|e| panic!("{e}"));
    let set = &ingested.measurements;
    let report = &ingested.report;
    // The boards behind the port are named, with their own rate: 4 samples of 5 repeat the one
    // before, fresh ones come at 20 Hz. The dead board never changes: not a slow board.
    let repeated = &report.logs[0].repeated;
    for su in sus.iter().filter(|s| *s != DEAD) {
        let r = repeated
            .get(su)
            .unwrap_or_else(|| panic!("{su}: {repeated:?}"));
        assert!((r.share - 0.8).abs() < 0.01, "{su}: {r:?}");
        assert!((r.fresh_rate - 20.0).abs() < 0.5, "{su}: {r:?}");
    }
    assert!(!repeated.contains_key(DEAD));
    assert!(
        report
            .warnings
            .iter()
            .any(|w| w.contains("slower than its port")),
        "{:#?}",
        report.warnings
    );
    let orientation = &set.structure.as_ref().unwrap().orientations[0];
    // The 40° move and the return 1° short are both moves of the hip pitch.
    assert!(
        orientation.moves.iter().all(|m| m.dof == "r_hip_pitch"),
        "{:?}",
        orientation.moves.iter().map(|m| &m.dof).collect::<Vec<_>>()
    );
    assert!(!orientation.moves.is_empty());
    let structure = explore(set, &ExploreConfig::default()).unwrap();
    let said = |kind: DiagnosticKind| {
        structure
            .diagnostics
            .iter()
            .filter(move |d| d.kind == kind)
            .map(|d| d.message.as_str())
    };
    // The dead board is named.
    assert!(
        structure
            .broken
            .iter()
            .any(|b| b.su == DEAD && b.kind == "dead"),
        "{:?}",
        structure.broken
    );
    assert_eq!(structure.broken.len(), 1, "{:?}", structure.broken);
    // The 40° move turned every live board (the return 1° short did not replace it), and the
    // DoFs that never moved are named.
    assert_eq!(said(DiagnosticKind::DofMovesNoSu).count(), 0);
    assert!(
        said(DiagnosticKind::NoStaticSegment).any(|m| m.contains("r_hip_pitch moved every SU")),
        "{:#?}",
        structure.diagnostics
    );
    let never: Vec<&str> = said(DiagnosticKind::DofNotExplored).collect();
    assert_eq!(never.len(), dofs.len() - 1, "{never:#?}");
    assert_eq!(set.sus.len(), sus.len());
    assert!(dofs.contains(&"r_hip_pitch".to_string()));

    // With the robot's description (`ingest --robot`): its other 20 DoFs have no joint states in
    // this log (a per-part port); they are named, not a reason to refuse it.
    let with_robot = ingest(
        &[dir.path().join("leg")],
        &IngestConfig {
            dofs: Some(robot.model.dof_names()),
            sus: Some(robot.model.su_names()),
            ..IngestConfig::default()
        },
        &mut |_, _, _| {},
    )
    .unwrap_or_else(|e| panic!("{e}"));
    let unrecorded = &with_robot.report.logs[0].unrecorded_joints;
    let others: Vec<String> = robot
        .model
        .dof_names()
        .into_iter()
        .filter(|d| !dofs.contains(d))
        .collect();
    assert_eq!(unrecorded, &others);
    assert_eq!(with_robot.measurements.dofs, dofs);
    assert!(
        with_robot
            .report
            .warnings
            .iter()
            .any(|w| w.contains("not recorded") && w.contains("l_knee")),
        "{:#?}",
        with_robot.report.warnings
    );
    // The description's SUs that this log has no sample of are left out by name.
    assert_eq!(with_robot.measurements.sus, sus);
}
