//! `skincal demo`: the whole pipeline on the built-in humanoid, written to one directory with its
//! report.

use std::path::{Path, PathBuf};

use anyhow::{Context, Result};
use clap::Args;
use skincal::estimate;
use skincal::explore::ExploreConfig;
use skincal::io::{self, SuPlacement};
use skincal::report;
use skincal::sim::{Imperfections, SimulationConfig};

use crate::out::{self, out, outln};
use crate::simulate::write_simulation;
use crate::{render, urdf};

#[derive(Debug, Args)]
pub(crate) struct DemoArgs {
    /// Where to write the demo's files [default: skincal-demo in the system's temporary directory].
    #[arg(long)]
    out: Option<PathBuf>,
    /// Seed of every random choice.
    #[arg(long, default_value_t = 1)]
    seed: u64,
    /// Write into --out even if it holds files that demo did not make.
    #[arg(long)]
    force: bool,
    /// Print one JSON document (what was written and the result's figures) instead of text.
    #[arg(long)]
    json: bool,
}

/// The demo's table against the truth: per limb, SU pose errors and held-out errors.
fn demo_rows(
    robot: &skincal::model::Robot,
    model: &skincal::estimate::body::BodyModel,
    check: &skincal::predict::Validation,
) -> Result<Vec<render::LimbRow>> {
    model
        .limbs
        .iter()
        .map(|limb| {
            let e = &limb.estimate;
            let accuracy = estimate::consecutive_su_errors(robot, &e.to_robot(), &e.chain, 30, 1)?;
            Ok(render::LimbRow::new(
                &limb.name,
                limb.dofs.len(),
                &limb.sus,
                e.converged,
                Some(&accuracy),
                check,
            ))
        })
        .chain(std::iter::once(Ok(render::LimbRow::new(
            &format!("{} (static)", model.reference),
            0,
            &model
                .static_sus
                .iter()
                .map(|s| s.su.clone())
                .collect::<Vec<_>>(),
            true,
            None,
            check,
        ))))
        .collect::<Result<Vec<_>>>()
}

/// Makes the demo's directory: it replaces its own directory on every run, and nothing else.
fn prepare_demo_dir(out: &Path, force: bool) -> Result<()> {
    // A directory it marked, or one that holds only the files a demo writes.
    let marker = out.join(".skincal-demo");
    const DEMO_FILES: [&str; 11] = [
        ".skincal-demo",
        "measurements.json",
        "truth.json",
        "structure.json",
        "structure.dot",
        "model.json",
        "model.urdf",
        "held-out",
        "humanoid.urdf",
        "humanoid-skin.urdf",
        "report.html",
    ];
    let holds_other_files = std::fs::read_dir(out).is_ok_and(|entries| {
        entries
            .filter_map(Result::ok)
            .any(|e| !DEMO_FILES.contains(&e.file_name().to_string_lossy().as_ref()))
    });
    if holds_other_files && !marker.exists() && !force {
        anyhow::bail!(
            "{} holds files that skincal demo did not make: choose another --out, or pass --force to overwrite them",
            out.display()
        );
    }
    std::fs::create_dir_all(out).with_context(|| format!("cannot create {}", out.display()))?;
    std::fs::write(
        &marker,
        "made by skincal demo, which replaces this directory's files on every run\n",
    )
    .with_context(|| format!("cannot write {}", marker.display()))?;
    Ok(())
}

/// A limb's line in the demo: its size, cost, residual and the DoF orders found.
fn demo_limb_line(limb: &skincal::estimate::body::BodyLimb) -> String {
    let orders: Vec<String> = limb
        .estimate
        .joint_orders
        .iter()
        .map(|o| format!("{} = {}", o.joint, o.dofs.join(" → ")))
        .collect();
    format!(
        "limb {:<4} {} DoFs, {} SUs, {} LM iterations in {:.1} ms, residual {:.3}× σ{}",
        limb.name,
        limb.dofs.len(),
        limb.sus.len(),
        limb.estimate.iterations,
        limb.estimate.seconds * 1e3,
        limb.estimate.residual_ratio,
        if orders.is_empty() {
            String::new()
        } else {
            format!("; DoF order found: {}", orders.join(", "))
        }
    )
}

