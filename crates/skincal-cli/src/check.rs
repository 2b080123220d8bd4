//! `check`: whether the skin still reads what a calibrated model predicts in a log of any motion,
//! and, with `--recalibrate`, a new model with what changed calibrated again.

use std::path::{Path, PathBuf};

use anyhow::{Context, Result};
use clap::Args;
use std::time::Duration;

use skincal::check::{check_skin, recalibrate, CheckConfig, CheckReport, LiveCheck, SuCheck};
use skincal::estimate::body::BodyModel;
use skincal::ingest::IngestConfig;
use skincal::io;
use skincal::log::{Sample, Stream, Topics};
use skincal::motion::MotionRecord;

use crate::out::{self, out, outln};
use crate::Incomplete;

#[derive(Debug, Args)]
pub struct CheckArgs {
    /// A calibrated model (model.json).
    model: PathBuf,
    /// Logs of the robot's motion, any motion (MCAP, rosbag2, ROS 1 bag, CSV directory), or a
    /// motion record (motion.json) that `ingest` wrote.
    #[arg(required = true)]
    logs: Vec<PathBuf>,
    /// Write a new model with the SUs that moved, changed bias or sensitivity or were swapped
    /// calibrated again
    /// from the same logs (everything else kept, the changes listed in its `changes`).
    #[arg(long, value_name = "MODEL")]
    recalibrate: Option<PathBuf>,
    /// The smallest shift to see, m.
    #[arg(long, default_value_t = CheckConfig::default().detect_position)]
    position: f64,
    /// The smallest turn to see, degrees.
    #[arg(long, default_value_t = 3.0)]
    orientation: f64,
    /// The smallest bias change to see, g.
    #[arg(long, default_value_t = 0.03)]
    bias: f64,
    /// The smallest change of an axis' sensitivity to see (relative: 0.03 is 3 %).
    #[arg(long, default_value_t = CheckConfig::default().detect_scale)]
    scale: f64,
    /// Probability of calling an unchanged SU changed, per SU.
    #[arg(long, default_value_t = CheckConfig::default().false_alarm)]
    false_alarm: f64,
    /// Read one MCAP log while it is being written (a rosbag2 recorder's .mcap file): a line
    /// every --every seconds of motion, the whole check when the file is complete or has not grown
    /// for --idle seconds.
    #[arg(long)]
    follow: bool,
    /// With --follow: seconds of motion between two lines.
    #[arg(long, default_value_t = 10.0, requires = "follow")]
    every: f64,
    /// With --follow: seconds without a new byte after which the log is taken as ended.
    #[arg(long, default_value_t = 30.0, requires = "follow")]
    idle: f64,
    /// Overwrite an existing --recalibrate output.
    #[arg(long)]
    force: bool,
    /// Print one JSON document (every SU's verdict and figures) instead of text.
    #[arg(long)]
    json: bool,
}

impl CheckArgs {
    fn config(&self) -> Result<CheckConfig> {
        let positive = |name: &str, v: f64| {
            anyhow::ensure!(
                v.is_finite() && v > 0.0,
                "--{name} {v}: give a positive number"
            );
            Ok(())
        };
        positive("position", self.position)?;
        positive("orientation", self.orientation)?;
        positive("bias", self.bias)?;
        positive("scale", self.scale)?;
        anyhow::ensure!(
            self.false_alarm > 0.0 && self.false_alarm < 0.5,
            "--false-alarm {}: give a probability in (0, 0.5)",
            self.false_alarm
        );
        Ok(CheckConfig {
            detect_position: self.position,
            detect_orientation: self.orientation.to_radians(),
            detect_bias: self.bias * skincal::model::sensor::STANDARD_GRAVITY,
            detect_scale: self.scale,
            false_alarm: self.false_alarm,
            ..CheckConfig::default()
        })
    }
}

pub fn check(args: CheckArgs) -> Result<()> {
    if args.json {
        out::json_mode();
    }
    let config = args.config()?;
    let model = io::read_model(&args.model)?;
    if args.follow {
        return follow(&args, &model, &config);
    }
    let record = motion_of(&args.logs, &args.model, &model)?;
    let report = check_skin(&model, &record, &config)
        .with_context(|| format!("checking {}", args.model.display()))?;
    out!("{}", table(&report));
    let mut written = None;
    if let Some(path) = &args.recalibrate {
        let (new, changes) = recalibrate(&model, &record, &report, &config)?;
        let text = serde_json::to_string_pretty(&new)?;
        io::write_all(&[(path.clone(), text)], args.force)?;
        outln!(
            "\n{}: {} SU(s) calibrated again from the log, everything else as in {}",
            path.display(),
            changes.len(),
            args.model.display()
        );
        written =
            Some(serde_json::json!({ "model": path.display().to_string(), "changes": changes }));
    }
    finish(&args, &report, written)
}

