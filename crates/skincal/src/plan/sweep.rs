//! The continuous program's motion: every DoF at once along its own smooth random path.
//!
//! DoF `d` follows a finite Fourier series about its pose `q₀` — the excitation trajectories of
//! robot dynamics identification — inside a window:
//!
//! ```text
//! q_d(τ) = q₀_d + w(τ) · Σₖ (a_dk sin 2πkfτ + b_dk cos 2πkfτ),   k = 1 … K
//! ```
//!
//! `w` rises from 0 to 1 over the first `ramp` seconds with the quintic smoothstep and falls back
//! over the last, so the sweep leaves its pose and comes back to it at rest. The coefficients are
//! drawn uniform in `±k^−1.25` (the low harmonics carry the range, in which gravity turns; the high
//! ones the accelerations, which tell the positions) and then scaled per DoF so
//! that the path stays within the DoF's range about `q₀` and its speed and acceleration within
//! the plan's share of the limits — checked on the windowed path itself, not on a bound.
//!
//! Unlike the training poses, nothing is ever still: gravity turns through every orientation the
//! ranges allow while every DoF accelerates, and the time-domain estimator takes every sample.

use std::f64::consts::PI;

use rand::Rng;
use serde::{Deserialize, Serialize};

use super::{plateau, PlanDof};

/// How a harmonic's amplitude falls with its order `k`: `k^−FALL`. On the paper's arm, 20 s of
/// harmonics up to 1.6 Hz predicted held-out poses at 0.0027/0.0036 m/s² (static/dynamic) with
/// 1.25, 0.0028/0.0074 with 1.75 (too little acceleration) and 0.0052/0.0050 up to 1.2 Hz.
const FALL: f64 = 1.25;
/// Grid points per period of the highest harmonic on which a drawn path's peaks are found.
const PEAK_GRID: f64 = 64.0;
/// The share of a limit a drawn path's sampled peak may reach (the true peak lies between grid
/// points, at most `1 − cos(π/64) ≈ 0.1 %` above the sampled one for the highest harmonic).
const PEAK_MARGIN: f64 = 0.99;

/// A sweep: the harmonics of every DoF's path.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Sweep {
    /// The fundamental frequency `f`, Hz.
    pub frequency: f64,
    /// Rise and fall of the window, s.
    pub ramp: f64,
    /// Per DoF (the plan's order), the sine and cosine amplitudes `[a_k, b_k]` of harmonics
    /// `k = 1 … K`, rad.
    pub harmonics: Vec<Vec<[f64; 2]>>,
}

impl Sweep {
    /// DoF `dof`'s displacement from the pose, velocity and acceleration at `tau` (s from the
    /// start of a sweep lasting `duration` s).
    pub fn at(&self, dof: usize, duration: f64, tau: f64) -> [f64; 3] {
        let Some(series) = self.harmonics.get(dof) else {
            return [0.0; 3];
        };
        let [w, dw, ddw] = plateau(self.ramp, duration, tau);
        if w == 0.0 && dw == 0.0 && ddw == 0.0 {
            return [0.0; 3];
        }
        // The harmonics' phases by turning the fundamental's: sin and cos of `kθ` from those of
        // `(k−1)θ` by the angle-sum identities, one `sin_cos` per call instead of one per
        // harmonic (the error grows by an ulp or so per step: 1e-13 at a thousand harmonics).
        let fundamental = 2.0 * PI * self.frequency;
        let (sin1, cos1) = (fundamental * tau).sin_cos();
        let (mut sin, mut cos) = (sin1, cos1);
        let (mut s, mut ds, mut dds) = (0.0, 0.0, 0.0);
        for (k, [a, b]) in series.iter().enumerate() {
            let omega = fundamental * (k + 1) as f64;
            s += a * sin + b * cos;
            ds += omega * (a * cos - b * sin);
            dds -= omega * omega * (a * sin + b * cos);
            (sin, cos) = (sin * cos1 + cos * sin1, cos * cos1 - sin * sin1);
        }
        [w * s, dw * s + w * ds, ddw * s + 2.0 * dw * ds + w * dds]
    }

    /// DoF `dof`'s path `factor` times as wide (and as fast): below 1 it keeps every limit the
    /// drawn path kept.
    pub fn scale(&mut self, dof: usize, factor: f64) {
        for h in self.harmonics.get_mut(dof).into_iter().flatten() {
            h[0] *= factor;
            h[1] *= factor;
        }
    }

