//! The estimate's uncertainty: DH standard deviations, the joints' covariance, and each SU's
//! pose relative to the one before with the directions no reading determines.

use super::*;

pub(super) fn column_names(dofs: &[String], sus: &[String], spec: &Spec) -> Vec<String> {
    spec.columns()
        .iter()
        .map(|&(b, c)| match spec.blocks[b] {
            Block::Gravity => format!("gravity.{}", ["x", "y", "z"][c]),
            Block::GravityDirection => format!("gravity.{}", ["tilt_1", "tilt_2"][c]),
            Block::OtherGravity(o) => format!("gravity_{o}.{}", ["x", "y", "z"][c]),
            Block::Intrinsics(u) => format!("{}.{}", sus[u], INTRINSIC_NAMES[c]),
            Block::Joint(k) => format!(
                "{}.{}",
                dofs[k],
                ["tilt_x", "tilt_y", "shift_x", "shift_y"][c]
            ),
            Block::JointFull(k) => {
                format!("{}.{}", dofs[k], ["rx", "ry", "rz", "x", "y", "z"][c])
            }
            Block::Su(u) => format!(
                "{}.{}",
                sus[u],
                ["rotation_x", "rotation_y", "rotation_z", "x", "y", "z"][c]
            ),
            Block::SkinDelay => "skin.delay".into(),
        })
        .collect()
}

/// The standard deviations of a DH+2 table's values: its Jacobian with respect to the joint lines
/// and SU frames (central differences through the table's construction) and the parameter
/// covariance. Empty when a perturbed chain has no DH+2 form.
pub(super) fn dh_sd(
    state: &ChainState,
    spec: &Spec,
    covariance: &DMatrix<f64>,
    data: &LimbData,
    table: (&[crate::estimate::DhRow], &[crate::estimate::SuRow]),
) -> (Vec<crate::estimate::DhRow>, Vec<crate::estimate::SuRow>) {
    // Angles sit at these places of each row's values; their differences are wrapped.
    const DOF_ANGLES: [bool; 4] = [true, false, false, true];
    const SU_ANGLES: [bool; 6] = [true, false, false, true, true, false];
    let flatten =
        |rows: (&[crate::estimate::DhRow], &[crate::estimate::SuRow])| -> Vec<(f64, bool)> {
            let dof = rows
                .0
                .iter()
                .flat_map(|r| r.values().into_iter().zip(DOF_ANGLES));
            dof.chain(
                rows.1
                    .iter()
                    .flat_map(|r| r.values().into_iter().zip(SU_ANGLES)),
            )
            .collect()
        };
    let nominal = flatten(table);
    let all = spec.columns();
    let columns: Vec<usize> = all
        .iter()
        .enumerate()
        .filter(|(_, &(b, _))| {
            matches!(
                spec.blocks[b],
                Block::Joint(_) | Block::JointFull(_) | Block::Su(_)
            )
        })
        .map(|(i, _)| i)
        .collect();
    let h = 1e-6;
    let mut jacobian = DMatrix::zeros(nominal.len(), columns.len());
    for (j, &c) in columns.iter().enumerate() {
        let mut values = [0.0; 2].map(|_| Vec::new());
        for (side, sign) in [1.0, -1.0].into_iter().enumerate() {
            let mut delta = vec![0.0; all.len()];
            delta[c] = sign * h;
            let moved = retract_columns(state, spec, &all, &delta);
            let Ok(robot) = limb_robot(&data.chain, &moved, &data.su_depth) else {
                return (Vec::new(), Vec::new());
            };
            let Some((a, b)) = crate::estimate::dh_form(&robot, &data.chain) else {
                return (Vec::new(), Vec::new());
            };
            values[side] = flatten((&a, &b));
        }
        if values[0].len() != nominal.len() || values[1].len() != nominal.len() {
            return (Vec::new(), Vec::new());
        }
        for (i, &(_, angle)) in nominal.iter().enumerate() {
            let mut d = values[0][i].0 - values[1][i].0;
            if angle {
                d = d.sin().atan2(d.cos());
            }
            jacobian[(i, j)] = d / (2.0 * h);
        }
    }
    let sigma = DMatrix::from_fn(columns.len(), columns.len(), |a, b| {
        covariance[(columns[a], columns[b])]
    });
    let variance = (&jacobian * sigma * jacobian.transpose()).diagonal();
    let sd: Vec<f64> = variance.iter().map(|v| v.max(0.0).sqrt()).collect();
    let (dof, su) = sd.split_at(4 * table.0.len());
    (
        dof.chunks(4)
            .map(crate::estimate::DhRow::from_values)
            .collect(),
        su.chunks(6)
            .map(crate::estimate::SuRow::from_values)
            .collect(),
    )
}

