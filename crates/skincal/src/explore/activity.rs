//! The activity matrix (step 1 of the module documentation) from the structure experiment's
//! readings, robust to misread ones: a reading whose norm is not the SU's |g|, one that turned
//! further than the DoF travelled (a rotation about one axis turns gravity by its angle at most),
//! a lone SU that turned unlike every other one the same move turned, or a change that the other
//! orientation contradicts, is left out; a misread rest is rebuilt from the moves that left the SU still; an
//! entry no orientation can then read is decided by the SU's row mates or by the tree, or left
//! undecided (the SU is set aside). Where the tree must choose between two readings, the more
//! doubtful one (turned beyond the travel, norm off |g|) gives way.

use serde::{Deserialize, Serialize};

use super::{ExploreConfig, ExploreError};
use crate::measurements::{MeasurementSet, StructureExperiment};
use crate::model::sensor::STANDARD_GRAVITY;
use crate::model::DofKind;

/// A static reading whose norm differs from its SU's median norm by more than this, g, is misread
/// (bias and scale errors move the norm by well under 0.1 g).
pub(super) const MISREAD_TOLERANCE: f64 = 0.15;
/// SUs that one move turned by angles this close, rad, agree (intrinsics bend angles a little).
const LONE_TURN_TOLERANCE: f64 = 0.15;
/// A recorded travel below this, rad, says too little to bound the turn of gravity.
const MIN_TRAVEL: f64 = 0.02;
/// How much further than recorded a DoF may really travel (servo compliance, backlash), relative.
const TRAVEL_SLACK: f64 = 0.2;
/// A move's turn tells moved from still SUs when it is this many times the still SUs' turn.
const TURN_OVER_NOISE: f64 = 4.0;
/// The smallest still turn assumed, rad (noise-free data turns still SUs by nothing).
const TURN_FLOOR: f64 = 0.002;
/// How many SUs must share a turn beyond the travel to be believed (a turn counts itself).
const TILT_GROUP: usize = 3;

/// The activity matrix with the measured change behind every entry.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct ActivityMatrix {
    /// SU names (rows).
    pub sus: Vec<String>,
    /// DoF names (columns).
    pub dofs: Vec<String>,
    /// `change[u][d]`: the largest change of any axis of SU `u`'s reading when DoF `d` moved, over
    /// all orientations, m/s² (0 for a DoF that was never moved). For a prismatic DoF, which turns
    /// no gravity: the typical acceleration its pattern gave the SU, scaled so that half the
    /// pattern's peak meets the threshold (`prismatic_columns`).
    pub change: Vec<Vec<f64>>,
    /// Whether each DoF was moved in at least one orientation (a prismatic one: excited in at
    /// least one training pose).
    pub explored: Vec<bool>,
    /// Per DoF: whether it is prismatic (empty when none is).
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub prismatic: Vec<bool>,
    /// Per DoF: whether its column was read from what it accelerated because its axis stood
    /// vertical in every base orientation (`upright_columns`; empty when none was).
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub upright: Vec<bool>,
    /// The threshold, m/s².
    pub threshold: f64,
    /// The uncertainty factor.
    pub uncertainty_factor: f64,
    /// Number of base orientations.
    pub orientations: usize,
    /// Per SU: the angle, rad, between its rest readings in the first and the second orientation
    /// (`None` with a single orientation).
    pub rest_turn: Vec<Option<f64>>,
    /// Readings that cannot be what an accelerometer at rest reads (their norm is far from the
    /// SU's |g|): the entries they would decide come from the other orientation.
    #[serde(default)]
    pub misread: Vec<Misread>,
    /// Entries that no orientation could decide once misread readings were left out (the only
    /// orientation left turned the DoF about gravity), decided by the other SUs whose rows agree.
    #[serde(default)]
    pub inferred: Vec<Inferred>,
    /// `(SU, DoF)` entries that neither the readings nor the other SUs nor the tree decide: the
    /// SU is set aside.
    #[serde(default)]
    pub undecided: Vec<(String, String)>,
    /// Per DoF: the DoF it follows, for a mimic DoF (empty when none is one). A mimic DoF has no
    /// column: its leader's moves move it.
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub leader_of: Vec<Option<usize>>,
    /// SUs on bodies that mimic DoFs drive (`explore/mimic.rs`): set aside.
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub mimic_driven: Vec<super::mimic::MimicDriven>,
    /// SUs whose readings no working accelerometer gives: set aside.
    #[serde(default)]
    pub broken: Vec<BrokenSu>,
}

/// An SU whose readings cannot come from a working accelerometer.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct BrokenSu {
    /// The SU.
    pub su: String,
    /// `dead`, `frozen` or `railed`.
    pub kind: String,
    /// What was seen.
    pub detail: String,
}

/// Below this norm, g, in every reading an SU is dead.
const DEAD_NORM: f64 = 0.05;
/// A still reading whose norm is off 1 g by more than this fraction is no working part's.
const FAR_FROM_G: f64 = 0.5;
/// An axis whose median static reading is beyond this, g, is railed: gravity and any bias of a
/// working SU stay well below it.
const RAIL: f64 = 1.5;

/// The SUs whose static readings (structure and training) no working accelerometer gives: all
/// (near) zero, exactly the same in every pose and base orientation, or an axis stuck beyond what
/// gravity can give.
pub fn broken_sus(set: &MeasurementSet) -> Vec<BrokenSu> {
    let Some(structure) = &set.structure else {
        return Vec::new();
    };
    let norm = |r: &[f64; 3]| r.iter().map(|x| x * x).sum::<f64>().sqrt();
    let mut out = Vec::new();
    for (u, su) in set.sus.iter().enumerate() {
        let training = set.training.iter().flat_map(|t| &t.poses);
        let readings: Vec<&[f64; 3]> = structure
            .orientations
            .iter()
            .flat_map(|o| std::iter::once(&o.rest).chain(o.moves.iter().map(|m| &m.readings)))
            .chain(training.map(|p| &p.static_readings))
            .filter_map(|r| r.get(u))
            .collect();
        if readings.is_empty() {
            continue;
        }
        let broken = |kind: &str, detail: String| BrokenSu {
            su: su.clone(),
            kind: kind.into(),
            detail,
        };
        if readings
            .iter()
            .all(|r| norm(r) < DEAD_NORM * STANDARD_GRAVITY)
        {
            out.push(broken(
                "dead",
                format!("every reading is below {DEAD_NORM} g (it reads zeros: no power, no data, or a broken link)"),
            ));
            continue;
        }
        if structure.orientations.len() >= 2 && readings.iter().all(|r| *r == readings[0]) {
            out.push(broken(
                "frozen",
                format!(
                    "it reads ({:.3}, {:.3}, {:.3}) g in every pose and base orientation, even when the base turned (a stale value: the sensor stopped updating)",
                    readings[0][0] / STANDARD_GRAVITY,
                    readings[0][1] / STANDARD_GRAVITY,
                    readings[0][2] / STANDARD_GRAVITY
                ),
            ));
            continue;
        }
        for k in 0..3 {
            let mut axis: Vec<f64> = readings.iter().map(|r| r[k]).collect();
            axis.sort_by(f64::total_cmp);
            let median = axis[axis.len() / 2];
            if median.abs() > RAIL * STANDARD_GRAVITY {
                out.push(broken(
                    "railed",
                    format!(
                        "its {} axis reads {:+.2} g (median over all poses), more than gravity can give: stuck at the end of its range",
                        ["x", "y", "z"][k],
                        median / STANDARD_GRAVITY
                    ),
                ));
                break;
            }
        }
        if out.last().is_some_and(|b| &b.su == su) {
            continue;
        }
        // Far from |g| in every still pose: no working part reads that (bias and scale move a
        // reading's norm by a tenth at most). A driver's placeholder for a board that stopped
        // answering, (-1, -1, -1), reads 0.18 g.
        if readings
            .iter()
            .all(|r| (norm(r) / STANDARD_GRAVITY - 1.0).abs() > FAR_FROM_G)
        {
            let n = norm(readings[0]) / STANDARD_GRAVITY;
            let same = readings.iter().all(|r| *r == readings[0]);
            out.push(broken(
                "dead",
                format!(
                    "every still reading's norm is far from 1 g ({n:.2} g{}), which no working accelerometer at rest reads (a placeholder value for a board that does not answer, or a broken part)",
                    if same {
                        format!(
                            ", always ({:.3}, {:.3}, {:.3}) m/s²",
                            readings[0][0], readings[0][1], readings[0][2]
                        )
                    } else {
                        " in the first pose".into()
                    }
                ),
            ));
        }
    }
    out
}

