//! Ingestion of a log that skincal did not simulate: an independent rigid-body simulation
//! (MuJoCo, `tests/python/physics_log.py`) of the 7-DoF arm with compliant position servos
//! (6 Hz bandwidth, damping 0.8), so that every excitation deflects the other DoFs and every stop
//! rings; the paper's pattern without a window (the acceleration steps at both ends) and 0.5 s
//! pauses; accelerometer noise and 10-bit quantisation; 17-bit encoders. With default options the
//! ingested readings must match the noise-free kinematic truth at the measured poses, and
//! calibrate as well as the condensed simulator's data.

use std::path::{Path, PathBuf};
use std::process::Command;

use nalgebra::Vector3;
use skincal::estimate::body::{calibrate_body, calibrate_body_on_motion};
use skincal::estimate::ml::{IntrinsicsModel, MlConfig};
use skincal::explore::{explore, ExploreConfig};
use skincal::ingest::motion::motion_record;
use skincal::ingest::{ingest, IngestConfig};
use skincal::measurements::MeasurementSet;
use skincal::model::description::RobotFile;
use skincal::model::sensor::{peak_dynamic_accelerations, static_readings};
use skincal::model::{presets, DofKind, Robot};
use skincal::plan::{Plan, PlanConfig, PlanDof};
use skincal::predict::validate;
use skincal::sim::BaseOrientation;

/// Runs the physics simulation into `out` (a CSV log directory).
fn physics_log(robot: &Path, plan: &Path, out: &Path, extra: &[&str]) {
    let script = Path::new(env!("CARGO_MANIFEST_DIR")).join("../../tests/python/physics_log.py");
    let interpreter = crate::common::test_python();
    let output = Command::new(&interpreter)
        .arg(&script)
        .arg(robot)
        .arg(plan)
        .arg(out)
        .args(extra)
        .arg("--raw")
        .output()
        .unwrap_or_else(|e| {
            panic!("cannot run {interpreter:?} ({e}): run the tests with `cargo xtask test`")
        });
    let stderr = String::from_utf8_lossy(&output.stderr);
    assert!(
        !stderr.contains("ModuleNotFoundError"),
        "the physics test needs MuJoCo's Python package (tests/python/requirements.txt): run the \
         tests with `cargo xtask test`, which installs it into target/test-env\n{stderr}"
    );
    assert!(output.status.success(), "{stderr}");
    write_csv_log(out);
}

/// `v` with `decimals` digits after the point, as C's `%.*f` prints it (to the last digit's
/// rounding of the product `v · 10^decimals`), appended to `s`: the logs hold tens of millions of
/// numbers, which the standard library's exact formatting takes seconds over.
fn fixed(s: &mut String, v: f64, decimals: u32) {
    use std::fmt::Write;
    let scale = 10u64.pow(decimals);
    let n = (v.abs() * scale as f64).round() as u64;
    if v < 0.0 && n != 0 {
        s.push('-');
    }
    write!(
        s,
        "{}.{:0width$}",
        n / scale,
        n % scale,
        width = decimals as usize
    )
    .unwrap();
}

/// The log's numbers read as the standard library prints them, to the last digit.
#[test]
fn the_logs_numbers_are_printed_as_the_standard_library_prints_them() {
    use rand::{Rng, SeedableRng};
    let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(3);
    for k in 0..100_000 {
        let v: f64 = match k % 3 {
            0 => rng.random_range(-20.0..20.0),
            1 => rng.random_range(-1e-5..1e-5),
            _ => rng.random_range(0.0..400.0),
        };
        for decimals in [6, 9] {
            let mut s = String::new();
            fixed(&mut s, v, decimals);
            let standard = format!("{v:.*}", decimals as usize);
            // Equal, or one in the last digit where the product rounded across a half.
            if s != standard {
                let [a, b] = [&s, &standard].map(|t| t.parse::<f64>().unwrap());
                assert!(
                    (a - b).abs() <= 1.01 * 10f64.powi(-(decimals as i32)),
                    "{s} {standard}"
                );
            }
        }
    }
}

/// The simulator's samples (`--raw`: little-endian doubles in `out`) written as skincal's CSV log
/// in `out`, as the simulator writes it without `--raw` (the same columns, `%.6f` stamps and
/// specific forces, `%.9f` joint positions), a sample's rows together; the raw files are removed.
fn write_csv_log(out: &Path) {
    #[derive(serde::Deserialize)]
    struct Raw {
        dofs: Vec<String>,
        sus: Vec<String>,
        start: f64,
        period: f64,
        samples: usize,
    }
    let raw: Raw =
        serde_json::from_str(&std::fs::read_to_string(out.join("raw.json")).unwrap()).unwrap();
    let doubles = |name: &str, per_sample: usize| -> Vec<f64> {
        let bytes = std::fs::read(out.join(name)).unwrap();
        assert_eq!(bytes.len(), raw.samples * per_sample * 8, "{name}");
        bytes
            .chunks_exact(8)
            .map(|b| f64::from_le_bytes(b.try_into().unwrap()))
            .collect()
    };
    let (dofs, sus) = (raw.dofs.len(), raw.sus.len());
    let (q, a) = (
        doubles("joint_states.f64", dofs),
        doubles("imu.f64", 3 * sus),
    );
    let stamp = |k: usize| raw.start + k as f64 * raw.period;
    let mut joints = format!("stamp,{}\n", raw.dofs.join(","));
    let mut imu = String::from("stamp,frame_id,ax,ay,az\n");
    let mut t = String::new();
    for k in 0..raw.samples {
        t.clear();
        fixed(&mut t, stamp(k), 6);
        joints.push_str(&t);
        for &v in &q[k * dofs..(k + 1) * dofs] {
            joints.push(',');
            fixed(&mut joints, v, 9);
        }
        joints.push('\n');
        for (s, name) in raw.sus.iter().enumerate() {
            imu.push_str(&t);
            imu.push(',');
            imu.push_str(name);
            for &v in &a[(k * sus + s) * 3..][..3] {
                imu.push(',');
                fixed(&mut imu, v, 6);
            }
            imu.push('\n');
        }
    }
    std::fs::write(out.join("joint_states.csv"), joints).unwrap();
    std::fs::write(out.join("imu.csv"), imu).unwrap();
    for name in ["raw.json", "joint_states.f64", "imu.f64"] {
        std::fs::remove_file(out.join(name)).unwrap();
    }
}

