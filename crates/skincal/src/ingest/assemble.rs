//! Stations, structure groups and the measurement set.

use std::collections::BTreeMap;

use serde_json::Map;

use super::fit::{Excitation, PooledFit};
use super::segment::{Event, Segmentation, SHORT_STILL};
use super::skin::{Accumulated, SuRegistry};
use super::timeline::Grid;
use super::{base, ExcitationFit, IngestConfig, IngestError, IngestReport, Ingested, LogReport};
use crate::measurements::{
    MeasurementSet, Move, Orientation, Reading, StructureExperiment, TrainingExperiment,
    TrainingPose, MAX_ORIENTATIONS,
};
use crate::model::sensor::ExcitationPattern;

/// A station: still windows at one pose, joined by excitations.
struct Station {
    log: usize,
    stills: Vec<usize>,
    excitations: Vec<usize>,
    pose: Vec<f64>,
    /// Index of the structure group (only for stations without excitations).
    group: Option<usize>,
    /// The base orientation of a training station (0: the one most training poses stood in).
    orientation: usize,
}

/// Everything the passes over the logs found, for assembling.
pub(super) struct Passes<'a> {
    pub(super) config: &'a IngestConfig,
    pub(super) dofs: &'a [String],
    pub(super) sus: &'a SuRegistry,
    pub(super) grids: &'a [Grid],
    pub(super) segs: &'a [Segmentation],
    pub(super) accumulated: &'a [Accumulated],
    pub(super) reports: Vec<LogReport>,
    pub(super) warnings: Vec<String>,
    /// Per SU, the variance of one sample (mean over the axes) in the still windows, m²/s⁴;
    /// `None` when an SU has too few samples there to tell.
    pub(super) variance: Option<Vec<f64>>,
    /// Per SU, which DoFs move it (by the structure part's tree), `None` for an SU the tree does
    /// not place; `None` altogether without a structure part. Needed only to attribute windows in
    /// which several DoFs were excited together.
    pub(super) moved_by: Option<Vec<Option<Vec<bool>>>>,
}

impl Passes<'_> {
    fn path(&self, log: usize) -> String {
        self.reports[log].path.display().to_string()
    }

    /// Start of a station, s from its log's first joint state.
    fn at(&self, st: &Station) -> f64 {
        let w = &self.segs[st.log].stills[st.stills[0]];
        self.grids[st.log].time(w.start)
    }

    /// The still windows a station's reading pools: the full ones, or the short ones where there
    /// is none, or those in which the DoFs crept least where none was still.
    fn pooled(&self, st: &Station) -> Vec<usize> {
        let windows = &self.segs[st.log].stills;
        let rank = |w: usize| {
            let w = &windows[w];
            w.reading.then(|| (w.creeping.unwrap_or(0.0), w.short))
        };
        let best = st
            .stills
            .iter()
            .filter_map(|&w| rank(w))
            .min_by(|a, b| a.0.total_cmp(&b.0).then(a.1.cmp(&b.1)));
        st.stills
            .iter()
            .copied()
            .filter(|&w| best.is_some() && rank(w) == best)
            .collect()
    }

    /// Counts a station read from windows in which the DoFs still crept in its log's report.
    fn count_creep(&mut self, st: &Station) {
        let windows = &self.segs[st.log].stills;
        if self
            .pooled(st)
            .first()
            .is_some_and(|&w| windows[w].creeping.is_some())
        {
            self.reports[st.log].creeping += 1;
        }
    }

    /// The static readings of a station, pooled over its still windows; why there are none as
    /// the error.
    fn still_reading(&self, st: &Station) -> Result<Vec<(Reading, u64)>, String> {
        let windows = &self.segs[st.log].stills;
        if st.stills.iter().all(|&w| !windows[w].reading) {
            return Err(format!(
                "it was never still for a static reading (every DoF below {} rad/s, or creeping \
                 below {} rad/s, for {:.3} s, plus {} s trimmed at both ends): servos that ring \
                 longer than the program holds need longer holds (`skincal plan --still S \
                 --settle S`), or ingest with a larger --quiet-velocity",
                self.config.still_velocity,
                self.config.quiet_velocity,
                self.config.min_still / SHORT_STILL as f64,
                self.config.trim
            ));
        }
        let pooled = self.pooled(st);
        let acc = &self.accumulated[st.log];
        (0..self.sus.names.len())
            .map(|su| {
                let mut n = 0u64;
                let mut sum = [0.0; 3];
                for &w in &pooled {
                    if let Some(s) = acc.stills[w].get(su) {
                        n += s.n;
                        for (total, v) in sum.iter_mut().zip(&s.sum) {
                            *total += v;
                        }
                    }
                }
                if n == 0 {
                    Err(format!(
                        "SU `{}` has no sample in its still windows",
                        self.sus.names[su]
                    ))
                } else {
                    Ok((sum.map(|v| v / n as f64), n))
                }
            })
            .collect()
    }
}

