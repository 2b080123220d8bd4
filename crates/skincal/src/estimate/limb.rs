//! Limbs as the maximum-likelihood estimator sees them: joints of one or more DoFs, any number of
//! SUs on every segment, and optionally a base path that an earlier estimate already fixed.

use nalgebra::Vector3;
use serde::{Deserialize, Serialize};

use super::EstimateError;
use crate::explore::Structure;
use crate::measurements::{MeasurementSet, TrainingPose};
use crate::model::sensor::ExcitationPattern;
use crate::model::DofKind;

/// A joint of a limb: the DoFs between two segments that carry SUs.
#[derive(Debug, Clone, PartialEq, Eq, Serialize, Deserialize)]
pub struct LimbJoint {
    /// Its id (the structure's `Jn`, or the DoF's name for a chain without a structure).
    pub id: String,
    /// Its DoFs along the chain. For a joint of several DoFs the order is not known before
    /// estimation; an estimate lists them in the order it found.
    pub dofs: Vec<String>,
    /// The segment it moves.
    pub segment: String,
    /// The SUs on that segment.
    pub sus: Vec<String>,
}

/// A limb to estimate: joints from its base outwards.
///
/// The first `base_joints` joints lead from the static reference to the limb's base (a branching
/// segment) and were estimated with an earlier limb; they are held at that estimate, and their SUs
/// do not enter.
#[derive(Debug, Clone, PartialEq, Eq, Serialize, Deserialize)]
pub struct LimbChain {
    /// Its name: the structure's end segment of the limb, or `chain`.
    pub name: String,
    /// Joints held from the parent limb's estimate.
    #[serde(default)]
    pub base_joints: usize,
    /// Joints from the static reference outwards.
    pub joints: Vec<LimbJoint>,
    /// The DoFs of the chain that are prismatic (the others are revolute).
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub prismatic: Vec<String>,
}

impl LimbChain {
    /// Whether each DoF along the chain is revolute or prismatic.
    pub fn kinds(&self) -> Vec<DofKind> {
        self.dofs()
            .iter()
            .map(|d| {
                if self.prismatic.contains(d) {
                    DofKind::Prismatic
                } else {
                    DofKind::Revolute
                }
            })
            .collect()
    }

    /// All DoFs along the chain.
    pub fn dofs(&self) -> Vec<String> {
        self.joints.iter().flat_map(|j| j.dofs.clone()).collect()
    }

    /// The SUs this limb estimates (those after its base), segment by segment.
    pub fn sus(&self) -> Vec<String> {
        self.joints[self.base_joints..]
            .iter()
            .flat_map(|j| j.sus.clone())
            .collect()
    }

    /// How many DoFs its base path has (held at the parent limb's estimate).
    pub fn base_dofs(&self) -> usize {
        self.joints[..self.base_joints]
            .iter()
            .map(|j| j.dofs.len())
            .sum()
    }

    /// For each SU of [`Self::sus`], the DoFs before its segment along [`Self::dofs`].
    pub fn su_depths(&self) -> Vec<usize> {
        let mut depth = 0;
        let mut out = Vec::new();
        for (j, joint) in self.joints.iter().enumerate() {
            depth += joint.dofs.len();
            if j >= self.base_joints {
                out.extend(std::iter::repeat_n(depth, joint.sus.len()));
            }
        }
        out
    }

    /// The name of the segment after DoF `k` of [`Self::dofs`]: the joint's segment after its last
    /// DoF, `segment_dof` between the DoFs of a multi-DoF joint.
    pub fn segment_after(&self, k: usize) -> String {
        let mut first = 0;
        for joint in &self.joints {
            if k < first + joint.dofs.len() {
                return if k + 1 == first + joint.dofs.len() {
                    joint.segment.clone()
                } else {
                    format!("{}_{}", joint.segment, joint.dofs[k - first])
                };
            }
            first += joint.dofs.len();
        }
        format!("segment_{k}")
    }

    /// Whether this is a serial chain in the paper's sense: one DoF and one SU per joint, no base
    /// path held from another limb.
    pub fn is_serial(&self) -> bool {
        self.base_joints == 0
            && self
                .joints
                .iter()
                .all(|j| j.dofs.len() == 1 && j.sus.len() == 1)
    }

