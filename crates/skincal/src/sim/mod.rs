//! Simulated experiments: what a robot with a known geometry would record.
//!
//! * **Structure experiment** (paper II-B.1): in each base orientation, a rest pose and, for every
//!   DoF, a static pose with only that DoF moved by [`SimulationConfig::structure_angle`] (towards
//!   the side its limits allow). By default it is repeated with the reference segment tilted 90°
//!   about its horizontal x axis, the paper's remedy for vertical DoF axes.
//! * **Training experiment** (paper II-C.2): `P` random poses, each DoF uniform in
//!   `±pose_range ∩ [lower, upper]`; in each pose every SU's static reading and, for every DoF, every
//!   SU's dynamic acceleration at the peak of the excitation pattern (eqs. 10–12).
//! * **Imperfections**, all seeded: uniform noise (the paper's ±0.01 g), Gaussian noise, each SU's
//!   accelerometer intrinsics (a constant bias, a scale error and misalignments per axis, see
//!   [`crate::model::intrinsics`]), saturation and quantisation (10 bit over ±2 g, the paper's
//!   BMA150). A static reading is `sense(K·f + b) + n`; a dynamic acceleration is what remains of
//!   the sensed peak reading after subtracting the sensed static one,
//!   `sense(K·(f + a) + b) − sense(K·f + b) + n`, so a constant bias cancels in it while
//!   saturation and quantisation act on the whole signal, as on a real sensor. Without saturation
//!   and quantisation `sense` is the identity.
//!
//! Random streams are separate for poses, noise, biases and scales, so changing the noise level
//! keeps the poses; [`SimulationConfig::pose_seed`] draws poses and noise anew for the same skin
//! (a held-out set). The ground truth (the robot, the gravity of every orientation, the
//! intrinsics) goes to a separate [`Truth`]; the measurement set never contains it.

use std::f64::consts::PI;

use nalgebra::{UnitQuaternion, Vector3};
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use rand_distr::{Distribution, Normal};
use serde::{Deserialize, Serialize};
use serde_json::{json, Map};

use crate::measurements::{
    MeasurementSet, Move, Orientation, Reading, StructureExperiment, TrainingExperiment,
    TrainingPose,
};
use crate::model::description::RobotFile;
use crate::model::intrinsics::Intrinsics;
use crate::model::sensor::{
    gravity_upright, peak_dynamic_accelerations_at, specific_force, ExcitationPattern, MAX_READING,
    STANDARD_GRAVITY,
};
use crate::model::{forward_kinematics, DofKind, Robot};
use crate::plan::pose_stream;
pub use crate::plan::structure_move;

pub mod changes;
mod robot_like;
pub mod timeseries;

pub use robot_like::{robot_like_limb, snake, RobotLikeConfig};

/// The largest noise or bias the simulator accepts, g.
pub const MAX_IMPERFECTION: f64 = 10.0;
/// The largest relative scale error the simulator accepts.
pub const MAX_SCALE_ERROR: f64 = 0.5;
/// The largest axis misalignment the simulator accepts, rad (about 17°).
pub const MAX_MISALIGNMENT: f64 = 0.3;

/// Sensor imperfections, in units of g (9.81 m/s²).
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct Imperfections {
    /// Half-width of uniform noise on every component, g (paper: 0.01).
    pub uniform_noise: f64,
    /// Standard deviation of Gaussian noise on every component, g.
    pub gaussian_noise: f64,
    /// Half-width of the uniform distribution of each SU's constant bias per axis, g.
    pub bias: f64,
    /// Half-width of the uniform distribution of each SU's relative scale error per axis
    /// (0.03: ±3 %).
    #[serde(default)]
    pub scale: f64,
    /// Half-width of the uniform distribution of each SU's 3 axis misalignments, rad.
    #[serde(default)]
    pub misalignment: f64,
    /// Fraction of all readings (structure and training, static and dynamic) replaced by a
    /// glitch: a random vector of 0.2–1.5 g in a random direction.
    #[serde(default)]
    pub glitches: f64,
    /// Saturation of every axis at ±this, g.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub saturation: Option<f64>,
    /// Quantisation to this many bits over ±`saturation` (saturation defaults to 2 g with it).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub quantization_bits: Option<u32>,
}

impl Default for Imperfections {
    /// The paper's: uniform ±0.01 g, nothing else.
    fn default() -> Self {
        Self {
            uniform_noise: 0.01,
            gaussian_noise: 0.0,
            bias: 0.0,
            scale: 0.0,
            misalignment: 0.0,
            glitches: 0.0,
            saturation: None,
            quantization_bits: None,
        }
    }
}

impl Imperfections {
    /// No imperfection at all.
    pub fn none() -> Self {
        Self {
            uniform_noise: 0.0,
            ..Self::default()
        }
    }

