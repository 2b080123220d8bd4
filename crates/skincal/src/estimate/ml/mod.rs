//! Maximum-likelihood estimation of a serial chain: least squares on the raw readings, solved on
//! the manifold of rigid transforms, initialised from closed-form physics.
//!
//! **Model.** The reference frame is the first DoF's joint frame (`z` = its axis). DoF `k` turns
//! about the `z` axis of its joint frame `J_k`, placed on segment `k` (segment 0 = reference):
//! `T_ref←seg(k+1) = T_ref←seg(k) · J_k · Rz(q_k)`, `J_0 = I`. SU `u` on segment `s` has the frame
//! `T_ref←seg(s) · S_u`. Gravity `g` in the reference frame is unknown (3 values).
//!
//! **Residuals** (whitened by the noise standard deviation σ), for every pose `p` and SU `u`:
//! the static reading `R_uᵀ·(−g) − s_meas`, and for **every** DoF `d` that moves `u` the dynamic
//! acceleration `α·R_uᵀ·(z_d × (p_u − o_d)) − a_meas` with `α = 2πfA` (the paper uses only the last
//! three DoFs and a spread-of-gravity term instead).
//!
//! **Parameters and gauge.** Each joint frame `J_k` (`k ≥ 1`) has 4 local parameters — tilts about its
//! `x` and `y` axes and shifts along them — because turning it about or sliding it along its own axis
//! is absorbed by the frames of the segment it moves. Each SU frame has 6 (a rotation vector and a
//! translation, both in its segment's frame). Turning everything about, or sliding it along, the
//! first axis changes no reading: the rotation about and translation along `z` of the first SU on
//! segment 1 are held fixed. Updates are applied on the manifold (`J ← J·T(δ)·R(δ)`,
//! `R ← exp(ω)·R`), so there are no Euler-angle or DH singularities. Every reading is computed
//! by one kinematics (`terms.rs`), whose rates along the joint lines come from dual numbers; the
//! Jacobian is checked against central differences in the tests.
//!
//! **Solver.** Levenberg–Marquardt on the normal equations, block by block (`problem.rs`): every
//! SU's rows depend on its own parameters and on the shared ones (gravity, the joint lines) only,
//! so each SU block is linearised on its own (in parallel), reduced to its small normal-equation
//! pieces and eliminated by the Schur complement (Cholesky of each damped SU block), and only the
//! reduced shared system is factorised (Cholesky; a step whose damped system is not positive
//! definite is not taken). Time is linear in the number of SUs; the damping grows on rejected
//! steps and shrinks on accepted ones. Readings are weighed by their own
//! standard deviations where the set has them, with a Huber weight per reading; weak 10 m priors
//! hold what no reading tells near the frames during the solves (never in what is reported).
//!
//! **Trees** (`tree.rs`). A limb on another limb's segment is fitted with its base path and
//! gravity held; afterwards every limb of a tree is fitted again in one problem, gravity and each
//! DoF's line shared by every SU they move, each limb's SU blocks eliminated as in its own fit.
//!
//! **Initialisation**, segment by segment (the physics first, search only where it is needed):
//! 1. An SU on the segment that DoF `k` moves directly sees all its DoF-`k` accelerations
//!    perpendicular to the axis: the axis direction in the SU frame is the right singular vector of
//!    the smallest singular value of those accelerations (Seel-style joint-axis estimation), and the
//!    lever arm follows from them as `r⊥ = mean(a/α) × n`.
//! 2. The joint's rotation follows from how gravity turns between the previous segment and this one
//!    (a Wahba problem, solved by SVD); when gravity does not turn (a vertical axis upstream) the
//!    rotation about the axis is searched over a low-discrepancy set of angles.
//! 3. The joint's position follows linearly from the accelerations that upstream DoFs cause.
//! 4. Every candidate (both signs of the axis, every searched angle) is refined by LM on the
//!    segment's data; the best is kept. Finally the whole chain is refined jointly.
//!
//! **Convergence** (`band.rs`). A fit is at the noise level when its residual ratio lies within
//! the band a right model stays in at the data's size (`√(χ²_ν(0.999)/ν)`: 1.02 σ at 10 000
//! degrees of freedom), not below a fixed bound; a fit off it goes on to other joint orders and
//! a wider search.
//!
//! **Uncertainty.** The parameter covariance is `σ̂²·(JᵀJ)⁺` by the same elimination, with
//! symmetric eigen-decompositions of the SU blocks and of the reduced shared system (directions
//! with no information get none), propagated to each SU's position and orientation relative to the
//! previous SU. The directions of that pose no reading determines — the null directions of the
//! information with the gauge released — are listed per SU, never given a deviation.

mod band;
mod bound;
mod init;
mod motion;
mod problem;
mod terms;
mod tree;

pub use band::{ResidualBand, FALSE_ALARM};
pub use motion::{LimbMotion, MAX_DELAY};
pub use tree::refine_trees;

pub use bound::{
    cramer_rao_bound, limb_state_of, observable_su_errors, state_of, ObservableErrors,
};

use std::time::Instant;

use nalgebra::{DMatrix, DVector, Isometry3, Matrix3, UnitQuaternion, Vector3, Vector6};
use rayon::prelude::*;
use serde::{Deserialize, Serialize};

use super::limb::{LimbChain, LimbData};
use super::{ChainData, EstimateError};
use crate::model::description::RobotFile;
use crate::model::intrinsics::{Intrinsics, INTRINSIC_NAMES};
use crate::model::sensor::STANDARD_GRAVITY;
use crate::model::{DofKind, DofSpec, Limits, PlacementSpec, Robot, RobotBuilder, SuSpec};
use problem::{
    covariance, frames, normal_system, prefixes, retract, retract_columns, solve, turns_of, Block,
    ColumnMap, Layout, Prefix, Readings, Solved, Spec,
};

/// Settings of the maximum-likelihood estimator.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct MlConfig {
    /// Standard deviation of the noise on every reading component, m/s² (default: uniform ±0.01 g).
    pub noise_sd: f64,
    /// Angles tried for a joint's rotation about its axis when gravity cannot tell it.
    pub angle_starts: usize,
    /// Largest number of LM iterations per solve.
    pub max_iterations: usize,
    /// A result whose residual RMS exceeds this multiple of `noise_sd` is never converged; a
    /// readings fit must also lie within the noise's band at its size ([`ResidualBand`]).
    pub converged_ratio: f64,
    /// Candidates carried from one segment to the next.
    pub beam: usize,
    /// Gravity is taken along the first axis when holding it there raises the χ² of segment 1 by
    /// less than this (default: the 99 % point of χ² with 2 degrees of freedom).
    pub vertical_test: f64,
    /// A parameter direction that the data determine only to worse than this (m or rad) is
    /// reported as unobservable.
    pub observable_limit: f64,
    /// Which accelerometer intrinsics are estimated with the kinematics: with
    /// `select_intrinsics`, the largest model the data may choose.
    #[serde(default)]
    pub intrinsics: IntrinsicsModel,
    /// Let the data choose the intrinsics: each model from none up to `intrinsics` is taken only
    /// when it fits significantly better than the one before ([`IntrinsicsTest`]), so that ideal
    /// sensors are not given parameters that only add variance.
    #[serde(default)]
    pub select_intrinsics: bool,
    /// Weight each reading by its own standard deviation where the measurement set gives them all
    /// (ingested logs); `noise_sd` is then only the unit the residuals are reported in.
    #[serde(default = "weigh_by_reading_sd")]
    pub reading_sd: bool,
    /// Fit the limbs of each tree together after the limb-by-limb fits ([`refine_trees`]): a
    /// DoF's line from every SU it moves, not only from its own limb's.
    #[serde(default = "fit_whole_trees")]
    pub whole_tree: bool,
}

fn fit_whole_trees() -> bool {
    true
}

fn weigh_by_reading_sd() -> bool {
    true
}

/// Which accelerometer intrinsics ([`Intrinsics`]) the estimator fits per SU.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, Serialize, Deserialize)]
#[serde(rename_all = "kebab-case")]
pub enum IntrinsicsModel {
    /// Ideal accelerometers.
    None,
    /// A bias per axis.
    Bias,
    /// A bias and a scale error per axis.
    #[default]
    BiasScale,
    /// Bias, scale and the 3 axis misalignments.
    Full,
}

impl IntrinsicsModel {
    /// How many of the 9 components ([`INTRINSIC_NAMES`] order) are estimated.
    pub fn components(self) -> usize {
        match self {
            IntrinsicsModel::None => 0,
            IntrinsicsModel::Bias => 3,
            IntrinsicsModel::BiasScale => 6,
            IntrinsicsModel::Full => 9,
        }
    }

    /// Its name on the command line and in files.
    pub fn name(self) -> &'static str {
        match self {
            IntrinsicsModel::None => "none",
            IntrinsicsModel::Bias => "bias",
            IntrinsicsModel::BiasScale => "bias-scale",
            IntrinsicsModel::Full => "full",
        }
    }
}

impl MlConfig {
    /// Whether the search for a limb's fit may stop at `e`: when it is at the noise level, or, for
    /// a limb fitted on a base path held at its parent's estimate (`held_path`) that the tree's
    /// joint fit frees afterwards ([`MlConfig::whole_tree`]), when it is within
    /// [`MlConfig::converged_ratio`]: the held path's own error leaves a misfit that no search of
    /// the limb removes (an arm on a trunk fitted from the trunk's few SUs ends at 1.03 σ, where
    /// 17 000 degrees of freedom allow 1.016), and the joint fit judges it again.
    pub fn search_done(&self, e: &MlChainEstimate, held_path: bool) -> bool {
        e.converged || (held_path && self.whole_tree && e.residual_ratio <= self.converged_ratio)
    }
}

impl Default for MlConfig {
    fn default() -> Self {
        Self {
            noise_sd: 0.01 * STANDARD_GRAVITY / 3f64.sqrt(),
            angle_starts: 6,
            max_iterations: 100,
            converged_ratio: 1.5,
            beam: 2,
            vertical_test: 9.21,
            observable_limit: 1.0,
            intrinsics: IntrinsicsModel::default(),
            select_intrinsics: true,
            reading_sd: true,
            whole_tree: true,
        }
    }
}

/// The geometry being estimated, in the chart described in the module documentation.
#[derive(Debug, Clone, PartialEq)]
pub struct ChainState {
    /// Gravity in the reference frame, m/s².
    pub gravity: Vector3<f64>,
    /// `joints[k]`: DoF `k`'s joint frame on segment `k` (`joints[0] = I`).
    pub joints: Vec<Isometry3<f64>>,
    /// SU frames on their segments.
    pub sus: Vec<Isometry3<f64>>,
    /// Each SU's accelerometer intrinsics.
    pub intrinsics: Vec<Intrinsics>,
    /// How late the skin's stamps run behind the joint states', s (fitted on a motion record
    /// only; 0 otherwise).
    pub skin_delay: f64,
}

/// The part of a limb that an earlier estimate fixed: the joint frames of the DoFs from the static
/// reference to the limb's base, and gravity, in that estimate's reference frame.
#[derive(Debug, Clone, PartialEq)]
pub struct LimbBase {
    /// Joint frames of the base path's DoFs.
    pub joints: Vec<Isometry3<f64>>,
    /// Gravity, m/s².
    pub gravity: Vector3<f64>,
}

impl LimbBase {
    /// The first `dofs` joint frames and the gravity of an estimate.
    pub fn of(estimate: &MlChainEstimate, dofs: usize) -> Option<Self> {
        let state = estimate.state.as_ref()?;
        (dofs <= state.joints.len()).then(|| Self {
            joints: state.joints[..dofs].to_vec(),
            gravity: state.gravity,
        })
    }
}

/// One SU's parameter uncertainty, relative to the previous SU of the chain (to the reference frame
/// for the first), at the zero pose: what the readings determine, and the directions they do not.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct SuUncertainty {
    /// The SU.
    pub su: String,
    /// Standard deviation of its position in the directions the readings determine, m (root of
    /// the trace of the 3×3 covariance with `undetermined_position` taken out).
    pub position_sd: f64,
    /// Standard deviation of its orientation about the axes the readings determine, rad.
    pub orientation_sd: f64,
    /// Directions (unit vectors in the previous SU's frame, the reference frame for the first)
    /// along which no reading determines its position: a gauge the estimate holds or a direction
    /// the information leaves free. Its standard deviation there is not finite.
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub undetermined_position: Vec<[f64; 3]>,
    /// Axes (unit vectors in its own frame) about which no reading determines its orientation.
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub undetermined_orientation: Vec<[f64; 3]>,
}

impl SuUncertainty {
    /// Whether some direction of its pose is not determined by the readings.
    pub fn is_partial(&self) -> bool {
        !self.undetermined_position.is_empty() || !self.undetermined_orientation.is_empty()
    }

    /// The undetermined directions in words, e.g. `position along (0.00, 0.00, 1.00); turn
    /// about (0.00, 0.00, 1.00)`; empty when every direction is determined.
    pub fn undetermined(&self) -> String {
        let list = |what: &str, v: &[[f64; 3]]| {
            v.iter()
                .map(|d| format!("{what} ({:.2}, {:.2}, {:.2})", d[0], d[1], d[2]))
                .collect::<Vec<_>>()
        };
        list("position along", &self.undetermined_position)
            .into_iter()
            .chain(list("turn about", &self.undetermined_orientation))
            .collect::<Vec<_>>()
            .join("; ")
    }
}

