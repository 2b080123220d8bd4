//! Structural exploration (paper Section II-B, Algorithm 1): from static readings to the kinematic
//! tree, with diagnostics instead of failures.
//!
//! 1. **Activity matrix** `A` (SU × DoF): `A[u][d] = 1` when SU `u`'s static reading changes by more
//!    than a threshold (default 0.05 g) on any axis between the rest pose and the pose in which only
//!    DoF `d` moved. Matrices of several base orientations are OR-ed: a DoF whose axis happens to be
//!    vertical rotates gravity about itself and changes no reading, so the reference segment is tilted
//!    by 90° for a second matrix. The measured change of every entry is kept; entries within a factor
//!    of 2 of the threshold are *uncertain*.
//! 2. **Merging**: DoFs with identical columns form one joint (several DoFs with no SU between them);
//!    SUs with identical rows (over joints) form one segment.
//! 3. **Connectivity**: the row of a segment is the set of joints between it and the reference, so
//!    the reference is the null row, and a segment's parent is the segment whose row is its own less
//!    exactly one joint — the joint that connects them. Ordering segments depth-first from the root
//!    and every joint by its child gives the paper's strictly lower-triangular matrix with ones on
//!    the secondary diagonal.
//! 4. **Anatomy**: end effectors (leaves), branching segments (more than two joints) and the limbs
//!    from the reference or a branching segment to the next end effector or branching segment.
//!
//! A mimic DoF has no column (its leader's moves move it); the SUs on the bodies it drives share
//! their leader's row and are told apart by their readings (`mimic.rs`) and set aside.
//!
//! Whatever does not fit a tree is reported in plain words and left out, and the largest
//! consistent part of the tree is returned.

use std::collections::{BTreeMap, HashMap};

use fixedbitset::FixedBitSet;
use serde::{Deserialize, Serialize};

use crate::measurements::MeasurementSet;
use crate::model::sensor::STANDARD_GRAVITY;

mod activity;
mod checks;
mod mimic;

pub use activity::{activity_matrix, broken_sus, ActivityMatrix, BrokenSu, Inferred, Misread};
use checks::physical_checks;
pub use mimic::MimicDriven;

/// Settings of the exploration.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct ExploreConfig {
    /// An entry is active when a reading changes by more than this on any axis, in g.
    pub threshold: f64,
    /// Entries whose change lies within this factor of the threshold are uncertain.
    pub uncertainty_factor: f64,
    /// Largest difference, rad, between how far two static SUs' gravity readings turn when the base
    /// is re-oriented, for them to count as one rigid reference segment.
    pub static_turn_tolerance: f64,
}

impl Default for ExploreConfig {
    fn default() -> Self {
        Self {
            threshold: 0.05,
            uncertainty_factor: 2.0,
            static_turn_tolerance: 0.15,
        }
    }
}

/// Errors that stop exploration before it starts.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
#[non_exhaustive]
pub enum ExploreError {
    /// The measurement set has no structure experiment.
    #[error("the measurement set has no structure experiment (`structure`): record one (skincal simulate, or skincal ingest of the structure moves)")]
    NoStructureExperiment,
    /// The structure experiment moves no DoF.
    #[error(
        "the structure experiment has no moves: every DoF must be moved once from the rest pose"
    )]
    NoMoves,
    /// A setting is out of range.
    #[error("{setting}: {reason}")]
    InvalidSetting {
        /// The setting.
        setting: &'static str,
        /// What is wrong.
        reason: String,
    },
}

/// How serious a diagnostic is.
#[derive(Debug, Clone, Copy, PartialEq, Eq, PartialOrd, Ord, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum Severity {
    /// Worth knowing; the tree is right.
    Info,
    /// The tree is consistent, but something deserves a look.
    Warning,
    /// Part of the robot is missing from the tree, or may be wrong.
    Error,
}

/// What a diagnostic is about.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum DiagnosticKind {
    /// A DoF was never moved in the structure experiment.
    DofNotExplored,
    /// A DoF changed no SU's reading.
    DofMovesNoSu,
    /// No SU stayed still: there is no null row.
    NoStaticSegment,
    /// SUs stayed still but do not turn with the reference segment: more than one null row.
    SeveralStaticGroups,
    /// Rows that cannot be sorted into a tree.
    Unsortable,
    /// A segment without SU had to be assumed to connect the tree.
    SegmentWithoutSu,
    /// An uncertain entry whose flip would make an SU fit the tree.
    UncertainEntry,
    /// Several DoFs form one joint; their order is not in the matrix.
    MultiDofJoint,
    /// In one move the SUs' readings turned by different angles: more than the one DoF moved
    /// (the base tilted, or another DoF slipped).
    MoveNotRigid,
    /// The readings are too noisy for the threshold: entries are decided by noise.
    TooNoisy,
    /// Readings that no accelerometer at rest reads (a glitch): left out, their entries decided
    /// by the other orientation.
    MisreadReading,
    /// An SU that reads zeros, the same value in every pose, or an axis stuck at its range.
    BrokenSu,
    /// SUs on a body that a mimic DoF drives, not the body of the DoF they move with.
    MimicDriven,
    /// DoFs whose axis stood vertical in every base orientation, their columns read from what
    /// they accelerated.
    UprightAxis,
}

/// A finding, with the SUs and DoFs involved and the likely cause in plain words.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Diagnostic {
    /// What it is about.
    pub kind: DiagnosticKind,
    /// How serious it is.
    pub severity: Severity,
    /// Plain words: what was seen, the likely cause, what to do.
    pub message: String,
    /// SUs involved.
    pub sus: Vec<String>,
    /// DoFs involved.
    pub dofs: Vec<String>,
}

/// A segment of the discovered tree.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct SegmentNode {
    /// `S0` (the reference), `S1`, … in depth-first order.
    pub id: String,
    /// The SUs on it.
    pub sus: Vec<String>,
    /// The joint that moves it (none for the reference).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub parent_joint: Option<String>,
    /// Assumed to connect the tree although no SU was seen on it.
    #[serde(default, skip_serializing_if = "std::ops::Not::not")]
    pub without_su: bool,
}

/// A joint of the discovered tree.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct JointNode {
    /// `J1`, `J2`, …: joint `Jn` moves segment `Sn`.
    pub id: String,
    /// Its DoFs, in input order (the order along the chain is not in the activity matrix).
    pub dofs: Vec<String>,
    /// The segment it is mounted on.
    pub parent: String,
    /// The segment it moves.
    pub child: String,
}

/// A limb: from a reference (the root or a branching segment) to an end effector or the next
/// branching segment.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Limb {
    /// The reference segment.
    pub from: String,
    /// The last segment.
    pub to: String,
    /// Joints from the reference outwards.
    pub joints: Vec<String>,
    /// Segments after the reference, outwards.
    pub segments: Vec<String>,
    /// DoFs from the reference outwards (input order inside a multi-DoF joint).
    pub dofs: Vec<String>,
    /// SUs on the limb's segments, segment by segment.
    pub sus: Vec<String>,
}

