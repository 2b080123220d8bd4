//! The least-squares problem of a limb: residuals and Jacobian per SU — each reading
//! `K Rᵀ (c + N p) (+ b)` of its segment's terms ([`super::terms`], which also give their rates
//! along the shared columns), so that this module holds only the chain rule through the SU's own
//! frame and intrinsics —, the Levenberg–Marquardt solver with the SU blocks eliminated (Schur
//! complement), and the parameter covariance.
//!
//! Every SU's readings depend on its own 6 parameters and on the shared ones (gravity and the joint
//! lines before it), never on another SU's: the normal matrix is block-arrow shaped. Each SU block is
//! linearised on its own (in parallel) and reduced at once to its small normal-equation pieces, the
//! SU blocks are eliminated and only the shared system is factorised, so an iteration costs time
//! linear in the number of SUs and memory independent of the number of readings.

use std::ops::Range;
use std::sync::Arc;

use nalgebra::{
    DMatrix, DVector, Isometry3, Matrix3, Matrix3x6, Translation3, UnitQuaternion, Vector3,
};
use rayon::prelude::*;

use super::motion::{segment_terms, LimbMotion, MAX_DELAY};
use super::terms::{link, Chain, Instant, ReadingInstants, SegmentTerms};
use super::{ChainState, Unobservable};
use crate::estimate::limb::LimbData;
use crate::model::intrinsics::Intrinsics;
use crate::model::sensor::STANDARD_GRAVITY;
use crate::model::DofKind;

/// The prior standard deviation of each intrinsic component (bias 0.1 g, scale 5 %,
/// misalignment 0.05 rad): weak beside what the readings tell when they tell it, it holds the
/// directions that no reading determines at the ideal sensor's values.
pub(super) const INTRINSIC_PRIOR_SD: [f64; 9] = [
    0.1 * STANDARD_GRAVITY,
    0.1 * STANDARD_GRAVITY,
    0.1 * STANDARD_GRAVITY,
    0.05,
    0.05,
    0.05,
    0.05,
    0.05,
    0.05,
];

/// The prior standard deviation of an SU's position on its segment and of a joint's on its parent
/// (from the frame before it), m: far beyond any robot, it leaves every position the readings tell
/// as they tell it (a bias of (σ/10 m)² of it), and keeps near their frames the directions no
/// reading tells — a shift along axes that are all parallel — which the solves would otherwise let
/// drift hundreds of metres away. Stronger, it slows the solves down (Gauss–Newton crawls along
/// the curved valley of what the readings hardly tell) and biases what they tell weakly: the joint
/// of two nearly parallel axes, whose common normal lies far along them (at 1 m, random DH chains'
/// SU rotations came out 1.9° off where 0.3° is the rule).
pub(super) const POSITION_PRIOR_SD: f64 = 10.0;

/// Which SU sits on which segment (1-based: segment `k` is moved directly by DoF `k−1`).
#[derive(Debug, Clone, PartialEq)]
pub(super) struct Layout {
    pub dofs: usize,
    pub su_segment: Vec<usize>,
    /// Per DoF: revolute or prismatic (turns about or slides along its joint frame's `z`).
    pub kinds: Vec<DofKind>,
    /// How many base orientations the training poses stood in (each beyond the usual one has
    /// a gravity block of its own).
    pub orientations: usize,
}

impl Layout {
    /// The layout of a limb's data.
    pub fn of(data: &LimbData) -> Self {
        Self {
            dofs: data.chain.dofs().len(),
            su_segment: data.su_depth.clone(),
            kinds: data.chain.kinds(),
            orientations: data.orientations(),
        }
    }
}

/// Readings of the limb, per pose and SU, in m/s².
#[derive(Debug, Clone)]
pub(super) struct Readings {
    pub q: Vec<Vec<f64>>,
    /// The motion of every DoF in every pose: `Rz(q)`, or `Tz(q)` for a prismatic one.
    pub turns: Vec<Vec<Isometry3<f64>>>,
    pub statics: Vec<Vec<Vector3<f64>>>,
    /// `dynamics[p][u][d]` for every DoF `d` before the SU.
    pub dynamics: Vec<Vec<Vec<Vector3<f64>>>>,
    pub alpha: f64,
    /// Huber's threshold on the whitened norm of one reading's 3-vector residual: beyond it a
    /// reading counts linearly, so a few wild ones cannot drag the fit. `None`: least squares.
    pub huber: Option<f64>,
    /// Readings left out (wild ones found after the fit): `rejected[p][u][0]` the static reading,
    /// `[1 + d]` the dynamic one of DoF `d`. Empty: none.
    pub rejected: Vec<Vec<Vec<bool>>>,
    /// Readings the measurement set does not have (indexed as `rejected`; zero in `dynamics`):
    /// never used, never counted as left out. Empty: none.
    pub missing: Vec<Vec<Vec<bool>>>,
    /// The standard deviation of the weak priors on the positions of SUs and joints that hold the
    /// directions no reading tells near their frames, m ([`POSITION_PRIOR_SD`] for the search and
    /// the fit); `None` for what is reported about the fit (residual, covariance, bounds).
    pub gauge_prior: Option<f64>,
    /// Each reading's own standard deviation (`[p][u][row]` as `rejected`), m/s²; `None`: every
    /// reading has the estimator's `sigma`.
    pub sd: Option<Arc<Vec<Vec<Vec<f64>>>>>,
    /// The limb's motion record, fitted sample by sample (rows after the poses'), each block
    /// whitened by its SU's own noise; `None`: readings only.
    pub motion: Option<Arc<LimbMotion>>,
    /// `orientation[p]`: the base orientation of pose `p`, whose gravity its static readings
    /// read (`gravity`, or [`ChainState::other_gravities`]). Empty: every pose in the usual one.
    pub orientation: Vec<usize>,
    /// Whether the motion rows' column of the skin's delay is the prediction's rate (the
    /// information the record holds about the delay: for what is reported of a fit) rather than
    /// the cost's own derivative (noisy, as the interpolated skin is: for the fit's steps).
    pub expected_delay_rate: bool,
}

impl Readings {
    /// How much more information its rows seem to hold along a slowly varying direction than
    /// they do ([`LimbMotion::overcount`]; 1 without a motion record).
    pub(super) fn overcount(&self) -> f64 {
        self.motion.as_ref().map_or(1.0, |m| m.overcount())
    }

    /// The base orientation of pose `p` (0: the usual one).
    pub(super) fn orientation_of(&self, p: usize) -> usize {
        self.orientation.get(p).copied().unwrap_or(0)
    }

    /// Whether reading `row` of SU `u` in pose `p` is left out of the fit: wild, or missing.
    pub(super) fn is_rejected(&self, p: usize, u: usize, row: usize) -> bool {
        let marked = |mask: &Vec<Vec<Vec<bool>>>| {
            mask.get(p)
                .and_then(|r| r.get(u))
                .and_then(|r| r.get(row))
                .copied()
                .unwrap_or(false)
        };
        marked(&self.rejected) || marked(&self.missing)
    }

    /// The weight of a reading whose whitened residual has norm `s` (1 within the Huber
    /// threshold), and its share of the cost.
    fn robust(&self, s: f64) -> (f64, f64) {
        match self.huber {
            Some(k) if s > k => (k / s, 2.0 * k * s - k * k),
            _ => (1.0, s * s),
        }
    }
}

/// A parameter block of the least-squares problem.
#[derive(Debug, Clone, Copy, PartialEq)]
pub(super) enum Block {
    /// Gravity's 3 components, m/s².
    Gravity,
    /// Gravity's direction alone (2 turns about its tangents; its magnitude held).
    GravityDirection,
    /// The 3 components of gravity in base orientation `o ≥ 1`, m/s² (training poses with the
    /// reference segment turned otherwise).
    OtherGravity(usize),
    /// The 4 line parameters of joint `k`.
    Joint(usize),
    /// All 6 parameters of joint `k` (initialisation only).
    JointFull(usize),
    /// The 6 parameters of SU `u`.
    Su(usize),
    /// The 9 accelerometer intrinsics of SU `u`: bias (3), scale (3), misalignment (3).
    Intrinsics(usize),
    /// How late the skin's clock runs behind the joint states', s (motion rows only).
    SkinDelay,
}

impl Block {
    fn len(self) -> usize {
        match self {
            Block::Gravity | Block::OtherGravity(_) => 3,
            Block::GravityDirection => 2,
            Block::Joint(_) => 4,
            Block::JointFull(_) | Block::Su(_) => 6,
            Block::Intrinsics(_) => 9,
            Block::SkinDelay => 1,
        }
    }
}

/// A least-squares problem: which blocks are free, which components are held, whose readings count.
#[derive(Debug, Clone, PartialEq)]
pub(super) struct Spec {
    pub blocks: Vec<Block>,
    /// (block index, component) held fixed.
    pub held: Vec<(usize, usize)>,
    /// SUs whose residuals enter.
    pub sus: Vec<usize>,
    /// Frames that the free blocks cannot change, per pose: the joint frames before the first
    /// free joint and the segment it sits on (a cache for the segment-by-segment solves).
    pub prefix: Option<Arc<Vec<Prefix>>>,
}

impl Spec {
    /// Free columns: (block index, component).
    pub fn columns(&self) -> Vec<(usize, usize)> {
        let held: std::collections::HashSet<&(usize, usize)> = self.held.iter().collect();
        self.blocks
            .iter()
            .enumerate()
            .flat_map(|(b, block)| (0..block.len()).map(move |c| (b, c)))
            .filter(|bc| !held.contains(bc))
            .collect()
    }
}

/// Where a free column lives: among the shared parameters, or in one SU's own block.
#[derive(Debug, Clone, Copy, PartialEq)]
enum Slot {
    Shared(usize),
    /// (position of the SU in `Spec::sus`, component).
    Own(usize, usize),
}

/// The free columns sorted into shared ones and per-SU ones.
#[derive(Debug, Clone)]
pub(super) struct ColumnMap {
    slots: Vec<Slot>,
    shared: Vec<(usize, usize)>,
    own: Vec<Vec<(usize, usize)>>,
}

impl ColumnMap {
    /// The shared columns, (block index, component), in the order of the shared system.
    pub fn shared(&self) -> &[(usize, usize)] {
        &self.shared
    }

    /// How many free columns there are, shared and own.
    pub fn len(&self) -> usize {
        self.slots.len()
    }

    pub fn new(spec: &Spec) -> Self {
        let mut slots = Vec::new();
        let mut shared = Vec::new();
        let mut own = vec![Vec::new(); spec.sus.len()];
        for (b, c) in spec.columns() {
            let owner = match spec.blocks[b] {
                Block::Su(u) | Block::Intrinsics(u) => spec.sus.iter().position(|&v| v == u),
                _ => None,
            };
            match owner {
                Some(i) => {
                    slots.push(Slot::Own(i, own[i].len()));
                    own[i].push((b, c));
                }
                None => {
                    slots.push(Slot::Shared(shared.len()));
                    shared.push((b, c));
                }
            }
        }
        Self { slots, shared, own }
    }
}

/// Frames of one pose.
pub(super) struct Frames {
    /// Joint frames in the reference frame.
    pub joints: Vec<Isometry3<f64>>,
    /// Segment frames in the reference frame (`segments[0] = I`).
    pub segments: Vec<Isometry3<f64>>,
    /// SU frames in the reference frame.
    pub sus: Vec<Isometry3<f64>>,
}

/// Joint frames `0…k−1` and the frame of segment `k` of one pose, in the reference frame.
#[derive(Debug, Clone, PartialEq)]
pub(super) struct Prefix {
    pub joints: Vec<Isometry3<f64>>,
    pub segment: Isometry3<f64>,
}

