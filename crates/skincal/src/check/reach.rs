//! What any motion could tell of an SU's change, and which DoF's motion tells which part: the
//! information of rich synthetic motion (random poses within the limits, every DoF of its chain
//! turning and accelerating), as a whole and one DoF at a time. A direction no motion tells (the
//! height of an SU along a vertical first axis that alone carries it, a tilt that its bias
//! mimics) is no reason to ask for more motion.

use nalgebra::Vector3;
use rand::Rng;
use rand_chacha::rand_core::SeedableRng;
use rand_chacha::ChaCha8Rng;

use super::kin::{self, BlockKinematics, SuPlace, CHANGE};
use super::test::{Change, ChangeMatrix};
use super::zero::Rates;
use crate::model::Robot;

/// Synthetic blocks of rich motion.
const RICH_BLOCKS: usize = 60;
/// Synthetic blocks per DoF moving alone.
const DOF_BLOCKS: usize = 24;
/// Speed and acceleration of the synthetic motion, rad/s and rad/s².
const RATE: f64 = 1.0;
const ACCELERATION: f64 = 4.0;
/// Blocks of rich motion that a direction must be told within: a minute of 10 ms blocks.
const MINUTE: f64 = 6000.0;

/// Per SU: the information per block of rich motion (scaled units, unit noise), and per DoF of
/// its chain the information that DoF's motion alone gives (scaled units).
#[derive(Debug, Clone)]
pub struct Reach {
    /// Per SU.
    pub rich: Vec<ChangeMatrix>,
    /// Per SU: `(DoF, information)`.
    pub by_dof: Vec<Vec<(usize, ChangeMatrix)>>,
    /// Per DoF: the information on its zero per block of rich motion, every SU it carries at
    /// unit noise, rad⁻² (none: no motion tells it — a vertical axis on the still reference
    /// segment turns what it carries about gravity, and no reading changes).
    pub zero: Vec<f64>,
    /// Per SU: what it reads in each block of rich motion, m/s².
    readings: Vec<Vec<Vector3<f64>>>,
}

impl Reach {
    /// The reach of every SU in `places` on `robot`, change components scaled by `scale`.
    pub fn new(robot: &Robot, places: &[SuPlace], chains: &[Vec<usize>], scale: &Change) -> Self {
        let d = ChangeMatrix::from_diagonal(scale);
        let n = robot.model.dofs().len();
        let mut rng = ChaCha8Rng::seed_from_u64(0x5eed);
        let mut rich = vec![ChangeMatrix::zeros(); places.len()];
        let mut zero = vec![0.0; n];
        let mut readings = vec![Vec::with_capacity(RICH_BLOCKS); places.len()];
        for _ in 0..RICH_BLOCKS {
            let (q, block) = random_block(robot, &mut rng, &|_| true);
            add_information(&mut rich, places, &block, &d);
            for (r, place) in readings.iter_mut().zip(places) {
                r.push(kin::reading(place, &block).0);
            }
            let rates = Rates::new(robot, &block, &q[0], &q[1], &q[2]);
            for (place, chain) in places.iter().map(|p| (p, &chains[p.segment])) {
                for &dof in chain {
                    zero[dof] += rates.first(dof, place).norm_squared() / RICH_BLOCKS as f64;
                }
            }
        }
        let mut by_dof: Vec<Vec<(usize, ChangeMatrix)>> = vec![Vec::new(); places.len()];
        for dof in 0..n {
            let carried: Vec<usize> = (0..places.len())
                .filter(|&u| chains[places[u].segment].contains(&dof))
                .collect();
            if carried.is_empty() {
                continue;
            }
            let mut info = vec![ChangeMatrix::zeros(); places.len()];
            for _ in 0..DOF_BLOCKS {
                let (_, block) = random_block(robot, &mut rng, &|k| k == dof);
                add_information(&mut info, places, &block, &d);
            }
            for u in carried {
                by_dof[u].push((dof, info[u]));
            }
        }
        for info in &mut rich {
            *info /= RICH_BLOCKS as f64;
        }
        Self {
            rich,
            by_dof,
            zero,
            readings,
        }
    }

    /// The root mean square over a block of rich motion of what SUs `u` and `v` read apart,
    /// m/s².
    pub fn apart(&self, u: usize, v: usize) -> f64 {
        let squares: f64 = self.readings[u]
            .iter()
            .zip(&self.readings[v])
            .map(|(a, b)| (a - b).norm_squared())
            .sum();
        (squares / RICH_BLOCKS as f64).sqrt()
    }

    /// Whether a minute of rich motion tells DoF `dof`'s zero to within `angle` (rad) at block
    /// noise `noise` with non-centrality `lambda`.
    pub fn zero_tellable(&self, dof: usize, angle: f64, noise: f64, lambda: f64) -> bool {
        self.zero[dof] * MINUTE / (noise * noise) * angle * angle >= lambda
    }

    /// The projector onto the change directions (scaled units) of SU `u` that a minute of rich
    /// motion tells at block noise `noise` with non-centrality `lambda`.
    pub fn tellable(&self, u: usize, noise: f64, lambda: f64) -> ChangeMatrix {
        let eigen = nalgebra::SymmetricEigen::new(self.rich[u] * (MINUTE / (noise * noise)));
        let mut p = ChangeMatrix::zeros();
        for i in 0..CHANGE {
            if eigen.eigenvalues[i] >= lambda {
                let e = eigen.eigenvectors.column(i);
                p += e * e.transpose();
            }
        }
        p
    }
}

/// One block at a random pose within the limits, the DoFs `moving` turning and accelerating at
/// random, the others still: its joint positions, velocities and accelerations, and its
/// kinematics.
fn random_block(
    robot: &Robot,
    rng: &mut ChaCha8Rng,
    moving: &dyn Fn(usize) -> bool,
) -> ([Vec<f64>; 3], BlockKinematics) {
    let dofs = robot.model.dofs();
    let q: Vec<f64> = dofs
        .iter()
        .map(|d| {
            let (lo, hi) = (d.limits.lower.max(-3.0), d.limits.upper.min(3.0));
            if hi > lo {
                rng.random_range(lo..hi)
            } else {
                lo
            }
        })
        .collect();
    let mut signed = |scale: f64, k: usize| {
        if moving(k) {
            scale * rng.random_range(-1.0..1.0)
        } else {
            0.0
        }
    };
    let qd: Vec<f64> = (0..dofs.len()).map(|k| signed(RATE, k)).collect();
    let qdd: Vec<f64> = (0..dofs.len()).map(|k| signed(ACCELERATION, k)).collect();
    let block = BlockKinematics::new(robot, &q, &qd, &qdd);
    ([q, qd, qdd], block)
}

fn add_information(
    info: &mut [ChangeMatrix],
    places: &[SuPlace],
    block: &BlockKinematics,
    d: &ChangeMatrix,
) {
    for (i, place) in info.iter_mut().zip(places) {
        let (_, jac) = kin::reading(place, block);
        let j = jac * d;
        *i += j.transpose() * j;
    }
}
