//! ROS 2 MCAP logs: writing ([`McapSink`]) and streaming reading ([`read`], in `read.rs`).

mod read;

pub use read::{bare_pass, follow, read};

use std::collections::BTreeMap;
use std::fs::File;
use std::io::BufWriter;
use std::path::{Path, PathBuf};

use mcap::records::MessageHeader;

use super::ros::{self, Imu, JointState, Time};
use super::{LogError, LogSink, Staged, Topics};

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

/// A ROS 2 MCAP file in memory with one channel, `topic`, of `schema` (`ros2msg` text, type
/// `schema_name`) and the CDR `messages` at their log times (ns); zstd chunks.
pub fn one_channel(
    topic: &str,
    schema_name: &str,
    schema: &str,
    messages: &[(u64, Vec<u8>)],
) -> Result<Vec<u8>, mcap::McapError> {
    let mut writer = mcap::WriteOptions::new()
        .compression(Some(mcap::Compression::Zstd))
        .profile("ros2")
        .library(concat!("skincal ", env!("CARGO_PKG_VERSION")))
        .create(std::io::Cursor::new(Vec::new()))?;
    let id = writer.add_schema(schema_name, ros::SCHEMA_ENCODING, schema.as_bytes())?;
    let channel = writer.add_channel(id, topic, ros::MESSAGE_ENCODING, &BTreeMap::new())?;
    for (sequence, (log_time, data)) in messages.iter().enumerate() {
        let header = MessageHeader {
            channel_id: channel,
            sequence: sequence as u32,
            log_time: *log_time,
            publish_time: *log_time,
        };
        writer.write_to_known_channel(&header, data)?;
    }
    writer.finish()?;
    Ok(writer.into_inner().into_inner())
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
    /// The message being written, encoded (one buffer for them all).
    encoded: Vec<u8>,
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
            encoded: Vec::new(),
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
        self.sequence.1 = self.sequence.1.wrapping_add(1);
        let log_time = self.pending_receive.nanoseconds();
        self.write(
            self.channels.1,
            self.sequence.1,
            log_time,
            ros::IMU_ARRAY,
            &message,
        )
    }

    fn error(&self, e: mcap::McapError) -> LogError {
        LogError::Mcap {
            path: self.path.clone(),
            reason: e.to_string(),
        }
    }

    /// Writes `message` (a message of `schema`) on `channel`.
    fn write<T: serde::Serialize>(
        &mut self,
        channel: u16,
        sequence: u32,
        log_time: u64,
        schema: &'static str,
        message: &T,
    ) -> Result<(), LogError> {
        ros::encode_into(message, &mut self.encoded).map_err(|e| LogError::Encode {
            schema,
            reason: e.to_string(),
        })?;
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
            .write_to_known_channel(&header, &self.encoded)
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
        // One thread: a log is written message by message, and zstd's worker threads would
        // take a lock for every one of them (a tenth of the time spent writing). zstd's fastest
        // level: a skin's noisy samples compress to the same size at level 3 (TALOS's 82.7 s
        // log: 455.1 MB against 455.7), which took 6 % more of the recording's time.
        let mut writer = mcap::WriteOptions::new()
            .compression(compression)
            .compression_threads(0)
            .compression_level(1)
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
        self.sequence.0 = self.sequence.0.wrapping_add(1);
        let log_time = receive.nanoseconds();
        self.write(
            self.channels.0,
            self.sequence.0,
            log_time,
            ros::JOINT_STATE,
            &message,
        )
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
        self.sequence.1 = self.sequence.1.wrapping_add(1);
        let log_time = receive.nanoseconds();
        self.write(
            self.channels.1,
            self.sequence.1,
            log_time,
            ros::IMU,
            &message,
        )
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
