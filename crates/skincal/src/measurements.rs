//! The measurement set: the contract between whatever records data (the simulator, log ingestion,
//! other tools) and whatever uses it (exploration, estimation). Documented in
//! `docs/measurements.md`.
//!
//! Every reading is a specific force in the SU's own frame, m/s² (see [`crate::model::sensor`]):
//! a resting SU whose z axis points up reads `(0, 0, +9.81)`. Dynamic accelerations are the SU's
//! response at the peak `α = 2πfA` of a positive excitation pattern, without gravity. Poses are in
//! rad, one value per DoF in the order of `dofs`; readings are one `[x, y, z]` per SU in the order
//! of `sus`.
//!
//! Fields that skincal does not know are kept as written (`extra`), at every level.

use std::collections::BTreeMap;

use serde::{Deserialize, Serialize};
use serde_json::{Map, Value};

use crate::model::sensor::{ExcitationPattern, MAX_ANGLE, MAX_READING, STANDARD_GRAVITY};
use crate::model::{DofKind, MimicSpec};

/// The value of the `format` field.
pub const FORMAT: &str = "skincal-measurements";
/// The version this library reads and writes.
pub const VERSION: u32 = 1;

/// One accelerometer reading `[x, y, z]`, m/s², in the SU frame.
pub type Reading = [f64; 3];

/// Errors in a measurement set.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
#[non_exhaustive]
pub enum MeasurementError {
    /// The JSON does not parse or lacks required fields (the message has line and column).
    #[error("{0}")]
    Syntax(String),
    /// The `format` field is not `skincal-measurements`.
    #[error("format is `{found}`, expected `skincal-measurements`: is this a measurement set?")]
    WrongFormat {
        /// What the file says.
        found: String,
    },
    /// A version this library does not read.
    #[error("version {found} is not supported (this skincal reads version 1)")]
    UnsupportedVersion {
        /// What the file says.
        found: u32,
    },
    /// An array has the wrong length.
    #[error("{field}: has {found} entries, expected {expected} ({what})")]
    Shape {
        /// Path of the field.
        field: String,
        /// Expected length.
        expected: usize,
        /// Actual length.
        found: usize,
        /// What the length must match.
        what: &'static str,
    },
    /// A DoF name that is not in `dofs`.
    #[error("{field}: unknown DoF `{name}` (not listed in `dofs`)")]
    UnknownDof {
        /// Path of the field.
        field: String,
        /// The name.
        name: String,
    },
    /// A value is NaN or infinite, or otherwise impossible.
    #[error("{field}: {reason}")]
    InvalidValue {
        /// Path of the field.
        field: String,
        /// What is wrong.
        reason: String,
    },
    /// A name appears twice in `dofs` or `sus`.
    #[error("{field}: `{name}` is listed twice")]
    DuplicateName {
        /// `dofs` or `sus`.
        field: &'static str,
        /// The name.
        name: String,
    },
}

/// Units of the set (always SI; recorded so that a reader can check).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Units {
    /// `"m/s^2"`.
    pub acceleration: String,
    /// `"rad"`.
    pub angle: String,
    /// Unknown fields, kept as written.
    #[serde(flatten)]
    pub extra: Map<String, Value>,
}

impl Default for Units {
    fn default() -> Self {
        Self {
            acceleration: "m/s^2".into(),
            angle: "rad".into(),
            extra: Map::new(),
        }
    }
}

/// A measurement set.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct MeasurementSet {
    /// Always [`FORMAT`].
    pub format: String,
    /// Always [`VERSION`].
    pub version: u32,
    /// Units.
    pub units: Units,
    /// DoF names; the order of every pose vector.
    pub dofs: Vec<String>,
    /// SU names; the order of every list of readings.
    pub sus: Vec<String>,
    /// The DoFs of `dofs` that are prismatic: their positions are in m and their pattern is the
    /// set's scaled by [`crate::model::PRISMATIC_PATTERN_SCALE`] (m per rad). Every other DoF is revolute.
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub prismatic: Vec<String>,
    /// The DoFs of `dofs` that are mimic joints, each with the DoF it follows
    /// (`{"finger_2": {"joint": "finger_1", "multiplier": -1.0, "offset": 0.0}}`): they have no
    /// actuator, so no move or excitation of their own; their leader's moves move them too.
    #[serde(default, skip_serializing_if = "BTreeMap::is_empty")]
    pub mimic: BTreeMap<String, MimicSpec>,
    /// The structure experiment, if recorded.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub structure: Option<StructureExperiment>,
    /// The training experiment, if recorded.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub training: Option<TrainingExperiment>,
    /// Unknown fields, kept as written.
    #[serde(flatten)]
    pub extra: Map<String, Value>,
}