/// Still windows at one pose joined by excitations are a station; stations joined by moves
/// form a structure group, which a transfer or a broken motion ends. Returns the stations and
/// the number of groups.
fn stations(segs: &[Segmentation], config: &IngestConfig) -> (Vec<Station>, usize) {
    let tolerance = config.motion_threshold;
    let mut stations: Vec<Station> = Vec::new();
    let mut group_count = 0usize;
    for (li, seg) in segs.iter().enumerate() {
        let mut current: Option<usize> = None;
        let mut group: Option<usize> = None;
        // Whether the last motion was an excitation: the DoFs came back, and the pause after it
        // is at the station's pose even where a servo ends it a few mrad off.
        let mut returned = false;
        for event in &seg.events {
            let after_excitation = std::mem::replace(&mut returned, false);
            match *event {
                Event::Still(s) => {
                    let pose = &seg.stills[s].pose;
                    let same = current.is_some_and(|c| {
                        after_excitation
                            || stations[c]
                                .pose
                                .iter()
                                .zip(pose)
                                .all(|(a, b)| (a - b).abs() < tolerance)
                    });
                    if let (true, Some(c)) = (same, current) {
                        stations[c].stills.push(s);
                        continue;
                    }
                    let g = *group.get_or_insert_with(|| {
                        group_count += 1;
                        group_count - 1
                    });
                    stations.push(Station {
                        log: li,
                        stills: vec![s],
                        excitations: Vec::new(),
                        pose: pose.clone(),
                        group: Some(g),
                        orientation: 0,
                    });
                    current = Some(stations.len() - 1);
                }
                Event::Excitation(x) => {
                    if let Some(c) = current {
                        stations[c].excitations.push(x);
                        returned = true;
                    }
                }
                Event::Move => current = None,
                Event::Transfer | Event::Broken => {
                    current = None;
                    group = None;
                }
            }
        }
    }
    (stations, group_count)
}

/// The fit of a station's windows for the SUs that the DoFs `dropped` do not move: their terms
/// are left out of every window (their coefficients are zero).
struct ClassFit {
    /// Per window, the kept columns of its full design.
    kept: Vec<Vec<usize>>,
    /// Per window, its design restricted to them.
    windows: Vec<Excitation>,
    fit: PooledFit,
}

impl ClassFit {
    fn new(excitations: &[&Excitation], dropped: &[usize]) -> ClassFit {
        let kept: Vec<Vec<usize>> = excitations.iter().map(|x| x.kept(dropped)).collect();
        let windows: Vec<Excitation> = excitations
            .iter()
            .zip(&kept)
            .map(|(x, k)| x.restricted(k))
            .collect();
        let fit = PooledFit::new(&windows.iter().collect::<Vec<_>>());
        ClassFit { kept, windows, fit }
    }
}

/// Which DoFs excited together at a station do not move `su`: their terms are left out of its
/// fit. An error says why the SU's response cannot be attributed.
fn dropped_for(
    passes: &Passes<'_>,
    excitations: &[&Excitation],
    together: &[usize],
    su: usize,
) -> Result<Vec<usize>, String> {
    if together.is_empty() {
        return Ok(Vec::new());
    }
    let name = |d: usize| format!("`{}`", passes.dofs[d]);
    let Some(moved) = passes.moved_by.as_ref().and_then(|m| m[su].as_ref()) else {
        return Err(format!(
            "DoFs were excited together ({} and others), and which of them moves SU `{}` is told \
             by the structure part: ingest its logs together with these, or give the tree of an \
             earlier structure experiment (--structure){}",
            name(together[0]),
            passes.sus.names[su],
            if passes.moved_by.is_some() {
                " (the tree does not place this SU)"
            } else {
                ""
            }
        ));
    };
    for x in excitations.iter().filter(|x| x.dofs.len() > 1) {
        let moving: Vec<usize> = x.dofs.iter().copied().filter(|&d| moved[d]).collect();
        if moving.len() > 1 {
            return Err(format!(
                "{} were excited together and both move SU `{}` (by the structure part), so their \
                 responses cannot be told apart: plan with a description whose tree is the robot's",
                moving
                    .iter()
                    .map(|&d| name(d))
                    .collect::<Vec<_>>()
                    .join(" and "),
                passes.sus.names[su]
            ));
        }
    }
    Ok(together.iter().copied().filter(|&d| !moved[d]).collect())
}

