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

fn noise_free(seed: u64) -> SimulationConfig {
    SimulationConfig {
        seed,
        imperfections: Imperfections::none(),
        ..SimulationConfig::default()
    }
}

fn held_out(robot: &Robot, seed: u64) -> skincal::measurements::MeasurementSet {
    simulate(
        robot,
        &SimulationConfig {
            structure: false,
            ..noise_free(seed)
        },
    )
    .unwrap()
    .measurements
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
        assert!(limb.estimate.converged, "{} {}", limb.name, limb.estimate.residual_ratio);
    }
    let check = validate(&model, &held_out(&robot, 99), "held-out").unwrap();
    assert!(check.static_max < 1e-6, "static {:e}", check.static_max);
    assert!(check.dynamic_max < 1e-6, "dynamic {:e}", check.dynamic_max);
    eprintln!("{} {:e} {:e} {:?}", check.poses, check.static_max, check.dynamic_max, check.sus.iter().map(|s| s.dynamic_count).collect::<Vec<_>>()); for l in &model.limbs { eprintln!("{} {:?} {} {:?}", l.name, l.dofs, l.estimate.iterations, l.estimate.joint_orders.iter().map(|j| j.dofs.clone()).collect::<Vec<_>>()); }
    // Every SU of the robot is covered, the torso's included.
    assert_eq!(check.sus.len(), robot.model.sus().len());
    assert!(check.not_in_model.is_empty());
}
