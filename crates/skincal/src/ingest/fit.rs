//! The least-squares fit of the excitation windows, against every DoF's measured motion.
//!
//! A real servo is compliant: exciting DoF `d` deflects the others by a few mrad (reaction
//! torques), and every stop rings. Each SU's reading in the window of DoF `d` is therefore modelled
//! with the motion of *every* DoF `e` that moved in it, measured by the encoders:
//!
//! ```text
//! s(t) = c_w + Σ_e [ h_e (cos Δθ_e − 1) + g_e sin Δθ_e + k_e α_e(t) + m_e ω_e(t)² ]
//! ```
//!
//! (gravity turned by each DoF, tangential and centripetal accelerations). With DoF `d` alone this
//! is the exact single-DoF model. Left out are the terms of second order in the motion that mix
//! two DoFs: the Coriolis products `ω_d ω_e`, and the turning of one DoF's coefficients by the
//! other's angle. On the physics test's arm (deflections of 13 mrad, 30 % of the signal) they
//! cost 0.04 m/s², while a product's coefficient, known only from the two windows in which it is
//! nearly collinear with the excitation, would let the encoders' quantisation through tenfold. The coefficients are 3-vectors in the SU
//! frame that depend on the pose only, so the windows of one station share them: `k_e` of the
//! window where `e` is excited is also the coefficient of `e`'s coupled motion in every other
//! window. One joint fit per station ([`PooledFit`]) therefore separates the response to the
//! excited DoF from the coupled motion, which in one window alone it could not (a deflection
//! that follows the excitation's acceleration is nearly collinear with it).
//!
//! The measured α is the long second difference over ±`l` grid points, which equals the discrete
//! acceleration filtered by a triangle; every other regressor and the SU signal go through the
//! same triangle, so the fit needs no smoothing model. The sample at grid point `m` enters the
//! normal equations with weight `W(m) = Σ_n X(n) w(n − m)`: the right-hand sides are streamed
//! sample by sample, and the variance they carry per unit sample variance is `Σ_m W(m) W(m)ᵀ`.

use std::collections::BTreeMap;

use nalgebra::{DMatrix, DVector};

use super::timeline::Timeline;

/// A term of the model of a reading in an excitation window.
#[derive(Debug, Clone, Copy, PartialEq, Eq, PartialOrd, Ord, Hash)]
pub(super) enum Term {
    /// The reading at the window's start pose (one per window).
    Offset,
    /// `cos Δθ_e − 1`: gravity turned by DoF `e`, second order.
    Cos(usize),
    /// `sin Δθ_e`: gravity turned by DoF `e`, first order.
    Sin(usize),
    /// `α_e`: the tangential acceleration of DoF `e`.
    Alpha(usize),
    /// `ω_e²`: the centripetal acceleration of DoF `e`.
    Omega2(usize),
}

impl Term {
    /// The DoF whose motion the term is, if any.
    fn dof(self) -> Option<usize> {
        match self {
            Term::Offset => None,
            Term::Cos(e) | Term::Sin(e) | Term::Alpha(e) | Term::Omega2(e) => Some(e),
        }
    }
}

/// A DoF whose position in a window spans less than this did not move in it, rad.
const STILL_SPAN: f64 = 1e-9;

/// An excitation window and its least-squares design.
#[derive(Debug, Clone)]
pub(super) struct Excitation {
    /// The excited DoFs (one, or several excited together), the one that moved most first.
    pub(super) dofs: Vec<usize>,
    /// Grid range `[start, end)`.
    pub(super) start: usize,
    pub(super) end: usize,
    /// The model's terms, in column order (`Offset` first, then four per DoF that moved, the
    /// excited DoFs' first).
    pub(super) terms: Vec<Term>,
    /// `W(m)` row by row: the weight of the sample at grid point `start + m` in each normal
    /// equation is `weights[m · terms.len() + c]` (empty in a [`Excitation::restricted`] design,
    /// which is only solved).
    pub(super) weights: Vec<f64>,
    /// `Σ_n X(n) X(n)ᵀ`, the normal matrix.
    pub(super) gram: DMatrix<f64>,
    /// `Σ_m W(m) W(m)ᵀ`: the covariance of the right-hand sides per unit sample variance.
    pub(super) spread: DMatrix<f64>,
    /// `Σ_m V(m) V(m)ᵀ` with `V(m) = (X(m − l) − 2X(m) + X(m + l))/(l·dt)²`: how a rounding error
    /// of one DoF's position at grid point `m`, through the measured accelerations, reaches the
    /// normal equations (per unit variance and unit coefficient of that DoF's acceleration).
    pub(super) rounding: DMatrix<f64>,
    /// Peak measured |ω| and |α| of the first excited DoF (for estimating the nominal pattern).
    pub(super) peak_velocity: f64,
    pub(super) peak_acceleration: f64,
}

