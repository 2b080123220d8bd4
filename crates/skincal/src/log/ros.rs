//! The ROS 2 messages of a skin log, CDR-encoded with the standard schemas.
//!
//! * `sensor_msgs/msg/JointState` on the joint topic: `name` = DoF names, `position` in rad,
//!   `velocity` in rad/s (may be empty), `effort` (ignored).
//! * `sensor_msgs/msg/Imu` on the skin topic, one message per SU sample: `header.frame_id` = SU
//!   name, `linear_acceleration` in m/s² (the specific force, +9.81 up at rest), orientation unknown
//!   (`orientation_covariance[0] = −1`), angular velocity unknown (`angular_velocity_covariance[0] =
//!   −1`).
//!
//! The schema texts are the `ros2msg` definitions with their dependencies appended, as ROS 2
//! bag recorders write them.

use serde::{Deserialize, Serialize};

/// Schema name of the joint states.
pub const JOINT_STATE: &str = "sensor_msgs/msg/JointState";
/// Schema name of the accelerometer samples.
pub const IMU: &str = "sensor_msgs/msg/Imu";
/// Type name of skincal's batch of Imu samples (every SU of one time step in one message).
pub const IMU_ARRAY: &str = "skin_msgs/msg/ImuArray";
/// Schema encoding.
pub const SCHEMA_ENCODING: &str = "ros2msg";
/// Message encoding.
pub const MESSAGE_ENCODING: &str = "cdr";

const SEPARATOR: &str =
    "================================================================================\n";

const HEADER_MSG: &str = "builtin_interfaces/Time stamp\nstring frame_id\n";
const TIME_MSG: &str = "int32 sec\nuint32 nanosec\n";

/// The `ros2msg` schema of `sensor_msgs/msg/JointState`.
pub fn joint_state_schema() -> String {
    format!(
        "std_msgs/Header header\nstring[] name\nfloat64[] position\nfloat64[] velocity\n\
         float64[] effort\n{SEPARATOR}MSG: std_msgs/Header\n{HEADER_MSG}{SEPARATOR}\
         MSG: builtin_interfaces/Time\n{TIME_MSG}"
    )
}

/// The `ros2msg` schema of `sensor_msgs/msg/Imu`.
pub fn imu_schema() -> String {
    format!(
        "std_msgs/Header header\ngeometry_msgs/Quaternion orientation\n\
         float64[9] orientation_covariance\ngeometry_msgs/Vector3 angular_velocity\n\
         float64[9] angular_velocity_covariance\ngeometry_msgs/Vector3 linear_acceleration\n\
         float64[9] linear_acceleration_covariance\n{SEPARATOR}MSG: std_msgs/Header\n{HEADER_MSG}\
         {SEPARATOR}MSG: builtin_interfaces/Time\n{TIME_MSG}{SEPARATOR}\
         MSG: geometry_msgs/Quaternion\nfloat64 x 0\nfloat64 y 0\nfloat64 z 0\nfloat64 w 1\n\
         {SEPARATOR}MSG: geometry_msgs/Vector3\nfloat64 x\nfloat64 y\nfloat64 z\n"
    )
}

/// The `ros2msg` schema of `skin_msgs/msg/ImuArray`: a header (the time step) and one
/// `sensor_msgs/Imu` per SU, each with its own stamp and `frame_id` = SU name.
pub fn imu_array_schema() -> String {
    let imu = imu_schema();
    let (imu_fields, nested) = imu.split_once(SEPARATOR).unwrap_or((imu.as_str(), ""));
    format!(
        "std_msgs/Header header\nsensor_msgs/Imu[] imus\n{SEPARATOR}MSG: sensor_msgs/Imu\n\
         {imu_fields}{SEPARATOR}{nested}"
    )
}

/// Type name of a planned trajectory.
pub const JOINT_TRAJECTORY: &str = "trajectory_msgs/msg/JointTrajectory";

