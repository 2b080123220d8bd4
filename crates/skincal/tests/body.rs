//! Whole-body calibration: every limb of the explored humanoid, multi-DoF joints, several SUs per
//! segment; predictions on held-out poses against the simulator's noise-free truth; URDF export.

use nalgebra::{Isometry3, Translation3, UnitQuaternion, Vector3};
use skincal::estimate::body::calibrate_body;
use skincal::estimate::ml::MlConfig;
use skincal::explore::{explore, ExploreConfig};
use skincal::model::description::with_random_sus;
use skincal::model::{forward_kinematics, presets, Robot};
use skincal::predict::{validate, PredictError};
use skincal::sim::{simulate, Imperfections, SimulationConfig};

use crate::common::{calibrated, held_out, run_python};

fn noise_free(seed: u64) -> SimulationConfig {
    SimulationConfig {
        seed,
        imperfections: Imperfections::none(),
        ..SimulationConfig::default()
    }
}

#[test]
fn noise_free_humanoid_predicts_held_out_readings_exactly() {
    let robot = presets::find("humanoid").unwrap().robot().unwrap();
    let set = simulate(&robot, &noise_free(1)).unwrap().measurements;
    let structure = explore(&set, &ExploreConfig::default()).unwrap();
    assert!(structure.complete);
    let config = MlConfig {
        noise_sd: 1e-6,
        ..MlConfig::default()
    };
    let model = calibrate_body(&set, Some(&structure), &config, None).unwrap();
    for limb in &model.limbs {
        assert!(
            limb.estimate.converged,
            "{} {}",
            limb.name, limb.estimate.residual_ratio
        );
    }
    let check = validate(&model, &held_out(&robot, 99), "held-out").unwrap();
    assert!(check.static_max < 1e-6, "static {:e}", check.static_max);
    assert!(check.dynamic_max < 1e-6, "dynamic {:e}", check.dynamic_max);
    // Every SU of the robot is covered, the torso's included.
    assert_eq!(check.sus.len(), robot.model.sus().len());
    assert!(check.not_in_model.is_empty());
    // The multi-DoF joints' DoFs come out in the order of the truth.
    for limb in &model.limbs {
        for order in &limb.estimate.joint_orders {
            let index: Vec<usize> = order
                .dofs
                .iter()
                .map(|d| robot.model.dof_index(d).unwrap())
                .collect();
            assert!(index.windows(2).all(|w| w[0] < w[1]), "{:?}", order.dofs);
        }
    }
}

/// A noisy humanoid with two SUs on every skinned segment, calibrated once for the tests below.
fn noisy_humanoid() -> (Robot, skincal::estimate::body::BodyModel) {
    let robot = presets::find("humanoid").unwrap().robot().unwrap();
    let robot = with_random_sus(&robot, 2, 7).unwrap();
    let model = calibrated(
        &robot,
        &SimulationConfig {
            seed: 3,
            ..SimulationConfig::default()
        },
    );
    (robot, model)
}

/// Axis lines (direction, point) of `dofs` in the frame of SU `su`, all DoFs at zero.
fn lines_in_su_frame(robot: &Robot, dofs: &[&str], su: &str) -> Vec<(Vector3<f64>, Vector3<f64>)> {
    let m = &robot.model;
    let k = forward_kinematics(m, &robot.parameters, &vec![0.0; m.dofs().len()]);
    let frame = k.sus[m.su_index(su).unwrap()];
    dofs.iter()
        .map(|d| {
            let i = m.dof_index(d).unwrap();
            let axis = k.joints[i].rotation * m.dofs()[i].axis.into_inner();
            let point = k.joints[i].translation.vector;
            (
                frame.rotation.inverse() * axis,
                frame.inverse() * nalgebra::Point3::from(point),
            )
        })
        .map(|(a, p)| (a, p.coords))
        .collect()
}

