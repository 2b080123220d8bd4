//! A limb fitted on every sample of a motion record: led from the quiet blocks (gravity alone)
//! to the whole motion, and the joint order chosen on the record.

use super::*;

/// The final fit of a limb on every sample of its motion record (`motion`, from the same robot's
/// log), from `start` (a fit on the measurement set's readings: the search's starts come from
/// there); the skin's delay behind the joint states is fitted with it. With `base`, the base
/// path and gravity are held at `base`, as in [`refine_limb`].
pub fn refine_on_motion(
    data: &LimbData,
    base: Option<&LimbBase>,
    start: ChainState,
    mut motion: LimbMotion,
    config: &MlConfig,
) -> Result<MlChainEstimate, EstimateError> {
    let (start, vertical) = held_start(data, base, start, config)?;
    if motion.is_empty() {
        return Err(EstimateError::UnsupportedLimb {
            limb: data.chain.name.clone(),
            reason: "the motion record has no block to fit".into(),
        });
    }
    let readings = motion_readings(data);
    let (start, iterations) = if data.static_only() {
        let lead = Lead {
            data,
            base,
            readings: &readings,
            motion: &motion,
            every: lead_thinning(motion.len()),
            vertical,
            config,
        };
        let ((led, _), its) = lead.run(start);
        (led, its)
    } else {
        (start, 0)
    };
    motion.weigh(&start, &data.su_depth);
    let readings = Readings {
        motion: Some(std::sync::Arc::new(motion)),
        ..readings
    };
    final_fit(
        data,
        base,
        readings,
        start,
        vertical,
        iterations,
        Instant::now(),
        config,
    )
}

/// A limb's readings for a fit on its motion record: the measurement set's readings of the usual
/// base orientation came from the same log, so only those of the other orientations (recorded
/// in logs of their own, which the record leaves out) join its rows.
pub(super) fn motion_readings(data: &LimbData) -> Readings {
    Readings {
        motion: None,
        ..readings(&data.other_orientations())
    }
}

/// What leading a start from static readings to a limb's motion takes: the limb, its base, its
/// readings (the motion rows come from every `every`-th block of `motion`) and whether gravity
/// is held along a vertical first axis.
pub(super) struct Lead<'a> {
    pub(super) data: &'a LimbData,
    pub(super) base: Option<&'a LimbBase>,
    pub(super) readings: &'a Readings,
    pub(super) motion: &'a LimbMotion,
    /// The lead fits every this many blocks of `motion`.
    pub(super) every: usize,
    pub(super) vertical: bool,
    pub(super) config: &'a MlConfig,
}

impl Lead<'_> {
    /// [`Lead::stages`] from `start` and, where gravity is held along a vertical first
    /// axis, from its mirror image too ([`mirrored`]: gravity alone cannot tell which way that
    /// axis turns, the motion tells): the better, with its cost, and the LM iterations of both.
    pub(super) fn run(&self, start: ChainState) -> ((ChainState, f64), usize) {
        let (first, its) = self.stages(start.clone());
        if !self.vertical {
            return (first, its);
        }
        let (second, more) = self.stages(mirrored(&start, &self.data.su_depth));
        let better = if second.1 < first.1 { second } else { first };
        (better, its + more)
    }

    /// A start from static readings alone (orientations and axes from gravity, every position
    /// at its prior) led to the whole motion: fitted with the motion's share of each prediction
    /// taken as error, lowered step by step ([`QUASI_STATIC_STEPS`],
    /// [`LimbMotion::weigh_as_static`]) — a fit on every block at once from positions that are
    /// all wrong would explain gravity's errors with metres of lever arm. Returns the state with
    /// its cost and the LM iterations.
    pub(super) fn stages(&self, start: ChainState) -> ((ChainState, f64), usize) {
        let Lead {
            data,
            base,
            readings,
            motion,
            every,
            vertical,
            config,
        } = *self;
        let layout = Layout::of(data);
        let mut spec = full_spec(
            &layout,
            data.chain.base_dofs().max(1),
            base.is_none(),
            gauge_su(data, base),
            IntrinsicsModel::None,
        );
        if vertical {
            spec.held.extend([(0, 0), (0, 1)]);
        }
        let (mut state, mut cost, mut iterations) = (start, f64::INFINITY, 0);
        // Each step starts from the one before, with the damping it ended with.
        let mut damping = problem::INITIAL_DAMPING;
        let coarse = motion.thinned(every);
        for kappa in QUASI_STATIC_STEPS {
            let mut weighed = coarse.clone();
            weighed.weigh_as_static(&state, &data.su_depth, kappa);
            let stage = Readings {
                huber: None,
                motion: Some(std::sync::Arc::new(weighed)),
                ..readings.clone()
            };
            let solved = problem::solve_near(
                state,
                &layout,
                &stage,
                &spec,
                (config.noise_sd, LEAD_TOLERANCE),
                config.max_iterations,
                damping,
            );
            state = solved.state;
            cost = solved.cost;
            damping = solved.damping;
            iterations += solved.iterations;
        }
        ((state, cost), iterations)
    }
}