/// The `ros2msg` schema of `trajectory_msgs/msg/JointTrajectory`.
pub fn joint_trajectory_schema() -> String {
    format!(
        "std_msgs/Header header\nstring[] joint_names\nJointTrajectoryPoint[] points\n\
         {SEPARATOR}MSG: std_msgs/Header\n{HEADER_MSG}{SEPARATOR}MSG: builtin_interfaces/Time\n\
         {TIME_MSG}{SEPARATOR}MSG: trajectory_msgs/JointTrajectoryPoint\nfloat64[] positions\n\
         float64[] velocities\nfloat64[] accelerations\nfloat64[] effort\n\
         builtin_interfaces/Duration time_from_start\n{SEPARATOR}\
         MSG: builtin_interfaces/Duration\n{TIME_MSG}"
    )
}

/// `builtin_interfaces/Time`.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, Serialize, Deserialize)]
pub struct Time {
    /// Whole seconds.
    pub sec: i32,
    /// Nanoseconds, `0..1e9`.
    pub nanosec: u32,
}

impl Time {
    /// The time `seconds` (rounded to the nanosecond).
    pub fn from_seconds(seconds: f64) -> Time {
        let total = (seconds * 1e9).round() as i64;
        Time {
            sec: total.div_euclid(1_000_000_000) as i32,
            nanosec: total.rem_euclid(1_000_000_000) as u32,
        }
    }

    /// The time `nanoseconds` after the epoch, exactly.
    pub fn from_nanoseconds(nanoseconds: i64) -> Time {
        Time {
            sec: nanoseconds.div_euclid(1_000_000_000) as i32,
            nanosec: nanoseconds.rem_euclid(1_000_000_000) as u32,
        }
    }

    /// Seconds.
    pub fn seconds(&self) -> f64 {
        f64::from(self.sec) + f64::from(self.nanosec) * 1e-9
    }

    /// Nanoseconds since the epoch (negative times clamp to 0), as MCAP log times.
    pub fn nanoseconds(&self) -> u64 {
        (i64::from(self.sec) * 1_000_000_000 + i64::from(self.nanosec)).max(0) as u64
    }
}

/// `std_msgs/Header`.
#[derive(Debug, Clone, PartialEq, Default, Serialize, Deserialize)]
pub struct Header {
    /// Time of the sample.
    pub stamp: Time,
    /// Frame of the data (the SU name for skin samples).
    pub frame_id: String,
}

/// `geometry_msgs/Quaternion`.
#[derive(Debug, Clone, Copy, PartialEq, Default, Serialize, Deserialize)]
pub struct Quaternion {
    /// x.
    pub x: f64,
    /// y.
    pub y: f64,
    /// z.
    pub z: f64,
    /// w.
    pub w: f64,
}

/// `geometry_msgs/Vector3`.
#[derive(Debug, Clone, Copy, PartialEq, Default, Serialize, Deserialize)]
pub struct Vector3 {
    /// x.
    pub x: f64,
    /// y.
    pub y: f64,
    /// z.
    pub z: f64,
}

/// `sensor_msgs/msg/Imu`.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Imu {
    /// Stamp and SU name.
    pub header: Header,
    /// Unknown for skin (`covariance[0] = −1`).
    pub orientation: Quaternion,
    /// Row-major 3×3.
    pub orientation_covariance: [f64; 9],
    /// rad/s; unknown for skin.
    pub angular_velocity: Vector3,
    /// Row-major 3×3.
    pub angular_velocity_covariance: [f64; 9],
    /// m/s².
    pub linear_acceleration: Vector3,
    /// Row-major 3×3, (m/s²)²; all zero = unknown.
    pub linear_acceleration_covariance: [f64; 9],
}

