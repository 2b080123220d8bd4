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
//! `R ← exp(ω)·R`), so there are no Euler-angle or DH singularities; the Jacobian is analytic at
//! the point of linearisation and checked against central differences in the tests.
//!
//! **Solver.** Levenberg–Marquardt with Marquardt scaling: every step solves the damped system by
//! Householder QR of the stacked matrix `[J; √λ·D]` (never `(JᵀJ)⁻¹`); the damping grows on rejected
//! steps and shrinks on accepted ones.
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
//! **Uncertainty.** The parameter covariance is `σ̂²·(RᵀR)⁻¹` from the R factor of the whitened
//! Jacobian's QR (triangular solves, no explicit normal-matrix inverse), and is propagated to each
//! SU's position and orientation relative to the previous SU.

use std::time::Instant;

use nalgebra::{
    DMatrix, DVector, Isometry3, Matrix3, Rotation3, Translation3, UnitQuaternion, Vector3,
};
use rayon::prelude::*;
use serde::{Deserialize, Serialize};

use super::{ChainData, EstimateError, SerialChain};
use crate::model::description::RobotFile;
use crate::model::sensor::STANDARD_GRAVITY;
use crate::model::{PlacementSpec, Robot};

/// Settings of the maximum-likelihood estimator.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct MlConfig {
    /// Standard deviation of the noise on every reading component, m/s² (default: uniform ±0.01 g).
    pub noise_sd: f64,
    /// Angles tried for a joint's rotation about its axis when gravity cannot tell it.
    pub angle_starts: usize,
    /// Largest number of LM iterations per solve.
    pub max_iterations: usize,
    /// A result whose residual RMS exceeds this multiple of `noise_sd` is not converged.
    pub converged_ratio: f64,
    /// Candidates carried from one segment to the next.
    pub beam: usize,
    /// Gravity is taken along the first axis when holding it there raises the χ² of segment 1 by
    /// less than this (default: the 99 % point of χ² with 2 degrees of freedom).
    pub vertical_test: f64,
    /// A parameter direction that the data determine only to worse than this (m or rad) is
    /// reported as unobservable.
    pub observable_limit: f64,
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
}

/// Which SU sits on which segment (1-based: segment `k` is moved directly by DoF `k−1`).
#[derive(Debug, Clone, PartialEq)]
struct Layout {
    dofs: usize,
    su_segment: Vec<usize>,
}

/// A parameter block of the least-squares problem.
#[derive(Debug, Clone, Copy, PartialEq)]
enum Block {
    Gravity,
    /// The 4 line parameters of joint `k`.
    Joint(usize),
    /// All 6 parameters of joint `k` (initialisation only).
    JointFull(usize),
    /// The 6 parameters of SU `u`.
    Su(usize),
}

impl Block {
    fn len(self) -> usize {
        match self {
            Block::Gravity => 3,
            Block::Joint(_) => 4,
            Block::JointFull(_) | Block::Su(_) => 6,
        }
    }
}

/// A least-squares problem: which blocks are free, which components are held, whose readings count.
#[derive(Debug, Clone, PartialEq)]
struct Spec {
    blocks: Vec<Block>,
    /// (block index, component) held fixed.
    held: Vec<(usize, usize)>,
    /// SUs whose residuals enter.
    sus: Vec<usize>,
    /// Frames that the free blocks cannot change, per pose: the joint frames before the first
    /// free joint and the segment it sits on (a cache for the segment-by-segment solves).
    prefix: Option<std::sync::Arc<Vec<Prefix>>>,
}

impl Spec {
    /// Free columns: (block index, component).
    fn columns(&self) -> Vec<(usize, usize)> {
        self.blocks
            .iter()
            .enumerate()
            .flat_map(|(b, block)| (0..block.len()).map(move |c| (b, c)))
            .filter(|bc| !self.held.contains(bc))
            .collect()
    }
}

/// Frames of one pose.
struct Frames {
    /// Joint frames in the reference frame.
    joints: Vec<Isometry3<f64>>,
    /// Segment frames in the reference frame (`segments[0] = I`).
    segments: Vec<Isometry3<f64>>,
    /// SU frames in the reference frame.
    sus: Vec<Isometry3<f64>>,
}

/// Joint frames `0…k−1` and the frame of segment `k` of one pose, in the reference frame.
#[derive(Debug, Clone, PartialEq)]
struct Prefix {
    joints: Vec<Isometry3<f64>>,
    segment: Isometry3<f64>,
}

/// The prefixes up to joint `k` of every pose.
fn prefixes(state: &ChainState, layout: &Layout, data: &Readings, k: usize) -> Vec<Prefix> {
    data.turns
        .iter()
        .map(|turns| {
            let f = frames(state, layout, turns, None, k);
            Prefix {
                joints: f.joints[..k].to_vec(),
                segment: f.segments[k],
            }
        })
        .collect()
}

/// `Rz(q_k)` for every DoF of a pose.
fn turns_of(q: &[f64]) -> Vec<UnitQuaternion<f64>> {
    q.iter()
        .map(|&a| UnitQuaternion::from_axis_angle(&Vector3::z_axis(), a))
        .collect()
}

