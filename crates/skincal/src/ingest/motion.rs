//! Logs → the motion record of the time-domain estimator (`motion.json`): every joint state and
//! skin sample of the logs on one grid of short blocks.
//!
//! Joint positions, velocities and accelerations at each block's centre come from a polynomial of
//! degree [`DEGREE`] fitted by least squares to the joint states within a half-width of it (jitter
//! and lost messages need no resampling first; an encoder's rounding is averaged over a window as
//! wide as the coarsest encoder needs, [`HALF_WIDTHS`], one for every DoF so that the skin can be
//! read through the same kernel, [`crate::motion::SkinFilter`], through which the positions and
//! velocities are then read too; the rounding's share of the
//! acceleration's uncertainty is a staircase's, [`rounded_acceleration_sd`]); the skin's fresh
//! samples are averaged per block and referred to its centre ([`super::blocks`]).

use std::collections::HashMap;
use std::path::PathBuf;

use nalgebra::{SMatrix, SVector};

use super::blocks::Centring;
use super::window::{JointSurvey, JointWindow, JointsSurveyed, SkinWindow};
use super::{IngestConfig, IngestError, IngestReport, LogReport, Progress};
use crate::log::{LogSource, Sample, Stream};
use crate::measurements::MeasurementSet;
use crate::motion::{Kernel, MotionRecord, MotionRun, SampleCount, MOTION_FORMAT, MOTION_VERSION};

/// Length of a block, s: the skin's samples are averaged over it (100 Hz: ten times the bandwidth
/// of any excitation a servo follows).
pub const BLOCK: f64 = 0.01;
pub use crate::motion::DEGREE;
/// Half-widths of the joint states' local polynomial, s, narrowest first: a record takes the
/// narrowest at which every DoF's encoder rounding leaves its acceleration a standard deviation
/// of at most [`ACCELERATION_NOISE`]. The narrowest follows every change of the motion (a
/// servo's jerk is no smoother than its commands) and the skin is read as block means; every
/// other reads the skin through the polynomial's own kernel ([`crate::motion::SkinFilter`],
/// from [`crate::motion::SKIN_FILTER_BLOCKS`] blocks), so that neither side is smoothed alone.
/// Between them (30–65 ms) the joints' accelerations would be smoothed and the skin not: a
/// 17-bit encoder read at 50 ms so left the paper arm's held-out dynamic error at 0.0070 m/s²,
/// and at 80 ms through the kernel 0.0016 (a Panda on reversing servos 0.0050 → 0.0042).
/// Wide averages a coarse encoder (a 13-bit one: 0.16 s at 1 kHz).
pub const HALF_WIDTHS: [f64; 6] = [0.02, 0.08, 0.1, 0.125, 0.16, 0.2];
/// The largest standard deviation of a DoF's acceleration that its encoder's rounding may leave,
/// rad/s² (0.01 m/s² at half a metre, half a block mean's noise).
pub const ACCELERATION_NOISE: f64 = 0.02;
/// The fewest joint states on each side of a block's centre within [`HALF_WIDTH`].
const FEWEST_PER_SIDE: usize = 3;
/// The fewest pairs of still blocks an SU's noise is estimated from.
const FEWEST_STILL_PAIRS: usize = 20;
/// The median of a χ² variable of one degree of freedom.
const CHI2_1_MEDIAN: f64 = 0.454_936_423_119_572_7;
/// The smallest noise a block mean is given, m/s² (0.01 mg): a simulated skin without noise
/// would otherwise weigh its still blocks without bound.
pub const NOISE_FLOOR: f64 = 1e-4;

/// The logs whose every sample the time-domain fit takes, all in one base orientation: those with
/// training poses (excitations), or where none has any, those where several DoFs moved at once (a
/// continuous program, ordinary work). A structure experiment's logs in other orientations have
/// neither, or their training is left out ([`LogReport::other_base`]).
pub fn training_logs(report: &IngestReport) -> Vec<PathBuf> {
    let with = |keep: &dyn Fn(&LogReport) -> bool| -> Vec<PathBuf> {
        report
            .logs
            .iter()
            .filter(|l| keep(l))
            .map(|l| l.path.clone())
            .collect()
    };
    let excited = with(&|l| l.excitations > 0 && !l.other_base);
    if excited.is_empty() {
        with(&|l| l.transfers > 0)
    } else {
        excited
    }
}

/// The motion record of the log files `logs` for the DoFs and SUs named (those of the
/// measurement set the same logs gave), in one pass over each log: [`motion_record_from`] files.
pub fn motion_record(
    logs: &[PathBuf],
    dofs: &[String],
    sus: &[String],
    config: &IngestConfig,
    progress: &mut Progress<'_>,
) -> Result<MotionRecord, IngestError> {
    let sources: Vec<LogSource> = logs.iter().cloned().map(LogSource::File).collect();
    motion_record_from(&sources, dofs, sus, config, progress)
}

/// What `skincal ingest` keeps beside the measurement set: the motion record of `ingested`'s
/// training logs ([`training_logs`]; `None` where no log has any), with what the set's structure
/// moves accelerated filled in from it ([`super::moves::accelerations_of_moves`]). Where
/// `config` names no kinds (no description), each DoF's is told from its structure moves first
/// ([`tell_kinds`]).
pub fn record_of(
    ingested: &mut super::Ingested,
    config: &IngestConfig,
    progress: &mut Progress<'_>,
) -> Result<Option<MotionRecord>, IngestError> {
    let mut record = training_record(ingested, config, progress)?;
    if config.prismatic.is_none() && tell_kinds(ingested, config, record.as_ref(), progress)? {
        record = training_record(ingested, config, progress)?;
    }
    if let Some(record) = &record {
        super::moves::accelerations_of_moves(&mut ingested.measurements, record);
        if let Some(tree) = tree_of_the_moves(ingested, config) {
            // The record is the logs' own, whichever tree attributes the readings.
            let config = IngestConfig {
                prismatic: Some(ingested.measurements.prismatic.clone()),
                tree: Some(tree),
                ..config.clone()
            };
            read_again(ingested, &config, progress)?;
            super::moves::accelerations_of_moves(&mut ingested.measurements, record);
        }
    }
    Ok(record)
}

