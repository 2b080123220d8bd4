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
    if !s.unplaced_sus.is_empty() || !s.unplaced_dofs.is_empty() {
        let _ = writeln!(
            out,
            "\nLeft out of the tree: {} SUs, {} DoFs",
            s.unplaced_sus.len(),
            s.unplaced_dofs.len()
        );
    }
    let _ = writeln!(
        out,
        "\n{}",
        if s.complete {
            "The tree is complete."
        } else {
            "The tree is INCOMPLETE: see the errors above."
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
    bound: (f64, f64),
) -> String {
    let mut out = String::new();
    let header = format!(
        "{:<34} {:>10} {:>12} {:>12} {:>12} {:>11} {:>11}",
        "", "median s", "median iter", "pos RMS mm", "pos max mm", "rot RMS °", "rot max °"
    );
    let _ = writeln!(out, "{header}");
    let line = |out: &mut String,
                label: &str,
                seconds: Option<f64>,
                evaluations: Option<f64>,
                a: (f64, f64, f64, f64)| {
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
    };
    let median = |mut v: Vec<f64>| {
        v.sort_by(f64::total_cmp);
        v[v.len() / 2]
    };
    let mut medians = Vec::new();
    for (method, rows) in methods {
        let name = match method {
            crate::Method::Ml => "ml",
            crate::Method::Paper => "paper",
        };
        if verbose {
            for r in rows {
                let a = &r.accuracy;
                line(
                    &mut out,
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
        }
        let n = rows.len() as f64;
        let pooled =
            |f: fn(&BenchRow) -> f64| (rows.iter().map(|r| f(r).powi(2)).sum::<f64>() / n).sqrt();
        let worst = |f: fn(&BenchRow) -> f64| rows.iter().map(f).fold(0.0, f64::max);
        let m = median(rows.iter().map(|r| r.seconds).collect());
        medians.push((name, m));
        line(
            &mut out,
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
    }
    let _ = writeln!(
        out,
        "{:<34} {:>10} {:>12} {:>12.2} {:>12} {:>11.3} {:>11}",
        "Cramér–Rao bound (RMS)",
        "",
        "",
        bound.0 * 1e3,
        "",
        bound.1.to_degrees(),
        ""
    );
    if let Some(fig6) = fig6 {
        line(
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

pub fn ml_summary(e: &skincal::estimate::ml::MlChainEstimate) -> String {
    let mut out = String::new();
    let g = e.gravity;
    let _ = writeln!(
        out,
        "gravity in the reference frame: ({:.4}, {:.4}, {:.4}) m/s², |g| = {:.4}",
        g[0],
        g[1],
        g[2],
        (g[0] * g[0] + g[1] * g[1] + g[2] * g[2]).sqrt()
    );
    let _ = writeln!(
        out,
        "residual RMS {:.3}× the noise σ (estimated σ {:.4} m/s²): {}",
        e.residual_ratio,
        e.noise_sd_estimate,
        if e.converged {
            "converged"
        } else {
            "NOT CONVERGED"
        }
    );
    let _ = writeln!(
        out,
        "{} LM iterations in {:.1} ms; gauge: {}",
        e.iterations,
        e.seconds * 1e3,
        e.fixed.join(", ")
    );
    for u in &e.unobservable {
        let _ = writeln!(
            out,
            "unobservable direction (σ_rel {:.1e}): {}",
            u.singular_value,
            u.parameters.join(", ")
        );
    }
    let _ = writeln!(
        out,
        "\n{:>12} {:>16} {:>18}",
        "SU", "position sd mm", "orientation sd °"
    );
    for u in &e.uncertainty {
        let _ = writeln!(
            out,
            "{:>12} {:>16.2} {:>18.3}",
            u.su,
            u.position_sd * 1e3,
            u.orientation_sd.to_degrees()
        );
    }
    let _ = writeln!(out, "(relative to the previous SU at the zero pose; the first SU relative to the reference frame)");
    out
}

/// One line of the demo's accuracy table.
pub struct DemoRow {
    pub limb: String,
    pub method: &'static str,
    pub seconds: f64,
    pub accuracy: skincal::estimate::ChainAccuracy,
}

pub fn demo_accuracy(rows: &[DemoRow]) -> String {
    let mut out = String::new();
    let _ = writeln!(
        out,
        "{:<8} {:<22} {:>10} {:>12} {:>12}",
        "limb", "method", "time ms", "pos RMS mm", "rot RMS °"
    );
    for r in rows {
        let _ = writeln!(
            out,
            "{:<8} {:<22} {:>10.1} {:>12.2} {:>12.3}",
            r.limb,
            r.method,
            r.seconds * 1e3,
            r.accuracy.position_rms * 1e3,
            r.accuracy.rotation_rms.to_degrees()
        );
    }
    let _ = writeln!(out, "(summary over the SU pairs after the first; the first pair is only defined up to a screw about the first axis)");
    out
}
