//! Text rendering of results for the terminal.

use std::fmt::Write;

use skincal::explore::Structure;
use skincal::measurements::Summary;
use skincal::model::sensor::STANDARD_GRAVITY;
use skincal::model::Robot;
use skincal::report;
use skincal::sim::SimulationConfig;

/// One line of `skincal robots`.
pub struct RobotRow {
    pub name: &'static str,
    pub dofs: usize,
    pub segments: usize,
    pub sus: usize,
    pub description: String,
}

pub fn robots_table(rows: &[RobotRow]) -> String {
    let mut s = String::new();
    let _ = writeln!(
        s,
        "{:<12} {:>4} {:>8} {:>4}  description",
        "robot", "DoFs", "segments", "SUs"
    );
    for r in rows {
        let _ = writeln!(
            s,
            "{:<12} {:>4} {:>8} {:>4}  {}",
            r.name, r.dofs, r.segments, r.sus, r.description
        );
    }
    s
}

pub fn simulation_summary(robot: &Robot, config: &SimulationConfig, summary: &Summary) -> String {
    let mut s = String::new();
    let m = &robot.model;
    let _ = writeln!(
        s,
        "robot       {}: {} DoFs, {} segments, {} SUs",
        m.name(),
        m.dofs().len(),
        m.segments().len(),
        m.sus().len()
    );
    let i = &config.imperfections;
    let mut noise = format!("uniform ±{} g", i.uniform_noise);
    if i.gaussian_noise > 0.0 {
        let _ = write!(noise, ", Gaussian σ {} g", i.gaussian_noise);
    }
    if i.bias > 0.0 {
        let _ = write!(noise, ", bias ±{} g", i.bias);
    }
    if let Some(b) = i.quantization_bits {
        let _ = write!(noise, ", {b}-bit");
    }
    if let Some(sat) = i.saturation {
        let _ = write!(noise, ", saturation ±{sat} g");
    }
    let _ = writeln!(s, "noise       {noise} (seed {})", config.seed);
    let _ = writeln!(
        s,
        "structure   {} orientation(s), {} static poses (DoFs moved by {} rad)",
        summary.orientations, summary.structure_poses, config.structure_angle
    );
    if let Some(p) = summary.pattern {
        let _ = writeln!(
            s,
            "training    {} poses (±{} rad), pattern A = {} rad/s, f = {} Hz, peak α = {:.3} rad/s²",
            summary.training_poses,
            config.pose_range,
            p.amplitude,
            p.frequency,
            p.peak_acceleration()
        );
    }
    let prismatic = m.prismatic_dof_names();
    if !prismatic.is_empty() {
        let _ = writeln!(
            s,
            "prismatic   {} (positions in m; structure moves and patterns scaled by {} m per rad)",
            prismatic.join(", "),
            skincal::model::PRISMATIC_PATTERN_SCALE
        );
    }
    for (follower, mimic) in m.mimic_specs() {
        let _ = writeln!(
            s,
            "mimic       {follower} follows {} (× {}, {:+}): moved with it, never alone",
            mimic.leader, mimic.multiplier, mimic.offset
        );
    }
    let (mean, sd) = summary.static_norm;
    let _ = writeln!(
        s,
        "static      |reading| = {mean:.3} ± {sd:.3} m/s² ({:.4} g) over all static readings",
        mean / STANDARD_GRAVITY
    );
    if summary.training_poses > 0 {
        let _ = writeln!(s, "dynamic     RMS |acceleration| per excited DoF, m/s²:");
        for (dof, rms) in &summary.dynamic_rms {
            let _ = writeln!(s, "              {dof:<20} {rms:8.4}");
        }
    }
    s
}

