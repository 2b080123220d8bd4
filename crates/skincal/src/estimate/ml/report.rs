//! What a limb's maximum-likelihood fit reports: the estimate, its SUs' uncertainty and
//! intrinsics, the readings left out, the noise components and the retries.

use super::*;

/// One SU's parameter uncertainty, relative to the previous SU of the chain (to the reference frame
/// for the first), at the zero pose: what the readings determine, and the directions they do not.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct SuUncertainty {
    /// The SU.
    pub su: String,
    /// Standard deviation of its position in the directions the readings determine, m (root of
    /// the trace of the 3×3 covariance with `undetermined_position` taken out).
    pub position_sd: f64,
    /// Standard deviation of its orientation about the axes the readings determine, rad.
    pub orientation_sd: f64,
    /// Directions (unit vectors in the previous SU's frame, the reference frame for the first)
    /// along which no reading determines its position: a gauge the estimate holds or a direction
    /// the information leaves free. Its standard deviation there is not finite.
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub undetermined_position: Vec<[f64; 3]>,
    /// Axes (unit vectors in its own frame) about which no reading determines its orientation.
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub undetermined_orientation: Vec<[f64; 3]>,
}

impl SuUncertainty {
    /// Whether some direction of its pose is not determined by the readings.
    pub fn is_partial(&self) -> bool {
        !self.undetermined_position.is_empty() || !self.undetermined_orientation.is_empty()
    }

    /// The undetermined directions in words, e.g. `position along (0.00, 0.00, 1.00); turn
    /// about (0.00, 0.00, 1.00)`; empty when every direction is determined.
    pub fn undetermined(&self) -> String {
        let list = |what: &str, v: &[[f64; 3]]| {
            v.iter()
                .map(|d| format!("{what} ({:.2}, {:.2}, {:.2})", d[0], d[1], d[2]))
                .collect::<Vec<_>>()
        };
        list("position along", &self.undetermined_position)
            .into_iter()
            .chain(list("turn about", &self.undetermined_orientation))
            .collect::<Vec<_>>()
            .join("; ")
    }
}

/// The covariance of a limb's free joint lines, for checks of the joints' geometry (`check-urdf`).
///
/// Each DoF has 4 components in its own joint frame (z along its axis, as the model's robot
/// description places it): the turns about the frame's x and y axes (rad) and the shifts along them
/// (m) that move the axis line; what follows the joint moves with it. Rows and columns run DoF by
/// DoF in [`JointCovariance::dofs`] order. DoFs held by the gauge (a limb's first) or taken from the
/// parent limb (a base path) are not listed.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct JointCovariance {
    /// The DoFs whose lines were fitted.
    pub dofs: Vec<String>,
    /// The `4·n × 4·n` covariance, row by row.
    pub matrix: Vec<Vec<f64>>,
}

impl JointCovariance {
    /// Component names, in order.
    pub const COMPONENTS: [&'static str; 4] = ["tilt_x", "tilt_y", "shift_x", "shift_y"];
}

/// Readings of one SU left out of the fit as wild: their residual was more than
/// 6 noise standard deviations (in norm) from the fit of everything else.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct SuRejected {
    /// The SU.
    pub su: String,
    /// Static readings left out.
    pub static_readings: usize,
    /// Dynamic readings left out.
    pub dynamic_readings: usize,
    /// Readings of this SU in the fit, all kinds (for the share).
    pub readings: usize,
}

/// The readings left out, per SU that has any.
pub(super) fn rejected_counts(readings: &Readings, names: &[String]) -> Vec<SuRejected> {
    names
        .iter()
        .enumerate()
        .filter_map(|(u, su)| {
            let (mut s, mut d, mut n) = (0, 0, 0);
            for (p, pose) in readings.rejected.iter().enumerate() {
                for (j, &r) in pose[u].iter().enumerate() {
                    let missing = readings.missing.get(p).is_some_and(|m| m[u][j]);
                    if missing {
                        continue;
                    }
                    n += 1;
                    match (r, j) {
                        (true, 0) => s += 1,
                        (true, _) => d += 1,
                        _ => {}
                    }
                }
            }
            (s + d > 0).then(|| SuRejected {
                su: su.clone(),
                static_readings: s,
                dynamic_readings: d,
                readings: n,
            })
        })
        .collect()
}

/// One SU's estimated accelerometer intrinsics.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct SuIntrinsics {
    /// The SU.
    pub su: String,
    /// The estimate (components not estimated are 0).
    pub value: Intrinsics,
    /// Standard deviation of each component (0 where not estimated).
    pub sd: Intrinsics,
    /// Components the readings do not determine (e.g. the bias along an axis that gravity never
    /// turns about): held near the ideal sensor's value by the prior, with about the prior's
    /// standard deviation.
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub held: Vec<String>,
}

