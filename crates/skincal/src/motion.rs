//! A log's motion as the time-domain estimator takes it (`motion.json`): the joint states and their
//! first two derivatives, and the skin's samples, on one grid of short blocks.
//!
//! Every sample of the log is in it. A block holds the mean of each SU's fresh samples in it (a
//! sample that exactly repeats the one before is a board behind its port, not a measurement) and
//! the joint positions, velocities and accelerations at its centre from a local polynomial fitted
//! to the joint states around it. The skin's block means are referred to the block's centre from
//! the times of their samples (a block mean is the reading at its samples' mean time, plus their
//! spread times half the reading's second derivative), so that both sides describe the same
//! instant.
//!
//! A coarse encoder needs a wide polynomial, which sees the joint's acceleration through a
//! kernel of its half-width ([`SkinFilter`]); the time-domain fit then reads the skin through the
//! same kernel, and the record holds the joint positions and velocities through it too, so that
//! neither side is smoothed alone.

use std::sync::Arc;

use nalgebra::{SMatrix, SVector, Vector3};
use serde::{Deserialize, Serialize};
use skincal_scratch::Buffer;

use crate::model::sensor::MAX_READING;

/// The `format` of a motion record.
pub const MOTION_FORMAT: &str = "skincal-motion";
/// The `version` of a motion record.
pub const MOTION_VERSION: u32 = 1;

/// The motion of a robot over one or more logs.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct MotionRecord {
    /// Always [`MOTION_FORMAT`].
    pub format: String,
    /// Always [`MOTION_VERSION`].
    pub version: u32,
    /// Length of a block, s.
    pub period: f64,
    /// The DoFs, in the order of every `q`, `qd`, `qdd` row.
    pub dofs: Vec<String>,
    /// The SUs, in the order of every `skin` row.
    pub sus: Vec<String>,
    /// Each SU's standard deviation of one component of a block mean, m/s², from the blocks in
    /// which the robot was still (`null`: never still long enough to tell).
    pub noise_sd: Vec<Option<f64>>,
    /// The half-width of the local polynomial every DoF's joint states were read through, s
    /// (`null`: a record written before this was kept, read as narrow).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub half_width: Option<f64>,
    /// Per DoF: the standard deviation of its encoder's rounding to whole counts (a count over
    /// √12), rad (m for a prismatic DoF); 0 where the readings are not rounded. Empty: a record
    /// written before this was kept, read as unrounded.
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub rounding: Vec<f64>,
    /// Stretches of consecutive blocks (a log, or the part of one between gaps in the joint
    /// states).
    pub runs: Vec<MotionRun>,
    /// Per SU: how many samples the logs held and why some were not used (empty: not counted, a
    /// record written before this was kept).
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub samples: Vec<SampleCount>,
}

/// How many samples of one SU a log held, and why some of them are in no block.
#[derive(Debug, Clone, Copy, Default, PartialEq, Serialize, Deserialize)]
pub struct SampleCount {
    /// Samples the log held for it.
    pub sent: u64,
    /// Of those, exactly the one before: a port repeating the last value of a board slower than
    /// it, or of a board that stopped measuring.
    pub repeated: u64,
    /// Of those, not finite or at the accelerometer's range (saturated).
    pub unusable: u64,
    /// The longest time it sent one value over and over, s (from the value's first sample to its
    /// last repeat).
    pub longest_repeat: f64,
    /// The longest time all its samples were unusable, s.
    pub longest_unusable: f64,
}

impl SampleCount {
    /// The sum of two counts (one SU over two logs).
    pub fn plus(self, other: SampleCount) -> SampleCount {
        SampleCount {
            sent: self.sent + other.sent,
            repeated: self.repeated + other.repeated,
            unusable: self.unusable + other.unusable,
            longest_repeat: self.longest_repeat.max(other.longest_repeat),
            longest_unusable: self.longest_unusable.max(other.longest_unusable),
        }
    }
}

/// Counts one SU's samples as they come, in order.
#[derive(Debug, Clone, Copy, Default)]
pub struct SampleCounter {
    /// What it counted so far.
    pub count: SampleCount,
    /// The stamp of the last fresh sample.
    fresh: Option<f64>,
    /// The stamp of the first of the current unusable samples.
    bad: Option<f64>,
}

impl SampleCounter {
    /// Counts one sample stamped `stamp` (s): `usable` (finite, within range), `repeat` (exactly
    /// the usable one before).
    pub fn add(&mut self, stamp: f64, usable: bool, repeat: bool) {
        let c = &mut self.count;
        c.sent += 1;
        if usable {
            self.bad = None;
            if repeat {
                c.repeated += 1;
                let from = *self.fresh.get_or_insert(stamp);
                c.longest_repeat = c.longest_repeat.max(stamp - from);
            } else {
                self.fresh = Some(stamp);
            }
        } else {
            c.unusable += 1;
            let from = *self.bad.get_or_insert(stamp);
            c.longest_unusable = c.longest_unusable.max(stamp - from);
        }
    }
}

/// Consecutive blocks.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct MotionRun {
    /// The log the run comes from.
    pub log: String,
    /// Centre of the first block on the joint states' clock, s.
    pub start: f64,
    /// `q[b][d]`: position of DoF `d` at the centre of block `b`, rad (read through the record's
    /// [`SkinFilter`] kernel where it has one, as the velocities are; the accelerations are the
    /// polynomial's, which is the same kernel).
    pub q: JointRows,
    /// Velocities, rad/s.
    pub qd: JointRows,
    /// Accelerations, rad/s².
    pub qdd: JointRows,
    /// The standard deviation of each acceleration, rad/s², from the local polynomial's misfit: an
    /// encoder's rounding, or a change of the motion too sudden for the polynomial to follow.
    pub qdd_sd: JointRows,
    /// `skin[b][u]`: the mean specific force SU `u` read in block `b` (SU frame, m/s²), `null`
    /// where it sent no fresh sample.
    pub skin: SkinRows,
    /// Where the record reads the skin through a kernel ([`SkinFilter`]): the positions,
    /// velocities and accelerations at each block's centre from the narrowest polynomial the
    /// joint states allow, not read through the kernel (empty otherwise; rows as `q`'s). The
    /// skin read through the kernel is the specific force read through it, which differs from the
    /// specific force at the joint states read through it by the motion's spread within the
    /// kernel (gravity turned by the position, the centripetal terms); from these the fit
    /// predicts through the kernel too.
    #[serde(default, skip_serializing_if = "Rows::is_empty")]
    pub q_sharp: JointRows,
    /// Velocities, rad/s (as `q_sharp`).
    #[serde(default, skip_serializing_if = "Rows::is_empty")]
    pub qd_sharp: JointRows,
    /// Accelerations, rad/s² (as `q_sharp`).
    #[serde(default, skip_serializing_if = "Rows::is_empty")]
    pub qdd_sharp: JointRows,
}

