//! Helpers shared by the tests: an independent implementation of the paper's matrices.

use nalgebra::Matrix4;

/// The paper's eq. 5, written out entry by entry (not via the library's transforms).
pub fn dh_matrix(theta: f64, d: f64, a: f64, alpha: f64) -> Matrix4<f64> {
    let (st, ct) = theta.sin_cos();
    let (sa, ca) = alpha.sin_cos();
    Matrix4::new(
        ct,
        -st * ca,
        st * sa,
        a * ct, //
        st,
        ct * ca,
        -ct * sa,
        a * st, //
        0.0,
        sa,
        ca,
        d, //
        0.0,
        0.0,
        0.0,
        1.0,
    )
}

/// The paper's eq. 7, written out.
pub fn sensor_matrix(theta_acc: f64, d_acc: f64) -> Matrix4<f64> {
    let (s, c) = theta_acc.sin_cos();
    Matrix4::new(
        c, -s, 0.0, 0.0, //
        s, c, 0.0, 0.0, //
        0.0, 0.0, 1.0, d_acc, //
        0.0, 0.0, 0.0, 1.0,
    )
}

/// Path of a file in `tests/fixtures`.
pub fn fixture(name: &str) -> std::path::PathBuf {
    std::path::Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("tests/fixtures")
        .join(name)
}

/// A held-out set of `robot`: training poses drawn from `seed`, no structure experiment, no noise
/// or other imperfection (what a calibration should predict exactly).
pub fn held_out(robot: &skincal::model::Robot, seed: u64) -> skincal::measurements::MeasurementSet {
    use skincal::sim::{simulate, Imperfections, SimulationConfig};
    simulate(
        robot,
        &SimulationConfig {
            seed,
            structure: false,
            imperfections: Imperfections::none(),
            ..SimulationConfig::default()
        },
    )
    .unwrap()
    .measurements
}

/// `robot` simulated with `config`, explored (the tree must be complete) and calibrated by
/// maximum likelihood with the default settings.
pub fn calibrated(
    robot: &skincal::model::Robot,
    config: &skincal::sim::SimulationConfig,
) -> skincal::estimate::body::BodyModel {
    use skincal::explore::{explore, ExploreConfig};
    let set = skincal::sim::simulate(robot, config).unwrap().measurements;
    let structure = explore(&set, &ExploreConfig::default()).unwrap();
    assert!(structure.complete, "{:?}", structure.diagnostics);
    skincal::estimate::body::calibrate_body(
        &set,
        Some(&structure),
        &skincal::estimate::ml::MlConfig::default(),
        None,
    )
    .unwrap()
}

/// `set` with the tree `structure` calibrated on every sample of `record` with `config`.
pub fn on_motion(
    set: &skincal::measurements::MeasurementSet,
    record: &skincal::motion::MotionRecord,
    structure: &skincal::explore::Structure,
    config: &skincal::estimate::ml::MlConfig,
) -> skincal::estimate::body::BodyModel {
    skincal::estimate::body::calibrate_body_on_motion(
        set,
        record,
        Some(structure),
        config,
        None,
        &[],
        &mut |_, _, _| {},
    )
    .unwrap()
}

/// `set` explored (the tree must be complete) and calibrated on every sample of `record` with
/// the default settings; every limb must converge below `max_ratio` times its noise.
pub fn calibrated_on_motion(
    set: &skincal::measurements::MeasurementSet,
    record: &skincal::motion::MotionRecord,
    max_ratio: f64,
) -> skincal::estimate::body::BodyModel {
    use skincal::explore::{explore, ExploreConfig};
    let structure = explore(set, &ExploreConfig::default()).unwrap();
    assert!(structure.complete, "{:?}", structure.diagnostics);
    let model = on_motion(
        set,
        record,
        &structure,
        &skincal::estimate::ml::MlConfig::default(),
    );
    for limb in &model.limbs {
        let e = &limb.estimate;
        assert!(
            e.converged && e.residual_ratio < max_ratio,
            "{}: {}",
            limb.name,
            e.residual_ratio
        );
    }
    model
}

