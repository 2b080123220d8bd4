//! Self-collision of a robot's body on its URDF collision geometry (parry3d).
//!
//! Every `<collision>` element of the URDF becomes one part on its link's segment: boxes, spheres,
//! cylinders and capsules as they are, meshes as their convex hull (what MuJoCo and most
//! planners collide). Two parts collide when they come closer than the [`CollisionOptions::clearance`]
//! (the skin on both surfaces); a part comes too near the floor when it is lower than
//! the floor plus half of that.
//!
//! Pairs that are not checked, as motion planners set them:
//! * parts of one segment (links joined by fixed joints);
//! * parts of adjacent segments: a segment and the nearest segment above it that has geometry
//!   (the links of a multi-DoF joint between them carry none); and of segments next but one
//!   when they touch at the rest pose (hulls that overlap around the joint between);
//! * pairs the robot's SRDF disables (`<disable_collisions link1 link2>`).
//!
//! Pairs that touch already at the rest pose (a hand beside a thigh, a cover over its neighbour)
//! are checked against going deeper: they collide when they come [`REST_SLACK`] nearer than at
//! rest (signed distances: overlap is negative).
//!
//! The floor check leaves out the reference segment's parts (the base stands on the floor).
//! Mesh files are read by the caller ([`crate::io::load_body`]); this module touches no file.

use std::collections::{BTreeMap, HashMap, HashSet};

use nalgebra::{Isometry3, Point3, UnitQuaternion, Vector3};
use parry3d_f64::bounding_volume::{Aabb, BoundingVolume};
use parry3d_f64::shape::SharedShape;

use crate::model::urdf::UrdfTree;
use crate::model::{forward_kinematics, Robot, SegmentIndex};

/// Errors building a robot's collision body.
#[derive(Debug, thiserror::Error)]
#[non_exhaustive]
pub enum CollisionError {
    /// The URDF does not parse or is not one tree.
    #[error("{0}")]
    Urdf(String),
    /// A link's mesh cannot be read or has no volume.
    #[error("link `{link}`: collision mesh `{file}`: {reason}")]
    Mesh {
        /// The link.
        link: String,
        /// The file name as the URDF gives it.
        file: String,
        /// What went wrong and what to do.
        reason: String,
    },
    /// An SRDF names a link the URDF does not have, or does not parse.
    #[error("SRDF: {0}")]
    Srdf(String),
}

/// What counts as a collision.
#[derive(Debug, Clone, PartialEq)]
pub struct CollisionOptions {
    /// The smallest distance allowed between two parts, m: the skin's thickness on both.
    pub clearance: f64,
    /// Height of a floor or table plane in the reference segment's frame (`z` up), m, if any.
    pub floor: Option<f64>,
    /// Link pairs not checked (from an SRDF's `disable_collisions`).
    pub disabled: Vec<(String, String)>,
}

impl Default for CollisionOptions {
    fn default() -> Self {
        Self {
            clearance: 2.0 * SKIN_THICKNESS,
            floor: None,
            disabled: Vec::new(),
        }
    }
}

/// A skin's thickness assumed where none is given, m.
pub const SKIN_THICKNESS: f64 = 0.005;

/// How much nearer than at rest two parts that touch at rest may come, m.
pub const REST_SLACK: f64 = 0.005;

/// Why a pair of links is not checked.
#[derive(Debug, Clone, Copy, PartialEq, Eq, serde::Serialize, serde::Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum Exclusion {
    /// Adjacent segments (or one segment).
    Adjacent,
    /// The SRDF disables the pair.
    Srdf,
    /// One joint apart with a link between them, and touching at the rest pose: their hulls
    /// overlap around the joint.
    NextButOneTouching,
}

/// A link pair that is not checked, and why.
#[derive(Debug, Clone, PartialEq, Eq, serde::Serialize, serde::Deserialize)]
pub struct ExcludedPair {
    /// One link.
    pub a: String,
    /// The other.
    pub b: String,
    /// Why.
    pub why: Exclusion,
}

