//! `skincal bench calibrate`: the estimators on the paper's arm (or random DH chains) over many
//! noise seeds, against the truth and the Cramér–Rao bound.

use anyhow::Result;
use clap::Args;
use skincal::estimate::paper::PaperConfig;
use skincal::estimate::{self, LimbChain, LimbData};
use skincal::io::{self, SuPlacement};
use skincal::sim::{self, Imperfections, SimulationConfig};

use crate::out::{self, out, outln};
use crate::{render, IntrinsicsArg, Method};

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
pub(crate) struct BenchCalibrateArgs {
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

pub(crate) fn bench_calibrate(args: BenchCalibrateArgs) -> Result<()> {
    if args.json {
        out::json_mode();
    }
    use skincal::estimate::ml;
    let paper = io::load_robot("paper-7dof", SuPlacement::default())?;
    let chain = LimbChain::serial("S7", &paper.model.dof_names(), &paper.model.su_names())?;
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
        let data = LimbData::new(&set, &chain)?;
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
    data: &LimbData,
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
            let e = ml::estimate_limb(
                data,
                None,
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