#[test]
fn a_three_dof_shoulder_without_sus_between_its_dofs_is_calibrated() {
    let (truth, model) = noisy_humanoid();
    let estimate = model.check().unwrap();
    let shoulder = ["l_shoulder_pitch", "l_shoulder_roll", "l_shoulder_yaw"];
    let limb = model
        .limbs
        .iter()
        .find(|l| l.dofs.contains(&shoulder[0].to_string()))
        .unwrap();
    assert!(limb.estimate.converged);
    assert_eq!(limb.estimate.joint_orders[0].dofs, shoulder);
    // Seen from an SU on the upper arm (gauge-free: the SU and the axes move together), each axis
    // direction and the distance between the axis lines and the SU. Tolerance: with σ = 0.057 m/s²
    // per component, α = 6.3 rad/s² and lever arms of 0.05–0.3 m, one reading fixes a direction to
    // ~0.04 rad and a lever arm to ~0.01 m; 20 poses × 2 SUs × the later segments average that to
    // about 0.1° and 2–3 mm (what this data set gives): 0.5° and 6 mm leave room for other seeds.
    let su = "l_upper_arm_su1";
    let t = lines_in_su_frame(&truth, &shoulder, su);
    let e = lines_in_su_frame(&estimate, &shoulder, su);
    for (i, ((ta, tp), (ea, ep))) in t.iter().zip(&e).enumerate() {
        let angle = ta.angle(ea);
        // Distance of the estimated point from the true line.
        let offset = (ep - tp) - ta * ta.dot(&(ep - tp));
        assert!(
            angle < 0.5f64.to_radians(),
            "{}: axis off by {:.2}°",
            shoulder[i],
            angle.to_degrees()
        );
        assert!(
            offset.norm() < 0.006,
            "{}: axis line off by {:.1} mm",
            shoulder[i],
            offset.norm() * 1e3
        );
    }
}

#[test]
fn urdf_export_keeps_the_forward_kinematics() {
    let (_, model) = noisy_humanoid();
    let robot = model.check().unwrap();
    let text = skincal::model::urdf::to_urdf(&robot).unwrap();
    let urdf = urdf_rs::read_from_string(&text).unwrap();
    // Kinematics only: nothing it does not know — no masses, no limits, nothing on fixed joints
    // but their origin.
    assert!(
        !text.contains("<inertial") && !text.contains("<limit"),
        "{text}"
    );
    for j in &urdf.joints {
        if j.joint_type == urdf_rs::JointType::Fixed {
            let element = &text[text.find(&format!("name=\"{}\"", j.name)).unwrap()..];
            let element = &element[..element.find("</joint>").unwrap()];
            assert!(!element.contains("<axis"), "{element}");
        }
    }
    // Independent forward kinematics of the URDF: compose origin · Rot(axis, q) from the root.
    let rpy = |p: &urdf_rs::Pose| {
        Isometry3::from_parts(
            Translation3::new(p.xyz[0], p.xyz[1], p.xyz[2]),
            UnitQuaternion::from_euler_angles(p.rpy[0], p.rpy[1], p.rpy[2]),
        )
    };
    let m = &robot.model;
    let mut rng_q = 0.37f64;
    for _ in 0..5 {
        let q: Vec<f64> = (0..m.dofs().len())
            .map(|_| {
                rng_q = (rng_q * 7.31 + 0.19).fract();
                (rng_q - 0.5) * 4.0
            })
            .collect();
        let mut poses = std::collections::HashMap::new();
        poses.insert(model.reference.clone(), Isometry3::identity());
        while poses.len() < urdf.links.len() {
            let before = poses.len();
            for j in &urdf.joints {
                if poses.contains_key(&j.child.link) {
                    continue;
                }
                let Some(parent) = poses.get(&j.parent.link).copied() else {
                    continue;
                };
                let motion = match &j.joint_type {
                    urdf_rs::JointType::Continuous => {
                        assert_eq!(urdf.joints.iter().filter(|k| k.name == j.name).count(), 1);
                        let d = m.dof_index(&j.name).expect("joints named after the DoFs");
                        let axis = nalgebra::Unit::new_normalize(Vector3::from(*j.axis.xyz));
                        Isometry3::from_parts(
                            Translation3::identity(),
                            UnitQuaternion::from_axis_angle(&axis, q[d]),
                        )
                    }
                    urdf_rs::JointType::Fixed => Isometry3::identity(),
                    other => panic!("unexpected joint type {other:?}"),
                };
                poses.insert(j.child.link.clone(), parent * rpy(&j.origin) * motion);
            }
            assert!(poses.len() > before, "the URDF is not one tree");
        }
        let k = forward_kinematics(m, &robot.parameters, &q);
        for (u, su) in m.sus().iter().enumerate() {
            let from_urdf = poses[&su.name];
            let difference = from_urdf.inverse() * k.sus[u];
            assert!(difference.translation.vector.norm() < 1e-9, "{}", su.name);
            assert!(difference.rotation.angle() < 1e-9, "{}", su.name);
        }
    }
}

