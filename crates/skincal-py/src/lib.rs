//! The native module of the `skincal` Python package (`skincal._skincal`).
//!
//! A thin layer over the library: each class holds the library's own value (a measurement set, a
//! structure, a calibrated model), numbers cross as numpy arrays (SI units), nested results as the
//! JSON the library and the CLI write (the Python layer parses it into objects), and errors become
//! `skincal.SkincalError` with the library's message. Long work runs with the interpreter released.

use std::collections::BTreeMap;
use std::path::PathBuf;

use numpy::ndarray::{Array2, Array3, Array4};
use numpy::{IntoPyArray, PyArray2, PyArray3, PyArray4, PyReadonlyArray2, PyReadonlyArray3};
use numpy::{PyReadonlyArray4, PyUntypedArrayMethods};
use pyo3::create_exception;
use pyo3::exceptions::PyException;
use pyo3::prelude::*;

use skincal::check::CheckConfig;
use skincal::estimate::body::{calibrate_body, BodyModel};
use skincal::estimate::ml::MlConfig;
use skincal::explore::{ExploreConfig, Structure as LibStructure};
use skincal::log::Sample;
use skincal::measurements::{MeasurementSet, TrainingExperiment, TrainingPose};
use skincal::model::sensor::{ExcitationPattern, STANDARD_GRAVITY};
use skincal::plan::{Plan, PlanConfig, PlanDof};
use skincal::predict::Predictor;
use skincal::sim::{Imperfections, SimulationConfig};

create_exception!(
    _skincal,
    SkincalError,
    PyException,
    "An error of skincal: bad input, an impossible setting, or a result that cannot be had. The \
     message names the file, field or sensor and what to do."
);

/// The library's error as a Python exception.
fn error(e: impl std::fmt::Display) -> PyErr {
    SkincalError::new_err(e.to_string())
}

/// Calls a Python progress callback, if any, from released work. An exception in it is printed
/// (as Python prints unraisable ones) and does not abort the work.
fn call(callback: &Option<Py<PyAny>>, stage: &str, done: u64, total: u64) {
    if let Some(f) = callback {
        Python::attach(|py| {
            if let Err(e) = f.call1(py, (stage, done, total)) {
                e.print(py);
            }
        });
    }
}

/// The SU frames of `robot` at `q` as 4×4 arrays.
fn su_frames_at<'py>(
    py: Python<'py>,
    robot: &skincal::model::Robot,
    q: &[f64],
) -> Vec<Bound<'py, PyArray2<f64>>> {
    let k = skincal::model::forward_kinematics(&robot.model, &robot.parameters, q);
    k.sus
        .iter()
        .map(|t| {
            let m = t.to_homogeneous();
            Array2::from_shape_fn((4, 4), |(i, j)| m[(i, j)]).into_pyarray(py)
        })
        .collect()
}

fn json<T: serde::Serialize>(value: &T) -> PyResult<String> {
    serde_json::to_string_pretty(value).map_err(error)
}

/// Writes `text` to `path` whole or not at all; refuses an existing file unless `force`.
fn write(path: PathBuf, text: String, force: bool) -> PyResult<()> {
    skincal::io::write_all(&[(path, text)], force).map_err(error)
}

/// A measurement set: the structure experiment and the training experiment of one robot.
#[pyclass(module = "skincal._skincal", name = "Measurements", frozen)]
struct Measurements {
    inner: MeasurementSet,
}

#[pymethods]
impl Measurements {
    /// Reads and checks a measurement set file (`measurements.json`).
    #[staticmethod]
    fn load(path: PathBuf) -> PyResult<Self> {
        let inner = skincal::io::read_measurements(&path).map_err(error)?;
        Ok(Self { inner })
    }

    /// Parses and checks a measurement set's JSON text.
    #[staticmethod]
    fn from_json(text: &str) -> PyResult<Self> {
        let inner = MeasurementSet::from_json(text).map_err(error)?;
        Ok(Self { inner })
    }

    /// The set's JSON text, exactly as the CLI writes it.
    fn to_json(&self) -> String {
        self.inner.to_json()
    }

