//! The calibrated limbs: per limb the fit, its residuals (per SU, and every reading's whitened
//! residual as a normal quantile plot and a histogram), the SUs' pose uncertainty, their pose
//! error against the truth beside the Cramér–Rao bound (the paper's Fig. 6) when a truth is at
//! hand, and the paper's DH+2 table.

use std::collections::BTreeMap;

use maud::{html, Markup};

use super::charts::{normal_quantiles, Chart, Mark, Series};
use crate::estimate::body::{BodyLimb, BodyModel};
use crate::estimate::ml::{self, MlConfig};
use crate::estimate::paper::PaperChainEstimate;
use crate::estimate::{ChainAccuracy, LimbData, ACCURACY_POSES, ACCURACY_SEED};
use crate::measurements::MeasurementSet;
use crate::model::Robot;
use crate::predict::SuResiduals;

/// The most points a normal quantile plot draws (evenly spaced ranks of the sorted residuals).
const QQ_POINTS: usize = 400;
/// The histogram's bins: whitened residuals from −`HISTOGRAM_RANGE` to +`HISTOGRAM_RANGE`.
const HISTOGRAM_RANGE: f64 = 5.0;
const HISTOGRAM_BINS: usize = 40;

/// The most SUs of a limb whose Cramér–Rao bound the page computes: the bound's cost grows with
/// the cube of the number of SUs (a dense Fisher information and its eigenvectors), seconds beyond.
pub(super) const BOUND_MAX_SUS: usize = 100;

/// A limb's SU pose errors against the truth (the paper's Fig. 6) and the Cramér–Rao bound.
pub(super) struct TruthErrors {
    pub accuracy: ChainAccuracy,
    /// The bound on the RMS position error of the pairs after the first, m, where the readings
    /// determine the errors (none for a sub-limb or a single SU).
    pub position_bound: Option<f64>,
    pub rotation_bound: Option<f64>,
    /// The limb's number of SUs.
    pub sus: usize,
}

/// The errors of `limb` against `truth` (`None` where the truth does not name its DoFs and SUs).
pub(super) fn truth_errors(
    m: &BodyModel,
    limb: &BodyLimb,
    truth: &Robot,
    set: Option<&MeasurementSet>,
) -> Option<TruthErrors> {
    let e = &limb.estimate;
    let accuracy = crate::estimate::consecutive_su_errors(
        truth,
        &e.to_robot(),
        &e.chain,
        ACCURACY_POSES,
        ACCURACY_SEED,
    )
    .ok()?;
    let gravity = nalgebra::Vector3::from(e.gravity);
    // The estimate in the estimator's chart (a model read from a file has only its robot).
    let state = e
        .state
        .clone()
        .or_else(|| ml::state_of(&e.to_robot(), &e.chain, &gravity));
    let bound = set
        .zip(state.as_ref())
        .filter(|_| limb.sus.len() <= BOUND_MAX_SUS)
        .and_then(|(set, state)| {
            let data = LimbData::new(set, &e.chain).ok()?;
            let config = MlConfig {
                noise_sd: m.noise_sd,
                intrinsics: e.intrinsics_model.unwrap_or_default(),
                ..MlConfig::default()
            };
            ml::observable_su_errors(
                truth,
                &gravity,
                state,
                &data,
                &config,
                ACCURACY_POSES,
                ACCURACY_SEED,
            )
        });
    Some(TruthErrors {
        accuracy,
        position_bound: bound.as_ref().map(|b| b.position_bound),
        rotation_bound: bound.as_ref().map(|b| b.rotation_bound),
        sus: limb.sus.len(),
    })
}

/// A DH+2 value with its standard deviation, the true one beside it when known; `gauge` for the
/// first rows' θ0 and d, which no reading determines (a choice of the estimator, not a
/// measurement: no deviation).
fn dh_cell(value: f64, sd: Option<f64>, truth: Option<f64>, gauge: bool) -> Markup {
    html! {
        td {
            (format!("{value:.4}"))
            @if gauge { span class="note" { " (gauge)" } }
            @else if let Some(sd) = sd { span class="note" { " ± " (format!("{sd:.4}")) } }
            @if let Some(t) = truth { br; span class="note" { "(" (format!("{t:.4}")) ")" } }
        }
    }
}

