//! The time-domain rows of a limb's problem: what every SU read in every block of a motion record
//! (`crate::motion`) against the specific force its frame has under the measured joint motion —
//! gravity, tangential, centripetal and Coriolis terms of every DoF before it, several DoFs moving
//! at once — with the delay of the skin's clock behind the joint states' as a parameter.
//!
//! Each sample is one instant of the chain's motion: its segments' terms and their derivatives
//! come from the limb's one kinematics ([`super::terms`]), as the readings' do.

use nalgebra::{DMatrix, DVector, Isometry3, Vector3};
use rayon::prelude::*;
use skincal_scratch::Buffer;

use super::problem::{turns_of, Block};
use super::terms::{link, Chain, Instant, SegmentTerms};
use super::ChainState;
use crate::estimate::limb::LimbData;
use crate::estimate::EstimateError;
use crate::model::sensor::STANDARD_GRAVITY;
use crate::model::DofKind;
use crate::motion::{
    JointRows, MotionRecord, SkinFilter, SkinRows, BLOCK_NOISE_CORRELATION, QUIET_REACH,
};

/// The largest delay of the skin's clock behind the joint states' that is estimated, s (a driver's
/// latency; more is another clock, which ingest refuses).
pub const MAX_DELAY: f64 = 0.05;
/// A block whose DoF accelerations are less certain than this is not fitted, rad/s²: the joint
/// motion changed faster than the record's local polynomial follows (a jerk at a phase's start),
/// and its prediction would be wrong by that much times the lever arm. A DoF whose encoder
/// leaves every block less certain gets [`SUDDEN`] times its median instead.
pub const MAX_ACCELERATION_SD: f64 = 0.05;
/// How many times its median uncertainty makes a DoF's acceleration too uncertain to fit.
pub const SUDDEN: f64 = 3.0;
/// The least standard deviation of the prior that holds a joint's corrected acceleration at what
/// the record read ([`LimbMotion::correct_joint_states`]), rad/s².
pub const ACCELERATION_PRIOR: f64 = 0.005;
/// The samples [`LimbMotion::read_through_kernel`] reads the prediction through the kernel for
/// at a time.
const SPREAD_CHUNK: usize = 1024;

/// The blocks of the record that the limb's fit uses, in two [`Buffer`]s (past a few megabytes,
/// mapped scratch files: an hour of log in 10 ms blocks is 360 000 samples): each one's run and
/// block, and its position, velocity, acceleration and the acceleration's uncertainty of every
/// DoF, then what the record read of every DoF's position and acceleration before any correction
/// ([`LimbMotion::correct_joint_states`]). A DoF's motion, `Rz(q)` or `Tz(q)` for a prismatic
/// one, is computed where it is needed ([`MotionSample::turns`]).
#[derive(Debug, Clone, Default)]
pub(super) struct Samples {
    dofs: usize,
    at: Buffer<[u32; 2]>,
    values: Buffer<f64>,
}

impl PartialEq for Samples {
    fn eq(&self, other: &Self) -> bool {
        self.dofs == other.dofs
            && self.at[..] == other.at[..]
            && self.values[..] == other.values[..]
    }
}

impl Samples {
    /// Adds block `block` of run `run` with these joint states, as the record read them.
    fn push(&mut self, run: usize, block: usize, q: &[f64], qd: &[f64], qdd: &[f64], sd: &[f64]) {
        self.dofs = q.len();
        self.at.push([run as u32, block as u32]);
        for part in [q, qd, qdd, sd, q, qdd] {
            self.values.extend_from_slice(part);
        }
    }

    /// How many samples.
    pub(super) fn len(&self) -> usize {
        self.at.len()
    }

    /// Whether there is none.
    fn is_empty(&self) -> bool {
        self.at.is_empty()
    }

    /// Sample `i`.
    pub(super) fn get(&self, i: usize) -> MotionSample<'_> {
        let [run, block] = self.at[i];
        let width = PARTS * self.dofs;
        MotionSample {
            run,
            block,
            values: &self.values[i * width..(i + 1) * width],
        }
    }

    /// Every sample in order.
    fn iter(&self) -> impl Iterator<Item = MotionSample<'_>> + '_ {
        (0..self.len()).map(|i| self.get(i))
    }

    /// Samples `range`, on the thread pool.
    fn par_range(
        &self,
        range: std::ops::Range<usize>,
    ) -> impl IndexedParallelIterator<Item = MotionSample<'_>> + '_ {
        range.into_par_iter().map(|i| self.get(i))
    }

    /// Moves sample `i`'s position and acceleration of DoF `d` by these corrections.
    fn correct(&mut self, i: usize, d: usize, q: f64, qdd: f64) {
        let (n, start) = (self.dofs, i * PARTS * self.dofs);
        self.values[start + Part::Q as usize * n + d] += q;
        self.values[start + Part::Qdd as usize * n + d] += qdd;
    }

    /// The samples `i` that `keep` keeps, in their order.
    fn select(&self, keep: impl Fn(usize) -> bool) -> Samples {
        let mut out = Samples {
            dofs: self.dofs,
            ..Samples::default()
        };
        let width = PARTS * self.dofs;
        for i in (0..self.len()).filter(|&i| keep(i)) {
            out.at.push(self.at[i]);
            out.values
                .extend_from_slice(&self.values[i * width..(i + 1) * width]);
        }
        out
    }
}

/// One sample of [`Samples`]: its run and block and every DoF's values.
#[derive(Clone, Copy)]
pub(super) struct MotionSample<'a> {
    run: u32,
    block: u32,
    values: &'a [f64],
}

/// The parts of [`MotionSample::values`] in their order, each one entry per DoF.
#[derive(Clone, Copy)]
enum Part {
    Q,
    Qd,
    Qdd,
    QddSd,
    ReadQ,
    ReadQdd,
}

/// How many parts a sample holds.
const PARTS: usize = Part::ReadQdd as usize + 1;

impl<'a> MotionSample<'a> {
    fn dofs(&self) -> usize {
        self.values.len() / PARTS
    }

    fn part(&self, part: Part) -> &'a [f64] {
        let (n, k) = (self.dofs(), part as usize);
        &self.values[k * n..(k + 1) * n]
    }

    fn run(&self) -> usize {
        self.run as usize
    }

    fn block(&self) -> usize {
        self.block as usize
    }

    fn q(&self) -> &'a [f64] {
        self.part(Part::Q)
    }

    fn qd(&self) -> &'a [f64] {
        self.part(Part::Qd)
    }

    fn qdd(&self) -> &'a [f64] {
        self.part(Part::Qdd)
    }

    fn qdd_sd(&self) -> &'a [f64] {
        self.part(Part::QddSd)
    }

    /// What the record read of DoF `d`'s position and acceleration.
    fn read(&self, d: usize) -> (f64, f64) {
        (self.part(Part::ReadQ)[d], self.part(Part::ReadQdd)[d])
    }

    /// Every DoF's motion at the sample's positions.
    fn turns(&self, kinds: &[DofKind]) -> Vec<Isometry3<f64>> {
        super::problem::turns_of(self.q(), kinds)
    }

    /// What the motion of the first `dofs` DoFs could add to gravity at an SU they move, m/s²:
    /// [`QUIET_REACH`] times `Σ|q̈| + (Σ|q̇|)²` over them, as the record read them.
    fn reach(&self, dofs: usize) -> f64 {
        let spin: f64 = self.qd().iter().take(dofs).map(|v| v.abs()).sum();
        let turn: f64 = self
            .part(Part::ReadQdd)
            .iter()
            .take(dofs)
            .map(|a| a.abs())
            .sum();
        QUIET_REACH * (turn + spin * spin)
    }
}

