//! Mutation fuzzing of every input format skincal reads.
//!
//! For each format a valid file is made here (measurement set, structure, model, robot TOML, URDF,
//! pose CSV and JSON, plan, CSV log, MCAP logs (zstd; uncompressed without CRCs, with one Imu per
//! SU or a batch per time step), a rosbag2 directory's metadata, a rosbag2 SQLite file, ROS 1 bags
//! (uncompressed and bz2, written by the `rosbags` Python package)) and mutated many times,
//! seeded: bit flips, truncations, duplicated and deleted spans, numbers replaced by extremes (NaN,
//! ±inf, 1e308, -0, huge integers) and, for JSON, missing and extra fields and wrong types. The library's entry point
//! reads each mutant from a file, and whatever it accepts goes on through the next stages
//! (exploration, calibration, prediction, simulation, ingestion) within a budget. Every case must
//! end without a panic, within a time limit, within a memory limit (the allocator refuses to hold
//! more), and a refusal must name the file. The formats are fuzzed side by side, one per thread,
//! each from its own seeded sequence.
//!
//! `SKINCAL_FUZZ_CASES` (mutants per format, default 1000) and `SKINCAL_FUZZ_SEED` (default 1) run
//! it longer or elsewhere: `SKINCAL_FUZZ_CASES=5000 cargo test --release -p skincal --test fuzz --
//! --nocapture`. The table of what ran is printed at the end; a failing case is written to
//! `fuzz-case-<format>.txt` in the test's temporary directory before it runs, so that an abort
//! (memory) still tells which it was.

use std::fmt::Write as _;
use std::path::{Path, PathBuf};
use std::sync::mpsc;
use std::time::Duration;

use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use serde_json::{json, Value};
use skincal::estimate::body::calibrate_body;
use skincal::estimate::ml::MlConfig;
use skincal::estimate::{limb_chains, serial_chains};
use skincal::explore::{explore, ExploreConfig};
use skincal::ingest::{ingest, IngestConfig};
use skincal::io::{self, SuPlacement};
use skincal::log::csv::CsvSink;
use skincal::log::mcap::{Compression, McapSink};
use skincal::log::Topics;
use skincal::model::presets;
use skincal::plan::{Plan, PlanConfig, PlanDof};
use skincal::predict::Predictor;
use skincal::sim::timeseries::{record, LogConfig};
use skincal::sim::{simulate, Imperfections, SimulationConfig};

mod bags;
#[allow(dead_code)]
mod common;

/// Every allocation goes through this; a case that holds more than [`MEMORY_LIMIT`] aborts.
#[global_allocator]
static ALLOCATOR: cap::Cap<std::alloc::System> = cap::Cap::new(std::alloc::System, usize::MAX);

/// Memory any one case may hold, bytes.
const MEMORY_LIMIT: usize = 2 << 30;
/// Time any one case may take.
const TIME_LIMIT: Duration = Duration::from_secs(30);
/// Accepted mutants per format that go on through the expensive stages (calibration, recording).
const DEEP_BUDGET: usize = 6;

/// How a format's bytes may be mutated.
#[derive(Clone, Copy, PartialEq)]
enum Kind {
    Json,
    Text,
    Binary,
}

/// Reads a file (and goes on with what it accepts); `bool`: run the expensive stages too.
type EntryPoint = dyn Fn(&Path, bool) -> Result<(), String> + Send + Sync;

/// One input format: a valid file and the entry point that reads it.
struct Format {
    name: &'static str,
    /// File name in the case directory (for CSV logs: the file mutated inside `log/`).
    file: &'static str,
    kind: Kind,
    valid: Vec<u8>,
    /// For a log that is a directory: the files copied beside the mutant; the directory is
    /// handed over.
    beside: Vec<PathBuf>,
    /// Reads the file at the path (and goes on with what it accepts); `deep`: run the expensive
    /// stages too. Err is the library's message.
    run: Box<EntryPoint>,
}

/// What the cases of one format did.
#[derive(Default)]
struct Tally {
    cases: usize,
    accepted: usize,
    refused: usize,
    findings: Vec<String>,
}