/// An uncertain entry of the activity matrix.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct UncertainEntry {
    /// The SU.
    pub su: String,
    /// The DoF.
    pub dof: String,
    /// The measured change, g.
    pub change_g: f64,
    /// Whether the entry counted as active.
    pub active: bool,
}

/// The merged and sorted activity matrix: segments × joints.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct SortedMatrix {
    /// Row labels (segment ids).
    pub segments: Vec<String>,
    /// Column labels (joint ids).
    pub joints: Vec<String>,
    /// `entries[s][j]`: whether joint `j` moves segment `s`.
    pub entries: Vec<Vec<bool>>,
}

/// The discovered kinematic structure.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Structure {
    /// The static reference segment (`S0`).
    pub root: String,
    /// Segments in depth-first order; `S0` is the reference.
    pub segments: Vec<SegmentNode>,
    /// Joints; `Jn` moves `Sn`.
    pub joints: Vec<JointNode>,
    /// True end effectors (leaves).
    pub end_effectors: Vec<String>,
    /// Branching segments (more than two joints): references of sub-limbs.
    pub branching: Vec<String>,
    /// Limbs.
    pub limbs: Vec<Limb>,
    /// Findings.
    pub diagnostics: Vec<Diagnostic>,
    /// Whether no error-level diagnostic was raised.
    pub complete: bool,
    /// SUs left out of the tree.
    pub unplaced_sus: Vec<String>,
    /// SUs whose readings no working accelerometer gives (among those left out).
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub broken: Vec<BrokenSu>,
    /// DoFs left out of the tree.
    pub unplaced_dofs: Vec<String>,
    /// The merged and sorted activity matrix (paper Fig. 2).
    pub matrix: SortedMatrix,
    /// Entries within the uncertainty band.
    pub uncertain: Vec<UncertainEntry>,
    /// The threshold used, g.
    pub threshold_g: f64,
    /// Number of base orientations combined.
    pub orientations: usize,
}

impl Structure {
    /// The segment with this id.
    pub fn segment(&self, id: &str) -> Option<&SegmentNode> {
        self.segments.iter().find(|s| s.id == id)
    }

    /// The joint with this id.
    pub fn joint(&self, id: &str) -> Option<&JointNode> {
        self.joints.iter().find(|j| j.id == id)
    }

    /// The first SU or DoF of the structure that `set` does not name: a structure of another
    /// robot or recording.
    pub fn first_unknown(&self, set: &MeasurementSet) -> Option<(&'static str, &str)> {
        let sus = self.segments.iter().flat_map(|g| &g.sus);
        let dofs = self.joints.iter().flat_map(|j| &j.dofs);
        sus.filter(|u| !set.sus.contains(u))
            .map(|u| ("SU", u.as_str()))
            .chain(
                dofs.filter(|d| !set.dofs.contains(d))
                    .map(|d| ("DoF", d.as_str())),
            )
            .next()
    }

    /// Checks that the structure is a tree that estimation can walk: unique ids, every reference
    /// resolved, one parent joint per segment, no loop, every SU and DoF in one place, limbs that
    /// are chains of the tree. A structure read from a file (edited by hand, or of another robot)
    /// is checked before use; the error names the field.
    pub fn check(&self) -> Result<(), String> {
        self.check_ids()?;
        let place = self.check_links()?;
        self.check_acyclic()?;
        self.check_limbs(&place)
    }

    /// Segment and joint ids are unique.
    fn check_ids(&self) -> Result<(), String> {
        let mut seen = std::collections::HashSet::new();
        for (i, s) in self.segments.iter().enumerate() {
            if !seen.insert(s.id.as_str()) {
                return Err(format!("segments[{i}].id: `{}` is listed twice", s.id));
            }
        }
        let mut seen = std::collections::HashSet::new();
        for (i, j) in self.joints.iter().enumerate() {
            if !seen.insert(j.id.as_str()) {
                return Err(format!("joints[{i}].id: `{}` is listed twice", j.id));
            }
        }
        Ok(())
    }

    /// The segment `id`, or an error naming `field`.
    fn named_segment(&self, field: String, id: &str) -> Result<&SegmentNode, String> {
        self.segment(id)
            .ok_or_else(|| format!("{field}: no segment `{id}` in `segments`"))
    }

    /// The root, joints and segments refer to each other consistently, every DoF is in one joint
    /// and every SU on one segment; returns the segment of each SU.
    fn check_links(&self) -> Result<HashMap<&str, &str>, String> {
        let root = self.named_segment("root".into(), &self.root)?;
        if let Some(j) = &root.parent_joint {
            return Err(format!(
                "root: the reference segment `{}` has a parent joint `{j}`",
                self.root
            ));
        }
        let mut joint_of_dof = HashMap::new();
        for (i, j) in self.joints.iter().enumerate() {
            self.named_segment(format!("joints[{i}].parent"), &j.parent)?;
            let child = self.named_segment(format!("joints[{i}].child"), &j.child)?;
            if child.parent_joint.as_deref() != Some(&j.id) {
                return Err(format!(
                    "joints[{i}].child: segment `{}` names {} as its parent joint, not `{}`",
                    j.child,
                    child
                        .parent_joint
                        .as_deref()
                        .map_or("none".to_string(), |p| format!("`{p}`")),
                    j.id
                ));
            }
            if j.dofs.is_empty() {
                return Err(format!("joints[{i}].dofs: joint `{}` has no DoF", j.id));
            }
            for d in &j.dofs {
                if let Some(other) = joint_of_dof.insert(d.as_str(), j.id.as_str()) {
                    return Err(format!(
                        "joints[{i}].dofs: DoF `{d}` is in joints `{other}` and `{}`",
                        j.id
                    ));
                }
            }
        }
        let mut place = HashMap::new();
        for (i, s) in self.segments.iter().enumerate() {
            if s.id != self.root {
                let Some(j) = &s.parent_joint else {
                    return Err(format!(
                        "segments[{i}].parent_joint: segment `{}` is not the root but has no parent joint",
                        s.id
                    ));
                };
                if self.joint(j).is_none() {
                    return Err(format!(
                        "segments[{i}].parent_joint: no joint `{j}` in `joints`"
                    ));
                }
            }
            for su in &s.sus {
                if let Some(other) = place.insert(su.as_str(), s.id.as_str()) {
                    return Err(if other == s.id {
                        format!("segments[{i}].sus: SU `{su}` is listed twice")
                    } else {
                        format!(
                            "segments[{i}].sus: SU `{su}` is on segments `{other}` and `{}`",
                            s.id
                        )
                    });
                }
            }
        }
        Ok(place)
    }

    /// Walking up from any segment reaches the root without meeting a segment twice.
    fn check_acyclic(&self) -> Result<(), String> {
        for s in &self.segments {
            let mut path = vec![s.id.as_str()];
            let mut at = s;
            while let Some(j) = &at.parent_joint {
                let joint = self.joint(j).expect("checked above");
                at = self.segment(&joint.parent).expect("checked above");
                if let Some(start) = path.iter().position(|p| *p == at.id) {
                    let mut cycle: Vec<&str> = path[start..].to_vec();
                    cycle.push(at.id.as_str());
                    return Err(format!(
                        "joints: the parents form a loop ({}), not a tree: each joint's `parent` must be nearer the root `{}` than its `child`",
                        cycle.join(" → "),
                        self.root
                    ));
                }
                path.push(at.id.as_str());
            }
        }
        Ok(())
    }

