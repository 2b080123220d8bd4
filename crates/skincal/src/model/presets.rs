//! Built-in robots, written in the TOML description format and compiled into the library.

use super::description::{DescriptionError, RobotFile};
use super::Robot;

/// A built-in robot.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Preset {
    /// Name to pass to `--robot`.
    pub name: &'static str,
    /// The description text (TOML).
    pub toml: &'static str,
}

/// Every built-in robot.
pub const PRESETS: &[Preset] = &[
    Preset {
        name: "paper-7dof",
        toml: include_str!("../../presets/paper-7dof.toml"),
    },
    Preset {
        name: "humanoid",
        toml: include_str!("../../presets/humanoid.toml"),
    },
];

/// The paper's own estimate of `paper-7dof` (its Fig. 6 `est` columns) in the description format:
/// reference data for comparing estimators, not a robot to simulate.
pub const PAPER_FIG6_ESTIMATE: Preset = Preset {
    name: "paper-7dof-fig6-estimate",
    toml: include_str!("../../presets/paper-7dof-fig6-estimate.toml"),
};

/// The built-in robot with this name, if there is one.
pub fn find(name: &str) -> Option<&'static Preset> {
    PRESETS.iter().find(|p| p.name == name)
}

impl Preset {
    /// The parsed description.
    pub fn file(&self) -> Result<RobotFile, DescriptionError> {
        RobotFile::from_toml(self.toml)
    }

    /// The robot.
    pub fn robot(&self) -> Result<Robot, DescriptionError> {
        self.file()?.build()
    }
}
