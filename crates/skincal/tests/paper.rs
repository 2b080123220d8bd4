//! The `paper-7dof` preset against the paper's own table (`shared/reference/paper-fig6.toml`).

use approx::assert_relative_eq;
use nalgebra::{Matrix4, Vector3};
use skincal::model::presets;
use skincal::model::sensor::{
    gravity_upright, peak_dynamic_accelerations, static_readings, ExcitationPattern,
};

use crate::common::{dh_matrix, sensor_matrix};

/// The `real` columns of the paper's table: DoF-DoF rows and DoF-SU rows.
fn paper_table() -> (Vec<[f64; 4]>, Vec<[f64; 6]>) {
    let path = std::path::Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("../../../shared/reference/paper-fig6.toml");
    let text = std::fs::read_to_string(&path).unwrap_or_else(|e| {
        panic!(
            "{}: {e} (the shared reference folder must sit beside the repository)",
            path.display()
        )
    });
    let doc: toml::Table = text.parse().unwrap();
    let real = |t: &toml::Value, key: &str| t[key]["real"].as_float().unwrap();
    let rows = doc["dof_dof"]
        .as_array()
        .unwrap()
        .iter()
        .map(|t| {
            [
                real(t, "theta0"),
                real(t, "d"),
                real(t, "a"),
                real(t, "alpha"),
            ]
        })
        .collect();
    let sus = doc["dof_su"]
        .as_array()
        .unwrap()
        .iter()
        .map(|t| {
            [
                real(t, "theta0"),
                real(t, "d"),
                real(t, "a"),
                real(t, "alpha"),
                real(t, "theta_acc"),
                real(t, "d_acc"),
            ]
        })
        .collect();
    (rows, sus)
}

#[test]
fn preset_holds_exactly_the_papers_real_values() {
    let robot = presets::find("paper-7dof").unwrap().robot().unwrap();
    let (rows, sus) = paper_table();
    assert_eq!(robot.model.dofs().len(), 7);
    assert_eq!(robot.model.sus().len(), 7);
    for (n, row) in rows.iter().enumerate() {
        let dof = format!("dof{}", n + 2);
        for (name, value) in ["theta0", "d", "a", "alpha"].iter().zip(row) {
            assert_eq!(
                robot.parameter(&format!("{dof}.origin.{name}")),
                Some(*value),
                "{dof}.{name}"
            );
        }
    }
    for (n, su) in sus.iter().enumerate() {
        let name = format!("su{}", n + 1);
        for (p, value) in ["theta0", "d", "a", "alpha", "theta_acc", "d_acc"]
            .iter()
            .zip(su)
        {
            assert_eq!(
                robot.parameter(&format!("{name}.{p}")),
                Some(*value),
                "{name}.{p}"
            );
        }
        // SU n sits on the segment that DoF n moves directly.
        let segment = robot.model.sus()[n].segment;
        assert_eq!(robot.model.segments()[segment].parent_dof, Some(n));
    }
}

#[test]
fn one_su_reading_in_one_pose_matches_an_independent_computation() {
    let robot = presets::find("paper-7dof").unwrap().robot().unwrap();
    let (rows, sus) = paper_table();
    let q = [0.5, -1.2, 2.0, 0.3, -2.5, 1.1, 0.7];
    // SU 5: eq. 4 as explicit matrix products of eq. 5 and eq. 7 (DoF1_T_RS = I).
    let mut t = Matrix4::<f64>::identity();
    for j in 0..4 {
        let r = rows[j];
        t *= dh_matrix(r[0] + q[j], r[1], r[2], r[3]);
    }
    let s = sus[4];
    let t_su = t * dh_matrix(s[0] + q[4], s[1], s[2], s[3]) * sensor_matrix(s[4], s[5]);
    let rotation = t_su.fixed_view::<3, 3>(0, 0).into_owned();
    let expected_static = rotation.transpose() * Vector3::new(0.0, 0.0, 9.81);
    let got = static_readings(&robot.model, &robot.parameters, &q, &gravity_upright());
    assert_relative_eq!(got[4], expected_static, epsilon = 1e-12);

    // Its dynamic acceleration for DoF 3: α z3 × (p_SU − p_3), with DoF 3's frame the product of
    // the first two DH matrices (its axis is that frame's z).
    let t3 = dh_matrix(rows[0][0] + q[0], rows[0][1], rows[0][2], rows[0][3])
        * dh_matrix(rows[1][0] + q[1], rows[1][1], rows[1][2], rows[1][3]);
    let z3 = t3.fixed_view::<3, 1>(0, 2).into_owned();
    let p3 = t3.fixed_view::<3, 1>(0, 3).into_owned();
    let p_su = t_su.fixed_view::<3, 1>(0, 3).into_owned();
    let alpha = 2.0 * std::f64::consts::PI * 2.0 * 0.5;
    let expected_dynamic = rotation.transpose() * (alpha * z3.cross(&(p_su - p3)));
    let got = peak_dynamic_accelerations(
        &robot.model,
        &robot.parameters,
        &q,
        2,
        &ExcitationPattern::default(),
    );
    assert_relative_eq!(got[4], expected_dynamic, epsilon = 1e-12);
    // The first DoF's frame is the reference frame and its axis is vertical: turning it leaves
    // every static reading's z component unchanged.
    let mut turned = q;
    turned[0] += 1.0;
    let a = static_readings(&robot.model, &robot.parameters, &q, &gravity_upright());
    let b = static_readings(&robot.model, &robot.parameters, &turned, &gravity_upright());
    for (x, y) in a.iter().zip(&b) {
        assert_relative_eq!(x, y, epsilon = 1e-12);
    }
}
