//! `skincal bench limbs`: the whole pipeline on robot-like limbs ([`sim::robot_like_limb`]):
//! parallel and intersecting axes, joint limits, several SUs per segment.

use std::fmt::Write as _;
use std::time::Instant;

use anyhow::Result;
use clap::Args;
use skincal::estimate::body::calibrate_body;
use skincal::estimate::limb::LimbData;
use skincal::estimate::ml::{self, MlConfig};
use skincal::explore::{explore, ExploreConfig};
use skincal::measurements::MeasurementSet;
use skincal::model::sensor::gravity_upright;
use skincal::model::Robot;
use skincal::sim::{self, Imperfections, RobotLikeConfig, SimulationConfig};

use crate::out::{out, outln};

#[derive(Debug, Args)]
pub struct BenchLimbsArgs {
    /// Print the results as JSON (every limb and the summary) instead of the tables.
    #[arg(long)]
    json: bool,
    /// Number of limbs (one per seed).
    #[arg(long, default_value_t = 100)]
    limbs: u64,
    /// The first seed (to rerun one limb: --first-seed 17 --limbs 1).
    #[arg(long, default_value_t = 1)]
    first_seed: u64,
    /// Fewest and most DoFs per limb.
    #[arg(long, num_args = 2, value_names = ["MIN", "MAX"], default_values_t = [4, 9])]
    dofs: Vec<usize>,
    /// Most SUs per segment.
    #[arg(long, default_value_t = 3)]
    sus_per_segment: usize,
    /// Training poses P.
    #[arg(long, default_value_t = 20)]
    poses: usize,
    /// Print one line per limb as it is done.
    #[arg(long)]
    each: bool,
}

/// One limb's outcome.
#[derive(serde::Serialize)]
struct Outcome {
    name: String,
    dofs: usize,
    sus: usize,
    converged: bool,
    residual: f64,
    statics: f64,
    dynamics: f64,
    pose: f64,
    /// SU pose error in the directions the readings determine, and its bound, m.
    observable: f64,
    bound: f64,
    /// The bound at the truth as given, m.
    truth_bound: f64,
    seconds: f64,
    /// Why the pipeline stopped short, if it did.
    failure: Option<String>,
}

fn run(seed: u64, args: &BenchLimbsArgs) -> Result<Outcome> {
    let config = RobotLikeConfig {
        min_dofs: args.dofs[0],
        max_dofs: args.dofs[1],
        max_sus_per_segment: args.sus_per_segment,
    };
    let robot = sim::robot_like_limb(&config, seed)?;
    let (set, held_out) = training_and_held_out(&robot, seed, args.poses)?;
    let mut outcome = Outcome {
        name: robot.model.name().to_string(),
        dofs: robot.model.dofs().len(),
        sus: robot.model.su_names().len(),
        converged: false,
        residual: f64::NAN,
        statics: f64::NAN,
        dynamics: f64::NAN,
        pose: f64::NAN,
        observable: f64::NAN,
        bound: f64::NAN,
        truth_bound: f64::NAN,
        seconds: 0.0,
        failure: None,
    };
    let structure = explore(&set, &ExploreConfig::default())?;
    if !structure.complete || structure.limbs.len() != 1 {
        outcome.failure = Some(format!(
            "structure: {} limbs, complete {}",
            structure.limbs.len(),
            structure.complete
        ));
        return Ok(outcome);
    }
    let start = Instant::now();
    let model = calibrate_body(&set, Some(&structure), &MlConfig::default(), None)?;
    outcome.seconds = start.elapsed().as_secs_f64();
    let Some(limb) = model.limbs.first() else {
        outcome.failure = Some("no limb calibrated".into());
        return Ok(outcome);
    };
    let e = &limb.estimate;
    outcome.converged = e.converged;
    outcome.residual = e.residual_ratio;
    let check = skincal::predict::validate(&model, &held_out, "held-out")?;
    outcome.statics = check.static_rms;
    outcome.dynamics = check.dynamic_rms;
    outcome.pose =
        skincal::estimate::consecutive_su_errors(&robot, &e.to_robot(), &e.chain, 30, seed)?
            .position_rms;
    if let Some(state) = &e.state {
        let data = LimbData::new(&set, &e.chain)?;
        if let Some(errors) = ml::observable_su_errors(
            &robot,
            &gravity_upright(),
            state,
            &data,
            &MlConfig::default(),
            30,
            seed,
        ) {
            outcome.observable = errors.position_rms;
            outcome.bound = errors.position_bound;
            outcome.truth_bound = errors.position_bound_at_truth;
        }
    }
    Ok(outcome)
}

