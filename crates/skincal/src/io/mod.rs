//! Files: robot descriptions, measurement sets and ground truth. The only module that touches the
//! file system. Outputs are written whole or not at all: every file goes to a temporary name in
//! its final directory first and is renamed into place only when all of them were written.

use std::fs;
use std::path::{Path, PathBuf};

use crate::log::Staged;
use crate::measurements::{MeasurementError, MeasurementSet};
use crate::model::description::{with_random_sus, DescriptionError, RobotFile};
use crate::model::presets;
use crate::model::urdf::{from_urdf, UrdfSus};
use crate::model::Robot;
use crate::sim::Truth;

mod body;
mod predictions;

pub use body::{load_body, resolve_mesh};
pub use predictions::{stream_predictions, write_predictions, Progress as PredictionProgress};

/// Errors reading or writing files; every variant names the file.
#[derive(Debug, thiserror::Error)]
#[non_exhaustive]
pub enum IoError {
    /// A file could not be read.
    #[error("cannot read {path}: {source}")]
    Read {
        /// The file.
        path: PathBuf,
        /// Why.
        source: std::io::Error,
    },
    /// A file could not be written.
    #[error("cannot write {path}: {source}")]
    Write {
        /// The file.
        path: PathBuf,
        /// Why.
        source: std::io::Error,
    },
    /// An output exists and overwriting was not asked for.
    #[error(
        "{path} already exists: choose another output directory or pass --force to overwrite it"
    )]
    Exists {
        /// The file.
        path: PathBuf,
    },
    /// A robot description is invalid.
    #[error("{path}: {source}")]
    Description {
        /// The file.
        path: PathBuf,
        /// What is wrong.
        source: DescriptionError,
    },
    /// A measurement set is invalid.
    #[error("{path}: {source}")]
    Measurements {
        /// The file.
        path: PathBuf,
        /// What is wrong.
        source: MeasurementError,
    },
    /// A JSON file does not parse.
    #[error("{path}: {message}")]
    Json {
        /// The file.
        path: PathBuf,
        /// What the parser said.
        message: String,
    },
    /// A URDF's collision geometry or an SRDF cannot be used.
    #[error("{path}: {source}")]
    Collision {
        /// The URDF or SRDF.
        path: PathBuf,
        /// What is wrong.
        source: crate::collision::CollisionError,
    },
    /// A URDF cannot be aligned with the model.
    #[error("{path}: {source}")]
    Align {
        /// The URDF.
        path: PathBuf,
        /// What is wrong.
        source: crate::align::AlignError,
    },
    /// Neither a built-in robot nor a robot file.
    #[error("unknown robot `{name}`: give a built-in robot ({known}) or a .toml or .urdf file")]
    UnknownRobot {
        /// What was given.
        name: String,
        /// The built-in robots.
        known: String,
    },
}

/// How SUs are placed when a robot is loaded.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub struct SuPlacement {
    /// Replace the described SUs by this many random ones per segment (per link for a URDF).
    pub per_link: Option<usize>,
    /// Seed of the random placement.
    pub seed: u64,
}

/// Whether the robot `spec` names (as [`load_robot`] takes it) places SUs of its own: a
/// built-in robot and a `.toml` description do; a `.urdf` file has none (those [`load_robot`]
/// gives it are placed at random and named after its links).
pub fn places_its_sus(spec: &str) -> bool {
    Path::new(spec)
        .extension()
        .and_then(|e| e.to_str())
        .is_none_or(|e| !e.eq_ignore_ascii_case("urdf"))
}

