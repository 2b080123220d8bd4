//! Joint states on a uniform grid.

use std::collections::HashMap;
use std::path::Path;

use skincal_scratch::Buffer;

use super::window::JointsSurveyed;
use super::{IngestConfig, IngestError, LogReport, Progress};
use crate::log::{LogSource, Sample, Stream};

/// Slowest joint-state rate that can resolve an excitation pattern, Hz.
const MIN_JOINT_RATE: f64 = 20.0;
/// Longest pause without joint states inside one log, s.
pub(super) const MAX_PAUSE: f64 = 600.0;

/// The period of a log's grid is fitted to the joint stamps of its first this many seconds, so
/// that a single pass can place samples on the grid long before the log ends.
pub(super) const GRID_SPAN: f64 = 1.0;

/// A log's grid: where grid point 0 lies, its period, and each DoF's encoder rounding.
#[derive(Debug, Clone)]
pub(super) struct Grid {
    pub(super) t0: f64,
    pub(super) dt: f64,
    /// Per DoF (in the order of the common DoF list), the standard deviation of its encoder's
    /// rounding, rad: the smallest step between two of its readings over √12 (0 for readings
    /// that are not rounded).
    pub(super) resolution: Vec<f64>,
    /// Per DoF, its encoder's count (the smallest change of its readings so far: those the grid
    /// was fitted to, kept up by a single pass as the log is read, [`Rounding`]), rad; 0 where
    /// they do not change by whole counts. A still DoF's readings may flicker by a count either
    /// way.
    pub(super) count: Vec<f64>,
}

impl Grid {
    /// The grid point nearest to `stamp` (negative before the first; halves round up).
    pub(super) fn index(&self, stamp: f64) -> i64 {
        // floor(x + ½) by truncation: f64::round is a library call on baseline x86-64, and this
        // runs once per skin sample.
        let x = (stamp - self.t0) / self.dt + 0.5;
        let t = x as i64;
        t.saturating_sub(i64::from((t as f64) > x))
    }

    /// Time of grid point `n`, s from the first.
    pub(super) fn time(&self, n: usize) -> f64 {
        n as f64 * self.dt
    }