    /// The paper's BMA150 on top of these: 10-bit quantisation over ±2 g.
    pub fn with_bma150(self) -> Self {
        Self {
            saturation: Some(2.0),
            quantization_bits: Some(10),
            ..self
        }
    }

    /// Checks every setting.
    pub fn validate(&self) -> Result<(), SimulationError> {
        let i = self;
        let bad =
            |setting, reason: String| Err(SimulationError::InvalidSetting { setting, reason });
        for (setting, v) in [
            ("noise", i.uniform_noise),
            ("gaussian_noise", i.gaussian_noise),
            ("bias", i.bias),
        ] {
            if !(0.0..=MAX_IMPERFECTION).contains(&v) {
                return bad(
                    setting,
                    format!(
                        "{} g must lie in 0…{MAX_IMPERFECTION} g (no accelerometer errs by more)",
                        crate::show::number(v)
                    ),
                );
            }
        }
        if !(0.0..=MAX_SCALE_ERROR).contains(&i.scale) {
            return bad(
                "scale",
                format!(
                    "{} must lie in 0…{MAX_SCALE_ERROR} (a relative error; 0.03 is ±3 %)",
                    crate::show::number(i.scale)
                ),
            );
        }
        if !(0.0..=0.5).contains(&i.glitches) {
            return bad(
                "glitches",
                format!(
                    "{} must lie in 0…0.5 (the fraction of readings replaced)",
                    crate::show::number(i.glitches)
                ),
            );
        }
        if !(0.0..=MAX_MISALIGNMENT).contains(&i.misalignment) {
            return bad(
                "misalignment",
                format!(
                    "{} rad must lie in 0…{MAX_MISALIGNMENT} rad ({}°)",
                    crate::show::number(i.misalignment),
                    MAX_MISALIGNMENT.to_degrees()
                ),
            );
        }
        if let Some(s) = i.saturation {
            let most = MAX_READING / STANDARD_GRAVITY;
            if !(s > 0.0 && s <= most) {
                return bad(
                    "saturation",
                    format!("{} g must lie in 0…{most} g", crate::show::number(s)),
                );
            }
        }
        if let Some(b) = i.quantization_bits {
            if !(2..=24).contains(&b) {
                return bad("quantization_bits", format!("{b} bits: use 2 to 24"));
            }
        }
        Ok(())
    }

    fn range(&self) -> Option<f64> {
        self.saturation.or(self.quantization_bits.map(|_| 2.0))
    }

    /// Saturation and quantisation of one component, m/s².
    fn sense(&self, value: f64) -> f64 {
        let Some(range) = self.range().map(|g| g * STANDARD_GRAVITY) else {
            return value;
        };
        let clipped = value.clamp(-range, range);
        match self.quantization_bits {
            Some(bits) => {
                let step = 2.0 * range / f64::from(1u32 << bits.min(31));
                (clipped / step).round() * step
            }
            None => clipped,
        }
    }
}

/// Errors in a simulation request.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
#[non_exhaustive]
pub enum SimulationError {
    /// A setting is out of its range.
    #[error("{setting}: {reason}")]
    InvalidSetting {
        /// The setting.
        setting: &'static str,
        /// What is wrong.
        reason: String,
    },
}

/// What to simulate.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct SimulationConfig {
    /// Record the structure experiment.
    pub structure: bool,
    /// Record the training experiment.
    pub training: bool,
    /// Number of training poses `P` (paper: 20).
    pub poses: usize,
    /// Half-range of random training poses, rad (paper: 2.62).
    pub pose_range: f64,
    /// How far each DoF moves in the structure experiment, rad.
    pub structure_angle: f64,
    /// Repeat the structure experiment with the reference segment tilted 90° about x.
    pub tilted_orientation: bool,
    /// Training poses recorded, after the `poses` upright ones, with the reference segment
    /// tilted 90° about x (base orientation 1 of the set): what gravity along a vertical first
    /// axis cannot tell, a turn about it, the tilted gravity tells.
    #[serde(default, skip_serializing_if = "crate::measurements::is_zero")]
    pub tilted_poses: usize,
    /// The excitation pattern.
    pub pattern: ExcitationPattern,
    /// Sensor imperfections.
    pub imperfections: Imperfections,
    /// Seed of every random choice.
    pub seed: u64,
    /// When given, the seed of the training poses and the noise instead of `seed`: the same
    /// physical skin (sensor intrinsics from `seed`) recorded again in other poses.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub pose_seed: Option<u64>,
    /// Broken SUs.
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub faults: Vec<SuFault>,
}

/// A broken SU of the simulation.
#[derive(Debug, Clone, PartialEq, Eq, Serialize, Deserialize)]
pub struct SuFault {
    /// The SU.
    pub su: String,
    /// What is wrong with it.
    pub fault: Fault,
}

/// How an SU is broken.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "kebab-case")]
pub enum Fault {
    /// Reads zeros.
    Dead,
    /// Repeats its first reading forever.
    Frozen,
    /// Its z axis is stuck at +2 g.
    Railed,
    /// Mounted or wired with its x and y axes swapped (an improper frame).
    SwapXy,
    /// Its z axis negated (an improper frame).
    NegateZ,
}

