//! Time-series logs of a skin-covered robot: joint states and raw accelerometer samples.
//!
//! Two formats written by the time-series simulator and read by the ingestion:
//!
//! * **MCAP** ([`mcap`]): ROS 2 messages, CDR-encoded ([`ros`]); joint states on
//!   `/joint_states`, skin samples on `/skin/imu` (topic names are options when reading).
//! * **CSV** ([`csv`]): a directory with `joint_states.csv` (`stamp,<DoF names…>`, rad)
//!   and `imu.csv` (`stamp,frame_id,ax,ay,az`, m/s²); stamps in seconds.
//!
//! Read as well: rosbag2 directories (their `metadata.yaml` lists MCAP or SQLite files,
//! [`db3`]), and ROS 1 bags ([`bag`]).
//!
//! Writers implement [`LogSink`] and write whole files or nothing (a temporary file renamed at
//! [`LogSink::finish`]). Readers stream: [`read_log`] calls back once per sample of the topics asked
//! for, so a log never has to fit in memory.

pub mod bag;
pub mod csv;
pub mod db3;
mod in_order;
pub mod mcap;
pub mod memory;
pub mod ros;
pub mod trajectory;

use std::collections::HashMap;
use std::path::{Path, PathBuf};

pub use memory::MemoryLog;
pub use ros::Time;

/// Default topic of the joint states.
pub const JOINT_TOPIC: &str = "/joint_states";
/// Default topic of the skin samples.
pub const IMU_TOPIC: &str = "/skin/imu";

/// Errors reading or writing a log.
#[derive(Debug, thiserror::Error)]
#[non_exhaustive]
pub enum LogError {
    /// A file could not be read or written.
    #[error("{path}: {source}")]
    Io {
        /// The file.
        path: PathBuf,
        /// The cause.
        source: std::io::Error,
    },
    /// The MCAP container is damaged or not MCAP.
    #[error("{path}: not a readable MCAP file: {reason}")]
    Mcap {
        /// The file.
        path: PathBuf,
        /// What the MCAP reader said.
        reason: String,
    },
    /// A ROS 1 bag cannot be read.
    #[error("{path}: not a readable ROS 1 bag: {reason}")]
    Bag {
        /// The file.
        path: PathBuf,
        /// What is wrong and what to do.
        reason: String,
    },
    /// A rosbag2 SQLite file cannot be read.
    #[error("{path}: not a readable rosbag2 SQLite file: {reason}")]
    Db3 {
        /// The file.
        path: PathBuf,
        /// What is wrong and what to do.
        reason: String,
    },
    /// A CSV file does not follow the format.
    #[error("{path}, line {line}: {reason}")]
    Csv {
        /// The file.
        path: PathBuf,
        /// 1-based line number.
        line: usize,
        /// What is wrong and what is expected.
        reason: String,
    },
    /// The path is neither an `.mcap` file nor a directory of CSV files.
    #[error("{path}: {reason}")]
    Unrecognised {
        /// The path.
        path: PathBuf,
        /// What was expected.
        reason: String,
    },
    /// The output exists and overwriting was not asked for.
    #[error("{path} exists; choose another output or pass --force to overwrite it")]
    Exists {
        /// The file.
        path: PathBuf,
    },
    /// A message could not be encoded.
    #[error("encoding a {schema} message: {reason}")]
    Encode {
        /// The message type.
        schema: &'static str,
        /// The encoder's message.
        reason: String,
    },
    /// The consumer of a log stopped reading.
    #[error("{0}")]
    Stopped(String),
}

/// Receives a time-series log in time order.
pub trait LogSink {
    /// Declares the DoF and SU names before the first sample, and the variance of each
    /// accelerometer component's noise, (m/s²)² (0: unknown).
    fn start(
        &mut self,
        dofs: &[String],
        sus: &[String],
        acceleration_variance: f64,
    ) -> Result<(), LogError>;
    /// One joint state: `stamp` (the header stamp), `receive` (when it was logged), positions
    /// (rad) and velocities (rad/s) of every DoF.
    fn joint_state(
        &mut self,
        stamp: Time,
        receive: Time,
        positions: &[f64],
        velocities: &[f64],
    ) -> Result<(), LogError>;
    /// One accelerometer sample of SU `su` (index into the names given to `start`), m/s².
    fn imu(&mut self, stamp: Time, receive: Time, su: usize, a: [f64; 3]) -> Result<(), LogError>;
    /// Completes the files (renames them into place).
    fn finish(&mut self) -> Result<Vec<PathBuf>, LogError>;
}

