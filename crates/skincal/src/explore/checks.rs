//! Checks of the structure experiment's physics beyond the activity matrix.

use super::activity::{angle_between, beyond_travel};
use super::{ActivityMatrix, Diagnostic, DiagnosticKind, Severity};
use crate::measurements::MeasurementSet;
use crate::model::sensor::STANDARD_GRAVITY;

/// What the readings say about themselves, beyond the activity matrix:
///
/// * One DoF turns everything it moves by one rotation, so every SU it moves sees gravity turn by
///   the same angle. Moved SUs whose angles fall apart mean that something else moved during the
///   move (most often the base): the tree built from it is wrong, so it is an error.
/// * The norm of a static reading is |g| in every pose, so its change between the rest pose and a
///   move is noise. Noise comparable to the threshold decides entries by chance.
pub(super) fn physical_checks(set: &MeasurementSet, a: &ActivityMatrix) -> Vec<Diagnostic> {
    let mut found = Vec::new();
    let Some(structure) = &set.structure else {
        return found;
    };
    let sigma = static_noise(structure);
    if sigma * NOISE_MARGIN > a.threshold {
        found.push(Diagnostic {
            kind: DiagnosticKind::TooNoisy,
            severity: Severity::Error,
            message: format!(
                "the static readings scatter by about {:.3} g (from how much their norm, which is |g| in every pose, changes between the rest pose and the moves), too close to the threshold {:.3} g: which SU moved with which DoF is decided by noise. Average more samples per still pose (longer still periods), or raise --threshold above {:.3} g if the moves turn the SUs far enough",
                sigma / STANDARD_GRAVITY,
                a.threshold / STANDARD_GRAVITY,
                sigma * NOISE_MARGIN / STANDARD_GRAVITY
            ),
            sus: Vec::new(),
            dofs: Vec::new(),
        });
        // The angle check below would only repeat the noise.
        return found;
    }
    // Angles are compared with a tolerance well above the noise of one angle (σ/|g| per reading).
    let tolerance = RIGID_TOLERANCE.max(6.0 * sigma / STANDARD_GRAVITY);
    found.extend(base_turns(set, a, 6.0 * sigma / STANDARD_GRAVITY));
    for (oi, o) in structure.orientations.iter().enumerate() {
        for mv in &o.moves {
            found.extend(unlike_turns(a, (oi, o), mv, sigma, tolerance));
        }
    }
    found
}

/// One move's SUs whose gravity turned by another angle than the others': more than the noise
/// and the sensors' bias and scale allow (`tolerance` is the noise's part). Those that agree with
/// each other turned by a second rotation (the move went wrong, an error); those that agree with
/// nobody read wrongly (a warning).
fn unlike_turns(
    a: &ActivityMatrix,
    (oi, o): (usize, &crate::measurements::Orientation),
    mv: &crate::measurements::Move,
    sigma: f64,
    tolerance: f64,
) -> Option<Diagnostic> {
    let norm = |r: &[f64; 3]| r.iter().map(|x| x * x).sum::<f64>().sqrt();
    let d = a.dofs.iter().position(|x| *x == mv.dof)?;
    if a.has_followers(d) {
        // Its mimic followers turn the bodies they drive by rotations of their own.
        return None;
    }
    let mut turned = turned_sus(a, (oi, o), mv);
    // SUs that turned further than the DoF travelled, each alone, read wrongly: the
    // activity matrix left them out already.
    let travel = (mv.pose[d] - o.rest_pose[d]).abs();
    let lone = beyond_travel(&turned, travel, tolerance.max(INTRINSIC_SHARE * travel));
    turned.retain(|(_, u)| !lone.contains(u));
    if turned.len() < 2 {
        return None;
    }
    // The angle of the move is that of the SUs the matrix says it moves (where a glitch
    // and a moved SU are all there is, the glitch must not set it).
    let mut moved: Vec<f64> = turned
        .iter()
        .filter(|&&(_, u)| a.is_active(u, d))
        .map(|&(angle, _)| angle)
        .collect();
    if moved.is_empty() {
        moved = turned.iter().map(|&(angle, _)| angle).collect();
    }
    moved.sort_by(f64::total_cmp);
    let median = moved[moved.len() / 2];
    // A real accelerometer's bias and scale change how far its reading turns, by a share
    // of the turn: angles that differ by less say nothing of a second rotation. They
    // change its norm over the turn by a share too; a reading whose norm changed by more
    // than bias and scale can is judged without that allowance.
    let strict = tolerance;
    let relaxed = tolerance.max(INTRINSIC_SHARE * median);
    let norm_change = |u: usize| (norm(&mv.readings[u]) - norm(&o.rest[u])).abs();
    let allowed_change = INTRINSIC_SHARE * median * STANDARD_GRAVITY + 6.0 * sigma;
    let tolerance_of = |u: usize| {
        if norm_change(u) > allowed_change {
            strict
        } else {
            relaxed
        }
    };
    turned.sort_by(|x, y| x.0.total_cmp(&y.0));
    type Turned<'t> = Vec<&'t (f64, usize)>;
    let (odd, rest): (Turned, Turned) = turned
        .iter()
        .partition(|&&(angle, u)| (angle - median).abs() > tolerance_of(u));
    if odd.is_empty() {
        return None;
    }
    // Odd SUs that agree with each other turned by a second rotation: the move went wrong
    // (the base tilted). Odd SUs that agree with nobody read wrongly (glitches).
    let agreeing = odd.iter().any(|&&(x, u)| {
        odd.iter()
            .any(|&&(y, v)| u != v && (x - y).abs() <= relaxed)
    });
    let lone = !agreeing && (rest.len() >= 2 || odd.iter().all(|&&(_, u)| !a.is_active(u, d)));
    Some(unlike_turns_found(
        a,
        (oi, mv),
        d,
        lone,
        (&odd, rest.len()),
        median,
    ))
}

