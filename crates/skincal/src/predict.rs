//! What a calibrated model predicts the skin reads, and the check of a calibration against a second
//! measurement set (held-out poses).
//!
//! Predictions follow the measurement set's conventions (docs/measurements.md): a static reading is
//! the specific force `R_SUᵀ·(−g)` in the SU frame, a dynamic acceleration the tangential
//! acceleration `α·R_SUᵀ·(z × r)` at the pattern's peak, in m/s². Only the DoFs that move an SU
//! have a dynamic entry for it (the others read zero by definition). Where the model holds an SU's
//! accelerometer intrinsics, a prediction is what that SU *reads* — `K·f + b` static, `K·a`
//! dynamic ([`crate::model::intrinsics`]) — which is what `validate` compares with measured
//! readings; [`Predictor::ideal`] predicts what an ideal accelerometer in the same frame would.

use std::collections::BTreeMap;

use serde::{Deserialize, Serialize};
use serde_json::{Map, Value};

use crate::estimate::body::BodyModel;
use crate::measurements::MeasurementSet;
use crate::model::intrinsics::Intrinsics;
use crate::model::sensor::{peak_dynamic_accelerations_at, specific_force, ExcitationPattern};
use crate::model::{forward_kinematics, Robot};
use nalgebra::Vector3;

/// Errors of prediction and validation.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
#[non_exhaustive]
pub enum PredictError {
    /// The model file is not a usable model.
    #[error("the model is not usable: {0}")]
    Model(String),
    /// Names of the model are missing from the other side.
    #[error("{what} of the model missing from {other}: {}; the model and the data must name the same {what}", missing.join(", "))]
    Missing {
        /// `DoFs` or `SUs`.
        what: &'static str,
        /// The data compared with.
        other: String,
        /// The names.
        missing: Vec<String>,
    },
    /// A pose table is malformed.
    #[error("poses: {0}")]
    Poses(String),
    /// The measurement set has no training experiment to compare with.
    #[error("the measurement set has no training experiment (`training`) to compare with")]
    NoTraining,
    /// A pose of the set stood in a base orientation the model was not calibrated in.
    #[error("{set}: training.poses[{pose}] stood in base orientation {orientation}, which the model's training had no poses in, so the gravity there is unknown: compare poses of the orientations it was calibrated in")]
    Orientation {
        /// The pose's index.
        pose: usize,
        /// Its base orientation.
        orientation: usize,
        /// The set compared with.
        set: String,
    },
}

/// Joint positions by DoF name: the `--poses` input of `skincal predict`.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct PoseTable {
    /// DoF names, one per column.
    pub dofs: Vec<String>,
    /// One row of positions (rad) per pose.
    pub poses: Vec<Vec<f64>>,
}

impl PoseTable {
    /// From CSV: a header of DoF names, one pose per row (rad). Blank lines and lines starting
    /// with `#` are skipped.
    pub fn from_csv(text: &str) -> Result<Self, PredictError> {
        let mut lines = text
            .lines()
            .enumerate()
            .filter(|(_, l)| !l.trim().is_empty() && !l.trim_start().starts_with('#'));
        let (_, header) = lines.next().ok_or_else(|| {
            PredictError::Poses("empty file: expected a header of DoF names".into())
        })?;
        let dofs = Self::csv_header(header);
        let mut poses = Vec::new();
        for (n, line) in lines {
            poses.push(Self::csv_row(line, n + 1, &dofs)?);
        }
        let table = Self { dofs, poses };
        table.check()?;
        Ok(table)
    }

    /// The DoF names of a CSV header line.
    pub fn csv_header(line: &str) -> Vec<String> {
        line.trim_start_matches('\u{feff}')
            .split(',')
            .map(|s| s.trim().to_string())
            .collect()
    }

    /// One CSV pose row (line number `line` for messages): one finite number per DoF.
    pub fn csv_row(text: &str, line: usize, dofs: &[String]) -> Result<Vec<f64>, PredictError> {
        let row: Vec<f64> = text
            .split(',')
            .enumerate()
            .map(|(c, v)| {
                v.trim()
                    .parse::<f64>()
                    .ok()
                    .filter(|x| x.is_finite())
                    .ok_or_else(|| {
                        PredictError::Poses(format!(
                            "line {line}, column {} (`{}`): `{}` is not a finite number",
                            c + 1,
                            dofs.get(c).map_or("?", String::as_str),
                            v.trim()
                        ))
                    })
            })
            .collect::<Result<_, _>>()?;
        if row.len() != dofs.len() {
            return Err(PredictError::Poses(format!(
                "line {line} has {} values for {} DoFs",
                row.len(),
                dofs.len()
            )));
        }
        Ok(row)
    }