    /// Writes the set (whole or not at all); an existing file is refused unless `force`.
    #[pyo3(signature = (path, force = false))]
    fn save(&self, path: PathBuf, force: bool) -> PyResult<()> {
        write(path, self.inner.to_json(), force)
    }

    #[getter]
    fn dofs(&self) -> Vec<String> {
        self.inner.dofs.clone()
    }

    #[getter]
    fn sus(&self) -> Vec<String> {
        self.inner.sus.clone()
    }

    /// The training experiment as arrays: poses (P×D, rad), static readings (P×U×3, m/s²),
    /// dynamic accelerations (P×D×U×3, m/s²; zero for a DoF not excited at a pose), the pattern
    /// `(A, f)`, and the readings' standard deviations (P×U and P×D×U, m/s²) or `None`; `None`
    /// without a training experiment.
    #[allow(clippy::type_complexity)]
    fn training<'py>(
        &self,
        py: Python<'py>,
    ) -> Option<(
        Bound<'py, PyArray2<f64>>,
        Bound<'py, PyArray3<f64>>,
        Bound<'py, PyArray4<f64>>,
        (f64, f64),
        Option<Bound<'py, PyArray2<f64>>>,
        Option<Bound<'py, PyArray3<f64>>>,
    )> {
        let t = self.inner.training.as_ref()?;
        let (p, d, u) = (t.poses.len(), self.inner.dofs.len(), self.inner.sus.len());
        let q = Array2::from_shape_fn((p, d), |(i, j)| t.poses[i].q[j]);
        let statics =
            Array3::from_shape_fn((p, u, 3), |(i, s, k)| t.poses[i].static_readings[s][k]);
        let dynamic = Array4::from_shape_fn((p, d, u, 3), |(i, j, s, k)| {
            t.poses[i]
                .dynamic
                .get(&self.inner.dofs[j])
                .map_or(0.0, |r| r[s][k])
        });
        let static_sd = t.poses.iter().all(|x| x.static_sd.is_some()).then(|| {
            Array2::from_shape_fn((p, u), |(i, s)| {
                t.poses[i].static_sd.as_ref().map_or(0.0, |v| v[s])
            })
            .into_pyarray(py)
        });
        let dynamic_sd = t.poses.iter().all(|x| !x.dynamic_sd.is_empty()).then(|| {
            Array3::from_shape_fn((p, d, u), |(i, j, s)| {
                t.poses[i]
                    .dynamic_sd
                    .get(&self.inner.dofs[j])
                    .map_or(0.0, |v| v[s])
            })
            .into_pyarray(py)
        });
        Some((
            q.into_pyarray(py),
            statics.into_pyarray(py),
            dynamic.into_pyarray(py),
            (t.pattern.amplitude, t.pattern.frequency),
            static_sd,
            dynamic_sd,
        ))
    }

    /// The structure experiment's JSON (`null` without one).
    fn structure_json(&self) -> PyResult<String> {
        json(&self.inner.structure)
    }

    /// A measurement set from arrays: see `training` for the shapes. `structure` is the JSON of a
    /// structure experiment (as `structure_json` gives), or `None`. The set is checked as a file
    /// would be.
    #[staticmethod]
    #[pyo3(signature = (dofs, sus, q, statics, dynamic, pattern, static_sd = None, dynamic_sd = None, structure = None))]
    #[allow(clippy::too_many_arguments)]
    fn from_arrays(
        dofs: Vec<String>,
        sus: Vec<String>,
        q: PyReadonlyArray2<'_, f64>,
        statics: PyReadonlyArray3<'_, f64>,
        dynamic: PyReadonlyArray4<'_, f64>,
        pattern: (f64, f64),
        static_sd: Option<PyReadonlyArray2<'_, f64>>,
        dynamic_sd: Option<PyReadonlyArray3<'_, f64>>,
        structure: Option<&str>,
    ) -> PyResult<Self> {
        let (p, d, u) = (q.shape()[0], dofs.len(), sus.len());
        let shapes: [(&str, &[usize], Vec<usize>); 3] = [
            ("q", q.shape(), vec![p, d]),
            ("statics", statics.shape(), vec![p, u, 3]),
            ("dynamic", dynamic.shape(), vec![p, d, u, 3]),
        ];
        for (name, got, want) in shapes {
            if got != want.as_slice() {
                return Err(error(format!(
                    "{name}: shape {got:?}, expected {want:?} (poses × DoFs {d} × SUs {u})"
                )));
            }
        }
        if let Some(sd) = &static_sd {
            if sd.shape() != [p, u] {
                return Err(error(format!(
                    "static_sd: shape {:?}, expected {:?}",
                    sd.shape(),
                    [p, u]
                )));
            }
        }
        if let Some(sd) = &dynamic_sd {
            if sd.shape() != [p, d, u] {
                return Err(error(format!(
                    "dynamic_sd: shape {:?}, expected {:?}",
                    sd.shape(),
                    [p, d, u]
                )));
            }
        }
        let (q, s, y) = (q.as_array(), statics.as_array(), dynamic.as_array());
        let ss = static_sd.as_ref().map(|a| a.as_array());
        let ds = dynamic_sd.as_ref().map(|a| a.as_array());
        let poses = (0..p)
            .map(|i| {
                let reading = |a: &numpy::ndarray::ArrayView3<f64>, s: usize| {
                    [a[[i, s, 0]], a[[i, s, 1]], a[[i, s, 2]]]
                };
                TrainingPose {
                    q: (0..d).map(|j| q[[i, j]]).collect(),
                    static_readings: (0..u).map(|k| reading(&s, k)).collect(),
                    dynamic: dofs
                        .iter()
                        .enumerate()
                        .map(|(j, name)| {
                            let r = (0..u)
                                .map(|k| [y[[i, j, k, 0]], y[[i, j, k, 1]], y[[i, j, k, 2]]])
                                .collect();
                            (name.clone(), r)
                        })
                        .collect(),
                    static_sd: ss.as_ref().map(|a| (0..u).map(|k| a[[i, k]]).collect()),
                    dynamic_sd: ds
                        .as_ref()
                        .map(|a| {
                            dofs.iter()
                                .enumerate()
                                .map(|(j, n)| (n.clone(), (0..u).map(|k| a[[i, j, k]]).collect()))
                                .collect()
                        })
                        .unwrap_or_default(),
                    orientation: 0,
                    extra: Default::default(),
                }
            })
            .collect();
        let mut inner = MeasurementSet::new(dofs, sus);
        if let Some(text) = structure {
            inner.structure = serde_json::from_str(text)
                .map_err(|e| error(format!("structure: not a structure experiment: {e}")))?;
        }
        inner.training = (p > 0).then(|| TrainingExperiment {
            from_motion: false,
            pattern: ExcitationPattern {
                amplitude: pattern.0,
                frequency: pattern.1,
            },
            poses,
            extra: Default::default(),
        });
        // The same checks as a file gets.
        let inner = MeasurementSet::from_json(&inner.to_json()).map_err(error)?;
        Ok(Self { inner })
    }

    fn __repr__(&self) -> String {
        let s = self.inner.summary();
        format!(
            "<MeasurementSet: {} DoFs, {} SUs, {} base orientations, {} training poses>",
            self.inner.dofs.len(),
            self.inner.sus.len(),
            s.orientations,
            s.training_poses
        )
    }
}