/// The training pose of a station with excitations: its static reading and, from one joint fit
/// of all its excitation windows, the dynamic acceleration of every excited DoF. `None` (with a
/// warning) when it cannot be used.
///
/// Where several DoFs were excited together (no SU is moved by two of them), each SU is fitted
/// without the terms of those that do not move it, and its reading for them is zero with the
/// uncertainty a reading of that DoF alone would have.
fn training_pose(
    passes: &mut Passes<'_>,
    st: &Station,
    pattern: &ExcitationPattern,
) -> Option<TrainingPose> {
    let skip = |passes: &mut Passes<'_>, why: String| {
        let warning = format!(
            "{}: training pose at {:.3} s skipped: {why}",
            passes.path(st.log),
            passes.at(st)
        );
        passes.warnings.push(warning);
    };
    let (static_readings, counts): (Vec<Reading>, Vec<u64>) = match passes.still_reading(st) {
        Ok(r) => {
            passes.count_creep(st);
            r.into_iter().unzip()
        }
        Err(why) => {
            skip(passes, why);
            return None;
        }
    };
    let segs = passes.segs;
    let windows = fittable_windows(passes, st);
    if windows.is_empty() {
        return None;
    }
    let excitations: Vec<&Excitation> = windows
        .iter()
        .map(|&xi| &segs[st.log].excitations[xi])
        .collect();
    let mut together: Vec<usize> = excitations
        .iter()
        .filter(|x| x.dofs.len() > 1)
        .flat_map(|x| x.dofs.iter().copied())
        .collect();
    together.sort_unstable();
    together.dedup();
    let dropped: Vec<Vec<usize>> = match (0..passes.sus.names.len())
        .map(|su| dropped_for(passes, &excitations, &together, su))
        .collect::<Result<_, _>>()
    {
        Ok(d) => d,
        Err(why) => {
            skip(passes, why);
            return None;
        }
    };
    let fits = PoseFits::new(&excitations, &together, &dropped);
    let alpha = pattern.peak_acceleration();
    let readings = dynamic_readings(passes, st.log, &windows, &fits, alpha);
    report_fits(
        &mut passes.reports[st.log],
        passes.dofs,
        &passes.grids[st.log],
        &excitations,
        &readings.powers,
    );
    let missing: Vec<&String> = passes
        .dofs
        .iter()
        .filter(|d| !readings.dynamic.contains_key(*d) && !passes.config.mimic.contains_key(*d))
        .collect();
    if !missing.is_empty() {
        let warning = format!(
            "{}: training pose at {:.3} s has no excitation of {missing:?}",
            passes.path(st.log),
            passes.at(st)
        );
        passes.warnings.push(warning);
    }
    let static_sd = passes.variance.as_ref().map(|v| {
        v.iter()
            .zip(&counts)
            .map(|(var, &n)| (var / n as f64).sqrt())
            .collect()
    });
    Some(TrainingPose {
        q: st.pose.clone(),
        static_readings,
        dynamic: readings.dynamic,
        static_sd,
        dynamic_sd: readings.dynamic_sd,
        orientation: st.orientation,
        extra: Map::new(),
    })
}

/// The excitation windows of a station in which every SU has a sample (the others cannot be
/// fitted; a warning says which SU had none).
fn fittable_windows(passes: &mut Passes<'_>, st: &Station) -> Vec<usize> {
    let seg = &passes.segs[st.log];
    let fits = &passes.accumulated[st.log].fits;
    let mut windows: Vec<usize> = Vec::new();
    for &xi in &st.excitations {
        let x = &seg.excitations[xi];
        match (0..passes.sus.names.len())
            .find(|&su| fits[xi].get(su).is_none_or(|f| f.samples == 0))
        {
            None => windows.push(xi),
            Some(su) => {
                let warning = format!(
                    "{}: excitation of `{}` at {:.3} s skipped: SU `{}` has no sample in it",
                    passes.path(st.log),
                    passes.dofs[x.dofs[0]],
                    passes.grids[st.log].time(x.start),
                    passes.sus.names[su]
                );
                passes.warnings.push(warning);
            }
        }
    }
    windows
}

/// The pooled fits of a station's windows: one per set of DoFs dropped for an SU, with the noise
/// factor of each DoF excited together with others as a reading of it alone.
struct PoseFits<'d> {
    classes: BTreeMap<Vec<usize>, ClassFit>,
    /// Per DoF excited together with others, the noise factor of its reading alone (that of the
    /// SUs it alone moves).
    alone: BTreeMap<usize, f64>,
    /// Per SU, the DoFs dropped from its fit.
    dropped: &'d [Vec<usize>],
}

impl<'d> PoseFits<'d> {
    fn new(excitations: &[&Excitation], together: &[usize], dropped: &'d [Vec<usize>]) -> Self {
        let mut classes: BTreeMap<Vec<usize>, ClassFit> = BTreeMap::new();
        let mut alone: BTreeMap<usize, f64> = BTreeMap::new();
        for &d in together {
            let solo: Vec<usize> = together.iter().copied().filter(|&e| e != d).collect();
            let class = classes
                .entry(solo)
                .or_insert_with_key(|solo| ClassFit::new(excitations, solo));
            alone.insert(
                d,
                class.fit.alpha(d).map_or(0.0, |c| class.fit.sd_factor(c)),
            );
        }
        for d in dropped {
            classes
                .entry(d.clone())
                .or_insert_with_key(|d| ClassFit::new(excitations, d));
        }
        PoseFits {
            classes,
            alone,
            dropped,
        }
    }
}

/// A station's dynamic readings per DoF and SU, scaled to the pattern's peak acceleration
/// `alpha` (a slide's, [`IngestConfig::speed_scale`] of it), their standard deviations, and per
/// window the power of the fitted signal from other DoFs and from the excited one, summed over
/// the SUs.
struct DynamicReadings {
    dynamic: BTreeMap<String, Vec<Reading>>,
    dynamic_sd: BTreeMap<String, Vec<f64>>,
    powers: Vec<(f64, f64)>,
}

