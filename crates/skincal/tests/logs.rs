//! Plans, time-series logs and their ingestion: plan → 1 kHz simulation (MCAP or CSV) → ingest
//! must give the readings the condensed simulator's physics gives at the same poses (computed here
//! from the true robot), and explore + calibrate on it must do as well as on condensed data.

use std::path::Path;

use crate::bags::{mcap_to_db3, ros1_bags, rosbag2};

use nalgebra::Vector3;
use skincal::estimate::body::calibrate_body;
use skincal::estimate::ml::MlConfig;
use skincal::explore::{explore, ExploreConfig};
use skincal::ingest::{ingest, IngestConfig};
use skincal::log::csv::CsvSink;
use skincal::log::mcap::{Compression, McapSink};
use skincal::log::ros::{decode, Imu, Time};
use skincal::log::{read_log, LogSink, Stream, Topics};
use skincal::measurements::MeasurementSet;
use skincal::model::sensor::{peak_dynamic_accelerations, static_readings};
use skincal::model::{presets, Robot};
use skincal::plan::{Action, Part, Plan, PlanConfig, PlanDof};
use skincal::predict::validate;
use skincal::sim::timeseries::{record, LogConfig};
use skincal::sim::{simulate, BaseOrientation, Imperfections, SimulationConfig};

fn robot(name: &str) -> Robot {
    presets::find(name).unwrap().robot().unwrap()
}

fn record_to(robot: &Robot, plan: &Plan, config: &LogConfig, path: &Path, mcap: bool) {
    let mut sink: Box<dyn LogSink> = if mcap {
        Box::new(McapSink::new(
            path,
            Topics::default(),
            Compression::Zstd,
            false,
        ))
    } else {
        Box::new(CsvSink::new(path, false))
    };
    record(robot, plan, config, sink.as_mut(), &mut |_| {}).unwrap();
}

/// Largest |ingested − truth| over static and dynamic readings of the training poses, m/s².
fn training_errors(robot: &Robot, set: &MeasurementSet) -> (f64, f64) {
    let t = set.training.as_ref().unwrap();
    let g = Vector3::new(0.0, 0.0, -9.81);
    let mut s_max = 0.0f64;
    for pose in &t.poses {
        let truth = static_readings(&robot.model, &robot.parameters, &pose.q, &g);
        for (r, e) in pose.static_readings.iter().zip(&truth) {
            s_max = s_max.max((Vector3::from(*r) - e).amax());
        }
    }
    let d_max = dynamic_errors(robot, set)
        .iter()
        .fold(0.0f64, |m, e| m.max(e.amax()));
    (s_max, d_max)
}

/// Ingested − truth of every dynamic reading of the training poses, m/s².
fn dynamic_errors(robot: &Robot, set: &MeasurementSet) -> Vec<Vector3<f64>> {
    let t = set.training.as_ref().unwrap();
    let mut errors = Vec::new();
    for pose in &t.poses {
        for (dof, readings) in &pose.dynamic {
            let d = set.dof_index(dof).unwrap();
            let truth =
                peak_dynamic_accelerations(&robot.model, &robot.parameters, &pose.q, d, &t.pattern);
            errors.extend(
                readings
                    .iter()
                    .zip(&truth)
                    .map(|(r, e)| Vector3::from(*r) - e),
            );
        }
    }
    errors
}

#[test]
fn a_skin_at_another_rate_than_the_joint_states_gives_readings_as_good_as_its_samples_allow() {
    // Regressions: with joint states at 100 Hz and the skin at 1 kHz, nine skin samples in ten
    // fell on a grid point that already had one and were dropped unsaid (the dynamic readings
    // √10 noisier than the log allows); each point now takes the mean of its samples. With the
    // skin at 500 or 250 Hz and joint states at 1 kHz, the points between its samples are
    // interpolated, and the readings' deviations said they were as good as at 1 kHz. With both
    // at 1 kHz, an excitation's window lost its samples where it reaches into the pause before
    // it, which the still window read instead, and filled them with its first (21 per SU and
    // excitation on this robot's default program): a sample in two windows now goes to both.
    let robot = robot("paper-7dof");
    let plan = Plan::new(
        PlanDof::from_robot(&robot),
        &PlanConfig {
            poses: 2,
            seed: 5,
            ..PlanConfig::default()
        },
    )
    .unwrap();
    let dir = tempfile::tempdir().unwrap();
    let full = dir.path().join("full");
    record_to(&robot, &plan, &LogConfig::default(), &full, false);
    // The log with the lines of `file` at one stamp in `every` (the header kept).
    let thinned = |file: &str, every: usize| {
        let out = dir.path().join(format!("{file}-{every}"));
        std::fs::create_dir(&out).unwrap();
        for f in ["joint_states.csv", "imu.csv"] {
            std::fs::copy(full.join(f), out.join(f)).unwrap();
        }
        let text = std::fs::read_to_string(full.join(file)).unwrap();
        let mut stamps: Vec<&str> = Vec::new();
        let kept: String = text
            .lines()
            .enumerate()
            .filter(|&(i, l)| {
                let stamp = l.split(',').next().unwrap();
                if stamps.last() != Some(&stamp) {
                    stamps.push(stamp);
                }
                i == 0 || (stamps.len() - 2) % every == 0
            })
            .map(|(_, l)| format!("{l}\n"))
            .collect();
        std::fs::write(out.join(file), kept).unwrap();
        out
    };
    let config = IngestConfig {
        pattern: Some(plan.pattern),
        ..IngestConfig::default()
    };
    // RMS error of the dynamic readings against the truth, and their mean deviation.
    let quality = |path: &Path| {
        let got = ingest(&[path.to_path_buf()], &config, &mut |_, _, _| {}).unwrap();
        let set = &got.measurements;
        let e = dynamic_errors(&robot, set);
        let rms = (e.iter().map(|e| e.norm_squared()).sum::<f64>() / e.len() as f64).sqrt();
        let sds: Vec<f64> = set
            .training
            .as_ref()
            .unwrap()
            .poses
            .iter()
            .flat_map(|p| p.dynamic_sd.values().flatten().copied())
            .collect();
        (
            rms,
            sds.iter().sum::<f64>() / sds.len() as f64,
            got.report.logs[0].clone(),
        )
    };
    let (e_1k, sd_1k, report) = quality(&full);
    assert_eq!(report.filled, 0, "a clean log's samples are all read");
    // The joint states at 100 Hz: the same skin samples, the same quality.
    let (e, sd, report) = quality(&thinned("joint_states.csv", 10));
    assert!((report.rate - 100.0).abs() < 0.1 && report.filled == 0);
    assert!(e < 1.2 * e_1k, "{e} against {e_1k}");
    assert!((sd / sd_1k - 1.0).abs() < 0.2, "{sd} against {sd_1k}");
    // The skin at 500 and 250 Hz: half and a quarter of the samples, errors and deviations √2
    // and 2 times as large.
    for every in [2, 4] {
        let (e, sd, report) = quality(&thinned("imu.csv", every));
        let k = (every as f64).sqrt();
        assert!(report.filled > 0);
        assert!(
            (e / (k * e_1k) - 1.0).abs() < 0.2,
            "1 in {every}: {e} against {e_1k}"
        );
        assert!(
            (sd / (k * sd_1k) - 1.0).abs() < 0.2,
            "1 in {every}: {sd} against {sd_1k}"
        );
    }
    // The deviations say the errors: the norm of three components, each of σ.
    assert!(
        (e_1k / (3f64.sqrt() * sd_1k) - 1.0).abs() < 0.35,
        "{e_1k} {sd_1k}"
    );
}

