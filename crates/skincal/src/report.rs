//! Pure renderers: results in, text out (terminal tables, Graphviz). Nothing here reads or writes
//! files or prints.

use std::fmt::Write;

use crate::explore::{DiagnosticKind, Severity, Structure};

/// The merged and sorted activity matrix in the style of the paper's Fig. 2, with the SUs of every
/// segment and the DoFs of every joint.
pub fn activity_table(s: &Structure) -> String {
    let mut out = String::new();
    let m = &s.matrix;
    let width = m.joints.iter().map(|j| j.len()).max().unwrap_or(2).max(2) + 1;
    let label = m.segments.iter().map(|x| x.len()).max().unwrap_or(2) + 1;
    let _ = write!(out, "{:label$}", "");
    for j in &m.joints {
        let _ = write!(out, "{j:>width$}");
    }
    out.push('\n');
    for (row, seg) in m.entries.iter().zip(&s.segments) {
        let _ = write!(out, "{:label$}", seg.id);
        for &e in row {
            let _ = write!(out, "{:>width$}", if e { "1" } else { "·" });
        }
        let sus = if seg.without_su {
            "(no SU: assumed)".to_string()
        } else {
            abbreviate(&seg.sus, 6)
        };
        let _ = writeln!(out, "   {sus}");
    }
    out
}

/// The tree, one segment a line, with the joint (and its DoFs) that leads to it.
///
/// ```
/// use skincal::explore::{explore, ExploreConfig};
/// use skincal::model::presets;
/// use skincal::sim::{simulate, SimulationConfig};
///
/// let robot = presets::find("paper-7dof").unwrap().robot().unwrap();
/// let set = simulate(&robot, &SimulationConfig { training: false, ..SimulationConfig::default() }).unwrap().measurements;
/// let text = skincal::report::tree(&explore(&set, &ExploreConfig::default()).unwrap());
/// assert!(text.contains("dof7"));
/// ```
pub fn tree(s: &Structure) -> String {
    let mut out = String::new();
    let root = &s.segments[0];
    let _ = writeln!(
        out,
        "{} reference, {}",
        root.id,
        su_count(root.sus.len(), root.without_su)
    );
    fn walk(s: &Structure, id: &str, prefix: &str, out: &mut String) {
        let kids: Vec<_> = s.joints.iter().filter(|j| j.parent == id).collect();
        for (i, j) in kids.iter().enumerate() {
            let last = i + 1 == kids.len();
            let seg = s.segment(&j.child).expect("joints name existing segments");
            let role = if s.end_effectors.contains(&seg.id) {
                ", end effector"
            } else if s.branching.contains(&seg.id) {
                ", branching"
            } else {
                ""
            };
            let _ = writeln!(
                out,
                "{prefix}{}{} [{}] → {} ({}{role})",
                if last { "└─ " } else { "├─ " },
                j.id,
                j.dofs.join(", "),
                seg.id,
                su_count(seg.sus.len(), seg.without_su)
            );
            let deeper = format!("{prefix}{}", if last { "   " } else { "│  " });
            walk(s, &seg.id, &deeper, out);
        }
    }
    walk(s, &root.id, "", &mut out);
    out
}

/// Limbs, one a line.
pub fn limbs(s: &Structure) -> String {
    let mut out = String::new();
    for l in &s.limbs {
        let _ = writeln!(
            out,
            "{} → {}: {} ({} DoFs, {} SUs)",
            l.from,
            l.to,
            l.joints.join(" "),
            l.dofs.len(),
            l.sus.len()
        );
    }
    out
}