    /// From JSON: `{"dofs": [names], "poses": [[q per DoF]]}` (the output of `predict` has this shape).
    pub fn from_json(text: &str) -> Result<Self, PredictError> {
        let table: Self = crate::json::parse(text, "a pose table").map_err(PredictError::Poses)?;
        table.check()?;
        Ok(table)
    }

    fn check(&self) -> Result<(), PredictError> {
        let mut seen = std::collections::HashSet::new();
        for d in &self.dofs {
            if d.is_empty() || !seen.insert(d) {
                return Err(PredictError::Poses(format!(
                    "DoF name `{d}` is empty or appears twice in the header"
                )));
            }
        }
        for (p, row) in self.poses.iter().enumerate() {
            if row.len() != self.dofs.len() {
                return Err(PredictError::Poses(format!(
                    "pose {} has {} values for {} DoFs",
                    p + 1,
                    row.len(),
                    self.dofs.len()
                )));
            }
            if let Some(c) = row.iter().position(|v| !v.is_finite()) {
                return Err(PredictError::Poses(format!(
                    "pose {}, DoF `{}`: not a finite number",
                    p + 1,
                    self.dofs[c]
                )));
            }
        }
        Ok(())
    }
}

/// A calibrated model ready to predict.
#[derive(Debug, Clone)]
pub struct Predictor {
    robot: Robot,
    /// Gravity (body frame) per SU of the robot.
    gravity: Vec<Vector3<f64>>,
    /// `other_gravity[o − 1]`: the same in base orientation `o` of the training poses, for each
    /// orientation every SU's calibration had.
    other_gravity: Vec<Vec<Vector3<f64>>>,
    /// Accelerometer intrinsics per SU of the robot (ideal where the model has none).
    intrinsics: Vec<Intrinsics>,
    /// DoFs of the robot's measurement set that the model does not calibrate: a pose may name
    /// them (their values do not matter).
    ignored: Vec<String>,
}

/// Readings of every SU in one pose, in the model's SU order.
#[derive(Debug, Clone, PartialEq)]
pub struct PoseReadings {
    /// Static readings, m/s².
    pub statics: Vec<Vector3<f64>>,
    /// Per model DoF: `(SU index, dynamic acceleration)` for every SU it moves.
    pub dynamic: Vec<Vec<(usize, Vector3<f64>)>>,
}

impl Predictor {
    /// Checks the model and builds its robot.
    pub fn new(model: &BodyModel) -> Result<Self, PredictError> {
        let robot = model.check().map_err(PredictError::Model)?;
        let names = robot.model.su_names();
        let other_gravity = (1..)
            .map(|o| {
                let by_su = model.gravity_by_su_in(o);
                names.iter().map(|s| by_su.get(s).copied()).collect()
            })
            .map_while(|g: Option<Vec<_>>| g)
            .collect();
        let by_su = model.gravity_by_su();
        let gravity = robot
            .model
            .su_names()
            .iter()
            .map(|s| {
                by_su.get(s).copied().ok_or_else(|| {
                    PredictError::Model(format!("SU `{s}` belongs to no limb and is not static"))
                })
            })
            .collect::<Result<_, _>>()?;
        let by_su: BTreeMap<&str, Intrinsics> = model
            .limbs
            .iter()
            .flat_map(|l| &l.estimate.intrinsics)
            .map(|i| (i.su.as_str(), i.value))
            .collect();
        let intrinsics = robot
            .model
            .su_names()
            .iter()
            .map(|s| by_su.get(s.as_str()).copied().unwrap_or_default())
            .collect();
        let ignored = model
            .not_calibrated
            .iter()
            .filter(|n| n.kind == "dof")
            .map(|n| n.name.clone())
            .collect();
        Ok(Self {
            robot,
            gravity,
            other_gravity,
            intrinsics,
            ignored,
        })
    }

    /// The same model with ideal accelerometers: predictions are the specific force (static) and
    /// the acceleration (dynamic) in each SU frame, not what the SU reads.
    pub fn ideal(mut self) -> Self {
        self.intrinsics = vec![Intrinsics::default(); self.intrinsics.len()];
        self
    }