/// `robot`'s training set (structure and `poses` training poses, seed `seed`, the default
/// noise) and 20 other poses within its limits, noise-free, to judge its calibration by.
pub(crate) fn training_and_held_out(
    robot: &Robot,
    seed: u64,
    poses: usize,
) -> Result<(MeasurementSet, MeasurementSet)> {
    let simulation = SimulationConfig {
        seed,
        poses,
        ..SimulationConfig::default()
    };
    let set = sim::simulate(robot, &simulation)?.measurements;
    let held_out = sim::simulate(
        robot,
        &SimulationConfig {
            structure: false,
            pose_seed: Some(1000 + seed),
            imperfections: Imperfections::none(),
            ..simulation
        },
    )?
    .measurements;
    Ok((set, held_out))
}

fn percentile(values: &[f64], q: f64) -> f64 {
    let mut v: Vec<f64> = values.iter().copied().filter(|x| x.is_finite()).collect();
    if v.is_empty() {
        return f64::NAN;
    }
    v.sort_by(f64::total_cmp);
    v[((v.len() - 1) as f64 * q).round() as usize]
}

pub fn bench_limbs(args: BenchLimbsArgs) -> Result<()> {
    if args.json {
        crate::out::json_mode();
    }
    anyhow::ensure!(
        args.dofs.len() == 2 && args.dofs[0] >= 1 && args.dofs[0] <= args.dofs[1],
        "--dofs MIN MAX: give at least 1, fewest first"
    );
    let last = args.first_seed + args.limbs.saturating_sub(1);
    outln!(
        "robot-like limbs, seeds {}…{last}: {}–{} DoFs, 1–{} SUs per segment, limits, P = {} poses within them, uniform ±0.01 g noise, default calibration (bias and scale fitted); held-out: 20 other noise-free poses within the limits\n",
        args.first_seed,
        args.dofs[0],
        args.dofs[1],
        args.sus_per_segment,
        args.poses
    );
    let mut outcomes = Vec::new();
    let bar = crate::out::progress_bar(
        (last + 1).saturating_sub(args.first_seed),
        "bench limbs: limbs",
    );
    for seed in args.first_seed..=last {
        bar.inc(1);
        match run(seed, &args) {
            Ok(o) => {
                if args.each {
                    outln!("seed {seed:>4}  {}", each_line(&o));
                }
                outcomes.push(o)
            }
            Err(e) => outln!("seed {seed}: {e}"),
        }
    }
    bar.finish_and_clear();
    let n = outcomes.len();
    let converged = outcomes.iter().filter(|o| o.converged).count();
    let (table, summary) = summary_table(&outcomes);
    out!("{table}");
    outln!(
        "\nconverged (residual within the noise's band at its size): {converged} of {n} ({:.1} %)",
        100.0 * converged as f64 / n.max(1) as f64
    );
    let within = |bound: fn(&Outcome) -> f64| {
        let ratios: Vec<f64> = outcomes
            .iter()
            .map(|o| o.observable / bound(o))
            .filter(|r| r.is_finite())
            .collect();
        let count = ratios.iter().filter(|&&r| r <= 1.5).count();
        (count, ratios.len())
    };
    let (count, of) = within(|o| o.bound);
    outln!(
        "SU pose error in the directions the readings determine within 1.5× its Cramér–Rao bound: {count} of {of} ({:.1} %)",
        100.0 * count as f64 / of.max(1) as f64
    );
    let (count, of) = within(|o| o.truth_bound);
    outln!(
        "  (the bound at the truth moved along what no reading tells to the estimate; at the truth as given: {count} of {of}, {:.1} %)",
        100.0 * count as f64 / of.max(1) as f64
    );
    let (within_bound, within_truth_bound) = (within(|o| o.bound), within(|o| o.truth_bound));
    crate::out::json(&serde_json::json!({
        "command": "bench limbs",
        "first_seed": args.first_seed,
        "limbs": n,
        "converged": converged,
        "observable_within_1_5_bound": within_bound.0,
        "observable_within_1_5_bound_at_truth": within_truth_bound.0,
        "summary": summary,
        "each": outcomes,
    }));
    not_converged(&outcomes);
    Ok(())
}

