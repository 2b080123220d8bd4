//! The SUs no small change explains: matched against every other SU's place, fitted anew on their
//! segment and on the others, each fit a Gauss–Newton on a thinned copy of the record's blocks.

use nalgebra::{Isometry3, Matrix3, Rotation3, Translation3, UnitQuaternion, Vector3};

use super::kin::{self, SuPlace};
use super::test::{Change, Tally};
use super::{
    block, median, refit_of, su_term, Block, CheckReport, Columns, Skin, SkinCheck, SuChange,
    Verdict,
};
use crate::motion::MotionRecord;

/// The most blocks a fit anew takes (evenly spread over the record).
const FIT_BLOCKS: usize = 3000;
/// Gauss–Newton steps of a fit anew.
const FIT_STEPS: usize = 25;
/// Alternations of the closed-form start (turn by Wahba, then position by least squares).
const START_ROUNDS: usize = 8;
/// The noise of a block mean when no SU's can be told, m/s².
const FALLBACK_NOISE: f64 = 0.03;

/// Each SU's block noise (model SU order): the record's from still blocks, else from the second
/// differences of its own block means (the motion's share is small there, and no model enters,
/// so a board that reads another's place is not taken for a noisy one), else the skin's median.
pub fn block_noise(columns: &Columns, record: &MotionRecord) -> Vec<f64> {
    let given: Vec<Option<f64>> = columns
        .sus
        .iter()
        .map(|c| c.and_then(|c| record.noise_sd[c]))
        .collect();
    let from_means: Vec<Option<f64>> = columns
        .sus
        .iter()
        .zip(&given)
        .map(|(c, g)| match (c, g) {
            (Some(c), None) => second_difference_noise(record, *c),
            _ => None,
        })
        .collect();
    let known: Vec<f64> = given
        .iter()
        .zip(&from_means)
        .filter_map(|(a, b)| a.or(*b))
        .collect();
    let fallback = if known.is_empty() {
        FALLBACK_NOISE
    } else {
        median(known)
    };
    given
        .iter()
        .zip(&from_means)
        .map(|(a, b)| a.or(*b).unwrap_or(fallback))
        .collect()
}

/// The standard deviation of one component of SU column `c`'s corrected block means from the
/// median of their second differences: a corrected mean is `(−m₋₁ + 26 m₀ − m₁)/24` of raw
/// means, so its second difference weighs five raw means by `(−1, 28, −54, 28, −1)/24`, a
/// variance of 4486/576 of one raw mean's against 678/576 for the corrected mean itself.
fn second_difference_noise(record: &MotionRecord, c: usize) -> Option<f64> {
    let mut values = Vec::new();
    for run in &record.runs {
        for b in 1..run.len().saturating_sub(1) {
            if let (Some(x), Some(y), Some(z)) = (
                run.skin.get(b - 1, c),
                run.skin.get(b, c),
                run.skin.get(b + 1, c),
            ) {
                values.extend((0..3).map(|i| (x[i] - 2.0 * y[i] + z[i]).abs()));
            }
            if values.len() >= 3 * FIT_BLOCKS {
                break;
            }
        }
    }
    if values.len() < 90 {
        return None;
    }
    Some(median(values) / 0.6745 * (678.0f64 / 4486.0).sqrt())
}

/// Thinned blocks of a record, computed once for every fit anew.
pub(super) struct Cache {
    blocks: Vec<Block>,
}

impl Cache {
    pub(super) fn new(skin: &Skin, columns: &Columns, record: &MotionRecord) -> Self {
        let total: usize = record.runs.iter().map(|r| r.len()).sum();
        let stride = total.div_ceil(FIT_BLOCKS).max(1);
        let blocks = record
            .runs
            .iter()
            .flat_map(|run| (0..run.len()).step_by(stride).map(move |b| (run, b)))
            .map(|(run, b)| block(skin, columns, run, b, record.period))
            .collect();
        Self { blocks }
    }

    /// SU `u`'s readings summed against `place`.
    pub(super) fn tally(
        &self,
        skin: &Skin,
        u: usize,
        place: &SuPlace,
        noise: f64,
        huber: f64,
    ) -> Tally {
        let mut tally = Tally::default();
        for block in &self.blocks {
            if let Some((r, jac, var)) = su_term(skin, block, u, place, noise) {
                tally.add(&r, &jac, var, huber);
            }
        }
        tally
    }