/// The kinematic structure that exploration found.
#[pyclass(module = "skincal._skincal", name = "NativeStructure", frozen)]
struct NativeStructure {
    inner: LibStructure,
}

#[pymethods]
impl NativeStructure {
    /// Reads and checks a structure file (`structure.json`).
    #[staticmethod]
    fn load(path: PathBuf) -> PyResult<Self> {
        let inner = skincal::io::read_structure(&path).map_err(error)?;
        Ok(Self { inner })
    }

    /// The structure's JSON text, exactly as the CLI writes it.
    fn to_json(&self) -> PyResult<String> {
        json(&self.inner)
    }

    /// Writes the structure (whole or not at all).
    #[pyo3(signature = (path, force = false))]
    fn save(&self, path: PathBuf, force: bool) -> PyResult<()> {
        write(path, json(&self.inner)?, force)
    }
}

/// A calibrated body.
#[pyclass(module = "skincal._skincal", name = "NativeModel", frozen)]
struct NativeModel {
    inner: BodyModel,
}

#[pymethods]
impl NativeModel {
    /// Reads and checks a model file (`model.json`).
    #[staticmethod]
    fn load(path: PathBuf) -> PyResult<Self> {
        let inner = skincal::io::read_model(&path).map_err(error)?;
        Ok(Self { inner })
    }

