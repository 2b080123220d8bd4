//! What the structure part's moves accelerated, read from the motion record. A DoF whose move
//! turns no gravity — a prismatic one, a revolute one whose axis stands vertical (a humanoid's
//! hip and waist yaw, an arm's first joint), or a leader whose mimic follower carries a body
//! without turning it (a parallel gripper's fingertip) — changes no static reading, so the
//! structure experiment's holds cannot tell which SUs it moves. Its move does accelerate them:
//! regressed on the DoF's acceleration over the move, an SU it carries reads the axis (a unit
//! vector per m/s² of a prismatic DoF) or the tangent times its lever arm (per rad/s² of a
//! revolute one), any other nothing. Where the training experiment excites the DoF its dynamic
//! readings tell the same; a continuous program has none. With these, no structure part needs
//! to be recorded again with the base tilted.
//!
//! The same regressions tell a slide from a turn where no description says which a DoF is
//! ([`kinds_of_moves`]): a turn turns gravity, spins its SUs outwards (a centripetal term as
//! large as the tangential one) and reads its lever arm; a slide does neither and reads its
//! axis, a unit vector, on every SU it carries.

use nalgebra::{DMatrix, DVector, Vector3};
use serde::{Deserialize, Serialize};

use crate::measurements::{MeasurementSet, Reading};
use crate::model::DofKind;
use crate::motion::{MotionRecord, MotionRun, SAME_POSE};

/// A DoF moves in a block when its speed exceeds this, rad/s (m/s); every other DoF is still in
/// a move when it stays below it.
const MOVING: f64 = 0.01;
/// How far another DoF may be from the move's pose during a move, rad (m): a servo deflected by
/// the move's reaction, or ringing as it stops. Its motion joins the move's regression.
const DEFLECTED: f64 = 0.02;
/// Blocks of stillness on each side of a move that join its regression (they carry the hold's
/// reading, which the regression's intercept takes).
const MARGIN: usize = 10;
/// The most blocks a DoF may stay below [`MOVING`] within one move: a servo that overshoots and
/// rings reverses at each swing (at 4 Hz and damping 0.6, a few blocks at each). Cut there, a
/// move would end at its first overshoot, away from its pose, and not be taken; a late swing
/// ending at the pose would stand for it and tell a wrist's gains only to within centimetres.
const RINGING: usize = 10;
/// The least `Σ(q̈ − mean)²` over a move's blocks for its regression to tell anything, (m/s²)²
/// or (rad/s²)²: a 4 cm finger move in 0.3 s gives about 60, a mobile manipulator's 3 cm lift
/// of its whole upper body on servos of 6 Hz 0.45 (and its SUs read 1.00 ± 0.05 per m/s²). Below
/// it the regressors are all but degenerate; above, the gain's deviation says how well it was
/// read.
const LEAST_EXCITATION: f64 = 0.1;
/// How many standard deviations make a term of the one-DoF model read: an SU carried, gravity
/// turned, a centripetal term, a gain other than a slide's.
const TOLD: f64 = 5.0;
/// The least gravity a turn's move turns on an SU for it to count: m/s² per unit of `sin Δθ` in
/// the regression, m/s² between the static readings at rest and after the move (a slide turns
/// none; a move of 0.3 rad about an axis within 10° of vertical turns less).
const TURNED: f64 = 0.5;
/// How many times more SUs must read a slide's gain than a turn's signs for a DoF to be told a
/// slide. Every SU a turn about a tilted axis carries turns gravity, and most it carries read a
/// lever arm other than 1 m; a slide's SUs may show a sign of a turn now and then: a lift that
/// carries an arm bounces as the arm's servos ring, and a hold read in the bounce (before the
/// lift is known as a slide, whose pauses are judged at a tenth of a turn's speed) turns gravity
/// on an SU or two of the thirty it carries, and a head on soft servos that nods with the lift's
/// acceleration reads 1.3 per m/s² (TIAGo with one SU per link on servos of 4 Hz: 14 slides, 3
/// such gains and one turn).
const SLIDE_MAJORITY: usize = 3;
/// How far from a slide's 1 per m/s² an SU's gain may read and still be a slide's.
const UNIT_GAIN: f64 = 0.2;

