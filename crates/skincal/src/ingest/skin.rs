//! The skin samples, routed to the windows they fall in.

use std::collections::HashMap;
use std::path::Path;

use super::fit::Excitation;
use super::segment::Segmentation;
use super::timeline::Timeline;
use super::{IngestConfig, IngestError, LogReport, Progress};
use crate::log::{self, Sample, Stream};

/// Names of the SUs and their indices.
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

/// Per SU, the running sums of a still window.
#[derive(Debug, Clone, Copy, Default)]
pub(super) struct StillSum {
    pub(super) n: u64,
    pub(super) sum: [f64; 3],
    pub(super) squares: [f64; 3],
}

/// Per SU, the right-hand sides of an excitation's normal equations and the last sample seen.
#[derive(Debug, Clone, Default)]
pub(super) struct FitSum {
    /// One per term of the window's model.
    pub(super) rhs: Vec<[f64; 3]>,
    pub(super) last: Option<(usize, [f64; 3])>,
    pub(super) samples: u64,
}

impl FitSum {
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

pub(super) fn read_skin(
    path: &Path,
    timeline: &Timeline,
    seg: &Segmentation,
    config: &IngestConfig,
    sus: &mut SuRegistry,
    report: &mut LogReport,
    progress: &mut Progress<'_>,
) -> Result<Accumulated, IngestError> {
    let total = log::size_of(path, Stream::Imu);
    let label = format!("skin samples of {}", path.display());
    let mut acc = Accumulated {
        stills: vec![Vec::new(); seg.stills.len()],
        fits: vec![Vec::new(); seg.excitations.len()],
    };
    let mut last_stamp: Vec<f64> = Vec::new();
    let mut hint = 0usize;
    let mut route = 0usize;
    let n = timeline.len() as i64;
    let mut saturated: HashMap<usize, u64> = HashMap::new();
    let mut filled = 0u64;
    let stats = log::read_log(
        path,
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
            report.imu_samples += 1;
            let Some(su) = sus.find(frame_id, hint) else {
                *report
                    .unknown_frames
                    .entry(frame_id.to_string())
                    .or_default() += 1;
                return Ok(());
            };
            hint = su + 1;
            grow(&mut last_stamp, su + 1);
            if stamp < last_stamp[su] {
                report.unsorted_imu_stamps += 1;
            }
            last_stamp[su] = stamp;
            let m = timeline.index(stamp);
            if m < 0 || m >= n {
                report.imu_outside += 1;
                return Ok(());
            }
            let m = m as usize;
            // The window holding m: usually the current one or the next.
            let routes = &seg.routes;
            if !(route < routes.len() && routes[route].0 <= m && m < routes[route].1) {
                route = routes.partition_point(|r| r.0 <= m).saturating_sub(1);
            }
            let Some(&(start, end, is_still, w)) = routes.get(route) else {
                return Ok(());
            };
            if m < start || m >= end {
                return Ok(());
            }
            if acceleration.iter().any(|v| v.abs() >= config.saturation) {
                // Only samples the readings would use are counted: a saturated sample during a
                // transfer does not matter.
                *saturated.entry(su).or_default() += 1;
                return Ok(());
            }
            if is_still {
                let sums = &mut acc.stills[w];
                grow(sums, su + 1);
                let s = &mut sums[su];
                s.n += 1;
                for (k, a) in acceleration.iter().enumerate() {
                    s.sum[k] += a;
                    s.squares[k] += a * a;
                }
            } else {
                let x = &seg.excitations[w];
                let fits = &mut acc.fits[w];
                grow(fits, su + 1);
                let f = &mut fits[su];
                let local = m - start;
                match f.last {
                    Some((prev, _)) if prev == local => return Ok(()),
                    Some((prev, value)) if prev + 1 < local => {
                        // Missing samples: linear interpolation.
                        for j in prev + 1..local {
                            let u = (j - prev) as f64 / (local - prev) as f64;
                            let v = [0, 1, 2].map(|k| value[k] + (acceleration[k] - value[k]) * u);
                            f.add(x, j, v);
                            filled += 1;
                        }
                    }
                    None if local > 0 => {
                        for j in 0..local {
                            f.add(x, j, acceleration);
                            filled += 1;
                        }
                    }
                    _ => {}
                }
                f.add(x, local, acceleration);
                f.samples += 1;
                if f.last.is_none_or(|(prev, _)| local > prev) {
                    f.last = Some((local, acceleration));
                }
            }
            Ok(())
        },
        &mut |done| progress(&label, done, total),
    )?;
    // Missing samples at the end of excitation windows.
    for (w, fits) in acc.fits.iter_mut().enumerate() {
        let x = &seg.excitations[w];
        for f in fits.iter_mut() {
            if let Some((last, value)) = f.last {
                for j in last + 1..x.len() {
                    f.add(x, j, value);
                    filled += 1;
                }
            }
        }
    }
    report.filled = filled;
    for (su, count) in saturated {
        report.saturated.insert(sus.names[su].clone(), count);
    }
    report.imu_read = stats;
    Ok(acc)
}