/// An SU's skin interpolated between its blocks ([`LimbMotion::interpolated`]).
#[derive(Debug, Clone, Copy)]
pub(super) struct Interpolated {
    pub value: Vector3<f64>,
    /// The value's rate with the delay, per s.
    pub rate: Vector3<f64>,
    /// The variance of its noise over a block's: between blocks the interpolation averages
    /// their noise (to 0.64 midway between independent block means), so that a cost of the
    /// interpolated skin weighed as a block would fall wherever the delay puts the skin between
    /// blocks, whatever the motion.
    pub variance: f64,
    /// That variance's rate with the delay, per s.
    pub variance_rate: f64,
}

/// How many consecutive samples at one reading of a coarse encoder share one correction of
/// its position ([`LimbMotion::correct_joint_states`]).
const TIED: usize = 3;
/// The most such stretches corrected in one pass (the longest where a log has more): their
/// system is dense, 10⁹ operations at this size.
const MOST_TIED: usize = 1500;

/// One sample's normal equations in its corrections ([`LimbMotion::correct_joint_states`]):
/// positions of the DoFs corrected, then their accelerations.
struct Local {
    /// `JᵀJ` of the whitened readings.
    information: DMatrix<f64>,
    /// `Jᵀr`.
    gradient: DVector<f64>,
    /// The priors' information per correction (diagonal).
    prior: DVector<f64>,
    /// Where each correction stands from what the record read.
    held_at: DVector<f64>,
}

impl Local {
    /// The system with the priors of every correction but the positions `tied` (chain indices):
    /// those are held once per stretch instead.
    fn with_priors(&self, tied: &[usize]) -> (DMatrix<f64>, DVector<f64>) {
        let mut a = self.information.clone();
        let mut g = self.gradient.clone();
        for c in 0..g.len() {
            if !tied.contains(&c) {
                a[(c, c)] += self.prior[c];
                g[c] += self.prior[c] * self.held_at[c];
            }
        }
        (a, g)
    }

    /// The normal equations in the positions `tied` with every other correction eliminated.
    fn reduced(&self, tied: &[usize]) -> (DMatrix<f64>, DVector<f64>) {
        let (a, g) = self.with_priors(tied);
        let free: Vec<usize> = (0..g.len()).filter(|c| !tied.contains(c)).collect();
        let att = a.select_rows(tied).select_columns(tied);
        let atf = a.select_rows(tied).select_columns(&free);
        let aff = a.select_rows(&free).select_columns(&free);
        let (gt, gf) = (g.select_rows(tied), g.select_rows(&free));
        match aff.cholesky() {
            Some(c) => (
                &att - &atf * c.solve(&atf.transpose()),
                gt - &atf * c.solve(&gf),
            ),
            None => (att, gt),
        }
    }

    /// The Gauss–Newton step of every correction with the positions `fixed` (chain index, step)
    /// set, and how many of the residual's degrees of freedom the free ones took.
    fn solve(&self, fixed: &[(usize, f64)]) -> Option<(DVector<f64>, f64)> {
        let tied: Vec<usize> = fixed.iter().map(|f| f.0).collect();
        let (a, mut g) = self.with_priors(&tied);
        let free: Vec<usize> = (0..g.len()).filter(|c| !tied.contains(c)).collect();
        let mut step = DVector::zeros(g.len());
        for &(c, v) in fixed {
            step[c] = v;
            g += a.column(c) * v;
        }
        let aff = a.select_rows(&free).select_columns(&free);
        let cholesky = aff.cholesky()?;
        let solved = cholesky.solve(&(-g.select_rows(&free)));
        for (x, &c) in free.iter().enumerate() {
            step[c] = solved[x];
        }
        let data = self.information.select_rows(&free).select_columns(&free);
        Some((step, cholesky.solve(&data).trace()))
    }
}

/// The tied positions' corrections ([`LimbMotion::correct_joint_states`]) and how many of the
/// residual's degrees of freedom they took.
struct Tied {
    values: Vec<f64>,
    taken: f64,
}

/// How many counts a joint whose acceleration the fit takes as an unknown may cross within the
/// polynomial's span and still have its uncertainty left out of the noise
/// ([`LimbMotion::weigh_fitted`]): a joint that stands or creeps, whose error is its encoder's
/// staircase, which the correction takes; one that moves faster errs where the polynomial
/// cannot follow it, in its velocity and position too, which no correction takes.
const SLOW_COUNTS: f64 = 4.0;

/// What the joint accelerations' uncertainty adds to the variance of each SU's prediction at
/// each sample ([`LimbMotion::weigh`]), (m/s²)², in single precision, sample by sample as it is
/// computed: `values[i * sus + u]` (past a few megabytes in a mapped scratch file, as the
/// record's skin).
#[derive(Debug, Clone, Default)]
struct JointVariance {
    sus: usize,
    values: Buffer<f32>,
}

impl PartialEq for JointVariance {
    fn eq(&self, other: &Self) -> bool {
        self.sus == other.sus && self.values[..] == other.values[..]
    }
}

impl JointVariance {
    /// SU `u`'s at sample `i`; `None` before any weighing.
    fn get(&self, i: usize, u: usize) -> Option<f32> {
        (u < self.sus).then(|| self.values.get(i * self.sus + u).copied())?
    }

    /// Those of the samples `i` that `kept` keeps, in their order.
    fn of_samples(&self, kept: impl Fn(usize) -> bool) -> Self {
        let rows = self.values.chunks(self.sus.max(1)).enumerate();
        let values = rows.filter(|(i, _)| kept(*i)).flat_map(|(_, row)| row);
        Self {
            sus: self.sus,
            values: values.copied().collect(),
        }
    }
}

