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

use nalgebra::{DMatrix, DVector};

use crate::measurements::{MeasurementSet, Reading};
use crate::model::DofKind;
use crate::motion::{MotionRecord, MotionRun, SAME_POSE};

/// A DoF moves in a block when its speed exceeds this, rad/s (m/s); every other DoF is still in
/// a move when it stays below it.
const MOVING: f64 = 0.01;
/// Blocks of stillness on each side of a move that join its regression (they carry the hold's
/// reading, which the regression's intercept takes).
const MARGIN: usize = 10;
/// The least `Σ(q̈ − mean)²` over a move's blocks for its regression to tell anything, (m/s²)²
/// or (rad/s²)²: a 4 cm finger move in 0.3 s gives about 60.
const LEAST_EXCITATION: f64 = 1.0;

/// Fills [`crate::measurements::Move::accelerated`] of `set`'s structure moves (of every DoF but
/// mimic followers, which move with their leaders) from `record` (ingested from the same logs):
/// for each move in the base orientation the record stood in ([`MotionRecord::same_base`] at
/// the rest pose), the record's stretches in which that DoF alone moved (its followers with it)
/// and which end at the move's pose. Moves the record does not hold stay empty.
pub fn accelerations_of_moves(set: &mut MeasurementSet, record: &MotionRecord) {
    let column = |name: &str| record.dofs.iter().position(|d| d == name);
    let su_column: Vec<Option<usize>> = set
        .sus
        .iter()
        .map(|su| record.sus.iter().position(|s| s == su))
        .collect();
    let wanted: Vec<(String, Vec<usize>, DofKind)> = (0..set.dofs.len())
        .filter(|&d| !set.mimic.contains_key(&set.dofs[d]))
        .filter_map(|d| {
            let mut moving = vec![column(&set.dofs[d])?];
            moving.extend(
                set.followers_of(d)
                    .into_iter()
                    .filter_map(|f| column(&set.dofs[f])),
            );
            Some((set.dofs[d].clone(), moving, set.dof_kind(d)))
        })
        .collect();
    if wanted.is_empty() {
        return;
    }
    // Each record column's place in the set's poses.
    let in_set: Option<Vec<usize>> = record.dofs.iter().map(|d| set.dof_index(d)).collect();
    let Some(in_set) = in_set else {
        return;
    };
    let to_record = |pose: &[f64]| -> Vec<f64> { in_set.iter().map(|&i| pose[i]).collect() };
    let Some(structure) = set.structure.as_mut() else {
        return;
    };
    for o in &mut structure.orientations {
        if record.same_base(&o.rest_pose, &o.rest) != Some(true) {
            continue;
        }
        for mv in &mut o.moves {
            let Some((_, moving, kind)) = wanted.iter().find(|(name, ..)| *name == mv.dof) else {
                continue;
            };
            let pose = to_record(&mv.pose);
            let stretches = moves_into(record, moving, &pose);
            if stretches.is_empty() {
                continue;
            }
            let revolute = *kind == DofKind::Revolute;
            let d = moving[0];
            let gains: Vec<Option<Reading>> = su_column
                .iter()
                .map(|u| u.and_then(|u| gain(&stretches, d, u, revolute, pose[d])))
                .collect();
            if gains.iter().any(Option::is_some) {
                mv.accelerated = gains.into_iter().map(|g| g.unwrap_or([0.0; 3])).collect();
            }
        }
    }
}

/// A stretch of a run: `(run, first block, end block)`.
type Stretch<'a> = (&'a MotionRun, usize, usize);

