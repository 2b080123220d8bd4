//! What a motion record's blocks are computed from as the samples come, in memory bounded by how
//! far the blocks still to compute reach: each DoF's joint states about the next block's centre
//! ([`JointWindow`]), each SU's fresh samples summed per block ([`SkinWindow`]), and what a
//! first look at a DoF's joint states tells of its encoder and rate ([`JointSurvey`]).

use std::collections::{BTreeMap, VecDeque};

use super::blocks::{raw_means, RawMean, SkinSum};
use super::motion::{half_width_of, local_polynomial};
use super::timeline::{Rounding, Samples};
use crate::motion::{Kernel, SampleCount, SampleCounter};

/// Per DoF, its joint states from the earliest that a block still to compute reads, in stamp
/// order.
#[derive(Debug, Clone)]
pub(super) struct JointWindow {
    states: Vec<VecDeque<(f64, f64)>>,
    /// The earliest stamp a block still to compute reads: a state stamped before it came after
    /// the blocks that would have read it.
    frontier: f64,
    /// Joint states that so came too late.
    pub(super) late: usize,
}

impl JointWindow {
    pub(super) fn new(dofs: usize) -> Self {
        JointWindow {
            states: vec![VecDeque::new(); dofs],
            frontier: f64::NEG_INFINITY,
            late: 0,
        }
    }

    /// Takes DoF `d`'s position `q` stamped `stamp`, in its place among those held (a stamp
    /// already held keeps the first state given it).
    pub(super) fn take(&mut self, d: usize, stamp: f64, q: f64) {
        if stamp < self.frontier {
            self.late += 1;
            return;
        }
        let states = &mut self.states[d];
        if states.back().is_none_or(|&(t, _)| t < stamp) {
            states.push_back((stamp, q));
            return;
        }
        let at = states.partition_point(|&(t, _)| t < stamp);
        if states[at].0 != stamp {
            states.insert(at, (stamp, q));
        }
    }

    /// The newest stamp every DoF's states reach; `None` while some DoF has none.
    pub(super) fn newest_common(&self) -> Option<f64> {
        self.states
            .iter()
            .map(|s| s.back().map(|&(t, _)| t))
            .try_fold(f64::INFINITY, |a, t| t.map(|t| a.min(t)))
    }

    /// Per DoF `[q, q̇, q̈, q̈'s deviation]` at `centre` from its local polynomial of half-width
    /// `h` ([`local_polynomial`]; `roundings`: each DoF's encoder's); `None` where some DoF's
    /// cannot be fitted there.
    pub(super) fn fit(
        &mut self,
        centre: f64,
        h: f64,
        roundings: &[f64],
        max_gap: f64,
        kernel: Option<&Kernel>,
    ) -> Option<Vec<[f64; 4]>> {
        self.states
            .iter_mut()
            .zip(roundings)
            .map(|(states, &rounding)| {
                local_polynomial(
                    states.make_contiguous(),
                    &mut 0,
                    centre,
                    h,
                    rounding,
                    max_gap,
                    kernel,
                )
            })
            .collect()
    }

    /// No block to compute reads a state stamped before `frontier`: they are dropped (each DoF
    /// keeps its newest), and any that comes later is late.
    pub(super) fn forget_before(&mut self, frontier: f64) {
        self.frontier = self.frontier.max(frontier);
        for states in &mut self.states {
            while states.len() > 1 && states[0].0 < self.frontier {
                states.pop_front();
            }
        }
    }

    /// The joint states held (what the window's memory grows with).
    pub(super) fn held(&self) -> usize {
        self.states.iter().map(VecDeque::len).sum()
    }
}

/// Per block from the oldest not yet taken, each SU's fresh samples summed; and per SU its
/// samples' count.
#[derive(Debug, Clone)]
pub(super) struct SkinWindow {
    /// `rows[i]`: block `base + i`, per SU (empty where no SU sent a sample in it).
    rows: VecDeque<Vec<SkinSum>>,
    base: usize,
    /// Per SU: its last sample (a repeat is a slower board's value held by its port).
    last: Vec<Option<[f64; 3]>>,
    samples: Vec<SampleCounter>,
    /// The latest stamp of any sample.
    pub(super) latest: f64,
    /// Fresh samples stamped in a block already taken.
    pub(super) late: usize,
}

