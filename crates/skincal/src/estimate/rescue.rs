//! What is tried when a fit is not at the noise level: the retry policy, in the order it runs.
//!
//! 1. **Within a limb's fit** (`ml::search`): the next orders of each multi-DoF joint's DoFs, then
//!    a wider search (more candidates per joint, more rotation starts). For a sub-limb on its
//!    parent's path these come after the rescues of step 2, and only when those leave it off
//!    the noise level ([`with_own_retries`]): the search with the path free searches the
//!    sub-limb's joints too, and costs one fit where its orders cost five (a sub-limb of a random
//!    tree at 3.88 σ on a wrong path: 7 s of its own retries to no gain, then 1.2 s free).
//! 2. **A sub-limb that did not converge on its parent's path** ([`with_parent`]). A sub-limb is
//!    fitted with its base path (the DoFs from the reference to the branching segment it hangs on)
//!    and gravity held at its parent's estimate. Two things can go wrong there:
//!    - *The parent's path is wrong*, which the sub-limb's readings tell: the path and the
//!      sub-limb searched together as one limb from the reference start the parent's fit again
//!      ([`with_parent_refitted`]); when that fits better, it replaces the parent and the limbs
//!      already on its path are fitted again on the new one.
//!    - *The sub-limb's search fails although its parent converged.* With the base held, the
//!      search cannot move gravity or the path, and can settle in a degenerate minimum (a
//!      humanoid's arms and neck on a trunk whose one yaw axis is vertical: gravity held exactly
//!      along it). The path and the sub-limb are then searched together as one limb from the
//!      reference ([`with_path_free`]); that fit, carried into the parent's frames, starts the
//!      sub-limb's fit with the base held again.
//! 3. **SUs that fit far worse than the rest** are set aside one by one (`body`), the limb fitted
//!    again each time.
//! 4. **A limb that still did not converge** would take the limbs hanging on it down with it:
//!    it is fitted again from each child's readings searched together with it
//!    ([`with_children`], via [`parent_from_child`]), before any child is fitted on its path.
//!
//! Every retry keeps the better of the fits ([`better_of`]) and notes what was tried in the
//! estimate's `retries`. Afterwards each tree is fitted again in one problem (`ml::tree`).
//!
//! Carrying a fit from one limb's frames into another's ([`carried_start`]): both fits see the same
//! SUs on the path, so the rigid motion that takes one's SU frames (at the zero pose) onto the
//! other's relates their reference frames; what lies beyond the path is relative to its segment
//! and carries over unchanged.

use nalgebra::{Isometry3, Matrix3, Rotation3, Translation3, UnitQuaternion, Vector3};

use super::limb::{LimbChain, LimbData};
use super::ml::{estimate_limb, refine_limb, ChainState, LimbBase, MlChainEstimate, MlConfig};
use super::EstimateError;
use crate::measurements::MeasurementSet;

/// `chain` as one limb from the reference: its base path is fitted with it, not held.
fn from_reference(chain: &LimbChain) -> LimbChain {
    LimbChain {
        base_joints: 0,
        ..chain.clone()
    }
}

/// Segment frames at the zero pose: `[k]` is the frame of the segment after `k` DoFs.
fn segments_at_zero(state: &ChainState) -> Vec<Isometry3<f64>> {
    let mut out = vec![Isometry3::identity()];
    for j in &state.joints {
        let next = out.last().expect("starts with the reference") * j;
        out.push(next);
    }
    out
}

/// SU `name`'s frame in the reference frame of `estimate`, at the zero pose.
fn su_at_zero(estimate: &MlChainEstimate, name: &str) -> Option<Isometry3<f64>> {
    let state = estimate.state.as_ref()?;
    let sus = estimate.chain.sus();
    let u = sus.iter().position(|s| s == name)?;
    let depth = estimate.chain.su_depths()[u];
    Some(segments_at_zero(state)[depth] * state.sus[u])
}

/// The rigid motion `a` with `a · from[i] ≈ to[i]` (least squares over rotations, then positions).
fn align(pairs: &[(Isometry3<f64>, Isometry3<f64>)]) -> Option<Isometry3<f64>> {
    if pairs.is_empty() {
        return None;
    }
    let sum: Matrix3<f64> = pairs
        .iter()
        .map(|(from, to)| {
            to.rotation.to_rotation_matrix().matrix()
                * from.rotation.to_rotation_matrix().matrix().transpose()
        })
        .sum();
    let rotation = UnitQuaternion::from_rotation_matrix(&Rotation3::from_matrix(&sum));
    let shift: Vector3<f64> = pairs
        .iter()
        .map(|(from, to)| to.translation.vector - rotation * from.translation.vector)
        .sum::<Vector3<f64>>()
        / pairs.len() as f64;
    Some(Isometry3::from_parts(Translation3::from(shift), rotation))
}

