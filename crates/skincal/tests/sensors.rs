//! Real sensors and imperfect skins: accelerometer bias and scale estimated with the kinematics
//! (against the simulator's drawn intrinsics), held-out sets of the same skin, and skins with
//! gaps calibrated where they can be.

use skincal::estimate::body::calibrate_body;
use skincal::estimate::ml::{IntrinsicsModel, MlConfig};
use skincal::explore::{explore, DiagnosticKind, ExploreConfig, Severity};
use skincal::model::{presets, Robot};
use skincal::predict::{validate, PoseTable, Predictor};
use skincal::sim::{simulate, Imperfections, SimulationConfig};

/// The paper's noise with BMA150-class intrinsics: bias ±0.06 g, scale ±3 % per axis.
fn real_sensors(seed: u64) -> SimulationConfig {
    SimulationConfig {
        seed,
        imperfections: Imperfections {
            bias: 0.06,
            scale: 0.03,
            ..Imperfections::default()
        },
        ..SimulationConfig::default()
    }
}

/// The same skin in 20 other poses, without noise.
fn same_skin_held_out(config: &SimulationConfig) -> SimulationConfig {
    SimulationConfig {
        structure: false,
        pose_seed: Some(99),
        imperfections: Imperfections {
            uniform_noise: 0.0,
            ..config.imperfections
        },
        ..config.clone()
    }
}

/// The estimator with the intrinsics model given, not chosen by the data.
fn config(intrinsics: IntrinsicsModel) -> MlConfig {
    MlConfig {
        intrinsics,
        select_intrinsics: false,
        ..MlConfig::default()
    }
}

#[test]
fn the_data_choose_the_intrinsics_ideal_sensors_lose_nothing_and_real_ones_get_their_correction() {
    // A Panda-like arm of 2 SUs per segment and the humanoid, ideal and real accelerometers;
    // the default estimator against the same data fitted with each model given.
    let arm = skincal::sim::robot_like_limb(
        &skincal::sim::RobotLikeConfig {
            min_dofs: 7,
            max_dofs: 7,
            max_sus_per_segment: 2,
        },
        3,
    )
    .unwrap();
    let humanoid = presets::find("humanoid").unwrap().robot().unwrap();
    for (robot, seed) in [(&arm, 3), (&humanoid, 5)] {
        let clean = SimulationConfig {
            seed,
            ..SimulationConfig::default()
        };
        for (sim, wanted) in [
            (clean.clone(), IntrinsicsModel::None),
            (real_sensors(seed), IntrinsicsModel::BiasScale),
        ] {
            let set = simulate(robot, &sim).unwrap().measurements;
            let held_out = simulate(robot, &same_skin_held_out(&sim))
                .unwrap()
                .measurements;
            let tree = explore(&set, &ExploreConfig::default()).unwrap();
            let chosen = calibrate_body(&set, Some(&tree), &MlConfig::default(), None).unwrap();
            let given = calibrate_body(&set, Some(&tree), &config(wanted), None).unwrap();
            let mut models = Vec::new();
            for limb in &chosen.limbs {
                let e = &limb.estimate;
                let first = e.intrinsics_tests.first().expect("a test per limb");
                // Bias against none: far beyond the threshold on real sensors; a draw of about
                // N(0, 1) on ideal ones.
                if wanted == IntrinsicsModel::None {
                    assert!(first.z.abs() < 3.5, "{}: {first:?}", limb.name);
                } else {
                    assert!(first.z > 10.0, "{}: {first:?}", limb.name);
                }
                models.push(e.intrinsics_model.unwrap());
            }
            if wanted == IntrinsicsModel::None {
                assert!(models.iter().all(|m| *m == wanted), "{models:?}");
            } else {
                // A short limb may not tell a scale from its kinematics: a bias alone there.
                assert!(
                    models.iter().all(|m| *m != IntrinsicsModel::None)
                        && models.iter().filter(|m| **m == wanted).count() * 2 > models.len(),
                    "{models:?}"
                );
            }
            let a = validate(&chosen, &held_out, "held-out").unwrap();
            let b = validate(&given, &held_out, "held-out").unwrap();
            assert!(
                a.static_rms <= 1.1 * b.static_rms && a.dynamic_rms <= 1.1 * b.dynamic_rms,
                "{}, {}: chosen {} / {} against {} given {} / {}",
                robot.model.name(),
                wanted.name(),
                a.static_rms,
                a.dynamic_rms,
                wanted.name(),
                b.static_rms,
                b.dynamic_rms
            );
        }
    }
}

