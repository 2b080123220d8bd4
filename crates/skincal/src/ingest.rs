//! From time-series logs to a measurement set.
//!
//! A log (MCAP or CSV, see [`crate::log`]) holds joint states and raw accelerometer samples of a
//! robot that followed the exploration protocol: still periods, and between them motions of one
//! DoF at a time (structure moves and windowed excitation patterns) or transfers of several DoFs.
//! Ingestion reads each log twice, streaming:
//!
//! 1. **Joint states → windows.** The joint positions are put on a uniform grid at the log's rate
//!    (linear interpolation; unsorted and duplicate stamps and gaps counted). A grid point is still
//!    when every DoF's speed, measured over ±`filter`, is below `still_velocity`; still runs longer
//!    than `min_still` are still windows (trimmed by `trim` at both ends). The motion between two
//!    still windows is classified by the DoFs that left their position by more than
//!    `motion_threshold`: none (ignored), one that comes back (an **excitation**), one that stays
//!    (a structure **move**), several (a **transfer**, skipped).
//! 2. **Samples → readings.** Every SU sample is routed to the window it falls in. A still window
//!    keeps the mean (the static reading). An excitation window keeps the least-squares normal
//!    equations of the exact single-DoF model
//!
//!    ```text
//!    s(t) = c + G_c (cos Δθ − 1) + G_s sin Δθ + k_α α(t) + k_ω ω(t)²
//!    ```
//!
//!    (gravity turned by the DoF's displacement Δθ, tangential and centripetal acceleration; the
//!    coefficients are constant in the SU frame because the axis is fixed in the moving segment), fit
//!    over the whole window. `α` is the DoF's *measured* angular acceleration, from the joint
//!    positions: a second difference over ±`filter` equals the measured acceleration filtered by a
//!    triangle, so the SU signal and the other regressors go through the same triangle and the fit
//!    stays exact — no smoothing bias, whatever the servo did (lag, other shape, negative
//!    direction). The **dynamic acceleration** stored is `k_α · 2πfA`: the SU's response to the
//!    nominal peak acceleration of a positive pattern, the measurement set's definition.
//!
//! Then still windows at one pose joined by excitations form a *station*: with excitations it is a
//! training pose (static reading pooled over its still windows, one dynamic acceleration per excited
//! DoF); without, a structure station. Structure stations joined by moves form one structure group
//! per base orientation: its rest pose is the pose it returns to most often, and every station that
//! differs from it in one DoF is a move of that DoF.
//!
//! Nothing is dropped silently: every skipped motion, unknown name, saturated or missing sample is
//! counted in the [`IngestReport`].

use std::collections::{BTreeMap, HashMap};
use std::path::{Path, PathBuf};

use nalgebra::{Matrix5, Vector5};
use serde::Serialize;
use serde_json::Map;

use crate::log::{self, LogError, LogFormat, ReadStats, Sample, Stream, Topics};
use crate::measurements::{
    MeasurementSet, Move, Orientation, Reading, StructureExperiment, TrainingExperiment,
    TrainingPose,
};
use crate::model::sensor::{ExcitationPattern, STANDARD_GRAVITY};