/// A start for `target` from `free`, a fit of a limb from the reference whose joints begin with
/// `target`'s: `target`'s own joints take `free`'s DoF order, frames and SUs; with `base` (the
/// estimate whose first joints are `target`'s base path), the path and gravity are `base`'s and
/// the rest is carried into its frames through the SUs both fits share. Returns the chain in that
/// order and the start, or `None` where the fits share too little.
pub(crate) fn carried_start(
    free: &MlChainEstimate,
    target: &LimbChain,
    base: Option<&MlChainEstimate>,
) -> Option<(LimbChain, ChainState)> {
    let fs = free.state.as_ref()?;
    let fchain = &free.chain;
    if fchain.joints.len() < target.joints.len()
        || fchain
            .joints
            .iter()
            .zip(&target.joints)
            .any(|(a, b)| a.id != b.id || a.dofs.len() != b.dofs.len())
    {
        return None;
    }
    let mut chain = target.clone();
    for j in target.base_joints..target.joints.len() {
        chain.joints[j].dofs = fchain.joints[j].dofs.clone();
    }
    let base_dofs = chain.base_dofs();
    let dofs = chain.dofs().len();
    let mut joints = fs.joints[..dofs].to_vec();
    let gravity = match base {
        None => fs.gravity,
        Some(b) => {
            // The path and gravity are the base's; the first joint after the path is carried from
            // `free`'s frames into the base's by the motion that takes the shared SUs' frames onto
            // each other (at the zero pose).
            let bs = b.state.as_ref()?;
            if bs.joints.len() < base_dofs {
                return None;
            }
            let pairs: Vec<(Isometry3<f64>, Isometry3<f64>)> = b
                .chain
                .sus()
                .iter()
                .filter_map(|su| Some((su_at_zero(free, su)?, su_at_zero(b, su)?)))
                .collect();
            let a = align(&pairs)?;
            let on_free = segments_at_zero(fs)[base_dofs];
            let on_base = segments_at_zero(bs)[base_dofs];
            joints[..base_dofs].copy_from_slice(&bs.joints[..base_dofs]);
            joints[base_dofs] = on_base.inverse() * a * on_free * fs.joints[base_dofs];
            bs.gravity
        }
    };
    // The SUs a limb fits are all beyond its base path: relative to their segments, as `free` has them.
    let mut sus = Vec::new();
    let mut intrinsics = Vec::new();
    let free_sus = fchain.sus();
    for name in chain.sus() {
        let u = free_sus.iter().position(|s| *s == name)?;
        sus.push(fs.sus[u]);
        intrinsics.push(fs.intrinsics[u]);
    }
    Some((
        chain,
        ChainState {
            gravity,
            joints,
            sus,
            intrinsics,
            skin_delay: 0.0,
            other_gravities: Vec::new(),
        },
    ))
}

/// Limb `chain` searched together with its base path as one limb from the reference (the start of
/// both rescues of a sub-limb, searched once).
fn searched_from_reference(
    set: &MeasurementSet,
    chain: &LimbChain,
    config: &MlConfig,
) -> Result<MlChainEstimate, EstimateError> {
    estimate_limb(&LimbData::new(set, &from_reference(chain))?, None, config)
}

/// A sub-limb `chain` (base path held at `parent`'s estimate) fitted again from `free`, its fit
/// searched together with its path as one limb from the reference ([`searched_from_reference`]):
/// carried into `parent`'s frames, fitted with the path held. Returns the estimate and what was
/// tried, or `None` when `free` gives no start.
pub(crate) fn with_path_free(
    set: &MeasurementSet,
    chain: &LimbChain,
    parent: &MlChainEstimate,
    free: &MlChainEstimate,
    config: &MlConfig,
) -> Result<Option<(MlChainEstimate, String)>, EstimateError> {
    let Some((ordered, start)) = carried_start(free, chain, Some(parent)) else {
        return Ok(None);
    };
    let base_dofs = ordered.base_dofs();
    let base = LimbBase::of(parent, base_dofs);
    let refined = refine_limb(&LimbData::new(set, &ordered)?, base.as_ref(), start, config)?;
    let note = format!(
        "searched together with its base path as one limb from the reference ({:.2} σ there), then fitted on {}'s path from that start: residual {:.2} σ",
        free.residual_ratio, parent.chain.name, refined.residual_ratio
    );
    Ok(Some((refined, note)))
}

