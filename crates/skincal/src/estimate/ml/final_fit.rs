//! The final fit of a limb over every reading: the gauge, the problem kept for the tree's joint
//! fit, the precision of its estimate, and the fit with the sensors' intrinsics.

use super::report::FitProblem;
use super::*;

/// The SU whose turn about and shift along the first axis are held in a limb's final fit: the
/// first, where the limb starts at the reference with a joint of one DoF (after a joint of several,
/// that freedom is left to the damping, not to a parameter).
pub(super) fn gauge_su(data: &LimbData, base: Option<&LimbBase>) -> Option<usize> {
    let first = &spans(data)[data.chain.base_joints];
    (base.is_none() && first.k0 == first.k1).then_some(0)
}

/// The mirror image of a limb's state about its vertical first axis: gravity reversed, and what
/// sits on the first segment (the next joint's frame, its SUs) turned half a turn about the
/// reference's x axis. In every pose each SU reads gravity as before, but the first DoF turns
/// the other way.
pub(super) fn mirrored(state: &ChainState, su_segment: &[usize]) -> ChainState {
    let half_turn = Isometry3::from_parts(
        nalgebra::Translation3::identity(),
        UnitQuaternion::from_axis_angle(&Vector3::x_axis(), std::f64::consts::PI),
    );
    let mut out = state.clone();
    out.gravity = -state.gravity;
    for g in &mut out.other_gravities {
        *g = half_turn.rotation * *g;
    }
    if let Some(j) = out.joints.get_mut(1) {
        *j = half_turn * *j;
    }
    for (su, _) in out.sus.iter_mut().zip(su_segment).filter(|(_, &s)| s == 1) {
        *su = half_turn * *su;
    }
    out
}

/// The final fit of a limb from `state`, and all that is reported of it: residual, covariance,
/// what is unobservable, intrinsics. `readings`: the limb's, screened; `vertical`: gravity is held
/// along the first axis.
#[allow(clippy::too_many_arguments)]
pub(super) fn final_fit(
    data: &LimbData,
    base: Option<&LimbBase>,
    readings: Readings,
    state: ChainState,
    vertical: bool,
    mut iterations: usize,
    started: Instant,
    config: &MlConfig,
) -> Result<MlChainEstimate, EstimateError> {
    let layout = Layout::of(data);
    // The whole limb at once: the kinematics, then with the accelerometer intrinsics; glitches
    // left out; the static and dynamic noise weighed apart.
    let gauge_su = gauge_su(data, base);
    let final_spec = |intrinsics: IntrinsicsModel| {
        let gauge = Gauge {
            base_dofs: data.chain.base_dofs(),
            base: base.is_some(),
            su: gauge_su,
            vertical,
        };
        final_spec(
            &layout,
            &gauge,
            readings.motion.is_some(),
            intrinsics,
            config,
        )
    };
    let (solved, spec, intrinsics_model, intrinsics_tests, its) =
        fit_with_intrinsics(state, &layout, &readings, final_spec, config);
    iterations += its;
    let (solved, readings, its) = leave_out_glitches(solved, &layout, &readings, &spec, config);
    iterations += its;
    let rejected = rejected_counts(&readings, &data.chain.sus());
    let (solved, weighted, its, noise_components) =
        weigh_by_noise_components(solved, &layout, readings, &spec, config);
    iterations += its;
    let (solved, weighted, its) =
        super::joint_states::with_joint_states(solved, &layout, weighted, &spec, config);
    iterations += its;
    let fixed = gauge_statement(data, base, gauge_su, vertical, &spec);
    let problem = FinalProblem {
        data: data.clone(),
        layout,
        spec,
        readings: weighted,
        fixed,
        intrinsics_model,
        intrinsics_tests,
        noise_components,
        rejected,
    };
    problem.report(solved.state, None, (iterations, started), config)
}