/// The prefixes up to joint `k` of every pose.
pub(super) fn prefixes(
    state: &ChainState,
    layout: &Layout,
    data: &Readings,
    k: usize,
) -> Arc<Vec<Prefix>> {
    Arc::new(
        data.turns
            .iter()
            .map(|turns| {
                let f = frames(state, layout, turns, None, k);
                Prefix {
                    joints: f.joints[..k].to_vec(),
                    segment: f.segments[k],
                }
            })
            .collect(),
    )
}

/// The motion of every DoF of a pose: `Rz(q_k)`, or `Tz(q_k)` for a prismatic DoF.
pub(super) fn turns_of(q: &[f64], kinds: &[DofKind]) -> Vec<Isometry3<f64>> {
    q.iter()
        .zip(kinds)
        .map(|(&a, kind)| kind.motion(&Vector3::z_axis(), a))
        .collect()
}

/// Frames of one pose up to segment `last` (joints `0…last−1`), continuing from `prefix` when given,
/// and the frames of the SUs on those segments (identity for the others).
pub(super) fn frames(
    state: &ChainState,
    layout: &Layout,
    turns: &[Isometry3<f64>],
    prefix: Option<&Prefix>,
    last: usize,
) -> Frames {
    let (mut joints, mut segments) = match prefix {
        Some(p) => {
            let mut segments = vec![Isometry3::identity(); p.joints.len()];
            segments.push(p.segment);
            (p.joints.clone(), segments)
        }
        None => (Vec::with_capacity(layout.dofs), vec![Isometry3::identity()]),
    };
    for k in joints.len()..last.min(layout.dofs) {
        let (joint, segment) = link(&segments[k], &state.joints[k], &turns[k]);
        joints.push(joint);
        segments.push(segment);
    }
    let sus = state
        .sus
        .iter()
        .zip(&layout.su_segment)
        .map(|(s, &seg)| segments.get(seg).map_or(Isometry3::identity(), |f| f * s))
        .collect();
    Frames {
        joints,
        segments,
        sus,
    }
}

/// Two unit vectors perpendicular to `g` and to each other (a fixed choice for every `g`).
fn gravity_tangents(g: &Vector3<f64>) -> (Vector3<f64>, Vector3<f64>) {
    let n = g.try_normalize(1e-300).unwrap_or_else(Vector3::z);
    let least = (0..3)
        .min_by(|&a, &b| n[a].abs().total_cmp(&n[b].abs()))
        .unwrap_or(0);
    let e1 = Vector3::ith(least, 1.0).cross(&n).normalize();
    (e1, n.cross(&e1))
}

/// How gravity changes with the 2 components of its direction block (turns about the two
/// tangents of [`gravity_tangents`]); the third entry is unused.
pub(super) fn gravity_directions(g: &Vector3<f64>) -> [Vector3<f64>; 3] {
    let (e1, e2) = gravity_tangents(g);
    [e1.cross(g), e2.cross(g), Vector3::zeros()]
}

/// The direction block's retraction: `g` turned by `x0` and `x1` about its tangents.
fn turn_gravity(g: &Vector3<f64>, x0: f64, x1: f64) -> Vector3<f64> {
    let (e1, e2) = gravity_tangents(g);
    UnitQuaternion::from_scaled_axis(e1 * x0 + e2 * x1) * g
}

/// The outermost segment that carries an SU of `spec`.
fn last_segment(layout: &Layout, spec: &Spec) -> usize {
    spec.sus
        .iter()
        .map(|&u| layout.su_segment[u])
        .max()
        .unwrap_or(0)
}

/// The shared columns of `spec` as blocks and components (what the segment terms are
/// differentiated along).
fn shared_columns(spec: &Spec, map: &ColumnMap) -> Vec<(Block, usize)> {
    map.shared
        .iter()
        .map(|&(b, c)| (spec.blocks[b], c))
        .collect()
}

/// The segment terms of every pose's readings for the SUs of `spec` (`[p][0]` the static
/// reading's instant, `[p][1 + d]` DoF `d`'s dynamic one), with their derivatives along the
/// shared columns when `jacobian`.
fn pose_terms(
    state: &ChainState,
    layout: &Layout,
    data: &Readings,
    spec: &Spec,
    map: &ColumnMap,
    jacobian: bool,
) -> Vec<Vec<SegmentTerms>> {
    let last = last_segment(layout, spec);
    let columns = shared_columns(spec, map);
    let chain = Chain::new(state, &layout.kinds, jacobian.then_some(columns.as_slice()));
    let readings = ReadingInstants::new(&layout.kinds, last, data.alpha);
    let orientations = data.orientation.iter().max().map_or(1, |&o| o + 1);
    let instants: Vec<_> = (0..orientations).map(|o| readings.instants(o)).collect();
    (0..data.q.len())
        .into_par_iter()
        .map(|p| {
            let prefix = spec.prefix.as_ref().map(|v| &v[p]);
            let instants = &instants[data.orientation_of(p)];
            chain.terms(&data.turns[p], prefix, instants, last)
        })
        .collect()
}

/// The motion rows' segment terms at `state` for the SUs of `spec` (with their derivatives along
/// the shared columns when `jacobian`), at `samples` of `motion`.
fn motion_terms(
    state: &ChainState,
    layout: &Layout,
    spec: &Spec,
    map: &ColumnMap,
    jacobian: bool,
    (motion, samples): (&LimbMotion, Range<usize>),
) -> Vec<SegmentTerms> {
    let last = last_segment(layout, spec);
    let columns = shared_columns(spec, map);
    segment_terms(
        state,
        motion,
        last,
        jacobian.then_some(columns.as_slice()),
        samples,
    )
}

/// What an SU's rows need of its state: its intrinsics, `Rᵀ` and `K Rᵀ` of its rotation on its
/// segment, its position there, and whether any of its intrinsics are free.
struct SuFrame<'a> {
    intrinsics: &'a Intrinsics,
    bias: Vector3<f64>,
    rt: Matrix3<f64>,
    krt: Matrix3<f64>,
    p: Vector3<f64>,
}

impl<'a> SuFrame<'a> {
    fn new(state: &'a ChainState, u: usize) -> Self {
        let intrinsics = &state.intrinsics[u];
        let rt = state.sus[u]
            .rotation
            .to_rotation_matrix()
            .into_inner()
            .transpose();
        Self {
            intrinsics,
            bias: Vector3::from(intrinsics.bias),
            rt,
            krt: intrinsics.matrix() * rt,
            p: state.sus[u].translation.vector,
        }
    }

    /// The specific force at the SU of segment entry `s` of `terms` (segment frame): `c + N p`.
    fn field(&self, terms: &SegmentTerms, s: usize) -> Vector3<f64> {
        terms.c(s) + terms.n(s) * self.p
    }

    /// What the SU reads of the field `v`: `K Rᵀ v`, plus its bias when `bias` (a reading, not
    /// the difference of two).
    fn reading(&self, v: &Vector3<f64>, bias: bool) -> Vector3<f64> {
        let read = self.krt * v;
        if bias {
            read + self.bias
        } else {
            read
        }
    }
}

/// What every SU of a limb reads at any instant of motion at one state, gravity on (the chain's
/// one kinematics, [`Chain`], and each SU's frame and sensor).
pub(super) struct Predictor<'a> {
    chain: Chain<'a>,
    /// Per SU: its segment and frame.
    sus: Vec<(usize, SuFrame<'a>)>,
    last: usize,
}

impl<'a> Predictor<'a> {
    pub(super) fn new(state: &'a ChainState, layout: &'a Layout) -> Self {
        let sus: Vec<(usize, SuFrame)> = layout
            .su_segment
            .iter()
            .enumerate()
            .map(|(u, &s)| (s, SuFrame::new(state, u)))
            .collect();
        Self {
            chain: Chain::new(state, &layout.kinds, None),
            last: layout.su_segment.iter().copied().max().unwrap_or(0),
            sus,
        }
    }

    /// Every SU's reading with the DoFs turned by `turns` (`Rz(q)` or `Tz(q)`), at rates `qd`
    /// and accelerations `qdd`; `None` for an SU on the reference segment.
    pub(super) fn readings(
        &self,
        turns: &[Isometry3<f64>],
        qd: &[f64],
        qdd: &[f64],
    ) -> Vec<Option<Vector3<f64>>> {
        let instant = [Instant::new(qd, qdd, true)];
        let terms = self.chain.terms(turns, None, &instant, self.last);
        self.sus
            .iter()
            .map(|(s, su)| {
                let e = s.checked_sub(1)?;
                Some(su.reading(&su.field(&terms[0], e), true))
            })
            .collect()
    }
}

/// Where the Jacobian rows of one reading go: the SU's own and the shared columns of its block,
/// from row `row`, each rate multiplied by `scale`.
struct JacobianRows<'a> {
    spec: &'a Spec,
    map: &'a ColumnMap,
    /// The SU and its place in `spec.sus`.
    u: usize,
    i: usize,
    row: usize,
    scale: f64,
}

impl JacobianRows<'_> {
    /// Fills the rows of the reading of SU `su` from segment entry `s` of `terms` (with its
    /// bias when `bias`): along the SU's own frame (`R ← exp(ω) R`: `K Rᵀ (v × e_c)`; a shift
    /// `K Rᵀ N e_c`) and intrinsics, and along the shared columns that move its segment (the
    /// other shared columns' rows stay zero).
    fn fill(
        &self,
        su: &SuFrame,
        terms: &SegmentTerms,
        s: usize,
        bias: bool,
        own: &mut DMatrix<f64>,
        shared: &mut DMatrix<f64>,
    ) {
        let v = su.field(terms, s);
        let n = terms.n(s);
        let mut partials = None;
        let mut rate = |block: Block, c: usize| match block {
            Block::Su(v_) if v_ == self.u && c < 3 => Some(su.krt * v.cross(&Vector3::ith(c, 1.0))),
            Block::Su(v_) if v_ == self.u => Some(su.krt * n.column(c - 3)),
            Block::Intrinsics(v_) if v_ == self.u => {
                let p = partials.get_or_insert_with(|| su.intrinsics.partials(&(su.rt * v), bias));
                Some(p[c])
            }
            _ => None,
        };
        for (col, &(b, c)) in self.map.own[self.i].iter().enumerate() {
            if let Some(d) = rate(self.spec.blocks[b], c) {
                own.fixed_view_mut::<3, 1>(self.row, col)
                    .copy_from(&(d * self.scale));
            }
        }
        // The SU's own frame and intrinsics are its own columns, never shared ones (see
        // `ColumnMap::new`): the shared columns are those of the terms' rates.
        for (col, dc, dn) in terms.rates(s) {
            let d = su.krt * (dc + dn * su.p);
            shared
                .fixed_view_mut::<3, 1>(self.row, *col)
                .copy_from(&(d * self.scale));
        }
        if let Some((frame, twists)) = terms.frame_rates(s) {
            let along = Matrix3x6::from_columns(&frame.map(|(dc, dn)| su.krt * (dc + dn * su.p)));
            for (col, twist) in twists {
                shared
                    .fixed_view_mut::<3, 1>(self.row, col)
                    .copy_from(&(along * twist * self.scale));
            }
        }
    }
}

/// The motion rows of one SU: where they start in its block, and what they need.
struct MotionRows<'a> {
    spec: &'a Spec,
    map: &'a ColumnMap,
    motion: &'a LimbMotion,
    /// The segment terms of samples `first..first + terms.len()` of the record.
    terms: &'a [SegmentTerms],
    first: usize,
    /// The SU, its place in `spec.sus`, and its segment's entry in the terms (segment − 1).
    u: usize,
    i: usize,
    segment: usize,
    /// The first motion row.
    at: usize,
}

