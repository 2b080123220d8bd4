//! Kinematic estimation (paper Section II-C, Algorithm 2): fitting serial-chain models of the limbs
//! to the training experiment.
//!
//! A limb is a [`LimbChain`]: joints of one or more DoFs from the static reference segment
//! outwards, any number of SUs on each segment. A **serial chain** is the paper's kind of limb
//! ([`LimbChain::serial`], [`LimbChain::is_serial`]): one DoF and one SU per joint. Its DH form (paper eqs. 4–7) is a table of
//! DoF-to-DoF rows `(θ0, d, a, α)` and DoF-to-SU rows `(θ0, d, a, α, θ_acc, d_acc)`; the reference frame
//! is the first DoF's axis frame (`DoF1_T_RS = I`).
//!
//! Accuracy is judged where it is physically meaningful ([`consecutive_su_errors`]): the pose of each SU
//! relative to the previous SU of the chain, over random held-out poses, against the truth. Parameters
//! such as the first transform's `θ0` and `d`, or DH equivalences like `(θ+π, d, −a, −α)`, cannot be
//! determined from accelerometer data and are not compared one by one.
//!
//! Modules: the paper's estimator (`paper`), the maximum-likelihood one (`ml`), limbs and their
//! readings (`limb`: `LimbChain`, `LimbData`), the whole body limb by limb and tree by tree
//! (`body`), what is tried when a fit is not at the noise level (`rescue`), and the paper's DH+2
//! table of a chain (`dh`).

pub mod body;
pub mod dh;
pub mod limb;
pub mod ml;
pub mod paper;
pub mod quiet;
mod rescue;

pub use dh::{chain_frames_at_zero, dh_form, true_dh_table, ChainFrames, DhRow, SuRow};
pub use limb::{limb_chains, LimbChain, LimbData, LimbJoint};

use nalgebra::{Isometry3, Vector3};
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use serde::{Deserialize, Serialize};

use crate::explore::Structure;
use crate::measurements::MeasurementSet;
use crate::model::{
    forward_kinematics, DofKind, DofSpec, Limits, PlacementSpec, Robot, RobotBuilder, SuSpec,
};

/// Errors that stop an estimation before it starts.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
#[non_exhaustive]
pub enum EstimateError {
    /// The measurement set has no training experiment.
    #[error("the measurement set has no training experiment (`training`): record static and dynamic readings in random poses first")]
    NoTrainingData,
    /// A DoF or SU of the chain is missing from the measurement set.
    #[error("{what} `{name}` of limb {limb} is not in the measurement set")]
    Unknown {
        /// "DoF" or "SU".
        what: &'static str,
        /// Its name.
        name: String,
        /// The limb.
        limb: String,
    },
    /// A training pose lacks the dynamic readings the paper's estimator needs.
    #[error("training.poses[{pose}] has no dynamic readings for DoF `{dof}`, which the paper's estimator needs for limb {limb} in every pose: record the excitation pattern of every DoF of the limb in every pose, or calibrate by maximum likelihood (method `ml`), which uses the poses that have them")]
    MissingDynamic {
        /// The pose index.
        pose: usize,
        /// The DoF.
        dof: String,
        /// The limb.
        limb: String,
    },
    /// No training pose has a dynamic reading of a DoF of a multi-DoF joint.
    #[error("none of the {poses} training poses has a dynamic reading of DoF `{dof}`, which limb {limb} needs: it shares a joint with other DoFs, whose order and axis lines are found from the accelerations their excitation patterns cause; record that pattern in some of the poses (missing it in a few costs only their readings)")]
    NeverExcited {
        /// The DoF.
        dof: String,
        /// The number of training poses.
        poses: usize,
        /// The limb.
        limb: String,
    },
    /// Too few training poses for the number of parameters.
    #[error("{poses} training poses cannot determine {parameters} parameters per step: record at least {parameters} poses")]
    TooFewPoses {
        /// Poses recorded.
        poses: usize,
        /// Parameters of the largest step.
        parameters: usize,
    },
    /// The measurement set is not valid.
    #[error("invalid measurement set: {0}")]
    Measurements(crate::measurements::MeasurementError),
    /// The fit ran away from finite numbers: the data cannot be what the model assumes.
    #[error("limb {limb}: the estimate is not a finite number ({reason}); the readings cannot be what the model assumes: check them for corrupt values and record again")]
    NotFinite {
        /// The limb.
        limb: String,
        /// What went wrong.
        reason: String,
    },
    /// The structure is not a tree (see [`Structure::check`]).
    #[error("invalid structure: {0}")]
    InvalidStructure(String),
    /// A limb that the method cannot model.
    #[error("limb {limb}: {reason}")]
    UnsupportedLimb {
        /// The limb.
        limb: String,
        /// Why, and what to do.
        reason: String,
    },
    /// A limb id that the structure does not have.
    #[error("no limb `{limb}`: the structure's limbs end at {known}")]
    UnknownLimb {
        /// What was asked.
        limb: String,
        /// The limbs there are.
        known: String,
    },
    /// A setting is out of range.
    #[error("{setting}: {reason}")]
    InvalidSetting {
        /// The setting.
        setting: &'static str,
        /// What is wrong.
        reason: String,
    },
}