    /// The robot, and per SU of it gravity (body frame) and the accelerometer's intrinsics.
    pub fn parts(&self) -> (&Robot, &[Vector3<f64>], &[Intrinsics]) {
        (&self.robot, &self.gravity, &self.intrinsics)
    }

    /// The model's DoF names.
    pub fn dofs(&self) -> Vec<String> {
        self.robot.model.dof_names()
    }

    /// The model's SU names.
    pub fn sus(&self) -> Vec<String> {
        self.robot.model.su_names()
    }

    /// Readings in pose `q` (model DoF order) under `pattern`: what each SU reads, with its
    /// intrinsics (see [`Predictor::ideal`]).
    ///
    /// ```
    /// use nalgebra::Vector3;
    /// use skincal::estimate::{body::calibrate_body, ml::MlConfig};
    /// use skincal::explore::{explore, ExploreConfig};
    /// use skincal::model::{forward_kinematics, presets};
    /// use skincal::predict::Predictor;
    /// use skincal::sim::{simulate, SimulationConfig};
    ///
    /// let robot = presets::find("paper-7dof").unwrap().robot().unwrap();
    /// let set = simulate(&robot, &SimulationConfig::default()).unwrap().measurements;
    /// let structure = explore(&set, &ExploreConfig::default()).unwrap();
    /// let model = calibrate_body(&set, Some(&structure), &MlConfig::default(), None).unwrap();
    /// let predictor = Predictor::new(&model).unwrap();
    ///
    /// // A pose by DoF name, in the model's order.
    /// let pose = [("dof1", 0.3), ("dof2", -0.2), ("dof3", 0.5), ("dof4", 0.1), ("dof5", -0.4), ("dof6", 0.2), ("dof7", 0.6)];
    /// let angle = |name: &str| pose.iter().find(|(d, _)| *d == name).unwrap().1;
    /// let q: Vec<f64> = predictor.dofs().iter().map(|d| angle(d)).collect();
    /// let predicted = predictor.readings(&q, &model.pattern);
    ///
    /// // The truth: an ideal accelerometer at rest reads the opposite of gravity in its own frame.
    /// let truth_q: Vec<f64> = robot.model.dof_names().iter().map(|d| angle(d)).collect();
    /// let frames = forward_kinematics(&robot.model, &robot.parameters, &truth_q);
    /// for (name, read) in predictor.sus().iter().zip(&predicted.statics) {
    ///     let frame = &frames.sus[robot.model.su_index(name).unwrap()];
    ///     let ideal = frame.rotation.inverse_transform_vector(&Vector3::new(0.0, 0.0, 9.80665));
    ///     assert!((ideal - read).norm() < 0.05, "{name}: {read:?} against {ideal:?}");
    /// }
    /// ```
    pub fn readings(&self, q: &[f64], pattern: &ExcitationPattern) -> PoseReadings {
        self.readings_with(q, pattern, &self.gravity)
    }

    /// Readings in pose `q` with the reference segment in base orientation `o` of the training
    /// poses (0: the usual one); `None` for an orientation the calibration had no poses in.
    pub fn readings_in(
        &self,
        q: &[f64],
        pattern: &ExcitationPattern,
        o: usize,
    ) -> Option<PoseReadings> {
        let gravity = match o {
            0 => &self.gravity,
            _ => self.other_gravity.get(o - 1)?,
        };
        Some(self.readings_with(q, pattern, gravity))
    }

    fn readings_with(
        &self,
        q: &[f64],
        pattern: &ExcitationPattern,
        gravity: &[Vector3<f64>],
    ) -> PoseReadings {
        let m = &self.robot.model;
        let k = forward_kinematics(m, &self.robot.parameters, q);
        let statics = k
            .sus
            .iter()
            .zip(gravity)
            .zip(&self.intrinsics)
            .map(|((frame, g), i)| i.read(&specific_force(frame, &Vector3::zeros(), g)))
            .collect();
        let dynamic = (0..m.dofs().len())
            .map(|d| {
                peak_dynamic_accelerations_at(m, &k, d, pattern)
                    .into_iter()
                    .enumerate()
                    .filter(|(u, _)| m.moves_su(d, *u))
                    .map(|(u, a)| (u, self.intrinsics[u].read_dynamic(&a)))
                    .collect()
            })
            .collect();
        PoseReadings { statics, dynamic }
    }