    /// The grid of the joint series `cleaned` (sorted, without repeated stamps, every DoF with two
    /// samples or more): it starts when every DoF has a sample, and its period is fitted to the
    /// stamps of the DoF with most samples in its first [`GRID_SPAN`] seconds.
    pub(super) fn fit(path: &Path, cleaned: &[Samples]) -> Result<Grid, IngestError> {
        let unusable = |reason: String| IngestError::Unusable {
            path: path.to_path_buf(),
            reason,
        };
        let prefix = |s: &[State]| s.partition_point(|p| p[0] < s[0][0] + GRID_SPAN).max(2);
        let densest = cleaned
            .iter()
            .max_by_key(|s| prefix(s))
            .ok_or_else(|| unusable("no DoF has joint states".into()))?;
        let densest = &densest[..prefix(densest).min(densest.len())];
        let mut steps: Vec<f64> = densest.windows(2).map(|w| w[1][0] - w[0][0]).collect();
        steps.sort_by(f64::total_cmp);
        let rough = steps[steps.len() / 2];
        if !(rough > 0.0 && rough.is_finite()) {
            return Err(unusable("the joint states have no usable time step".into()));
        }
        // The period to far better than the stamps' resolution: a straight line through (sample
        // number, stamp), numbering the samples by the rough period between neighbours so that
        // lost ones keep their place. A grid whose period is off by 1e-4 would slip by a sample
        // every ten seconds.
        let dt = {
            let first = densest[0][0];
            let (mut sk, mut st, mut skk, mut skt, mut count) = (0.0, 0.0, 0.0, 0.0, 0.0);
            let mut k = 0.0;
            let mut previous = first;
            for &[t, _] in densest {
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
        let rate = 1.0 / dt;
        if rate < MIN_JOINT_RATE {
            return Err(unusable(format!(
                "the joint states come every {} (stamp units) — {rate:.3} Hz if the stamps are \
                 seconds, too slow to see an excitation pattern (at least {MIN_JOINT_RATE} Hz): \
                 stamps must be in seconds; if they are in ms, µs or ns, divide them by 1e3, 1e6 \
                 or 1e9",
                crate::show::number(dt)
            )));
        }
        Ok(Grid {
            t0: cleaned.iter().map(|s| s[0][0]).fold(f64::MIN, f64::max),
            dt,
            resolution: Vec::new(),
            count: cleaned
                .iter()
                .map(|s| {
                    let mut rounding = Rounding::default();
                    rounding.read(s);
                    rounding.count()
                })
                .collect(),
        })
    }

    /// Number of grid points of the whole log; checks that the DoFs overlap in time and that no
    /// stamp is far off.
    pub(super) fn points(&self, path: &Path, cleaned: &[Samples]) -> Result<usize, IngestError> {
        let t1 = newest_common(cleaned);
        let unusable = |reason: String| IngestError::Unusable {
            path: path.to_path_buf(),
            reason,
        };
        if t1 <= self.t0 {
            return Err(unusable(
                "the DoFs' joint states do not overlap in time".into(),
            ));
        }
        let rate = 1.0 / self.dt;
        // Lengths come from the stamps: one far-off stamp must not make a grid of years.
        let span_points = (t1 - self.t0) / self.dt;
        let samples = cleaned.iter().map(|s| s.len()).max().unwrap_or(0) as f64;
        if span_points > 4.0 * samples + MAX_PAUSE * rate {
            return Err(unusable(format!(
                "the joint states span {} s, but their {} samples at {rate:.1} Hz cover {:.1} s: \
                 a stamp is far off (corrupt), or the log holds recordings with long pauses \
                 between them (split it); the stamps run from {} to {}",
                crate::show::number(t1 - self.t0),
                samples,
                samples / rate,
                crate::show::number(self.t0),
                crate::show::number(t1)
            )));
        }
        Ok(span_points.round() as usize + 1)
    }

    /// The whole log's figures in its report: duration, rate, gaps; and the encoders' rounding.
    pub(super) fn finish(
        &mut self,
        cleaned: &[Samples],
        config: &IngestConfig,
        report: &mut LogReport,
    ) {
        report.duration = newest_common(cleaned) - self.t0;
        report.rate = 1.0 / self.dt;
        for s in cleaned {
            for w in s.windows(2) {
                let gap = w[1][0] - w[0][0];
                if gap > config.max_gap {
                    report.joint_gaps += 1;
                }
                report.longest_joint_gap = report.longest_joint_gap.max(gap);
            }
        }
        self.resolution = cleaned.iter().map(|s| encoder_rounding(s)).collect();
    }
}

/// The newest stamp every DoF's series has reached (`f64::MIN` while one is empty).
pub(super) fn newest_common(series: &[Samples]) -> f64 {
    series
        .iter()
        .map(|s| s.last().map_or(f64::MIN, |p| p[0]))
        .fold(f64::MAX, f64::min)
}

/// One joint state: `[stamp, position]`.
pub(super) type State = [f64; 2];

/// One DoF's joint states, sorted: on the heap up to [`SERIES_HEAP`], past it in a scratch file.
pub(super) type Samples = Buffer<State>;

/// The most bytes of one DoF's joint states (its series as read, its positions on the grid) held
/// on the heap: a minute at 1 kHz. A longer log's are in a scratch file, so that the heap holds
/// as much for a log of hours as for one of a minute, whatever the number of DoFs.
pub(super) const SERIES_HEAP: usize = 1 << 20;

/// An empty series of joint states.
pub(super) fn new_series() -> Samples {
    Samples::with_limit(SERIES_HEAP)
}

/// Joint positions of grid points `[first, first + len)` of one log.
#[derive(Debug, Clone)]
pub(super) struct Timeline {
    pub(super) grid: Grid,
    /// The grid point of `theta[·][0]`.
    pub(super) first: usize,
    /// Positions per DoF (in the order of the common DoF list), one per grid point.
    pub(super) theta: Vec<Buffer<f64>>,
    /// Grid points inside a joint-state gap.
    pub(super) invalid: Vec<bool>,
    /// Per DoF: a mimic joint, which moves only with its leader (empty when none is).
    pub(super) mimic: Vec<bool>,
}

impl Timeline {
    pub(super) fn len(&self) -> usize {
        self.invalid.len()
    }

    /// Time of local point `n`, s from the log's first grid point.
    pub(super) fn time(&self, n: usize) -> f64 {
        self.grid.time(self.first + n)
    }

    /// Whether DoF `e` is a mimic joint: its motion is its leader's and tells nothing of its own.
    pub(super) fn follows(&self, e: usize) -> bool {
        self.mimic.get(e).copied().unwrap_or(false)
    }

    /// Grid points `[from, to)` of `grid`, the DoFs' positions linearly interpolated between their
    /// samples `cleaned` (sorted, without repeated stamps, in the order of `dofs`); points inside
    /// a gap longer than `config.max_gap` are invalid.
    pub(super) fn build(
        grid: &Grid,
        (cleaned, dofs): (&[Samples], &[String]),
        from: usize,
        to: usize,
        config: &IngestConfig,
    ) -> Timeline {
        let max_gap = config.max_gap;
        let n = to.saturating_sub(from);
        let mut invalid = vec![false; n];
        let mut theta = Vec::with_capacity(cleaned.len());
        for s in cleaned {
            let mut column = Buffer::with_limit(SERIES_HEAP);
            column.reserve(n);
            let time = |i: usize| grid.t0 + (from + i) as f64 * grid.dt;
            // The last sample at or before the point, but never the last of all.
            let mut j = s
                .partition_point(|p| p[0] <= time(0))
                .saturating_sub(1)
                .min(s.len() - 2);
            for (i, flag) in invalid.iter_mut().enumerate() {
                let t = time(i);
                while j + 2 < s.len() && s[j + 1][0] <= t {
                    j += 1;
                }
                let (a, b) = (s[j], s[j + 1]);
                let span = b[0] - a[0];
                if span > max_gap && t > a[0] && t < b[0] {
                    *flag = true;
                }
                let u = ((t - a[0]) / span).clamp(0.0, 1.0);
                column.push(a[1] + (b[1] - a[1]) * u);
            }
            theta.push(column);
        }
        Timeline {
            grid: grid.clone(),
            first: from,
            theta,
            invalid,
            mimic: dofs.iter().map(|d| config.mimic.contains_key(d)).collect(),
        }
    }
}

/// The joint states of one log as read, per DoF name in order of first appearance: `[stamp,
/// position]` in arrival order.
#[derive(Debug, Default)]
pub(super) struct Series {
    pub(super) by_name: HashMap<String, Samples>,
    pub(super) order: Vec<String>,
}

impl Series {
    pub(super) fn push(&mut self, stamp: f64, names: &[String], positions: &[f64]) {
        for (name, &q) in names.iter().zip(positions) {
            let entry = self.by_name.entry(name.clone()).or_insert_with(|| {
                self.order.push(name.clone());
                new_series()
            });
            entry.push([stamp, q]);
        }
    }

    /// The series of the DoFs (the expected ones, else all seen, which become the expected ones),
    /// sorted and without repeated stamps; unknown names, unsorted and repeated stamps counted.
    pub(super) fn clean(
        mut self,
        path: &Path,
        config: &IngestConfig,
        dof_names: &mut Option<Vec<String>>,
        report: &mut LogReport,
    ) -> Result<Vec<Samples>, IngestError> {
        let dofs = expected_dofs(path, config, &self.order, dof_names, report, |name| {
            self.by_name.get(name).map_or(0, |s| s.len()) as u64
        })?;
        let mut cleaned: Vec<Samples> = Vec::with_capacity(dofs.len());
        for d in &dofs {
            let mut s = self.by_name.remove(d).unwrap_or_else(new_series);
            report.unsorted_joint_stamps +=
                s.windows(2).filter(|w| w[1][0] < w[0][0]).count() as u64;
            s.sort_by(|a, b| a[0].total_cmp(&b[0]));
            report.duplicate_joint_stamps += s.dedup_by(|b, a| b[0] == a[0]) as u64;
            too_few(path, d, &s)?;
            cleaned.push(s);
        }
        Ok(cleaned)
    }
}

/// An error unless DoF `d` has two joint states or more.
fn too_few(path: &Path, d: &str, s: &[State]) -> Result<(), IngestError> {
    if s.len() < 2 {
        return Err(IngestError::Unusable {
            path: path.to_path_buf(),
            reason: format!("DoF `{d}` has fewer than two joint states"),
        });
    }
    Ok(())
}

/// The DoFs of a log whose joint states named `seen` (in order of first appearance; `count` gives
/// a name's samples): the expected ones (other names are reported as unknown), else those seen,
/// which become the expected ones of the next logs. Expected DoFs the log does not have (a log of
/// one part of the robot) are named in the report and left out of the expected ones, provided it
/// has one of them at least.
pub(super) fn expected_dofs(
    path: &Path,
    config: &IngestConfig,
    seen: &[String],
    dof_names: &mut Option<Vec<String>>,
    report: &mut LogReport,
    count: impl Fn(&str) -> u64,
) -> Result<Vec<String>, IngestError> {
    match dof_names {
        Some(known) => {
            for name in seen {
                if !known.contains(name) {
                    report.unknown_joints.insert(name.clone(), count(name));
                }
            }
            let (recorded, missing): (Vec<String>, Vec<String>) =
                known.iter().cloned().partition(|d| seen.contains(d));
            if recorded.is_empty() {
                return Err(IngestError::Unusable {
                    path: path.to_path_buf(),
                    reason: format!(
                        "no joint states for any of the DoF(s) {missing:?} (names seen: \
                         {seen:?}); check the joint topic (--joint-topic) and that the log is of \
                         this robot"
                    ),
                });
            }
            if !missing.is_empty() {
                report.unrecorded_joints = missing;
                *known = recorded;
            }
            Ok(known.clone())
        }
        None => {
            if seen.is_empty() {
                return Err(IngestError::Unusable {
                    path: path.to_path_buf(),
                    reason: format!(
                        "no joint states found (topic `{}`); choose it with --joint-topic",
                        config.topics.joints
                    ),
                });
            }
            *dof_names = Some(seen.to_vec());
            Ok(seen.to_vec())
        }
    }
}

/// The joint states of the log at `path` on its grid: a pass over them alone.
pub(super) fn read_joints(
    source: &LogSource,
    config: &IngestConfig,
    dof_names: &mut Option<Vec<String>>,
    report: &mut LogReport,
    progress: &mut Progress<'_>,
) -> Result<Timeline, IngestError> {
    let path = source.path();
    let total = source.size(Stream::Joints);
    let label = format!("joint states of {}", path.display());
    let mut series = Series::default();
    let stats = source.read(
        Stream::Joints,
        &config.topics,
        &mut |s| {
            if let Sample::Joints {
                stamp,
                names,
                positions,
            } = s
            {
                series.push(stamp, names, positions);
            }
            Ok(())
        },
        &mut |done| progress(&label, done, total),
    )?;
    report.joint_states = stats.joints.samples;
    report.joint_read = stats.joints;
    let cleaned = series.clean(path, config, dof_names, report)?;
    report.surveyed = Some(JointsSurveyed::of(
        dof_names.as_deref().unwrap_or_default(),
        &cleaned,
    ));
    let mut grid = Grid::fit(path, &cleaned)?;
    let n = grid.points(path, &cleaned)?;
    grid.finish(&cleaned, config, report);
    let dofs = dof_names.clone().unwrap_or_default();
    Ok(Timeline::build(&grid, (&cleaned, &dofs), 0, n, config))
}

/// Steps between readings below this are floating-point noise, not an encoder's, rad.
const FINEST_STEP: f64 = 1e-9;
/// The changes of at most this many steps tell whether an encoder's readings are rounded.
const FEW_STEPS: f64 = 20.0;
/// How far from a whole number of steps such a change may be.
const WHOLE: f64 = 0.02;

/// The standard deviation of an encoder's rounding from its readings `(stamp, position)`: a
/// rounded reading changes by whole steps, the smallest of them (over √12, a uniform rounding
/// error's deviation); 0 when the readings change by less than a step's worth anywhere (they are
/// not rounded, or the DoF never moved).
pub(super) fn encoder_rounding(series: &[State]) -> f64 {
    let mut rounding = Rounding::default();
    rounding.read(series);
    rounding.count() / 12f64.sqrt()
}

/// An encoder's step, told from its readings as they come, in memory bounded whatever their
/// number: the smallest change between two of them, and whether every change of a few such
/// steps is a whole number of them. A change of more than [`FEW_STEPS`] steps tells nothing, and
/// steps only shrink: only the distinct small changes (to [`FINEST_STEP`]) are kept, to be looked
/// at again when a smaller step comes. A rounded encoder's small changes take a few dozen values
/// (whole counts, give or take what its printed decimals leave); readings that take more than
/// [`MOST_SMALL_CHANGES`] are no encoder's counts.
#[derive(Debug, Clone, PartialEq)]
pub(super) struct Rounding {
    /// Readings of the series [`Self::read`] looks at, looked at.
    read: usize,
    /// The last reading taken.
    last: Option<f64>,
    step: f64,
    whole: bool,
    /// The changes of at most [`FEW_STEPS`] steps, by their number of [`FINEST_STEP`]s; `None`
    /// once there were too many to be an encoder's.
    small: Option<std::collections::BTreeMap<i64, f64>>,
}

/// The most distinct small changes an encoder's readings are taken to have.
const MOST_SMALL_CHANGES: usize = 4096;

impl Default for Rounding {
    fn default() -> Self {
        Rounding {
            read: 0,
            last: None,
            step: f64::INFINITY,
            whole: true,
            small: Some(Default::default()),
        }
    }
}

impl Rounding {
    /// Looks at the readings of `series` (the same series, grown) not yet looked at.
    pub(super) fn read(&mut self, series: &[State]) {
        for &[_, q] in &series[self.read.min(series.len())..] {
            self.take(q);
        }
        self.read = self.read.max(series.len());
    }

    /// Takes the next reading.
    pub(super) fn take(&mut self, q: f64) {
        let Some(last) = self.last.replace(q) else {
            return;
        };
        let change = (q - last).abs();
        if change <= FINEST_STEP || !change.is_finite() {
            return;
        }
        let Some(small) = self.small.as_mut() else {
            return;
        };
        if change < self.step {
            self.step = change;
            // Changes of more than a few of the new step tell nothing from now on.
            small.retain(|_, c| *c <= FEW_STEPS * change);
            self.whole = small.values().all(|&c| whole_steps(c, change));
        } else if self.whole {
            self.whole = whole_steps(change, self.step);
        }
        if change <= FEW_STEPS * self.step {
            small.insert((change / FINEST_STEP).round() as i64, change);
            if small.len() > MOST_SMALL_CHANGES {
                self.small = None;
            }
        }
    }

    /// The encoder's count, rad: 0 when no reading changed or they do not change by whole steps.
    pub(super) fn count(&self) -> f64 {
        if self.whole && self.step.is_finite() && self.small.is_some() {
            self.step
        } else {
            0.0
        }
    }
}

/// Whether `change` is a whole number of `step`s, if it is a few of them. A rounded encoder's
/// every change is, within what the log's printed decimals leave; a large change carries the
/// step's own error times its count (9 decimals on a 17-bit step: 1e-5 of it) and tells nothing.
fn whole_steps(change: f64, step: f64) -> bool {
    let k = change / step;
    k > FEW_STEPS || (k - k.round()).abs() < WHOLE
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn an_encoders_rounding_is_told_by_its_smallest_step() {
        let step = 2.0 * std::f64::consts::PI / f64::from(1u32 << 17);
        let motion = |t: f64| 0.3 * (2.0 * t).sin();
        let series = |round: bool| -> Vec<State> {
            (0..2000)
                .map(|i| {
                    let t = f64::from(i) * 1e-3;
                    let q = motion(t);
                    [t, if round { (q / step).round() * step } else { q }]
                })
                .collect()
        };
        let rounded = encoder_rounding(&series(true));
        assert!(
            (rounded / (step / 12f64.sqrt()) - 1.0).abs() < 1e-9,
            "{rounded}"
        );
        assert_eq!(encoder_rounding(&series(false)), 0.0);
        // Printed with 9 decimals, as a CSV log holds it, and moving fast (hundreds of steps
        // per sample): still told rounded by its small changes.
        let fast: Vec<State> = (0..2000)
            .map(|i| {
                let t = f64::from(i) * 1e-3;
                let q = ((1.5 * (10.0 * t).sin()) / step).round() * step;
                [t, format!("{q:.9}").parse().unwrap()]
            })
            .collect();
        let printed = encoder_rounding(&fast);
        assert!(
            (printed / (step / 12f64.sqrt()) - 1.0).abs() < 1e-3,
            "{printed}"
        );
        assert_eq!(encoder_rounding(&[[0.0, 0.25], [0.001, 0.25]]), 0.0);
    }

    #[test]
    fn an_encoders_count_kept_up_as_readings_come_is_that_of_all_of_them() {
        // Still for a second (no change), then a move with flicker: read in chunks of any
        // size, the count is the whole series' once its first change has come, and 0 before.
        let step = 2.0 * std::f64::consts::PI / 4096.0;
        let series: Vec<State> = (0..3000)
            .map(|i| {
                let t = f64::from(i) * 1e-3;
                let q = if t < 1.0 {
                    0.0
                } else {
                    0.3 * (1.0 - (3.0 * (t - 1.0)).cos())
                };
                let flicker = if t >= 1.0 && i % 7 == 0 { step } else { 0.0 };
                [
                    t,
                    format!("{:.9}", (q / step).round() * step + flicker)
                        .parse()
                        .unwrap(),
                ]
            })
            .collect();
        let whole = encoder_rounding(&series) * 12f64.sqrt();
        assert!((whole / step - 1.0).abs() < 1e-6, "{whole} against {step}");
        for chunk in [1, 13, 999, 3000] {
            let mut rounding = Rounding::default();
            let mut end = 0;
            while end < series.len() {
                end = (end + chunk).min(series.len());
                rounding.read(&series[..end]);
                if end <= 1000 && series[..end].iter().all(|p| p[1] == 0.0) {
                    assert_eq!(rounding.count(), 0.0, "chunk {chunk}, {end} read");
                }
            }
            assert_eq!(rounding.count(), whole, "chunk {chunk}");
        }
        // Readings that do not change by whole steps: no count, however they are read.
        let smooth: Vec<State> = (0..2000)
            .map(|i| [f64::from(i) * 1e-3, (f64::from(i) * 2e-3).sin()])
            .collect();
        let mut rounding = Rounding::default();
        for end in (100..=2000).step_by(100) {
            rounding.read(&smooth[..end]);
        }
        assert_eq!(rounding.count(), 0.0);
    }
}