#[test]
fn plan_log_ingest_matches_the_condensed_physics_and_calibrates_as_well() {
    let robot = robot("paper-7dof");
    let plan = Plan::new(
        PlanDof::from_robot(&robot),
        &PlanConfig {
            poses: 12,
            seed: 3,
            ..PlanConfig::default()
        },
    )
    .unwrap();
    let dir = tempfile::tempdir().unwrap();
    let upright = dir.path().join("upright.mcap");
    let tilted = dir.path().join("tilted");
    let noise = LogConfig {
        seed: 5,
        ..LogConfig::default()
    };
    record_to(&robot, &plan, &noise, &upright, true);
    record_to(
        &robot,
        &plan,
        &LogConfig {
            part: Some(Part::Structure),
            orientation: BaseOrientation::tilted(),
            seed: 6,
            ..LogConfig::default()
        },
        &tilted,
        false,
    );
    let ingested = ingest(
        &[upright.clone(), tilted.clone()],
        &IngestConfig::default(),
        &mut |_, _, _| {},
    )
    .unwrap();
    let set = ingested.measurements;
    set.validate().unwrap();
    let report = &ingested.report;
    assert_eq!(report.orientations, 2, "{report:#?}");
    assert_eq!(report.training_poses, 12);
    assert_eq!(report.dynamic, 12 * 7);
    assert!(report.warnings.is_empty(), "{:?}", report.warnings);
    // The estimated pattern is the plan's within the smoothing of the peak estimates.
    assert!(
        (report.pattern.peak_acceleration() / plan.pattern.peak_acceleration() - 1.0).abs() < 0.05
    );
    // Within the noise: one sample has ±0.098 m/s² of uniform noise (σ 0.057); a static reading
    // averages thousands of samples, a dynamic one is fitted over a 2 s window.
    let (s_max, d_max) = training_errors(&robot, &set);
    assert!(s_max < 0.01, "static {s_max}");
    assert!(d_max < 0.06, "dynamic {d_max}");

    // Explore and calibrate as on condensed data with the same sensor noise.
    let structure = explore(&set, &ExploreConfig::default()).unwrap();
    assert!(structure.complete, "{:?}", structure.diagnostics);
    let condensed = simulate(
        &robot,
        &SimulationConfig {
            poses: 12,
            seed: 3,
            ..SimulationConfig::default()
        },
    )
    .unwrap()
    .measurements;
    let condensed_structure = explore(&condensed, &ExploreConfig::default()).unwrap();
    assert_eq!(
        structure.matrix, condensed_structure.matrix,
        "the same sorted activity matrix"
    );
    assert!(structure.uncertain.is_empty(), "{:?}", structure.uncertain);
    let held_out = crate::common::held_out(&robot, 77);
    let config = MlConfig::default();
    let from_log = calibrate_body(&set, Some(&structure), &config, None).unwrap();
    let from_condensed =
        calibrate_body(&condensed, Some(&condensed_structure), &config, None).unwrap();
    let a = validate(&from_log, &held_out, "held-out").unwrap();
    let b = validate(&from_condensed, &held_out, "held-out").unwrap();
    eprintln!(
        "held-out RMS static/dynamic: from the log {:.4}/{:.4}, condensed {:.4}/{:.4} m/s²",
        a.static_rms, a.dynamic_rms, b.static_rms, b.dynamic_rms
    );
    assert!(
        a.static_rms <= b.static_rms * 1.2 + 0.005,
        "{} vs {}",
        a.static_rms,
        b.static_rms
    );
    assert!(
        a.dynamic_rms <= b.dynamic_rms * 1.2 + 0.005,
        "{} vs {}",
        a.dynamic_rms,
        b.dynamic_rms
    );
}

/// The whole path of the short program on a preset: plan (as many poses as the forecast needs
/// for 0.009 m/s²) → 1 kHz logs, upright and the structure part tilted → ingest with windows
/// fitted to the plan's still periods → explore → calibrate → a noise-free held-out set.
/// Returns the plan and the held-out RMS (static, dynamic).
fn short_program_whole_path(name: &str) -> (Plan, f64, f64) {
    let robot = robot(name);
    let dofs = PlanDof::from_robot(&robot);
    let (plan, forecast) = skincal::design::poses_for(
        &robot,
        &dofs,
        &PlanConfig::short(),
        (0.009, None),
        None,
        &mut |_| {},
    )
    .unwrap();
    assert!(forecast.worst() <= 0.009, "{forecast:?}");
    let dir = tempfile::tempdir().unwrap();
    let upright = dir.path().join("upright.mcap");
    let tilted = dir.path().join("tilted.mcap");
    record_to(&robot, &plan, &LogConfig::default(), &upright, true);
    let tilt = LogConfig {
        part: Some(Part::Structure),
        orientation: BaseOrientation::tilted(),
        seed: 2,
        ..LogConfig::default()
    };
    record_to(&robot, &plan, &tilt, &tilted, true);
    let config = IngestConfig {
        pattern: Some(plan.pattern),
        ..IngestConfig::default()
    }
    .for_still_periods(plan.config.still);
    let ingested = ingest(&[upright, tilted], &config, &mut |_, _, _| {}).unwrap();
    let report = &ingested.report;
    assert!(report.warnings.is_empty(), "{:?}", report.warnings);
    assert_eq!(report.training_poses, plan.config.poses);
    assert_eq!(
        report.dynamic,
        plan.config.poses * dofs.len(),
        "every excitation, the last one's too"
    );
    let set = ingested.measurements;
    let structure = explore(&set, &ExploreConfig::default()).unwrap();
    assert!(structure.complete, "{:?}", structure.diagnostics);
    let condensed = simulate(&robot, &SimulationConfig::default())
        .unwrap()
        .measurements;
    assert_eq!(
        structure.matrix,
        explore(&condensed, &ExploreConfig::default())
            .unwrap()
            .matrix
    );
    let model = calibrate_body(&set, Some(&structure), &MlConfig::default(), None).unwrap();
    assert!(model.limbs.iter().all(|l| l.estimate.converged));
    let check = validate(&model, &crate::common::held_out(&robot, 99), "held-out").unwrap();
    eprintln!(
        "{name}: {:.1} s, {} poses; forecast static {:.4}, dynamic {:.4}; held-out RMS static \
         {:.4}, dynamic {:.4} m/s²",
        plan.duration,
        plan.config.poses,
        forecast.static_rms,
        forecast.dynamic_rms,
        check.static_rms,
        check.dynamic_rms
    );
    // The forecast (condensed readings at the plan's poses with the noise one recorded pose
    // showed) against the whole path from the logs: one recording scatters about it.
    for (measured, forecast) in [
        (check.static_rms, forecast.static_rms),
        (check.dynamic_rms, forecast.dynamic_rms),
    ] {
        assert!(
            (0.6..1.6).contains(&(measured / forecast)),
            "{measured} against {forecast}"
        );
    }
    (plan, check.static_rms, check.dynamic_rms)
}

