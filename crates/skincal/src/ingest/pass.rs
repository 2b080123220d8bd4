//! One pass over a log: the joint states put on the grid as they come, the skin samples held only
//! until the windows they fall in are known.
//!
//! The grid's period is fitted to the first [`GRID_SPAN`] seconds of joint states, so samples can
//! be placed on it from then on. Every so often the stretch of the timeline from the last pause
//! not yet settled to the newest joint state is built and segmented: every pause and motion
//! before the stretch's last pause is final (the decisions of [`pieces`] look at a motion and the
//! pauses around it only), so they are added to the log's windows, and the held samples up to
//! that pause go to their windows (once a pause is over, its still window is final too). The held
//! samples are thus those of the current motion: memory does not grow with the log.
//!
//! The result is the one the two passes of [`super::timeline::read_joints`] and
//! [`super::skin::read_skin`] give. Where a log breaks what the single pass relies on (joint stamps
//! out of order, a DoF first seen after the grid is fixed, a motion longer than the samples it
//! may hold), it gives up and the caller reads the log twice.

use std::collections::HashMap;
use std::path::Path;

use super::queue::Queue;
use super::segment::{filter_points, pieces, trim_points, Segmentation};
use super::skin::{Accumulated, Router, SuRegistry};
use super::timeline::{
    new_series, newest_common, Grid, Rounding, Samples, Timeline, GRID_SPAN, MAX_PAUSE,
};
use super::window::JointsSurveyed;
use super::{IngestConfig, IngestError, LogReport, Progress};
use crate::log::{LogError, LogSource, PassStats, Sample, Stream};

/// Skin samples that arrive between two segmentations of the timeline.
pub(super) const HELD: usize = 1 << 18;
/// Most skin samples held (270 MB at 32 bytes each; 8 s of motion of 1000 SUs at 1 kHz): beyond,
/// the log is read twice instead.
const MOST_HELD: usize = 1 << 23;
/// The longest motion whose skin samples are held, s: longer than any transfer or excitation of a
/// structure or training program; a continuous program's sweep, or ordinary work, is read in two
/// passes instead (its samples, which no reading of the set takes, would fill [`MOST_HELD`]:
/// 270 MB held for a minute of 105 SUs).
const LONGEST_HELD: f64 = 10.0;
/// A skin sample this far ahead of the newest joint state waits aside until the log ends, s.
const STRAY: f64 = 10.0;

/// What one pass over a log found: its grid, its windows and their sums.
pub(super) struct LogPass {
    pub(super) grid: Grid,
    pub(super) seg: Segmentation,
    pub(super) acc: Accumulated,
}

/// A skin sample held until its window is known: SU, grid point, specific force.
type Held = (u32, u32, [f64; 3]);

/// The grid point of `stamp` as held: a sample before the grid's start is outside (counted).
fn held_at(grid: &Grid, stamp: f64, report: &mut LogReport) -> Option<u32> {
    match u32::try_from(grid.index(stamp)) {
        Ok(m) => Some(m),
        // Past the end of any grid it is outside too, when the log ends.
        Err(_) if stamp > grid.t0 => Some(u32::MAX),
        Err(_) => {
            report.imu_outside += 1;
            None
        }
    }
}

/// The state of the pass.
struct Pass<'a> {
    path: &'a Path,
    config: &'a IngestConfig,
    /// The DoFs: the expected ones, or those seen so far.
    dofs: Vec<String>,
    expected: bool,
    index: HashMap<String, usize>,
    /// The last joint message's names and their DoFs.
    names: Vec<String>,
    columns: Vec<Option<usize>>,
    /// Per DoF, `[stamp, position]`, sorted, without repeated stamps.
    series: Vec<Samples>,
    /// Per DoF, its encoder's step from the readings so far (the grid's `count`, kept up: a log
    /// whose robot stood still for the grid's first second shows no step there).
    rounding: Vec<Rounding>,
    grid: Option<Grid>,
    seg: Segmentation,
    router: Router,
    /// The skin samples that came before the grid was fixed: SU, stamp, specific force.
    early: Queue<(u32, f64, [f64; 3])>,
    /// The skin samples not yet routed, in the order they came.
    held: Queue<Held>,
    /// Skin samples far ahead of the joint states, routed at the end.
    strays: Vec<Held>,
    /// Held samples at which the timeline is segmented again.
    threshold: usize,
    /// Samples that arrive between two segmentations.
    step: usize,
    /// Whether the first pause of the stretch not yet settled has its still window added.
    pause_added: bool,
    /// The grid point where the stretch not yet settled starts.
    from: usize,
    /// Samples before this grid point go to their windows.
    cut: usize,
    /// Why the single pass gave up.
    abandoned: Option<&'static str>,
}

