//! Hostile input: each case here once panicked, hung or gave a confident wrong answer. Every one
//! must now end in an error that names the file, field or SU and says what to do.

use std::path::Path;

use serde_json::{json, Value};
use skincal::estimate::body::calibrate_body;
use skincal::estimate::ml::MlConfig;
use skincal::estimate::EstimateError;
use skincal::explore::{explore, ExploreConfig, Structure};
use skincal::ingest::{ingest, IngestConfig};
use skincal::io;
use skincal::measurements::MeasurementSet;
use skincal::model::presets;
use skincal::sim::{simulate, Imperfections, SimulationConfig};

fn paper_set(poses: usize) -> MeasurementSet {
    let robot = presets::find("paper-7dof").unwrap().robot().unwrap();
    simulate(
        &robot,
        &SimulationConfig {
            poses,
            ..SimulationConfig::default()
        },
    )
    .unwrap()
    .measurements
}

/// Why ingesting the log at `path` fails (it must).
fn ingest_error(path: &Path, config: &IngestConfig) -> String {
    ingest(
        std::slice::from_ref(&path.to_path_buf()),
        config,
        &mut |_, _, _| {},
    )
    .unwrap_err()
    .to_string()
}

fn as_value(set: &MeasurementSet) -> Value {
    serde_json::from_str(&set.to_json()).unwrap()
}

/// The error of a measurement set edited by `edit`.
fn refused(edit: impl FnOnce(&mut Value)) -> String {
    let mut v = as_value(&paper_set(3));
    edit(&mut v);
    MeasurementSet::from_json(&v.to_string())
        .expect_err("an impossible set must be refused")
        .to_string()
}

/// Multiplies every reading (static and dynamic) by `k`: the set in another unit.
fn scaled(v: &mut Value, k: f64) {
    fn walk(v: &mut Value, k: f64) {
        match v {
            Value::Array(a) if a.len() == 3 && a.iter().all(Value::is_f64) => {
                for x in a {
                    *x = json!(x.as_f64().unwrap() * k);
                }
            }
            Value::Array(a) => a.iter_mut().for_each(|x| walk(x, k)),
            Value::Object(o) => o.iter_mut().for_each(|(_, x)| walk(x, k)),
            _ => {}
        }
    }
    for o in v["structure"]["orientations"].as_array_mut().unwrap() {
        walk(&mut o["rest"], k);
        for m in o["moves"].as_array_mut().unwrap() {
            walk(&mut m["readings"], k);
        }
    }
    for p in v["training"]["poses"].as_array_mut().unwrap() {
        walk(&mut p["static"], k);
        walk(&mut p["dynamic"], k);
    }
}

#[test]
fn huge_readings_and_angles_are_refused_by_field_and_su() {
    let e = refused(|v| v["training"]["poses"][0]["static"][1][0] = json!(1e308));
    assert!(
        e.starts_with("training.poses[0].static[1][0] (SU su2): 1e308 m/s²"),
        "{e}"
    );
    let e = refused(|v| v["training"]["poses"][2]["dynamic"]["dof4"][6][2] = json!(-7e5));
    assert!(e.contains("dynamic[\"dof4\"][6][2] (SU su7)"), "{e}");
    let e = refused(|v| v["structure"]["orientations"][0]["rest_pose"][3] = json!(1e300));
    assert!(
        e.contains("rest_pose[3] (DoF dof4)") && e.contains("rad"),
        "{e}"
    );
}

#[test]
fn patterns_no_servo_can_run_are_refused() {
    for (field, value) in [
        ("amplitude", 1e308),
        ("frequency", 1e-300),
        ("amplitude", -1.0),
    ] {
        let e = refused(|v| v["training"]["pattern"][field] = json!(value));
        assert!(
            e.starts_with("training.pattern") && e.contains(field),
            "{field} = {value}: {e}"
        );
    }
}

#[test]
fn units_other_than_si_are_refused_with_the_conversion() {
    let e = refused(|v| v["units"]["acceleration"] = json!("g"));
    assert!(
        e.starts_with("units.acceleration") && e.contains("9.81"),
        "{e}"
    );
    let e = refused(|v| v["units"]["acceleration"] = json!("furlong/fortnight^2"));
    assert!(e.contains("m/s²"), "{e}");
    let e = refused(|v| v["units"]["angle"] = json!("deg"));
    assert!(e.starts_with("units.angle") && e.contains("π/180"), "{e}");
}

#[test]
fn readings_in_g_or_mg_are_recognised_by_their_magnitude() {
    // 1 g = 9.81 m/s²: the same physical set written in g and in mg, labelled m/s².
    let e = refused(|v| scaled(v, 1.0 / 9.81));
    assert!(e.contains("look like g") && e.contains("1.0"), "{e}");
    let e = refused(|v| scaled(v, 1000.0 / 9.81));
    assert!(e.contains("look like mg"), "{e}");
    // A few dead SUs (all zeros) do not make a set look like another unit.
    let mut v = as_value(&paper_set(3));
    for p in v["training"]["poses"].as_array_mut().unwrap() {
        p["static"][2] = json!([0.0, 0.0, 0.0]);
    }
    assert!(MeasurementSet::from_json(&v.to_string()).is_ok());
}