#[test]
fn a_pose_seed_records_the_same_skin_in_other_poses() {
    let robot = presets::find("paper-7dof").unwrap().robot().unwrap();
    let a = simulate(&robot, &real_sensors(4)).unwrap();
    let b = simulate(&robot, &same_skin_held_out(&real_sensors(4))).unwrap();
    assert_eq!(a.truth.su_intrinsics, b.truth.su_intrinsics);
    assert!(a.truth.su_intrinsics.iter().all(|i| {
        i.bias.iter().all(|b| b.abs() <= 0.06 * 9.81 && *b != 0.0)
            && i.scale.iter().all(|s| s.abs() <= 0.03 && *s != 0.0)
    }));
    let (ta, tb) = (
        a.measurements.training.unwrap(),
        b.measurements.training.unwrap(),
    );
    assert_ne!(ta.poses[0].q, tb.poses[0].q);
}

#[test]
fn bias_and_scale_are_estimated_with_the_kinematics_and_predictions_read_like_the_skin() {
    let robot = presets::find("paper-7dof").unwrap().robot().unwrap();
    let sim = simulate(&robot, &real_sensors(2)).unwrap();
    let set = &sim.measurements;
    let held_out = simulate(&robot, &same_skin_held_out(&real_sensors(2)))
        .unwrap()
        .measurements;

    // Ideal accelerometers cannot explain 0.06 g offsets at the paper's noise.
    let ideal = calibrate_body(set, None, &config(IntrinsicsModel::None), None).unwrap();
    assert!(ideal.limbs[0].estimate.residual_ratio > 1.5);

    let model = calibrate_body(set, None, &config(IntrinsicsModel::BiasScale), None).unwrap();
    let e = &model.limbs[0].estimate;
    assert!(e.converged, "residual {}", e.residual_ratio);
    assert!((e.residual_ratio - 1.0).abs() < 0.15);
    // Each SU's estimate against the drawn truth, within 4.5 standard deviations per component
    // where the readings determine it.
    let names = robot.model.su_names();
    let mut checked = 0;
    for i in &e.intrinsics {
        let truth = sim.truth.su_intrinsics[names.iter().position(|n| *n == i.su).unwrap()];
        let pairs = [
            (
                i.value.bias,
                i.sd.bias,
                truth.bias,
                ["bias_x", "bias_y", "bias_z"],
            ),
            (
                i.value.scale,
                i.sd.scale,
                truth.scale,
                ["scale_x", "scale_y", "scale_z"],
            ),
        ];
        for (value, sd, truth, labels) in pairs {
            for c in 0..3 {
                if i.held.iter().any(|h| h == labels[c]) {
                    continue;
                }
                assert!(sd[c] > 0.0);
                assert!(
                    (value[c] - truth[c]).abs() < 4.5 * sd[c],
                    "{} {}: {} vs truth {} (sd {})",
                    i.su,
                    labels[c],
                    value[c],
                    truth[c],
                    sd[c]
                );
                checked += 1;
            }
        }
    }
    assert!(checked >= 36, "only {checked} components determined");

    // Predictions are what the skin reads: close to the held-out readings of the same skin, and
    // far closer than the ideal-sensor model's.
    let with = validate(&model, &held_out, "held-out").unwrap();
    let without = validate(&ideal, &held_out, "held-out").unwrap();
    assert!(with.static_rms < 0.06, "static {}", with.static_rms);
    assert!(with.static_rms * 5.0 < without.static_rms);
    // `ideal` predicts the specific force: the held-out (noise-free) readings corrected with the
    // simulator's true intrinsics, for every SU whose intrinsics the readings determine (where
    // they do not, the SU's fitted frame absorbs the bias it cannot tell).
    let ideal = Predictor::new(&model).unwrap().ideal();
    let truth_of = |su: &str| sim.truth.su_intrinsics[names.iter().position(|n| n == su).unwrap()];
    let sus = ideal.sus();
    let (mut worst, mut compared): (f64, usize) = (0.0, 0);
    for pose in &held_out.training.as_ref().unwrap().poses {
        let predicted = ideal.readings(&pose.q, &model.pattern);
        for (u, su) in sus.iter().enumerate() {
            if e.intrinsics
                .iter()
                .any(|i| i.su == *su && !i.held.is_empty())
            {
                continue;
            }
            let v = held_out.sus.iter().position(|n| n == su).unwrap();
            let read = nalgebra::Vector3::from(pose.static_readings[v]);
            let force = truth_of(su).correct(&read).unwrap();
            worst = worst.max((predicted.statics[u] - force).norm());
            compared += 1;
        }
    }
    assert!(compared >= 4 * 20, "only {compared} readings compared");
    assert!(worst < 0.15, "largest ideal-force error {worst} m/s²");
}