/// Errors of an ingestion.
#[derive(Debug, thiserror::Error)]
#[non_exhaustive]
pub enum IngestError {
    /// A log could not be read.
    #[error(transparent)]
    Log(#[from] LogError),
    /// A setting is out of range.
    #[error("{setting}: {reason}")]
    InvalidSetting {
        /// The option.
        setting: &'static str,
        /// What is allowed.
        reason: String,
    },
    /// A log cannot be used at all.
    #[error("{path}: {reason}")]
    Unusable {
        /// The log.
        path: PathBuf,
        /// Why, and what to do.
        reason: String,
    },
    /// Nothing usable was found in the logs.
    #[error("no measurements found {0}")]
    Empty(String),
}

/// Options of the ingestion.
#[derive(Debug, Clone, PartialEq)]
pub struct IngestConfig {
    /// MCAP topic names.
    pub topics: Topics,
    /// A DoF is still below this speed, rad/s.
    pub still_velocity: f64,
    /// A DoF has moved when it left its position by more than this, rad.
    pub motion_threshold: f64,
    /// Shortest still window, s.
    pub min_still: f64,
    /// Dropped at both ends of a still window, s.
    pub trim: f64,
    /// Half-width of the differentiation and of the triangle filter, s.
    pub filter: f64,
    /// Joint-state gaps longer than this make the motion they fall in unusable, s.
    pub max_gap: f64,
    /// An axis at or beyond this magnitude is saturated, m/s².
    pub saturation: f64,
    /// The nominal pattern (estimated from the joint motion when `None`).
    pub pattern: Option<ExcitationPattern>,
    /// The DoFs expected (in this order); others are reported as unknown. All seen when `None`.
    pub dofs: Option<Vec<String>>,
    /// The SUs expected (in this order); other frame ids are reported as unknown.
    pub sus: Option<Vec<String>>,
}

impl Default for IngestConfig {
    fn default() -> Self {
        Self {
            topics: Topics::default(),
            still_velocity: 0.01,
            motion_threshold: 0.002,
            min_still: 0.25,
            trim: 0.1,
            filter: 0.02,
            max_gap: 0.05,
            saturation: 2.0 * STANDARD_GRAVITY,
            pattern: None,
            dofs: None,
            sus: None,
        }
    }
}

impl IngestConfig {
    fn validate(&self) -> Result<(), IngestError> {
        for (setting, v) in [
            ("still_velocity", self.still_velocity),
            ("motion_threshold", self.motion_threshold),
            ("min_still", self.min_still),
            ("filter", self.filter),
            ("max_gap", self.max_gap),
            ("saturation", self.saturation),
        ] {
            if !(v.is_finite() && v > 0.0) {
                return Err(IngestError::InvalidSetting {
                    setting,
                    reason: format!("{v} must be a positive number"),
                });
            }
        }
        if !(self.trim.is_finite() && self.trim >= 0.0) {
            return Err(IngestError::InvalidSetting {
                setting: "trim",
                reason: format!("{} s must be zero or positive", self.trim),
            });
        }
        if let Some(p) = &self.pattern {
            if !p.is_valid() {
                return Err(IngestError::InvalidSetting {
                    setting: "pattern",
                    reason: "amplitude and frequency must be positive".into(),
                });
            }
        }
        Ok(())
    }
}

/// What happened to one log.
#[derive(Debug, Clone, Default, PartialEq, Serialize)]
pub struct LogReport {
    /// The log.
    pub path: PathBuf,
    /// `mcap` or `csv`.
    pub format: String,
    /// From the first to the last joint state, s.
    pub duration: f64,
    /// Rate of the joint states, Hz.
    pub rate: f64,
    /// Joint-state messages (or rows) read.
    pub joint_states: u64,
    /// Accelerometer samples read.
    pub imu_samples: u64,
    /// Joint stamps earlier than the one before (sorted before use).
    pub unsorted_joint_stamps: u64,
    /// Joint samples with a stamp already seen (the later one dropped).
    pub duplicate_joint_stamps: u64,
    /// Gaps in the joint states longer than `max_gap`.
    pub joint_gaps: u64,
    /// Longest gap in the joint states, s.
    pub longest_joint_gap: f64,
    /// Joint names not expected, with their sample counts.
    pub unknown_joints: BTreeMap<String, u64>,
    /// Frame ids not expected, with their sample counts.
    pub unknown_frames: BTreeMap<String, u64>,
    /// SU samples earlier than the previous one of the same SU.
    pub unsorted_imu_stamps: u64,
    /// SU samples outside the time covered by the joint states.
    pub imu_outside: u64,
    /// Saturated SU samples inside still and excitation windows (not used), by SU.
    pub saturated: BTreeMap<String, u64>,
    /// Missing SU samples inside excitation windows, filled by linear interpolation.
    pub filled: u64,
    /// Still windows found.
    pub still_windows: usize,
    /// Single-DoF excitations found.
    pub excitations: usize,
    /// Single-DoF structure moves found.
    pub moves: usize,
    /// Motions of several DoFs (transfers), skipped.
    pub transfers: usize,
    /// Motions that could not be used, with the reason.
    pub skipped: Vec<String>,
    /// Joint-state decoding problems.
    pub joint_read: ReadStats,
    /// Skin decoding problems.
    pub imu_read: ReadStats,
}

/// What the ingestion found and did.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct IngestReport {
    /// Per log.
    pub logs: Vec<LogReport>,
    /// The nominal pattern the dynamic accelerations are scaled to.
    pub pattern: ExcitationPattern,
    /// `given` or `estimated from N excitations`.
    pub pattern_source: String,
    /// Structure groups (base orientations) in the measurement set.
    pub orientations: usize,
    /// Training poses in the measurement set.
    pub training_poses: usize,
    /// Dynamic accelerations (pose × DoF) in the measurement set.
    pub dynamic: usize,
    /// RMS of the SU samples about their mean in still windows, m/s² (the sensor noise).
    pub sample_noise: Option<f64>,
    /// Problems that affect the result, in words.
    pub warnings: Vec<String>,
}