/// One sample read from a log.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum Sample<'a> {
    /// A joint state: stamp (s), names and positions (rad), in the same order.
    Joints {
        /// Header stamp, s.
        stamp: f64,
        /// Joint names.
        names: &'a [String],
        /// Positions, rad.
        positions: &'a [f64],
    },
    /// An accelerometer sample.
    Imu {
        /// Header stamp, s.
        stamp: f64,
        /// The SU.
        frame_id: &'a str,
        /// Specific force, m/s².
        acceleration: [f64; 3],
    },
}

/// Which samples a pass over a log wants.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Stream {
    /// The joint states only.
    Joints,
    /// The accelerometer samples only.
    Imu,
    /// Both, in one pass (a CSV log's joint file first).
    Both,
}

impl Stream {
    /// Whether the pass delivers joint states.
    pub fn joints(self) -> bool {
        self != Stream::Imu
    }

    /// Whether the pass delivers accelerometer samples.
    pub fn imu(self) -> bool {
        self != Stream::Joints
    }
}

/// Topic names of an MCAP log.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Topics {
    /// `sensor_msgs/msg/JointState` topic.
    pub joints: String,
    /// `sensor_msgs/msg/Imu` topic.
    pub imu: String,
}

impl Default for Topics {
    fn default() -> Self {
        Self {
            joints: JOINT_TOPIC.into(),
            imu: IMU_TOPIC.into(),
        }
    }
}

/// What a pass over a log met besides the samples it delivered.
#[derive(Debug, Clone, Default, PartialEq, serde::Serialize, serde::Deserialize)]
#[serde(default)]
pub struct ReadStats {
    /// Samples delivered.
    pub samples: u64,
    /// Messages on other topics, by topic.
    pub other_topics: std::collections::BTreeMap<String, u64>,
    /// Messages (or CSV rows) that could not be decoded.
    pub undecodable: u64,
    /// The first decoding problem, for the report.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub first_problem: Option<String>,
}

/// What a pass over a log met, per stream (a pass of one stream leaves the other's empty).
#[derive(Debug, Clone, Default, PartialEq)]
pub struct PassStats {
    /// Joint states; messages on other topics are counted here.
    pub joints: ReadStats,
    /// Accelerometer samples.
    pub imu: ReadStats,
}

impl PassStats {
    /// Where a problem of no one stream is counted: with the joint states when the pass reads
    /// them.
    pub(crate) fn general(&mut self, stream: Stream) -> &mut ReadStats {
        if stream.joints() {
            &mut self.joints
        } else {
            &mut self.imu
        }
    }

    /// Adds a later file's counts (of the same log).
    fn add(&mut self, other: PassStats) {
        for (mine, theirs) in [(&mut self.joints, other.joints), (&mut self.imu, other.imu)] {
            mine.samples += theirs.samples;
            mine.undecodable += theirs.undecodable;
            for (topic, n) in theirs.other_topics {
                *mine.other_topics.entry(topic).or_default() += n;
            }
            mine.first_problem = mine.first_problem.take().or(theirs.first_problem);
        }
    }
}

impl ReadStats {
    fn problem(&mut self, what: String) {
        self.undecodable += 1;
        if self.first_problem.is_none() {
            self.first_problem = Some(what);
        }
    }
}

/// What the messages on one topic of a log are to the ingestion.
#[derive(Debug, Clone)]
pub(crate) enum ChannelKind {
    Joints,
    Imu,
    /// `skin_msgs/msg/ImuArray` on the Imu topic.
    ImuArray,
    Other(String),
    /// The topic is one of ours but the type or encoding is not.
    Wrong(String),
}

