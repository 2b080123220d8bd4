//! `skincal bench check`: how often `check` names each kind of change in ordinary motion, how often
//! it cries wolf, and how fast it runs.
//!
//! Detection: the robot calibrated by its continuous program (structure part, 20 s sweep, every
//! sample), then per trial a sweep of ordinary motion from a fresh seed, recorded after one change
//! at random — made on the robot (one SU shifted by 10 mm in a random direction or turned by 3°
//! about a random axis, two SUs swapped, a DoF's zero moved by 2°) or on the samples as its board
//! would send them (a 0.03 g bias step, a 3 % change of sensitivity in a random direction of the
//! three axes, silent, frozen within the first half, railed, 4× noisier)
//! — and an unchanged skin; every SU-check of an SU the change did not touch counts towards the
//! false alarms. A zero of a DoF that moves one SU alone counts as named when that SU is called
//! moved with the zero as what else it could be (`or_zero`): nothing on the robot tells more. A
//! change not named whose part that any motion tells is smaller than the size the check must see
//! (`Skin::told_part`: the height of an SU along a vertical axis that alone carries it, a tilt or
//! a sensitivity its bias mimics) is counted apart with that part, as one the report says no
//! motion tells is. Trials run on every core. Speed: the check alone on a record of `--sus` SUs
//! (random places on the paper's arm, calibrated from a simulated set) at 1 kHz, on one thread.

use std::time::Instant;

use anyhow::{bail, Result};
use clap::Args;
use rand::{Rng, SeedableRng};
use rayon::prelude::*;
use skincal::check::{check_skin, CheckConfig, CheckReport, LiveCheck, Verdict};
use skincal::estimate::body::{calibrate_body, calibrate_body_on_motion, BodyModel};
use skincal::estimate::ml::MlConfig;
use skincal::explore::{explore, ExploreConfig};
use skincal::ingest::{ingest, motion::motion_record, IngestConfig};
use skincal::log::csv::CsvSink;
use skincal::log::mcap::{Compression, McapSink};
use skincal::log::{read_log, Stream, Topics};
use skincal::model::sensor::STANDARD_GRAVITY;
use skincal::model::Robot;
use skincal::motion::MotionRecord;
use skincal::plan::{Plan, PlanConfig, PlanDof};
use skincal::sim::changes::{ChangedLog, SkinChange};
use skincal::sim::timeseries::{record, LogConfig};
use skincal::sim::{simulate, BaseOrientation, SimulationConfig};

use crate::logs::scratch;
use crate::out::{self, outln};

#[derive(Debug, Args)]
pub(crate) struct BenchCheckArgs {
    /// The robot (built-in name, TOML or URDF), calibrated by its continuous program.
    #[arg(long, default_value = "paper-7dof")]
    robot: String,
    /// Trials per kind of change.
    #[arg(long, default_value_t = 20)]
    trials: usize,
    /// Seconds of ordinary motion per trial.
    #[arg(long, default_value_t = 60.0)]
    seconds: f64,
    /// Only these kinds of change (repeat for several; every kind when none is given). Each
    /// kind's trials draw the same changes whichever others run.
    #[arg(long = "change", value_name = "KIND", value_parser = clap::builder::PossibleValuesParser::new(KINDS))]
    changes: Vec<String>,
    /// SUs of the speed measurement.
    #[arg(long, default_value_t = 1000)]
    sus: usize,
    /// Print the table as JSON instead of text.
    #[arg(long)]
    json: bool,
}

const KINDS: [&str; 11] = [
    "shift",
    "turn",
    "bias",
    "scale",
    "swap",
    "silent",
    "frozen",
    "railed",
    "noisy",
    "zero",
    "unchanged",
];

