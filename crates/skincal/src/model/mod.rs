//! The kinematic model of a skin-covered robot.
//!
//! A robot is a tree of rigid **segments** joined by revolute or prismatic **DoFs**; **sensor units** (SUs, one
//! 3-axis accelerometer each) sit on segments. The model is flat and immutable: segments are stored
//! in topological order (index 0 is the static reference segment, every segment after its parent),
//! DoFs and SUs in the order they were given, and every number that describes the geometry lives
//! in a separate parameter vector (see [`Placement`]). Forward kinematics
//! ([`forward_kinematics`]) is a free function over `(model, parameters, q)`, generic over the
//! scalar so that estimators differentiate it with dual numbers.
//!
//! Frames: the **reference frame** is the frame of segment 0 (the paper's `RS`). A DoF's **joint
//! frame** is placed on its parent segment by the DoF's origin [`Placement`]; the DoF rotates about
//! a fixed unit axis expressed in that joint frame (`z` for DH placements), and the child segment's
//! frame is the joint frame rotated by the DoF position `q`:
//!
//! ```text
//! T_ref←child(q) = T_ref←parent(q) · T_origin · Rot(axis, q)
//! ```
//!
//! With DH placements this is exactly the paper's chain (eq. 4): the origin of DoF `d+1` on the
//! segment of DoF `d` is `Rz(θ0_d)·Tz(d_d)·Tx(a_d)·Rx(α_d)`, and `Rot(z, q_d) · Rz(θ0_d) = Rz(θ0_d + q_d)`
//! gives eq. 5 with `θ = θ0 + pose` (eq. 6). An SU's frame is its segment's frame times its own
//! placement, e.g. the paper's DoF-to-SU DH transform followed by eq. 7.

mod builder;
pub mod description;
pub mod intrinsics;
mod kinematics;
pub mod presets;
pub mod sensor;
pub mod transform;
pub mod urdf;

pub use builder::{DofSpec, MimicSpec, PlacementSpec, RobotBuilder, SuSpec};
pub use kinematics::{
    forward_kinematics, segment_frames, segment_motion, specific_force, BodyMotion, Kinematics,
};

use nalgebra::{Isometry3, RealField, Unit, Vector3};
use serde::{Deserialize, Serialize};

/// Index of a segment in [`RobotModel::segments`].
pub type SegmentIndex = usize;
/// Index of a DoF in [`RobotModel::dofs`] (and in a pose vector `q`).
pub type DofIndex = usize;
/// Index of a sensor unit in [`RobotModel::sus`].
pub type SuIndex = usize;

/// Errors raised while assembling a robot model.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
#[non_exhaustive]
pub enum ModelError {
    /// Two DoFs, two SUs or two segments share a name.
    #[error("duplicate {kind} name `{name}`: every {kind} needs a unique name")]
    DuplicateName {
        /// "DoF", "SU" or "segment".
        kind: &'static str,
        /// The repeated name.
        name: String,
    },
    /// A DoF or SU refers to a segment that does not exist.
    #[error("{what} refers to unknown segment `{segment}`")]
    UnknownSegment {
        /// The DoF or SU that refers to it.
        what: String,
        /// The missing segment.
        segment: String,
    },
    /// A segment is the child of more than one DoF (a closed loop), or the reference is a child.
    #[error("segment `{segment}` is the child of several DoFs ({dofs:?}); skincal models trees only (no closed loops), and the reference segment must not be anybody's child")]
    SeveralParents {
        /// The segment.
        segment: String,
        /// The DoFs that name it as their child.
        dofs: Vec<String>,
    },
    /// A segment cannot be reached from the reference segment.
    #[error("segment `{segment}` is not connected to the reference segment `{reference}` (check the parent/child names of its DoFs)")]
    Unreachable {
        /// The segment.
        segment: String,
        /// The reference segment.
        reference: String,
    },
    /// A DoF's axis is zero or not finite.
    #[error("DoF `{dof}` has an invalid axis {axis:?}: give a non-zero, finite direction")]
    InvalidAxis {
        /// The DoF.
        dof: String,
        /// The axis as given.
        axis: [f64; 3],
    },
    /// A DoF's limits are impossible.
    #[error("DoF `{dof}` has impossible limits: {reason}")]
    InvalidLimits {
        /// The DoF.
        dof: String,
        /// What is wrong.
        reason: String,
    },
    /// A geometric value is NaN or infinite.
    #[error("{what} has a non-finite value in its placement")]
    NotFinite {
        /// The DoF or SU.
        what: String,
    },
    /// A mimic DoF's leader is missing, is itself, or is itself a follower.
    #[error("DoF `{dof}` mimics `{leader}`, which {reason}: a mimic DoF follows a DoF with its own actuator")]
    InvalidMimic {
        /// The mimic DoF.
        dof: String,
        /// The leader it names.
        leader: String,
        /// What is wrong.
        reason: &'static str,
    },
    /// The model has no DoF.
    #[error("the robot has no DoF: at least one revolute or prismatic DoF is needed")]
    NoDofs,
}