#[test]
fn names_that_differ_between_model_and_data_are_named_in_the_error() {
    let (_, model) = noisy_humanoid();
    // Data of another robot: the humanoid's DoFs are missing and named.
    let arm = presets::find("paper-7dof").unwrap().robot().unwrap();
    let err = validate(&model, &held_out(&arm, 1), "arm.json").unwrap_err();
    let message = err.to_string();
    assert!(
        matches!(err, PredictError::Missing { what: "DoFs", .. }),
        "{message}"
    );
    assert!(
        message.contains("neck_yaw") && message.contains("arm.json"),
        "{message}"
    );
    // The same robot with one SU renamed: that SU is named.
    let robot =
        with_random_sus(&presets::find("humanoid").unwrap().robot().unwrap(), 2, 7).unwrap();
    let mut data = held_out(&robot, 2);
    data.sus[0] = "mystery".into();
    let err = validate(&model, &data, "held-out").unwrap_err().to_string();
    assert!(
        err.contains("SUs") && err.contains(&robot.model.su_names()[0]),
        "{err}"
    );
    // A pose table without one of the model's DoFs, and one with a DoF the model lacks.
    let predictor = skincal::predict::Predictor::new(&model).unwrap();
    let mut dofs = predictor.dofs();
    dofs.pop();
    let table = skincal::predict::PoseTable {
        poses: vec![vec![0.0; dofs.len()]],
        dofs,
    };
    let err = predictor
        .arrange(&table, "poses.csv")
        .unwrap_err()
        .to_string();
    assert!(
        err.contains("r_ankle_roll") && err.contains("poses.csv"),
        "{err}"
    );
}

#[test]
fn urdf_export_loads_in_mujoco_with_the_same_kinematics() {
    let (_, model) = noisy_humanoid();
    let robot = model.check().unwrap();
    let m = &robot.model;
    let dir = tempfile::tempdir().unwrap();
    let urdf = dir.path().join("body.urdf");
    std::fs::write(&urdf, skincal::model::urdf::to_urdf(&robot).unwrap()).unwrap();
    let mut cases = Vec::new();
    let mut x = 0.61f64;
    for _ in 0..5 {
        let q: Vec<f64> = (0..m.dofs().len())
            .map(|_| {
                x = (x * 9.17 + 0.23).fract();
                (x - 0.5) * 5.0
            })
            .collect();
        let k = forward_kinematics(m, &robot.parameters, &q);
        let links: serde_json::Map<String, serde_json::Value> = m
            .segments()
            .iter()
            .zip(&k.segments)
            .map(|(s, t)| {
                let (p, r) = (t.translation.vector, t.rotation);
                (
                    s.name.clone(),
                    serde_json::json!([p.x, p.y, p.z, r.w, r.i, r.j, r.k]),
                )
            })
            .collect();
        cases.push(serde_json::json!({"q": q, "links": links}));
    }
    let poses = dir.path().join("poses.json");
    std::fs::write(
        &poses,
        serde_json::json!({"dofs": m.dof_names(), "cases": cases}).to_string(),
    )
    .unwrap();
    // MuJoCo loads the URDF (a refusal fails here with its message) and compares the frames.
    let out = run_python("urdf_fk.py", &[&urdf, &poses]);
    let result: serde_json::Value = serde_json::from_slice(&out).unwrap();
    eprintln!("{result}");
    // Every moving segment is a body of its own in MuJoCo.
    assert!(result["compared"].as_u64().unwrap() >= 5 * (m.segments().len() as u64 - 1));
    assert!(result["position"].as_f64().unwrap() < 1e-9, "{result}");
    assert!(result["rotation"].as_f64().unwrap() < 1e-9, "{result}");
}

