//! Real robots' descriptions (URDF files of example-robot-data, which `cargo xtask test` fetches
//! into the directory `SKINCAL_ROBOT_DESCRIPTIONS` names): with 2 random SUs per link, ±0.01 g
//! noise and 20 training poses within each joint's real limits, the whole pipeline finds the tree
//! the description has, every limb converges, and the calibrated body predicts 20 fresh noise-free
//! poses of the description within 0.05 m/s² RMS, static and dynamic.

use std::path::PathBuf;

use skincal::estimate::body::calibrate_body;
use skincal::estimate::ml::MlConfig;
use skincal::explore::{explore, ExploreConfig, Structure};
use skincal::io::{load_robot, SuPlacement};
use skincal::measurements::MeasurementSet;
use skincal::model::Robot;
use skincal::predict::validate;
use skincal::sim::{simulate, Imperfections, SimulationConfig};

pub(crate) fn description(path: &str) -> PathBuf {
    let dir = std::env::var_os("SKINCAL_ROBOT_DESCRIPTIONS").unwrap_or_else(|| {
        panic!(
            "SKINCAL_ROBOT_DESCRIPTIONS is not set: run the tests with `cargo xtask test`, which \
             fetches the robot descriptions (tests/python/robot-descriptions.txt) and sets it"
        )
    });
    let file = PathBuf::from(dir).join(path);
    assert!(file.exists(), "{} is missing", file.display());
    file
}

/// Whether every SU of the structure sits after exactly the DoFs that move it in `truth`, and
/// only SUs and DoFs that mimic joints make ambiguous are left out: SUs behind a mimic DoF or a
/// DoF with mimic followers (whose bodies are told apart and set aside), and those DoFs.
pub(crate) fn tree_is_exact(truth: &Robot, s: &Structure) -> bool {
    let m = &truth.model;
    s.unplaced_sus.iter().all(|su| {
        let u = m.su_index(su).unwrap();
        m.chain_to(m.sus()[u].segment)
            .into_iter()
            .any(|d| coupled(truth, d))
    }) && placed_sus_are_exact(truth, s)
}

/// Whether DoF `d` is a mimic DoF or has mimic followers.
fn coupled(truth: &Robot, d: usize) -> bool {
    truth.model.is_follower(d) || !truth.model.followers_of(d).is_empty()
}

/// Whether every SU the structure places sits after exactly the DoFs that move it in `truth` (a
/// mimic DoF stands for its leader, which moves it).
fn placed_sus_are_exact(truth: &Robot, s: &Structure) -> bool {
    let m = &truth.model;
    s.unplaced_dofs
        .iter()
        .all(|d| m.dof_index(d).is_some_and(|d| coupled(truth, d)))
        && s.segments.iter().all(|segment| {
            let mut found: Vec<String> = Vec::new();
            let mut current = segment;
            while let Some(j) = &current.parent_joint {
                let joint = s.joint(j).unwrap();
                found.extend(joint.dofs.iter().cloned());
                current = s.segment(&joint.parent).unwrap();
            }
            found.sort();
            segment.sus.iter().all(|su| {
                let u = m.su_index(su).unwrap();
                let mut truth: Vec<String> = m
                    .chain_to(m.sus()[u].segment)
                    .into_iter()
                    .map(|d| {
                        m.dofs()[m.dofs()[d].mimic.map_or(d, |x| x.leader)]
                            .name
                            .clone()
                    })
                    .collect();
                truth.sort();
                truth.dedup();
                truth == found
            })
        })
}

/// The description in `file` with 2 random SUs on every link (placed by `seed`).
pub(crate) fn with_two_sus_per_link(file: &std::path::Path, seed: u64) -> Robot {
    load_robot(
        file.to_str().unwrap(),
        SuPlacement {
            per_link: Some(2),
            seed,
        },
    )
    .unwrap()
}

/// The description in `file` with 2 random SUs per link (`seed`), its simulated experiments
/// (±0.01 g, 20 poses) explored, and 20 fresh noise-free poses of it (seed + 1000).
pub(crate) fn simulated(
    file: &std::path::Path,
    seed: u64,
) -> (Robot, MeasurementSet, Structure, MeasurementSet) {
    let robot = with_two_sus_per_link(file, seed);
    let set = simulate(
        &robot,
        &SimulationConfig {
            seed,
            ..SimulationConfig::default()
        },
    )
    .unwrap()
    .measurements;
    let structure = explore(&set, &ExploreConfig::default()).unwrap();
    let held_out = simulate(
        &robot,
        &SimulationConfig {
            seed: seed + 1000,
            structure: false,
            imperfections: Imperfections::none(),
            ..SimulationConfig::default()
        },
    )
    .unwrap()
    .measurements;
    (robot, set, structure, held_out)
}