impl Fault {
    /// Its name on the command line.
    pub fn name(self) -> &'static str {
        match self {
            Fault::Dead => "dead",
            Fault::Frozen => "frozen",
            Fault::Railed => "railed",
            Fault::SwapXy => "swap-xy",
            Fault::NegateZ => "negate-z",
        }
    }

    /// All faults.
    pub const ALL: [Fault; 5] = [
        Fault::Dead,
        Fault::Frozen,
        Fault::Railed,
        Fault::SwapXy,
        Fault::NegateZ,
    ];
}

impl Default for SimulationConfig {
    fn default() -> Self {
        Self {
            structure: true,
            training: true,
            poses: 20,
            pose_range: 2.62,
            structure_angle: crate::plan::STRUCTURE_ANGLE,
            tilted_orientation: true,
            tilted_poses: 0,
            pattern: ExcitationPattern::default(),
            imperfections: Imperfections::default(),
            seed: 1,
            pose_seed: None,
            faults: Vec::new(),
        }
    }
}

impl SimulationConfig {
    /// Checks every setting.
    pub fn validate(&self) -> Result<(), SimulationError> {
        let bad =
            |setting, reason: String| Err(SimulationError::InvalidSetting { setting, reason });
        if self.training && self.poses == 0 {
            return bad("poses", "must be at least 1".into());
        }
        if !(self.pose_range > 0.0 && self.pose_range <= PI) {
            return bad(
                "pose_range",
                format!(
                    "{} rad must lie in 0…π rad",
                    crate::show::number(self.pose_range)
                ),
            );
        }
        if !(self.structure_angle > 0.0 && self.structure_angle <= PI) {
            return bad(
                "structure_angle",
                format!(
                    "{} rad must lie in 0…π rad",
                    crate::show::number(self.structure_angle)
                ),
            );
        }
        if let Err(reason) = self.pattern.check() {
            return bad("pattern", reason);
        }
        self.imperfections.validate()
    }
}

/// One orientation of the reference segment in the world.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct BaseOrientation {
    /// `upright` or `tilted`.
    pub label: String,
    /// Gravity in the reference frame, m/s².
    pub gravity: [f64; 3],
}

impl BaseOrientation {
    /// The reference segment upright: gravity `(0, 0, −9.81)`.
    pub fn upright() -> Self {
        BaseOrientation {
            label: "upright".into(),
            gravity: gravity_upright().into(),
        }
    }

    /// The reference segment tilted by 90° about its x axis.
    pub fn tilted() -> Self {
        let tilt = UnitQuaternion::from_axis_angle(&Vector3::x_axis(), std::f64::consts::FRAC_PI_2);
        BaseOrientation {
            label: "tilted".into(),
            gravity: tilt.inverse_transform_vector(&gravity_upright()).into(),
        }
    }
}

/// The ground truth of a simulation (written to `truth.json`; estimators never read it).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Truth {
    /// Always `skincal-truth`.
    pub format: String,
    /// Always 1.
    pub version: u32,
    /// The simulated robot, in the robot description format.
    pub robot: RobotFile,
    /// The base orientations of the structure experiment, in order.
    pub orientations: Vec<BaseOrientation>,
    /// Gravity in the reference frame during training, m/s².
    pub training_gravity: [f64; 3],
    /// Gravity in the reference frame during the training poses recorded tilted (base
    /// orientation 1), m/s²; absent without such poses.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub tilted_training_gravity: Option<[f64; 3]>,
    /// Each SU's accelerometer intrinsics (bias m/s², scale, misalignment rad), in SU order.
    #[serde(default)]
    pub su_intrinsics: Vec<Intrinsics>,
    /// The settings used.
    pub config: SimulationConfig,
}

/// A simulated experiment: what was measured and what is true.
#[derive(Debug, Clone, PartialEq)]
pub struct Simulation {
    /// The measurement set.
    pub measurements: MeasurementSet,
    /// The ground truth.
    pub truth: Truth,
}

// Stream 1 is the training poses' (`plan::POSE_STREAM`).
const NOISE_STREAM: u64 = 2;
const BIAS_STREAM: u64 = 3;
const SCALE_STREAM: u64 = 4;
const GLITCH_STREAM: u64 = 5;

pub(crate) fn stream(seed: u64, id: u64) -> ChaCha8Rng {
    let mut rng = ChaCha8Rng::seed_from_u64(seed);
    rng.set_stream(id);
    rng
}

/// The accelerometers of a simulated robot: per-SU intrinsics, noise, saturation and quantisation.
pub(crate) struct Sensors<'a> {
    imperfections: &'a Imperfections,
    pub(crate) intrinsics: Vec<Intrinsics>,
    rng: ChaCha8Rng,
    glitch_rng: ChaCha8Rng,
    gaussian: Option<Normal<f64>>,
    /// Per SU: how it is broken, and (frozen) the value it repeats.
    faults: Vec<Option<(Fault, Option<Vector3<f64>>)>>,
}