#[test]
fn every_format_survives_mutation() {
    let cases: usize = env_or("SKINCAL_FUZZ_CASES", 1000);
    let seed: u64 = env_or("SKINCAL_FUZZ_SEED", 1);
    // `format:case` runs that case alone (with the same seed and case count).
    let only: Option<(String, usize)> = std::env::var("SKINCAL_FUZZ_ONLY").ok().and_then(|v| {
        let (f, c) = v.rsplit_once(':')?;
        Some((f.to_string(), c.parse().ok()?))
    });
    let work = tempfile::tempdir().unwrap();
    let formats = formats(work.path());
    // The formats are fuzzed side by side, on as many plain threads as the machine has cores
    // (not rayon's: the cases' own stages run on its pool, which a worker waiting on a case
    // would starve). Each may hold its own limit's worth at once.
    let workers = std::thread::available_parallelism().map_or(1, usize::from);
    ALLOCATOR
        .set_limit(ALLOCATOR.allocated() + MEMORY_LIMIT * workers)
        .unwrap();
    let quiet = std::panic::take_hook();
    std::panic::set_hook(Box::new(|_| {}));
    let formats: Vec<std::sync::Arc<Format>> =
        formats.into_iter().map(std::sync::Arc::new).collect();
    let run = Run {
        cases,
        seed,
        only,
        work: work.path(),
    };
    let next = std::sync::atomic::AtomicUsize::new(0);
    let tallies = std::sync::Mutex::new(Vec::new());
    std::thread::scope(|scope| {
        for _ in 0..workers {
            scope.spawn(|| loop {
                // The last first: the bags, the slowest to read (bz2 most of all), do not
                // start when the other threads are nearly done.
                let taken = next.fetch_add(1, std::sync::atomic::Ordering::Relaxed);
                let Some(f) = formats.len().checked_sub(taken + 1) else {
                    break;
                };
                let format = &formats[f];
                let tally = run.format(f, format);
                tallies.lock().unwrap().push((f, tally));
            });
        }
    });
    let mut tallies = tallies.into_inner().unwrap();
    tallies.sort_by_key(|(f, _)| *f);
    std::panic::set_hook(quiet);
    let mut report = String::new();
    writeln!(
        report,
        "format            cases  accepted  refused  findings   (seed {seed})"
    )
    .unwrap();
    let mut failures = Vec::new();
    for (format, (_, tally)) in formats.iter().zip(tallies) {
        writeln!(
            report,
            "{:<17} {:>5}  {:>8}  {:>7}  {:>8}",
            format.name,
            tally.cases,
            tally.accepted,
            tally.refused,
            tally.findings.len()
        )
        .unwrap();
        failures.extend(tally.findings);
    }
    println!("{report}");
    assert!(
        failures.is_empty(),
        "{} findings:\n{}\n\n{report}",
        failures.len(),
        failures
            .iter()
            .take(30)
            .cloned()
            .collect::<Vec<_>>()
            .join("\n")
    );
}

/// What every format's cases share.
struct Run<'a> {
    cases: usize,
    seed: u64,
    only: Option<(String, usize)>,
    work: &'a Path,
}