    /// The model's JSON text, exactly as `skincal calibrate` writes it.
    fn to_json(&self) -> PyResult<String> {
        json(&self.inner)
    }

    /// Writes the model (whole or not at all).
    #[pyo3(signature = (path, force = false))]
    fn save(&self, path: PathBuf, force: bool) -> PyResult<()> {
        write(path, json(&self.inner)?, force)
    }

    /// The predicted readings at `q` (N×D, rad, the model's DoFs in order): static (N×U×3) and the
    /// dynamic acceleration of pattern `(A, f)` on each DoF (N×D×U×3, zero where the DoF does not
    /// move the SU), m/s², the model's SUs in order.
    #[allow(clippy::type_complexity)]
    fn predict<'py>(
        &self,
        py: Python<'py>,
        q: PyReadonlyArray2<'_, f64>,
        pattern: (f64, f64),
    ) -> PyResult<(Bound<'py, PyArray3<f64>>, Bound<'py, PyArray4<f64>>)> {
        let predictor = Predictor::new(&self.inner).map_err(error)?;
        let (d, u) = (predictor.dofs().len(), predictor.sus().len());
        if q.shape().len() != 2 || q.shape()[1] != d {
            return Err(error(format!(
                "q: shape {:?}, expected (poses, {d}) — one angle per DoF of the model: {:?}",
                q.shape(),
                predictor.dofs()
            )));
        }
        let pattern = ExcitationPattern {
            amplitude: pattern.0,
            frequency: pattern.1,
        };
        pattern.check().map_err(error)?;
        let q = q.as_array().to_owned();
        let n = q.nrows();
        let (statics, dynamic) = py.detach(|| {
            let mut statics = Array3::zeros((n, u, 3));
            let mut dynamic = Array4::zeros((n, d, u, 3));
            for i in 0..n {
                let row: Vec<f64> = q.row(i).to_vec();
                let r = predictor.readings(&row, &pattern);
                for (s, v) in r.statics.iter().enumerate() {
                    for k in 0..3 {
                        statics[[i, s, k]] = v[k];
                    }
                }
                for (j, per) in r.dynamic.iter().enumerate() {
                    for (s, v) in per {
                        for k in 0..3 {
                            dynamic[[i, j, *s, k]] = v[k];
                        }
                    }
                }
            }
            (statics, dynamic)
        });
        Ok((statics.into_pyarray(py), dynamic.into_pyarray(py)))
    }

    /// Every SU's pose (4×4, m) in the body frame at `q` (rad per model DoF), in the model's SU
    /// order.
    fn su_frames<'py>(
        &self,
        py: Python<'py>,
        q: Vec<f64>,
    ) -> PyResult<Vec<Bound<'py, PyArray2<f64>>>> {
        let robot = self.inner.check().map_err(error)?;
        if q.len() != robot.model.dofs().len() {
            return Err(error(format!(
                "pose: {} angles, expected one per DoF of the model ({})",
                q.len(),
                robot.model.dofs().len()
            )));
        }
        Ok(su_frames_at(py, &robot, &q))
    }

    /// The model's DoFs and SUs, in the order of `predict`'s arrays.
    fn names(&self) -> PyResult<(Vec<String>, Vec<String>)> {
        let predictor = Predictor::new(&self.inner).map_err(error)?;
        Ok((predictor.dofs(), predictor.sus()))
    }

    /// Predicts the training experiment of `other` and compares: the validation's JSON.
    fn validate(&self, py: Python<'_>, other: &Measurements) -> PyResult<String> {
        let v = py
            .detach(|| skincal::predict::validate(&self.inner, &other.inner, "python"))
            .map_err(error)?;
        json(&v)
    }

    /// The calibrated kinematics as URDF text (one link per segment, one fixed joint per SU).
    fn to_urdf(&self) -> PyResult<String> {
        let robot = self.inner.check().map_err(error)?;
        skincal::model::urdf::to_urdf(&robot).map_err(error)
    }
}

