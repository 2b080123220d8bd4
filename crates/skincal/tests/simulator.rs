//! The simulator, checked against laws that must hold and against its own settings.

use approx::assert_relative_eq;
use nalgebra::Vector3;
use skincal::model::description::RobotFile;
use skincal::model::presets;
use skincal::sim::{simulate, structure_move, Imperfections, SimulationConfig};

fn paper() -> skincal::model::Robot {
    presets::find("paper-7dof").unwrap().robot().unwrap()
}

fn norm(r: &[f64; 3]) -> f64 {
    Vector3::from(*r).norm()
}

#[test]
fn noise_free_static_readings_have_the_norm_of_gravity() {
    let config = SimulationConfig {
        imperfections: Imperfections::none(),
        ..SimulationConfig::default()
    };
    let sim = simulate(
        &presets::find("humanoid").unwrap().robot().unwrap(),
        &config,
    )
    .unwrap();
    let set = &sim.measurements;
    for o in &set.structure.as_ref().unwrap().orientations {
        for r in o
            .rest
            .iter()
            .chain(o.moves.iter().flat_map(|m| &m.readings))
        {
            assert_relative_eq!(norm(r), 9.81, epsilon = 1e-12);
        }
    }
    for p in &set.training.as_ref().unwrap().poses {
        for r in &p.static_readings {
            assert_relative_eq!(norm(r), 9.81, epsilon = 1e-12);
        }
    }
}

#[test]
fn noise_stays_within_its_bound_and_is_not_zero() {
    let robot = paper();
    let clean = simulate(
        &robot,
        &SimulationConfig {
            imperfections: Imperfections::none(),
            ..SimulationConfig::default()
        },
    )
    .unwrap();
    let noisy = simulate(&robot, &SimulationConfig::default()).unwrap();
    let (c, n) = (
        clean.measurements.training.unwrap(),
        noisy.measurements.training.unwrap(),
    );
    let mut largest: f64 = 0.0;
    for (pc, pn) in c.poses.iter().zip(&n.poses) {
        assert_eq!(pc.q, pn.q, "noise must not change the poses");
        let pairs = pc.static_readings.iter().zip(&pn.static_readings).chain(
            pc.dynamic
                .values()
                .flatten()
                .zip(pn.dynamic.values().flatten()),
        );
        for (a, b) in pairs {
            for k in 0..3 {
                largest = largest.max((a[k] - b[k]).abs());
            }
        }
    }
    assert!(largest <= 0.01 * 9.81 + 1e-12, "{largest}");
    assert!(
        largest > 0.08,
        "uniform ±0.0981 noise over 1000+ values should come close to its bound: {largest}"
    );
}

#[test]
fn the_same_seed_gives_the_same_set_and_another_seed_another() {
    let robot = paper();
    let a = simulate(
        &robot,
        &SimulationConfig {
            seed: 5,
            ..SimulationConfig::default()
        },
    )
    .unwrap();
    let b = simulate(
        &robot,
        &SimulationConfig {
            seed: 5,
            ..SimulationConfig::default()
        },
    )
    .unwrap();
    let c = simulate(
        &robot,
        &SimulationConfig {
            seed: 6,
            ..SimulationConfig::default()
        },
    )
    .unwrap();
    assert_eq!(a.measurements.to_json(), b.measurements.to_json());
    assert_ne!(a.measurements.to_json(), c.measurements.to_json());
}

#[test]
fn poses_respect_limits_and_range() {
    let robot = presets::find("humanoid").unwrap().robot().unwrap();
    let sim = simulate(
        &robot,
        &SimulationConfig {
            poses: 200,
            ..SimulationConfig::default()
        },
    )
    .unwrap();
    let dofs = robot.model.dofs();
    for p in &sim.measurements.training.unwrap().poses {
        for (q, d) in p.q.iter().zip(dofs) {
            assert!(
                *q >= d.limits.lower.max(-2.62) && *q <= d.limits.upper.min(2.62),
                "{} = {q}",
                d.name
            );
        }
    }
    for o in &sim.measurements.structure.unwrap().orientations {
        for (i, m) in o.moves.iter().enumerate() {
            assert_eq!(m.dof, dofs[i].name);
            let moved: Vec<usize> = (0..dofs.len())
                .filter(|&j| m.pose[j] != o.rest_pose[j])
                .collect();
            assert_eq!(moved, [i], "only {} moves", m.dof);
            assert!(m.pose[i] >= dofs[i].limits.lower && m.pose[i] <= dofs[i].limits.upper);
            assert_relative_eq!((m.pose[i] - o.rest_pose[i]).abs(), 0.3, epsilon = 1e-12);
        }
    }
}