/// Static readings for structural exploration, in one or more base orientations.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct StructureExperiment {
    /// One block per orientation of the reference segment.
    pub orientations: Vec<Orientation>,
    /// Unknown fields, kept as written.
    #[serde(flatten)]
    pub extra: Map<String, Value>,
}

/// The structure experiment in one orientation of the reference segment.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Orientation {
    /// The rest pose, rad per DoF.
    pub rest_pose: Vec<f64>,
    /// Static readings at the rest pose, one per SU.
    pub rest: Vec<Reading>,
    /// One static pose per DoF moved away from the rest pose.
    pub moves: Vec<Move>,
    /// Unknown fields, kept as written.
    #[serde(flatten)]
    pub extra: Map<String, Value>,
}

/// A static pose with one DoF moved.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Move {
    /// The DoF that moved.
    pub dof: String,
    /// The pose, rad per DoF.
    pub pose: Vec<f64>,
    /// Static readings, one per SU.
    pub readings: Vec<Reading>,
    /// Per SU, how much its reading changed per unit of the DoF's acceleration on the way into
    /// this pose (least squares over the move, SU frame; m/s² per m/s² for a prismatic DoF, per
    /// rad/s² for a revolute one, which is m): a DoF that turns no gravity (a prismatic one) or
    /// a body it moves without turning it (a parallel gripper's fingertip) changes no static
    /// reading, but accelerates what it carries. Empty: not measured (where the training
    /// experiment excites the DoF, its dynamic readings tell the same).
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub accelerated: Vec<Reading>,
    /// Per SU, the standard deviation of each component of its `accelerated` value (the
    /// regression's, from its residual; same units): a move the record barely holds tells its
    /// gains only to within centimetres of lever arm. `null` for an SU that sent too little in the
    /// move to tell; empty: not given (the gains are taken as exact).
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub accelerated_sd: Vec<Option<f64>>,
    /// Unknown fields, kept as written.
    #[serde(flatten)]
    pub extra: Map<String, Value>,
}

/// Static and dynamic readings in random poses, for kinematic estimation.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct TrainingExperiment {
    /// The excitation pattern the dynamic readings refer to.
    pub pattern: ExcitationPattern,
    /// The poses.
    pub poses: Vec<TrainingPose>,
    /// The poses are quiet moments of a motion record
    /// ([`crate::motion::MotionRecord::quiet_poses`]): static readings only, a start for the fit
    /// on every sample, which finds the positions and the order of a joint's DoFs from the motion.
    #[serde(default, skip_serializing_if = "std::ops::Not::not")]
    pub from_motion: bool,
    /// Unknown fields, kept as written.
    #[serde(flatten)]
    pub extra: Map<String, Value>,
}

/// One training pose.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct TrainingPose {
    /// The pose, rad per DoF.
    pub q: Vec<f64>,
    /// Static readings, one per SU.
    #[serde(rename = "static")]
    pub static_readings: Vec<Reading>,
    /// Per excited DoF: the dynamic acceleration of every SU at the pattern peak.
    pub dynamic: BTreeMap<String, Vec<Reading>>,
    /// The standard deviation of each component of every SU's static reading, m/s² (from the
    /// samples it was averaged from; absent: the estimator's noise setting applies).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub static_sd: Option<Vec<f64>>,
    /// The same for the dynamic readings, per excited DoF.
    #[serde(default, skip_serializing_if = "BTreeMap::is_empty")]
    pub dynamic_sd: BTreeMap<String, Vec<f64>>,
    /// The base orientation the reference segment stood in: 0 (absent) for the set's usual one,
    /// 1, 2, … for poses recorded with the reference segment turned otherwise (the robot's base
    /// tilted on its mount). Each other orientation has its own gravity in the fit; its static
    /// readings tell what gravity along the first axis cannot (a segment's turn about it).
    #[serde(default, skip_serializing_if = "is_zero")]
    pub orientation: usize,
    /// Unknown fields, kept as written.
    #[serde(flatten)]
    pub extra: Map<String, Value>,
}