/// The covariance of a limb's free joint lines, for checks of the joints' geometry (`check-urdf`).
///
/// Each DoF has 4 components in its own joint frame (z along its axis, as the model's robot
/// description places it): the turns about the frame's x and y axes (rad) and the shifts along them
/// (m) that move the axis line; what follows the joint moves with it. Rows and columns run DoF by
/// DoF in [`JointCovariance::dofs`] order. DoFs held by the gauge (a limb's first) or taken from the
/// parent limb (a base path) are not listed.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct JointCovariance {
    /// The DoFs whose lines were fitted.
    pub dofs: Vec<String>,
    /// The `4·n × 4·n` covariance, row by row.
    pub matrix: Vec<Vec<f64>>,
}

impl JointCovariance {
    /// Component names, in order.
    pub const COMPONENTS: [&'static str; 4] = ["tilt_x", "tilt_y", "shift_x", "shift_y"];
}

/// Readings of one SU left out of the fit as wild: their residual was more than
/// 6 noise standard deviations (in norm) from the fit of everything else.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct SuRejected {
    /// The SU.
    pub su: String,
    /// Static readings left out.
    pub static_readings: usize,
    /// Dynamic readings left out.
    pub dynamic_readings: usize,
    /// Readings of this SU in the fit, all kinds (for the share).
    pub readings: usize,
}

/// The readings left out, per SU that has any.
fn rejected_counts(readings: &Readings, names: &[String]) -> Vec<SuRejected> {
    names
        .iter()
        .enumerate()
        .filter_map(|(u, su)| {
            let (mut s, mut d, mut n) = (0, 0, 0);
            for (p, pose) in readings.rejected.iter().enumerate() {
                for (j, &r) in pose[u].iter().enumerate() {
                    let missing = readings.missing.get(p).is_some_and(|m| m[u][j]);
                    if missing {
                        continue;
                    }
                    n += 1;
                    match (r, j) {
                        (true, 0) => s += 1,
                        (true, _) => d += 1,
                        _ => {}
                    }
                }
            }
            (s + d > 0).then(|| SuRejected {
                su: su.clone(),
                static_readings: s,
                dynamic_readings: d,
                readings: n,
            })
        })
        .collect()
}

/// One SU's estimated accelerometer intrinsics.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct SuIntrinsics {
    /// The SU.
    pub su: String,
    /// The estimate (components not estimated are 0).
    pub value: Intrinsics,
    /// Standard deviation of each component (0 where not estimated).
    pub sd: Intrinsics,
    /// Components the readings do not determine (e.g. the bias along an axis that gravity never
    /// turns about): held near the ideal sensor's value by the prior, with about the prior's
    /// standard deviation.
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub held: Vec<String>,
}

/// A parameter direction the data cannot determine.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Unobservable {
    /// Relative singular value of the whitened Jacobian.
    pub singular_value: f64,
    /// The parameters that make up the direction, largest share first.
    pub parameters: Vec<String>,
}

/// A chain in the paper's DH+2 form (Fig. 6).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct DhTable {
    /// DoF-to-DoF rows `k → k+1`.
    pub dof_dof: Vec<super::DhRow>,
    /// DoF-to-SU rows.
    pub dof_su: Vec<super::SuRow>,
    /// The standard deviation of every value of `dof_dof` (from the parameter covariance).
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub dof_dof_sd: Vec<super::DhRow>,
    /// The standard deviation of every value of `dof_su`.
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub dof_su_sd: Vec<super::SuRow>,
}

/// How well one order of a multi-DoF joint's DoFs explains the accelerations.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct OrderMisfit {
    /// DoFs from the parent segment outwards.
    pub dofs: Vec<String>,
    /// Scatter of the accelerations about the closed-form axis model (m², accelerations divided
    /// by α); the order along the chain has the smallest, near the noise floor.
    pub misfit: f64,
}

/// The order found for the DoFs of a joint that has several.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct JointOrder {
    /// The joint.
    pub joint: String,
    /// Its DoFs from the parent segment outwards.
    pub dofs: Vec<String>,
    /// Every order tried, best first.
    pub alternatives: Vec<OrderMisfit>,
}

/// What a limb's time-domain fit used and found beside the kinematics.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct MotionFit {
    /// Blocks of the motion record fitted.
    pub blocks: usize,
    /// How late the skin's stamps run behind the joint states', s.
    pub skin_delay: f64,
    /// Its standard deviation, s.
    pub skin_delay_sd: f64,
}

/// A larger intrinsics model against the smaller one before it, fitted to the same readings: the
/// nested F test, `F = ((χ²_small − χ²_large) / k) / (χ²_large / ν)` with `k` the added
/// parameters and `ν` the large model's residual degrees of freedom, whose scale does not depend
/// on the noise assumed. The larger model is taken when `F` lies 5 standard deviations beyond
/// what the smaller one explains (`z` > 5 in Paulson's normal approximation, p ≈ 3·10⁻⁷): a
/// real robot's readings are never exactly the model's, and ideal sensors fitted a bias at
/// z = 3.7 for the smallest misfit (a UR5, clean, where it cost 60 % of the held-out static
/// accuracy), while real ones ask for theirs at z = 16 and beyond.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct IntrinsicsTest {
    /// The larger model.
    pub model: IntrinsicsModel,
    /// The model it was tested against.
    pub against: IntrinsicsModel,
    /// Parameters it adds.
    pub parameters: usize,
    /// Residual degrees of freedom of the larger model.
    pub degrees_of_freedom: usize,
    /// χ² of the smaller and of the larger model.
    #[serde(default)]
    pub chi2: [f64; 2],
    /// The F statistic.
    pub f: f64,
    /// Paulson's normal deviate of `f` (≈ N(0, 1) when the larger model adds nothing).
    pub z: f64,
    /// Whether the larger model was taken.
    pub taken: bool,
}

/// The normal deviate that [`IntrinsicsTest`] takes a larger model beyond.
pub const INTRINSICS_TEST_Z: f64 = 5.0;

/// The tests of several limbs of one skin pooled step by step (their χ², parameters and degrees
/// of freedom summed: one skin, one sensor model), and the model they choose: the largest reached
/// by tests that are all taken. `None` when no limb has a test.
pub fn pooled_intrinsics<'a>(
    tests: impl IntoIterator<Item = &'a [IntrinsicsTest]>,
) -> Option<(IntrinsicsModel, Vec<IntrinsicsTest>)> {
    let mut steps: Vec<(IntrinsicsModel, IntrinsicsModel, [f64; 2], usize, usize)> = Vec::new();
    for limb in tests {
        for (i, t) in limb.iter().enumerate() {
            if steps.len() <= i {
                steps.push((t.model, t.against, [0.0; 2], 0, 0));
            }
            let step = &mut steps[i];
            if step.0 != t.model {
                continue;
            }
            step.2[0] += t.chi2[0];
            step.2[1] += t.chi2[1];
            step.3 += t.parameters;
            step.4 += t.degrees_of_freedom;
        }
    }
    let first = steps.first()?.1;
    let pooled: Vec<IntrinsicsTest> = steps
        .into_iter()
        .map(|(model, against, chi2, k, nu)| {
            IntrinsicsTest::new(model, against, chi2[0], chi2[1], k, nu)
        })
        .collect();
    let chosen = pooled
        .iter()
        .take_while(|t| t.taken)
        .last()
        .map_or(first, |t| t.model);
    Some((chosen, pooled))
}

impl IntrinsicsTest {
    /// The test of `model` against `against` from their χ² (`small`, `large`), the parameters
    /// `model` adds and its residual degrees of freedom.
    pub fn new(
        model: IntrinsicsModel,
        against: IntrinsicsModel,
        small: f64,
        large: f64,
        parameters: usize,
        degrees_of_freedom: usize,
    ) -> Self {
        let (k, nu) = (parameters.max(1) as f64, degrees_of_freedom.max(1) as f64);
        let f = ((small - large).max(0.0) / k) / (large / nu).max(1e-300);
        // Paulson (1942): F^(1/3) is nearly normal.
        let (a, b) = (2.0 / (9.0 * k), 2.0 / (9.0 * nu));
        let root = f.cbrt();
        let z = ((1.0 - b) * root - (1.0 - a)) / (a + root * root * b).sqrt();
        Self {
            model,
            against,
            parameters,
            degrees_of_freedom,
            chi2: [small, large],
            f,
            z,
            taken: z > INTRINSICS_TEST_Z,
        }
    }
}

/// The noise of a limb's static and dynamic readings, estimated apart (two variance components)
/// from the residuals of a fit that weighed every reading alike: a dynamic reading is a difference
/// of samples, √2 times a static one's noise and more.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct NoiseComponents {
    /// Standard deviation of a static reading's component, m/s².
    pub static_sd: f64,
    /// Standard deviation of a dynamic reading's component, m/s².
    pub dynamic_sd: f64,
}

/// The maximum-likelihood estimate of one limb.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct MlChainEstimate {
    /// The limb, the DoFs of every joint in the order found.
    pub chain: LimbChain,
    /// For every joint of several DoFs: the order found and how well each order fits.
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub joint_orders: Vec<JointOrder>,
    /// The estimated limb as a robot description (reference = the first DoF's joint frame; the
    /// base path's joints, for a limb on a branching segment, as the parent limb estimated them).
    pub robot: RobotFile,
    /// Gravity in the reference frame, m/s².
    pub gravity: [f64; 3],
    /// Residual RMS relative to the noise standard deviation (≈ 1 at the noise limit).
    pub residual_ratio: f64,
    /// Estimated noise standard deviation, m/s² (with `reading_sd`: the residual in units of the
    /// configured `noise_sd`).
    pub noise_sd_estimate: f64,
    /// Whether every reading was weighted by its own standard deviation (from the measurement
    /// set) rather than by the configured noise.
    #[serde(default)]
    pub reading_sd: bool,
    /// Whether the residual is at the noise level: within its band at the data's size
    /// ([`ResidualBand`]; a fit on a motion record: within `MlConfig::converged_ratio`).
    pub converged: bool,
    /// The band of the residual ratio at the noise level, at the fit's size (readings fits).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub residual_band: Option<ResidualBand>,
    /// The gauge: parameters held, or directions the data leave free.
    pub fixed: Vec<String>,
    /// Directions the data do not determine.
    pub unobservable: Vec<Unobservable>,
    /// Per SU: standard deviations.
    pub uncertainty: Vec<SuUncertainty>,
    /// The covariance of the fitted joint lines.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub joint_covariance: Option<JointCovariance>,
    /// Per SU, in [`LimbChain::sus`] order: the RMS of its residuals relative to the noise (≈ 1
    /// for an SU the model explains; far above the others: a broken or loose SU).
    #[serde(default)]
    pub su_residual_ratio: Vec<f64>,
    /// Per SU with wild readings (glitches): how many were left out of the fit.
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub rejected: Vec<SuRejected>,
    /// The limb's DoFs whose dynamic readings the set lacks, with the number of training poses
    /// that lack them (a DoF lacking them in every pose is placed from gravity alone).
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub missing_excitations: Vec<(String, usize)>,
    /// Per SU: the accelerometer intrinsics estimated with the kinematics (empty when none are).
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub intrinsics: Vec<SuIntrinsics>,
    /// The intrinsics fitted (with `select_intrinsics`, the model the data chose).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub intrinsics_model: Option<IntrinsicsModel>,
    /// With `select_intrinsics`: each larger model against the one before it, in order.
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub intrinsics_tests: Vec<IntrinsicsTest>,
    /// Where the set gives no reading its own deviation: the static and the dynamic readings'
    /// noise estimated apart from the residuals, which weighed them in the fit.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub noise_components: Option<NoiseComponents>,
    /// Other orders of joints' DoFs tried because the first fit was not at the noise level, and
    /// how each fitted.
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub retries: Vec<String>,
    /// The same limb in the paper's DH+2 form (only for a paper-style chain: single-DoF joints,
    /// one SU per segment).
    pub dh: Option<DhTable>,
    /// The time-domain fit's share: the blocks of the motion record fitted, and how late the skin's
    /// stamps run behind the joint states'. `None`: fitted on the measurement set's readings.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub motion: Option<MotionFit>,
    /// LM iterations, all solves.
    pub iterations: usize,
    /// Wall time, s. Not written to files: a model file is the same for the same data, whichever
    /// run or machine made it.
    #[serde(default, skip_serializing)]
    pub seconds: f64,
    /// The estimate in the estimator's own chart (not written to files).
    #[serde(skip)]
    pub state: Option<ChainState>,
    /// What its final fit solved (not written to files; no part of the estimate's value).
    #[serde(skip)]
    pub(crate) problem: FitProblem,
}

/// What a limb's final fit solved, kept with its estimate for the fit of its whole tree; any two
/// are equal (it is how the estimate was reached, not what it is).
#[derive(Clone, Default)]
pub(crate) struct FitProblem(Option<std::sync::Arc<FinalProblem>>);

impl PartialEq for FitProblem {
    fn eq(&self, _: &Self) -> bool {
        true
    }
}

impl std::fmt::Debug for FitProblem {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(if self.0.is_some() {
            "FitProblem(kept)"
        } else {
            "FitProblem(none)"
        })
    }
}

impl MlChainEstimate {
    /// The estimated limb as a robot.
    pub fn to_robot(&self) -> Robot {
        self.robot
            .build()
            .expect("an estimated chain is a valid robot")
    }
}

fn readings(data: &LimbData) -> Readings {
    Readings {
        q: data.q.clone(),
        turns: {
            let kinds = data.chain.kinds();
            data.q.iter().map(|q| turns_of(q, &kinds)).collect()
        },
        statics: data.statics.clone(),
        dynamics: data.dynamics.clone(),
        alpha: data.pattern.peak_acceleration(),
        huber: Some(HUBER),
        rejected: Vec::new(),
        missing: data.missing.clone(),
        gauge_prior: Some(problem::POSITION_PRIOR_SD),
        sd: data.sd.clone().map(std::sync::Arc::new),
        motion: None,
    }
}

