//! `skincal bench motion`: the time-domain fit on a simulated 1 kHz log — the motion record's
//! pass, the readings' fit and the refit on every sample, timed on a pool of `--threads`, with
//! the held-out accuracy of both fits against the simulator's robot.

use std::time::Instant;

use anyhow::{bail, Result};
use clap::Args;
use skincal::estimate::body::{calibrate_body, calibrate_body_on_motion, BodyModel};
use skincal::estimate::ml::MlConfig;
use skincal::explore::{explore, ExploreConfig};
use skincal::ingest::{ingest, motion::record_of, IngestConfig};
use skincal::log::mcap::{Compression, McapSink};
use skincal::log::Topics;
use skincal::measurements::MeasurementSet;
use skincal::model::Robot;
use skincal::motion::MotionRecord;
use skincal::predict::validate;
use skincal::sim::timeseries::{record, LogConfig};
use skincal::sim::{simulate, Imperfections, SimulationConfig};

use crate::logs::{bench_program, scratch};
use crate::out::{self, outln};

#[derive(Debug, Args)]
pub(crate) struct BenchMotionArgs {
    /// SUs on the robot (random, on the paper's 7-DoF arm).
    #[arg(long, default_value_t = 100)]
    sus: usize,
    /// Seconds of log (the paper's training program at 1 kHz, ±0.01 g noise).
    #[arg(long, default_value_t = 60.0)]
    seconds: f64,
    /// Threads of the fits (1: one core).
    #[arg(long, default_value_t = 1)]
    threads: usize,
    /// Print the table as JSON instead of text.
    #[arg(long)]
    json: bool,
}

pub(crate) fn bench_motion(args: BenchMotionArgs) -> Result<()> {
    if args.json {
        out::json_mode();
    }
    if args.sus == 0 || args.threads == 0 || !args.seconds.is_finite() || args.seconds <= 0.0 {
        bail!("--sus, --seconds and --threads must be positive");
    }
    let (robot, plan) = bench_program(args.sus, args.seconds)?;
    let scratch = scratch()?;
    let log = scratch.path().join("log.mcap");
    let mut sink = McapSink::new(&log, Topics::default(), Compression::Zstd, false);
    record(&robot, &plan, &LogConfig::default(), &mut sink, &mut |_| {})?;
    let config = IngestConfig::default();
    // Each stage's peak memory apart (the simulator's log is written to disk as it goes).
    crate::reset_peak_memory();
    let started = Instant::now();
    let mut ingested = ingest(std::slice::from_ref(&log), &config, &mut |_, _, _| {})?;
    let ingest_s = started.elapsed().as_secs_f64();
    let ingest_mb = (crate::peak_memory_mb(), crate::peak_heap_mb());
    crate::reset_peak_memory();
    let started = Instant::now();
    // As `skincal ingest` makes it, from what the measurement set's pass told of the joints.
    let Some(motion) = record_of(&mut ingested, &config, &mut |_, _, _| {})? else {
        bail!("the bench's log gave no motion record");
    };
    let set = ingested.measurements;
    let record_s = started.elapsed().as_secs_f64();
    let record_mb = (crate::peak_memory_mb(), crate::peak_heap_mb());
    crate::reset_peak_memory();
    let fits = Fits::of(&robot, &set, &motion, args.threads)?;
    let fits_mb = (crate::peak_memory_mb(), crate::peak_heap_mb());
    let held_out = simulate(
        &robot,
        &SimulationConfig {
            seed: 77,
            structure: false,
            imperfections: Imperfections::none(),
            ..SimulationConfig::default()
        },
    )?
    .measurements;
    let [r, s] = [&fits.readings, &fits.samples].map(|m| validate(m, &held_out, "held-out"));
    let (r, s) = (r?, s?);
    let blocks: usize = fits
        .samples
        .limbs
        .iter()
        .filter_map(|l| l.estimate.motion.as_ref().map(|m| m.blocks))
        .max()
        .unwrap_or(0);
    outln!(
        "The time-domain fit of a {:.0} s, 1 kHz log of paper-7dof with {} SUs ({} blocks of {} ms), \
         fits on {} thread(s); held-out: 30 noise-free poses, RMS m/s²",
        plan.duration,
        robot.model.sus().len(),
        motion.blocks(),
        motion.period * 1e3,
        args.threads
    );
    let row = Row {
        times: [ingest_s, record_s, fits.readings_s, fits.samples_s],
        blocks,
        held_out: [r.static_rms, r.dynamic_rms, s.static_rms, s.dynamic_rms],
        peaks: [ingest_mb, record_mb, fits_mb],
    };
    row.print();
    out::json(&serde_json::json!({
        "command": "bench motion",
        "seconds": plan.duration,
        "sus": robot.model.sus().len(),
        "blocks": motion.blocks(),
        "threads": args.threads,
        "ingest_s": ingest_s,
        "record_s": record_s,
        "readings_fit_s": fits.readings_s,
        "samples_fit_s": fits.samples_s,
        "held_out": {
            "readings": [r.static_rms, r.dynamic_rms],
            "samples": [s.static_rms, s.dynamic_rms],
        },
        "peak_mb": {
            "ingest": ingest_mb.0,
            "record": record_mb.0,
            "fits": fits_mb.0,
        },
        // null unless built with the `heap-count` feature.
        "peak_heap_mb": {
            "ingest": ingest_mb.1,
            "record": record_mb.1,
            "fits": fits_mb.1,
        },
    }));
    Ok(())
}

