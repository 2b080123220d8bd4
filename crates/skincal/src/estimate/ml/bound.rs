//! How close an estimate can come to the truth, and how close it came: the Cramér–Rao bound on
//! the SU poses, and an estimate's SU pose errors in the directions the readings determine.
//!
//! Real limbs leave directions that no reading tells: a shift along axes that are all parallel, the
//! turn about a vertical first axis of the SUs it alone moves. An estimate may sit anywhere along
//! them (held near its start by the weak gauge priors) and still predict every reading, so an error
//! against the truth along them says nothing about the estimator. [`observable_su_errors`] first
//! moves the truth along those directions as close to the estimate as it goes (Gauss–Newton on the
//! null space of the Fisher information, linearised again at every step because orbits about an
//! axis are not straight), then measures what is left and the Cramér–Rao bound on it.

use nalgebra::{DMatrix, DVector, Isometry3, Translation3, UnitQuaternion, Vector3};
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;

use super::problem::{
    covariance, frames, information, normal_system, pose_jacobian, retract_columns, turns_of,
    Block, ColumnMap, Layout, Readings, Spec,
};
use super::{full_spec, readings, serial_layout, ChainState, IntrinsicsModel, MlConfig};
use crate::estimate::limb::{LimbChain, LimbData};
use crate::model::intrinsics::Intrinsics;
use crate::model::Robot;

/// The chain state of a robot that names the limb's DoFs and SUs (e.g. the truth), in this
/// estimator's frames: reference = the first DoF's joint frame with `z` along its axis. `None` for
/// a limb with a base path held from another limb, or one the robot does not name.
pub fn state_of(robot: &Robot, chain: &LimbChain, gravity: &Vector3<f64>) -> Option<ChainState> {
    if chain.base_joints != 0 {
        return None;
    }
    sequence_state_of(robot, chain, &chain.su_depths(), gravity)
}

/// The chain state of a robot for SUs anywhere along the chain: SU `u` on segment `su_depth[u]`
/// (the number of the chain's DoFs that move it).
fn sequence_state_of(
    robot: &Robot,
    chain: &LimbChain,
    su_depth: &[usize],
    gravity: &Vector3<f64>,
) -> Option<ChainState> {
    let (joint_world, su_world) = super::super::chain_frames_at_zero(robot, chain)?;
    if su_depth.len() != su_world.len() || su_depth.iter().any(|&d| d == 0 || d > joint_world.len())
    {
        return None;
    }
    let to_reference = joint_world[0].inverse();
    let world: Vec<Isometry3<f64>> = joint_world.iter().map(|j| to_reference * j).collect();
    let mut joints = vec![Isometry3::identity(); world.len()];
    for i in 1..world.len() {
        joints[i] = world[i - 1].inverse() * world[i];
    }
    let su_states: Vec<Isometry3<f64>> = su_world
        .iter()
        .zip(su_depth)
        .map(|(s, &d)| world[d - 1].inverse() * (to_reference * s))
        .collect();
    Some(ChainState {
        gravity: to_reference.rotation * gravity,
        joints,
        intrinsics: vec![Intrinsics::default(); su_states.len()],
        sus: su_states,
        skin_delay: 0.0,
        other_gravities: Vec::new(),
    })
}