/// How a fixed transform (a DoF's joint origin or an SU's frame) is parameterised.
///
/// Conventions are distinct variants, never flags: the parameter names and their order are given
/// by [`Parameterization::parameter_names`].
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum Parameterization {
    /// The identity transform; no parameters.
    Identity,
    /// Standard DH (paper eq. 5): `Rz(θ0)·Tz(d)·Tx(a)·Rx(α)`; parameters `theta0, d, a, alpha`.
    StandardDh,
    /// Standard DH to a virtual axis, then the sensor frame of eq. 7:
    /// `Rz(θ0)·Tz(d)·Tx(a)·Rx(α)·Rz(θ_acc)·Tz(d_acc)`; parameters
    /// `theta0, d, a, alpha, theta_acc, d_acc`.
    StandardDhSensor,
    /// URDF-style origin: translation, then `Rz(yaw)·Ry(pitch)·Rx(roll)`; parameters
    /// `x, y, z, roll, pitch, yaw`.
    XyzRpy,
}

impl Parameterization {
    /// Names of the parameters, in vector order.
    pub fn parameter_names(self) -> &'static [&'static str] {
        match self {
            Self::Identity => &[],
            Self::StandardDh => &["theta0", "d", "a", "alpha"],
            Self::StandardDhSensor => &["theta0", "d", "a", "alpha", "theta_acc", "d_acc"],
            Self::XyzRpy => &["x", "y", "z", "roll", "pitch", "yaw"],
        }
    }

    /// Number of parameters.
    pub fn len(self) -> usize {
        self.parameter_names().len()
    }

    /// Whether it has no parameters.
    pub fn is_empty(self) -> bool {
        self.len() == 0
    }

    /// The transform for the given parameters (`p.len() == self.len()`).
    pub fn transform<T: RealField>(self, p: &[T]) -> Isometry3<T> {
        use transform::{sensor_frame, standard_dh, xyz_rpy};
        match self {
            Self::Identity => Isometry3::identity(),
            Self::StandardDh => standard_dh(p[0].clone(), p[1].clone(), p[2].clone(), p[3].clone()),
            Self::StandardDhSensor => {
                standard_dh(p[0].clone(), p[1].clone(), p[2].clone(), p[3].clone())
                    * sensor_frame(p[4].clone(), p[5].clone())
            }
            Self::XyzRpy => xyz_rpy(
                [p[0].clone(), p[1].clone(), p[2].clone()],
                [p[3].clone(), p[4].clone(), p[5].clone()],
            ),
        }
    }
}

/// A fixed transform of the model: its parameterisation and where its parameters start in the
/// parameter vector.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
pub struct Placement {
    /// The parameterisation.
    pub kind: Parameterization,
    /// Index of the first parameter in the parameter vector.
    pub offset: usize,
}

impl Placement {
    /// The range of this placement's parameters in the parameter vector.
    pub fn range(&self) -> std::ops::Range<usize> {
        self.offset..self.offset + self.kind.len()
    }