/// Training poses in other base orientations: fewer than [`MAX_ORIENTATIONS`], each numbered
/// without a gap, and some poses in the usual one (0), which the fit starts from.
fn check_orientations(t: &TrainingExperiment) -> Result<(), MeasurementError> {
    let mut count = [0usize; MAX_ORIENTATIONS];
    for (p, tp) in t.poses.iter().enumerate() {
        match count.get_mut(tp.orientation) {
            Some(n) => *n += 1,
            None => {
                return Err(MeasurementError::InvalidValue {
                    field: format!("training.poses[{p}].orientation"),
                    reason: format!(
                        "{} is not a base orientation: number them 0 (the usual one) to {}",
                        tp.orientation,
                        MAX_ORIENTATIONS - 1
                    ),
                })
            }
        }
    }
    if count[0] == 0 {
        return Err(MeasurementError::InvalidValue {
            field: "training.poses".into(),
            reason: "has no pose in base orientation 0: the usual orientation is the one the fit starts from, so number the orientation most poses were recorded in 0".into(),
        });
    }
    if let Some(gap) = (1..MAX_ORIENTATIONS).find(|&o| count[o] > 0 && count[o - 1] == 0) {
        return Err(MeasurementError::InvalidValue {
            field: "training.poses".into(),
            reason: format!(
                "has poses in base orientation {gap} but none in {}: number the orientations without a gap",
                gap - 1
            ),
        });
    }
    Ok(())
}

pub(crate) fn is_zero(n: &usize) -> bool {
    *n == 0
}

/// The most base orientations a training experiment may have (the usual one and seven others).
pub const MAX_ORIENTATIONS: usize = 8;

impl MeasurementSet {
    /// An empty set for these DoFs and SUs.
    pub fn new(dofs: Vec<String>, sus: Vec<String>) -> Self {
        Self {
            format: FORMAT.into(),
            version: VERSION,
            units: Units::default(),
            dofs,
            sus,
            prismatic: Vec::new(),
            mimic: BTreeMap::new(),
            structure: None,
            training: None,
            extra: Map::new(),
        }
    }

    /// Parses and validates JSON text.
    pub fn from_json(text: &str) -> Result<Self, MeasurementError> {
        let set: Self =
            crate::json::parse(text, "a measurement set").map_err(MeasurementError::Syntax)?;
        set.validate()?;
        Ok(set)
    }

    /// Serialises to pretty JSON.
    pub fn to_json(&self) -> String {
        serde_json::to_string_pretty(self).expect("a measurement set always serialises")
    }

    /// The same set without the readings of the SUs named in `drop` (names it does not have are
    /// ignored): what the skin would have recorded without them.
    pub fn without_sus(&self, drop: &[String]) -> Self {
        let keep: Vec<bool> = self.sus.iter().map(|su| !drop.contains(su)).collect();
        // Any per-SU list (readings, their deviations); an empty one stays empty.
        fn filter<T>(values: &mut Vec<T>, keep: &[bool]) {
            let mut kept = keep.iter();
            values.retain(|_| kept.next().copied().unwrap_or(true));
        }
        let mut set = self.clone();
        set.sus.retain(|su| !drop.contains(su));
        for o in set.structure.iter_mut().flat_map(|s| &mut s.orientations) {
            filter(&mut o.rest, &keep);
            for mv in &mut o.moves {
                filter(&mut mv.readings, &keep);
                filter(&mut mv.accelerated, &keep);
                filter(&mut mv.accelerated_sd, &keep);
            }
        }
        for pose in set.training.iter_mut().flat_map(|t| &mut t.poses) {
            filter(&mut pose.static_readings, &keep);
            for readings in pose.dynamic.values_mut() {
                filter(readings, &keep);
            }
            pose.static_sd.iter_mut().for_each(|sd| filter(sd, &keep));
            pose.dynamic_sd
                .values_mut()
                .for_each(|sd| filter(sd, &keep));
        }
        set
    }

    /// The same readings without their standard deviations: every one then has the estimator's
    /// noise setting.
    pub fn without_uncertainties(&self) -> Self {
        let mut set = self.clone();
        for pose in set.training.iter_mut().flat_map(|t| &mut t.poses) {
            pose.static_sd = None;
            pose.dynamic_sd.clear();
        }
        set
    }