/// Huber's threshold on a reading's whitened residual norm: the 99.9 % point of χ² with 3 degrees
/// of freedom is 16.3, so nearly every reading of an honest fit counts fully.
const HUBER: f64 = 4.03;
/// A reading whose whitened residual norm exceeds this after the fit is left out as wild (χ² with
/// 3 degrees of freedom passes 36 with probability 4·10⁻⁸), and the fit is repeated without it.
const REJECT: f64 = 6.0;
/// The largest share of one SU's readings that may be left out as wild.
const MAX_GLITCH_SHARE: f64 = 0.1;
/// Most rounds of leaving wild readings out and fitting again.
const REJECT_ROUNDS: usize = 4;

/// Readings the search should not trust, before any fit (`[p][u][row]` as
/// [`Readings::rejected`]): a static reading whose norm is 0.15 g off the SU's median norm (a
/// static reading's norm is |g|), and a dynamic one more than 3 times the SU's median for that DoF
/// (plus 8σ). The final fit judges every reading again by its residual.
fn screen(data: &Readings, sigma: f64) -> Vec<Vec<Vec<bool>>> {
    let poses = data.q.len();
    let sus = data.statics.first().map_or(0, Vec::len);
    let median = |mut v: Vec<f64>| {
        v.sort_by(f64::total_cmp);
        v.get(v.len() / 2).copied().unwrap_or(0.0)
    };
    let mut out: Vec<Vec<Vec<bool>>> = (0..poses)
        .map(|p| {
            (0..sus)
                .map(|u| vec![false; 1 + data.dynamics[p][u].len()])
                .collect()
        })
        .collect();
    for u in 0..sus {
        let norm = median((0..poses).map(|p| data.statics[p][u].norm()).collect());
        for (p, pose) in out.iter_mut().enumerate() {
            pose[u][0] = (data.statics[p][u].norm() - norm).abs() > 0.15 * STANDARD_GRAVITY;
        }
        let depth = data.dynamics.first().map_or(0, |d| d[u].len());
        for d in 0..depth {
            let typical = median(
                (0..poses)
                    .filter(|&p| !data.is_rejected(p, u, 1 + d))
                    .map(|p| data.dynamics[p][u][d].norm())
                    .collect(),
            );
            for (p, pose) in out.iter_mut().enumerate() {
                pose[u][1 + d] = data.dynamics[p][u][d].norm() > 3.0 * typical + 8.0 * sigma;
            }
        }
    }
    out
}

/// Most DoFs in one joint whose order is searched (all orders are tried).
const MAX_JOINT_DOFS: usize = 4;
/// Starts (local minima of the closed-form misfit, each with both senses of the first axis) tried
/// for the lines of a multi-DoF joint.
const LINE_STARTS: usize = 2;
/// Relative cost decrease below which an initialisation solve stops.
const INIT_TOLERANCE: f64 = 1e-6;
/// Relative cost decrease below which the final refinement stops.
const FINAL_TOLERANCE: f64 = 1e-10;

/// Estimates one serial chain (one DoF and one SU per joint) by maximum likelihood.
///
/// ```
/// use skincal::estimate::{ml, ChainData, SerialChain};
/// use skincal::model::presets;
/// use skincal::sim::{simulate, SimulationConfig};
///
/// let robot = presets::find("paper-7dof").unwrap().robot().unwrap();
/// let set = simulate(&robot, &SimulationConfig::default()).unwrap().measurements;
/// let chain = SerialChain { name: "arm".into(), dofs: robot.model.dof_names(), sus: robot.model.su_names() };
/// let estimate = ml::estimate_chain(&ChainData::new(&set, &chain).unwrap(), &ml::MlConfig::default()).unwrap();
/// assert!(estimate.converged);
/// assert!((estimate.residual_ratio - 1.0).abs() < 0.2); // at the noise level
/// ```
pub fn estimate_chain(
    data: &ChainData,
    config: &MlConfig,
) -> Result<MlChainEstimate, EstimateError> {
    estimate_limb(&LimbData::from(data), None, config)
}

/// A joint of the limb in chain indices: its first and last DoF and the SUs on the segment it moves.
struct Span {
    k0: usize,
    k1: usize,
    sus: Vec<usize>,
}

fn spans(data: &LimbData) -> Vec<Span> {
    let mut out = Vec::new();
    let mut k = 0;
    for joint in &data.chain.joints {
        let k1 = k + joint.dofs.len() - 1;
        out.push(Span {
            k0: k,
            k1,
            sus: (0..data.su_depth.len())
                .filter(|&u| data.su_depth[u] == k1 + 1)
                .collect(),
        });
        k = k1 + 1;
    }
    out
}

/// A start for one joint's solves.
struct Candidate {
    state: ChainState,
    cost: f64,
    beam: usize,
}

/// Keeps the `size` cheapest distinct states.
fn keep_best(mut ranked: Vec<(ChainState, f64)>, size: usize) -> Vec<(ChainState, f64)> {
    ranked.sort_by(|a, b| a.1.total_cmp(&b.1));
    let mut beam: Vec<(ChainState, f64)> = Vec::new();
    for (state, cost) in ranked {
        if beam.len() == size.max(1) {
            break;
        }
        if beam
            .iter()
            .all(|(_, c)| (c - cost).abs() > 1e-7 * cost.abs().max(1.0))
        {
            beam.push((state, cost));
        }
    }
    beam
}

/// Estimates one limb by maximum likelihood: joints of one or more DoFs, any number of SUs per
/// segment. With `base`, the joints of the limb's base path are held at that earlier estimate.
pub fn estimate_limb(
    data: &LimbData,
    base: Option<&LimbBase>,
    config: &MlConfig,
) -> Result<MlChainEstimate, EstimateError> {
    validate(config)?;
    let started = Instant::now();
    let base_dofs = data.chain.base_dofs();
    check_base(data, base)?;
    let (orders, joint_orders) = order_joints(data, config)?;
    let fit = |choice: &[usize], config: &MlConfig| {
        let ordered = orders
            .iter()
            .zip(choice)
            .fold(data.clone(), |d, ((j, tried), &c)| {
                d.with_joint_order(*j, &tried[c].0)
            });
        fit_ordered(&ordered, base, base_dofs, config)
    };
    let mut best = fit(&vec![0; orders.len()], config)?;
    let mut retries = Retries {
        iterations: best.iterations,
        notes: Vec::new(),
    };
    let done = |e: &MlChainEstimate| config.search_done(e, base.is_some());
    retries.other_orders(&mut best, data, &orders, done, |c| fit(c, config))?;
    retries.wider_search(&mut best, data, &orders, config, done, fit)?;
    best.joint_orders = joint_orders
        .into_iter()
        .map(|mut o| {
            if let Some(j) = best.chain.joints.iter().find(|j| j.id == o.joint) {
                o.dofs = j.dofs.clone();
            }
            o
        })
        .collect();
    best.retries = retries.notes;
    best.iterations = retries.iterations;
    best.seconds = started.elapsed().as_secs_f64();
    Ok(best)
}

/// Refuses a base estimate that is not the limb's base path, and a sub-limb without one.
fn check_base(data: &LimbData, base: Option<&LimbBase>) -> Result<(), EstimateError> {
    let chain = &data.chain;
    let base_dofs = chain.base_dofs();
    match base {
        Some(b) if b.joints.len() != base_dofs => Err(EstimateError::UnsupportedLimb {
            limb: chain.name.clone(),
            reason: format!(
                "its base path has {base_dofs} DoFs but the base estimate {}",
                b.joints.len()
            ),
        }),
        None if chain.base_joints > 0 => Err(EstimateError::UnsupportedLimb {
            limb: chain.name.clone(),
            reason: "it hangs on a branching segment: estimate the limb that leads there first"
                .into(),
        }),
        _ => Ok(()),
    }
}

/// The order of every multi-DoF joint's DoFs as [`order_joints`] gives them: per joint its index
/// and every order with its misfit, best first.
type JointOrders = Vec<(usize, Vec<(Vec<usize>, f64)>)>;

/// The retry policy of a limb's fit that is not at the noise level: what was tried and the LM
/// iterations of every fit.
struct Retries {
    iterations: usize,
    notes: Vec<String>,
}

impl Retries {
    /// The closed-form order of a joint's DoFs may be wrong (joint limits narrow what its axes
    /// show): the next orders of each joint in turn ([`ORDER_RETRIES`]), each fitted by `fit`
    /// from the choice of orders, until one is `done`; `best` the best of them.
    fn other_orders(
        &mut self,
        best: &mut MlChainEstimate,
        data: &LimbData,
        orders: &JointOrders,
        done: impl Fn(&MlChainEstimate) -> bool,
        fit: impl Fn(&[usize]) -> Result<MlChainEstimate, EstimateError>,
    ) -> Result<(), EstimateError> {
        for (n, (j, tried)) in orders.iter().enumerate() {
            for (c, (order, _)) in tried.iter().enumerate().skip(1).take(ORDER_RETRIES) {
                if done(best) {
                    return Ok(());
                }
                let mut choice = vec![0; orders.len()];
                choice[n] = c;
                let names: Vec<String> = order
                    .iter()
                    .map(|&i| data.chain.joints[*j].dofs[i].clone())
                    .collect();
                let alternative = fit(&choice)?;
                let what = format!(
                    "joint {} in the order {}",
                    data.chain.joints[*j].id,
                    names.join(", ")
                );
                self.keep_better(best, alternative, what);
            }
        }
        Ok(())
    }

    /// Still not at the noise level: a wider search (more candidates kept per joint, more
    /// rotation starts), with the orders that fitted best.
    fn wider_search(
        &mut self,
        best: &mut MlChainEstimate,
        data: &LimbData,
        orders: &JointOrders,
        config: &MlConfig,
        done: impl Fn(&MlChainEstimate) -> bool,
        fit: impl Fn(&[usize], &MlConfig) -> Result<MlChainEstimate, EstimateError>,
    ) -> Result<(), EstimateError> {
        if done(best) {
            return Ok(());
        }
        let wider = MlConfig {
            beam: config.beam * WIDER_BEAM,
            angle_starts: config.angle_starts * WIDER_ANGLES,
            ..*config
        };
        let choice: Vec<usize> = orders
            .iter()
            .map(|(j, tried)| {
                tried
                    .iter()
                    .position(|(o, _)| {
                        o.iter()
                            .map(|&i| &data.chain.joints[*j].dofs[i])
                            .eq(best.chain.joints[*j].dofs.iter())
                    })
                    .unwrap_or(0)
            })
            .collect();
        let alternative = fit(&choice, &wider)?;
        let what = format!(
            "a wider search (beam {}, {} rotation starts)",
            wider.beam, wider.angle_starts
        );
        self.keep_better(best, alternative, what);
        Ok(())
    }

    /// Notes what was tried (`what`) with its residual and keeps the better of the two.
    fn keep_better(
        &mut self,
        best: &mut MlChainEstimate,
        alternative: MlChainEstimate,
        what: String,
    ) {
        self.iterations += alternative.iterations;
        self.notes.push(format!(
            "{what}: residual {:.2} σ (was {:.2} σ)",
            alternative.residual_ratio, best.residual_ratio
        ));
        if alternative.residual_ratio < best.residual_ratio {
            *best = alternative;
        }
    }
}

/// How many other orders of one joint's DoFs are tried when a fit is not at the noise level: all
/// five others of a three-DoF joint (the limits can hide which of its axes comes first).
const ORDER_RETRIES: usize = 5;
/// How much wider the last search of a fit not at the noise level is: its beam and its rotation
/// starts, times.
const WIDER_BEAM: usize = 16;
const WIDER_ANGLES: usize = 4;

/// The order of the DoFs inside every joint that has several, from the closed-form axis model:
/// per such joint its index and every order (relative to the input's) with its misfit, best first,
/// and how it is reported. Reordering one joint permutes only its own DoF indices, so the input's
/// readings and spans serve every joint.
#[allow(clippy::type_complexity)]
fn order_joints(
    data: &LimbData,
    config: &MlConfig,
) -> Result<(Vec<(usize, Vec<(Vec<usize>, f64)>)>, Vec<JointOrder>), EstimateError> {
    let chain = &data.chain;
    let mut input_readings = readings(data);
    input_readings.rejected = screen(&input_readings, config.noise_sd);
    let input_spans = spans(data);
    let mut orders = Vec::new();
    let mut joint_orders = Vec::new();
    for (j, span) in input_spans.iter().enumerate().skip(chain.base_joints) {
        let m = span.k1 - span.k0 + 1;
        if m == 1 {
            continue;
        }
        if m > MAX_JOINT_DOFS {
            return Err(EstimateError::UnsupportedLimb {
                limb: chain.name.clone(),
                reason: format!(
                    "joint {} has {m} DoFs ({}) with no SU between them; at most {MAX_JOINT_DOFS} can be put in order from the data: put an SU on a segment between them, or check the structure (`skincal explore`)",
                    chain.joints[j].id,
                    chain.joints[j].dofs.join(", ")
                ),
            });
        }
        let mut tried: Vec<(Vec<usize>, f64)> = init::permutations(m)
            .into_iter()
            .map(|order| {
                let dofs: Vec<usize> = order.iter().map(|&i| span.k0 + i).collect();
                let misfit = init::joint_lines(&input_readings, span.sus[0], &dofs).misfit;
                (order, misfit)
            })
            .collect();
        tried.sort_by(|a, b| a.1.total_cmp(&b.1));
        let names = &chain.joints[j].dofs;
        let alternatives = tried
            .iter()
            .map(|(order, misfit)| OrderMisfit {
                dofs: order.iter().map(|&i| names[i].clone()).collect(),
                misfit: *misfit,
            })
            .collect();
        joint_orders.push(JointOrder {
            joint: chain.joints[j].id.clone(),
            dofs: tried[0].0.iter().map(|&i| names[i].clone()).collect(),
            alternatives,
        });
        orders.push((j, tried));
    }
    Ok((orders, joint_orders))
}