    /// A serial chain in the paper's sense: DoF `k` moves segment `segment_<dof k>`, which carries
    /// SU `k` alone. Needs as many SUs as DoFs.
    pub fn serial(
        name: impl Into<String>,
        dofs: &[String],
        sus: &[String],
    ) -> Result<Self, EstimateError> {
        let name = name.into();
        if dofs.len() != sus.len() {
            return Err(EstimateError::UnsupportedLimb {
                limb: name,
                reason: format!(
                    "a serial chain has one SU after every DoF, but {} SUs were given for {} DoFs",
                    sus.len(),
                    dofs.len()
                ),
            });
        }
        Ok(LimbChain {
            name,
            base_joints: 0,
            prismatic: Vec::new(),
            joints: dofs
                .iter()
                .zip(sus)
                .map(|(d, s)| LimbJoint {
                    id: d.clone(),
                    dofs: vec![d.clone()],
                    segment: format!("segment_{d}"),
                    sus: vec![s.clone()],
                })
                .collect(),
        })
    }
}

/// The limbs of an explored structure, in an order where every limb comes after the limb that ends
/// at its base: each limb runs from the static reference (through the joints of its base path,
/// held) to an end effector or the next branching segment, with every SU of its segments.
pub fn limb_chains(structure: &Structure) -> Result<Vec<LimbChain>, EstimateError> {
    structure.check().map_err(EstimateError::InvalidStructure)?;
    let mut limbs = Vec::new();
    for limb in &structure.limbs {
        let mut path = Vec::new();
        let mut segment =
            structure
                .segment(&limb.to)
                .ok_or_else(|| EstimateError::UnsupportedLimb {
                    limb: limb.to.clone(),
                    reason: "its end segment is not in the structure".into(),
                })?;
        while let Some(joint_id) = &segment.parent_joint {
            let joint = structure.joint(joint_id).expect("parent joints exist");
            if segment.sus.is_empty() {
                return Err(EstimateError::UnsupportedLimb {
                    limb: limb.to.clone(),
                    reason: format!(
                        "segment {} carries no SU (it was assumed to connect the tree): joint {} cannot be calibrated; put an SU on it",
                        segment.id, joint.id
                    ),
                });
            }
            path.push(LimbJoint {
                id: joint.id.clone(),
                dofs: joint.dofs.clone(),
                segment: segment.id.clone(),
                sus: segment.sus.clone(),
            });
            segment = structure.segment(&joint.parent).expect("parents exist");
        }
        path.reverse();
        let base_joints = path.len() - limb.joints.len();
        limbs.push(LimbChain {
            name: limb.to.clone(),
            base_joints,
            joints: path,
            prismatic: Vec::new(),
        });
    }
    // Parents first: a limb's base path is a prefix of its parent's path.
    limbs.sort_by_key(|l| l.base_joints);
    Ok(limbs)
}

/// The training data of one limb, in chain order, in m/s².
#[derive(Debug, Clone, PartialEq)]
pub struct LimbData {
    /// The limb.
    pub chain: LimbChain,
    /// `q[p][k]`: position of chain DoF `k` in pose `p`.
    pub q: Vec<Vec<f64>>,
    /// For every SU of [`LimbChain::sus`]: the number of chain DoFs that move it.
    pub su_depth: Vec<usize>,
    /// `statics[p][u]`: static reading of SU `u` in pose `p`.
    pub statics: Vec<Vec<Vector3<f64>>>,
    /// `dynamics[p][u][k]`: dynamic acceleration of SU `u` for the pattern of chain DoF `k`
    /// (`k < su_depth[u]`).
    pub dynamics: Vec<Vec<Vec<Vector3<f64>>>>,
    /// The excitation pattern.
    pub pattern: ExcitationPattern,
    /// `sd[p][u][0]`: standard deviation of each component of the static reading of SU `u` in
    /// pose `p`, m/s², `[1 + k]` of its dynamic reading of chain DoF `k`; `None` unless the set
    /// gives every one of them.
    pub sd: Option<Vec<Vec<Vec<f64>>>>,
    /// `missing[p][u][1 + k]`: the set has no dynamic reading of chain DoF `k` in pose `p` (an
    /// excitation that was not recorded or not found in a log); its `dynamics` entry is zero and
    /// no fit uses it. `[p][u][0]` is always `false`. Empty: nothing is missing.
    pub missing: Vec<Vec<Vec<bool>>>,
    /// `orientation[p]`: the base orientation of pose `p` (0 the usual one; each other one has its
    /// own gravity). Empty: every pose in the usual one.
    pub orientation: Vec<usize>,
}