/// `robot` through `plan` logged at 1 kHz into `dir` (±0.01 g skin, the structure part again
/// with the base tilted) and ingested with `config`: what ingest found, and the upright log.
pub fn logged_and_ingested(
    robot: &skincal::model::Robot,
    plan: &skincal::plan::Plan,
    config: &skincal::ingest::IngestConfig,
    dir: &std::path::Path,
) -> (skincal::ingest::Ingested, std::path::PathBuf) {
    use skincal::log::mcap::{Compression, McapSink};
    use skincal::log::Topics;
    use skincal::sim::timeseries::{record, LogConfig};
    let log = |name: &str, config: &LogConfig| {
        let path = dir.join(name);
        let mut sink = McapSink::new(&path, Topics::default(), Compression::Zstd, false);
        record(robot, plan, config, &mut sink, &mut |_| {}).unwrap();
        path
    };
    let upright = log("upright.mcap", &LogConfig::default());
    let tilted = log(
        "tilted.mcap",
        &LogConfig {
            part: Some(skincal::plan::Part::Structure),
            orientation: skincal::sim::BaseOrientation::tilted(),
            seed: 6,
            ..LogConfig::default()
        },
    );
    let ingested =
        skincal::ingest::ingest(&[upright.clone(), tilted], config, &mut |_, _, _| {}).unwrap();
    (ingested, upright)
}

/// `set` (ingested from `log` with `config`) calibrated on `structure` from the windows'
/// readings and from every sample of `log`: both predict 20 fresh noise-free poses of `robot`
/// (seed 99) within 0.05 m/s² RMS, static and dynamic (printed under `what`).
pub fn logs_calibrate(
    robot: &skincal::model::Robot,
    (set, structure): (
        &skincal::measurements::MeasurementSet,
        &skincal::explore::Structure,
    ),
    log: &std::path::Path,
    config: &skincal::ingest::IngestConfig,
    what: &str,
) {
    use skincal::estimate::body::{calibrate_body, calibrate_body_on_motion};
    let ml = skincal::estimate::ml::MlConfig::default();
    let windows = calibrate_body(set, Some(structure), &ml, None).unwrap();
    let record = skincal::ingest::motion::motion_record(
        &[log.to_path_buf()],
        &set.dofs,
        &set.sus,
        config,
        &mut |_, _, _| {},
    )
    .unwrap();
    let samples = calibrate_body_on_motion(
        set,
        &record,
        Some(structure),
        &ml,
        None,
        &[],
        &mut |_, _, _| {},
    )
    .unwrap();
    let held_out = held_out(robot, 99);
    for (how, model) in [("windows", &windows), ("every sample", &samples)] {
        let check = skincal::predict::validate(model, &held_out, "held-out").unwrap();
        eprintln!(
            "{what} from its logs, {how}: held-out static {:.4}, dynamic {:.4} m/s²",
            check.static_rms, check.dynamic_rms
        );
        assert!(
            check.static_rms <= 0.05 && check.dynamic_rms <= 0.05,
            "{what}, {how}: {:.4} / {:.4}",
            check.static_rms,
            check.dynamic_rms
        );
    }
}

/// The Python that runs the scripts of `tests/python` (`cargo xtask test` makes it and sets
/// `SKINCAL_TEST_PYTHON`).
pub fn test_python() -> std::ffi::OsString {
    std::env::var_os("SKINCAL_TEST_PYTHON").unwrap_or_else(|| "python3".into())
}

/// Runs `tests/python/<script>` with `args` and returns what it printed; a failure shows what it
/// said.
pub fn run_python(script: &str, args: &[&std::path::Path]) -> Vec<u8> {
    let path = std::path::Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("../../tests/python")
        .join(script);
    let out = std::process::Command::new(test_python())
        .arg(&path)
        .args(args)
        .output()
        .expect("run the tests with `cargo xtask test`, which makes the Python environment");
    assert!(
        out.status.success(),
        "{script}: {}",
        String::from_utf8_lossy(&out.stderr)
    );
    out.stdout
}

/// `plan`'s short program of `poses` training poses for `robot`, drawn with `seed`.
pub fn short_plan(robot: &skincal::model::Robot, poses: usize, seed: u64) -> skincal::plan::Plan {
    use skincal::plan::{Plan, PlanConfig, PlanDof};
    Plan::new(
        PlanDof::from_robot(robot),
        &PlanConfig {
            poses,
            seed,
            ..PlanConfig::short()
        },
    )
    .unwrap()
}
