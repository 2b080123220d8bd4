//! Whole-body calibration: every limb of an explored structure estimated by maximum likelihood,
//! assembled into one calibrated model (`model.json`).
//!
//! **Frames.** The body's reference frame is the static reference segment's, with `z` pointing up
//! (against gravity). Each limb that starts at the reference segment has its own frame (its first
//! DoF's joint frame) and its own gravity estimate; in the body it is turned so that its gravity
//! points down. Where on the reference segment such a limb sits, and how it is turned about the
//! vertical, no accelerometer reading can tell (the reference segment never moves): those limbs
//! start at the origin with the heading the estimate gave. A limb that starts at a branching
//! segment hangs on the segment of its parent limb, fully determined. SUs on the reference segment
//! read a constant: only their tilt is known (placed at the origin, turned so that their reading
//! is gravity).
//!
//! **Order.** Each limb is searched and fitted on its own, parent first, a sub-limb with its base
//! path and gravity held at its parent's estimate; then the limbs of each tree (a limb on the
//! reference segment and every limb on it) are fitted again together ([`refine_trees`]), so that
//! a trunk's DoFs are estimated from every SU they move (`MlConfig::whole_tree`) — on a motion
//! record every tree of the body in one problem, with the skin's one delay.

use std::collections::BTreeMap;

use nalgebra::{Isometry3, UnitQuaternion, Vector3};
use serde::{Deserialize, Serialize};

use super::limb::{limb_chains, LimbChain, LimbData};
use super::ml::{
    estimate_limb, order_on_motion, refine_on_motion, refine_trees, ChainState, LimbBase,
    LimbMotion, MlChainEstimate, MlConfig,
};
use super::rescue::{self, Rescue};
use super::{chain_in_listed_order, EstimateError};
use crate::explore::{BrokenSu, Structure};
use crate::measurements::{MeasurementSet, TrainingExperiment};
use crate::model::description::RobotFile;
use crate::model::sensor::ExcitationPattern;
use crate::model::{DofSpec, Limits, PlacementSpec, Robot, RobotBuilder, SuSpec};
use crate::motion::MotionRecord;

/// Format name of a calibrated model file.
pub const MODEL_FORMAT: &str = "skincal-model";
/// Version of the calibrated model file.
pub const MODEL_VERSION: u32 = 2;

/// A rigid placement, m and rad (roll-pitch-yaw about fixed x, y, z as in URDF).
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct Frame {
    /// Translation, m.
    pub xyz: [f64; 3],
    /// Rotation, rad.
    pub rpy: [f64; 3],
}

impl Frame {
    /// From an isometry.
    pub fn from_isometry(pose: &Isometry3<f64>) -> Self {
        let (r, p, y) = pose.rotation.euler_angles();
        Self {
            xyz: pose.translation.vector.into(),
            rpy: [r, p, y],
        }
    }

    /// As an isometry.
    pub fn to_isometry(&self) -> Isometry3<f64> {
        Isometry3::from_parts(
            Vector3::from(self.xyz).into(),
            UnitQuaternion::from_euler_angles(self.rpy[0], self.rpy[1], self.rpy[2]),
        )
    }
}

/// One limb of the calibrated body.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct BodyLimb {
    /// Its name (the structure's end segment of the limb).
    pub name: String,
    /// The limb it hangs on (none: it starts at the static reference segment).
    pub parent: Option<String>,
    /// The limb's own frame (its first DoF's joint frame) in the body's reference frame.
    pub base_frame: Frame,
    /// Gravity in the body's reference frame, m/s².
    pub gravity: [f64; 3],
    /// Gravity in the body's reference frame in base orientations 1, 2, … of the training poses,
    /// m/s² (empty: every pose in the usual one).
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub other_gravities: Vec<[f64; 3]>,
    /// The DoFs it estimates, along the chain.
    pub dofs: Vec<String>,
    /// The SUs it estimates.
    pub sus: Vec<String>,
    /// The estimate in the limb's own frame: joints, SU poses, uncertainties, gauge, fit.
    pub estimate: MlChainEstimate,
}

/// An SU on the static reference segment: its reading never changes.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct StaticSu {
    /// The SU.
    pub su: String,
    /// Its mean static reading over the training poses, m/s².
    pub reading: [f64; 3],
    /// Its mean static reading in base orientations 1, 2, … of the training poses, m/s².
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub other_readings: Vec<[f64; 3]>,
}

/// A DoF or SU of the measurement set that the model does not calibrate.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct NotCalibrated {
    /// `dof` or `su`.
    pub kind: String,
    /// Its name in the measurement set.
    pub name: String,
    /// Why, in plain words.
    pub reason: String,
}

/// One change a recalibration made to a model (kept in `model.json`'s `changes`, oldest first).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(tag = "kind", rename_all = "kebab-case")]
pub enum ModelChange {
    /// An SU given a new place, bias or sensitivity.
    Su(Box<SuModelChange>),
    /// A DoF given a new zero.
    Zero {
        /// The DoF.
        dof: String,
        /// The angle added to its encoder's reading, rad.
        offset: f64,
        /// The log(s) it was found in.
        logs: Vec<String>,
    },
}

/// An SU given a new place, bias or sensitivity.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct SuModelChange {
    /// The SU.
    pub su: String,
    /// What the check found.
    pub verdict: FoundChange,
    /// The log(s) it was found in and fitted from.
    pub logs: Vec<String>,
    /// Its frame on its segment before, and after.
    pub before: Frame,
    /// After.
    pub after: Frame,
    /// Its bias before and after, m/s².
    pub bias_before: [f64; 3],
    /// After.
    pub bias_after: [f64; 3],
    /// Each axis' relative sensitivity error before and after (as `Intrinsics::scale`; absent
    /// in models written before it was recalibrated).
    #[serde(default)]
    pub scale_before: [f64; 3],
    /// After.
    #[serde(default)]
    pub scale_after: [f64; 3],
    /// RMS whitened residual of its readings in the log against its new place.
    pub residual_ratio: f64,
}