/// The joint-line block of the parameter covariance.
pub(super) fn joint_covariance(
    spec: &Spec,
    dofs: &[String],
    covariance: &DMatrix<f64>,
) -> Option<JointCovariance> {
    let columns = spec.columns();
    let mut joints: Vec<usize> = Vec::new();
    let mut index: Vec<(usize, usize, usize)> = Vec::new(); // (column, joint slot, component)
    for (col, &(b, c)) in columns.iter().enumerate() {
        if let Block::Joint(k) = spec.blocks[b] {
            let slot = match joints.iter().position(|&j| j == k) {
                Some(slot) => slot,
                None => {
                    joints.push(k);
                    joints.len() - 1
                }
            };
            index.push((col, slot, c));
        }
    }
    if joints.is_empty() {
        return None;
    }
    let n = 4 * joints.len();
    let mut matrix = vec![vec![0.0; n]; n];
    for &(ca, ja, a) in &index {
        for &(cb, jb, b) in &index {
            matrix[4 * ja + a][4 * jb + b] = covariance[(ca, cb)];
        }
    }
    Some(JointCovariance {
        dofs: joints.iter().map(|&k| dofs[k].clone()).collect(),
        matrix,
    })
}

/// Pose of SU `u` relative to the previous SU (reference for the first) at q = 0.
pub(super) fn relative_pose(state: &ChainState, layout: &Layout, u: usize) -> Isometry3<f64> {
    let f = frames(
        state,
        layout,
        &vec![Isometry3::identity(); layout.dofs],
        None,
        layout.dofs,
    );
    if u == 0 {
        f.sus[0]
    } else {
        f.sus[u - 1].inverse() * f.sus[u]
    }
}

/// A change of an SU's relative pose smaller than this per unit step along a free direction (m or
/// rad per unit of the direction) does not count as the direction moving it.
pub(super) const FREE_MOTION: f64 = 1e-6;

/// Unit vectors spanning `vectors` (Gram–Schmidt), those shorter than [`FREE_MOTION`] left out.
pub(super) fn span_of(vectors: &[Vector3<f64>]) -> Vec<Vector3<f64>> {
    let mut basis: Vec<Vector3<f64>> = Vec::new();
    for v in vectors {
        let mut r = *v;
        for b in &basis {
            r -= b * b.dot(&r);
        }
        if r.norm() > FREE_MOTION.max(1e-3 * v.norm()) && basis.len() < 3 {
            basis.push(r.normalize());
        }
    }
    basis
}

/// The standard deviation left in a 3×3 covariance once the directions of `basis` are taken out.
pub(super) fn sd_without(cov: &Matrix3<f64>, basis: &[Vector3<f64>]) -> f64 {
    let p = basis
        .iter()
        .fold(Matrix3::identity(), |p, b| p - b * b.transpose());
    (p * cov * p).trace().max(0.0).sqrt()
}

/// `spec` with the gauge released: its SUs' held components freed (the gauge holds one SU's turn
/// about and shift along the first axis, which fixes a direction without being it: the free
/// motion is a turn about the axis itself).
pub(super) fn released(spec: &Spec) -> Spec {
    let mut open = spec.clone();
    open.held
        .retain(|(b, _)| !matches!(spec.blocks[*b], Block::Su(_)));
    open
}

/// The directions no reading determines: the null directions of `normal`, the normal system of
/// the problem with its gauge released ([`released`], whose columns `map` maps), as unit vectors
/// over its columns.
pub(super) fn free_directions(normal: &Normal, map: &ColumnMap) -> Vec<DVector<f64>> {
    let names = vec![String::new(); map.len()];
    problem::eliminate(normal, map, &names, f64::INFINITY).free
}

