//! `record`, `ingest` and `bench ingest`: from a real robot's logs to a measurement set.

use std::path::{Path, PathBuf};
use std::time::Instant;

use crate::out::{self, out, outln, progress_bar};
use anyhow::{bail, Context, Result};
use clap::{Args, ValueEnum};
use skincal::ingest::{ingest, IngestConfig, IngestReport};
use skincal::io::{self, SuPlacement};
use skincal::log::csv::CsvSink;
use skincal::log::mcap::{Compression, McapSink};
use skincal::log::TransientDir;
use skincal::log::{LogSink, Topics};
use skincal::model::sensor::STANDARD_GRAVITY;
use skincal::plan::{Action, Part, Plan, PlanConfig, PlanDof};
use skincal::sim::timeseries::{record, LogConfig};
use skincal::sim::{BaseOrientation, Imperfections};

use crate::{parse_pattern, peak_memory_mb};

#[derive(Debug, Clone, Copy, PartialEq, Eq, ValueEnum)]
pub(crate) enum LogFormatArg {
    /// ROS 2 MCAP (sensor_msgs/JointState and sensor_msgs/Imu, CDR).
    Mcap,
    /// A directory with joint_states.csv and imu.csv.
    Csv,
}

#[derive(Debug, Clone, Copy, PartialEq, Eq, ValueEnum)]
pub(crate) enum CompressionArg {
    /// Zstandard (the ROS 2 default).
    Zstd,
    /// LZ4.
    Lz4,
    /// None.
    None,
}

impl From<CompressionArg> for Compression {
    fn from(c: CompressionArg) -> Self {
        match c {
            CompressionArg::Zstd => Compression::Zstd,
            CompressionArg::Lz4 => Compression::Lz4,
            CompressionArg::None => Compression::None,
        }
    }
}

#[derive(Debug, Clone, Copy, PartialEq, Eq, ValueEnum)]
pub(crate) enum PartArg {
    /// The structure experiment only.
    Structure,
    /// The training experiment only.
    Training,
    /// What the plan runs again with the base tilted: the structure experiment and its
    /// `--tilted-poses` training poses.
    Tilted,
}

#[derive(Debug, Args)]
pub(crate) struct RecordArgs {
    /// The simulated robot: a built-in robot, a .toml description or a .urdf file.
    #[arg(long)]
    robot: String,
    /// The plan (plan.json from `skincal plan`).
    #[arg(long)]
    plan: PathBuf,
    /// The log to write: an .mcap file, or a directory for CSV.
    #[arg(long)]
    out: PathBuf,
    /// Overwrite an existing log.
    #[arg(long)]
    force: bool,
    /// Log format.
    #[arg(long, value_enum, default_value_t = LogFormatArg::Mcap)]
    format: LogFormatArg,
    /// MCAP chunk compression.
    #[arg(long, value_enum, default_value_t = CompressionArg::Zstd)]
    compression: CompressionArg,
    /// Write every SU of a time step as one `skin_msgs/msg/ImuArray` message (MCAP), as skin
    /// drivers that read all SUs at once publish them, instead of one `sensor_msgs/Imu` per SU.
    #[arg(long)]
    imu_batch: bool,
    /// Run only one part of the plan.
    #[arg(long, value_enum)]
    part: Option<PartArg>,
    /// The base tilted by 90° about its x axis (the second orientation of the structure part).
    #[arg(long)]
    tilted: bool,
    /// Place K random SUs per segment instead of the described ones.
    #[arg(long, value_name = "K")]
    sus_per_link: Option<usize>,
    /// Sample rate, Hz.
    #[arg(long, default_value_t = 1000.0)]
    rate: f64,
    /// Uniform noise ±G on every sample component, in g.
    #[arg(long, value_name = "G", default_value_t = 0.01)]
    noise: f64,
    /// Constant bias per SU and axis, uniform in ±G, in g.
    #[arg(long, value_name = "G", default_value_t = 0.0)]
    bias: f64,
    /// Quantise like the BMA150: 10 bit over ±2 g (and saturate there).
    #[arg(long)]
    bma150: bool,
    /// Joint positions reported in steps of this size, rad.
    #[arg(long, value_name = "RAD", default_value_t = 0.0)]
    encoder_resolution: f64,
    /// Standard deviation of the timestamp jitter, s.
    #[arg(long, value_name = "S", default_value_t = 0.0)]
    jitter: f64,
    /// Probability that a message is lost.
    #[arg(long, value_name = "P", default_value_t = 0.0)]
    drop: f64,
    /// Seed of noise, bias, jitter and losses (and of random SUs).
    #[arg(long, default_value_t = 1)]
    seed: u64,
    /// Print one JSON document (what was written and the result's figures) instead of text.
    #[arg(long)]
    json: bool,
}