    /// Draws a sweep of `duration` s about `centre` for `dofs`: the harmonics of one period over
    /// the sweep up to `highest` Hz, each DoF scaled to its range about the centre (within
    /// `±pose_range` of 0) and to `fraction` of its speed and acceleration limits. The
    /// fundamental falls as the sweep grows, so that a longer sweep also reaches further on a
    /// DoF whose speed limit is what bounds it.
    pub(super) fn draw(
        dofs: &[PlanDof],
        centre: &[f64],
        duration: f64,
        highest: f64,
        pose_range: f64,
        fraction: f64,
        rng: &mut impl Rng,
    ) -> Sweep {
        let frequency = 1.0 / duration;
        let harmonics = ((highest * duration).round() as usize).max(1);
        let ramp = ramp(duration, frequency);
        let mut sweep = Sweep {
            frequency,
            ramp,
            harmonics: Vec::with_capacity(dofs.len()),
        };
        for (d, dof) in dofs.iter().enumerate() {
            let series: Vec<[f64; 2]> = (1..=harmonics)
                .map(|k| {
                    let scale = (k as f64).powf(-FALL);
                    [
                        rng.random_range(-scale..=scale),
                        rng.random_range(-scale..=scale),
                    ]
                })
                .collect();
            sweep.harmonics.push(series);
            let (lo, hi) = usable_range(dof, pose_range);
            let room = (centre[d] - lo).min(hi - centre[d]).max(0.0);
            let peaks = sweep.peaks(d, duration);
            let limit = |allowed: f64, peak: f64| {
                if peak > 0.0 {
                    allowed / peak
                } else {
                    0.0
                }
            };
            let scale = PEAK_MARGIN
                * limit(room, peaks[0])
                    .min(limit(fraction * dof.velocity, peaks[1]))
                    .min(limit(fraction * dof.acceleration, peaks[2]));
            for c in &mut sweep.harmonics[d] {
                c[0] *= scale;
                c[1] *= scale;
            }
        }
        sweep
    }

    /// The largest `|displacement|`, `|velocity|` and `|acceleration|` of DoF `dof`'s path over a
    /// sweep of `duration` s, on a grid of `PEAK_GRID` points per period of the highest harmonic.
    pub fn peaks(&self, dof: usize, duration: f64) -> [f64; 3] {
        let highest = self.frequency * self.harmonics.get(dof).map_or(1, Vec::len).max(1) as f64;
        let n = (duration * highest * PEAK_GRID).ceil().max(2.0) as usize;
        let mut peaks = [0.0f64; 3];
        for i in 0..=n {
            let v = self.at(dof, duration, duration * i as f64 / n as f64);
            for k in 0..3 {
                peaks[k] = peaks[k].max(v[k].abs());
            }
        }
        peaks
    }

    /// Checks a sweep read from a plan file for `dofs` DoFs and a phase of `duration` s.
    pub(super) fn check(&self, dofs: usize, duration: f64) -> Result<(), String> {
        if !(self.frequency.is_finite() && self.frequency > 0.0 && self.frequency <= 100.0) {
            return Err(format!(
                "sweep frequency {} must be in (0, 100] Hz",
                self.frequency
            ));
        }
        if !(self.ramp.is_finite() && self.ramp >= 0.0 && 2.0 * self.ramp <= duration + 1e-9) {
            return Err(format!(
                "sweep ramp {} s must be at least 0 and at most half the phase ({duration} s)",
                self.ramp
            ));
        }
        if self.harmonics.len() != dofs {
            return Err(format!(
                "sweep harmonics has {} rows, expected one per DoF ({dofs})",
                self.harmonics.len()
            ));
        }
        let limit = crate::model::sensor::MAX_ANGLE;
        if self
            .harmonics
            .iter()
            .flatten()
            .flatten()
            .any(|c| !(c.is_finite() && c.abs() <= limit))
        {
            return Err("sweep harmonics hold an amplitude that is not a finite angle".into());
        }
        if self.harmonics.iter().any(|h| h.len() > 1000) {
            return Err("sweep harmonics: more than 1000 harmonics per DoF".into());
        }
        Ok(())
    }
}

/// The window's rise of a sweep of `duration` s at `frequency` Hz: a fifth of the fundamental's
/// period, at most [`MAX_RAMP`] and a quarter of the sweep.
fn ramp(duration: f64, frequency: f64) -> f64 {
    (0.2 / frequency).min(MAX_RAMP).min(duration / 4.0)
}

/// The longest rise and fall of a sweep's window, s.
const MAX_RAMP: f64 = 2.0;

/// The range a DoF sweeps in: its limits within `±pose_range`.
fn usable_range(dof: &PlanDof, pose_range: f64) -> (f64, f64) {
    let (lo, hi) = (dof.lower.max(-pose_range), dof.upper.min(pose_range));
    if lo <= hi {
        (lo, hi)
    } else {
        (dof.lower, dof.upper)
    }
}