/// Where DoFs were excited together and told apart by a tree explored from the structure part's
/// static readings, the tree that the structure part with its moves' accelerations (filled in)
/// gives, where that places some SU otherwise. A DoF about a vertical axis in a log of one base
/// orientation, or a slide, turns no gravity: the static tree has it move no SU, and every SU's
/// reading of it was set to zero. (The training readings, which that tree attributed, are left
/// out: their zeros would tell exploration that the DoF accelerated nothing.)
fn tree_of_the_moves(
    ingested: &super::Ingested,
    config: &IngestConfig,
) -> Option<crate::explore::Structure> {
    let used = ingested.moved_by.as_ref()?;
    if config.tree.is_some() {
        return None;
    }
    let set = &ingested.measurements;
    let structure_part = MeasurementSet {
        training: None,
        ..set.clone()
    };
    let tree = crate::explore::explore(&structure_part, &config.explore).ok()?;
    (super::assemble::moved_by_tree(&tree, &set.dofs, &set.sus) != *used).then_some(tree)
}

/// `ingested`'s logs read again with `config`, the DoFs' kinds told before kept.
fn read_again(
    ingested: &mut super::Ingested,
    config: &IngestConfig,
    progress: &mut Progress<'_>,
) -> Result<(), IngestError> {
    let logs: Vec<PathBuf> = ingested
        .report
        .logs
        .iter()
        .map(|l| l.path.clone())
        .collect();
    let kinds = std::mem::take(&mut ingested.report.kinds);
    *ingested = super::ingest(&logs, config, progress)?;
    note_kinds(&mut ingested.report, kinds);
    Ok(())
}

/// The motion record of `ingested`'s training logs, if any has some.
pub(super) fn training_record(
    ingested: &super::Ingested,
    config: &IngestConfig,
    progress: &mut Progress<'_>,
) -> Result<Option<MotionRecord>, IngestError> {
    let logs = training_logs(&ingested.report);
    if logs.is_empty() {
        return Ok(None);
    }
    let set = &ingested.measurements;
    let known: Vec<Option<&JointsSurveyed>> = logs
        .iter()
        .map(|path| {
            let log = ingested.report.logs.iter().find(|l| &l.path == path);
            log.and_then(|l| l.surveyed.as_ref())
        })
        .collect();
    let sources: Vec<LogSource> = logs.into_iter().map(LogSource::File).collect();
    record(&sources, &known, &set.dofs, &set.sus, config, progress).map(Some)
}

/// Each DoF's kind told from its structure moves ([`super::moves::kinds_of_moves`]), with what
/// `record` read of them where there is one (`ingested` read with `config`, which names no
/// kinds). Where some DoF slides, the logs are read again with the slides named (a slide's
/// pattern runs at a tenth of a turn's speed, which the pauses' thresholds must know:
/// [`IngestConfig::speed_scale`]), and `true` says so (a record made before is of the old set).
/// The set names the slides, the report says what told each DoF's kind and warns of those
/// nothing told (taken as revolute).
pub fn tell_kinds(
    ingested: &mut super::Ingested,
    config: &IngestConfig,
    record: Option<&MotionRecord>,
    progress: &mut Progress<'_>,
) -> Result<bool, IngestError> {
    let kinds = super::moves::kinds_of_moves(&ingested.measurements, record);
    let slides: Vec<String> = kinds
        .iter()
        .filter(|k| k.kind == Some(crate::model::DofKind::Prismatic))
        .map(|k| k.dof.clone())
        .collect();
    let again = !slides.is_empty();
    if again {
        let config = IngestConfig {
            prismatic: Some(slides),
            ..config.clone()
        };
        read_again(ingested, &config, progress)?;
    }
    note_kinds(&mut ingested.report, kinds);
    Ok(again)
}

/// The DoFs' kinds as told in `report`, with a warning of those nothing told.
fn note_kinds(report: &mut IngestReport, kinds: Vec<super::moves::KindTold>) {
    // The DoFs nothing told, grouped by why.
    let mut untold: std::collections::BTreeMap<&str, Vec<String>> = Default::default();
    for k in kinds.iter().filter(|k| k.kind.is_none()) {
        untold
            .entry(&k.evidence)
            .or_default()
            .push(format!("`{}`", k.dof));
    }
    if !untold.is_empty() {
        let why: Vec<String> = untold
            .iter()
            .map(|(why, dofs)| format!("{} ({why})", dofs.join(", ")))
            .collect();
        report.warnings.push(format!(
            "the structure moves did not tell whether DoF(s) {} slide or turn: taken as \
             revolute; if any is prismatic, name the robot's description (--robot) or the plan \
             (--plan)",
            why.join("; ")
        ));
    }
    report.kinds = kinds;
}

/// The motion record of `logs` (files or logs in memory) for the DoFs and SUs named, in memory
/// bounded by the record itself: a first look at each log's joint states tells each DoF's encoder
/// and rate ([`JointSurvey`]), and with them the polynomials' half-width; then a pass over each
/// log makes its blocks as its samples come ([`Blocks`]), holding only what the blocks still to
/// compute read. A log whose samples come so far out of their stamps' order that some would be
/// left out is read again holding all of them.
pub fn motion_record_from(
    logs: &[LogSource],
    dofs: &[String],
    sus: &[String],
    config: &IngestConfig,
    progress: &mut Progress<'_>,
) -> Result<MotionRecord, IngestError> {
    record(logs, &vec![None; logs.len()], dofs, sus, config, progress)
}

