//! The skin samples, routed to the windows they fall in.

use std::collections::{BTreeMap, HashMap};

use super::fit::Excitation;
use super::segment::Segmentation;
use super::timeline::Timeline;
use super::{IngestConfig, IngestError, LogReport, Progress, Repeated};
use crate::log::{LogSource, Sample, Stream};

/// Names of the SUs and their indices.
#[derive(Debug, Clone)]
pub(super) struct SuRegistry {
    pub(super) names: Vec<String>,
    pub(super) index: HashMap<String, usize>,
    pub(super) fixed: bool,
}

impl SuRegistry {
    pub(super) fn new(known: Option<Vec<String>>) -> Self {
        let fixed = known.is_some();
        let names = known.unwrap_or_default();
        let index = names
            .iter()
            .enumerate()
            .map(|(i, n)| (n.clone(), i))
            .collect();
        SuRegistry {
            names,
            index,
            fixed,
        }
    }

    /// The index of `name`, registering it unless the list is fixed; `hint` is tried first.
    pub(super) fn find(&mut self, name: &str, hint: usize) -> Option<usize> {
        if self.names.get(hint).is_some_and(|n| n == name) {
            return Some(hint);
        }
        if let Some(&i) = self.index.get(name) {
            return Some(i);
        }
        if self.fixed {
            return None;
        }
        self.names.push(name.to_string());
        self.index.insert(name.to_string(), self.names.len() - 1);
        Some(self.names.len() - 1)
    }
}

/// Most names a message lists.
const NAMED: usize = 10;

/// `names` as a list for a message: the first [`NAMED`], then how many more.
fn listed<'a>(names: impl ExactSizeIterator<Item = &'a str>) -> String {
    let more = names.len().saturating_sub(NAMED);
    let mut list: Vec<String> = names.take(NAMED).map(|n| format!("`{n}`")).collect();
    if more > 0 {
        list.push(format!("{more} more"));
    }
    list.join(", ")
}

impl SuRegistry {
    /// The SUs that have no sample in any window of any log: a unit that is broken, unplugged or
    /// only ever sent NaN, one the robot lists but the logs do not hold, or one under another name.
    pub(super) fn silent(&self, accumulated: &[Accumulated]) -> Vec<usize> {
        let heard = |su: usize| {
            accumulated.iter().any(|acc| {
                acc.stills
                    .iter()
                    .any(|w| w.get(su).is_some_and(|s| s.n > 0))
                    || acc
                        .fits
                        .iter()
                        .any(|w| w.get(su).is_some_and(|f| f.samples > 0))
            })
        };
        (0..self.names.len()).filter(|&su| !heard(su)).collect()
    }

    /// Leaves out the SUs `silent` (sorted), so that the others' poses are not all skipped for want
    /// of them, and re-indexes `accumulated` to match; returns the names left out.
    pub(super) fn leave_out(
        &mut self,
        silent: &[usize],
        accumulated: &mut [Accumulated],
    ) -> Vec<String> {
        let kept: Vec<usize> = (0..self.names.len())
            .filter(|su| silent.binary_search(su).is_err())
            .collect();
        // `kept` is sorted: the kept SUs a window has entries for come first.
        fn compact<T: Clone>(v: &mut Vec<T>, kept: &[usize]) {
            *v = kept
                .iter()
                .take_while(|&&su| su < v.len())
                .map(|&su| v[su].clone())
                .collect();
        }
        for acc in accumulated.iter_mut() {
            acc.stills.iter_mut().for_each(|w| compact(w, &kept));
            acc.fits.iter_mut().for_each(|w| compact(w, &kept));
        }
        let left_out = silent.iter().map(|&su| self.names[su].clone()).collect();
        self.names = kept.iter().map(|&su| self.names[su].clone()).collect();
        self.index = self
            .names
            .iter()
            .enumerate()
            .map(|(i, n)| (n.clone(), i))
            .collect();
        left_out
    }
}

