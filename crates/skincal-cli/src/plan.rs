//! `skincal plan`: the exploration program for a real robot — its structure moves, training poses
//! and patterns within the robot's limits, clear of its own body — as a plan, trajectories, ROS 2
//! goals, and a forecast of what it will reach.

use std::path::PathBuf;

use anyhow::{bail, Context, Result};
use clap::Args;
use skincal::io::{self, SuPlacement};
use skincal::plan::{Action, Plan, PlanConfig, PlanDof};

use crate::out::{self, out, outln};
use crate::parse_pattern;

/// An exploration program.
#[derive(Debug, Clone, Copy, PartialEq, Eq, clap::ValueEnum)]
pub(crate) enum Protocol {
    /// The paper's: 20 poses, 1 s still periods, 2 s excitations, one DoF at a time.
    Paper,
    /// 0.5 s still periods, one-period excitations, the limbs excited in parallel, and as many
    /// poses (at least 6) as the forecast needs for 0.009 m/s² held-out RMS.
    Short,
    /// The short structure experiment, then every DoF moving at once along smooth random paths
    /// (20 s; no training pose, no still period, no pattern), calibrated on every sample.
    Continuous,
}

#[derive(Debug, Args)]
pub(crate) struct PlanArgs {
    /// A built-in robot, a .toml description or a .urdf file: DoF names and limits.
    #[arg(long)]
    robot: String,
    /// Output directory: plan.json, trajectory.csv, trajectory.json, and ros2/ (what a ROS 2
    /// joint trajectory controller executes: goal.yaml, goal_structure.yaml, start.yaml,
    /// joint_trajectory.mcap, joint_trajectory_structure.mcap).
    #[arg(long)]
    out: PathBuf,
    /// Overwrite existing output files.
    #[arg(long)]
    force: bool,
    /// The program: `short` (0.5 s still periods, one-period excitations, the limbs of a tree
    /// excited at the same time, at least 6 poses and as many as the forecast needs for 0.009 m/s²
    /// held-out RMS) or `paper` (20 poses, 1 s still periods, 2 s excitations, one DoF at a time,
    /// as the paper does), or `continuous` (every DoF at once along smooth random paths for
    /// --sweep seconds after the structure experiment, calibrated on every sample of its log);
    /// the options below change single values.
    #[arg(long, value_enum, default_value_t = Protocol::Short)]
    protocol: Protocol,
    /// Seconds of continuous motion of every DoF at once in place of the training poses
    /// [default: 20 for `continuous`, none for the others].
    #[arg(long, value_name = "SECONDS")]
    sweep: Option<f64>,
    /// Number of training poses P [default: the protocol's].
    #[arg(long)]
    poses: Option<usize>,
    /// Run the first N training poses again with the base tilted, after the structure part
    /// (`goal_structure.yaml` then holds both): they tell how what a vertical first axis turns
    /// sits about it, which no upright pose does.
    #[arg(long, value_name = "N", default_value_t = 0)]
    tilted_poses: usize,
    /// Use this pattern A,f (rad/s, Hz) instead of choosing one; it is checked against the limits.
    #[arg(long, value_name = "A,f")]
    pattern: Option<String>,
    /// Velocity limit, rad/s, for every DoF (`X`) or one (`DOF=X`); repeatable.
    #[arg(long, value_name = "[DOF=]X")]
    velocity: Vec<String>,
    /// Acceleration limit, rad/s², for every DoF (`X`) or one (`DOF=X`); repeatable.
    #[arg(long, value_name = "[DOF=]X")]
    acceleration: Vec<String>,
    /// Position range of one DoF, rad; repeatable.
    #[arg(long, value_name = "DOF=LO,HI")]
    range: Vec<String>,
    /// Largest pattern excursion A/(πf), rad.
    #[arg(long, default_value_t = 0.1)]
    max_excursion: f64,
    /// Half-range of the random training poses, rad (clipped to the limits).
    #[arg(long, default_value_t = std::f64::consts::FRAC_PI_2)]
    pose_range: f64,
    /// How far each DoF moves in the structure experiment, rad.
    #[arg(long, default_value_t = 0.3)]
    structure_angle: f64,
    /// Still period for static readings, s [default: the protocol's].
    #[arg(long)]
    still: Option<f64>,
    /// Still period after each excitation, s [default: the protocol's].
    #[arg(long)]
    settle: Option<f64>,
    /// Periods of the excitation window's rise and of its fall (eq. 13) [default: the
    /// protocol's].
    #[arg(long)]
    ramp_cycles: Option<f64>,
    /// Periods of the excitation window at full amplitude [default: the protocol's].
    #[arg(long)]
    hold_cycles: Option<f64>,
    /// Leave out the structure experiment.
    #[arg(long)]
    no_structure: bool,
    /// Leave out the training experiment.
    #[arg(long)]
    no_training: bool,
    /// Excite one DoF at a time even where the protocol runs the limbs in parallel.
    #[arg(long)]
    one_at_a_time: bool,
    /// Add training poses (a continuous program: lengthen its sweep) until the forecast held-out
    /// RMS error (static and dynamic) is at most this, m/s², starting from --poses (--sweep) or
    /// the protocol's [default: 0.009 for `short` without --poses].
    #[arg(long, value_name = "M/S²")]
    accuracy: Option<f64>,
    /// The accelerometers' noise per axis and sample, m/s² (standard deviation) for the forecast
    /// [default: the simulator's uniform ±0.01 g, 0.057 m/s²].
    #[arg(long, value_name = "M/S²")]
    sample_noise: Option<f64>,
    /// Do not forecast the accuracy (it simulates the plan on the description: a second or two).
    #[arg(long, conflicts_with = "accuracy")]
    no_forecast: bool,
    /// Sample rate of the trajectory files, Hz.
    #[arg(long, default_value_t = 1000.0)]
    rate: f64,
    /// Seed of the training poses.
    #[arg(long, default_value_t = 1)]
    seed: u64,
    /// The ros2_control joint trajectory controller that executes the plan: ros2/*.mcap publish
    /// on /NAME/joint_trajectory; the goals are for /NAME/follow_joint_trajectory.
    #[arg(
        long,
        value_name = "NAME",
        default_value = "joint_trajectory_controller"
    )]
    controller: String,
    /// Knot spacing of the ROS 2 trajectories inside moving phases, s (each knot has positions,
    /// velocities and accelerations; the controller's quintic splines follow the plan between).
    #[arg(long, value_name = "SECONDS", default_value_t = skincal::plan::trajectory::DEFAULT_STEP)]
    knot_step: f64,
    /// Time ros2/start.yaml gives the robot to reach the plan's first pose from wherever it
    /// stands, s.
    #[arg(long, value_name = "SECONDS", default_value_t = 10.0)]
    start_time: f64,
    /// Smallest distance allowed between two links of the robot, m: the skin's thickness on
    /// both (checked on the URDF's collision geometry when --robot is a URDF).
    #[arg(long, value_name = "M", default_value_t = skincal::collision::CollisionOptions::default().clearance)]
    clearance: f64,
    /// A floor or table plane at this height in the base's frame (z up), m: no moving link
    /// comes nearer than half the clearance (the upright program only).
    #[arg(long, value_name = "M", allow_hyphen_values = true)]
    floor: Option<f64>,
    /// The robot's SRDF: the link pairs its `disable_collisions` names are not checked.
    #[arg(long, value_name = "FILE")]
    srdf: Option<PathBuf>,
    /// Check joint limits only, not the robot's body.
    #[arg(long)]
    no_collision_check: bool,
    /// Print one JSON document (what was written and the result's figures) instead of text.
    #[arg(long)]
    json: bool,
}

