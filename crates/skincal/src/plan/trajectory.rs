//! The plan as a joint trajectory controller executes it: knots that `log::trajectory` writes as
//! ROS 2 messages (a `control_msgs/action/FollowJointTrajectory` goal, a
//! `trajectory_msgs/msg/JointTrajectory` in MCAP).
//!
//! The trajectory has a knot at the start and end of every phase and every `step` seconds inside
//! phases that move, each with the plan's position, velocity and acceleration: a controller that
//! interpolates knots with positions, velocities and accelerations (quintic splines, as the joint
//! trajectory controller does) follows the plan to within what [`Trajectory::interpolation_error`]
//! reports, and a still period costs two knots. The first knot is the end of the first still
//! period, so the robot must stand at the plan's first pose when the goal starts (send
//! [`Trajectory::start_goal`] first).

use super::{Action, Plan};

/// Knot spacing inside moving phases that keeps the quintic interpolation of the planned
/// patterns and sweeps far below the encoders' resolution, s.
pub const DEFAULT_STEP: f64 = 0.02;

/// Which part of the program a trajectory carries.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Section {
    /// The whole program (the base upright).
    Whole,
    /// What is run again with the base tilted: the structure experiment, and the first
    /// [`super::PlanConfig::tilted_poses`] training poses ([`Plan::tilted_end`]).
    Tilted,
}

/// One knot of a joint trajectory.
#[derive(Debug, Clone, PartialEq)]
pub struct Knot {
    /// Time from the start of the trajectory, s.
    pub time: f64,
    /// rad.
    pub positions: Vec<f64>,
    /// rad/s.
    pub velocities: Vec<f64>,
    /// rad/s².
    pub accelerations: Vec<f64>,
}

/// A plan's joint trajectory, ready to be sent to a controller.
#[derive(Debug, Clone, PartialEq)]
pub struct Trajectory {
    /// The DoFs (the URDF's joint names when the robot came from a URDF).
    pub joint_names: Vec<String>,
    /// Knots in strictly increasing time.
    pub knots: Vec<Knot>,
}

impl Plan {
    /// The plan's `section` as a joint trajectory with knots every `step` s inside moving phases,
    /// of the DoFs with an actuator (a controller commands no mimic joint: it follows its leader).
    ///
    /// # Panics
    /// If `step` is not positive and finite (a programming error: the CLI checks its option).
    pub fn trajectory(&self, section: Section, step: f64) -> Trajectory {
        assert!(step.is_finite() && step > 0.0, "knot step {step}");
        let end = match section {
            Section::Whole => self.duration,
            Section::Tilted => self.tilted_end(),
        };
        let mut times: Vec<f64> = Vec::new();
        for phase in &self.phases {
            if phase.start >= end - 1e-9 {
                break;
            }
            if !matches!(phase.action, Action::Still) {
                let inner = (phase.duration / step).ceil() as usize;
                times.extend(
                    (1..inner).map(|i| phase.start + phase.duration * i as f64 / inner as f64),
                );
            }
            times.push(phase.start + phase.duration);
        }
        // The first still period's start is where the robot already stands.
        times.retain(|&t| t > 1e-9);
        times.dedup_by(|b, a| *b - *a < 1e-9);
        let driven: Vec<usize> = (0..self.dofs.len())
            .filter(|&d| self.dofs[d].mimic.is_none())
            .collect();
        let pick = |v: &[f64]| driven.iter().map(|&d| v[d]).collect::<Vec<f64>>();
        let knots = times
            .into_iter()
            .map(|t| {
                let s = self.state(t);
                Knot {
                    time: t,
                    positions: pick(&s.q),
                    velocities: pick(&s.qd),
                    accelerations: pick(&s.qdd),
                }
            })
            .collect();
        Trajectory {
            joint_names: driven.iter().map(|&d| self.dofs[d].name.clone()).collect(),
            knots,
        }
    }
}

impl Trajectory {
    /// Duration, s.
    pub fn duration(&self) -> f64 {
        self.knots.last().map_or(0.0, |k| k.time)
    }