impl SkinWindow {
    pub(super) fn new(sus: usize) -> Self {
        SkinWindow {
            rows: VecDeque::new(),
            base: 0,
            last: vec![None; sus],
            samples: vec![SampleCounter::default(); sus],
            latest: f64::NEG_INFINITY,
            late: 0,
        }
    }

    /// Takes SU `u`'s sample `a` stamped `stamp`, `at` blocks after block 0's start (not
    /// before it; `usable`: finite and within range).
    pub(super) fn take(&mut self, u: usize, stamp: f64, at: f64, a: [f64; 3], usable: bool) {
        self.latest = self.latest.max(stamp);
        let repeat = self.last[u] == Some(a);
        self.samples[u].add(stamp, usable, repeat);
        if !usable || repeat {
            return;
        }
        self.last[u] = Some(a);
        let block = at as usize;
        if block < self.base {
            self.late += 1;
            return;
        }
        while self.base + self.rows.len() <= block {
            self.rows.push_back(Vec::new());
        }
        let row = &mut self.rows[block - self.base];
        if row.is_empty() {
            row.resize(self.last.len(), SkinSum::default());
        }
        row[u].add(a, at - block as f64 - 0.5);
    }

    /// Block `b`'s raw means and when their samples were taken (`b` not before a block taken
    /// already), the blocks up to it dropped: a sample stamped in them is late from now on.
    pub(super) fn take_block(&mut self, b: usize) -> Vec<Option<RawMean>> {
        let mut means = None;
        while self.base <= b {
            let row = self.rows.pop_front().unwrap_or_default();
            if self.base == b && !row.is_empty() {
                means = Some(raw_means(&row));
            }
            self.base += 1;
        }
        means.unwrap_or_else(|| vec![None; self.last.len()])
    }

    /// Per SU: how many samples came, and why some are in no block.
    pub(super) fn samples(&self) -> Vec<SampleCount> {
        self.samples.iter().map(|c| c.count).collect()
    }

    /// The blocks held (what the window's memory grows with).
    pub(super) fn held(&self) -> usize {
        self.rows.len()
    }
}

/// What one look at a DoF's joint states tells, in memory bounded whatever their number: its
/// encoder's rounding ([`Rounding`]) and its median step between states.
#[derive(Debug, Clone, Default, PartialEq)]
pub(super) struct JointSurvey {
    rounding: Rounding,
    steps: StepMedian,
    last: Option<f64>,
}

impl JointSurvey {
    /// Takes the next state (one stamped no later than the last is left out).
    pub(super) fn take(&mut self, stamp: f64, q: f64) {
        if let Some(last) = self.last {
            if stamp <= last {
                return;
            }
            self.steps.add(stamp - last);
        }
        self.last = Some(stamp);
        self.rounding.take(q);
    }

    /// The standard deviation of the encoder's rounding (a count over √12), 0 for readings that
    /// are not rounded or never changed.
    pub(super) fn rounding(&self) -> f64 {
        self.rounding.count() / 12f64.sqrt()
    }

    /// The half-width of this DoF's local polynomial ([`half_width_of`]).
    pub(super) fn half_width(&self) -> f64 {
        half_width_of(self.rounding(), self.steps.median())
    }
}

/// What a log's joint states tell each DoF's polynomial ([`JointSurvey`]), and the first stamp.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct JointsSurveyed {
    pub(super) origin: Option<f64>,
    pub(super) dofs: std::collections::HashMap<String, JointSurvey>,
}

impl JointsSurveyed {
    /// The survey of the series (stamp order) of the DoFs `names`.
    pub(super) fn of(names: &[String], series: &[Samples]) -> Self {
        let mut surveyed = JointsSurveyed::default();
        for (name, series) in names.iter().zip(series) {
            let survey = surveyed.dofs.entry(name.clone()).or_default();
            for &[stamp, q] in series.iter() {
                survey.take(stamp, q);
            }
            if let Some(&[first, _]) = series.first() {
                surveyed.origin = Some(surveyed.origin.map_or(first, |o: f64| o.min(first)));
            }
        }
        surveyed
    }
}