/// Leaves out the SUs with no sample in any window of the logs, with a warning that names them
/// (and the frame ids the logs hold that are no SU's, which may be the same SUs under other
/// names); an error when no SU has one but the logs hold other frame ids, or every sample in a
/// window was saturated.
pub(super) fn leave_out_silent(
    sus: &mut SuRegistry,
    accumulated: &mut [Accumulated],
    reports: &[LogReport],
    config: &IngestConfig,
) -> Result<Option<String>, IngestError> {
    let silent = sus.silent(accumulated);
    if silent.is_empty() {
        return Ok(None);
    }
    let unknown: BTreeMap<&str, u64> = reports.iter().flat_map(|r| &r.unknown_frames).fold(
        BTreeMap::new(),
        |mut all, (name, n)| {
            *all.entry(name.as_str()).or_default() += n;
            all
        },
    );
    let others = (!unknown.is_empty()).then(|| {
        format!(
            "the logs' frame ids that are no SU's: {}",
            listed(unknown.keys().copied())
        )
    });
    if silent.len() == sus.names.len() {
        let saturated: u64 = reports.iter().flat_map(|r| r.saturated.values()).sum();
        if saturated > 0 {
            let unit = if config.skin_scale == 1.0 {
                "a skin driver that publishes mg needs --skin-unit mg".to_string()
            } else {
                format!(
                    "they were scaled by {}: if the skin's samples are in m/s² already, leave \
                     out --skin-unit",
                    config.skin_scale
                )
            };
            return Err(IngestError::Empty(format!(
                "every skin sample in a window is saturated ({saturated} at or beyond ±{:.1} \
                 m/s²): {unit}; otherwise give the accelerometers' range with --saturation",
                config.saturation
            )));
        }
        return match others {
            Some(others) => Err(IngestError::Empty(format!(
                "no SU listed ({}) has a sample in the logs; {others}: the skin's frame ids must \
                 be the robot's SU names",
                listed(sus.names.iter().map(String::as_str))
            ))),
            // The windows will say what is missing.
            None => Ok(None),
        };
    }
    let kept = sus.names.len() - silent.len();
    let left_out = sus.leave_out(&silent, accumulated);
    let count = match left_out.len() {
        1 => "1 SU has".to_string(),
        n => format!("{n} SUs have"),
    };
    let mut warning = format!(
        "{count} no sample in any still or excitation window of the logs (broken, unplugged, \
         sending only NaN, or not on the part recorded): left out of the measurement set, which \
         holds the other {kept}: {}",
        listed(left_out.iter().map(String::as_str))
    );
    if let Some(others) = others {
        warning.push_str(&format!("; {others} (the same SUs under other names?)"));
    }
    Ok(Some(warning))
}

/// Per SU, the running sums of a still window.
#[derive(Debug, Clone, Copy, Default)]
pub(super) struct StillSum {
    pub(super) n: u64,
    pub(super) sum: [f64; 3],
    pub(super) squares: [f64; 3],
}

/// Per SU, the right-hand sides of an excitation's normal equations, from the mean of the
/// samples at each grid point: a skin faster than the joint states gives several per point.
#[derive(Debug, Clone, Default)]
pub(super) struct FitSum {
    /// One per term of the window's model.
    pub(super) rhs: Vec<[f64; 3]>,
    /// The newest grid point with samples (in the window), their sum and number: their mean
    /// goes into `rhs` once a later point has a sample, or the window ends.
    newest: Option<(usize, [f64; 3], u32)>,
    /// Samples routed here.
    pub(super) samples: u64,
    /// Grid points with samples, and the sum over them of one over their number of samples (the
    /// variance of their means in units of one sample's).
    pub(super) points: u64,
    pub(super) inverse: f64,
}

/// The mean of `k` samples whose sum is `sum` (the sum itself for one).
fn mean_of(sum: [f64; 3], k: u32) -> [f64; 3] {
    if k == 1 {
        sum
    } else {
        sum.map(|s| s / f64::from(k))
    }
}

