//! The measurement set format: round trip, unknown fields kept, every invariant checked.

use skincal::measurements::{MeasurementError, MeasurementSet};
use skincal::model::presets;
use skincal::sim::{simulate, SimulationConfig};

fn small_set() -> MeasurementSet {
    let robot = presets::find("paper-7dof").unwrap().robot().unwrap();
    simulate(
        &robot,
        &SimulationConfig {
            poses: 3,
            ..SimulationConfig::default()
        },
    )
    .unwrap()
    .measurements
}

#[test]
fn a_set_survives_a_round_trip_through_json() {
    let set = small_set();
    let again = MeasurementSet::from_json(&set.to_json()).unwrap();
    assert_eq!(set, again);
}

#[test]
fn unknown_fields_stay_as_written() {
    let mut v: serde_json::Value = serde_json::from_str(&small_set().to_json()).unwrap();
    v["recorded_by"] = serde_json::json!({"lab": "x", "runs": [1, 2]});
    v["training"]["poses"][0]["static_std"] = serde_json::json!([[0.01, 0.01, 0.02]]);
    v["structure"]["orientations"][1]["moves"][2]["note"] = serde_json::json!("cable snag");
    let set = MeasurementSet::from_json(&v.to_string()).unwrap();
    let back: serde_json::Value = serde_json::from_str(&set.to_json()).unwrap();
    assert_eq!(back, v);
}

fn broken(edit: impl FnOnce(&mut serde_json::Value)) -> MeasurementError {
    let mut v: serde_json::Value = serde_json::from_str(&small_set().to_json()).unwrap();
    edit(&mut v);
    MeasurementSet::from_json(&v.to_string()).unwrap_err()
}

#[test]
fn every_broken_invariant_is_named() {
    let e = broken(|v| v["format"] = "something-else".into());
    assert!(matches!(e, MeasurementError::WrongFormat { .. }));
    let e = broken(|v| v["version"] = 7.into());
    assert!(matches!(
        e,
        MeasurementError::UnsupportedVersion { found: 7 }
    ));
    let e = broken(|v| {
        v["training"]["poses"][2]["q"]
            .as_array_mut()
            .unwrap()
            .pop()
            .map(|_| ())
            .unwrap()
    });
    assert_eq!(
        e.to_string(),
        "training.poses[2].q: has 6 entries, expected 7 (one angle per DoF)"
    );
    let e = broken(|v| v["structure"]["orientations"][0]["moves"][1]["dof"] = "dof9".into());
    assert_eq!(
        e.to_string(),
        "structure.orientations[0].moves[1].dof: unknown DoF `dof9` (not listed in `dofs`)"
    );
    let e =
        broken(|v| v["training"]["poses"][1]["dynamic"]["dof3"][4] = serde_json::json!([0.0, 0.0]));
    assert!(
        e.to_string().contains("line") || e.to_string().contains("length"),
        "{e}"
    );
    let e = broken(|v| v["training"]["poses"][1]["static"][4][1] = serde_json::Value::Null);
    assert!(
        e.to_string().contains("null") && e.to_string().contains("NaN"),
        "{e}"
    );
    let e = broken(|v| v["sus"][3] = "su1".into());
    assert!(matches!(
        e,
        MeasurementError::DuplicateName { field: "sus", .. }
    ));
    let e = broken(|v| v["training"]["pattern"]["frequency"] = 0.0.into());
    assert!(e.to_string().starts_with("training.pattern"), "{e}");
    let e = broken(|v| {
        v["structure"]["orientations"][1]["rest"]
            .as_array_mut()
            .unwrap()
            .truncate(2)
    });
    assert!(
        e.to_string().contains("structure.orientations[1].rest")
            && e.to_string().contains("one reading per SU"),
        "{e}"
    );
    // The readings' standard deviations: one positive number per SU, of dynamic readings there are.
    let e = broken(|v| v["training"]["poses"][0]["static_sd"] = serde_json::json!(vec![0.01; 6]));
    assert_eq!(
        e.to_string(),
        "training.poses[0].static_sd: has 6 entries, expected 7 (one standard deviation per SU)"
    );
    let e = broken(|v| {
        v["training"]["poses"][1]["dynamic_sd"] =
            serde_json::json!({"dof2": [0.01, 0.01, -0.01, 0.01, 0.01, 0.01, 0.01]})
    });
    assert!(
        e.to_string().starts_with(
            "training.poses[1].dynamic_sd[\"dof2\"][2] (SU su3): -0.01 must be a positive"
        ),
        "{e}"
    );
    let e = broken(|v| {
        v["training"]["poses"][1]["dynamic"]
            .as_object_mut()
            .unwrap()
            .remove("dof2");
        v["training"]["poses"][1]["dynamic_sd"] = serde_json::json!({"dof2": vec![0.01; 7]})
    });
    assert!(
        e.to_string().contains("no dynamic readings of that DoF"),
        "{e}"
    );
    // A move's gains' standard deviations: with the gains, one non-negative number or null per SU.
    let gains = serde_json::json!(vec![[0.0, 0.0, 0.0]; 7]);
    let e = broken(|v| {
        v["structure"]["orientations"][0]["moves"][1]["accelerated_sd"] =
            serde_json::json!(vec![0.001; 7])
    });
    assert_eq!(
        e.to_string(),
        "structure.orientations[0].moves[1].accelerated_sd: is given without `accelerated`: give \
         both, or leave it out"
    );
    let e = broken(|v| {
        let mv = &mut v["structure"]["orientations"][0]["moves"][1];
        mv["accelerated"] = gains.clone();
        mv["accelerated_sd"] = serde_json::json!([0.001, null, 0.001, -0.002, 0.001, 0.001, 0.001]);
    });
    assert!(
        e.to_string().starts_with(
            "structure.orientations[0].moves[1].accelerated_sd[3] (SU su4): -0.002 must be a \
             non-negative number"
        ),
        "{e}"
    );
    let mut v: serde_json::Value = serde_json::from_str(&small_set().to_json()).unwrap();
    let mv = &mut v["structure"]["orientations"][0]["moves"][1];
    mv["accelerated"] = gains;
    mv["accelerated_sd"] = serde_json::json!([0.001, null, 0.001, 0.002, 0.001, 0.001, 0.001]);
    let set = MeasurementSet::from_json(&v.to_string()).unwrap();
    let sd = &set.structure.unwrap().orientations[0].moves[1].accelerated_sd;
    assert_eq!(sd[1], None);
    assert_eq!(sd[3], Some(0.002));
    // Base orientations: numbered from the usual one (0) without a gap, at most 8.
    let e = broken(|v| v["training"]["poses"][2]["orientation"] = 8.into());
    assert!(
        e.to_string()
            .starts_with("training.poses[2].orientation: 8 is not a base orientation"),
        "{e}"
    );
    let e = broken(|v| v["training"]["poses"][2]["orientation"] = 2.into());
    assert!(
        e.to_string()
            .contains("has poses in base orientation 2 but none in 1"),
        "{e}"
    );
    let e = broken(|v| {
        for p in v["training"]["poses"].as_array_mut().unwrap() {
            p["orientation"] = 1.into();
        }
    });
    assert!(
        e.to_string().contains("has no pose in base orientation 0"),
        "{e}"
    );
}

#[test]
fn either_experiment_may_be_absent() {
    let mut set = small_set();
    set.structure = None;
    assert!(MeasurementSet::from_json(&set.to_json()).is_ok());
    set.training = None;
    let json = set.to_json();
    assert!(!json.contains("training") && !json.contains("structure"));
    assert!(MeasurementSet::from_json(&json).is_ok());
}
