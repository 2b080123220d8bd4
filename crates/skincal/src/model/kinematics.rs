//! Forward kinematics of the segment tree (paper eq. 4, generalised to trees).

use nalgebra::{Isometry3, Matrix3, RealField, Vector3};

use super::transform::{scalar, vector};
use super::{DofIndex, DofKind, RobotModel, SuIndex};

/// The frames of one configuration, all expressed in the reference frame.
#[derive(Debug, Clone, PartialEq)]
pub struct Kinematics<T: RealField> {
    /// Per DoF: its joint frame (before its own rotation), `T_ref←joint`.
    pub joints: Vec<Isometry3<T>>,
    /// Per segment: `T_ref←segment`.
    pub segments: Vec<Isometry3<T>>,
    /// Per SU: `T_ref←SU`.
    pub sus: Vec<Isometry3<T>>,
}

impl<T: RealField> Kinematics<T> {
    /// Unit axis of `dof` in the reference frame.
    pub fn axis(&self, model: &RobotModel, dof: DofIndex) -> Vector3<T> {
        self.joints[dof]
            .rotation
            .transform_vector(&vector::<T>(model.dofs()[dof].axis.as_ref()))
    }

    /// A point on the axis of `dof` (its joint frame origin), in the reference frame.
    pub fn axis_point(&self, dof: DofIndex) -> Vector3<T> {
        self.joints[dof].translation.vector.clone()
    }

    /// Position of SU `su` in the reference frame.
    pub fn su_position(&self, su: SuIndex) -> Vector3<T> {
        self.sus[su].translation.vector.clone()
    }
}

/// Frames of every joint, segment and SU at pose `q` (one position per DoF: rad, or m for a
/// prismatic one).
///
/// Segments are visited in topological order, so every parent frame is ready before its children:
/// `T_ref←child = T_ref←parent · T_origin · Rot(axis, q)` (or `Trans(axis·q)` for a prismatic DoF);
/// `T_ref←SU = T_ref←segment · T_SU`. A mimic DoF takes its position from its leader
/// ([`super::Dof::position`]); its own entry of `q` is not read.
///
/// # Panics
/// If `parameters` or `q` do not have the model's lengths (a programming error: measurement files
/// are checked against the model when they are read).
pub fn forward_kinematics<T: RealField>(
    model: &RobotModel,
    parameters: &[T],
    q: &[T],
) -> Kinematics<T> {
    let mut k = segment_frames(model, parameters, q);
    k.sus = model
        .sus()
        .iter()
        .map(|su| k.segments[su.segment].clone() * su.placement.transform(parameters))
        .collect();
    k
}

/// The frames of every joint and segment at pose `q`, as [`forward_kinematics`], with no SU
/// frames (`sus` is empty): for callers that place the SUs on the segments themselves, where the
/// SU frames would cost more than the chain (a thousand SUs on seven segments).
///
/// # Panics
/// As [`forward_kinematics`].
pub fn segment_frames<T: RealField>(
    model: &RobotModel,
    parameters: &[T],
    q: &[T],
) -> Kinematics<T> {
    assert_eq!(
        parameters.len(),
        model.parameter_count(),
        "parameter vector length"
    );
    assert_eq!(q.len(), model.dofs().len(), "pose vector length");
    let mut segments = vec![Isometry3::identity(); model.segments().len()];
    let mut joints = vec![Isometry3::identity(); model.dofs().len()];
    for (s, segment) in model.segments().iter().enumerate().skip(1) {
        let d = segment
            .parent_dof
            .expect("non-root segments have a parent DoF");
        let dof = &model.dofs()[d];
        let joint = segments[dof.parent].clone() * dof.origin.transform(parameters);
        segments[s] = joint.clone() * dof.kind.motion(&dof.axis, dof.position(d, q));
        joints[d] = joint;
    }
    Kinematics {
        joints,
        segments,
        sus: Vec::new(),
    }
}