impl Imu {
    /// An accelerometer-only sample of SU `frame_id`; `variance`: of each component's noise,
    /// (m/s²)², independent between components (0: unknown).
    pub fn accelerometer(stamp: Time, frame_id: &str, a: [f64; 3], variance: f64) -> Imu {
        let mut covariance = [0.0; 9];
        for i in 0..3 {
            covariance[4 * i] = variance;
        }
        let mut unknown = [0.0; 9];
        unknown[0] = -1.0;
        Imu {
            header: Header {
                stamp,
                frame_id: frame_id.to_string(),
            },
            orientation: Quaternion::default(),
            orientation_covariance: unknown,
            angular_velocity: Vector3::default(),
            angular_velocity_covariance: unknown,
            linear_acceleration: Vector3 {
                x: a[0],
                y: a[1],
                z: a[2],
            },
            linear_acceleration_covariance: covariance,
        }
    }
}

/// `skin_msgs/msg/ImuArray`: the samples of every SU at one time step.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct ImuArray {
    /// The time step (receive time) and an empty frame.
    pub header: Header,
    /// One sample per SU.
    pub imus: Vec<Imu>,
}

/// The part of `sensor_msgs/msg/Imu` the ingestion needs: everything up to the linear acceleration
/// (CDR is read in order; the last covariance is not decoded).
#[derive(Debug, Clone, PartialEq, Deserialize)]
pub struct ImuAcceleration {
    /// Stamp and SU name.
    pub header: Header,
    /// Unused.
    pub orientation: Quaternion,
    /// Unused.
    pub orientation_covariance: [f64; 9],
    /// Unused.
    pub angular_velocity: Vector3,
    /// Unused.
    pub angular_velocity_covariance: [f64; 9],
    /// m/s².
    pub linear_acceleration: Vector3,
}

/// `sensor_msgs/msg/JointState`.
#[derive(Debug, Clone, PartialEq, Default, Serialize, Deserialize)]
pub struct JointState {
    /// Stamp.
    pub header: Header,
    /// DoF names.
    pub name: Vec<String>,
    /// rad.
    pub position: Vec<f64>,
    /// rad/s, or empty.
    pub velocity: Vec<f64>,
    /// N·m, or empty.
    pub effort: Vec<f64>,
}

/// `trajectory_msgs/msg/JointTrajectoryPoint`.
#[derive(Debug, Clone, PartialEq, Default, Serialize, Deserialize)]
pub struct JointTrajectoryPoint {
    /// rad.
    pub positions: Vec<f64>,
    /// rad/s.
    pub velocities: Vec<f64>,
    /// rad/s².
    pub accelerations: Vec<f64>,
    /// N·m, or empty.
    pub effort: Vec<f64>,
    /// `builtin_interfaces/Duration` (the same fields as a time).
    pub time_from_start: Time,
}

/// `trajectory_msgs/msg/JointTrajectory`.
#[derive(Debug, Clone, PartialEq, Default, Serialize, Deserialize)]
pub struct JointTrajectory {
    /// A zero stamp: start on arrival.
    pub header: Header,
    /// The joints, in the order of every point's values.
    pub joint_names: Vec<String>,
    /// The knots.
    pub points: Vec<JointTrajectoryPoint>,
}

/// CDR (little-endian, with the encapsulation header) of a message.
pub fn encode<T: Serialize>(message: &T) -> Result<Vec<u8>, cdr::Error> {
    let mut bytes = Vec::new();
    encode_into(message, &mut bytes)?;
    Ok(bytes)
}

/// [`encode`] into `bytes` (cleared first): a writer of many messages reuses one buffer, and
/// the message is serialised once, without a pass that sizes it first.
pub fn encode_into<T: Serialize>(message: &T, bytes: &mut Vec<u8>) -> Result<(), cdr::Error> {
    bytes.clear();
    cdr::serialize_into::<_, _, _, cdr::CdrLe>(bytes, message, cdr::Infinite)
}

/// A message from CDR with the encapsulation header (either byte order). Trusted input only:
/// the decoder allocates whatever a string's length field claims; logs are read with
/// [`decode_imu`] and [`decode_joint_state`].
pub fn decode<'de, T: Deserialize<'de>>(bytes: &[u8]) -> Result<T, cdr::Error> {
    cdr::deserialize(bytes)
}