/// `[DOF=]X` options applied to `dofs` through `set`.
fn apply_limits(
    dofs: &mut [PlanDof],
    options: &[String],
    flag: &str,
    set: impl Fn(&mut PlanDof, &str) -> Result<()>,
) -> Result<()> {
    for option in options {
        let (target, value) = match option.split_once('=') {
            Some((d, v)) => (Some(d.trim()), v.trim()),
            None => (None, option.trim()),
        };
        match target {
            None => {
                for d in dofs.iter_mut() {
                    set(d, value).with_context(|| format!("--{flag} {option}"))?;
                }
            }
            Some(name) => {
                let Some(d) = dofs.iter_mut().find(|d| d.name == name) else {
                    let names: Vec<&str> = dofs.iter().map(|d| d.name.as_str()).collect();
                    bail!("--{flag} {option}: the robot has no DoF `{name}` (its DoFs: {names:?})");
                };
                set(d, value).with_context(|| format!("--{flag} {option}"))?;
            }
        }
    }
    Ok(())
}

fn positive(text: &str, unit: &str) -> Result<f64> {
    match text.parse::<f64>() {
        Ok(v) if v.is_finite() && v > 0.0 => Ok(v),
        _ => bail!("`{text}` must be a positive number in {unit}"),
    }
}

