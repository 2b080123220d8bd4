//! The paper's DH+2 form of a serial chain (Fig. 6, eqs. 4–7): DoF-to-DoF rows `(θ0, d, a, α)` along
//! the common normals between consecutive axes, and DoF-to-SU rows to each SU's z axis with
//! `θ_acc`, `d_acc` for the rest — of an estimate, or of a truth written in that form.
//!
//! An SU's z axis is often almost parallel to its DoF's axis (a sensor mounted flat on a link whose
//! axis is normal to the skin). The common normal of two lines `ε` rad apart lies about `1/ε` away,
//! so an exact row would read `d = 963 m, d_acc = −963 m`. Below [`SU_PARALLEL_BELOW`] rad an SU row
//! is written as for parallel lines — the normal through the DoF frame's origin, the rest in `d_acc` —
//! which moves the SU's z axis by less than that angle, far below what any skin determines.

use nalgebra::{Isometry3, Vector3};

use super::LimbChain;
/// A DoF-to-DoF row of the paper's table (Fig. 6): `θ0, d, a, α`, m and rad.
pub use crate::model::description::DhEntry as DhRow;
/// A DoF-to-SU row of the paper's table (Fig. 6): `θ0, d, a, α, θ_acc, d_acc`, m and rad.
pub use crate::model::description::DhSensorEntry as SuRow;
use crate::model::{forward_kinematics, Robot};

/// Below this angle (rad) between a DoF's axis and an SU's z axis, the SU's row is written as for
/// parallel lines.
pub const SU_PARALLEL_BELOW: f64 = 1e-3;

/// Below this `sin²` of the angle between consecutive DoF axes, they are taken as parallel: a
/// DoF-to-DoF row is kept exact, since the next rows are built on its frame.
const DOF_PARALLEL_BELOW_SIN2: f64 = 1e-12;

/// The true DH table of `chain`, when the truth is written in the paper's DH form (DoFs placed by
/// DH rows on the previous DoF's segment, SUs by DH-plus-sensor rows); `None` otherwise.
pub fn true_dh_table(truth: &Robot, chain: &LimbChain) -> Option<(Vec<DhRow>, Vec<SuRow>)> {
    use crate::model::Parameterization as P;
    let m = &truth.model;
    let (dofs, su_names) = (chain.dofs(), chain.sus());
    let mut rows = Vec::new();
    for k in 1..dofs.len() {
        let dof = &m.dofs()[m.dof_index(&dofs[k])?];
        let previous = m.dof_index(&dofs[k - 1])?;
        if dof.origin.kind != P::StandardDh || m.segments()[dof.parent].parent_dof != Some(previous)
        {
            return None;
        }
        let v = &truth.parameters[dof.origin.range()];
        rows.push(DhRow::from_values(v));
    }
    let mut sus = Vec::new();
    for (k, name) in su_names.iter().enumerate() {
        let su = &m.sus()[m.su_index(name)?];
        if su.placement.kind != P::StandardDhSensor
            || m.segments()[su.segment].parent_dof != m.dof_index(&dofs[k])
        {
            return None;
        }
        let v = &truth.parameters[su.placement.range()];
        sus.push(SuRow::from_values(v));
    }
    Some((rows, sus))
}

