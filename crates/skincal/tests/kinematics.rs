//! Forward kinematics and the sensor model: a 2-link arm by hand, properties on random DH chains,
//! the paper's numerical eq. 9 and dual-number derivatives.

use std::f64::consts::PI;

use approx::assert_relative_eq;
use nalgebra::{DVector, Matrix3, Matrix4, Vector3};
use proptest::prelude::*;
use skincal::model::description::RobotFile;
use skincal::model::sensor::{
    gravity_upright, numerical_accelerations_at, numerical_peak_accelerations,
    peak_dynamic_accelerations, readings_during_pattern, static_readings, ExcitationPattern,
};
use skincal::model::{
    forward_kinematics, DofSpec, Limits, PlacementSpec, Robot, RobotBuilder, SuSpec,
};

use crate::common::{dh_matrix, sensor_matrix};

/// A planar 2-link arm turning about horizontal y axes: shoulder at the origin, elbow 0.5 m along
/// the first link's x, SU `tip` 0.3 m along the second link's x, SU `tip_yawed` at the same place
/// turned 90° about its z.
fn two_link() -> Robot {
    RobotFile::from_toml(
        r#"
        name = "two-link"
        reference = "base"
        [[dofs]]
        name = "shoulder"
        child = "upper"
        axis = [0, 1, 0]
        [[dofs]]
        name = "elbow"
        child = "lower"
        origin = { xyz = [0.5, 0, 0] }
        axis = [0, 1, 0]
        [[sus]]
        name = "tip"
        segment = "lower"
        xyz = [0.3, 0, 0]
        [[sus]]
        name = "tip_yawed"
        segment = "lower"
        xyz = [0.3, 0, 0]
        rpy = [0, 0, 1.5707963267948966]
        "#,
    )
    .unwrap()
    .build()
    .unwrap()
}

#[test]
fn two_link_arm_readings_match_hand_computation() {
    let robot = two_link();
    let (q1, q2) = (0.3, 0.5);
    let q = [q1, q2];
    let g = 9.81;
    // Static: the SU frame is Ry(q1 + q2); it reads Ry(-(q1+q2))·(0, 0, g) = (-g sin θ, 0, g cos θ).
    let theta: f64 = q1 + q2;
    let r = static_readings(&robot.model, &robot.parameters, &q, &gravity_upright());
    assert_relative_eq!(
        r[0],
        Vector3::new(-g * theta.sin(), 0.0, g * theta.cos()),
        epsilon = 1e-12
    );
    // Turned 90° about its z, the second SU reads (y, -x, z) of the first.
    assert_relative_eq!(
        r[1],
        Vector3::new(0.0, g * theta.sin(), g * theta.cos()),
        epsilon = 1e-12
    );

    // Dynamic at the pattern peak, α = 2πfA = 2π for A = 0.5 rad/s, f = 2 Hz.
    let pattern = ExcitationPattern::default();
    let alpha = 2.0 * PI;
    // Elbow: the SU lies 0.3 m along its own x from the axis y, so α y × r = α·0.3·(−z).
    let elbow = peak_dynamic_accelerations(&robot.model, &robot.parameters, &q, 1, &pattern);
    assert_relative_eq!(
        elbow[0],
        Vector3::new(0.0, 0.0, -0.3 * alpha),
        epsilon = 1e-12
    );
    // Shoulder: in the SU frame r = (0.5 cos q2 + 0.3, 0, 0.5 sin q2) and the axis is y,
    // so α y × r = α (r_z, 0, −r_x).
    let shoulder = peak_dynamic_accelerations(&robot.model, &robot.parameters, &q, 0, &pattern);
    let expected = Vector3::new(0.5 * q2.sin(), 0.0, -(0.5 * q2.cos() + 0.3)) * alpha;
    assert_relative_eq!(shoulder[0], expected, epsilon = 1e-12);
    assert_relative_eq!(
        shoulder[1],
        Vector3::new(expected.y, -expected.x, expected.z),
        epsilon = 1e-12
    );
    // Hand values, so that a sign slip in the formulas above cannot hide: 2π·(0.2397, 0, −0.7388).
    assert_relative_eq!(
        shoulder[0],
        Vector3::new(1.50616, 0.0, -4.64190),
        epsilon = 1e-4
    );
}