pub(crate) fn bench_check(args: BenchCheckArgs) -> Result<()> {
    if args.json {
        out::json_mode();
    }
    if args.trials == 0 || args.sus == 0 || !(args.seconds.is_finite() && args.seconds >= 5.0) {
        bail!("--trials and --sus must be positive, --seconds at least 5");
    }
    let scratch = scratch()?;
    let robot = skincal::io::load_robot(&args.robot, Default::default())?;
    let model = calibrated(&robot, scratch.path())?;
    let mut rows = Vec::new();
    let chosen = |kind: &str| args.changes.is_empty() || args.changes.iter().any(|c| c == kind);
    let kinds = KINDS.iter().filter(|k| chosen(k)).count();
    let bar = out::progress_bar((kinds * args.trials) as u64, "bench check: trials");
    for (k, kind) in KINDS.iter().enumerate().filter(|(_, k)| chosen(k)) {
        // The trials run on every core; each one's check is timed on its own.
        let trials = (0..args.trials)
            .into_par_iter()
            .map(|trial| {
                let seed = 1000 * (k as u64 + 1) + trial as u64;
                let change = random_change(kind, &robot, seed, args.seconds);
                let row = trial_of(&robot, &model, change, args.seconds, seed, scratch.path());
                bar.inc(1);
                row
            })
            .collect::<Result<Vec<Row>>>()?;
        let row = trials.into_iter().fold(Row::default(), Row::plus);
        rows.push((kind, row));
    }
    bar.finish_and_clear();
    let speed = speed(args.sus, scratch.path())?;
    print_table(&args, &rows, &speed);
    Ok(())
}

/// One kind of change over its trials.
#[derive(Default)]
struct Row {
    named: usize,
    /// Of those, moves called a bias change on an SU whose tilt a bias mimics.
    mimicked: usize,
    /// Changes the report said no motion tells (not named, and no miss): a zero there, a shift
    /// of an SU whose position nothing tells, a swap of two SUs that read alike.
    never_told: usize,
    /// Changes not named whose part that any motion tells is smaller than the size to see (the
    /// rest lies where the physics hides it), with that part in units of the size to see.
    hidden: Vec<f64>,
    alarms: usize,
    checks: usize,
    seconds: f64,
    misses: Vec<String>,
}

impl Row {
    fn plus(mut self, other: Row) -> Row {
        self.named += other.named;
        self.mimicked += other.mimicked;
        self.never_told += other.never_told;
        self.hidden.extend(other.hidden);
        self.alarms += other.alarms;
        self.checks += other.checks;
        self.seconds += other.seconds;
        self.misses.extend(other.misses);
        self
    }
}