#[test]
fn json_errors_name_the_field_and_the_usual_cause() {
    let text = as_value(&paper_set(3)).to_string();
    // A NaN literal, as Python's json.dump writes it.
    let nan = text.replacen("[0.0,", "[NaN,", 1);
    let e = MeasurementSet::from_json(&nan).unwrap_err().to_string();
    assert!(e.contains("NaN") && e.contains("not JSON"), "{e}");
    // A reading with four components.
    let mut v: Value = serde_json::from_str(&text).unwrap();
    v["training"]["poses"][0]["static"][1] = json!([0.0, 0.0, 9.81, 1.0]);
    let e = MeasurementSet::from_json(&v.to_string())
        .unwrap_err()
        .to_string();
    assert!(
        e.starts_with("training.poses[0].static[1]") && e.contains("[x, y, z]"),
        "{e}"
    );
    // A missing field names its place.
    let mut v: Value = serde_json::from_str(&text).unwrap();
    v["training"]["poses"][1]
        .as_object_mut()
        .unwrap()
        .remove("q");
    let e = MeasurementSet::from_json(&v.to_string())
        .unwrap_err()
        .to_string();
    assert!(
        e.starts_with("training.poses[1]") && e.contains("`q`"),
        "{e}"
    );
}

#[test]
fn impossible_simulation_settings_are_refused_not_panicked_on() {
    let robot = presets::find("paper-7dof").unwrap().robot().unwrap();
    let sim = |imperfections: Imperfections, amplitude: f64, frequency: f64| {
        let mut config = SimulationConfig {
            poses: 2,
            imperfections,
            ..SimulationConfig::default()
        };
        config.pattern.amplitude = amplitude;
        config.pattern.frequency = frequency;
        simulate(&robot, &config).map(|_| ())
    };
    let ok = Imperfections::default();
    for (imperfections, a, f, setting) in [
        (Imperfections { bias: 1e308, ..ok }, 0.5, 2.0, "bias"),
        (
            Imperfections {
                uniform_noise: 1e308,
                ..ok
            },
            0.5,
            2.0,
            "noise",
        ),
        (
            Imperfections {
                gaussian_noise: 1e308,
                ..ok
            },
            0.5,
            2.0,
            "gaussian_noise",
        ),
        (ok, 1e308, 2.0, "amplitude"),
        (ok, 0.5, 1e-300, "frequency"),
    ] {
        let e = sim(imperfections, a, f).unwrap_err().to_string();
        assert!(e.contains(setting), "{setting}: {e}");
    }
}

fn explored() -> (MeasurementSet, Structure) {
    let set = paper_set(12);
    let structure = explore(&set, &ExploreConfig::default()).unwrap();
    (set, structure)
}

fn write_structure(dir: &Path, edit: impl FnOnce(&mut Value)) -> std::path::PathBuf {
    let (_, s) = explored();
    let mut v = serde_json::to_value(&s).unwrap();
    edit(&mut v);
    let path = dir.join("structure.json");
    std::fs::write(&path, v.to_string()).unwrap();
    path
}

#[test]
fn a_structure_with_a_loop_is_refused_at_once() {
    // Regression: calibrate ran for minutes and took gigabytes walking J2 → S5 → … → S2 forever.
    let dir = tempfile::tempdir().unwrap();
    let path = write_structure(dir.path(), |v| v["joints"][1]["parent"] = json!("S5"));
    let e = io::read_structure(&path).unwrap_err().to_string();
    assert!(e.contains("structure.json") && e.contains("loop"), "{e}");
    assert!(e.contains("S2 → S5 → S4 → S3 → S2"), "{e}");
    // The library refuses it too when it is handed over in memory.
    let (set, mut s) = explored();
    s.joints[1].parent = "S5".into();
    let e = calibrate_body(&set, Some(&s), &MlConfig::default(), None).unwrap_err();
    assert!(matches!(e, EstimateError::InvalidStructure(_)), "{e}");
    assert!(skincal::estimate::serial_chains(&s).is_err());
}

