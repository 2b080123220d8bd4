//! The one kinematics of a limb's chain, and what every row of its problem reads of it.
//!
//! A [`ChainState`] places joint `k`'s frame on segment `k` and turns DoF `k` about that frame's
//! `z`: `S_{k+1} = S_k · J_k · Rz(q_k)` ([`link`]). At one **instant** of motion — a pose with
//! every DoF's rate and acceleration, gravity on or off — every SU on segment `s` at `p` (segment
//! frame) with rotation `R` reads `Rᵀ (c_s + N_s p)`: `c_s = R_sᵀ (a_s + M_s x_s − g)` and
//! `N_s = R_sᵀ M_s R_s` from the segment's motion ([`BodyMotion`]: `a(p) = a + M p`). These 12
//! numbers per segment and instant are shared by every SU on the segment.
//!
//! The instants are a motion record's samples (gravity on), a pose's static reading (rates zero,
//! gravity on) and the paper's dynamic reading of DoF `d` at a pose (its acceleration `α` alone,
//! gravity off: the difference of two samples at one pose). Their derivatives along gravity are
//! `∂c_s = −R_sᵀ δg` (`N_s` does not see it); along a joint line's columns they come from dual
//! numbers through the same code, in one of two ways:
//! - where no DoF from joint `k` on moves at the instant, a change of joint `k`'s frame moves
//!   every later segment rigidly, with its motion: each segment's terms change as its frame moved
//!   by the column's world twist (`k`'s frame · step · frame⁻¹). So each segment's terms are
//!   differentiated once along the 6 unit world twists ([`FrameRates`]), each joint column's twist
//!   is taken once per pose ([`JointTwists`]), and a rate is their product — the paper's static
//!   and dynamic readings need nothing else, at a cost of the square of the chain's length, not
//!   its cube;
//! - otherwise (a motion record's samples, where later DoFs move), a pass down the chain per
//!   column, starting at its joint from the real pass's state and leaving out the instants that
//!   cannot see it (a dynamic reading of DoF `d` sees only the joints after `d`:
//!   `Instant::blind_to_joint`) or that the first way serves.

use std::sync::Arc;

use nalgebra::{
    Isometry3, Matrix3, Quaternion, RealField, Translation3, UnitQuaternion, Vector3, Vector6,
};
use num_dual::Dual64;

use super::problem::{gravity_directions, Block, Prefix};
use super::ChainState;
use crate::model::{BodyMotion, DofKind};

/// Joint `k`'s frame and the frame of the segment its DoF turns, from the frame `segment` of the
/// segment it sits on, its frame `joint` there and its turn `Rz(q_k)`: `(S·J, S·J·Rz(q))`.
pub(super) fn link<T: RealField + Copy>(
    segment: &Isometry3<T>,
    joint: &Isometry3<T>,
    turn: &Isometry3<T>,
) -> (Isometry3<T>, Isometry3<T>) {
    let frame = segment * joint;
    (frame, frame * turn)
}

/// One instant of a chain's motion at a pose: every DoF's rate and acceleration (rad/s, rad/s²),
/// and whether gravity acts.
#[derive(Debug, Clone, Copy)]
pub(super) struct Instant<'a> {
    qd: &'a [f64],
    qdd: &'a [f64],
    gravity: bool,
    /// The base orientation whose gravity acts (0: the usual one).
    orientation: usize,
    /// The first DoF that moves: the segments before it are still.
    moving_from: usize,
    /// One past the last DoF that moves.
    moving_to: usize,
    /// Whether any DoF has a rate (else no segment turns now: `ω = 0` everywhere).
    turning: bool,
}

impl<'a> Instant<'a> {
    pub fn new(qd: &'a [f64], qdd: &'a [f64], gravity: bool) -> Self {
        let moving_from = qd
            .iter()
            .zip(qdd)
            .position(|(v, a)| *v != 0.0 || *a != 0.0)
            .unwrap_or(qd.len());
        let moving_to = qd
            .iter()
            .zip(qdd)
            .rposition(|(v, a)| *v != 0.0 || *a != 0.0)
            .map_or(moving_from, |k| k + 1);
        Self {
            qd,
            qdd,
            gravity,
            orientation: 0,
            moving_from,
            moving_to,
            turning: qd.iter().any(|v| *v != 0.0),
        }
    }

    /// The same instant under the gravity of base orientation `o`.
    pub fn in_orientation(self, o: usize) -> Self {
        Self {
            orientation: o,
            ..self
        }
    }