    /// SU `u`'s readings fitted from `start` (pose and bias, and with `sensitivity` its
    /// sensitivity too), by Gauss–Newton with a little damping; the place found and its RMS
    /// whitened residual.
    pub(super) fn fit(
        &self,
        skin: &Skin,
        u: usize,
        start: SuPlace,
        noise: f64,
        huber: f64,
        sensitivity: bool,
    ) -> (SuPlace, f64) {
        let mut place = start;
        for _ in 0..FIT_STEPS {
            let tally = self.tally(skin, u, &place, noise, huber);
            let (mut a, mut g) = (tally.information, tally.gradient);
            if !sensitivity {
                // Held: its rows and columns of the normal equations are the identity's.
                for k in 9..kin::CHANGE {
                    a.row_mut(k).fill(0.0);
                    a.column_mut(k).fill(0.0);
                    a[(k, k)] = 1.0;
                    g[k] = 0.0;
                }
            }
            for i in 0..kin::CHANGE {
                a[(i, i)] *= 1.0 + 1e-6;
                a[(i, i)] += 1e-9;
            }
            let Some(step) = a.cholesky().map(|c| c.solve(&g)) else {
                break;
            };
            place = kin::changed(&place, step.as_slice());
            if step.fixed_rows::<3>(0).norm() < 1e-6 && step.fixed_rows::<3>(3).norm() < 1e-6 {
                break;
            }
        }
        let tally = self.tally(skin, u, &place, noise, huber);
        (place, tally.residual_ratio(&Change::zeros()))
    }

    /// A start for SU `u` on `segment` from its readings alone: its turn by Wahba's problem
    /// (the readings against gravity and motion at the current position guess) and its position
    /// by linear least squares, alternated.
    fn start_on(&self, u: usize, segment: usize, like: &SuPlace) -> SuPlace {
        let mut position = Vector3::zeros();
        let mut rotation = UnitQuaternion::identity();
        let corrected: Vec<Option<Vector3<f64>>> = self
            .blocks
            .iter()
            .map(|b| b.readings[u].and_then(|y| like.intrinsics.correct(&y)))
            .collect();
        for _ in 0..START_ROUNDS {
            let mut wahba = Matrix3::zeros();
            let (mut mtm, mut mtr) = (Matrix3::zeros(), Vector3::zeros());
            for (block, f) in self.blocks.iter().zip(&corrected) {
                let Some(f) = f else { continue };
                let frame = block.kinematics.segments[segment];
                let motion = &block.kinematics.motion[segment];
                let m = motion.point_matrix();
                let rs = frame.rotation.to_rotation_matrix().into_inner();
                let world =
                    motion.accel + m * (frame.translation.vector + rs * position) - like.gravity;
                wahba += (rs.transpose() * world) * f.transpose();
                // R_s R_su f = accel + M (t_s + R_s p) − g, linear in p.
                let lhs = m * rs;
                let rhs = rs * (rotation * f) - motion.accel - m * frame.translation.vector
                    + like.gravity;
                mtm += lhs.transpose() * lhs;
                mtr += lhs.transpose() * rhs;
            }
            rotation = nearest_rotation(&wahba);
            let ridge = 1e-6 * mtm.trace().max(1e-12);
            if let Some(p) = (mtm + Matrix3::identity() * ridge).try_inverse() {
                position = p * mtr;
            }
        }
        SuPlace {
            segment,
            placement: Isometry3::from_parts(Translation3::from(position), rotation),
            ..*like
        }
    }
}

/// The rotation `R` that maximises `tr(Rᵀ B)` (Wahba's problem through the SVD).
fn nearest_rotation(b: &Matrix3<f64>) -> UnitQuaternion<f64> {
    let svd = b.svd(true, true);
    let (Some(u), Some(vt)) = (svd.u, svd.v_t) else {
        return UnitQuaternion::identity();
    };
    let sign = (u * vt).determinant().signum();
    let r = u * Matrix3::from_diagonal(&Vector3::new(1.0, 1.0, sign)) * vt;
    UnitQuaternion::from_rotation_matrix(&Rotation3::from_matrix_unchecked(r))
}