/// Simulates a robot: a built-in name, a `.toml` description or a URDF. Returns the measurement
/// set and the truth's JSON.
#[pyfunction]
#[pyo3(signature = (robot, poses = 20, noise = 0.01, seed = 1, structure = true, training = true, tilted = true, pose_seed = None))]
#[allow(clippy::too_many_arguments)]
fn simulate(
    py: Python<'_>,
    robot: &str,
    poses: usize,
    noise: f64,
    seed: u64,
    structure: bool,
    training: bool,
    tilted: bool,
    pose_seed: Option<u64>,
) -> PyResult<(Measurements, String)> {
    let robot = skincal::io::load_robot(
        robot,
        skincal::io::SuPlacement {
            per_link: None,
            seed,
        },
    )
    .map_err(error)?;
    let config = SimulationConfig {
        structure,
        training,
        poses,
        tilted_orientation: tilted,
        imperfections: Imperfections {
            uniform_noise: noise,
            ..Imperfections::none()
        },
        seed,
        pose_seed,
        ..SimulationConfig::default()
    };
    let sim = py
        .detach(|| skincal::sim::simulate(&robot, &config))
        .map_err(error)?;
    Ok((
        Measurements {
            inner: sim.measurements,
        },
        json(&sim.truth)?,
    ))
}

/// Structural exploration with the default settings.
#[pyfunction]
fn explore(py: Python<'_>, measurements: &Measurements) -> PyResult<NativeStructure> {
    let inner = py
        .detach(|| skincal::explore::explore(&measurements.inner, &ExploreConfig::default()))
        .map_err(error)?;
    Ok(NativeStructure { inner })
}

/// Kinematic estimation (maximum likelihood) of every limb; `noise` is the uniform noise in g
/// that weights every reading (default: each reading's own standard deviation where the set has
/// them, else 0.01 g), as `skincal calibrate --noise`. `progress(limb, done, total)` is called as
/// each limb is calibrated.
#[pyfunction]
#[pyo3(signature = (measurements, structure = None, noise = None, progress = None))]
fn calibrate(
    py: Python<'_>,
    measurements: &Measurements,
    structure: Option<&NativeStructure>,
    noise: Option<f64>,
    progress: Option<Py<PyAny>>,
) -> PyResult<NativeModel> {
    let config = MlConfig {
        noise_sd: noise.unwrap_or(0.01) * STANDARD_GRAVITY / 3f64.sqrt(),
        reading_sd: noise.is_none(),
        ..MlConfig::default()
    };
    let structure = structure_for(py, measurements, structure)?;
    let inner = py
        .detach(|| {
            skincal::estimate::body::calibrate_body_reporting(
                &measurements.inner,
                structure.as_deref(),
                &config,
                None,
                &[],
                &mut |limb, done, total| call(&progress, limb, done as u64, total as u64),
            )
        })
        .map_err(error)?;
    Ok(NativeModel { inner })
}

/// The structure a calibration uses: the one given, else the set's structure experiment explored
/// with the default settings (the interpreter released), else none.
fn structure_for<'a>(
    py: Python<'_>,
    measurements: &Measurements,
    structure: Option<&'a NativeStructure>,
) -> PyResult<Option<std::borrow::Cow<'a, skincal::explore::Structure>>> {
    use std::borrow::Cow;
    Ok(match structure {
        Some(s) => Some(Cow::Borrowed(&s.inner)),
        None if measurements.inner.structure.is_some() => Some(Cow::Owned(
            py.detach(|| skincal::explore::explore(&measurements.inner, &ExploreConfig::default()))
                .map_err(error)?,
        )),
        None => None,
    })
}

