//! What a plan can be expected to reach, before the robot runs it.
//!
//! The forecast runs the plan on the robot's description (which must place SUs) in two steps:
//!
//! 1. **Per-reading noise.** One training pose of the plan's protocol, one DoF at a time, is
//!    recorded as a 1 kHz log with the sensor's sample noise and ingested: the standard deviations
//!    ingest gives its static and dynamic readings (from the samples, through the same window fits
//!    it uses on real logs) are the noise of one reading.
//! 2. **Calibration at the plan's poses.** The exact readings at the plan's training poses, with
//!    that noise drawn `trials` times, are calibrated with the description's tree and compared with
//!    a noise-free held-out set of 20 random poses; the forecast is the RMS over the trials.
//!
//! [`poses_for`] adds training poses until the forecast meets a target (`plan --accuracy`).
//!
//! A continuous program ([`PlanConfig::continuous`]) has no poses: [`forecast_sweep`] records its
//! sweep once and calibrates the description from that log's motion alone.

use std::collections::BTreeMap;

use nalgebra::Vector3;
use rand::SeedableRng;
use rand_chacha::ChaCha8Rng;
use rand_distr::{Distribution, Normal};

use crate::estimate::body::{calibrate_body, calibrate_body_on_motion};
use crate::estimate::ml::MlConfig;
use crate::estimate::EstimateError;
use crate::explore::{explore, ExploreConfig, ExploreError, Structure};
use crate::ingest::motion::motion_record_from;
use crate::ingest::{ingest_from, IngestConfig, IngestError};
use crate::log::{LogSource, MemoryLog};
use crate::measurements::{MeasurementSet, TrainingExperiment, TrainingPose};
use crate::model::sensor::{gravity_upright, peak_dynamic_accelerations, static_readings};
use crate::model::{DofKind, Robot};
use crate::plan::{Clearance, Part, PartlyMeasured, Plan, PlanConfig, PlanDof, PlanError};
pub use crate::plan::{DofForecast, Forecast, OffNoise, ReadingNoise};
use crate::predict::{validate, PredictError};
use crate::sim::timeseries::{record, LogConfig, RecordError};
use crate::sim::{simulate, Imperfections, SimulationConfig, SimulationError};

