//! ROS 2 MCAP logs: writing ([`McapSink`]) and streaming reading ([`read`]).

use std::collections::{BTreeMap, HashMap};
use std::fs::File;
use std::io::{BufWriter, Read};
use std::path::{Path, PathBuf};

use mcap::records::{op, MessageHeader, Record};
use mcap::sans_io::linear_reader::{LinearReadEvent, LinearReader, LinearReaderOptions};

use super::ros::{self, Imu, JointState, Time};
use super::{deliver, ChannelKind, LogError, LogSink, ReadStats, Sample, Staged, Stream, Topics};

/// Chunk compression of a written MCAP file.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub enum Compression {
    /// No compression (fastest to read).
    None,
    /// LZ4.
    Lz4,
    /// Zstandard (what ROS 2 recorders use by default; smallest).
    #[default]
    Zstd,
}

/// Writes a skin log as ROS 2 MCAP: `sensor_msgs/msg/JointState` and `sensor_msgs/msg/Imu`.
pub struct McapSink {
    path: PathBuf,
    force: bool,
    compression: Compression,
    topics: Topics,
    staged: Option<Staged>,
    writer: Option<mcap::Writer<BufWriter<File>>>,
    channels: (u16, u16),
    sequence: (u32, u32),
    dofs: Vec<String>,
    sus: Vec<String>,
    /// Of each accelerometer component's noise, (m/s²)² (0: unknown).
    acceleration_variance: f64,
    /// Every SU of a time step in one `skin_msgs/msg/ImuArray` ([`McapSink::batched`]).
    batch: bool,
    /// The samples of the time step being gathered, and its receive time.
    pending: Vec<Imu>,
    pending_receive: Time,
}

impl McapSink {
    /// A sink that writes `path` (whole, at [`LogSink::finish`]); without `force` an existing
    /// file is an error.
    pub fn new(path: &Path, topics: Topics, compression: Compression, force: bool) -> McapSink {
        McapSink {
            path: path.to_path_buf(),
            force,
            compression,
            topics,
            staged: None,
            writer: None,
            channels: (0, 0),
            sequence: (0, 0),
            dofs: Vec::new(),
            sus: Vec::new(),
            acceleration_variance: 0.0,
            batch: false,
            pending: Vec::new(),
            pending_receive: Time::default(),
        }
    }

    /// The same sink writing every SU of a time step as one `skin_msgs/msg/ImuArray` on the Imu
    /// topic, as skin drivers that read all SUs at once publish them.
    pub fn batched(mut self) -> McapSink {
        self.batch = true;
        self
    }

    /// Writes the gathered time step as one batch.
    fn flush_batch(&mut self) -> Result<(), LogError> {
        if self.pending.is_empty() {
            return Ok(());
        }
        let message = ros::ImuArray {
            header: ros::Header {
                stamp: self.pending_receive,
                frame_id: String::new(),
            },
            imus: std::mem::take(&mut self.pending),
        };
        let data = ros::encode(&message).map_err(|e| LogError::Encode {
            schema: ros::IMU_ARRAY,
            reason: e.to_string(),
        })?;
        self.sequence.1 = self.sequence.1.wrapping_add(1);
        let log_time = self.pending_receive.nanoseconds();
        self.write(self.channels.1, self.sequence.1, log_time, &data)
    }

    fn error(&self, e: mcap::McapError) -> LogError {
        LogError::Mcap {
            path: self.path.clone(),
            reason: e.to_string(),
        }
    }

    fn write(
        &mut self,
        channel: u16,
        sequence: u32,
        log_time: u64,
        data: &[u8],
    ) -> Result<(), LogError> {
        let header = MessageHeader {
            channel_id: channel,
            sequence,
            log_time,
            publish_time: log_time,
        };
        let Some(writer) = self.writer.as_mut() else {
            return Err(LogError::Stopped("MCAP sink used before start".into()));
        };
        writer
            .write_to_known_channel(&header, data)
            .map_err(|e| LogError::Mcap {
                path: self.path.clone(),
                reason: e.to_string(),
            })
    }
}