/// What a DoF's structure moves told of its kind, where no description said
/// ([`kinds_of_moves`]).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct KindTold {
    /// The DoF's name.
    pub dof: String,
    /// `None` where its moves told neither (no gravity turned, and no move in the motion record
    /// or no SU it carries read well enough): it is taken as revolute.
    pub kind: Option<DofKind>,
    /// What told it, in words.
    pub evidence: String,
}

/// Fills [`crate::measurements::Move::accelerated`] of `set`'s structure moves (of every DoF but
/// mimic followers, which move with their leaders) from `record` (ingested from the same logs):
/// for each move in the base orientation the record stood in ([`MotionRecord::same_base`] at
/// the rest pose), the record's stretches in which that DoF alone moved (its followers with it)
/// and which end at the move's pose. Moves the record does not hold stay empty.
pub fn accelerations_of_moves(set: &mut MeasurementSet, record: &MotionRecord) {
    let su_column = su_columns(set, record);
    // Per move held: its orientation, its index there, and each SU's gain with its deviation.
    type Gains = Vec<Option<(Reading, f64)>>;
    let gains: Vec<(usize, usize, Gains)> = held_moves(set, record)
        .iter()
        .map(|held| {
            let revolute = set.dof_kind(held.dof) == DofKind::Revolute;
            let gains = su_column
                .iter()
                .map(|u| {
                    let fit = u.and_then(|u| regress(held, u, revolute))?;
                    fit.gain()
                })
                .collect();
            (held.orientation, held.index, gains)
        })
        .collect();
    let Some(structure) = set.structure.as_mut() else {
        return;
    };
    for (o, j, gains) in gains {
        if gains.iter().any(Option::is_some) {
            let mv = &mut structure.orientations[o].moves[j];
            // An SU that sent too little in the move reads nothing, to within an unknown error.
            (mv.accelerated, mv.accelerated_sd) = gains
                .into_iter()
                .map(|g| g.map_or(([0.0; 3], None), |(k, sd)| (k, Some(sd))))
                .unzip();
        }
    }
}

/// Whether each DoF of `set` (but mimic followers) slides or turns, told from its structure
/// moves where no description says. A slide turns no gravity; a turn that is not about a vertical
/// axis does, so any move whose static readings differ from the rest's by more than
/// [`TURNED`] on some SU makes its DoF revolute (in any base orientation, with or without a
/// motion record). In `record`, every SU is regressed on the revolute model over each move
/// (which holds the slide's as a special case) and each SU a move carries votes: a turn turns
/// gravity on it, or reads a gain other than a slide's 1 per m/s² (its lever arm, m), or a
/// centripetal term as large as that gain; a slide reads 1 per m/s² with neither. One vote for a
/// turn makes the DoF revolute (a slide's reading can be a turn's with a lever arm of 1 m); one
/// for a slide and none for a turn, prismatic.
pub fn kinds_of_moves(set: &MeasurementSet, record: Option<&MotionRecord>) -> Vec<KindTold> {
    let held = record.map_or_else(Vec::new, |record| held_moves(set, record));
    let su_column = record.map_or_else(Vec::new, |record| su_columns(set, record));
    (0..set.dofs.len())
        .filter(|&d| !set.is_follower(d))
        .map(|dof| {
            let mut votes = Votes {
                turned: static_turns(set, dof),
                ..Votes::default()
            };
            let moves: Vec<&Held<'_>> = held.iter().filter(|h| h.dof == dof).collect();
            for held in &moves {
                for u in su_column.iter().flatten() {
                    if let Some(fit) = regress(held, *u, true) {
                        votes.add(&fit);
                    }
                }
            }
            votes.told(&set.dofs[dof], moves.len())
        })
        .collect()
}

/// How many SUs a structure move of DoF `dof` (alone, its followers with it) turned gravity
/// on: its static reading at the move's pose differs from the rest's by more than [`TURNED`]
/// (most over its moves).
fn static_turns(set: &MeasurementSet, dof: usize) -> usize {
    let Some(structure) = set.structure.as_ref() else {
        return 0;
    };
    let followers = set.followers_of(dof);
    structure
        .orientations
        .iter()
        .flat_map(|o| o.moves.iter().map(move |mv| (o, mv)))
        .filter(|(o, mv)| {
            mv.dof == set.dofs[dof]
                && mv.pose.len() == o.rest_pose.len()
                && mv
                    .pose
                    .iter()
                    .zip(&o.rest_pose)
                    .enumerate()
                    .all(|(e, (p, r))| {
                        e == dof || followers.contains(&e) || (p - r).abs() <= SAME_POSE
                    })
        })
        .map(|(o, mv)| {
            mv.readings
                .iter()
                .zip(&o.rest)
                .filter(|(m, r)| {
                    let change: f64 = (0..3).map(|a| (m[a] - r[a]).powi(2)).sum();
                    change.sqrt() > TURNED
                })
                .count()
        })
        .max()
        .unwrap_or(0)
}

