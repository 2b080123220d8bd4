//! A DoF whose zero moved (an encoder homed anew after a hard reset): every SU beyond it reads as
//! if the DoF stood a little further. Per block, how each segment's specific-force field changes
//! with each DoF's angle, to second order (central differences of the kinematics); per SU and DoF
//! of its chain, the sums of that angle's quadratic model of the readings with the SU's own
//! change; a DoF is taken to have moved when its one angle explains about as much of its SUs'
//! readings as their twelve changes each would (the Bayesian information criterion), and its angle
//! is then taken out of their sums.
//!
//! The second order matters: a 2° zero moves a reading by about `0.035 g`, and the first-order
//! model misses the square of that angle's share — on two head SUs, a few hundred of a χ² of
//! 10⁶, more than the criterion's price of their two dozen numbers.

use std::ops::AddAssign;

use nalgebra::{Matrix3, Matrix3x2, Vector3};
use serde::{Deserialize, Serialize};

use super::kin::{BlockKinematics, Field, Jacobian, SuPlace, CHANGE};
use super::test::{self, Change, Tally};
use crate::model::Robot;

/// The step of the central differences, rad (their truncation error `STEP²/6` of the third
/// derivative, their rounding `ε/STEP²` of the field: both below 1e-7 of a reading).
const STEP: f64 = 1e-4;
/// The model's own error of a DoF's zero that is never taken for a change, rad.
pub const ZERO_FLOOR: f64 = 0.2 * std::f64::consts::PI / 180.0;

/// How one segment's field changes with one DoF's angle: a point `p` of the segment reads, in the
/// segment's axes, `c₀ − Rᵀ g + N p`; these are the first and second derivatives of `(c₀, Rᵀ, N)`.
#[derive(Debug, Clone, Copy)]
struct FieldRate {
    first: Field,
    second: Field,
}

/// Per DoF, per segment beyond it: the rate of its field (`None` for segments it does not move).
pub struct Rates(Vec<Vec<Option<FieldRate>>>);

impl Rates {
    /// The rates at `q` with velocities `qd` and accelerations `qdd` (model order); `block` is the
    /// kinematics there.
    pub fn new(robot: &Robot, block: &BlockKinematics, q: &[f64], qd: &[f64], qdd: &[f64]) -> Self {
        let m = &robot.model;
        let here = &block.fields;
        let at = |d: usize, step: f64| {
            let mut moved = q.to_vec();
            moved[d] += step;
            BlockKinematics::new(robot, &moved, qd, qdd).fields
        };
        let rates = (0..m.dofs().len())
            .map(|d| {
                let (ahead, behind) = (at(d, STEP), at(d, -STEP));
                (0..m.segments().len())
                    .map(|s| {
                        let (a, h, b) = (&ahead[s], &here[s], &behind[s]);
                        let first = |x: f64| x / (2.0 * STEP);
                        let second = |x: f64| x / (STEP * STEP);
                        m.moves_segment(d, s).then(|| FieldRate {
                            first: (
                                (a.0 - b.0).map(first),
                                (a.1 - b.1).map(first),
                                (a.2 - b.2).map(first),
                            ),
                            second: (
                                (a.0 - 2.0 * h.0 + b.0).map(second),
                                (a.1 - 2.0 * h.1 + b.1).map(second),
                                (a.2 - 2.0 * h.2 + b.2).map(second),
                            ),
                        })
                    })
                    .collect()
            })
            .collect();
        Self(rates)
    }

    /// The first derivative of SU `place`'s reading with DoF `d`'s angle (zero where `d` does
    /// not move it).
    pub fn first(&self, d: usize, place: &SuPlace) -> Vector3<f64> {
        self.of(d, place, &place.sensor().kt)
            .map_or(Vector3::zeros(), |jk| jk.column(0).into_owned())
    }