/// Kinematic estimation by the paper's method (progressive NLopt MLSL-LDS + Nelder–Mead on e_T)
/// of every serial chain, as `skincal calibrate --method paper`: the structure given, else the
/// set's own explored, else its DoFs in listed order. `progress(limb, done, total)` is called as
/// each chain starts and after the last. Returns what `model-paper.json` holds.
#[pyfunction]
#[pyo3(signature = (measurements, structure = None, seed = 1, e_stop = 0.1, max_evaluations = 100_000, progress = None))]
fn calibrate_paper(
    py: Python<'_>,
    measurements: &Measurements,
    structure: Option<&NativeStructure>,
    seed: u64,
    e_stop: f64,
    max_evaluations: u32,
    progress: Option<Py<PyAny>>,
) -> PyResult<NativePaperModel> {
    use skincal::estimate::paper;
    let config = paper::PaperConfig {
        seed,
        e_stop,
        max_evaluations,
        ..paper::PaperConfig::default()
    };
    let structure = structure_for(py, measurements, structure)?;
    let model = py
        .detach(|| {
            let structure = structure.as_deref();
            if structure.is_some_and(|s| !s.complete) {
                return Err(
                    "the explored structure is incomplete (see skincal.explore): fix the \
                     structure experiment before calibrating"
                        .to_string(),
                );
            }
            let chains =
                paper::chains(&measurements.inner, structure, None).map_err(|e| e.to_string())?;
            paper::estimate_chains(
                &measurements.inner,
                &chains,
                &config,
                &mut |limb, done, total| call(&progress, limb, done as u64, total as u64),
            )
            .map_err(|e| e.to_string())
        })
        .map_err(error)?;
    Ok(NativePaperModel { inner: model })
}

/// The paper's estimate of every chain (what `model-paper.json` holds).
#[pyclass(module = "skincal._skincal", name = "NativePaperModel", frozen)]
struct NativePaperModel {
    inner: skincal::estimate::paper::PaperModel,
}

#[pymethods]
impl NativePaperModel {
    fn to_json(&self) -> PyResult<String> {
        json(&self.inner)
    }

    fn save(&self, path: PathBuf, force: bool) -> PyResult<()> {
        write(path, json(&self.inner)?, force)
    }

    /// The SU frames (4×4, m, in the chain's base frame) of chain `limb` at `q` (one angle per
    /// DoF of the chain).
    fn su_frames<'py>(
        &self,
        py: Python<'py>,
        limb: usize,
        q: Vec<f64>,
    ) -> PyResult<Vec<Bound<'py, PyArray2<f64>>>> {
        let estimate = self.inner.limbs.get(limb).ok_or_else(|| {
            error(format!(
                "limb {limb}: the model has {}",
                self.inner.limbs.len()
            ))
        })?;
        let robot = estimate.robot();
        if q.len() != robot.model.dofs().len() || q.iter().any(|v| !v.is_finite()) {
            return Err(pyo3::exceptions::PyValueError::new_err(format!(
                "pose: {} finite angles expected, one per DoF of limb `{}`",
                robot.model.dofs().len(),
                estimate.chain.name
            )));
        }
        Ok(su_frames_at(py, &robot, &q))
    }
}

/// Ingests robot logs (MCAP, rosbag2 directories, ROS 1 bags, CSV directories). `plan` is a plan
/// file whose pattern and still periods apply; `pattern` `(A, f)` the nominal pattern instead.
/// `progress(stage, done, total)` is called as the logs are read. Returns the measurement set and
/// the report's JSON.
#[pyfunction]
#[pyo3(signature = (logs, plan = None, pattern = None, progress = None))]
fn ingest(
    py: Python<'_>,
    logs: Vec<PathBuf>,
    plan: Option<PathBuf>,
    pattern: Option<(f64, f64)>,
    progress: Option<Py<PyAny>>,
) -> PyResult<(Measurements, String)> {
    use skincal::ingest::IngestConfig;
    let mut config = IngestConfig::default();
    if let Some(path) = &plan {
        let text =
            std::fs::read_to_string(path).map_err(|e| error(format!("{}: {e}", path.display())))?;
        let plan = Plan::from_json(&text).map_err(|e| error(format!("{}: {e}", path.display())))?;
        config = config.with_plan(&plan);
    }
    if let Some((amplitude, frequency)) = pattern {
        config.pattern = Some(ExcitationPattern {
            amplitude,
            frequency,
        });
    }
    let ingested = py
        .detach(|| {
            let mut report =
                |stage: &str, done: u64, total: u64| call(&progress, stage, done, total);
            let mut ingested = skincal::ingest::ingest(&logs, &config, &mut report)?;
            // What the structure moves accelerated, from the motion record, as `skincal ingest`.
            skincal::ingest::motion::record_of(&mut ingested, &config, &mut report)?;
            Ok::<_, skincal::ingest::IngestError>(ingested)
        })
        .map_err(error)?;
    Ok((
        Measurements {
            inner: ingested.measurements,
        },
        json(&ingested.report)?,
    ))
}