pub fn structure_summary(s: &Structure) -> String {
    let mut out = String::new();
    let multi = s.joints.iter().filter(|j| j.dofs.len() > 1).count();
    let _ = writeln!(
        out,
        "{} segments, {} joints ({} with several DoFs), {} limbs; threshold {} g over {} base orientation(s)",
        s.segments.len(),
        s.joints.len(),
        multi,
        s.limbs.len(),
        s.threshold_g,
        s.orientations
    );
    let _ = writeln!(
        out,
        "\nActivity matrix, merged and sorted (rows: segments, columns: joints)\n"
    );
    out.push_str(&report::activity_table(s));
    let _ = writeln!(out, "\nKinematic tree\n");
    out.push_str(&report::tree(s));
    let _ = writeln!(out, "\nLimbs\n");
    out.push_str(&report::limbs(s));
    if !s.uncertain.is_empty() {
        let _ = writeln!(
            out,
            "\n{} entries lie within the uncertainty band (see structure.json, `uncertain`)",
            s.uncertain.len()
        );
    }
    if !s.diagnostics.is_empty() {
        let _ = writeln!(out, "\nDiagnostics\n");
        out.push_str(&report::diagnostics(s));
    }
    let left_out = !s.unplaced_sus.is_empty() || !s.unplaced_dofs.is_empty();
    if left_out {
        let _ = writeln!(out, "\nLeft out of the tree (not calibrated):");
        for (what, names) in [("SUs", &s.unplaced_sus), ("DoFs", &s.unplaced_dofs)] {
            if !names.is_empty() {
                let _ = writeln!(out, "  {} {what}: {}", names.len(), names.join(", "));
            }
        }
    }
    let _ = writeln!(
        out,
        "\n{}",
        match (s.complete, left_out) {
            (true, false) => "The tree is complete.",
            (true, true) =>
                "The tree of the rest is consistent: `calibrate` calibrates every limb of it and lists what was left out.",
            (false, _) => "The tree is INCOMPLETE: see the errors above.",
        }
    );
    out
}

/// Min, median and max of each named series of durations, ms.
pub fn timing_table(rows: &[(&str, Vec<f64>)]) -> String {
    let mut out = String::new();
    let _ = writeln!(
        out,
        "{:<20} {:>10} {:>10} {:>10}",
        "stage", "min ms", "median ms", "max ms"
    );
    for (name, values) in rows {
        let mut v = values.clone();
        v.sort_by(f64::total_cmp);
        let median = v[v.len() / 2];
        let _ = writeln!(
            out,
            "{name:<20} {:>10.3} {median:>10.3} {:>10.3}",
            v[0],
            v[v.len() - 1]
        );
    }
    out
}

/// One data set of a calibration benchmark.
pub struct BenchRow {
    pub seed: u64,
    pub converged: bool,
    pub seconds: f64,
    pub evaluations: usize,
    pub accuracy: skincal::estimate::ChainAccuracy,
    /// The Cramér–Rao bound of this data set (position m, rotation rad).
    pub bound: Option<(f64, f64)>,
}

pub fn calibration_bench(
    methods: &[(crate::Method, Vec<BenchRow>)],
    verbose: bool,
    fig6: Option<&skincal::estimate::ChainAccuracy>,
    bounds: &[(String, (f64, f64))],
) -> String {
    let mut out = String::new();
    let header = format!(
        "{:<34} {:>10} {:>12} {:>12} {:>12} {:>11} {:>11}",
        "", "median s", "median iter", "pos RMS mm", "pos max mm", "rot RMS °", "rot max °"
    );
    let _ = writeln!(out, "{header}");
    let mut medians = Vec::new();
    for (method, rows) in methods {
        let name = match method {
            crate::Method::Ml => "ml",
            crate::Method::Paper => "paper",
        };
        if verbose {
            for r in rows {
                bench_seed_line(&mut out, name, r);
            }
        }
        medians.push((name, bench_method_lines(&mut out, name, rows)));
    }
    for (label, bound) in bounds {
        let _ = writeln!(
            out,
            "{:<34} {:>10} {:>12} {:>12.2} {:>12} {:>11.3} {:>11}",
            label,
            "",
            "",
            bound.0 * 1e3,
            "",
            bound.1.to_degrees(),
            ""
        );
    }
    if let Some(fig6) = fig6 {
        bench_line(
            &mut out,
            "paper's Fig. 6 estimate (its run)",
            Some(86.0),
            Some(7672.0),
            (
                fig6.position_rms,
                fig6.position_max,
                fig6.rotation_rms,
                fig6.rotation_max,
            ),
        );
    }
    if let (Some(ml), Some(paper)) = (
        medians.iter().find(|m| m.0 == "ml"),
        medians.iter().find(|m| m.0 == "paper"),
    ) {
        let _ = writeln!(out, "\nmedian time, paper / ml: {:.0}×", paper.1 / ml.1);
    }
    let _ = writeln!(out, "(iterations: NLopt evaluations for paper, LM iterations for ml; the paper's own time is on a 2.26 GHz Core 2 Duo)");
    out
}

