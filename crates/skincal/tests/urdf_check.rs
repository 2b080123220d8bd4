//! The calibrated body on the robot's own URDF: SU frames merged into a URDF of the humanoid with
//! its own link names (checked by an independent forward kinematics in Python), and the check of
//! the URDF's joints against perturbations made here.

use nalgebra::{Isometry3, Translation3, UnitQuaternion, Vector3};
use skincal::align::{align, merge_sus};
use skincal::estimate::body::BodyModel;
use skincal::model::{forward_kinematics, presets, Robot};
use skincal::report::urdf_check;
use skincal::sim::SimulationConfig;

/// A joint origin error: the axis turned by `tilt` (a rotation vector perpendicular to the axis,
/// in the joint frame, rad) about a line through the joint's origin, and shifted along that line
/// by `shift` m.
struct Error {
    dof: &'static str,
    tilt: Vector3<f64>,
    shift: f64,
}

/// The link a segment becomes in the user's URDF (names of its own).
fn link(segment: &str) -> String {
    if segment == "torso" {
        "base_link".into()
    } else {
        format!("{segment}_link")
    }
}

/// The robot as a user's URDF: links named by [`link`] with inertial and visual elements, the
/// joints at their exact origins (but for `errors`), their limits, no SUs.
fn users_urdf(robot: &Robot, errors: &[Error]) -> String {
    let m = &robot.model;
    let k = forward_kinematics(m, &robot.parameters, &vec![0.0; m.dofs().len()]);
    let mut out = String::from("<?xml version=\"1.0\"?>\n<!-- the user's robot -->\n<robot name=\"humanoid_description\">\n");
    for s in m.segments() {
        out.push_str(&format!(
            "  <link name=\"{}\">\n    <inertial>\n      <mass value=\"1.5\"/>\n      <inertia ixx=\"0.01\" ixy=\"0\" ixz=\"0\" iyy=\"0.01\" iyz=\"0\" izz=\"0.01\"/>\n    </inertial>\n    <visual>\n      <geometry><box size=\"0.05 0.05 0.05\"/></geometry>\n    </visual>\n  </link>\n",
            link(&s.name)
        ));
    }
    for (d, dof) in m.dofs().iter().enumerate() {
        let mut origin = k.segments[dof.parent].inverse() * k.joints[d];
        if let Some(e) = errors.iter().find(|e| e.dof == dof.name) {
            assert!(
                e.tilt.dot(&dof.axis).abs() < 1e-12,
                "a tilt is perpendicular to the axis"
            );
            origin *= Isometry3::from_parts(
                Translation3::from(e.tilt.normalize() * e.shift),
                UnitQuaternion::from_scaled_axis(e.tilt),
            );
        }
        let (r, p, y) = origin.rotation.euler_angles();
        let v = origin.translation.vector;
        let a = dof.axis;
        out.push_str(&format!(
            "  <joint name=\"{}\" type=\"revolute\">\n    <origin xyz=\"{} {} {}\" rpy=\"{r} {p} {y}\"/>\n    <parent link=\"{}\"/>\n    <child link=\"{}\"/>\n    <axis xyz=\"{} {} {}\"/>\n    <limit lower=\"{}\" upper=\"{}\" effort=\"40\" velocity=\"3\"/>\n  </joint>\n",
            dof.name,
            v.x, v.y, v.z,
            link(&m.segments()[dof.parent].name),
            link(&m.segments()[dof.child].name),
            a.x, a.y, a.z,
            dof.limits.lower, dof.limits.upper,
        ));
    }
    out.push_str("</robot>\n");
    out
}

fn calibrated_humanoid() -> (Robot, BodyModel) {
    let robot = presets::find("humanoid").unwrap().robot().unwrap();
    let model = crate::common::calibrated(
        &robot,
        &SimulationConfig {
            seed: 5,
            ..SimulationConfig::default()
        },
    );
    (robot, model)
}