/// A limb's share of a motion record: its DoFs (chain order) and SUs.
#[derive(Debug, Clone, PartialEq)]
pub struct LimbMotion {
    period: f64,
    /// Per chain DoF: revolute or prismatic.
    kinds: Vec<DofKind>,
    /// Blocks between two samples the fit takes in a run.
    stride: usize,
    /// The kernel the skin was read through, where it was ([`SkinFilter`]).
    filter: Option<SkinFilter>,
    /// The correlation of the skin's noise between blocks 0 to 3 apart
    /// ([`BLOCK_NOISE_CORRELATION`] for the record's block means): what
    /// [`LimbMotion::interpolated`] averages.
    noise_correlation: [f64; 4],
    pub(super) samples: Samples,
    /// Per run, the block means: the record's own, or where it has a [`SkinFilter`], the limb's
    /// SUs' read through it. Shared (not copied) with the record and by the limb's coarse and
    /// at-rest versions ([`LimbMotion::thinned`], [`LimbMotion::at_rest`]).
    skin: Vec<SkinRows>,
    /// Per limb SU, its column in `skin`.
    columns: Vec<usize>,
    /// Each SU's standard deviation of one component of `skin`, m/s².
    pub(super) sd: Vec<f64>,
    /// The variance the joint accelerations' uncertainty adds to each SU's prediction at each
    /// sample (empty until [`LimbMotion::weigh`]).
    joint_var: JointVariance,
    /// Per chain DoF: its encoder's rounding ([`MotionRecord::rounding`]), rad.
    rounding: Vec<f64>,
    /// How many of the residual's degrees of freedom the last correction of the joint states
    /// took ([`LimbMotion::correct_joint_states`]): per sample, the trace of its hat matrix.
    corrected: f64,
    /// The limb's DoFs' columns in the record.
    dofs: Vec<usize>,
    /// Per run, the record's sharp joint states (`q`, `q̇`, `q̈`, [`crate::motion::MotionRun::q_sharp`],
    /// shared); empty where the record has none or reads no kernel.
    sharp: Vec<[JointRows; 3]>,
    /// Per run, what reading the prediction through the kernel adds to the prediction at the
    /// kernel's joint states, at the samples' blocks, per limb SU
    /// ([`LimbMotion::read_through_kernel`]); empty until computed.
    spread: Vec<SkinRows>,
}

impl LimbMotion {
    /// The blocks of `record` for the limb of `data` (every block at least [`MAX_DELAY`] and two
    /// blocks from its run's ends, so that any delay reads the same blocks). Where the record's
    /// joint states were read through a wide polynomial, the skin is read through the same
    /// kernel ([`SkinFilter`]) and every [`SkinFilter::stride`]-th block is taken (what lies
    /// between adds little the kernel has not averaged already). An SU the record
    /// cannot tell its noise for gets `fallback_sd` over the square root of the skin samples a
    /// block holds at the record's period and 1 kHz.
    pub fn new(
        record: &MotionRecord,
        data: &LimbData,
        fallback_sd: f64,
    ) -> Result<Self, EstimateError> {
        let limb = &data.chain.name;
        let find = |kind: &str, names: &[String], name: &String| {
            names
                .iter()
                .position(|n| n == name)
                .ok_or_else(|| EstimateError::UnsupportedLimb {
                    limb: limb.clone(),
                    reason: format!(
                        "the motion record has no {kind} `{name}`: ingest the logs again with it"
                    ),
                })
        };
        let dofs: Vec<usize> = data
            .chain
            .dofs()
            .iter()
            .map(|d| find("DoF", &record.dofs, d))
            .collect::<Result<_, _>>()?;
        let sus: Vec<usize> = data
            .chain
            .sus()
            .iter()
            .map(|s| find("SU", &record.sus, s))
            .collect::<Result<_, _>>()?;
        let kinds = data.chain.kinds();
        let margin = (MAX_DELAY / record.period).ceil() as usize + 2;
        let limits = sudden_limits(record, &dofs);
        let filter = record.skin_filter();
        let stride = filter.as_ref().map_or(1, SkinFilter::stride);
        let mut samples = Samples::default();
        let mut skin = Vec::new();
        for (r, run) in record.runs.iter().enumerate() {
            let pick = |row: &[f64]| dofs.iter().map(|&d| row[d]).collect::<Vec<f64>>();
            for b in (margin..run.len().saturating_sub(margin)).step_by(stride) {
                let sudden = dofs.iter().zip(&limits);
                if sudden
                    .into_iter()
                    .any(|(&d, &limit)| run.qdd_sd[b][d] > limit)
                {
                    continue;
                }
                samples.push(
                    r,
                    b,
                    &pick(&run.q[b]),
                    &pick(&run.qd[b]),
                    &pick(&run.qdd[b]),
                    &pick(&run.qdd_sd[b]),
                );
            }
            skin.push(match &filter {
                None => run.skin.clone(),
                Some(f) => {
                    let mut smoothed = SkinRows::empty(sus.len(), run.skin.len());
                    for (column, &u) in sus.iter().enumerate() {
                        let means: Vec<Option<Vector3<f64>>> = (0..run.skin.len())
                            .map(|b| run.skin.get(b, u).map(Vector3::from))
                            .collect();
                        for b in 0..means.len() {
                            let value = f.smooth(&means, b).map(|v| [v.x, v.y, v.z]);
                            smoothed.set(b, column, value);
                        }
                    }
                    smoothed
                }
            });
        }
        let per_block = (record.period * 1000.0).max(1.0);
        let factor = filter.as_ref().map_or(1.0, SkinFilter::noise_factor);
        let sd = sus
            .iter()
            .map(|&u| factor * record.noise_sd[u].unwrap_or(fallback_sd / per_block.sqrt()))
            .collect();
        let rounding = dofs
            .iter()
            .map(|&d| record.rounding.get(d).copied().unwrap_or(0.0))
            .collect();
        let noise_correlation = std::array::from_fn(|lag| match &filter {
            Some(f) => f.correlation(lag),
            None => BLOCK_NOISE_CORRELATION[lag],
        });
        let sharp = match filter {
            Some(_) if record.runs.iter().all(|r| r.q_sharp.len() == r.len()) => record
                .runs
                .iter()
                .map(|r| [r.q_sharp.clone(), r.qd_sharp.clone(), r.qdd_sharp.clone()])
                .collect(),
            _ => Vec::new(),
        };
        let columns = match filter {
            None => sus.clone(),
            Some(_) => (0..sus.len()).collect(),
        };
        Ok(Self {
            period: record.period,
            kinds,
            stride,
            filter,
            noise_correlation,
            samples,
            skin,
            columns,
            sd,
            joint_var: JointVariance::default(),
            rounding,
            corrected: 0.0,
            dofs,
            sharp,
            spread: Vec::new(),
        })
    }

    /// Whether the prediction can be read through the skin's kernel
    /// ([`LimbMotion::read_through_kernel`]).
    pub(super) fn reads_through_kernel(&self) -> bool {
        !self.sharp.is_empty()
    }

