//! The HTML report: one self-contained page (inline CSS, SVG, script and uPlot for the charts;
//! nothing fetched) made from whatever a result directory holds. Every section appears only when
//! its inputs do, one module each:
//!
//! - `summary` (here): what the directory holds;
//! - `structure`: the activity matrices (the paper's Fig. 2: SUs × DoFs as explored, per base
//!   orientation, and segments × joints merged, uncertain entries marked) and the kinematic tree;
//! - `body3d`: the calibrated body in 3D, limbs where the URDF puts them (else a layout),
//!   turned with the mouse, a slider per DoF;
//! - `limbs`: per limb the fit, its residuals and uncertainties, every reading's whitened
//!   residual (normal quantile plot, histogram), the pose errors against the truth beside the
//!   Cramér–Rao bound (Fig. 6), the DH+2 table;
//! - `checks`: held-out errors per SU against the noise floor, the URDF's joints, what was set
//!   aside and why;
//! - `timeline`: for logs, each recording's windows, moves and excitations per DoF.
//!
//! Charts are drawn by `charts`: their numbers are in the page as JSON. A script catches
//! JavaScript errors into `#script-errors`, so that a headless browser's DOM says whether the page
//! ran cleanly; the page records how long it took to draw in `data-drawn-ms`.

mod body3d;
mod charts;
mod checks;
mod limbs;
mod structure;
mod timeline;

use std::collections::BTreeMap;

use maud::{html, Markup, PreEscaped, DOCTYPE};
use nalgebra::Isometry3;

use crate::estimate::body::BodyModel;
use crate::explore::Structure;
use crate::ingest::IngestReport;
use crate::measurements::MeasurementSet;
use crate::predict::Validation;
use body3d::{Bases, Colouring};

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
    /// Where the URDF alignment puts every SU at the zero pose, in the URDF's root frame: the 3D
    /// view places the limbs on the reference segment by it.
    pub urdf_su_frames: BTreeMap<String, Isometry3<f64>>,
    /// The skin checked against ordinary motion, and the logs' names.
    pub check: Option<(crate::check::CheckReport, String)>,
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
figure.chart { display: inline-block; vertical-align: top; margin: 0.5rem 1.5rem 0.8rem 0; }
figure.chart figcaption { font-size: 12px; color: #555; max-width: 700px; }
.scroll { overflow-x: auto; }
.u-legend td, .u-legend th { border: none; background: none; padding: 0 4px; }
figure, table, svg, canvas, .uplot { break-inside: avoid; page-break-inside: avoid; }
h2, h3, h4 { break-after: avoid; page-break-after: avoid; }
@media print {
  body { max-width: none; padding: 0; font-size: 11px; }
  .scroll { overflow: visible; } .scroll svg { max-width: 100%; height: auto; }
  #view3d-sliders { display: none; } canvas { max-width: 100%; height: auto !important; }
  section { break-before: page; } section#summary { break-before: auto; }
}
";

const ERROR_HOOK: &str = "window.addEventListener('error', function (e) {
  var box = document.getElementById('script-errors');
  if (box) { box.textContent += (e.message || 'error') + '\\n'; }
});";

