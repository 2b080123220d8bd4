//! Stations, structure groups and the measurement set.

use std::collections::BTreeMap;

use nalgebra::Vector5;
use serde_json::Map;

use super::segment::{Event, Segmentation};
use super::skin::{Accumulated, SuRegistry};
use super::timeline::Timeline;
use super::{IngestConfig, IngestError, IngestReport, Ingested, LogReport};
use crate::measurements::{
    MeasurementSet, Move, Orientation, Reading, StructureExperiment, TrainingExperiment,
    TrainingPose,
};
use crate::model::sensor::ExcitationPattern;

/// A station: still windows at one pose, joined by excitations.
pub(super) struct Station {
    pub(super) log: usize,
    pub(super) stills: Vec<usize>,
    pub(super) excitations: Vec<usize>,
    pub(super) pose: Vec<f64>,
    /// Index of the structure group (only for stations without excitations).
    pub(super) group: Option<usize>,
}

#[allow(clippy::too_many_arguments)]
pub(super) fn assemble(
    config: &IngestConfig,
    dofs: &[String],
    sus: &SuRegistry,
    timelines: &[Timeline],
    segs: &[Segmentation],
    accumulated: &[Accumulated],
    pattern: ExcitationPattern,
    pattern_source: String,
    reports: Vec<LogReport>,
) -> Result<Ingested, IngestError> {
    let nu = sus.names.len();
    let tolerance = config.motion_threshold;
    let mut warnings = Vec::new();
    if nu == 0 {
        return Err(IngestError::Empty(
            "no skin samples (check the topic with --imu-topic and the frame ids)".into(),
        ));
    }
    // Stations and structure groups.
    let mut stations: Vec<Station> = Vec::new();
    let mut group_count = 0usize;
    for (li, seg) in segs.iter().enumerate() {
        let mut current: Option<usize> = None;
        let mut group: Option<usize> = None;
        for event in &seg.events {
            match event {
                Event::Still(s) => {
                    let pose = &seg.stills[*s].pose;
                    let same = current.is_some_and(|c| {
                        stations[c]
                            .pose
                            .iter()
                            .zip(pose)
                            .all(|(a, b)| (a - b).abs() < tolerance)
                    });
                    if same {
                        stations[current.expect("checked")].stills.push(*s);
                    } else {
                        stations.push(Station {
                            log: li,
                            stills: vec![*s],
                            excitations: Vec::new(),
                            pose: pose.clone(),
                            group: None,
                        });
                        current = Some(stations.len() - 1);
                        if group.is_none() {
                            group = Some(group_count);
                            group_count += 1;
                        }
                        stations.last_mut().expect("pushed").group = group;
                    }
                }
                Event::Excitation(x) => {
                    if let Some(c) = current {
                        stations[c].excitations.push(*x);
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
    // Readings of a station, pooled over its still windows; None if an SU has no sample.
    let still_reading = |st: &Station| -> Result<Vec<Reading>, String> {
        let acc = &accumulated[st.log];
        (0..nu)
            .map(|su| {
                let mut n = 0u64;
                let mut sum = [0.0; 3];
                for &w in &st.stills {
                    if let Some(s) = acc.stills[w].get(su) {
                        n += s.n;
                        for (total, v) in sum.iter_mut().zip(&s.sum) {
                            *total += v;
                        }
                    }
                }
                if n == 0 {
                    Err(sus.names[su].clone())
                } else {
                    Ok(sum.map(|v| v / n as f64))
                }
            })
            .collect()
    };
    let at = |st: &Station| -> f64 {
        let w = &segs[st.log].stills[st.stills[0]];
        timelines[st.log].time(w.start)
    };

    // Training poses.
    let alpha = pattern.peak_acceleration();
    let mut poses = Vec::new();
    let mut dynamic_count = 0;
    for st in stations.iter().filter(|s| !s.excitations.is_empty()) {
        let static_readings = match still_reading(st) {
            Ok(r) => r,
            Err(su) => {
                warnings.push(format!(
                    "{}: training pose at {:.3} s skipped: SU `{su}` has no sample in its still \
                     windows",
                    reports[st.log].path.display(),
                    at(st)
                ));
                continue;
            }
        };
        let mut dynamic: BTreeMap<String, Vec<Reading>> = BTreeMap::new();
        let mut counts: BTreeMap<usize, usize> = BTreeMap::new();
        for &xi in &st.excitations {
            let x = &segs[st.log].excitations[xi];
            let fits = &accumulated[st.log].fits[xi];
            let mut readings = Vec::with_capacity(nu);
            let mut missing = None;
            for su in 0..nu {
                match fits.get(su).filter(|f| f.samples > 0) {
                    Some(f) => {
                        let mut k = [0.0; 3];
                        for (axis, kv) in k.iter_mut().enumerate() {
                            let rhs = Vector5::from_fn(|c, _| f.rhs[c][axis]);
                            *kv = (x.inverse * rhs)[3] * alpha;
                        }
                        readings.push(k);
                    }
                    None => {
                        missing = Some(su);
                        break;
                    }
                }
            }
            if let Some(su) = missing {
                warnings.push(format!(
                    "{}: excitation of `{}` at {:.3} s skipped: SU `{}` has no sample in it",
                    reports[st.log].path.display(),
                    dofs[x.dof],
                    timelines[st.log].time(x.start),
                    sus.names[su]
                ));
                continue;
            }
            let name = dofs[x.dof].clone();
            let count = counts.entry(x.dof).or_default();
            *count += 1;
            match dynamic.get_mut(&name) {
                // Repeated excitations of a DoF at one pose: running mean.
                Some(prev) => {
                    let c = *count as f64;
                    for (p, r) in prev.iter_mut().zip(&readings) {
                        for k in 0..3 {
                            p[k] += (r[k] - p[k]) / c;
                        }
                    }
                }
                None => {
                    dynamic.insert(name, readings);
                }
            }
        }
        if dynamic.is_empty() {
            continue;
        }
        let missing: Vec<&String> = dofs.iter().filter(|d| !dynamic.contains_key(*d)).collect();
        if !missing.is_empty() {
            warnings.push(format!(
                "{}: training pose at {:.3} s has no excitation of {missing:?}",
                reports[st.log].path.display(),
                at(st)
            ));
        }
        dynamic_count += dynamic.len();
        poses.push(TrainingPose {
            q: st.pose.clone(),
            static_readings,
            dynamic,
            extra: Map::new(),
        });
    }

    let found = stations
        .iter()
        .filter(|s| !s.excitations.is_empty())
        .count();
    if found > 0 && poses.is_empty() {
        return Err(IngestError::Empty(format!(
            "all {found} training poses found in the joint states were skipped, so the result \
             would have none; the first reason: {}",
            warnings.first().map_or("unknown", String::as_str)
        )));
    }

    // Structure groups.
    let mut orientations = Vec::new();
    for g in 0..group_count {
        let members: Vec<&Station> = stations
            .iter()
            .filter(|s| s.group == Some(g) && s.excitations.is_empty())
            .collect();
        if members.len() < 2 {
            continue;
        }
        let path = reports[members[0].log].path.display().to_string();
        let close = |a: &[f64], b: &[f64]| a.iter().zip(b).all(|(x, y)| (x - y).abs() < tolerance);
        // The rest pose: the one most stations share (the first of the most frequent).
        let (rest_index, _) = members
            .iter()
            .enumerate()
            .map(|(i, s)| {
                (
                    i,
                    members.iter().filter(|o| close(&o.pose, &s.pose)).count(),
                )
            })
            .fold(
                (0, 0),
                |best, (i, c)| if c > best.1 { (i, c) } else { best },
            );
        let rest_pose = members[rest_index].pose.clone();
        let mut rest_sum = vec![[0.0; 3]; nu];
        let mut rest_n = 0usize;
        let mut moves = Vec::new();
        for st in &members {
            let readings = match still_reading(st) {
                Ok(r) => r,
                Err(su) => {
                    warnings.push(format!(
                        "{path}: structure pose at {:.3} s skipped: SU `{su}` has no sample in it",
                        at(st)
                    ));
                    continue;
                }
            };
            let differs: Vec<usize> = (0..dofs.len())
                .filter(|&d| (st.pose[d] - rest_pose[d]).abs() >= tolerance)
                .collect();
            match differs.as_slice() {
                [] => {
                    rest_n += 1;
                    for (s, r) in rest_sum.iter_mut().zip(&readings) {
                        for k in 0..3 {
                            s[k] += r[k];
                        }
                    }
                }
                [d] => moves.push(Move {
                    dof: dofs[*d].clone(),
                    pose: st.pose.clone(),
                    readings,
                    extra: Map::new(),
                }),
                several => warnings.push(format!(
                    "{path}: structure pose at {:.3} s differs from the rest pose in {} DoFs; \
                     skipped",
                    at(st),
                    several.len()
                )),
            }
        }
        if rest_n == 0 || moves.is_empty() {
            continue;
        }
        let mut extra = Map::new();
        extra.insert(
            "source".into(),
            serde_json::Value::String(format!("{path} from {:.3} s", at(members[0]))),
        );
        orientations.push(Orientation {
            rest_pose,
            rest: rest_sum
                .iter()
                .map(|s| s.map(|v| v / rest_n as f64))
                .collect(),
            moves,
            extra,
        });
    }

    if group_count > 0 && orientations.is_empty() && poses.is_empty() {
        return Err(IngestError::Empty(format!(
            "every structure pose found in the joint states was skipped; the first reason: {}",
            warnings.first().map_or("unknown", String::as_str)
        )));
    }
    let mut set = MeasurementSet::new(dofs.to_vec(), sus.names.clone());
    if !orientations.is_empty() {
        set.structure = Some(StructureExperiment {
            orientations,
            extra: Map::new(),
        });
    }
    let training_poses = poses.len();
    if !poses.is_empty() {
        set.training = Some(TrainingExperiment {
            pattern,
            poses,
            extra: Map::new(),
        });
    }
    if set.structure.is_none() && set.training.is_none() {
        return Err(IngestError::Empty(
            "no structure moves and no training poses in the logs: do they follow the protocol \
             (still periods, one DoF moving at a time)? The thresholds are options."
                .into(),
        ));
    }
    // Sensor noise from the still windows.
    let (mut var, mut dof) = (0.0, 0.0);
    for acc in accumulated {
        for w in &acc.stills {
            for s in w.iter().filter(|s| s.n > 1) {
                for k in 0..3 {
                    let n = s.n as f64;
                    var += (s.squares[k] - s.sum[k] * s.sum[k] / n).max(0.0);
                    dof += n - 1.0;
                }
            }
        }
    }
    let sample_noise = (dof > 0.0).then(|| (var / dof).sqrt());
    for r in &reports {
        if !r.unknown_frames.is_empty() {
            warnings.push(format!(
                "{}: samples of unknown frame ids ignored: {:?}",
                r.path.display(),
                r.unknown_frames
            ));
        }
        if !r.saturated.is_empty() {
            warnings.push(format!(
                "{}: saturated samples (±{:.2} m/s²) not used: {:?}",
                r.path.display(),
                config.saturation,
                r.saturated
            ));
        }
    }
    let report = IngestReport {
        orientations: set.structure.as_ref().map_or(0, |s| s.orientations.len()),
        training_poses,
        dynamic: dynamic_count,
        logs: reports,
        pattern,
        pattern_source,
        sample_noise,
        warnings,
    };
    Ok(Ingested {
        measurements: set,
        report,
    })
}