#[test]
fn structure_moves_go_where_the_limits_allow() {
    let limits = |lower, upper| skincal::model::Limits {
        lower,
        upper,
        velocity: None,
        acceleration: None,
    };
    assert_eq!(structure_move(&limits(-1.0, 1.0), 0.0, 0.3), 0.3);
    assert_eq!(structure_move(&limits(-1.0, 0.1), 0.0, 0.3), -0.3);
    assert_eq!(structure_move(&limits(-0.1, 0.2), 0.0, 0.3), 0.2);
    assert_eq!(structure_move(&limits(-0.25, 0.2), 0.0, 0.3), -0.25);
}

#[test]
fn the_tilted_orientation_turns_gravity_into_the_reference_y_axis() {
    let sim = simulate(&paper(), &SimulationConfig::default()).unwrap();
    let g: Vec<[f64; 3]> = sim.truth.orientations.iter().map(|o| o.gravity).collect();
    assert_relative_eq!(
        Vector3::from(g[0]),
        Vector3::new(0.0, 0.0, -9.81),
        epsilon = 1e-12
    );
    assert_relative_eq!(
        Vector3::from(g[1]),
        Vector3::new(0.0, -9.81, 0.0),
        epsilon = 1e-12
    );
    // The first DoF's axis is vertical upright: moving it changes no reading beyond noise, but it
    // does once the base is tilted.
    let s = sim.measurements.structure.unwrap();
    let change = |o: usize, su: usize| {
        let (a, b) = (
            s.orientations[o].rest[su],
            s.orientations[o].moves[0].readings[su],
        );
        (0..3).map(|k| (a[k] - b[k]).abs()).fold(0.0, f64::max)
    };
    for su in 0..7 {
        assert!(
            change(0, su) < 2.0 * 0.0981 + 1e-9,
            "upright SU {su}: {}",
            change(0, su)
        );
        assert!(change(1, su) > 0.5, "tilted SU {su}: {}", change(1, su));
    }
}

#[test]
fn quantisation_and_saturation_act_like_the_bma150() {
    let config = SimulationConfig {
        imperfections: Imperfections::none().with_bma150(),
        ..SimulationConfig::default()
    };
    let sim = simulate(&paper(), &config).unwrap();
    let step = 4.0 * 9.81 / 1024.0;
    for p in &sim.measurements.training.unwrap().poses {
        for r in &p.static_readings {
            for &x in r {
                assert_relative_eq!((x / step).round() * step, x, epsilon = 1e-9);
                assert!(x.abs() <= 2.0 * 9.81);
            }
        }
    }
    // A large pattern drives readings into saturation: dynamic accelerations are clipped so that
    // static + dynamic stays within ±2 g.
    let strong = SimulationConfig {
        pattern: skincal::model::sensor::ExcitationPattern {
            amplitude: 5.0,
            frequency: 4.0,
        },
        ..config
    };
    let sim = simulate(&paper(), &strong).unwrap();
    for p in &sim.measurements.training.unwrap().poses {
        for (d, readings) in &p.dynamic {
            for (s, a) in p.static_readings.iter().zip(readings) {
                for k in 0..3 {
                    assert!(
                        (s[k] + a[k]).abs() <= 2.0 * 9.81 + step,
                        "{d}: {} + {}",
                        s[k],
                        a[k]
                    );
                }
            }
        }
    }
}