    /// Whether segment `s` (turned by DoF `s − 1`) is still at this instant.
    fn still(&self, s: usize) -> bool {
        s <= self.moving_from
    }

    /// Whether no term of this instant changes with joint `k`'s frame: with gravity off and only
    /// DoFs from `k` on moving, a change of that frame moves every moving axis and every segment
    /// after it rigidly, and a segment's terms, seen in its own frame, do not see a rigid motion.
    /// (A paper's dynamic reading of DoF `d` depends only on the joints after `d`.)
    fn blind_to_joint(&self, k: usize) -> bool {
        !self.gravity && self.moving_from >= k
    }

    /// Whether a change of joint `k`'s frame moves everything after it rigidly at this instant
    /// (no DoF from `k` on moves), so that each segment's terms change as its frame moved by that
    /// joint's twist ([`SegmentTerms::frame_rates`]): no pass down the chain is needed.
    fn rigid_after(&self, k: usize) -> bool {
        self.rigid_from() <= k
    }

    /// The first joint the instant is rigid after: 0 when nothing moves.
    fn rigid_from(&self) -> usize {
        if self.moving_from >= self.moving_to {
            0
        } else {
            self.moving_to
        }
    }

    /// Whether the terms' rates along joint `k`'s columns need a pass down the chain.
    fn needs_pass(&self, k: usize) -> bool {
        !self.blind_to_joint(k) && !self.rigid_after(k)
    }
}

/// The instants of a pose's readings: the static one, then the dynamic one of each DoF (its
/// acceleration `alpha` alone, gravity off).
pub(super) struct ReadingInstants {
    zeros: Vec<f64>,
    kicks: Vec<Vec<f64>>,
}

impl ReadingInstants {
    /// For a chain of DoFs of `kinds` whose dynamic readings are those of DoFs `0…dynamic−1`,
    /// under a pattern of peak acceleration `alpha` (scaled for a prismatic DoF).
    pub fn new(kinds: &[DofKind], dynamic: usize, alpha: f64) -> Self {
        let dofs = kinds.len();
        let kicks = (0..dynamic.min(dofs))
            .map(|d| {
                let mut a = vec![0.0; dofs];
                a[d] = alpha * kinds[d].pattern_scale();
                a
            })
            .collect();
        Self {
            zeros: vec![0.0; dofs],
            kicks,
        }
    }

    /// Entry 0 the static reading's instant (under the gravity of base orientation
    /// `orientation`), entry `1 + d` DoF `d`'s dynamic one.
    pub fn instants(&self, orientation: usize) -> Vec<Instant<'_>> {
        std::iter::once(Instant::new(&self.zeros, &self.zeros, true).in_orientation(orientation))
            .chain(
                self.kicks
                    .iter()
                    .map(|a| Instant::new(&self.zeros, a, false)),
            )
            .collect()
    }
}

/// Segment `s`'s `(c_s, N_s)` at one instant (entry `s − 1`) and their rates along the shared
/// columns that move it (gravity, and the lines of joints up to `s`; every other column's are
/// zero). Entries before `from` (the segments before a prefix's) are zero and not stored.
///
/// A joint's columns are given in one of two ways. Where the instant is rigid after the joint
/// (`Instant::rigid_after`), a change of its frame moves the segment's frame by the joint's
/// twist and nothing else, so the rates are the segment's [`FrameRates`] times the twist
/// ([`JointTwists`]); elsewhere they are `rates`, from passes down the chain.
pub(super) struct SegmentTerms {
    from: usize,
    /// Entries `from..`: `(c_s, N_s)` and where their rates lie in `rates`.
    entries: Vec<Entry>,
    /// Every stored segment's rates, segment after segment.
    rates: Vec<ColumnRate>,
    /// The first joint the instant is rigid after.
    rigid_from: usize,
    /// The frame rates of entries `frame_from..`, where a joint's twist reaches them.
    frame_from: usize,
    frame: Vec<FrameRates>,
    twists: Arc<JointTwists>,
}

/// One segment's terms at one instant, and the range of its rates.
#[derive(Clone)]
struct Entry {
    c: Vector3<f64>,
    n: Matrix3<f64>,
    rates: (u32, u32),
}

/// The rates of a segment's `(c_s, N_s)` as its frame moves by each unit world twist: turns
/// about the reference axes `x, y, z`, then shifts along them (`p ↦ p + φ × p + t`, `(φ, t)`).
pub(super) type FrameRates = [(Vector3<f64>, Matrix3<f64>); 6];

