//! Keeping a robot calibrated: whether each SU still reads what the calibrated model predicts
//! from the joint states of any motion (a motion record of ordinary work, no protocol), and if not,
//! what changed.
//!
//! For every block of the record the model gives each SU's reading and how that reading would
//! change if the SU had shifted or turned on its segment or its bias or sensitivity had changed
//! (a change of 12 numbers, [`kin::CHANGE`]). The blocks' normal equations are summed per SU
//! ([`Tally`], bounded memory, fed a run at a time, so a live stream can be checked as it comes);
//! their solution is the change the log estimates, tested by a Wald test against what the noise
//! and the model's own uncertainty allow (`test::change_test`). An SU that no small change
//! explains is then matched against every other SU's place (swapped, or reading another's),
//! fitted anew on its segment (moved far) and on the others (the tree changed), or named broken
//! (`refit`). [`recalibrate`] writes the changes into a new model.

mod kin;
mod live;
mod reach;
mod recalibrate;
mod refit;
mod test;
mod zero;

use std::collections::BTreeMap;

use nalgebra::{Isometry3, Vector3};
use serde::{Deserialize, Serialize};

pub use crate::estimate::body::{FoundChange, ModelChange, SuModelChange};
pub use kin::{BlockKinematics, SuPlace, CHANGE};
pub use live::{LiveCheck, RECENT, WARM_UP};
pub use recalibrate::{recalibrate, RecalibrateError};
pub use test::{critical, non_centrality, Tally};
pub use zero::ZeroChange;

use crate::estimate::body::BodyModel;
use crate::model::sensor::STANDARD_GRAVITY;
use crate::model::Robot;
use crate::motion::{MotionRecord, MotionRun, SampleCount};
use crate::predict::Predictor;

/// What the check must see and how often it may cry wolf.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(default)]
pub struct CheckConfig {
    /// Probability that an unchanged SU is reported changed, per SU and log.
    pub false_alarm: f64,
    /// Probability with which a change of the sizes below is seen, where the log tells it.
    pub power: f64,
    /// The shift the check must see, m.
    pub detect_position: f64,
    /// The turn the check must see, rad.
    pub detect_orientation: f64,
    /// The bias change the check must see, m/s².
    pub detect_bias: f64,
    /// The change of an axis' sensitivity the check must see (relative: `0.03` is 3 %).
    pub detect_scale: f64,
    /// The model's own error of an SU's position that is never taken for a change (added to the
    /// calibration's deviation), m.
    pub position_floor: f64,
    /// The same for its orientation, rad.
    pub orientation_floor: f64,
    /// The same for its bias, m/s².
    pub bias_floor: f64,
    /// The same for its sensitivity (relative).
    pub scale_floor: f64,
    /// A block whose whitened residual is larger than this counts less (Huber).
    pub huber: f64,
    /// An SU whose RMS whitened residual stays above this after the best small change is not
    /// explained by one: it is matched with other places, fitted anew, or broken.
    pub misfit: f64,
    /// An SU noisier than this many times the skin's median is broken (noisy).
    pub noisy: f64,
}

impl Default for CheckConfig {
    fn default() -> Self {
        Self {
            false_alarm: 1e-3,
            power: 0.99,
            detect_position: 0.010,
            detect_orientation: 3f64.to_radians(),
            detect_bias: 0.03 * STANDARD_GRAVITY,
            detect_scale: 0.03,
            position_floor: 0.001,
            orientation_floor: 0.2f64.to_radians(),
            bias_floor: 0.002 * STANDARD_GRAVITY,
            scale_floor: 0.002,
            huber: 4.0,
            misfit: 2.0,
            noisy: 3.0,
        }
    }
}

/// What the check found for one SU.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(tag = "kind", rename_all = "kebab-case")]
pub enum Verdict {
    /// It reads what the model predicts.
    Unchanged,
    /// It shifted or turned on its segment (see [`SuCheck::change`]).
    Moved,
    /// Its bias changed (see [`SuCheck::change`]).
    BiasChanged,
    /// Its sensitivity changed, with or without its bias (see [`SuCheck::change`]): its
    /// accelerometer drifted.
    ScaleChanged,
    /// It and `with` exchanged identities (re-plugged into each other's ports).
    Swapped {
        /// The other SU.
        with: String,
    },
    /// It reads what SU `su` should, which itself still reads right: its identity is another's.
    ReadsAs {
        /// The SU it reads like.
        su: String,
    },
    /// It now sits on another segment: the tree changed there.
    OtherSegment {
        /// The segment on which it fits.
        segment: String,
    },
    /// It is broken.
    Broken {
        /// `silent` (no samples, or fresh ones in almost no block), `frozen` (one value sent
        /// over and over), `railed` (at the accelerometer's range), `dead` (reads near zero),
        /// `noisy`, or `erratic` (no place explains it).
        how: String,
    },
    /// The log's motion does not tell whether it changed.
    NotEnoughMotion,
}

impl Verdict {
    /// A short word for tables.
    pub fn word(&self) -> String {
        match self {
            Verdict::Unchanged => "unchanged".into(),
            Verdict::Moved => "MOVED".into(),
            Verdict::BiasChanged => "BIAS CHANGED".into(),
            Verdict::ScaleChanged => "SCALE CHANGED".into(),
            Verdict::Swapped { with } => format!("SWAPPED with {with}"),
            Verdict::ReadsAs { su } => format!("READS AS {su}"),
            Verdict::OtherSegment { segment } => format!("ON SEGMENT {segment}"),
            Verdict::Broken { how } => format!("BROKEN ({how})"),
            Verdict::NotEnoughMotion => "not enough motion".into(),
        }
    }