/// The two-sided 99.9 % band of χ² with `k` degrees of freedom (Wilson–Hilferty).
fn chi2_band(k: usize) -> (f64, f64) {
    let k = k.max(1) as f64;
    let a = 2.0 / (9.0 * k);
    let at = |z: f64| k * (1.0 - a + z * a.sqrt()).powi(3);
    (at(-3.29), at(3.29))
}

fn calibrates(path: &str, seeds: &[u64]) {
    let file = description(path);
    for &seed in seeds {
        let (robot, set, structure, held_out) = simulated(&file, seed);
        assert!(
            tree_is_exact(&robot, &structure),
            "{path}, seed {seed}: {:?}",
            structure.diagnostics
        );
        let model = calibrate_body(&set, Some(&structure), &MlConfig::default(), None).unwrap();
        for limb in &model.limbs {
            assert!(
                limb.estimate.converged,
                "{path}, seed {seed}: limb ({}) at {:.2} σ; tried {:?}",
                limb.dofs.join(" "),
                limb.estimate.residual_ratio,
                limb.estimate.retries
            );
        }
        let check = validate(&model, &held_out, "held-out").unwrap();
        assert!(
            check.static_rms <= 0.05 && check.dynamic_rms <= 0.05,
            "{path}, seed {seed}: held-out static {:.4}, dynamic {:.4} m/s²",
            check.static_rms,
            check.dynamic_rms
        );
        // The robot's own URDF checked against the calibration: its joints are where the
        // calibration puts them, within the uncertainty it reports — χ² of the joints of limbs on
        // the reference segment within its two-sided 99.9 % band for its degrees of freedom (at
        // 3σ about one joint in 370 is flagged by chance). A limb on another limb's segment is
        // fitted with that limb's path and gravity held, whose uncertainty its covariance does
        // not carry (the check says so at its base): its joints' χ² is printed, not bounded.
        let urdf = std::fs::read_to_string(&file).unwrap();
        let urdf_check = skincal::align::align(&model, &urdf).unwrap().check;
        let on_reference: std::collections::BTreeSet<&str> = model
            .limbs
            .iter()
            .filter(|l| l.parent.is_none())
            .flat_map(|l| l.dofs.iter().map(String::as_str))
            .collect();
        let (mut chi2, mut components, mut sub_chi2, mut sub_components) = (0.0, 0, 0.0, 0);
        for j in urdf_check.joints.iter().filter(|j| j.components > 0) {
            if on_reference.contains(j.dof.as_str()) {
                chi2 += j.chi2;
                components += j.components;
            } else {
                sub_chi2 += j.chi2;
                sub_components += j.components;
            }
        }
        eprintln!(
            "{path}, seed {seed}: χ²/dof {:.2} over {components} components of limbs on the reference, {:.2} over {sub_components} of limbs on limbs; disagree {:?}",
            chi2 / components.max(1) as f64,
            sub_chi2 / sub_components.max(1) as f64,
            urdf_check.disagree
        );
        // Every calibrated DoF is compared or starts a limb.
        for j in &urdf_check.joints {
            assert!(
                j.verdict != skincal::align::JointVerdict::NotCompared,
                "{path}: {} {}",
                j.dof,
                j.note
            );
        }
        let (low, high) = chi2_band(components);
        assert!(
            (low..high).contains(&chi2),
            "{path}, seed {seed}: χ² {chi2:.1} over {components} components, outside {low:.1}–{high:.1}"
        );
        let disagree_on_reference = urdf_check
            .disagree
            .iter()
            .filter(|d| on_reference.contains(d.as_str()))
            .count();
        assert!(disagree_on_reference <= 1, "{:?}", urdf_check.disagree);
    }
}

/// Each DoF's held-out dynamic RMS error of `model` on `held_out`, and the median DoF's.
fn dof_errors(
    model: &skincal::estimate::body::BodyModel,
    held_out: &MeasurementSet,
) -> (std::collections::BTreeMap<String, f64>, f64) {
    let errors: std::collections::BTreeMap<String, f64> = validate(model, held_out, "held-out")
        .unwrap()
        .dofs
        .into_iter()
        .map(|d| (d.dof, d.dynamic_rms))
        .collect();
    let mut sorted: Vec<f64> = errors.values().copied().collect();
    sorted.sort_by(f64::total_cmp);
    let median = sorted[sorted.len() / 2];
    (errors, median)
}

#[test]
fn talos_humanoid() {
    calibrates("talos_data/robots/talos_reduced.urdf", &[1, 2]);
}