/// The report page.
///
/// ```
/// use skincal::explore::{explore, ExploreConfig};
/// use skincal::html::{render, ReportInputs};
/// use skincal::model::presets;
/// use skincal::sim::{simulate, SimulationConfig};
///
/// let robot = presets::find("paper-7dof").unwrap().robot().unwrap();
/// let set = simulate(&robot, &SimulationConfig { training: false, ..SimulationConfig::default() }).unwrap().measurements;
/// let structure = explore(&set, &ExploreConfig::default()).unwrap();
/// let page = render(&ReportInputs {
///     title: "paper arm".into(),
///     structure: Some(structure),
///     measurements: Some(set),
///     ..ReportInputs::default()
/// });
/// assert!(page.starts_with("<!DOCTYPE html>") && page.contains("paper arm"));
/// ```
pub fn render(inputs: &ReportInputs) -> String {
    let residuals = match (&inputs.model, &inputs.measurements) {
        (Some(m), Some(set)) => {
            crate::predict::whitened_residuals(m, set, "the measurement set").ok()
        }
        _ => None,
    };
    let bases = if inputs.urdf_su_frames.is_empty() {
        Bases::Layout
    } else {
        inputs.model.as_ref().map_or(Bases::Layout, |m| {
            Bases::Urdf(body3d::urdf_bases(m, &inputs.urdf_su_frames))
        })
    };
    let colouring = colouring(inputs);
    let truth_errors = match (&inputs.model, &inputs.truth) {
        (Some(m), Some(t)) => limbs::all_truth_errors(m, t, inputs.measurements.as_ref()),
        _ => BTreeMap::new(),
    };
    let page = html! {
        (DOCTYPE)
        html lang="en" {
            head {
                meta charset="utf-8";
                title { "skincal report — " (inputs.title) }
                style { (PreEscaped(STYLE)) (PreEscaped(charts::UPLOT_CSS)) }
                script { (PreEscaped(ERROR_HOOK)) }
                script { (PreEscaped(charts::UPLOT_JS)) }
            }
            body {
                h1 { "skincal report — " (inputs.title) }
                pre id="script-errors" {}
                (summary(inputs))
                @if let Some(s) = &inputs.structure {
                    section id="activity" {
                        h2 { "Activity matrix (Fig. 2)" }
                        @if let Some(set) = &inputs.measurements { (structure::su_activity(s, set)) }
                        (structure::activity(s))
                    }
                    (structure::tree(s))
                }
                @if let Some(m) = &inputs.model {
                    (body3d::view3d(m, &bases, &colouring))
                    (limbs::limbs(m, &limbs::LimbInputs {
                        truth: inputs.truth.as_ref(),
                        paper: &inputs.paper,
                        residuals: residuals.as_deref(),
                        truth_errors: &truth_errors,
                    }))
                }
                @if let Some((v, name)) = &inputs.validation {
                    (checks::validation(v, name))
                }
                @if let Some((c, name)) = &inputs.urdf_check {
                    (checks::urdf_check(c, name))
                }
                @if let Some((r, name)) = &inputs.check {
                    (checks::skin_check(r, name))
                }
                @if let Some(m) = inputs.model.as_ref().filter(|m| !m.changes.is_empty()) {
                    (checks::model_changes(&m.changes))
                }
                @if inputs.structure.is_some() || inputs.model.is_some() {
                    (checks::set_aside(inputs.structure.as_ref(), inputs.model.as_ref()))
                }
                @if let Some(r) = &inputs.ingest {
                    (timeline::recording(r))
                }
                script { (PreEscaped(charts::DRAW)) }
            }
        }
    };
    page.into_string()
}

/// What colours the SUs of the 3D view: their held-out static error when the model was checked,
/// else their position uncertainty.
fn colouring(inputs: &ReportInputs) -> Colouring {
    match (&inputs.validation, &inputs.model) {
        (Some((v, _)), _) => Colouring {
            what: "the held-out static error".into(),
            values: v.sus.iter().map(|s| (s.su.clone(), s.static_rms)).collect(),
        },
        (None, Some(m)) => Colouring {
            what: "the position uncertainty".into(),
            values: m
                .limbs
                .iter()
                .flat_map(|l| &l.estimate.uncertainty)
                .map(|u| (u.su.clone(), u.position_sd))
                .collect(),
        },
        _ => Colouring {
            what: "nothing".into(),
            values: BTreeMap::new(),
        },
    }
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
                @if let Some((r, name)) = &inputs.check {
                    li { "Skin checked against " (name) " (" (format!("{:.1}", r.seconds)) " s of motion): "
                        (r.changed().count()) " SU(s) changed"
                        @if let Some(z) = &r.zero { ", the zero of " (z.dof) " moved" } "." }
                }
                @if let Some(m) = inputs.model.as_ref().filter(|m| !m.changes.is_empty()) {
                    li { (m.changes.len()) " change(s) made by recalibration since the calibration." }
                }
            }
        }
    }
}