#[test]
fn a_constant_bias_shifts_static_readings_and_cancels_in_dynamic_ones() {
    let robot = paper();
    let base = SimulationConfig {
        imperfections: Imperfections::none(),
        ..SimulationConfig::default()
    };
    let biased = SimulationConfig {
        imperfections: Imperfections {
            bias: 0.05,
            ..Imperfections::none()
        },
        ..base.clone()
    };
    let (a, b) = (
        simulate(&robot, &base).unwrap(),
        simulate(&robot, &biased).unwrap(),
    );
    let bias: Vec<[f64; 3]> = b.truth.su_intrinsics.iter().map(|i| i.bias).collect();
    let (ta, tb) = (
        a.measurements.training.unwrap(),
        b.measurements.training.unwrap(),
    );
    for (pa, pb) in ta.poses.iter().zip(&tb.poses) {
        for ((sb, sa), b) in pb
            .static_readings
            .iter()
            .zip(&pa.static_readings)
            .zip(&bias)
        {
            let shift = Vector3::from(*sb) - Vector3::from(*sa);
            assert_relative_eq!(shift, Vector3::from(*b), epsilon = 1e-12);
        }
        for d in pa.dynamic.keys() {
            for (x, y) in pa.dynamic[d].iter().zip(&pb.dynamic[d]) {
                assert_relative_eq!(Vector3::from(*x), Vector3::from(*y), epsilon = 1e-12);
            }
        }
    }
    assert!(bias.iter().flatten().all(|b| b.abs() <= 0.05 * 9.81));
}

#[test]
fn the_truth_file_describes_the_simulated_robot() {
    let robot = paper();
    let sim = simulate(&robot, &SimulationConfig::default()).unwrap();
    let rebuilt = sim.truth.robot.build().unwrap();
    assert_eq!(rebuilt.parameters, robot.parameters);
    let text = serde_json::to_string(&sim.truth).unwrap();
    let back: skincal::sim::Truth = serde_json::from_str(&text).unwrap();
    assert_eq!(back, sim.truth);
    // The measurement set itself carries no geometry.
    assert!(!sim.measurements.to_json().contains("theta0"));
    let _ = RobotFile::from_robot(&rebuilt, None);
}

#[test]
fn bad_settings_are_refused() {
    let robot = paper();
    for config in [
        SimulationConfig {
            poses: 0,
            ..SimulationConfig::default()
        },
        SimulationConfig {
            pose_range: -1.0,
            ..SimulationConfig::default()
        },
        SimulationConfig {
            imperfections: Imperfections {
                uniform_noise: f64::NAN,
                ..Imperfections::default()
            },
            ..SimulationConfig::default()
        },
        SimulationConfig {
            pattern: skincal::model::sensor::ExcitationPattern {
                amplitude: 0.0,
                frequency: 2.0,
            },
            ..SimulationConfig::default()
        },
    ] {
        assert!(simulate(&robot, &config).is_err());
    }
}

#[test]
fn a_robot_too_large_to_simulate_is_refused_with_the_size_it_would_need() {
    // A 3000-link chain with one SU per link: 20 poses × 3001 excitations × 3001 SUs × 3 numbers
    // would take about 5 GB in memory and 12 GB as JSON; refused before anything is allocated.
    let n = 3000;
    let links: String = (0..=n).map(|i| format!("<link name=\"l{i}\"/>")).collect();
    let joints: String = (0..n)
        .map(|i| {
            format!(
                "<joint name=\"j{i}\" type=\"revolute\"><parent link=\"l{i}\"/><child link=\"l{}\"/>\
                 <origin xyz=\"0 0 0.01\"/><axis xyz=\"0 {} {}\"/>\
                 <limit lower=\"-1\" upper=\"1\" effort=\"1\" velocity=\"1\"/></joint>",
                i + 1,
                i % 2,
                (i + 1) % 2
            )
        })
        .collect();
    let text = format!("<robot name=\"long\">{links}{joints}</robot>");
    let robot = skincal::model::urdf::from_urdf(
        &text,
        skincal::model::urdf::UrdfSus::RandomPerLink {
            per_link: 1,
            seed: 1,
        },
    )
    .unwrap();
    let config = skincal::sim::SimulationConfig::default();
    let e = skincal::sim::simulate(&robot, &config)
        .unwrap_err()
        .to_string();
    // 3 × 3001 × (2 × 3001 + 20 × 3001) readings.
    assert!(
        e.contains(&format!("{} readings", 3 * 3001 * 22 * 3001)),
        "{e}"
    );
    assert!(e.contains("--poses"), "{e}");
}
