//! Mimic joints (URDF `<mimic>`): a follower has no actuator and moves only with its leader.
//! Truths: the same robot with the follower as an independent DoF put where the mimic relation
//! says, finite differences of the kinematics, the stock descriptions' own `<mimic>` tags, and
//! the simulated robot's tree.

use skincal::explore::{explore, DiagnosticKind, ExploreConfig, Severity};
use skincal::io::{load_robot, SuPlacement};
use skincal::model::sensor::{
    numerical_peak_accelerations, peak_dynamic_accelerations, ExcitationPattern,
};
use skincal::model::urdf::{from_urdf, to_urdf, UrdfSus};
use skincal::model::{forward_kinematics, Robot};
use skincal::plan::trajectory::Section;
use skincal::plan::{Action, Plan, PlanConfig, PlanDof};
use skincal::sim::{simulate, SimulationConfig};

use crate::real_robots::{description, tree_is_exact};

/// A two-DoF arm with a gripper: `grip` moves the first finger, `grip_2` the second, mirrored
/// (`<mimic multiplier="-0.5" offset="0.1">`), and a tip on the second finger; one SU on every
/// link. With `mimic` false, `grip_2` is an independent joint.
fn gripper_urdf(mimic: bool) -> String {
    let tag = if mimic {
        r#"<mimic joint="grip" multiplier="-0.5" offset="0.1"/>"#
    } else {
        ""
    };
    gripper_urdf_with(tag)
}