/// One trial: `seconds` of ordinary motion of `robot` after `change`, checked against `model`.
fn trial_of(
    robot: &Robot,
    model: &BodyModel,
    change: Option<SkinChange>,
    seconds: f64,
    seed: u64,
    dir: &std::path::Path,
) -> Result<Row> {
    let mut row = Row::default();
    let changed = change
        .as_ref()
        .map_or(Ok(robot.clone()), |c| c.robot(robot))?;
    let record = ordinary(&changed, model, change.as_ref(), seconds, seed, dir)?;
    let started = Instant::now();
    let report = check_skin(model, &record, &CheckConfig::default())?;
    row.seconds += started.elapsed().as_secs_f64();
    let target = targets(change.as_ref());
    // A DoF's zero that one SU alone tells: named by that SU's move, read as the zero.
    let lone_zero = match &change {
        Some(SkinChange::Zero { dof, .. }) => report
            .sus
            .iter()
            .find(|s| s.or_zero.as_ref().is_some_and(|z| &z.dof == dof))
            .map(|s| s.su.clone()),
        _ => None,
    };
    for s in report
        .sus
        .iter()
        .filter(|s| !target.iter().any(|(su, _)| su == &s.su) && lone_zero.as_ref() != Some(&s.su))
    {
        row.checks += 1;
        row.alarms += usize::from(!s.verdict.is_quiet());
    }
    // A DoF's zero: named when the report names that DoF; anywhere else it is a false alarm.
    let zero_named = match &change {
        Some(SkinChange::Zero { dof, .. }) => {
            report.zero.as_ref().is_some_and(|z| &z.dof == dof) || lone_zero.is_some()
        }
        _ => {
            row.checks += 1;
            row.alarms += usize::from(report.zero.is_some());
            true
        }
    };
    // A move or a sensitivity change called a bias change counts, apart, on an SU whose tilt or
    // sensitivity no motion tells from a bias (one on the reference segment, which never turns).
    let mut mimicked = false;
    let named = zero_named
        && target.iter().all(|(su, v)| {
            report.sus.iter().any(|s| {
                let alike = match v {
                    Verdict::Moved => "orientation",
                    Verdict::ScaleChanged => "sensitivity",
                    _ => "",
                };
                let mimics = !alike.is_empty()
                    && s.verdict == Verdict::BiasChanged
                    && s.never_told.contains(alike);
                mimicked |= &s.su == su && mimics;
                &s.su == su && (&s.verdict == v || mimics)
            })
        });
    row.named += usize::from(named);
    row.mimicked += usize::from(named && mimicked);
    // A change the report says no motion tells: a zero there, a shift of an SU on the still
    // reference segment (segment 0), whose position nothing tells, a swap of two SUs that read
    // alike in every pose.
    let position_never_told = |su: &String| {
        let on_reference = robot
            .model
            .sus()
            .iter()
            .any(|x| &x.name == su && x.segment == 0);
        on_reference
            && report
                .sus
                .iter()
                .any(|s| &s.su == su && s.never_told.contains("position"))
    };
    let never_told = !named
        && match &change {
            Some(SkinChange::Zero { dof, .. }) => report.zeros_never_told.contains(dof),
            Some(SkinChange::Move { su, turn, .. }) => *turn == [0.0; 3] && position_never_told(su),
            Some(SkinChange::Swap { a, b }) => report
                .alike
                .iter()
                .any(|pair| pair.contains(a) && pair.contains(b)),
            _ => false,
        };
    row.never_told += usize::from(never_told);
    let told = (!named && !never_told)
        .then(|| told_part(model, &report, change.as_ref()))
        .flatten();
    let hidden = told.is_some_and(|t| t < 1.0);
    if hidden {
        row.hidden.extend(told);
    }
    if !named && !never_told && !hidden {
        let found: Vec<String> = target
            .iter()
            .filter_map(|(su, _)| report.sus.iter().find(|s| &s.su == su))
            .map(|s| format!("{} {} (p {:.1e})", s.su, s.verdict.word(), s.p_value))
            .collect();
        let told = told.map_or(String::new(), |t| format!(", told part {t:.2}"));
        row.misses.push(format!(
            "{change:?}: found {} {:?}{told}",
            found.join(", "),
            report.zero
        ));
    }
    Ok(row)
}

fn print_table(args: &BenchCheckArgs, rows: &[(&&str, Row)], speed: &Speed) {
    outln!(
        "{} calibrated by its continuous program; {} trials of {} s of ordinary motion per change, ±0.01 g\n",
        args.robot, args.trials, args.seconds
    );
    outln!(
        "{:<10} {:>7} {:>13} {:>22} {:>12}",
        "change",
        "named",
        "rate",
        "false alarms / checks",
        "check s"
    );
    for (kind, r) in rows {
        outln!(
            "{:<10} {:>7} {:>12.1}% {:>22} {:>12.3}",
            kind,
            r.named,
            100.0 * r.named as f64 / args.trials as f64,
            format!("{} / {}", r.alarms, r.checks),
            r.seconds / args.trials as f64
        );
    }
    for (kind, r) in rows.iter().filter(|r| r.1.mimicked > 0) {
        outln!(
            "{kind}: {} of the named were called a bias change on an SU whose {} no motion tells from a bias",
            r.mimicked,
            if **kind == "scale" { "sensitivity" } else { "tilt" }
        );
    }
    for (kind, r) in rows.iter().filter(|r| !r.1.hidden.is_empty()) {
        let parts: Vec<String> = r.hidden.iter().map(|t| format!("{t:.2}")).collect();
        outln!(
            "{kind}: {} trials not named made a change whose part that any motion tells is smaller than the size to see ({} of it; the rest lies where no motion of the robot tells), rate of the others {:.1}%",
            r.hidden.len(),
            parts.join(", "),
            100.0 * r.named as f64 / (args.trials - r.never_told - r.hidden.len()).max(1) as f64
        );
    }
    for (kind, r) in rows.iter().filter(|r| r.1.never_told > 0) {
        outln!(
            "{kind}: {} trials made a change the report said no motion tells (rate of the others {:.1}%)",
            r.never_told,
            100.0 * r.named as f64 / (args.trials - r.never_told).max(1) as f64
        );
    }
    for (kind, r) in rows {
        for miss in &r.misses {
            outln!("missed ({kind}): {miss}");
        }
    }
    outln!(
        "\nspeed on 1 thread: {} SUs, {:.0} s of 1 kHz MCAP log ({} blocks): reading its motion record {:.2} s, \
         check {:.2} s, fastest of {CHECK_RUNS} (slowest {:.2} s) ({:.1}× real time; {:.1}× with the reading); live, every sample pushed as read: {:.2} s ({:.1}× real time)",
        speed.sus,
        speed.seconds,
        speed.blocks,
        speed.read,
        speed.check,
        speed.check_slowest,
        speed.seconds / speed.check,
        speed.seconds / (speed.read + speed.check),
        speed.live,
        speed.seconds / speed.live
    );
    let json_rows: Vec<serde_json::Value> = rows
        .iter()
        .map(|(kind, r)| {
            serde_json::json!({
                "change": kind, "trials": args.trials, "named": r.named, "named_as_bias": r.mimicked, "never_told": r.never_told, "told_part_below_size": r.hidden,
                "false_alarms": r.alarms, "checks": r.checks,
                "check_seconds": r.seconds / args.trials as f64, "missed": r.misses,
            })
        })
        .collect();
    out::json(&serde_json::json!({
        "command": "bench check", "rows": json_rows,
        "speed": {"sus": speed.sus, "seconds": speed.seconds, "blocks": speed.blocks, "read_seconds": speed.read, "check_seconds": speed.check, "check_seconds_slowest": speed.check_slowest, "check_runs": CHECK_RUNS, "live_seconds": speed.live},
    }));
}