/// What a check found of an SU that a recalibration changed (its verdict, as `check` words it).
#[derive(Debug, Clone, PartialEq, Eq, Serialize, Deserialize)]
#[serde(tag = "kind", rename_all = "kebab-case")]
pub enum FoundChange {
    /// It shifted or turned on its segment.
    Moved,
    /// Its bias changed.
    BiasChanged,
    /// Its sensitivity changed (with or without its bias).
    ScaleChanged,
    /// It and `with` exchanged identities.
    Swapped {
        /// The other SU.
        with: String,
    },
}

impl FoundChange {
    /// A short word for tables.
    pub fn word(&self) -> String {
        match self {
            Self::Moved => "MOVED".into(),
            Self::BiasChanged => "BIAS CHANGED".into(),
            Self::ScaleChanged => "SCALE CHANGED".into(),
            Self::Swapped { with } => format!("SWAPPED with {with}"),
        }
    }
}

/// A calibrated body: the file `model.json`.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct BodyModel {
    /// Always [`MODEL_FORMAT`].
    pub format: String,
    /// Always [`MODEL_VERSION`].
    pub version: u32,
    /// The estimator (`ml`).
    pub method: String,
    /// Noise standard deviation assumed, m/s².
    pub noise_sd: f64,
    /// The excitation pattern of the training data (what `predict` uses by default).
    pub pattern: ExcitationPattern,
    /// The static reference segment.
    pub reference: String,
    /// The whole calibrated body as a robot description (body reference frame, z up).
    pub robot: RobotFile,
    /// Limbs, every one after the limb it hangs on.
    pub limbs: Vec<BodyLimb>,
    /// SUs on the static reference segment.
    pub static_sus: Vec<StaticSu>,
    /// SUs that the calibration found broken and set aside.
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub broken: Vec<BrokenSu>,
    /// DoFs and SUs of the measurement set that are not calibrated, and why: their readings and
    /// angles do not enter, and a pose may give any value for such a DoF.
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub not_calibrated: Vec<NotCalibrated>,
    /// What `skincal check --recalibrate` changed since the calibration, oldest first.
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub changes: Vec<ModelChange>,
}

impl BodyModel {
    /// Checks the format and version and that the robot description builds.
    pub fn check(&self) -> Result<Robot, String> {
        if self.format != MODEL_FORMAT || self.version != MODEL_VERSION {
            return Err(format!(
                "`format`/`version` are {:?}/{}, expected {MODEL_FORMAT:?}/{MODEL_VERSION} (a model written by `skincal calibrate`)",
                self.format, self.version
            ));
        }
        if !self.pattern.is_valid() {
            return Err("`pattern`: amplitude and frequency must be positive".into());
        }
        self.robot.build().map_err(|e| format!("`robot`: {e}"))
    }

    /// Gravity (body frame) that each SU of the model reads, by SU name.
    pub fn gravity_by_su(&self) -> BTreeMap<String, Vector3<f64>> {
        self.gravity_by_su_in(0)
    }

    /// Gravity (body frame) that each SU of the model reads in base orientation `o` of its
    /// training poses (0: the usual one), by SU name; an SU whose calibration had no pose in
    /// that orientation is left out.
    pub fn gravity_by_su_in(&self, o: usize) -> BTreeMap<String, Vector3<f64>> {
        let mut out = BTreeMap::new();
        for limb in &self.limbs {
            let gravity = match o {
                0 => Some(limb.gravity),
                _ => limb.other_gravities.get(o - 1).copied(),
            };
            for su in gravity.iter().flat_map(|_| &limb.sus) {
                out.insert(su.clone(), Vector3::from(gravity.unwrap_or_default()));
            }
        }
        for s in &self.static_sus {
            let usual = Vector3::from(s.reading);
            let read = match o {
                0 => Some(usual),
                _ => s.other_readings.get(o - 1).map(|r| Vector3::from(*r)),
            };
            // The SU sits turned so that its usual reading points along z (`assemble`).
            let turn = turn_onto(&usual, &Vector3::z());
            if let Some(read) = read {
                out.insert(s.su.clone(), -(turn * read));
            }
        }
        out
    }
}

/// Calibrates every limb of `structure` (or, without one, the DoFs of the set in listed order as
/// one chain with one SU per segment). With `only`, just that limb and the limbs it hangs on.
/// SUs whose readings the fit cannot explain are set aside (see [`calibrate_body_keeping`]).
///
/// ```
/// use skincal::estimate::{body::calibrate_body, ml::MlConfig};
/// use skincal::explore::{explore, ExploreConfig};
/// use skincal::model::presets;
/// use skincal::sim::{simulate, SimulationConfig};
///
/// let robot = presets::find("paper-7dof").unwrap().robot().unwrap();
/// let set = simulate(&robot, &SimulationConfig::default()).unwrap().measurements;
/// let structure = explore(&set, &ExploreConfig::default()).unwrap();
/// let model = calibrate_body(&set, Some(&structure), &MlConfig::default(), None).unwrap();
/// assert_eq!(model.limbs.len(), 1);
/// assert!(model.limbs[0].estimate.converged);
/// assert_eq!(model.robot.dofs.len(), 7);
/// ```
pub fn calibrate_body(
    set: &MeasurementSet,
    structure: Option<&Structure>,
    config: &MlConfig,
    only: Option<&str>,
) -> Result<BodyModel, EstimateError> {
    calibrate_body_keeping(set, structure, config, only, &[])
}