pub(crate) fn plan(args: PlanArgs) -> Result<()> {
    if args.json {
        out::json_mode();
    }
    let robot = io::load_robot(&args.robot, SuPlacement::default())?;
    let dofs = plan_dofs(&robot, &args)?;
    let config = plan_config(&args)?;
    let accuracy = args.accuracy.or((args.protocol == Protocol::Short
        && config.sweep == 0.0
        && args.poses.is_none()
        && !args.no_forecast)
        .then_some(skincal::design::SHORT_ACCURACY));
    let body = collision_body(&args, &robot)?;
    let names: Vec<String> = dofs.iter().map(|d| d.name.clone()).collect();
    let clearance = body
        .as_ref()
        .map(|body| skincal::collision::PlanClearance::new(body, &robot, &names))
        .transpose()
        .map_err(|e| anyhow::anyhow!("the collision check: {e}"))?;
    let clearance = clearance
        .as_ref()
        .map(|c| c as &(dyn skincal::plan::Clearance + Sync));
    let busy = out::spinner(match (&body, args.no_forecast) {
        (Some(_), true) => "planning, clear of the robot's body",
        (Some(_), false) => "planning, clear of the robot's body, and forecasting its accuracy",
        (None, true) => "planning",
        (None, false) => "planning and forecasting its accuracy",
    });
    let planned = planned(&robot, dofs, &config, &args, accuracy, clearance);
    busy.finish_and_clear();
    let (plan, forecast_note) = planned?;
    let mut files = trajectory_files(&plan, &args)?;
    files.extend(ros2_files(&plan, &args)?);
    io::write_all(&files, args.force)?;
    out!("{}", render_plan(&plan));
    outln!("{}", render_collision(&plan, body.as_ref()));
    outln!("{forecast_note}");
    for (f, _) in &files {
        outln!("wrote {}", f.display());
    }
    out::json(&serde_json::json!({
        "wrote": files.iter().map(|(f, _)| f.display().to_string()).collect::<Vec<_>>(),
        "duration": plan.duration,
        "structure_duration": plan.structure_duration,
        "training_poses": plan.training_poses().len(),
        "pattern": plan.pattern,
        "forecast": plan.forecast,
        "collision": plan.collision,
        "note": forecast_note,
    }));
    Ok(())
}

/// Shows what the search for a program that meets `target` m/s² is doing: a spinner while a
/// program is forecast, and a line on standard error for each forecast (each takes minutes on a
/// robot of many DoFs).
fn design_progress(target: f64) -> impl FnMut(skincal::design::DesignStep<'_>) {
    use skincal::design::DesignStep;
    let mut busy: Option<indicatif::ProgressBar> = None;
    let mut started = std::time::Instant::now();
    let program = |config: &PlanConfig| {
        if config.sweep > 0.0 {
            format!("a sweep of {} s", config.sweep)
        } else {
            format!(
                "{} training poses (best of {} draws)",
                config.poses,
                skincal::design::CANDIDATES
            )
        }
    };
    move |step| match step {
        DesignStep::Trying(config) => {
            started = std::time::Instant::now();
            busy = Some(out::spinner(&format!(
                "forecast: calibrating {} on the description",
                program(config)
            )));
        }
        DesignStep::Forecast(config, f) => {
            let line = format!(
                "forecast of {}: held-out RMS static {:.4}, dynamic {:.4} m/s² (aim {target}) in {:.1} s",
                program(config),
                f.static_rms,
                f.dynamic_rms,
                started.elapsed().as_secs_f64()
            );
            if let Some(bar) = busy.take() {
                bar.finish_and_clear();
            }
            eprintln!("{line}");
        }
    }
}

/// The robot's DoFs with the limits and ranges the options give.
fn plan_dofs(robot: &skincal::model::Robot, args: &PlanArgs) -> Result<Vec<PlanDof>> {
    let mut dofs = PlanDof::from_robot(robot);
    apply_limits(&mut dofs, &args.velocity, "velocity", |d, v| {
        d.velocity = positive(v, "rad/s")?;
        d.velocity_assumed = false;
        Ok(())
    })?;
    apply_limits(&mut dofs, &args.acceleration, "acceleration", |d, v| {
        d.acceleration = positive(v, "rad/s²")?;
        d.acceleration_assumed = false;
        Ok(())
    })?;
    for option in &args.range {
        let parsed = option.split_once('=').and_then(|(name, r)| {
            let (lo, hi) = r.split_once(',')?;
            Some((
                name.trim(),
                lo.trim().parse::<f64>().ok()?,
                hi.trim().parse::<f64>().ok()?,
            ))
        });
        let Some((name, lo, hi)) = parsed else {
            bail!("--range {option}: expected DOF=LO,HI in rad, e.g. elbow=-1.2,0.8");
        };
        let Some(d) = dofs.iter_mut().find(|d| d.name == name) else {
            bail!("--range {option}: the robot has no DoF `{name}`");
        };
        d.lower = lo;
        d.upper = hi;
    }
    Ok(dofs)
}