    /// The largest difference, rad, between the plan and the quintic interpolation of the knots
    /// (each segment the polynomial that meets both knots' position, velocity and acceleration,
    /// as the joint trajectory controller's splines do), checked at `per_segment` points inside
    /// every segment: how faithfully a controller reproduces the plan from these knots.
    pub fn interpolation_error(&self, plan: &Plan, per_segment: usize) -> f64 {
        let index: Vec<Option<usize>> = self
            .joint_names
            .iter()
            .map(|n| plan.dofs.iter().position(|d| &d.name == n))
            .collect();
        let mut worst = 0.0f64;
        for pair in self.knots.windows(2) {
            let (a, b) = (&pair[0], &pair[1]);
            let h = b.time - a.time;
            for i in 1..=per_segment {
                let t = a.time + h * i as f64 / (per_segment + 1) as f64;
                let truth = plan.state(t).q;
                for (d, q) in index
                    .iter()
                    .enumerate()
                    .filter_map(|(d, i)| Some((d, truth[(*i)?])))
                {
                    let p = quintic(
                        [a.positions[d], a.velocities[d], a.accelerations[d]],
                        [b.positions[d], b.velocities[d], b.accelerations[d]],
                        h,
                        t - a.time,
                    );
                    worst = worst.max((p - q).abs());
                }
            }
        }
        worst
    }

    /// A goal of one knot, the trajectory's first pose at rest `duration` s from now: it brings
    /// the robot to where the trajectory starts.
    pub fn start_goal(&self, duration: f64) -> Trajectory {
        let first = self.knots.first();
        let n = self.joint_names.len();
        Trajectory {
            joint_names: self.joint_names.clone(),
            knots: first
                .map(|k| Knot {
                    time: duration,
                    positions: k.positions.clone(),
                    velocities: vec![0.0; n],
                    accelerations: vec![0.0; n],
                })
                .into_iter()
                .collect(),
        }
    }
}

/// The quintic with position, velocity and acceleration `a` at 0 and `b` at `h`, at `t`.
fn quintic(a: [f64; 3], b: [f64; 3], h: f64, t: f64) -> f64 {
    let (h2, h3) = (h * h, h * h * h);
    let c0 = a[0];
    let c1 = a[1];
    let c2 = a[2] / 2.0;
    let dp = b[0] - a[0] - a[1] * h - a[2] * h2 / 2.0;
    let dv = b[1] - a[1] - a[2] * h;
    let da = b[2] - a[2];
    let c3 = (20.0 * dp - 8.0 * dv * h + da * h2) / (2.0 * h3);
    let c4 = (-30.0 * dp + 14.0 * dv * h - 2.0 * da * h2) / (2.0 * h3 * h);
    let c5 = (12.0 * dp - 6.0 * dv * h + da * h2) / (2.0 * h3 * h2);
    c0 + t * (c1 + t * (c2 + t * (c3 + t * (c4 + t * c5))))
}

#[cfg(test)]
mod tests {
    use super::*;

    fn plan(config: &super::super::PlanConfig) -> Plan {
        let robot = crate::model::presets::find("paper-7dof")
            .and_then(|p| p.robot().ok())
            .expect("built in");
        Plan::new(super::super::PlanDof::from_robot(&robot), config).expect("plans")
    }

    /// The knots of the short and the continuous program: strictly increasing, and dense enough that a controller's quintic splines stay within 1e-5 rad of the
    /// plan everywhere between them (the patterns' and sweeps' own curvature decides it).
    #[test]
    fn the_knots_reproduce_the_plan_between_them() {
        for config in [
            super::super::PlanConfig::short(),
            super::super::PlanConfig::continuous(),
        ] {
            let plan = plan(&config);
            for (section, end) in [
                (Section::Whole, plan.duration),
                (Section::Tilted, plan.tilted_end()),
            ] {
                let trajectory = plan.trajectory(section, DEFAULT_STEP);
                let times: Vec<f64> = trajectory.knots.iter().map(|k| k.time).collect();
                assert!(times[0] > 0.0);
                assert!(times.windows(2).all(|w| w[1] > w[0]), "times increase");
                assert!((trajectory.duration() - end).abs() < 1e-9);
                let error = trajectory.interpolation_error(&plan, 7);
                assert!(error < 1e-5, "{section:?}: {error} rad between knots");
            }
        }
    }

    #[test]
    fn the_quintic_meets_both_ends_and_reproduces_a_quintic() {
        // p(t) = 1 + 2t − t² + 0.5t³ − 0.25t⁴ + 0.1t⁵ on [0, 2], from its values at the ends.
        let p =
            |t: f64| 1.0 + 2.0 * t - t * t + 0.5 * t.powi(3) - 0.25 * t.powi(4) + 0.1 * t.powi(5);
        let v = |t: f64| 2.0 - 2.0 * t + 1.5 * t * t - t.powi(3) + 0.5 * t.powi(4);
        let a = |t: f64| -2.0 + 3.0 * t - 3.0 * t * t + 2.0 * t.powi(3);
        let h = 2.0;
        for t in [0.0, 0.3, 1.0, 1.7, 2.0] {
            let q = quintic([p(0.0), v(0.0), a(0.0)], [p(h), v(h), a(h)], h, t);
            assert!((q - p(t)).abs() < 1e-12, "t {t}: {q} against {}", p(t));
        }
    }
}