/// Each of `set`'s SUs' column in `record`.
fn su_columns(set: &MeasurementSet, record: &MotionRecord) -> Vec<Option<usize>> {
    set.sus
        .iter()
        .map(|su| record.sus.iter().position(|s| s == su))
        .collect()
}

/// A structure move the motion record holds.
struct Held<'a> {
    /// Its place in the set: orientation, move.
    orientation: usize,
    index: usize,
    /// Its DoF in the set.
    dof: usize,
    /// Its DoF's column in the record.
    column: usize,
    /// Where it moved ([`moves_into`]).
    stretches: Vec<Stretch<'a>>,
    /// Its DoF's position at the move's pose.
    pose: f64,
    /// The other DoFs (record columns) that moved a little in its stretches — servos deflected
    /// by the move and ringing as it stops: their accelerations join the regression, so what
    /// they add is not read as the move's.
    others: Vec<usize>,
}

/// `set`'s structure moves (of every DoF but mimic followers) that `record` holds: in the base
/// orientation the record stood in ([`MotionRecord::same_base`] at the rest pose), the
/// record's stretches in which that DoF alone moved (its followers with it) and which end at
/// the move's pose.
fn held_moves<'a>(set: &MeasurementSet, record: &'a MotionRecord) -> Vec<Held<'a>> {
    let column = |name: &str| record.dofs.iter().position(|d| d == name);
    // Each record column's place in the set's poses.
    let in_set: Option<Vec<usize>> = record.dofs.iter().map(|d| set.dof_index(d)).collect();
    let (Some(in_set), Some(structure)) = (in_set, set.structure.as_ref()) else {
        return Vec::new();
    };
    let mut held = Vec::new();
    for (o, orientation) in structure.orientations.iter().enumerate() {
        if record.same_base(&orientation.rest_pose, &orientation.rest) != Some(true) {
            continue;
        }
        for (index, mv) in orientation.moves.iter().enumerate() {
            let Some(dof) = set.dof_index(&mv.dof).filter(|&d| !set.is_follower(d)) else {
                continue;
            };
            let Some(leader) = column(&set.dofs[dof]) else {
                continue;
            };
            let mut moving = vec![leader];
            moving.extend(
                set.followers_of(dof)
                    .into_iter()
                    .filter_map(|f| column(&set.dofs[f])),
            );
            let pose: Vec<f64> = in_set.iter().map(|&i| mv.pose[i]).collect();
            let stretches = moves_into(record, &moving, &pose);
            if !stretches.is_empty() {
                let others = (0..record.dofs.len())
                    .filter(|e| !moving.contains(e))
                    .filter(|&e| {
                        stretches.iter().any(|&(run, start, end)| {
                            (start..end).any(|b| run.qd[b][e].abs() > MOVING)
                        })
                    })
                    .collect();
                held.push(Held {
                    orientation: o,
                    index,
                    dof,
                    column: leader,
                    stretches,
                    pose: pose[leader],
                    others,
                });
            }
        }
    }
    held
}

/// A stretch of a run: `(run, first block, end block)`.
type Stretch<'a> = (&'a MotionRun, usize, usize);