/// A parameter direction the data cannot determine.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Unobservable {
    /// Relative singular value of the whitened Jacobian.
    pub singular_value: f64,
    /// The parameters that make up the direction, largest share first.
    pub parameters: Vec<String>,
}

/// A chain in the paper's DH+2 form (Fig. 6).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct DhTable {
    /// DoF-to-DoF rows `k → k+1`.
    pub dof_dof: Vec<crate::estimate::DhRow>,
    /// DoF-to-SU rows.
    pub dof_su: Vec<crate::estimate::SuRow>,
    /// The standard deviation of every value of `dof_dof` (from the parameter covariance).
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub dof_dof_sd: Vec<crate::estimate::DhRow>,
    /// The standard deviation of every value of `dof_su`.
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub dof_su_sd: Vec<crate::estimate::SuRow>,
}

/// How well one order of a multi-DoF joint's DoFs explains the accelerations.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct OrderMisfit {
    /// DoFs from the parent segment outwards.
    pub dofs: Vec<String>,
    /// Scatter of the accelerations about the closed-form axis model (m², accelerations divided
    /// by α); the order along the chain has the smallest, near the noise floor.
    pub misfit: f64,
}

/// The order found for the DoFs of a joint that has several.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct JointOrder {
    /// The joint.
    pub joint: String,
    /// Its DoFs from the parent segment outwards.
    pub dofs: Vec<String>,
    /// Every order tried, best first.
    pub alternatives: Vec<OrderMisfit>,
}

/// What a limb's time-domain fit used and found beside the kinematics.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct MotionFit {
    /// Blocks of the motion record fitted.
    pub blocks: usize,
    /// How late the skin's stamps run behind the joint states', s.
    pub skin_delay: f64,
    /// Its standard deviation, s.
    pub skin_delay_sd: f64,
    /// The residual of the blocks in which the limb stood still (gravity and the sensors alone,
    /// against the skin's own noise), and its band at their size: a fit is converged only within
    /// it. `None`: the record has no such block.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub at_rest: Option<RestResidual>,
}

/// The residual of a time-domain fit's blocks at rest.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct RestResidual {
    /// The RMS whitened residual per component (1: the skin's noise).
    pub residual_ratio: f64,
    /// Residual components counted.
    pub rows: usize,
    /// The band of a fit at the noise level, at that size.
    pub band: Option<ResidualBand>,
}

/// A larger intrinsics model against the smaller one before it, fitted to the same readings: the
/// nested F test, `F = ((χ²_small − χ²_large) / k) / (χ²_large / ν)` with `k` the added
/// parameters and `ν` the large model's residual degrees of freedom, whose scale does not depend
/// on the noise assumed. The larger model is taken when `F` lies 5 standard deviations beyond
/// what the smaller one explains (`z` > 5 in Paulson's normal approximation, p ≈ 3·10⁻⁷): a
/// real robot's readings are never exactly the model's, and ideal sensors fitted a bias at
/// z = 3.7 for the smallest misfit (a UR5, clean, where it cost 60 % of the held-out static
/// accuracy), while real ones ask for theirs at z = 16 and beyond.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct IntrinsicsTest {
    /// The larger model.
    pub model: IntrinsicsModel,
    /// The model it was tested against.
    pub against: IntrinsicsModel,
    /// Parameters it adds.
    pub parameters: usize,
    /// Residual degrees of freedom of the larger model.
    pub degrees_of_freedom: usize,
    /// χ² of the smaller and of the larger model.
    #[serde(default)]
    pub chi2: [f64; 2],
    /// How many times more information the rows seem to hold along the added parameters than
    /// they do (a filtered motion record's correlated samples, [`crate::motion::SkinFilter::overcount`];
    /// 1 for independent readings): `f` is divided by it.
    #[serde(default = "one")]
    pub overcount: f64,
    /// The F statistic.
    pub f: f64,
    /// Paulson's normal deviate of `f` (≈ N(0, 1) when the larger model adds nothing).
    pub z: f64,
    /// Whether the larger model was taken.
    pub taken: bool,
}

/// The normal deviate that [`IntrinsicsTest`] takes a larger model beyond.
pub const INTRINSICS_TEST_Z: f64 = 5.0;