/// One line of the calibration bench: time, iterations and the position and rotation errors
/// `(RMS, max, RMS, max)` in m and rad.
fn bench_line(
    out: &mut String,
    label: &str,
    seconds: Option<f64>,
    evaluations: Option<f64>,
    a: (f64, f64, f64, f64),
) {
    let s = seconds.map_or("—".into(), |s| format!("{s:.4}"));
    let e = evaluations.map_or("—".into(), |e| format!("{e:.0}"));
    let _ = writeln!(
        out,
        "{label:<34} {s:>10} {e:>12} {:>12.2} {:>12.2} {:>11.3} {:>11.3}",
        a.0 * 1e3,
        a.1 * 1e3,
        a.2.to_degrees(),
        a.3.to_degrees()
    );
}

/// One seed's line (`--verbose`), with its Cramér–Rao bound.
fn bench_seed_line(out: &mut String, name: &str, r: &BenchRow) {
    let a = &r.accuracy;
    bench_line(
        out,
        &format!(
            "{name} seed {}{}",
            r.seed,
            if r.converged { "" } else { " (not converged)" }
        ),
        Some(r.seconds),
        Some(r.evaluations as f64),
        (
            a.position_rms,
            a.position_max,
            a.rotation_rms,
            a.rotation_max,
        ),
    );
    if let Some((p, q)) = r.bound {
        out.pop();
        let _ = writeln!(out, "   bound {:.2} mm {:.3}°", p * 1e3, q.to_degrees());
    }
}

/// A method's summary over its seeds (errors pooled, worst cases, medians) and how many
/// converged; returns its median time.
fn bench_method_lines(out: &mut String, name: &str, rows: &[BenchRow]) -> f64 {
    let median = |mut v: Vec<f64>| {
        v.sort_by(f64::total_cmp);
        v[v.len() / 2]
    };
    let n = rows.len() as f64;
    let pooled =
        |f: fn(&BenchRow) -> f64| (rows.iter().map(|r| f(r).powi(2)).sum::<f64>() / n).sqrt();
    let worst = |f: fn(&BenchRow) -> f64| rows.iter().map(f).fold(0.0, f64::max);
    let m = median(rows.iter().map(|r| r.seconds).collect());
    bench_line(
        out,
        &format!("{name}: all {} seeds", rows.len()),
        Some(m),
        Some(median(rows.iter().map(|r| r.evaluations as f64).collect())),
        (
            pooled(|r| r.accuracy.position_rms),
            worst(|r| r.accuracy.position_max),
            pooled(|r| r.accuracy.rotation_rms),
            worst(|r| r.accuracy.rotation_max),
        ),
    );
    let converged = rows.iter().filter(|r| r.converged).count();
    let failed: Vec<String> = rows
        .iter()
        .filter(|r| !r.converged)
        .map(|r| r.seed.to_string())
        .collect();
    let _ = writeln!(
        out,
        "{:<34} converged {converged} of {} ({:.1} %){}",
        "",
        rows.len(),
        100.0 * converged as f64 / n,
        if failed.is_empty() {
            String::new()
        } else {
            format!("; not converged: seeds {}", failed.join(", "))
        }
    );
    m
}

/// The line naming the DoFs whose dynamic readings the set lacks, if any.
fn missing_excitations(out: &mut String, e: &skincal::estimate::ml::MlChainEstimate) {
    if e.missing_excitations.is_empty() {
        return;
    }
    let lacking: Vec<String> = e
        .missing_excitations
        .iter()
        .map(|(dof, n)| format!("{dof} {n}"))
        .collect();
    let _ = writeln!(
        out,
        "dynamic readings missing from the set (fitted without them), poses lacking each: {}",
        lacking.join(", ")
    );
}

pub fn ml_summary(e: &skincal::estimate::ml::MlChainEstimate) -> String {
    let mut out = String::new();
    fit_lines(&mut out, e);
    // The SU column as wide as the longest name (a description's link names run to 30).
    let width = e
        .uncertainty
        .iter()
        .map(|u| u.su.chars().count())
        .max()
        .unwrap_or(0)
        .max(12);
    let _ = writeln!(
        out,
        "\n{:>width$} {:>16} {:>18} {:>11} {:>22} {:>20} {:>9}",
        "SU",
        "position sd mm",
        "orientation sd °",
        "residual/σ",
        "bias mg (x, y, z)",
        "scale % (x, y, z)",
        "rejected"
    );
    for u in &e.uncertainty {
        su_row(&mut out, e, u, width);
    }
    if e.intrinsics.iter().any(|i| !i.held.is_empty()) {
        let _ = writeln!(
            out,
            "(* not determined by the readings: held near 0 by the prior)"
        );
    }
    if !e.rejected.is_empty() {
        let _ = writeln!(
            out,
            "(rejected: readings left out as glitches, more than 6σ off the fit)"
        );
    }
    let _ = writeln!(out, "(relative to the previous SU at the zero pose; the first SU relative to the reference frame)");
    for u in e.uncertainty.iter().filter(|u| u.is_partial()) {
        let _ = writeln!(
            out,
            "† {}: not determined by any reading: {} (position in the frame it is relative to, turn in its own; the deviations cover the other directions)",
            u.su,
            u.undetermined()
        );
    }
    out
}