/// An entry decided from the SUs whose rows agree, not from its own readings.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Inferred {
    /// The SU.
    pub su: String,
    /// The DoF.
    pub dof: String,
    /// The decision.
    pub active: bool,
}

/// The SUs of one move whose gravity turned unlike the others' (`turned`: angle, SU): those
/// outside the largest group that agrees within [`LONE_TURN_TOLERANCE`], when that group has at
/// least two and more than half of them and the others are a few (when no two agree, which is
/// right cannot be told here).
fn odd_turns(turned: &[(f64, usize)]) -> Vec<usize> {
    if turned.len() < 2 {
        return Vec::new();
    }
    let group = |centre: f64| {
        turned
            .iter()
            .filter(|(a, _)| (a - centre).abs() <= LONE_TURN_TOLERANCE)
            .count()
    };
    let (best, size) = turned
        .iter()
        .map(|&(a, _)| (a, group(a)))
        .max_by_key(|&(_, n)| n)
        .expect("at least two");
    let odd: Vec<usize> = turned
        .iter()
        .filter(|(a, _)| (a - best).abs() > LONE_TURN_TOLERANCE)
        .map(|&(_, u)| u)
        .collect();
    // Glitches are a few; many SUs turning otherwise is the move itself going wrong (the base
    // tilted), which the physics check reports.
    if size >= 2 && 2 * size > turned.len() && odd.len() <= (turned.len() / 5).max(2) {
        odd
    } else {
        Vec::new()
    }
}

/// The SUs of one move whose gravity turned further than the DoF travelled (`travel`, rad), which
/// no rotation about one axis can do (gravity turns by the travel at most, when the axis is
/// horizontal): glitches, unless at least [`TILT_GROUP`] of them agree on the turn within `agree`,
/// rad (the base tilted or another DoF slipped, which the physics check reports; two glitches
/// agree by chance too often to tell). A travel too small to tell is no law.
pub(super) fn beyond_travel(turned: &[(f64, usize)], travel: f64, agree: f64) -> Vec<usize> {
    if travel < MIN_TRAVEL {
        return Vec::new();
    }
    let limit = travel * (1.0 + TRAVEL_SLACK) + LONE_TURN_TOLERANCE;
    let beyond: Vec<f64> = turned
        .iter()
        .map(|&(a, _)| a)
        .filter(|&a| a > limit)
        .collect();
    turned
        .iter()
        .filter(|&&(a, _)| {
            a > limit && beyond.iter().filter(|&&b| (a - b).abs() <= agree).count() < TILT_GROUP
        })
        .map(|&(_, u)| u)
        .collect()
}

/// Whether an SU's `rest` reading is misread, judged by its move readings `reads` of the same
/// orientation, each with the travel of its DoF, rad: more than half of them (and at least three)
/// lie within `threshold` (largest axis) of their component-wise median, none lies within
/// `threshold` of the rest, and gravity turned from the rest to that median by more than those
/// moves' DoFs travelled. A true rest can be unlike most moves: DoFs about parallel axes that
/// travel alike all turn an SU they move to one reading (a UR arm's lift, elbow and wrist), but
/// never further than they travelled, while a glitch of |g|'s norm points anywhere.
fn rest_unlike_moves(rest: &[f64; 3], reads: &[(&[f64; 3], f64)], threshold: f64) -> bool {
    if reads.len() < 3 {
        return false;
    }
    let median: [f64; 3] = std::array::from_fn(|k| {
        let mut v: Vec<f64> = reads.iter().map(|(r, _)| r[k]).collect();
        v.sort_by(f64::total_cmp);
        v[v.len() / 2]
    });
    let off = |a: &[f64; 3], b: &[f64; 3]| (0..3).map(|k| (a[k] - b[k]).abs()).fold(0.0, f64::max);
    let agreeing: Vec<f64> = reads
        .iter()
        .filter(|(r, _)| off(r, &median) <= threshold)
        .map(|&(_, travel)| travel)
        .collect();
    if 2 * agreeing.len() <= reads.len()
        || off(rest, &median) <= threshold
        || reads.iter().any(|(r, _)| off(r, rest) <= threshold)
    {
        return false;
    }
    let travel = agreeing.iter().copied().fold(0.0, f64::max);
    travel < MIN_TRAVEL
        || angle_between(rest, &median) > travel * (1.0 + TRAVEL_SLACK) + LONE_TURN_TOLERANCE
}

/// `[o][d]`: whether DoF `d` clearly moved at least two SUs in orientation `o` (its axis was not
/// vertical there).
fn sighted_dofs(per: &[Vec<Vec<Option<f64>>>], clear: f64) -> Vec<Vec<bool>> {
    per.iter()
        .map(|o| {
            let nd = o.first().map_or(0, Vec::len);
            (0..nd)
                .map(|d| {
                    o.iter()
                        .filter(|row| row[d].is_some_and(|c| c > clear))
                        .count()
                        >= 2
                })
                .collect()
        })
        .collect()
}

/// The change behind every entry, the largest over the orientations that read it. An entry that
/// only orientations blind to the DoF (it moved no SU there: its axis was vertical) or none at all
/// could read, because misread readings were left out, is unknown: its segment mates
/// ([`segment_mates_say`]) and the tree ([`settle_by_tree`]) decide it, or it stays undecided.
/// Entries only one orientation supports are weighed by the tree too where it has conflicts.
/// Returns the changes, the entries decided so `(su, dof, active)`, the readings contradicted
/// (below) and the undecided entries `(su, dof)`.
///
/// First, a DoF turns gravity by the same angle for every SU it moves, so in an orientation where
/// it clearly moves at least two SUs, an SU it leaves clearly still is not downstream of it: an
/// activity of that SU in another orientation is a misread reading, left out (returned as
/// `(su, orientation, dof)`).
#[allow(clippy::type_complexity)]
fn combine_orientations(
    per: &mut [Vec<Vec<Option<f64>>>],
    (turns, doubt, led): (&[Vec<Vec<Option<f64>>>], &[Vec<f64>], &[bool]),
    threshold: f64,
    uncertainty_factor: f64,
) -> (
    Vec<Vec<f64>>,
    Vec<(usize, usize, bool)>,
    Vec<(usize, usize, usize)>,
    Vec<(usize, usize)>,
) {
    // SUs × DoFs.
    let size = (doubt.len(), doubt.first().map_or(0, Vec::len));
    let clear_still = threshold / uncertainty_factor;
    let contradicted = leave_out_contradicted(per, (size, led), threshold, uncertainty_factor);
    let (mut change, known, by_turns) = known_entries(per, turns, size, threshold, clear_still);
    let measured: Vec<Vec<bool>> = change
        .iter()
        .map(|row| row.iter().map(|&c| c > threshold).collect())
        .collect();
    let mut active = measured.clone();
    // First guesses: an unknown entry as the SUs whose other entries agree decide, when at least
    // two do and alike (the SU's segment mates); otherwise it is undecided unless the tree below
    // decides it. A suspicious entry stays.
    let mut undecided: Vec<(usize, usize)> = Vec::new();
    let questionable = questionable_entries(per, &active, &known, threshold);
    for &(u, d, _) in questionable.iter().filter(|q| q.2) {
        match segment_mates_say(&known, u, d) {
            Some(a) => active[u][d] = a,
            None => undecided.push((u, d)),
        }
    }
    settle_by_tree(&mut active, &questionable, &measured, doubt, &mut undecided);
    let mut inferred = Vec::new();
    for &(u, d, unknown) in &questionable {
        let decision = active[u][d];
        if decision != measured[u][d] {
            change[u][d] = if decision {
                typical_change(&change, u, d, threshold)
            } else {
                0.0
            };
        }
        if undecided.contains(&(u, d)) {
            continue;
        }
        if unknown || !decision {
            inferred.push((u, d, decision));
        }
    }
    inferred.extend(by_turns);
    (change, inferred, contradicted, undecided)
}

