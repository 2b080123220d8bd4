//! Predictions for pose files of any length: the JSON of [`Predictor::predict`], written with
//! memory that does not grow with the number of poses. A CSV pose file is read a row at a time;
//! every array of the output (the poses, each SU's static readings, each SU's dynamic readings per
//! DoF) is appended to its own temporary file, and the files are copied out in order at the end.

use std::collections::BTreeMap;
use std::fs;
use std::io::{BufRead, BufWriter, Write};
use std::path::{Path, PathBuf};

use super::{read_poses, staging_error, IoError};
use crate::log::Staged;
use crate::model::sensor::ExcitationPattern;
use crate::predict::{PoseTable, Predictor};

/// [`stream_predictions`] into the file `out`, written whole or not at all; refuses to overwrite
/// it without `force`. Returns the number of poses.
pub fn write_predictions(
    predictor: &Predictor,
    poses: &Path,
    pattern: &ExcitationPattern,
    out: &Path,
    force: bool,
    progress: &mut dyn FnMut(Progress),
) -> Result<usize, IoError> {
    let (mut stage, mut file) = Staged::create(out, force).map_err(|e| staging_error(e, out))?;
    let beside = out
        .parent()
        .filter(|p| !p.as_os_str().is_empty())
        .unwrap_or(Path::new("."));
    let count = stream_predictions(predictor, poses, pattern, beside, &mut file, out, progress)?;
    stage.commit().map_err(|e| staging_error(e, out))?;
    Ok(count)
}

/// How far [`stream_predictions`] has come.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Progress {
    /// This many poses predicted (how many the file holds is known at its end).
    Predicted(usize),
    /// The output written so far: this many parts of `of` (each SU's static readings, then each
    /// SU's dynamic readings).
    Written {
        /// Parts written.
        parts: usize,
        /// Parts in all.
        of: usize,
    },
}

/// Streams the predictions of `predictor` for every pose of the pose file `poses` to `out` (named
/// `out_path` in errors), as the JSON of [`Predictor::predict`], compact; the arrays are spilled
/// to a temporary directory in `spill_in`. Returns the number of poses. `progress` is called after
/// each pose, then as each SU's arrays are written out.
pub fn stream_predictions(
    predictor: &Predictor,
    poses: &Path,
    pattern: &ExcitationPattern,
    spill_in: &Path,
    out: &mut dyn Write,
    out_path: &Path,
    progress: &mut dyn FnMut(Progress),
) -> Result<usize, IoError> {
    let mut spill = Spill::create(spill_in)?;
    let mut count = 0usize;
    for_each_pose(predictor, poses, &mut |q| {
        let r = predictor.readings(q, pattern);
        spill.push(Array::Poses, q)?;
        for (u, s) in r.statics.iter().enumerate() {
            spill.push(Array::Static(u), &[s.x, s.y, s.z])?;
        }
        for (d, moved) in r.dynamic.iter().enumerate() {
            for (u, a) in moved {
                spill.push(Array::Dynamic(*u, d), &[a.x, a.y, a.z])?;
            }
        }
        count += 1;
        progress(Progress::Predicted(count));
        Ok(())
    })?;
    spill
        .write_json(&mut BufWriter::new(out), predictor, pattern, progress)
        .map_err(|source| match source {
            Failure::Out(source) => IoError::Write {
                path: out_path.to_path_buf(),
                source,
            },
            Failure::Io(e) => e,
        })?;
    Ok(count)
}

/// Calls `f` with every pose of the file, in model DoF order: a CSV file row by row, a JSON table
/// (`{"dofs", "poses"}`) as a whole.
fn for_each_pose(
    predictor: &Predictor,
    poses: &Path,
    f: &mut dyn FnMut(&[f64]) -> Result<(), IoError>,
) -> Result<(), IoError> {
    let pose_error = |message: String| IoError::Json {
        path: poses.to_path_buf(),
        message,
    };
    let read_error = |source| IoError::Read {
        path: poses.to_path_buf(),
        source,
    };
    let source = poses.display().to_string();
    if poses
        .extension()
        .is_some_and(|e| e.eq_ignore_ascii_case("json"))
    {
        let table = read_poses(poses)?;
        let rows = predictor
            .arrange(&table, &source)
            .map_err(|e| pose_error(e.to_string()))?;
        return rows.iter().try_for_each(|q| f(q));
    }
    let file = fs::File::open(poses).map_err(read_error)?;
    let mut columns: Option<(Vec<String>, Vec<usize>)> = None;
    let mut q = Vec::new();
    for (n, line) in std::io::BufReader::new(file).lines().enumerate() {
        let line = line.map_err(read_error)?;
        if line.trim().is_empty() || line.trim_start().starts_with('#') {
            continue;
        }
        let Some((header, index)) = &columns else {
            let header = PoseTable::csv_header(&line);
            let index = predictor
                .columns(&header, &source)
                .map_err(|e| pose_error(e.to_string()))?;
            columns = Some((header, index));
            continue;
        };
        let row =
            PoseTable::csv_row(&line, n + 1, header).map_err(|e| pose_error(e.to_string()))?;
        q.clear();
        q.extend(index.iter().map(|&c| row[c]));
        f(&q)?;
    }
    match columns {
        Some(_) => Ok(()),
        None => Err(pose_error(
            "empty file: expected a header of DoF names".into(),
        )),
    }
}

