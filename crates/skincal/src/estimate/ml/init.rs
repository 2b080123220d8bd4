//! Closed-form starts: SU axes from accelerations, the axis lines of a multi-DoF joint and their
//! order, joint rotations from gravity, positions from upstream accelerations.

use nalgebra::{
    DMatrix, Isometry3, Matrix3, Rotation3, Translation3, Unit, UnitQuaternion, Vector3,
};

use super::problem::{frames, Layout, Readings};
use super::ChainState;
use crate::model::DofKind;

/// Rotation taking unit vector `n` onto `z`.
pub(super) fn onto_z(n: &Vector3<f64>) -> UnitQuaternion<f64> {
    UnitQuaternion::rotation_between(n, &Vector3::z()).unwrap_or_else(|| {
        UnitQuaternion::from_axis_angle(&Vector3::x_axis(), std::f64::consts::PI)
    })
}

/// The unit right singular vector of the smallest singular value of the rows, and that value².
fn null_direction(rows: &[Vector3<f64>]) -> (Vector3<f64>, f64) {
    let m = DMatrix::from_fn(rows.len(), 3, |i, c| rows[i][c]);
    let (v, value) = smallest_singular(&m);
    let n = Vector3::new(v[0], v[1], v[2]);
    (n.normalize(), if rows.len() >= 3 { value } else { 0.0 })
}

/// The right singular vector of `m`'s smallest singular value, and that value². Rows of zeros
/// are added up to the number of columns, so that the SVD has every right singular vector
/// (with fewer rows, the thin SVD's smallest would lie in the rows' span).
fn smallest_singular(m: &DMatrix<f64>) -> (nalgebra::DVector<f64>, f64) {
    let columns = m.ncols();
    let padded = DMatrix::from_fn(m.nrows().max(columns), columns, |i, c| {
        if i < m.nrows() {
            m[(i, c)]
        } else {
            0.0
        }
    });
    let svd = padded.svd(false, true);
    let vt = svd.v_t.expect("requested");
    let smallest = (0..svd.singular_values.len())
        .min_by(|&a, &b| svd.singular_values[a].total_cmp(&svd.singular_values[b]))
        .unwrap_or(0);
    (
        vt.row(smallest).transpose(),
        svd.singular_values[smallest].powi(2),
    )
}

/// Closed-form placement of SU `u` on the segment that DoF `d` moves directly: an axis direction
/// perpendicular to its DoF-`d` accelerations, the lever arm from their mean. `sign` picks the axis
/// sense. (Those accelerations are the same in every pose, so the direction is fixed only up to a
/// turn about them; the solves that follow settle it.) Without a dynamic reading of `d` the axis
/// comes from gravity ([`axis_from_gravity`]) and the lever arm is left at zero: static readings
/// cannot tell it.
pub(super) fn su_from_axis(
    state: &ChainState,
    layout: &Layout,
    data: &Readings,
    u: usize,
    d: usize,
    sign: f64,
) -> Isometry3<f64> {
    let rows: Vec<Vector3<f64>> = (0..data.q.len())
        .filter(|&p| !data.is_rejected(p, u, 1 + d))
        .map(|p| data.dynamics[p][u][d])
        .collect();
    if layout.kinds[d] == DofKind::Prismatic {
        return su_on_slide(&rows, sign);
    }
    if rows.is_empty() {
        let n = axis_from_gravity(state, layout, data, u, d) * sign;
        return Isometry3::from_parts(Translation3::identity(), onto_z(&n));
    }
    let n = null_direction(&rows).0 * sign;
    let mean: Vector3<f64> = rows.iter().sum::<Vector3<f64>>() / (rows.len() as f64 * data.alpha);
    let lever = mean.cross(&n);
    let rotation = onto_z(&n);
    Isometry3::from_parts(Translation3::from(rotation * lever), rotation)
}