/// Two parts (or a part and the floor) closer than allowed.
#[derive(Debug, Clone, PartialEq)]
pub struct Contact {
    /// One link.
    pub a: String,
    /// The other link, or `floor`.
    pub b: String,
    /// Their distance, m (negative: they overlap).
    pub distance: f64,
    /// The segments of `a` and `b` (the reference segment for the floor).
    pub segments: (SegmentIndex, SegmentIndex),
}

impl std::fmt::Display for Contact {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(
            f,
            "{} and {} {:.1} mm apart",
            self.a,
            self.b,
            self.distance * 1e3
        )
    }
}

struct Part {
    link: String,
    segment: SegmentIndex,
    /// `T_segment←shape`.
    offset: Isometry3<f64>,
    shape: SharedShape,
    /// The shape's bounding box in its own frame.
    local_box: Aabb,
}

/// Two links that touch at the rest pose.
#[derive(Debug, Clone, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct RestContact {
    /// One link.
    pub a: String,
    /// The other.
    pub b: String,
    /// Their signed distance at rest, m (negative: they overlap).
    pub distance: f64,
}

/// The parts' bounding boxes at a pose: each enclosing box (its local box turned with it) at
/// once, the exact one only where the enclosing boxes meet.
struct Boxes {
    enclosing: Vec<Aabb>,
    exact: Vec<Option<Aabb>>,
}

/// A robot's collision geometry, ready to check poses.
pub struct Body {
    parts: Vec<Part>,
    /// Index pairs into `parts` that are checked, each with the signed distance below which
    /// they collide.
    pairs: Vec<(usize, usize, f64)>,
    excluded: Vec<ExcludedPair>,
    at_rest: Vec<RestContact>,
    options: CollisionOptions,
}

impl std::fmt::Debug for Body {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("Body")
            .field("parts", &self.parts.len())
            .field("pairs", &self.pairs.len())
            .field("excluded", &self.excluded)
            .field("at_rest", &self.at_rest)
            .field("options", &self.options)
            .finish()
    }
}

/// A mesh's vertices, m, in the mesh file's frame. A Collada file's `<up_axis>` turns its
/// vertices to `z` up, as ROS's mesh readers (assimp) do.
pub fn mesh_vertices(bytes: &[u8], file: &str) -> Result<Vec<Point3<f64>>, String> {
    let scene = mesh_loader::Loader::default()
        .load_from_slice(bytes, file)
        .map_err(|e| e.to_string())?;
    let up = collada_up_axis(bytes);
    Ok(scene
        .meshes
        .iter()
        .flat_map(|m| m.vertices.iter())
        .map(|v| {
            let [x, y, z] = v.map(f64::from);
            match up {
                Some('Y') => Point3::new(x, -z, y),
                Some('X') => Point3::new(-y, x, z),
                _ => Point3::new(x, y, z),
            }
        })
        .collect())
}

/// The axis a Collada file's `<asset><up_axis>` names (`X`, `Y` or `Z`), if it is one.
fn collada_up_axis(bytes: &[u8]) -> Option<char> {
    let text = std::str::from_utf8(bytes).ok()?;
    let doc = roxmltree::Document::parse(text).ok()?;
    let axis = doc
        .descendants()
        .find(|n| n.has_tag_name("up_axis"))?
        .text()?
        .trim()
        .chars()
        .next()?;
    Some(axis)
}

/// Collision shapes from URDF geometry; each mesh's convex hull made once per file and scale.
struct Hulls<'m> {
    shapes: HashMap<(String, [u64; 3]), SharedShape>,
    /// A mesh file's bytes by the name the URDF gives.
    mesh: &'m mut dyn FnMut(&str) -> Result<Vec<u8>, String>,
}

