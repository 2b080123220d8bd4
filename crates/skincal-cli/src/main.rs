//! `skincal`: self-calibration of skin-covered robots from their own accelerometers.
//!
//! A thin layer over the `skincal` library: parse the command line, call the library, print.

mod bench_body;
mod bench_check;
mod bench_limbs;
mod bench_motion;
mod bench_report;
mod bench_sensors;
mod check;
mod logs;
mod out;
mod render;
mod urdf;

use std::path::{Path, PathBuf};
use std::process::ExitCode;

use anyhow::{Context, Result};
use clap::{Args, Parser, Subcommand};
use out::{out, outln};
use skincal::estimate::paper::PaperConfig;
use skincal::estimate::{self, ChainData, SerialChain};
use skincal::explore::ExploreConfig;
use skincal::io::{self, SuPlacement};
use skincal::model::presets::PRESETS;
use skincal::model::sensor::ExcitationPattern;
use skincal::report;
use skincal::sim::{self, Imperfections, RandomTreeConfig, SimulationConfig};

const EXIT_CODES: &str = "\
Exit codes:
  0  success
  1  error: bad input (unknown robot, malformed file, impossible setting) or a file that cannot be
     read or written; the message names the file or field and what to do
  2  usage error: unknown command or option
  3  incomplete: the results were written, but part of them is missing or unreliable (explore:
     the tree has error-level diagnostics), or a check failed (check-urdf, and report --urdf: a
     joint of the URDF disagrees with the calibration); the message says which
  130 interrupted (Ctrl-C, SIGTERM, SIGHUP): half-written outputs were removed

No command overwrites an existing result unless --force is given (demo replaces only the
directory it made itself).";

/// Self-calibration of robots covered with artificial skin, from the skin's own accelerometers.
///
/// Units are SI throughout: m, rad, s, m/s² (noise levels are given in g = 9.81 m/s²).
#[derive(Debug, Parser)]
#[command(name = "skincal", version, after_help = EXIT_CODES)]
struct Cli {
    #[command(subcommand)]
    command: Command,
}

#[derive(Debug, Subcommand)]
enum Command {
    /// Run the whole job on a built-in robot and print what it found.
    #[command(after_help = EXIT_CODES)]
    Demo(DemoArgs),
    /// Simulate the structure and training experiments of a robot: writes DIR/measurements.json
    /// and DIR/truth.json.
    #[command(after_help = EXIT_CODES)]
    Simulate(SimulateArgs),
    /// List the built-in robots.
    #[command(after_help = EXIT_CODES)]
    Robots(RobotsArgs),
    /// Structural exploration: find segments, joints and limbs in DIR/measurements.json; writes
    /// DIR/structure.json and DIR/structure.dot.
    #[command(after_help = EXIT_CODES)]
    Explore(ExploreArgs),
    /// Kinematic estimation of every limb in DIR/measurements.json: writes the calibrated body to
    /// DIR/model.json (method ml) or the paper's chains to DIR/model-paper.json (method paper).
    #[command(after_help = EXIT_CODES)]
    Calibrate(CalibrateArgs),
    /// Write DIR/report.html: one self-contained page (activity matrix, kinematic tree, limbs with
    /// residual and uncertainty charts, held-out errors) from what DIR holds.
    #[command(after_help = EXIT_CODES)]
    Report(ReportArgs),
    /// Write a calibrated model as URDF, kinematics only: one link per segment, continuous joints
    /// named after the DoFs, one link per SU on a fixed joint; or, with --into, the SU frames
    /// added to the robot's own URDF.
    #[command(name = "export-urdf", after_help = EXIT_CODES)]
    ExportUrdf(urdf::ExportUrdfArgs),
    /// Check the robot's own URDF against a calibrated model: per joint, the angle and distance
    /// between its axis and the calibrated one, with their uncertainty and a verdict.
    #[command(name = "check-urdf", after_help = EXIT_CODES)]
    CheckUrdf(urdf::CheckUrdfArgs),
    /// Predict every SU's static and dynamic readings in given poses (JSON, measurement-set units).
    #[command(after_help = EXIT_CODES)]
    Predict(PredictArgs),
    /// Check a calibrated model against a second measurement set: prediction error per SU.
    #[command(after_help = EXIT_CODES)]
    Validate(ValidateArgs),
    /// Check that every SU still reads what a calibrated model predicts, from a log of any motion
    /// of the robot: per SU unchanged, moved (how far), bias changed, swapped, on another segment,
    /// broken, or not enough motion to tell; --recalibrate writes a model with what changed
    /// calibrated again (exit 3 when something changed).
    #[command(after_help = EXIT_CODES)]
    Check(check::CheckArgs),
    /// Measure speed on generated data and print a table (build with --release).
    #[command(subcommand)]
    Bench(BenchCommand),
    /// Write the exploration program for a real robot (structure moves, training poses with one
    /// excitation pattern per DoF) from its DoF limits: DIR/plan.json, trajectory.csv/.json.
    Plan(logs::PlanArgs),
    /// Execute a plan on a simulated robot and record its log (ROS 2 MCAP or CSV, 1 kHz).
    Record(logs::RecordArgs),
    /// Extract a measurement set from logs of joint states and skin samples (MCAP or CSV).
    Ingest(logs::IngestArgs),
}

/// Which accelerometer intrinsics `ml` estimates per SU.
#[derive(Debug, Clone, Copy, PartialEq, Eq, clap::ValueEnum)]
pub(crate) enum IntrinsicsArg {
    /// Chosen by the data for the whole skin: none, a bias, or a bias and a scale error, each
    /// taken only when it fits significantly better than the one before (the limbs' nested F
    /// tests pooled, 5σ).
    Auto,
    /// Ideal accelerometers.
    None,
    /// A zero-g offset per axis.
    Bias,
    /// Offset and sensitivity (scale) per axis.
    BiasScale,
    /// Offset, scale and the 3 axis misalignments.
    Full,
}

impl IntrinsicsArg {
    /// Whether the data choose the model (up to the one `into` gives).
    pub(crate) fn selects(self) -> bool {
        self == IntrinsicsArg::Auto
    }
}

impl From<IntrinsicsArg> for skincal::estimate::ml::IntrinsicsModel {
    fn from(a: IntrinsicsArg) -> Self {
        use skincal::estimate::ml::IntrinsicsModel as M;
        match a {
            IntrinsicsArg::Auto => M::BiasScale,
            IntrinsicsArg::None => M::None,
            IntrinsicsArg::Bias => M::Bias,
            IntrinsicsArg::BiasScale => M::BiasScale,
            IntrinsicsArg::Full => M::Full,
        }
    }
}

#[derive(Debug, Clone, Copy, PartialEq, Eq, clap::ValueEnum)]
pub(crate) enum Method {
    /// Maximum likelihood on the raw readings: closed-form start, Levenberg-Marquardt, covariance.
    Ml,
    /// The paper's method: progressive NLopt MLSL-LDS + Nelder-Mead on e_T.
    Paper,
}

#[derive(Debug, Args)]
struct CalibrateArgs {
    /// Directory with measurements.json (and structure.json, truth.json if present).
    dir: PathBuf,
    /// Estimation method.
    #[arg(long, value_enum, default_value_t = Method::Ml)]
    method: Method,
    /// Noise of every reading (uniform ±G, in g) for weighting and the convergence test of `ml`.
    /// Default: each reading's own standard deviation where the measurement set gives them
    /// (sets from `skincal ingest`), else 0.01 g.
    #[arg(long, value_name = "G")]
    noise: Option<f64>,
    /// Only the limb that ends at this segment (e.g. S7; see `skincal explore`).
    #[arg(long, value_name = "ID")]
    limb: Option<String>,
    /// Accelerometer intrinsics estimated per SU with the kinematics (method ml).
    #[arg(long, value_enum, default_value_t = IntrinsicsArg::Auto)]
    intrinsics: IntrinsicsArg,
    /// Keep this SU in the fit even if its readings look broken (repeatable; method ml).
    #[arg(long, value_name = "SU")]
    keep: Vec<String>,
    /// Seed of NLopt's random numbers (method paper; method ml is deterministic).
    #[arg(long, default_value_t = 1)]
    seed: u64,
    /// Global stop of the paper's method: e_T ≤ E (g²).
    #[arg(long, value_name = "E", default_value_t = 0.1)]
    e_stop: f64,
    /// Cap on error-function evaluations per step (method paper).
    #[arg(long, default_value_t = 100_000)]
    max_evaluations: u32,
    /// Overwrite an existing model file.
    #[arg(long)]
    force: bool,
    /// Print a JSON summary instead of the text: per limb whether it converged, its residual,
    /// iterations and time; what was left out (the model file is written as always).
    #[arg(long)]
    json: bool,
    /// Fit the readings of measurements.json only, even where DIR holds the motion record of
    /// its logs (motion.json, from `skincal ingest`), which is fitted sample by sample by default
    /// (method ml).
    #[arg(long)]
    readings_only: bool,
}