/// The single pass over the log at `path`, segmenting the timeline again every `step` skin
/// samples; `Ok(None)` when the log needs two passes.
pub(super) fn one_pass(
    source: &LogSource,
    step: usize,
    config: &IngestConfig,
    dof_names: &mut Option<Vec<String>>,
    sus: &mut SuRegistry,
    report: &mut LogReport,
    progress: &mut Progress<'_>,
) -> Result<Option<LogPass>, IngestError> {
    let path = source.path();
    let total = source.size(Stream::Both);
    let label = format!("samples of {}", path.display());
    let dofs = dof_names.clone().unwrap_or_default();
    let mut pass = Pass {
        path,
        config,
        index: dofs
            .iter()
            .enumerate()
            .map(|(i, d)| (d.clone(), i))
            .collect(),
        series: vec![new_series(); dofs.len()],
        rounding: Vec::new(),
        expected: dof_names.is_some(),
        dofs,
        names: Vec::new(),
        columns: Vec::new(),
        grid: None,
        seg: Segmentation::default(),
        router: Router::default(),
        early: Queue::default(),
        held: Queue::default(),
        strays: Vec::new(),
        threshold: step,
        step,
        pause_added: false,
        from: 0,
        cut: 0,
        abandoned: None,
    };
    let read = source.read(
        Stream::Both,
        &config.topics,
        &mut |s| {
            match s {
                Sample::Joints {
                    stamp,
                    names,
                    positions,
                } => pass.joints(stamp, names, positions, report),
                Sample::Imu {
                    stamp,
                    frame_id,
                    acceleration,
                } => {
                    if let Some(su) = pass.router.arrive(sus, frame_id, stamp, report) {
                        pass.imu(su as u32, stamp, acceleration, report);
                    }
                }
            }
            match pass.abandoned {
                Some(why) => Err(LogError::Stopped(why.into())),
                None => Ok(()),
            }
        },
        &mut |done| progress(&label, done, total),
    );
    let stats = match read {
        Err(LogError::Stopped(_)) if pass.abandoned.is_some() => return Ok(None),
        other => other?,
    };
    Ok(pass.finish(stats, dof_names, sus, report))
}