#[test]
fn the_html_report_has_a_section_per_input_and_draws_the_whole_tree() {
    let robot = presets::find("humanoid").unwrap().robot().unwrap();
    let set = simulate(&robot, &SimulationConfig::default())
        .unwrap()
        .measurements;
    let structure = explore(&set, &ExploreConfig::default()).unwrap();
    let model = calibrate_body(&set, Some(&structure), &MlConfig::default(), None).unwrap();
    let check = validate(&model, &held_out(&robot, 3), "held-out").unwrap();
    let only_set = skincal::html::render(&skincal::html::ReportInputs {
        title: "set".into(),
        measurements: Some(set.clone()),
        ..Default::default()
    });
    assert!(only_set.contains("<section id=\"summary\""));
    for absent in ["activity", "tree", "limbs", "validation"] {
        assert!(
            !only_set.contains(&format!("<section id=\"{absent}\"")),
            "{absent}"
        );
    }
    let page = skincal::html::render(&skincal::html::ReportInputs {
        title: "humanoid".into(),
        measurements: Some(set),
        structure: Some(structure.clone()),
        model: Some(model.clone()),
        validation: Some((check, "held-out".into())),
        ..Default::default()
    });
    for section in [
        "summary",
        "activity",
        "tree",
        "limbs",
        "validation",
        "set-aside",
    ] {
        assert!(
            page.contains(&format!("<section id=\"{section}\"")),
            "{section}"
        );
    }
    // Fig. 2: one cell per segment and joint, filled where the joint moves the segment.
    let m = &structure.matrix;
    let filled = m.entries.iter().flatten().filter(|&&e| e).count();
    assert_eq!(page.matches("<td class=\"on").count(), filled);
    // The SU × DoF matrices as explored: an SU's change passes the threshold in some orientation
    // exactly where the merged matrix says the DoF's joint moves the SU's segment.
    let data = page
        .split("<script type=\"application/json\" id=\"su-activity-data\">")
        .nth(1)
        .and_then(|rest| rest.split("</script>").next())
        .expect("the SU × DoF matrices");
    let data: serde_json::Value = serde_json::from_str(data).unwrap();
    let names = |key: &str| -> Vec<String> { serde_json::from_value(data[key].clone()).unwrap() };
    let (sus, dofs) = (names("sus"), names("dofs"));
    let levels = data["levels"].as_str().unwrap();
    let orientations = names("orientations");
    assert_eq!((sus.len(), dofs.len(), orientations.len()), (31, 26, 2));
    let segment_of = |su: &str| {
        structure
            .segments
            .iter()
            .position(|g| g.sus.iter().any(|s| s == su))
    };
    let joint_of = |dof: &str| {
        structure
            .joints
            .iter()
            .position(|j| j.dofs.iter().any(|d| d == dof))
    };
    for (i, su) in sus.iter().enumerate() {
        for (j, dof) in dofs.iter().enumerate() {
            let active = orientations.iter().any(|cells| {
                let c = cells.as_bytes()[i * dofs.len() + j] as char;
                levels.find(c).unwrap() >= 32
            });
            let seg = &structure.segments[segment_of(su).unwrap()].id;
            let joint = &structure.joints[joint_of(dof).unwrap()].id;
            let r = m.segments.iter().position(|x| x == seg).unwrap();
            let c = m.joints.iter().position(|x| x == joint).unwrap();
            assert_eq!(active, m.entries[r][c], "{su} × {dof}");
        }
    }
    // The tree: one edge per joint, one node per segment.
    assert_eq!(
        page.matches("<path class=\"joint\"").count(),
        structure.joints.len()
    );
    assert_eq!(
        page.matches("<g class=\"segment\"").count(),
        structure.segments.len()
    );
    // End effectors ringed, branching segments square.
    assert_eq!(
        page.matches("stroke-width=\"2\"").count(),
        structure.end_effectors.len()
    );
    // Every limb and every SU of the model.
    for limb in &model.limbs {
        assert!(page.contains(&format!("Limb {}", limb.name)));
        for su in &limb.sus {
            assert!(page.contains(su.as_str()), "{su}");
        }
    }
}