#[derive(Debug, Subcommand)]
enum BenchCommand {
    /// Structural exploration, from readings to tree, on a random robot.
    Explore(BenchExploreArgs),
    /// Kinematic estimation of paper-7dof over many noise seeds: time, evaluations, accuracy.
    Calibrate(BenchCalibrateArgs),
    /// The whole pipeline (explore, calibrate every limb, validate on held-out poses) on the
    /// humanoid or a random tree: time, memory, accuracy against the truth.
    Body(bench_body::BenchBodyArgs),
    /// Ingestion of a 1 kHz log with many SUs (MCAP and CSV): time against real time.
    Ingest(logs::BenchIngestArgs),
    /// The time-domain fit on a 1 kHz log (the motion record, the readings' fit and the refit on
    /// every sample): time, memory and held-out accuracy.
    Motion(bench_motion::BenchMotionArgs),
    /// Real sensors and imperfect skins (intrinsics, glitches, broken SUs) against clean data.
    Sensors(bench_sensors::BenchSensorsArgs),
    /// Robot-like limbs (parallel and intersecting axes, joint limits, several SUs per segment):
    /// convergence, held-out prediction, accuracy against the truth.
    Limbs(bench_limbs::BenchLimbsArgs),
    /// The HTML report of a random tree (calibrated first, untimed): time and size of the page.
    Report(bench_report::BenchReportArgs),
    /// `check` on ordinary motion after random changes of the skin: how often each is named,
    /// false alarms, and the check's speed on many SUs.
    Check(bench_check::BenchCheckArgs),
}

#[derive(Debug, Args)]
struct PredictArgs {
    /// A calibrated model (model.json).
    model: PathBuf,
    /// Poses: CSV with a header of DoF names and one pose per row (rad), or JSON {"dofs", "poses"}.
    #[arg(long)]
    poses: PathBuf,
    /// Excitation pattern A,f (rad/s, Hz) [default: the model's training pattern].
    #[arg(long, value_name = "A,F")]
    pattern: Option<String>,
    /// Write the JSON here instead of printing it.
    #[arg(long)]
    out: Option<PathBuf>,
    /// Overwrite an existing output.
    #[arg(long)]
    force: bool,
    /// Predict what an ideal accelerometer in each SU frame would read (the specific force and
    /// the acceleration), not what the SU reads with its calibrated bias and scale.
    #[arg(long)]
    ideal: bool,
    /// With --out, print one JSON document of what was written instead of the line (without
    /// --out the predictions themselves are the JSON printed).
    #[arg(long)]
    json: bool,
}

#[derive(Debug, Args)]
struct RobotsArgs {
    /// Print one JSON document instead of the table.
    #[arg(long)]
    json: bool,
}

#[derive(Debug, Args)]
struct ReportArgs {
    /// A result directory (measurements.json, structure.json, model.json: what it has).
    dir: PathBuf,
    /// Also check the model against this measurement set (directory or file).
    #[arg(long, value_name = "DIR2")]
    validate: Option<PathBuf>,
    /// Also check the robot's own URDF against the model (see `check-urdf`).
    #[arg(long, value_name = "URDF")]
    urdf: Option<PathBuf>,
    /// Also check the skin against the robot's ordinary motion in these logs (or a motion.json),
    /// with `check`'s defaults (repeat for several logs).
    #[arg(long = "check", value_name = "LOG")]
    check: Vec<PathBuf>,
    /// Where to write the page (default DIR/report.html).
    #[arg(long)]
    out: Option<PathBuf>,
    /// Overwrite an existing page.
    #[arg(long)]
    force: bool,
    /// Print one JSON document (what was written and the result's figures) instead of text.
    #[arg(long)]
    json: bool,
}

#[derive(Debug, Args)]
struct ValidateArgs {
    /// A calibrated model (model.json).
    model: PathBuf,
    /// Directory with the second measurements.json (or the file itself); its training poses are
    /// compared.
    dir: PathBuf,
    /// Print the result as JSON (per SU and overall) instead of the table.
    #[arg(long)]
    json: bool,
}

#[derive(Debug, Clone, Copy, PartialEq, Eq, clap::ValueEnum)]
enum BenchMethod {
    /// Both estimators on the same data.
    Both,
    /// Maximum likelihood only.
    Ml,
    /// The paper's method only.
    Paper,
}

#[derive(Debug, Args)]
struct BenchCalibrateArgs {
    /// Print the results as JSON (every seed and the pooled accuracy) instead of the table.
    #[arg(long)]
    json: bool,
    /// Estimators to run.
    #[arg(long, value_enum, default_value_t = BenchMethod::Both)]
    method: BenchMethod,
    /// Number of noise seeds (data sets), 1…N.
    #[arg(long, default_value_t = 10)]
    seeds: u64,
    /// The first seed (to rerun one case: --first-seed 280 --seeds 1).
    #[arg(long, default_value_t = 1)]
    first_seed: u64,
    /// Training poses P.
    #[arg(long, default_value_t = 20)]
    poses: usize,
    /// Uniform noise, g.
    #[arg(long, value_name = "G", default_value_t = 0.01)]
    noise: f64,
    /// Print one row per seed.
    #[arg(long)]
    verbose: bool,
    /// Instead of paper-7dof, a different random 7-DoF DH chain for every seed (eq. 18's bounds).
    #[arg(long)]
    random_chains: bool,
    /// Accelerometer intrinsics that `ml` estimates.
    #[arg(long, value_enum, default_value_t = IntrinsicsArg::Auto)]
    intrinsics: IntrinsicsArg,
    /// Simulated bias per SU and axis, uniform in ±G, g.
    #[arg(long, value_name = "G", default_value_t = 0.0)]
    bias: f64,
    /// Simulated scale error per SU and axis, uniform in ±F (0.03: ±3 %).
    #[arg(long, value_name = "F", default_value_t = 0.0)]
    scale: f64,
}

#[derive(Debug, Args)]
struct BenchExploreArgs {
    /// Print the timings as JSON instead of the table.
    #[arg(long)]
    json: bool,
    /// Number of SUs of the random robot.
    #[arg(long, default_value_t = 2000)]
    sus: usize,
    /// Number of DoFs of the random robot.
    #[arg(long, default_value_t = 60)]
    dofs: usize,
    /// Timed repetitions.
    #[arg(long, default_value_t = 30)]
    repeat: usize,
    /// Seed of the robot and the simulation.
    #[arg(long, default_value_t = 1)]
    seed: u64,
}

#[derive(Debug, Args)]
struct ExploreArgs {
    /// Directory with measurements.json (or the measurement file itself).
    dir: PathBuf,
    /// A reading that changes by more than this on any axis marks the SU as moved by the DoF, in g.
    #[arg(long, value_name = "G", default_value_t = 0.05)]
    threshold: f64,
    /// Entries within this factor of the threshold are reported as uncertain.
    #[arg(long, default_value_t = 2.0)]
    uncertainty_factor: f64,
    /// Print the structure as JSON on standard output instead of the tables.
    #[arg(long)]
    json: bool,
    /// Overwrite an existing structure.json and structure.dot.
    #[arg(long)]
    force: bool,
}

#[derive(Debug, Args)]
struct DemoArgs {
    /// Where to write the demo's files [default: skincal-demo in the system's temporary directory].
    #[arg(long)]
    out: Option<PathBuf>,
    /// Seed of every random choice.
    #[arg(long, default_value_t = 1)]
    seed: u64,
    /// Write into --out even if it holds files that demo did not make.
    #[arg(long)]
    force: bool,
    /// Print one JSON document (what was written and the result's figures) instead of text.
    #[arg(long)]
    json: bool,
}