/// A limb fit's gravity, residual against the noise, cost, retries, intrinsics tests, missing
/// excitations and unobservable directions.
fn fit_lines(out: &mut String, e: &skincal::estimate::ml::MlChainEstimate) {
    let g = e.gravity;
    let _ = writeln!(
        out,
        "gravity in the reference frame: ({:.4}, {:.4}, {:.4}) m/s², |g| = {:.4}",
        g[0],
        g[1],
        g[2],
        (g[0] * g[0] + g[1] * g[1] + g[2] * g[2]).sqrt()
    );
    let verdict = match (e.converged, &e.residual_band) {
        (true, Some(b)) => format!("converged (within {:.3}×, the noise's band at {} degrees of freedom)", b.upper, b.dof),
        (false, Some(b)) => format!("NOT CONVERGED (beyond {:.3}×, the noise's band at {} degrees of freedom: a misfit, or noise larger than the weights say)", b.upper, b.dof),
        (true, None) => "converged".into(),
        (false, None) => "NOT CONVERGED".into(),
    };
    if let Some(m) = &e.motion {
        let verdict = match (&m.at_rest, e.converged) {
            (Some(r), converged) => {
                let band = r
                    .band
                    .map_or(String::new(), |b| format!(", band {:.3}×", b.upper));
                format!(
                    "{}; at rest {:.3}× over {} components{band}{}",
                    if converged {
                        "converged"
                    } else {
                        "NOT CONVERGED"
                    },
                    r.residual_ratio,
                    r.rows,
                    if converged {
                        ""
                    } else {
                        ": a misfit, or noise larger than the still blocks gave"
                    }
                )
            }
            (None, _) => verdict,
        };
        let _ = writeln!(
            out,
            "fitted on every sample of the log: {} blocks of the motion record; residual RMS {:.3}× each SU's own noise: {verdict}",
            m.blocks, e.residual_ratio
        );
        let _ = writeln!(
            out,
            "the skin's stamps run {:.2} ± {:.2} ms behind the joint states'",
            m.skin_delay * 1e3,
            m.skin_delay_sd * 1e3
        );
    } else if e.reading_sd {
        let _ = writeln!(
            out,
            "residual RMS {:.3}× the readings' own standard deviations: {verdict}",
            e.residual_ratio
        );
    } else {
        let _ = writeln!(
            out,
            "residual RMS {:.3}× the noise σ (estimated σ {:.4} m/s²): {verdict}",
            e.residual_ratio, e.noise_sd_estimate
        );
    }
    let _ = writeln!(
        out,
        "{} LM iterations in {:.1} ms; gauge: {}",
        e.iterations,
        e.seconds * 1e3,
        e.fixed.join(", ")
    );
    for r in &e.retries {
        let _ = writeln!(out, "tried: {r}");
    }
    if !e.intrinsics_tests.is_empty() {
        let tests: Vec<String> = e
            .intrinsics_tests
            .iter()
            .map(|t| {
                // A filtered record's correlated samples: F is divided by their overcount.
                let correlated = if t.overcount > 1.0 {
                    format!(", samples' overcount {:.2}", t.overcount)
                } else {
                    String::new()
                };
                format!(
                    "{} against {}: F = {:.2} (+{} parameters{correlated}), z = {:.1} → {}",
                    t.model.name(),
                    t.against.name(),
                    t.f,
                    t.parameters,
                    t.z,
                    if t.taken { "taken" } else { "not needed" }
                )
            })
            .collect();
        let pooled = if e.intrinsics_left_out.is_empty() {
            "every limb of the skin pooled".to_string()
        } else {
            format!(
                "the skin's limbs at the noise level pooled ({} left out: off it, a misfit is no sensor's)",
                e.intrinsics_left_out.join(", ")
            )
        };
        let _ = writeln!(
            out,
            "intrinsics as the data chose, {pooled}: {} ({})",
            e.intrinsics_model.map_or("?", |m| m.name()),
            tests.join("; ")
        );
    }
    missing_excitations(out, e);
    for u in &e.unobservable {
        let _ = writeln!(
            out,
            "unobservable direction (σ_rel {:.1e}): {}",
            u.singular_value,
            u.parameters.join(", ")
        );
    }
}