fn sink_for(
    format: LogFormatArg,
    out: &Path,
    compression: Compression,
    force: bool,
) -> Box<dyn LogSink> {
    match format {
        LogFormatArg::Mcap => Box::new(McapSink::new(out, Topics::default(), compression, force)),
        LogFormatArg::Csv => Box::new(CsvSink::new(out, force)),
    }
}

pub(crate) fn record_log(args: RecordArgs) -> Result<()> {
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
    let plan = skincal::io::read_plan(&args.plan)?;
    let config = log_config(&args);
    let truth_path = truth_path(&args.out);
    if !args.force && truth_path.exists() {
        bail!(
            "{} exists; choose another output or pass --force",
            truth_path.display()
        );
    }
    let mut sink = record_sink(&args)?;
    let started = Instant::now();
    let bar = progress_bar(1000, "simulating");
    let summary = record(&robot, &plan, &config, sink.as_mut(), &mut |f| {
        bar.set_position((f * 1000.0) as u64)
    })
    .context("cannot record the log")?;
    bar.finish_and_clear();
    let truth = serde_json::json!({
        "format": "skincal-log-truth",
        "version": 1,
        "robot": skincal::model::description::RobotFile::from_robot(&robot, None),
        "gravity": config.orientation.gravity,
        "orientation": config.orientation.label,
        "su_intrinsics": summary.su_intrinsics,
        "config": config,
    });
    io::write_all(
        &[(truth_path.clone(), serde_json::to_string_pretty(&truth)?)],
        args.force,
    )?;
    outln!(
        "Recorded {:.1} s at {} Hz ({} orientation{}): {} joint states, {} skin samples ({} SUs), \
         {} lost, {} saturated, in {:.1} s",
        summary.duration,
        config.rate,
        config.orientation.label,
        config
            .part
            .map_or(String::new(), |p| format!(", {p:?} part only")
                .to_lowercase()),
        summary.joint_messages,
        summary.imu_messages,
        robot.model.sus().len(),
        summary.dropped,
        summary.saturated,
        started.elapsed().as_secs_f64()
    );
    outln!("wrote {}", args.out.display());
    outln!("wrote {}", truth_path.display());
    out::json(&serde_json::json!({
        "wrote": [args.out.display().to_string(), truth_path.display().to_string()],
        "duration": summary.duration,
        "rate": config.rate,
        "orientation": config.orientation.label,
        "joint_messages": summary.joint_messages,
        "imu_messages": summary.imu_messages,
        "sus": robot.model.sus().len(),
        "lost": summary.dropped,
        "saturated": summary.saturated,
    }));
    Ok(())
}

/// How `record` runs the plan and records it.
fn log_config(args: &RecordArgs) -> LogConfig {
    let mut imperfections = Imperfections {
        uniform_noise: args.noise,
        bias: args.bias,
        ..Imperfections::none()
    };
    if args.bma150 {
        imperfections = imperfections.with_bma150();
    }
    LogConfig {
        rate: args.rate,
        orientation: if args.tilted {
            BaseOrientation::tilted()
        } else {
            BaseOrientation::upright()
        },
        part: args.part.map(|p| match p {
            PartArg::Structure => Part::Structure,
            PartArg::Training => Part::Training,
            PartArg::Tilted => Part::Tilted,
        }),
        imperfections,
        encoder_resolution: args.encoder_resolution,
        jitter: args.jitter,
        drop_probability: args.drop,
        seed: args.seed,
        ..LogConfig::default()
    }
}

/// The log `record` writes: its format, and for MCAP one message per SU or batches.
fn record_sink(args: &RecordArgs) -> Result<Box<dyn LogSink>> {
    Ok(match args.format {
        LogFormatArg::Mcap if args.imu_batch => Box::new(
            McapSink::new(
                &args.out,
                Topics::default(),
                args.compression.into(),
                args.force,
            )
            .batched(),
        ),
        LogFormatArg::Csv if args.imu_batch => {
            anyhow::bail!("--imu-batch is an MCAP layout: leave it out with --format csv")
        }
        _ => sink_for(args.format, &args.out, args.compression.into(), args.force),
    })
}

/// `run/upright.mcap` → `run/upright.truth.json`; a CSV directory `run/log` → `run/log.truth.json`.
fn truth_path(log: &Path) -> PathBuf {
    let stem = log
        .file_stem()
        .map(|s| s.to_string_lossy().into_owned())
        .unwrap_or_else(|| "log".into());
    log.with_file_name(format!("{stem}.truth.json"))
}

