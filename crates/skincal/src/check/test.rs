//! The statistics of one SU's check: the change a log's blocks estimate, tested against what the
//! noise and the model's own uncertainty allow.

use nalgebra::{SMatrix, SVector};
use statrs::distribution::{ChiSquared, ContinuousCDF};

use super::kin::{Jacobian, CHANGE};

/// A [`CHANGE`]-vector.
pub type Change = SVector<f64, CHANGE>;
/// A [`CHANGE`] × [`CHANGE`] matrix.
pub type ChangeMatrix = SMatrix<f64, CHANGE, CHANGE>;

/// One SU's sums over the blocks of a log: the normal equations of its change (whitened, Huber
/// weighted), the weighted χ² at the model, how many blocks and how many were down-weighted.
#[derive(Debug, Clone, Default)]
pub struct Tally {
    /// `Σ Jᵀ W J`.
    pub information: ChangeMatrix,
    /// `Σ Jᵀ W r`.
    pub gradient: Change,
    /// `Σ rᵀ W r`.
    pub chi2: f64,
    /// Blocks counted.
    pub blocks: usize,
    /// Blocks whose whitened residual exceeded the Huber threshold.
    pub down_weighted: usize,
    /// `Σ |y|` of the readings, m/s².
    pub norm_sum: f64,
}

impl Tally {
    /// Adds one block: residual `r` (measured − predicted), Jacobian `jac`, variance of one
    /// component `var`, Huber threshold `huber` on the whitened residual's norm; returns the
    /// block's weight.
    pub fn add(&mut self, r: &nalgebra::Vector3<f64>, jac: &Jacobian, var: f64, huber: f64) -> f64 {
        let whitened = r.norm() / var.sqrt();
        let w = if whitened > huber {
            self.down_weighted += 1;
            huber / whitened
        } else {
            1.0
        } / var;
        self.information.gemm_tr(w, jac, jac, 1.0);
        self.gradient.gemv_tr(w, jac, r, 1.0);
        self.chi2 += r.norm_squared() * w;
        self.blocks += 1;
        w
    }

    /// Another tally's sums added to these.
    pub fn merge(&mut self, other: &Tally) {
        self.information += other.information;
        self.gradient += other.gradient;
        self.chi2 += other.chi2;
        self.blocks += other.blocks;
        self.down_weighted += other.down_weighted;
        self.norm_sum += other.norm_sum;
    }

    /// The change that fits the sums best by least squares (none in directions they do not tell).
    pub fn best_change(&self) -> Change {
        self.information
            .pseudo_inverse(1e-12)
            .map_or(Change::zeros(), |inv| inv * self.gradient)
    }

    /// The RMS whitened residual per component after the best change is taken out (≈ 1 when a
    /// small change of pose, bias and sensitivity explains the readings).
    pub fn residual_ratio(&self, change: &Change) -> f64 {
        let dof = (3 * self.blocks).saturating_sub(CHANGE).max(1) as f64;
        ((self.chi2 - change.dot(&self.gradient)).max(0.0) / dof).sqrt()
    }
}

/// The test of one SU's change in scaled units (each component over the change the check must
/// see: [`super::CheckConfig::detect`]).
#[derive(Debug, Clone)]
pub struct ChangeTest {
    /// The estimated change, physical units (m, rad, m/s²).
    pub change: Change,
    /// Its covariance under "unchanged" (noise and the model's own uncertainty), physical units.
    pub covariance: ChangeMatrix,
    /// The Wald statistic over the directions this log tells.
    pub statistic: f64,
    /// Its degrees of freedom (the directions told).
    pub dof: usize,
    /// `P(χ²_dof ≥ statistic)`.
    pub p_value: f64,
    /// What is left of the change when a move alone (shift and turn), a bias change alone or a
    /// change of bias and sensitivity explains as much of it as it can: the statistic of the rest
    /// and its degrees of freedom.
    pub left_by: [(f64, usize); 3],
    /// Per block (position, orientation, bias, sensitivity): whether some direction of it that
    /// motion can tell is not told by this log (a change of the size to see would be missed
    /// there).
    pub untold: [bool; 4],
    /// Those directions, scaled units.
    pub untold_directions: Vec<Change>,
}