    /// Index of a DoF by name.
    pub fn dof_index(&self, name: &str) -> Option<usize> {
        self.dofs.iter().position(|d| d == name)
    }

    /// Whether DoF `d` (an index into `dofs`) is revolute or prismatic.
    pub fn dof_kind(&self, d: usize) -> DofKind {
        if self.prismatic.contains(&self.dofs[d]) {
            DofKind::Prismatic
        } else {
            DofKind::Revolute
        }
    }

    /// Whether DoF `d` (an index into `dofs`) is a mimic joint (it moves only with its leader).
    pub fn is_follower(&self, d: usize) -> bool {
        self.mimic.contains_key(&self.dofs[d])
    }

    /// The indices of the DoFs that follow DoF `leader` (mimic joints).
    pub fn followers_of(&self, leader: usize) -> Vec<usize> {
        self.mimic
            .iter()
            .filter(|(_, m)| m.leader == self.dofs[leader])
            .filter_map(|(f, _)| self.dof_index(f))
            .collect()
    }

    /// Checks every invariant of the format: header, unique names, array lengths, known DoF
    /// names, finite values.
    pub fn validate(&self) -> Result<(), MeasurementError> {
        if self.format != FORMAT {
            return Err(MeasurementError::WrongFormat {
                found: self.format.clone(),
            });
        }
        if self.version != VERSION {
            return Err(MeasurementError::UnsupportedVersion {
                found: self.version,
            });
        }
        for (field, names) in [("dofs", &self.dofs), ("sus", &self.sus)] {
            let mut seen = std::collections::HashSet::new();
            for n in names {
                if !seen.insert(n) {
                    return Err(MeasurementError::DuplicateName {
                        field,
                        name: n.clone(),
                    });
                }
            }
        }
        for (i, name) in self.prismatic.iter().enumerate() {
            self.check_dof(format!("prismatic[{i}]"), name)?;
        }
        for (name, m) in &self.mimic {
            self.check_dof(format!("mimic.{name}"), name)?;
            self.check_dof(format!("mimic.{name}.joint"), &m.leader)?;
            if self.mimic.contains_key(&m.leader)
                || !m.multiplier.is_finite()
                || !m.offset.is_finite()
            {
                return Err(MeasurementError::InvalidValue {
                    field: format!("mimic.{name}"),
                    reason: format!("it follows `{}`, which follows another DoF itself or with a non-finite factor: name the DoF with the actuator and finite `multiplier` and `offset`", m.leader),
                });
            }
        }
        self.units.check()?;
        if let Some(s) = &self.structure {
            self.check_structure(s)?;
        }
        if let Some(t) = &self.training {
            self.check_training(t)?;
        }
        self.check_gravity_scale()
    }

    /// `q` at `field`: one angle per DoF, each within [`MAX_ANGLE`].
    fn check_pose(&self, field: String, q: &[f64]) -> Result<(), MeasurementError> {
        shape(&field, q.len(), self.dofs.len(), "one angle per DoF")?;
        bounded(
            q.iter().copied(),
            MAX_ANGLE,
            "rad",
            "wrap the angle into ±π",
        )
        .map_err(|(i, reason)| MeasurementError::InvalidValue {
            field: format!("{field}[{i}] (DoF {})", self.dofs[i]),
            reason,
        })
    }

    /// `r` at `field`: one reading per SU, each component within [`MAX_READING`].
    fn check_readings(&self, field: String, r: &[Reading]) -> Result<(), MeasurementError> {
        shape(&field, r.len(), self.sus.len(), "one reading per SU")?;
        bounded(
            r.iter().flatten().copied(),
            MAX_READING,
            "m/s²",
            "no accelerometer reads that much: is the file in another unit, or the reading corrupt?",
        )
        .map_err(|(i, reason)| MeasurementError::InvalidValue {
            field: format!("{field}[{}][{}] (SU {})", i / 3, i % 3, self.sus[i / 3]),
            reason,
        })
    }

    /// `name` at `field` is one of the set's DoFs.
    fn check_dof(&self, field: String, name: &str) -> Result<(), MeasurementError> {
        match self.dof_index(name) {
            Some(_) => Ok(()),
            None => Err(MeasurementError::UnknownDof {
                field,
                name: name.to_string(),
            }),
        }
    }

