//! Joint states on a uniform grid.

use std::collections::HashMap;
use std::path::Path;

use super::{IngestConfig, IngestError, LogReport, Progress};
use crate::log::{self, Sample, Stream};

/// Slowest joint-state rate that can resolve an excitation pattern, Hz.
const MIN_JOINT_RATE: f64 = 20.0;
/// Longest pause without joint states inside one log, s.
const MAX_PAUSE: f64 = 600.0;

/// Joint positions of one log on a uniform grid.
#[derive(Debug, Clone)]
pub(super) struct Timeline {
    t0: f64,
    pub(super) dt: f64,
    /// Positions per DoF (in the order of the common DoF list), one per grid point.
    pub(super) theta: Vec<Vec<f64>>,
    /// Grid points inside a joint-state gap.
    pub(super) invalid: Vec<bool>,
    /// Per DoF, the standard deviation of its encoder's rounding, rad: the smallest step between
    /// two of its readings over √12 (0 for readings that are not rounded).
    pub(super) resolution: Vec<f64>,
}

impl Timeline {
    pub(super) fn len(&self) -> usize {
        self.invalid.len()
    }

    pub(super) fn index(&self, stamp: f64) -> i64 {
        ((stamp - self.t0) / self.dt).round() as i64
    }

    pub(super) fn time(&self, n: usize) -> f64 {
        n as f64 * self.dt
    }
}

pub(super) fn read_joints(
    path: &Path,
    config: &IngestConfig,
    dof_names: &mut Option<Vec<String>>,
    report: &mut LogReport,
    progress: &mut Progress<'_>,
) -> Result<Timeline, IngestError> {
    let total = log::size_of(path, Stream::Joints);
    let label = format!("joint states of {}", path.display());
    let mut series: HashMap<String, Vec<(f64, f64)>> = HashMap::new();
    let mut order: Vec<String> = Vec::new();
    let stats = log::read_log(
        path,
        Stream::Joints,
        &config.topics,
        &mut |s| {
            if let Sample::Joints {
                stamp,
                names,
                positions,
            } = s
            {
                for (name, &q) in names.iter().zip(positions) {
                    let entry = series.entry(name.clone()).or_insert_with(|| {
                        order.push(name.clone());
                        Vec::new()
                    });
                    entry.push((stamp, q));
                }
            }
            Ok(())
        },
        &mut |done| progress(&label, done, total),
    )?;
    report.joint_states = stats.samples;
    report.joint_read = stats;
    let dofs: Vec<String> = match dof_names {
        Some(known) => {
            for name in &order {
                if !known.contains(name) {
                    report
                        .unknown_joints
                        .insert(name.clone(), series[name].len() as u64);
                }
            }
            let missing: Vec<&String> = known.iter().filter(|d| !series.contains_key(*d)).collect();
            if !missing.is_empty() {
                return Err(IngestError::Unusable {
                    path: path.to_path_buf(),
                    reason: format!(
                        "no joint states for DoF(s) {missing:?} (names seen: {order:?}); check the \
                         joint topic (--joint-topic) and that the log is of this robot"
                    ),
                });
            }
            known.clone()
        }
        None => {
            if order.is_empty() {
                return Err(IngestError::Unusable {
                    path: path.to_path_buf(),
                    reason: format!(
                        "no joint states found (topic `{}`); choose it with --joint-topic",
                        config.topics.joints
                    ),
                });
            }
            *dof_names = Some(order.clone());
            order.clone()
        }
    };
    let mut cleaned: Vec<Vec<(f64, f64)>> = Vec::with_capacity(dofs.len());
    for d in &dofs {
        let mut s = series.remove(d).unwrap_or_default();
        report.unsorted_joint_stamps += s.windows(2).filter(|w| w[1].0 < w[0].0).count() as u64;
        s.sort_by(|a, b| a.0.total_cmp(&b.0));
        let before = s.len();
        s.dedup_by(|b, a| b.0 == a.0);
        report.duplicate_joint_stamps += (before - s.len()) as u64;
        if s.len() < 2 {
            return Err(IngestError::Unusable {
                path: path.to_path_buf(),
                reason: format!("DoF `{d}` has fewer than two joint states"),
            });
        }
        cleaned.push(s);
    }
    // The rate from the DoF with most samples.
    let densest = cleaned
        .iter()
        .max_by_key(|s| s.len())
        .expect("at least one DoF");
    let mut steps: Vec<f64> = densest.windows(2).map(|w| w[1].0 - w[0].0).collect();
    steps.sort_by(f64::total_cmp);
    let rough = steps[steps.len() / 2];
    if !(rough > 0.0 && rough.is_finite()) {
        return Err(IngestError::Unusable {
            path: path.to_path_buf(),
            reason: "the joint states have no usable time step".into(),
        });
    }
    // The period to far better than the stamps' resolution: a straight line through (sample
    // number, stamp), numbering the samples by the rough period between neighbours so that lost
    // ones keep their place. A grid whose period is off by 1e-4 would slip by a sample every ten seconds.
    let dt = {
        let first = densest[0].0;
        let (mut sk, mut st, mut skk, mut skt, mut count) = (0.0, 0.0, 0.0, 0.0, 0.0);
        let mut k = 0.0;
        let mut previous = first;
        for &(t, _) in densest {
            // Numbered step by step: a lost sample shows as a double step.
            k += ((t - previous) / rough).round();
            previous = t;
            let t = t - first;
            sk += k;
            st += t;
            skk += k * k;
            skt += k * t;
            count += 1.0;
        }
        let denominator = count * skk - sk * sk;
        let slope = (count * skt - sk * st) / denominator;
        if denominator > 0.0 && slope.is_finite() && (slope / rough - 1.0).abs() < 0.1 {
            slope
        } else {
            rough
        }
    };
    let t0 = cleaned.iter().map(|s| s[0].0).fold(f64::MIN, f64::max);
    let t1 = cleaned
        .iter()
        .map(|s| s[s.len() - 1].0)
        .fold(f64::MAX, f64::min);
    if t1 <= t0 {
        return Err(IngestError::Unusable {
            path: path.to_path_buf(),
            reason: "the DoFs' joint states do not overlap in time".into(),
        });
    }
    let rate = 1.0 / dt;
    if rate < MIN_JOINT_RATE {
        return Err(IngestError::Unusable {
            path: path.to_path_buf(),
            reason: format!(
                "the joint states come every {} (stamp units) — {rate:.3} Hz if the stamps are \
                 seconds, too slow to see an excitation pattern (at least {MIN_JOINT_RATE} Hz): \
                 stamps must be in seconds; if they are in ms, µs or ns, divide them by 1e3, 1e6 \
                 or 1e9",
                crate::show::number(dt)
            ),
        });
    }
    // Lengths come from the stamps: one far-off stamp must not make a grid of years.
    let span_points = (t1 - t0) / dt;
    let samples = densest.len() as f64;
    if span_points > 4.0 * samples + MAX_PAUSE * rate {
        return Err(IngestError::Unusable {
            path: path.to_path_buf(),
            reason: format!(
                "the joint states span {} s, but their {} samples at {rate:.1} Hz cover {:.1} s: \
                 a stamp is far off (corrupt), or the log holds recordings with long pauses \
                 between them (split it); the stamps run from {} to {}",
                crate::show::number(t1 - t0),
                densest.len(),
                samples / rate,
                crate::show::number(t0),
                crate::show::number(t1)
            ),
        });
    }
    let n = span_points.round() as usize + 1;
    report.duration = t1 - t0;
    report.rate = 1.0 / dt;
    let mut invalid = vec![false; n];
    let mut theta = Vec::with_capacity(dofs.len());
    let resolution = cleaned.iter().map(|s| encoder_rounding(s)).collect();
    for s in &cleaned {
        let mut column = Vec::with_capacity(n);
        let mut j = 0;
        for (i, flag) in invalid.iter_mut().enumerate() {
            let t = t0 + i as f64 * dt;
            while j + 2 < s.len() && s[j + 1].0 <= t {
                j += 1;
            }
            let (a, b) = (s[j], s[j + 1]);
            let span = b.0 - a.0;
            if span > config.max_gap && t > a.0 && t < b.0 {
                *flag = true;
            }
            let u = ((t - a.0) / span).clamp(0.0, 1.0);
            column.push(a.1 + (b.1 - a.1) * u);
        }
        for w in s.windows(2) {
            let gap = w[1].0 - w[0].0;
            if gap > config.max_gap {
                report.joint_gaps += 1;
            }
            report.longest_joint_gap = report.longest_joint_gap.max(gap);
        }
        theta.push(column);
    }
    Ok(Timeline {
        t0,
        dt,
        theta,
        invalid,
        resolution,
    })
}