fn dynamic_readings(
    passes: &Passes<'_>,
    log: usize,
    windows: &[usize],
    fits: &PoseFits<'_>,
    alpha: f64,
) -> DynamicReadings {
    let sums = &passes.accumulated[log].fits;
    let resolution = &passes.grids[log].resolution;
    let mut out = DynamicReadings {
        dynamic: BTreeMap::new(),
        dynamic_sd: BTreeMap::new(),
        powers: vec![(0.0, 0.0); windows.len()],
    };
    for su in 0..passes.sus.names.len() {
        // The fit's variance in units of one with a sample at every grid point (1 when the skin
        // and the joint states run at the same rate and none is lost): a faster skin gives
        // several samples per point, whose mean varies less; points without a sample (lost, or
        // a slower skin) are interpolated from their neighbours, whose noise then counts for
        // them too.
        let (points, inverse, length) = windows.iter().fold((0u64, 0.0, 0usize), |acc, &xi| {
            let (n, i, len) = acc;
            let len = len + passes.segs[log].excitations[xi].len();
            sums[xi]
                .get(su)
                .map_or((n, i, len), |f| (n + f.points, i + f.inverse, len))
        });
        let thinned = if points > 0 {
            inverse / points as f64 * (length as f64 / points as f64).max(1.0)
        } else {
            1.0
        };
        let class = &fits.classes[&fits.dropped[su]];
        let rhs: Vec<Vec<[f64; 3]>> = windows
            .iter()
            .zip(&class.kept)
            .map(|(&xi, kept)| kept.iter().map(|&c| sums[xi][su].rhs[c]).collect())
            .collect();
        let coefficients = class
            .fit
            .solve(&rhs.iter().map(Vec::as_slice).collect::<Vec<_>>());
        // The samples' noise through the fit, and the encoders' rounding through the measured
        // accelerations of every DoF, weighted by that DoF's coefficient.
        let rounding: f64 = class
            .fit
            .accelerations()
            .map(|(e, c)| {
                let k2 = (0..3).map(|a| coefficients[(c, a)].powi(2)).sum::<f64>() / 3.0;
                resolution[e].powi(2) * k2
            })
            .sum();
        for (w, x) in class.windows.iter().enumerate() {
            let (other, own) = class.fit.powers(w, x, &coefficients);
            out.powers[w].0 += other;
            out.powers[w].1 += own;
            for &d in &x.dofs {
                let name = &passes.dofs[d];
                if out.dynamic.get(name).is_some_and(|r| r.len() > su) {
                    continue;
                }
                // A slide's pattern is the nominal one scaled to m (the measurement set's
                // convention, docs/measurements.md).
                let alpha = alpha * passes.config.speed_scale(name);
                let (reading, variance) = match class.fit.alpha(d) {
                    Some(column) => (
                        [0, 1, 2].map(|axis| coefficients[(column, axis)] * alpha),
                        passes.variance.as_ref().map(|v| {
                            class.fit.sd_factor(column).powi(2) * v[su] * thinned
                                + class.fit.rounding_factor(column).powi(2) * rounding
                        }),
                    ),
                    None => (
                        [0.0; 3],
                        passes
                            .variance
                            .as_ref()
                            .map(|v| fits.alone[&d].powi(2) * v[su] * thinned),
                    ),
                };
                out.dynamic.entry(name.clone()).or_default().push(reading);
                if let Some(variance) = variance {
                    out.dynamic_sd
                        .entry(name.clone())
                        .or_default()
                        .push(alpha * variance.sqrt());
                }
            }
        }
    }
    out
}

/// Each window's fit in the log's report: its DoFs, time, the DoFs coupled into it and the
/// share of the signal they carry.
fn report_fits(
    report: &mut LogReport,
    dofs: &[String],
    grid: &Grid,
    excitations: &[&Excitation],
    powers: &[(f64, f64)],
) {
    for (x, &(other, own)) in excitations.iter().zip(powers) {
        let coupled_dofs = x.terms[1 + 4 * x.dofs.len()..]
            .iter()
            .filter_map(|t| match t {
                super::fit::Term::Alpha(e) => Some(dofs[*e].clone()),
                _ => None,
            })
            .collect();
        report.fits.push(ExcitationFit {
            dof: dofs[x.dofs[0]].clone(),
            together: x.dofs[1..].iter().map(|&d| dofs[d].clone()).collect(),
            start: grid.time(x.start),
            duration: x.len() as f64 * grid.dt,
            coupled_dofs,
            coupled: if own > 0.0 { (other / own).sqrt() } else { 0.0 },
        });
    }
}

/// The DoFs in which pose `a` differs from `b`: beyond `motion_threshold`, and beyond
/// `coupled_fraction` of the largest difference (a compliant servo sags differently when another
/// DoF changes the load). A mimic DoF (named in `config`, of `dofs`) differs with its leader and
/// is not counted.
fn differing(a: &[f64], b: &[f64], dofs: &[String], config: &IngestConfig) -> Vec<usize> {
    let own = |d: usize| dofs.get(d).is_none_or(|n| !config.mimic.contains_key(n));
    let largest = (0..a.len())
        .filter(|&d| own(d))
        .fold(0.0f64, |m, d| m.max((a[d] - b[d]).abs()));
    let bound = config
        .motion_threshold
        .max(config.coupled_fraction * largest);
    (0..a.len())
        .filter(|&d| own(d) && (a[d] - b[d]).abs() >= bound)
        .collect()
}