/// A `sensor_msgs/msg/Imu` sample from a log, its lengths checked against the message first.
pub fn decode_imu(bytes: &[u8]) -> Result<ImuAcceleration, cdr::Error> {
    lengths_fit(bytes, false)?;
    cdr::deserialize(bytes)
}

/// An Imu's stamp, frame id and linear acceleration, read in place from its CDR bytes: the hot
/// path of ingestion, which allocates nothing (a million samples a second go through it).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct ImuView<'a> {
    /// The header's stamp.
    pub stamp: Time,
    /// The header's frame id (the SU).
    pub frame_id: &'a str,
    /// m/s².
    pub linear_acceleration: [f64; 3],
}

/// [`ImuView`] of a `sensor_msgs/msg/Imu` in CDR (either byte order); what does not fit in the
/// bytes is an error, as with [`decode_imu`].
pub fn imu_view(bytes: &[u8]) -> Result<ImuView<'_>, cdr::Error> {
    let fields = imu_fields(bytes)?;
    let frame_id = std::str::from_utf8(&bytes[fields.frame.0 as usize..fields.frame.1 as usize])
        .map_err(utf8_error)?;
    Ok(ImuView {
        stamp: fields.stamp,
        frame_id,
        linear_acceleration: fields.linear_acceleration,
    })
}

/// The error of a frame id that is not UTF-8.
pub fn utf8_error(e: std::str::Utf8Error) -> cdr::Error {
    cdr::Error::Message(e.to_string())
}

/// What [`imu_view`] reads, with the frame id as a byte range of the message, not yet checked to
/// be UTF-8 (a reader checks each frame id once, not in every message).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct ImuFields {
    /// The header's stamp.
    pub stamp: Time,
    /// The frame id's bytes in the message, `[from, to)`, without the terminating NUL.
    pub frame: (u32, u32),
    /// m/s².
    pub linear_acceleration: [f64; 3],
}

/// The [`ImuFields`] of a `sensor_msgs/msg/Imu` in CDR; what does not fit in the bytes is an
/// error.
pub fn imu_fields(bytes: &[u8]) -> Result<ImuFields, cdr::Error> {
    let (body, little) = cdr_body(bytes)?;
    imu_at(body, little, 0).map(|(fields, _)| fields)
}

/// The [`ImuFields`] of every Imu of a `skin_msgs/msg/ImuArray` in CDR (a header, then the
/// sequence of Imu messages); a string or sequence that claims more than the message holds, or an
/// Imu cut short, is an error.
pub fn imu_array_fields(bytes: &[u8]) -> Result<Vec<ImuFields>, cdr::Error> {
    let (body, little) = cdr_body(bytes)?;
    // The batch's header: its stamp (sec, nanosec), then its frame id.
    let mut at = 8;
    let n = length(body, little, &mut at)?;
    if n > body.len().saturating_sub(at) {
        return Err(too_long());
    }
    at += n;
    let count = length(body, little, &mut at)?;
    if count > body.len().saturating_sub(at) / SMALLEST_IMU {
        return Err(too_long());
    }
    let mut imus = Vec::with_capacity(count);
    for _ in 0..count {
        let (fields, end) = imu_at(body, little, at)?;
        if end > body.len() {
            return Err(too_long());
        }
        imus.push(fields);
        at = end;
    }
    Ok(imus)
}

/// The fewest bytes an Imu takes in CDR: its stamp, its frame id's length and 37 f64 (orientation
/// 4, angular velocity and linear acceleration 3 each, three covariances of 9).
const SMALLEST_IMU: usize = 12 + 8 * 37;

/// The body of a CDR message (after its 4-byte encapsulation) and whether it is little-endian.
fn cdr_body(bytes: &[u8]) -> Result<(&[u8], bool), cdr::Error> {
    let (Some(&[_, kind, _, _]), Some(body)) = (bytes.first_chunk::<4>(), bytes.get(4..)) else {
        return Err(cdr::Error::InvalidEncapsulation);
    };
    Ok((body, kind & 1 == 1))
}

