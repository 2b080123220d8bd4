//! Executes a [`Plan`] on a simulated robot and records the log a real robot would write: joint
//! states and raw accelerometer samples at a fixed rate (default 1 kHz).
//!
//! Every sample is the full rigid-body physics of the commanded motion: each SU's acceleration is
//! the second time derivative of its position under the plan (whatever moves: one DoF or several),
//! so gravity, tangential and centripetal terms are all there. Then the sensor imperfections of the
//! condensed simulator (bias, saturation and quantisation, noise; see [`super`]), optionally
//! encoder quantisation of the joint positions, timestamp jitter and dropped messages.
//!
//! The acceleration is a central difference of positions with a step of 0.1 ms on the analytic
//! trajectory — an independent computation from the closed-form `α z × r + ω² z × (z × r)` the
//! condensed simulator and the estimators use (truncation error below 1e-6 m/s²).

use nalgebra::Vector3;
use rand::Rng;
use rand_distr::{Distribution, Normal};
use serde::{Deserialize, Serialize};

use super::{stream, BaseOrientation, Imperfections, Sensors, SimulationError};
use crate::log::{LogError, LogSink, Time};
use crate::model::sensor::specific_force;
use crate::model::{forward_kinematics, Kinematics, Robot};
use crate::plan::{Action, Part, Plan};

const JITTER_STREAM: u64 = 4;

/// How a plan is executed and recorded.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(default)]
pub struct LogConfig {
    /// Sample rate of joint states and every SU, Hz.
    pub rate: f64,
    /// Stamp of the first sample, s (ROS time).
    pub start_stamp: f64,
    /// Orientation of the reference segment (gravity in its frame).
    pub orientation: BaseOrientation,
    /// Run only this part of the plan (both when `None`).
    pub part: Option<Part>,
    /// Accelerometer imperfections (noise in g).
    pub imperfections: Imperfections,
    /// Joint positions are reported rounded to this step, rad (0: exact).
    pub encoder_resolution: f64,
    /// Standard deviation of the timestamp jitter of every message, s.
    pub jitter: f64,
    /// Probability that a message is lost.
    pub drop_probability: f64,
    /// Seed of noise, bias, jitter and drops.
    pub seed: u64,
    /// The skin's stamps run this late behind the joint states' (a driver's latency), s.
    pub skin_delay: f64,
}

impl Default for LogConfig {
    fn default() -> Self {
        Self {
            rate: 1000.0,
            start_stamp: 1_767_225_600.0,
            orientation: BaseOrientation::upright(),
            part: None,
            imperfections: Imperfections::default(),
            encoder_resolution: 0.0,
            jitter: 0.0,
            drop_probability: 0.0,
            seed: 0,
            skin_delay: 0.0,
        }
    }
}

impl LogConfig {
    /// Checks every setting.
    pub fn validate(&self) -> Result<(), SimulationError> {
        let bad =
            |setting, reason: String| Err(SimulationError::InvalidSetting { setting, reason });
        if !(self.rate.is_finite() && self.rate >= 10.0 && self.rate <= 100_000.0) {
            return bad("rate", format!("{} Hz: use 10 Hz to 100 kHz", self.rate));
        }
        if !(self.start_stamp.is_finite() && self.start_stamp >= 0.0 && self.start_stamp < 2.0e9) {
            return bad(
                "start_stamp",
                format!(
                    "{} s must be a ROS time between 0 and 2e9",
                    self.start_stamp
                ),
            );
        }
        for (setting, v) in [
            ("encoder_resolution", self.encoder_resolution),
            ("jitter", self.jitter),
            ("skin_delay", self.skin_delay),
        ] {
            if !(v.is_finite() && v >= 0.0) {
                return bad(setting, format!("{v} must be zero or positive"));
            }
        }
        if self.jitter * self.rate > 0.25 {
            return bad(
                "jitter",
                format!(
                    "{} s is more than a quarter of the sample period {} s",
                    self.jitter,
                    1.0 / self.rate
                ),
            );
        }
        if !(0.0..0.5).contains(&self.drop_probability) {
            return bad(
                "drop_probability",
                format!("{} must be in [0, 0.5)", self.drop_probability),
            );
        }
        self.imperfections.validate()
    }
}

/// What a recorded log holds.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct LogSummary {
    /// Duration, s.
    pub duration: f64,
    /// Joint-state messages written.
    pub joint_messages: u64,
    /// Accelerometer samples written.
    pub imu_messages: u64,
    /// Messages dropped on purpose.
    pub dropped: u64,
    /// Samples with an axis at the saturation limit.
    pub saturated: u64,
    /// Per-SU accelerometer intrinsics used (the ground truth).
    pub su_intrinsics: Vec<crate::model::intrinsics::Intrinsics>,
}

