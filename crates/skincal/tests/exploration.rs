//! Structural exploration against the simulator's ground truth, hand-built activity matrices and
//! one constructed case per diagnostic.

use std::collections::{BTreeMap, BTreeSet};

use proptest::prelude::*;
use skincal::explore::{
    explore, structure_from_activity, ActivityMatrix, DiagnosticKind, ExploreConfig, Severity,
    Structure,
};
use skincal::model::{presets, Robot};
use skincal::sim::{random_tree, simulate, RandomTreeConfig, SimulationConfig};

type Names = BTreeSet<String>;

/// The tree the model really has, as (segments by SU set, joints by DoF set with parent and child
/// SU sets). A joint is the run of DoFs between two segments that carry SUs.
fn true_tree(robot: &Robot) -> (BTreeSet<Names>, BTreeMap<Names, (Names, Names)>) {
    let m = &robot.model;
    let sus_of = |s: usize| -> Names {
        m.sus()
            .iter()
            .filter(|u| u.segment == s)
            .map(|u| u.name.clone())
            .collect()
    };
    let segments: BTreeSet<Names> = (0..m.segments().len())
        .map(sus_of)
        .filter(|s| !s.is_empty())
        .collect();
    let mut joints = BTreeMap::new();
    for s in 1..m.segments().len() {
        if sus_of(s).is_empty() {
            continue;
        }
        let mut dofs = Names::new();
        let mut cur = s;
        loop {
            let d = m.segments()[cur].parent_dof.unwrap();
            dofs.insert(m.dofs()[d].name.clone());
            cur = m.dofs()[d].parent;
            if !sus_of(cur).is_empty() || cur == 0 {
                break;
            }
        }
        joints.insert(dofs, (sus_of(cur), sus_of(s)));
    }
    (segments, joints)
}

/// The same view of an explored structure.
fn found_tree(s: &Structure) -> (BTreeSet<Names>, BTreeMap<Names, (Names, Names)>) {
    let sus = |id: &str| -> Names { s.segment(id).unwrap().sus.iter().cloned().collect() };
    let segments = s
        .segments
        .iter()
        .map(|x| x.sus.iter().cloned().collect::<Names>())
        .filter(|x| !x.is_empty())
        .collect();
    let joints = s
        .joints
        .iter()
        .map(|j| {
            (
                j.dofs.iter().cloned().collect(),
                (sus(&j.parent), sus(&j.child)),
            )
        })
        .collect();
    (segments, joints)
}

fn structure_only() -> SimulationConfig {
    SimulationConfig {
        training: false,
        ..SimulationConfig::default()
    }
}

#[test]
fn humanoid_tree_is_exact_with_multi_dof_shoulders_and_hips() {
    let robot = presets::find("humanoid").unwrap().robot().unwrap();
    let sim = simulate(&robot, &structure_only()).unwrap();
    let s = explore(&sim.measurements, &ExploreConfig::default()).unwrap();
    assert!(s.complete, "{:?}", s.diagnostics);
    assert_eq!(found_tree(&s), true_tree(&robot));
    let joint = |dof: &str| {
        s.joints
            .iter()
            .find(|j| j.dofs.contains(&dof.to_string()))
            .unwrap()
            .dofs
            .clone()
    };
    assert_eq!(
        joint("l_shoulder_roll"),
        ["l_shoulder_pitch", "l_shoulder_roll", "l_shoulder_yaw"]
    );
    assert_eq!(
        joint("r_hip_pitch"),
        ["r_hip_yaw", "r_hip_roll", "r_hip_pitch"]
    );
    assert_eq!(joint("neck_pitch"), ["neck_yaw", "neck_pitch"]);
    assert_eq!(s.joints.len(), 13);
    assert_eq!(s.end_effectors.len(), 5);
    assert!(s.branching.is_empty());
    assert_eq!(s.limbs.len(), 5);
    let arm = s
        .limbs
        .iter()
        .find(|l| l.dofs.contains(&"l_elbow".to_string()))
        .unwrap();
    assert_eq!(
        arm.dofs,
        [
            "l_shoulder_pitch",
            "l_shoulder_roll",
            "l_shoulder_yaw",
            "l_elbow",
            "l_wrist_yaw",
            "l_wrist_pitch"
        ]
    );
    assert_eq!(arm.sus.last().unwrap(), "l_hand_back");
    // Strictly lower triangular with ones on the secondary diagonal.
    for (i, row) in s.matrix.entries.iter().enumerate() {
        for (j, &e) in row.iter().enumerate() {
            if j + 1 > i {
                assert!(!e, "entry ({i}, {j}) above the secondary diagonal");
            }
            if j + 1 == i {
                assert!(e, "secondary diagonal ({i}, {j})");
            }
        }
    }
}