/// The exploration program of a robot: `short` (the default, with its forecast; as many poses as
/// `accuracy` m/s² needs when given or when `poses` is not) or `paper`. Returns the plan's JSON
/// (as `skincal plan` writes `plan.json`).
#[pyfunction]
#[pyo3(signature = (robot, protocol = "short", poses = None, accuracy = None, seed = 1))]
fn plan(
    py: Python<'_>,
    robot: &str,
    protocol: &str,
    poses: Option<usize>,
    accuracy: Option<f64>,
    seed: u64,
) -> PyResult<String> {
    let robot =
        skincal::io::load_robot(robot, skincal::io::SuPlacement::default()).map_err(error)?;
    let base = match protocol {
        "short" => PlanConfig::short(),
        "paper" => PlanConfig::default(),
        other => return Err(error(format!("protocol `{other}`: use `short` or `paper`"))),
    };
    let config = PlanConfig {
        poses: poses.unwrap_or(base.poses),
        seed,
        ..base
    };
    let target = accuracy
        .or((protocol == "short" && poses.is_none()).then_some(skincal::design::SHORT_ACCURACY));
    let dofs = PlanDof::from_robot(&robot);
    let plan = py
        .detach(|| -> Result<Plan, String> {
            match target {
                Some(t) => {
                    skincal::design::poses_for(&robot, &dofs, &config, (t, None), None, &mut |_| {})
                        .map(|(plan, _)| plan)
                        .map_err(|e| e.to_string())
                }
                None => {
                    let mut plan = Plan::new(dofs.clone(), &config).map_err(|e| e.to_string())?;
                    // A description without SUs has no forecast; the plan stands without one.
                    let _ = skincal::design::forecast_plan(&robot, &mut plan, None);
                    Ok(plan)
                }
            }
        })
        .map_err(error)?;
    json(&plan)
}

/// The median wall time of `repeats` library calibrations of `measurements` with `structure`
/// (default settings), s, timed in Rust: the reference for the Python layer's overhead
/// (`benches/overhead.py`).
#[pyfunction]
fn bench_calibrate(
    py: Python<'_>,
    measurements: &Measurements,
    structure: &NativeStructure,
    repeats: usize,
) -> PyResult<f64> {
    let mut times = py
        .detach(|| {
            (0..repeats.max(1))
                .map(|_| {
                    let started = std::time::Instant::now();
                    calibrate_body(
                        &measurements.inner,
                        Some(&structure.inner),
                        &MlConfig::default(),
                        None,
                    )
                    .map(|_| started.elapsed().as_secs_f64())
                })
                .collect::<Result<Vec<f64>, _>>()
        })
        .map_err(error)?;
    times.sort_by(f64::total_cmp);
    Ok(times[times.len() / 2])
}

/// Checks `model` against logs of any motion (or a `motion.json`): the report's JSON, as
/// `skincal check --json` gives it under `report`.
#[pyfunction]
fn check(py: Python<'_>, model: &NativeModel, logs: Vec<PathBuf>) -> PyResult<String> {
    let report = py
        .detach(|| -> Result<_, String> {
            let record = match logs.as_slice() {
                [one] if one.extension().is_some_and(|e| e == "json") => {
                    skincal::io::read_motion(one).map_err(|e| e.to_string())?
                }
                _ => {
                    let robot = model.inner.check()?;
                    skincal::ingest::motion::motion_record(
                        &logs,
                        &robot.model.dof_names(),
                        &robot.model.su_names(),
                        &skincal::ingest::IngestConfig::default(),
                        &mut |_, _, _| {},
                    )
                    .map_err(|e| e.to_string())?
                }
            };
            skincal::check::check_skin(&model.inner, &record, &CheckConfig::default())
                .map_err(|e| e.to_string())
        })
        .map_err(error)?;
    json(&report)
}