/// [`motion_record_from`] with what the measurement set's pass already told of some logs'
/// joint states (`known`, per log): those are not looked at again.
fn record(
    logs: &[LogSource],
    known: &[Option<&JointsSurveyed>],
    dofs: &[String],
    sus: &[String],
    config: &IngestConfig,
    progress: &mut Progress<'_>,
) -> Result<MotionRecord, IngestError> {
    let index = |names: &[String]| -> HashMap<String, usize> {
        names
            .iter()
            .enumerate()
            .map(|(i, n)| (n.clone(), i))
            .collect()
    };
    let (dof_index, su_index) = (index(dofs), index(sus));
    let surveys: Vec<Survey> = logs
        .iter()
        .zip(known)
        .map(|(log, known)| match known {
            Some(known) => Ok(Survey::known(known, dofs)),
            None => survey(log, &dof_index, config, progress),
        })
        .collect::<Result<_, _>>()?;
    let h = surveys
        .iter()
        .flat_map(|s| s.dofs.iter().map(JointSurvey::half_width))
        .fold(HALF_WIDTHS[0], f64::max);
    // Each DoF's coarsest rounding over the logs (one encoder; a log in which it never moved
    // tells none).
    let rounding = (0..dofs.len())
        .map(|d| {
            surveys
                .iter()
                .map(|s| s.dofs[d].rounding())
                .fold(0.0, f64::max)
        })
        .collect();
    let mut runs = Vec::new();
    let mut samples = vec![SampleCount::default(); sus.len()];
    for (log, survey) in logs.iter().zip(&surveys) {
        let Some(origin) = survey.origin else {
            continue;
        };
        let pass = Pass {
            source: log,
            origin,
            h,
            config,
        };
        let roundings: Vec<f64> = survey.dofs.iter().map(JointSurvey::rounding).collect();
        let mut part = pass.read(&dof_index, &su_index, &roundings, true, progress)?;
        if part.late > 0 {
            // A pass that holds every sample leaves none out.
            part = pass.read(&dof_index, &su_index, &roundings, false, progress)?;
        }
        for (total, count) in samples.iter_mut().zip(part.samples) {
            *total = total.plus(count);
        }
        runs.extend(part.runs);
    }
    if runs.is_empty() {
        return Err(IngestError::Empty(format!(
            "for the time-domain record in {}: no stretch of {} s where every DoF has joint states on both sides",
            logs.iter()
                .map(|l| l.path().display().to_string())
                .collect::<Vec<_>>()
                .join(", "),
            2.0 * HALF_WIDTHS[HALF_WIDTHS.len() - 1]
        )));
    }
    let noise_sd = (0..sus.len())
        .map(|u| still_noise(&runs, u, config))
        .collect();
    let record = MotionRecord {
        format: MOTION_FORMAT.into(),
        version: MOTION_VERSION,
        period: BLOCK,
        dofs: dofs.to_vec(),
        sus: sus.to_vec(),
        noise_sd,
        half_width: Some(h),
        rounding,
        runs,
        samples,
    };
    Ok(record)
}

/// How long after the latest skin sample one stamped earlier may still come, s: a block is
/// filled in once the skin is this far past it. Beyond the few milliseconds a board's driver
/// adds, and a second of blocks of 100 SUs is half a megabyte.
const SKIN_LATENCY: f64 = 1.0;

/// What a first look at a log's joint states tells: its first stamp (block 0 starts there) and
/// each DoF's encoder and rate.
struct Survey {
    origin: Option<f64>,
    dofs: Vec<JointSurvey>,
}

impl Survey {
    /// The survey of the DoFs `dofs` from what a pass over the log told.
    fn known(known: &JointsSurveyed, dofs: &[String]) -> Survey {
        Survey {
            origin: known.origin,
            dofs: dofs
                .iter()
                .map(|d| known.dofs.get(d).cloned().unwrap_or_default())
                .collect(),
        }
    }
}

fn survey(
    source: &LogSource,
    dof_index: &HashMap<String, usize>,
    config: &IngestConfig,
    progress: &mut Progress<'_>,
) -> Result<Survey, IngestError> {
    let mut survey = Survey {
        origin: None,
        dofs: vec![JointSurvey::default(); dof_index.len()],
    };
    let label = format!("joint states of {}", source.path().display());
    let total = source.size(Stream::Joints);
    source.read(
        Stream::Joints,
        &config.topics,
        &mut |sample| {
            if let Sample::Joints {
                stamp,
                names,
                positions,
            } = sample
            {
                survey.origin.get_or_insert(stamp);
                for (name, &q) in names.iter().zip(positions) {
                    if let (Some(&d), true) = (dof_index.get(name.as_str()), q.is_finite()) {
                        survey.dofs[d].take(stamp, q);
                    }
                }
            }
            Ok(())
        },
        &mut |done| progress(&label, done, total),
    )?;
    Ok(survey)
}

/// A log's part of the record.
struct LogPart {
    runs: Vec<MotionRun>,
    /// Per SU, its count of samples.
    samples: Vec<SampleCount>,
    /// The most joint states and skin blocks held at once while the log was read.
    #[cfg(test)]
    most_held: (usize, usize),
    /// Samples that came after the blocks that read them were computed (left out).
    late: usize,
}

/// One log's part of the record, made in one pass over its samples.
struct Pass<'a> {
    source: &'a LogSource,
    /// The stamp block 0 starts at.
    origin: f64,
    /// The polynomials' half-width, s.
    h: f64,
    config: &'a IngestConfig,
}

impl Pass<'_> {
    /// The runs of consecutive blocks at whose centres every DoF's local polynomial can be
    /// fitted (`roundings`: each DoF's encoder's), and per SU its count of samples. `bounded`:
    /// each block's joint states are computed as soon as every DoF's states reach past its
    /// window, and its skin once the skin has come [`SKIN_LATENCY`] past it, and what no later
    /// block reads is dropped (some sample may come after that: [`LogPart::late`]); else every
    /// sample is held and the blocks computed at the end.
    fn read(
        &self,
        dof_index: &HashMap<String, usize>,
        su_index: &HashMap<String, usize>,
        roundings: &[f64],
        bounded: bool,
        progress: &mut Progress<'_>,
    ) -> Result<LogPart, IngestError> {
        let mut blocks = Blocks {
            pass: self,
            roundings,
            kernel: Kernel::of_record(self.h, BLOCK),
            joints: JointWindow::new(dof_index.len()),
            skin: SkinWindow::new(su_index.len()),
            runs: Vec::new(),
            open: false,
            next_joints: 0,
            next_skin: 0,
            current: 0,
            centring: Centring::default(),
            #[cfg(test)]
            most_held: (0, 0),
        };
        let label = format!("motion of {}", self.source.path().display());
        let total = self.source.size(Stream::Both);
        self.source.read(
            Stream::Both,
            &self.config.topics,
            &mut |sample| {
                match sample {
                    Sample::Joints {
                        stamp,
                        names,
                        positions,
                    } => {
                        for (name, &q) in names.iter().zip(positions) {
                            if let (Some(&d), true) = (dof_index.get(name.as_str()), q.is_finite())
                            {
                                blocks.joints.take(d, stamp, q);
                            }
                        }
                    }
                    Sample::Imu {
                        stamp,
                        frame_id,
                        acceleration,
                    } => {
                        let a = acceleration.map(|x| x * self.config.skin_scale);
                        let at = (stamp - self.origin) / BLOCK;
                        let usable = a.iter().all(|x| x.is_finite()) && !self.config.saturated(&a);
                        if let (Some(&u), true) = (su_index.get(frame_id), at >= 0.0) {
                            blocks.skin.take(u, stamp, at, a, usable);
                        }
                    }
                }
                if bounded {
                    blocks.advance(matches!(sample, Sample::Joints { .. }));
                }
                Ok(())
            },
            &mut |done| progress(&label, done, total),
        )?;
        Ok(blocks.finish())
    }

    fn centre(&self, b: usize) -> f64 {
        self.origin + (b as f64 + 0.5) * BLOCK
    }
}

