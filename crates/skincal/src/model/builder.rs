//! Assembling a [`Robot`] from named parts, with every structural check in one place.

use std::collections::{HashMap, HashSet};

use nalgebra::{Isometry3, Unit, Vector3};
use serde::{Deserialize, Serialize};

use super::transform::to_xyz_rpy;
use super::{
    Dof, DofKind, Limits, Mimic, ModelError, Parameterization, Placement, Robot, RobotModel,
    Segment, SensorUnit,
};

/// A placement with its values, as given by a robot description.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct PlacementSpec {
    /// The parameterisation.
    pub kind: Parameterization,
    /// Its values, in the order of [`Parameterization::parameter_names`].
    pub values: Vec<f64>,
}

impl PlacementSpec {
    /// The identity placement.
    pub fn identity() -> Self {
        Self {
            kind: Parameterization::Identity,
            values: vec![],
        }
    }

    /// A standard DH placement (paper eq. 5).
    pub fn dh(theta0: f64, d: f64, a: f64, alpha: f64) -> Self {
        Self {
            kind: Parameterization::StandardDh,
            values: vec![theta0, d, a, alpha],
        }
    }

    /// A DH-plus-sensor-frame placement (paper eqs. 5 and 7).
    pub fn dh_sensor(theta0: f64, d: f64, a: f64, alpha: f64, theta_acc: f64, d_acc: f64) -> Self {
        Self {
            kind: Parameterization::StandardDhSensor,
            values: vec![theta0, d, a, alpha, theta_acc, d_acc],
        }
    }

    /// A URDF-style placement.
    pub fn xyz_rpy(xyz: [f64; 3], rpy: [f64; 3]) -> Self {
        Self {
            kind: Parameterization::XyzRpy,
            values: vec![xyz[0], xyz[1], xyz[2], rpy[0], rpy[1], rpy[2]],
        }
    }

    /// A URDF-style placement equal to `pose`.
    pub fn from_isometry(pose: &Isometry3<f64>) -> Self {
        let (xyz, rpy) = to_xyz_rpy(pose);
        Self::xyz_rpy(xyz, rpy)
    }

    /// The transform it describes.
    pub fn transform(&self) -> Isometry3<f64> {
        self.kind.transform(&self.values)
    }
}

/// A DoF as given by a robot description (segments by name).
#[derive(Debug, Clone, PartialEq)]
pub struct DofSpec {
    /// Unique name.
    pub name: String,
    /// Name of the segment it is mounted on.
    pub parent: String,
    /// Name of the segment it moves.
    pub child: String,
    /// Placement of its joint frame on the parent segment.
    pub origin: PlacementSpec,
    /// Axis in the joint frame (normalised by the builder): of rotation, or of translation.
    pub axis: Vector3<f64>,
    /// Revolute or prismatic.
    pub kind: DofKind,
    /// Limits.
    pub limits: Limits,
    /// The DoF it follows, if it is a mimic joint.
    pub mimic: Option<MimicSpec>,
}

/// A mimic DoF's leader by name, as a robot description gives it (URDF `<mimic>`).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct MimicSpec {
    /// The DoF it follows (URDF `joint`).
    #[serde(rename = "joint")]
    pub leader: String,
    /// `q = multiplier · q_leader + offset`.
    #[serde(default = "one")]
    pub multiplier: f64,
    /// Offset, rad or m.
    #[serde(default)]
    pub offset: f64,
}

fn one() -> f64 {
    1.0
}

/// A sensor unit as given by a robot description.
#[derive(Debug, Clone, PartialEq)]
pub struct SuSpec {
    /// Unique name.
    pub name: String,
    /// Name of its segment.
    pub segment: String,
    /// Placement of its accelerometer frame on the segment.
    pub placement: PlacementSpec,
}

/// Collects named DoFs and SUs and checks that they form a tree rooted at the reference segment.
#[derive(Debug, Clone, PartialEq)]
pub struct RobotBuilder {
    /// The robot's name.
    pub name: String,
    /// Name of the static reference segment (the root).
    pub reference: String,
    /// DoFs, in the order a pose vector uses.
    pub dofs: Vec<DofSpec>,
    /// Sensor units.
    pub sus: Vec<SuSpec>,
}

impl RobotBuilder {
    /// An empty robot with the given name and reference segment.
    pub fn new(name: impl Into<String>, reference: impl Into<String>) -> Self {
        Self {
            name: name.into(),
            reference: reference.into(),
            dofs: vec![],
            sus: vec![],
        }
    }