/// The humanoid with no SU on its hands: the wrist DoFs move no SU.
fn handless_humanoid() -> Robot {
    let mut file = presets::find("humanoid").unwrap().file().unwrap();
    file.sus.retain(|s| !s.segment.ends_with("_hand"));
    file.build().unwrap()
}

#[test]
fn a_skin_with_gaps_is_calibrated_where_it_can_be_and_says_what_it_left_out() {
    let robot = handless_humanoid();
    let set = simulate(&robot, &SimulationConfig::default())
        .unwrap()
        .measurements;
    let structure = explore(&set, &ExploreConfig::default()).unwrap();
    let wrists = [
        "l_wrist_yaw",
        "l_wrist_pitch",
        "r_wrist_yaw",
        "r_wrist_pitch",
    ];
    assert!(structure.complete, "{:?}", structure.diagnostics);
    assert_eq!(structure.unplaced_dofs, wrists);
    assert!(structure
        .diagnostics
        .iter()
        .filter(|d| d.kind == DiagnosticKind::DofMovesNoSu)
        .all(|d| d.severity == Severity::Warning));
    let model = calibrate_body(&set, Some(&structure), &MlConfig::default(), None).unwrap();
    assert_eq!(model.limbs.len(), 5);
    assert!(model.limbs.iter().all(|l| l.estimate.converged));
    let left: Vec<&str> = model
        .not_calibrated
        .iter()
        .map(|n| n.name.as_str())
        .collect();
    assert_eq!(left, wrists);
    assert!(model
        .not_calibrated
        .iter()
        .all(|n| n.kind == "dof" && n.reason.contains("moves no SU")));
    let held_out = simulate(
        &robot,
        &SimulationConfig {
            structure: false,
            pose_seed: Some(99),
            imperfections: Imperfections::none(),
            ..SimulationConfig::default()
        },
    )
    .unwrap()
    .measurements;
    let check = validate(&model, &held_out, "held-out").unwrap();
    assert!(
        check.static_rms < 0.06 && check.dynamic_rms < 0.05,
        "{check:?}"
    );
    // A pose table of every DoF of the robot, wrists included, is accepted; another name is not.
    let predictor = Predictor::new(&model).unwrap();
    let mut table = PoseTable {
        dofs: held_out.dofs.clone(),
        poses: vec![held_out.training.as_ref().unwrap().poses[0].q.clone()],
    };
    let rows = predictor.arrange(&table, "poses.csv").unwrap();
    assert_eq!(rows[0].len(), robot.model.dofs().len() - 4);
    table.dofs.push("tail".into());
    table.poses[0].push(0.0);
    let error = predictor.arrange(&table, "poses.csv").unwrap_err();
    assert!(error.to_string().contains("`tail`"), "{error}");
}

/// The segments (as sorted SU lists, without `aside`) and joints (sorted DoF lists) of a tree.
fn shape(
    s: &skincal::explore::Structure,
    aside: &[String],
) -> (Vec<Vec<String>>, Vec<Vec<String>>) {
    let mut segments: Vec<Vec<String>> = s
        .segments
        .iter()
        .map(|seg| {
            let mut v: Vec<String> = seg
                .sus
                .iter()
                .filter(|su| !aside.contains(su))
                .cloned()
                .collect();
            v.sort();
            v
        })
        .filter(|v| !v.is_empty())
        .collect();
    segments.sort();
    let mut joints: Vec<Vec<String>> = s
        .joints
        .iter()
        .map(|j| {
            let mut v = j.dofs.clone();
            v.sort();
            v
        })
        .collect();
    joints.sort();
    (segments, joints)
}

