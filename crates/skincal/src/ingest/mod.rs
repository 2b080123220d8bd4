//! From time-series logs to a measurement set.
//!
//! A log (MCAP or CSV, see [`crate::log`]) holds joint states and raw accelerometer samples of a
//! robot that followed the exploration protocol: still periods, and between them motions of one
//! DoF at a time (structure moves and windowed excitation patterns) or transfers of several DoFs.
//! Ingestion reads each log once, streaming (`pass`: the skin samples wait until the window they
//! fall in is known; a log that breaks what this relies on is read twice, the joint states first):
//!
//! 1. **Joint states → windows.** The joint positions are put on a uniform grid at the log's rate
//!    (its period fitted to the first second's stamps; linear interpolation; unsorted and duplicate
//!    stamps and gaps counted). A grid point is still
//!    when every DoF's speed, measured over ±`filter`, is below `still_velocity`; still runs longer
//!    than `min_still` are still windows (trimmed by `trim` at both ends), and a pause with none is
//!    read where its DoFs crept least (a servo that settles slower than the hold). The motion
//!    between two still windows is classified by the DoFs that left their position by more than
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

mod assemble;
mod base;
mod blocks;
mod fit;
pub mod motion;
pub mod moves;
mod pass;
mod queue;
mod segment;
mod skin;
pub mod stream;
mod timeline;
mod window;

use std::collections::BTreeMap;
use std::path::{Path, PathBuf};

use serde::{Deserialize, Serialize};

use crate::log::{LogError, LogSource, ReadStats, Topics};
use crate::measurements::{ApparentUnit, MeasurementError, MeasurementSet};
use crate::model::sensor::{ExcitationPattern, STANDARD_GRAVITY};
use assemble::{assemble, Passes};
use pass::{one_pass, LogPass};
use segment::{estimate_pattern, segment};
use skin::{leave_out_silent, read_skin, SuRegistry};
use timeline::read_joints;

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
    /// The skin's samples are not in m/s².
    #[error("{0}")]
    SkinUnit(String),
    /// The measurement set assembled from the logs breaks a rule of its format (nothing is
    /// written).
    #[error("{0}")]
    Invalid(String),
}

/// The share of the range below it that an accelerometer's highest code may sit: one step of a
/// converter of 9 bits or more over its range.
pub const TOP_CODE: f64 = 1.0 / 256.0;

/// Options of the ingestion.
#[derive(Debug, Clone, PartialEq)]
pub struct IngestConfig {
    /// MCAP topic names.
    pub topics: Topics,
    /// A DoF is still below this speed, rad/s (still windows give the static readings; for a
    /// prismatic DoF, [`IngestConfig::speed_scale`] of it in m/s).
    pub still_velocity: f64,
    /// Between two motions every DoF is slower than this, rad/s: a pause, which may ring (scaled
    /// as `still_velocity` for a prismatic DoF).
    pub quiet_velocity: f64,
    /// Shortest pause that separates two motions, s.
    pub min_pause: f64,
    /// A DoF has moved when it left its position by more than this, rad.
    pub motion_threshold: f64,
    /// A DoF that moved less than this fraction of the DoF that moved most only followed it
    /// (servo compliance): it is a regressor of the fit, not a second excited DoF.
    pub coupled_fraction: f64,
    /// Shortest still window, s.
    pub min_still: f64,
    /// Dropped at both ends of a still window, s.
    pub trim: f64,
    /// Half-width of the differentiation and of the triangle filter, s.
    pub filter: f64,
    /// Joint-state gaps longer than this make the motion they fall in unusable, s.
    pub max_gap: f64,
    /// An axis at or beyond this magnitude (the accelerometer's range) is saturated, m/s²; so is
    /// one within [`TOP_CODE`] of it (see [`IngestConfig::saturated`]).
    pub saturation: f64,
    /// Every skin sample is multiplied by this: 1 for m/s² (what `sensor_msgs/Imu` carries),
    /// [`STANDARD_GRAVITY`] for a driver that publishes g.
    pub skin_scale: f64,
    /// The nominal pattern (estimated from the joint motion when `None`).
    pub pattern: Option<ExcitationPattern>,
    /// The DoFs expected (in this order); others are reported as unknown. All seen when `None`.
    pub dofs: Option<Vec<String>>,
    /// The SUs expected (in this order); other frame ids are reported as unknown.
    pub sus: Option<Vec<String>>,
    /// The DoFs that are prismatic (from the robot's description or the plan): the measurement
    /// set says so, so that their positions are read in m and their patterns as scaled. `None`
    /// where no description says: each DoF's kind is then told from what its structure moves
    /// did to the skin ([`moves::kinds_of_moves`], by [`motion::record_of`]).
    pub prismatic: Option<Vec<String>>,
    /// The DoFs that are mimic joints, with the DoF each follows (from the robot's description or
    /// the plan): they move only with their leaders, so a leader's motion is told by the leader
    /// alone, and the measurement set says so.
    pub mimic: std::collections::BTreeMap<String, crate::model::MimicSpec>,
    /// How the structure part's tree is found where ingest needs it (to tell which DoF of
    /// several excited together moved an SU): the settings `explore` will be run with.
    pub explore: crate::explore::ExploreConfig,
    /// The tree that tells which DoF of several excited together moved an SU (`skincal ingest
    /// --structure`: an earlier structure experiment's); `None`: the one explored from the
    /// structure part's static readings. A DoF that turns no gravity (a vertical axis in a log of
    /// one base orientation, a slide) moves no SU by those: [`motion::record_of`] reads the logs
    /// again with the tree their structure moves' accelerations give where it differs.
    pub tree: Option<crate::explore::Structure>,
}

