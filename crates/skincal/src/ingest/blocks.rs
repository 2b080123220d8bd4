//! The skin's side of a motion record's blocks: each SU's fresh samples summed per block with
//! the times they were taken, and each block's mean referred to the block's centre.
//!
//! A block's mean is the signal's value at the mean time of its samples, not at its centre: a
//! 1 kHz board fills a 10 ms block with samples 0.5 ms before it on average when the block
//! starts on a sample, 0.5 ms after when a sample's stamp rounds to just before the boundary
//! (stamps of epoch seconds in an `f64` resolve 240 ns, and which side a boundary sample falls
//! on drifts along the log), and a board sending at 20 Hz puts its one sample anywhere within
//! ±5 ms of the centre. At the speed of a distal SU's reading in a continuous program
//! (30 m/s³) half a millisecond is 0.015 m/s², eight times a block mean's noise. So every
//! block mean is corrected with its own samples' times: the reading `f` and its first two
//! derivatives at the centre are solved from the means of the block and of the nearest blocks
//! on each side where the SU sent samples, each mean being
//! `f + f'·τ̄ + ½ f''·τ²̄` over its samples' times `τ` from the centre (exact for a quadratic
//! signal; for a block filled evenly this is the mean less `Δ²/24` of its second derivative).

use std::collections::VecDeque;

use nalgebra::{Matrix3, Vector3};

use crate::motion::MotionRun;

/// How many blocks apart the nearest means a block's correction reads may lie on each side: a
/// board sending at 20 Hz leaves four blocks between two of its samples. A block whose SU sent
/// nothing within this on either side keeps its mean.
pub const CORRECTION_REACH: usize = 5;

/// One SU's fresh samples in one block: the sums of their components, their count, and the sums
/// of their times from the block's centre and of those times squared (in blocks).
#[derive(Debug, Clone, Copy, Default, PartialEq)]
pub struct SkinSum {
    sum: [f64; 3],
    count: f64,
    time: f64,
    time_squared: f64,
}

impl SkinSum {
    /// Takes sample `a`, taken `offset` blocks after the block's centre.
    pub fn add(&mut self, a: [f64; 3], offset: f64) {
        for (s, x) in self.sum.iter_mut().zip(a) {
            *s += x;
        }
        self.count += 1.0;
        self.time += offset;
        self.time_squared += offset * offset;
    }

    /// The samples' mean and its times; `None` without a sample.
    pub fn mean(&self) -> Option<RawMean> {
        (self.count > 0.0).then(|| RawMean {
            value: self.sum.map(|s| s / self.count),
            time: self.time / self.count,
            time_squared: self.time_squared / self.count,
        })
    }
}

/// A block's mean of one SU's samples, and the mean and mean square of their times from the
/// block's centre, in blocks.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct RawMean {
    /// The mean, SU frame, m/s².
    pub value: [f64; 3],
    /// The samples' mean time from the centre, blocks.
    pub time: f64,
    /// Their mean squared time from the centre, blocks².
    pub time_squared: f64,
}

/// Block `index` of `rows` (one SU `u`) referred to its centre from the nearest means within
/// [`CORRECTION_REACH`] on each side; its own mean where either side has none.
fn corrected(rows: &VecDeque<Vec<Option<RawMean>>>, index: usize, u: usize) -> Option<[f64; 3]> {
    let own = rows[index][u]?;
    let before = (1..=CORRECTION_REACH.min(index))
        .find_map(|j| rows[index - j][u].map(|m| (-(j as f64), m)));
    let after = (1..=CORRECTION_REACH)
        .take_while(|j| index + j < rows.len())
        .find_map(|j| rows[index + j][u].map(|m| (j as f64, m)));
    let (Some(before), Some(after)) = (before, after) else {
        return Some(own.value);
    };
    // Row j: the mean of block j blocks away, `f + f'·τ̄ + ½ f''·τ²̄` with its times taken
    // from this block's centre.
    let row = |(shift, m): (f64, RawMean)| {
        [
            1.0,
            m.time + shift,
            0.5 * (m.time_squared + 2.0 * shift * m.time + shift * shift),
        ]
    };
    let means = [before, (0.0, own), after];
    let a = means.map(row);
    let lu = Matrix3::from_fn(|i, j| a[i][j]).lu();
    let mut value = [0.0; 3];
    for (c, v) in value.iter_mut().enumerate() {
        let b = Vector3::from_fn(|i, _| means[i].1.value[c]);
        *v = lu.solve(&b)?[0];
    }
    Some(value)
}