#[test]
fn paper_arm_is_one_limb_even_though_its_base_has_no_su() {
    let robot = presets::find("paper-7dof").unwrap().robot().unwrap();
    let s = explore(
        &simulate(&robot, &structure_only()).unwrap().measurements,
        &ExploreConfig::default(),
    )
    .unwrap();
    assert!(s.complete);
    assert_eq!(found_tree(&s), true_tree(&robot));
    assert_eq!(s.limbs.len(), 1);
    assert_eq!(
        s.limbs[0].dofs,
        ["dof1", "dof2", "dof3", "dof4", "dof5", "dof6", "dof7"]
    );
    assert!(s.segments[0].without_su);
    assert!(s
        .diagnostics
        .iter()
        .any(|d| d.kind == DiagnosticKind::NoStaticSegment && d.dofs == ["dof1"]));
}

#[test]
fn without_the_tilted_orientation_vertical_axes_are_reported_not_hidden() {
    let robot = presets::find("paper-7dof").unwrap().robot().unwrap();
    let config = SimulationConfig {
        tilted_orientation: false,
        ..structure_only()
    };
    let s = explore(
        &simulate(&robot, &config).unwrap().measurements,
        &ExploreConfig::default(),
    )
    .unwrap();
    assert!(!s.complete);
    // At the rest pose dof1, dof5 and dof7 of the paper's arm point straight up.
    let flagged: Vec<&str> = s
        .diagnostics
        .iter()
        .filter(|d| d.kind == DiagnosticKind::DofMovesNoSu)
        .map(|d| d.dofs[0].as_str())
        .collect();
    assert_eq!(flagged, ["dof1", "dof5", "dof7"]);
    let message = &s
        .diagnostics
        .iter()
        .find(|d| d.kind == DiagnosticKind::DofMovesNoSu)
        .unwrap()
        .message;
    assert!(
        message.contains("vertical") && message.contains("tilted"),
        "{message}"
    );
}

/// An activity matrix from 0/1 rows (1 → a change of 1 g, 0 → none).
fn matrix(sus: &[&str], dofs: &[&str], rows: &[&[u8]]) -> ActivityMatrix {
    ActivityMatrix {
        upright: Vec::new(),
        sus: sus.iter().map(|s| s.to_string()).collect(),
        dofs: dofs.iter().map(|s| s.to_string()).collect(),
        change: rows
            .iter()
            .map(|r| r.iter().map(|&x| f64::from(x) * 9.81).collect())
            .collect(),
        explored: vec![true; dofs.len()],
        prismatic: Vec::new(),
        threshold: 0.05 * 9.81,
        uncertainty_factor: 2.0,
        orientations: 2,
        rest_turn: vec![Some(std::f64::consts::FRAC_PI_2); sus.len()],
        misread: Vec::new(),
        inferred: Vec::new(),
        undecided: Vec::new(),
        leader_of: Vec::new(),
        mimic_driven: Vec::new(),
        broken: Vec::new(),
    }
}

fn kinds(s: &Structure) -> Vec<DiagnosticKind> {
    s.diagnostics
        .iter()
        .filter(|d| d.severity > Severity::Info)
        .map(|d| d.kind)
        .collect()
}

