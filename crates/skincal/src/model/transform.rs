//! Elementary rigid transforms, generic over the scalar.
//!
//! Every function here builds an [`Isometry3`] that maps coordinates in a child frame into the
//! parent frame (the pose of the child frame expressed in the parent frame). All of them are
//! generic over `T: RealField`, so the same code evaluates with `f64` and with dual numbers.

use nalgebra::{Isometry3, RealField, Translation3, Unit, UnitQuaternion, Vector3};

/// Converts an `f64` constant into the scalar type `T`.
#[inline]
pub fn scalar<T: RealField>(value: f64) -> T {
    nalgebra::convert(value)
}

/// Converts an `f64` vector into a vector of `T`.
#[inline]
pub fn vector<T: RealField>(v: &Vector3<f64>) -> Vector3<T> {
    v.map(scalar)
}

/// Rotation by `angle` about the unit `axis` (right-hand rule).
pub fn rotation_about<T: RealField>(axis: &Unit<Vector3<f64>>, angle: T) -> UnitQuaternion<T> {
    let axis_t = Unit::new_unchecked(vector::<T>(axis.as_ref()));
    UnitQuaternion::from_axis_angle(&axis_t, angle)
}

/// Pure rotation about z: `Rz(angle)`.
pub fn rot_z<T: RealField>(angle: T) -> Isometry3<T> {
    Isometry3::from_parts(
        Translation3::identity(),
        UnitQuaternion::from_axis_angle(&Vector3::z_axis(), angle),
    )
}

/// Pure rotation about x: `Rx(angle)`.
pub fn rot_x<T: RealField>(angle: T) -> Isometry3<T> {
    Isometry3::from_parts(
        Translation3::identity(),
        UnitQuaternion::from_axis_angle(&Vector3::x_axis(), angle),
    )
}

/// Pure translation.
pub fn translation<T: RealField>(x: T, y: T, z: T) -> Isometry3<T> {
    Isometry3::from_parts(Translation3::new(x, y, z), UnitQuaternion::identity())
}

/// The standard Denavit–Hartenberg transform of the paper's eq. 5:
/// `Rz(θ) · Tz(d) · Tx(a) · Rx(α)`.
///
/// It is the pose of the next axis frame (`DoF d+1`) in the current one (`DoF d`); `θ` already
/// contains the offset, the DoF position and the pattern angle (eq. 6).
pub fn standard_dh<T: RealField>(theta: T, d: T, a: T, alpha: T) -> Isometry3<T> {
    let zero = T::zero();
    rot_z(theta)
        * translation(zero.clone(), zero.clone(), d)
        * translation(a, zero.clone(), zero)
        * rot_x(alpha)
}

/// The sensor-frame transform of the paper's eq. 7: `Rz(θ_acc) · Tz(d_acc)`, from the virtual
/// DoF axis reached by a DoF-to-SU DH transform to the accelerometer frame.
pub fn sensor_frame<T: RealField>(theta_acc: T, d_acc: T) -> Isometry3<T> {
    rot_z(theta_acc) * translation(T::zero(), T::zero(), d_acc)
}

/// A URDF-style origin: translation `xyz`, then rotation `Rz(yaw) · Ry(pitch) · Rx(roll)`.
pub fn xyz_rpy<T: RealField>(xyz: [T; 3], rpy: [T; 3]) -> Isometry3<T> {
    let [x, y, z] = xyz;
    let [roll, pitch, yaw] = rpy;
    Isometry3::from_parts(
        Translation3::new(x, y, z),
        UnitQuaternion::from_euler_angles(roll, pitch, yaw),
    )
}

/// Splits an isometry into URDF `xyz` and `rpy` (inverse of [`xyz_rpy`]).
pub fn to_xyz_rpy(pose: &Isometry3<f64>) -> ([f64; 3], [f64; 3]) {
    let t = pose.translation.vector;
    let (r, p, y) = pose.rotation.euler_angles();
    ([t.x, t.y, t.z], [r, p, y])
}