/// What a limb's final fit solved: the limb's readings as the fit weighed them, the problem and
/// what the fit chose on the way (kept with the estimate, so that the limbs of one tree can be
/// fitted again together: [`tree::refine_trees`]).
#[derive(Debug, Clone)]
pub(super) struct FinalProblem {
    pub(super) data: LimbData,
    pub(super) layout: Layout,
    pub(super) spec: Spec,
    /// The readings, weighed as the fit weighed them (by the noise components when it estimated
    /// them).
    pub(super) readings: Readings,
    /// What the gauge holds, in words.
    pub(super) fixed: Vec<String>,
    pub(super) intrinsics_model: IntrinsicsModel,
    pub(super) intrinsics_tests: Vec<IntrinsicsTest>,
    pub(super) noise_components: Option<NoiseComponents>,
    pub(super) rejected: Vec<SuRejected>,
}

impl FinalProblem {
    /// All that is reported of the fit that ended at `state` after `iterations` from `started`:
    /// its precision, its uncertainty, the limb as a robot; `others`: what other limbs' readings
    /// tell of its shared columns, when they were fitted together ([`Precision::of`]).
    pub(super) fn report(
        self,
        state: ChainState,
        others: Option<&DMatrix<f64>>,
        (iterations, started): (usize, Instant),
        config: &MlConfig,
    ) -> Result<MlChainEstimate, EstimateError> {
        let precision = Precision::of(&state, &self, others, config);
        if !precision.residual_ratio.is_finite() {
            return Err(EstimateError::NotFinite {
                limb: self.data.chain.name.clone(),
                reason: format!("residual / noise = {}", precision.residual_ratio),
            });
        }
        let fit = FinalFit {
            state,
            precision,
            problem: self,
        };
        fit.estimate((iterations, started), config)
    }
}

/// A limb's final fit and what is known of its precision.
pub(super) struct FinalFit {
    pub(super) state: ChainState,
    pub(super) precision: Precision,
    pub(super) problem: FinalProblem,
}

impl FinalFit {
    /// All that is reported of the fit, which took `iterations` from `started`.
    pub(super) fn estimate(
        self,
        (iterations, started): (usize, Instant),
        config: &MlConfig,
    ) -> Result<MlChainEstimate, EstimateError> {
        let (state, precision, problem) = (self.state, self.precision, self.problem);
        let (data, layout, spec) = (&problem.data, &problem.layout, &problem.spec);
        let readings = &precision.readings;
        let residual_ratio = precision.residual_ratio;
        let flat_dofs = data.chain.dofs();
        let flat_sus = data.chain.sus();
        let cov = &precision.cov;
        let open = &precision.open;
        let limb = limb_robot(&data.chain, &state, &data.su_depth)?;
        Ok(MlChainEstimate {
            robot: RobotFile::from_robot(&limb, Some("maximum-likelihood estimate".into())),
            dh: dh_table(&limb, &state, spec, cov, data),
            chain: data.chain.clone(),
            joint_orders: Vec::new(),
            retries: Vec::new(),
            gravity: state.gravity.into(),
            other_gravities: state.other_gravities.iter().map(|&g| g.into()).collect(),
            residual_ratio,
            noise_sd_estimate: config.noise_sd * residual_ratio,
            reading_sd: readings.sd.is_some(),
            converged: residual_ratio <= config.converged_ratio
                && precision.band.is_none_or(|b| b.holds(residual_ratio))
                && precision
                    .at_rest
                    .is_none_or(|r| r.band.is_none_or(|b| b.holds(r.residual_ratio))),
            residual_band: precision.band,
            fixed: problem.fixed.clone(),
            uncertainty: su_uncertainty(&state, layout, spec, &flat_sus, cov, open),
            joint_covariance: joint_covariance(spec, &flat_dofs, cov),
            intrinsics: su_intrinsics(&state, spec, &flat_sus, cov, problem.intrinsics_model),
            intrinsics_model: Some(problem.intrinsics_model),
            intrinsics_tests: problem.intrinsics_tests.clone(),
            intrinsics_left_out: Vec::new(),
            noise_components: problem.noise_components,
            rejected: problem.rejected.clone(),
            missing_excitations: if readings.motion.is_some() {
                Vec::new()
            } else {
                data.missing_excitations()
            },
            motion: readings.motion.as_ref().map(|m| {
                let at = precision.names.iter().position(|n| n == "skin.delay");
                MotionFit {
                    blocks: m.len(),
                    skin_delay: state.skin_delay,
                    skin_delay_sd: at.map_or(f64::NAN, |i| cov[(i, i)].max(0.0).sqrt()),
                    at_rest: precision.at_rest,
                }
            }),
            su_residual_ratio: su_residual_ratios(&state, layout, readings, spec, config.noise_sd),
            unobservable: precision.unobservable,
            iterations,
            seconds: started.elapsed().as_secs_f64(),
            state: Some(state),
            runner_ups: Vec::new(),
            problem: FitProblem(Some(std::sync::Arc::new(problem))),
        })
    }
}