/// Diagnostics, most serious first.
pub fn diagnostics(s: &Structure) -> String {
    let mut out = String::new();
    let multi: Vec<String> = s
        .diagnostics
        .iter()
        .filter(|d| d.kind == DiagnosticKind::MultiDofJoint)
        .map(|d| d.dofs.join("+"))
        .collect();
    for d in s
        .diagnostics
        .iter()
        .filter(|d| d.kind != DiagnosticKind::MultiDofJoint)
    {
        let level = match d.severity {
            Severity::Error => "error",
            Severity::Warning => "warning",
            Severity::Info => "note",
        };
        let _ = writeln!(out, "{level}: {}", d.message);
        if !d.dofs.is_empty() {
            let _ = writeln!(out, "    DoFs: {}", abbreviate(&d.dofs, 12));
        }
        if !d.sus.is_empty() {
            let _ = writeln!(out, "    SUs:  {}", abbreviate(&d.sus, 12));
        }
    }
    if !multi.is_empty() {
        let _ = writeln!(
            out,
            "note: {} joints combine several DoFs with no SU between them ({}); the order of the DoFs inside such a joint cannot be seen in the activity matrix and is listed in input order — kinematic estimation determines it",
            multi.len(),
            multi.join(", ")
        );
    }
    out
}

/// The tree as a Graphviz digraph: segments as boxes, joints as labelled edges.
pub fn structure_dot(s: &Structure) -> String {
    let mut out = String::from("digraph structure {\n  rankdir=TB;\n  node [shape=box, style=rounded, fontname=\"Helvetica\"];\n  edge [fontname=\"Helvetica\", fontsize=10];\n");
    for seg in &s.segments {
        let reference = if seg.id == s.root { " (reference)" } else { "" };
        let label = format!(
            "{}{reference}\\n{}",
            escape(&seg.id),
            su_count(seg.sus.len(), seg.without_su)
        );
        let style = if seg.without_su {
            ", style=\"rounded,dashed\""
        } else if seg.id == s.root {
            ", penwidth=2"
        } else {
            ""
        };
        let _ = writeln!(
            out,
            "  \"{}\" [label=\"{label}\", tooltip=\"{}\"{style}];",
            escape(&seg.id),
            escape(&seg.sus.join(", "))
        );
    }
    for j in &s.joints {
        let dofs: Vec<String> = j.dofs.iter().map(|d| escape(d)).collect();
        let _ = writeln!(
            out,
            "  \"{}\" -> \"{}\" [label=\"{}\\n{}\"];",
            escape(&j.parent),
            escape(&j.child),
            escape(&j.id),
            dofs.join("\\n")
        );
    }
    out.push_str("}\n");
    out
}

fn escape(s: &str) -> String {
    s.replace('\\', "\\\\").replace('"', "\\\"")
}

fn su_count(n: usize, without: bool) -> String {
    match (n, without) {
        (_, true) => "no SU".into(),
        (1, _) => "1 SU".into(),
        (n, _) => format!("{n} SUs"),
    }
}

fn abbreviate(names: &[String], keep: usize) -> String {
    if names.len() <= keep {
        names.join(", ")
    } else {
        format!("{}, … ({} in all)", names[..keep].join(", "), names.len())
    }
}

/// The paper's Fig. 6 for one chain: DoF-to-DoF and DoF-to-SU tables, with the true values beside
/// the estimates when known and deviations above 0.1 (rad or m) marked with `*`.
pub fn dh_tables(
    chain: &crate::estimate::LimbChain,
    dof_dof: &[crate::estimate::DhRow],
    dof_su: &[crate::estimate::SuRow],
    truth: Option<&(Vec<crate::estimate::DhRow>, Vec<crate::estimate::SuRow>)>,
) -> String {
    let mut out = String::new();
    let (dofs, sus) = (chain.dofs(), chain.sus());
    let dd: Vec<(String, Vec<f64>)> = dof_dof
        .iter()
        .enumerate()
        .map(|(k, r)| (format!("{}→{}", dofs[k], dofs[k + 1]), r.values().to_vec()))
        .collect();
    let ds: Vec<(String, Vec<f64>)> = dof_su
        .iter()
        .enumerate()
        .map(|(k, r)| (format!("{}→{}", dofs[k], sus[k]), r.values().to_vec()))
        .collect();
    let true_dd: Option<Vec<Vec<f64>>> =
        truth.map(|(rows, _)| rows.iter().map(|r| r.values().to_vec()).collect());
    let true_ds: Option<Vec<Vec<f64>>> =
        truth.map(|(_, rows)| rows.iter().map(|r| r.values().to_vec()).collect());
    if !dd.is_empty() {
        let _ = writeln!(out, "DoF-DoF transformation parameters");
        table(&mut out, &dd, true_dd.as_deref(), &["θ0", "d", "a", "α"]);
        out.push('\n');
    }
    let _ = writeln!(out, "DoF-SU transformation parameters");
    table(
        &mut out,
        &ds,
        true_ds.as_deref(),
        &["θ0", "d", "a", "α", "θ_acc", "d_acc"],
    );
    if truth.is_some() {
        let _ = writeln!(out, "(* deviation above 0.1 rad or m)");
    }
    out
}