/// The result: a measurement set and the report.
#[derive(Debug, Clone)]
pub struct Ingested {
    /// The measurement set.
    pub measurements: MeasurementSet,
    /// What was found.
    pub report: IngestReport,
}

/// Progress of an ingestion: `(what, done, total)` in bytes of the pass.
pub type Progress<'a> = dyn FnMut(&str, u64, u64) + 'a;

/// Reads `logs` and extracts the measurement set.
pub fn ingest(
    logs: &[PathBuf],
    config: &IngestConfig,
    progress: &mut Progress<'_>,
) -> Result<Ingested, IngestError> {
    ingest_logs(logs, config, progress).map_err(|e| match e {
        IngestError::Empty(reason) if !logs.is_empty() => IngestError::Empty(format!(
            "in {}: {reason}",
            logs.iter()
                .map(|l| l.display().to_string())
                .collect::<Vec<_>>()
                .join(", ")
        )),
        other => other,
    })
}

fn ingest_logs(
    logs: &[PathBuf],
    config: &IngestConfig,
    progress: &mut Progress<'_>,
) -> Result<Ingested, IngestError> {
    config.validate()?;
    if logs.is_empty() {
        return Err(IngestError::Empty(": no log given".into()));
    }
    let mut timelines = Vec::new();
    let mut reports = Vec::new();
    let mut dof_names: Option<Vec<String>> = config.dofs.clone();
    for path in logs {
        let mut report = LogReport {
            path: path.clone(),
            format: match log::format_of(path)? {
                LogFormat::Mcap => "mcap".into(),
                LogFormat::Csv => "csv".into(),
                LogFormat::Db3 => "rosbag2 sqlite3".into(),
                LogFormat::Rosbag2(files) => format!("rosbag2 ({} files)", files.len()),
            },
            ..LogReport::default()
        };
        let timeline = read_joints(path, config, &mut dof_names, &mut report, progress)?;
        timelines.push(timeline);
        reports.push(report);
    }
    let dofs = dof_names.unwrap_or_default();

    // Pass 1 results: windows of every log.
    let mut plans = Vec::new();
    for (timeline, report) in timelines.iter().zip(&mut reports) {
        plans.push(segment(timeline, config, report));
    }

    let (pattern, pattern_source) = match config.pattern {
        Some(p) => (p, "given".to_string()),
        None => {
            let excitations: usize = plans.iter().map(|p| p.excitations.len()).sum();
            match estimate_pattern(&plans) {
                Some(found) => found,
                // A structure-only log: no training pose will need the pattern.
                None if excitations == 0 => (
                    ExcitationPattern::default(),
                    "none needed: the logs hold no excitation".to_string(),
                ),
                None => {
                    return Err(IngestError::Empty(format!(
                        "the {excitations} excitations found give no usable pattern (peak speed \
                         and acceleration out of range): give the nominal one with --plan or \
                         --pattern A,f"
                    )))
                }
            }
        }
    };

    // Pass 2: the skin samples.
    let mut sus = SuRegistry::new(config.sus.clone());
    let mut accumulators = Vec::new();
    for ((path, timeline), (plan, report)) in logs
        .iter()
        .zip(&timelines)
        .zip(plans.iter().zip(&mut reports))
    {
        accumulators.push(read_skin(
            path, timeline, plan, config, &mut sus, report, progress,
        )?);
    }

    assemble(
        config,
        &dofs,
        &sus,
        &timelines,
        &plans,
        &accumulators,
        pattern,
        pattern_source,
        reports,
    )
}