    /// For every model DoF, its column among `given` (a pose table's header); every model DoF must
    /// be there and no other.
    pub fn columns(&self, given: &[String], source: &str) -> Result<Vec<usize>, PredictError> {
        columns(&self.dofs(), given, &self.ignored, source)
    }

    /// The columns of `table` in model DoF order; every model DoF must be there and no other.
    pub fn arrange(&self, table: &PoseTable, source: &str) -> Result<Vec<Vec<f64>>, PredictError> {
        let dofs = self.dofs();
        let index = columns(&dofs, &table.dofs, &self.ignored, source)?;
        Ok(table
            .poses
            .iter()
            .map(|row| index.iter().map(|&c| row[c]).collect())
            .collect())
    }

    /// Predictions for every pose of `table` as JSON:
    /// `{"dofs", "pattern", "poses", "static": {su: [[x,y,z] per pose]}, "dynamic": {su: {dof: [...]}}}`.
    pub fn predict(
        &self,
        table: &PoseTable,
        pattern: &ExcitationPattern,
        source: &str,
    ) -> Result<Value, PredictError> {
        let poses = self.arrange(table, source)?;
        let dofs = self.dofs();
        let sus = self.sus();
        let mut statics: Vec<Vec<Value>> = vec![Vec::new(); sus.len()];
        let mut dynamic: Vec<Map<String, Value>> = vec![Map::new(); sus.len()];
        let vector = |v: &Vector3<f64>| serde_json::json!([v.x, v.y, v.z]);
        for q in &poses {
            let r = self.readings(q, pattern);
            for (u, s) in r.statics.iter().enumerate() {
                statics[u].push(vector(s));
            }
            for (d, moved) in r.dynamic.iter().enumerate() {
                for (u, a) in moved {
                    dynamic[*u]
                        .entry(dofs[d].clone())
                        .or_insert_with(|| Value::Array(Vec::new()))
                        .as_array_mut()
                        .expect("arrays only")
                        .push(vector(a));
                }
            }
        }
        let mut out = Map::new();
        out.insert("dofs".into(), serde_json::json!(dofs));
        out.insert("pattern".into(), serde_json::json!(pattern));
        out.insert("poses".into(), serde_json::json!(poses));
        out.insert(
            "static".into(),
            Value::Object(
                sus.iter()
                    .cloned()
                    .zip(statics.into_iter().map(Value::Array))
                    .collect(),
            ),
        );
        out.insert(
            "dynamic".into(),
            Value::Object(
                sus.iter()
                    .cloned()
                    .zip(dynamic.into_iter().map(Value::Object))
                    .filter(|(_, v)| v.as_object().is_some_and(|m| !m.is_empty()))
                    .collect(),
            ),
        );
        Ok(Value::Object(out))
    }
}

/// For every name of `wanted`, its column in `given`; `given` must hold every wanted name and no
/// other but those of `ignored`.
fn columns(
    wanted: &[String],
    given: &[String],
    ignored: &[String],
    source: &str,
) -> Result<Vec<usize>, PredictError> {
    let missing: Vec<String> = wanted
        .iter()
        .filter(|d| !given.contains(d))
        .cloned()
        .collect();
    if !missing.is_empty() {
        return Err(PredictError::Missing {
            what: "DoFs",
            other: source.into(),
            missing,
        });
    }
    if let Some(extra) = given
        .iter()
        .find(|d| !wanted.contains(d) && !ignored.contains(d))
    {
        return Err(PredictError::Poses(format!(
            "{source} names DoF `{extra}`, which the model does not have (its DoFs: {})",
            wanted.join(", ")
        )));
    }
    Ok(wanted
        .iter()
        .map(|d| given.iter().position(|g| g == d).expect("checked"))
        .collect())
}

/// Prediction errors of one SU: norm of the 3-vector difference, m/s².
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct SuError {
    /// The SU.
    pub su: String,
    /// RMS over poses of the static reading error.
    pub static_rms: f64,
    /// Largest static reading error.
    pub static_max: f64,
    /// RMS over poses and moving DoFs of the dynamic acceleration error (0 if no DoF moves it).
    pub dynamic_rms: f64,
    /// Largest dynamic acceleration error.
    pub dynamic_max: f64,
    /// Dynamic readings compared.
    pub dynamic_count: usize,
}