/// A run's values per block and entry (DoF or SU), row by row in one [`Buffer`], which past a
/// few megabytes is a memory-mapped scratch file: the fit reads a window of blocks at a time,
/// every entry of each, and a long record's rows are the page cache's rather than the heap's. A
/// copy shares the values until one of them is changed: the time-domain fit reads a record's
/// skin as it is, without a copy of its own. Row `b` is [`Rows::slice`]`(b)`.
#[derive(Debug, Clone, Default)]
pub struct Rows<E: Entry> {
    /// The number of rows.
    rows: usize,
    /// Entries per row (the first row's).
    width: usize,
    values: Arc<Buffer<E>>,
    /// The first row read with another number of entries than the first, and that number (the
    /// row is kept cut, or padded with [`Entry::NONE`], to the width; [`MotionRecord::check`]
    /// refuses it).
    ragged: Option<(usize, usize)>,
}

/// What [`Rows`] hold per entry, and how `motion.json` writes it.
pub trait Entry: bytemuck::Pod + Default {
    /// An entry with no value (NaN).
    const NONE: Self;
    /// An entry as given and as read from `motion.json`.
    type In: serde::de::DeserializeOwned + Copy;
    /// An entry as written to `motion.json`.
    type Out: Serialize;
    /// What the rows are, for serde's error message.
    const EXPECTING: &'static str;
    /// An entry as held.
    fn held(entry: Self::In) -> Self;
    /// An entry as written.
    fn written(self) -> Self::Out;
}

impl Entry for f64 {
    const NONE: Self = f64::NAN;
    type In = f64;
    type Out = f64;
    const EXPECTING: &'static str = "rows of numbers per DoF";
    fn held(entry: f64) -> f64 {
        entry
    }
    fn written(self) -> f64 {
        self
    }
}

/// A skin mean as held: `NONE` (NaN) where there is none; written in single precision (`null`
/// where there is none), as it is held.
impl Entry for [f32; 3] {
    const NONE: Self = [f32::NAN; 3];
    type In = Option<[f64; 3]>;
    type Out = Option<[f32; 3]>;
    const EXPECTING: &'static str = "rows of `null` or `[x, y, z]` per SU";
    fn held(mean: Option<[f64; 3]>) -> Self {
        mean.map_or(Self::NONE, |m| m.map(|x| x as f32))
    }
    fn written(self) -> Option<[f32; 3]> {
        (!self[0].is_nan()).then_some(self)
    }
}

/// One number per DoF and block of a run (`[block][d]`), rad, rad/s or rad/s²; written as rows
/// of numbers. Row `b` is `rows[b]`.
pub type JointRows = Rows<f64>;

/// The skin's block means of a run, `[block][u]`, held in single precision: a millionth of a
/// m/s² at gravity's size, far below any accelerometer's resolution and a block mean's noise,
/// and 12 bytes per SU and block (a minute of 100 SUs in 10 ms blocks is 7.2 MB). Written as
/// rows of `null` (no fresh sample in the block) or `[x, y, z]`.
pub type SkinRows = Rows<[f32; 3]>;

impl<E: Entry> Rows<E> {
    /// `rows` rows of `width` entries, none of them holding a value.
    pub fn empty(width: usize, rows: usize) -> Self {
        Self {
            rows,
            width,
            values: Arc::new(Buffer::filled(width * rows, E::NONE)),
            ragged: None,
        }
    }

    /// The number of rows (blocks).
    pub fn len(&self) -> usize {
        self.rows
    }

    /// Whether there is no row.
    pub fn is_empty(&self) -> bool {
        self.rows == 0
    }

    /// Entries per row (0 before the first row).
    pub fn width(&self) -> usize {
        self.width
    }

    /// Whether its values are in a scratch file rather than on the heap.
    pub fn is_mapped(&self) -> bool {
        self.values.is_mapped()
    }

    /// Row `b` as held (a row within the rows).
    pub fn slice(&self, b: usize) -> &[E] {
        assert!(b < self.rows, "row {b} of {}", self.rows);
        &self.values[b * self.width..(b + 1) * self.width]
    }

    /// Row `b` as held, to change (a row within the rows).
    pub fn slice_mut(&mut self, b: usize) -> &mut [E] {
        assert!(b < self.rows, "row {b} of {}", self.rows);
        let width = self.width;
        &mut Arc::make_mut(&mut self.values)[b * width..(b + 1) * width]
    }

    /// Adds a row of `len` entries (the first sets the width), `at(i)` giving entry `i`.
    fn push_with(&mut self, len: usize, at: impl Fn(usize) -> E) {
        if self.rows == 0 && self.width == 0 {
            self.width = len;
        }
        if len != self.width && self.ragged.is_none() {
            self.ragged = Some((self.rows, len));
        }
        let values = Arc::make_mut(&mut self.values);
        let start = values.len();
        values.resize(start + self.width, E::NONE);
        for (i, slot) in values[start..].iter_mut().enumerate().take(len) {
            *slot = at(i);
        }
        self.rows += 1;
    }

    /// The rows from `at` on, taken off (these keep the first `at`).
    pub fn split_off(&mut self, at: usize) -> Self {
        let at = at.min(self.rows);
        let mut rest = Buffer::new();
        rest.extend_from_slice(&self.values[at * self.width..]);
        Arc::make_mut(&mut self.values).truncate(at * self.width);
        let rest = Self {
            rows: self.rows - at,
            width: self.width,
            values: Arc::new(rest),
            ragged: None,
        };
        self.rows = at;
        rest
    }

    /// Appends `other`'s rows.
    pub fn append(&mut self, other: &mut Self) {
        if self.rows == 0 && self.width == 0 {
            std::mem::swap(self, other);
            return;
        }
        if other.width == self.width {
            Arc::make_mut(&mut self.values).extend_from_slice(&other.values);
            self.rows += other.rows;
        } else {
            for b in 0..other.rows {
                let row = other.slice(b);
                self.push_with(row.len(), |i| row[i]);
            }
        }
        *other = Self::default();
    }

    /// Adds a row (the first sets the width).
    pub fn push(&mut self, row: &[E::In]) {
        self.push_with(row.len(), |i| E::held(row[i]));
    }

    /// The first row read with another number of entries than the first, and that number.
    fn ragged(&self) -> Option<(usize, usize)> {
        self.ragged
    }
}

impl JointRows {
    /// Every row in order.
    pub fn iter(&self) -> impl ExactSizeIterator<Item = &[f64]> + '_ {
        (0..self.rows).map(|b| self.slice(b))
    }

    /// The first row.
    pub fn first(&self) -> Option<&[f64]> {
        (self.rows > 0).then(|| self.slice(0))
    }
}

impl std::ops::Index<usize> for JointRows {
    type Output = [f64];
    fn index(&self, b: usize) -> &[f64] {
        self.slice(b)
    }
}

impl std::ops::IndexMut<usize> for JointRows {
    fn index_mut(&mut self, b: usize) -> &mut [f64] {
        self.slice_mut(b)
    }
}