/// The world twists `(φ, t)` of the joint columns at one pose, by joint: `(joint, column, twist)`
/// in the order of the joints.
#[derive(Default)]
pub(super) struct JointTwists(Vec<(usize, usize, Vector6<f64>)>);

impl SegmentTerms {
    /// Zero terms of entries `from..last`, room for `(rates, frames)` rates and frame rates, for
    /// `instant`.
    fn zeros(from: usize, last: usize, (rates, frames): (usize, usize), instant: &Instant) -> Self {
        let entry = Entry {
            c: Vector3::zeros(),
            n: Matrix3::zeros(),
            rates: (0, 0),
        };
        Self {
            from,
            entries: vec![entry; last.saturating_sub(from)],
            rates: Vec::with_capacity(rates),
            rigid_from: instant.rigid_from(),
            frame_from: usize::MAX,
            frame: Vec::with_capacity(frames),
            twists: Arc::default(),
        }
    }

    /// `c_s` of segment entry `e` (segment `e + 1`).
    pub fn c(&self, e: usize) -> Vector3<f64> {
        e.checked_sub(self.from)
            .map_or_else(Vector3::zeros, |i| self.entries[i].c)
    }

    /// `N_s` of segment entry `e` (segment `e + 1`).
    pub fn n(&self, e: usize) -> Matrix3<f64> {
        e.checked_sub(self.from)
            .map_or_else(Matrix3::zeros, |i| self.entries[i].n)
    }

    /// The rates `(column, ∂c_s, ∂N_s)` of segment entry `e` (segment `e + 1`) from passes down
    /// the chain.
    pub fn rates(&self, e: usize) -> &[ColumnRate] {
        match e.checked_sub(self.from) {
            Some(i) => {
                let (lo, hi) = self.entries[i].rates;
                &self.rates[lo as usize..hi as usize]
            }
            None => &[],
        }
    }

    /// Segment entry `e`'s frame rates and the twists `(column, (φ, t))` of the joint columns
    /// they serve (the joints before the segment that the instant is rigid after), if any.
    pub fn frame_rates(
        &self,
        e: usize,
    ) -> Option<(&FrameRates, impl Iterator<Item = (usize, &Vector6<f64>)>)> {
        let rates = self.frame.get(e.checked_sub(self.frame_from)?)?;
        let twists = &self.twists.0;
        let lo = twists.partition_point(|t| t.0 < self.rigid_from);
        let hi = twists.partition_point(|t| t.0 <= e);
        Some((rates, twists[lo..hi].iter().map(|(_, col, xi)| (*col, xi))))
    }
}

/// A shared column and the rates `(∂c_s, ∂N_s)` of one segment's terms along it.
pub(super) type ColumnRate = (usize, Vector3<f64>, Matrix3<f64>);

/// Where a pass down the chain stands at segment `s`: its frame, and its motion at each instant;
/// for a pass along a joint's column, that joint (the instants blind to it are skipped).
#[derive(Clone)]
struct Stage<T: RealField> {
    s: usize,
    segment: Isometry3<T>,
    motions: Vec<BodyMotion<T>>,
    along: Option<usize>,
}

impl<T: RealField> Stage<T> {
    /// Whether this pass skips `instant`: its terms have no rate along the pass's joint, or
    /// their rates are the segment's frame rates times the joint's twist.
    fn skips(&self, instant: &Instant) -> bool {
        self.along.is_some_and(|k| !instant.needs_pass(k))
    }
}

impl<T: RealField + Copy> Stage<T> {
    /// The segment's terms at each instant, under its orientation's gravity (`gravity`, one per
    /// base orientation) where the instant has it, each passed to `emit` with the instant's index.
    fn terms(
        &self,
        instants: &[Instant],
        gravity: &[Vector3<T>],
        mut emit: impl FnMut(usize, Vector3<T>, Matrix3<T>),
    ) {
        let rt = self
            .segment
            .rotation
            .to_rotation_matrix()
            .into_inner()
            .transpose();
        let x = rt * self.segment.translation.vector;
        for (i, (instant, motion)) in instants.iter().zip(&self.motions).enumerate() {
            if self.skips(instant) {
                continue;
            }
            if let Some((c, n)) = seen(self.s, instant, motion, &rt, &x, gravity) {
                emit(i, c, n);
            }
        }
    }