#[test]
fn the_report_puts_the_truth_beside_every_value_of_the_papers_table() {
    let robot = presets::find("paper-7dof").unwrap().robot().unwrap();
    let set = simulate(&robot, &SimulationConfig::default())
        .unwrap()
        .measurements;
    let structure = explore(&set, &ExploreConfig::default()).unwrap();
    let model = calibrate_body(&set, Some(&structure), &MlConfig::default(), None).unwrap();
    let chain = skincal::estimate::LimbChain::serial(
        "S7",
        &robot.model.dof_names(),
        &robot.model.su_names(),
    )
    .unwrap();
    let data = skincal::estimate::LimbData::new(&set, &chain).unwrap();
    let paper = skincal::estimate::paper::estimate_chain(
        &data,
        &skincal::estimate::paper::PaperConfig::default(),
    )
    .unwrap();
    let page = skincal::html::render(&skincal::html::ReportInputs {
        title: "arm".into(),
        model: Some(model),
        truth: Some(robot),
        paper: vec![paper],
        ..Default::default()
    });
    assert!(page.contains("the truth in brackets"));
    // The paper's method's rows beside the ML ones.
    assert_eq!(page.matches("<tr class=\"paper\">").count(), 6 + 7);
    // 6 DoF → DoF rows of 4 values and 7 DoF → SU rows of 6, each with its true value.
    assert_eq!(
        page.matches("<br><span class=\"note\">(").count(),
        6 * 4 + 7 * 6
    );
    // The truth's a of dof2 → dof3 (0.3 m) is there.
    assert!(page.contains("(0.3000)"));
    // The first rows' θ0 and d are the estimator's gauge: named so, with no deviation.
    assert_eq!(page.matches("(gauge)").count(), 4);
}

/// A limb's fit converged with a residual at its noise level (within 15 %).
fn fits_at_its_noise(limb: &skincal::estimate::ml::MlChainEstimate) {
    assert!(limb.converged, "residual {}", limb.residual_ratio);
    assert!(
        (0.85..1.15).contains(&limb.residual_ratio),
        "{}",
        limb.residual_ratio
    );
}

/// The paper's arm with its ±0.01 g noise (seed 4), and its measurement set.
fn paper_arm_with_the_papers_noise() -> (Robot, skincal::measurements::MeasurementSet) {
    let robot = presets::find("paper-7dof").unwrap().robot().unwrap();
    let config = SimulationConfig {
        seed: 4,
        ..SimulationConfig::default()
    };
    let set = simulate(&robot, &config).unwrap().measurements;
    (robot, set)
}

