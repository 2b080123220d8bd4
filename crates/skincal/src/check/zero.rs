//! A DoF whose zero moved (an encoder homed anew after a hard reset): every SU beyond it reads as
//! if the DoF stood a little further. Per block, how each segment's specific-force field changes
//! with each DoF's angle (a finite difference of the kinematics); per SU and DoF of its chain, the
//! normal equations of that angle summed with the SU's own; a DoF is taken to have moved when its
//! one angle explains about as much of its SUs' readings as their nine changes each would (the
//! Bayesian information criterion), and its angle is then taken out of their sums.

use nalgebra::{Matrix3, Vector3};
use serde::{Deserialize, Serialize};

use super::kin::{BlockKinematics, Jacobian, SuPlace};
use super::test::{self, Change, Tally};
use crate::model::Robot;

/// The step of the finite difference, rad.
const STEP: f64 = 1e-6;
/// The model's own error of a DoF's zero that is never taken for a change, rad.
pub const ZERO_FLOOR: f64 = 0.2 * std::f64::consts::PI / 180.0;

/// How one segment's field changes with one DoF's angle: a point `p` of the segment reads, in the
/// segment's axes, `c₀ − Rᵀ g + N p`; these are the derivatives of `c₀`, `Rᵀ` and `N`.
#[derive(Debug, Clone, Copy)]
struct FieldRate {
    c: Vector3<f64>,
    rt: Matrix3<f64>,
    n: Matrix3<f64>,
}

/// Per DoF, per segment beyond it: the rate of its field (`None` for segments it does not move).
pub struct Rates(Vec<Vec<Option<FieldRate>>>);

impl Rates {
    /// The rates at `q` with velocities `qd` and accelerations `qdd` (model order); `block` is the
    /// kinematics there.
    pub fn new(robot: &Robot, block: &BlockKinematics, q: &[f64], qd: &[f64], qdd: &[f64]) -> Self {
        let m = &robot.model;
        let here = fields(block);
        let rates = (0..m.dofs().len())
            .map(|d| {
                let mut moved = q.to_vec();
                moved[d] += STEP;
                let there = fields(&BlockKinematics::new(robot, &moved, qd, qdd));
                (0..m.segments().len())
                    .map(|s| {
                        m.moves_segment(d, s).then(|| FieldRate {
                            c: (there[s].0 - here[s].0) / STEP,
                            rt: (there[s].1 - here[s].1) / STEP,
                            n: (there[s].2 - here[s].2) / STEP,
                        })
                    })
                    .collect()
            })
            .collect();
        Self(rates)
    }

    /// How SU `place`'s reading changes with DoF `d`'s angle; `kr` is the SU's `K Rᵀ`.
    fn of(&self, d: usize, place: &SuPlace, kr: &Matrix3<f64>) -> Option<Vector3<f64>> {
        let rate = self.0[d][place.segment]?;
        let p = place.placement.translation.vector;
        Some(kr * (rate.c - rate.rt * place.gravity + rate.n * p))
    }
}

/// Per segment `(c₀, Rᵀ, N)`.
fn fields(block: &BlockKinematics) -> Vec<(Vector3<f64>, Matrix3<f64>, Matrix3<f64>)> {
    block
        .segments
        .iter()
        .zip(&block.motion)
        .map(|(frame, motion)| {
            let rt = frame.rotation.to_rotation_matrix().into_inner().transpose();
            let m = motion.point_matrix();
            let c = rt * (motion.accel + m * frame.translation.vector);
            (c, rt, rt * m * rt.transpose())
        })
        .collect()
}

/// One SU's sums for one DoF of its chain: `Σ jᵀWj`, `Σ jᵀWr`, and `Σ JᵀWj` with its own change.
#[derive(Debug, Clone, Default)]
pub struct ZeroSums {
    /// The DoF.
    pub dof: usize,
    information: f64,
    gradient: f64,
    cross: Change,
}

