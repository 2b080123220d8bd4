//! `skincal predict` and `skincal validate`: what a calibrated model predicts the skin reads, and
//! how far a measurement set is from it.

use std::path::{Path, PathBuf};

use anyhow::Result;
use clap::Args;
use skincal::io;

use crate::out::{self, out, outln};
use crate::{measurement_paths, parse_pattern, render};

#[derive(Debug, Args)]
pub(crate) struct PredictArgs {
    /// A calibrated model (model.json).
    model: PathBuf,
    /// Poses: CSV with a header of DoF names and one pose per row (rad), or JSON {"dofs", "poses"}.
    #[arg(long)]
    poses: PathBuf,
    /// Excitation pattern A,f (rad/s, Hz) [default: the model's training pattern].
    #[arg(long, value_name = "A,F")]
    pattern: Option<String>,
    /// Write the JSON here instead of printing it.
    #[arg(long)]
    out: Option<PathBuf>,
    /// Overwrite an existing output.
    #[arg(long)]
    force: bool,
    /// Predict what an ideal accelerometer in each SU frame would read (the specific force and
    /// the acceleration), not what the SU reads with its calibrated bias and scale.
    #[arg(long)]
    ideal: bool,
    /// With --out, print one JSON document of what was written instead of the line (without
    /// --out the predictions themselves are the JSON printed).
    #[arg(long)]
    json: bool,
}

#[derive(Debug, Args)]
pub(crate) struct ValidateArgs {
    /// A calibrated model (model.json).
    model: PathBuf,
    /// Directory with the second measurements.json (or the file itself); its training poses are
    /// compared.
    dir: PathBuf,
    /// Print the result as JSON (per SU and overall) instead of the table.
    #[arg(long)]
    json: bool,
}

pub(crate) fn predict(args: PredictArgs) -> Result<()> {
    if args.json && args.out.is_some() {
        out::json_mode();
    }
    let model = io::read_model(&args.model)?;
    let pattern = match &args.pattern {
        Some(p) => parse_pattern(p)?,
        None => model.pattern,
    };
    let mut predictor = skincal::predict::Predictor::new(&model)
        .map_err(|e| anyhow::anyhow!("{}: {e}", args.model.display()))?;
    if args.ideal {
        predictor = predictor.ideal();
    }
    if !model.not_calibrated.is_empty() {
        let names: Vec<String> = model
            .not_calibrated
            .iter()
            .map(|n| format!("{} {}", n.kind, n.name))
            .collect();
        eprintln!(
            "note: not calibrated, so not predicted (their angles in the poses are ignored): {}",
            names.join(", ")
        );
    }
    let bar = out::progress_bar(1, "predicting");
    let to_file = args.out.is_some();
    let mut progress = |p: io::PredictionProgress| match p {
        io::PredictionProgress::Predicted(poses) => {
            bar.set_message(format!("predicting: {poses} poses"));
            bar.tick();
        }
        // On standard output the bar would break into the text.
        io::PredictionProgress::Written { .. } if !to_file => bar.finish_and_clear(),
        io::PredictionProgress::Written { parts, of } => {
            bar.set_message("writing");
            bar.set_length(of as u64);
            bar.set_position(parts as u64);
        }
    };
    match args.out {
        Some(out) => {
            let poses = io::write_predictions(
                &predictor,
                &args.poses,
                &pattern,
                &out,
                args.force,
                &mut progress,
            );
            bar.finish_and_clear();
            let poses = poses?;
            outln!(
                "wrote {} ({poses} poses, {} SUs, pattern A = {} rad/s, f = {} Hz)",
                out.display(),
                predictor.sus().len(),
                pattern.amplitude,
                pattern.frequency
            );
            out::json(&serde_json::json!({
                "command": "predict",
                "wrote": out.display().to_string(),
                "poses": poses,
                "sus": predictor.sus().len(),
                "pattern": {"amplitude": pattern.amplitude, "frequency": pattern.frequency},
                "ideal": args.ideal,
            }));
        }
        None => {
            let mut stdout = std::io::stdout().lock();
            let streamed = io::stream_predictions(
                &predictor,
                &args.poses,
                &pattern,
                &std::env::temp_dir(),
                &mut stdout,
                Path::new("standard output"),
                &mut progress,
            );
            bar.finish_and_clear();
            match streamed {
                // The reader has gone (`| head`): nothing is lost but the rest of the text.
                Err(io::IoError::Write { path, source })
                    if source.kind() == std::io::ErrorKind::BrokenPipe
                        && path == Path::new("standard output") => {}
                other => {
                    other?;
                }
            }
        }
    }
    Ok(())
}

pub(crate) fn validate(args: ValidateArgs) -> Result<()> {
    if args.json {
        out::json_mode();
    }
    let model = io::read_model(&args.model)?;
    let (file, _) = measurement_paths(&args.dir);
    let set = io::read_measurements(&file)?;
    let check = skincal::predict::validate(&model, &set, &file.display().to_string())?;
    outln!(
        "{} against {} ({} poses, pattern A = {} rad/s, f = {} Hz)\n",
        args.model.display(),
        file.display(),
        check.poses,
        set.training.as_ref().map_or(0.0, |t| t.pattern.amplitude),
        set.training.as_ref().map_or(0.0, |t| t.pattern.frequency)
    );
    out!("{}", render::validation_table(&check));
    out::json(&serde_json::json!({
        "command": "validate",
        "model": args.model.display().to_string(),
        "measurements": file.display().to_string(),
        "validation": check,
    }));
    Ok(())
}