/// Loads a robot: a built-in name, a `.toml` description or a `.urdf` file.
///
/// A URDF has no SUs of its own: unless `sus.per_link` says otherwise, one random SU is placed on
/// every link.
pub fn load_robot(spec: &str, sus: SuPlacement) -> Result<Robot, IoError> {
    let path = Path::new(spec);
    let ext = path
        .extension()
        .and_then(|e| e.to_str())
        .map(str::to_ascii_lowercase);
    let description = |source| IoError::Description {
        path: path.to_path_buf(),
        source,
    };
    match ext.as_deref() {
        Some("urdf") => {
            let text = read(path)?;
            let per_link = sus.per_link.unwrap_or(1);
            from_urdf(
                &text,
                UrdfSus::RandomPerLink {
                    per_link,
                    seed: sus.seed,
                },
            )
            .map_err(description)
        }
        Some("toml") => {
            let file = RobotFile::from_toml(&read(path)?).map_err(description)?;
            match &file.urdf {
                Some(urdf) => {
                    let urdf_path = path.parent().unwrap_or(Path::new(".")).join(urdf);
                    let text = read(&urdf_path)?;
                    let source = match sus.per_link {
                        Some(per_link) => UrdfSus::RandomPerLink {
                            per_link,
                            seed: sus.seed,
                        },
                        None => UrdfSus::Listed(&file.sus),
                    };
                    from_urdf(&text, source).map_err(|source| IoError::Description {
                        path: urdf_path,
                        source,
                    })
                }
                None => {
                    let robot = file.build().map_err(description)?;
                    randomise(robot, sus).map_err(description)
                }
            }
        }
        _ => match presets::find(spec) {
            Some(preset) => {
                let robot = preset.robot().map_err(description)?;
                randomise(robot, sus).map_err(description)
            }
            None => Err(IoError::UnknownRobot {
                name: spec.to_string(),
                known: presets::PRESETS
                    .iter()
                    .map(|p| p.name)
                    .collect::<Vec<_>>()
                    .join(", "),
            }),
        },
    }
}

fn randomise(robot: Robot, sus: SuPlacement) -> Result<Robot, DescriptionError> {
    match sus.per_link {
        Some(k) => with_random_sus(&robot, k, sus.seed),
        None => Ok(robot),
    }
}

fn read(path: &Path) -> Result<String, IoError> {
    fs::read_to_string(path).map_err(|source| IoError::Read {
        path: path.to_path_buf(),
        source,
    })
}

/// The URDF file a `--robot` argument describes the robot with: the file itself, or the `urdf`
/// a TOML description names; `None` for built-in robots and TOML descriptions of their own.
pub fn urdf_of(spec: &str) -> Result<Option<PathBuf>, IoError> {
    let path = Path::new(spec);
    let ext = path
        .extension()
        .and_then(|e| e.to_str())
        .map(str::to_ascii_lowercase);
    match ext.as_deref() {
        Some("urdf") => Ok(Some(path.to_path_buf())),
        Some("toml") => {
            let file =
                RobotFile::from_toml(&read(path)?).map_err(|source| IoError::Description {
                    path: path.to_path_buf(),
                    source,
                })?;
            Ok(file
                .urdf
                .map(|urdf| path.parent().unwrap_or(Path::new(".")).join(urdf)))
        }
        _ => Ok(None),
    }
}

/// Reads and validates a measurement set.
pub fn read_measurements(path: &Path) -> Result<MeasurementSet, IoError> {
    MeasurementSet::from_json(&read(path)?).map_err(|source| IoError::Measurements {
        path: path.to_path_buf(),
        source,
    })
}

/// Reads the robot's own URDF and aligns `model` with it (see [`crate::align`]); returns the text
/// too, for merging.
pub fn read_urdf_alignment(
    model: &crate::estimate::body::BodyModel,
    path: &Path,
) -> Result<(String, crate::align::Alignment), IoError> {
    let text = read(path)?;
    let alignment = crate::align::align(model, &text).map_err(|source| IoError::Align {
        path: path.to_path_buf(),
        source,
    })?;
    Ok((text, alignment))
}

/// Reads a ground-truth file.
pub fn read_truth(path: &Path) -> Result<Truth, IoError> {
    crate::json::parse(&read(path)?, "a ground truth").map_err(|message| IoError::Json {
        path: path.to_path_buf(),
        message,
    })
}