/// The tests of several limbs of one skin pooled step by step (their χ², parameters and degrees
/// of freedom summed: one skin, one sensor model), and the model they choose: the largest reached
/// by tests that are all taken. `None` when no limb has a test.
pub fn pooled_intrinsics<'a>(
    tests: impl IntoIterator<Item = &'a [IntrinsicsTest]>,
) -> Option<(IntrinsicsModel, Vec<IntrinsicsTest>)> {
    // Per step: the models, χ², parameters, degrees of freedom and the overcounts weighed by
    // the degrees of freedom.
    type Step = (
        IntrinsicsModel,
        IntrinsicsModel,
        [f64; 2],
        usize,
        usize,
        f64,
    );
    let mut steps: Vec<Step> = Vec::new();
    for limb in tests {
        for (i, t) in limb.iter().enumerate() {
            if steps.len() <= i {
                steps.push((t.model, t.against, [0.0; 2], 0, 0, 0.0));
            }
            let step = &mut steps[i];
            if step.0 != t.model {
                continue;
            }
            step.2[0] += t.chi2[0];
            step.2[1] += t.chi2[1];
            step.3 += t.parameters;
            step.4 += t.degrees_of_freedom;
            step.5 += t.overcount * t.degrees_of_freedom as f64;
        }
    }
    let first = steps.first()?.1;
    let pooled: Vec<IntrinsicsTest> = steps
        .into_iter()
        .map(|(model, against, chi2, k, nu, weighed)| {
            let overcount = if nu > 0 { weighed / nu as f64 } else { 1.0 };
            IntrinsicsTest::new(model, against, chi2, k, nu, overcount)
        })
        .collect();
    let chosen = pooled
        .iter()
        .take_while(|t| t.taken)
        .last()
        .map_or(first, |t| t.model);
    Some((chosen, pooled))
}

impl IntrinsicsTest {
    /// The test of `model` against `against` from their χ² (`[small, large]`), the parameters
    /// `model` adds, its residual degrees of freedom and the rows' `overcount` (1 for
    /// independent rows).
    pub fn new(
        model: IntrinsicsModel,
        against: IntrinsicsModel,
        [small, large]: [f64; 2],
        parameters: usize,
        degrees_of_freedom: usize,
        overcount: f64,
    ) -> Self {
        let (k, nu) = (parameters.max(1) as f64, degrees_of_freedom.max(1) as f64);
        let overcount = overcount.max(1.0);
        let f = ((small - large).max(0.0) / k) / (large / nu).max(1e-300) / overcount;
        // Paulson (1942): F^(1/3) is nearly normal.
        let (a, b) = (2.0 / (9.0 * k), 2.0 / (9.0 * nu / overcount));
        let root = f.cbrt();
        let z = ((1.0 - b) * root - (1.0 - a)) / (a + root * root * b).sqrt();
        Self {
            model,
            against,
            parameters,
            degrees_of_freedom,
            chi2: [small, large],
            overcount,
            f,
            z,
            taken: z > INTRINSICS_TEST_Z,
        }
    }
}

/// The noise of a limb's static and dynamic readings, estimated apart (two variance components)
/// from the residuals of a fit that weighed every reading alike: a dynamic reading is a difference
/// of samples, √2 times a static one's noise and more.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct NoiseComponents {
    /// Standard deviation of a static reading's component, m/s².
    pub static_sd: f64,
    /// Standard deviation of a dynamic reading's component, m/s².
    pub dynamic_sd: f64,
}