    /// End effectors and branching segments exist, limbs are chains of the tree, and every joint
    /// is in exactly one limb. `place`: the segment of each SU.
    fn check_limbs(&self, place: &HashMap<&str, &str>) -> Result<(), String> {
        for (field, ids) in [
            ("end_effectors", &self.end_effectors),
            ("branching", &self.branching),
        ] {
            for (i, id) in ids.iter().enumerate() {
                self.named_segment(format!("{field}[{i}]"), id)?;
            }
        }
        let mut in_limb = HashMap::new();
        for (l, limb) in self.limbs.iter().enumerate() {
            let field = format!("limbs[{l}]");
            self.named_segment(format!("{field}.from"), &limb.from)?;
            if limb.joints.len() != limb.segments.len() || limb.joints.is_empty() {
                return Err(format!(
                    "{field}: {} joints for {} segments; a limb has one joint per segment",
                    limb.joints.len(),
                    limb.segments.len()
                ));
            }
            let mut parent = limb.from.as_str();
            let mut dofs = Vec::new();
            for (k, (j, s)) in limb.joints.iter().zip(&limb.segments).enumerate() {
                let Some(joint) = self.joint(j) else {
                    return Err(format!("{field}.joints[{k}]: no joint `{j}` in `joints`"));
                };
                if joint.parent != parent || &joint.child != s {
                    return Err(format!(
                        "{field}.joints[{k}]: joint `{j}` connects `{}` to `{}`, but the limb runs from `{parent}` to `{s}`",
                        joint.parent, joint.child
                    ));
                }
                dofs.extend(joint.dofs.iter().cloned());
                parent = s;
            }
            if limb.to != parent {
                return Err(format!(
                    "{field}.to: `{}`, but the limb's segments end at `{parent}`",
                    limb.to
                ));
            }
            if limb.dofs != dofs {
                return Err(format!(
                    "{field}.dofs: [{}], but its joints have [{}]",
                    limb.dofs.join(", "),
                    dofs.join(", ")
                ));
            }
            for j in &limb.joints {
                if let Some(other) = in_limb.insert(j.as_str(), l) {
                    return Err(format!(
                        "{field}.joints: joint `{j}` is also in limbs[{other}]; every joint is in one limb"
                    ));
                }
            }
            for (k, su) in limb.sus.iter().enumerate() {
                if !limb
                    .segments
                    .iter()
                    .any(|s| place.get(su.as_str()) == Some(&s.as_str()))
                {
                    return Err(format!(
                        "{field}.sus[{k}]: SU `{su}` is not on a segment of the limb"
                    ));
                }
            }
        }
        if let Some(j) = self
            .joints
            .iter()
            .find(|j| !in_limb.contains_key(j.id.as_str()))
        {
            return Err(format!(
                "limbs: joint `{}` is in no limb; every joint is in one limb",
                j.id
            ));
        }
        Ok(())
    }
}

/// Structural exploration of a measurement set: activity matrix, then [`structure_from_activity`].
///
/// ```
/// use skincal::explore::{explore, ExploreConfig};
/// use skincal::model::presets;
/// use skincal::sim::{simulate, SimulationConfig};
///
/// let robot = presets::find("paper-7dof").unwrap().robot().unwrap();
/// let sim = simulate(&robot, &SimulationConfig { training: false, ..SimulationConfig::default() }).unwrap();
/// let structure = explore(&sim.measurements, &ExploreConfig::default()).unwrap();
/// assert!(structure.complete);
/// assert_eq!(structure.joints.len(), 7);
/// assert_eq!(structure.limbs.len(), 1);
/// ```
pub fn explore(set: &MeasurementSet, config: &ExploreConfig) -> Result<Structure, ExploreError> {
    let activity = activity_matrix(set, config)?;
    let mut structure = structure_from_activity(&activity, config);
    let found = physical_checks(set, &activity);
    if found.iter().any(|d| d.severity == Severity::Error) {
        structure.complete = false;
    }
    structure.diagnostics.extend(found);
    Ok(structure)
}

/// One attempt at the tree on a subset of SUs.
struct Attempt {
    /// Joints: DoF indices, each list in input order.
    joints: Vec<Vec<usize>>,
    /// Segments: row over joints, SU indices (empty for a segment without SU).
    segments: Vec<(FixedBitSet, Vec<usize>)>,
    /// Index of the root segment.
    root: usize,
    /// `parent[s] = (parent segment, joint)`.
    parent: Vec<Option<(usize, usize)>>,
}

enum Outcome {
    Tree(Attempt),
    /// Rows that do not fit: the segment to leave out and why.
    Conflict {
        segment: Vec<usize>,
        joints: Vec<usize>,
        reason: String,
        attempt: Attempt,
    },
    /// A segment without SU must be assumed: its row over DoFs.
    AddSegment(FixedBitSet),
}

/// Merges, sorts and connects an activity matrix into a tree; see the module documentation.
pub fn structure_from_activity(a: &ActivityMatrix, config: &ExploreConfig) -> Structure {
    let nu = a.sus.len();
    let mut diagnostics = unexplored_dofs(a);
    diagnostics.extend(misread_readings(a));
    diagnostics.extend(upright_axes(a));
    let moving = moving_dofs(a, &mut diagnostics);
    let dof_rows: Vec<FixedBitSet> = (0..nu).map(|u| activity_row(a, u, &moving)).collect();
    let mut excluded = vec![false; nu];
    set_aside_broken(a, &mut excluded, &mut diagnostics);
    set_aside_mimic_driven(a, &mut excluded, &mut diagnostics);
    set_aside_undecided(a, &mut excluded, &mut diagnostics);
    diagnostics.extend(null_rows(a, config, &dof_rows, &moving, &mut excluded));
    let attempt = sort_into_tree(a, &dof_rows, &moving, &mut excluded, &mut diagnostics);
    finish(a, attempt, diagnostics, &excluded, &moving, &dof_rows)
}

/// An error for every DoF the structure experiment never moved (a mimic DoF moves with its
/// leader and needs no move of its own).
fn unexplored_dofs(a: &ActivityMatrix) -> Vec<Diagnostic> {
    (0..a.dofs.len())
        .filter(|&d| !a.explored[d] && !a.is_follower(d))
        .map(|d| Diagnostic {
            kind: DiagnosticKind::DofNotExplored,
            severity: Severity::Error,
            message: if a.is_prismatic(d) {
                format!("prismatic DoF `{}` has no dynamic reading in the training experiment and no accelerations of its structure moves: it turns no gravity, so only the accelerations it causes tell which SUs it carries; record the training experiment with its pattern, or ingest the log of its structure moves with the rest (`skincal ingest` reads them from the motion record)", a.dofs[d])
            } else {
                format!("DoF `{}` was never moved in the structure experiment, so nothing is known about it: add a move of it from the rest pose", a.dofs[d])
            },
            sus: vec![],
            dofs: vec![a.dofs[d].clone()],
        })
        .collect()
}