    /// The transform for the given full parameter vector.
    pub fn transform<T: RealField>(&self, parameters: &[T]) -> Isometry3<T> {
        self.kind.transform(&parameters[self.range()])
    }
}

/// Position, velocity and acceleration limits of a DoF (rad, rad/s, rad/s²; m, m/s, m/s² for a
/// prismatic one).
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct Limits {
    /// Lowest position.
    pub lower: f64,
    /// Highest position.
    pub upper: f64,
    /// Largest speed, if known.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub velocity: Option<f64>,
    /// Largest angular acceleration, if known.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub acceleration: Option<f64>,
}

impl Limits {
    /// Full turn in both directions, no velocity or acceleration limit.
    pub const CONTINUOUS: Limits = Limits {
        lower: -std::f64::consts::PI,
        upper: std::f64::consts::PI,
        velocity: None,
        acceleration: None,
    };

    /// `q` clamped into `[lower, upper]`.
    pub fn clamp(&self, q: f64) -> f64 {
        q.clamp(self.lower, self.upper)
    }

    fn check(&self) -> Result<(), String> {
        if !self.lower.is_finite() || !self.upper.is_finite() {
            return Err(format!(
                "lower {} and upper {} must be finite numbers",
                self.lower, self.upper
            ));
        }
        if self.lower > self.upper {
            return Err(format!(
                "lower {} is above upper {}",
                self.lower, self.upper
            ));
        }
        for (name, value) in [
            ("velocity", self.velocity),
            ("acceleration", self.acceleration),
        ] {
            if let Some(v) = value {
                if !(v.is_finite() && v > 0.0) {
                    return Err(format!("{name} limit {v} must be a positive finite number"));
                }
            }
        }
        Ok(())
    }
}

/// A rigid body of the robot.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Segment {
    /// Unique name.
    pub name: String,
    /// The DoF whose child this segment is; `None` for the reference segment.
    pub parent_dof: Option<DofIndex>,
}

/// How a DoF moves the segment it carries.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum DofKind {
    /// It turns about its axis; positions in rad.
    #[default]
    Revolute,
    /// It slides along its axis; positions in m. It turns no gravity, so only the accelerations of
    /// its motion tell what it carries and where its axis points.
    Prismatic,
}

/// Metres of travel a prismatic DoF makes per radian of a revolute DoF's excitation pattern: its
/// pattern is the revolute one scaled by this (eqs. 10–12 with `A` in m/s), so that the plan's one
/// pattern drives a gripper finger or a linear axis as a point 0.1 m from a revolute axis moves.
pub const PRISMATIC_PATTERN_SCALE: f64 = 0.1;

impl DofKind {
    /// The transform of the child segment's frame in the joint frame at position `q`.
    pub fn motion<T: RealField>(self, axis: &Unit<Vector3<f64>>, q: T) -> Isometry3<T> {
        match self {
            Self::Revolute => Isometry3::from_parts(
                nalgebra::Translation3::identity(),
                transform::rotation_about(axis, q),
            ),
            Self::Prismatic => Isometry3::from_parts(
                nalgebra::Translation3::from(transform::vector::<T>(axis.as_ref()) * q),
                nalgebra::UnitQuaternion::identity(),
            ),
        }
    }

    /// The unit of its position: `rad` or `m`.
    pub fn unit(self) -> &'static str {
        match self {
            Self::Revolute => "rad",
            Self::Prismatic => "m",
        }
    }

    /// The factor from the plan's excitation pattern (rad) to this DoF's (1 or
    /// [`PRISMATIC_PATTERN_SCALE`]).
    pub fn pattern_scale(self) -> f64 {
        match self {
            Self::Revolute => 1.0,
            Self::Prismatic => PRISMATIC_PATTERN_SCALE,
        }
    }

    /// Its name as URDF and the robot descriptions spell it.
    pub fn name(self) -> &'static str {
        match self {
            Self::Revolute => "revolute",
            Self::Prismatic => "prismatic",
        }
    }
}