/// The program the options ask for, on top of the chosen protocol; the output options checked.
fn plan_config(args: &PlanArgs) -> Result<PlanConfig> {
    let protocol = match args.protocol {
        Protocol::Paper => PlanConfig::default(),
        Protocol::Short => PlanConfig::short(),
        Protocol::Continuous => PlanConfig::continuous(),
    };
    let config = PlanConfig {
        structure: !args.no_structure,
        training: !args.no_training,
        poses: args.poses.unwrap_or(protocol.poses),
        pose_range: args.pose_range,
        structure_angle: args.structure_angle,
        still: args.still.unwrap_or(protocol.still),
        settle: args.settle.unwrap_or(protocol.settle),
        ramp_cycles: args.ramp_cycles.unwrap_or(protocol.ramp_cycles),
        hold_cycles: args.hold_cycles.unwrap_or(protocol.hold_cycles),
        max_excursion: args.max_excursion,
        pattern: args.pattern.as_deref().map(parse_pattern).transpose()?,
        seed: args.seed,
        parallel: protocol.parallel && !args.one_at_a_time,
        sweep: args.sweep.unwrap_or(protocol.sweep),
        tilted_poses: args.tilted_poses,
        ..protocol
    };
    if !(args.rate.is_finite() && args.rate >= 1.0) {
        bail!("--rate {}: use at least 1 Hz", args.rate);
    }
    if !(args.knot_step.is_finite() && args.knot_step >= 1e-3) {
        bail!("--knot-step {}: use at least 0.001 s", args.knot_step);
    }
    if !(args.start_time.is_finite() && args.start_time > 0.0) {
        bail!(
            "--start-time {}: use a positive number of seconds",
            args.start_time
        );
    }
    let controller = args.controller.trim_matches('/');
    if controller.is_empty() || controller.contains(char::is_whitespace) {
        bail!(
            "--controller `{}`: give the controller's name, e.g. joint_trajectory_controller",
            args.controller
        );
    }
    for (flag, v) in [
        ("accuracy", args.accuracy),
        ("sample-noise", args.sample_noise),
    ] {
        if v.is_some_and(|v| !(v.is_finite() && v > 0.0)) {
            bail!("--{flag}: must be a positive number of m/s²");
        }
    }
    Ok(config)
}

/// The plan and its trajectory sampled at `--rate` (CSV and JSON), as files to write.
fn trajectory_files(plan: &Plan, args: &PlanArgs) -> Result<Vec<(PathBuf, Vec<u8>)>> {
    let samples = plan.sample(args.rate);
    let names = plan.dof_names();
    let mut csv = format!("time,{}\n", names.join(","));
    for (t, q) in &samples {
        csv.push_str(&format!("{t:.6}"));
        for v in q {
            csv.push_str(&format!(",{v:.9}"));
        }
        csv.push('\n');
    }
    let trajectory = serde_json::json!({
        "format": "skincal-trajectory",
        "version": 1,
        "dofs": names,
        "rate": args.rate,
        "time": samples.iter().map(|(t, _)| *t).collect::<Vec<_>>(),
        "positions": samples.iter().map(|(_, q)| q).collect::<Vec<_>>(),
    });
    Ok(vec![
        (
            args.out.join("plan.json"),
            serde_json::to_string_pretty(plan)?.into_bytes(),
        ),
        (args.out.join("trajectory.csv"), csv.into_bytes()),
        (
            args.out.join("trajectory.json"),
            serde_json::to_string(&trajectory)?.into_bytes(),
        ),
    ])
}