#[derive(Debug, Args)]
struct SimulateArgs {
    /// A built-in robot (see `skincal robots`), a .toml description or a .urdf file.
    #[arg(long)]
    robot: String,
    /// Output directory.
    #[arg(long)]
    out: PathBuf,
    /// Overwrite existing output files.
    #[arg(long)]
    force: bool,
    /// Place K random SUs per segment (per link for a URDF) instead of the described ones.
    #[arg(long, value_name = "K")]
    sus_per_link: Option<usize>,
    /// Number of random training poses P.
    #[arg(long, default_value_t = 20)]
    poses: usize,
    /// Half-range of the random training poses, rad (clipped to each DoF's limits).
    #[arg(long, default_value_t = 2.62)]
    pose_range: f64,
    /// How far each DoF moves in the structure experiment, rad.
    #[arg(long, default_value_t = 0.3)]
    structure_angle: f64,
    /// Record the structure experiment in the upright orientation only (no 90° tilt).
    #[arg(long)]
    no_tilt: bool,
    /// Excitation pattern velocity amplitude A, rad/s.
    #[arg(long, default_value_t = 0.5)]
    amplitude: f64,
    /// Excitation pattern frequency f, Hz.
    #[arg(long, default_value_t = 2.0)]
    frequency: f64,
    /// Uniform noise ±G on every reading component, in g.
    #[arg(long, value_name = "G", default_value_t = 0.01)]
    noise: f64,
    /// Gaussian noise with standard deviation G on every component, in g.
    #[arg(long, value_name = "G", default_value_t = 0.0)]
    gaussian_noise: f64,
    /// Constant bias per SU and axis, uniform in ±G, in g.
    #[arg(long, value_name = "G", default_value_t = 0.0)]
    bias: f64,
    /// Scale (sensitivity) error per SU and axis, uniform in ±F (0.03: ±3 %).
    #[arg(long, value_name = "F", default_value_t = 0.0)]
    scale: f64,
    /// Misalignment of each SU's axes (3 angles), uniform in ±DEG, in degrees.
    #[arg(long, value_name = "DEG", default_value_t = 0.0)]
    misalignment: f64,
    /// Replace this fraction of all readings by glitches: random vectors of 0.2–1.5 g.
    #[arg(long, value_name = "FRACTION", default_value_t = 0.0)]
    glitches: f64,
    /// Break an SU: SU=dead|frozen|railed|swap-xy|negate-z (repeat for several).
    #[arg(long, value_name = "SU=FAULT")]
    broken: Vec<String>,
    /// Saturate every axis at ±G, in g.
    #[arg(long, value_name = "G")]
    saturation: Option<f64>,
    /// Quantise like the BMA150: 10 bit over ±2 g.
    #[arg(long)]
    bma150: bool,
    /// Seed of every random choice (poses, noise, sensor intrinsics, random SUs).
    #[arg(long, default_value_t = 1)]
    seed: u64,
    /// Draw the training poses and the noise from this seed instead: the same skin (SU placement
    /// and intrinsics from --seed) recorded again, e.g. as a held-out set for `validate`.
    #[arg(long, value_name = "SEED")]
    pose_seed: Option<u64>,
    /// Print one JSON document (what was written and the result's figures) instead of text.
    #[arg(long)]
    json: bool,
}

fn main() -> ExitCode {
    let cli = Cli::parse();
    // Ctrl-C, SIGTERM or SIGHUP: remove half-written outputs and scratch files, then stop.
    let _ = ctrlc::set_handler(|| {
        skincal::log::remove_transient();
        eprintln!("interrupted: partial outputs removed");
        std::process::exit(130);
    });
    match run(cli) {
        Ok(()) => ExitCode::SUCCESS,
        Err(e) => {
            eprintln!("error: {}", message(&e));
            ExitCode::from(if e.is::<Incomplete>() { 3 } else { 1 })
        }
    }
}

/// The results were written, but part of them is missing or unreliable: exit code 3.
#[derive(Debug)]
pub(crate) struct Incomplete(pub(crate) String);

impl std::fmt::Display for Incomplete {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(&self.0)
    }
}

impl std::error::Error for Incomplete {}

/// An error and its causes in one line, each said once: library errors often repeat their cause
/// in their own text (`cannot read F: No such file (os error 2)`).
fn message(e: &anyhow::Error) -> String {
    let mut text = String::new();
    for cause in e.chain() {
        let part = cause.to_string();
        if !text.contains(&part) {
            if !text.is_empty() {
                text.push_str(": ");
            }
            text.push_str(&part);
        }
    }
    text
}

fn run(cli: Cli) -> Result<()> {
    match cli.command {
        Command::Demo(args) => demo(args),
        Command::Simulate(args) => simulate(args),
        Command::Robots(args) => robots(args),
        Command::Explore(args) => explore(args),
        Command::Calibrate(args) => calibrate(args),
        Command::ExportUrdf(args) => urdf::export_urdf(args),
        Command::CheckUrdf(args) => urdf::check_urdf(args),
        Command::Report(args) => report_page(args),
        Command::Predict(args) => predict(args),
        Command::Validate(args) => validate(args),
        Command::Check(args) => check::check(args),
        Command::Bench(BenchCommand::Check(args)) => bench_check::bench_check(args),
        Command::Bench(BenchCommand::Body(args)) => bench_body::bench_body(args),
        Command::Bench(BenchCommand::Sensors(args)) => bench_sensors::bench_sensors(args),
        Command::Bench(BenchCommand::Limbs(args)) => bench_limbs::bench_limbs(args),
        Command::Bench(BenchCommand::Explore(args)) => bench_explore(args),
        Command::Bench(BenchCommand::Calibrate(args)) => bench_calibrate(args),
        Command::Bench(BenchCommand::Ingest(args)) => logs::bench_ingest(args),
        Command::Bench(BenchCommand::Motion(args)) => bench_motion::bench_motion(args),
        Command::Bench(BenchCommand::Report(args)) => bench_report::bench_report(args),
        Command::Plan(args) => logs::plan(args),
        Command::Record(args) => logs::record_log(args),
        Command::Ingest(args) => logs::ingest_logs(args),
    }
}

/// The measurement file and the output directory of a `DIR` argument.
fn measurement_paths(dir: &Path) -> (PathBuf, PathBuf) {
    if dir.is_file() {
        let parent = dir
            .parent()
            .filter(|p| !p.as_os_str().is_empty())
            .unwrap_or(Path::new("."));
        (dir.to_path_buf(), parent.to_path_buf())
    } else {
        (dir.join("measurements.json"), dir.to_path_buf())
    }
}

fn explore(args: ExploreArgs) -> Result<()> {
    let (file, dir) = measurement_paths(&args.dir);
    let set = io::read_measurements(&file)?;
    let config = ExploreConfig {
        threshold: args.threshold,
        uncertainty_factor: args.uncertainty_factor,
        ..ExploreConfig::default()
    };
    let structure =
        skincal::explore::explore(&set, &config).with_context(|| file.display().to_string())?;
    let json = serde_json::to_string_pretty(&structure)?;
    let (json_path, dot_path) = (dir.join("structure.json"), dir.join("structure.dot"));
    io::write_all(
        &[
            (json_path.clone(), json.clone()),
            (dot_path.clone(), report::structure_dot(&structure)),
        ],
        args.force,
    )?;
    if args.json {
        outln!("{json}");
    } else {
        out!("{}", render::structure_summary(&structure));
        outln!(
            "\nwrote {}\nwrote {}",
            json_path.display(),
            dot_path.display()
        );
    }
    if !structure.complete {
        let errors = structure
            .diagnostics
            .iter()
            .filter(|d| d.severity == skincal::explore::Severity::Error)
            .count();
        return Err(Incomplete(format!(
            "the tree is incomplete ({errors} error-level diagnostic(s); {} SUs and {} DoFs left out): {} was written, but calibrate will refuse it until the structure experiment is fixed",
            structure.unplaced_sus.len(),
            structure.unplaced_dofs.len(),
            json_path.display()
        ))
        .into());
    }
    Ok(())
}

/// The structure to calibrate: DIR/structure.json, else from exploring the set, else none (the
/// DoFs in listed order as one chain).
fn structure_of(
    set: &skincal::measurements::MeasurementSet,
    dir: &Path,
) -> Result<(Option<skincal::explore::Structure>, String)> {
    let structure_path = dir.join("structure.json");
    let (structure, source) = if structure_path.exists() {
        (
            Some(io::read_structure(&structure_path)?),
            format!("limbs from {}", structure_path.display()),
        )
    } else if set.structure.is_some() {
        (
            Some(skincal::explore::explore(set, &ExploreConfig::default())?),
            "limbs from exploring the structure experiment".to_string(),
        )
    } else {
        (
            None,
            "no structure experiment: the DoFs in listed order as one chain".to_string(),
        )
    };
    if let (Some(s), true) = (&structure, structure_path.exists()) {
        // A structure.json of another robot, or of an older recording, is named with the fix.
        if let Some((what, name)) = s.first_unknown(set) {
            anyhow::bail!(
                "{}: {what} `{name}` is not in the measurement set beside it: is the structure of another robot or recording? Run `skincal explore {} --force` to explore this set again",
                structure_path.display(),
                dir.display()
            );
        }
    }
    if structure.as_ref().is_some_and(|s| !s.complete) {
        anyhow::bail!("the explored structure is incomplete (see `skincal explore`): fix the structure experiment before calibrating");
    }
    Ok((structure, source))
}

fn calibrate(args: CalibrateArgs) -> Result<()> {
    if args.json {
        out::json_mode();
    }
    let (file, dir) = measurement_paths(&args.dir);
    let set = io::read_measurements(&file)?;
    let (structure, source) = structure_of(&set, &dir)?;
    refuse_readings_without_readings(&args, &set, &file, &dir)?;
    let truth_path = dir.join("truth.json");
    let truth = if truth_path.exists() {
        truth_of_this_set(io::read_true_robot(&truth_path)?, &set, &truth_path)
    } else {
        None
    };
    if args.method == Method::Ml {
        return calibrate_ml(
            &args,
            &set,
            structure.as_ref(),
            truth.as_ref(),
            &source,
            &dir,
        );
    }
    calibrate_paper(
        &args,
        &set,
        structure.as_ref(),
        truth.as_ref(),
        &source,
        &dir,
    )
}