/// One base orientation of the structure experiment from the stations of group `g`: the rest
/// pose is the pose most of them share, and every station that differs from it in one DoF is a
/// move of that DoF.
fn orientation(passes: &mut Passes<'_>, members: &[&Station]) -> Option<Orientation> {
    let config = passes.config;
    let nu = passes.sus.names.len();
    let path = passes.path(members[0].log);
    let (rest_index, _) = members
        .iter()
        .enumerate()
        .map(|(i, s)| {
            let same = members
                .iter()
                .filter(|o| differing(&o.pose, &s.pose, passes.dofs, config).is_empty())
                .count();
            (i, same)
        })
        .fold(
            (0, 0),
            |best, (i, c)| if c > best.1 { (i, c) } else { best },
        );
    let rest_pose = members[rest_index].pose.clone();
    let mut rest_sum = vec![[0.0; 3]; nu];
    let mut rest_n = 0usize;
    let mut moves = Vec::new();
    for st in members {
        let readings: Vec<Reading> = match passes.still_reading(st) {
            Ok(r) => {
                passes.count_creep(st);
                r.into_iter().map(|(r, _)| r).collect()
            }
            Err(why) => {
                let warning = format!(
                    "{path}: structure pose at {:.3} s skipped: {why}",
                    passes.at(st)
                );
                passes.warnings.push(warning);
                continue;
            }
        };
        match differing(&st.pose, &rest_pose, passes.dofs, config).as_slice() {
            [] => {
                rest_n += 1;
                for (s, r) in rest_sum.iter_mut().zip(&readings) {
                    for k in 0..3 {
                        s[k] += r[k];
                    }
                }
            }
            [d] => moves.push(Move {
                dof: passes.dofs[*d].clone(),
                pose: st.pose.clone(),
                readings,
                accelerated: Vec::new(),
                accelerated_sd: Vec::new(),
                extra: Map::new(),
            }),
            several => {
                let warning = format!(
                    "{path}: structure pose at {:.3} s differs from the rest pose in {} DoFs; \
                     skipped",
                    passes.at(st),
                    several.len()
                );
                passes.warnings.push(warning);
            }
        }
    }
    if rest_n == 0 || moves.is_empty() {
        return None;
    }
    let mut extra = Map::new();
    extra.insert(
        "source".into(),
        serde_json::Value::String(format!("{path} from {:.3} s", passes.at(members[0]))),
    );
    Some(Orientation {
        rest_pose,
        rest: rest_sum
            .iter()
            .map(|s| s.map(|v| v / rest_n as f64))
            .collect(),
        moves,
        extra,
    })
}

/// Per SU, the sum of squared deviations of its samples from their window's mean in the still
/// windows (over the three axes) and its degrees of freedom.
fn scatter(accumulated: &[Accumulated], segs: &[Segmentation], sus: usize) -> Vec<(f64, f64)> {
    let mut out = vec![(0.0, 0.0); sus];
    for (acc, seg) in accumulated.iter().zip(segs) {
        let still = acc
            .stills
            .iter()
            .zip(&seg.stills)
            .filter(|(_, window)| window.creeping.is_none());
        for (w, _) in still {
            for (s, o) in w.iter().zip(out.iter_mut()).filter(|(s, _)| s.n > 1) {
                for k in 0..3 {
                    let n = s.n as f64;
                    o.0 += (s.squares[k] - s.sum[k] * s.sum[k] / n).max(0.0);
                    o.1 += n - 1.0;
                }
            }
        }
    }
    out
}

/// Per SU, which DoFs move it, by the configuration's tree or else the one exploration finds in
/// the structure part (with the configuration's settings); `None` for an SU it does not place.
fn moved_by(passes: &Passes<'_>, orientations: &[Orientation]) -> Vec<Option<Vec<bool>>> {
    if let Some(tree) = &passes.config.tree {
        return moved_by_tree(tree, passes.dofs, &passes.sus.names);
    }
    let mut set = MeasurementSet::new(passes.dofs.to_vec(), passes.sus.names.clone());
    set.prismatic = prismatic_of(passes);
    set.mimic = mimic_of(passes);
    set.structure = Some(StructureExperiment {
        orientations: orientations.to_vec(),
        extra: Map::new(),
    });
    match crate::explore::explore(&set, &passes.config.explore) {
        Ok(structure) => moved_by_tree(&structure, passes.dofs, &passes.sus.names),
        Err(_) => vec![None; passes.sus.names.len()],
    }
}

