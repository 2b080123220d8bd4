//! Encoders that round to whole counts: the joint states of a motion record as unknowns.
//!
//! A joint that stands still, or creeps across a few counts, is read only to within a count, and
//! its acceleration from the staircase that the record's local polynomial bends to follow. Those
//! errors are the same for every SU the joint moves, so every SU's residual tells them: a fit
//! that takes the joint states as read puts them into the geometry (on a Kinova Jaco with
//! 13-bit encoders, 0.0106 m/s² held-out static where its exact encoders give 0.0008). Here the
//! positions and accelerations of the coarse DoFs at every sample are unknowns too, each held at
//! what the record read by a prior (the encoder's rounding; the record's uncertainty of the
//! acceleration) — errors in variables. They are solved by alternation: per sample, the
//! corrections that best explain all its SUs' residuals at the fit, a still joint's position
//! corrected once for all the samples at its count ([`LimbMotion::correct_joint_states`]),
//! over-relaxed by [`RELAXATION`]; then the fit again on
//! the corrected record, from where it stood; [`PASSES`] times. On the Kinova the held-out error
//! settled by the fourth pass when this was written: 0.0106 / 0.0076 m/s² static / dynamic, then
//! 0.0084 / 0.0078, 0.0077 / 0.0072, 0.0072 / 0.0063 after four, 0.0071 / 0.0062 after six,
//! 0.0070 / 0.0065 after ten (with the record's positions read through the skin's kernel: 0.0105 /
//! 0.0063 as read, 0.0070 / 0.0048 after six; with a still joint's samples at one count sharing
//! one correction, 0.0050 / 0.0048 after six and 0.0047 / 0.0053 after twelve). Over-relaxed,
//! the whole cost does not fall pass by pass, so the passes are counted, not tested.
//!
//! A corrected acceleration's uncertainty is its correction's prior, and no longer weighs the
//! residual too ([`LimbMotion::weigh_fitted`]): weighed twice, the UR5's and the Kinova's fits
//! ended at 0.72 and 0.78 σ, below the noise, and the paper arm's 0.044° record (below) at
//! 0.0020 / 0.0030 m/s²; weighed once, 0.95 and 0.97 σ, and 0.0019 / 0.0019.
//!
//! The same passes read the prediction through the skin's kernel where the record reads the skin
//! through one ([`LimbMotion::read_through_kernel`]): the skin read through the kernel is the
//! specific force read through it, not the specific force at the joint states read through it,
//! and the difference, the motion's spread within the kernel, depends on the fit's parameters.
//! Each pass computes it at the fit so far; where no joint state is corrected, [`KERNEL_PASSES`]
//! passes. On the paper arm with 13-bit encoders and its skin 8 ms late (160 ms kernel), the
//! held-out error fell from 0.0021 / 0.0089 m/s² to 0.0020 / 0.0030.

use std::sync::Arc;

use super::final_fit::refit;
use super::motion::LimbMotion;
use super::problem::{Layout, Predictor, Readings, Solved, Spec};
use super::MlConfig;

/// The over-relaxation of the corrections: alternation creeps along the direction in which the
/// geometry takes up what the corrections leave (a pass without it gains a fifth of what is left
/// on the Kinova); 2 would oscillate.
pub const RELAXATION: f64 = 1.6;
/// The passes of corrections and fits.
pub const PASSES: usize = 6;
/// The passes of fits with the prediction read through the kernel, where no joint state is
/// corrected: what the kernel adds changes little with the fit's parameters.
pub const KERNEL_PASSES: usize = 2;

/// `solved` (the fit on `readings` with `spec`) with the joint states of its motion record's
/// coarse DoFs corrected, and its prediction read through the skin's kernel where the record
/// reads the skin through one ([`LimbMotion::read_through_kernel`]), and the fit repeated, as
/// the module says; the readings with the corrected record, and the LM iterations taken.
/// Unchanged without a motion record, or with neither a coarse DoF ([`MlConfig::joint_states`]
/// on) nor a kernel ([`MlConfig::through_kernel`] on).
pub(super) fn with_joint_states(
    solved: Solved,
    layout: &Layout,
    readings: Readings,
    spec: &Spec,
    config: &MlConfig,
) -> (Solved, Readings, usize) {
    let Some(record) = readings.motion.as_ref() else {
        return (solved, readings, 0);
    };
    let dofs = if config.joint_states {
        record.coarse_dofs()
    } else {
        Vec::new()
    };
    let kernel = config.through_kernel && record.reads_through_kernel();
    if dofs.is_empty() && !kernel {
        return (solved, readings, 0);
    }
    let mut motion = LimbMotion::clone(record);
    if !dofs.is_empty() {
        motion.weigh_fitted(&solved.state, &layout.su_segment, &dofs);
    }
    let (mut solved, mut readings, mut iterations) = (solved, readings, 0);
    let passes = if dofs.is_empty() {
        KERNEL_PASSES
    } else {
        PASSES
    };
    for _ in 0..passes {
        let state = &solved.state;
        let predictor = Predictor::new(state, layout);
        let predict = |t: &[_], v: &[f64], a: &[f64]| predictor.readings(t, v, a);
        if kernel {
            motion.read_through_kernel(predict);
        }
        if !dofs.is_empty() {
            motion.correct_joint_states(&dofs, state.skin_delay, RELAXATION, predict);
        }
        let corrected = Readings {
            motion: Some(Arc::new(motion.clone())),
            ..readings.clone()
        };
        let from = (solved.state.clone(), solved.damping);
        let next = refit(from, layout, &corrected, spec, config);
        iterations += next.iterations;
        (solved, readings) = (next, corrected);
    }
    (solved, readings, iterations)
}