/// A DoF turns gravity by the same angle for every SU it moves: in an orientation where it
/// clearly moves at least two SUs, an SU it leaves clearly still is not downstream of it, and its
/// activity in another orientation is a misread reading, left out of `per`. Returns those
/// `(su, orientation, dof)`. DoFs `led` (with mimic followers, whose bodies turn about axes of
/// their own) are not judged.
fn leave_out_contradicted(
    per: &mut [Vec<Vec<Option<f64>>>],
    ((nu, nd), led): ((usize, usize), &[bool]),
    threshold: f64,
    uncertainty_factor: f64,
) -> Vec<(usize, usize, usize)> {
    let clear_still = threshold / uncertainty_factor;
    let sighted = sighted_dofs(per, threshold * uncertainty_factor);
    let mut contradicted = Vec::new();
    for u in 0..nu {
        for d in (0..nd).filter(|&d| !led.get(d).copied().unwrap_or(false)) {
            let still_where_sighted = (0..per.len())
                .any(|o| sighted[o][d] && per[o][u][d].is_some_and(|c| c < clear_still));
            if !still_where_sighted {
                continue;
            }
            for (o, p) in per.iter_mut().enumerate() {
                if p[u][d].is_some_and(|c| c > threshold) {
                    p[u][d] = None;
                    contradicted.push((u, o, d));
                }
            }
        }
    }
    contradicted
}

/// Every entry's change (the largest over the orientations that read it) and whether it is
/// known: `Some(active)`, or `None` where no orientation that sees the DoF could read the SU
/// clearly — unless the turns decide it (returned as `(su, dof, active)`, its change then read
/// as the SUs it turned with).
#[allow(clippy::type_complexity)]
fn known_entries(
    per: &[Vec<Vec<Option<f64>>>],
    turns: &[Vec<Vec<Option<f64>>>],
    (nu, nd): (usize, usize),
    threshold: f64,
    clear_still: f64,
) -> (
    Vec<Vec<f64>>,
    Vec<Vec<Option<bool>>>,
    Vec<(usize, usize, bool)>,
) {
    let blind: Vec<Vec<bool>> = per
        .iter()
        .map(|o| {
            (0..nd)
                .map(|d| !(0..nu).any(|u| o[u][d].is_some_and(|c| c > threshold)))
                .collect()
        })
        .collect();
    let unseen: Vec<bool> = (0..nd).map(|d| blind.iter().all(|o| o[d])).collect();
    let mut change = vec![vec![0.0; nd]; nu];
    let turned_with = turns_say(per, turns, threshold, clear_still);
    let mut by_turns = Vec::new();
    let mut known = vec![vec![None; nd]; nu];
    for u in 0..nu {
        for d in 0..nd {
            let readable: Vec<(usize, f64)> = per
                .iter()
                .enumerate()
                .filter_map(|(o, p)| p[u][d].map(|c| (o, c)))
                .collect();
            change[u][d] = readable.iter().map(|r| r.1).fold(0.0, f64::max);
            // Unknown: not seen moving, and every orientation that sees the DoF move SUs could
            // not read this one clearly (or, for a DoF seen moving no SU, some orientation could
            // not: that may be the one reading that would show it move).
            let clear = |c: f64| c > threshold || c < clear_still;
            let sighted = readable.iter().any(|&(o, c)| !blind[o][d] && clear(c));
            let lost =
                (0..per.len()).any(|o| (!blind[o][d] || unseen[d]) && per[o][u][d].is_none());
            known[u][d] = if change[u][d] > threshold || sighted || !lost {
                Some(change[u][d] > threshold)
            } else {
                turned_with(u, d).inspect(|&a| by_turns.push((u, d, a)))
            };
        }
    }
    for &(u, d, a) in &by_turns {
        change[u][d] = if a {
            typical_change(&change, u, d, threshold)
        } else {
            change[u][d].min(clear_still)
        };
    }
    (change, known, by_turns)
}

/// The entries the structure must weigh, `(su, dof, unknown)`: the unknown ones, and — where the
/// tree has conflicts — those that only one orientation supports (the other turned the DoF
/// about gravity, or saw the SU still; a misread reading would look the same) on an SU whose row
/// no other SU shares (a misread entry gives its SU such a row; weighing only those keeps large
/// skins fast).
fn questionable_entries(
    per: &[Vec<Vec<Option<f64>>>],
    active: &[Vec<bool>],
    known: &[Vec<Option<bool>>],
    threshold: f64,
) -> Vec<(usize, usize, bool)> {
    let (nu, nd) = (active.len(), active.first().map_or(0, Vec::len));
    let suspicious = |u: usize, d: usize| {
        (0..per.len())
            .filter(|&o| per[o][u][d].is_some_and(|c| c > threshold))
            .count()
            == 1
    };
    let conflicts = orphan_rows(active) > 0;
    let shared: Vec<bool> = (0..nu)
        .map(|u| (0..nu).any(|v| v != u && active[v] == active[u]))
        .collect();
    (0..nu)
        .flat_map(|u| (0..nd).map(move |d| (u, d)))
        .filter_map(|(u, d)| {
            let unknown = known[u][d].is_none();
            (unknown || (conflicts && !shared[u] && suspicious(u, d))).then_some((u, d, unknown))
        })
        .collect()
}

/// The median change of the SUs other than `u` that DoF `d` moves (for an entry decided active
/// without a reading of its own).
fn typical_change(change: &[Vec<f64>], u: usize, d: usize, threshold: f64) -> f64 {
    let mut c: Vec<f64> = (0..change.len())
        .filter(|&v| v != u && change[v][d] > threshold)
        .map(|v| change[v][d])
        .collect();
    c.sort_by(f64::total_cmp);
    c.get(c.len() / 2).copied().unwrap_or(2.0 * threshold)
}

/// Whether the turns of the moves say DoF `d` moves SU `u`: one DoF turns gravity by one angle
/// for every SU it moves, so where it clearly moved SUs by an angle well above the still SUs'
/// noise, an SU that turned by about that angle moved with them and one that barely turned did
/// not, whatever its change on one axis (a DoF whose axis is near vertical turns SUs too little
/// for the threshold to tell). `None` where no orientation tells, or they disagree.
fn turns_say<'a>(
    per: &'a [Vec<Vec<Option<f64>>>],
    turns: &'a [Vec<Vec<Option<f64>>>],
    threshold: f64,
    clear_still: f64,
) -> impl Fn(usize, usize) -> Option<bool> + 'a {
    let median = |mut v: Vec<f64>| {
        v.sort_by(f64::total_cmp);
        v.get(v.len() / 2).copied()
    };
    move |u: usize, d: usize| {
        let says: Vec<bool> = per
            .iter()
            .zip(turns)
            .filter_map(|(p, t)| {
                let turn = t[u][d]?;
                let of = |keep: &dyn Fn(f64) -> bool| -> Vec<f64> {
                    (0..p.len())
                        .filter(|&v| v != u && p[v][d].is_some_and(keep))
                        .filter_map(|v| t[v][d])
                        .collect()
                };
                let moved = median(of(&|c| c > threshold))?;
                let noise = median(of(&|c| c < clear_still)).unwrap_or(0.0);
                if moved < TURN_OVER_NOISE * noise.max(TURN_FLOOR) {
                    return None;
                }
                if (turn - moved).abs() < moved / 3.0 {
                    Some(true)
                } else if turn < moved / 3.0 {
                    Some(false)
                } else {
                    None
                }
            })
            .collect();
        (!says.is_empty() && says.iter().all(|&x| x == says[0])).then(|| says[0])
    }
}

