//! Prismatic DoFs: gripper fingers of stock URDFs, a linear axis under an arm, fingers without
//! skin. Truth is the simulated robot: the tree its description has, and fresh noise-free poses.

use skincal::estimate::body::calibrate_body;
use skincal::estimate::ml::MlConfig;
use skincal::explore::{explore, DiagnosticKind, ExploreConfig, Severity};
use skincal::io::{load_robot, SuPlacement};
use skincal::model::{DofKind, Robot};
use skincal::predict::validate;
use skincal::sim::{simulate, SimulationConfig};

use crate::real_robots::{description, simulated, tree_is_exact};

/// Simulated experiments of `robot` (±0.01 g, 20 poses, `seed`), explored; the tree checked
/// exact; calibrated; every limb converged; the robot's URDF (`urdf`) checked against the
/// calibration: at most one compared joint outside 3σ; the held-out static and dynamic RMS errors
/// on 20 fresh noise-free poses.
fn calibrated_error(robot: &Robot, urdf: &str, seed: u64, what: &str) -> (f64, f64) {
    let config = SimulationConfig {
        seed,
        ..SimulationConfig::default()
    };
    let set = simulate(robot, &config).unwrap().measurements;
    let structure = explore(&set, &ExploreConfig::default()).unwrap();
    assert!(
        tree_is_exact(robot, &structure),
        "{what}, seed {seed}: {:?}",
        structure.diagnostics
    );
    let model = calibrate_body(&set, Some(&structure), &MlConfig::default(), None).unwrap();
    for limb in &model.limbs {
        assert!(
            limb.estimate.converged,
            "{what}, seed {seed}: {:?} at {:.2} σ",
            limb.dofs, limb.estimate.residual_ratio
        );
    }
    let check = skincal::align::align(&model, urdf).unwrap().check;
    assert!(
        check.disagree.len() <= 1,
        "{what}, seed {seed}: {:?}",
        check.joints
    );
    let held_out = crate::common::held_out(robot, seed + 1000);
    let check = validate(&model, &held_out, "held-out").unwrap();
    eprintln!(
        "{what}, seed {seed}: held-out static {:.4}, dynamic {:.4} m/s²",
        check.static_rms, check.dynamic_rms
    );
    // The calibrated body keeps each DoF's kind.
    let body = model.check().unwrap();
    for dof in robot.model.dofs() {
        if let Some(d) = body.model.dof_index(&dof.name) {
            assert_eq!(body.model.dofs()[d].kind, dof.kind, "{what}: {}", dof.name);
        }
    }
    (check.static_rms, check.dynamic_rms)
}

#[test]
fn stock_urdfs_with_prismatic_fingers_calibrate_without_edits() {
    for (path, fingers) in [
        ("panda_description/urdf/panda.urdf", 2),
        ("baxter_description/urdf/baxter.urdf", 4),
    ] {
        let file = description(path);
        let robot = load_robot(
            file.to_str().unwrap(),
            SuPlacement {
                per_link: Some(2),
                seed: 1,
            },
        )
        .unwrap();
        assert_eq!(robot.model.prismatic_dof_names().len(), fingers, "{path}");
        let urdf = std::fs::read_to_string(&file).unwrap();
        let (s, d) = calibrated_error(&robot, &urdf, 1, path);
        assert!(s <= 0.05 && d <= 0.05, "{path}: {s:.4} / {d:.4} m/s²");
    }
}