impl Run<'_> {
    /// Runs the unmutated file and `cases` mutants of format number `f`, seeded by the run's
    /// seed and `f` (so a format's cases are the same whatever runs beside them). A failing
    /// valid file is a finding too.
    fn format(&self, f: usize, format: &std::sync::Arc<Format>) -> Tally {
        let seed = self.seed;
        let mut rng = ChaCha8Rng::seed_from_u64(seed.wrapping_mul(1000).wrapping_add(f as u64));
        let case_file = PathBuf::from(env!("CARGO_TARGET_TMPDIR"))
            .join(format!("fuzz-case-{}.txt", format.name.replace(' ', "-")));
        let mut tally = Tally::default();
        // The unmutated file first: it must be accepted.
        for case in 0..=self.cases {
            let (bytes, what) = if case == 0 {
                (format.valid.clone(), "unmutated".to_string())
            } else {
                mutate(&format.valid, format.kind, &mut rng)
            };
            if self
                .only
                .as_ref()
                .is_some_and(|(name, c)| name != format.name || *c != case)
            {
                continue;
            }
            let dir = self.work.join(format!("{f}-{case}"));
            std::fs::create_dir_all(&dir).unwrap();
            let path = place(format, &dir, &bytes);
            std::fs::write(
                &case_file,
                format!("{} case {case} (seed {seed}): {what}\n", format.name),
            )
            .unwrap();
            let deep = tally.accepted < DEEP_BUDGET;
            let outcome = run_bounded(format, path.clone(), deep);
            tally.cases += 1;
            let label = format!("{} case {case} ({what})", format.name);
            match outcome {
                Outcome::Ok => tally.accepted += 1,
                Outcome::Refused(message) => {
                    tally.refused += 1;
                    if case == 0 {
                        tally
                            .findings
                            .push(format!("{label}: the valid file was refused: {message}"));
                    } else if !message.contains(format.file)
                        && !message.contains(&path.display().to_string())
                    {
                        tally.findings.push(format!(
                            "{label}: the error does not name {}: {message}",
                            format.file
                        ));
                    }
                }
                Outcome::Panicked(message) => {
                    tally.findings.push(format!("{label}: panicked: {message}"))
                }
                Outcome::TimedOut => tally
                    .findings
                    .push(format!("{label}: still running after {TIME_LIMIT:?}")),
            }
            let _ = std::fs::remove_dir_all(&dir);
        }
        let _ = std::fs::remove_file(&case_file);
        tally
    }
}

enum Outcome {
    Ok,
    Refused(String),
    Panicked(String),
    TimedOut,
}

/// Runs one case on its own thread: a panic is caught, a hang is left behind and reported.
fn run_bounded(format: &std::sync::Arc<Format>, path: PathBuf, deep: bool) -> Outcome {
    let (send, receive) = mpsc::channel();
    let format = std::sync::Arc::clone(format);
    std::thread::spawn(move || {
        let result =
            std::panic::catch_unwind(std::panic::AssertUnwindSafe(|| (format.run)(&path, deep)));
        let _ = send.send(result);
    });
    match receive.recv_timeout(TIME_LIMIT) {
        Ok(Ok(Ok(()))) => Outcome::Ok,
        Ok(Ok(Err(message))) => Outcome::Refused(message),
        Ok(Err(payload)) => Outcome::Panicked(
            payload
                .downcast_ref::<String>()
                .cloned()
                .or_else(|| payload.downcast_ref::<&str>().map(|s| s.to_string()))
                .unwrap_or_default(),
        ),
        Err(mpsc::RecvTimeoutError::Timeout) => Outcome::TimedOut,
        Err(mpsc::RecvTimeoutError::Disconnected) => Outcome::Panicked("no result".into()),
    }
}

/// Writes the mutant where the entry point looks for it; returns the path to hand over.
fn place(format: &Format, dir: &Path, bytes: &[u8]) -> PathBuf {
    if format.beside.is_empty() {
        let path = dir.join(format.file);
        std::fs::write(&path, bytes).unwrap();
        return path;
    }
    let log = dir.join("log");
    std::fs::create_dir_all(&log).unwrap();
    std::fs::write(log.join(format.file), bytes).unwrap();
    for other in &format.beside {
        std::fs::copy(other, log.join(other.file_name().unwrap())).unwrap();
    }
    log
}

fn env_or<T: std::str::FromStr>(name: &str, default: T) -> T {
    std::env::var(name)
        .ok()
        .and_then(|v| v.parse().ok())
        .unwrap_or(default)
}

// ---------------------------------------------------------------------------------------------
// Mutations

/// Extreme numbers, as JSON/TOML/CSV text.
const EXTREMES: [&str; 14] = [
    "NaN",
    "Infinity",
    "-Infinity",
    "inf",
    "1e308",
    "-1e308",
    "1e-320",
    "-0",
    "-0.0",
    "18446744073709551616",
    "-9223372036854775809",
    "99999999999999999999999",
    "0",
    "-1",
];

fn mutate(valid: &[u8], kind: Kind, rng: &mut ChaCha8Rng) -> (Vec<u8>, String) {
    let structural = kind == Kind::Json && rng.random_bool(0.4);
    if structural {
        if let Ok(mut v) = serde_json::from_slice::<Value>(valid) {
            let what = mutate_json(&mut v, rng);
            return (v.to_string().into_bytes(), what);
        }
    }
    let numeric = kind != Kind::Binary && rng.random_bool(0.35);
    if numeric {
        if let Some(result) = replace_number(valid, rng) {
            return result;
        }
    }
    mutate_bytes(valid, kind, rng)
}