impl Excitation {
    /// Number of grid points.
    pub(super) fn len(&self) -> usize {
        self.end - self.start
    }

    /// The columns of the terms that are not the motion of a DoF in `dropped`.
    pub(super) fn kept(&self, dropped: &[usize]) -> Vec<usize> {
        (0..self.terms.len())
            .filter(|&c| self.terms[c].dof().is_none_or(|e| !dropped.contains(&e)))
            .collect()
    }

    /// The design with only the columns `kept` (see [`Excitation::kept`]): the fit of an SU that
    /// the DoFs left out do not move. Its right-hand sides are the same columns of the full
    /// ones, since each column's is `Σ_m W_c(m) s(m)` alone; so it is only solved, never
    /// streamed, and carries no per-sample weights.
    pub(super) fn restricted(&self, kept: &[usize]) -> Excitation {
        let sub = |m: &DMatrix<f64>| {
            DMatrix::from_fn(kept.len(), kept.len(), |a, b| m[(kept[a], kept[b])])
        };
        Excitation {
            dofs: self.dofs.clone(),
            start: self.start,
            end: self.end,
            terms: kept.iter().map(|&c| self.terms[c]).collect(),
            weights: Vec::new(),
            gram: sub(&self.gram),
            spread: sub(&self.spread),
            rounding: sub(&self.rounding),
            peak_velocity: self.peak_velocity,
            peak_acceleration: self.peak_acceleration,
        }
    }
}

/// The weights of the triangle of half-width `l` samples: `(l − |k|)/l²`, `|k| < l`.
fn triangle(l: usize) -> Vec<f64> {
    let l2 = (l * l) as f64;
    (0..2 * l - 1)
        .map(|i| (l as f64 - (i as f64 - (l as f64 - 1.0)).abs()) / l2)
        .collect()
}

/// `x` filtered by `kernel` (odd length, centred) at `n`, with `x` taken as zero outside.
fn filtered(x: &[f64], kernel: &[f64], n: usize) -> f64 {
    let half = kernel.len() / 2;
    let mut s = 0.0;
    for (k, w) in kernel.iter().enumerate() {
        let i = n + k;
        if i >= half && i - half < x.len() {
            s += w * x[i - half];
        }
    }
    s
}

/// The measured motion of one DoF in a window, relative to the window's start pose.
struct Motion {
    cos: Vec<f64>,
    sin: Vec<f64>,
    /// One-step central difference, rad/s.
    omega: Vec<f64>,
}

impl Motion {
    fn of(th: &[f64], l: usize, dt: f64) -> Motion {
        let len = th.len();
        // The start pose: the mean over the still points before the motion.
        let base = th[..l].iter().sum::<f64>() / l as f64;
        let omega = (0..len)
            .map(|i| {
                let (a, b) = (i.saturating_sub(1), (i + 1).min(len - 1));
                (th[b] - th[a]) / ((b - a) as f64 * dt)
            })
            .collect();
        Motion {
            cos: th.iter().map(|q| (q - base).cos() - 1.0).collect(),
            sin: th.iter().map(|q| (q - base).sin()).collect(),
            omega,
        }
    }
}