#[test]
fn check_urdf_flags_exactly_the_perturbed_joints() {
    let (robot, model) = calibrated_humanoid();
    let exact = align(&model, &users_urdf(&robot, &[])).unwrap();
    eprintln!("{}", urdf_check(&exact.check));
    assert!(
        exact.check.disagree.is_empty(),
        "{:?}",
        exact.check.disagree
    );
    let errors = [
        Error {
            dof: "l_elbow",
            tilt: Vector3::new(0.04, 0.0, 0.0),
            shift: 0.004,
        },
        Error {
            dof: "r_knee",
            tilt: Vector3::new(0.0, 0.0, -0.03),
            shift: -0.003,
        },
        Error {
            dof: "l_wrist_pitch",
            tilt: Vector3::new(0.0, 0.0, 0.05),
            shift: 0.005,
        },
    ];
    let off = align(&model, &users_urdf(&robot, &errors)).unwrap();
    eprintln!("{}", urdf_check(&off.check));
    let mut flagged = off.check.disagree.clone();
    flagged.sort();
    let mut expected: Vec<String> = errors.iter().map(|e| e.dof.to_string()).collect();
    expected.sort();
    assert_eq!(flagged, expected);
    for e in &errors {
        let j = off.check.joints.iter().find(|j| j.dof == e.dof).unwrap();
        let (angle, distance) = (e.tilt.norm(), e.shift.abs());
        assert!(
            (j.angle - angle).abs() <= 3.0 * j.angle_sd,
            "{}: angle {} vs {angle} ± {}",
            e.dof,
            j.angle,
            j.angle_sd
        );
        assert!(
            (j.distance - distance).abs() <= 3.0 * j.distance_sd,
            "{}: distance {} vs {distance} ± {}",
            e.dof,
            j.distance,
            j.distance_sd
        );
        // The correction turns the URDF's axis back: against the error.
        let tilt = Vector3::from(j.tilt);
        assert!(
            tilt.normalize().dot(&e.tilt.normalize()) < -0.99,
            "{}: tilt {tilt:?}",
            e.dof
        );
    }
}

#[test]
fn su_frames_merged_into_the_users_urdf_read_what_the_model_predicts() {
    use rand::{Rng, SeedableRng};
    let (robot, model) = calibrated_humanoid();
    let urdf = users_urdf(&robot, &[]);
    let alignment = align(&model, &urdf).unwrap();
    let merged = merge_sus(&alignment, &urdf, "", false).unwrap();
    // Everything of the user's URDF is kept as it was, the SU frames added before `</robot>`.
    let end = urdf.rfind("</robot>").unwrap();
    assert!(merged.starts_with(&urdf[..end]) && merged.ends_with(&urdf[end..]));
    // The torso's SUs are on the static reference segment: only their tilt is known.
    let on_torso: Vec<&str> = alignment.unplaced.iter().map(|(s, _)| s.as_str()).collect();
    let m = &robot.model;
    for su in m.sus() {
        let on_reference = m.segments()[su.segment].parent_dof.is_none();
        assert_eq!(
            on_torso.contains(&su.name.as_str()),
            on_reference,
            "{}",
            su.name
        );
    }

    // Held-out poses within the limits.
    let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(17);
    let poses: Vec<Vec<f64>> = (0..12)
        .map(|_| {
            m.dofs()
                .iter()
                .map(|d| rng.random_range(d.limits.lower..=d.limits.upper))
                .collect()
        })
        .collect();
    let placed: Vec<&str> = alignment.sus.iter().map(|s| s.su.as_str()).collect();
    let dir = tempfile::tempdir().unwrap();
    let (urdf_path, request) = (dir.path().join("skin.urdf"), dir.path().join("poses.json"));
    std::fs::write(&urdf_path, &merged).unwrap();
    std::fs::write(
        &request,
        serde_json::json!({"joints": m.dof_names(), "links": placed, "poses": poses}).to_string(),
    )
    .unwrap();
    let out = crate::common::run_python("urdf_link_rotations.py", &[&urdf_path, &request]);
    let fk: serde_json::Value = serde_json::from_slice(&out).unwrap();

    // Each SU hangs on the link of its segment.
    for su in &placed {
        let segment = &m.segments()[m.sus()[m.su_index(su).unwrap()].segment].name;
        assert_eq!(
            fk["parents"][*su].as_str(),
            Some(link(segment).as_str()),
            "{su}"
        );
    }
    // Each SU's uncertainty in the limb's frame: its orientation's, summed along the limb.
    let mut sd = std::collections::HashMap::new();
    for limb in &model.limbs {
        let mut variance = 0.0;
        for u in &limb.estimate.uncertainty {
            variance += u.orientation_sd * u.orientation_sd;
            sd.insert(u.su.clone(), variance.sqrt());
        }
    }
    let predictor = skincal::predict::Predictor::new(&model).unwrap().ideal();
    let model_sus = predictor.sus();
    let gravity = model.gravity_by_su();
    let mut worst: f64 = 0.0;
    for (p, q) in poses.iter().enumerate() {
        let readings = predictor.readings(q, &model.pattern);
        for (i, su) in placed.iter().enumerate() {
            let r: Vec<f64> = fk["rotations"][p][i]
                .as_array()
                .unwrap()
                .iter()
                .map(|x| x.as_f64().unwrap())
                .collect();
            let rotation = nalgebra::Matrix3::from_row_slice(&r);
            let g = gravity[*su].norm();
            let from_urdf = rotation.transpose() * Vector3::new(0.0, 0.0, g);
            let predicted = readings.statics[model_sus.iter().position(|s| s == su).unwrap()];
            let error = (from_urdf - predicted).norm();
            let ratio = error / (3.0 * g * sd[*su]);
            worst = worst.max(ratio);
            assert!(
                ratio <= 1.0,
                "{su} in pose {p}: {error} m/s² apart, 3σ = {}",
                3.0 * g * sd[*su]
            );
        }
    }
    eprintln!("largest difference: {worst:.2} of 3σ");
}

