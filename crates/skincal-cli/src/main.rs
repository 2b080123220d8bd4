//! `skincal`: self-calibration of skin-covered robots from their own accelerometers.
//!
//! A thin layer over the `skincal` library: parse the command line, call the library, print.

/// The estimator allocates and frees blocks of hundreds of kilobytes in every iteration of its
/// fits, on every thread: glibc's per-thread arenas hand such memory back to the kernel and fault
/// it in again each time (a third of a 60-DoF chain's calibration); mimalloc keeps it.
#[cfg(not(feature = "heap-count"))]
#[global_allocator]
static ALLOCATOR: mimalloc::MiMalloc = mimalloc::MiMalloc;

/// With the `heap-count` feature, every allocation is counted, so that `bench motion` can tell
/// the most a stage held at once ([`peak_heap_mb`]), apart from what the allocator keeps for
/// later and from what stages before it left. The count is two atomic operations on one shared
/// counter per allocation, which the threads of a fit contend for: TALOS's calibration took a
/// tenth to a sixth longer on two cores with it, so it is a build for measuring, not the default.
#[cfg(feature = "heap-count")]
static HEAP: peakmem_alloc::PeakMemAlloc<mimalloc::MiMalloc> =
    peakmem_alloc::PeakMemAlloc::new(mimalloc::MiMalloc);
#[cfg(feature = "heap-count")]
#[global_allocator]
static ALLOCATOR: &peakmem_alloc::PeakMemAlloc<mimalloc::MiMalloc> = &HEAP;

mod bench_body;
mod bench_calibrate;
mod bench_chain;
mod bench_check;
mod bench_limbs;
mod bench_motion;
mod bench_report;
mod bench_sensors;
mod calibrate;
mod check;
mod demo;
mod logs;
mod out;
mod plan;
mod predict;
mod render;
mod simulate;
mod urdf;

use std::path::{Path, PathBuf};
use std::process::ExitCode;

use anyhow::{Context, Result};
use clap::{Args, Parser, Subcommand};
use out::{out, outln};
use skincal::explore::ExploreConfig;
use skincal::io;
use skincal::model::presets::PRESETS;
use skincal::model::sensor::ExcitationPattern;
use skincal::report;
use skincal::sim::{self, RandomTreeConfig, SimulationConfig};

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
    Demo(demo::DemoArgs),
    /// Simulate the structure and training experiments of a robot: writes DIR/measurements.json
    /// and DIR/truth.json.
    #[command(after_help = EXIT_CODES)]
    Simulate(simulate::SimulateArgs),
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
    Calibrate(calibrate::CalibrateArgs),
    /// Write DIR/report.html: one self-contained page (activity matrix, kinematic tree, limbs with
    /// residual and uncertainty charts, held-out errors) from what DIR holds.
    #[command(after_help = EXIT_CODES)]
    Report(ReportArgs),
    /// Write a calibrated model as URDF, kinematics only: one link per segment, continuous (or
    /// prismatic) joints named after the DoFs, one link per SU on a fixed joint; or, with --into, the SU frames
    /// added to the robot's own URDF.
    #[command(name = "export-urdf", after_help = EXIT_CODES)]
    ExportUrdf(urdf::ExportUrdfArgs),
    /// Check the robot's own URDF against a calibrated model: per joint, the angle and distance
    /// between its axis and the calibrated one, with their uncertainty and a verdict.
    #[command(name = "check-urdf", after_help = EXIT_CODES)]
    CheckUrdf(urdf::CheckUrdfArgs),
    /// Predict every SU's static and dynamic readings in given poses (JSON, measurement-set units).
    #[command(after_help = EXIT_CODES)]
    Predict(predict::PredictArgs),
    /// Check a calibrated model against a second measurement set: prediction error per SU.
    #[command(after_help = EXIT_CODES)]
    Validate(predict::ValidateArgs),
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
    Plan(plan::PlanArgs),
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

#[derive(Debug, Subcommand)]
enum BenchCommand {
    /// Structural exploration, from readings to tree, on a random robot.
    Explore(BenchExploreArgs),
    /// Kinematic estimation of paper-7dof over many noise seeds: time, evaluations, accuracy.
    Calibrate(bench_calibrate::BenchCalibrateArgs),
    /// One long serial chain (a snake, one SU per segment) as it grows: time, LM iterations,
    /// held-out accuracy.
    Chain(bench_chain::BenchChainArgs),
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
        Command::Demo(args) => demo::demo(args),
        Command::Simulate(args) => simulate::simulate(args),
        Command::Robots(args) => robots(args),
        Command::Explore(args) => explore(args),
        Command::Calibrate(args) => calibrate::calibrate(args),
        Command::ExportUrdf(args) => urdf::export_urdf(args),
        Command::CheckUrdf(args) => urdf::check_urdf(args),
        Command::Report(args) => report_page(args),
        Command::Predict(args) => predict::predict(args),
        Command::Validate(args) => predict::validate(args),
        Command::Check(args) => check::check(args),
        Command::Bench(BenchCommand::Check(args)) => bench_check::bench_check(args),
        Command::Bench(BenchCommand::Body(args)) => bench_body::bench_body(args),
        Command::Bench(BenchCommand::Sensors(args)) => bench_sensors::bench_sensors(args),
        Command::Bench(BenchCommand::Limbs(args)) => bench_limbs::bench_limbs(args),
        Command::Bench(BenchCommand::Explore(args)) => bench_explore(args),
        Command::Bench(BenchCommand::Calibrate(args)) => bench_calibrate::bench_calibrate(args),
        Command::Bench(BenchCommand::Chain(args)) => bench_chain::bench_chain(args),
        Command::Bench(BenchCommand::Ingest(args)) => logs::bench_ingest(args),
        Command::Bench(BenchCommand::Motion(args)) => bench_motion::bench_motion(args),
        Command::Bench(BenchCommand::Report(args)) => bench_report::bench_report(args),
        Command::Plan(args) => plan::plan(args),
        Command::Record(args) => logs::record_log(args),
        Command::Ingest(args) => logs::ingest_logs(args),
    }
}

/// The measurement file and the output directory of a `DIR` argument.
pub(crate) fn measurement_paths(dir: &Path) -> (PathBuf, PathBuf) {
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

/// `A,f` → an excitation pattern.
pub(crate) fn parse_pattern(text: &str) -> Result<ExcitationPattern> {
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

/// Starts the peak of [`peak_memory_mb`] again from the memory in use now (Linux; elsewhere the
/// peak stays the process's), and [`peak_heap_mb`] from nothing.
pub(crate) fn reset_peak_memory() {
    let _ = std::fs::write("/proc/self/clear_refs", "5");
    #[cfg(feature = "heap-count")]
    peakmem_alloc::PeakMemAllocTrait::reset_peak_memory(&HEAP);
}

/// The most memory allocated at once beyond what was allocated at the last
/// [`reset_peak_memory`], MB: what a stage needed of its own, whatever the allocator kept of
/// earlier stages' memory for later; `None` unless built with the `heap-count` feature.
pub(crate) fn peak_heap_mb() -> Option<f64> {
    #[cfg(feature = "heap-count")]
    return Some(
        peakmem_alloc::PeakMemAllocTrait::get_peak_memory(&HEAP) as f64 / (1024.0 * 1024.0),
    );
    #[cfg(not(feature = "heap-count"))]
    None
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
