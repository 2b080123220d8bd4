//! The maximum-likelihood estimator against the simulator's ground truth, central differences and
//! a constructed unobservable case.

use nalgebra::{UnitQuaternion, Vector3};
use skincal::estimate::ml::{estimate_limb, internals, state_of, MlConfig};
use skincal::estimate::{consecutive_su_errors, LimbChain, LimbData};
use skincal::model::description::RobotFile;
use skincal::model::presets;
use skincal::model::sensor::gravity_upright;
use skincal::sim::{simulate, Imperfections, SimulationConfig};

fn chain(n: usize) -> LimbChain {
    let dofs: Vec<String> = (1..=n).map(|k| format!("dof{k}")).collect();
    let sus: Vec<String> = (1..=n).map(|k| format!("su{k}")).collect();
    LimbChain::serial("chain", &dofs, &sus).unwrap()
}

/// The data of `truth` simulated with the paper's noise from `seed`, as one 7-DoF chain.
fn paper_noise_data(truth: &skincal::model::Robot, seed: u64) -> LimbData {
    let sim = simulate(
        truth,
        &SimulationConfig {
            seed,
            ..SimulationConfig::default()
        },
    )
    .unwrap();
    LimbData::new(&sim.measurements, &chain(7)).unwrap()
}

fn noise_free() -> SimulationConfig {
    SimulationConfig {
        imperfections: Imperfections::none(),
        ..SimulationConfig::default()
    }
}

#[test]
fn noise_free_data_gives_back_the_poses() {
    let truth = presets::find("paper-7dof").unwrap().robot().unwrap();
    let sim = simulate(&truth, &noise_free()).unwrap();
    let data = LimbData::new(&sim.measurements, &chain(7)).unwrap();
    let estimate = estimate_limb(
        &data,
        None,
        &MlConfig {
            noise_sd: 1e-3,
            ..MlConfig::default()
        },
    )
    .unwrap();
    assert!(estimate.converged);
    assert!(
        estimate.residual_ratio < 1e-6,
        "{}",
        estimate.residual_ratio
    );
    let a = consecutive_su_errors(&truth, &estimate.to_robot(), &chain(7), 30, 5).unwrap();
    assert!(a.position_max <= 1e-6, "{} m", a.position_max);
    assert!(a.rotation_max <= 1e-6, "{} rad", a.rotation_max);
    for pair in &a.pairs {
        assert!(
            pair.position_max <= 1e-6 && pair.rotation_max <= 1e-6,
            "{pair:?}"
        );
    }
    // Gravity comes back along the first axis with its true magnitude.
    let g = Vector3::from(estimate.gravity);
    assert!((g - Vector3::new(0.0, 0.0, -9.81)).norm() < 1e-6, "{g}");
}

/// A random 5-DoF chain in DH form within eq. 18's bounds, as a description.
fn random_chain(seed: u64) -> skincal::model::Robot {
    use rand::{Rng, SeedableRng};
    let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(seed);
    let mut text = String::from("name = \"r\"\nreference = \"base\"\n");
    let pi = std::f64::consts::PI;
    for k in 1..=5 {
        text += &format!("[[dofs]]\nname = \"dof{k}\"\nchild = \"l{k}\"\n");
        if k > 1 {
            text += &format!(
                "dh = {{ theta0 = {}, d = {}, a = {}, alpha = {} }}\n",
                rng.random_range(-pi..pi),
                rng.random_range(-0.3..0.3),
                rng.random_range(0.05..0.4),
                rng.random_range(-pi..pi)
            );
        }
    }
    for k in 1..=5 {
        text += &format!(
            "[[sus]]\nname = \"su{k}\"\nsegment = \"l{k}\"\nxyz = [{}, {}, {}]\nrpy = [{}, {}, {}]\n",
            rng.random_range(-0.15..0.15),
            rng.random_range(-0.15..0.15),
            rng.random_range(-0.15..0.15),
            rng.random_range(-pi..pi),
            rng.random_range(-1.5..1.5),
            rng.random_range(-pi..pi)
        );
    }
    RobotFile::from_toml(&text).unwrap().build().unwrap()
}