/// What the SUs whose known entries all agree with SU `u`'s say of entry `(u, d)`, when at least
/// two of them know it and agree (the SU's segment mates); `None` otherwise (the one SU that
/// agrees may be its parent segment's, and where the segments before and after `d` both agree,
/// which one `u` is on cannot be told). The SUs known wherever `u` is are asked first: one with
/// unknown entries of its own agrees with more than its mates (a child segment's SU, unknown
/// where `u` is still, agrees with `u`), so it only votes when they do not settle it.
fn segment_mates_say(known: &[Vec<Option<bool>>], u: usize, d: usize) -> Option<bool> {
    let agree = |v: usize, strict: bool| {
        v != u
            && known[u].iter().zip(&known[v]).all(|pair| match pair {
                (Some(a), Some(b)) => a == b,
                (Some(_), None) => !strict,
                _ => true,
            })
    };
    let say = |strict: bool| {
        let votes: Vec<bool> = (0..known.len())
            .filter(|&v| agree(v, strict))
            .filter_map(|v| known[v][d])
            .collect();
        (votes.len() >= 2 && votes.iter().all(|&a| a == votes[0])).then(|| votes[0])
    };
    say(true).or_else(|| say(false))
}

/// Settles the `questionable` entries `(su, dof, unknown)` of `active` by the tree: the flip that
/// leaves the fewest rows without a parent ([`orphan_rows`]), one at a time, while one helps;
/// among equals, the one that overrides the fewest readings (`measured`; an unknown entry has
/// none), then the one with fewer distinct rows (a misread entry gives its SU a row of its own),
/// then the one whose reading is most in `doubt` (how far its turn went beyond the DoF's travel and
/// its norm from |g|). An undecided entry (no reading, no segment mates) flips only to remove a
/// conflict, and stays undecided if neither value adds one.
fn settle_by_tree(
    active: &mut [Vec<bool>],
    questionable: &[(usize, usize, bool)],
    measured: &[Vec<bool>],
    doubt: &[Vec<f64>],
    undecided: &mut Vec<(usize, usize)>,
) {
    let cost = |active: &[Vec<bool>]| {
        let overrides = questionable
            .iter()
            .filter(|&&(u, d, unknown)| !unknown && active[u][d] != measured[u][d])
            .count();
        let mut rows = active.to_vec();
        rows.sort();
        rows.dedup();
        (orphan_rows(active), overrides, rows.len())
    };
    for _ in 0..questionable.len() {
        let now = cost(active);
        let best = questionable
            .iter()
            .filter_map(|&(u, d, _)| {
                active[u][d] = !active[u][d];
                let c = cost(active);
                active[u][d] = !active[u][d];
                // An entry nothing could read is decided only by a conflict it removes: fewer
                // rows alone is no evidence that an SU shares a segment.
                let blind_guess = undecided.contains(&(u, d)) && c.0 >= now.0;
                (!blind_guess).then_some((c, doubt[u][d], u, d))
            })
            .min_by(|x, y| x.0.cmp(&y.0).then(y.1.total_cmp(&x.1)));
        match best {
            Some((c, _, u, d)) if c < now => {
                active[u][d] = !active[u][d];
                undecided.retain(|&x| x != (u, d));
            }
            _ => break,
        }
    }
    let now = orphan_rows(active);
    undecided.retain(|&(u, d)| {
        active[u][d] = !active[u][d];
        let n = orphan_rows(active);
        active[u][d] = !active[u][d];
        n == now
    });
}

/// How far `active` is from a tree: the distinct non-empty rows that have no parent or several (no
/// other row, or the empty one, lacks exactly one of their joints, or several do; columns equal
/// over every SU form one joint), plus the joints whose rows do not all hold the shortest of them,
/// plus the joints that directly move segments hanging from different parents.
fn orphan_rows(active: &[Vec<bool>]) -> usize {
    let nd = active.first().map_or(0, Vec::len);
    let column = |d: usize| active.iter().map(|row| row[d]).collect::<Vec<bool>>();
    let mut joints: Vec<Vec<bool>> = Vec::new();
    let mut joint_of = vec![usize::MAX; nd];
    for (d, joint) in joint_of.iter_mut().enumerate() {
        let c = column(d);
        if !c.iter().any(|&x| x) {
            continue;
        }
        *joint = match joints.iter().position(|j| *j == c) {
            Some(j) => j,
            None => {
                joints.push(c);
                joints.len() - 1
            }
        };
    }
    let mut rows: Vec<Vec<usize>> = active
        .iter()
        .map(|row| {
            let mut r: Vec<usize> = (0..nd).filter(|&d| row[d]).map(|d| joint_of[d]).collect();
            r.sort_unstable();
            r.dedup();
            r
        })
        .collect();
    rows.sort();
    rows.dedup();
    // A row's parents: the rows (or the empty one) it holds all but one joint of. A tree gives
    // every row exactly one; none is an orphan, two a segment hanging from two (crossing joints).
    let parents = |r: &Vec<usize>| {
        r.iter()
            .filter(|&&j| {
                let parent: Vec<usize> = r.iter().copied().filter(|&x| x != j).collect();
                parent.is_empty() || rows.contains(&parent)
            })
            .count()
    };
    let orphans = rows
        .iter()
        .filter(|r| !r.is_empty())
        .filter(|r| parents(r) != 1)
        .count();
    // A joint moves one segment and what hangs from it: every row with the joint holds the
    // shortest such row.
    let split = (0..joints.len())
        .filter(|&j| {
            let with: Vec<&Vec<usize>> = rows.iter().filter(|r| r.contains(&j)).collect();
            let shortest = with.iter().min_by_key(|r| r.len());
            shortest.is_some_and(|s| with.iter().any(|r| !s.iter().all(|x| r.contains(x))))
        })
        .count();
    // A joint moves one segment directly, hanging from one parent: rows that it ends (the row
    // less it is a row, or empty) with different parents put it in two places (an SU on the first
    // link read as moved by the fourth joint hangs the fourth joint from the first link too).
    let crossing = (0..joints.len())
        .filter(|&j| {
            let mut parents: Vec<Vec<usize>> = rows
                .iter()
                .filter(|r| r.contains(&j))
                .map(|r| {
                    r.iter()
                        .copied()
                        .filter(|&x| x != j)
                        .collect::<Vec<usize>>()
                })
                .filter(|p| p.is_empty() || rows.contains(p))
                .collect();
            parents.sort();
            parents.dedup();
            parents.len() > 1
        })
        .count();
    orphans + split + crossing
}

/// A structure-experiment reading left out as misread.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Misread {
    /// The SU.
    pub su: String,
    /// The base orientation (1-based).
    pub orientation: usize,
    /// The move's DoF, or `None` for the rest reading.
    pub dof: Option<String>,
    /// Its norm, g.
    pub norm_g: f64,
    /// The SU's usual norm, g.
    pub expected_g: f64,
}

impl ActivityMatrix {
    /// Whether DoF `d` is prismatic.
    pub fn is_prismatic(&self, d: usize) -> bool {
        self.prismatic.get(d).copied().unwrap_or(false)
    }

    /// Whether DoF `d`'s column was read from what it accelerated (its axis stood vertical).
    pub fn is_upright(&self, d: usize) -> bool {
        self.upright.get(d).copied().unwrap_or(false)
    }

    /// Whether DoF `d` is a mimic DoF (it moves only with its leader and has no column).
    pub fn is_follower(&self, d: usize) -> bool {
        self.leader_of.get(d).is_some_and(Option::is_some)
    }

    /// Whether DoF `d` has mimic followers (its moves turn their bodies by other rotations).
    pub fn has_followers(&self, d: usize) -> bool {
        self.leader_of.contains(&Some(d))
    }

    /// Whether DoF `d` moves SU `u`.
    pub fn is_active(&self, u: usize, d: usize) -> bool {
        self.explored[d] && self.change[u][d] > self.threshold
    }