/// The pose a sweep runs about: the middle of every DoF's usable range.
pub(super) fn centre(dofs: &[PlanDof], pose_range: f64) -> Vec<f64> {
    dofs.iter()
        .map(|d| {
            let (lo, hi) = usable_range(d, pose_range);
            0.5 * (lo + hi)
        })
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;
    use rand::SeedableRng;

    fn dof(lower: f64, upper: f64) -> PlanDof {
        PlanDof {
            name: "j".into(),
            lower,
            upper,
            velocity: 1.0,
            acceleration: 5.0,
            velocity_assumed: false,
            acceleration_assumed: false,
            parent: None,
            kind: crate::model::DofKind::Revolute,
            mimic: None,
        }
    }

    /// The derivatives `at` gives are those of its displacement (central differences), and the
    /// path starts and ends at rest.
    #[test]
    fn derivatives_match_differences() {
        let dofs = [dof(-1.0, 2.0)];
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(3);
        let sweep = Sweep::draw(&dofs, &[0.5], 12.0, 0.5, 3.0, 0.9, &mut rng);
        let h = 1e-5;
        for i in 1..200 {
            let t = 12.0 * i as f64 / 200.0;
            let [q, v, a] = sweep.at(0, 12.0, t);
            let [qm, vm, _] = sweep.at(0, 12.0, t - h);
            let [qp, vp, _] = sweep.at(0, 12.0, t + h);
            assert!((v - (qp - qm) / (2.0 * h)).abs() < 1e-6, "velocity at {t}");
            assert!(
                (a - (vp - vm) / (2.0 * h)).abs() < 1e-5,
                "acceleration at {t}"
            );
            assert!(q.is_finite());
        }
        for t in [0.0, 12.0] {
            assert_eq!(sweep.at(0, 12.0, t), [0.0; 3]);
        }
    }

    /// The series summed by turning the fundamental's phase equals the formula in the module's
    /// doc evaluated term by term, at a thousand harmonics and late in a long sweep.
    #[test]
    fn turned_phases_equal_the_series_term_by_term() {
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(11);
        let series: Vec<[f64; 2]> = (0..1000)
            .map(|_| [rng.random_range(-1.0..1.0), rng.random_range(-1.0..1.0)])
            .collect();
        let sweep = Sweep {
            frequency: 1.0 / 600.0,
            ramp: 0.0,
            harmonics: vec![series.clone()],
        };
        for tau in [0.37, 123.4, 599.9] {
            let (mut s, mut ds, mut dds) = (0.0, 0.0, 0.0);
            for (k, [a, b]) in series.iter().enumerate() {
                let omega = 2.0 * PI * (k + 1) as f64 / 600.0;
                let (sin, cos) = (omega * tau).sin_cos();
                s += a * sin + b * cos;
                ds += omega * (a * cos - b * sin);
                dds -= omega * omega * (a * sin + b * cos);
            }
            let [q, v, a] = sweep.at(0, 600.0, tau);
            assert!(
                (q - s).abs() < 1e-10 * s.abs().max(1.0),
                "{tau}: {q} vs {s}"
            );
            assert!(
                (v - ds).abs() < 1e-10 * ds.abs().max(1.0),
                "{tau}: {v} vs {ds}"
            );
            assert!(
                (a - dds).abs() < 1e-10 * dds.abs().max(1.0),
                "{tau}: {a} vs {dds}"
            );
        }
    }

    /// A drawn path keeps within the range about its centre and within the share of the limits,
    /// checked on a grid ten times finer than the one it was scaled on; one limit is reached.
    #[test]
    fn drawn_paths_keep_their_limits() {
        let dofs = [dof(-0.3, 2.0), dof(-2.0, 2.0), dof(0.0, 0.2)];
        let centre = centre(&dofs, 1.5);
        assert_eq!(centre, vec![0.6, 0.0, 0.1]);
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(7);
        let sweep = Sweep::draw(&dofs, &centre, 20.0, 0.8, 1.5, 0.95, &mut rng);
        assert_eq!(sweep.harmonics[0].len(), 16);
        for (d, dof) in dofs.iter().enumerate() {
            let n = 20.0 * 0.8 * PEAK_GRID * 10.0;
            let mut peaks = [0.0f64; 3];
            for i in 0..=n as usize {
                let v = sweep.at(d, 20.0, 20.0 * i as f64 / n);
                for k in 0..3 {
                    peaks[k] = peaks[k].max(v[k].abs());
                }
            }
            let room = (centre[d] - dof.lower.max(-1.5)).min(dof.upper.min(1.5) - centre[d]);
            let shares = [
                peaks[0] / room,
                peaks[1] / (0.95 * dof.velocity),
                peaks[2] / (0.95 * dof.acceleration),
            ];
            assert!(shares.iter().all(|s| *s <= 1.0), "DoF {d}: {shares:?}");
            let most = shares.iter().copied().fold(0.0, f64::max);
            assert!(
                most > 0.97,
                "DoF {d} uses only {most} of its tightest limit"
            );
        }
    }
}