impl MotionRows<'_> {
    /// Fills the SU's motion rows of `samples` (within the terms' samples; from row `at`, 3 per
    /// sample) of `r` (and of its Jacobian blocks `(own, shared)` when given):
    /// `(K Rᵀ (c + N p) + b − measured) / sd` per sample, Huber-weighted, with `predicted`
    /// ([`MotionRows::predicted`]) the first part. Returns the cost and the number of rows that
    /// count.
    fn fill(
        &self,
        state: &ChainState,
        data: &Readings,
        (samples, predicted): (Range<usize>, &[Vector3<f64>]),
        r: &mut DVector<f64>,
        mut jacobian: Option<(&mut DMatrix<f64>, &mut DMatrix<f64>)>,
    ) -> (f64, usize) {
        let (u, motion, s) = (self.u, self.motion, self.segment);
        let su = SuFrame::new(state, u);
        let (mut cost, mut count) = (0.0, 0);
        let delay_column = self
            .map
            .shared
            .iter()
            .position(|&(b, _)| self.spec.blocks[b] == Block::SkinDelay);
        for j in samples.clone() {
            let terms = &self.terms[j - self.first];
            let row = self.at + 3 * (j - samples.start);
            let Some(measured) = motion.interpolated(u, j, state.skin_delay) else {
                continue;
            };
            // Weighed by the interpolated skin's own noise, so that where the delay puts the
            // skin between blocks does not pay by itself.
            let sd = motion.residual_variance(u, j, measured.variance).sqrt();
            let residual = (predicted[j - self.first] - measured.value) / sd;
            let (w, c) = data.robust(residual.norm());
            cost += c;
            count += 3;
            let scale = w.sqrt() / sd;
            r.fixed_rows_mut::<3>(row).copy_from(&(residual * w.sqrt()));
            let Some((own, shared)) = jacobian.as_mut() else {
                continue;
            };
            let rows = JacobianRows {
                spec: self.spec,
                map: self.map,
                u,
                i: self.i,
                row,
                scale,
            };
            rows.fill(&su, terms, s, true, own, shared);
            if let Some(col) = delay_column {
                // The residual's rate with the delay: of what is measured and of its weight
                // (the cost's own); or, for what is reported, the information the record holds
                // about the delay, the prediction's own rate standing for the measured one's.
                let d = if data.expected_delay_rate {
                    self.rate(predicted, j)
                } else {
                    let sd_rate = motion.skin_variance(u) * measured.variance_rate / (2.0 * sd);
                    measured.rate + residual * sd_rate
                };
                shared
                    .fixed_view_mut::<3, 1>(row, col)
                    .copy_from(&(-d * scale));
            }
        }
        (cost, count)
    }

    /// What the SU is predicted to read at every sample of the terms.
    fn predicted(&self, state: &ChainState) -> Vec<Vector3<f64>> {
        let su = SuFrame::new(state, self.u);
        self.terms
            .iter()
            .map(|t| su.reading(&su.field(t, self.segment), true))
            .collect()
    }

    /// The rate of `predicted` at sample `j`: a central difference where both neighbouring
    /// blocks are in its run, one-sided at a run's end, zero for a run of one block. The
    /// neighbours must be among the terms' samples where the record has them.
    fn rate(&self, predicted: &[Vector3<f64>], j: usize) -> Vector3<f64> {
        let (motion, first) = (self.motion, self.first);
        let rate = |a: usize, b: usize| {
            (predicted[b - first] - predicted[a - first]) / (motion.spacing() * (b - a) as f64)
        };
        let before = (j > 0 && motion.adjacent(j - 1, j)).then(|| j - 1);
        let after = (j + 1 < motion.len() && motion.adjacent(j, j + 1)).then(|| j + 1);
        match (before, after) {
            (Some(a), Some(b)) => rate(a, b),
            (Some(a), None) => rate(a, j),
            (None, Some(b)) => rate(j, b),
            (None, None) => Vector3::zeros(),
        }
    }
}

/// One SU's residuals (whitened; rows: pose by pose, the static reading then the dynamic
/// acceleration of every DoF before it; then the motion record's samples; then the priors of its
/// free intrinsics) and, when asked, the Jacobian columns of its own block and of the shared
/// parameters.
struct SuBlock {
    r: DVector<f64>,
    own: DMatrix<f64>,
    shared: DMatrix<f64>,
    /// The (robust) cost of these residuals.
    cost: f64,
    /// Residuals that count (rejected readings' rows are zero and do not).
    count: usize,
}

impl SuBlock {
    /// Every row zero again, no cost.
    fn clear(&mut self) {
        self.r.as_mut_slice().fill(0.0);
        self.own.as_mut_slice().fill(0.0);
        self.shared.as_mut_slice().fill(0.0);
        self.cost = 0.0;
        self.count = 0;
    }

    /// Adds one reading's cost to the block's and weighs its 3 rows from `at`: by its own
    /// deviation where it has one, and by the robust weight of its whitened norm. Returns the
    /// factor its Jacobian rows must take (0 for a rejected reading).
    fn weigh(
        &mut self,
        data: &Readings,
        sigma: f64,
        (p, u, j): (usize, usize, usize),
        at: usize,
    ) -> f64 {
        let mut rows = self.r.fixed_rows_mut::<3>(at);
        if data.is_rejected(p, u, j) {
            rows.fill(0.0);
            return 0.0;
        }
        let mut scale = 1.0;
        if let Some(sd) = &data.sd {
            scale = sigma / sd[p][u][j];
            rows.scale_mut(scale);
        }
        let (w, c) = data.robust(rows.norm());
        self.cost += c;
        self.count += 3;
        if w < 1.0 {
            scale *= w.sqrt();
            rows.scale_mut(w.sqrt());
        }
        scale
    }
}

impl SuBlock {
    /// Adds the block's pieces of the normal equations to `part`: its own `(A, B, g_o)`,
    /// `J_sᵀJ_s` and `J_sᵀr`, its cost and its rows that count.
    ///
    /// Most rows see a few shared columns only (a dynamic reading of DoF `d` sees the joints
    /// between `d` and the SU), so the rows are grouped by the range of shared columns that is
    /// not zero in them and each group multiplied on its range alone. Products of transposes:
    /// nalgebra multiplies those by a blocked kernel (`matrixmultiply`), `tr_mul` by one dot
    /// product per entry.
    fn add_to(&self, part: &mut SuPart) {
        for ((lo, hi), rows) in self.shared_ranges() {
            let w = hi - lo;
            let j = self.shared.columns(lo, w).select_rows(&rows);
            let o_t = self.own.select_rows(&rows).transpose();
            let r = self.r.select_rows(&rows);
            let j_t = j.transpose();
            part.c.view_mut((lo, lo), (w, w)).gemm(1.0, &j_t, &j, 1.0);
            let n = self.own.ncols();
            part.su.b.view_mut((0, lo), (n, w)).gemm(1.0, &o_t, &j, 1.0);
            part.gs.rows_mut(lo, w).gemv(1.0, &j_t, &r, 1.0);
        }
        self.add_own_to(part);
    }

    /// [`SuBlock::add_to`] for rows that all see about the same shared columns (a motion
    /// record's: the joints before the SU's segment, gravity, the delay): the range of shared
    /// columns not zero in any row, without grouping the rows, entry by entry, each a dot
    /// product of two columns (contiguous: the blocks are column-major), the symmetric ones
    /// once. On a chunk's few hundred rows this is faster than a transposed copy and a blocked
    /// product.
    fn add_on_one_range_to(&self, part: &mut SuPart) {
        let (m, n) = (self.shared.ncols(), self.own.ncols());
        let nonzero = |k: &usize| self.shared.column(*k).iter().any(|x| *x != 0.0);
        let lo = (0..m).find(nonzero).unwrap_or(m);
        let hi = (lo..m).rev().find(nonzero).map_or(lo, |k| k + 1);
        let (shared, own) = (
            |k: usize| self.shared.column(k),
            |k: usize| self.own.column(k),
        );
        for k in lo..hi {
            for l in k..hi {
                let x = shared(k).dot(&shared(l));
                part.c[(k, l)] += x;
                if l != k {
                    part.c[(l, k)] += x;
                }
            }
            part.gs[k] += shared(k).dot(&self.r);
            for o in 0..n {
                part.su.b[(o, k)] += own(o).dot(&shared(k));
            }
        }
        self.add_own_to(part);
    }

    /// Adds the products of the own columns (`A`, `g_o`), the cost and the count to `part`.
    fn add_own_to(&self, part: &mut SuPart) {
        let own = |k: usize| self.own.column(k);
        for o in 0..self.own.ncols() {
            for p in o..self.own.ncols() {
                let x = own(o).dot(&own(p));
                part.su.a[(o, p)] += x;
                if p != o {
                    part.su.a[(p, o)] += x;
                }
            }
            part.su.go[o] += own(o).dot(&self.r);
        }
        part.cost += self.cost;
        part.count += self.count;
    }

    /// The rows with a shared column not zero, grouped by the range of such columns
    /// (`lo..hi`), in the order of the ranges.
    fn shared_ranges(&self) -> std::collections::BTreeMap<(usize, usize), Vec<usize>> {
        let rows = self.shared.nrows();
        // Rows sorted by the first and last of their shared columns not zero. Through the
        // columns in order: a row's first is where its `lo` is first set, its last where `hi`
        // was set last.
        let (mut lo, mut hi) = (vec![usize::MAX; rows], vec![0; rows]);
        for (k, column) in self.shared.column_iter().enumerate() {
            for ((x, lo), hi) in column.iter().zip(&mut lo).zip(&mut hi) {
                if *x != 0.0 {
                    *lo = (*lo).min(k);
                    *hi = k + 1;
                }
            }
        }
        let mut groups = std::collections::BTreeMap::<(usize, usize), Vec<usize>>::new();
        for r in (0..rows).filter(|&r| hi[r] > 0) {
            groups.entry((lo[r], hi[r])).or_default().push(r);
        }
        groups
    }
}

/// What every SU block of a problem at one state shares: the data, and the segment terms of the
/// poses' readings and of the motion rows (with their derivatives when the blocks carry
/// Jacobians).
struct Blocks<'a> {
    state: &'a ChainState,
    layout: &'a Layout,
    data: &'a Readings,
    spec: &'a Spec,
    map: &'a ColumnMap,
    sigma: f64,
    jacobian: bool,
    poses: Vec<Vec<SegmentTerms>>,
    /// The motion rows' terms at every sample of the record; `None` without a record, or when
    /// the rows are formed a window at a time ([`Blocks::add_motion`], [`normal_system`]).
    terms: Option<Vec<SegmentTerms>>,
}

impl<'a> Blocks<'a> {
    /// The blocks at `state`, with the segment terms of every sample of a motion record when
    /// `whole_record` (else the motion rows are formed a window at a time:
    /// [`Blocks::add_motion`]).
    #[allow(clippy::too_many_arguments)]
    fn new(
        state: &'a ChainState,
        layout: &'a Layout,
        data: &'a Readings,
        spec: &'a Spec,
        map: &'a ColumnMap,
        sigma: f64,
        jacobian: bool,
        whole_record: bool,
    ) -> Self {
        let terms = data.motion.as_ref().filter(|_| whole_record).map(|motion| {
            motion_terms(
                state,
                layout,
                spec,
                map,
                jacobian,
                (motion, 0..motion.len()),
            )
        });
        Self {
            state,
            layout,
            data,
            spec,
            map,
            sigma,
            jacobian,
            poses: pose_terms(state, layout, data, spec, map, jacobian),
            terms,
        }
    }

    /// The block of SU `spec.sus[i]`: its pose rows, its motion rows, its priors.
    fn block(&self, i: usize) -> SuBlock {
        self.block_with(i, true)
    }

