//! What a real accelerometer adds to the specific force: a zero-g offset (bias), a sensitivity
//! (scale) error per axis and a misalignment of its axes (they are not quite orthogonal).
//!
//! An SU whose frame sees the specific force `f` (and, during an excitation, the extra
//! acceleration `a`) reads
//!
//! ```text
//! static  = K·f + b          dynamic = K·a          K = diag(1 + s) · (I + L(m))
//! ```
//!
//! with `b` the bias (m/s²), `s` the relative scale error per axis and `L(m)` strictly lower
//! triangular: `y` leans towards `x` by `m₀`, `z` towards `x` by `m₁` and towards `y` by `m₂`
//! (rad, small). A rotation of the sensor's axes is the SU frame's, so these 9 numbers are all that
//! a linear accelerometer model adds. The bias cancels in a dynamic acceleration (a difference of
//! two readings of the same SU).
//!
//! To turn a raw reading `r` into the specific force of an ideal accelerometer in the SU frame:
//! `f = K⁻¹·(r − b)` ([`Intrinsics::correct`]).

use nalgebra::{Matrix3, Vector3};
use serde::{Deserialize, Serialize};

/// Components of [`Intrinsics`] in the order of [`Intrinsics::to_array`].
pub const INTRINSIC_NAMES: [&str; 9] = [
    "bias_x",
    "bias_y",
    "bias_z",
    "scale_x",
    "scale_y",
    "scale_z",
    "misalignment_yx",
    "misalignment_zx",
    "misalignment_zy",
];

/// One accelerometer's intrinsics (all zero: an ideal sensor).
#[derive(Debug, Clone, Copy, PartialEq, Default, Serialize, Deserialize)]
pub struct Intrinsics {
    /// Zero-g offset per axis, m/s².
    pub bias: [f64; 3],
    /// Relative sensitivity error per axis (`0.02`: reads 2 % too much).
    pub scale: [f64; 3],
    /// Axis misalignments `[yx, zx, zy]`, rad.
    pub misalignment: [f64; 3],
}

impl Intrinsics {
    /// `K = diag(1 + s)·(I + L(m))`.
    pub fn matrix(&self) -> Matrix3<f64> {
        let [m0, m1, m2] = self.misalignment;
        let [s0, s1, s2] = self.scale.map(|s| 1.0 + s);
        // The rows of the lower-triangular `I + L` scaled.
        Matrix3::new(s0, 0.0, 0.0, s1 * m0, s1, 0.0, s2 * m1, s2 * m2, s2)
    }

    /// The static reading of specific force `f`: `K·f + b`.
    pub fn read(&self, f: &Vector3<f64>) -> Vector3<f64> {
        self.matrix() * f + Vector3::from(self.bias)
    }

    /// The dynamic acceleration read for an acceleration `a`: `K·a`.
    pub fn read_dynamic(&self, a: &Vector3<f64>) -> Vector3<f64> {
        self.matrix() * a
    }

    /// The specific force an ideal accelerometer would read, from a raw static reading:
    /// `K⁻¹·(r − b)`. `None` when `K` is singular (a scale error of −100 %).
    pub fn correct(&self, reading: &Vector3<f64>) -> Option<Vector3<f64>> {
        self.matrix()
            .try_inverse()
            .map(|k| k * (reading - Vector3::from(self.bias)))
    }

    /// The 9 numbers in [`INTRINSIC_NAMES`] order.
    pub fn to_array(&self) -> [f64; 9] {
        let mut out = [0.0; 9];
        out[..3].copy_from_slice(&self.bias);
        out[3..6].copy_from_slice(&self.scale);
        out[6..].copy_from_slice(&self.misalignment);
        out
    }

    /// From 9 numbers in [`INTRINSIC_NAMES`] order.
    pub fn from_array(x: &[f64; 9]) -> Self {
        Self {
            bias: [x[0], x[1], x[2]],
            scale: [x[3], x[4], x[5]],
            misalignment: [x[6], x[7], x[8]],
        }
    }

    /// These intrinsics with only their first `components` ([`INTRINSIC_NAMES`] order) kept, the
    /// rest ideal: what a fit of a smaller sensor model starts from.
    pub fn truncated(&self, components: usize) -> Self {
        let mut x = self.to_array();
        for v in x.iter_mut().skip(components) {
            *v = 0.0;
        }
        Self::from_array(&x)
    }

    /// These intrinsics changed by `delta` (9 numbers, [`INTRINSIC_NAMES`] order).
    pub fn moved(&self, delta: &[f64]) -> Self {
        let mut x = self.to_array();
        for (v, d) in x.iter_mut().zip(delta) {
            *v += d;
        }
        Self::from_array(&x)
    }

    /// How the reading of `v` (`K·v + b` when `with_bias`, else `K·v`) changes with each of the 9
    /// components.
    pub fn partials(&self, v: &Vector3<f64>, with_bias: bool) -> [Vector3<f64>; 9] {
        let [_, s1, s2] = self.scale;
        let [m0, m1, m2] = self.misalignment;
        let lv = Vector3::new(v.x, m0 * v.x + v.y, m1 * v.x + m2 * v.y + v.z);
        let b = if with_bias { 1.0 } else { 0.0 };
        [
            Vector3::x() * b,
            Vector3::y() * b,
            Vector3::z() * b,
            Vector3::x() * lv.x,
            Vector3::y() * lv.y,
            Vector3::z() * lv.z,
            Vector3::y() * ((1.0 + s1) * v.x),
            Vector3::z() * ((1.0 + s2) * v.x),
            Vector3::z() * ((1.0 + s2) * v.y),
        ]
    }

    /// Whether every number is zero (an ideal accelerometer).
    pub fn is_ideal(&self) -> bool {
        self.to_array().iter().all(|&x| x == 0.0)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The partials agree with central differences of the reading, and `correct` undoes `read`.
    #[test]
    fn partials_and_correction() {
        let i = Intrinsics {
            bias: [0.3, -0.2, 0.5],
            scale: [0.02, -0.03, 0.01],
            misalignment: [0.01, -0.02, 0.015],
        };
        let v = Vector3::new(1.5, -7.0, 4.0);
        for with_bias in [true, false] {
            let read = |x: &Intrinsics| {
                x.matrix() * v
                    + if with_bias {
                        Vector3::from(x.bias)
                    } else {
                        Vector3::zeros()
                    }
            };
            let p = i.partials(&v, with_bias);
            for (c, pc) in p.iter().enumerate() {
                let mut d = [0.0; 9];
                d[c] = 1e-6;
                let plus = read(&i.moved(&d));
                d[c] = -1e-6;
                let minus = read(&i.moved(&d));
                assert!(((plus - minus) / 2e-6 - pc).norm() < 1e-6, "component {c}");
            }
        }
        // y leans towards x by m0: K·x̂ has a y component (1 + s_y)·m0.
        let k = i.matrix();
        assert!((k[(1, 0)] - 0.97 * 0.01).abs() < 1e-15);
        let back = i.correct(&i.read(&v)).unwrap();
        assert!((back - v).norm() < 1e-12);
    }
}