/// Of every order of the DoFs inside the limb's joints of several DoFs (gravity alone cannot
/// tell them apart), the readings' fit whose start leads best to the motion of `record`
/// (the lead on every fourth block), with the limb's data in that order. `first`:
/// the fit of `data`'s order, kept where the limb has no such joint or the readings hold
/// dynamic readings (which tell the order themselves).
pub fn order_on_motion(
    data: &LimbData,
    base: Option<&LimbBase>,
    first: MlChainEstimate,
    record: &crate::motion::MotionRecord,
    config: &MlConfig,
) -> Result<(MlChainEstimate, LimbData), EstimateError> {
    let chain = &data.chain;
    let joints: Vec<usize> = (chain.base_joints..chain.joints.len())
        .filter(|&j| chain.joints[j].dofs.len() > 1)
        .collect();
    if joints.is_empty() || !data.static_only() {
        return Ok((first, data.clone()));
    }
    // Every combination of the joints' orders.
    let mut choices: Vec<Vec<Vec<usize>>> = vec![Vec::new()];
    for &j in &joints {
        let orders = init::permutations(chain.joints[j].dofs.len());
        choices = choices
            .into_iter()
            .flat_map(|c| {
                orders.iter().map(move |o| {
                    let mut c = c.clone();
                    c.push(o.clone());
                    c
                })
            })
            .collect();
    }
    let mut best: Option<(f64, MlChainEstimate, LimbData)> = None;
    // The order of the first fit comes first and is taken as soon as it fits at the noise level:
    // the wrong ones leave residuals of ten to sixty standard deviations.
    let unchanged = |c: &[Vec<usize>]| c.iter().all(|o| o.iter().enumerate().all(|(i, &k)| i == k));
    choices.sort_by_key(|c| !unchanged(c));
    for choice in choices.into_iter().take(MAX_ORDER_CHOICES) {
        let identity = unchanged(&choice);
        let ordered = joints
            .iter()
            .zip(&choice)
            .fold(data.clone(), |d, (&j, o)| d.with_joint_order(j, o));
        let estimate = if identity {
            first.clone()
        } else {
            estimate_limb(&ordered, base, config)?
        };
        let Some(start) = estimate.state.clone() else {
            continue;
        };
        let (start, vertical) = held_start(&ordered, base, start, config)?;
        let motion = LimbMotion::new(record, &ordered, config.noise_sd)?.thinned(ORDER_THINNING);
        let readings = motion_readings(&ordered);
        let lead = Lead {
            data: &ordered,
            base,
            readings: &readings,
            motion: &motion,
            every: LEAD_THINNING,
            vertical,
            config,
        };
        let ((_, cost), _) = lead.run(start);
        let residuals = 3 * motion.len() * ordered.su_depth.len();
        let at_noise = cost <= ORDER_ACCEPTED * residuals as f64;
        if best.as_ref().is_none_or(|b| cost < b.0) {
            best = Some((cost, estimate, ordered));
        }
        if identity && at_noise {
            break;
        }
    }
    Ok(best.map_or_else(|| (first, data.clone()), |(_, e, d)| (e, d)))
}

/// [`order_on_motion`] fits every this many blocks of the record times [`LEAD_THINNING`].
pub(super) const ORDER_THINNING: usize = 4;
/// The cost per residual at which [`order_on_motion`] takes the first fit's order without trying
/// the others: the humanoid's right orders led to 0.5–4.5, the wrong ones to 21–1000.
pub(super) const ORDER_ACCEPTED: f64 = 2.0;
/// The most combinations of joint orders [`order_on_motion`] tries (two joints of three DoFs).
pub(super) const MAX_ORDER_CHOICES: usize = 36;

/// The steps of [`Lead::stages`]: how much of what the motion adds to gravity is taken as
/// error.
pub(super) const QUASI_STATIC_STEPS: [f64; 4] = [1.0, 0.3, 0.1, 0.0];
/// The steps of [`Lead::stages`] fit every this many blocks of the record at least: they lead
/// the fit to the right basin, the final fit takes every block.
pub(super) const LEAD_THINNING: usize = 5;
/// About how many blocks of a long record a limb's lead fits (every [`LEAD_THINNING`]-th block
/// where that is fewer than 360): 300 blocks of a skin of 100 SUs are 90,000 readings for some 700
/// parameters. On a 64 s continuous record (6383 blocks) the lead on every 21st block ends where
/// the one on every 5th does: the final fit is the same, in a third of the lead's time.
pub(super) const LEAD_BLOCKS: usize = 300;

/// How many blocks apart the blocks of a record of `blocks` that a limb's lead fits are.
fn lead_thinning(blocks: usize) -> usize {
    LEAD_THINNING.max(blocks / LEAD_BLOCKS)
}

/// The relative change of the cost at which a step of [`Lead::stages`] stops.
pub(super) const LEAD_TOLERANCE: f64 = 1e-6;