/// The search and the final fit of a limb whose joints' DoFs are in their order: the paper's
/// Algorithm 2 as steps — the first joint from gravity, each later joint searched from every state
/// of the beam, the SUs of each segment added, then the whole limb at once.
fn fit_ordered(
    data: &LimbData,
    base: Option<&LimbBase>,
    base_dofs: usize,
    config: &MlConfig,
) -> Result<MlChainEstimate, EstimateError> {
    let started = Instant::now();
    enough_poses(data, base_dofs)?;
    let search = Search::new(data, config);
    let first = data.chain.base_joints;
    let (mut beam, vertical, mut iterations) = match base {
        Some(b) => (vec![(search.on_base(b), 0.0)], false, 0),
        None => search.first_joint(first),
    };
    let after = if base.is_some() { first } else { first + 1 };
    for span in &search.spans[after..] {
        let (next, its) = search.next_joint(&beam, span);
        beam = next;
        iterations += its;
    }
    let mut state = beam.swap_remove(0).0;
    if vertical {
        // Held along the first axis in the final fit (below).
        state.gravity = Vector3::new(0.0, 0.0, state.gravity.z.signum() * state.gravity.norm());
    }
    final_fit(
        data,
        base,
        search.readings,
        state,
        vertical,
        iterations,
        started,
        config,
    )
}

/// Refuses a limb with fewer poses than its parameters need (at least [`super::body::MIN_POSES`]).
fn enough_poses(data: &LimbData, base_dofs: usize) -> Result<(), EstimateError> {
    let dofs = data.q.first().map_or(0, |q| q.len());
    let parameters = 3 + 4 * (dofs - base_dofs) + 6 * data.su_depth.len();
    let per_pose: usize = data.su_depth.iter().map(|&d| 3 * (1 + d)).sum();
    let needed = parameters
        .div_ceil(per_pose.max(1))
        .max(super::body::MIN_POSES);
    if data.poses() < needed {
        return Err(EstimateError::TooFewPoses {
            poses: data.poses(),
            parameters: needed,
        });
    }
    Ok(())
}

/// What the search of a limb works on: its layout, its readings (screened) and the span of every
/// joint.
struct Search<'a> {
    data: &'a LimbData,
    config: &'a MlConfig,
    layout: Layout,
    readings: Readings,
    spans: Vec<Span>,
    /// Every joint at the identity, every SU at its segment's origin, no gravity.
    empty: ChainState,
}

impl<'a> Search<'a> {
    fn new(data: &'a LimbData, config: &'a MlConfig) -> Self {
        let dofs = data.q.first().map_or(0, |q| q.len());
        let sus = data.su_depth.len();
        let mut readings = readings(data);
        readings.rejected = screen(&readings, config.noise_sd);
        Self {
            data,
            config,
            layout: Layout::of(data),
            readings,
            spans: spans(data),
            empty: ChainState {
                gravity: Vector3::zeros(),
                joints: vec![Isometry3::identity(); dofs],
                sus: vec![Isometry3::identity(); sus],
                intrinsics: vec![Intrinsics::default(); sus],
                skin_delay: 0.0,
            },
        }
    }

    /// A sub-limb's start: its base path and gravity as the parent limb estimated them.
    fn on_base(&self, base: &LimbBase) -> ChainState {
        let mut state = self.empty.clone();
        state.joints[..base.joints.len()].copy_from_slice(&base.joints);
        state.gravity = base.gravity;
        state
    }

    /// Starts of `state` with the SU `u` of a joint's segment placed from its DoFs `k0..=k1`:
    /// for a single DoF, both senses of its axis (mirror images fit the segment equally well);
    /// for several, the joint's lines searched from gravity.
    fn su_starts(&self, state: &ChainState, k0: usize, k1: usize, u: usize) -> Vec<ChainState> {
        if k0 == k1 {
            return [1.0, -1.0]
                .into_iter()
                .map(|sign| {
                    let mut s = state.clone();
                    s.sus[u] = init::su_from_axis(&s, &self.layout, &self.readings, u, k0, sign);
                    s
                })
                .collect();
        }
        let dofs: Vec<usize> = (k0..=k1).collect();
        init::joint_line_starts(&self.readings, u, &dofs, LINE_STARTS)
            .into_iter()
            .map(|lines| {
                let mut s = state.clone();
                init::place_joint_lines(&mut s, k0, u, &lines.lines);
                s
            })
            .collect()
    }

    fn solve(&self, state: ChainState, spec: &Spec, max: usize) -> Solved {
        solve(
            state,
            &self.layout,
            &self.readings,
            spec,
            self.config.noise_sd,
            max,
            INIT_TOLERANCE,
        )
    }

    /// The first joint (`first`): its tail in closed form, gravity from the static readings,
    /// each start refined; then its segment's SUs. Returns the beam, whether the first axis is
    /// vertical (every start's likelihood-ratio test of gravity along it says so) and the LM
    /// iterations.
    fn first_joint(&self, first: usize) -> (Vec<(ChainState, f64)>, bool, usize) {
        let span = &self.spans[first];
        let u = span.sus[0];
        let starts = self.su_starts(&self.empty, span.k0, span.k1, u);
        let count = starts.len();
        let mut beam = Vec::with_capacity(count);
        let (mut votes, mut iterations) = (0, 0);
        for mut s in starts {
            s.gravity = self.gravity_from_statics(&s, span.k1, u);
            let mut blocks = vec![Block::Gravity];
            blocks.extend((1..=span.k1).map(Block::Joint));
            blocks.push(Block::Su(u));
            let su_block = blocks.len() - 1;
            let spec = Spec {
                blocks,
                held: if span.k0 == span.k1 {
                    vec![(su_block, 2), (su_block, 5)]
                } else {
                    vec![]
                },
                sus: vec![u],
                prefix: None,
            };
            let (free, upright, its) = self.vertical_test(s, spec);
            iterations += its;
            votes += usize::from(upright);
            // The search goes on with gravity free even so: held exactly along the first axis,
            // it leaves the turn of the next joint about that axis exactly free, and the searches
            // of the joints after it settle in degenerate minima (on robot-like limbs with a
            // vertical first axis, about a quarter did). Gravity is put on the axis for the final fit.
            beam.push((free.state, free.cost));
        }
        // Mirror images have the same cost here: keep them all (no merging of equal costs).
        beam.sort_by(|a, b| a.1.total_cmp(&b.1));
        beam.truncate(self.config.beam.max(2));
        let (beam, its) = add_segment_sus(beam, &self.layout, &self.readings, span, self.config);
        (beam, votes == count, iterations + its)
    }

    /// Gravity in the reference frame as the static readings of SU `u` on the segment after DoF
    /// `k1` give it at `state`: minus their mean turned into the reference frame.
    fn gravity_from_statics(&self, state: &ChainState, k1: usize, u: usize) -> Vector3<f64> {
        let tail = init::tails(state, &self.readings, 0, k1, u);
        let poses = self.data.poses();
        let minus_g: Vector3<f64> = (0..poses)
            .map(|p| self.readings.turns[p][0] * (tail[p].rotation * self.readings.statics[p][u]))
            .sum::<Vector3<f64>>()
            / poses as f64;
        -minus_g
    }

    /// `start` refined under `spec` with gravity free, and again with gravity held along the
    /// first axis: the free fit, whether the first axis is vertical (the likelihood ratio of the
    /// two below the configured test) and the iterations of both.
    fn vertical_test(&self, start: ChainState, spec: Spec) -> (Solved, bool, usize) {
        let max = self.config.max_iterations;
        let free = self.solve(start, &spec, max);
        let mut upright = free.state.clone();
        upright.gravity = Vector3::new(
            0.0,
            0.0,
            upright.gravity.z.signum() * upright.gravity.norm(),
        );
        let mut held = spec.held.clone();
        held.extend([(0, 0), (0, 1)]);
        let fixed = self.solve(upright, &Spec { held, ..spec }, max);
        let vertical = fixed.cost - free.cost < self.config.vertical_test;
        let iterations = free.iterations + fixed.iterations;
        (free, vertical, iterations)
    }

    /// The joint of `span` after the beam's: its tail in closed form, its rotation from gravity
    /// (or searched), its position from upstream accelerations, every candidate refined in
    /// parallel ([`Search::joint_then_lines`]), the best few kept and its segment's SUs added.
    fn next_joint(
        &self,
        beam: &[(ChainState, f64)],
        span: &Span,
    ) -> (Vec<(ChainState, f64)>, usize) {
        let (k0, k1, u) = (span.k0, span.k1, span.sus[0]);
        let caches: Vec<_> = beam
            .iter()
            .map(|(state, _)| prefixes(state, &self.layout, &self.readings, k0))
            .collect();
        let mut candidates = Vec::new();
        for (b, (state, cost)) in beam.iter().enumerate() {
            for s in self.su_starts(state, k0, k1, u) {
                let tail = init::tails(&s, &self.readings, k0, k1, u);
                let starts = init::joint_starts(
                    &s,
                    &self.layout,
                    &self.readings,
                    k0,
                    u,
                    &tail,
                    self.config.angle_starts,
                );
                for start in starts {
                    let mut state = s.clone();
                    state.joints[k0] = start;
                    candidates.push(Candidate {
                        state,
                        cost: *cost,
                        beam: b,
                    });
                }
            }
        }
        let solved: Vec<(Solved, f64, usize)> = candidates
            .into_par_iter()
            .map(|c| {
                let (solved, its) = self.joint_then_lines(c.state, span, &caches[c.beam]);
                (solved, c.cost, its)
            })
            .collect();
        let mut iterations: usize = solved.iter().map(|s| s.2).sum();
        let ranked = solved
            .into_iter()
            .map(|(s, cost, _)| (s.state, cost + s.cost))
            .collect();
        let kept = keep_best(ranked, self.config.beam);
        let (beam, its) = add_segment_sus(kept, &self.layout, &self.readings, span, self.config);
        iterations += its;
        (beam, iterations)
    }

    /// One candidate of the joint of `span`: first its frame alone (a few iterations), then the
    /// joint's lines with its segment's first SU. Returns the solution and the iterations.
    fn joint_then_lines(
        &self,
        state: ChainState,
        span: &Span,
        cache: &std::sync::Arc<Vec<Prefix>>,
    ) -> (Solved, usize) {
        let (k0, k1, u) = (span.k0, span.k1, span.sus[0]);
        let frame = Spec {
            blocks: vec![Block::JointFull(k0)],
            held: vec![],
            sus: vec![u],
            prefix: Some(cache.clone()),
        };
        let first = self.solve(state, &frame, self.config.max_iterations.min(10));
        let mut blocks: Vec<Block> = (k0..=k1).map(Block::Joint).collect();
        blocks.push(Block::Su(u));
        let lines = Spec {
            blocks,
            held: vec![],
            sus: vec![u],
            prefix: Some(cache.clone()),
        };
        let second = self.solve(first.state, &lines, self.config.max_iterations);
        let iterations = first.iterations + second.iterations;
        (second, iterations)
    }
}

/// Refits a limb from `start`, a state of its layout (DoFs in `data`'s order), without the
/// search: the final fit of [`estimate_limb`]. With `base`, the base path's joints and gravity
/// are held at `base`, whatever `start` says of them. Gravity exactly along the first axis in
/// `start` (a limb from the reference whose first axis is vertical) is held there.
pub fn refine_limb(
    data: &LimbData,
    base: Option<&LimbBase>,
    start: ChainState,
    config: &MlConfig,
) -> Result<MlChainEstimate, EstimateError> {
    let (start, vertical) = held_start(data, base, start, config)?;
    let mut readings = readings(data);
    readings.rejected = screen(&readings, config.noise_sd);
    final_fit(
        data,
        base,
        readings,
        start,
        vertical,
        0,
        Instant::now(),
        config,
    )
}

/// A refit's start checked against the limb, its base path and gravity held at `base`'s; and
/// whether gravity is held along the first axis (exactly vertical in `start`, no base).
fn held_start(
    data: &LimbData,
    base: Option<&LimbBase>,
    mut start: ChainState,
    config: &MlConfig,
) -> Result<(ChainState, bool), EstimateError> {
    validate(config)?;
    let dofs = data.q.first().map_or(0, |q| q.len());
    if start.joints.len() != dofs || start.sus.len() != data.su_depth.len() {
        return Err(EstimateError::UnsupportedLimb {
            limb: data.chain.name.clone(),
            reason: "the start has another layout than the limb".into(),
        });
    }
    if let Some(b) = base {
        start.joints[..b.joints.len()].copy_from_slice(&b.joints);
        start.gravity = b.gravity;
    }
    let vertical = base.is_none() && start.gravity.x == 0.0 && start.gravity.y == 0.0;
    Ok((start, vertical))
}