    /// Whether the SU reads what the model predicts (or the log cannot tell).
    pub fn is_quiet(&self) -> bool {
        matches!(self, Verdict::Unchanged | Verdict::NotEnoughMotion)
    }
}

/// A change of an SU's pose, bias and sensitivity with its standard deviations.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct SuChange {
    /// Shift in the SU's frame (as the model has it), m.
    pub shift: [f64; 3],
    /// Its standard deviation per axis, m (none after a fit anew, judged by its residual).
    pub shift_sd: Option<[f64; 3]>,
    /// Turn (rotation vector) in the SU's frame, rad.
    pub turn: [f64; 3],
    /// Its standard deviation per axis, rad.
    pub turn_sd: Option<[f64; 3]>,
    /// Change of the bias, m/s².
    pub bias: [f64; 3],
    /// Its standard deviation per axis, m/s².
    pub bias_sd: Option<[f64; 3]>,
    /// Relative change of each axis' sensitivity (`0.03`: reads 3 % more; absent in reports
    /// written before it was checked).
    #[serde(default)]
    pub scale: [f64; 3],
    /// Its standard deviation per axis.
    #[serde(default)]
    pub scale_sd: Option<[f64; 3]>,
}

/// The check of one SU.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct SuCheck {
    /// The SU.
    pub su: String,
    /// What was found.
    pub verdict: Verdict,
    /// Blocks of the log in which it sent a fresh sample and the joint states are known.
    pub blocks: usize,
    /// How many samples the log held of it, and why some are in no block (none: not counted).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub samples: Option<SampleCount>,
    /// The standard deviation of one component of its block mean, m/s².
    pub noise_sd: f64,
    /// The Wald statistic of its change over the directions the log tells, and their number.
    pub statistic: f64,
    /// Degrees of freedom of [`Self::statistic`].
    pub dof: usize,
    /// `P(χ² ≥ statistic)` if it is unchanged.
    pub p_value: f64,
    /// RMS whitened residual after the best small change (≈ 1: explained).
    pub residual_ratio: f64,
    /// The change the log estimates (for `moved`, `bias-changed`, and after a refit the whole
    /// change from the model's place on the same segment).
    pub change: Option<SuChange>,
    /// What of its place this log does not tell (`position`, `orientation`, `bias`), with the
    /// DoFs whose motion would.
    #[serde(default, skip_serializing_if = "String::is_empty")]
    pub untold: String,
    /// What of its place no motion of the robot tells (a shift along a vertical first axis that
    /// alone carries it; a tilt that a bias mimics): a change there is never seen.
    #[serde(default, skip_serializing_if = "String::is_empty")]
    pub never_told: String,
    /// For a `moved` (or `scale-changed`) SU that alone tells a DoF's zero: that zero, moved by
    /// the angle that reads as this change (an encoder homed anew looks the same; only another SU
    /// beyond the DoF could tell them apart).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub or_zero: Option<ZeroChange>,
    /// Its place as found anew, on its segment or another (`moved` far, `other-segment`), in the
    /// segment's frame.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub refit: Option<Refit>,
    /// What to do about it (empty when nothing needs doing).
    #[serde(default, skip_serializing_if = "String::is_empty")]
    pub advice: String,
}

/// An SU fitted anew on a segment.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct Refit {
    /// Its frame on the segment: translation, m.
    pub xyz: [f64; 3],
    /// Rotation, rad (roll, pitch, yaw).
    pub rpy: [f64; 3],
    /// Its bias, m/s².
    pub bias: [f64; 3],
    /// RMS whitened residual of the fit.
    pub residual_ratio: f64,
}

/// The check of a whole skin against one log.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct CheckReport {
    /// Seconds of the log checked (blocks with joint states).
    pub seconds: f64,
    /// Per SU of the model, in its order (judged with a moved zero taken out).
    pub sus: Vec<SuCheck>,
    /// A DoF whose zero moved (its encoder homed anew), every SU beyond it telling the same angle.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub zero: Option<ZeroChange>,
    /// DoFs whose zero this log does not tell to within the turn the check promised to see
    /// (`detect_orientation`), though a minute of rich motion would: too little of their motion,
    /// or no SU beyond them that the model still explains (all broken, swapped or moved far).
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub zeros_untold: Vec<String>,
    /// DoFs whose zero no motion tells: a vertical axis on the still reference segment turns
    /// what it carries about gravity, and no reading changes (a zero moved there is never seen
    /// and changes no prediction).
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub zeros_never_told: Vec<String>,
    /// Pairs of SUs that read alike in every pose (turned alike on the still reference segment):
    /// no motion tells an exchange of the two, and the check cannot see one.
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub alike: Vec<[String; 2]>,
    /// The smallest changes the check promised to see and its false-alarm rate.
    pub config: CheckConfig,
    /// Remarks about the log as a whole.
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub notes: Vec<String>,
}

impl CheckReport {
    /// Whether anything changed: an SU, or a DoF's zero.
    pub fn any_change(&self) -> bool {
        self.zero.is_some() || self.changed().next().is_some()
    }

    /// The SUs that changed or broke.
    pub fn changed(&self) -> impl Iterator<Item = &SuCheck> {
        self.sus.iter().filter(|s| !s.verdict.is_quiet())
    }
}

/// Why a check cannot run.
#[derive(Debug, thiserror::Error)]
pub enum CheckError {
    /// The model is not a calibrated model.
    #[error("the model: {0}")]
    Model(crate::predict::PredictError),
    /// The motion record does not fit the model.
    #[error("the motion record: {0}")]
    Record(String),
}

