//! Readings weighed by the noise they show and the wild ones left out: variance components,
//! glitches, each SU's residual.

use super::*;

/// Where the set gives no reading its own deviation, no uniform noise was asked for
/// (`reading_sd`) and the fit has no motion record: the
/// static and the dynamic readings' noise estimated apart from the residuals (their sums of
/// squares, corrected for the parameters fitted), every reading weighed by its component's, and
/// the fit repeated. Returns the solution, the readings with those deviations, the LM iterations
/// and the components; unchanged when there is nothing to estimate.
pub(super) fn weigh_by_noise_components(
    solved: Solved,
    layout: &Layout,
    readings: Readings,
    spec: &Spec,
    config: &MlConfig,
) -> (Solved, Readings, usize, Option<NoiseComponents>) {
    if readings.sd.is_some() || readings.motion.is_some() || !config.reading_sd {
        return (solved, readings, 0, None);
    }
    let sigma = config.noise_sd;
    let norms = problem::reading_norms(&solved.state, layout, &readings, spec, sigma);
    let (mut sums, mut counts) = ([0.0f64; 2], [0usize; 2]);
    for (p, pose) in norms.iter().enumerate() {
        for (u, rows) in pose.iter().enumerate() {
            for (j, n) in rows.iter().enumerate() {
                if !readings.is_rejected(p, u, j) {
                    let kind = usize::from(j > 0);
                    sums[kind] += n * n;
                    counts[kind] += 3;
                }
            }
        }
    }
    let rows = counts[0] + counts[1];
    let parameters = spec.columns().len();
    if counts.contains(&0) || rows <= 2 * parameters {
        return (solved, readings, 0, None);
    }
    let correction = rows as f64 / (rows - parameters) as f64;
    let [s, d] = [0, 1].map(|k| sigma * (sums[k] / counts[k] as f64 * correction).sqrt());
    if !(s > 0.0 && d > 0.0 && s.is_finite() && d.is_finite()) {
        return (solved, readings, 0, None);
    }
    let sd: Vec<Vec<Vec<f64>>> = (0..readings.q.len())
        .map(|_| {
            layout
                .su_segment
                .iter()
                .map(|&seg| (0..=seg).map(|j| if j == 0 { s } else { d }).collect())
                .collect()
        })
        .collect();
    let readings = Readings {
        sd: Some(std::sync::Arc::new(sd)),
        ..readings
    };
    let solved = refit(
        (solved.state, solved.damping),
        layout,
        &readings,
        spec,
        config,
    );
    let iterations = solved.iterations;
    (
        solved,
        readings,
        iterations,
        Some(NoiseComponents {
            static_sd: s,
            dynamic_sd: d,
        }),
    )
}

/// Wild readings (glitches) out and the fit repeated by plain least squares on the rest, until
/// the set left out stops changing ([`REJECT_ROUNDS`] at most). Returns the solution, the
/// readings with those left out marked, and the LM iterations.
pub(super) fn leave_out_glitches(
    mut solved: Solved,
    layout: &Layout,
    readings: &Readings,
    spec: &Spec,
    config: &MlConfig,
) -> (Solved, Readings, usize) {
    let sigma = config.noise_sd;
    let mut readings = Readings {
        huber: None,
        rejected: Vec::new(),
        ..readings.clone()
    };
    let mut iterations = 0;
    for _ in 0..REJECT_ROUNDS {
        let norms = problem::reading_norms(&solved.state, layout, &readings, spec, sigma);
        let rejected = wild_readings(&norms, layout.su_segment.len());
        let unchanged = rejected == readings.rejected
            || (readings.rejected.is_empty() && rejected.iter().flatten().flatten().all(|r| !r));
        readings.rejected = rejected;
        if unchanged {
            break;
        }
        solved = refit(
            (solved.state, solved.damping),
            layout,
            &readings,
            spec,
            config,
        );
        iterations += solved.iterations;
    }
    (solved, readings, iterations)
}

/// `[p][u][row]`: the readings more than [`REJECT`] off (whitened norms `norms`), except for an
/// SU with more than [`MAX_GLITCH_SHARE`] of its readings off: glitches are rare, so that SU is
/// misfit (a broken SU or a wrong model), not glitching, and keeps them all.
pub(super) fn wild_readings(norms: &[Vec<Vec<f64>>], sus: usize) -> Vec<Vec<Vec<bool>>> {
    let mut wild: Vec<Vec<Vec<bool>>> = norms
        .iter()
        .map(|pose| {
            pose.iter()
                .map(|su| su.iter().map(|&n| n > REJECT).collect())
                .collect()
        })
        .collect();
    for u in 0..sus {
        let (off, all) = wild.iter().fold((0, 0), |(o, a), pose| {
            (
                o + pose[u].iter().filter(|&&r| r).count(),
                a + pose[u].len(),
            )
        });
        if off as f64 > MAX_GLITCH_SHARE * all as f64 {
            for pose in &mut wild {
                pose[u].iter_mut().for_each(|r| *r = false);
            }
        }
    }
    wild
}

/// Per SU: the RMS of its whitened residuals over the readings that count, per component.
pub(super) fn su_residual_ratios(
    state: &ChainState,
    layout: &Layout,
    readings: &Readings,
    spec: &Spec,
    sigma: f64,
) -> Vec<f64> {
    let norms = problem::reading_norms(state, layout, readings, spec, sigma);
    let motion = problem::motion_sums(state, layout, readings, spec, sigma);
    (0..layout.su_segment.len())
        .map(|u| {
            let (sum, n) = norms
                .iter()
                .enumerate()
                .fold((0.0, 0), |(s, n), (p, pose)| {
                    pose[u]
                        .iter()
                        .enumerate()
                        .filter(|&(j, _)| !readings.is_rejected(p, u, j))
                        .fold((s, n), |(s, n), (_, x)| (s + x * x, n + 3))
                });
            let (sum, n) = (sum + motion[u].0, n + motion[u].1);
            (sum / n.max(1) as f64).sqrt()
        })
        .collect()
}