/// What a ROS 2 robot executes (`ros2/` in the output directory): the goals of the
/// controller's FollowJointTrajectory action for the whole program, the run with the base
/// tilted (the structure part, and the first `--tilted-poses` training poses) and the way to the
/// first pose, and the two trajectories as MCAP.
fn ros2_files(plan: &Plan, args: &PlanArgs) -> Result<Vec<(PathBuf, Vec<u8>)>> {
    use skincal::log::trajectory::{goal_yaml, mcap};
    use skincal::plan::trajectory::Section;
    let dir = args.out.join("ros2");
    let topic = format!("/{}/joint_trajectory", args.controller.trim_matches('/'));
    let whole = plan.trajectory(Section::Whole, args.knot_step);
    let mut sections = vec![("", whole.clone())];
    let tilted = plan.tilted_end();
    if tilted > 0.0 && tilted < plan.duration {
        sections.push((
            "_structure",
            plan.trajectory(Section::Tilted, args.knot_step),
        ));
    }
    let mut files = vec![(
        dir.join("start.yaml"),
        goal_yaml(&whole.start_goal(args.start_time), GOAL_TIME_TOLERANCE).into_bytes(),
    )];
    for (suffix, trajectory) in sections {
        files.push((
            dir.join(format!("goal{suffix}.yaml")),
            goal_yaml(&trajectory, GOAL_TIME_TOLERANCE).into_bytes(),
        ));
        let bag = mcap(&trajectory, &topic).context("cannot write the ROS 2 trajectory")?;
        files.push((dir.join(format!("joint_trajectory{suffix}.mcap")), bag));
    }
    Ok(files)
}

/// The robot's collision body from its URDF (none for descriptions without one, or with
/// `--no-collision-check`).
fn collision_body(
    args: &PlanArgs,
    robot: &skincal::model::Robot,
) -> Result<Option<skincal::collision::Body>> {
    if !(args.clearance.is_finite() && args.clearance >= 0.0) {
        bail!(
            "--clearance {}: give a distance in m, 0 or more",
            args.clearance
        );
    }
    if args.floor.is_some_and(|f| !f.is_finite()) {
        bail!("--floor: give a height in m");
    }
    if args.no_collision_check {
        return Ok(None);
    }
    let Some(urdf) = io::urdf_of(&args.robot)? else {
        if args.srdf.is_some() || args.floor.is_some() {
            bail!(
                "--srdf and --floor need the robot's collision geometry: give --robot as a URDF \
                 (or a description that names one)"
            );
        }
        return Ok(None);
    };
    let options = skincal::collision::CollisionOptions {
        clearance: args.clearance,
        floor: args.floor,
        disabled: Vec::new(),
    };
    let body = io::load_body(&urdf, robot, args.srdf.as_deref(), &options).context(
        "cannot check the program against the robot's body (--no-collision-check skips it)",
    )?;
    Ok(Some(body))
}

fn render_collision(plan: &Plan, body: Option<&skincal::collision::Body>) -> String {
    use std::fmt::Write as _;
    let (Some(body), Some(check)) = (body, &plan.collision) else {
        return "Self-collision: not checked (no URDF collision geometry): the program keeps the \
                joint limits only"
            .into();
    };
    let mut s = format!(
        "Self-collision: {} parts of the URDF's collision geometry, {} pairs checked at {} poses \
         ({} mm clearance{}); {} pairs of adjacent links{} not checked",
        body.part_count(),
        body.pair_count(),
        check.checked,
        body.options().clearance * 1e3,
        body.options()
            .floor
            .map(|f| format!(", floor at {f} m"))
            .unwrap_or_default(),
        body.excluded()
            .iter()
            .filter(|e| e.why == skincal::collision::Exclusion::Adjacent)
            .count(),
        match body
            .excluded()
            .iter()
            .filter(|e| e.why == skincal::collision::Exclusion::Srdf)
            .count()
        {
            0 => String::new(),
            n => format!(" and {n} the SRDF disables"),
        }
    );
    if !body.touching_at_rest().is_empty() {
        let _ =
            write!(
            s,
            "\n  {} link pairs touch at the rest pose (checked against coming {} mm nearer): {}",
            body.touching_at_rest().len(),
            skincal::collision::REST_SLACK * 1e3,
            body.touching_at_rest()
                .iter()
                .take(4)
                .map(|c| format!("{}–{}", c.a, c.b))
                .collect::<Vec<_>>()
                .join(", ")
                + if body.touching_at_rest().len() > 4 { ", …" } else { "" }
        );
    }
    if check.redrawn_poses + check.redrawn_sweeps > 0 {
        let _ = write!(
            s,
            "\n  mended where they touched (drawn again nearer the rest pose): {} training poses or transfers, {} sweeps",
            check.redrawn_poses, check.redrawn_sweeps
        );
    }
    if check.contacts.is_empty() {
        s.push_str("\n  no contact in the program");
    } else {
        let _ = write!(
            s,
            "\n  WARNING: the program still touches {} times (the structure part's moves are \
             fixed: change --structure-angle or --range):",
            check.contacts.len()
        );
        for c in check.contacts.iter().take(5) {
            let _ = write!(s, "\n    at {:.2} s: {}", c.time, c.what);
        }
    }
    s
}

