//! The least-squares design of an excitation window.

use nalgebra::{Matrix5, Vector5};

use super::segment::Excitation;
use super::timeline::Timeline;

/// The weights of the triangle of half-width `l` samples: `(l − |k|)/l²`, `|k| < l`.
pub(super) fn triangle(l: usize) -> Vec<f64> {
    let l2 = (l * l) as f64;
    (0..2 * l - 1)
        .map(|i| (l as f64 - (i as f64 - (l as f64 - 1.0)).abs()) / l2)
        .collect()
}

/// `x` filtered by `kernel` (odd length, centred) at `n`, with `x` taken as zero outside.
pub(super) fn filtered(x: &[f64], kernel: &[f64], n: usize) -> f64 {
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

/// The least-squares design of an excitation of DoF `d` over grid `[start, end)`.
pub(super) fn design(
    timeline: &Timeline,
    d: usize,
    start: usize,
    end: usize,
    l: usize,
) -> Option<Excitation> {
    let th = &timeline.theta[d][start..end];
    let len = th.len();
    if len < 4 * l + 4 {
        return None;
    }
    let dt = timeline.dt;
    let kernel = triangle(l);
    let base = th[0];
    let cos: Vec<f64> = th.iter().map(|q| (q - base).cos() - 1.0).collect();
    let sin: Vec<f64> = th.iter().map(|q| (q - base).sin()).collect();
    let omega2: Vec<f64> = (0..len)
        .map(|i| {
            let (a, b) = (th[i.saturating_sub(1)], th[(i + 1).min(len - 1)]);
            let w = (b - a) / (((i + 1).min(len - 1) - i.saturating_sub(1)) as f64 * dt);
            w * w
        })
        .collect();
    // Regressors at the valid points n ∈ [l, len − l): filtered by the triangle; the measured
    // acceleration is the long second difference (= triangle-filtered discrete acceleration).
    let span = (l as f64 * dt).powi(2);
    let mut rows: Vec<(usize, [f64; 5])> = Vec::with_capacity(len);
    let (mut peak_velocity, mut peak_acceleration) = (0.0f64, 0.0f64);
    for i in l..len - l {
        let alpha = (th[i + l] - 2.0 * th[i] + th[i - l]) / span;
        let omega = (th[i + l] - th[i - l]) / (2.0 * l as f64 * dt);
        peak_velocity = peak_velocity.max(omega.abs());
        peak_acceleration = peak_acceleration.max(alpha.abs());
        rows.push((
            i,
            [
                1.0,
                filtered(&cos, &kernel, i),
                filtered(&sin, &kernel, i),
                alpha,
                filtered(&omega2, &kernel, i),
            ],
        ));
    }
    let mut g = Matrix5::zeros();
    for (_, x) in &rows {
        let v = Vector5::from(*x);
        g += v * v.transpose();
    }
    // Scale the columns for a well-conditioned inverse.
    let scale = Vector5::from_fn(|i, _| 1.0 / g[(i, i)].max(1e-300).sqrt());
    let gs = Matrix5::from_fn(|i, j| g[(i, j)] * scale[i] * scale[j]);
    let inverse_scaled = gs.cholesky()?.inverse();
    let inverse = Matrix5::from_fn(|i, j| inverse_scaled[(i, j)] * scale[i] * scale[j]);
    if inverse[(3, 3)] * g[(3, 3)] > 1e4 || peak_acceleration == 0.0 {
        // α is (nearly) a combination of the other regressors: nothing to fit against.
        return None;
    }
    // W(m) = Σ_n X(n) w(n − m): the adjoint of the triangle applied to the regressors.
    let half = kernel.len() / 2;
    let mut weights = vec![[0.0; 5]; len];
    for (i, x) in &rows {
        for (k, w) in kernel.iter().enumerate() {
            let m = i + k - half;
            for (c, xc) in x.iter().enumerate() {
                weights[m][c] += w * xc;
            }
        }
    }
    Some(Excitation {
        dof: d,
        start,
        end,
        weights,
        inverse,
        peak_velocity,
        peak_acceleration,
    })
}