/// The part of `change` (a move, a bias or a sensitivity change of one SU) that any motion tells,
/// in units of the size the check must see ([`skincal::check::Skin::told_part`]).
fn told_part(model: &BodyModel, report: &CheckReport, change: Option<&SkinChange>) -> Option<f64> {
    let mut numbers = [0.0; skincal::check::CHANGE];
    let su = match change? {
        SkinChange::Move { su, shift, turn } => {
            numbers[..3].copy_from_slice(shift);
            numbers[3..6].copy_from_slice(turn);
            su
        }
        SkinChange::Bias { su, bias } => {
            numbers[6..9].copy_from_slice(bias);
            su
        }
        SkinChange::Scale { su, scale } => {
            numbers[9..12].copy_from_slice(scale);
            su
        }
        _ => return None,
    };
    let noise = report.sus.iter().find(|s| &s.su == su)?.noise_sd;
    let config = CheckConfig::default();
    let skin = skincal::check::Skin::new(model, &config).ok()?;
    skin.told_part(su, &numbers, noise, &config)
}

/// The SUs a change touches and the verdict each should get.
fn targets(change: Option<&SkinChange>) -> Vec<(String, Verdict)> {
    match change {
        Some(SkinChange::Move { su, .. }) => vec![(su.clone(), Verdict::Moved)],
        Some(SkinChange::Bias { su, .. }) => vec![(su.clone(), Verdict::BiasChanged)],
        Some(SkinChange::Scale { su, .. }) => vec![(su.clone(), Verdict::ScaleChanged)],
        Some(SkinChange::Swap { a, b }) => vec![
            (a.clone(), Verdict::Swapped { with: b.clone() }),
            (b.clone(), Verdict::Swapped { with: a.clone() }),
        ],
        Some(SkinChange::Silent { su }) => vec![(
            su.clone(),
            Verdict::Broken {
                how: "silent".into(),
            },
        )],
        Some(SkinChange::Frozen { su, .. }) => vec![(
            su.clone(),
            Verdict::Broken {
                how: "frozen".into(),
            },
        )],
        Some(SkinChange::Railed { su }) => vec![(
            su.clone(),
            Verdict::Broken {
                how: "railed".into(),
            },
        )],
        Some(SkinChange::Noisy { su, .. }) => vec![(
            su.clone(),
            Verdict::Broken {
                how: "noisy".into(),
            },
        )],
        Some(SkinChange::Zero { .. }) | None => Vec::new(),
    }
}

