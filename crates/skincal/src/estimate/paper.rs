//! The paper's estimator (Section II-C.3–4), implemented faithfully as the baseline.
//!
//! **Error function** (eqs. 14–17), with accelerations in g:
//!
//! ```text
//! e_T = e1 + e2
//! e1  = Σ_p | R_ref←SU_N(q_p) · g_p − (1/P) Σ_p' R_ref←SU_N(q_p') · g_p' |²
//! e2  = Σ_p Σ_d | a_model(N, d, p) − a_train(N, d, p) |²,  d over the (up to) three DoFs before SU N
//! ```
//!
//! where `g_p` is SU N's static reading in pose `p` and `a` its dynamic acceleration for DoF `d`'s
//! pattern (eq. 8; the model's peak tangential acceleration, which eq. 9 approximates numerically).
//! Eq. 17's index range reads `d = N−3…N`, the text says three DoFs; three are used.
//!
//! **Progressive estimation** (Fig. 4): step `N` fits only the new DoF-to-DoF row `(N−1 → N)` and the
//! DoF-to-SU row of SU `N`, re-using every row estimated before: 4 parameters in step 1 (the first
//! DoF-to-SU row's `θ0` and `d` are arbitrary and fixed at 0), 8 in step 2 (the first DoF-to-DoF row's
//! `θ0` and `d` are arbitrary and fixed at 0), 10 from step 3 on.
//!
//! **Optimiser**: NLopt's MLSL with low-discrepancy sampling (`G_MLSL_LDS`) and Nelder–Mead
//! (`LN_NELDERMEAD`) as local optimiser, bounds of eq. 18 (`θ0, α, θ_acc ∈ [−π, π]`, `d, d_acc ∈ [−1, 1]`,
//! `a ∈ [0, 1]`) with the start in their middle, the global stop `e_T ≤ e_stop`, the local stop
//! `Δe_T / e_T ≤ ftol_rel`, and a cap on evaluations. NLopt's random numbers are seeded per step, so a
//! run repeats exactly.

use std::f64::consts::PI;
use std::time::Instant;

use nalgebra::Vector3;
use serde::{Deserialize, Serialize};
use skincal_nlopt::{Algorithm, Optimizer};

use super::{
    chain_in_listed_order, dh_chain_robot, serial_chains, DhRow, EstimateError, LimbChain,
    LimbData, SuRow,
};
use crate::explore::Structure;
use crate::measurements::MeasurementSet;
use crate::model::forward_kinematics;
use crate::model::sensor::{peak_dynamic_accelerations_at, STANDARD_GRAVITY};
use crate::model::Robot;

/// Settings of the paper's estimator.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct PaperConfig {
    /// Global stop: a step ends as soon as `e_T ≤ e_stop` (g²; paper: 0.1).
    pub e_stop: f64,
    /// Local relative stop of Nelder–Mead (paper: 1e-6).
    pub ftol_rel: f64,
    /// Cap on error-function evaluations per step.
    pub max_evaluations: u32,
    /// Seed of NLopt's random numbers.
    pub seed: u64,
    /// How many DoFs before the SU are excited in e2 (paper: 3).
    pub excited_dofs: usize,
}

impl Default for PaperConfig {
    fn default() -> Self {
        Self {
            e_stop: 0.1,
            ftol_rel: 1e-6,
            max_evaluations: 100_000,
            seed: 1,
            excited_dofs: 3,
        }
    }
}

/// What one progressive step did (the paper's "Optimization Steps" table).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct StepReport {
    /// Step number `N` (1-based): it fits SU `N`.
    pub step: usize,
    /// The SU it fits.
    pub su: String,
    /// The DoFs whose patterns enter e2.
    pub excited: Vec<String>,
    /// The parameters it estimates.
    pub parameters: Vec<String>,
    /// Error-function evaluations.
    pub evaluations: usize,
    /// Wall time, s.
    pub seconds: f64,
    /// Final `e_T`, g².
    pub e_t: f64,
    /// Whether `e_T ≤ e_stop`.
    pub converged: bool,
    /// NLopt's termination reason.
    pub stop: String,
}