/// Baxter (stock URDF, one SU per link) through the short program of one pose, noise-free, in
/// one upright log: its two arms run their patterns at the same time, a gripper's slide with
/// the other arm's wrist, and a mimic finger follows each slide. The static readings place no
/// slide; what the structure moves accelerated places each, and the SUs of the finger its mimic
/// drives move with it: every reading is the true one, for the slides ten times below the
/// arms' (their pattern at 0.1 m per rad). (The readings were zero for every slide; taken from
/// the whole set, the tree saw those zeros and placed no slide either, and left the mimic
/// fingers' SUs unplaced, so every pose was skipped.)
#[test]
fn parallel_arms_with_slides_and_mimic_fingers_in_one_upright_log_give_the_true_readings() {
    use skincal::ingest::IngestConfig;
    use skincal::log::mcap::{Compression, McapSink};
    use skincal::plan::{Plan, PlanConfig, PlanDof};
    use skincal::sim::timeseries::{record, LogConfig};

    let file = description("baxter_description/urdf/baxter.urdf");
    let robot = load_robot(
        file.to_str().unwrap(),
        SuPlacement {
            per_link: Some(1),
            seed: 1,
        },
    )
    .unwrap();
    let plan = Plan::new(
        PlanDof::from_robot(&robot),
        &PlanConfig {
            poses: 1,
            ..PlanConfig::short()
        },
    )
    .unwrap();
    let dir = tempfile::tempdir().unwrap();
    let log = dir.path().join("upright.mcap");
    let mut sink = McapSink::new(&log, Default::default(), Compression::Zstd, false);
    let exact = LogConfig {
        imperfections: skincal::sim::Imperfections::none(),
        ..LogConfig::default()
    };
    record(&robot, &plan, &exact, &mut sink, &mut |_| {}).unwrap();
    let config = IngestConfig::default().with_plan(&plan);
    let logs = [log];
    let mut ingested = skincal::ingest::ingest(&logs, &config, &mut |_, _, _| {}).unwrap();
    skincal::ingest::motion::record_of(&mut ingested, &config, &mut |_, _, _| {}).unwrap();
    let set = &ingested.measurements;
    let t = set.training.as_ref().expect("the pose is kept");
    assert_eq!(t.poses.len(), 1);
    let pose = &t.poses[0];
    let slides = robot.model.prismatic_dof_names();
    let (mut worst, mut slide_peak) = (0.0f64, 0.0f64);
    for (dof, readings) in &pose.dynamic {
        let d = robot.model.dof_index(dof).unwrap();
        let truth = skincal::model::sensor::peak_dynamic_accelerations(
            &robot.model,
            &robot.parameters,
            &pose.q,
            d,
            &t.pattern,
        );
        for ((name, r), e) in set.sus.iter().zip(readings).zip(&truth) {
            assert_eq!(
                robot.model.su_index(name),
                set.sus.iter().position(|s| s == name)
            );
            let r = nalgebra::Vector3::from(*r);
            worst = worst.max((r - e).amax());
            if slides.contains(dof) {
                slide_peak = slide_peak.max(r.norm());
            }
        }
    }
    eprintln!("largest error {worst:.2e} m/s²; a slide's largest reading {slide_peak:.3} m/s²");
    // The one-period windows of the short protocol leave 1.4e-3 m/s² of the stamps' resolution.
    assert!(worst < 2e-3, "{worst}");
    assert!(slide_peak > 0.1 && slide_peak < 0.2 * t.pattern.peak_acceleration());
}

/// The paper's arm on a linear axis (tilted 17° from horizontal, ±0.3 m) whose carriage carries
/// two SUs, and the same robot with that axis revolute.
pub(crate) fn arm_on_a_rail(kind: &str) -> Robot {
    let preset = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("presets/paper-7dof.toml");
    let text = std::fs::read_to_string(preset).unwrap().replacen(
        "[[dofs]]\nname = \"dof1\"\n",
        &format!(
            "[[dofs]]\nname = \"rail\"\nchild = \"carriage\"\nkind = \"{kind}\"\n\
             origin = {{ xyz = [0.1, 0.0, 0.2], rpy = [0.0, 0.0, 0.0] }}\naxis = [1.0, 0.0, 0.3]\n\
             lower = -0.3\nupper = 0.3\nvelocity = 0.5\nacceleration = 3.0\n\n\
             [[dofs]]\nname = \"dof1\"\n"
        ),
        1,
    ) + "\n[[sus]]\nname = \"carriage_su1\"\nsegment = \"carriage\"\nxyz = [0.05, 0.03, 0.02]\nrpy = [0.3, -0.2, 1.0]\n\
         \n[[sus]]\nname = \"carriage_su2\"\nsegment = \"carriage\"\nxyz = [-0.04, 0.06, 0.01]\nrpy = [2.0, 0.4, -0.5]\n";
    let dir = tempfile::tempdir().unwrap();
    let file = dir.path().join(format!("rail-{kind}.toml"));
    std::fs::write(&file, text).unwrap();
    load_robot(file.to_str().unwrap(), SuPlacement::default()).unwrap()
}