/// What the limbs section shows besides the model.
pub(super) struct LimbInputs<'a> {
    pub truth: Option<&'a Robot>,
    pub paper: &'a [PaperChainEstimate],
    /// Every SU's whitened residuals on the training set.
    pub residuals: Option<&'a [SuResiduals]>,
    /// Each limb's errors against the truth, by name.
    pub truth_errors: &'a BTreeMap<String, TruthErrors>,
}

/// Every limb's errors against the truth ([`truth_errors`]), by limb name, computed in parallel
/// (the bound is the costly part: a Fisher information per limb).
pub(super) fn all_truth_errors(
    m: &BodyModel,
    truth: &Robot,
    set: Option<&MeasurementSet>,
) -> BTreeMap<String, TruthErrors> {
    use rayon::prelude::*;
    m.limbs
        .par_iter()
        .filter_map(|limb| Some((limb.name.clone(), truth_errors(m, limb, truth, set)?)))
        .collect()
}

pub(super) fn limbs(m: &BodyModel, inputs: &LimbInputs) -> Markup {
    let by_su: BTreeMap<&str, &SuResiduals> = inputs
        .residuals
        .unwrap_or_default()
        .iter()
        .map(|r| (r.su.as_str(), r))
        .collect();
    html! {
        section id="limbs" {
            h2 { "Calibrated limbs" }
            @for limb in &m.limbs {
                (one_limb(m, limb, inputs, &by_su))
            }
        }
    }
}

fn one_limb(
    m: &BodyModel,
    limb: &BodyLimb,
    inputs: &LimbInputs,
    residuals: &BTreeMap<&str, &SuResiduals>,
) -> Markup {
    let e = &limb.estimate;
    let broken: Vec<&str> = m.broken.iter().map(|b| b.su.as_str()).collect();
    let ratios = Chart::categories(limb.sus.clone(), "SU", "residual, σ")
        .with(Series::new(
            "residual",
            Mark::Bars,
            "#4a78a8",
            e.su_residual_ratio.clone(),
        ))
        .with(Series::level("the noise", 1.0, limb.sus.len()));
    let flagged: Vec<&str> = limb
        .sus
        .iter()
        .zip(&e.su_residual_ratio)
        .filter(|(su, r)| **r > 1.5 || broken.contains(&su.as_str()))
        .map(|(su, _)| su.as_str())
        .collect();
    let uncertainty = Chart::categories(
        e.uncertainty.iter().map(|u| u.su.clone()).collect(),
        "SU",
        "mm",
    )
    .with(Series::new(
        "position sd",
        Mark::Bars,
        "#59a14f",
        e.uncertainty.iter().map(|u| u.position_sd * 1e3).collect(),
    ));
    let whitened: Vec<f64> = limb
        .sus
        .iter()
        .filter_map(|su| residuals.get(su.as_str()))
        .flat_map(|r| r.statics.iter().chain(&r.dynamics).copied())
        .filter(|v| v.is_finite())
        .collect();
    let truth = inputs.truth_errors.get(&limb.name);
    html! {
        div class="limb" {
            h3 { "Limb " (limb.name) @if let Some(p) = &limb.parent { " (on " (p) ")" } }
            p {
                (limb.dofs.len()) " DoFs (" (limb.dofs.join(", ")) "), " (limb.sus.len()) " SUs; residual "
                span class=(if e.converged { "" } else { "bad" }) { (format!("{:.3}", e.residual_ratio)) " σ, "
                    (if e.converged { "converged" } else { "NOT CONVERGED" }) }
                @if let Some(b) = &e.residual_band {
                    " (the noise's band at " (b.dof) " degrees of freedom: up to " (format!("{:.3}", b.upper)) " σ)"
                }
                "; " (e.iterations) " iterations"
                @if e.seconds > 0.0 { " in " (format!("{:.1}", e.seconds * 1e3)) " ms" }
                @if let Some(model) = e.intrinsics_model { "; accelerometer model: " (model.name()) }
                "."
            }
            div class="charts" {
                (ratios.figure(html! { "Residual per SU, in σ; dashed: the noise level."
                    @if !flagged.is_empty() { " " span class="bad" { "Above 1.5 σ or broken: " (flagged.join(", ")) "." } } }))
                (uncertainty.figure(html! { "SU position uncertainty (1σ), mm, relative to the SU before it (the first: to the reference frame), in the directions the readings determine; the table lists those they do not." }))
                @if whitened.len() >= 8 {
                    (quantile_plot(&whitened).figure(html! { "Normal quantile plot of every reading's whitened residual ("
                        (whitened.len()) " components): on the dashed line where the noise model is right; a steeper line means more noise than assumed, bent ends heavy tails." }))
                    (histogram(&whitened).figure(html! { "Histogram of the whitened residuals; line: the standard normal density." }))
                }
                @if let Some(t) = truth {
                    (pose_errors(t))
                }
            }
            table {
                tr { th class="name" { "SU" } th { "position sd, mm" } th { "orientation sd, °" } th { "residual, σ" } th class="name" { "not determined by any reading" } }
                @for (u, r) in e.uncertainty.iter().zip(&e.su_residual_ratio) {
                    tr {
                        td class="name" { (u.su) }
                        td { (format!("{:.2}", u.position_sd * 1e3)) }
                        td { (format!("{:.3}", u.orientation_sd.to_degrees())) }
                        td class=(if *r > 1.5 { "bad" } else { "" }) { (format!("{r:.2}")) }
                        td class="name note" { (u.undetermined()) }
                    }
                }
            }
            (dh_tables(limb, inputs))
        }
    }
}