/// The arrays of the output JSON, in its order.
#[derive(Debug, Clone, Copy, PartialEq, Eq, PartialOrd, Ord)]
enum Array {
    Poses,
    /// Static readings of SU `u`.
    Static(usize),
    /// Dynamic readings of SU `u` for DoF `d`.
    Dynamic(usize, usize),
}

/// A failure while copying out: writing the output, or reading a spilled array back.
enum Failure {
    Out(std::io::Error),
    Io(IoError),
}

/// The spilled arrays, in a temporary directory that is removed when dropped (or on a signal).
struct Spill {
    arrays: BTreeMap<Array, (PathBuf, BufWriter<fs::File>, bool)>,
    // Dropped after the files are closed (fields drop in order).
    dir: crate::log::TransientDir,
}

impl Spill {
    fn create(beside: &Path) -> Result<Self, IoError> {
        let dir =
            crate::log::TransientDir::new(".skincal-spill-", Some(beside)).map_err(|source| {
                IoError::Write {
                    path: beside.to_path_buf(),
                    source,
                }
            })?;
        Ok(Spill {
            dir,
            arrays: BTreeMap::new(),
        })
    }

    /// Appends `[values…]` to an array, making its file on the first element.
    fn push(&mut self, array: Array, values: &[f64]) -> Result<(), IoError> {
        let written = |path: &Path| {
            let path = path.to_path_buf();
            move |source| IoError::Write { path, source }
        };
        if !self.arrays.contains_key(&array) {
            let path = self.dir.path().join(self.arrays.len().to_string());
            let file = fs::File::create(&path).map_err(written(&path))?;
            self.arrays
                .insert(array, (path, BufWriter::new(file), true));
        }
        let (path, file, empty) = self.arrays.get_mut(&array).expect("inserted above");
        let separator = if std::mem::take(empty) { "[" } else { ",[" };
        let mut element = || -> std::io::Result<()> {
            file.write_all(separator.as_bytes())?;
            for (i, v) in values.iter().enumerate() {
                // Debug of a finite f64 is the shortest text that reads back exactly, and JSON.
                write!(file, "{}{v:?}", if i > 0 { "," } else { "" })?;
            }
            file.write_all(b"]")
        };
        element().map_err(written(path))
    }

    /// The whole JSON: names and pattern, then every array copied from its file.
    fn write_json(
        &mut self,
        w: &mut dyn Write,
        predictor: &Predictor,
        pattern: &ExcitationPattern,
        progress: &mut dyn FnMut(Progress),
    ) -> Result<(), Failure> {
        let (dofs, sus) = (predictor.dofs(), predictor.sus());
        let put = |w: &mut dyn Write, s: &str| w.write_all(s.as_bytes()).map_err(Failure::Out);
        put(
            w,
            &format!(
                "{{\"dofs\":{},\"pattern\":{},\"poses\":",
                json(&dofs),
                json(pattern)
            ),
        )?;
        self.copy(w, Array::Poses)?;
        put(w, ",\"static\":{")?;
        for (u, su) in sus.iter().enumerate() {
            put(w, &format!("{}{}:", if u > 0 { "," } else { "" }, json(su)))?;
            self.copy(w, Array::Static(u))?;
            progress(Progress::Written {
                parts: u + 1,
                of: 2 * sus.len(),
            });
        }
        put(w, "},\"dynamic\":{")?;
        let mut first = true;
        for (u, su) in sus.iter().enumerate() {
            progress(Progress::Written {
                parts: sus.len() + u,
                of: 2 * sus.len(),
            });
            let moved: Vec<usize> = (0..dofs.len())
                .filter(|&d| self.arrays.contains_key(&Array::Dynamic(u, d)))
                .collect();
            if moved.is_empty() {
                continue;
            }
            put(
                w,
                &format!("{}{}:{{", if first { "" } else { "," }, json(su)),
            )?;
            first = false;
            for (k, d) in moved.into_iter().enumerate() {
                put(
                    w,
                    &format!("{}{}:", if k > 0 { "," } else { "" }, json(&dofs[d])),
                )?;
                self.copy(w, Array::Dynamic(u, d))?;
            }
            put(w, "}")?;
        }
        put(w, "}}\n")?;
        w.flush().map_err(Failure::Out)
    }

    /// `[…]` of one array (empty when it has no element).
    fn copy(&mut self, w: &mut dyn Write, array: Array) -> Result<(), Failure> {
        w.write_all(b"[").map_err(Failure::Out)?;
        if let Some((path, file, _)) = self.arrays.get_mut(&array) {
            let spilled = |source| {
                Failure::Io(IoError::Read {
                    path: path.clone(),
                    source,
                })
            };
            file.flush().map_err(spilled)?;
            let mut f = fs::File::open(&*path).map_err(spilled)?;
            std::io::copy(&mut f, w).map_err(Failure::Out)?;
        }
        w.write_all(b"]").map_err(Failure::Out)
    }
}

/// JSON text of the small values (names, the pattern) around the arrays.
fn json<T: serde::Serialize + ?Sized>(value: &T) -> String {
    serde_json::to_string(value).unwrap_or_else(|_| "null".into())
}
