//! `skincal bench sensors`: the whole pipeline on real sensors and imperfect skins (intrinsics,
//! glitches, broken SUs, a skin with gaps) against the same seed's clean data.

use std::fmt::Write as _;

use anyhow::Result;
use clap::Args;
use skincal::estimate::body::{calibrate_body, BodyModel};
use skincal::estimate::ml::MlConfig;
use skincal::explore::{explore, ExploreConfig, Structure};
use skincal::io::{self, SuPlacement};
use skincal::model::Robot;
use skincal::sim::{self, Fault, Imperfections, SimulationConfig, SuFault};

use crate::out::{out, outln};

#[derive(Debug, Args)]
pub struct BenchSensorsArgs {
    /// Print the results as JSON (per scenario) instead of the table.
    #[arg(long)]
    json: bool,
    /// A built-in robot, a .toml description or a .urdf file.
    #[arg(long, default_value = "humanoid")]
    robot: String,
    /// Data seeds 1…N.
    #[arg(long, default_value_t = 8)]
    seeds: u64,
}

/// One scenario's figures over the seeds.
#[derive(Default)]
struct Tally {
    runs: usize,
    exact: usize,
    set_aside: usize,
    limbs: usize,
    converged: usize,
    /// Per seed, the ratios to the clean run: SU pose RMS, held-out static, dynamic.
    ratios: [Vec<f64>; 3],
    /// The largest of those ratios.
    worst: [f64; 3],
}

/// What a run gives: SU pose RMS against the truth (m), held-out static and dynamic RMS (m/s²) of
/// the SUs every run calibrates, and the structure.
struct Run {
    pose: f64,
    statics: f64,
    dynamics: f64,
    model: BodyModel,
    structure: Structure,
    set: skincal::measurements::MeasurementSet,
}

fn run(
    robot: &Robot,
    config: &SimulationConfig,
    held_out: &skincal::measurements::MeasurementSet,
    ignore: &[String],
) -> Result<Run> {
    let set = sim::simulate(robot, config)?.measurements;
    let structure = explore(&set, &ExploreConfig::default())?;
    let model = calibrate_body(&set, Some(&structure), &MlConfig::default(), None)?;
    let (mut pose, mut pairs) = (0.0, 0usize);
    for limb in &model.limbs {
        let e = &limb.estimate;
        let a = skincal::estimate::consecutive_su_errors(robot, &e.to_robot(), &e.chain, 30, 1)?;
        let n = e.chain.sus().len().saturating_sub(2);
        pose += a.position_rms.powi(2) * n as f64;
        pairs += n;
    }
    let check = skincal::predict::validate(&model, held_out, "held-out")?;
    let kept: Vec<_> = check
        .sus
        .iter()
        .filter(|e| !ignore.contains(&e.su))
        .collect();
    let n = kept.len().max(1) as f64;
    let rms = |f: fn(&skincal::predict::SuError) -> f64| {
        (kept.iter().map(|e| f(e).powi(2)).sum::<f64>() / n).sqrt()
    };
    Ok(Run {
        pose: (pose / pairs.max(1) as f64).sqrt(),
        statics: rms(|e| e.static_rms),
        dynamics: rms(|e| e.dynamic_rms),
        model,
        structure,
        set,
    })
}

fn sorted(v: &[String]) -> Vec<String> {
    let mut v = v.to_vec();
    v.sort();
    v
}

/// The joints as sorted DoF sets, and every placed SU's segment as its sorted SU set.
fn shape(s: &Structure) -> (Vec<Vec<String>>, Vec<Vec<String>>) {
    let mut joints: Vec<Vec<String>> = s.joints.iter().map(|j| sorted(&j.dofs)).collect();
    joints.sort();
    let mut segments: Vec<Vec<String>> = s.segments.iter().map(|g| sorted(&g.sus)).collect();
    segments.sort();
    (joints, segments)
}

/// The tree of `s` is the one the clean readings give without the SUs `s` set aside (leaving an
/// SU out can merge the joints on either side of its segment).
fn same_tree(clean: &skincal::measurements::MeasurementSet, s: &Structure) -> Result<bool> {
    let expected = explore(
        &clean.without_sus(&s.unplaced_sus),
        &ExploreConfig::default(),
    )?;
    Ok(sorted(&s.unplaced_dofs) == sorted(&expected.unplaced_dofs) && shape(s) == shape(&expected))
}