/// The paper's estimate of one chain: its DH table (Fig. 6) and how the steps went.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct PaperChainEstimate {
    /// The chain: one DoF and one SU per joint.
    pub chain: LimbChain,
    /// DoF-to-DoF rows `k → k+1`.
    pub dof_dof: Vec<DhRow>,
    /// DoF-to-SU rows, one per SU.
    pub dof_su: Vec<SuRow>,
    /// Parameters fixed because the data cannot determine them.
    pub fixed: Vec<String>,
    /// The steps.
    pub steps: Vec<StepReport>,
    /// The settings used.
    pub config: PaperConfig,
}

impl PaperChainEstimate {
    /// Whether every step reached `e_T ≤ e_stop`.
    pub fn converged(&self) -> bool {
        self.steps.iter().all(|s| s.converged)
    }

    /// The estimated chain as a robot (names as in the chain).
    pub fn robot(&self) -> Robot {
        let sus: Vec<(usize, SuRow)> = self.dof_su.iter().copied().enumerate().collect();
        dh_chain_robot(&self.chain, self.chain.dofs().len(), &self.dof_dof, &sus)
    }

    /// Total evaluations over all steps.
    pub fn evaluations(&self) -> usize {
        self.steps.iter().map(|s| s.evaluations).sum()
    }

    /// Total wall time over all steps, s.
    pub fn seconds(&self) -> f64 {
        self.steps.iter().map(|s| s.seconds).sum()
    }
}

/// What `model-paper.json` holds: the paper's estimate of every chain of a set.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct PaperModel {
    /// `skincal-model-paper`.
    pub format: String,
    /// The file format's version (1).
    pub version: u32,
    /// `paper`.
    pub method: String,
    /// One estimate per chain, in the structure's order.
    pub limbs: Vec<PaperChainEstimate>,
}

impl PaperModel {
    /// The file of these chain estimates.
    pub fn new(limbs: Vec<PaperChainEstimate>) -> Self {
        Self {
            format: "skincal-model-paper".into(),
            version: 1,
            method: "paper".into(),
            limbs,
        }
    }
}

/// The paper's serial chains of a set: those of its structure, or, without one, its DoFs in their
/// listed order as one chain. `limb` keeps the chain of that name alone (an error lists the others).
pub fn chains(
    set: &MeasurementSet,
    structure: Option<&Structure>,
    limb: Option<&str>,
) -> Result<Vec<LimbChain>, EstimateError> {
    let mut chains = match structure {
        Some(s) => serial_chains(s)?,
        None => vec![chain_in_listed_order(set)?],
    };
    if let Some(limb) = limb {
        let known = chains
            .iter()
            .map(|c| c.name.clone())
            .collect::<Vec<_>>()
            .join(", ");
        chains.retain(|c| c.name == limb);
        if chains.is_empty() {
            return Err(EstimateError::UnknownLimb {
                limb: limb.into(),
                known,
            });
        }
    }
    Ok(chains)
}

/// The paper's estimate of every chain of [`chains`], one after another; `progress(chain, done,
/// total)` is called before each and after the last.
pub fn estimate_chains(
    set: &MeasurementSet,
    chains: &[LimbChain],
    config: &PaperConfig,
    progress: &mut dyn FnMut(&str, usize, usize),
) -> Result<PaperModel, EstimateError> {
    let mut limbs = Vec::with_capacity(chains.len());
    for (i, chain) in chains.iter().enumerate() {
        progress(&chain.name, i, chains.len());
        limbs.push(estimate_chain(&LimbData::new(set, chain)?, config)?);
    }
    progress("", chains.len(), chains.len());
    Ok(PaperModel::new(limbs))
}

/// The paper's `e_T` of step `n` (0-based SU index) for the full step parameter vector
/// (DoF-to-DoF rows `0…n−1` then SU `n`'s row, as laid out by [`dh_chain_robot`]).
struct StepProblem<'a> {
    data: &'a LimbData,
    robot: Robot,
    n: usize,
    excited: std::ops::Range<usize>,
}