/// How a rigid body moves at one instant, in the reference frame: its angular velocity `omega`
/// and angular acceleration `alpha` (rad/s, rad/s²), and `accel`, the acceleration of the body's
/// point that is at the reference origin (m/s²). A point `p` of the body accelerates at
/// `accel + alpha × p + omega × (omega × p)`.
#[derive(Debug, Clone, PartialEq)]
pub struct BodyMotion<T: RealField> {
    /// Angular velocity, rad/s.
    pub omega: Vector3<T>,
    /// Angular acceleration, rad/s².
    pub alpha: Vector3<T>,
    /// Acceleration of the body's point at the reference origin, m/s².
    pub accel: Vector3<T>,
}

impl<T: RealField> BodyMotion<T> {
    /// A body that does not move (the static reference segment).
    pub fn still() -> Self {
        Self {
            omega: Vector3::zeros(),
            alpha: Vector3::zeros(),
            accel: Vector3::zeros(),
        }
    }

    /// The acceleration of the body's point now at `p`, m/s².
    pub fn point_acceleration(&self, p: &Vector3<T>) -> Vector3<T> {
        self.accel.clone() + self.alpha.cross(p) + self.omega.cross(&self.omega.cross(p))
    }

    /// The matrix `M` with `alpha × p + omega × (omega × p) = M·p`.
    pub fn point_matrix(&self) -> Matrix3<T> {
        let w = self.omega.cross_matrix();
        self.alpha.cross_matrix() + &w * &w
    }

    /// The specific-force field of the body seen in `frame`, a frame fixed to it (reference ←
    /// frame): `(c, N)` such that an ideal accelerometer aligned with `frame` at `p` (frame
    /// coordinates) reads `c + N p` under `gravity`.
    pub fn field_in(&self, frame: &Isometry3<T>, gravity: &Vector3<T>) -> (Vector3<T>, Matrix3<T>) {
        let rt = frame
            .rotation
            .clone()
            .to_rotation_matrix()
            .into_inner()
            .transpose();
        let x = &rt * &frame.translation.vector;
        self.field_seen(&rt, &x, gravity)
    }

    /// [`BodyMotion::field_in`] with the frame given as `Rᵀ` and its origin in its own axes,
    /// `x_f = Rᵀx` (for many motions seen in one frame). With `ω_f = Rᵀω` and `α_f = Rᵀα`:
    /// `N = [α_f]× + [ω_f]×²` (`[ω]×² = ω ωᵀ − |ω|² I`) and `c = Rᵀ(accel − g) + N x_f` —
    /// rotated vectors, no product of matrices.
    pub fn field_seen(
        &self,
        rt: &Matrix3<T>,
        x: &Vector3<T>,
        gravity: &Vector3<T>,
    ) -> (Vector3<T>, Matrix3<T>) {
        let w = rt * &self.omega;
        let spin = &w * w.transpose() - Matrix3::identity() * w.norm_squared();
        let n = (rt * &self.alpha).cross_matrix() + spin;
        let c = rt * (self.accel.clone() - gravity.clone()) + &n * x;
        (c, n)
    }

    /// [`BodyMotion::field_seen`] of a body that does not turn now (`ω = 0`, as at a pose's
    /// static or dynamic reading): `N = [α_f]×`, so `c = Rᵀ(accel − g) + α_f × x_f`.
    pub fn field_seen_unturning(
        &self,
        rt: &Matrix3<T>,
        x: &Vector3<T>,
        gravity: &Vector3<T>,
    ) -> (Vector3<T>, Matrix3<T>) {
        let alpha = rt * &self.alpha;
        let c = rt * (self.accel.clone() - gravity.clone()) + alpha.cross(x);
        (c, alpha.cross_matrix())
    }

