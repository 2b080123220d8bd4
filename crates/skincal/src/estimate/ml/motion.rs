//! The time-domain rows of a limb's problem: what every SU read in every block of a motion record
//! (`crate::motion`) against the specific force its frame has under the measured joint motion —
//! gravity, tangential, centripetal and Coriolis terms of every DoF before it, several DoFs moving
//! at once — with the delay of the skin's clock behind the joint states' as a parameter.
//!
//! For a segment `s` at one instant, an SU at `p` (segment frame) with rotation `R` reads
//! `Rᵀ (c_s + N_s p)`: `c_s = R_sᵀ (a_s + M_s x_s − g)` and `N_s = R_sᵀ M_s R_s` from the segment's
//! motion ([`crate::model::BodyMotion`]: `a(p) = a + M p`). These 12 numbers per segment and
//! sample are shared by every SU on the segment; their derivatives with respect to the joint
//! lines and gravity come from dual numbers through the same kinematics, one pass per column.

use nalgebra::{Isometry3, Matrix3, Quaternion, RealField, Translation3, UnitQuaternion, Vector3};
use num_dual::Dual64;
use rayon::prelude::*;

use super::problem::{gravity_directions, Block};
use super::ChainState;
use crate::estimate::limb::LimbData;
use crate::estimate::EstimateError;
use crate::model::BodyMotion;
use crate::motion::{MotionRecord, QUIET_REACH};

/// The largest delay of the skin's clock behind the joint states' that is estimated, s (a driver's
/// latency; more is another clock, which ingest refuses).
pub const MAX_DELAY: f64 = 0.05;
/// A block whose DoF accelerations are less certain than this is not fitted, rad/s²: the joint
/// motion changed faster than the record's local polynomial follows (a jerk at a phase's start),
/// and its prediction would be wrong by that much times the lever arm. A DoF whose encoder
/// leaves every block less certain gets [`SUDDEN`] times its median instead.
pub const MAX_ACCELERATION_SD: f64 = 0.05;
/// How many times its median uncertainty makes a DoF's acceleration too uncertain to fit.
pub const SUDDEN: f64 = 3.0;

/// One block of the record that the limb's fit uses.
#[derive(Debug, Clone, PartialEq)]
pub(super) struct MotionSample {
    run: usize,
    block: usize,
    q: Vec<f64>,
    qd: Vec<f64>,
    qdd: Vec<f64>,
    qdd_sd: Vec<f64>,
}

/// A limb's share of a motion record: its DoFs (chain order) and SUs.
#[derive(Debug, Clone, PartialEq)]
pub struct LimbMotion {
    period: f64,
    pub(super) samples: Vec<MotionSample>,
    /// `skin[run][u][block]` for the limb's SUs.
    skin: Vec<Vec<Vec<Option<Vector3<f64>>>>>,
    /// Each SU's standard deviation of one component of a block mean, m/s².
    pub(super) sd: Vec<f64>,
    /// `joint_var[u][i]`: the variance the joint accelerations' uncertainty adds to SU `u`'s
    /// prediction at sample `i`, (m/s²)² (empty until [`LimbMotion::weigh`]).
    joint_var: Vec<Vec<f64>>,
}