#[test]
fn excitations_missing_from_some_poses_cost_only_their_readings() {
    // A log rarely holds every excitation of every pose: a window lost to a gap, a pattern the
    // servo did not follow. The fit uses what the set has; only a DoF never excited stops it.
    let (robot, full) = paper_arm_with_the_papers_noise();
    let structure = explore(&full, &ExploreConfig::default()).unwrap();
    let mut partial = full.clone();
    let mut removed = 0;
    let mut draw = 0x2545_f491_4f6c_dd1du64;
    for (p, pose) in partial
        .training
        .as_mut()
        .unwrap()
        .poses
        .iter_mut()
        .enumerate()
    {
        let dofs: Vec<String> = pose.dynamic.keys().cloned().collect();
        for dof in dofs {
            // Pose 3 lost every excitation; elsewhere about one in four is lost (a fixed xorshift).
            draw ^= draw << 13;
            draw ^= draw >> 7;
            draw ^= draw << 17;
            if p == 3 || draw % 4 == 0 {
                pose.dynamic.remove(&dof);
                removed += 1;
            }
        }
    }
    assert!(removed > 30, "{removed}");
    partial.validate().unwrap();
    let truth = held_out(&robot, 99);
    let config = MlConfig::default();
    let check = |set| {
        let model = calibrate_body(set, Some(&structure), &config, None).unwrap();
        let limb = &model.limbs[0].estimate;
        // The residual's readings are the ones the set has: noise alone, none counted as left out.
        fits_at_its_noise(limb);
        assert!(limb.rejected.is_empty(), "{:?}", limb.rejected);
        validate(&model, &truth, "held-out").unwrap()
    };
    let (all, some) = (check(&full), check(&partial));
    eprintln!(
        "held-out RMS with every excitation: static {:.4}, dynamic {:.4}; without {removed} of \
         140: {:.4}, {:.4} m/s²",
        all.static_rms, all.dynamic_rms, some.static_rms, some.dynamic_rms
    );
    // A quarter fewer dynamic readings: their noise weighs √(4/3) more, not more than that much.
    assert!(some.static_rms < 1.5 * all.static_rms, "{some:?}");
    assert!(some.dynamic_rms < 1.5 * all.dynamic_rms, "{some:?}");

    // A DoF excited in no pose: its axis comes from gravity alone.
    let mut never = full.clone();
    for pose in &mut never.training.as_mut().unwrap().poses {
        pose.dynamic.remove("dof4");
    }
    let without = check(&never);
    eprintln!(
        "held-out RMS with dof4 never excited: static {:.4}, dynamic {:.4} m/s²",
        without.static_rms, without.dynamic_rms
    );
    assert!(without.static_rms < 1.5 * all.static_rms, "{without:?}");
    // The other DoFs' accelerations still tell the positions: not the static-only summary.
    let model = calibrate_body(&never, Some(&structure), &config, None).unwrap();
    let limb = &model.limbs[0].estimate;
    assert_eq!(limb.missing_excitations, [("dof4".to_string(), 20)]);
    assert!(limb
        .unobservable
        .iter()
        .all(|u| u.parameters != [skincal::estimate::ml::STATIC_ONLY_POSITIONS]));
}

#[test]
fn a_set_of_static_readings_alone_calibrates_every_orientation() {
    // What many labs record: mean readings at a list of poses, no excitation. Gravity tells every
    // axis direction and SU orientation; no position, and the estimate says so in one line.
    let (robot, mut set) = paper_arm_with_the_papers_noise();
    let structure = explore(&set, &ExploreConfig::default()).unwrap();
    let config = MlConfig::default();
    let full = calibrate_body(&set, Some(&structure), &config, None).unwrap();
    for pose in &mut set.training.as_mut().unwrap().poses {
        pose.dynamic.clear();
        pose.dynamic_sd.clear();
    }
    set.validate().unwrap();
    let model = calibrate_body(&set, Some(&structure), &config, None).unwrap();
    let limb = &model.limbs[0].estimate;
    fits_at_its_noise(limb);
    assert_eq!(
        limb.unobservable[0].parameters,
        [skincal::estimate::ml::STATIC_ONLY_POSITIONS]
    );
    let every: Vec<(String, usize)> = (1..=7).map(|k| (format!("dof{k}"), 20)).collect();
    assert_eq!(limb.missing_excitations, every);
    let truth = held_out(&robot, 99);
    let (with, without) = (
        validate(&full, &truth, "held-out").unwrap(),
        validate(&model, &truth, "held-out").unwrap(),
    );
    eprintln!(
        "held-out static RMS: with dynamic readings {:.4}, static readings alone {:.4} m/s²",
        with.static_rms, without.static_rms
    );
    // Static readings predict static readings as well as the whole set does.
    assert!(without.static_rms < 1.3 * with.static_rms, "{without:?}");
    // Every SU's orientation against the truth's, relative to the second SU's, within a degree.
    // (The first axis is vertical: gravity cannot tell the first SU's turn about it, nor the turn
    // of the rest of the arm about it.)
    let frames = |r: &Robot| forward_kinematics(&r.model, &r.parameters, &[0.0; 7]).sus;
    let truth_frames = frames(&robot);
    let estimated = model.limbs[0].estimate.to_robot();
    let estimated_frames = frames(&estimated);
    let relative = |f: &[Isometry3<f64>], u: usize| f[1].rotation.inverse() * f[u].rotation;
    let mut largest = 0.0f64;
    for u in 2..7 {
        let angle = relative(&truth_frames, u)
            .angle_to(&relative(&estimated_frames, u))
            .to_degrees();
        largest = largest.max(angle);
        assert!(angle < 1.0, "su{} turned {angle:.2}° from the truth", u + 1);
    }
    eprintln!("largest SU orientation error from static readings alone: {largest:.3}°");

    // The order and lines of a joint of several DoFs (the humanoid's shoulders and hips) are
    // told by their accelerations alone: refused, naming the DoF.
    let humanoid = presets::find("humanoid").unwrap().robot().unwrap();
    let mut set = simulate(&humanoid, &noise_free(2)).unwrap().measurements;
    let structure = explore(&set, &ExploreConfig::default()).unwrap();
    for pose in &mut set.training.as_mut().unwrap().poses {
        pose.dynamic.clear();
        pose.dynamic_sd.clear();
    }
    let err = calibrate_body(&set, Some(&structure), &config, None)
        .unwrap_err()
        .to_string();
    let multi: Vec<&String> = structure
        .joints
        .iter()
        .filter(|j| j.dofs.len() > 1)
        .flat_map(|j| &j.dofs)
        .collect();
    assert!(
        err.contains("shares a joint with other DoFs")
            && multi.iter().any(|d| err.contains(&format!("`{d}`"))),
        "{err}"
    );
}