/// A degree of freedom: revolute or prismatic.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Dof {
    /// Unique name.
    pub name: String,
    /// The segment it is mounted on.
    pub parent: SegmentIndex,
    /// The segment it moves.
    pub child: SegmentIndex,
    /// Placement of the joint frame on the parent segment.
    pub origin: Placement,
    /// Unit axis in the joint frame: of rotation, or of translation for a prismatic DoF.
    pub axis: Unit<Vector3<f64>>,
    /// Revolute or prismatic.
    #[serde(default, skip_serializing_if = "is_revolute")]
    pub kind: DofKind,
    /// Limits.
    pub limits: Limits,
    /// The DoF it follows, if it is a mimic joint (no actuator of its own).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub mimic: Option<Mimic>,
}

/// How a mimic DoF (a URDF `<mimic>` joint: a gripper's second finger, a hand's coupled
/// phalanges) follows its leader: `q = multiplier · q_leader + offset`, in the follower's own unit
/// (rad or m). It has no actuator: a plan never moves it alone, and the kinematics compute its
/// position, velocity and acceleration from the leader's, whatever a pose vector holds for it.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct Mimic {
    /// The DoF it follows (itself never a follower).
    pub leader: DofIndex,
    /// Factor on the leader's position.
    pub multiplier: f64,
    /// Offset, rad or m.
    #[serde(default)]
    pub offset: f64,
}

impl Dof {
    /// Its position in pose `q`: `q[leader]·multiplier + offset` for a mimic DoF, else `q[own]`.
    pub fn position<T: RealField>(&self, own: DofIndex, q: &[T]) -> T {
        match &self.mimic {
            Some(m) => {
                q[m.leader].clone() * transform::scalar(m.multiplier) + transform::scalar(m.offset)
            }
            None => q[own].clone(),
        }
    }

    /// Its rate (velocity or acceleration) from the pose-rate vector `rates`: the leader's times
    /// the multiplier for a mimic DoF, else its own.
    pub fn rate<T: RealField>(&self, own: DofIndex, rates: &[T]) -> T {
        match &self.mimic {
            Some(m) => rates[m.leader].clone() * transform::scalar(m.multiplier),
            None => rates[own].clone(),
        }
    }
}

fn is_revolute(kind: &DofKind) -> bool {
    *kind == DofKind::Revolute
}

/// A sensor unit: one 3-axis accelerometer on a segment.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct SensorUnit {
    /// Unique name.
    pub name: String,
    /// The segment it is mounted on.
    pub segment: SegmentIndex,
    /// Placement of the accelerometer frame on the segment.
    pub placement: Placement,
}

/// The structure of a robot: segments, DoFs, SUs and the layout of the parameter vector.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct RobotModel {
    name: String,
    segments: Vec<Segment>,
    dofs: Vec<Dof>,
    sus: Vec<SensorUnit>,
    parameter_names: Vec<String>,
    /// `moved_by[segment][dof]`: whether the DoF lies on the path from the reference to the segment.
    moved_by: Vec<Vec<bool>>,
}

impl RobotModel {
    /// The robot's name.
    pub fn name(&self) -> &str {
        &self.name
    }

    /// Segments in topological order; index 0 is the reference segment.
    pub fn segments(&self) -> &[Segment] {
        &self.segments
    }

    /// DoFs in input order (the order of a pose vector `q`).
    pub fn dofs(&self) -> &[Dof] {
        &self.dofs
    }

    /// Sensor units in input order.
    pub fn sus(&self) -> &[SensorUnit] {
        &self.sus
    }

    /// Names of all parameters, e.g. `dof2.origin.alpha` or `su3.theta_acc`.
    pub fn parameter_names(&self) -> &[String] {
        &self.parameter_names
    }

    /// Length of the parameter vector.
    pub fn parameter_count(&self) -> usize {
        self.parameter_names.len()
    }

    /// Whether moving `dof` moves `segment` (the DoF, or a mimic DoF that follows it, is on the
    /// segment's path to the reference).
    pub fn moves_segment(&self, dof: DofIndex, segment: SegmentIndex) -> bool {
        self.moved_by[segment][dof]
    }