/// One limb's line (`--each`).
fn each_line(o: &Outcome) -> String {
    format!(
        "{:<36} {} DoFs {:>2} SUs  residual {:>6.2} σ  static {:.4}  dynamic {:.4}  SU pose {:>8.2} mm  observable {:>7.2} mm  bound {:>7.2} mm  {:.2} s",
        o.name,
        o.dofs,
        o.sus,
        o.residual,
        o.statics,
        o.dynamics,
        o.pose * 1000.0,
        o.observable * 1000.0,
        o.bound * 1000.0,
        o.seconds
    )
}

/// Median, 95th percentile and largest of each figure over the limbs, as a table and as JSON.
fn summary_table(outcomes: &[Outcome]) -> (String, serde_json::Map<String, serde_json::Value>) {
    let col = |f: fn(&Outcome) -> f64| outcomes.iter().map(f).collect::<Vec<f64>>();
    let mut table = String::new();
    let mut summary = serde_json::Map::new();
    let _ = writeln!(
        table,
        "{:<24} {:>10} {:>10} {:>10}",
        "", "median", "95 %", "max"
    );
    let rows: [(&str, Vec<f64>, f64); 7] = [
        ("residual / σ", col(|o| o.residual), 1.0),
        ("held-out static, m/s²", col(|o| o.statics), 1.0),
        ("held-out dynamic, m/s²", col(|o| o.dynamics), 1.0),
        ("SU pose RMS, mm", col(|o| o.pose), 1000.0),
        ("  observable part, mm", col(|o| o.observable), 1000.0),
        ("  / its bound", col(|o| o.observable / o.bound), 1.0),
        ("calibrate, s", col(|o| o.seconds), 1.0),
    ];
    for (name, values, scale) in rows {
        summary.insert(
            name.trim().to_string(),
            serde_json::json!({
                "median": percentile(&values, 0.5) * scale,
                "p95": percentile(&values, 0.95) * scale,
                "max": percentile(&values, 1.0) * scale,
            }),
        );
        let _ = writeln!(
            table,
            "{:<24} {:>10.4} {:>10.4} {:>10.4}",
            name,
            percentile(&values, 0.5) * scale,
            percentile(&values, 0.95) * scale,
            percentile(&values, 1.0) * scale
        );
    }
    (table, summary)
}

/// The limbs that did not converge, with their geometry and why.
fn not_converged(outcomes: &[Outcome]) {
    let failed: Vec<&Outcome> = outcomes.iter().filter(|o| !o.converged).collect();
    if failed.is_empty() {
        return;
    }
    outln!("\nnot converged (geometry: first axis Vertical/Horizontal, then per joint its relation to the previous one — Parallel, Intersecting, Offset, Along the link — and its DoF count):");
    for o in failed {
        outln!(
            "  {:<36} {} DoFs {:>2} SUs  {}",
            o.name,
            o.dofs,
            o.sus,
            o.failure
                .clone()
                .unwrap_or_else(|| format!("residual {:.2} σ", o.residual))
        );
    }
}