impl LogSink for McapSink {
    fn start(
        &mut self,
        dofs: &[String],
        sus: &[String],
        acceleration_variance: f64,
    ) -> Result<(), LogError> {
        self.acceleration_variance = acceleration_variance;
        let (staged, file) = Staged::create(&self.path, self.force)?;
        let compression = match self.compression {
            Compression::None => None,
            Compression::Lz4 => Some(mcap::Compression::Lz4),
            Compression::Zstd => Some(mcap::Compression::Zstd),
        };
        let mut writer = mcap::WriteOptions::new()
            .compression(compression)
            .profile("ros2")
            .library(concat!("skincal ", env!("CARGO_PKG_VERSION")))
            .create(BufWriter::with_capacity(1 << 20, file))
            .map_err(|e| self.error(e))?;
        let no_metadata = BTreeMap::new();
        let joints_schema = writer
            .add_schema(
                ros::JOINT_STATE,
                ros::SCHEMA_ENCODING,
                ros::joint_state_schema().as_bytes(),
            )
            .map_err(|e| self.error(e))?;
        let imu_schema = if self.batch {
            writer.add_schema(
                ros::IMU_ARRAY,
                ros::SCHEMA_ENCODING,
                ros::imu_array_schema().as_bytes(),
            )
        } else {
            writer.add_schema(ros::IMU, ros::SCHEMA_ENCODING, ros::imu_schema().as_bytes())
        }
        .map_err(|e| self.error(e))?;
        let joints = writer
            .add_channel(
                joints_schema,
                &self.topics.joints,
                ros::MESSAGE_ENCODING,
                &no_metadata,
            )
            .map_err(|e| self.error(e))?;
        let imu = writer
            .add_channel(
                imu_schema,
                &self.topics.imu,
                ros::MESSAGE_ENCODING,
                &no_metadata,
            )
            .map_err(|e| self.error(e))?;
        self.channels = (joints, imu);
        self.staged = Some(staged);
        self.writer = Some(writer);
        self.dofs = dofs.to_vec();
        self.sus = sus.to_vec();
        Ok(())
    }

    fn joint_state(
        &mut self,
        stamp: Time,
        receive: Time,
        positions: &[f64],
        velocities: &[f64],
    ) -> Result<(), LogError> {
        let message = JointState {
            header: ros::Header {
                stamp,
                frame_id: String::new(),
            },
            name: self.dofs.clone(),
            position: positions.to_vec(),
            velocity: velocities.to_vec(),
            effort: Vec::new(),
        };
        let data = ros::encode(&message).map_err(|e| LogError::Encode {
            schema: ros::JOINT_STATE,
            reason: e.to_string(),
        })?;
        self.sequence.0 = self.sequence.0.wrapping_add(1);
        let log_time = receive.nanoseconds();
        self.write(self.channels.0, self.sequence.0, log_time, &data)
    }

    fn imu(&mut self, stamp: Time, receive: Time, su: usize, a: [f64; 3]) -> Result<(), LogError> {
        let name = self.sus.get(su).map(String::as_str).unwrap_or_default();
        let message = Imu::accelerometer(stamp, name, a, self.acceleration_variance);
        if self.batch {
            if !self.pending.is_empty() && receive != self.pending_receive {
                self.flush_batch()?;
            }
            self.pending_receive = receive;
            self.pending.push(message);
            return Ok(());
        }
        let data = ros::encode(&message).map_err(|e| LogError::Encode {
            schema: ros::IMU,
            reason: e.to_string(),
        })?;
        self.sequence.1 = self.sequence.1.wrapping_add(1);
        let log_time = receive.nanoseconds();
        self.write(self.channels.1, self.sequence.1, log_time, &data)
    }

    fn finish(&mut self) -> Result<Vec<PathBuf>, LogError> {
        self.flush_batch()?;
        let (Some(mut writer), Some(mut staged)) = (self.writer.take(), self.staged.take()) else {
            return Ok(Vec::new());
        };
        writer.finish().map_err(|e| self.error(e))?;
        let mut inner = writer.into_inner();
        std::io::Write::flush(&mut inner).map_err(|source| LogError::Io {
            path: staged.tmp().to_path_buf(),
            source,
        })?;
        drop(inner);
        Ok(vec![staged.commit()?])
    }
}

/// How many times its file size a decompressed chunk may be.
const MAX_INFLATION: u64 = 256;
/// The longest record read, bytes, whatever the file size (ROS 2 writes chunks of a few MB).
const MAX_RECORD: usize = 1 << 30;

