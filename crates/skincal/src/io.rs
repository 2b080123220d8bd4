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

/// Reads and validates a measurement set.
pub fn read_measurements(path: &Path) -> Result<MeasurementSet, IoError> {
    MeasurementSet::from_json(&read(path)?).map_err(|source| IoError::Measurements {
        path: path.to_path_buf(),
        source,
    })
}

/// Reads a ground-truth file.
pub fn read_truth(path: &Path) -> Result<Truth, IoError> {
    crate::json::parse(&read(path)?, "a ground truth").map_err(|message| IoError::Json {
        path: path.to_path_buf(),
        message,
    })
}

/// Writes every `(path, contents)` pair whole or not at all. Without `force`, fails before writing
/// anything if one of the paths exists. Creates missing directories.
pub fn write_all(files: &[(PathBuf, String)], force: bool) -> Result<(), IoError> {
    if !force {
        if let Some((path, _)) = files.iter().find(|(p, _)| p.exists()) {
            return Err(IoError::Exists { path: path.clone() });
        }
    }
    let as_io = |e: crate::log::LogError| match e {
        crate::log::LogError::Exists { path } => IoError::Exists { path },
        crate::log::LogError::Io { path, source } => IoError::Write { path, source },
        other => IoError::Write {
            path: PathBuf::new(),
            source: std::io::Error::other(other.to_string()),
        },
    };
    // Staged files are removed again if anything fails before every one is written.
    let mut staged = Vec::with_capacity(files.len());
    for (path, contents) in files {
        let (stage, mut file) = Staged::create(path, true).map_err(as_io)?;
        std::io::Write::write_all(&mut file, contents.as_bytes()).map_err(|source| {
            IoError::Write {
                path: stage.tmp().to_path_buf(),
                source,
            }
        })?;
        staged.push(stage);
    }
    for stage in &mut staged {
        stage.commit().map_err(as_io)?;
    }
    Ok(())
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

/// [`stream_predictions`] into the file `out`, written whole or not at all; refuses to overwrite
/// it without `force`. Returns the number of poses.
pub fn write_predictions(
    predictor: &crate::predict::Predictor,
    poses: &Path,
    pattern: &crate::model::sensor::ExcitationPattern,
    out: &Path,
    force: bool,
) -> Result<usize, IoError> {
    let as_io = |e: crate::log::LogError| match e {
        crate::log::LogError::Exists { path } => IoError::Exists { path },
        other => IoError::Write {
            path: out.to_path_buf(),
            source: std::io::Error::other(other.to_string()),
        },
    };
    let (mut stage, mut file) = Staged::create(out, force).map_err(as_io)?;
    let beside = out
        .parent()
        .filter(|p| !p.as_os_str().is_empty())
        .unwrap_or(Path::new("."));
    let count = stream_predictions(predictor, poses, pattern, beside, &mut file, out)?;
    stage.commit().map_err(as_io)?;
    Ok(count)
}

/// Streams the predictions of `predictor` for every pose of the pose file `poses` to `out` (named
/// `out_path` in errors), as the JSON of [`crate::predict::Predictor::predict`], compact. A CSV
/// pose file is read a row at a time and every section of the output is spilled to a temporary
/// file in `spill_in`, then copied out in order: memory does not grow with the number of poses.
/// Returns the number of poses.
pub fn stream_predictions(
    predictor: &crate::predict::Predictor,
    poses: &Path,
    pattern: &crate::model::sensor::ExcitationPattern,
    spill_in: &Path,
    out: &mut dyn std::io::Write,
    out_path: &Path,
) -> Result<usize, IoError> {
    use std::io::{BufRead, Write};
    let pose_error = |message: String| IoError::Json {
        path: poses.to_path_buf(),
        message,
    };
    let written = |path: &Path| {
        let path = path.to_path_buf();
        move |source| IoError::Write { path, source }
    };
    let spill = SpillDir::create(spill_in).map_err(written(spill_in))?;
    // Sections by (kind, SU, DoF): poses (0), static per SU (1), dynamic per SU and DoF (2).
    let mut sections: std::collections::BTreeMap<(u8, usize, usize), Section> = Default::default();
    let section = |key: (u8, usize, usize),
                   sections: &mut std::collections::BTreeMap<(u8, usize, usize), Section>|
     -> Result<(), IoError> {
        if !sections.contains_key(&key) {
            let path = spill.0.join(sections.len().to_string());
            let file = fs::File::create(&path).map_err(written(&path))?;
            sections.insert(key, Section::new(path, file));
        }
        Ok(())
    };
    let dofs = predictor.dofs();
    let sus = predictor.sus();
    let mut count = 0usize;
    let mut handle = |q: &[f64],
                      sections: &mut std::collections::BTreeMap<(u8, usize, usize), Section>|
     -> Result<(), IoError> {
        let r = predictor.readings(q, pattern);
        if count == 0 {
            section((0, 0, 0), sections)?;
            for u in 0..r.statics.len() {
                section((1, u, 0), sections)?;
            }
            for (d, moved) in r.dynamic.iter().enumerate() {
                for (u, _) in moved {
                    section((2, *u, d), sections)?;
                }
            }
        }
        let mut push = |key, values: &[f64]| match sections.get_mut(&key) {
            Some(s) => s.push(values),
            None => Ok(()),
        };
        push((0, 0, 0), q)?;
        for (u, s) in r.statics.iter().enumerate() {
            push((1, u, 0), &[s.x, s.y, s.z])?;
        }
        for (d, moved) in r.dynamic.iter().enumerate() {
            for (u, a) in moved {
                push((2, *u, d), &[a.x, a.y, a.z])?;
            }
        }
        count += 1;
        Ok(())
    };
    let is_json = poses
        .extension()
        .is_some_and(|e| e.eq_ignore_ascii_case("json"));
    let source = poses.display().to_string();
    if is_json {
        let table = read_poses(poses)?;
        for q in predictor
            .arrange(&table, &source)
            .map_err(|e| pose_error(e.to_string()))?
        {
            handle(&q, &mut sections)?;
        }
    } else {
        let file = fs::File::open(poses).map_err(|source| IoError::Read {
            path: poses.to_path_buf(),
            source,
        })?;
        let mut columns = None;
        let mut q = vec![0.0; dofs.len()];
        for (n, line) in std::io::BufReader::new(file).lines().enumerate() {
            let line = line.map_err(|source| IoError::Read {
                path: poses.to_path_buf(),
                source,
            })?;
            if line.trim().is_empty() || line.trim_start().starts_with('#') {
                continue;
            }
            let Some((header, index)) = &columns else {
                let header = crate::predict::PoseTable::csv_header(&line);
                let index = predictor
                    .columns(&header, &source)
                    .map_err(|e| pose_error(e.to_string()))?;
                columns = Some((header, index));
                continue;
            };
            let row = crate::predict::PoseTable::csv_row(&line, n + 1, header)
                .map_err(|e| pose_error(e.to_string()))?;
            for (k, &c) in index.iter().enumerate() {
                q[k] = row[c];
            }
            handle(&q, &mut sections)?;
        }
        if columns.is_none() {
            return Err(pose_error(
                "empty file: expected a header of DoF names".into(),
            ));
        }
    }
    // The sections in the order of Predictor::predict's JSON.
    let mut w = std::io::BufWriter::new(out);
    let text = |v: &dyn erased::Json| v.text();
    let put = |w: &mut std::io::BufWriter<&mut dyn std::io::Write>, s: &str| {
        w.write_all(s.as_bytes()).map_err(written(out_path))
    };
    let copy = |w: &mut std::io::BufWriter<&mut dyn std::io::Write>,
                s: Option<&mut Section>|
     -> Result<(), IoError> {
        w.write_all(b"[").map_err(written(out_path))?;
        if let Some(s) = s {
            s.finish()?;
            let mut f = fs::File::open(&s.path).map_err(|source| IoError::Read {
                path: s.path.clone(),
                source,
            })?;
            std::io::copy(&mut f, w).map_err(written(out_path))?;
        }
        w.write_all(b"]").map_err(written(out_path))
    };
    put(
        &mut w,
        &format!(
            "{{\"dofs\":{},\"pattern\":{},\"poses\":",
            text(&dofs),
            text(pattern)
        ),
    )?;
    copy(&mut w, sections.get_mut(&(0, 0, 0)))?;
    put(&mut w, ",\"static\":{")?;
    for (u, su) in sus.iter().enumerate() {
        put(
            &mut w,
            &format!("{}{}:", if u > 0 { "," } else { "" }, text(su)),
        )?;
        copy(&mut w, sections.get_mut(&(1, u, 0)))?;
    }
    put(&mut w, "},\"dynamic\":{")?;
    let mut first_su = true;
    for (u, su) in sus.iter().enumerate() {
        let moved: Vec<usize> = (0..dofs.len())
            .filter(|d| sections.contains_key(&(2, u, *d)))
            .collect();
        if moved.is_empty() {
            continue;
        }
        put(
            &mut w,
            &format!("{}{}:{{", if first_su { "" } else { "," }, text(su)),
        )?;
        first_su = false;
        for (k, d) in moved.into_iter().enumerate() {
            put(
                &mut w,
                &format!("{}{}:", if k > 0 { "," } else { "" }, text(&dofs[d])),
            )?;
            copy(&mut w, sections.get_mut(&(2, u, d)))?;
        }
        put(&mut w, "}")?;
    }
    put(&mut w, "}}\n")?;
    w.flush().map_err(written(out_path))?;
    Ok(count)
}

/// JSON text of small values (names, the pattern) in the streamed output.
mod erased {
    pub trait Json {
        fn text(&self) -> String;
    }
    impl<T: serde::Serialize + ?Sized> Json for T {
        fn text(&self) -> String {
            serde_json::to_string(self).unwrap_or_else(|_| "null".into())
        }
    }
}

/// One streamed JSON array: elements appended to a temporary file.
struct Section {
    path: PathBuf,
    file: Option<std::io::BufWriter<fs::File>>,
    empty: bool,
}

impl Section {
    fn new(path: PathBuf, file: fs::File) -> Self {
        Section {
            path,
            file: Some(std::io::BufWriter::new(file)),
            empty: true,
        }
    }

    fn push(&mut self, values: &[f64]) -> Result<(), IoError> {
        use std::io::Write;
        let file = self.file.as_mut().expect("open until finished");
        let sep = if self.empty { "" } else { "," };
        self.empty = false;
        write!(file, "{sep}[")
            .and_then(|()| {
                for (i, v) in values.iter().enumerate() {
                    // Debug of a finite f64 is the shortest text that reads back exactly, and JSON.
                    write!(file, "{}{v:?}", if i > 0 { "," } else { "" })?;
                }
                write!(file, "]")
            })
            .map_err(|source| IoError::Write {
                path: self.path.clone(),
                source,
            })
    }

    fn finish(&mut self) -> Result<(), IoError> {
        use std::io::Write;
        if let Some(mut f) = self.file.take() {
            f.flush().map_err(|source| IoError::Write {
                path: self.path.clone(),
                source,
            })?;
        }
        Ok(())
    }
}

/// A temporary directory for spilled sections, removed when dropped.
struct SpillDir(PathBuf);

impl SpillDir {
    fn create(beside: &Path) -> std::io::Result<Self> {
        let nanos = std::time::SystemTime::now()
            .duration_since(std::time::UNIX_EPOCH)
            .map_or(0, |d| d.subsec_nanos());
        let path = beside.join(format!(".skincal-spill-{}-{nanos}", std::process::id()));
        fs::create_dir_all(&path)?;
        crate::log::hold_transient(&path);
        Ok(SpillDir(path))
    }
}

impl Drop for SpillDir {
    fn drop(&mut self) {
        let _ = fs::remove_dir_all(&self.0);
        crate::log::release_transient(&self.0);
    }
}
