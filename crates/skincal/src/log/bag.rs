//! ROS 1 bags (`.bag`, format 2.0), read with the `rosbag` crate: its chunk records (uncompressed,
//! bz2 or lz4) in file order, the connections inside them naming each topic's type. The two
//! message types ingestion needs are decoded in place from ROS 1's serialization (little-endian,
//! unaligned; a string is its `u32` length and its bytes): `sensor_msgs/Imu` and
//! `sensor_msgs/JointState`.

use std::collections::HashMap;
use std::path::Path;

use rosbag::{ChunkRecord, MessageRecord, RosBag};

use super::{
    usable_positions, LogError, PassStats, Sample, Stream, Topics, NON_FINITE_ACCELERATION,
    NON_FINITE_POSITION,
};

/// ROS 1's name of the Imu type.
const IMU: &str = "sensor_msgs/Imu";
/// ROS 1's name of the JointState type.
const JOINT_STATE: &str = "sensor_msgs/JointState";

/// What a connection carries.
enum Kind {
    Joints,
    Imu,
    Other(String),
    Wrong(String),
}

/// Streams the samples of `stream` from the ROS 1 bag at `path`.
pub fn read(
    path: &Path,
    stream: Stream,
    topics: &Topics,
    visit: &mut dyn FnMut(Sample<'_>) -> Result<(), LogError>,
    progress: &mut dyn FnMut(u64),
) -> Result<PassStats, LogError> {
    let error = |reason: String| bag_error(path, reason);
    check_index(path).map_err(error)?;
    // The rosbag crate slices some record headers without checking their lengths: a damaged bag
    // must be an error, not a crash.
    std::panic::catch_unwind(std::panic::AssertUnwindSafe(|| {
        read_checked(path, stream, topics, visit, progress)
    }))
    .unwrap_or_else(|_| {
        Err(error(
            "a damaged record: copy the bag again, or repair it with `rosbag reindex`".into(),
        ))
    })
}

fn bag_error(path: &Path, reason: String) -> LogError {
    LogError::Bag {
        path: path.to_path_buf(),
        reason,
    }
}

/// Checks the bag header's pointer to the index, which the rosbag crate trusts: a bag cut short
/// or never closed points beyond its end, or nowhere.
fn check_index(path: &Path) -> Result<(), String> {
    let bytes = {
        let mut start = vec![0u8; 4096];
        let n = std::fs::File::open(path)
            .and_then(|mut f| std::io::Read::read(&mut f, &mut start))
            .map_err(|e| e.to_string())?;
        start.truncate(n);
        start
    };
    let size = std::fs::metadata(path).map_err(|e| e.to_string())?.len();
    const MAGIC: &[u8] = b"#ROSBAG V2.0\n";
    let mut c = Cursor {
        bytes: bytes.get(MAGIC.len()..).unwrap_or_default(),
        at: 0,
    };
    let cut = || "its header is cut short: the file is damaged".to_string();
    let header_len = c.u32().ok_or_else(cut)? as usize;
    let header = c.take(header_len).ok_or_else(cut)?;
    let mut fields = Cursor {
        bytes: header,
        at: 0,
    };
    let mut index = None;
    while fields.at < header.len() {
        let field = fields
            .u32()
            .and_then(|n| fields.take(n as usize))
            .ok_or_else(cut)?;
        if let Some(value) = field.strip_prefix(b"index_pos=") {
            index = value.try_into().ok().map(u64::from_le_bytes);
        }
    }
    match index {
        None => Err("its header has no index_pos: not a bag rosbag wrote".into()),
        Some(0) => Err(
            "it has no index (the recording was not closed): run `rosbag reindex FILE.bag`".into(),
        ),
        Some(at) if at > size => Err(format!(
            "its index should start at byte {at}, but the file has {size}: it was cut short (an \
             incomplete copy?); copy it again, or `rosbag reindex` what there is"
        )),
        Some(_) => Ok(()),
    }
}

fn read_checked(
    path: &Path,
    stream: Stream,
    topics: &Topics,
    visit: &mut dyn FnMut(Sample<'_>) -> Result<(), LogError>,
    progress: &mut dyn FnMut(u64),
) -> Result<PassStats, LogError> {
    let error = |reason: String| bag_error(path, reason);
    let bag = RosBag::new(path).map_err(|e| error(format!("{e}")))?;
    let size = std::fs::metadata(path).map_or(0, |m| m.len());
    let chunks = u64::from(bag.get_chunk_count().max(1));
    let mut kinds: HashMap<u32, Kind> = HashMap::new();
    let mut stats = PassStats::default();
    let mut names: Vec<String> = Vec::new();
    let mut positions: Vec<f64> = Vec::new();
    let damaged = |e: rosbag::Error| {
        error(format!(
            "{e}: the bag is damaged or cut short; `rosbag reindex` may repair it"
        ))
    };
    let mut done = 0u64;
    for record in bag.chunk_records() {
        let ChunkRecord::Chunk(chunk) = record.map_err(damaged)? else {
            continue;
        };
        for message in chunk.messages() {
            match message.map_err(damaged)? {
                MessageRecord::Connection(c) => {
                    let kind = if c.topic == topics.joints {
                        expect(c.topic, c.tp, JOINT_STATE, Kind::Joints)
                    } else if c.topic == topics.imu {
                        expect(c.topic, c.tp, IMU, Kind::Imu)
                    } else {
                        Kind::Other(c.topic.to_string())
                    };
                    kinds.insert(c.id, kind);
                }
                MessageRecord::MessageData(m) => match kinds.get(&m.conn_id) {
                    Some(Kind::Imu) if stream.imu() => match imu(m.data) {
                        Some((_, _, a)) if !a.iter().all(|v| v.is_finite()) => stats
                            .imu
                            .problem(format!("{}: {NON_FINITE_ACCELERATION}", topics.imu)),
                        Some((stamp, frame_id, acceleration)) => {
                            stats.imu.samples += 1;
                            visit(Sample::Imu {
                                stamp,
                                frame_id,
                                acceleration,
                            })?;
                        }
                        None => stats
                            .imu
                            .problem(format!("{}: a damaged Imu message", topics.imu)),
                    },
                    Some(Kind::Joints) if stream.joints() => {
                        match joint_state(m.data, &mut names, &mut positions) {
                            Some(_) if !usable_positions(&positions) => {
                                stats
                                    .joints
                                    .problem(format!("{}: {NON_FINITE_POSITION}", topics.joints));
                            }
                            Some(stamp) => {
                                stats.joints.samples += 1;
                                visit(Sample::Joints {
                                    stamp,
                                    names: &names,
                                    positions: &positions,
                                })?;
                            }
                            None => stats.joints.problem(format!(
                                "{}: a damaged JointState message, or one with fewer positions \
                                 than names",
                                topics.joints
                            )),
                        }
                    }
                    Some(Kind::Other(topic)) if stream.joints() => {
                        *stats.joints.other_topics.entry(topic.clone()).or_default() += 1;
                    }
                    Some(Kind::Wrong(why)) if stream.joints() => stats.joints.problem(why.clone()),
                    None if stream.joints() => stats.joints.problem(format!(
                        "a message on connection {} that no connection record describes",
                        m.conn_id
                    )),
                    _ => {}
                },
            }
        }
        done += 1;
        progress(size * done / chunks);
    }
    Ok(stats)
}

/// The kind of one of our topics that carries `found`.
fn expect(topic: &str, found: &str, wanted: &str, kind: Kind) -> Kind {
    if found == wanted {
        kind
    } else {
        Kind::Wrong(format!(
            "topic {topic} carries `{found}`; expected `{wanted}` (choose the topics with \
             --joint-topic/--imu-topic)"
        ))
    }
}

/// Reads ROS 1's serialization in place.
struct Cursor<'a> {
    bytes: &'a [u8],
    at: usize,
}

impl<'a> Cursor<'a> {
    fn take(&mut self, n: usize) -> Option<&'a [u8]> {
        let b = self.bytes.get(self.at..self.at.checked_add(n)?)?;
        self.at += n;
        Some(b)
    }

    fn u32(&mut self) -> Option<u32> {
        Some(u32::from_le_bytes(self.take(4)?.try_into().ok()?))
    }

    fn f64(&mut self) -> Option<f64> {
        Some(f64::from_le_bytes(self.take(8)?.try_into().ok()?))
    }

    fn string(&mut self) -> Option<&'a str> {
        let n = self.u32()? as usize;
        std::str::from_utf8(self.take(n)?).ok()
    }

    /// `std_msgs/Header` (seq, stamp secs and nsecs, frame_id): the stamp in seconds and the
    /// frame id.
    fn header(&mut self) -> Option<(f64, &'a str)> {
        let _seq = self.u32()?;
        let (secs, nsecs) = (self.u32()?, self.u32()?);
        Some((f64::from(secs) + f64::from(nsecs) * 1e-9, self.string()?))
    }
}