    /// Whether the entry lies within the uncertainty band around the threshold.
    pub fn is_uncertain(&self, u: usize, d: usize) -> bool {
        let c = self.change[u][d];
        self.explored[d]
            && c >= self.threshold / self.uncertainty_factor
            && c <= self.threshold * self.uncertainty_factor
    }
}

/// Builds the activity matrix from the structure experiment of a measurement set.
pub fn activity_matrix(
    set: &MeasurementSet,
    config: &ExploreConfig,
) -> Result<ActivityMatrix, ExploreError> {
    check_config(config)?;
    let structure = set
        .structure
        .as_ref()
        .ok_or(ExploreError::NoStructureExperiment)?;
    let screen = Screen::new(set, structure);
    let threshold = config.threshold * STANDARD_GRAVITY;
    let rest_misread = screen.rest_misread(threshold);
    let mut moves = screen.read_moves(&rest_misread, config);
    if !moves.explored.iter().any(|&e| e) {
        return Err(ExploreError::NoMoves);
    }
    screen.rebuild_rests(&rest_misread, &mut moves.per, config);
    let leader_of = mimic_leaders(set);
    // A DoF with mimic followers turns each body they drive about an axis of its own: an SU it
    // leaves still in one orientation may turn in the other.
    let led: Vec<bool> = (0..set.dofs.len())
        .map(|d| leader_of.contains(&Some(d)))
        .collect();
    let (change, mut inferred, contradicted, mut undecided) = combine_orientations(
        &mut moves.per,
        (&moves.turns, &moves.doubt, &led),
        threshold,
        config.uncertainty_factor,
    );
    let prismatic: Vec<bool> = (0..set.dofs.len())
        .map(|d| set.dof_kind(d) == DofKind::Prismatic)
        .collect();
    let mut change = change;
    let mut explored = moves.explored;
    prismatic_columns(set, &prismatic, &mut change, &mut explored, threshold);
    led_columns(set, &prismatic, &mut change, threshold);
    let upright = upright_columns(
        set,
        &prismatic,
        &mut change,
        threshold,
        config.uncertainty_factor,
    );
    let is_broken = |u: usize| screen.is_broken[u];
    // Prismatic columns come from the training experiment, and mimic DoFs have none.
    let own_column = |d: usize| !prismatic[d] && leader_of[d].is_none();
    inferred.retain(|&(u, d, _)| !is_broken(u) && own_column(d));
    undecided.retain(|&(u, d)| !is_broken(u) && own_column(d));
    let contradicted: Vec<_> = contradicted
        .into_iter()
        .filter(|&(_, _, d)| own_column(d))
        .collect();
    let mut misread = moves.misreads;
    for (u, o, d) in contradicted {
        let orientation = &structure.orientations[o];
        if let Some(mv) = orientation.moves.iter().find(|m| m.dof == set.dofs[d]) {
            misread.push(screen.misread_at(u, o, Some(&set.dofs[d]), &mv.readings[u]));
        }
    }
    let mut active: Vec<Vec<bool>> = change
        .iter()
        .map(|row| {
            row.iter()
                .zip(&explored)
                .map(|(&c, &e)| e && c > threshold)
                .collect()
        })
        .collect();
    for (u, d) in near_upright_axes(&mut active, &upright) {
        change[u][d] = typical_change(&change, u, d, threshold);
        inferred.push((u, d, true));
    }
    let mimic_driven = super::mimic::mimic_driven(set, &active, &screen.is_broken);
    let rest_turn = rest_turns(structure, &rest_misread, set.sus.len());
    Ok(ActivityMatrix {
        sus: set.sus.clone(),
        dofs: set.dofs.clone(),
        change,
        explored,
        prismatic: if prismatic.contains(&true) {
            prismatic
        } else {
            Vec::new()
        },
        upright: if upright.contains(&true) {
            upright
        } else {
            Vec::new()
        },
        threshold,
        uncertainty_factor: config.uncertainty_factor,
        orientations: structure.orientations.len(),
        rest_turn,
        misread,
        inferred: inferred
            .into_iter()
            .map(|(u, d, active)| Inferred {
                su: set.sus[u].clone(),
                dof: set.dofs[d].clone(),
                active,
            })
            .collect(),
        undecided: undecided
            .into_iter()
            .map(|(u, d)| (set.sus[u].clone(), set.dofs[d].clone()))
            .collect(),
        leader_of: if leader_of.iter().any(Option::is_some) {
            leader_of
        } else {
            Vec::new()
        },
        mimic_driven,
        broken: screen.broken,
    })
}

/// Per DoF of `set`, the index of the DoF it follows as a mimic joint.
fn mimic_leaders(set: &MeasurementSet) -> Vec<Option<usize>> {
    (0..set.dofs.len())
        .map(|d| {
            set.mimic
                .get(&set.dofs[d])
                .and_then(|m| set.dof_index(&m.leader))
        })
        .collect()
}

/// Per SU, the angle its rest reading turned from the first orientation to the second (`None`
/// with one orientation, or where either rest reading was misread), for `sus` SUs.
fn rest_turns(
    structure: &StructureExperiment,
    rest_misread: &[Vec<bool>],
    sus: usize,
) -> Vec<Option<f64>> {
    (0..sus)
        .map(|u| match structure.orientations.as_slice() {
            [first, second, ..] if !rest_misread[0][u] && !rest_misread[1][u] => {
                Some(angle_between(&first.rest[u], &second.rest[u]))
            }
            _ => None,
        })
        .collect()
}

/// The columns of the prismatic DoFs, from the training experiment: a prismatic DoF turns no
/// gravity, so its structure move changes no static reading, but its pattern accelerates every SU
/// it carries by `α s` along its axis at the peak (`α = 2πfA`, `s` the pattern scale) and no other
/// SU at all. `change[u][d]` becomes the median over the poses of the norm of SU `u`'s dynamic
/// reading of `d`, times `threshold / (α s / 2)`: an SU is moved when it typically read more than
/// half the pattern's peak. A DoF with no dynamic reading is not explored.
fn prismatic_columns(
    set: &MeasurementSet,
    prismatic: &[bool],
    change: &mut [Vec<f64>],
    explored: &mut [bool],
    threshold: f64,
) {
    for d in (0..set.dofs.len()).filter(|&d| prismatic[d]) {
        explored[d] = false;
        for row in change.iter_mut() {
            row[d] = 0.0;
        }
        // Per SU, the typical reading in units of what the DoF's pattern (or a unit of its
        // acceleration) gives an SU it carries.
        let carried = dynamic_medians(set, d)
            .map(|(medians, peak)| medians.into_iter().map(|m| m / peak).collect())
            .or_else(|| accelerated_medians(set, d));
        let Some(carried) = carried else {
            continue;
        };
        explored[d] = true;
        for (row, c) in change.iter_mut().zip(carried) {
            row[d] = c * threshold / 0.5;
        }
    }
}

/// Per SU, the median norm of the training experiment's dynamic readings of DoF `d`, and the
/// peak of the prismatic pattern; `None` without such readings.
fn dynamic_medians(set: &MeasurementSet, d: usize) -> Option<(Vec<f64>, f64)> {
    let training = set.training.as_ref()?;
    let peak = training.pattern.of(DofKind::Prismatic).peak_acceleration();
    let readings: Vec<&Vec<[f64; 3]>> = training
        .poses
        .iter()
        .filter_map(|p| p.dynamic.get(&set.dofs[d]))
        .collect();
    if readings.is_empty() || peak.is_nan() || peak <= 0.0 {
        return None;
    }
    Some((per_su_median(&readings, set.sus.len()), peak))
}

/// How many of its standard deviations are taken off the norm of a move's gain
/// ([`crate::measurements::Move::accelerated`]) before it counts: the norm of a gain that is only
/// noise (three components of deviation σ) exceeds 3σ once in 35, and then by little. A move the
/// motion record barely holds (a wrist's on a soft servo: 0.04 ± 0.03 m on SUs it does not
/// carry) so tells nothing instead of carrying every SU.
const GAIN_DEVIATIONS: f64 = 3.0;

