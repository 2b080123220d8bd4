//! Where a fit on a motion record starts when the measurement set has no training poses (a
//! continuous program, ordinary work): static readings from the record's quiet moments and from
//! the structure experiment's holds, in every base orientation it stood in.
//!
//! The quiet moments of a humanoid's record are its structure part's, one DoF at a time, so
//! most of them find an arm at its rest pose; the holds name every DoF of every limb turned on
//! its own, upright and tilted, which is what gravity needs to tell each axis.

use crate::measurements::{MeasurementSet, Orientation, TrainingExperiment, TrainingPose};
use crate::model::sensor::ExcitationPattern;
use crate::motion::MotionRecord;

/// Quiet moments of a motion record that start a fit without training poses.
pub const QUIET_POSES: usize = 40;

/// The standard deviation of a held reading whose SU's noise the record does not know, m/s²: no
/// weight.
const UNKNOWN_SD: f64 = 1e3;

/// `set` with the start of a fit on `motion` as its training poses: [`QUIET_POSES`] of the
/// record's quiet moments ([`MotionRecord::quiet_poses`]) and the structure experiment's holds
/// ([`structure_holds`]).
pub fn quiet_set(set: &MeasurementSet, motion: &MotionRecord) -> MeasurementSet {
    let mut poses = motion.quiet_poses(QUIET_POSES);
    poses.extend(structure_holds(set, motion));
    let mut quiet = set.clone();
    quiet.training = Some(TrainingExperiment {
        pattern: ExcitationPattern::default(),
        poses,
        from_motion: true,
        extra: Default::default(),
    });
    quiet
}

/// The structure experiment's rest and moved poses of `set` as static training poses, each SU's
/// reading weighed by its noise in `motion` (that of a block mean: a hold averages many).
///
/// An orientation in which the record's base stood too ([`MotionRecord::same_base`] at its rest
/// pose) is base orientation 0, the record's; every other is numbered 1, 2, … and fitted with a
/// gravity of its own, so that no tilt need be known, and a structure part recorded apart from
/// the record still tells what it holds.
pub fn structure_holds(set: &MeasurementSet, motion: &MotionRecord) -> Vec<TrainingPose> {
    let Some(structure) = &set.structure else {
        return Vec::new();
    };
    let sd: Vec<f64> = motion
        .noise_sd
        .iter()
        .map(|s| s.unwrap_or(UNKNOWN_SD))
        .collect();
    let mut others = 0;
    let mut poses = Vec::new();
    for o in &structure.orientations {
        let orientation = if motion.same_base(&o.rest_pose, &o.rest) == Some(true) {
            0
        } else {
            others += 1;
            others
        };
        if orientation >= crate::measurements::MAX_ORIENTATIONS {
            continue;
        }
        poses.extend(holds(o).map(|(q, readings)| TrainingPose {
            q: q.to_vec(),
            static_readings: readings.to_vec(),
            dynamic: Default::default(),
            static_sd: Some(sd.clone()),
            dynamic_sd: Default::default(),
            orientation,
            extra: Default::default(),
        }));
    }
    poses
}

/// The rest pose and every move of one orientation, with their readings.
fn holds(o: &Orientation) -> impl Iterator<Item = (&[f64], &[[f64; 3]])> {
    std::iter::once((o.rest_pose.as_slice(), o.rest.as_slice())).chain(
        o.moves
            .iter()
            .map(|m| (m.pose.as_slice(), m.readings.as_slice())),
    )
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::measurements::{Move, StructureExperiment};
    use crate::motion::{MotionRun, MOTION_FORMAT, MOTION_VERSION};
    use nalgebra::{Rotation3, Vector3};

    /// Two SUs' gravity readings at the rest pose, turned by `tilt` about x (rad).
    fn gravity(tilt: f64) -> Vec<[f64; 3]> {
        let turn = Rotation3::from_axis_angle(&Vector3::x_axis(), tilt);
        [Vector3::new(0.0, 0.0, 9.81), Vector3::new(6.0, 0.0, -7.76)]
            .iter()
            .map(|g| (turn * g).into())
            .collect()
    }

    /// A structure orientation at rest pose 0 read with `tilt`, and one move of the DoF.
    fn orientation(tilt: f64) -> Orientation {
        Orientation {
            rest_pose: vec![0.0],
            rest: gravity(tilt),
            moves: vec![Move {
                dof: "j".into(),
                pose: vec![0.3],
                readings: gravity(tilt + 0.3),
                accelerated: Vec::new(),
                accelerated_sd: Vec::new(),
                extra: Default::default(),
            }],
            extra: Default::default(),
        }
    }

    /// A record that holds pose `q` still for 20 blocks, reading gravity as the upright base.
    fn record(q: f64) -> MotionRecord {
        let mut run = MotionRun::new("log", 0.0);
        for _ in 0..20 {
            run.push(
                &[[q, 0.0, 0.0, 0.01]],
                gravity(0.0).into_iter().map(Some).collect(),
            );
        }
        MotionRecord {
            format: MOTION_FORMAT.into(),
            version: MOTION_VERSION,
            period: 0.01,
            dofs: vec!["j".into()],
            sus: vec!["a".into(), "b".into()],
            noise_sd: vec![Some(0.02), None],
            half_width: None,
            rounding: Vec::new(),
            runs: vec![run],
            samples: Vec::new(),
        }
    }

    fn set(tilts: &[f64]) -> MeasurementSet {
        let mut set = MeasurementSet::new(vec!["j".into()], vec!["a".into(), "b".into()]);
        set.structure = Some(StructureExperiment {
            orientations: tilts.iter().map(|&t| orientation(t)).collect(),
            extra: Default::default(),
        });
        set
    }

    fn orientations(poses: &[TrainingPose]) -> Vec<usize> {
        poses.iter().map(|p| p.orientation).collect()
    }

    #[test]
    fn the_orientation_the_record_stood_in_is_base_orientation_0_wherever_it_is_listed() {
        // 0.5° is a reading's noise; 30° is a tilted mount.
        let (noise, tilt) = (0.5_f64.to_radians(), 30_f64.to_radians());
        let holds = structure_holds(&set(&[noise, tilt]), &record(0.0));
        assert_eq!(orientations(&holds), [0, 0, 1, 1]);
        let holds = structure_holds(&set(&[tilt, noise]), &record(0.0));
        assert_eq!(orientations(&holds), [1, 1, 0, 0]);
        // Each hold is its pose and readings, weighed by the SU's noise; an SU the record has no
        // noise for has no weight.
        assert_eq!(holds[1].q, [0.3]);
        assert_eq!(holds[1].static_readings, gravity(tilt + 0.3));
        assert_eq!(holds[1].static_sd.as_deref(), Some(&[0.02, UNKNOWN_SD][..]));
    }

    #[test]
    fn a_structure_part_the_record_never_held_is_fitted_with_gravities_of_its_own() {
        let holds = structure_holds(&set(&[0.0, 0.5]), &record(1.0));
        assert_eq!(orientations(&holds), [1, 1, 2, 2]);
        // With the quiet moments, in orientation 0.
        let quiet = quiet_set(&set(&[0.0]), &record(0.0));
        let training = quiet.training.unwrap();
        assert!(training.from_motion);
        assert_eq!(training.poses.len(), QUIET_POSES.min(20) + 2);
        assert!(training.poses.iter().all(|p| p.orientation == 0));
    }
}