#[test]
fn the_readings_jacobian_matches_central_differences_on_random_chains() {
    for seed in 0..4 {
        let truth = random_chain(seed);
        // Seeds 2 and 3 with two poses in a second base orientation (a gravity block of its own).
        let tilted_poses = if seed >= 2 { 2 } else { 0 };
        let sim = simulate(
            &truth,
            &SimulationConfig {
                poses: 6,
                seed,
                tilted_poses,
                ..SimulationConfig::default()
            },
        )
        .unwrap();
        let data = LimbData::new(&sim.measurements, &chain(5)).unwrap();
        // Linearised at the truth, which with noisy readings is not the optimum.
        let mut state = state_of(&truth, &chain(5), &gravity_upright()).unwrap();
        if let Some(g) = sim.truth.tilted_training_gravity {
            // A tilted gravity in the chain's frame (its value does not matter to the check).
            let turn = UnitQuaternion::rotation_between(&gravity_upright(), &state.gravity)
                .unwrap_or_else(UnitQuaternion::identity);
            state.other_gravities = vec![turn * Vector3::from(g)];
        }
        let (_, jac) = internals::full_problem(&data, &state, 0.05);
        let h = 1e-6;
        for c in 0..jac.ncols() {
            let mut plus = vec![0.0; jac.ncols()];
            plus[c] = h;
            let mut minus = vec![0.0; jac.ncols()];
            minus[c] = -h;
            let numeric = (internals::residuals_after(&data, &state, 0.05, &plus)
                - internals::residuals_after(&data, &state, 0.05, &minus))
                / (2.0 * h);
            let diff = (&numeric - jac.column(c)).amax();
            // Central differences err by O(h²) and by rounding ~1e-16·|r|/h: √h is a safe bound.
            assert!(
                diff < 1e-3 * (1.0 + numeric.amax()),
                "seed {seed}, column {c}: {diff}"
            );
        }
    }
}

#[test]
fn parallel_axes_leave_directions_the_data_cannot_see_and_they_are_named() {
    // Three DoFs with parallel horizontal axes (α = 0): the planar arm's offsets along the axes are
    // invisible to every reading.
    let text = "name = \"planar\"\nreference = \"base\"\n\
        [[dofs]]\nname = \"dof1\"\nchild = \"l1\"\norigin = { rpy = [1.5707963267948966, 0, 0] }\n\
        [[dofs]]\nname = \"dof2\"\nchild = \"l2\"\ndh = { theta0 = 0.3, d = 0.05, a = 0.3, alpha = 0.0 }\n\
        [[dofs]]\nname = \"dof3\"\nchild = \"l3\"\ndh = { theta0 = -0.2, d = 0.02, a = 0.25, alpha = 0.0 }\n\
        [[sus]]\nname = \"su1\"\nsegment = \"l1\"\nxyz = [0.1, 0.02, 0.03]\nrpy = [0.2, 0.1, 0.3]\n\
        [[sus]]\nname = \"su2\"\nsegment = \"l2\"\nxyz = [0.12, -0.03, 0.04]\nrpy = [-0.3, 0.2, 0.1]\n\
        [[sus]]\nname = \"su3\"\nsegment = \"l3\"\nxyz = [0.08, 0.02, -0.05]\nrpy = [0.1, -0.4, 0.6]\n";
    let truth = RobotFile::from_toml(text).unwrap().build().unwrap();
    let sim = simulate(
        &truth,
        &SimulationConfig {
            seed: 2,
            ..SimulationConfig::default()
        },
    )
    .unwrap();
    let data = LimbData::new(&sim.measurements, &chain(3)).unwrap();
    let estimate = estimate_limb(&data, None, &MlConfig::default()).unwrap();
    assert!(estimate.converged, "{}", estimate.residual_ratio);
    let named: Vec<String> = estimate
        .unobservable
        .iter()
        .flat_map(|u| u.parameters.clone())
        .collect();
    assert!(named.len() >= 2, "{named:?}");
    // Every SU's position along the common axis direction (z of its segment frame) is among them.
    for su in ["su2.z", "su3.z"] {
        assert!(named.iter().any(|n| n == su), "{su} not in {named:?}");
    }
}