/// Per SU, the median over the structure moves of DoF `d` of what it read per unit of the DoF's
/// acceleration on the way ([`crate::measurements::Move::accelerated`]): the norm, less
/// [`GAIN_DEVIATIONS`] of its standard deviation where the move gives one, and at least 0;
/// `None` where no move has it.
fn accelerated_medians(set: &MeasurementSet, d: usize) -> Option<Vec<f64>> {
    let moves: Vec<&crate::measurements::Move> = set
        .structure
        .iter()
        .flat_map(|s| &s.orientations)
        .flat_map(|o| &o.moves)
        .filter(|m| m.dof == set.dofs[d] && m.accelerated.len() == set.sus.len())
        .collect();
    let told = |m: &crate::measurements::Move, u: usize| {
        let sd = match m.accelerated_sd.get(u) {
            None => 0.0,
            Some(sd) => sd.unwrap_or(f64::INFINITY),
        };
        (norm(&m.accelerated[u]) - GAIN_DEVIATIONS * sd).max(0.0)
    };
    (!moves.is_empty()).then(|| {
        (0..set.sus.len())
            .map(|u| median(moves.iter().map(|m| told(m, u)).collect()))
            .collect()
    })
}

/// The median of `values` (the upper one of an even count).
fn median(mut values: Vec<f64>) -> f64 {
    values.sort_by(f64::total_cmp);
    values[values.len() / 2]
}

/// Per SU, the median norm of its reading in `readings` (one reading per SU each).
fn per_su_median(readings: &[&Vec<[f64; 3]>], sus: usize) -> Vec<f64> {
    (0..sus)
        .map(|u| median(readings.iter().map(|r| norm(&r[u])).collect()))
        .collect()
}

/// The columns of revolute DoFs with mimic followers, completed from the training experiment: a
/// follower may carry a body without turning it against the leader's parent (a parallel
/// gripper's fingertip stays level), which no static reading sees, while the leader's pattern
/// accelerates it. An SU whose dynamic reading of the DoF typically exceeds half the peak of a
/// point 0.1 m from its axis ([`crate::model::PRISMATIC_PATTERN_SCALE`]) is moved by it.
fn led_columns(set: &MeasurementSet, prismatic: &[bool], change: &mut [Vec<f64>], threshold: f64) {
    let scale = crate::model::PRISMATIC_PATTERN_SCALE;
    for d in (0..set.dofs.len()).filter(|&d| !prismatic[d] && !set.followers_of(d).is_empty()) {
        let Some(arm) = lever_arms(set, d) else {
            continue;
        };
        for (row, a) in change.iter_mut().zip(arm) {
            row[d] = row[d].max(a * threshold / (0.5 * scale));
        }
    }
}

/// Per SU, the typical lever arm about revolute DoF `d` its readings give, m: the training
/// experiment's dynamic readings of `d` per unit of the pattern's peak, or what the structure
/// moves accelerated per rad/s²; `None` without either.
fn lever_arms(set: &MeasurementSet, d: usize) -> Option<Vec<f64>> {
    let scale = crate::model::PRISMATIC_PATTERN_SCALE;
    dynamic_medians(set, d)
        .map(|(medians, peak)| medians.into_iter().map(|m| m * scale / peak).collect())
        .or_else(|| accelerated_medians(set, d))
}

/// The lever arm beyond which an SU counts as moved by a revolute DoF whose structure move turned
/// no gravity, m: the regression on a 0.3 rad move leaves under 2 mm on SUs it does not carry,
/// and an SU 1 cm from the axis (skin on a link's surface is 2–8 cm from its centre line) reads
/// twice this.
pub(super) const UPRIGHT_LEVER: f64 = 0.005;

/// The columns of revolute DoFs whose axis stood (nearly) vertical in every base orientation of
/// the structure experiment, completed from what they accelerated: turning about gravity changes
/// no static reading, so no SU's change reaches `uncertainty_factor` times the threshold, while
/// the move accelerates every SU the DoF carries by its lever arm
/// ([`crate::measurements::Move::accelerated`]). An SU whose typical lever arm exceeds
/// [`UPRIGHT_LEVER`] is moved by it; one on the axis itself stays unseen, as in any base
/// orientation's gravity along the axis. Returns which DoFs' columns were completed so.
fn upright_columns(
    set: &MeasurementSet,
    prismatic: &[bool],
    change: &mut [Vec<f64>],
    threshold: f64,
    uncertainty_factor: f64,
) -> Vec<bool> {
    let mut upright = vec![false; set.dofs.len()];
    for d in (0..set.dofs.len()).filter(|&d| !prismatic[d] && set.followers_of(d).is_empty()) {
        let largest = change.iter().map(|row| row[d]).fold(0.0, f64::max);
        if largest >= threshold * uncertainty_factor {
            continue;
        }
        // A move is this DoF alone, regressed over hundreds of blocks (under 2 mm where it
        // carries nothing); a pattern may run with other DoFs' at once, and one dynamic
        // reading's noise is some 15 mm of lever arm.
        let Some(arm) = accelerated_medians(set, d) else {
            continue;
        };
        upright[d] = true;
        for (row, a) in change.iter_mut().zip(arm) {
            row[d] = row[d].max(a * threshold / UPRIGHT_LEVER);
        }
    }
    upright
}

/// The entries of `upright` columns ([`upright_columns`]) that make an SU a segment mate of
/// others: an SU on (or within a few mm of) an upright axis feels neither the gravity nor the
/// acceleration of its turn, so its row lacks that DoF and does not fit the tree. For each SU
/// whose row no other SU shares, the candidates are the other SUs' rows that hold its row plus
/// upright DoFs only; the candidate that leaves the fewest conflicts in the tree
/// ([`orphan_rows`]), then adds the fewest entries, is taken while one lowers the conflicts. Those
/// entries are set in `active` and returned `(su, dof)`.
fn near_upright_axes(active: &mut [Vec<bool>], upright: &[bool]) -> Vec<(usize, usize)> {
    let now = orphan_rows(active);
    if !upright.contains(&true) || now == 0 {
        return Vec::new();
    }
    // The greedy choice can be a tie that leads astray (an SU moved to the next segment instead
    // of its mate to its own): every first step is followed to its end, and the ending with the
    // fewest conflicts, then the fewest entries added, is kept.
    let mut best: Option<(usize, Vec<(usize, usize)>)> = None;
    for (u, adds) in upright_candidates(active, upright) {
        let mut trial = active.to_vec();
        for &d in &adds {
            trial[u][d] = true;
        }
        if orphan_rows(&trial) >= now {
            continue;
        }
        let mut added: Vec<(usize, usize)> = adds.iter().map(|&d| (u, d)).collect();
        added.extend(greedy_upright(&mut trial, upright));
        let ending = (orphan_rows(&trial), added);
        if best
            .as_ref()
            .is_none_or(|b| (ending.0, ending.1.len()) < (b.0, b.1.len()))
        {
            best = Some(ending);
        }
    }
    let Some((_, mut added)) = best else {
        return Vec::new();
    };
    for &(u, d) in &added {
        active[u][d] = true;
    }
    added.sort_unstable();
    added
}

/// The candidate additions of [`near_upright_axes`]: per SU alone on its row, each distinct set
/// of upright DoFs that makes its row another SU's.
fn upright_candidates(active: &[Vec<bool>], upright: &[bool]) -> Vec<(usize, Vec<usize>)> {
    let nu = active.len();
    let mut candidates = Vec::new();
    for u in (0..nu).filter(|&u| (0..nu).all(|v| v == u || active[v] != active[u])) {
        let mut tried: Vec<Vec<usize>> = Vec::new();
        for v in (0..nu).filter(|&v| v != u) {
            let holds = active[u].iter().zip(&active[v]).all(|(&m, &t)| !m || t);
            let adds: Vec<usize> = (0..upright.len())
                .filter(|&d| active[v][d] && !active[u][d])
                .collect();
            if holds
                && !adds.is_empty()
                && adds.iter().all(|&d| upright[d])
                && !tried.contains(&adds)
            {
                tried.push(adds.clone());
                candidates.push((u, adds));
            }
        }
    }
    candidates
}

