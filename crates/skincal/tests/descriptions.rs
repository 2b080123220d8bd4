//! The TOML robot format, the humanoid preset and model checks.

use approx::assert_relative_eq;
use skincal::model::description::{with_random_sus, DescriptionError, RobotFile};
use skincal::model::{forward_kinematics, presets, ModelError};

#[test]
fn a_dh_row_and_the_equivalent_urdf_origin_give_the_same_kinematics() {
    // Rz(θ0)·Tz(d)·Tx(a)·Rx(α) = translation (a cos θ0, a sin θ0, d), rotation Rz(θ0)·Rx(α),
    // i.e. rpy = (α, 0, θ0).
    let (t0, d, a, al) = (0.4_f64, 0.12, 0.3, -1.1);
    let dh = format!(
        r#"name = "x"
        reference = "b"
        [[dofs]]
        name = "j1"
        child = "l1"
        [[dofs]]
        name = "j2"
        child = "l2"
        dh = {{ theta0 = {t0}, d = {d}, a = {a}, alpha = {al} }}
        [[sus]]
        name = "s"
        segment = "l2"
        xyz = [0.1, 0.2, 0.3]"#
    );
    let origin = dh.replace(
        &format!("dh = {{ theta0 = {t0}, d = {d}, a = {a}, alpha = {al} }}"),
        &format!(
            "origin = {{ xyz = [{}, {}, {d}], rpy = [{al}, 0, {t0}] }}\naxis = [0, 0, 1]",
            a * t0.cos(),
            a * t0.sin()
        ),
    );
    let r1 = RobotFile::from_toml(&dh).unwrap().build().unwrap();
    let r2 = RobotFile::from_toml(&origin).unwrap().build().unwrap();
    for q in [[0.0, 0.0], [1.0, -2.0], [-0.3, 2.9]] {
        let k1 = forward_kinematics(&r1.model, &r1.parameters, &q);
        let k2 = forward_kinematics(&r2.model, &r2.parameters, &q);
        assert_relative_eq!(
            k1.sus[0].to_homogeneous(),
            k2.sus[0].to_homogeneous(),
            epsilon = 1e-12
        );
    }
}

#[test]
fn a_robot_written_back_as_a_description_is_the_same_robot() {
    for preset in presets::PRESETS {
        let robot = preset.robot().unwrap();
        let text = RobotFile::from_robot(&robot, None).to_toml();
        let again = RobotFile::from_toml(&text).unwrap().build().unwrap();
        let q: Vec<f64> = (0..robot.model.dofs().len())
            .map(|i| 0.1 * i as f64 - 0.5)
            .collect();
        let k1 = forward_kinematics(&robot.model, &robot.parameters, &q);
        let k2 = forward_kinematics(&again.model, &again.parameters, &q);
        for (a, b) in k1.sus.iter().zip(&k2.sus) {
            assert_relative_eq!(a.to_homogeneous(), b.to_homogeneous(), epsilon = 1e-12);
        }
        assert_eq!(robot.model.dof_names(), again.model.dof_names());
        assert_eq!(robot.model.su_names(), again.model.su_names());
    }
}

#[test]
fn humanoid_has_the_described_anatomy() {
    let robot = presets::find("humanoid").unwrap().robot().unwrap();
    let m = &robot.model;
    assert_eq!(m.segments()[0].name, "torso");
    assert_eq!(m.dofs().len(), 26);
    assert_eq!(m.segments().len(), 27);
    // Segments between the DoFs of a multi-DoF joint carry no SU; every other segment 1–3.
    let bare = [
        "neck",
        "l_shoulder_a",
        "l_shoulder_b",
        "r_shoulder_a",
        "r_shoulder_b",
        "l_wrist",
        "r_wrist",
        "l_hip_a",
        "l_hip_b",
        "r_hip_a",
        "r_hip_b",
        "l_ankle",
        "r_ankle",
    ];
    for (s, segment) in m.segments().iter().enumerate() {
        let n = m.sus().iter().filter(|su| su.segment == s).count();
        if bare.contains(&segment.name.as_str()) {
            assert_eq!(n, 0, "{}", segment.name);
        } else {
            assert!((1..=3).contains(&n), "{} has {n} SUs", segment.name);
        }
    }
    // At q = 0 the arm hangs: the left hand's frame is 0.04 + 0.28 + 0.24 + 0.03 m below the
    // shoulder at (0, 0.19 + 0.03, 0.20).
    let k = forward_kinematics(m, &robot.parameters, &vec![0.0; 26]);
    let hand = m.segment_index("l_hand").unwrap();
    assert_relative_eq!(
        k.segments[hand].translation.vector,
        nalgebra::Vector3::new(0.0, 0.22, 0.20 - 0.59),
        epsilon = 1e-12
    );
    // The chain to the hand is the six arm DoFs.
    let names: Vec<&str> = m
        .chain_to(hand)
        .iter()
        .map(|&d| m.dofs()[d].name.as_str())
        .collect();
    assert_eq!(
        names,
        [
            "l_shoulder_pitch",
            "l_shoulder_roll",
            "l_shoulder_yaw",
            "l_elbow",
            "l_wrist_yaw",
            "l_wrist_pitch"
        ]
    );
}