/// A `sensor_msgs/Imu`: stamp, frame id and linear acceleration.
fn imu(bytes: &[u8]) -> Option<(f64, &str, [f64; 3])> {
    let mut c = Cursor { bytes, at: 0 };
    let (stamp, frame) = c.header()?;
    // Orientation (4), its covariance (9), angular velocity (3) and its covariance (9).
    c.take(8 * (4 + 9 + 3 + 9))?;
    Some((stamp, frame, [c.f64()?, c.f64()?, c.f64()?]))
}

/// A `sensor_msgs/JointState`'s stamp, its names and positions into `names` and `positions`.
fn joint_state(bytes: &[u8], names: &mut Vec<String>, positions: &mut Vec<f64>) -> Option<f64> {
    let mut c = Cursor { bytes, at: 0 };
    let (stamp, _) = c.header()?;
    let n = c.u32()? as usize;
    // Every name takes at least its 4-byte length: a damaged count cannot make us allocate.
    if n > bytes.len() / 4 {
        return None;
    }
    names.clear();
    for _ in 0..n {
        names.push(c.string()?.to_string());
    }
    let m = c.u32()? as usize;
    if m != n {
        return None;
    }
    positions.clear();
    for _ in 0..m {
        positions.push(c.f64()?);
    }
    Some(stamp)
}