impl StepProblem<'_> {
    fn error(&self, parameters: &[f64]) -> f64 {
        let g = STANDARD_GRAVITY;
        let model = &self.robot.model;
        let mut rotated = Vec::with_capacity(self.data.poses());
        let mut e2 = 0.0;
        for p in 0..self.data.poses() {
            let q = &self.data.q[p][..=self.n];
            let k = forward_kinematics(model, parameters, q);
            rotated.push(k.sus[0].rotation * (self.data.statics[p][self.n] / g));
            for d in self.excited.clone() {
                let model_a =
                    peak_dynamic_accelerations_at(model, &k, d, &self.data.pattern)[0] / g;
                e2 += (model_a - self.data.dynamics[p][self.n][d] / g).norm_squared();
            }
        }
        let mean: Vector3<f64> = rotated.iter().sum::<Vector3<f64>>() / rotated.len() as f64;
        let e1: f64 = rotated.iter().map(|r| (r - mean).norm_squared()).sum();
        e1 + e2
    }
}

const ROW: [&str; 4] = ["theta0", "d", "a", "alpha"];
const SU_ROW: [&str; 6] = ["theta0", "d", "a", "alpha", "theta_acc", "d_acc"];

fn bounds(name: &str) -> (f64, f64) {
    match name {
        "d" | "d_acc" => (-1.0, 1.0),
        "a" => (0.0, 1.0),
        _ => (-PI, PI),
    }
}

/// Estimates one chain progressively with the paper's method.
///
/// ```
/// use skincal::estimate::{paper, LimbChain, LimbData};
/// use skincal::model::presets;
/// use skincal::sim::{simulate, SimulationConfig};
///
/// let robot = presets::find("paper-7dof").unwrap().robot().unwrap();
/// let set = simulate(&robot, &SimulationConfig::default()).unwrap().measurements;
/// let chain = LimbChain::serial("arm", &robot.model.dof_names(), &robot.model.su_names()).unwrap();
/// let data = LimbData::new(&set, &chain).unwrap();
/// let estimate = paper::estimate_chain(&data, &paper::PaperConfig::default()).unwrap();
/// assert_eq!(estimate.steps.len(), 7);
/// assert!(estimate.steps.iter().all(|s| s.e_t <= 0.1)); // this data set: every step meets e_stop
/// ```
pub fn estimate_chain(
    data: &LimbData,
    config: &PaperConfig,
) -> Result<PaperChainEstimate, EstimateError> {
    validate(config)?;
    // The paper's method has one gravity: poses recorded in another base orientation are left out.
    let usual;
    let data = if data.orientations() > 1 {
        usual = data.usual_orientation();
        &usual
    } else {
        data
    };
    let chain = papers_chain(data)?;
    let n_dofs = chain.dofs().len();
    let largest = match n_dofs {
        1 => 4,
        2 => 8,
        _ => 10,
    };
    if data.poses() < largest {
        return Err(EstimateError::TooFewPoses {
            poses: data.poses(),
            parameters: largest,
        });
    }
    let mut dof_dof: Vec<DhRow> = Vec::new();
    let mut dof_su: Vec<SuRow> = Vec::new();
    let mut steps = Vec::new();
    for n in 0..n_dofs {
        let (report, v) = Step::new(chain, n).run(data, &dof_dof, config)?;
        if n > 0 {
            dof_dof.push(DhRow::from_values(&v[4 * (n - 1)..]));
        }
        dof_su.push(SuRow::from_values(&v[v.len() - 6..]));
        steps.push(report);
    }
    Ok(PaperChainEstimate {
        chain: chain.clone(),
        dof_dof,
        dof_su,
        fixed: gauge_of(chain),
        steps,
        config: *config,
    })
}

/// The chain of `data` as the paper's method takes it: one revolute DoF and one SU per segment,
/// from the static reference, every DoF's dynamic readings in every pose.
fn papers_chain(data: &LimbData) -> Result<&LimbChain, EstimateError> {
    let (chain, limb) = (&data.chain, &data.chain.name);
    if !chain.is_serial() {
        return Err(EstimateError::UnsupportedLimb {
            limb: limb.clone(),
            reason:
                "the paper's estimator takes a serial chain from the static reference with one \
                     DoF and one SU per segment: use the maximum-likelihood estimator (the default)"
                    .into(),
        });
    }
    if let Some(d) = data.chain.prismatic.first() {
        return Err(EstimateError::UnsupportedLimb {
            limb: limb.clone(),
            reason: format!(
                "DoF `{d}` is prismatic, and the paper's estimator models revolute DoFs only: use \
                 the maximum-likelihood estimator (the default)"
            ),
        });
    }
    let dofs = chain.dofs();
    for p in 0..data.poses() {
        if let Some(k) = (0..dofs.len()).find(|&k| data.is_missing(p, k, k)) {
            return Err(EstimateError::MissingDynamic {
                pose: p,
                dof: dofs[k].clone(),
                limb: limb.clone(),
            });
        }
    }
    Ok(chain)
}