/// Adds one block of SU `place` (residual `r`, Jacobian `jac`, weight `w`) to its sums for every
/// DoF of `chain`.
pub fn add(
    sums: &mut Vec<ZeroSums>,
    rates: &Rates,
    chain: &[usize],
    place: &SuPlace,
    r: &Vector3<f64>,
    jac: &Jacobian,
    w: f64,
) {
    if sums.is_empty() {
        sums.extend(chain.iter().map(|&dof| ZeroSums {
            dof,
            ..ZeroSums::default()
        }));
    }
    let turn = place.placement.rotation.to_rotation_matrix().into_inner();
    let kr = place.intrinsics.matrix() * turn.transpose();
    for s in sums.iter_mut() {
        if let Some(j) = rates.of(s.dof, place, &kr) {
            s.information += j.norm_squared() * w;
            s.gradient += j.dot(r) * w;
            s.cross += jac.transpose() * j * w;
        }
    }
}

/// A DoF whose zero moved.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct ZeroChange {
    /// The DoF.
    pub dof: String,
    /// How far it now stands from what its encoder says (add it to the reading), rad.
    pub offset: f64,
    /// Its standard deviation from the log, rad.
    pub offset_sd: f64,
    /// The SUs it moves, whose readings told it.
    pub sus: Vec<String>,
}

/// The DoF (at most one) whose zero moved, judged from the sums of the SUs `usable`, and its
/// angle; `tallies` are then corrected for it.
pub fn moved_zero(
    robot: &Robot,
    tallies: &mut [Tally],
    zero: &[Vec<ZeroSums>],
    usable: &[bool],
    alpha: f64,
) -> Option<ZeroChange> {
    let n = robot.model.dofs().len();
    let best = (0..n)
        .filter_map(|d| judge(tallies, zero, usable, d, alpha / n as f64))
        .max_by(|a, b| a.1.total_cmp(&b.1))?;
    let (d, _, offset, sd) = best;
    let mut sus = Vec::new();
    let names = robot.model.su_names();
    for (u, sums) in zero.iter().enumerate() {
        let Some(s) = sums.iter().find(|s| s.dof == d).filter(|_| usable[u]) else {
            continue;
        };
        let t = &mut tallies[u];
        t.chi2 += -2.0 * offset * s.gradient + offset * offset * s.information;
        t.gradient -= s.cross * offset;
        sus.push(names[u].clone());
    }
    Some(ZeroChange {
        dof: robot.model.dofs()[d].name.clone(),
        offset,
        offset_sd: sd,
        sus,
    })
}

/// DoF `d`: `(d, χ² it explains, angle, its deviation)` when its angle is significant at `alpha`
/// and explains its SUs' readings about as well as their own changes do.
fn judge(
    tallies: &[Tally],
    zero: &[Vec<ZeroSums>],
    usable: &[bool],
    d: usize,
    alpha: f64,
) -> Option<(usize, f64, f64, f64)> {
    let (mut a, mut g, mut own, mut count, mut blocks) = (0.0, 0.0, 0.0, 0usize, 0usize);
    for (u, sums) in zero.iter().enumerate() {
        let Some(s) = sums.iter().find(|s| s.dof == d).filter(|_| usable[u]) else {
            continue;
        };
        a += s.information;
        g += s.gradient;
        let t = &tallies[u];
        own += t.gradient.dot(&t.best_change());
        count += 1;
        blocks += t.blocks;
    }
    // One SU alone cannot tell its own turn about the DoF's axis from the DoF's zero.
    if count < 2 || a <= 0.0 {
        return None;
    }
    let (offset, explained) = (g / a, g * g / a);
    let variance = 1.0 / a + ZERO_FLOOR * ZERO_FLOOR;
    if test::survival(offset * offset / variance, 1) >= alpha {
        return None;
    }
    // One angle against nine numbers per SU: the information criterion's price of the others.
    let price = (9 * count - 1) as f64 * ((3 * blocks.max(1)) as f64).ln() / 2.0;
    (own - explained < price).then_some((d, explained, offset, variance.sqrt()))
}