/// [`calibrate_body`], keeping the SUs of `keep` in the fit whatever their residuals.
///
/// An SU whose residual is more than [`MISFIT_RATIO`] times the noise and twice its limb's median
/// SU is broken: if its readings with one axis negated fit at the noise level, its frame is
/// improper (swapped or negated axes); otherwise it is noisy or loose. Either way the limb is
/// fitted again without it (unless it is the only SU of its segment), worst first.
pub fn calibrate_body_keeping(
    set: &MeasurementSet,
    structure: Option<&Structure>,
    config: &MlConfig,
    only: Option<&str>,
    keep: &[String],
) -> Result<BodyModel, EstimateError> {
    calibrate_body_reporting(set, structure, config, only, keep, &mut |_, _, _| {})
}

/// [`calibrate_body_keeping`], calling `progress(limb, done, total)` as each limb is calibrated.
pub fn calibrate_body_reporting(
    set: &MeasurementSet,
    structure: Option<&Structure>,
    config: &MlConfig,
    only: Option<&str>,
    keep: &[String],
    progress: &mut dyn FnMut(&str, usize, usize),
) -> Result<BodyModel, EstimateError> {
    calibrate_body_on(set, None, structure, config, only, keep, progress)
}

/// [`calibrate_body_reporting`], each limb then fitted again on every sample of `motion` (the
/// motion record of the logs `set` was ingested from; see [`refine_on_motion`]), with the skin's
/// delay behind the joint states.
///
/// A set with fewer than [`MIN_POSES`] training poses (a continuous program, a log of ordinary
/// work, servos that never came to rest at the poses: ingest finds too few readings) starts from
/// [`QUIET_POSES`] of the record's quietest moments and the structure experiment's holds instead
/// ([`super::quiet::quiet_set`]: static readings, weighted by what the motion there could add to
/// gravity); the poses it has are in the record.
/// Without a structure part, the tree must come from an earlier structure experiment.
pub fn calibrate_body_on_motion(
    set: &MeasurementSet,
    motion: &MotionRecord,
    structure: Option<&Structure>,
    config: &MlConfig,
    only: Option<&str>,
    keep: &[String],
    progress: &mut dyn FnMut(&str, usize, usize),
) -> Result<BodyModel, EstimateError> {
    motion.check().map_err(EstimateError::InvalidStructure)?;
    if !starts_from_quiet(set) {
        return calibrate_body_on(set, Some(motion), structure, config, only, keep, progress);
    }
    if motion.dofs != set.dofs || motion.sus != set.sus {
        return Err(EstimateError::InvalidStructure(
            "the motion record names other DoFs or SUs than the measurement set: ingest both \
             from the same logs"
                .into(),
        ));
    }
    let quiet = super::quiet::quiet_set(set, motion);
    // The quiet readings' deviations are what weighs them, whatever weighs the rest.
    let config = MlConfig {
        reading_sd: true,
        ..*config
    };
    calibrate_body_on(
        &quiet,
        Some(motion),
        structure,
        &config,
        only,
        keep,
        progress,
    )
}

pub use super::quiet::QUIET_POSES;

/// The fewest training poses the readings' fit starts from: a DoF's axis and its joint's place
/// take three poses whatever the number of SUs.
pub const MIN_POSES: usize = 3;

/// The number of training poses of `set`.
pub fn training_poses(set: &MeasurementSet) -> usize {
    set.training.as_ref().map_or(0, |t| t.poses.len())
}

/// Whether a fit on a motion record starts from the record's quiet moments rather than from the
/// set's training poses: the set has fewer than [`MIN_POSES`].
pub fn starts_from_quiet(set: &MeasurementSet) -> bool {
    training_poses(set) < MIN_POSES
}

fn calibrate_body_on(
    set: &MeasurementSet,
    motion: Option<&MotionRecord>,
    structure: Option<&Structure>,
    config: &MlConfig,
    only: Option<&str>,
    keep: &[String],
    progress: &mut dyn FnMut(&str, usize, usize),
) -> Result<BodyModel, EstimateError> {
    let model = calibrate_limbs(set, motion, structure, config, only, keep, progress)?;
    if !config.select_intrinsics {
        return Ok(model);
    }
    // One skin, one sensor model: the limbs' tests pooled decide it, so that a limb with few SUs
    // (a trunk, whose estimate the limbs on it hold) is not left to decide alone. A limb whose
    // fit ended off the noise level is left out (its misfit is what a larger sensor model would
    // take up: a TALOS arm at 17 σ made a clean skin's pooled test take bias and scale with
    // z = 84), unless no limb converged.
    let any_converged = model.limbs.iter().any(|l| l.estimate.converged);
    let pooled_in = |l: &BodyLimb| l.estimate.converged || !any_converged;
    let left_out: Vec<String> = model
        .limbs
        .iter()
        .filter(|l| !pooled_in(l) && !l.estimate.intrinsics_tests.is_empty())
        .map(|l| l.name.clone())
        .collect();
    let Some((chosen, pooled)) = super::ml::pooled_intrinsics(
        model
            .limbs
            .iter()
            .filter(|l| pooled_in(l))
            .map(|l| l.estimate.intrinsics_tests.as_slice()),
    ) else {
        return Ok(model);
    };
    let mut model = if model
        .limbs
        .iter()
        .all(|l| l.estimate.intrinsics_model == Some(chosen))
    {
        model
    } else {
        let fixed = MlConfig {
            intrinsics: chosen,
            select_intrinsics: false,
            ..*config
        };
        calibrate_limbs(set, motion, structure, &fixed, only, keep, progress)?
    };
    for limb in &mut model.limbs {
        limb.estimate.intrinsics_model = Some(chosen);
        limb.estimate.intrinsics_tests.clone_from(&pooled);
        limb.estimate.intrinsics_left_out.clone_from(&left_out);
    }
    Ok(model)
}