impl FitSum {
    /// A sample at point `local` of window `x`; returns the points filled by linear
    /// interpolation (the gap since the newest point, or the window's start).
    fn sample(&mut self, x: &Excitation, local: usize, a: [f64; 3]) -> u64 {
        self.samples += 1;
        match &mut self.newest {
            Some((p, sum, k)) if *p == local => {
                for (s, v) in sum.iter_mut().zip(a) {
                    *s += v;
                }
                *k += 1;
                0
            }
            &mut Some((p, sum, k)) if p < local => {
                let value = mean_of(sum, k);
                self.mean(x, p, value, k);
                for j in p + 1..local {
                    let u = (j - p) as f64 / (local - p) as f64;
                    self.add(x, j, [0, 1, 2].map(|i| value[i] + (a[i] - value[i]) * u));
                }
                self.newest = Some((local, a, 1));
                (local - p - 1) as u64
            }
            // Earlier than the newest point (stamps out of order): on its own.
            Some(_) => {
                self.mean(x, local, a, 1);
                0
            }
            None => {
                for j in 0..local {
                    self.add(x, j, a);
                }
                self.newest = Some((local, a, 1));
                local as u64
            }
        }
    }

    /// The window's end: the newest point's mean added and the points after it filled with it;
    /// returns how many were filled.
    fn end(&mut self, x: &Excitation) -> u64 {
        let Some((p, sum, k)) = self.newest.take() else {
            return 0;
        };
        let value = mean_of(sum, k);
        self.mean(x, p, value, k);
        for j in p + 1..x.len() {
            self.add(x, j, value);
        }
        (x.len() - p - 1) as u64
    }

    /// The mean `value` of `k` samples at point `m`.
    fn mean(&mut self, x: &Excitation, m: usize, value: [f64; 3], k: u32) {
        self.add(x, m, value);
        self.points += 1;
        // One sample per point is the rule: no division for it.
        self.inverse += if k == 1 { 1.0 } else { 1.0 / f64::from(k) };
    }

    fn add(&mut self, x: &Excitation, m: usize, a: [f64; 3]) {
        let nc = x.terms.len();
        if self.rhs.len() < nc {
            self.rhs.resize(nc, [0.0; 3]);
        }
        for (r, w) in self.rhs.iter_mut().zip(&x.weights[m * nc..(m + 1) * nc]) {
            for (axis, v) in a.iter().enumerate() {
                r[axis] += w * v;
            }
        }
    }
}

/// The accumulated samples of one log.
#[derive(Debug, Clone, Default)]
pub(super) struct Accumulated {
    pub(super) stills: Vec<Vec<StillSum>>,
    pub(super) fits: Vec<Vec<FitSum>>,
}

pub(super) fn grow<T: Default + Clone>(v: &mut Vec<T>, len: usize) {
    if v.len() < len {
        v.resize(len, T::default());
    }
}

/// The skin samples of one log on their way into the windows' sums: what arrives is checked
/// (the SU known, its stamps in order), what is routed goes to the window it falls in.
#[derive(Debug, Default)]
pub(super) struct Router {
    pub(super) acc: Accumulated,
    last_stamp: Vec<f64>,
    hint: usize,
    route: usize,
    saturated: HashMap<usize, u64>,
    filled: u64,
    /// The earliest and latest stamp of the samples of known SUs.
    span: Option<(f64, f64)>,
    /// Per SU: its last sample, its samples, how many repeated the one before exactly, and
    /// whether any differed from it.
    repeats: Vec<Repeats>,
}

/// How an SU's samples repeat (see [`LogReport::repeated`]).
#[derive(Debug, Clone)]
struct Repeats {
    last: Option<[f64; 3]>,
    samples: u64,
    repeated: u64,
    /// The length of the run of equal samples that goes on.
    run: usize,
    /// How many finished runs had each length (the last entry: that length or longer).
    runs: [u64; LONGEST_RUN + 1],
}