/// The least-squares design of an excitation of the DoFs `excited` over grid `[start, end)`;
/// `None` when the window is too short or an excited DoF's acceleration cannot be told from its
/// other terms.
pub(super) fn design(
    timeline: &Timeline,
    excited: &[usize],
    start: usize,
    end: usize,
    l: usize,
) -> Option<Excitation> {
    let len = end - start;
    if len < 4 * l + 4 {
        return None;
    }
    let dofs = moving_dofs(timeline, excited, start, end);
    let mut terms = vec![Term::Offset];
    for &e in &dofs {
        terms.extend([Term::Cos(e), Term::Sin(e), Term::Alpha(e), Term::Omega2(e)]);
    }
    let nc = terms.len();
    let regressors = Regressors::of(timeline, &dofs, start, end, l);
    let x = &regressors.x;
    let rows = len - 2 * l;
    let gram = DMatrix::from_fn(nc, nc, |a, b| {
        (0..rows)
            .map(|r| x[r * nc + a] * x[r * nc + b])
            .sum::<f64>()
    });
    if !accelerations_told_apart(&gram, excited.len()) || regressors.peak_acceleration == 0.0 {
        return None;
    }
    let weights = adjoint_weights(x, &triangle(l), l, len, nc);
    let spread = DMatrix::from_fn(nc, nc, |a, b| {
        (0..len)
            .map(|m| weights[m * nc + a] * weights[m * nc + b])
            .sum()
    });
    let span = (l as f64 * timeline.grid.dt).powi(2);
    let rounding = rounding_spread(x, l, len, nc, span);
    Some(Excitation {
        dofs: excited.to_vec(),
        start,
        end,
        terms,
        weights,
        gram,
        spread,
        rounding,
        peak_velocity: regressors.peak_velocity,
        peak_acceleration: regressors.peak_acceleration,
    })
}

/// The excited DoFs first, then every other DoF that moved over `[start, end)` (but the mimic
/// ones: their motion is their leaders').
fn moving_dofs(timeline: &Timeline, excited: &[usize], start: usize, end: usize) -> Vec<usize> {
    let mut dofs = excited.to_vec();
    dofs.extend((0..timeline.theta.len()).filter(|&e| {
        if timeline.follows(e) {
            return false;
        }
        let th = &timeline.theta[e][start..end];
        let (lo, hi) = th
            .iter()
            .fold((f64::MAX, f64::MIN), |(a, b), &q| (a.min(q), b.max(q)));
        !excited.contains(&e) && hi - lo > STILL_SPAN
    }));
    dofs
}

/// The regressors of an excitation at the valid points `n ∈ [l, len − l)`, triangle-filtered,
/// row after row (an offset, then per DoF `cos`, `sin`, `α`, `ω²`); the measured acceleration is
/// the long second difference (= the triangle-filtered discrete acceleration). With the first
/// DoF's peak speed and acceleration.
struct Regressors {
    x: Vec<f64>,
    peak_velocity: f64,
    peak_acceleration: f64,
}

impl Regressors {
    fn of(timeline: &Timeline, dofs: &[usize], start: usize, end: usize, l: usize) -> Self {
        let (len, nc) = (end - start, 1 + 4 * dofs.len());
        let dt = timeline.grid.dt;
        let kernel = triangle(l);
        let span = (l as f64 * dt).powi(2);
        let motions: Vec<Motion> = dofs
            .iter()
            .map(|&e| Motion::of(&timeline.theta[e][start..end], l, dt))
            .collect();
        let squares: Vec<Vec<f64>> = motions
            .iter()
            .map(|m| m.omega.iter().map(|w| w * w).collect())
            .collect();
        let mut x = vec![0.0; (len - 2 * l) * nc];
        let (mut peak_velocity, mut peak_acceleration) = (0.0f64, 0.0f64);
        for (r, i) in (l..len - l).enumerate() {
            let row = &mut x[r * nc..(r + 1) * nc];
            row[0] = 1.0;
            for (k, (&e, m)) in dofs.iter().zip(&motions).enumerate() {
                let th = &timeline.theta[e][start..end];
                let alpha = (th[i + l] - 2.0 * th[i] + th[i - l]) / span;
                if k == 0 {
                    let omega = (th[i + l] - th[i - l]) / (2.0 * l as f64 * dt);
                    peak_velocity = peak_velocity.max(omega.abs());
                    peak_acceleration = peak_acceleration.max(alpha.abs());
                }
                let c = 1 + 4 * k;
                row[c] = filtered(&m.cos, &kernel, i);
                row[c + 1] = filtered(&m.sin, &kernel, i);
                row[c + 2] = alpha;
                row[c + 3] = filtered(&squares[k], &kernel, i);
            }
        }
        Self {
            x,
            peak_velocity,
            peak_acceleration,
        }
    }
}