/// The test of a tally: `scale` the change each component must see, `prior` the variance of the
/// model's own error of each component (physical units), `lambda` the non-centrality that the test
/// needs to see a change with the power asked, `tellable` the projector onto the directions
/// (scaled units) some motion tells.
pub fn change_test(
    tally: &Tally,
    scale: &Change,
    prior: &Change,
    lambda: f64,
    tellable: &ChangeMatrix,
) -> ChangeTest {
    let d = ChangeMatrix::from_diagonal(scale);
    let scaled = d * tally.information * d;
    let eigen = nalgebra::SymmetricEigen::new(scaled);
    // A direction is told when a change of the size to see along it stands `lambda` above the
    // noise alone.
    let told: Vec<usize> = (0..CHANGE)
        .filter(|&i| eigen.eigenvalues[i] >= lambda)
        .collect();
    let mut noise = ChangeMatrix::zeros();
    let mut projector = ChangeMatrix::zeros();
    for &i in &told {
        let e = eigen.eigenvectors.column(i);
        noise += e * e.transpose() / eigen.eigenvalues[i];
        projector += e * e.transpose();
    }
    let change_scaled = noise * d * tally.gradient;
    let prior_scaled =
        ChangeMatrix::from_diagonal(&prior.component_div(&scale.component_mul(scale)));
    let covariance_scaled = noise + projector * prior_scaled * projector;
    let (statistic, dof) = wald(&change_scaled, &covariance_scaled, 0..CHANGE);
    let left_by =
        [0..6, 6..9, 6..CHANGE].map(|keep| left(&change_scaled, &covariance_scaled, keep));
    let untold_directions: Vec<Change> = (0..CHANGE)
        .filter(|i| !told.contains(i))
        .map(|i| eigen.eigenvectors.column(i).into_owned())
        .filter(|e| (tellable * e).norm_squared() > 0.5)
        .collect();
    let untold = [0, 3, 6, 9].map(|k| {
        untold_directions
            .iter()
            .any(|e| (k..k + 3).any(|c| e[c].abs() > 0.3))
    });
    ChangeTest {
        change: d * change_scaled,
        covariance: d * covariance_scaled * d,
        statistic,
        dof,
        p_value: survival(statistic, dof),
        left_by,
        untold,
        untold_directions,
    }
}

/// `xᵀ C⁺ x` over the components `range`, with the rank of that block of `C`.
fn wald(x: &Change, c: &ChangeMatrix, range: std::ops::Range<usize>) -> (f64, usize) {
    let n = range.len();
    let start = range.start;
    let block = c.view((start, start), (n, n)).clone_owned();
    let sub = x.rows(start, n).clone_owned();
    let eigen = nalgebra::SymmetricEigen::new(block);
    let top = eigen.eigenvalues.iter().copied().fold(0.0, f64::max);
    let mut t = 0.0;
    let mut rank = 0;
    for i in 0..n {
        let l = eigen.eigenvalues[i];
        if l > top * 1e-9 && l > 0.0 {
            let e = eigen.eigenvectors.column(i);
            t += e.dot(&sub).powi(2) / l;
            rank += 1;
        }
    }
    (t, rank)
}