/// `n` values uniform in ±`half` (zeros without drawing when `half` is 0).
fn uniform3(rng: &mut ChaCha8Rng, half: f64) -> [f64; 3] {
    std::array::from_fn(|_| {
        if half > 0.0 {
            rng.random_range(-half..=half)
        } else {
            0.0
        }
    })
}

impl<'a> Sensors<'a> {
    /// `sus` sensors with intrinsics drawn from `seed` (biases from the bias stream, scales and
    /// misalignments from their own) and noise from the noise stream of `noise_seed`.
    /// `imperfections` must be valid.
    pub(crate) fn new(
        imperfections: &'a Imperfections,
        sus: usize,
        seed: u64,
        noise_seed: u64,
    ) -> Self {
        let mut bias_rng = stream(seed, BIAS_STREAM);
        let mut scale_rng = stream(seed, SCALE_STREAM);
        let b = imperfections.bias * STANDARD_GRAVITY;
        let intrinsics = (0..sus)
            .map(|_| Intrinsics {
                bias: uniform3(&mut bias_rng, b),
                scale: uniform3(&mut scale_rng, imperfections.scale),
                misalignment: uniform3(&mut scale_rng, imperfections.misalignment),
            })
            .collect();
        Sensors {
            imperfections,
            intrinsics,
            rng: stream(noise_seed, NOISE_STREAM),
            glitch_rng: stream(noise_seed, GLITCH_STREAM),
            faults: vec![None; sus],
            gaussian: (imperfections.gaussian_noise > 0.0).then(|| {
                Normal::new(0.0, imperfections.gaussian_noise * STANDARD_GRAVITY)
                    .expect("validated")
            }),
        }
    }

    /// One raw sample of SU `su` whose true specific force is `f`: `sense(K·f + b) + n`.
    pub(crate) fn sample(&mut self, su: usize, f: &Vector3<f64>) -> Vector3<f64> {
        self.sense(&self.intrinsics[su].read(f)) + self.noise()
    }

    fn noise(&mut self) -> Vector3<f64> {
        let u = self.imperfections.uniform_noise * STANDARD_GRAVITY;
        Vector3::from_fn(|_, _| {
            let mut n = if u > 0.0 {
                self.rng.random_range(-u..=u)
            } else {
                0.0
            };
            if let Some(g) = &self.gaussian {
                n += g.sample(&mut self.rng);
            }
            n
        })
    }

    fn sense(&self, v: &Vector3<f64>) -> Vector3<f64> {
        v.map(|x| self.imperfections.sense(x))
    }

    /// With the glitch rate's probability, a random vector of 0.2–1.5 g instead of `v`.
    fn glitch(&mut self, v: Vector3<f64>) -> Vector3<f64> {
        let rate = self.imperfections.glitches;
        if rate <= 0.0 || !self.glitch_rng.random_bool(rate) {
            return v;
        }
        let r = &mut self.glitch_rng;
        let z: f64 = r.random_range(-1.0..=1.0);
        let phi: f64 = r.random_range(0.0..2.0 * PI);
        let norm = r.random_range(0.2..=1.5) * STANDARD_GRAVITY;
        let h = (1.0 - z * z).max(0.0).sqrt();
        Vector3::new(h * phi.cos(), h * phi.sin(), z) * norm
    }

    /// What a broken SU makes of a reading `v` (`static`: a static reading, else a dynamic one, a
    /// difference of two readings).
    fn break_reading(&mut self, su: usize, v: Vector3<f64>, is_static: bool) -> Vector3<f64> {
        let Some((fault, frozen)) = &mut self.faults[su] else {
            return v;
        };
        match fault {
            Fault::Dead => Vector3::zeros(),
            Fault::Frozen if is_static => *frozen.get_or_insert(v),
            Fault::Frozen => Vector3::zeros(),
            Fault::Railed if is_static => Vector3::new(v.x, v.y, 2.0 * STANDARD_GRAVITY),
            Fault::Railed => Vector3::new(v.x, v.y, 0.0),
            Fault::SwapXy => Vector3::new(v.y, v.x, v.z),
            Fault::NegateZ => Vector3::new(v.x, v.y, -v.z),
        }
    }

    fn static_reading(&mut self, su: usize, f: &Vector3<f64>) -> Reading {
        let v = self.sample(su, f);
        let v = self.break_reading(su, v, true);
        self.glitch(v).into()
    }

    fn dynamic_reading(&mut self, su: usize, f: &Vector3<f64>, a: &Vector3<f64>) -> Reading {
        let i = &self.intrinsics[su];
        let v = self.sense(&i.read(&(f + a))) - self.sense(&i.read(f)) + self.noise();
        let v = self.break_reading(su, v, false);
        self.glitch(v).into()
    }
}