#[test]
fn the_short_program_runs_under_a_minute_and_predicts_held_out_readings_within_0_01() {
    let (plan, s, d) = short_program_whole_path("paper-7dof");
    let paper = Plan::new(plan.dofs.clone(), &PlanConfig::default()).unwrap();
    assert!(plan.duration <= 60.0 && plan.duration * 7.0 < paper.duration);
    assert!(s < 0.01 && d < 0.01);
}

#[test]
fn the_humanoids_short_program_runs_under_four_minutes_and_predicts_within_0_01() {
    // Five limbs in parallel: 6 windows per pose instead of 26.
    let (plan, s, d) = short_program_whole_path("humanoid");
    let paper = Plan::new(plan.dofs.clone(), &PlanConfig::default()).unwrap();
    eprintln!("paper's program {:.1} s", paper.duration);
    assert!(plan.duration <= 240.0 && plan.duration * 10.0 < paper.duration);
    assert!(s < 0.01 && d < 0.01);
}

#[test]
fn noise_free_log_gives_the_exact_readings_whatever_the_servo_did() {
    // The robot runs the pattern backwards, at 2.5 Hz instead of 2, with another window; the
    // ingestion, told the nominal pattern, must still give the response to the nominal positive
    // pattern — from a CSV log with jittered stamps and lost samples.
    let robot = robot("paper-7dof");
    let nominal = Plan::new(
        PlanDof::from_robot(&robot),
        &PlanConfig {
            poses: 3,
            seed: 9,
            ..PlanConfig::default()
        },
    )
    .unwrap();
    for (variant, csv) in [(false, false), (true, true)] {
        let mut plan = nominal.clone();
        let mut config = LogConfig {
            imperfections: Imperfections::none(),
            ..LogConfig::default()
        };
        if variant {
            plan.pattern.amplitude = -0.4;
            plan.pattern.frequency = 2.5;
            plan.window.ramp_cycles = 1.5;
            plan.window.hold_cycles = 1.0;
            // Re-time the phases for the new pattern length.
            let mut t = 0.0;
            for p in &mut plan.phases {
                p.start = t;
                if matches!(p.action, Action::Excitation { .. }) {
                    p.duration = plan.window.duration(plan.pattern.frequency);
                }
                t += p.duration;
            }
            plan.duration = t;
            config.jitter = 2e-5;
            config.drop_probability = 0.01;
            config.seed = 4;
        }
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join(if csv { "log" } else { "log.mcap" });
        record_to(&robot, &plan, &config, &path, !csv);
        let ingested = ingest(
            &[path],
            &IngestConfig {
                pattern: Some(nominal.pattern),
                ..IngestConfig::default()
            },
            &mut |_, _, _| {},
        )
        .unwrap();
        let report = &ingested.report;
        assert_eq!(report.training_poses, 3, "{report:#?}");
        assert_eq!(report.orientations, 1);
        if variant {
            assert!(
                report.logs[0].filled > 0,
                "lost samples are filled and counted"
            );
        }
        let (s_max, d_max) = training_errors(&robot, &ingested.measurements);
        // Exact physics leaves only the stamps' resolution (0.24 µs at ROS epoch times): 1e-3.
        // Jitter of 20 µs on the joint stamps misplaces positions by up to 1e-5 rad, an
        // acceleration noise of ~0.06 rad/s² in the ±20 ms difference: 5e-3. CSV keeps 6 decimals.
        let (s_tol, d_tol) = if variant { (1e-5, 5e-3) } else { (1e-9, 1e-3) };
        assert!(s_max < s_tol, "variant {variant}: static {s_max:e}");
        assert!(d_max < d_tol, "variant {variant}: dynamic {d_max:e}");
        // Structure moves: one per DoF, at the planned poses.
        let structure = ingested.measurements.structure.as_ref().unwrap();
        assert_eq!(structure.orientations[0].moves.len(), 7);
    }
}

/// Records `plan` noise-free: the whole plan upright and its structure part tilted.
fn noise_free_logs(robot: &Robot, plan: &Plan, dir: &Path) -> [std::path::PathBuf; 2] {
    let exact = LogConfig {
        imperfections: Imperfections::none(),
        ..LogConfig::default()
    };
    let paths = [dir.join("upright.mcap"), dir.join("tilted.mcap")];
    record_to(robot, plan, &exact, &paths[0], true);
    let tilt = LogConfig {
        part: Some(Part::Structure),
        orientation: BaseOrientation::tilted(),
        ..exact
    };
    record_to(robot, plan, &tilt, &paths[1], true);
    paths
}

/// The humanoid's short program of 2 poses, whose five limbs run their patterns at the same
/// time, one depth of the tree after the other, and its ingestion settings.
fn parallel_limbs() -> (Robot, Plan, IngestConfig) {
    let robot = robot("humanoid");
    let plan = Plan::new(
        PlanDof::from_robot(&robot),
        &PlanConfig {
            poses: 2,
            ..PlanConfig::short()
        },
    )
    .unwrap();
    let config = IngestConfig {
        pattern: Some(plan.pattern),
        ..IngestConfig::default()
    }
    .for_still_periods(plan.config.still);
    (robot, plan, config)
}

/// Noise-free, every reading of `set` is the true one for its DoF alone — zero exactly where the
/// model says the DoF does not move the SU — as if the DoFs had been excited one at a time.
fn each_dof_its_exact_response(robot: &Robot, set: &MeasurementSet) {
    let (s_max, d_max) = training_errors(robot, set);
    // The one-period windows of the short protocol leave 1.4e-3 m/s² of the stamps' resolution
    // whether the DoFs run one at a time or together.
    assert!(
        s_max < 1e-9 && d_max < 2e-3,
        "static {s_max:e}, dynamic {d_max:e}"
    );
    let pose = &set.training.as_ref().unwrap().poses[0];
    let mut zeros = 0;
    for (dof, readings) in &pose.dynamic {
        let d = robot.model.dof_index(dof).unwrap();
        for (name, r) in set.sus.iter().zip(readings) {
            let su = robot.model.su_index(name).unwrap();
            if !robot.model.moves_su(d, su) {
                assert_eq!(*r, [0.0; 3], "{dof} on {name}");
                zeros += 1;
            }
        }
    }
    assert!(zeros > 26 * 31 / 2, "{zeros}");
}

#[test]
fn limbs_excited_in_parallel_give_each_dof_its_exact_response() {
    // Each SU answers to at most one DoF of a window; which one the structure part tells.
    let (robot, plan, config) = parallel_limbs();
    let windows: Vec<(&String, &Vec<String>)> = plan
        .phases
        .iter()
        .filter_map(|p| match &p.action {
            Action::Excitation { dof, together } => Some((dof, together)),
            _ => None,
        })
        .collect();
    assert_eq!(windows.len(), 2 * 6, "6 depths: the legs' 6 DoFs");
    let dir = tempfile::tempdir().unwrap();
    let logs = noise_free_logs(&robot, &plan, dir.path());
    let ingested = ingest(&logs, &config, &mut |_, _, _| {}).unwrap();
    let report = &ingested.report;
    assert!(report.warnings.is_empty(), "{:?}", report.warnings);
    assert_eq!(report.training_poses, 2);
    assert_eq!(report.dynamic, 2 * 26, "every DoF of every limb");
    let fits = &report.logs[0].fits;
    assert_eq!(fits.len(), windows.len());
    for (fit, (dof, together)) in fits.iter().zip(&windows) {
        let mut found: Vec<&String> = std::iter::once(&fit.dof).chain(&fit.together).collect();
        let mut planned: Vec<&String> = std::iter::once(*dof).chain(*together).collect();
        found.sort();
        planned.sort();
        assert_eq!(found, planned);
    }
    each_dof_its_exact_response(&robot, &ingested.measurements);
    // The tree is found with the user's exploration settings: at a threshold above any change
    // of gravity (3 g) no DoF moves any SU, so no SU is given a response in these windows.
    let blind = IngestConfig {
        explore: skincal::explore::ExploreConfig {
            threshold: 3.0,
            ..Default::default()
        },
        ..config
    };
    let set = ingest(&logs, &blind, &mut |_, _, _| {})
        .unwrap()
        .measurements;
    let pose = &set.training.as_ref().unwrap().poses[0];
    assert!(pose.dynamic.values().flatten().all(|r| *r == [0.0; 3]));
}