#[test]
fn a_resting_su_facing_up_reads_plus_g_on_z() {
    let robot = two_link();
    let r = static_readings(
        &robot.model,
        &robot.parameters,
        &[0.0, 0.0],
        &gravity_upright(),
    );
    assert_relative_eq!(r[0], Vector3::new(0.0, 0.0, 9.81), epsilon = 1e-12);
}

#[test]
fn a_dof_does_not_move_sus_before_it() {
    let robot = two_link();
    let b = RobotBuilder {
        sus: vec![SuSpec {
            name: "on_upper".into(),
            segment: "upper".into(),
            placement: PlacementSpec::xyz_rpy([0.2, 0.0, 0.0], [0.0; 3]),
        }],
        ..robot.to_builder()
    };
    let robot = b.build().unwrap();
    let elbow = peak_dynamic_accelerations(
        &robot.model,
        &robot.parameters,
        &[0.4, -0.2],
        1,
        &ExcitationPattern::default(),
    );
    assert_eq!(elbow[0], Vector3::zeros());
}

/// A serial chain of `n` DoFs with DH rows, one SU per segment with a DH+sensor placement.
fn dh_chain(rows: &[[f64; 4]], sus: &[[f64; 6]]) -> Robot {
    let mut b = RobotBuilder::new("chain", "s0");
    for (i, su) in sus.iter().enumerate() {
        let origin = if i == 0 {
            PlacementSpec::identity()
        } else {
            let r = rows[i - 1];
            PlacementSpec::dh(r[0], r[1], r[2], r[3])
        };
        b.dofs.push(DofSpec {
            name: format!("d{}", i + 1),
            parent: format!("s{i}"),
            child: format!("s{}", i + 1),
            origin,
            axis: Vector3::z(),
            kind: skincal::model::DofKind::Revolute,
            limits: Limits::CONTINUOUS,
            mimic: None,
        });
        b.sus.push(SuSpec {
            name: format!("su{}", i + 1),
            segment: format!("s{}", i + 1),
            placement: PlacementSpec::dh_sensor(su[0], su[1], su[2], su[3], su[4], su[5]),
        });
    }
    b.build().unwrap()
}

/// The paper's eq. 4 by matrix products: reference → SU `k` (0-based) of a DH chain.
fn chain_product(rows: &[[f64; 4]], sus: &[[f64; 6]], q: &[f64], k: usize) -> Matrix4<f64> {
    let mut t = Matrix4::<f64>::identity();
    for j in 0..k {
        let r = rows[j];
        t *= dh_matrix(r[0] + q[j], r[1], r[2], r[3]);
    }
    let s = sus[k];
    t * dh_matrix(s[0] + q[k], s[1], s[2], s[3]) * sensor_matrix(s[4], s[5])
}

fn chain_strategy() -> impl Strategy<Value = (Vec<[f64; 4]>, Vec<[f64; 6]>, Vec<f64>)> {
    (1usize..=7).prop_flat_map(|n| {
        let row = (-PI..PI, -1.0..1.0, 0.0..1.0, -PI..PI).prop_map(|(t, d, a, al)| [t, d, a, al]);
        let su = (-PI..PI, -1.0..1.0, 0.0..1.0, -PI..PI, -PI..PI, -1.0..1.0)
            .prop_map(|(t, d, a, al, ta, da)| [t, d, a, al, ta, da]);
        (
            prop::collection::vec(row, n.saturating_sub(1)),
            prop::collection::vec(su, n),
            prop::collection::vec(-2.62..2.62, n),
        )
    })
}