#[test]
fn random_sus_replace_the_described_ones_reproducibly() {
    let robot = presets::find("humanoid").unwrap().robot().unwrap();
    let a = with_random_sus(&robot, 2, 7).unwrap();
    let b = with_random_sus(&robot, 2, 7).unwrap();
    let c = with_random_sus(&robot, 2, 8).unwrap();
    assert_eq!(a, b);
    assert_ne!(a.parameters, c.parameters);
    assert_eq!(a.model.sus().len(), 14 * 2);
    assert_eq!(a.model.sus()[0].name, "torso_su1");
}

fn build(text: &str) -> Result<skincal::model::Robot, DescriptionError> {
    RobotFile::from_toml(text)?.build()
}

#[test]
fn malformed_toml_names_the_line() {
    let err = build("name = \"x\"\nreference = \"b\"\n[[dofs]]\nname = 3\n").unwrap_err();
    let msg = err.to_string();
    assert!(msg.contains("line 4"), "{msg}");
}

#[test]
fn unknown_fields_are_rejected_with_their_name() {
    let err = build(
        "name = \"x\"\nreference = \"b\"\n[[dofs]]\nname = \"j\"\nchild = \"l\"\nlenght = 3\n",
    )
    .unwrap_err();
    assert!(err.to_string().contains("lenght"), "{err}");
}

#[test]
fn impossible_limits_name_the_dof() {
    let err = build("name = \"x\"\nreference = \"b\"\n[[dofs]]\nname = \"elbow\"\nchild = \"l\"\nlower = 1.0\nupper = -1.0\n").unwrap_err();
    assert!(
        matches!(err, DescriptionError::Model(ModelError::InvalidLimits { ref dof, .. }) if dof == "elbow"),
        "{err}"
    );
    let err = build("name = \"x\"\nreference = \"b\"\n[[dofs]]\nname = \"elbow\"\nchild = \"l\"\nlower = -1.0\n").unwrap_err();
    assert!(err.to_string().contains("elbow"), "{err}");
    let err = build("name = \"x\"\nreference = \"b\"\n[[dofs]]\nname = \"elbow\"\nchild = \"l\"\nvelocity = -2.0\n").unwrap_err();
    assert!(err.to_string().contains("velocity"), "{err}");
}

#[test]
fn structural_errors_name_the_culprit() {
    let head = "name = \"x\"\nreference = \"b\"\n";
    let loop_ = format!("{head}[[dofs]]\nname = \"j1\"\nchild = \"l\"\n[[dofs]]\nname = \"j2\"\nparent = \"b\"\nchild = \"l\"\n");
    assert!(matches!(
        build(&loop_),
        Err(DescriptionError::Model(ModelError::SeveralParents { .. }))
    ));
    let unknown = format!("{head}[[dofs]]\nname = \"j1\"\nchild = \"l\"\n[[sus]]\nname = \"s\"\nsegment = \"nowhere\"\n");
    let err = build(&unknown).unwrap_err();
    assert!(
        err.to_string().contains("nowhere") && err.to_string().contains("`s`"),
        "{err}"
    );
    let detached = format!("{head}[[dofs]]\nname = \"j1\"\nparent = \"l2\"\nchild = \"l1\"\n[[dofs]]\nname = \"j2\"\nparent = \"l1\"\nchild = \"l2\"\n");
    assert!(matches!(
        build(&detached),
        Err(DescriptionError::Model(ModelError::Unreachable { .. }))
    ));
    let zero_axis =
        format!("{head}[[dofs]]\nname = \"j1\"\nchild = \"l\"\norigin = {{}}\naxis = [0, 0, 0]\n");
    assert!(matches!(
        build(&zero_axis),
        Err(DescriptionError::Model(ModelError::InvalidAxis { .. }))
    ));
    let dup = format!(
        "{head}[[dofs]]\nname = \"j1\"\nchild = \"l\"\n[[dofs]]\nname = \"j1\"\nchild = \"m\"\n"
    );
    assert!(matches!(
        build(&dup),
        Err(DescriptionError::Model(ModelError::DuplicateName { .. }))
    ));
    let no_reference = "name = \"x\"\n[[dofs]]\nname = \"j1\"\nchild = \"l\"\n";
    assert!(build(no_reference)
        .unwrap_err()
        .to_string()
        .contains("reference"));
}