/// From `active`, the candidate ([`upright_candidates`]) that leaves the fewest conflicts, then
/// adds the fewest entries, taken while one lowers the conflicts; returns the entries added.
fn greedy_upright(active: &mut [Vec<bool>], upright: &[bool]) -> Vec<(usize, usize)> {
    let mut added = Vec::new();
    loop {
        let now = orphan_rows(active);
        if now == 0 {
            break;
        }
        let mut best: Option<((usize, usize), usize, Vec<usize>)> = None;
        for (u, adds) in upright_candidates(active, upright) {
            let row = active[u].clone();
            for &d in &adds {
                active[u][d] = true;
            }
            let cost = (orphan_rows(active), adds.len());
            active[u] = row;
            if cost.0 < now && best.as_ref().is_none_or(|b| cost < b.0) {
                best = Some((cost, u, adds));
            }
        }
        let Some((_, u, adds)) = best else {
            break;
        };
        for d in adds {
            active[u][d] = true;
            added.push((u, d));
        }
    }
    added
}

fn check_config(config: &ExploreConfig) -> Result<(), ExploreError> {
    if !(config.threshold.is_finite() && config.threshold > 0.0) {
        return Err(ExploreError::InvalidSetting {
            setting: "threshold",
            reason: format!("{} g must be positive", config.threshold),
        });
    }
    if !(config.uncertainty_factor.is_finite() && config.uncertainty_factor >= 1.0) {
        return Err(ExploreError::InvalidSetting {
            setting: "uncertainty_factor",
            reason: format!("{} must be at least 1", config.uncertainty_factor),
        });
    }
    Ok(())
}

fn norm(r: &[f64; 3]) -> f64 {
    r.iter().map(|x| x * x).sum::<f64>().sqrt()
}

/// The largest change of any axis between two readings.
fn largest_change(before: &[f64; 3], after: &[f64; 3]) -> f64 {
    (0..3)
        .map(|k| (after[k] - before[k]).abs())
        .fold(0.0, f64::max)
}

/// What the structure experiment's moves read, per orientation `o`, SU `u` and DoF `d`.
struct MoveReadings {
    /// The change, `None` where not moved or misread.
    per: Vec<Vec<Vec<Option<f64>>>>,
    /// The angle gravity turned by, where `per` reads the change.
    turns: Vec<Vec<Vec<Option<f64>>>>,
    /// `[u][d]`: how doubtful the turn is (see [`settle_by_tree`]).
    doubt: Vec<Vec<f64>>,
    /// Whether each DoF was moved at all.
    explored: Vec<bool>,
    /// The readings left out.
    misreads: Vec<Misread>,
}

/// Which static readings to trust: every static reading's norm is the SU's |g| (up to its bias
/// and scale), so one far from the SU's median norm is misread; broken SUs read nothing, so none
/// of theirs is a misread.
struct Screen<'a> {
    set: &'a MeasurementSet,
    structure: &'a StructureExperiment,
    /// Per SU, the median norm of its readings, m/s².
    expected: Vec<f64>,
    broken: Vec<BrokenSu>,
    is_broken: Vec<bool>,
}

impl<'a> Screen<'a> {
    fn new(set: &'a MeasurementSet, structure: &'a StructureExperiment) -> Self {
        let expected = (0..set.sus.len())
            .map(|u| {
                let mut norms: Vec<f64> = structure
                    .orientations
                    .iter()
                    .flat_map(|o| {
                        std::iter::once(&o.rest[u]).chain(o.moves.iter().map(|m| &m.readings[u]))
                    })
                    .map(norm)
                    .collect();
                norms.sort_by(f64::total_cmp);
                norms[norms.len() / 2]
            })
            .collect();
        let broken = broken_sus(set);
        let is_broken = set
            .sus
            .iter()
            .map(|su| broken.iter().any(|b| b.su == *su))
            .collect();
        Self {
            set,
            structure,
            expected,
            broken,
            is_broken,
        }
    }

    fn misread(&self, u: usize, r: &[f64; 3]) -> bool {
        !self.is_broken[u]
            && (norm(r) - self.expected[u]).abs() > MISREAD_TOLERANCE * STANDARD_GRAVITY
    }

    /// The record of SU `u`'s reading `r` left out in orientation index `o`.
    fn misread_at(&self, u: usize, o: usize, dof: Option<&str>, r: &[f64; 3]) -> Misread {
        Misread {
            su: self.set.sus[u].clone(),
            orientation: o + 1,
            dof: dof.map(str::to_string),
            norm_g: norm(r) / STANDARD_GRAVITY,
            expected_g: self.expected[u] / STANDARD_GRAVITY,
        }
    }

    /// `[o][u]`: a rest reading is misread if its norm is off, or if it is unlike what the SU
    /// read in most moves of its orientation while those agree ([`rest_unlike_moves`]: most DoFs
    /// leave an SU still, so a glitch of |g|'s norm at rest shows as every move turning it).
    fn rest_misread(&self, threshold: f64) -> Vec<Vec<bool>> {
        self.structure
            .orientations
            .iter()
            .map(|o| {
                (0..self.set.sus.len())
                    .map(|u| {
                        let reads: Vec<(&[f64; 3], f64)> = o
                            .moves
                            .iter()
                            .filter(|m| !self.misread(u, &m.readings[u]))
                            .map(|m| {
                                let d = self
                                    .set
                                    .dof_index(&m.dof)
                                    .expect("validated measurement set");
                                (&m.readings[u], (m.pose[d] - o.rest_pose[d]).abs())
                            })
                            .collect();
                        self.misread(u, &o.rest[u])
                            || rest_unlike_moves(&o.rest[u], &reads, threshold)
                    })
                    .collect()
            })
            .collect()
    }

    /// How far a move of DoF `d` can turn an SU, relative to its travel: 1, plus the multipliers
    /// of the mimic DoFs that follow it (a chain of them turns its last body by their sum).
    fn travel_factor(&self, d: usize) -> f64 {
        1.0 + self
            .set
            .followers_of(d)
            .iter()
            .filter_map(|&f| self.set.mimic.get(&self.set.dofs[f]))
            .map(|m| m.multiplier.abs())
            .sum::<f64>()
    }