/// How a limb's final fit fixes what the readings cannot tell.
pub(super) struct Gauge {
    /// DoFs of the base path (a sub-limb's, held at the parent's estimate).
    pub(super) base_dofs: usize,
    /// Whether the limb has a base path from a parent limb.
    pub(super) base: bool,
    /// The SU whose turn about and shift along the first axis are held.
    pub(super) su: Option<usize>,
    /// Whether gravity is held along the first axis.
    pub(super) vertical: bool,
}

/// The final fit's problem: every block of the limb (the base path held), its intrinsics as
/// `intrinsics` says, the skin's delay where there is a motion record, and gravity's direction
/// alone where scales are fitted or chosen.
pub(super) fn final_spec(
    layout: &Layout,
    gauge: &Gauge,
    motion: bool,
    intrinsics: IntrinsicsModel,
    config: &MlConfig,
) -> Spec {
    let mut spec = full_spec(
        layout,
        gauge.base_dofs.max(1),
        !gauge.base,
        gauge.su,
        intrinsics,
    );
    if gauge.vertical {
        // Gravity along the first axis: its direction is held, which leaves the turn of
        // everything after segment 1 about that axis exactly free (reported below).
        spec.held.extend([(0, 0), (0, 1)]);
    }
    if motion {
        spec.blocks.push(Block::SkinDelay);
    }
    if !gauge.base {
        // Each other base orientation's gravity, whole: the usual one's magnitude (or scales)
        // holds the scale, and the turn about the first axis that gravity along it leaves free
        // is held by the gauge SU, not by a gravity.
        spec.blocks
            .extend((1..layout.orientations).map(Block::OtherGravity));
    }
    if !gauge.base && (intrinsics.components() > 3 || config.select_intrinsics) {
        // A common scale error of every SU and a gravity as much weaker read the same: the
        // magnitude of gravity is what scales are measured against. When the data choose
        // the model, every model holds it there, so that each is nested in the next and a
        // limb with few SUs (a trunk) does not hand the limbs on it a magnitude of its own.
        spec.blocks[0] = Block::GravityDirection;
    }
    spec
}

/// What a final fit reports of its precision: from the readings alone (not the gauge priors),
/// the residual against the noise configured (or the set's own deviations), the covariance
/// from the readings weighed as the fit weighed them.
pub(super) struct Precision {
    /// The readings the residual is measured on.
    pub(super) readings: Readings,
    pub(super) residual_ratio: f64,
    /// The band of the residual ratio at the noise level (readings fits only: what the joint
    /// states' derivatives leave unmatched in motion is no noise of the skin's).
    pub(super) band: Option<ResidualBand>,
    /// A fit on a motion record: the residual of its blocks at rest.
    pub(super) at_rest: Option<RestResidual>,
    pub(super) cov: DMatrix<f64>,
    /// The parameters' names, in the covariance's order.
    pub(super) names: Vec<String>,
    pub(super) unobservable: Vec<Unobservable>,
    /// The problem with its gauge released ([`released`]) and the directions no reading
    /// determines, over its columns ([`free_directions`]).
    pub(super) open: (Spec, Vec<DVector<f64>>),
}

