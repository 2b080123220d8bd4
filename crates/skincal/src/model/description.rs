//! The TOML robot description format (documented in `docs/robot-format.md`).
//!
//! A description names the static reference segment, lists the DoFs (each with its parent and
//! child segment, the placement of its axis and its limits) and the SUs (segment and placement).
//! Axis placements are written either as DH rows (`dh = { theta0, d, a, alpha }`, axis z — the
//! paper's chains) or as URDF-like origins (`origin = { xyz, rpy }` plus `axis`). A description
//! may instead point at a URDF file (`urdf = "arm.urdf"`) and only add SUs on its links; reading
//! that file is the caller's job (see [`crate::io`]), the conversion is [`super::urdf`].

use nalgebra::{Isometry3, Vector3};
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use serde::{Deserialize, Serialize};

use super::{
    DofKind, DofSpec, Limits, MimicSpec, ModelError, Parameterization, PlacementSpec, Robot,
    RobotBuilder, SuSpec,
};

/// Errors in a robot description.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
#[non_exhaustive]
pub enum DescriptionError {
    /// The TOML text does not parse or does not have the expected fields (message has the line).
    #[error("{0}")]
    Syntax(String),
    /// A field has a value that is not allowed.
    #[error("{field}: {reason}")]
    Invalid {
        /// Path of the field, e.g. `dofs[2] (elbow).upper`.
        field: String,
        /// What is wrong and what to do.
        reason: String,
    },
    /// The URDF text does not parse.
    #[error("URDF does not parse: {0}")]
    Urdf(String),
    /// A URDF joint type that skincal cannot model.
    #[error("URDF joint `{joint}` is {kind}: skincal models revolute, continuous and prismatic DoFs only (fixed joints merge links); make it fixed or remove it")]
    UnsupportedJoint {
        /// The joint.
        joint: String,
        /// Its type.
        kind: String,
    },
    /// The parts do not form a valid tree.
    #[error(transparent)]
    Model(#[from] ModelError),
}

/// A robot description file.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct RobotFile {
    /// The robot's name.
    pub name: String,
    /// Free text.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub description: Option<String>,
    /// Name of the static reference segment; required unless `urdf` is given (then the URDF's
    /// root link is the reference).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub reference: Option<String>,
    /// A URDF file (relative to this file) that provides segments and DoFs.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub urdf: Option<String>,
    /// DoFs, in pose-vector order (not allowed together with `urdf`).
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub dofs: Vec<DofEntry>,
    /// Sensor units.
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub sus: Vec<SuEntry>,
}

/// One `[[dofs]]` entry.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct DofEntry {
    /// Unique name.
    pub name: String,
    /// Segment it is mounted on; defaults to the previous DoF's child (the reference for the
    /// first DoF), which makes serial chains short to write.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub parent: Option<String>,
    /// Segment it moves.
    pub child: String,
    /// Axis placement as a standard DH row from the parent segment's frame (axis = z).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub dh: Option<DhEntry>,
    /// Axis placement as a URDF-like origin on the parent segment.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub origin: Option<OriginEntry>,
    /// Axis in the joint frame (only with `origin` or no placement); default `[0, 0, 1]`.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub axis: Option<[f64; 3]>,
    /// `revolute` (the default) or `prismatic` (it slides along its axis; positions in m, and
    /// `lower` and `upper` are needed).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub kind: Option<DofKind>,
    /// Lowest position, rad. With `upper` omitted too, the DoF turns freely (±π is sampled).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub lower: Option<f64>,
    /// Highest position, rad.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub upper: Option<f64>,
    /// Largest speed, rad/s.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub velocity: Option<f64>,
    /// Largest angular acceleration, rad/s².
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub acceleration: Option<f64>,
    /// The DoF it follows, if it is a mimic joint with no actuator of its own:
    /// `mimic = { joint = "finger_1", multiplier = -1.0, offset = 0.0 }` (`multiplier` defaults
    /// to 1, `offset` to 0), `q = multiplier · q_joint + offset`.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub mimic: Option<MimicSpec>,
}