    /// The block of SU `spec.sus[i]`, with its motion rows or without.
    fn block_with(&self, i: usize, with_motion: bool) -> SuBlock {
        let u = self.spec.sus[i];
        let s = self.layout.su_segment[u];
        let priors = self.prior_columns(i);
        let pose_rows = 3 * (1 + s) * self.data.q.len();
        let motion = self
            .terms
            .as_deref()
            .and_then(|terms| self.motion_rows(i, pose_rows, (terms, 0)))
            .filter(|_| with_motion);
        let motion_rows = motion.as_ref().map_or(0, |m| 3 * m.motion.len());
        let mut block = self.zeros(i, pose_rows + motion_rows + priors.len());
        let su = SuFrame::new(self.state, u);
        for p in 0..self.poses.len() {
            self.pose_rows(i, p, &su, &mut block);
        }
        if let Some(rows) = motion {
            let predicted = rows.predicted(self.state);
            let SuBlock { r, own, shared, .. } = &mut block;
            let (c, n) = rows.fill(
                self.state,
                self.data,
                (0..rows.motion.len(), &predicted),
                r,
                self.jacobian.then_some((own, shared)),
            );
            block.cost += c;
            block.count += n;
        }
        self.prior_rows(i, &priors, pose_rows + motion_rows, &mut block);
        block
    }

    /// A block of `rows` zero rows for SU `spec.sus[i]` (with its Jacobian's columns when the
    /// blocks carry one).
    fn zeros(&self, i: usize, rows: usize) -> SuBlock {
        let (own, shared) = if self.jacobian {
            (
                DMatrix::zeros(rows, self.map.own[i].len()),
                DMatrix::zeros(rows, self.map.shared.len()),
            )
        } else {
            (DMatrix::zeros(0, 0), DMatrix::zeros(0, 0))
        };
        SuBlock {
            r: DVector::zeros(rows),
            own,
            shared,
            cost: 0.0,
            count: 0,
        }
    }

    /// The motion rows of SU `spec.sus[i]` from row `at`, when the readings hold a record, on
    /// the segment terms of its samples `first..first + terms.len()`.
    fn motion_rows<'t>(
        &'t self,
        i: usize,
        at: usize,
        (terms, first): (&'t [SegmentTerms], usize),
    ) -> Option<MotionRows<'t>> {
        let motion = self.data.motion.as_deref()?;
        let u = self.spec.sus[i];
        Some(MotionRows {
            spec: self.spec,
            map: self.map,
            motion,
            terms,
            first,
            u,
            i,
            segment: self.layout.su_segment[u] - 1,
            at,
        })
    }

    /// The pieces of the normal equations of the pose rows and the priors of SUs `spec.sus[i]`,
    /// `i` in `group`, each SU's as one block.
    fn pose_parts(&self, group: &[usize]) -> Vec<SuPart> {
        group
            .iter()
            .map(|&i| {
                let mut part = SuPart::zeros(self.map.own[i].len(), self.map.shared.len());
                self.block_with(i, false).add_to(&mut part);
                part
            })
            .collect()
    }

    /// Adds to `parts` the motion rows of `samples` of SUs `spec.sus[i]`, `i` in `group` (SUs of
    /// one segment), from `window`: the segment terms of samples `first..first + terms.len()`
    /// (one more on each side of `samples` where the record has it, for the delay's rate).
    /// [`MOTION_CHUNK`] samples at a time, every SU of the group in turn: the same sums as one
    /// block of all the SU's rows, without a block of a whole record's rows (a minute at 100 Hz
    /// is 18 000 rows per SU) written and read back through memory, and with the segment's terms
    /// at those samples read once for all its SUs.
    fn add_motion(
        &self,
        group: &[usize],
        parts: &mut [SuPart],
        window: (&[SegmentTerms], usize),
        samples: Range<usize>,
    ) {
        let motions: Vec<MotionRows> = group
            .iter()
            .filter_map(|&i| self.motion_rows(i, 0, window))
            .collect();
        let predicted: Vec<Vec<Vector3<f64>>> = motions
            .iter()
            .map(|rows| rows.predicted(self.state))
            .collect();
        let mut chunks: Vec<SuBlock> = group
            .iter()
            .map(|&i| self.zeros(i, 3 * MOTION_CHUNK))
            .collect();
        for lo in samples.clone().step_by(MOTION_CHUNK) {
            let range = lo..(lo + MOTION_CHUNK).min(samples.end);
            for (((rows, predicted), chunk), part) in motions
                .iter()
                .zip(&predicted)
                .zip(&mut chunks)
                .zip(parts.iter_mut())
            {
                chunk.clear();
                let SuBlock { r, own, shared, .. } = chunk;
                let (cost, count) = rows.fill(
                    self.state,
                    self.data,
                    (range.clone(), predicted),
                    r,
                    Some((own, shared)),
                );
                chunk.cost = cost;
                chunk.count = count;
                chunk.add_on_one_range_to(part);
            }
        }
    }

    /// Per SU (`spec.sus` index), the cost of its motion rows and how many count, a window of
    /// [`MOTION_WINDOW`] samples at a time (the segment terms of one window held at once, not of
    /// the whole record), window by window in the record's order.
    fn motion_costs(&self) -> Vec<(usize, (f64, usize))> {
        let Some(motion) = self.data.motion.as_deref() else {
            return Vec::new();
        };
        let mut out = Vec::new();
        for lo in (0..motion.len()).step_by(MOTION_WINDOW) {
            let hi = (lo + MOTION_WINDOW).min(motion.len());
            let terms = motion_terms(
                self.state,
                self.layout,
                self.spec,
                self.map,
                false,
                (motion, lo..hi),
            );
            let window: Vec<(usize, (f64, usize))> = (0..self.spec.sus.len())
                .into_par_iter()
                .filter_map(|i| {
                    let rows = self.motion_rows(i, 0, (&terms, lo))?;
                    let predicted = rows.predicted(self.state);
                    let mut r = DVector::zeros(3 * (hi - lo));
                    Some((
                        i,
                        rows.fill(self.state, self.data, (lo..hi, &predicted), &mut r, None),
                    ))
                })
                .collect();
            out.extend(window);
        }
        out
    }

    /// The free intrinsics of SU `spec.sus[i]` (and its position's components under a gauge
    /// prior), each with a prior row after the readings: (own column, block, component).
    fn prior_columns(&self, i: usize) -> Vec<(usize, Block, usize)> {
        self.map.own[i]
            .iter()
            .enumerate()
            .filter(|(_, &(b, c))| match self.spec.blocks[b] {
                Block::Intrinsics(_) => true,
                Block::Su(_) => self.data.gauge_prior.is_some() && c >= 3,
                _ => false,
            })
            .map(|(col, &(b, c))| (col, self.spec.blocks[b], c))
            .collect()
    }

    /// Pose `p`'s rows of SU `spec.sus[i]` (and their Jacobian when the blocks carry one): the
    /// static reading and the dynamic one of each DoF before it, whitened and weighed.
    fn pose_rows(&self, i: usize, p: usize, su: &SuFrame, block: &mut SuBlock) {
        let u = self.spec.sus[i];
        let s = self.layout.su_segment[u];
        let row = p * 3 * (1 + s);
        let (sigma, data) = (self.sigma, self.data);
        for (j, terms) in self.poses[p].iter().take(1 + s).enumerate() {
            let (measured, bias) = match j {
                0 => (&data.statics[p][u], true),
                _ => (&data.dynamics[p][u][j - 1], false),
            };
            let at = row + 3 * j;
            let predicted = su.reading(&su.field(terms, s - 1), bias);
            block
                .r
                .fixed_rows_mut::<3>(at)
                .copy_from(&((predicted - measured) / sigma));
            let scale = block.weigh(data, sigma, (p, u, j), at);
            if self.jacobian && scale != 0.0 {
                let rows = JacobianRows {
                    spec: self.spec,
                    map: self.map,
                    u,
                    i,
                    row: at,
                    scale: scale / sigma,
                };
                rows.fill(su, terms, s - 1, bias, &mut block.own, &mut block.shared);
            }
        }
    }

    /// The prior rows of SU `spec.sus[i]` from `at`: each free intrinsic over its prior's
    /// deviation, and its position's components under a gauge prior.
    fn prior_rows(
        &self,
        i: usize,
        priors: &[(usize, Block, usize)],
        at: usize,
        block: &mut SuBlock,
    ) {
        let u = self.spec.sus[i];
        let values = self.state.intrinsics[u].to_array();
        for (n, &(col, b, c)) in priors.iter().enumerate() {
            let (value, sd) = match b {
                Block::Su(v) => (
                    self.state.sus[v].translation.vector[c - 3],
                    self.data.gauge_prior.unwrap_or(f64::INFINITY),
                ),
                _ => (values[c], INTRINSIC_PRIOR_SD[c]),
            };
            let x = value / sd;
            block.r[at + n] = x;
            block.cost += x * x;
            block.count += 1;
            if self.jacobian {
                block.own[(at + n, col)] = 1.0 / sd;
            }
        }
    }
}

/// One SU's share of the normal equations: its own pieces, `J_sᵀJ_s`, `J_sᵀr`, `|r|²` and the
/// number of residuals that count.
struct SuPart {
    su: SuNormal,
    c: DMatrix<f64>,
    gs: DVector<f64>,
    cost: f64,
    count: usize,
}

impl SuPart {
    fn zeros(own: usize, shared: usize) -> Self {
        Self {
            su: SuNormal {
                a: DMatrix::zeros(own, own),
                b: DMatrix::zeros(own, shared),
                go: DVector::zeros(own),
            },
            c: DMatrix::zeros(shared, shared),
            gs: DVector::zeros(shared),
            cost: 0.0,
            count: 0,
        }
    }
}

/// The motion samples whose rows [`Blocks::add_motion`] fills and multiplies at a time.
const MOTION_CHUNK: usize = 64;

/// The motion samples whose segment terms [`normal_system`] holds at a time.
const MOTION_WINDOW: usize = 512;

/// The SUs of one segment whose motion rows [`Blocks::add_motion`] forms together at most.
const SU_GROUP: usize = 8;

/// One SU's pieces of the normal equations: `A = J_oᵀJ_o`, `B = J_oᵀJ_s`, `g_o = J_oᵀr`.
#[derive(Debug, Clone)]
struct SuNormal {
    a: DMatrix<f64>,
    b: DMatrix<f64>,
    go: DVector<f64>,
}

/// The normal equations of a problem at a state, SU blocks kept apart.
#[derive(Debug, Clone)]
pub(super) struct Normal {
    sus: Vec<SuNormal>,
    /// `Σ J_sᵀJ_s`.
    c: DMatrix<f64>,
    /// `Σ J_sᵀr`.
    gs: DVector<f64>,
    /// `|r|²`.
    pub cost: f64,
    /// Number of residuals.
    pub rows: usize,
}