    /// Whether moving `dof` moves sensor unit `su`.
    pub fn moves_su(&self, dof: DofIndex, su: SuIndex) -> bool {
        self.moved_by[self.sus[su].segment][dof]
    }

    /// The DoFs from the reference to `segment`, root first.
    pub fn chain_to(&self, segment: SegmentIndex) -> Vec<DofIndex> {
        let mut chain = Vec::new();
        let mut s = segment;
        while let Some(d) = self.segments[s].parent_dof {
            chain.push(d);
            s = self.dofs[d].parent;
        }
        chain.reverse();
        chain
    }

    /// Index of the DoF with this name.
    pub fn dof_index(&self, name: &str) -> Option<DofIndex> {
        self.dofs.iter().position(|d| d.name == name)
    }

    /// Index of the SU with this name.
    pub fn su_index(&self, name: &str) -> Option<SuIndex> {
        self.sus.iter().position(|s| s.name == name)
    }

    /// Index of the segment with this name.
    pub fn segment_index(&self, name: &str) -> Option<SegmentIndex> {
        self.segments.iter().position(|s| s.name == name)
    }

    /// DoF names in order.
    pub fn dof_names(&self) -> Vec<String> {
        self.dofs.iter().map(|d| d.name.clone()).collect()
    }

    /// Names of the prismatic DoFs, in order.
    pub fn prismatic_dof_names(&self) -> Vec<String> {
        self.dofs
            .iter()
            .filter(|d| d.kind == DofKind::Prismatic)
            .map(|d| d.name.clone())
            .collect()
    }

    /// Whether DoF `d` follows another (a mimic joint).
    pub fn is_follower(&self, d: DofIndex) -> bool {
        self.dofs[d].mimic.is_some()
    }

    /// The DoFs that have an actuator (every DoF but the mimic ones), in order: those a plan moves.
    pub fn driven_dofs(&self) -> Vec<DofIndex> {
        (0..self.dofs.len())
            .filter(|&d| !self.is_follower(d))
            .collect()
    }

    /// The mimic DoFs that follow `leader`.
    pub fn followers_of(&self, leader: DofIndex) -> Vec<DofIndex> {
        (0..self.dofs.len())
            .filter(|&d| self.dofs[d].mimic.is_some_and(|m| m.leader == leader))
            .collect()
    }

    /// `q` with every mimic DoF's entry set from its leader's (`rates`: without the offset, for
    /// velocities and accelerations), so a pose written out agrees with what the kinematics use.
    pub fn follow_leaders(&self, q: &mut [f64], rates: bool) {
        for (d, dof) in self.dofs.iter().enumerate() {
            if let Some(m) = dof.mimic {
                q[d] = q[m.leader] * m.multiplier + if rates { 0.0 } else { m.offset };
            }
        }
    }

    /// Each mimic DoF's name with its leader's, as a measurement set lists them.
    pub fn mimic_specs(&self) -> std::collections::BTreeMap<String, MimicSpec> {
        self.dofs
            .iter()
            .filter_map(|d| {
                let m = d.mimic?;
                Some((
                    d.name.clone(),
                    MimicSpec {
                        leader: self.dofs[m.leader].name.clone(),
                        multiplier: m.multiplier,
                        offset: m.offset,
                    },
                ))
            })
            .collect()
    }

    /// SU names in order.
    pub fn su_names(&self) -> Vec<String> {
        self.sus.iter().map(|s| s.name.clone()).collect()
    }
}

/// A model together with the parameter values that describe one concrete robot.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Robot {
    /// The structure.
    pub model: RobotModel,
    /// One value per [`RobotModel::parameter_names`] entry (m, rad).
    pub parameters: Vec<f64>,
}

impl Robot {
    /// The value of the parameter with this name.
    pub fn parameter(&self, name: &str) -> Option<f64> {
        let i = self.model.parameter_names.iter().position(|n| n == name)?;
        Some(self.parameters[i])
    }
}