impl LimbMotion {
    /// The blocks of `record` for the limb of `data` (every block at least [`MAX_DELAY`] and two
    /// blocks from its run's ends, so that any delay reads the same blocks). An SU the record
    /// cannot tell its noise for gets `fallback_sd` over the square root of the skin samples a
    /// block holds at the record's period and 1 kHz.
    pub fn new(
        record: &MotionRecord,
        data: &LimbData,
        fallback_sd: f64,
    ) -> Result<Self, EstimateError> {
        let limb = &data.chain.name;
        let find = |kind: &str, names: &[String], name: &String| {
            names
                .iter()
                .position(|n| n == name)
                .ok_or_else(|| EstimateError::UnsupportedLimb {
                    limb: limb.clone(),
                    reason: format!(
                        "the motion record has no {kind} `{name}`: ingest the logs again with it"
                    ),
                })
        };
        let dofs: Vec<usize> = data
            .chain
            .dofs()
            .iter()
            .map(|d| find("DoF", &record.dofs, d))
            .collect::<Result<_, _>>()?;
        let sus: Vec<usize> = data
            .chain
            .sus()
            .iter()
            .map(|s| find("SU", &record.sus, s))
            .collect::<Result<_, _>>()?;
        let margin = (MAX_DELAY / record.period).ceil() as usize + 2;
        let limits: Vec<f64> = dofs
            .iter()
            .map(|&d| {
                let mut sds: Vec<f64> = record
                    .runs
                    .iter()
                    .flat_map(|run| run.qdd_sd.iter().map(move |row| row[d]))
                    .collect();
                if sds.is_empty() {
                    return MAX_ACCELERATION_SD;
                }
                let mid = sds.len() / 2;
                let median = *sds.select_nth_unstable_by(mid, f64::total_cmp).1;
                MAX_ACCELERATION_SD.max(SUDDEN * median)
            })
            .collect();
        let mut samples = Vec::new();
        let mut skin = Vec::new();
        for (r, run) in record.runs.iter().enumerate() {
            let pick = |row: &Vec<f64>| dofs.iter().map(|&d| row[d]).collect::<Vec<f64>>();
            for b in margin..run.len().saturating_sub(margin) {
                let sudden = dofs.iter().zip(&limits);
                if sudden
                    .into_iter()
                    .any(|(&d, &limit)| run.qdd_sd[b][d] > limit)
                {
                    continue;
                }
                samples.push(MotionSample {
                    run: r,
                    block: b,
                    q: pick(&run.q[b]),
                    qd: pick(&run.qd[b]),
                    qdd: pick(&run.qdd[b]),
                    qdd_sd: pick(&run.qdd_sd[b]),
                });
            }
            skin.push(
                sus.iter()
                    .map(|&u| {
                        run.skin
                            .iter()
                            .map(|row| row[u].map(Vector3::from))
                            .collect()
                    })
                    .collect(),
            );
        }
        let per_block = (record.period * 1000.0).max(1.0);
        let sd = sus
            .iter()
            .map(|&u| record.noise_sd[u].unwrap_or(fallback_sd / per_block.sqrt()))
            .collect();
        Ok(Self {
            period: record.period,
            samples,
            skin,
            sd,
            joint_var: Vec::new(),
        })
    }

    /// Sets what each sample's joint accelerations add to the variance of each SU's prediction,
    /// at `state` (the start of the fit, held through it so that the weights do not pull the
    /// SUs towards the axes): `Σ_d σ²(q̈_d) |z_d × (p − o_d)|²` over the DoFs before the SU on
    /// segment `su_segment[u]`.
    pub(super) fn weigh(&mut self, state: &ChainState, su_segment: &[usize]) {
        self.weigh_as_static(state, su_segment, 0.0);
    }

    /// [`LimbMotion::weigh`], and each prediction taken as if the limb stood still, with what its
    /// motion could add to gravity as error: `kappa` times [`QUIET_REACH`] times
    /// `Σ|q̈_d| + (Σ|q̇_d|)²` over the DoFs before the SU. With `kappa` 1 the quiet blocks count
    /// and the fast ones hardly; lowered step by step, the fit is led from a start that gravity
    /// alone gave (orientations and axes) to the whole motion.
    pub(super) fn weigh_as_static(&mut self, state: &ChainState, su_segment: &[usize], kappa: f64) {
        let joint_var: Vec<Vec<f64>> = self
            .samples
            .par_iter()
            .map(|sample| {
                let mut segment = Isometry3::<f64>::identity();
                let mut segments = vec![segment];
                let mut axes = Vec::with_capacity(state.joints.len());
                for (k, joint) in state.joints.iter().enumerate() {
                    let frame = segment * joint;
                    axes.push((frame.rotation * Vector3::z(), frame.translation.vector));
                    segment =
                        frame * UnitQuaternion::from_axis_angle(&Vector3::z_axis(), sample.q[k]);
                    segments.push(segment);
                }
                su_segment
                    .iter()
                    .zip(&state.sus)
                    .map(|(&s, su)| {
                        let p = (segments[s] * su).translation.vector;
                        let joints: f64 = axes
                            .iter()
                            .take(s)
                            .zip(&sample.qdd_sd)
                            .map(|((z, o), sd)| (z.cross(&(p - o)) * *sd).norm_squared())
                            .sum();
                        let spin: f64 = sample.qd.iter().take(s).map(|v| v.abs()).sum();
                        let turn: f64 = sample.qdd.iter().take(s).map(|a| a.abs()).sum();
                        joints + (kappa * QUIET_REACH * (turn + spin * spin)).powi(2)
                    })
                    .collect()
            })
            .collect();
        // Transposed: per SU, per sample.
        self.joint_var = (0..su_segment.len())
            .map(|u| joint_var.iter().map(|v| v[u]).collect())
            .collect();
    }