/// Every limb of the body in parent-first order with `config` as it is (see
/// [`calibrate_body_on`]): each limb searched and fitted on its parent's base path, rescued
/// where it does not converge (with its parent, or with its path free; a parent with its
/// children), its misfit SUs set aside, fitted on every sample of `motion`; then each tree's
/// limbs fitted together (with `whole_tree`), the reference segment's SUs and the model.
fn calibrate_limbs(
    set: &MeasurementSet,
    motion: Option<&MotionRecord>,
    structure: Option<&Structure>,
    config: &MlConfig,
    only: Option<&str>,
    keep: &[String],
    progress: &mut dyn FnMut(&str, usize, usize),
) -> Result<BodyModel, EstimateError> {
    let plain;
    let set = if config.reading_sd {
        set
    } else {
        plain = set.without_uncertainties();
        &plain
    };
    let chains = limbs_to_calibrate(set, structure, only)?;
    let training = set.training.as_ref().ok_or(EstimateError::NoTrainingData)?;
    let mut fitted = Fitted::default();
    for chain in &chains {
        fitted.add(set, chain, &chains, motion, config, keep)?;
        let done = fitted.estimates.last().expect("just added");
        progress(&done.chain.name, fitted.estimates.len(), chains.len());
    }
    let static_sus = structure.map_or_else(Vec::new, |s| reference_sus(set, s, training, config));
    let reference = structure.map_or_else(|| "reference".to_string(), |s| s.root.clone());
    let Fitted {
        mut estimates,
        parents,
        broken,
    } = fitted;
    if config.whole_tree {
        refine_trees(&mut estimates, &parents, config)?;
    }
    // The final problems (each limb's data and readings, kept for the tree's fit) are not part
    // of the model: the model does not carry a copy of the measurement set.
    for estimate in &mut estimates {
        estimate.problem = Default::default();
    }
    let parents = parents
        .iter()
        .map(|p| p.map(|p| estimates[p].chain.name.clone()))
        .collect();
    let not_calibrated = left_out(set, structure, &estimates, &static_sus, only, &broken);
    let mut model = assemble(
        set,
        &reference,
        estimates,
        parents,
        static_sus,
        config,
        training.pattern,
    );
    model.not_calibrated = not_calibrated;
    model.broken = broken;
    Ok(model)
}

/// The limbs to calibrate, parent first: the structure's (or the set's listed chain), with
/// `only` those on the way to the limb it names.
fn limbs_to_calibrate(
    set: &MeasurementSet,
    structure: Option<&Structure>,
    only: Option<&str>,
) -> Result<Vec<LimbChain>, EstimateError> {
    let mut chains = match structure {
        Some(s) => limb_chains(s)?,
        None => vec![chain_in_listed_order(set)?],
    };
    if let Some(name) = only {
        let target = chains
            .iter()
            .find(|c| c.name == name)
            .cloned()
            .ok_or_else(|| EstimateError::UnknownLimb {
                limb: name.into(),
                known: chains
                    .iter()
                    .map(|c| c.name.clone())
                    .collect::<Vec<_>>()
                    .join(", "),
            })?;
        chains.retain(|c| {
            c.joints.len() <= target.joints.len()
                && c.joints
                    .iter()
                    .zip(&target.joints)
                    .all(|(a, b)| a.id == b.id)
        });
    }
    if chains.is_empty() {
        return Err(EstimateError::InvalidStructure(
            "it has no limbs: there is nothing to calibrate".into(),
        ));
    }
    Ok(chains)
}

/// The limbs fitted so far, parent first: their estimates, each one's parent limb, and the SUs
/// set aside.
#[derive(Default)]
struct Fitted {
    estimates: Vec<MlChainEstimate>,
    parents: Vec<Option<usize>>,
    broken: Vec<BrokenSu>,
}

impl Fitted {
    /// Limb `chain` (one of `chains`, every limb it hangs on already fitted) searched and fitted on
    /// its parent's base path, rescued where it does not converge (with its parent, or with its
    /// path free; as a parent, with its children), its misfit SUs set aside (`keep` excepted),
    /// then fitted on every sample of `motion`.
    fn add(
        &mut self,
        set: &MeasurementSet,
        chain: &LimbChain,
        chains: &[LimbChain],
        motion: Option<&MotionRecord>,
        config: &MlConfig,
        keep: &[String],
    ) -> Result<(), EstimateError> {
        let mut chain = chain.clone();
        // SUs set aside in a parent limb stay out of its sub-limbs' base path.
        for j in &mut chain.joints {
            j.sus.retain(|su| !self.broken.iter().any(|b| b.su == *su));
        }
        let parent = self.parent_of(&mut chain)?;
        let base_dofs = chain.base_dofs();
        let mut base = parent.and_then(|p| LimbBase::of(&self.estimates[p], base_dofs));
        // On a parent's path, the rescues come before the limb's own retries (`rescue`).
        let first_config = MlConfig {
            limb_retries: config.limb_retries && parent.is_none(),
            ..*config
        };
        let mut first = estimate_limb(&LimbData::new(set, &chain)?, base.as_ref(), &first_config)?;
        if let (false, Some(p)) = (config.search_done(&first, parent.is_some()), parent) {
            let (estimates, parents) = (&mut self.estimates, &self.parents);
            match rescue::with_parent(set, &chain, &mut first, (estimates, parents, p), config)? {
                Rescue::None => {}
                Rescue::PathFree => chain = first.chain.clone(),
                Rescue::ParentReplaced => {
                    chain = first.chain.clone();
                    base = LimbBase::of(&self.estimates[p], base_dofs);
                }
            }
            if config.limb_retries && !config.search_done(&first, true) {
                first = rescue::with_own_retries(set, &chain, first, base.as_ref(), config)?;
            }
        }
        let broken = &mut self.broken;
        let estimate = set_aside_misfits(set, chain, base.as_ref(), config, first, keep, broken)?;
        let on = parent.map(|p| &self.estimates[p]);
        let mut estimate = rescue::with_children(set, estimate, on, chains, config)?;
        if let Some(record) = motion {
            estimate = on_motion(set, record, estimate, base.as_ref(), config)?;
        }
        self.estimates.push(estimate);
        self.parents.push(parent);
        Ok(())
    }

