//! `skincal bench body`: the whole pipeline (explore, calibrate every limb, validate on held-out
//! poses) on whole robots — the humanoid, robot descriptions (TOML or URDF) or random trees — with
//! time, memory, convergence and accuracy against the truth.

use std::fmt::Write as _;
use std::time::Instant;

use anyhow::Result;
use clap::Args;
use skincal::estimate::body::calibrate_body;
use skincal::estimate::ml::MlConfig;
use skincal::explore::{explore, ExploreConfig, Structure};
use skincal::io::{self, SuPlacement};
use skincal::model::sensor::STANDARD_GRAVITY;
use skincal::model::Robot;
use skincal::sim::{self, Imperfections, RandomTreeConfig, SimulationConfig};

use crate::out::{out, outln};
use crate::peak_memory_mb;

#[derive(Debug, Args)]
pub struct BenchBodyArgs {
    /// Print the results as JSON (every data set, per robot) instead of the tables.
    #[arg(long)]
    json: bool,
    /// Robots to run: built-in names, TOML descriptions or URDF files (repeat for several; the
    /// humanoid when none is given). Each gets --sus-per-segment random SUs per link, per seed.
    #[arg(long, value_name = "ROBOT", conflicts_with = "random_dofs")]
    robot: Vec<String>,
    /// A random tree with this many DoFs instead of a robot.
    #[arg(long, value_name = "N")]
    random_dofs: Option<usize>,
    /// SUs of the random tree.
    #[arg(long, default_value_t = 200)]
    random_sus: usize,
    /// SUs per skinned segment of a robot (per link of a URDF).
    #[arg(long, default_value_t = 2)]
    sus_per_segment: usize,
    /// Training poses (within each DoF's limits).
    #[arg(long, default_value_t = 20)]
    poses: usize,
    /// Noise (uniform ±G, in g).
    #[arg(long, value_name = "G", default_value_t = 0.01)]
    noise: f64,
    /// Data sets (seeds 1…N).
    #[arg(long, default_value_t = 5)]
    seeds: u64,
    /// Fit each limb on its own only (as `calibrate --limb-by-limb`), not each tree's limbs
    /// together afterwards.
    #[arg(long)]
    limb_by_limb: bool,
}

/// One data set.
#[derive(serde::Serialize)]
struct Run {
    seed: u64,
    dofs: usize,
    sus: usize,
    limbs: usize,
    converged: usize,
    exact: bool,
    explore_s: f64,
    calibrate_s: f64,
    static_rms: f64,
    dynamic_rms: f64,
    /// The limbs that did not converge: their DoFs and residual in σ.
    failed: Vec<(String, f64)>,
}

/// What one robot of the benchmark is.
enum Subject<'a> {
    Robot(&'a str),
    RandomTree(usize),
}

pub fn bench_body(args: BenchBodyArgs) -> Result<()> {
    if args.json {
        crate::out::json_mode();
    }
    let robots: Vec<String> = if args.robot.is_empty() {
        vec!["humanoid".to_string()]
    } else {
        args.robot.clone()
    };
    let subjects: Vec<Subject> = match args.random_dofs {
        Some(d) => vec![Subject::RandomTree(d)],
        None => robots.iter().map(|r| Subject::Robot(r)).collect(),
    };
    let mut summary = Vec::new();
    for subject in &subjects {
        let what = match subject {
            Subject::RandomTree(d) => format!("random trees, {d} DoFs, {} SUs", args.random_sus),
            Subject::Robot(r) => format!("{r}, {} SUs per skinned segment", args.sus_per_segment),
        };
        let fit = if args.limb_by_limb {
            "each limb fitted on its own"
        } else {
            "each tree's limbs fitted together"
        };
        outln!(
            "whole pipeline on {what}; P = {} poses within the limits, uniform ±{} g noise, seeds 1…{}; {fit}; held-out: 20 fresh noise-free poses\n",
            args.poses, args.noise, args.seeds
        );
        let mut runs = Vec::new();
        let bar = crate::out::progress_bar(args.seeds, "bench body: seeds");
        for seed in 1..=args.seeds {
            bar.inc(1);
            let robot = match subject {
                Subject::RandomTree(dofs) => sim::random_tree(
                    &RandomTreeConfig {
                        dofs: *dofs,
                        sus: args.random_sus,
                        ..RandomTreeConfig::default()
                    },
                    seed,
                )?,
                Subject::Robot(spec) => io::load_robot(
                    spec,
                    SuPlacement {
                        per_link: Some(args.sus_per_segment),
                        seed,
                    },
                )?,
            };
            match run(&robot, seed, &args)? {
                Ok(r) => runs.push(r),
                Err(e) => outln!("seed {seed}: {e}"),
            }
        }
        bar.finish_and_clear();
        out!("{}", table(&runs));
        outln!();
        let name = match subject {
            Subject::RandomTree(d) => format!("random tree, {d} DoFs"),
            Subject::Robot(r) => r.to_string(),
        };
        summary.push((name, args.seeds as usize, runs));
    }
    if summary.len() > 1 {
        out!("{}", summary_table(&summary));
    }
    outln!(
        "peak resident memory of the whole run: {:.0} MB",
        peak_memory_mb()
    );
    crate::out::json(&serde_json::json!({
        "command": "bench body",
        "poses": args.poses,
        "uniform_noise_g": args.noise,
        "seeds": args.seeds,
        "subjects": summary.iter().map(|(name, seeds, runs)| serde_json::json!({
            "name": name,
            "seeds": seeds,
            "converged_limbs": runs.iter().map(|r| r.converged).sum::<usize>(),
            "limbs": runs.iter().map(|r| r.limbs).sum::<usize>(),
            "exact_structures": runs.iter().filter(|r| r.exact).count(),
            "runs": runs,
        })).collect::<Vec<_>>(),
        "peak_mb": peak_memory_mb(),
    }));
    Ok(())
}