/// Per SU of `sus`, which of `dofs` move it by `structure`; `None` for an SU it does not place.
pub(super) fn moved_by_tree(
    structure: &crate::explore::Structure,
    dofs: &[String],
    sus: &[String],
) -> Vec<Option<Vec<bool>>> {
    let dof = |name: &String| dofs.iter().position(|d| d == name);
    let su = |name: &String| sus.iter().position(|u| u == name);
    let matrix = &structure.matrix;
    let mut out = vec![None; sus.len()];
    for (row, id) in matrix.segments.iter().enumerate() {
        let mut moved = vec![false; dofs.len()];
        for (column, joint) in matrix.joints.iter().enumerate() {
            if matrix.entries[row][column] {
                for d in structure.joint(joint).into_iter().flat_map(|j| &j.dofs) {
                    if let Some(d) = dof(d) {
                        moved[d] = true;
                    }
                }
            }
        }
        for u in structure.segment(id).into_iter().flat_map(|s| &s.sus) {
            if let Some(u) = su(u) {
                out[u] = Some(moved.clone());
            }
        }
    }
    // SUs on a body a mimic DoF drives (left out of the tree): its leader moves them, with
    // every DoF that moves the body the leader is mounted on.
    let mimic_driven = structure
        .diagnostics
        .iter()
        .filter(|d| d.kind == crate::explore::DiagnosticKind::MimicDriven);
    for driven in mimic_driven {
        let Some(leader) = driven.dofs.first() else {
            continue;
        };
        let Some(joint) = structure.joints.iter().find(|j| j.dofs.contains(leader)) else {
            continue;
        };
        let mut moved = vec![false; dofs.len()];
        let mut next = Some(joint);
        while let Some(j) = next {
            for d in j.dofs.iter().filter_map(dof) {
                moved[d] = true;
            }
            next = structure
                .segment(&j.parent)
                .and_then(|s| s.parent_joint.as_deref())
                .and_then(|id| structure.joint(id));
        }
        for u in driven.sus.iter().filter_map(su) {
            out[u] = Some(moved.clone());
        }
    }
    out
}

/// Fewest degrees of freedom of an SU's sample variance for the readings' uncertainties.
const MIN_NOISE_DOF: f64 = 30.0;

pub(super) fn assemble(
    mut passes: Passes<'_>,
    pattern: ExcitationPattern,
    pattern_source: String,
) -> Result<Ingested, IngestError> {
    if passes.sus.names.is_empty() {
        return Err(IngestError::Empty(
            "no skin samples (check the topic with --imu-topic and the frame ids)".into(),
        ));
    }
    let (stations, group_count) = stations(passes.segs, passes.config);
    let stations = training_orientations(&mut passes, stations);
    let sample_noise = sample_noise(&mut passes);
    let orientations = orientations(&mut passes, &stations, group_count);
    let poses = training_poses(&mut passes, &stations, &pattern)?;
    // Motion of several DoFs at once (a continuous program, ordinary work) gives no reading, but
    // its motion record calibrates given the tree of an earlier structure experiment.
    let moved = passes.reports.iter().any(|r| r.transfers > 0);
    if group_count > 0 && orientations.is_empty() && poses.is_empty() && !moved {
        return Err(IngestError::Empty(match passes.warnings.first() {
            Some(first) => format!(
                "every structure pose found in the joint states was skipped; the first reason: \
                 {first}"
            ),
            None => "the joint states hold still poses but no single-DoF move between two of \
                     them and no excitation: is the log long enough, and does it follow the \
                     protocol (see `skincal plan`)?"
                .into(),
        }));
    }
    let mut set = MeasurementSet::new(passes.dofs.to_vec(), passes.sus.names.clone());
    set.prismatic = prismatic_of(&passes);
    set.mimic = mimic_of(&passes);
    let dynamic = poses.iter().map(|p| p.dynamic.len()).sum();
    let (orientation_count, training_poses) = (orientations.len(), poses.len());
    if !orientations.is_empty() {
        set.structure = Some(StructureExperiment {
            orientations,
            extra: Map::new(),
        });
    }
    if !poses.is_empty() {
        set.training = Some(TrainingExperiment {
            from_motion: false,
            pattern,
            poses,
            extra: Map::new(),
        });
    }
    if set.structure.is_none() && set.training.is_none() && moved {
        passes.warnings.push(
            "no structure moves and no training poses, only motion of several DoFs at once: \
             the motion record (motion.json) calibrates it given the tree of an earlier structure \
             experiment (its structure.json in this directory)"
                .into(),
        );
    } else if set.structure.is_none() && set.training.is_none() {
        return Err(IngestError::Empty(
            "no structure moves and no training poses in the logs: do they follow the protocol \
             (still periods, one DoF moving at a time)? The thresholds are options."
                .into(),
        ));
    }
    let warnings = warnings(&mut passes);
    let report = IngestReport {
        orientations: orientation_count,
        training_poses,
        dynamic,
        sample_noise,
        logs: passes.reports,
        pattern,
        pattern_source,
        kinds: Vec::new(),
        warnings,
    };
    Ok(Ingested {
        measurements: set,
        report,
        moved_by: passes.moved_by,
    })
}