    /// Reads the prediction through the skin's kernel, as the skin is: at every sample's block
    /// `b`, the kernel's mean of `predict` at the sharp joint states of the blocks it spans,
    /// `Σⱼ wⱼ f(xᵇ⁺ʲ) / Σⱼ wⱼ`, less `predict` at their kernel mean `x̄ = Σⱼ wⱼ xᵇ⁺ʲ / Σⱼ wⱼ`:
    /// what the motion's spread within the kernel adds (gravity turned by the position, the
    /// centripetal terms, the tangential ones turned), which the fit then adds to its
    /// prediction at the record's joint states, themselves read through the kernel
    /// ([`LimbMotion::interpolated`] subtracts it from the skin). `predict`: every SU's reading
    /// at an instant (turns, rates, accelerations; `None` for one no DoF moves) at the fit's
    /// current parameters. Without sharp joint states, nothing.
    pub(super) fn read_through_kernel<F>(&mut self, predict: F)
    where
        F: Fn(&[Isometry3<f64>], &[f64], &[f64]) -> Vec<Option<Vector3<f64>>> + Sync,
    {
        let Some(filter) = self.filter.as_ref().filter(|_| !self.sharp.is_empty()) else {
            return;
        };
        let weights: Vec<f64> = {
            let w = filter.weights();
            let total: f64 = w.iter().sum();
            w.iter().map(|w| w / total).collect()
        };
        let reach = weights.len() / 2;
        let (sus, n) = (self.sd.len(), self.dofs.len());
        let mut rows: Vec<SkinRows> = self
            .sharp
            .iter()
            .map(|[q, _, _]| SkinRows::empty(sus, q.len()))
            .collect();
        // A chunk of samples of one run at a time: the prediction at each block they reach
        // computed once (a block lies within the kernel of about `2·reach / stride` samples),
        // and the heap bounded by the chunk, not the record.
        let mut i = 0;
        while i < self.samples.len() {
            let run = self.samples.get(i).run();
            let end = (i..self.samples.len())
                .take(SPREAD_CHUNK)
                .take_while(|&k| self.samples.get(k).run() == run)
                .last()
                .map_or(i + 1, |k| k + 1);
            let sharp = &self.sharp[run];
            let first = self.samples.get(i).block().saturating_sub(reach);
            let last = (self.samples.get(end - 1).block() + reach).min(sharp[0].len() - 1);
            // Per block from `first`: the chain DoFs' sharp `q`, `q̇`, `q̈`, and the prediction.
            let states: Vec<Vec<f64>> = (first..=last)
                .map(|b| {
                    let row = |rows: &JointRows| -> Vec<f64> {
                        self.dofs.iter().map(|&d| rows[b][d]).collect()
                    };
                    sharp.iter().flat_map(row).collect()
                })
                .collect();
            let at =
                |x: &[f64]| predict(&turns_of(&x[..n], &self.kinds), &x[n..2 * n], &x[2 * n..]);
            let predicted: Vec<Vec<Option<Vector3<f64>>>> =
                states.par_iter().map(|x| at(x)).collect();
            let spreads: Vec<Option<Vec<Option<Vector3<f64>>>>> = self
                .samples
                .par_range(i..end)
                .map(|s| {
                    let start = s.block().checked_sub(reach)?;
                    if s.block() + reach > last {
                        return None;
                    }
                    let mut mean = vec![Some(Vector3::zeros()); sus];
                    let mut centre = vec![0.0; 3 * n];
                    for (j, w) in weights.iter().enumerate() {
                        let k = start + j - first;
                        for (m, f) in mean.iter_mut().zip(&predicted[k]) {
                            *m = m.zip(*f).map(|(m, f)| m + f * *w);
                        }
                        for (c, x) in centre.iter_mut().zip(&states[k]) {
                            *c += x * w;
                        }
                    }
                    let spread = mean.into_iter().zip(at(&centre));
                    Some(spread.map(|(m, f)| m.zip(f).map(|(m, f)| m - f)).collect())
                })
                .collect();
            for (k, spread) in (i..end).zip(spreads) {
                let b = self.samples.get(k).block();
                for (u, v) in spread.into_iter().flatten().enumerate() {
                    rows[run].set(b, u, v.map(|v| [v.x, v.y, v.z]));
                }
            }
            i = end;
        }
        self.spread = rows;
    }

    /// How many of the residual's degrees of freedom the joint states' corrections took: the sum
    /// over the samples of `tr((JᵀJ + P)⁻¹ JᵀJ)` of their last solve (0 before any).
    pub(super) fn corrected_dof(&self) -> f64 {
        self.corrected
    }

    /// How much more information along a slowly varying direction the samples seem to hold,
    /// weighed each alone, than they do: their filtered noise is correlated
    /// ([`SkinFilter::overcount`]; 1 where the skin is read as block means).
    pub(super) fn overcount(&self) -> f64 {
        self.filter
            .as_ref()
            .map_or(1.0, |f| f.overcount(self.stride))
    }

    /// The degrees of freedom of a residual over the samples per independent one
    /// ([`SkinFilter::square_overcount`]; 1 where the skin is read as block means).
    pub(super) fn square_overcount(&self) -> f64 {
        self.filter
            .as_ref()
            .map_or(1.0, |f| f.square_overcount(self.stride))
    }

    /// The quietest SU's standard deviation of one component of a sample, m/s².
    fn quietest(&self) -> f64 {
        self.sd.iter().copied().fold(f64::INFINITY, f64::min)
    }

    /// The revolute DoFs (chain indices) whose encoders round coarsely enough to matter: one
    /// rounding's deviation turns gravity by more than a tenth of the quietest SU's noise.
    pub(super) fn coarse_dofs(&self) -> Vec<usize> {
        let quietest = self.quietest();
        (0..self.kinds.len())
            .filter(|&d| {
                self.kinds[d] == DofKind::Revolute
                    && self.rounding[d] * STANDARD_GRAVITY > 0.1 * quietest
            })
            .collect()
    }

    /// One pass of the joint states' correction ([`super::joint_states`]): at every sample, the
    /// positions and accelerations of `dofs` moved by `relaxation` times the Gauss–Newton step
    /// that best explains what every SU read there (with the skin `delay` s late), each SU
    /// whitened by its noise, against `predict` (every SU's reading at an instant: turns, rates,
    /// accelerations; `None` for one no DoF moves), and the corrections held at what the record
    /// read by priors: the encoder's rounding for a position, the record's uncertainty (at least
    /// [`ACCELERATION_PRIOR`]) for an acceleration. Where a DoF read one count on consecutive
    /// samples (it stood still, [`LimbMotion::held_counts`]), its position's error is one for
    /// them all: one correction, held once by the rounding, is solved from every sample's
    /// readings with their other corrections eliminated, and those then given it. (Taken apart,
    /// each sample's correction was held by the whole rounding's prior against one sample's
    /// readings and stayed small: on the Kinova with 13-bit encoders, 0.0068 m/s² held-out
    /// static where tied 0.0050.) Keeps how many of the residual's degrees of freedom the
    /// corrections took ([`LimbMotion::corrected_dof`]).
    pub(super) fn correct_joint_states<F>(
        &mut self,
        dofs: &[usize],
        delay: f64,
        relaxation: f64,
        predict: F,
    ) where
        F: Fn(&[Isometry3<f64>], &[f64], &[f64]) -> Vec<Option<Vector3<f64>>> + Sync,
    {
        let n = dofs.len();
        let locals: Vec<Option<Local>> = (0..self.samples.len())
            .into_par_iter()
            .map(|i| self.local(i, dofs, delay, &predict))
            .collect();
        // Where a DoF's reading stood at one count, one correction of its position for all of
        // the stretch's samples.
        let held = self.held_counts(dofs);
        let mut tie: Vec<Vec<Option<usize>>> = vec![vec![None; n]; self.samples.len()];
        for (t, (k, range)) in held.iter().enumerate() {
            for i in range.clone() {
                tie[i][*k] = Some(t);
            }
        }
        let tied = self.tied_steps(&locals, &tie, &held, dofs);
        let steps: Vec<Option<(DVector<f64>, f64)>> = locals
            .par_iter()
            .zip(&tie)
            .map(|(local, ties)| {
                let local = local.as_ref()?;
                let fixed: Vec<(usize, f64)> = ties
                    .iter()
                    .enumerate()
                    .filter_map(|(k, t)| Some((k, tied.values[(*t)?])))
                    .collect();
                local.solve(&fixed)
            })
            .collect();
        self.corrected = steps.iter().flatten().map(|(_, taken)| taken).sum::<f64>() + tied.taken;
        for (i, step) in steps.into_iter().enumerate() {
            if let Some((step, _)) = step {
                for (k, &d) in dofs.iter().enumerate() {
                    let (q, qdd) = (relaxation * step[k], relaxation * step[n + k]);
                    self.samples.correct(i, d, q, qdd);
                }
            }
        }
    }