    /// The first and second derivatives of SU `place`'s reading with DoF `d`'s angle, side by
    /// side; `kt` is the SU's `K Tᵀ`.
    fn of(&self, d: usize, place: &SuPlace, kt: &Matrix3<f64>) -> Option<Matrix3x2<f64>> {
        let rate = self.0[d][place.segment].as_ref()?;
        let p = &place.placement.translation.vector;
        let reading = |f: &Field| kt * (f.0 - f.1 * place.gravity + f.2 * p);
        Some(Matrix3x2::from_columns(&[
            reading(&rate.first),
            reading(&rate.second),
        ]))
    }
}

/// One SU's sums for one DoF of its chain, whose angle `δ` moves the reading by `jδ + ½kδ²`:
/// the weighted products of `j`, `k`, the residual `r` and the SU's own change Jacobian `J`.
#[derive(Debug, Clone, Default)]
pub struct ZeroSums {
    /// The DoF.
    pub dof: usize,
    /// `Σ jᵀWj`.
    information: f64,
    /// `Σ jᵀWr`.
    gradient: f64,
    /// `Σ JᵀWj`.
    cross: Change,
    /// `Σ kᵀWk`, `Σ jᵀWk`, `Σ kᵀWr`.
    curvature: [f64; 3],
    /// `Σ JᵀWk`.
    cross_curvature: Change,
}

impl ZeroSums {
    /// How much less the χ² of these sums is after an angle `delta`: `‖r‖² − ‖r − jδ − ½kδ²‖²`.
    fn explained(&self, delta: f64) -> f64 {
        let [kk, jk, kr] = self.curvature;
        let d2 = delta * delta;
        2.0 * delta * self.gradient + d2 * kr
            - d2 * self.information
            - d2 * delta * jk
            - 0.25 * d2 * d2 * kk
    }

    /// How the own change's gradient `Σ JᵀWr` falls after an angle `delta`.
    fn gradient_taken(&self, delta: f64) -> Change {
        self.cross * delta + self.cross_curvature * (0.5 * delta * delta)
    }
}

/// Adds one block of SU `place` (its `K Tᵀ` `kt`, residual `r`, Jacobian `jac` of
/// [`super::kin::reading`], whose bias block is the identity and sensitivity block diagonal,
/// weight `w`) to its sums for every
/// DoF of `chain`.
#[allow(clippy::too_many_arguments)]
pub fn add(
    sums: &mut Vec<ZeroSums>,
    rates: &Rates,
    chain: &[usize],
    place: &SuPlace,
    kt: &Matrix3<f64>,
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
    for s in sums.iter_mut() {
        if let Some(jk) = rates.of(s.dof, place, kt) {
            let (j, k) = (jk.column(0), jk.column(1));
            // `Jᵀ W [j k]`: the bias block of `J` is the identity, the sensitivity block diagonal.
            let jkw = jk * w;
            let pose = jac.fixed_columns::<6>(0).tr_mul(&jkw);
            let sensed = jac.fixed_view::<3, 3>(0, 9).diagonal();
            s.information += j.dot(&jkw.column(0));
            s.gradient += r.dot(&jkw.column(0));
            s.curvature[0] += k.dot(&jkw.column(1));
            s.curvature[1] += j.dot(&jkw.column(1));
            s.curvature[2] += r.dot(&jkw.column(1));
            for (sum, c) in [(&mut s.cross, 0), (&mut s.cross_curvature, 1)] {
                sum.fixed_rows_mut::<6>(0).add_assign(&pose.column(c));
                sum.fixed_rows_mut::<3>(6).add_assign(&jkw.column(c));
                sum.fixed_rows_mut::<3>(9)
                    .add_assign(&sensed.component_mul(&jkw.column(c)));
            }
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
        // One SU alone cannot tell its own turn about the DoF's axis from the DoF's zero.
        .filter_map(|d| judge(tallies, zero, usable, d, alpha / n as f64, 2))
        .max_by(|a, b| a.1.total_cmp(&b.1))?;
    let (d, _, offset, sd) = best;
    let mut sus = Vec::new();
    let names = robot.model.su_names();
    for (u, sums) in zero.iter().enumerate() {
        let Some(s) = sums.iter().find(|s| s.dof == d).filter(|_| usable[u]) else {
            continue;
        };
        take_out(&mut tallies[u], s, offset);
        sus.push(names[u].clone());
    }
    Some(ZeroChange {
        dof: robot.model.dofs()[d].name.clone(),
        offset,
        offset_sd: sd,
        sus,
    })
}

/// Takes a zero's angle `offset` out of an SU's `tally` through its sums `s` for that DoF.
pub fn take_out(tally: &mut Tally, s: &ZeroSums, offset: f64) {
    tally.chi2 -= s.explained(offset);
    tally.gradient -= s.gradient_taken(offset);
}

/// SU `u`'s sums for DoF `dof`.
pub fn sums_of<'a>(
    zero: &'a [Vec<ZeroSums>],
    u: usize,
    dof: &str,
    robot: &Robot,
) -> Option<&'a ZeroSums> {
    let d = robot.model.dofs().iter().position(|x| x.name == dof)?;
    zero[u].iter().find(|s| s.dof == d)
}