/// The most readings (numbers) a simulated measurement set may hold: 100 million take 0.8 GB
/// in memory and about 2 GB as JSON.
pub const MAX_READINGS: u64 = 100_000_000;

/// Refuses a simulation whose measurement set would not fit: every SU reads 3 numbers in the rest
/// pose and after every DoF's move (per base orientation), and statically and for every DoF's
/// excitation in every training pose.
fn check_size(nd: usize, nu: usize, config: &SimulationConfig) -> Result<(), SimulationError> {
    let (nd, nu) = (nd as u64, nu as u64);
    let orientations = if config.tilted_orientation { 2 } else { 1 };
    let structure = if config.structure {
        orientations * (1 + nd)
    } else {
        0
    };
    let training = if config.training {
        config.poses as u64 * (1 + nd)
    } else {
        0
    };
    let readings = 3 * nu * (structure + training);
    if readings <= MAX_READINGS {
        return Ok(());
    }
    Err(SimulationError::InvalidSetting {
        setting: "size",
        reason: format!(
            "{nd} DoFs and {nu} SUs would give {readings} readings ({:.1} GB in memory, about \
             {:.0} GB as JSON), more than the {MAX_READINGS} a measurement set may hold: simulate \
             fewer training poses (--poses), fewer SUs per link, or a part of the robot",
            readings as f64 * 8e-9,
            readings as f64 * 20e-9
        ),
    })
}

/// Runs the experiments of `config` on `robot`.
///
/// ```
/// use skincal::model::presets;
/// use skincal::sim::{simulate, SimulationConfig};
///
/// let robot = presets::find("paper-7dof").unwrap().robot().unwrap();
/// let sim = simulate(&robot, &SimulationConfig { poses: 5, ..SimulationConfig::default() }).unwrap();
/// let summary = sim.measurements.summary();
/// assert_eq!((summary.dofs, summary.sus, summary.training_poses), (7, 7, 5));
/// // At rest every SU reads gravity, 9.81 m/s², give or take the noise (0.01 g per axis).
/// let (mean, sd) = summary.static_norm;
/// assert!((mean - 9.80665).abs() < 0.05 && sd < 0.2);
/// ```
pub fn simulate(robot: &Robot, config: &SimulationConfig) -> Result<Simulation, SimulationError> {
    config.validate()?;
    let model = &robot.model;
    check_size(model.dofs().len(), model.sus().len(), config)?;
    let data_seed = config.pose_seed.unwrap_or(config.seed);
    let mut sensors = faulty_sensors(robot, config, data_seed)?;
    let mut pose_rng = pose_stream(data_seed);
    let mut set = MeasurementSet::new(model.dof_names(), model.su_names());
    set.prismatic = model.prismatic_dof_names();
    set.mimic = model.mimic_specs();
    let mut orientations = vec![BaseOrientation::upright()];
    if config.tilted_orientation {
        orientations.push(BaseOrientation::tilted());
    }
    if config.structure {
        set.structure = Some(structure_experiment(
            robot,
            &mut sensors,
            &orientations,
            config,
        ));
    }
    let training_gravity = gravity_upright();
    let tilted_gravity = Vector3::from(BaseOrientation::tilted().gravity);
    if config.training {
        let mut poses: Vec<TrainingPose> = (0..config.poses)
            .map(|_| {
                let q = training_angles(model, &mut pose_rng, config.pose_range);
                training_pose(robot, &mut sensors, q, &training_gravity, config)
            })
            .collect();
        poses.extend((0..config.tilted_poses).map(|_| {
            let q = training_angles(model, &mut pose_rng, config.pose_range);
            TrainingPose {
                orientation: 1,
                ..training_pose(robot, &mut sensors, q, &tilted_gravity, config)
            }
        }));
        set.training = Some(TrainingExperiment {
            from_motion: false,
            pattern: config.pattern,
            poses,
            extra: Map::new(),
        });
    }
    let truth = Truth {
        format: "skincal-truth".into(),
        version: 1,
        robot: RobotFile::from_robot(robot, None),
        orientations,
        training_gravity: training_gravity.into(),
        tilted_training_gravity: (config.training && config.tilted_poses > 0)
            .then(|| tilted_gravity.into()),
        su_intrinsics: sensors.intrinsics.clone(),
        config: config.clone(),
    };
    Ok(Simulation {
        measurements: set,
        truth,
    })
}

/// The skin's sensors with the configured imperfections and faults.
fn faulty_sensors<'a>(
    robot: &Robot,
    config: &'a SimulationConfig,
    data_seed: u64,
) -> Result<Sensors<'a>, SimulationError> {
    let model = &robot.model;
    let mut sensors = Sensors::new(
        &config.imperfections,
        model.sus().len(),
        config.seed,
        data_seed,
    );
    for f in &config.faults {
        let u = model
            .su_names()
            .iter()
            .position(|n| *n == f.su)
            .ok_or_else(|| SimulationError::InvalidSetting {
                setting: "faults",
                reason: format!("the robot has no SU `{}`", f.su),
            })?;
        sensors.faults[u] = Some((f.fault, None));
    }
    Ok(sensors)
}