/// The SUs a move clearly moved, with the angle their gravity reading turned by: readings whose
/// norm is not |g| (misread) say nothing about how the move turned, nor do broken SUs.
fn turned_sus(
    a: &ActivityMatrix,
    (oi, o): (usize, &crate::measurements::Orientation),
    mv: &crate::measurements::Move,
) -> Vec<(f64, usize)> {
    let misread = |u: usize| {
        a.misread.iter().any(|m| {
            m.orientation == oi + 1
                && m.su == a.sus[u]
                && m.dof.as_ref().is_none_or(|x| *x == mv.dof)
                && (m.norm_g - m.expected_g).abs() > super::activity::MISREAD_TOLERANCE
        })
    };
    (0..a.sus.len())
        .filter(|&u| !misread(u))
        .filter(|&u| !a.broken.iter().any(|b| b.su == a.sus[u]))
        .filter(|&u| {
            let c = (0..3)
                .map(|k| (mv.readings[u][k] - o.rest[u][k]).abs())
                .fold(0.0, f64::max);
            c > a.threshold * a.uncertainty_factor
        })
        .map(|u| (angle_between(&o.rest[u], &mv.readings[u]), u))
        .collect()
}

/// The diagnostic of a move whose `odd` SUs turned otherwise than `agreeing` others by about
/// `median`: `lone` ones read wrongly (a warning), others turned by a second rotation (an error).
fn unlike_turns_found(
    a: &ActivityMatrix,
    (oi, mv): (usize, &crate::measurements::Move),
    d: usize,
    lone: bool,
    (odd, agreeing): (&[&(f64, usize)], usize),
    median: f64,
) -> Diagnostic {
    let names = odd
        .iter()
        .map(|(angle, u)| format!("{} {:.1}°", a.sus[*u], angle.to_degrees()))
        .collect::<Vec<_>>()
        .join(", ");
    Diagnostic {
        kind: if lone {
            DiagnosticKind::MisreadReading
        } else {
            DiagnosticKind::MoveNotRigid
        },
        severity: if lone {
            Severity::Warning
        } else {
            Severity::Error
        },
        message: format!(
            "in the move of {} (orientation {}), the SUs' gravity readings turned by different angles: {} SUs by about {:.1}°, but {}. One DoF turns everything it moves by one rotation, so something else moved during this move — most often the base (the reference segment) tilted, or another DoF slipped. Hold the base still and record this move again",
            mv.dof,
            oi + 1,
            agreeing,
            median.to_degrees(),
            names
        ),
        sus: odd.iter().map(|(_, u)| a.sus[*u].clone()).collect(),
        dofs: vec![a.dofs[d].clone()],
    }
}

/// The noise of the static readings along gravity, m/s²: for each (SU, move), |r_move| − |r_rest|
/// has twice its variance; the median of the squares (robust to misread readings) over that of χ²
/// with one degree of freedom (0.455) estimates it.
fn static_noise(structure: &crate::measurements::StructureExperiment) -> f64 {
    let norm = |r: &[f64; 3]| r.iter().map(|x| x * x).sum::<f64>().sqrt();
    let mut squares: Vec<f64> = Vec::new();
    for o in &structure.orientations {
        for mv in &o.moves {
            for (before, after) in o.rest.iter().zip(&mv.readings) {
                let d = norm(after) - norm(before);
                squares.push(d * d);
            }
        }
    }
    squares.sort_by(f64::total_cmp);
    squares
        .get(squares.len() / 2)
        .map_or(0.0, |m| (m / 0.455 / 2.0).sqrt())
}