/// The two fits of the log, each timed on a pool of `threads`: on the readings alone, and on
/// every sample of the motion record (its time includes the readings' fit it starts from).
struct Fits {
    readings: BodyModel,
    readings_s: f64,
    samples: BodyModel,
    samples_s: f64,
}

impl Fits {
    fn of(
        robot: &Robot,
        set: &MeasurementSet,
        motion: &MotionRecord,
        threads: usize,
    ) -> Result<Self> {
        // The tree from the robot's own structure experiment (the log has none).
        let condensed = simulate(robot, &SimulationConfig::default())?.measurements;
        let structure = explore(&condensed, &ExploreConfig::default())?;
        let pool = rayon::ThreadPoolBuilder::new()
            .num_threads(threads)
            .build()?;
        let ml = MlConfig::default();
        pool.install(|| -> Result<_> {
            let started = Instant::now();
            let readings = calibrate_body(set, Some(&structure), &ml, None)?;
            let readings_s = started.elapsed().as_secs_f64();
            let started = Instant::now();
            let samples = calibrate_body_on_motion(
                set,
                motion,
                Some(&structure),
                &ml,
                None,
                &[],
                &mut |_, _, _| {},
            )?;
            Ok(Self {
                readings,
                readings_s,
                samples,
                samples_s: started.elapsed().as_secs_f64(),
            })
        })
    }
}

/// The table's one row: ingest, record, readings' fit and samples' fit times (s), the blocks
/// fitted, the held-out static and dynamic RMS of both fits (m/s²) and the peak memory (MB) of
/// the ingest, the record's pass and the fits: each stage's peak resident memory (what the
/// stages before it left included, and what the allocator keeps of their freed memory), and the
/// most it allocated at once beyond what was allocated when it started (its own heap: for the
/// fits, what they need beyond the record and the readings they are given; counted only in a
/// build with the `heap-count` feature).
struct Row {
    times: [f64; 4],
    blocks: usize,
    held_out: [f64; 4],
    peaks: [(f64, Option<f64>); 3],
}

impl Row {
    fn print(&self) {
        outln!(
            "{:>10} {:>10} {:>12} {:>12} {:>10} {:>14} {:>14} {:>14} {:>14} {:>10} {:>10} {:>8} {:>12} {:>12} {:>10}",
            "ingest s",
            "record s",
            "readings s",
            "samples s",
            "fitted",
            "readings stat",
            "readings dyn",
            "samples stat",
            "samples dyn",
            "ingest MB",
            "record MB",
            "fits MB",
            "ingest heap",
            "record heap",
            "fits heap"
        );
        let [ingest, record, readings, samples] = self.times;
        let [rs, rd, ss, sd] = self.held_out;
        let heap = self
            .peaks
            .map(|(_, heap)| heap.map_or("-".to_string(), |mb| format!("{mb:.0}")));
        outln!(
            "{:>10.2} {:>10.2} {:>12.2} {:>12.2} {:>10} {:>14.4} {:>14.4} {:>14.4} {:>14.4} {:>10.0} {:>10.0} {:>8.0} {:>12} {:>12} {:>10}",
            ingest,
            record,
            readings,
            samples,
            self.blocks,
            rs,
            rd,
            ss,
            sd,
            self.peaks[0].0,
            self.peaks[1].0,
            self.peaks[2].0,
            heap[0],
            heap[1],
            heap[2]
        );
        if self.peaks.iter().all(|(_, heap)| heap.is_none()) {
            outln!("(the heap peaks are counted in a build with `--features heap-count`)");
        }
    }
}