/// The serial chains from the reference segment to every end effector of an explored structure,
/// with the first SU of every segment. Every joint on them must have a single DoF (the paper's
/// chain model); the error names the joint otherwise.
pub fn serial_chains(structure: &Structure) -> Result<Vec<LimbChain>, EstimateError> {
    structure.check().map_err(EstimateError::InvalidStructure)?;
    let mut chains = Vec::new();
    for end in &structure.end_effectors {
        let mut joints = Vec::new();
        let mut segment = structure.segment(end).expect("end effectors are segments");
        while let Some(joint_id) = &segment.parent_joint {
            let joint = structure.joint(joint_id).expect("parent joints exist");
            if joint.dofs.len() != 1 {
                return Err(EstimateError::UnsupportedLimb {
                    limb: end.clone(),
                    reason: format!(
                        "joint {} has {} DoFs ({}) with no SU between them; the paper's serial-chain model needs one SU after every DoF: use `--method ml`, which calibrates multi-DoF joints",
                        joint.id,
                        joint.dofs.len(),
                        joint.dofs.join(", ")
                    ),
                });
            }
            let su = segment
                .sus
                .first()
                .ok_or_else(|| EstimateError::UnsupportedLimb {
                    limb: end.clone(),
                    reason: format!("segment {} carries no SU", segment.id),
                })?;
            joints.push(LimbJoint {
                id: joint.id.clone(),
                dofs: joint.dofs.clone(),
                segment: segment.id.clone(),
                sus: vec![su.clone()],
            });
            segment = structure.segment(&joint.parent).expect("parents exist");
        }
        joints.reverse();
        chains.push(LimbChain {
            name: end.clone(),
            base_joints: 0,
            joints,
            prismatic: Vec::new(),
        });
    }
    Ok(chains)
}

/// Without a structure: the DoFs of the set in their order as one chain, the `k`-th SU on the
/// segment after the `k`-th DoF. Needs as many SUs as DoFs.
pub fn chain_in_listed_order(set: &MeasurementSet) -> Result<LimbChain, EstimateError> {
    if set.sus.len() != set.dofs.len() {
        return Err(EstimateError::UnsupportedLimb {
            limb: "chain".into(),
            reason: format!(
                "without a structure (no structure experiment, no structure.json) the DoFs are taken as one chain in listed order with one SU per segment, but there are {} SUs for {} DoFs: record the structure experiment",
                set.sus.len(),
                set.dofs.len()
            ),
        });
    }
    LimbChain::serial("chain", &set.dofs, &set.sus)
}

/// The training experiment of a valid set with at least one pose.
pub(crate) fn checked_training(
    set: &MeasurementSet,
) -> Result<&crate::measurements::TrainingExperiment, EstimateError> {
    set.validate().map_err(EstimateError::Measurements)?;
    let training = set.training.as_ref().ok_or(EstimateError::NoTrainingData)?;
    if training.poses.is_empty() {
        return Err(EstimateError::NoTrainingData);
    }
    Ok(training)
}