/// The Wald statistic of `x` (covariance `c`) after the components `keep` take up as much of it
/// as they can: `min_y (x − S y)ᵀ C⁺ (x − S y)`, with `S` those components' columns, and its
/// degrees of freedom (the rank of `C` less what `S` spans of it).
fn left(x: &Change, c: &ChangeMatrix, keep: std::ops::Range<usize>) -> (f64, usize) {
    let eigen = nalgebra::SymmetricEigen::new(*c);
    let top = eigen.eigenvalues.iter().copied().fold(0.0, f64::max);
    let mut w = ChangeMatrix::zeros();
    let mut rank: usize = 0;
    for i in 0..CHANGE {
        let l = eigen.eigenvalues[i];
        if l > top * 1e-9 && l > 0.0 {
            let e = eigen.eigenvectors.column(i);
            w += e * e.transpose() / l;
            rank += 1;
        }
    }
    let n = keep.len();
    let s = ChangeMatrix::identity()
        .columns(keep.start, n)
        .clone_owned();
    let sws = s.transpose() * w * &s;
    let sw_eigen = nalgebra::SymmetricEigen::new(sws.clone());
    let sw_top = sw_eigen.eigenvalues.iter().copied().fold(0.0, f64::max);
    let spanned = sw_eigen
        .eigenvalues
        .iter()
        .filter(|&&l| l > sw_top * 1e-9 && l > 0.0)
        .count();
    let y = sws
        .pseudo_inverse(sw_top * 1e-9)
        .map(|inv| inv * s.transpose() * w * x)
        .unwrap_or_else(|_| nalgebra::DVector::zeros(n));
    let rest = x - &s * y;
    (rest.dot(&(w * rest)), rank.saturating_sub(spanned))
}

/// `P(χ²_dof ≥ t)` (1 for no degree of freedom).
pub fn survival(t: f64, dof: usize) -> f64 {
    if dof == 0 {
        return 1.0;
    }
    ChiSquared::new(dof as f64).map_or(1.0, |c| c.sf(t))
}

/// The value a χ² of `dof` degrees of freedom exceeds with probability `alpha`.
pub fn critical(alpha: f64, dof: usize) -> f64 {
    ChiSquared::new(dof.max(1) as f64).map_or(f64::INFINITY, |c| c.inverse_cdf(1.0 - alpha))
}

/// The non-centrality at which a χ² test of `dof` degrees of freedom at level `alpha` rejects
/// with probability `power`: the non-central χ² as the Poisson mixture of central ones,
/// `P(X > x) = Σⱼ e^{−λ/2} (λ/2)ʲ / j! · P(χ²_{k+2j} > x)`, solved for `λ` by bisection.
pub fn non_centrality(alpha: f64, power: f64, dof: usize) -> f64 {
    let k = dof.max(1) as f64;
    let limit = critical(alpha, dof);
    let power_at = |lambda: f64| {
        let half = lambda / 2.0;
        let terms = (half + 12.0 * half.sqrt() + 20.0).ceil() as usize;
        (0..terms)
            .map(|j| {
                let j = j as f64;
                let weight = if half > 0.0 {
                    (j * half.ln() - half - statrs::function::gamma::ln_gamma(j + 1.0)).exp()
                } else if j == 0.0 {
                    1.0
                } else {
                    0.0
                };
                weight * ChiSquared::new(k + 2.0 * j).map_or(0.0, |c| c.sf(limit))
            })
            .sum::<f64>()
    };
    let (mut lo, mut hi) = (0.0, 1.0);
    while power_at(hi) < power && hi < 1e6 {
        hi *= 2.0;
    }
    for _ in 0..60 {
        let mid = 0.5 * (lo + hi);
        if power_at(mid) < power {
            lo = mid;
        } else {
            hi = mid;
        }
    }
    hi
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_critical_values_are_the_tables() {
        // χ²₃ at 0.999: 16.266; χ²₉: 27.877 (any table of the χ² distribution).
        assert!((critical(1e-3, 3) - 16.266).abs() < 1e-3);
        assert!((critical(1e-3, 9) - 27.877).abs() < 1e-3);
    }

    #[test]
    fn the_non_centrality_gives_the_power_asked() {
        // One degree of freedom: the test rejects |z| > 3.29 and a shift μ is seen with power
        // Φ(μ − 3.29) (+ the negligible other tail): 0.99 needs μ = 3.29 + 2.326 = 5.617.
        let lambda = non_centrality(1e-3, 0.99, 1);
        assert!((lambda.sqrt() - 5.617).abs() < 0.01, "{}", lambda.sqrt());
    }
}