pub(super) fn normal_system(
    state: &ChainState,
    layout: &Layout,
    data: &Readings,
    spec: &Spec,
    map: &ColumnMap,
    sigma: f64,
) -> Normal {
    let blocks = Blocks::new(state, layout, data, spec, map, sigma, true, false);
    let m = map.shared.len();
    // The SUs by segment (their motion rows read the same terms), in the SUs' order, at most
    // [`SU_GROUP`] together (a segment of many SUs still shares out among the threads).
    let mut by_segment: Vec<Vec<usize>> = Vec::new();
    let mut group_of = std::collections::HashMap::new();
    for (i, &u) in spec.sus.iter().enumerate() {
        let g = *group_of.entry(layout.su_segment[u]).or_insert_with(|| {
            by_segment.push(Vec::new());
            by_segment.len() - 1
        });
        by_segment[g].push(i);
    }
    let groups: Vec<&[usize]> = by_segment
        .iter()
        .flat_map(|sus| sus.chunks(SU_GROUP))
        .collect();
    let mut by_group: Vec<Vec<SuPart>> = groups.par_iter().map(|g| blocks.pose_parts(g)).collect();
    // A motion record's rows a window of samples at a time: the segment terms (with their rates,
    // kilobytes per sample) of one window held at once, not of the whole record.
    if let Some(motion) = data.motion.as_deref() {
        for lo in (0..motion.len()).step_by(MOTION_WINDOW) {
            let hi = (lo + MOTION_WINDOW).min(motion.len());
            let first = lo.saturating_sub(1);
            let reach = first..(hi + 1).min(motion.len());
            let terms = motion_terms(state, layout, spec, map, true, (motion, reach));
            groups
                .par_iter()
                .zip(by_group.par_iter_mut())
                .for_each(|(g, parts)| blocks.add_motion(g, parts, (&terms, first), lo..hi));
        }
    }
    let mut parts: Vec<(usize, SuPart)> = groups
        .iter()
        .zip(by_group)
        .flat_map(|(g, parts)| g.iter().copied().zip(parts))
        .collect();
    parts.sort_by_key(|(i, _)| *i);
    let mut c = DMatrix::zeros(m, m);
    let mut gs = DVector::zeros(m);
    let (mut cost, mut rows) = (0.0, 0);
    for (columns, jacobian, r) in joint_priors(state, data, spec, map) {
        for (i, &ci) in columns.iter().enumerate() {
            gs[ci] += jacobian.column(i).dot(&r);
            for (j, &cj) in columns.iter().enumerate() {
                c[(ci, cj)] += jacobian.column(i).dot(&jacobian.column(j));
            }
        }
        cost += r.norm_squared();
        rows += 3;
    }
    let mut sus = Vec::with_capacity(parts.len());
    for (_, part) in parts {
        c += part.c;
        gs += part.gs;
        cost += part.cost;
        rows += part.count;
        sus.push(part.su);
    }
    Normal {
        sus,
        c,
        gs,
        cost,
        rows,
    }
}

impl Normal {
    /// The normal equations of the problem with fewer columns of the SUs' own: `self`, formed
    /// with the columns of `from`, kept to those of `to` (whose shared columns are `from`'s, and
    /// whose SUs' own columns are among `from`'s). Each entry is a sum over the rows of two
    /// columns' products, so it is what [`normal_system`] forms with `to`'s columns.
    pub(super) fn restricted(&self, from: &ColumnMap, to: &ColumnMap) -> Normal {
        let sus = self
            .sus
            .iter()
            .zip(from.own.iter().zip(&to.own))
            .map(|(su, (all, kept))| {
                let at: Vec<usize> = kept
                    .iter()
                    .filter_map(|column| all.iter().position(|c| c == column))
                    .collect();
                SuNormal {
                    a: su.a.select_rows(&at).select_columns(&at),
                    b: su.b.select_rows(&at),
                    go: su.go.select_rows(&at),
                }
            })
            .collect();
        Normal {
            sus,
            c: self.c.clone(),
            gs: self.gs.clone(),
            cost: self.cost,
            rows: self.rows,
        }
    }

    /// Adds `information` (in the shared columns' order) to the shared block: what other
    /// readings tell of the shared parameters.
    pub(super) fn add_shared_information(&mut self, information: &DMatrix<f64>) {
        self.c += information;
    }

    /// The information of the shared columns with every SU's own columns eliminated (each SU
    /// block by its pseudo-inverse, as [`eliminate`] does): `C − Σ Bᵀ A⁺ B`.
    pub(super) fn shared_information(&self) -> DMatrix<f64> {
        let floor = self.largest_diagonal() * 1e-12;
        let mut s = self.c.clone();
        for su in &self.sus {
            let (inv, _) = pseudo_inverse(&su.a, floor);
            s -= su.b.transpose() * &inv * &su.b;
        }
        s
    }

    /// The largest diagonal entry of the whole normal matrix.
    fn largest_diagonal(&self) -> f64 {
        self.sus
            .iter()
            .flat_map(|s| s.a.diagonal().iter().copied().collect::<Vec<_>>())
            .chain(self.c.diagonal().iter().copied())
            .fold(0.0f64, f64::max)
            .max(1e-300)
    }
}

/// The dense information matrix `JᵀJ` (columns in `spec.columns()` order) of a normal system.
pub(super) fn information(normal: &Normal, map: &ColumnMap) -> DMatrix<f64> {
    let n = map.slots.len();
    let mut f = DMatrix::zeros(n, n);
    for (i, si) in map.slots.iter().enumerate() {
        for (j, sj) in map.slots.iter().enumerate() {
            f[(i, j)] = match (*si, *sj) {
                (Slot::Shared(a), Slot::Shared(b)) => normal.c[(a, b)],
                (Slot::Own(u, a), Slot::Own(v, b)) if u == v => normal.sus[u].a[(a, b)],
                (Slot::Own(u, a), Slot::Shared(b)) => normal.sus[u].b[(a, b)],
                (Slot::Shared(a), Slot::Own(v, b)) => normal.sus[v].b[(b, a)],
                (Slot::Own(..), Slot::Own(..)) => 0.0,
            };
        }
    }
    f
}

/// The gradient `Jᵀr` (columns in `spec.columns()` order) of a normal system.
pub(super) fn gradient(normal: &Normal, map: &ColumnMap) -> DVector<f64> {
    DVector::from_iterator(
        map.slots.len(),
        map.slots.iter().map(|slot| match *slot {
            Slot::Shared(a) => normal.gs[a],
            Slot::Own(u, a) => normal.sus[u].go[a],
        }),
    )
}

/// `|r|²` at a state.
pub(super) fn cost_of(
    state: &ChainState,
    layout: &Layout,
    data: &Readings,
    spec: &Spec,
    map: &ColumnMap,
    sigma: f64,
) -> f64 {
    cost_and_rows(state, layout, data, spec, map, sigma).0
}

/// `|r|²` at a state and the number of residuals that count (as [`normal_system`] counts them).
pub(super) fn cost_and_rows(
    state: &ChainState,
    layout: &Layout,
    data: &Readings,
    spec: &Spec,
    map: &ColumnMap,
    sigma: f64,
) -> (f64, usize) {
    let blocks = Blocks::new(state, layout, data, spec, map, sigma, false, false);
    let priors = joint_priors(state, data, spec, map);
    let prior_cost: f64 = priors.iter().map(|(_, _, r)| r.norm_squared()).sum();
    // Summed in SU order: a parallel sum adds in the order its threads happened to split the
    // work, and a step the fit takes or refuses on a last bit of the cost would vary run to run.
    let mut costs: Vec<(f64, usize)> = (0..spec.sus.len())
        .into_par_iter()
        .map(|i| {
            let block = blocks.block(i);
            (block.cost, block.count)
        })
        .collect();
    for (i, (cost, count)) in blocks.motion_costs() {
        costs[i].0 += cost;
        costs[i].1 += count;
    }
    (
        prior_cost + costs.iter().map(|c| c.0).sum::<f64>(),
        3 * priors.len() + costs.iter().map(|c| c.1).sum::<usize>(),
    )
}

/// The prior rows of every free joint's position on its parent ([`Readings::gauge_prior`], for
/// the same reason as an SU's): per joint, its shared columns, their 3×n Jacobian and the residual
/// `t / sd`. A joint after axes that are all parallel can slide along them unseen; held near its
/// parent, it does not drift hundreds of metres away.
fn joint_priors(
    state: &ChainState,
    data: &Readings,
    spec: &Spec,
    map: &ColumnMap,
) -> Vec<(Vec<usize>, nalgebra::Matrix3xX<f64>, Vector3<f64>)> {
    let mut out = Vec::new();
    let Some(sd) = data.gauge_prior else {
        return out;
    };
    for (b, block) in spec.blocks.iter().enumerate() {
        let (k, first) = match *block {
            Block::Joint(k) => (k, 2),
            Block::JointFull(k) => (k, 3),
            _ => continue,
        };
        let joint = &state.joints[k];
        let columns: Vec<(usize, usize)> = map
            .shared
            .iter()
            .enumerate()
            .filter(|(_, &(bb, c))| bb == b && c >= first)
            .map(|(col, &(_, c))| (col, c - first))
            .collect();
        if columns.is_empty() {
            continue;
        }
        let axes = joint.rotation.to_rotation_matrix().into_inner();
        let jacobian = nalgebra::Matrix3xX::from_columns(
            &columns
                .iter()
                .map(|&(_, axis)| axes.column(axis) / sd)
                .collect::<Vec<_>>(),
        );
        out.push((
            columns.iter().map(|&(col, _)| col).collect(),
            jacobian,
            joint.translation.vector / sd,
        ));
    }
    out
}

/// The whitened residual norm of every reading at a state (`[p][u][0]` static, `[1 + d]` the
/// dynamic one of DoF `d`; SUs outside `spec.sus` empty), plain least squares, nothing left out.
pub(super) fn reading_norms(
    state: &ChainState,
    layout: &Layout,
    data: &Readings,
    spec: &Spec,
    sigma: f64,
) -> Vec<Vec<Vec<f64>>> {
    let plain = Readings {
        huber: None,
        rejected: Vec::new(),
        ..data.clone()
    };
    let map = ColumnMap::new(spec);
    // The readings' rows alone: a motion record's rows are not readings, and every SU's block of
    // them held at once would grow with the record (30 MB for two minutes of 100 SUs).
    let inputs = Blocks::new(state, layout, &plain, spec, &map, sigma, false, false);
    let blocks: Vec<(usize, SuBlock)> = (0..spec.sus.len())
        .into_par_iter()
        .map(|i| (spec.sus[i], inputs.block_with(i, false)))
        .collect();
    let mut out = vec![vec![Vec::new(); layout.su_segment.len()]; data.q.len()];
    for (u, block) in blocks {
        let per_pose = 1 + layout.su_segment[u];
        for (p, pose) in out.iter_mut().enumerate() {
            pose[u] = (0..per_pose)
                .map(|j| block.r.fixed_rows::<3>(3 * (p * per_pose + j)).norm())
                .collect();
        }
    }
    out
}

/// Per SU (layout index; zero outside `spec.sus`): the sum of squares of its whitened motion
/// rows, plain least squares, and how many count.
pub(super) fn motion_sums(
    state: &ChainState,
    layout: &Layout,
    data: &Readings,
    spec: &Spec,
    sigma: f64,
) -> Vec<(f64, usize)> {
    let mut out = vec![(0.0, 0); layout.su_segment.len()];
    let Some(motion) = &data.motion else {
        return out;
    };
    if motion.is_empty() {
        return out;
    }
    let plain = Readings {
        huber: None,
        ..data.clone()
    };
    let map = ColumnMap::new(spec);
    let inputs = Blocks::new(state, layout, &plain, spec, &map, sigma, false, false);
    for (i, (cost, count)) in inputs.motion_costs() {
        let sum = &mut out[spec.sus[i]];
        sum.0 += cost;
        sum.1 += count;
    }
    out
}

/// Residuals and the dense Jacobian (columns in `spec.columns()` order; rows SU by SU, then the
/// joints' priors).
pub(super) fn dense_problem(
    state: &ChainState,
    layout: &Layout,
    data: &Readings,
    spec: &Spec,
    sigma: f64,
) -> (DVector<f64>, DMatrix<f64>) {
    dense_rows(state, layout, data, spec, sigma, (true, false))
}

/// The rows of the poses' readings alone in [`dense_problem`]'s Jacobian (no motion rows, no
/// prior rows): SU by SU (`spec.sus` order), pose by pose, the static reading and then the
/// dynamic one of each DoF before the SU, 3 rows each.
pub(super) fn pose_jacobian(
    state: &ChainState,
    layout: &Layout,
    data: &Readings,
    spec: &Spec,
    sigma: f64,
) -> DMatrix<f64> {
    dense_rows(state, layout, data, spec, sigma, (true, true)).1
}

