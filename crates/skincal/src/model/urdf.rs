//! URDF import (via `urdf-rs`).
//!
//! Revolute, continuous and prismatic joints become DoFs; links joined by fixed joints are merged
//! into one segment, named after the link closest to the root, and every merged link keeps its
//! offset `T_segment←link`, so that joint origins and SU placements given on any link land
//! correctly. The root link becomes the static reference segment. Floating, planar and spherical
//! joints are rejected with an error naming the joint.

use std::collections::{HashMap, HashSet, VecDeque};

use nalgebra::{Isometry3, Vector3};
use rand::SeedableRng;
use rand_chacha::ChaCha8Rng;

use super::description::{random_su_placement, DescriptionError, SuEntry};
use super::transform::xyz_rpy;
use super::{DofKind, DofSpec, Limits, MimicSpec, PlacementSpec, Robot, RobotBuilder, SuSpec};

/// Where the SUs of an imported URDF come from.
#[derive(Debug, Clone, PartialEq)]
pub enum UrdfSus<'a> {
    /// Listed by a robot description, each on a named link.
    Listed(&'a [SuEntry]),
    /// `per_link` random SUs around the origin of every link, seeded.
    RandomPerLink {
        /// SUs on each link.
        per_link: usize,
        /// Seed of the placement.
        seed: u64,
    },
}

/// A URDF's joint, as the tree needs it.
#[derive(Debug, Clone, PartialEq)]
pub struct UrdfJoint {
    /// Its name.
    pub name: String,
    /// Its type.
    pub kind: urdf_rs::JointType,
    /// Parent link.
    pub parent: String,
    /// Child link.
    pub child: String,
    /// `T_parent←joint` (the child link's frame at the zero position).
    pub origin: Isometry3<f64>,
    /// The axis in the joint frame (unit; `x` for a fixed joint with none).
    pub axis: Vector3<f64>,
    /// The joint's limits as the file gives them.
    pub limit: urdf_rs::JointLimit,
    /// The joint it follows, if it is a mimic joint.
    pub mimic: Option<MimicSpec>,
}

/// A URDF's kinematic tree: its links and joints checked to form one tree, joints in breadth-first
/// order from the root, and every link's frame at the zero position.
#[derive(Debug, Clone, PartialEq)]
pub struct UrdfTree {
    /// The robot's name.
    pub name: String,
    /// The root link.
    pub root: String,
    /// The links, in file order.
    pub links: Vec<String>,
    /// The joints, in file order.
    pub joints: Vec<UrdfJoint>,
    /// Indices into `joints`, parents before children (breadth-first from the root).
    pub order: Vec<usize>,
    /// Each link's frame in the root link's frame at the zero position.
    pub frames: HashMap<String, Isometry3<f64>>,
}

/// The one root link of a URDF whose joints name only links it defines.
fn root_link(urdf: &urdf_rs::Robot) -> Result<&str, DescriptionError> {
    let invalid = |field: String, reason: String| DescriptionError::Invalid { field, reason };
    let links: HashSet<&str> = urdf.links.iter().map(|l| l.name.as_str()).collect();
    for j in &urdf.joints {
        for (role, link) in [("parent", &j.parent.link), ("child", &j.child.link)] {
            if !links.contains(link.as_str()) {
                return Err(invalid(
                    format!("joint `{}`", j.name),
                    format!("{role} link `{link}` is not defined"),
                ));
            }
        }
    }
    let children: HashSet<&str> = urdf.joints.iter().map(|j| j.child.link.as_str()).collect();
    let roots: Vec<&str> = urdf
        .links
        .iter()
        .map(|l| l.name.as_str())
        .filter(|l| !children.contains(l))
        .collect();
    match roots.as_slice() {
        [root] => Ok(root),
        [] => Err(invalid(
            "links".into(),
            "no root link (every link is some joint's child: a closed loop)".into(),
        )),
        many => Err(invalid(
            "links".into(),
            format!("several root links {many:?}: the URDF must be one tree"),
        )),
    }
}

