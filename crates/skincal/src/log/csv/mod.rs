//! CSV logs: a directory with `joint_states.csv` (`stamp,<DoF names…>`, s and rad) and `imu.csv`
//! (`stamp,frame_id,ax,ay,az`, s and m/s²), one row per sample, `#` lines are comments.

use std::fs::File;
use std::io::{BufRead, BufReader, BufWriter, Write};
use std::path::{Path, PathBuf};

use super::{LogError, LogSink, PassStats, ReadStats, Sample, Staged, Stream, Time};

mod rows;

/// File of the joint states in a CSV log directory.
pub const JOINTS_FILE: &str = "joint_states.csv";
/// File of the skin samples in a CSV log directory.
pub const IMU_FILE: &str = "imu.csv";

/// Writes a CSV log directory.
pub struct CsvSink {
    dir: PathBuf,
    force: bool,
    files: Option<[(Staged, BufWriter<File>); 2]>,
    sus: Vec<String>,
    line: String,
}

impl CsvSink {
    /// A sink writing `dir/joint_states.csv` and `dir/imu.csv`.
    pub fn new(dir: &Path, force: bool) -> CsvSink {
        CsvSink {
            dir: dir.to_path_buf(),
            force,
            files: None,
            sus: Vec::new(),
            line: String::new(),
        }
    }

    fn write_line(&mut self, which: usize) -> Result<(), LogError> {
        let Some(files) = self.files.as_mut() else {
            return Err(LogError::Stopped("CSV sink used before start".into()));
        };
        let (staged, w) = &mut files[which];
        w.write_all(self.line.as_bytes())
            .map_err(|source| LogError::Io {
                path: staged.tmp().to_path_buf(),
                source,
            })
    }
}

impl LogSink for CsvSink {
    fn start(
        &mut self,
        dofs: &[String],
        sus: &[String],
        _acceleration_variance: f64,
    ) -> Result<(), LogError> {
        let (js, jf) = Staged::create(&self.dir.join(JOINTS_FILE), self.force)?;
        let (is, imf) = Staged::create(&self.dir.join(IMU_FILE), self.force)?;
        self.files = Some([
            (js, BufWriter::with_capacity(1 << 20, jf)),
            (is, BufWriter::with_capacity(1 << 20, imf)),
        ]);
        self.sus = sus.to_vec();
        self.line = format!("stamp,{}\n", dofs.join(","));
        self.write_line(0)?;
        self.line = "stamp,frame_id,ax,ay,az\n".into();
        self.write_line(1)
    }

    fn joint_state(
        &mut self,
        stamp: Time,
        _receive: Time,
        positions: &[f64],
        _velocities: &[f64],
    ) -> Result<(), LogError> {
        use std::fmt::Write as _;
        self.line.clear();
        let _ = write!(self.line, "{}.{:09}", stamp.sec, stamp.nanosec);
        for q in positions {
            let _ = write!(self.line, ",{q:.9}");
        }
        self.line.push('\n');
        self.write_line(0)
    }

    fn imu(&mut self, stamp: Time, _receive: Time, su: usize, a: [f64; 3]) -> Result<(), LogError> {
        use std::fmt::Write as _;
        self.line.clear();
        let name = self.sus.get(su).map(String::as_str).unwrap_or_default();
        let _ = writeln!(
            self.line,
            "{}.{:09},{name},{:.6},{:.6},{:.6}",
            stamp.sec, stamp.nanosec, a[0], a[1], a[2]
        );
        self.write_line(1)
    }

    fn finish(&mut self) -> Result<Vec<PathBuf>, LogError> {
        let Some(files) = self.files.take() else {
            return Ok(Vec::new());
        };
        let mut staged = Vec::new();
        for (s, mut w) in files {
            w.flush().map_err(|source| LogError::Io {
                path: s.tmp().to_path_buf(),
                source,
            })?;
            staged.push(s);
        }
        staged.iter_mut().map(Staged::commit).collect()
    }
}