impl SkinRows {
    /// SU `u`'s mean in block `b`; `None` where it sent no fresh sample, or beyond the rows.
    pub fn get(&self, b: usize, u: usize) -> Option<[f64; 3]> {
        if u >= self.width || b >= self.rows {
            return None;
        }
        let m = self.values[b * self.width + u];
        (!m[0].is_nan()).then(|| m.map(f64::from))
    }

    /// Row `b`, SU by SU.
    pub fn row(&self, b: usize) -> impl Iterator<Item = Option<[f64; 3]>> + '_ {
        (0..self.width()).map(move |u| self.get(b, u))
    }

    /// Sets SU `u`'s mean in block `b` (a block within the rows).
    pub fn set(&mut self, b: usize, u: usize, mean: Option<[f64; 3]>) {
        if u < self.width && b < self.rows {
            self.slice_mut(b)[u] = Entry::held(mean);
        }
    }

    /// Replaces row `b` (a row within the rows).
    pub fn set_row(&mut self, b: usize, row: &[Option<[f64; 3]>]) {
        for u in 0..self.width() {
            self.set(b, u, row.get(u).copied().flatten());
        }
    }
}

/// Two records' rows are the same where they hold the same bits (a missing value is equal to a
/// missing value).
impl<E: Entry> PartialEq for Rows<E> {
    fn eq(&self, other: &Self) -> bool {
        fn bytes<E: Entry>(r: &Rows<E>) -> &[u8] {
            bytemuck::cast_slice(&r.values[..])
        }
        self.rows == other.rows
            && self.width == other.width
            && self.ragged == other.ragged
            && bytes(self) == bytes(other)
    }
}

impl<E: Entry> From<Vec<Vec<E::In>>> for Rows<E> {
    fn from(rows: Vec<Vec<E::In>>) -> Self {
        let mut out = Self::default();
        for row in &rows {
            out.push(row);
        }
        out
    }
}

impl<E: Entry> Serialize for Rows<E> {
    fn serialize<S: serde::Serializer>(&self, serializer: S) -> Result<S::Ok, S::Error> {
        use serde::ser::SerializeSeq;
        let mut rows = serializer.serialize_seq(Some(self.rows))?;
        for b in 0..self.rows {
            let row: Vec<E::Out> = self.slice(b).iter().map(|e| e.written()).collect();
            rows.serialize_element(&row)?;
        }
        rows.end()
    }
}

/// Read one row at a time into the flat store, never a nested `Vec` of the whole run.
impl<'de, E: Entry> Deserialize<'de> for Rows<E> {
    fn deserialize<D: serde::Deserializer<'de>>(deserializer: D) -> Result<Self, D::Error> {
        struct Visitor<E>(std::marker::PhantomData<E>);
        impl<'de, E: Entry> serde::de::Visitor<'de> for Visitor<E> {
            type Value = Rows<E>;
            fn expecting(&self, f: &mut std::fmt::Formatter) -> std::fmt::Result {
                f.write_str(E::EXPECTING)
            }
            fn visit_seq<A: serde::de::SeqAccess<'de>>(
                self,
                mut seq: A,
            ) -> Result<Rows<E>, A::Error> {
                let mut out = Rows::default();
                while let Some(row) = seq.next_element::<Vec<E::In>>()? {
                    out.push(&row);
                }
                Arc::make_mut(&mut out.values).shrink_to_fit();
                Ok(out)
            }
        }
        deserializer.deserialize_seq(Visitor(std::marker::PhantomData))
    }
}

impl MotionRun {
    /// A run of no block yet, its first block's centre at `start`.
    pub fn new(log: &str, start: f64) -> Self {
        Self {
            log: log.to_string(),
            start,
            q: JointRows::default(),
            qd: JointRows::default(),
            qdd: JointRows::default(),
            qdd_sd: JointRows::default(),
            skin: SkinRows::default(),
            q_sharp: JointRows::default(),
            qd_sharp: JointRows::default(),
            qdd_sharp: JointRows::default(),
        }
    }

    /// Adds a block's sharp joint states (`[q, q̇, q̈]` per DoF, see [`MotionRun::q_sharp`]).
    pub fn push_sharp(&mut self, joints: &[[f64; 3]]) {
        let column = |k: usize| joints.iter().map(|x| x[k]).collect::<Vec<f64>>();
        self.q_sharp.push(&column(0));
        self.qd_sharp.push(&column(1));
        self.qdd_sharp.push(&column(2));
    }

    /// Adds a block: per DoF `[q, q̇, q̈, q̈'s deviation]`, and each SU's block mean.
    pub fn push(&mut self, joints: &[[f64; 4]], skin: Vec<Option<[f64; 3]>>) {
        self.push_joints(joints);
        self.skin.push(&skin);
    }

    /// Adds a block's joint states (per DoF `[q, q̇, q̈, q̈'s deviation]`) without its skin, which
    /// is added after ([`SkinRows::push`]).
    pub fn push_joints(&mut self, joints: &[[f64; 4]]) {
        let column = |k: usize| joints.iter().map(|x| x[k]).collect::<Vec<f64>>();
        self.q.push(&column(0));
        self.qd.push(&column(1));
        self.qdd.push(&column(2));
        self.qdd_sd.push(&column(3));
    }

    /// The number of blocks.
    pub fn len(&self) -> usize {
        self.q.len()
    }

    /// The blocks from `at` on, taken off this run (which keeps the first `at`); blocks are
    /// `period` long.
    pub fn split_off(&mut self, at: usize, period: f64) -> MotionRun {
        let at = at.min(self.len());
        MotionRun {
            log: self.log.clone(),
            start: self.start + at as f64 * period,
            q: self.q.split_off(at),
            qd: self.qd.split_off(at),
            qdd: self.qdd.split_off(at),
            qdd_sd: self.qdd_sd.split_off(at),
            skin: self.skin.split_off(at),
            q_sharp: self.q_sharp.split_off(at),
            qd_sharp: self.qd_sharp.split_off(at),
            qdd_sharp: self.qdd_sharp.split_off(at),
        }
    }

    /// Appends `next` when it continues this run (same log, its first block the one after this
    /// run's last, blocks `period` long); else gives it back.
    pub fn extend_with(&mut self, mut next: MotionRun, period: f64) -> Option<MotionRun> {
        let end = self.start + self.len() as f64 * period;
        if next.log != self.log || (next.start - end).abs() > 1e-3 * period {
            return Some(next);
        }
        self.q.append(&mut next.q);
        self.qd.append(&mut next.qd);
        self.qdd.append(&mut next.qdd);
        self.qdd_sd.append(&mut next.qdd_sd);
        self.skin.append(&mut next.skin);
        self.q_sharp.append(&mut next.q_sharp);
        self.qd_sharp.append(&mut next.qd_sharp);
        self.qdd_sharp.append(&mut next.qdd_sharp);
        None
    }

    /// Whether the run has no block.
    pub fn is_empty(&self) -> bool {
        self.q.is_empty()
    }
}

