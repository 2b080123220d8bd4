//! The limbs of one tree fitted together: a limb that hangs on another is searched and fitted with
//! its base path and gravity held at its parent's estimate, so the DoFs of a trunk are first
//! estimated from the trunk's own few SUs although every SU of the arms and the head reads their
//! motion. Here every limb hanging (directly or not) on one limb that starts at the reference
//! segment is fitted again in one maximum-likelihood problem from where the limb-by-limb fits
//! ended: gravity and every DoF's line shared by all the SUs they move, each SU block eliminated
//! as in a limb's own fit (time linear in the number of SUs), the gauge that the root limb holds
//! holding the whole tree. Limbs that start at the reference segment share nothing that a reading
//! of gravity tells (how each sits on the segment, and so its gravity, is its own): each is a
//! tree of its own. They share the skin's clock: where the limbs were fitted on a motion record
//! with the skin's delay free, every tree of the body is fitted in one problem whose one delay
//! every SU tells, and each tree alone only where that fit is not kept.
//!
//! What is reported of each limb afterwards (residual, covariance, undetermined directions) is
//! computed from its own readings, as before, at the shared solution: a trunk's covariance does
//! not take the information the limbs on it add, so it is larger than the tree's (never smaller).

use std::collections::HashMap;
use std::time::Instant;

use nalgebra::DMatrix;

use super::problem::{
    normal_system, pseudo_inverse, solve_together, Block, ColumnMap, Member, Readings, Spec,
};
use super::{ChainState, FinalProblem, MlChainEstimate, MlConfig};

/// The joint fit stops when an accepted step lowers the cost by less than this (relative): it
/// starts from the limbs' own optima, and what is left after the first few steps is a crawl along
/// directions only the weak gauge priors hold (on TALOS, 0.13 of a χ² of 39 150 over 90 more
/// iterations), worth nothing to the estimate and 3 s of time.
const JOINT_TOLERANCE: f64 = 1e-7;
use crate::estimate::EstimateError;

/// A parameter by what it is, so that the limbs that share it give it one column.
#[derive(Debug, Clone, PartialEq, Eq, Hash)]
enum Shared {
    /// A component of a tree's gravity (tree, component).
    Gravity(usize, usize),
    /// A component of a tree's gravity in another base orientation (tree, orientation,
    /// component).
    OtherGravity(usize, usize, usize),
    /// A component of a DoF's joint line.
    Joint(String, usize),
    /// The skin's delay behind the joint states: one clock, whichever limb or tree an SU is on.
    SkinDelay,
}

/// Every limb of `estimates` that hangs on a limb starting at the reference segment fitted again
/// with that limb and every other limb of its tree in one problem (`parents[i]`: the index of the
/// limb that limb `i` hangs on); where the limbs fitted the skin's delay and the body has more
/// than one tree, every tree in one problem with one delay first. Limbs whose own fits ended
/// beyond [`MlConfig::converged_ratio`] take no part, nor do those that hang on them. A group is
/// left as it was when a limb's final problem is not kept, or when the joint fit leaves a limb
/// that converged on its own above the noise.
pub fn refine_trees(
    estimates: &mut [MlChainEstimate],
    parents: &[Option<usize>],
    config: &MlConfig,
) -> Result<(), EstimateError> {
    // A limb whose fit ended off the noise level (a wrong basin) is no evidence of what it shares
    // with the others: it and the limbs that hang on it stay as they are (TALOS: an arm left at
    // 17 σ pulled its trunk's second joint 19 mm from the truth, and the head and the other arm
    // with it, each to 1.03–1.05 σ). A limb on a held path within `converged_ratio`, whose
    // misfit is its parent's path, is what this fit is for.
    let mut joins = vec![false; estimates.len()];
    for i in 0..estimates.len() {
        let fits = estimates[i].converged || estimates[i].residual_ratio <= config.converged_ratio;
        joins[i] = fits && parents[i].is_none_or(|p| joins[p]);
    }
    let trees: Vec<Vec<usize>> = (0..estimates.len())
        .filter(|&i| parents[i].is_none() && joins[i])
        .map(|root| tree_of(root, parents, &joins))
        .collect();
    let delayed = estimates.iter().any(|e| {
        e.problem
            .0
            .as_ref()
            .is_some_and(|p| p.spec.blocks.contains(&Block::SkinDelay))
    });
    if trees.len() > 1 && delayed && refine_group(estimates, &trees, config)? {
        return Ok(());
    }
    for tree in trees.into_iter().filter(|t| t.len() > 1) {
        refine_group(estimates, &[tree], config)?;
    }
    Ok(())
}