/// Refers a run's block means to the blocks' centres as the blocks come ([`Self::push`]):
/// each block's is corrected once the blocks [`CORRECTION_REACH`] after it have come, and the
/// run's last blocks when it ends ([`Self::finish`]).
#[derive(Debug, Default)]
pub struct Centring {
    /// The raw means of the run's latest blocks, the last one newest.
    rows: VecDeque<Vec<Option<RawMean>>>,
    /// How many of `rows` (from the front) are already corrected and kept only as neighbours.
    done: usize,
}

impl Centring {
    /// Adds a block to `run` (per DoF `[q, q̇, q̈, q̈'s deviation]`, and each SU's raw mean, which
    /// it holds until corrected) and corrects the block [`CORRECTION_REACH`] before it.
    pub fn push(&mut self, run: &mut MotionRun, joints: &[[f64; 4]], raw: Vec<Option<RawMean>>) {
        run.push_joints(joints);
        self.push_skin(run, raw);
    }

    /// Adds a block's raw skin means to `run` (whose joint states may be in already), and
    /// corrects the block [`CORRECTION_REACH`] before it.
    pub fn push_skin(&mut self, run: &mut MotionRun, raw: Vec<Option<RawMean>>) {
        let values: Vec<Option<[f64; 3]>> = raw.iter().map(|m| m.map(|m| m.value)).collect();
        run.skin.push(&values);
        self.rows.push_back(raw);
        if self.rows.len() > self.done + CORRECTION_REACH {
            self.correct_next(run);
        }
        while self.done > CORRECTION_REACH {
            self.rows.pop_front();
            self.done -= 1;
        }
    }

    /// How many of the run's last blocks are not corrected yet.
    pub fn pending(&self) -> usize {
        self.rows.len() - self.done
    }

    /// The run ends: its blocks not yet corrected are, from what there is.
    pub fn finish(&mut self, run: &mut MotionRun) {
        while self.pending() > 0 {
            self.correct_next(run);
        }
        self.rows.clear();
        self.done = 0;
    }

    /// Corrects the oldest pending block, in `run`.
    fn correct_next(&mut self, run: &mut MotionRun) {
        let index = self.done;
        let b = run.skin.len() - self.pending();
        let values: Vec<Option<[f64; 3]>> = (0..self.rows[index].len())
            .map(|u| corrected(&self.rows, index, u))
            .collect();
        run.skin.set_row(b, &values);
        self.done += 1;
    }
}