    /// Sample `i`'s normal equations in the corrections of `dofs`' positions and accelerations
    /// (in that order), whitened by each SU's noise, and their priors
    /// ([`LimbMotion::correct_joint_states`]); `None` where no SU it moves read there.
    fn local<F>(&self, i: usize, dofs: &[usize], delay: f64, predict: &F) -> Option<Local>
    where
        F: Fn(&[Isometry3<f64>], &[f64], &[f64]) -> Vec<Option<Vector3<f64>>> + Sync,
    {
        let n = dofs.len();
        let sample = self.samples.get(i);
        let measured: Vec<(usize, Vector3<f64>)> = (0..self.sd.len())
            .filter_map(|u| Some((u, self.measured(u, i, delay)?)))
            .collect();
        let at = |x: &[f64]| {
            let (mut q, mut qdd) = (sample.q().to_vec(), sample.qdd().to_vec());
            for (k, &d) in dofs.iter().enumerate() {
                q[d] += x[k];
                qdd[d] += x[n + k];
            }
            predict(
                &super::problem::turns_of(&q, &self.kinds),
                sample.qd(),
                &qdd,
            )
        };
        let mut x = vec![0.0; 2 * n];
        let base = at(&x);
        let rows: Vec<(usize, Vector3<f64>, Vector3<f64>)> = measured
            .into_iter()
            .filter_map(|(u, m)| Some((u, base[u]?, m)))
            .collect();
        if rows.is_empty() {
            return None;
        }
        let mut jac = DMatrix::zeros(3 * rows.len(), 2 * n);
        let mut r = DVector::zeros(3 * rows.len());
        for (k, (u, p, m)) in rows.iter().enumerate() {
            r.fixed_rows_mut::<3>(3 * k)
                .copy_from(&((p - m) / self.sd[*u]));
        }
        for j in 0..2 * n {
            // A position by a microradian; the reading is linear in an acceleration.
            let h = if j < n { 1e-6 } else { 1e-3 };
            x[j] = h;
            let moved = at(&x);
            x[j] = 0.0;
            for (k, (u, p, _)) in rows.iter().enumerate() {
                if let Some(m) = moved[*u] {
                    jac.fixed_view_mut::<3, 1>(3 * k, j)
                        .copy_from(&((m - p) / (h * self.sd[*u])));
                }
            }
        }
        let mut prior = DVector::zeros(2 * n);
        let mut held_at = DVector::zeros(2 * n);
        for (k, &d) in dofs.iter().enumerate() {
            prior[k] = self.rounding[d].powi(-2);
            let (read_q, read_qdd) = sample.read(d);
            held_at[k] = sample.q()[d] - read_q;
            prior[n + k] = sample.qdd_sd()[d].max(ACCELERATION_PRIOR).powi(-2);
            held_at[n + k] = sample.qdd()[d] - read_qdd;
        }
        Some(Local {
            information: jac.transpose() * &jac,
            gradient: jac.transpose() * &r,
            prior,
            held_at,
        })
    }

    /// The stretches `(chain index into dofs, samples)` in which a DoF of `dofs` read one
    /// position on [`TIED`] or more consecutive samples of a run: a joint standing at a count,
    /// whose error is one for the whole stretch (at most [`MOST_TIED`]).
    fn held_counts(&self, dofs: &[usize]) -> Vec<(usize, std::ops::Range<usize>)> {
        let mut held = Vec::new();
        for (k, &d) in dofs.iter().enumerate() {
            let mut start = 0;
            for i in 1..=self.samples.len() {
                let same = i < self.samples.len() && {
                    let (a, b) = (self.samples.get(start), self.samples.get(i));
                    a.run == b.run && (a.read(d).0 - b.read(d).0).abs() <= 1e-9
                };
                if !same {
                    if i - start >= TIED {
                        held.push((k, start..i));
                    }
                    start = i;
                }
            }
        }
        // Their corrections are solved together (a dense system): the longest, where many.
        if held.len() > MOST_TIED {
            held.sort_by_key(|(_, range)| std::cmp::Reverse(range.len()));
            held.truncate(MOST_TIED);
        }
        held
    }

    /// The corrections of the tied positions (`held`, `tie[i][k]`: the stretch sample `i`'s
    /// DoF `k` belongs to), every other correction of their samples eliminated, each stretch
    /// held once by its encoder's rounding.
    fn tied_steps(
        &self,
        locals: &[Option<Local>],
        tie: &[Vec<Option<usize>>],
        held: &[(usize, std::ops::Range<usize>)],
        dofs: &[usize],
    ) -> Tied {
        let m = held.len();
        let mut a = DMatrix::<f64>::zeros(m, m);
        let mut b = DVector::<f64>::zeros(m);
        for (local, ties) in locals.iter().zip(tie) {
            let Some(local) = local else {
                continue;
            };
            let at: Vec<(usize, usize)> = ties
                .iter()
                .enumerate()
                .filter_map(|(k, t)| Some((k, (*t)?)))
                .collect();
            if at.is_empty() {
                continue;
            }
            let (reduced, gradient) = local.reduced(&at.iter().map(|p| p.0).collect::<Vec<_>>());
            for (x, &(_, s)) in at.iter().enumerate() {
                b[s] += gradient[x];
                for (y, &(_, t)) in at.iter().enumerate() {
                    a[(s, t)] += reduced[(x, y)];
                }
            }
        }
        let data = a.clone();
        for (t, (k, range)) in held.iter().enumerate() {
            let d = dofs[*k];
            let first = self.samples.get(range.start);
            let prior = self.rounding[d].powi(-2);
            a[(t, t)] += prior;
            b[t] += (first.q()[d] - first.read(d).0) * prior;
        }
        let Some(cholesky) = (m > 0).then(|| a.cholesky()).flatten() else {
            return Tied {
                values: vec![0.0; m],
                taken: 0.0,
            };
        };
        Tied {
            values: cholesky.solve(&(-b)).iter().copied().collect(),
            taken: cholesky.solve(&data).trace(),
        }
    }
    /// Sets what each sample's joint accelerations add to the variance of each SU's prediction,
    /// at `state` (the start of the fit, held through it so that the weights do not pull the
    /// SUs towards the axes): `Σ_d σ²(q̈_d) |z_d × (p − o_d)|²` over the DoFs before the SU on
    /// segment `su_segment[u]`.
    pub(super) fn weigh(&mut self, state: &ChainState, su_segment: &[usize]) {
        self.weigh_as_static(state, su_segment, 0.0);
    }