/// The maximum-likelihood estimate of one limb.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct MlChainEstimate {
    /// The limb, the DoFs of every joint in the order found.
    pub chain: LimbChain,
    /// For every joint of several DoFs: the order found and how well each order fits.
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub joint_orders: Vec<JointOrder>,
    /// The estimated limb as a robot description (reference = the first DoF's joint frame; the
    /// base path's joints, for a limb on a branching segment, as the parent limb estimated them).
    pub robot: RobotFile,
    /// Gravity in the reference frame, m/s².
    pub gravity: [f64; 3],
    /// Gravity in the reference frame in base orientations 1, 2, … of the training poses, m/s²
    /// (empty: every pose in the usual one).
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub other_gravities: Vec<[f64; 3]>,
    /// Residual RMS relative to the noise standard deviation (≈ 1 at the noise limit).
    pub residual_ratio: f64,
    /// Estimated noise standard deviation, m/s² (with `reading_sd`: the residual in units of the
    /// configured `noise_sd`).
    pub noise_sd_estimate: f64,
    /// Whether every reading was weighted by its own standard deviation (from the measurement
    /// set) rather than by the configured noise.
    #[serde(default)]
    pub reading_sd: bool,
    /// Whether the residual is at the noise level: within its band at the data's size
    /// ([`ResidualBand`]; a fit on a motion record: its blocks at rest within theirs, and the
    /// whole within `MlConfig::converged_ratio`, what the joint states' derivatives leave
    /// unmatched in motion being no noise of the skin's).
    pub converged: bool,
    /// The band of the residual ratio at the noise level, at the fit's size (readings fits).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub residual_band: Option<ResidualBand>,
    /// The gauge: parameters held, or directions the data leave free.
    pub fixed: Vec<String>,
    /// Directions the data do not determine.
    pub unobservable: Vec<Unobservable>,
    /// Per SU: standard deviations.
    pub uncertainty: Vec<SuUncertainty>,
    /// The covariance of the fitted joint lines.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub joint_covariance: Option<JointCovariance>,
    /// Per SU, in [`LimbChain::sus`] order: the RMS of its residuals relative to the noise (≈ 1
    /// for an SU the model explains; far above the others: a broken or loose SU).
    #[serde(default)]
    pub su_residual_ratio: Vec<f64>,
    /// Per SU with wild readings (glitches): how many were left out of the fit.
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub rejected: Vec<SuRejected>,
    /// The limb's DoFs whose dynamic readings the set lacks, with the number of training poses
    /// that lack them (a DoF lacking them in every pose is placed from gravity alone).
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub missing_excitations: Vec<(String, usize)>,
    /// Per SU: the accelerometer intrinsics estimated with the kinematics (empty when none are).
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub intrinsics: Vec<SuIntrinsics>,
    /// The intrinsics fitted (with `select_intrinsics`, the model the data chose).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub intrinsics_model: Option<IntrinsicsModel>,
    /// With `select_intrinsics`: each larger model against the one before it, in order.
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub intrinsics_tests: Vec<IntrinsicsTest>,
    /// The limbs of the body whose tests were left out of the pooled [`Self::intrinsics_tests`]:
    /// their fits ended off the noise level, where a misfit, not the sensors, is what larger
    /// sensor models would explain.
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub intrinsics_left_out: Vec<String>,
    /// Where the set gives no reading its own deviation: the static and the dynamic readings'
    /// noise estimated apart from the residuals, which weighed them in the fit.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub noise_components: Option<NoiseComponents>,
    /// Other orders of joints' DoFs tried because the first fit was not at the noise level, and
    /// how each fitted.
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub retries: Vec<String>,
    /// The same limb in the paper's DH+2 form (only for a paper-style chain: single-DoF joints,
    /// one SU per segment).
    pub dh: Option<DhTable>,
    /// The time-domain fit's share: the blocks of the motion record fitted, and how late the skin's
    /// stamps run behind the joint states'. `None`: fitted on the measurement set's readings.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub motion: Option<MotionFit>,
    /// LM iterations, all solves.
    pub iterations: usize,
    /// Wall time, s. Not written to files: a model file is the same for the same data, whichever
    /// run or machine made it.
    #[serde(default, skip_serializing)]
    pub seconds: f64,
    /// The estimate in the estimator's own chart (not written to files).
    #[serde(skip)]
    pub state: Option<ChainState>,
    /// The search's other end states whose readings fit within [`RUNNER_UP_MARGIN`] of the one
    /// kept: readings that cannot tell them apart (static readings alone, a record's quiet
    /// moments) leave the motion to choose (not written to files).
    #[serde(skip)]
    pub runner_ups: Vec<ChainState>,
    /// What its final fit solved (not written to files; no part of the estimate's value).
    #[serde(skip)]
    pub(crate) problem: FitProblem,
}

/// What a limb's final fit solved, kept with its estimate for the fit of its whole tree; any two
/// are equal (it is how the estimate was reached, not what it is).
#[derive(Clone, Default)]
pub(crate) struct FitProblem(pub(super) Option<std::sync::Arc<FinalProblem>>);

impl PartialEq for FitProblem {
    fn eq(&self, _: &Self) -> bool {
        true
    }
}

impl std::fmt::Debug for FitProblem {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(if self.0.is_some() {
            "FitProblem(kept)"
        } else {
            "FitProblem(none)"
        })
    }
}

impl MlChainEstimate {
    /// This estimate, a refit from `search`'s state, with `search`'s record kept: the joint
    /// orders tried, the retries, and the iterations and time of both.
    pub(crate) fn after(self, search: MlChainEstimate) -> Self {
        Self {
            joint_orders: search.joint_orders,
            retries: search.retries,
            iterations: search.iterations + self.iterations,
            seconds: search.seconds + self.seconds,
            ..self
        }
    }

    /// The estimated limb as a robot.
    pub fn to_robot(&self) -> Robot {
        self.robot
            .build()
            .expect("an estimated chain is a valid robot")
    }
}

/// 1, the default of a count that files written before it lack.
fn one() -> f64 {
    1.0
}
