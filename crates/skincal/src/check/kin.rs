//! What a calibrated model predicts an SU reads in one block of a motion record, and how that
//! reading changes when the SU moves on its segment or its bias or sensitivity changes.

use nalgebra::{Isometry3, Matrix3, SMatrix, Vector3};

use crate::model::intrinsics::Intrinsics;
use crate::model::Robot;
use crate::model::{segment_frames, segment_motion, BodyMotion};

/// The parameters of a change of one SU: its shift (3, m) and turn (3, rad), both in its own frame
/// as the model has it, the change of its bias (3, m/s²) and of each axis' sensitivity (3,
/// relative: `0.03` reads 3 % more).
pub const CHANGE: usize = 12;

/// The largest change of an axis' sensitivity the check takes for a drift (relative): a larger
/// one is no small change (a board that reads a still segment's constant gravity fits a
/// sensitivity of zero and that gravity as its bias), and the SU is matched and fitted anew as
/// one that no small change explains.
pub const MAX_DRIFT: f64 = 0.2;

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
    /// Per segment: its specific-force field in its own axes.
    pub fields: Vec<Field>,
}

/// A segment's specific-force field in its own axes, `(c, Rᵀ, N)`: a point `p` of the segment
/// (segment frame) reads `c − Rᵀ g + N p` under gravity `g`, where `R` is the segment's turn,
/// `c = Rᵀ (a₀ + M t)` the acceleration of its origin and `N = Rᵀ M R` its point matrix, both
/// in its axes (a derivative of a field is a field of the same shape).
pub type Field = (Vector3<f64>, Matrix3<f64>, Matrix3<f64>);

impl BlockKinematics {
    /// The frames and motions at joint positions `q`, velocities `qd`, accelerations `qdd` (model
    /// DoF order).
    pub fn new(robot: &Robot, q: &[f64], qd: &[f64], qdd: &[f64]) -> Self {
        let frames = segment_frames(&robot.model, &robot.parameters, q);
        let motion = segment_motion(&robot.model, &frames, qd, qdd);
        let axes = (0..robot.model.dofs().len())
            .map(|d| (frames.axis(&robot.model, d), frames.axis_point(d)))
            .collect();
        let fields = frames
            .segments
            .iter()
            .zip(&motion)
            .map(|(frame, motion)| {
                let rt = frame.rotation.to_rotation_matrix().into_inner().transpose();
                let (c, n) = motion.field_in(frame, &Vector3::zeros());
                (c, rt, n)
            })
            .collect();
        Self {
            segments: frames.segments,
            motion,
            axes,
            fields,
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

/// The reading `y = K Tᵀ (c − Rᵀ g + N p) + b` of an SU placed as `place` (turn `T`, position `p`
/// on its segment) in `block` (its segment's [`Field`]), and its Jacobian in the change
/// parameters ([`CHANGE`]): a shift `δx` and turn `δφ` in the SU's frame move it to `p + T δx`,
/// `T Exp(δφ)`, so `∂y/∂δx = K Tᵀ N T`, `∂y/∂δφ = K [f]×` with `f` the specific force in the
/// SU's axes, `∂y/∂δb = I`; a sensitivity change `δs` makes it `(I + diag δs) K Tᵀ (…) + b`, so
/// `∂y/∂δs = diag(K f)`.
pub fn reading(place: &SuPlace, block: &BlockKinematics) -> (Vector3<f64>, Jacobian) {
    reading_with(place, &place.sensor(), block)
}

/// [`reading`] with the SU's [`Sensor`] matrices already made.
pub fn reading_with(
    place: &SuPlace,
    sensor: &Sensor,
    block: &BlockKinematics,
) -> (Vector3<f64>, Jacobian) {
    let (c, rt, n) = &block.fields[place.segment];
    let Sensor { turn, k, .. } = sensor;
    let v = c - rt * place.gravity + n * place.placement.translation.vector;
    let f = turn.tr_mul(&v);
    let sensed = k * f;
    let y = sensed + Vector3::from(place.intrinsics.bias);
    let mut jac = Jacobian::zeros();
    jac.fixed_view_mut::<3, 3>(0, 0)
        .copy_from(&(k * turn.tr_mul(&(n * turn))));
    jac.fixed_view_mut::<3, 3>(0, 3)
        .copy_from(&(k * f.cross_matrix()));
    jac.fixed_view_mut::<3, 3>(0, 6)
        .copy_from(&Matrix3::identity());
    jac.fixed_view_mut::<3, 3>(0, 9)
        .copy_from(&Matrix3::from_diagonal(&sensed));
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
    let p = block.segments[place.segment]
        .transform_point(&place.placement.translation.vector.into())
        .coords;
    chain
        .iter()
        .map(|&d| {
            let (axis, point) = &block.axes[d];
            axis.cross(&(p - point)).norm_squared() * qdd_sd[d] * qdd_sd[d]
        })
        .sum::<f64>()
        / 3.0
}

/// The matrices an SU reads through: its turn `T` on its segment, its intrinsics `K` and `K Tᵀ`
/// (which maps its segment's field onto its reading).
#[derive(Debug, Clone, Copy)]
pub struct Sensor {
    /// `T`.
    pub turn: Matrix3<f64>,
    /// `K`.
    pub k: Matrix3<f64>,
    /// `K Tᵀ`.
    pub kt: Matrix3<f64>,
}

impl SuPlace {
    /// The matrices it reads through.
    pub fn sensor(&self) -> Sensor {
        let turn = self.placement.rotation.to_rotation_matrix().into_inner();
        let k = self.intrinsics.matrix();
        Sensor {
            turn,
            k,
            kt: k * turn.transpose(),
        }
    }
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
    // `K = diag(1 + s)(I + L)`: the change scales each row.
    for (s, d) in intrinsics.scale.iter_mut().zip(&delta[9..12]) {
        *s = (1.0 + *s) * (1.0 + d) - 1.0;
    }
    SuPlace {
        placement: place.placement * step,
        intrinsics,
        ..*place
    }
}