/// The readings left out as misread (glitches), and the entries then decided by the SUs whose
/// rows agree.
fn misread_readings(a: &ActivityMatrix) -> Option<Diagnostic> {
    if a.misread.is_empty() {
        return None;
    }
    let list: Vec<String> = a
        .misread
        .iter()
        .map(|m| {
            format!(
                "{} ({}, orientation {}: |r| = {:.2} g, usually {:.2} g)",
                m.su,
                m.dof
                    .as_deref()
                    .map_or("rest".to_string(), |d| format!("move of {d}")),
                m.orientation,
                m.norm_g,
                m.expected_g
            )
        })
        .collect();
    let mut sus: Vec<String> = a.misread.iter().map(|m| m.su.clone()).collect();
    sus.dedup();
    Some(Diagnostic {
        kind: DiagnosticKind::MisreadReading,
        severity: Severity::Warning,
        message: format!(
            "{} reading(s) are not what an accelerometer at rest reads (a norm far from the SU's |g|, a turn further than the DoF travelled or unlike that of every other SU the same move turned, or a change where the other orientation, which sees the DoF turn other SUs, saw this one still): glitches, left out; the entries they would decide come from the other base orientation: {}{}",
            a.misread.len(),
            list.join("; "),
            if a.inferred.is_empty() {
                String::new()
            } else {
                format!(
                    ". Entries no orientation could read then, decided by the SUs whose rows agree: {}",
                    a.inferred
                        .iter()
                        .map(|i| format!("{} × {} ({})", i.su, i.dof, if i.active { "moves" } else { "still" }))
                        .collect::<Vec<_>>()
                        .join(", ")
                )
            }
        ),
        sus,
        dofs: Vec::new(),
    })
}

/// The DoFs whose columns were read from what they accelerated, their axes vertical in every
/// base orientation, and the entries then decided by the tree (SUs near those axes).
fn upright_axes(a: &ActivityMatrix) -> Option<Diagnostic> {
    let dofs: Vec<String> = (0..a.dofs.len())
        .filter(|&d| a.is_upright(d))
        .map(|d| a.dofs[d].clone())
        .collect();
    if dofs.is_empty() {
        return None;
    }
    let near: Vec<&Inferred> = a
        .inferred
        .iter()
        .filter(|i| i.active && dofs.contains(&i.dof))
        .collect();
    let mut sus: Vec<String> = near.iter().map(|i| i.su.clone()).collect();
    sus.dedup();
    Some(Diagnostic {
        kind: DiagnosticKind::UprightAxis,
        severity: Severity::Info,
        message: format!(
            "DoF(s) {} turned no SU's gravity by {:.2} g in any base orientation (their axes stood vertical, or nearly): the SUs each moves are completed from what its structure moves accelerated, read with a lever arm of more than {:.0} mm beyond three times the move's own uncertainty{}",
            dofs.iter().map(|d| format!("`{d}`")).collect::<Vec<_>>().join(", "),
            a.threshold * a.uncertainty_factor / STANDARD_GRAVITY,
            activity::UPRIGHT_LEVER * 1e3,
            if near.is_empty() {
                String::new()
            } else {
                format!(
                    "; SUs nearer an axis, placed on the segment their other entries give: {}",
                    near.iter()
                        .map(|i| format!("{} × {}", i.su, i.dof))
                        .collect::<Vec<_>>()
                        .join(", ")
                )
            }
        ),
        sus,
        dofs,
    })
}

/// The explored DoFs that move some SU; each other one is named with why it moves none.
fn moving_dofs(a: &ActivityMatrix, diagnostics: &mut Vec<Diagnostic>) -> Vec<usize> {
    let (nu, nd) = (a.sus.len(), a.dofs.len());
    let mut moving: Vec<usize> = Vec::new();
    for d in (0..nd).filter(|&d| a.explored[d]) {
        if (0..nu).any(|u| a.is_active(u, d)) {
            moving.push(d);
            continue;
        }
        let largest = (0..nu).map(|u| a.change[u][d]).fold(0.0, f64::max) / STANDARD_GRAVITY;
        // With two base orientations no axis is vertical in both: the DoF moves no SU at all, so
        // it sits at a chain's end and leaving it out changes nothing else.
        let unread: Vec<&str> = a
            .undecided
            .iter()
            .filter(|(_, dof)| *dof == a.dofs[d])
            .map(|(su, _)| su.as_str())
            .collect();
        let lost;
        let (cause, severity) = if a.is_prismatic(d) {
            ("it is prismatic, and its excitation pattern accelerated no SU by half its peak: the segment it moves carries no SU (a gripper finger without skin), or the DoF did not actually move; it is left out and not calibrated", Severity::Warning)
        } else if !unread.is_empty() {
            lost = format!("but the readings of {} in its moves were misread, so whether it moves them cannot be told; the DoF is left out and not calibrated (record its move again)", unread.join(", "));
            (lost.as_str(), Severity::Warning)
        } else if a.orientations < 2 {
            ("its axis was probably vertical (turning about gravity changes no reading): record the structure experiment again with the reference segment tilted by 90° about a horizontal axis; or the segment it moves carries no SU", Severity::Error)
        } else {
            ("the segment it moves carries no SU (a chain's end without skin), or the DoF did not actually move; it is left out and not calibrated", Severity::Warning)
        };
        diagnostics.push(Diagnostic {
            kind: DiagnosticKind::DofMovesNoSu,
            severity,
            message: if a.is_prismatic(d) {
                format!("DoF `{}` accelerated no SU by more than half its pattern's peak (largest: {:.2} of the peak): {cause}", a.dofs[d], largest * STANDARD_GRAVITY / a.threshold / 2.0)
            } else {
                format!("DoF `{}` changed no SU's reading by more than {:.3} g (largest change {largest:.3} g): {cause}", a.dofs[d], a.threshold / STANDARD_GRAVITY)
            },
            sus: vec![],
            dofs: vec![a.dofs[d].clone()],
        });
    }
    moving
}

/// SU `u`'s row of the activity matrix over the `moving` DoFs.
fn activity_row(a: &ActivityMatrix, u: usize, moving: &[usize]) -> FixedBitSet {
    let mut b = FixedBitSet::with_capacity(a.dofs.len());
    for &d in moving {
        if a.is_active(u, d) {
            b.insert(d);
        }
    }
    b
}

/// Broken SUs are left out of the tree, each named with its failure.
fn set_aside_broken(a: &ActivityMatrix, excluded: &mut [bool], diagnostics: &mut Vec<Diagnostic>) {
    for b in &a.broken {
        if let Some(u) = a.sus.iter().position(|x| *x == b.su) {
            excluded[u] = true;
        }
        diagnostics.push(Diagnostic {
            kind: DiagnosticKind::BrokenSu,
            severity: Severity::Warning,
            message: format!(
                "SU `{}` is broken ({}): {}; it is left out of the tree and not calibrated",
                b.su, b.kind, b.detail
            ),
            sus: vec![b.su.clone()],
            dofs: vec![],
        });
    }
}