    /// Moves the stage on to the segment DoF `k` (of `kind`) moves by `turn`, its joint frame
    /// `joint` on this segment (followed by the local motion `step` when given).
    fn advance(
        &mut self,
        k: usize,
        kind: DofKind,
        joint: &Isometry3<T>,
        step: Option<&Isometry3<T>>,
        turn: &Isometry3<T>,
        instants: &[Instant],
    ) {
        let joint = step.map_or(*joint, |s| joint * s);
        let (frame, segment) = link(&self.segment, &joint, turn);
        let axis = frame.rotation * Vector3::z();
        let point = frame.translation.vector;
        let along = self.along;
        for (motion, i) in self.motions.iter_mut().zip(instants) {
            // A DoF at rest adds nothing to the motion it carries on (exactly: every term of
            // `through` and `slide` is a multiple of its rate or acceleration).
            let skipped = along.is_some_and(|j| !i.needs_pass(j));
            if !skipped && (i.qd[k] != 0.0 || i.qdd[k] != 0.0) {
                *motion = motion.moved_by(
                    kind,
                    &axis,
                    &point,
                    T::from_subset(&i.qd[k]),
                    T::from_subset(&i.qdd[k]),
                );
            }
        }
        self.s = k + 1;
        self.segment = segment;
    }
}

impl Stage<f64> {
    /// The segment's [`FrameRates`] at each instant that `wanted`, passed to `emit` with the
    /// instant's index: the same terms through dual numbers, the segment's frame moved by each
    /// unit world twist and the motion held.
    fn frame_rates(
        &self,
        instants: &[Instant],
        gravity: &[Vector3<f64>],
        wanted: impl Fn(&Instant) -> bool,
        mut emit: impl FnMut(usize, FrameRates),
    ) {
        let mut frames = None;
        let gravity: Vec<Vector3<Dual64>> = gravity.iter().map(|g| g.map(Dual64::from)).collect();
        for (i, (instant, motion)) in instants.iter().zip(&self.motions).enumerate() {
            if !wanted(instant) {
                continue;
            }
            let frames = frames.get_or_insert_with(|| {
                let segment = lift(&self.segment);
                (0..6)
                    .map(|j| {
                        let moved = unit_motion(j) * segment;
                        let rt = moved.rotation.to_rotation_matrix().into_inner().transpose();
                        (rt, rt * moved.translation.vector)
                    })
                    .collect::<Vec<_>>()
            });
            let motion = lift_motion(motion);
            let mut rates = [(Vector3::zeros(), Matrix3::zeros()); 6];
            for (rate, (rt, x)) in rates.iter_mut().zip(frames.iter()) {
                if let Some((c, n)) = seen(self.s, instant, &motion, rt, x, &gravity) {
                    *rate = (c.map(|v| v.eps), n.map(|v| v.eps));
                }
            }
            emit(i, rates);
        }
    }
}

/// What the SUs of segment `s` read at `instant` of the field of its `motion`, seen through
/// `rt` and `x` ([`BodyMotion::field_seen`]), under its orientation's gravity (`gravity`, one per
/// base orientation): `None` for a still segment without gravity.
fn seen<T: RealField + Copy>(
    s: usize,
    instant: &Instant,
    motion: &BodyMotion<T>,
    rt: &Matrix3<T>,
    x: &Vector3<T>,
    gravity: &[Vector3<T>],
) -> Option<(Vector3<T>, Matrix3<T>)> {
    let zero = Vector3::zeros();
    let g = if instant.gravity {
        &gravity[instant.orientation]
    } else {
        &zero
    };
    if instant.still(s) {
        // A still segment with no gravity has no field, nor any rate of it.
        instant.gravity.then(|| (-(rt * g), Matrix3::zeros()))
    } else if instant.turning {
        Some(motion.field_seen(rt, x, g))
    } else {
        Some(motion.field_seen_unturning(rt, x, g))
    }
}

/// A shared column of the problem as the terms see it.
enum Column {
    /// The gravity of a base orientation moved along this direction.
    Gravity(usize, Vector3<f64>),
    /// Joint `k`'s frame followed by this local motion (the dual unit in one component).
    Joint(usize, Isometry3<Dual64>),
    /// A column the terms do not depend on.
    Other,
}