#[derive(Debug, Args)]
pub(crate) struct IngestArgs {
    /// Logs: .mcap files or CSV directories (joint_states.csv + imu.csv); e.g. one per base
    /// orientation.
    #[arg(required = true)]
    logs: Vec<PathBuf>,
    /// Output directory: measurements.json, ingest-report.json and motion.json (every sample of
    /// the logs with training poses, for `calibrate`'s time-domain fit).
    #[arg(long)]
    out: PathBuf,
    /// Write no motion.json: `calibrate` then fits the readings of measurements.json only.
    #[arg(long)]
    no_motion: bool,
    /// Overwrite existing output files.
    #[arg(long)]
    force: bool,
    /// The robot the logs are of (built-in, .toml or .urdf): fixes the DoF names, their order,
    /// kinds and mimic joints, and where the description places SUs (built-in, .toml) their
    /// names and order; other names are reported as unknown. A URDF places none: the SUs are
    /// the frame ids the logs hold.
    #[arg(long)]
    robot: Option<String>,
    /// The plan the logs followed: its pattern is the nominal one.
    #[arg(long)]
    plan: Option<PathBuf>,
    /// The tree of an earlier structure experiment (its structure.json): which DoF of several
    /// excited together moved each SU, for training logs recorded without their structure part.
    /// Without it, the logs' own structure part tells.
    #[arg(long, value_name = "STRUCTURE_JSON")]
    structure: Option<PathBuf>,
    /// The nominal pattern A,f (rad/s, Hz); estimated from the motion when neither this nor
    /// --plan is given.
    #[arg(long, value_name = "A,f")]
    pattern: Option<String>,
    /// MCAP topic of sensor_msgs/msg/JointState.
    #[arg(long, default_value = skincal::log::JOINT_TOPIC)]
    joint_topic: String,
    /// MCAP topic of sensor_msgs/msg/Imu.
    #[arg(long, default_value = skincal::log::IMU_TOPIC)]
    imu_topic: String,
    /// A DoF is still below this speed, rad/s (a tenth of it in m/s for a prismatic DoF).
    #[arg(long, default_value_t = IngestConfig::default().still_velocity)]
    still_velocity: f64,
    /// Between two motions every DoF is slower than this (servo ringing allowed), rad/s (a tenth
    /// of it in m/s for a prismatic DoF).
    #[arg(long, default_value_t = IngestConfig::default().quiet_velocity)]
    quiet_velocity: f64,
    /// Shortest pause that separates two motions, s.
    #[arg(long, default_value_t = IngestConfig::default().min_pause)]
    min_pause: f64,
    /// A DoF has moved when it left its position by more than this, rad.
    #[arg(long, default_value_t = IngestConfig::default().motion_threshold)]
    motion_threshold: f64,
    /// A DoF that moved less than this fraction of the DoF that moved most only followed it
    /// (servo compliance): fitted as coupled motion, not a second excited DoF.
    #[arg(long, default_value_t = IngestConfig::default().coupled_fraction)]
    coupled_fraction: f64,
    /// Shortest still window, s [default: 0.15; with --plan, at most 0.3 of its still periods].
    #[arg(long)]
    min_still: Option<f64>,
    /// Dropped at both ends of a still window (at least the filter's half-width), s [default:
    /// 0.05; with --plan, at most a tenth of its still periods].
    #[arg(long)]
    trim: Option<f64>,
    /// Half-width of the differentiation filter, s.
    #[arg(long, default_value_t = IngestConfig::default().filter)]
    filter: f64,
    /// Joint-state gaps longer than this make a motion unusable, s.
    #[arg(long, default_value_t = IngestConfig::default().max_gap)]
    max_gap: f64,
    /// Accelerometer range: samples at ±G or beyond (or within a converter step of 9 bits or
    /// more below it: the highest code) are saturated, in g.
    #[arg(long, value_name = "G", default_value_t = 2.0)]
    saturation: f64,
    /// The unit of the skin's samples: m/s² (what sensor_msgs/Imu carries), or g or mg for a
    /// driver that publishes those.
    #[arg(long, value_enum, default_value_t = SkinUnit::Ms2)]
    skin_unit: SkinUnit,
    /// The threshold `explore` will be run with, in g: ingest finds the structure part's tree
    /// with it where several DoFs were excited together (to tell which moved an SU).
    #[arg(long, value_name = "G", default_value_t = skincal::explore::ExploreConfig::default().threshold)]
    explore_threshold: f64,
    /// Print one JSON document (what was written and the result's figures) instead of text.
    #[arg(long)]
    json: bool,
}