/// Streams the samples of `stream` from the MCAP file at `path`.
pub fn read(
    path: &Path,
    stream: Stream,
    topics: &Topics,
    visit: &mut dyn FnMut(Sample<'_>) -> Result<(), LogError>,
    progress: &mut dyn FnMut(u64),
) -> Result<ReadStats, LogError> {
    let io_error = |source| LogError::Io {
        path: path.to_path_buf(),
        source,
    };
    let mut file = File::open(path).map_err(io_error)?;
    let size = file.metadata().map_err(io_error)?.len();
    let mcap_error = |e: mcap::McapError| LogError::Mcap {
        path: path.to_path_buf(),
        reason: damage(&e, size),
    };
    // Lengths come from the file: a damaged one may claim exabytes. No record can be longer than
    // the file, nor a chunk decompress to more than MAX_INFLATION times its size (zstd's best
    // ratio on skin logs is far below).
    let limit = usize::try_from(size.saturating_mul(MAX_INFLATION))
        .unwrap_or(usize::MAX)
        .clamp(1 << 20, MAX_RECORD);
    let mut reader = LinearReader::new_with_options(
        LinearReaderOptions::default().with_record_length_limit(limit),
    );
    let mut schemas: HashMap<u16, String> = HashMap::new();
    let mut channels: HashMap<u16, ChannelKind> = HashMap::new();
    let mut stats = ReadStats::default();
    let mut read_bytes = 0u64;
    let mut since_progress = 0u64;
    while let Some(event) = reader.next_event() {
        match event.map_err(mcap_error)? {
            LinearReadEvent::ReadRequest(need) => {
                let want = need.max(1 << 20);
                let n = file.read(reader.insert(want)).map_err(io_error)?;
                reader.notify_read(n);
                read_bytes += n as u64;
                since_progress += n as u64;
                if since_progress >= 1 << 22 || n == 0 {
                    progress(read_bytes);
                    since_progress = 0;
                }
            }
            LinearReadEvent::Record { opcode, data } => match opcode {
                op::MESSAGE => {
                    let Some((channel, body)) = message_body(data) else {
                        stats.problem("a message record shorter than its header".into());
                        continue;
                    };
                    match channels.get(&channel) {
                        Some(kind) => deliver(kind, body, stream, topics, &mut stats, visit)?,
                        None => stats.problem(format!("a message on unknown channel {channel}")),
                    }
                }
                op::SCHEMA | op::CHANNEL => match lengths_fit(opcode, data)
                    .and_then(|()| mcap::parse_record(opcode, data))
                    .map_err(mcap_error)?
                {
                    Record::Schema { header, .. } => {
                        schemas.insert(header.id, header.name);
                    }
                    Record::Channel(c) => {
                        let schema = schemas.get(&c.schema_id).cloned().unwrap_or_default();
                        let kind = ChannelKind::of(&c.topic, &schema, &c.message_encoding, topics);
                        channels.insert(c.id, kind);
                    }
                    _ => {}
                },
                _ => {}
            },
        }
    }
    progress(read_bytes);
    Ok(stats)
}

/// What a reader error means for the user's file, and what to do.
fn damage(e: &mcap::McapError, size: u64) -> String {
    use mcap::McapError as E;
    let salvage = "copy it again, or salvage its complete part with `mcap recover`";
    match e {
        _ if size == 0 => "the file is empty: was the recording started?".into(),
        _ if size < 8 => format!("{size} bytes are too few for an MCAP file"),
        E::BadMagic => "it does not start with MCAP's magic bytes: give a ROS 2 bag recorded with \
                        `--storage mcap` (or its .mcap file)"
            .into(),
        E::UnexpectedEof => format!(
            "it ends in the middle of a record after {size} bytes: it was cut short (recording \
             interrupted, or an incomplete copy); {salvage}"
        ),
        E::RecordTooLarge { opcode, len } => format!(
            "a record (opcode {opcode:#04x}) claims {len} bytes, more than a {size}-byte file \
             can hold: the file is damaged; {salvage}"
        ),
        E::ChunkTooLarge(len) => format!(
            "a chunk claims {len} bytes, more than a {size}-byte file can hold: the file is \
             damaged; {salvage}"
        ),
        E::BadChunkCrc { .. } | E::BadDataCrc { .. } | E::BadSummaryCrc { .. } => {
            format!("{e}: the file is damaged; {salvage}")
        }
        other => format!("{other}; if the file is damaged, {salvage}"),
    }
}

/// Checks that every length inside a schema or channel record fits in the record before the mcap
/// crate parses it (it allocates a string's claimed length first).
fn lengths_fit(opcode: u8, data: &[u8]) -> Result<(), mcap::McapError> {
    let mut at;
    let bytes = |at: &mut usize, limit: usize| -> Option<()> {
        let field: [u8; 4] = data.get(*at..*at + 4)?.try_into().ok()?;
        let n = u32::from_le_bytes(field) as usize;
        *at += 4;
        (n <= limit.saturating_sub(*at)).then(|| *at += n)
    };
    let fits = match opcode {
        // id u16, name, encoding, data
        op::SCHEMA => {
            at = 2;
            (0..3).try_for_each(|_| bytes(&mut at, data.len()))
        }
        // id u16, schema_id u16, topic, message_encoding, metadata map<string, string>
        op::CHANNEL => {
            at = 4;
            (0..2)
                .try_for_each(|_| bytes(&mut at, data.len()))
                .and_then(|()| {
                    let start = at + 4;
                    bytes(&mut at, data.len())?;
                    let end = at;
                    let mut entry = start;
                    while entry < end {
                        bytes(&mut entry, end)?;
                        bytes(&mut entry, end)?;
                    }
                    Some(())
                })
        }
        _ => Some(()),
    };
    fits.ok_or(mcap::McapError::RecordTooLarge {
        opcode,
        len: data.len() as u64,
    })
}

/// Channel id and CDR payload of a message record (opcode 0x05): `channel_id u16, sequence u32,
/// log_time u64, publish_time u64, data`.
fn message_body(record: &[u8]) -> Option<(u16, &[u8])> {
    const HEADER: usize = 2 + 4 + 8 + 8;
    if record.len() < HEADER {
        return None;
    }
    let channel = u16::from_le_bytes([record[0], record[1]]);
    Some((channel, &record[HEADER..]))
}