#[test]
fn a_structure_listing_an_su_twice_or_naming_nothing_is_refused() {
    let dir = tempfile::tempdir().unwrap();
    let path = write_structure(dir.path(), |v| {
        v["segments"][3]["sus"]
            .as_array_mut()
            .unwrap()
            .push(json!("su3"))
    });
    let e = io::read_structure(&path).unwrap_err().to_string();
    assert!(e.contains("segments[3].sus") && e.contains("su3"), "{e}");
    let path = write_structure(dir.path(), |v| v["limbs"][0]["joints"][2] = json!("J9"));
    let e = io::read_structure(&path).unwrap_err().to_string();
    assert!(e.contains("limbs[0].joints[2]") && e.contains("J9"), "{e}");
    let path = write_structure(dir.path(), |v| {
        v["segments"][4]["parent_joint"] = json!(null)
    });
    let e = io::read_structure(&path).unwrap_err().to_string();
    assert!(e.contains("`S4`") && e.contains("parent joint"), "{e}");
}

#[test]
fn a_file_of_another_kind_is_named_for_what_it_is() {
    let dir = tempfile::tempdir().unwrap();
    let (set, s) = explored();
    let m = dir.path().join("measurements.json");
    std::fs::write(&m, set.to_json()).unwrap();
    let e = io::read_model(&m).unwrap_err().to_string();
    assert!(
        e.contains("measurements.json") && e.contains("this is a measurement set"),
        "{e}"
    );
    let st = dir.path().join("structure.json");
    std::fs::write(&st, serde_json::to_string(&s).unwrap()).unwrap();
    let e = io::read_model(&st).unwrap_err().to_string();
    assert!(e.contains("this is a structure"), "{e}");
    let e = io::read_measurements(&st).unwrap_err().to_string();
    assert!(e.contains("this is a structure"), "{e}");
}

#[test]
fn a_structure_only_log_ingests_without_a_pattern() {
    // Regression: "no measurements found" although the structure moves were all there, because
    // no excitation pattern could be estimated from a log that has none.
    use skincal::log::csv::CsvSink;
    use skincal::plan::{Part, Plan, PlanConfig, PlanDof};
    use skincal::sim::timeseries::{record, LogConfig};
    let robot = presets::find("paper-7dof").unwrap().robot().unwrap();
    let plan = Plan::new(
        PlanDof::from_robot(&robot),
        &PlanConfig {
            poses: 1,
            ..PlanConfig::default()
        },
    )
    .unwrap();
    let dir = tempfile::tempdir().unwrap();
    let log = dir.path().join("log");
    let config = LogConfig {
        part: Some(Part::Structure),
        rate: 200.0,
        ..LogConfig::default()
    };
    record(
        &robot,
        &plan,
        &config,
        &mut CsvSink::new(&log, false),
        &mut |_| {},
    )
    .unwrap();
    let ingested = ingest(&[log], &IngestConfig::default(), &mut |_, _, _| {}).unwrap();
    let set = &ingested.measurements;
    assert!(set.training.is_none());
    let moves = &set.structure.as_ref().unwrap().orientations[0].moves;
    assert_eq!(moves.len(), 7, "one move per DoF");
}

#[test]
fn streamed_predictions_equal_the_in_memory_ones() {
    // `predict` streams (a million poses once took 10 GB); the streamed JSON must hold exactly
    // what Predictor::predict builds in memory, whatever the column order of the pose file.
    use skincal::predict::{PoseTable, Predictor};
    let (set, s) = explored();
    let model = calibrate_body(&set, Some(&s), &MlConfig::default(), None).unwrap();
    let predictor = Predictor::new(&model).unwrap();
    let dir = tempfile::tempdir().unwrap();
    let csv = "# poses\ndof7,dof1,dof2,dof3,dof4,dof5,dof6\n0.1,0.2,0.3,0.4,0.5,0.6,0.7\n\n-1,0,1e-7,0,-1,0,1\n";
    let path = dir.path().join("poses.csv");
    std::fs::write(&path, csv).unwrap();
    let out = dir.path().join("predicted.json");
    let n =
        io::write_predictions(&predictor, &path, &model.pattern, &out, false, &mut |_| {}).unwrap();
    assert_eq!(n, 2);
    let streamed: Value = serde_json::from_str(&std::fs::read_to_string(&out).unwrap()).unwrap();
    let table = PoseTable::from_csv(csv).unwrap();
    let in_memory = predictor
        .predict(&table, &model.pattern, "poses.csv")
        .unwrap();
    assert_eq!(streamed, in_memory);
    // No spill files are left beside the output, and it is not overwritten unasked.
    assert_eq!(std::fs::read_dir(dir.path()).unwrap().count(), 2);
    assert!(
        io::write_predictions(&predictor, &path, &model.pattern, &out, false, &mut |_| {}).is_err()
    );
    // A bad row names the file and the line.
    std::fs::write(&path, "dof1,dof2,dof3,dof4,dof5,dof6,dof7\n1,2,3,x,5,6,7\n").unwrap();
    let e = io::write_predictions(&predictor, &path, &model.pattern, &out, true, &mut |_| {})
        .unwrap_err()
        .to_string();
    assert!(e.contains("poses.csv") && e.contains("line 2"), "{e}");
}