#[test]
fn an_su_the_tree_puts_on_the_wrong_segment_is_named_as_misplaced_with_the_segment_it_fits() {
    // The humanoid's tree as explored, then one SU moved by hand one segment up its arm: the
    // calibration must not call the limb fine nor the sensor noisy, but say where it fits.
    let robot = presets::find("humanoid").unwrap().robot().unwrap();
    let set = simulate(&robot, &SimulationConfig::default())
        .unwrap()
        .measurements;
    let explored = explore(&set, &ExploreConfig::default()).unwrap();
    let home = |s: &skincal::explore::Structure, su: &str| {
        s.segments
            .iter()
            .find(|g| g.sus.iter().any(|x| x == su))
            .map(|g| g.id.clone())
            .unwrap()
    };
    let (su, from) = ("l_forearm_front", home(&explored, "l_forearm_front"));
    let upper = home(&explored, "l_upper_arm_front");
    assert_ne!(from, upper);
    let mut wrong = explored.clone();
    for g in &mut wrong.segments {
        g.sus.retain(|x| x != su);
        if g.id == upper {
            g.sus.push(su.into());
        }
    }
    for l in &mut wrong.limbs {
        l.sus.retain(|x| x != su);
        if l.segments.contains(&upper) {
            l.sus.push(su.into());
        }
    }
    let model = calibrate_body(&set, Some(&wrong), &MlConfig::default(), None).unwrap();
    let named = model
        .broken
        .iter()
        .find(|b| b.su == su)
        .expect("the misplaced SU");
    assert_eq!(named.kind, "misplaced", "{named:?}");
    assert!(
        named.detail.contains(&format!("on segment {upper} where"))
            && named.detail.contains(&format!("on segment {from}:")),
        "{named:?}"
    );
    // Nothing else is blamed, and every limb fits at the noise without it.
    assert_eq!(model.broken.len(), 1, "{:?}", model.broken);
    assert!(model.limbs.iter().all(|l| l.estimate.converged));
}