/// `root` and every limb that hangs on it, directly or not, of those that `joins`, parents
/// before children.
fn tree_of(root: usize, parents: &[Option<usize>], joins: &[bool]) -> Vec<usize> {
    let mut tree = vec![root];
    let mut at = 0;
    while at < tree.len() {
        let parent = tree[at];
        tree.extend((0..parents.len()).filter(|&i| parents[i] == Some(parent) && joins[i]));
        at += 1;
    }
    tree
}

/// One limb of the tree: its final problem, its state at the start of the joint fit, and its
/// problem with the base path and gravity freed (the blocks the tree shares).
struct Limb {
    problem: std::sync::Arc<FinalProblem>,
    state: ChainState,
    spec: Spec,
}

/// The limbs of `trees` (each its root first) fitted in one problem; whether the fit was kept.
fn refine_group(
    estimates: &mut [MlChainEstimate],
    trees: &[Vec<usize>],
    config: &MlConfig,
) -> Result<bool, EstimateError> {
    let started = Instant::now();
    let mut limbs = Vec::new();
    let mut tree_of_limb = Vec::new();
    for (t, tree) in trees.iter().enumerate() {
        let Some(freed) = freed(estimates, tree) else {
            return Ok(false);
        };
        tree_of_limb.extend(std::iter::repeat_n(t, freed.len()));
        limbs.extend(freed);
    }
    // The skin has one clock: every limb starts from the delay the limbs found together (each
    // limb's weighed by its precision), and the group fits it as one.
    let group: Vec<usize> = trees.concat();
    if let Some(delay) = common_delay(group.iter().map(|&i| &estimates[i])) {
        for limb in &mut limbs {
            limb.state.skin_delay = delay;
        }
    }
    let mut columns: HashMap<Shared, usize> = HashMap::new();
    let mut shared_of = Vec::with_capacity(limbs.len());
    for (limb, &t) in limbs.iter().zip(&tree_of_limb) {
        let Some(at) = place(&limb.spec, &limb.problem, t, &mut columns) else {
            return Ok(false);
        };
        shared_of.push(at);
    }
    let members = limbs
        .iter()
        .zip(shared_of.iter().cloned())
        .map(|(limb, shared)| Member {
            state: limb.state.clone(),
            layout: &limb.problem.layout,
            data: &limb.problem.readings,
            spec: &limb.spec,
            shared,
        })
        .collect();
    let (states, _, iterations) = solve_together(
        members,
        columns.len(),
        config.noise_sd,
        config.max_iterations,
        JOINT_TOLERANCE,
    );
    let others = what_others_tell(
        &limbs,
        &tree_of_limb,
        &states,
        &shared_of,
        &mut columns,
        config,
    );
    // The joint fit's iterations and time are the first limb's; each limb adds its own report.
    let joint_s = started.elapsed().as_secs_f64();
    let what = if trees.len() == 1 {
        format!("the {} limbs of its tree", group.len())
    } else {
        format!(
            "the {} limbs of the body's {} trees (one skin delay)",
            group.len(),
            trees.len()
        )
    };
    let mut refined = Vec::with_capacity(group.len());
    for (m, (((&i, limb), state), others)) in group
        .iter()
        .zip(&limbs)
        .zip(states)
        .zip(&others)
        .enumerate()
    {
        let before = &estimates[i];
        let problem = FinalProblem::clone(&limb.problem);
        let (its, earlier) = if m == 0 {
            (before.iterations + iterations, before.seconds + joint_s)
        } else {
            (before.iterations, before.seconds)
        };
        let mut after = problem.report(state, others.as_ref(), (its, Instant::now()), config)?;
        if before.converged && !after.converged {
            return Ok(false);
        }
        after.seconds += earlier;
        after.joint_orders.clone_from(&before.joint_orders);
        after.retries.clone_from(&before.retries);
        after.retries.push(format!(
            "fitted with {what} in one problem (every DoF's line shared by the SUs it moves; {iterations} LM iterations in {:.0} ms, counted with limb {}): residual {:.2} σ, {:.2} σ alone",
            joint_s * 1e3,
            limbs[0].problem.data.chain.name,
            after.residual_ratio,
            before.residual_ratio
        ));
        refined.push(after);
    }
    for (&i, after) in group.iter().zip(refined) {
        estimates[i] = after;
    }
    Ok(true)
}