/// The final fit of a limb on every sample of its motion record (`motion`, from the same robot's
/// log), from `start` (a fit on the measurement set's readings: the search's starts come from
/// there); the skin's delay behind the joint states is fitted with it. With `base`, the base
/// path and gravity are held at `base`, as in [`refine_limb`].
pub fn refine_on_motion(
    data: &LimbData,
    base: Option<&LimbBase>,
    start: ChainState,
    mut motion: LimbMotion,
    config: &MlConfig,
) -> Result<MlChainEstimate, EstimateError> {
    let (start, vertical) = held_start(data, base, start, config)?;
    if motion.is_empty() {
        return Err(EstimateError::UnsupportedLimb {
            limb: data.chain.name.clone(),
            reason: "the motion record has no block to fit".into(),
        });
    }
    let readings = motion_readings(data);
    let (start, iterations) = if data.static_only() {
        let lead = Lead {
            data,
            base,
            readings: &readings,
            motion: &motion,
            vertical,
            config,
        };
        let ((led, _), its) = lead.run(start);
        (led, its)
    } else {
        (start, 0)
    };
    motion.weigh(&start, &data.su_depth);
    let readings = Readings {
        motion: Some(std::sync::Arc::new(motion)),
        ..readings
    };
    final_fit(
        data,
        base,
        readings,
        start,
        vertical,
        iterations,
        Instant::now(),
        config,
    )
}

/// A limb's readings for a fit on its motion record alone: the measurement set's readings came
/// from the same log.
fn motion_readings(data: &LimbData) -> Readings {
    Readings {
        q: Vec::new(),
        turns: Vec::new(),
        statics: Vec::new(),
        dynamics: Vec::new(),
        missing: Vec::new(),
        sd: None,
        motion: None,
        ..readings(data)
    }
}

/// What leading a start from static readings to a limb's motion takes: the limb, its base, its
/// readings (the motion rows come from `motion`) and whether gravity is held along a vertical
/// first axis.
struct Lead<'a> {
    data: &'a LimbData,
    base: Option<&'a LimbBase>,
    readings: &'a Readings,
    motion: &'a LimbMotion,
    vertical: bool,
    config: &'a MlConfig,
}

impl Lead<'_> {
    /// [`Lead::stages`] from `start` and, where gravity is held along a vertical first
    /// axis, from its mirror image too ([`mirrored`]: gravity alone cannot tell which way that
    /// axis turns, the motion tells): the better, with its cost, and the LM iterations of both.
    fn run(&self, start: ChainState) -> ((ChainState, f64), usize) {
        let (first, its) = self.stages(start.clone());
        if !self.vertical {
            return (first, its);
        }
        let (second, more) = self.stages(mirrored(&start, &self.data.su_depth));
        let better = if second.1 < first.1 { second } else { first };
        (better, its + more)
    }

    /// A start from static readings alone (orientations and axes from gravity, every position
    /// at its prior) led to the whole motion: fitted with the motion's share of each prediction
    /// taken as error, lowered step by step ([`QUASI_STATIC_STEPS`],
    /// [`LimbMotion::weigh_as_static`]) — a fit on every block at once from positions that are
    /// all wrong would explain gravity's errors with metres of lever arm. Returns the state with
    /// its cost and the LM iterations.
    fn stages(&self, start: ChainState) -> ((ChainState, f64), usize) {
        let Lead {
            data,
            base,
            readings,
            motion,
            vertical,
            config,
        } = *self;
        let layout = Layout::of(data);
        let mut spec = full_spec(
            &layout,
            data.chain.base_dofs().max(1),
            base.is_none(),
            gauge_su(data, base),
            IntrinsicsModel::None,
        );
        if vertical {
            spec.held.extend([(0, 0), (0, 1)]);
        }
        let (mut state, mut cost, mut iterations) = (start, f64::INFINITY, 0);
        let coarse = motion.thinned(LEAD_THINNING);
        for kappa in QUASI_STATIC_STEPS {
            let mut weighed = coarse.clone();
            weighed.weigh_as_static(&state, &data.su_depth, kappa);
            let stage = Readings {
                huber: None,
                motion: Some(std::sync::Arc::new(weighed)),
                ..readings.clone()
            };
            let solved = solve(
                state,
                &layout,
                &stage,
                &spec,
                config.noise_sd,
                config.max_iterations,
                LEAD_TOLERANCE,
            );
            state = solved.state;
            cost = solved.cost;
            iterations += solved.iterations;
        }
        ((state, cost), iterations)
    }
}

/// Of every order of the DoFs inside the limb's joints of several DoFs (gravity alone cannot
/// tell them apart), the readings' fit whose start leads best to the motion of `record`
/// (the lead on every fourth block), with the limb's data in that order. `first`:
/// the fit of `data`'s order, kept where the limb has no such joint or the readings hold
/// dynamic readings (which tell the order themselves).
pub fn order_on_motion(
    data: &LimbData,
    base: Option<&LimbBase>,
    first: MlChainEstimate,
    record: &crate::motion::MotionRecord,
    config: &MlConfig,
) -> Result<(MlChainEstimate, LimbData), EstimateError> {
    let chain = &data.chain;
    let joints: Vec<usize> = (chain.base_joints..chain.joints.len())
        .filter(|&j| chain.joints[j].dofs.len() > 1)
        .collect();
    if joints.is_empty() || !data.static_only() {
        return Ok((first, data.clone()));
    }
    // Every combination of the joints' orders.
    let mut choices: Vec<Vec<Vec<usize>>> = vec![Vec::new()];
    for &j in &joints {
        let orders = init::permutations(chain.joints[j].dofs.len());
        choices = choices
            .into_iter()
            .flat_map(|c| {
                orders.iter().map(move |o| {
                    let mut c = c.clone();
                    c.push(o.clone());
                    c
                })
            })
            .collect();
    }
    let mut best: Option<(f64, MlChainEstimate, LimbData)> = None;
    // The order of the first fit comes first and is taken as soon as it fits at the noise level:
    // the wrong ones leave residuals of ten to sixty standard deviations.
    let unchanged = |c: &[Vec<usize>]| c.iter().all(|o| o.iter().enumerate().all(|(i, &k)| i == k));
    choices.sort_by_key(|c| !unchanged(c));
    for choice in choices.into_iter().take(MAX_ORDER_CHOICES) {
        let identity = unchanged(&choice);
        let ordered = joints
            .iter()
            .zip(&choice)
            .fold(data.clone(), |d, (&j, o)| d.with_joint_order(j, o));
        let estimate = if identity {
            first.clone()
        } else {
            estimate_limb(&ordered, base, config)?
        };
        let Some(start) = estimate.state.clone() else {
            continue;
        };
        let (start, vertical) = held_start(&ordered, base, start, config)?;
        let motion = LimbMotion::new(record, &ordered, config.noise_sd)?.thinned(ORDER_THINNING);
        let readings = motion_readings(&ordered);
        let lead = Lead {
            data: &ordered,
            base,
            readings: &readings,
            motion: &motion,
            vertical,
            config,
        };
        let ((_, cost), _) = lead.run(start);
        let residuals = 3 * motion.len() * ordered.su_depth.len();
        let at_noise = cost <= ORDER_ACCEPTED * residuals as f64;
        if best.as_ref().is_none_or(|b| cost < b.0) {
            best = Some((cost, estimate, ordered));
        }
        if identity && at_noise {
            break;
        }
    }
    Ok(best.map_or_else(|| (first, data.clone()), |(_, e, d)| (e, d)))
}

/// [`order_on_motion`] fits every this many blocks of the record times [`LEAD_THINNING`].
const ORDER_THINNING: usize = 4;
/// The cost per residual at which [`order_on_motion`] takes the first fit's order without trying
/// the others: the humanoid's right orders led to 0.5–4.5, the wrong ones to 21–1000.
const ORDER_ACCEPTED: f64 = 2.0;
/// The most combinations of joint orders [`order_on_motion`] tries (two joints of three DoFs).
const MAX_ORDER_CHOICES: usize = 36;

/// The steps of [`Lead::stages`]: how much of what the motion adds to gravity is taken as
/// error.
const QUASI_STATIC_STEPS: [f64; 4] = [1.0, 0.3, 0.1, 0.0];
/// The steps of [`Lead::stages`] fit every this many blocks of the record: they lead the fit
/// to the right basin, the final fit takes every block.
const LEAD_THINNING: usize = 5;
/// The relative change of the cost at which a step of [`Lead::stages`] stops.
const LEAD_TOLERANCE: f64 = 1e-6;

/// The SU whose turn about and shift along the first axis are held in a limb's final fit: the
/// first, where the limb starts at the reference with a joint of one DoF (after a joint of several,
/// that freedom is left to the damping, not to a parameter).
fn gauge_su(data: &LimbData, base: Option<&LimbBase>) -> Option<usize> {
    let first = &spans(data)[data.chain.base_joints];
    (base.is_none() && first.k0 == first.k1).then_some(0)
}

/// The mirror image of a limb's state about its vertical first axis: gravity reversed, and what
/// sits on the first segment (the next joint's frame, its SUs) turned half a turn about the
/// reference's x axis. In every pose each SU reads gravity as before, but the first DoF turns
/// the other way.
fn mirrored(state: &ChainState, su_segment: &[usize]) -> ChainState {
    let half_turn = Isometry3::from_parts(
        nalgebra::Translation3::identity(),
        UnitQuaternion::from_axis_angle(&Vector3::x_axis(), std::f64::consts::PI),
    );
    let mut out = state.clone();
    out.gravity = -state.gravity;
    if let Some(j) = out.joints.get_mut(1) {
        *j = half_turn * *j;
    }
    for (su, _) in out.sus.iter_mut().zip(su_segment).filter(|(_, &s)| s == 1) {
        *su = half_turn * *su;
    }
    out
}

/// The final fit of a limb from `state`, and all that is reported of it: residual, covariance,
/// what is unobservable, intrinsics. `readings`: the limb's, screened; `vertical`: gravity is held
/// along the first axis.
#[allow(clippy::too_many_arguments)]
fn final_fit(
    data: &LimbData,
    base: Option<&LimbBase>,
    readings: Readings,
    state: ChainState,
    vertical: bool,
    mut iterations: usize,
    started: Instant,
    config: &MlConfig,
) -> Result<MlChainEstimate, EstimateError> {
    let layout = Layout::of(data);
    // The whole limb at once: the kinematics, then with the accelerometer intrinsics; glitches
    // left out; the static and dynamic noise weighed apart.
    let gauge_su = gauge_su(data, base);
    let final_spec = |intrinsics: IntrinsicsModel| {
        let gauge = Gauge {
            base_dofs: data.chain.base_dofs(),
            base: base.is_some(),
            su: gauge_su,
            vertical,
        };
        final_spec(
            &layout,
            &gauge,
            readings.motion.is_some(),
            intrinsics,
            config,
        )
    };
    let (solved, spec, intrinsics_model, intrinsics_tests, its) =
        fit_with_intrinsics(state, &layout, &readings, final_spec, config);
    iterations += its;
    let (solved, readings, its) = leave_out_glitches(solved, &layout, &readings, &spec, config);
    iterations += its;
    let rejected = rejected_counts(&readings, &data.chain.sus());
    let (solved, weighted, its, noise_components) =
        weigh_by_noise_components(solved, &layout, readings, &spec, config);
    iterations += its;
    let fixed = gauge_statement(data, base, gauge_su, vertical, &spec);
    let problem = FinalProblem {
        data: data.clone(),
        layout,
        spec,
        readings: weighted,
        fixed,
        intrinsics_model,
        intrinsics_tests,
        noise_components,
        rejected,
    };
    problem.report(solved.state, None, (iterations, started), config)
}

/// What a limb's final fit solved: the limb's readings as the fit weighed them, the problem and
/// what the fit chose on the way (kept with the estimate, so that the limbs of one tree can be
/// fitted again together: [`tree::refine_trees`]).
#[derive(Debug, Clone)]
struct FinalProblem {
    data: LimbData,
    layout: Layout,
    spec: Spec,
    /// The readings, weighed as the fit weighed them (by the noise components when it estimated
    /// them).
    readings: Readings,
    /// What the gauge holds, in words.
    fixed: Vec<String>,
    intrinsics_model: IntrinsicsModel,
    intrinsics_tests: Vec<IntrinsicsTest>,
    noise_components: Option<NoiseComponents>,
    rejected: Vec<SuRejected>,
}

impl FinalProblem {
    /// All that is reported of the fit that ended at `state` after `iterations` from `started`:
    /// its precision, its uncertainty, the limb as a robot; `others`: what other limbs' readings
    /// tell of its shared columns, when they were fitted together ([`Precision::of`]).
    fn report(
        self,
        state: ChainState,
        others: Option<&DMatrix<f64>>,
        (iterations, started): (usize, Instant),
        config: &MlConfig,
    ) -> Result<MlChainEstimate, EstimateError> {
        let precision = Precision::of(&state, &self, others, config);
        if !precision.residual_ratio.is_finite() {
            return Err(EstimateError::NotFinite {
                limb: self.data.chain.name.clone(),
                reason: format!("residual / noise = {}", precision.residual_ratio),
            });
        }
        let fit = FinalFit {
            state,
            precision,
            problem: self,
        };
        fit.estimate((iterations, started), config)
    }
}

/// A limb's final fit and what is known of its precision.
struct FinalFit {
    state: ChainState,
    precision: Precision,
    problem: FinalProblem,
}