fn mutate_bytes(valid: &[u8], kind: Kind, rng: &mut ChaCha8Rng) -> (Vec<u8>, String) {
    let mut b = valid.to_vec();
    let n = b.len().max(1);
    let at = rng.random_range(0..n);
    let span = rng.random_range(1..=64.min(n));
    let end = (at + span).min(b.len());
    match rng.random_range(0..7) {
        0 => {
            let bit = rng.random_range(0..8);
            if let Some(x) = b.get_mut(at) {
                *x ^= 1 << bit;
            }
            (b, format!("bit {bit} of byte {at} flipped"))
        }
        1 => {
            b.truncate(at);
            (b, format!("truncated to {at} bytes"))
        }
        2 => {
            let copy = b[at..end].to_vec();
            let to = rng.random_range(0..=b.len());
            b.splice(to..to, copy);
            (b, format!("bytes {at}..{end} duplicated at {to}"))
        }
        3 => {
            b.drain(at..end);
            (b, format!("bytes {at}..{end} deleted"))
        }
        4 if kind == Kind::Binary => {
            // A length field claiming everything.
            for x in b.iter_mut().skip(at).take(8) {
                *x = 0xff;
            }
            (b, format!("8 bytes at {at} set to 0xff"))
        }
        4 | 5 => {
            let value = rng.random::<u8>();
            for x in b.iter_mut().skip(at).take(span) {
                *x = value;
            }
            (b, format!("bytes {at}..{end} set to {value:#04x}"))
        }
        _ => {
            // A whole line (or span) repeated many times: size without structure.
            let copy = b[at..end].to_vec();
            let times = rng.random_range(2..200);
            for _ in 0..times {
                b.splice(at..at, copy.iter().copied());
            }
            (b, format!("bytes {at}..{end} repeated {times} times"))
        }
    }
}

/// Replaces one number of the text by an extreme.
fn replace_number(valid: &[u8], rng: &mut ChaCha8Rng) -> Option<(Vec<u8>, String)> {
    let text = std::str::from_utf8(valid).ok()?;
    let bytes = text.as_bytes();
    let mut numbers = Vec::new();
    let mut i = 0;
    while i < bytes.len() {
        let starts = bytes[i].is_ascii_digit()
            || (bytes[i] == b'-' && bytes.get(i + 1).is_some_and(u8::is_ascii_digit));
        let after_word = i > 0 && (bytes[i - 1].is_ascii_alphabetic() || bytes[i - 1] == b'_');
        if starts && !after_word {
            let start = i;
            i += 1;
            while i < bytes.len()
                && matches!(bytes[i], b'0'..=b'9' | b'.' | b'e' | b'E' | b'-' | b'+')
            {
                i += 1;
            }
            numbers.push(start..i);
        } else {
            i += 1;
        }
    }
    if numbers.is_empty() {
        return None;
    }
    let range = numbers[rng.random_range(0..numbers.len())].clone();
    let extreme = EXTREMES[rng.random_range(0..EXTREMES.len())];
    let mut out = String::with_capacity(text.len() + 32);
    out.push_str(&text[..range.start]);
    out.push_str(extreme);
    out.push_str(&text[range.end..]);
    let what = format!(
        "number `{}` at byte {} → {extreme}",
        &text[range.clone()],
        range.start
    );
    Some((out.into_bytes(), what))
}