    /// [`LimbMotion::weigh`] without what of the accelerations of `fitted` (chain DoFs) the fit
    /// takes as unknowns ([`LimbMotion::correct_joint_states`], each held by a prior of that
    /// same uncertainty), which weighed in the noise as well would count twice: all of it where
    /// the joint crossed at most [`SLOW_COUNTS`] counts within the polynomial's span, and
    /// elsewhere the rounding's share, the least any sample of the DoF was uncertain of (where
    /// its polynomial fitted within the rounding).
    pub(super) fn weigh_fitted(
        &mut self,
        state: &ChainState,
        su_segment: &[usize],
        fitted: &[usize],
    ) {
        self.weigh_with(state, su_segment, 0.0, fitted);
    }

    /// [`LimbMotion::weigh`], and each prediction taken as if the limb stood still, with what its
    /// motion could add to gravity as error: `kappa` times [`QUIET_REACH`] times
    /// `Σ|q̈_d| + (Σ|q̇_d|)²` over the DoFs before the SU. With `kappa` 1 the quiet blocks count
    /// and the fast ones hardly; lowered step by step, the fit is led from a start that gravity
    /// alone gave (orientations and axes) to the whole motion.
    pub(super) fn weigh_as_static(&mut self, state: &ChainState, su_segment: &[usize], kappa: f64) {
        self.weigh_with(state, su_segment, kappa, &[]);
    }

    /// [`LimbMotion::weigh_as_static`] without what the corrections take of the accelerations of
    /// the chain DoFs `fitted` ([`LimbMotion::weigh_fitted`]).
    fn weigh_with(
        &mut self,
        state: &ChainState,
        su_segment: &[usize],
        kappa: f64,
        fitted: &[usize],
    ) {
        let sus = su_segment.len().max(1);
        // What of a fitted DoF's acceleration the correction takes ([`Self::weigh_fitted`]): per
        // DoF, the speed below which all of it, and the rounding's share above.
        let span = self.filter.as_ref().map_or(0.0, |f| {
            (f.weights().len().saturating_sub(1)) as f64 * self.period
        });
        let taken: Vec<Option<(f64, f64)>> = (0..self.kinds.len())
            .map(|d| {
                fitted.contains(&d).then(|| {
                    let slow = SLOW_COUNTS * self.rounding[d] * 12f64.sqrt();
                    let sds = self
                        .samples
                        .par_range(0..self.samples.len())
                        .map(|s| s.qdd_sd()[d]);
                    let floor = sds.filter(|sd| *sd > 0.0).min_by(f64::total_cmp);
                    (slow, floor.unwrap_or(0.0))
                })
            })
            .collect();
        // Sample by sample, every SU's, in one buffer.
        let mut by_sample = Buffer::filled(self.samples.len() * sus, 0f32);
        by_sample
            .par_chunks_mut(sus)
            .zip(self.samples.par_range(0..self.samples.len()))
            .for_each(|(out, sample)| {
                let mut segment = Isometry3::<f64>::identity();
                let mut segments = vec![segment];
                let mut axes = Vec::with_capacity(state.joints.len());
                // Each DoF's acceleration variance the residual keeps, rad²/s⁴.
                let kept: Vec<f64> = (sample.qd().iter().zip(sample.qdd_sd()).zip(&taken))
                    .map(|((qd, sd), taken)| match taken {
                        None => sd * sd,
                        Some((slow, _)) if qd.abs() * span <= *slow => 0.0,
                        Some((_, floor)) => (sd * sd - floor * floor).max(0.0),
                    })
                    .collect();
                let turns = sample.turns(&self.kinds);
                for ((joint, turn), kind) in state.joints.iter().zip(&turns).zip(&self.kinds) {
                    let (frame, next) = link(&segment, joint, turn);
                    axes.push((
                        frame.rotation * Vector3::z(),
                        frame.translation.vector,
                        *kind,
                    ));
                    segment = next;
                    segments.push(segment);
                }
                let values = su_segment.iter().zip(&state.sus).map(|(&s, su)| {
                    let p = (segments[s] * su).translation.vector;
                    let joints: f64 = axes
                        .iter()
                        .take(s)
                        .zip(&kept)
                        .map(|((z, o, kind), var)| match kind {
                            DofKind::Revolute => z.cross(&(p - o)).norm_squared() * var,
                            DofKind::Prismatic => *var,
                        })
                        .sum();
                    (joints + (kappa * sample.reach(s)).powi(2)) as f32
                });
                for (o, v) in out.iter_mut().zip(values) {
                    *o = v;
                }
            });
        self.joint_var = JointVariance {
            sus,
            values: by_sample,
        };
    }

    /// The variance of one component of SU `u`'s block, (m/s²)².
    pub(super) fn skin_variance(&self, u: usize) -> f64 {
        self.sd[u].powi(2)
    }

    /// The variance of one component of SU `u`'s residual at sample `i` where the skin's noise
    /// has `variance` times a block's ([`Interpolated::variance`]), (m/s²)².
    pub(super) fn residual_variance(&self, u: usize, i: usize, variance: f64) -> f64 {
        let extra = self.joint_var.get(i, u);
        self.sd[u].powi(2) * variance + extra.map_or(0.0, f64::from)
    }

    /// Every `every`-th of the blocks the fit uses (the skin kept whole, the samples' weights
    /// kept): a coarse version for the steps that lead a fit to where the whole record takes
    /// over, and for choosing the sensors' model. Neighbouring samples are `every` times as far
    /// apart, and their filtered noise as much less correlated.
    pub(super) fn thinned(&self, every: usize) -> Self {
        let every = every.max(1);
        self.with_samples(
            self.samples.select(|i| i % every == 0),
            self.joint_var.of_samples(|i| i % every == 0),
            self.stride * every,
        )
    }

    /// This record's share with `samples` (their weights `joint_var`, `stride` blocks apart in
    /// a run) in place of its own; the skin shared, not copied.
    fn with_samples(&self, samples: Samples, joint_var: JointVariance, stride: usize) -> Self {
        Self {
            period: self.period,
            kinds: self.kinds.clone(),
            stride,
            filter: self.filter.clone(),
            noise_correlation: self.noise_correlation,
            samples,
            skin: self.skin.clone(),
            columns: self.columns.clone(),
            sd: self.sd.clone(),
            joint_var,
            rounding: self.rounding.clone(),
            corrected: self.corrected,
            dofs: self.dofs.clone(),
            sharp: self.sharp.clone(),
            spread: self.spread.clone(),
        }
    }

    /// The samples in which the limb stood so still that its motion adds less than a tenth of
    /// the quietest SU's noise to what gravity reads (by [`QUIET_REACH`]): the rows that test a
    /// fit's geometry, gravity and sensors against the skin's own noise, free of what the joint
    /// states' derivatives leave unmatched in motion.
    pub(super) fn at_rest(&self) -> Self {
        let quietest = self.quietest();
        let keep: Vec<bool> = self
            .samples
            .iter()
            .map(|s| s.reach(s.dofs()) < 0.1 * quietest)
            .collect();
        self.with_samples(
            self.samples.select(|i| keep[i]),
            self.joint_var.of_samples(|i| keep[i]),
            self.stride,
        )
    }