/// The residual of the blocks of `readings`' motion record in which the limb stood still, with
/// its band: every component of theirs counts (the parameters, fitted on the whole record, take
/// next to nothing from them). `None` without a motion record or a block at rest.
fn rest_residual(
    state: &ChainState,
    problem: &FinalProblem,
    readings: &Readings,
    sigma: f64,
) -> Option<RestResidual> {
    let rest = readings.motion.as_ref()?.at_rest();
    if rest.is_empty() {
        return None;
    }
    let only_rest = Readings {
        q: Vec::new(),
        turns: Vec::new(),
        statics: Vec::new(),
        dynamics: Vec::new(),
        rejected: Vec::new(),
        missing: Vec::new(),
        sd: None,
        orientation: Vec::new(),
        gauge_prior: None,
        motion: Some(std::sync::Arc::new(rest)),
        ..readings.clone()
    };
    let (layout, spec) = (&problem.layout, &problem.spec);
    let map = ColumnMap::new(spec);
    let (cost, rows) = problem::cost_and_rows(state, layout, &only_rest, spec, &map, sigma);
    // The filtered samples' noise is correlated: their sum of squares varies as that of fewer
    // independent ones.
    let independent = rows as f64 / readings.motion.as_ref()?.square_overcount();
    (rows > 0).then(|| RestResidual {
        residual_ratio: (cost / rows as f64).sqrt(),
        rows,
        band: ResidualBand::at(independent.round() as usize),
    })
}

impl Precision {
    /// The precision of `problem`'s fit at `state`; `others`: what other limbs' readings tell of
    /// its shared columns (information, in their order), when they were fitted together.
    pub(super) fn of(
        state: &ChainState,
        problem: &FinalProblem,
        others: Option<&DMatrix<f64>>,
        config: &MlConfig,
    ) -> Self {
        let (layout, spec, data) = (&problem.layout, &problem.spec, &problem.data);
        let components = problem.noise_components.is_some();
        let weighted = problem.readings.clone();
        let sigma = config.noise_sd;
        let weighted = Readings {
            gauge_prior: None,
            expected_delay_rate: true,
            ..weighted
        };
        let (readings, weighted) = if components {
            let plain = Readings {
                sd: None,
                ..weighted.clone()
            };
            (plain, Some(weighted))
        } else {
            (weighted, None)
        };
        // The parameters, and what the corrections of a coarse encoder's joint states took.
        let corrected = readings.motion.as_ref().map_or(0.0, |m| m.corrected_dof());
        let dof_count = spec.columns().len() + corrected.round() as usize;
        let names = column_names(&data.chain.dofs(), &data.chain.sus(), spec);
        let map = ColumnMap::new(spec);
        let ratio_of = |(cost, rows): (f64, usize)| {
            (cost / (rows.saturating_sub(dof_count)).max(1) as f64).sqrt()
        };
        // The normal system of the readings as weighed, formed once with the gauge released:
        // its null directions are what no reading determines, and kept to the fit's columns it
        // is the fit's own.
        let open = released(spec);
        let open_map = ColumnMap::new(&open);
        let weighed = weighted.as_ref().unwrap_or(&readings);
        let released_normal = normal_system(state, layout, weighed, &open, &open_map, sigma);
        let free = free_directions(&released_normal, &open_map);
        let mut normal = released_normal.restricted(&open_map, &map);
        // The plain residual: the weighted one's when the noise was not weighed by components.
        let scale = ratio_of((normal.cost, normal.rows));
        let (plain_rows, residual_ratio) = match &weighted {
            Some(_) => {
                let plain = problem::cost_and_rows(state, layout, &readings, spec, &map, sigma);
                (plain.1, ratio_of(plain))
            }
            None => (normal.rows, scale),
        };
        let band = readings
            .motion
            .is_none()
            .then(|| ResidualBand::at(plain_rows.saturating_sub(dof_count)));
        if let Some(others) = others {
            normal.add_shared_information(others);
        }
        // A filtered record's samples hold less than each weighed alone says.
        let overcount = readings.overcount();
        let (cov, unobservable) = covariance(
            &normal,
            &map,
            scale.max(1.0) * overcount.sqrt(),
            &names,
            config.observable_limit,
        );
        let unobservable = positions_in_one(unobservable, data, &readings);
        let at_rest = rest_residual(state, problem, &readings, sigma);
        Self {
            readings,
            residual_ratio,
            band: band.flatten(),
            at_rest,
            cov,
            names,
            unobservable,
            open: (open, free),
        }
    }
}