/// A log's blocks as its samples come: each block's joint states computed once every DoF's
/// states reach past its window, which opens, extends or ends a run; its skin once the skin has
/// come past it and its joint states are in, into the run it falls in.
struct Blocks<'a> {
    pass: &'a Pass<'a>,
    roundings: &'a [f64],
    kernel: Option<Kernel>,
    joints: JointWindow,
    skin: SkinWindow,
    /// The runs so far, each with the index of its first block.
    runs: Vec<(usize, MotionRun)>,
    /// Whether the last block computed extended the last run.
    open: bool,
    /// The next block whose joint states to compute.
    next_joints: usize,
    /// The next block whose skin to take.
    next_skin: usize,
    /// The run the next skin block falls in or precedes.
    current: usize,
    centring: Centring,
    /// The most joint states and skin blocks held after a sample.
    #[cfg(test)]
    most_held: (usize, usize),
}

impl Blocks<'_> {
    /// Computes the blocks whose samples are all in, and drops what no later block reads.
    /// `joint_states`: the sample just taken was a joint state (only that lets a block's joint
    /// states be computed; a skin sample, most of a log's, only lets a block's skin be taken).
    fn advance(&mut self, joint_states: bool) {
        let (h, latency) = (self.pass.h, SKIN_LATENCY);
        while joint_states
            && self
                .joints
                .newest_common()
                .is_some_and(|t| t > self.pass.centre(self.next_joints) + h)
        {
            self.compute_joints();
            self.joints
                .forget_before(self.pass.centre(self.next_joints) - h);
        }
        while self.next_skin < self.next_joints
            && self.skin.latest > self.pass.centre(self.next_skin) + 0.5 * BLOCK + latency
        {
            self.take_skin();
        }
        #[cfg(test)]
        {
            self.most_held = (
                self.most_held.0.max(self.joints.held()),
                self.most_held.1.max(self.skin.held()),
            );
        }
    }

    /// Block `next_joints`'s joint states, into the runs.
    fn compute_joints(&mut self) {
        let b = self.next_joints;
        let centre = self.pass.centre(b);
        let config = self.pass.config;
        let fitted = self.joints.fit(
            centre,
            self.pass.h,
            self.roundings,
            config.max_gap,
            self.kernel.as_ref(),
        );
        self.next_joints += 1;
        let Some(fitted) = fitted else {
            self.open = false;
            return;
        };
        if !self.open {
            let label = self.pass.source.path().display().to_string();
            self.runs.push((b, MotionRun::new(&label, centre)));
            self.open = true;
        }
        let (_, run) = self.runs.last_mut().expect("a run was opened");
        run.push_joints(&fitted);
        if self.kernel.is_some() {
            // The sharp states (`MotionRun::q_sharp`): the narrowest polynomial every DoF's
            // states allow, its own position and velocity; the kernel's where none does.
            let mut narrower = HALF_WIDTHS.into_iter().take_while(|&w| w < self.pass.h);
            let sharp = narrower
                .find_map(|w| {
                    self.joints
                        .fit(centre, w, self.roundings, config.max_gap, None)
                })
                .unwrap_or(fitted);
            run.push_sharp(&sharp.iter().map(|x| [x[0], x[1], x[2]]).collect::<Vec<_>>());
        }
    }

    /// Block `next_skin`'s raw means, into the run it falls in (its joint states are in).
    fn take_skin(&mut self) {
        let b = self.next_skin;
        let raw = self.skin.take_block(b);
        self.next_skin += 1;
        while let Some((first, run)) = self.runs.get_mut(self.current) {
            if b < *first {
                return;
            }
            if b < *first + run.len() {
                self.centring.push_skin(run, raw);
                return;
            }
            self.centring.finish(run);
            self.current += 1;
        }
    }

    /// Every block up to the last joint state every DoF has, as a whole log's record computes
    /// them; the runs of three blocks or more, and each SU's count of samples.
    fn finish(mut self) -> LogPart {
        #[cfg(test)]
        let most_held = self.most_held;
        if let Some(last) = self.joints.newest_common() {
            let blocks = ((last - self.pass.origin) / BLOCK).floor().max(0.0) as usize;
            while self.next_joints < blocks {
                self.compute_joints();
            }
        }
        while self.next_skin < self.next_joints {
            self.take_skin();
        }
        if let Some((_, run)) = self.runs.get_mut(self.current) {
            self.centring.finish(run);
        }
        let runs = self
            .runs
            .into_iter()
            .map(|(_, run)| run)
            .filter(|r| r.len() >= 3)
            .collect();
        LogPart {
            runs,
            samples: self.skin.samples(),
            #[cfg(test)]
            most_held,
            late: self.joints.late + self.skin.late,
        }
    }
}

/// The narrowest of [`HALF_WIDTHS`] at which an encoder's rounding (`rounding`: its standard
/// deviation, rad) leaves the DoF's acceleration within [`ACCELERATION_NOISE`] (the widest where
/// none does): the variance of the polynomial's second coefficient on a window of joint states
/// evenly spaced by `step` (the series' median, s).
pub(super) fn half_width_of(rounding: f64, step: f64) -> f64 {
    if rounding == 0.0 || !(step > 0.0 && step.is_finite()) {
        return HALF_WIDTHS[0];
    }
    let sd = |h: f64| {
        let n = (h / step).floor() as i64;
        let mut a = SMatrix::<f64, { DEGREE + 1 }, { DEGREE + 1 }>::zeros();
        for i in -n..=n {
            let phi = powers(i as f64 * step / h);
            a += phi * phi.transpose();
        }
        let inverse = a.try_inverse().map_or(f64::INFINITY, |m| m[(2, 2)]);
        rounding * 2.0 / (h * h) * inverse.sqrt()
    };
    HALF_WIDTHS
        .into_iter()
        .find(|&h| sd(h) <= ACCELERATION_NOISE)
        .unwrap_or(HALF_WIDTHS[HALF_WIDTHS.len() - 1])
}

/// `(1, x, x², …, x^DEGREE)`.
fn powers(x: f64) -> SVector<f64, { DEGREE + 1 }> {
    let mut phi = SVector::<f64, { DEGREE + 1 }>::zeros();
    let mut power = 1.0;
    for p in phi.iter_mut() {
        *p = power;
        power *= x;
    }
    phi
}