impl Hulls<'_> {
    /// The shape of `geometry` on `link`, and the turn that brings parry's axis onto the URDF's.
    fn shape(
        &mut self,
        link: &str,
        geometry: &urdf_rs::Geometry,
    ) -> Result<(SharedShape, Option<UnitQuaternion<f64>>), CollisionError> {
        Ok(match geometry {
            urdf_rs::Geometry::Box { size } => (
                SharedShape::cuboid(size[0] / 2.0, size[1] / 2.0, size[2] / 2.0),
                None,
            ),
            urdf_rs::Geometry::Sphere { radius } => (SharedShape::ball(*radius), None),
            // URDF cylinders run along z, parry's along y.
            urdf_rs::Geometry::Cylinder { radius, length } => (
                SharedShape::cylinder(length / 2.0, *radius),
                Some(UnitQuaternion::from_axis_angle(
                    &Vector3::x_axis(),
                    std::f64::consts::FRAC_PI_2,
                )),
            ),
            urdf_rs::Geometry::Capsule { radius, length } => {
                (SharedShape::capsule_z(length / 2.0, *radius), None)
            }
            urdf_rs::Geometry::Mesh { filename, scale } => {
                let scale = scale.map_or([1.0; 3], |s| s.0);
                (self.hull(link, filename, scale)?, None)
            }
        })
    }

    /// The convex hull of mesh `file` scaled by `scale`.
    fn hull(
        &mut self,
        link: &str,
        file: &str,
        scale: [f64; 3],
    ) -> Result<SharedShape, CollisionError> {
        let key = (file.to_string(), scale.map(f64::to_bits));
        if let Some(shape) = self.shapes.get(&key) {
            return Ok(shape.clone());
        }
        let error = |reason: String| CollisionError::Mesh {
            link: link.to_string(),
            file: file.to_string(),
            reason,
        };
        let bytes = (self.mesh)(file).map_err(error)?;
        let points: Vec<Point3<f64>> = mesh_vertices(&bytes, file)
            .map_err(error)?
            .into_iter()
            .map(|p| Point3::new(p.x * scale[0], p.y * scale[1], p.z * scale[2]))
            .collect();
        let hull = SharedShape::convex_hull(&points).ok_or_else(|| {
            error(format!(
                "its {} vertices have no volume (a flat or empty mesh): \
                 give the link a box or another mesh",
                points.len()
            ))
        })?;
        self.shapes.insert(key, hull.clone());
        Ok(hull)
    }
}

impl Body {
    /// The collision body of `robot` (loaded from the URDF `text`): `mesh` returns a mesh
    /// file's bytes by the file name the URDF gives. A link with no collision element has no
    /// part; the rest pose decides which pairs always touch.
    pub fn new(
        text: &str,
        robot: &Robot,
        options: &CollisionOptions,
        mesh: &mut dyn FnMut(&str) -> Result<Vec<u8>, String>,
    ) -> Result<Body, CollisionError> {
        let urdf =
            crate::model::urdf::read_urdf(text).map_err(|e| CollisionError::Urdf(e.to_string()))?;
        let tree = UrdfTree::parse(text).map_err(|e| CollisionError::Urdf(e.to_string()))?;
        let placement = tree.segments().links;
        let model = &robot.model;
        let segment_index: HashMap<&str, SegmentIndex> = model
            .segments()
            .iter()
            .enumerate()
            .map(|(i, s)| (s.name.as_str(), i))
            .collect();
        let mut parts = Vec::new();
        let mut hulls = Hulls {
            shapes: HashMap::new(),
            mesh,
        };
        for link in &urdf.links {
            let Some((segment, link_offset)) = placement.get(&link.name) else {
                continue;
            };
            let Some(&segment) = segment_index.get(segment.as_str()) else {
                continue;
            };
            for c in &link.collision {
                let origin = crate::model::transform::xyz_rpy(c.origin.xyz.0, c.origin.rpy.0);
                let (shape, turn) = hulls.shape(&link.name, &c.geometry)?;
                let mut offset = link_offset * origin;
                if let Some(turn) = turn {
                    offset *= Isometry3::from_parts(Default::default(), turn);
                }
                parts.push(Part {
                    link: link.name.clone(),
                    segment,
                    offset,
                    local_box: shape.compute_local_aabb(),
                    shape,
                });
            }
        }
        let links: HashSet<&str> = urdf.links.iter().map(|l| l.name.as_str()).collect();
        for (a, b) in &options.disabled {
            for l in [a, b] {
                if !links.contains(l.as_str()) {
                    return Err(CollisionError::Srdf(format!(
                        "disable_collisions names link `{l}`, which the URDF does not have: \
                         is it the SRDF of another robot?"
                    )));
                }
            }
        }
        let mut body = Body {
            parts,
            pairs: Vec::new(),
            excluded: Vec::new(),
            at_rest: Vec::new(),
            options: options.clone(),
        };
        body.choose_pairs(robot);
        Ok(body)
    }