/// The calibrated skin as the check sees it.
#[derive(Debug, Clone)]
pub struct Skin {
    robot: Robot,
    places: Vec<SuPlace>,
    /// Per SU: the matrices it reads through at its place.
    sensors: Vec<kin::Sensor>,
    /// Per segment: the DoFs between it and the reference.
    chains: Vec<Vec<usize>>,
    /// Per SU: the variance of the model's own error of each change component.
    prior: Vec<test::Change>,
    /// Per SU: how late the skin runs behind the joint states, s.
    delay: Vec<f64>,
    /// The change components' scales: the change the check must see.
    scale: test::Change,
    /// What any motion could tell of each SU, and each DoF's share.
    reach: reach::Reach,
}

impl Skin {
    /// The skin of a calibrated model.
    pub fn new(model: &BodyModel, config: &CheckConfig) -> Result<Self, CheckError> {
        let predictor = Predictor::new(model).map_err(CheckError::Model)?;
        let (robot, gravity, intrinsics) = predictor.parts();
        let robot = robot.clone();
        let m = &robot.model;
        let places: Vec<SuPlace> = m
            .sus()
            .iter()
            .enumerate()
            .map(|(u, su)| SuPlace {
                segment: su.segment,
                placement: su.placement.transform(&robot.parameters),
                intrinsics: intrinsics[u],
                gravity: gravity[u],
            })
            .collect();
        let chains: Vec<Vec<usize>> = (0..m.segments().len()).map(|s| m.chain_to(s)).collect();
        let deviations = su_deviations(model);
        let delays = su_delays(model);
        let prior = m
            .su_names()
            .iter()
            .map(|name| {
                let (p, o) = deviations.get(name).copied().unwrap_or((0.0, 0.0));
                let position = config.position_floor.powi(2) + p * p / 3.0;
                let orientation = config.orientation_floor.powi(2) + o * o / 3.0;
                let bias = config.bias_floor.powi(2);
                let scale = config.scale_floor.powi(2);
                test::Change::from_iterator(
                    [position; 3]
                        .into_iter()
                        .chain([orientation; 3])
                        .chain([bias; 3])
                        .chain([scale; 3]),
                )
            })
            .collect();
        let delay = m
            .su_names()
            .iter()
            .map(|n| delays.get(n).copied().unwrap_or(0.0))
            .collect();
        let scale = test::Change::from_iterator(
            [config.detect_position; 3]
                .into_iter()
                .chain([config.detect_orientation; 3])
                .chain([config.detect_bias; 3])
                .chain([config.detect_scale; 3]),
        );
        let reach = reach::Reach::new(&robot, &places, &chains, &scale);
        Ok(Self {
            robot,
            sensors: places.iter().map(SuPlace::sensor).collect(),
            places,
            chains,
            prior,
            delay,
            scale,
            reach,
        })
    }

    /// How much of `change` ([`CHANGE`] numbers in physical units: shift, turn, bias,
    /// sensitivity) of SU `su` a minute of rich motion tells at block noise `noise` (m/s²) with
    /// the power of `config`: the length of its part in the directions some motion tells, in
    /// units of the change the check must see. Below 1, what the physics hides (a height along
    /// a vertical axis that alone carries the SU, a tilt or a sensitivity its bias mimics) leaves
    /// less than that to see. `None` for an SU the model does not have.
    pub fn told_part(
        &self,
        su: &str,
        change: &[f64; CHANGE],
        noise: f64,
        config: &CheckConfig,
    ) -> Option<f64> {
        let u = self.robot.model.su_index(su)?;
        let lambda = non_centrality(config.false_alarm, config.power, CHANGE);
        let tellable = self.reach.tellable(u, noise.max(1e-6), lambda);
        let scaled = test::Change::from_row_slice(change).component_div(&self.scale);
        Some((tellable * scaled).norm())
    }

    /// The pairs of SUs (`u < v`) on one segment that read alike in every pose: what the first
    /// reads apart from the second's place, taken as a change of the first, is below what the
    /// check must see in every direction that some motion tells (at the larger of the two
    /// SUs' block noise `noise[u]`, `noise[v]`, with non-centrality `lambda`). Turned alike on a
    /// segment that never moves, or set apart only along a vertical axis that alone carries
    /// them: an exchange of the two (their cables swapped) is told by no motion.
    fn alike(&self, noise: &[f64], lambda: f64) -> Vec<(usize, usize)> {
        let mut by_segment: Vec<Vec<usize>> = vec![Vec::new(); self.chains.len()];
        for (u, place) in self.places.iter().enumerate() {
            by_segment[place.segment].push(u);
        }
        let mut pairs = Vec::new();
        for sus in &by_segment {
            for (i, &u) in sus.iter().enumerate() {
                for &v in &sus[i + 1..] {
                    // Beyond this a small change describes the difference poorly, and a
                    // difference that size is seen anyway.
                    if self.reach.apart(u, v) > ALIKE_GATE {
                        continue;
                    }
                    let c = refit::whole_change(&self.places[u], &self.places[v]);
                    let change = test::Change::from_iterator(
                        c.shift
                            .into_iter()
                            .chain(c.turn)
                            .chain(c.bias)
                            .chain(c.scale),
                    );
                    let sd = noise[u].max(noise[v]).max(1e-6);
                    let tellable = self.reach.tellable(u, sd, lambda);
                    if (tellable * change.component_div(&self.scale)).norm() < 1.0 {
                        pairs.push((u, v));
                    }
                }
            }
        }
        pairs
    }