/// Reads the true robot from a ground-truth file: `truth.json` from `simulate`, or the truth that
/// `record` writes beside a log (`*.truth.json`). Both hold the robot under `robot`.
pub fn read_true_robot(path: &Path) -> Result<Robot, IoError> {
    #[derive(serde::Deserialize)]
    struct AnyTruth {
        format: String,
        robot: RobotFile,
    }
    let json = |message| IoError::Json {
        path: path.to_path_buf(),
        message,
    };
    let truth: AnyTruth = crate::json::parse(&read(path)?, "a ground truth").map_err(json)?;
    if !matches!(truth.format.as_str(), "skincal-truth" | "skincal-log-truth") {
        return Err(json(format!(
            "`format` is `{}`: expected a ground truth (truth.json from skincal simulate, or a log's from skincal record)",
            truth.format
        )));
    }
    truth.robot.build().map_err(|source| IoError::Description {
        path: path.to_path_buf(),
        source,
    })
}

/// Writes every `(path, contents)` pair whole or not at all. Without `force`, fails before writing
/// anything if one of the paths exists. Creates missing directories.
pub fn write_all<C: AsRef<[u8]>>(files: &[(PathBuf, C)], force: bool) -> Result<(), IoError> {
    let writers: Vec<(PathBuf, Box<Writer<'_>>)> = files
        .iter()
        .map(|(path, contents)| {
            let write: Box<Writer<'_>> = Box::new(move |w| w.write_all(contents.as_ref()));
            (path.clone(), write)
        })
        .collect();
    write_all_with(&writers, force)
}

/// What writes one file's contents ([`write_all_with`]).
pub type Writer<'a> = dyn Fn(&mut dyn std::io::Write) -> std::io::Result<()> + 'a;

/// [`write_all`] with each file's contents written by its own function straight into the file
/// (a long log's motion record serialised as it goes, never held as one string).
pub fn write_all_with(files: &[(PathBuf, Box<Writer<'_>>)], force: bool) -> Result<(), IoError> {
    if !force {
        if let Some((path, _)) = files.iter().find(|(p, _)| p.exists()) {
            return Err(IoError::Exists { path: path.clone() });
        }
    }
    let as_io = |e| staging_error(e, Path::new(""));
    // Staged files are removed again if anything fails before every one is written.
    let mut staged = Vec::with_capacity(files.len());
    for (path, write) in files {
        let (stage, file) = Staged::create(path, true).map_err(as_io)?;
        let mut file = std::io::BufWriter::new(file);
        write(&mut file)
            .and_then(|()| std::io::Write::flush(&mut file))
            .map_err(|source| IoError::Write {
                path: stage.tmp().to_path_buf(),
                source,
            })?;
        staged.push(stage);
    }
    for stage in &mut staged {
        stage.commit().map_err(as_io)?;
    }
    Ok(())
}

/// A staging failure as an [`IoError`]; `path` names the output when the error does not.
fn staging_error(e: crate::log::LogError, path: &Path) -> IoError {
    match e {
        crate::log::LogError::Exists { path } => IoError::Exists { path },
        crate::log::LogError::Io { path, source } => IoError::Write { path, source },
        other => IoError::Write {
            path: path.to_path_buf(),
            source: std::io::Error::other(other.to_string()),
        },
    }
}

/// Reads a structure written by exploration (`structure.json`).
pub fn read_structure(path: &Path) -> Result<crate::explore::Structure, IoError> {
    let json = |message| IoError::Json {
        path: path.to_path_buf(),
        message,
    };
    let structure: crate::explore::Structure =
        crate::json::parse(&read(path)?, "a structure").map_err(json)?;
    structure.check().map_err(json)?;
    Ok(structure)
}

/// Reads a motion record (`motion.json`, written by `skincal ingest`) and checks it.
pub fn read_motion(path: &Path) -> Result<crate::motion::MotionRecord, IoError> {
    let json = |message: String| IoError::Json {
        path: path.to_path_buf(),
        message,
    };
    let file = fs::File::open(path).map_err(|source| IoError::Read {
        path: path.to_path_buf(),
        source,
    })?;
    let record: crate::motion::MotionRecord =
        crate::json::parse_reader(file, "a motion record", || fs::read_to_string(path))
            .map_err(json)?;
    record.check().map_err(json)?;
    Ok(record)
}

/// Reads a calibrated model (`model.json`) and checks that it is one.
pub fn read_model(path: &Path) -> Result<crate::estimate::body::BodyModel, IoError> {
    let json = |message: String| IoError::Json {
        path: path.to_path_buf(),
        message,
    };
    let model: crate::estimate::body::BodyModel =
        crate::json::parse(&read(path)?, "a calibrated model").map_err(json)?;
    model.check().map_err(json)?;
    Ok(model)
}

/// What a result directory holds for a report: `measurements.json`, `structure.json`,
/// `model.json`, `model-paper.json`, `ingest-report.json`, `truth.json` (each when present); with
/// `validate`, the model checked against the measurement set in that directory (or file); with
/// `urdf`, the robot's own URDF checked against the model. Present files that cannot be read are
/// errors.
pub fn read_report_inputs(
    dir: &Path,
    validate: Option<&Path>,
    urdf: Option<&Path>,
) -> Result<crate::html::ReportInputs, IoError> {
    let present = |name: &str| Some(dir.join(name)).filter(|p| p.is_file());
    let measurements = present("measurements.json")
        .map(|p| read_measurements(&p))
        .transpose()?;
    let structure = present("structure.json")
        .map(|p| read_structure(&p))
        .transpose()?;
    let model = present("model.json").map(|p| read_model(&p)).transpose()?;
    let ingest = present("ingest-report.json")
        .map(|p| {
            crate::json::parse(&read(&p)?, "an ingest report").map_err(|message| IoError::Json {
                path: p.clone(),
                message,
            })
        })
        .transpose()?;
    let truth = present("truth.json")
        .map(|p| read_true_robot(&p))
        .transpose()?;
    let paper = match present("model-paper.json") {
        Some(p) => {
            #[derive(serde::Deserialize)]
            struct PaperModel {
                limbs: Vec<crate::estimate::paper::PaperChainEstimate>,
            }
            let parsed: PaperModel = crate::json::parse(&read(&p)?, "the paper's method's model")
                .map_err(|message| IoError::Json {
                path: p.clone(),
                message,
            })?;
            parsed.limbs
        }
        None => Vec::new(),
    };
    let validation = match (validate, &model) {
        (Some(other), Some(model)) => {
            let file = if other.is_dir() {
                other.join("measurements.json")
            } else {
                other.to_path_buf()
            };
            let set = read_measurements(&file)?;
            let name = file.display().to_string();
            let check =
                crate::predict::validate(model, &set, &name).map_err(|e| IoError::Json {
                    path: file.clone(),
                    message: format!("cannot check the model against it: {e}"),
                })?;
            Some((check, name))
        }
        _ => None,
    };
    let (urdf_check, urdf_su_frames) = match (urdf, &model) {
        (Some(path), Some(model)) => {
            let (_, alignment) = read_urdf_alignment(model, path)?;
            let frames = alignment.su_frames();
            (Some((alignment.check, path.display().to_string())), frames)
        }
        _ => (None, Default::default()),
    };
    Ok(crate::html::ReportInputs {
        urdf_check,
        urdf_su_frames,
        check: None,
        title: dir.file_name().map_or_else(
            || dir.display().to_string(),
            |n| n.to_string_lossy().into_owned(),
        ),
        measurements,
        structure,
        model,
        ingest,
        truth,
        paper,
        validation,
    })
}

/// Reads and checks an exploration plan (`plan.json`).
pub fn read_plan(path: &Path) -> Result<crate::plan::Plan, IoError> {
    crate::plan::Plan::from_json(&read(path)?).map_err(|e| IoError::Json {
        path: path.to_path_buf(),
        message: e.to_string(),
    })
}

/// Reads a pose table: CSV (header of DoF names, one pose per row) or, for `.json`, `{"dofs",
/// "poses"}`.
pub fn read_poses(path: &Path) -> Result<crate::predict::PoseTable, IoError> {
    let text = read(path)?;
    let is_json = path
        .extension()
        .is_some_and(|e| e.eq_ignore_ascii_case("json"));
    let table = if is_json {
        crate::predict::PoseTable::from_json(&text)
    } else {
        crate::predict::PoseTable::from_csv(&text)
    };
    table.map_err(|e| IoError::Json {
        path: path.to_path_buf(),
        message: e.to_string(),
    })
}