/// Prediction errors of the dynamic readings of one excited DoF: every SU it moves, in every
/// pose whose set gives its excitation; norm of the 3-vector difference, m/s².
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct DofError {
    /// The DoF.
    pub dof: String,
    /// RMS over poses and the SUs it moves of the dynamic acceleration error.
    pub dynamic_rms: f64,
    /// Largest dynamic acceleration error.
    pub dynamic_max: f64,
    /// Dynamic readings compared.
    pub dynamic_count: usize,
    /// The error a perfect model would show on these readings: their own noise (as
    /// [`Validation::dynamic_floor`]).
    pub floor: f64,
}

/// Why some DoFs' dynamic readings predict worse than others', for tables and the report.
pub const UNEVEN_DOFS: &str = "a DoF read only by SUs near its axis or on the first segments of a \
     limb predicts worse; more poses lower every DoF alike";

/// Each of `errors` (one per DoF) as a multiple of their median; `None` when there are none or
/// the median is zero.
pub fn over_median(errors: &[f64]) -> Option<Vec<f64>> {
    let mut sorted = errors.to_vec();
    sorted.sort_by(f64::total_cmp);
    let median = *sorted.get(sorted.len() / 2).filter(|m| **m > 0.0)?;
    Some(errors.iter().map(|e| e / median).collect())
}

/// A model checked against a measurement set.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Validation {
    /// Poses compared.
    pub poses: usize,
    /// Per SU of the model.
    pub sus: Vec<SuError>,
    /// RMS over every static reading compared, m/s².
    pub static_rms: f64,
    /// Largest static error, m/s².
    pub static_max: f64,
    /// RMS over every dynamic acceleration compared, m/s².
    pub dynamic_rms: f64,
    /// Largest dynamic error, m/s².
    pub dynamic_max: f64,
    /// Per model DoF whose excitation the set gives (model order): its dynamic readings' errors.
    /// A DoF whose excitation few SUs read, all of them near its axis or on the first segments
    /// of a limb (few DoFs tell their pose), predicts worse than the rest.
    #[serde(default)]
    pub dofs: Vec<DofError>,
    /// SUs of the set that the model does not cover (not compared).
    pub not_in_model: Vec<String>,
    /// The static error a perfect model would show, m/s² RMS: the readings' own noise (the norm
    /// of a 3-vector of it), from the set's standard deviations, else the model's noise.
    #[serde(default)]
    pub static_floor: f64,
    /// The same for the dynamic readings.
    #[serde(default)]
    pub dynamic_floor: f64,
    /// Where the floors come from: `"the readings' standard deviations"` or `"the model's noise"`.
    #[serde(default)]
    pub floor_source: String,
}

/// Each model DoF's and SU's column in `set`, which must name them all.
fn columns_in(
    dofs: &[String],
    sus: &[String],
    set: &MeasurementSet,
    source: &str,
) -> Result<(Vec<usize>, Vec<usize>), PredictError> {
    for (what, names, given) in [("DoFs", dofs, &set.dofs), ("SUs", sus, &set.sus)] {
        let missing: Vec<String> = names
            .iter()
            .filter(|n| !given.contains(n))
            .cloned()
            .collect();
        if !missing.is_empty() {
            return Err(PredictError::Missing {
                what,
                other: source.into(),
                missing,
            });
        }
    }
    let column = |names: &[String], given: &[String]| -> Vec<usize> {
        names
            .iter()
            .map(|n| given.iter().position(|g| g == n).expect("checked"))
            .collect()
    };
    Ok((column(dofs, &set.dofs), column(sus, &set.sus)))
}

/// One SU's residuals on a measurement set: every component of every reading, predicted minus
/// read, divided by the reading's standard deviation (the set's own where it has one, else the
/// static or dynamic noise its limb's fit estimated, else the model's noise). A model whose noise
/// is right leaves them standard normal.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct SuResiduals {
    /// The SU.
    pub su: String,
    /// Its static readings' components, whitened.
    pub statics: Vec<f64>,
    /// Its dynamic readings' components, whitened.
    pub dynamics: Vec<f64>,
}

/// One reading of a measurement set beside the model's prediction of it.
struct Compared {
    /// The SU, in the model's order.
    su: usize,
    /// The excited DoF of a dynamic reading (model order); `None`: the static reading.
    dof: Option<usize>,
    /// Predicted minus read, m/s².
    error: Vector3<f64>,
    /// The standard deviation of each component that the set gives, if it does.
    sd: Option<f64>,
}