    /// The robot of the model.
    pub fn robot(&self) -> &Robot {
        &self.robot
    }

    /// Each SU's place, in the model's SU order.
    pub fn places(&self) -> &[SuPlace] {
        &self.places
    }
}

/// Per SU: its position and orientation standard deviations from the calibration.
fn su_deviations(model: &BodyModel) -> BTreeMap<String, (f64, f64)> {
    model
        .limbs
        .iter()
        .flat_map(|l| &l.estimate.uncertainty)
        .map(|u| {
            let finite = |x: f64| if x.is_finite() { x } else { 0.0 };
            (
                u.su.clone(),
                (finite(u.position_sd), finite(u.orientation_sd)),
            )
        })
        .collect()
}

/// Per SU: the skin delay its limb's time-domain fit found.
fn su_delays(model: &BodyModel) -> BTreeMap<String, f64> {
    model
        .limbs
        .iter()
        .flat_map(|l| {
            let delay = l.estimate.motion.as_ref().map_or(0.0, |m| m.skin_delay);
            l.sus.iter().map(move |s| (s.clone(), delay))
        })
        .collect()
}

/// A skin's model matched to the columns of a motion record.
#[derive(Debug, Clone)]
pub struct Columns {
    /// Per model DoF: its column in the record.
    pub dofs: Vec<usize>,
    /// Per model SU: its column in the record (`None`: the log has no samples of it).
    pub sus: Vec<Option<usize>>,
}

impl Columns {
    /// The columns of `dofs`/`sus` (a record's names) for `skin`; every model DoF must be there.
    pub fn new(skin: &Skin, dofs: &[String], sus: &[String]) -> Result<Self, CheckError> {
        let m = &skin.robot.model;
        let missing: Vec<String> = m
            .dof_names()
            .into_iter()
            .filter(|d| !dofs.contains(d))
            .collect();
        if !missing.is_empty() {
            return Err(CheckError::Record(format!(
                "no joint states for the model's DoF(s) {}: record a log with every calibrated joint",
                missing.join(", ")
            )));
        }
        let column = |names: &[String], n: &String| names.iter().position(|x| x == n);
        Ok(Self {
            dofs: m
                .dof_names()
                .iter()
                .map(|d| column(dofs, d).expect("checked above"))
                .collect(),
            sus: m.su_names().iter().map(|s| column(sus, s)).collect(),
        })
    }
}

/// One block of a run in the model's order: joint states and each SU's reading at its delay.
pub struct Block {
    /// Joint positions, velocities and accelerations, model DoF order.
    pub q: [Vec<f64>; 3],
    /// Frames and motions.
    pub kinematics: BlockKinematics,
    /// Joint acceleration deviations, model DoF order.
    pub qdd_sd: Vec<f64>,
    /// Per model SU: its reading (`None`: no fresh sample there).
    pub readings: Vec<Option<Vector3<f64>>>,
}

/// Block `b` of `run` (block length `period`).
pub fn block(skin: &Skin, columns: &Columns, run: &MotionRun, b: usize, period: f64) -> Block {
    let pick = |row: &[f64]| columns.dofs.iter().map(|&c| row[c]).collect::<Vec<_>>();
    let q = [pick(&run.q[b]), pick(&run.qd[b]), pick(&run.qdd[b])];
    let kinematics = BlockKinematics::new(&skin.robot, &q[0], &q[1], &q[2]);
    let readings = columns
        .sus
        .iter()
        .zip(&skin.delay)
        .map(|(c, &delay)| c.and_then(|c| skin_at(run, c, b as f64 + delay / period)))
        .collect();
    Block {
        q,
        kinematics,
        qdd_sd: pick(&run.qdd_sd[b]),
        readings,
    }
}

/// SU column `c`'s reading at fractional block `t`, linear between the blocks around it.
fn skin_at(run: &MotionRun, c: usize, t: f64) -> Option<Vector3<f64>> {
    if t < 0.0 || t > (run.len() - 1) as f64 {
        return None;
    }
    let lo = t.floor() as usize;
    let frac = t - lo as f64;
    let at = |b: usize| run.skin.get(b, c).map(Vector3::from);
    if frac < 1e-9 {
        return at(lo);
    }
    Some(at(lo)? * (1.0 - frac) + at(lo + 1)? * frac)
}

/// The residual, Jacobian and variance of SU `u` placed as `place` in `block` with block noise
/// `noise_sd`; `None` where it has no reading.
pub fn su_term(
    skin: &Skin,
    block: &Block,
    u: usize,
    place: &SuPlace,
    noise_sd: f64,
) -> Option<(Vector3<f64>, kin::Jacobian, f64)> {
    su_term_with(skin, block, u, place, &place.sensor(), noise_sd)
}

/// [`su_term`] with the place's [`kin::Sensor`] already made.
fn su_term_with(
    skin: &Skin,
    block: &Block,
    u: usize,
    place: &SuPlace,
    sensor: &kin::Sensor,
    noise_sd: f64,
) -> Option<(Vector3<f64>, kin::Jacobian, f64)> {
    let y = block.readings[u]?;
    let (predicted, jac) = kin::reading_with(place, sensor, &block.kinematics);
    let lever = kin::lever_variance(
        place,
        &block.kinematics,
        &skin.chains[place.segment],
        &block.qdd_sd,
    );
    Some((y - predicted, jac, noise_sd * noise_sd + lever))
}