/// One SU's row of a limb's table: its pose's deviations (marked † where some direction is not
/// determined), residual, intrinsics (* where held by the prior) and rejected readings.
fn su_row(
    out: &mut String,
    e: &skincal::estimate::ml::MlChainEstimate,
    u: &skincal::estimate::ml::SuUncertainty,
    width: usize,
) {
    let i = e.chain.sus().iter().position(|s| *s == u.su);
    let ratio = i
        .and_then(|i| e.su_residual_ratio.get(i))
        .map_or("—".to_string(), |r| format!("{r:.2}"));
    let intrinsics = e.intrinsics.iter().find(|x| x.su == u.su);
    let triple = |v: [f64; 3], f: f64, held: &[&str]| {
        v.iter()
            .zip(held)
            .map(|(x, h)| {
                let mark = if intrinsics.is_some_and(|i| i.held.iter().any(|n| n == h)) {
                    "*"
                } else {
                    ""
                };
                format!("{:.0}{mark}", x * f)
            })
            .collect::<Vec<_>>()
            .join(", ")
    };
    let (bias, scale) = intrinsics.map_or(("—".to_string(), "—".to_string()), |i| {
        (
            triple(
                i.value.bias,
                1e3 / skincal::model::sensor::STANDARD_GRAVITY,
                &["bias_x", "bias_y", "bias_z"],
            ),
            triple(i.value.scale, 100.0, &["scale_x", "scale_y", "scale_z"]),
        )
    });
    let rejected = e
        .rejected
        .iter()
        .find(|r| r.su == u.su)
        .map_or(String::new(), |r| {
            (r.static_readings + r.dynamic_readings).to_string()
        });
    let mark = if u.is_partial() { "†" } else { "" };
    let _ = writeln!(
        out,
        "{:>width$} {:>16} {:>18} {:>11} {:>22} {:>20} {:>9}",
        u.su,
        format!("{:.2}{mark}", u.position_sd * 1e3),
        format!("{:.3}{mark}", u.orientation_sd.to_degrees()),
        ratio,
        bias,
        scale,
        rejected
    );
}

/// One line of the demo's per-limb table.
pub struct LimbRow {
    name: String,
    dofs: usize,
    sus: usize,
    converged: bool,
    position_mm: Option<f64>,
    rotation_deg: Option<f64>,
    static_rms: f64,
    dynamic_rms: Option<f64>,
}

impl LimbRow {
    /// A limb's row: its SU pose accuracy against the truth (if any pair is judged) and the
    /// held-out prediction errors of its SUs.
    pub fn new(
        name: &str,
        dofs: usize,
        sus: &[String],
        converged: bool,
        accuracy: Option<&skincal::estimate::ChainAccuracy>,
        check: &skincal::predict::Validation,
    ) -> Self {
        let mine: Vec<&skincal::predict::SuError> =
            check.sus.iter().filter(|e| sus.contains(&e.su)).collect();
        let n = mine.len().max(1) as f64;
        let static_rms = (mine.iter().map(|e| e.static_rms.powi(2)).sum::<f64>() / n).sqrt();
        let count: usize = mine.iter().map(|e| e.dynamic_count).sum();
        let dynamic_rms = (count > 0).then(|| {
            (mine
                .iter()
                .map(|e| e.dynamic_rms.powi(2) * e.dynamic_count as f64)
                .sum::<f64>()
                / count as f64)
                .sqrt()
        });
        let judged = accuracy.filter(|a| a.pairs.len() > 1);
        Self {
            name: name.to_string(),
            dofs,
            sus: sus.len(),
            converged,
            position_mm: judged.map(|a| a.position_rms * 1e3),
            rotation_deg: judged.map(|a| a.rotation_rms.to_degrees()),
            static_rms,
            dynamic_rms,
        }
    }
}

fn or_dash(v: Option<f64>, precision: usize) -> String {
    v.map_or("—".to_string(), |x| format!("{x:.precision$}"))
}

