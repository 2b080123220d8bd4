//! Forward kinematics of the segment tree (paper eq. 4, generalised to trees).

use nalgebra::{Isometry3, RealField, Vector3};

use super::transform::{rotation_about, vector};
use super::{DofIndex, RobotModel, SuIndex};

/// The frames of one configuration, all expressed in the reference frame.
#[derive(Debug, Clone, PartialEq)]
pub struct Kinematics<T: RealField> {
    /// Per DoF: its joint frame (before its own rotation), `T_ref←joint`.
    pub joints: Vec<Isometry3<T>>,
    /// Per segment: `T_ref←segment`.
    pub segments: Vec<Isometry3<T>>,
    /// Per SU: `T_ref←SU`.
    pub sus: Vec<Isometry3<T>>,
}

impl<T: RealField> Kinematics<T> {
    /// Unit axis of `dof` in the reference frame.
    pub fn axis(&self, model: &RobotModel, dof: DofIndex) -> Vector3<T> {
        self.joints[dof]
            .rotation
            .transform_vector(&vector::<T>(model.dofs()[dof].axis.as_ref()))
    }

    /// A point on the axis of `dof` (its joint frame origin), in the reference frame.
    pub fn axis_point(&self, dof: DofIndex) -> Vector3<T> {
        self.joints[dof].translation.vector.clone()
    }

    /// Position of SU `su` in the reference frame.
    pub fn su_position(&self, su: SuIndex) -> Vector3<T> {
        self.sus[su].translation.vector.clone()
    }
}

/// Frames of every joint, segment and SU at pose `q` (one angle per DoF, rad).
///
/// Segments are visited in topological order, so every parent frame is ready before its children:
/// `T_ref←child = T_ref←parent · T_origin · Rot(axis, q)`; `T_ref←SU = T_ref←segment · T_SU`.
///
/// # Panics
/// If `parameters` or `q` do not have the model's lengths (a programming error: measurement files
/// are checked against the model when they are read).
pub fn forward_kinematics<T: RealField>(
    model: &RobotModel,
    parameters: &[T],
    q: &[T],
) -> Kinematics<T> {
    assert_eq!(
        parameters.len(),
        model.parameter_count(),
        "parameter vector length"
    );
    assert_eq!(q.len(), model.dofs().len(), "pose vector length");
    let mut segments = vec![Isometry3::identity(); model.segments().len()];
    let mut joints = vec![Isometry3::identity(); model.dofs().len()];
    for (s, segment) in model.segments().iter().enumerate().skip(1) {
        let d = segment
            .parent_dof
            .expect("non-root segments have a parent DoF");
        let dof = &model.dofs()[d];
        let joint = segments[dof.parent].clone() * dof.origin.transform(parameters);
        segments[s] = joint.clone() * rotation_about(&dof.axis, q[d].clone());
        joints[d] = joint;
    }
    let sus = model
        .sus()
        .iter()
        .map(|su| segments[su.segment].clone() * su.placement.transform(parameters))
        .collect();
    Kinematics {
        joints,
        segments,
        sus,
    }
}