/// Step `n + 1` of the progressive estimation (Fig. 4): which entries of the new DoF-to-DoF row
/// and of SU `n`'s row are free, their names and bounds.
struct Step<'a> {
    chain: &'a LimbChain,
    n: usize,
    row_free: &'static [&'static str],
    su_free: &'static [&'static str],
    names: Vec<String>,
    lower: Vec<f64>,
    upper: Vec<f64>,
}

impl<'a> Step<'a> {
    fn new(chain: &'a LimbChain, n: usize) -> Self {
        let (dofs, sus) = (chain.dofs(), chain.sus());
        let row_free: &[&str] = match n {
            0 => &[],
            1 => &["a", "alpha"],
            _ => &ROW,
        };
        let su_free: &[&str] = if n == 0 {
            &["a", "alpha", "theta_acc", "d_acc"]
        } else {
            &SU_ROW
        };
        let mut names: Vec<String> = Vec::new();
        let (mut lower, mut upper) = (Vec::new(), Vec::new());
        for (prefix, free) in [
            (
                format!(
                    "{}-{}",
                    dofs.get(n.wrapping_sub(1)).map_or("", |s| s),
                    dofs[n]
                ),
                row_free,
            ),
            (format!("{}-{}", dofs[n], sus[n]), su_free),
        ] {
            for &p in free {
                names.push(format!("{prefix}.{p}"));
                let (lo, hi) = bounds(p);
                lower.push(lo);
                upper.push(hi);
            }
        }
        Self {
            chain,
            n,
            row_free,
            su_free,
            names,
            lower,
            upper,
        }
    }

    /// The chain's parameters up to SU `n`: the rows found before, then this step's rows with the
    /// free entries from `x` and the others 0.
    fn assemble(&self, before: &[f64], x: &[f64]) -> Vec<f64> {
        let mut v = before.to_vec();
        let mut it = x.iter().copied();
        if self.n > 0 {
            for p in ROW {
                v.push(if self.row_free.contains(&p) {
                    it.next().expect("free")
                } else {
                    0.0
                });
            }
        }
        for p in SU_ROW {
            v.push(if self.su_free.contains(&p) {
                it.next().expect("free")
            } else {
                0.0
            });
        }
        v
    }

    /// Minimises the step's error from the middle of its bounds, with the rows of `dof_dof`
    /// fixed: the report and the chain's parameters up to SU `n`.
    fn run(
        self,
        data: &LimbData,
        dof_dof: &[DhRow],
        config: &PaperConfig,
    ) -> Result<(StepReport, Vec<f64>), EstimateError> {
        let (chain, n) = (self.chain, self.n);
        let (dofs, sus) = (chain.dofs(), chain.sus());
        let excited = n + 1 - config.excited_dofs.min(n + 1)..n + 1;
        let placeholder = SuRow {
            theta0: 0.0,
            d: 0.0,
            a: 0.0,
            alpha: 0.0,
            theta_acc: 0.0,
            d_acc: 0.0,
        };
        let mut rows = dof_dof.to_vec();
        if n > 0 {
            rows.push(DhRow {
                theta0: 0.0,
                d: 0.0,
                a: 0.0,
                alpha: 0.0,
            });
        }
        let problem = StepProblem {
            data,
            robot: dh_chain_robot(chain, n + 1, &rows, &[(n, placeholder)]),
            n,
            excited: excited.clone(),
        };
        let before: Vec<f64> = dof_dof.iter().flat_map(|r| r.values()).collect();
        let mut x: Vec<f64> = self
            .lower
            .iter()
            .zip(&self.upper)
            .map(|(lo, hi)| 0.5 * (lo + hi))
            .collect();
        let started = Instant::now();
        let mut evaluations = 0usize;
        let stop = minimize_step(
            config,
            config.seed.wrapping_add(n as u64),
            (&self.lower, &self.upper),
            &mut x,
            |x| {
                evaluations += 1;
                problem.error(&self.assemble(&before, x))
            },
        )?;
        let seconds = started.elapsed().as_secs_f64();
        let v = self.assemble(&before, &x);
        let e_t = problem.error(&v);
        if !e_t.is_finite() || v.iter().any(|p| !p.is_finite()) {
            return Err(EstimateError::NotFinite {
                limb: chain.name.clone(),
                reason: format!("step {} (SU {}): e_T = {}", n + 1, sus[n], e_t),
            });
        }
        let report = StepReport {
            step: n + 1,
            su: sus[n].clone(),
            excited: excited.map(|d| dofs[d].clone()).collect(),
            parameters: self.names,
            evaluations,
            seconds,
            e_t,
            converged: e_t <= config.e_stop,
            stop,
        };
        Ok((report, v))
    }
}