fn table(
    out: &mut String,
    columns: &[(String, Vec<f64>)],
    truth: Option<&[Vec<f64>]>,
    rows: &[&str],
) {
    let per = if truth.is_some() { 16 } else { 8 };
    let width = columns
        .iter()
        .map(|(n, _)| n.chars().count())
        .max()
        .unwrap_or(0)
        .max(per);
    let _ = write!(out, "{:7}", "");
    for (name, _) in columns {
        let _ = write!(out, " {name:>width$}");
    }
    out.push('\n');
    if truth.is_some() {
        let _ = write!(out, "{:7}", "");
        for _ in columns {
            let _ = write!(
                out,
                " {:>w$}",
                format!("{:>7} {:>8}", "real", "est"),
                w = width
            );
        }
        out.push('\n');
    }
    for (i, row) in rows.iter().enumerate() {
        let _ = write!(out, "{row:7}");
        for (c, (_, values)) in columns.iter().enumerate() {
            let est = values[i];
            let cell = match truth {
                Some(t) => {
                    let real = t[c][i];
                    let mut diff = est - real;
                    if !matches!(*row, "d" | "a" | "d_acc") {
                        diff = (diff + std::f64::consts::PI).rem_euclid(2.0 * std::f64::consts::PI)
                            - std::f64::consts::PI;
                    }
                    let mark = if diff.abs() > 0.1 { "*" } else { " " };
                    format!("{real:>7.3} {est:>7.3}{mark}")
                }
                None => format!("{est:>8.3}"),
            };
            let _ = write!(out, " {cell:>width$}");
        }
        out.push('\n');
    }
}

/// The paper's "Optimization Steps" table.
pub fn optimization_steps(estimate: &crate::estimate::paper::PaperChainEstimate) -> String {
    let mut out = String::new();
    let _ = writeln!(
        out,
        "{:>5} {:>8} {:>6} {:>12} {:>10} {:>10}  stop",
        "step", "SU", "params", "evaluations", "time s", "e_T"
    );
    for s in &estimate.steps {
        let _ = writeln!(
            out,
            "{:>5} {:>8} {:>6} {:>12} {:>10.3} {:>10.4}{} {}",
            s.step,
            s.su,
            s.parameters.len(),
            s.evaluations,
            s.seconds,
            s.e_t,
            if s.converged { " " } else { "!" },
            s.stop
        );
    }
    let _ = writeln!(
        out,
        "{:>5} {:>8} {:>6} {:>12} {:>10.3} {:>10}",
        "total",
        "",
        "",
        estimate.evaluations(),
        estimate.seconds(),
        ""
    );
    if !estimate.converged() {
        let _ = writeln!(
            out,
            "! e_T above e_stop = {}: the step did not converge",
            estimate.config.e_stop
        );
    }
    out
}