impl LimbData {
    /// Extracts and checks the data of `chain`.
    pub fn new(set: &MeasurementSet, chain: &LimbChain) -> Result<Self, EstimateError> {
        let training = super::checked_training(set)?;
        if chain.joints.len() <= chain.base_joints {
            return Err(EstimateError::UnsupportedLimb {
                limb: chain.name.clone(),
                reason: "it has no joint to estimate".into(),
            });
        }
        let find =
            |what, names: &[String], name: &String| super::position(what, names, name, &chain.name);
        let dofs = chain.dofs();
        let dof_index: Vec<usize> = dofs
            .iter()
            .map(|d| find("DoF", &set.dofs, d))
            .collect::<Result<_, _>>()?;
        let su_index = su_indices(set, chain)?;
        let su_depth = chain.su_depths();
        let mut q = Vec::new();
        let mut statics = Vec::new();
        let mut dynamics = Vec::new();
        let mut missing = Vec::new();
        let mut sd = Some(Vec::new());
        let mut orientation = Vec::new();
        for pose in &training.poses {
            orientation.push(pose.orientation);
            sd = sd
                .zip(pose_sd(pose, &su_index, &su_depth, &dofs))
                .map(|(mut all, this)| {
                    all.push(this);
                    all
                });
            q.push(dof_index.iter().map(|&d| pose.q[d]).collect());
            statics.push(
                su_index
                    .iter()
                    .map(|&u| Vector3::from(pose.static_readings[u]))
                    .collect(),
            );
            let (per_su, lacking) = pose_dynamics(pose, &su_index, &su_depth, &dofs);
            dynamics.push(per_su);
            missing.push(lacking);
        }
        let chain = with_prismatic(set, chain, &dofs, &dof_index)?;
        let data = Self {
            chain,
            q,
            su_depth,
            statics,
            dynamics,
            pattern: training.pattern,
            sd,
            missing,
            orientation: if orientation.iter().any(|&o| o > 0) {
                orientation
            } else {
                Vec::new()
            },
        };
        if !training.from_motion {
            data.check_excited()?;
        }
        Ok(data)
    }

    /// Whether the dynamic reading of chain DoF `k` is missing for SU `u` in pose `p`.
    pub fn is_missing(&self, p: usize, u: usize, k: usize) -> bool {
        self.missing
            .get(p)
            .and_then(|m| m.get(u))
            .and_then(|m| m.get(1 + k))
            .copied()
            .unwrap_or(false)
    }

    /// The chain DoFs whose dynamic readings are missing, with the number of poses that lack
    /// them, in chain order.
    pub fn missing_excitations(&self) -> Vec<(String, usize)> {
        let dofs = self.chain.dofs();
        (0..dofs.len())
            .filter_map(|k| {
                let su = self.su_depth.iter().position(|&d| k < d)?;
                let lacking = (0..self.poses())
                    .filter(|&p| self.is_missing(p, su, k))
                    .count();
                (lacking > 0).then(|| (dofs[k].clone(), lacking))
            })
            .collect()
    }

    /// Whether no pose has a dynamic reading of any of the limb's DoFs: static readings, which
    /// tell orientations and axes only.
    pub fn static_only(&self) -> bool {
        let missing = self.missing_excitations();
        !missing.is_empty()
            && missing.len() == self.chain.dofs().len()
            && missing.iter().all(|(_, lacking)| *lacking == self.poses())
    }