/// Time a controller may take past a goal's last knot, s.
const GOAL_TIME_TOLERANCE: f64 = 0.5;

/// The plan, with its forecast when the description allows one (and as many poses as
/// `--accuracy` needs), and a line about the forecast.
fn planned(
    robot: &skincal::model::Robot,
    dofs: Vec<PlanDof>,
    config: &PlanConfig,
    args: &PlanArgs,
    accuracy: Option<f64>,
    clearance: Option<&(dyn skincal::plan::Clearance + Sync)>,
) -> Result<(Plan, String)> {
    use skincal::design;
    let context = "cannot plan the exploration";
    if let (Some(target), true) = (accuracy, config.training) {
        // A continuous program searches the sweep's length, any other the training poses.
        let sweep = config.sweep > 0.0;
        let search = if sweep {
            design::sweep_for
        } else {
            design::poses_for
        };
        let (plan, forecast) = search(
            robot,
            &dofs,
            config,
            (target, args.sample_noise),
            clearance,
            &mut design_progress(target),
        )
        .context(context)?;
        let met = forecast.worst() <= target;
        let note = match (sweep, met) {
            (true, true) => format!(
                "a sweep of {} s meets {target} m/s² held-out RMS by the forecast (--accuracy)",
                plan.config.sweep
            ),
            (true, false) => format!(
                "warning: even a sweep of {} s misses --accuracy {target} m/s² by the forecast",
                plan.config.sweep
            ),
            (false, true) => format!(
                "{} training poses (the best of {} draws) meet {target} m/s² held-out RMS by the forecast \
                 (--accuracy)",
                forecast.poses,
                design::CANDIDATES
            ),
            (false, false) => format!(
                "warning: even {} training poses miss --accuracy {target} m/s² by the forecast",
                forecast.poses
            ),
        };
        return Ok((plan, note));
    }
    let mut plan = Plan::new_clear(
        dofs,
        config,
        clearance.map(|c| c as &dyn skincal::plan::Clearance),
    )
    .context(context)?;
    if args.no_forecast || !config.training {
        return Ok((plan, String::new()));
    }
    let note = match design::forecast_plan(robot, &mut plan, args.sample_noise) {
        Ok(()) => String::new(),
        Err(e) => format!("note: no forecast: {e}"),
    };
    Ok((plan, note))
}