impl IngestConfig {
    /// Whether a skin sample (m/s², scaled) reached the accelerometer's range on an axis: at
    /// least `saturation` less [`TOP_CODE`] of it. A two's-complement converter's highest code is
    /// one step below its range (a 10-bit one over ±2 g tops at +19.575 m/s² and −19.613): the
    /// positive rail would otherwise pass for a reading.
    pub fn saturated(&self, a: &[f64; 3]) -> bool {
        a.iter()
            .any(|v| v.abs() >= self.saturation * (1.0 - TOP_CODE))
    }

    /// The factor on the speed thresholds (`still_velocity`, `quiet_velocity`) for DoF `dof`:
    /// [`crate::model::PRISMATIC_PATTERN_SCALE`] for one the configuration names prismatic (its
    /// pattern runs that many m per rad, so that a slide's pattern, a tenth of a turn's speed, is
    /// not taken for a pause), else 1.
    pub fn speed_scale(&self, dof: &str) -> f64 {
        if self
            .prismatic
            .as_ref()
            .is_some_and(|p| p.iter().any(|d| d == dof))
        {
            crate::model::PRISMATIC_PATTERN_SCALE
        } else {
            1.0
        }
    }

    /// The configuration for the logs of `plan`'s program: its pattern, still windows that fit its
    /// still periods ([`IngestConfig::for_still_periods`]), and, where no description named them
    /// already, its DoFs' kinds and mimic joints.
    pub fn with_plan(mut self, plan: &crate::plan::Plan) -> Self {
        self.pattern = Some(plan.pattern);
        if self.prismatic.is_none() {
            self.prismatic = Some(plan.prismatic_dof_names());
            self.mimic = plan.mimic_specs();
        }
        self.for_still_periods(plan.config.still)
    }

    /// The still-window lengths made to fit still periods of `still` seconds (a plan's): the
    /// trim shrinks to a tenth of the period and the shortest window to 0.3 of it, where the
    /// defaults would not fit. Longer periods keep the defaults.
    pub fn for_still_periods(mut self, still: f64) -> Self {
        if still.is_finite() && still > 0.0 {
            self.trim = self.trim.min(0.1 * still);
            self.min_still = self.min_still.min(0.3 * still);
        }
        self
    }
}

impl Default for IngestConfig {
    fn default() -> Self {
        Self {
            topics: Topics::default(),
            still_velocity: 0.01,
            quiet_velocity: 0.05,
            min_pause: 0.1,
            motion_threshold: 0.002,
            coupled_fraction: 0.3,
            min_still: 0.15,
            trim: 0.05,
            filter: 0.05,
            max_gap: 0.05,
            saturation: 2.0 * STANDARD_GRAVITY,
            skin_scale: 1.0,
            pattern: None,
            dofs: None,
            sus: None,
            prismatic: None,
            mimic: std::collections::BTreeMap::new(),
            explore: crate::explore::ExploreConfig::default(),
            tree: None,
        }
    }
}

