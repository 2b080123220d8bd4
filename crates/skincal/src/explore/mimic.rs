//! Bodies that a mimic DoF drives. A DoF with mimic followers (a gripper's second finger, a hand's
//! coupled phalanges) moves several bodies in one move, and every SU on any of them has the same
//! row of the activity matrix: rows alone would merge them into one segment. SUs on one rigid body
//! keep one rotation between their frames whatever the robot does, so their gravity readings in
//! every static pose agree up to one fixed rotation (and each sensor's bias); SUs on bodies that a
//! follower turns against the leader's body do not. Slides turn nothing, so for a prismatic leader
//! the accelerations of its excitation tell instead: SUs on one body read them along one direction,
//! a mirrored finger along the opposite one.

use nalgebra::{Matrix3, Rotation3, Vector3};
use serde::{Deserialize, Serialize};

use crate::measurements::MeasurementSet;
use crate::model::sensor::STANDARD_GRAVITY;
use crate::model::DofKind;

/// SUs on one body agree up to a fixed rotation within this, g, in three poses of four: the noise
/// of two readings (±0.01 g each) stays below it, while a body that a follower turns by two
/// degrees against the leader's moves gravity by 0.035 g. Sensors' scale errors of several
/// percent may split one body (its SUs are then set aside, never fitted wrongly).
const RIGID_RESIDUAL: f64 = 0.03;
/// Two SUs on one slide read its accelerations along one direction: the cosine between them (in
/// one frame) is near 1, near −1 for a mirrored finger.
const SAME_SLIDE_COSINE: f64 = 0.8;

/// An SU that a DoF with mimic followers moves but that is not on one rigid body with the other
/// SUs of its row: it sits on a body one of the followers drives.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct MimicDriven {
    /// The SU.
    pub su: String,
    /// The DoF with the actuator.
    pub leader: String,
    /// The mimic DoFs that follow it.
    pub followers: Vec<String>,
    /// The SUs of the same row, on the body kept for the leader, that it does not move rigidly
    /// with (none when no body could be told to be the leader's).
    pub kept: Vec<String>,
}

/// The SUs on bodies that mimic DoFs drive, among those that `active[u][d]` says a leader moves:
/// for every leader, the SUs with one row are grouped into rigid bodies ([`rigid_pair`]); where
/// there are several, the largest stays the leader's when every follower turns as much as the
/// leader (|multiplier| 1), and the others are returned — all of them otherwise. SUs `skip`
/// (broken) are not judged.
pub(super) fn mimic_driven(
    set: &MeasurementSet,
    active: &[Vec<bool>],
    skip: &[bool],
) -> Vec<MimicDriven> {
    let mut found = Vec::new();
    for leader in 0..set.dofs.len() {
        let followers = set.followers_of(leader);
        if followers.is_empty() {
            continue;
        }
        let moved: Vec<usize> = (0..set.sus.len())
            .filter(|&u| active[u][leader] && !skip[u])
            .collect();
        let mut rows: Vec<Vec<usize>> = Vec::new();
        for &u in &moved {
            match rows.iter_mut().find(|r| active[r[0]] == active[u]) {
                Some(r) => r.push(u),
                None => rows.push(vec![u]),
            }
        }
        // A follower that turns as much as its leader (|multiplier| 1: a gripper's mirrored
        // finger) moves its body as the leader's would, up to the axis' direction, which the fit
        // finds: the largest body can stand for the leader's. Otherwise which body is the
        // leader's cannot be told from the readings, and none is kept.
        let mirrored = followers.iter().all(|&f| {
            set.mimic
                .get(&set.dofs[f])
                .is_some_and(|m| (m.multiplier.abs() - 1.0).abs() < 1e-9)
        });
        for row in rows.iter().filter(|r| r.len() >= 2) {
            let bodies = rigid_bodies(set, row, leader);
            if bodies.len() < 2 {
                continue;
            }
            let largest = bodies
                .iter()
                .enumerate()
                .max_by_key(|(i, b)| (b.len(), usize::MAX - i))
                .map(|(i, _)| i)
                .filter(|_| mirrored);
            let kept: Vec<String> = largest
                .map(|i| bodies[i].iter().map(|&k| set.sus[k].clone()).collect())
                .unwrap_or_default();
            let others = bodies
                .iter()
                .enumerate()
                .filter(|&(i, _)| Some(i) != largest)
                .flat_map(|(_, b)| b);
            for &u in others {
                found.push(MimicDriven {
                    su: set.sus[u].clone(),
                    leader: set.dofs[leader].clone(),
                    followers: followers.iter().map(|&f| set.dofs[f].clone()).collect(),
                    kept: kept.clone(),
                });
            }
        }
    }
    found
}

/// `row`'s SUs grouped into rigid bodies: each SU joins the first body whose first SU it moves
/// rigidly with.
fn rigid_bodies(set: &MeasurementSet, row: &[usize], leader: usize) -> Vec<Vec<usize>> {
    let mut bodies: Vec<Vec<usize>> = Vec::new();
    for &u in row {
        match bodies.iter_mut().find(|b| rigid_pair(set, b[0], u, leader)) {
            Some(b) => b.push(u),
            None => bodies.push(vec![u]),
        }
    }
    bodies
}