#[test]
fn a_trunk_is_fitted_from_every_su_it_moves() {
    // TALOS's trunk (2 DoFs) carries 4 SUs of its own, and both arms and the head on it. Fitted
    // from its own SUs with the arms and the head held on its estimate, torso_2_joint predicted
    // its held-out dynamic readings 0.056 (seed 1) and 0.035 m/s² (seed 2) off, 3–5× the median
    // DoF; fitted with the limbs on it, within 0.03 m/s² and 1.5× the median.
    let file = description("talos_data/robots/talos_reduced.urdf");
    for seed in [1, 2] {
        let (_, set, structure, held_out) = simulated(&file, seed);
        let model = calibrate_body(&set, Some(&structure), &MlConfig::default(), None).unwrap();
        let (errors, median) = dof_errors(&model, &held_out);
        for dof in ["torso_1_joint", "torso_2_joint"] {
            let e = errors[dof];
            eprintln!("seed {seed}: {dof} {e:.4} m/s², median DoF {median:.4}");
            assert!(
                e <= 0.03 && e <= 1.5 * median,
                "seed {seed}: {dof} {e:.4} m/s², median DoF {median:.4}"
            );
        }
        let trunk = model
            .limbs
            .iter()
            .find(|l| l.dofs.iter().any(|d| d == "torso_1_joint"))
            .unwrap();
        assert!(
            trunk
                .estimate
                .retries
                .iter()
                .any(|r| r.contains("limbs of its tree in one problem")),
            "{:?}",
            trunk.estimate.retries
        );
    }
}

#[test]
fn romeo_humanoid_whose_trunk_alone_leaves_a_mirror_open() {
    // Seed 1: the trunk's yaw limb fits its own two SUs equally well upside down; the arms and
    // neck tell, and the trunk is fitted again from them.
    calibrates("romeo_description/urdf/romeo.urdf", &[1, 2]);
}

#[test]
fn unitree_g1_humanoid() {
    calibrates("g1_description/urdf/g1_29dof_rev_1_0.urdf", &[1, 2]);
}

#[test]
fn simple_humanoid() {
    calibrates(
        "simple_humanoid_description/urdf/simple_humanoid.urdf",
        &[1, 2],
    );
}

#[test]
fn alex_humanoid() {
    calibrates("alex_description/urdf/alex_nub_hands.urdf", &[1, 2]);
}

#[test]
fn arms_with_parallel_and_intersecting_axes() {
    for arm in [
        "ur_description/urdf/ur5_robot.urdf",
        "kinova_description/robots/kinova.urdf",
        "xarm_description/urdf/xarm7.urdf",
        "z1_description/urdf/z1.urdf",
        "so_arm_description/urdf/so101.urdf",
    ] {
        calibrates(arm, &[1, 2]);
    }
}

#[test]
fn glitches_set_aside_only_the_sus_they_hit_and_few_of_them() {
    // Arms with 2 SUs per link and 1 % of the readings replaced by random vectors of 0.2–1.5 g:
    // an entry a glitch hid is decided by the tree's own constraints before any vote (an SU on
    // the first link read as moved by the fourth joint would hang that joint from two places).
    // Which readings a glitch hit: those that differ from the same seed's set without glitches.
    // The Panda as shipped has prismatic fingers; here they are held (fixed), their links skinned.
    let dir = tempfile::tempdir().unwrap();
    let panda = dir.path().join("panda.urdf");
    let text = std::fs::read_to_string(description("panda_description/urdf/panda.urdf")).unwrap();
    std::fs::write(&panda, text.replace("type=\"prismatic\"", "type=\"fixed\"")).unwrap();
    for file in [
        description("ur_description/urdf/ur5_robot.urdf"),
        description("kinova_description/robots/kinova.urdf"),
        panda,
    ] {
        let path = file.file_name().unwrap().to_string_lossy().to_string();
        let (mut set_aside, mut runs, mut misplaced) = (0, 0, Vec::new());
        for seed in 1..=25 {
            let robot = with_two_sus_per_link(&file, seed);
            let config = |glitches| SimulationConfig {
                seed,
                poses: 2,
                imperfections: Imperfections {
                    glitches,
                    ..Imperfections::default()
                },
                ..SimulationConfig::default()
            };
            let set = simulate(&robot, &config(0.01)).unwrap().measurements;
            let clean = simulate(&robot, &config(0.0)).unwrap().measurements;
            let (a, b) = (
                set.structure.as_ref().unwrap(),
                clean.structure.as_ref().unwrap(),
            );
            let hit: Vec<&String> = (0..set.sus.len())
                .filter(|&u| {
                    a.orientations.iter().zip(&b.orientations).any(|(x, y)| {
                        x.rest[u] != y.rest[u]
                            || x.moves
                                .iter()
                                .zip(&y.moves)
                                .any(|(m, n)| m.readings[u] != n.readings[u])
                    })
                })
                .map(|u| &set.sus[u])
                .collect();
            let s = explore(&set, &ExploreConfig::default()).unwrap();
            if !placed_sus_are_exact(&robot, &s) {
                misplaced.push(seed);
            }
            for su in &s.unplaced_sus {
                assert!(
                    hit.contains(&su),
                    "{path}, seed {seed}: {su} set aside, no glitch hit it"
                );
            }
            set_aside += s.unplaced_sus.len();
            runs += 1;
        }
        // Without the tree's constraints first, the Panda lost 0.95 SUs a run.
        eprintln!(
            "{path}: {set_aside} SUs set aside in {runs} runs; a wrong tree on seeds {misplaced:?}"
        );
        // The Panda's seed 2: a glitch hid link4_su1's rest reading in the tilted orientation,
        // where joint 5 turns about gravity, and the rebuilt rest hangs it after joint 5.
        let known: &[u64] = if path == "panda.urdf" { &[2] } else { &[] };
        assert_eq!(misplaced, known, "{path}");
        assert!(
            set_aside * 4 <= runs * 3,
            "{path}: {set_aside} SUs set aside in {runs} runs"
        );
    }
}