/// SUs on bodies that mimic DoFs drive are left out of the tree, named with their leader: the
/// tree has one body per joint, and a follower's body is not its leader's.
fn set_aside_mimic_driven(
    a: &ActivityMatrix,
    excluded: &mut [bool],
    diagnostics: &mut Vec<Diagnostic>,
) {
    let mut by_leader: BTreeMap<&str, Vec<&MimicDriven>> = BTreeMap::new();
    for m in &a.mimic_driven {
        by_leader.entry(m.leader.as_str()).or_default().push(m);
        if let Some(u) = a.sus.iter().position(|x| *x == m.su) {
            excluded[u] = true;
        }
    }
    for (leader, driven) in by_leader {
        let sus: Vec<String> = driven.iter().map(|m| m.su.clone()).collect();
        diagnostics.push(Diagnostic {
            kind: DiagnosticKind::MimicDriven,
            severity: Severity::Warning,
            message: if driven[0].kept.is_empty() {
                format!(
                    "{} move with DoF `{leader}` on several rigid bodies (their gravity readings do not keep one rotation between them over the poses, or they read its slide in opposite ways): the mimic DoFs following `{leader}` ({}) drive them, by other multiples of its motion, and which body is `{leader}`'s own cannot be told from the readings; skincal calibrates one body per DoF, so they are left out of the tree and not calibrated",
                    sus.join(", "),
                    driven[0].followers.join(", ")
                )
            } else {
                format!(
                    "{} move with DoF `{leader}` but not as one rigid body with {} (their gravity readings do not keep one rotation between them over the poses, or they read its slide the other way): they sit on a body that a mimic DoF following `{leader}` drives ({}); skincal calibrates one body per DoF, so they are left out of the tree and not calibrated",
                    sus.join(", "),
                    driven[0].kept.join(", "),
                    driven[0].followers.join(", ")
                )
            },
            sus,
            dofs: vec![leader.to_string()],
        });
    }
}

/// SUs with an entry nothing decides are left out of the tree.
fn set_aside_undecided(
    a: &ActivityMatrix,
    excluded: &mut [bool],
    diagnostics: &mut Vec<Diagnostic>,
) {
    if a.undecided.is_empty() {
        return;
    }
    let mut sus: Vec<String> = a.undecided.iter().map(|(s, _)| s.clone()).collect();
    sus.dedup();
    for s in &sus {
        if let Some(u) = a.sus.iter().position(|x| x == s) {
            excluded[u] = true;
        }
    }
    diagnostics.push(Diagnostic {
        kind: DiagnosticKind::MisreadReading,
        severity: Severity::Warning,
        message: format!(
            "whether these DoFs move these SUs cannot be told: the reading that would tell was misread, the other orientation turned the DoF about gravity, and neither the SUs with the same row nor the tree decide it: {}; the SUs are left out of the tree and not calibrated (record the move again to place them)",
            a.undecided
                .iter()
                .map(|(s, d)| format!("{s} × {d}"))
                .collect::<Vec<_>>()
                .join(", ")
        ),
        sus,
        dofs: a.undecided.iter().map(|(_, d)| d.clone()).collect(),
    });
}

/// The null-row SUs (still in every move): none says the reference segment carries no SU; those
/// whose gravity reading turned unlike the rest's when the base was re-oriented are not on the
/// reference segment and are left out.
fn null_rows(
    a: &ActivityMatrix,
    config: &ExploreConfig,
    dof_rows: &[FixedBitSet],
    moving: &[usize],
    excluded: &mut [bool],
) -> Option<Diagnostic> {
    let nu = a.sus.len();
    let still: Vec<usize> = (0..nu)
        .filter(|&u| dof_rows[u].is_clear() && !excluded[u])
        .collect();
    if still.is_empty() {
        let everything: Vec<usize> = moving
            .iter()
            .copied()
            .filter(|&d| (0..nu).all(|u| a.is_active(u, d)))
            .collect();
        let names: Vec<String> = everything.iter().map(|&d| a.dofs[d].clone()).collect();
        let message = if everything.is_empty() {
            "no SU stayed still in every move (no null row): the reference segment carries no SU; the tree is rooted at an assumed reference segment without SU".to_string()
        } else {
            format!("no SU stayed still in every move (no null row), and DoF(s) {} moved every SU: either the reference segment carries no SU (normal for an arm whose base has no skin: its first joint moves everything), or the reference segment itself moved with them — then hold it still. The tree is rooted at an assumed reference segment without SU", names.join(", "))
        };
        return Some(Diagnostic {
            kind: DiagnosticKind::NoStaticSegment,
            severity: Severity::Info,
            message,
            sus: vec![],
            dofs: names,
        });
    }
    // Null-row SUs must turn together with the reference segment when the base is re-oriented.
    let turns = still
        .iter()
        .map(|&u| a.rest_turn[u])
        .collect::<Option<Vec<f64>>>()?;
    let mut sorted = turns.clone();
    sorted.sort_by(f64::total_cmp);
    let median = sorted[sorted.len() / 2];
    let odd: Vec<usize> = still
        .iter()
        .zip(&turns)
        .filter(|(_, t)| (**t - median).abs() > config.static_turn_tolerance)
        .map(|(&u, _)| u)
        .collect();
    if odd.is_empty() {
        return None;
    }
    for &u in &odd {
        excluded[u] = true;
    }
    Some(Diagnostic {
        kind: DiagnosticKind::SeveralStaticGroups,
        severity: Severity::Warning,
        message: format!(
            "more than one null row: these SUs stayed still in every move, but their gravity reading turned by a different angle than the reference segment's ({:.0}°) when the base was re-oriented, so they are not on the reference segment: loose SUs, SUs on another static body, or SUs on a segment whose DoFs were not moved; left out of the tree",
            median.to_degrees()
        ),
        sus: odd.iter().map(|&u| a.sus[u].clone()).collect(),
        dofs: vec![],
    })
}