fn render_plan(plan: &Plan) -> String {
    use std::fmt::Write as _;
    let mut s = String::new();
    let sweep = plan.phases.iter().find_map(|phase| match &phase.action {
        Action::Sweep(sweep) => Some((sweep, phase.duration)),
        _ => None,
    });
    if let Some((sweep, duration)) = sweep {
        render_sweep(&mut s, plan, sweep, duration);
    } else {
        render_pattern(&mut s, plan);
    }
    let assumed: Vec<&str> = plan
        .dofs
        .iter()
        .filter(|d| d.velocity_assumed || d.acceleration_assumed)
        .map(|d| d.name.as_str())
        .collect();
    if !assumed.is_empty() {
        let _ = writeln!(
            s,
            "  note: no velocity/acceleration limit given for {} DoF(s) ({}…); assumed {} rad/s and \
             {} rad/s² — give real limits with --velocity/--acceleration",
            assumed.len(),
            assumed.iter().take(3).copied().collect::<Vec<_>>().join(", "),
            skincal::plan::DEFAULT_VELOCITY,
            skincal::plan::DEFAULT_ACCELERATION
        );
    }
    let (still, moving, exciting) = plan.time_by_action();
    let exciting_what = if sweep.is_some() {
        "continuous motion"
    } else {
        "excitations"
    };
    let count = |f: &dyn Fn(&Action) -> bool| plan.phases.iter().filter(|p| f(&p.action)).count();
    let _ = writeln!(
        s,
        "\nProgram: {:.1} s in all ({:.1} s still, {:.1} s moves and transfers, {:.1} s {exciting_what})",
        plan.duration, still, moving, exciting
    );
    if plan.config.structure {
        let _ = writeln!(
            s,
            "  structure experiment: 0 – {:.1} s, {} single-DoF moves of {} rad from the rest pose \
             and back",
            plan.structure_duration,
            count(&|a| matches!(a, Action::Move { .. })),
            plan.config.structure_angle
        );
    }
    if plan.config.structure && sweep.is_some() {
        let _ = writeln!(
            s,
            "  one log, upright, is enough: `skincal ingest` tells what a DoF about a vertical \
             axis moves from what its\n  structure move accelerated (a second recording of the \
             structure part with the base tilted by about 90°\n  adds static readings in another \
             orientation; give both logs to `skincal ingest`)."
        );
    } else if plan.config.structure && plan.config.tilted_poses == 0 {
        let _ = writeln!(
            s,
            "  OPERATOR: record the structure part twice, in two base orientations — upright, then \
             with the base\n  tilted by about 90° — as separate logs, and give both to `skincal \
             ingest` (a vertical axis cannot be seen in one orientation)."
        );
    }
    if plan.config.tilted_poses > 0 {
        let _ = writeln!(
            s,
            "  OPERATOR: record the whole program upright, then the tilted run — 0 – {:.1} s: the \
             structure part and the first\n  {} training poses — with the base tilted by about \
             90° (`goal_structure.yaml`; simulated: `record --part tilted --tilted`),\n  as \
             separate logs, and give both to `skincal ingest`: the tilted poses' static readings \
             tell what no upright pose can.",
            plan.tilted_end(),
            plan.config.tilted_poses.min(plan.config.poses)
        );
    }
    if plan.config.training && sweep.is_some() {
        let _ = writeln!(
            s,
            "  training experiment: {:.1} – {:.1} s, every DoF at once along its path (no still \
             period): `skincal ingest` keeps every sample for the time-domain fit",
            plan.structure_duration, plan.duration
        );
    } else if plan.config.training {
        let windows = count(&|a| matches!(a, Action::Excitation { .. }));
        let driven = plan.dofs.len() - plan.mimic_specs().len();
        let _ = writeln!(
            s,
            "  training experiment: {:.1} – {:.1} s, {} poses × {} DoFs{}",
            plan.structure_duration,
            plan.duration,
            plan.config.poses,
            driven,
            if windows < plan.config.poses * driven {
                format!(
                    " in {} excitation windows ({} per pose: the limbs in parallel, the DoFs at \
                     one depth of the tree at a time)",
                    windows,
                    windows / plan.config.poses.max(1)
                )
            } else {
                format!(" = {windows} excitations, one DoF at a time")
            }
        );
    }
    if let Some(f) = &plan.forecast {
        render_forecast(&mut s, f, sweep.is_some(), plan.config.tilted_poses);
    }
    s
}

/// What the plan's forecast expects the calibration to reach.
fn render_forecast(s: &mut String, f: &skincal::plan::Forecast, sweep: bool, tilted: usize) {
    use std::fmt::Write as _;
    if sweep {
        let _ = writeln!(
            s,
            "\nForecast: held-out RMS static {:.4} m/s², dynamic {:.4} m/s² from the sweep\n  \
             (recorded once on the description with sample noise {:.3} m/s², a block mean's \
             {:.4};\n  calibrated from its motion alone with the description's tree, against {} \
             held-out poses)",
            f.static_rms, f.dynamic_rms, f.noise.sample_sd, f.noise.static_sd, f.held_out
        );
    } else {
        let _ = writeln!(
            s,
            "\nForecast: held-out RMS static {:.4} m/s², dynamic {:.4} m/s² from the {} training \
             poses\n  (readings' noise static {:.4}, dynamic {:.4} m/s² from one recorded pose with \
             sample noise {:.3} m/s²;\n  calibrated on the description's skin at the plan's poses, \
             mean over {} noise draws, against {} held-out poses)",
            f.static_rms,
            f.dynamic_rms,
            f.poses,
            f.noise.static_sd,
            f.noise.dynamic_sd,
            f.noise.sample_sd,
            f.trials,
            f.held_out
        );
    }
    let weak = f.weakest_dofs(WEAK_DOF);
    if !weak.is_empty() {
        let list: Vec<String> = weak
            .iter()
            .take(4)
            .map(|(d, r)| format!("{} {:.4} m/s² ({r:.2}×)", d.dof, d.dynamic_rms))
            .collect();
        let more = weak.len().saturating_sub(4);
        let _ = writeln!(
            s,
            "  DoFs forecast above {WEAK_DOF}× the median DoF's dynamic error: {}{}\n  (each: every SU \
             it moves; {})",
            list.join(", "),
            if more > 0 { format!(" and {more} more") } else { String::new() },
            skincal::predict::UNEVEN_DOFS
        );
    }
    if !f.off_noise.is_empty() {
        let list: Vec<String> = f
            .off_noise
            .iter()
            .map(|o| {
                format!(
                    "{} ({} of {} draws, up to {:.1} σ)",
                    o.limb, o.draws, f.trials, o.residual
                )
            })
            .collect();
        let _ = writeln!(
            s,
            "  WARNING: limbs whose fit ended off the noise level: {}\n  (the program's poses do \
             not tell their kinematics apart, and the errors above include that misfit: more \
             poses, `--poses N`, or a wider `--pose-range`)",
            list.join(", ")
        );
    }
    if !f.partly_measured.is_empty() {
        let list: Vec<String> = f
            .partly_measured
            .iter()
            .map(|p| {
                let mut left = Vec::new();
                if p.positions > 0 {
                    left.push(format!("{} position direction(s)", p.positions));
                }
                if p.turns > 0 {
                    left.push(format!("{} turn(s)", p.turns));
                }
                format!("{} ({})", p.su, left.join(", "))
            })
            .collect();
        let _ = writeln!(
            s,
            "  partly measured (what no reading of the plan tells, relative to the SU before): {}",
            list.join(", ")
        );
        if tilted > 0 {
            let _ = writeln!(
                s,
                "  (with the {tilted} tilted poses; a position along a vertical first axis no \
                 accelerometer tells)"
            );
        } else if f.partly_measured.iter().any(|p| p.turns > 0) {
            let _ = writeln!(
                s,
                "  `--tilted-poses N` runs N poses again with the base tilted: their readings \
                 tell those turns"
            );
        }
    }
}

