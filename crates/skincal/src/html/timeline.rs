//! The recording's timeline: each log's still windows, pauses, moves, excitations and skipped
//! transfers per DoF, and the noise found.

use std::fmt::Write as _;

use maud::{html, Markup, PreEscaped};

use crate::ingest::{IngestReport, LogReport};
use crate::show::xml_escape as escape;

/// The timeline of every log the set was ingested from, and the noise found.
pub(super) fn recording(r: &IngestReport) -> Markup {
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

/// Where a stretch of the timeline is drawn and how: its row's top (the windows' row, or its
/// DoF's), its fill and a note for its title; `None` for a kind not drawn. An excitation is the
/// darker, the more of its signal came from other DoFs.
fn stretch_style(
    log: &LogReport,
    s: &crate::ingest::Span,
    dofs: &[&str],
    row: f64,
) -> Option<(f64, String, String)> {
    let middle = (s.start + s.end) / 2.0;
    let coupled = log
        .fits
        .iter()
        .find(|f| {
            s.dof.as_deref() == Some(f.dof.as_str())
                && f.start <= middle
                && middle <= f.start + f.duration
        })
        .map(|f| f.coupled);
    Some(match (s.kind.as_str(), &s.dof) {
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
        _ => return None,
    })
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
        let Some((y, fill, note)) = stretch_style(log, s, &dofs, row) else {
            continue;
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