/// The limbs of `tree` (the root first) with their base paths and gravity freed: each sub-limb's
/// problem gains the root's gravity blocks (the usual orientation's held as the root holds it, and
/// each other base orientation's) and its path's joint blocks
/// (free, as in the problems of the limbs they belong to), and starts from their values there.
/// `None` when an estimate has no final problem or state kept.
fn freed(estimates: &[MlChainEstimate], tree: &[usize]) -> Option<Vec<Limb>> {
    let root = estimates[tree[0]].problem.0.clone()?;
    let root_state = estimates[tree[0]].state.clone()?;
    let gravity = match root.spec.blocks.first() {
        Some(b @ (Block::Gravity | Block::GravityDirection)) => Some(*b),
        _ => None,
    };
    // Each DoF's line as the limb that owns it (the one it is not on the base path of) has it.
    let mut owned = HashMap::new();
    for &i in tree {
        let (problem, state) = (
            estimates[i].problem.0.as_ref()?,
            estimates[i].state.as_ref()?,
        );
        let chain = &problem.data.chain;
        for (k, dof) in chain.dofs().into_iter().enumerate().skip(chain.base_dofs()) {
            owned.insert(dof, state.joints[k]);
        }
    }
    let mut limbs = Vec::with_capacity(tree.len());
    for &i in tree {
        let problem = estimates[i].problem.0.clone()?;
        let mut state = estimates[i].state.clone()?;
        let chain = &problem.data.chain;
        let base_dofs = chain.base_dofs();
        let spec = if base_dofs == 0 {
            problem.spec.clone()
        } else {
            let dofs = chain.dofs();
            for (k, dof) in dofs.iter().enumerate().take(base_dofs).skip(1) {
                state.joints[k] = *owned.get(dof)?;
            }
            state.gravity = root_state.gravity;
            state.other_gravities = root_state.other_gravities.clone();
            let others = root.spec.blocks.iter().filter_map(|b| match b {
                Block::OtherGravity(_) => Some(*b),
                _ => None,
            });
            let mut spec = with_path(&problem.spec, gravity, &root.spec, base_dofs);
            spec.blocks.extend(others);
            spec
        };
        limbs.push(Limb {
            problem,
            state,
            spec,
        });
    }
    Some(limbs)
}

/// The mean of the skin delays that the limbs of `estimates` fitted on a motion record found,
/// each weighed by the inverse of its variance (equally where one has none); `None` when none
/// was fitted on a record.
fn common_delay<'a>(estimates: impl Iterator<Item = &'a MlChainEstimate>) -> Option<f64> {
    let delays: Vec<(f64, f64)> = estimates
        .filter_map(|e| e.motion.as_ref())
        .map(|m| (m.skin_delay, m.skin_delay_sd))
        .collect();
    let precise = delays.iter().all(|(_, sd)| sd.is_finite() && *sd > 0.0);
    let weight = |sd: f64| if precise { sd.powi(-2) } else { 1.0 };
    let total: f64 = delays.iter().map(|&(_, sd)| weight(sd)).sum();
    (!delays.is_empty()).then(|| delays.iter().map(|&(d, sd)| d * weight(sd)).sum::<f64>() / total)
}