#[test]
fn the_same_data_gives_the_same_estimate() {
    let truth = presets::find("paper-7dof").unwrap().robot().unwrap();
    let data = paper_noise_data(&truth, 4);
    let a = estimate_limb(&data, None, &MlConfig::default()).unwrap();
    let b = estimate_limb(&data, None, &MlConfig::default()).unwrap();
    assert_eq!(a.robot, b.robot);
    assert_eq!(a.uncertainty, b.uncertainty);
    assert!(
        a.converged && (a.residual_ratio - 1.0).abs() < 0.15,
        "{}",
        a.residual_ratio
    );
}

#[test]
fn with_the_papers_noise_the_error_is_near_the_bound_and_the_sds_are_honest() {
    // Over 5 data sets the consecutive-SU error stays within 1.5× the Cramér–Rao bound, and the
    // reported standard deviations describe the actual errors of the later SUs.
    let truth = presets::find("paper-7dof").unwrap().robot().unwrap();
    let sd = 0.01 * 9.81 / 3f64.sqrt();
    let (mut err, mut bound) = (0.0, 0.0);
    for seed in 1..=5 {
        let data = paper_noise_data(&truth, seed);
        let e = estimate_limb(&data, None, &MlConfig::default()).unwrap();
        assert!(e.converged, "seed {seed}");
        let a = consecutive_su_errors(&truth, &e.to_robot(), &chain(7), 30, seed).unwrap();
        err += a.position_rms.powi(2);
        let (p, _) = skincal::estimate::ml::cramer_rao_bound(
            &truth,
            &gravity_upright(),
            &data,
            sd,
            30,
            seed,
            skincal::estimate::ml::IntrinsicsModel::BiasScale,
        )
        .unwrap();
        bound += p * p;
        for u in &e.uncertainty[2..] {
            assert!(u.position_sd > 1e-4 && u.position_sd < 0.02, "{u:?}");
        }
    }
    assert!(
        err.sqrt() < 1.5 * bound.sqrt(),
        "{} vs bound {}",
        err.sqrt(),
        bound.sqrt()
    );
}

#[test]
fn what_no_reading_tells_is_listed_as_undetermined_never_given_a_deviation() {
    // The paper's arm starts at the reference with one vertical DoF: where along that axis its
    // first SU sits, and how far it is turned about it, no reading tells (the gauge holds them).
    let truth = presets::find("paper-7dof").unwrap().robot().unwrap();
    let data = paper_noise_data(&truth, 1);
    let e = estimate_limb(&data, None, &MlConfig::default()).unwrap();
    // The length of `v`'s share in the span of `basis` (orthonormal).
    let share = |basis: &[[f64; 3]], v: Vector3<f64>| {
        basis
            .iter()
            .map(|b| Vector3::from(*b).dot(&v).powi(2))
            .sum::<f64>()
            .sqrt()
    };
    let first = &e.uncertainty[0];
    // The limb's reference frame is its first joint frame: the first axis is its z.
    let z = Vector3::z();
    assert!(
        (share(&first.undetermined_position, z) - 1.0).abs() < 1e-6,
        "{first:?}"
    );
    let robot = e.to_robot();
    let k = skincal::model::forward_kinematics(&robot.model, &robot.parameters, &[0.0; 7]);
    let own_axis = k.sus[0].rotation.inverse() * z;
    assert!(
        (share(&first.undetermined_orientation, own_axis) - 1.0).abs() < 1e-6,
        "{first:?}"
    );
    assert!(first.undetermined().contains("position along"));
    // So is the first pair's: the first SU is moved by the first DoF alone, whose accelerations
    // are perpendicular to its axis and whose turn leaves gravity alone, so how far along and
    // about that axis the second SU sits from the first no reading tells either (the paper's
    // first pair, compared up to that screw).
    let pair = &e.uncertainty[1];
    let in_first = k.sus[0].rotation.inverse() * z;
    let in_second = k.sus[1].rotation.inverse() * z;
    assert!(
        (share(&pair.undetermined_position, in_first) - 1.0).abs() < 1e-6,
        "{pair:?}"
    );
    assert!(
        (share(&pair.undetermined_orientation, in_second) - 1.0).abs() < 1e-6,
        "{pair:?}"
    );
    assert_eq!(
        (
            pair.undetermined_position.len(),
            pair.undetermined_orientation.len()
        ),
        (2, 1),
        "a screw: along the axis, and a turn about it that moves the SU too"
    );
    // Every later SU's pose relative to the one before is determined in every direction.
    for u in &e.uncertainty[2..] {
        assert!(!u.is_partial(), "{u:?}");
    }
    // The same in `model.json`: the directions are written, and read back.
    let json = serde_json::to_string(&e.uncertainty).unwrap();
    let back: Vec<skincal::estimate::ml::SuUncertainty> = serde_json::from_str(&json).unwrap();
    assert_eq!(back, e.uncertainty);
}