/// Closed-form placement of an SU on the segment a prismatic DoF moves directly: its pattern
/// accelerates the SU along the axis alone, so the axis in the SU frame is the mean direction of
/// those accelerations (`sign` −1 gives the reverse, a start the fit should leave). Where on the
/// segment the SU sits is not told by the slide (its line may be anywhere): the SU is put at the
/// segment's origin and the joint's position found from the upstream DoFs.
fn su_on_slide(rows: &[Vector3<f64>], sign: f64) -> Isometry3<f64> {
    let mean: Vector3<f64> = rows.iter().sum();
    let n = mean.try_normalize(1e-12).unwrap_or_else(Vector3::z) * sign;
    Isometry3::from_parts(Translation3::identity(), onto_z(&n))
}

/// The axis of DoF `d` in the frame of SU `u` on the segment it moves directly, from the SU's
/// static readings `s_p` alone. Gravity seen from the segment before the DoF, `w_p`, and the SU's
/// reading have the same component along the axis (the DoF turns about it): `a·s_p = n·w_p` with
/// `a` the axis in the SU frame and `n` in that segment's. With the joints before `d` known (the
/// search's state), `(a, n)` is the null vector of the rows `[s_pᵀ, −w_pᵀ]`. For the first DoF
/// gravity is the same in every pose: the readings lie on a cone about the axis, which is the
/// null direction of the readings less their mean.
fn axis_from_gravity(
    state: &ChainState,
    layout: &Layout,
    data: &Readings,
    u: usize,
    d: usize,
) -> Vector3<f64> {
    let kept: Vec<usize> = (0..data.q.len())
        .filter(|&p| !data.is_rejected(p, u, 0))
        .collect();
    if d == 0 {
        let mean = kept
            .iter()
            .map(|&p| data.statics[p][u])
            .sum::<Vector3<f64>>()
            / kept.len().max(1) as f64;
        let rows: Vec<Vector3<f64>> = kept.iter().map(|&p| data.statics[p][u] - mean).collect();
        return null_direction(&rows).0;
    }
    // Gravity seen from the segment before the DoF, per kept pose.
    let seen: Vec<Vector3<f64>> = kept
        .iter()
        .map(|&p| {
            let segment = frames(state, layout, &data.turns[p], None, d).segments[d];
            segment.rotation.inverse() * -state.gravity
        })
        .collect();
    let m = DMatrix::from_fn(kept.len(), 6, |i, c| {
        if c < 3 {
            data.statics[kept[i]][u][c]
        } else {
            -seen[i][c - 3]
        }
    });
    let (v, _) = smallest_singular(&m);
    Vector3::new(v[0], v[1], v[2])
        .try_normalize(1e-12)
        .unwrap_or_else(Vector3::z)
}

/// Rotation by `angle` about the line through `o` along the unit vector `n`.
fn about_line(n: &Vector3<f64>, o: &Vector3<f64>, angle: f64) -> Isometry3<f64> {
    let r = UnitQuaternion::from_axis_angle(&Unit::new_unchecked(*n), angle);
    Isometry3::from_parts(Translation3::from(o - r * o), r)
}

/// An axis line: unit direction and a point on it.
type Line = (Vector3<f64>, Vector3<f64>);

/// The axis lines `(direction, point)` of a joint of several DoFs, in the frame of an SU on the
/// segment after it with the joint's DoFs at zero, and how badly they explain the accelerations.
#[derive(Debug, Clone)]
pub(super) struct JointLines {
    pub lines: Vec<(Vector3<f64>, Vector3<f64>)>,
    pub misfit: f64,
}

/// The lines of joint DoFs `dofs` (chain indices, in the assumed order along the chain) seen from
/// SU `u`.
///
/// The tangential acceleration an axis causes is perpendicular to it, and the SU sees the axis of
/// an earlier DoF turned by the later DoFs of the joint. In the SU frame the last DoF's acceleration
/// `v` is the same in every pose, so its axis lies in the plane perpendicular to `v` (one angle ψ
/// left open); for a given ψ, each earlier axis at the zero pose is the direction perpendicular to
/// all of its accelerations turned back by the later DoFs — a smallest singular vector — and its
/// position follows from the mean of the same accelerations. ψ is searched over a grid and refined;
/// `misfit` is the scatter of the accelerations about that model (m² per rad²·s⁻⁴·α⁻²), so the
/// order along the chain that explains the data has the smallest.
pub(super) fn joint_lines(data: &Readings, u: usize, dofs: &[usize]) -> JointLines {
    joint_line_starts(data, u, dofs, 1)
        .into_iter()
        .next()
        .expect("at least one start")
}