/// A check in progress: the skin, and every SU's sums over the blocks fed so far. A clone shares
/// the skin and copies the sums (a live report sums the open run's last blocks on a clone).
#[derive(Clone)]
pub struct SkinCheck {
    skin: std::sync::Arc<Skin>,
    columns: Columns,
    config: CheckConfig,
    noise: Vec<f64>,
    tallies: Vec<Tally>,
    /// Per SU: its sums for each DoF of its chain (a DoF's zero).
    zero: Vec<Vec<zero::ZeroSums>>,
    /// Per SU: blocks since its last fresh reading, and the most there were.
    quiet: Vec<(usize, usize)>,
    blocks: usize,
    period: f64,
}

impl SkinCheck {
    /// A check of `skin` on records with the columns `columns`, each SU's block noise `noise`
    /// (model SU order, m/s²).
    pub fn new(skin: Skin, columns: Columns, noise: Vec<f64>, config: CheckConfig) -> Self {
        let n = skin.places.len();
        Self {
            skin: std::sync::Arc::new(skin),
            columns,
            config,
            noise,
            tallies: vec![Tally::default(); n],
            zero: vec![Vec::new(); n],
            quiet: vec![(0, 0); n],
            blocks: 0,
            period: 0.0,
        }
    }

    /// Adds every block of `run` (block length `period`, s).
    pub fn feed(&mut self, run: &MotionRun, period: f64) {
        self.feed_range(run, 0..run.len(), period);
    }

    /// Adds blocks `range` of `run` (the others are their context: an SU's reading at its delay
    /// lies between two blocks).
    pub fn feed_range(&mut self, run: &MotionRun, range: std::ops::Range<usize>, period: f64) {
        self.period = period;
        for b in range {
            let block = block(&self.skin, &self.columns, run, b, period);
            let [q, qd, qdd] = &block.q;
            let rates = zero::Rates::new(&self.skin.robot, &block.kinematics, q, qd, qdd);
            self.blocks += 1;
            for (u, tally) in self.tallies.iter_mut().enumerate() {
                let place = &self.skin.places[u];
                let quiet = &mut self.quiet[u];
                quiet.0 = if block.readings[u].is_some() {
                    0
                } else {
                    quiet.0 + 1
                };
                quiet.1 = quiet.1.max(quiet.0);
                let sensor = &self.skin.sensors[u];
                let term = su_term_with(&self.skin, &block, u, place, sensor, self.noise[u]);
                if let Some((r, jac, var)) = term {
                    let w = tally.add(&r, &jac, var, self.config.huber);
                    tally.norm_sum += block.readings[u].map_or(0.0, |y| y.norm());
                    let chain = &self.skin.chains[place.segment];
                    zero::add(
                        &mut self.zero[u],
                        &rates,
                        chain,
                        place,
                        &sensor.kt,
                        &r,
                        &jac,
                        w,
                    );
                }
            }
        }
    }

    /// Each SU's verdict from the sums alone (what a small change explains; an SU it does not
    /// is `Broken { how: "erratic" }` until the refit finds better); `samples` is the record's
    /// count of each SU's samples (record SU order; empty: not counted).
    pub fn verdicts(&self, samples: &[SampleCount]) -> CheckReport {
        let lambda = non_centrality(self.config.false_alarm, self.config.power, CHANGE);
        let skin = &self.skin;
        let typical = Typical {
            noise: median(self.noise.clone()),
            quiet: median(self.quiet.iter().map(|q| q.1 as f64).collect()) * self.period,
        };
        let names = self.skin.robot.model.su_names();
        // A DoF whose zero moved is taken out of its SUs' sums before they are judged.
        let mut tallies = self.tallies.clone();
        // SUs the model's place roughly explains tell a zero (not swapped, dead or wild ones).
        let usable: Vec<bool> = tallies
            .iter()
            .map(|t| {
                t.blocks > 0 && t.residual_ratio(&test::Change::zeros()) < 10.0 * self.config.misfit
            })
            .collect();
        let (zeros_untold, zeros_never_told) = self.untold_zeros(&usable, typical.noise);
        let mut zero = zero::moved_zero(
            &skin.robot,
            &mut tallies,
            &self.zero,
            &usable,
            self.config.false_alarm,
        );
        let judged = |u: usize, tally: &Tally| {
            let tellable = skin.reach.tellable(u, self.noise[u].max(1e-6), lambda);
            let t = test::change_test(tally, &skin.scale, &skin.prior[u], lambda, &tellable);
            let count = self.skin_count(samples, u);
            let mut check = self.verdict(&names[u], u, tally, &t, &typical, count);
            check.never_told = never_told(&tellable);
            check
        };
        let mut sus: Vec<SuCheck> = (0..names.len())
            .map(|u| {
                let mut check = judged(u, &tallies[u]);
                let changed = matches!(check.verdict, Verdict::Moved | Verdict::ScaleChanged);
                if changed && zero.is_none() {
                    check.or_zero = zero::alike(
                        &skin.robot,
                        &tallies,
                        &self.zero,
                        u,
                        self.config.false_alarm,
                    );
                }
                check
            })
            .collect();
        if zero.is_none() {
            zero = self.lone_zero(&mut sus, &tallies, &judged);
        }
        let alike = skin
            .alike(&self.noise, lambda)
            .into_iter()
            .map(|(u, v)| [names[u].clone(), names[v].clone()])
            .collect();
        CheckReport {
            seconds: self.blocks as f64 * self.period,
            sus,
            zero,
            zeros_untold,
            zeros_never_told,
            alike,
            config: self.config,
            notes: Vec::new(),
        }
    }