/// The rows of the SUs not `excluded` sorted into a tree ([`attempt_tree`]): a conflict leaves
/// out the SUs of the segment it names (or the segments assumed so far, or, when nothing
/// explains it, every SU), a missing segment row is assumed, until a tree stands.
fn sort_into_tree(
    a: &ActivityMatrix,
    dof_rows: &[FixedBitSet],
    moving: &[usize],
    excluded: &mut [bool],
    diagnostics: &mut Vec<Diagnostic>,
) -> Attempt {
    let (nu, nd) = (a.sus.len(), a.dofs.len());
    let uncertain: Vec<usize> = (0..nu)
        .map(|u| moving.iter().filter(|&&d| a.is_uncertain(u, d)).count())
        .collect();
    // Every round either leaves out at least one SU or assumes a segment row that did not exist;
    // past a generous bound no more segments are assumed, so the loop always ends.
    let mut extra_rows: Vec<FixedBitSet> = Vec::new();
    let limit = 4 * (nu + nd) + 8;
    let mut rounds = 0;
    loop {
        rounds += 1;
        let active: Vec<usize> = (0..nu).filter(|&u| !excluded[u]).collect();
        match attempt_tree(
            dof_rows,
            &active,
            moving,
            &extra_rows,
            nd,
            rounds < limit,
            &uncertain,
        ) {
            Outcome::Tree(t) => return t,
            Outcome::AddSegment(row) => extra_rows.push(row),
            Outcome::Conflict {
                segment,
                joints,
                reason,
                attempt,
            } => {
                let dofs: Vec<String> = joints
                    .iter()
                    .flat_map(|&j| attempt.joints[j].iter().map(|&d| a.dofs[d].clone()))
                    .collect();
                if !segment.is_empty() {
                    for &u in &segment {
                        excluded[u] = true;
                    }
                } else if !extra_rows.is_empty() {
                    extra_rows.clear();
                } else {
                    excluded.iter_mut().for_each(|e| *e = true);
                }
                // SUs set aside leave a consistent tree of the rest (a warning); a conflict that
                // no SU explains leaves no tree to trust.
                diagnostics.push(Diagnostic {
                    kind: DiagnosticKind::Unsortable,
                    severity: if segment.is_empty() { Severity::Error } else { Severity::Warning },
                    message: format!("the activity matrix cannot be sorted into a tree: {reason}. Likely causes: a closed kinematic loop, a reference segment that moved, a segment without SU in mid-chain, or a misread entry; these SUs are left out of the tree and not calibrated"),
                    sus: segment.iter().map(|&u| a.sus[u].clone()).collect(),
                    dofs,
                });
            }
        }
    }
}

/// Merges the active SUs' rows into joints and segments and connects them, or reports the first
/// conflict.
fn attempt_tree(
    dof_rows: &[FixedBitSet],
    active: &[usize],
    moving: &[usize],
    extra_rows: &[FixedBitSet],
    nd: usize,
    may_assume_segments: bool,
    uncertain: &[usize],
) -> Outcome {
    let joints = merge_columns(dof_rows, active, moving, extra_rows);
    let (segments, root) = merge_rows(dof_rows, active, extra_rows, &joints, nd);
    let (parent, orphans, conflict) = connect(&segments, root, &joints, uncertain);
    let attempt = Attempt {
        joints,
        segments,
        root,
        parent,
    };
    if let Some((s, joints, reason)) = conflict {
        let segment = attempt.segments[s].1.clone();
        return Outcome::Conflict {
            segment,
            joints,
            reason,
            attempt,
        };
    }
    let Some(&orphan) = orphans.first() else {
        return Outcome::Tree(attempt);
    };
    if may_assume_segments {
        if let Some(row) = shared_parent_row(&attempt, &orphans, nd) {
            return Outcome::AddSegment(row);
        }
    }
    let segment = attempt.segments[orphan].1.clone();
    let joints: Vec<usize> = attempt.segments[orphan].0.ones().collect();
    Outcome::Conflict {
        segment,
        joints,
        reason: "no other segment's row equals this segment's row less one joint, so it hangs from nothing".into(),
        attempt,
    }
}

/// The joints: DoFs with identical non-empty columns over the active SUs (and the assumed
/// segments' rows), each joint its DoFs, ordered by its first.
fn merge_columns(
    dof_rows: &[FixedBitSet],
    active: &[usize],
    moving: &[usize],
    extra_rows: &[FixedBitSet],
) -> Vec<Vec<usize>> {
    let mut columns: BTreeMap<Vec<usize>, Vec<usize>> = BTreeMap::new();
    for &d in moving {
        let column: Vec<usize> = active
            .iter()
            .copied()
            .filter(|&u| dof_rows[u].contains(d))
            .collect();
        let extra: Vec<usize> = extra_rows
            .iter()
            .enumerate()
            .filter(|(_, r)| r.contains(d))
            .map(|(i, _)| usize::MAX - i)
            .collect();
        if column.is_empty() {
            continue;
        }
        columns.entry([column, extra].concat()).or_default().push(d);
    }
    let mut joints: Vec<Vec<usize>> = columns.into_values().collect();
    joints.sort_by_key(|j| j[0]);
    joints
}

/// The segments: the active SUs with identical rows over `joints` (and the assumed segments,
/// without SU), sorted by how many joints move them; with the root (the row no joint moves,
/// assumed without SU where none is) and its index.
fn merge_rows(
    dof_rows: &[FixedBitSet],
    active: &[usize],
    extra_rows: &[FixedBitSet],
    joints: &[Vec<usize>],
    nd: usize,
) -> (Vec<(FixedBitSet, Vec<usize>)>, usize) {
    let mut joint_of = vec![usize::MAX; nd];
    for (j, ds) in joints.iter().enumerate() {
        for &d in ds {
            joint_of[d] = j;
        }
    }
    let to_joint_row = |r: &FixedBitSet| -> FixedBitSet {
        let mut b = FixedBitSet::with_capacity(joints.len());
        for d in r.ones() {
            if joint_of[d] != usize::MAX {
                b.insert(joint_of[d]);
            }
        }
        b
    };
    let mut by_row: HashMap<FixedBitSet, Vec<usize>> = HashMap::new();
    for &u in active {
        by_row
            .entry(to_joint_row(&dof_rows[u]))
            .or_default()
            .push(u);
    }
    for r in extra_rows {
        by_row.entry(to_joint_row(r)).or_default();
    }
    let mut segments: Vec<(FixedBitSet, Vec<usize>)> = by_row.into_iter().collect();
    segments.sort_by(|a, b| {
        a.0.count_ones(..)
            .cmp(&b.0.count_ones(..))
            .then_with(|| a.0.cmp(&b.0))
    });
    let root = match segments.iter().position(|(r, _)| r.is_clear()) {
        Some(i) => i,
        None => {
            segments.insert(0, (FixedBitSet::with_capacity(joints.len()), vec![]));
            0
        }
    };
    (segments, root)
}

/// A conflict found while connecting: the segment to leave out, the joints involved, why.
type Conflict = (usize, Vec<usize>, String);

/// Connects each segment to the placed one whose row is its own less one joint: per segment its
/// `(parent, joint)`, the segments that hang from nothing, and the first conflict (a joint two
/// segments claim, or several possible parents) with the segment to leave out — of the parties,
/// the one whose SUs have the most uncertain entries, then the one with the fewest SUs, then the
/// segment being placed.
#[allow(clippy::type_complexity)]
fn connect(
    segments: &[(FixedBitSet, Vec<usize>)],
    root: usize,
    joints: &[Vec<usize>],
    uncertain: &[usize],
) -> (Vec<Option<(usize, usize)>>, Vec<usize>, Option<Conflict>) {
    let n = segments.len();
    let suspect = |parties: &[usize]| -> usize {
        *parties
            .iter()
            .min_by_key(|&&p| {
                let doubt: usize = segments[p].1.iter().map(|&u| uncertain[u]).sum();
                (std::cmp::Reverse(doubt), segments[p].1.len())
            })
            .expect("a conflict has parties")
    };
    let mut parent: Vec<Option<(usize, usize)>> = vec![None; n];
    let mut claimed: Vec<Option<usize>> = vec![None; joints.len()];
    let mut placed = vec![false; n];
    placed[root] = true;
    let mut orphans: Vec<usize> = Vec::new();
    for s in (0..n).filter(|&s| s != root) {
        let row = &segments[s].0;
        let size = row.count_ones(..);
        let candidates: Vec<usize> = (0..n)
            .filter(|&p| {
                placed[p]
                    && segments[p].0.is_subset(row)
                    && segments[p].0.count_ones(..) + 1 == size
            })
            .collect();
        match candidates.as_slice() {
            [p] => {
                let j = row
                    .difference(&segments[*p].0)
                    .next()
                    .expect("rows differ by one joint");
                if let Some(other) = claimed[j] {
                    let guilty = suspect(&[s, other]);
                    let reason = format!(
                        "two segments claim to be the one that joint of DoF(s) {:?} moves directly",
                        joints[j]
                    );
                    return (parent, orphans, Some((guilty, vec![j], reason)));
                }
                claimed[j] = Some(s);
                parent[s] = Some((*p, j));
                placed[s] = true;
            }
            [] => orphans.push(s),
            many => {
                let guilty = suspect(&[&[s][..], many].concat());
                let reason = format!(
                    "a segment could hang from {} different segments",
                    many.len()
                );
                return (
                    parent,
                    orphans,
                    Some((guilty, row.ones().collect(), reason)),
                );
            }
        }
    }
    (parent, orphans, None)
}