    /// The pairs to check: every pair of parts but those of one or adjacent segments, those the
    /// SRDF disables and those that touch at the rest pose.
    fn choose_pairs(&mut self, robot: &Robot) {
        let model = &robot.model;
        let has_parts: HashSet<SegmentIndex> = self.parts.iter().map(|p| p.segment).collect();
        // The nearest segment above each one that has geometry.
        let above = |s: SegmentIndex| {
            let mut s = s;
            while let Some(d) = model.segments()[s].parent_dof {
                s = model.dofs()[d].parent;
                if has_parts.contains(&s) {
                    return Some(s);
                }
            }
            None
        };
        let disabled: HashSet<(&str, &str)> = self
            .options
            .disabled
            .iter()
            .flat_map(|(a, b)| [(a.as_str(), b.as_str()), (b.as_str(), a.as_str())])
            .collect();
        // By link pair, names in order, so that the lists come out sorted.
        let link_pair = |a: &Part, b: &Part| {
            let (a, b) = (a.link.clone(), b.link.clone());
            if a <= b {
                (a, b)
            } else {
                (b, a)
            }
        };
        let mut excluded: BTreeMap<(String, String), Exclusion> = BTreeMap::new();
        let mut candidates = Vec::new();
        for i in 0..self.parts.len() {
            for j in i + 1..self.parts.len() {
                let (a, b) = (&self.parts[i], &self.parts[j]);
                let key = link_pair(a, b);
                if a.segment == b.segment
                    || above(a.segment) == Some(b.segment)
                    || above(b.segment) == Some(a.segment)
                {
                    excluded.entry(key).or_insert(Exclusion::Adjacent);
                } else if disabled.contains(&(a.link.as_str(), b.link.as_str())) {
                    excluded.entry(key).or_insert(Exclusion::Srdf);
                } else {
                    candidates.push((i, j));
                }
            }
        }
        // Pairs that touch at rest: next but one in the tree (a joint's hulls overlapping
        // around it) are not checked; others are held to their rest distance less the slack.
        let rest = rest_pose(robot);
        let frames = self.frames(robot, &rest);
        let mut boxes = self.boxes(&frames);
        let clearance = self.options.clearance;
        let mut at_rest: BTreeMap<(String, String), f64> = BTreeMap::new();
        let mut pairs = Vec::with_capacity(candidates.len());
        for (i, j) in candidates {
            let Some(d) = self.distance(&frames, &mut boxes, (i, j), clearance) else {
                pairs.push((i, j, clearance));
                continue;
            };
            let (a, b) = (&self.parts[i], &self.parts[j]);
            let next_but_one = above(a.segment).and_then(above) == Some(b.segment)
                || above(b.segment).and_then(above) == Some(a.segment);
            if next_but_one {
                excluded
                    .entry(link_pair(a, b))
                    .or_insert(Exclusion::NextButOneTouching);
                continue;
            }
            let nearest = at_rest.entry(link_pair(a, b)).or_insert(d);
            *nearest = nearest.min(d);
            pairs.push((i, j, d - REST_SLACK));
        }
        self.pairs = pairs;
        self.excluded = excluded
            .into_iter()
            .map(|((a, b), why)| ExcludedPair { a, b, why })
            .collect();
        self.at_rest = at_rest
            .into_iter()
            .map(|((a, b), distance)| RestContact { a, b, distance })
            .collect();
    }

    /// Every part's frame at `q`.
    fn frames(&self, robot: &Robot, q: &[f64]) -> Vec<Isometry3<f64>> {
        let k = forward_kinematics(&robot.model, &robot.parameters, q);
        self.parts
            .iter()
            .map(|p| k.segments[p.segment] * p.offset)
            .collect()
    }