/// A joint's unit axis (`x` for a fixed joint with none).
fn joint_axis(j: &urdf_rs::Joint) -> Result<Vector3<f64>, DescriptionError> {
    let axis = Vector3::from(j.axis.xyz.0);
    match axis.try_normalize(1e-12) {
        Some(a) if a.iter().all(|x| x.is_finite()) => Ok(a),
        _ if matches!(j.joint_type, urdf_rs::JointType::Fixed) => Ok(Vector3::x()),
        _ => Err(DescriptionError::Invalid {
            field: format!("joint `{}`.axis", j.name),
            reason: format!(
                "{:?} is not a direction: give a non-zero axis",
                axis.as_slice()
            ),
        }),
    }
}

impl UrdfTree {
    /// Parses URDF text and checks that it is one tree.
    pub fn parse(text: &str) -> Result<Self, DescriptionError> {
        let urdf = read_urdf(text)?;
        let invalid = |field: String, reason: String| DescriptionError::Invalid { field, reason };
        let root = root_link(&urdf)?;
        let mut by_parent: HashMap<&str, Vec<usize>> = HashMap::new();
        for (i, j) in urdf.joints.iter().enumerate() {
            by_parent.entry(j.parent.link.as_str()).or_default().push(i);
        }
        let mut frames = HashMap::from([(root.to_string(), Isometry3::identity())]);
        let mut joints: Vec<Option<UrdfJoint>> = vec![None; urdf.joints.len()];
        let mut order = Vec::with_capacity(urdf.joints.len());
        let mut queue = VecDeque::from([root]);
        while let Some(link) = queue.pop_front() {
            let frame = frames[link];
            for &i in by_parent.get(link).into_iter().flatten() {
                let j = &urdf.joints[i];
                let child = j.child.link.as_str();
                if frames.contains_key(child) {
                    return Err(invalid(
                        format!("joint `{}`", j.name),
                        format!("link `{child}` is reached twice (closed loop)"),
                    ));
                }
                let origin = xyz_rpy(j.origin.xyz.0, j.origin.rpy.0);
                let axis = joint_axis(j)?;
                frames.insert(child.to_string(), frame * origin);
                order.push(i);
                joints[i] = Some(UrdfJoint {
                    name: j.name.clone(),
                    kind: j.joint_type.clone(),
                    parent: link.to_string(),
                    child: child.to_string(),
                    origin,
                    axis,
                    limit: j.limit.clone(),
                    mimic: j.mimic.as_ref().map(|m| MimicSpec {
                        leader: m.joint.clone(),
                        multiplier: m.multiplier.unwrap_or(1.0),
                        offset: m.offset.unwrap_or(0.0),
                    }),
                });
                queue.push_back(child);
            }
        }
        if let Some(i) = joints.iter().position(Option::is_none) {
            return Err(invalid(
                format!("joint `{}`", urdf.joints[i].name),
                format!(
                    "not reached from the root link `{root}`: its links form a closed loop apart from the tree"
                ),
            ));
        }
        Ok(Self {
            name: urdf.name.clone(),
            root: root.to_string(),
            links: urdf.links.iter().map(|l| l.name.clone()).collect(),
            joints: joints.into_iter().flatten().collect(),
            order,
            frames,
        })
    }

    /// The joint whose child is `link` (none for the root).
    pub fn joint_to(&self, link: &str) -> Option<&UrdfJoint> {
        self.joints.iter().find(|j| j.child == link)
    }