pub fn bench_sensors(args: BenchSensorsArgs) -> Result<()> {
    if args.json {
        crate::out::json_mode();
    }
    let robot = io::load_robot(&args.robot, SuPlacement::default())?;
    let broken = broken_sus(&robot.model.su_names());
    let broken_names: Vec<String> = broken.iter().map(|f| f.su.clone()).collect();
    outln!(
        "{} on real sensors, seeds 1…{}; P = 20, uniform ±0.01 g noise; every scenario against the same seed without it: SU pose RMS (relative to the previous SU, against the truth), held-out prediction of the same skin (20 other noise-free poses), static and dynamic RMS\n",
        args.robot, args.seeds
    );
    let scenarios = scenarios(broken);
    let mut tallies: Vec<Tally> = scenarios.iter().map(|_| Tally::default()).collect();
    let mut named = 0;
    let bar = crate::out::progress_bar(args.seeds, "bench sensors: seeds");
    for seed in 1..=args.seeds {
        bar.inc(1);
        named += one_seed(&robot, seed, &scenarios, &broken_names, &mut tallies)?;
    }
    bar.finish_and_clear();
    out!("{}", table(&scenarios, &tallies));
    if !broken_names.is_empty() {
        outln!(
            "\nbroken SUs ({}) named with the right fault: {named} of {}",
            broken_names.join(", "),
            broken_names.len() * args.seeds as usize
        );
    }
    outln!("(tree exact: the tree the clean readings give without the SUs set aside, which explore names with the reason; ratios: median over seeds, worst in brackets; the broken-SU scenario compares the other SUs only)");
    crate::out::json(&summary(
        &args,
        &scenarios,
        &tallies,
        named,
        broken_names.len(),
    ));
    Ok(())
}

/// Four broken SUs, on different limbs where the robot has them (the humanoid's).
fn broken_sus(names: &[String]) -> Vec<SuFault> {
    [
        ("l_forearm_side", Fault::Dead),
        ("r_thigh_back", Fault::Frozen),
        ("head_top", Fault::Railed),
        ("l_shank_front", Fault::SwapXy),
    ]
    .into_iter()
    .filter(|(su, _)| names.iter().any(|n| n == su))
    .map(|(su, fault)| SuFault {
        su: su.into(),
        fault,
    })
    .collect()
}

/// The scenarios: biased and mis-scaled sensors, glitches, and `broken` SUs (when there are any).
fn scenarios(broken: Vec<SuFault>) -> Vec<Scenario> {
    let none_broken = broken.is_empty();
    let mut scenarios: Vec<Scenario> = vec![
        (
            "bias ±0.06 g, scale ±3 %",
            Box::new(|c: &mut SimulationConfig| {
                c.imperfections.bias = 0.06;
                c.imperfections.scale = 0.03;
            }),
        ),
        (
            "1 % glitches (0.2–1.5 g)",
            Box::new(|c: &mut SimulationConfig| c.imperfections.glitches = 0.01),
        ),
        (
            "4 broken SUs",
            Box::new(move |c: &mut SimulationConfig| c.faults = broken.clone()),
        ),
    ];
    if none_broken {
        scenarios.pop();
    }
    scenarios
}

/// Every scenario on `seed` against the same seed without it, added to `tallies`; returns how
/// many broken SUs were named with the right fault.
fn one_seed(
    robot: &Robot,
    seed: u64,
    scenarios: &[Scenario],
    broken_names: &[String],
    tallies: &mut [Tally],
) -> Result<usize> {
    let mut named = 0;
    let clean_config = SimulationConfig {
        seed,
        ..SimulationConfig::default()
    };
    // The same skin in other poses, noise-free: its intrinsics, no glitch, no fault.
    let held_out = |c: &SimulationConfig| -> Result<_> {
        let mut held = c.clone();
        held.structure = false;
        held.pose_seed = Some(1000 + seed);
        held.faults.clear();
        held.imperfections = Imperfections {
            uniform_noise: 0.0,
            glitches: 0.0,
            ..c.imperfections
        };
        Ok(sim::simulate(robot, &held)?.measurements)
    };
    for (i, (name, apply)) in scenarios.iter().enumerate() {
        let mut config = clean_config.clone();
        apply(&mut config);
        let ignore = if config.faults.is_empty() {
            Vec::new()
        } else {
            broken_names.to_vec()
        };
        let clean = run(robot, &clean_config, &held_out(&clean_config)?, &ignore)?;
        let r = match run(robot, &config, &held_out(&config)?, &ignore) {
            Ok(r) => r,
            Err(e) => {
                outln!("seed {seed}, {name}: {e}");
                continue;
            }
        };
        tallies[i].add(&clean, &r)?;
        named += named_faults(&config.faults, &r.model);
    }
    Ok(named)
}