/// Position, velocity, acceleration and the acceleration's standard deviation at `centre` from
/// the polynomial of degree [`DEGREE`] fitted to the joint states within `h` (`rounding`: the
/// encoder's); `None` where too few lie on either side or a gap
/// longer than `max_gap` lies among them. `cursor`: the first state not before the window of the
/// previous (earlier) centre.
///
/// With `kernel` (a record whose skin is read through it, [`crate::motion::SkinFilter`]), the
/// position and velocity are read through the kernel too: the polynomial's acceleration is the
/// true one through the kernel, and the skin is read through it, so the position and velocity
/// must be — the polynomial's own are exact to a higher order (`∫K t⁴ ≠ 0`), and on a 6 Hz servo
/// at 160 ms the difference turns gravity by about 1 mrad in the fastest blocks.
pub(super) fn local_polynomial(
    series: &[(f64, f64)],
    cursor: &mut usize,
    centre: f64,
    h: f64,
    rounding: f64,
    max_gap: f64,
    kernel: Option<&Kernel>,
) -> Option<[f64; 4]> {
    const N: usize = DEGREE + 1;
    while *cursor < series.len() && series[*cursor].0 < centre - h {
        *cursor += 1;
    }
    let window: Vec<(f64, f64)> = series[*cursor..]
        .iter()
        .take_while(|s| s.0 <= centre + h)
        .copied()
        .collect();
    let before = window.iter().filter(|s| s.0 < centre).count();
    if before < FEWEST_PER_SIDE || window.len() - before < FEWEST_PER_SIDE {
        return None;
    }
    let edges = [
        window[0].0 - (centre - h),
        centre + h - window[window.len() - 1].0,
    ];
    let gaps = window.windows(2).map(|w| w[1].0 - w[0].0);
    if edges.into_iter().chain(gaps).any(|g| g > max_gap) {
        return None;
    }
    // In the scaled time x = (t − centre)/h, about the window's first position.
    let q0 = window[0].1;
    let mut a = SMatrix::<f64, N, N>::zeros();
    let mut rhs = SVector::<f64, N>::zeros();
    for &(t, q) in &window {
        let x = (t - centre) / h;
        let phi = powers(x);
        a += phi * phi.transpose();
        rhs += phi * (q - q0);
    }
    let cholesky = a.cholesky()?;
    let c = cholesky.solve(&rhs);
    // The acceleration's standard deviation from the fit's own misfit (an encoder's rounding, or
    // a change of the motion the polynomial cannot follow), and the rounding's at least.
    let misfit: f64 = window
        .iter()
        .map(|&(t, q)| (q - q0 - powers((t - centre) / h).dot(&c)).powi(2))
        .sum::<f64>()
        / (window.len() - N).max(1) as f64;
    let inverse = cholesky.inverse();
    let white = 2.0 / (h * h) * (misfit.max(rounding * rounding) * inverse[(2, 2)]).sqrt();
    let count = rounding * 12f64.sqrt();
    let (lowest, highest) = window
        .iter()
        .fold((f64::INFINITY, f64::NEG_INFINITY), |(lo, hi), &(_, q)| {
            (lo.min(q), hi.max(q))
        });
    // Crossing many counts, the readings' rounding errors are as good as independent: `white`.
    let qdd_sd = if rounding > 0.0 && highest - lowest <= MANY_COUNTS * count {
        let weights: Vec<(f64, f64)> = window
            .iter()
            .map(|&(t, _)| {
                let phi = powers((t - centre) / h);
                (2.0 / (h * h) * (inverse * phi)[2], phi.dot(&c))
            })
            .collect();
        white.max(rounded_acceleration_sd(&weights, count))
    } else {
        white
    };
    let own = (q0 + c[0], c[1] / h);
    let (q, qd) = kernel.map_or(own, |k| {
        through_kernel(k, &window, centre, h).unwrap_or(own)
    });
    Some([q, qd, 2.0 * c[2] / (h * h), qdd_sd])
}

/// The position and velocity of the joint states `window` (stamp, position) about `centre`
/// read through `kernel` of half-width `h`: `Σ K(xᵢ)Δxᵢ qᵢ / Σ K(xᵢ)Δxᵢ` and `−(1/h)∫K′q`,
/// normalised so that a line is exact, each reading standing for the half-gaps on either side of
/// it (trapezoids); `None` where the window carries no weight.
fn through_kernel(
    kernel: &Kernel,
    window: &[(f64, f64)],
    centre: f64,
    h: f64,
) -> Option<(f64, f64)> {
    let x = |i: usize| (window[i].0 - centre) / h;
    let q0 = window[0].1;
    let (mut value, mut weight, mut slope, mut scale) = (0.0, 0.0, 0.0, 0.0);
    for (i, &(_, q)) in window.iter().enumerate() {
        let before = if i == 0 { -1.0 } else { x(i - 1) };
        let after = if i + 1 < window.len() { x(i + 1) } else { 1.0 };
        let dx = 0.5 * (after - before);
        let (k, k1) = (kernel.value(x(i)) * dx, kernel.slope(x(i)) * dx);
        value += k * (q - q0);
        weight += k;
        slope += k1 * (q - q0);
        scale += k1 * x(i);
    }
    (weight > 0.0 && scale != 0.0).then(|| (q0 + value / weight, slope / (h * scale)))
}

/// Terms of the sawtooth's Fourier series in [`rounded_acceleration_sd`]: the variance they
/// leave out is at most 4 % of the whole.
const SAWTOOTH_TERMS: usize = 16;
/// Beyond this many counts crossed within the window, readings' rounding errors are as good as
/// independent, and [`rounded_acceleration_sd`] would give the white-noise value.
const MANY_COUNTS: f64 = 64.0;