/// A set with too few training poses is calibrated from its motion record: the paper's method
/// and `--readings-only`, which fit readings, are refused with what to do.
fn refuse_readings_without_readings(
    args: &CalibrateArgs,
    set: &skincal::measurements::MeasurementSet,
    file: &Path,
    dir: &Path,
) -> Result<()> {
    let poses = skincal::estimate::body::training_poses(set);
    if !(skincal::estimate::body::starts_from_quiet(set) && dir.join("motion.json").exists()) {
        return Ok(());
    }
    let has = if poses == 0 {
        "no readings".to_string()
    } else {
        format!(
            "{poses} training pose(s), too few to fit readings on (it takes {}),",
            skincal::estimate::body::MIN_POSES
        )
    };
    if args.method != Method::Ml {
        anyhow::bail!(
            "{} has {has} and the motion record motion.json: the paper's method fits \
             readings; use --method ml (the default), which fits the motion",
            file.display()
        );
    }
    if args.readings_only {
        anyhow::bail!(
            "{} has {has} and the motion record motion.json: leave out --readings-only to \
             calibrate from the motion",
            file.display()
        );
    }
    Ok(())
}

/// `calibrate --method paper`: every chain by the paper's progressive steps, each reported with
/// its DH tables (beside the truth's where there is one) and steps.
fn calibrate_paper(
    args: &CalibrateArgs,
    set: &skincal::measurements::MeasurementSet,
    structure: Option<&skincal::explore::Structure>,
    truth: Option<&skincal::model::Robot>,
    source: &str,
    dir: &Path,
) -> Result<()> {
    let chains = estimate::paper::chains(set, structure, args.limb.as_deref())?;
    let config = PaperConfig {
        seed: args.seed,
        e_stop: args.e_stop,
        max_evaluations: args.max_evaluations,
        ..PaperConfig::default()
    };
    outln!("kinematic estimation, the paper's method (MLSL-LDS + Nelder-Mead, e_stop {} g², seed {}); {source}\n", config.e_stop, config.seed);
    let mut estimates = Vec::new();
    for chain in &chains {
        let data = ChainData::new(set, chain)?;
        let busy = out::spinner(&format!(
            "limb {}: the paper's progressive steps",
            chain.name
        ));
        let estimate = estimate::paper::estimate_chain(&data, &config);
        busy.finish_and_clear();
        let estimate = estimate?;
        outln!(
            "limb {} ({} DoFs, {} training poses)\n",
            chain.name,
            chain.dofs.len(),
            data.poses()
        );
        let true_rows = truth.and_then(|t| estimate::true_dh_table(t, chain));
        out!(
            "{}",
            report::dh_tables(
                &estimate.chain,
                &estimate.dof_dof,
                &estimate.dof_su,
                true_rows.as_ref()
            )
        );
        outln!("\nOptimization steps\n");
        out!("{}", report::optimization_steps(&estimate));
        if let Some(t) = truth {
            let accuracy = estimate::consecutive_su_errors(t, &estimate.robot(), chain, 30, 1)?;
            outln!("\nPose of each SU relative to the previous one, against the truth (30 held-out poses)\n");
            out!("{}", report::chain_accuracy(&accuracy));
        }
        outln!();
        estimates.push(estimate);
    }
    let model = estimate::paper::PaperModel::new(estimates);
    let estimates = &model.limbs;
    let out = dir.join(model_file("model-paper", args.limb.as_deref()));
    io::write_all(
        &[(out.clone(), serde_json::to_string_pretty(&model)?)],
        args.force,
    )?;
    outln!("wrote {}", out.display());
    out::json(&serde_json::json!({
        "command": "calibrate",
        "method": "paper",
        "model": out.display().to_string(),
        "limbs": estimates.iter().map(|e| serde_json::json!({
            "name": e.chain.name,
            "dofs": e.chain.dofs,
            "sus": e.chain.sus,
            "converged": e.converged(),
            "evaluations": e.steps.iter().map(|s| s.evaluations).sum::<usize>(),
            "seconds": e.steps.iter().map(|s| s.seconds).sum::<f64>(),
        })).collect::<Vec<_>>(),
    }));
    if estimates.iter().any(|e| !e.converged()) {
        eprintln!("warning: some steps did not reach e_T ≤ e_stop (marked !)");
    }
    Ok(())
}

fn calibrate_ml(
    args: &CalibrateArgs,
    set: &skincal::measurements::MeasurementSet,
    structure: Option<&skincal::explore::Structure>,
    truth: Option<&skincal::model::Robot>,
    source: &str,
    dir: &Path,
) -> Result<()> {
    use skincal::estimate::ml::MlConfig;
    let uniform = args.noise.unwrap_or(DEFAULT_NOISE);
    let config = MlConfig {
        noise_sd: uniform * skincal::model::sensor::STANDARD_GRAVITY / 3f64.sqrt(),
        intrinsics: args.intrinsics.into(),
        select_intrinsics: args.intrinsics.selects(),
        reading_sd: args.noise.is_none(),
        ..MlConfig::default()
    };
    let own = config.reading_sd
        && set
            .training
            .as_ref()
            .is_some_and(|t| t.poses.iter().all(|p| p.static_sd.is_some()));
    let noise = if own {
        format!(
            "each reading weighted by its own standard deviation, residuals in units of σ = {:.4} m/s²",
            config.noise_sd
        )
    } else {
        format!(
            "noise σ = {:.4} m/s² = uniform ±{uniform} g",
            config.noise_sd
        )
    };
    outln!(
        "kinematic estimation, maximum likelihood ({noise}; intrinsics per SU: {}); {source}",
        if config.select_intrinsics {
            format!("up to {}, as the data choose", config.intrinsics.name())
        } else {
            config.intrinsics.name().to_string()
        }
    );
    let motion = motion_record(args, set, dir)?;
    outln!();
    let bar = out::progress_bar(1, "calibrating");
    let mut progress = |limb: &str, done: usize, total: usize| {
        bar.set_length(total as u64);
        bar.set_position(done as u64);
        if !limb.is_empty() {
            bar.set_message(format!("calibrating (limb {limb} done)"));
        }
    };
    let model = match &motion {
        Some(record) => skincal::estimate::body::calibrate_body_on_motion(
            set,
            record,
            structure,
            &config,
            args.limb.as_deref(),
            &args.keep,
            &mut progress,
        ),
        None => skincal::estimate::body::calibrate_body_reporting(
            set,
            structure,
            &config,
            args.limb.as_deref(),
            &args.keep,
            &mut progress,
        ),
    };
    bar.finish_and_clear();
    let model = model?;
    let accuracies = limb_accuracies(&model, truth)?;
    for (limb, accuracy) in model.limbs.iter().zip(&accuracies) {
        out!("{}", limb_report(limb, truth, accuracy.as_ref())?);
    }
    if !model.not_calibrated.is_empty() {
        outln!("Not calibrated ({}):", model.not_calibrated.len());
        for n in &model.not_calibrated {
            outln!("  {} {}: {}", n.kind, n.name, n.reason);
        }
        outln!();
    }
    let out = dir.join(model_file("model", args.limb.as_deref()));
    io::write_all(
        &[(out.clone(), serde_json::to_string_pretty(&model)?)],
        args.force,
    )?;
    outln!("wrote {}", out.display());
    out::json(&ml_json(&model, &accuracies, &out, own, config.noise_sd));
    if model.limbs.iter().any(|l| !l.estimate.converged) {
        eprintln!("warning: some limbs did not converge to the noise level (see above)");
    }
    Ok(())
}

/// The motion record beside the set, unless `--readings-only`, with a line on how it is used.
fn motion_record(
    args: &CalibrateArgs,
    set: &skincal::measurements::MeasurementSet,
    dir: &Path,
) -> Result<Option<skincal::motion::MotionRecord>> {
    let motion_path = dir.join("motion.json");
    if !motion_path.exists() || args.readings_only {
        return Ok(None);
    }
    let record = io::read_motion(&motion_path)?;
    let poses = skincal::estimate::body::training_poses(set);
    if !skincal::estimate::body::starts_from_quiet(set) {
        outln!(
            "then every limb fitted again on every sample of its logs: {} ({} blocks of {} ms; --readings-only to skip)",
            motion_path.display(),
            record.blocks(),
            record.period * 1e3
        );
    } else {
        let readings = if poses == 0 {
            "no readings in the set".to_string()
        } else {
            format!(
                "{poses} training pose(s) in the set, too few for a start from readings (it \
                 takes {})",
                skincal::estimate::body::MIN_POSES
            )
        };
        outln!(
            "{readings}: every limb starts from {} quiet moments of {} ({} blocks of {} ms) \
             and is fitted on every sample of it",
            skincal::estimate::body::QUIET_POSES,
            motion_path.display(),
            record.blocks(),
            record.period * 1e3
        );
    }
    Ok(Some(record))
}