/// The physics simulator's options for position servos of `bandwidth` Hz at `damping`, tuned at
/// the largest inertia, with gravity compensation and ±0.01 g skin noise; then `extra`.
fn servos<'a>(bandwidth: &'a str, damping: &'a str, extra: &[&'a str]) -> Vec<&'a str> {
    let servo = [
        "--tune",
        "largest",
        "--gravcomp",
        "--bandwidth",
        bandwidth,
        "--damping",
        damping,
        "--noise",
        "0.0981",
    ];
    [&servo[..], extra].concat()
}

/// The physics logs of `robot` through the short program with 8 poses on servos of 6 Hz at
/// damping 0.8, reversed near the limits, with 13-bit encoders.
fn thirteen_bit_logs(robot: &Robot, dir: &Path) -> (PathBuf, PathBuf) {
    let plan = Plan::new(
        PlanDof::from_robot(robot),
        &PlanConfig {
            poses: 8,
            seed: 1,
            ..PlanConfig::short()
        },
    )
    .unwrap();
    let extra = ["--encoder-bits", "13", "--away-from-nearer-limit"];
    physics_logs(robot, &plan, dir, &servos("6", "0.8", &extra))
}

/// The physics simulation of `plan` on `robot` into `dir`: the whole plan upright (seed 1) and
/// its structure part tilted (seed 2), each with `extra` options; returns the two log directories.
fn physics_logs(robot: &Robot, plan: &Plan, dir: &Path, extra: &[&str]) -> (PathBuf, PathBuf) {
    let upright = upright_physics_log(robot, plan, dir, extra);
    let (robot_file, plan_file) = (dir.join("robot.json"), dir.join("plan.json"));
    let tilted = dir.join("tilted");
    let g = BaseOrientation::tilted().gravity;
    let gravity = format!("{},{},{}", g[0], g[1], g[2]);
    let tilt = ["--part", "structure", "--seed", "2", "--gravity", &gravity];
    physics_log(
        &robot_file,
        &plan_file,
        &tilted,
        &[&tilt[..], extra].concat(),
    );
    (upright, tilted)
}

/// The physics simulation of the whole of `plan` on `robot`, upright (seed 1), with `extra`
/// options, into `dir/upright` (beside the robot and plan files it reads); returns that log
/// directory.
fn upright_physics_log(robot: &Robot, plan: &Plan, dir: &Path, extra: &[&str]) -> PathBuf {
    let (robot_file, plan_file) = (dir.join("robot.json"), dir.join("plan.json"));
    std::fs::write(
        &robot_file,
        serde_json::to_string(&RobotFile::from_robot(robot, None)).unwrap(),
    )
    .unwrap();
    std::fs::write(&plan_file, serde_json::to_string(plan).unwrap()).unwrap();
    let upright = dir.join("upright");
    physics_log(
        &robot_file,
        &plan_file,
        &upright,
        &[&["--seed", "1"][..], extra].concat(),
    );
    upright
}

/// The calibrated `model`'s predictions against 30 noise-free held-out poses of `robot` (seed 77),
/// printed after `label`.
fn held_out_rms(
    model: &skincal::estimate::body::BodyModel,
    robot: &Robot,
    label: &str,
) -> skincal::predict::Validation {
    let v = validate(model, &crate::common::held_out(robot, 77), "held-out").unwrap();
    let residuals: Vec<String> = model
        .limbs
        .iter()
        .map(|l| format!("{:.3}", l.estimate.residual_ratio))
        .collect();
    eprintln!(
        "{label}held-out RMS static {:.4}, dynamic {:.4} m/s², residual {} σ",
        v.static_rms,
        v.dynamic_rms,
        residuals.join(", ")
    );
    v
}

/// The description at `path` (2 SUs per link) through the short program (6 poses, plan seed
/// `seed`) in the physics simulator with `options`, upright and its structure part tilted,
/// ingested with default options as `skincal ingest` does: the robot, the ingestion and its
/// motion record.
fn short_program_ingested(
    path: &str,
    seed: u64,
    options: &[&str],
) -> (
    Robot,
    skincal::ingest::Ingested,
    skincal::motion::MotionRecord,
) {
    let robot =
        crate::real_robots::with_two_sus_per_link(&crate::real_robots::description(path), 1);
    let (ingested, record) = short_program_of(&robot, seed, options);
    (robot, ingested, record)
}

/// `robot` through the short program (6 poses, plan seed `seed`) in the physics simulator with
/// `options`, upright and its structure part tilted, ingested with default options as `skincal
/// ingest` does: the ingestion and its motion record.
fn short_program_of(
    robot: &Robot,
    seed: u64,
    options: &[&str],
) -> (skincal::ingest::Ingested, skincal::motion::MotionRecord) {
    let plan = Plan::new(
        PlanDof::from_robot(robot),
        &PlanConfig {
            poses: 6,
            seed,
            ..PlanConfig::short()
        },
    )
    .unwrap();
    let dir = tempfile::tempdir().unwrap();
    let (upright, tilted) = physics_logs(robot, &plan, dir.path(), options);
    let config = IngestConfig::default();
    let mut ingested = ingest(&[upright, tilted], &config, &mut |_, _, _| {}).unwrap();
    // The motion record, and what the structure moves accelerated.
    let record = skincal::ingest::motion::record_of(&mut ingested, &config, &mut |_, _, _| {})
        .unwrap()
        .unwrap();
    (ingested, record)
}

/// The tree of `set` checked complete and with the activity matrix of the condensed simulation
/// of `robot` (independent kinematic data, the robot's own tree); every limb fitted on `record`
/// within 1.1 σ; the held-out RMS, printed after `label`.
fn exact_tree_and_held_out(
    robot: &Robot,
    set: &skincal::measurements::MeasurementSet,
    record: &skincal::motion::MotionRecord,
    label: &str,
) -> skincal::predict::Validation {
    let structure = explore(set, &ExploreConfig::default()).unwrap();
    assert!(structure.complete, "{:?}", structure.diagnostics);
    let condensed = skincal::sim::simulate(robot, &skincal::sim::SimulationConfig::default())
        .unwrap()
        .measurements;
    let truth = explore(&condensed, &ExploreConfig::default()).unwrap();
    assert_eq!(structure.matrix, truth.matrix);
    let model = crate::common::calibrated_on_motion(set, record, 1.1);
    held_out_rms(&model, robot, label)
}

