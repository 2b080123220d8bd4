//! # skincal
//!
//! Self-calibration of robots covered with artificial skin, from the skin's own accelerometers:
//! no camera, tracker or CAD model. The method follows Mittendorfer and Cheng, *Open-loop
//! self-calibration of articulated robots with artificial skins*:
//!
//! 1. **Structural exploration** — which sensor unit (SU) moves with which DoF, merged into
//!    segments and joints and sorted into a kinematic tree.
//! 2. **Kinematic estimation** — Denavit–Hartenberg chains and SU frames fitted to static gravity
//!    readings and to the accelerations of short excitation patterns.
//!
//! Modules, in the direction their dependencies point (ARCHITECTURE.md has the map):
//!
//! - [`model`]: the kinematic tree, DH and URDF placements, the sensor model, robot descriptions;
//! - [`measurements`]: the measurement-set contract; [`motion`]: the motion record of a log;
//! - [`plan`]: the exploration program; [`collision`]: self-collision on a URDF's geometry;
//! - [`log`]: ROS 2 (MCAP, rosbag2), ROS 1 and CSV logs, read and written as streams;
//! - [`sim`]: simulated experiments and logs with the ground truth;
//! - [`explore`]: structural exploration (the activity matrix, the tree);
//! - [`ingest`]: logs into a measurement set and a motion record;
//! - [`estimate`]: kinematic estimation (the paper's estimator, maximum likelihood, the body);
//! - [`predict`]: what a calibrated model predicts, checked against a measurement set;
//! - [`design`]: what a plan can be expected to reach; [`align`]: the model on the robot's URDF;
//! - [`check`]: whether the skin still reads what a model predicts in any motion, and what changed;
//! - [`report`] and [`html`]: text and the report page; [`io`]: every file read and written.
//!
//! Units are SI throughout: m, rad, s, m/s².
//!
//! ```
//! use skincal::model::{presets, forward_kinematics};
//! let robot = presets::find("paper-7dof").unwrap().robot().unwrap();
//! let q = vec![0.0; robot.model.dofs().len()];
//! let frames = forward_kinematics(&robot.model, &robot.parameters, &q);
//! assert_eq!(frames.sus.len(), 7);
//! ```

#![warn(missing_docs)]

pub mod align;
pub mod check;
pub mod collision;
pub mod design;
pub mod estimate;
pub mod explore;
pub mod html;
pub mod ingest;
pub mod io;
mod json;
pub mod log;
pub mod measurements;
pub mod model;
pub mod motion;
pub mod plan;
pub mod predict;
pub mod report;
mod show;
pub mod sim;