/// The record's stretches `(run, first block, end block)` in which `moving[0]` moved with every
/// DoF but `moving` (its followers) within [`DEFLECTED`] of `pose` (still, or deflected by the
/// move), widened by up to [`MARGIN`] still blocks on each side, and whose last block holds
/// `pose`.
fn moves_into<'a>(record: &'a MotionRecord, moving: &[usize], pose: &[f64]) -> Vec<Stretch<'a>> {
    record
        .runs
        .iter()
        .flat_map(|run| {
            let moves = |b: usize| run.qd[b][moving[0]].abs() > MOVING;
            let others_still = |b: usize| {
                run.q[b]
                    .iter()
                    .zip(pose)
                    .enumerate()
                    .all(|(e, (q, p))| moving.contains(&e) || (q - p).abs() <= DEFLECTED)
            };
            let mut stretches = Vec::new();
            let mut b = 0;
            while b < run.len() {
                if !moves(b) {
                    b += 1;
                    continue;
                }
                let first = b;
                // Through every reversal of a servo that overshoots and rings: its speed drops
                // below `MOVING` for a few blocks at each, and the move ends where it settles.
                loop {
                    while b < run.len() && moves(b) {
                        b += 1;
                    }
                    match (b..run.len().min(b + RINGING)).find(|&c| moves(c)) {
                        Some(c) => b = c,
                        None => break,
                    }
                }
                let (mut start, mut end) = (first, b);
                while start > 0 && first - start < MARGIN && !moves(start - 1) {
                    start -= 1;
                }
                while end < run.len() && end - b < MARGIN && !moves(end) {
                    end += 1;
                }
                let held = run.q[end - 1]
                    .iter()
                    .zip(pose)
                    .all(|(q, p)| (q - p).abs() <= SAME_POSE);
                if held && (start..end).all(others_still) {
                    stretches.push((run, start, end));
                }
            }
            stretches
        })
        .collect()
}

/// One SU's readings over a move regressed on the exact model of one DoF moving with everything
/// upstream still,
///
/// ```text
/// s = c + k q̈                                        (prismatic: gravity does not turn)
/// s = c + G_c (cos Δθ − 1) + G_s sin Δθ + k q̈ + k_ω q̇²   (revolute: Δθ from the move's pose)
/// ```
///
/// whose coefficients are constant in the SU frame (the axis is fixed in the moving segment), so
/// the gravity the move turns does not leak into `k`: `k` is the axis for a prismatic DoF that
/// carries the SU (a unit vector), the tangent times the lever arm for a revolute one (its norm in
/// m), zero for an SU the DoF does not move; `k_ω` is minus the radial direction times the lever
/// arm, as long as `k`.
struct OneDof {
    /// Per regressor (rows: `c`, then `G_c`, `G_s` for a turn, `k`, then `k_ω`; then each
    /// deflected DoF's acceleration), per axis.
    coefficients: DMatrix<f64>,
    /// The inverse of the regressors' Gram matrix.
    inverse: DMatrix<f64>,
    /// The residual's variance per axis, (m/s²)².
    variance: f64,
    revolute: bool,
}

impl OneDof {
    /// The revolute model's rows of `G_s`, `k` and `k_ω` (the slide's has `c` and `k` alone).
    const TURNED: usize = 2;
    const GAIN: usize = 3;
    const SPIN: usize = 4;

    /// The row of `k`.
    fn k_row(&self) -> usize {
        if self.revolute {
            Self::GAIN
        } else {
            1
        }
    }

    /// Regressor `row`'s coefficient and its standard deviation per axis.
    fn term(&self, row: usize) -> (Vector3<f64>, f64) {
        (
            Vector3::from_fn(|a, _| self.coefficients[(row, a)]),
            (self.variance * self.inverse[(row, row)]).max(0.0).sqrt(),
        )
    }

    /// `k`, the SU's reading per unit of the DoF's acceleration, and the standard deviation of
    /// each of its components; `None` where the move did not excite `q̈` apart from the other
    /// regressors enough to tell ([`LEAST_EXCITATION`]).
    fn gain(&self) -> Option<(Reading, f64)> {
        let k = self.k_row();
        // `1 / (G⁻¹)ₖₖ` is what of `Σ q̈²` the other regressors leave to tell `k`.
        if self.inverse[(k, k)] <= 0.0 || 1.0 / self.inverse[(k, k)] < LEAST_EXCITATION {
            return None;
        }
        let (gain, sd) = self.term(k);
        Some((gain.into(), sd))
    }
}