#[test]
fn hand_built_matrix_of_a_torso_head_arm_and_two_fingered_hand() {
    // As in the paper's description: torso (reference), a 2-DoF neck and head, a 3-DoF shoulder,
    // upper arm, elbow, forearm, wrist, palm, and two one-joint fingers on the palm. SUs and DoFs are
    // listed out of order on purpose.
    let dofs = [
        "elbow",
        "neck_yaw",
        "finger_a",
        "sh_1",
        "wrist",
        "neck_pitch",
        "sh_2",
        "finger_b",
        "sh_3",
    ];
    let sus = [
        "palm", "torso1", "head", "tip_a", "upper", "torso2", "fore", "tip_b", "upper2",
    ];
    //                           elb ny fa s1 wr np s2 fb s3
    let rows: [&[u8]; 9] = [
        &[1, 0, 0, 1, 1, 0, 1, 0, 1], // palm
        &[0, 0, 0, 0, 0, 0, 0, 0, 0], // torso1
        &[0, 1, 0, 0, 0, 1, 0, 0, 0], // head
        &[1, 0, 1, 1, 1, 0, 1, 0, 1], // tip_a
        &[0, 0, 0, 1, 0, 0, 1, 0, 1], // upper
        &[0, 0, 0, 0, 0, 0, 0, 0, 0], // torso2
        &[1, 0, 0, 1, 0, 0, 1, 0, 1], // fore
        &[1, 0, 0, 1, 1, 0, 1, 1, 1], // tip_b
        &[0, 0, 0, 1, 0, 0, 1, 0, 1], // upper2
    ];
    let s = structure_from_activity(&matrix(&sus, &dofs, &rows), &ExploreConfig::default());
    assert!(s.complete && kinds(&s).is_empty(), "{:?}", s.diagnostics);
    let ids = |names: &[&str]| -> String {
        s.segments
            .iter()
            .find(|x| x.sus.iter().map(String::as_str).eq(names.iter().copied()))
            .unwrap()
            .id
            .clone()
    };
    let (torso, head, upper, fore, palm, tip_a, tip_b) = (
        ids(&["torso1", "torso2"]),
        ids(&["head"]),
        ids(&["upper", "upper2"]),
        ids(&["fore"]),
        ids(&["palm"]),
        ids(&["tip_a"]),
        ids(&["tip_b"]),
    );
    assert_eq!(torso, "S0");
    assert_eq!(s.segments.len(), 7);
    let joint = |child: &str| s.joints.iter().find(|j| j.child == child).unwrap();
    assert_eq!(
        (joint(&head).parent.as_str(), joint(&head).dofs.clone()),
        (
            torso.as_str(),
            vec!["neck_yaw".to_string(), "neck_pitch".into()]
        )
    );
    assert_eq!(joint(&upper).dofs, ["sh_1", "sh_2", "sh_3"]);
    assert_eq!(joint(&fore).parent, upper);
    assert_eq!(joint(&palm).parent, fore);
    assert_eq!(joint(&tip_a).parent, palm);
    assert_eq!(joint(&tip_b).dofs, ["finger_b"]);
    let mut ends = s.end_effectors.clone();
    ends.sort();
    let mut expected = vec![head.clone(), tip_a.clone(), tip_b.clone()];
    expected.sort();
    assert_eq!(ends, expected);
    assert_eq!(s.branching, std::slice::from_ref(&palm));
    let limbs: BTreeSet<(String, String)> = s
        .limbs
        .iter()
        .map(|l| (l.from.clone(), l.to.clone()))
        .collect();
    assert_eq!(
        limbs,
        BTreeSet::from([
            (torso.clone(), head),
            (torso, palm.clone()),
            (palm.clone(), tip_a),
            (palm, tip_b)
        ])
    );
}

#[test]
fn a_dof_that_was_never_moved_is_reported() {
    let mut a = matrix(&["base", "tip"], &["j1", "j2"], &[&[0, 0], &[1, 0]]);
    a.explored[1] = false;
    let s = structure_from_activity(&a, &ExploreConfig::default());
    assert_eq!(kinds(&s), [DiagnosticKind::DofNotExplored]);
    assert_eq!(s.unplaced_dofs, ["j2"]);
    assert_eq!(s.joints.len(), 1);
}

#[test]
fn a_dof_that_moves_no_su_is_reported_with_its_likely_cause() {
    let a = matrix(&["base", "tip"], &["j1", "j2"], &[&[0, 0], &[1, 0]]);
    let s = structure_from_activity(&a, &ExploreConfig::default());
    assert_eq!(kinds(&s), [DiagnosticKind::DofMovesNoSu]);
    assert!(s.diagnostics[0].message.contains("carries no SU"));
    assert_eq!(s.diagnostics[0].dofs, ["j2"]);
    // Seen in two base orientations, it is a chain's end without skin: left out, and the rest
    // is a consistent tree.
    assert_eq!(s.diagnostics[0].severity, Severity::Warning);
    assert_eq!(s.unplaced_dofs, ["j2"]);
    assert!(s.complete);
    assert_eq!(s.limbs.len(), 1);
}

#[test]
fn several_static_groups_are_told_apart_by_how_they_turn_with_the_base() {
    let mut a = matrix(
        &["base1", "base2", "loose", "tip"],
        &["j1"],
        &[&[0], &[0], &[0], &[1]],
    );
    a.rest_turn[2] = Some(0.0);
    let s = structure_from_activity(&a, &ExploreConfig::default());
    assert_eq!(kinds(&s), [DiagnosticKind::SeveralStaticGroups]);
    assert_eq!(s.diagnostics[0].sus, ["loose"]);
    assert_eq!(s.unplaced_sus, ["loose"]);
    assert_eq!(s.segments[0].sus, ["base1", "base2"]);
}