    /// Links joined by fixed joints are one segment, named after the link closest to the root.
    pub fn segments(&self) -> Segments {
        let root = self.root.clone();
        let mut links = HashMap::from([(root.clone(), (root, Isometry3::identity()))]);
        let mut joints = HashMap::new();
        for j in self.order.iter().map(|&i| &self.joints[i]) {
            let (segment, offset) = links[&j.parent].clone();
            let origin = offset * j.origin;
            if matches!(j.kind, urdf_rs::JointType::Fixed) {
                links.insert(j.child.clone(), (segment, origin));
            } else {
                joints.insert(j.name.clone(), (segment, origin));
                links.insert(j.child.clone(), (j.child.clone(), Isometry3::identity()));
            }
        }
        Segments { links, joints }
    }

    /// The nearest joint above `link` that moves (not fixed), if any.
    pub fn moving_joint_above(&self, link: &str) -> Option<&UrdfJoint> {
        let mut link = link;
        while let Some(j) = self.joint_to(link) {
            if !matches!(j.kind, urdf_rs::JointType::Fixed) {
                return Some(j);
            }
            link = &j.parent;
        }
        None
    }
}

/// Parses URDF text with `urdf-rs`, leaving out what makers' files carry and `urdf-rs` refuses
/// although it says nothing: `<texture/>` elements without a file name (iCub's).
pub fn read_urdf(text: &str) -> Result<urdf_rs::Robot, DescriptionError> {
    let parse =
        |t: &str| urdf_rs::read_from_string(t).map_err(|e| DescriptionError::Urdf(e.to_string()));
    let Ok(doc) = roxmltree::Document::parse(text) else {
        return parse(text);
    };
    let mut empty: Vec<std::ops::Range<usize>> = doc
        .descendants()
        .filter(|n| n.has_tag_name("texture") && n.attribute("filename").is_none())
        .map(|n| n.range())
        .collect();
    if empty.is_empty() {
        return parse(text);
    }
    empty.sort_by_key(|r| r.start);
    let mut kept = String::with_capacity(text.len());
    let mut at = 0;
    for range in empty {
        kept.push_str(&text[at..range.start]);
        at = range.end;
    }
    kept.push_str(&text[at..]);
    parse(&kept)
}

/// Where a URDF's links and moving joints sit on the segments of its robot model.
#[derive(Debug, Clone, PartialEq)]
pub struct Segments {
    /// Per link: its segment and its frame in that segment (`T_segment←link`).
    pub links: HashMap<String, (String, Isometry3<f64>)>,
    /// Per moving joint: its parent segment and its origin in that segment.
    pub joints: HashMap<String, (String, Isometry3<f64>)>,
}

impl UrdfTree {
    /// Joint `j`'s leader as a DoF follows it: through a chain of mimic joints to the first that
    /// follows nobody (`q = m₂(m₁ q + o₁) + o₂`). A mimic tag on a fixed joint, or one naming a
    /// joint the file does not have, is left for the builder to report.
    fn mimic_of(&self, j: &UrdfJoint) -> Option<MimicSpec> {
        let mut spec = j.mimic.clone()?;
        for _ in 0..self.joints.len() {
            let Some(next) = self
                .joints
                .iter()
                .find(|l| l.name == spec.leader && l.name != j.name)
                .and_then(|l| l.mimic.as_ref())
            else {
                break;
            };
            spec = MimicSpec {
                leader: next.leader.clone(),
                multiplier: spec.multiplier * next.multiplier,
                offset: spec.multiplier * next.offset + spec.offset,
            };
        }
        Some(spec)
    }
}