impl Pass<'_> {
    /// The log's end: the last stretch segmented and every held sample routed; `None` where the
    /// two passes must read the log (they refuse what is wrong with it in their own words).
    fn finish(
        mut self,
        stats: PassStats,
        dof_names: &mut Option<Vec<String>>,
        sus: &SuRegistry,
        report: &mut LogReport,
    ) -> Option<LogPass> {
        if self.series.is_empty() || self.series.iter().any(|s| s.len() < 2) {
            return None;
        }
        if self.grid.is_none() {
            self.fix_grid(report);
        }
        let mut grid = self.grid.clone()?;
        let n = grid.points(self.path, &self.series).ok()?;
        self.settle_to(n, true, report);
        if self.abandoned.is_some() {
            return None;
        }
        if !self.expected {
            *dof_names = Some(self.dofs.clone());
        }
        grid.finish(&self.series, self.config, report);
        report.surveyed = Some(JointsSurveyed::of(&self.dofs, &self.series));
        self.seg.finish(report);
        report.joint_states = stats.joints.samples;
        report.joint_read = stats.joints;
        report.imu_read = stats.imu;
        let acc = self.router.finish(&self.seg, sus, report);
        Some(LogPass {
            grid,
            seg: self.seg,
            acc,
        })
    }

    /// One skin sample of SU `su`: held (on the grid once it is fixed), and the timeline segmented
    /// again once `step` more have come.
    fn imu(&mut self, su: u32, stamp: f64, acceleration: [f64; 3], report: &mut LogReport) {
        match &self.grid {
            Some(grid) => {
                if let Some(m) = held_at(grid, stamp, report) {
                    self.held.push_back((su, m, acceleration));
                }
            }
            None => self.early.push_back((su, stamp, acceleration)),
        }
        if self.held.len() + self.early.len() >= self.threshold {
            self.settle(report);
            self.threshold = self.held.len() + self.early.len() + self.step;
        }
    }

    /// One joint state.
    fn joints(&mut self, stamp: f64, names: &[String], positions: &[f64], report: &mut LogReport) {
        if self.names != names {
            self.names = names.to_vec();
            self.columns = Vec::with_capacity(names.len());
            for name in names {
                let column = match self.index.get(name) {
                    Some(&d) => Some(d),
                    None if self.expected => None,
                    None if self.grid.is_some() => {
                        self.abandoned = Some("a DoF first seen after the grid was fixed");
                        return;
                    }
                    None => {
                        self.index.insert(name.clone(), self.dofs.len());
                        self.dofs.push(name.clone());
                        self.series.push(new_series());
                        Some(self.dofs.len() - 1)
                    }
                };
                self.columns.push(column);
            }
        }
        for ((&column, name), &q) in self.columns.iter().zip(names).zip(positions) {
            let Some(d) = column else {
                *report.unknown_joints.entry(name.clone()).or_default() += 1;
                continue;
            };
            let s = &mut self.series[d];
            match s.last() {
                Some(&[last, _]) if stamp < last => {
                    self.abandoned = Some("joint stamps out of order");
                    return;
                }
                Some(&[last, _]) if stamp == last => report.duplicate_joint_stamps += 1,
                _ => s.push([stamp, q]),
            }
        }
        if self.grid.is_none() {
            let spanned = |s: &Samples| s.len() >= 2 && s[s.len() - 1][0] >= s[0][0] + GRID_SPAN;
            if !self.series.is_empty() && self.series.iter().all(spanned) {
                self.fix_grid(report);
            }
        }
    }

    /// The grid from the joint states so far (all of the first [`GRID_SPAN`] seconds).
    fn fix_grid(&mut self, report: &mut LogReport) {
        if self.series.iter().any(|s| s.len() < 2) {
            return;
        }
        match Grid::fit(self.path, &self.series) {
            Ok(grid) => {
                let mut early = std::mem::take(&mut self.early);
                while let Some((su, stamp, a)) = early.pop_front() {
                    if let Some(m) = held_at(&grid, stamp, report) {
                        self.held.push_back((su, m, a));
                    }
                }
                self.grid = Some(grid);
            }
            Err(_) => self.abandoned = Some("no grid from the first joint states"),
        }
    }

    /// Segments the stretch not yet settled up to the newest joint state common to every DoF.
    fn settle(&mut self, report: &mut LogReport) {
        let Some(grid) = self.grid.clone() else {
            if self.early.len() > MOST_HELD {
                self.abandoned = Some("too many samples before the grid was fixed");
            }
            return;
        };
        let newest = newest_common(&self.series);
        let to = ((newest - grid.t0) / grid.dt).floor();
        // A far-off stamp must not make a stretch of years: the two passes will say what is wrong.
        let samples = self.series.iter().map(|s| s.len()).max().unwrap_or(0) as f64;
        if to > 4.0 * samples + MAX_PAUSE / grid.dt {
            self.abandoned = Some("a joint stamp far off");
            return;
        }
        if to >= 0.0 {
            self.settle_to(to as usize + 1, false, report);
        }
        let held_for = self
            .held
            .front()
            .map_or(0.0, |(_, m, _)| (to - f64::from(m)) * grid.dt);
        if self.held.len() + self.strays.len() > MOST_HELD || held_for > LONGEST_HELD {
            self.abandoned = Some("a motion longer than the samples that may be held");
        }
    }

    /// Segments grid points `[from, to)`, the log's last when `at_end`, adds what is final to the
    /// windows and routes the held samples that precede what is not.
    fn settle_to(&mut self, to: usize, at_end: bool, report: &mut LogReport) {
        let Some(grid) = self.grid.as_mut() else {
            return;
        };
        self.rounding.resize(self.series.len(), Rounding::default());
        for (rounding, s) in self.rounding.iter_mut().zip(&self.series) {
            rounding.read(s);
        }
        grid.count = self.rounding.iter().map(Rounding::count).collect();
        let grid = grid.clone();
        if to > self.from {
            let timeline = Timeline::build(
                &grid,
                (&self.series, &self.dofs),
                self.from,
                to,
                self.config,
            );
            let mut found = pieces(&timeline, &self.dofs, self.config, at_end);
            let settled = if at_end {
                found.len()
            } else {
                found.len().saturating_sub(1)
            };
            // The pieces before the last are complete (all of them at the end).
            for (i, piece) in found.drain(..settled).enumerate() {
                self.seg.add(piece, i > 0 || !self.pause_added, report);
            }
            if let Some(open) = found.first() {
                if settled > 0 {
                    self.pause_added = false;
                }
                // Once its pause is over, its still window is final and the next window, the
                // motion's, starts 2l before the pause's end; until then the next windows start
                // a trim into the pause (the still window) or 2l + 1 points (the motion's: a
                // pause is at least 4l + 1 long) or later. The next stretch starts at the pause,
                // with the filter's reach before it.
                let l = filter_points(self.config, grid.dt);
                let earliest = trim_points(self.config, grid.dt, l).min(2 * l + 1);
                if open.closed && !self.pause_added {
                    self.seg.add_pause(open, report);
                    self.pause_added = true;
                }
                self.cut = if open.closed {
                    open.pause.1 - 2 * l
                } else {
                    open.pause.0 + earliest
                };
                self.from = open.pause.0.saturating_sub(l + 1);
            }
        }
        // The held samples in the order they came, up to the first that may fall in a window
        // not yet known; one far ahead of the joint states (a skin clock's jump, a damaged stamp)
        // waits aside until the log ends, so as not to hold up the others.
        let cut = if at_end { to } else { self.cut };
        let ahead = to.saturating_add((STRAY / grid.dt) as usize);
        if at_end {
            for s in self.strays.drain(..) {
                self.held.push_back(s);
            }
        }
        while let Some((su, m, acceleration)) = self.held.front() {
            if at_end && m as usize >= to {
                report.imu_outside += 1;
            } else if !at_end && m as usize >= ahead {
                self.strays.push((su, m, acceleration));
            } else if (m as usize) < cut {
                self.router.route(
                    &self.seg,
                    self.config,
                    su as usize,
                    m as usize,
                    acceleration,
                );
            } else {
                break;
            }
            self.held.pop_front();
        }
    }
}