impl Default for Repeats {
    fn default() -> Self {
        Self {
            last: None,
            samples: 0,
            repeated: 0,
            run: 0,
            runs: [0; LONGEST_RUN + 1],
        }
    }
}

impl Repeats {
    fn add(&mut self, sample: [f64; 3]) {
        self.samples += 1;
        if self.last == Some(sample) {
            self.repeated += 1;
            self.run += 1;
            return;
        }
        if self.run > 0 {
            self.runs[self.run.min(LONGEST_RUN)] += 1;
        }
        self.last = Some(sample);
        self.run = 1;
    }

    /// A board held by a slower port: most samples repeat the one before, in short runs that
    /// end (the typical run is 2 long or more). A simulated noise-free skin repeats for whole
    /// still periods but changes at every sample in motion (its typical run is 1); a dead or
    /// frozen board never changes.
    fn held(&self) -> bool {
        let finished: u64 = self.runs.iter().sum();
        let mut below = 0;
        let typical = (1..=LONGEST_RUN).find(|&k| {
            below += self.runs[k];
            2 * below >= finished
        });
        finished > 0
            && self.repeated as f64 > HELD_SHARE * self.samples as f64
            && typical.is_some_and(|k| (2..LONGEST_RUN).contains(&k))
    }
}

/// An SU whose samples repeat the one before this often (in short runs) is a slower board behind
/// a port that repeats its last sample.
const HELD_SHARE: f64 = 0.5;
/// Runs of equal samples this long or longer are counted together: a board this much slower
/// than its port is a stale one.
const LONGEST_RUN: usize = 64;

impl Router {
    /// The SU of a sample of `frame_id` at `stamp`; `None` (counted) for a frame not expected.
    pub(super) fn arrive(
        &mut self,
        sus: &mut SuRegistry,
        frame_id: &str,
        stamp: f64,
        report: &mut LogReport,
    ) -> Option<usize> {
        report.imu_samples += 1;
        let Some(su) = sus.find(frame_id, self.hint) else {
            *report
                .unknown_frames
                .entry(frame_id.to_string())
                .or_default() += 1;
            return None;
        };
        self.hint = su + 1;
        self.span = match self.span {
            Some((first, last)) => Some((first.min(stamp), last.max(stamp))),
            None => Some((stamp, stamp)),
        };
        grow(&mut self.last_stamp, su + 1);
        if stamp < self.last_stamp[su] {
            report.unsorted_imu_stamps += 1;
        }
        self.last_stamp[su] = stamp;
        Some(su)
    }

    /// Adds the sample of SU `su` at grid point `m` to the windows of `seg` it falls in. A
    /// motion's window reaches `2l` into the pauses on either side, where their still windows
    /// read too: an excitation takes every sample of its window (one its fit lacks is filled
    /// with its nearest sample), and a still window shares the end of its pause with the
    /// excitation after it but not its start with the one before, where a servo that stopped
    /// may still ring.
    pub(super) fn route(
        &mut self,
        seg: &Segmentation,
        config: &IngestConfig,
        su: usize,
        m: usize,
        acceleration: [f64; 3],
    ) {
        let acceleration = acceleration.map(|v| v * config.skin_scale);
        grow(&mut self.repeats, su + 1);
        self.repeats[su].add(acceleration);
        // The last window starting at or before m: usually the current one or the next.
        let routes = &seg.routes;
        let r = self.route;
        let current =
            r < routes.len() && routes[r].0 <= m && routes.get(r + 1).is_none_or(|next| next.0 > m);
        if !current {
            self.route = routes.partition_point(|r| r.0 <= m).saturating_sub(1);
        }
        // Windows overlap only their neighbours: each is longer than what its neighbours reach
        // into it (a pause is at least 4l + 1 long, its still window trimmed at both ends).
        let (mut routed, mut after_motion) = (false, false);
        for k in self.route.saturating_sub(2)..=self.route {
            let Some(&(start, end, is_still, w)) = routes.get(k) else {
                continue;
            };
            if m < start || m >= end || (is_still && after_motion) {
                continue;
            }
            after_motion |= !is_still;
            if !routed && config.saturated(&acceleration) {
                // Only samples the readings would use are counted: a saturated sample during a
                // transfer does not matter.
                *self.saturated.entry(su).or_default() += 1;
                return;
            }
            routed = true;
            self.add(seg, su, (m, start, is_still, w), acceleration);
        }
    }

