//! Still windows and the motions between them.

use nalgebra::Matrix5;

use super::fit::design;
use super::timeline::Timeline;
use super::{IngestConfig, LogReport};
use crate::model::sensor::ExcitationPattern;

/// A still window: grid range `[start, end)` and the mean pose.
#[derive(Debug, Clone)]
pub(super) struct StillWindow {
    pub(super) start: usize,
    pub(super) end: usize,
    pub(super) pose: Vec<f64>,
}

/// An excitation window and its least-squares design.
#[derive(Debug, Clone)]
pub(super) struct Excitation {
    pub(super) dof: usize,
    pub(super) start: usize,
    pub(super) end: usize,
    /// `W(m)`: the weight of the sample at grid point `start + m` in each of the five normal
    /// equations (the regressors filtered twice by the triangle).
    pub(super) weights: Vec<[f64; 5]>,
    /// `G⁻¹`, the inverse of the normal matrix.
    pub(super) inverse: Matrix5<f64>,
    /// Peak measured |ω| and |α| (for estimating the nominal pattern).
    pub(super) peak_velocity: f64,
    pub(super) peak_acceleration: f64,
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
    config: &IngestConfig,
    report: &mut LogReport,
) -> Segmentation {
    let n = timeline.len();
    let dt = timeline.dt;
    let l = ((config.filter / dt).round() as usize).max(2);
    let trim = ((config.trim / dt).round() as usize).max(2 * l + 1);
    let min_still = ((config.min_still / dt).round() as usize).max(1);
    let nd = timeline.theta.len();
    // Still grid points.
    let still: Vec<bool> = (0..n)
        .map(|i| {
            if i < l || i + l >= n || timeline.invalid[i] {
                return false;
            }
            (0..nd).all(|d| {
                let th = &timeline.theta[d];
                ((th[i + l] - th[i - l]) / (2.0 * l as f64 * dt)).abs() < config.still_velocity
            })
        })
        .collect();
    // Still runs.
    let mut runs = Vec::new();
    let mut i = 0;
    while i < n {
        if still[i] {
            let s = i;
            while i < n && still[i] {
                i += 1;
            }
            if i - s >= min_still + 2 * trim {
                runs.push((s, i));
            }
        } else {
            i += 1;
        }
    }
    let mut seg = Segmentation::default();
    for (k, &(s, e)) in runs.iter().enumerate() {
        let (a, b) = (s + trim, e - trim);
        let pose = (0..nd)
            .map(|d| timeline.theta[d][a..b].iter().sum::<f64>() / (b - a) as f64)
            .collect();
        seg.stills.push(StillWindow {
            start: a,
            end: b,
            pose,
        });
        seg.events.push(Event::Still(k));
        let Some(&(next_s, _)) = runs.get(k + 1) else {
            break;
        };
        // The motion between run k and run k + 1.
        let (ms, me) = (e, next_s);
        let at = timeline.time(ms);
        if timeline.invalid[ms..me].iter().any(|&x| x) {
            report
                .skipped
                .push(format!("motion at {at:.3} s: joint states missing (gap)"));
            seg.events.push(Event::Broken);
            continue;
        }
        let moved: Vec<usize> = (0..nd)
            .filter(|&d| {
                let th = &timeline.theta[d];
                th[ms..me]
                    .iter()
                    .any(|q| (q - th[ms]).abs() > config.motion_threshold)
            })
            .collect();
        match moved.as_slice() {
            [] => {}
            [d] => {
                let d = *d;
                let th = &timeline.theta[d];
                if (th[me] - th[ms]).abs() > config.motion_threshold {
                    report.moves += 1;
                    seg.events.push(Event::Move);
                } else {
                    let start = e.saturating_sub(2 * l);
                    let end = (next_s + 2 * l).min(n);
                    match design(timeline, d, start, end, l) {
                        Some(x) => {
                            report.excitations += 1;
                            seg.events.push(Event::Excitation(seg.excitations.len()));
                            seg.excitations.push(x);
                        }
                        None => {
                            report.skipped.push(format!(
                                "excitation of DoF {d} at {at:.3} s: too short or no acceleration \
                                 to fit against"
                            ));
                            seg.events.push(Event::Broken);
                        }
                    }
                }
            }
            _ => {
                report.transfers += 1;
                seg.events.push(Event::Transfer);
            }
        }
    }
    report.still_windows = seg.stills.len();
    for (i, s) in seg.stills.iter().enumerate() {
        seg.routes.push((s.start, s.end, true, i));
    }
    for (i, x) in seg.excitations.iter().enumerate() {
        seg.routes.push((x.start, x.end, false, i));
    }
    seg.routes.sort_by_key(|r| r.0);
    seg
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