    /// The limb `chain` hangs on (none for a limb from the reference), its base path given the
    /// DoF order the parent's estimate found.
    fn parent_of(&self, chain: &mut LimbChain) -> Result<Option<usize>, EstimateError> {
        if chain.base_joints == 0 {
            return Ok(None);
        }
        let found = self.estimates.iter().position(|e| {
            e.chain.joints.len() == chain.base_joints
                && e.chain
                    .joints
                    .iter()
                    .zip(&chain.joints)
                    .all(|(a, b)| a.id == b.id)
        });
        let Some(p) = found else {
            return Err(EstimateError::UnsupportedLimb {
                limb: chain.name.clone(),
                reason: "no limb ends at its base segment".into(),
            });
        };
        for j in 0..chain.base_joints {
            chain.joints[j].dofs = self.estimates[p].chain.joints[j].dofs.clone();
        }
        Ok(Some(p))
    }
}

/// The SUs on the reference segment of `structure`: each one's robust mean static reading.
fn reference_sus(
    set: &MeasurementSet,
    structure: &Structure,
    training: &TrainingExperiment,
    config: &MlConfig,
) -> Vec<StaticSu> {
    let Some(root) = structure.segment(&structure.root) else {
        return Vec::new();
    };
    root.sus
        .iter()
        .filter_map(|su| {
            let u = set.sus.iter().position(|n| n == su)?;
            let mean_in = |o: usize| {
                let readings: Vec<Vector3<f64>> = training
                    .poses
                    .iter()
                    .filter(|p| p.orientation == o)
                    .map(|p| Vector3::from(p.static_readings[u]))
                    .collect();
                robust_mean(&readings, 6.0 * config.noise_sd).into()
            };
            let orientations = training.poses.iter().map(|p| p.orientation).max();
            Some(StaticSu {
                su: su.clone(),
                reading: mean_in(0),
                other_readings: (1..=orientations.unwrap_or(0)).map(mean_in).collect(),
            })
        })
        .collect()
}

/// A limb's estimate fitted again on every sample of `record`, from where the readings' fit
/// ended; the search's record (orders tried, retries) is kept.
///
/// Readings may not tell the search's end states apart: where the fit from the kept one ends off
/// the noise level, each runner-up ([`MlChainEstimate::runner_ups`]) is led to the motion in turn
/// until one reaches it, and the best fit is kept. From static readings alone (a record's quiet
/// moments), a head on a humanoid's trunk from a continuous program ended at 30 σ from the one
/// and at the noise level from the other, whose readings fit 0.2 worse in χ²; with dynamic
/// readings from one upright log, whose vertical axes leave them less to tell, the short
/// program's humanoid neck ended at 8.5 σ from the one and at 1.0 σ from the other.
fn on_motion(
    set: &MeasurementSet,
    record: &MotionRecord,
    estimate: MlChainEstimate,
    base: Option<&LimbBase>,
    config: &MlConfig,
) -> Result<MlChainEstimate, EstimateError> {
    let data = LimbData::new(set, &estimate.chain)?;
    let (mut estimate, data) = order_on_motion(&data, base, estimate, record, config)?;
    let Some(start) = estimate.state.clone() else {
        return Ok(estimate);
    };
    // The intrinsics the readings chose: the motion's thousands of rows would take a larger
    // model for the smallest misfit of the signal chain, and pay for it in variance.
    let config = match estimate.intrinsics_model {
        Some(model) if config.select_intrinsics && !data.static_only() => MlConfig {
            intrinsics: model,
            select_intrinsics: false,
            ..*config
        },
        _ => *config,
    };
    // Each fit takes the limb's motion (built again for each: held twice, a long record's would
    // double the memory).
    let refine = |start: ChainState| {
        let motion = LimbMotion::new(record, &data, config.noise_sd)?;
        refine_on_motion(&data, base, start, motion, &config)
    };
    let mut best = refine(start)?;
    if best.converged {
        return Ok(best.after(estimate));
    }
    // What the fits not kept took is counted with the one kept.
    let (mut iterations, mut seconds) = (0, 0.0);
    for (k, runner_up) in std::mem::take(&mut estimate.runner_ups)
        .into_iter()
        .enumerate()
    {
        let mut other = refine(runner_up)?;
        estimate.retries.push(format!(
            "the search's runner-up {} led to the motion: residual {:.2} σ (was {:.2} σ)",
            k + 1,
            other.residual_ratio,
            best.residual_ratio
        ));
        if other.residual_ratio < best.residual_ratio {
            std::mem::swap(&mut best, &mut other);
        }
        iterations += other.iterations;
        seconds += other.seconds;
        if best.converged {
            break;
        }
    }
    best.iterations += iterations;
    best.seconds += seconds;
    Ok(best.after(estimate))
}

/// A residual this many times the noise, and twice the limb's median SU's, marks a broken SU.
pub const MISFIT_RATIO: f64 = 3.0;
/// A fitted relative scale error beyond this marks a broken SU (real parts err by a few %).
const MAX_SCALE_ERROR: f64 = 0.5;
/// Most SUs set aside per limb.
const MAX_SET_ASIDE: usize = 3;

