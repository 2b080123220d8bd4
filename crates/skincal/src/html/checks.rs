//! The calibration checked: against a held-out measurement set (per SU, with the noise floor),
//! the robot's own URDF joint by joint, and the skin against ordinary motion (`check`), with what
//! recalibrations changed since.

use maud::{html, Markup};

use super::charts::{Chart, Mark, Series};
use crate::check::{CheckReport, ModelChange, SuCheck, Verdict};
use crate::estimate::body::BodyModel;
use crate::explore::{Diagnostic, Severity, Structure};
use crate::model::sensor::STANDARD_GRAVITY;
use crate::predict::Validation;

/// The held-out check: per SU the static and dynamic error against the floor the readings' own
/// noise sets.
pub(super) fn validation(v: &Validation, name: &str) -> Markup {
    let labels: Vec<String> = v.sus.iter().map(|s| s.su.clone()).collect();
    let n = labels.len();
    let statics = Chart::categories(labels.clone(), "SU", "m/s² RMS")
        .with(Series::new(
            "static error",
            Mark::Bars,
            "#4a78a8",
            v.sus.iter().map(|s| s.static_rms).collect(),
        ))
        .with(Series::level("noise floor", v.static_floor, n));
    // An SU that no excited DoF moves has no dynamic reading: a gap, not a zero.
    let mut dynamic = Series::new("dynamic error", Mark::Bars, "#e15759", Vec::new());
    dynamic.values = v
        .sus
        .iter()
        .map(|s| (s.dynamic_count > 0).then_some(s.dynamic_rms))
        .collect();
    let dynamics = Chart::categories(labels, "SU", "m/s² RMS")
        .with(dynamic)
        .with(Series::level("noise floor", v.dynamic_floor, n));
    let dof_labels: Vec<String> = v.dofs.iter().map(|d| d.dof.clone()).collect();
    let per_dof = Chart::categories(dof_labels, "excited DoF", "m/s² RMS")
        .with(Series::new(
            "dynamic error",
            Mark::Bars,
            "#e15759",
            v.dofs.iter().map(|d| d.dynamic_rms).collect(),
        ))
        .with(Series::level("noise floor", v.dynamic_floor, v.dofs.len()));
    let without: Vec<&str> = v
        .sus
        .iter()
        .filter(|s| s.dynamic_count == 0)
        .map(|s| s.su.as_str())
        .collect();
    html! {
        section id="validation" {
            h2 { "Held-out check against " (name) }
            p { (v.poses) " poses: static " (format!("{:.4}", v.static_rms)) " m/s² RMS (max " (format!("{:.4}", v.static_max))
                "), dynamic " (format!("{:.4}", v.dynamic_rms)) " m/s² RMS (max " (format!("{:.4}", v.dynamic_max)) "). "
                "A perfect model would show the readings' own noise: static " (format!("{:.4}", v.static_floor))
                ", dynamic " (format!("{:.4}", v.dynamic_floor)) " m/s² RMS (from " (v.floor_source) ")." }
            (statics.figure(html! { "Static error per SU, m/s² RMS; dashed: the noise floor." }))
            (dynamics.figure(html! { "Dynamic error per SU, m/s² RMS; dashed: the noise floor."
                @if !without.is_empty() { " No DoF excited in the set moves " (without.join(", ")) ": no dynamic reading, no bar." } }))
            @if !v.dofs.is_empty() {
                (per_dof.figure(html! { "Dynamic error per excited DoF (every SU it moves, in every pose), m/s² RMS; dashed: the noise floor; " (crate::predict::UNEVEN_DOFS) "." }))
            }
        }
    }
}

