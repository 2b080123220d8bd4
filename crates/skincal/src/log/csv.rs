//! CSV logs: a directory with `joint_states.csv` (`stamp,<DoF names…>`, s and rad) and `imu.csv`
//! (`stamp,frame_id,ax,ay,az`, s and m/s²), one row per sample, `#` lines are comments.

use std::fs::File;
use std::io::{BufRead, BufReader, BufWriter, Read, Write};
use std::path::{Path, PathBuf};

use super::{LogError, LogSink, PassStats, ReadStats, Sample, Staged, Stream, Time};

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
    let mut reader = BufReader::with_capacity(1 << 20, file);
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
                        if joints {
                            "`stamp,<DoF names…>`"
                        } else {
                            "`stamp,frame_id,ax,ay,az`"
                        }
                    ),
                ));
            }
            let rest: Vec<String> = fields.map(|f| f.trim().to_string()).collect();
            if !joints && rest != ["frame_id", "ax", "ay", "az"] {
                return Err(csv_error(
                    number,
                    format!("expected the header `stamp,frame_id,ax,ay,az`, found `{row}`"),
                ));
            }
            if joints && (rest.is_empty() || rest.iter().any(String::is_empty)) {
                return Err(csv_error(
                    number,
                    "the header needs one non-empty DoF name per column after `stamp`".into(),
                ));
            }
            names = Some(rest);
            if !joints {
                // The rows, parsed in parallel.
                let rows = ImuRows {
                    path: &path,
                    line: number,
                    bytes,
                };
                return rows.read(reader, stats, visit, progress);
            }
            continue;
        }
        let Ok(stamp) = first.parse::<f64>() else {
            stats.problem(format!(
                "{}, line {number}: stamp `{first}` is not a number",
                path.display()
            ));
            continue;
        };
        // Only joint rows come here: an Imu file's rows go to the parallel parser after its header.
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
    if names.is_none() {
        return Err(csv_error(number, "the file is empty (no header)".into()));
    }
    progress(bytes);
    Ok(())
}

/// Bytes of `imu.csv` parsed as one block.
const BLOCK: usize = 1 << 22;
/// Blocks parsed together.
const BLOCKS: usize = 4;

/// The rows of `imu.csv` after its header: a producer thread reads blocks of whole lines and
/// parses a batch of them in parallel; the caller's thread hands the rows to the visitor in order.
struct ImuRows<'a> {
    path: &'a Path,
    /// Lines before the first block.
    line: usize,
    /// Bytes before the first block.
    bytes: u64,
}

/// One parsed block: its text, its rows and its bad lines.
#[derive(Default)]
struct Parsed {
    text: String,
    /// `(stamp, frame id's byte range in text, acceleration)`.
    rows: Vec<(f64, std::ops::Range<usize>, [f64; 3])>,
    /// Lines that are not a sample, by their number within the block (1-based).
    bad: Vec<usize>,
    lines: usize,
}

impl ImuRows<'_> {
    fn read(
        self,
        reader: BufReader<File>,
        stats: &mut ReadStats,
        visit: &mut dyn FnMut(Sample<'_>) -> Result<(), LogError>,
        progress: &mut dyn FnMut(u64),
    ) -> Result<(), LogError> {
        let path = self.path;
        let io_error = |source| LogError::Io {
            path: path.to_path_buf(),
            source,
        };
        let carry = reader.buffer().to_vec();
        let file = reader.into_inner();
        std::thread::scope(|scope| {
            let (blocks, received) = std::sync::mpsc::sync_channel::<(Parsed, u64)>(2 * BLOCKS);
            let producer = scope.spawn(move || produce(file, carry, &blocks));
            let (mut line, mut bytes) = (self.line, self.bytes);
            for (block, read) in &received {
                for &bad in &block.bad {
                    stats.problem(format!(
                        "{}, line {}: expected `stamp,frame_id,ax,ay,az` with finite numbers",
                        path.display(),
                        line + bad
                    ));
                }
                for (stamp, frame, a) in &block.rows {
                    stats.samples += 1;
                    visit(Sample::Imu {
                        stamp: *stamp,
                        frame_id: &block.text[frame.clone()],
                        acceleration: *a,
                    })?;
                }
                line += block.lines;
                bytes = self.bytes + read;
                progress(bytes);
            }
            drop(received);
            // A producer that panicked read only part of the file: never a silent short read.
            let stopped = || {
                Err(Produced::Io(std::io::Error::other(
                    "the reading thread stopped unexpectedly",
                )))
            };
            producer
                .join()
                .unwrap_or_else(|_| stopped())
                .map_err(|e| match e {
                    Produced::Io(source) => io_error(source),
                    Produced::Utf8(at) => LogError::Csv {
                        path: path.to_path_buf(),
                        line: line + 1,
                        reason: format!("not UTF-8 text (byte {at} of the rows): is it a CSV log?"),
                    },
                })?;
            progress(bytes);
            Ok(())
        })
    }
}