/// Against the truth, static and dynamic: the RMS over the training poses of the norm of
/// (ingested − truth), m/s², and the RMS of each component's error in its reported standard
/// deviations.
fn errors(robot: &Robot, set: &MeasurementSet) -> ([f64; 2], [f64; 2]) {
    let t = set.training.as_ref().unwrap();
    let g = Vector3::new(0.0, 0.0, -9.81);
    let mut sums = [[0.0; 3]; 2];
    let mut add = |which: usize, r: &[f64; 3], e: &Vector3<f64>, sd: f64| {
        let error = Vector3::from(*r) - e;
        sums[which][0] += error.norm_squared();
        sums[which][1] += (error / sd).norm_squared() / 3.0;
        sums[which][2] += 1.0;
    };
    for pose in &t.poses {
        let truth = static_readings(&robot.model, &robot.parameters, &pose.q, &g);
        let sd = pose
            .static_sd
            .as_ref()
            .expect("ingest reports the uncertainty");
        for ((r, e), sd) in pose.static_readings.iter().zip(&truth).zip(sd) {
            add(0, r, e, *sd);
        }
        for (dof, readings) in &pose.dynamic {
            let k = set.dof_index(dof).unwrap();
            let truth =
                peak_dynamic_accelerations(&robot.model, &robot.parameters, &pose.q, k, &t.pattern);
            for ((r, e), sd) in readings.iter().zip(&truth).zip(&pose.dynamic_sd[dof]) {
                // A reading the tree sets to zero (a DoF excited together with the one that
                // moves the SU) is not a measurement: it is checked by the test, not counted.
                if *r != [0.0; 3] {
                    add(1, r, e, *sd);
                }
            }
        }
    }
    let rms = |k: usize, i: usize| (sums[k][i] / sums[k][2]).sqrt();
    ([rms(0, 0), rms(1, 0)], [rms(0, 1), rms(1, 1)])
}

/// The paper's arm on MuJoCo's servos (17-bit encoders, ±0.01 g), the short program of 8 poses,
/// upright and tilted, through the whole default path: ingest finds every excitation and move
/// where the plan put them, each reading within its reported deviation of the noise-free truth;
/// the readings calibrate at their own noise, and every sample of the log calibrates within
/// 0.005 m/s².
#[test]
fn a_compliant_robot_from_an_independent_physics_engine_ingests_with_default_options() {
    let robot = presets::find("paper-7dof").unwrap().robot().unwrap();
    let poses = 8;
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
    let (upright, tilted) = physics_logs(&robot, &plan, dir.path(), &[]);
    let mut ingested = ingest(
        &[upright, tilted],
        &IngestConfig::default(),
        &mut |_, _, _| {},
    )
    .unwrap();
    every_excitation_and_move_is_read(&ingested, poses);
    the_timeline_is_drawn(&ingested.report, poses);
    the_servos_coupled_the_dofs(&ingested.report);
    let (zs, zd) = readings_within_their_deviations(&robot, &ingested.measurements);
    readings_calibrate_at_their_own_noise(&robot, &ingested.measurements, (zs, zd));

    // The default path, every sample of the logs: 0.0004 / 0.0013 m/s² against the readings'
    // 0.0013 / 0.0134 (one dynamic reading per DoF and pose, each 0.03 m/s² off the truth,
    // against every sample of the holds, patterns and moves).
    let config = IngestConfig::default();
    let record = skincal::ingest::motion::record_of(&mut ingested, &config, &mut |_, _, _| {})
        .unwrap()
        .unwrap();
    let every = crate::common::calibrated_on_motion(&ingested.measurements, &record, 1.1);
    let v = held_out_rms(&every, &robot, "every sample: ");
    assert!(v.static_rms < 0.005 && v.dynamic_rms < 0.005, "{v:?}");
}

/// Every excitation of the `poses` training poses is read, no pose skipped, no warning, and each
/// orientation's structure part holds one move of every DoF, in order.
fn every_excitation_and_move_is_read(ingested: &skincal::ingest::Ingested, poses: usize) {
    let report = &ingested.report;
    let set = &ingested.measurements;
    set.validate().unwrap();
    assert!(report.warnings.is_empty(), "{:#?}", report.warnings);
    assert_eq!(
        report.logs[0].excitations,
        poses * 7,
        "{:#?}",
        report.logs[0]
    );
    assert!(
        report.logs[0].skipped.is_empty(),
        "{:?}",
        report.logs[0].skipped
    );
    assert_eq!(report.training_poses, poses);
    assert_eq!(report.dynamic, poses * 7);
    assert_eq!(report.orientations, 2);
    for o in &set.structure.as_ref().unwrap().orientations {
        let mut moved: Vec<&str> = o.moves.iter().map(|m| m.dof.as_str()).collect();
        moved.dedup();
        assert_eq!(moved, set.dofs, "one move of every DoF, in order");
    }
}

/// The timeline holds every excitation and move where it was, in order, and the report draws
/// each excitation of both logs.
fn the_timeline_is_drawn(report: &skincal::ingest::IngestReport, poses: usize) {
    let timeline = &report.logs[0].timeline;
    let count = |kind: &str| timeline.iter().filter(|s| s.kind == kind).count();
    assert_eq!(count("excitation"), poses * 7);
    assert_eq!(count("move"), 14);
    assert!(timeline.windows(2).all(|w| w[0].end <= w[1].start + 1e-9));
    let page = skincal::html::render(&skincal::html::ReportInputs {
        title: "physics".into(),
        ingest: Some(report.clone()),
        ..Default::default()
    });
    assert!(page.contains("<section id=\"timeline\""));
    assert_eq!(
        page.matches("<title>excitation of ").count(),
        count("excitation")
            + report.logs[1]
                .timeline
                .iter()
                .filter(|s| s.kind == "excitation")
                .count()
    );
}

/// The servos really coupled the DoFs: the proximal excitations moved the others.
fn the_servos_coupled_the_dofs(report: &skincal::ingest::IngestReport) {
    let fits = &report.logs[0].fits;
    let coupled = fits.iter().map(|f| f.coupled).fold(0.0, f64::max);
    eprintln!(
        "largest share of coupled motion in a window: {:.0} %",
        coupled * 100.0
    );
    assert!(coupled > 0.2, "{fits:#?}");
}

/// The readings against the noise-free truth: within 0.01 (static) and 0.05 m/s² (dynamic) RMS,
/// and their errors the size of their reported deviations — the static ones from the samples'
/// scatter, the dynamic ones from the same and the encoders' rounding through the fit (the terms
/// the model leaves out add a little). Returns the errors in deviations, static and dynamic.
fn readings_within_their_deviations(robot: &Robot, set: &MeasurementSet) -> (f64, f64) {
    let ([s, dynamic], [zs, zd]) = errors(robot, set);
    eprintln!(
        "against the noise-free truth: static {s:.4}, dynamic {dynamic:.4} m/s² RMS; \
         {zs:.2} and {zd:.2} standard deviations"
    );
    assert!(s <= 0.01, "static {s}");
    assert!(dynamic <= 0.05, "dynamic {dynamic}");
    assert!(
        (0.7..1.3).contains(&zs),
        "static errors are {zs} reported deviations"
    );
    assert!(
        (0.7..1.6).contains(&zd),
        "dynamic errors are {zd} reported deviations"
    );
    (zs, zd)
}