    /// Every part's bounding boxes in the frames `frames`.
    fn boxes(&self, frames: &[Isometry3<f64>]) -> Boxes {
        Boxes {
            enclosing: self
                .parts
                .iter()
                .zip(frames)
                .map(|(p, f)| p.local_box.transform_by(f))
                .collect(),
            exact: vec![None; self.parts.len()],
        }
    }

    /// Part `i`'s exact bounding box in `frames` (kept in `boxes` once computed).
    fn exact_box(&self, frames: &[Isometry3<f64>], boxes: &mut Boxes, i: usize) -> Aabb {
        *boxes.exact[i].get_or_insert_with(|| self.parts[i].shape.compute_aabb(&frames[i]))
    }

    /// The signed distance of parts `i` and `j` (negative: the depth of their overlap) if it is
    /// below `limit`.
    fn distance(
        &self,
        frames: &[Isometry3<f64>],
        boxes: &mut Boxes,
        (i, j): (usize, usize),
        limit: f64,
    ) -> Option<f64> {
        let margin = limit.max(0.0);
        // The enclosing boxes first: where they keep apart, so do the exact ones.
        if !boxes.enclosing[i]
            .loosened(margin)
            .intersects(&boxes.enclosing[j])
        {
            return None;
        }
        let (box_i, box_j) = (
            self.exact_box(frames, boxes, i),
            self.exact_box(frames, boxes, j),
        );
        if !box_i.loosened(margin).intersects(&box_j) {
            return None;
        }
        let (a, b) = (&self.parts[i], &self.parts[j]);
        let contact =
            parry3d_f64::query::contact(&frames[i], &*a.shape, &frames[j], &*b.shape, margin)
                .ok()??;
        (contact.dist < limit).then_some(contact.dist)
    }

    /// The first contact at pose `q` (rad, one per DoF), if any: two checked parts closer than
    /// the clearance, or a part of a moving segment nearer the floor than half of it.
    pub fn contact(&self, robot: &Robot, q: &[f64]) -> Option<Contact> {
        self.contact_within(robot, q, 0.0)
    }

    /// [`Body::contact`] with `extra` m added to every distance allowed.
    pub fn contact_within(&self, robot: &Robot, q: &[f64], extra: f64) -> Option<Contact> {
        let frames = self.frames(robot, q);
        let mut boxes = self.boxes(&frames);
        for &(i, j, limit) in &self.pairs {
            if let Some(distance) = self.distance(&frames, &mut boxes, (i, j), limit + extra) {
                return Some(Contact {
                    a: self.parts[i].link.clone(),
                    b: self.parts[j].link.clone(),
                    distance,
                    segments: (self.parts[i].segment, self.parts[j].segment),
                });
            }
        }
        let floor = self.options.floor?;
        let skin = self.options.clearance / 2.0 + extra;
        // The lowest point of a convex part is its exact bounding box's bottom, which the
        // enclosing box's is below.
        let near: Vec<usize> = (0..self.parts.len())
            .filter(|&i| self.parts[i].segment != 0 && boxes.enclosing[i].mins.z - floor < skin)
            .collect();
        near.into_iter().find_map(|i| {
            let low = self.exact_box(&frames, &mut boxes, i).mins.z - floor;
            let p = &self.parts[i];
            (low < skin).then(|| Contact {
                a: p.link.clone(),
                b: "floor".into(),
                distance: low,
                segments: (p.segment, 0),
            })
        })
    }

    /// Parts (collision elements) with geometry.
    pub fn part_count(&self) -> usize {
        self.parts.len()
    }

    /// Pairs of parts that are checked.
    pub fn pair_count(&self) -> usize {
        self.pairs.len()
    }

    /// The link pairs that are not checked, and why.
    pub fn excluded(&self) -> &[ExcludedPair] {
        &self.excluded
    }

    /// The link pairs that touch at the rest pose: they collide when they come
    /// [`REST_SLACK`] nearer.
    pub fn touching_at_rest(&self) -> &[RestContact] {
        &self.at_rest
    }

    /// What counts as a collision.
    pub fn options(&self) -> &CollisionOptions {
        &self.options
    }
}

