//! Still windows and the motions between them.

use super::fit::{design, Excitation};
use super::timeline::Timeline;
use super::{IngestConfig, LogReport, Span};
use crate::model::sensor::ExcitationPattern;

/// A pause between motions: where every DoF is slower than `quiet_velocity` (servo ringing
/// allowed). Its longest run slower than `still_velocity`, trimmed, is its still window, which
/// gives a static reading when it is at least `min_still` long.
#[derive(Debug, Clone)]
pub(super) struct StillWindow {
    /// Grid range `[start, end)` of the still window (of the whole pause without one).
    pub(super) start: usize,
    pub(super) end: usize,
    /// The mean pose over that range.
    pub(super) pose: Vec<f64>,
    /// Whether the range is a still window for a static reading.
    pub(super) reading: bool,
}

/// Runs of `true` in `mask` at least `min` long, as `[start, end)`.
fn runs(mask: &[bool], min: usize) -> Vec<(usize, usize)> {
    let mut out = Vec::new();
    let mut i = 0;
    while i < mask.len() {
        if mask[i] {
            let s = i;
            while i < mask.len() && mask[i] {
                i += 1;
            }
            if i - s >= min.max(1) {
                out.push((s, i));
            }
        } else {
            i += 1;
        }
    }
    out
}

#[derive(Debug, Clone)]
pub(super) enum Event {
    Still(usize),
    Excitation(usize),
    Move,
    Transfer,
    Broken,
}

/// The windows of one log.
#[derive(Debug, Clone, Default)]
pub(super) struct Segmentation {
    pub(super) stills: Vec<StillWindow>,
    pub(super) excitations: Vec<Excitation>,
    pub(super) events: Vec<Event>,
    /// Every window's `(start, end, still?, index)`, sorted by start, for routing samples.
    pub(super) routes: Vec<(usize, usize, bool, usize)>,
}

pub(super) fn segment(
    timeline: &Timeline,
    dofs: &[String],
    config: &IngestConfig,
    report: &mut LogReport,
) -> Segmentation {
    let n = timeline.len();
    let dt = timeline.dt;
    let l = ((config.filter / dt).round() as usize).max(2);
    let trim = ((config.trim / dt).round() as usize).max(2 * l + 1);
    let min_still = ((config.min_still / dt).round() as usize).max(1);
    let min_pause = (config.min_pause / dt).round() as usize;
    let nd = timeline.theta.len();
    // Grid points where every DoF is slower than `limit`.
    let below = |limit: f64| -> Vec<bool> {
        (0..n)
            .map(|i| {
                if i < l || i + l >= n || timeline.invalid[i] {
                    return false;
                }
                timeline
                    .theta
                    .iter()
                    .all(|th| ((th[i + l] - th[i - l]) / (2.0 * l as f64 * dt)).abs() < limit)
            })
            .collect()
    };
    let still = below(config.still_velocity);
    let quiet = below(config.quiet_velocity);
    let mut pauses = runs(&quiet, min_pause.max(4 * l + 1));
    // The recording's ends close a motion too: a quiet run that reaches the first or the last grid
    // point the filter can judge is a pause even when shorter (the log started or stopped in it).
    let short = runs(&quiet, 2 * l + 1);
    if let Some(&last) = short.last() {
        if last.1 + l >= n && pauses.last() != Some(&last) {
            pauses.push(last);
        }
    }
    if let Some(&first) = short.first() {
        if first.0 <= l && pauses.first() != Some(&first) {
            pauses.insert(0, first);
        }
    }
    let mut seg = Segmentation::default();
    for (k, &(s, e)) in pauses.iter().enumerate() {
        // The longest still run of the pause, trimmed, gives the static reading.
        let reading = runs(&still[s..e], min_still + 2 * trim)
            .into_iter()
            .max_by_key(|(a, b)| b - a)
            .map(|(a, b)| (s + a + trim, s + b - trim));
        let (a, b) = reading.unwrap_or((s, e));
        let pose = (0..nd)
            .map(|d| timeline.theta[d][a..b].iter().sum::<f64>() / (b - a) as f64)
            .collect();
        seg.stills.push(StillWindow {
            start: a,
            end: b,
            pose,
            reading: reading.is_some(),
        });
        seg.events.push(Event::Still(k));
        let mut span = |kind: &str, dof: Option<usize>, from: usize, to: usize| {
            report.timeline.push(Span {
                kind: kind.into(),
                dof: dof.map(|d| dofs[d].clone()),
                start: timeline.time(from),
                end: timeline.time(to),
            })
        };
        span(
            if reading.is_some() { "still" } else { "pause" },
            None,
            s,
            e,
        );
        let Some(&(next_s, _)) = pauses.get(k + 1) else {
            break;
        };
        // The motion between run k and run k + 1.
        let (ms, me) = (e, next_s);
        let at = timeline.time(ms);
        if timeline.invalid[ms..me].iter().any(|&x| x) {
            span("broken", None, ms, me);
            report
                .skipped
                .push(format!("motion at {at:.3} s: joint states missing (gap)"));
            seg.events.push(Event::Broken);
            continue;
        }
        match classify(timeline, ms, me, config) {
            Motion::None => {}
            Motion::Move(d) => {
                span("move", Some(d), ms, me);
                report.moves += 1;
                seg.events.push(Event::Move);
            }
            Motion::Transfer => {
                span("transfer", None, ms, me);
                report.transfers += 1;
                seg.events.push(Event::Transfer);
            }
            Motion::Excitation(excited) => {
                let start = e.saturating_sub(2 * l);
                let end = (next_s + 2 * l).min(n);
                let names = excited
                    .iter()
                    .map(|&d| format!("`{}`", dofs[d]))
                    .collect::<Vec<_>>()
                    .join(" and ");
                match design(timeline, &excited, start, end, l) {
                    Some(x) => {
                        for &d in &excited {
                            span("excitation", Some(d), ms, me);
                        }
                        report.excitations += 1;
                        seg.events.push(Event::Excitation(seg.excitations.len()));
                        seg.excitations.push(x);
                    }
                    None => {
                        span("broken", Some(excited[0]), ms, me);
                        report.skipped.push(format!(
                            "excitation of {names} at {at:.3} s: too short or no acceleration to \
                             fit against"
                        ));
                        seg.events.push(Event::Broken);
                    }
                }
            }
        }
    }
    report.still_windows = seg.stills.iter().filter(|s| s.reading).count();
    report.pauses = seg.stills.len() - report.still_windows;
    for (i, s) in seg.stills.iter().enumerate().filter(|(_, s)| s.reading) {
        seg.routes.push((s.start, s.end, true, i));
    }
    for (i, x) in seg.excitations.iter().enumerate() {
        seg.routes.push((x.start, x.end, false, i));
    }
    seg.routes.sort_by_key(|r| r.0);
    seg
}