/// Frames of one pose up to segment `last` (joints `0…last−1`), continuing from `prefix` when given,
/// and the frames of the SUs on those segments (identity for the others).
fn frames(
    state: &ChainState,
    layout: &Layout,
    turns: &[UnitQuaternion<f64>],
    prefix: Option<&Prefix>,
    last: usize,
) -> Frames {
    let (mut joints, mut segments) = match prefix {
        Some(p) => {
            let mut segments = vec![Isometry3::identity(); p.joints.len()];
            segments.push(p.segment);
            (p.joints.clone(), segments)
        }
        None => (Vec::with_capacity(layout.dofs), vec![Isometry3::identity()]),
    };
    for k in joints.len()..last.min(layout.dofs) {
        let j = segments[k] * state.joints[k];
        joints.push(j);
        segments.push(j * turns[k]);
    }
    let sus = state
        .sus
        .iter()
        .zip(&layout.su_segment)
        .map(|(s, &seg)| segments.get(seg).map_or(Isometry3::identity(), |f| f * s))
        .collect();
    Frames {
        joints,
        segments,
        sus,
    }
}

/// The local motion of component `c` of a joint block, as a world twist `(ω, v)` such that a point
/// `p` downstream moves by `ω × p + v` and a direction rotates by `ω`.
fn joint_twist(joint: &Isometry3<f64>, c: usize) -> (Vector3<f64>, Vector3<f64>) {
    let axis = |i: usize| joint.rotation * Vector3::ith(i, 1.0);
    let o = joint.translation.vector;
    match c {
        // Rotations about the joint's own x, y (and z for the full block) through its origin.
        0 | 1 | 4 => {
            let w = axis(if c == 4 { 2 } else { c });
            (w, -w.cross(&o))
        }
        // Shifts along x, y (and z).
        2 | 3 => (Vector3::zeros(), axis(c - 2)),
        _ => (Vector3::zeros(), axis(2)),
    }
}

/// Residual vector (whitened) and its Jacobian with respect to the free columns of `spec`, at `state`.
fn linearise(
    state: &ChainState,
    layout: &Layout,
    data: &Readings,
    spec: &Spec,
    sigma: f64,
    jacobian: bool,
) -> (DVector<f64>, DMatrix<f64>) {
    let columns = spec.columns();
    let rows: usize = spec
        .sus
        .iter()
        .map(|&u| 3 * (1 + layout.su_segment[u]))
        .sum::<usize>()
        * data.q.len();
    let mut r = DVector::zeros(rows);
    let mut jac = DMatrix::zeros(if jacobian { rows } else { 0 }, columns.len());
    let g = state.gravity;
    let alpha = data.alpha;
    let last = spec
        .sus
        .iter()
        .map(|&u| layout.su_segment[u])
        .max()
        .unwrap_or(0);
    let mut row = 0;
    for p in 0..data.q.len() {
        let f = frames(
            state,
            layout,
            &data.turns[p],
            spec.prefix.as_ref().map(|v| &v[p]),
            last,
        );
        for &u in &spec.sus {
            let s = layout.su_segment[u];
            let ru = f.sus[u].rotation.to_rotation_matrix().into_inner();
            let rut = ru.transpose();
            let pu = f.sus[u].translation.vector;
            let measured_static = data.statics[p][u];
            r.fixed_rows_mut::<3>(row)
                .copy_from(&((rut * (-g) - measured_static) / sigma));
            let axes: Vec<(Vector3<f64>, Vector3<f64>)> = (0..s)
                .map(|d| {
                    (
                        f.joints[d].rotation * Vector3::z(),
                        f.joints[d].translation.vector,
                    )
                })
                .collect();
            for (d, (z, o)) in axes.iter().enumerate() {
                let w = z.cross(&(pu - o));
                let predicted = rut * (w * alpha);
                r.fixed_rows_mut::<3>(row + 3 * (1 + d))
                    .copy_from(&((predicted - data.dynamics[p][u][d]) / sigma));
            }
            if jacobian {
                for (col, &(b, c)) in columns.iter().enumerate() {
                    // Effect of the column on (R_u, p_u) as a world twist, and on axes d ≥ `moved_from`.
                    let (omega, dp, moved_from, dg) = match spec.blocks[b] {
                        Block::Gravity => (
                            Vector3::zeros(),
                            Vector3::zeros(),
                            usize::MAX,
                            Some(Vector3::ith(c, 1.0)),
                        ),
                        Block::Joint(k) | Block::JointFull(k) => {
                            if k >= s {
                                continue;
                            }
                            let c = if matches!(spec.blocks[b], Block::Joint(_)) {
                                c
                            } else {
                                [0, 1, 4, 2, 3, 5][c]
                            };
                            let (w, v) = joint_twist(&f.joints[k], c);
                            (w, w.cross(&pu) + v, k, None)
                        }
                        Block::Su(v) => {
                            if v != u {
                                continue;
                            }
                            let rs = f.segments[s].rotation;
                            if c < 3 {
                                (
                                    rs * Vector3::ith(c, 1.0),
                                    Vector3::zeros(),
                                    usize::MAX,
                                    None,
                                )
                            } else {
                                (
                                    Vector3::zeros(),
                                    rs * Vector3::ith(c - 3, 1.0),
                                    usize::MAX,
                                    None,
                                )
                            }
                        }
                    };
                    let mut column = jac.fixed_view_mut::<3, 1>(row, col);
                    match dg {
                        Some(e) => column.copy_from(&(-(rut * e) / sigma)),
                        None => column.copy_from(&(rut * omega.cross(&g) / sigma)),
                    }
                    for (d, (z, o)) in axes.iter().enumerate() {
                        if d >= moved_from || dg.is_some() {
                            continue; // the axis moves with the SU (or gravity does not enter).
                        }
                        let w = z.cross(&(pu - o));
                        let delta = rut * (w.cross(&omega) + z.cross(&dp)) * alpha;
                        jac.fixed_view_mut::<3, 1>(row + 3 * (1 + d), col)
                            .copy_from(&(delta / sigma));
                    }
                }
            }
            row += 3 * (1 + s);
        }
    }
    (r, jac)
}