/// What the final fit held to fix the gauge, in words.
pub(super) fn gauge_statement(
    data: &LimbData,
    base: Option<&LimbBase>,
    gauge_su: Option<usize>,
    vertical: bool,
    spec: &Spec,
) -> Vec<String> {
    let (flat_dofs, flat_sus) = (data.chain.dofs(), data.chain.sus());
    let mut fixed = Vec::new();
    match (base, gauge_su) {
        (Some(_), _) => fixed.push(format!(
            "the base path ({} DoFs) and gravity, as the parent limb estimated them",
            data.chain.base_dofs()
        )),
        (None, Some(u)) => fixed.extend([
            format!("{}.rotation_z", flat_sus[u]),
            format!("{}.z", flat_sus[u]),
        ]),
        (None, None) => fixed.push(format!(
            "the turn about and shift along {}'s axis of everything it moves (no SU before {}: left to the damping, not held by a parameter)",
            flat_dofs[0], flat_dofs.get(1).map_or("", String::as_str)
        )),
    }
    if vertical {
        fixed.push(format!("gravity.direction (along {}'s axis)", flat_dofs[0]));
    }
    if spec.blocks.first() == Some(&Block::GravityDirection) {
        fixed.push(format!(
            "gravity.magnitude ({STANDARD_GRAVITY} m/s²: what the sensors are measured against)"
        ));
    }
    fixed
}

/// The limb's DH table with its standard deviations, for a serial chain.
pub(super) fn dh_table(
    limb: &Robot,
    state: &ChainState,
    spec: &Spec,
    cov: &DMatrix<f64>,
    data: &LimbData,
) -> Option<DhTable> {
    if !data.chain.is_serial() {
        return None;
    }
    let (dof_dof, dof_su) = crate::estimate::dh_form(limb, &data.chain)?;
    let (dof_dof_sd, dof_su_sd) = dh_sd(state, spec, cov, data, (&dof_dof, &dof_su));
    Some(DhTable {
        dof_dof,
        dof_su,
        dof_dof_sd,
        dof_su_sd,
    })
}