impl FinalFit {
    /// All that is reported of the fit, which took `iterations` from `started`.
    fn estimate(
        self,
        (iterations, started): (usize, Instant),
        config: &MlConfig,
    ) -> Result<MlChainEstimate, EstimateError> {
        let (state, precision, problem) = (self.state, self.precision, self.problem);
        let (data, layout, spec) = (&problem.data, &problem.layout, &problem.spec);
        let readings = &precision.readings;
        let residual_ratio = precision.residual_ratio;
        let flat_dofs = data.chain.dofs();
        let flat_sus = data.chain.sus();
        let cov = &precision.cov;
        let open = free_directions(&state, layout, readings, spec, config.noise_sd);
        let limb = limb_robot(&data.chain, &state, &data.su_depth)?;
        Ok(MlChainEstimate {
            robot: RobotFile::from_robot(&limb, Some("maximum-likelihood estimate".into())),
            dh: dh_table(&limb, &state, spec, cov, data),
            chain: data.chain.clone(),
            joint_orders: Vec::new(),
            retries: Vec::new(),
            gravity: state.gravity.into(),
            residual_ratio,
            noise_sd_estimate: config.noise_sd * residual_ratio,
            reading_sd: readings.sd.is_some(),
            converged: residual_ratio <= config.converged_ratio
                && precision.band.is_none_or(|b| b.holds(residual_ratio)),
            residual_band: precision.band,
            fixed: problem.fixed.clone(),
            uncertainty: su_uncertainty(&state, layout, spec, &flat_sus, cov, &open),
            joint_covariance: joint_covariance(spec, &flat_dofs, cov),
            intrinsics: su_intrinsics(&state, spec, &flat_sus, cov, problem.intrinsics_model),
            intrinsics_model: Some(problem.intrinsics_model),
            intrinsics_tests: problem.intrinsics_tests.clone(),
            noise_components: problem.noise_components,
            rejected: problem.rejected.clone(),
            missing_excitations: if readings.motion.is_some() {
                Vec::new()
            } else {
                data.missing_excitations()
            },
            motion: readings.motion.as_ref().map(|m| {
                let at = precision.names.iter().position(|n| n == "skin.delay");
                MotionFit {
                    blocks: m.len(),
                    skin_delay: state.skin_delay,
                    skin_delay_sd: at.map_or(f64::NAN, |i| cov[(i, i)].max(0.0).sqrt()),
                }
            }),
            su_residual_ratio: su_residual_ratios(&state, layout, readings, spec, config.noise_sd),
            unobservable: precision.unobservable,
            iterations,
            seconds: started.elapsed().as_secs_f64(),
            state: Some(state),
            problem: FitProblem(Some(std::sync::Arc::new(problem))),
        })
    }
}

/// How a limb's final fit fixes what the readings cannot tell.
struct Gauge {
    /// DoFs of the base path (a sub-limb's, held at the parent's estimate).
    base_dofs: usize,
    /// Whether the limb has a base path from a parent limb.
    base: bool,
    /// The SU whose turn about and shift along the first axis are held.
    su: Option<usize>,
    /// Whether gravity is held along the first axis.
    vertical: bool,
}

/// The final fit's problem: every block of the limb (the base path held), its intrinsics as
/// `intrinsics` says, the skin's delay where there is a motion record, and gravity's direction
/// alone where scales are fitted or chosen.
fn final_spec(
    layout: &Layout,
    gauge: &Gauge,
    motion: bool,
    intrinsics: IntrinsicsModel,
    config: &MlConfig,
) -> Spec {
    let mut spec = full_spec(
        layout,
        gauge.base_dofs.max(1),
        !gauge.base,
        gauge.su,
        intrinsics,
    );
    if gauge.vertical {
        // Gravity along the first axis: its direction is held, which leaves the turn of
        // everything after segment 1 about that axis exactly free (reported below).
        spec.held.extend([(0, 0), (0, 1)]);
    }
    if motion {
        spec.blocks.push(Block::SkinDelay);
    }
    if !gauge.base && (intrinsics.components() > 3 || config.select_intrinsics) {
        // A common scale error of every SU and a gravity as much weaker read the same: the
        // magnitude of gravity is what scales are measured against. When the data choose
        // the model, every model holds it there, so that each is nested in the next and a
        // limb with few SUs (a trunk) does not hand the limbs on it a magnitude of its own.
        spec.blocks[0] = Block::GravityDirection;
    }
    spec
}

/// What a final fit reports of its precision: from the readings alone (not the gauge priors),
/// the residual against the noise configured (or the set's own deviations), the covariance
/// from the readings weighed as the fit weighed them.
struct Precision {
    /// The readings the residual is measured on.
    readings: Readings,
    residual_ratio: f64,
    /// The band of the residual ratio at the noise level (readings fits only: a motion
    /// record's noise model is approximate).
    band: Option<ResidualBand>,
    cov: DMatrix<f64>,
    /// The parameters' names, in the covariance's order.
    names: Vec<String>,
    unobservable: Vec<Unobservable>,
}

impl Precision {
    /// The precision of `problem`'s fit at `state`; `others`: what other limbs' readings tell of
    /// its shared columns (information, in their order), when they were fitted together.
    fn of(
        state: &ChainState,
        problem: &FinalProblem,
        others: Option<&DMatrix<f64>>,
        config: &MlConfig,
    ) -> Self {
        let (layout, spec, data) = (&problem.layout, &problem.spec, &problem.data);
        let components = problem.noise_components.is_some();
        let weighted = problem.readings.clone();
        let sigma = config.noise_sd;
        let weighted = Readings {
            gauge_prior: None,
            ..weighted
        };
        let (readings, weighted) = if components {
            let plain = Readings {
                sd: None,
                ..weighted.clone()
            };
            (plain, Some(weighted))
        } else {
            (weighted, None)
        };
        let dof_count = spec.columns().len();
        let names = column_names(&data.chain.dofs(), &data.chain.sus(), spec);
        let map = ColumnMap::new(spec);
        let ratio_of = |normal: &problem::Normal| {
            (normal.cost / (normal.rows.saturating_sub(dof_count)).max(1) as f64).sqrt()
        };
        let normal = normal_system(state, layout, &readings, spec, &map, sigma);
        let residual_ratio = ratio_of(&normal);
        let band = readings
            .motion
            .is_none()
            .then(|| ResidualBand::at(normal.rows.saturating_sub(dof_count)));
        let (mut normal, scale) = match &weighted {
            Some(weighted) => {
                let normal = normal_system(state, layout, weighted, spec, &map, sigma);
                let ratio = ratio_of(&normal);
                (normal, ratio)
            }
            None => (normal, residual_ratio),
        };
        if let Some(others) = others {
            normal.add_shared_information(others);
        }
        let (cov, unobservable) = covariance(
            &normal,
            &map,
            scale.max(1.0),
            &names,
            config.observable_limit,
        );
        let unobservable = positions_in_one(unobservable, data, &readings);
        Self {
            readings,
            residual_ratio,
            band: band.flatten(),
            cov,
            names,
            unobservable,
        }
    }
}

/// What the final fit held to fix the gauge, in words.
fn gauge_statement(
    data: &LimbData,
    base: Option<&LimbBase>,
    gauge_su: Option<usize>,
    vertical: bool,
    spec: &Spec,
) -> Vec<String> {
    let (flat_dofs, flat_sus) = (data.chain.dofs(), data.chain.sus());
    let mut fixed = Vec::new();
    match (base, gauge_su) {
        (Some(_), _) => fixed.push(format!(
            "the base path ({} DoFs) and gravity, as the parent limb estimated them",
            data.chain.base_dofs()
        )),
        (None, Some(u)) => fixed.extend([
            format!("{}.rotation_z", flat_sus[u]),
            format!("{}.z", flat_sus[u]),
        ]),
        (None, None) => fixed.push(format!(
            "the turn about and shift along {}'s axis of everything it moves (no SU before {}: left to the damping, not held by a parameter)",
            flat_dofs[0], flat_dofs.get(1).map_or("", String::as_str)
        )),
    }
    if vertical {
        fixed.push(format!("gravity.direction (along {}'s axis)", flat_dofs[0]));
    }
    if spec.blocks.first() == Some(&Block::GravityDirection) {
        fixed.push(format!(
            "gravity.magnitude ({STANDARD_GRAVITY} m/s²: what the sensors are measured against)"
        ));
    }
    fixed
}

/// The limb's DH table with its standard deviations, for a serial chain.
fn dh_table(
    limb: &Robot,
    state: &ChainState,
    spec: &Spec,
    cov: &DMatrix<f64>,
    data: &LimbData,
) -> Option<DhTable> {
    let serial = data.chain.as_serial()?;
    let (dof_dof, dof_su) = super::dh_form(limb, &serial)?;
    let (dof_dof_sd, dof_su_sd) = dh_sd(state, spec, cov, data, &serial, (&dof_dof, &dof_su));
    Some(DhTable {
        dof_dof,
        dof_su,
        dof_dof_sd,
        dof_su_sd,
    })
}

/// The final fit from the search's best state: the kinematics alone, then, with `config`'s
/// intrinsics, everything together (gravity set to 9.81 m/s² when only its direction is free);
/// with `select_intrinsics`, each model from none upwards only when the data ask for it (each
/// fitted from the one before). Returns the solution, its problem, the model fitted, the tests
/// and the LM iterations.
fn fit_with_intrinsics(
    state: ChainState,
    layout: &Layout,
    readings: &Readings,
    final_spec: impl Fn(IntrinsicsModel) -> Spec,
    config: &MlConfig,
) -> (Solved, Spec, IntrinsicsModel, Vec<IntrinsicsTest>, usize) {
    let fit = |state: ChainState, spec: &Spec| refit(state, layout, readings, spec, config);
    // A start for `spec`: gravity at 9.81 m/s² when only its direction is free.
    let from = |state: &ChainState, spec: &Spec| {
        let mut start = state.clone();
        if spec.blocks.first() == Some(&Block::GravityDirection) {
            start.gravity = start.gravity.normalize() * STANDARD_GRAVITY;
        }
        start
    };
    let spec = final_spec(IntrinsicsModel::None);
    let mut solved = fit(from(&state, &spec), &spec);
    let mut iterations = solved.iterations;
    let (mut spec, mut model) = (spec, IntrinsicsModel::None);
    let mut tests = Vec::new();
    let ladder: Vec<IntrinsicsModel> = if config.select_intrinsics {
        [
            IntrinsicsModel::Bias,
            IntrinsicsModel::BiasScale,
            IntrinsicsModel::Full,
        ]
        .into_iter()
        .filter(|m| m.components() <= config.intrinsics.components())
        .collect()
    } else if config.intrinsics == IntrinsicsModel::None {
        Vec::new()
    } else {
        vec![config.intrinsics]
    };
    // The residual rows that count (the same for every model: the readings do not change).
    let rows = if config.select_intrinsics && !ladder.is_empty() {
        let map = ColumnMap::new(&spec);
        normal_system(
            &solved.state,
            layout,
            readings,
            &spec,
            &map,
            config.noise_sd,
        )
        .rows
    } else {
        0
    };
    // Every model of the ladder is fitted (each from the one before) so that the tests can be
    // pooled over a skin; the one kept is the last of those taken in a row.
    let mut climbing = true;
    let mut current = (solved.clone(), spec.clone(), model);
    for next in ladder {
        let next_spec = final_spec(next);
        let larger = fit(from(&current.0.state, &next_spec), &next_spec);
        iterations += larger.iterations;
        if config.select_intrinsics {
            let (before, after) = (current.1.columns().len(), next_spec.columns().len());
            let test = IntrinsicsTest::new(
                next,
                current.2,
                current.0.cost,
                larger.cost,
                after.saturating_sub(before),
                rows.saturating_sub(after),
            );
            tests.push(test);
            climbing &= test.taken;
        }
        current = (larger, next_spec, next);
        if climbing || !config.select_intrinsics {
            (solved, spec, model) = current.clone();
        }
    }
    (solved, spec, model, tests, iterations)
}

/// The final fit's solve: from `state` to [`FINAL_TOLERANCE`].
fn refit(
    state: ChainState,
    layout: &Layout,
    readings: &Readings,
    spec: &Spec,
    config: &MlConfig,
) -> Solved {
    solve(
        state,
        layout,
        readings,
        spec,
        config.noise_sd,
        config.max_iterations,
        FINAL_TOLERANCE,
    )
}

/// Where the set gives no reading its own deviation, no uniform noise was asked for
/// (`reading_sd`) and the fit has no motion record: the
/// static and the dynamic readings' noise estimated apart from the residuals (their sums of
/// squares, corrected for the parameters fitted), every reading weighed by its component's, and
/// the fit repeated. Returns the solution, the readings with those deviations, the LM iterations
/// and the components; unchanged when there is nothing to estimate.
fn weigh_by_noise_components(
    solved: Solved,
    layout: &Layout,
    readings: Readings,
    spec: &Spec,
    config: &MlConfig,
) -> (Solved, Readings, usize, Option<NoiseComponents>) {
    if readings.sd.is_some() || readings.motion.is_some() || !config.reading_sd {
        return (solved, readings, 0, None);
    }
    let sigma = config.noise_sd;
    let norms = problem::reading_norms(&solved.state, layout, &readings, spec, sigma);
    let (mut sums, mut counts) = ([0.0f64; 2], [0usize; 2]);
    for (p, pose) in norms.iter().enumerate() {
        for (u, rows) in pose.iter().enumerate() {
            for (j, n) in rows.iter().enumerate() {
                if !readings.is_rejected(p, u, j) {
                    let kind = usize::from(j > 0);
                    sums[kind] += n * n;
                    counts[kind] += 3;
                }
            }
        }
    }
    let rows = counts[0] + counts[1];
    let parameters = spec.columns().len();
    if counts.contains(&0) || rows <= 2 * parameters {
        return (solved, readings, 0, None);
    }
    let correction = rows as f64 / (rows - parameters) as f64;
    let [s, d] = [0, 1].map(|k| sigma * (sums[k] / counts[k] as f64 * correction).sqrt());
    if !(s > 0.0 && d > 0.0 && s.is_finite() && d.is_finite()) {
        return (solved, readings, 0, None);
    }
    let sd: Vec<Vec<Vec<f64>>> = (0..readings.q.len())
        .map(|_| {
            layout
                .su_segment
                .iter()
                .map(|&seg| (0..=seg).map(|j| if j == 0 { s } else { d }).collect())
                .collect()
        })
        .collect();
    let readings = Readings {
        sd: Some(std::sync::Arc::new(sd)),
        ..readings
    };
    let solved = refit(solved.state, layout, &readings, spec, config);
    let iterations = solved.iterations;
    (
        solved,
        readings,
        iterations,
        Some(NoiseComponents {
            static_sd: s,
            dynamic_sd: d,
        }),
    )
}

