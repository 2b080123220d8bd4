//! Self-collision on a URDF's collision geometry: distances computed by hand on a small arm, the
//! pairs left out, the SRDF, the floor, and mesh files found as ROS finds them.

use std::path::{Path, PathBuf};

use skincal::collision::{srdf_disabled_pairs, Body, CollisionOptions, Exclusion};
use skincal::io::{load_body, load_robot, resolve_mesh, SuPlacement};
use skincal::model::urdf::{from_urdf, UrdfSus};

use crate::real_robots::description;

/// A base box (0.2 × 0.2 × 0.1 m, on z = 0), a vertical cylinder link (r 0.05, z 0.1 … 0.5), a
/// 0.3 m box link from z = 0.5 turning about y, and a sphere (r 0.05) 0.25 m out along a third
/// link turning about y at the end of the box.
const ARM: &str = r#"<robot name="arm">
  <link name="base"><collision><origin xyz="0 0 0.05"/><geometry><box size="0.2 0.2 0.1"/></geometry></collision></link>
  <link name="column"><collision><origin xyz="0 0 0.2"/><geometry><cylinder radius="0.05" length="0.4"/></geometry></collision></link>
  <link name="beam"><collision><origin xyz="0 0 0.15"/><geometry><box size="0.05 0.05 0.3"/></geometry></collision></link>
  <link name="tip"><collision><origin xyz="0 0 0.25"/><geometry><sphere radius="0.05"/></geometry></collision></link>
  <joint name="yaw" type="revolute"><parent link="base"/><child link="column"/><origin xyz="0 0 0.1"/><axis xyz="0 0 1"/><limit lower="-3" upper="3" effort="1" velocity="1"/></joint>
  <joint name="shoulder" type="revolute"><parent link="column"/><child link="beam"/><origin xyz="0 0 0.4"/><axis xyz="0 1 0"/><limit lower="-3.2" upper="3.2" effort="1" velocity="1"/></joint>
  <joint name="elbow" type="revolute"><parent link="beam"/><child link="tip"/><origin xyz="0 0 0.3"/><axis xyz="0 1 0"/><limit lower="-3.2" upper="3.2" effort="1" velocity="1"/></joint>
</robot>"#;

fn arm_robot() -> skincal::model::Robot {
    from_urdf(
        ARM,
        UrdfSus::RandomPerLink {
            per_link: 1,
            seed: 1,
        },
    )
    .unwrap()
}

fn arm(options: &CollisionOptions) -> (skincal::model::Robot, Body) {
    let robot = arm_robot();
    let body = Body::new(ARM, &robot, options, &mut |_| Err("no meshes".into())).unwrap();
    (robot, body)
}

#[test]
fn distances_pairs_and_the_floor_as_computed_by_hand() {
    use std::f64::consts::{FRAC_PI_2, PI};
    let (robot, body) = arm(&CollisionOptions::default());
    assert_eq!(body.part_count(), 4);
    // Adjacent: base–column, column–beam, beam–tip; checked: base–beam, base–tip, column–tip.
    assert_eq!(body.pair_count(), 3);
    assert_eq!(body.excluded().len(), 3);
    assert!(body.excluded().iter().all(|e| e.why == Exclusion::Adjacent));
    assert!(body.touching_at_rest().is_empty());
    assert!(body.contact(&robot, &[0.0, 0.0, 0.0]).is_none());
    // The beam level along +x, the tip folded back over the column: the sphere's centre at
    // (0.05, 0, 0.5), on the rim of the column's top face, so they overlap by its radius.
    let folded = [0.0, FRAC_PI_2, PI];
    let c = body
        .contact(&robot, &folded)
        .expect("the tip is in the column");
    assert_eq!((c.a.as_str(), c.b.as_str()), ("column", "tip"));
    assert!((c.distance + 0.05).abs() < 1e-6, "{}", c.distance);
    // The tip hanging down at (0.3, 0, 0.25): 0.2 m from the column's surface and the base's
    // edge, so a clearance of 0.19 m is kept and one of 0.21 m is not.
    let hanging = [0.0, FRAC_PI_2, FRAC_PI_2];
    let wide = |clearance| {
        arm(&CollisionOptions {
            clearance,
            ..Default::default()
        })
    };
    let (robot, body) = wide(0.19);
    assert!(body.contact(&robot, &hanging).is_none());
    let (robot, body) = wide(0.21);
    let c = body.contact(&robot, &hanging).expect("nearer than 0.21 m");
    assert!((c.distance - 0.2).abs() < 1e-6, "{c}");
    // The SRDF's pair is not checked.
    let srdf = r#"<robot name="arm"><disable_collisions link1="tip" link2="column" reason="Never"/></robot>"#;
    let disabled = srdf_disabled_pairs(srdf).unwrap();
    assert_eq!(disabled, vec![("tip".to_string(), "column".to_string())]);
    let (robot, body) = arm(&CollisionOptions {
        disabled,
        ..Default::default()
    });
    assert!(body.contact(&robot, &folded).is_none());
    assert_eq!(body.pair_count(), 2);
    // A floor 3 mm below the column's bottom (z = 0.1), nearer than the skin (5 mm); the
    // base's own box stands on any floor and is not checked.
    let floor = |height| {
        arm(&CollisionOptions {
            floor: Some(height),
            ..Default::default()
        })
    };
    let (robot, body) = floor(0.097);
    let c = body
        .contact(&robot, &hanging)
        .expect("the column's skin is on the floor");
    assert_eq!((c.a.as_str(), c.b.as_str()), ("column", "floor"));
    assert!((c.distance - 0.003).abs() < 1e-6, "{c}");
    let (robot, body) = floor(0.09);
    assert!(body.contact(&robot, &hanging).is_none());
    // An SRDF of another robot is refused by name.
    let other = vec![("tip".to_string(), "gripper".to_string())];
    let robot = arm_robot();
    let options = CollisionOptions {
        disabled: other,
        ..Default::default()
    };
    let e = Body::new(ARM, &robot, &options, &mut |_| Err(String::new())).unwrap_err();
    assert!(e.to_string().contains("`gripper`"), "{e}");
}