/// Where `name` (a DoF or SU of limb `limb`) stands in `names`.
pub(crate) fn position(
    what: &'static str,
    names: &[String],
    name: &String,
    limb: &str,
) -> Result<usize, EstimateError> {
    names
        .iter()
        .position(|n| n == name)
        .ok_or_else(|| EstimateError::Unknown {
            what,
            name: name.clone(),
            limb: limb.to_string(),
        })
}

/// A serial chain as a [`Robot`]: reference segment `reference`, DoF `k` (axis z of its joint frame)
/// placed by `origins[k]` on the segment of DoF `k−1`, and SU `k` placed by `sus` entries `(k, placement)`
/// on the segment of DoF `k`. Only the first `origins.len()` DoFs are built.
pub fn chain_robot(
    chain: &LimbChain,
    origins: Vec<PlacementSpec>,
    sus: Vec<(usize, PlacementSpec)>,
) -> Robot {
    let mut b = RobotBuilder::new(chain.name.clone(), "reference");
    let (dofs, su_names) = (chain.dofs(), chain.sus());
    let segment = |k: usize| format!("segment_{}", dofs[k]);
    for (k, origin) in origins.into_iter().enumerate() {
        b.dofs.push(DofSpec {
            name: dofs[k].clone(),
            parent: if k == 0 {
                "reference".into()
            } else {
                segment(k - 1)
            },
            child: segment(k),
            origin,
            axis: Vector3::z(),
            kind: DofKind::Revolute,
            limits: Limits::CONTINUOUS,
            mimic: None,
        });
    }
    for (k, placement) in sus {
        b.sus.push(SuSpec {
            name: su_names[k].clone(),
            segment: segment(k),
            placement,
        });
    }
    b.build()
        .expect("a chain with distinct names is a valid tree")
}

/// The paper's chain model (eqs. 4–7) as a [`Robot`]: DoF `k+1` placed on the segment of DoF `k`
/// by `dof_dof[k]`, SU `k` on the segment of DoF `k` by its row. `dof_su` may name only some SUs,
/// and `dof_dof` has one row less than the DoFs used.
pub fn dh_chain_robot(
    chain: &LimbChain,
    dofs: usize,
    dof_dof: &[DhRow],
    dof_su: &[(usize, SuRow)],
) -> Robot {
    let origins = (0..dofs)
        .map(|k| match k {
            0 => PlacementSpec::identity(),
            _ => dof_dof[k - 1].placement(),
        })
        .collect();
    let sus = dof_su.iter().map(|(k, r)| (*k, r.placement())).collect();
    chain_robot(chain, origins, sus)
}

/// Errors of one consecutive SU pair over held-out poses.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct PairError {
    /// The previous SU.
    pub from: String,
    /// The SU whose pose relative to `from` is judged.
    pub to: String,
    /// RMS position error, m.
    pub position_rms: f64,
    /// Largest position error, m.
    pub position_max: f64,
    /// RMS rotation error, rad.
    pub rotation_rms: f64,
    /// Largest rotation error, rad.
    pub rotation_max: f64,
}

/// The first SU pair in one held-out pose: true and estimated relative poses, and the first axis
/// (direction and a point) in the first SU's true frame.
struct FirstPair {
    truth: Isometry3<f64>,
    estimate: Isometry3<f64>,
    axis: Vector3<f64>,
    point: Vector3<f64>,
}

/// How many held-out poses, from which seed, `calibrate` and the report judge each limb's SU
/// poses against the truth over ([`consecutive_su_errors`]).
pub const ACCURACY_POSES: usize = 30;
/// See [`ACCURACY_POSES`].
pub const ACCURACY_SEED: u64 = 1;

/// Accuracy of a chain estimate against the truth.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct ChainAccuracy {
    /// Per consecutive SU pair (the first one compared up to a screw about the first axis).
    pub pairs: Vec<PairError>,
    /// RMS position error over the pairs after the first and all poses, m.
    pub position_rms: f64,
    /// Largest position error over the pairs after the first, m.
    pub position_max: f64,
    /// RMS rotation error over the pairs after the first and all poses, rad.
    pub rotation_rms: f64,
    /// Largest rotation error over the pairs after the first, rad.
    pub rotation_max: f64,
    /// Number of held-out poses.
    pub poses: usize,
}