/// A chain at one state, ready to give the terms of any instant: its joint frames as dual numbers,
/// and the shared columns the derivatives are wanted along.
pub(super) struct Chain<'a> {
    state: &'a ChainState,
    kinds: &'a [DofKind],
    lifted: Vec<Isometry3<Dual64>>,
    /// Gravity in each base orientation, and lifted to dual numbers.
    gravity: Vec<Vector3<f64>>,
    lifted_gravity: Vec<Vector3<Dual64>>,
    columns: Vec<Column>,
    /// How many of the columns are each joint's, and how many each orientation's gravity's.
    joint_columns: Vec<usize>,
    /// How many joint columns the joints before each joint have (one entry more than joints).
    columns_before: Vec<usize>,
    gravity_columns: Vec<usize>,
}

impl<'a> Chain<'a> {
    /// `columns`: the problem's shared columns (block and component) to differentiate along;
    /// `None` for the terms alone.
    pub fn new(
        state: &'a ChainState,
        kinds: &'a [DofKind],
        columns: Option<&[(Block, usize)]>,
    ) -> Self {
        let directions = gravity_directions(&state.gravity);
        let columns = columns
            .unwrap_or(&[])
            .iter()
            .map(|&(block, c)| match block {
                Block::Gravity => Column::Gravity(0, Vector3::ith(c, 1.0)),
                Block::GravityDirection => Column::Gravity(0, directions[c]),
                Block::OtherGravity(o) => Column::Gravity(o, Vector3::ith(c, 1.0)),
                Block::Joint(k) => Column::Joint(k, joint_step(false, c)),
                Block::JointFull(k) => Column::Joint(k, joint_step(true, c)),
                _ => Column::Other,
            })
            .collect::<Vec<_>>();
        let gravity: Vec<Vector3<f64>> = std::iter::once(state.gravity)
            .chain(state.other_gravities.iter().copied())
            .collect();
        let mut joint_columns = vec![0; state.joints.len()];
        let mut gravity_columns = vec![0; gravity.len()];
        for column in &columns {
            match column {
                Column::Gravity(o, _) => gravity_columns[*o] += 1,
                Column::Joint(k, _) => joint_columns[*k] += 1,
                Column::Other => {}
            }
        }
        Self {
            state,
            kinds,
            lifted: state.joints.iter().map(lift).collect(),
            lifted_gravity: gravity.iter().map(|g| g.map(Dual64::from)).collect(),
            gravity,
            columns,
            columns_before: std::iter::once(0)
                .chain(joint_columns.iter().scan(0, |sum, n| {
                    *sum += n;
                    Some(*sum)
                }))
                .collect(),
            joint_columns,
            gravity_columns,
        }
    }

    /// The terms of segments `1..=last` at each instant of a pose whose DoFs move by `turns`
    /// (`Rz(q)` or `Tz(q)` per DoF), and their rates along the chain's columns. From `prefix`, the frames
    /// before its segment are taken from it, and the segments before it get zero terms.
    ///
    /// One pass down the chain. At each joint, its columns' world twists are taken, and the
    /// passes of its columns start from the real stage (lifted to dual numbers) for the instants
    /// that are not rigid after it; every pass moves on with the real one. At each segment, its
    /// terms, their frame rates where a twist reaches them, and the passes' rates.
    pub fn terms(
        &self,
        turns: &[Isometry3<f64>],
        prefix: Option<&Prefix>,
        instants: &[Instant],
        last: usize,
    ) -> Vec<SegmentTerms> {
        let (first, mut stage) = self.start(prefix, instants);
        let from = first.max(1) - 1;
        let mut out: Vec<SegmentTerms> = instants
            .iter()
            .map(|i| SegmentTerms::zeros(from, last, self.rate_count(first, last, i), i))
            .collect();
        let mut passes: Vec<(usize, usize, Stage<Dual64>)> = Vec::new();
        let mut twists = JointTwists::default();
        for s in first.max(1)..=last {
            if s > first {
                let k = s - 1;
                self.begin_joint(k, &stage, instants, &mut passes, &mut twists);
                let kind = self.kinds[k];
                stage.advance(k, kind, &self.state.joints[k], None, &turns[k], instants);
                let turn = lift(&turns[k]);
                for (col, from, pass) in &mut passes {
                    let step = match &self.columns[*col] {
                        Column::Joint(_, step) if *from == k => Some(step),
                        _ => None,
                    };
                    pass.advance(k, kind, &self.lifted[k], step, &turn, instants);
                }
            }
            self.segment(s - 1, (first, from), &stage, &passes, instants, &mut out);
        }
        let twists = Arc::new(twists);
        for o in &mut out {
            o.twists = twists.clone();
        }
        out
    }