/// [`gripper_urdf`] with `tag` on `grip_2`.
fn gripper_urdf_with(tag: &str) -> String {
    let joint = |name: &str, parent: &str, child: &str, xyz: &str, axis: &str, extra: &str| {
        format!(
            r#"<joint name="{name}" type="revolute"><parent link="{parent}"/><child link="{child}"/><origin xyz="{xyz}" rpy="0.1 0 0.2"/><axis xyz="{axis}"/><limit lower="-1.5" upper="1.5" effort="1" velocity="1"/>{extra}</joint>"#
        )
    };
    let links: String = ["base", "upper", "hand", "finger_1", "finger_2", "tip"]
        .iter()
        .map(|l| format!(r#"<link name="{l}"/>"#))
        .collect();
    format!(
        r#"<robot name="gripper">{links}{}{}{}{}{}</robot>"#,
        joint("shoulder", "base", "upper", "0 0 0.2", "0 1 0", ""),
        joint("elbow", "upper", "hand", "0.3 0 0", "0 1 0", ""),
        joint("grip", "hand", "finger_1", "0.1 0.02 0", "0 0 1", ""),
        joint("grip_2", "hand", "finger_2", "0.1 -0.02 0", "0 0 -1", tag),
        r#"<joint name="tip_fixed" type="fixed"><parent link="finger_2"/><child link="tip"/><origin xyz="0.05 0 0"/></joint>"#,
    )
}

fn gripper(mimic: bool) -> Robot {
    from_urdf(
        &gripper_urdf(mimic),
        UrdfSus::RandomPerLink {
            per_link: 2,
            seed: 3,
        },
    )
    .unwrap()
}

#[test]
fn a_mimic_joint_is_where_its_leader_puts_it() {
    let (follower, free) = (gripper(true), gripper(false));
    let m = &follower.model;
    let (grip, grip_2) = (m.dof_index("grip").unwrap(), m.dof_index("grip_2").unwrap());
    assert!(m.is_follower(grip_2) && !m.is_follower(grip));
    assert_eq!(m.followers_of(grip), [grip_2]);
    assert_eq!(m.driven_dofs().len(), 3);
    // The leader moves the follower's body, and its SUs.
    let su = m.su_index("finger_2_su1").unwrap();
    assert!(m.moves_su(grip, su));
    for q in [[0.3, -0.2, 0.7, 9.0], [-1.0, 0.4, -1.2, -3.0]] {
        // The follower's own entry is not read: the free robot with it at −0.5 q + 0.1 agrees.
        let mut q_free = q.to_vec();
        q_free[grip_2] = -0.5 * q[grip] + 0.1;
        let a = forward_kinematics(m, &follower.parameters, &q);
        let b = forward_kinematics(&free.model, &free.parameters, &q_free);
        for (x, y) in a.sus.iter().zip(&b.sus) {
            assert!((x.translation.vector - y.translation.vector).norm() < 1e-12);
            assert!(x.rotation.angle_to(&y.rotation) < 1e-12);
        }
        // Exciting the leader accelerates the follower's body as the finite differences of its
        // positions say (the pattern moves the follower by −0.5 times the leader's angle).
        let pattern = ExcitationPattern::default();
        let analytic = peak_dynamic_accelerations(m, &follower.parameters, &q, grip, &pattern);
        let numeric = numerical_peak_accelerations(m, &follower.parameters, &q, grip, &pattern);
        for (u, (x, y)) in analytic.iter().zip(&numeric).enumerate() {
            assert!((x - y).norm() < 1e-4, "{}: {x} vs {y}", m.sus()[u].name);
        }
        assert!(
            analytic[su].norm() > 0.05,
            "the leader accelerates the follower's SU"
        );
    }
}

#[test]
fn mimic_tags_are_read_chained_and_written_back() {
    // Chained: a follower of a follower follows the first leader, factors composed.
    let text = gripper_urdf(true).replace(
        "</robot>",
        r#"<link name="nail"/><joint name="nail_joint" type="revolute"><parent link="finger_2"/><child link="nail"/><origin xyz="0.02 0 0"/><axis xyz="0 0 1"/><limit lower="-1" upper="1" effort="1" velocity="1"/><mimic joint="grip_2" multiplier="2" offset="0.3"/></joint></robot>"#,
    );
    let robot = from_urdf(
        &text,
        UrdfSus::RandomPerLink {
            per_link: 1,
            seed: 1,
        },
    )
    .unwrap();
    let m = &robot.model;
    let nail = m.dofs()[m.dof_index("nail_joint").unwrap()].mimic.unwrap();
    assert_eq!(m.dofs()[nail.leader].name, "grip");
    // q = 2 (−0.5 q + 0.1) + 0.3 = −q + 0.5.
    assert!((nail.multiplier + 1.0).abs() < 1e-12 && (nail.offset - 0.5).abs() < 1e-12);
    // Written back, the tags give the same kinematics.
    let again = from_urdf(&to_urdf(&robot).unwrap(), UrdfSus::Listed(&[])).unwrap();
    assert_eq!(again.model.mimic_specs(), m.mimic_specs());
    let q = [0.2, -0.3, 0.4, 0.0, 0.0];
    let (a, b) = (
        forward_kinematics(m, &robot.parameters, &q),
        forward_kinematics(&again.model, &again.parameters, &q),
    );
    for s in 0..m.segments().len() {
        let t = again
            .model
            .segment_index(&m.segments()[s].name)
            .expect("every segment is a link");
        assert!(
            (a.segments[s].translation.vector - b.segments[t].translation.vector).norm() < 1e-9
        );
    }
    // A leader that is no joint of the robot is refused by name.
    let bad = gripper_urdf(true).replace(r#"joint="grip""#, r#"joint="gripper""#);
    let err = from_urdf(
        &bad,
        UrdfSus::RandomPerLink {
            per_link: 1,
            seed: 1,
        },
    )
    .unwrap_err()
    .to_string();
    assert!(err.contains("grip_2") && err.contains("gripper"), "{err}");
}

#[test]
fn a_plan_never_moves_a_mimic_joint_alone_and_does_not_command_it() {
    let robot = gripper(true);
    let plan = Plan::new(PlanDof::from_robot(&robot), &PlanConfig::short()).unwrap();
    for phase in &plan.phases {
        match &phase.action {
            Action::Move { dof } => assert_ne!(dof, "grip_2"),
            Action::Excitation { dof, together } => {
                assert_ne!(dof, "grip_2");
                assert!(!together.contains(&"grip_2".to_string()));
            }
            _ => {}
        }
    }
    let (grip, grip_2) = (2, 3);
    let mut t = 0.0;
    while t < plan.duration {
        let s = plan.state(t);
        assert!(
            (s.q[grip_2] - (-0.5 * s.q[grip] + 0.1)).abs() < 1e-12,
            "at {t} s"
        );
        assert!((s.qd[grip_2] + 0.5 * s.qd[grip]).abs() < 1e-12);
        assert!((s.qdd[grip_2] + 0.5 * s.qdd[grip]).abs() < 1e-12);
        t += 0.01;
    }
    // The structure part moves each of the three driven DoFs once.
    let moves = plan
        .phases
        .iter()
        .filter(|p| matches!(p.action, Action::Move { .. }))
        .count();
    assert_eq!(moves, 2 * 3);
    let trajectory = plan.trajectory(Section::Whole, 0.05);
    assert_eq!(trajectory.joint_names, ["shoulder", "elbow", "grip"]);
    assert!(trajectory.knots.iter().all(|k| k.positions.len() == 3));
    assert!(trajectory.interpolation_error(&plan, 4) < 1e-3);
}

/// The SUs of a body a follower drives are told from the leader's body by their readings and
/// set aside with a warning naming the leader; the follower is left out; the rest of the tree is
/// exact.
#[test]
fn the_bodies_mimic_joints_drive_are_told_apart_and_set_aside() {
    let gripper = gripper(true);
    let pr2 = load_robot(
        description("pr2_description/urdf/pr2.urdf")
            .to_str()
            .unwrap(),
        SuPlacement {
            per_link: Some(2),
            seed: 1,
        },
    )
    .unwrap();
    for (what, robot, aside) in [
        // Which finger is the leader's cannot be told when the follower turns by half as much:
        // both are set aside.
        (
            "gripper",
            &gripper,
            [
                "finger_1_su1",
                "finger_1_su2",
                "finger_2_su1",
                "finger_2_su2",
                "tip_su1",
                "tip_su2",
            ]
            .map(String::from)
            .to_vec(),
        ),
        // The PR2's grippers: the leader turns the left finger; the right one turns the other
        // way, and the fingertips (with the left tip's frame) stay level as the fingers open, so
        // the leader's pattern accelerates them without turning them. The parallelogram links
        // turn exactly as the left finger does and stay with it (their bodies keep one rotation).
        (
            "PR2",
            &pr2,
            ["l", "r"]
                .iter()
                .flat_map(|side| {
                    [
                        "l_finger_tip_frame",
                        "l_finger_tip_link",
                        "r_finger_link",
                        "r_finger_tip_link",
                    ]
                    .iter()
                    .flat_map(move |link| [1, 2].map(|k| format!("{side}_gripper_{link}_su{k}")))
                })
                .collect::<Vec<String>>(),
        ),
    ] {
        for seed in 1..=2 {
            let set = simulate(
                robot,
                &SimulationConfig {
                    seed,
                    ..SimulationConfig::default()
                },
            )
            .unwrap()
            .measurements;
            assert!(!set.mimic.is_empty());
            let structure = explore(&set, &ExploreConfig::default()).unwrap();
            assert!(
                structure
                    .diagnostics
                    .iter()
                    .all(|d| d.severity != Severity::Error),
                "{what}, seed {seed}: {:?}",
                structure.diagnostics
            );
            let mut unplaced = structure.unplaced_sus.clone();
            unplaced.sort();
            assert_eq!(unplaced, aside, "{what}, seed {seed}");
            let warned: Vec<&String> = structure
                .diagnostics
                .iter()
                .filter(|d| d.kind == DiagnosticKind::MimicDriven)
                .flat_map(|d| &d.sus)
                .collect();
            assert_eq!(warned.len(), aside.len(), "{what}, seed {seed}");
            assert!(tree_is_exact(robot, &structure), "{what}, seed {seed}");
        }
    }
}

/// The gripper with mirrored fingers (`multiplier="1"` about the opposite axis) through a short program logged at 1 kHz
/// (±0.01 g, the tilted structure part too) and ingested with the robot's mimic list (as
/// `ingest --robot` does): the follower is no move or excitation of its own, so every structure
/// move and excitation is found; one finger's SUs are set aside, the rest of the tree is exact, and both the windows' readings and every sample of the log calibrate it to the
/// noise-free held-out poses within 0.05 m/s².
#[test]
fn a_gripper_with_a_mimic_finger_is_calibrated_from_its_logs() {
    use skincal::ingest::IngestConfig;

    let urdf = gripper_urdf_with(r#"<mimic joint="grip" multiplier="1"/>"#);
    let robot = from_urdf(
        &urdf,
        UrdfSus::RandomPerLink {
            per_link: 2,
            seed: 3,
        },
    )
    .unwrap();
    let plan = crate::common::short_plan(&robot, 8, 3);
    let dir = tempfile::tempdir().unwrap();
    let config = IngestConfig {
        mimic: robot.model.mimic_specs(),
        ..IngestConfig::default()
    };
    let (ingested, upright) =
        crate::common::logged_and_ingested(&robot, &plan, &config, dir.path());
    assert!(
        ingested.report.warnings.is_empty(),
        "{:?}",
        ingested.report.warnings
    );
    let set = ingested.measurements;
    assert_eq!(set.mimic.keys().collect::<Vec<_>>(), ["grip_2"]);
    let training = set.training.as_ref().unwrap();
    assert_eq!(training.poses.len(), 8);
    for p in &training.poses {
        let mut excited: Vec<&String> = p.dynamic.keys().collect();
        excited.sort();
        assert_eq!(excited, ["elbow", "grip", "shoulder"]);
    }
    let structure = explore(&set, &ExploreConfig::default()).unwrap();
    assert!(structure.complete, "{:?}", structure.diagnostics);
    assert!(tree_is_exact(&robot, &structure));
    let mut aside = structure.unplaced_sus.clone();
    aside.sort();
    // The second finger's body (with the tip) is the larger, and a mirrored follower's body
    // moves as the leader's would: it stands for the leader's, and the first finger is set aside.
    assert_eq!(aside, ["finger_1_su1", "finger_1_su2"]);
    crate::common::logs_calibrate(&robot, (&set, &structure), &upright, &config, "gripper");
}