/// A change of `kind` at random: an SU, a unit direction, when a board froze in a log of
/// `seconds`.
fn random_change(kind: &str, robot: &Robot, seed: u64, seconds: f64) -> Option<SkinChange> {
    let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(seed);
    let names = robot.model.su_names();
    let su = names[rng.random_range(0..names.len())].clone();
    let mut unit = || {
        let v: nalgebra::Vector3<f64> = nalgebra::Vector3::new(
            rng.random_range(-1.0..1.0),
            rng.random_range(-1.0..1.0),
            rng.random_range(-1.0..1.0),
        );
        let v = v / v.norm().max(1e-9);
        [v.x, v.y, v.z]
    };
    let d = CheckConfig::default();
    let scaled = |v: [f64; 3], s: f64| v.map(|x| x * s);
    Some(match kind {
        "shift" => SkinChange::Move {
            su,
            shift: scaled(unit(), d.detect_position),
            turn: [0.0; 3],
        },
        "turn" => SkinChange::Move {
            su,
            shift: [0.0; 3],
            turn: scaled(unit(), d.detect_orientation),
        },
        "bias" => SkinChange::Bias {
            su,
            bias: scaled(unit(), 0.03 * STANDARD_GRAVITY),
        },
        "scale" => SkinChange::Scale {
            su,
            scale: scaled(unit(), d.detect_scale),
        },
        "swap" => {
            let other = names
                .iter()
                .filter(|n| **n != su)
                .nth(seed as usize % (names.len() - 1))?;
            SkinChange::Swap {
                a: su,
                b: other.clone(),
            }
        }
        "silent" => SkinChange::Silent { su },
        "frozen" => SkinChange::Frozen {
            su,
            // Within the first half: the rest is what the check has to tell it by.
            after: rng.random_range(0.0..seconds / 2.0),
        },
        "railed" => SkinChange::Railed { su },
        "zero" => {
            let dofs = robot.model.dof_names();
            let sign = if seed % 2 == 0 { 1.0 } else { -1.0 };
            SkinChange::Zero {
                // Not the first: about a vertical first axis its zero is the gauge, told by nothing.
                dof: dofs[1 + (seed as usize / 2) % (dofs.len() - 1).max(1)].clone(),
                offset: sign * 2f64.to_radians(),
            }
        }
        "noisy" => SkinChange::Noisy {
            su,
            factor: 4.0,
            seed,
        },
        _ => return None,
    })
}

/// The arm calibrated by the continuous program (upright log and tilted structure part).
fn calibrated(robot: &Robot, dir: &std::path::Path) -> Result<BodyModel> {
    let plan = Plan::new(
        PlanDof::from_robot(robot),
        &PlanConfig {
            seed: 2,
            ..PlanConfig::continuous()
        },
    )?;
    let upright = dir.join("calibration-upright");
    let tilted = dir.join("calibration-tilted");
    record(
        robot,
        &plan,
        &LogConfig {
            seed: 5,
            ..LogConfig::default()
        },
        &mut CsvSink::new(&upright, true),
        &mut |_| {},
    )?;
    let tilt = LogConfig {
        part: Some(skincal::plan::Part::Structure),
        orientation: BaseOrientation::tilted(),
        seed: 6,
        ..LogConfig::default()
    };
    record(
        robot,
        &plan,
        &tilt,
        &mut CsvSink::new(&tilted, true),
        &mut |_| {},
    )?;
    let config = IngestConfig::default();
    let set = ingest(&[upright.clone(), tilted], &config, &mut |_, _, _| {})?.measurements;
    let structure = explore(&set, &ExploreConfig::default())?;
    let motion = motion_record(&[upright], &set.dofs, &set.sus, &config, &mut |_, _, _| {})?;
    Ok(calibrate_body_on_motion(
        &set,
        &motion,
        Some(&structure),
        &MlConfig::default(),
        None,
        &[],
        &mut |_, _, _| {},
    )?)
}