/// The unit of a skin driver's accelerations.
#[derive(Debug, Clone, Copy, PartialEq, Eq, clap::ValueEnum)]
enum SkinUnit {
    /// m/s²
    #[value(name = "m/s2")]
    Ms2,
    /// Standard gravity, 9.80665 m/s²
    G,
    /// A thousandth of g
    Mg,
}

impl SkinUnit {
    /// m/s² per unit.
    fn scale(self) -> f64 {
        match self {
            SkinUnit::Ms2 => 1.0,
            SkinUnit::G => STANDARD_GRAVITY,
            SkinUnit::Mg => STANDARD_GRAVITY / 1000.0,
        }
    }
}

pub(crate) fn ingest_logs(args: IngestArgs) -> Result<()> {
    if args.json {
        out::json_mode();
    }
    let config = ingest_config(&args)?;
    let measurements = args.out.join("measurements.json");
    let report_path = args.out.join("ingest-report.json");
    let motion_path = args.out.join("motion.json");
    if !args.force {
        for p in [&measurements, &report_path, &motion_path] {
            if p.exists() {
                bail!(
                    "{} exists; choose another --out or pass --force",
                    p.display()
                );
            }
        }
    }
    let started = Instant::now();
    let bar = progress_bar(1, "reading");
    // The bar follows each pass: its message and length change with what is read.
    let mut current = String::new();
    let mut show = |what: &str, done: u64, total: u64| {
        if what != current {
            current = what.to_string();
            bar.set_message(what.to_string());
            bar.set_length(total.max(1));
        }
        bar.set_position(done);
    };
    let mut ingested = ingest(&args.logs, &config, &mut show)?;
    let training_logs = skincal::ingest::motion::training_logs(&ingested.report);
    let motion = if args.no_motion {
        if config.prismatic.is_none() {
            skincal::ingest::motion::tell_kinds(&mut ingested, &config, None, &mut show)?;
        }
        None
    } else {
        skincal::ingest::motion::record_of(&mut ingested, &config, &mut show)?
    };
    bar.finish_and_clear();
    let (set_json, report_json) = (
        ingested.measurements.to_json(),
        serde_json::to_string_pretty(&ingested.report)?,
    );
    fn text(text: &str) -> Box<io::Writer<'_>> {
        Box::new(move |w| w.write_all(text.as_bytes()))
    }
    let mut files = vec![
        (measurements.clone(), text(&set_json)),
        (report_path.clone(), text(&report_json)),
    ];
    if let Some(record) = &motion {
        // A long log's record is written as it is serialised, not held as one string.
        let write: Box<io::Writer<'_>> =
            Box::new(move |w| serde_json::to_writer(w, record).map_err(std::io::Error::other));
        files.push((motion_path.clone(), write));
    }
    io::write_all_with(&files, args.force)?;
    if motion.is_none() && motion_path.exists() {
        // An earlier ingest's record would be fitted with this set (only reached with --force).
        std::fs::remove_file(&motion_path)
            .with_context(|| format!("removing the old {}", motion_path.display()))?;
    }
    out!("{}", render_report(&ingested.report));
    if let Some(record) = &motion {
        outln!(
            "motion record: {} blocks of {} ms in {} runs from {} log(s) with training motion",
            record.blocks(),
            record.period * 1e3,
            record.runs.len(),
            training_logs.len()
        );
        let moves: Vec<&skincal::measurements::Move> = ingested
            .measurements
            .structure
            .iter()
            .flat_map(|s| &s.orientations)
            .flat_map(|o| &o.moves)
            .collect();
        let accelerated = moves.iter().filter(|m| !m.accelerated.is_empty()).count();
        if accelerated > 0 {
            outln!(
                "structure moves read by what they accelerated, from the motion record: {} of \
                 {} (they tell what a DoF that turns no gravity moves: a prismatic one, or one \
                 about a vertical axis)",
                accelerated,
                moves.len()
            );
        }
    }
    outln!("in {:.2} s", started.elapsed().as_secs_f64());
    outln!("wrote {}", measurements.display());
    outln!("wrote {}", report_path.display());
    if motion.is_some() {
        outln!("wrote {}", motion_path.display());
    }
    out::json(&serde_json::json!({
        "wrote": files.iter().map(|(f, _)| f.display().to_string()).collect::<Vec<_>>(),
        "seconds": started.elapsed().as_secs_f64(),
        "report": ingested.report,
        "motion_blocks": motion.as_ref().map(|r| r.blocks()),
    }));
    Ok(())
}