impl IngestConfig {
    fn validate(&self) -> Result<(), IngestError> {
        for (setting, v) in [
            ("still_velocity", self.still_velocity),
            ("quiet_velocity", self.quiet_velocity),
            ("min_pause", self.min_pause),
            ("motion_threshold", self.motion_threshold),
            ("min_still", self.min_still),
            ("filter", self.filter),
            ("max_gap", self.max_gap),
            ("saturation", self.saturation),
            ("skin_scale", self.skin_scale),
            ("explore.threshold", self.explore.threshold),
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
        if self.quiet_velocity < self.still_velocity {
            return Err(IngestError::InvalidSetting {
                setting: "quiet_velocity",
                reason: format!(
                    "{} rad/s must be at least still_velocity ({} rad/s)",
                    self.quiet_velocity, self.still_velocity
                ),
            });
        }
        if !(self.coupled_fraction > 0.0 && self.coupled_fraction < 1.0) {
            return Err(IngestError::InvalidSetting {
                setting: "coupled_fraction",
                reason: format!("{} must lie between 0 and 1", self.coupled_fraction),
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

/// An SU whose samples mostly repeat the one before (see [`LogReport::repeated`]).
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct Repeated {
    /// The share of its samples that repeat the one before exactly.
    pub share: f64,
    /// Its fresh samples per second, Hz: the board's own rate.
    pub fresh_rate: f64,
}

/// What happened to one log.
#[derive(Debug, Clone, Default, PartialEq, Serialize, Deserialize)]
#[serde(default)]
pub struct LogReport {
    /// The log.
    pub path: PathBuf,
    /// `mcap` or `csv`.
    pub format: String,
    /// Passes over the log: 1, or 2 where it breaks what a single pass relies on (joint stamps
    /// out of order, a DoF first seen late, a motion too long to hold its skin samples).
    pub passes: u8,
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
    /// The robot's DoFs (the expected ones) that this log has no joint states for: a log of one
    /// part of the robot (a per-part port, a controller's own topic). The measurement set covers
    /// the DoFs the logs have.
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub unrecorded_joints: Vec<String>,
    /// Frame ids not expected, with their sample counts.
    pub unknown_frames: BTreeMap<String, u64>,
    /// SU samples earlier than the previous one of the same SU.
    pub unsorted_imu_stamps: u64,
    /// SU samples outside the time covered by the joint states.
    pub imu_outside: u64,
    /// The first joint state's stamp, s (the log's clock, often since the epoch).
    pub joint_start: f64,
    /// The earliest and the latest stamp of the samples of known SUs, s (the log's clock).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub imu_span: Option<[f64; 2]>,
    /// Saturated SU samples inside still and excitation windows (not used), by SU.
    pub saturated: BTreeMap<String, u64>,
    /// SUs whose samples mostly repeat the one before exactly, with how many do: a board slower
    /// than the port that sends for it, which repeats its last sample (a working accelerometer's
    /// noise makes two samples alike now and then, not most of the time). A board that never
    /// changes is not here: it is dead or frozen, which `explore` names.
    #[serde(default, skip_serializing_if = "BTreeMap::is_empty")]
    pub repeated: BTreeMap<String, Repeated>,
    /// Missing SU samples inside excitation windows, filled by linear interpolation.
    pub filled: u64,
    /// Still windows found (each gives a static reading).
    pub still_windows: usize,
    /// Poses (structure and training) read from still windows in which the DoFs still crept,
    /// never below `still_velocity` for long enough: the servos settle slower than the program
    /// holds.
    #[serde(default, skip_serializing_if = "crate::measurements::is_zero")]
    pub creeping: usize,
    /// Pauses between motions too short or too restless for a static reading.
    pub pauses: usize,
    /// Single-DoF excitations found.
    pub excitations: usize,
    /// Its robot's base stood otherwise than in the logs with most training poses: its training
    /// poses are another base orientation of the set (`training.poses[p].orientation`), and
    /// the motion record, fitted with one gravity, leaves its samples out; its structure moves
    /// count.
    #[serde(default, skip_serializing_if = "std::ops::Not::not")]
    pub other_base: bool,
    /// Single-DoF structure moves found.
    pub moves: usize,
    /// Motions of several DoFs (transfers), skipped.
    pub transfers: usize,
    /// Pairs of DoFs that moved alone together in transfers, one a fixed multiple of the other:
    /// a mimic joint with its leader, when ingest was not told of it (`--robot`, `--plan`).
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub together: Vec<Together>,
    /// Motions that could not be used, with the reason.
    pub skipped: Vec<String>,
    /// The excitation windows of the training poses, as fitted.
    pub fits: Vec<ExcitationFit>,
    /// Every pause and motion found, in time order.
    pub timeline: Vec<Span>,
    /// Joint-state decoding problems.
    pub joint_read: ReadStats,
    /// Skin decoding problems.
    pub imu_read: ReadStats,
    /// What its joint states tell the motion record's polynomials (not written).
    #[serde(skip)]
    pub(crate) surveyed: Option<window::JointsSurveyed>,
}

/// Two DoFs that moved alone together, the second a fixed multiple of the first (see
/// [`LogReport::together`]).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Together {
    /// The first of the two in the log's order.
    pub leader: String,
    /// The other.
    pub follower: String,
    /// The follower's motion over the leader's, in the first such transfer.
    pub multiplier: f64,
    /// How many transfers they made so.
    pub motions: usize,
    /// Whether every one of them had that multiplier (within [`SAME_MULTIPLIER`]): a mimic
    /// joint's is fixed, a plan's transfer of two DoFs along one profile has one of its own.
    pub same: bool,
}

/// Multipliers that differ by less than this share are one.
pub const SAME_MULTIPLIER: f64 = 0.01;

impl LogReport {
    /// Counts a transfer in which `follower` moved alone with `leader`, `multiplier` times it.
    pub(crate) fn add_together(&mut self, leader: String, follower: String, multiplier: f64) {
        match self
            .together
            .iter_mut()
            .find(|t| t.leader == leader && t.follower == follower)
        {
            Some(t) => {
                t.motions += 1;
                t.same &= (multiplier - t.multiplier).abs() <= SAME_MULTIPLIER * t.multiplier.abs();
            }
            None => self.together.push(Together {
                leader,
                follower,
                multiplier,
                motions: 1,
                same: true,
            }),
        }
    }
}

/// One window of a log's timeline.
#[derive(Debug, Clone, Default, PartialEq, Serialize, Deserialize)]
pub struct Span {
    /// `still` (a still window: static readings), `pause` (too short or restless for them),
    /// `excitation`, `move`, `transfer` (skipped) or `broken` (unusable: gap, too short).
    pub kind: String,
    /// The DoF of an excitation or a move.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub dof: Option<String>,
    /// Start and end, s from the log's first joint state.
    pub start: f64,
    /// End, s.
    pub end: f64,
}

/// One fitted excitation window.
#[derive(Debug, Clone, Default, PartialEq, Serialize, Deserialize)]
pub struct ExcitationFit {
    /// The excited DoF.
    pub dof: String,
    /// Other DoFs excited at the same time (a plan's parallel limbs).
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub together: Vec<String>,
    /// Start of the window, s from the log's first joint state.
    pub start: f64,
    /// Length of the window, s.
    pub duration: f64,
    /// The other DoFs that moved in it (servo compliance).
    pub coupled_dofs: Vec<String>,
    /// How much of the SU signals came from the other DoFs' motion: the RMS of their fitted
    /// contribution over the RMS of the excited DoF's own, over every SU and axis.
    pub coupled: f64,
}

/// What the ingestion found and did (`ingest-report.json`).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
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
    /// Each DoF's kind as its structure moves told it, where no description said
    /// ([`moves::kinds_of_moves`]).
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub kinds: Vec<moves::KindTold>,
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
    /// Per SU, which DoFs move it by the tree that told the DoFs excited together apart (`None`
    /// for an SU it does not place); `None` where no DoFs were excited together.
    pub(crate) moved_by: Option<Vec<Option<Vec<bool>>>>,
}

/// Progress of an ingestion: `(what, done, total)` in bytes of the pass.
pub type Progress<'a> = dyn FnMut(&str, u64, u64) + 'a;

/// Reads `logs` and extracts the measurement set.
///
/// ```
/// use skincal::ingest::{ingest, IngestConfig};
/// use skincal::log::csv::CsvSink;
/// use skincal::model::presets;
/// use skincal::plan::{Part, Plan, PlanConfig, PlanDof};
/// use skincal::sim::timeseries::{record, LogConfig};
/// use skincal::sim::BaseOrientation;
///
/// let robot = presets::find("paper-7dof").unwrap().robot().unwrap();
/// let program = PlanConfig { poses: 2, ..PlanConfig::short() };
/// let plan = Plan::new(PlanDof::from_robot(&robot), &program).unwrap();
/// // The program as the robot runs it, logged at 1 kHz: all of it upright, then the structure
/// // part again with the base tilted.
/// let dir = tempfile::tempdir().unwrap();
/// let (upright, tilted) = (dir.path().join("upright"), dir.path().join("tilted"));
/// let log = LogConfig::default();
/// record(&robot, &plan, &log, &mut CsvSink::new(&upright, false), &mut |_| {}).unwrap();
/// let log = LogConfig { orientation: BaseOrientation::tilted(), part: Some(Part::Structure), ..log };
/// record(&robot, &plan, &log, &mut CsvSink::new(&tilted, false), &mut |_| {}).unwrap();
///
/// let found = ingest(&[upright, tilted], &IngestConfig::default(), &mut |_, _, _| {}).unwrap();
/// let summary = found.measurements.summary();
/// assert_eq!((summary.orientations, summary.training_poses), (2, 2));
/// assert_eq!((summary.dofs, summary.sus), (7, 7));
/// ```
pub fn ingest(
    logs: &[PathBuf],
    config: &IngestConfig,
    progress: &mut Progress<'_>,
) -> Result<Ingested, IngestError> {
    let sources: Vec<LogSource> = logs.iter().cloned().map(LogSource::File).collect();
    ingest_from(&sources, config, progress)
}

/// Reads `logs`, files or logs in memory, and extracts the measurement set: [`ingest`] of any
/// [`LogSource`].
///
/// ```
/// use skincal::ingest::{ingest_from, IngestConfig};
/// use skincal::log::{LogSource, MemoryLog};
/// use skincal::model::presets;
/// use skincal::plan::{Plan, PlanConfig, PlanDof};
/// use skincal::sim::timeseries::{record, LogConfig};
///
/// let robot = presets::find("paper-7dof").unwrap().robot().unwrap();
/// let program = PlanConfig { poses: 1, ..PlanConfig::short() };
/// let plan = Plan::new(PlanDof::from_robot(&robot), &program).unwrap();
/// // The program recorded at 1 kHz into memory, and read from there: no file between the two.
/// let mut log = MemoryLog::new("recorded");
/// record(&robot, &plan, &LogConfig::default(), &mut log, &mut |_| {}).unwrap();
/// let found = ingest_from(&[LogSource::Memory(log)], &IngestConfig::default(), &mut |_, _, _| {})
///     .unwrap();
/// assert_eq!(found.measurements.summary().training_poses, 1);
/// assert_eq!(found.report.logs[0].format, "memory");
/// ```
pub fn ingest_from(
    logs: &[LogSource],
    config: &IngestConfig,
    progress: &mut Progress<'_>,
) -> Result<Ingested, IngestError> {
    ingest_logs(logs, config, progress, Some(pass::HELD)).map_err(|e| match e {
        IngestError::Empty(reason) if !logs.is_empty() => {
            IngestError::Empty(format!("in {}: {reason}", paths(logs)))
        }
        other => other,
    })
}

/// The ingestion, each log read in one pass (segmented every `step` skin samples) where it can
/// be, else (and with `step` `None`) in two.
fn ingest_logs(
    logs: &[LogSource],
    config: &IngestConfig,
    progress: &mut Progress<'_>,
    step: Option<usize>,
) -> Result<Ingested, IngestError> {
    config.validate()?;
    if logs.is_empty() {
        return Err(IngestError::Empty(": no log given".into()));
    }
    let mut grids = Vec::new();
    let mut plans = Vec::new();
    let mut accumulators = Vec::new();
    let mut reports = Vec::new();
    let mut dof_names: Option<Vec<String>> = config.dofs.clone();
    let mut sus = SuRegistry::new(config.sus.clone());
    for source in logs {
        let (log, report) = read_log(source, config, step, &mut dof_names, &mut sus, progress)?;
        grids.push(log.grid);
        plans.push(log.seg);
        accumulators.push(log.acc);
        reports.push(report);
    }
    let dofs = dof_names.unwrap_or_default();
    let (pattern, pattern_source) = pattern_of(config, &plans)?;
    let silent = leave_out_silent(&mut sus, &mut accumulators, &reports, config)?;
    let passes = Passes {
        config,
        dofs: &dofs,
        sus: &sus,
        grids: &grids,
        segs: &plans,
        accumulated: &accumulators,
        reports,
        warnings: silent.into_iter().collect(),
        variance: None,
        moved_by: None,
    };
    let ingested = assemble(passes, pattern, pattern_source)?;
    skin_unit(&ingested.measurements, config.skin_scale, logs)?;
    ingested
        .measurements
        .validate()
        .map_err(|e| invalid_set(logs, &e))?;
    Ok(ingested)
}

/// The error of a measurement set read from `logs` that breaks a rule of its format.
fn invalid_set(logs: &[LogSource], e: &MeasurementError) -> IngestError {
    IngestError::Invalid(format!(
        "{}: the measurement set read from these logs is not valid ({e}); nothing was written: \
         check the logs' values that field comes from (if they are sound, this is a defect of \
         skincal: please report it with the logs)",
        paths(logs)
    ))
}

/// The paths of `logs`, comma-separated.
fn paths(logs: &[LogSource]) -> String {
    logs.iter()
        .map(|l| l.path().display().to_string())
        .collect::<Vec<_>>()
        .join(", ")
}

/// One log read in one pass where it can be (segmented every `step` skin samples), else in
/// two; the DoF names and SUs it holds added to those of the logs before.
fn read_log(
    source: &LogSource,
    config: &IngestConfig,
    step: Option<usize>,
    dof_names: &mut Option<Vec<String>>,
    sus: &mut SuRegistry,
    progress: &mut Progress<'_>,
) -> Result<(LogPass, LogReport), IngestError> {
    let path = source.path();
    let format = source.format()?;
    let fresh = || LogReport {
        path: path.to_path_buf(),
        format: format.clone(),
        ..LogReport::default()
    };
    let mut report = fresh();
    let (names_before, sus_before) = (dof_names.clone(), sus.clone());
    let once = match step {
        Some(step) => one_pass(source, step, config, dof_names, sus, &mut report, progress)?,
        None => None,
    };
    let log = match once {
        Some(log) => {
            report.passes = 1;
            log
        }
        None => {
            // The log breaks what one pass relies on: read it twice.
            (*dof_names, *sus, report) = (names_before, sus_before, fresh());
            report.passes = 2;
            two_passes(source, config, dof_names, sus, &mut report, progress)?
        }
    };
    report.joint_start = log.grid.t0;
    one_clock(path, &report)?;
    Ok((log, report))
}

/// The excitation pattern: the configured one, else the one the logs' excitations show (none is
/// needed where they hold none).
fn pattern_of(
    config: &IngestConfig,
    plans: &[segment::Segmentation],
) -> Result<(ExcitationPattern, String), IngestError> {
    if let Some(p) = config.pattern {
        return Ok((p, "given".to_string()));
    }
    let excitations: usize = plans.iter().map(|p| p.excitations.len()).sum();
    match estimate_pattern(plans) {
        Some(found) => Ok(found),
        // A structure-only log: no training pose will need the pattern.
        None if excitations == 0 => Ok((
            ExcitationPattern::default(),
            "none needed: the logs hold no excitation".to_string(),
        )),
        None => Err(IngestError::Empty(format!(
            "the {excitations} excitations found give no usable pattern (peak speed \
             and acceleration out of range): give the nominal one with --plan or \
             --pattern A,f"
        ))),
    }
}

/// An error when the static readings' median norm is far from |g|: the skin's samples are in
/// another unit than m/s² (a driver that publishes g or mg), and every reading would be off by
/// that factor; `scale` is what they were multiplied by.
fn skin_unit(set: &MeasurementSet, scale: f64, logs: &[LogSource]) -> Result<(), IngestError> {
    let Some(median) = set.median_static_norm() else {
        return Ok(());
    };
    if ApparentUnit::of(median).is_none() {
        return Ok(());
    }
    // What the samples are in as the driver published them.
    let advice = match ApparentUnit::of(median / scale) {
        None => "the skin's samples are in m/s² already: leave out --skin-unit".to_string(),
        Some(ApparentUnit::G) => "the skin's driver publishes g: give --skin-unit g".to_string(),
        Some(ApparentUnit::Mg) => "the skin's driver publishes mg: give --skin-unit mg".to_string(),
        Some(ApparentUnit::Zero) => {
            "most SUs read zero: dead sensors, or a driver that does not fill in the acceleration"
                .to_string()
        }
        Some(ApparentUnit::Other(to_si)) => {
            format!("the skin's samples are in another unit: they need scaling by {to_si:.5}")
        }
    };
    let scaled = if scale == 1.0 {
        String::new()
    } else {
        format!(", after scaling by {scale}")
    };
    let names: Vec<String> = logs
        .iter()
        .map(|l| l.path().display().to_string())
        .collect();
    Err(IngestError::SkinUnit(format!(
        "{}: the static readings' median norm is {median:.4} m/s²{scaled}, but a resting \
         accelerometer reads |g| = {STANDARD_GRAVITY} m/s² (sensor_msgs/Imu carries m/s²): {advice}",
        names.join(", ")
    )))
}

/// An error when most skin samples of the log at `path` lie outside the joint states' time: the
/// two were stamped by different clocks (a driver's own clock against ROS time), and every window
/// would be empty.
fn one_clock(path: &Path, report: &LogReport) -> Result<(), IngestError> {
    let Some([first, last]) = report.imu_span else {
        return Ok(());
    };
    if report.imu_outside * 2 <= report.imu_samples {
        return Ok(());
    }
    let (start, end) = (report.joint_start, report.joint_start + report.duration);
    let apart = (first + last) / 2.0 - (start + end) / 2.0;
    Err(IngestError::Unusable {
        path: path.to_path_buf(),
        reason: format!(
            "{} of {} skin samples are stamped outside the joint states' time: the joint states \
             run from {start:.3} to {end:.3} s, the skin samples from {first:.3} to {last:.3} s \
             ({apart:+.3} s apart); they were stamped by different clocks: stamp both with one \
             clock (ROS time, the header stamp of each message), or shift one file's stamps",
            report.imu_outside, report.imu_samples
        ),
    })
}

/// The log at `path` read twice: its joint states (put on the grid and segmented), then its skin
/// samples.
fn two_passes(
    source: &LogSource,
    config: &IngestConfig,
    dof_names: &mut Option<Vec<String>>,
    sus: &mut SuRegistry,
    report: &mut LogReport,
    progress: &mut Progress<'_>,
) -> Result<LogPass, IngestError> {
    let timeline = read_joints(source, config, dof_names, report, progress)?;
    let dofs = dof_names.clone().unwrap_or_default();
    let seg = segment(&timeline, &dofs, config, report);
    let acc = read_skin(source, &timeline, &seg, config, sus, report, progress)?;
    Ok(LogPass {
        grid: timeline.grid,
        seg,
        acc,
    })
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::log::csv::CsvSink;
    use crate::log::mcap::{Compression, McapSink};
    use crate::model::presets;
    use crate::plan::{Part, Plan, PlanConfig, PlanDof};
    use crate::sim::timeseries::{record, LogConfig};
    use crate::sim::BaseOrientation;

    #[test]
    fn a_converters_highest_code_is_its_rail() {
        // A 10-bit converter over ±2 g: codes −512…511 of 4·9.80665/1024 m/s².
        let config = IngestConfig::default();
        let step = 4.0 * STANDARD_GRAVITY / 1024.0;
        assert!(config.saturated(&[0.0, 511.0 * step, 0.0]));
        assert!(config.saturated(&[-512.0 * step, 0.0, 0.0]));
        assert!(!config.saturated(&[0.0, 0.0, 509.0 * step]));
        assert!(!config.saturated(&[-9.81, 3.0, 1.0]));
    }

    /// The ingestion of `logs` read once (segmented every `step` samples) and read twice.
    fn once_and_twice(logs: &[PathBuf], step: usize) -> (Ingested, Ingested) {
        let logs: Vec<LogSource> = logs.iter().cloned().map(LogSource::File).collect();
        let logs = &logs[..];
        let config = IngestConfig::default();
        let once = ingest_logs(logs, &config, &mut |_, _, _| {}, Some(step)).unwrap();
        let twice = ingest_logs(logs, &config, &mut |_, _, _| {}, None).unwrap();
        (once, twice)
    }

    /// Everything but the number of passes.
    fn same(a: &Ingested, b: &Ingested) {
        let mut a_report = a.report.clone();
        for (log, other) in a_report.logs.iter_mut().zip(&b.report.logs) {
            log.passes = other.passes;
        }
        assert_eq!(a_report, b.report);
        assert_eq!(
            serde_json::to_string(&a.measurements).unwrap(),
            serde_json::to_string(&b.measurements).unwrap()
        );
    }

    #[test]
    fn one_pass_gives_what_two_passes_give() {
        // A real recording's flaws (noise, jitter, lost messages, a rounding encoder) in an MCAP
        // log of the structure part and training poses, and a CSV log of the structure part with
        // the base tilted; segmented every few hundred samples, so that every pause and motion is
        // settled across many stretches.
        let robot = presets::find("paper-7dof").unwrap().robot().unwrap();
        let plan = Plan::new(
            PlanDof::from_robot(&robot),
            &PlanConfig {
                poses: 2,
                seed: 5,
                ..PlanConfig::short()
            },
        )
        .unwrap();
        let dir = tempfile::tempdir().unwrap();
        let flawed = LogConfig {
            jitter: 2e-5,
            drop_probability: 0.01,
            encoder_resolution: 2.0 * std::f64::consts::PI / f64::from(1u32 << 17),
            seed: 3,
            ..LogConfig::default()
        };
        let upright = dir.path().join("upright.mcap");
        let mut sink = McapSink::new(&upright, Topics::default(), Compression::Zstd, false);
        record(&robot, &plan, &flawed, &mut sink, &mut |_| {}).unwrap();
        let tilted = dir.path().join("tilted");
        let mut sink = CsvSink::new(&tilted, false);
        let config = LogConfig {
            orientation: BaseOrientation::tilted(),
            part: Some(Part::Structure),
            ..flawed.clone()
        };
        record(&robot, &plan, &config, &mut sink, &mut |_| {}).unwrap();
        let logs = [upright, tilted];
        for step in [300, 5000] {
            let (once, twice) = once_and_twice(&logs, step);
            assert!(once.report.logs.iter().all(|l| l.passes == 1), "{step}");
            assert!(twice.report.logs.iter().all(|l| l.passes == 2));
            assert!(once.report.logs[0].excitations >= 14, "{:?}", once.report);
            assert!(once.report.logs[1].moves >= 7, "{:?}", once.report);
            same(&once, &twice);
        }
        // What the pass told the motion record of the joint states is what the record's own look
        // at them tells: the same record.
        let (once, _) = once_and_twice(&logs, 300);
        let config = IngestConfig::default();
        let told = motion::training_record(&once, &config, &mut |_, _, _| {})
            .unwrap()
            .unwrap();
        let set = &once.measurements;
        let looked =
            motion::motion_record(&logs[..1], &set.dofs, &set.sus, &config, &mut |_, _, _| {})
                .unwrap();
        assert!(told.rounding.iter().any(|&r| r > 0.0));
        assert_eq!(told, looked);

        // Joint stamps out of order: read twice, and the same.
        let shaken = dir.path().join("shaken.mcap");
        let mut sink = McapSink::new(&shaken, Topics::default(), Compression::None, false);
        let config = LogConfig {
            jitter: 2.4e-4,
            part: Some(Part::Structure),
            ..flawed
        };
        record(&robot, &plan, &config, &mut sink, &mut |_| {}).unwrap();
        let (once, twice) = once_and_twice(std::slice::from_ref(&shaken), 300);
        assert!(once.report.logs[0].unsorted_joint_stamps > 0);
        assert_eq!(once.report.logs[0].passes, 2);
        same(&once, &twice);
    }

    #[test]
    fn a_sweep_is_read_in_two_passes() {
        // A continuous program's sweep (15 s of every DoF at once) is one motion longer than the
        // pass holds the skin samples of: read twice, its structure part whole.
        let robot = presets::find("paper-7dof").unwrap().robot().unwrap();
        let plan = Plan::new(
            PlanDof::from_robot(&robot),
            &PlanConfig {
                sweep: 15.0,
                ..PlanConfig::continuous()
            },
        )
        .unwrap();
        let dir = tempfile::tempdir().unwrap();
        let log = dir.path().join("sweep.mcap");
        let mut sink = McapSink::new(&log, Topics::default(), Compression::Zstd, false);
        record(&robot, &plan, &LogConfig::default(), &mut sink, &mut |_| {}).unwrap();
        let (once, _) = once_and_twice(std::slice::from_ref(&log), 5000);
        let report = &once.report.logs[0];
        assert_eq!(report.passes, 2);
        assert!(report.moves >= 7 && report.transfers > 0, "{report:?}");
    }

    #[test]
    fn a_log_in_memory_gives_what_its_file_gives() {
        // One recording written to an MCAP file (whose CDR keeps every f64 and nanosecond
        // stamps) and to memory under the file's name: the same measurement set, the same report
        // but for the format.
        let robot = presets::find("paper-7dof").unwrap().robot().unwrap();
        let plan = Plan::new(
            PlanDof::from_robot(&robot),
            &PlanConfig {
                poses: 2,
                seed: 7,
                ..PlanConfig::short()
            },
        )
        .unwrap();
        let flawed = LogConfig {
            jitter: 2e-5,
            drop_probability: 0.01,
            seed: 4,
            ..LogConfig::default()
        };
        let dir = tempfile::tempdir().unwrap();
        let file = dir.path().join("recorded.mcap");
        let mut sink = McapSink::new(&file, Topics::default(), Compression::None, false);
        record(&robot, &plan, &flawed, &mut sink, &mut |_| {}).unwrap();
        let mut memory = crate::log::MemoryLog::new(&file);
        record(&robot, &plan, &flawed, &mut memory, &mut |_| {}).unwrap();
        let config = IngestConfig::default();
        let from_file = ingest(std::slice::from_ref(&file), &config, &mut |_, _, _| {}).unwrap();
        let mut from_memory =
            ingest_from(&[LogSource::Memory(memory)], &config, &mut |_, _, _| {}).unwrap();
        assert_eq!(from_memory.report.logs[0].format, "memory");
        assert_eq!(from_file.report.logs[0].format, "mcap");
        from_memory.report.logs[0].format = "mcap".into();
        assert!(
            from_file.report.training_poses == 2,
            "{:?}",
            from_file.report
        );
        same(&from_file, &from_memory);
    }
}