/// A structural change at a random place of a JSON value.
fn mutate_json(root: &mut Value, rng: &mut ChaCha8Rng) -> String {
    // Choose a random path down the tree (as a JSON pointer), stopping at random.
    let (mut pointer, mut path) = (String::new(), String::new());
    let mut node = &*root;
    while rng.random_bool(0.75) {
        let next = match node {
            Value::Object(o) if !o.is_empty() => {
                let k = o.keys().nth(rng.random_range(0..o.len())).unwrap();
                write!(pointer, "/{}", k.replace('~', "~0").replace('/', "~1")).unwrap();
                write!(path, ".{k}").unwrap();
                &o[k]
            }
            Value::Array(a) if !a.is_empty() => {
                let i = rng.random_range(0..a.len());
                write!(pointer, "/{i}").unwrap();
                write!(path, "[{i}]").unwrap();
                &a[i]
            }
            _ => break,
        };
        node = next;
    }
    let node = root.pointer_mut(&pointer).unwrap();
    let what = match node {
        Value::Object(o) if !o.is_empty() && rng.random_bool(0.5) => {
            let k = o.keys().nth(rng.random_range(0..o.len())).unwrap().clone();
            o.remove(&k);
            format!("field `{k}` removed")
        }
        Value::Object(o) => {
            o.insert("unexpected_field".into(), json!({"x": [1, 2]}));
            "an unknown field added".into()
        }
        Value::Array(a) if !a.is_empty() => match rng.random_range(0..3) {
            0 => {
                a.clear();
                "array emptied".into()
            }
            1 => {
                let x = a[0].clone();
                a.push(x);
                "first element appended again".into()
            }
            _ => {
                a.pop();
                "last element removed".into()
            }
        },
        other => leaf_change(other, rng),
    };
    format!("{path}: {what}")
}

fn leaf_change(v: &mut Value, rng: &mut ChaCha8Rng) -> String {
    let (new, what) = match rng.random_range(0..6) {
        0 => (Value::Null, "null"),
        1 => (json!("text"), "a string"),
        2 => (json!({"a": 1}), "an object"),
        3 => (json!([]), "an empty array"),
        4 => (json!(-0.0), "-0"),
        _ => (json!(u64::MAX), "u64::MAX"),
    };
    *v = new;
    format!("value → {what}")
}

// ---------------------------------------------------------------------------------------------
// The formats and their entry points

/// A small two-DoF arm with two SUs: fast to simulate, record and calibrate.
const ARM_TOML: &str = r#"name = "fuzz_arm"
reference = "base"

[[dofs]]
name = "shoulder"
child = "upper"
dh = { theta0 = 0.0, d = 0.1, a = 0.0, alpha = 1.5707963 }
lower = -2.5
upper = 2.5

[[dofs]]
name = "elbow"
child = "fore"
dh = { theta0 = 0.3, d = 0.0, a = 0.25, alpha = 0.0 }
lower = -2.0
upper = 2.0

[[sus]]
name = "upper_su"
segment = "upper"
xyz = [0.05, 0.02, 0.03]
rpy = [0.1, -0.2, 0.3]

[[sus]]
name = "fore_su"
segment = "fore"
xyz = [0.12, -0.01, 0.02]
rpy = [-0.3, 0.2, 0.1]
"#;

fn err(e: impl std::fmt::Display) -> String {
    e.to_string()
}

