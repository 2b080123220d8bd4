//! URDF import of `tests/fixtures/arm.urdf`: fixed joints merge links, revolute and continuous
//! joints become DoFs, SUs land on the right segment at the right place.

use approx::assert_relative_eq;
use nalgebra::{Matrix3, Vector3};
use skincal::io::{load_robot, IoError, SuPlacement};
use skincal::model::description::DescriptionError;
use skincal::model::sensor::{gravity_upright, static_readings};
use skincal::model::{forward_kinematics, DofKind};

use crate::common::fixture;

fn ry(a: f64) -> Matrix3<f64> {
    let (s, c) = a.sin_cos();
    Matrix3::new(c, 0.0, s, 0.0, 1.0, 0.0, -s, 0.0, c)
}
fn rz(a: f64) -> Matrix3<f64> {
    let (s, c) = a.sin_cos();
    Matrix3::new(c, -s, 0.0, s, c, 0.0, 0.0, 0.0, 1.0)
}
fn rx(a: f64) -> Matrix3<f64> {
    let (s, c) = a.sin_cos();
    Matrix3::new(1.0, 0.0, 0.0, 0.0, c, -s, 0.0, s, c)
}

#[test]
fn fixed_joints_merge_links_and_movable_joints_become_dofs() {
    let robot = load_robot(
        fixture("arm-sus.toml").to_str().unwrap(),
        SuPlacement::default(),
    )
    .unwrap();
    let m = &robot.model;
    let segments: Vec<&str> = m.segments().iter().map(|s| s.name.as_str()).collect();
    assert_eq!(segments, ["world", "upper", "hand"]);
    assert_eq!(m.dof_names(), ["shoulder", "wrist"]);
    let shoulder = &m.dofs()[0];
    assert_eq!(
        (
            shoulder.limits.lower,
            shoulder.limits.upper,
            shoulder.limits.velocity
        ),
        (-1.5, 2.0, Some(2.5))
    );
    let wrist = &m.dofs()[1];
    assert_eq!(
        (wrist.limits.lower, wrist.limits.upper),
        (-std::f64::consts::PI, std::f64::consts::PI)
    );
    assert_eq!(wrist.limits.velocity, Some(4.0));
    assert_eq!(m.segments()[m.sus()[0].segment].name, "hand");
    assert_eq!(m.segments()[m.sus()[1].segment].name, "upper");
}

#[test]
fn imported_kinematics_match_the_urdf_by_hand() {
    let robot = load_robot(
        fixture("arm-sus.toml").to_str().unwrap(),
        SuPlacement::default(),
    )
    .unwrap();
    let (s, w) = (0.7, -1.3);
    let k = forward_kinematics(&robot.model, &robot.parameters, &[s, w]);
    // tool_su: 0.05 m along the tool link, which is 0.1 m along the hand's x; the hand frame is
    // T(0, 0, 0.1 + 0.2) · Ry(s) · T(0.4, 0, 0) · Rz(π/2) · Rx(w).
    let p = Vector3::new(0.4 * s.cos(), 0.15, 0.3 - 0.4 * s.sin());
    assert_relative_eq!(k.sus[0].translation.vector, p, epsilon = 1e-12);
    let r = ry(s) * rz(std::f64::consts::FRAC_PI_2) * rx(w);
    assert_relative_eq!(
        k.sus[0].rotation.to_rotation_matrix().into_inner(),
        r,
        epsilon = 1e-12
    );
    let reading = static_readings(&robot.model, &robot.parameters, &[s, w], &gravity_upright());
    assert_relative_eq!(
        reading[0],
        r.transpose() * Vector3::new(0.0, 0.0, 9.81),
        epsilon = 1e-12
    );
    // upper_su: (0.2, 0, 0.03) on the upper link, turning with the shoulder about y at z = 0.3.
    let p = Vector3::new(
        0.2 * s.cos() + 0.03 * s.sin(),
        0.0,
        0.3 - 0.2 * s.sin() + 0.03 * s.cos(),
    );
    assert_relative_eq!(k.sus[1].translation.vector, p, epsilon = 1e-12);
}

#[test]
fn a_bare_urdf_gets_random_sus_on_every_link() {
    let path = fixture("arm.urdf");
    let a = load_robot(
        path.to_str().unwrap(),
        SuPlacement {
            per_link: Some(2),
            seed: 3,
        },
    )
    .unwrap();
    assert_eq!(a.model.sus().len(), 10);
    assert_eq!(a.model.sus()[0].name, "world_su1");
    let b = load_robot(
        path.to_str().unwrap(),
        SuPlacement {
            per_link: Some(2),
            seed: 3,
        },
    )
    .unwrap();
    assert_eq!(a, b);
    // SUs stay within the placement cube around their link's origin: tool SUs near (0.5, 0, 0.3)
    // at q = 0 (hand origin 0.4 m out, tool 0.1 m further).
    let k = forward_kinematics(&a.model, &a.parameters, &[0.0, 0.0]);
    let tool = a.model.su_index("tool_su1").unwrap();
    assert!(
        (k.sus[tool].translation.vector - Vector3::new(0.4, 0.1, 0.3))
            .abs()
            .max()
            <= 0.05 + 1e-12
    );
}