/// The Cramér–Rao bound on the consecutive-SU pose errors of [`crate::estimate::consecutive_su_errors`]:
/// the parameter covariance `σ²(JᵀJ)⁻¹` of the whitened Jacobian at the truth (for the training poses
/// of `data`; readings do not enter), propagated to each SU's pose relative to the previous one over
/// `poses` random held-out poses (seeded, each DoF uniform in ±2.62 rad). Returns the RMS position
/// bound (m) and the RMS rotation bound (rad) over the pairs that the metric aggregates (all but the
/// first). With `intrinsics`, the bound of an estimator that fits those intrinsics too (ideal
/// sensors at the truth, the gravity magnitude held when scales are fitted, as the estimator does).
pub fn cramer_rao_bound(
    truth: &Robot,
    gravity: &Vector3<f64>,
    data: &LimbData,
    sigma: f64,
    poses: usize,
    seed: u64,
    intrinsics: IntrinsicsModel,
) -> Option<(f64, f64)> {
    // `gravity` is the usual base orientation's: the bound of the poses recorded in it.
    let usual = data.usual_orientation();
    let data = &usual;
    let chain = &data.chain;
    let state = state_of(truth, chain, gravity)?;
    let dofs = chain.dofs().len();
    let layout = serial_layout(dofs);
    let spec = bound_spec(&layout, Some(0), intrinsics);
    let map = ColumnMap::new(&spec);
    let normal = normal_system(&state, &layout, &least_squares(data), &spec, &map, sigma);
    let columns = spec.columns();
    let n = columns.len();
    let (covariance, _) = covariance(
        &normal,
        &map,
        1.0,
        &vec![String::new(); n],
        MlConfig::default().observable_limit,
    );
    let mut rng = ChaCha8Rng::seed_from_u64(seed);
    let (mut position, mut rotation, mut count) = (0.0, 0.0, 0usize);
    let h = 1e-6;
    for _ in 0..poses {
        let q = turns_of(
            &(0..dofs)
                .map(|_| rng.random_range(-2.62..=2.62))
                .collect::<Vec<f64>>(),
            &layout.kinds,
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
                let plus = pair(&retract_columns(&state, &spec, &columns, &delta), i);
                delta[c] = -h;
                let minus = pair(&retract_columns(&state, &spec, &columns, &delta), i);
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

/// Per DoF of a limb (chain order): the Cramér–Rao bound on the RMS error of its dynamic
/// readings predicted at the poses of `held_out` (the norm of each SU's 3-vector error, every SU
/// the DoF moves, as [`crate::predict::validate`] measures it), for an estimator that fits
/// `data`'s readings (noise `sigma` per component, or each reading's own deviation where the set
/// gives them) with `intrinsics`: the parameters' covariance
/// at the truth, propagated to those predictions. The directions no reading tells change no
/// prediction in the same base orientation and are left out. `None` for a limb on a parent's
/// path, or a truth that does not name the limb's DoFs and SUs.
pub fn dynamic_reading_bounds(
    truth: &Robot,
    gravity: &Vector3<f64>,
    data: &LimbData,
    held_out: &LimbData,
    sigma: f64,
    intrinsics: IntrinsicsModel,
) -> Option<Vec<f64>> {
    let (data, held_out) = (data.usual_orientation(), held_out.usual_orientation());
    let chain = &data.chain;
    if chain.base_joints != 0 || held_out.su_depth != data.su_depth {
        return None;
    }
    let state = sequence_state_of(truth, chain, &data.su_depth, gravity)?;
    let layout = Layout::of(&data);
    let spec = bound_spec(&layout, None, intrinsics);
    let map = ColumnMap::new(&spec);
    let normal = normal_system(&state, &layout, &least_squares(&data), &spec, &map, sigma);
    let (_, covariance) = free_and_inverse(information(&normal, &map));
    let jac = pose_jacobian(&state, &layout, &least_squares(&held_out), &spec, sigma) * sigma;
    let dofs = layout.dofs;
    let (mut sum, mut count) = (vec![0.0; dofs], vec![0usize; dofs]);
    let mut row = 0;
    for &u in &spec.sus {
        let s = layout.su_segment[u];
        for _ in 0..held_out.q.len() {
            for j in 1..=s {
                let rows = jac.rows(row + 3 * j, 3);
                sum[j - 1] += (rows * &covariance * rows.transpose()).trace();
                count[j - 1] += 1;
            }
            row += 3 * (1 + s);
        }
    }
    Some(
        sum.iter()
            .zip(&count)
            .map(|(s, &c)| (s.max(0.0) / c.max(1) as f64).sqrt())
            .collect(),
    )
}

/// Every parameter the estimator fits with `intrinsics` (the gravity's magnitude held where
/// scales are fitted, as the estimator does), `gauge_su`'s height and turn held where given.
fn bound_spec(layout: &Layout, gauge_su: Option<usize>, intrinsics: IntrinsicsModel) -> Spec {
    let mut spec = full_spec(layout, 1, true, gauge_su, intrinsics);
    if intrinsics.components() > 3 {
        spec.blocks[0] = Block::GravityDirection;
    }
    spec
}

/// The readings of `data` for a bound: plain least squares (the Jacobian alone, whatever the
/// readings' residuals at the truth), with no gauge prior.
fn least_squares(data: &LimbData) -> Readings {
    Readings {
        huber: None,
        gauge_prior: None,
        ..readings(data)
    }
}

/// A basis of the directions an information matrix leaves free (eigenvalues below
/// [`FREE_DIRECTION`] of the largest), and its pseudo-inverse on the others (the parameters'
/// covariance).
fn free_and_inverse(information: DMatrix<f64>) -> (DMatrix<f64>, DMatrix<f64>) {
    let n = information.nrows();
    let eig = information.symmetric_eigen();
    let largest = eig.eigenvalues.iter().copied().fold(0.0f64, f64::max);
    let mut basis = Vec::new();
    let mut inverse = DMatrix::zeros(n, n);
    for (i, &e) in eig.eigenvalues.iter().enumerate() {
        let v = eig.eigenvectors.column(i).into_owned();
        if e <= largest * FREE_DIRECTION {
            basis.push(v);
        } else {
            inverse += &v * v.transpose() / e;
        }
    }
    let basis = if basis.is_empty() {
        DMatrix::zeros(n, 0)
    } else {
        DMatrix::from_columns(&basis)
    };
    (basis, inverse)
}

/// An estimate's SU poses against the truth, each relative to the previous SU along the limb, in
/// the directions the training readings determine ([`observable_su_errors`]).
#[derive(Debug, Clone, PartialEq)]
pub struct ObservableErrors {
    /// RMS position error over the held-out poses and SU pairs, m.
    pub position_rms: f64,
    /// The Cramér–Rao bound on it, at the truth moved along the free directions to the estimate, m.
    pub position_bound: f64,
    /// RMS rotation error over the held-out poses and SU pairs, rad.
    pub rotation_rms: f64,
    /// The Cramér–Rao bound on it, at the truth moved as for the position, rad.
    pub rotation_bound: f64,
    /// The bound on the position error at the truth as it is given, m: where the free directions
    /// sit as the truth has them, which no reading tells an estimator.
    pub position_bound_at_truth: f64,
    /// The RMS position error before the truth is moved along what no reading tells, m.
    pub raw_position_rms: f64,
    /// How many parameter directions no reading tells (at the truth).
    pub free_directions: usize,
}

/// Weight of a rotation error against a position error when the truth is moved along the free
/// directions, m/rad (an SU a decimetre from the axis it turns about).
const ROTATION_WEIGHT: f64 = 0.1;

/// An eigenvalue of the information matrix below this share of the largest is a direction that no
/// reading tells (exact gauges sit at round-off, ~1e-16).
const FREE_DIRECTION: f64 = 1e-10;

/// The pose of every SU of a limb relative to the previous one, `estimate` against `truth`, over
/// `poses` held-out poses (seeded; each DoF uniform in its true limits ∩ ±2.62 rad), after the truth
/// has been moved along every direction that the training readings of `data` leave free, as close
/// to the estimate as it goes; with the Cramér–Rao bound on the same errors there (the Fisher
/// information of `data`'s poses with `config`'s noise and intrinsics, propagated to the pairs;
/// the free directions' images taken out of errors and bound alike), and at the truth as given.
///
/// Every state the truth can be moved to reads exactly like it, so each is the truth as far as
/// any estimator can know; the bound differs between them (a joint tilt error swings an SU that
/// sits a metre along parallel axes ten times further than one a decimetre along them), and the one
/// an estimate answers to is the bound where its own free directions put it.
///
/// `estimate` is in the estimator's chart for `data`'s layout (e.g. [`super::MlChainEstimate`]'s
/// `state`). `None` for a limb on a parent's path, one SU, or a truth that does not name the
/// limb's DoFs and SUs.
pub fn observable_su_errors(
    truth: &Robot,
    gravity: &Vector3<f64>,
    estimate: &ChainState,
    data: &LimbData,
    config: &MlConfig,
    poses: usize,
    seed: u64,
) -> Option<ObservableErrors> {
    // `gravity` is the usual base orientation's: the errors the poses recorded in it allow.
    let usual = data.usual_orientation();
    let data = &usual;
    let chain = &data.chain;
    let sus = data.su_depth.len();
    if chain.base_joints != 0
        || sus < 2
        || poses == 0
        || estimate.sus.len() != sus
        || estimate.joints.len() != chain.dofs().len()
    {
        return None;
    }
    let state = sequence_state_of(truth, chain, &data.su_depth, gravity)?;
    let dofs: Vec<usize> = chain
        .dofs()
        .iter()
        .map(|d| truth.model.dof_index(d))
        .collect::<Option<_>>()?;
    let mut rng = ChaCha8Rng::seed_from_u64(seed);
    let kinds = data.chain.kinds();
    let held_out: Vec<Vec<Isometry3<f64>>> = (0..poses)
        .map(|_| {
            let q: Vec<f64> = dofs
                .iter()
                .map(|&d| {
                    let l = &truth.model.dofs()[d].limits;
                    let (lo, hi) = (l.lower.max(-2.62), l.upper.min(2.62));
                    if hi > lo {
                        rng.random_range(lo..=hi)
                    } else {
                        lo
                    }
                })
                .collect();
            turns_of(&q, &kinds)
        })
        .collect();
    let problem = PairProblem::new(data, config, held_out, estimate);

    let (basis, inverse) = problem.information(&state);
    let free_directions = basis.ncols();
    let at_truth = problem.variances(&problem.jacobian(&state), &basis, &inverse);
    let raw = problem.errors(&state);
    let (aligned, (basis, inverse)) = problem.align(problem.turn_first_segment(state));
    let jac = problem.jacobian(&aligned);
    let bound = problem.variances(&jac, &basis, &inverse);
    let left = problem.project(
        &problem.images(&jac, &basis),
        &DMatrix::from_column_slice(problem.rows, 1, problem.errors(&aligned).as_slice()),
    );
    let count = problem.target.len() as f64;
    let (mut position, mut rotation, mut position_bound, mut rotation_bound) = (0.0, 0.0, 0.0, 0.0);
    let (mut raw_position, mut truth_bound) = (0.0, 0.0);
    for i in 0..problem.rows {
        if i % 6 < 3 {
            position += left[i] * left[i];
            position_bound += bound[i];
            raw_position += raw[i] * raw[i];
            truth_bound += at_truth[i];
        } else {
            rotation += left[i] * left[i];
            rotation_bound += bound[i];
        }
    }
    let w2 = ROTATION_WEIGHT * ROTATION_WEIGHT;
    Some(ObservableErrors {
        position_rms: (position / count).sqrt(),
        position_bound: (position_bound.max(0.0) / count).sqrt(),
        rotation_rms: (rotation / w2 / count).sqrt(),
        rotation_bound: (rotation_bound.max(0.0) / w2 / count).sqrt(),
        position_bound_at_truth: (truth_bound.max(0.0) / count).sqrt(),
        raw_position_rms: (raw_position / count).sqrt(),
        free_directions,
    })
}

/// The SU pairs of a limb at held-out poses, against an estimate's, and the readings' information.
struct PairProblem<'a> {
    data: &'a LimbData,
    layout: Layout,
    /// Every parameter the estimator fits, the turn about and shift along the first axis included.
    spec: Spec,
    columns: Vec<(usize, usize)>,
    map: ColumnMap,
    readings: Readings,
    sigma: f64,
    held_out: Vec<Vec<Isometry3<f64>>>,
    /// The estimate's pairs, and its SU frames on their segments.
    target: Vec<Isometry3<f64>>,
    estimate_sus: Vec<Isometry3<f64>>,
    /// 6 per pair: position, then rotation (times [`ROTATION_WEIGHT`]).
    rows: usize,
}

impl<'a> PairProblem<'a> {
    fn new(
        data: &'a LimbData,
        config: &MlConfig,
        held_out: Vec<Vec<Isometry3<f64>>>,
        estimate: &ChainState,
    ) -> Self {
        let layout = Layout::of(data);
        let spec = bound_spec(&layout, None, config.intrinsics);
        let mut problem = Self {
            data,
            columns: spec.columns(),
            map: ColumnMap::new(&spec),
            spec,
            layout,
            readings: least_squares(data),
            sigma: config.noise_sd,
            held_out,
            target: Vec::new(),
            estimate_sus: estimate.sus.clone(),
            rows: 0,
        };
        problem.target = problem.pairs(estimate);
        problem.rows = 6 * problem.target.len();
        problem
    }

    /// Every SU relative to the previous one, pose by pose.
    fn pairs(&self, s: &ChainState) -> Vec<Isometry3<f64>> {
        let sus = self.layout.su_segment.len();
        self.held_out
            .iter()
            .flat_map(|turns| {
                let f = frames(s, &self.layout, turns, None, self.layout.dofs);
                (1..sus)
                    .map(|u| f.sus[u - 1].inverse() * f.sus[u])
                    .collect::<Vec<_>>()
            })
            .collect()
    }

    /// The estimate's pairs against `s`'s: per pair, the position difference and the rotation
    /// vector of `s⁻¹·estimate`, weighted.
    fn errors(&self, s: &ChainState) -> DVector<f64> {
        let mut e = DVector::zeros(self.rows);
        for (i, (t, x)) in self.pairs(s).iter().zip(&self.target).enumerate() {
            let dt = x.translation.vector - t.translation.vector;
            let dr = (t.rotation.inverse() * x.rotation).scaled_axis() * ROTATION_WEIGHT;
            e.rows_mut(6 * i, 3).copy_from(&dt);
            e.rows_mut(6 * i + 3, 3).copy_from(&dr);
        }
        e
    }

    /// The pairs' Jacobian (weighted like the errors), by central differences.
    fn jacobian(&self, s: &ChainState) -> DMatrix<f64> {
        let h = 1e-6;
        let n = self.columns.len();
        let mut jac = DMatrix::zeros(self.rows, n);
        let base = self.pairs(s);
        for (c, &(b, _)) in self.columns.iter().enumerate() {
            if !matches!(self.spec.blocks[b], Block::Joint(_) | Block::Su(_)) {
                continue;
            }
            let mut delta = vec![0.0; n];
            delta[c] = h;
            let plus = self.pairs(&retract_columns(s, &self.spec, &self.columns, &delta));
            delta[c] = -h;
            let minus = self.pairs(&retract_columns(s, &self.spec, &self.columns, &delta));
            for (i, ((p, m), o)) in plus.iter().zip(&minus).zip(&base).enumerate() {
                let dt = (p.translation.vector - m.translation.vector) / (2.0 * h);
                let dr = ((o.rotation.inverse() * p.rotation).scaled_axis()
                    - (o.rotation.inverse() * m.rotation).scaled_axis())
                    / (2.0 * h)
                    * ROTATION_WEIGHT;
                jac.view_mut((6 * i, c), (3, 1)).copy_from(&dt);
                jac.view_mut((6 * i + 3, c), (3, 1)).copy_from(&dr);
            }
        }
        jac
    }

    /// The readings' information at a state: a basis of the directions it leaves free, and its
    /// pseudo-inverse on the others (the parameter covariance).
    fn information(&self, s: &ChainState) -> (DMatrix<f64>, DMatrix<f64>) {
        let normal = normal_system(
            s,
            &self.layout,
            &self.readings,
            &self.spec,
            &self.map,
            self.sigma,
        );
        free_and_inverse(information(&normal, &self.map))
    }

    /// An orthonormal basis of what the free directions `basis` do to the pairs.
    fn images(&self, jac: &DMatrix<f64>, basis: &DMatrix<f64>) -> DMatrix<f64> {
        if basis.ncols() == 0 {
            return DMatrix::zeros(self.rows, 0);
        }
        let svd = (jac * basis).svd(true, false);
        let largest = svd.singular_values.max();
        let Some(u) = svd.u else {
            return DMatrix::zeros(self.rows, 0);
        };
        let kept: Vec<_> = (0..svd.singular_values.len())
            .filter(|&i| svd.singular_values[i] > 1e-9 * largest)
            .map(|i| u.column(i).into_owned())
            .collect();
        if kept.is_empty() {
            DMatrix::zeros(self.rows, 0)
        } else {
            DMatrix::from_columns(&kept)
        }
    }

    /// Per row of the errors, the variance that the bound allows with the free directions `basis`
    /// taken out, from the pairs' Jacobian and the parameter covariance `inverse`.
    fn variances(
        &self,
        jac: &DMatrix<f64>,
        basis: &DMatrix<f64>,
        inverse: &DMatrix<f64>,
    ) -> Vec<f64> {
        let spread = self.project(&self.images(jac, basis), jac);
        let bound = &spread * inverse;
        (0..self.rows)
            .map(|i| bound.row(i).dot(&spread.row(i)))
            .collect()
    }

    /// `m` with the span of `images` taken out.
    fn project(&self, images: &DMatrix<f64>, m: &DMatrix<f64>) -> DMatrix<f64> {
        m - images * (images.transpose() * m)
    }

    /// A vertical first axis leaves each SU that it alone moves free to turn about it (and to slide
    /// along it): each is turned (and slid) to match its pose relative to the previous SU in the
    /// estimate as well as a turn can, then all of them together against the SUs further out
    /// (searches over the circle, which Gauss–Newton may not cross from afar).
    fn turn_first_segment(&self, mut state: ChainState) -> ChainState {
        let depth = &self.data.su_depth;
        let estimate_sus = &self.estimate_sus;
        if state.gravity.normalize().cross(&Vector3::z()).norm() > 1e-9 {
            return state;
        }
        let misfit = |a: &Isometry3<f64>, b: &Isometry3<f64>| {
            (a.translation.vector - b.translation.vector).norm_squared()
                + (a.rotation.angle_to(&b.rotation) * ROTATION_WEIGHT).powi(2)
        };
        let about = |angle: f64, shift: f64| {
            Isometry3::from_parts(
                Translation3::new(0.0, 0.0, shift),
                UnitQuaternion::from_axis_angle(&Vector3::z_axis(), angle),
            )
        };
        let first = depth.iter().take_while(|&&d| d == 1).count();
        for u in 1..first {
            let shift = (estimate_sus[u].translation.z - estimate_sus[u - 1].translation.z)
                - (state.sus[u].translation.z - state.sus[u - 1].translation.z);
            let wanted = estimate_sus[u - 1].inverse() * estimate_sus[u];
            let fit = |angle: f64| {
                misfit(
                    &(state.sus[u - 1].inverse() * about(angle, shift) * state.sus[u]),
                    &wanted,
                )
            };
            let best = best_angle(720, fit);
            state.sus[u] = about(best, shift) * state.sus[u];
        }
        if first > 0 && first < depth.len() {
            let turned = |angle: f64| {
                let mut s = state.clone();
                for su in &mut s.sus[..first] {
                    *su = about(angle, 0.0) * *su;
                }
                s
            };
            let best = best_angle(360, |a| self.errors(&turned(a)).norm_squared());
            state = turned(best);
        }
        state
    }

    /// Gauss–Newton on the free directions: the state that reads like `state` and whose pairs come
    /// closest to the estimate's, with its [`Self::information`].
    fn align(&self, mut state: ChainState) -> (ChainState, (DMatrix<f64>, DMatrix<f64>)) {
        let (mut basis, mut inverse) = self.information(&state);
        let free = basis.ncols();
        for _ in 0..20 {
            if basis.ncols() == 0 {
                break;
            }
            let e = self.errors(&state);
            let svd = (self.jacobian(&state) * &basis).svd(true, true);
            let tolerance = 1e-9 * svd.singular_values.max();
            let Ok(step) = svd.solve(&e, tolerance) else {
                break;
            };
            let moved = retract_columns(
                &state,
                &self.spec,
                &self.columns,
                (&basis * &step).as_slice(),
            );
            // A step that reads differently (the free directions are not those of the truth's
            // state any more) is not a move along them.
            let (next, next_inverse) = self.information(&moved);
            if self.errors(&moved).norm() >= e.norm() || next.ncols() != free {
                break;
            }
            state = moved;
            (basis, inverse) = (next, next_inverse);
            if step.norm() < 1e-9 {
                break;
            }
        }
        (state, (basis, inverse))
    }
}

/// The angle of `steps` evenly spaced over the circle where `misfit` is least.
fn best_angle(steps: u32, misfit: impl Fn(f64) -> f64) -> f64 {
    (0..steps)
        .map(|i| f64::from(i) * std::f64::consts::TAU / f64::from(steps))
        .map(|a| (misfit(a), a))
        .min_by(|a, b| a.0.total_cmp(&b.0))
        .map_or(0.0, |(_, a)| a)
}