/// Up to `count` distinct starts for the lines of a multi-DoF joint (the best local minima of the
/// misfit over ψ), best first, each also with the first axis's sense reversed (noise can make the
/// closed form pick the wrong one when the lever arms are short).
pub(super) fn joint_line_starts(
    data: &Readings,
    u: usize,
    dofs: &[usize],
    count: usize,
) -> Vec<JointLines> {
    let joint = JointAccelerations::new(data, u, dofs);
    let evaluate = |psi: f64, reverse_first: bool| joint.lines(data, dofs, psi, reverse_first);
    let steps = 72;
    let step = 2.0 * std::f64::consts::PI / steps as f64;
    let grid: Vec<f64> = (0..steps)
        .map(|i| evaluate(i as f64 * step, false).misfit)
        .collect();
    let mut minima: Vec<usize> = (0..steps)
        .filter(|&i| grid[i] <= grid[(i + steps - 1) % steps] && grid[i] <= grid[(i + 1) % steps])
        .collect();
    minima.sort_by(|&a, &b| grid[a].total_cmp(&grid[b]));
    minima.truncate(count.max(1));
    let mut out = Vec::new();
    for i in minima {
        let psi = golden_section(
            &|psi| evaluate(psi, false).misfit,
            i as f64 * step,
            step,
            grid[i],
        );
        out.push(evaluate(psi, false));
        if count > 1 {
            out.push(evaluate(psi, true));
        }
    }
    out.sort_by(|a, b| a.misfit.total_cmp(&b.misfit));
    out
}

/// The minimum of `misfit` within `centre ± step` by golden sections; `centre` itself unless the
/// refinement beats `at_centre`.
fn golden_section(misfit: &dyn Fn(f64) -> f64, centre: f64, step: f64, at_centre: f64) -> f64 {
    let ratio = 0.5 * (5f64.sqrt() - 1.0);
    let (mut lo, mut hi) = (centre - step, centre + step);
    for _ in 0..30 {
        let a = hi - ratio * (hi - lo);
        let b = lo + ratio * (hi - lo);
        if misfit(a) < misfit(b) {
            hi = b;
        } else {
            lo = a;
        }
    }
    if misfit(0.5 * (lo + hi)) < at_centre {
        0.5 * (lo + hi)
    } else {
        centre
    }
}

/// One SU's accelerations from the DoFs of a joint, per trusted pose, over the pattern's
/// acceleration; the last DoF's mean `v` and the plane perpendicular to it (`e1`, `e2`) where its
/// axis lies.
struct JointAccelerations {
    /// Poses whose readings of these DoFs are all trusted.
    kept: Vec<usize>,
    scaled: Vec<Vec<Vector3<f64>>>,
    v: Vector3<f64>,
    /// The last DoF's scatter about `v`.
    base_misfit: f64,
    e1: Vector3<f64>,
    e2: Vector3<f64>,
}

impl JointAccelerations {
    fn new(data: &Readings, u: usize, dofs: &[usize]) -> Self {
        let m = dofs.len();
        let kept: Vec<usize> = (0..data.q.len())
            .filter(|&p| !dofs.iter().any(|&d| data.is_rejected(p, u, 1 + d)))
            .collect();
        let poses = kept.len().max(1);
        let scaled: Vec<Vec<Vector3<f64>>> = kept
            .iter()
            .map(|&p| {
                dofs.iter()
                    .map(|&d| data.dynamics[p][u][d] / data.alpha)
                    .collect()
            })
            .collect();
        let v: Vector3<f64> = scaled.iter().map(|s| s[m - 1]).sum::<Vector3<f64>>() / poses as f64;
        let base_misfit: f64 = scaled.iter().map(|s| (s[m - 1] - v).norm_squared()).sum();
        let direction = if v.norm() > 1e-9 {
            v.normalize()
        } else {
            Vector3::z()
        };
        let e1 = direction.cross(&Vector3::x());
        let e1 = if e1.norm() > 0.1 {
            e1.normalize()
        } else {
            direction.cross(&Vector3::y()).normalize()
        };
        let e2 = direction.cross(&e1);
        Self {
            kept,
            scaled,
            v,
            base_misfit,
            e1,
            e2,
        }
    }