/// The JSON document, and exit code 3 naming what changed.
fn finish(
    args: &CheckArgs,
    report: &CheckReport,
    written: Option<serde_json::Value>,
) -> Result<()> {
    out::json(&serde_json::json!({
        "command": "check",
        "model": args.model.display().to_string(),
        "report": report,
        "recalibrated": written,
    }));
    if !report.any_change() {
        return Ok(());
    }
    let mut what: Vec<String> = report
        .changed()
        .map(|s| format!("{} {}", s.su, s.verdict.word()))
        .collect();
    if let Some(zero) = &report.zero {
        what.insert(0, format!("the zero of {}", zero.dof));
    }
    Err(Incomplete(format!(
        "the skin does not read what {} predicts: {}",
        args.model.display(),
        what.join(", ")
    ))
    .into())
}

/// `check --follow`: the live check of one MCAP log as it is written, a line every `--every`
/// seconds of motion, the whole table at its end.
fn follow(args: &CheckArgs, model: &BodyModel, config: &CheckConfig) -> Result<()> {
    let [log] = args.logs.as_slice() else {
        anyhow::bail!("--follow reads one MCAP log as it is written; give one");
    };
    anyhow::ensure!(
        args.recalibrate.is_none(),
        "--recalibrate needs the whole log: run `check` on {} once it is written",
        log.display()
    );
    for (name, v) in [("every", args.every), ("idle", args.idle)] {
        anyhow::ensure!(
            v.is_finite() && v > 0.0,
            "--{name} {v}: give a positive number of seconds"
        );
    }
    let mut live = LiveCheck::new(model, config)?;
    let mut next: Option<f64> = None;
    skincal::log::follow_log(
        log,
        Duration::from_secs_f64(args.idle),
        Stream::Both,
        &Topics::default(),
        &mut |sample| {
            live.push(&sample);
            let stamp = match sample {
                Sample::Joints { stamp, .. } | Sample::Imu { stamp, .. } => stamp,
            };
            let due = next.get_or_insert(stamp + args.every);
            if stamp >= *due {
                *due = stamp + args.every;
                if let Some(report) = live.report() {
                    outln!("{}", status(&report));
                }
            }
            Ok(())
        },
        &mut |_| {},
    )?;
    let report = live.report().ok_or_else(|| {
        anyhow::anyhow!(
            "{}: less than {} s of motion with every DoF's joint states: nothing to check",
            log.display(),
            skincal::check::WARM_UP
        )
    })?;
    out!("\n{}", table(&report));
    finish(args, &report, None)
}

/// One line of a followed check: how long, how many SUs are fine, which changed.
fn status(report: &CheckReport) -> String {
    let changed: Vec<String> = report
        .changed()
        .map(|s| format!("{} {}", s.su, s.verdict.word()))
        .collect();
    let untold = report
        .sus
        .iter()
        .filter(|s| s.verdict == skincal::check::Verdict::NotEnoughMotion)
        .count();
    let zero = report
        .zero
        .as_ref()
        .map_or(String::new(), |z| format!("; the zero of {} moved", z.dof));
    format!(
        "{:.0} s: {} unchanged, {} not told yet{}{}",
        report.seconds,
        report.sus.len() - changed.len() - untold,
        untold,
        if changed.is_empty() {
            String::new()
        } else {
            format!("; CHANGED: {}", changed.join(", "))
        },
        zero
    )
}

/// The motion record of `logs`: a motion.json as it is, or the logs read for the DoFs and SUs of
/// `model` (read from `model_path`).
pub(crate) fn motion_of(
    logs: &[PathBuf],
    model_path: &Path,
    model: &BodyModel,
) -> Result<MotionRecord> {
    if let [one] = logs {
        if one.extension().is_some_and(|e| e == "json") {
            return Ok(io::read_motion(one)?);
        }
    }
    let robot = model
        .check()
        .map_err(|e| anyhow::anyhow!("{}: {e}", model_path.display()))?;
    let bar = out::spinner("reading the logs");
    let record = skincal::ingest::motion::motion_record(
        logs,
        &robot.model.dof_names(),
        &robot.model.su_names(),
        &IngestConfig::default(),
        &mut |_, _, _| bar.tick(),
    )?;
    bar.finish_and_clear();
    Ok(record)
}