/// The residuals of [`dense_problem`] alone (no Jacobian is formed).
pub(super) fn dense_residuals(
    state: &ChainState,
    layout: &Layout,
    data: &Readings,
    spec: &Spec,
    sigma: f64,
) -> DVector<f64> {
    dense_rows(state, layout, data, spec, sigma, (false, false)).0
}

/// [`dense_problem`], its Jacobian formed when `jacobian` (else it has no columns); with
/// `poses_only`, each SU's pose rows alone and no prior rows ([`pose_jacobian`]).
fn dense_rows(
    state: &ChainState,
    layout: &Layout,
    data: &Readings,
    spec: &Spec,
    sigma: f64,
    (jacobian, poses_only): (bool, bool),
) -> (DVector<f64>, DMatrix<f64>) {
    let map = ColumnMap::new(spec);
    let inputs = Blocks::new(state, layout, data, spec, &map, sigma, jacobian, true);
    let blocks: Vec<SuBlock> = (0..spec.sus.len()).map(|i| inputs.block(i)).collect();
    let kept = |i: usize, block: &SuBlock| match poses_only {
        true => 3 * (1 + layout.su_segment[spec.sus[i]]) * data.q.len(),
        false => block.r.len(),
    };
    let priors = match poses_only {
        true => Vec::new(),
        false => joint_priors(state, data, spec, &map),
    };
    let rows: usize = blocks
        .iter()
        .enumerate()
        .map(|(i, b)| kept(i, b))
        .sum::<usize>()
        + 3 * priors.len();
    let mut r = DVector::zeros(rows);
    let mut jac = DMatrix::zeros(rows, if jacobian { map.slots.len() } else { 0 });
    let mut row = 0;
    for (i, block) in blocks.iter().enumerate() {
        let n = kept(i, block);
        r.rows_mut(row, n).copy_from(&block.r.rows(0, n));
        if !jacobian {
            row += n;
            continue;
        }
        for (col, slot) in map.slots.iter().enumerate() {
            match *slot {
                Slot::Shared(j) => jac
                    .view_mut((row, col), (n, 1))
                    .copy_from(&block.shared.view((0, j), (n, 1))),
                Slot::Own(owner, l) if owner == i => jac
                    .view_mut((row, col), (n, 1))
                    .copy_from(&block.own.view((0, l), (n, 1))),
                Slot::Own(..) => {}
            }
        }
        row += n;
    }
    let shared_at: Vec<usize> = map
        .slots
        .iter()
        .enumerate()
        .filter(|(_, slot)| matches!(slot, Slot::Shared(_)))
        .map(|(col, _)| col)
        .collect();
    for (columns, prior_jacobian, residual) in priors {
        r.fixed_rows_mut::<3>(row).copy_from(&residual);
        if jacobian {
            for (k, &c) in columns.iter().enumerate() {
                jac.fixed_view_mut::<3, 1>(row, shared_at[c])
                    .copy_from(&prior_jacobian.column(k));
            }
        }
        row += 3;
    }
    (r, jac)
}

/// The damped Gauss–Newton step `(JᵀJ + λ·diag(JᵀJ))·δ = −Jᵀr` of problems that share parameters,
/// with every problem's SU blocks eliminated: `parts[i]` is a problem's normal system, its
/// columns, and where each of its shared columns sits among the `shared` columns of all (the
/// shared systems are summed there). Returns each problem's step in its columns' order and the
/// decrease of the cost (`|r|²`) the linearised problem predicts for it, `−δᵀJᵀr + λ·δᵀdiag·δ`;
/// `None` when a factorisation fails (the caller raises λ).
fn schur_step(
    parts: &[(&Normal, &ColumnMap, &[usize])],
    shared: usize,
    lambda: f64,
) -> Option<(Vec<Vec<f64>>, f64)> {
    let mut s = DMatrix::<f64>::zeros(shared, shared);
    let mut rhs = DVector::zeros(shared);
    for (normal, _, at) in parts {
        for (i, &gi) in at.iter().enumerate() {
            rhs[gi] -= normal.gs[i];
            for (j, &gj) in at.iter().enumerate() {
                s[(gi, gj)] += normal.c[(i, j)];
            }
        }
    }
    let gradient = -rhs.clone();
    let diagonal: Vec<f64> = (0..shared).map(|j| s[(j, j)].max(1e-24)).collect();
    for (j, d) in diagonal.iter().enumerate() {
        s[(j, j)] += lambda * d;
    }
    let mut reduced = Vec::with_capacity(parts.len());
    for (normal, _, at) in parts {
        let mut own = Vec::with_capacity(normal.sus.len());
        for su in &normal.sus {
            let k = su.a.nrows();
            if k == 0 {
                own.push(None);
                continue;
            }
            let mut a = su.a.clone();
            for l in 0..k {
                a[(l, l)] += lambda * su.a[(l, l)].max(1e-24);
            }
            let chol = a.cholesky()?;
            let w = chol.solve(&su.b);
            let wv = chol.solve(&su.go);
            let (sw, swv) = (su.b.tr_mul(&w), su.b.tr_mul(&wv));
            for (i, &gi) in at.iter().enumerate() {
                rhs[gi] += swv[i];
                for (j, &gj) in at.iter().enumerate() {
                    s[(gi, gj)] -= sw[(i, j)];
                }
            }
            own.push(Some((w, wv)));
        }
        reduced.push(own);
    }
    let ds = if shared > 0 {
        s.cholesky()?.solve(&rhs)
    } else {
        DVector::zeros(0)
    };
    // The predicted decrease, term by term: column `j` with gradient `g`, diagonal `d`, step `x`.
    let decrease = |g: f64, d: f64, x: f64| -g * x + lambda * d * x * x;
    let mut predicted: f64 = (0..shared)
        .map(|j| decrease(gradient[j], diagonal[j], ds[j]))
        .sum();
    let steps = parts
        .iter()
        .zip(reduced)
        .map(|((normal, map, at), own)| {
            let local = DVector::from_iterator(at.len(), at.iter().map(|&g| ds[g]));
            let own: Vec<Option<DVector<f64>>> = own
                .into_iter()
                .zip(&normal.sus)
                .map(|(part, su)| {
                    let step = part.map(|(w, wv)| -(wv + w * &local))?;
                    predicted += (0..step.len())
                        .map(|l| decrease(su.go[l], su.a[(l, l)].max(1e-24), step[l]))
                        .sum::<f64>();
                    Some(step)
                })
                .collect();
            map.slots
                .iter()
                .map(|slot| match *slot {
                    Slot::Shared(j) => local[j],
                    Slot::Own(i, l) => own[i].as_ref().map_or(0.0, |d| d[l]),
                })
                .collect()
        })
        .collect();
    Some((steps, predicted))
}

/// Applies a step of the free columns to the state (the retraction).
pub(super) fn retract(state: &ChainState, spec: &Spec, delta: &[f64]) -> ChainState {
    retract_columns(state, spec, &spec.columns(), delta)
}

/// [`retract`] with the spec's free columns computed once by the caller.
pub(super) fn retract_columns(
    state: &ChainState,
    spec: &Spec,
    columns: &[(usize, usize)],
    delta: &[f64],
) -> ChainState {
    let mut full: Vec<[f64; 9]> = vec![[0.0; 9]; spec.blocks.len()];
    for (&(b, c), &x) in columns.iter().zip(delta) {
        full[b][c] = x;
    }
    let mut next = state.clone();
    for (b, block) in spec.blocks.iter().enumerate() {
        let x = full[b];
        match *block {
            Block::Gravity => next.gravity += Vector3::new(x[0], x[1], x[2]),
            Block::OtherGravity(o) => next.other_gravities[o - 1] += Vector3::new(x[0], x[1], x[2]),
            Block::GravityDirection => next.gravity = turn_gravity(&state.gravity, x[0], x[1]),
            Block::Intrinsics(u) => next.intrinsics[u] = state.intrinsics[u].moved(&x),
            Block::SkinDelay => {
                next.skin_delay = (state.skin_delay + x[0]).clamp(-MAX_DELAY, MAX_DELAY)
            }
            Block::Joint(k) => {
                let local = Isometry3::from_parts(
                    Translation3::new(x[2], x[3], 0.0),
                    UnitQuaternion::from_scaled_axis(Vector3::new(x[0], x[1], 0.0)),
                );
                next.joints[k] = state.joints[k] * local;
            }
            Block::JointFull(k) => {
                let local = Isometry3::from_parts(
                    Translation3::new(x[3], x[4], x[5]),
                    UnitQuaternion::from_scaled_axis(Vector3::new(x[0], x[1], x[2])),
                );
                next.joints[k] = state.joints[k] * local;
            }
            Block::Su(u) => {
                let s = &state.sus[u];
                next.sus[u] = Isometry3::from_parts(
                    Translation3::from(s.translation.vector + Vector3::new(x[3], x[4], x[5])),
                    UnitQuaternion::from_scaled_axis(Vector3::new(x[0], x[1], x[2])) * s.rotation,
                );
            }
        }
    }
    next
}

/// Outcome of one LM solve.
#[derive(Debug, Clone)]
pub(super) struct Solved {
    pub state: ChainState,
    pub cost: f64,
    pub iterations: usize,
    /// The damping after its last step taken: where a solve of a nearby problem from this
    /// state may start ([`solve_near`]).
    pub damping: f64,
    /// Where the solve stood when it reached its cap of iterations (`None` when it stopped
    /// before): [`resume`] goes on from there as if it had not stopped.
    pub capped: Option<Lm>,
}

/// Where Levenberg–Marquardt stands between iterations: the cost at its state, its damping and
/// the iterations taken.
#[derive(Debug, Clone, Copy)]
pub(super) struct Lm {
    cost: f64,
    lambda: f64,
    /// The damping after the last step taken (`lambda` is higher after steps refused).
    settled: f64,
    iterations: usize,
}

/// Levenberg–Marquardt with Marquardt scaling from `state`: stops when an accepted step lowers the
/// cost by less than `tolerance` (relative), or after `max_iterations`.
pub(super) fn solve(
    state: ChainState,
    layout: &Layout,
    data: &Readings,
    spec: &Spec,
    sigma: f64,
    max_iterations: usize,
    tolerance: f64,
) -> Solved {
    let criteria = (sigma, tolerance);
    solve_near(
        state,
        layout,
        data,
        spec,
        criteria,
        max_iterations,
        INITIAL_DAMPING,
    )
}

/// [`solve`] from the damping `damping` instead of [`INITIAL_DAMPING`]: for a state at the
/// minimum of a nearby problem (the same readings with more intrinsics, or weighed otherwise),
/// with the damping that solve ended with. From the initial damping, the directions the new
/// columns make weak (a bias against its SU's turn) would move only as the damping decays, a
/// third per iteration: on a motion record, the bias rung of the intrinsics' ladder took 11
/// iterations for what 3 do.
pub(super) fn solve_near(
    state: ChainState,
    layout: &Layout,
    data: &Readings,
    spec: &Spec,
    (sigma, tolerance): (f64, f64),
    max_iterations: usize,
    damping: f64,
) -> Solved {
    let member = Member::whole(state, layout, data, spec);
    solve_single(
        member,
        (sigma, tolerance),
        max_iterations,
        Start::Damped(damping),
    )
}

/// The damping of Levenberg–Marquardt's first step from a state that is not at a minimum
/// (relative to the normal matrix's diagonal).
pub(super) const INITIAL_DAMPING: f64 = 1e-3;

