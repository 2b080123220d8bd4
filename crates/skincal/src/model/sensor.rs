//! The accelerometer model (paper Section II-A.3 and eqs. 8–12).
//!
//! An SU measures the **specific force** in its own frame, in m/s²:
//!
//! ```text
//! f_SU = R_SU←ref · (a − g)            (eq. 3, sign chosen so that a resting SU reads −g)
//! ```
//!
//! where `a` is the acceleration of its mounting point and `g` the gravity vector, both in the
//! reference frame. A resting SU whose z axis points up reads `+9.81` on z.
//!
//! When DoF `d` turns with angular velocity `ω` and acceleration `α` about its unit axis `z_d`
//! (reference frame) through the point `p_d`, an SU at `p` that it moves accelerates by
//!
//! ```text
//! a = α z_d × r + ω² z_d × (z_d × r),   r = p − p_d      (eqs. 1 and 2)
//! ```
//!
//! The excitation pattern (eqs. 10–12) is `θ(t) = A/(2πf)·(1 − cos 2πft)`, `ω(t) = A sin 2πft`,
//! `α(t) = 2πfA cos 2πft`; at its peak `t = 0` the DoF is at its pose, `ω = 0` and `α = 2πfA`, so
//! the **dynamic acceleration** stored in a measurement set is the tangential term alone, rotated
//! into the SU frame: `R_SU←ref · (2πfA · z_d × r)`.

use std::f64::consts::PI;

use nalgebra::{RealField, Vector3};
use serde::{Deserialize, Serialize};

use super::kinematics::{forward_kinematics, segment_motion, BodyMotion, Kinematics};
use super::transform::scalar;
use super::{DofIndex, DofKind, RobotModel, SuIndex};

/// Gravitational acceleration used throughout, m/s² (1 g).
pub const STANDARD_GRAVITY: f64 = 9.81;

/// The largest magnitude of one reading component that any accelerometer of a robot skin can
/// report, m/s² (±500 g; MEMS parts range from ±2 g to ±400 g). Larger values are refused as
/// corrupt or in another unit.
pub const MAX_READING: f64 = 500.0 * STANDARD_GRAVITY;

/// The largest joint angle accepted, rad (about 1600 turns of an unwrapped continuous joint).
pub const MAX_ANGLE: f64 = 1.0e4;

/// Velocity amplitudes `A` of an excitation pattern that a servo can run, rad/s.
pub const PATTERN_AMPLITUDE: std::ops::RangeInclusive<f64> = 1.0e-4..=100.0;

/// Frequencies `f` of an excitation pattern, Hz.
pub const PATTERN_FREQUENCY: std::ops::RangeInclusive<f64> = 1.0e-3..=1.0e3;

/// Gravity in a reference frame whose z axis points up: `(0, 0, −9.81)` m/s².
pub fn gravity_upright() -> Vector3<f64> {
    Vector3::new(0.0, 0.0, -STANDARD_GRAVITY)
}

/// The sinusoidal excitation pattern of eqs. 10–12.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct ExcitationPattern {
    /// Velocity amplitude `A`, rad/s.
    pub amplitude: f64,
    /// Frequency `f`, Hz.
    pub frequency: f64,
}

impl Default for ExcitationPattern {
    /// The paper's default: `A = 0.5 rad/s`, `f = 2 Hz`.
    fn default() -> Self {
        Self {
            amplitude: 0.5,
            frequency: 2.0,
        }
    }
}

impl ExcitationPattern {
    /// The pattern a DoF of `kind` runs: this one for a revolute DoF, scaled by
    /// [`DofKind::pattern_scale`] (m per rad) for a prismatic one.
    pub fn of(&self, kind: DofKind) -> ExcitationPattern {
        ExcitationPattern {
            amplitude: self.amplitude * kind.pattern_scale(),
            frequency: self.frequency,
        }
    }

    /// `θ_patt(t) = A/(2πf)·(1 − cos 2πft)` (eq. 10), rad.
    pub fn angle(&self, t: f64) -> f64 {
        let w = 2.0 * PI * self.frequency;
        self.amplitude / w * (1.0 - (w * t).cos())
    }