    /// Every DoF of a joint of several DoFs must have been excited in at least one pose: their
    /// order and axis lines are found from the accelerations they cause. A joint of one DoF
    /// excited in no pose is found from gravity alone (its position is then unobservable).
    fn check_excited(&self) -> Result<(), EstimateError> {
        let in_multi_dof_joint = |dof: &String| {
            self.chain
                .joints
                .iter()
                .any(|j| j.dofs.len() > 1 && j.dofs.contains(dof))
        };
        match self
            .missing_excitations()
            .into_iter()
            .find(|(dof, lacking)| *lacking == self.poses() && in_multi_dof_joint(dof))
        {
            Some((dof, _)) => Err(EstimateError::NeverExcited {
                dof,
                poses: self.poses(),
                limb: self.chain.name.clone(),
            }),
            None => Ok(()),
        }
    }

    /// Number of poses.
    pub fn poses(&self) -> usize {
        self.q.len()
    }

    /// The base orientation of pose `p` (0: the usual one).
    pub fn orientation_of(&self, p: usize) -> usize {
        self.orientation.get(p).copied().unwrap_or(0)
    }

    /// How many base orientations the poses were recorded in (1: the usual one only).
    pub fn orientations(&self) -> usize {
        self.orientation.iter().max().map_or(1, |&o| o + 1)
    }

    /// The poses recorded in the usual base orientation (0) alone.
    pub fn usual_orientation(&self) -> Self {
        self.poses_where(|o| o == 0)
    }

    /// The poses recorded in the other base orientations (1, 2, …) alone.
    pub fn other_orientations(&self) -> Self {
        self.poses_where(|o| o > 0)
    }

    /// The poses whose base orientation `keep` keeps.
    fn poses_where(&self, keep: impl Fn(usize) -> bool) -> Self {
        let keep: Vec<usize> = (0..self.poses())
            .filter(|&p| keep(self.orientation_of(p)))
            .collect();
        fn pick<T: Clone>(v: &[T], keep: &[usize]) -> Vec<T> {
            if v.is_empty() {
                Vec::new()
            } else {
                keep.iter().map(|&p| v[p].clone()).collect()
            }
        }
        Self {
            chain: self.chain.clone(),
            q: pick(&self.q, &keep),
            su_depth: self.su_depth.clone(),
            statics: pick(&self.statics, &keep),
            dynamics: pick(&self.dynamics, &keep),
            pattern: self.pattern,
            sd: self.sd.as_ref().map(|sd| pick(sd, &keep)),
            missing: pick(&self.missing, &keep),
            orientation: pick(&self.orientation, &keep),
        }
    }

    /// The same data with the DoFs of joint `joint` in the order `order` (indices into its DoFs).
    pub fn with_joint_order(&self, joint: usize, order: &[usize]) -> Self {
        let first: usize = self.chain.joints[..joint]
            .iter()
            .map(|j| j.dofs.len())
            .sum();
        let mut chain = self.chain.clone();
        let dofs = &self.chain.joints[joint].dofs;
        chain.joints[joint].dofs = order.iter().map(|&i| dofs[i].clone()).collect();
        let permute = |k: usize| {
            if k >= first && k < first + order.len() {
                first + order[k - first]
            } else {
                k
            }
        };
        let q = self
            .q
            .iter()
            .map(|q| (0..q.len()).map(|k| q[permute(k)]).collect())
            .collect();
        let dynamics = self
            .dynamics
            .iter()
            .map(|per_su| {
                per_su
                    .iter()
                    .map(|d| (0..d.len()).map(|k| d[permute(k)]).collect())
                    .collect()
            })
            .collect();
        // Per-reading values `[p][u][row]`: row 0 the static reading, `1 + k` chain DoF k's.
        fn reordered<T: Copy>(
            v: &[Vec<Vec<T>>],
            permute: impl Fn(usize) -> usize,
        ) -> Vec<Vec<Vec<T>>> {
            v.iter()
                .map(|per_su| {
                    per_su
                        .iter()
                        .map(|r| {
                            (0..r.len())
                                .map(|j| if j == 0 { r[0] } else { r[1 + permute(j - 1)] })
                                .collect()
                        })
                        .collect()
                })
                .collect()
        }
        let sd = self.sd.as_ref().map(|sd| reordered(sd, permute));
        let missing = reordered(&self.missing, permute);
        Self {
            chain,
            q,
            dynamics,
            sd,
            missing,
            ..self.clone()
        }
    }
}