/// Where a solve starts: afresh with a damping, or where an earlier run on the same problem
/// stood.
#[derive(Debug, Clone, Copy)]
enum Start {
    Damped(f64),
    Resumed(Lm),
}

/// `solved` (from [`solve`] on the same problem) carried on to `max_iterations` in all, exactly
/// as one solve to that cap would have gone.
pub(super) fn resume(
    solved: Solved,
    layout: &Layout,
    data: &Readings,
    spec: &Spec,
    sigma: f64,
    max_iterations: usize,
    tolerance: f64,
) -> Solved {
    let Some(lm) = solved.capped else {
        return solved;
    };
    let member = Member::whole(solved.state, layout, data, spec);
    solve_single(
        member,
        (sigma, tolerance),
        max_iterations,
        Start::Resumed(lm),
    )
}

/// One problem solved from `start` ([`solve_members`]) under `(sigma, tolerance)`.
fn solve_single(
    member: Member,
    criteria: (f64, f64),
    max_iterations: usize,
    start: Start,
) -> Solved {
    let shared = member.shared.len();
    let (mut states, lm, stopped) =
        solve_members(vec![member], shared, criteria, max_iterations, start);
    Solved {
        state: states.remove(0),
        cost: lm.cost,
        iterations: lm.iterations,
        damping: lm.settled,
        capped: (!stopped).then_some(lm),
    }
}

/// One of several problems solved together: its state and problem, and where each of its shared
/// columns sits among the columns the problems share (problems that share a parameter give it
/// the same place there and hold the same value of it).
pub(super) struct Member<'a> {
    pub state: ChainState,
    pub layout: &'a Layout,
    pub data: &'a Readings,
    pub spec: &'a Spec,
    pub shared: Vec<usize>,
}

impl<'a> Member<'a> {
    /// A problem solved alone at `state`: every shared column its own.
    fn whole(state: ChainState, layout: &'a Layout, data: &'a Readings, spec: &'a Spec) -> Self {
        Self {
            state,
            layout,
            data,
            spec,
            shared: (0..ColumnMap::new(spec).shared.len()).collect(),
        }
    }
}

/// Levenberg–Marquardt on the sum of the members' costs, their SU blocks eliminated and their
/// shared columns solved as one system of `shared` columns ([`solve`] for one problem). Returns
/// the members' states, the cost and the iterations.
pub(super) fn solve_together(
    members: Vec<Member>,
    shared: usize,
    sigma: f64,
    max_iterations: usize,
    tolerance: f64,
) -> (Vec<ChainState>, f64, usize) {
    let start = Start::Damped(INITIAL_DAMPING);
    let (states, lm, _) = solve_members(members, shared, (sigma, tolerance), max_iterations, start);
    (states, lm.cost, lm.iterations)
}

/// [`solve_together`] from `start`; also whether it stopped before its cap.
fn solve_members(
    mut members: Vec<Member>,
    shared: usize,
    (sigma, tolerance): (f64, f64),
    max_iterations: usize,
    start: Start,
) -> (Vec<ChainState>, Lm, bool) {
    let maps: Vec<ColumnMap> = members.iter().map(|m| ColumnMap::new(m.spec)).collect();
    let columns: Vec<Vec<(usize, usize)>> = members.iter().map(|m| m.spec.columns()).collect();
    let normals = |members: &[Member]| -> Vec<Normal> {
        members
            .iter()
            .zip(&maps)
            .map(|(m, map)| normal_system(&m.state, m.layout, m.data, m.spec, map, sigma))
            .collect()
    };
    let mut normal = normals(&members);
    let Lm {
        mut cost,
        mut lambda,
        mut settled,
        mut iterations,
    } = match start {
        Start::Resumed(lm) => lm,
        Start::Damped(lambda) => Lm {
            cost: normal.iter().map(|n| n.cost).sum(),
            lambda,
            settled: lambda,
            iterations: 0,
        },
    };
    let mut stopped = false;
    while iterations < max_iterations {
        iterations += 1;
        let (mut improved, mut refused) = (false, false);
        for _ in 0..40 {
            let problems = (members.as_slice(), maps.as_slice(), columns.as_slice());
            // After a step refused, the least decrease that counts as one (relative and
            // absolute): where the linearised problem predicts less, no shorter step would
            // count either. (Not before: a robust cost falls more than its linearisation, the
            // weights following the residuals.)
            let wanted = if refused {
                (tolerance * cost).max(MIN_DECREASE)
            } else {
                f64::NEG_INFINITY
            };
            let (trials, trial_cost, step_norm, predicted) =
                match damped_step(problems, &normal, shared, (sigma, lambda), wanted) {
                    Trial::Taken(trials, trial_cost, step_norm, predicted) => {
                        (trials, trial_cost, step_norm, predicted)
                    }
                    Trial::Singular => {
                        lambda *= 10.0;
                        continue;
                    }
                    Trial::Negligible => break,
                };
            if trial_cost < cost {
                let decrease = cost - trial_cost;
                let relative = decrease / cost.max(1e-300);
                for (m, t) in members.iter_mut().zip(trials) {
                    m.state = t;
                }
                cost = trial_cost;
                lambda = (lambda / 3.0).max(1e-12);
                settled = lambda;
                // A step that lowered the cost, and was predicted to, by less than
                // `CONVERGED_DECREASE` was the last that moved anything measurably.
                let settled_step = predicted.max(decrease) < CONVERGED_DECREASE;
                improved = relative > tolerance
                    && decrease > MIN_DECREASE
                    && step_norm > 1e-10
                    && !settled_step;
                break;
            }
            refused = true;
            lambda *= 4.0;
            if lambda > 1e12 {
                break;
            }
        }
        if !improved {
            stopped = true;
            break;
        }
        if iterations < max_iterations {
            normal = normals(&members);
        }
    }
    let lm = Lm {
        cost,
        lambda,
        settled,
        iterations,
    };
    (members.into_iter().map(|m| m.state).collect(), lm, stopped)
}

/// The least decrease of the cost (`|r|²`, whitened) that an LM step counts as progress.
const MIN_DECREASE: f64 = 1e-6;
/// The decrease of the cost below which a step, taken and predicted alike, ends a solve: a
/// Gauss–Newton step lowers the whitened cost by its own length squared in the estimate's
/// standard deviations, so it moved no combination of the parameters by more than a tenth of
/// that combination's standard deviation, and what a further step would move is smaller again.
const CONVERGED_DECREASE: f64 = 1e-2;

/// Problems solved together: the members, their column maps and the columns of their specs.
type Problems<'a, 'b> = (&'a [Member<'b>], &'a [ColumnMap], &'a [Vec<(usize, usize)>]);

/// A step damped by λ, tried.
enum Trial {
    /// The damped system is not positive definite.
    Singular,
    /// The linearised problem predicts a smaller decrease than the solve's stop asks for: no
    /// step from here would count, whatever λ (a larger one shortens it).
    Negligible,
    /// The members' states after the step, their cost, the step's norm and the decrease of
    /// the cost the linearised problem predicted.
    Taken(Vec<ChainState>, f64, f64, f64),
}

/// The step damped by `lambda` from the members' normal equations `normal`, tried where the
/// linearised problem predicts a decrease of the cost of at least `wanted`.
fn damped_step(
    (members, maps, columns): Problems,
    normal: &[Normal],
    shared: usize,
    (sigma, lambda): (f64, f64),
    wanted: f64,
) -> Trial {
    let parts: Vec<(&Normal, &ColumnMap, &[usize])> = normal
        .iter()
        .zip(maps)
        .zip(members)
        .map(|((n, map), m)| (n, map, m.shared.as_slice()))
        .collect();
    let Some((steps, predicted)) = schur_step(&parts, shared, lambda) else {
        return Trial::Singular;
    };
    if predicted < wanted {
        return Trial::Negligible;
    }
    let trials: Vec<ChainState> = members
        .iter()
        .zip(columns)
        .zip(&steps)
        .map(|((m, columns), step)| retract_columns(&m.state, m.spec, columns, step))
        .collect();
    let cost = trials
        .iter()
        .zip(members)
        .zip(maps)
        .map(|((t, m), map)| cost_of(t, m.layout, m.data, m.spec, map, sigma))
        .sum();
    let step_norm = steps.iter().flatten().map(|x| x * x).sum::<f64>().sqrt();
    Trial::Taken(trials, cost, step_norm, predicted)
}

/// Symmetric pseudo-inverse, eigen-pairs below `floor` dropped; also returns the eigen-pairs.
pub(super) fn pseudo_inverse(
    m: &DMatrix<f64>,
    floor: f64,
) -> (DMatrix<f64>, Vec<(f64, DVector<f64>)>) {
    let n = m.nrows();
    let mut inverse = DMatrix::zeros(n, n);
    let mut pairs = Vec::with_capacity(n);
    if n == 0 {
        return (inverse, pairs);
    }
    let eig = m.clone().symmetric_eigen();
    for (i, &e) in eig.eigenvalues.iter().enumerate() {
        let v = eig.eigenvectors.column(i).into_owned();
        if e > floor {
            inverse += &v * v.transpose() / e;
        }
        pairs.push((e, v));
    }
    (inverse, pairs)
}

/// The normal system's pseudo-inverse by the Schur complement, in parts: symmetric
/// eigen-decompositions of the small SU blocks and of the reduced shared system. Directions with
/// no information at all (a gauge the data leave free: eigenvalue below 1e-12 of the largest
/// diagonal entry) get no variance and are returned as unit vectors over the columns (`free`);
/// directions the data determine only to worse than `limit` (m or rad) are named by the parameters
/// that make them up (`unobservable`).
pub(super) struct Eliminated {
    n: usize,
    own_index: Vec<Vec<usize>>,
    shared_index: Vec<usize>,
    a_inverse: Vec<DMatrix<f64>>,
    k: Vec<DMatrix<f64>>,
    s_inverse: DMatrix<f64>,
    pub unobservable: Vec<Unobservable>,
    pub free: Vec<DVector<f64>>,
}

pub(super) fn eliminate(
    normal: &Normal,
    map: &ColumnMap,
    names: &[String],
    limit: f64,
) -> Eliminated {
    let n = map.slots.len();
    let largest = normal.largest_diagonal();
    let mut found = Directions {
        names,
        n,
        largest,
        floor: largest * 1e-12,
        weak: 1.0 / (limit * limit),
        unobservable: Vec::new(),
        free: Vec::new(),
    };
    let mut own_index: Vec<Vec<usize>> = vec![Vec::new(); normal.sus.len()];
    let mut shared_index = Vec::new();
    for (col, slot) in map.slots.iter().enumerate() {
        match *slot {
            Slot::Shared(_) => shared_index.push(col),
            Slot::Own(i, _) => own_index[i].push(col),
        }
    }
    let mut a_inverse = Vec::with_capacity(normal.sus.len());
    let mut s = normal.c.clone();
    for (i, su) in normal.sus.iter().enumerate() {
        let (inv, pairs) = pseudo_inverse(&su.a, found.floor);
        for (e, v) in pairs {
            let weights: Vec<(usize, f64)> = own_index[i]
                .iter()
                .copied()
                .zip(v.iter().copied())
                .collect();
            found.direction(e, &weights, false);
        }
        s -= su.b.transpose() * &inv * &su.b;
        a_inverse.push(inv);
    }
    let (s_inverse, pairs) = pseudo_inverse(&s, found.floor);
    let k: Vec<DMatrix<f64>> = normal
        .sus
        .iter()
        .zip(&a_inverse)
        .map(|(su, inv)| inv * &su.b)
        .collect();
    // A direction without information (free) or with less than `limit` allows (weak): with
    // `limit` infinite only the free ones, whose eigenvalue rounding leaves either side of 0.
    let (weak, floor) = (found.weak, found.floor);
    for (e, v) in pairs.into_iter().filter(|(e, _)| *e < weak || *e <= floor) {
        // The shared direction with every SU's own columns following it.
        let mut weights: Vec<(usize, f64)> = shared_index
            .iter()
            .copied()
            .zip(v.iter().copied())
            .collect();
        for (i, ki) in k.iter().enumerate() {
            let own = -(ki * &v);
            weights.extend(own_index[i].iter().copied().zip(own.iter().copied()));
        }
        found.direction(e, &weights, true);
    }
    Eliminated {
        n,
        own_index,
        shared_index,
        a_inverse,
        k,
        s_inverse,
        unobservable: found.unobservable,
        free: found.free,
    }
}