    /// The joint's lines with the last axis at angle `psi` in its plane, each earlier one from
    /// its accelerations turned back by the later DoFs; `reverse_first` takes the first axis with
    /// the sense that fits worse.
    fn lines(&self, data: &Readings, dofs: &[usize], psi: f64, reverse_first: bool) -> JointLines {
        let (m, kept, scaled) = (dofs.len(), &self.kept, &self.scaled);
        let poses = kept.len().max(1);
        let n = self.e1 * psi.cos() + self.e2 * psi.sin();
        let mut lines = vec![(Vector3::zeros(), Vector3::zeros()); m];
        lines[m - 1] = (n, n.cross(&self.v));
        let mut misfit = self.base_misfit;
        for stage in (0..m - 1).rev() {
            // The SU's motion relative to the joint's zero position, caused by the later DoFs.
            let motion: Vec<Isometry3<f64>> = (0..kept.len())
                .map(|p| {
                    ((stage + 1)..m).fold(Isometry3::identity(), |g, t| {
                        g * about_line(&lines[t].0, &lines[t].1, data.q[kept[p]][dofs[t]])
                    })
                })
                .collect();
            let turned: Vec<Vector3<f64>> = (0..kept.len())
                .map(|p| motion[p].rotation * scaled[p][stage])
                .collect();
            let (n, _) = null_direction(&turned);
            let mut fits: Vec<(f64, Line)> = [1.0, -1.0]
                .iter()
                .map(|&sign| {
                    let n = n * sign;
                    let w: Vec<Vector3<f64>> = (0..kept.len())
                        .map(|p| turned[p] - n.cross(&motion[p].translation.vector))
                        .collect();
                    let mean = w.iter().sum::<Vector3<f64>>() / poses as f64;
                    let scatter: f64 = w.iter().map(|x| (x - mean).norm_squared()).sum();
                    (scatter, (n, n.cross(&mean)))
                })
                .collect();
            fits.sort_by(|a, b| a.0.total_cmp(&b.0));
            let pick = if stage == 0 && reverse_first { 1 } else { 0 };
            misfit += fits[pick].0;
            lines[stage] = fits[pick].1;
        }
        JointLines { lines, misfit }
    }
}

/// All orders of `n` items.
pub(super) fn permutations(n: usize) -> Vec<Vec<usize>> {
    if n <= 1 {
        return vec![(0..n).collect()];
    }
    let mut out = Vec::new();
    for first in 0..n {
        for rest in permutations(n - 1) {
            let mut p = vec![first];
            p.extend(rest.iter().map(|&r| if r >= first { r + 1 } else { r }));
            out.push(p);
        }
    }
    out
}

/// The state's joint frames `k0+1…k1` and SU `u`'s frame from the lines of a multi-DoF joint.
pub(super) fn place_joint_lines(
    state: &mut ChainState,
    k0: usize,
    u: usize,
    lines: &[(Vector3<f64>, Vector3<f64>)],
) {
    let frame = |(n, o): &(Vector3<f64>, Vector3<f64>)| {
        Isometry3::from_parts(Translation3::from(*o), onto_z(n).inverse())
    };
    let f: Vec<Isometry3<f64>> = lines.iter().map(frame).collect();
    for i in 1..f.len() {
        state.joints[k0 + i] = f[i - 1].inverse() * f[i];
    }
    state.sus[u] = f[f.len() - 1].inverse();
}