#[test]
fn a_linear_axis_under_an_arm_is_calibrated_as_well_as_a_revolute_one() {
    let sliding = arm_on_a_rail("prismatic");
    let turning = arm_on_a_rail("revolute");
    assert_eq!(sliding.model.dofs()[0].kind, DofKind::Prismatic);
    assert_eq!(turning.model.dofs()[0].kind, DofKind::Revolute);
    // Each robot's own URDF is its description exported (a prismatic or a continuous rail).
    let mean = |robot: &Robot, what: &str| {
        let urdf = skincal::model::urdf::to_urdf(robot).unwrap();
        let errors: Vec<(f64, f64)> = (1..=3)
            .map(|seed| calibrated_error(robot, &urdf, seed, what))
            .collect();
        let n = errors.len() as f64;
        (
            errors.iter().map(|e| e.0).sum::<f64>() / n,
            errors.iter().map(|e| e.1).sum::<f64>() / n,
        )
    };
    let (ps, pd) = mean(&sliding, "arm on a prismatic rail");
    let (rs, rd) = mean(&turning, "arm on a revolute rail");
    assert!(
        ps <= 1.2 * rs && pd <= 1.2 * rd,
        "prismatic {ps:.4} / {pd:.4} against revolute {rs:.4} / {rd:.4} m/s²"
    );
}

#[test]
fn fingers_without_skin_are_listed_and_left_out() {
    let robot = load_robot(
        description("panda_description/urdf/panda.urdf")
            .to_str()
            .unwrap(),
        SuPlacement {
            per_link: Some(2),
            seed: 2,
        },
    )
    .unwrap();
    let mut builder = robot.to_builder();
    builder.sus.retain(|s| !s.segment.contains("finger"));
    let robot = builder.build().unwrap();
    let set = simulate(
        &robot,
        &SimulationConfig {
            seed: 2,
            ..SimulationConfig::default()
        },
    )
    .unwrap()
    .measurements;
    let structure = explore(&set, &ExploreConfig::default()).unwrap();
    let mut unseen: Vec<&str> = structure
        .diagnostics
        .iter()
        .filter(|d| d.kind == DiagnosticKind::DofMovesNoSu)
        .inspect(|d| assert_eq!(d.severity, Severity::Warning, "{}", d.message))
        .flat_map(|d| d.dofs.iter().map(String::as_str))
        .collect();
    unseen.sort();
    // The second finger is a mimic joint of the first: it moves with it, and is left out with it.
    assert_eq!(unseen, ["panda_finger_joint1"]);
    let mut left_out = structure.unplaced_dofs.clone();
    left_out.sort();
    assert_eq!(left_out, ["panda_finger_joint1", "panda_finger_joint2"]);
    assert!(structure
        .diagnostics
        .iter()
        .all(|d| d.severity != Severity::Error));
    let model = calibrate_body(&set, Some(&structure), &MlConfig::default(), None).unwrap();
    let calibrated: Vec<&String> = model.limbs.iter().flat_map(|l| &l.dofs).collect();
    assert_eq!(calibrated.len(), 7, "{calibrated:?}");
}

