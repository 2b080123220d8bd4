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
//! 4. Every candidate (both signs of the axis, every searched angle, from each state of the beam)
//!    is refined by LM on the segment's data, as a race: after a few iterations, those tens of
//!    times above the best so far stop (they sit in another basin, which LM leaves slowly if at
//!    all); the best few are kept. Finally the whole chain is refined jointly.
//!
//! **Convergence** (`band.rs`). A fit is at the noise level when its residual ratio lies within
//! the band a right model stays in at the data's size (`√(χ²_ν(0.999)/ν)`: 1.02 σ at 10 000
//! degrees of freedom), not below a fixed bound; a fit off it goes on to other joint orders and
//! a wider search. A fit on every sample of a log is judged so on its blocks at rest, where the
//! joint states' derivatives add nothing unmatched.
//!
//! **Uncertainty.** The parameter covariance is `σ̂²·(JᵀJ)⁺` by the same elimination, with
//! symmetric eigen-decompositions of the SU blocks and of the reduced shared system (directions
//! with no information get none), propagated to each SU's position and orientation relative to the
//! previous SU. The directions of that pose no reading determines — the null directions of the
//! information with the gauge released — are listed per SU, never given a deviation.
//!
//! **Where each step is.** [`estimate_limb`] (here) runs them in order: the joint search and its
//! retries (`search.rs`, starts from `init.rs`), the final fit with the sensors' intrinsics
//! (`final_fit.rs`; SUs added per segment in `segment_sus.rs`, readings weighed and screened in
//! `robust.rs`), the uncertainty (`uncertainty.rs`), and what is reported (`report.rs`). A fit on
//! every sample of a motion record is `on_motion.rs` over `motion.rs`'s rows; the normal
//! equations and their Schur elimination are `problem.rs` over the kinematics of `terms.rs`; the
//! tree's joint fit is `tree.rs`, the Cramér–Rao bound `bound.rs`, the convergence band `band.rs`.

mod band;
mod bound;
mod final_fit;
mod init;
pub mod joint_states;
mod motion;
mod on_motion;
mod problem;
mod report;
mod robust;
mod search;
mod segment_sus;
mod terms;
mod tree;
mod uncertainty;

pub use band::{ResidualBand, FALSE_ALARM};
use final_fit::{final_fit, gauge_su, mirrored, refit, FinalProblem};
pub use motion::{LimbMotion, MAX_DELAY};
pub use on_motion::{order_on_motion, refine_on_motion};
use report::rejected_counts;
pub use report::{
    pooled_intrinsics, DhTable, IntrinsicsTest, JointCovariance, JointOrder, MlChainEstimate,
    MotionFit, NoiseComponents, OrderMisfit, RestResidual, SuIntrinsics, SuRejected, SuUncertainty,
    Unobservable, INTRINSICS_TEST_Z,
};
use robust::{leave_out_glitches, su_residual_ratios, weigh_by_noise_components};
pub use search::RUNNER_UP_MARGIN;
use search::{fit_ordered, keep_best, order_joints, spans, Retries, Span};
pub use segment_sus::STATIC_ONLY_POSITIONS;
use segment_sus::{add_segment_sus, full_spec, positions_in_one, su_intrinsics};
pub use tree::refine_trees;
use uncertainty::{
    column_names, dh_sd, free_directions, joint_covariance, released, su_uncertainty,
};

pub use bound::{
    cramer_rao_bound, dynamic_reading_bounds, observable_su_errors, state_of, ObservableErrors,
};

use std::time::Instant;

use nalgebra::{DMatrix, DVector, Isometry3, Matrix3, UnitQuaternion, Vector3, Vector6};
use rayon::prelude::*;
use serde::{Deserialize, Serialize};