/// Errors of a time-series simulation.
#[derive(Debug, thiserror::Error)]
#[non_exhaustive]
pub enum RecordError {
    /// A setting is out of range.
    #[error(transparent)]
    Setting(#[from] SimulationError),
    /// The plan does not fit the robot.
    #[error(
        "the plan's DoFs {plan:?} are not the robot's {robot:?}: make the plan for this robot"
    )]
    PlanMismatch {
        /// DoFs of the plan.
        plan: Vec<String>,
        /// DoFs of the robot.
        robot: Vec<String>,
    },
    /// Writing failed.
    #[error(transparent)]
    Log(#[from] LogError),
}

/// Executes `plan` on `robot` and writes the log to `sink`; `progress` gets the fraction done.
pub fn record(
    robot: &Robot,
    plan: &Plan,
    config: &LogConfig,
    sink: &mut dyn LogSink,
    progress: &mut dyn FnMut(f64),
) -> Result<LogSummary, RecordError> {
    config.validate()?;
    let model = &robot.model;
    if plan.dof_names() != model.dof_names() {
        return Err(RecordError::PlanMismatch {
            plan: plan.dof_names(),
            robot: model.dof_names(),
        });
    }
    let (begin, end) = match config.part {
        None => (0.0, plan.duration),
        Some(Part::Structure) => (0.0, plan.structure_duration),
        Some(Part::Training) => (plan.structure_duration, plan.duration),
        Some(Part::Tilted) => (0.0, plan.tilted_end()),
    };
    let mut recorder = Recorder::new(robot, config, end - begin);
    // The noise of every component, (m/s²)²: uniform ±u has variance u²/3.
    let g0 = crate::model::sensor::STANDARD_GRAVITY;
    let variance = (config.imperfections.uniform_noise * g0).powi(2) / 3.0
        + (config.imperfections.gaussian_noise * g0).powi(2);
    sink.start(&model.dof_names(), &model.su_names(), variance)?;
    let n = ((end - begin) * config.rate).floor() as u64;
    let frames = |t: f64| forward_kinematics(model, &robot.parameters, &plan.state(t).q);
    // Still phases reuse the frames of their pose.
    let mut still_cache: Option<(usize, Kinematics<f64>)> = None;
    for k in 0..=n {
        let t = begin + k as f64 / config.rate;
        let receive_ns = recorder.first + (k as f64 * recorder.period).round() as i64;
        let state = plan.state(t);
        let phase = plan.phase_at(t);
        let is_still = plan
            .phases
            .get(phase)
            .is_some_and(|p| p.action == Action::Still && t > p.start);
        recorder.joints(receive_ns, &state.q, &state.qd, sink)?;
        let (now, accelerations) = if is_still {
            let cached = match still_cache.take() {
                Some((i, kin)) if i == phase => kin,
                _ => frames(t),
            };
            (cached, None)
        } else {
            let (now, a) = su_accelerations(&frames, t);
            (now, Some(a))
        };
        recorder.skin(receive_ns, &now, accelerations.as_deref(), sink)?;
        if is_still {
            still_cache = Some((phase, now));
        }
        if k % 1000 == 0 {
            progress(k as f64 / n.max(1) as f64);
        }
    }
    progress(1.0);
    sink.finish()?;
    Ok(recorder.summary)
}

/// The frames at `t` and every SU's acceleration there: the central difference of its positions
/// 0.1 ms either side.
fn su_accelerations(
    frames: &dyn Fn(f64) -> Kinematics<f64>,
    t: f64,
) -> (Kinematics<f64>, Vec<Vector3<f64>>) {
    let h = 1e-4;
    let (before, now, after) = (frames(t - h), frames(t), frames(t + h));
    let a = (0..now.sus.len())
        .map(|su| {
            (after.su_position(su) + before.su_position(su) - now.su_position(su) * 2.0) / (h * h)
        })
        .collect();
    (now, a)
}

/// What the recording keeps from sample to sample: the sensors, the clock's jitter and losses,
/// and the tally.
struct Recorder<'a> {
    config: &'a LogConfig,
    sensors: Sensors<'a>,
    rng: rand_chacha::ChaCha8Rng,
    jitter: Option<Normal<f64>>,
    gravity: Vector3<f64>,
    /// The ADC's range, m/s², if it has one.
    saturation: Option<f64>,
    /// The first stamp, ns.
    first: i64,
    /// The sample period, ns.
    period: f64,
    /// How late the skin's stamps run, ns.
    skin_late: i64,
    /// The joint positions as the encoders read them.
    positions: Vec<f64>,
    summary: LogSummary,
}