/// `spec` (a sub-limb's, its base path held) with gravity (`gravity`, held as `root` holds it)
/// and the joint blocks of its path's DoFs `1…base_dofs−1` free.
fn with_path(spec: &Spec, gravity: Option<Block>, root: &Spec, base_dofs: usize) -> Spec {
    let mut blocks: Vec<Block> = gravity.into_iter().collect();
    let mut held: Vec<(usize, usize)> = if gravity.is_some() {
        root.held
            .iter()
            .filter(|&&(b, _)| b == 0)
            .copied()
            .collect()
    } else {
        Vec::new()
    };
    blocks.extend((1..base_dofs).map(Block::Joint));
    let offset = blocks.len();
    blocks.extend(spec.blocks.iter().copied());
    held.extend(spec.held.iter().map(|&(b, c)| (b + offset, c)));
    Spec {
        blocks,
        held,
        sus: spec.sus.clone(),
        prefix: None,
    }
}

/// Where each shared column of `spec` (a limb's problem, on tree `tree` of the group) sits among
/// the group's `columns`, which gain the parameters not yet placed; `None` for a block a final
/// problem does not share.
fn place(
    spec: &Spec,
    problem: &FinalProblem,
    tree: usize,
    columns: &mut HashMap<Shared, usize>,
) -> Option<Vec<usize>> {
    let dofs = problem.data.chain.dofs();
    ColumnMap::new(spec)
        .shared()
        .iter()
        .map(|&(b, c)| {
            let key = match spec.blocks[b] {
                Block::Gravity | Block::GravityDirection => Shared::Gravity(tree, c),
                Block::OtherGravity(o) => Shared::OtherGravity(tree, o, c),
                Block::Joint(k) => Shared::Joint(dofs[k].clone(), c),
                Block::SkinDelay => Shared::SkinDelay,
                _ => return None,
            };
            let next = columns.len();
            Some(*columns.entry(key).or_insert(next))
        })
        .collect()
}

/// Per limb at the group's solution: the information that the other limbs' readings give of its
/// own problem's shared columns (in their order), given its base path — the group's information
/// (every SU block eliminated) with the path held and the columns of no concern to the limb
/// marginalised, less the limb's own. `None` for a limb no other limb tells anything more.
fn what_others_tell(
    limbs: &[Limb],
    tree_of_limb: &[usize],
    states: &[ChainState],
    shared_of: &[Vec<usize>],
    columns: &mut HashMap<Shared, usize>,
    config: &MlConfig,
) -> Vec<Option<DMatrix<f64>>> {
    let n = columns.len();
    let own: Vec<DMatrix<f64>> = limbs
        .iter()
        .zip(states)
        .map(|(limb, state)| {
            let readings = Readings {
                gauge_prior: None,
                expected_delay_rate: true,
                ..limb.problem.readings.clone()
            };
            let map = ColumnMap::new(&limb.spec);
            let layout = &limb.problem.layout;
            normal_system(state, layout, &readings, &limb.spec, &map, config.noise_sd)
                .shared_information()
        })
        .collect();
    let mut tree = DMatrix::zeros(n, n);
    for (s, at) in own.iter().zip(shared_of) {
        for (a, &ga) in at.iter().enumerate() {
            for (b, &gb) in at.iter().enumerate() {
                tree[(ga, gb)] += s[(a, b)];
            }
        }
    }
    let floor = tree.diagonal().iter().fold(0.0f64, |m, &d| m.max(d)) * 1e-12;
    limbs
        .iter()
        .enumerate()
        .map(|(i, limb)| {
            let mine = place(&limb.problem.spec, &limb.problem, tree_of_limb[i], columns)?;
            let freed = &shared_of[i];
            let rest: Vec<usize> = (0..n)
                .filter(|g| !freed.contains(g) && !mine.contains(g))
                .collect();
            let pick = |rows: &[usize], cols: &[usize]| {
                DMatrix::from_fn(rows.len(), cols.len(), |a, b| tree[(rows[a], cols[b])])
            };
            let (inverse, _) = pseudo_inverse(&pick(&rest, &rest), floor);
            let cross = pick(&mine, &rest);
            let marginal = pick(&mine, &mine) - &cross * inverse * cross.transpose();
            let at: Vec<usize> = mine
                .iter()
                .map(|g| freed.iter().position(|f| f == g))
                .collect::<Option<_>>()?;
            let alone = DMatrix::from_fn(at.len(), at.len(), |a, b| own[i][(at[a], at[b])]);
            let others = marginal - alone;
            (others.amax() > floor).then_some(others)
        })
        .collect()
}