use super::limb::{LimbChain, LimbData};
use super::EstimateError;
use crate::model::description::RobotFile;
use crate::model::intrinsics::{Intrinsics, INTRINSIC_NAMES};
use crate::model::sensor::STANDARD_GRAVITY;
use crate::model::{DofKind, DofSpec, Limits, PlacementSpec, Robot, RobotBuilder, SuSpec};
use problem::{
    covariance, frames, normal_system, prefixes, resume, retract, retract_columns, solve, turns_of,
    Block, ColumnMap, Layout, Normal, Prefix, Readings, Solved, Spec,
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
    /// readings fit must also lie within the noise's band at its size ([`ResidualBand`]), a fit
    /// on a motion record with its blocks at rest ([`RestResidual`]).
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
    /// DoF's line from every SU it moves, not only from its own limb's; on a motion record, every
    /// tree in one problem with the skin's one delay.
    #[serde(default = "fit_whole_trees")]
    pub whole_tree: bool,
    /// A limb's fit off the noise level tries the other orders of its joints' DoFs and then a
    /// wider search before it is returned. The body's calibration turns this off for a sub-limb's
    /// first fit on its parent's path, whose rescues (`estimate::rescue`) come first.
    #[serde(default = "retry_within_limbs")]
    pub limb_retries: bool,
    /// On a motion record whose encoders round coarsely, fit the joint states of those DoFs as
    /// unknowns held at what the encoders read ([`joint_states`]).
    #[serde(default = "fit_joint_states")]
    pub joint_states: bool,
    /// On a motion record whose skin is read through a kernel, read the prediction through it
    /// too ([`joint_states`]; the record's sharp joint states, `MotionRun::q_sharp`).
    #[serde(default = "predict_through_kernel")]
    pub through_kernel: bool,
}

fn fit_joint_states() -> bool {
    true
}

fn predict_through_kernel() -> bool {
    true
}

fn retry_within_limbs() -> bool {
    true
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
            limb_retries: true,
            joint_states: true,
            through_kernel: true,
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
    /// Gravity in the reference frame in base orientations 1, 2, … (training poses recorded
    /// with the reference segment turned otherwise), m/s². Empty: the usual orientation only.
    pub other_gravities: Vec<Vector3<f64>>,
}

/// The part of a limb that an earlier estimate fixed: the joint frames of the DoFs from the static
/// reference to the limb's base, and gravity, in that estimate's reference frame.
#[derive(Debug, Clone, PartialEq)]
pub struct LimbBase {
    /// Joint frames of the base path's DoFs.
    pub joints: Vec<Isometry3<f64>>,
    /// Gravity, m/s².
    pub gravity: Vector3<f64>,
    /// Gravity in the other base orientations ([`ChainState::other_gravities`]), m/s².
    pub other_gravities: Vec<Vector3<f64>>,
}