/// The demo's structure (JSON and Graphviz), model and model URDF, written whole.
fn write_demo_results(
    out: &Path,
    structure: &skincal::explore::Structure,
    model: &skincal::estimate::body::BodyModel,
) -> Result<Vec<PathBuf>> {
    let (json_path, dot_path, model_path, urdf_path) = (
        out.join("structure.json"),
        out.join("structure.dot"),
        out.join("model.json"),
        out.join("model.urdf"),
    );
    let robot_model = model.check().map_err(|e| anyhow::anyhow!(e))?;
    io::write_all(
        &[
            (json_path.clone(), serde_json::to_string_pretty(structure)?),
            (dot_path.clone(), report::structure_dot(structure)),
            (model_path.clone(), serde_json::to_string_pretty(model)?),
            (
                urdf_path.clone(),
                skincal::model::urdf::to_urdf(&robot_model)?,
            ),
        ],
        true,
    )?;
    Ok(vec![json_path, dot_path, model_path, urdf_path])
}

pub(crate) fn demo(args: DemoArgs) -> Result<()> {
    if args.json {
        out::json_mode();
    }
    let started = std::time::Instant::now();
    let out = args
        .out
        .unwrap_or_else(|| std::env::temp_dir().join("skincal-demo"));
    prepare_demo_dir(&out, args.force)?;
    let robot = io::load_robot("humanoid", SuPlacement::default())?;
    let config = SimulationConfig {
        seed: args.seed,
        ..SimulationConfig::default()
    };
    outln!(
        "skincal demo: the built-in humanoid ({} DoFs, {} SUs)\n",
        robot.model.dofs().len(),
        robot.model.sus().len()
    );
    outln!("1. Simulated experiments\n");
    let (mut files, summary) = write_simulation(&robot, &config, &out, true)?;
    out!("{summary}");
    outln!("\n2. Structural exploration\n");
    let set = io::read_measurements(&files[0])?;
    let structure = skincal::explore::explore(&set, &ExploreConfig::default())?;
    out!("{}", report::tree(&structure));
    outln!();
    out!("{}", report::diagnostics(&structure));

    outln!("\n3. Kinematic estimation of every limb, maximum likelihood\n");
    let ml = skincal::estimate::ml::MlConfig::default();
    let model = skincal::estimate::body::calibrate_body(&set, Some(&structure), &ml, None)?;
    for limb in &model.limbs {
        outln!("{}", demo_limb_line(limb));
    }

    outln!("\n4. Against the truth: each limb's SU poses (relative to the previous SU, 30 random poses) and its");
    outln!("   predictions on 20 held-out poses of a fresh experiment without noise\n");
    let held_out_config = SimulationConfig {
        seed: args.seed + 1000,
        structure: false,
        imperfections: Imperfections::none(),
        ..SimulationConfig::default()
    };
    let held_out_dir = out.join("held-out");
    let (held_files, _) = write_simulation(&robot, &held_out_config, &held_out_dir, true)?;
    let held_out = io::read_measurements(&held_files[0])?;
    let check =
        skincal::predict::validate(&model, &held_out, &held_files[0].display().to_string())?;
    let rows = demo_rows(&robot, &model, &check)?;
    out!("{}", render::body_table(&rows, &check));

    files.extend(write_demo_results(&out, &structure, &model)?);
    files.extend(held_files);
    outln!("\n5. The robot's own URDF: SU frames on its links, its joints checked\n");
    let urdf_files = urdf::demo_step(&robot, &model, &out)?;
    // The report, with the held-out check and the URDF's.
    let report_path = out.join("report.html");
    let inputs = io::read_report_inputs(&out, Some(&held_out_dir), Some(&urdf_files[0]))?;
    files.extend(urdf_files);
    io::write_all(
        &[(report_path.clone(), skincal::html::render(&inputs))],
        true,
    )?;
    files.push(report_path);
    outln!();
    for f in &files {
        outln!("wrote {}", f.display());
    }
    outln!(
        "\nfinished in {:.2} s; check another data set with `skincal validate {} DIR`",
        started.elapsed().as_secs_f64(),
        out.join("model.json").display()
    );
    out::json(&serde_json::json!({
        "wrote": files.iter().map(|f| f.display().to_string()).collect::<Vec<_>>(),
        "seconds": started.elapsed().as_secs_f64(),
        "limbs": model.limbs.iter().map(|l| serde_json::json!({
            "name": l.name,
            "dofs": l.dofs.len(),
            "sus": l.sus.len(),
            "residual_ratio": l.estimate.residual_ratio,
            "converged": l.estimate.converged,
        })).collect::<Vec<_>>(),
        "held_out": {
            "static_rms": check.static_rms,
            "dynamic_rms": check.dynamic_rms,
        },
    }));
    Ok(())
}