/// The directions an elimination finds: free (no information: eigenvalue at most `floor`) and
/// unobservable (less than `weak`).
struct Directions<'a> {
    names: &'a [String],
    /// Columns.
    n: usize,
    /// The largest diagonal entry of the normal matrix.
    largest: f64,
    floor: f64,
    weak: f64,
    unobservable: Vec<Unobservable>,
    free: Vec<DVector<f64>>,
}

impl Directions<'_> {
    /// An eigenpair `e` over the columns of `weights`, recorded as free and as unobservable
    /// where it is (`normalize` the free direction where the weights are not a unit vector).
    fn direction(&mut self, e: f64, weights: &[(usize, f64)], normalize: bool) {
        if e <= self.floor {
            let mut direction = DVector::zeros(self.n);
            for &(c, w) in weights {
                direction[c] = w;
            }
            self.free.push(if normalize {
                direction.normalize()
            } else {
                direction
            });
        }
        if e < self.weak {
            self.unobservable.push(Unobservable {
                singular_value: (e.max(0.0) / self.largest).sqrt(),
                parameters: self.named(weights),
            });
        }
    }

    /// The parameters that make up a direction: those with at least 0.3 of its norm, largest
    /// first.
    fn named(&self, weights: &[(usize, f64)]) -> Vec<String> {
        let norm = weights.iter().map(|(_, w)| w * w).sum::<f64>().sqrt();
        let mut parts: Vec<(f64, usize)> = weights
            .iter()
            .map(|&(c, w)| (w.abs() / norm.max(1e-300), c))
            .filter(|(w, _)| *w > 0.3)
            .collect();
        parts.sort_by(|a, b| b.0.total_cmp(&a.0));
        parts.iter().map(|&(_, c)| self.names[c].clone()).collect()
    }
}

/// Parameter covariance `scale²·(JᵀJ)⁺` (columns in `spec.columns()` order) from the normal
/// equations at the solution ([`eliminate`]), and the directions it names as unobservable.
pub(super) fn covariance(
    normal: &Normal,
    map: &ColumnMap,
    scale: f64,
    names: &[String],
    limit: f64,
) -> (DMatrix<f64>, Vec<Unobservable>) {
    let Eliminated {
        n,
        own_index,
        shared_index,
        a_inverse,
        k,
        s_inverse,
        unobservable,
        ..
    } = eliminate(normal, map, names, limit);
    let mut cov = DMatrix::zeros(n, n);
    let put = |cov: &mut DMatrix<f64>, rows: &[usize], cols: &[usize], block: &DMatrix<f64>| {
        for (a, &r) in rows.iter().enumerate() {
            for (b, &c) in cols.iter().enumerate() {
                cov[(r, c)] = block[(a, b)] * scale * scale;
            }
        }
    };
    put(&mut cov, &shared_index, &shared_index, &s_inverse);
    let ks: Vec<DMatrix<f64>> = k.iter().map(|ki| ki * &s_inverse).collect();
    for i in 0..normal.sus.len() {
        let cross = -&ks[i];
        put(&mut cov, &own_index[i], &shared_index, &cross);
        put(&mut cov, &shared_index, &own_index[i], &cross.transpose());
        for j in 0..normal.sus.len() {
            let mut block = &ks[i] * k[j].transpose();
            if i == j {
                block += &a_inverse[i];
            }
            put(&mut cov, &own_index[i], &own_index[j], &block);
        }
    }
    (cov, unobservable)
}

#[cfg(test)]
mod tests {
    use super::*;
    use rand::{Rng, SeedableRng};
    use rand_chacha::ChaCha8Rng;

    #[test]
    fn products_by_column_range_and_on_one_range_equal_the_dense_products() {
        // A block shaped like a chain's: each reading sees a range of the shared columns (a
        // staircase), some readings none, some rows rejected (zero), a few own columns.
        let mut rng = ChaCha8Rng::seed_from_u64(7);
        let (rows, shared, own) = (90, 24, 6);
        let mut block = SuBlock {
            r: DVector::from_fn(rows, |_, _| rng.random_range(-1.0..1.0)),
            own: DMatrix::from_fn(rows, own, |_, _| rng.random_range(-1.0..1.0)),
            shared: DMatrix::zeros(rows, shared),
            cost: 0.0,
            count: 0,
        };
        for reading in 0..rows / 3 {
            let lo = reading % 9 * 2;
            let hi = (lo + 1 + reading % 5 * 3).min(shared);
            for row in 3 * reading..3 * reading + 3 {
                if reading % 7 == 3 {
                    continue;
                }
                for c in lo..hi {
                    block.shared[(row, c)] = rng.random_range(-1.0..1.0);
                }
            }
        }
        let (own_t, shared_t) = (block.own.transpose(), block.shared.transpose());
        let close = |a: &DMatrix<f64>, b: &DMatrix<f64>| (a - b).amax() < 1e-12 * (1.0 + b.amax());
        let (m, n) = (block.shared.ncols(), block.own.ncols());
        let (mut grouped, mut one_range) = (SuPart::zeros(n, m), SuPart::zeros(n, m));
        block.add_to(&mut grouped);
        block.add_on_one_range_to(&mut one_range);
        for SuPart { su, c, gs, .. } in [grouped, one_range] {
            assert!(close(&c, &(&shared_t * &block.shared)));
            assert!(close(&su.b, &(&own_t * &block.shared)));
            assert!(close(&su.a, &(&own_t * &block.own)));
            assert!((&gs - &shared_t * &block.r).amax() < 1e-12);
            assert!((&su.go - &own_t * &block.r).amax() < 1e-12);
        }
    }

    /// Two SUs' random blocks of `rows` rows, `own` columns each and `shared` columns, from
    /// `seed`, and their normal system.
    fn random_system(seed: u64, rows: usize, shared: usize, own: usize) -> (Vec<SuBlock>, Normal) {
        let mut rng = ChaCha8Rng::seed_from_u64(seed);
        let mut random =
            |r: usize, c: usize| DMatrix::from_fn(r, c, |_, _| rng.random_range(-1.0..1.0));
        let blocks: Vec<SuBlock> = (0..2)
            .map(|_| SuBlock {
                r: random(rows, 1).column(0).into_owned(),
                own: random(rows, own),
                shared: random(rows, shared),
                cost: 0.0,
                count: 0,
            })
            .collect();
        let mut normal = Normal {
            sus: Vec::new(),
            c: DMatrix::zeros(shared, shared),
            gs: DVector::zeros(shared),
            cost: blocks.iter().map(|b| b.r.norm_squared()).sum(),
            rows: 2 * rows,
        };
        for block in &blocks {
            let mut part = SuPart::zeros(own, shared);
            block.add_to(&mut part);
            normal.c += &part.c;
            normal.gs += &part.gs;
            normal.sus.push(part.su);
        }
        (blocks, normal)
    }

    #[test]
    fn a_system_kept_to_fewer_own_columns_is_that_of_those_columns() {
        // Two SUs of 6 own columns and 4 shared ones; kept: SU 0's columns 0, 2 and 5 (as a
        // gauge holds some of an SU's pose), every column of SU 1.
        let (rows, shared, own) = (15, 4, 6);
        let (blocks, normal) = random_system(5, rows, shared, own);
        let map_of = |kept: [Vec<usize>; 2]| {
            let mut slots: Vec<Slot> = (0..shared).map(Slot::Shared).collect();
            slots.extend((0..2).flat_map(|i| (0..kept[i].len()).map(move |l| Slot::Own(i, l))));
            ColumnMap {
                slots,
                shared: (0..shared).map(|c| (0, c)).collect(),
                own: kept
                    .iter()
                    .enumerate()
                    .map(|(i, k)| k.iter().map(|&c| (1 + i, c)).collect())
                    .collect(),
            }
        };
        let kept = [vec![0, 2, 5], (0..own).collect()];
        let from = map_of([(0..own).collect(), (0..own).collect()]);
        let to = map_of(kept.clone());
        let restricted = normal.restricted(&from, &to);
        for (i, (block, su)) in blocks.iter().zip(&restricted.sus).enumerate() {
            let own_kept = block.own.select_columns(&kept[i]);
            let close = |a: &DMatrix<f64>, b: &DMatrix<f64>| (a - b).amax() < 1e-12;
            assert!(close(&su.a, &own_kept.tr_mul(&own_kept)), "SU {i}");
            assert!(close(&su.b, &own_kept.tr_mul(&block.shared)), "SU {i}");
            assert!(
                (&su.go - own_kept.tr_mul(&block.r)).amax() < 1e-12,
                "SU {i}"
            );
        }
        assert_eq!(restricted.c, normal.c);
        assert_eq!((restricted.cost, restricted.rows), (normal.cost, 2 * rows));
    }

    #[test]
    fn the_damped_step_solves_the_damped_normal_equations_and_predicts_a_linear_problems_decrease()
    {
        // A linear problem r(δ) = r + Jδ: two SUs of 3 own columns each and 4 shared columns,
        // one random block of rows per SU. The Schur step must be the dense damped step, and
        // its predicted decrease |r|² − |r + Jδ|² exactly.
        let (rows, shared, own) = (12, 4, 3);
        let (blocks, normal) = random_system(11, rows, shared, own);
        // Columns: the shared ones, then each SU's own.
        let mut slots: Vec<Slot> = (0..shared).map(Slot::Shared).collect();
        slots.extend((0..2).flat_map(|i| (0..own).map(move |l| Slot::Own(i, l))));
        let map = ColumnMap {
            slots,
            shared: (0..shared).map(|c| (0, c)).collect(),
            own: vec![(0..own).map(|c| (1, c)).collect(); 2],
        };
        // The dense Jacobian in the same column order, and the residual.
        let n = shared + 2 * own;
        let mut jacobian = DMatrix::zeros(2 * rows, n);
        let mut r = DVector::zeros(2 * rows);
        for (i, block) in blocks.iter().enumerate() {
            let at = i * rows;
            jacobian
                .view_mut((at, 0), (rows, shared))
                .copy_from(&block.shared);
            jacobian
                .view_mut((at, shared + i * own), (rows, own))
                .copy_from(&block.own);
            r.rows_mut(at, rows).copy_from(&block.r);
        }
        let at: Vec<usize> = (0..shared).collect();
        for lambda in [1e-6, 0.1, 10.0] {
            let (steps, predicted) =
                schur_step(&[(&normal, &map, at.as_slice())], shared, lambda).unwrap();
            let step = DVector::from_vec(steps[0].clone());
            let h = jacobian.tr_mul(&jacobian);
            let damped = &h + DMatrix::from_diagonal(&(h.diagonal() * lambda));
            let dense = damped.cholesky().unwrap().solve(&-jacobian.tr_mul(&r));
            assert!((&step - &dense).amax() < 1e-10 * dense.amax(), "λ {lambda}");
            let decrease = r.norm_squared() - (&r + &jacobian * &step).norm_squared();
            assert!(
                (predicted - decrease).abs() < 1e-10 * decrease.abs().max(1e-12),
                "λ {lambda}: predicted {predicted}, decrease {decrease}"
            );
        }
    }
}