#[test]
fn explore_refuses_trees_that_the_readings_contradict() {
    // Regressions: a base that tilted 10° during one structure move hung the whole body off
    // l_shoulder_pitch, and 10× noise merged dof1…dof6 into one joint — both called complete.
    use nalgebra::{Rotation3, Vector3};
    use skincal::explore::{DiagnosticKind, Severity};
    use skincal::model::sensor::static_readings;
    let kinds = |s: &Structure| -> Vec<DiagnosticKind> {
        s.diagnostics
            .iter()
            .filter(|d| d.severity == Severity::Error)
            .map(|d| d.kind)
            .collect()
    };
    let humanoid = presets::find("humanoid").unwrap().robot().unwrap();
    for bias in [0.0, 0.05] {
        let config = SimulationConfig {
            poses: 2,
            imperfections: Imperfections {
                bias,
                ..Imperfections::default()
            },
            ..SimulationConfig::default()
        };
        let set = simulate(&humanoid, &config).unwrap().measurements;
        let s = explore(&set, &ExploreConfig::default()).unwrap();
        assert!(s.complete, "bias {bias} g: {:?}", kinds(&s));
    }
    // The base tilted by 10° about x during the move of l_shoulder_pitch (noise-free readings).
    let mut set = simulate(
        &humanoid,
        &SimulationConfig {
            poses: 2,
            ..SimulationConfig::default()
        },
    )
    .unwrap()
    .measurements;
    let tilt = Rotation3::from_axis_angle(&Vector3::x_axis(), 10f64.to_radians());
    let g = tilt * Vector3::new(0.0, 0.0, -9.81);
    let o = &mut set.structure.as_mut().unwrap().orientations[0];
    let mv = o
        .moves
        .iter_mut()
        .find(|m| m.dof == "l_shoulder_pitch")
        .unwrap();
    mv.readings = static_readings(&humanoid.model, &humanoid.parameters, &mv.pose, &g)
        .iter()
        .map(|r| [r.x, r.y, r.z])
        .collect();
    let s = explore(&set, &ExploreConfig::default()).unwrap();
    assert!(!s.complete);
    let d = s
        .diagnostics
        .iter()
        .find(|d| d.kind == DiagnosticKind::MoveNotRigid)
        .expect("the tilted move is named");
    assert_eq!(d.dofs, ["l_shoulder_pitch"]);
    assert!(d.message.contains("base"), "{}", d.message);

    // Ten times the paper's noise: ±0.1 g against a 0.05 g threshold.
    let paper = presets::find("paper-7dof").unwrap().robot().unwrap();
    for (noise, noisy) in [(0.01, false), (0.1, true)] {
        let config = SimulationConfig {
            poses: 2,
            imperfections: Imperfections {
                uniform_noise: noise,
                ..Imperfections::default()
            },
            ..SimulationConfig::default()
        };
        let set = simulate(&paper, &config).unwrap().measurements;
        let s = explore(&set, &ExploreConfig::default()).unwrap();
        assert_eq!(
            kinds(&s).contains(&DiagnosticKind::TooNoisy),
            noisy,
            "noise {noise} g: {:?}",
            kinds(&s)
        );
        assert_eq!(s.complete, !noisy, "noise {noise} g");
    }
}

/// A 200 Hz CSV log of paper-7dof's structure moves.
fn structure_log(dir: &Path) -> std::path::PathBuf {
    let log = dir.join("log");
    record_structure(&mut skincal::log::csv::CsvSink::new(&log, false));
    log
}

/// The structure part of a plan of paper-7dof, recorded at 200 Hz by `sink`.
fn record_structure(sink: &mut dyn skincal::log::LogSink) {
    use skincal::plan::{Part, Plan, PlanConfig, PlanDof};
    use skincal::sim::timeseries::{record, LogConfig};
    let robot = presets::find("paper-7dof").unwrap().robot().unwrap();
    let plan = Plan::new(
        PlanDof::from_robot(&robot),
        &PlanConfig {
            poses: 1,
            ..PlanConfig::default()
        },
    )
    .unwrap();
    let config = LogConfig {
        part: Some(Part::Structure),
        rate: 200.0,
        ..LogConfig::default()
    };
    record(&robot, &plan, &config, sink, &mut |_| {}).unwrap();
}

/// The structure part of [`record_structure`] as an MCAP log (zstd) `name` in `dir`, with a skin
/// batch per time step when `batched`.
fn structure_mcap(dir: &Path, name: &str, batched: bool) -> std::path::PathBuf {
    use skincal::log::mcap::{Compression, McapSink};
    let path = dir.join(name);
    let sink = McapSink::new(
        &path,
        skincal::log::Topics::default(),
        Compression::Zstd,
        false,
    );
    record_structure(&mut if batched { sink.batched() } else { sink });
    path
}