/// Every SU's static reading in pose `q` under gravity `g`.
fn static_readings(
    robot: &Robot,
    sensors: &mut Sensors<'_>,
    q: &[f64],
    g: &Vector3<f64>,
) -> Vec<Reading> {
    let k = forward_kinematics(&robot.model, &robot.parameters, q);
    k.sus
        .iter()
        .enumerate()
        .map(|(su, frame)| sensors.static_reading(su, &specific_force(frame, &Vector3::zeros(), g)))
        .collect()
}

/// The structure experiment: in each base orientation, the rest pose and one move per DoF.
fn structure_experiment(
    robot: &Robot,
    sensors: &mut Sensors<'_>,
    orientations: &[BaseOrientation],
    config: &SimulationConfig,
) -> StructureExperiment {
    let model = &robot.model;
    let mut rest_pose: Vec<f64> = model.dofs().iter().map(|d| d.limits.clamp(0.0)).collect();
    model.follow_leaders(&mut rest_pose, false);
    let mut blocks = Vec::new();
    for o in orientations {
        let g = Vector3::from(o.gravity);
        let rest = static_readings(robot, sensors, &rest_pose, &g);
        let moves = model
            .driven_dofs()
            .into_iter()
            .map(|d| {
                let mut pose = rest_pose.clone();
                let dof = &model.dofs()[d];
                let angle = config.structure_angle * dof.kind.pattern_scale();
                pose[d] = structure_move(&dof.limits, rest_pose[d], angle);
                model.follow_leaders(&mut pose, false);
                let readings = static_readings(robot, sensors, &pose, &g);
                Move {
                    dof: model.dofs()[d].name.clone(),
                    pose,
                    readings,
                    accelerated: Vec::new(),
                    accelerated_sd: Vec::new(),
                    extra: Map::new(),
                }
            })
            .collect();
        let mut extra = Map::new();
        extra.insert("label".into(), json!(o.label));
        blocks.push(Orientation {
            rest_pose: rest_pose.clone(),
            rest,
            moves,
            extra,
        });
    }
    StructureExperiment {
        orientations: blocks,
        extra: Map::new(),
    }
}

/// A random training pose: each DoF uniform within its limits and `±range` (its limits alone
/// where the two do not meet); a mimic DoF where its leader puts it.
fn training_angles(model: &crate::model::RobotModel, rng: &mut ChaCha8Rng, range: f64) -> Vec<f64> {
    let mut q: Vec<f64> = model
        .dofs()
        .iter()
        .map(|d| {
            let (lo, hi) = (d.limits.lower.max(-range), d.limits.upper.min(range));
            let (lo, hi) = if lo <= hi {
                (lo, hi)
            } else {
                (d.limits.lower, d.limits.upper)
            };
            if hi > lo {
                rng.random_range(lo..=hi)
            } else {
                lo
            }
        })
        .collect();
    model.follow_leaders(&mut q, false);
    q
}

/// The training readings in pose `q`: static under `gravity`, and every driven DoF's pattern's
/// peak (a mimic DoF moves with its leader's pattern).
fn training_pose(
    robot: &Robot,
    sensors: &mut Sensors<'_>,
    q: Vec<f64>,
    gravity: &Vector3<f64>,
    config: &SimulationConfig,
) -> TrainingPose {
    let model = &robot.model;
    let k = forward_kinematics(model, &robot.parameters, &q);
    let forces: Vec<Vector3<f64>> = k
        .sus
        .iter()
        .map(|f| specific_force(f, &Vector3::zeros(), gravity))
        .collect();
    let static_readings = forces
        .iter()
        .enumerate()
        .map(|(su, f)| sensors.static_reading(su, f))
        .collect();
    let dynamic = model
        .driven_dofs()
        .into_iter()
        .map(|d| {
            let peak = peak_dynamic_accelerations_at(model, &k, d, &config.pattern);
            let r = peak
                .iter()
                .enumerate()
                .map(|(su, a)| sensors.dynamic_reading(su, &forces[su], a))
                .collect();
            (model.dofs()[d].name.clone(), r)
        })
        .collect();
    TrainingPose {
        q,
        static_readings,
        dynamic,
        static_sd: None,
        dynamic_sd: std::collections::BTreeMap::new(),
        orientation: 0,
        extra: Map::new(),
    }
}