#[test]
fn a_prismatic_joint_slides_its_link_along_its_axis() {
    // slider.urdf: `rail` slides `carriage` along the base's x within 0…0.5 m.
    let robot = load_robot(
        fixture("slider.urdf").to_str().unwrap(),
        SuPlacement {
            per_link: Some(1),
            seed: 3,
        },
    )
    .unwrap();
    let m = &robot.model;
    let rail = &m.dofs()[0];
    assert_eq!(
        (rail.name.as_str(), rail.kind),
        ("rail", DofKind::Prismatic)
    );
    assert_eq!((rail.limits.lower, rail.limits.upper), (0.0, 0.5));
    assert_eq!(m.prismatic_dof_names(), ["rail"]);
    let (base, carriage) = (
        m.su_index("base_su1").unwrap(),
        m.su_index("carriage_su1").unwrap(),
    );
    let at = |q: f64| forward_kinematics(m, &robot.parameters, &[q]);
    let (k0, k1) = (at(0.0), at(0.3));
    // The carriage's SU moves 0.3 m along x and does not turn; the base's stays.
    assert_relative_eq!(
        k1.sus[carriage].translation.vector - k0.sus[carriage].translation.vector,
        Vector3::new(0.3, 0.0, 0.0),
        epsilon = 1e-12
    );
    assert_relative_eq!(
        k1.sus[carriage]
            .rotation
            .angle_to(&k0.sus[carriage].rotation),
        0.0,
        epsilon = 1e-12
    );
    assert_eq!(k0.sus[base], k1.sus[base]);
}

#[test]
fn floating_and_planar_joints_are_refused_by_name() {
    let dir = tempfile::tempdir().unwrap();
    for kind in ["floating", "planar"] {
        let file = dir.path().join(format!("{kind}.urdf"));
        std::fs::write(
            &file,
            format!(
                r#"<robot name="r"><link name="a"/><link name="b"/>
                <joint name="free" type="{kind}"><parent link="a"/><child link="b"/><axis xyz="0 0 1"/></joint></robot>"#
            ),
        )
        .unwrap();
        let err = load_robot(file.to_str().unwrap(), SuPlacement::default()).unwrap_err();
        match &err {
            IoError::Description {
                source: DescriptionError::UnsupportedJoint { joint, kind: found },
                ..
            } => assert_eq!((joint.as_str(), found.as_str()), ("free", kind)),
            other => panic!("unexpected {other}"),
        }
        assert!(err.to_string().contains(&format!("{kind}.urdf")));
    }
}

#[test]
fn an_su_on_an_unknown_link_is_named() {
    let dir = tempfile::tempdir().unwrap();
    std::fs::copy(fixture("arm.urdf"), dir.path().join("arm.urdf")).unwrap();
    let toml = dir.path().join("robot.toml");
    std::fs::write(
        &toml,
        "name = \"a\"\nurdf = \"arm.urdf\"\n[[sus]]\nname = \"s1\"\nsegment = \"elbow\"\n",
    )
    .unwrap();
    let err = load_robot(toml.to_str().unwrap(), SuPlacement::default())
        .unwrap_err()
        .to_string();
    assert!(err.contains("elbow") && err.contains("s1"), "{err}");
}

#[test]
fn a_closed_loop_beside_the_tree_is_refused_by_name() {
    // Links b and c are each other's children: the root a is unique, but the walk from it never
    // reaches their joints (this once panicked).
    let text = r#"<robot name="r"><link name="a"/><link name="b"/><link name="c"/>
<joint name="j1" type="revolute"><parent link="b"/><child link="c"/><axis xyz="0 0 1"/><limit lower="-1" upper="1" effort="1" velocity="1"/></joint>
<joint name="j2" type="revolute"><parent link="c"/><child link="b"/><axis xyz="0 0 1"/><limit lower="-1" upper="1" effort="1" velocity="1"/></joint>
</robot>"#;
    let err = skincal::model::urdf::from_urdf(
        text,
        skincal::model::urdf::UrdfSus::RandomPerLink {
            per_link: 1,
            seed: 1,
        },
    )
    .unwrap_err()
    .to_string();
    assert!(err.contains("`j1`") && err.contains("closed loop"), "{err}");
    // A joint without a direction is refused too.
    let zero = r#"<robot name="r"><link name="a"/><link name="b"/>
<joint name="j" type="continuous"><parent link="a"/><child link="b"/><axis xyz="0 0 0"/></joint></robot>"#;
    let err = skincal::model::urdf::UrdfTree::parse(zero)
        .unwrap_err()
        .to_string();
    assert!(
        err.contains("`j`.axis") && err.contains("non-zero"),
        "{err}"
    );
}