/// Each SU's pose uncertainty relative to the previous SU, and the directions of it that no
/// reading determines: the images of the free directions of the problem with its gauge released
/// ([`free_directions`]).
pub(super) fn su_uncertainty(
    state: &ChainState,
    layout: &Layout,
    spec: &Spec,
    names: &[String],
    covariance: &DMatrix<f64>,
    (open, free): &(Spec, Vec<DVector<f64>>),
) -> Vec<SuUncertainty> {
    let columns = spec.columns();
    let open_columns = open.columns();
    let n = columns.len();
    let h = 1e-6;
    (0..layout.su_segment.len())
        .into_par_iter()
        .map(|u| {
            let base = relative_pose(state, layout, u);
            // How a step along `column` of `these` columns moves the relative pose (position in
            // the previous SU's frame, rotation in the SU's own), per unit.
            let motion_in = |spec: &Spec,
                             these: &[(usize, usize)],
                             column: usize|
             -> Vector6<f64> {
                let mut delta = vec![0.0; these.len()];
                delta[column] = h;
                let plus = relative_pose(&retract_columns(state, spec, these, &delta), layout, u);
                delta[column] = -h;
                let minus = relative_pose(&retract_columns(state, spec, these, &delta), layout, u);
                let dt = (plus.translation.vector - minus.translation.vector) / (2.0 * h);
                let dr = ((base.rotation.inverse() * plus.rotation).scaled_axis()
                    - (base.rotation.inverse() * minus.rotation).scaled_axis())
                    / (2.0 * h);
                Vector6::new(dt.x, dt.y, dt.z, dr.x, dr.y, dr.z)
            };
            // Only the two SUs' own blocks and the joints move the relative pose (no intrinsics,
            // no gravity).
            let moves = |b: usize| match spec.blocks[b] {
                Block::Su(v) => v == u || v + 1 == u,
                Block::Intrinsics(_)
                | Block::Gravity
                | Block::GravityDirection
                | Block::OtherGravity(_)
                | Block::SkinDelay => false,
                Block::Joint(_) | Block::JointFull(_) => true,
            };
            // How each column moves the pose, once, over the open problem's columns (the
            // fitted problem's are among them).
            let moved: Vec<(usize, Vector6<f64>)> = (0..open_columns.len())
                .filter(|&c| moves(open_columns[c].0))
                .map(|c| (c, motion_in(open, &open_columns, c)))
                .collect();
            let relevant: Vec<usize> = (0..n).filter(|&c| moves(columns[c].0)).collect();
            let mut jac = DMatrix::zeros(6, relevant.len());
            for (j, &c) in relevant.iter().enumerate() {
                let m = moved
                    .iter()
                    .find(|(o, _)| open_columns[*o] == columns[c])
                    .map_or_else(|| motion_in(spec, &columns, c), |(_, m)| *m);
                jac.set_column(j, &m);
            }
            let sub = DMatrix::from_fn(relevant.len(), relevant.len(), |a, b| {
                covariance[(relevant[a], relevant[b])]
            });
            let cov = &jac * sub * jac.transpose();
            // What no reading tells: the images of the free directions with the gauge released.
            let unmoored: Vec<Vector6<f64>> = free
                .iter()
                .map(|f| moved.iter().map(|(c, m)| m * f[*c]).sum())
                .collect();
            let position = span_of(
                &unmoored
                    .iter()
                    .map(|m| m.fixed_rows::<3>(0).into_owned())
                    .collect::<Vec<_>>(),
            );
            let orientation = span_of(
                &unmoored
                    .iter()
                    .map(|m| m.fixed_rows::<3>(3).into_owned())
                    .collect::<Vec<_>>(),
            );
            let block = |r: usize| Matrix3::from_fn(|i, j| cov[(r + i, r + j)]);
            SuUncertainty {
                su: names[u].clone(),
                position_sd: sd_without(&block(0), &position),
                orientation_sd: sd_without(&block(3), &orientation),
                undetermined_position: position.iter().map(|v| (*v).into()).collect(),
                undetermined_orientation: orientation.iter().map(|v| (*v).into()).collect(),
            }
        })
        .collect()
}
