//! A new model with only what changed calibrated again: each moved SU and each changed bias or
//! sensitivity fitted anew from the same log, swapped SUs given back their places, everything
//! else kept; a record of what changed and from which log.

use nalgebra::Vector3;

use super::refit::Cache;
use super::test::Tally;
use super::{CheckConfig, CheckError, CheckReport, Columns, Skin, SuPlace, Verdict};
use crate::estimate::body::{BodyModel, FoundChange, Frame, ModelChange, SuModelChange};
use crate::estimate::ml::SuIntrinsics;
use crate::motion::MotionRecord;

/// Why a recalibration could not be made.
#[derive(Debug, thiserror::Error)]
pub enum RecalibrateError {
    /// The model or the record.
    #[error(transparent)]
    Check(#[from] CheckError),
    /// Two swapped SUs' names are also names of other things in the model.
    #[error("SU `{0}` shares its name with a DoF or segment: rename it before swapping")]
    AmbiguousName(String),
}

/// `model` with the changes of `report` (a check of it against `record`) calibrated again: moved
/// SUs and changed biases and sensitivities refitted from the check's estimate on the record's
/// blocks, swapped SUs given each other's names. SUs on another segment, reading as another or
/// broken are left as they are (they need the structure experiment or a repair): the report says
/// so.
pub fn recalibrate(
    model: &BodyModel,
    record: &MotionRecord,
    report: &CheckReport,
    config: &CheckConfig,
) -> Result<(BodyModel, Vec<ModelChange>), RecalibrateError> {
    let mut out = model.clone();
    let logs = logs_of(record);
    let mut changes = Vec::new();
    if let Some(zero) = &report.zero {
        set_zero(&mut out, &zero.dof, zero.offset);
        changes.push(ModelChange::Zero {
            dof: zero.dof.clone(),
            offset: zero.offset,
            logs: logs.clone(),
        });
    }
    // The SUs are fitted anew on the model with the DoF's new zero.
    let skin = Skin::new(&out, config)?;
    let columns = Columns::new(&skin, &record.dofs, &record.sus)?;
    let refitted: Vec<usize> = (0..report.sus.len())
        .filter(|&u| {
            matches!(
                report.sus[u].verdict,
                Verdict::Moved | Verdict::BiasChanged | Verdict::ScaleChanged
            )
        })
        .collect();
    if !refitted.is_empty() {
        let cache = Cache::new(&skin, &columns, record);
        for &u in &refitted {
            let check = &report.sus[u];
            let old = skin.places[u];
            let start = start_of(&old, check);
            // A sensitivity is fitted anew where the check found it changed; elsewhere the
            // calibration's is kept.
            let drifted = check.verdict == Verdict::ScaleChanged;
            let (new, ratio) = cache.fit(&skin, u, start, check.noise_sd, config.huber, drifted);
            let tally = cache.tally(&skin, u, &new, check.noise_sd, config.huber);
            set_place(&mut out, &check.su, &new, &tally);
            changes.push(ModelChange::Su(Box::new(SuModelChange {
                su: check.su.clone(),
                verdict: match check.verdict {
                    Verdict::Moved => FoundChange::Moved,
                    Verdict::ScaleChanged => FoundChange::ScaleChanged,
                    _ => FoundChange::BiasChanged,
                },
                logs: logs.clone(),
                before: Frame::from_isometry(&old.placement),
                after: Frame::from_isometry(&new.placement),
                bias_before: old.intrinsics.bias,
                bias_after: new.intrinsics.bias,
                scale_before: old.intrinsics.scale,
                scale_after: new.intrinsics.scale,
                residual_ratio: ratio,
            })));
        }
    }
    for (u, check) in report.sus.iter().enumerate() {
        let Verdict::Swapped { with } = &check.verdict else {
            continue;
        };
        // Each pair once: the first of the two in the model's order renames both.
        let Some(v) = report.sus.iter().position(|s| &s.su == with) else {
            continue;
        };
        if v < u {
            continue;
        }
        swap_names(&mut out, &check.su, with)?;
        for (a, b) in [(u, v), (v, u)] {
            let name = &report.sus[a].su;
            changes.push(ModelChange::Su(Box::new(SuModelChange {
                su: name.clone(),
                verdict: FoundChange::Swapped {
                    with: report.sus[b].su.clone(),
                },
                logs: logs.clone(),
                before: Frame::from_isometry(&skin.places[a].placement),
                after: Frame::from_isometry(&skin.places[b].placement),
                bias_before: skin.places[a].intrinsics.bias,
                bias_after: skin.places[b].intrinsics.bias,
                scale_before: skin.places[a].intrinsics.scale,
                scale_after: skin.places[b].intrinsics.scale,
                residual_ratio: report.sus[a].residual_ratio,
            })));
        }
    }
    out.changes.extend(changes.iter().cloned());
    Ok((out, changes))
}

fn logs_of(record: &MotionRecord) -> Vec<String> {
    let mut logs: Vec<String> = record.runs.iter().map(|r| r.log.clone()).collect();
    logs.dedup();
    logs
}

/// Where a refit starts: the place the check found anew, else the model's moved by the check's
/// estimate (its sensitivity changed only where the check said so).
fn start_of(old: &SuPlace, check: &super::SuCheck) -> SuPlace {
    if let Some(refit) = &check.refit {
        let mut place = *old;
        place.placement = Frame {
            xyz: refit.xyz,
            rpy: refit.rpy,
        }
        .to_isometry();
        place.intrinsics.bias = refit.bias;
        return place;
    }
    let Some(change) = &check.change else {
        return *old;
    };
    let delta: Vec<f64> = change
        .shift
        .iter()
        .chain(&change.turn)
        .chain(&change.bias)
        .copied()
        .chain(change.scale.map(|s| {
            if check.verdict == Verdict::ScaleChanged {
                s
            } else {
                0.0
            }
        }))
        .collect();
    super::kin::changed(old, &delta)
}

/// Writes SU `su`'s new place, bias and sensitivity into the model (the body's robot, its limb's
/// robot, its intrinsics and its deviations from the refit's information).
fn set_place(model: &mut BodyModel, su: &str, place: &SuPlace, tally: &Tally) {
    let frame = Frame::from_isometry(&place.placement);
    let robots = std::iter::once(&mut model.robot)
        .chain(model.limbs.iter_mut().map(|l| &mut l.estimate.robot));
    for robot in robots {
        for entry in robot.sus.iter_mut().filter(|e| e.name == su) {
            entry.xyz = Some(frame.xyz);
            entry.rpy = Some(frame.rpy);
            entry.dh = None;
        }
    }
    let covariance = tally.information.try_inverse();
    for limb in model
        .limbs
        .iter_mut()
        .filter(|l| l.sus.iter().any(|s| s == su))
    {
        let estimate = &mut limb.estimate;
        match estimate.intrinsics.iter_mut().find(|i| i.su == su) {
            Some(i) => {
                i.value.bias = place.intrinsics.bias;
                i.value.scale = place.intrinsics.scale;
            }
            None if Vector3::from(place.intrinsics.bias).norm() > 0.0
                || Vector3::from(place.intrinsics.scale).norm() > 0.0 =>
            {
                estimate.intrinsics.push(SuIntrinsics {
                    su: su.to_string(),
                    value: place.intrinsics,
                    sd: Default::default(),
                    held: Vec::new(),
                });
            }
            None => {}
        }
        if let (Some(c), Some(u)) = (
            covariance,
            estimate.uncertainty.iter_mut().find(|u| u.su == su),
        ) {
            u.position_sd = (c[(0, 0)] + c[(1, 1)] + c[(2, 2)]).max(0.0).sqrt();
            u.orientation_sd = (c[(3, 3)] + c[(4, 4)] + c[(5, 5)]).max(0.0).sqrt();
        }
    }
}

/// Exchanges the names `a` and `b` everywhere in the model (every string that is exactly one of
/// them): the two boards read each other's places.
fn swap_names(model: &mut BodyModel, a: &str, b: &str) -> Result<(), RecalibrateError> {
    let other_names: Vec<String> = model
        .robot
        .dofs
        .iter()
        .flat_map(|d| [d.name.clone(), d.child.clone()])
        .chain(model.robot.reference.clone())
        .collect();
    for name in [a, b] {
        if other_names.iter().any(|n| n == name) {
            return Err(RecalibrateError::AmbiguousName(name.to_string()));
        }
    }
    let mut value = serde_json::to_value(&*model).expect("a model serialises");
    rename(&mut value, a, b);
    *model = serde_json::from_value(value).expect("renaming keeps the model's shape");
    Ok(())
}

fn rename(value: &mut serde_json::Value, a: &str, b: &str) {
    match value {
        serde_json::Value::String(s) if s == a => *s = b.to_string(),
        serde_json::Value::String(s) if s == b => *s = a.to_string(),
        serde_json::Value::Array(items) => items.iter_mut().for_each(|v| rename(v, a, b)),
        serde_json::Value::Object(map) => map.values_mut().for_each(|v| rename(v, a, b)),
        _ => {}
    }
}

/// DoF `dof`'s zero moved by `offset`: its origin turned about its axis by that much, in the
/// body's robot and in its limb's (a DH row becomes an origin).
fn set_zero(model: &mut BodyModel, dof: &str, offset: f64) {
    let robots = std::iter::once(&mut model.robot)
        .chain(model.limbs.iter_mut().map(|l| &mut l.estimate.robot));
    for robot in robots {
        for entry in robot.dofs.iter_mut().filter(|e| e.name == dof) {
            let origin = match (&entry.origin, &entry.dh) {
                (Some(o), _) => Frame {
                    xyz: o.xyz,
                    rpy: o.rpy,
                }
                .to_isometry(),
                (None, Some(dh)) => {
                    crate::model::PlacementSpec::dh(dh.theta0, dh.d, dh.a, dh.alpha)
                        .kind
                        .transform(&[dh.theta0, dh.d, dh.a, dh.alpha])
                }
                (None, None) => nalgebra::Isometry3::identity(),
            };
            let axis =
                nalgebra::Unit::new_normalize(Vector3::from(entry.axis.unwrap_or([0.0, 0.0, 1.0])));
            let turned = origin * nalgebra::UnitQuaternion::from_axis_angle(&axis, offset);
            let frame = Frame::from_isometry(&turned);
            entry.origin = Some(crate::model::description::OriginEntry {
                xyz: frame.xyz,
                rpy: frame.rpy,
            });
            entry.dh = None;
            if entry.axis.is_none() {
                entry.axis = Some([0.0, 0.0, 1.0]);
            }
        }
    }
}