/// The same program in one upright log (no tilted structure part): the yaw DoFs' axes stand
/// vertical at the structure part's poses, so their moves turn no gravity and the static tree
/// has them move no SU — every SU's reading of them was zero, and every limb's fit of those
/// readings ended at 11–52 σ. The moves' accelerations from the motion record place them, and
/// the readings are assembled again by that tree: every one is the true one.
#[test]
fn limbs_excited_in_parallel_in_one_upright_log_are_told_apart_by_what_the_moves_accelerated() {
    let (robot, plan, config) = parallel_limbs();
    let dir = tempfile::tempdir().unwrap();
    let [upright, _] = noise_free_logs(&robot, &plan, dir.path());
    let logs = [upright];
    let static_tree = ingest(&logs, &config, &mut |_, _, _| {}).unwrap();
    let yaw = |set: &MeasurementSet| -> Vec<[f64; 3]> {
        let pose = &set.training.as_ref().unwrap().poses[0];
        ["l_hip_yaw", "r_hip_yaw", "neck_yaw"]
            .iter()
            .flat_map(|d| pose.dynamic[*d].iter().copied())
            .collect()
    };
    assert!(
        yaw(&static_tree.measurements)
            .iter()
            .all(|r| *r == [0.0; 3]),
        "the static tree has the vertical axes move no SU"
    );
    let mut ingested = static_tree;
    let record = skincal::ingest::motion::record_of(&mut ingested, &config, &mut |_, _, _| {})
        .unwrap()
        .unwrap();
    assert!(
        ingested.report.warnings.is_empty(),
        "{:?}",
        ingested.report.warnings
    );
    assert_eq!(ingested.report.dynamic, 2 * 26);
    let set = &ingested.measurements;
    assert!(yaw(set).iter().any(|r| *r != [0.0; 3]));
    each_dof_its_exact_response(&robot, set);
    // What the moves accelerated is filled in again on the set read with the tree.
    let moves = &set.structure.as_ref().unwrap().orientations[0].moves;
    assert!(moves.iter().all(|m| !m.accelerated.is_empty()));
    assert_eq!(record.dofs, set.dofs);
}

/// Limbs excited in parallel: without the structure part, and with a wrong tree, ingest says why
/// it cannot attribute them; given the tree of an earlier structure experiment, it can.
#[test]
fn limbs_excited_in_parallel_need_the_structure_part_and_a_true_tree() {
    let robot = robot("humanoid");
    let dofs = PlanDof::from_robot(&robot);
    let short = PlanConfig {
        poses: 1,
        ..PlanConfig::short()
    };
    let dir = tempfile::tempdir().unwrap();
    let config = IngestConfig::default().for_still_periods(short.still);
    // Without the structure part, which DoF of a window moves an SU is unknown.
    let plan = Plan::new(dofs.clone(), &short).unwrap();
    let training = dir.path().join("training.mcap");
    let only = LogConfig {
        part: Some(Part::Training),
        imperfections: Imperfections::none(),
        ..LogConfig::default()
    };
    record_to(&robot, &plan, &only, &training, true);
    let err = ingest(std::slice::from_ref(&training), &config, &mut |_, _, _| {})
        .unwrap_err()
        .to_string();
    assert!(
        err.contains("excited together")
            && err.contains("structure part")
            && err.contains("--structure"),
        "{err}"
    );
    // The tree of an earlier structure experiment (here the condensed simulation's) tells them
    // apart: every reading is the true one.
    let condensed = simulate(&robot, &SimulationConfig::default())
        .unwrap()
        .measurements;
    let given = IngestConfig {
        tree: Some(explore(&condensed, &ExploreConfig::default()).unwrap()),
        pattern: Some(plan.pattern),
        ..config.clone()
    };
    let ingested = ingest(&[training], &given, &mut |_, _, _| {}).unwrap();
    assert_eq!(ingested.report.dynamic, 26);
    each_dof_its_exact_response(&robot, &ingested.measurements);
    // A description whose tree is wrong (every DoF on the base) puts DoFs of one chain in one
    // window: the SUs that both move are named.
    let flat: Vec<PlanDof> = dofs
        .into_iter()
        .map(|d| PlanDof { parent: None, ..d })
        .collect();
    let plan = Plan::new(flat, &short).unwrap();
    let logs = noise_free_logs(&robot, &plan, dir.path());
    let err = ingest(&logs, &config, &mut |_, _, _| {})
        .unwrap_err()
        .to_string();
    assert!(
        err.contains("both move SU") && err.contains("tree"),
        "{err}"
    );
}

/// Largest |finite difference| of the sampled trajectory against each DoF's limits.
#[test]
fn plans_respect_every_limit() {
    let mut robot = robot("humanoid");
    // Mixed limits: some DoFs slow, some with a narrow range; one with no limits given.
    let mut dofs = PlanDof::from_robot(&robot);
    for (i, d) in dofs.iter_mut().enumerate() {
        if i % 3 == 0 {
            d.velocity = 0.3;
            d.acceleration = 2.0;
        }
        if i % 5 == 1 {
            d.lower = -0.2;
            d.upper = 0.35;
        }
    }
    let _ = &mut robot;
    for protocol in [PlanConfig::default(), PlanConfig::short()] {
        respects_every_limit(&robot, &dofs, protocol);
    }
}