/// Applies a step of the free columns to the state (the retraction).
fn retract(state: &ChainState, spec: &Spec, delta: &[f64]) -> ChainState {
    let mut full: Vec<[f64; 6]> = vec![[0.0; 6]; spec.blocks.len()];
    for (&(b, c), &x) in spec.columns().iter().zip(delta) {
        full[b][c] = x;
    }
    let mut next = state.clone();
    for (b, block) in spec.blocks.iter().enumerate() {
        let x = full[b];
        match *block {
            Block::Gravity => next.gravity += Vector3::new(x[0], x[1], x[2]),
            Block::Joint(k) => {
                let local = Isometry3::from_parts(
                    Translation3::new(x[2], x[3], 0.0),
                    UnitQuaternion::from_scaled_axis(Vector3::new(x[0], x[1], 0.0)),
                );
                next.joints[k] = state.joints[k] * local;
            }
            Block::JointFull(k) => {
                let local = Isometry3::from_parts(
                    Translation3::new(x[3], x[4], x[5]),
                    UnitQuaternion::from_scaled_axis(Vector3::new(x[0], x[1], x[2])),
                );
                next.joints[k] = state.joints[k] * local;
            }
            Block::Su(u) => {
                let s = &state.sus[u];
                next.sus[u] = Isometry3::from_parts(
                    Translation3::from(s.translation.vector + Vector3::new(x[3], x[4], x[5])),
                    UnitQuaternion::from_scaled_axis(Vector3::new(x[0], x[1], x[2])) * s.rotation,
                );
            }
        }
    }
    next
}

/// Relative cost decrease below which an initialisation solve stops.
const INIT_TOLERANCE: f64 = 1e-6;
/// Relative cost decrease below which the final joint refinement stops.
const FINAL_TOLERANCE: f64 = 1e-10;

/// A start for one segment's solve: the beam state it extends, the SU placement and joint frame to
/// start from, the cost so far and the beam entry it came from.
struct Candidate {
    state: ChainState,
    su: Isometry3<f64>,
    start: Isometry3<f64>,
    cost: f64,
    beam: usize,
}

/// Outcome of one LM solve.
#[derive(Debug, Clone)]
struct Solved {
    state: ChainState,
    cost: f64,
    residuals: usize,
    iterations: usize,
}

fn solve(
    state: ChainState,
    layout: &Layout,
    data: &Readings,
    spec: &Spec,
    sigma: f64,
    max_iterations: usize,
    tolerance: f64,
) -> Solved {
    let mut state = state;
    let (mut r, mut jac) = linearise(&state, layout, data, spec, sigma, true);
    let mut cost = r.norm_squared();
    let n = jac.ncols();
    let mut lambda: f64 = 1e-3;
    let mut iterations = 0;
    while iterations < max_iterations {
        iterations += 1;
        // One QR of the Jacobian per iteration; each trial damping only needs a small QR of
        // [R; √λ·D] (the MINPACK scheme).
        let scale: Vec<f64> = (0..n).map(|c| jac.column(c).norm().max(1e-12)).collect();
        let qr = std::mem::replace(&mut jac, DMatrix::zeros(0, 0)).qr();
        let mut qtr = -r.clone();
        qr.q_tr_mul(&mut qtr);
        let r_factor = qr.r();
        let mut improved = false;
        for _ in 0..40 {
            let mut stacked = DMatrix::zeros(2 * n, n);
            stacked.view_mut((0, 0), (n, n)).copy_from(&r_factor);
            for c in 0..n {
                stacked[(n + c, c)] = lambda.sqrt() * scale[c];
            }
            let mut rhs = DVector::zeros(2 * n);
            rhs.rows_mut(0, n).copy_from(&qtr.rows(0, n));
            let small = stacked.qr();
            small.q_tr_mul(&mut rhs);
            let Some(step) = small
                .r()
                .solve_upper_triangular(&rhs.rows(0, n).into_owned())
            else {
                lambda *= 10.0;
                continue;
            };
            let trial = retract(&state, spec, step.as_slice());
            let (tr, _) = linearise(&trial, layout, data, spec, sigma, false);
            let trial_cost = tr.norm_squared();
            if trial_cost < cost {
                let relative = (cost - trial_cost) / cost.max(1e-300);
                state = trial;
                cost = trial_cost;
                lambda = (lambda / 3.0).max(1e-12);
                improved = relative > tolerance && cost * relative > 1e-6 && step.norm() > 1e-10;
                break;
            }
            lambda *= 4.0;
            if lambda > 1e12 {
                break;
            }
        }
        if !improved {
            break;
        }
        (r, jac) = linearise(&state, layout, data, spec, sigma, true);
    }
    Solved {
        residuals: r.len(),
        state,
        cost,
        iterations,
    }
}

/// Readings of the chain, per pose and SU, in m/s².
#[derive(Debug, Clone)]
struct Readings {
    q: Vec<Vec<f64>>,
    /// `Rz(q)` of every DoF in every pose.
    turns: Vec<Vec<UnitQuaternion<f64>>>,
    statics: Vec<Vec<Vector3<f64>>>,
    /// `dynamics[p][u][d]` for every DoF `d` before the SU.
    dynamics: Vec<Vec<Vec<Vector3<f64>>>>,
    alpha: f64,
}

/// One SU's parameter uncertainty, relative to the previous SU of the chain (to the reference frame
/// for the first), at the zero pose.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct SuUncertainty {
    /// The SU.
    pub su: String,
    /// Standard deviation of its position, m (root of the trace of the 3×3 covariance).
    pub position_sd: f64,
    /// Standard deviation of its orientation, rad (root of the trace of the rotation covariance).
    pub orientation_sd: f64,
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
}