#[test]
fn a_closed_loop_cannot_be_sorted_and_the_rest_of_the_tree_survives() {
    // Segment `c` is moved by the DoFs of two separate branches.
    let a = matrix(
        &["base", "a", "b", "c"],
        &["j1", "j2"],
        &[&[0, 0], &[1, 0], &[0, 1], &[1, 1]],
    );
    let s = structure_from_activity(&a, &ExploreConfig::default());
    assert_eq!(kinds(&s), [DiagnosticKind::Unsortable]);
    assert_eq!(s.diagnostics[0].sus, ["c"]);
    assert!(s.diagnostics[0].message.contains("closed kinematic loop"));
    assert_eq!(s.segments.len(), 3);
    assert_eq!(s.joints.len(), 2);
}

#[test]
fn a_branching_segment_without_su_is_assumed_and_reported() {
    // j1 moves a segment without SU from which j2 and j3 branch off.
    let a = matrix(
        &["base", "left", "right"],
        &["j1", "j2", "j3"],
        &[&[0, 0, 0], &[1, 1, 0], &[1, 0, 1]],
    );
    let s = structure_from_activity(&a, &ExploreConfig::default());
    assert_eq!(kinds(&s), [DiagnosticKind::SegmentWithoutSu]);
    assert!(s.complete);
    let hidden = s
        .segments
        .iter()
        .find(|x| x.without_su && x.id != "S0")
        .unwrap();
    assert_eq!(
        s.joints.iter().find(|j| j.child == hidden.id).unwrap().dofs,
        ["j1"]
    );
    assert_eq!(s.joints.iter().filter(|j| j.parent == hidden.id).count(), 2);
    assert_eq!(s.branching, std::slice::from_ref(&hidden.id));
}

#[test]
fn an_uncertain_entry_that_breaks_the_tree_comes_with_the_flip_that_mends_it() {
    // `odd` sits on the tip segment, but its reading changed by only 0.04 g when j1 moved.
    let mut a = matrix(
        &["base", "mid", "tip", "odd"],
        &["j1", "j2"],
        &[&[0, 0], &[1, 0], &[1, 1], &[0, 1]],
    );
    a.change[3][0] = 0.04 * 9.81;
    let s = structure_from_activity(&a, &ExploreConfig::default());
    assert_eq!(s.unplaced_sus, ["odd"]);
    let flip = s
        .diagnostics
        .iter()
        .find(|d| d.kind == DiagnosticKind::UncertainEntry)
        .expect("flip suggested");
    assert_eq!(
        (flip.sus.as_slice(), flip.dofs.as_slice()),
        (&["odd".to_string()][..], &["j1".to_string()][..])
    );
    let tip = s.segments.iter().find(|x| x.sus == ["tip"]).unwrap();
    assert!(
        flip.message.contains(&tip.id) && flip.message.contains("0.040 g"),
        "{}",
        flip.message
    );
    assert!(s
        .uncertain
        .iter()
        .any(|u| u.su == "odd" && u.dof == "j1" && !u.active));
}

#[test]
fn identical_columns_form_a_multi_dof_joint_in_input_order() {
    let a = matrix(
        &["base", "arm"],
        &["b", "a", "c"],
        &[&[0, 0, 0], &[1, 1, 1]],
    );
    let s = structure_from_activity(&a, &ExploreConfig::default());
    assert_eq!(s.joints[0].dofs, ["b", "a", "c"]);
    assert!(s
        .diagnostics
        .iter()
        .any(|d| d.kind == DiagnosticKind::MultiDofJoint && d.message.contains("input order")));
    assert!(s.complete);
}

