//! The motion record built as the samples come (a live stream, or a log read in chunks): the same
//! blocks as [`super::motion::motion_record`] — joint states by the same local polynomials, the
//! skin's fresh samples averaged per block and referred to its centre — each given out as soon as
//! the joint states beyond its polynomial's window and the skin of the blocks its centring reads
//! ([`super::blocks::CORRECTION_REACH`] after it) have arrived. Unlike a whole log's record, which
//! looks at every joint state first, each DoF's polynomial width and encoder are learnt from its
//! first [`LEARN`] seconds. Memory is bounded by that latency, not by the stream's length.

use std::collections::HashMap;

use super::blocks::Centring;
use super::motion::{BLOCK, HALF_WIDTHS};
use super::window::{JointSurvey, JointWindow, SkinWindow};
use super::IngestConfig;
use crate::log::Sample;
use crate::motion::{Kernel, MotionRun, SampleCount};

/// Seconds of each DoF's joint states from which its polynomial's half-width and its encoder's
/// rounding are judged before any block is given out.
const LEARN: f64 = 2.0;
/// How long after a block's end the skin may still deliver samples stamped in it, s.
const SKIN_LATENCY: f64 = 0.05;

/// Joint states and skin samples in, blocks of the motion record out.
#[derive(Debug)]
pub struct MotionStream {
    dofs: HashMap<String, usize>,
    sus: HashMap<String, usize>,
    config: IngestConfig,
    label: String,
    /// The stamp of block 0's start (the first sample's).
    origin: Option<f64>,
    /// The joint states the blocks still to compute read.
    joints: JointWindow,
    /// Per DoF: the polynomial's half-width and the encoder's rounding, once learnt.
    widths: Vec<Option<(f64, f64)>>,
    /// Per DoF: its first stamp and what its states tell, until the widths are learnt.
    learning: Vec<(Option<f64>, JointSurvey)>,
    /// Once the widths are learnt: the kernel the joint states are read through (`None` inside:
    /// the record reads the block means, [`Kernel::of_record`]).
    kernel: Option<Option<Kernel>>,
    /// The skin's blocks not yet computed.
    skin: SkinWindow,
    /// The next block to compute.
    next: usize,
    /// Blocks computed; the last [`Centring::pending`] of them wait for the blocks after them
    /// to refer their skin means to their centres.
    open: Option<MotionRun>,
    /// The open run's latest raw skin means.
    centring: Centring,
    done: Vec<MotionRun>,
}

impl MotionStream {
    /// A stream of the DoFs and SUs named (others are ignored), its runs labelled `label`.
    pub fn new(dofs: &[String], sus: &[String], config: &IngestConfig, label: &str) -> Self {
        let index = |names: &[String]| {
            names
                .iter()
                .enumerate()
                .map(|(i, n)| (n.clone(), i))
                .collect::<HashMap<_, _>>()
        };
        Self {
            dofs: index(dofs),
            sus: index(sus),
            config: config.clone(),
            label: label.to_string(),
            origin: None,
            joints: JointWindow::new(dofs.len()),
            widths: vec![None; dofs.len()],
            kernel: None,
            learning: vec![(None, JointSurvey::default()); dofs.len()],
            skin: SkinWindow::new(sus.len()),
            next: 0,
            open: None,
            centring: Centring::default(),
            done: Vec::new(),
        }
    }

    /// Takes one sample.
    pub fn push(&mut self, sample: &Sample<'_>) {
        match *sample {
            Sample::Joints {
                stamp,
                names,
                positions,
            } => {
                self.origin.get_or_insert(stamp);
                for (name, &q) in names.iter().zip(positions) {
                    if let (Some(&d), true) = (self.dofs.get(name), q.is_finite()) {
                        self.joint(d, stamp, q);
                    }
                }
            }
            Sample::Imu {
                stamp,
                frame_id,
                acceleration,
            } => {
                let origin = *self.origin.get_or_insert(stamp);
                let a = acceleration.map(|x| x * self.config.skin_scale);
                let usable = a.iter().all(|x| x.is_finite()) && !self.config.saturated(&a);
                if let (Some(&u), true) = (self.sus.get(frame_id), stamp >= origin) {
                    self.skin
                        .take(u, stamp, (stamp - origin) / BLOCK, a, usable);
                }
            }
        }
        self.advance();
    }