impl LimbBase {
    /// The first `dofs` joint frames and the gravity of an estimate.
    pub fn of(estimate: &MlChainEstimate, dofs: usize) -> Option<Self> {
        let state = estimate.state.as_ref()?;
        (dofs <= state.joints.len()).then(|| Self {
            joints: state.joints[..dofs].to_vec(),
            gravity: state.gravity,
            other_gravities: state.other_gravities.clone(),
        })
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
        orientation: data.orientation.clone(),
        dynamics: data.dynamics.clone(),
        alpha: data.pattern.peak_acceleration(),
        huber: Some(HUBER),
        rejected: Vec::new(),
        missing: data.missing.clone(),
        gauge_prior: Some(problem::POSITION_PRIOR_SD),
        sd: data.sd.clone().map(std::sync::Arc::new),
        motion: None,
        expected_delay_rate: false,
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

/// Estimates one limb by maximum likelihood: joints of one or more DoFs, any number of SUs per
/// segment. With `base`, the joints of the limb's base path are held at that earlier estimate.
///
/// ```
/// use skincal::estimate::{ml, LimbChain, LimbData};
/// use skincal::model::presets;
/// use skincal::sim::{simulate, SimulationConfig};
///
/// let robot = presets::find("paper-7dof").unwrap().robot().unwrap();
/// let set = simulate(&robot, &SimulationConfig::default()).unwrap().measurements;
/// let chain = LimbChain::serial("arm", &robot.model.dof_names(), &robot.model.su_names()).unwrap();
/// let data = LimbData::new(&set, &chain).unwrap();
/// let estimate = ml::estimate_limb(&data, None, &ml::MlConfig::default()).unwrap();
/// assert!(estimate.converged);
/// assert!((estimate.residual_ratio - 1.0).abs() < 0.2); // at the noise level
/// ```
pub fn estimate_limb(
    data: &LimbData,
    base: Option<&LimbBase>,
    config: &MlConfig,
) -> Result<MlChainEstimate, EstimateError> {
    validate(config)?;
    if data.orientations() > 1 {
        return with_other_orientations(data, base, config);
    }
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
    if config.limb_retries {
        retries.other_orders(&mut best, data, &orders, done, |c| fit(c, config))?;
        retries.wider_search(&mut best, data, &orders, config, done, fit)?;
    }
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

/// A limb whose training poses stood in several base orientations: estimated from the poses of the
/// usual one (the search assumes one gravity), then refitted on every pose from there, each
/// other orientation with a gravity of its own, started from what the SUs read in it.
///
/// Where gravity runs along a vertical first axis, the usual orientation's readings cannot tell
/// the fit from its mirror image ([`mirrored`]: the first DoF turning the other way), and the
/// search keeps whichever came first; the other orientations can, so both are refitted and the
/// better kept (a humanoid's trunk refitted from the wrong one ended with bias and scale taking up
/// the misfit). The search's runner-ups get their other gravities too.
fn with_other_orientations(
    data: &LimbData,
    base: Option<&LimbBase>,
    config: &MlConfig,
) -> Result<MlChainEstimate, EstimateError> {
    let mut usual = estimate_limb(&data.usual_orientation(), base, config)?;
    let Some(start) = usual.state.clone() else {
        return Ok(usual);
    };
    let ordered = in_order_of(data, &usual.chain);
    let with_gravities = |mut state: ChainState| {
        state.other_gravities = other_gravities_read(&ordered, &state);
        state
    };
    let runner_ups = std::mem::take(&mut usual.runner_ups);
    let read = with_gravities(start.clone());
    let vertical = held_start(&ordered, base, read.clone(), config)?.1;
    let mut best = refine_limb(&ordered, base, read, config)?;
    if vertical {
        let mirror = with_gravities(mirrored(&start, &ordered.su_depth));
        let other = refine_limb(&ordered, base, mirror, config)?;
        if other.residual_ratio < best.residual_ratio {
            usual.retries.push(format!(
                "the mirror image about the vertical first axis, which the other base \
                 orientations tell apart: residual {:.2} σ (was {:.2} σ)",
                other.residual_ratio, best.residual_ratio
            ));
            best = MlChainEstimate {
                iterations: other.iterations + best.iterations,
                seconds: other.seconds + best.seconds,
                ..other
            };
        } else {
            best.iterations += other.iterations;
            best.seconds += other.seconds;
        }
    }
    best.runner_ups = runner_ups.into_iter().map(with_gravities).collect();
    Ok(best.after(usual))
}

/// `data` with every joint's DoFs in the order `chain` (the same limb) has them.
fn in_order_of(data: &LimbData, chain: &LimbChain) -> LimbData {
    chain
        .joints
        .iter()
        .enumerate()
        .fold(data.clone(), |d, (j, joint)| {
            let dofs = &d.chain.joints[j].dofs;
            let order: Option<Vec<usize>> = joint
                .dofs
                .iter()
                .map(|name| dofs.iter().position(|x| x == name))
                .collect();
            match order {
                Some(order) if order.len() == dofs.len() => d.with_joint_order(j, &order),
                _ => d,
            }
        })
}

/// Gravity in each other base orientation of `data` as its SUs read it at `state` (placed by the
/// usual orientation's fit): per pose and SU, the static reading turned into the reference frame,
/// and per orientation the component-wise median, which SUs whose turn the usual orientation
/// leaves free cannot drag.
fn other_gravities_read(data: &LimbData, state: &ChainState) -> Vec<Vector3<f64>> {
    let layout = Layout::of(data);
    let kinds = data.chain.kinds();
    let mut read: Vec<[Vec<f64>; 3]> = vec![Default::default(); data.orientations() - 1];
    for p in (0..data.poses()).filter(|&p| data.orientation_of(p) > 0) {
        let turns = problem::turns_of(&data.q[p], &kinds);
        let frames = problem::frames(state, &layout, &turns, None, layout.dofs);
        for (u, frame) in frames.sus.iter().enumerate() {
            let bias = Vector3::from(state.intrinsics[u].bias);
            let g = -(frame.rotation * (data.statics[p][u] - bias));
            for (c, column) in read[data.orientation_of(p) - 1].iter_mut().enumerate() {
                column.push(g[c]);
            }
        }
    }
    read.into_iter()
        .map(|[x, y, z]| Vector3::new(median(x), median(y), median(z)))
        .collect()
}

/// The median of `v` (its upper middle; 0 for none).
fn median(mut v: Vec<f64>) -> f64 {
    v.sort_by(f64::total_cmp);
    v.get(v.len() / 2).copied().unwrap_or(0.0)
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
        if !b.other_gravities.is_empty() {
            start.other_gravities = b.other_gravities.clone();
        }
    }
    if start.other_gravities.len() + 1 < data.orientations() {
        return Err(EstimateError::UnsupportedLimb {
            limb: data.chain.name.clone(),
            reason: format!(
                "its poses stood in {} base orientations, but the start has a gravity for {}",
                data.orientations(),
                start.other_gravities.len() + 1
            ),
        });
    }
    let vertical = base.is_none() && start.gravity.x == 0.0 && start.gravity.y == 0.0;
    Ok((start, vertical))
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
        orientations: 1,
    }
}

/// Test access to the internals: the Jacobian and the residuals through the chart, for a
/// chain state built from a robot.
#[doc(hidden)]
pub mod internals {
    use super::*;