/// The record's stretches `(run, first block, end block)` in which `moving[0]` moved with no
/// DoF but `moving` (its followers) moving, widened by up to [`MARGIN`] still blocks on each
/// side, and whose last block holds `pose`.
fn moves_into<'a>(record: &'a MotionRecord, moving: &[usize], pose: &[f64]) -> Vec<Stretch<'a>> {
    record
        .runs
        .iter()
        .flat_map(|run| {
            let moves = |b: usize| run.qd[b][moving[0]].abs() > MOVING;
            let others_still = |b: usize| {
                run.qd[b]
                    .iter()
                    .enumerate()
                    .all(|(e, v)| moving.contains(&e) || v.abs() <= MOVING)
            };
            let mut stretches = Vec::new();
            let mut b = 0;
            while b < run.len() {
                if !moves(b) {
                    b += 1;
                    continue;
                }
                let first = b;
                while b < run.len() && moves(b) {
                    b += 1;
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

/// SU `u`'s reading per unit of DoF `d`'s acceleration over `stretches`: the least-squares
/// coefficient of `q̈` in the exact model of one DoF moving with everything upstream still,
///
/// ```text
/// s = c + k q̈                                        (prismatic: gravity does not turn)
/// s = c + G_c (cos Δθ − 1) + G_s sin Δθ + k q̈ + k_ω q̇²   (revolute: Δθ from the move's pose)
/// ```
///
/// whose coefficients are constant in the SU frame (the axis is fixed in the moving segment), so
/// the gravity the move turns does not leak into `k`: `k` is the axis for a prismatic DoF that
/// carries the SU (a unit vector), the tangent times the lever arm for a revolute one (its norm in
/// m), zero for an SU the DoF does not move. `None` where the stretches do not excite `q̈` apart
/// from the other regressors enough to tell ([`LEAST_EXCITATION`]) or the SU sent too little in
/// them.
fn gain(
    stretches: &[Stretch<'_>],
    d: usize,
    u: usize,
    revolute: bool,
    pose: f64,
) -> Option<Reading> {
    let regressors = |run: &MotionRun, b: usize| -> Vec<f64> {
        let a = run.qdd[b][d];
        if revolute {
            let turned = run.q[b][d] - pose;
            vec![
                1.0,
                turned.cos() - 1.0,
                turned.sin(),
                a,
                run.qd[b][d].powi(2),
            ]
        } else {
            vec![1.0, a]
        }
    };
    let k = if revolute { 3 } else { 1 };
    let n = if revolute { 5 } else { 2 };
    let mut gram = DMatrix::<f64>::zeros(n, n);
    let mut moment = DMatrix::<f64>::zeros(n, 3);
    let mut samples = 0;
    for &(run, start, end) in stretches {
        for b in start..end {
            let Some(y) = run.skin[b][u] else {
                continue;
            };
            let x = DVector::from_vec(regressors(run, b));
            gram += &x * x.transpose();
            for (c, v) in y.iter().enumerate() {
                moment.column_mut(c).axpy(*v, &x, 1.0);
            }
            samples += 1;
        }
    }
    if samples <= n + 1 {
        return None;
    }
    let inverse = gram.try_inverse()?;
    // `1 / (G⁻¹)ₖₖ` is what of `Σ q̈²` the other regressors leave to tell `k`.
    if inverse[(k, k)] <= 0.0 || 1.0 / inverse[(k, k)] < LEAST_EXCITATION {
        return None;
    }
    let coefficients = inverse * moment;
    Some([
        coefficients[(k, 0)],
        coefficients[(k, 1)],
        coefficients[(k, 2)],
    ])
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
            extra: Default::default(),
        };
        set.structure = Some(StructureExperiment {
            orientations: vec![Orientation {
                rest_pose: vec![0.0, 0.0],
                rest: GRAVITY.to_vec(),
                moves: vec![
                    hold(vec![0.04, 0.0], "slide"),
                    hold(vec![0.04, 0.3], "turn"),
                ],
                extra: Default::default(),
            }],
            extra: Default::default(),
        });
        set
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

    #[test]
    fn a_turn_reads_its_lever_arm_on_what_it_carries_whether_or_not_it_turns_gravity() {
        let mut set = MeasurementSet::new(
            vec!["yaw".into(), "pitch".into()],
            vec!["a".into(), "b".into()],
        );
        let hold = |pose: Vec<f64>, dof: &str| Move {
            dof: dof.into(),
            pose,
            readings: vec![[0.0; 3]; 2],
            accelerated: Vec::new(),
            extra: Default::default(),
        };
        set.structure = Some(StructureExperiment {
            orientations: vec![Orientation {
                rest_pose: vec![0.0, 0.0],
                rest: vec![[0.0, 9.81, 0.0]; 2],
                moves: vec![hold(vec![0.3, 0.0], "yaw"), hold(vec![0.3, 0.3], "pitch")],
                extra: Default::default(),
            }],
            extra: Default::default(),
        });
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
