//! `export-urdf` (standalone, or the SU frames merged into the robot's own URDF) and `check-urdf`.

use std::path::PathBuf;

use anyhow::{Context, Result};
use clap::Args;
use skincal::io;

use crate::out::{self, out, outln};
use crate::Incomplete;

#[derive(Debug, Args)]
pub struct ExportUrdfArgs {
    /// A calibrated model (model.json).
    model: PathBuf,
    /// The robot's own URDF: add one link per SU to it, each on the link that its segment
    /// corresponds to (DoF names = the URDF's joint names), keeping the rest of the file as it is.
    #[arg(long, value_name = "URDF")]
    into: Option<PathBuf>,
    /// With --into: write only the SU links and joints, as a file to include in a xacro
    /// (`<xacro:include filename="…"/>`).
    #[arg(long, requires = "into")]
    snippet: bool,
    /// With --into: a prefix for the SU links and joints (when their names are taken).
    #[arg(long, requires = "into", default_value = "")]
    prefix: String,
    /// Output file [default: the model's name with .urdf; with --into, the URDF's name with
    /// -skin.urdf (-skin.xacro with --snippet)].
    #[arg(long)]
    out: Option<PathBuf>,
    /// Overwrite an existing output.
    #[arg(long)]
    force: bool,
    /// Print one JSON document (what was written and the result's figures) instead of text.
    #[arg(long)]
    json: bool,
}

#[derive(Debug, Args)]
pub struct CheckUrdfArgs {
    /// A calibrated model (model.json).
    model: PathBuf,
    /// The robot's URDF, joints named as the model's DoFs.
    urdf: PathBuf,
    /// Print the check as JSON instead of the table.
    #[arg(long)]
    json: bool,
}

pub fn export_urdf(args: ExportUrdfArgs) -> Result<()> {
    if args.json {
        out::json_mode();
    }
    let model = io::read_model(&args.model)?;
    if let Some(into) = &args.into {
        return export_into(&args, &model, into);
    }
    let robot = model
        .check()
        .map_err(|e| anyhow::anyhow!("{}: {e}", args.model.display()))?;
    let mut text =
        skincal::model::urdf::to_urdf(&robot).with_context(|| args.model.display().to_string())?;
    if !model.not_calibrated.is_empty() {
        // Said in the file itself, after the XML declaration.
        let list: Vec<String> = model
            .not_calibrated
            .iter()
            .map(|n| format!("{} {} ({})", n.kind, n.name, n.reason.replace("--", "-")))
            .collect();
        let comment = format!(
            "<!-- Not calibrated by skincal (absent from this description):\n     {}\n-->\n",
            list.join("\n     ")
        );
        let at = text.find("?>\n").map_or(0, |i| i + 3);
        text.insert_str(at, &comment);
    }
    let out = args
        .out
        .unwrap_or_else(|| args.model.with_extension("urdf"));
    io::write_all(&[(out.clone(), text)], args.force)?;
    let prismatic = robot.model.prismatic_dof_names().len();
    outln!(
        "wrote {} ({} links, {} continuous{} joints, {} SU links; kinematics only)",
        out.display(),
        robot.model.segments().len() + robot.model.sus().len(),
        robot.model.dofs().len() - prismatic,
        if prismatic > 0 {
            format!(" and {prismatic} prismatic")
        } else {
            String::new()
        },
        robot.model.sus().len()
    );
    out::json(&serde_json::json!({
        "wrote": out.display().to_string(),
        "links": robot.model.segments().len() + robot.model.sus().len(),
        "joints": robot.model.dofs().len(),
        "sus": robot.model.sus().len(),
    }));
    Ok(())
}

fn export_into(
    args: &ExportUrdfArgs,
    model: &skincal::estimate::body::BodyModel,
    into: &std::path::Path,
) -> Result<()> {
    let (text, alignment) = io::read_urdf_alignment(model, into)?;
    let merged = skincal::align::merge_sus(&alignment, &text, &args.prefix, args.snippet)
        .with_context(|| into.display().to_string())?;
    let out = args.out.clone().unwrap_or_else(|| {
        let stem = into.file_stem().unwrap_or_default().to_string_lossy();
        let ext = if args.snippet { "xacro" } else { "urdf" };
        into.with_file_name(format!("{stem}-skin.{ext}"))
    });
    // Mesh names relative to the robot's URDF would not load from another folder.
    let folder = |p: &std::path::Path| {
        let parent = p.parent().filter(|d| !d.as_os_str().is_empty());
        std::path::absolute(parent.unwrap_or(std::path::Path::new("."))).ok()
    };
    let merged = match (folder(into), folder(&out)) {
        (Some(from), Some(to)) if from != to && !args.snippet => {
            skincal::align::relocated(&merged, &from)
        }
        _ => merged,
    };
    io::write_all(&[(out.clone(), merged)], args.force)?;
    let links: std::collections::BTreeSet<&str> =
        alignment.sus.iter().map(|s| s.link.as_str()).collect();
    outln!(
        "wrote {}: {} SU frames on {} links of `{}`{}",
        out.display(),
        alignment.sus.len(),
        links.len(),
        alignment.tree.name,
        if args.snippet {
            " (the SU links and joints only, to include in a xacro)"
        } else {
            ", the rest of the URDF as it was"
        }
    );
    for (su, why) in &alignment.unplaced {
        outln!("  not placed: {su}: {why}");
    }
    for (su, why) in &alignment.partial {
        outln!("  partly measured: {su}: {why}");
    }
    if !alignment.check.disagree.is_empty() {
        eprintln!(
            "warning: {} with the calibration beyond 3σ; the SU frames after them are placed relative to the calibrated axes (see `skincal check-urdf`)",
            disagreement(&alignment.check.disagree)
        );
    }
    out::json(&serde_json::json!({
        "wrote": out.display().to_string(),
        "sus": alignment.sus.len(),
        "links": links.len(),
        "not_placed": alignment.unplaced.iter().map(|(su, why)| serde_json::json!({"su": su, "why": why})).collect::<Vec<_>>(),
        "partly_measured": alignment.partial.iter().map(|(su, why)| serde_json::json!({"su": su, "why": why})).collect::<Vec<_>>(),
        "disagree": alignment.check.disagree,
    }));
    Ok(())
}