/// Steps between readings below this are floating-point noise, not an encoder's, rad.
const FINEST_STEP: f64 = 1e-9;

/// The standard deviation of an encoder's rounding from its readings `(stamp, position)`: a
/// rounded reading changes by whole steps, the smallest of them (over √12, a uniform rounding
/// error's deviation); 0 when the readings change by less than a step's worth anywhere (they are
/// not rounded, or the DoF never moved).
fn encoder_rounding(series: &[(f64, f64)]) -> f64 {
    let step = series
        .windows(2)
        .map(|w| (w[1].1 - w[0].1).abs())
        .filter(|&d| d > FINEST_STEP)
        .fold(f64::INFINITY, f64::min);
    if !step.is_finite() {
        return 0.0;
    }
    // A rounded encoder: every change is a whole number of steps.
    let whole = series
        .windows(2)
        .map(|w| (w[1].1 - w[0].1).abs() / step)
        .all(|k| (k - k.round()).abs() < 1e-3);
    if whole {
        step / 12f64.sqrt()
    } else {
        0.0
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn an_encoders_rounding_is_told_by_its_smallest_step() {
        let step = 2.0 * std::f64::consts::PI / f64::from(1u32 << 17);
        let motion = |t: f64| 0.3 * (2.0 * t).sin();
        let series = |round: bool| -> Vec<(f64, f64)> {
            (0..2000)
                .map(|i| {
                    let t = f64::from(i) * 1e-3;
                    let q = motion(t);
                    (t, if round { (q / step).round() * step } else { q })
                })
                .collect()
        };
        let rounded = encoder_rounding(&series(true));
        assert!(
            (rounded / (step / 12f64.sqrt()) - 1.0).abs() < 1e-9,
            "{rounded}"
        );
        assert_eq!(encoder_rounding(&series(false)), 0.0);
        assert_eq!(encoder_rounding(&[(0.0, 0.25), (0.001, 0.25)]), 0.0);
    }
}