/// The standard deviation that an encoder's rounding to whole counts of `count` (rad) leaves in
/// a local polynomial's acceleration, from each reading's weight in that acceleration and its
/// position along the polynomial, `(wᵢ, xᵢ)`. A rounded reading's error is a sawtooth of the
/// joint's true position, `count · saw(xᵢ/count + φ)` with `saw(u) = u − round(u)` and the
/// phase `φ` unknown (uniform): readings within a count of each other share their error. From
/// the sawtooth's Fourier series, `saw(u) = Σₖ (−1)^{k+1} sin(2πku)/(πk)`, the acceleration's
/// variance is `count² Σₖ |Σᵢ wᵢ e^{2πi k xᵢ/count}|² / (2π²k²)`: zero for a joint at rest (a
/// constant error is no acceleration), `count²/12 Σᵢ wᵢ²` for one crossing many counts (the
/// errors independent), and several times that for a joint creeping across a few, whose
/// staircase the polynomial bends to follow.
fn rounded_acceleration_sd(weights: &[(f64, f64)], count: f64) -> f64 {
    let mut sums = [nalgebra::Complex::new(0.0, 0.0); SAWTOOTH_TERMS];
    for &(w, x) in weights {
        // e^{2πikx/count} for k = 1, 2, … by repeated multiplication.
        let turn = nalgebra::Complex::from_polar(1.0, std::f64::consts::TAU * x / count);
        let mut power = turn;
        for sum in &mut sums {
            *sum += power * w;
            power *= turn;
        }
    }
    let variance: f64 = sums
        .iter()
        .enumerate()
        .map(|(k, sum)| sum.norm_sqr() / (2.0 * (std::f64::consts::PI * (k + 1) as f64).powi(2)))
        .sum();
    count * variance.sqrt()
}

/// The standard deviation of one component of SU `u`'s corrected block means, from three
/// consecutive ones whose raw means all came from blocks in which every DoF was still (below the
/// still speed, and not yet accelerating away): the median of their squared second differences
/// (robust to a glitch, and blind to a reading that drifts steadily while the robot creeps below
/// the still speed, as a distal SU's gravity does; a first difference takes such a drift for
/// noise), at least [`NOISE_FLOOR`]; `None` when fewer than [`FEWEST_STILL_PAIRS`] such runs
/// exist.
pub(crate) fn still_noise(runs: &[MotionRun], u: usize, config: &IngestConfig) -> Option<f64> {
    let still = |run: &MotionRun, b: usize| {
        run.qd[b].iter().all(|v| v.abs() < config.still_velocity)
            && run.qdd[b]
                .iter()
                .all(|a| a.abs() < 10.0 * config.still_velocity)
    };
    let mut squares = Vec::new();
    for run in runs {
        // The corrected means of b − 1 … b + 1 read the raw means of b − 2 … b + 2.
        for b in 2..run.len().saturating_sub(2) {
            if !(b - 2..=b + 2).all(|c| still(run, c)) {
                continue;
            }
            if let (Some(a), Some(m), Some(c)) = (
                run.skin.get(b - 1, u),
                run.skin.get(b, u),
                run.skin.get(b + 1, u),
            ) {
                squares.extend((0..3).map(|i| (a[i] - 2.0 * m[i] + c[i]).powi(2)));
            }
        }
    }
    if squares.len() < 3 * FEWEST_STILL_PAIRS {
        return None;
    }
    squares.sort_by(f64::total_cmp);
    let median = squares[squares.len() / 2];
    // In independent means, a corrected mean is (−m₋₁ + 26 m₀ − m₁)/24: a variance of 678/576 of
    // one mean's. The second difference of three corrected means is
    // (−m₋₂ + 28 m₋₁ − 54 m₀ + 28 m₁ − m₂)/24: 4486/576 of it.
    let sd = (median / CHI2_1_MEDIAN * 678.0 / 4486.0).sqrt();
    Some(sd.max(NOISE_FLOOR))
}

#[cfg(test)]
mod tests {
    use nalgebra::Vector3;

    use super::*;
    use crate::ingest::blocks::RawMean;
    use crate::ingest::timeline::encoder_rounding;
    use crate::motion::SkinFilter;

    /// The kernel keeps a cubic's value at the centre: `∫K = 1`, `∫K t = 0`, `∫K t² = 0`.
    #[test]
    fn the_skin_filter_keeps_a_cubic() {
        let (h, period) = (0.1, 0.001);
        let filter = SkinFilter::new(h, period).unwrap();
        let cubic = |t: f64| 0.3 - 2.0 * t + 40.0 * t * t + 900.0 * t * t * t;
        let series: Vec<Option<Vector3<f64>>> = (0..401)
            .map(|b| Some(Vector3::repeat(cubic(b as f64 * period))))
            .collect();
        let at = filter.smooth(&series, 200).unwrap();
        assert!(
            (at.x - cubic(0.2)).abs() < 1e-6,
            "{} vs {}",
            at.x,
            cubic(0.2)
        );
    }

    /// What the local polynomial makes of a joint whose acceleration steps (a servo's pattern
    /// starting without a window) is the true acceleration read through the kernel, wherever the
    /// step falls in the window: a least-squares fit on one side, a closed-form kernel on the other.
    #[test]
    fn the_polynomial_sees_the_acceleration_through_the_skin_filter() {
        let (h, period, rate) = (0.12, 0.001, 1000.0);
        let filter = SkinFilter::new(h, period).unwrap();
        let step_at = 0.5005;
        let q = |t: f64| 3.0 * 0.5 * (t - step_at).max(0.0).powi(2) + 0.1 * t;
        let series: Vec<(f64, f64)> = (0..1000)
            .map(|i| (i as f64 / rate, q(i as f64 / rate)))
            .collect();
        let qdd: Vec<Option<Vector3<f64>>> = (0..1000)
            .map(|i| {
                Some(Vector3::repeat(if i as f64 / rate >= step_at {
                    3.0
                } else {
                    0.0
                }))
            })
            .collect();
        for centre in [0.40, 0.45, 0.47, 0.50, 0.53, 0.58, 0.65] {
            let b = (centre * rate) as usize;
            let fitted =
                local_polynomial(&series, &mut 0, b as f64 / rate, h, 0.0, 0.01, None).unwrap();
            let filtered = filter.smooth(&qdd, b).unwrap().x;
            assert!(
                (fitted[2] - filtered).abs() < 0.02,
                "at {centre} s: polynomial {} vs kernel {filtered}",
                fitted[2]
            );
        }
        // Away from the step both are the acceleration itself.
        let far = local_polynomial(&series, &mut 0, 0.8, h, 0.0, 0.01, None).unwrap();
        assert!((far[2] - 3.0).abs() < 1e-6);
    }

