//! Whether a fit's residual is at the noise level: the band within which the residual of a fit
//! with ν degrees of freedom stays when every reading's noise is what its weight says.
//!
//! The residual ratio `r = √(χ²/ν)` of a model that is right follows `χ²_ν / ν` for Gaussian
//! noise: about 1 ± √(2/ν). So a fit on 10 000 readings that ends at 1.05 σ is a misfit, however
//! small 0.05 looks, and a fixed bound such as 1.5 σ lets a wrong minimum through. Noise with
//! lighter tails (uniform, a difference of samples) spreads less, so the Gaussian band is the
//! wider one; wild readings (glitches) are left out or down-weighted before the residual is
//! judged, and a misfit must not widen its own band.

use serde::{Deserialize, Serialize};
use statrs::distribution::{ChiSquared, ContinuousCDF};

/// The probability that a fit at the noise level lies outside the band (is reported as not
/// converged).
pub const FALSE_ALARM: f64 = 1e-3;

/// The band of a fit's residual ratio at the noise level.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct ResidualBand {
    /// The largest residual ratio that a fit at the noise level exceeds only with probability
    /// [`FALSE_ALARM`]: `√(χ²_ν(1 − FALSE_ALARM) / ν)`.
    pub upper: f64,
    /// The residual's degrees of freedom ν: reading components less parameters.
    pub dof: usize,
}

impl ResidualBand {
    /// The band of a fit with `dof` degrees of freedom; `None` with none.
    pub fn at(dof: usize) -> Option<Self> {
        let nu = dof as f64;
        let upper = ChiSquared::new(nu)
            .ok()
            .map(|chi| (chi.inverse_cdf(1.0 - FALSE_ALARM) / nu).sqrt())
            .filter(|u| u.is_finite())?;
        Some(Self { upper, dof })
    }

    /// Whether a residual ratio lies within the band.
    pub fn holds(&self, ratio: f64) -> bool {
        ratio <= self.upper
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use rand::SeedableRng;
    use rand_chacha::ChaCha8Rng;
    use rand_distr::{Distribution, Normal};

    #[test]
    fn the_band_is_the_chi_square_quantile() {
        // χ²(0.999; 100) = 149.45 and χ²(0.999; 300) = 381.43 (tables): the ratio's bounds are
        // √(149.45 / 100) = 1.2225 and √(381.43 / 300) = 1.1276; for large ν, 1 + 3.09 / √(2ν).
        let upper = |dof| ResidualBand::at(dof).unwrap().upper;
        assert!((upper(100) - 1.2225).abs() < 1e-3);
        assert!((upper(300) - 1.1276).abs() < 1e-3);
        assert!((upper(1_000_000) - (1.0 + 3.0902 / 2e6f64.sqrt())).abs() < 1e-4);
    }

    #[test]
    fn residuals_at_the_noise_level_lie_within_and_a_five_percent_excess_does_not() {
        let mut rng = ChaCha8Rng::seed_from_u64(11);
        let normal = Normal::<f64>::new(0.0, 1.0).unwrap();
        let band = ResidualBand::at(9000).unwrap();
        let (mut inside, mut excess) = (0, 0);
        for _ in 0..200 {
            let sum: f64 = (0..9000).map(|_| normal.sample(&mut rng).powi(2)).sum();
            let ratio = (sum / 9000.0).sqrt();
            inside += usize::from(band.holds(ratio));
            excess += usize::from(band.holds(1.05 * ratio));
        }
        assert!(inside >= 199, "{inside} of 200 within");
        assert_eq!(excess, 0);
    }

    #[test]
    fn no_degrees_of_freedom_give_no_band() {
        assert_eq!(ResidualBand::at(0), None);
    }
}
