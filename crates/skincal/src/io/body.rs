//! A robot's collision body from its URDF file: mesh files found as ROS finds them.

use std::path::{Path, PathBuf};

use crate::collision::{srdf_disabled_pairs, Body, CollisionOptions};
use crate::model::Robot;

use super::{read, IoError};

/// The collision body of `robot`, loaded from the URDF file `urdf`, with the link pairs the SRDF
/// file `srdf` disables (if given) added to `options`. Mesh file names are resolved by
/// [`resolve_mesh`].
pub fn load_body(
    urdf: &Path,
    robot: &Robot,
    srdf: Option<&Path>,
    options: &CollisionOptions,
) -> Result<Body, IoError> {
    let text = read(urdf)?;
    let mut options = options.clone();
    if let Some(srdf) = srdf {
        let pairs = srdf_disabled_pairs(&read(srdf)?).map_err(|source| IoError::Collision {
            path: srdf.to_path_buf(),
            source,
        })?;
        options.disabled.extend(pairs);
    }
    let mut mesh = |file: &str| {
        let path = resolve_mesh(urdf, file)?;
        std::fs::read(&path).map_err(|e| format!("cannot read {}: {e}", path.display()))
    };
    Body::new(&text, robot, &options, &mut mesh).map_err(|source| IoError::Collision {
        path: urdf.to_path_buf(),
        source,
    })
}

/// The file a URDF's mesh `filename` names: `file://` paths as they are, relative paths from the
/// URDF's folder, and `package://PKG/REST` as ROS finds them — `PKG/REST` in a folder of
/// `ROS_PACKAGE_PATH`, `share/PKG/REST` under a prefix of `AMENT_PREFIX_PATH` — or, when ROS
/// is not set up, in the folders around the URDF: `PKG/REST` or `REST` (or `REST` without its
/// first folders, as descriptions unpacked from a package's `share` folder hold it) in the
/// URDF's folder or any folder above it.
pub fn resolve_mesh(urdf: &Path, filename: &str) -> Result<PathBuf, String> {
    let here = urdf.parent().unwrap_or(Path::new("."));
    if let Some(path) = filename.strip_prefix("file://") {
        let path = PathBuf::from(path);
        return if path.is_file() {
            Ok(path)
        } else {
            Err(format!("{} does not exist", path.display()))
        };
    }
    let Some(rest) = filename.strip_prefix("package://") else {
        let path = here.join(filename);
        return if path.is_file() {
            Ok(path)
        } else {
            Err(format!(
                "{} does not exist (relative to the URDF's folder)",
                path.display()
            ))
        };
    };
    let (package, rest) = rest.split_once('/').unwrap_or((rest, ""));
    let mut candidates: Vec<PathBuf> = Vec::new();
    for (variable, under) in [("ROS_PACKAGE_PATH", ""), ("AMENT_PREFIX_PATH", "share")] {
        if let Some(paths) = std::env::var_os(variable) {
            for dir in std::env::split_paths(&paths) {
                candidates.push(dir.join(under).join(package).join(rest));
            }
        }
    }
    let parts: Vec<&str> = rest.split('/').filter(|p| !p.is_empty()).collect();
    for dir in here.ancestors() {
        candidates.push(dir.join(package).join(rest));
        if dir.file_name().is_some_and(|n| n == package) {
            candidates.push(dir.join(rest));
        }
        for skip in 0..parts.len() {
            candidates.push(
                parts[skip..]
                    .iter()
                    .fold(dir.to_path_buf(), |p, c| p.join(c)),
            );
        }
    }
    candidates.into_iter().find(|p| p.is_file()).ok_or_else(|| {
        format!(
            "package `{package}` not found: set ROS_PACKAGE_PATH to the folder that holds \
             `{package}` (or source the ROS workspace that has it), or keep the URDF inside the \
             package's folder"
        )
    })
}