fn respects_every_limit(robot: &Robot, dofs: &[PlanDof], protocol: PlanConfig) {
    let dofs = dofs.to_vec();
    let config = PlanConfig {
        poses: 3,
        seed: 1,
        ..protocol
    };
    let plan = Plan::new(dofs.clone(), &config).unwrap();
    // A and f were chosen from the slowest DoF.
    assert!(plan.pattern.amplitude <= 0.3 * 0.95 + 1e-12);
    assert!(plan.pattern.excursion() <= config.max_excursion + 1e-12);
    let rate = 1000.0;
    let samples = plan.sample(rate);
    let dt = 1.0 / rate;
    for (d, lim) in dofs.iter().enumerate() {
        let q: Vec<f64> = samples.iter().map(|(_, q)| q[d]).collect();
        let (lo, hi) = q
            .iter()
            .fold((f64::MAX, f64::MIN), |(a, b), &x| (a.min(x), b.max(x)));
        assert!(
            lo >= lim.lower - 1e-12 && hi <= lim.upper + 1e-12,
            "{}: range {lo}..{hi}",
            lim.name
        );
        let v = q
            .windows(2)
            .map(|w| ((w[1] - w[0]) / dt).abs())
            .fold(0.0, f64::max);
        let a = q
            .windows(3)
            .map(|w| ((w[2] - 2.0 * w[1] + w[0]) / (dt * dt)).abs())
            .fold(0.0, f64::max);
        assert!(
            v <= lim.velocity,
            "{}: velocity {v} > {}",
            lim.name,
            lim.velocity
        );
        assert!(
            a <= lim.acceleration,
            "{}: acceleration {a} > {}",
            lim.name,
            lim.acceleration
        );
    }
    // One DoF at a time except transfers and parallel excitations; every excitation ends where
    // it started, and DoFs excited together are on different branches of the tree (neither
    // moves the other's segment).
    let model = &robot.model;
    let mut excited = vec![0; dofs.len()];
    for p in &plan.phases {
        let moved = p.from.iter().zip(&p.to).filter(|(a, b)| a != b).count();
        match &p.action {
            Action::Still => assert_eq!(moved, 0),
            Action::Excitation { dof, together } => {
                assert_eq!(moved, 0);
                assert!(config.parallel || together.is_empty());
                let all: Vec<usize> = std::iter::once(dof)
                    .chain(together)
                    .map(|n| model.dof_index(n).unwrap())
                    .collect();
                for &a in &all {
                    excited[a] += 1;
                    for &b in &all {
                        assert!(a == b || !model.moves_segment(a, model.dofs()[b].child));
                    }
                }
            }
            Action::Move { .. } => assert_eq!(moved, 1),
            Action::Transfer => {}
            Action::Sweep(_) => panic!("a program of training poses has no sweep"),
        }
    }
    assert!(excited.iter().all(|&n| n == config.poses), "{excited:?}");
    if config.parallel {
        // As few windows per pose as the longest chain of DoFs.
        let longest = (0..model.segments().len())
            .map(|s| model.chain_to(s).len())
            .max()
            .unwrap();
        let windows = plan
            .phases
            .iter()
            .filter(|p| matches!(p.action, Action::Excitation { .. }))
            .count();
        assert_eq!(windows, longest * config.poses);
    }
    // A given pattern that is too fast for a DoF is refused, naming it.
    let err = Plan::new(
        dofs,
        &PlanConfig {
            pattern: Some(skincal::model::sensor::ExcitationPattern {
                amplitude: 0.5,
                frequency: 2.0,
            }),
            ..config
        },
    )
    .unwrap_err()
    .to_string();
    assert!(err.contains(&robot.model.dofs()[0].name), "{err}");
}

#[test]
fn recorded_imu_messages_carry_exact_millisecond_stamps_and_the_noise_covariance() {
    // At an epoch-sized start an f64 of seconds resolves only about 240 ns: the stamps of a 1 kHz
    // log must still be whole milliseconds apart, and every Imu must state its noise.
    let robot = robot("paper-7dof");
    let plan = Plan::new(PlanDof::from_robot(&robot), &PlanConfig::default()).unwrap();
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("structure.mcap");
    let config = LogConfig {
        part: Some(Part::Structure),
        start_stamp: 1_767_225_600.123,
        ..LogConfig::default()
    };
    record_to(&robot, &plan, &config, &path, true);
    let bytes = std::fs::read(&path).unwrap();
    let first: u64 = 1_767_225_600_123_000_000;
    // The default ±0.01 g, g = 9.81 m/s² as everywhere in skincal (σ = 0.0566 m/s²).
    let g0 = 9.81;
    let variance = (0.01 * g0) * (0.01 * g0) / 3.0;
    let mut imus = 0;
    let mut first_seen = None;
    for message in mcap::MessageStream::new(&bytes).unwrap() {
        let message = message.unwrap();
        if message.channel.topic != Topics::default().imu {
            continue;
        }
        let imu: Imu = decode(&message.data).unwrap();
        let stamp = imu.header.stamp.nanoseconds();
        assert!(stamp >= first, "stamp {stamp}");
        assert_eq!((stamp - first) % 1_000_000, 0, "stamp {stamp}");
        assert_eq!(imu.header.stamp, Time::from_nanoseconds(stamp as i64));
        assert_eq!(message.log_time, stamp);
        let c = imu.linear_acceleration_covariance;
        for (i, v) in c.iter().enumerate() {
            let expected = if i % 4 == 0 { variance } else { 0.0 };
            assert!((v - expected).abs() < 1e-15, "{c:?}");
        }
        assert_eq!(imu.orientation_covariance[0], -1.0);
        first_seen = first_seen.or(Some(stamp));
        imus += 1;
    }
    let sus = robot.model.su_names().len();
    assert!(imus > 1000 * sus, "{imus} Imu messages");
    assert_eq!(first_seen, Some(first));
}

#[test]
fn rosbag2_bags_in_mcap_and_sqlite_read_as_one_log_and_other_formats_say_what_they_are() {
    let robot = robot("paper-7dof");
    let plan = Plan::new(
        PlanDof::from_robot(&robot),
        &PlanConfig {
            poses: 3,
            seed: 4,
            ..PlanConfig::default()
        },
    )
    .unwrap();
    let dir = tempfile::tempdir().unwrap();
    // The whole program in one file, and the same program as a bag split in two files: the
    // structure part, then the training part stamped on from where the first ends.
    let whole = dir.path().join("whole.mcap");
    record_to(&robot, &plan, &LogConfig::default(), &whole, true);
    let first = dir.path().join("first.mcap");
    let second = dir.path().join("second.mcap");
    let start = LogConfig::default().start_stamp;
    record_to(
        &robot,
        &plan,
        &LogConfig {
            part: Some(Part::Structure),
            ..LogConfig::default()
        },
        &first,
        true,
    );
    record_to(
        &robot,
        &plan,
        &LogConfig {
            part: Some(Part::Training),
            start_stamp: start + plan.structure_duration,
            ..LogConfig::default()
        },
        &second,
        true,
    );
    let config = IngestConfig::default();
    let one = ingest(std::slice::from_ref(&whole), &config, &mut |_, _, _| {}).unwrap();
    let bag = dir.path().join("bag");
    rosbag2(&bag, &[&whole]);
    let same = ingest(std::slice::from_ref(&bag), &config, &mut |_, _, _| {}).unwrap();
    // The same readings; only the source each orientation names differs.
    assert_eq!(same.measurements.training, one.measurements.training);
    let orientations = |m: &MeasurementSet| {
        m.structure
            .as_ref()
            .unwrap()
            .orientations
            .iter()
            .map(|o| (o.rest_pose.clone(), o.rest.clone(), o.moves.clone()))
            .collect::<Vec<_>>()
    };
    assert_eq!(
        orientations(&same.measurements),
        orientations(&one.measurements)
    );
    assert!(
        same.report.logs[0].format.starts_with("rosbag2"),
        "{:?}",
        same.report.logs[0]
    );
    let split = dir.path().join("split");
    rosbag2(&split, &[&first, &second]);
    let two = ingest(&[split], &config, &mut |_, _, _| {}).unwrap();
    assert_eq!(two.report.training_poses, 3, "{:#?}", two.report);
    assert_eq!(two.report.dynamic, 3 * 7);
    let (s_max, d_max) = training_errors(&robot, &two.measurements);
    assert!(s_max < 0.01 && d_max < 0.06, "{s_max} {d_max}");

    // The same program in rosbag2's SQLite storage (as Humble writes it), alone and as a bag.
    let db3 = dir.path().join("whole.db3");
    mcap_to_db3(&whole, &db3);
    let from_db3 = ingest(std::slice::from_ref(&db3), &config, &mut |_, _, _| {}).unwrap();
    assert_eq!(from_db3.measurements.training, one.measurements.training);
    assert_eq!(
        orientations(&from_db3.measurements),
        orientations(&one.measurements)
    );
    let sqlite_bag = dir.path().join("sqlite_bag");
    std::fs::create_dir_all(&sqlite_bag).unwrap();
    std::fs::copy(&db3, sqlite_bag.join("sqlite_bag_0.db3")).unwrap();
    std::fs::write(
        sqlite_bag.join("metadata.yaml"),
        "rosbag2_bagfile_information:\n  version: 5\n  storage_identifier: sqlite3\n  relative_file_paths:\n    - sqlite_bag_0.db3\n",
    )
    .unwrap();
    let from_bag = ingest(
        std::slice::from_ref(&sqlite_bag),
        &config,
        &mut |_, _, _| {},
    )
    .unwrap();
    assert_eq!(from_bag.measurements.training, one.measurements.training);

    // What is not read says what it is and what to do.
    let refused = |path: &Path| {
        ingest(&[path.to_path_buf()], &config, &mut |_, _, _| {})
            .unwrap_err()
            .to_string()
    };
    let damaged = dir.path().join("damaged.db3");
    let mut bytes = std::fs::read(&db3).unwrap();
    bytes.truncate(200);
    bytes.extend(std::iter::repeat_n(0x5a, 4000));
    std::fs::write(&damaged, bytes).unwrap();
    let message = refused(&damaged);
    assert!(
        message.contains("damaged.db3") && message.contains("SQLite"),
        "{message}"
    );
    let ros1 = dir.path().join("cut.bag");
    std::fs::write(&ros1, b"#ROSBAG V2.0\nE\0\0\0").unwrap();
    let message = refused(&ros1);
    assert!(
        message.contains("cut.bag") && message.contains("ROS 1 bag"),
        "{message}"
    );
    let ros1 = dir.path().join("old.bag");
    std::fs::write(&ros1, b"#ROSBAG V1.2\nE\0\0\0").unwrap();
    let message = refused(&ros1);
    assert!(message.contains("rosbag fix"), "{message}");
    std::fs::remove_file(bag.join("bag_0.mcap")).unwrap();
    let message = refused(&bag);
    assert!(
        message.contains("bag_0.mcap") && message.contains("not there"),
        "{message}"
    );
}