#[test]
fn a_humanoid_trained_upright_and_tilted_predicts_both_orientations_exactly() {
    // 20 upright poses and 6 with the torso tilted 90°: every limb (and each tree of limbs in one
    // fit) gets a gravity for the tilted poses; the torso's own SUs keep a reading per
    // orientation. Noise-free, held-out poses in both orientations are predicted exactly.
    let robot = presets::find("humanoid").unwrap().robot().unwrap();
    let tilted = |seed: u64, structure: bool| SimulationConfig {
        tilted_poses: 6,
        structure,
        ..noise_free(seed)
    };
    let set = simulate(&robot, &tilted(1, true)).unwrap().measurements;
    let structure = explore(&set, &ExploreConfig::default()).unwrap();
    assert!(structure.complete);
    let config = MlConfig {
        noise_sd: 1e-6,
        ..MlConfig::default()
    };
    let model = calibrate_body(&set, Some(&structure), &config, None).unwrap();
    for limb in &model.limbs {
        assert!(limb.estimate.converged, "{}", limb.name);
        assert_eq!(limb.other_gravities.len(), 1, "{}", limb.name);
    }
    let held_out = simulate(&robot, &tilted(99, false)).unwrap().measurements;
    let poses = &held_out.training.as_ref().unwrap().poses;
    assert_eq!(poses.iter().filter(|p| p.orientation == 1).count(), 6);
    let check = validate(&model, &held_out, "held-out").unwrap();
    assert_eq!(check.poses, 26);
    // Exactly, to the fits' tolerance (a wrong frame of a gravity would be off by m/s²).
    assert!(check.static_max < 1e-5, "static {:e}", check.static_max);
    assert!(check.dynamic_max < 1e-5, "dynamic {:e}", check.dynamic_max);
    assert_eq!(check.sus.len(), robot.model.sus().len());
    // A model trained upright alone knows no tilted gravity: such poses are refused by name.
    let upright = calibrate_body(
        &simulate(&robot, &noise_free(1)).unwrap().measurements,
        Some(&structure),
        &config,
        None,
    )
    .unwrap();
    let err = validate(&upright, &held_out, "held-out").unwrap_err();
    assert!(
        matches!(
            err,
            PredictError::Orientation {
                pose: 20,
                orientation: 1,
                ..
            }
        ),
        "{err}"
    );
}

#[test]
fn a_dofs_dynamic_error_counts_the_readings_of_every_su_it_moves_and_no_other() {
    // Physics: an SU reads the excitation of the DoFs before it only. A noise-free calibration
    // predicts every held-out reading exactly; moving one SU that one DoF alone carries then
    // changes that DoF's dynamic error, by exactly that SU's share, and no other DoF's.
    let robot = presets::find("paper-7dof").unwrap().robot().unwrap();
    let set = simulate(&robot, &noise_free(3)).unwrap().measurements;
    let structure = explore(&set, &ExploreConfig::default()).unwrap();
    let config = MlConfig {
        noise_sd: 1e-6,
        ..MlConfig::default()
    };
    let mut model = calibrate_body(&set, Some(&structure), &config, None).unwrap();
    let truth = held_out(&robot, 5);
    let exact = validate(&model, &truth, "held-out").unwrap();
    assert_eq!(exact.dofs.len(), robot.model.dof_names().len());
    assert!(
        exact.dofs.iter().all(|d| d.dynamic_rms < 1e-6),
        "{:?}",
        exact.dofs
    );
    // Every dynamic reading is counted once by its SU and once by its DoF.
    let by_su: usize = exact.sus.iter().map(|s| s.dynamic_count).sum();
    let by_dof: usize = exact.dofs.iter().map(|d| d.dynamic_count).sum();
    assert_eq!(by_su, by_dof);
    // The SU that one DoF alone moves: one dynamic reading per pose.
    let lone = exact
        .sus
        .iter()
        .find(|s| s.dynamic_count == exact.poses)
        .expect("an SU on the first segment")
        .su
        .clone();
    let entry = model.robot.sus.iter_mut().find(|s| s.name == lone).unwrap();
    let xyz = entry.xyz.as_mut().expect("a placed SU");
    for c in xyz.iter_mut() {
        *c += 0.02;
    }
    let moved = validate(&model, &truth, "held-out").unwrap();
    let su = moved.sus.iter().find(|s| s.su == lone).unwrap();
    assert!(su.dynamic_rms > 1e-3, "{su:?}");
    let changed: Vec<_> = moved.dofs.iter().filter(|d| d.dynamic_rms > 1e-6).collect();
    assert_eq!(changed.len(), 1, "{:?}", moved.dofs);
    let first = &model.limbs[0].dofs[0];
    assert_eq!(&changed[0].dof, first);
    // Its squared errors are the SU's, over the DoF's readings.
    let d = changed[0];
    let share = su.dynamic_rms.powi(2) * su.dynamic_count as f64;
    let whole = d.dynamic_rms.powi(2) * d.dynamic_count as f64;
    assert!(
        (whole - share).abs() < 1e-9 * share,
        "{whole} against {share}"
    );
    assert!((d.dynamic_max - su.dynamic_max).abs() < 1e-12);
}