/// A limb `chain` that did not converge (`base`: the estimate its base path is held at), fitted
/// again from the fit of `child` (a limb hanging on it) searched together with its path as one limb
/// from the reference. Returns the estimate and what was tried, or `None` when that found no start.
pub(crate) fn parent_from_child(
    set: &MeasurementSet,
    chain: &LimbChain,
    base: Option<&MlChainEstimate>,
    child: &LimbChain,
    config: &MlConfig,
) -> Result<Option<(MlChainEstimate, String)>, EstimateError> {
    let free = estimate_limb(&LimbData::new(set, &from_reference(child))?, None, config)?;
    if !free.converged {
        return Ok(None);
    }
    let Some((ordered, start)) = carried_start(&free, chain, base) else {
        return Ok(None);
    };
    let base_dofs = ordered.base_dofs();
    let held = base.and_then(|b| LimbBase::of(b, base_dofs));
    let refined = refine_limb(&LimbData::new(set, &ordered)?, held.as_ref(), start, config)?;
    let note = format!(
        "fitted again from limb {}'s readings searched together with this limb ({:.2} σ there): residual {:.2} σ",
        child.name, free.residual_ratio, refined.residual_ratio
    );
    Ok(Some((refined, note)))
}

/// A parent limb fitted again because a limb hanging on it (`child`, not converged with its base
/// path held at `parent`) converges when searched together with that path as one limb from the
/// reference (`free`, [`searched_from_reference`]): the parent's own readings can leave a mirror
/// image open (a trunk with one yaw axis and SUs near it fits with gravity along the axis either
/// way) that the child's readings close. `grandparent`: the estimate `parent`'s base path is held
/// at. Returns the parent and the child
/// fitted again, both at the noise level, with what was done; `None` otherwise.
pub(crate) fn with_parent_refitted(
    set: &MeasurementSet,
    child: &LimbChain,
    (parent, grandparent): (&MlChainEstimate, Option<&MlChainEstimate>),
    free: &MlChainEstimate,
    config: &MlConfig,
) -> Result<Option<(MlChainEstimate, MlChainEstimate, String)>, EstimateError> {
    if !free.converged {
        return Ok(None);
    }
    let Some((pchain, pstart)) = carried_start(free, &parent.chain, grandparent) else {
        return Ok(None);
    };
    let held = |chain: &LimbChain, on: Option<&MlChainEstimate>| {
        let dofs = chain.base_dofs();
        on.and_then(|b| LimbBase::of(b, dofs))
    };
    let new_parent = refine_limb(
        &LimbData::new(set, &pchain)?,
        held(&pchain, grandparent).as_ref(),
        pstart,
        config,
    )?;
    if !new_parent.converged {
        return Ok(None);
    }
    let mut child = child.clone();
    for (j, pj) in child.joints.iter_mut().zip(&new_parent.chain.joints) {
        j.dofs = pj.dofs.clone();
    }
    let Some((cchain, cstart)) = carried_start(free, &child, Some(&new_parent)) else {
        return Ok(None);
    };
    let new_child = refine_limb(
        &LimbData::new(set, &cchain)?,
        held(&cchain, Some(&new_parent)).as_ref(),
        cstart,
        config,
    )?;
    if !new_child.converged {
        return Ok(None);
    }
    let note = format!(
        "searched together with its base path as one limb from the reference ({:.2} σ there); limb {} fitted again from that start ({:.2} σ, was {:.2} σ), then this limb on its path: residual {:.2} σ",
        free.residual_ratio,
        parent.chain.name,
        new_parent.residual_ratio,
        parent.residual_ratio,
        new_child.residual_ratio
    );
    Ok(Some((new_parent, new_child, note)))
}

/// A sub-limb `chain` whose fit `first` did not converge on the path of its parent `p` (of
/// the limbs fitted so far, `estimates`, each with its parent in `parents`): the parent
/// fitted again from both limbs' readings searched together (and replaced, its other
/// sub-limbs fitted again on it), or else the sub-limb with its path free; `first` becomes
/// the better of its fits.
pub(crate) fn with_parent(
    set: &MeasurementSet,
    chain: &LimbChain,
    first: &mut MlChainEstimate,
    (estimates, parents, p): (&mut [MlChainEstimate], &[Option<usize>], usize),
    config: &MlConfig,
) -> Result<Rescue, EstimateError> {
    let grandparent = parents[p].map(|g| &estimates[g]);
    let free = searched_from_reference(set, chain, config)?;
    let refitted = with_parent_refitted(set, chain, (&estimates[p], grandparent), &free, config)?;
    if let Some((mut new_parent, again, note)) = refitted {
        new_parent.retries.push(format!(
            "fitted again from limb {}'s readings searched together with it",
            chain.name
        ));
        replace_parent(set, estimates, p, new_parent, config)?;
        *first = better_of(first.clone(), again, note);
        return Ok(Rescue::ParentReplaced);
    }
    if let Some((again, note)) = with_path_free(set, chain, &estimates[p], &free, config)? {
        *first = better_of(first.clone(), again, note);
        return Ok(Rescue::PathFree);
    }
    Ok(Rescue::None)
}