/// Sets aside, worst first, the SUs of `estimate` whose residuals are far above the others' (see
/// [`calibrate_body_keeping`]), fitting the limb again each time; returns the final estimate and
/// adds what it found to `broken`.
fn set_aside_misfits(
    set: &MeasurementSet,
    mut chain: LimbChain,
    base: Option<&LimbBase>,
    config: &MlConfig,
    mut estimate: MlChainEstimate,
    keep: &[String],
    broken: &mut Vec<BrokenSu>,
) -> Result<MlChainEstimate, EstimateError> {
    for _ in 0..MAX_SET_ASIDE {
        let Some(misfit) = Misfit::worst(&estimate, keep) else {
            break;
        };
        let su = estimate.chain.sus()[misfit.u].clone();
        // The only SU of its segment carries the segment: it stays.
        let Some(joint) = chain.joints.iter().position(|j| j.sus.contains(&su)) else {
            break;
        };
        if chain.joints[joint].sus.len() < 2 {
            break;
        }
        let fit = LimbFit {
            set,
            chain: &chain,
            base,
            config,
        };
        let (kind, detail) = misfit.diagnose(&fit, joint, &su);
        broken.push(BrokenSu {
            su: su.clone(),
            kind: kind.into(),
            detail,
        });
        chain.joints[joint].sus.retain(|s| *s != su);
        estimate = estimate_limb(&LimbData::new(set, &chain)?, base, config)?;
    }
    Ok(estimate)
}

/// A limb's fit as the misfit tests run it again: its set, chain, base and settings.
struct LimbFit<'a> {
    set: &'a MeasurementSet,
    chain: &'a LimbChain,
    base: Option<&'a LimbBase>,
    config: &'a MlConfig,
}

/// The SU of a limb's estimate whose readings the fit explains worst, with what tells why.
struct Misfit {
    /// Its index in the estimate's SUs.
    u: usize,
    /// Its residual over the noise, and the limb's median SU's.
    ratio: f64,
    median: f64,
    /// Its fitted sensitivities less 1 (zero without fitted scales).
    scale: [f64; 3],
}

impl Misfit {
    /// The worst SU of `estimate` not in `keep` whose residual is more than [`MISFIT_RATIO`]
    /// times the noise and twice its limb's median SU's, or whose sensitivity is far from 1 (a
    /// negative one is an axis that reads mirrored: an improper frame the scale absorbed).
    fn worst(estimate: &MlChainEstimate, keep: &[String]) -> Option<Self> {
        let sus = estimate.chain.sus();
        let ratios = &estimate.su_residual_ratio;
        let mut sorted = ratios.clone();
        sorted.sort_by(f64::total_cmp);
        let median = *sorted.get(sorted.len() / 2)?;
        let scale = |u: usize| {
            estimate
                .intrinsics
                .iter()
                .find(|i| i.su == sus[u])
                .map_or([0.0; 3], |i| i.value.scale)
        };
        let odd_scale = |u: usize| scale(u).iter().any(|s| s.abs() > MAX_SCALE_ERROR);
        let u = (0..sus.len())
            .filter(|&u| odd_scale(u) || (ratios[u] > MISFIT_RATIO && ratios[u] > 2.0 * median))
            .filter(|&u| !keep.contains(&sus[u]))
            .max_by(|&a, &b| {
                (odd_scale(a), ratios[a])
                    .partial_cmp(&(odd_scale(b), ratios[b]))
                    .unwrap_or(std::cmp::Ordering::Equal)
            })?;
        Some(Self {
            u,
            ratio: ratios[u],
            median,
            scale: scale(u),
        })
    }

    /// What is wrong with the SU `su` of joint `joint` of `fit`'s chain, and the words that say
    /// it: an improper frame (a sensitivity negative, or its readings with one axis negated
    /// fitting at the noise level), a scale far from 1, a segment of the limb other than the
    /// structure's on which it fits at the noise level, else noise.
    fn diagnose(&self, fit: &LimbFit, joint: usize, su: &str) -> (&'static str, String) {
        let LimbFit {
            set,
            chain,
            base,
            config,
        } = *fit;
        let ratio = self.ratio;
        let negated: Vec<&str> = (0..3)
            .filter(|&k| 1.0 + self.scale[k] < 0.0)
            .map(|k| ["x", "y", "z"][k])
            .collect();
        let sensitivities = self
            .scale
            .iter()
            .map(|s| format!("{:+.2}", 1.0 + s))
            .collect::<Vec<_>>()
            .join(", ");
        // Does a reflection explain it? Its readings with z negated, fitted again (only asked
        // when the fitted sensitivities do not already tell).
        let reflected = || {
            LimbData::new(&mirror_su(set, su), chain)
                .and_then(|data| estimate_limb(&data, base, config))
                .ok()
                .and_then(|e| e.su_residual_ratio.get(self.u).copied())
        };
        if !negated.is_empty() {
            (
                "improper frame",
                format!(
                    "its {} axis reads mirrored (fitted sensitivity {sensitivities}): its axes form a left-handed frame (two axes swapped or one negated by wiring or mounting; a rotation of the frame absorbs which)",
                    negated.join(" and "),
                ),
            )
        } else if self.scale.iter().any(|s| s.abs() > MAX_SCALE_ERROR) {
            (
                "scale",
                format!(
                    "its fitted sensitivities ({sensitivities}) are far from 1: a wrong range setting or a faulty part"
                ),
            )
        } else if let Some((segment, r)) = fits_elsewhere(set, chain, joint, su, base, config) {
            (
                "misplaced",
                format!(
                    "its readings fit {ratio:.1}× the noise on segment {} where the structure puts it, but {r:.2}× on segment {segment}: the tree is wrong for this SU (check its row of the activity matrix, or record its structure moves again and explore)",
                    chain.joints[joint].segment
                ),
            )
        } else if let Some(r) = reflected().filter(|&r| r < config.converged_ratio) {
            (
                "improper frame",
                format!(
                    "its readings fit {ratio:.1}× the noise, but {r:.2}× with one axis negated: its axes form a left-handed frame (two axes swapped or one negated by wiring or mounting; which ones no reading can tell, a rotation of the frame absorbs the rest)"
                ),
            )
        } else {
            (
                "noisy",
                format!(
                    "its readings fit {ratio:.1}× the noise while its limb's SUs fit {:.1}× (a noisy, loose or intermittent sensor)",
                    self.median
                ),
            )
        }
    }
}