/// Slowest joint-state rate that can resolve an excitation pattern, Hz.
const MIN_JOINT_RATE: f64 = 20.0;
/// Longest pause without joint states inside one log, s.
const MAX_PAUSE: f64 = 600.0;

/// Joint positions of one log on a uniform grid.
#[derive(Debug, Clone)]
struct Timeline {
    t0: f64,
    dt: f64,
    /// Positions per DoF (in the order of the common DoF list), one per grid point.
    theta: Vec<Vec<f64>>,
    /// Grid points inside a joint-state gap.
    invalid: Vec<bool>,
}

impl Timeline {
    fn len(&self) -> usize {
        self.invalid.len()
    }

    fn index(&self, stamp: f64) -> i64 {
        ((stamp - self.t0) / self.dt).round() as i64
    }

    fn time(&self, n: usize) -> f64 {
        n as f64 * self.dt
    }
}

fn read_joints(
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
    })
}

/// A still window: grid range `[start, end)` and the mean pose.
#[derive(Debug, Clone)]
struct StillWindow {
    start: usize,
    end: usize,
    pose: Vec<f64>,
}

/// An excitation window and its least-squares design.
#[derive(Debug, Clone)]
struct Excitation {
    dof: usize,
    start: usize,
    end: usize,
    /// `W(m)`: the weight of the sample at grid point `start + m` in each of the five normal
    /// equations (the regressors filtered twice by the triangle).
    weights: Vec<[f64; 5]>,
    /// `G⁻¹`, the inverse of the normal matrix.
    inverse: Matrix5<f64>,
    /// Peak measured |ω| and |α| (for estimating the nominal pattern).
    peak_velocity: f64,
    peak_acceleration: f64,
}

#[derive(Debug, Clone)]
enum Event {
    Still(usize),
    Excitation(usize),
    Move,
    Transfer,
    Broken,
}

/// The windows of one log.
#[derive(Debug, Clone, Default)]
struct Segmentation {
    stills: Vec<StillWindow>,
    excitations: Vec<Excitation>,
    events: Vec<Event>,
    /// Every window's `(start, end, still?, index)`, sorted by start, for routing samples.
    routes: Vec<(usize, usize, bool, usize)>,
}

/// The weights of the triangle of half-width `l` samples: `(l − |k|)/l²`, `|k| < l`.
fn triangle(l: usize) -> Vec<f64> {
    let l2 = (l * l) as f64;
    (0..2 * l - 1)
        .map(|i| (l as f64 - (i as f64 - (l as f64 - 1.0)).abs()) / l2)
        .collect()
}

/// `x` filtered by `kernel` (odd length, centred) at `n`, with `x` taken as zero outside.
fn filtered(x: &[f64], kernel: &[f64], n: usize) -> f64 {
    let half = kernel.len() / 2;
    let mut s = 0.0;
    for (k, w) in kernel.iter().enumerate() {
        let i = n + k;
        if i >= half && i - half < x.len() {
            s += w * x[i - half];
        }
    }
    s
}