/// Bins per doubling of [`StepMedian`]'s histogram.
const STEP_BINS_PER_OCTAVE: f64 = 128.0;

/// The median of positive steps, from a histogram of them in bins of half a per cent (each
/// bin's steps' count and sum: the median bin's mean is given, the median itself when the steps
/// are regular). A DoF's steps span a few octaves at most: a few hundred bins.
#[derive(Debug, Clone, Default, PartialEq)]
struct StepMedian {
    bins: BTreeMap<i32, (u64, f64)>,
    count: u64,
}

impl StepMedian {
    fn add(&mut self, step: f64) {
        if !(step > 0.0 && step.is_finite()) {
            return;
        }
        let bin = (step.log2() * STEP_BINS_PER_OCTAVE).floor() as i32;
        let (count, sum) = self.bins.entry(bin).or_insert((0, 0.0));
        *count += 1;
        *sum += step;
        self.count += 1;
    }

    /// The median bin's mean step; NaN without steps.
    fn median(&self) -> f64 {
        let mut below = 0;
        for &(count, sum) in self.bins.values() {
            below += count;
            if 2 * below > self.count {
                return sum / count as f64;
            }
        }
        f64::NAN
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_median_step_is_that_of_regular_steps_and_within_a_bin_of_any() {
        let mut regular = StepMedian::default();
        for k in 0..1001 {
            // 1 kHz stamps read from f64 epoch seconds: steps off by ±240 ns.
            regular.add(1e-3 + if k % 2 == 0 { 2.4e-7 } else { -2.4e-7 });
        }
        assert!((regular.median() / 1e-3 - 1.0).abs() < 1e-6);
        let mut spread = StepMedian::default();
        for k in 1..=999 {
            spread.add(f64::from(k) * 1e-4);
        }
        // The true median is 0.05; its bin is 0.54 % wide.
        assert!(
            (spread.median() / 0.05 - 1.0).abs() < 0.006,
            "{}",
            spread.median()
        );
        assert!(StepMedian::default().median().is_nan());
    }

    #[test]
    fn joint_states_out_of_order_are_put_in_order_and_late_ones_counted() {
        let mut window = JointWindow::new(1);
        for &t in &[0.0, 0.002, 0.001, 0.003, 0.002] {
            window.take(0, t, t * 10.0);
        }
        let held: Vec<(f64, f64)> = window.states[0].iter().copied().collect();
        assert_eq!(
            held,
            vec![(0.0, 0.0), (0.001, 0.01), (0.002, 0.02), (0.003, 0.03)]
        );
        window.forget_before(0.0025);
        assert_eq!(window.held(), 1);
        window.take(0, 0.0024, 1.0);
        assert_eq!(window.late, 1);
        assert_eq!(window.newest_common(), Some(0.003));
    }

    #[test]
    fn a_skin_block_is_taken_once_and_samples_after_it_are_late() {
        let mut window = SkinWindow::new(2);
        window.take(0, 0.0, 0.2, [1.0, 2.0, 3.0], true);
        window.take(0, 0.0, 0.7, [3.0, 2.0, 1.0], true);
        window.take(1, 0.0, 2.5, [1.0; 3], true);
        // A repeat is the board's value held, not a sample.
        window.take(1, 0.0, 2.6, [1.0; 3], true);
        let first = window.take_block(0);
        assert_eq!(first[0].unwrap().value, [2.0; 3]);
        assert!((first[0].unwrap().time - (-0.05)).abs() < 1e-12);
        assert_eq!(first[1], None);
        assert_eq!(window.take_block(2)[1].unwrap().value, [1.0; 3]);
        window.take(0, 0.0, 1.5, [0.0; 3], true);
        assert_eq!(window.late, 1);
        assert_eq!(window.held(), 0);
        assert_eq!(window.samples()[1].repeated, 1);
    }
}
