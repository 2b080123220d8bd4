//! The search of a limb's joints, segment by segment from closed-form starts, and the retries
//! (other joint orders, a wider search) when a fit ends off the noise level.

use super::*;

/// A joint of the limb in chain indices: its first and last DoF and the SUs on the segment it moves.
pub(super) struct Span {
    pub(super) k0: usize,
    pub(super) k1: usize,
    pub(super) sus: Vec<usize>,
}

pub(super) fn spans(data: &LimbData) -> Vec<Span> {
    let mut out = Vec::new();
    let mut k = 0;
    for joint in &data.chain.joints {
        let k1 = k + joint.dofs.len() - 1;
        out.push(Span {
            k0: k,
            k1,
            sus: (0..data.su_depth.len())
                .filter(|&u| data.su_depth[u] == k1 + 1)
                .collect(),
        });
        k = k1 + 1;
    }
    out
}

/// A start for one joint's solves.
pub(super) struct Candidate {
    pub(super) state: ChainState,
    pub(super) cost: f64,
    pub(super) beam: usize,
}

/// Keeps the `size` cheapest distinct states.
pub(super) fn keep_best(mut ranked: Vec<(ChainState, f64)>, size: usize) -> Vec<(ChainState, f64)> {
    ranked.sort_by(|a, b| a.1.total_cmp(&b.1));
    let mut beam: Vec<(ChainState, f64)> = Vec::new();
    for (state, cost) in ranked {
        if beam.len() == size.max(1) {
            break;
        }
        if beam
            .iter()
            .all(|(_, c)| (c - cost).abs() > 1e-7 * cost.abs().max(1.0))
        {
            beam.push((state, cost));
        }
    }
    beam
}

/// The retry policy of a limb's fit that is not at the noise level: what was tried and the LM
/// iterations of every fit.
pub(super) struct Retries {
    pub(super) iterations: usize,
    pub(super) notes: Vec<String>,
}

impl Retries {
    /// The closed-form order of a joint's DoFs may be wrong (joint limits narrow what its axes
    /// show): the next orders of each joint in turn ([`ORDER_RETRIES`]), each fitted by `fit`
    /// from the choice of orders, until one is `done`; `best` the best of them. Each joint's
    /// orders are tried with the orders that fitted best so far for the others (two joints'
    /// orders may both be wrong).
    pub(super) fn other_orders(
        &mut self,
        best: &mut MlChainEstimate,
        data: &LimbData,
        orders: &JointOrders,
        done: impl Fn(&MlChainEstimate) -> bool,
        fit: impl Fn(&[usize]) -> Result<MlChainEstimate, EstimateError>,
    ) -> Result<(), EstimateError> {
        let mut best_choice = vec![0; orders.len()];
        for (n, (j, tried)) in orders.iter().enumerate() {
            let base = best_choice.clone();
            for (c, (order, _)) in tried.iter().enumerate().skip(1).take(ORDER_RETRIES) {
                if done(best) {
                    return Ok(());
                }
                let mut choice = base.clone();
                choice[n] = c;
                let names: Vec<String> = order
                    .iter()
                    .map(|&i| data.chain.joints[*j].dofs[i].clone())
                    .collect();
                let alternative = fit(&choice)?;
                let what = format!(
                    "joint {} in the order {}",
                    data.chain.joints[*j].id,
                    names.join(", ")
                );
                if self.keep_better(best, alternative, what) {
                    best_choice = choice;
                }
            }
        }
        Ok(())
    }