#[test]
fn joint_states_split_over_messages_read_like_whole_ones() {
    // Robots whose controllers each publish their own joints on /joint_states: every stamp's
    // positions come in two messages, three DoFs and four.
    use skincal::log::ros::JointState;
    let robot = robot("paper-7dof");
    let plan = Plan::new(
        PlanDof::from_robot(&robot),
        &PlanConfig {
            poses: 1,
            ..PlanConfig::default()
        },
    )
    .unwrap();
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("log.mcap");
    let config = LogConfig {
        part: Some(Part::Structure),
        rate: 200.0,
        ..LogConfig::default()
    };
    record_to(&robot, &plan, &config, &path, true);
    let split = dir.path().join("split.mcap");
    let bytes = std::fs::read(&path).unwrap();
    let file = std::io::BufWriter::new(std::fs::File::create(&split).unwrap());
    let mut writer = mcap::Writer::new(file).unwrap();
    for message in mcap::MessageStream::new(&bytes).unwrap() {
        let message = message.unwrap();
        if message.channel.topic != Topics::default().joints {
            writer.write(&message).unwrap();
            continue;
        }
        let j: JointState = skincal::log::ros::decode(&message.data).unwrap();
        for part in [0..3, 3..j.name.len()] {
            let mut m = message.clone();
            let half = JointState {
                header: j.header.clone(),
                name: j.name[part.clone()].to_vec(),
                position: j.position[part.clone()].to_vec(),
                velocity: j
                    .velocity
                    .get(part.clone())
                    .map(<[f64]>::to_vec)
                    .unwrap_or_default(),
                effort: vec![],
            };
            m.data = skincal::log::ros::encode(&half).unwrap().into();
            writer.write(&m).unwrap();
        }
    }
    writer.finish().unwrap();
    drop(writer);
    let read = |path: &Path| {
        ingest(
            std::slice::from_ref(&path.to_path_buf()),
            &IngestConfig::default(),
            &mut |_, _, _| {},
        )
        .unwrap()
    };
    let (whole, halves) = (read(&path), read(&split));
    assert_eq!(
        halves.report.logs[0].joint_states,
        2 * whole.report.logs[0].joint_states
    );
    let readings = |m: &MeasurementSet| {
        let s = m.structure.as_ref().unwrap();
        s.orientations
            .iter()
            .map(|o| (o.rest.clone(), o.moves.clone()))
            .collect::<Vec<_>>()
    };
    assert_eq!(
        readings(&halves.measurements),
        readings(&whole.measurements)
    );
}

#[test]
fn imu_batches_read_like_one_message_per_su() {
    // A skin driver that publishes every SU of a time step in one skin_msgs/ImuArray: the same
    // recording ingests to the same readings as with one sensor_msgs/Imu per SU.
    let robot = robot("paper-7dof");
    let plan = Plan::new(
        PlanDof::from_robot(&robot),
        &PlanConfig {
            poses: 2,
            seed: 8,
            ..PlanConfig::default()
        },
    )
    .unwrap();
    let dir = tempfile::tempdir().unwrap();
    let single = dir.path().join("single.mcap");
    record_to(&robot, &plan, &LogConfig::default(), &single, true);
    let batched = dir.path().join("batched.mcap");
    let mut sink = McapSink::new(&batched, Topics::default(), Compression::Zstd, false).batched();
    record(&robot, &plan, &LogConfig::default(), &mut sink, &mut |_| {}).unwrap();
    // One batch per time step, every SU in it, each with its own stamp and name.
    let bytes = std::fs::read(&batched).unwrap();
    let (mut batches, mut samples) = (0, 0);
    for message in mcap::MessageStream::new(&bytes).unwrap() {
        let message = message.unwrap();
        if message.channel.topic != Topics::default().imu {
            continue;
        }
        let schema = message.channel.schema.as_ref().unwrap();
        assert_eq!(schema.name, "skin_msgs/msg/ImuArray");
        let batch: skincal::log::ros::ImuArray = decode(&message.data).unwrap();
        assert_eq!(batch.imus.len(), 7);
        assert_eq!(batch.imus[3].header.frame_id, "su4");
        assert_eq!(batch.header.stamp.nanoseconds(), message.log_time);
        batches += 1;
        samples += batch.imus.len();
    }
    assert!(batches > 1000, "{batches}");
    let config = IngestConfig::default();
    let one = ingest(std::slice::from_ref(&single), &config, &mut |_, _, _| {}).unwrap();
    let other = ingest(std::slice::from_ref(&batched), &config, &mut |_, _, _| {}).unwrap();
    assert_eq!(other.measurements.training, one.measurements.training);
    assert_eq!(other.report.training_poses, 2);
    assert_eq!(samples, 7 * batches);
}