impl MotionRecord {
    /// Checks the format, the shapes and the ranges; the error names the field.
    pub fn check(&self) -> Result<(), String> {
        if self.format != MOTION_FORMAT || self.version != MOTION_VERSION {
            return Err(format!(
                "`format`/`version` are {:?}/{}, expected {MOTION_FORMAT:?}/{MOTION_VERSION} (a record written by `skincal ingest`)",
                self.format, self.version
            ));
        }
        if !(self.period.is_finite() && self.period > 0.0 && self.period <= 1.0) {
            return Err(format!(
                "`period` is {}, expected a block length in (0, 1] s",
                self.period
            ));
        }
        if self.noise_sd.len() != self.sus.len() {
            return Err(format!(
                "`noise_sd` has {} entries for {} SUs",
                self.noise_sd.len(),
                self.sus.len()
            ));
        }
        if !self.rounding.is_empty() && self.rounding.len() != self.dofs.len() {
            return Err(format!(
                "`rounding` has {} entries for {} DoFs",
                self.rounding.len(),
                self.dofs.len()
            ));
        }
        if let Some((d, x)) = self
            .rounding
            .iter()
            .enumerate()
            .find(|(_, x)| !(x.is_finite() && **x >= 0.0))
        {
            return Err(format!(
                "`rounding[{d}]` is {x}, expected a standard deviation ≥ 0"
            ));
        }
        if !self.samples.is_empty() && self.samples.len() != self.sus.len() {
            return Err(format!(
                "`samples` has {} entries for {} SUs",
                self.samples.len(),
                self.sus.len()
            ));
        }
        if let Some((u, sd)) = self
            .noise_sd
            .iter()
            .enumerate()
            .find_map(|(u, s)| s.filter(|s| !(s.is_finite() && *s > 0.0)).map(|s| (u, s)))
        {
            return Err(format!(
                "`noise_sd[{u}]` is {sd}, expected a positive number"
            ));
        }
        for (r, run) in self.runs.iter().enumerate() {
            self.check_run(r, run)?;
        }
        Ok(())
    }

    /// [`MotionRecord::check`] of run `r`: every row of every block there, each as long as the
    /// DoFs or SUs, finite, the skin within range.
    fn check_run(&self, r: usize, run: &MotionRun) -> Result<(), String> {
        let n = run.len();
        let rows = [("qd", &run.qd), ("qdd", &run.qdd), ("qdd_sd", &run.qdd_sd)];
        if let Some((name, _)) = rows.iter().find(|(_, v)| v.len() != n) {
            return Err(format!("`runs[{r}].{name}` has another length than `q`"));
        }
        if run.skin.len() != n {
            return Err(format!("`runs[{r}].skin` has another length than `q`"));
        }
        let sharp = [
            ("q_sharp", &run.q_sharp),
            ("qd_sharp", &run.qd_sharp),
            ("qdd_sharp", &run.qdd_sharp),
        ];
        let has_sharp = sharp.iter().any(|(_, v)| !v.is_empty());
        if let Some((name, _)) = sharp.iter().find(|(_, v)| has_sharp && v.len() != n) {
            return Err(format!(
                "`runs[{r}].{name}` has another length than `q` (the three sharp rows are \
                 all there or all left out)"
            ));
        }
        let all = [
            ("q", &run.q),
            ("qd", &run.qd),
            ("qdd", &run.qdd),
            ("qdd_sd", &run.qdd_sd),
        ];
        for (name, rows) in all
            .into_iter()
            .chain(sharp.into_iter().filter(|_| has_sharp))
        {
            let ragged = rows
                .ragged()
                .map(|(b, _)| b)
                .or_else(|| (n > 0 && rows.width() != self.dofs.len()).then_some(0));
            if let Some(b) = ragged {
                return Err(format!(
                    "`runs[{r}].{name}[{b}]`: expected {} finite numbers",
                    self.dofs.len()
                ));
            }
            for (b, row) in rows.iter().enumerate() {
                if row.len() != self.dofs.len() || row.iter().any(|x| !x.is_finite()) {
                    return Err(format!(
                        "`runs[{r}].{name}[{b}]`: expected {} finite numbers",
                        self.dofs.len()
                    ));
                }
            }
        }
        let ragged = run.skin.ragged.or_else(|| {
            (n > 0 && run.skin.width() != self.sus.len()).then_some((0, run.skin.width()))
        });
        if let Some((b, entries)) = ragged {
            return Err(format!(
                "`runs[{r}].skin[{b}]` has {entries} entries for {} SUs",
                self.sus.len()
            ));
        }
        for b in 0..n {
            let wild = run
                .skin
                .row(b)
                .flatten()
                .flatten()
                .any(|x| !x.is_finite() || x.abs() > MAX_READING);
            if wild {
                return Err(format!(
                    "`runs[{r}].skin[{b}]`: a reading beyond ±{MAX_READING} m/s²"
                ));
            }
        }
        Ok(())
    }

    /// The number of blocks over every run.
    pub fn blocks(&self) -> usize {
        self.runs.iter().map(MotionRun::len).sum()
    }

    /// The kernel through which the record's joint accelerations see the motion, where it spans
    /// enough blocks to read the skin through ([`SkinFilter::new`]).
    pub fn skin_filter(&self) -> Option<SkinFilter> {
        SkinFilter::new(self.half_width?, self.period)
    }
}

/// Degree of the local polynomial through which a record's joint states are read: 4 leaves a
/// bias of 0.03 % of the acceleration of a 2 Hz motion at 40 ms half-width (2: 1 %).
pub const DEGREE: usize = 4;
/// The fewest blocks on each side of its centre over which [`SkinFilter`] reads the skin: the
/// record's polynomial is then wide enough to be worth matching on the skin's side. Narrower ones
/// are the narrowest of the half-widths, which follows a servo's motion so closely that the block
/// means fit as they are (exact encoders: the paper arm's held-out dynamic error 0.0018 m/s²);
/// a record whose encoder asks for more is read at 80 ms or wider, both sides through the kernel
/// ([`crate::ingest::motion::HALF_WIDTHS`]).
pub const SKIN_FILTER_BLOCKS: usize = 8;

/// The correlation of the noise of a record's block means 0 to 3 blocks apart. Each is its
/// block's mean referred to the block's centre (`crate::ingest::blocks`): for a block filled evenly,
/// `(−m₋₁ + 26 m₀ − m₁)/24` of raw means with independent noise, a variance of 678/576 of one
/// mean's, −52/576 shared with each neighbour and 1/576 with the next but one. Between blocks
/// the interpolated skin averages neighbours whose noise runs against each other: taken as
/// independent, its variance midway was 6 % too high, and a limb whose motion tells the delay
/// less than its SUs' stillness tells their noise put the skin's delay midway between blocks
/// (TALOS's trunk alone: 3.3 to 3.8 ms off, at rest 0.967 of its noise). A wide kernel
/// ([`SkinFilter`]) averages such means as it would raw ones, whose noise is 576/678 of theirs.
pub const BLOCK_NOISE_CORRELATION: [f64; 4] = [1.0, -52.0 / 678.0, 1.0 / 678.0, 0.0];