    /// Still not at the noise level: a wider search (more candidates kept per joint, more
    /// rotation starts), with the orders that fitted best.
    pub(super) fn wider_search(
        &mut self,
        best: &mut MlChainEstimate,
        data: &LimbData,
        orders: &JointOrders,
        config: &MlConfig,
        done: impl Fn(&MlChainEstimate) -> bool,
        fit: impl Fn(&[usize], &MlConfig) -> Result<MlChainEstimate, EstimateError>,
    ) -> Result<(), EstimateError> {
        if done(best) {
            return Ok(());
        }
        let wider = MlConfig {
            beam: config.beam * WIDER_BEAM,
            angle_starts: config.angle_starts * WIDER_ANGLES,
            ..*config
        };
        let choice: Vec<usize> = orders
            .iter()
            .map(|(j, tried)| {
                tried
                    .iter()
                    .position(|(o, _)| {
                        o.iter()
                            .map(|&i| &data.chain.joints[*j].dofs[i])
                            .eq(best.chain.joints[*j].dofs.iter())
                    })
                    .unwrap_or(0)
            })
            .collect();
        let alternative = fit(&choice, &wider)?;
        let what = format!(
            "a wider search (beam {}, {} rotation starts)",
            wider.beam, wider.angle_starts
        );
        self.keep_better(best, alternative, what);
        Ok(())
    }

    /// Notes what was tried (`what`) with its residual and keeps the better of the two;
    /// whether that is the alternative.
    pub(super) fn keep_better(
        &mut self,
        best: &mut MlChainEstimate,
        alternative: MlChainEstimate,
        what: String,
    ) -> bool {
        self.iterations += alternative.iterations;
        self.notes.push(format!(
            "{what}: residual {:.2} σ (was {:.2} σ)",
            alternative.residual_ratio, best.residual_ratio
        ));
        let better = alternative.residual_ratio < best.residual_ratio;
        if better {
            *best = alternative;
        }
        better
    }
}

/// How many other orders of one joint's DoFs are tried when a fit is not at the noise level: all
/// five others of a three-DoF joint (the limits can hide which of its axes comes first).
pub(super) const ORDER_RETRIES: usize = 5;
/// How much wider the last search of a fit not at the noise level is: its beam and its rotation
/// starts, times.
pub(super) const WIDER_BEAM: usize = 16;
pub(super) const WIDER_ANGLES: usize = 4;

/// The iterations every candidate of a joint's search runs before the race drops those far
/// behind the best ([`Search::race`]), and how far is far: times the best cost.
pub(super) const RACE_ITERATIONS: usize = 12;
pub(super) const RACE_MARGIN: f64 = 4.0;

/// The order of the DoFs inside every joint that has several, from the closed-form axis model:
/// per such joint its index and every order (relative to the input's) with its misfit, best first,
/// and how it is reported. Reordering one joint permutes only its own DoF indices, so the input's
/// readings and spans serve every joint.
#[allow(clippy::type_complexity)]
pub(super) fn order_joints(
    data: &LimbData,
    config: &MlConfig,
) -> Result<(Vec<(usize, Vec<(Vec<usize>, f64)>)>, Vec<JointOrder>), EstimateError> {
    let chain = &data.chain;
    let mut input_readings = readings(data);
    input_readings.rejected = screen(&input_readings, config.noise_sd);
    let input_spans = spans(data);
    let mut orders = Vec::new();
    let mut joint_orders = Vec::new();
    for (j, span) in input_spans.iter().enumerate().skip(chain.base_joints) {
        let m = span.k1 - span.k0 + 1;
        if m == 1 {
            continue;
        }
        if m > MAX_JOINT_DOFS {
            return Err(EstimateError::UnsupportedLimb {
                limb: chain.name.clone(),
                reason: format!(
                    "joint {} has {m} DoFs ({}) with no SU between them; at most {MAX_JOINT_DOFS} can be put in order from the data: put an SU on a segment between them, or check the structure (`skincal explore`)",
                    chain.joints[j].id,
                    chain.joints[j].dofs.join(", ")
                ),
            });
        }
        let mut tried: Vec<(Vec<usize>, f64)> = init::permutations(m)
            .into_iter()
            .map(|order| {
                let dofs: Vec<usize> = order.iter().map(|&i| span.k0 + i).collect();
                let misfit = init::joint_lines(&input_readings, span.sus[0], &dofs).misfit;
                (order, misfit)
            })
            .collect();
        tried.sort_by(|a, b| a.1.total_cmp(&b.1));
        let names = &chain.joints[j].dofs;
        let alternatives = tried
            .iter()
            .map(|(order, misfit)| OrderMisfit {
                dofs: order.iter().map(|&i| names[i].clone()).collect(),
                misfit: *misfit,
            })
            .collect();
        joint_orders.push(JointOrder {
            joint: chain.joints[j].id.clone(),
            dofs: tried[0].0.iter().map(|&i| names[i].clone()).collect(),
            alternatives,
        });
        orders.push((j, tried));
    }
    Ok((orders, joint_orders))
}