/// Why no forecast could be made.
#[derive(Debug, thiserror::Error)]
#[non_exhaustive]
pub enum DesignError {
    /// The description places no SU: there is nothing to calibrate.
    #[error(
        "the robot description places no SU, so the accuracy cannot be forecast (a URDF without \
         skin: give a description with SUs, e.g. one `skincal simulate --robot … --sus-per-link` \
         wrote)"
    )]
    NoSus,
    /// Simulating the description failed.
    #[error("forecast: simulating {what}: {source}")]
    Simulate {
        /// What was simulated.
        what: &'static str,
        /// Why.
        #[source]
        source: SimulationError,
    },
    /// Recording the plan as a log failed.
    #[error("forecast: recording {what}: {source}")]
    Record {
        /// What was recorded.
        what: &'static str,
        /// Why.
        #[source]
        source: RecordError,
    },
    /// Reading the recorded log failed.
    #[error("forecast: {what}: {source}")]
    Ingest {
        /// What was read.
        what: &'static str,
        /// Why.
        #[source]
        source: IngestError,
    },
    /// Exploring the simulated structure experiment failed.
    #[error("forecast: exploring the description: {0}")]
    Explore(#[source] ExploreError),
    /// Calibrating on the forecast's readings failed.
    #[error("forecast: {what}: {source}")]
    Calibrate {
        /// From what.
        what: &'static str,
        /// Why.
        #[source]
        source: EstimateError,
    },
    /// Predicting the held-out poses failed.
    #[error("forecast: predicting the held-out poses: {0}")]
    Predict(#[source] PredictError),
    /// A step gave less than the forecast needs (the message says what).
    #[error("forecast: {0}")]
    Incomplete(&'static str),
    /// The plan itself.
    #[error(transparent)]
    Plan(#[from] PlanError),
}

/// The sensor the forecast assumes: `Imperfections` of one sample.
fn sensor(sample_sd: Option<f64>) -> Imperfections {
    match sample_sd {
        Some(sd) => Imperfections {
            uniform_noise: 0.0,
            gaussian_noise: sd / crate::model::sensor::STANDARD_GRAVITY,
            ..Imperfections::none()
        },
        None => Imperfections::default(),
    }
}

/// The standard deviation per axis of one sample of `imperfections`, m/s².
fn per_sample_sd(imperfections: &Imperfections) -> f64 {
    let g = crate::model::sensor::STANDARD_GRAVITY;
    (imperfections.uniform_noise.powi(2) / 3.0 + imperfections.gaussian_noise.powi(2)).sqrt() * g
}

/// `plan` (its training part alone, with `part`) recorded as a 1 kHz log of `robot` with
/// `imperfections`, in memory; `what` names it in an error.
fn recorded(
    robot: &Robot,
    plan: &Plan,
    part: Option<Part>,
    imperfections: &Imperfections,
    what: &'static str,
) -> Result<LogSource, DesignError> {
    let config = LogConfig {
        imperfections: *imperfections,
        part,
        ..LogConfig::default()
    };
    let mut log = MemoryLog::new(what);
    record(robot, plan, &config, &mut log, &mut |_| {})
        .map_err(|source| DesignError::Record { what, source })?;
    Ok(LogSource::Memory(log))
}

/// The noise of one reading under `plan`'s protocol with samples of `sample_sd` m/s² per axis
/// (the simulator's uniform ±0.01 g when `None`): one training pose recorded and ingested.
pub fn reading_noise(
    robot: &Robot,
    plan: &Plan,
    sample_sd: Option<f64>,
) -> Result<ReadingNoise, DesignError> {
    if robot.model.sus().is_empty() {
        return Err(DesignError::NoSus);
    }
    let one = Plan::new(
        plan.dofs.clone(),
        &PlanConfig {
            structure: false,
            poses: 1,
            parallel: false,
            pattern: Some(plan.pattern),
            ..plan.config.clone()
        },
    )?;
    let imperfections = sensor(sample_sd);
    let log = recorded(
        robot,
        &one,
        Some(Part::Training),
        &imperfections,
        "one pose",
    )?;
    let ingest_config = IngestConfig::default().with_plan(plan);
    let ingested = ingest_from(
        std::slice::from_ref(&log),
        &ingest_config,
        &mut |_, _, _| {},
    )
    .map_err(|source| DesignError::Ingest {
        what: "ingesting one recorded pose",
        source,
    })?;
    let pose = ingested
        .measurements
        .training
        .as_ref()
        .and_then(|t| t.poses.first())
        .ok_or(DesignError::Incomplete(
            "one recorded pose gave no training pose",
        ))?;
    let rms = |v: &mut dyn Iterator<Item = f64>| {
        let (sum, n) = v.fold((0.0, 0usize), |(s, n), x| (s + x * x, n + 1));
        (n > 0).then(|| (sum / n as f64).sqrt())
    };
    let missing = || DesignError::Incomplete("ingest gave no reading uncertainty");
    let static_sd = rms(&mut pose.static_sd.iter().flatten().copied()).ok_or_else(missing)?;
    let dynamic_sd = rms(&mut pose.dynamic_sd.values().flatten().copied()).ok_or_else(missing)?;
    Ok(ReadingNoise {
        static_sd,
        dynamic_sd,
        sample_sd: per_sample_sd(&imperfections),
    })
}

/// What every forecast of one robot compares with: the description's tree and its structure
/// experiment (from a noise-free simulation) and a noise-free held-out set of 20 random poses.
/// Built once per search, whatever the number of plans forecast.
pub struct Reference {
    structure: Structure,
    explored: MeasurementSet,
    held_out: MeasurementSet,
}

impl Reference {
    /// The reference of `robot` (which must place SUs).
    pub fn of(robot: &Robot) -> Result<Reference, DesignError> {
        if robot.model.sus().is_empty() {
            return Err(DesignError::NoSus);
        }
        let simulated = |config: SimulationConfig, what: &'static str| {
            simulate(robot, &config)
                .map(|s| s.measurements)
                .map_err(|source| DesignError::Simulate { what, source })
        };
        // A slide turns no gravity and a mimic DoF's body is told apart by the poses: their
        // columns and bodies come from the training part.
        let model = &robot.model;
        let training_tells = (0..model.dofs().len())
            .any(|d| model.dofs()[d].kind == DofKind::Prismatic || model.is_follower(d));
        let explored = simulated(
            SimulationConfig {
                training: training_tells,
                imperfections: Imperfections::none(),
                ..SimulationConfig::default()
            },
            "the structure part",
        )?;
        let structure =
            explore(&explored, &ExploreConfig::default()).map_err(DesignError::Explore)?;
        if !structure.complete {
            return Err(DesignError::Incomplete(
                "exploring the description does not give its whole tree",
            ));
        }
        let held_out = simulated(
            SimulationConfig {
                structure: false,
                imperfections: Imperfections::none(),
                seed: HELD_OUT_SEED,
                ..SimulationConfig::default()
            },
            "the held-out poses",
        )?;
        Ok(Reference {
            structure,
            explored,
            held_out,
        })
    }

    /// A measurement set of the description with its structure part and no training: its DoFs
    /// and SUs, which DoFs slide and which follow another (without them a slide would be
    /// fitted as a hinge), for the readings of a program to be added to.
    fn described(&self) -> MeasurementSet {
        MeasurementSet {
            training: None,
            ..self.explored.clone()
        }
    }
}

/// The exact readings at one pose: static per SU, dynamic per DoF and SU.
struct Exact {
    static_readings: Vec<Vector3<f64>>,
    dynamic: Vec<Vec<Vector3<f64>>>,
}

impl Exact {
    fn at(robot: &Robot, plan: &Plan, q: &[f64], gravity: &Vector3<f64>) -> Exact {
        let (model, p) = (&robot.model, &robot.parameters);
        Exact {
            static_readings: static_readings(model, p, q, gravity),
            dynamic: (0..model.dofs().len())
                .map(|d| peak_dynamic_accelerations(model, p, q, d, &plan.pattern))
                .collect(),
        }
    }

    /// A training pose of these readings with Gaussian noise of `noise` drawn from `rng`.
    fn drawn(
        &self,
        robot: &Robot,
        q: &[f64],
        noise: &ReadingNoise,
        rng: &mut ChaCha8Rng,
    ) -> TrainingPose {
        let nu = self.static_readings.len();
        let mut draw = |sd: f64, v: &Vector3<f64>| -> [f64; 3] {
            let normal = Normal::new(0.0, sd).unwrap_or_else(|_| Normal::new(0.0, 0.0).unwrap());
            [0, 1, 2].map(|k| v[k] + normal.sample(rng))
        };
        let names = robot.model.dof_names();
        let dynamic: BTreeMap<String, Vec<[f64; 3]>> = names
            .iter()
            .zip(&self.dynamic)
            .map(|(name, r)| {
                let drawn = r.iter().map(|v| draw(noise.dynamic_sd, v)).collect();
                (name.clone(), drawn)
            })
            .collect();
        TrainingPose {
            q: q.to_vec(),
            static_readings: self
                .static_readings
                .iter()
                .map(|v| draw(noise.static_sd, v))
                .collect(),
            dynamic_sd: names
                .into_iter()
                .map(|k| (k, vec![noise.dynamic_sd; nu]))
                .collect(),
            dynamic,
            static_sd: Some(vec![noise.static_sd; nu]),
            orientation: 0,
            extra: Default::default(),
        }
    }
}

/// Seed of the held-out poses.
const HELD_OUT_SEED: u64 = 99;

/// The expected held-out RMS of a calibration from `plan`'s training poses with readings of
/// `noise`, over `trials` noise draws, against `reference` ([`Reference::of`] the same robot).
pub fn forecast(
    robot: &Robot,
    reference: &Reference,
    plan: &Plan,
    noise: &ReadingNoise,
    trials: usize,
) -> Result<Forecast, DesignError> {
    // The plan's poses upright, then the first `tilted_poses` of them again with the base tilted
    // (base orientation 1, as ingest numbers the tilted run's poses).
    let upright = plan.training_poses();
    let tilted = upright.len().min(plan.config.tilted_poses);
    let tilted_gravity = Vector3::from(crate::sim::BaseOrientation::tilted().gravity);
    let poses: Vec<(&Vec<f64>, usize)> = upright
        .iter()
        .map(|q| (q, 0))
        .chain(upright[..tilted].iter().map(|q| (q, 1)))
        .collect();
    let exact: Vec<Exact> = poses
        .iter()
        .map(|&(q, o)| {
            let g = if o == 0 {
                gravity_upright()
            } else {
                tilted_gravity
            };
            Exact::at(robot, plan, q, &g)
        })
        .collect();
    let (mut static_ss, mut dynamic_ss) = (0.0, 0.0);
    let mut dof_ss: BTreeMap<String, f64> = BTreeMap::new();
    let mut partly_measured = Vec::new();
    let mut off_noise = Vec::new();
    for trial in 0..trials.max(1) {
        let mut rng = ChaCha8Rng::seed_from_u64(trial as u64);
        let mut set = reference.described();
        set.training = Some(TrainingExperiment {
            from_motion: false,
            pattern: plan.pattern,
            poses: poses
                .iter()
                .zip(&exact)
                .map(|(&(q, orientation), e)| TrainingPose {
                    orientation,
                    ..e.drawn(robot, q, noise, &mut rng)
                })
                .collect(),
            extra: Default::default(),
        });
        let calibrated =
            calibrate_body(&set, Some(&reference.structure), &MlConfig::default(), None).map_err(
                |source| DesignError::Calibrate {
                    what: "calibrating the plan's poses",
                    source,
                },
            )?;
        let check =
            validate(&calibrated, &reference.held_out, "held-out").map_err(DesignError::Predict)?;
        static_ss += check.static_rms.powi(2);
        dynamic_ss += check.dynamic_rms.powi(2);
        for (dof, ss) in dof_squares(&check) {
            *dof_ss.entry(dof).or_default() += ss;
        }
        if trial == 0 {
            partly_measured = partly_measured_in(&calibrated);
        }
        off_noise_in(&calibrated, &mut off_noise);
    }
    let n = trials.max(1) as f64;
    Ok(Forecast {
        poses: upright.len(),
        static_rms: (static_ss / n).sqrt(),
        dynamic_rms: (dynamic_ss / n).sqrt(),
        noise: noise.clone(),
        trials: trials.max(1),
        held_out: reference.held_out.summary().training_poses,
        partly_measured,
        dofs: dof_forecasts(robot, &dof_ss, n),
        off_noise,
    })
}

/// Adds the limbs of `model` whose fit ended off the noise level to `off`: one more draw each,
/// and the larger residual.
fn off_noise_in(model: &crate::estimate::body::BodyModel, off: &mut Vec<OffNoise>) {
    for limb in model.limbs.iter().filter(|l| !l.estimate.converged) {
        let residual = limb.estimate.residual_ratio;
        match off.iter_mut().find(|o| o.limb == limb.name) {
            Some(o) => {
                o.draws += 1;
                o.residual = o.residual.max(residual);
            }
            None => off.push(OffNoise {
                limb: limb.name.clone(),
                draws: 1,
                residual,
            }),
        }
    }
}

/// Each DoF's dynamic RMS error squared in `check`.
fn dof_squares(check: &crate::predict::Validation) -> BTreeMap<String, f64> {
    check
        .dofs
        .iter()
        .map(|d| (d.dof.clone(), d.dynamic_rms.powi(2)))
        .collect()
}

/// Per DoF of `robot` (its order) with a sum in `squares` (of its dynamic RMS errors squared over
/// `draws` draws): the RMS over the draws.
fn dof_forecasts(robot: &Robot, squares: &BTreeMap<String, f64>, draws: f64) -> Vec<DofForecast> {
    robot
        .model
        .dof_names()
        .into_iter()
        .filter_map(|dof| {
            let ss = squares.get(&dof)?;
            Some(DofForecast {
                dynamic_rms: (ss / draws).sqrt(),
                dof,
            })
        })
        .collect()
}

/// The SUs of `model` whose pose some direction of no reading determines.
fn partly_measured_in(model: &crate::estimate::body::BodyModel) -> Vec<PartlyMeasured> {
    model
        .limbs
        .iter()
        .flat_map(|l| &l.estimate.uncertainty)
        .filter(|u| u.is_partial())
        .map(|u| PartlyMeasured {
            su: u.su.clone(),
            positions: u.undetermined_position.len(),
            turns: u.undetermined_orientation.len(),
        })
        .collect()
}

/// The forecast of `plan` as it is (its poses, or its sweep: [`forecast_sweep`]), stored in its
/// `forecast`.
pub fn forecast_plan(
    robot: &Robot,
    plan: &mut Plan,
    sample_sd: Option<f64>,
) -> Result<(), DesignError> {
    let f = if plan.config.sweep > 0.0 {
        forecast_sweep(robot, &Reference::of(robot)?, plan, sample_sd)?
    } else {
        let noise = reading_noise(robot, plan, sample_sd)?;
        forecast(robot, &Reference::of(robot)?, plan, &noise, TRIALS)?
    };
    plan.forecast = Some(f);
    Ok(())
}

/// The expected held-out RMS of a calibration from a continuous program's sweep: the program
/// recorded once (upright, structure part and sweep) as a 1 kHz log of the description with samples of `sample_sd` m/s² per axis
/// (the simulator's uniform ±0.01 g when `None`), its motion record calibrated with the
/// description's tree from the record alone (as `calibrate` does with such a log), and compared
/// with `reference`'s held-out poses. The noise it reports is a block mean's.
pub fn forecast_sweep(
    robot: &Robot,
    reference: &Reference,
    plan: &Plan,
    sample_sd: Option<f64>,
) -> Result<Forecast, DesignError> {
    if robot.model.sus().is_empty() {
        return Err(DesignError::NoSus);
    }
    let imperfections = sensor(sample_sd);
    // The whole upright log, as the robot records it: the structure part's still periods are
    // the quiet moments the fit starts from.
    let log = recorded(robot, plan, None, &imperfections, "the program")?;
    let (dofs, sus) = (robot.model.dof_names(), robot.model.su_names());
    let motion = motion_record_from(
        std::slice::from_ref(&log),
        &dofs,
        &sus,
        &IngestConfig::default(),
        &mut |_, _, _| {},
    )
    .map_err(|source| DesignError::Ingest {
        what: "reading the recorded sweep",
        source,
    })?;
    let set = reference.described();
    let calibrated = calibrate_body_on_motion(
        &set,
        &motion,
        Some(&reference.structure),
        &MlConfig::default(),
        None,
        &[],
        &mut |_, _, _| {},
    )
    .map_err(|source| DesignError::Calibrate {
        what: "calibrating from the sweep",
        source,
    })?;
    let check =
        validate(&calibrated, &reference.held_out, "held-out").map_err(DesignError::Predict)?;
    let block: Vec<f64> = motion.noise_sd.iter().flatten().copied().collect();
    let block_sd = (block.iter().map(|s| s * s).sum::<f64>() / block.len().max(1) as f64).sqrt();
    Ok(Forecast {
        poses: 0,
        static_rms: check.static_rms,
        dynamic_rms: check.dynamic_rms,
        noise: ReadingNoise {
            static_sd: block_sd,
            dynamic_sd: block_sd,
            sample_sd: per_sample_sd(&imperfections),
        },
        trials: 1,
        held_out: reference.held_out.summary().training_poses,
        partly_measured: partly_measured_in(&calibrated),
        dofs: dof_forecasts(robot, &dof_squares(&check), 1.0),
        off_noise: {
            let mut off = Vec::new();
            off_noise_in(&calibrated, &mut off);
            off
        },
    })
}

/// The held-out RMS, m/s², that the short protocol plans for when no number of poses is given
/// (`plan --accuracy`).
pub const SHORT_ACCURACY: f64 = 0.009;

/// Noise draws per forecast.
pub const TRIALS: usize = 8;
/// Where [`poses_for`] aims when it adds poses, as a fraction of the target.
const AIM: f64 = 0.9;
/// The most training poses [`poses_for`] tries.
pub const MAX_POSES: usize = 60;

/// Pose draws tried for each number of poses (seeds `config.seed` on).
pub const CANDIDATES: usize = 4;

/// Of [`CANDIDATES`] draws of `config.poses` training poses, the plan with the best forecast.
/// Random poses differ: six drawn for the humanoid forecast 0.010–0.015 m/s², and one draw
/// 0.34 (a pose set that leaves a limb's kinematics open).
pub fn best_draw(
    robot: &Robot,
    reference: &Reference,
    dofs: &[PlanDof],
    config: &PlanConfig,
    noise: &ReadingNoise,
    clearance: Option<&(dyn Clearance + Sync)>,
) -> Result<(Plan, Forecast), DesignError> {
    use rayon::prelude::*;
    let tried: Vec<(Plan, Forecast)> = (0..CANDIDATES as u64)
        .into_par_iter()
        .map(|k| {
            let plan = Plan::new_clear(
                dofs.to_vec(),
                &PlanConfig {
                    seed: config.seed.wrapping_add(k),
                    ..config.clone()
                },
                clearance.map(|c| c as &dyn Clearance),
            )?;
            let f = forecast(robot, reference, &plan, noise, TRIALS)?;
            Ok((plan, f))
        })
        .collect::<Result<_, DesignError>>()?;
    tried
        .into_iter()
        .min_by(|a, b| a.1.worst().total_cmp(&b.1.worst()))
        .ok_or(DesignError::Incomplete("no pose draw tried"))
}

/// What [`poses_for`] and [`sweep_for`] are doing, for a caller that shows it: a program about
/// to be forecast (each step calibrates it on the description several times, minutes on a robot
/// of many DoFs), then its forecast.
#[derive(Debug, Clone, Copy)]
pub enum DesignStep<'a> {
    /// This program is being forecast.
    Trying(&'a PlanConfig),
    /// Its forecast.
    Forecast(&'a PlanConfig, &'a Forecast),
}

/// The plan with the fewest training poses (from `config.poses` up, at most [`MAX_POSES`]) whose
/// forecast meets `target` m/s² RMS, static and dynamic, each the best of [`CANDIDATES`] pose
/// draws, with its forecast (also in the plan's `forecast`); the largest tried when none does.
/// `progress` is told each step ([`DesignStep`]).
pub fn poses_for(
    robot: &Robot,
    dofs: &[PlanDof],
    config: &PlanConfig,
    (target, sample_sd): (f64, Option<f64>),
    clearance: Option<&(dyn Clearance + Sync)>,
    progress: &mut dyn FnMut(DesignStep<'_>),
) -> Result<(Plan, Forecast), DesignError> {
    let mut poses = config.poses.max(1);
    let noise = reading_noise(robot, &Plan::new(dofs.to_vec(), config)?, sample_sd)?;
    let reference = Reference::of(robot)?;
    loop {
        let config = PlanConfig {
            poses,
            ..config.clone()
        };
        progress(DesignStep::Trying(&config));
        let (mut plan, f) = best_draw(robot, &reference, dofs, &config, &noise, clearance)?;
        progress(DesignStep::Forecast(&config, &f));
        if f.worst() <= target || poses >= MAX_POSES {
            plan.forecast = Some(f.clone());
            return Ok((plan, f));
        }
        // The error falls as 1/√P. One recording scatters around the forecast (the humanoid's
        // 8-pose program: 0.0065–0.0104 m/s² over five recordings against a forecast of 0.0073),
        // so the added poses aim a tenth below the target: at least one pose more, at most half
        // as many again.
        let wanted = (poses as f64 * (f.worst() / (AIM * target)).powi(2)).ceil() as usize;
        poses = wanted.clamp(poses + 1, (poses * 3 / 2).max(poses + 1).min(MAX_POSES));
    }
}

/// The longest sweep [`sweep_for`] tries, s.
pub const MAX_SWEEP: f64 = 240.0;

/// The continuous program with the shortest sweep (from `config.sweep` up, at most
/// [`MAX_SWEEP`] s) whose forecast ([`forecast_sweep`]) meets `target` m/s² RMS, static and
/// dynamic, with its forecast (also in the plan's `forecast`); the longest tried when none does.
/// `progress` is told each step ([`DesignStep`]).
pub fn sweep_for(
    robot: &Robot,
    dofs: &[PlanDof],
    config: &PlanConfig,
    (target, sample_sd): (f64, Option<f64>),
    clearance: Option<&(dyn Clearance + Sync)>,
    progress: &mut dyn FnMut(DesignStep<'_>),
) -> Result<(Plan, Forecast), DesignError> {
    let reference = Reference::of(robot)?;
    let mut sweep = config.sweep.max(1.0);
    loop {
        let config = PlanConfig {
            sweep,
            ..config.clone()
        };
        progress(DesignStep::Trying(&config));
        let mut plan = Plan::new_clear(
            dofs.to_vec(),
            &config,
            clearance.map(|c| c as &dyn Clearance),
        )?;
        let f = forecast_sweep(robot, &reference, &plan, sample_sd)?;
        progress(DesignStep::Forecast(&config, &f));
        plan.forecast = Some(f.clone());
        if f.worst() <= target || sweep >= MAX_SWEEP {
            return Ok((plan, f));
        }
        // The error falls about as 1/√T, faster where a longer sweep also reaches further: aim a
        // tenth below the target, a quarter longer at least, twice as long at most.
        let factor = (f.worst() / (AIM * target)).powi(2).clamp(1.25, 2.0);
        sweep = (sweep * factor).ceil().min(MAX_SWEEP);
    }
}
