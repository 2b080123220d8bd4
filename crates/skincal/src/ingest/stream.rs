//! The motion record built as the samples come (a live stream, or a log read in chunks): the same
//! blocks as [`super::motion::motion_record`] — joint states by the same local polynomials, the
//! skin's fresh samples averaged per block and referred to its centre — each given out as soon as
//! the joint states beyond its polynomial's window and the skin of the blocks its centring reads
//! ([`super::blocks::CORRECTION_REACH`] after it) have arrived.
//! Memory is bounded by that latency, not by the stream's length.

use std::collections::{HashMap, VecDeque};

use super::blocks::{raw_means, Centring, RawMean, SkinSum};
use super::motion::{half_width, local_polynomial, BLOCK, HALF_WIDTHS};
use super::timeline::encoder_rounding;
use super::IngestConfig;
use crate::log::Sample;
use crate::motion::{Kernel, MotionRun, SampleCount, SampleCounter};

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
    su_count: usize,
    config: IngestConfig,
    label: String,
    /// The stamp of block 0's start (the first sample's).
    origin: Option<f64>,
    /// Per DoF: its recent joint states, oldest first.
    joints: Vec<VecDeque<(f64, f64)>>,
    /// Per DoF: the polynomial's half-width and the encoder's rounding, once learnt.
    widths: Vec<Option<(f64, f64)>>,
    /// Per DoF: its first states, until the widths are learnt.
    learning: Vec<Vec<(f64, f64)>>,
    /// Once the widths are learnt: the kernel the joint states are read through (`None` inside:
    /// the record reads the block means, [`Kernel::of_record`]).
    kernel: Option<Option<Kernel>>,
    /// Per block from `base`: per SU its fresh samples.
    skin: VecDeque<Vec<SkinSum>>,
    base: usize,
    /// Per SU: its last sample (a repeat is a slower board's value held by its port).
    last: Vec<Option<[f64; 3]>>,
    /// Per SU: its samples so far.
    samples: Vec<SampleCounter>,
    latest_skin: f64,
    /// The next block to compute.
    next: usize,
    /// Blocks computed; the last [`Centring::pending`] of them wait for the blocks after them
    /// to refer their skin means to their centres.
    open: Option<MotionRun>,
    /// The open run's latest raw skin means.
    centring: Centring,
    done: Vec<MotionRun>,
    /// Skin samples stamped in a block already given out.
    pub late_samples: usize,
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
            su_count: sus.len(),
            config: config.clone(),
            label: label.to_string(),
            origin: None,
            joints: vec![VecDeque::new(); dofs.len()],
            widths: vec![None; dofs.len()],
            kernel: None,
            learning: vec![Vec::new(); dofs.len()],
            skin: VecDeque::new(),
            base: 0,
            last: vec![None; sus.len()],
            samples: vec![SampleCounter::default(); sus.len()],
            latest_skin: f64::NEG_INFINITY,
            next: 0,
            open: None,
            centring: Centring::default(),
            done: Vec::new(),
            late_samples: 0,
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
                self.latest_skin = self.latest_skin.max(stamp);
                let a = acceleration.map(|x| x * self.config.skin_scale);
                let usable = a.iter().all(|x| x.is_finite()) && !self.config.saturated(&a);
                let Some(&u) = self.sus.get(frame_id) else {
                    return;
                };
                if stamp < origin {
                    return;
                }
                let repeat = self.last[u] == Some(a);
                self.samples[u].add(stamp, usable, repeat);
                if !usable || repeat {
                    return;
                }
                self.last[u] = Some(a);
                let at = (stamp - origin) / BLOCK;
                let block = at as usize;
                if block < self.base.max(self.next) {
                    self.late_samples += 1;
                    return;
                }
                while self.base + self.skin.len() <= block {
                    self.skin.push_back(vec![SkinSum::default(); self.su_count]);
                }
                self.skin[block - self.base][u].add(a, at - block as f64 - 0.5);
            }
        }
        self.advance();
    }

    fn joint(&mut self, d: usize, stamp: f64, q: f64) {
        if self.joints[d].back().is_some_and(|&(t, _)| t >= stamp) {
            return;
        }
        self.joints[d].push_back((stamp, q));
        if self.widths[d].is_none() {
            let learning = &mut self.learning[d];
            learning.push((stamp, q));
            if stamp - learning[0].0 >= LEARN {
                self.widths[d] = Some((half_width(learning), encoder_rounding(learning)));
                *learning = Vec::new();
            }
        }
    }

    /// Computes every block whose joint states and skin are complete.
    fn advance(&mut self) {
        let Some(origin) = self.origin else { return };
        loop {
            let centre = origin + (self.next as f64 + 0.5) * BLOCK;
            let joints_in = self.half_width().is_some_and(|h| {
                self.joints
                    .iter()
                    .all(|j| j.back().is_some_and(|&(t, _)| t > centre + h))
            });
            // The block's own skin is in (its correction waits for the blocks after it).
            let skin_in = self.latest_skin > centre + 0.5 * BLOCK + SKIN_LATENCY;
            if !(joints_in && skin_in) {
                return;
            }
            self.compute(centre);
            self.next += 1;
            self.trim(centre);
        }
    }

    /// Block `self.next` at `centre`.
    fn compute(&mut self, centre: f64) {
        let max_gap = self.config.max_gap;
        let h = self.half_width().expect("widths learnt before any block");
        let kernel = *self
            .kernel
            .get_or_insert_with(|| Kernel::of_record(h, BLOCK));
        let fitted: Option<Vec<[f64; 4]>> = self
            .joints
            .iter_mut()
            .zip(&self.widths)
            .map(|(series, w)| {
                let (_, rounding) = w.expect("widths learnt before any block");
                local_polynomial(
                    series.make_contiguous(),
                    &mut 0,
                    centre,
                    h,
                    rounding,
                    max_gap,
                    kernel.as_ref(),
                )
            })
            .collect();
        let raw = self.raw_means(self.next);
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

    /// Block `b`'s raw skin means and when their samples were taken.
    fn raw_means(&self, b: usize) -> Vec<Option<RawMean>> {
        match b.checked_sub(self.base).and_then(|i| self.skin.get(i)) {
            Some(row) => raw_means(row),
            None => vec![None; self.su_count],
        }
    }

    /// Drops what no later block needs.
    fn trim(&mut self, centre: f64) {
        let keep_from = centre - HALF_WIDTHS[HALF_WIDTHS.len() - 1] - BLOCK;
        for series in &mut self.joints {
            while series.len() > 1 && series[0].0 < keep_from {
                series.pop_front();
            }
        }
        // The centring keeps the raw means the corrections still need.
        while self.base < self.next && !self.skin.is_empty() {
            self.skin.pop_front();
            self.base += 1;
        }
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
        if let (Some(origin), Some(last)) = (
            self.origin,
            self.joints
                .iter()
                .map(|j| j.back().map_or(f64::NEG_INFINITY, |x| x.0))
                .reduce(f64::min),
        ) {
            self.latest_skin = f64::INFINITY;
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
        self.samples.iter().map(|c| c.count).collect()
    }

    /// Joint states and skin blocks held now (what the stream's memory grows with).
    pub fn held(&self) -> (usize, usize) {
        (
            self.joints.iter().map(VecDeque::len).sum(),
            self.skin.len() + self.open.as_ref().map_or(0, MotionRun::len),
        )
    }
}