/// Wild readings (glitches) out and the fit repeated by plain least squares on the rest, until
/// the set left out stops changing ([`REJECT_ROUNDS`] at most). Returns the solution, the
/// readings with those left out marked, and the LM iterations.
fn leave_out_glitches(
    mut solved: Solved,
    layout: &Layout,
    readings: &Readings,
    spec: &Spec,
    config: &MlConfig,
) -> (Solved, Readings, usize) {
    let sigma = config.noise_sd;
    let mut readings = Readings {
        huber: None,
        rejected: Vec::new(),
        ..readings.clone()
    };
    let mut iterations = 0;
    for _ in 0..REJECT_ROUNDS {
        let norms = problem::reading_norms(&solved.state, layout, &readings, spec, sigma);
        let rejected = wild_readings(&norms, layout.su_segment.len());
        let unchanged = rejected == readings.rejected
            || (readings.rejected.is_empty() && rejected.iter().flatten().flatten().all(|r| !r));
        readings.rejected = rejected;
        if unchanged {
            break;
        }
        solved = refit(solved.state, layout, &readings, spec, config);
        iterations += solved.iterations;
    }
    (solved, readings, iterations)
}

/// `[p][u][row]`: the readings more than [`REJECT`] off (whitened norms `norms`), except for an
/// SU with more than [`MAX_GLITCH_SHARE`] of its readings off: glitches are rare, so that SU is
/// misfit (a broken SU or a wrong model), not glitching, and keeps them all.
fn wild_readings(norms: &[Vec<Vec<f64>>], sus: usize) -> Vec<Vec<Vec<bool>>> {
    let mut wild: Vec<Vec<Vec<bool>>> = norms
        .iter()
        .map(|pose| {
            pose.iter()
                .map(|su| su.iter().map(|&n| n > REJECT).collect())
                .collect()
        })
        .collect();
    for u in 0..sus {
        let (off, all) = wild.iter().fold((0, 0), |(o, a), pose| {
            (
                o + pose[u].iter().filter(|&&r| r).count(),
                a + pose[u].len(),
            )
        });
        if off as f64 > MAX_GLITCH_SHARE * all as f64 {
            for pose in &mut wild {
                pose[u].iter_mut().for_each(|r| *r = false);
            }
        }
    }
    wild
}

/// Per SU: the RMS of its whitened residuals over the readings that count, per component.
fn su_residual_ratios(
    state: &ChainState,
    layout: &Layout,
    readings: &Readings,
    spec: &Spec,
    sigma: f64,
) -> Vec<f64> {
    let norms = problem::reading_norms(state, layout, readings, spec, sigma);
    let motion = problem::motion_sums(state, layout, readings, spec, sigma);
    (0..layout.su_segment.len())
        .map(|u| {
            let (sum, n) = norms
                .iter()
                .enumerate()
                .fold((0.0, 0), |(s, n), (p, pose)| {
                    pose[u]
                        .iter()
                        .enumerate()
                        .filter(|&(j, _)| !readings.is_rejected(p, u, j))
                        .fold((s, n), |(s, n), (_, x)| (s + x * x, n + 3))
                });
            let (sum, n) = (sum + motion[u].0, n + motion[u].1);
            (sum / n.max(1) as f64).sqrt()
        })
        .collect()
}

/// Places the other SUs of a joint's segment (closed-form starts, each refined alone with the
/// joints held) and refines the joint's lines with all of them; returns the re-ranked beam.
fn add_segment_sus(
    beam: Vec<(ChainState, f64)>,
    layout: &Layout,
    data: &Readings,
    span: &Span,
    config: &MlConfig,
) -> (Vec<(ChainState, f64)>, usize) {
    if span.sus.len() < 2 {
        return (beam, 0);
    }
    let sigma = config.noise_sd;
    let s = span.k1 + 1;
    let results: Vec<((ChainState, f64), usize)> = beam
        .into_par_iter()
        .map(|(mut state, cost)| {
            let mut iterations = 0;
            // The cost so far: earlier segments plus this segment's first SU.
            let previous = cost - single_su_cost(&state, layout, data, span.sus[0], sigma);
            let cache = prefixes(&state, layout, data, s);
            for &v in &span.sus[1..] {
                let spec = Spec {
                    blocks: vec![Block::Su(v)],
                    held: vec![],
                    sus: vec![v],
                    prefix: Some(cache.clone()),
                };
                let best = init::su_starts(&state, layout, data, v, s, config.angle_starts)
                    .into_iter()
                    .map(|start| {
                        let mut c = state.clone();
                        c.sus[v] = start;
                        solve(
                            c,
                            layout,
                            data,
                            &spec,
                            sigma,
                            config.max_iterations,
                            INIT_TOLERANCE,
                        )
                    })
                    .min_by(|a, b| a.cost.total_cmp(&b.cost))
                    .expect("at least one start");
                iterations += best.iterations;
                state.sus[v] = best.state.sus[v];
            }
            let first_free = if span.k0 == 0 { 1 } else { span.k0 };
            let mut blocks: Vec<Block> = (first_free..=span.k1).map(Block::Joint).collect();
            blocks.extend(span.sus.iter().map(|&v| Block::Su(v)));
            let spec = Spec {
                blocks,
                held: vec![],
                sus: span.sus.clone(),
                prefix: Some(prefixes(&state, layout, data, first_free)),
            };
            let solved = solve(
                state,
                layout,
                data,
                &spec,
                sigma,
                config.max_iterations,
                INIT_TOLERANCE,
            );
            iterations += solved.iterations;
            ((solved.state, previous.max(0.0) + solved.cost), iterations)
        })
        .collect();
    let iterations = results.iter().map(|r| r.1).sum();
    (
        keep_best(results.into_iter().map(|r| r.0).collect(), usize::MAX),
        iterations,
    )
}

/// The cost of one SU's readings.
fn single_su_cost(
    state: &ChainState,
    layout: &Layout,
    data: &Readings,
    u: usize,
    sigma: f64,
) -> f64 {
    let spec = Spec {
        blocks: vec![],
        held: vec![],
        sus: vec![u],
        prefix: None,
    };
    problem::cost_of(state, layout, data, &spec, &ColumnMap::new(&spec), sigma)
}

/// The final problem: gravity (when `with_gravity`), every joint line from `first_joint` on, every
/// SU and, per `intrinsics`, its accelerometer intrinsics; the gauge SU's rotation about and shift
/// along z held.
fn full_spec(
    layout: &Layout,
    first_joint: usize,
    with_gravity: bool,
    gauge_su: Option<usize>,
    intrinsics: IntrinsicsModel,
) -> Spec {
    let mut blocks = Vec::new();
    if with_gravity {
        blocks.push(Block::Gravity);
    }
    blocks.extend((first_joint..layout.dofs).map(Block::Joint));
    let first_su = blocks.len();
    let sus = layout.su_segment.len();
    blocks.extend((0..sus).map(Block::Su));
    let mut held: Vec<(usize, usize)> = gauge_su
        .map(|u| vec![(first_su + u, 2), (first_su + u, 5)])
        .unwrap_or_default();
    if intrinsics != IntrinsicsModel::None {
        let first_intrinsics = blocks.len();
        blocks.extend((0..sus).map(Block::Intrinsics));
        for u in 0..sus {
            held.extend((intrinsics.components()..9).map(|c| (first_intrinsics + u, c)));
        }
    }
    Spec {
        prefix: None,
        held,
        blocks,
        sus: (0..sus).collect(),
    }
}

/// Each SU's intrinsics with their standard deviations from the covariance, and the components
/// whose standard deviation is more than half the prior's (the readings hardly tell them).
fn su_intrinsics(
    state: &ChainState,
    spec: &Spec,
    names: &[String],
    covariance: &DMatrix<f64>,
    model: IntrinsicsModel,
) -> Vec<SuIntrinsics> {
    if model == IntrinsicsModel::None {
        return Vec::new();
    }
    let columns = spec.columns();
    let mut sd = vec![[0.0f64; 9]; names.len()];
    for (col, &(b, c)) in columns.iter().enumerate() {
        if let Block::Intrinsics(u) = spec.blocks[b] {
            sd[u][c] = covariance[(col, col)].max(0.0).sqrt();
        }
    }
    names
        .iter()
        .enumerate()
        .map(|(u, su)| SuIntrinsics {
            su: su.clone(),
            value: state.intrinsics[u],
            sd: Intrinsics::from_array(&sd[u]),
            held: (0..model.components())
                .filter(|&c| sd[u][c] > 0.5 * problem::INTRINSIC_PRIOR_SD[c])
                .map(|c| INTRINSIC_NAMES[c].to_string())
                .collect(),
        })
        .collect()
}

/// The name that stands for every position of a limb whose set has no dynamic reading.
pub const STATIC_ONLY_POSITIONS: &str =
    "every joint line's and SU's position (the set has no dynamic reading of this limb: static \
     readings tell orientations only)";

/// Where a limb's set has no dynamic reading at all, every position is unobservable: its many
/// directions are said once, by [`STATIC_ONLY_POSITIONS`].
fn positions_in_one(
    unobservable: Vec<Unobservable>,
    data: &LimbData,
    readings: &Readings,
) -> Vec<Unobservable> {
    if readings.motion.is_some() || !data.static_only() {
        return unobservable;
    }
    let position = |name: &String| {
        [".x", ".y", ".z", ".shift_x", ".shift_y"]
            .iter()
            .any(|end| name.ends_with(end))
    };
    let mut out = vec![Unobservable {
        singular_value: 0.0,
        parameters: vec![STATIC_ONLY_POSITIONS.into()],
    }];
    out.extend(
        unobservable
            .into_iter()
            .filter(|u| !u.parameters.iter().all(position)),
    );
    out
}

fn column_names(dofs: &[String], sus: &[String], spec: &Spec) -> Vec<String> {
    spec.columns()
        .iter()
        .map(|&(b, c)| match spec.blocks[b] {
            Block::Gravity => format!("gravity.{}", ["x", "y", "z"][c]),
            Block::GravityDirection => format!("gravity.{}", ["tilt_1", "tilt_2"][c]),
            Block::Intrinsics(u) => format!("{}.{}", sus[u], INTRINSIC_NAMES[c]),
            Block::Joint(k) => format!(
                "{}.{}",
                dofs[k],
                ["tilt_x", "tilt_y", "shift_x", "shift_y"][c]
            ),
            Block::JointFull(k) => {
                format!("{}.{}", dofs[k], ["rx", "ry", "rz", "x", "y", "z"][c])
            }
            Block::Su(u) => format!(
                "{}.{}",
                sus[u],
                ["rotation_x", "rotation_y", "rotation_z", "x", "y", "z"][c]
            ),
            Block::SkinDelay => "skin.delay".into(),
        })
        .collect()
}

/// The standard deviations of a DH+2 table's values: its Jacobian with respect to the joint lines
/// and SU frames (central differences through the table's construction) and the parameter
/// covariance. Empty when a perturbed chain has no DH+2 form.
fn dh_sd(
    state: &ChainState,
    spec: &Spec,
    covariance: &DMatrix<f64>,
    data: &LimbData,
    serial: &super::SerialChain,
    table: (&[super::DhRow], &[super::SuRow]),
) -> (Vec<super::DhRow>, Vec<super::SuRow>) {
    // Angles sit at these places of each row's values; their differences are wrapped.
    const DOF_ANGLES: [bool; 4] = [true, false, false, true];
    const SU_ANGLES: [bool; 6] = [true, false, false, true, true, false];
    let flatten = |rows: (&[super::DhRow], &[super::SuRow])| -> Vec<(f64, bool)> {
        let dof = rows
            .0
            .iter()
            .flat_map(|r| r.values().into_iter().zip(DOF_ANGLES));
        dof.chain(
            rows.1
                .iter()
                .flat_map(|r| r.values().into_iter().zip(SU_ANGLES)),
        )
        .collect()
    };
    let nominal = flatten(table);
    let all = spec.columns();
    let columns: Vec<usize> = all
        .iter()
        .enumerate()
        .filter(|(_, &(b, _))| {
            matches!(
                spec.blocks[b],
                Block::Joint(_) | Block::JointFull(_) | Block::Su(_)
            )
        })
        .map(|(i, _)| i)
        .collect();
    let h = 1e-6;
    let mut jacobian = DMatrix::zeros(nominal.len(), columns.len());
    for (j, &c) in columns.iter().enumerate() {
        let mut values = [0.0; 2].map(|_| Vec::new());
        for (side, sign) in [1.0, -1.0].into_iter().enumerate() {
            let mut delta = vec![0.0; all.len()];
            delta[c] = sign * h;
            let moved = retract_columns(state, spec, &all, &delta);
            let Ok(robot) = limb_robot(&data.chain, &moved, &data.su_depth) else {
                return (Vec::new(), Vec::new());
            };
            let Some((a, b)) = super::dh_form(&robot, serial) else {
                return (Vec::new(), Vec::new());
            };
            values[side] = flatten((&a, &b));
        }
        if values[0].len() != nominal.len() || values[1].len() != nominal.len() {
            return (Vec::new(), Vec::new());
        }
        for (i, &(_, angle)) in nominal.iter().enumerate() {
            let mut d = values[0][i].0 - values[1][i].0;
            if angle {
                d = d.sin().atan2(d.cos());
            }
            jacobian[(i, j)] = d / (2.0 * h);
        }
    }
    let sigma = DMatrix::from_fn(columns.len(), columns.len(), |a, b| {
        covariance[(columns[a], columns[b])]
    });
    let variance = (&jacobian * sigma * jacobian.transpose()).diagonal();
    let sd: Vec<f64> = variance.iter().map(|v| v.max(0.0).sqrt()).collect();
    let (dof, su) = sd.split_at(4 * table.0.len());
    (
        dof.chunks(4).map(super::DhRow::from_values).collect(),
        su.chunks(6).map(super::SuRow::from_values).collect(),
    )
}