/// A robot's body as a plan's [`crate::plan::Clearance`]: the plan's poses name its DoFs in the
/// plan's order; the robot's other DoFs stay at the rest pose.
pub struct PlanClearance<'a> {
    body: &'a Body,
    robot: &'a Robot,
    /// Per plan DoF, the robot's DoF.
    dofs: Vec<usize>,
    /// Where the robot's other DoFs stay.
    rest: Vec<f64>,
}

impl<'a> PlanClearance<'a> {
    /// The clearance of `robot`'s `body` for poses of the DoFs `names` (in that order). A name the
    /// robot does not have is an error naming it.
    pub fn new(body: &'a Body, robot: &'a Robot, names: &[String]) -> Result<Self, String> {
        let dofs = names
            .iter()
            .map(|n| {
                robot
                    .model
                    .dofs()
                    .iter()
                    .position(|d| &d.name == n)
                    .ok_or_else(|| format!("the robot has no DoF `{n}`"))
            })
            .collect::<Result<_, _>>()?;
        Ok(Self {
            body,
            robot,
            dofs,
            rest: rest_pose(robot),
        })
    }
}

impl crate::plan::Clearance for PlanClearance<'_> {
    fn contact(&self, q: &[f64], extra: f64) -> Option<crate::plan::Touch> {
        let mut pose = self.rest.clone();
        for (&d, &v) in self.dofs.iter().zip(q) {
            pose[d] = v;
        }
        let contact = self.body.contact_within(self.robot, &pose, extra)?;
        let between = dofs_between(&self.robot.model, contact.segments.0, contact.segments.1);
        Some(crate::plan::Touch {
            what: contact.to_string(),
            dofs: (0..self.dofs.len())
                .filter(|&i| between.contains(&self.dofs[i]))
                .collect(),
        })
    }

    fn rules(&self) -> crate::plan::CollisionRules {
        let body = self.body;
        crate::plan::CollisionRules {
            clearance: body.options.clearance,
            not_checked: body
                .excluded
                .iter()
                .map(|e| [e.a.clone(), e.b.clone()])
                .collect(),
            touching_at_rest: body
                .at_rest
                .iter()
                .map(|c| (c.a.clone(), c.b.clone(), c.distance))
                .collect(),
        }
    }
}

/// The DoFs on the tree's path between segments `a` and `b`.
fn dofs_between(model: &crate::model::RobotModel, a: SegmentIndex, b: SegmentIndex) -> Vec<usize> {
    let up = |mut s: SegmentIndex| {
        let mut path = Vec::new();
        while let Some(d) = model.segments()[s].parent_dof {
            path.push((s, d));
            s = model.dofs()[d].parent;
        }
        path
    };
    let (pa, pb) = (up(a), up(b));
    let on_a: HashSet<SegmentIndex> = pa.iter().map(|(s, _)| *s).collect();
    let on_b: HashSet<SegmentIndex> = pb.iter().map(|(s, _)| *s).collect();
    // Below the lowest common segment: on one path and not the other.
    pa.iter()
        .filter(|(s, _)| !on_b.contains(s))
        .chain(pb.iter().filter(|(s, _)| !on_a.contains(s)))
        .map(|(_, d)| *d)
        .collect()
}

/// Every DoF at 0, or at the limit nearest to it: the pose a URDF's geometry is drawn in.
fn rest_pose(robot: &Robot) -> Vec<f64> {
    robot
        .model
        .dofs()
        .iter()
        .map(|d| 0f64.clamp(d.limits.lower, d.limits.upper))
        .collect()
}

/// The `disable_collisions` pairs of an SRDF's text.
pub fn srdf_disabled_pairs(text: &str) -> Result<Vec<(String, String)>, CollisionError> {
    let doc = roxmltree::Document::parse(text).map_err(|e| CollisionError::Srdf(e.to_string()))?;
    doc.descendants()
        .filter(|n| n.has_tag_name("disable_collisions"))
        .map(|n| {
            let link = |name: &str| {
                n.attribute(name).map(str::to_string).ok_or_else(|| {
                    let line = doc.text_pos_at(n.range().start).row;
                    CollisionError::Srdf(format!(
                        "the <disable_collisions> element on line {line} has no {name}"
                    ))
                })
            };
            Ok((link("link1")?, link("link2")?))
        })
        .collect()
}