    /// Checks the description and assembles the model and its parameter vector.
    pub fn build(&self) -> Result<Robot, ModelError> {
        if self.dofs.is_empty() {
            return Err(ModelError::NoDofs);
        }
        unique("DoF", self.dofs.iter().map(|d| d.name.as_str()))?;
        unique("SU", self.sus.iter().map(|s| s.name.as_str()))?;
        self.check_segments()?;
        let (segments, segment_of) = self.segments_in_order()?;
        let mut parameters = Parameters::default();
        let dofs = self.dofs(&segment_of, &mut parameters)?;
        let sus = self.sus(&segment_of, &mut parameters)?;
        let moved_by = moved_by(&segments, &dofs);
        Ok(Robot {
            model: RobotModel {
                name: self.name.clone(),
                segments,
                dofs,
                sus,
                parameter_names: parameters.names,
                moved_by,
            },
            parameters: parameters.values,
        })
    }

    /// Every segment a child of one DoF at most (the reference of none), and every DoF and SU on a
    /// segment that exists.
    fn check_segments(&self) -> Result<(), ModelError> {
        let mut parents_of: HashMap<&str, Vec<usize>> = HashMap::new();
        for (i, d) in self.dofs.iter().enumerate() {
            parents_of.entry(d.child.as_str()).or_default().push(i);
        }
        for (segment, dofs) in &parents_of {
            if dofs.len() > 1 || *segment == self.reference {
                return Err(ModelError::SeveralParents {
                    segment: segment.to_string(),
                    dofs: dofs.iter().map(|&i| self.dofs[i].name.clone()).collect(),
                });
            }
        }
        let known: HashSet<&str> = std::iter::once(self.reference.as_str())
            .chain(self.dofs.iter().map(|d| d.child.as_str()))
            .collect();
        let on = self
            .dofs
            .iter()
            .map(|d| (format!("DoF `{}`", d.name), &d.parent))
            .chain(
                self.sus
                    .iter()
                    .map(|s| (format!("SU `{}`", s.name), &s.segment)),
            );
        for (what, segment) in on {
            if !known.contains(segment.as_str()) {
                return Err(ModelError::UnknownSegment {
                    what,
                    segment: segment.clone(),
                });
            }
        }
        Ok(())
    }

    /// The segments in topological order (a depth-first walk from the reference, children in DoF
    /// order), and each one's index by name.
    fn segments_in_order(&self) -> Result<(Vec<Segment>, HashMap<&str, usize>), ModelError> {
        let mut children: HashMap<&str, Vec<usize>> = HashMap::new();
        for (i, d) in self.dofs.iter().enumerate() {
            children.entry(d.parent.as_str()).or_default().push(i);
        }
        let mut segments = vec![Segment {
            name: self.reference.clone(),
            parent_dof: None,
        }];
        let mut segment_of: HashMap<&str, usize> = HashMap::from([(self.reference.as_str(), 0)]);
        let mut stack: Vec<usize> = children
            .get(self.reference.as_str())
            .cloned()
            .unwrap_or_default();
        stack.reverse();
        while let Some(d) = stack.pop() {
            let child = self.dofs[d].child.as_str();
            segment_of.insert(child, segments.len());
            segments.push(Segment {
                name: child.to_string(),
                parent_dof: Some(d),
            });
            if let Some(grand) = children.get(child) {
                stack.extend(grand.iter().rev());
            }
        }
        if let Some(d) = self
            .dofs
            .iter()
            .find(|d| !segment_of.contains_key(d.child.as_str()))
        {
            return Err(ModelError::Unreachable {
                segment: d.child.clone(),
                reference: self.reference.clone(),
            });
        }
        Ok((segments, segment_of))
    }

    /// The DoFs, their axes and limits checked and their origins placed in `parameters`.
    fn dofs(
        &self,
        segment_of: &HashMap<&str, usize>,
        parameters: &mut Parameters,
    ) -> Result<Vec<Dof>, ModelError> {
        let mut dofs = Vec::with_capacity(self.dofs.len());
        for d in &self.dofs {
            let norm = d.axis.norm();
            if !(norm.is_finite() && norm > 1e-9) {
                return Err(ModelError::InvalidAxis {
                    dof: d.name.clone(),
                    axis: d.axis.into(),
                });
            }
            d.limits
                .check()
                .map_err(|reason| ModelError::InvalidLimits {
                    dof: d.name.clone(),
                    reason,
                })?;
            let owner = format!("DoF `{}`", d.name);
            let origin = parameters.place(&owner, &d.origin, &format!("{}.origin.", d.name))?;
            let mimic = d.mimic.as_ref().map(|m| self.mimic(d, m)).transpose()?;
            dofs.push(Dof {
                name: d.name.clone(),
                parent: segment_of[d.parent.as_str()],
                child: segment_of[d.child.as_str()],
                origin,
                axis: Unit::new_normalize(d.axis),
                kind: d.kind,
                limits: d.limits,
                mimic,
            });
        }
        Ok(dofs)
    }