/// One data set of `robot`: simulate, explore, calibrate, validate on held-out poses. The outer
/// error is the benchmark's own failure; the inner one a calibration that refused the data.
fn run(robot: &Robot, seed: u64, args: &BenchBodyArgs) -> Result<Result<Run, String>> {
    let config = SimulationConfig {
        seed,
        poses: args.poses,
        imperfections: Imperfections {
            uniform_noise: args.noise,
            ..Imperfections::none()
        },
        ..SimulationConfig::default()
    };
    let set = sim::simulate(robot, &config)?.measurements;
    let t0 = Instant::now();
    let structure = explore(&set, &ExploreConfig::default())?;
    let explore_s = t0.elapsed().as_secs_f64();
    let exact = structure_is_exact(robot, &structure);
    let t1 = Instant::now();
    let ml = MlConfig {
        noise_sd: args.noise * STANDARD_GRAVITY / 3f64.sqrt(),
        whole_tree: !args.limb_by_limb,
        ..Default::default()
    };
    let model = match calibrate_body(&set, Some(&structure), &ml, None) {
        Ok(m) => m,
        Err(e) => return Ok(Err(e.to_string())),
    };
    let calibrate_s = t1.elapsed().as_secs_f64();
    let held_out = sim::simulate(
        robot,
        &SimulationConfig {
            seed: seed + 1000,
            structure: false,
            poses: 20,
            imperfections: Imperfections::none(),
            ..SimulationConfig::default()
        },
    )?
    .measurements;
    let check = skincal::predict::validate(&model, &held_out, "held-out")?;
    let failed = model
        .limbs
        .iter()
        .filter(|l| !l.estimate.converged)
        .map(|l| (l.dofs.join(" "), l.estimate.residual_ratio))
        .collect();
    Ok(Ok(Run {
        seed,
        dofs: robot.model.dofs().len(),
        sus: robot.model.sus().len(),
        limbs: model.limbs.len(),
        converged: model.limbs.iter().filter(|l| l.estimate.converged).count(),
        exact,
        explore_s,
        calibrate_s,
        static_rms: check.static_rms,
        dynamic_rms: check.dynamic_rms,
        failed,
    }))
}

