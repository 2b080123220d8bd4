//! The HTML report: one self-contained page (inline CSS, SVG and script; nothing fetched) made
//! from whatever a result directory holds. Every section appears only when its inputs do:
//!
//! - `summary`: what the directory holds;
//! - `activity`: the sorted activity matrix (the paper's Fig. 2), uncertain entries marked, the
//!   change in g on hover;
//! - `tree`: the kinematic tree drawn (laid out here: depth down, leaves across), limbs coloured,
//!   end effectors and branching segments marked, left-out DoFs and SUs listed;
//! - `view3d`: the calibrated body drawn in 3D (segments, joint axes, SU frames as triads, each
//!   SU's position uncertainty as a circle), turned with the mouse, a slider per DoF;
//! - `limbs`: per limb the fit (converged, residual, iterations), its SUs' residuals and pose
//!   uncertainties as charts, broken SUs flagged, the paper's DH+2 table where the limb has one;
//! - `validation`: held-out errors per SU;
//! - `timeline`: for logs, each recording's still windows, pauses, moves, excitations (with the
//!   share of coupled motion fitted out) and skipped transfers per DoF, and the noise found.
//!
//! A script catches JavaScript errors into `#script-errors`, so that a headless browser's DOM says
//! whether the page ran cleanly.

use std::collections::BTreeMap;
use std::fmt::Write as _;

use maud::{html, Markup, PreEscaped, DOCTYPE};

use crate::estimate::body::BodyModel;
use crate::explore::Structure;
use crate::ingest::{IngestReport, LogReport};
use crate::measurements::MeasurementSet;
use crate::predict::Validation;
use crate::show::xml_escape as escape;

/// What a report is made from; every part optional.
#[derive(Debug, Default)]
pub struct ReportInputs {
    /// A title (the directory's name).
    pub title: String,
    /// The measurement set.
    pub measurements: Option<MeasurementSet>,
    /// The explored structure.
    pub structure: Option<Structure>,
    /// The calibrated model.
    pub model: Option<BodyModel>,
    /// What the ingestion of logs found.
    pub ingest: Option<IngestReport>,
    /// The true robot (a simulation's `truth.json`): its DH+2 table beside the calibrated one.
    pub truth: Option<crate::model::Robot>,
    /// The paper's method's chains (`model-paper.json`), shown beside the ML limbs.
    pub paper: Vec<crate::estimate::paper::PaperChainEstimate>,
    /// The model checked against a held-out set, and that set's name.
    pub validation: Option<(Validation, String)>,
    /// The robot's own URDF checked against the model, and the URDF's name.
    pub urdf_check: Option<(crate::align::UrdfCheck, String)>,
}

/// Colours of the limbs, in order.
const PALETTE: [&str; 8] = [
    "#1f77b4", "#d62728", "#2ca02c", "#9467bd", "#ff7f0e", "#17becf", "#8c564b", "#e377c2",
];