#[test]
fn the_dh_form_of_the_truth_is_the_papers_table_and_the_estimate_gives_it_back() {
    use skincal::estimate::{dh_form, true_dh_table};
    let truth = presets::find("paper-7dof").unwrap().robot().unwrap();
    let (rows, sus) = dh_form(&truth, &chain(7)).unwrap();
    let (true_rows, true_sus) = true_dh_table(&truth, &chain(7)).unwrap();
    let close = |a: f64, b: f64| (a - b).abs() < 1e-9;
    for (r, t) in rows.iter().zip(&true_rows) {
        assert!(
            close(r.theta0, t.theta0)
                && close(r.d, t.d)
                && close(r.a, t.a)
                && close(r.alpha, t.alpha),
            "{r:?} vs {t:?}"
        );
    }
    for (r, t) in sus.iter().zip(&true_sus) {
        assert!(
            close(r.theta0, t.theta0)
                && close(r.a, t.a)
                && close(r.alpha, t.alpha)
                && close(r.theta_acc, t.theta_acc),
            "{r:?} vs {t:?}"
        );
        // With α = 0 the virtual axis is the SU's z axis itself: only d + d_acc is defined.
        if t.alpha.abs() > 1e-9 {
            assert!(close(r.d, t.d) && close(r.d_acc, t.d_acc), "{r:?} vs {t:?}");
        } else {
            assert!(close(r.d + r.d_acc, t.d + t.d_acc), "{r:?} vs {t:?}");
        }
    }

    // The noise-free estimate: every row but the gauge (the first rows' θ0 and d) comes back.
    let sim = simulate(&truth, &noise_free()).unwrap();
    let data = LimbData::new(&sim.measurements, &chain(7)).unwrap();
    let estimate = estimate_limb(
        &data,
        None,
        &MlConfig {
            noise_sd: 1e-3,
            ..MlConfig::default()
        },
    )
    .unwrap();
    let (est_rows, est_sus) = dh_form(&estimate.to_robot(), &chain(7)).unwrap();
    let near = |a: f64, b: f64| (a - b).abs() < 1e-6;
    for (i, (e, r)) in est_rows.iter().zip(&rows).enumerate() {
        assert!(
            near(e.a, r.a) && near(e.alpha, r.alpha),
            "row {i}: {e:?} vs {r:?}"
        );
        if i > 0 {
            assert!(
                near(e.theta0, r.theta0) && near(e.d, r.d),
                "row {i}: {e:?} vs {r:?}"
            );
        }
    }
    for (i, (e, r)) in est_sus.iter().zip(&sus).enumerate().skip(1) {
        assert!(
            near(e.theta0, r.theta0)
                && near(e.d, r.d)
                && near(e.a, r.a)
                && near(e.alpha, r.alpha)
                && near(e.theta_acc, r.theta_acc)
                && near(e.d_acc, r.d_acc),
            "SU {i}: {e:?} vs {r:?}"
        );
    }
}