#[test]
fn ros1_bags_written_by_the_rosbags_package_read_like_the_csv_log_they_hold() {
    let robot = robot("paper-7dof");
    let plan = Plan::new(
        PlanDof::from_robot(&robot),
        &PlanConfig {
            poses: 1,
            seed: 4,
            ..PlanConfig::default()
        },
    )
    .unwrap();
    let dir = tempfile::tempdir().unwrap();
    let csv = dir.path().join("log");
    let config = LogConfig {
        seed: 8,
        ..LogConfig::default()
    };
    record_to(&robot, &plan, &config, &csv, false);
    let read = |path: &Path| {
        ingest(
            std::slice::from_ref(&path.to_path_buf()),
            &IngestConfig::default(),
            &mut |_, _, _| {},
        )
    };
    let from_csv = read(&csv).unwrap();
    let compressions = ["none", "bz2", "lz4"];
    let bags: Vec<_> = compressions
        .iter()
        .map(|c| dir.path().join(format!("{c}.bag")))
        .collect();
    let specs: Vec<(&Path, &str)> = bags
        .iter()
        .zip(compressions)
        .map(|(b, c)| (b.as_path(), c))
        .collect();
    ros1_bags(&csv, &specs);
    for (bag, compression) in specs {
        let from_bag = read(bag).unwrap();
        let (a, b) = (&from_csv.measurements, &from_bag.measurements);
        assert_eq!(from_bag.report.logs[0].format, "ros1 bag");
        assert_eq!(a.training, b.training, "{compression}");
        let readings = |m: &skincal::measurements::MeasurementSet| {
            let s = m.structure.as_ref().unwrap();
            s.orientations
                .iter()
                .map(|o| (o.rest.clone(), o.moves.clone()))
                .collect::<Vec<_>>()
        };
        assert_eq!(readings(a), readings(b), "{compression}");
        assert_eq!(
            from_csv.report.logs[0].imu_samples,
            from_bag.report.logs[0].imu_samples
        );
    }
    // A bag cut short is an error naming it, not a panic or a partial result.
    let bytes = std::fs::read(dir.path().join("lz4.bag")).unwrap();
    let cut = dir.path().join("cut.bag");
    std::fs::write(&cut, &bytes[..bytes.len() / 2]).unwrap();
    let message = read(&cut).unwrap_err().to_string();
    assert!(message.contains("cut.bag"), "{message}");
}

#[test]
fn the_forecast_follows_the_laws_of_noise_and_poses() {
    // The readings' noise is linear in the samples' noise, and the calibration's error falls as
    // 1/√P with the number of poses (within the scatter of the draws).
    use skincal::design::{forecast, reading_noise, Reference};
    let robot = robot("paper-7dof");
    let dofs = PlanDof::from_robot(&robot);
    let plan = |poses| {
        Plan::new(
            dofs.clone(),
            &PlanConfig {
                poses,
                ..PlanConfig::short()
            },
        )
        .unwrap()
    };
    let six = plan(6);
    let low = reading_noise(&robot, &six, Some(0.05)).unwrap();
    let high = reading_noise(&robot, &six, Some(0.1)).unwrap();
    for (a, b) in [
        (low.static_sd, high.static_sd),
        (low.dynamic_sd, high.dynamic_sd),
    ] {
        assert!((b / a - 2.0).abs() < 0.2, "{a} → {b}");
    }
    // Past the first few poses (with six, each more pose also fixes the kinematics' conditioning).
    let reference = Reference::of(&robot).unwrap();
    let small = forecast(&robot, &reference, &plan(12), &low, 8).unwrap();
    let large = forecast(&robot, &reference, &plan(48), &low, 8).unwrap();
    for (a, b) in [
        (small.static_rms, large.static_rms),
        (small.dynamic_rms, large.dynamic_rms),
    ] {
        assert!((0.35..0.7).contains(&(b / a)), "{a} → {b} (1/√4 = 0.5)");
    }
    // Every DoF's own forecast falls with the poses too, and their median as 1/√P.
    let names = robot.model.dof_names();
    for f in [&small, &large] {
        let dofs: Vec<&String> = f.dofs.iter().map(|d| &d.dof).collect();
        assert_eq!(dofs, names.iter().collect::<Vec<_>>());
    }
    let mut ratios: Vec<f64> = small
        .dofs
        .iter()
        .zip(&large.dofs)
        .map(|(a, b)| {
            let ratio = b.dynamic_rms / a.dynamic_rms;
            assert!(
                ratio < 0.9,
                "{}: {} → {}",
                a.dof,
                a.dynamic_rms,
                b.dynamic_rms
            );
            ratio
        })
        .collect();
    ratios.sort_by(f64::total_cmp);
    let median = ratios[ratios.len() / 2];
    assert!((0.35..0.7).contains(&median), "{ratios:?} (1/√4 = 0.5)");
    // Without SUs there is nothing to forecast, and it says so.
    let bare = skincal::io::load_robot(
        &crate::common::fixture("arm.urdf").display().to_string(),
        skincal::io::SuPlacement {
            per_link: Some(0),
            seed: 0,
        },
    )
    .unwrap();
    let p = Plan::new(PlanDof::from_robot(&bare), &PlanConfig::short()).unwrap();
    let err = reading_noise(&bare, &p, None).unwrap_err().to_string();
    assert!(err.contains("places no SU"), "{err}");
}

/// Logs read from every worker of rayon's global pool at once (a caller's parallel loop over
/// logs), CSV and MCAP: every read ends, with the samples a read on one thread gives.
#[test]
fn logs_read_inside_a_parallel_loop_over_them_give_every_sample() {
    use rayon::prelude::*;
    let robot = robot("paper-7dof");
    let plan = Plan::new(
        PlanDof::from_robot(&robot),
        &PlanConfig {
            poses: 1,
            seed: 3,
            ..PlanConfig::default()
        },
    )
    .unwrap();
    let dir = tempfile::tempdir().unwrap();
    let csv = dir.path().join("log-csv");
    let mcap = dir.path().join("log.mcap");
    record_to(&robot, &plan, &LogConfig::default(), &csv, false);
    record_to(&robot, &plan, &LogConfig::default(), &mcap, true);
    let count = |path: &Path| {
        let mut n = 0usize;
        read_log(
            path,
            Stream::Both,
            &Topics::default(),
            &mut |_| {
                n += 1;
                Ok(())
            },
            &mut |_| {},
        )
        .unwrap();
        n
    };
    let alone = [count(&csv), count(&mcap)];
    assert!(alone[0] > 10_000 && alone[0] == alone[1], "{alone:?}");
    let paths: Vec<&Path> = (0..4 * rayon::current_num_threads())
        .map(|i| {
            if i % 2 == 0 {
                csv.as_path()
            } else {
                mcap.as_path()
            }
        })
        .collect();
    let together: Vec<usize> = paths.par_iter().map(|p| count(p)).collect();
    assert!(together.iter().all(|&n| n == alone[0]), "{together:?}");
}