    /// The standard deviation of one component of SU `u`'s residual at sample `i`: its block
    /// mean's noise and what the joint accelerations add.
    pub(super) fn residual_sd(&self, u: usize, i: usize) -> f64 {
        let extra = self.joint_var.get(u).and_then(|v| v.get(i)).copied();
        (self.sd[u].powi(2) + extra.unwrap_or(0.0)).sqrt()
    }

    /// Every `every`-th of the blocks the fit uses (the skin kept whole): a coarse version for
    /// the steps that only lead a fit to where the whole record takes over.
    pub(super) fn thinned(&self, every: usize) -> Self {
        let every = every.max(1);
        Self {
            samples: self.samples.iter().step_by(every).cloned().collect(),
            joint_var: Vec::new(),
            ..self.clone()
        }
    }

    /// The number of blocks the fit uses.
    pub fn len(&self) -> usize {
        self.samples.len()
    }

    /// Whether the fit uses no block.
    pub fn is_empty(&self) -> bool {
        self.samples.is_empty()
    }

    /// What SU `u` read at sample `i` with the skin's clock `delay` s behind the joints': its
    /// block means interpolated (Catmull–Rom) at the block `delay` later; `None` where a block
    /// the interpolation needs has no sample.
    pub(super) fn measured(&self, u: usize, i: usize, delay: f64) -> Option<Vector3<f64>> {
        let sample = &self.samples[i];
        let series = &self.skin[sample.run][u];
        let x = sample.block as f64 + delay.clamp(-MAX_DELAY, MAX_DELAY) / self.period;
        let k = x.floor();
        let t = x - k;
        let k = k as usize;
        let at = |j: usize| series.get(j).copied().flatten();
        let (p0, p1, p2, p3) = (at(k.checked_sub(1)?)?, at(k)?, at(k + 1)?, at(k + 2)?);
        let (t2, t3) = (t * t, t * t * t);
        Some(
            (p1 * 2.0
                + (p2 - p0) * t
                + (p0 * 2.0 - p1 * 5.0 + p2 * 4.0 - p3) * t2
                + (p1 * 3.0 - p0 - p2 * 3.0 + p3) * t3)
                * 0.5,
        )
    }

    /// Whether samples `i` and `j` are neighbouring blocks of one run.
    pub(super) fn adjacent(&self, i: usize, j: usize) -> bool {
        let (a, b) = (&self.samples[i], &self.samples[j]);
        a.run == b.run && a.block.abs_diff(b.block) == 1
    }

    /// The length of a block, s.
    pub(super) fn period(&self) -> f64 {
        self.period
    }
}

/// Segment `s`'s `(c_s, N_s)` at one sample (index `s − 1`) and, per shared column, their
/// derivatives.
pub(super) struct SegmentTerms {
    pub c: Vec<Vector3<f64>>,
    pub n: Vec<Matrix3<f64>>,
    /// Per segment `s − 1`: `(column, ∂c_s, ∂N_s)` of the shared columns that move it (gravity,
    /// and the lines of joints up to `s`; every other column's are zero).
    pub d: Vec<Vec<ColumnRate>>,
}

/// A shared column and the rates `(∂c_s, ∂N_s)` of one segment's terms along it.
pub(super) type ColumnRate = (usize, Vector3<f64>, Matrix3<f64>);

/// `(c_s, N_s, R_s)` of segments `1..=last` of a chain whose joint frames (each on the segment
/// before it, as in [`ChainState::joints`]) are `joints`, at one sample, under `gravity`; with
/// `step`, joint `k`'s frame is followed by the local motion given.
fn terms<T: RealField + Copy>(
    joints: &[Isometry3<T>],
    step: Option<(usize, &Isometry3<T>)>,
    sample: &MotionSample,
    gravity: &Vector3<T>,
    last: usize,
) -> Vec<(Vector3<T>, Matrix3<T>, Matrix3<T>)> {
    let mut segment = Isometry3::<T>::identity();
    let mut motion = BodyMotion::<T>::still();
    let mut out = Vec::with_capacity(last);
    for (k, joint) in joints.iter().enumerate().take(last) {
        let mut frame = segment * joint;
        if let Some((_, local)) = step.filter(|(at, _)| *at == k) {
            frame *= local;
        }
        let axis = frame.rotation * Vector3::z();
        let point = frame.translation.vector;
        motion = motion.through(
            &axis,
            &point,
            T::from_subset(&sample.qd[k]),
            T::from_subset(&sample.qdd[k]),
        );
        segment = frame
            * UnitQuaternion::from_axis_angle(&Vector3::z_axis(), T::from_subset(&sample.q[k]));
        let r = segment.rotation.to_rotation_matrix().into_inner();
        let m = motion.point_matrix();
        let c = r.transpose() * (motion.accel + m * segment.translation.vector - gravity);
        out.push((c, r.transpose() * m * r, r));
    }
    out
}