/// The [`ImuFields`] of the Imu at `at` in a CDR body (aligned from the body's start; byte
/// ranges of the whole message, encapsulation included) and where the Imu ends, which may be
/// beyond the body: only the fields read must be in it.
fn imu_at(body: &[u8], little: bool, at: usize) -> Result<(ImuFields, usize), cdr::Error> {
    let word = |w: &[u8; 4]| {
        if little {
            u32::from_le_bytes(*w)
        } else {
            u32::from_be_bytes(*w)
        }
    };
    // The stamp (sec, nanosec) and the frame id's length, then its text (the length counts the
    // terminating NUL); then orientation (4), its covariance (9), angular velocity (3) and its
    // covariance (9), all f64 and the first 8-aligned; then the linear acceleration (3 f64) and
    // its covariance (9).
    let at = at.next_multiple_of(4);
    let Some(head) = body.get(at..).and_then(<[u8]>::first_chunk::<12>) else {
        return Err(too_long());
    };
    let [sec, nanosec, n] = [0, 4, 8].map(|k| word(head[k..k + 4].try_into().expect("4")));
    let text = at + 12;
    let text_end = text.saturating_add(n as usize);
    let acceleration = text_end
        .next_multiple_of(8)
        .saturating_add(8 * (4 + 9 + 3 + 9));
    let Some(a) = body.get(acceleration..).and_then(<[u8]>::first_chunk::<24>) else {
        return Err(too_long());
    };
    // Within the body: it ends before the acceleration.
    let nul = usize::from(body[text..text_end].last() == Some(&0));
    let offset = |i: usize| u32::try_from(4 + i).map_err(|_| too_long());
    let frame = (offset(text)?, offset(text_end - nul)?);
    let float = |k: usize| {
        let b: [u8; 8] = a[k..k + 8].try_into().expect("8 bytes");
        if little {
            f64::from_le_bytes(b)
        } else {
            f64::from_be_bytes(b)
        }
    };
    let fields = ImuFields {
        stamp: Time {
            sec: sec as i32,
            nanosec,
        },
        frame,
        linear_acceleration: [float(0), float(8), float(16)],
    };
    Ok((fields, acceleration + 8 * (3 + 9)))
}

/// A `skin_msgs/msg/ImuArray` from a log; no string or sequence may claim more bytes than the
/// message has (a damaged log may claim gigabytes).
pub fn decode_imu_array(bytes: &[u8]) -> Result<ImuArray, cdr::Error> {
    imu_array_fields(bytes)?;
    cdr::deserialize_from(bytes, cdr::Bounded(bytes.len() as u64))
}

/// A `sensor_msgs/msg/JointState` from a log, its lengths checked against the message first.
pub fn decode_joint_state(bytes: &[u8]) -> Result<JointState, cdr::Error> {
    lengths_fit(bytes, true)?;
    cdr::deserialize(bytes)
}

/// Walks the strings and sequences of a message (the header's `frame_id`, and a JointState's
/// `name`, `position`, `velocity` and `effort`) and checks that every length field fits in what is
/// left of the message: a damaged log may claim gigabytes.
fn lengths_fit(bytes: &[u8], joint_state: bool) -> Result<(), cdr::Error> {
    let (Some(encapsulation), Some(body)) = (bytes.get(..4), bytes.get(4..)) else {
        return Err(cdr::Error::InvalidEncapsulation);
    };
    let little = encapsulation[1] & 1 == 1;
    let string = |at: &mut usize| -> Result<(), cdr::Error> {
        let n = length(body, little, at)?;
        if n > body.len().saturating_sub(*at) {
            return Err(too_long());
        }
        *at += n;
        Ok(())
    };
    // Offsets are aligned relative to the body; the stamp (sec, nanosec) comes first.
    let mut at = 8usize;
    string(&mut at)?;
    if joint_state {
        let n = length(body, little, &mut at)?;
        // Every name takes at least its 4-byte length.
        if n > body.len().saturating_sub(at) / 4 {
            return Err(too_long());
        }
        for _ in 0..n {
            string(&mut at)?;
        }
        // Positions, velocities and efforts: f64, 8-aligned after their length.
        for _ in 0..3 {
            let n = length(body, little, &mut at)?;
            if n > 0 {
                at = at.next_multiple_of(8);
                if n > body.len().saturating_sub(at) / 8 {
                    return Err(too_long());
                }
                at += 8 * n;
            }
        }
    }
    Ok(())
}