/// The DoF row of a segment without SU to assume: two orphans whose rows share all but one
/// joint branch off a segment with the shared row, where none has it.
fn shared_parent_row(attempt: &Attempt, orphans: &[usize], nd: usize) -> Option<FixedBitSet> {
    for (i, &s) in orphans.iter().enumerate() {
        for &t in &orphans[i + 1..] {
            let (rs, rt) = (&attempt.segments[s].0, &attempt.segments[t].0);
            let size = rs.count_ones(..);
            if size == rt.count_ones(..) && rs.intersection_count(rt) + 1 == size {
                let mut common = FixedBitSet::with_capacity(rs.len());
                common.extend(rs.intersection(rt));
                if attempt.segments.iter().all(|(r, _)| *r != common) {
                    let mut dof_row = FixedBitSet::with_capacity(nd);
                    for j in common.ones() {
                        dof_row.extend(attempt.joints[j].iter().copied());
                    }
                    return Some(dof_row);
                }
            }
        }
    }
    None
}

/// Numbers the tree depth-first, derives its anatomy and suggests flips for left-out SUs.
fn finish(
    a: &ActivityMatrix,
    t: Attempt,
    mut diagnostics: Vec<Diagnostic>,
    excluded: &[bool],
    moving: &[usize],
    dof_rows: &[FixedBitSet],
) -> Structure {
    let numbered = Numbered::new(&t);
    let segments: Vec<SegmentNode> = numbered
        .order
        .iter()
        .map(|&s| SegmentNode {
            id: numbered.id[s].clone(),
            sus: t.segments[s].1.iter().map(|&u| a.sus[u].clone()).collect(),
            parent_joint: t.parent[s].map(|_| numbered.joint_id(s)),
            without_su: t.segments[s].1.is_empty(),
        })
        .collect();
    let joints: Vec<JointNode> = numbered
        .order
        .iter()
        .filter_map(|&s| {
            t.parent[s].map(|(p, j)| JointNode {
                id: numbered.joint_id(s),
                dofs: t.joints[j].iter().map(|&d| a.dofs[d].clone()).collect(),
                parent: numbered.id[p].clone(),
                child: numbered.id[s].clone(),
            })
        })
        .collect();
    diagnostics.extend(shape_notes(&segments, &joints));
    diagnostics.extend(flips_that_place(
        a, &t, &numbered, excluded, moving, dof_rows,
    ));
    let (end_effectors, branching, limbs) = anatomy(a, &t, &numbered);
    diagnostics.sort_by_key(|d| std::cmp::Reverse(d.severity));
    let complete = diagnostics.iter().all(|d| d.severity != Severity::Error);
    Structure {
        root: "S0".into(),
        segments,
        joints,
        end_effectors,
        branching,
        limbs,
        diagnostics,
        complete,
        unplaced_sus: (0..a.sus.len())
            .filter(|&u| excluded[u])
            .map(|u| a.sus[u].clone())
            .collect(),
        unplaced_dofs: unplaced_dofs(&t, moving, a.dofs.len())
            .iter()
            .map(|&d| a.dofs[d].clone())
            .collect(),
        broken: a.broken.clone(),
        matrix: sorted_matrix(&t, &numbered),
        uncertain: uncertain_entries(a),
        threshold_g: a.threshold / STANDARD_GRAVITY,
        orientations: a.orientations,
    }
}

/// An attempt's segments numbered depth-first from the root (`S0`; joint `Jk` is the parent
/// joint of `Sk`), each one's children by their first DoF.
struct Numbered {
    /// Per segment: `(first DoF of the joint, child segment)`, sorted.
    children: Vec<Vec<(usize, usize)>>,
    /// The segments in depth-first order.
    order: Vec<usize>,
    /// Per segment: its id.
    id: Vec<String>,
}

impl Numbered {
    fn new(t: &Attempt) -> Self {
        let n = t.segments.len();
        let mut children: Vec<Vec<(usize, usize)>> = vec![vec![]; n];
        for (s, p) in t.parent.iter().enumerate() {
            if let Some((p, j)) = p {
                children[*p].push((t.joints[*j][0], s));
            }
        }
        for c in &mut children {
            c.sort();
        }
        let mut order = Vec::with_capacity(n);
        let mut stack = vec![t.root];
        while let Some(s) = stack.pop() {
            order.push(s);
            stack.extend(children[s].iter().rev().map(|&(_, c)| c));
        }
        let mut id = vec![String::new(); n];
        for (k, &s) in order.iter().enumerate() {
            id[s] = format!("S{k}");
        }
        Self {
            children,
            order,
            id,
        }
    }

    /// The id of segment `s`'s parent joint.
    fn joint_id(&self, s: usize) -> String {
        format!("J{}", self.order.iter().position(|&x| x == s).unwrap_or(0))
    }

    /// How many joints segment `s` of `t` has.
    fn degree(&self, t: &Attempt, s: usize) -> usize {
        self.children[s].len() + usize::from(t.parent[s].is_some())
    }
}

/// The DoFs the tree does not place: those that move no SU, and those of joints that connect
/// nothing (all their SUs were left out).
fn unplaced_dofs(t: &Attempt, moving: &[usize], nd: usize) -> Vec<usize> {
    let used: Vec<usize> = t.parent.iter().flatten().map(|&(_, j)| j).collect();
    let mut unplaced: Vec<usize> = (0..nd).filter(|d| !moving.contains(d)).collect();
    for (j, ds) in t.joints.iter().enumerate() {
        if !used.contains(&j) {
            unplaced.extend(ds);
        }
    }
    unplaced.extend(
        moving
            .iter()
            .copied()
            .filter(|&d| !t.joints.iter().any(|j| j.contains(&d))),
    );
    unplaced.sort();
    unplaced.dedup();
    unplaced
}

