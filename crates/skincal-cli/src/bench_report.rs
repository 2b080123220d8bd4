//! `skincal bench report`: the HTML report of a calibrated random tree, timed.

use anyhow::Result;
use clap::Args;
use skincal::explore::ExploreConfig;
use skincal::sim::{self, SimulationConfig};

use crate::out::{self, out, outln};
use crate::render;

#[derive(Debug, Args)]
pub struct BenchReportArgs {
    /// Print the table as JSON instead of text.
    #[arg(long)]
    json: bool,
    /// Number of SUs of the random robot.
    #[arg(long, default_value_t = 2000)]
    sus: usize,
    /// Number of DoFs of the random robot.
    #[arg(long, default_value_t = 60)]
    dofs: usize,
    /// Timed repetitions.
    #[arg(long, default_value_t = 5)]
    repeat: usize,
    /// Seed of the robot and the simulation.
    #[arg(long, default_value_t = 1)]
    seed: u64,
    /// Also write the page here (to open it in a browser).
    #[arg(long)]
    out: Option<std::path::PathBuf>,
}

pub fn bench_report(args: BenchReportArgs) -> Result<()> {
    use std::time::Instant;
    if args.json {
        out::json_mode();
    }
    let robot = crate::random_robot(args.dofs, args.sus, args.seed)?;
    let config = SimulationConfig {
        seed: args.seed,
        ..SimulationConfig::default()
    };
    let set = sim::simulate(&robot, &config)?.measurements;
    let held_out = sim::simulate(
        &robot,
        &SimulationConfig {
            structure: false,
            pose_seed: Some(args.seed + 1000),
            ..config.clone()
        },
    )?
    .measurements;
    let structure = skincal::explore::explore(&set, &ExploreConfig::default())?;
    let model = skincal::estimate::body::calibrate_body(
        &set,
        Some(&structure),
        &skincal::estimate::ml::MlConfig::default(),
        None,
    )?;
    let check = skincal::predict::validate(&model, &held_out, "held-out")?;
    let inputs = skincal::html::ReportInputs {
        title: format!("random tree, {} DoFs, {} SUs", args.dofs, args.sus),
        measurements: Some(set),
        structure: Some(structure),
        model: Some(model),
        validation: Some((check, "held-out".into())),
        urdf_check: None,
        urdf_su_frames: Default::default(),
        check: None,
        ingest: None,
        truth: Some(robot),
        paper: Vec::new(),
    };
    let mut ms = Vec::new();
    let mut page = String::new();
    for _ in 0..args.repeat.max(1) {
        let t = Instant::now();
        page = skincal::html::render(&inputs);
        ms.push(t.elapsed().as_secs_f64() * 1e3);
    }
    let size = page.len();
    if let Some(path) = &args.out {
        skincal::io::write_all(&[(path.clone(), &page)], true)?;
    }
    outln!(
        "HTML report of a random tree: {} DoFs, {} SUs, calibrated and checked on held-out poses (untimed), with the truth (pose errors and their bound per limb, limbs in parallel); {} repetitions\n",
        args.dofs, args.sus, ms.len()
    );
    out!(
        "{}",
        render::timing_table(&[("render report.html", ms.clone())])
    );
    outln!("page size: {:.2} MB", size as f64 / 1e6);
    out::json(&serde_json::json!({
        "command": "bench report",
        "dofs": args.dofs,
        "sus": args.sus,
        "milliseconds": ms,
        "bytes": size,
        "wrote": args.out.as_ref().map(|p| p.display().to_string()),
    }));
    Ok(())
}