fn too_long() -> cdr::Error {
    cdr::Error::Message("a string or sequence is longer than the message".into())
}

/// The 4-aligned `u32` length field at `at`, which moves past it.
fn length(body: &[u8], little: bool, at: &mut usize) -> Result<usize, cdr::Error> {
    *at = at.next_multiple_of(4);
    let field: [u8; 4] = body
        .get(*at..*at + 4)
        .and_then(|b| b.try_into().ok())
        .ok_or_else(too_long)?;
    *at += 4;
    Ok(if little {
        u32::from_le_bytes(field)
    } else {
        u32::from_be_bytes(field)
    } as usize)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_in_place_imu_reader_reads_what_the_cdr_crate_decodes_in_either_byte_order() {
        for (i, name) in ["su7", "", "left_forearm/su_12", "ü"].iter().enumerate() {
            let imu = Imu::accelerometer(
                Time::from_seconds(1.7e9 + i as f64 * 0.001),
                name,
                [0.1 * i as f64, -0.2, 9.81],
                0.0032,
            );
            let le = encode(&imu).unwrap();
            let be = cdr::serialize::<_, _, cdr::CdrBe>(&imu, cdr::Infinite).unwrap();
            for bytes in [&le, &be] {
                let full = decode_imu(bytes).unwrap();
                let view = imu_view(bytes).unwrap();
                assert_eq!(view.stamp, full.header.stamp);
                assert_eq!(view.frame_id, full.header.frame_id);
                let a = full.linear_acceleration;
                assert_eq!(view.linear_acceleration, [a.x, a.y, a.z]);
            }
            // Cut anywhere before the acceleration's end: an error, never a panic.
            let end = le.len() - 72;
            for cut in 0..end {
                assert!(imu_view(&le[..cut]).is_err(), "cut at {cut}");
            }
        }
    }

    #[test]
    fn damaged_length_fields_are_refused_before_decoding() {
        let imu = Imu::accelerometer(Time::from_seconds(12.5), "su7", [0.1, -0.2, 9.81], 0.0032);
        let joints = JointState {
            header: Header {
                stamp: Time::from_seconds(3.0),
                frame_id: String::new(),
            },
            name: vec!["shoulder".into(), "elbow".into()],
            position: vec![0.5, -1.0],
            velocity: vec![],
            effort: vec![],
        };
        let (imu_cdr, joints_cdr) = (encode(&imu).unwrap(), encode(&joints).unwrap());
        assert_eq!(decode_imu(&imu_cdr).unwrap().header.frame_id, "su7");
        assert_eq!(decode_joint_state(&joints_cdr).unwrap(), joints);
        // frame_id's length sits after the encapsulation (4) and the stamp (8): claim 3 GB.
        let mut bad = imu_cdr.clone();
        bad[12..16].copy_from_slice(&3_000_000_000u32.to_le_bytes());
        assert!(decode_imu(&bad).is_err());
        // The length of the second name: after header (4 + 8 + 4 + 1 → 20), count (4),
        // "shoulder\0" (4 + 9 → 37), aligned to 40.
        let mut bad = joints_cdr.clone();
        assert_eq!(
            &bad[40..44],
            &6u32.to_le_bytes(),
            "\"elbow\\0\" is where it should be"
        );
        bad[40..44].copy_from_slice(&u32::MAX.to_le_bytes());
        assert!(decode_joint_state(&bad).is_err());
        // The count of positions: after "elbow\0" (44 + 6 → 50), aligned to 52; it claims
        // 2^32 - 1 f64 (32 GB).
        let mut bad = joints_cdr.clone();
        assert_eq!(&bad[52..56], &2u32.to_le_bytes(), "two positions");
        bad[52..56].copy_from_slice(&u32::MAX.to_le_bytes());
        assert!(lengths_fit(&bad, true).is_err());
        assert!(decode_joint_state(&bad).is_err());
        // The empty velocities' count: after the positions (aligned to 60, 16 bytes).
        let mut bad = joints_cdr.clone();
        assert_eq!(&bad[76..80], &0u32.to_le_bytes(), "no velocities");
        bad[76..80].copy_from_slice(&1_000_000u32.to_le_bytes());
        assert!(lengths_fit(&bad, true).is_err());
        assert!(lengths_fit(&joints_cdr, true).is_ok());
        assert!(decode_imu(&imu_cdr[..10]).is_err());
        // A batch whose Imu count claims 3 billion samples, and one whose second frame_id claims
        // 3 GB: refused, nothing that size allocated.
        let batch = ImuArray {
            header: Header::default(),
            imus: vec![imu.clone(), imu.clone()],
        };
        let batch_cdr = encode(&batch).unwrap();
        assert_eq!(decode_imu_array(&batch_cdr).unwrap(), batch);
        // The count follows the encapsulation (4), the stamp (8) and the empty frame_id (4 + 1,
        // aligned to 4 → 20).
        assert_eq!(&batch_cdr[20..24], &2u32.to_le_bytes());
        let mut bad = batch_cdr.clone();
        bad[20..24].copy_from_slice(&3_000_000_000u32.to_le_bytes());
        assert!(decode_imu_array(&bad).is_err());
        let second = 24 + (batch_cdr.len() - 24) / 2;
        let mut bad = batch_cdr.clone();
        bad[second + 8..second + 12].copy_from_slice(&3_000_000_000u32.to_le_bytes());
        assert!(decode_imu_array(&bad).is_err());
        assert!(imu_array_fields(&bad).is_err());
        // The second Imu cut short in its last covariance.
        assert!(imu_array_fields(&batch_cdr[..batch_cdr.len() - 8]).is_err());
        assert!(imu_array_fields(&batch_cdr[..20]).is_err());
    }

    #[test]
    fn the_in_place_batch_reader_reads_what_the_cdr_crate_decodes_in_either_byte_order() {
        // Frame ids of every length modulo 8 shift the alignment of what follows each.
        let names = [
            "",
            "a",
            "su",
            "su7",
            "su_12",
            "ü/su_1",
            "arm/su7",
            "left_forearm/su_12",
        ];
        let imus: Vec<Imu> = names
            .iter()
            .enumerate()
            .map(|(i, name)| {
                let stamp = Time::from_seconds(1.7e9 + i as f64 * 1e-4);
                Imu::accelerometer(stamp, name, [0.1 * i as f64, -0.2, 9.81 - i as f64], 1e-4)
            })
            .collect();
        for header in ["", "skin"] {
            let batch = ImuArray {
                header: Header {
                    stamp: Time::from_seconds(1.7e9),
                    frame_id: header.into(),
                },
                imus: imus.clone(),
            };
            let le = encode(&batch).unwrap();
            let be = cdr::serialize::<_, _, cdr::CdrBe>(&batch, cdr::Infinite).unwrap();
            for bytes in [&le, &be] {
                let fields = imu_array_fields(bytes).unwrap();
                assert_eq!(fields.len(), imus.len());
                for (f, imu) in fields.iter().zip(&imus) {
                    assert_eq!(f.stamp, imu.header.stamp);
                    let frame = &bytes[f.frame.0 as usize..f.frame.1 as usize];
                    assert_eq!(frame, imu.header.frame_id.as_bytes());
                    let a = &imu.linear_acceleration;
                    assert_eq!(f.linear_acceleration, [a.x, a.y, a.z]);
                }
            }
        }
        let empty = ImuArray {
            header: Header::default(),
            imus: vec![],
        };
        assert!(imu_array_fields(&encode(&empty).unwrap())
            .unwrap()
            .is_empty());
    }
}