/// Every reading of `set`'s training poses that `predictor` predicts — each SU's static reading,
/// and its dynamic reading for every excited DoF that moves it — handed to `visit` pose by pose;
/// returns the number of poses.
fn compare_readings(
    predictor: &Predictor,
    set: &MeasurementSet,
    source: &str,
    mut visit: impl FnMut(Compared),
) -> Result<usize, PredictError> {
    let training = set.training.as_ref().ok_or(PredictError::NoTraining)?;
    let (dofs, sus) = (predictor.dofs(), predictor.sus());
    let (dof_col, su_col) = columns_in(&dofs, &sus, set, source)?;
    for (p, pose) in training.poses.iter().enumerate() {
        let q: Vec<f64> = dof_col.iter().map(|&c| pose.q[c]).collect();
        let r = predictor
            .readings_in(&q, &training.pattern, pose.orientation)
            .ok_or_else(|| PredictError::Orientation {
                pose: p,
                orientation: pose.orientation,
                set: source.to_string(),
            })?;
        for (u, predicted) in r.statics.iter().enumerate() {
            visit(Compared {
                su: u,
                dof: None,
                error: predicted - Vector3::from(pose.static_readings[su_col[u]]),
                sd: pose.static_sd.as_ref().map(|sd| sd[su_col[u]]),
            });
        }
        for (d, moved) in r.dynamic.iter().enumerate() {
            let Some(measured) = pose.dynamic.get(&dofs[d]) else {
                continue;
            };
            let sd = pose.dynamic_sd.get(&dofs[d]);
            for (u, a) in moved {
                visit(Compared {
                    su: *u,
                    dof: Some(d),
                    error: a - Vector3::from(measured[su_col[*u]]),
                    sd: sd.map(|sd| sd[su_col[*u]]),
                });
            }
        }
    }
    Ok(training.poses.len())
}

/// The whitened residuals ([`SuResiduals`]) of every SU of the model on the training poses of
/// `set`, in the model's SU order.
pub fn whitened_residuals(
    model: &BodyModel,
    set: &MeasurementSet,
    source: &str,
) -> Result<Vec<SuResiduals>, PredictError> {
    let predictor = Predictor::new(model)?;
    // Where the set gives no deviation: the static and dynamic noise the SU's limb estimated.
    let estimated: BTreeMap<&str, (f64, f64)> = model
        .limbs
        .iter()
        .filter_map(|l| {
            let n = l.estimate.noise_components.as_ref()?;
            Some(
                l.sus
                    .iter()
                    .map(move |s| (s.as_str(), (n.static_sd, n.dynamic_sd))),
            )
        })
        .flatten()
        .collect();
    let mut out: Vec<(SuResiduals, (f64, f64))> = predictor
        .sus()
        .into_iter()
        .map(|su| {
            let noise = estimated
                .get(su.as_str())
                .copied()
                .unwrap_or((model.noise_sd, model.noise_sd));
            let residuals = SuResiduals {
                su,
                statics: Vec::new(),
                dynamics: Vec::new(),
            };
            (residuals, noise)
        })
        .collect();
    compare_readings(&predictor, set, source, |c| {
        let (r, (static_sd, dynamic_sd)) = &mut out[c.su];
        let (into, sd) = if c.dof.is_some() {
            (&mut r.dynamics, c.sd.unwrap_or(*dynamic_sd))
        } else {
            (&mut r.statics, c.sd.unwrap_or(*static_sd))
        };
        into.extend(c.error.iter().map(|e| e / sd));
    })?;
    Ok(out.into_iter().map(|(r, _)| r).collect())
}

/// Errors of a group of readings (an SU's static or dynamic ones, a DoF's): norms of the 3-vector
/// differences, and the noise variance of the same readings.
#[derive(Debug, Clone, Copy, Default)]
struct Errors {
    squares: f64,
    max: f64,
    count: usize,
    noise: f64,
}

impl Errors {
    fn add(&mut self, error: f64, noise_variance: f64) {
        self.squares += error * error;
        self.max = self.max.max(error);
        self.count += 1;
        self.noise += noise_variance;
    }

