//! The check on a live stream: joint states and skin samples pushed as they come (a ROS 2 node's
//! callbacks, chunks of a log), blocks built by [`MotionStream`], every SU's sums updated as each
//! block is given out; a report at any moment. Memory is bounded: the stream's latency, the
//! first [`WARM_UP`] seconds (each SU's noise is judged there), and the last [`RECENT`] seconds
//! that the refit of an SU no small change explains works on.

use std::collections::VecDeque;

use super::refit::{block_noise, explain};
use super::{CheckConfig, CheckError, CheckReport, Columns, Skin, SkinCheck};
use crate::estimate::body::BodyModel;
use crate::ingest::motion::BLOCK;
use crate::ingest::stream::MotionStream;
use crate::ingest::IngestConfig;
use crate::log::Sample;
use crate::motion::{MotionRecord, MotionRun, MOTION_FORMAT, MOTION_VERSION};

/// Seconds of motion from which each SU's noise is judged before the sums start.
pub const WARM_UP: f64 = 10.0;
/// Seconds of the latest motion kept for the refit of an SU no small change explains.
pub const RECENT: f64 = 30.0;

/// A check fed sample by sample.
pub struct LiveCheck {
    stream: MotionStream,
    skin: Option<Skin>,
    columns: Columns,
    config: CheckConfig,
    ingest: IngestConfig,
    dofs: Vec<String>,
    sus: Vec<String>,
    warm_up: Vec<MotionRun>,
    check: Option<SkinCheck>,
    recent: VecDeque<MotionRun>,
}

impl LiveCheck {
    /// A live check of `model`.
    pub fn new(model: &BodyModel, config: &CheckConfig) -> Result<Self, CheckError> {
        let skin = Skin::new(model, config)?;
        let dofs = skin.robot.model.dof_names();
        let sus = skin.robot.model.su_names();
        let columns = Columns::new(&skin, &dofs, &sus)?;
        let ingest = IngestConfig::default();
        Ok(Self {
            stream: MotionStream::new(&dofs, &sus, &ingest, "live"),
            skin: Some(skin),
            columns,
            config: *config,
            ingest,
            dofs,
            sus,
            warm_up: Vec::new(),
            check: None,
            recent: VecDeque::new(),
        })
    }

    /// Takes one sample (joint states or an SU's sample).
    pub fn push(&mut self, sample: &Sample<'_>) {
        self.stream.push(sample);
    }

    /// Feeds every block the stream has given out since the last call.
    fn feed(&mut self) {
        for run in self.stream.take() {
            if run.is_empty() {
                continue;
            }
            self.recent.push_back(run.clone());
            while self.recent.iter().map(MotionRun::len).sum::<usize>() as f64 * BLOCK > RECENT
                && self.recent.len() > 1
            {
                self.recent.pop_front();
            }
            match &mut self.check {
                Some(check) => check.feed(&run, BLOCK),
                None => self.warm_up.push(run),
            }
        }
        let warm: usize = self.warm_up.iter().map(MotionRun::len).sum();
        if self.check.is_none() && warm as f64 * BLOCK >= WARM_UP {
            self.start();
        }
    }

    /// Each SU's noise from the warm-up, then the warm-up's blocks summed.
    fn start(&mut self) {
        let warm_up = std::mem::take(&mut self.warm_up);
        let record = self.record(warm_up);
        let skin = self.skin.take().expect("the skin is kept until the start");
        let noise = block_noise(&self.columns, &record);
        let mut check = SkinCheck::new(skin, self.columns.clone(), noise, self.config);
        for run in &record.runs {
            check.feed(run, BLOCK);
        }
        self.check = Some(check);
    }

    fn record(&self, runs: Vec<MotionRun>) -> MotionRecord {
        let noise_sd = (0..self.sus.len())
            .map(|u| crate::ingest::motion::still_noise(&runs, u, &self.ingest))
            .collect();
        MotionRecord {
            format: MOTION_FORMAT.into(),
            version: MOTION_VERSION,
            period: BLOCK,
            dofs: self.dofs.clone(),
            sus: self.sus.clone(),
            noise_sd,
            runs,
            samples: self.stream.samples().to_vec(),
        }
    }

    /// The check so far (`None` before [`WARM_UP`] seconds of motion have come): every SU's
    /// verdict from its sums, the SUs no small change explains refitted on the last [`RECENT`]
    /// seconds.
    pub fn report(&mut self) -> Option<CheckReport> {
        self.feed();
        let check = self.check.as_ref()?;
        let mut report = check.verdicts(self.stream.samples());
        let recent = self.record(self.recent.iter().cloned().collect());
        explain(check, &recent, &mut report);
        Some(report)
    }

    /// What the check holds now: joint states and skin blocks of the stream, blocks kept for
    /// the warm-up and the refit.
    pub fn held(&mut self) -> (usize, usize, usize) {
        self.feed();
        let (joints, skin) = self.stream.held();
        let kept = self
            .warm_up
            .iter()
            .chain(&self.recent)
            .map(MotionRun::len)
            .sum();
        (joints, skin, kept)
    }
}