/// The ingestion's settings from the options, the robot's description and the plan.
fn ingest_config(args: &IngestArgs) -> Result<IngestConfig> {
    let mut config = IngestConfig {
        topics: Topics {
            joints: args.joint_topic.clone(),
            imu: args.imu_topic.clone(),
        },
        still_velocity: args.still_velocity,
        quiet_velocity: args.quiet_velocity,
        min_pause: args.min_pause,
        motion_threshold: args.motion_threshold,
        coupled_fraction: args.coupled_fraction,
        filter: args.filter,
        max_gap: args.max_gap,
        saturation: args.saturation * STANDARD_GRAVITY,
        skin_scale: args.skin_unit.scale(),
        explore: skincal::explore::ExploreConfig {
            threshold: args.explore_threshold,
            ..Default::default()
        },
        ..IngestConfig::default()
    };
    if let Some(spec) = &args.robot {
        let robot = io::load_robot(spec, SuPlacement::default())?;
        config.dofs = Some(robot.model.dof_names());
        if io::places_its_sus(spec) {
            config.sus = Some(robot.model.su_names());
        }
        config.prismatic = Some(robot.model.prismatic_dof_names());
        config.mimic = robot.model.mimic_specs();
    }
    if let Some(path) = &args.plan {
        let plan = skincal::io::read_plan(path)?;
        if config.dofs.is_none() {
            config.dofs = Some(plan.dof_names());
        }
        config = config.with_plan(&plan);
    }
    if let Some(path) = &args.structure {
        config.tree = Some(io::read_structure(path)?);
    }
    config.min_still = args.min_still.unwrap_or(config.min_still);
    config.trim = args.trim.unwrap_or(config.trim);
    if let Some(p) = &args.pattern {
        config.pattern = Some(parse_pattern(p)?);
    }
    Ok(config)
}

fn render_report(r: &IngestReport) -> String {
    use std::fmt::Write as _;
    let mut s = String::new();
    for l in &r.logs {
        let _ = writeln!(
            s,
            "{} ({}): {:.1} s at {:.1} Hz, {} joint states, {} skin samples",
            l.path.display(),
            l.format,
            l.duration,
            l.rate,
            l.joint_states,
            l.imu_samples
        );
        if l.passes > 1 {
            let _ = writeln!(
                s,
                "  read twice (joint states, then skin samples): its joint stamps go back in time, \
                 a joint appears late, or a motion is longer than the skin samples one pass may \
                 hold"
            );
        }
        let _ = writeln!(
            s,
            "  windows: {} still{}, {} short pauses, {} excitations, {} structure moves; {} \
             transfers skipped",
            l.still_windows,
            if l.creeping > 0 {
                format!(" ({} poses read creeping)", l.creeping)
            } else {
                String::new()
            },
            l.pauses,
            l.excitations,
            l.moves,
            l.transfers
        );
        if let Some(line) = coupled_motion(l) {
            let _ = writeln!(s, "{line}");
        }
        let issues = log_issues(l);
        if issues.is_empty() {
            let _ = writeln!(s, "  clean: no gaps, losses, unknown names or saturation");
        } else {
            let _ = writeln!(s, "  {}", issues.join("; "));
        }
    }
    let p = &r.pattern;
    let _ = writeln!(
        s,
        "\nNominal pattern: A = {:.4} rad/s, f = {:.3} Hz (2πfA = {:.3} rad/s²), {}",
        p.amplitude,
        p.frequency,
        p.peak_acceleration(),
        r.pattern_source
    );
    let _ = writeln!(
        s,
        "Measurement set: {} base orientation(s) of structure moves, {} training poses, {} dynamic \
         accelerations",
        r.orientations, r.training_poses, r.dynamic
    );
    if let Some(n) = r.sample_noise {
        let _ = writeln!(
            s,
            "Sensor noise in still windows: {:.4} m/s² RMS per axis ({:.4} g)",
            n,
            n / STANDARD_GRAVITY
        );
    }
    if !r.kinds.is_empty() {
        let _ = writeln!(s, "{}", render_kinds(&r.kinds));
    }
    for w in &r.warnings {
        let _ = writeln!(s, "warning: {w}");
    }
    s
}

/// The DoFs' kinds as their structure moves told them (no description named them): each slide
/// with what told it, the turns counted.
fn render_kinds(kinds: &[skincal::ingest::moves::KindTold]) -> String {
    use skincal::model::DofKind;
    use std::fmt::Write as _;
    let turns = kinds
        .iter()
        .filter(|k| k.kind == Some(DofKind::Revolute))
        .count();
    let mut line = format!(
        "DoF kinds, told from what the structure moves did to the skin (no --robot or --plan \
         named them): {turns} revolute"
    );
    for slide in kinds.iter().filter(|k| k.kind == Some(DofKind::Prismatic)) {
        let _ = write!(line, "; `{}` prismatic: {}", slide.dof, slide.evidence);
    }
    line
}