/// The arm on its prismatic rail through a short program, logged at 1 kHz (±0.01 g skin, the
/// tilted structure part too) and ingested with the rail named prismatic (as `ingest --robot`
/// does): the tree is exact, and both the windows' readings and every sample of the log
/// calibrate it to the noise-free held-out poses within 0.05 m/s².
#[test]
fn a_linear_axis_is_calibrated_from_its_logs() {
    use skincal::ingest::IngestConfig;

    let robot = arm_on_a_rail("prismatic");
    let plan = crate::common::short_plan(&robot, 8, 3);
    assert_eq!(plan.prismatic_dof_names(), ["rail"]);
    let dir = tempfile::tempdir().unwrap();
    let config = IngestConfig {
        prismatic: Some(robot.model.prismatic_dof_names()),
        ..IngestConfig::default()
    };
    let (ingested, upright) =
        crate::common::logged_and_ingested(&robot, &plan, &config, dir.path());
    let set = ingested.measurements;
    assert_eq!(set.prismatic, ["rail"]);
    // The rail's readings answer its pattern scaled to m (the set's convention): within their
    // deviations of the truth. (They were read against the unscaled pattern, ten times too
    // large: 21 deviations off.)
    let t = set.training.as_ref().unwrap();
    let rail = robot.model.dof_index("rail").unwrap();
    let (mut squares, mut n) = (0.0, 0.0);
    for pose in &t.poses {
        let truth = skincal::model::sensor::peak_dynamic_accelerations(
            &robot.model,
            &robot.parameters,
            &pose.q,
            rail,
            &t.pattern,
        );
        let readings = pose.dynamic["rail"].iter().zip(&pose.dynamic_sd["rail"]);
        for ((r, sd), e) in readings.zip(&truth) {
            squares += (nalgebra::Vector3::from(*r) - e).norm_squared() / (3.0 * sd * sd);
            n += 1.0;
        }
    }
    let z = (squares / n).sqrt();
    eprintln!("the rail's readings: {z:.2} deviations RMS off the truth");
    assert!(z < 1.6, "{z}");
    let structure = explore(&set, &ExploreConfig::default()).unwrap();
    assert!(structure.complete, "{:?}", structure.diagnostics);
    assert!(tree_is_exact(&robot, &structure));
    crate::common::logs_calibrate(&robot, (&set, &structure), &upright, &config, "rail");
}

/// The arm on its prismatic rail logged as above but ingested as `skincal ingest` does with no
/// description (`--robot`, `--plan`): no DoF is named prismatic, and each DoF's kind is told
/// from what its structure moves did to the skin. The rail is told prismatic (its carriage's
/// two SUs read its axis, a unit vector per m/s², and the arm's every SU the same axis), every
/// arm DoF revolute (the vertical first one from its lever arms and centripetal terms), so the
/// set is the one ingested with the kinds given, and calibrates as it does.
#[test]
fn a_linear_axis_is_told_from_its_moves_where_no_description_names_it() {
    use skincal::ingest::IngestConfig;

    let robot = arm_on_a_rail("prismatic");
    let plan = crate::common::short_plan(&robot, 8, 3);
    let dir = tempfile::tempdir().unwrap();
    let read = |config: &IngestConfig, name: &str| {
        let dir = dir.path().join(name);
        std::fs::create_dir(&dir).unwrap();
        let (mut ingested, upright) =
            crate::common::logged_and_ingested(&robot, &plan, config, &dir);
        skincal::ingest::motion::record_of(&mut ingested, config, &mut |_, _, _| {}).unwrap();
        (ingested, upright)
    };
    let untold = IngestConfig::default();
    assert_eq!(untold.prismatic, None);
    let (told, upright) = read(&untold, "untold");
    for kind in &told.report.kinds {
        eprintln!("{}: {:?}, {}", kind.dof, kind.kind, kind.evidence);
        let truth = robot.model.dofs()[robot.model.dof_index(&kind.dof).unwrap()].kind;
        assert_eq!(kind.kind, Some(truth), "{kind:?}");
    }
    assert_eq!(told.report.kinds.len(), robot.model.dofs().len());
    assert!(
        told.report
            .warnings
            .iter()
            .all(|w| !w.contains("slide or turn")),
        "{:?}",
        told.report.warnings
    );
    let given = IngestConfig {
        prismatic: Some(robot.model.prismatic_dof_names()),
        ..IngestConfig::default()
    };
    let (named, _) = read(&given, "named");
    assert!(named.report.kinds.is_empty());
    // The same set but for the logs' directory its sources name.
    let text = |set: &skincal::measurements::MeasurementSet, dir: &str| {
        serde_json::to_string(set).unwrap().replace(dir, "logs")
    };
    assert_eq!(
        text(&told.measurements, "untold"),
        text(&named.measurements, "named")
    );
    let set = told.measurements;
    let structure = explore(&set, &ExploreConfig::default()).unwrap();
    assert!(tree_is_exact(&robot, &structure));
    crate::common::logs_calibrate(&robot, (&set, &structure), &upright, &untold, "told rail");
}