impl<'a> Recorder<'a> {
    fn new(robot: &Robot, config: &'a LogConfig, duration: f64) -> Self {
        let model = &robot.model;
        let sensors = Sensors::new(
            &config.imperfections,
            model.sus().len(),
            config.seed,
            config.seed,
        );
        let summary = LogSummary {
            duration,
            joint_messages: 0,
            imu_messages: 0,
            dropped: 0,
            saturated: 0,
            su_intrinsics: sensors.intrinsics.clone(),
        };
        Self {
            config,
            sensors,
            rng: stream(config.seed, JITTER_STREAM),
            jitter: (config.jitter > 0.0)
                .then(|| Normal::new(0.0, config.jitter).expect("validated")),
            gravity: Vector3::from(config.orientation.gravity),
            saturation: config
                .imperfections
                .saturation
                .or(config.imperfections.quantization_bits.map(|_| 2.0))
                .map(|g| g * crate::model::sensor::STANDARD_GRAVITY),
            // Stamps in whole nanoseconds from the first one, exact at any epoch. The first is
            // taken to the microsecond: an f64 of epoch seconds resolves only about 240 ns, so no
            // finer start is meant (1767225600.123 is held as …600.12299990654).
            first: (config.start_stamp * 1e6).round() as i64 * 1000,
            period: 1e9 / config.rate,
            skin_late: (config.skin_delay * 1e9).round() as i64,
            positions: vec![0.0; model.dofs().len()],
            summary,
        }
    }

    /// The stamp of a message received at `receive_ns`: with the clock's jitter.
    fn stamp(&mut self, receive_ns: i64) -> Time {
        let jitter = self
            .jitter
            .as_ref()
            .map_or(0.0, |j| j.sample(&mut self.rng));
        Time::from_nanoseconds(receive_ns + (jitter * 1e9).round() as i64)
    }

    /// Whether the next message is lost (its stamp drawn all the same, so that the draws stay in
    /// step).
    fn dropped(&mut self, receive_ns: i64) -> bool {
        let p = self.config.drop_probability;
        if p > 0.0 && self.rng.random::<f64>() < p {
            self.summary.dropped += 1;
            let _ = self.stamp(receive_ns);
            return true;
        }
        false
    }

    /// One joint-state message: positions as the encoders round them.
    fn joints(
        &mut self,
        receive_ns: i64,
        q: &[f64],
        qd: &[f64],
        sink: &mut dyn LogSink,
    ) -> Result<(), RecordError> {
        if self.dropped(receive_ns) {
            return Ok(());
        }
        let resolution = self.config.encoder_resolution;
        for (p, q) in self.positions.iter_mut().zip(q) {
            *p = if resolution > 0.0 {
                (q / resolution).round() * resolution
            } else {
                *q
            };
        }
        let s = self.stamp(receive_ns);
        sink.joint_state(s, Time::from_nanoseconds(receive_ns), &self.positions, qd)?;
        self.summary.joint_messages += 1;
        Ok(())
    }

    /// Every SU's sample with the frames `now` and SU accelerations (none: still).
    fn skin(
        &mut self,
        receive_ns: i64,
        now: &Kinematics<f64>,
        accelerations: Option<&[Vector3<f64>]>,
        sink: &mut dyn LogSink,
    ) -> Result<(), RecordError> {
        for su in 0..now.sus.len() {
            let a = accelerations.map_or_else(Vector3::zeros, |a| a[su]);
            let f = specific_force(&now.sus[su], &a, &self.gravity);
            let mut v = self.sensors.sample(su, &f);
            if let Some(s) = self.saturation {
                // An ADC cannot report beyond its range, noise included.
                v = v.map(|x| x.clamp(-s, s));
            }
            if self.dropped(receive_ns) {
                continue;
            }
            if self
                .saturation
                .is_some_and(|s| v.iter().any(|x| x.abs() >= s * (1.0 - 1e-9)))
            {
                self.summary.saturated += 1;
            }
            let stamp = self.stamp(receive_ns).nanoseconds() as i64 + self.skin_late;
            sink.imu(
                Time::from_nanoseconds(stamp),
                Time::from_nanoseconds(receive_ns),
                su,
                v.into(),
            )?;
            self.summary.imu_messages += 1;
        }
        Ok(())
    }
}