/// The share of coupled motion fitted out of a log's excitation windows, if any had some.
fn coupled_motion(l: &skincal::ingest::LogReport) -> Option<String> {
    let mut shares: Vec<&skincal::ingest::ExcitationFit> = l
        .fits
        .iter()
        .filter(|f| !f.coupled_dofs.is_empty())
        .collect();
    if shares.is_empty() {
        return None;
    }
    shares.sort_by(|a, b| a.coupled.total_cmp(&b.coupled));
    let largest = shares[shares.len() - 1];
    Some(format!(
        "  coupled motion: in {} of {} excitation windows other DoFs moved too and were fitted \
         out: median {:.0} %, largest {:.0} % of the signal ({} at {:.2} s)",
        shares.len(),
        l.fits.len(),
        shares[shares.len() / 2].coupled * 100.0,
        largest.coupled * 100.0,
        largest.dof,
        largest.start
    ))
}

/// What went wrong reading a log, one phrase each.
fn log_issues(l: &skincal::ingest::LogReport) -> Vec<String> {
    let mut issues = Vec::new();
    for (n, what) in [
        (l.unsorted_joint_stamps, "unsorted joint stamps"),
        (l.duplicate_joint_stamps, "duplicate joint stamps"),
        (l.joint_gaps, "joint-state gaps"),
        (l.unsorted_imu_stamps, "unsorted skin stamps"),
        (l.imu_outside, "skin samples outside the joint states' time"),
        (
            l.filled,
            "skin samples interpolated (lost, or a skin slower than the joint states)",
        ),
        (l.joint_read.undecodable, "undecodable joint messages"),
        (l.imu_read.undecodable, "undecodable skin messages"),
    ] {
        if n > 0 {
            issues.push(format!("{n} {what}"));
        }
    }
    let saturated: u64 = l.saturated.values().sum();
    if saturated > 0 {
        issues.push(format!(
            "{saturated} saturated samples in windows (not used)"
        ));
    }
    let unknown: u64 = l.unknown_frames.values().sum();
    if unknown > 0 {
        issues.push(format!(
            "{unknown} samples of unknown frame ids {:?}",
            l.unknown_frames.keys().collect::<Vec<_>>()
        ));
    }
    if !l.unknown_joints.is_empty() {
        issues.push(format!(
            "unknown joints {:?}",
            l.unknown_joints.keys().collect::<Vec<_>>()
        ));
    }
    if !l.skipped.is_empty() {
        issues.push(format!("{} motions skipped", l.skipped.len()));
    }
    for (topic, n) in &l.joint_read.other_topics {
        issues.push(format!("{n} messages on {topic} (ignored)"));
    }
    if let Some(p) = l
        .joint_read
        .first_problem
        .as_ref()
        .or(l.imu_read.first_problem.as_ref())
    {
        issues.push(format!("first decoding problem: {p}"));
    }
    issues
}

#[derive(Debug, Args)]
pub(crate) struct BenchIngestArgs {
    /// SUs on the robot (random, on the paper's 7-DoF arm).
    #[arg(long, default_value_t = 1000)]
    sus: usize,
    /// Seconds of log (training excitations at 1 kHz).
    #[arg(long, default_value_t = 10.0)]
    seconds: f64,
    /// Log formats to measure.
    #[arg(long, value_enum, default_values_t = [LogFormatArg::Mcap, LogFormatArg::Csv])]
    format: Vec<LogFormatArg>,
    /// MCAP chunk compression.
    #[arg(long, value_enum, default_values_t = [CompressionArg::Zstd, CompressionArg::None])]
    compression: Vec<CompressionArg>,
    /// Runs of the bare pass and of the ingestion; the fastest of each is printed.
    #[arg(long, default_value_t = 3)]
    repeats: usize,
    /// Print the table as JSON instead of text.
    #[arg(long)]
    json: bool,
    /// Keep the logs in this directory (a temporary one otherwise).
    #[arg(long)]
    dir: Option<PathBuf>,
}

