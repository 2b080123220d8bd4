//! `skincal simulate`: a simulated measurement set with its ground truth.

use std::path::PathBuf;

use anyhow::{Context, Result};
use clap::Args;
use skincal::io::{self, SuPlacement};
use skincal::model::sensor::ExcitationPattern;
use skincal::sim::{self, Imperfections, SimulationConfig};

use crate::out::{self, out, outln};
use crate::render;

#[derive(Debug, Args)]
pub(crate) struct SimulateArgs {
    /// A built-in robot (see `skincal robots`), a .toml description or a .urdf file.
    #[arg(long)]
    robot: String,
    /// Output directory.
    #[arg(long)]
    out: PathBuf,
    /// Overwrite existing output files.
    #[arg(long)]
    force: bool,
    /// Place K random SUs per segment (per link for a URDF) instead of the described ones.
    #[arg(long, value_name = "K")]
    sus_per_link: Option<usize>,
    /// Number of random training poses P.
    #[arg(long, default_value_t = 20)]
    poses: usize,
    /// Half-range of the random training poses, rad (clipped to each DoF's limits).
    #[arg(long, default_value_t = 2.62)]
    pose_range: f64,
    /// How far each DoF moves in the structure experiment, rad.
    #[arg(long, default_value_t = 0.3)]
    structure_angle: f64,
    /// Record the structure experiment in the upright orientation only (no 90° tilt).
    #[arg(long)]
    no_tilt: bool,
    /// Also record N training poses with the reference segment tilted 90° about x (base
    /// orientation 1): they tell how SUs turn about a vertical first axis.
    #[arg(long, value_name = "N", default_value_t = 0)]
    tilted_poses: usize,
    /// Excitation pattern velocity amplitude A, rad/s.
    #[arg(long, default_value_t = 0.5)]
    amplitude: f64,
    /// Excitation pattern frequency f, Hz.
    #[arg(long, default_value_t = 2.0)]
    frequency: f64,
    /// Uniform noise ±G on every reading component, in g.
    #[arg(long, value_name = "G", default_value_t = 0.01)]
    noise: f64,
    /// Gaussian noise with standard deviation G on every component, in g.
    #[arg(long, value_name = "G", default_value_t = 0.0)]
    gaussian_noise: f64,
    /// Constant bias per SU and axis, uniform in ±G, in g.
    #[arg(long, value_name = "G", default_value_t = 0.0)]
    bias: f64,
    /// Scale (sensitivity) error per SU and axis, uniform in ±F (0.03: ±3 %).
    #[arg(long, value_name = "F", default_value_t = 0.0)]
    scale: f64,
    /// Misalignment of each SU's axes (3 angles), uniform in ±DEG, in degrees.
    #[arg(long, value_name = "DEG", default_value_t = 0.0)]
    misalignment: f64,
    /// Replace this fraction of all readings by glitches: random vectors of 0.2–1.5 g.
    #[arg(long, value_name = "FRACTION", default_value_t = 0.0)]
    glitches: f64,
    /// Break an SU: SU=dead|frozen|railed|swap-xy|negate-z (repeat for several).
    #[arg(long, value_name = "SU=FAULT")]
    broken: Vec<String>,
    /// Saturate every axis at ±G, in g.
    #[arg(long, value_name = "G")]
    saturation: Option<f64>,
    /// Quantise like the BMA150: 10 bit over ±2 g.
    #[arg(long)]
    bma150: bool,
    /// Seed of every random choice (poses, noise, sensor intrinsics, random SUs).
    #[arg(long, default_value_t = 1)]
    seed: u64,
    /// Draw the training poses and the noise from this seed instead: the same skin (SU placement
    /// and intrinsics from --seed) recorded again, e.g. as a held-out set for `validate`.
    #[arg(long, value_name = "SEED")]
    pose_seed: Option<u64>,
    /// Print one JSON document (what was written and the result's figures) instead of text.
    #[arg(long)]
    json: bool,
}

/// `SU=FAULT` → a broken SU of the simulation.
fn parse_fault(text: &str) -> Result<sim::SuFault> {
    let names: Vec<&str> = sim::Fault::ALL.iter().map(|f| f.name()).collect();
    let (su, fault) = text.split_once('=').ok_or_else(|| {
        anyhow::anyhow!(
            "--broken `{text}`: expected SU=FAULT, FAULT one of {}",
            names.join(", ")
        )
    })?;
    let fault = sim::Fault::ALL
        .into_iter()
        .find(|f| f.name() == fault)
        .ok_or_else(|| {
            anyhow::anyhow!(
                "--broken `{text}`: unknown fault `{fault}`; use one of {}",
                names.join(", ")
            )
        })?;
    Ok(sim::SuFault {
        su: su.to_string(),
        fault,
    })
}

pub(crate) fn simulate(args: SimulateArgs) -> Result<()> {
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
    let mut imperfections = Imperfections {
        uniform_noise: args.noise,
        gaussian_noise: args.gaussian_noise,
        bias: args.bias,
        scale: args.scale,
        misalignment: args.misalignment.to_radians(),
        glitches: args.glitches,
        saturation: args.saturation,
        quantization_bits: None,
    };
    if args.bma150 {
        imperfections = Imperfections {
            saturation: args.saturation.or(Some(2.0)),
            ..imperfections.with_bma150()
        };
    }
    let config = SimulationConfig {
        poses: args.poses,
        pose_range: args.pose_range,
        structure_angle: args.structure_angle,
        tilted_orientation: !args.no_tilt,
        tilted_poses: args.tilted_poses,
        pattern: ExcitationPattern {
            amplitude: args.amplitude,
            frequency: args.frequency,
        },
        imperfections,
        seed: args.seed,
        pose_seed: args.pose_seed,
        faults: args
            .broken
            .iter()
            .map(|b| parse_fault(b))
            .collect::<Result<_>>()?,
        ..SimulationConfig::default()
    };
    let files = write_simulation(&robot, &config, &args.out, args.force)?;
    out!("{}", files.1);
    for f in &files.0 {
        outln!("wrote {}", f.display());
    }
    out::json(&serde_json::json!({
        "wrote": files.0.iter().map(|f| f.display().to_string()).collect::<Vec<_>>(),
        "robot": robot.model.name(),
        "dofs": robot.model.dofs().len(),
        "sus": robot.model.sus().len(),
        "training_poses": config.poses,
    }));
    Ok(())
}

/// Simulates and writes `measurements.json` and `truth.json`; returns the paths and a summary.
pub(crate) fn write_simulation(
    robot: &skincal::model::Robot,
    config: &SimulationConfig,
    out: &std::path::Path,
    force: bool,
) -> Result<(Vec<PathBuf>, String)> {
    let simulation = sim::simulate(robot, config).context("invalid simulation setting")?;
    let measurements = out.join("measurements.json");
    let truth = out.join("truth.json");
    let truth_json = serde_json::to_string_pretty(&simulation.truth)?;
    io::write_all(
        &[
            (measurements.clone(), simulation.measurements.to_json()),
            (truth.clone(), truth_json),
        ],
        force,
    )?;
    let summary = render::simulation_summary(robot, config, &simulation.measurements.summary());
    Ok((vec![measurements, truth], summary))
}