/// SU `u`'s frame relative to the segment after DoF `k0` in every pose: `J_{k0+1}·Rz(q)⋯S_u`.
pub(super) fn tails(
    state: &ChainState,
    data: &Readings,
    k0: usize,
    k1: usize,
    u: usize,
) -> Vec<Isometry3<f64>> {
    data.turns
        .iter()
        .map(|turns| {
            ((k0 + 1)..=k1).fold(Isometry3::identity(), |t, k| t * state.joints[k] * turns[k])
                * state.sus[u]
        })
        .collect()
}

/// Solves `min_R Σ |a_i − R b_i|²` (Wahba) and reports how well the `b_i` span 3-D.
fn wahba(a: &[Vector3<f64>], b: &[Vector3<f64>]) -> (Rotation3<f64>, f64) {
    let mut h = Matrix3::zeros();
    for (x, y) in a.iter().zip(b) {
        h += x * y.transpose();
    }
    let svd = h.svd(true, true);
    let (u, vt) = (svd.u.expect("requested"), svd.v_t.expect("requested"));
    let mut d = Matrix3::identity();
    if (u * vt).determinant() < 0.0 {
        d[(2, 2)] = -1.0;
    }
    let mut s: Vec<f64> = svd.singular_values.iter().copied().collect();
    s.sort_by(f64::total_cmp);
    let spread = if s[2] > 0.0 { s[1] / s[2] } else { 0.0 };
    (Rotation3::from_matrix_unchecked(u * d * vt), spread)
}

/// Rotations that map the vectors `b` onto `a` (Wahba); when the `b` hardly span a plane, every
/// turn about their mean direction fits, and `angles` of them are returned.
fn rotation_starts(
    a: &[Vector3<f64>],
    b: &[Vector3<f64>],
    angles: usize,
) -> Vec<UnitQuaternion<f64>> {
    let (rotation, spread) = wahba(a, b);
    let base = UnitQuaternion::from_rotation_matrix(&rotation);
    if spread >= 0.2 {
        return vec![base];
    }
    let direction = Unit::new_normalize(b.iter().sum::<Vector3<f64>>());
    let n = angles.max(1);
    (0..n)
        .map(|i| {
            base * UnitQuaternion::from_axis_angle(
                &direction,
                2.0 * std::f64::consts::PI * i as f64 / n as f64,
            )
        })
        .collect()
}

/// Accumulates the 3×3 linear least-squares problem `M·t ≈ b`.
#[derive(Default)]
struct Lsq3 {
    ata: Matrix3<f64>,
    atb: Vector3<f64>,
}

impl Lsq3 {
    fn add(&mut self, m: &Matrix3<f64>, b: &Vector3<f64>) {
        self.ata += m.transpose() * m;
        self.atb += m.transpose() * b;
    }

    /// The least-norm solution: directions the rows do not determine (a shift along axes that are
    /// all parallel to it) stay at zero instead of growing without bound.
    fn solve(&self) -> Vector3<f64> {
        let svd = self.ata.svd(true, true);
        let largest = svd.singular_values.max();
        svd.solve(&self.atb, largest * 1e-8)
            .ok()
            .filter(|t| t.iter().all(|x| x.is_finite()))
            .unwrap_or_else(Vector3::zeros)
    }
}

/// Adds the upstream accelerations of an SU whose position is `c + R_seg·t` (world) with unknown `t`:
/// `a_w/α = z × (c + R_seg t − o)`, i.e. `[z]×·R_seg·t = a_w/α − z × (c − o)`, for every revolute
/// DoF `d` of the `upstream` ones (a prismatic DoF accelerates every point it carries alike: its
/// readings tell no position).
fn add_lever_rows(
    lsq: &mut Lsq3,
    f: &super::problem::Frames,
    upstream: &[DofKind],
    rseg: &Matrix3<f64>,
    c: &Vector3<f64>,
    accelerations_world: impl Fn(usize) -> Option<Vector3<f64>>,
) {
    for (d, kind) in upstream.iter().enumerate() {
        if *kind == DofKind::Prismatic {
            continue;
        }
        let Some(a) = accelerations_world(d) else {
            continue;
        };
        let z = f.joints[d].rotation * Vector3::z();
        let o = f.joints[d].translation.vector;
        let m = z.cross_matrix() * rseg;
        lsq.add(&m, &(a - z.cross(&(c - o))));
    }
}