    /// The number of blocks the fit uses.
    pub fn len(&self) -> usize {
        self.samples.len()
    }

    /// Whether the fit uses no block.
    pub fn is_empty(&self) -> bool {
        self.samples.is_empty()
    }

    /// What SU `u` read at sample `i` with the skin's clock `delay` s behind the joints': its
    /// block means interpolated (Catmull–Rom) at the block `delay` later; `None` where a block
    /// the interpolation needs has no sample.
    pub(super) fn measured(&self, u: usize, i: usize, delay: f64) -> Option<Vector3<f64>> {
        self.interpolated(u, i, delay).map(|m| m.value)
    }

    /// [`LimbMotion::measured`] with its rate with the delay and its noise's: see
    /// [`Interpolated`].
    pub(super) fn interpolated(&self, u: usize, i: usize, delay: f64) -> Option<Interpolated> {
        let sample = self.samples.get(i);
        let (series, column) = (&self.skin[sample.run()], self.columns[u]);
        let x = sample.block() as f64 + delay.clamp(-MAX_DELAY, MAX_DELAY) / self.period;
        let k = x.floor();
        let t = x - k;
        let k = k as usize;
        let at = |j: usize| series.get(j, column).map(Vector3::from);
        let (p0, p1, p2, p3) = (at(k.checked_sub(1)?)?, at(k)?, at(k + 1)?, at(k + 2)?);
        let (t2, t3) = (t * t, t * t * t);
        // The weights of the four blocks, and their rates with `t`.
        let w = [
            0.5 * (-t + 2.0 * t2 - t3),
            0.5 * (2.0 - 5.0 * t2 + 3.0 * t3),
            0.5 * (t + 4.0 * t2 - 3.0 * t3),
            0.5 * (t3 - t2),
        ];
        let dw = [
            0.5 * (-1.0 + 4.0 * t - 3.0 * t2),
            0.5 * (9.0 * t2 - 10.0 * t),
            0.5 * (1.0 + 8.0 * t - 9.0 * t2),
            0.5 * (3.0 * t2 - 2.0 * t),
        ];
        let held = delay.abs() >= MAX_DELAY;
        let per_second = if held { 0.0 } else { 1.0 / self.period };
        let blocks = [p0, p1, p2, p3];
        let weighed = |weights: &[f64; 4]| -> Vector3<f64> {
            blocks.iter().zip(weights).map(|(p, w)| p * *w).sum()
        };
        let (mut value, rate) = (weighed(&w), weighed(&dw) * per_second);
        if let Some(spread) = self.spread.get(sample.run()) {
            // What the kernel adds to the prediction ([`LimbMotion::read_through_kernel`]),
            // at the joint states' block whatever the delay: the skin there is read through the
            // kernel about it.
            value -= Vector3::from(spread.get(sample.block(), u).unwrap_or_default());
        }
        let (mut variance, mut variance_rate) = (0.0, 0.0);
        for a in 0..4_usize {
            for b in 0..4 {
                let rho = self.noise_correlation[a.abs_diff(b)];
                variance += w[a] * w[b] * rho;
                variance_rate += 2.0 * dw[a] * w[b] * rho;
            }
        }
        Some(Interpolated {
            value,
            rate,
            variance,
            variance_rate: variance_rate * per_second,
        })
    }

    /// Whether samples `i` and `j` are neighbouring samples of one run, a stride apart.
    pub(super) fn adjacent(&self, i: usize, j: usize) -> bool {
        let (a, b) = (self.samples.get(i), self.samples.get(j));
        a.run == b.run && a.block().abs_diff(b.block()) == self.stride
    }

    /// The time between two adjacent samples ([`LimbMotion::adjacent`]), s.
    pub(super) fn spacing(&self) -> f64 {
        self.period * self.stride as f64
    }
}

/// Per DoF of `dofs` (record indices), the uncertainty of its acceleration above which a block
/// is too sudden to fit: [`MAX_ACCELERATION_SD`], or [`SUDDEN`] times the DoF's median where its
/// encoder leaves every block less certain.
fn sudden_limits(record: &MotionRecord, dofs: &[usize]) -> Vec<f64> {
    dofs.iter()
        .map(|&d| {
            let mut sds: Vec<f64> = record
                .runs
                .iter()
                .flat_map(|run| run.qdd_sd.iter().map(move |row| row[d]))
                .collect();
            if sds.is_empty() {
                return MAX_ACCELERATION_SD;
            }
            let mid = sds.len() / 2;
            let median = *sds.select_nth_unstable_by(mid, f64::total_cmp).1;
            MAX_ACCELERATION_SD.max(SUDDEN * median)
        })
        .collect()
}