/// The final fit from the search's best state: the kinematics alone, then, with `config`'s
/// intrinsics, everything together (gravity set to 9.81 m/s² when only its direction is free);
/// with `select_intrinsics`, each model from none upwards only when the data ask for it (each
/// fitted from the one before). Returns the solution, its problem, the model fitted, the tests
/// and the LM iterations.
pub(super) fn fit_with_intrinsics(
    state: ChainState,
    layout: &Layout,
    readings: &Readings,
    final_spec: impl Fn(IntrinsicsModel) -> Spec,
    config: &MlConfig,
) -> (Solved, Spec, IntrinsicsModel, Vec<IntrinsicsTest>, usize) {
    // A long motion record climbs the ladder on every few of its blocks; the model chosen is then
    // fitted on every block, from there.
    let whole = readings;
    let coarse = coarse_readings(readings);
    let readings = coarse.as_ref().unwrap_or(readings);
    let fit = |from: (ChainState, f64), spec: &Spec| refit(from, layout, readings, spec, config);
    // A start for `model`'s `spec`: gravity at 9.81 m/s² when only its direction is free; when
    // the data choose the model, the intrinsics that `model` does not fit ideal (a start from an
    // earlier fit of a larger model keeps its biases, and the smaller model would be tested with
    // them held: a clean Kinova arm's continuous log took biases at z = 202 against a "none"
    // that held the readings fit's, at z = −2 against ideal sensors).
    let from = |state: &ChainState, spec: &Spec, model: IntrinsicsModel| {
        let mut start = state.clone();
        if spec.blocks.first() == Some(&Block::GravityDirection) {
            start.gravity = start.gravity.normalize() * STANDARD_GRAVITY;
        }
        if config.select_intrinsics {
            for intrinsics in &mut start.intrinsics {
                *intrinsics = intrinsics.truncated(model.components());
            }
        }
        start
    };
    let spec = final_spec(IntrinsicsModel::None);
    let start = from(&state, &spec, IntrinsicsModel::None);
    let mut solved = fit((start, problem::INITIAL_DAMPING), &spec);
    let mut iterations = solved.iterations;
    let (mut spec, mut model) = (spec, IntrinsicsModel::None);
    let mut tests = Vec::new();
    let ladder: Vec<IntrinsicsModel> = if config.select_intrinsics {
        [
            IntrinsicsModel::Bias,
            IntrinsicsModel::BiasScale,
            IntrinsicsModel::Full,
        ]
        .into_iter()
        .filter(|m| m.components() <= config.intrinsics.components())
        .collect()
    } else if config.intrinsics == IntrinsicsModel::None {
        Vec::new()
    } else {
        vec![config.intrinsics]
    };
    // The residual rows that count (the same for every model: the readings do not change).
    let rows = if config.select_intrinsics && !ladder.is_empty() {
        let map = ColumnMap::new(&spec);
        problem::cost_and_rows(
            &solved.state,
            layout,
            readings,
            &spec,
            &map,
            config.noise_sd,
        )
        .1
    } else {
        0
    };
    // A filtered record's samples hold less along an intrinsic's direction than each weighed
    // alone says: the test divides what the larger model gains by it.
    let overcount = readings.overcount();
    // Every model of the ladder is fitted (each from the one before) so that the tests can be
    // pooled over a skin; the one kept is the last of those taken in a row.
    let mut climbing = true;
    let mut current = (solved.clone(), spec.clone(), model);
    for next in ladder {
        let next_spec = final_spec(next);
        // From the smaller model's solution: each larger model adds columns to it.
        let start = from(&current.0.state, &next_spec, next);
        let larger = fit((start, current.0.damping), &next_spec);
        iterations += larger.iterations;
        if config.select_intrinsics {
            let (before, after) = (current.1.columns().len(), next_spec.columns().len());
            let test = IntrinsicsTest::new(
                next,
                current.2,
                [current.0.cost, larger.cost],
                after.saturating_sub(before),
                rows.saturating_sub(after),
                overcount,
            );
            tests.push(test);
            climbing &= test.taken;
        }
        current = (larger, next_spec, next);
        if climbing || !config.select_intrinsics {
            (solved, spec, model) = current.clone();
        }
    }
    if coarse.is_some() {
        solved = refit((solved.state, solved.damping), layout, whole, &spec, config);
        iterations += solved.iterations;
    }
    (solved, spec, model, tests, iterations)
}

/// `readings` with every few blocks of their motion record, where it holds more than
/// [`LADDER_BLOCKS`] times [`LADDER_THINNING`]: what [`fit_with_intrinsics`] climbs its ladder on.
/// The tests stay valid on the blocks kept (their noise is independent, and correlated filtered
/// noise is counted at their spacing); they lose power only where a sensor's error is within a
/// few block means' noise of nothing.
fn coarse_readings(readings: &Readings) -> Option<Readings> {
    let motion = readings.motion.as_ref()?;
    (motion.len() >= LADDER_BLOCKS * LADDER_THINNING).then(|| Readings {
        motion: Some(std::sync::Arc::new(motion.thinned(LADDER_THINNING))),
        ..readings.clone()
    })
}

/// [`fit_with_intrinsics`] climbs its ladder on every this many blocks of a long motion record.
const LADDER_THINNING: usize = 5;
/// The fewest blocks [`fit_with_intrinsics`] climbs its ladder on.
const LADDER_BLOCKS: usize = 1000;

/// The final fit's solve: from `state` to [`FINAL_TOLERANCE`], its first step damped by
/// `damping` ([`problem::INITIAL_DAMPING`] from a state off the minimum; from a solution of a
/// nearby problem, the damping that solve ended with: [`problem::solve_near`]).
pub(super) fn refit(
    (state, damping): (ChainState, f64),
    layout: &Layout,
    readings: &Readings,
    spec: &Spec,
    config: &MlConfig,
) -> Solved {
    problem::solve_near(
        state,
        layout,
        readings,
        spec,
        (config.noise_sd, FINAL_TOLERANCE),
        config.max_iterations,
        damping,
    )
}