/// The stations with the training poses of logs whose base stood otherwise than in the logs with
/// most training poses numbered as base orientations 1, 2, … (each such log named and marked: the
/// fit gives each orientation a gravity of its own, and the motion record leaves their samples
/// out). Their structure stations stay (another orientation of the structure part). Beyond
/// [`MAX_ORIENTATIONS`], a log's training poses are left out, with a warning.
fn training_orientations(passes: &mut Passes<'_>, mut stations: Vec<Station>) -> Vec<Station> {
    let mut trained: Vec<usize> = stations
        .iter()
        .filter(|s| !s.excitations.is_empty())
        .map(|s| s.log)
        .collect();
    trained.dedup();
    if trained.len() < 2 {
        return stations;
    }
    let classes = {
        let shared: &Passes<'_> = passes;
        let stills: Vec<base::Still<'_>> = stations.iter().map(|s| (s.log, &s.pose[..])).collect();
        let same = |a: &[f64], b: &[f64]| differing(a, b, shared.dofs, shared.config).is_empty();
        let at = |k: usize| {
            let r = shared.still_reading(&stations[k]).ok()?;
            Some(r.into_iter().map(|(r, _)| r).collect())
        };
        let read = base::Readings {
            same_pose: &same,
            at: &at,
        };
        base::base_orientations(shared.reports.len(), &stills, &read)
    };
    let mut poses = BTreeMap::<usize, usize>::new();
    for st in stations.iter().filter(|s| !s.excitations.is_empty()) {
        if let Some(c) = classes[st.log] {
            *poses.entry(c).or_default() += 1;
        }
    }
    let Some(kept) = poses
        .iter()
        .max_by_key(|&(c, n)| (*n, std::cmp::Reverse(*c)))
        .map(|(c, _)| *c)
    else {
        return stations;
    };
    let first_kept = (0..classes.len()).find(|&l| classes[l] == Some(kept));
    let others: Vec<usize> = poses.keys().copied().filter(|&c| c != kept).collect();
    let orientation_of = |log: usize| {
        let c = classes[log]?;
        (c != kept).then(|| 1 + others.iter().position(|&o| o == c).unwrap_or(0))
    };
    for log in trained {
        let Some(o) = orientation_of(log) else {
            continue;
        };
        let count = stations
            .iter()
            .filter(|s| s.log == log && !s.excitations.is_empty())
            .count();
        let message = if o < MAX_ORIENTATIONS {
            format!(
                "{}: its {count} training poses stood in another base orientation than {} (at \
                 one joint pose held in both, the SUs' gravity readings turned by more than \
                 {:.0}°): kept as base orientation {o}, fitted with a gravity of their own; the \
                 fit on every sample leaves this log's samples out",
                passes.path(log),
                first_kept.map_or_else(|| "the other logs".into(), |l| passes.path(l)),
                base::OTHER_BASE.to_degrees()
            )
        } else {
            format!(
                "{}: its {count} training poses are left out: they stood in a base orientation \
                 beyond the {MAX_ORIENTATIONS} a set may have; ingest fewer orientations at once",
                passes.path(log)
            )
        };
        passes.warnings.push(message);
        passes.reports[log].other_base = true;
    }
    for s in stations.iter_mut().filter(|s| !s.excitations.is_empty()) {
        s.orientation = orientation_of(s.log).unwrap_or(0);
    }
    stations
        .into_iter()
        .filter(|s| s.excitations.is_empty() || s.orientation < MAX_ORIENTATIONS)
        .collect()
}

/// Each SU's sample variance from the spread of its still windows (in `passes`, where every SU
/// has enough samples to tell; at least [`super::motion::NOISE_FLOOR`] squared, so that a skin
/// without noise, a simulated one, still gives readings a deviation), and the noise of one
/// sample over all SUs, m/s².
fn sample_noise(passes: &mut Passes<'_>) -> Option<f64> {
    let scatter = scatter(passes.accumulated, passes.segs, passes.sus.names.len());
    let floor = super::motion::NOISE_FLOOR.powi(2);
    passes.variance = scatter
        .iter()
        .all(|&(_, dof)| dof >= MIN_NOISE_DOF)
        .then(|| {
            scatter
                .iter()
                .map(|&(ss, dof)| (ss / dof).max(floor))
                .collect()
        });
    let (ss, dof) = scatter
        .iter()
        .fold((0.0, 0.0), |a, &(s, d)| (a.0 + s, a.1 + d));
    (dof > 0.0).then(|| (ss / dof).sqrt())
}

/// The structure part's orientations, one per group of still stations without excitations;
/// where DoFs were excited together, which DoFs move each SU by the tree they give, or the
/// configuration's (in `passes`).
fn orientations(
    passes: &mut Passes<'_>,
    stations: &[Station],
    group_count: usize,
) -> Vec<Orientation> {
    let mut orientations = Vec::new();
    for g in 0..group_count {
        let members: Vec<&Station> = stations
            .iter()
            .filter(|s| s.group == Some(g) && s.excitations.is_empty())
            .collect();
        if members.len() >= 2 {
            orientations.extend(orientation(passes, &members));
        }
    }
    let together = stations.iter().any(|st| {
        st.excitations
            .iter()
            .any(|&x| passes.segs[st.log].excitations[x].dofs.len() > 1)
    });
    if together && (passes.config.tree.is_some() || !orientations.is_empty()) {
        passes.moved_by = Some(moved_by(passes, &orientations));
    }
    orientations
}

