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