/// A sub-limb `chain` still off the noise level after its rescues (`first`: the best fit so far)
/// fitted again on its path (held at `base`) with its own retries: other orders of its joints'
/// DoFs and a wider search; the better of the two.
pub(crate) fn with_own_retries(
    set: &MeasurementSet,
    chain: &LimbChain,
    first: MlChainEstimate,
    base: Option<&LimbBase>,
    config: &MlConfig,
) -> Result<MlChainEstimate, EstimateError> {
    let again = estimate_limb(&LimbData::new(set, chain)?, base, config)?;
    let note = format!(
        "searched again on its path with the other orders of its joints and a wider search: \
         residual {:.2} σ",
        again.residual_ratio
    );
    Ok(better_of(first, again, note))
}

/// What rescuing a sub-limb did ([`with_parent`]).
pub(crate) enum Rescue {
    /// Nothing fitted better or differently.
    None,
    /// The sub-limb was fitted with its path free.
    PathFree,
    /// The parent was fitted again with it and replaced.
    ParentReplaced,
}

/// A limb that did not converge would take the limbs hanging on it down with it: fitted again
/// from each of theirs (of `chains`) searched together with it, until it converges.
pub(crate) fn with_children(
    set: &MeasurementSet,
    mut estimate: MlChainEstimate,
    on: Option<&MlChainEstimate>,
    chains: &[LimbChain],
    config: &MlConfig,
) -> Result<MlChainEstimate, EstimateError> {
    let children: Vec<&LimbChain> = chains
        .iter()
        .filter(|c| hangs_on(c, &estimate.chain))
        .collect();
    for child in children {
        if config.search_done(&estimate, on.is_some()) {
            break;
        }
        let tried = parent_from_child(set, &estimate.chain, on, child, config)?;
        if let Some((again, note)) = tried {
            estimate = better_of(estimate, again, note);
        }
    }
    Ok(estimate)
}

/// Puts `new_parent` in place of `estimates[p]` and fits the limbs already fitted on its old path
/// again on the new one.
fn replace_parent(
    set: &MeasurementSet,
    estimates: &mut [MlChainEstimate],
    p: usize,
    new_parent: MlChainEstimate,
    config: &MlConfig,
) -> Result<(), EstimateError> {
    estimates[p] = new_parent;
    let (done, later) = estimates.split_at_mut(p + 1);
    let parent = &done[p];
    let held = LimbBase::of(parent, parent.chain.dofs().len());
    for sibling in later
        .iter_mut()
        .filter(|e| hangs_on(&e.chain, &parent.chain))
    {
        let mut chain = sibling.chain.clone();
        for (j, pj) in chain.joints.iter_mut().zip(&parent.chain.joints) {
            j.dofs = pj.dofs.clone();
        }
        let mut again = estimate_limb(&LimbData::new(set, &chain)?, held.as_ref(), config)?;
        again.retries.push(format!(
            "fitted again on {}'s path as fitted again",
            parent.chain.name
        ));
        *sibling = again;
    }
    Ok(())
}

/// Whether limb `child` hangs directly on the segment where limb `parent` ends.
fn hangs_on(child: &LimbChain, parent: &LimbChain) -> bool {
    child.base_joints == parent.joints.len()
        && child
            .joints
            .iter()
            .zip(&parent.joints)
            .all(|(a, b)| a.id == b.id)
}

/// Of a limb's estimate and another fit of it, the one nearer the noise level, with what was tried
/// (`note`) added to the first's retries.
pub(crate) fn better_of(
    first: MlChainEstimate,
    again: MlChainEstimate,
    note: String,
) -> MlChainEstimate {
    let mut retries = first.retries.clone();
    retries.extend(again.retries.iter().cloned());
    retries.push(note);
    let mut best = if again.residual_ratio < first.residual_ratio {
        again
    } else {
        first
    };
    best.retries = retries;
    best
}
