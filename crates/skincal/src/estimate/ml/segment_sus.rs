//! SUs added to a segment after its joints are fitted, each from its own readings, and the
//! full problem's parameter specification.

use super::*;

/// Places the other SUs of a joint's segment (closed-form starts, each refined alone with the
/// joints held) and refines the joint's lines with all of them; returns the re-ranked beam.
pub(super) fn add_segment_sus(
    beam: Vec<(ChainState, f64)>,
    layout: &Layout,
    data: &Readings,
    span: &Span,
    config: &MlConfig,
) -> (Vec<(ChainState, f64)>, usize) {
    if span.sus.len() < 2 {
        return (beam, 0);
    }
    let sigma = config.noise_sd;
    let s = span.k1 + 1;
    let results: Vec<((ChainState, f64), usize)> = beam
        .into_par_iter()
        .map(|(mut state, cost)| {
            let mut iterations = 0;
            // The cost so far: earlier segments plus this segment's first SU.
            let previous = cost - single_su_cost(&state, layout, data, span.sus[0], sigma);
            let cache = prefixes(&state, layout, data, s);
            for &v in &span.sus[1..] {
                let spec = Spec {
                    blocks: vec![Block::Su(v)],
                    held: vec![],
                    sus: vec![v],
                    prefix: Some(cache.clone()),
                };
                let best = init::su_starts(&state, layout, data, v, s, config.angle_starts)
                    .into_iter()
                    .map(|start| {
                        let mut c = state.clone();
                        c.sus[v] = start;
                        solve(
                            c,
                            layout,
                            data,
                            &spec,
                            sigma,
                            config.max_iterations,
                            INIT_TOLERANCE,
                        )
                    })
                    .min_by(|a, b| a.cost.total_cmp(&b.cost))
                    .expect("at least one start");
                iterations += best.iterations;
                state.sus[v] = best.state.sus[v];
            }
            let first_free = if span.k0 == 0 { 1 } else { span.k0 };
            let mut blocks: Vec<Block> = (first_free..=span.k1).map(Block::Joint).collect();
            blocks.extend(span.sus.iter().map(|&v| Block::Su(v)));
            let spec = Spec {
                blocks,
                held: vec![],
                sus: span.sus.clone(),
                prefix: Some(prefixes(&state, layout, data, first_free)),
            };
            let solved = solve(
                state,
                layout,
                data,
                &spec,
                sigma,
                config.max_iterations,
                INIT_TOLERANCE,
            );
            iterations += solved.iterations;
            ((solved.state, previous.max(0.0) + solved.cost), iterations)
        })
        .collect();
    let iterations = results.iter().map(|r| r.1).sum();
    (
        keep_best(results.into_iter().map(|r| r.0).collect(), usize::MAX),
        iterations,
    )
}

/// The cost of one SU's readings.
pub(super) fn single_su_cost(
    state: &ChainState,
    layout: &Layout,
    data: &Readings,
    u: usize,
    sigma: f64,
) -> f64 {
    let spec = Spec {
        blocks: vec![],
        held: vec![],
        sus: vec![u],
        prefix: None,
    };
    problem::cost_of(state, layout, data, &spec, &ColumnMap::new(&spec), sigma)
}

/// The final problem: gravity (when `with_gravity`), every joint line from `first_joint` on, every
/// SU and, per `intrinsics`, its accelerometer intrinsics; the gauge SU's rotation about and shift
/// along z held.
pub(super) fn full_spec(
    layout: &Layout,
    first_joint: usize,
    with_gravity: bool,
    gauge_su: Option<usize>,
    intrinsics: IntrinsicsModel,
) -> Spec {
    let mut blocks = Vec::new();
    if with_gravity {
        blocks.push(Block::Gravity);
    }
    blocks.extend((first_joint..layout.dofs).map(Block::Joint));
    let first_su = blocks.len();
    let sus = layout.su_segment.len();
    blocks.extend((0..sus).map(Block::Su));
    let mut held: Vec<(usize, usize)> = gauge_su
        .map(|u| vec![(first_su + u, 2), (first_su + u, 5)])
        .unwrap_or_default();
    if intrinsics != IntrinsicsModel::None {
        let first_intrinsics = blocks.len();
        blocks.extend((0..sus).map(Block::Intrinsics));
        for u in 0..sus {
            held.extend((intrinsics.components()..9).map(|c| (first_intrinsics + u, c)));
        }
    }
    Spec {
        prefix: None,
        held,
        blocks,
        sus: (0..sus).collect(),
    }
}

/// Each SU's intrinsics with their standard deviations from the covariance, and the components
/// whose standard deviation is more than half the prior's (the readings hardly tell them).
pub(super) fn su_intrinsics(
    state: &ChainState,
    spec: &Spec,
    names: &[String],
    covariance: &DMatrix<f64>,
    model: IntrinsicsModel,
) -> Vec<SuIntrinsics> {
    if model == IntrinsicsModel::None {
        return Vec::new();
    }
    let columns = spec.columns();
    let mut sd = vec![[0.0f64; 9]; names.len()];
    for (col, &(b, c)) in columns.iter().enumerate() {
        if let Block::Intrinsics(u) = spec.blocks[b] {
            sd[u][c] = covariance[(col, col)].max(0.0).sqrt();
        }
    }
    names
        .iter()
        .enumerate()
        .map(|(u, su)| SuIntrinsics {
            su: su.clone(),
            value: state.intrinsics[u],
            sd: Intrinsics::from_array(&sd[u]),
            held: (0..model.components())
                .filter(|&c| sd[u][c] > 0.5 * problem::INTRINSIC_PRIOR_SD[c])
                .map(|c| INTRINSIC_NAMES[c].to_string())
                .collect(),
        })
        .collect()
}

/// The name that stands for every position of a limb whose set has no dynamic reading.
pub const STATIC_ONLY_POSITIONS: &str =
    "every joint line's and SU's position (the set has no dynamic reading of this limb: static \
     readings tell orientations only)";

/// Where a limb's set has no dynamic reading at all, every position is unobservable: its many
/// directions are said once, by [`STATIC_ONLY_POSITIONS`].
pub(super) fn positions_in_one(
    unobservable: Vec<Unobservable>,
    data: &LimbData,
    readings: &Readings,
) -> Vec<Unobservable> {
    if readings.motion.is_some() || !data.static_only() {
        return unobservable;
    }
    let position = |name: &String| {
        [".x", ".y", ".z", ".shift_x", ".shift_y"]
            .iter()
            .any(|end| name.ends_with(end))
    };
    let mut out = vec![Unobservable {
        singular_value: 0.0,
        parameters: vec![STATIC_ONLY_POSITIONS.into()],
    }];
    out.extend(
        unobservable
            .into_iter()
            .filter(|u| !u.parameters.iter().all(position)),
    );
    out
}