#[test]
fn glitches_neither_break_the_tree_nor_drag_the_fit() {
    let robot = presets::find("paper-7dof").unwrap().robot().unwrap();
    // Seed 5 glitches the rest reading of su2 in the upright orientation, among others.
    let clean = SimulationConfig {
        seed: 5,
        ..SimulationConfig::default()
    };
    let glitchy = SimulationConfig {
        imperfections: Imperfections {
            glitches: 0.01,
            ..Imperfections::default()
        },
        ..clean.clone()
    };
    let held_out = simulate(&robot, &same_skin_held_out(&clean))
        .unwrap()
        .measurements;
    let mut errors = Vec::new();
    let mut trees = Vec::new();
    for config in [&clean, &glitchy] {
        let set = simulate(&robot, config).unwrap().measurements;
        let structure = explore(&set, &ExploreConfig::default()).unwrap();
        assert!(structure.complete, "{:?}", structure.diagnostics);
        let model = calibrate_body(&set, Some(&structure), &MlConfig::default(), None).unwrap();
        assert!(model.limbs.iter().all(|l| l.estimate.converged));
        let check = validate(&model, &held_out, "held-out").unwrap();
        errors.push((check.static_rms, check.dynamic_rms));
        trees.push((structure, model));
    }
    // The glitches were there, were seen, and changed nothing of the tree.
    let (glitch_tree, glitch_model) = &trees[1];
    assert!(glitch_tree
        .diagnostics
        .iter()
        .any(|d| d.kind == DiagnosticKind::MisreadReading));
    assert_eq!(shape(&trees[0].0, &[]), shape(glitch_tree, &[]));
    let rejected: usize = glitch_model
        .limbs
        .iter()
        .flat_map(|l| &l.estimate.rejected)
        .map(|r| r.static_readings + r.dynamic_readings)
        .sum();
    assert!(rejected > 0);
    assert!(errors[1].0 < 1.3 * errors[0].0, "{errors:?}");
    assert!(errors[1].1 < 1.3 * errors[0].1, "{errors:?}");
}

/// Replaces what `su` read in the move of `dof` (orientation index `o`; `"rest"`: its rest
/// reading) by a glitch: its rest reading turned by `degrees` (about an axis across it) and
/// scaled to `norm_g` g.
fn glitch(
    set: &mut skincal::measurements::MeasurementSet,
    o: usize,
    dof: &str,
    su: &str,
    degrees: f64,
    norm_g: f64,
) {
    use nalgebra::{Rotation3, Unit, Vector3};
    let u = set.sus.iter().position(|x| x == su).unwrap();
    let orientation = &mut set.structure.as_mut().unwrap().orientations[o];
    let rest = Vector3::from(orientation.rest[u]);
    let across = Unit::new_normalize(rest.cross(&Vector3::new(0.3, -0.5, 0.8)));
    let turned = Rotation3::from_axis_angle(&across, degrees.to_radians()) * rest;
    let reading = turned.normalize() * norm_g * 9.81;
    let glitched = [reading.x, reading.y, reading.z];
    if dof == "rest" {
        orientation.rest[u] = glitched;
    } else {
        let mv = orientation.moves.iter_mut().find(|m| m.dof == dof).unwrap();
        mv.readings[u] = glitched;
    }
}