/// The training poses of the stations with excitations; an error when there were some and every
/// one was skipped, unless it was for a tree that the structure moves' accelerations may give.
fn training_poses(
    passes: &mut Passes<'_>,
    stations: &[Station],
    pattern: &ExcitationPattern,
) -> Result<Vec<TrainingPose>, IngestError> {
    let training: Vec<&Station> = stations
        .iter()
        .filter(|s| !s.excitations.is_empty())
        .collect();
    let poses: Vec<TrainingPose> = training
        .iter()
        .filter_map(|st| training_pose(passes, st, pattern))
        .collect();
    // Where the structure part's static readings leave SUs unplaced (a slide, or a DoF about a
    // vertical axis in one base orientation, turns no gravity), what its moves accelerated, from
    // the motion record, may place them: the set keeps its structure part for that, and
    // `motion::record_of` reads the logs again with the tree it gives.
    let unplaced = passes
        .moved_by
        .as_ref()
        .is_some_and(|m| m.iter().any(Option::is_none));
    if !training.is_empty() && poses.is_empty() && unplaced && passes.config.tree.is_none() {
        passes.warnings.push(format!(
            "none of the {} training poses was read: DoFs were excited together, and the \
             structure part's static readings do not tell which of them moves every SU (a slide, \
             or a DoF about a vertical axis, turns no gravity); what its moves accelerated does, \
             from the motion record, which `skincal ingest` makes and then reads the logs again",
            training.len()
        ));
    } else if !training.is_empty() && poses.is_empty() {
        return Err(IngestError::Empty(format!(
            "all {} training poses found in the joint states were skipped, so the result \
             would have none; the first reason: {}",
            training.len(),
            passes
                .warnings
                .iter()
                .find(|w| w.contains("training pose"))
                .or(passes.warnings.first())
                .map_or("unknown", String::as_str)
        )));
    }
    Ok(poses)
}

/// The warnings of the whole ingestion: those gathered in `passes`, then per log the unknown
/// frame ids and the saturated samples.
fn warnings(passes: &mut Passes<'_>) -> Vec<String> {
    let mut warnings = std::mem::take(&mut passes.warnings);
    // A mimic pair moves only together, always in one proportion: neither DoF has a move or an
    // excitation of its own in any log.
    let alone: std::collections::BTreeSet<&str> = passes
        .reports
        .iter()
        .flat_map(|r| &r.timeline)
        .filter(|s| s.kind == "move" || s.kind == "excitation")
        .filter_map(|s| s.dof.as_deref())
        .collect();
    for r in &passes.reports {
        let pairs = r.together.iter().filter(|t| {
            t.same
                && t.motions >= 2
                && !alone.contains(t.leader.as_str())
                && !alone.contains(t.follower.as_str())
        });
        for t in pairs {
            warnings.push(format!(
                "{}: DoFs `{}` and `{}` moved together, alone, in {} motion(s), `{}` {:.3} times \
                 `{}` throughout: read as transfers of several DoFs and skipped. If `{}` is a \
                 mimic joint of `{}` (a gripper's second finger), give `--robot` (the URDF) or \
                 `--plan`, which name mimic joints: ingest then reads these as structure moves of \
                 `{}`",
                r.path.display(),
                t.leader,
                t.follower,
                t.motions,
                t.follower,
                t.multiplier,
                t.leader,
                t.follower,
                t.leader,
                t.leader
            ));
        }
        if !r.unrecorded_joints.is_empty() {
            warnings.push(format!(
                "{}: no joint states for the robot's DoF(s) {:?}: not recorded (a log of one part \
                 of the robot); the measurement set covers the {} DoF(s) the logs have, the others \
                 held wherever they stood",
                r.path.display(),
                r.unrecorded_joints,
                passes.dofs.len()
            ));
        }
        if r.creeping > 0 {
            warnings.push(format!(
                "{}: {} of its poses were read where the DoFs still crept, never below {} rad/s \
                 for long enough: its servos settle slower than the program holds. A creep is no \
                 acceleration and the readings hold, but longer holds (`skincal plan --still S \
                 --settle S`) read those poses still",
                r.path.display(),
                r.creeping,
                passes.config.still_velocity
            ));
        }
        if !r.unknown_frames.is_empty() {
            warnings.push(format!(
                "{}: samples of unknown frame ids ignored: {:?}",
                r.path.display(),
                r.unknown_frames
            ));
        }
        if !r.repeated.is_empty() {
            let share: Vec<String> = r
                .repeated
                .iter()
                .map(|(su, x)| {
                    format!(
                        "{su} ({:.0} % repeated, fresh at about {:.0} Hz)",
                        100.0 * x.share,
                        x.fresh_rate
                    )
                })
                .collect();
            warnings.push(format!(
                "{}: SUs whose samples mostly repeat the one before exactly: {} — a board slower \
                 than its port, which repeats its last sample; its readings' deviations count the \
                 repeats as samples, and so are too small (by the square root of the share of \
                 fresh samples)",
                r.path.display(),
                share.join(", ")
            ));
        }
        if !r.saturated.is_empty() {
            warnings.push(format!(
                "{}: saturated samples (±{:.2} m/s²) not used: {:?}",
                r.path.display(),
                passes.config.saturation,
                r.saturated
            ));
        }
    }
    warnings
}

/// The logged DoFs that the configuration names mimic joints of logged leaders.
fn mimic_of(passes: &Passes<'_>) -> std::collections::BTreeMap<String, crate::model::MimicSpec> {
    passes
        .config
        .mimic
        .iter()
        .filter(|(f, m)| passes.dofs.contains(f) && passes.dofs.contains(&m.leader))
        .map(|(f, m)| (f.clone(), m.clone()))
        .collect()
}

/// The logged DoFs that the configuration names prismatic (none where it names no kinds: they
/// are told from the motion record, [`super::motion::record_of`]).
fn prismatic_of(passes: &Passes<'_>) -> Vec<String> {
    passes
        .dofs
        .iter()
        .filter(|d| {
            passes
                .config
                .prismatic
                .as_ref()
                .is_some_and(|p| p.contains(d))
        })
        .cloned()
        .collect()
}