    /// A fast joint motion read at 1 kHz through a wide polynomial: the position and velocity
    /// [`local_polynomial`] gives with the kernel are the true ones through the skin's kernel, as its acceleration is
    /// (truth: the kernel integrated against the analytic motion on a fine grid), within a
    /// hundredth of what the polynomial's own differ from them.
    #[test]
    fn position_and_velocity_are_read_through_the_skins_kernel() {
        let (h, rate, w) = (0.16, 1000.0, std::f64::consts::TAU * 3.0);
        let q = |t: f64| 0.4 * (w * t).sin() + 0.1 * (2.3 * w * t).cos() + 0.2 * t;
        let qd = |t: f64| 0.4 * w * (w * t).cos() - 0.23 * w * (2.3 * w * t).sin() + 0.2;
        let series: Vec<(f64, f64)> = (0..2000)
            .map(|i| (i as f64 / rate, q(i as f64 / rate)))
            .collect();
        let kernel = Kernel::new();
        let through = |f: &dyn Fn(f64) -> f64, centre: f64| {
            let n = 200_000;
            let dx = 2.0 / n as f64;
            (0..n)
                .map(|i| {
                    let x = -1.0 + (i as f64 + 0.5) * dx;
                    kernel.value(x) * f(centre + h * x) * dx
                })
                .sum::<f64>()
        };
        for centre in [0.5, 0.7321, 1.1] {
            let read =
                local_polynomial(&series, &mut 0, centre, h, 0.0, 0.01, Some(&kernel)).unwrap();
            let own = local_polynomial(&series, &mut 0, centre, h, 0.0, 0.01, None).unwrap();
            let (q_k, qd_k) = (through(&q, centre), through(&qd, centre));
            for (k, truth) in [(0, q_k), (1, qd_k)] {
                let (kernel_error, own_error) = ((read[k] - truth).abs(), (own[k] - truth).abs());
                assert!(
                    kernel_error < 0.01 * own_error && own_error > 1e-3,
                    "at {centre} s, {k}: through the kernel {}, the polynomial's own {}, truth {truth}",
                    read[k],
                    own[k]
                );
            }
            assert_eq!(read[2], own[2]);
        }
    }

    /// A joint that moves as a servo does (damped steps to targets drawn at random, each held
    /// until the next), read through a 13-bit encoder: at every speed, from creeping across a
    /// count to crossing hundreds, the acceleration's error (against the same polynomial through
    /// the exact positions) is what its stated standard deviation says. Taken as independent
    /// per reading, the rounding's share was 3–4 times too small where the joint creeps across a
    /// few counts, whose staircase the polynomial bends to follow.
    #[test]
    fn a_coarse_encoders_acceleration_is_as_uncertain_as_it_says() {
        use rand::{Rng, SeedableRng};
        use std::f64::consts::TAU;
        let count = TAU / 8192.0;
        let (omega, zeta, hold): (f64, f64, f64) = (TAU * 6.0, 0.8, 1.5);
        let damped = omega * (1.0 - zeta * zeta).sqrt();
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(7);
        let targets: Vec<f64> = (0..41).map(|_| rng.random_range(-0.3..0.3)).collect();
        let q = |t: f64| {
            let k = (t / hold) as usize;
            let (from, to) = (targets[k], targets[k + 1]);
            let s = t - k as f64 * hold;
            let decay = (-zeta * omega * s).exp();
            to + (from - to)
                * decay
                * ((damped * s).cos() + zeta * omega / damped * (damped * s).sin())
        };
        let exact: Vec<(f64, f64)> = (0..60_000)
            .map(|i| {
                let t = f64::from(i) * 1e-3;
                (t, q(t))
            })
            .collect();
        let rounded: Vec<(f64, f64)> = exact
            .iter()
            .map(|&(t, x)| (t, (x / count).round() * count))
            .collect();
        let h = 0.16;
        let states: Vec<[f64; 2]> = rounded.iter().map(|&(t, x)| [t, x]).collect();
        let rounding = encoder_rounding(&states);
        assert!((rounding * 12f64.sqrt() / count - 1.0).abs() < 1e-9);
        // By the counts the window's readings cross: none (held), a few (creeping), many.
        let edges = [1.0, 4.0, 21.0, 101.0, f64::INFINITY];
        let mut bins = [(0.0, 0usize); 5];
        let (mut a, mut b) = (0, 0);
        for centre in (20..5980).map(|k| f64::from(k) * 0.01) {
            let truth = local_polynomial(&exact, &mut a, centre, h, 0.0, 0.01, None).unwrap();
            let read = local_polynomial(&rounded, &mut b, centre, h, rounding, 0.01, None).unwrap();
            let window = rounded.iter().filter(|s| (s.0 - centre).abs() <= h);
            let (lo, hi) = window.fold((f64::INFINITY, f64::NEG_INFINITY), |(lo, hi), s| {
                (lo.min(s.1), hi.max(s.1))
            });
            let crossed = ((hi - lo) / count).round();
            let bin = edges.iter().position(|&e| crossed < e).unwrap();
            let error = read[2] - truth[2];
            if bin == 0 {
                // Readings of one count: the motion within it is below what the encoder tells.
                continue;
            }
            bins[bin].0 += (error / read[3]).powi(2);
            bins[bin].1 += 1;
        }
        // Where many counts are crossed, the stated deviation also holds the polynomial's own
        // misfit (a 6 Hz ringing that a cubic over 0.32 s does not follow), which the exact
        // positions share: there it exceeds the rounding's error many times.
        let lowest = [0.0, 0.6, 0.6, 0.0, 0.0];
        for ((edge, (sum, n)), low) in edges.iter().zip(bins).zip(lowest).skip(1) {
            let z = (sum / n as f64).sqrt();
            eprintln!(
                "fewer than {edge} counts crossed: {n} blocks, RMS error / stated deviation {z:.2}"
            );
            assert!(n >= 200 && (low..1.3).contains(&z), "{n} blocks, {z}");
        }
    }

    /// A skin whose block means carry independent noise of a known deviation, read while the
    /// arm holds still between short moves that start from rest (the speed below the still
    /// speed for a few blocks while the acceleration, and with it the reading, already grows):
    /// the noise comes out as the truth's, the moves' starts left out.
    #[test]
    fn the_still_noise_is_the_skins_own_whatever_the_moves_that_start_from_rest() {
        use rand::SeedableRng;
        use rand_distr::{Distribution, Normal};
        let sd = 0.02;
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(3);
        let noise = Normal::new(0.0, sd).unwrap();
        let mut run = MotionRun::new("test", 0.0);
        let mut centring = Centring::default();
        // 1000 cycles: 5 blocks of hold, then a move from rest whose acceleration ramps at
        // 45 rad/s³ for 5 blocks (the SU reads 0.8 q̈ more on each axis). The move's second and
        // third blocks are below the still speed (2 and 9 mrad/s) and read 0.36 and 0.72 m/s²
        // more.
        for _ in 0..1000 {
            for b in 0..10usize {
                let t = b.saturating_sub(5) as f64 * BLOCK;
                let (qdd, qd) = (45.0 * t, 22.5 * t * t);
                let joints = [[0.0, qd, qdd, 0.0]];
                let mean = [0.8 * qdd, 0.8 * qdd, 9.81 + 0.8 * qdd];
                let raw = vec![Some(RawMean {
                    value: std::array::from_fn(|i| mean[i] + noise.sample(&mut rng)),
                    time: 0.0,
                    time_squared: 1.0 / 12.0,
                })];
                centring.push(&mut run, &joints, raw);
            }
        }
        centring.finish(&mut run);
        let truth = sd * (678.0f64 / 576.0).sqrt();
        let found = still_noise(&[run], 0, &IngestConfig::default()).unwrap();
        assert!(
            (found / truth - 1.0).abs() < 0.05,
            "{found} for a truth of {truth}"
        );
    }