    /// Joint `k`'s columns where the real pass reaches it (`stage`, on segment `k`): their world
    /// twists, and a pass of each when an instant is not rigid after the joint.
    fn begin_joint(
        &self,
        k: usize,
        stage: &Stage<f64>,
        instants: &[Instant],
        passes: &mut Vec<(usize, usize, Stage<Dual64>)>,
        twists: &mut JointTwists,
    ) {
        let frame = stage.segment * self.state.joints[k];
        let pass = instants.iter().any(|i| i.needs_pass(k));
        for (col, column) in self.columns.iter().enumerate() {
            let Column::Joint(j, step) = column else {
                continue;
            };
            if *j == k {
                twists.0.push((k, col, twist(&frame, step)));
                if pass {
                    passes.push((col, k, lift_stage(stage, k)));
                }
            }
        }
    }

    /// Segment entry `entry`'s terms at every instant into `out`, with their rates: along
    /// gravity, the frame rates where a joint's twist reaches the segment, and the passes'.
    /// `first`: the chain's first segment (a prefix's); `from`: the first entry `out` stores.
    fn segment(
        &self,
        entry: usize,
        (first, from): (usize, usize),
        stage: &Stage<f64>,
        passes: &[(usize, usize, Stage<Dual64>)],
        instants: &[Instant],
        out: &mut [SegmentTerms],
    ) {
        let e = entry - from;
        for o in out.iter_mut() {
            o.entries[e].rates.0 = o.rates.len() as u32;
        }
        stage.terms(instants, &self.gravity, |i, c, n| {
            out[i].entries[e].c = c;
            out[i].entries[e].n = n;
        });
        for (col, column) in self.columns.iter().enumerate() {
            let Column::Gravity(orientation, dir) = column else {
                continue;
            };
            let dc = -stage.segment.rotation.inverse_transform_vector(dir);
            let under = |i: &Instant| i.gravity && i.orientation == *orientation;
            for (o, _) in out.iter_mut().zip(instants).filter(|(_, i)| under(i)) {
                o.rates.push((col, dc, Matrix3::zeros()));
            }
        }
        let reached = |i: &Instant| self.reached(entry, first, i);
        stage.frame_rates(instants, &self.gravity, reached, |i, rates| {
            let o = &mut out[i];
            if o.frame.is_empty() {
                o.frame_from = entry;
            }
            o.frame.push(rates);
        });
        for (col, _, pass) in passes {
            pass.terms(instants, &self.lifted_gravity, |i, c, n| {
                out[i]
                    .rates
                    .push((*col, c.map(|x| x.eps), n.map(|x| x.eps)));
            });
        }
        for o in out.iter_mut() {
            o.entries[e].rates.1 = o.rates.len() as u32;
        }
    }

    /// Whether a joint twist reaches segment entry `entry` at `instant`: a joint column before
    /// it (from `first`) that the instant is rigid after.
    fn reached(&self, entry: usize, first: usize, instant: &Instant) -> bool {
        let lo = instant.rigid_from().max(first).min(entry + 1);
        self.columns_before[entry + 1] > self.columns_before[lo]
    }

    /// How many rates the passes and gravity give the terms of segments `first..=last` at
    /// `instant` (per segment, the gravity columns when the instant has gravity, and the
    /// columns of the joints before it that need a pass at the instant), and how many segments
    /// get frame rates.
    fn rate_count(&self, first: usize, last: usize, instant: &Instant) -> (usize, usize) {
        let gravity = if instant.gravity {
            self.gravity_columns[instant.orientation]
        } else {
            0
        };
        let (mut seen, mut total, mut frames) = (0, 0, 0);
        for s in first.max(1)..=last {
            if s > first && instant.needs_pass(s - 1) {
                seen += self.joint_columns[s - 1];
            }
            total += gravity + seen;
            frames += usize::from(self.reached(s - 1, first, instant));
        }
        (total, frames)
    }