/// The segment of `chain` (other than its joint `joint`'s) on which SU `su` fits at the noise
/// level, and its residual there: the limb fitted again with the SU moved to each of the others
/// (the one it fits best, if any fits). A wrong tree for one SU then reads as what it is, not as
/// a noisy sensor.
fn fits_elsewhere(
    set: &MeasurementSet,
    chain: &LimbChain,
    joint: usize,
    su: &str,
    base: Option<&LimbBase>,
    config: &MlConfig,
) -> Option<(String, f64)> {
    (chain.base_joints..chain.joints.len())
        .filter(|&j| j != joint)
        .filter_map(|j| {
            let mut moved = chain.clone();
            moved.joints[joint].sus.retain(|s| s != su);
            moved.joints[j].sus.push(su.to_string());
            let e = estimate_limb(&LimbData::new(set, &moved).ok()?, base, config).ok()?;
            let at = e.chain.sus().iter().position(|s| s == su)?;
            let r = *e.su_residual_ratio.get(at)?;
            (e.converged && r < config.converged_ratio)
                .then(|| (moved.joints[j].segment.clone(), r))
        })
        .min_by(|a, b| a.1.total_cmp(&b.1))
}

/// `set` with SU `su`'s training readings mirrored (z negated).
fn mirror_su(set: &MeasurementSet, su: &str) -> MeasurementSet {
    let mut out = set.clone();
    let Some(u) = set.sus.iter().position(|s| s == su) else {
        return out;
    };
    if let Some(t) = &mut out.training {
        for pose in &mut t.poses {
            pose.static_readings[u][2] = -pose.static_readings[u][2];
            for readings in pose.dynamic.values_mut() {
                readings[u][2] = -readings[u][2];
            }
        }
    }
    out
}

/// Every DoF and SU of `set` that no estimate and no static SU covers, with the reason the
/// structure gives (the diagnostic that names it) or the limb selection.
fn left_out(
    set: &MeasurementSet,
    structure: Option<&Structure>,
    estimates: &[MlChainEstimate],
    static_sus: &[StaticSu],
    only: Option<&str>,
    broken: &[BrokenSu],
) -> Vec<NotCalibrated> {
    use crate::explore::DiagnosticKind as K;
    let dofs: Vec<String> = estimates.iter().flat_map(|e| e.chain.dofs()).collect();
    let sus: Vec<String> = estimates
        .iter()
        .flat_map(|e| e.chain.sus())
        .chain(static_sus.iter().map(|s| s.su.clone()))
        .collect();
    let reason = |kind: &str, name: &str| -> String {
        let explored = structure.and_then(|s| s.broken.iter().find(|b| b.su == name));
        if let Some(b) = broken.iter().find(|b| b.su == name).or(explored) {
            return format!("broken ({}): {}", b.kind, b.detail);
        }
        let found = structure.and_then(|s| {
            // A note names what it is about, not what was left out.
            let explains =
                |d: &&crate::explore::Diagnostic| d.severity != crate::explore::Severity::Info;
            s.diagnostics.iter().filter(explains).find(|d| {
                if kind == "dof" {
                    d.dofs.iter().any(|n| n == name)
                } else {
                    d.sus.iter().any(|n| n == name)
                }
            })
        });
        match (found.map(|d| d.kind), only) {
            (Some(K::DofMovesNoSu), _) => "it moves no SU (no skin on the segment it moves)".into(),
            (Some(K::DofNotExplored), _) => "it was never moved in the structure experiment".into(),
            (Some(K::SeveralStaticGroups), _) => {
                "it stayed still in every move but is not on the reference segment".into()
            }
            (Some(K::Unsortable), _) => {
                "its activity row does not fit the tree (set aside by explore)".into()
            }
            (Some(k), _) => format!("left out by explore ({k:?}; see structure.json)"),
            (None, Some(limb)) => format!("not on limb {limb} (calibrate --limb {limb})"),
            (None, None) => "left out by explore (see structure.json)".into(),
        }
    };
    let mut out = Vec::new();
    for (kind, names, covered) in [("dof", &set.dofs, &dofs), ("su", &set.sus, &sus)] {
        for name in names.iter().filter(|n| !covered.contains(n)) {
            out.push(NotCalibrated {
                kind: kind.into(),
                name: name.clone(),
                reason: reason(kind, name),
            });
        }
    }
    out
}

/// The mean of the readings within `radius` of their component-wise median: a glitch among the
/// readings of an SU that never moves does not shift it.
fn robust_mean(readings: &[Vector3<f64>], radius: f64) -> Vector3<f64> {
    let median = Vector3::from_fn(|i, _| {
        let mut v: Vec<f64> = readings.iter().map(|r| r[i]).collect();
        v.sort_by(f64::total_cmp);
        v.get(v.len() / 2).copied().unwrap_or(0.0)
    });
    let near: Vec<&Vector3<f64>> = readings
        .iter()
        .filter(|r| (*r - median).norm() <= radius)
        .collect();
    if near.is_empty() {
        median
    } else {
        near.iter().copied().sum::<Vector3<f64>>() / near.len() as f64
    }
}