/// The moves during which the reference segment turned: its SUs — those that stay still in every
/// other move of their orientation — all turned together, by more than the noise allows
/// (`noise`, rad) and by much the same angle. A base that tilts by a few degrees moves no SU
/// beyond the activity threshold far from the axis, and bias and scale errors do not make a
/// still SU turn: this names what the angles of the moved SUs cannot.
fn base_turns(set: &MeasurementSet, a: &ActivityMatrix, noise: f64) -> Vec<Diagnostic> {
    let mut found = Vec::new();
    let Some(structure) = &set.structure else {
        return found;
    };
    let noise = noise.max(MIN_BASE_TURN);
    let usable = |u: usize| !a.broken.iter().any(|b| b.su == a.sus[u]);
    // angles[o][k][u]: how far SU u's reading turned in move k of orientation o.
    let angles: Vec<Vec<Vec<f64>>> = structure
        .orientations
        .iter()
        .map(|o| {
            o.moves
                .iter()
                .map(|mv| {
                    (0..a.sus.len())
                        .map(|u| angle_between(&o.rest[u], &mv.readings[u]))
                        .collect()
                })
                .collect()
        })
        .collect();
    for (oi, o) in structure.orientations.iter().enumerate() {
        for (m, mv) in o.moves.iter().enumerate() {
            // Still in every other move of every orientation (three at least): an SU that only
            // this move's DoF moves turns in that DoF's move in the other orientation too.
            let reference: Vec<usize> = (0..a.sus.len())
                .filter(|&u| usable(u))
                .filter(|&u| {
                    let others: Vec<f64> = angles
                        .iter()
                        .enumerate()
                        .flat_map(|(p, moves)| {
                            moves
                                .iter()
                                .enumerate()
                                .filter(move |&(k, _)| (p, k) != (oi, m))
                                .map(move |(_, turned)| turned[u])
                        })
                        .collect();
                    others.len() >= 3 && others.iter().all(|&x| x < noise)
                })
                .collect();
            if reference.len() < 2 {
                continue;
            }
            let mut turned: Vec<f64> = reference.iter().map(|&u| angles[oi][m][u]).collect();
            turned.sort_by(f64::total_cmp);
            let (least, median) = (turned[0], turned[turned.len() / 2]);
            // SUs that only this DoF moves, about an axis vertical in the other orientation,
            // look still elsewhere too; they turn by the DoF's travel, a base by far less.
            let d = set.dof_index(&mv.dof);
            let travel = d.map_or(0.0, |d| (mv.pose[d] - o.rest_pose[d]).abs());
            if least > noise && least > 0.5 * median && median < 0.5 * travel {
                found.push(Diagnostic {
                    kind: DiagnosticKind::MoveNotRigid,
                    severity: Severity::Error,
                    message: format!(
                        "in the move of {} (orientation {}), the SUs that stay still in every other move — those on the reference segment — turned by about {:.1}° (the noise allows {:.1}°): the base tilted or moved during this move, and every SU's change in it is off by that turn. Hold the base still and record this move again",
                        mv.dof,
                        oi + 1,
                        median.to_degrees(),
                        noise.to_degrees()
                    ),
                    sus: reference.iter().map(|&u| a.sus[u].clone()).collect(),
                    dofs: vec![mv.dof.clone()],
                });
            }
        }
    }
    found
}

/// The smallest turn of the reference segment's SUs that counts as the base turning, rad: below
/// it a still reading's noise and the settling of a compliant base explain it.
const MIN_BASE_TURN: f64 = 0.0175;

/// The noise must stay below the threshold by this factor.
const NOISE_MARGIN: f64 = 3.0;
/// Smallest difference between two SUs' gravity turn angles in one move that counts, rad.
pub(super) const RIGID_TOLERANCE: f64 = 0.05;
/// The share of a turn by which a real accelerometer's reading may turn further or less: a bias
/// of up to 0.1 g moves a reading's norm, and so the angle between two readings, by a tenth or
/// so, and scale factors that differ by up to ±5 % per axis by as much again (the angle between
/// two readings of an SU with 0.06 g of bias and 3 % of scale errors differed by 3.7° in a 17°
/// move of the humanoid's ankle). A second rotation (a base that tilts) turns the SUs the DoF
/// does not move too, and those differ by the whole turn.
const INTRINSIC_SHARE: f64 = 0.3;