/// `seconds` of ordinary motion (a sweep from plan seed `seed`) as `model`'s motion record, the
/// samples as the boards send them after `change`.
fn ordinary(
    robot: &Robot,
    model: &BodyModel,
    change: Option<&SkinChange>,
    seconds: f64,
    seed: u64,
    dir: &std::path::Path,
) -> Result<MotionRecord> {
    let plan = Plan::new(
        PlanDof::from_robot(robot),
        &PlanConfig::ordinary(seconds, seed),
    )?;
    let log = dir.join(format!("ordinary-{seed}"));
    let mut csv = CsvSink::new(&log, true);
    let mut sink = ChangedLog::new(change, &mut csv);
    let config = LogConfig {
        seed: seed + 100,
        ..LogConfig::default()
    };
    record(robot, &plan, &config, &mut sink, &mut |_| {})?;
    let record = read(log.clone(), model);
    // A minute of 1 kHz CSV is tens of megabytes: hundreds of trials would fill a disk.
    let _ = std::fs::remove_dir_all(&log);
    record
}

/// The motion record of `log` for `model`'s DoFs and SUs.
fn read(log: std::path::PathBuf, model: &BodyModel) -> Result<MotionRecord> {
    let m = model.check().map_err(anyhow::Error::msg)?.model;
    Ok(motion_record(
        &[log],
        &m.dof_names(),
        &m.su_names(),
        &IngestConfig::default(),
        &mut |_, _, _| {},
    )?)
}

/// Timed runs of the check on the speed measurement's record.
const CHECK_RUNS: usize = 3;

/// The check's speed on many SUs, one thread.
struct Speed {
    sus: usize,
    seconds: f64,
    blocks: usize,
    /// Reading the log's motion record.
    read: f64,
    /// The check of the record: the fastest of [`CHECK_RUNS`] (a shared machine's other loads
    /// only ever add), and the slowest.
    check: f64,
    check_slowest: f64,
    /// The live check: every sample of the log pushed as it is read, and a report at the end.
    live: f64,
}

/// The check on `sus` SUs (random places on the paper's arm, calibrated from a simulated set)
/// against 30 s of ordinary motion in an MCAP log, on one thread.
fn speed(sus: usize, dir: &std::path::Path) -> Result<Speed> {
    let (robot, _) = crate::logs::bench_program(sus, 30.0)?;
    let set = simulate(&robot, &SimulationConfig::default())?.measurements;
    let structure = explore(&set, &ExploreConfig::default())?;
    let model = calibrate_body(&set, Some(&structure), &MlConfig::default(), None)?;
    let plan = Plan::new(PlanDof::from_robot(&robot), &PlanConfig::ordinary(30.0, 7))?;
    let log = dir.join("speed.mcap");
    let mut sink = McapSink::new(&log, Topics::default(), Compression::Zstd, true);
    record(&robot, &plan, &LogConfig::default(), &mut sink, &mut |_| {})?;
    let pool = rayon::ThreadPoolBuilder::new().num_threads(1).build()?;
    let timed = |f: &mut (dyn FnMut() -> Result<()> + Send)| -> Result<f64> {
        let started = Instant::now();
        pool.install(&mut *f)?;
        Ok(started.elapsed().as_secs_f64())
    };
    let mut motion = None;
    let read_s = timed(&mut || {
        motion = Some(read(log.clone(), &model)?);
        Ok(())
    })?;
    let motion = motion.expect("read above");
    let runs = (0..CHECK_RUNS)
        .map(|_| {
            timed(&mut || {
                check_skin(&model, &motion, &CheckConfig::default())?;
                Ok(())
            })
        })
        .collect::<Result<Vec<f64>>>()?;
    let check_s = runs.iter().copied().fold(f64::INFINITY, f64::min);
    let check_slowest = runs.iter().copied().fold(0.0, f64::max);
    let live_s = timed(&mut || {
        let mut live = LiveCheck::new(&model, &CheckConfig::default())?;
        read_log(
            &log,
            Stream::Both,
            &Topics::default(),
            &mut |sample| {
                live.push(&sample);
                Ok(())
            },
            &mut |_| {},
        )?;
        live.report();
        Ok(())
    })?;
    let blocks = motion.runs.iter().map(|r| r.len()).sum::<usize>();
    Ok(Speed {
        sus: model.robot.sus.len(),
        seconds: blocks as f64 * motion.period,
        blocks,
        read: read_s,
        check: check_s,
        check_slowest,
        live: live_s,
    })
}