/// An SU's line of the check's table, and the notes under it.
fn su_lines(su: &SuCheck) -> String {
    let (shift, turn, bias, scale) = su.change.map_or(
        (
            "—".to_string(),
            "—".to_string(),
            "—".to_string(),
            "—".to_string(),
        ),
        |c| {
            let norm = |v: [f64; 3]| nalgebra::Vector3::from(v).norm();
            let sd = |v: Option<[f64; 3]>| {
                v.map_or(String::new(), |v| {
                    format!("±{:.1}", norm(v) * 1e3 / 3f64.sqrt())
                })
            };
            (
                format!("{:.1}{}", norm(c.shift) * 1e3, sd(c.shift_sd)),
                format!("{:.2}", norm(c.turn).to_degrees()),
                format!(
                    "{:.1}",
                    norm(c.bias) / skincal::model::sensor::STANDARD_GRAVITY * 1e3
                ),
                format!(
                    "{:.2}",
                    c.scale.iter().fold(0.0, |m: f64, x| m.max(x.abs())) * 1e2
                ),
            )
        },
    );
    let mut s = format!(
        "{:<14} {:<24} {:>7} {:>14} {:>12} {:>11} {:>9} {:>9.1e} {:>7.2}\n",
        su.su,
        su.verdict.word(),
        su.blocks,
        shift,
        turn,
        bias,
        scale,
        su.p_value,
        su.residual_ratio
    );
    if su.verdict == skincal::check::Verdict::NotEnoughMotion {
        s += &format!("{:<14} {}\n", "", su.untold);
    }
    if !su.never_told.is_empty() {
        s += &format!("{:<14} {}\n", "", su.never_told);
    }
    if let Some(zero) = &su.or_zero {
        s += &format!(
            "{:<14} or the zero of {} moved by {:.2}° ± {:.2}°: this one SU cannot tell the two apart\n",
            "",
            zero.dof,
            zero.offset.to_degrees(),
            zero.offset_sd.to_degrees()
        );
    }
    if let (skincal::check::Verdict::Broken { .. }, Some(c)) = (&su.verdict, su.samples) {
        s += &format!(
            "{:<14} {} samples: {} repeats of the one before (one value for {:.1} s at most), {} unusable ({:.1} s at most)\n",
            "", c.sent, c.repeated, c.longest_repeat, c.unusable, c.longest_unusable
        );
    }
    s
}

/// One line per SU: its verdict, the change found with its deviation, the test, what the log does
/// not tell.
fn table(report: &CheckReport) -> String {
    let mut s = format!(
        "{:.1} s of motion checked; changes to see: {:.0} mm, {:.1}°, {:.3} g, {:.1} % sensitivity, false alarms ≤ {} per SU\n\n",
        report.seconds,
        report.config.detect_position * 1e3,
        report.config.detect_orientation.to_degrees(),
        report.config.detect_bias / skincal::model::sensor::STANDARD_GRAVITY,
        report.config.detect_scale * 1e2,
        report.config.false_alarm
    );
    s += &format!(
        "{:<14} {:<24} {:>7} {:>14} {:>12} {:>11} {:>9} {:>9} {:>7}\n",
        "SU", "verdict", "blocks", "shift mm", "turn °", "bias mg", "scale %", "p", "resid"
    );
    for su in &report.sus {
        s += &su_lines(su);
    }
    if let Some(zero) = &report.zero {
        s += &format!(
            "\nthe zero of {} moved: it stands {:.3}° ± {:.3}° from what its encoder says (every SU beyond it, {}, tells the same; they are judged above with it taken out)\n",
            zero.dof,
            zero.offset.to_degrees(),
            zero.offset_sd.to_degrees(),
            zero.sus.join(", ")
        );
    }
    if !report.zeros_untold.is_empty() {
        s += &format!(
            "\nthe zeros of {} are not told by this log (a {:.1}° change would not be seen): too little of their motion, or no SU beyond them that the model still explains\n",
            report.zeros_untold.join(", "),
            report.config.detect_orientation.to_degrees()
        );
    }
    if !report.zeros_never_told.is_empty() {
        s += &format!(
            "\nthe zeros of {} are told by no motion: each turns what it carries about gravity on the still reference segment, so no reading depends on it\n",
            report.zeros_never_told.join(", ")
        );
    }
    if !report.alike.is_empty() {
        let pairs: Vec<String> = report
            .alike
            .iter()
            .map(|[a, b]| format!("{a} and {b}"))
            .collect();
        s += &format!(
            "\n{} read alike in every pose (turned alike on a segment that never moves): no motion tells an exchange of the two, so a swap there is never seen\n",
            pairs.join(", ")
        );
    }
    let todo: Vec<&SuCheck> = report.sus.iter().filter(|s| !s.advice.is_empty()).collect();
    if !todo.is_empty() || report.zero.is_some() {
        s += "\nwhat to do:\n";
        if let Some(zero) = &report.zero {
            s += &format!(
                "  {}: its encoder was homed anew; `check --recalibrate` sets its zero again\n",
                zero.dof
            );
        }
        for su in todo {
            s += &format!("  {}: {}\n", su.su, su.advice);
        }
    }
    for note in &report.notes {
        s += &format!("\nnote: {note}\n");
    }
    s
}