/// The kernel `K` through which a local polynomial of degree [`DEGREE`] and half-width `h`,
/// least-squares fitted to evenly spaced joint states, sees the joint's acceleration: its
/// second coefficient is `∫ K(t/h)/h · q̈(t) dt`, exactly, whatever the motion did (`K''` is the
/// polynomial's second-coefficient weight, `K` and `K'` vanish at ±h; `∫K = 1` and, degree 4
/// fitting `t⁴` exactly, `∫K t² = 0`). Reading the skin through the same kernel puts both sides
/// of the fit through one filter: a servo's jerk or its ringing, which a wide polynomial smooths,
/// is smoothed alike in what the skin read. Such a record's positions and velocities are read
/// through the kernel too ([`Kernel`]), so that what stays unmatched is only of second order in
/// the motion's deviation within the window.
#[derive(Debug, Clone, PartialEq)]
pub struct SkinFilter {
    /// `K(j·period/h)` for the blocks `j = −n..=n` about the centre.
    weights: Vec<f64>,
}

impl SkinFilter {
    /// The kernel of half-width `half_width` on blocks of `period`; `None` when it spans fewer
    /// than [`SKIN_FILTER_BLOCKS`] blocks on each side.
    pub fn new(half_width: f64, period: f64) -> Option<Self> {
        let n = filtered_reach(half_width, period)?;
        let k = Kernel::new();
        Some(Self {
            weights: (-n..=n)
                .map(|j| k.value(j as f64 * period / half_width))
                .collect(),
        })
    }

    /// `K(j·period/h)` for the blocks `j = −n..=n` about the centre (not normalised).
    pub fn weights(&self) -> &[f64] {
        &self.weights
    }

    /// Blocks on each side of the centre.
    fn reach(&self) -> usize {
        self.weights.len() / 2
    }

    /// Blocks between two values the fit takes: a quarter of the kernel's half-width (what lies
    /// between adds little the kernel has not averaged already; a 13-bit arm at 160 ms predicts
    /// as well from every fourth block as from all, and better than from every eighth).
    pub fn stride(&self) -> usize {
        (self.reach() / 4).max(1)
    }

    /// The standard deviation of a filtered value over that of one block mean (their noise
    /// correlated as [`BLOCK_NOISE_CORRELATION`] says, every block present).
    pub fn noise_factor(&self) -> f64 {
        let sum: f64 = self.weights.iter().sum();
        self.covariance(0).sqrt() / sum
    }

    /// The covariance of the filtered noise (unnormalised weights) of two blocks `lag` apart,
    /// in units of one block mean's variance: `Σ_i Σ_j w_i w_j ρ(|i + lag − j|)`.
    fn covariance(&self, lag: usize) -> f64 {
        let w = &self.weights;
        let rho = |i: usize, j: usize| BLOCK_NOISE_CORRELATION.get((i + lag).abs_diff(j));
        w.iter()
            .enumerate()
            .flat_map(|(i, a)| {
                w.iter()
                    .enumerate()
                    .filter_map(move |(j, b)| rho(i, j).map(|r| a * b * r))
            })
            .sum()
    }

    /// How many times more a slowly varying direction's sum over the values a fit takes (every
    /// `stride`-th block) varies than [`SkinFilter::noise_factor`] says if they were
    /// independent: `1 + 2 Σ_m ρ(m·stride)` over the filtered noise's autocorrelation `ρ`
    /// (≈ `576/678 / (stride · noise_factor²)`, the block means' noise summing over many blocks as raw means' does; 2.8 for every half-width read through the kernel at
    /// [`SkinFilter::stride`]). A fit that weighs each value alone takes this much more
    /// information from the record than it holds along such directions (a sensor's bias, a
    /// frame's pose): their variances and the intrinsics' tests are scaled by it.
    pub fn overcount(&self, stride: usize) -> f64 {
        self.correlation_sum(stride, 1)
    }

    /// How many times more the sum of squares of the values a fit takes (every `stride`-th
    /// block) varies than if they were independent: `1 + 2 Σ_m ρ(m·stride)²`. A residual's
    /// band at its size counts its degrees of freedom divided by this.
    pub fn square_overcount(&self, stride: usize) -> f64 {
        self.correlation_sum(stride, 2)
    }

    /// The correlation of the filtered noise of two blocks `lag` apart (the block means' noise
    /// correlated as [`BLOCK_NOISE_CORRELATION`] says, read through the kernel).
    pub fn correlation(&self, lag: usize) -> f64 {
        self.covariance(lag) / self.covariance(0)
    }

    /// `1 + 2 Σ_{m ≥ 1} ρ(m·stride)^power`.
    fn correlation_sum(&self, stride: usize, power: i32) -> f64 {
        let w = &self.weights;
        let rho = |lag: usize| self.correlation(lag);
        let beyond: f64 = (1..)
            .map(|m| m * stride.max(1))
            .take_while(|&lag| lag < w.len())
            .map(|lag| rho(lag).powi(power))
            .sum();
        1.0 + 2.0 * beyond
    }

    /// `series` read through the kernel at block `b`: the weighted mean of the blocks present,
    /// `None` where fewer than [`FEWEST_FILTERED`] blocks on either side are, or the present
    /// ones carry less than half the kernel's weight.
    pub fn smooth(&self, series: &[Option<Vector3<f64>>], b: usize) -> Option<Vector3<f64>> {
        let n = self.reach();
        let (start, end) = (b.checked_sub(n)?, b + n);
        if end >= series.len() {
            return None;
        }
        let mut sum = Vector3::zeros();
        let (mut weight, mut total) = (0.0, 0.0);
        let (mut before, mut after) = (0, 0);
        for (j, w) in (start..=end).zip(&self.weights) {
            total += w;
            if let Some(x) = series[j] {
                sum += x * *w;
                weight += w;
                before += usize::from(j < b);
                after += usize::from(j > b);
            }
        }
        (before >= FEWEST_FILTERED && after >= FEWEST_FILTERED && weight >= 0.5 * total)
            .then(|| sum / weight)
    }
}

/// The blocks on each side of the centre that a record of `half_width` on blocks of `period`
/// reads its skin through; `None` below [`SKIN_FILTER_BLOCKS`] (it reads the block means).
fn filtered_reach(half_width: f64, period: f64) -> Option<i64> {
    let n = (half_width / period).floor();
    (n.is_finite() && n >= SKIN_FILTER_BLOCKS as f64).then_some(n as i64)
}

/// The fewest blocks with samples on each side of a block [`SkinFilter::smooth`] reads.
pub const FEWEST_FILTERED: usize = 2;

/// The kernel of [`SkinFilter`], `K` on `[−1, 1]` (zero outside): `K'' = 2 e₂ᵀ M⁻¹ φ(x)` with
/// `M = ∫φφᵀ` the Gram matrix of the monomials `φ = (1, x, …, x^DEGREE)` on `[−1, 1]`,
/// integrated twice from `K(−1) = K'(−1) = 0`.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Kernel {
    /// Its coefficients, lowest power first.
    c: [f64; DEGREE + 3],
}