/// The largest change of position that a DoF's servo sag explains, in motion thresholds.
const SAG_STEPS: f64 = 10.0;

/// What a motion between two still windows was.
enum Motion {
    /// No DoF left its position.
    None,
    /// One DoF moved to a new position (a structure move).
    Move(usize),
    /// Several DoFs moved.
    Transfer,
    /// One DoF (or several together, the one that moved most first) moved and came back.
    Excitation(Vec<usize>),
}

/// The motion over grid `[ms, me]`, told by each DoF's largest excursion from its start: DoFs that
/// moved less than `coupled_fraction` of the one that moved most only followed it (servo
/// compliance, reaction torques, ringing), and so do their changes of position at the end
/// (the sag of a compliant servo under a changed load). DoFs that moved more and all came back
/// were excited together (a plan's parallel limbs).
fn classify(timeline: &Timeline, ms: usize, me: usize, config: &IngestConfig) -> Motion {
    let excursion: Vec<f64> = timeline
        .theta
        .iter()
        .map(|th| {
            th[ms..=me]
                .iter()
                .fold(0.0f64, |m, q| m.max((q - th[ms]).abs()))
        })
        .collect();
    let Some((main, &largest)) = excursion
        .iter()
        .enumerate()
        .max_by(|a, b| a.1.total_cmp(b.1))
    else {
        return Motion::None;
    };
    if largest <= config.motion_threshold {
        return Motion::None;
    }
    let followed = |x: f64, of: f64| x <= config.motion_threshold.max(config.coupled_fraction * of);
    let net = |th: &Vec<f64>| (th[me] - th[ms]).abs();
    let mut leading = vec![main];
    leading.extend((0..excursion.len()).filter(|&e| e != main && !followed(excursion[e], largest)));
    if leading
        .iter()
        .all(|&e| net(&timeline.theta[e]) <= config.motion_threshold)
    {
        return Motion::Excitation(leading);
    }
    if leading.len() > 1 {
        return Motion::Transfer;
    }
    let moved = net(&timeline.theta[main]);
    // A compliant servo's sag under a changed load is small in itself, not only beside the move:
    // a DoF that ends a tenth of a radian away was moved too.
    let sag = SAG_STEPS * config.motion_threshold;
    if timeline
        .theta
        .iter()
        .enumerate()
        .any(|(e, th)| e != main && !followed(net(th), moved.min(sag / config.coupled_fraction)))
    {
        Motion::Transfer
    } else {
        Motion::Move(main)
    }
}

/// The nominal pattern from the measured motion of every excitation: the median peak speed is `A`,
/// the median peak acceleration `2πfA`.
pub(super) fn estimate_pattern(plans: &[Segmentation]) -> Option<(ExcitationPattern, String)> {
    let mut v: Vec<f64> = Vec::new();
    let mut a: Vec<f64> = Vec::new();
    for p in plans {
        for x in &p.excitations {
            v.push(x.peak_velocity);
            a.push(x.peak_acceleration);
        }
    }
    if v.is_empty() {
        return None;
    }
    let median = |x: &mut Vec<f64>| {
        x.sort_by(f64::total_cmp);
        x[x.len() / 2]
    };
    let (amplitude, peak) = (median(&mut v), median(&mut a));
    let pattern = ExcitationPattern {
        amplitude,
        frequency: peak / (2.0 * std::f64::consts::PI * amplitude),
    };
    pattern.is_valid().then(|| {
        (
            pattern,
            format!(
                "estimated from {} excitations (median peak speed and acceleration)",
                v.len()
            ),
        )
    })
}