pub fn check_urdf(args: CheckUrdfArgs) -> Result<()> {
    if args.json {
        out::json_mode();
    }
    let model = io::read_model(&args.model)?;
    let (_, alignment) = io::read_urdf_alignment(&model, &args.urdf)?;
    let check = &alignment.check;
    outln!(
        "{} against {} (`{}`): each joint's axis line after aligning the URDF's along its limb; angle and distance between the axes (at the URDF joint's origin) ± 1σ\n",
        args.urdf.display(),
        args.model.display(),
        check.robot
    );
    out!("{}", skincal::report::urdf_check(check));
    if !alignment.partial.is_empty() {
        let sus: Vec<&str> = alignment
            .partial
            .iter()
            .map(|(su, _)| su.as_str())
            .collect();
        outln!(
            "\nnot measured: where {} sit along and about the axes before them relative to the rest of their limb (see `export-urdf --into`); nothing here checks the URDF there",
            sus.join(", ")
        );
    }
    out::json(&serde_json::json!({
        "command": "check-urdf",
        "model": args.model.display().to_string(),
        "urdf": args.urdf.display().to_string(),
        "check": check,
        "partly_measured": alignment.partial.iter().map(|(su, why)| serde_json::json!({"su": su, "why": why})).collect::<Vec<_>>(),
    }));
    if check.disagree.is_empty() {
        outln!("\nevery compared joint agrees with the calibration within 3σ");
        Ok(())
    } else {
        Err(Incomplete(format!(
            "{} with the calibration beyond 3σ",
            disagreement(&check.disagree)
        ))
        .into())
    }
}

/// "the URDF's joint `a` disagrees" or "the URDF's joints `a`, `b` disagree".
pub(crate) fn disagreement(joints: &[String]) -> String {
    let names: Vec<String> = joints.iter().map(|j| format!("`{j}`")).collect();
    match names.as_slice() {
        [one] => format!("the URDF's joint {one} disagrees"),
        many => format!("the URDF's joints {} disagree", many.join(", ")),
    }
}

/// The demo's last step: the robot's own URDF (the simulated truth without its skin, as its maker
/// would give it), the SU frames merged into it and its joints checked. Returns the files written
/// (URDF, merged URDF) and prints what was found.
pub fn demo_step(
    truth: &skincal::model::Robot,
    model: &skincal::estimate::body::BodyModel,
    dir: &std::path::Path,
) -> Result<Vec<PathBuf>> {
    let mut bare = skincal::model::description::RobotFile::from_robot(truth, None);
    bare.sus.clear();
    let text = skincal::model::urdf::to_urdf(&bare.build()?)?;
    let (urdf_path, merged_path) = (
        dir.join(format!("{}.urdf", truth.model.name())),
        dir.join(format!("{}-skin.urdf", truth.model.name())),
    );
    let alignment = skincal::align::align(model, &text)
        .with_context(|| format!("the robot's URDF {}", urdf_path.display()))?;
    let merged = skincal::align::merge_sus(&alignment, &text, "", false)?;
    io::write_all(
        &[(urdf_path.clone(), text), (merged_path.clone(), merged)],
        true,
    )?;
    use skincal::align::JointVerdict as V;
    let count = |v: V| {
        alignment
            .check
            .joints
            .iter()
            .filter(|j| j.verdict == v)
            .count()
    };
    outln!(
        "{} SU frames on the links of {} ({} on the static reference segment keep only their tilt);",
        alignment.sus.len(),
        urdf_path.display(),
        alignment.unplaced.len()
    );
    outln!(
        "its joints against the calibration: {} agree, {} beyond 3σ, {} limb bases not observable",
        count(V::Agrees),
        match count(V::Disagrees) {
            1 => "1 disagrees".to_string(),
            n => format!("{n} disagree"),
        },
        count(V::LimbBase)
    );
    Ok(vec![urdf_path, merged_path])
}