/// The tree is exact, and the readings' fit, weighted by the readings' own deviations, ends near
/// 1 of them; with the default noise setting of ±0.01 g instead, it would be far below it and
/// every reported standard deviation far too large. The dynamic readings' errors against the
/// truth are `zd` of their deviations (`readings_within_their_deviations`): where that is beyond
/// what the noise allows at this many readings, a fit to the truth is beyond the band too, and
/// must not be called converged.
fn readings_calibrate_at_their_own_noise(
    robot: &Robot,
    set: &MeasurementSet,
    (zs, zd): (f64, f64),
) {
    let structure = explore(set, &ExploreConfig::default()).unwrap();
    assert!(structure.complete, "{:?}", structure.diagnostics);
    let model = calibrate_body(set, Some(&structure), &MlConfig::default(), None).unwrap();
    for limb in &model.limbs {
        let ratio = limb.estimate.residual_ratio;
        let band = limb.estimate.residual_band.unwrap();
        eprintln!(
            "limb {}: residual {ratio:.2} σ, the noise's band {:.3} σ at {} degrees of freedom",
            limb.estimate.chain.name, band.upper, band.dof
        );
        assert!((0.7..1.4).contains(&ratio), "residual {ratio} σ");
        assert_eq!(
            limb.estimate.converged,
            zd.max(zs) < band.upper,
            "readings {zs:.2} / {zd:.2} σ off the truth, fit {ratio:.2} σ"
        );
    }
    let unweighted = calibrate_body(
        set,
        Some(&structure),
        &MlConfig {
            reading_sd: false,
            ..MlConfig::default()
        },
        None,
    )
    .unwrap();
    let ratio = unweighted.limbs[0].estimate.residual_ratio;
    eprintln!("with the default noise setting instead: residual {ratio:.2} σ");
    assert!(ratio < 0.5, "{ratio}");
    let v = held_out_rms(&model, robot, "");
    assert!(v.static_rms < 0.03 && v.dynamic_rms < 0.03, "{v:?}");
}

#[test]
fn limbs_excited_in_parallel_on_compliant_servos_are_told_apart() {
    // The humanoid's short program (limbs in parallel) in the physics engine: every stop rings and
    // every excitation deflects the limb's other DoFs, while the other limbs run their own pattern
    // at the same time. Each SU's readings must still match the truth of its own DoF alone. The
    // servos are tuned at each DoF's largest inertia over the plan's poses: tuned at the first
    // pose, the hip yaws (whose inertia grows tenfold when the leg is lifted) ring at 0.5 rad/s
    // for seconds, where no still window fits. These servos lag and ring for 0.25 s after a
    // structure move of a shoulder, which leaves too little of a 0.5 s still period for a static
    // reading: the still periods are 0.8 s (`plan --still 0.8`).
    let robot = presets::find("humanoid").unwrap().robot().unwrap();
    let poses = 3;
    let plan = Plan::new(
        PlanDof::from_robot(&robot),
        &PlanConfig {
            poses,
            still: 0.8,
            ..PlanConfig::short()
        },
    )
    .unwrap();
    let dir = tempfile::tempdir().unwrap();
    let (upright, tilted) = physics_logs(&robot, &plan, dir.path(), &["--tune", "largest"]);
    // The still windows fitted to the plan's still periods, as `ingest --plan` does.
    let config = IngestConfig::default().for_still_periods(plan.config.still);
    let ingested = ingest(&[upright, tilted], &config, &mut |_, _, _| {}).unwrap();
    let report = &ingested.report;
    assert!(report.warnings.is_empty(), "{:#?}", report.warnings);
    assert_eq!(report.logs[0].excitations, poses * 6, "6 windows per pose");
    assert_eq!(report.training_poses, poses);
    assert_eq!(report.dynamic, poses * 26);
    assert!(report.logs[0].fits.iter().any(|f| f.together.len() == 4));
    let ([s, dynamic], [zs, zd]) = errors(&robot, &ingested.measurements);
    eprintln!(
        "parallel limbs against the noise-free truth: static {s:.4}, dynamic {dynamic:.4} m/s² \
         RMS; {zs:.2} and {zd:.2} standard deviations"
    );
    assert!(s <= 0.01, "static {s}");
    assert!(dynamic <= 0.05, "dynamic {dynamic}");
    assert!(
        (0.7..1.3).contains(&zs),
        "static errors are {zs} reported deviations"
    );
    assert!(
        (0.7..1.6).contains(&zd),
        "dynamic errors are {zd} reported deviations"
    );
    // Every zero is where the true robot's DoF does not move the SU.
    let set = &ingested.measurements;
    for pose in &set.training.as_ref().unwrap().poses {
        for (dof, readings) in &pose.dynamic {
            let d = robot.model.dof_index(dof).unwrap();
            for (su, r) in set.sus.iter().zip(readings) {
                let moved = robot.model.moves_su(d, robot.model.su_index(su).unwrap());
                assert_eq!(*r == [0.0; 3], !moved, "{dof} on {su}");
            }
        }
    }
}

/// The Kinova arm's description with 2 SUs per link.
fn kinova() -> Robot {
    let file = crate::real_robots::description("kinova_description/robots/kinova.urdf");
    crate::real_robots::with_two_sus_per_link(&file, 1)
}