    /// `ω_patt(t) = A sin 2πft` (eq. 11), rad/s.
    pub fn velocity(&self, t: f64) -> f64 {
        self.amplitude * (2.0 * PI * self.frequency * t).sin()
    }

    /// `α_patt(t) = 2πfA cos 2πft` (eq. 12), rad/s².
    pub fn acceleration(&self, t: f64) -> f64 {
        let w = 2.0 * PI * self.frequency;
        w * self.amplitude * (w * t).cos()
    }

    /// The peak angular acceleration `2πfA`, rad/s².
    pub fn peak_acceleration(&self) -> f64 {
        2.0 * PI * self.frequency * self.amplitude
    }

    /// The largest excursion from the pose, `A/(πf)`, rad.
    pub fn excursion(&self) -> f64 {
        self.amplitude / (PI * self.frequency)
    }

    /// Whether both numbers lie in the ranges a servo can run ([`PATTERN_AMPLITUDE`],
    /// [`PATTERN_FREQUENCY`]).
    pub fn is_valid(&self) -> bool {
        self.check().is_ok()
    }

    /// Why the pattern cannot be run, naming the number at fault and its range.
    pub fn check(&self) -> Result<(), String> {
        let (a, f) = (PATTERN_AMPLITUDE, PATTERN_FREQUENCY);
        if !a.contains(&self.amplitude) {
            return Err(format!(
                "amplitude {} rad/s is outside {}…{} rad/s",
                crate::show::number(self.amplitude),
                a.start(),
                a.end()
            ));
        }
        if !f.contains(&self.frequency) {
            return Err(format!(
                "frequency {} Hz is outside {}…{} Hz",
                crate::show::number(self.frequency),
                f.start(),
                f.end()
            ));
        }
        Ok(())
    }
}

/// The specific force `R_SU←ref · (a − g)` sensed by an SU with frame `T_ref←SU`.
pub fn specific_force<T: RealField>(
    su_frame: &nalgebra::Isometry3<T>,
    acceleration: &Vector3<T>,
    gravity: &Vector3<T>,
) -> Vector3<T> {
    su_frame
        .rotation
        .inverse_transform_vector(&(acceleration - gravity))
}

/// The motion of every segment when DoF `dof` turns (or slides) with rate `omega` and
/// acceleration `alpha` and every other DoF is still, but for the mimic DoFs that follow it.
fn driven_motion<T: RealField>(
    model: &RobotModel,
    kinematics: &Kinematics<T>,
    dof: DofIndex,
    omega: T,
    alpha: T,
) -> Vec<BodyMotion<T>> {
    let n = model.dofs().len();
    let (mut qd, mut qdd) = (vec![T::zero(); n], vec![T::zero(); n]);
    qd[dof] = omega;
    qdd[dof] = alpha;
    segment_motion(model, kinematics, &qd, &qdd)
}

/// Acceleration (reference frame) of SU `su` when DoF `dof` turns with `omega` and `alpha`:
/// `α z × r + ω² z × (z × r)`, or slides with them: `α z`; zero when the DoF does not move the SU.
/// The mimic DoFs that follow `dof` move with it.
pub fn su_acceleration<T: RealField>(
    model: &RobotModel,
    kinematics: &Kinematics<T>,
    su: SuIndex,
    dof: DofIndex,
    omega: T,
    alpha: T,
) -> Vector3<T> {
    if !model.moves_su(dof, su) {
        return Vector3::zeros();
    }
    let motion = driven_motion(model, kinematics, dof, omega, alpha);
    motion[model.sus()[su].segment].point_acceleration(&kinematics.su_position(su))
}

/// Static readings of every SU at pose `q` under `gravity` (reference frame), m/s².
pub fn static_readings<T: RealField>(
    model: &RobotModel,
    parameters: &[T],
    q: &[T],
    gravity: &Vector3<T>,
) -> Vec<Vector3<T>> {
    let k = forward_kinematics(model, parameters, q);
    k.sus
        .iter()
        .map(|f| specific_force(f, &Vector3::zeros(), gravity))
        .collect()
}

