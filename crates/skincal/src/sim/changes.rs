//! Changes of a skin after its calibration, for checking `check`: an SU shifted or turned on its
//! segment, two SUs' identities exchanged, a DoF's zero moved (made on the robot, before
//! recording), a bias step, a drift of sensitivity or a broken board (made on the log's samples as
//! the board sends them, [`SkinChange::on_log`]).

use std::path::PathBuf;

use nalgebra::{Isometry3, Vector3};
use rand_chacha::ChaCha8Rng;
use rand_distr::{Distribution, Normal};
use serde::{Deserialize, Serialize};

use crate::log::ros::Time;
use crate::log::{LogError, LogSink};
use crate::model::sensor::STANDARD_GRAVITY;
use crate::model::{ModelError, PlacementSpec, Robot};

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
    /// SU `su`'s sensitivity drifted: each axis sends `1 + scale[k]` times what it sent before
    /// (its zero-g offset scaled with it).
    Scale {
        /// The SU.
        su: String,
        /// The relative change of each axis' sensitivity (`0.03`: reads 3 % more).
        scale: [f64; 3],
    },
    /// DoF `dof`'s encoder homed anew: it now reads `offset` (rad) less than before in the same
    /// posture (made on the robot: its joint frame turned about its axis by `offset`).
    Zero {
        /// The DoF.
        dof: String,
        /// The angle, rad.
        offset: f64,
    },
    /// SU `su` sends nothing (unplugged, or its port not mapped).
    Silent {
        /// The SU.
        su: String,
    },
    /// SU `su`'s accelerometer stopped measuring `after` seconds into the log; its port sends
    /// the last value over and over.
    Frozen {
        /// The SU.
        su: String,
        /// When it froze, s from the log's first sample.
        after: f64,
    },
    /// SU `su`'s z axis stuck at +2 g, its range.
    Railed {
        /// The SU.
        su: String,
    },
    /// SU `su` became `factor` times noisier (white noise added to each of its samples).
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
    /// The robot as it is after the change (changes made on the samples leave it as it is).
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

    /// `sink` fed what the boards send after the change: a bias step, scaled axes, no samples, a
    /// frozen board's repeated value, a railed axis, added noise (changes made on the robot pass
    /// every sample through).
    pub fn on_log<'a>(&'a self, sink: &'a mut dyn LogSink) -> ChangedLog<'a> {
        ChangedLog::new(Some(self), sink)
    }

    /// The SU whose samples the change edits.
    fn sensor(&self) -> Option<&str> {
        match self {
            SkinChange::Bias { su, .. }
            | SkinChange::Scale { su, .. }
            | SkinChange::Silent { su }
            | SkinChange::Frozen { su, .. }
            | SkinChange::Railed { su }
            | SkinChange::Noisy { su, .. } => Some(su),
            SkinChange::Move { .. } | SkinChange::Swap { .. } | SkinChange::Zero { .. } => None,
        }
    }
}

/// A log sink behind which one board sends what a [`SkinChange`] makes of its samples.
pub struct ChangedLog<'a> {
    change: Option<&'a SkinChange>,
    sink: &'a mut dyn LogSink,
    /// The changed SU's index among the sink's SUs.
    su: Option<usize>,
    /// The added noise's generator and distribution.
    noise: Option<(ChaCha8Rng, Normal<f64>)>,
    /// The first sample's stamp, s.
    first: Option<f64>,
    /// A frozen board's last value.
    held: Option<[f64; 3]>,
}

impl<'a> ChangedLog<'a> {
    /// `sink` fed what the boards send after `change` (all of it as it is for none).
    pub fn new(change: Option<&'a SkinChange>, sink: &'a mut dyn LogSink) -> Self {
        Self {
            change,
            sink,
            su: None,
            noise: None,
            first: None,
            held: None,
        }
    }
}

impl LogSink for ChangedLog<'_> {
    fn start(
        &mut self,
        dofs: &[String],
        sus: &[String],
        acceleration_variance: f64,
    ) -> Result<(), LogError> {
        self.su = self
            .change
            .and_then(SkinChange::sensor)
            .and_then(|name| sus.iter().position(|s| s == name));
        if let Some(SkinChange::Noisy { factor, seed, .. }) = self.change {
            // A skin of unknown noise is taken at ±0.01 g.
            let sd = if acceleration_variance > 0.0 {
                acceleration_variance.sqrt()
            } else {
                0.01 * STANDARD_GRAVITY
            };
            let added = sd * (factor * factor - 1.0).max(0.0).sqrt();
            let normal = Normal::new(0.0, added).map_err(|e| LogError::Stopped(e.to_string()))?;
            self.noise = Some((super::stream(*seed, 77), normal));
        }
        self.sink.start(dofs, sus, acceleration_variance)
    }

    fn joint_state(
        &mut self,
        stamp: Time,
        receive: Time,
        positions: &[f64],
        velocities: &[f64],
    ) -> Result<(), LogError> {
        self.first.get_or_insert(stamp.seconds());
        self.sink.joint_state(stamp, receive, positions, velocities)
    }

    fn imu(&mut self, stamp: Time, receive: Time, su: usize, a: [f64; 3]) -> Result<(), LogError> {
        let first = *self.first.get_or_insert(stamp.seconds());
        let Some(change) = self.change.filter(|_| Some(su) == self.su) else {
            return self.sink.imu(stamp, receive, su, a);
        };
        let mut a = a;
        match change {
            SkinChange::Bias { bias, .. } => {
                for (x, b) in a.iter_mut().zip(bias) {
                    *x += b;
                }
            }
            SkinChange::Scale { scale, .. } => {
                for (x, s) in a.iter_mut().zip(scale) {
                    *x *= 1.0 + s;
                }
            }
            SkinChange::Silent { .. } => return Ok(()),
            SkinChange::Frozen { after, .. } => {
                if stamp.seconds() - first >= *after {
                    a = *self.held.get_or_insert(a);
                }
            }
            SkinChange::Railed { .. } => a[2] = 2.0 * STANDARD_GRAVITY,
            SkinChange::Noisy { .. } => {
                if let Some((rng, normal)) = &mut self.noise {
                    for x in &mut a {
                        *x += normal.sample(rng);
                    }
                }
            }
            SkinChange::Move { .. } | SkinChange::Swap { .. } | SkinChange::Zero { .. } => {}
        }
        self.sink.imu(stamp, receive, su, a)
    }

    fn finish(&mut self) -> Result<Vec<PathBuf>, LogError> {
        self.sink.finish()
    }
}