fn segment(timeline: &Timeline, config: &IngestConfig, report: &mut LogReport) -> Segmentation {
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

/// The least-squares design of an excitation of DoF `d` over grid `[start, end)`.
fn design(timeline: &Timeline, d: usize, start: usize, end: usize, l: usize) -> Option<Excitation> {
    let th = &timeline.theta[d][start..end];
    let len = th.len();
    if len < 4 * l + 4 {
        return None;
    }
    let dt = timeline.dt;
    let kernel = triangle(l);
    let base = th[0];
    let cos: Vec<f64> = th.iter().map(|q| (q - base).cos() - 1.0).collect();
    let sin: Vec<f64> = th.iter().map(|q| (q - base).sin()).collect();
    let omega2: Vec<f64> = (0..len)
        .map(|i| {
            let (a, b) = (th[i.saturating_sub(1)], th[(i + 1).min(len - 1)]);
            let w = (b - a) / (((i + 1).min(len - 1) - i.saturating_sub(1)) as f64 * dt);
            w * w
        })
        .collect();
    // Regressors at the valid points n ∈ [l, len − l): filtered by the triangle; the measured
    // acceleration is the long second difference (= triangle-filtered discrete acceleration).
    let span = (l as f64 * dt).powi(2);
    let mut rows: Vec<(usize, [f64; 5])> = Vec::with_capacity(len);
    let (mut peak_velocity, mut peak_acceleration) = (0.0f64, 0.0f64);
    for i in l..len - l {
        let alpha = (th[i + l] - 2.0 * th[i] + th[i - l]) / span;
        let omega = (th[i + l] - th[i - l]) / (2.0 * l as f64 * dt);
        peak_velocity = peak_velocity.max(omega.abs());
        peak_acceleration = peak_acceleration.max(alpha.abs());
        rows.push((
            i,
            [
                1.0,
                filtered(&cos, &kernel, i),
                filtered(&sin, &kernel, i),
                alpha,
                filtered(&omega2, &kernel, i),
            ],
        ));
    }
    let mut g = Matrix5::zeros();
    for (_, x) in &rows {
        let v = Vector5::from(*x);
        g += v * v.transpose();
    }
    // Scale the columns for a well-conditioned inverse.
    let scale = Vector5::from_fn(|i, _| 1.0 / g[(i, i)].max(1e-300).sqrt());
    let gs = Matrix5::from_fn(|i, j| g[(i, j)] * scale[i] * scale[j]);
    let inverse_scaled = gs.cholesky()?.inverse();
    let inverse = Matrix5::from_fn(|i, j| inverse_scaled[(i, j)] * scale[i] * scale[j]);
    if inverse[(3, 3)] * g[(3, 3)] > 1e4 || peak_acceleration == 0.0 {
        // α is (nearly) a combination of the other regressors: nothing to fit against.
        return None;
    }
    // W(m) = Σ_n X(n) w(n − m): the adjoint of the triangle applied to the regressors.
    let half = kernel.len() / 2;
    let mut weights = vec![[0.0; 5]; len];
    for (i, x) in &rows {
        for (k, w) in kernel.iter().enumerate() {
            let m = i + k - half;
            for (c, xc) in x.iter().enumerate() {
                weights[m][c] += w * xc;
            }
        }
    }
    Some(Excitation {
        dof: d,
        start,
        end,
        weights,
        inverse,
        peak_velocity,
        peak_acceleration,
    })
}

/// The nominal pattern from the measured motion of every excitation: the median peak speed is `A`,
/// the median peak acceleration `2πfA`.
fn estimate_pattern(plans: &[Segmentation]) -> Option<(ExcitationPattern, String)> {
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

/// Names of the SUs and their indices.
struct SuRegistry {
    names: Vec<String>,
    index: HashMap<String, usize>,
    fixed: bool,
}

impl SuRegistry {
    fn new(known: Option<Vec<String>>) -> Self {
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
    fn find(&mut self, name: &str, hint: usize) -> Option<usize> {
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
struct StillSum {
    n: u64,
    sum: [f64; 3],
    squares: [f64; 3],
}

/// Per SU, the right-hand sides of an excitation's normal equations and the last sample seen.
#[derive(Debug, Clone, Copy, Default)]
struct FitSum {
    rhs: [[f64; 3]; 5],
    last: Option<(usize, [f64; 3])>,
    samples: u64,
}

impl FitSum {
    fn add(&mut self, weights: &[[f64; 5]], m: usize, a: [f64; 3]) {
        let w = &weights[m];
        for (c, wc) in w.iter().enumerate() {
            for (axis, v) in a.iter().enumerate() {
                self.rhs[c][axis] += wc * v;
            }
        }
    }
}

/// The accumulated samples of one log.
#[derive(Debug, Clone, Default)]
struct Accumulated {
    stills: Vec<Vec<StillSum>>,
    fits: Vec<Vec<FitSum>>,
}

fn grow<T: Default + Clone>(v: &mut Vec<T>, len: usize) {
    if v.len() < len {
        v.resize(len, T::default());
    }
}

fn read_skin(
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
                            f.add(&x.weights, j, v);
                            filled += 1;
                        }
                    }
                    None if local > 0 => {
                        for j in 0..local {
                            f.add(&x.weights, j, acceleration);
                            filled += 1;
                        }
                    }
                    _ => {}
                }
                f.add(&x.weights, local, acceleration);
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
        let len = seg.excitations[w].weights.len();
        for f in fits.iter_mut() {
            if let Some((last, value)) = f.last {
                for j in last + 1..len {
                    f.add(&seg.excitations[w].weights, j, value);
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

/// A station: still windows at one pose, joined by excitations.
struct Station {
    log: usize,
    stills: Vec<usize>,
    excitations: Vec<usize>,
    pose: Vec<f64>,
    /// Index of the structure group (only for stations without excitations).
    group: Option<usize>,
}

#[allow(clippy::too_many_arguments)]
fn assemble(
    config: &IngestConfig,
    dofs: &[String],
    sus: &SuRegistry,
    timelines: &[Timeline],
    segs: &[Segmentation],
    accumulated: &[Accumulated],
    pattern: ExcitationPattern,
    pattern_source: String,
    reports: Vec<LogReport>,
) -> Result<Ingested, IngestError> {
    let nu = sus.names.len();
    let tolerance = config.motion_threshold;
    let mut warnings = Vec::new();
    if nu == 0 {
        return Err(IngestError::Empty(
            "no skin samples (check the topic with --imu-topic and the frame ids)".into(),
        ));
    }
    // Stations and structure groups.
    let mut stations: Vec<Station> = Vec::new();
    let mut group_count = 0usize;
    for (li, seg) in segs.iter().enumerate() {
        let mut current: Option<usize> = None;
        let mut group: Option<usize> = None;
        for event in &seg.events {
            match event {
                Event::Still(s) => {
                    let pose = &seg.stills[*s].pose;
                    let same = current.is_some_and(|c| {
                        stations[c]
                            .pose
                            .iter()
                            .zip(pose)
                            .all(|(a, b)| (a - b).abs() < tolerance)
                    });
                    if same {
                        stations[current.expect("checked")].stills.push(*s);
                    } else {
                        stations.push(Station {
                            log: li,
                            stills: vec![*s],
                            excitations: Vec::new(),
                            pose: pose.clone(),
                            group: None,
                        });
                        current = Some(stations.len() - 1);
                        if group.is_none() {
                            group = Some(group_count);
                            group_count += 1;
                        }
                        stations.last_mut().expect("pushed").group = group;
                    }
                }
                Event::Excitation(x) => {
                    if let Some(c) = current {
                        stations[c].excitations.push(*x);
                    }
                }
                Event::Move => current = None,
                Event::Transfer | Event::Broken => {
                    current = None;
                    group = None;
                }
            }
        }
    }
    // Readings of a station, pooled over its still windows; None if an SU has no sample.
    let still_reading = |st: &Station| -> Result<Vec<Reading>, String> {
        let acc = &accumulated[st.log];
        (0..nu)
            .map(|su| {
                let mut n = 0u64;
                let mut sum = [0.0; 3];
                for &w in &st.stills {
                    if let Some(s) = acc.stills[w].get(su) {
                        n += s.n;
                        for (total, v) in sum.iter_mut().zip(&s.sum) {
                            *total += v;
                        }
                    }
                }
                if n == 0 {
                    Err(sus.names[su].clone())
                } else {
                    Ok(sum.map(|v| v / n as f64))
                }
            })
            .collect()
    };
    let at = |st: &Station| -> f64 {
        let w = &segs[st.log].stills[st.stills[0]];
        timelines[st.log].time(w.start)
    };

    // Training poses.
    let alpha = pattern.peak_acceleration();
    let mut poses = Vec::new();
    let mut dynamic_count = 0;
    for st in stations.iter().filter(|s| !s.excitations.is_empty()) {
        let static_readings = match still_reading(st) {
            Ok(r) => r,
            Err(su) => {
                warnings.push(format!(
                    "{}: training pose at {:.3} s skipped: SU `{su}` has no sample in its still \
                     windows",
                    reports[st.log].path.display(),
                    at(st)
                ));
                continue;
            }
        };
        let mut dynamic: BTreeMap<String, Vec<Reading>> = BTreeMap::new();
        let mut counts: BTreeMap<usize, usize> = BTreeMap::new();
        for &xi in &st.excitations {
            let x = &segs[st.log].excitations[xi];
            let fits = &accumulated[st.log].fits[xi];
            let mut readings = Vec::with_capacity(nu);
            let mut missing = None;
            for su in 0..nu {
                match fits.get(su).filter(|f| f.samples > 0) {
                    Some(f) => {
                        let mut k = [0.0; 3];
                        for (axis, kv) in k.iter_mut().enumerate() {
                            let rhs = Vector5::from_fn(|c, _| f.rhs[c][axis]);
                            *kv = (x.inverse * rhs)[3] * alpha;
                        }
                        readings.push(k);
                    }
                    None => {
                        missing = Some(su);
                        break;
                    }
                }
            }
            if let Some(su) = missing {
                warnings.push(format!(
                    "{}: excitation of `{}` at {:.3} s skipped: SU `{}` has no sample in it",
                    reports[st.log].path.display(),
                    dofs[x.dof],
                    timelines[st.log].time(x.start),
                    sus.names[su]
                ));
                continue;
            }
            let name = dofs[x.dof].clone();
            let count = counts.entry(x.dof).or_default();
            *count += 1;
            match dynamic.get_mut(&name) {
                // Repeated excitations of a DoF at one pose: running mean.
                Some(prev) => {
                    let c = *count as f64;
                    for (p, r) in prev.iter_mut().zip(&readings) {
                        for k in 0..3 {
                            p[k] += (r[k] - p[k]) / c;
                        }
                    }
                }
                None => {
                    dynamic.insert(name, readings);
                }
            }
        }
        if dynamic.is_empty() {
            continue;
        }
        let missing: Vec<&String> = dofs.iter().filter(|d| !dynamic.contains_key(*d)).collect();
        if !missing.is_empty() {
            warnings.push(format!(
                "{}: training pose at {:.3} s has no excitation of {missing:?}",
                reports[st.log].path.display(),
                at(st)
            ));
        }
        dynamic_count += dynamic.len();
        poses.push(TrainingPose {
            q: st.pose.clone(),
            static_readings,
            dynamic,
            extra: Map::new(),
        });
    }

    let found = stations
        .iter()
        .filter(|s| !s.excitations.is_empty())
        .count();
    if found > 0 && poses.is_empty() {
        return Err(IngestError::Empty(format!(
            "all {found} training poses found in the joint states were skipped, so the result \
             would have none; the first reason: {}",
            warnings.first().map_or("unknown", String::as_str)
        )));
    }

    // Structure groups.
    let mut orientations = Vec::new();
    for g in 0..group_count {
        let members: Vec<&Station> = stations
            .iter()
            .filter(|s| s.group == Some(g) && s.excitations.is_empty())
            .collect();
        if members.len() < 2 {
            continue;
        }
        let path = reports[members[0].log].path.display().to_string();
        let close = |a: &[f64], b: &[f64]| a.iter().zip(b).all(|(x, y)| (x - y).abs() < tolerance);
        // The rest pose: the one most stations share (the first of the most frequent).
        let (rest_index, _) = members
            .iter()
            .enumerate()
            .map(|(i, s)| {
                (
                    i,
                    members.iter().filter(|o| close(&o.pose, &s.pose)).count(),
                )
            })
            .fold(
                (0, 0),
                |best, (i, c)| if c > best.1 { (i, c) } else { best },
            );
        let rest_pose = members[rest_index].pose.clone();
        let mut rest_sum = vec![[0.0; 3]; nu];
        let mut rest_n = 0usize;
        let mut moves = Vec::new();
        for st in &members {
            let readings = match still_reading(st) {
                Ok(r) => r,
                Err(su) => {
                    warnings.push(format!(
                        "{path}: structure pose at {:.3} s skipped: SU `{su}` has no sample in it",
                        at(st)
                    ));
                    continue;
                }
            };
            let differs: Vec<usize> = (0..dofs.len())
                .filter(|&d| (st.pose[d] - rest_pose[d]).abs() >= tolerance)
                .collect();
            match differs.as_slice() {
                [] => {
                    rest_n += 1;
                    for (s, r) in rest_sum.iter_mut().zip(&readings) {
                        for k in 0..3 {
                            s[k] += r[k];
                        }
                    }
                }
                [d] => moves.push(Move {
                    dof: dofs[*d].clone(),
                    pose: st.pose.clone(),
                    readings,
                    extra: Map::new(),
                }),
                several => warnings.push(format!(
                    "{path}: structure pose at {:.3} s differs from the rest pose in {} DoFs; \
                     skipped",
                    at(st),
                    several.len()
                )),
            }
        }
        if rest_n == 0 || moves.is_empty() {
            continue;
        }
        let mut extra = Map::new();
        extra.insert(
            "source".into(),
            serde_json::Value::String(format!("{path} from {:.3} s", at(members[0]))),
        );
        orientations.push(Orientation {
            rest_pose,
            rest: rest_sum
                .iter()
                .map(|s| s.map(|v| v / rest_n as f64))
                .collect(),
            moves,
            extra,
        });
    }

    if group_count > 0 && orientations.is_empty() && poses.is_empty() {
        return Err(IngestError::Empty(format!(
            "every structure pose found in the joint states was skipped; the first reason: {}",
            warnings.first().map_or("unknown", String::as_str)
        )));
    }
    let mut set = MeasurementSet::new(dofs.to_vec(), sus.names.clone());
    if !orientations.is_empty() {
        set.structure = Some(StructureExperiment {
            orientations,
            extra: Map::new(),
        });
    }
    let training_poses = poses.len();
    if !poses.is_empty() {
        set.training = Some(TrainingExperiment {
            pattern,
            poses,
            extra: Map::new(),
        });
    }
    if set.structure.is_none() && set.training.is_none() {
        return Err(IngestError::Empty(
            "no structure moves and no training poses in the logs: do they follow the protocol \
             (still periods, one DoF moving at a time)? The thresholds are options."
                .into(),
        ));
    }
    // Sensor noise from the still windows.
    let (mut var, mut dof) = (0.0, 0.0);
    for acc in accumulated {
        for w in &acc.stills {
            for s in w.iter().filter(|s| s.n > 1) {
                for k in 0..3 {
                    let n = s.n as f64;
                    var += (s.squares[k] - s.sum[k] * s.sum[k] / n).max(0.0);
                    dof += n - 1.0;
                }
            }
        }
    }
    let sample_noise = (dof > 0.0).then(|| (var / dof).sqrt());
    for r in &reports {
        if !r.unknown_frames.is_empty() {
            warnings.push(format!(
                "{}: samples of unknown frame ids ignored: {:?}",
                r.path.display(),
                r.unknown_frames
            ));
        }
        if !r.saturated.is_empty() {
            warnings.push(format!(
                "{}: saturated samples (±{:.2} m/s²) not used: {:?}",
                r.path.display(),
                config.saturation,
                r.saturated
            ));
        }
    }
    let report = IngestReport {
        orientations: set.structure.as_ref().map_or(0, |s| s.orientations.len()),
        training_poses,
        dynamic: dynamic_count,
        logs: reports,
        pattern,
        pattern_source,
        sample_noise,
        warnings,
    };
    Ok(Ingested {
        measurements: set,
        report,
    })
}