/// The pose of every SU of `chain` relative to the previous SU, estimated against true, over
/// `poses` random poses (each chain DoF uniform in `±2.62 rad ∩` its true limits; other DoFs of
/// the truth at 0), seeded.
///
/// Both robots must name the chain's DoFs and SUs. The relative pose is `T_prev⁻¹ · T_su`; the
/// position error is the norm of the difference of the translations (in the previous SU's frame),
/// the rotation error the angle of `R_trueᵀ · R_est`.
///
/// The first pair is different: the first SU is moved by the first DoF alone, whose accelerations
/// are all perpendicular to its axis, so no reading tells how far along that axis it sits from the
/// rest of the chain; and when the first axis is vertical (as on most arms, and the paper's), gravity
/// does not tell how far about it the first SU is turned either. The first pair is therefore
/// compared up to one screw about the first axis (the same for all poses: the best rotation about it,
/// and any shift along it), and the summary figures are taken over the pairs after the first.
pub fn consecutive_su_errors(
    truth: &Robot,
    estimate: &Robot,
    chain: &LimbChain,
    poses: usize,
    seed: u64,
) -> Result<ChainAccuracy, EstimateError> {
    let (t_dofs, t_sus) = (chain_dofs(truth, chain)?, chain_sus(truth, chain)?);
    let (e_dofs, e_sus) = (chain_dofs(estimate, chain)?, chain_sus(estimate, chain)?);
    let mut rng = ChaCha8Rng::seed_from_u64(seed);
    let n_pairs = chain.sus().len().saturating_sub(1);
    let mut pos = vec![Vec::new(); n_pairs];
    let mut rot = vec![Vec::new(); n_pairs];
    let mut first: Vec<FirstPair> = Vec::new();
    for _ in 0..poses {
        let (qt, qe) = held_out_pose(&mut rng, truth, estimate, &t_dofs, &e_dofs);
        let kt = forward_kinematics(&truth.model, &truth.parameters, &qt);
        let ke = forward_kinematics(&estimate.model, &estimate.parameters, &qe);
        let rel = |k: &crate::model::Kinematics<f64>, a: usize, b: usize| -> Isometry3<f64> {
            k.sus[a].inverse() * k.sus[b]
        };
        for i in 0..n_pairs {
            let true_rel = rel(&kt, t_sus[i], t_sus[i + 1]);
            let est_rel = rel(&ke, e_sus[i], e_sus[i + 1]);
            if i == 0 {
                let su = &kt.sus[t_sus[0]];
                let axis = su
                    .rotation
                    .inverse_transform_vector(&kt.axis(&truth.model, t_dofs[0]));
                let point = su
                    .inverse_transform_point(&kt.axis_point(t_dofs[0]).into())
                    .coords;
                first.push(FirstPair {
                    truth: true_rel,
                    estimate: est_rel,
                    axis,
                    point,
                });
                continue;
            }
            pos[i].push((est_rel.translation.vector - true_rel.translation.vector).norm());
            rot[i].push((true_rel.rotation.inverse() * est_rel.rotation).angle());
        }
    }
    if !first.is_empty() {
        let screw = best_screw(&first);
        for pair in &first {
            let (position, rotation) = pair.errors_after(screw);
            pos[0].push(position);
            rot[0].push(rotation);
        }
    }
    Ok(chain_accuracy(chain, &pos, &rot, poses))
}

/// The index in `robot` of every DoF of `chain`.
fn chain_dofs(robot: &Robot, chain: &LimbChain) -> Result<Vec<usize>, EstimateError> {
    indices_in(chain, "DoF", &chain.dofs(), |n| robot.model.dof_index(n))
}

/// The index in `robot` of every SU of `chain`.
fn chain_sus(robot: &Robot, chain: &LimbChain) -> Result<Vec<usize>, EstimateError> {
    indices_in(chain, "SU", &chain.sus(), |n| robot.model.su_index(n))
}

fn indices_in(
    chain: &LimbChain,
    what: &'static str,
    names: &[String],
    index: impl Fn(&str) -> Option<usize>,
) -> Result<Vec<usize>, EstimateError> {
    names
        .iter()
        .map(|name| {
            index(name).ok_or_else(|| EstimateError::Unknown {
                what,
                name: name.clone(),
                limb: chain.name.clone(),
            })
        })
        .collect()
}