/// Whether each of the first `excited` DoFs' acceleration can be told apart from its own other
/// terms (and the offset) in the window's Gram matrix.
fn accelerations_told_apart(gram: &DMatrix<f64>, excited: usize) -> bool {
    (0..excited).all(|k| {
        let own = [0, 1 + 4 * k, 2 + 4 * k, 3 + 4 * k, 4 + 4 * k];
        let scale: Vec<f64> = own
            .iter()
            .map(|&c| 1.0 / gram[(c, c)].max(1e-300).sqrt())
            .collect();
        let scaled = DMatrix::from_fn(5, 5, |i, j| gram[(own[i], own[j])] * scale[i] * scale[j]);
        scaled
            .cholesky()
            .is_some_and(|c| c.inverse()[(3, 3)] <= 1e4)
    })
}

/// `W(m) = Σ_n X(n) w(n − m)`: the adjoint of the triangle `kernel` applied to the regressors
/// `x`, for every grid point `m` of the window.
fn adjoint_weights(x: &[f64], kernel: &[f64], l: usize, len: usize, nc: usize) -> Vec<f64> {
    let half = kernel.len() / 2;
    let mut weights = vec![0.0; len * nc];
    for (r, i) in (l..len - l).enumerate() {
        let row = &x[r * nc..(r + 1) * nc];
        for (k, w) in kernel.iter().enumerate() {
            let m = i + k - half;
            for (target, v) in weights[m * nc..(m + 1) * nc].iter_mut().zip(row) {
                *target += w * v;
            }
        }
    }
    weights
}

/// How an independent error at every grid point (an encoder's rounding) spreads into the normal
/// equations: an error ε at point m enters α at rows m − l, m, m + l with weights 1, −2, 1 over
/// `span`.
fn rounding_spread(x: &[f64], l: usize, len: usize, nc: usize, span: f64) -> DMatrix<f64> {
    let row = |n: usize| (n >= l && n < len - l).then(|| &x[(n - l) * nc..(n - l + 1) * nc]);
    let mut rounding = DMatrix::<f64>::zeros(nc, nc);
    let mut v = vec![0.0; nc];
    for m in 0..len {
        v.fill(0.0);
        for (n, c) in [(m.checked_sub(l), 1.0), (Some(m), -2.0), (Some(m + l), 1.0)] {
            if let Some(r) = n.and_then(row) {
                for (vi, xi) in v.iter_mut().zip(r) {
                    *vi += c * xi / span;
                }
            }
        }
        for a in 0..nc {
            for b in 0..nc {
                rounding[(a, b)] += v[a] * v[b];
            }
        }
    }
    rounding
}

/// Directions of the scaled normal matrix (unit diagonal) with an eigenvalue below this are
/// unknown and held at zero (a DoF that moved only by coupling at a station where it was never
/// excited; two DoFs that moved alike wherever either moved, as two excited together with one
/// pattern and nowhere apart). They are left out of the inverse rather than damped: a damped
/// inverse is of the order of its damping's inverse along them, and its quadratic forms (the
/// readings' variances) then cancel to nothing.
const UNKNOWN: f64 = 1e-9;

/// The joint fit of the excitation windows of one station: the pose-dependent coefficients are
/// shared, the offsets are per window.
pub(super) struct PooledFit {
    /// Per window, the pooled column of each of its terms.
    columns: Vec<Vec<usize>>,
    /// The pooled column of each shared term.
    shared: BTreeMap<Term, usize>,
    /// The inverse of the regularised pooled normal matrix.
    inverse: DMatrix<f64>,
    /// `Σ_w P_wᵀ (Σ_m W W ᵀ) P_w`: the covariance of the pooled right-hand sides per unit variance.
    spread: DMatrix<f64>,
    /// The same for the encoders' rounding (see [`Excitation::rounding`]).
    rounding: DMatrix<f64>,
}