/// Each limb's SU poses against the truth, where there is one (the report draws the same).
fn limb_accuracies(
    model: &skincal::estimate::body::BodyModel,
    truth: Option<&skincal::model::Robot>,
) -> Result<Vec<Option<estimate::ChainAccuracy>>> {
    Ok(model
        .limbs
        .iter()
        .map(|limb| {
            let e = &limb.estimate;
            truth
                .map(|t| {
                    estimate::consecutive_su_errors(
                        t,
                        &e.to_robot(),
                        &e.chain.su_sequence(),
                        estimate::ACCURACY_POSES,
                        estimate::ACCURACY_SEED,
                    )
                })
                .transpose()
        })
        .collect::<Result<Vec<_>, _>>()?)
}

/// `calibrate --json`'s summary of a maximum-likelihood calibration written to `out`.
fn ml_json(
    model: &skincal::estimate::body::BodyModel,
    accuracies: &[Option<estimate::ChainAccuracy>],
    out: &Path,
    own: bool,
    noise_sd: f64,
) -> serde_json::Value {
    serde_json::json!({
        "command": "calibrate",
        "method": "ml",
        "model": out.display().to_string(),
        "weights": if own { "each reading's own standard deviation" } else { "one noise for every reading" },
        "noise_sd": noise_sd,
        "limbs": model.limbs.iter().zip(accuracies).map(|(l, accuracy)| serde_json::json!({
            "name": l.name,
            "accuracy": accuracy,
            "parent": l.parent,
            "dofs": l.dofs,
            "sus": l.sus,
            "converged": l.estimate.converged,
            "residual_ratio": l.estimate.residual_ratio,
            "motion": l.estimate.motion,
            "iterations": l.estimate.iterations,
            "seconds": l.estimate.seconds,
            "retries": l.estimate.retries,
            "rejected_readings": l.estimate.rejected,
        })).collect::<Vec<_>>(),
        "broken": model.broken,
        "not_calibrated": model.not_calibrated,
    })
}

/// The readings' noise when neither the set nor `--noise` gives it: uniform ±0.01 g, the paper's.
const DEFAULT_NOISE: f64 = 0.01;

/// `model.json`, or `model-S4.json` for a run on one limb: a part never replaces the whole.
fn model_file(stem: &str, limb: Option<&str>) -> String {
    match limb {
        Some(l) => format!("{stem}-{l}.json"),
        None => format!("{stem}.json"),
    }
}

/// What `calibrate` prints for one limb: the fit, the DH form of a paper-style chain, and the
/// accuracy against the truth when there is one.
fn limb_report(
    limb: &skincal::estimate::body::BodyLimb,
    truth: Option<&skincal::model::Robot>,
    accuracy: Option<&estimate::ChainAccuracy>,
) -> Result<String> {
    use std::fmt::Write as _;
    let e = &limb.estimate;
    let mut out = String::new();
    writeln!(
        out,
        "limb {} ({} DoFs: {}; {} SUs){}\n",
        limb.name,
        limb.dofs.len(),
        limb.dofs.join(", "),
        limb.sus.len(),
        limb.parent
            .as_ref()
            .map_or(String::new(), |p| format!(", on limb {p}"))
    )?;
    out.push_str(&render::ml_summary(e));
    if let (Some(dh), Some(serial)) = (&e.dh, e.chain.as_serial()) {
        let true_rows = truth.and_then(|t| estimate::dh_form(t, &serial));
        writeln!(
            out,
            "\nIn the paper's DH+2 form (Fig. 6; the first rows' θ0 and d are a gauge choice)\n"
        )?;
        out.push_str(&report::dh_tables(
            &serial,
            &dh.dof_dof,
            &dh.dof_su,
            true_rows.as_ref(),
        ));
    }
    if let Some(accuracy) = accuracy {
        writeln!(out, "\nPose of each SU relative to the previous one, against the truth (30 held-out poses)\n")?;
        out.push_str(&report::chain_accuracy(accuracy));
    }
    out.push('\n');
    Ok(out)
}

fn report_page(args: ReportArgs) -> Result<()> {
    if args.json {
        out::json_mode();
    }
    let mut inputs =
        io::read_report_inputs(&args.dir, args.validate.as_deref(), args.urdf.as_deref())?;
    if inputs.measurements.is_none() && inputs.structure.is_none() && inputs.model.is_none() {
        anyhow::bail!(
            "{} holds no measurements.json, structure.json or model.json to report on",
            args.dir.display()
        );
    }
    if !args.check.is_empty() {
        let model_path = args.dir.join("model.json");
        let Some(model) = &inputs.model else {
            anyhow::bail!(
                "--check needs a calibrated model: {} has no model.json",
                args.dir.display()
            );
        };
        let record = check::motion_of(&args.check, &model_path, model)?;
        let report = skincal::check::check_skin(model, &record, &Default::default())
            .with_context(|| format!("checking {}", model_path.display()))?;
        let names: Vec<String> = args.check.iter().map(|p| p.display().to_string()).collect();
        inputs.check = Some((report, names.join(", ")));
    }
    let out = args.out.unwrap_or_else(|| args.dir.join("report.html"));
    let page = skincal::html::render(&inputs);
    io::write_all(&[(out.clone(), &page)], args.force)?;
    outln!("wrote {}", out.display());
    out::json(&serde_json::json!({"wrote": out.display().to_string(), "bytes": page.len()}));
    // One rule for every check: a joint that disagrees, a skin that changed, is exit code 3, here
    // as in check-urdf and check.
    let mut found = Vec::new();
    if let Some((check, _)) = inputs
        .urdf_check
        .as_ref()
        .filter(|c| !c.0.disagree.is_empty())
    {
        found.push(format!(
            "{} with the calibration beyond 3σ",
            urdf::disagreement(&check.disagree)
        ));
    }
    if let Some((report, _)) = inputs.check.as_ref().filter(|c| c.0.any_change()) {
        let changed: Vec<&str> = report.changed().map(|s| s.su.as_str()).collect();
        found.push(format!(
            "the skin changed ({}{})",
            changed.join(", "),
            report
                .zero
                .as_ref()
                .map_or(String::new(), |z| format!("; the zero of {}", z.dof))
        ));
    }
    if found.is_empty() {
        Ok(())
    } else {
        Err(Incomplete(format!("the page is written; {}", found.join("; "))).into())
    }
}

/// `SU=FAULT` → a broken SU of the simulation.
fn parse_fault(text: &str) -> Result<sim::SuFault> {
    let names: Vec<&str> = sim::Fault::ALL.iter().map(|f| f.name()).collect();
    let (su, fault) = text.split_once('=').ok_or_else(|| {
        anyhow::anyhow!(
            "--broken `{text}`: expected SU=FAULT, FAULT one of {}",
            names.join(", ")
        )
    })?;
    let fault = sim::Fault::ALL
        .into_iter()
        .find(|f| f.name() == fault)
        .ok_or_else(|| {
            anyhow::anyhow!(
                "--broken `{text}`: unknown fault `{fault}`; use one of {}",
                names.join(", ")
            )
        })?;
    Ok(sim::SuFault {
        su: su.to_string(),
        fault,
    })
}

/// `A,f` → an excitation pattern.
fn parse_pattern(text: &str) -> Result<ExcitationPattern> {
    let parts: Vec<&str> = text.split(',').map(str::trim).collect();
    let bad = || {
        anyhow::anyhow!("--pattern `{text}`: expected A,f (velocity amplitude in rad/s, frequency in Hz), both positive, e.g. 0.5,2")
    };
    let [a, f] = parts.as_slice() else {
        return Err(bad());
    };
    let pattern = ExcitationPattern {
        amplitude: a.parse().map_err(|_| bad())?,
        frequency: f.parse().map_err(|_| bad())?,
    };
    if !pattern.is_valid() {
        return Err(bad());
    }
    Ok(pattern)
}