/// Whether SUs `i` and `j` sit on one rigid body: their static readings (structure experiment and
/// training poses) agree up to one rotation and an offset (the biases), within [`RIGID_RESIDUAL`]
/// in three training poses of four, and, for a prismatic `leader`, they read its slide along one
/// direction (its excitation in the training poses, or what its structure moves accelerated,
/// [`crate::measurements::Move::accelerated`]). The structure experiment holds the leader at
/// rest but for its own move, so its readings agree whatever the bodies: without training poses
/// only the slide can tell two bodies apart, and without either every pair is rigid.
fn rigid_pair(set: &MeasurementSet, i: usize, j: usize, leader: usize) -> bool {
    let poses = set
        .training
        .as_ref()
        .map_or(&[][..], |t| t.poses.as_slice());
    let mut pairs: Vec<(Vector3<f64>, Vector3<f64>)> = poses
        .iter()
        .map(|p| {
            (
                Vector3::from(p.static_readings[i]),
                Vector3::from(p.static_readings[j]),
            )
        })
        .collect();
    let orientations = || set.structure.iter().flat_map(|s| &s.orientations);
    let moves = || orientations().flat_map(|o| &o.moves);
    pairs.extend(orientations().map(|o| (Vector3::from(o.rest[i]), Vector3::from(o.rest[j]))));
    pairs.extend(moves().map(|m| (Vector3::from(m.readings[i]), Vector3::from(m.readings[j]))));
    let Some((rotation, residuals)) = fit_rotation(&pairs) else {
        return true;
    };
    // Only the training poses' residuals judge.
    let mut sorted = residuals[..poses.len()].to_vec();
    sorted.sort_by(f64::total_cmp);
    if sorted
        .get((3 * sorted.len()) / 4)
        .is_some_and(|&r| r > RIGID_RESIDUAL * STANDARD_GRAVITY)
    {
        return false;
    }
    if set.dof_kind(leader) != DofKind::Prismatic {
        return true;
    }
    let name = &set.dofs[leader];
    let slides = poses.iter().filter_map(|p| p.dynamic.get(name)).chain(
        moves()
            .filter(|m| m.dof == *name && !m.accelerated.is_empty())
            .map(|m| &m.accelerated),
    );
    let (mut along, mut size) = (0.0, 0.0);
    for r in slides {
        let (a, b) = (Vector3::from(r[i]), rotation * Vector3::from(r[j]));
        along += a.dot(&b);
        size += a.norm() * b.norm();
    }
    size == 0.0 || along / size > SAME_SLIDE_COSINE
}

/// The rotation `R` and offset `c` that best map the second vector of every pair onto the first
/// (`a ≈ R b + c`, least squares: Kabsch on the centred vectors), and each pair's residual norm.
/// `None` with fewer than three pairs.
fn fit_rotation(pairs: &[(Vector3<f64>, Vector3<f64>)]) -> Option<(Rotation3<f64>, Vec<f64>)> {
    if pairs.len() < 3 {
        return None;
    }
    let n = pairs.len() as f64;
    let mean_a = pairs.iter().map(|p| p.0).sum::<Vector3<f64>>() / n;
    let mean_b = pairs.iter().map(|p| p.1).sum::<Vector3<f64>>() / n;
    let h: Matrix3<f64> = pairs
        .iter()
        .map(|(a, b)| (b - mean_b) * (a - mean_a).transpose())
        .sum();
    let svd = h.svd(true, true);
    let (u, v_t) = (svd.u?, svd.v_t?);
    let mut d = Matrix3::identity();
    if (v_t.transpose() * u.transpose()).determinant() < 0.0 {
        d[(2, 2)] = -1.0;
    }
    let rotation = Rotation3::from_matrix_unchecked(v_t.transpose() * d * u.transpose());
    let offset = mean_a - rotation * mean_b;
    let residuals = pairs
        .iter()
        .map(|(a, b)| (a - rotation * b - offset).norm())
        .collect();
    Some((rotation, residuals))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_rotation_between_two_frames_is_found_from_vector_pairs() {
        // Hand-made: b = Rᵀ (a − c) for a known rotation and offset, so the fit must return them.
        let truth = Rotation3::from_euler_angles(0.3, -1.1, 2.0);
        let c = Vector3::new(0.2, -0.1, 0.4);
        let pairs: Vec<_> = [
            [9.81, 0.0, 0.0],
            [0.0, 9.81, 0.0],
            [0.0, 0.0, 9.81],
            [5.0, 5.0, -6.6],
            [-3.0, 7.0, 5.9],
        ]
        .iter()
        .map(|a| {
            let a = Vector3::from(*a);
            (a, truth.inverse() * (a - c))
        })
        .collect();
        let (r, residuals) = fit_rotation(&pairs).unwrap();
        // Compared entrywise: the angle between two rotations is an arccosine, which cannot
        // resolve a difference below about 1e-8 rad.
        assert!((r.matrix() - truth.matrix()).norm() < 1e-9);
        assert!(residuals.iter().all(|&e| e < 1e-9));
        // A mirror image is no rotation: the fit leaves a residual.
        let mirrored: Vec<_> = pairs.iter().map(|(a, b)| (*a, -b)).collect();
        let (_, residuals) = fit_rotation(&mirrored).unwrap();
        assert!(residuals.iter().any(|&e| e > 1.0));
    }
}