#[test]
fn the_merge_keeps_the_files_line_endings_and_a_closing_tag_on_a_line_of_its_own() {
    let (robot, model) = calibrated_humanoid();
    let plain = users_urdf(&robot, &[]);
    for urdf in [
        plain.replace('\n', "\r\n"),
        plain.replace("  </joint>\n</robot>\n", "  </joint></robot>"),
    ] {
        let alignment = align(&model, &urdf).unwrap();
        let merged = merge_sus(&alignment, &urdf, "skin_", false).unwrap();
        let end = urdf.rfind("</robot>").unwrap();
        assert!(merged.starts_with(&urdf[..end]) && merged.ends_with(&urdf[end..]));
        let crlf = urdf.contains("\r\n");
        assert_eq!(merged.matches("\r\n").count() > 0, crlf);
        if crlf {
            assert_eq!(merged.matches('\n').count(), merged.matches("\r\n").count());
        }
        assert_eq!(merged.matches("_mount\" type=\"fixed\"").count(), 28);
        // It reads back with every SU on its link (checked inside `merge_sus`), and `</robot>`
        // now stands on a line of its own.
        assert!(merged.contains("</joint>") && merged.trim_end().ends_with("</robot>"));
    }
}

#[test]
fn a_relocated_urdf_names_its_meshes_absolutely_keeps_package_names_and_tells_mujoco_where_they_were(
) {
    let text = r#"<robot name="r"><link name="a"><visual><geometry><mesh filename="../meshes/a.stl"/></geometry></visual><collision><geometry><mesh filename="package://r/meshes/a.stl" scale="1 1 1"/></geometry></collision></link><link name="b"><visual><geometry><mesh filename="/opt/b.dae"/></geometry></visual></link></robot>"#;
    let out = skincal::align::relocated(text, std::path::Path::new("/home/u/r/urdf"));
    assert!(
        out.contains(r#"filename="/home/u/r/urdf/../meshes/a.stl""#),
        "{out}"
    );
    assert!(
        out.contains(r#"filename="package://r/meshes/a.stl" scale="1 1 1""#),
        "{out}"
    );
    assert!(out.contains(r#"filename="/opt/b.dae""#), "{out}");
    assert_eq!(out.len(), text.len() + "/home/u/r/urdf/".len());
    // A MuJoCo block: its compiler looks for the meshes' last names where the file was, unless
    // it says where already.
    let with_block = text.replace(
        "</robot>",
        r#"<mujoco><compiler fusestatic="false"/></mujoco></robot>"#,
    );
    let out = skincal::align::relocated(&with_block, std::path::Path::new("/home/u/r/urdf"));
    assert!(
        out.contains(r#"<compiler meshdir="/home/u/r/urdf" fusestatic="false"/>"#),
        "{out}"
    );
    let told = with_block.replace("<compiler ", r#"<compiler meshdir="m" "#);
    let out = skincal::align::relocated(&told, std::path::Path::new("/home/u/r/urdf"));
    assert!(out.contains(r#"<compiler meshdir="m" fusestatic"#), "{out}");
    let told = with_block.replace("<compiler ", "<compiler\n    meshdir=\"m\" ");
    let out = skincal::align::relocated(&told, std::path::Path::new("/home/u/r/urdf"));
    assert_eq!(out.matches("meshdir").count(), 1, "{out}");
}

#[test]
fn an_su_whose_place_no_reading_tells_is_merged_with_a_word_saying_so() {
    // The paper's arm: su1 is moved by the vertical first DoF alone, so how far along and about
    // that axis it sits from su2 on, no reading tells; everything after su1 is determined.
    let robot = presets::find("paper-7dof").unwrap().robot().unwrap();
    let model = crate::common::calibrated(&robot, &SimulationConfig::default());
    let text = users_urdf(&robot, &[]);
    let alignment = align(&model, &text).unwrap();
    let named: Vec<&str> = alignment
        .partial
        .iter()
        .map(|(su, _)| su.as_str())
        .collect();
    assert_eq!(named, ["su1"], "{:?}", alignment.partial);
    assert!(
        alignment.partial[0].1.contains("position along"),
        "{:?}",
        alignment.partial
    );
    let merged = merge_sus(&alignment, &text, "", false).unwrap();
    assert_eq!(merged.matches("partly measured").count(), 1);
    let comment = merged.find("<!-- su1: partly measured").unwrap();
    let link = merged.find("<link name=\"su1\"/>").unwrap();
    assert!(comment < link);
}