fn predict(args: PredictArgs) -> Result<()> {
    if args.json && args.out.is_some() {
        out::json_mode();
    }
    let model = io::read_model(&args.model)?;
    let pattern = match &args.pattern {
        Some(p) => parse_pattern(p)?,
        None => model.pattern,
    };
    let mut predictor = skincal::predict::Predictor::new(&model)
        .map_err(|e| anyhow::anyhow!("{}: {e}", args.model.display()))?;
    if args.ideal {
        predictor = predictor.ideal();
    }
    if !model.not_calibrated.is_empty() {
        let names: Vec<String> = model
            .not_calibrated
            .iter()
            .map(|n| format!("{} {}", n.kind, n.name))
            .collect();
        eprintln!(
            "note: not calibrated, so not predicted (their angles in the poses are ignored): {}",
            names.join(", ")
        );
    }
    let bar = out::progress_bar(1, "predicting");
    let to_file = args.out.is_some();
    let mut progress = |p: io::PredictionProgress| match p {
        io::PredictionProgress::Predicted(poses) => {
            bar.set_message(format!("predicting: {poses} poses"));
            bar.tick();
        }
        // On standard output the bar would break into the text.
        io::PredictionProgress::Written { .. } if !to_file => bar.finish_and_clear(),
        io::PredictionProgress::Written { parts, of } => {
            bar.set_message("writing");
            bar.set_length(of as u64);
            bar.set_position(parts as u64);
        }
    };
    match args.out {
        Some(out) => {
            let poses = io::write_predictions(
                &predictor,
                &args.poses,
                &pattern,
                &out,
                args.force,
                &mut progress,
            );
            bar.finish_and_clear();
            let poses = poses?;
            outln!(
                "wrote {} ({poses} poses, {} SUs, pattern A = {} rad/s, f = {} Hz)",
                out.display(),
                predictor.sus().len(),
                pattern.amplitude,
                pattern.frequency
            );
            out::json(&serde_json::json!({
                "command": "predict",
                "wrote": out.display().to_string(),
                "poses": poses,
                "sus": predictor.sus().len(),
                "pattern": {"amplitude": pattern.amplitude, "frequency": pattern.frequency},
                "ideal": args.ideal,
            }));
        }
        None => {
            let mut stdout = std::io::stdout().lock();
            let streamed = io::stream_predictions(
                &predictor,
                &args.poses,
                &pattern,
                &std::env::temp_dir(),
                &mut stdout,
                Path::new("standard output"),
                &mut progress,
            );
            bar.finish_and_clear();
            match streamed {
                // The reader has gone (`| head`): nothing is lost but the rest of the text.
                Err(io::IoError::Write { path, source })
                    if source.kind() == std::io::ErrorKind::BrokenPipe
                        && path == Path::new("standard output") => {}
                other => {
                    other?;
                }
            }
        }
    }
    Ok(())
}

fn validate(args: ValidateArgs) -> Result<()> {
    if args.json {
        out::json_mode();
    }
    let model = io::read_model(&args.model)?;
    let (file, _) = measurement_paths(&args.dir);
    let set = io::read_measurements(&file)?;
    let check = skincal::predict::validate(&model, &set, &file.display().to_string())?;
    outln!(
        "{} against {} ({} poses, pattern A = {} rad/s, f = {} Hz)\n",
        args.model.display(),
        file.display(),
        check.poses,
        set.training.as_ref().map_or(0.0, |t| t.pattern.amplitude),
        set.training.as_ref().map_or(0.0, |t| t.pattern.frequency)
    );
    out!("{}", render::validation_table(&check));
    out::json(&serde_json::json!({
        "command": "validate",
        "model": args.model.display().to_string(),
        "measurements": file.display().to_string(),
        "validation": check,
    }));
    Ok(())
}

fn bench_calibrate(args: BenchCalibrateArgs) -> Result<()> {
    if args.json {
        out::json_mode();
    }
    use skincal::estimate::ml;
    let paper = io::load_robot("paper-7dof", SuPlacement::default())?;
    let chain = SerialChain {
        name: "S7".into(),
        dofs: paper.model.dof_names(),
        sus: paper.model.su_names(),
    };
    let g = skincal::model::sensor::STANDARD_GRAVITY;
    let sd = args.noise * g / 3f64.sqrt();
    outln!(
        "{}, P = {}, uniform ±{} g noise (σ = {:.4} m/s²), seeds {}…{}; accuracy: pose of each SU relative to the previous one over 30 held-out poses\n",
        if args.random_chains { "random 7-DoF DH chains (robot seed = data seed)" } else { "paper-7dof" },
        args.poses,
        args.noise,
        sd,
        args.first_seed,
        args.first_seed + args.seeds.saturating_sub(1)
    );
    let methods: Vec<Method> = match args.method {
        BenchMethod::Both => vec![Method::Ml, Method::Paper],
        BenchMethod::Ml => vec![Method::Ml],
        BenchMethod::Paper => vec![Method::Paper],
    };
    let mut rows: Vec<(Method, Vec<render::BenchRow>)> =
        methods.iter().map(|&m| (m, Vec::new())).collect();
    let intrinsics: ml::IntrinsicsModel = args.intrinsics.into();
    let mut bounds = vec![(ml::IntrinsicsModel::None, 0.0, 0.0)];
    if intrinsics != ml::IntrinsicsModel::None {
        bounds.push((intrinsics, 0.0, 0.0));
    }
    let bar = crate::out::progress_bar(args.seeds, "bench calibrate: seeds");
    for seed in args.first_seed..args.first_seed.saturating_add(args.seeds) {
        bar.inc(1);
        let (truth, set) = bench_set(&args, &paper, seed)?;
        let data = ChainData::new(&set, &chain)?;
        let mut seed_bound = None;
        for (model, position, rotation) in &mut bounds {
            seed_bound = ml::cramer_rao_bound(
                &truth,
                &skincal::model::sensor::gravity_upright(),
                &data,
                sd.max(1e-9),
                30,
                1000 + seed,
                *model,
            );
            if let Some((p, r)) = seed_bound {
                *position += p * p;
                *rotation += r * r;
            }
        }
        for (method, list) in &mut rows {
            let (robot, converged, seconds, evaluations) =
                bench_fit(*method, &data, seed, sd, &args)?;
            let accuracy =
                estimate::consecutive_su_errors(&truth, &robot, &chain, 30, 1000 + seed)?;
            list.push(render::BenchRow {
                seed,
                converged,
                seconds,
                evaluations,
                accuracy,
                bound: seed_bound,
            });
        }
    }
    bar.finish_and_clear();
    let n = args.seeds.max(1) as f64;
    let bounds: Vec<(String, (f64, f64))> = bounds
        .into_iter()
        .map(|(model, p, r)| {
            (
                match model {
                    ml::IntrinsicsModel::None => "Cramér–Rao bound, ideal sensors".to_string(),
                    m => format!("Cramér–Rao bound, {} fitted", m.name()),
                },
                ((p / n).sqrt(), (r / n).sqrt()),
            )
        })
        .collect();
    let fig6 = skincal::model::presets::PAPER_FIG6_ESTIMATE.robot()?;
    let fig6_accuracy = (!args.random_chains)
        .then(|| estimate::consecutive_su_errors(&paper, &fig6, &chain, 30, 1000))
        .transpose()?;
    out!(
        "{}",
        render::calibration_bench(&rows, args.verbose, fig6_accuracy.as_ref(), &bounds)
    );
    out::json(&calibration_bench_json(
        &args,
        &rows,
        &bounds,
        fig6_accuracy,
    ));
    Ok(())
}

/// The bench's robot for `seed` (the paper's arm, or a random DH chain) and its simulated set.
fn bench_set(
    args: &BenchCalibrateArgs,
    paper: &skincal::model::Robot,
    seed: u64,
) -> Result<(skincal::model::Robot, skincal::measurements::MeasurementSet)> {
    let config = SimulationConfig {
        poses: args.poses,
        seed,
        imperfections: Imperfections {
            uniform_noise: args.noise,
            bias: args.bias,
            scale: args.scale,
            ..Imperfections::none()
        },
        ..SimulationConfig::default()
    };
    let truth = if args.random_chains {
        sim::random_dh_chain(7, seed)?
    } else {
        paper.clone()
    };
    let set = sim::simulate(&truth, &config)?.measurements;
    Ok((truth, set))
}

/// One calibration of the bench: the estimated robot, whether it converged, its time and its
/// evaluations (NLopt's for the paper's method, LM iterations for ML).
fn bench_fit(
    method: Method,
    data: &ChainData,
    seed: u64,
    sd: f64,
    args: &BenchCalibrateArgs,
) -> Result<(skincal::model::Robot, bool, f64, usize)> {
    use skincal::estimate::ml::{self, MlConfig};
    Ok(match method {
        Method::Paper => {
            let e = estimate::paper::estimate_chain(
                data,
                &PaperConfig {
                    seed,
                    ..PaperConfig::default()
                },
            )?;
            (e.robot(), e.converged(), e.seconds(), e.evaluations())
        }
        Method::Ml => {
            let e = ml::estimate_chain(
                data,
                &MlConfig {
                    noise_sd: sd.max(1e-6),
                    intrinsics: args.intrinsics.into(),
                    select_intrinsics: args.intrinsics.selects(),
                    ..MlConfig::default()
                },
            )?;
            (e.to_robot(), e.converged, e.seconds, e.iterations)
        }
    })
}

