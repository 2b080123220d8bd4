//! Changes of a skin after its calibration, for checking `check`: an SU shifted or turned on its
//! segment, two SUs' identities exchanged (made on the robot, before recording), a bias step or a
//! broken board (made on the motion record, as the board's samples would arrive).

use nalgebra::{Isometry3, Vector3};
use serde::{Deserialize, Serialize};

use crate::model::{ModelError, PlacementSpec, Robot};
use crate::motion::MotionRecord;

/// What a change does to one block mean of an SU.
type Edit = dyn Fn(&mut Option<[f64; 3]>);

/// One change of a skin.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(tag = "kind", rename_all = "kebab-case")]
pub enum SkinChange {
    /// SU `su` shifted by `shift` (m) and turned by `turn` (rotation vector, rad), both in its
    /// own frame.
    Move {
        /// The SU.
        su: String,
        /// Shift, m.
        shift: [f64; 3],
        /// Turn, rad.
        turn: [f64; 3],
    },
    /// SUs `a` and `b` exchanged identities (their boards plugged into each other's ports).
    Swap {
        /// One SU.
        a: String,
        /// The other.
        b: String,
    },
    /// SU `su`'s bias stepped by `bias` (m/s², its own frame).
    Bias {
        /// The SU.
        su: String,
        /// The step, m/s².
        bias: [f64; 3],
    },
    /// DoF `dof`'s encoder homed anew: it now reads `offset` (rad) less than before in the same
    /// posture (made on the robot: its joint frame turned about its axis by `offset`).
    Zero {
        /// The DoF.
        dof: String,
        /// The angle, rad.
        offset: f64,
    },
    /// SU `su` stopped sending fresh samples (dead, frozen or unplugged).
    Silent {
        /// The SU.
        su: String,
    },
    /// SU `su`'s z axis stuck at +2 g.
    Railed {
        /// The SU.
        su: String,
    },
    /// SU `su` became `factor` times noisier (white noise added to its block means, and to the
    /// noise its still blocks show).
    Noisy {
        /// The SU.
        su: String,
        /// Its new noise over its old.
        factor: f64,
        /// Seed of the added noise.
        seed: u64,
    },
}

impl SkinChange {
    /// The robot as it is after the change (changes made on the record leave it as it is).
    pub fn robot(&self, robot: &Robot) -> Result<Robot, ModelError> {
        let mut builder = robot.to_builder();
        match self {
            SkinChange::Move { su, shift, turn } => {
                let Some(u) = robot.model.su_index(su) else {
                    return Ok(robot.clone());
                };
                let old = robot.model.sus()[u].placement.transform(&robot.parameters);
                let new = old * Isometry3::new(Vector3::from(*shift), Vector3::from(*turn));
                let (r, p, y) = new.rotation.euler_angles();
                if let Some(spec) = builder.sus.iter_mut().find(|s| &s.name == su) {
                    spec.placement =
                        PlacementSpec::xyz_rpy(new.translation.vector.into(), [r, p, y]);
                }
            }
            SkinChange::Swap { a, b } => {
                for spec in &mut builder.sus {
                    if &spec.name == a {
                        spec.name.clone_from(b);
                    } else if &spec.name == b {
                        spec.name.clone_from(a);
                    }
                }
            }
            SkinChange::Zero { dof, offset } => {
                if let Some(spec) = builder.dofs.iter_mut().find(|d| &d.name == dof) {
                    let origin = spec.origin.kind.transform(&spec.origin.values);
                    let axis = nalgebra::Unit::new_normalize(spec.axis);
                    let turned = origin * nalgebra::UnitQuaternion::from_axis_angle(&axis, *offset);
                    spec.origin = PlacementSpec::from_isometry(&turned);
                }
            }
            _ => return Ok(robot.clone()),
        }
        builder.build()
    }

    /// The record as its boards would have sent it after the change (changes made on the robot
    /// leave it as it is).
    pub fn apply_to_record(&self, record: &mut MotionRecord) {
        let column = |su: &str| record.sus.iter().position(|s| s == su);
        let (su, edit): (&str, Box<Edit>) = match self {
            SkinChange::Bias { su, bias } => {
                let bias = *bias;
                (
                    su,
                    Box::new(move |v| {
                        if let Some(v) = v {
                            for (x, b) in v.iter_mut().zip(bias) {
                                *x += b;
                            }
                        }
                    }),
                )
            }
            SkinChange::Silent { su } => (su, Box::new(|v| *v = None)),
            SkinChange::Railed { su } => (
                su,
                Box::new(|v| {
                    if let Some(v) = v {
                        v[2] = 2.0 * crate::model::sensor::STANDARD_GRAVITY;
                    }
                }),
            ),
            SkinChange::Noisy { su, factor, seed } => {
                let Some(c) = column(su) else { return };
                let old = record.noise_sd[c].unwrap_or(0.02);
                let added = old * (factor * factor - 1.0).max(0.0).sqrt();
                record.noise_sd[c] = Some(old * factor);
                let mut rng = super::stream(*seed, 77);
                let normal = rand_distr::Normal::new(0.0, added).expect("a finite deviation");
                for run in &mut record.runs {
                    for row in &mut run.skin {
                        if let Some(v) = &mut row[c] {
                            for x in v.iter_mut() {
                                *x += rand_distr::Distribution::sample(&normal, &mut rng);
                            }
                        }
                    }
                }
                return;
            }
            _ => return,
        };
        let Some(c) = column(su) else { return };
        for run in &mut record.runs {
            for row in &mut run.skin {
                edit(&mut row[c]);
            }
        }
    }
}