/// The Kinova arm's description (2 SUs per link) on softer servos than the paper's arm test: 6 Hz
/// at damping 0.5, tuned at the largest inertia, gravity compensated, the short program's 0.5 s
/// holds, and the servo options `extra`; with default options every excitation and move must be
/// found, the readings must match the truth and the calibration predict held-out poses.
fn kinova_on_soft_servos(extra: &[&str]) {
    let robot = kinova();
    let poses = 4;
    let limits = PlanDof::from_robot(&robot);
    let plan = Plan::new(
        limits.clone(),
        &PlanConfig {
            poses,
            seed: 1,
            ..PlanConfig::short()
        },
    )
    .unwrap();
    if extra.contains(&"--away-from-nearer-limit") {
        // Backwards from the poses in the upper half of a DoF's range.
        let backwards = plan
            .phases
            .iter()
            .filter_map(|p| match &p.action {
                skincal::plan::Action::Excitation { dof, .. } => Some((p, dof)),
                _ => None,
            })
            .filter(|(p, dof)| {
                let d = limits.iter().position(|l| &l.name == *dof).unwrap();
                limits[d].upper - p.from[d] < p.from[d] - limits[d].lower
            })
            .count();
        assert!(backwards >= 2, "{backwards} patterns run backwards");
    }
    let dir = tempfile::tempdir().unwrap();
    let servo = servos("6", "0.5", extra);
    let (upright, tilted) = physics_logs(&robot, &plan, dir.path(), &servo);
    let ingested = ingest(
        &[upright.clone(), tilted],
        &IngestConfig::default(),
        &mut |_, _, _| {},
    )
    .unwrap();
    let report = &ingested.report;
    let dofs = robot.model.dofs().len();
    assert!(report.warnings.is_empty(), "{:#?}", report.warnings);
    assert_eq!(report.logs[0].excitations, poses * dofs);
    assert_eq!(report.logs[0].moves, 2 * dofs);
    assert_eq!(report.logs[1].moves, 2 * dofs);
    assert_eq!(report.training_poses, poses);
    assert_eq!(report.dynamic, poses * dofs);
    assert_eq!(report.orientations, 2);
    let set = &ingested.measurements;
    let ([s, dynamic], [zs, zd]) = errors(&robot, set);
    eprintln!(
        "{extra:?}: against the noise-free truth static {s:.4}, dynamic {dynamic:.4} m/s² RMS; \
         {zs:.2} and {zd:.2} standard deviations"
    );
    assert!(s <= 0.01, "static {s}");
    assert!(dynamic <= 0.05, "dynamic {dynamic}");
    let structure = explore(set, &ExploreConfig::default()).unwrap();
    assert!(structure.complete, "{:?}", structure.diagnostics);
    let model = calibrate_body(set, Some(&structure), &MlConfig::default(), None).unwrap();
    for limb in &model.limbs {
        assert!(
            limb.estimate.converged,
            "{:?}",
            limb.estimate.residual_ratio
        );
    }
    let v = held_out_rms(&model, &robot, &format!("{extra:?}: "));
    assert!(v.static_rms < 0.05 && v.dynamic_rms < 0.05, "{v:?}");
    // Every sample of the upright log, from that fit: with these 4 poses 0.0040/0.0050 (1 s
    // pauses) and 0.0067/0.0045 m/s² (0.3 s) against the windows' 0.025/0.013 and 0.029/0.012.
    let record = motion_record(
        &[upright],
        &set.dofs,
        &set.sus,
        &IngestConfig::default(),
        &mut |_, _, _| {},
    )
    .unwrap();
    let config = MlConfig::default();
    let model = calibrate_body_on_motion(
        set,
        &record,
        Some(&structure),
        &config,
        None,
        &[],
        &mut |_, _, _| {},
    )
    .unwrap();
    for limb in &model.limbs {
        let e = &limb.estimate;
        assert!(e.converged, "{:?}", e.residual_ratio);
        let delay = e.motion.as_ref().unwrap().skin_delay;
        assert!(delay.abs() < 5e-4, "{delay} s");
    }
    let every = held_out_rms(&model, &robot, &format!("{extra:?}, every sample: "));
    assert!(
        every.static_rms < (v.static_rms / 2.5).min(0.01)
            && every.dynamic_rms < (v.dynamic_rms / 2.0).min(0.01),
        "{every:?} against {v:?}"
    );
}

#[test]
fn a_servo_that_lags_its_pattern_and_reverses_near_limits_ingests_with_default_options() {
    // The unwindowed pattern run away from the nearer limit (another protocol's habit), 1 s
    // pauses: the servo lags the pattern and ends it 5–20 mrad away before it settles. With the
    // old 0.002 rad rule for "came back", 13 of 24 excitations were found and 22 structure moves
    // reported in a log that has 12.
    kinova_on_soft_servos(&["--pause", "1.0", "--away-from-nearer-limit"]);
}

#[test]
fn excitations_whose_short_pauses_ring_through_are_read_one_by_one() {
    // 0.3 s pauses after each pattern: the servo rings through most of them, so that two
    // excitations in a row form one motion (they were read as excited together, and the pose
    // was lost), and the structure moves' 0.5 s holds leave still windows shorter than the
    // default 0.15 s.
    kinova_on_soft_servos(&["--pause", "0.3"]);
}

/// `robot`'s physics logs through `plan`'s continuous program (sweep 40, seed 1) on servos of
/// 6 Hz at damping 0.8 with `extra` options — upright, and with `tilted` its structure part
/// again with the base tilted — ingested with default options: what ingest found, and the
/// motion record of its training log (the upright one).
fn continuous_program_ingested(
    robot: &Robot,
    extra: &[&str],
    tilted: bool,
) -> (skincal::ingest::Ingested, skincal::motion::MotionRecord) {
    let plan = Plan::new(
        PlanDof::from_robot(robot),
        &PlanConfig {
            sweep: 40.0,
            seed: 1,
            ..PlanConfig::continuous()
        },
    )
    .unwrap();
    let dir = tempfile::tempdir().unwrap();
    let servo = servos("6", "0.8", extra);
    let logs = if tilted {
        let (upright, tilted) = physics_logs(robot, &plan, dir.path(), &servo);
        vec![upright, tilted]
    } else {
        vec![upright_physics_log(robot, &plan, dir.path(), &servo)]
    };
    let upright = logs[0].clone();
    let config = IngestConfig::default();
    let mut ingested = ingest(&logs, &config, &mut |_, _, _| {}).unwrap();
    let training = skincal::ingest::motion::training_logs(&ingested.report);
    assert_eq!(training, vec![upright]);
    let record = skincal::ingest::motion::record_of(&mut ingested, &config, &mut |_, _, _| {})
        .unwrap()
        .unwrap();
    // No description named the kinds: the servos' moves, ringing as they stop, tell each DoF a
    // turn (as `skincal ingest` does).
    let kinds = &ingested.report.kinds;
    assert_eq!(kinds.len(), robot.model.dofs().len());
    assert!(
        kinds.iter().all(|k| k.kind == Some(DofKind::Revolute)),
        "{kinds:?}"
    );
    (ingested, record)
}

