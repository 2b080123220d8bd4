//! The check on a live stream: joint states and skin samples pushed as they come (a ROS 2 node's
//! callbacks, chunks of a log), blocks built by [`MotionStream`], every SU's sums updated as each
//! block is given out; a report at any moment. Memory is bounded: the stream's latency, the
//! first [`WARM_UP`] seconds (each SU's noise is judged there), and the last [`RECENT`] seconds
//! that the refit of an SU no small change explains works on.

use std::collections::VecDeque;

use super::refit::block_noise;
use super::{conclude, CheckConfig, CheckError, CheckReport, Columns, Skin, SkinCheck};
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
    /// The open run: its blocks from the first one a later block may still need.
    tail: Option<MotionRun>,
    /// Blocks of `tail` summed.
    fed: usize,
    /// Blocks of context a block needs on either side (the SUs' delays).
    margin: usize,
    /// Runs that ended before the start, to be summed then.
    waiting: Vec<MotionRun>,
}

/// Appends `run` to `runs`, joined to the last one where it continues it.
fn join(runs: &mut Vec<MotionRun>, run: MotionRun) {
    if run.is_empty() {
        return;
    }
    let rest = match runs.last_mut() {
        Some(last) => last.extend_with(run, BLOCK),
        None => Some(run),
    };
    runs.extend(rest);
}

/// Appends `run` to `runs` and keeps only their last `blocks` blocks.
fn keep_last(runs: &mut VecDeque<MotionRun>, run: MotionRun, blocks: usize) {
    let rest = match runs.back_mut() {
        Some(last) => last.extend_with(run, BLOCK),
        None => Some(run),
    };
    runs.extend(rest);
    let mut held: usize = runs.iter().map(MotionRun::len).sum();
    while held > blocks {
        let Some(first) = runs.front_mut() else { break };
        let drop = (held - blocks).min(first.len());
        *first = first.split_off(drop, BLOCK);
        held -= drop;
        if first.is_empty() {
            runs.pop_front();
        }
    }
}

impl LiveCheck {
    /// A live check of `model`.
    pub fn new(model: &BodyModel, config: &CheckConfig) -> Result<Self, CheckError> {
        let skin = Skin::new(model, config)?;
        let dofs = skin.robot.model.dof_names();
        let sus = skin.robot.model.su_names();
        let columns = Columns::new(&skin, &dofs, &sus)?;
        let ingest = IngestConfig::default();
        let margin = skin.delay.iter().fold(0.0f64, |m, d| m.max(d.abs()));
        let margin = (margin / BLOCK).ceil() as usize + 1;
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
            tail: None,
            fed: 0,
            margin,
            waiting: Vec::new(),
        })
    }

    /// Takes one sample (joint states or an SU's sample).
    pub fn push(&mut self, sample: &Sample<'_>) {
        self.stream.push(sample);
    }

    /// Feeds every block the stream has given out since the last call. The outcome does not
    /// depend on when it is called: the stream's runs are joined where they continue each other
    /// (a block is summed once the blocks its SUs' delays reach have come), each SU's noise is
    /// judged on the first [`WARM_UP`] seconds of blocks exactly, and the refit works on the last
    /// [`RECENT`] seconds.
    fn feed(&mut self) {
        let warm_blocks = (WARM_UP / BLOCK).round() as usize;
        for run in self.stream.take() {
            if run.is_empty() {
                continue;
            }
            keep_last(
                &mut self.recent,
                run.clone(),
                (RECENT / BLOCK).round() as usize,
            );
            if self.check.is_none() {
                let warm: usize = self.warm_up.iter().map(MotionRun::len).sum();
                let mut first = run.clone();
                first.split_off(warm_blocks - warm, BLOCK);
                join(&mut self.warm_up, first);
            }
            let rest = match self.tail.as_mut() {
                Some(tail) => tail.extend_with(run, BLOCK),
                None => Some(run),
            };
            if let Some(run) = rest {
                // A gap: the run before it ends here.
                self.feed_tail(true);
                self.tail = Some(run);
                self.fed = 0;
            }
            if self.check.is_none()
                && self.warm_up.iter().map(MotionRun::len).sum::<usize>() >= warm_blocks
            {
                self.start();
            }
            self.feed_tail(false);
        }
    }

    /// Sums the blocks of the open run whose context has come (all of them at its `end`), and
    /// lets go of those no later block needs. Before the start, a run that ended waits.
    fn feed_tail(&mut self, end: bool) {
        let Some(tail) = self.tail.as_mut() else {
            return;
        };
        let Some(check) = self.check.as_mut() else {
            if end {
                self.waiting.push(tail.clone());
            }
            return;
        };
        let upto = if end {
            tail.len()
        } else {
            tail.len().saturating_sub(self.margin)
        };
        if upto > self.fed {
            check.feed_range(tail, self.fed..upto, BLOCK);
            self.fed = upto;
        }
        let done = self.fed.saturating_sub(self.margin);
        *tail = tail.split_off(done, BLOCK);
        self.fed -= done;
    }

    /// Each SU's noise from the warm-up, then the runs that ended before it summed.
    fn start(&mut self) {
        let warm_up = std::mem::take(&mut self.warm_up);
        let record = self.record(warm_up);
        let skin = self.skin.take().expect("the skin is kept until the start");
        let noise = block_noise(&self.columns, &record);
        let mut check = SkinCheck::new(skin, self.columns.clone(), noise, self.config);
        for run in std::mem::take(&mut self.waiting) {
            check.feed(&run, BLOCK);
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
            half_width: self.stream.half_width(),
            rounding: self.stream.roundings(),
            runs,
            samples: self.stream.samples(),
        }
    }

    /// The check so far (`None` before [`WARM_UP`] seconds of motion have come): every SU's
    /// verdict from its sums, the SUs no small change explains refitted on the last [`RECENT`]
    /// seconds.
    pub fn report(&mut self) -> Option<CheckReport> {
        self.feed();
        // The open run taken as ending here: its last blocks summed on a copy.
        let mut check = self.check.clone()?;
        if let Some(tail) = &self.tail {
            check.feed_range(tail, self.fed..tail.len(), BLOCK);
        }
        let mut report = check.verdicts(&self.stream.samples());
        let recent = self.record(self.recent.iter().cloned().collect());
        conclude(&check, &recent, &mut report);
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
            .chain(&self.waiting)
            .chain(&self.tail)
            .map(MotionRun::len)
            .sum();
        (joints, skin, kept)
    }
}