#[test]
fn a_plans_tilted_run_ingests_as_a_second_orientation_and_tells_the_first_axis_turns() {
    // `plan --tilted-poses 2`: the whole program upright, then the tilted run (the structure
    // part and the first 2 training poses) with the base tilted. Ingested together, the tilted
    // run's 2 poses are base orientation 1; the calibration then tells how su1 turns about the
    // vertical first axis relative to su2, and its forecast said so beforehand.
    let robot = robot("paper-7dof");
    let plan = Plan::new(
        PlanDof::from_robot(&robot),
        &PlanConfig {
            poses: 4,
            tilted_poses: 2,
            seed: 3,
            ..PlanConfig::default()
        },
    )
    .unwrap();
    assert!(plan.structure_duration < plan.tilted_end() && plan.tilted_end() < plan.duration);
    let dir = tempfile::tempdir().unwrap();
    let path = |name: &str| dir.path().join(name);
    record_to(
        &robot,
        &plan,
        &LogConfig {
            seed: 5,
            ..LogConfig::default()
        },
        &path("upright.mcap"),
        true,
    );
    record_to(
        &robot,
        &plan,
        &LogConfig {
            seed: 6,
            orientation: BaseOrientation::tilted(),
            part: Some(skincal::plan::Part::Tilted),
            ..LogConfig::default()
        },
        &path("tilted.mcap"),
        true,
    );
    let logs = [path("upright.mcap"), path("tilted.mcap")];
    let ingested = ingest(&logs, &IngestConfig::default(), &mut |_, _, _| {}).unwrap();
    let report = &ingested.report;
    assert_eq!(report.orientations, 2, "{report:#?}");
    assert_eq!(report.training_poses, 6, "{:?}", report.warnings);
    let training = ingested.measurements.training.as_ref().unwrap();
    assert_eq!(
        training.poses.iter().filter(|p| p.orientation == 1).count(),
        2
    );
    let set = &ingested.measurements;
    let structure = explore(set, &ExploreConfig::default()).unwrap();
    assert!(structure.complete, "{:?}", structure.diagnostics);
    let model = calibrate_body(set, Some(&structure), &MlConfig::default(), None).unwrap();
    let limb = &model.limbs[0];
    assert!(limb.estimate.converged);
    assert!(limb.estimate.uncertainty[1]
        .undetermined_orientation
        .is_empty());
    let check = validate(&model, &crate::common::held_out(&robot, 77), "held-out").unwrap();
    assert!(
        check.static_rms < 0.05 && check.dynamic_rms < 0.05,
        "{check:?}"
    );
    // The forecast of the same plan, and of it without the tilted run: su2's turn about the
    // first axis relative to su1 is undetermined only without it.
    let turns = |plan: &Plan| {
        let mut plan = plan.clone();
        skincal::design::forecast_plan(&robot, &mut plan, None).unwrap();
        let f = plan.forecast.unwrap();
        f.partly_measured
            .iter()
            .find(|p| p.su == "su2")
            .map_or(0, |p| p.turns)
    };
    let upright_only = Plan::new(
        PlanDof::from_robot(&robot),
        &PlanConfig {
            tilted_poses: 0,
            ..plan.config.clone()
        },
    )
    .unwrap();
    assert_eq!((turns(&plan), turns(&upright_only)), (0, 1));
}

#[test]
fn training_recorded_in_a_second_base_orientation_is_kept_as_its_own_and_named() {
    // The whole program recorded twice, the second time on a tilted mount: the two logs' training
    // poses read two gravities, which one gravity cannot explain (it ended at 756 σ). The tilted
    // log's training poses become base orientation 1 (a gravity of their own in the fit), named,
    // and kept out of the motion record; its structure moves count. They tell what upright poses
    // cannot: how su1 is turned about the vertical first axis relative to su2. Recorded twice on
    // the same mount, both logs' training is kept in one orientation.
    let robot = robot("paper-7dof");
    let poses = 4;
    let plan = Plan::new(
        PlanDof::from_robot(&robot),
        &PlanConfig {
            poses,
            seed: 3,
            ..PlanConfig::default()
        },
    )
    .unwrap();
    let dir = tempfile::tempdir().unwrap();
    let path = |name: &str| dir.path().join(name);
    let whole = |seed, orientation| LogConfig {
        seed,
        orientation,
        ..LogConfig::default()
    };
    record_to(
        &robot,
        &plan,
        &whole(5, BaseOrientation::upright()),
        &path("upright.mcap"),
        true,
    );
    record_to(
        &robot,
        &plan,
        &whole(6, BaseOrientation::tilted()),
        &path("tilted.mcap"),
        true,
    );
    record_to(
        &robot,
        &plan,
        &whole(7, BaseOrientation::upright()),
        &path("again.mcap"),
        true,
    );

    let logs = [path("upright.mcap"), path("tilted.mcap")];
    let ingested = ingest(&logs, &IngestConfig::default(), &mut |_, _, _| {}).unwrap();
    let report = &ingested.report;
    assert_eq!(report.orientations, 2, "{report:#?}");
    assert_eq!(report.training_poses, 2 * poses);
    assert!(!report.logs[0].other_base && report.logs[1].other_base);
    assert_eq!(report.warnings.len(), 1, "{:?}", report.warnings);
    assert!(
        report.warnings[0].starts_with(&format!(
            "{}: its {poses} training poses stood in another base orientation than {}",
            logs[1].display(),
            logs[0].display()
        )) && report.warnings[0].contains("kept as base orientation 1"),
        "{}",
        report.warnings[0]
    );
    let training = ingested.measurements.training.as_ref().unwrap();
    let tilted = training.poses.iter().filter(|p| p.orientation == 1).count();
    assert_eq!(tilted, poses);
    assert_eq!(
        skincal::ingest::motion::training_logs(report),
        vec![logs[0].clone()]
    );
    let set = &ingested.measurements;
    let structure = explore(set, &ExploreConfig::default()).unwrap();
    assert!(structure.complete, "{:?}", structure.diagnostics);
    let windows = calibrate_body(set, Some(&structure), &MlConfig::default(), None).unwrap();
    let record = skincal::ingest::motion::motion_record(
        &skincal::ingest::motion::training_logs(report),
        &set.dofs,
        &set.sus,
        &IngestConfig::default(),
        &mut |_, _, _| {},
    )
    .unwrap();
    let samples = skincal::estimate::body::calibrate_body_on_motion(
        set,
        &record,
        Some(&structure),
        &MlConfig::default(),
        None,
        &[],
        &mut |_, _, _| {},
    )
    .unwrap();
    for (how, model) in [("windows", &windows), ("every sample", &samples)] {
        let limb = &model.limbs[0];
        assert!(limb.estimate.converged, "{how}");
        assert_eq!(limb.other_gravities.len(), 1, "{how}");
        let pair = &limb.estimate.uncertainty[1];
        assert!(pair.undetermined_orientation.is_empty(), "{how}: {pair:?}");
        let check = validate(model, &crate::common::held_out(&robot, 77), "held-out").unwrap();
        assert!(
            check.static_rms < 0.05 && check.dynamic_rms < 0.05,
            "{how}: {check:?}"
        );
        eprintln!(
            "upright and tilted logs, {how}: {:.3} σ, held-out static {:.4}, dynamic {:.4} m/s²",
            limb.estimate.residual_ratio, check.static_rms, check.dynamic_rms
        );
    }

    let logs = [path("upright.mcap"), path("again.mcap")];
    let ingested = ingest(&logs, &IngestConfig::default(), &mut |_, _, _| {}).unwrap();
    let report = &ingested.report;
    assert_eq!(report.training_poses, 2 * poses, "{:?}", report.warnings);
    assert!(report.logs.iter().all(|l| !l.other_base));
    assert_eq!(skincal::ingest::motion::training_logs(report).len(), 2);
}