/// SU `u`'s readings over `held`'s stretches regressed on the one-DoF model ([`OneDof`]);
/// `None` where the SU sent too little in them or the regressors are degenerate.
fn regress(held: &Held<'_>, u: usize, revolute: bool) -> Option<OneDof> {
    let d = held.column;
    let regressors = |run: &MotionRun, b: usize| -> Vec<f64> {
        let a = run.qdd[b][d];
        let mut x = if revolute {
            let turned = run.q[b][d] - held.pose;
            vec![
                1.0,
                turned.cos() - 1.0,
                turned.sin(),
                a,
                run.qd[b][d].powi(2),
            ]
        } else {
            vec![1.0, a]
        };
        // A deflected DoF's small motion, by its acceleration: its turn follows the move's
        // acceleration (the servo yields to the reaction), and, a regressor of its own, would
        // take the move's share; the gravity it turns is 0.01 rad of it at most.
        for &e in &held.others {
            x.push(run.qdd[b][e]);
        }
        x
    };
    let n = if revolute { 5 } else { 2 } + held.others.len();
    let mut gram = DMatrix::<f64>::zeros(n, n);
    let mut moment = DMatrix::<f64>::zeros(n, 3);
    let mut squares = 0.0;
    let mut samples = 0;
    for &(run, start, end) in &held.stretches {
        for b in start..end {
            let Some(y) = run.skin.get(b, u) else {
                continue;
            };
            let x = DVector::from_vec(regressors(run, b));
            gram += &x * x.transpose();
            for (c, v) in y.iter().enumerate() {
                moment.column_mut(c).axpy(*v, &x, 1.0);
                squares += v * v;
            }
            samples += 1;
        }
    }
    if samples <= n + 1 {
        return None;
    }
    let inverse = gram.try_inverse()?;
    let coefficients = &inverse * &moment;
    let explained: f64 = (0..3)
        .map(|c| coefficients.column(c).dot(&moment.column(c)))
        .sum();
    Some(OneDof {
        coefficients,
        inverse,
        variance: (squares - explained).max(0.0) / (3 * (samples - n)) as f64,
        revolute,
    })
}

/// The votes of a DoF's carried SUs on its kind ([`kinds_of_moves`]).
#[derive(Default)]
struct Votes {
    /// SUs on which its moves turned gravity.
    turned: usize,
    /// Gains of SUs that read other than a slide's, m (lever arms).
    levers: Vec<f64>,
    /// SUs with a centripetal term.
    spun: usize,
    /// Gains of SUs that read a slide's.
    slides: Vec<f64>,
}

impl Votes {
    /// `fit`'s vote, if its SU is carried (its gain told apart from nothing).
    fn add(&mut self, fit: &OneDof) {
        if !fit.revolute || fit.gain().is_none() {
            return;
        }
        let (k, sd_k) = fit.term(OneDof::GAIN);
        let gain = k.norm();
        if gain <= TOLD * sd_k {
            return;
        }
        let (turned, sd_turned) = fit.term(OneDof::TURNED);
        let (spin, sd_spin) = fit.term(OneDof::SPIN);
        let is_turned = turned.norm() > TURNED && turned.norm() > TOLD * sd_turned;
        let off_unit = (gain - 1.0).abs();
        let is_lever = off_unit > UNIT_GAIN && off_unit > TOLD * sd_k;
        let is_spun = spin.norm() > 0.5 * gain && spin.norm() > TOLD * sd_spin;
        self.turned += usize::from(is_turned);
        self.spun += usize::from(is_spun);
        if is_lever {
            self.levers.push(gain);
        }
        if !(is_turned || is_lever || is_spun) && off_unit <= UNIT_GAIN {
            self.slides.push(gain);
        }
    }