/// The zero that reads exactly as SU `u`'s move: a DoF that moves no other SU the log saw, whose
/// angle (significant at `alpha`) explains the SU's readings about as well as its own change.
/// One SU alone cannot tell them apart (on the last segment, its turn about the DoF's axis is
/// the zero).
pub fn alike(
    robot: &Robot,
    tallies: &[Tally],
    zero: &[Vec<ZeroSums>],
    u: usize,
    alpha: f64,
) -> Option<ZeroChange> {
    let n = robot.model.dofs().len();
    let alone = |d: usize| {
        zero.iter()
            .enumerate()
            .all(|(v, sums)| v == u || tallies[v].blocks == 0 || sums.iter().all(|s| s.dof != d))
    };
    let only: Vec<bool> = (0..zero.len()).map(|v| v == u).collect();
    let (d, _, offset, sd) = zero[u]
        .iter()
        .filter(|s| alone(s.dof))
        .filter_map(|s| judge(tallies, zero, &only, s.dof, alpha / n as f64, 1))
        .max_by(|a, b| a.1.total_cmp(&b.1))?;
    Some(ZeroChange {
        dof: robot.model.dofs()[d].name.clone(),
        offset,
        offset_sd: sd,
        sus: vec![robot.model.su_names()[u].clone()],
    })
}

/// Per DoF, the information on its zero `Σ jᵀWj` of the SUs `usable`, rad⁻².
pub fn information(zero: &[Vec<ZeroSums>], usable: &[bool], dofs: usize) -> Vec<f64> {
    let mut info = vec![0.0; dofs];
    for sums in zero.iter().zip(usable).filter(|(_, &u)| u).map(|(s, _)| s) {
        for s in sums {
            info[s.dof] += s.information;
        }
    }
    info
}