/// The search and the final fit of a limb whose joints' DoFs are in their order: the paper's
/// Algorithm 2 as steps — the first joint from gravity, each later joint searched from every state
/// of the beam, the SUs of each segment added, then the whole limb at once.
pub(super) fn fit_ordered(
    data: &LimbData,
    base: Option<&LimbBase>,
    base_dofs: usize,
    config: &MlConfig,
) -> Result<MlChainEstimate, EstimateError> {
    let started = Instant::now();
    enough_poses(data, base_dofs)?;
    let search = Search::new(data, config);
    let first = data.chain.base_joints;
    let (mut beam, vertical, mut iterations) = match base {
        Some(b) => (vec![(search.on_base(b), 0.0)], false, 0),
        None => search.first_joint(first),
    };
    let after = if base.is_some() { first } else { first + 1 };
    for span in &search.spans[after..] {
        let (next, its) = search.next_joint(&beam, span);
        beam = next;
        iterations += its;
    }
    let upright = |mut state: ChainState| {
        if vertical {
            // Held along the first axis in the final fit (below).
            state.gravity = Vector3::new(0.0, 0.0, state.gravity.z.signum() * state.gravity.norm());
        }
        state
    };
    let (state, best) = beam.remove(0);
    let runner_ups = beam
        .into_iter()
        .filter(|(_, cost)| cost - best <= RUNNER_UP_MARGIN)
        .map(|(state, _)| upright(state))
        .collect();
    let mut estimate = final_fit(
        data,
        base,
        search.readings,
        upright(state),
        vertical,
        iterations,
        started,
        config,
    )?;
    estimate.runner_ups = runner_ups;
    Ok(estimate)
}

/// How much more than the best a search's end state may cost (`χ²`, whitened) and still be a
/// runner-up ([`MlChainEstimate::runner_ups`]): a likelihood ratio the readings cannot tell.
pub const RUNNER_UP_MARGIN: f64 = 9.0;

/// Refuses a limb with fewer poses than its parameters need (at least [`crate::estimate::body::MIN_POSES`]).
pub(super) fn enough_poses(data: &LimbData, base_dofs: usize) -> Result<(), EstimateError> {
    let dofs = data.q.first().map_or(0, |q| q.len());
    let parameters = 3 + 4 * (dofs - base_dofs) + 6 * data.su_depth.len();
    let per_pose: usize = data.su_depth.iter().map(|&d| 3 * (1 + d)).sum();
    let needed = parameters
        .div_ceil(per_pose.max(1))
        .max(crate::estimate::body::MIN_POSES);
    if data.poses() < needed {
        return Err(EstimateError::TooFewPoses {
            poses: data.poses(),
            parameters: needed,
        });
    }
    Ok(())
}

/// What the search of a limb works on: its layout, its readings (screened) and the span of every
/// joint.
pub(super) struct Search<'a> {
    pub(super) data: &'a LimbData,
    pub(super) config: &'a MlConfig,
    pub(super) layout: Layout,
    pub(super) readings: Readings,
    pub(super) spans: Vec<Span>,
    /// Every joint at the identity, every SU at its segment's origin, no gravity.
    pub(super) empty: ChainState,
}

impl<'a> Search<'a> {
    pub(super) fn new(data: &'a LimbData, config: &'a MlConfig) -> Self {
        let dofs = data.q.first().map_or(0, |q| q.len());
        let sus = data.su_depth.len();
        let mut readings = readings(data);
        readings.rejected = screen(&readings, config.noise_sd);
        Self {
            data,
            config,
            layout: Layout::of(data),
            readings,
            spans: spans(data),
            empty: ChainState {
                gravity: Vector3::zeros(),
                joints: vec![Isometry3::identity(); dofs],
                sus: vec![Isometry3::identity(); sus],
                intrinsics: vec![Intrinsics::default(); sus],
                skin_delay: 0.0,
                other_gravities: Vec::new(),
            },
        }
    }