/// The entries fixed at 0 because no reading tells them: the first SU row's and the first
/// DoF-to-DoF row's `θ0` and `d`.
fn gauge_of(chain: &LimbChain) -> Vec<String> {
    let (dofs, sus) = (chain.dofs(), chain.sus());
    let mut fixed = vec![
        format!("{}-{}.theta0", dofs[0], sus[0]),
        format!("{}-{}.d", dofs[0], sus[0]),
    ];
    if dofs.len() > 1 {
        fixed.extend([
            format!("{}-{}.theta0", dofs[0], dofs[1]),
            format!("{}-{}.d", dofs[0], dofs[1]),
        ]);
    }
    fixed
}

fn validate(config: &PaperConfig) -> Result<(), EstimateError> {
    let bad = |setting, reason: String| Err(EstimateError::InvalidSetting { setting, reason });
    if !(config.e_stop.is_finite() && config.e_stop >= 0.0) {
        return bad(
            "e_stop",
            format!("{} must be zero or positive", config.e_stop),
        );
    }
    if !(config.ftol_rel.is_finite() && config.ftol_rel > 0.0) {
        return bad("ftol_rel", format!("{} must be positive", config.ftol_rel));
    }
    if config.max_evaluations == 0 {
        return bad("max_evaluations", "must be at least 1".into());
    }
    if config.excited_dofs == 0 {
        return bad("excited_dofs", "must be at least 1".into());
    }
    Ok(())
}

/// One progressive step's search, as the paper runs it: NLopt's MLSL-LDS over the box `bounds`
/// with Nelder–Mead as the local optimiser, stopped at `e_T ≤ e_stop` or after the evaluation cap,
/// NLopt's random numbers seeded with `seed`. Leaves the best point in `x` and returns NLopt's stop
/// reason (its failure codes, such as a round-off limit, are reasons too: the point is still its best).
fn minimize_step(
    config: &PaperConfig,
    seed: u64,
    (lower, upper): (&[f64], &[f64]),
    x: &mut [f64],
    error: impl FnMut(&[f64]) -> f64,
) -> Result<String, EstimateError> {
    let refused = |e: skincal_nlopt::Error| EstimateError::InvalidSetting {
        setting: "nlopt",
        reason: format!("NLopt refused the bounds or stop criteria: {e}"),
    };
    skincal_nlopt::seed(seed);
    let mut local = Optimizer::new(Algorithm::NelderMead, x.len()).map_err(refused)?;
    local.set_ftol_rel(config.ftol_rel).map_err(refused)?;
    let mut global = Optimizer::new(Algorithm::MlslLds, x.len()).map_err(refused)?;
    global.set_bounds(lower, upper).map_err(refused)?;
    global.set_stopval(config.e_stop).map_err(refused)?;
    global
        .set_maxeval(config.max_evaluations as usize)
        .map_err(refused)?;
    global.set_local_optimizer(&local).map_err(refused)?;
    Ok(match global.minimize(x, error) {
        Ok(minimum) => format!("{:?}", minimum.stop),
        Err(failure) => format!("{:?}", failure.error.kind),
    })
}