    /// Adds the sample of SU `su` at grid point `m` to window `w` (a still one or an excitation)
    /// that starts at grid point `start`.
    fn add(
        &mut self,
        seg: &Segmentation,
        su: usize,
        (m, start, is_still, w): (usize, usize, bool, usize),
        acceleration: [f64; 3],
    ) {
        if is_still {
            grow(&mut self.acc.stills, w + 1);
            let sums = &mut self.acc.stills[w];
            grow(sums, su + 1);
            let s = &mut sums[su];
            s.n += 1;
            for (k, a) in acceleration.iter().enumerate() {
                s.sum[k] += a;
                s.squares[k] += a * a;
            }
        } else {
            let x = &seg.excitations[w];
            grow(&mut self.acc.fits, w + 1);
            let fits = &mut self.acc.fits[w];
            grow(fits, su + 1);
            self.filled += fits[su].sample(x, m - start, acceleration);
        }
    }

    /// The sums of every window of `seg`, once every sample is routed: the missing samples at the
    /// ends of excitation windows filled, the saturated and filled ones counted in `report`.
    pub(super) fn finish(
        mut self,
        seg: &Segmentation,
        sus: &SuRegistry,
        report: &mut LogReport,
    ) -> Accumulated {
        grow(&mut self.acc.stills, seg.stills.len());
        grow(&mut self.acc.fits, seg.excitations.len());
        for (w, fits) in self.acc.fits.iter_mut().enumerate() {
            let x = &seg.excitations[w];
            for f in fits.iter_mut() {
                self.filled += f.end(x);
            }
        }
        report.filled = self.filled;
        report.imu_span = self.span.map(|(first, last)| [first, last]);
        for (su, count) in self.saturated {
            report.saturated.insert(sus.names[su].clone(), count);
        }
        let seconds = self.span.map_or(0.0, |(first, last)| last - first);
        for (su, r) in self.repeats.iter().enumerate() {
            if r.held() && seconds > 0.0 {
                report.repeated.insert(
                    sus.names[su].clone(),
                    Repeated {
                        share: r.repeated as f64 / r.samples as f64,
                        fresh_rate: (r.samples - r.repeated) as f64 / seconds,
                    },
                );
            }
        }
        self.acc
    }
}

/// The skin samples of the log at `path` into the windows of its timeline: a pass over them alone.
pub(super) fn read_skin(
    source: &LogSource,
    timeline: &Timeline,
    seg: &Segmentation,
    config: &IngestConfig,
    sus: &mut SuRegistry,
    report: &mut LogReport,
    progress: &mut Progress<'_>,
) -> Result<Accumulated, IngestError> {
    let path = source.path();
    let total = source.size(Stream::Imu);
    let label = format!("skin samples of {}", path.display());
    let mut router = Router::default();
    let n = timeline.len() as i64;
    let stats = source.read(
        Stream::Imu,
        &config.topics,
        &mut |s| {
            let Sample::Imu {
                stamp,
                frame_id,
                acceleration,
            } = s
            else {
                return Ok(());
            };
            let Some(su) = router.arrive(sus, frame_id, stamp, report) else {
                return Ok(());
            };
            let m = timeline.grid.index(stamp);
            if m < 0 || m >= n {
                report.imu_outside += 1;
            } else {
                router.route(seg, config, su, m as usize, acceleration);
            }
            Ok(())
        },
        &mut |done| progress(&label, done, total),
    )?;
    report.imu_read = stats.imu;
    Ok(router.finish(seg, sus, report))
}
