//! CSV logs: a directory with `joint_states.csv` (`stamp,<DoF names…>`, s and rad) and `imu.csv`
//! (`stamp,frame_id,ax,ay,az`, s and m/s²), one row per sample, `#` lines are comments.

use std::fs::File;
use std::io::{BufRead, BufReader, BufWriter, Write};
use std::path::{Path, PathBuf};

use super::{LogError, LogSink, ReadStats, Sample, Staged, Stream, Time};

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

/// Streams the samples of `stream` from the CSV log directory `dir`.
pub fn read(
    dir: &Path,
    stream: Stream,
    visit: &mut dyn FnMut(Sample<'_>) -> Result<(), LogError>,
    progress: &mut dyn FnMut(u64),
) -> Result<ReadStats, LogError> {
    let path = dir.join(match stream {
        Stream::Joints => JOINTS_FILE,
        Stream::Imu => IMU_FILE,
    });
    let file = File::open(&path).map_err(|source| LogError::Io {
        path: path.clone(),
        source,
    })?;
    let mut reader = BufReader::with_capacity(1 << 20, file);
    let mut stats = ReadStats::default();
    let mut line = String::new();
    let mut number = 0usize;
    let mut bytes = 0u64;
    let mut since_progress = 0u64;
    let mut names: Option<Vec<String>> = None;
    let mut positions: Vec<f64> = Vec::new();
    let csv_error = |line: usize, reason: String| LogError::Csv {
        path: path.clone(),
        line,
        reason,
    };
    loop {
        line.clear();
        let n = reader.read_line(&mut line).map_err(|source| LogError::Io {
            path: path.clone(),
            source,
        })?;
        if n == 0 {
            break;
        }
        number += 1;
        bytes += n as u64;
        since_progress += n as u64;
        if since_progress >= 1 << 22 {
            progress(bytes);
            since_progress = 0;
        }
        let mut row = line.trim_end_matches(['\n', '\r']);
        if number == 1 {
            // Spreadsheet programs start UTF-8 files with a byte-order mark.
            row = row.trim_start_matches('\u{feff}');
        }
        if row.is_empty() || row.starts_with('#') {
            continue;
        }
        let mut fields = row.split(',');
        let first = fields.next().unwrap_or_default().trim();
        if names.is_none() {
            // The header.
            if first != "stamp" {
                return Err(csv_error(
                    number,
                    format!(
                        "the header must start with `stamp` (found `{first}`); expected {}",
                        match stream {
                            Stream::Joints => "`stamp,<DoF names…>`",
                            Stream::Imu => "`stamp,frame_id,ax,ay,az`",
                        }
                    ),
                ));
            }
            let rest: Vec<String> = fields.map(|f| f.trim().to_string()).collect();
            if stream == Stream::Imu && rest != ["frame_id", "ax", "ay", "az"] {
                return Err(csv_error(
                    number,
                    format!("expected the header `stamp,frame_id,ax,ay,az`, found `{row}`"),
                ));
            }
            if stream == Stream::Joints && (rest.is_empty() || rest.iter().any(String::is_empty)) {
                return Err(csv_error(
                    number,
                    "the header needs one non-empty DoF name per column after `stamp`".into(),
                ));
            }
            names = Some(rest);
            continue;
        }
        let Ok(stamp) = first.parse::<f64>() else {
            stats.problem(format!(
                "{}, line {number}: stamp `{first}` is not a number",
                path.display()
            ));
            continue;
        };
        match stream {
            Stream::Joints => {
                let names = names.as_deref().unwrap_or_default();
                positions.clear();
                let mut ok = true;
                for f in fields {
                    match f.trim().parse::<f64>() {
                        Ok(v) if v.is_finite() => positions.push(v),
                        _ => {
                            ok = false;
                            break;
                        }
                    }
                }
                if !ok || positions.len() != names.len() || !stamp.is_finite() {
                    stats.problem(format!(
                        "{}, line {number}: expected a stamp and {} finite positions",
                        path.display(),
                        names.len()
                    ));
                    continue;
                }
                stats.samples += 1;
                visit(Sample::Joints {
                    stamp,
                    names,
                    positions: &positions,
                })?;
            }
            Stream::Imu => {
                let frame = fields.next().unwrap_or_default().trim();
                let mut a = [0.0; 3];
                let mut count = 0;
                for f in fields {
                    if count < 3 {
                        a[count] = f.trim().parse::<f64>().unwrap_or(f64::NAN);
                    }
                    count += 1;
                }
                if count != 3
                    || frame.is_empty()
                    || !stamp.is_finite()
                    || a.iter().any(|v| !v.is_finite())
                {
                    stats.problem(format!(
                        "{}, line {number}: expected `stamp,frame_id,ax,ay,az` with finite numbers",
                        path.display()
                    ));
                    continue;
                }
                stats.samples += 1;
                visit(Sample::Imu {
                    stamp,
                    frame_id: frame,
                    acceleration: a,
                })?;
            }
        }
    }
    if names.is_none() {
        return Err(csv_error(number, "the file is empty (no header)".into()));
    }
    progress(bytes);
    Ok(stats)
}