/// Whether the structure places every SU of `truth` after exactly the DoFs that move it.
pub(crate) fn structure_is_exact(truth: &Robot, s: &Structure) -> bool {
    let m = &truth.model;
    // Mimic DoFs and their leaders drive bodies that explore sets aside by design: an SU or DoF
    // behind one may stay unplaced, and a follower stands for its leader.
    let coupled = |d: usize| m.is_follower(d) || !m.followers_of(d).is_empty();
    let unplaced_sus = s.unplaced_sus.iter().all(|su| {
        m.su_index(su)
            .is_some_and(|u| m.chain_to(m.sus()[u].segment).into_iter().any(&coupled))
    });
    let unplaced_dofs = s
        .unplaced_dofs
        .iter()
        .all(|d| m.dof_index(d).is_some_and(&coupled));
    unplaced_sus
        && unplaced_dofs
        && s.segments.iter().all(|segment| {
            let mut found: Vec<String> = Vec::new();
            let mut current = segment;
            while let Some(j) = &current.parent_joint {
                let joint = s.joint(j).expect("parent joints exist");
                found.extend(joint.dofs.iter().cloned());
                current = s.segment(&joint.parent).expect("parents exist");
            }
            found.sort();
            segment.sus.iter().all(|su| {
                let Some(u) = m.su_index(su) else {
                    return false;
                };
                let mut expected: Vec<String> = m
                    .chain_to(m.sus()[u].segment)
                    .into_iter()
                    .map(|d| {
                        m.dofs()[m.dofs()[d].mimic.map_or(d, |x| x.leader)]
                            .name
                            .clone()
                    })
                    .collect();
                expected.sort();
                expected.dedup();
                expected == found
            })
        })
}

fn rms(values: impl Iterator<Item = f64>) -> f64 {
    let (sum, n) = values.fold((0.0, 0usize), |(s, n), v| (s + v * v, n + 1));
    if n == 0 {
        0.0
    } else {
        (sum / n as f64).sqrt()
    }
}

fn table(runs: &[Run]) -> String {
    let mut out = String::new();
    let _ = writeln!(
        out,
        "{:>5} {:>5} {:>5} {:>6} {:>10} {:>10} {:>11} {:>13} {:>13} {:>14}",
        "seed",
        "DoFs",
        "SUs",
        "exact",
        "converged",
        "explore ms",
        "calibrate s",
        "total s",
        "static m/s²",
        "dynamic m/s²"
    );
    for r in runs {
        let _ = writeln!(
            out,
            "{:>5} {:>5} {:>5} {:>6} {:>10} {:>10.1} {:>11.3} {:>13.3} {:>13.4} {:>14.4}",
            r.seed,
            r.dofs,
            r.sus,
            if r.exact { "yes" } else { "NO" },
            format!("{}/{}", r.converged, r.limbs),
            r.explore_s * 1e3,
            r.calibrate_s,
            r.explore_s + r.calibrate_s,
            r.static_rms,
            r.dynamic_rms
        );
    }
    if runs.is_empty() {
        return out;
    }
    let mut totals: Vec<f64> = runs.iter().map(|r| r.explore_s + r.calibrate_s).collect();
    totals.sort_by(f64::total_cmp);
    let _ = writeln!(
        out,
        "all: structure exact {}/{}, median pipeline {:.3} s, held-out RMS static {:.4} m/s², dynamic {:.4} m/s²",
        runs.iter().filter(|r| r.exact).count(),
        runs.len(),
        totals[totals.len() / 2],
        rms(runs.iter().map(|r| r.static_rms)),
        rms(runs.iter().map(|r| r.dynamic_rms))
    );
    for r in runs {
        for (dofs, ratio) in &r.failed {
            let _ = writeln!(
                out,
                "  seed {}: limb ({dofs}) NOT CONVERGED at {ratio:.2} σ",
                r.seed
            );
        }
    }
    out
}

/// One line per robot: `(name, seeds asked, runs done)`.
fn summary_table(summary: &[(String, usize, Vec<Run>)]) -> String {
    let mut out = String::new();
    let _ = writeln!(
        out,
        "{:<40} {:>6} {:>11} {:>12} {:>16} {:>17}",
        "robot", "runs", "tree exact", "limbs conv.", "static m/s² max", "dynamic m/s² max"
    );
    for (name, seeds, runs) in summary {
        let limbs: usize = runs.iter().map(|r| r.limbs).sum();
        let converged: usize = runs.iter().map(|r| r.converged).sum();
        let worst = |f: &dyn Fn(&Run) -> f64| runs.iter().map(f).fold(0.0, f64::max);
        let name = std::path::Path::new(name)
            .file_name()
            .map_or(name.clone(), |n| n.to_string_lossy().into_owned());
        let _ = writeln!(
            out,
            "{:<40} {:>6} {:>11} {:>12} {:>16.4} {:>17.4}",
            name,
            format!("{}/{}", runs.len(), seeds),
            format!("{}/{}", runs.iter().filter(|r| r.exact).count(), runs.len()),
            format!("{converged}/{limbs}"),
            worst(&|r| r.static_rms),
            worst(&|r| r.dynamic_rms)
        );
    }
    out
}