/// Every limb of `model` kept ideal sensors (the data chose no intrinsics).
fn asks_for_no_intrinsics(model: &skincal::estimate::body::BodyModel) {
    for limb in &model.limbs {
        let e = &limb.estimate;
        assert_eq!(
            e.intrinsics_model,
            Some(IntrinsicsModel::None),
            "{}: {:?}",
            limb.name,
            e.intrinsics_tests
        );
    }
}

/// The Kinova arm's description (2 SUs per link, speed limits of 0.63 rad/s) through the
/// continuous program on the physics engine's servos (6 Hz, damping 0.8, gravity compensated),
/// recorded once, upright: the arm's vertical axes at its rest pose turn no gravity in their
/// structure moves, and `explore` reads what they move from what the moves accelerated on the
/// servos (no structure part with the base tilted); the 40 s sweep (nothing still, every DoF
/// moving) gives no reading, and from its motion alone every limb converges at the noise level
/// and predicts held-out poses within 0.005 static and dynamic.
#[test]
fn a_continuous_program_on_physical_servos_calibrates_from_its_motion() {
    let robot = kinova();
    let (ingested, record) = continuous_program_ingested(&robot, &[], false);
    let report = &ingested.report;
    assert_eq!(report.training_poses, 0);
    assert_eq!(report.orientations, 1);
    let structure = skincal::explore::explore(
        &ingested.measurements,
        &skincal::explore::ExploreConfig::default(),
    )
    .unwrap();
    assert!(
        structure
            .diagnostics
            .iter()
            .any(|d| d.kind == skincal::explore::DiagnosticKind::UprightAxis),
        "{:?}",
        structure.diagnostics
    );
    let set = &ingested.measurements;
    let model = crate::common::calibrated_on_motion(set, &record, 1.1);
    // The skin is ideal but for its noise and quantisation: the data must not ask for biases
    // (they were taken at z = 202 when the "none" they were tested against held the biases of the
    // quiet readings' fit, and cost the static prediction a fifth: 0.0039 against 0.0032).
    asks_for_no_intrinsics(&model);
    let v = held_out_rms(&model, &robot, "continuous program: ");
    assert!(v.static_rms < 0.005 && v.dynamic_rms < 0.005, "{v:?}");
}

/// The slow corner of the servo matrix: the Kinova arm on 3 Hz servos at damping 0.5 with 0.3 s
/// pauses after its patterns. The arm rings through most pauses into the next pattern, so ingest
/// reads the training poses' excitations as excited together or as transfers and keeps one pose of
/// four: too few for the readings' fit, which used to refuse the set. With default options the
/// structure part is still read right, and every limb starts from the motion record's quiet
/// moments and is fitted on every sample of the log, at the noise level.
#[test]
fn servos_too_slow_for_the_programs_pauses_calibrate_from_the_motion() {
    let robot = kinova();
    let plan = Plan::new(
        PlanDof::from_robot(&robot),
        &PlanConfig {
            poses: 4,
            seed: 1,
            ..PlanConfig::short()
        },
    )
    .unwrap();
    let dir = tempfile::tempdir().unwrap();
    let servo = servos("3", "0.5", &["--pause", "0.3"]);
    let (upright, tilted) = physics_logs(&robot, &plan, dir.path(), &servo);
    let config = IngestConfig::default();
    let ingested = ingest(&[upright.clone(), tilted], &config, &mut |_, _, _| {}).unwrap();
    let dofs = robot.model.dofs().len();
    assert_eq!(ingested.report.logs[0].moves, 2 * dofs);
    assert_eq!(ingested.report.logs[1].moves, 2 * dofs);
    let set = &ingested.measurements;
    assert!(
        skincal::estimate::body::starts_from_quiet(set),
        "{} training poses",
        skincal::estimate::body::training_poses(set)
    );
    let record =
        motion_record(&[upright], &set.dofs, &set.sus, &config, &mut |_, _, _| {}).unwrap();
    let model = crate::common::calibrated_on_motion(set, &record, 1.2);
    // 0.0044 / 0.0028 m/s² (read at 50 ms with the skin unfiltered: 0.0042 / 0.0056).
    let v = held_out_rms(&model, &robot, "3 Hz servos, 0.3 s pauses, every sample: ");
    assert!(v.static_rms < 0.01 && v.dynamic_rms < 0.01, "{v:?}");
}

/// A UR5 whose encoders count 13 bits a turn (0.77 mrad), on 6 Hz servos at damping 0.8, through
/// `plan`'s short program of 8 poses: the record reads the joints through a 160 ms polynomial,
/// and the fit ends at the noise level and predicts held-out poses within 0.005 m/s². The
/// rounding's share of each block's acceleration is that of a staircase: where a joint creeps
/// across a few counts, the readings within one count share their error. Taken as independent
/// per reading, it was stated 3–4 times too small there, and the fit ended at 1.49 σ (0.0024 /
/// 0.0048 m/s² held-out); with it, 1.01 σ (0.0018 / 0.0040); with the joint states fitted as
/// unknowns too (`coarse_encoders_joint_states_are_fitted_as_unknowns`) and the positions and
/// velocities read through the skin's kernel, 0.0018 / 0.0022 at 0.72 σ: a corrected
/// acceleration's uncertainty weighed the residual as well as held its correction. Weighed once,
/// 0.0014 / 0.0014 at 0.95 σ.
#[test]
fn thirteen_bit_encoders_calibrate_at_the_noise_level() {
    let file = crate::real_robots::description("ur_description/urdf/ur5_robot.urdf");
    let robot = crate::real_robots::with_two_sus_per_link(&file, 1);
    let dir = tempfile::tempdir().unwrap();
    let (upright, tilted) = thirteen_bit_logs(&robot, dir.path());
    let config = IngestConfig::default();
    let ingested = ingest(&[upright.clone(), tilted], &config, &mut |_, _, _| {}).unwrap();
    let set = &ingested.measurements;
    let record =
        motion_record(&[upright], &set.dofs, &set.sus, &config, &mut |_, _, _| {}).unwrap();
    assert_eq!(record.half_width, Some(0.16));
    let model = crate::common::calibrated_on_motion(set, &record, 1.1);
    let v = held_out_rms(&model, &robot, "13-bit encoders: ");
    assert!(v.static_rms < 0.005 && v.dynamic_rms < 0.005, "{v:?}");
    let residual = model.limbs[0].estimate.residual_ratio;
    assert!(residual > 0.9, "below the noise: {residual} σ");
}