    /// The motion of a body that turns relative to this one about the line through `point` along
    /// the unit `axis` (both fixed in this body, in the reference frame now) at rate `rate` and
    /// acceleration `accel` (rad/s, rad/s²).
    ///
    /// The relative motion of a point `p` is a rotation about a fixed line of this body:
    /// `a = a_this(p) + q̈ z × r + q̇² z × (z × r) + 2 ω × (q̇ z × r)`, `r = p − point`; the
    /// angular acceleration gains `q̈ z + ω × q̇ z` (the axis turns with this body).
    pub fn through(&self, axis: &Vector3<T>, point: &Vector3<T>, rate: T, accel: T) -> Self {
        let spin = axis.clone() * rate.clone();
        // The relative terms at the reference origin (r = −point).
        let r = -point.clone();
        let tangential = axis.cross(&r) * accel.clone();
        let centripetal = spin.cross(&spin.cross(&r));
        let coriolis = self.omega.cross(&spin.cross(&r)) * scalar::<T>(2.0);
        Self {
            omega: self.omega.clone() + spin.clone(),
            alpha: self.alpha.clone() + axis.clone() * accel + self.omega.cross(&spin),
            accel: self.accel.clone() + tangential + centripetal + coriolis,
        }
    }

    /// The motion of a body that slides relative to this one along the unit `axis` (fixed in this
    /// body, in the reference frame now) at rate `rate` and acceleration `accel` (m/s, m/s²).
    ///
    /// A point of the sliding body moves as this body's point where it is, plus `q̇ z` relative to
    /// it: `a = a_this(p) + q̈ z + 2 ω × q̇ z` (the axis turns with this body); the two bodies turn
    /// alike.
    pub fn slide(&self, axis: &Vector3<T>, rate: T, accel: T) -> Self {
        let coriolis = self.omega.cross(axis) * (rate * scalar::<T>(2.0));
        Self {
            omega: self.omega.clone(),
            alpha: self.alpha.clone(),
            accel: self.accel.clone() + axis.clone() * accel + coriolis,
        }
    }

    /// The motion of the body that DoF of kind `kind` moves relative to this one: [`Self::through`]
    /// or [`Self::slide`] (`point` is unused for a prismatic DoF).
    pub fn moved_by(
        &self,
        kind: DofKind,
        axis: &Vector3<T>,
        point: &Vector3<T>,
        rate: T,
        accel: T,
    ) -> Self {
        match kind {
            DofKind::Revolute => self.through(axis, point, rate, accel),
            DofKind::Prismatic => self.slide(axis, rate, accel),
        }
    }
}

/// The motion of every segment at pose `q` with joint velocities `qd` and accelerations `qdd`
/// (one per DoF, rad/s and rad/s², or m/s and m/s² for a prismatic one), from the frames of [`forward_kinematics`] at `q`, with the
/// reference segment still.
///
/// # Panics
/// If `qd` or `qdd` do not have one entry per DoF.
pub fn segment_motion<T: RealField>(
    model: &RobotModel,
    frames: &Kinematics<T>,
    qd: &[T],
    qdd: &[T],
) -> Vec<BodyMotion<T>> {
    assert_eq!(qd.len(), model.dofs().len(), "velocity vector length");
    assert_eq!(qdd.len(), model.dofs().len(), "acceleration vector length");
    let mut motion = vec![BodyMotion::still(); model.segments().len()];
    for (s, segment) in model.segments().iter().enumerate().skip(1) {
        let d = segment
            .parent_dof
            .expect("non-root segments have a parent DoF");
        let dof = &model.dofs()[d];
        motion[s] = motion[dof.parent].moved_by(
            dof.kind,
            &frames.axis(model, d),
            &frames.axis_point(d),
            dof.rate(d, qd),
            dof.rate(d, qdd),
        );
    }
    motion
}

/// The specific force an ideal accelerometer with frame `frame` (reference ← SU) reads on a body
/// moving as `motion` under `gravity` (reference frame): `Rᵀ (a(p) − g)`, m/s².
pub fn specific_force<T: RealField>(
    frame: &Isometry3<T>,
    motion: &BodyMotion<T>,
    gravity: &Vector3<T>,
) -> Vector3<T> {
    let a = motion.point_acceleration(&frame.translation.vector);
    frame
        .rotation
        .inverse_transform_vector(&(a - gravity.clone()))
}