impl Default for Kernel {
    fn default() -> Self {
        Self::new()
    }
}

impl Kernel {
    /// The kernel of a polynomial of degree [`DEGREE`].
    pub fn new() -> Self {
        const N: usize = DEGREE + 1;
        let gram = SMatrix::<f64, N, N>::from_fn(|i, j| {
            if (i + j) % 2 == 0 {
                2.0 / (i + j + 1) as f64
            } else {
                0.0
            }
        });
        let second: SVector<f64, N> = gram
            .try_inverse()
            .expect("the monomials' Gram matrix is positive definite")
            .column(2)
            * 2.0;
        let mut c = [0.0; N + 2];
        for (k, a) in second.iter().enumerate() {
            c[k + 2] = a / ((k + 1) * (k + 2)) as f64;
        }
        let mut kernel = Self { c };
        kernel.c[1] -= kernel.polynomial_slope(-1.0);
        kernel.c[0] -= kernel.polynomial(-1.0);
        kernel
    }

    fn polynomial(&self, x: f64) -> f64 {
        self.c.iter().rev().fold(0.0, |acc, c| acc * x + c)
    }

    fn polynomial_slope(&self, x: f64) -> f64 {
        (1..self.c.len())
            .rev()
            .fold(0.0, |acc, k| acc * x + k as f64 * self.c[k])
    }

    /// The kernel through which a record of `half_width` on blocks of `period` reads its skin,
    /// and so its joint positions and velocities ([`SkinFilter::new`]); `None` where it reads the
    /// block means.
    pub fn of_record(half_width: f64, period: f64) -> Option<Self> {
        filtered_reach(half_width, period).map(|_| Self::new())
    }

    /// `K(x)` (zero outside `(−1, 1)`).
    pub fn value(&self, x: f64) -> f64 {
        if x.abs() < 1.0 {
            self.polynomial(x)
        } else {
            0.0
        }
    }

    /// `K'(x)` (zero outside `(−1, 1)`).
    pub fn slope(&self, x: f64) -> f64 {
        if x.abs() < 1.0 {
            self.polynomial_slope(x)
        } else {
            0.0
        }
    }
}

/// The reach assumed when a motion record's quiet blocks stand in for static readings, m: the
/// acceleration an SU feels besides gravity is at most about this times the joints' `Σ|q̈| + Σq̇²`.
pub const QUIET_REACH: f64 = 1.0;
/// How far from a quiet block an SU's nearest fresh sample may lie, blocks (a 20 Hz board sends
/// one every 5).
const QUIET_SEARCH: usize = 25;
/// The standard deviation of a reading an SU did not send near a quiet block, m/s²: no weight.
const UNKNOWN_SD: f64 = 1e3;

impl MotionRecord {
    /// `count` static readings from the record's quietest moments, spread over it: of each of
    /// `count` equal stretches of its blocks, the one whose joint motion adds the least to
    /// gravity. Each SU reads its nearest fresh sample; each reading's standard deviation adds to
    /// the SU's noise what motion could add to gravity there (at a reach of [`QUIET_REACH`]:
    /// `Σ|q̈| + Σq̇²` times the reach, and the turn of gravity between the block and the sample).
    ///
    /// A start for a time-domain fit of a log without training poses (a continuous program,
    /// ordinary work): orientations and axes from gravity, which the fit on every sample then
    /// corrects with the rest.
    pub fn quiet_poses(&self, count: usize) -> Vec<crate::measurements::TrainingPose> {
        let g = crate::model::sensor::STANDARD_GRAVITY;
        let blocks: Vec<(usize, usize)> = self
            .runs
            .iter()
            .enumerate()
            .flat_map(|(r, run)| (0..run.len()).map(move |b| (r, b)))
            .collect();
        let count = count.min(blocks.len());
        let motion = |(r, b): (usize, usize)| self.runs[r].motion_at(b);
        (0..count)
            .filter_map(|k| {
                let slice = &blocks[k * blocks.len() / count..(k + 1) * blocks.len() / count];
                let &(r, b) = slice
                    .iter()
                    .min_by(|x, y| motion(**x).total_cmp(&motion(**y)))?;
                let run = &self.runs[r];
                let speed: f64 = run.qd[b].iter().map(|v| v.abs()).sum();
                let (readings, sd): (Vec<[f64; 3]>, Vec<f64>) = (0..self.sus.len())
                    .map(|u| {
                        let noise = self.noise_sd[u].unwrap_or(0.0);
                        match nearest_sample(run, u, b) {
                            Some((reading, off)) => {
                                let turned = g * speed * off as f64 * self.period;
                                let bound = motion((r, b)) + turned;
                                (reading, (noise * noise + bound * bound).sqrt())
                            }
                            None => ([0.0; 3], UNKNOWN_SD),
                        }
                    })
                    .unzip();
                Some(crate::measurements::TrainingPose {
                    q: run.q[b].to_vec(),
                    static_readings: readings,
                    dynamic: Default::default(),
                    static_sd: Some(sd),
                    dynamic_sd: Default::default(),
                    orientation: 0,
                    extra: Default::default(),
                })
            })
            .collect()
    }
}

impl MotionRun {
    /// What the joint motion at block `b` could add to gravity, m/s² (at a reach of
    /// [`QUIET_REACH`]: `Σ|q̈| + Σq̇²` times the reach).
    fn motion_at(&self, b: usize) -> f64 {
        let qdd: f64 = self.qdd[b].iter().map(|a| a.abs()).sum();
        let qd2: f64 = self.qd[b].iter().map(|v| v * v).sum();
        QUIET_REACH * (qdd + qd2)
    }
}

/// The median angle between two static readings of one joint pose beyond which the base stood
/// otherwise, rad (3°: a reading's noise turns it by well under a degree, a tilted mount turns
/// every SU's gravity by the tilt, tens of degrees).
pub const OTHER_BASE: f64 = 3.0 * std::f64::consts::PI / 180.0;
/// How far a block's joint pose may be from a held one and still be it, rad (m): a few counts of
/// a coarse encoder.
pub const SAME_POSE: f64 = 0.005;
/// A reading shorter than this (m/s²) tells no direction of gravity (a dead or railed SU).
pub const LEAST_GRAVITY: f64 = 3.0;