/// Candidate frames of joint `k` on segment `k`, given the frames `tail[p]` of SU `u` relative to the
/// segment after DoF `k` (`J_{k+1}·Rz(q)⋯S_u`): the rotation from how gravity turns between the
/// segments (searched about the gravity direction when it hardly turns), the position by linear
/// least squares on the accelerations that upstream DoFs cause at the SU.
pub(super) fn joint_starts(
    state: &ChainState,
    layout: &Layout,
    data: &Readings,
    k: usize,
    u: usize,
    tail: &[Isometry3<f64>],
    angles: usize,
) -> Vec<Isometry3<f64>> {
    let poses = data.q.len();
    let minus_g = -state.gravity;
    let all: Vec<_> = (0..poses)
        .map(|p| frames(state, layout, &data.turns[p], None, k))
        .collect();
    let before: Vec<Vector3<f64>> = all
        .iter()
        .map(|f| f.segments[k].rotation.inverse() * minus_g)
        .collect();
    let after: Vec<Vector3<f64>> = (0..poses)
        .map(|p| data.turns[p][k] * (tail[p].rotation * data.statics[p][u]))
        .collect();
    rotation_starts(&before, &after, angles)
        .into_iter()
        .map(|r| {
            let mut lsq = Lsq3::default();
            for (p, f) in all.iter().enumerate() {
                let seg = f.segments[k];
                let turn = data.turns[p][k];
                let r_world = seg.rotation * r * turn * tail[p].rotation;
                let c =
                    (seg * nalgebra::Point3::from(r * (turn * tail[p]).translation.vector)).coords;
                let rseg = seg.rotation.to_rotation_matrix().into_inner();
                add_lever_rows(&mut lsq, f, &layout.kinds[..k], &rseg, &c, |d| {
                    (!data.is_rejected(p, u, 1 + d))
                        .then(|| r_world * data.dynamics[p][u][d] / data.alpha)
                });
            }
            Isometry3::from_parts(Translation3::from(lsq.solve()), r)
        })
        .collect()
}

/// Candidate frames of SU `u` on segment `s` with every joint known: its rotation from gravity
/// (searched about the gravity direction when gravity hardly turns in the segment), its position
/// from the accelerations of the DoFs before it.
pub(super) fn su_starts(
    state: &ChainState,
    layout: &Layout,
    data: &Readings,
    u: usize,
    s: usize,
    angles: usize,
) -> Vec<Isometry3<f64>> {
    let poses = data.q.len();
    let all: Vec<_> = (0..poses)
        .map(|p| frames(state, layout, &data.turns[p], None, s))
        .collect();
    let gravity_in_segment: Vec<Vector3<f64>> = all
        .iter()
        .map(|f| f.segments[s].rotation.inverse() * (-state.gravity))
        .collect();
    let statics: Vec<Vector3<f64>> = (0..poses).map(|p| data.statics[p][u]).collect();
    rotation_starts(&gravity_in_segment, &statics, angles)
        .into_iter()
        .map(|r| {
            let mut lsq = Lsq3::default();
            for (p, f) in all.iter().enumerate() {
                let seg = f.segments[s];
                let rseg = seg.rotation.to_rotation_matrix().into_inner();
                let r_world = seg.rotation * r;
                let kinds = &layout.kinds[..s];
                add_lever_rows(&mut lsq, f, kinds, &rseg, &seg.translation.vector, |d| {
                    (!data.is_rejected(p, u, 1 + d))
                        .then(|| r_world * data.dynamics[p][u][d] / data.alpha)
                });
            }
            Isometry3::from_parts(Translation3::from(lsq.solve()), r)
        })
        .collect()
}