#[test]
fn the_dh_tables_standard_deviations_describe_the_spread_over_data_sets() {
    // The distance a and twist α between consecutive axes (no gauge in either): over 24 data
    // sets their errors against the truth, in units of the reported standard deviation, have an
    // RMS near 1.
    use skincal::estimate::dh_form;
    let truth = presets::find("paper-7dof").unwrap().robot().unwrap();
    let (true_rows, _) = dh_form(&truth, &chain(7)).unwrap();
    let mut normalised = Vec::new();
    for seed in 1..=24 {
        let data = paper_noise_data(&truth, seed);
        let e = estimate_limb(&data, None, &MlConfig::default()).unwrap();
        let dh = e.dh.unwrap();
        assert_eq!(dh.dof_dof_sd.len(), dh.dof_dof.len());
        assert_eq!(dh.dof_su_sd.len(), dh.dof_su.len());
        for ((r, sd), t) in dh.dof_dof.iter().zip(&dh.dof_dof_sd).zip(&true_rows) {
            assert!(sd.a > 0.0 && sd.alpha > 0.0, "{sd:?}");
            normalised.push((r.a - t.a) / sd.a);
            let twist = r.alpha - t.alpha;
            normalised.push(twist.sin().atan2(twist.cos()) / sd.alpha);
        }
    }
    let rms = (normalised.iter().map(|x| x * x).sum::<f64>() / normalised.len() as f64).sqrt();
    eprintln!(
        "RMS of the normalised errors over {} values: {rms:.2}",
        normalised.len()
    );
    assert!((0.7..1.4).contains(&rms), "{rms}");
}

#[test]
fn training_poses_with_the_base_tilted_tell_the_turn_about_a_vertical_first_axis() {
    // Upright, gravity runs along the paper arm's first axis: how far su1 is turned about that
    // axis relative to su2 no reading tells. With 8 of the poses recorded with the base tilted
    // 90° (a gravity of their own in the fit, which is not told the tilt), it is told; where
    // along the axis su1 sits no accelerometer ever tells (a point turning about a fixed axis
    // accelerates the same at every height along it).
    let truth = presets::find("paper-7dof").unwrap().robot().unwrap();
    let sim = simulate(
        &truth,
        &SimulationConfig {
            tilted_poses: 8,
            ..SimulationConfig::default()
        },
    )
    .unwrap();
    let data = LimbData::new(&sim.measurements, &chain(7)).unwrap();
    assert_eq!(data.orientations(), 2);
    let e = estimate_limb(&data, None, &MlConfig::default()).unwrap();
    assert!(e.converged, "residual {}", e.residual_ratio);
    // The tilted gravity: 9.81 m/s², a quarter turn from the upright one (the simulator's tilt).
    assert_eq!(e.other_gravities.len(), 1);
    let (g0, g1) = (
        Vector3::from(e.gravity),
        Vector3::from(e.other_gravities[0]),
    );
    assert!((g1.norm() - 9.81).abs() < 0.02, "{g1}");
    let angle = g0.angle(&g1).to_degrees();
    assert!((angle - 90.0).abs() < 0.3, "{angle}°");
    // su1 relative to the reference: still the screw about the axis (the tilted gravity is
    // fitted freely, so the whole limb's turn about it is the gauge) and the height along it.
    let first = &e.uncertainty[0];
    assert_eq!(
        (
            first.undetermined_position.len(),
            first.undetermined_orientation.len()
        ),
        (2, 1),
        "{first:?}"
    );
    // su1 → su2: only the position along the first axis is left undetermined.
    let pair = &e.uncertainty[1];
    assert_eq!(
        (
            pair.undetermined_position.len(),
            pair.undetermined_orientation.len()
        ),
        (1, 0),
        "{pair:?}"
    );
    // And the turn it now gives is the truth's: su1's frame relative to su2's at the zero pose.
    let relative = |robot: &skincal::model::Robot| {
        let k = skincal::model::forward_kinematics(&robot.model, &robot.parameters, &[0.0; 7]);
        k.sus[1].rotation.inverse() * k.sus[0].rotation
    };
    let error = (relative(&e.to_robot()).inverse() * relative(&truth)).angle();
    assert!(error.to_degrees() < 0.5, "{}°", error.to_degrees());
    // Upright alone, the same turn is the gauge's choice, nowhere near the truth.
    let upright = estimate_limb(&data.usual_orientation(), None, &MlConfig::default()).unwrap();
    let guessed = (relative(&upright.to_robot()).inverse() * relative(&truth)).angle();
    assert!(guessed.to_degrees() > 2.0, "{}°", guessed.to_degrees());
    eprintln!(
        "tilted poses: residual {:.3} σ, gravities {angle:.3}° apart, |g1| {:.4} m/s²; su1 turn relative to su2 off by {:.3}° (upright alone: {:.1}°)",
        e.residual_ratio,
        g1.norm(),
        error.to_degrees(),
        guessed.to_degrees()
    );
}