/// Why the producer stopped.
enum Produced {
    Io(std::io::Error),
    /// Bytes read before the text that is not UTF-8.
    Utf8(u64),
}

/// Reads `file` (after `carry`) in blocks of whole lines, parses them a batch at a time in
/// parallel, and sends them in order with the bytes read so far.
fn produce(
    mut file: File,
    mut carry: Vec<u8>,
    blocks: &std::sync::mpsc::SyncSender<(Parsed, u64)>,
) -> Result<(), Produced> {
    use rayon::prelude::*;
    let mut read = 0u64;
    let mut done = false;
    while !done {
        let mut batch: Vec<(Vec<u8>, u64)> = Vec::with_capacity(BLOCKS);
        while batch.len() < BLOCKS && !done {
            let mut block = std::mem::take(&mut carry);
            let start = block.len();
            block.resize(start + BLOCK, 0);
            let n = read_full(&mut file, &mut block[start..]).map_err(Produced::Io)?;
            block.truncate(start + n);
            done = n == 0;
            // Whole lines only: the rest goes to the next block.
            let cut = if done {
                block.len()
            } else {
                block.iter().rposition(|&b| b == b'\n').map_or(0, |i| i + 1)
            };
            carry = block.split_off(cut);
            let at = read;
            read += block.len() as u64;
            if !block.is_empty() {
                batch.push((block, at));
            }
        }
        let parsed: Vec<Result<Parsed, u64>> = batch
            .into_par_iter()
            .map(|(block, at)| {
                String::from_utf8(block)
                    .map(parse)
                    .map_err(|e| at + e.utf8_error().valid_up_to() as u64)
            })
            .collect();
        for p in parsed {
            if blocks.send((p.map_err(Produced::Utf8)?, read)).is_err() {
                return Ok(());
            }
        }
    }
    Ok(())
}

/// Fills `buffer` as far as the file goes.
fn read_full(file: &mut File, buffer: &mut [u8]) -> std::io::Result<usize> {
    let mut n = 0;
    while n < buffer.len() {
        match file.read(&mut buffer[n..]) {
            Ok(0) => break,
            Ok(k) => n += k,
            Err(e) if e.kind() == std::io::ErrorKind::Interrupted => {}
            Err(e) => return Err(e),
        }
    }
    Ok(n)
}

/// The rows `stamp,frame_id,ax,ay,az` of a block of whole lines.
fn parse(text: String) -> Parsed {
    let mut parsed = Parsed::default();
    let mut offset = 0;
    for raw in text.split_inclusive('\n') {
        parsed.lines += 1;
        let start = offset;
        offset += raw.len();
        let row = raw.trim_end_matches(['\n', '\r']);
        if row.is_empty() || row.starts_with('#') {
            continue;
        }
        let mut fields = row.split(',');
        let stamp = fields.next().unwrap_or_default().trim().parse::<f64>();
        let frame = fields.next().unwrap_or_default();
        let trimmed = frame.trim();
        let frame_start = start
            + (frame.as_ptr() as usize - row.as_ptr() as usize)
            + (frame.len() - frame.trim_start().len());
        let mut a = [0.0; 3];
        let mut count = 0;
        for f in fields {
            if count < 3 {
                a[count] = f.trim().parse::<f64>().unwrap_or(f64::NAN);
            }
            count += 1;
        }
        match stamp {
            Ok(stamp)
                if count == 3
                    && !trimmed.is_empty()
                    && stamp.is_finite()
                    && a.iter().all(|v| v.is_finite()) =>
            {
                parsed
                    .rows
                    .push((stamp, frame_start..frame_start + trimmed.len(), a));
            }
            _ => parsed.bad.push(parsed.lines),
        }
    }
    parsed.text = text;
    parsed
}