fn formats(work: &Path) -> Vec<Format> {
    let valid = work.join("valid");
    std::fs::create_dir_all(&valid).unwrap();
    let paper = presets::find("paper-7dof").unwrap().robot().unwrap();
    let sim = simulate(
        &paper,
        &SimulationConfig {
            poses: 12,
            ..SimulationConfig::default()
        },
    )
    .unwrap();
    let set = sim.measurements;
    let structure = explore(&set, &ExploreConfig::default()).unwrap();
    let config = MlConfig::default();
    let model = calibrate_body(&set, Some(&structure), &config, None).unwrap();
    let model_json = serde_json::to_string_pretty(&model).unwrap();
    let pose_csv =
        "dof1,dof2,dof3,dof4,dof5,dof6,dof7\n0.1,0.2,0.3,0.4,0.5,0.6,0.7\n-1,0,1,0,-1,0,1\n";
    let pose_json = r#"{"dofs": ["dof7", "dof6", "dof5", "dof4", "dof3", "dof2", "dof1"], "poses": [[0, 0, 0, 0, 0, 0, 0], [0.5, -0.5, 1, 2, -2, 0.1, 3]]}"#;

    // The small arm: its plan, and a short 100 Hz log of it in both log formats.
    let arm_path = valid.join("arm.toml");
    std::fs::write(&arm_path, ARM_TOML).unwrap();
    let arm = io::load_robot(arm_path.to_str().unwrap(), SuPlacement::default()).unwrap();
    let plan = Plan::new(
        PlanDof::from_robot(&arm),
        &PlanConfig {
            poses: 1,
            still: 0.5,
            settle: 0.2,
            ..PlanConfig::default()
        },
    )
    .unwrap();
    let plan_json = serde_json::to_string_pretty(&plan).unwrap();
    let log_config = LogConfig {
        rate: 100.0,
        ..LogConfig::default()
    };
    let csv_dir = valid.clone();
    let mut sink = CsvSink::new(&csv_dir, true);
    record(&arm, &plan, &log_config, &mut sink, &mut |_| {}).unwrap();
    let mcap_path = valid.join("log.mcap");
    let mut sink = McapSink::new(&mcap_path, Topics::default(), Compression::Zstd, true);
    record(&arm, &plan, &log_config, &mut sink, &mut |_| {}).unwrap();
    // The same log as a skin driver that publishes a batch per time step writes it, and in the
    // formats of rosbag2 (a directory, an SQLite file) and of ROS 1.
    let batches_path = valid.join("batches.mcap");
    let mut sink =
        McapSink::new(&batches_path, Topics::default(), Compression::None, true).batched();
    record(&arm, &plan, &log_config, &mut sink, &mut |_| {}).unwrap();
    let rosbag2_dir = valid.join("rosbag2");
    bags::rosbag2(&rosbag2_dir, &[&mcap_path]);
    let db3_path = valid.join("log.db3");
    bags::mcap_to_db3(&mcap_path, &db3_path);
    let (bag_path, bz2_path) = (valid.join("log.bag"), valid.join("bz2.bag"));
    bags::ros1_bags(&csv_dir, &[(&bag_path, "none"), (&bz2_path, "bz2")]);
    let urdf = std::fs::read(concat!(
        env!("CARGO_MANIFEST_DIR"),
        "/tests/fixtures/arm.urdf"
    ))
    .unwrap();
    // The fixture arm calibrated, for aligning mutated URDFs with it (`check-urdf`, `--into`).
    let urdf_model = {
        let robot = io::load_robot(
            concat!(env!("CARGO_MANIFEST_DIR"), "/tests/fixtures/arm.urdf"),
            SuPlacement::default(),
        )
        .unwrap();
        let set = simulate(&robot, &SimulationConfig::default())
            .unwrap()
            .measurements;
        let s = explore(&set, &ExploreConfig::default()).unwrap();
        calibrate_body(&set, Some(&s), &MlConfig::default(), None).unwrap()
    };

    let set_for_structure = set.clone();
    let set_for_model = set.clone();
    let model_for_poses = std::sync::Arc::new(model.clone());
    let model_for_json = std::sync::Arc::clone(&model_for_poses);
    let arm_for_plan = arm.clone();
    let pattern = plan.pattern;
    let ingest_log = move |path: &Path, deep: bool| -> Result<(), String> {
        let config = IngestConfig {
            pattern: Some(pattern),
            ..IngestConfig::default()
        };
        let ingested = ingest(&[path.to_path_buf()], &config, &mut |_, _, _| {}).map_err(err)?;
        let set = &ingested.measurements;
        if let Ok(s) = explore(set, &ExploreConfig::default()) {
            if deep && s.complete {
                let _ = calibrate_body(set, Some(&s), &MlConfig::default(), None);
            }
        }
        Ok(())
    };
    vec![
        Format {
            name: "measurement set",
            file: "measurements.json",
            kind: Kind::Json,
            valid: set.to_json().into_bytes(),
            beside: Vec::new(),
            run: Box::new(|path, deep| {
                let set = io::read_measurements(path).map_err(err)?;
                if let Ok(s) = explore(&set, &ExploreConfig::default()) {
                    let _ = serial_chains(&s);
                    if deep {
                        let _ = calibrate_body(&set, Some(&s), &MlConfig::default(), None);
                    }
                }
                Ok(())
            }),
        },
        Format {
            name: "structure",
            file: "structure.json",
            kind: Kind::Json,
            valid: serde_json::to_string_pretty(&structure)
                .unwrap()
                .into_bytes(),
            beside: Vec::new(),
            run: Box::new(move |path, deep| {
                let s = io::read_structure(path).map_err(err)?;
                let _ = limb_chains(&s);
                let _ = serial_chains(&s);
                if deep {
                    let _ =
                        calibrate_body(&set_for_structure, Some(&s), &MlConfig::default(), None);
                }
                Ok(())
            }),
        },
        Format {
            name: "model",
            file: "model.json",
            kind: Kind::Json,
            valid: model_json.into_bytes(),
            beside: Vec::new(),
            run: Box::new(move |path, _| {
                let model = io::read_model(path).map_err(err)?;
                let _ = skincal::predict::validate(&model, &set_for_model, "set");
                if let Ok(robot) = model.check() {
                    let _ = skincal::model::urdf::to_urdf(&robot);
                }
                if let Ok(predictor) = Predictor::new(&model) {
                    let q = vec![0.3; predictor.dofs().len()];
                    let _ = predictor.readings(&q, &model.pattern);
                }
                Ok(())
            }),
        },
        Format {
            name: "robot toml",
            file: "robot.toml",
            kind: Kind::Text,
            valid: ARM_TOML.as_bytes().to_vec(),
            beside: Vec::new(),
            run: Box::new(|path, deep| {
                let robot =
                    io::load_robot(path.to_str().unwrap(), SuPlacement::default()).map_err(err)?;
                let poses = if deep { 8 } else { 2 };
                let config = SimulationConfig {
                    poses,
                    imperfections: Imperfections::none(),
                    ..SimulationConfig::default()
                };
                if let Ok(sim) = simulate(&robot, &config) {
                    if let Ok(s) = explore(&sim.measurements, &ExploreConfig::default()) {
                        if deep && s.complete {
                            let set = &sim.measurements;
                            let _ = calibrate_body(set, Some(&s), &MlConfig::default(), None);
                        }
                    }
                }
                Ok(())
            }),
        },
        Format {
            name: "urdf",
            file: "robot.urdf",
            kind: Kind::Text,
            valid: urdf,
            beside: Vec::new(),
            run: Box::new(move |path, _| {
                if let Ok((text, alignment)) = io::read_urdf_alignment(&urdf_model, path) {
                    let _ = skincal::align::merge_sus(&alignment, &text, "skin_", false);
                }
                let robot =
                    io::load_robot(path.to_str().unwrap(), SuPlacement::default()).map_err(err)?;
                let config = SimulationConfig {
                    poses: 2,
                    ..SimulationConfig::default()
                };
                let _ = simulate(&robot, &config);
                let _ = skincal::model::urdf::to_urdf(&robot);
                Ok(())
            }),
        },
        Format {
            name: "poses csv",
            file: "poses.csv",
            kind: Kind::Text,
            valid: pose_csv.as_bytes().to_vec(),
            beside: Vec::new(),
            run: Box::new(move |path, _| {
                let table = io::read_poses(path).map_err(err)?;
                let predictor = Predictor::new(&model_for_poses).map_err(err)?;
                predictor
                    .predict(
                        &table,
                        &model_for_poses.pattern,
                        &path.display().to_string(),
                    )
                    .map_err(err)?;
                Ok(())
            }),
        },
        Format {
            name: "poses json",
            file: "poses.json",
            kind: Kind::Json,
            valid: pose_json.as_bytes().to_vec(),
            beside: Vec::new(),
            run: Box::new(move |path, _| {
                let table = io::read_poses(path).map_err(err)?;
                let predictor = Predictor::new(&model_for_json).map_err(err)?;
                predictor
                    .predict(&table, &model_for_json.pattern, &path.display().to_string())
                    .map_err(err)?;
                Ok(())
            }),
        },
        Format {
            name: "plan",
            file: "plan.json",
            kind: Kind::Json,
            valid: plan_json.into_bytes(),
            beside: Vec::new(),
            run: Box::new(move |path, deep| {
                let plan = io::read_plan(path).map_err(err)?;
                if deep {
                    let out = path.with_file_name("recorded");
                    let mut sink = CsvSink::new(&out, true);
                    let config = LogConfig {
                        rate: 100.0,
                        ..LogConfig::default()
                    };
                    let _ = record(&arm_for_plan, &plan, &config, &mut sink, &mut |_| {});
                }
                Ok(())
            }),
        },
        Format {
            name: "csv log imu",
            file: "imu.csv",
            kind: Kind::Text,
            valid: std::fs::read(csv_dir.join("imu.csv")).unwrap(),
            beside: vec![csv_dir.join("joint_states.csv")],
            run: Box::new(ingest_log),
        },
        Format {
            name: "csv log joints",
            file: "joint_states.csv",
            kind: Kind::Text,
            valid: std::fs::read(csv_dir.join("joint_states.csv")).unwrap(),
            beside: vec![csv_dir.join("imu.csv")],
            run: Box::new(ingest_log),
        },
        Format {
            name: "mcap log",
            file: "log.mcap",
            kind: Kind::Binary,
            valid: std::fs::read(&mcap_path).unwrap(),
            beside: Vec::new(),
            run: Box::new(ingest_log),
        },
        Format {
            name: "mcap raw",
            file: "raw.mcap",
            kind: Kind::Binary,
            valid: exposed(&mcap_path),
            beside: Vec::new(),
            run: Box::new(ingest_log),
        },
        Format {
            name: "mcap batches",
            file: "batches.mcap",
            kind: Kind::Binary,
            valid: exposed(&batches_path),
            beside: Vec::new(),
            run: Box::new(ingest_log),
        },
        Format {
            name: "rosbag2 yaml",
            file: "metadata.yaml",
            kind: Kind::Text,
            valid: std::fs::read(rosbag2_dir.join("metadata.yaml")).unwrap(),
            beside: vec![rosbag2_dir.join("bag_0.mcap")],
            run: Box::new(ingest_log),
        },
        Format {
            name: "rosbag2 db3",
            file: "log.db3",
            kind: Kind::Binary,
            valid: std::fs::read(&db3_path).unwrap(),
            beside: Vec::new(),
            run: Box::new(ingest_log),
        },
        Format {
            name: "ros1 bag",
            file: "log.bag",
            kind: Kind::Binary,
            valid: std::fs::read(&bag_path).unwrap(),
            beside: Vec::new(),
            run: Box::new(ingest_log),
        },
        Format {
            name: "ros1 bag bz2",
            file: "bz2.bag",
            kind: Kind::Binary,
            valid: std::fs::read(&bz2_path).unwrap(),
            beside: Vec::new(),
            run: Box::new(ingest_log),
        },
    ]
}