/// Settings of [`random_tree`].
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct RandomTreeConfig {
    /// Number of DoFs.
    pub dofs: usize,
    /// Number of SUs (at least one per segment that carries skin).
    pub sus: usize,
    /// Largest number of DoFs in one joint (DoFs with no SU between them).
    pub max_joint_dofs: usize,
    /// Fraction of DoF axes that are exactly vertical at the rest pose.
    pub vertical_axes: f64,
    /// Probability that a new joint continues the newest segment rather than a random one
    /// (higher: longer chains, lower: bushier trees).
    pub chain_bias: f64,
}

impl Default for RandomTreeConfig {
    fn default() -> Self {
        Self {
            dofs: 20,
            sus: 100,
            max_joint_dofs: 3,
            vertical_axes: 0.2,
            chain_bias: 0.6,
        }
    }
}

/// A random robot: a tree of segments joined by joints of 1 to `max_joint_dofs` revolute DoFs
/// (the segments between the DoFs of one joint carry no SU), random link offsets (0.1–0.4 m) and
/// orientations, random axes of which a fraction is exactly vertical at the rest pose, freely
/// turning DoFs, and SUs spread over every other segment (at least one each, the reference
/// included) within ±0.1 m of the segment frame, randomly oriented. Seeded.
///
/// Names: DoFs `dof1…`, segments `seg0…` (the reference is `seg0`), SUs `su1…`.
pub fn random_tree(config: &RandomTreeConfig, seed: u64) -> Result<Robot, SimulationError> {
    use crate::model::RobotBuilder;
    use nalgebra::UnitQuaternion;

    let bad = |setting, reason: String| Err(SimulationError::InvalidSetting { setting, reason });
    if config.dofs == 0 {
        return bad("dofs", "must be at least 1".into());
    }
    if config.max_joint_dofs == 0 {
        return bad("max_joint_dofs", "must be at least 1".into());
    }
    let mut rng = ChaCha8Rng::seed_from_u64(seed);
    let mut builder = RobotBuilder::new(
        format!("random-{}dof-{}su-{seed}", config.dofs, config.sus),
        "seg0",
    );
    // Real segments (those that carry skin) with their rest orientation in the reference frame.
    let mut real: Vec<(String, UnitQuaternion<f64>)> =
        vec![("seg0".into(), UnitQuaternion::identity())];
    let mut n = 0;
    while n < config.dofs {
        let parent = if real.len() == 1 || rng.random_bool(config.chain_bias) {
            real.len() - 1
        } else {
            rng.random_range(0..real.len())
        };
        let k = rng.random_range(1..=config.max_joint_dofs.min(config.dofs - n));
        let mut end = real[parent].clone();
        for i in 0..k {
            n += 1;
            let child = if i + 1 == k {
                format!("seg{}", real.len())
            } else {
                format!("link_dof{n}")
            };
            end = random_dof(&mut builder, &mut rng, config, end, i == 0, n, child);
        }
        real.push(end);
    }
    if config.sus < real.len() {
        return bad(
            "sus",
            format!(
                "{} SUs cannot cover {} segments: give at least one per segment",
                config.sus,
                real.len()
            ),
        );
    }
    random_skin(&mut builder, &mut rng, &real, config.sus);
    builder
        .build()
        .map_err(|e| SimulationError::InvalidSetting {
            setting: "random tree",
            reason: e.to_string(),
        })
}

/// A random unit vector.
fn random_unit(rng: &mut ChaCha8Rng) -> Vector3<f64> {
    loop {
        let v = Vector3::from_fn(|_, _| rng.random_range(-1.0..1.0));
        let n = v.norm();
        if n > 0.1 && n <= 1.0 {
            break v / n;
        }
    }
}

/// DoF `dof{n}` of a random tree on `segment` (with its rest orientation in the reference frame),
/// moving `child`: the first DoF of a joint at 0.1–0.4 m from its segment's frame, a further one
/// within 3 cm; returns the child and its rest orientation.
fn random_dof(
    builder: &mut crate::model::RobotBuilder,
    rng: &mut ChaCha8Rng,
    config: &RandomTreeConfig,
    (segment, orientation): (String, nalgebra::UnitQuaternion<f64>),
    first: bool,
    n: usize,
    child: String,
) -> (String, nalgebra::UnitQuaternion<f64>) {
    use crate::model::{DofSpec, Limits, PlacementSpec};
    use nalgebra::{Isometry3, UnitQuaternion};
    let length = if first {
        rng.random_range(0.1..0.4)
    } else {
        rng.random_range(0.0..0.03)
    };
    let offset: Vector3<f64> = random_unit(rng) * length;
    let turn = UnitQuaternion::from_scaled_axis(
        random_unit(rng) * rng.random_range(0.0..std::f64::consts::PI),
    );
    let origin = Isometry3::from_parts(offset.into(), turn);
    let joint = orientation * origin.rotation;
    let axis = if rng.random_bool(config.vertical_axes.clamp(0.0, 1.0)) {
        joint.inverse_transform_vector(&Vector3::z())
    } else {
        random_unit(rng)
    };
    builder.dofs.push(DofSpec {
        name: format!("dof{n}"),
        parent: segment,
        child: child.clone(),
        origin: PlacementSpec::from_isometry(&origin),
        axis,
        kind: DofKind::Revolute,
        limits: Limits {
            velocity: Some(2.0),
            acceleration: Some(10.0),
            ..Limits::CONTINUOUS
        },
        mimic: None,
    });
    (child, joint)
}