    /// Every move's changes and turns against the rest, leaving out misread readings: a norm off
    /// |g|, a turn beyond the DoF's travel ([`beyond_travel`]), or a lone turn unlike the clear
    /// majority's ([`odd_turns`]).
    fn read_moves(&self, rest_misread: &[Vec<bool>], config: &ExploreConfig) -> MoveReadings {
        let (nu, nd) = (self.set.sus.len(), self.set.dofs.len());
        let no = self.structure.orientations.len();
        let mut out = MoveReadings {
            per: vec![vec![vec![None; nd]; nu]; no],
            turns: vec![vec![vec![None; nd]; nu]; no],
            doubt: vec![vec![0.0; nd]; nu],
            explored: vec![false; nd],
            misreads: Vec::new(),
        };
        let clear = config.threshold * STANDARD_GRAVITY * config.uncertainty_factor;
        for (oi, orientation) in self.structure.orientations.iter().enumerate() {
            for (u, &bad) in rest_misread[oi].iter().enumerate() {
                if bad {
                    out.misreads
                        .push(self.misread_at(u, oi, None, &orientation.rest[u]));
                }
            }
            for mv in &orientation.moves {
                let d = self
                    .set
                    .dof_index(&mv.dof)
                    .expect("validated measurement set");
                out.explored[d] = true;
                let mut changes: Vec<Option<f64>> = Vec::with_capacity(nu);
                for (u, (before, after)) in orientation.rest.iter().zip(&mv.readings).enumerate() {
                    if self.misread(u, after) {
                        out.misreads
                            .push(self.misread_at(u, oi, Some(&mv.dof), after));
                        changes.push(None);
                        continue;
                    }
                    changes.push((!rest_misread[oi][u]).then(|| largest_change(before, after)));
                }
                // One DoF turns everything it moves by one rotation, by its travel at most: the
                // SUs it clearly moved agree on the angle gravity turned by.
                let turned: Vec<(f64, usize)> = (0..nu)
                    .filter(|&u| changes[u].is_some_and(|c| c > clear))
                    .map(|u| (angle_between(&orientation.rest[u], &mv.readings[u]), u))
                    .collect();
                // Mimic DoFs that follow this one turn their bodies too, in a chain by their
                // own travels on top of its.
                let led = self.set.followers_of(d);
                let travel = (mv.pose[d] - orientation.rest_pose[d]).abs() * self.travel_factor(d);
                let beyond = beyond_travel(&turned, travel, super::checks::RIGID_TOLERANCE);
                let turned: Vec<(f64, usize)> = turned
                    .into_iter()
                    .filter(|(_, u)| !beyond.contains(u))
                    .collect();
                // How doubtful each turn is, for the tree to weigh: how far it went beyond the
                // travel, and how far its norm is from |g|, both relative.
                for &(angle, u) in &turned {
                    let excess = (angle - travel).max(0.0) / travel.max(MIN_TRAVEL);
                    let off = (norm(&mv.readings[u]) - self.expected[u]).abs() / self.expected[u];
                    out.doubt[u][d] = f64::max(out.doubt[u][d], excess + off);
                }
                // A DoF with followers turns each body they drive by its own rotation: unlike
                // turns are no glitch there.
                let odd = if led.is_empty() {
                    odd_turns(&turned)
                } else {
                    Vec::new()
                };
                for u in beyond.into_iter().chain(odd) {
                    out.misreads
                        .push(self.misread_at(u, oi, Some(&mv.dof), &mv.readings[u]));
                    changes[u] = None;
                }
                // Every move of a DoF is evidence (a move out, and a return that misses the rest
                // pose by a degree): the largest change read counts, with its turn.
                for (u, c) in changes.into_iter().enumerate() {
                    let c = c.filter(|_| !self.is_broken[u]);
                    if let Some(c) = c.filter(|&c| out.per[oi][u][d].is_none_or(|p| c > p)) {
                        out.per[oi][u][d] = Some(c);
                        out.turns[oi][u][d] =
                            Some(angle_between(&orientation.rest[u], &mv.readings[u]));
                    }
                }
            }
        }
        out
    }

    /// A misread rest reading: the rest is what the SU read in the moves of DoFs that, where they
    /// visibly turn other SUs, leave it still; its other entries are measured against that.
    fn rebuild_rests(
        &self,
        rest_misread: &[Vec<bool>],
        per: &mut [Vec<Vec<Option<f64>>>],
        config: &ExploreConfig,
    ) {
        let threshold = config.threshold * STANDARD_GRAVITY;
        let sighted = sighted_dofs(per, threshold * config.uncertainty_factor);
        let clear_still = threshold / config.uncertainty_factor;
        let dof = |mv: &crate::measurements::Move| {
            self.set
                .dof_index(&mv.dof)
                .expect("validated measurement set")
        };
        for (oi, orientation) in self.structure.orientations.iter().enumerate() {
            for u in (0..self.set.sus.len()).filter(|&u| rest_misread[oi][u]) {
                let still: Vec<&[f64; 3]> = orientation
                    .moves
                    .iter()
                    .filter(|mv| !self.misread(u, &mv.readings[u]))
                    .filter(|mv| {
                        (0..per.len()).any(|o| {
                            o != oi
                                && sighted[o][dof(mv)]
                                && per[o][u][dof(mv)].is_some_and(|c| c < clear_still)
                        })
                    })
                    .map(|mv| &mv.readings[u])
                    .collect();
                if still.is_empty() {
                    continue;
                }
                let rest: [f64; 3] = std::array::from_fn(|k| {
                    let mut v: Vec<f64> = still.iter().map(|r| r[k]).collect();
                    v.sort_by(f64::total_cmp);
                    v[v.len() / 2]
                });
                // Each DoF's largest change over its moves, as `read_moves` keeps it.
                let mut rebuilt: Vec<Option<f64>> = vec![None; per[oi][u].len()];
                for mv in &orientation.moves {
                    if !self.misread(u, &mv.readings[u]) {
                        let c = largest_change(&rest, &mv.readings[u]);
                        let entry = &mut rebuilt[dof(mv)];
                        *entry = Some(entry.map_or(c, |p| p.max(c)));
                    }
                }
                for (d, c) in rebuilt.into_iter().enumerate() {
                    if c.is_some() {
                        per[oi][u][d] = c;
                    }
                }
            }
        }
    }
}

pub(super) fn angle_between(a: &[f64; 3], b: &[f64; 3]) -> f64 {
    let dot: f64 = (0..3).map(|k| a[k] * b[k]).sum();
    let na = a.iter().map(|x| x * x).sum::<f64>().sqrt();
    let nb = b.iter().map(|x| x * x).sum::<f64>().sqrt();
    if na == 0.0 || nb == 0.0 {
        return 0.0;
    }
    (dot / (na * nb)).clamp(-1.0, 1.0).acos()
}

#[cfg(test)]
mod tests {
    use super::*;

    /// 0/1 rows as an activity matrix.
    fn rows(r: &[[u8; 3]]) -> Vec<Vec<bool>> {
        r.iter()
            .map(|r| r.iter().map(|&x| x == 1).collect())
            .collect()
    }

    #[test]
    fn an_su_near_an_upright_axis_joins_the_segment_its_row_becomes() {
        // A chain yaw → pitch → yaw2; yaw and yaw2 stood vertical. Two SUs per segment; the
        // second SU on the pitch's segment sits on yaw's axis, the second on yaw2's segment on
        // yaw's too.
        let mut active = rows(&[
            [1, 0, 0],
            [1, 0, 0],
            [1, 1, 0],
            [0, 1, 0],
            [1, 1, 1],
            [0, 1, 1],
        ]);
        let added = near_upright_axes(&mut active, &[true, false, true]);
        assert_eq!(added, vec![(3, 0), (5, 0)]);
        assert_eq!(active[3], active[2]);
        assert_eq!(active[5], active[4]);
        assert_eq!(orphan_rows(&active), 0);
        // Without upright DoFs nothing is added.
        let mut plain = rows(&[[1, 0, 0], [0, 1, 0]]);
        assert!(near_upright_axes(&mut plain, &[false; 3]).is_empty());
    }

    #[test]
    fn a_moves_gain_counts_less_three_of_its_deviations() {
        let robot = crate::model::presets::find("paper-7dof")
            .unwrap()
            .robot()
            .unwrap();
        let mut set = crate::sim::simulate(&robot, &crate::sim::SimulationConfig::default())
            .unwrap()
            .measurements;
        let sus = set.sus.len();
        let dof = set.dofs[0].clone();
        let mut with = |gain: [f64; 3], sd: Vec<Option<f64>>| {
            for mv in set
                .structure
                .iter_mut()
                .flat_map(|s| &mut s.orientations)
                .flat_map(|o| &mut o.moves)
                .filter(|m| m.dof == dof)
            {
                mv.accelerated = vec![gain; sus];
                mv.accelerated_sd = sd.clone();
            }
            accelerated_medians(&set, 0).unwrap()
        };
        // 5 cm of lever arm (norm of 0.03, 0.04, 0): as given where no deviation is.
        let gain = [0.03, 0.04, 0.0];
        assert!(with(gain, Vec::new())
            .iter()
            .all(|&m| (m - 0.05).abs() < 1e-12));
        // Told within a millimetre: 5 cm less 3 mm.
        let told = with(gain, vec![Some(0.001); sus]);
        assert!(told.iter().all(|&m| (m - 0.047).abs() < 1e-12), "{told:?}");
        // Within 3 cm (a move the record barely held): nothing; an SU that sent too little: nothing.
        assert!(with(gain, vec![Some(0.03); sus]).iter().all(|&m| m == 0.0));
        let mut unknown = vec![Some(0.001); sus];
        unknown[2] = None;
        assert_eq!(with(gain, unknown)[2], 0.0);
    }
}
