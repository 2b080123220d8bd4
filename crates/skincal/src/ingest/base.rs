//! Which base orientation each log was recorded in: two logs that hold the robot still at one
//! joint pose read the same gravity on every SU when its base stood alike, and read it turned by
//! the tilt when it did not. The training experiment is fitted with one gravity, so its poses
//! must come from logs of one base orientation; a structure experiment's logs in the other
//! orientation give it nothing but their structure moves.

use crate::measurements::Reading;

use crate::motion::LEAST_GRAVITY;
pub(super) use crate::motion::OTHER_BASE;

/// One still station of a log, as this module needs it: the log and the joint pose held.
pub(super) type Still<'a> = (usize, &'a [f64]);

/// How the module reads the data: whether two joint poses are one, and the static readings of a
/// station (by its index in the stations; asked for only where its pose is met in another log).
pub(super) struct Readings<'a> {
    pub same_pose: &'a dyn Fn(&[f64], &[f64]) -> bool,
    pub at: &'a dyn Fn(usize) -> Option<Vec<Reading>>,
}

/// Per log (of `logs`), the base orientation it was recorded in, numbered in order of first
/// appearance; `None` for a log that holds no still pose another log holds too (nothing tells).
pub(super) fn base_orientations(
    logs: usize,
    stills: &[Still<'_>],
    read: &Readings<'_>,
) -> Vec<Option<usize>> {
    let mut class: Vec<Option<usize>> = vec![None; logs];
    let mut classes = 0;
    for log in 0..logs {
        let mut differs = false;
        for earlier in 0..log {
            let Some(c) = class[earlier] else { continue };
            match turned(stills, log, earlier, read) {
                Some(angle) if angle <= OTHER_BASE => {
                    class[log] = Some(c);
                    break;
                }
                Some(_) => differs = true,
                None => {}
            }
        }
        if class[log].is_none() && (log == 0 || differs) {
            class[log] = Some(classes);
            classes += 1;
        }
    }
    class
}

/// The median angle between the gravity readings of logs `a` and `b` at the first joint pose
/// both hold still; `None` where they share none.
fn turned(stills: &[Still<'_>], a: usize, b: usize, read: &Readings<'_>) -> Option<f64> {
    let (first, second) = (0..stills.len())
        .filter(|&s| stills[s].0 == a)
        .find_map(|s| {
            let t = (0..stills.len())
                .find(|&t| stills[t].0 == b && (read.same_pose)(stills[s].1, stills[t].1))?;
            Some(((read.at)(s)?, (read.at)(t)?))
        })?;
    let mut angles: Vec<f64> = first
        .iter()
        .zip(&second)
        .filter_map(|(x, y)| {
            let (x, y) = (nalgebra::Vector3::from(*x), nalgebra::Vector3::from(*y));
            (x.norm() > LEAST_GRAVITY && y.norm() > LEAST_GRAVITY).then(|| x.angle(&y))
        })
        .collect();
    if angles.is_empty() {
        return None;
    }
    angles.sort_by(f64::total_cmp);
    Some(angles[angles.len() / 2])
}

#[cfg(test)]
mod tests {
    use super::*;

    fn tilted(r: Reading, degrees: f64) -> Reading {
        let (s, c) = degrees.to_radians().sin_cos();
        [r[0], c * r[1] - s * r[2], s * r[1] + c * r[2]]
    }

    #[test]
    fn logs_at_one_pose_are_told_apart_by_how_far_gravity_turned() {
        let rest = [0.0, 0.5];
        let elsewhere = [1.0, 0.5];
        let upright = vec![[0.0, 0.0, -9.81], [0.0, 6.9, -6.9], [9.81, 0.0, 0.0]];
        let again = vec![[0.05, 0.0, -9.81], [0.0, 6.95, -6.9], [9.8, 0.1, 0.0]];
        let mounted: Vec<Reading> = upright.iter().map(|&r| tilted(r, 20.0)).collect();
        let dead = vec![[0.0; 3]; 3];
        let stills: [Still<'_>; 6] = [
            (0, &rest),
            (1, &rest),
            (2, &elsewhere),
            (2, &rest),
            (3, &elsewhere),
            (4, &rest),
        ];
        let readings = [&upright, &mounted, &upright, &again, &mounted, &dead];
        let same = |a: &[f64], b: &[f64]| a.iter().zip(b).all(|(x, y)| (x - y).abs() < 1e-3);
        let at = |k: usize| Some(readings[k].clone());
        let read = Readings {
            same_pose: &same,
            at: &at,
        };
        // Log 2 stood as log 0 did; log 1 was tilted 20°; log 3 shares its pose only with log 2
        // and reads it turned; a dead skin tells nothing.
        assert_eq!(
            base_orientations(5, &stills, &read),
            vec![Some(0), Some(1), Some(0), Some(2), None]
        );
    }
}