/// A standard DH row, paper eq. 5.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct DhEntry {
    /// Offset of the joint angle, rad.
    pub theta0: f64,
    /// Offset along z, m.
    pub d: f64,
    /// Length along x, m.
    pub a: f64,
    /// Twist about x, rad.
    pub alpha: f64,
}

/// A DH row to a virtual axis plus the sensor frame of eq. 7.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct DhSensorEntry {
    /// Offset of the joint angle, rad.
    pub theta0: f64,
    /// Offset along z, m.
    pub d: f64,
    /// Length along x, m.
    pub a: f64,
    /// Twist about x, rad.
    pub alpha: f64,
    /// Rotation of the accelerometer about the virtual axis, rad.
    pub theta_acc: f64,
    /// Translation of the accelerometer along the virtual axis, m.
    pub d_acc: f64,
}

impl DhEntry {
    /// The row from values in parameter order `theta0, d, a, alpha` (at least 4).
    pub fn from_values(v: &[f64]) -> Self {
        Self {
            theta0: v[0],
            d: v[1],
            a: v[2],
            alpha: v[3],
        }
    }

    /// The values in parameter order.
    pub fn values(&self) -> [f64; 4] {
        [self.theta0, self.d, self.a, self.alpha]
    }

    /// The row as a placement.
    pub fn placement(&self) -> PlacementSpec {
        PlacementSpec {
            kind: Parameterization::StandardDh,
            values: self.values().to_vec(),
        }
    }
}

impl DhSensorEntry {
    /// The row from values in parameter order `theta0, d, a, alpha, theta_acc, d_acc` (at least 6).
    pub fn from_values(v: &[f64]) -> Self {
        Self {
            theta0: v[0],
            d: v[1],
            a: v[2],
            alpha: v[3],
            theta_acc: v[4],
            d_acc: v[5],
        }
    }

    /// The values in parameter order.
    pub fn values(&self) -> [f64; 6] {
        [
            self.theta0,
            self.d,
            self.a,
            self.alpha,
            self.theta_acc,
            self.d_acc,
        ]
    }

    /// The row as a placement.
    pub fn placement(&self) -> PlacementSpec {
        PlacementSpec {
            kind: Parameterization::StandardDhSensor,
            values: self.values().to_vec(),
        }
    }
}

/// A URDF-like origin.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct OriginEntry {
    /// Translation, m.
    #[serde(default)]
    pub xyz: [f64; 3],
    /// Roll, pitch, yaw (rotation `Rz(yaw)·Ry(pitch)·Rx(roll)`), rad.
    #[serde(default)]
    pub rpy: [f64; 3],
}

/// One `[[sus]]` entry.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct SuEntry {
    /// Unique name.
    pub name: String,
    /// Segment it sits on (with `urdf`: any link name, fixed-joint links included).
    pub segment: String,
    /// Position on the segment, m.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub xyz: Option<[f64; 3]>,
    /// Orientation on the segment, rad.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub rpy: Option<[f64; 3]>,
    /// Placement as the paper's DoF-to-SU transform instead of `xyz`/`rpy`.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub dh: Option<DhSensorEntry>,
}

impl SuEntry {
    /// The placement this entry describes.
    pub fn placement(&self, field: &str) -> Result<PlacementSpec, DescriptionError> {
        match (&self.dh, self.xyz.is_some() || self.rpy.is_some()) {
            (Some(_), true) => Err(DescriptionError::Invalid {
                field: field.to_string(),
                reason: "give either `dh` or `xyz`/`rpy`, not both".into(),
            }),
            (Some(h), false) => Ok(h.placement()),
            (None, _) => Ok(PlacementSpec::xyz_rpy(
                self.xyz.unwrap_or_default(),
                self.rpy.unwrap_or_default(),
            )),
        }
    }
}

impl RobotFile {
    /// Parses TOML text; errors carry the line and column.
    pub fn from_toml(text: &str) -> Result<Self, DescriptionError> {
        toml::from_str(text)
            .map_err(|e| DescriptionError::Syntax(e.to_string().trim_end().to_string()))
    }

    /// Serialises to TOML.
    pub fn to_toml(&self) -> String {
        toml::to_string(self).expect("a robot file always serialises")
    }