/// The MCAP log `from` written again to `to` through the MCAP writer (so that its chunks' CRCs
/// hold), each message's data first passed to `edit` with its topic.
fn rewritten(from: &Path, to: &Path, mut edit: impl FnMut(&str, &mut Vec<u8>)) {
    let bytes = std::fs::read(from).unwrap();
    let file = std::io::BufWriter::new(std::fs::File::create(to).unwrap());
    let mut writer = mcap::Writer::new(file).unwrap();
    for message in mcap::MessageStream::new(&bytes).unwrap() {
        let mut message = message.unwrap();
        let mut data = message.data.into_owned();
        edit(&message.channel.topic, &mut data);
        message.data = data.into();
        writer.write(&message).unwrap();
    }
    writer.finish().unwrap();
}

#[test]
fn logs_with_stamps_in_ms_are_errors_not_empty_results() {
    let dir = tempfile::tempdir().unwrap();
    let log = structure_log(dir.path());
    // Stamps in ms: every stamp × 1000.
    for file in ["joint_states.csv", "imu.csv"] {
        let path = log.join(file);
        let text = std::fs::read_to_string(&path).unwrap();
        let ms: String = text
            .lines()
            .map(|l| match l.split_once(',') {
                Some((stamp, rest)) => match stamp.parse::<f64>() {
                    Ok(t) => format!("{:.6},{rest}\n", t * 1000.0),
                    Err(_) => format!("{l}\n"),
                },
                None => format!("{l}\n"),
            })
            .collect();
        std::fs::write(log.join(format!("ms-{file}")), ms).unwrap();
    }
    let ms = dir.path().join("ms");
    std::fs::create_dir(&ms).unwrap();
    for file in ["joint_states.csv", "imu.csv"] {
        std::fs::rename(log.join(format!("ms-{file}")), ms.join(file)).unwrap();
    }
    let e = ingest_error(&ms, &IngestConfig::default());
    assert!(
        e.contains("ms") && e.contains("seconds") && e.contains("/ms"),
        "{e}"
    );
}

#[test]
fn a_skin_in_g_or_mg_is_refused_with_the_option_that_reads_it() {
    // Regression: a driver that publishes g gave a measurement set a tenth of the truth, refused
    // only later by `explore`, which told the user to edit measurements.json.
    use skincal::model::sensor::STANDARD_GRAVITY;
    let dir = tempfile::tempdir().unwrap();
    let log = structure_log(dir.path());
    let read = |path: &Path, skin_scale: f64| {
        let config = IngestConfig {
            skin_scale,
            ..IngestConfig::default()
        };
        ingest(
            std::slice::from_ref(&path.to_path_buf()),
            &config,
            &mut |_, _, _| {},
        )
    };
    let truth = read(&log, 1.0).unwrap();
    // A log in m/s² read as g is refused too (every sample beyond ±2 g).
    let e = read(&log, STANDARD_GRAVITY).unwrap_err().to_string();
    assert!(
        e.contains("saturated") && e.contains("m/s² already, leave out --skin-unit"),
        "{e}"
    );
    for (unit, per_unit) in [("g", STANDARD_GRAVITY), ("mg", STANDARD_GRAVITY / 1000.0)] {
        let text = std::fs::read_to_string(log.join("imu.csv")).unwrap();
        let mut lines = text.lines();
        let mut out = format!("{}\n", lines.next().unwrap());
        for l in lines {
            let f: Vec<&str> = l.split(',').collect();
            let a: Vec<String> = f[2..]
                .iter()
                .map(|v| format!("{:.9}", v.parse::<f64>().unwrap() / per_unit))
                .collect();
            out.push_str(&format!("{},{},{}\n", f[0], f[1], a.join(",")));
        }
        let other = dir.path().join(unit);
        std::fs::create_dir(&other).unwrap();
        std::fs::write(other.join("imu.csv"), out).unwrap();
        std::fs::copy(log.join("joint_states.csv"), other.join("joint_states.csv")).unwrap();
        // Refused, naming the log and the option (in mg, every sample is beyond ±2 g).
        let e = read(&other, 1.0).unwrap_err().to_string();
        assert!(
            e.contains(&format!("--skin-unit {unit}"))
                && e.contains(&format!("{}: ", other.display()))
                && !e.contains(": :"),
            "{e}"
        );
        // Read in its unit, it gives the readings of the log in m/s².
        let got = read(&other, per_unit).unwrap();
        let rest = |m: &MeasurementSet| m.structure.as_ref().unwrap().orientations[0].rest.clone();
        for (a, b) in rest(&truth.measurements)
            .iter()
            .zip(&rest(&got.measurements))
        {
            for (x, y) in a.iter().zip(b) {
                assert!((x - y).abs() < 1e-6, "{unit}: {x} {y}");
            }
        }
    }
}