/// The robot's own URDF against the calibration, joint by joint.
pub(super) fn urdf_check(c: &crate::align::UrdfCheck, name: &str) -> Markup {
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

/// Everything left out along the way and why: SUs found broken, DoFs and SUs outside the tree or
/// not calibrated, readings the fit set aside, and the structure's findings.
pub(super) fn set_aside(s: Option<&Structure>, m: Option<&BodyModel>) -> Markup {
    let mut rows: Vec<(String, String, String)> = Vec::new();
    if let Some(s) = s {
        for b in &s.broken {
            rows.push((format!("SU ({})", b.kind), b.su.clone(), b.detail.clone()));
        }
        for su in s
            .unplaced_sus
            .iter()
            .filter(|u| !s.broken.iter().any(|b| &b.su == *u))
        {
            rows.push((
                "SU".into(),
                su.clone(),
                "left out of the tree by the structure experiment (see its findings below)".into(),
            ));
        }
        for dof in &s.unplaced_dofs {
            rows.push((
                "DoF".into(),
                dof.clone(),
                "left out of the tree by the structure experiment (see its findings below)".into(),
            ));
        }
    }
    if let Some(m) = m {
        for b in &m.broken {
            rows.push((format!("SU ({})", b.kind), b.su.clone(), b.detail.clone()));
        }
        for n in &m.not_calibrated {
            rows.push((
                n.kind.to_uppercase().replace("DOF", "DoF"),
                n.name.clone(),
                n.reason.clone(),
            ));
        }
        for limb in &m.limbs {
            for r in &limb.estimate.rejected {
                rows.push((
                    "readings".into(),
                    r.su.clone(),
                    format!(
                        "limb {}: {} static and {} dynamic of its {} readings left out as wild (far beyond the noise after the fit)",
                        limb.name, r.static_readings, r.dynamic_readings, r.readings
                    ),
                ));
            }
        }
    }
    let findings: Vec<&Diagnostic> = s
        .map(|s| {
            s.diagnostics
                .iter()
                .filter(|d| d.severity != Severity::Info)
                .collect()
        })
        .unwrap_or_default();
    html! {
        section id="set-aside" {
            h2 { "Set aside, and why" }
            @if rows.is_empty() && findings.is_empty() {
                p { "Nothing: every SU and DoF of the set is in the tree and calibrated, and no reading was left out." }
            }
            @if !rows.is_empty() {
                table {
                    tr { th.name { "what" } th.name { "name" } th.name { "why" } }
                    @for (what, name, why) in &rows {
                        tr { td.name { (what) } td.name { (name) } td.name { (why) } }
                    }
                }
            }
            @if !findings.is_empty() {
                h4 { "Findings of the structure experiment" }
                ul {
                    @for d in &findings {
                        li class=(if d.severity == Severity::Error { "bad" } else { "" }) { (d.message) }
                    }
                }
            }
        }
    }
}

/// The skin checked against ordinary motion: how strongly each SU's readings call for a change,
/// the SUs that changed with what was found and what to do, a DoF whose zero moved.
pub(super) fn skin_check(r: &CheckReport, name: &str) -> Markup {
    let labels: Vec<String> = r.sus.iter().map(|s| s.su.clone()).collect();
    let n = labels.len();
    // −log₁₀ p, capped where the χ² tail underflows.
    let evidence = |p: f64| (-p.max(1e-300).log10()).max(0.0);
    let chart = Chart::categories(labels, "SU", "−log₁₀ p")
        .with(Series::new(
            "evidence of a change",
            Mark::Bars,
            "#4a78a8",
            r.sus.iter().map(|s| evidence(s.p_value)).collect(),
        ))
        .with(Series::level(
            "false-alarm level",
            evidence(r.config.false_alarm),
            n,
        ));
    let changed: Vec<&SuCheck> = r.changed().collect();
    let untold: Vec<&SuCheck> = r
        .sus
        .iter()
        .filter(|s| s.verdict == Verdict::NotEnoughMotion)
        .collect();
    let norm = |v: [f64; 3]| nalgebra::Vector3::from(v).norm();
    html! {
        section id="skin-check" {
            h2 { "The skin checked against " (name) }
            p { (format!("{:.1}", r.seconds)) " s of motion; changes looked for: "
                (format!("{:.0} mm, {:.1}°, {:.3} g, {:.1} % sensitivity", r.config.detect_position * 1e3,
                    r.config.detect_orientation.to_degrees(), r.config.detect_bias / STANDARD_GRAVITY,
                    r.config.detect_scale * 1e2))
                ", at most " (r.config.false_alarm) " false alarms per SU. "
                (r.sus.len() - changed.len() - untold.len()) " SUs read what the model predicts, "
                (untold.len()) " the motion does not tell. "
                @if changed.is_empty() && r.zero.is_none() { "Nothing changed." }
                @else { span.bad { (changed.len()) " SU(s) changed" @if r.zero.is_some() { ", a DoF's zero moved" } "." } } }
            @if let Some(z) = &r.zero {
                p.bad { "The zero of " (z.dof) " moved: it stands " (format!("{:.3}° ± {:.3}°", z.offset.to_degrees(), z.offset_sd.to_degrees()))
                    " from what its encoder says; every SU beyond it (" (z.sus.join(", ")) ") tells the same. `check --recalibrate` sets it again." }
            }
            (chart.figure(html! { "Per SU, how strongly its readings call for a change of its place, bias or sensitivity (the Wald test over the directions the motion tells); above the dashed line it changed." }))
            @if !changed.is_empty() {
                table {
                    tr { th.name { "SU" } th.name { "verdict" } th { "shift (mm)" } th { "turn (°)" } th { "bias (mg)" } th { "scale (%)" } th { "residual" } th.name { "what to do" } }
                    @for s in &changed {
                        tr {
                            td.name { (s.su) }
                            td.name { span.bad { (s.verdict.word()) } }
                            @if let Some(c) = &s.change {
                                td { (format!("{:.1}", norm(c.shift) * 1e3)) }
                                td { (format!("{:.2}", norm(c.turn).to_degrees())) }
                                td { (format!("{:.1}", norm(c.bias) / STANDARD_GRAVITY * 1e3)) }
                                td { (format!("{:.2}", largest(c.scale) * 1e2)) }
                            } @else { td {} td {} td {} td {} }
                            td { (format!("{:.2}", s.residual_ratio)) }
                            td.name { (s.advice) }
                        }
                    }
                }
            }
            @if !r.alike.is_empty() {
                p.note { "Read alike in every pose, so that no motion tells an exchange of the two: "
                    @for (i, [a, b]) in r.alike.iter().enumerate() { @if i > 0 { "; " } (a) " and " (b) } "." }
            }
            @if !untold.is_empty() {
                p.note { "Not told by this motion: " @for (i, s) in untold.iter().enumerate() { @if i > 0 { "; " } (s.su) " — " (s.untold) } "." }
            }
        }
    }
}

/// What recalibrations changed in the model since it was calibrated, oldest first.
pub(super) fn model_changes(changes: &[ModelChange]) -> Markup {
    let distance =
        |a: [f64; 3], b: [f64; 3]| (nalgebra::Vector3::from(a) - nalgebra::Vector3::from(b)).norm();
    html! {
        section id="model-changes" {
            h2 { "Changes since the calibration" }
            p { "What `check --recalibrate` changed, oldest first; everything else is as calibrated." }
            table {
                tr { th.name { "what" } th.name { "found" } th { "moved (mm)" } th { "bias change (mg)" } th { "scale change (%)" } th.name { "from the log(s)" } }
                @for c in changes {
                    tr {
                        @match c {
                            ModelChange::Su(s) => {
                                td.name { (s.su) }
                                td.name { (s.verdict.word()) }
                                td { (format!("{:.1}", distance(s.after.xyz, s.before.xyz) * 1e3)) }
                                td { (format!("{:.1}", distance(s.bias_after, s.bias_before) / STANDARD_GRAVITY * 1e3)) }
                                td { (format!("{:.2}", largest(std::array::from_fn(|k| s.scale_after[k] - s.scale_before[k])) * 1e2)) }
                                td.name { (s.logs.join(", ")) }
                            }
                            ModelChange::Zero { dof, offset, logs } => {
                                td.name { (dof) }
                                td.name { "zero set again by " (format!("{:.3}°", offset.to_degrees())) }
                                td {} td {} td {}
                                td.name { (logs.join(", ")) }
                            }
                        }
                    }
                }
            }
        }
    }
}

/// The largest of three components in magnitude.
fn largest(v: [f64; 3]) -> f64 {
    v.iter().fold(0.0, |m: f64, x| m.max(x.abs()))
}