/// The JSON summary: per scenario its tallies, and the broken SUs named of `broken` per seed.
fn summary(
    args: &BenchSensorsArgs,
    scenarios: &[Scenario],
    tallies: &[Tally],
    named: usize,
    broken: usize,
) -> serde_json::Value {
    serde_json::json!({
        "command": "bench sensors",
        "robot": args.robot,
        "seeds": args.seeds,
        "scenarios": scenarios.iter().zip(tallies).map(|((name, _), t)| {
            let ratio = |k: usize| serde_json::json!({
                "median": median(&t.ratios[k]),
                "worst": t.worst[k],
            });
            serde_json::json!({
                "scenario": name,
                "runs": t.runs,
                "tree_exact": t.exact,
                "set_aside": t.set_aside,
                "limbs": t.limbs,
                "converged_limbs": t.converged,
                "pose_rms_ratio": ratio(0),
                "static_ratio": ratio(1),
                "dynamic_ratio": ratio(2),
            })
        }).collect::<Vec<_>>(),
        "broken_named": named,
        "broken": broken * args.seeds as usize,
    })
}

/// The median of `values` (NaN when empty).
fn median(values: &[f64]) -> f64 {
    let mut v = values.to_vec();
    v.sort_by(f64::total_cmp);
    v.get(v.len() / 2).copied().unwrap_or(f64::NAN)
}

impl Tally {
    /// Adds one seed's run `r` against the same seed's `clean` run.
    fn add(&mut self, clean: &Run, r: &Run) -> Result<()> {
        self.runs += 1;
        self.exact += usize::from(same_tree(&clean.set, &r.structure)?);
        self.set_aside += r.structure.unplaced_sus.len();
        self.limbs += r.model.limbs.len();
        self.converged += r
            .model
            .limbs
            .iter()
            .filter(|l| l.estimate.converged)
            .count();
        let ratios = [
            r.pose / clean.pose,
            r.statics / clean.statics,
            r.dynamics / clean.dynamics,
        ];
        for (k, ratio) in ratios.iter().enumerate() {
            self.ratios[k].push(*ratio);
            self.worst[k] = self.worst[k].max(*ratio);
        }
        Ok(())
    }
}

/// How many of the broken SUs `faults` the model names with the right fault.
fn named_faults(faults: &[SuFault], model: &BodyModel) -> usize {
    faults
        .iter()
        .filter(|f| {
            let kind = match f.fault {
                Fault::Dead => "dead",
                Fault::Frozen => "frozen",
                Fault::Railed => "railed",
                Fault::SwapXy | Fault::NegateZ => "improper frame",
            };
            model
                .not_calibrated
                .iter()
                .any(|n| n.name == f.su && n.reason.starts_with(&format!("broken ({kind})")))
        })
        .count()
}

type Scenario = (&'static str, Box<dyn Fn(&mut SimulationConfig)>);

fn table(scenarios: &[Scenario], tallies: &[Tally]) -> String {
    let mut table = String::new();
    let _ = writeln!(
        table,
        "{:<28} {:>6} {:>10} {:>10} {:>12} {:>16} {:>16} {:>16}",
        "scenario",
        "runs",
        "tree exact",
        "set aside",
        "limbs conv.",
        "pose RMS ratio",
        "static ratio",
        "dynamic ratio"
    );
    for ((name, _), t) in scenarios.iter().zip(tallies) {
        let ratio = |k: usize| format!("{:.2} (≤ {:.2})", median(&t.ratios[k]), t.worst[k]);
        let _ = writeln!(
            table,
            "{:<28} {:>6} {:>10} {:>10} {:>12} {:>16} {:>16} {:>16}",
            name,
            t.runs,
            format!("{}/{}", t.exact, t.runs),
            t.set_aside,
            format!("{}/{}", t.converged, t.limbs),
            ratio(0),
            ratio(1),
            ratio(2)
        );
    }
    table
}