#[test]
fn skin_stamped_by_another_clock_than_the_joints_is_an_error_that_says_so() {
    // Regression: a skin driver stamping with its own clock, 1000 s off ROS time, gave "training
    // pose skipped: SU `su1` has no sample in its still windows".
    let dir = tempfile::tempdir().unwrap();
    let log = structure_log(dir.path());
    let shifted = |by: f64| {
        let text = std::fs::read_to_string(log.join("imu.csv")).unwrap();
        let mut lines = text.lines();
        let mut out = format!("{}\n", lines.next().unwrap());
        for l in lines {
            let (stamp, rest) = l.split_once(',').unwrap();
            let t: f64 = stamp.parse().unwrap();
            out.push_str(&format!("{:.6},{rest}\n", t + by));
        }
        let moved = dir.path().join(format!("shifted{by}"));
        std::fs::create_dir_all(&moved).unwrap();
        std::fs::write(moved.join("imu.csv"), out).unwrap();
        std::fs::copy(log.join("joint_states.csv"), moved.join("joint_states.csv")).unwrap();
        moved
    };
    let e = ingest_error(&shifted(-1000.0), &IngestConfig::default());
    assert!(
        e.contains("shifted-1000")
            && e.contains("different clocks")
            && e.contains("(-1000.000 s apart)"),
        "{e}"
    );
    // A skin that starts late is not another clock: its samples outside are counted.
    let late = ingest(&[shifted(0.5)], &IngestConfig::default(), &mut |_, _, _| {}).unwrap();
    let report = &late.report.logs[0];
    assert!(report.imu_outside > 0 && report.imu_outside * 10 < report.imu_samples);
}

#[test]
fn an_su_the_robot_lists_but_the_log_never_holds_is_left_out_by_name() {
    // Regression: one dead SU made every pose be skipped ("SU `su3` has no sample in its still
    // windows"), so a skin with one broken unit gave no measurement set at all.
    let dir = tempfile::tempdir().unwrap();
    let log = structure_log(dir.path());
    let text = std::fs::read_to_string(log.join("imu.csv")).unwrap();
    let without: String = text
        .lines()
        .filter(|l| !l.contains(",su3,"))
        .map(|l| format!("{l}\n"))
        .collect();
    std::fs::write(log.join("imu.csv"), without).unwrap();
    let robot = presets::find("paper-7dof").unwrap().robot().unwrap();
    let read = |sus: Option<Vec<String>>| {
        let config = IngestConfig {
            sus,
            ..IngestConfig::default()
        };
        ingest(std::slice::from_ref(&log), &config, &mut |_, _, _| {}).unwrap()
    };
    let listed = read(Some(robot.model.su_names()));
    let warning = listed
        .report
        .warnings
        .iter()
        .find(|w| w.contains("`su3`"))
        .expect("a warning names su3");
    assert!(
        warning.starts_with("1 SU has no sample") && warning.contains("left out"),
        "{warning}"
    );
    let mut expected = robot.model.su_names();
    expected.retain(|s| s != "su3");
    assert_eq!(listed.measurements.sus, expected);
    // The others' readings are those of the log read without the robot's list.
    let found = read(None);
    assert_eq!(found.measurements.sus, expected);
    assert_eq!(listed.measurements.structure, found.measurements.structure);
    // A skin driver that names its SUs otherwise: when none is the robot's, an error lists the
    // log's names; when some are, the warning points at the others.
    let text = std::fs::read_to_string(log.join("imu.csv")).unwrap();
    std::fs::write(log.join("imu.csv"), text.replace(",su", ",skin/su")).unwrap();
    let config = IngestConfig {
        sus: Some(robot.model.su_names()),
        ..IngestConfig::default()
    };
    let e = ingest_error(&log, &config);
    assert!(
        e.contains(&format!("{}: no SU listed (`su1`, `su2`", log.display()))
            && e.contains("`skin/su1`, `skin/su2`")
            && e.contains("/log"),
        "{e}"
    );
    let text = std::fs::read_to_string(log.join("imu.csv")).unwrap();
    std::fs::write(log.join("imu.csv"), text.replace(",skin/su1,", ",su1,")).unwrap();
    let one = read(Some(robot.model.su_names()));
    assert_eq!(one.measurements.sus, ["su1"]);
    let warning = &one.report.warnings[0];
    assert!(
        warning.starts_with("6 SUs have no sample")
            && warning.contains("`su2`, `su3`, `su4`")
            && warning.contains("`skin/su2`, `skin/su4`")
            && warning.contains("other names?"),
        "{warning}"
    );
}