proptest! {
    #![proptest_config(ProptestConfig {
        cases: 128,
        rng_seed: proptest::test_runner::RngSeed::Fixed(20261121),
        failure_persistence: Some(Box::new(proptest::test_runner::FileFailurePersistence::Direct("tests/proptest-regressions/kinematics.txt"))),
        ..ProptestConfig::default()
    })]

    #[test]
    fn fk_of_a_chain_is_the_product_of_its_links((rows, sus, q) in chain_strategy()) {
        let robot = dh_chain(&rows, &sus);
        let k = forward_kinematics(&robot.model, &robot.parameters, &q);
        for i in 0..sus.len() {
            let expected = chain_product(&rows, &sus, &q, i);
            let got = k.sus[i].to_homogeneous();
            prop_assert!((got - expected).abs().max() < 1e-12, "SU {i}: {got} vs {expected}");
        }
    }

    #[test]
    fn rotations_stay_orthonormal((rows, sus, q) in chain_strategy()) {
        let robot = dh_chain(&rows, &sus);
        let k = forward_kinematics(&robot.model, &robot.parameters, &q);
        for f in k.sus.iter().chain(&k.segments).chain(&k.joints) {
            let r: Matrix3<f64> = f.rotation.to_rotation_matrix().into_inner();
            prop_assert!((r.transpose() * r - Matrix3::identity()).abs().max() < 1e-12);
            prop_assert!((r.determinant() - 1.0).abs() < 1e-12);
        }
    }

    #[test]
    fn analytic_dynamic_acceleration_equals_numerical_second_difference((rows, sus, q) in chain_strategy()) {
        let robot = dh_chain(&rows, &sus);
        let pattern = ExcitationPattern::default();
        let k = forward_kinematics(&robot.model, &robot.parameters, &q);
        // eq. 9 with h = 1/(1000 f) has truncation error h²/12·|p⁗(0)|; with ω = 2πf and
        // α = 2πfA, |p⁗(0)| ≤ (ω²α + 3α²)·|r| for an SU at distance |r| from the axis.
        let h = 1.0 / (1000.0 * pattern.frequency);
        let (w, alpha) = (2.0 * PI * pattern.frequency, pattern.peak_acceleration());
        for d in 0..q.len() {
            let analytic = peak_dynamic_accelerations(&robot.model, &robot.parameters, &q, d, &pattern);
            let numeric = numerical_peak_accelerations(&robot.model, &robot.parameters, &q, d, &pattern);
            for (su, (a, n)) in analytic.iter().zip(&numeric).enumerate() {
                let r = (k.su_position(su) - k.axis_point(d)).norm();
                let bound = h * h / 12.0 * (w * w * alpha + 3.0 * alpha * alpha) * r + 1e-8;
                prop_assert!((a - n).norm() <= bound, "DoF {d}: {a} vs {n}, bound {bound}");
            }
        }
    }
}

#[test]
fn reading_at_any_time_of_a_pattern_equals_the_numerical_one_plus_gravity() {
    let rows = [[0.1, 0.1, 0.2, 1.57], [0.2, 0.1, 0.3, 1.57]];
    let sus = [
        [0.1, 0.05, 0.11, 1.0, 0.1, 0.05],
        [0.22, 0.1, 0.12, 0.0, -0.11, 0.1],
        [-0.13, 0.05, 0.1, 0.05, 0.2, 0.05],
    ];
    let robot = dh_chain(&rows, &sus);
    let q = [0.4, -1.1, 2.0];
    let g = gravity_upright();
    let pattern = ExcitationPattern {
        amplitude: 0.8,
        frequency: 1.5,
    };
    for d in 0..3 {
        for t in [0.0, 0.07, 0.2, 0.31, 0.5] {
            let general =
                readings_during_pattern(&robot.model, &robot.parameters, &q, &g, d, &pattern, t);
            let kinematic = numerical_accelerations_at(
                &robot.model,
                &robot.parameters,
                &q,
                d,
                &pattern,
                t,
                1e-4,
            );
            let mut qt = q.to_vec();
            qt[d] += pattern.angle(t);
            let k = forward_kinematics(&robot.model, &robot.parameters, &qt);
            for su in 0..3 {
                let expected = kinematic[su] - k.sus[su].rotation.inverse_transform_vector(&g);
                assert!(
                    (general[su] - expected).norm() < 1e-5,
                    "DoF {d}, t {t}, SU {su}: {} vs {expected}",
                    general[su]
                );
            }
        }
    }
    // At the peak the general reading is the static one plus the peak dynamic acceleration.
    let peak = readings_during_pattern(&robot.model, &robot.parameters, &q, &g, 1, &pattern, 0.0);
    let still = static_readings(&robot.model, &robot.parameters, &q, &g);
    let dynamic = peak_dynamic_accelerations(&robot.model, &robot.parameters, &q, 1, &pattern);
    for su in 0..3 {
        assert_relative_eq!(peak[su], still[su] + dynamic[su], epsilon = 1e-12);
    }
}