/// Converts URDF text into a robot.
pub fn from_urdf(text: &str, sus: UrdfSus<'_>) -> Result<Robot, DescriptionError> {
    let tree = UrdfTree::parse(text)?;
    let invalid = |field: String, reason: String| DescriptionError::Invalid { field, reason };
    for j in &tree.joints {
        use urdf_rs::JointType as J;
        let kind = match j.kind {
            J::Revolute | J::Continuous | J::Prismatic | J::Fixed => continue,
            J::Floating => "floating",
            J::Planar => "planar",
            J::Spherical => "spherical",
        };
        return Err(DescriptionError::UnsupportedJoint {
            joint: j.name.clone(),
            kind: kind.into(),
        });
    }

    let Segments {
        links: placement,
        joints: joint_origin,
    } = tree.segments();
    let mut builder = RobotBuilder::new(tree.name.clone(), &tree.root);
    for j in tree
        .joints
        .iter()
        .filter(|j| !matches!(j.kind, urdf_rs::JointType::Fixed))
    {
        let (parent, origin) = joint_origin[j.name.as_str()].clone();
        let limits = if matches!(j.kind, urdf_rs::JointType::Continuous) {
            Limits {
                velocity: positive(j.limit.velocity),
                ..Limits::CONTINUOUS
            }
        } else {
            Limits {
                lower: j.limit.lower,
                upper: j.limit.upper,
                velocity: positive(j.limit.velocity),
                acceleration: positive(j.limit.acceleration),
            }
        };
        builder.dofs.push(DofSpec {
            name: j.name.clone(),
            parent,
            child: j.child.clone(),
            origin: PlacementSpec::from_isometry(&origin),
            axis: j.axis,
            kind: if matches!(j.kind, urdf_rs::JointType::Prismatic) {
                DofKind::Prismatic
            } else {
                DofKind::Revolute
            },
            limits,
            mimic: tree.mimic_of(j),
        });
    }

    match sus {
        UrdfSus::Listed(entries) => {
            for (i, s) in entries.iter().enumerate() {
                let field = format!("sus[{i}] ({})", s.name);
                let (segment, offset) = placement.get(s.segment.as_str()).ok_or_else(|| {
                    invalid(
                        format!("{field}.segment"),
                        format!("`{}` is not a link of the URDF", s.segment),
                    )
                })?;
                let pose = offset * s.placement(&field)?.transform();
                builder.sus.push(SuSpec {
                    name: s.name.clone(),
                    segment: segment.clone(),
                    placement: PlacementSpec::from_isometry(&pose),
                });
            }
        }
        UrdfSus::RandomPerLink { per_link, seed } => {
            let mut rng = ChaCha8Rng::seed_from_u64(seed);
            for link in &tree.links {
                let (segment, offset) = &placement[link.as_str()];
                for k in 0..per_link {
                    builder.sus.push(SuSpec {
                        name: format!("{}_su{}", link, k + 1),
                        segment: segment.clone(),
                        placement: random_su_placement(&mut rng, offset),
                    });
                }
            }
        }
    }
    Ok(builder.build()?)
}

fn positive(v: f64) -> Option<f64> {
    (v.is_finite() && v > 0.0).then_some(v)
}