    /// A zero one SU alone tells because no small change of its own explains its readings (a
    /// DoF that moves it alone, with another DoF between them: the hand's SU past a wrist's yaw
    /// and pitch), where that zero does: the zero, and the SU judged again with it taken out. An
    /// SU whose own change explains its readings only loosely (called moved or drifted, with the
    /// zero beside it) is given the zero too when the zero leaves it unchanged and explains
    /// clearly more (a tenth of its residual: on thousands of blocks the ratio varies by about a
    /// hundredth); where the zero is just its turn about the DoF's axis, both explain alike and
    /// the zero stays beside the move.
    fn lone_zero(
        &self,
        sus: &mut [SuCheck],
        tallies: &[Tally],
        judged: &dyn Fn(usize, &Tally) -> SuCheck,
    ) -> Option<ZeroChange> {
        let robot = &self.skin.robot;
        let erratic = |c: &SuCheck| {
            c.verdict
                == Verdict::Broken {
                    how: "erratic".into(),
                }
        };
        let loose = |c: &SuCheck| {
            matches!(c.verdict, Verdict::Moved | Verdict::ScaleChanged) && c.or_zero.is_some()
        };
        let (u, found, check) = (0..sus.len())
            .filter(|&u| erratic(&sus[u]) || loose(&sus[u]))
            .filter_map(|u| {
                let z = zero::alike(robot, tallies, &self.zero, u, self.config.false_alarm)?;
                let mut tally = tallies[u].clone();
                zero::take_out(
                    &mut tally,
                    zero::sums_of(&self.zero, u, &z.dof, robot)?,
                    z.offset,
                );
                let check = judged(u, &tally);
                let explains = if erratic(&sus[u]) {
                    !erratic(&check)
                } else {
                    check.verdict.is_quiet() && check.residual_ratio < 0.9 * sus[u].residual_ratio
                };
                explains.then_some((u, z, check))
            })
            .min_by(|a, b| a.2.residual_ratio.total_cmp(&b.2.residual_ratio))?;
        sus[u] = check;
        Some(found)
    }

    /// The DoFs whose zero this log does not tell to
    /// within `detect_orientation` from the SUs `usable`, and of those the ones no motion tells
    /// (judged at block noise `noise`).
    fn untold_zeros(&self, usable: &[bool], noise: f64) -> (Vec<String>, Vec<String>) {
        let m = &self.skin.robot.model;
        let n = m.dofs().len();
        let lambda = non_centrality(self.config.false_alarm / n as f64, self.config.power, 1);
        let angle = self.config.detect_orientation;
        let info = zero::information(&self.zero, usable, n);
        let (mut untold, mut never) = (Vec::new(), Vec::new());
        for d in (0..n).filter(|&d| info[d] * angle * angle < lambda) {
            let name = m.dofs()[d].name.clone();
            if self
                .skin
                .reach
                .zero_tellable(d, angle, noise.max(1e-6), lambda)
            {
                untold.push(name);
            } else {
                never.push(name);
            }
        }
        (untold, never)
    }

    /// Model SU `u`'s count in `samples` (record SU order).
    fn skin_count(&self, samples: &[SampleCount], u: usize) -> Option<SampleCount> {
        self.columns.sus[u].and_then(|c| samples.get(c).copied())
    }

    fn verdict(
        &self,
        name: &str,
        u: usize,
        tally: &Tally,
        t: &test::ChangeTest,
        typical: &Typical,
        samples: Option<SampleCount>,
    ) -> SuCheck {
        let alpha = self.config.false_alarm;
        let residual_ratio = tally.residual_ratio(&t.change);
        let reads_near_zero =
            tally.blocks > 0 && tally.norm_sum / (tally.blocks as f64) < 0.3 * STANDARD_GRAVITY;
        let quiet = self.quiet[u].1 as f64 * self.period;
        let verdict = if let Some(how) = starved(samples, tally.blocks, quiet, typical.quiet) {
            let how = if how == "frozen" && reads_near_zero {
                "dead"
            } else {
                how
            };
            Verdict::Broken { how: how.into() }
        } else if reads_near_zero {
            Verdict::Broken { how: "dead".into() }
        } else if self.noise[u] > self.config.noisy * typical.noise {
            Verdict::Broken {
                how: "noisy".into(),
            }
        } else if residual_ratio > self.config.misfit
            || (9..CHANGE).any(|k| t.change[k].abs() > kin::MAX_DRIFT)
        {
            Verdict::Broken {
                how: "erratic".into(),
            }
        } else if t.p_value < alpha {
            // Which change explains it: a move alone, a bias change alone, or one of bias and
            // sensitivity. Where a bias and a move both do (a tilt on an SU whose gravity never
            // turns), the one that leaves less; a move before a drift that explains it too (on
            // such an SU a sensitivity reads much as a tilt or a shift along its lever); a drift
            // where no move does and it leaves less.
            let [moved, biased, drifted] = t.left_by.map(|(stat, dof)| test::survival(stat, dof));
            if biased >= alpha && biased >= moved {
                Verdict::BiasChanged
            } else if moved < alpha && drifted > moved {
                Verdict::ScaleChanged
            } else {
                Verdict::Moved
            }
        } else if t.untold.iter().any(|&x| x) {
            Verdict::NotEnoughMotion
        } else {
            Verdict::Unchanged
        };
        let untold = self.untold(u, t);
        let sd = |k: usize| t.covariance[(k, k)].sqrt();
        let change = SuChange {
            shift: [t.change[0], t.change[1], t.change[2]],
            shift_sd: Some([sd(0), sd(1), sd(2)]),
            turn: [t.change[3], t.change[4], t.change[5]],
            turn_sd: Some([sd(3), sd(4), sd(5)]),
            bias: [t.change[6], t.change[7], t.change[8]],
            bias_sd: Some([sd(6), sd(7), sd(8)]),
            scale: [t.change[9], t.change[10], t.change[11]],
            scale_sd: Some([sd(9), sd(10), sd(11)]),
        };
        SuCheck {
            su: name.to_string(),
            verdict,
            blocks: tally.blocks,
            samples,
            noise_sd: self.noise[u],
            statistic: t.statistic,
            dof: t.dof,
            p_value: t.p_value,
            residual_ratio,
            change: (tally.blocks > 0).then_some(change),
            untold,
            never_told: String::new(),
            or_zero: None,
            refit: None,
            advice: String::new(),
        }
    }