/// The joint-line block of the parameter covariance.
fn joint_covariance(
    spec: &Spec,
    dofs: &[String],
    covariance: &DMatrix<f64>,
) -> Option<JointCovariance> {
    let columns = spec.columns();
    let mut joints: Vec<usize> = Vec::new();
    let mut index: Vec<(usize, usize, usize)> = Vec::new(); // (column, joint slot, component)
    for (col, &(b, c)) in columns.iter().enumerate() {
        if let Block::Joint(k) = spec.blocks[b] {
            let slot = match joints.iter().position(|&j| j == k) {
                Some(slot) => slot,
                None => {
                    joints.push(k);
                    joints.len() - 1
                }
            };
            index.push((col, slot, c));
        }
    }
    if joints.is_empty() {
        return None;
    }
    let n = 4 * joints.len();
    let mut matrix = vec![vec![0.0; n]; n];
    for &(ca, ja, a) in &index {
        for &(cb, jb, b) in &index {
            matrix[4 * ja + a][4 * jb + b] = covariance[(ca, cb)];
        }
    }
    Some(JointCovariance {
        dofs: joints.iter().map(|&k| dofs[k].clone()).collect(),
        matrix,
    })
}

/// Pose of SU `u` relative to the previous SU (reference for the first) at q = 0.
fn relative_pose(state: &ChainState, layout: &Layout, u: usize) -> Isometry3<f64> {
    let f = frames(
        state,
        layout,
        &vec![Isometry3::identity(); layout.dofs],
        None,
        layout.dofs,
    );
    if u == 0 {
        f.sus[0]
    } else {
        f.sus[u - 1].inverse() * f.sus[u]
    }
}

/// A change of an SU's relative pose smaller than this per unit step along a free direction (m or
/// rad per unit of the direction) does not count as the direction moving it.
const FREE_MOTION: f64 = 1e-6;

/// Unit vectors spanning `vectors` (Gram–Schmidt), those shorter than [`FREE_MOTION`] left out.
fn span_of(vectors: &[Vector3<f64>]) -> Vec<Vector3<f64>> {
    let mut basis: Vec<Vector3<f64>> = Vec::new();
    for v in vectors {
        let mut r = *v;
        for b in &basis {
            r -= b * b.dot(&r);
        }
        if r.norm() > FREE_MOTION.max(1e-3 * v.norm()) && basis.len() < 3 {
            basis.push(r.normalize());
        }
    }
    basis
}

/// The standard deviation left in a 3×3 covariance once the directions of `basis` are taken out.
fn sd_without(cov: &Matrix3<f64>, basis: &[Vector3<f64>]) -> f64 {
    let p = basis
        .iter()
        .fold(Matrix3::identity(), |p, b| p - b * b.transpose());
    (p * cov * p).trace().max(0.0).sqrt()
}

/// The directions no reading determines, with the gauge released: `spec` with its SUs' held
/// components freed (the gauge holds one SU's turn about and shift along the first axis, which
/// fixes a direction without being it: the free motion is a turn about the axis itself), and the
/// null directions of the information of that problem, unit vectors over its columns.
fn free_directions(
    state: &ChainState,
    layout: &Layout,
    readings: &Readings,
    spec: &Spec,
    sigma: f64,
) -> (Spec, Vec<DVector<f64>>) {
    let mut open = spec.clone();
    open.held
        .retain(|(b, _)| !matches!(spec.blocks[*b], Block::Su(_)));
    let readings = Readings {
        gauge_prior: None,
        ..readings.clone()
    };
    let map = ColumnMap::new(&open);
    let normal = normal_system(state, layout, &readings, &open, &map, sigma);
    let names = vec![String::new(); open.columns().len()];
    let free = problem::eliminate(&normal, &map, &names, f64::INFINITY).free;
    (open, free)
}

/// Each SU's pose uncertainty relative to the previous SU, and the directions of it that no
/// reading determines: the images of the free directions of the problem with its gauge released
/// ([`free_directions`]).
fn su_uncertainty(
    state: &ChainState,
    layout: &Layout,
    spec: &Spec,
    names: &[String],
    covariance: &DMatrix<f64>,
    (open, free): &(Spec, Vec<DVector<f64>>),
) -> Vec<SuUncertainty> {
    let columns = spec.columns();
    let open_columns = open.columns();
    let n = columns.len();
    let h = 1e-6;
    (0..layout.su_segment.len())
        .into_par_iter()
        .map(|u| {
            let base = relative_pose(state, layout, u);
            // How a step along `column` of `these` columns moves the relative pose (position in
            // the previous SU's frame, rotation in the SU's own), per unit.
            let motion_in = |spec: &Spec,
                             these: &[(usize, usize)],
                             column: usize|
             -> Vector6<f64> {
                let mut delta = vec![0.0; these.len()];
                delta[column] = h;
                let plus = relative_pose(&retract_columns(state, spec, these, &delta), layout, u);
                delta[column] = -h;
                let minus = relative_pose(&retract_columns(state, spec, these, &delta), layout, u);
                let dt = (plus.translation.vector - minus.translation.vector) / (2.0 * h);
                let dr = ((base.rotation.inverse() * plus.rotation).scaled_axis()
                    - (base.rotation.inverse() * minus.rotation).scaled_axis())
                    / (2.0 * h);
                Vector6::new(dt.x, dt.y, dt.z, dr.x, dr.y, dr.z)
            };
            // Only the two SUs' own blocks and the joints move the relative pose (no intrinsics,
            // no gravity).
            let moves = |b: usize| match spec.blocks[b] {
                Block::Su(v) => v == u || v + 1 == u,
                Block::Intrinsics(_)
                | Block::Gravity
                | Block::GravityDirection
                | Block::SkinDelay => false,
                Block::Joint(_) | Block::JointFull(_) => true,
            };
            // How each column moves the pose, once, over the open problem's columns (the
            // fitted problem's are among them).
            let moved: Vec<(usize, Vector6<f64>)> = (0..open_columns.len())
                .filter(|&c| moves(open_columns[c].0))
                .map(|c| (c, motion_in(open, &open_columns, c)))
                .collect();
            let relevant: Vec<usize> = (0..n).filter(|&c| moves(columns[c].0)).collect();
            let mut jac = DMatrix::zeros(6, relevant.len());
            for (j, &c) in relevant.iter().enumerate() {
                let m = moved
                    .iter()
                    .find(|(o, _)| open_columns[*o] == columns[c])
                    .map_or_else(|| motion_in(spec, &columns, c), |(_, m)| *m);
                jac.set_column(j, &m);
            }
            let sub = DMatrix::from_fn(relevant.len(), relevant.len(), |a, b| {
                covariance[(relevant[a], relevant[b])]
            });
            let cov = &jac * sub * jac.transpose();
            // What no reading tells: the images of the free directions with the gauge released.
            let unmoored: Vec<Vector6<f64>> = free
                .iter()
                .map(|f| moved.iter().map(|(c, m)| m * f[*c]).sum())
                .collect();
            let position = span_of(
                &unmoored
                    .iter()
                    .map(|m| m.fixed_rows::<3>(0).into_owned())
                    .collect::<Vec<_>>(),
            );
            let orientation = span_of(
                &unmoored
                    .iter()
                    .map(|m| m.fixed_rows::<3>(3).into_owned())
                    .collect::<Vec<_>>(),
            );
            let block = |r: usize| Matrix3::from_fn(|i, j| cov[(r + i, r + j)]);
            SuUncertainty {
                su: names[u].clone(),
                position_sd: sd_without(&block(0), &position),
                orientation_sd: sd_without(&block(3), &orientation),
                undetermined_position: position.iter().map(|v| (*v).into()).collect(),
                undetermined_orientation: orientation.iter().map(|v| (*v).into()).collect(),
            }
        })
        .collect()
}

/// The estimated limb as a robot: reference = the first joint frame, DoF `k` on the segment after
/// DoF `k−1`, every SU on its segment.
fn limb_robot(
    chain: &LimbChain,
    state: &ChainState,
    su_depth: &[usize],
) -> Result<Robot, EstimateError> {
    let dofs = chain.dofs();
    let sus = chain.sus();
    let mut b = RobotBuilder::new(chain.name.clone(), "reference");
    let kinds = chain.kinds();
    for (k, dof) in dofs.iter().enumerate() {
        b.dofs.push(DofSpec {
            name: dof.clone(),
            parent: if k == 0 {
                "reference".into()
            } else {
                chain.segment_after(k - 1)
            },
            child: chain.segment_after(k),
            origin: PlacementSpec::from_isometry(&state.joints[k]),
            axis: Vector3::z(),
            kind: kinds[k],
            limits: Limits::CONTINUOUS,
            mimic: None,
        });
    }
    for (u, su) in sus.iter().enumerate() {
        b.sus.push(SuSpec {
            name: su.clone(),
            segment: chain.segment_after(su_depth[u] - 1),
            placement: PlacementSpec::from_isometry(&state.sus[u]),
        });
    }
    // Names are distinct by construction, so only non-finite numbers can be refused here.
    b.build().map_err(|e| EstimateError::NotFinite {
        limb: chain.name.clone(),
        reason: e.to_string(),
    })
}

fn validate(config: &MlConfig) -> Result<(), EstimateError> {
    let bad = |setting, reason: String| Err(EstimateError::InvalidSetting { setting, reason });
    if !(config.noise_sd.is_finite() && config.noise_sd > 0.0) {
        return bad(
            "noise_sd",
            format!("{} m/s² must be positive", config.noise_sd),
        );
    }
    if config.max_iterations == 0 {
        return bad("max_iterations", "must be at least 1".into());
    }
    if !(config.converged_ratio.is_finite() && config.converged_ratio >= 1.0) {
        return bad(
            "converged_ratio",
            format!("{} must be at least 1", config.converged_ratio),
        );
    }
    Ok(())
}

fn serial_layout(dofs: usize) -> Layout {
    Layout {
        dofs,
        su_segment: (1..=dofs).collect(),
        kinds: vec![DofKind::Revolute; dofs],
    }
}

/// Test access to the internals: the Jacobian and the residuals through the chart, for a
/// chain state built from a robot.
#[doc(hidden)]
pub mod internals {
    use super::*;

    /// Residuals and Jacobian of the full problem at `state`.
    pub fn full_problem(
        data: &ChainData,
        state: &ChainState,
        sigma: f64,
    ) -> (nalgebra::DVector<f64>, DMatrix<f64>) {
        let layout = serial_layout(data.chain.dofs.len());
        let spec = full_spec(&layout, 1, true, Some(0), IntrinsicsModel::Full);
        problem::dense_problem(
            state,
            &layout,
            &readings(&LimbData::from(data)),
            &spec,
            sigma,
        )
    }

    /// The full problem of the motion rows alone (every block of `record`, the skin's delay a
    /// column after the others): residuals, Jacobian, and the residuals after a step
    /// `delta` of its columns for each step given.
    pub fn motion_problem(
        data: &ChainData,
        record: &crate::motion::MotionRecord,
        state: &ChainState,
        deltas: &[Vec<f64>],
    ) -> (
        nalgebra::DVector<f64>,
        DMatrix<f64>,
        Vec<nalgebra::DVector<f64>>,
    ) {
        let limb = LimbData::from(data);
        let layout = serial_layout(data.chain.dofs.len());
        let mut spec = full_spec(&layout, 1, true, Some(0), IntrinsicsModel::Full);
        spec.blocks.push(Block::SkinDelay);
        let mut motion = LimbMotion::new(record, &limb, 0.05).expect("the record has the chain");
        motion.weigh(state, &limb.su_depth);
        let readings = Readings {
            q: Vec::new(),
            turns: Vec::new(),
            statics: Vec::new(),
            dynamics: Vec::new(),
            motion: Some(std::sync::Arc::new(motion)),
            // Plain least squares: Huber's weights change with the state and have no column.
            huber: None,
            ..readings(&limb)
        };
        let (r, jac) = problem::dense_problem(state, &layout, &readings, &spec, 0.05);
        let after = deltas
            .iter()
            .map(|d| {
                let moved = retract(state, &spec, d);
                problem::dense_problem(&moved, &layout, &readings, &spec, 0.05).0
            })
            .collect();
        (r, jac, after)
    }

    /// Residuals after a step `delta` of the full problem's columns.
    pub fn residuals_after(
        data: &ChainData,
        state: &ChainState,
        sigma: f64,
        delta: &[f64],
    ) -> nalgebra::DVector<f64> {
        let layout = serial_layout(data.chain.dofs.len());
        let spec = full_spec(&layout, 1, true, Some(0), IntrinsicsModel::Full);
        problem::dense_problem(
            &retract(state, &spec, delta),
            &layout,
            &readings(&LimbData::from(data)),
            &spec,
            sigma,
        )
        .0
    }
}