    /// The first segment of a pass and its stage: the reference segment, still, or `prefix`'s
    /// segment with the motion its joints give it.
    fn start(&self, prefix: Option<&Prefix>, instants: &[Instant]) -> (usize, Stage<f64>) {
        let still = vec![BodyMotion::still(); instants.len()];
        let Some(prefix) = prefix else {
            return (
                0,
                Stage {
                    s: 0,
                    segment: Isometry3::identity(),
                    motions: still,
                    along: None,
                },
            );
        };
        let lines: Vec<(Vector3<f64>, Vector3<f64>)> = prefix
            .joints
            .iter()
            .map(|frame| (frame.rotation * Vector3::z(), frame.translation.vector))
            .collect();
        let mut motions = still;
        for (m, i) in motions.iter_mut().zip(instants) {
            // Only the DoFs that move add to the motion (as in `Stage::advance`).
            let moving = i.moving_from.min(lines.len())..i.moving_to.min(lines.len());
            for (k, (axis, point)) in lines[moving.clone()].iter().enumerate() {
                let k = moving.start + k;
                if i.qd[k] != 0.0 || i.qdd[k] != 0.0 {
                    *m = m.moved_by(self.kinds[k], axis, point, i.qd[k], i.qdd[k]);
                }
            }
        }
        let first = prefix.joints.len();
        (
            first,
            Stage {
                s: first,
                segment: prefix.segment,
                motions,
                along: None,
            },
        )
    }
}

/// An `f64` isometry as one of dual numbers (no derivative).
fn lift(iso: &Isometry3<f64>) -> Isometry3<Dual64> {
    Isometry3::from_parts(
        Translation3::from(iso.translation.vector.map(Dual64::from)),
        lift_turn(&iso.rotation),
    )
}

/// An `f64` rotation as one of dual numbers (no derivative).
fn lift_turn(q: &UnitQuaternion<f64>) -> UnitQuaternion<Dual64> {
    UnitQuaternion::new_unchecked(Quaternion::from(q.coords.map(Dual64::from)))
}

/// A real pass's stage as one of dual numbers (no derivative), for the pass along joint `k`.
fn lift_stage(stage: &Stage<f64>, k: usize) -> Stage<Dual64> {
    Stage {
        s: stage.s,
        segment: lift(&stage.segment),
        motions: stage.motions.iter().map(lift_motion).collect(),
        along: Some(k),
    }
}

/// An `f64` body motion as one of dual numbers (no derivative).
fn lift_motion(m: &BodyMotion<f64>) -> BodyMotion<Dual64> {
    BodyMotion {
        omega: m.omega.map(Dual64::from),
        alpha: m.alpha.map(Dual64::from),
        accel: m.accel.map(Dual64::from),
    }
}

/// The first-order local motion of component `c` of a joint block (as [`super::problem`]'s
/// retraction applies it) with the dual unit in that component: rotations as `(1, ε/2)`
/// quaternions, exact to first order (a rotation vector's norm has no derivative at zero).
fn joint_step(full: bool, c: usize) -> Isometry3<Dual64> {
    // Joint: (rx, ry, x, y); full: (rx, ry, rz, x, y, z).
    unit_motion(if full { c } else { [0, 1, 3, 4][c] })
}
/// The world twist `(φ, t)` of the local motion `step` (dual unit in one component) of the joint
/// frame `frame`: everything after the joint moves by `frame · step · frame⁻¹`, to first order
/// `p ↦ p + φ × p + t`.
fn twist(frame: &Isometry3<f64>, step: &Isometry3<Dual64>) -> Vector6<f64> {
    let frame = lift(frame);
    let moved = frame * step * frame.inverse();
    let q = moved.rotation.quaternion();
    let t = moved.translation.vector;
    Vector6::new(
        2.0 * q.i.eps,
        2.0 * q.j.eps,
        2.0 * q.k.eps,
        t.x.eps,
        t.y.eps,
        t.z.eps,
    )
}

/// The first-order motion with the dual unit in component `slot` of `(rx, ry, rz, x, y, z)`: a
/// turn `(1, ε e_j / 2)` about axis `j = slot < 3`, a shift `ε e_{slot−3}` otherwise (the unit
/// world twists of [`FrameRates`], and a joint column's local motion).
fn unit_motion(slot: usize) -> Isometry3<Dual64> {
    let mut x = [Dual64::from(0.0); 6];
    x[slot] = Dual64::new(0.0, 1.0);
    let half = Dual64::from(0.5);
    Isometry3::from_parts(
        Translation3::new(x[3], x[4], x[5]),
        UnitQuaternion::new_unchecked(Quaternion::new(
            Dual64::from(1.0),
            x[0] * half,
            x[1] * half,
            x[2] * half,
        )),
    )
}