    /// The kind told of DoF `dof` from `moves` structure moves.
    fn told(self, dof: &str, moves: usize) -> KindTold {
        let range = |v: &[f64], scale: f64, digits: usize| {
            let (low, high) = v
                .iter()
                .fold((f64::INFINITY, f64::NEG_INFINITY), |(l, h), &x| {
                    (l.min(x), h.max(x))
                });
            if v.len() == 1 {
                format!("{:.digits$}", low * scale)
            } else {
                format!("{:.digits$}–{:.digits$}", low * scale, high * scale)
            }
        };
        let turns = self.turned + self.spun + self.levers.len();
        let (kind, evidence) = if turns > 0 && self.slides.len() < SLIDE_MAJORITY * turns {
            let mut why = Vec::new();
            if self.turned > 0 {
                why.push(format!("turned gravity on {} SU(s)", self.turned));
            }
            if !self.levers.is_empty() {
                why.push(format!(
                    "{} SU(s) read lever arms of {} mm",
                    self.levers.len(),
                    range(&self.levers, 1e3, 0)
                ));
            }
            if self.spun > 0 {
                why.push(format!("{} SU(s) were spun outwards", self.spun));
            }
            (Some(DofKind::Revolute), why.join("; "))
        } else if !self.slides.is_empty() {
            (
                Some(DofKind::Prismatic),
                format!(
                    "{} SU(s) read its axis at {} per m/s², and {} turned gravity, was spun \
                     outwards or read a lever arm",
                    self.slides.len(),
                    range(&self.slides, 1.0, 2),
                    if turns == 0 {
                        "none".to_string()
                    } else {
                        turns.to_string()
                    }
                ),
            )
        } else if moves == 0 {
            (
                None,
                "no gravity turned, and no move of it alone in the motion record".to_string(),
            )
        } else {
            (
                None,
                "no SU its moves carried read them well enough".to_string(),
            )
        };
        KindTold {
            dof: dof.to_string(),
            kind,
            evidence,
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::measurements::{Move, Orientation, StructureExperiment};
    use crate::motion::{MOTION_FORMAT, MOTION_VERSION};
    use rand::SeedableRng;
    use rand_chacha::ChaCha8Rng;
    use rand_distr::{Distribution, Normal};

    /// Gravity as SU `a` (on the slide, its frame turned so that the slide's axis is its
    /// (0, 0.6, 0.8)) and SU `b` (on the base) read it.
    const GRAVITY: [[f64; 3]; 2] = [[0.0, 7.848, -5.886], [0.0, 0.0, 9.81]];
    /// The slide's axis in SU `a`'s frame.
    const AXIS: [f64; 3] = [0.0, 0.6, 0.8];

    /// A log of a prismatic DoF `slide` and a revolute `turn`: still at rest, `slide` moved out by
    /// 4 cm in 0.3 s (a quintic) and held, then `turn` moved on its own, at 10 ms blocks with
    /// ±0.01 g of noise on every reading (seeded).
    fn record() -> MotionRecord {
        let mut rng = ChaCha8Rng::seed_from_u64(7);
        let noise = Normal::new(0.0, 0.0566 / 10f64.sqrt()).unwrap();
        let mut run = MotionRun::new("log", 0.0);
        let (travel, time) = (0.04, 0.3);
        for b in 0..200 {
            let t = b as f64 * 0.01 - 0.5;
            let s = (t / time).clamp(0.0, 1.0);
            let (q, qd, qdd) = if (0.0..=time).contains(&t) {
                (
                    travel * (10.0 * s.powi(3) - 15.0 * s.powi(4) + 6.0 * s.powi(5)),
                    travel * (30.0 * s * s - 60.0 * s.powi(3) + 30.0 * s.powi(4)) / time,
                    travel * (60.0 * s - 180.0 * s * s + 120.0 * s.powi(3)) / (time * time),
                )
            } else {
                (if t > time { travel } else { 0.0 }, 0.0, 0.0)
            };
            // The turn moves later, on its own: it accelerates SU `a` too, but is no slide.
            let turning = (1.2..1.5).contains(&t);
            let turn = if turning {
                [0.3, 1.0, 5.0, 0.0]
            } else {
                [0.0; 4]
            };
            let mut a = GRAVITY[0];
            for k in 0..3 {
                a[k] += AXIS[k] * qdd + noise.sample(&mut rng) + if turning { 2.0 } else { 0.0 };
            }
            let mut still = GRAVITY[1];
            for v in &mut still {
                *v += noise.sample(&mut rng);
            }
            run.push(&[[q, qd, qdd, 0.0], turn], vec![Some(a), Some(still)]);
        }
        two_sus(run, ["slide", "turn"])
    }

    /// A record of SUs `a` and `b` at 10 ms blocks, holding `run`, of DoFs `dofs`.
    fn two_sus(run: MotionRun, dofs: [&str; 2]) -> MotionRecord {
        MotionRecord {
            format: MOTION_FORMAT.into(),
            version: MOTION_VERSION,
            period: 0.01,
            dofs: dofs.iter().map(|d| d.to_string()).collect(),
            sus: vec!["a".into(), "b".into()],
            noise_sd: vec![Some(0.018); 2],
            half_width: None,
            rounding: Vec::new(),
            runs: vec![run],
            samples: Vec::new(),
        }
    }

    fn set() -> MeasurementSet {
        let mut set = MeasurementSet::new(
            vec!["slide".into(), "turn".into()],
            vec!["a".into(), "b".into()],
        );
        set.prismatic = vec!["slide".into()];
        let hold = |pose: Vec<f64>, dof: &str| Move {
            dof: dof.into(),
            pose,
            readings: GRAVITY.to_vec(),
            accelerated: Vec::new(),
            accelerated_sd: Vec::new(),
            extra: Default::default(),
        };
        set.structure = Some(upright(
            GRAVITY.to_vec(),
            vec![
                hold(vec![0.04, 0.0], "slide"),
                hold(vec![0.04, 0.3], "turn"),
            ],
        ));
        set
    }

    /// A structure experiment of one base orientation: at rest (every DoF at 0) reading `rest`,
    /// then `moves`.
    fn upright(rest: Vec<Reading>, moves: Vec<Move>) -> StructureExperiment {
        StructureExperiment {
            orientations: vec![Orientation {
                rest_pose: vec![0.0; moves.first().map_or(0, |m| m.pose.len())],
                rest,
                moves,
                extra: Default::default(),
            }],
            extra: Default::default(),
        }
    }

    #[test]
    fn a_slide_reads_its_axis_on_what_it_carries_and_nothing_elsewhere() {
        let mut set = set();
        accelerations_of_moves(&mut set, &record());
        let moves = &set.structure.as_ref().unwrap().orientations[0].moves;
        let carried = moves[0].accelerated[0];
        for k in 0..3 {
            assert!((carried[k] - AXIS[k]).abs() < 0.01, "{carried:?}");
        }
        let still = moves[0].accelerated[1];
        assert!(still.iter().all(|v| v.abs() < 0.01), "{still:?}");
        // The turn's hold is not where the record's turn ended: nothing is regressed for it.
        assert!(moves[1].accelerated.is_empty());
    }

    /// A log of two revolute DoFs moved on their own by 0.3 rad in 0.5 s (quintics) from rest,
    /// each about the z axis of SU `a`'s frame, which sits `LEVER` m from it along x: `yaw` with
    /// its axis vertical (gravity stays where it is in the SU frame), then `pitch` with its axis
    /// horizontal (gravity turns in the x–y plane). SU `b` stays on the base. 10 ms blocks, ±0.01 g noise (seeded).
    fn turns() -> MotionRecord {
        let mut rng = ChaCha8Rng::seed_from_u64(11);
        let noise = Normal::new(0.0, 0.0566 / 10f64.sqrt()).unwrap();
        let (travel, time) = (0.3, 0.5);
        let quintic = |t: f64| -> [f64; 3] {
            if t <= 0.0 {
                return [0.0; 3];
            }
            if t >= time {
                return [travel, 0.0, 0.0];
            }
            let s = t / time;
            [
                travel * (10.0 * s.powi(3) - 15.0 * s.powi(4) + 6.0 * s.powi(5)),
                travel * (30.0 * s * s - 60.0 * s.powi(3) + 30.0 * s.powi(4)) / time,
                travel * (60.0 * s - 180.0 * s * s + 120.0 * s.powi(3)) / (time * time),
            ]
        };
        let mut run = MotionRun::new("log", 0.0);
        for b in 0..300 {
            let t = b as f64 * 0.01;
            // yaw from 0.5 s, pitch from 1.8 s.
            let [y, yd, ydd] = quintic(t - 0.5);
            let [p, pd, pdd] = quintic(t - 1.8);
            let (speed, acceleration) = (yd + pd, ydd + pdd);
            // Specific force in the turning SU frame: tangential α r along y, centripetal −ω² r
            // along x, minus gravity, (0, −9.81, 0) at rest: the yaw leaves it where it is, the
            // pitch turns it back by its angle.
            let g_pitch = [-9.81 * p.sin(), -9.81 * p.cos(), 0.0];
            let mut a = [
                -speed * speed * LEVER - g_pitch[0],
                acceleration * LEVER - g_pitch[1],
                0.0,
            ];
            let mut still = [0.0, 9.81, 0.0];
            for k in 0..3 {
                a[k] += noise.sample(&mut rng);
                still[k] += noise.sample(&mut rng);
            }
            run.push(
                &[[y, yd, ydd, 0.0], [p, pd, pdd, 0.0]],
                vec![Some(a), Some(still)],
            );
        }
        two_sus(run, ["yaw", "pitch"])
    }

    /// SU `a`'s distance from both axes, m.
    const LEVER: f64 = 0.03;

    /// The structure experiment of [`turns`]'s record: the yaw's move, then the pitch's.
    fn turns_set() -> MeasurementSet {
        let mut set = MeasurementSet::new(
            vec!["yaw".into(), "pitch".into()],
            vec!["a".into(), "b".into()],
        );
        set.structure = Some(upright(
            vec![[0.0, 9.81, 0.0]; 2],
            vec![
                turn_hold(vec![0.3, 0.0], "yaw"),
                turn_hold(vec![0.3, 0.3], "pitch"),
            ],
        ));
        set
    }

    /// A structure move of `dof` to `pose` in [`turns`]'s record, with the static readings
    /// there: the yaw leaves gravity where it was, the pitch turns it on SU `a`.
    fn turn_hold(pose: Vec<f64>, dof: &str) -> Move {
        let p = pose[1];
        Move {
            dof: dof.into(),
            pose,
            readings: vec![[9.81 * p.sin(), 9.81 * p.cos(), 0.0], [0.0, 9.81, 0.0]],
            accelerated: Vec::new(),
            accelerated_sd: Vec::new(),
            extra: Default::default(),
        }
    }

    #[test]
    fn a_turn_reads_its_lever_arm_on_what_it_carries_whether_or_not_it_turns_gravity() {
        let mut set = turns_set();
        accelerations_of_moves(&mut set, &turns());
        for mv in &set.structure.unwrap().orientations[0].moves {
            let [x, y, z] = mv.accelerated[0];
            // The tangent (y) times the lever arm; the gravity the pitch turns (0.3 rad: 2.9
            // m/s² on x) and the centripetal term leave nothing on it.
            assert!(
                (y - LEVER).abs() < 0.002,
                "{}: {:?}",
                mv.dof,
                mv.accelerated
            );
            assert!(
                x.abs() < 0.002 && z.abs() < 0.002,
                "{}: {:?}",
                mv.dof,
                mv.accelerated
            );
            let still = mv.accelerated[1];
            assert!(
                still.iter().all(|v| v.abs() < 0.002),
                "{}: {still:?}",
                mv.dof
            );
        }
    }

    #[test]
    fn a_slide_and_turns_are_told_apart_by_what_their_moves_did_to_the_skin() {
        // The slide's move: SU `a` reads its axis, 1 per m/s², and nothing turns or spins.
        let mut set = set();
        set.prismatic.clear();
        let told = kinds_of_moves(&set, Some(&record()));
        assert_eq!(told.len(), 2);
        assert_eq!(told[0].kind, Some(DofKind::Prismatic), "{:?}", told[0]);
        // The turn's record holds no motion the one-DoF model can read (a constant speed and
        // acceleration with its position held): nothing tells it.
        assert_eq!(told[1].kind, None, "{:?}", told[1]);
        // A yaw about a vertical axis turns no gravity, but its SU reads a 30 mm lever arm (and
        // a pitch turns gravity too): both are turns.
        let set = turns_set();
        let told = kinds_of_moves(&set, Some(&turns()));
        assert_eq!(told[0].kind, Some(DofKind::Revolute), "{:?}", told[0]);
        assert!(
            told[0].evidence.contains("lever arms of 30 mm"),
            "{:?}",
            told[0]
        );
        assert!(
            !told[0].evidence.contains("turned gravity"),
            "{:?}",
            told[0]
        );
        assert_eq!(told[1].kind, Some(DofKind::Revolute), "{:?}", told[1]);
        assert!(
            told[1].evidence.contains("turned gravity on 1 SU"),
            "{:?}",
            told[1]
        );
    }

    #[test]
    fn a_move_the_record_does_not_hold_stays_unmeasured() {
        // The hold is somewhere the record never went.
        let mut set = set();
        set.structure.as_mut().unwrap().orientations[0].moves[0].pose = vec![0.02, 0.0];
        accelerations_of_moves(&mut set, &record());
        assert!(set.structure.unwrap().orientations[0].moves[0]
            .accelerated
            .is_empty());
        // Nor one in a base orientation the record did not stand in.
        let mut set = set_tilted();
        accelerations_of_moves(&mut set, &record());
        assert!(set.structure.unwrap().orientations[0].moves[0]
            .accelerated
            .is_empty());
    }

    fn set_tilted() -> MeasurementSet {
        let mut set = set();
        let o = &mut set.structure.as_mut().unwrap().orientations[0];
        o.rest = vec![[9.81, 0.0, 0.0], [9.81, 0.0, 0.0]];
        set
    }
}