#[test]
fn damaged_or_empty_mcap_logs_are_refused_without_taking_memory() {
    // Regression: one flipped byte in a length field made the reader allocate 4 EB and abort.
    let dir = tempfile::tempdir().unwrap();
    let path = structure_mcap(dir.path(), "log.mcap", false);
    let mut bytes = std::fs::read(&path).unwrap();
    // The footer record (opcode, length u64, …, 29 bytes) sits before the 8 magic bytes.
    let footer = bytes.len() - 8 - 29;
    assert_eq!(bytes[footer], 0x02, "footer opcode");
    bytes[footer + 8] ^= 0x40; // the length's top byte: 4.6e18
    let damaged = dir.path().join("damaged.mcap");
    std::fs::write(&damaged, &bytes).unwrap();
    let empty = dir.path().join("empty.mcap");
    std::fs::write(&empty, b"").unwrap();
    // A chunk whose compression name claims 2.5 GB (the mcap crate allocates a string's claimed
    // length before reading it).
    let mut bytes = std::fs::read(&path).unwrap();
    let mut at = 8;
    while bytes[at] != 0x06 {
        at += 9 + u64::from_le_bytes(bytes[at + 1..at + 9].try_into().unwrap()) as usize;
    }
    bytes[at + 9 + 28..at + 9 + 32].copy_from_slice(&0x9A00_0000u32.to_le_bytes());
    let chunk = dir.path().join("chunk.mcap");
    std::fs::write(&chunk, &bytes).unwrap();
    for (path, words) in [(damaged, "damaged"), (empty, "empty"), (chunk, "damaged")] {
        let e = ingest_error(&path, &IngestConfig::default());
        let name = path.file_name().unwrap().to_string_lossy().into_owned();
        assert!(e.contains(&name) && e.contains(words), "{e}");
    }
}

#[test]
fn skin_batches_whose_lengths_claim_gigabytes_are_counted_not_allocated() {
    // Regression: a skin_msgs/ImuArray whose frame id claimed 2.9 GB made the CDR decoder
    // reserve it (an abort where memory is capped, seconds of work elsewhere). Written through
    // the MCAP writer, so that the chunks' CRCs hold and only the messages are damaged.
    use skincal::log::Topics;
    let dir = tempfile::tempdir().unwrap();
    let path = structure_mcap(dir.path(), "batches.mcap", true);
    let whole = ingest(
        std::slice::from_ref(&path),
        &IngestConfig::default(),
        &mut |_, _, _| {},
    )
    .unwrap();
    let damaged = dir.path().join("damaged.mcap");
    let mut batches = 0;
    rewritten(&path, &damaged, |topic, data| {
        if topic == Topics::default().imu {
            batches += 1;
            // After the encapsulation (4) and the stamp (8): the batch's frame id length; after
            // the empty frame id (4 + 1, aligned to 4 → 20): the count of Imu messages.
            match batches {
                100 => data[12..16].copy_from_slice(&0xAB00_0000u32.to_le_bytes()),
                200 => data[20..24].copy_from_slice(&0xAB00_0000u32.to_le_bytes()),
                _ => {}
            }
        }
    });
    let read = ingest(&[damaged], &IngestConfig::default(), &mut |_, _, _| {}).unwrap();
    let (before, after) = (&whole.report.logs[0], &read.report.logs[0]);
    let sus = presets::find("paper-7dof")
        .unwrap()
        .robot()
        .unwrap()
        .model
        .su_names()
        .len() as u64;
    assert_eq!(after.imu_read.undecodable, 2);
    assert_eq!(after.imu_read.samples, before.imu_read.samples - 2 * sus);
    let problem = after.imu_read.first_problem.as_deref().unwrap();
    assert!(problem.contains("longer than the message"), "{problem}");
}

#[test]
fn non_finite_samples_and_joint_states_are_counted_not_averaged_in() {
    // Drivers publish NaN for a reading they could not take. One Imu sample in fifty with a NaN
    // or infinite component, and one joint state in a hundred with a NaN position: counted as
    // undecodable, and the readings are those of the log without them.
    use skincal::log::ros::{imu_fields, JointState};
    use skincal::log::Topics;
    let dir = tempfile::tempdir().unwrap();
    let path = structure_mcap(dir.path(), "log.mcap", false);
    let read = |path: &Path| {
        ingest(
            std::slice::from_ref(&path.to_path_buf()),
            &IngestConfig::default(),
            &mut |_, _, _| {},
        )
    };
    let whole = read(&path).unwrap();
    let damaged = dir.path().join("nan.mcap");
    let (mut imus, mut joints) = (0, 0);
    rewritten(&path, &damaged, |topic, data| {
        if topic == Topics::default().imu {
            imus += 1;
            if imus % 50 == 0 {
                // The acceleration is the last 24 + 72 bytes before the covariance's end.
                let f = imu_fields(data).unwrap();
                let at = data.len() - 72 - 24 + 8 * (imus / 50 % 3);
                let bad = [f64::NAN, f64::INFINITY, f64::NEG_INFINITY][imus / 50 % 3];
                assert_eq!(
                    f64::from_le_bytes(data[at..at + 8].try_into().unwrap()),
                    f.linear_acceleration[imus / 50 % 3]
                );
                data[at..at + 8].copy_from_slice(&bad.to_le_bytes());
            }
        } else if topic == Topics::default().joints {
            joints += 1;
            if joints % 100 == 0 {
                let mut j: JointState = skincal::log::ros::decode(data).unwrap();
                let d = joints / 100 % j.position.len();
                j.position[d] = f64::NAN;
                *data = skincal::log::ros::encode(&j).unwrap();
            }
        }
    });
    let got = read(&damaged).unwrap();
    let (before, after) = (&whole.report.logs[0], &got.report.logs[0]);
    assert_eq!(after.imu_read.undecodable, (imus / 50) as u64, "{after:?}");
    assert_eq!(
        after.joint_read.undecodable,
        (joints / 100) as u64,
        "{after:?}"
    );
    assert_eq!(after.still_windows, before.still_windows);
    let orientations = |m: &MeasurementSet| m.structure.as_ref().unwrap().orientations.clone();
    let (a, b) = (
        orientations(&whole.measurements),
        orientations(&got.measurements),
    );
    assert_eq!(a.len(), b.len());
    for (a, b) in a.iter().zip(&b) {
        for (ra, rb) in a.rest.iter().zip(&b.rest) {
            for (x, y) in ra.iter().zip(rb) {
                assert!(y.is_finite() && (x - y).abs() < 0.01, "{x} {y}");
            }
        }
    }
}