#[test]
fn a_humanoids_legs_predict_their_dynamic_readings_at_the_cramer_rao_bound() {
    // The first DoFs of a humanoid's legs predict their held-out dynamic readings worse than the
    // median DoF (on G1, hip pitch 1.2–2.0× the median over seeds 1–8): each is read by the
    // SUs of one leg alone, where an arm's DoFs are fitted with their trunk and the other limbs
    // on it. That is the data's, not the estimator's: per DoF of a limb on the reference
    // segment, the RMS error over 8 seeds is its Cramér–Rao bound (the bound of that limb's
    // readings alone, which a trunk fitted with the limbs on it beats), and the hip's bound
    // alone is 1.4–1.8× the median DoF's error.
    use skincal::estimate::limb::{limb_chains, LimbData};
    use skincal::estimate::ml::{dynamic_reading_bounds, IntrinsicsModel};
    let sd = 0.01 * 9.81 / 3f64.sqrt();
    for path in [
        "g1_description/urdf/g1_29dof_rev_1_0.urdf",
        "talos_data/robots/talos_reduced.urdf",
    ] {
        let file = description(path);
        let mut sums: std::collections::BTreeMap<String, (f64, f64, bool)> = Default::default();
        for seed in 1..=8u64 {
            let (robot, set, structure, held_out) = simulated(&file, seed);
            let model = calibrate_body(&set, Some(&structure), &MlConfig::default(), None).unwrap();
            let (errors, median) = dof_errors(&model, &held_out);
            let mut worst = (String::new(), 0.0);
            for chain in limb_chains(&structure).unwrap() {
                let alone = !model
                    .limbs
                    .iter()
                    .any(|l| l.parent.as_deref() == Some(chain.name.as_str()));
                let bounds = dynamic_reading_bounds(
                    &robot,
                    &skincal::model::sensor::gravity_upright(),
                    &LimbData::new(&set, &chain).unwrap(),
                    &LimbData::new(&held_out, &chain).unwrap(),
                    sd,
                    IntrinsicsModel::None,
                );
                for (dof, b) in chain.dofs().into_iter().zip(bounds.unwrap_or_default()) {
                    let e = errors[&dof];
                    if alone && b / median > worst.1 {
                        worst = (dof.clone(), b / median);
                    }
                    let s = sums.entry(dof).or_insert((0.0, 0.0, alone));
                    s.0 += e * e;
                    s.1 += b * b;
                }
            }
            eprintln!(
                "{path}, seed {seed}: median DoF {median:.4} m/s²; a leg's worst bound {:.4} ({}), {:.2}× it",
                worst.1 * median,
                worst.0,
                worst.1
            );
        }
        let (mut legs, mut leg_bounds) = (0.0, 0.0);
        for (dof, (e, b, alone)) in &sums {
            let ratio = (e / b).sqrt();
            eprintln!("{path}: {dof} {ratio:.2}× its bound over 8 seeds");
            assert!(ratio < 1.3, "{path}: {dof} {ratio:.2}× its bound");
            if *alone {
                legs += e;
                leg_bounds += b;
            }
        }
        let ratio = (legs / leg_bounds).sqrt();
        assert!(
            (0.85..1.15).contains(&ratio),
            "{path}: legs {ratio:.2}× their bound"
        );
    }
}