    /// The groups taken as one.
    fn total(groups: &[Errors]) -> Errors {
        groups.iter().fold(Errors::default(), |a, g| Errors {
            squares: a.squares + g.squares,
            max: a.max.max(g.max),
            count: a.count + g.count,
            noise: a.noise + g.noise,
        })
    }

    /// RMS error (0 for no reading).
    fn rms(&self) -> f64 {
        (self.squares / self.count.max(1) as f64).sqrt()
    }

    /// What a perfect model would show: the readings' own noise, RMS.
    fn floor(&self) -> f64 {
        (self.noise / self.count.max(1) as f64).sqrt()
    }
}

/// Compares the model's predictions with the training experiment of `set` (its poses, its pattern).
/// Every DoF and SU of the model must be in the set.
///
/// ```
/// use skincal::estimate::{body::calibrate_body, ml::MlConfig};
/// use skincal::explore::{explore, ExploreConfig};
/// use skincal::model::presets;
/// use skincal::predict::validate;
/// use skincal::sim::{simulate, Imperfections, SimulationConfig};
///
/// let robot = presets::find("paper-7dof").unwrap().robot().unwrap();
/// let set = simulate(&robot, &SimulationConfig::default()).unwrap().measurements;
/// let structure = explore(&set, &ExploreConfig::default()).unwrap();
/// let model = calibrate_body(&set, Some(&structure), &MlConfig::default(), None).unwrap();
/// // Fresh poses of the same robot, without noise: what the calibration predicts there.
/// let held_out = SimulationConfig {
///     seed: 1001,
///     structure: false,
///     imperfections: Imperfections::none(),
///     ..SimulationConfig::default()
/// };
/// let held_out = simulate(&robot, &held_out).unwrap().measurements;
/// let check = validate(&model, &held_out, "held-out").unwrap();
/// assert_eq!(check.poses, held_out.summary().training_poses);
/// assert!(check.static_rms < 0.05 && check.dynamic_rms < 0.05, "{check:?}"); // m/s²
/// ```
pub fn validate(
    model: &BodyModel,
    set: &MeasurementSet,
    source: &str,
) -> Result<Validation, PredictError> {
    let predictor = Predictor::new(model)?;
    let (dofs, sus) = (predictor.dofs(), predictor.sus());
    let mut own_sd = true;
    let (mut statics, mut dynamics) = (
        vec![Errors::default(); sus.len()],
        vec![Errors::default(); sus.len()],
    );
    let mut per_dof = vec![Errors::default(); dofs.len()];
    let poses = compare_readings(&predictor, set, source, |c| {
        let e = c.error.norm();
        // The reading's own noise: a component's variance, summed over the 3 components.
        let sd = c.sd.unwrap_or_else(|| {
            own_sd = false;
            model.noise_sd
        });
        let variance = 3.0 * sd * sd;
        match c.dof {
            Some(d) => {
                dynamics[c.su].add(e, variance);
                per_dof[d].add(e, variance);
            }
            None => statics[c.su].add(e, variance),
        }
    })?;
    let per_su = sus
        .iter()
        .zip(statics.iter().zip(&dynamics))
        .map(|(su, (s, d))| SuError {
            su: su.clone(),
            static_rms: s.rms(),
            static_max: s.max,
            dynamic_rms: d.rms(),
            dynamic_max: d.max,
            dynamic_count: d.count,
        })
        .collect();
    let dofs = dofs
        .into_iter()
        .zip(&per_dof)
        .filter(|(_, e)| e.count > 0)
        .map(|(dof, e)| DofError {
            dof,
            dynamic_rms: e.rms(),
            dynamic_max: e.max,
            dynamic_count: e.count,
            floor: e.floor(),
        })
        .collect();
    let (all_static, all_dynamic) = (Errors::total(&statics), Errors::total(&dynamics));
    Ok(Validation {
        poses,
        sus: per_su,
        static_rms: all_static.rms(),
        static_max: all_static.max,
        dynamic_rms: all_dynamic.rms(),
        dynamic_max: all_dynamic.max,
        dofs,
        not_in_model: set
            .sus
            .iter()
            .filter(|s| !sus.contains(s))
            .cloned()
            .collect(),
        static_floor: all_static.floor(),
        dynamic_floor: all_dynamic.floor(),
        floor_source: if own_sd {
            "the readings' standard deviations"
        } else {
            "the model's noise"
        }
        .into(),
    })
}