    /// A sub-limb's start: its base path and gravity as the parent limb estimated them.
    pub(super) fn on_base(&self, base: &LimbBase) -> ChainState {
        let mut state = self.empty.clone();
        state.joints[..base.joints.len()].copy_from_slice(&base.joints);
        state.gravity = base.gravity;
        state.other_gravities = base.other_gravities.clone();
        state
    }

    /// Starts of `state` with the SU `u` of a joint's segment placed from its DoFs `k0..=k1`:
    /// for a single DoF, both senses of its axis (mirror images fit the segment equally well);
    /// for several, the joint's lines searched from gravity.
    pub(super) fn su_starts(
        &self,
        state: &ChainState,
        k0: usize,
        k1: usize,
        u: usize,
    ) -> Vec<ChainState> {
        if k0 == k1 {
            return [1.0, -1.0]
                .into_iter()
                .map(|sign| {
                    let mut s = state.clone();
                    s.sus[u] = init::su_from_axis(&s, &self.layout, &self.readings, u, k0, sign);
                    s
                })
                .collect();
        }
        let dofs: Vec<usize> = (k0..=k1).collect();
        init::joint_line_starts(&self.readings, u, &dofs, LINE_STARTS)
            .into_iter()
            .map(|lines| {
                let mut s = state.clone();
                init::place_joint_lines(&mut s, k0, u, &lines.lines);
                s
            })
            .collect()
    }

    pub(super) fn solve(&self, state: ChainState, spec: &Spec, max: usize) -> Solved {
        solve(
            state,
            &self.layout,
            &self.readings,
            spec,
            self.config.noise_sd,
            max,
            INIT_TOLERANCE,
        )
    }

    /// The first joint (`first`): its tail in closed form, gravity from the static readings,
    /// each start refined; then its segment's SUs. Returns the beam, whether the first axis is
    /// vertical (every start's likelihood-ratio test of gravity along it says so) and the LM
    /// iterations.
    pub(super) fn first_joint(&self, first: usize) -> (Vec<(ChainState, f64)>, bool, usize) {
        let span = &self.spans[first];
        let u = span.sus[0];
        let starts = self.su_starts(&self.empty, span.k0, span.k1, u);
        let count = starts.len();
        let mut beam = Vec::with_capacity(count);
        let (mut votes, mut iterations) = (0, 0);
        for mut s in starts {
            s.gravity = self.gravity_from_statics(&s, span.k1, u);
            let mut blocks = vec![Block::Gravity];
            blocks.extend((1..=span.k1).map(Block::Joint));
            blocks.push(Block::Su(u));
            let su_block = blocks.len() - 1;
            let spec = Spec {
                blocks,
                held: if span.k0 == span.k1 {
                    vec![(su_block, 2), (su_block, 5)]
                } else {
                    vec![]
                },
                sus: vec![u],
                prefix: None,
            };
            let (free, upright, its) = self.vertical_test(s, spec);
            iterations += its;
            votes += usize::from(upright);
            // The search goes on with gravity free even so: held exactly along the first axis,
            // it leaves the turn of the next joint about that axis exactly free, and the searches
            // of the joints after it settle in degenerate minima (on robot-like limbs with a
            // vertical first axis, about a quarter did). Gravity is put on the axis for the final fit.
            beam.push((free.state, free.cost));
        }
        // Mirror images have the same cost here: keep them all (no merging of equal costs).
        beam.sort_by(|a, b| a.1.total_cmp(&b.1));
        beam.truncate(self.config.beam.max(2));
        let (beam, its) = add_segment_sus(beam, &self.layout, &self.readings, span, self.config);
        (beam, votes == count, iterations + its)
    }