impl MotionRecord {
    /// Whether the robot's base stood in the record as it did when `readings` (one static reading
    /// per SU) were taken at joint pose `pose`: the median angle between them and the skin at the
    /// record's quietest block at that pose is within [`OTHER_BASE`]. `None` where the record never
    /// holds that pose, or no SU read gravity at both.
    pub fn same_base(&self, pose: &[f64], readings: &[[f64; 3]]) -> Option<bool> {
        let at_pose = |q: &[f64]| {
            q.len() == pose.len() && q.iter().zip(pose).all(|(a, b)| (a - b).abs() <= SAME_POSE)
        };
        let (run, b) = self
            .runs
            .iter()
            .flat_map(|run| (0..run.len()).map(move |b| (run, b)))
            .filter(|(run, b)| at_pose(&run.q[*b]))
            .min_by(|x, y| x.0.motion_at(x.1).total_cmp(&y.0.motion_at(y.1)))?;
        let mut angles: Vec<f64> = readings
            .iter()
            .enumerate()
            .filter_map(|(u, held)| {
                let (read, _) = nearest_sample(run, u, b)?;
                let (x, y) = (Vector3::from(read), Vector3::from(*held));
                (x.norm() > LEAST_GRAVITY && y.norm() > LEAST_GRAVITY).then(|| x.angle(&y))
            })
            .collect();
        if angles.is_empty() {
            return None;
        }
        angles.sort_by(f64::total_cmp);
        Some(angles[angles.len() / 2] <= OTHER_BASE)
    }
}

/// SU `u`'s fresh sample nearest block `b` of `run`, within [`QUIET_SEARCH`] blocks, with how
/// many blocks away it is.
fn nearest_sample(run: &MotionRun, u: usize, b: usize) -> Option<([f64; 3], usize)> {
    (0..=QUIET_SEARCH).find_map(|off| {
        [b.checked_sub(off), Some(b + off)]
            .into_iter()
            .flatten()
            .find_map(|i| run.skin.get(i, u))
            .map(|s| (s, off))
    })
}

#[cfg(test)]
mod tests {
    use super::*;
    use rand::SeedableRng;
    use rand_chacha::ChaCha8Rng;
    use rand_distr::{Distribution, Normal};

    /// A record of `rows` skin rows (JSON), one DoF at rest.
    fn record_of_skin(rows: &str, sus: usize) -> Result<MotionRecord, String> {
        let blocks = serde_json::from_str::<Vec<serde_json::Value>>(rows)
            .unwrap()
            .len();
        let zeros = vec![vec![0.0]; blocks];
        let text = serde_json::json!({
            "format": MOTION_FORMAT, "version": MOTION_VERSION, "period": 0.01,
            "dofs": ["j"], "sus": (0..sus).map(|u| format!("su{u}")).collect::<Vec<_>>(),
            "noise_sd": vec![None::<f64>; sus],
            "runs": [{"log": "l", "start": 0.0, "q": zeros, "qd": zeros, "qdd": zeros,
                      "qdd_sd": zeros, "skin": serde_json::from_str::<serde_json::Value>(rows).unwrap()}],
        });
        let record: MotionRecord = serde_json::from_value(text).map_err(|e| e.to_string())?;
        record.check().map(|()| record)
    }

    #[test]
    fn the_skin_is_written_as_it_was_read_and_kept_to_single_precision() {
        let rows = "[[[1.5,-2.25,9.8125],null],[null,[0.1,0.2,0.3]],[[1e-3,2,3],[4,5,6]]]";
        let record = record_of_skin(rows, 2).unwrap();
        let skin = &record.runs[0].skin;
        assert_eq!((skin.len(), skin.width()), (3, 2));
        assert_eq!(skin.get(0, 0), Some([1.5, -2.25, 9.8125]));
        assert_eq!(
            (skin.get(0, 1), skin.get(1, 0), skin.get(3, 0)),
            (None, None, None)
        );
        // 0.1 as single precision: within half its spacing (7.5e-9), not to f64's last digit.
        let read = skin.get(1, 1).unwrap();
        for (x, want) in read.iter().zip([0.1, 0.2, 0.3]) {
            assert!((x - want).abs() < 1.5e-8 && *x != want, "{x} for {want}");
        }
        // Written back: the same rows, each number the shortest that reads as its single.
        let written = serde_json::to_string(&record.runs[0].skin).unwrap();
        assert_eq!(
            written,
            "[[[1.5,-2.25,9.8125],null],[null,[0.1,0.2,0.3]],[[0.001,2.0,3.0],[4.0,5.0,6.0]]]"
        );
        // Split and joined again, the same rows.
        let mut run = record.runs[0].clone();
        let tail = run.split_off(1, 0.01);
        assert_eq!(
            (run.len(), tail.len(), tail.skin.get(0, 1)),
            (1, 2, Some(read))
        );
        assert!(run.extend_with(tail, 0.01).is_none());
        assert_eq!(run, record.runs[0]);
    }

    #[test]
    fn a_skin_row_of_another_width_or_out_of_range_is_refused_by_name() {
        let ragged = record_of_skin("[[null,null],[null],[null,null]]", 2).unwrap_err();
        assert!(
            ragged.contains("`runs[0].skin[1]` has 1 entries for 2 SUs"),
            "{ragged}"
        );
        let narrow = record_of_skin("[[null],[null]]", 2).unwrap_err();
        assert!(
            narrow.contains("`runs[0].skin[0]` has 1 entries for 2 SUs"),
            "{narrow}"
        );
        let wild = record_of_skin("[[null,null],[[1,2,3],[1e300,0,0]]]", 2).unwrap_err();
        assert!(
            wild.contains("`runs[0].skin[1]`: a reading beyond"),
            "{wild}"
        );
    }

    /// A run longer than a few megabytes: its rows leave the heap for a scratch file, and read,
    /// split, join and write as they were given (the truth: the values pushed, and the same rows
    /// written by serde from nested vectors).
    #[test]
    fn a_long_runs_rows_are_in_a_scratch_file_and_read_as_they_were_given() {
        let mut rng = ChaCha8Rng::seed_from_u64(5);
        let normal = Normal::new(0.0, 3.0).unwrap();
        let (sus, dofs, blocks) = (120, 7, 3000);
        let mut run = MotionRun::new("l", 0.5);
        let (mut skin, mut joints) = (Vec::new(), Vec::new());
        for b in 0..blocks {
            let row: Vec<Option<[f64; 3]>> = (0..sus)
                .map(|u| {
                    let m = [0; 3].map(|_| f64::from(normal.sample(&mut rng) as f32));
                    ((u + b) % 17 != 0).then_some(m)
                })
                .collect();
            let joint: Vec<[f64; 4]> = (0..dofs)
                .map(|_| [0; 4].map(|_| normal.sample(&mut rng)))
                .collect();
            run.push(&joint, row.clone());
            skin.push(row);
            joints.push(joint);
        }
        assert!(run.skin.is_mapped(), "{} bytes of skin", 12 * sus * blocks);
        assert!(
            !run.q.values.is_mapped(),
            "{} bytes of positions",
            8 * dofs * blocks
        );
        for b in [0, 1, 1717, blocks - 1] {
            assert!(run.skin.row(b).eq(skin[b].iter().copied()));
            let qdd: Vec<f64> = joints[b].iter().map(|x| x[2]).collect();
            assert_eq!(run.qdd[b], qdd[..]);
        }
        assert_eq!(run.skin.get(blocks, 0), None);
        let nested: Vec<Vec<Option<[f32; 3]>>> = skin
            .iter()
            .map(|row| row.iter().map(|m| m.map(|m| m.map(|x| x as f32))).collect())
            .collect();
        assert_eq!(
            serde_json::to_string(&run.skin).unwrap(),
            serde_json::to_string(&nested).unwrap()
        );
        let positions: Vec<Vec<f64>> = joints
            .iter()
            .map(|row| row.iter().map(|x| x[0]).collect())
            .collect();
        assert_eq!(
            serde_json::to_string(&run.q).unwrap(),
            serde_json::to_string(&positions).unwrap()
        );
        let read: SkinRows =
            serde_json::from_str(&serde_json::to_string(&nested).unwrap()).unwrap();
        assert!(read.is_mapped() && read == run.skin);
        let whole = run.clone();
        let tail = run.split_off(1234, 0.01);
        assert_eq!((run.len(), tail.len()), (1234, blocks - 1234));
        assert!(tail.skin.row(0).eq(skin[1234].iter().copied()));
        assert_eq!(tail.qd[5][3], joints[1239][3][1]);
        assert!(run.extend_with(tail, 0.01).is_none());
        assert!(run == whole);
    }