/// The normal quantile plot of `values`: at most [`QQ_POINTS`] evenly spaced ranks.
fn quantile_plot(values: &[f64]) -> Chart {
    let mut sorted = values.to_vec();
    sorted.sort_by(f64::total_cmp);
    let n = sorted.len();
    let quantiles = normal_quantiles(n);
    let ranks: Vec<usize> = if n <= QQ_POINTS {
        (0..n).collect()
    } else {
        let mut r: Vec<usize> = (0..QQ_POINTS)
            .map(|k| (k as f64 * (n - 1) as f64 / (QQ_POINTS - 1) as f64).round() as usize)
            .collect();
        r.dedup();
        r
    };
    let x: Vec<f64> = ranks.iter().map(|&i| quantiles[i]).collect();
    let y: Vec<f64> = ranks.iter().map(|&i| sorted[i]).collect();
    Chart::numeric(x.clone(), "standard normal quantile", "whitened residual")
        .with(Series::new("residuals", Mark::Points, "#4a78a8", y))
        .with(Series::new("y = x", Mark::Dashed, "#000", x))
}

/// The histogram of `values` over ±[`HISTOGRAM_RANGE`], with the standard normal density scaled
/// to their number.
fn histogram(values: &[f64]) -> Chart {
    let width = 2.0 * HISTOGRAM_RANGE / HISTOGRAM_BINS as f64;
    let mut counts = vec![0.0; HISTOGRAM_BINS];
    for v in values {
        let bin = ((v + HISTOGRAM_RANGE) / width).floor();
        if (0.0..HISTOGRAM_BINS as f64).contains(&bin) {
            counts[bin as usize] += 1.0;
        }
    }
    let centres: Vec<f64> = (0..HISTOGRAM_BINS)
        .map(|b| -HISTOGRAM_RANGE + (b as f64 + 0.5) * width)
        .collect();
    let n = values.len() as f64;
    let density = centres
        .iter()
        .map(|x| n * width * (-0.5 * x * x).exp() / (2.0 * std::f64::consts::PI).sqrt())
        .collect();
    Chart::numeric(centres, "whitened residual", "readings' components")
        .with(Series::new("count", Mark::Bars, "#4a78a8", counts))
        .with(Series::new("normal", Mark::Line, "#000", density))
}