    /// What of SU `u`'s place the log does not tell, and the DoFs whose motion would (those
    /// whose motion alone gives at least a tenth of the most any one gives in those directions).
    fn untold(&self, u: usize, t: &test::ChangeTest) -> String {
        let parts: Vec<&str> = ["position", "orientation", "bias", "sensitivity"]
            .iter()
            .zip(&t.untold)
            .filter(|(_, &x)| x)
            .map(|(n, _)| *n)
            .collect();
        if parts.is_empty() {
            return String::new();
        }
        let score: Vec<(usize, f64)> = self.skin.reach.by_dof[u]
            .iter()
            .map(|(d, info)| {
                let s = t.untold_directions.iter().map(|e| e.dot(&(info * e))).sum();
                (*d, s)
            })
            .collect();
        let top = score.iter().map(|x| x.1).fold(0.0, f64::max);
        let dofs = self.skin.robot.model.dof_names();
        let names: Vec<&str> = score
            .iter()
            .filter(|(_, s)| *s >= 0.1 * top && *s > 0.0)
            .map(|(d, _)| dofs[*d].as_str())
            .collect();
        format!(
            "{} not told by this log: motion of {} would tell",
            parts.join(", "),
            names.join(", ")
        )
    }
}

/// What the skin's SUs typically show, against which one SU is judged broken.
struct Typical {
    /// The median block noise, m/s².
    noise: f64,
    /// The median of each SU's longest stretch without a fresh reading, s.
    quiet: f64,
}

/// Two SUs whose readings over rich motion lie further apart than this (RMS, m/s²) are told
/// apart by the check: a difference so large is no small change.
const ALIKE_GATE: f64 = 1.0;

/// How long an SU may go without a fresh reading, while the rest of the skin sends, before it is
/// taken for broken, s.
const STARVED: f64 = 5.0;

/// Why an SU gave no fresh reading for `quiet` seconds (`fresh`: blocks in which it gave one),
/// when the typical SU's longest such stretch is `typical`: `frozen` when it sent one value over
/// and over for most of that time (a board that stopped measuring, its port sending its last
/// value), `railed` when its samples were at the accelerometer's range, `silent` otherwise (no
/// samples, or not counted). `None` for an SU that gave enough.
fn starved(
    samples: Option<SampleCount>,
    fresh: usize,
    quiet: f64,
    typical: f64,
) -> Option<&'static str> {
    if fresh > 0 && (quiet < STARVED || quiet < 10.0 * typical) {
        return None;
    }
    let Some(c) = samples.filter(|c| c.sent > 0) else {
        return Some("silent");
    };
    Some(if c.longest_unusable >= 0.5 * quiet {
        "railed"
    } else if c.longest_repeat >= 0.5 * quiet {
        "frozen"
    } else {
        "silent"
    })
}

/// The median of `x` (0 for none).
fn median(mut x: Vec<f64>) -> f64 {
    x.retain(|v| v.is_finite());
    if x.is_empty() {
        return 0.0;
    }
    x.sort_by(f64::total_cmp);
    x[x.len() / 2]
}