/// The maximum-likelihood estimate of one chain.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct MlChainEstimate {
    /// The chain.
    pub chain: SerialChain,
    /// The estimated limb as a robot description (reference = the first DoF's joint frame).
    pub robot: RobotFile,
    /// Gravity in the reference frame, m/s².
    pub gravity: [f64; 3],
    /// Residual RMS relative to the noise standard deviation (≈ 1 at the noise limit).
    pub residual_ratio: f64,
    /// Estimated noise standard deviation, m/s².
    pub noise_sd_estimate: f64,
    /// Whether the residual is at the noise level.
    pub converged: bool,
    /// Parameters held by the gauge.
    pub fixed: Vec<String>,
    /// Directions the data do not determine.
    pub unobservable: Vec<Unobservable>,
    /// Per SU: standard deviations.
    pub uncertainty: Vec<SuUncertainty>,
    /// The same limb in the paper's DH+2 form (`None` if it cannot be expressed).
    pub dh: Option<DhTable>,
    /// LM iterations, all solves.
    pub iterations: usize,
    /// Wall time, s.
    pub seconds: f64,
}

impl MlChainEstimate {
    /// The estimated limb as a robot.
    pub fn to_robot(&self) -> Robot {
        self.robot
            .build()
            .expect("an estimated chain is a valid robot")
    }
}

fn readings(data: &ChainData) -> Readings {
    Readings {
        q: data.q.clone(),
        turns: data.q.iter().map(|q| turns_of(q)).collect(),
        statics: data.static_readings.clone(),
        dynamics: data
            .dynamic
            .iter()
            .map(|per_su| {
                per_su
                    .iter()
                    .enumerate()
                    .map(|(u, d)| d[..=u].to_vec())
                    .collect()
            })
            .collect(),
        alpha: data.pattern.peak_acceleration(),
    }
}

/// Rotation taking unit vector `n` onto `z`.
fn onto_z(n: &Vector3<f64>) -> UnitQuaternion<f64> {
    UnitQuaternion::rotation_between(n, &Vector3::z()).unwrap_or_else(|| {
        UnitQuaternion::from_axis_angle(&Vector3::x_axis(), std::f64::consts::PI)
    })
}

/// Closed-form placement of SU `u` on the segment that DoF `d = u` moves: the axis direction from the
/// smallest singular vector of its DoF-`d` accelerations, the lever arm from their mean. `sign` picks
/// the axis sense.
fn su_from_axis(data: &Readings, u: usize, sign: f64) -> Isometry3<f64> {
    let d = u;
    let p = data.q.len();
    let m = DMatrix::from_fn(p, 3, |i, c| data.dynamics[i][u][d][c]);
    let svd = m.svd(false, true);
    let vt = svd.v_t.expect("requested");
    let smallest = (0..svd.singular_values.len())
        .min_by(|&a, &b| svd.singular_values[a].total_cmp(&svd.singular_values[b]))
        .unwrap_or(0);
    let n =
        Vector3::new(vt[(smallest, 0)], vt[(smallest, 1)], vt[(smallest, 2)]).normalize() * sign;
    let mean: Vector3<f64> = (0..p)
        .map(|i| data.dynamics[i][u][d] / data.alpha)
        .sum::<Vector3<f64>>()
        / p as f64;
    let lever = mean.cross(&n);
    let rotation = onto_z(&n);
    Isometry3::from_parts(Translation3::from(rotation * lever), rotation)
}

/// Solves `min_R Σ |a_i − R b_i|²` (Wahba) and reports how well the `b_i` span 3-D.
fn wahba(a: &[Vector3<f64>], b: &[Vector3<f64>]) -> (Rotation3<f64>, f64) {
    let mut h = Matrix3::zeros();
    for (x, y) in a.iter().zip(b) {
        h += x * y.transpose();
    }
    let svd = h.svd(true, true);
    let (u, vt) = (svd.u.expect("requested"), svd.v_t.expect("requested"));
    let mut d = Matrix3::identity();
    if (u * vt).determinant() < 0.0 {
        d[(2, 2)] = -1.0;
    }
    let mut s: Vec<f64> = svd.singular_values.iter().copied().collect();
    s.sort_by(f64::total_cmp);
    let spread = if s[2] > 0.0 { s[1] / s[2] } else { 0.0 };
    (Rotation3::from_matrix_unchecked(u * d * vt), spread)
}

