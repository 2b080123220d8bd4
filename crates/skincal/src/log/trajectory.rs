//! A plan's trajectory ([`crate::plan::trajectory`]) as a ROS 2 robot executes it: a
//! `control_msgs/action/FollowJointTrajectory` goal (YAML: the fields of the action's goal, as
//! `ros2 action send_goal` and `rosidl_runtime_py.set_message_fields` take them), or one
//! `trajectory_msgs/msg/JointTrajectory` message in an MCAP file that `ros2 bag play` publishes
//! on a joint trajectory controller's `~/joint_trajectory` topic.

use serde::Serialize;
use serde_saphyr::FlowSeq;

use super::ros::{self, Time};
use super::LogError;
use crate::plan::trajectory::Trajectory;

/// The `trajectory_msgs/msg/JointTrajectory` message (no stamp: the controller starts it on
/// arrival).
pub fn message(trajectory: &Trajectory) -> ros::JointTrajectory {
    ros::JointTrajectory {
        header: ros::Header::default(),
        joint_names: trajectory.joint_names.clone(),
        points: trajectory
            .knots
            .iter()
            .map(|k| ros::JointTrajectoryPoint {
                positions: k.positions.clone(),
                velocities: k.velocities.clone(),
                accelerations: k.accelerations.clone(),
                effort: Vec::new(),
                time_from_start: Time::from_seconds(k.time),
            })
            .collect(),
    }
}

/// An MCAP file (bytes) with the trajectory as one message on `topic` (a joint trajectory
/// controller's `/<name>/joint_trajectory`) at log time 0.
pub fn mcap(trajectory: &Trajectory, topic: &str) -> Result<Vec<u8>, LogError> {
    let data = ros::encode(&message(trajectory)).map_err(|e| LogError::Encode {
        schema: ros::JOINT_TRAJECTORY,
        reason: e.to_string(),
    })?;
    super::mcap::one_channel(
        topic,
        ros::JOINT_TRAJECTORY,
        &ros::joint_trajectory_schema(),
        &[(0, data)],
    )
    .map_err(|e| LogError::Encode {
        schema: ros::JOINT_TRAJECTORY,
        reason: e.to_string(),
    })
}

/// The `control_msgs/action/FollowJointTrajectory` goal as YAML: the trajectory, and
/// `goal_time_tolerance` s for reaching its last knot. Every number is written with a decimal
/// point, as YAML 1.1 readers (PyYAML, which ROS 2 uses) need to read it as a float.
pub fn goal_yaml(trajectory: &Trajectory, goal_time_tolerance: f64) -> String {
    let goal = Goal {
        trajectory: YamlTrajectory {
            joint_names: FlowSeq(trajectory.joint_names.clone()),
            points: trajectory
                .knots
                .iter()
                .map(|k| YamlPoint {
                    positions: FlowSeq(k.positions.clone()),
                    velocities: FlowSeq(k.velocities.clone()),
                    accelerations: FlowSeq(k.accelerations.clone()),
                    time_from_start: Time::from_seconds(k.time),
                })
                .collect(),
        },
        goal_time_tolerance: Time::from_seconds(goal_time_tolerance),
    };
    serde_saphyr::to_string(&goal).expect("a goal of numbers and names serialises")
}

#[derive(Serialize)]
struct Goal {
    trajectory: YamlTrajectory,
    goal_time_tolerance: Time,
}

#[derive(Serialize)]
struct YamlTrajectory {
    joint_names: FlowSeq<Vec<String>>,
    points: Vec<YamlPoint>,
}

#[derive(Serialize)]
struct YamlPoint {
    positions: FlowSeq<Vec<f64>>,
    velocities: FlowSeq<Vec<f64>>,
    accelerations: FlowSeq<Vec<f64>>,
    time_from_start: Time,
}