    /// Builds the robot of a self-contained description (no `urdf`).
    pub fn to_builder(&self) -> Result<RobotBuilder, DescriptionError> {
        if self.urdf.is_some() {
            return Err(DescriptionError::Invalid {
                field: "urdf".into(),
                reason:
                    "this description refers to a URDF file; read it with skincal::io::read_robot"
                        .into(),
            });
        }
        let reference = self
            .reference
            .clone()
            .ok_or_else(|| DescriptionError::Invalid {
                field: "reference".into(),
                reason: "missing: name the static reference segment (the root of the tree)".into(),
            })?;
        let mut builder = RobotBuilder::new(self.name.clone(), reference.clone());
        let mut previous_child = reference;
        for (i, d) in self.dofs.iter().enumerate() {
            let field = format!("dofs[{i}] ({})", d.name);
            let invalid = |what: &str, reason: &str| DescriptionError::Invalid {
                field: format!("{field}{what}"),
                reason: reason.into(),
            };
            let origin = match (&d.dh, &d.origin) {
                (Some(_), Some(_)) => {
                    return Err(invalid("", "give either `dh` or `origin`, not both"))
                }
                (Some(_), None) if d.axis.is_some() => {
                    return Err(invalid(
                        ".axis",
                        "a DH placement rotates about z; remove `axis` or use `origin`",
                    ))
                }
                (Some(h), None) => h.placement(),
                (None, Some(o)) => PlacementSpec::xyz_rpy(o.xyz, o.rpy),
                (None, None) => PlacementSpec::identity(),
            };
            let kind = d.kind.unwrap_or_default();
            let limits = match (d.lower, d.upper) {
                (None, None) if kind == DofKind::Prismatic => {
                    return Err(invalid(
                        "",
                        "a prismatic DoF slides within limits: give `lower` and `upper` (m)",
                    ))
                }
                (None, None) => Limits {
                    velocity: d.velocity,
                    acceleration: d.acceleration,
                    ..Limits::CONTINUOUS
                },
                (Some(lower), Some(upper)) => Limits {
                    lower,
                    upper,
                    velocity: d.velocity,
                    acceleration: d.acceleration,
                },
                _ => {
                    return Err(invalid(
                        "",
                        "give both `lower` and `upper`, or neither for a freely turning DoF",
                    ))
                }
            };
            let parent = d.parent.clone().unwrap_or(previous_child);
            previous_child = d.child.clone();
            builder.dofs.push(DofSpec {
                name: d.name.clone(),
                parent,
                child: d.child.clone(),
                origin,
                axis: Vector3::from(d.axis.unwrap_or([0.0, 0.0, 1.0])),
                kind,
                limits,
                mimic: d.mimic.clone(),
            });
        }
        for (i, s) in self.sus.iter().enumerate() {
            builder.sus.push(SuSpec {
                name: s.name.clone(),
                segment: s.segment.clone(),
                placement: s.placement(&format!("sus[{i}] ({})", s.name))?,
            });
        }
        Ok(builder)
    }

    /// Builds and checks the robot of a self-contained description.
    pub fn build(&self) -> Result<Robot, DescriptionError> {
        Ok(self.to_builder()?.build()?)
    }