/// An arm with the Denavit–Hartenberg geometry of a UR5 (published by its maker): shoulder lift,
/// elbow and first wrist joint turn about parallel axes.
const UR_LIKE_ARM: &str = r#"
name = "ur-like"
reference = "base"
[[dofs]]
name = "shoulder_pan"
child = "shoulder"
dh = { theta0 = 0.0, d = 0.0, a = 0.0, alpha = 0.0 }
[[dofs]]
name = "shoulder_lift"
child = "upper_arm"
dh = { theta0 = 0.0, d = 0.089159, a = 0.0, alpha = 1.5707963 }
[[dofs]]
name = "elbow"
child = "forearm"
dh = { theta0 = 0.0, d = 0.0, a = -0.425, alpha = 0.0 }
[[dofs]]
name = "wrist_1"
child = "wrist_1_link"
dh = { theta0 = 0.0, d = 0.0, a = -0.39225, alpha = 0.0 }
[[dofs]]
name = "wrist_2"
child = "wrist_2_link"
dh = { theta0 = 0.0, d = 0.10915, a = 0.0, alpha = 1.5707963 }
[[dofs]]
name = "wrist_3"
child = "wrist_3_link"
dh = { theta0 = 0.0, d = 0.09465, a = 0.0, alpha = -1.5707963 }
# Where the skin lies on each link; the test places SUs at random around these.
[[sus]]
name = "base_skin"
segment = "base"
xyz = [0.05, 0.0, 0.03]
[[sus]]
name = "shoulder_skin"
segment = "shoulder"
xyz = [0.0, 0.05, 0.0]
[[sus]]
name = "upper_arm_skin"
segment = "upper_arm"
xyz = [-0.21, 0.0, 0.12]
[[sus]]
name = "forearm_skin"
segment = "forearm"
xyz = [-0.2, 0.0, 0.02]
[[sus]]
name = "wrist_1_skin"
segment = "wrist_1_link"
xyz = [0.0, 0.04, 0.05]
[[sus]]
name = "wrist_2_skin"
segment = "wrist_2_link"
xyz = [0.0, 0.04, 0.05]
[[sus]]
name = "wrist_3_skin"
segment = "wrist_3_link"
xyz = [0.03, 0.0, 0.03]
"#;

#[test]
fn sus_that_parallel_axes_turn_alike_keep_their_rest_readings() {
    // Lift, elbow and wrist 1 move by the same angle about parallel axes, so every SU beyond the
    // wrist reads the same in all three moves, unlike its rest: a rest that looks like a glitch
    // by majority, but gravity turned by no more than the DoFs travelled.
    let arm = skincal::model::description::RobotFile::from_toml(UR_LIKE_ARM)
        .unwrap()
        .build()
        .unwrap();
    for seed in 1..=6 {
        let robot = skincal::model::description::with_random_sus(&arm, 2, seed).unwrap();
        let config = SimulationConfig {
            seed,
            ..structure_only()
        };
        let sim = simulate(&robot, &config).unwrap();
        let s = explore(&sim.measurements, &ExploreConfig::default()).unwrap();
        assert!(s.complete, "seed {seed}: {:?}", s.diagnostics);
        assert_eq!(found_tree(&s), true_tree(&robot), "seed {seed}");
        assert!(
            s.diagnostics
                .iter()
                .all(|d| d.severity != Severity::Warning),
            "seed {seed}: {:?}",
            s.diagnostics
        );
    }
}

#[test]
fn a_random_tree_of_the_largest_size_is_recovered_exactly() {
    let robot = random_tree(
        &RandomTreeConfig {
            dofs: 60,
            sus: 2000,
            ..RandomTreeConfig::default()
        },
        11,
    )
    .unwrap();
    let sim = simulate(
        &robot,
        &SimulationConfig {
            seed: 11,
            ..structure_only()
        },
    )
    .unwrap();
    let s = explore(&sim.measurements, &ExploreConfig::default()).unwrap();
    assert!(
        s.complete,
        "{:?}",
        s.diagnostics
            .iter()
            .filter(|d| d.severity == Severity::Error)
            .collect::<Vec<_>>()
    );
    assert_eq!(found_tree(&s), true_tree(&robot));
}

proptest! {
    #![proptest_config(ProptestConfig {
        cases: 24,
        rng_seed: proptest::test_runner::RngSeed::Fixed(3),
        failure_persistence: Some(Box::new(proptest::test_runner::FileFailurePersistence::Direct("tests/proptest-regressions/exploration.txt"))),
        ..ProptestConfig::default()
    })]

    #[test]
    fn simulate_then_explore_recovers_random_trees(dofs in 1usize..=60, sus_per_dof in 1usize..=33, max_joint_dofs in 1usize..=3, seed in 0u64..1000) {
        let sus = (dofs * sus_per_dof).clamp(dofs + 1, 2000);
        let robot = random_tree(&RandomTreeConfig { dofs, sus, max_joint_dofs, ..RandomTreeConfig::default() }, seed).unwrap();
        let sim = simulate(&robot, &SimulationConfig { seed, ..structure_only() }).unwrap();
        let s = explore(&sim.measurements, &ExploreConfig::default()).unwrap();
        prop_assert!(s.complete, "{:?}", s.diagnostics);
        prop_assert_eq!(found_tree(&s), true_tree(&robot));
    }
}