/// The MCAP log at `path` again, its chunks neither compressed nor checked by a CRC, so that
/// mutations reach the records and messages rather than the decompressor or the checksum.
fn exposed(path: &Path) -> Vec<u8> {
    let bytes = std::fs::read(path).unwrap();
    let mut out = std::io::Cursor::new(Vec::new());
    let mut writer = mcap::WriteOptions::new()
        .compression(None)
        .calculate_chunk_crcs(false)
        .calculate_data_section_crc(false)
        .calculate_summary_section_crc(false)
        .chunk_size(Some(16 << 10))
        .create(&mut out)
        .unwrap();
    for message in mcap::MessageStream::new(&bytes).unwrap() {
        writer.write(&message.unwrap()).unwrap();
    }
    writer.finish().unwrap();
    drop(writer);
    out.into_inner()
}

#[test]
fn the_mutations_change_the_file_and_repeat_with_the_seed() {
    // The harness itself: every mutation kind produces a different file, and a seed gives the
    // same sequence again (so a finding can be reproduced).
    let valid = br#"{"a": [1.5, 2, {"b": -3e2}], "c": "x"}"#.to_vec();
    let run = |seed| {
        let mut rng = ChaCha8Rng::seed_from_u64(seed);
        (0..200)
            .map(|_| mutate(&valid, Kind::Json, &mut rng))
            .collect::<Vec<_>>()
    };
    let a = run(7);
    assert_eq!(a, run(7));
    assert_ne!(a, run(8));
    let changed = a.iter().filter(|(b, _)| *b != valid).count();
    // A structural change can by chance restore a value (e.g. -0 for a -0), rarely.
    assert!(
        changed >= 190,
        "{changed} of 200 mutants differ from the file"
    );
    let (text, what) =
        replace_number(b"x = 12.5\ny = 3", &mut ChaCha8Rng::seed_from_u64(1)).unwrap();
    let text = String::from_utf8(text).unwrap();
    assert!(!text.contains("12.5") || !text.contains("= 3"), "{text}");
    assert!(what.starts_with("number"), "{what}");
}