/// Notes on the tree's shape: joints of several DoFs (their order is the estimator's to find),
/// segments assumed without SU.
fn shape_notes(segments: &[SegmentNode], joints: &[JointNode]) -> Vec<Diagnostic> {
    let mut notes = Vec::new();
    for j in joints.iter().filter(|j| j.dofs.len() > 1) {
        notes.push(Diagnostic {
            kind: DiagnosticKind::MultiDofJoint,
            severity: Severity::Info,
            message: format!("{} combines {} DoFs with no SU between them; their order along the chain cannot be seen in the activity matrix (identical columns) and is listed in input order — kinematic estimation determines it", j.id, j.dofs.len()),
            sus: vec![],
            dofs: j.dofs.clone(),
        });
    }
    for s in segments.iter().filter(|s| s.without_su && s.id != "S0") {
        let out: Vec<&JointNode> = joints.iter().filter(|j| j.parent == s.id).collect();
        notes.push(Diagnostic {
            kind: DiagnosticKind::SegmentWithoutSu,
            severity: Severity::Warning,
            message: format!("joints {} start from a segment that carries no SU; it was assumed as {} to connect the tree. Cover it with at least one SU so that it can be calibrated", out.iter().map(|j| j.id.as_str()).collect::<Vec<_>>().join(", "), s.id),
            sus: vec![],
            dofs: out.iter().flat_map(|j| j.dofs.clone()).collect(),
        });
    }
    notes
}

/// Every entry of the activity matrix near its threshold.
fn uncertain_entries(a: &ActivityMatrix) -> Vec<UncertainEntry> {
    let mut uncertain = Vec::new();
    for u in 0..a.sus.len() {
        for d in 0..a.dofs.len() {
            if a.is_uncertain(u, d) {
                uncertain.push(UncertainEntry {
                    su: a.sus[u].clone(),
                    dof: a.dofs[d].clone(),
                    change_g: a.change[u][d] / STANDARD_GRAVITY,
                    active: a.is_active(u, d),
                });
            }
        }
    }
    uncertain
}

/// The uncertain entries of left-out SUs whose flip would make the SU fit a placed segment,
/// each named with that segment.
fn flips_that_place(
    a: &ActivityMatrix,
    t: &Attempt,
    numbered: &Numbered,
    excluded: &[bool],
    moving: &[usize],
    dof_rows: &[FixedBitSet],
) -> Vec<Diagnostic> {
    let placed_rows: HashMap<FixedBitSet, usize> = (0..t.segments.len())
        .map(|s| (dof_row_of_segment(t, s, a.dofs.len()), s))
        .collect();
    let mut flips = Vec::new();
    for u in (0..a.sus.len()).filter(|&u| excluded[u]) {
        for &d in moving {
            if !a.is_uncertain(u, d) {
                continue;
            }
            let mut flipped = dof_rows[u].clone();
            flipped.toggle(d);
            let flipped = expand_to_joints(t, &flipped);
            if let Some(&s) = placed_rows.get(&flipped) {
                flips.push(Diagnostic {
                    kind: DiagnosticKind::UncertainEntry,
                    severity: Severity::Warning,
                    message: format!(
                        "SU `{}` would sit on {} if its entry for DoF `{}` were {} (measured change {:.3} g against a threshold of {:.3} g): check that SU and that move, or re-run with another --threshold",
                        a.sus[u], numbered.id[s], a.dofs[d], if a.is_active(u, d) { 0 } else { 1 }, a.change[u][d] / STANDARD_GRAVITY, a.threshold / STANDARD_GRAVITY
                    ),
                    sus: vec![a.sus[u].clone()],
                    dofs: vec![a.dofs[d].clone()],
                });
            }
        }
    }
    flips
}

/// The tree's anatomy: its end effectors, its branching segments and its limbs (from the root
/// or a branching segment to an end effector or the next branching segment).
fn anatomy(
    a: &ActivityMatrix,
    t: &Attempt,
    numbered: &Numbered,
) -> (Vec<String>, Vec<String>, Vec<Limb>) {
    let Numbered {
        children,
        order,
        id,
    } = numbered;
    let end_effectors: Vec<String> = order
        .iter()
        .filter(|&&s| s != t.root && numbered.degree(t, s) == 1)
        .map(|&s| id[s].clone())
        .collect();
    let branching: Vec<String> = order
        .iter()
        .filter(|&&s| s != t.root && numbered.degree(t, s) > 2)
        .map(|&s| id[s].clone())
        .collect();
    let mut limbs = Vec::new();
    for &reference in order
        .iter()
        .filter(|&&s| s == t.root || numbered.degree(t, s) > 2)
    {
        for &(_, first) in &children[reference] {
            let mut limb = Limb {
                from: id[reference].clone(),
                to: String::new(),
                joints: vec![],
                segments: vec![],
                dofs: vec![],
                sus: vec![],
            };
            let mut s = first;
            loop {
                let (_, j) = t.parent[s].expect("children have parents");
                limb.joints.push(numbered.joint_id(s));
                limb.dofs
                    .extend(t.joints[j].iter().map(|&d| a.dofs[d].clone()));
                limb.segments.push(id[s].clone());
                limb.sus
                    .extend(t.segments[s].1.iter().map(|&u| a.sus[u].clone()));
                if children[s].len() == 1 {
                    s = children[s][0].1;
                } else {
                    break;
                }
            }
            limb.to = id[s].clone();
            limbs.push(limb);
        }
    }
    (end_effectors, branching, limbs)
}

/// The activity matrix sorted into the tree's lower-triangular form: per segment, which joints
/// move it.
fn sorted_matrix(t: &Attempt, numbered: &Numbered) -> SortedMatrix {
    let order = &numbered.order;
    SortedMatrix {
        segments: order.iter().map(|&s| numbered.id[s].clone()).collect(),
        joints: order
            .iter()
            .skip(1)
            .map(|&s| numbered.joint_id(s))
            .collect(),
        entries: order
            .iter()
            .map(|&s| {
                order
                    .iter()
                    .skip(1)
                    .map(|&c| t.parent[c].is_some_and(|(_, j)| t.segments[s].0.contains(j)))
                    .collect()
            })
            .collect(),
    }
}

fn dof_row_of_segment(t: &Attempt, s: usize, nd: usize) -> FixedBitSet {
    let mut b = FixedBitSet::with_capacity(nd);
    for j in t.segments[s].0.ones() {
        b.extend(t.joints[j].iter().copied());
    }
    b
}

/// A row over DoFs in the form of a placed segment's row: unchanged if it holds every DoF of each
/// joint it touches; a row that splits a joint is returned as it is (and matches no segment).
fn expand_to_joints(t: &Attempt, row: &FixedBitSet) -> FixedBitSet {
    let mut b = FixedBitSet::with_capacity(row.len());
    for ds in &t.joints {
        let inside = ds.iter().filter(|&&d| row.contains(d)).count();
        if inside == ds.len() {
            b.extend(ds.iter().copied());
        } else if inside > 0 {
            return row.clone();
        }
    }
    // DoFs outside every joint stay as they are.
    for d in row.ones() {
        if !t.joints.iter().any(|j| j.contains(&d)) {
            b.insert(d);
        }
    }
    b
}