impl ChannelKind {
    /// The kind of `topic`, carrying messages of type `schema` in `encoding`.
    pub(crate) fn of(topic: &str, schema: &str, encoding: &str, topics: &Topics) -> ChannelKind {
        let expected = if topic == topics.joints {
            Some((ros::JOINT_STATE, ChannelKind::Joints))
        } else if topic == topics.imu {
            Some((ros::IMU, ChannelKind::Imu))
        } else {
            None
        };
        match expected {
            None => ChannelKind::Other(topic.to_string()),
            Some((name, kind)) => {
                let cdr = encoding == ros::MESSAGE_ENCODING;
                if cdr && matches!(kind, ChannelKind::Imu) && schema == ros::IMU_ARRAY {
                    ChannelKind::ImuArray
                } else if cdr && schema == name {
                    kind
                } else {
                    ChannelKind::Wrong(format!(
                        "topic {topic} carries `{schema}` in `{encoding}`; expected `{name}` in \
                         `cdr` (or `{}` on the Imu topic; choose the topics with \
                         --joint-topic/--imu-topic)",
                        ros::IMU_ARRAY
                    ))
                }
            }
        }
    }
}

/// Decodes one CDR message of a topic of `kind` and gives it to `visit` when it belongs to
/// `stream`; what cannot be decoded is counted in `stats`, other topics too (on a pass that reads
/// the joint states).
pub(crate) fn deliver(
    kind: &ChannelKind,
    body: &[u8],
    stream: Stream,
    topics: &Topics,
    frames: &mut FrameNames,
    stats: &mut PassStats,
    visit: &mut dyn FnMut(Sample<'_>) -> Result<(), LogError>,
) -> Result<(), LogError> {
    match kind {
        ChannelKind::Imu if stream.imu() => match ros::imu_fields(body) {
            Ok(m) => imu_sample(m, body, frames, stats, topics, visit)?,
            Err(e) => stats.imu.problem(format!("{}: {e}", topics.imu)),
        },
        ChannelKind::Joints if stream.joints() => match ros::decode_joint_state(body) {
            Ok(joint) => {
                if joint.position.len() != joint.name.len() {
                    stats.joints.problem(format!(
                        "{}: {} names but {} positions",
                        topics.joints,
                        joint.name.len(),
                        joint.position.len()
                    ));
                    return Ok(());
                }
                if !usable_positions(&joint.position) {
                    stats
                        .joints
                        .problem(format!("{}: {NON_FINITE_POSITION}", topics.joints));
                    return Ok(());
                }
                stats.joints.samples += 1;
                visit(Sample::Joints {
                    stamp: joint.header.stamp.seconds(),
                    names: &joint.name,
                    positions: &joint.position,
                })?;
            }
            Err(e) => stats.joints.problem(format!("{}: {e}", topics.joints)),
        },
        ChannelKind::ImuArray if stream.imu() => match ros::imu_array_fields(body) {
            Ok(batch) => {
                for m in batch {
                    imu_sample(m, body, frames, stats, topics, visit)?;
                }
            }
            Err(e) => stats.imu.problem(format!("{}: {e}", topics.imu)),
        },
        ChannelKind::Joints | ChannelKind::Imu | ChannelKind::ImuArray => {}
        ChannelKind::Other(topic) => {
            if stream.joints() {
                *stats.joints.other_topics.entry(topic.clone()).or_default() += 1;
            }
        }
        ChannelKind::Wrong(why) => {
            if stream.joints() {
                stats.joints.problem(why.clone());
            }
        }
    }
    Ok(())
}

/// Why a skin sample is not used: drivers publish NaN for a reading they could not take.
pub(crate) const NON_FINITE_ACCELERATION: &str =
    "a sample with a non-finite acceleration (NaN or infinite: a reading the driver could not take)";
/// Why a joint state is not used.
pub(crate) const NON_FINITE_POSITION: &str =
    "a joint state with a non-finite position (NaN or infinite: a reading the driver could not \
     take) or one beyond ±10000 rad (a damaged one)";

/// The largest joint position a log may hold, rad: what a measurement set holds (its poses' own
/// bound, a layer above the logs).
const MAX_POSITION: f64 = 1.0e4;

/// Whether every position of a joint state can be used: finite and within [`MAX_POSITION`].
pub(crate) fn usable_positions(positions: &[f64]) -> bool {
    positions
        .iter()
        .all(|q| q.is_finite() && q.abs() <= MAX_POSITION)
}

/// One accelerometer sample, read in place from the CDR `message`, to `visit`, counted; one with
/// a non-finite component or whose frame id is not UTF-8 is counted as a problem.
fn imu_sample(
    m: ros::ImuFields,
    message: &[u8],
    frames: &mut FrameNames,
    stats: &mut PassStats,
    topics: &Topics,
    visit: &mut dyn FnMut(Sample<'_>) -> Result<(), LogError>,
) -> Result<(), LogError> {
    if !m.linear_acceleration.iter().all(|v| v.is_finite()) {
        stats
            .imu
            .problem(format!("{}: {NON_FINITE_ACCELERATION}", topics.imu));
        return Ok(());
    }
    let frame = &message[m.frame.0 as usize..m.frame.1 as usize];
    match frames.name(frame) {
        Ok(frame_id) => {
            stats.imu.samples += 1;
            visit(Sample::Imu {
                stamp: m.stamp.seconds(),
                frame_id,
                acceleration: m.linear_acceleration,
            })
        }
        Err(e) => {
            let e = ros::utf8_error(e);
            stats.imu.problem(format!("{}: {e}", topics.imu));
            Ok(())
        }
    }
}

/// The frame ids a reader has seen, so that each is checked to be UTF-8 once rather than in every
/// message. SUs usually come in the same order at every time step: the one after the last is
/// tried first.
#[derive(Debug, Default)]
pub(crate) struct FrameNames {
    names: Vec<String>,
    index: HashMap<Vec<u8>, usize>,
    next: usize,
}

/// Frame ids remembered at most (beyond, the others are checked every time).
const MOST_FRAMES: usize = 1 << 16;

impl FrameNames {
    /// `bytes` as text.
    pub(crate) fn name<'a>(&'a mut self, bytes: &'a [u8]) -> Result<&'a str, std::str::Utf8Error> {
        let found = match self.names.get(self.next) {
            Some(n) if n.as_bytes() == bytes => Some(self.next),
            _ => self.index.get(bytes).copied(),
        };
        if let Some(i) = found {
            self.next = i + 1;
            return Ok(&self.names[i]);
        }
        let name = std::str::from_utf8(bytes)?;
        if self.names.len() == MOST_FRAMES {
            return Ok(name);
        }
        self.index.insert(bytes.to_vec(), self.names.len());
        self.names.push(name.to_string());
        self.next = self.names.len();
        Ok(&self.names[self.names.len() - 1])
    }
}

/// The kind of a log path.
#[derive(Debug, Clone, PartialEq, Eq)]
pub enum LogFormat {
    /// An `.mcap` file.
    Mcap,
    /// A directory with `joint_states.csv` and `imu.csv`.
    Csv,
    /// A rosbag2 SQLite file (`.db3`).
    Db3,
    /// A ROS 1 bag (`.bag`, format 2.0).
    Bag,
    /// A rosbag2 directory: its files (`.mcap` or `.db3`), in the order its `metadata.yaml` lists
    /// them.
    Rosbag2(Vec<PathBuf>),
}

/// The part of a rosbag2 `metadata.yaml` that says where the messages are.
#[derive(Debug, serde::Deserialize)]
struct Rosbag2Metadata {
    rosbag2_bagfile_information: Rosbag2Information,
}

#[derive(Debug, serde::Deserialize)]
struct Rosbag2Information {
    storage_identifier: String,
    relative_file_paths: Vec<String>,
}

/// Tells the format of `path`: a directory with a rosbag2 `metadata.yaml` is a bag, another
/// directory a CSV log, a file an MCAP log unless its first bytes say it is a rosbag2 SQLite file
/// or a ROS 1 bag.
pub fn format_of(path: &Path) -> Result<LogFormat, LogError> {
    let unrecognised = |reason: String| LogError::Unrecognised {
        path: path.to_path_buf(),
        reason,
    };
    if path.is_dir() {
        let metadata = path.join("metadata.yaml");
        if metadata.is_file() {
            return rosbag2_files(path, &metadata);
        }
        for extension in ["mcap", "db3"] {
            if !path.join(csv::JOINTS_FILE).is_file() && has_extension(path, extension) {
                return Err(unrecognised(format!(
                    "a directory of .{extension} files without metadata.yaml: give the \
                     .{extension} file itself, or the rosbag2 directory with its metadata.yaml"
                )));
            }
        }
        return Ok(LogFormat::Csv);
    }
    if !path.is_file() {
        return Err(unrecognised(
            "no such file or directory (give an .mcap file, a rosbag2 directory, or a directory \
             with joint_states.csv and imu.csv)"
                .into(),
        ));
    }
    let mut start = [0u8; 16];
    let read = std::fs::File::open(path)
        .and_then(|mut f| std::io::Read::read(&mut f, &mut start))
        .map_err(|source| LogError::Io {
            path: path.to_path_buf(),
            source,
        })?;
    let start = &start[..read];
    if start.starts_with(b"SQLite format 3\0") {
        Ok(LogFormat::Db3)
    } else if start.starts_with(b"#ROSBAG V2.0\n") {
        Ok(LogFormat::Bag)
    } else if start.starts_with(b"#ROSBAG V") {
        Err(unrecognised(
            "a ROS 1 bag of a format before 2.0: convert it with `rosbag fix FILE.bag NEW.bag` \
             (ROS 1) and give the new bag"
                .into(),
        ))
    } else if path.file_name().is_some_and(|n| n == "metadata.yaml") {
        Err(unrecognised(
            "a rosbag2 metadata file: give the bag's directory".into(),
        ))
    } else {
        Ok(LogFormat::Mcap)
    }
}

/// Whether `dir` holds a file whose name ends in `.extension`.
fn has_extension(dir: &Path, extension: &str) -> bool {
    std::fs::read_dir(dir).is_ok_and(|entries| {
        entries
            .flatten()
            .any(|e| e.path().extension().is_some_and(|x| x == extension))
    })
}

/// The message files of the rosbag2 directory `dir`, from its `metadata.yaml`.
fn rosbag2_files(dir: &Path, metadata: &Path) -> Result<LogFormat, LogError> {
    let unrecognised = |reason: String| LogError::Unrecognised {
        path: metadata.to_path_buf(),
        reason,
    };
    let text = std::fs::read_to_string(metadata).map_err(|source| LogError::Io {
        path: metadata.to_path_buf(),
        source,
    })?;
    let parsed: Rosbag2Metadata = serde_saphyr::from_str(&text).map_err(|e| {
        unrecognised(format!(
            "not a rosbag2 metadata file ({e}); it needs rosbag2_bagfile_information with \
             storage_identifier and relative_file_paths"
        ))
    })?;
    let info = parsed.rosbag2_bagfile_information;
    match info.storage_identifier.as_str() {
        "mcap" | "sqlite3" => {}
        other => {
            return Err(unrecognised(format!(
                "rosbag2 storage `{other}`: skincal reads bags stored as mcap or sqlite3"
            )))
        }
    }
    if info.relative_file_paths.is_empty() {
        return Err(unrecognised("relative_file_paths lists no file".into()));
    }
    let files: Vec<PathBuf> = info
        .relative_file_paths
        .iter()
        .map(|f| dir.join(f))
        .collect();
    if let Some(missing) = files.iter().find(|f| !f.is_file()) {
        return Err(unrecognised(format!(
            "it lists {}, which is not there (a bag copied without all its files?)",
            missing.display()
        )));
    }
    Ok(LogFormat::Rosbag2(files))
}

/// A log to read: a file or directory on disk (any format [`format_of`] recognises), or one held
/// in memory.
#[derive(Debug, Clone, PartialEq)]
pub enum LogSource {
    /// A log on disk.
    File(PathBuf),
    /// A log in memory (e.g. one the simulator just recorded).
    Memory(MemoryLog),
}

impl From<PathBuf> for LogSource {
    fn from(path: PathBuf) -> LogSource {
        LogSource::File(path)
    }
}

impl From<&Path> for LogSource {
    fn from(path: &Path) -> LogSource {
        LogSource::File(path.to_path_buf())
    }
}

impl From<MemoryLog> for LogSource {
    fn from(log: MemoryLog) -> LogSource {
        LogSource::Memory(log)
    }
}

impl LogSource {
    /// The file's path, or the name of the log in memory: what messages call it.
    pub fn path(&self) -> &Path {
        match self {
            LogSource::File(path) => path,
            LogSource::Memory(log) => log.name(),
        }
    }

    /// Its format in words (`mcap`, `csv`, `rosbag2 (3 files)`, `memory`); an error where a file
    /// is in none that is read.
    pub fn format(&self) -> Result<String, LogError> {
        let LogSource::File(path) = self else {
            return Ok("memory".into());
        };
        Ok(match format_of(path)? {
            LogFormat::Mcap => "mcap".into(),
            LogFormat::Csv => "csv".into(),
            LogFormat::Db3 => "rosbag2 sqlite3".into(),
            LogFormat::Bag => "ros1 bag".into(),
            LogFormat::Rosbag2(files) => format!("rosbag2 ({} files)", files.len()),
        })
    }

    /// What a pass over `stream` reads, for progress ([`size_of`] for a file).
    pub fn size(&self, stream: Stream) -> u64 {
        match self {
            LogSource::File(path) => size_of(path, stream),
            LogSource::Memory(log) => log.size(stream),
        }
    }

    /// Streams the samples of `stream` to `visit` ([`read_log`] for a file; a log in memory in
    /// the order it was recorded).
    pub fn read(
        &self,
        stream: Stream,
        topics: &Topics,
        visit: &mut dyn FnMut(Sample<'_>) -> Result<(), LogError>,
        progress: &mut dyn FnMut(u64),
    ) -> Result<PassStats, LogError> {
        match self {
            LogSource::File(path) => read_log(path, stream, topics, visit, progress),
            LogSource::Memory(log) => log.read(stream, visit, progress),
        }
    }
}

/// Size in bytes of what a pass over `path` reads, for progress.
pub fn size_of(path: &Path, stream: Stream) -> u64 {
    let size = |file: &Path| std::fs::metadata(file).map(|m| m.len()).unwrap_or(0);
    match (format_of(path), stream) {
        (Ok(LogFormat::Csv), Stream::Joints) => size(&path.join(csv::JOINTS_FILE)),
        (Ok(LogFormat::Csv), Stream::Imu) => size(&path.join(csv::IMU_FILE)),
        (Ok(LogFormat::Csv), Stream::Both) => {
            size(&path.join(csv::JOINTS_FILE)) + size(&path.join(csv::IMU_FILE))
        }
        (Ok(LogFormat::Rosbag2(files)), _) => files.iter().map(|f| size(f)).sum(),
        _ => size(path),
    }
}

/// Streams the samples of `stream` from the log at `path` to `visit`, in file order; `progress`
/// gets the bytes read so far. Samples that cannot be decoded are counted, not fatal.
pub fn read_log(
    path: &Path,
    stream: Stream,
    topics: &Topics,
    visit: &mut dyn FnMut(Sample<'_>) -> Result<(), LogError>,
    progress: &mut dyn FnMut(u64),
) -> Result<PassStats, LogError> {
    match format_of(path)? {
        LogFormat::Mcap => mcap::read(path, stream, topics, visit, progress),
        LogFormat::Csv => csv::read(path, stream, visit, progress),
        LogFormat::Db3 => db3::read(path, stream, topics, visit, progress),
        LogFormat::Bag => bag::read(path, stream, topics, visit, progress),
        LogFormat::Rosbag2(files) => {
            // One pass over the bag's files in order, as one log.
            let mut stats = PassStats::default();
            let mut done = 0u64;
            for file in &files {
                let mut at = |n| progress(done + n);
                let part = if file.extension().is_some_and(|x| x == "db3") {
                    db3::read(file, stream, topics, visit, &mut at)?
                } else {
                    mcap::read(file, stream, topics, visit, &mut at)?
                };
                done += std::fs::metadata(file).map(|m| m.len()).unwrap_or(0);
                stats.add(part);
            }
            Ok(stats)
        }
    }
}

/// Streams the samples of `stream` from the MCAP log at `path` while it is being written (a
/// rosbag2 recorder's MCAP storage, or any MCAP writer that appends chunks): at its end, waits for
/// more until the file is complete or has not grown for `idle` (see [`mcap::follow`]). Other
/// formats are refused: they cannot be read before they are whole.
pub fn follow_log(
    path: &Path,
    idle: std::time::Duration,
    stream: Stream,
    topics: &Topics,
    visit: &mut dyn FnMut(Sample<'_>) -> Result<(), LogError>,
    progress: &mut dyn FnMut(u64),
) -> Result<PassStats, LogError> {
    // Named as MCAP, or starting as MCAP does (a file just created may hold nothing yet).
    let mut start = [0u8; 8];
    let mcap = path.extension().is_some_and(|e| e == "mcap")
        || std::fs::File::open(path)
            .and_then(|mut f| std::io::Read::read_exact(&mut f, &mut start))
            .is_ok_and(|()| start == *::mcap::MAGIC);
    if !mcap {
        return Err(LogError::Unrecognised {
            path: path.to_path_buf(),
            reason:
                "only an MCAP file can be followed while it is written (a rosbag2 \
                     directory's .mcap file, or one MCAP log); check other logs once they are whole"
                    .into(),
        });
    }
    mcap::follow(path, idle, stream, topics, visit, progress)
}

/// The least any reader must do with the log at `path`: read (and decompress) everything and walk
/// every message (MCAP) or row (CSV), decoding nothing; returns their number. A yardstick for
/// the readers' speed; rosbag2 directories, SQLite files and ROS 1 bags are not measured (`None`).
pub fn bare_pass(path: &Path) -> Result<Option<u64>, LogError> {
    match format_of(path)? {
        LogFormat::Mcap => mcap::bare_pass(path).map(Some),
        LogFormat::Csv => {
            let mut rows = 0u64;
            for name in [csv::JOINTS_FILE, csv::IMU_FILE] {
                let file = path.join(name);
                let io_error = |source| LogError::Io {
                    path: file.clone(),
                    source,
                };
                let mut f = std::fs::File::open(&file).map_err(io_error)?;
                let mut buffer = vec![0u8; 1 << 20];
                loop {
                    let n = std::io::Read::read(&mut f, &mut buffer).map_err(io_error)?;
                    if n == 0 {
                        break;
                    }
                    rows += buffer[..n].iter().filter(|&&b| b == b'\n').count() as u64;
                }
            }
            Ok(Some(rows))
        }
        LogFormat::Db3 | LogFormat::Bag | LogFormat::Rosbag2(_) => Ok(None),
    }
}

/// Files and directories that exist only while an operation runs: staged outputs, spilled
/// sections, scratch directories.
static TRANSIENT: std::sync::Mutex<Vec<PathBuf>> = std::sync::Mutex::new(Vec::new());

/// Records a file or directory that must not outlive the operation that made it.
pub fn hold_transient(path: &Path) {
    if let Ok(mut t) = TRANSIENT.lock() {
        t.push(path.to_path_buf());
    }
}

/// Forgets a transient path again (it was committed or removed).
pub fn release_transient(path: &Path) {
    if let Ok(mut t) = TRANSIENT.lock() {
        if let Some(i) = t.iter().rposition(|p| p == path) {
            t.swap_remove(i);
        }
    }
}

/// A temporary directory held as transient ([`hold_transient`]) while it lives: removed when
/// dropped, or by [`remove_transient`] on a signal. The one kind of scratch directory skincal
/// makes.
#[derive(Debug)]
pub struct TransientDir(tempfile::TempDir);

impl TransientDir {
    /// A new directory named `prefix…` in `parent` (the system's temporary directory when
    /// `None`).
    pub fn new(prefix: &str, parent: Option<&Path>) -> std::io::Result<TransientDir> {
        let mut builder = tempfile::Builder::new();
        builder.prefix(prefix);
        let dir = match parent {
            Some(parent) => builder.tempdir_in(parent)?,
            None => builder.tempdir()?,
        };
        hold_transient(dir.path());
        Ok(TransientDir(dir))
    }

    /// Its path.
    pub fn path(&self) -> &Path {
        self.0.path()
    }
}

impl Drop for TransientDir {
    fn drop(&mut self) {
        release_transient(self.0.path());
    }
}

/// Removes every transient file and directory still held: what a process interrupted by a signal
/// calls before it exits, so that no half-written output is left behind.
pub fn remove_transient() {
    let paths = match TRANSIENT.lock() {
        Ok(mut t) => std::mem::take(&mut *t),
        Err(_) => return,
    };
    for p in paths {
        if p.is_dir() {
            let _ = std::fs::remove_dir_all(&p);
        } else {
            let _ = std::fs::remove_file(&p);
        }
    }
}

/// A temporary file beside `path`, renamed onto it by [`Staged::commit`] and removed if dropped
/// before that (or by [`remove_transient`] on a signal).
#[derive(Debug)]
pub(crate) struct Staged {
    tmp: PathBuf,
    path: PathBuf,
    committed: bool,
    /// The directory it made for `path`, if there was none.
    made_dir: Option<PathBuf>,
}

impl Staged {
    pub(crate) fn create(path: &Path, force: bool) -> Result<(Staged, std::fs::File), LogError> {
        if !force && path.exists() {
            return Err(LogError::Exists {
                path: path.to_path_buf(),
            });
        }
        let dir = path
            .parent()
            .filter(|d| !d.as_os_str().is_empty())
            .unwrap_or(Path::new("."));
        let made_dir = (!dir.exists()).then(|| dir.to_path_buf());
        std::fs::create_dir_all(dir).map_err(|source| LogError::Io {
            path: dir.to_path_buf(),
            source,
        })?;
        if let Some(d) = &made_dir {
            hold_transient(d);
        }
        let name = path
            .file_name()
            .map(|n| n.to_string_lossy().into_owned())
            .unwrap_or_default();
        let tmp = dir.join(format!(".{name}.{}.tmp", std::process::id()));
        let file = std::fs::File::create(&tmp).map_err(|source| LogError::Io {
            path: tmp.clone(),
            source,
        })?;
        hold_transient(&tmp);
        Ok((
            Staged {
                tmp,
                path: path.to_path_buf(),
                committed: false,
                made_dir,
            },
            file,
        ))
    }

    pub(crate) fn commit(&mut self) -> Result<PathBuf, LogError> {
        std::fs::rename(&self.tmp, &self.path).map_err(|source| LogError::Io {
            path: self.path.clone(),
            source,
        })?;
        self.committed = true;
        release_transient(&self.tmp);
        if let Some(d) = &self.made_dir {
            release_transient(d);
        }
        Ok(self.path.clone())
    }

    pub(crate) fn tmp(&self) -> &Path {
        &self.tmp
    }
}

impl Drop for Staged {
    fn drop(&mut self) {
        if !self.committed {
            let _ = std::fs::remove_file(&self.tmp);
            release_transient(&self.tmp);
            if let Some(d) = &self.made_dir {
                // Only if nothing else was put there.
                let _ = std::fs::remove_dir(d);
                release_transient(d);
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn frame_names_give_back_the_text_of_any_bytes_in_any_order() {
        let mut frames = FrameNames::default();
        let names: Vec<String> = (0..50).map(|i| format!("link{}_su{i}", i % 7)).collect();
        // Round after round in the same order, then in another, then some never seen.
        let order = (0..3 * names.len())
            .map(|k| k % names.len())
            .chain((0..names.len()).map(|k| (k * 17) % names.len()));
        for i in order {
            assert_eq!(frames.name(names[i].as_bytes()).unwrap(), names[i]);
        }
        assert_eq!(frames.name("süß".as_bytes()).unwrap(), "süß");
        assert_eq!(frames.name(b"").unwrap(), "");
        assert!(frames.name(&[b's', 0xff, b'u']).is_err());
        // Past the most remembered, names are still right.
        for i in 0..MOST_FRAMES + 10 {
            let name = format!("f{i}");
            assert_eq!(frames.name(name.as_bytes()).unwrap(), name);
        }
        assert_eq!(frames.names.len(), MOST_FRAMES);
    }
}