/// Estimates one chain by maximum likelihood.
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
    validate(config)?;
    let started = Instant::now();
    let dofs = data.chain.dofs.len();
    let parameters = 3 + 4 * (dofs - 1) + 6 * dofs - 2;
    let per_pose: usize = (0..dofs).map(|u| 3 * (2 + u)).sum();
    let needed = parameters.div_ceil(per_pose).max(3);
    if data.poses() < needed {
        return Err(EstimateError::TooFewPoses {
            poses: data.poses(),
            parameters: needed,
        });
    }
    let layout = Layout {
        dofs,
        su_segment: (1..=dofs).collect(),
    };
    let readings = readings(data);
    let sigma = config.noise_sd;
    let mut iterations = 0;

    // Segment 1: the SU relative to the first axis in closed form, gravity from its static readings.
    // Both senses of the axis are kept: with a vertical first axis they fit segment 1 equally well
    // (mirror images), and only the later segments tell them apart.
    let empty = ChainState {
        gravity: Vector3::zeros(),
        joints: vec![Isometry3::identity(); dofs],
        sus: vec![Isometry3::identity(); dofs],
    };
    let mut beam: Vec<(ChainState, f64)> = Vec::new();
    let mut vertical_votes = 0;
    for sign in [1.0, -1.0] {
        let mut s = empty.clone();
        s.sus[0] = su_from_axis(&readings, 0, sign);
        let minus_g: Vector3<f64> = (0..data.poses())
            .map(|p| {
                UnitQuaternion::from_axis_angle(&Vector3::z_axis(), readings.q[p][0])
                    * (s.sus[0].rotation * readings.statics[p][0])
            })
            .sum::<Vector3<f64>>()
            / data.poses() as f64;
        s.gravity = -minus_g;
        let spec = Spec {
            blocks: vec![Block::Gravity, Block::Su(0)],
            held: vec![(1, 2), (1, 5)],
            sus: vec![0],
            prefix: None,
        };
        let free = solve(
            s,
            &layout,
            &readings,
            &spec,
            sigma,
            config.max_iterations,
            INIT_TOLERANCE,
        );
        // Is the first axis vertical? A likelihood-ratio test of gravity along it.
        let mut upright = free.state.clone();
        upright.gravity = Vector3::new(
            0.0,
            0.0,
            upright.gravity.z.signum() * upright.gravity.norm(),
        );
        let spec_upright = Spec {
            held: vec![(0, 0), (0, 1), (1, 2), (1, 5)],
            ..spec
        };
        let held = solve(
            upright,
            &layout,
            &readings,
            &spec_upright,
            sigma,
            config.max_iterations,
            INIT_TOLERANCE,
        );
        iterations += free.iterations + held.iterations;
        if held.cost - free.cost < config.vertical_test {
            vertical_votes += 1;
            beam.push((held.state, held.cost));
        } else {
            beam.push((free.state, free.cost));
        }
    }
    let vertical = vertical_votes == 2;

    // Segments 2…N: SU from its own axis, joint rotation from gravity (or searched), joint position
    // from upstream accelerations; every candidate refined (in parallel), the best few kept.
    for k in 1..dofs {
        // Joints 0…k−1 stay as they are in this segment's solves: their frames are computed once.
        let caches: Vec<std::sync::Arc<Vec<Prefix>>> = beam
            .iter()
            .map(|(state, _)| std::sync::Arc::new(prefixes(state, &layout, &readings, k)))
            .collect();
        let mut candidates: Vec<Candidate> = Vec::new();
        for (b, (state, cost)) in beam.iter().enumerate() {
            for sign in [1.0, -1.0] {
                let su = su_from_axis(&readings, k, sign);
                for start in joint_starts(state, &layout, &readings, k, &su, config.angle_starts) {
                    candidates.push(Candidate {
                        state: state.clone(),
                        su,
                        start,
                        cost: *cost,
                        beam: b,
                    });
                }
            }
        }
        // Phase 1: the joint frame alone from every start; phase 2: joint and SU together.
        let phase1: Vec<(Solved, f64, usize)> = candidates
            .into_par_iter()
            .map(
                |Candidate {
                     state,
                     su,
                     start,
                     cost,
                     beam: b,
                 }| {
                    let mut s = state;
                    s.sus[k] = su;
                    s.joints[k] = start;
                    let spec = Spec {
                        blocks: vec![Block::JointFull(k)],
                        held: vec![],
                        sus: vec![k],
                        prefix: Some(caches[b].clone()),
                    };
                    (
                        solve(
                            s,
                            &layout,
                            &readings,
                            &spec,
                            sigma,
                            config.max_iterations.min(10),
                            INIT_TOLERANCE,
                        ),
                        cost,
                        b,
                    )
                },
            )
            .collect();
        iterations += phase1.iter().map(|s| s.0.iterations).sum::<usize>();
        let solved: Vec<(Solved, f64)> = phase1
            .into_par_iter()
            .map(|(first, cost, b)| {
                let spec = Spec {
                    blocks: vec![Block::Joint(k), Block::Su(k)],
                    held: vec![],
                    sus: vec![k],
                    prefix: Some(caches[b].clone()),
                };
                let solved = solve(
                    first.state,
                    &layout,
                    &readings,
                    &spec,
                    sigma,
                    config.max_iterations,
                    INIT_TOLERANCE,
                );
                let total = cost + solved.cost;
                (solved, total)
            })
            .collect();
        iterations += solved.iter().map(|s| s.0.iterations).sum::<usize>();
        let mut ranked: Vec<(ChainState, f64)> = solved
            .into_iter()
            .map(|(s, total)| (s.state, total))
            .collect();
        ranked.sort_by(|a, b| a.1.total_cmp(&b.1));
        beam.clear();
        for (state, cost) in ranked {
            if beam.len() == config.beam.max(1) {
                break;
            }
            if beam
                .iter()
                .all(|(_, c)| (c - cost).abs() > 1e-7 * cost.abs().max(1.0))
            {
                beam.push((state, cost));
            }
        }
    }
    let state = beam.swap_remove(0).0;
    // The whole chain at once.
    let mut spec = full_spec(&layout);
    if vertical {
        // Gravity along the first axis: its horizontal components are held at zero, which leaves
        // the turn of everything after segment 1 about that axis exactly free (reported below).
        spec.held.extend([(0, 0), (0, 1)]);
    }
    let solved = solve(
        state,
        &layout,
        &readings,
        &spec,
        sigma,
        config.max_iterations,
        FINAL_TOLERANCE,
    );
    iterations += solved.iterations;
    let state = solved.state;
    let dof_count = spec.columns().len();
    let noise_sd_estimate =
        sigma * (solved.cost / (solved.residuals.saturating_sub(dof_count)).max(1) as f64).sqrt();
    let residual_ratio = noise_sd_estimate / sigma;

    let names = column_names(&data.chain, &spec);
    let (_, jac) = linearise(&state, &layout, &readings, &spec, sigma, true);
    let (covariance, unobservable) = covariance(
        &jac,
        residual_ratio.max(1.0),
        &names,
        config.observable_limit,
    );
    let uncertainty = su_uncertainty(&state, &layout, &spec, &data.chain, &covariance);
    let mut fixed = vec![
        format!("{}.rotation_z", data.chain.sus[0]),
        format!("{}.z", data.chain.sus[0]),
    ];
    if vertical {
        fixed.extend(["gravity.x".to_string(), "gravity.y".to_string()]);
    }
    let limb = chain_robot(&data.chain, &state);
    let dh =
        super::dh_form(&limb, &data.chain).map(|(dof_dof, dof_su)| DhTable { dof_dof, dof_su });
    Ok(MlChainEstimate {
        robot: RobotFile::from_robot(&limb, Some("maximum-likelihood estimate".into())),
        dh,
        chain: data.chain.clone(),
        gravity: state.gravity.into(),
        residual_ratio,
        noise_sd_estimate,
        converged: residual_ratio <= config.converged_ratio,
        fixed,
        unobservable,
        uncertainty,
        iterations,
        seconds: started.elapsed().as_secs_f64(),
    })
}