impl PooledFit {
    /// The fit of `windows` (at least one).
    pub(super) fn new(windows: &[&Excitation]) -> PooledFit {
        let mut shared = BTreeMap::new();
        let mut count = windows.len();
        for x in windows {
            for t in &x.terms[1..] {
                shared.entry(*t).or_insert_with(|| {
                    count += 1;
                    count - 1
                });
            }
        }
        let columns: Vec<Vec<usize>> = windows
            .iter()
            .enumerate()
            .map(|(w, x)| {
                x.terms
                    .iter()
                    .map(|t| if *t == Term::Offset { w } else { shared[t] })
                    .collect()
            })
            .collect();
        let mut gram = DMatrix::<f64>::zeros(count, count);
        let mut spread = DMatrix::<f64>::zeros(count, count);
        let mut rounding = DMatrix::<f64>::zeros(count, count);
        for (x, cols) in windows.iter().zip(&columns) {
            for (a, &ca) in cols.iter().enumerate() {
                for (b, &cb) in cols.iter().enumerate() {
                    gram[(ca, cb)] += x.gram[(a, b)];
                    spread[(ca, cb)] += x.spread[(a, b)];
                    rounding[(ca, cb)] += x.rounding[(a, b)];
                }
            }
        }
        let scale = DVector::from_fn(count, |i, _| {
            let g = gram[(i, i)];
            if g > 0.0 {
                1.0 / g.sqrt()
            } else {
                0.0
            }
        });
        let scaled = DMatrix::from_fn(count, count, |i, j| gram[(i, j)] * scale[i] * scale[j]);
        let inverse_scaled = scaled
            .try_symmetric_eigen(f64::EPSILON, 10_000)
            .map(|eigen| {
                let kept = eigen
                    .eigenvalues
                    .map(|l| if l > UNKNOWN { 1.0 / l } else { 0.0 });
                &eigen.eigenvectors * DMatrix::from_diagonal(&kept) * eigen.eigenvectors.transpose()
            })
            .unwrap_or_else(|| DMatrix::zeros(count, count));
        let inverse = DMatrix::from_fn(count, count, |i, j| {
            inverse_scaled[(i, j)] * scale[i] * scale[j]
        });
        PooledFit {
            columns,
            shared,
            inverse,
            spread,
            rounding,
        }
    }

    /// The pooled coefficients (one column per axis) from each window's right-hand sides.
    pub(super) fn solve(&self, rhs: &[&[[f64; 3]]]) -> DMatrix<f64> {
        let mut b = DMatrix::zeros(self.inverse.nrows(), 3);
        for (cols, r) in self.columns.iter().zip(rhs) {
            for (&c, v) in cols.iter().zip(r.iter()) {
                for axis in 0..3 {
                    b[(c, axis)] += v[axis];
                }
            }
        }
        &self.inverse * b
    }

    /// The pooled column of `Alpha(dof)`.
    pub(super) fn alpha(&self, dof: usize) -> Option<usize> {
        self.shared.get(&Term::Alpha(dof)).copied()
    }

    /// The standard deviation of the coefficient in `column` per unit sample standard deviation.
    pub(super) fn sd_factor(&self, column: usize) -> f64 {
        let u = self.inverse.row(column);
        (u * &self.spread * u.transpose())[(0, 0)].max(0.0).sqrt()
    }

    /// The standard deviation of the coefficient in `column` per unit rounding deviation of one
    /// DoF's encoder and unit coefficient of that DoF's acceleration.
    pub(super) fn rounding_factor(&self, column: usize) -> f64 {
        let u = self.inverse.row(column);
        (u * &self.rounding * u.transpose())[(0, 0)].max(0.0).sqrt()
    }