pub fn body_table(rows: &[LimbRow], check: &skincal::predict::Validation) -> String {
    let mut out = String::new();
    let _ = writeln!(
        out,
        "{:<14} {:>4} {:>4} {:>9} {:>11} {:>10} {:>14} {:>14}",
        "limb", "DoFs", "SUs", "converged", "SU pos mm", "SU rot °", "static m/s²", "dynamic m/s²"
    );
    for r in rows {
        let _ = writeln!(
            out,
            "{:<14} {:>4} {:>4} {:>9} {:>11} {:>10} {:>14.4} {:>14}",
            r.name,
            r.dofs,
            r.sus,
            if r.converged { "yes" } else { "NO" },
            or_dash(r.position_mm, 2),
            or_dash(r.rotation_deg, 3),
            r.static_rms,
            or_dash(r.dynamic_rms, 4)
        );
    }
    let _ = writeln!(
        out,
        "{:<14} {:>4} {:>4} {:>9} {:>11} {:>10} {:>14.4} {:>14.4}",
        "whole body",
        "",
        check.sus.len(),
        "",
        "",
        "",
        check.static_rms,
        check.dynamic_rms
    );
    let _ = writeln!(out, "(SU pos/rot: RMS error of each SU's pose relative to the previous SU of its limb, pairs after the first;");
    let _ = writeln!(out, " static/dynamic: RMS norm of the prediction error against the noise-free truth, held-out poses;");
    let _ = writeln!(
        out,
        " the noise on the training readings has an RMS norm of 0.098 m/s²)"
    );
    out
}

/// Per excited DoF: its dynamic readings' error, and how many times the median DoF's it is.
fn dof_table(v: &skincal::predict::Validation) -> String {
    let mut out = String::new();
    if v.dofs.is_empty() {
        return out;
    }
    let errors: Vec<f64> = v.dofs.iter().map(|d| d.dynamic_rms).collect();
    let ratios = skincal::predict::over_median(&errors);
    let w = v
        .dofs
        .iter()
        .map(|d| d.dof.chars().count())
        .fold(20, usize::max);
    let _ = writeln!(
        out,
        "\n{:<w$} {:>12} {:>12} {:>9} {:>9} {:>12}",
        "excited DoF", "dynamic RMS", "dynamic max", "dynamic n", "× median", "noise floor"
    );
    for (i, d) in v.dofs.iter().enumerate() {
        let ratio = ratios
            .as_ref()
            .map_or_else(|| "-".to_string(), |r| format!("{:.2}", r[i]));
        let _ = writeln!(
            out,
            "{:<w$} {:>12.4} {:>12.4} {:>9} {:>9} {:>12.4}",
            d.dof, d.dynamic_rms, d.dynamic_max, d.dynamic_count, ratio, d.floor
        );
    }
    let _ = writeln!(
        out,
        "(every SU a DoF moves, in every pose; {})",
        skincal::predict::UNEVEN_DOFS
    );
    out
}

pub fn validation_table(v: &skincal::predict::Validation) -> String {
    let g = skincal::model::sensor::STANDARD_GRAVITY;
    let mut out = String::new();
    let w = v
        .sus
        .iter()
        .map(|e| e.su.chars().count())
        .fold(20, usize::max);
    let _ = writeln!(
        out,
        "{:<w$} {:>12} {:>12} {:>12} {:>12} {:>9}",
        "SU", "static RMS", "static max", "dynamic RMS", "dynamic max", "dynamic n"
    );
    for e in &v.sus {
        let _ = writeln!(
            out,
            "{:<w$} {:>12.4} {:>12.4} {:>12.4} {:>12.4} {:>9}",
            e.su, e.static_rms, e.static_max, e.dynamic_rms, e.dynamic_max, e.dynamic_count
        );
    }
    let _ = writeln!(
        out,
        "{:<w$} {:>12.4} {:>12.4} {:>12.4} {:>12.4}",
        "all (m/s²)", v.static_rms, v.static_max, v.dynamic_rms, v.dynamic_max
    );
    let _ = writeln!(
        out,
        "{:<w$} {:>12.5} {:>12.5} {:>12.5} {:>12.5}",
        "all (g)",
        v.static_rms / g,
        v.static_max / g,
        v.dynamic_rms / g,
        v.dynamic_max / g
    );
    let _ = writeln!(
        out,
        "(norm of the 3-vector difference between prediction and measurement, m/s² unless marked)"
    );
    out.push_str(&dof_table(v));
    if !v.not_in_model.is_empty() {
        let _ = writeln!(
            out,
            "not in the model, not compared: {}",
            v.not_in_model.join(", ")
        );
    }
    out
}