/// The paper's Fig. 6: each SU's pose relative to the previous one against the truth, with the
/// Cramér–Rao bound.
fn pose_errors(t: &TruthErrors) -> Markup {
    let pairs = &t.accuracy.pairs;
    let labels: Vec<String> = pairs.iter().map(|p| p.to.clone()).collect();
    let n = labels.len();
    let mut position = Chart::categories(labels.clone(), "SU, relative to the one before", "mm")
        .with(Series::new(
            "position error (RMS)",
            Mark::Bars,
            "#f28e2b",
            pairs.iter().map(|p| p.position_rms * 1e3).collect(),
        ));
    if let Some(b) = t.position_bound {
        position = position.with(Series::level("Cramér–Rao bound", b * 1e3, n));
    }
    let mut rotation =
        Chart::categories(labels, "SU, relative to the one before", "°").with(Series::new(
            "rotation error (RMS)",
            Mark::Bars,
            "#edc948",
            pairs.iter().map(|p| p.rotation_rms.to_degrees()).collect(),
        ));
    if let Some(b) = t.rotation_bound {
        rotation = rotation.with(Series::level("Cramér–Rao bound", b.to_degrees(), n));
    }
    let a = &t.accuracy;
    html! {
        (position.figure(html! { "Fig. 6: each SU's position relative to the previous one against the truth, RMS over "
            (a.poses) " held-out poses (the first pair up to a screw about the first axis)"
            @if n > 1 { "; over the pairs after the first " (format!("{:.2}", a.position_rms * 1e3)) " mm RMS"
                @if let Some(b) = t.position_bound { ", Cramér–Rao bound " (format!("{:.2}", b * 1e3)) " mm (dashed)" }
            @else if t.sus > BOUND_MAX_SUS { " (the bound is computed for limbs of up to " (BOUND_MAX_SUS) " SUs)" } }
            "." }))
        (rotation.figure(html! { "Fig. 6: each SU's rotation relative to the previous one"
            @if n > 1 { "; over the pairs after the first " (format!("{:.3}", a.rotation_rms.to_degrees())) "° RMS"
                @if let Some(b) = t.rotation_bound { ", Cramér–Rao bound " (format!("{:.3}", b.to_degrees())) "° (dashed)" } }
            "." }))
    }
}

fn dh_tables(limb: &BodyLimb, inputs: &LimbInputs) -> Markup {
    let e = &limb.estimate;
    let (truth, paper) = (inputs.truth, inputs.paper);
    html! {
        @if let (Some(dh), true) = (&e.dh, e.chain.is_serial()) {
            @let (dofs, sus) = (e.chain.dofs(), e.chain.sus());
            @let true_rows = truth.and_then(|t| crate::estimate::dh_form(t, &e.chain));
            @let by_paper = paper.iter().find(|p| p.chain.dofs() == dofs && p.chain.sus() == sus);
            h4 { "In the paper's DH+2 form (Fig. 6; m and rad, ± 1σ; the first rows' θ0 and d are a gauge choice)"
                @if true_rows.is_some() { "; the truth in brackets" }
                @if by_paper.is_some() { "; the paper's method's estimate below, in italics" } }
            table {
                tr { th class="name" { "DoF → DoF" } th { "θ0" } th { "d" } th { "a" } th { "α" } }
                @for (k, r) in dh.dof_dof.iter().enumerate() {
                    @let t = true_rows.as_ref().and_then(|(rows, _)| rows.get(k)).map(|r| r.values());
                    @let sd = dh.dof_dof_sd.get(k).map(|r| r.values());
                    tr { td class="name" { (dofs[k]) " → " (dofs.get(k + 1).cloned().unwrap_or_default()) }
                        @for (i, v) in r.values().iter().enumerate() { (dh_cell(*v, sd.map(|s| s[i]), t.map(|t| t[i]), k == 0 && i < 2)) } }
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
                    tr { td class="name" { (dofs[k]) " → " (sus.get(k).cloned().unwrap_or_default()) }
                        @for (i, v) in r.values().iter().enumerate() { (dh_cell(*v, sd.map(|s| s[i]), t.map(|t| t[i]), k == 0 && i < 2)) } }
                    @if let Some(row) = by_paper.and_then(|p| p.dof_su.get(k)) {
                        tr class="paper" { td class="name" { i { "paper's method" } }
                            @for v in row.values() { td { i { (format!("{v:.4}")) } } } }
                    }
                }
            }
        }
    }
}