    /// How the samples of [`synthetic_log`] are put in the log.
    #[derive(Clone, Copy, PartialEq)]
    enum Order {
        /// By stamp, skin and joint states interleaved.
        Stamps,
        /// Every joint state first, then the skin SU by SU (as a hand-made CSV might).
        Grouped,
    }

    /// `seconds` of 1 kHz joint states of two DoFs moving smoothly (the second on a 13-bit
    /// encoder) and of three SUs reading smooth signals with the same stamps.
    fn synthetic_log(seconds: f64, order: Order) -> LogSource {
        use crate::log::{LogSink, MemoryLog, Time};
        let count = 2.0 * std::f64::consts::PI / 8192.0;
        let n = (seconds * 1000.0) as usize;
        let stamp = |i: usize| 100.0 + i as f64 * 1e-3;
        let q = |t: f64| {
            [
                0.4 * (1.3 * t).sin(),
                ((0.7 * t).cos() / count).round() * count,
            ]
        };
        let a = |u: usize, t: f64| [u as f64 + (2.0 * t).sin(), 9.81 * (0.5 * t).cos(), 0.1];
        let mut log = MemoryLog::new("synthetic");
        let dofs = ["j1".to_string(), "j2".into()];
        let sus: Vec<String> = (0..3).map(|u| format!("su{u}")).collect();
        log.start(&dofs, &sus, 0.0).unwrap();
        let t = Time::from_seconds;
        let joint = |log: &mut MemoryLog, i: usize| {
            let s = stamp(i);
            log.joint_state(t(s), t(s), &q(s), &[0.0; 2]).unwrap();
        };
        match order {
            Order::Stamps => {
                for i in 0..n {
                    joint(&mut log, i);
                    for u in 0..3 {
                        log.imu(t(stamp(i)), t(stamp(i)), u, a(u, stamp(i)))
                            .unwrap();
                    }
                }
            }
            Order::Grouped => {
                for i in 0..n {
                    joint(&mut log, i);
                }
                for u in 0..3 {
                    for i in 0..n {
                        log.imu(t(stamp(i)), t(stamp(i)), u, a(u, stamp(i)))
                            .unwrap();
                    }
                }
            }
        }
        LogSource::Memory(log)
    }

    fn names(prefix: &str, n: usize) -> Vec<String> {
        (0..n).map(|i| format!("{prefix}{i}")).collect()
    }

    #[test]
    fn the_record_pass_holds_what_its_next_blocks_read_however_long_the_log() {
        let dofs = vec!["j1".to_string(), "j2".into()];
        let sus = names("su", 3);
        let config = IngestConfig::default();
        let index = |names: &[String]| -> HashMap<String, usize> {
            names.iter().cloned().zip(0..).collect()
        };
        let held = |seconds: f64| {
            let source = synthetic_log(seconds, Order::Stamps);
            let survey = survey(&source, &index(&dofs), &config, &mut |_, _, _| {}).unwrap();
            let h = survey
                .dofs
                .iter()
                .map(JointSurvey::half_width)
                .fold(0.0, f64::max);
            let pass = Pass {
                source: &source,
                origin: survey.origin.unwrap(),
                h,
                config: &config,
            };
            let roundings: Vec<f64> = survey.dofs.iter().map(JointSurvey::rounding).collect();
            let part = pass
                .read(
                    &index(&dofs),
                    &index(&sus),
                    &roundings,
                    true,
                    &mut |_, _, _| {},
                )
                .unwrap();
            assert_eq!(part.late, 0);
            // Every block but those within a half-width of the ends.
            let blocks: usize = part.runs.iter().map(MotionRun::len).sum();
            let ends = 2 * (h / BLOCK).ceil() as usize + 1;
            assert!(
                blocks + ends >= (seconds / BLOCK) as usize,
                "{blocks} blocks"
            );
            (h, part.most_held)
        };
        let (h, short) = held(10.0);
        let (_, long) = held(60.0);
        // The 13-bit encoder needs a wide polynomial; the joint states of its window on either
        // side, and a second of skin blocks, whatever the log's length.
        assert!(h >= 0.1, "{h}");
        assert_eq!(short, long);
        let window = dofs.len() * (2 * ((h + 2.0 * BLOCK) * 1000.0) as usize + 2);
        assert!(long.0 <= window, "{long:?} against {window}");
        let latency = ((SKIN_LATENCY + 2.0 * BLOCK) / BLOCK) as usize;
        assert!(long.1 <= latency, "{long:?} against {latency}");
    }

    #[test]
    fn a_log_out_of_stamp_order_gives_the_record_it_gives_in_order() {
        let dofs = vec!["j1".to_string(), "j2".into()];
        let sus = names("su", 3);
        let config = IngestConfig::default();
        let record = |order| {
            motion_record_from(
                &[synthetic_log(12.0, order)],
                &dofs,
                &sus,
                &config,
                &mut |_, _, _| {},
            )
            .unwrap()
        };
        let (ordered, grouped) = (record(Order::Stamps), record(Order::Grouped));
        assert_eq!(ordered.runs, grouped.runs);
        assert_eq!(ordered.samples, grouped.samples);
        // And what it holds is the motion: the first DoF's acceleration and an SU's reading at
        // a block's centre.
        let run = &ordered.runs[0];
        let b = run.len() / 2;
        let t = run.start + b as f64 * BLOCK;
        assert!((run.qdd[b][0] + 0.4 * 1.69 * (1.3 * t).sin()).abs() < 1e-4);
        let skin = run.skin.get(b, 1).unwrap();
        assert!(
            (skin[1] - 9.81 * (0.5 * t).cos()).abs() < 1e-4,
            "{skin:?} at {t}"
        );
    }
}