    fn check_structure(&self, s: &StructureExperiment) -> Result<(), MeasurementError> {
        if s.orientations.is_empty() {
            return Err(MeasurementError::InvalidValue {
                field: "structure.orientations".into(),
                reason: "empty: a structure experiment has at least one base orientation (leave `structure` out when there is none)".into(),
            });
        }
        for (o, orientation) in s.orientations.iter().enumerate() {
            let base = format!("structure.orientations[{o}]");
            self.check_pose(format!("{base}.rest_pose"), &orientation.rest_pose)?;
            self.check_readings(format!("{base}.rest"), &orientation.rest)?;
            for (m, mv) in orientation.moves.iter().enumerate() {
                let field = format!("{base}.moves[{m}]");
                self.check_dof(format!("{field}.dof"), &mv.dof)?;
                self.check_pose(format!("{field}.pose"), &mv.pose)?;
                self.check_readings(format!("{field}.readings"), &mv.readings)?;
                if !mv.accelerated.is_empty() {
                    self.check_readings(format!("{field}.accelerated"), &mv.accelerated)?;
                }
                self.check_gain_deviations(&field, mv)?;
            }
        }
        Ok(())
    }

    /// A move's `accelerated_sd`: with `accelerated`, one non-negative number (or `null`) per SU.
    fn check_gain_deviations(&self, field: &str, mv: &Move) -> Result<(), MeasurementError> {
        if mv.accelerated_sd.is_empty() {
            return Ok(());
        }
        let field = format!("{field}.accelerated_sd");
        if mv.accelerated.is_empty() {
            return Err(MeasurementError::InvalidValue {
                field,
                reason: "is given without `accelerated`: give both, or leave it out".into(),
            });
        }
        shape(
            &field,
            mv.accelerated_sd.len(),
            self.sus.len(),
            "one standard deviation (or null) per SU",
        )?;
        let bad = mv
            .accelerated_sd
            .iter()
            .enumerate()
            .find_map(|(i, v)| v.filter(|v| !(v.is_finite() && *v >= 0.0)).map(|v| (i, v)));
        if let Some((i, v)) = bad {
            return Err(MeasurementError::InvalidValue {
                field: format!("{field}[{i}] (SU {})", self.sus[i]),
                reason: format!(
                    "{v} must be a non-negative number in the units of `accelerated`, or null \
                     where the SU's value is not known"
                ),
            });
        }
        Ok(())
    }

    fn check_training(&self, t: &TrainingExperiment) -> Result<(), MeasurementError> {
        if t.poses.is_empty() {
            return Err(MeasurementError::InvalidValue {
                field: "training.poses".into(),
                reason: "is empty: record training poses, or leave `training` out".into(),
            });
        }
        if let Err(reason) = t.pattern.check() {
            return Err(MeasurementError::InvalidValue {
                field: "training.pattern".into(),
                reason,
            });
        }
        for (p, tp) in t.poses.iter().enumerate() {
            let base = format!("training.poses[{p}]");
            self.check_pose(format!("{base}.q"), &tp.q)?;
            self.check_readings(format!("{base}.static"), &tp.static_readings)?;
            for (dof, r) in &tp.dynamic {
                let field = format!("{base}.dynamic[\"{dof}\"]");
                self.check_dof(field.clone(), dof)?;
                self.check_readings(field, r)?;
            }
            self.check_deviations(&base, tp)?;
        }
        check_orientations(t)
    }

    /// A training pose's standard deviations: one positive number per SU, dynamic ones only for
    /// the DoFs the pose has readings of.
    fn check_deviations(&self, base: &str, tp: &TrainingPose) -> Result<(), MeasurementError> {
        let sds = tp
            .static_sd
            .iter()
            .map(|sd| (format!("{base}.static_sd"), sd));
        let dynamic = tp
            .dynamic_sd
            .iter()
            .map(|(dof, sd)| (format!("{base}.dynamic_sd[\"{dof}\"]"), sd));
        for (field, sd) in sds.chain(dynamic) {
            shape(
                &field,
                sd.len(),
                self.sus.len(),
                "one standard deviation per SU",
            )?;
            if let Some(i) = sd.iter().position(|v| !(v.is_finite() && *v > 0.0)) {
                return Err(MeasurementError::InvalidValue {
                    field: format!("{field}[{i}] (SU {})", self.sus[i]),
                    reason: format!(
                        "{} must be a positive number of m/s²; leave the field out \
                         when the uncertainty is not known",
                        sd[i]
                    ),
                });
            }
        }
        for dof in tp.dynamic_sd.keys() {
            if !tp.dynamic.contains_key(dof) {
                return Err(MeasurementError::InvalidValue {
                    field: format!("{base}.dynamic_sd[\"{dof}\"]"),
                    reason: "has no dynamic readings of that DoF in the pose".into(),
                });
            }
        }
        Ok(())
    }