/// Each SU's raw means of a row of sums.
pub fn raw_means(row: &[SkinSum]) -> Vec<Option<RawMean>> {
    row.iter().map(SkinSum::mean).collect()
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Runs `means` (per block, per SU: value and the times of its samples) through [`Centring`].
    fn centred(means: &[Vec<Option<RawMean>>]) -> Vec<Vec<Option<[f64; 3]>>> {
        let mut run = MotionRun::new("test", 0.0);
        let mut centring = Centring::default();
        for raw in means {
            centring.push(&mut run, &[], raw.clone());
        }
        centring.finish(&mut run);
        (0..run.skin.len())
            .map(|b| run.skin.row(b).collect())
            .collect()
    }

    /// Whether `x` is `want` as the record holds it (single precision: within its rounding,
    /// besides the arithmetic's own 1e-12).
    fn held(x: f64, want: f64) -> bool {
        (x - want).abs() <= 1e-12 + f64::from(f32::EPSILON) * want.abs()
    }

    /// `value` as the record holds it.
    fn rounded(value: [f64; 3]) -> [f64; 3] {
        value.map(|x| f64::from(x as f32))
    }

    /// The mean over `samples` taken at `times` (blocks from block `b`'s centre) of `f`.
    fn mean_of(f: &dyn Fn(f64) -> f64, b: usize, times: &[f64]) -> RawMean {
        let mut sum = SkinSum::default();
        for &t in times {
            let x = f(b as f64 + t);
            sum.add([x, 2.0 * x, -x], t);
        }
        sum.mean().unwrap()
    }

    #[test]
    fn a_quadratic_is_read_at_every_centre_whenever_its_samples_were_taken() {
        // Ten samples a block, starting on the block's start (0.45 blocks early on average) or
        // just after it (0.55 late: a boundary sample in the block before), switching every
        // seven blocks; SU 1 a slow board's one sample every third block at varying times.
        let f = |t: f64| 3.0 + 0.7 * t - 0.2 * t * t;
        let even: Vec<f64> = (0..10).map(|k| -0.5 + 0.1 * f64::from(k)).collect();
        let late: Vec<f64> = (1..=10).map(|k| -0.5 + 0.1 * f64::from(k)).collect();
        let means: Vec<Vec<Option<RawMean>>> = (0..30)
            .map(|b| {
                let times = if (b / 7) % 2 == 0 { &even } else { &late };
                let slow = (b % 3 == 0).then(|| mean_of(&f, b, &[0.37 - 0.08 * (b % 5) as f64]));
                vec![Some(mean_of(&f, b, times)), slow]
            })
            .collect();
        let got = centred(&means);
        for (b, row) in got.iter().enumerate() {
            let want = f(b as f64);
            // The first and last blocks have no neighbour on one side: their means stay.
            let inner = b > 0 && b < 29;
            let fast = row[0].unwrap();
            if inner {
                for (x, s) in fast.iter().zip([1.0, 2.0, -1.0]) {
                    assert!(held(*x, s * want), "block {b}: {x} for {}", s * want);
                }
            } else {
                assert_eq!(fast, rounded(means[b][0].unwrap().value), "block {b}");
            }
            match means[b][1] {
                Some(_) if b > 0 && b < 27 => {
                    let x = row[1].unwrap()[0];
                    assert!(held(x, want), "slow board, block {b}: {x} for {want}");
                }
                Some(m) => assert_eq!(row[1], Some(rounded(m.value)), "slow board, block {b}"),
                None => assert_eq!(row[1], None, "slow board, block {b}"),
            }
        }
    }

    #[test]
    fn an_evenly_filled_block_loses_a_24th_of_its_second_difference() {
        // The correction the continuous mean over a block implies: `τ̄ = 0`, `τ²̄ = 1/12`.
        let even = |value: f64| {
            Some(RawMean {
                value: [value; 3],
                time: 0.0,
                time_squared: 1.0 / 12.0,
            })
        };
        let got = centred(&[vec![even(1.0)], vec![even(5.0)], vec![even(2.0)]]);
        let want = 5.0 - (1.0 - 10.0 + 2.0) / 24.0;
        assert!(held(got[1][0].unwrap()[0], want));
    }

    #[test]
    fn a_board_silent_beyond_the_reach_keeps_its_means() {
        let at = |value: f64| {
            Some(RawMean {
                value: [value; 3],
                time: 0.3,
                time_squared: 0.09,
            })
        };
        let mut means = vec![vec![None]; 2 * CORRECTION_REACH + 3];
        means[0][0] = at(1.0);
        means[CORRECTION_REACH + 1][0] = at(2.0);
        means[2 * CORRECTION_REACH + 2][0] = at(4.0);
        let got = centred(&means);
        assert_eq!(got[CORRECTION_REACH + 1][0], Some([2.0; 3]));
        assert!(got.iter().flatten().filter(|x| x.is_some()).count() == 3);
    }
}