fn full_spec(layout: &Layout) -> Spec {
    let mut blocks = vec![Block::Gravity];
    blocks.extend((1..layout.dofs).map(Block::Joint));
    blocks.extend((0..layout.su_segment.len()).map(Block::Su));
    // The first SU (on segment 1) holds the gauge: its rotation about and shift along z.
    let first_su = layout.dofs;
    Spec {
        prefix: None,
        blocks,
        held: vec![(first_su, 2), (first_su, 5)],
        sus: (0..layout.su_segment.len()).collect(),
    }
}

fn column_names(chain: &SerialChain, spec: &Spec) -> Vec<String> {
    spec.columns()
        .iter()
        .map(|&(b, c)| match spec.blocks[b] {
            Block::Gravity => format!("gravity.{}", ["x", "y", "z"][c]),
            Block::Joint(k) => format!(
                "{}.{}",
                chain.dofs[k],
                ["tilt_x", "tilt_y", "shift_x", "shift_y"][c]
            ),
            Block::JointFull(k) => {
                format!("{}.{}", chain.dofs[k], ["rx", "ry", "rz", "x", "y", "z"][c])
            }
            Block::Su(u) => format!(
                "{}.{}",
                chain.sus[u],
                ["rotation_x", "rotation_y", "rotation_z", "x", "y", "z"][c]
            ),
        })
        .collect()
}

/// Candidate joint frames for joint `k` given SU `k`'s placement `su` on segment `k+1`.
fn joint_starts(
    state: &ChainState,
    layout: &Layout,
    data: &Readings,
    k: usize,
    su: &Isometry3<f64>,
    angles: usize,
) -> Vec<Isometry3<f64>> {
    let p = data.q.len();
    let minus_g = -state.gravity;
    // Gravity in segment k's frame (known) and in segment k+1's frame turned back by q_k.
    let mut before = Vec::with_capacity(p);
    let mut after = Vec::with_capacity(p);
    let mut segment = Vec::with_capacity(p);
    for i in 0..p {
        let f = frames(state, layout, &data.turns[i], None, layout.dofs);
        before.push(f.segments[k].rotation.inverse() * minus_g);
        after.push(
            UnitQuaternion::from_axis_angle(&Vector3::z_axis(), data.q[i][k])
                * (su.rotation * data.statics[i][k]),
        );
        segment.push(f.segments[k]);
    }
    let (rotation, spread) = wahba(&before, &after);
    let mut rotations = vec![UnitQuaternion::from_rotation_matrix(&rotation)];
    if spread < 0.2 {
        // Gravity hardly turns between the segments: every rotation that maps its direction onto
        // itself fits the statics, so the angle about that direction is searched.
        let base = rotations[0];
        let direction = nalgebra::Unit::new_normalize(after.iter().sum::<Vector3<f64>>());
        let n = angles.max(1);
        rotations = (0..n)
            .map(|i| {
                base * UnitQuaternion::from_axis_angle(
                    &direction,
                    2.0 * std::f64::consts::PI * i as f64 / n as f64,
                )
            })
            .collect();
    }
    rotations
        .into_iter()
        .map(|r| {
            let t = joint_position(state, layout, data, k, su, &r, &segment);
            Isometry3::from_parts(Translation3::from(t), r)
        })
        .collect()
}