/// Explains the SUs that [`SkinCheck::verdicts`] left `erratic`: another SU's place they read
/// (swapped, or another's identity), a place found anew on their segment (moved far) or on
/// another (the tree changed); what nothing explains stays erratic.
pub fn explain(check: &SkinCheck, record: &MotionRecord, report: &mut CheckReport) {
    let erratic: Vec<usize> = (0..report.sus.len())
        .filter(|&u| {
            report.sus[u].verdict
                == Verdict::Broken {
                    how: "erratic".into(),
                }
        })
        .collect();
    if erratic.is_empty() {
        return;
    }
    let skin = &check.skin;
    let cache = Cache::new(skin, &check.columns, record);
    let huber = check.config.huber;
    let misfit = check.config.misfit;
    let names = skin.robot.model.su_names();
    // Per erratic SU, the other SUs' places it reads as, best first.
    let candidates: Vec<Vec<usize>> = erratic
        .iter()
        .map(|&u| {
            let mut fits: Vec<(usize, f64)> = (0..names.len())
                .filter(|&v| v != u)
                .map(|v| {
                    let t = cache.tally(skin, u, &skin.places[v], check.noise[u], huber);
                    (v, t.residual_ratio(&Change::zeros()))
                })
                .filter(|&(_, ratio)| ratio < misfit)
                .collect();
            fits.sort_by(|a, b| a.1.total_cmp(&b.1));
            fits.into_iter().map(|(v, _)| v).collect()
        })
        .collect();
    let reads = |w: usize, v: usize| {
        erratic
            .iter()
            .position(|&x| x == w)
            .is_some_and(|j| candidates[j].contains(&v))
    };
    for (i, &u) in erratic.iter().enumerate() {
        // A partner that reads as this one's place is a swap, ahead of a better fit that does
        // not: two SUs that read alike (on one still segment, turned alike) fit equally well.
        let partner = candidates[i].iter().copied().find(|&v| reads(v, u));
        if let Some(v) = partner.or(candidates[i].first().copied()) {
            report.sus[u].untold.clear();
            report.sus[u].verdict = if partner.is_some() {
                Verdict::Swapped {
                    with: names[v].clone(),
                }
            } else {
                Verdict::ReadsAs {
                    su: names[v].clone(),
                }
            };
            continue;
        }
        relocate(check, &cache, u, misfit, report);
    }
}

/// SU `u` fitted anew: from its place, then from its readings alone on its segment, then on every
/// other segment; the first fit at the noise level decides.
fn relocate(check: &SkinCheck, cache: &Cache, u: usize, misfit: f64, report: &mut CheckReport) {
    let skin = &check.skin;
    let noise = check.noise[u];
    let huber = check.config.huber;
    let own = skin.places[u];
    let mut best = cache.fit(skin, u, own, noise, huber, false);
    if best.1 > misfit {
        let start = cache.start_on(u, own.segment, &own);
        let fresh = cache.fit(skin, u, start, noise, huber, false);
        if fresh.1 < best.1 {
            best = fresh;
        }
    }
    if best.1 <= misfit {
        let entry = &mut report.sus[u];
        entry.untold.clear();
        entry.verdict = Verdict::Moved;
        entry.residual_ratio = best.1;
        entry.change = Some(whole_change(&own, &best.0));
        entry.refit = Some(refit_of(&best.0.placement, best.0.intrinsics.bias, best.1));
        return;
    }
    let segments = skin.robot.model.segments();
    let elsewhere = (0..segments.len())
        .filter(|&s| s != own.segment && !skin.chains[s].is_empty())
        .map(|s| cache.fit(skin, u, cache.start_on(u, s, &own), noise, huber, false))
        .filter(|(_, ratio)| *ratio <= misfit)
        .min_by(|a, b| a.1.total_cmp(&b.1));
    if let Some((place, ratio)) = elsewhere {
        let entry = &mut report.sus[u];
        entry.untold.clear();
        entry.verdict = Verdict::OtherSegment {
            segment: segments[place.segment].name.clone(),
        };
        entry.residual_ratio = ratio;
        entry.refit = Some(refit_of(&place.placement, place.intrinsics.bias, ratio));
    }
}

/// The change from `old` to `new` on the same segment, in `old`'s frame.
pub(super) fn whole_change(old: &SuPlace, new: &SuPlace) -> SuChange {
    let step = old.placement.inverse() * new.placement;
    let bias = Vector3::from(new.intrinsics.bias) - Vector3::from(old.intrinsics.bias);
    SuChange {
        shift: step.translation.vector.into(),
        shift_sd: None,
        turn: step.rotation.scaled_axis().into(),
        turn_sd: None,
        bias: bias.into(),
        bias_sd: None,
        scale: std::array::from_fn(|k| {
            (1.0 + new.intrinsics.scale[k]) / (1.0 + old.intrinsics.scale[k]) - 1.0
        }),
        scale_sd: None,
    }
}