#[test]
fn pattern_derivatives_are_consistent() {
    let p = ExcitationPattern {
        amplitude: 0.5,
        frequency: 2.0,
    };
    let h = 1e-5;
    for t in [0.0, 0.1, 0.13, 0.37] {
        assert_relative_eq!(
            (p.angle(t + h) - p.angle(t - h)) / (2.0 * h),
            p.velocity(t),
            epsilon = 1e-8
        );
        assert_relative_eq!(
            (p.velocity(t + h) - p.velocity(t - h)) / (2.0 * h),
            p.acceleration(t),
            epsilon = 1e-6
        );
    }
    assert_eq!(p.angle(0.0), 0.0);
    assert_relative_eq!(p.angle(1.0 / p.frequency), 0.0, epsilon = 1e-15);
    assert_relative_eq!(p.angle(0.5 / p.frequency), p.excursion(), epsilon = 1e-15);
}

#[test]
fn dual_number_derivatives_match_central_differences() {
    use num_dual::{jacobian, DualDVec64};
    let rows = [
        [0.1, 0.1, 0.2, 1.57],
        [0.2, 0.1, 0.3, 1.57],
        [-0.1, 0.0, 0.3, 1.57],
    ];
    let sus = [
        [0.1, 0.05, 0.11, 1.0, 0.1, 0.05],
        [0.22, 0.1, 0.12, 0.0, -0.11, 0.1],
        [-0.13, 0.05, 0.1, 0.05, 0.2, 0.05],
        [0.27, -0.05, 0.09, -0.07, 0.2, -0.05],
    ];
    let robot = dh_chain(&rows, &sus);
    let model = &robot.model;
    let q = [0.3, -0.7, 1.2, 2.0];
    let pattern = ExcitationPattern::default();
    // Static and dynamic readings of every SU as a function of all parameters.
    let readings = |p: &[DualDVec64]| -> Vec<DualDVec64> {
        let qd: Vec<DualDVec64> = q.iter().map(|&x| DualDVec64::from_re(x)).collect();
        let g = gravity_upright().map(DualDVec64::from_re);
        let mut out = Vec::new();
        for r in static_readings(model, p, &qd, &g) {
            out.extend(r.iter().cloned());
        }
        for d in 0..q.len() {
            for r in peak_dynamic_accelerations(model, p, &qd, d, &pattern) {
                out.extend(r.iter().cloned());
            }
        }
        out
    };
    let x = DVector::from_vec(robot.parameters.clone());
    let (values, jac) = jacobian(
        |p: DVector<DualDVec64>| DVector::from_vec(readings(p.as_slice())),
        &x,
    );
    let f64_readings = |p: &[f64]| -> Vec<f64> {
        let mut out = Vec::new();
        for r in static_readings(model, p, &q, &gravity_upright()) {
            out.extend(r.iter());
        }
        for d in 0..q.len() {
            for r in peak_dynamic_accelerations(model, p, &q, d, &pattern) {
                out.extend(r.iter());
            }
        }
        out
    };
    assert_eq!(
        values.as_slice(),
        f64_readings(&robot.parameters).as_slice()
    );
    let h = 1e-6;
    for j in 0..robot.parameters.len() {
        let (mut plus, mut minus) = (robot.parameters.clone(), robot.parameters.clone());
        plus[j] += h;
        minus[j] -= h;
        let (fp, fm) = (f64_readings(&plus), f64_readings(&minus));
        for i in 0..fp.len() {
            let numeric = (fp[i] - fm[i]) / (2.0 * h);
            assert!(
                (jac[(i, j)] - numeric).abs() < 1e-6 * (1.0 + numeric.abs()),
                "d reading {i} / d {}: {} vs {numeric}",
                model.parameter_names()[j],
                jac[(i, j)]
            );
        }
    }
}