#[test]
fn each_dofs_bound_on_its_dynamic_readings_is_what_noise_draws_give() {
    // The Cramér–Rao bound on each DoF's held-out dynamic readings (the parameters' covariance
    // at the truth propagated to their predictions) against the whole calibration run on 24
    // draws of Gaussian noise on the same poses: per DoF, the draws' RMS error is the bound's,
    // within what 48 draws tell (a DoF's squared error depends on a few parameters' errors and
    // scatters about its mean by about its mean: the RMS over 48 by about a tenth).
    use rand::SeedableRng;
    use rand_distr::Distribution;
    use skincal::estimate::body::calibrate_body;
    use skincal::estimate::ml::{dynamic_reading_bounds, IntrinsicsModel};
    use skincal::explore::{explore, ExploreConfig};
    use skincal::predict::validate;
    let truth = presets::find("paper-7dof").unwrap().robot().unwrap();
    let clean = simulate(&truth, &noise_free()).unwrap().measurements;
    let held_out = simulate(
        &truth,
        &SimulationConfig {
            seed: 1001,
            structure: false,
            ..noise_free()
        },
    )
    .unwrap()
    .measurements;
    let structure = explore(&clean, &ExploreConfig::default()).unwrap();
    let sd = 0.01 * 9.81 / 3f64.sqrt();
    let bounds = dynamic_reading_bounds(
        &truth,
        &gravity_upright(),
        &LimbData::new(&clean, &chain(7)).unwrap(),
        &LimbData::new(&held_out, &chain(7)).unwrap(),
        sd,
        IntrinsicsModel::None,
    )
    .unwrap();
    let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(8);
    let normal = rand_distr::Normal::new(0.0, sd).unwrap();
    let draws = 48;
    let mut squares = [0.0; 7];
    for _ in 0..draws {
        let mut set = clean.clone();
        for pose in &mut set.training.as_mut().unwrap().poses {
            let dynamic = pose.dynamic.values_mut().flatten();
            for reading in pose.static_readings.iter_mut().chain(dynamic) {
                for x in reading {
                    *x += normal.sample(&mut rng);
                }
            }
        }
        let model = calibrate_body(&set, Some(&structure), &MlConfig::default(), None).unwrap();
        let check = validate(&model, &held_out, "held-out").unwrap();
        for e in check.dofs {
            let d: usize = e.dof.trim_start_matches("dof").parse().unwrap();
            squares[d - 1] += e.dynamic_rms.powi(2) / draws as f64;
        }
    }
    for (d, (square, bound)) in squares.iter().zip(&bounds).enumerate() {
        let ratio = square.sqrt() / bound;
        eprintln!(
            "dof{}: {:.4} m/s² over {draws} draws, bound {bound:.4} ({ratio:.2}×)",
            d + 1,
            square.sqrt()
        );
        assert!((0.8..1.25).contains(&ratio), "dof{}: {ratio:.2}×", d + 1);
    }
}