    /// The median norm of every static reading, m/s² (`None` without any): |g| for accelerometers
    /// at rest, whatever their orientation.
    pub fn median_static_norm(&self) -> Option<f64> {
        let mut norms: Vec<f64> = self.static_readings().map(norm).collect();
        if norms.is_empty() {
            return None;
        }
        let mid = norms.len() / 2;
        Some(*norms.select_nth_unstable_by(mid, f64::total_cmp).1)
    }

    /// A resting accelerometer reads |g|: when the median norm of the static readings is far from
    /// it, the readings are in another unit (g, mg) or not accelerometer readings at all. A few dead
    /// or biased SUs do not move the median.
    fn check_gravity_scale(&self) -> Result<(), MeasurementError> {
        let Some(median) = self.median_static_norm() else {
            return Ok(());
        };
        let looks_like = match ApparentUnit::of(median) {
            None => return Ok(()),
            Some(ApparentUnit::G) => "they look like g: multiply every reading by 9.81".to_string(),
            Some(ApparentUnit::Mg) => {
                "they look like mg: multiply every reading by 0.00981".to_string()
            }
            Some(ApparentUnit::Zero) => {
                "most SUs read zero: dead sensors, or readings not filled in".to_string()
            }
            Some(ApparentUnit::Other(scale)) => {
                format!("scale them by {scale:.4} if they are in another unit")
            }
        };
        Err(MeasurementError::InvalidValue {
            field: "static readings".into(),
            reason: format!(
                "their median norm is {median:.4} m/s², but a resting accelerometer reads |g| = {STANDARD_GRAVITY} m/s² (`units.acceleration` says {}): {looks_like}",
                self.units.acceleration
            ),
        })
    }
}

/// The unit accelerometer readings at rest seem to be in, told by their median norm taken as
/// m/s² (|g| in m/s², 1 in g, 1000 in mg).
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum ApparentUnit {
    /// Standard gravity.
    G,
    /// A thousandth of g.
    Mg,
    /// Nothing: most readings are zero.
    Zero,
    /// Another: the readings times this are in m/s².
    Other(f64),
}

impl ApparentUnit {
    /// The unit of readings whose median norm is `median`; `None` for m/s² (within a factor of 2
    /// of |g|, which dead or biased sensors do not leave).
    pub fn of(median: f64) -> Option<ApparentUnit> {
        if (0.5..=2.0).contains(&(median / STANDARD_GRAVITY)) {
            None
        } else if (0.5..=2.0).contains(&median) {
            Some(ApparentUnit::G)
        } else if (500.0..=2000.0).contains(&median) {
            Some(ApparentUnit::Mg)
        } else if median == 0.0 {
            Some(ApparentUnit::Zero)
        } else {
            Some(ApparentUnit::Other(STANDARD_GRAVITY / median))
        }
    }
}

impl Units {
    /// Refuses units other than SI, saying how to convert.
    pub fn check(&self) -> Result<(), MeasurementError> {
        let acceleration = self.acceleration.trim();
        if !matches!(
            acceleration,
            "m/s^2" | "m/s²" | "m s^-2" | "m*s^-2" | "m/s/s"
        ) {
            let convert = match acceleration.to_ascii_lowercase().as_str() {
                "g" | "g0" | "gee" => "multiply every reading by 9.81",
                "mg" | "milli-g" => "multiply every reading by 0.00981",
                "cm/s^2" | "cm/s²" | "gal" => "multiply every reading by 0.01",
                _ => "convert every reading to m/s²",
            };
            return Err(MeasurementError::InvalidValue {
                field: "units.acceleration".into(),
                reason: format!(
                    "`{}` is not supported: skincal reads specific force in m/s² only; {convert} and write \"m/s^2\"",
                    self.acceleration
                ),
            });
        }
        let angle = self.angle.trim();
        if angle != "rad" {
            let convert = match angle.to_ascii_lowercase().as_str() {
                "deg" | "degree" | "degrees" | "°" => "multiply every angle by π/180 = 0.0174533",
                _ => "convert every angle to rad",
            };
            return Err(MeasurementError::InvalidValue {
                field: "units.angle".into(),
                reason: format!(
                    "`{}` is not supported: skincal reads joint angles in rad only; {convert} and write \"rad\"",
                    self.angle
                ),
            });
        }
        Ok(())
    }
}