/// Streams the samples of `stream` from the CSV log directory `dir` (both: the joint file first).
pub fn read(
    dir: &Path,
    stream: Stream,
    visit: &mut dyn FnMut(Sample<'_>) -> Result<(), LogError>,
    progress: &mut dyn FnMut(u64),
) -> Result<PassStats, LogError> {
    let mut stats = PassStats::default();
    let mut done = 0u64;
    if stream.joints() {
        read_file(dir, true, &mut stats.joints, visit, progress)?;
        done = std::fs::metadata(dir.join(JOINTS_FILE)).map_or(0, |m| m.len());
    }
    if stream.imu() {
        read_file(dir, false, &mut stats.imu, visit, &mut |n| {
            progress(done + n)
        })?;
    }
    Ok(stats)
}

/// Streams the rows of the joint file (`joints`) or of the Imu file of `dir`.
fn read_file(
    dir: &Path,
    joints: bool,
    stats: &mut ReadStats,
    visit: &mut dyn FnMut(Sample<'_>) -> Result<(), LogError>,
    progress: &mut dyn FnMut(u64),
) -> Result<(), LogError> {
    let path = dir.join(if joints { JOINTS_FILE } else { IMU_FILE });
    let file = File::open(&path).map_err(|source| LogError::Io {
        path: path.clone(),
        source,
    })?;
    let mut lines = Lines {
        path: &path,
        reader: BufReader::with_capacity(1 << 20, file),
        line: String::new(),
        number: 0,
        bytes: 0,
    };
    let csv_error = |line: usize, reason: String| LogError::Csv {
        path: path.clone(),
        line,
        reason,
    };
    let names = loop {
        let Some(row) = lines.next_row(progress)? else {
            return Err(csv_error(
                lines.number,
                "the file is empty (no header)".into(),
            ));
        };
        if !row.is_empty() && !row.starts_with('#') {
            break header(row, joints).map_err(|reason| csv_error(lines.number, reason))?;
        }
    };
    if !joints {
        // The rows, parsed in parallel.
        let rows = rows::ImuRows {
            path: &path,
            line: lines.number,
            bytes: lines.bytes,
        };
        return rows.read(lines.reader, stats, visit, progress);
    }
    let mut positions: Vec<f64> = Vec::new();
    while let Some(row) = lines.next_row(progress)? {
        if row.is_empty() || row.starts_with('#') {
            continue;
        }
        let stamp = rows::joint_row(row, names.len(), &mut positions)
            .filter(|_| super::usable_positions(&positions));
        let Some(stamp) = stamp else {
            stats.problem(format!(
                "{}, line {}: expected a stamp and {} finite positions within ±10000 rad",
                path.display(),
                lines.number,
                names.len()
            ));
            continue;
        };
        stats.samples += 1;
        visit(Sample::Joints {
            stamp,
            names: &names,
            positions: &positions,
        })?;
    }
    progress(lines.bytes);
    Ok(())
}

/// The names after `stamp` in a header row, checked against what the file must hold.
fn header(row: &str, joints: bool) -> Result<Vec<String>, String> {
    let mut fields = row.split(',').map(str::trim);
    let first = fields.next().unwrap_or_default();
    if first != "stamp" {
        return Err(format!(
            "the header must start with `stamp` (found `{first}`); expected {}",
            if joints {
                "`stamp,<DoF names…>`"
            } else {
                "`stamp,frame_id,ax,ay,az`"
            }
        ));
    }
    let rest: Vec<String> = fields.map(str::to_string).collect();
    if !joints && rest != ["frame_id", "ax", "ay", "az"] {
        return Err(format!(
            "expected the header `stamp,frame_id,ax,ay,az`, found `{row}`"
        ));
    }
    if joints && (rest.is_empty() || rest.iter().any(String::is_empty)) {
        return Err("the header needs one non-empty DoF name per column after `stamp`".into());
    }
    Ok(rest)
}

/// The lines of a CSV file, read one at a time, counted, with progress every 4 MB.
struct Lines<'a> {
    path: &'a Path,
    reader: BufReader<File>,
    line: String,
    /// The current line's number (1-based).
    number: usize,
    /// Bytes read.
    bytes: u64,
}

impl Lines<'_> {
    /// The next line without its line end (or byte-order mark, on the first), `None` at the end.
    fn next_row(&mut self, progress: &mut dyn FnMut(u64)) -> Result<Option<&str>, LogError> {
        self.line.clear();
        let n = self
            .reader
            .read_line(&mut self.line)
            .map_err(|source| LogError::Io {
                path: self.path.to_path_buf(),
                source,
            })?;
        if n == 0 {
            return Ok(None);
        }
        self.number += 1;
        let before = self.bytes;
        self.bytes += n as u64;
        if before >> 22 != self.bytes >> 22 {
            progress(self.bytes);
        }
        let row = self.line.trim_end_matches(['\n', '\r']);
        // Spreadsheet programs start UTF-8 files with a byte-order mark.
        Ok(Some(if self.number == 1 {
            row.trim_start_matches('\u{feff}')
        } else {
            row
        }))
    }
}