/// An `f64` isometry as one of dual numbers (no derivative).
fn lift(iso: &Isometry3<f64>) -> Isometry3<Dual64> {
    let q = iso.rotation.coords.map(Dual64::from);
    Isometry3::from_parts(
        Translation3::from(iso.translation.vector.map(Dual64::from)),
        UnitQuaternion::new_unchecked(Quaternion::from(q)),
    )
}

/// The first-order local motion of component `c` of a joint block (as [`super::problem`]'s
/// retraction applies it) with the dual unit in that component: rotations as `(1, ε/2)`
/// quaternions, exact to first order (a rotation vector's norm has no derivative at zero).
fn joint_step(full: bool, c: usize) -> Isometry3<Dual64> {
    let mut x = [Dual64::from(0.0); 6];
    // Joint: (rx, ry, x, y); full: (rx, ry, rz, x, y, z).
    let slot = if full { c } else { [0, 1, 3, 4][c] };
    x[slot] = Dual64::new(0.0, 1.0);
    let half = Dual64::from(0.5);
    Isometry3::from_parts(
        Translation3::new(x[3], x[4], x[5]),
        UnitQuaternion::new_unchecked(Quaternion::new(
            Dual64::from(1.0),
            x[0] * half,
            x[1] * half,
            x[2] * half,
        )),
    )
}

/// The segment terms of every sample at `state`, for segments `1..=last`; with `columns` (the
/// shared columns of the problem: block and component), their derivatives too: along gravity
/// `∂c_s = −R_sᵀ δg` (`N_s` does not see it), along a joint line by dual numbers through
/// [`terms`], one pass per column.
pub(super) fn segment_terms(
    state: &ChainState,
    motion: &LimbMotion,
    last: usize,
    columns: Option<&[(Block, usize)]>,
) -> Vec<SegmentTerms> {
    let directions = gravity_directions(&state.gravity);
    let lifted: Vec<Isometry3<Dual64>> = state.joints.iter().map(lift).collect();
    let g_dual = state.gravity.map(Dual64::from);
    let steps: Vec<Option<(usize, Isometry3<Dual64>)>> = columns
        .unwrap_or(&[])
        .iter()
        .map(|&(block, c)| match block {
            Block::Joint(k) | Block::JointFull(k) if k < last => {
                Some((k, joint_step(matches!(block, Block::JointFull(_)), c)))
            }
            _ => None,
        })
        .collect();
    motion
        .samples
        .par_iter()
        .map(|sample| {
            let values = terms(&state.joints, None, sample, &state.gravity, last);
            let mut out = SegmentTerms {
                c: values.iter().map(|v| v.0).collect(),
                n: values.iter().map(|v| v.1).collect(),
                d: vec![Vec::new(); last],
            };
            for (col, (&(block, c), step)) in columns.unwrap_or(&[]).iter().zip(&steps).enumerate()
            {
                let gravity = match block {
                    Block::Gravity => Some(Vector3::ith(c, 1.0)),
                    Block::GravityDirection => Some(directions[c]),
                    _ => None,
                };
                let along = step
                    .as_ref()
                    .map(|(k, local)| terms(&lifted, Some((*k, local)), sample, &g_dual, last));
                for (s, (_, _, r)) in values.iter().enumerate() {
                    let (dc, dn) = match (&along, gravity, step) {
                        // Joint k's line moves segments k + 1 on (terms' entries k on).
                        (Some(d), _, Some((k, _))) if s >= *k => {
                            (d[s].0.map(|x| x.eps), d[s].1.map(|x| x.eps))
                        }
                        (None, Some(dir), _) => (-(r.transpose() * dir), Matrix3::zeros()),
                        _ => continue,
                    };
                    out.d[s].push((col, dc, dn));
                }
            }
            out
        })
        .collect()
}