/// The standard DH row that places the line `(point, direction)` (in `frame`'s coordinates) as the
/// next axis: x along the common normal from `frame`'s z to the line, `a ≥ 0`. For axes whose angle
/// has `sin² ≤ parallel_below_sin2` the normal through `frame`'s origin is taken (`d = 0`), and `α`
/// turns z towards the line about it; for intersecting axes `x = z × u`.
fn dh_to_line(
    point: &Vector3<f64>,
    direction: &Vector3<f64>,
    parallel_below_sin2: f64,
) -> (DhRow, Isometry3<f64>) {
    let u = direction.normalize();
    let b = u.z;
    let denominator = 1.0 - b * b;
    let (t, foot) = if denominator > parallel_below_sin2 {
        let t = (point.z - b * u.dot(point)) / denominator;
        let s = (b * point.z - u.dot(point)) / denominator;
        (t, point + u * s)
    } else {
        // Parallel: the foot on the line at the height of the origin.
        let s = if u.z.abs() > 0.0 { -point.z / u.z } else { 0.0 };
        (0.0, point + u * s)
    };
    let normal = foot - Vector3::new(0.0, 0.0, t);
    let a = normal.norm();
    let x = if a > 1e-12 {
        normal / a
    } else {
        let c = Vector3::z().cross(&u);
        if c.norm() > 1e-12 {
            c.normalize()
        } else {
            Vector3::x()
        }
    };
    let theta0 = x.y.atan2(x.x);
    let alpha = Vector3::z().cross(&u).dot(&x).atan2(u.z);
    let row = DhRow {
        theta0,
        d: t,
        a,
        alpha,
    };
    let frame = crate::model::transform::standard_dh(theta0, t, a, alpha);
    (row, frame)
}

/// Frames of a chain at the zero pose: (joint frames with z along each axis, SU frames).
pub type ChainFrames = (Vec<Isometry3<f64>>, Vec<Isometry3<f64>>);

/// The frames of a chain of any robot at the zero pose, in the robot's reference frame: every
/// DoF's joint frame turned so that its z axis is the DoF's axis, and every chain SU's frame.
pub fn chain_frames_at_zero(robot: &Robot, chain: &LimbChain) -> Option<ChainFrames> {
    let m = &robot.model;
    let dofs: Vec<usize> = chain
        .dofs()
        .iter()
        .map(|d| m.dof_index(d))
        .collect::<Option<_>>()?;
    let sus: Vec<usize> = chain
        .sus()
        .iter()
        .map(|s| m.su_index(s))
        .collect::<Option<_>>()?;
    let k = forward_kinematics(m, &robot.parameters, &vec![0.0; m.dofs().len()]);
    let joints = dofs
        .iter()
        .map(|&d| {
            let axis = m.dofs()[d].axis.into_inner();
            let align = nalgebra::UnitQuaternion::rotation_between(&Vector3::z(), &axis)
                .unwrap_or_else(|| {
                    nalgebra::UnitQuaternion::from_axis_angle(
                        &Vector3::x_axis(),
                        std::f64::consts::PI,
                    )
                });
            k.joints[d] * align
        })
        .collect();
    Some((joints, sus.iter().map(|&s| k.sus[s]).collect()))
}

/// The paper's DH+2 table (Fig. 6) of a chain of any robot that names its DoFs and SUs — an estimate
/// or the truth: DoF-to-DoF rows from the common normals between consecutive axes at the zero pose,
/// the first DH frame being the first joint's frame (the paper's `DoF1_T_RS = I`), and DoF-to-SU
/// rows to each SU's z axis, with `θ_acc`, `d_acc` for the rest.
pub fn dh_form(robot: &Robot, chain: &LimbChain) -> Option<(Vec<DhRow>, Vec<SuRow>)> {
    let (joints, su_frames) = chain_frames_at_zero(robot, chain)?;
    let base = joints[0];

    let mut frames = vec![Isometry3::identity()];
    let mut rows = Vec::new();
    for (i, joint) in joints.iter().enumerate().skip(1) {
        let next = base.inverse() * joint;
        let local = frames[i - 1].inverse() * next;
        let (row, step) = dh_to_line(
            &local.translation.vector,
            &(local.rotation * Vector3::z()),
            DOF_PARALLEL_BELOW_SIN2,
        );
        rows.push(row);
        frames.push(frames[i - 1] * step);
    }
    let mut su_rows = Vec::new();
    for (i, frame) in su_frames.iter().enumerate() {
        let su = frames[i].inverse() * (base.inverse() * frame);
        let (row, virtual_frame) = dh_to_line(
            &su.translation.vector,
            &(su.rotation * Vector3::z()),
            SU_PARALLEL_BELOW.sin().powi(2),
        );
        let rest = virtual_frame.inverse() * su;
        let x = rest.rotation * Vector3::x();
        su_rows.push(SuRow {
            theta0: row.theta0,
            d: row.d,
            a: row.a,
            alpha: row.alpha,
            theta_acc: x.y.atan2(x.x),
            d_acc: rest.translation.vector.z,
        });
    }
    Some((rows, su_rows))
}