/// `export-urdf --into` the stock Panda: each SU on a finger is put on its finger link where the
/// simulated robot has it, read back from the merged file by URDF import (every link's frame at
/// the zero pose, against the truth's forward kinematics there): a slide's line is not measured,
/// so its segment keeps the hand's alignment instead of being shifted onto it.
#[test]
fn finger_sus_merged_into_the_stock_urdf_sit_where_the_truth_has_them() {
    use skincal::align::{align, merge_sus};
    use skincal::model::forward_kinematics;
    use skincal::model::urdf::UrdfTree;
    let file = description("panda_description/urdf/panda.urdf");
    let urdf = std::fs::read_to_string(&file).unwrap();
    for seed in 1..=3 {
        let (robot, set, structure, _) = simulated(&file, seed);
        let model = calibrate_body(&set, Some(&structure), &MlConfig::default(), None).unwrap();
        let alignment = align(&model, &urdf).unwrap();
        let merged = UrdfTree::parse(&merge_sus(&alignment, &urdf, "", false).unwrap()).unwrap();
        let m = &robot.model;
        let truth = forward_kinematics(m, &robot.parameters, &vec![0.0; m.dofs().len()]);
        let mut fingers = 0;
        for (u, su) in m.sus().iter().enumerate() {
            // The right finger follows the left one (a mimic joint): its SUs are set aside.
            if !m.segments()[su.segment].name.contains("leftfinger") {
                assert!(
                    !m.segments()[su.segment].name.contains("rightfinger")
                        || !merged.frames.contains_key(&su.name)
                );
                continue;
            }
            fingers += 1;
            let placed = merged.frames[&su.name];
            let position = (placed.translation.vector - truth.sus[u].translation.vector).norm();
            let angle = placed
                .rotation
                .angle_to(&truth.sus[u].rotation)
                .to_degrees();
            eprintln!(
                "seed {seed}, {}: {:.2} mm, {angle:.2}°",
                su.name,
                position * 1e3
            );
            assert!(
                position < 0.01 && angle < 2.0,
                "seed {seed}, {}: {:.1} mm, {angle:.2}° from the truth",
                su.name,
                position * 1e3
            );
        }
        assert_eq!(fingers, 2);
    }
}

/// A program's forecast on an arm on a linear axis is as good as on the same arm with that axis
/// revolute (whose acceleration limit binds the pattern: a pattern chosen at a limit must pass
/// that limit's check when the forecast gives it back), and every limb's fit ends at the noise: the slide is fitted as a slide (the
/// forecast's readings once went to a set that called every DoF revolute, and the hinge fitted
/// to the slide ended at 15 σ, 2.5 m/s² off on the rail's readings; on TIAGo, whose torso lifts,
/// every limb did, and each draw ran the wider search: minutes per forecast).
#[test]
fn a_forecast_fits_a_slide_as_a_slide() {
    use skincal::design::{forecast, reading_noise, Reference};
    use skincal::plan::{Plan, PlanConfig, PlanDof};
    let forecast_of = |kind: &str| {
        let robot = arm_on_a_rail(kind);
        let plan = Plan::new(
            PlanDof::from_robot(&robot),
            &PlanConfig {
                poses: 12,
                ..PlanConfig::short()
            },
        )
        .unwrap();
        let noise = reading_noise(&robot, &plan, None).unwrap();
        let f = forecast(&robot, &Reference::of(&robot).unwrap(), &plan, &noise, 4).unwrap();
        eprintln!(
            "{kind} rail: forecast static {:.4}, dynamic {:.4} m/s²; off the noise: {:?}",
            f.static_rms, f.dynamic_rms, f.off_noise
        );
        assert!(f.off_noise.is_empty(), "{kind}: {:?}", f.off_noise);
        f
    };
    let (sliding, turning) = (forecast_of("prismatic"), forecast_of("revolute"));
    // (The draws scatter by some 15 %; the hinge fitted to the slide was 6× and 80× off.)
    assert!(
        sliding.static_rms <= 1.35 * turning.static_rms
            && sliding.dynamic_rms <= 1.35 * turning.dynamic_rms,
        "prismatic {:.4} / {:.4} against revolute {:.4} / {:.4} m/s²",
        sliding.static_rms,
        sliding.dynamic_rms,
        turning.static_rms,
        turning.dynamic_rms
    );
}
