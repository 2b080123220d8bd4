//! What a calibrated model predicts an SU reads in one block of a motion record, and how that
//! reading changes when the SU moves on its segment or its bias changes.

use nalgebra::{Isometry3, Matrix3, SMatrix, Vector3};

use crate::model::intrinsics::Intrinsics;
use crate::model::Robot;
use crate::model::{forward_kinematics, segment_motion, BodyMotion};

/// The parameters of a change of one SU: its shift (3, m) and turn (3, rad), both in its own frame
/// as the model has it, and the change of its bias (3, m/s²).
pub const CHANGE: usize = 9;

/// The 3 × [`CHANGE`] Jacobian of one reading.
pub type Jacobian = SMatrix<f64, 3, CHANGE>;

/// Every segment's frame and motion in one block, and each DoF's axis line.
#[derive(Debug, Clone)]
pub struct BlockKinematics {
    /// Per segment: `T_ref←segment`.
    pub segments: Vec<Isometry3<f64>>,
    /// Per segment: how it moves.
    pub motion: Vec<BodyMotion<f64>>,
    /// Per DoF: its unit axis and a point on it, reference frame.
    pub axes: Vec<(Vector3<f64>, Vector3<f64>)>,
}

impl BlockKinematics {
    /// The frames and motions at joint positions `q`, velocities `qd`, accelerations `qdd` (model
    /// DoF order).
    pub fn new(robot: &Robot, q: &[f64], qd: &[f64], qdd: &[f64]) -> Self {
        let frames = forward_kinematics(&robot.model, &robot.parameters, q);
        let motion = segment_motion(&robot.model, &frames, qd, qdd);
        let axes = (0..robot.model.dofs().len())
            .map(|d| (frames.axis(&robot.model, d), frames.axis_point(d)))
            .collect();
        Self {
            segments: frames.segments,
            motion,
            axes,
        }
    }
}

/// One SU as the check sees it: where it sits, what it reads with.
#[derive(Debug, Clone, Copy)]
pub struct SuPlace {
    /// Its segment.
    pub segment: usize,
    /// Its frame on the segment.
    pub placement: Isometry3<f64>,
    /// Its accelerometer.
    pub intrinsics: Intrinsics,
    /// Gravity in the body frame, m/s².
    pub gravity: Vector3<f64>,
}

/// The reading `y = K Rᵀ (a(p) − g) + b` of an SU placed as `place` in `block`, and its Jacobian
/// in the change parameters ([`CHANGE`]): a shift `δx` and turn `δφ` in the SU's frame move it to
/// `p + R δx`, `R Exp(δφ)`, so `∂y/∂δx = K Rᵀ M R`, `∂y/∂δφ = K [f]×`, `∂y/∂δb = I`.
pub fn reading(place: &SuPlace, block: &BlockKinematics) -> (Vector3<f64>, Jacobian) {
    let frame = block.segments[place.segment] * place.placement;
    let motion = &block.motion[place.segment];
    let r = frame.rotation.to_rotation_matrix().into_inner();
    let p = frame.translation.vector;
    let m = motion.point_matrix();
    let f = r.transpose() * (motion.accel + m * p - place.gravity);
    let k = place.intrinsics.matrix();
    let y = k * f + Vector3::from(place.intrinsics.bias);
    let mut jac = Jacobian::zeros();
    jac.fixed_view_mut::<3, 3>(0, 0)
        .copy_from(&(k * r.transpose() * m * r));
    jac.fixed_view_mut::<3, 3>(0, 3)
        .copy_from(&(k * f.cross_matrix()));
    jac.fixed_view_mut::<3, 3>(0, 6)
        .copy_from(&Matrix3::identity());
    (y, jac)
}

/// The variance one component of an SU's predicted reading has from the uncertainty of the joint
/// accelerations (`qdd_sd`, rad/s², model DoF order) of the DoFs in `chain`: each moves the SU's
/// point by its distance from the DoF's axis.
pub fn lever_variance(
    place: &SuPlace,
    block: &BlockKinematics,
    chain: &[usize],
    qdd_sd: &[f64],
) -> f64 {
    let p = (block.segments[place.segment] * place.placement)
        .translation
        .vector;
    chain
        .iter()
        .map(|&d| {
            let (axis, point) = &block.axes[d];
            (axis.cross(&(p - point)).norm() * qdd_sd[d]).powi(2)
        })
        .sum::<f64>()
        / 3.0
}

/// `place` moved by the change `delta` ([`CHANGE`] numbers).
pub fn changed(place: &SuPlace, delta: &[f64]) -> SuPlace {
    let shift = Vector3::new(delta[0], delta[1], delta[2]);
    let turn = Vector3::new(delta[3], delta[4], delta[5]);
    let step = Isometry3::new(shift, turn);
    let mut intrinsics = place.intrinsics;
    for (b, d) in intrinsics.bias.iter_mut().zip(&delta[6..9]) {
        *b += d;
    }
    SuPlace {
        placement: place.placement * step,
        intrinsics,
        ..*place
    }
}