/// Joint `k`'s position on segment `k` by linear least squares on the accelerations that upstream
/// DoFs cause at SU `k`, for a given joint rotation.
fn joint_position(
    state: &ChainState,
    layout: &Layout,
    data: &Readings,
    k: usize,
    su: &Isometry3<f64>,
    rotation: &UnitQuaternion<f64>,
    segment: &[Isometry3<f64>],
) -> Vector3<f64> {
    let mut ata = Matrix3::zeros();
    let mut atb = Vector3::zeros();
    for (i, seg) in segment.iter().enumerate() {
        let f = frames(state, layout, &data.turns[i], None, layout.dofs);
        let turn = UnitQuaternion::from_axis_angle(&Vector3::z_axis(), data.q[i][k]);
        let r_world = seg.rotation * rotation * turn * su.rotation;
        // p_u = seg·(t + R·Rz(q)·t_su) = c + Rseg·t.
        let c = seg * nalgebra::Point3::from(rotation * (turn * su.translation.vector));
        let c = c.coords;
        let rseg = seg.rotation.to_rotation_matrix().into_inner();
        for d in 0..k {
            let z = f.joints[d].rotation * Vector3::z();
            let o = f.joints[d].translation.vector;
            // a/α in world = z × (c + Rseg t − o)  →  [z]× Rseg t = a_w/α − z × (c − o).
            let a_world = r_world * data.dynamics[i][k][d] / data.alpha;
            let m = z.cross_matrix() * rseg;
            let b = a_world - z.cross(&(c - o));
            ata += m.transpose() * m;
            atb += m.transpose() * b;
        }
    }
    (ata + Matrix3::identity() * 1e-9)
        .lu()
        .solve(&atb)
        .unwrap_or_else(Vector3::zeros)
}

/// Parameter covariance from a column-pivoted QR of the whitened Jacobian `J·P = Q·R`: the leading
/// pivot columns get `scale²·(R₁₁ᵀR₁₁)⁻¹` by triangular solves (no normal-matrix inverse). A direction
/// the data determine only to worse than `limit` (1 m or 1 rad by default: the whitened Jacobian's
/// singular value below `1/limit`) counts as unobservable: it is reported by the parameters that
/// make it up (from the SVD). Directions with no information at all (singular value below 1e-9 of
/// the largest: what the data leave free, like a gauge) correspond to the pivot columns beyond the
/// numerical rank; those are held at their estimate and get no variance.
fn covariance(
    jac: &DMatrix<f64>,
    scale: f64,
    names: &[String],
    limit: f64,
) -> (DMatrix<f64>, Vec<Unobservable>) {
    let n = jac.ncols();
    let svd = jac.clone().svd(false, true);
    let largest = svd.singular_values.max().max(1e-300);
    let mut unobservable = Vec::new();
    if let Some(vt) = &svd.v_t {
        for (i, &s) in svd.singular_values.iter().enumerate() {
            if s * limit < 1.0 {
                let mut parts: Vec<(f64, usize)> = (0..n)
                    .map(|c| (vt[(i, c)].abs(), c))
                    .filter(|(w, _)| *w > 0.3)
                    .collect();
                parts.sort_by(|a, b| b.0.total_cmp(&a.0));
                unobservable.push(Unobservable {
                    singular_value: s / largest,
                    parameters: parts.iter().map(|&(_, c)| names[c].clone()).collect(),
                });
            }
        }
    }
    let qr = jac.clone().col_piv_qr();
    let r = qr.r();
    let mut order = DMatrix::from_fn(1, n, |_, c| c as f64);
    qr.p().permute_columns(&mut order);
    let order: Vec<usize> = order.iter().map(|&c| c as usize).collect();
    // Only directions with no information at all (a gauge the data leave free) are held; weakly
    // determined ones keep their large variance.
    let null = svd
        .singular_values
        .iter()
        .filter(|&&s| s <= largest * 1e-9)
        .count();
    let rank = n.saturating_sub(null).min(r.nrows());
    let mut covariance = DMatrix::zeros(n, n);
    let r11 = r.view((0, 0), (rank, rank)).into_owned();
    if let Some(r_inv) = r11.solve_upper_triangular(&DMatrix::identity(rank, rank)) {
        let sub = &r_inv * r_inv.transpose() * (scale * scale);
        for i in 0..rank {
            for j in 0..rank {
                covariance[(order[i], order[j])] = sub[(i, j)];
            }
        }
    }
    (covariance, unobservable)
}

/// Pose of SU `u` relative to the previous SU (reference for the first) at q = 0.
fn relative_pose(state: &ChainState, layout: &Layout, u: usize) -> Isometry3<f64> {
    let f = frames(
        state,
        layout,
        &vec![UnitQuaternion::identity(); layout.dofs],
        None,
        layout.dofs,
    );
    if u == 0 {
        f.sus[0]
    } else {
        f.sus[u - 1].inverse() * f.sus[u]
    }
}

fn su_uncertainty(
    state: &ChainState,
    layout: &Layout,
    spec: &Spec,
    chain: &SerialChain,
    covariance: &DMatrix<f64>,
) -> Vec<SuUncertainty> {
    let n = spec.columns().len();
    let h = 1e-6;
    (0..layout.su_segment.len())
        .map(|u| {
            let base = relative_pose(state, layout, u);
            let mut jac = DMatrix::zeros(6, n);
            for c in 0..n {
                let mut delta = vec![0.0; n];
                delta[c] = h;
                let plus = relative_pose(&retract(state, spec, &delta), layout, u);
                delta[c] = -h;
                let minus = relative_pose(&retract(state, spec, &delta), layout, u);
                let dt = (plus.translation.vector - minus.translation.vector) / (2.0 * h);
                let dr = (base.rotation.inverse() * plus.rotation).scaled_axis()
                    - (base.rotation.inverse() * minus.rotation).scaled_axis();
                for i in 0..3 {
                    jac[(i, c)] = dt[i];
                    jac[(3 + i, c)] = dr[i] / (2.0 * h);
                }
            }
            let cov = &jac * covariance * jac.transpose();
            SuUncertainty {
                su: chain.sus[u].clone(),
                position_sd: (cov[(0, 0)] + cov[(1, 1)] + cov[(2, 2)]).max(0.0).sqrt(),
                orientation_sd: (cov[(3, 3)] + cov[(4, 4)] + cov[(5, 5)]).max(0.0).sqrt(),
            }
        })
        .collect()
}