#[test]
fn glitches_that_look_like_moves_are_told_by_the_physics_of_one_rotation() {
    // On the humanoid, each wrist DoF moves one SU (the hand's) and only in one orientation: the
    // other one turns it about gravity. Glitches of |g|'s norm there have no majority to lose to.
    let robot = presets::find("humanoid").unwrap().robot().unwrap();
    let config = SimulationConfig {
        imperfections: Imperfections {
            uniform_noise: 0.0,
            ..Imperfections::default()
        },
        ..SimulationConfig::default()
    };
    let clean_set = simulate(&robot, &config).unwrap().measurements;
    let clean = explore(&clean_set, &ExploreConfig::default()).unwrap();
    assert!(clean.complete);
    // (orientation, DoF, SU, turn in degrees, norm in g)
    type Glitch<'a> = (usize, &'a str, &'a str, f64, f64);
    let cases: [(&str, &[Glitch]); 5] = [
        // SUs turned further than the 0.3 rad (17°) travel, by unlike angles, beside the hand
        // (17°) and where the DoF turns nothing: only glitches do that.
        (
            "beyond the travel",
            &[
                (1, "r_wrist_yaw", "l_upper_arm_front", 140.0, 1.0),
                (1, "r_wrist_yaw", "l_forearm_front", 76.0, 1.0),
                (0, "r_wrist_yaw", "r_forearm_front", 88.0, 1.0),
            ],
        ),
        // Two glitches that agree on a turn (88° and 87°) where l_shoulder_pitch turns about
        // gravity: two SUs agreeing on a turn no rotation of the DoF gives is chance, not a move.
        (
            "agreeing beyond the travel",
            &[
                (1, "l_shoulder_pitch", "torso_chest", 88.0, 1.0),
                (1, "l_shoulder_pitch", "r_thigh_side", 87.0, 1.0),
            ],
        ),
        // A glitch within the travel (21°, 1.1 g) beside the one SU the DoF turns (17°): the
        // tree cannot have both, and the glitch is the doubtful one.
        (
            "within the travel",
            &[(0, "l_wrist_pitch", "r_hand_back", 21.0, 1.1)],
        ),
        // A rest reading of |g|'s norm, turned: every move seems to turn the SU, but the moves
        // agree among themselves.
        ("rest", &[(0, "rest", "l_foot_top", 160.0, 1.0)]),
        // The one clear reading of r_foot_sole in the knee's move, lost (the other orientation
        // turns the knee about gravity): left still, the foot would hang from the thigh and
        // the shank at once.
        (
            "hanging from two",
            &[(0, "r_knee", "r_foot_sole", 120.0, 1.0)],
        ),
    ];
    for (name, glitches) in cases {
        let mut set = clean_set.clone();
        for &(o, dof, su, degrees, norm) in glitches {
            glitch(&mut set, o, dof, su, degrees, norm);
        }
        let s = explore(&set, &ExploreConfig::default()).unwrap();
        assert!(s.complete, "{name}: {:?}", s.diagnostics);
        assert!(s.unplaced_sus.is_empty(), "{name}: {:?}", s.unplaced_sus);
        assert_eq!(shape(&s, &[]), shape(&clean, &[]), "{name}");
        let misread = s
            .diagnostics
            .iter()
            .find(|d| d.kind == DiagnosticKind::MisreadReading)
            .unwrap_or_else(|| panic!("{name}: glitches not named"));
        for &(_, _, su, _, _) in glitches {
            assert!(misread.sus.iter().any(|x| x == su), "{name}: {su}");
        }
    }

    // The one reading that shows r_wrist_pitch move anything, misread: what it moves cannot be
    // told. The hand is set aside and the DoF left out, both named; the rest is the clean tree.
    let mut set = clean_set.clone();
    glitch(&mut set, 0, "r_wrist_pitch", "r_hand_back", 40.0, 0.5);
    let s = explore(&set, &ExploreConfig::default()).unwrap();
    assert!(s.complete, "{:?}", s.diagnostics);
    assert_eq!(s.unplaced_sus, ["r_hand_back"]);
    assert!(s.unplaced_dofs.contains(&"r_wrist_pitch".to_string()));
    let lost = s
        .diagnostics
        .iter()
        .find(|d| d.kind == DiagnosticKind::DofMovesNoSu && d.dofs == ["r_wrist_pitch"])
        .unwrap();
    assert!(lost.message.contains("r_hand_back"), "{}", lost.message);
    let aside = vec!["r_hand_back".to_string()];
    let (segments, _) = shape(&s, &aside);
    assert_eq!(segments, shape(&clean, &aside).0);
    // The same tree as the readings without the hand give: nothing else lost.
    let without = explore(&clean_set.without_sus(&aside), &ExploreConfig::default()).unwrap();
    assert_eq!(shape(&s, &[]), shape(&without, &[]));
    assert_eq!(s.unplaced_dofs.len(), without.unplaced_dofs.len());
}