/// One held-out pose for the truth and the estimate: each chain DoF uniform in `±2.62 rad ∩` its
/// true limits, every other DoF at 0.
fn held_out_pose(
    rng: &mut ChaCha8Rng,
    truth: &Robot,
    estimate: &Robot,
    t_dofs: &[usize],
    e_dofs: &[usize],
) -> (Vec<f64>, Vec<f64>) {
    let mut qt = vec![0.0; truth.model.dofs().len()];
    let mut qe = vec![0.0; estimate.model.dofs().len()];
    for (&t, &e) in t_dofs.iter().zip(e_dofs) {
        let l = &truth.model.dofs()[t].limits;
        let (lo, hi) = (l.lower.max(-2.62), l.upper.min(2.62));
        let v = if hi > lo {
            rng.random_range(lo..=hi)
        } else {
            lo
        };
        qt[t] = v;
        qe[e] = v;
    }
    (qt, qe)
}

/// The screw angle about the first axis that best aligns the first pair's rotations over all
/// poses (a grid of 0.5°, then halving steps).
fn best_screw(first: &[FirstPair]) -> f64 {
    let misfit = |phi: f64| -> f64 { first.iter().map(|p| p.turn_error(phi).powi(2)).sum() };
    let mut best = (0..720)
        .map(|i| -std::f64::consts::PI + i as f64 * std::f64::consts::PI / 360.0)
        .min_by(|a, b| misfit(*a).total_cmp(&misfit(*b)))
        .unwrap_or(0.0);
    let mut step = std::f64::consts::PI / 360.0;
    while step > 1e-9 {
        for candidate in [best - step, best + step] {
            if misfit(candidate) < misfit(best) {
                best = candidate;
            }
        }
        step *= 0.5;
    }
    best
}

impl FirstPair {
    /// The estimate turned by `phi` about the first axis.
    fn turn(&self, phi: f64) -> nalgebra::UnitQuaternion<f64> {
        nalgebra::UnitQuaternion::from_axis_angle(&nalgebra::Unit::new_normalize(self.axis), phi)
    }

    /// The rotation error after a turn of `phi` about the first axis, rad.
    fn turn_error(&self, phi: f64) -> f64 {
        (self.truth.rotation.inverse() * self.turn(phi) * self.estimate.rotation).angle()
    }

    /// Position (m, any shift along the axis left out) and rotation error (rad) after the screw
    /// of `phi` about the first axis.
    fn errors_after(&self, phi: f64) -> (f64, f64) {
        let (a, c) = (&self.axis, &self.point);
        let moved = self.turn(phi) * (self.estimate.translation.vector - c) + c;
        let mut error = moved - self.truth.translation.vector;
        error -= a * a.dot(&error);
        (error.norm(), self.turn_error(phi))
    }
}

/// Per pair and over the pairs after the first: RMS and largest errors.
fn chain_accuracy(
    chain: &LimbChain,
    pos: &[Vec<f64>],
    rot: &[Vec<f64>],
    poses: usize,
) -> ChainAccuracy {
    let rms = |v: &[f64]| (v.iter().map(|x| x * x).sum::<f64>() / v.len().max(1) as f64).sqrt();
    let max = |v: &[f64]| v.iter().copied().fold(0.0, f64::max);
    let sus = chain.sus();
    let pairs = (0..pos.len())
        .map(|i| PairError {
            from: sus[i].clone(),
            to: sus[i + 1].clone(),
            position_rms: rms(&pos[i]),
            position_max: max(&pos[i]),
            rotation_rms: rms(&rot[i]),
            rotation_max: max(&rot[i]),
        })
        .collect();
    let later_pos: Vec<f64> = pos.iter().skip(1).flatten().copied().collect();
    let later_rot: Vec<f64> = rot.iter().skip(1).flatten().copied().collect();
    ChainAccuracy {
        pairs,
        position_rms: rms(&later_pos),
        position_max: max(&later_pos),
        rotation_rms: rms(&later_rot),
        rotation_max: max(&later_rot),
        poses,
    }
}