/// A robot as URDF text, kinematics only: one link per segment (the reference segment is the root
/// link), one `continuous` joint per revolute DoF named after it (origin and axis as in the model;
/// the range the model's limits give is noted in a comment, not written as a `<limit>`: the
/// robot's real limits, effort and velocity are not known), one `prismatic` joint per prismatic
/// DoF (whose `<limit>` URDF requires: the model's range, effort and velocity 0 as unknown), a
/// `<mimic>` on each DoF that follows another, and one link per SU named after it, attached
/// to its segment by a fixed joint `<su>_mount` (origin only). No link has inertial values.
/// Loading the text back and composing the joints gives the model's forward kinematics.
///
/// ```
/// use skincal::model::presets;
/// use skincal::model::urdf::{to_urdf, UrdfTree};
///
/// let robot = presets::find("paper-7dof").unwrap().robot().unwrap();
/// let text = to_urdf(&robot).unwrap();
/// let tree = UrdfTree::parse(&text).unwrap();
/// // One joint per DoF and one fixed mount per SU.
/// assert_eq!(tree.joints.len(), 7 + 7);
/// ```
pub fn to_urdf(robot: &Robot) -> Result<String, DescriptionError> {
    use crate::show::xml_escape;
    let m = &robot.model;
    let k = super::forward_kinematics(m, &robot.parameters, &vec![0.0; m.dofs().len()]);
    for su in m.sus() {
        if m.segments().iter().any(|s| s.name == su.name) {
            return Err(DescriptionError::Invalid {
                field: format!("sus.{}", su.name),
                reason: "an SU has the name of a segment: URDF link names must be unique".into(),
            });
        }
    }
    let origin = |t: &Isometry3<f64>| {
        let (r, p, y) = t.rotation.euler_angles();
        let v = t.translation.vector;
        format!(
            "<origin xyz=\"{} {} {}\" rpy=\"{r} {p} {y}\"/>",
            v.x, v.y, v.z
        )
    };
    let mut out = String::new();
    out.push_str("<?xml version=\"1.0\"?>\n");
    out.push_str(
        "<!-- Kinematics only, from skincal's calibration: link frames, joint axes and SU frames. \
         No inertial values, and no joint limits (the robot's are not known: the DoFs are \
         continuous joints; each notes the range the calibration data covered). -->\n",
    );
    out.push_str(&format!("<robot name=\"{}\">\n", xml_escape(m.name())));
    // MuJoCo refuses moving bodies without mass: it may bound them instead; and it keeps links
    // on fixed joints (the SUs) as bodies of their own (other readers skip the element).
    out.push_str(
        "  <mujoco><compiler boundmass=\"1e-6\" boundinertia=\"1e-12\" fusestatic=\"false\"/></mujoco>\n",
    );
    for s in m.segments() {
        out.push_str(&format!("  <link name=\"{}\"/>\n", xml_escape(&s.name)));
    }
    for su in m.sus() {
        out.push_str(&format!("  <link name=\"{}\"/>\n", xml_escape(&su.name)));
    }
    for (d, dof) in m.dofs().iter().enumerate() {
        let placement = k.segments[dof.parent].inverse() * k.joints[d];
        let axis = dof.axis.into_inner();
        let kind = match dof.kind {
            DofKind::Revolute => "continuous",
            DofKind::Prismatic => "prismatic",
        };
        out.push_str(&format!(
            "  <joint name=\"{}\" type=\"{kind}\">\n",
            xml_escape(&dof.name)
        ));
        if dof.kind == DofKind::Prismatic {
            out.push_str(&format!(
                "    <limit lower=\"{}\" upper=\"{}\" effort=\"0\" velocity=\"0\"/>\n",
                dof.limits.lower, dof.limits.upper
            ));
        } else if dof.limits != super::Limits::CONTINUOUS {
            out.push_str(&format!(
                "    <!-- calibrated over {} … {} rad -->\n",
                dof.limits.lower, dof.limits.upper
            ));
        }
        if let Some(mimic) = &dof.mimic {
            out.push_str(&format!(
                "    <mimic joint=\"{}\" multiplier=\"{}\" offset=\"{}\"/>\n",
                xml_escape(&m.dofs()[mimic.leader].name),
                mimic.multiplier,
                mimic.offset
            ));
        }
        out.push_str(&format!(
            "    {}\n    <parent link=\"{}\"/>\n    <child link=\"{}\"/>\n    <axis xyz=\"{} {} {}\"/>\n  </joint>\n",
            origin(&placement),
            xml_escape(&m.segments()[dof.parent].name),
            xml_escape(&m.segments()[dof.child].name),
            axis.x,
            axis.y,
            axis.z
        ));
    }
    for (u, su) in m.sus().iter().enumerate() {
        out.push_str(&format!(
            "  <joint name=\"{}_mount\" type=\"fixed\">\n    {}\n    <parent link=\"{}\"/>\n    <child link=\"{}\"/>\n  </joint>\n",
            xml_escape(&su.name),
            origin(&(k.segments[su.segment].inverse() * k.sus[u])),
            xml_escape(&m.segments()[su.segment].name),
            xml_escape(&su.name)
        ));
    }
    out.push_str("</robot>\n");
    Ok(out)
}