/// A check fed joint states and skin samples as they come.
#[pyclass(module = "skincal._skincal", name = "NativeLiveCheck")]
struct NativeLiveCheck {
    inner: skincal::check::LiveCheck,
}

#[pymethods]
impl NativeLiveCheck {
    #[new]
    fn new(model: &NativeModel) -> PyResult<Self> {
        let inner =
            skincal::check::LiveCheck::new(&model.inner, &CheckConfig::default()).map_err(error)?;
        Ok(Self { inner })
    }

    /// One joint state: stamp (s), names and positions (rad).
    fn joints(&mut self, stamp: f64, names: Vec<String>, positions: Vec<f64>) -> PyResult<()> {
        if names.len() != positions.len() {
            return Err(error(format!(
                "joint state at {stamp} s: {} names but {} positions",
                names.len(),
                positions.len()
            )));
        }
        self.inner.push(&Sample::Joints {
            stamp,
            names: &names,
            positions: &positions,
        });
        Ok(())
    }

    /// Skin samples: stamps (N, s), the SUs' names (N) and their specific forces (N×3, m/s²).
    fn imu(
        &mut self,
        stamps: Vec<f64>,
        sus: Vec<String>,
        accelerations: PyReadonlyArray2<'_, f64>,
    ) -> PyResult<()> {
        let a = accelerations.as_array();
        if a.shape() != [stamps.len(), 3] || sus.len() != stamps.len() {
            return Err(error(format!(
                "skin samples: {} stamps, {} SU names and accelerations of shape {:?}; give N, N and N×3",
                stamps.len(),
                sus.len(),
                a.shape()
            )));
        }
        for (i, (stamp, su)) in stamps.iter().zip(&sus).enumerate() {
            self.inner.push(&Sample::Imu {
                stamp: *stamp,
                frame_id: su,
                acceleration: [a[[i, 0]], a[[i, 1]], a[[i, 2]]],
            });
        }
        Ok(())
    }

    /// The report so far as JSON (`None` before the warm-up's seconds of motion have come).
    fn report(&mut self, py: Python<'_>) -> PyResult<Option<String>> {
        let inner = &mut self.inner;
        py.detach(|| inner.report()).map(|r| json(&r)).transpose()
    }

    /// What it holds now: joint states and skin blocks of the stream, blocks kept.
    fn held(&mut self) -> (usize, usize, usize) {
        self.inner.held()
    }
}

/// The built-in robots: name → their description (TOML).
#[pyfunction]
fn robots() -> BTreeMap<String, String> {
    skincal::model::presets::PRESETS
        .iter()
        .map(|p| (p.name.to_string(), p.toml.to_string()))
        .collect()
}

#[pymodule]
fn _skincal(m: &Bound<'_, PyModule>) -> PyResult<()> {
    m.add("__version__", env!("CARGO_PKG_VERSION"))?;
    m.add("SkincalError", m.py().get_type::<SkincalError>())?;
    m.add_class::<Measurements>()?;
    m.add_class::<NativeStructure>()?;
    m.add_class::<NativeModel>()?;
    m.add_class::<NativePaperModel>()?;
    m.add_class::<NativeLiveCheck>()?;
    m.add_function(wrap_pyfunction!(check, m)?)?;
    m.add_function(wrap_pyfunction!(simulate, m)?)?;
    m.add_function(wrap_pyfunction!(explore, m)?)?;
    m.add_function(wrap_pyfunction!(calibrate, m)?)?;
    m.add_function(wrap_pyfunction!(calibrate_paper, m)?)?;
    m.add_function(wrap_pyfunction!(ingest, m)?)?;
    m.add_function(wrap_pyfunction!(plan, m)?)?;
    m.add_function(wrap_pyfunction!(robots, m)?)?;
    m.add_function(wrap_pyfunction!(bench_calibrate, m)?)?;
    Ok(())
}