/// Dynamic acceleration of every SU at the peak of `pattern` on `dof`, in each SU's frame (m/s²):
/// `R_SU←ref · (2πfA · z_d × r)` (`R_SU←ref · 2πfA s · z_d` for a prismatic DoF, whose pattern is
/// scaled by `s`, [`ExcitationPattern::of`]). SUs that the DoF does not move read zero.
pub fn peak_dynamic_accelerations<T: RealField>(
    model: &RobotModel,
    parameters: &[T],
    q: &[T],
    dof: DofIndex,
    pattern: &ExcitationPattern,
) -> Vec<Vector3<T>> {
    let k = forward_kinematics(model, parameters, q);
    peak_dynamic_accelerations_at(model, &k, dof, pattern)
}

/// [`peak_dynamic_accelerations`] for frames already computed at the pose.
pub fn peak_dynamic_accelerations_at<T: RealField>(
    model: &RobotModel,
    kinematics: &Kinematics<T>,
    dof: DofIndex,
    pattern: &ExcitationPattern,
) -> Vec<Vector3<T>> {
    let alpha: T = scalar(pattern.of(model.dofs()[dof].kind).peak_acceleration());
    let motion = driven_motion(model, kinematics, dof, T::zero(), alpha);
    (0..model.sus().len())
        .map(|su| {
            let a = motion[model.sus()[su].segment].point_acceleration(&kinematics.su_position(su));
            kinematics.sus[su].rotation.inverse_transform_vector(&a)
        })
        .collect()
}

/// The full reading of every SU at time `t` of `pattern` on `dof`, starting from pose `q`:
/// the DoF is at `q_d + θ(t)` and every SU senses gravity plus the tangential and centripetal
/// accelerations of that instant, `R_SU←ref(t) · (a(t) − g)`.
pub fn readings_during_pattern<T: RealField>(
    model: &RobotModel,
    parameters: &[T],
    q: &[T],
    gravity: &Vector3<T>,
    dof: DofIndex,
    pattern: &ExcitationPattern,
    t: f64,
) -> Vec<Vector3<T>> {
    let pattern = pattern.of(model.dofs()[dof].kind);
    let mut qt = q.to_vec();
    qt[dof] += scalar::<T>(pattern.angle(t));
    let k = forward_kinematics(model, parameters, &qt);
    let motion = driven_motion(
        model,
        &k,
        dof,
        scalar(pattern.velocity(t)),
        scalar(pattern.acceleration(t)),
    );
    (0..model.sus().len())
        .map(|su| {
            let a = motion[model.sus()[su].segment].point_acceleration(&k.su_position(su));
            specific_force(&k.sus[su], &a, gravity)
        })
        .collect()
}

/// The paper's numerical dynamic acceleration (eqs. 8 and 9): the second central difference of
/// each SU's position under the pattern, `(p(h) + p(−h) − 2p(0)) / h²` with `h = 1/(1000 f)`,
/// rotated into the SU frame at `t = 0`.
pub fn numerical_peak_accelerations(
    model: &RobotModel,
    parameters: &[f64],
    q: &[f64],
    dof: DofIndex,
    pattern: &ExcitationPattern,
) -> Vec<Vector3<f64>> {
    let h = 1.0 / (1000.0 * pattern.frequency);
    numerical_accelerations_at(model, parameters, q, dof, pattern, 0.0, h)
}

/// Second central difference of every SU's position at time `t` of the pattern, step `h`, in the
/// SU frame at `t` (the kinematic acceleration, without gravity).
pub fn numerical_accelerations_at(
    model: &RobotModel,
    parameters: &[f64],
    q: &[f64],
    dof: DofIndex,
    pattern: &ExcitationPattern,
    t: f64,
    h: f64,
) -> Vec<Vector3<f64>> {
    let pattern = pattern.of(model.dofs()[dof].kind);
    let at = |time: f64| {
        let mut qt = q.to_vec();
        qt[dof] += pattern.angle(time);
        forward_kinematics(model, parameters, &qt)
    };
    let (minus, zero, plus) = (at(t - h), at(t), at(t + h));
    (0..model.sus().len())
        .map(|su| {
            let a = (plus.su_position(su) + minus.su_position(su) - zero.su_position(su) * 2.0)
                / (h * h);
            zero.sus[su].rotation.inverse_transform_vector(&a)
        })
        .collect()
}
