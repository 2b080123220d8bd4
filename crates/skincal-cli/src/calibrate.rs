//! `skincal calibrate`: kinematic estimation of every limb of a measurement set, by maximum
//! likelihood (the default) or by the paper's method.

use std::collections::BTreeSet;
use std::path::{Path, PathBuf};

use anyhow::Result;
use clap::Args;
use skincal::estimate::paper::PaperConfig;
use skincal::estimate::{self, LimbData};
use skincal::explore::ExploreConfig;
use skincal::io;
use skincal::report;

use crate::out::{self, out, outln};
use crate::{measurement_paths, render, IntrinsicsArg, Method};

#[derive(Debug, Args)]
pub(crate) struct CalibrateArgs {
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
    /// Fit each limb on its own only: a limb on another limb's segment keeps the path and gravity
    /// that limb's own SUs gave (by default the limbs of each tree are then fitted together, so
    /// that a trunk's DoFs are estimated from every SU they move; method ml).
    #[arg(long)]
    limb_by_limb: bool,
    /// Take the joint states of the directory's motion record as its encoders read them, even
    /// where they round coarsely (by default those DoFs' positions and accelerations at every
    /// sample are fitted too, held at what the encoders read: docs/logs.md).
    #[arg(long)]
    encoders_as_read: bool,
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

pub(crate) fn calibrate(args: CalibrateArgs) -> Result<()> {
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
    let inputs = Inputs {
        set: &set,
        structure: structure.as_ref(),
        truth: truth.as_ref(),
        source: &source,
        dir: &dir,
    };
    match args.method {
        Method::Ml => calibrate_ml(&args, &inputs),
        Method::Paper => calibrate_paper(&args, &inputs),
    }
}

/// What a calibration starts from: the set, its structure (and where it came from), the truth
/// where the set has one, and the set's directory (where the model is written).
#[derive(Clone, Copy)]
struct Inputs<'a> {
    set: &'a skincal::measurements::MeasurementSet,
    structure: Option<&'a skincal::explore::Structure>,
    truth: Option<&'a skincal::model::Robot>,
    source: &'a str,
    dir: &'a Path,
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
fn calibrate_paper(args: &CalibrateArgs, inputs: &Inputs<'_>) -> Result<()> {
    let Inputs {
        set,
        structure,
        truth,
        source,
        dir,
    } = *inputs;
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
        let data = LimbData::new(set, chain)?;
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
            chain.dofs().len(),
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
            "dofs": e.chain.dofs(),
            "sus": e.chain.sus(),
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

fn calibrate_ml(args: &CalibrateArgs, inputs: &Inputs<'_>) -> Result<()> {
    let Inputs {
        set,
        structure,
        truth,
        source,
        dir,
    } = *inputs;
    use skincal::estimate::ml::MlConfig;
    let uniform = args.noise.unwrap_or(DEFAULT_NOISE);
    let config = MlConfig {
        noise_sd: uniform * skincal::model::sensor::STANDARD_GRAVITY / 3f64.sqrt(),
        intrinsics: args.intrinsics.into(),
        select_intrinsics: args.intrinsics.selects(),
        reading_sd: args.noise.is_none(),
        whole_tree: !args.limb_by_limb,
        joint_states: !args.encoders_as_read,
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
        let holds = skincal::estimate::quiet::structure_holds(set, &record);
        let orientations = holds.iter().map(|p| p.orientation).collect::<BTreeSet<_>>();
        let holds = match holds.len() {
            0 => String::new(),
            n => format!(
                " and the structure part's {n} holds ({} base orientation{})",
                orientations.len(),
                if orientations.len() == 1 { "" } else { "s" }
            ),
        };
        outln!(
            "{readings}: every limb starts from {} quiet moments of {} ({} blocks of {} ms){holds} \
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
                        &e.chain,
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
    if let (Some(dh), true) = (&e.dh, e.chain.is_serial()) {
        let true_rows = truth.and_then(|t| estimate::dh_form(t, &e.chain));
        writeln!(
            out,
            "\nIn the paper's DH+2 form (Fig. 6; the first rows' θ0 and d are a gauge choice)\n"
        )?;
        out.push_str(&report::dh_tables(
            &e.chain,
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