    fn joint(&mut self, d: usize, stamp: f64, q: f64) {
        self.joints.take(d, stamp, q);
        if self.widths[d].is_none() {
            let (first, survey) = &mut self.learning[d];
            survey.take(stamp, q);
            if stamp - *first.get_or_insert(stamp) >= LEARN {
                self.widths[d] = Some((survey.half_width(), survey.rounding()));
                *survey = JointSurvey::default();
            }
        }
    }

    /// Computes every block whose joint states and skin are complete.
    fn advance(&mut self) {
        let Some(origin) = self.origin else { return };
        loop {
            let centre = origin + (self.next as f64 + 0.5) * BLOCK;
            let joints_in = self
                .half_width()
                .is_some_and(|h| self.joints.newest_common().is_some_and(|t| t > centre + h));
            // The block's own skin is in (its correction waits for the blocks after it).
            let skin_in = self.skin.latest > centre + 0.5 * BLOCK + SKIN_LATENCY;
            if !(joints_in && skin_in) {
                return;
            }
            self.compute(centre);
            self.next += 1;
            self.joints
                .forget_before(centre - HALF_WIDTHS[HALF_WIDTHS.len() - 1] - BLOCK);
        }
    }

    /// Block `self.next` at `centre`.
    fn compute(&mut self, centre: f64) {
        let max_gap = self.config.max_gap;
        let h = self.half_width().expect("widths learnt before any block");
        let kernel = *self
            .kernel
            .get_or_insert_with(|| Kernel::of_record(h, BLOCK));
        let roundings = self.roundings();
        let fitted = self
            .joints
            .fit(centre, h, &roundings, max_gap, kernel.as_ref());
        let raw = self.skin.take_block(self.next);
        let Some(fitted) = fitted else {
            // A run's first block keeps its mean, as in the record of a whole log.
            self.close();
            return;
        };
        let label = &self.label;
        let run = self
            .open
            .get_or_insert_with(|| MotionRun::new(label, centre));
        self.centring.push(run, &fitted, raw);
    }

    /// Ends the open run: every block of it corrected, the last ones from the blocks before.
    fn close(&mut self) {
        if let Some(mut run) = self.open.take() {
            self.centring.finish(&mut run);
            self.done.push(run);
        }
    }

    /// Every block given out so far, as runs; the last blocks computed stay behind until the
    /// skin of the blocks after them has come.
    pub fn take(&mut self) -> Vec<MotionRun> {
        let pending = self.centring.pending();
        if let Some(run) = self.open.as_mut().filter(|r| r.len() > pending) {
            let keep = run.split_off(run.len() - pending, BLOCK);
            let given = std::mem::replace(run, keep);
            self.done.push(given);
        }
        std::mem::take(&mut self.done)
    }

    /// Ends the stream: the blocks up to the last joint state's are computed as the whole log's
    /// record computes them (where the polynomial has its states), and every block is given out.
    pub fn finish(mut self) -> Vec<MotionRun> {
        if let (Some(origin), Some(last)) = (self.origin, self.joints.newest_common()) {
            self.skin.latest = f64::INFINITY;
            self.advance();
            let blocks = ((last - origin) / BLOCK).floor().max(0.0) as usize;
            if self.widths.iter().all(Option::is_some) {
                while self.next < blocks {
                    self.compute(origin + (self.next as f64 + 0.5) * BLOCK);
                    self.next += 1;
                }
            }
        }
        self.close();
        self.done.retain(|r| r.len() >= 3);
        self.done
    }

    /// Each DoF's encoder rounding ([`crate::motion::MotionRecord::rounding`]), 0 until learnt.
    pub fn roundings(&self) -> Vec<f64> {
        self.widths
            .iter()
            .map(|w| w.map_or(0.0, |(_, r)| r))
            .collect()
    }

    /// The half-width of every DoF's polynomial: the widest any DoF's encoder needs, once every
    /// DoF's is learnt.
    pub fn half_width(&self) -> Option<f64> {
        self.widths
            .iter()
            .map(|w| w.map(|(h, _)| h))
            .try_fold(HALF_WIDTHS[0], |a, h| h.map(|h| a.max(h)))
    }

    /// Per SU: how many samples came so far, and why some are in no block.
    pub fn samples(&self) -> Vec<SampleCount> {
        self.skin.samples()
    }

    /// Skin samples stamped in a block already given out.
    pub fn late_samples(&self) -> usize {
        self.skin.late
    }

    /// Joint states and skin blocks held now (what the stream's memory grows with).
    pub fn held(&self) -> (usize, usize) {
        (
            self.joints.held(),
            self.skin.held() + self.open.as_ref().map_or(0, MotionRun::len),
        )
    }
}