#[cfg(test)]
mod tests {
    use super::*;
    use nalgebra::UnitQuaternion;

    /// The SU frame a row places: the DH step, then `θ_acc` about and `d_acc` along its z.
    fn su_frame(row: &SuRow) -> Isometry3<f64> {
        crate::model::transform::standard_dh(row.theta0, row.d, row.a, row.alpha)
            * Isometry3::from_parts(
                Vector3::new(0.0, 0.0, row.d_acc).into(),
                UnitQuaternion::from_axis_angle(&Vector3::z_axis(), row.theta_acc),
            )
    }

    fn su_row(point: Vector3<f64>, rotation: UnitQuaternion<f64>) -> SuRow {
        let (row, virtual_frame) = dh_to_line(
            &point,
            &(rotation * Vector3::z()),
            SU_PARALLEL_BELOW.sin().powi(2),
        );
        let rest = virtual_frame.inverse() * Isometry3::from_parts(point.into(), rotation);
        let x = rest.rotation * Vector3::x();
        SuRow {
            theta0: row.theta0,
            d: row.d,
            a: row.a,
            alpha: row.alpha,
            theta_acc: x.y.atan2(x.x),
            d_acc: rest.translation.vector.z,
        }
    }

    #[test]
    fn an_su_axis_a_hundred_thousandth_of_a_radian_off_its_dofs_reads_as_parallel() {
        // An SU 0.1 m out along x and 0.02 m along y, 0.3 m up, its z tilted 1e-5 rad about y
        // and turned 0.4 rad about z: by hand, the parallel row is θ0 = atan2(0.02, 0.1),
        // a = |(0.1, 0.02)|, d = 0, α ≈ 0, and d_acc ≈ 0.3, each to within what the tilt moves
        // over the SU's height (0.3 m × 1e-5 = 3e-6 m).
        let slack = 0.3 * 1e-5 * 1.5;
        let point = Vector3::new(0.1, 0.02, 0.3);
        let rotation = UnitQuaternion::from_axis_angle(&Vector3::y_axis(), 1e-5)
            * UnitQuaternion::from_axis_angle(&Vector3::z_axis(), 0.4);
        let row = su_row(point, rotation);
        assert!(
            (row.theta0 - 0.02f64.atan2(0.1)).abs() < slack / 0.1,
            "{row:?}"
        );
        assert!((row.a - 0.1f64.hypot(0.02)).abs() < slack, "{row:?}");
        assert!(row.d.abs() < 1e-12 && row.alpha.abs() < 2e-5, "{row:?}");
        assert!((row.d_acc - 0.3).abs() < slack, "{row:?}");
        assert!((row.theta_acc - (0.4 - row.theta0)).abs() < 1e-4, "{row:?}");
        // The row places the SU where it is, its z within the tilt.
        let placed = su_frame(&row);
        assert!((placed.translation.vector - point).norm() < slack);
        assert!(placed.rotation.angle_to(&rotation) < 2e-5);
    }

    #[test]
    fn an_su_axis_a_tenth_of_a_radian_off_its_dofs_keeps_its_common_normal() {
        // Beyond the threshold the row is exact: the SU line crosses the DoF's z axis's normal at
        // a finite foot, and the row puts the SU back to 1e-12.
        let point = Vector3::new(0.1, 0.02, 0.3);
        let rotation = UnitQuaternion::from_axis_angle(&Vector3::y_axis(), 0.1)
            * UnitQuaternion::from_axis_angle(&Vector3::z_axis(), 0.4);
        let row = su_row(point, rotation);
        let placed = su_frame(&row);
        assert!(
            (placed.translation.vector - point).norm() < 1e-12,
            "{row:?}"
        );
        assert!(placed.rotation.angle_to(&rotation) < 1e-12, "{row:?}");
        assert!((row.alpha.abs() - 0.1).abs() < 1e-12, "{row:?}");
    }
}