pub(crate) fn bench_ingest(args: BenchIngestArgs) -> Result<()> {
    if args.json {
        crate::out::json_mode();
    }
    if args.sus == 0 || args.repeats == 0 || !args.seconds.is_finite() || args.seconds <= 0.0 {
        bail!("--sus, --seconds and --repeats must be positive");
    }
    let (robot, plan) = bench_program(args.sus, args.seconds)?;
    let sus = robot.model.sus().len();
    let scratch = match &args.dir {
        Some(_) => None,
        None => Some(scratch()?),
    };
    let dir = match (&args.dir, &scratch) {
        (Some(d), _) => d.clone(),
        (_, s) => s
            .as_ref()
            .map(|s| s.path().to_path_buf())
            .unwrap_or_default(),
    };
    let cores = std::thread::available_parallelism().map_or(1, usize::from);
    ingest_header(&plan, sus, cores, args.repeats);
    let mut rows = Vec::new();
    for (format, compression) in bench_variants(&args.format, &args.compression) {
        let (path, row) = ingest_row(&robot, &plan, &dir, (format, compression), args.repeats)?;
        rows.push(row);
        if args.dir.is_none() {
            let _ = std::fs::remove_dir_all(&path).or_else(|_| std::fs::remove_file(&path));
        }
    }
    crate::out::json(&serde_json::json!({
        "command": "bench ingest",
        "log_seconds": plan.duration,
        "sus": sus,
        "rate_hz": 1000,
        "cores": cores,
        "rows": rows,
    }));
    drop(scratch);
    Ok(())
}

/// What `bench ingest` measures, and its table's header.
fn ingest_header(plan: &Plan, sus: usize, cores: usize, repeats: usize) {
    outln!(
        "Ingestion of a {:.0} s, 1 kHz log of paper-7dof with {} SUs ({} skin samples/s), {} cores;\n\
         bare pass: read (and decompress) the log and walk every message or row, decoding nothing;\n\
         the fastest of {} runs of each; CPU s: the least CPU time of a run, every thread's;\n\
         peak MB: the most memory in use during an ingestion",
        plan.duration,
        sus,
        sus * 1000,
        cores,
        repeats
    );
    outln!(
        "{:<12} {:>10} {:>12} {:>10} {:>10} {:>12} {:>12} {:>12} {:>10} {:>12} {:>14} {:>10}",
        "format",
        "size MB",
        "samples",
        "bare s",
        "ingest s",
        "ingest/bare",
        "bare CPU s",
        "ingest CPU s",
        "CPU ratio",
        "× real time",
        "samples/s",
        "peak MB"
    );
}

/// `plan` recorded in one format (and compression) in `dir` and ingested `repeats` times: its
/// table row printed; returns the log's path and the row as JSON.
fn ingest_row(
    robot: &skincal::model::Robot,
    plan: &Plan,
    dir: &Path,
    (format, compression): (LogFormatArg, Option<CompressionArg>),
    repeats: usize,
) -> Result<(PathBuf, serde_json::Value)> {
    let name = match compression {
        Some(c) => format!("mcap-{c:?}").to_lowercase(),
        None => "csv".into(),
    };
    let path = dir.join(match format {
        LogFormatArg::Mcap => format!("{name}.mcap"),
        LogFormatArg::Csv => name.clone(),
    });
    let compression = compression.unwrap_or(CompressionArg::None).into();
    let mut sink = sink_for(format, &path, compression, true);
    record(
        robot,
        plan,
        &LogConfig::default(),
        sink.as_mut(),
        &mut |_| {},
    )?;
    let size = dir_size(&path) as f64 / 1e6;
    let config = IngestConfig {
        pattern: Some(plan.pattern),
        dofs: Some(robot.model.dof_names()),
        sus: Some(robot.model.su_names()),
        ..IngestConfig::default()
    };
    let t = time_ingest(&path, &config, repeats)?;
    let cpu_ratio = t.cpu.zip(t.bare_cpu).map(|(i, b)| i / b);
    let optional = |v: Option<f64>| v.map_or("-".into(), |v| format!("{v:.2}"));
    outln!(
        "{:<12} {:>10.1} {:>12} {:>10.2} {:>10.2} {:>12.2} {:>12} {:>12} {:>10} {:>12.1} {:>14.0} {:>10.0}",
        name,
        size,
        t.samples,
        t.bare,
        t.seconds,
        t.seconds / t.bare,
        optional(t.bare_cpu),
        optional(t.cpu),
        optional(cpu_ratio),
        plan.duration / t.seconds,
        t.samples as f64 / t.seconds,
        t.peak
    );
    Ok((
        path,
        serde_json::json!({
            "format": name,
            "size_mb": size,
            "samples": t.samples,
            "bare_s": t.bare,
            "ingest_s": t.seconds,
            "ingest_over_bare": t.seconds / t.bare,
            "bare_cpu_s": t.bare_cpu,
            "ingest_cpu_s": t.cpu,
            "cpu_ingest_over_bare": cpu_ratio,
            "times_real_time": plan.duration / t.seconds,
            "samples_per_s": t.samples as f64 / t.seconds,
            "peak_mb": t.peak,
        }),
    ))
}