    /// The pooled columns of every DoF's acceleration.
    pub(super) fn accelerations(&self) -> impl Iterator<Item = (usize, usize)> + '_ {
        self.shared.iter().filter_map(|(t, &c)| match t {
            Term::Alpha(e) => Some((*e, c)),
            _ => None,
        })
    }

    /// In window `w` (`x`), the power of the coupled motion of the other DoFs and of the excited
    /// DoFs' own motion, summed over the axes of `coefficients`.
    pub(super) fn powers(
        &self,
        w: usize,
        x: &Excitation,
        coefficients: &DMatrix<f64>,
    ) -> (f64, f64) {
        let cols = &self.columns[w];
        let (mut other, mut own) = (0.0, 0.0);
        for axis in 0..3 {
            let part = |pick: &dyn Fn(Term) -> bool| {
                let beta = DVector::from_fn(cols.len(), |c, _| {
                    if pick(x.terms[c]) {
                        coefficients[(cols[c], axis)]
                    } else {
                        0.0
                    }
                });
                (beta.transpose() * &x.gram * &beta)[(0, 0)]
            };
            let excited = |t: Term| t.dof().is_some_and(|e| x.dofs.contains(&e));
            own += part(&excited);
            other += part(&|t| t != Term::Offset && !excited(t));
        }
        (other, own)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_long_second_difference_is_the_triangle_filtered_short_one() {
        // Any sequence: (q[i+l] − 2q[i] + q[i−l]) / l² = Σ_k w(k) (q[i+k+1] − 2q[i+k] + q[i+k−1]).
        let q: Vec<f64> = (0..200u32)
            .map(|i| (f64::from(i) * 0.37).sin() * 0.3 + f64::from(i * i % 17) * 1e-3)
            .collect();
        for l in [2, 5, 20] {
            let k = triangle(l);
            assert_eq!(k.len(), 2 * l - 1);
            assert!((k.iter().sum::<f64>() - 1.0).abs() < 1e-12);
            let short: Vec<f64> = (0..q.len())
                .map(|i| {
                    if i == 0 || i + 1 == q.len() {
                        0.0
                    } else {
                        q[i + 1] - 2.0 * q[i] + q[i - 1]
                    }
                })
                .collect();
            for i in [l + 1, 60, 150] {
                let long = (q[i + l] - 2.0 * q[i] + q[i - l]) / (l * l) as f64;
                assert!(
                    (long - filtered(&short, &k, i)).abs() < 1e-12,
                    "l {l}, i {i}"
                );
            }
        }
    }

    /// A window of `rows` samples whose columns are `x` (row-major, `terms.len()` per row),
    /// each sample weighted once: the right-hand sides carry `Σ X Xᵀ` per unit sample variance.
    fn plain_window(terms: Vec<Term>, x: &[f64], rows: usize) -> Excitation {
        let nc = terms.len();
        let gram = DMatrix::from_fn(nc, nc, |a, b| {
            (0..rows)
                .map(|r| x[r * nc + a] * x[r * nc + b])
                .sum::<f64>()
        });
        Excitation {
            dofs: vec![0],
            start: 0,
            end: rows,
            terms,
            weights: x.to_vec(),
            spread: gram.clone(),
            rounding: DMatrix::zeros(nc, nc),
            gram,
            peak_velocity: 1.0,
            peak_acceleration: 1.0,
        }
    }

    #[test]
    fn a_coefficients_deviation_is_that_of_its_estimates_when_two_dofs_moved_alike() {
        // DoF 1 moved as DoF 0 did, at 0.7 of its amplitude (two DoFs excited together with one
        // pattern): the direction of their difference is unknown (held at zero), and DoF 0's
        // acceleration coefficient is the estimate of their shared response. Its deviation from
        // the fit must be that of its estimates over independent noise draws (before, the damped
        // inverse's quadratic form cancelled to 0 here, and ingest wrote a deviation of 0 that
        // explore refused).
        use rand::SeedableRng;
        use rand_distr::{Distribution, Normal};
        let rows = 600;
        let terms = vec![
            Term::Offset,
            Term::Sin(0),
            Term::Alpha(0),
            Term::Sin(1),
            Term::Alpha(1),
        ];
        let nc = terms.len();
        let mut x = Vec::with_capacity(rows * nc);
        for r in 0..rows {
            let t = r as f64 * 1e-3;
            let (sin, alpha) = ((12.0 * t).sin() * 0.3, -(12.0 * t).sin() * 43.0 + 5.0 * t);
            x.extend([1.0, sin, alpha, 0.7 * sin, 0.7 * alpha]);
        }
        let window = plain_window(terms, &x, rows);
        let fit = PooledFit::new(&[&window]);
        let column = fit.alpha(0).unwrap();
        let predicted = fit.sd_factor(column);
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(3);
        let noise = Normal::new(0.0, 1.0).unwrap();
        let draws = 4000;
        let mut sum2 = 0.0;
        for _ in 0..draws {
            let mut rhs = vec![[0.0; 3]; nc];
            for r in 0..rows {
                let e = [0, 1, 2].map(|_| noise.sample(&mut rng));
                for (c, v) in rhs.iter_mut().enumerate() {
                    for axis in 0..3 {
                        v[axis] += x[r * nc + c] * e[axis];
                    }
                }
            }
            let k = fit.solve(&[&rhs]);
            sum2 += (0..3).map(|a| k[(column, a)].powi(2)).sum::<f64>() / 3.0;
        }
        let sampled = (sum2 / f64::from(draws)).sqrt();
        assert!(
            predicted > 0.0 && (predicted / sampled - 1.0).abs() < 0.05,
            "deviation per unit noise from the fit {predicted:e}, over {draws} draws {sampled:e}"
        );
    }
}