#[test]
fn mesh_files_are_found_as_ros_finds_them_and_a_missing_one_is_named() {
    let dir = tempfile::tempdir().unwrap();
    let package = dir.path().join("share/my_robot");
    std::fs::create_dir_all(package.join("meshes")).unwrap();
    std::fs::create_dir_all(package.join("urdf")).unwrap();
    std::fs::write(package.join("meshes/link.stl"), b"solid x\nendsolid x\n").unwrap();
    let urdf = package.join("urdf/robot.urdf");
    // The URDF inside its package: found above it.
    let found = resolve_mesh(&urdf, "package://my_robot/meshes/link.stl").unwrap();
    assert_eq!(found, package.join("meshes/link.stl"));
    // Relative to the URDF, and file:// paths.
    assert_eq!(
        resolve_mesh(&urdf, "../meshes/link.stl").unwrap(),
        package.join("urdf/../meshes/link.stl")
    );
    let absolute = format!("file://{}", package.join("meshes/link.stl").display());
    assert_eq!(
        resolve_mesh(&urdf, &absolute).unwrap(),
        package.join("meshes/link.stl")
    );
    let e = resolve_mesh(&urdf, "package://other_robot/meshes/missing.stl").unwrap_err();
    assert!(
        e.contains("`other_robot`") && e.contains("ROS_PACKAGE_PATH"),
        "{e}"
    );
}

/// A copy of a stock URDF in `dir` with its prismatic joints held (fixed) and its meshes named
/// by absolute `file://` paths.
fn held_copy(stock: &Path, dir: &Path) -> PathBuf {
    let root = description("");
    let text = std::fs::read_to_string(stock).unwrap();
    let text = text
        .replace("type=\"prismatic\"", "type=\"fixed\"")
        .replace(
            "package://example-robot-data/robots/",
            &format!("file://{}/", root.display()),
        );
    let copy = dir.join(stock.file_name().unwrap());
    std::fs::write(&copy, text).unwrap();
    copy
}

#[test]
fn stock_descriptions_load_their_collision_meshes_and_srdfs() {
    // STL (Panda, TALOS) and Collada with a y-up axis (iCub): every <collision> element is one
    // part, and at the rest pose the two sides of each humanoid mirror each other.
    let dir = tempfile::tempdir().unwrap();
    for (urdf, srdf, parts) in [
        (
            "panda_description/urdf/panda.urdf",
            "panda_description/srdf/panda.srdf",
            17,
        ),
        (
            "talos_data/robots/talos_reduced.urdf",
            "talos_data/srdf/talos.srdf",
            52,
        ),
        (
            "icub_description/robots/icub_reduced.urdf",
            "icub_description/srdf/icub.srdf",
            28,
        ),
    ] {
        let copy = held_copy(&description(urdf), dir.path());
        let robot = load_robot(copy.to_str().unwrap(), SuPlacement::default()).unwrap();
        let body = load_body(
            &copy,
            &robot,
            Some(&description(srdf)),
            &CollisionOptions::default(),
        )
        .unwrap();
        assert_eq!(body.part_count(), parts, "{urdf}");
        assert!(body.excluded().iter().any(|e| e.why == Exclusion::Srdf) || urdf.contains("icub"));
        // TALOS names sides `left`/`right`, iCub by an `l_`/`r_` prefix.
        let mirrored = |name: &str| {
            let swapped = name
                .replace("left", "@")
                .replace("right", "left")
                .replace('@', "right");
            match swapped.split_at_checked(2) {
                Some(("l_", rest)) => format!("r_{rest}"),
                Some(("r_", rest)) => format!("l_{rest}"),
                _ => swapped,
            }
        };
        for c in body.touching_at_rest() {
            let twin = body.touching_at_rest().iter().find(|t| {
                let (a, b) = (mirrored(&c.a), mirrored(&c.b));
                (t.a == a && t.b == b) || (t.a == b && t.b == a)
            });
            let twin = twin.unwrap_or_else(|| {
                panic!(
                    "{urdf}: {} – {} touch at rest, not their mirror: {:?}",
                    c.a,
                    c.b,
                    body.touching_at_rest()
                )
            });
            assert!(
                (twin.distance - c.distance).abs() < 1e-3,
                "{urdf}: {c:?} against {twin:?}"
            );
        }
    }
}