/// DoF `d`: `(d, χ² it explains, angle, its deviation)` when at least `least` SUs tell it, its
/// angle is significant at `alpha` and explains its SUs' readings about as well as their own
/// changes do.
fn judge(
    tallies: &[Tally],
    zero: &[Vec<ZeroSums>],
    usable: &[bool],
    d: usize,
    alpha: f64,
    least: usize,
) -> Option<(usize, f64, f64, f64)> {
    let told: Vec<(&ZeroSums, &Tally)> = zero
        .iter()
        .enumerate()
        .filter(|(u, _)| usable[*u])
        .filter_map(|(u, sums)| Some((sums.iter().find(|s| s.dof == d)?, &tallies[u])))
        .collect();
    let mut total = ZeroSums::default();
    for (s, _) in &told {
        total.information += s.information;
        total.gradient += s.gradient;
        for k in 0..3 {
            total.curvature[k] += s.curvature[k];
        }
    }
    let (a, count) = (total.information, told.len());
    if count < least || a <= 0.0 {
        return None;
    }
    let offset = best_angle(&total);
    let explained = total.explained(offset);
    // What the SUs' own changes explain beyond the angle.
    let rest: f64 = told
        .iter()
        .map(|(s, t)| {
            let mut left = (*t).clone();
            left.gradient -= s.gradient_taken(offset);
            left.gradient.dot(&left.best_change())
        })
        .sum();
    let blocks: usize = told.iter().map(|(_, t)| t.blocks).sum();
    let variance = 1.0 / a + ZERO_FLOOR * ZERO_FLOOR;
    if test::survival(offset * offset / variance, 1) >= alpha {
        return None;
    }
    // One angle against the change's numbers per SU: the information criterion's price of the
    // others.
    let price = (CHANGE * count - 1) as f64 * ((3 * blocks.max(1)) as f64).ln() / 2.0;
    (rest < price).then_some((d, explained, offset, variance.sqrt()))
}

/// The angle that explains most of `sums` (the quadratic model's χ² is a quartic in it): Newton
/// steps from the first-order angle, kept while they explain more.
fn best_angle(sums: &ZeroSums) -> f64 {
    let [kk, jk, kr] = sums.curvature;
    let mut delta = sums.gradient / sums.information;
    for _ in 0..8 {
        // The first and second derivatives of `explained` at `delta`.
        let d2 = delta * delta;
        let slope = 2.0 * sums.gradient + 2.0 * delta * (kr - sums.information)
            - 3.0 * d2 * jk
            - d2 * delta * kk;
        let bend = 2.0 * (kr - sums.information) - 6.0 * delta * jk - 3.0 * d2 * kk;
        if bend >= 0.0 {
            break;
        }
        let next = delta - slope / bend;
        if sums.explained(next) <= sums.explained(delta) {
            break;
        }
        delta = next;
    }
    delta
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Readings that an angle `δ` moves by exactly `jδ + ½kδ²`: the quadratic model finds `δ`
    /// and explains all but the third order of their χ², where the first-order angle leaves `δ²/2`
    /// of each reading's change.
    #[test]
    fn the_quadratic_model_finds_a_large_angle_and_explains_all_it_moved() {
        let delta = 4f64.to_radians();
        let mut sums = ZeroSums::default();
        let mut chi2 = 0.0;
        for i in 0..50 {
            let t = i as f64 * 0.37;
            // A rotation about z of a unit vector tilted off the axis: j and k its derivatives.
            let v = |a: f64| Vector3::new((t + a).cos(), (t + a).sin(), 0.3) * 9.81;
            let j = Vector3::new(-t.sin(), t.cos(), 0.0) * 9.81;
            let k = Vector3::new(-t.cos(), -t.sin(), 0.0) * 9.81;
            // The exact change, not its expansion: what is left is the third order.
            let r = v(delta) - v(0.0);
            sums.information += j.norm_squared();
            sums.gradient += j.dot(&r);
            sums.curvature[0] += k.norm_squared();
            sums.curvature[1] += j.dot(&k);
            sums.curvature[2] += k.dot(&r);
            chi2 += r.norm_squared();
        }
        let first = sums.gradient / sums.information;
        let found = best_angle(&sums);
        // The reading moved by `sin δ` along j and `1 − cos δ` along k: both models find the
        // angle to within the third order `δ³/6`, but only the quadratic one explains the `δ²/2`.
        assert!(
            (found - delta).abs() < 1.1 * delta.powi(3) / 6.0,
            "{found} vs {delta}"
        );
        let left = chi2 - sums.explained(found);
        let left_first = chi2 - (sums.gradient * first);
        assert!(left < 1e-5 * chi2, "left {left} of {chi2}");
        assert!(
            left_first > 1e-3 * chi2,
            "first order left {left_first} of {chi2}"
        );
    }
}