/// `bench calibrate --json`.
fn calibration_bench_json(
    args: &BenchCalibrateArgs,
    rows: &[(Method, Vec<render::BenchRow>)],
    bounds: &[(String, (f64, f64))],
    fig6_accuracy: Option<estimate::ChainAccuracy>,
) -> serde_json::Value {
    serde_json::json!({
        "command": "bench calibrate",
        "chains": if args.random_chains { "random 7-DoF DH chains" } else { "paper-7dof" },
        "poses": args.poses,
        "uniform_noise_g": args.noise,
        "first_seed": args.first_seed,
        "seeds": args.seeds,
        "methods": rows.iter().map(|(method, list)| serde_json::json!({
            "method": match method { Method::Ml => "ml", Method::Paper => "paper" },
            "converged": list.iter().filter(|r| r.converged).count(),
            "each": list.iter().map(|r| serde_json::json!({
                "seed": r.seed,
                "converged": r.converged,
                "seconds": r.seconds,
                "evaluations": r.evaluations,
                "accuracy": r.accuracy,
                "bound": r.bound.map(|(p, q)| serde_json::json!({"position": p, "rotation": q})),
            })).collect::<Vec<_>>(),
        })).collect::<Vec<_>>(),
        "bounds": bounds.iter().map(|(name, (p, q))| serde_json::json!({
            "intrinsics": name, "position": p, "rotation": q,
        })).collect::<Vec<_>>(),
        "paper_table_accuracy": fig6_accuracy,
    })
}

/// A random tree of `dofs` DoFs and `sus` SUs (the benches' robot).
pub(crate) fn random_robot(dofs: usize, sus: usize, seed: u64) -> Result<skincal::model::Robot> {
    Ok(sim::random_tree(
        &RandomTreeConfig {
            dofs,
            sus,
            ..RandomTreeConfig::default()
        },
        seed,
    )?)
}

fn bench_explore(args: BenchExploreArgs) -> Result<()> {
    use std::time::Instant;
    if args.json {
        out::json_mode();
    }
    let robot = random_robot(args.dofs, args.sus, args.seed)?;
    let config = SimulationConfig {
        training: false,
        seed: args.seed,
        ..SimulationConfig::default()
    };
    let set = sim::simulate(&robot, &config)?.measurements;
    let explore_config = ExploreConfig::default();
    let repeat = args.repeat.max(1);
    let (mut activity_ms, mut tree_ms, mut total_ms) = (Vec::new(), Vec::new(), Vec::new());
    let mut structure = None;
    for _ in 0..repeat {
        let t0 = Instant::now();
        let activity = skincal::explore::activity_matrix(&set, &explore_config)?;
        let t1 = Instant::now();
        let s = skincal::explore::structure_from_activity(&activity, &explore_config);
        let t2 = Instant::now();
        activity_ms.push((t1 - t0).as_secs_f64() * 1e3);
        tree_ms.push((t2 - t1).as_secs_f64() * 1e3);
        total_ms.push((t2 - t0).as_secs_f64() * 1e3);
        structure = Some(s);
    }
    let s = structure.expect("at least one repetition");
    outln!(
        "structural exploration, one thread: {} SUs × {} DoFs, {} base orientations, {} repetitions",
        args.sus, args.dofs, config.tilted_orientation as usize + 1, repeat
    );
    outln!(
        "found {} segments, {} joints, {} limbs; complete: {}\n",
        s.segments.len(),
        s.joints.len(),
        s.limbs.len(),
        s.complete
    );
    let stages = [
        ("activity matrix", activity_ms),
        ("merge, sort, tree", tree_ms),
        ("readings → tree", total_ms),
    ];
    out!("{}", render::timing_table(&stages));
    out::json(&serde_json::json!({
        "command": "bench explore",
        "sus": args.sus,
        "dofs": args.dofs,
        "seed": args.seed,
        "segments": s.segments.len(),
        "joints": s.joints.len(),
        "limbs": s.limbs.len(),
        "complete": s.complete,
        "milliseconds": stages.iter().map(|(stage, ms)| (stage.to_string(), serde_json::json!(ms)))
            .collect::<serde_json::Map<_, _>>(),
    }));
    Ok(())
}

fn robots(args: RobotsArgs) -> Result<()> {
    if args.json {
        out::json_mode();
    }
    let mut rows = Vec::new();
    for p in PRESETS {
        let robot = p
            .robot()
            .with_context(|| format!("built-in robot {}", p.name))?;
        let description = p.file()?.description.unwrap_or_default();
        rows.push(render::RobotRow {
            name: p.name,
            dofs: robot.model.dofs().len(),
            segments: robot.model.segments().len(),
            sus: robot.model.sus().len(),
            description,
        });
    }
    out!("{}", render::robots_table(&rows));
    out::json(&serde_json::json!({
        "robots": rows.iter().map(|r| serde_json::json!({
            "name": r.name,
            "dofs": r.dofs,
            "segments": r.segments,
            "sus": r.sus,
            "description": r.description,
        })).collect::<Vec<_>>(),
    }));
    Ok(())
}

fn simulate(args: SimulateArgs) -> Result<()> {
    if args.json {
        out::json_mode();
    }
    let robot = io::load_robot(
        &args.robot,
        SuPlacement {
            per_link: args.sus_per_link,
            seed: args.seed,
        },
    )?;
    let mut imperfections = Imperfections {
        uniform_noise: args.noise,
        gaussian_noise: args.gaussian_noise,
        bias: args.bias,
        scale: args.scale,
        misalignment: args.misalignment.to_radians(),
        glitches: args.glitches,
        saturation: args.saturation,
        quantization_bits: None,
    };
    if args.bma150 {
        imperfections = Imperfections {
            saturation: args.saturation.or(Some(2.0)),
            ..imperfections.with_bma150()
        };
    }
    let config = SimulationConfig {
        poses: args.poses,
        pose_range: args.pose_range,
        structure_angle: args.structure_angle,
        tilted_orientation: !args.no_tilt,
        pattern: ExcitationPattern {
            amplitude: args.amplitude,
            frequency: args.frequency,
        },
        imperfections,
        seed: args.seed,
        pose_seed: args.pose_seed,
        faults: args
            .broken
            .iter()
            .map(|b| parse_fault(b))
            .collect::<Result<_>>()?,
        ..SimulationConfig::default()
    };
    let files = write_simulation(&robot, &config, &args.out, args.force)?;
    out!("{}", files.1);
    for f in &files.0 {
        outln!("wrote {}", f.display());
    }
    out::json(&serde_json::json!({
        "wrote": files.0.iter().map(|f| f.display().to_string()).collect::<Vec<_>>(),
        "robot": robot.model.name(),
        "dofs": robot.model.dofs().len(),
        "sus": robot.model.sus().len(),
        "training_poses": config.poses,
    }));
    Ok(())
}

/// The truth beside a set, if it is the truth of that set's robot: every DoF and SU of the set
/// named in it. Otherwise a warning names what it lacks, and the comparison is left out.
fn truth_of_this_set(
    truth: skincal::model::Robot,
    set: &skincal::measurements::MeasurementSet,
    path: &std::path::Path,
) -> Option<skincal::model::Robot> {
    let m = &truth.model;
    let missing: Vec<String> = set
        .dofs
        .iter()
        .filter(|d| !m.dofs().iter().any(|x| &x.name == *d))
        .map(|d| format!("DoF `{d}`"))
        .chain(
            set.sus
                .iter()
                .filter(|u| !m.sus().iter().any(|x| &x.name == *u))
                .map(|u| format!("SU `{u}`")),
        )
        .collect();
    if missing.is_empty() {
        return Some(truth);
    }
    eprintln!(
        "warning: {} is not the truth of this measurement set: it has no {}{}; calibrating \
         without comparing against it",
        path.display(),
        missing[..missing.len().min(3)].join(", "),
        if missing.len() > 3 {
            format!(" and {} more", missing.len() - 3)
        } else {
            String::new()
        }
    );
    None
}

/// Simulates and writes `measurements.json` and `truth.json`; returns the paths and a summary.
fn write_simulation(
    robot: &skincal::model::Robot,
    config: &SimulationConfig,
    out: &std::path::Path,
    force: bool,
) -> Result<(Vec<PathBuf>, String)> {
    let simulation = sim::simulate(robot, config).context("invalid simulation setting")?;
    let measurements = out.join("measurements.json");
    let truth = out.join("truth.json");
    let truth_json = serde_json::to_string_pretty(&simulation.truth)?;
    io::write_all(
        &[
            (measurements.clone(), simulation.measurements.to_json()),
            (truth.clone(), truth_json),
        ],
        force,
    )?;
    let summary = render::simulation_summary(robot, config, &simulation.measurements.summary());
    Ok((vec![measurements, truth], summary))
}