/// The motion of every segment and the specific force of every SU, from
/// [`skincal::model::segment_motion`], against central differences of the forward kinematics along
/// a smooth trajectory of a random tree (the SU's position differenced twice, its rotation's rate
/// and the rate of that): the velocity recursion is checked by nothing but the positions.
#[test]
fn segment_motion_is_the_second_derivative_of_the_forward_kinematics() {
    use skincal::sim::{random_tree, RandomTreeConfig};
    let config = RandomTreeConfig {
        dofs: 9,
        sus: 14,
        ..RandomTreeConfig::default()
    };
    let robot = random_tree(&config, 11).unwrap();
    motion_matches_differences(&robot);
    // The same tree with every third DoF sliding along its axis instead of turning about it.
    let mut builder = robot.to_builder();
    for d in builder.dofs.iter_mut().step_by(3) {
        d.kind = skincal::model::DofKind::Prismatic;
        d.limits = Limits {
            lower: -0.5,
            upper: 0.5,
            ..d.limits
        };
    }
    let sliding = builder.build().unwrap();
    assert_eq!(sliding.model.prismatic_dof_names().len(), 3);
    motion_matches_differences(&sliding);
}

fn motion_matches_differences(robot: &skincal::model::Robot) {
    use skincal::model::{segment_motion, specific_force};
    let n = robot.model.dofs().len();
    // q(t) = a sin(w t + phase): every DoF moving, with velocity and acceleration at once.
    let at = |t: f64, order: u32| -> Vec<f64> {
        (0..n)
            .map(|d| {
                let (a, w, phase) = (0.4 + 0.05 * d as f64, 1.3 + 0.37 * d as f64, 0.7 * d as f64);
                let x = w * t + phase;
                a * w.powi(order as i32)
                    * match order % 4 {
                        0 => x.sin(),
                        1 => x.cos(),
                        2 => -x.sin(),
                        _ => -x.cos(),
                    }
            })
            .collect()
    };
    let g = Vector3::new(0.3, -0.2, -9.81);
    let h = 1e-4;
    for &t in &[0.0, 0.37, 1.9] {
        let frames = |t: f64| forward_kinematics(&robot.model, &robot.parameters, &at(t, 0));
        let (before, now, after) = (frames(t - h), frames(t), frames(t + h));
        let motion = segment_motion(&robot.model, &now, &at(t, 1), &at(t, 2));
        for (u, su) in robot.model.sus().iter().enumerate() {
            let p = |f: &skincal::model::Kinematics<f64>| f.sus[u].translation.vector;
            let accel = (p(&after) - 2.0 * p(&now) + p(&before)) / (h * h);
            let m = &motion[su.segment];
            let analytic = m.point_acceleration(&p(&now));
            assert!(
                (analytic - accel).norm() < 1e-4 * (1.0 + accel.norm()),
                "SU {u} at t = {t}: {analytic:?} against {accel:?}"
            );
            // Angular velocity: the rotation's rate, R(t+h) R(t−h)ᵀ ≈ exp(2h [ω]×).
            let turn = after.sus[u].rotation * before.sus[u].rotation.inverse();
            let omega = turn.scaled_axis() / (2.0 * h);
            assert!(
                (m.omega - omega).norm() < 1e-6 * (1.0 + omega.norm()),
                "ω of SU {u}"
            );
            let force = specific_force(&now.sus[u], m, &g);
            let expected = now.sus[u].rotation.inverse() * (accel - g);
            assert!((force - expected).norm() < 1e-4 * (1.0 + expected.norm()));
        }
        // Angular acceleration: the rate of the angular velocity.
        let omega_at = |t: f64| segment_motion(&robot.model, &frames(t), &at(t, 1), &at(t, 2));
        let (wb, wa) = (omega_at(t - h), omega_at(t + h));
        for (s, m) in motion.iter().enumerate() {
            let alpha = (wa[s].omega - wb[s].omega) / (2.0 * h);
            assert!(
                (m.alpha - alpha).norm() < 1e-5 * (1.0 + alpha.norm()),
                "α of segment {s}"
            );
        }
    }
}