/// The paper's 7-DoF arm with about `sus` random SUs, and a training program cut to `seconds`.
pub(crate) fn bench_program(sus: usize, seconds: f64) -> Result<(skincal::model::Robot, Plan)> {
    let base = io::load_robot("paper-7dof", SuPlacement::default())?;
    let segments = base
        .model
        .sus()
        .iter()
        .map(|su| su.segment)
        .collect::<std::collections::BTreeSet<_>>()
        .len();
    let robot = skincal::model::description::with_random_sus(&base, sus.div_ceil(segments), 1)
        .context("cannot place the SUs")?;
    let mut plan = Plan::new(
        PlanDof::from_robot(&robot),
        &PlanConfig {
            structure: false,
            poses: 50,
            ..PlanConfig::default()
        },
    )?;
    // Ingestion needs an excitation and the still period after it.
    let first = plan
        .phases
        .iter()
        .position(|p| matches!(p.action, Action::Excitation { .. }))
        .and_then(|i| plan.phases.get(i + 1))
        .map_or(plan.duration, |still| still.start + still.duration);
    if seconds < first {
        bail!(
            "--seconds {seconds} is too short: the program's first excitation and the still period \
             after it end at {first:.1} s"
        );
    }
    plan.phases.retain(|p| p.start < seconds);
    plan.duration = seconds.min(plan.duration);
    Ok((robot, plan))
}

/// The logs to measure: each MCAP compression, and CSV.
fn bench_variants(
    formats: &[LogFormatArg],
    compressions: &[CompressionArg],
) -> Vec<(LogFormatArg, Option<CompressionArg>)> {
    let mut variants = Vec::new();
    for &f in formats {
        match f {
            LogFormatArg::Mcap => variants.extend(compressions.iter().map(|&c| (f, Some(c)))),
            LogFormatArg::Csv => variants.push((f, None)),
        }
    }
    variants
}

/// The fastest bare pass and ingestion of a log over some runs (wall and CPU time, s; CPU time
/// counts every thread's and is steadier than wall time on a shared machine), the ingestions'
/// peak memory (MB) and the skin samples read.
struct Timing {
    bare: f64,
    seconds: f64,
    bare_cpu: Option<f64>,
    cpu: Option<f64>,
    peak: f64,
    samples: u64,
}

/// The wall and CPU time `run` takes, s.
fn timed<T>(run: impl FnOnce() -> Result<T>) -> Result<(T, f64, Option<f64>)> {
    let cpu = crate::cpu_seconds();
    let started = Instant::now();
    let out = run()?;
    let wall = started.elapsed().as_secs_f64();
    let cpu = cpu.zip(crate::cpu_seconds()).map(|(a, b)| b - a);
    Ok((out, wall, cpu))
}

/// The least of two optional times.
fn least(a: Option<f64>, b: Option<f64>) -> Option<f64> {
    match (a, b) {
        (Some(a), Some(b)) => Some(a.min(b)),
        (a, b) => a.or(b),
    }
}

fn time_ingest(path: &Path, config: &IngestConfig, repeats: usize) -> Result<Timing> {
    let mut t = Timing {
        bare: f64::INFINITY,
        seconds: f64::INFINITY,
        bare_cpu: None,
        cpu: None,
        peak: 0.0,
        samples: 0,
    };
    for _ in 0..repeats {
        let ((), wall, cpu) = timed(|| Ok(skincal::log::bare_pass(path).map(|_| ())?))?;
        t.bare = t.bare.min(wall);
        t.bare_cpu = least(t.bare_cpu, cpu);
        crate::reset_peak_memory();
        let (run, wall, cpu) =
            timed(|| Ok(ingest(&[path.to_path_buf()], config, &mut |_, _, _| {})?))?;
        t.seconds = t.seconds.min(wall);
        t.cpu = least(t.cpu, cpu);
        t.peak = t.peak.max(peak_memory_mb());
        t.samples = run.report.logs[0].imu_samples;
    }
    Ok(t)
}

/// A scratch directory for the benchmarks' logs, removed when dropped, on an error, or by a
/// signal.
pub(crate) fn scratch() -> Result<TransientDir> {
    TransientDir::new("skincal-bench-", None)
        .context("cannot create a scratch directory in the system's temporary directory")
}

fn dir_size(path: &Path) -> u64 {
    if path.is_dir() {
        std::fs::read_dir(path)
            .map(|entries| {
                entries
                    .filter_map(|e| e.ok())
                    .filter_map(|e| e.metadata().ok())
                    .map(|m| m.len())
                    .sum()
            })
            .unwrap_or(0)
    } else {
        std::fs::metadata(path).map(|m| m.len()).unwrap_or(0)
    }
}