/// The segment terms of `samples` at `state`, for segments `1..=last`; with `columns` (the
/// shared columns of the problem: block and component), their derivatives too.
pub(super) fn segment_terms(
    state: &ChainState,
    motion: &LimbMotion,
    last: usize,
    columns: Option<&[(Block, usize)]>,
    samples: std::ops::Range<usize>,
) -> Vec<SegmentTerms> {
    let chain = Chain::new(state, &motion.kinds, columns);
    motion
        .samples
        .par_range(samples)
        .map(|sample| {
            let instant = [Instant::new(sample.qd(), sample.qdd(), true)];
            let mut terms = chain.terms(&sample.turns(&motion.kinds), None, &instant, last);
            terms.swap_remove(0)
        })
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A record of one SU and one block-mean series (no filter, `period` 10 ms), with one
    /// sample at block `block`.
    fn one_series(series: Vec<Option<Vector3<f64>>>, block: usize) -> LimbMotion {
        LimbMotion {
            period: 0.01,
            kinds: vec![DofKind::Revolute],
            stride: 1,
            filter: None,
            noise_correlation: [1.0, 0.0, 0.0, 0.0],
            samples: {
                let mut samples = Samples::default();
                samples.push(0, block, &[0.0], &[0.0], &[0.0], &[0.0]);
                samples
            },
            skin: vec![SkinRows::from(
                series
                    .iter()
                    .map(|m| vec![m.map(|v| [v.x, v.y, v.z])])
                    .collect::<Vec<_>>(),
            )],
            columns: vec![0],
            sd: vec![0.01],
            joint_var: JointVariance::default(),
            rounding: vec![0.0],
            corrected: 0.0,
            dofs: vec![0],
            sharp: Vec::new(),
            spread: Vec::new(),
        }
    }

    /// The prediction read through the kernel is the kernel's mean of the prediction less the
    /// prediction at the kernel's mean, with the kernel's own weights `K(j·period/h)`: checked
    /// on a joint swinging `q = 0.6 sin(2π·1.5 t)` at 160 ms and 10 ms blocks, against a
    /// prediction of `(cos q, q̇², q̈)` (gravity turned, centripetal, tangential), which the
    /// kernel turns by a hand-summed amount for the first two and leaves for the linear third.
    /// The skin then reads the prediction at the kernel's joint states plus that amount.
    #[test]
    fn the_prediction_is_read_through_the_kernel_as_the_skin_is() {
        let (period, h, blocks, b) = (0.01, 0.16, 101, 50);
        let (amplitude, omega) = (0.6, std::f64::consts::TAU * 1.5);
        let state = |j: usize| {
            let t = j as f64 * period;
            let (s, c) = (omega * t).sin_cos();
            [
                amplitude * s,
                amplitude * omega * c,
                -amplitude * omega * omega * s,
            ]
        };
        let rows =
            |k: usize| JointRows::from((0..blocks).map(|j| vec![state(j)[k]]).collect::<Vec<_>>());
        let mut motion = one_series(vec![Some(Vector3::new(1.0, 2.0, 3.0)); blocks], b);
        motion.filter = SkinFilter::new(h, period);
        motion.sharp = vec![[rows(0), rows(1), rows(2)]];
        motion.read_through_kernel(|turns, qd, qdd| {
            let q = turns[0].rotation.scaled_axis().z;
            vec![Some(Vector3::new(q.cos(), qd[0] * qd[0], qdd[0]))]
        });
        let kernel = crate::motion::Kernel::new();
        let (mut weight, mut mean, mut centre) = (0.0, Vector3::zeros(), [0.0; 3]);
        for j in b - 16..=b + 16 {
            let w = kernel.value((j as f64 - b as f64) * period / h);
            let [q, qd, qdd] = state(j);
            weight += w;
            mean += w * Vector3::new(q.cos(), qd * qd, qdd);
            for (c, x) in centre.iter_mut().zip([q, qd, qdd]) {
                *c += w * x;
            }
        }
        let [q, qd, qdd] = centre.map(|c| c / weight);
        let expected = mean / weight - Vector3::new(q.cos(), qd * qd, qdd);
        let spread = Vector3::from(motion.spread[0].get(b, 0).unwrap());
        assert!((spread - expected).norm() < 1e-6, "{spread} vs {expected}");
        // The swing's spread within 160 ms turns gravity and the centripetal term measurably;
        // the tangential term is linear in the motion, its mean its value at the mean.
        assert!(
            expected.x.abs() > 1e-3 && expected.y.abs() > 1e-2,
            "{expected}"
        );
        let read = motion.measured(0, 0, 0.0).unwrap();
        assert!(
            (read - (Vector3::new(1.0, 2.0, 3.0) - expected)).norm() < 1e-6,
            "{read}"
        );
    }

    /// Two samples at one count of an encoder, each with a position and an acceleration to
    /// correct: their position shared, its prior counted once. Eliminating each sample's
    /// acceleration, summing what is left with the prior and solving, then each acceleration
    /// given the position, must give the joint problem's minimiser, solved here directly in its
    /// three unknowns.
    #[test]
    fn a_position_held_at_one_count_is_corrected_once_for_its_samples() {
        let local = |information: [[f64; 2]; 2], gradient: [f64; 2], held_at: [f64; 2]| Local {
            information: DMatrix::from_row_slice(2, 2, information.as_flattened()),
            gradient: DVector::from_row_slice(&gradient),
            prior: DVector::from_row_slice(&[4.0, 0.5]),
            held_at: DVector::from_row_slice(&held_at),
        };
        let a = local([[9.0, 2.0], [2.0, 3.0]], [1.5, -0.4], [0.1, 0.0]);
        let b = local([[5.0, -1.0], [-1.0, 2.0]], [-0.7, 0.9], [0.1, 0.3]);
        let (ra, ga) = a.reduced(&[0]);
        let (rb, gb) = b.reduced(&[0]);
        // The position's prior once, at where the stretch stands (0.1 from the reading).
        let z = -(ga[0] + gb[0] + 4.0 * 0.1) / (ra[(0, 0)] + rb[(0, 0)] + 4.0);
        let (sa, _) = a.solve(&[(0, z)]).unwrap();
        let (sb, _) = b.solve(&[(0, z)]).unwrap();
        // Unknowns (position, a's acceleration, b's acceleration): the quadratics summed.
        let h = DMatrix::from_row_slice(
            3,
            3,
            &[
                9.0 + 5.0 + 4.0,
                2.0,
                -1.0,
                2.0,
                3.0 + 0.5,
                0.0,
                -1.0,
                0.0,
                2.0 + 0.5,
            ],
        );
        let g = DVector::from_row_slice(&[1.5 - 0.7 + 4.0 * 0.1, -0.4, 0.9 + 0.5 * 0.3]);
        let direct = h.cholesky().unwrap().solve(&(-g));
        assert!((sa[0] - direct[0]).abs() < 1e-12 && (sb[0] - direct[0]).abs() < 1e-12);
        assert!((sa[1] - direct[1]).abs() < 1e-12, "{sa} {direct}");
        assert!((sb[1] - direct[2]).abs() < 1e-12, "{sb} {direct}");
    }

    /// Between blocks, a quadratic series is read exactly with its rate (Catmull–Rom reproduces
    /// quadratics), and the noise of independent block means is averaged by the weights: midway,
    /// `(1 + 81 + 81 + 1) / 256` of a block's variance; on a block, all of it. The variance's
    /// rate is its derivative.
    #[test]
    fn the_interpolated_skin_reads_a_quadratic_exactly_and_states_its_averaged_noise() {
        let f = |x: f64| Vector3::new(1.0 + 2.0 * x - 0.5 * x * x, -x * x, 3.0);
        let df = |x: f64| Vector3::new(2.0 - x, -2.0 * x, 0.0);
        let series: Vec<Option<Vector3<f64>>> = (0..10).map(|k| Some(f(k as f64))).collect();
        let motion = one_series(series, 4);
        for (delay, x) in [(0.005, 4.5), (0.0, 4.0), (0.0023, 4.23), (-0.007, 3.3)] {
            let read = motion.interpolated(0, 0, delay).unwrap();
            assert!(
                (read.value - f(x)).amax() < 1e-12,
                "{delay}: {}",
                read.value
            );
            // Per s: per block over the period.
            assert!(
                (read.rate - df(x) / 0.01).amax() < 1e-9,
                "{delay}: {}",
                read.rate
            );
            let h = 1e-7;
            let above = motion.interpolated(0, 0, delay + h).unwrap().variance;
            let below = motion.interpolated(0, 0, delay - h).unwrap().variance;
            let numeric = (above - below) / (2.0 * h);
            assert!((read.variance_rate - numeric).abs() < 1e-5 * (1.0 + numeric.abs()));
        }
        let midway = motion.interpolated(0, 0, 0.005).unwrap().variance;
        assert!((midway - 164.0 / 256.0).abs() < 1e-15, "{midway}");
        assert_eq!(motion.interpolated(0, 0, 0.0).unwrap().variance, 1.0);
        // A block the interpolation needs has no sample: nothing is read.
        let mut gap: Vec<Option<Vector3<f64>>> = (0..10).map(|k| Some(f(k as f64))).collect();
        gap[6] = None;
        assert!(one_series(gap, 4).interpolated(0, 0, 0.015).is_none());
    }
}