/// The UR5 on 13-bit encoders through `plan`'s continuous program alone (no holds, no
/// patterns): the record is read through a 160 ms kernel and every fourth block is fitted, so
/// neighbouring samples share most of their noise and, weighed each alone, seem to hold 2.8 times
/// the information they do along a sensor's bias. The intrinsics' test divides by that: the clean
/// skin asks for no biases (taken at z = 5.5, F = 2.6, before), and the calibration predicts
/// held-out poses at the noise level.
#[test]
fn a_clean_skin_read_through_the_kernel_asks_for_no_intrinsics() {
    let file = crate::real_robots::description("ur_description/urdf/ur5_robot.urdf");
    let robot = crate::real_robots::with_two_sus_per_link(&file, 1);
    let (ingested, record) = continuous_program_ingested(&robot, &["--encoder-bits", "13"], true);
    let set = &ingested.measurements;
    assert_eq!(record.half_width, Some(0.16));
    let model = crate::common::calibrated_on_motion(set, &record, 1.1);
    asks_for_no_intrinsics(&model);
    for limb in &model.limbs {
        let bias = &limb.estimate.intrinsics_tests[0];
        eprintln!("{}: {bias:?}", limb.name);
        assert_eq!(bias.model, IntrinsicsModel::Bias);
        assert!(
            (2.5..3.2).contains(&bias.overcount) && bias.z.abs() < 3.0,
            "{bias:?}"
        );
    }
    let v = held_out_rms(&model, &robot, "13-bit encoders, continuous program: ");
    assert!(v.static_rms < 0.008 && v.dynamic_rms < 0.005, "{v:?}");
}

/// The Kinova arm's description (2 SUs per link) with 13-bit encoders, on servos of 6 Hz at
/// damping 0.8 tuned at the largest inertia, gravity compensated, through the short program (8
/// poses): a still joint is read only to within a count, and a creeping one's acceleration from
/// the staircase the polynomial bends to follow. Taken as read, the joint states put those errors
/// into the geometry; fitted as unknowns held at the encoders' readings (`MlConfig::joint_states`,
/// the default) the held-out error falls, static by half and dynamic by a fifth (0.0099 /
/// 0.0062 to 0.0050 / 0.0047 m/s²; exact encoders give 0.0008 / 0.0026), and the residual is the
/// noise's (0.97 σ; 0.78 σ while the corrected accelerations' uncertainty weighed it too). A still
/// joint's samples at one count share one correction: taken apart, each was held by the whole
/// rounding's prior against one sample's readings, and the static error fell only to 0.0068.
#[test]
fn coarse_encoders_joint_states_are_fitted_as_unknowns() {
    let robot = kinova();
    let dir = tempfile::tempdir().unwrap();
    let (upright, tilted) = thirteen_bit_logs(&robot, dir.path());
    let config = IngestConfig::default();
    let ingested = ingest(&[upright.clone(), tilted], &config, &mut |_, _, _| {}).unwrap();
    let set = &ingested.measurements;
    let structure = explore(set, &ExploreConfig::default()).unwrap();
    let record =
        motion_record(&[upright], &set.dofs, &set.sus, &config, &mut |_, _, _| {}).unwrap();
    let count = std::f64::consts::TAU / 8192.0;
    assert!(
        record
            .rounding
            .iter()
            .all(|r| (r * 12f64.sqrt() / count - 1.0).abs() < 1e-6),
        "every encoder's count is read: {:?}",
        record.rounding
    );
    let fit = |joint_states: bool, label: &str| {
        let ml = MlConfig {
            joint_states,
            ..MlConfig::default()
        };
        let model = crate::common::on_motion(set, &record, &structure, &ml);
        for limb in &model.limbs {
            let e = &limb.estimate;
            assert!(
                e.converged && e.residual_ratio > 0.9,
                "{label}{}",
                e.residual_ratio
            );
        }
        held_out_rms(&model, &robot, label)
    };
    let (read, fitted) = (fit(false, "joint states as read: "), fit(true, "fitted: "));
    assert!(
        fitted.static_rms < 0.6 * read.static_rms && fitted.dynamic_rms < 0.85 * read.dynamic_rms,
        "static {} vs {}, dynamic {} vs {}",
        fitted.static_rms,
        read.static_rms,
        fitted.dynamic_rms,
        read.dynamic_rms
    );
    assert!(
        fitted.static_rms < 0.0055 && fitted.dynamic_rms < 0.0055,
        "{fitted:?}"
    );
}

/// The paper's arm on a linear axis (tilted 17° from horizontal) on MuJoCo's servos (a slide
/// joint and seven hinges, 6 Hz at damping 0.8, gravity compensated) through the short program,
/// ingested with default options and no description: the rail's kind is told from what its
/// structure move did to the skin — every SU it carries read its axis, one per m/s², once the
/// accelerations of the arm's servos, deflected by the rail's reaction, are regressed out — and
/// every arm DoF's from the gravity its move turned. The logs are then read again with the rail
/// named: its patterns (4.7 mm at 0.042 m/s, a tenth of a turn's speed) were pauses to thresholds
/// in rad/s, and every training pose lacked the rail's excitation (the readings' fit then
/// started the time-domain fit in a minimum at 8.1 σ, 0.38 m/s² held-out). The tree is exact and
/// every sample of the log calibrates the arm on its rail at the noise level.
#[test]
fn a_linear_axis_on_physical_servos_is_told_prismatic_from_its_move() {
    let robot = crate::prismatic::arm_on_a_rail("prismatic");
    let plan = crate::common::short_plan(&robot, 8, 3);
    let dir = tempfile::tempdir().unwrap();
    let (upright, tilted) = physics_logs(&robot, &plan, dir.path(), &servos("6", "0.8", &[]));
    let config = IngestConfig::default();
    let mut ingested = ingest(&[upright, tilted], &config, &mut |_, _, _| {}).unwrap();
    assert_eq!(
        ingested.report.dynamic,
        7 * 8,
        "the rail's patterns are pauses at first"
    );
    let record = skincal::ingest::motion::record_of(&mut ingested, &config, &mut |_, _, _| {})
        .unwrap()
        .unwrap();
    assert_eq!(
        ingested.report.dynamic,
        8 * 8,
        "read again with the rail named"
    );
    for told in &ingested.report.kinds {
        eprintln!("{}: {:?}, {}", told.dof, told.kind, told.evidence);
        let truth = robot.model.dofs()[robot.model.dof_index(&told.dof).unwrap()].kind;
        assert_eq!(told.kind, Some(truth), "{told:?}");
    }
    assert_eq!(ingested.report.kinds.len(), robot.model.dofs().len());
    let rail = &ingested.report.kinds[0];
    assert!(
        rail.evidence.starts_with("9 SU(s) read its axis"),
        "{rail:?}"
    );
    let set = &ingested.measurements;
    assert_eq!(set.prismatic, ["rail"]);
    let structure = explore(set, &ExploreConfig::default()).unwrap();
    assert!(crate::real_robots::tree_is_exact(&robot, &structure));
    let model = crate::common::calibrated_on_motion(set, &record, 1.1);
    let v = held_out_rms(&model, &robot, "rail told from its move, every sample: ");
    assert!(v.static_rms < 0.005 && v.dynamic_rms < 0.005, "{v:?}");
}