/// The demo's table against the truth: per limb, SU pose errors and held-out errors.
fn demo_rows(
    robot: &skincal::model::Robot,
    model: &skincal::estimate::body::BodyModel,
    check: &skincal::predict::Validation,
) -> Result<Vec<render::LimbRow>> {
    model
        .limbs
        .iter()
        .map(|limb| {
            let e = &limb.estimate;
            let accuracy = estimate::consecutive_su_errors(
                robot,
                &e.to_robot(),
                &e.chain.su_sequence(),
                30,
                1,
            )?;
            Ok(render::LimbRow::new(
                &limb.name,
                limb.dofs.len(),
                &limb.sus,
                e.converged,
                Some(&accuracy),
                check,
            ))
        })
        .chain(std::iter::once(Ok(render::LimbRow::new(
            &format!("{} (static)", model.reference),
            0,
            &model
                .static_sus
                .iter()
                .map(|s| s.su.clone())
                .collect::<Vec<_>>(),
            true,
            None,
            check,
        ))))
        .collect::<Result<Vec<_>>>()
}

/// Makes the demo's directory: it replaces its own directory on every run, and nothing else.
fn prepare_demo_dir(out: &Path, force: bool) -> Result<()> {
    // A directory it marked, or one that holds only the files a demo writes.
    let marker = out.join(".skincal-demo");
    const DEMO_FILES: [&str; 11] = [
        ".skincal-demo",
        "measurements.json",
        "truth.json",
        "structure.json",
        "structure.dot",
        "model.json",
        "model.urdf",
        "held-out",
        "humanoid.urdf",
        "humanoid-skin.urdf",
        "report.html",
    ];
    let holds_other_files = std::fs::read_dir(out).is_ok_and(|entries| {
        entries
            .filter_map(Result::ok)
            .any(|e| !DEMO_FILES.contains(&e.file_name().to_string_lossy().as_ref()))
    });
    if holds_other_files && !marker.exists() && !force {
        anyhow::bail!(
            "{} holds files that skincal demo did not make: choose another --out, or pass --force to overwrite them",
            out.display()
        );
    }
    std::fs::create_dir_all(out).with_context(|| format!("cannot create {}", out.display()))?;
    std::fs::write(
        &marker,
        "made by skincal demo, which replaces this directory's files on every run\n",
    )
    .with_context(|| format!("cannot write {}", marker.display()))?;
    Ok(())
}

/// A limb's line in the demo: its size, cost, residual and the DoF orders found.
fn demo_limb_line(limb: &skincal::estimate::body::BodyLimb) -> String {
    let orders: Vec<String> = limb
        .estimate
        .joint_orders
        .iter()
        .map(|o| format!("{} = {}", o.joint, o.dofs.join(" → ")))
        .collect();
    format!(
        "limb {:<4} {} DoFs, {} SUs, {} LM iterations in {:.1} ms, residual {:.3}× σ{}",
        limb.name,
        limb.dofs.len(),
        limb.sus.len(),
        limb.estimate.iterations,
        limb.estimate.seconds * 1e3,
        limb.estimate.residual_ratio,
        if orders.is_empty() {
            String::new()
        } else {
            format!("; DoF order found: {}", orders.join(", "))
        }
    )
}

/// The demo's structure (JSON and Graphviz), model and model URDF, written whole.
fn write_demo_results(
    out: &Path,
    structure: &skincal::explore::Structure,
    model: &skincal::estimate::body::BodyModel,
) -> Result<Vec<PathBuf>> {
    let (json_path, dot_path, model_path, urdf_path) = (
        out.join("structure.json"),
        out.join("structure.dot"),
        out.join("model.json"),
        out.join("model.urdf"),
    );
    let robot_model = model.check().map_err(|e| anyhow::anyhow!(e))?;
    io::write_all(
        &[
            (json_path.clone(), serde_json::to_string_pretty(structure)?),
            (dot_path.clone(), report::structure_dot(structure)),
            (model_path.clone(), serde_json::to_string_pretty(model)?),
            (
                urdf_path.clone(),
                skincal::model::urdf::to_urdf(&robot_model)?,
            ),
        ],
        true,
    )?;
    Ok(vec![json_path, dot_path, model_path, urdf_path])
}

fn demo(args: DemoArgs) -> Result<()> {
    if args.json {
        out::json_mode();
    }
    let started = std::time::Instant::now();
    let out = args
        .out
        .unwrap_or_else(|| std::env::temp_dir().join("skincal-demo"));
    prepare_demo_dir(&out, args.force)?;
    let robot = io::load_robot("humanoid", SuPlacement::default())?;
    let config = SimulationConfig {
        seed: args.seed,
        ..SimulationConfig::default()
    };
    outln!(
        "skincal demo: the built-in humanoid ({} DoFs, {} SUs)\n",
        robot.model.dofs().len(),
        robot.model.sus().len()
    );
    outln!("1. Simulated experiments\n");
    let (mut files, summary) = write_simulation(&robot, &config, &out, true)?;
    out!("{summary}");
    outln!("\n2. Structural exploration\n");
    let set = io::read_measurements(&files[0])?;
    let structure = skincal::explore::explore(&set, &ExploreConfig::default())?;
    out!("{}", report::tree(&structure));
    outln!();
    out!("{}", report::diagnostics(&structure));

    outln!("\n3. Kinematic estimation of every limb, maximum likelihood\n");
    let ml = skincal::estimate::ml::MlConfig::default();
    let model = skincal::estimate::body::calibrate_body(&set, Some(&structure), &ml, None)?;
    for limb in &model.limbs {
        outln!("{}", demo_limb_line(limb));
    }

    outln!("\n4. Against the truth: each limb's SU poses (relative to the previous SU, 30 random poses) and its");
    outln!("   predictions on 20 held-out poses of a fresh experiment without noise\n");
    let held_out_config = SimulationConfig {
        seed: args.seed + 1000,
        structure: false,
        imperfections: Imperfections::none(),
        ..SimulationConfig::default()
    };
    let held_out_dir = out.join("held-out");
    let (held_files, _) = write_simulation(&robot, &held_out_config, &held_out_dir, true)?;
    let held_out = io::read_measurements(&held_files[0])?;
    let check =
        skincal::predict::validate(&model, &held_out, &held_files[0].display().to_string())?;
    let rows = demo_rows(&robot, &model, &check)?;
    out!("{}", render::body_table(&rows, &check));

    files.extend(write_demo_results(&out, &structure, &model)?);
    files.extend(held_files);
    outln!("\n5. The robot's own URDF: SU frames on its links, its joints checked\n");
    let urdf_files = urdf::demo_step(&robot, &model, &out)?;
    // The report, with the held-out check and the URDF's.
    let report_path = out.join("report.html");
    let inputs = io::read_report_inputs(&out, Some(&held_out_dir), Some(&urdf_files[0]))?;
    files.extend(urdf_files);
    io::write_all(
        &[(report_path.clone(), skincal::html::render(&inputs))],
        true,
    )?;
    files.push(report_path);
    outln!();
    for f in &files {
        outln!("wrote {}", f.display());
    }
    outln!(
        "\nfinished in {:.2} s; check another data set with `skincal validate {} DIR`",
        started.elapsed().as_secs_f64(),
        out.join("model.json").display()
    );
    out::json(&serde_json::json!({
        "wrote": files.iter().map(|f| f.display().to_string()).collect::<Vec<_>>(),
        "seconds": started.elapsed().as_secs_f64(),
        "limbs": model.limbs.iter().map(|l| serde_json::json!({
            "name": l.name,
            "dofs": l.dofs.len(),
            "sus": l.sus.len(),
            "residual_ratio": l.estimate.residual_ratio,
            "converged": l.estimate.converged,
        })).collect::<Vec<_>>(),
        "held_out": {
            "static_rms": check.static_rms,
            "dynamic_rms": check.dynamic_rms,
        },
    }));
    Ok(())
}

/// Starts the peak of [`peak_memory_mb`] again from the memory in use now (Linux; elsewhere the
/// peak stays the process's).
pub(crate) fn reset_peak_memory() {
    let _ = std::fs::write("/proc/self/clear_refs", "5");
}

/// CPU time this process has used so far, every thread's (those that ended too), s; `None` where
/// the system has no such clock.
pub(crate) fn cpu_seconds() -> Option<f64> {
    #[cfg(unix)]
    {
        let t = rustix::time::clock_gettime(rustix::time::ClockId::ProcessCPUTime);
        Some(t.tv_sec as f64 + t.tv_nsec as f64 * 1e-9)
    }
    #[cfg(not(unix))]
    {
        None
    }
}

/// Peak resident memory of this process, MB (Linux; 0 elsewhere).
pub(crate) fn peak_memory_mb() -> f64 {
    std::fs::read_to_string("/proc/self/status")
        .ok()
        .and_then(|s| {
            s.lines()
                .find(|l| l.starts_with("VmHWM:"))
                .and_then(|l| l.split_whitespace().nth(1))
                .and_then(|kb| kb.parse::<f64>().ok())
        })
        .map_or(0.0, |kb| kb / 1024.0)
}