/// `sus` SUs on the `real` segments: one on each, the rest on segments drawn at random, each
/// within 5 cm of its segment's frame and turned at random.
fn random_skin(
    builder: &mut crate::model::RobotBuilder,
    rng: &mut ChaCha8Rng,
    real: &[(String, nalgebra::UnitQuaternion<f64>)],
    sus: usize,
) {
    use crate::model::description::random_su_placement;
    use crate::model::SuSpec;
    let mut count = vec![1usize; real.len()];
    for _ in real.len()..sus {
        count[rng.random_range(0..real.len())] += 1;
    }
    let mut k = 0;
    for ((segment, _), &c) in real.iter().zip(&count) {
        for _ in 0..c {
            k += 1;
            let anchor = nalgebra::Isometry3::translation(
                rng.random_range(-0.05..0.05),
                rng.random_range(-0.05..0.05),
                rng.random_range(-0.05..0.05),
            );
            builder.sus.push(SuSpec {
                name: format!("su{k}"),
                segment: segment.clone(),
                placement: random_su_placement(rng, &anchor),
            });
        }
    }
}

/// A random serial chain in the paper's DH form: `dofs` DoFs, DoF-to-DoF rows and one DoF-to-SU row
/// per segment drawn uniformly within the bounds of the paper's eq. 18 (`θ0, α, θ_acc ∈ [−π, π]`,
/// `d, d_acc ∈ [−1, 1]`, `a ∈ [0, 1]`), freely turning DoFs, reference = the first DoF's frame.
/// Names as in `paper-7dof`: DoFs `dof1…`, segments `link1…`, SUs `su1…`. Seeded.
pub fn random_dh_chain(dofs: usize, seed: u64) -> Result<Robot, SimulationError> {
    use crate::model::PlacementSpec;
    use std::f64::consts::PI;
    let mut rng = ChaCha8Rng::seed_from_u64(seed);
    serial_dh_chain(
        format!("random-dh-{dofs}dof-{seed}"),
        dofs,
        &mut rng,
        |rng, _| {
            PlacementSpec::dh(
                rng.random_range(-PI..PI),
                rng.random_range(-1.0..1.0),
                rng.random_range(0.0..1.0),
                rng.random_range(-PI..PI),
            )
        },
        |rng| {
            PlacementSpec::dh_sensor(
                rng.random_range(-PI..PI),
                rng.random_range(-1.0..1.0),
                rng.random_range(0.0..1.0),
                rng.random_range(-PI..PI),
                rng.random_range(-PI..PI),
                rng.random_range(-1.0..1.0),
            )
        },
    )
}

/// A serial chain named as `paper-7dof` is (reference `base`, DoFs `dof1…` turning segments
/// `link1…`, SU `suk` on `linkk`): freely turning DoFs (1.7 rad/s, 10 rad/s²), DoF `k ≥ 2` placed
/// by `dof_row(rng, k)`, then every SU by `su_row(rng)`.
pub(crate) fn serial_dh_chain(
    name: String,
    dofs: usize,
    rng: &mut ChaCha8Rng,
    dof_row: impl Fn(&mut ChaCha8Rng, usize) -> crate::model::PlacementSpec,
    su_row: impl Fn(&mut ChaCha8Rng) -> crate::model::PlacementSpec,
) -> Result<Robot, SimulationError> {
    use crate::model::{DofSpec, Limits, PlacementSpec, RobotBuilder, SuSpec};
    if dofs == 0 {
        return Err(SimulationError::InvalidSetting {
            setting: "dofs",
            reason: "must be at least 1".into(),
        });
    }
    let mut b = RobotBuilder::new(name, "base");
    for k in 1..=dofs {
        let origin = if k == 1 {
            PlacementSpec::identity()
        } else {
            dof_row(rng, k)
        };
        b.dofs.push(DofSpec {
            name: format!("dof{k}"),
            parent: if k == 1 {
                "base".into()
            } else {
                format!("link{}", k - 1)
            },
            child: format!("link{k}"),
            origin,
            axis: Vector3::z(),
            kind: DofKind::Revolute,
            limits: Limits {
                velocity: Some(1.7),
                acceleration: Some(10.0),
                ..Limits::CONTINUOUS
            },
            mimic: None,
        });
    }
    for k in 1..=dofs {
        b.sus.push(SuSpec {
            name: format!("su{k}"),
            segment: format!("link{k}"),
            placement: su_row(rng),
        });
    }
    b.build().map_err(|e| SimulationError::InvalidSetting {
        setting: "serial chain",
        reason: e.to_string(),
    })
}