const STYLE: &str = "
body { font: 14px/1.45 system-ui, sans-serif; margin: 0 auto; max-width: 72rem; padding: 1rem 2rem; color: #222; }
h1 { font-size: 1.6rem; } h2 { border-bottom: 1px solid #ccc; margin-top: 2rem; }
table { border-collapse: collapse; margin: 0.5rem 0; }
td, th { border: 1px solid #ddd; padding: 2px 6px; text-align: right; }
th { background: #f4f4f4; } td.name, th.name { text-align: left; }
table.matrix td { width: 1.1rem; height: 1.1rem; padding: 0; text-align: center; }
td.on { background: #333; } td.uncertain { outline: 2px dashed #e69f00; outline-offset: -3px; }
.bad { color: #b00; font-weight: bold; } .note { color: #666; }
svg text { font: 11px system-ui, sans-serif; }
#view3d-sliders label { display: flex; justify-content: space-between; align-items: center; padding-right: 1.5rem; break-inside: avoid; }
#script-errors:empty { display: none; } #script-errors { color: #b00; }
";

const ERROR_HOOK: &str = "window.addEventListener('error', function (e) {
  var box = document.getElementById('script-errors');
  if (box) { box.textContent += (e.message || 'error') + '\\n'; }
});";

/// The report page.
pub fn render(inputs: &ReportInputs) -> String {
    let page = html! {
        (DOCTYPE)
        html lang="en" {
            head {
                meta charset="utf-8";
                title { "skincal report — " (inputs.title) }
                style { (PreEscaped(STYLE)) }
                script { (PreEscaped(ERROR_HOOK)) }
            }
            body {
                h1 { "skincal report — " (inputs.title) }
                pre id="script-errors" {}
                (summary(inputs))
                @if let Some(s) = &inputs.structure {
                    (activity(s))
                    (tree(s))
                }
                @if let Some(m) = &inputs.model {
                    (view3d(m))
                    (limbs(m, inputs.truth.as_ref(), &inputs.paper))
                }
                @if let Some((v, name)) = &inputs.validation {
                    (validation(v, name))
                }
                @if let Some((c, name)) = &inputs.urdf_check {
                    (urdf_check(c, name))
                }
                @if let Some(r) = &inputs.ingest {
                    (recording(r))
                }
            }
        }
    };
    page.into_string()
}

fn summary(inputs: &ReportInputs) -> Markup {
    html! {
        section id="summary" {
            h2 { "What this directory holds" }
            ul {
                @if let Some(m) = &inputs.measurements {
                    li { "Measurement set: " (m.dofs.len()) " DoFs, " (m.sus.len()) " SUs, "
                        (m.structure.as_ref().map_or(0, |s| s.orientations.len())) " base orientation(s) of structure moves, "
                        (m.training.as_ref().map_or(0, |t| t.poses.len())) " training poses." }
                }
                @if let Some(s) = &inputs.structure {
                    li { "Structure: " (s.segments.len()) " segments, " (s.joints.len()) " joints, "
                        (s.limbs.len()) " limbs; " (if s.complete { "complete" } else { "INCOMPLETE" }) "." }
                }
                @if let Some(m) = &inputs.model {
                    li { "Calibrated model: " (m.limbs.len()) " limbs, "
                        (m.limbs.iter().filter(|l| l.estimate.converged).count()) " converged; "
                        (m.broken.len()) " broken SUs set aside; "
                        (m.not_calibrated.len()) " parts not calibrated." }
                }
                @if let Some((v, name)) = &inputs.validation {
                    li { "Checked against " (name) ": static " (format!("{:.4}", v.static_rms))
                        ", dynamic " (format!("{:.4}", v.dynamic_rms)) " m/s² RMS." }
                }
            }
        }
    }
}

fn activity(s: &Structure) -> Markup {
    let m = &s.matrix;
    // The change in g of the uncertain entries, by segment and joint.
    let su_segment: BTreeMap<&str, &str> = s
        .segments
        .iter()
        .flat_map(|seg| seg.sus.iter().map(move |su| (su.as_str(), seg.id.as_str())))
        .collect();
    let dof_joint: BTreeMap<&str, &str> = s
        .joints
        .iter()
        .flat_map(|j| j.dofs.iter().map(move |d| (d.as_str(), j.id.as_str())))
        .collect();
    let mut uncertain: BTreeMap<(&str, &str), Vec<String>> = BTreeMap::new();
    for u in &s.uncertain {
        if let (Some(seg), Some(joint)) =
            (su_segment.get(u.su.as_str()), dof_joint.get(u.dof.as_str()))
        {
            uncertain.entry((seg, joint)).or_default().push(format!(
                "{} × {}: {:.3} g ({})",
                u.su,
                u.dof,
                u.change_g,
                if u.active {
                    "counted active"
                } else {
                    "counted still"
                }
            ));
        }
    }
    let sus_of = |id: &str| {
        s.segments
            .iter()
            .find(|seg| seg.id == id)
            .map(|seg| seg.sus.join(", "))
            .unwrap_or_default()
    };
    let dofs_of = |id: &str| {
        s.joints
            .iter()
            .find(|j| j.id == id)
            .map(|j| j.dofs.join(", "))
            .unwrap_or_default()
    };
    html! {
        section id="activity" {
            h2 { "Activity matrix (Fig. 2)" }
            p class="note" { "Segments × joints, sorted into lower-triangular form: a filled cell means the joint moves the segment's SUs (gravity turned by more than "
                (format!("{:.3}", s.threshold_g)) " g over " (s.orientations) " base orientation(s)). Dashed: within the uncertainty band; hover for the change in g." }
            table class="matrix" {
                tr { th {} @for j in &m.joints { th title=(dofs_of(j)) { (j) } } }
                @for (r, seg) in m.segments.iter().enumerate() {
                    tr {
                        th class="name" title=(sus_of(seg)) { (seg) }
                        @for (c, j) in m.joints.iter().enumerate() {
                            @let notes = uncertain.get(&(seg.as_str(), j.as_str()));
                            @let class = match (m.entries[r][c], notes.is_some()) {
                                (true, true) => "on uncertain", (true, false) => "on",
                                (false, true) => "uncertain", (false, false) => "",
                            };
                            td class=(class) title=(notes.map(|n| n.join("; ")).unwrap_or_else(|| format!("{seg} × {j}"))) {}
                        }
                    }
                }
            }
        }
    }
}

/// The tree as SVG: each segment a node at (leaf order, depth), each joint an edge labelled with
/// its DoFs, coloured by the limb it belongs to.
fn tree(s: &Structure) -> Markup {
    let children = |id: &str| -> Vec<&crate::explore::JointNode> {
        s.joints.iter().filter(|j| j.parent == id).collect()
    };
    // Depth-first: leaves get consecutive x, inner nodes the mean of their children.
    let mut x: BTreeMap<String, f64> = BTreeMap::new();
    let mut depth: BTreeMap<String, usize> = BTreeMap::new();
    let mut next_leaf = 0.0;
    fn place<'a>(
        id: &str,
        level: usize,
        children: &dyn Fn(&str) -> Vec<&'a crate::explore::JointNode>,
        x: &mut BTreeMap<String, f64>,
        depth: &mut BTreeMap<String, usize>,
        next_leaf: &mut f64,
    ) -> f64 {
        depth.insert(id.to_string(), level);
        let kids = children(id);
        let at = if kids.is_empty() {
            *next_leaf += 1.0;
            *next_leaf - 1.0
        } else {
            let xs: Vec<f64> = kids
                .iter()
                .map(|j| place(&j.child, level + 1, children, x, depth, next_leaf))
                .collect();
            xs.iter().sum::<f64>() / xs.len() as f64
        };
        x.insert(id.to_string(), at);
        at
    }
    place(&s.root, 0, &children, &mut x, &mut depth, &mut next_leaf);
    let limb_of: BTreeMap<&str, usize> = s
        .limbs
        .iter()
        .enumerate()
        .flat_map(|(i, l)| l.segments.iter().map(move |seg| (seg.as_str(), i)))
        .collect();
    let (dx, dy, margin) = (110.0, 70.0, 30.0);
    let width = next_leaf.max(1.0) * dx + 2.0 * margin;
    let height = (depth.values().max().copied().unwrap_or(0) as f64 + 1.0) * dy + 2.0 * margin;
    let at = |id: &str| {
        (
            margin + dx / 2.0 + x.get(id).copied().unwrap_or(0.0) * dx,
            margin + depth.get(id).copied().unwrap_or(0) as f64 * dy,
        )
    };
    let mut svg = String::new();
    let _ = write!(
        svg,
        "<svg xmlns=\"http://www.w3.org/2000/svg\" width=\"{width:.0}\" height=\"{height:.0}\" viewBox=\"0 0 {width:.0} {height:.0}\">"
    );
    for j in &s.joints {
        let ((x1, y1), (x2, y2)) = (at(&j.parent), at(&j.child));
        let colour = limb_of
            .get(j.child.as_str())
            .map_or("#999", |&i| PALETTE[i % PALETTE.len()]);
        let _ = write!(
            svg,
            "<line class=\"joint\" x1=\"{x1:.1}\" y1=\"{y1:.1}\" x2=\"{x2:.1}\" y2=\"{y2:.1}\" stroke=\"{colour}\" stroke-width=\"3\"><title>{} ({})</title></line>",
            escape(&j.id),
            escape(&j.dofs.join(", "))
        );
        // The joint's id on the edge (its DoFs on hover): DoF names would overlap.
        let label = match j.dofs.as_slice() {
            [one] => one.clone(),
            many => format!("{} ({} DoFs)", j.id, many.len()),
        };
        let _ = write!(
            svg,
            "<text x=\"{:.1}\" y=\"{:.1}\" fill=\"#555\">{}</text>",
            x1 + (x2 - x1) * 0.75 + 4.0,
            y1 + (y2 - y1) * 0.75,
            escape(&label)
        );
    }
    for seg in &s.segments {
        let (cx, cy) = at(&seg.id);
        let end = s.end_effectors.contains(&seg.id);
        let branching = s.branching.contains(&seg.id);
        let fill = if seg.id == s.root {
            "#000"
        } else {
            limb_of
                .get(seg.id.as_str())
                .map_or("#999", |&i| PALETTE[i % PALETTE.len()])
        };
        let shape = if branching {
            format!(
                "<rect x=\"{:.1}\" y=\"{:.1}\" width=\"16\" height=\"16\" fill=\"{fill}\"/>",
                cx - 8.0,
                cy - 8.0
            )
        } else {
            format!(
                "<circle cx=\"{cx:.1}\" cy=\"{cy:.1}\" r=\"{}\" fill=\"{fill}\"{}/>",
                if end { 9 } else { 7 },
                if end {
                    " stroke=\"#000\" stroke-width=\"2\""
                } else {
                    ""
                }
            )
        };
        let _ = write!(
            svg,
            "<g class=\"segment\"><title>{}: {}</title>{shape}<text x=\"{:.1}\" y=\"{:.1}\" text-anchor=\"middle\">{}</text></g>",
            escape(&seg.id),
            escape(&if seg.sus.is_empty() {
                "no SU".to_string()
            } else {
                seg.sus.join(", ")
            }),
            cx,
            cy + 22.0,
            escape(&seg.id)
        );
    }
    svg.push_str("</svg>");
    html! {
        section id="tree" {
            h2 { "Kinematic tree" }
            p class="note" { "Root (black) at the top; a colour per limb; end effectors ringed, branching segments square. Hover for the SUs of a segment and the DoFs of a joint." }
            (PreEscaped(svg))
            @if !s.unplaced_dofs.is_empty() || !s.unplaced_sus.is_empty() {
                p class="bad" { "Left out: DoFs " (s.unplaced_dofs.join(", ")) "; SUs " (s.unplaced_sus.join(", ")) "." }
            }
        }
    }
}

/// A horizontal bar chart as SVG: one bar per label, a reference line at `reference`.
fn bars(values: &[(String, f64, bool)], unit: &str, reference: Option<f64>) -> String {
    let (row, label_width, chart) = (16.0, 140.0, 360.0);
    let top = values
        .iter()
        .map(|v| v.1)
        .chain(reference)
        .fold(0.0f64, f64::max)
        .max(1e-12);
    let height = values.len() as f64 * row + 24.0;
    let mut svg = format!(
        "<svg xmlns=\"http://www.w3.org/2000/svg\" width=\"{:.0}\" height=\"{height:.0}\">",
        label_width + chart + 80.0
    );
    for (i, (name, v, bad)) in values.iter().enumerate() {
        let y = i as f64 * row + 4.0;
        let w = (v / top * chart).max(0.0);
        let _ = write!(
            svg,
            "<text x=\"{:.1}\" y=\"{:.1}\" text-anchor=\"end\">{}</text><rect x=\"{label_width:.1}\" y=\"{y:.1}\" width=\"{w:.1}\" height=\"{:.1}\" fill=\"{}\"><title>{}: {v:.4} {unit}</title></rect><text x=\"{:.1}\" y=\"{:.1}\">{v:.3}</text>",
            label_width - 6.0,
            y + 11.0,
            escape(name),
            row - 4.0,
            if *bad { "#c0392b" } else { "#4a78a8" },
            escape(name),
            label_width + w + 4.0,
            y + 11.0
        );
    }
    if let Some(r) = reference {
        let x = label_width + r / top * chart;
        let _ = write!(
            svg,
            "<line x1=\"{x:.1}\" y1=\"0\" x2=\"{x:.1}\" y2=\"{:.1}\" stroke=\"#000\" stroke-dasharray=\"4 3\"/>",
            height - 20.0
        );
    }
    svg.push_str("</svg>");
    svg
}

/// A DH+2 value, and the true one beside it when known.
fn dh_cell(value: f64, sd: Option<f64>, truth: Option<f64>) -> Markup {
    html! {
        td {
            (format!("{value:.4}"))
            @if let Some(sd) = sd { span class="note" { " ± " (format!("{sd:.4}")) } }
            @if let Some(t) = truth { br; span class="note" { "(" (format!("{t:.4}")) ")" } }
        }
    }
}

fn limbs(
    m: &BodyModel,
    truth: Option<&crate::model::Robot>,
    paper: &[crate::estimate::paper::PaperChainEstimate],
) -> Markup {
    let broken: Vec<&str> = m.broken.iter().map(|b| b.su.as_str()).collect();
    html! {
        section id="limbs" {
            h2 { "Calibrated limbs" }
            @if !m.broken.is_empty() {
                p class="bad" { "Broken SUs set aside: "
                    (m.broken.iter().map(|b| format!("{} ({})", b.su, b.kind)).collect::<Vec<_>>().join(", ")) }
            }
            @if !m.not_calibrated.is_empty() {
                p class="note" { "Not calibrated: "
                    (m.not_calibrated.iter().map(|n| format!("{} {} ({})", n.kind, n.name, n.reason)).collect::<Vec<_>>().join("; ")) }
            }
            @for limb in &m.limbs {
                @let e = &limb.estimate;
                div class="limb" {
                    h3 { "Limb " (limb.name) @if let Some(p) = &limb.parent { " (on " (p) ")" } }
                    p {
                        (limb.dofs.len()) " DoFs (" (limb.dofs.join(", ")) "), " (limb.sus.len()) " SUs; residual "
                        span class=(if e.converged { "" } else { "bad" }) { (format!("{:.3}", e.residual_ratio)) " σ, "
                            (if e.converged { "converged" } else { "NOT CONVERGED" }) }
                        "; " (e.iterations) " iterations"
                        @if e.seconds > 0.0 { " in " (format!("{:.1}", e.seconds * 1e3)) " ms" }
                        "."
                    }
                    h4 { "Residual per SU, in σ (dashed: 1)" }
                    (PreEscaped(bars(
                        &limb.sus.iter().zip(&e.su_residual_ratio)
                            .map(|(su, r)| (su.clone(), *r, *r > 1.5 || broken.contains(&su.as_str()))).collect::<Vec<_>>(),
                        "σ", Some(1.0))))
                    h4 { "SU position uncertainty, mm" }
                    (PreEscaped(bars(
                        &e.uncertainty.iter().map(|u| (u.su.clone(), u.position_sd * 1e3, false)).collect::<Vec<_>>(),
                        "mm", None)))
                    table {
                        tr { th class="name" { "SU" } th { "position sd, mm" } th { "orientation sd, °" } th { "residual, σ" } }
                        @for (u, r) in e.uncertainty.iter().zip(&e.su_residual_ratio) {
                            tr {
                                td class="name" { (u.su) }
                                td { (format!("{:.2}", u.position_sd * 1e3)) }
                                td { (format!("{:.3}", u.orientation_sd.to_degrees())) }
                                td class=(if *r > 1.5 { "bad" } else { "" }) { (format!("{r:.2}")) }
                            }
                        }
                    }
                    @if let (Some(dh), Some(serial)) = (&e.dh, e.chain.as_serial()) {
                        @let true_rows = truth.and_then(|t| crate::estimate::dh_form(t, &serial));
                        @let by_paper = paper.iter().find(|p| p.chain.dofs == serial.dofs && p.chain.sus == serial.sus);
                        h4 { "In the paper's DH+2 form (Fig. 6; m and rad, ± 1σ; the first rows' θ0 and d are a gauge choice)"
                            @if true_rows.is_some() { "; the truth in brackets" }
                            @if by_paper.is_some() { "; the paper's method's estimate below, in italics" } }
                        table {
                            tr { th class="name" { "DoF → DoF" } th { "θ0" } th { "d" } th { "a" } th { "α" } }
                            @for (k, r) in dh.dof_dof.iter().enumerate() {
                                @let t = true_rows.as_ref().and_then(|(rows, _)| rows.get(k)).map(|r| r.values());
                                @let sd = dh.dof_dof_sd.get(k).map(|r| r.values());
                                tr { td class="name" { (serial.dofs[k]) " → " (serial.dofs.get(k + 1).cloned().unwrap_or_default()) }
                                    @for (i, v) in r.values().iter().enumerate() { (dh_cell(*v, sd.map(|s| s[i]), t.map(|t| t[i]))) } }
                                @if let Some(row) = by_paper.and_then(|p| p.dof_dof.get(k)) {
                                    tr class="paper" { td class="name" { i { "paper's method" } }
                                        @for v in row.values() { td { i { (format!("{v:.4}")) } } } }
                                }
                            }
                        }
                        table {
                            tr { th class="name" { "DoF → SU" } th { "θ0" } th { "d" } th { "a" } th { "α" } th { "θacc" } th { "dacc" } }
                            @for (k, r) in dh.dof_su.iter().enumerate() {
                                @let t = true_rows.as_ref().and_then(|(_, rows)| rows.get(k)).map(|r| r.values());
                                @let sd = dh.dof_su_sd.get(k).map(|r| r.values());
                                tr { td class="name" { (serial.dofs[k]) " → " (serial.sus.get(k).cloned().unwrap_or_default()) }
                                    @for (i, v) in r.values().iter().enumerate() { (dh_cell(*v, sd.map(|s| s[i]), t.map(|t| t[i]))) } }
                                @if let Some(row) = by_paper.and_then(|p| p.dof_su.get(k)) {
                                    tr class="paper" { td class="name" { i { "paper's method" } }
                                        @for v in row.values() { td { i { (format!("{v:.4}")) } } } }
                                }
                            }
                        }
                    }
                }
            }
        }
    }
}

fn validation(v: &Validation, name: &str) -> Markup {
    html! {
        section id="validation" {
            h2 { "Held-out check against " (name) }
            p { (v.poses) " poses: static " (format!("{:.4}", v.static_rms)) " m/s² RMS (max " (format!("{:.4}", v.static_max))
                "), dynamic " (format!("{:.4}", v.dynamic_rms)) " m/s² RMS (max " (format!("{:.4}", v.dynamic_max)) ")." }
            h4 { "Static error per SU, m/s² RMS" }
            (PreEscaped(bars(&v.sus.iter().map(|s| (s.su.clone(), s.static_rms, false)).collect::<Vec<_>>(), "m/s²", None)))
            h4 { "Dynamic error per SU, m/s² RMS" }
            (PreEscaped(bars(&v.sus.iter().map(|s| (s.su.clone(), s.dynamic_rms, false)).collect::<Vec<_>>(), "m/s²", None)))
        }
    }
}

/// The robot's own URDF against the calibration, joint by joint.
fn urdf_check(c: &crate::align::UrdfCheck, name: &str) -> Markup {
    use crate::align::JointVerdict as V;
    html! {
        section id="urdf-check" {
            h2 { "The URDF's joints against the calibration" }
            p { (name) " (`" (c.robot) "`), aligned limb by limb on the calibrated axis lines. Per joint: the angle between its axis and the calibrated one and their distance at the URDF joint's origin, ± 1σ of the calibration; a joint disagrees outside the 3σ region of all its components (χ²). "
                @if c.disagree.is_empty() { "Every compared joint agrees." }
                @else { span.bad { (c.disagree.len()) " disagree: " (c.disagree.join(", ")) "." } } }
            p.note { "A turn of a link frame about its own joint's axis or a shift along it (a zero offset, a length along the axis) shows at the next joint; where a limb sits on the reference segment no reading tells." }
            table {
                tr { th.name { "joint" } th { "angle (°)" } th { "distance (mm)" } th { "χ² (components)" } th.name { "verdict" } }
                @for j in &c.joints {
                    tr {
                        td.name { (j.dof) }
                        @if matches!(j.verdict, V::Agrees | V::Disagrees) {
                            td { (format!("{:.3} ± {:.3}", j.angle.to_degrees(), j.angle_sd.to_degrees())) }
                            td { (format!("{:.2} ± {:.2}", j.distance * 1e3, j.distance_sd * 1e3)) }
                            td { (format!("{:.1} ({})", j.chi2, j.components)) }
                        } @else { td {} td {} td {} }
                        td.name {
                            @match j.verdict {
                                V::Agrees => { "agrees" }
                                V::Disagrees => { span.bad { "disagrees" } }
                                V::LimbBase => { span.note { "limb base" } }
                                V::NotCompared => { span.note { "not compared: " (j.note) } }
                            }
                        }
                    }
                }
            }
        }
    }
}

/// The timeline of every log the set was ingested from, and the noise found.
fn recording(r: &IngestReport) -> Markup {
    html! {
        section id="timeline" {
            h2 { "Recordings" }
            p { "Nominal pattern A = " (format!("{:.4}", r.pattern.amplitude)) " rad/s, f = " (format!("{:.3}", r.pattern.frequency))
                " Hz (" (r.pattern_source) ")" @if let Some(n) = r.sample_noise { "; sensor noise in the still windows "
                (format!("{n:.4}")) " m/s² RMS per axis (" (format!("{:.4}", n / crate::model::sensor::STANDARD_GRAVITY)) " g)" } "." }
            p class="note" { "Top band: still windows (green; static readings), short pauses (pale), transfers (grey, skipped), unusable motions (red). One row per DoF: its moves (orange) and excitations (blue, darker the more of the signal came from other DoFs' coupled motion). Hover for times." }
            @for log in &r.logs {
                h3 { (log.path.display().to_string()) " (" (log.format) ", " (format!("{:.1}", log.duration)) " s)" }
                (PreEscaped(timeline_svg(log)))
                @if !r.warnings.is_empty() {
                    ul class="bad" { @for w in &r.warnings { li { (w) } } }
                }
            }
        }
    }
}

fn timeline_svg(log: &LogReport) -> String {
    let mut dofs: Vec<&str> = Vec::new();
    for s in &log.timeline {
        if let Some(d) = &s.dof {
            if !dofs.contains(&d.as_str()) {
                dofs.push(d);
            }
        }
    }
    let (label, width, row) = (110.0, 860.0, 16.0);
    let duration = log.duration.max(1e-9);
    let x = |t: f64| label + t / duration * width;
    let height = (dofs.len() as f64 + 1.0) * row + 30.0;
    let mut svg = format!(
        "<svg xmlns=\"http://www.w3.org/2000/svg\" width=\"{:.0}\" height=\"{height:.0}\">",
        label + width + 10.0
    );
    let _ = write!(
        svg,
        "<text x=\"{:.1}\" y=\"12\" text-anchor=\"end\">windows</text>",
        label - 6.0
    );
    for (i, d) in dofs.iter().enumerate() {
        let _ = write!(
            svg,
            "<text x=\"{:.1}\" y=\"{:.1}\" text-anchor=\"end\">{}</text>",
            label - 6.0,
            (i as f64 + 1.0) * row + 12.0,
            escape(d)
        );
    }
    for s in &log.timeline {
        let coupled = log
            .fits
            .iter()
            .find(|f| {
                s.dof.as_deref() == Some(f.dof.as_str())
                    && f.start <= (s.start + s.end) / 2.0
                    && (s.start + s.end) / 2.0 <= f.start + f.duration
            })
            .map(|f| f.coupled);
        let (y, fill, note) = match (s.kind.as_str(), &s.dof) {
            ("still", _) => (0.0, "#59a14f".to_string(), String::new()),
            ("pause", _) => (0.0, "#cfe8c8".to_string(), String::new()),
            ("transfer", _) => (0.0, "#999".to_string(), String::new()),
            ("broken", _) => (0.0, "#c0392b".to_string(), String::new()),
            (kind, Some(d)) => {
                let r = (dofs.iter().position(|x| x == d).unwrap_or(0) as f64 + 1.0) * row;
                if kind == "move" {
                    (r, "#f28e2b".to_string(), String::new())
                } else {
                    let share = coupled.unwrap_or(0.0);
                    let light = (75.0 - 45.0 * share.min(1.0)).round();
                    (
                        r,
                        format!("hsl(210, 70%, {light}%)"),
                        coupled.map_or(String::new(), |c| {
                            format!(", {:.0} % of the signal from other DoFs", c * 100.0)
                        }),
                    )
                }
            }
            _ => continue,
        };
        let _ = write!(
            svg,
            "<rect x=\"{:.2}\" y=\"{:.1}\" width=\"{:.2}\" height=\"{:.1}\" fill=\"{fill}\"><title>{}{} {:.2}–{:.2} s{}</title></rect>",
            x(s.start),
            y + 2.0,
            (x(s.end) - x(s.start)).max(0.5),
            row - 3.0,
            escape(&s.kind),
            s.dof.as_ref().map_or(String::new(), |d| format!(" of {}", escape(d))),
            s.start,
            s.end,
            note
        );
    }
    let axis = (dofs.len() as f64 + 1.0) * row + 4.0;
    let _ = write!(
        svg,
        "<line x1=\"{label:.1}\" y1=\"{axis:.1}\" x2=\"{:.1}\" y2=\"{axis:.1}\" stroke=\"#333\"/>",
        label + width
    );
    let step = [1.0, 2.0, 5.0, 10.0, 20.0, 50.0, 100.0, 200.0, 500.0, 1000.0]
        .into_iter()
        .find(|s| duration / s <= 12.0)
        .unwrap_or(2000.0);
    let mut t = 0.0;
    while t <= duration {
        let _ = write!(
            svg,
            "<text x=\"{:.1}\" y=\"{:.1}\" text-anchor=\"middle\">{t:.0} s</text>",
            x(t),
            axis + 16.0
        );
        t += step;
    }
    svg.push_str("</svg>");
    svg
}

/// The script of the 3D view: forward kinematics of the embedded body and an orthographic
/// drawing on a canvas, turned by dragging.
const VIEW3D: &str = r#"(function () {
  var data = JSON.parse(document.getElementById('body-data').textContent);
  var canvas = document.getElementById('view3d'), ctx = canvas.getContext('2d');
  var q = data.dofs.map(function () { return 0; });
  var yaw = 0.7, pitch = 0.35, zoom = 1;
  function mul(a, b) { // rigid transforms {r: 3x3 row-major, p: [3]}
    var r = [], p = [];
    for (var i = 0; i < 3; i++) {
      for (var j = 0; j < 3; j++) {
        r[3 * i + j] = a.r[3 * i] * b.r[j] + a.r[3 * i + 1] * b.r[3 + j] + a.r[3 * i + 2] * b.r[6 + j];
      }
      p[i] = a.r[3 * i] * b.p[0] + a.r[3 * i + 1] * b.p[1] + a.r[3 * i + 2] * b.p[2] + a.p[i];
    }
    return { r: r, p: p };
  }
  function turn(k, t) { // rotation by t about the unit axis k
    var c = Math.cos(t), s = Math.sin(t), v = 1 - c, x = k[0], y = k[1], z = k[2];
    return { r: [c + x * x * v, x * y * v - z * s, x * z * v + y * s,
                 y * x * v + z * s, c + y * y * v, y * z * v - x * s,
                 z * x * v - y * s, z * y * v + x * s, c + z * z * v], p: [0, 0, 0] };
  }
  function apply(t, v) { return mul(t, { r: [1, 0, 0, 0, 1, 0, 0, 0, 1], p: v }).p; }
  function frames() {
    var seg = [{ r: [1, 0, 0, 0, 1, 0, 0, 0, 1], p: [0, 0, 0] }], joints = [];
    data.dofs.forEach(function (d, i) {
      var j = mul(seg[d.parent], { r: d.r, p: d.o });
      joints[i] = j;
      seg[d.child] = mul(j, turn(d.axis, q[i]));
    });
    return { seg: seg, joints: joints };
  }
  function project(v) {
    var cy = Math.cos(yaw), sy = Math.sin(yaw), cp = Math.cos(pitch), sp = Math.sin(pitch);
    var x = cy * v[0] + sy * v[1], y = -sy * v[0] + cy * v[1];
    var up = cp * v[2] - sp * y;
    var s = zoom * canvas.height / (2.4 * data.extent);
    return [canvas.width / 2 + s * (x - data.centre[0]), canvas.height / 2 - s * (up - data.centre[2])];
  }
  function line(a, b, colour, width) {
    var p = project(a), r = project(b);
    ctx.strokeStyle = colour; ctx.lineWidth = width;
    ctx.beginPath(); ctx.moveTo(p[0], p[1]); ctx.lineTo(r[0], r[1]); ctx.stroke();
  }
  function draw() {
    var f = frames(), axis = data.extent * 0.08, triad = data.extent * 0.05;
    ctx.clearRect(0, 0, canvas.width, canvas.height);
    data.dofs.forEach(function (d, i) { // the segment: from its parent's joint to this joint
      var from = data.parent_joint[d.parent];
      line(from < 0 ? [0, 0, 0] : f.joints[from].p, f.joints[i].p, '#888', 3);
      var z = apply(f.joints[i], d.axis.map(function (c) { return c * axis; }));
      var back = apply(f.joints[i], d.axis.map(function (c) { return -c * axis; }));
      line(back, z, '#222', 2);
    });
    var s = zoom * canvas.height / (2.4 * data.extent);
    data.sus.forEach(function (u) {
      var t = mul(f.seg[u.seg], { r: u.r, p: u.p }), from = data.parent_joint[u.seg];
      line(from < 0 ? [0, 0, 0] : f.joints[from].p, t.p, '#ccc', 1);
      ['#d62728', '#2ca02c', '#1f77b4'].forEach(function (colour, k) {
        var e = [0, 0, 0]; e[k] = triad; line(t.p, apply(t, e), colour, 2);
      });
      var c = project(t.p);
      ctx.strokeStyle = 'rgba(230, 159, 0, 0.9)'; ctx.lineWidth = 1;
      ctx.beginPath(); ctx.arc(c[0], c[1], Math.max(2, u.sd * s), 0, 2 * Math.PI); ctx.stroke();
    });
  }
  var box = document.getElementById('view3d-sliders');
  data.dofs.forEach(function (d, i) {
    var label = document.createElement('label'), input = document.createElement('input');
    input.type = 'range'; input.min = d.lower; input.max = d.upper; input.step = 0.01; input.value = 0;
    input.addEventListener('input', function () { q[i] = parseFloat(input.value); draw(); });
    label.appendChild(document.createTextNode(d.name + ' '));
    label.appendChild(input);
    box.appendChild(label);
  });
  var dragging = null;
  canvas.addEventListener('mousedown', function (e) { dragging = [e.clientX, e.clientY]; });
  window.addEventListener('mouseup', function () { dragging = null; });
  window.addEventListener('mousemove', function (e) {
    if (!dragging) { return; }
    yaw += (e.clientX - dragging[0]) * 0.01;
    pitch = Math.max(-1.5, Math.min(1.5, pitch + (e.clientY - dragging[1]) * 0.01));
    dragging = [e.clientX, e.clientY];
    draw();
  });
  canvas.addEventListener('wheel', function (e) {
    e.preventDefault(); zoom *= e.deltaY < 0 ? 1.1 : 1 / 1.1; draw();
  }, { passive: false });
  // `#pose=0.3` in the address sets every DoF (for checking the drawing against the model).
  var pose = /pose=([-0-9.e]+)/.exec(location.hash);
  if (pose) {
    q = q.map(function () { return parseFloat(pose[1]); });
    box.querySelectorAll('input').forEach(function (input) { input.value = pose[1]; });
  }
  draw();
  var f = frames();
  document.getElementById('view3d-sus').textContent = JSON.stringify(data.sus.map(function (u) {
    return [u.name, mul(f.seg[u.seg], { r: u.r, p: u.p }).p];
  }));
})();"#;

/// The calibrated body for the 3D view: every DoF's joint frame on its parent segment and axis,
/// every SU's frame on its segment and position uncertainty, at the zero pose.
fn body_data(m: &BodyModel) -> Option<serde_json::Value> {
    let robot = m.check().ok()?;
    let model = &robot.model;
    let k =
        crate::model::forward_kinematics(model, &robot.parameters, &vec![0.0; model.dofs().len()]);
    let frame = |t: &nalgebra::Isometry3<f64>| {
        let r = t.rotation.to_rotation_matrix();
        let r: Vec<f64> = (0..9).map(|i| r[(i / 3, i % 3)]).collect();
        (r, t.translation.vector)
    };
    // DoFs in the order their parents are known (segments are topological).
    let mut order: Vec<usize> = (0..model.dofs().len()).collect();
    order.sort_by_key(|&d| model.dofs()[d].child);
    let mut parent_joint = vec![-1i64; model.segments().len()];
    let mut dofs = Vec::new();
    for (i, &d) in order.iter().enumerate() {
        let dof = &model.dofs()[d];
        parent_joint[dof.child] = i as i64;
        let (r, o) = frame(&(k.segments[dof.parent].inverse() * k.joints[d]));
        let finite = |v: f64, or: f64| if v.is_finite() { v } else { or };
        dofs.push(serde_json::json!({
            "name": dof.name, "parent": dof.parent, "child": dof.child,
            "r": r, "o": [o.x, o.y, o.z], "axis": dof.axis.as_ref().as_slice(),
            "lower": finite(dof.limits.lower, -std::f64::consts::PI),
            "upper": finite(dof.limits.upper, std::f64::consts::PI),
        }));
    }
    let sd: BTreeMap<&str, f64> = m
        .limbs
        .iter()
        .flat_map(|l| {
            l.estimate
                .uncertainty
                .iter()
                .map(|u| (u.su.as_str(), u.position_sd))
        })
        .collect();
    let sus: Vec<serde_json::Value> = model
        .sus()
        .iter()
        .enumerate()
        .map(|(u, su)| {
            let (r, p) = frame(&(k.segments[su.segment].inverse() * k.sus[u]));
            serde_json::json!({
                "name": su.name, "seg": su.segment, "r": r, "p": [p.x, p.y, p.z],
                "sd": sd.get(su.name.as_str()).copied().unwrap_or(0.0),
            })
        })
        .collect();
    let points: Vec<nalgebra::Vector3<f64>> = k
        .joints
        .iter()
        .chain(&k.sus)
        .map(|t| t.translation.vector)
        .chain(std::iter::once(nalgebra::Vector3::zeros()))
        .collect();
    let (lo, hi) = points.iter().fold(
        (
            nalgebra::Vector3::repeat(f64::MAX),
            nalgebra::Vector3::repeat(f64::MIN),
        ),
        |(lo, hi), p| (lo.inf(p), hi.sup(p)),
    );
    let centre = (lo + hi) / 2.0;
    Some(serde_json::json!({
        "dofs": dofs, "sus": sus, "parent_joint": parent_joint,
        "centre": [centre.x, centre.y, centre.z],
        "extent": ((hi - lo).amax() / 2.0).max(0.05),
    }))
}

fn view3d(m: &BodyModel) -> Markup {
    let Some(data) = body_data(m) else {
        return html! {};
    };
    // Inside a script element only `</` could end it early.
    let json = data.to_string().replace("</", "<\\/");
    html! {
        section id="view3d-section" {
            h2 { "The calibrated body" }
            p class="note" { "At the zero pose, in the body frame (z up): segments grey, joint axes black, each SU's frame as a triad (x red, y green, z blue) and its position uncertainty as an orange circle (to scale). Every limb on the static reference segment starts at its origin: where a limb sits on it, and how it is turned about the vertical, no accelerometer reading tells. Drag to turn, wheel to zoom; a slider per DoF." }
            canvas id="view3d" width="900" height="600" style="border: 1px solid #ddd; cursor: grab" {}
            div id="view3d-sliders" style="columns: 3; font-size: 12px" {}
            // Where the drawing put every SU, for checking it against the model.
            pre id="view3d-sus" hidden {}
            script type="application/json" id="body-data" { (PreEscaped(json)) }
            script { (PreEscaped(VIEW3D)) }
        }
    }
}