#[test]
fn csv_logs_that_are_not_text_or_have_no_line_ends_are_refused_by_file_and_line() {
    let dir = tempfile::tempdir().unwrap();
    let header = "stamp,frame_id,ax,ay,az\n0.0,su1,0,0,9.81\n";
    let cases: [(&str, Vec<u8>, &str); 2] = [
        // A binary file renamed: its rows are not UTF-8.
        (
            "binary",
            [header.as_bytes(), &[0xff, 0xfe, 0x00, b'\n']].concat(),
            "not UTF-8",
        ),
        // 70 MB without a line end must not be read into memory whole.
        (
            "one-line",
            [header.as_bytes(), &vec![b'1'; 70 << 20]].concat(),
            "longer than 64 MB",
        ),
    ];
    for (name, imu, words) in cases {
        let log = dir.path().join(name);
        std::fs::create_dir(&log).unwrap();
        std::fs::write(log.join("joint_states.csv"), "stamp,j1\n0.0,0\n0.001,0\n").unwrap();
        std::fs::write(log.join("imu.csv"), imu).unwrap();
        let e = ingest_error(&log, &IngestConfig::default());
        assert!(
            e.contains("imu.csv") && e.contains("line 3") && e.contains(words),
            "{name}: {e}"
        );
    }
}

#[test]
fn a_training_experiment_without_poses_is_refused() {
    // Regression: `validate` against it printed all zeros.
    let e = refused(|v| v["training"]["poses"] = json!([]));
    assert!(
        e.starts_with("training.poses") && e.contains("empty"),
        "{e}"
    );
}

#[test]
fn a_structure_experiment_without_orientations_is_refused_by_field() {
    // Exploration once indexed the first orientation of an empty list.
    let e = refused(|v| v["structure"]["orientations"] = json!([]));
    assert!(
        e.contains("structure.orientations") && e.contains("empty"),
        "{e}"
    );
}

#[test]
fn a_broken_motion_record_is_refused_naming_its_field_line_and_column() {
    // `motion.json` is read as a stream; an error is worded from the file's text, as for every
    // other JSON file: the field path, the line and column, the file.
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("motion.json");
    let zeros = "[[0.0],[0.0]]";
    let record = |skin: &str| {
        format!(
            "{{\"format\":\"skincal-motion\",\"version\":1,\"period\":0.01,\"dofs\":[\"j\"],\n\
             \"sus\":[\"a\",\"b\"],\"noise_sd\":[null,null],\"runs\":[{{\"log\":\"l\",\"start\":0.0,\n\
             \"q\":{zeros},\"qd\":{zeros},\"qdd\":{zeros},\"qdd_sd\":{zeros},\n\
             \"skin\":{skin}}}]}}"
        )
    };
    std::fs::write(&path, record("[[null,[1,2,3]],[null,null]]")).unwrap();
    let read = io::read_motion(&path).unwrap();
    assert_eq!(read.runs[0].skin.get(0, 1), Some([1.0, 2.0, 3.0]));
    std::fs::write(&path, record("[[null,[1,2,\"x\"]],[null,null]]")).unwrap();
    let message = io::read_motion(&path).unwrap_err().to_string();
    for part in ["motion.json", "runs[0].skin", "line 4"] {
        assert!(message.contains(part), "{part}: {message}");
    }
    std::fs::write(&path, record("[[null,[1,2,3]],[null]]")).unwrap();
    let message = io::read_motion(&path).unwrap_err().to_string();
    assert!(
        message.contains("`runs[0].skin[1]` has 1 entries for 2 SUs"),
        "{message}"
    );
}