    /// Residuals and Jacobian of the full problem at `state`.
    pub fn full_problem(
        data: &LimbData,
        state: &ChainState,
        sigma: f64,
    ) -> (nalgebra::DVector<f64>, DMatrix<f64>) {
        let (layout, spec) = full_of(data);
        problem::dense_problem(state, &layout, &readings(data), &spec, sigma)
    }

    /// The full problem of the motion rows alone (every block of `record`, the skin's delay a
    /// column after the others): residuals, Jacobian, and the residuals after a step
    /// `delta` of its columns for each step given.
    pub fn motion_problem(
        data: &LimbData,
        record: &crate::motion::MotionRecord,
        state: &ChainState,
        deltas: &[Vec<f64>],
    ) -> (
        nalgebra::DVector<f64>,
        DMatrix<f64>,
        Vec<nalgebra::DVector<f64>>,
    ) {
        let (layout, spec, readings) = motion_rows_only(data, record, state);
        let (r, jac) = problem::dense_problem(state, &layout, &readings, &spec, 0.05);
        let after = deltas
            .iter()
            .map(|d| {
                let moved = retract(state, &spec, d);
                problem::dense_residuals(&moved, &layout, &readings, &spec, 0.05)
            })
            .collect();
        (r, jac, after)
    }

    /// The normal equations of [`motion_problem`]'s problem at `state` as the fit forms them
    /// (SU blocks apart, a record's rows taken a chunk at a time), put together in its columns'
    /// order: the information `JᵀJ` and the gradient `Jᵀr`.
    pub fn motion_normal(
        data: &LimbData,
        record: &crate::motion::MotionRecord,
        state: &ChainState,
    ) -> (DMatrix<f64>, nalgebra::DVector<f64>) {
        let (layout, spec, readings) = motion_rows_only(data, record, state);
        let map = problem::ColumnMap::new(&spec);
        let normal = problem::normal_system(state, &layout, &readings, &spec, &map, 0.05);
        (
            problem::information(&normal, &map),
            problem::gradient(&normal, &map),
        )
    }

    /// The layout, the spec and the readings of [`motion_problem`].
    fn motion_rows_only(
        data: &LimbData,
        record: &crate::motion::MotionRecord,
        state: &ChainState,
    ) -> (Layout, Spec, Readings) {
        let layout = serial_layout(data.chain.dofs().len());
        let mut spec = full_spec(&layout, 1, true, Some(0), IntrinsicsModel::Full);
        spec.blocks.push(Block::SkinDelay);
        let mut motion = LimbMotion::new(record, data, 0.05).expect("the record has the chain");
        motion.weigh(state, &data.su_depth);
        let readings = Readings {
            q: Vec::new(),
            turns: Vec::new(),
            statics: Vec::new(),
            dynamics: Vec::new(),
            motion: Some(std::sync::Arc::new(motion)),
            // Plain least squares: Huber's weights change with the state and have no column.
            huber: None,
            ..readings(data)
        };
        (layout, spec, readings)
    }

    /// The serial layout of `data` and its full problem: every block, each other base
    /// orientation's gravity last.
    fn full_of(data: &LimbData) -> (Layout, Spec) {
        let layout = Layout {
            orientations: data.orientations(),
            ..serial_layout(data.chain.dofs().len())
        };
        let mut spec = full_spec(&layout, 1, true, Some(0), IntrinsicsModel::Full);
        spec.blocks
            .extend((1..layout.orientations).map(Block::OtherGravity));
        (layout, spec)
    }

    /// Residuals after a step `delta` of the full problem's columns.
    pub fn residuals_after(
        data: &LimbData,
        state: &ChainState,
        sigma: f64,
        delta: &[f64],
    ) -> nalgebra::DVector<f64> {
        let (layout, spec) = full_of(data);
        problem::dense_residuals(
            &retract(state, &spec, delta),
            &layout,
            &readings(data),
            &spec,
            sigma,
        )
    }
}