    /// Gravity in the reference frame as the static readings of SU `u` on the segment after DoF
    /// `k1` give it at `state`: minus their mean turned into the reference frame.
    pub(super) fn gravity_from_statics(
        &self,
        state: &ChainState,
        k1: usize,
        u: usize,
    ) -> Vector3<f64> {
        let tail = init::tails(state, &self.readings, 0, k1, u);
        let poses = self.data.poses();
        let minus_g: Vector3<f64> = (0..poses)
            .map(|p| self.readings.turns[p][0] * (tail[p].rotation * self.readings.statics[p][u]))
            .sum::<Vector3<f64>>()
            / poses as f64;
        -minus_g
    }

    /// `start` refined under `spec` with gravity free, and again with gravity held along the
    /// first axis: the free fit, whether the first axis is vertical (the likelihood ratio of the
    /// two below the configured test) and the iterations of both.
    pub(super) fn vertical_test(&self, start: ChainState, spec: Spec) -> (Solved, bool, usize) {
        let max = self.config.max_iterations;
        let free = self.solve(start, &spec, max);
        let mut upright = free.state.clone();
        upright.gravity = Vector3::new(
            0.0,
            0.0,
            upright.gravity.z.signum() * upright.gravity.norm(),
        );
        let mut held = spec.held.clone();
        held.extend([(0, 0), (0, 1)]);
        let fixed = self.solve(upright, &Spec { held, ..spec }, max);
        let vertical = fixed.cost - free.cost < self.config.vertical_test;
        let iterations = free.iterations + fixed.iterations;
        (free, vertical, iterations)
    }

    /// The joint of `span` after the beam's: its tail in closed form, its rotation from gravity
    /// (or searched), its position from upstream accelerations, every candidate refined in
    /// parallel ([`Search::joint_then_lines`]), the best few kept and its segment's SUs added.
    pub(super) fn next_joint(
        &self,
        beam: &[(ChainState, f64)],
        span: &Span,
    ) -> (Vec<(ChainState, f64)>, usize) {
        let (k0, k1, u) = (span.k0, span.k1, span.sus[0]);
        let caches: Vec<_> = beam
            .iter()
            .map(|(state, _)| prefixes(state, &self.layout, &self.readings, k0))
            .collect();
        let mut candidates = Vec::new();
        for (b, (state, cost)) in beam.iter().enumerate() {
            for s in self.su_starts(state, k0, k1, u) {
                let tail = init::tails(&s, &self.readings, k0, k1, u);
                let starts = init::joint_starts(
                    &s,
                    &self.layout,
                    &self.readings,
                    k0,
                    u,
                    &tail,
                    self.config.angle_starts,
                );
                for start in starts {
                    let mut state = s.clone();
                    state.joints[k0] = start;
                    candidates.push(Candidate {
                        state,
                        cost: *cost,
                        beam: b,
                    });
                }
            }
        }
        let solved = self.race(candidates, span, &caches);
        let mut iterations: usize = solved.iter().map(|s| s.2).sum();
        let ranked = solved
            .into_iter()
            .map(|(s, cost, _)| (s.state, cost + s.cost))
            .collect();
        let kept = keep_best(ranked, self.config.beam);
        let (beam, its) = add_segment_sus(kept, &self.layout, &self.readings, span, self.config);
        iterations += its;
        (beam, iterations)
    }

    /// Every candidate of the joint of `span` refined ([`Search::joint_then_lines`]) with its
    /// beam entry's cost and its iterations, as a race: each runs [`RACE_ITERATIONS`] first, and
    /// only those not done then whose cost is within [`RACE_MARGIN`] times the best so far go on
    /// (a candidate in another basin ends tens of times above the best, after many iterations).
    pub(super) fn race(
        &self,
        candidates: Vec<Candidate>,
        span: &Span,
        caches: &[std::sync::Arc<Vec<Prefix>>],
    ) -> Vec<(Solved, f64, usize)> {
        let max = self.config.max_iterations;
        let first: Vec<(Solved, f64, usize, usize)> = candidates
            .into_par_iter()
            .map(|c| {
                let (solved, its) =
                    self.joint_then_lines(c.state, span, &caches[c.beam], RACE_ITERATIONS.min(max));
                (solved, c.cost, its, c.beam)
            })
            .collect();
        let best = first.iter().map(|s| s.0.cost).fold(f64::INFINITY, f64::min);
        first
            .into_par_iter()
            .map(|(solved, cost, its, beam)| {
                if solved.cost > RACE_MARGIN * best {
                    return (solved, cost, its);
                }
                let before = solved.iterations;
                let spec = self.lines_spec(span, &caches[beam]);
                let solved = resume(
                    solved,
                    &self.layout,
                    &self.readings,
                    &spec,
                    self.config.noise_sd,
                    max,
                    INIT_TOLERANCE,
                );
                let its = its + solved.iterations - before;
                (solved, cost, its)
            })
            .collect()
    }