#[test]
fn a_lost_entry_is_decided_by_segment_mates_not_by_sus_with_lost_entries_of_their_own() {
    // torso_chest's readings in both moves of neck_yaw are lost, and so are head_face's in both
    // moves of neck_pitch. torso_chest's mates say neck_yaw leaves it still; head_face, whose
    // own row is open where torso_chest is known, must not outvote them. head_face itself is on
    // the head or on a segment between the two neck DoFs: nothing in the readings tells, so it
    // is set aside and named.
    let robot = presets::find("humanoid").unwrap().robot().unwrap();
    let clean_set = simulate(&robot, &SimulationConfig::default())
        .unwrap()
        .measurements;
    let clean = explore(&clean_set, &ExploreConfig::default()).unwrap();
    let mut set = clean_set.clone();
    for o in 0..2 {
        glitch(&mut set, o, "neck_yaw", "torso_chest", 100.0, 0.4);
        glitch(&mut set, o, "neck_pitch", "head_face", 100.0, 0.4);
    }
    let s = explore(&set, &ExploreConfig::default()).unwrap();
    assert!(s.complete, "{:?}", s.diagnostics);
    assert_eq!(s.unplaced_sus, ["head_face"]);
    let aside = vec!["head_face".to_string()];
    assert_eq!(shape(&s, &aside), shape(&clean, &aside));
}

#[test]
fn a_lost_reading_is_told_by_how_far_gravity_turned() {
    // paper-7dof: dof4's axis is near vertical in the tilted orientation, where it turns su4…su7
    // by about 3° (0.05 g, at the threshold). With su4's reading in the upright orientation
    // misread, that turn alone says su4 moves with dof4.
    let robot = presets::find("paper-7dof").unwrap().robot().unwrap();
    let config = SimulationConfig {
        seed: 6,
        ..SimulationConfig::default()
    };
    let clean_set = simulate(&robot, &config).unwrap().measurements;
    let clean = explore(&clean_set, &ExploreConfig::default()).unwrap();
    let mut set = clean_set.clone();
    glitch(&mut set, 0, "dof4", "su4", 97.0, 0.35);
    let s = explore(&set, &ExploreConfig::default()).unwrap();
    assert!(s.complete, "{:?}", s.diagnostics);
    assert!(s.unplaced_sus.is_empty(), "{:?}", s.unplaced_sus);
    assert_eq!(shape(&s, &[]), shape(&clean, &[]));
    let a = skincal::explore::activity_matrix(&set, &ExploreConfig::default()).unwrap();
    assert!(a
        .inferred
        .iter()
        .any(|i| i.su == "su4" && i.dof == "dof4" && i.active));
}

#[test]
fn broken_sus_are_named_set_aside_and_the_rest_is_calibrated() {
    use skincal::sim::{Fault, SuFault};
    let robot = presets::find("humanoid").unwrap().robot().unwrap();
    let faults = [
        ("l_forearm_side", Fault::Dead, "dead"),
        ("r_thigh_back", Fault::Frozen, "frozen"),
        ("head_top", Fault::Railed, "railed"),
        ("l_shank_front", Fault::SwapXy, "improper frame"),
    ];
    let config = SimulationConfig {
        seed: 3,
        faults: faults
            .iter()
            .map(|&(su, fault, _)| SuFault {
                su: su.into(),
                fault,
            })
            .collect(),
        ..SimulationConfig::default()
    };
    let set = simulate(&robot, &config).unwrap().measurements;
    let structure = explore(&set, &ExploreConfig::default()).unwrap();
    assert!(structure.complete, "{:?}", structure.diagnostics);
    let model = calibrate_body(&set, Some(&structure), &MlConfig::default(), None).unwrap();
    assert!(model.limbs.iter().all(|l| l.estimate.converged));
    for (su, _, kind) in faults {
        let n = model
            .not_calibrated
            .iter()
            .find(|n| n.name == su)
            .unwrap_or_else(|| panic!("{su} not named: {:?}", model.not_calibrated));
        assert!(
            n.reason.contains(&format!("broken ({kind})")),
            "{su}: {}",
            n.reason
        );
    }
    assert_eq!(model.not_calibrated.len(), 4, "{:?}", model.not_calibrated);
    // The other SUs predict a held-out set about as well as from the same data without faults.
    let clean_set = simulate(
        &robot,
        &SimulationConfig {
            faults: Vec::new(),
            ..config.clone()
        },
    )
    .unwrap()
    .measurements;
    let clean_structure = explore(&clean_set, &ExploreConfig::default()).unwrap();
    let clean = calibrate_body(
        &clean_set,
        Some(&clean_structure),
        &MlConfig::default(),
        None,
    )
    .unwrap();
    let held_out = simulate(&robot, &same_skin_held_out(&SimulationConfig::default()))
        .unwrap()
        .measurements;
    let rms = |m: &skincal::estimate::body::BodyModel| {
        let check = validate(m, &held_out, "held-out").unwrap();
        let others: Vec<_> = check
            .sus
            .iter()
            .filter(|e| !faults.iter().any(|f| f.0 == e.su))
            .collect();
        let n = others.len() as f64;
        (
            (others.iter().map(|e| e.static_rms.powi(2)).sum::<f64>() / n).sqrt(),
            (others.iter().map(|e| e.dynamic_rms.powi(2)).sum::<f64>() / n).sqrt(),
        )
    };
    let (with, without) = (rms(&model), rms(&clean));
    assert!(
        with.0 < 1.3 * without.0 && with.1 < 1.3 * without.1,
        "{with:?} vs {without:?}"
    );
}