/// The range each DoF covered in the set's poses, as its limits in the calibrated model.
fn observed_limits(set: &MeasurementSet, dof: &str) -> Limits {
    let Some(d) = set.dofs.iter().position(|n| n == dof) else {
        return Limits::CONTINUOUS;
    };
    let mut values: Vec<f64> = Vec::new();
    if let Some(t) = &set.training {
        values.extend(t.poses.iter().map(|p| p.q[d]));
    }
    if let Some(s) = &set.structure {
        for o in &s.orientations {
            values.push(o.rest_pose[d]);
            values.extend(o.moves.iter().map(|m| m.pose[d]));
        }
    }
    let lower = values.iter().copied().fold(f64::INFINITY, f64::min);
    let upper = values.iter().copied().fold(f64::NEG_INFINITY, f64::max);
    if lower.is_finite() && upper > lower {
        Limits {
            lower,
            upper,
            velocity: None,
            acceleration: None,
        }
    } else {
        Limits::CONTINUOUS
    }
}

fn assemble(
    set: &MeasurementSet,
    reference: &str,
    estimates: Vec<MlChainEstimate>,
    parents: Vec<Option<String>>,
    static_sus: Vec<StaticSu>,
    config: &MlConfig,
    pattern: ExcitationPattern,
) -> BodyModel {
    let mut builder = RobotBuilder::new("calibrated", reference);
    let mut limbs: Vec<BodyLimb> = Vec::new();
    for (estimate, parent) in estimates.into_iter().zip(parents) {
        let (base, body_gravity, other_gravities) = match &parent {
            None => {
                let (base, gravity) = upright_base(&Vector3::from(estimate.gravity));
                let others = estimate
                    .other_gravities
                    .iter()
                    .map(|g| (base.rotation * Vector3::from(*g)).into())
                    .collect();
                (base, gravity, others)
            }
            Some(p) => {
                let parent = limbs.iter().find(|l| &l.name == p).expect("parents first");
                (
                    parent.base_frame.to_isometry(),
                    Vector3::from(parent.gravity),
                    parent.other_gravities.clone(),
                )
            }
        };
        add_limb(&mut builder, set, reference, &estimate, &base);
        let chain = &estimate.chain;
        limbs.push(BodyLimb {
            name: chain.name.clone(),
            parent,
            base_frame: Frame::from_isometry(&base),
            gravity: body_gravity.into(),
            other_gravities,
            dofs: chain.dofs()[chain.base_dofs()..].to_vec(),
            sus: chain.sus(),
            estimate,
        });
    }
    for s in &static_sus {
        builder.sus.push(SuSpec {
            name: s.su.clone(),
            segment: reference.to_string(),
            placement: PlacementSpec::from_isometry(&Isometry3::from_parts(
                Vector3::zeros().into(),
                turn_onto(&Vector3::from(s.reading), &Vector3::z()),
            )),
        });
    }
    let robot = builder
        .build()
        .expect("limbs with distinct names form a valid tree");
    BodyModel {
        format: MODEL_FORMAT.into(),
        version: MODEL_VERSION,
        method: "ml".into(),
        noise_sd: config.noise_sd,
        pattern,
        reference: reference.to_string(),
        robot: RobotFile::from_robot(
            &robot,
            Some("calibrated by skincal (maximum likelihood)".into()),
        ),
        limbs,
        static_sus,
        broken: Vec::new(),
        not_calibrated: Vec::new(),
        changes: Vec::new(),
    }
}

/// The rotation that turns `from` onto `to` (half a turn about x where they are opposite).
fn turn_onto(from: &Vector3<f64>, to: &Vector3<f64>) -> UnitQuaternion<f64> {
    UnitQuaternion::rotation_between(from, to).unwrap_or_else(|| {
        UnitQuaternion::from_axis_angle(&Vector3::x_axis(), std::f64::consts::PI)
    })
}

/// A limb on the reference segment turned so that its `gravity` points down: its base frame in
/// the body and gravity in the body frame.
fn upright_base(gravity: &Vector3<f64>) -> (Isometry3<f64>, Vector3<f64>) {
    (
        Isometry3::from_parts(Vector3::zeros().into(), turn_onto(gravity, &-Vector3::z())),
        Vector3::new(0.0, 0.0, -gravity.norm()),
    )
}

/// The estimate's own DoFs (after its base path) and SUs added to the body, its first joint
/// placed by `base` on the reference segment.
fn add_limb(
    builder: &mut RobotBuilder,
    set: &MeasurementSet,
    reference: &str,
    estimate: &MlChainEstimate,
    base: &Isometry3<f64>,
) {
    let state = estimate
        .state
        .as_ref()
        .expect("a fresh estimate has its state");
    let chain = &estimate.chain;
    let base_dofs = chain.base_dofs();
    let kinds = chain.kinds();
    for (k, dof) in chain.dofs().iter().enumerate().skip(base_dofs) {
        let origin = if k == 0 {
            base * state.joints[0]
        } else {
            state.joints[k]
        };
        builder.dofs.push(DofSpec {
            name: dof.clone(),
            parent: if k == 0 {
                reference.to_string()
            } else {
                chain.segment_after(k - 1)
            },
            child: chain.segment_after(k),
            origin: PlacementSpec::from_isometry(&origin),
            axis: Vector3::z(),
            kind: kinds[k],
            limits: observed_limits(set, dof),
            mimic: None,
        });
    }
    let depth: Vec<usize> = chain.joints[chain.base_joints..]
        .iter()
        .scan(base_dofs, |d, j| {
            *d += j.dofs.len();
            Some(vec![*d; j.sus.len()])
        })
        .flatten()
        .collect();
    for (u, su) in chain.sus().iter().enumerate() {
        builder.sus.push(SuSpec {
            name: su.clone(),
            segment: chain.segment_after(depth[u] - 1),
            placement: PlacementSpec::from_isometry(&state.sus[u]),
        });
    }
}
