//! `skincal bench chain`: the cost of one long serial chain ([`sim::snake`]) as it grows: time,
//! LM iterations and held-out accuracy of its calibration, one SU per segment.

use std::time::Instant;

use anyhow::{Context, Result};
use clap::Args;
use skincal::estimate::body::calibrate_body;
use skincal::estimate::ml::MlConfig;
use skincal::explore::{explore, ExploreConfig};
use skincal::sim;

use crate::out::outln;

#[derive(Debug, Args)]
pub struct BenchChainArgs {
    /// Print the results as one JSON document instead of the table.
    #[arg(long)]
    json: bool,
    /// The chains' DoF counts.
    #[arg(long, value_delimiter = ',', default_values_t = [15, 30, 60])]
    dofs: Vec<usize>,
    /// Seed of the chains' geometry and of the noise.
    #[arg(long, default_value_t = 1)]
    seed: u64,
    /// Training poses P.
    #[arg(long, default_value_t = 20)]
    poses: usize,
}

/// One chain's outcome.
#[derive(serde::Serialize)]
struct Outcome {
    dofs: usize,
    seconds: f64,
    iterations: usize,
    residual: f64,
    converged: bool,
    statics: f64,
    dynamics: f64,
}

fn run(dofs: usize, args: &BenchChainArgs) -> Result<Outcome> {
    let robot = sim::snake(dofs, args.seed)?;
    let (set, held_out) = crate::bench_limbs::training_and_held_out(&robot, args.seed, args.poses)?;
    let structure = explore(&set, &ExploreConfig::default())?;
    let start = Instant::now();
    let model = calibrate_body(&set, Some(&structure), &MlConfig::default(), None)?;
    let seconds = start.elapsed().as_secs_f64();
    let limb = model
        .limbs
        .first()
        .with_context(|| format!("the {dofs}-DoF snake gave no limb"))?;
    let check = skincal::predict::validate(&model, &held_out, "held-out")?;
    Ok(Outcome {
        dofs,
        seconds,
        iterations: limb.estimate.iterations,
        residual: limb.estimate.residual_ratio,
        converged: limb.estimate.converged,
        statics: check.static_rms,
        dynamics: check.dynamic_rms,
    })
}

pub fn bench_chain(args: BenchChainArgs) -> Result<()> {
    if args.json {
        crate::out::json_mode();
    }
    anyhow::ensure!(
        !args.dofs.is_empty() && args.dofs.iter().all(|&n| n >= 1),
        "--dofs: give chain lengths of at least 1, e.g. 15,30,60"
    );
    outln!(
        "snakes (seed {}): revolute DoFs in a row, axes a quarter turn apart, links 8–12 cm, one SU per segment; P = {} poses, uniform ±0.01 g noise, default calibration; held-out: 20 other noise-free poses\n",
        args.seed,
        args.poses
    );
    outln!(
        "{:>5} {:>12} {:>8} {:>10} {:>10} {:>14} {:>15}",
        "DoFs",
        "calibrate s",
        "growth",
        "LM its",
        "residual/σ",
        "held-out stat",
        "held-out dyn"
    );
    let mut outcomes: Vec<Outcome> = Vec::new();
    for &dofs in &args.dofs {
        let o = run(dofs, &args)?;
        // The exponent of the time's growth with the DoFs since the chain before.
        let growth = outcomes
            .last()
            .filter(|p| p.dofs != o.dofs && p.seconds > 0.0)
            .map(|p| (o.seconds / p.seconds).ln() / (o.dofs as f64 / p.dofs as f64).ln())
            .map_or("".to_string(), |g| format!("n^{g:.1}"));
        outln!(
            "{:>5} {:>12.2} {:>8} {:>10} {:>9.3}{} {:>14.4} {:>15.4}",
            o.dofs,
            o.seconds,
            growth,
            o.iterations,
            o.residual,
            if o.converged { " " } else { "!" },
            o.statics,
            o.dynamics
        );
        outcomes.push(o);
    }
    outln!("\n(! not converged; static and dynamic held-out RMS in m/s²)");
    let memory = crate::peak_memory_mb();
    outln!("peak resident memory of the whole run: {memory:.0} MB");
    crate::out::json(&serde_json::json!({
        "seed": args.seed,
        "poses": args.poses,
        "chains": outcomes,
        "peak_memory_mb": memory,
    }));
    Ok(())
}