/// Pose errors of consecutive SUs against the truth.
pub fn chain_accuracy(a: &crate::estimate::ChainAccuracy) -> String {
    let mut out = String::new();
    let _ = writeln!(
        out,
        "{:>18} {:>12} {:>12} {:>12} {:>12}",
        "SU pair", "pos RMS mm", "pos max mm", "rot RMS °", "rot max °"
    );
    for p in &a.pairs {
        let _ = writeln!(
            out,
            "{:>18} {:>12.2} {:>12.2} {:>12.3} {:>12.3}",
            format!("{}→{}", p.from, p.to),
            p.position_rms * 1e3,
            p.position_max * 1e3,
            p.rotation_rms.to_degrees(),
            p.rotation_max.to_degrees()
        );
    }
    if a.pairs.len() < 2 {
        // The summary is over the pairs after the first (compared only up to a screw about the
        // first axis): a limb of two SUs has none.
        let _ = writeln!(
            out,
            "{:>18} {:>12} {:>12} {:>12} {:>12}   (no pair after the first)",
            "all", "—", "—", "—", "—"
        );
        return out;
    }
    let _ = writeln!(
        out,
        "{:>18} {:>12.2} {:>12.2} {:>12.3} {:>12.3}",
        "all",
        a.position_rms * 1e3,
        a.position_max * 1e3,
        a.rotation_rms.to_degrees(),
        a.rotation_max.to_degrees()
    );
    out
}

/// The check of a URDF's joints against a calibration (`skincal check-urdf`): one row per DoF.
pub fn urdf_check(check: &crate::align::UrdfCheck) -> String {
    use crate::align::JointVerdict as V;
    let width = check
        .joints
        .iter()
        .map(|j| j.dof.chars().count())
        .max()
        .unwrap_or(3)
        .max(3);
    let mut out = format!(
        "{:width$}  {:>17}  {:>17}  {:>6}  verdict\n",
        "DoF", "angle (°)", "distance (mm)", "χ²"
    );
    for j in &check.joints {
        let verdict = match j.verdict {
            V::Agrees => "agrees".to_string(),
            V::Disagrees => "DISAGREES".to_string(),
            V::LimbBase => format!("limb base ({})", j.note),
            V::NotCompared => format!("not compared ({})", j.note),
        };
        if matches!(j.verdict, V::Agrees | V::Disagrees) {
            let partial = if j.components < 4 {
                format!(", {} of 4 components", j.components)
            } else {
                String::new()
            };
            out.push_str(&format!(
                "{:width$}  {:>8.3} ± {:<6.3}  {:>8.2} ± {:<6.2}  {:>6.1}  {verdict}{partial}\n",
                j.dof,
                j.angle.to_degrees(),
                j.angle_sd.to_degrees(),
                j.distance * 1e3,
                j.distance_sd * 1e3,
                j.chi2,
            ));
        } else {
            out.push_str(&format!(
                "{:width$}  {:>17}  {:>17}  {:>6}  {verdict}\n",
                j.dof, "", "", ""
            ));
        }
    }
    out
}

#[cfg(test)]
mod tests {
    use crate::estimate::{ChainAccuracy, PairError};

    fn pair(from: &str, to: &str, mm: f64) -> PairError {
        PairError {
            from: from.into(),
            to: to.into(),
            position_rms: mm * 1e-3,
            position_max: mm * 1e-3,
            rotation_rms: 0.001,
            rotation_max: 0.002,
        }
    }

    #[test]
    fn a_limb_of_two_sus_has_no_summary_row_of_numbers() {
        // The summary covers the pairs after the first; with one pair there is none to show
        // (it printed −0.00).
        let one = ChainAccuracy {
            pairs: vec![pair("a", "b", 2.64)],
            position_rms: -0.0,
            position_max: 0.0,
            rotation_rms: -0.0,
            rotation_max: 0.0,
            poses: 30,
        };
        let text = super::chain_accuracy(&one);
        assert!(text.contains("a→b") && text.contains("2.64"), "{text}");
        assert!(
            text.contains("no pair after the first") && !text.contains("-0.00"),
            "{text}"
        );
        let two = ChainAccuracy {
            pairs: vec![pair("a", "b", 2.64), pair("b", "c", 1.5)],
            position_rms: 1.5e-3,
            position_max: 1.5e-3,
            rotation_rms: 0.001,
            rotation_max: 0.002,
            poses: 30,
        };
        let last = super::chain_accuracy(&two)
            .lines()
            .last()
            .unwrap()
            .to_string();
        assert!(last.contains("all") && last.contains("1.50"), "{last}");
    }
}