    /// One candidate of the joint of `span`: first its frame alone (a few iterations), then the
    /// joint's lines with its segment's first SU (at most `max` iterations). Returns the
    /// solution and the iterations.
    pub(super) fn joint_then_lines(
        &self,
        state: ChainState,
        span: &Span,
        cache: &std::sync::Arc<Vec<Prefix>>,
        max: usize,
    ) -> (Solved, usize) {
        let (k0, u) = (span.k0, span.sus[0]);
        let frame = Spec {
            blocks: vec![Block::JointFull(k0)],
            held: vec![],
            sus: vec![u],
            prefix: Some(cache.clone()),
        };
        let first = self.solve(state, &frame, self.config.max_iterations.min(10));
        let second = self.solve(first.state, &self.lines_spec(span, cache), max);
        let iterations = first.iterations + second.iterations;
        (second, iterations)
    }

    /// The problem of the lines of the joint of `span` with its segment's first SU.
    fn lines_spec(&self, span: &Span, cache: &std::sync::Arc<Vec<Prefix>>) -> Spec {
        let mut blocks: Vec<Block> = (span.k0..=span.k1).map(Block::Joint).collect();
        blocks.push(Block::Su(span.sus[0]));
        Spec {
            blocks,
            held: vec![],
            sus: vec![span.sus[0]],
            prefix: Some(cache.clone()),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::estimate::LimbChain;
    use crate::sim::{simulate, SimulationConfig};

    /// A solve stopped at its cap and resumed ends exactly where one solve to the larger cap
    /// ends (so the race changes nothing for the candidates it lets go on).
    #[test]
    fn a_resumed_solve_equals_one_solve_to_the_same_cap() {
        let robot = crate::model::presets::find("paper-7dof")
            .unwrap()
            .robot()
            .unwrap();
        let set = simulate(&robot, &SimulationConfig::default())
            .unwrap()
            .measurements;
        let chain =
            LimbChain::serial("arm", &robot.model.dof_names(), &robot.model.su_names()).unwrap();
        let data = LimbData::new(&set, &chain).unwrap();
        let config = MlConfig::default();
        let search = Search::new(&data, &config);
        // The whole chain from the empty state: far from its minimum, so no solve stops early.
        let mut blocks = vec![Block::Gravity];
        blocks.extend((1..7).map(Block::Joint));
        blocks.extend((0..7).map(Block::Su));
        let spec = Spec {
            blocks,
            held: vec![],
            sus: (0..7).collect(),
            prefix: None,
        };
        let mut start = search.empty.clone();
        start.gravity = Vector3::new(0.0, 0.0, -9.81);
        let whole = search.solve(start.clone(), &spec, 9);
        let part = search.solve(start, &spec, 4);
        assert_eq!(part.iterations, 4);
        assert!(
            part.capped.is_some(),
            "the first part stopped before its cap"
        );
        let part_cost = part.cost;
        let resumed = resume(
            part,
            &search.layout,
            &search.readings,
            &spec,
            config.noise_sd,
            9,
            INIT_TOLERANCE,
        );
        assert_eq!(resumed.iterations, whole.iterations);
        assert_eq!(resumed.cost, whole.cost);
        assert_eq!(resumed.state, whole.state);
        assert!(resumed.iterations > 4 && resumed.cost < part_cost);
    }
}