fn shape(
    field: &str,
    found: usize,
    expected: usize,
    what: &'static str,
) -> Result<(), MeasurementError> {
    if found == expected {
        Ok(())
    } else {
        Err(MeasurementError::Shape {
            field: field.to_string(),
            expected,
            found,
            what,
        })
    }
}

/// The norm of a reading, m/s².
fn norm(r: &Reading) -> f64 {
    (r[0] * r[0] + r[1] * r[1] + r[2] * r[2]).sqrt()
}

/// Every value finite and within ±`limit`, else the index of the first that is not and why.
fn bounded(
    values: impl Iterator<Item = f64>,
    limit: f64,
    unit: &str,
    hint: &str,
) -> Result<(), (usize, String)> {
    for (i, v) in values.enumerate() {
        if !v.is_finite() {
            return Err((i, format!("{v} is not a finite number")));
        }
        if v.abs() > limit {
            return Err((
                i,
                format!(
                    "{} {unit} is beyond ±{limit} {unit}: {hint}",
                    crate::show::number(v)
                ),
            ));
        }
    }
    Ok(())
}

/// Figures that tell at a glance what a measurement set holds.
#[derive(Debug, Clone, PartialEq)]
pub struct Summary {
    /// Number of DoFs.
    pub dofs: usize,
    /// Number of SUs.
    pub sus: usize,
    /// Number of base orientations of the structure experiment.
    pub orientations: usize,
    /// Number of static poses of the structure experiment (rest poses included).
    pub structure_poses: usize,
    /// Number of training poses.
    pub training_poses: usize,
    /// The training excitation pattern.
    pub pattern: Option<ExcitationPattern>,
    /// Mean and standard deviation of the norm of every static reading, m/s² (≈ 9.81 at rest).
    pub static_norm: (f64, f64),
    /// Per DoF: RMS norm of the dynamic accelerations over poses and SUs, m/s².
    pub dynamic_rms: Vec<(String, f64)>,
}

impl MeasurementSet {
    /// Every static reading: structure rest and moves, training poses.
    fn static_readings(&self) -> impl Iterator<Item = &Reading> {
        let structure = self.structure.iter().flat_map(|s| &s.orientations);
        let training = self.training.iter().flat_map(|t| &t.poses);
        structure
            .flat_map(|o| {
                o.rest
                    .iter()
                    .chain(o.moves.iter().flat_map(|m| &m.readings))
            })
            .chain(training.flat_map(|p| &p.static_readings))
    }

    /// Figures that tell at a glance what the set holds.
    pub fn summary(&self) -> Summary {
        let norms: Vec<f64> = self.static_readings().map(norm).collect();
        let orientations = self.structure.as_ref().map_or(0, |s| s.orientations.len());
        let structure_poses = self
            .structure
            .iter()
            .flat_map(|s| &s.orientations)
            .map(|o| 1 + o.moves.len())
            .sum();
        let poses = self.training.as_ref().map_or(&[][..], |t| &t.poses[..]);
        let n = norms.len().max(1) as f64;
        let mean = norms.iter().sum::<f64>() / n;
        let sd = (norms.iter().map(|x| (x - mean).powi(2)).sum::<f64>() / n).sqrt();
        let dynamic_rms = self
            .dofs
            .iter()
            .map(|d| {
                let v: Vec<f64> = poses
                    .iter()
                    .filter_map(|p| p.dynamic.get(d))
                    .flatten()
                    .map(norm)
                    .collect();
                let rms = (v.iter().map(|x| x * x).sum::<f64>() / v.len().max(1) as f64).sqrt();
                (d.clone(), rms)
            })
            .collect();
        Summary {
            dofs: self.dofs.len(),
            sus: self.sus.len(),
            orientations,
            structure_poses,
            training_poses: poses.len(),
            pattern: self.training.as_ref().map(|t| t.pattern),
            static_norm: (mean, sd),
            dynamic_rms,
        }
    }
}