/// How many times the median DoF's forecast dynamic error a DoF's must exceed to be named.
const WEAK_DOF: f64 = 1.3;

/// The excitation pattern and its window.
fn render_pattern(s: &mut String, plan: &Plan) {
    use std::fmt::Write as _;
    let p = &plan.pattern;
    let _ = writeln!(
        s,
        "Excitation pattern: A = {:.4} rad/s, f = {:.3} Hz → peak α = 2πfA = {:.3} rad/s², excursion \
         A/(πf) = {:.4} rad ({:.2}°)",
        p.amplitude,
        p.frequency,
        p.peak_acceleration(),
        p.excursion(),
        p.excursion().to_degrees()
    );
    let _ = writeln!(s, "  limited by {}", plan.pattern_limited_by);
    let prismatic = plan.prismatic_dof_names();
    if !prismatic.is_empty() {
        let scale = skincal::model::PRISMATIC_PATTERN_SCALE;
        let _ = writeln!(
            s,
            "  prismatic {}: the pattern scaled by {scale} m per rad (A = {:.4} m/s, peak {:.3} m/s², excursion {:.4} m)",
            prismatic.join(", "),
            p.amplitude * scale,
            p.peak_acceleration() * scale,
            p.excursion() * scale
        );
    }
    for (follower, m) in plan.mimic_specs() {
        let _ = writeln!(
            s,
            "  mimic {follower}: follows {} (× {}{}), never moved alone and left out of the ROS 2 goals",
            m.leader,
            m.multiplier,
            if m.offset == 0.0 {
                String::new()
            } else {
                format!(", {:+}", m.offset)
            }
        );
    }
    let _ = writeln!(
        s,
        "  window: {} period(s) rise, {} at full amplitude, {} fall ({:.2} s per excitation)",
        plan.window.ramp_cycles,
        plan.window.hold_cycles,
        plan.window.ramp_cycles,
        plan.window.duration(p.frequency)
    );
}

/// The continuous motion: its frequencies and how much of each limit the paths use.
fn render_sweep(s: &mut String, plan: &Plan, sweep: &skincal::plan::Sweep, duration: f64) {
    use std::fmt::Write as _;
    let highest = sweep.frequency * sweep.harmonics.iter().map(Vec::len).max().unwrap_or(1) as f64;
    let _ = writeln!(
        s,
        "Continuous motion: {duration:.1} s of every DoF at once, {} harmonics of {:.3} Hz (up to \
         {highest:.3} Hz), {:.1} s rise and fall",
        sweep.harmonics.first().map_or(0, Vec::len),
        sweep.frequency,
        sweep.ramp
    );
    let (mut range, mut velocity, mut acceleration) = (0.0f64, 0.0f64, 0.0f64);
    for (d, dof) in plan.dofs.iter().enumerate() {
        let [q, v, a] = sweep.peaks(d, duration);
        range = range.max(q);
        velocity = velocity.max(v / dof.velocity);
        acceleration = acceleration.max(a / dof.acceleration);
    }
    let _ = writeln!(
        s,
        "  paths reach ±{range:.2} rad about the middle of each range, {:.0} % of a velocity limit, \
         {:.0} % of an acceleration limit at most",
        100.0 * velocity,
        100.0 * acceleration
    );
}