    /// DoF `d`'s mimic relation with its leader's index: a leader that exists, is another DoF
    /// and follows nobody, and finite factors.
    fn mimic(&self, d: &DofSpec, m: &MimicSpec) -> Result<Mimic, ModelError> {
        let invalid = |reason| ModelError::InvalidMimic {
            dof: d.name.clone(),
            leader: m.leader.clone(),
            reason,
        };
        let leader = self
            .dofs
            .iter()
            .position(|l| l.name == m.leader)
            .ok_or_else(|| invalid("is not a DoF of the robot"))?;
        if self.dofs[leader].name == d.name {
            return Err(invalid("is the DoF itself"));
        }
        if self.dofs[leader].mimic.is_some() {
            return Err(invalid("follows another DoF itself"));
        }
        if !(m.multiplier.is_finite() && m.offset.is_finite()) {
            return Err(invalid("it follows with a non-finite multiplier or offset"));
        }
        Ok(Mimic {
            leader,
            multiplier: m.multiplier,
            offset: m.offset,
        })
    }

    /// The SUs, their placements in `parameters` (after every DoF's).
    fn sus(
        &self,
        segment_of: &HashMap<&str, usize>,
        parameters: &mut Parameters,
    ) -> Result<Vec<SensorUnit>, ModelError> {
        self.sus
            .iter()
            .map(|s| {
                let owner = format!("SU `{}`", s.name);
                Ok(SensorUnit {
                    name: s.name.clone(),
                    segment: segment_of[s.segment.as_str()],
                    placement: parameters.place(&owner, &s.placement, &format!("{}.", s.name))?,
                })
            })
            .collect()
    }
}

/// The parameter vector as it is filled: names and values.
#[derive(Default)]
struct Parameters {
    names: Vec<String>,
    values: Vec<f64>,
}

impl Parameters {
    /// `spec`'s values appended under names `prefix` + parameter name; `owner` names it in errors.
    fn place(
        &mut self,
        owner: &str,
        spec: &PlacementSpec,
        prefix: &str,
    ) -> Result<Placement, ModelError> {
        if spec.values.len() != spec.kind.len() || spec.values.iter().any(|v| !v.is_finite()) {
            return Err(ModelError::NotFinite {
                what: owner.to_string(),
            });
        }
        let offset = self.values.len();
        self.values.extend_from_slice(&spec.values);
        self.names.extend(
            spec.kind
                .parameter_names()
                .iter()
                .map(|p| format!("{prefix}{p}")),
        );
        Ok(Placement {
            kind: spec.kind,
            offset,
        })
    }
}

/// `moved_by[segment][dof]`: whether the DoF, or a mimic DoF that follows it, lies on the path
/// from the reference to the segment (segments in topological order).
fn moved_by(segments: &[Segment], dofs: &[Dof]) -> Vec<Vec<bool>> {
    let mut moved_by = vec![vec![false; dofs.len()]; segments.len()];
    for s in 1..segments.len() {
        let d = segments[s]
            .parent_dof
            .expect("only the reference has no parent DoF");
        let mut row = moved_by[dofs[d].parent].clone();
        row[d] = true;
        if let Some(m) = dofs[d].mimic {
            row[m.leader] = true;
        }
        moved_by[s] = row;
    }
    moved_by
}

fn unique<'a>(kind: &'static str, names: impl Iterator<Item = &'a str>) -> Result<(), ModelError> {
    let mut seen = HashSet::new();
    for n in names {
        if !seen.insert(n) {
            return Err(ModelError::DuplicateName {
                kind,
                name: n.to_string(),
            });
        }
    }
    Ok(())
}

impl Robot {
    /// The placement of a DoF's joint origin or SU frame, with its values, as a description gives it.
    pub fn placement_spec(&self, placement: &Placement) -> PlacementSpec {
        PlacementSpec {
            kind: placement.kind,
            values: self.parameters[placement.range()].to_vec(),
        }
    }

    /// The builder that reproduces this robot (names, placements, axes and limits).
    pub fn to_builder(&self) -> RobotBuilder {
        let m = &self.model;
        RobotBuilder {
            name: m.name.clone(),
            reference: m.segments[0].name.clone(),
            dofs: m
                .dofs
                .iter()
                .map(|d| DofSpec {
                    name: d.name.clone(),
                    parent: m.segments[d.parent].name.clone(),
                    child: m.segments[d.child].name.clone(),
                    origin: self.placement_spec(&d.origin),
                    axis: d.axis.into_inner(),
                    kind: d.kind,
                    limits: d.limits,
                    mimic: d.mimic.map(|x| MimicSpec {
                        leader: m.dofs[x.leader].name.clone(),
                        multiplier: x.multiplier,
                        offset: x.offset,
                    }),
                })
                .collect(),
            sus: m
                .sus
                .iter()
                .map(|s| SuSpec {
                    name: s.name.clone(),
                    segment: m.segments[s.segment].name.clone(),
                    placement: self.placement_spec(&s.placement),
                })
                .collect(),
        }
    }
}