/// The set's index of every SU of `chain`'s estimated segments, in chain order; an estimated
/// segment without SU is refused.
fn su_indices(set: &MeasurementSet, chain: &LimbChain) -> Result<Vec<usize>, EstimateError> {
    let mut su_index = Vec::new();
    for joint in &chain.joints[chain.base_joints..] {
        if joint.sus.is_empty() {
            return Err(EstimateError::UnsupportedLimb {
                limb: chain.name.clone(),
                reason: format!(
                    "segment {} (after joint {}) carries no SU",
                    joint.segment, joint.id
                ),
            });
        }
        for su in &joint.sus {
            su_index.push(super::position("SU", &set.sus, su, &chain.name)?);
        }
    }
    Ok(su_index)
}

/// Per SU (set indices `su_index`, moved by the first `su_depth` of `dofs`): the deviation of
/// its static reading in `pose`, then of its dynamic reading of each DoF; `None` unless the
/// pose gives every one of them.
fn pose_sd(
    pose: &TrainingPose,
    su_index: &[usize],
    su_depth: &[usize],
    dofs: &[String],
) -> Option<Vec<Vec<f64>>> {
    let statics = pose.static_sd.as_ref()?;
    su_index
        .iter()
        .zip(su_depth)
        .map(|(&u, &depth)| {
            let dynamic = dofs[..depth].iter().map(|dof| {
                // A missing reading's deviation is never used: any positive value holds its place.
                match (pose.dynamic.contains_key(dof), pose.dynamic_sd.get(dof)) {
                    (false, _) => Some(1.0),
                    (true, sd) => sd.map(|v| v[u]),
                }
            });
            std::iter::once(Some(statics[u])).chain(dynamic).collect()
        })
        .collect()
}

/// Per SU: its dynamic readings in `pose` of the DoFs that move it (zero where the pose has
/// none), and which of them are missing (`[0]`, the static reading, never).
#[allow(clippy::type_complexity)]
fn pose_dynamics(
    pose: &TrainingPose,
    su_index: &[usize],
    su_depth: &[usize],
    dofs: &[String],
) -> (Vec<Vec<Vector3<f64>>>, Vec<Vec<bool>>) {
    let mut per_su: Vec<Vec<Vector3<f64>>> =
        su_depth.iter().map(|&d| Vec::with_capacity(d)).collect();
    let mut lacking: Vec<Vec<bool>> = su_depth.iter().map(|&d| vec![false; 1 + d]).collect();
    for (k, dof) in dofs.iter().enumerate() {
        let readings = pose.dynamic.get(dof);
        for (i, &u) in su_index.iter().enumerate() {
            if k < su_depth[i] {
                per_su[i].push(readings.map_or_else(Vector3::zeros, |r| r[u].into()));
                lacking[i][1 + k] = readings.is_none();
            }
        }
    }
    (per_su, lacking)
}

/// `chain` with its prismatic DoFs (of `dofs`, set indices `dof_index`) named; a prismatic DoF
/// that shares a joint with others (no SU between them) is refused.
fn with_prismatic(
    set: &MeasurementSet,
    chain: &LimbChain,
    dofs: &[String],
    dof_index: &[usize],
) -> Result<LimbChain, EstimateError> {
    let mut chain = chain.clone();
    chain.prismatic = dofs
        .iter()
        .zip(dof_index)
        .filter(|&(_, &d)| set.dof_kind(d) == DofKind::Prismatic)
        .map(|(name, _)| name.clone())
        .collect();
    if let Some(joint) = chain
        .joints
        .iter()
        .find(|j| j.dofs.len() > 1 && j.dofs.iter().any(|d| chain.prismatic.contains(d)))
    {
        return Err(EstimateError::UnsupportedLimb {
            limb: chain.name.clone(),
            reason: format!(
                "joint {} holds the prismatic DoF(s) {:?} among the DoFs {:?} with no SU between \
                 them: a prismatic DoF is calibrated only with skin on the segment it moves (put \
                 an SU there, or hold the DoF still: make it fixed in the description)",
                joint.id,
                joint
                    .dofs
                    .iter()
                    .filter(|d| chain.prismatic.contains(d))
                    .collect::<Vec<_>>(),
                joint.dofs
            ),
        });
    }
    Ok(chain)
}