#[test]
fn biased_and_mis_scaled_accelerometers_raise_no_tilt_alarm_and_a_real_tilt_is_still_caught() {
    // A biased, mis-scaled accelerometer reports another angle between two gravity directions
    // than the turn: with ±0.06 g and ±3 % (README's real-sensor example), seeds 1 and 7 of the
    // humanoid were refused as "the base tilted" (19.1° against 15.4° in a 17° ankle move).
    use nalgebra::{Rotation3, Vector3};
    use skincal::model::sensor::static_readings;
    let tilt_alarms = |s: &skincal::explore::Structure| {
        s.diagnostics
            .iter()
            .filter(|d| d.kind == DiagnosticKind::MoveNotRigid)
            .count()
    };
    let real = |seed: u64, bias: f64, scale: f64| SimulationConfig {
        seed,
        poses: 2,
        imperfections: Imperfections {
            bias,
            scale,
            ..Imperfections::default()
        },
        ..SimulationConfig::default()
    };
    let mut alarms = 0;
    let mut runs = 0;
    for name in ["humanoid", "paper-7dof"] {
        let robot = presets::find(name).unwrap().robot().unwrap();
        for seed in 1..=25 {
            for (bias, scale) in [(0.06, 0.03), (0.1, 0.05)] {
                let set = simulate(&robot, &real(seed, bias, scale))
                    .unwrap()
                    .measurements;
                let s = explore(&set, &ExploreConfig::default()).unwrap();
                alarms += tilt_alarms(&s);
                runs += 1;
            }
        }
    }
    assert_eq!(
        alarms, 0,
        "{alarms} tilt alarms in {runs} real-sensor structure experiments"
    );

    // A real tilt of the base by 3° during one move, on the same sensors: caught and named.
    let humanoid = presets::find("humanoid").unwrap().robot().unwrap();
    for seed in [1, 7] {
        let sim = simulate(&humanoid, &real(seed, 0.06, 0.03)).unwrap();
        let mut set = sim.measurements;
        let tilt = Rotation3::from_axis_angle(&Vector3::x_axis(), 3f64.to_radians());
        let g = tilt * Vector3::new(0.0, 0.0, -9.81);
        let o = &mut set.structure.as_mut().unwrap().orientations[0];
        let mv = o.moves.iter_mut().find(|m| m.dof == "l_elbow").unwrap();
        // The same SUs' intrinsics (the simulator's truth) on the tilted gravity.
        let ideal = static_readings(&humanoid.model, &humanoid.parameters, &mv.pose, &g);
        let before = static_readings(
            &humanoid.model,
            &humanoid.parameters,
            &mv.pose,
            &Vector3::new(0.0, 0.0, -9.81),
        );
        for (r, (a, b)) in mv.readings.iter_mut().zip(ideal.iter().zip(&before)) {
            // The reading's own error (bias, scale, noise) kept; only gravity tilted.
            let shift = a - b;
            for k in 0..3 {
                r[k] += shift[k];
            }
        }
        let s = explore(&set, &ExploreConfig::default()).unwrap();
        // Refused, naming the move: the torso's SUs, still in every other move, turned by 3°.
        let caught = s.diagnostics.iter().find(|d| {
            d.severity == Severity::Error
                && d.kind == DiagnosticKind::MoveNotRigid
                && d.dofs == ["l_elbow"]
        });
        assert!(!s.complete, "seed {seed}: {:#?}", s.diagnostics);
        let caught = caught.unwrap_or_else(|| panic!("seed {seed}: {:#?}", s.diagnostics));
        assert!(
            caught.message.contains("reference segment"),
            "{}",
            caught.message
        );
    }
}