/// The estimated chain as a robot: reference = the first joint frame.
fn chain_robot(chain: &SerialChain, state: &ChainState) -> Robot {
    let origins = state
        .joints
        .iter()
        .map(PlacementSpec::from_isometry)
        .collect();
    let sus = state
        .sus
        .iter()
        .enumerate()
        .map(|(u, s)| (u, PlacementSpec::from_isometry(s)))
        .collect();
    super::chain_robot(chain, origins, sus)
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

/// Test access to the internals: the analytic Jacobian and the residuals through the chart, for a
/// chain state built from a robot.
#[doc(hidden)]
pub mod internals {
    use super::*;

    /// Residuals and analytic Jacobian of the full problem at `state`.
    pub fn full_problem(
        data: &ChainData,
        state: &ChainState,
        sigma: f64,
    ) -> (DVector<f64>, DMatrix<f64>) {
        let layout = Layout {
            dofs: data.chain.dofs.len(),
            su_segment: (1..=data.chain.dofs.len()).collect(),
        };
        linearise(
            state,
            &layout,
            &readings(data),
            &full_spec(&layout),
            sigma,
            true,
        )
    }

    /// Residuals after a step `delta` of the full problem's columns.
    pub fn residuals_after(
        data: &ChainData,
        state: &ChainState,
        sigma: f64,
        delta: &[f64],
    ) -> DVector<f64> {
        let layout = Layout {
            dofs: data.chain.dofs.len(),
            su_segment: (1..=data.chain.dofs.len()).collect(),
        };
        let spec = full_spec(&layout);
        linearise(
            &retract(state, &spec, delta),
            &layout,
            &readings(data),
            &spec,
            sigma,
            false,
        )
        .0
    }
}

/// The chain state of a robot that names the chain's DoFs and SUs (e.g. the truth), in this
/// estimator's frames: reference = the first DoF's joint frame with `z` along its axis.
pub fn state_of(robot: &Robot, chain: &SerialChain, gravity: &Vector3<f64>) -> Option<ChainState> {
    let (joint_world, su_world) = super::chain_frames_at_zero(robot, chain)?;
    let to_reference = joint_world[0].inverse();
    let world: Vec<Isometry3<f64>> = joint_world.iter().map(|j| to_reference * j).collect();
    let mut joints = vec![Isometry3::identity(); world.len()];
    for i in 1..world.len() {
        joints[i] = world[i - 1].inverse() * world[i];
    }
    let su_states = su_world
        .iter()
        .enumerate()
        .map(|(u, s)| world[u].inverse() * (to_reference * s))
        .collect();
    Some(ChainState {
        gravity: to_reference.rotation * gravity,
        joints,
        sus: su_states,
    })
}

/// The Cramér–Rao bound on the consecutive-SU pose errors of [`super::consecutive_su_errors`]:
/// the parameter covariance `σ²(JᵀJ)⁻¹` of the whitened Jacobian at the truth (for the training poses
/// of `data`; readings do not enter), propagated to each SU's pose relative to the previous one over
/// `poses` random held-out poses (seeded, each DoF uniform in ±2.62 rad). Returns the RMS position
/// bound (m) and the RMS rotation bound (rad) over the pairs that the metric aggregates (all but the
/// first).
pub fn cramer_rao_bound(
    truth: &Robot,
    gravity: &Vector3<f64>,
    data: &ChainData,
    sigma: f64,
    poses: usize,
    seed: u64,
) -> Option<(f64, f64)> {
    use rand::{Rng, SeedableRng};
    let state = state_of(truth, &data.chain, gravity)?;
    let dofs = data.chain.dofs.len();
    let layout = Layout {
        dofs,
        su_segment: (1..=dofs).collect(),
    };
    let spec = full_spec(&layout);
    let (_, jac) = linearise(&state, &layout, &readings(data), &spec, sigma, true);
    let n = jac.ncols();
    let (covariance, _) = covariance(
        &jac,
        1.0,
        &vec![String::new(); n],
        MlConfig::default().observable_limit,
    );
    let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(seed);
    let (mut position, mut rotation, mut count) = (0.0, 0.0, 0usize);
    let h = 1e-6;
    for _ in 0..poses {
        let q = turns_of(
            &(0..dofs)
                .map(|_| rng.random_range(-2.62..=2.62))
                .collect::<Vec<f64>>(),
        );
        let pair = |s: &ChainState, i: usize| {
            let f = frames(s, &layout, &q, None, layout.dofs);
            f.sus[i].inverse() * f.sus[i + 1]
        };
        for i in 1..dofs.saturating_sub(1) {
            let base = pair(&state, i);
            let mut jac_t = DMatrix::zeros(3, n);
            let mut jac_r = DMatrix::zeros(3, n);
            for c in 0..n {
                let mut delta = vec![0.0; n];
                delta[c] = h;
                let plus = pair(&retract(&state, &spec, &delta), i);
                delta[c] = -h;
                let minus = pair(&retract(&state, &spec, &delta), i);
                let dt = (plus.translation.vector - minus.translation.vector) / (2.0 * h);
                let dr = ((base.rotation.inverse() * plus.rotation).scaled_axis()
                    - (base.rotation.inverse() * minus.rotation).scaled_axis())
                    / (2.0 * h);
                jac_t.set_column(c, &dt);
                jac_r.set_column(c, &dr);
            }
            position += (&jac_t * &covariance * jac_t.transpose()).trace();
            rotation += (&jac_r * &covariance * jac_r.transpose()).trace();
            count += 1;
        }
    }
    let count = count.max(1) as f64;
    Some(((position / count).sqrt(), (rotation / count).sqrt()))
}