/// Checks a calibrated model against a motion record of any motion of the robot: each SU's
/// noise (the record's, or from its residuals' differences), every block summed, small changes
/// tested, and the SUs no small change explains matched and fitted anew (`refit::explain`).
///
/// ```
/// use skincal::check::{check_skin, recalibrate, CheckConfig, Verdict};
/// use skincal::estimate::body::calibrate_body;
/// use skincal::estimate::ml::MlConfig;
/// use skincal::explore::{explore, ExploreConfig};
/// use skincal::ingest::{motion::motion_record_from, IngestConfig};
/// use skincal::log::{LogSource, MemoryLog};
/// use skincal::model::presets;
/// use skincal::plan::{Plan, PlanConfig, PlanDof};
/// use skincal::sim::changes::SkinChange;
/// use skincal::sim::timeseries::{record, LogConfig};
/// use skincal::sim::{simulate, SimulationConfig};
///
/// // Calibrated once, from the simulated experiments.
/// let robot = presets::find("paper-7dof").unwrap().robot().unwrap();
/// let set = simulate(&robot, &SimulationConfig::default()).unwrap().measurements;
/// let structure = explore(&set, &ExploreConfig::default()).unwrap();
/// let model = calibrate_body(&set, Some(&structure), &MlConfig::default(), None).unwrap();
///
/// // Later, su5 has shifted 2 cm on its segment, and the robot moves as it likes for 20 s.
/// let moved = SkinChange::Move { su: "su5".into(), shift: [0.02, 0.0, 0.0], turn: [0.0; 3] };
/// let changed = moved.robot(&robot).unwrap();
/// let plan = Plan::new(PlanDof::from_robot(&robot), &PlanConfig::continuous()).unwrap();
/// let mut log = MemoryLog::new("ordinary motion");
/// record(&changed, &plan, &LogConfig::default(), &mut log, &mut |_| {}).unwrap();
/// let (dofs, sus) = (robot.model.dof_names(), robot.model.su_names());
/// let logs = [LogSource::Memory(log)];
/// let config = IngestConfig::default();
/// let motion = motion_record_from(&logs, &dofs, &sus, &config, &mut |_, _, _| {}).unwrap();
///
/// let report = check_skin(&model, &motion, &CheckConfig::default()).unwrap();
/// for su in &report.sus {
///     assert_eq!(su.verdict == Verdict::Moved, su.su == "su5", "{}: {:?}", su.su, su.verdict);
/// }
/// // Only su5 is fitted again, from the same motion.
/// let (_, changes) = recalibrate(&model, &motion, &report, &CheckConfig::default()).unwrap();
/// assert_eq!(changes.len(), 1);
/// ```
pub fn check_skin(
    model: &BodyModel,
    record: &MotionRecord,
    config: &CheckConfig,
) -> Result<CheckReport, CheckError> {
    record.check().map_err(CheckError::Record)?;
    let skin = Skin::new(model, config)?;
    let columns = Columns::new(&skin, &record.dofs, &record.sus)?;
    let noise = refit::block_noise(&columns, record);
    let mut check = SkinCheck::new(skin, columns, noise, *config);
    for run in &record.runs {
        check.feed(run, record.period);
    }
    let mut report = check.verdicts(&record.samples);
    conclude(&check, record, &mut report);
    Ok(report)
}

/// The verdicts of `check` finished: the SUs no small change explains matched and fitted anew on
/// `record` (its recent blocks), what to do about each, remarks on the whole.
fn conclude(check: &SkinCheck, record: &MotionRecord, report: &mut CheckReport) {
    refit::explain(check, record, report);
    for su in &mut report.sus {
        su.advice = advice(&check.skin, &su.verdict);
        if su.verdict != Verdict::Moved {
            su.or_zero = None;
        }
        if let Some(zero) = &su.or_zero {
            su.advice += &format!(
                "; or the zero of {} moved by {:.2}° (an encoder homed anew reads the same on this \
                 one SU): if the robot was reset, home {} again instead",
                zero.dof,
                zero.offset.to_degrees(),
                zero.dof
            );
        }
    }
    if report.sus.len() >= 4 && report.changed().count() * 2 > report.sus.len() {
        report.notes.push(
            "more than half the SUs disagree with the model: the base may be mounted otherwise, \
             the joints' zero positions may have changed, or the log belongs to another robot"
                .into(),
        );
    }
}

/// An SU's frame on its segment as a [`Refit`]'s numbers.
fn refit_of(placement: &Isometry3<f64>, bias: [f64; 3], residual_ratio: f64) -> Refit {
    let (r, p, y) = placement.rotation.euler_angles();
    Refit {
        xyz: placement.translation.vector.into(),
        rpy: [r, p, y],
        bias,
        residual_ratio,
    }
}

/// What to do about an SU with `verdict`.
fn advice(skin: &Skin, verdict: &Verdict) -> String {
    match verdict {
        Verdict::Unchanged | Verdict::NotEnoughMotion => String::new(),
        Verdict::Moved | Verdict::BiasChanged | Verdict::ScaleChanged | Verdict::Swapped { .. } => {
            "`check --recalibrate` fits it anew from this log".into()
        }
        Verdict::ReadsAs { su } => format!(
            "its samples carry another board's id: map its port again (it reads what {su} should)"
        ),
        Verdict::OtherSegment { segment } => {
            let m = &skin.robot.model;
            let dofs = m
                .segment_index(segment)
                .map(|s| m.chain_to(s))
                .unwrap_or_default()
                .into_iter()
                .map(|d| m.dofs()[d].name.clone())
                .collect::<Vec<_>>();
            format!(
                "the tree changed: record the structure experiment for {} and calibrate that limb again",
                dofs.join(", ")
            )
        }
        Verdict::Broken { how } => match how.as_str() {
            "silent" => "the log holds (almost) no sample of it: an unplugged board or a port \
                         not mapped; check its cable and its id"
                .into(),
            "frozen" => "it sends one value over and over: its accelerometer stopped measuring; \
                         power-cycle or replace the board"
                .into(),
            "railed" => {
                "its samples are at the accelerometer's range: an axis failed or the board \
                         is loose; re-seat or replace it"
                    .into()
            }
            "dead" => "it reads near zero: replace the board".into(),
            "noisy" => {
                "it is far noisier than the rest of the skin: check its mounting and cable".into()
            }
            _ => "no place on the body explains its readings: replace or re-seat the board".into(),
        },
    }
}

/// What of an SU's place no motion tells, from the projector onto what a minute of rich motion
/// tells: the components with a share of the directions left out.
fn never_told(tellable: &test::ChangeMatrix) -> String {
    let blind = test::ChangeMatrix::identity() - tellable;
    let parts: Vec<&str> = [
        (0, "position"),
        (3, "orientation"),
        (6, "bias"),
        (9, "sensitivity"),
    ]
    .into_iter()
    .filter(|&(k, _)| (k..k + 3).any(|c| blind[(c, c)] > 0.1))
    .map(|(_, n)| n)
    .collect();
    if parts.is_empty() {
        return String::new();
    }
    format!(
        "{}: in part, no motion of this robot tells",
        parts.join(", ")
    )
}