/// A uFactory xArm 7 (a description no other test uses; 2 SUs per link) on soft servos — 4 Hz at
/// damping 0.6, tuned at the largest inertia — with 0.3 s pauses and 14-bit encoders, through
/// the short program, ingested, explored and calibrated with default options. Its first, third,
/// fifth and seventh axes stand vertical at the rest pose, so what they move is completed from
/// what their structure moves accelerated. Each move overshoots and rings: cut at its first
/// reversal, a move ended away from its pose and was not taken, or only a late swing of it was,
/// whose regression told the wrist's gains to within 3 cm (0.01–0.08 m on every SU, the base's
/// included): joint7 moved the whole arm, the tree was wrong, four SUs were set aside and the fit
/// ended at 16 σ. Read through its ringing, every move tells every SU's gain within 3 mm, the
/// tree is the simulator's and every sample calibrates the arm within 0.005 m/s² held-out.
#[test]
fn a_move_that_rings_is_read_to_where_it_settles() {
    let (robot, ingested, record) = short_program_ingested(
        "xarm_description/urdf/xarm7.urdf",
        3,
        &servos("4", "0.6", &["--pause", "0.3", "--encoder-bits", "14"]),
    );
    let set = &ingested.measurements;
    let moves = &set.structure.as_ref().unwrap().orientations[0].moves;
    for mv in moves {
        let sd = mv
            .accelerated_sd
            .iter()
            .flatten()
            .fold(0.0, |a: f64, &b| a.max(b));
        eprintln!(
            "{}: gains read {}, largest deviation {:.1} mm",
            mv.dof,
            !mv.accelerated.is_empty(),
            sd * 1e3
        );
        let upright = ["joint1", "joint3", "joint5", "joint7"].contains(&mv.dof.as_str());
        assert!(
            !upright || (!mv.accelerated.is_empty() && sd < 0.003),
            "{}: {:?} ± {:?}",
            mv.dof,
            mv.accelerated,
            mv.accelerated_sd
        );
    }
    let v = exact_tree_and_held_out(
        &robot,
        set,
        &record,
        "xArm 7 on 4 Hz servos, 14-bit encoders: ",
    );
    assert!(v.static_rms < 0.005 && v.dynamic_rms < 0.005, "{v:?}");
}

/// A hobby arm (SO-101) on servos of 5 Hz at damping 0.7 with 12-bit encoders (0.088°): at a
/// structure pose the gravity-loaded elbow and shoulder flicker by a count. The grid's first
/// second, where the robot stood still and no encoder changed, once gave every count as 0: no
/// flicker was allowed, three structure poses per log were "never still", and the tree lacked
/// both DoFs. The count is now kept up as the log is read.
#[test]
fn an_encoder_that_first_changes_after_the_first_second_may_flicker_at_a_pose() {
    let (robot, ingested, record) = short_program_ingested(
        "so_arm_description/urdf/so101.urdf",
        1,
        &servos("5", "0.7", &["--encoder-bits", "12"]),
    );
    let skipped: Vec<&String> = ingested
        .report
        .warnings
        .iter()
        .filter(|w| w.contains("never still"))
        .collect();
    assert!(skipped.is_empty(), "{skipped:#?}");
    let set = &ingested.measurements;
    let v = exact_tree_and_held_out(
        &robot,
        set,
        &record,
        "SO-101 on 5 Hz servos, 12-bit encoders: ",
    );
    assert!(v.static_rms < 0.005 && v.dynamic_rms < 0.005, "{v:?}");
}

/// A mobile manipulator (TIAGo: two wheels, and a lift that carries a 2-DoF head and a 7-DoF
/// arm; two SUs per link) on servos of 4 Hz at damping 0.6 with 14-bit encoders, ingested with
/// default options and no description. Its heavy arm's servos ring after each move and then
/// creep at 0.02 rad/s to the end of the hold, never below the still speed: those poses are read
/// where they crept least (a creep is no acceleration). Its lift turns no gravity, so only what
/// its 3 cm move accelerated tells which SUs it carries, and that it slides: the move's
/// excitation (Σq̈² 0.45) was below what a move had to excite to be read, and the lift was left
/// out of the tree, its bounce an unexplained misfit of every limb it carries. Known as a slide,
/// its pauses are judged at a tenth of a turn's speed, and the lift bouncing a few tenths of a
/// millimetre as the arm rang (6 mm/s) broke the arm's holds until a slide that stays within the
/// motion threshold counted as not moving. Its patterns (6.8 mm) run with the arm's first
/// joints (0.07 rad), and compared in their own units they were taken for the lift following
/// the arm. Before: no measurement set at all; now the tree is exact and every sample of the
/// log calibrates the robot at the noise level.
#[test]
fn a_mobile_manipulators_lift_on_soft_servos_is_told_a_slide_and_calibrated() {
    let file = crate::real_robots::description("tiago_description/robots/tiago_no_hand.urdf");
    let robot = crate::real_robots::with_two_sus_per_link(&file, 1);
    let options = servos("4", "0.6", &["--encoder-bits", "14"]);
    let (ingested, record) = short_program_of(&robot, 1, &options);
    let report = &ingested.report;
    let lift = report
        .kinds
        .iter()
        .find(|k| k.dof == "torso_lift_joint")
        .unwrap();
    assert_eq!(lift.kind, Some(DofKind::Prismatic), "{lift:?}");
    let set = &ingested.measurements;
    assert_eq!(set.prismatic, ["torso_lift_joint"]);
    let dofs = robot.model.dofs().len();
    assert_eq!(report.dynamic, report.training_poses * dofs, "{report:#?}");
    let crept: usize = report.logs.iter().map(|l| l.creeping).sum();
    eprintln!(
        "poses read creeping: {crept}; warnings {:#?}",
        report.warnings
    );
    let v = exact_tree_and_held_out(
        &robot,
        set,
        &record,
        "TIAGo on 4 Hz servos at damping 0.6, 14-bit encoders: ",
    );
    assert!(v.static_rms < 0.005 && v.dynamic_rms < 0.005, "{v:?}");
}