    /// The self-contained description of a robot (the inverse of [`RobotFile::build`]).
    pub fn from_robot(robot: &Robot, description: Option<String>) -> Self {
        let b = robot.to_builder();
        let dofs = b
            .dofs
            .iter()
            .map(|d| {
                let v = &d.origin.values;
                let (dh, origin) = match d.origin.kind {
                    Parameterization::Identity => (None, None),
                    Parameterization::StandardDh => (Some(DhEntry::from_values(v)), None),
                    Parameterization::XyzRpy => (
                        None,
                        Some(OriginEntry {
                            xyz: [v[0], v[1], v[2]],
                            rpy: [v[3], v[4], v[5]],
                        }),
                    ),
                    Parameterization::StandardDhSensor => {
                        let (xyz, rpy) = super::transform::to_xyz_rpy(&d.origin.transform());
                        (None, Some(OriginEntry { xyz, rpy }))
                    }
                };
                let free = d.kind == DofKind::Revolute
                    && d.limits.lower == Limits::CONTINUOUS.lower
                    && d.limits.upper == Limits::CONTINUOUS.upper;
                DofEntry {
                    name: d.name.clone(),
                    parent: Some(d.parent.clone()),
                    child: d.child.clone(),
                    axis: dh.is_none().then(|| d.axis.into()),
                    kind: (d.kind != DofKind::Revolute).then_some(d.kind),
                    dh,
                    origin,
                    lower: (!free).then_some(d.limits.lower),
                    upper: (!free).then_some(d.limits.upper),
                    velocity: d.limits.velocity,
                    acceleration: d.limits.acceleration,
                    mimic: d.mimic.clone(),
                }
            })
            .collect();
        let sus = b
            .sus
            .iter()
            .map(|s| {
                let v = &s.placement.values;
                match s.placement.kind {
                    Parameterization::StandardDhSensor => SuEntry {
                        name: s.name.clone(),
                        segment: s.segment.clone(),
                        xyz: None,
                        rpy: None,
                        dh: Some(DhSensorEntry::from_values(v)),
                    },
                    Parameterization::XyzRpy => SuEntry {
                        name: s.name.clone(),
                        segment: s.segment.clone(),
                        xyz: Some([v[0], v[1], v[2]]),
                        rpy: Some([v[3], v[4], v[5]]),
                        dh: None,
                    },
                    Parameterization::Identity | Parameterization::StandardDh => {
                        let (xyz, rpy) = super::transform::to_xyz_rpy(&s.placement.transform());
                        SuEntry {
                            name: s.name.clone(),
                            segment: s.segment.clone(),
                            xyz: Some(xyz),
                            rpy: Some(rpy),
                            dh: None,
                        }
                    }
                }
            })
            .collect();
        RobotFile {
            name: b.name,
            description,
            reference: Some(b.reference),
            urdf: None,
            dofs,
            sus,
        }
    }
}

/// Half-width of the cube in which [`random_su_placement`] places an SU around its anchor, m.
pub const RANDOM_SU_SPREAD: f64 = 0.05;

/// A random SU placement: uniform within ±[`RANDOM_SU_SPREAD`] of `anchor` and uniformly random in
/// orientation.
pub fn random_su_placement(rng: &mut impl Rng, anchor: &Isometry3<f64>) -> PlacementSpec {
    let offset = Vector3::from_fn(|_, _| rng.random_range(-RANDOM_SU_SPREAD..RANDOM_SU_SPREAD));
    let orientation = nalgebra::UnitQuaternion::from_quaternion(nalgebra::Quaternion::new(
        gaussian(rng),
        gaussian(rng),
        gaussian(rng),
        gaussian(rng),
    ));
    let pose = Isometry3::from_parts((anchor.translation.vector + offset).into(), orientation);
    PlacementSpec::from_isometry(&pose)
}

fn gaussian(rng: &mut impl Rng) -> f64 {
    rand_distr::Distribution::sample(&rand_distr::StandardNormal, rng)
}

/// The robot with its SUs replaced by `per_segment` random ones on every segment that carried at
/// least one SU, each placed around one of the original SUs of that segment (in turn).
/// Names are `<segment>_su<k>`, k from 1. Seeded: the same seed gives the same SUs.
pub fn with_random_sus(
    robot: &Robot,
    per_segment: usize,
    seed: u64,
) -> Result<Robot, DescriptionError> {
    let mut builder = robot.to_builder();
    let mut rng = ChaCha8Rng::seed_from_u64(seed);
    let mut sus = Vec::new();
    for segment in robot.model.segments() {
        let anchors: Vec<&SuSpec> = builder
            .sus
            .iter()
            .filter(|s| s.segment == segment.name)
            .collect();
        if anchors.is_empty() {
            continue;
        }
        for k in 0..per_segment {
            let anchor = anchors[k % anchors.len()].placement.transform();
            sus.push(SuSpec {
                name: format!("{}_su{}", segment.name, k + 1),
                segment: segment.name.clone(),
                placement: random_su_placement(
                    &mut rng,
                    &Isometry3::translation(
                        anchor.translation.x,
                        anchor.translation.y,
                        anchor.translation.z,
                    ),
                ),
            });
        }
    }
    builder.sus = sus;
    Ok(builder.build()?)
}
