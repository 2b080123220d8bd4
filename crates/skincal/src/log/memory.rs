//! A log held in memory: what a [`LogSink`] received, read back as a log file is, sample for
//! sample and in the order it came. A program that records and then ingests (a forecast, a test)
//! needs no file between the two.

use std::path::{Path, PathBuf};

use super::{LogError, LogSink, PassStats, Sample, Stream, Time};

/// One sample as the sink received it.
#[derive(Debug, Clone, PartialEq)]
enum Entry {
    Joints { stamp: f64, positions: Vec<f64> },
    Imu { stamp: f64, su: usize, a: [f64; 3] },
}

/// A log in memory, named for messages as a file would be.
#[derive(Debug, Clone, PartialEq)]
pub struct MemoryLog {
    name: PathBuf,
    dofs: Vec<String>,
    sus: Vec<String>,
    entries: Vec<Entry>,
}

/// Bytes a joint state or an accelerometer sample counts as in a pass's progress (roughly what
/// it takes in an MCAP file).
const ENTRY_BYTES: u64 = 64;

impl MemoryLog {
    /// An empty log that messages call `name`.
    pub fn new(name: impl Into<PathBuf>) -> MemoryLog {
        MemoryLog {
            name: name.into(),
            dofs: Vec::new(),
            sus: Vec::new(),
            entries: Vec::new(),
        }
    }

    /// The name messages call it by.
    pub fn name(&self) -> &Path {
        &self.name
    }

    /// The number of samples it holds (joint states and accelerometer samples).
    pub fn len(&self) -> usize {
        self.entries.len()
    }

    /// Whether it holds no sample.
    pub fn is_empty(&self) -> bool {
        self.entries.is_empty()
    }

    /// What a pass over `stream` counts its progress in.
    pub fn size(&self, stream: Stream) -> u64 {
        let n = self
            .entries
            .iter()
            .filter(|e| match e {
                Entry::Joints { .. } => stream.joints(),
                Entry::Imu { .. } => stream.imu(),
            })
            .count();
        n as u64 * ENTRY_BYTES
    }

    /// Streams the samples of `stream` to `visit` in the order the sink received them;
    /// `progress` gets [`MemoryLog::size`]'s units read so far.
    pub fn read(
        &self,
        stream: Stream,
        visit: &mut dyn FnMut(Sample<'_>) -> Result<(), LogError>,
        progress: &mut dyn FnMut(u64),
    ) -> Result<PassStats, LogError> {
        let mut stats = PassStats::default();
        let mut done = 0u64;
        for entry in &self.entries {
            match entry {
                Entry::Joints { stamp, positions } if stream.joints() => {
                    stats.joints.samples += 1;
                    visit(Sample::Joints {
                        stamp: *stamp,
                        names: &self.dofs,
                        positions,
                    })?;
                }
                Entry::Imu { stamp, su, a } if stream.imu() => {
                    stats.imu.samples += 1;
                    visit(Sample::Imu {
                        stamp: *stamp,
                        frame_id: &self.sus[*su],
                        acceleration: *a,
                    })?;
                }
                _ => continue,
            }
            done += ENTRY_BYTES;
            if done % (1 << 16) == 0 {
                progress(done);
            }
        }
        progress(done);
        Ok(stats)
    }
}

impl LogSink for MemoryLog {
    fn start(
        &mut self,
        dofs: &[String],
        sus: &[String],
        _acceleration_variance: f64,
    ) -> Result<(), LogError> {
        self.dofs = dofs.to_vec();
        self.sus = sus.to_vec();
        self.entries.clear();
        Ok(())
    }

    fn joint_state(
        &mut self,
        stamp: Time,
        _receive: Time,
        positions: &[f64],
        _velocities: &[f64],
    ) -> Result<(), LogError> {
        if positions.len() != self.dofs.len() {
            return Err(LogError::Stopped(format!(
                "{}: a joint state of {} positions for {} DoFs",
                self.name.display(),
                positions.len(),
                self.dofs.len()
            )));
        }
        self.entries.push(Entry::Joints {
            stamp: stamp.seconds(),
            positions: positions.to_vec(),
        });
        Ok(())
    }

    fn imu(&mut self, stamp: Time, _receive: Time, su: usize, a: [f64; 3]) -> Result<(), LogError> {
        if su >= self.sus.len() {
            return Err(LogError::Stopped(format!(
                "{}: a sample of SU {su} of {}",
                self.name.display(),
                self.sus.len()
            )));
        }
        self.entries.push(Entry::Imu {
            stamp: stamp.seconds(),
            su,
            a,
        });
        Ok(())
    }

    fn finish(&mut self) -> Result<Vec<PathBuf>, LogError> {
        Ok(Vec::new())
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_pass_gives_back_what_the_sink_received_in_order_and_by_stream() {
        let mut log = MemoryLog::new("recorded");
        let (dofs, sus) = (vec!["a".to_string(), "b".into()], vec!["su0".to_string()]);
        log.start(&dofs, &sus, 0.0).unwrap();
        let t = Time::from_seconds;
        log.joint_state(t(1.0), t(1.0), &[0.1, 0.2], &[0.0, 0.0])
            .unwrap();
        log.imu(t(1.0005), t(1.0005), 0, [0.0, 0.0, 9.81]).unwrap();
        log.joint_state(t(1.001), t(1.001), &[0.3, 0.4], &[0.0, 0.0])
            .unwrap();
        // A sample of an SU it was not told of is refused, not kept.
        assert!(log.imu(t(1.002), t(1.002), 1, [0.0; 3]).is_err());
        let mut seen = Vec::new();
        let stats = log
            .read(
                Stream::Both,
                &mut |s| {
                    seen.push(match s {
                        Sample::Joints {
                            stamp, positions, ..
                        } => format!("j {stamp:.4} {positions:?}"),
                        Sample::Imu {
                            stamp,
                            frame_id,
                            acceleration,
                        } => format!("i {stamp:.4} {frame_id} {acceleration:?}"),
                    });
                    Ok(())
                },
                &mut |_| {},
            )
            .unwrap();
        assert_eq!(
            seen,
            [
                "j 1.0000 [0.1, 0.2]",
                "i 1.0005 su0 [0.0, 0.0, 9.81]",
                "j 1.0010 [0.3, 0.4]"
            ]
        );
        assert_eq!((stats.joints.samples, stats.imu.samples), (2, 1));
        let mut imu_only = 0;
        log.read(
            Stream::Imu,
            &mut |s| {
                imu_only += matches!(s, Sample::Imu { .. }) as usize;
                assert!(matches!(s, Sample::Imu { .. }));
                Ok(())
            },
            &mut |_| {},
        )
        .unwrap();
        assert_eq!(imu_only, 1);
        assert_eq!(log.size(Stream::Joints), 2 * ENTRY_BYTES);
    }
}