    #[test]
    fn a_joint_row_of_another_width_is_refused_by_name() {
        let text = |q: &str| {
            format!(
                r#"{{"format": "{MOTION_FORMAT}", "version": {MOTION_VERSION}, "period": 0.01,
                "dofs": ["j", "k"], "sus": [], "noise_sd": [], "runs": [{{"log": "l",
                "start": 0.0, "q": {q}, "qd": [[0,0],[0,0]], "qdd": [[0,0],[0,0]],
                "qdd_sd": [[0,0],[0,0]], "skin": [[],[]]}}]}}"#
            )
        };
        let check = |q: &str| {
            let record: MotionRecord = serde_json::from_str(&text(q)).unwrap();
            record.check()
        };
        assert_eq!(check("[[0,0],[0,0]]"), Ok(()));
        let long = check("[[0,0],[0,0,0]]").unwrap_err();
        assert!(
            long.contains("`runs[0].q[1]`: expected 2 finite numbers"),
            "{long}"
        );
        let narrow = check("[[0],[0]]").unwrap_err();
        assert!(
            narrow.contains("`runs[0].q[0]`: expected 2 finite numbers"),
            "{narrow}"
        );
    }

    /// The sharp joint states are optional, but all three or none, each row as `q`'s.
    #[test]
    fn sharp_joint_states_are_all_there_or_none_and_checked_as_q() {
        let text = |sharp: &str| {
            format!(
                r#"{{"format": "{MOTION_FORMAT}", "version": {MOTION_VERSION}, "period": 0.01,
                "dofs": ["j"], "sus": [], "noise_sd": [], "runs": [{{"log": "l",
                "start": 0.0, "q": [[0],[0]], "qd": [[0],[0]], "qdd": [[0],[0]],
                "qdd_sd": [[0],[0]], "skin": [[],[]]{sharp}}}]}}"#
            )
        };
        let check = |sharp: &str| {
            let record: MotionRecord = serde_json::from_str(&text(sharp)).unwrap();
            record.check()
        };
        assert_eq!(check(""), Ok(()));
        let all = r#", "q_sharp": [[0],[0]], "qd_sharp": [[0],[0]], "qdd_sharp": [[0],[0]]"#;
        assert_eq!(check(all), Ok(()));
        let two = check(r#", "q_sharp": [[0],[0]], "qd_sharp": [[0],[0]]"#).unwrap_err();
        assert!(
            two.contains("`runs[0].qdd_sharp` has another length"),
            "{two}"
        );
        let wide = r#", "q_sharp": [[0],[0]], "qd_sharp": [[0],[0,1]], "qdd_sharp": [[0],[0]]"#;
        let wide = check(wide).unwrap_err();
        assert!(
            wide.contains("`runs[0].qd_sharp[1]`: expected 1 finite numbers"),
            "{wide}"
        );
    }

    #[test]
    fn the_overcount_is_what_the_filtered_noise_does() {
        // Block means as ingest refers them to their blocks' centres, `(−m₋₁ + 26 m₀ − m₁)/24` of
        // white raw means (scaled to unit variance), through the kernel, every stride-th value
        // taken: the variance of their sum over many independent records against what
        // independent values would give.
        let mut rng = ChaCha8Rng::seed_from_u64(11);
        let normal = Normal::new(0.0, 1.0).unwrap();
        for (half_width, period) in [(0.08, 0.01), (0.1, 0.01), (0.16, 0.01), (0.2, 0.01)] {
            let filter = SkinFilter::new(half_width, period).unwrap();
            let (n, taken_per_record, records) = (filter.reach(), 300, 2000);
            let stride = filter.stride();
            let blocks = 2 * n + 1 + stride * taken_per_record;
            let (mut sums, mut squares) = (Vec::new(), Vec::new());
            for _ in 0..records {
                let raw: Vec<f64> = (0..blocks + 2).map(|_| normal.sample(&mut rng)).collect();
                let scale = 24.0 * (678.0f64 / 576.0).sqrt();
                let noise: Vec<Option<Vector3<f64>>> = raw
                    .windows(3)
                    .map(|m| Some(Vector3::new((26.0 * m[1] - m[0] - m[2]) / scale, 0.0, 0.0)))
                    .collect();
                let taken: Vec<f64> = (0..taken_per_record)
                    .map(|i| filter.smooth(&noise, n + i * stride).unwrap().x)
                    .collect();
                sums.push(taken.iter().sum::<f64>());
                squares.push(taken.iter().map(|x| x * x).sum::<f64>());
            }
            let variance = |x: &[f64]| {
                let mean = x.iter().sum::<f64>() / x.len() as f64;
                x.iter().map(|v| (v - mean).powi(2)).sum::<f64>() / (x.len() - 1) as f64
            };
            let f2 = filter.noise_factor().powi(2);
            let independent = taken_per_record as f64 * f2;
            let measured = variance(&sums) / independent;
            // Independent values' sum of squares varies by 2 N f⁴.
            let of_squares = variance(&squares) / (2.0 * independent * f2);
            assert!(
                (of_squares / filter.square_overcount(stride) - 1.0).abs() < 0.12,
                "{half_width} s: sum of squares measured {of_squares:.3}, stated {:.3}",
                filter.square_overcount(stride)
            );
            // 2000 records: the variance is known to ±3.2 % (1 sd); the records' ends, where a value
            // has neighbours on one side only, take under 1 %.
            assert!(
                (measured / filter.overcount(stride) - 1.0).abs() < 0.12,
                "{half_width} s: measured {measured:.3}, stated {:.3}",
                filter.overcount(stride)
            );
            // Over many blocks the corrected means' noise sums as the raw means' does: 576/678.
            let long_run = 576.0 / 678.0;
            let approximate = long_run / (stride as f64 * filter.noise_factor().powi(2));
            assert!((filter.overcount(stride) / approximate - 1.0).abs() < 0.1);
        }
    }
}
