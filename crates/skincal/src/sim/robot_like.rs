//! Robot-like limbs: the axis patterns, joint limits and skin that real arms and legs have, which
//! random DH chains do not — parallel axes (hip–knee–ankle pitch), perpendicular axes that
//! intersect (spherical shoulders, hips and wrists: several DoFs with no link between), axes
//! with zero link offsets, a vertical or horizontal first axis, narrow and asymmetric limits that
//! need not contain 0, and 1–3 SUs per segment anywhere on the link, some close to an axis.

use std::f64::consts::{FRAC_PI_2, PI};

use nalgebra::{Isometry3, Translation3, UnitQuaternion, Vector3};
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use serde::{Deserialize, Serialize};

use super::SimulationError;
use crate::model::{DofKind, DofSpec, Limits, PlacementSpec, Robot, RobotBuilder, SuSpec};

/// Settings of [`robot_like_limb`].
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct RobotLikeConfig {
    /// Fewest DoFs of the limb.
    pub min_dofs: usize,
    /// Most DoFs of the limb.
    pub max_dofs: usize,
    /// Most SUs on one segment (at least one on every segment with skin).
    pub max_sus_per_segment: usize,
}

impl Default for RobotLikeConfig {
    fn default() -> Self {
        Self {
            min_dofs: 4,
            max_dofs: 9,
            max_sus_per_segment: 3,
        }
    }
}

/// How the next joint's first axis sits relative to the current one.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum Relation {
    /// Parallel, displaced across the axis by a link (pitch after pitch).
    Parallel,
    /// Perpendicular and intersecting it, displaced along it or not (roll after pitch).
    Intersecting,
    /// Perpendicular with a common normal of non-zero length.
    Offset,
    /// Along the link that leaves the current axis (a roll about the forearm).
    Along,
}

impl Relation {
    fn code(self) -> char {
        match self {
            Relation::Parallel => 'P',
            Relation::Intersecting => 'I',
            Relation::Offset => 'O',
            Relation::Along => 'A',
        }
    }
}

/// A robot-like serial limb of `min_dofs…max_dofs` revolute DoFs from the reference segment
/// `base`: joints of 1 DoF, or of 2 or 3 perpendicular DoFs whose axes intersect (no link, no
/// SU between them); consecutive joints related as real robots relate them (parallel, intersecting,
/// offset or along the link, with link lengths of 0.1–0.4 m or none); the first axis vertical or
/// horizontal; limits 0.6–3.5 rad wide, asymmetric, a quarter of them not containing 0 (the rest
/// pose is clipped into them); 1–`max_sus_per_segment` SUs on every segment including the base,
/// on the link's surface (2–8 cm from its centre line), one in five within 1.5 cm of the axis that
/// moves the segment, randomly turned.
///
/// The robot's name records its geometry: the first axis (`V`ertical or `H`orizontal), then per
/// joint its DoF count and the relation to the previous joint (`P`arallel, `I`ntersecting,
/// `O`ffset, `A`long the link), e.g. `like-V-1-P1-I3-A1-7`. Names: DoFs `dof1…`, segments
/// `base`, `link1…`, SUs `su1…`. Seeded.
pub fn robot_like_limb(config: &RobotLikeConfig, seed: u64) -> Result<Robot, SimulationError> {
    let bad = |setting, reason: String| Err(SimulationError::InvalidSetting { setting, reason });
    if config.min_dofs == 0 || config.min_dofs > config.max_dofs {
        return bad(
            "dofs",
            format!(
                "{}…{} DoFs: give at least one, fewest first",
                config.min_dofs, config.max_dofs
            ),
        );
    }
    if config.max_sus_per_segment == 0 {
        return bad("max_sus_per_segment", "must be at least 1".into());
    }
    let mut rng = ChaCha8Rng::seed_from_u64(seed);
    let dofs = rng.random_range(config.min_dofs..=config.max_dofs);
    let joints = joint_sizes(&mut rng, dofs);
    let vertical = rng.random_bool(0.5);
    let mut name = format!("like-{}", if vertical { 'V' } else { 'H' });
    let mut limb = Limb {
        builder: RobotBuilder::new(String::new(), "base"),
        parent: "base".to_string(),
        dofs: 0,
    };
    // Per segment (base first): the link from its frame to the next joint, for the SUs.
    let mut links: Vec<(String, Vector3<f64>)> = Vec::new();
    let mut origin = first_joint(&mut rng, vertical);
    for (j, &k) in joints.iter().enumerate() {
        if j > 0 {
            let relation = match rng.random_range(0..4) {
                0 => Relation::Parallel,
                1 => Relation::Intersecting,
                2 => Relation::Offset,
                _ => Relation::Along,
            };
            name.push('-');
            name.push(relation.code());
            origin = next_joint(&mut rng, relation);
        }
        name.push_str(&k.to_string());
        if j == 0 {
            links.push(("base".into(), origin.translation.vector));
        } else if let Some(last) = links.last_mut() {
            last.1 = origin.translation.vector;
        }
        limb.joint(&mut rng, j, k, origin);
        // Until the next joint is drawn, the link is an end effector's.
        let tip = Vector3::new(0.0, 0.0, rng.random_range(0.08..0.2));
        links.push((limb.parent.clone(), tip));
    }
    name.push_str(&format!("-{seed}"));
    let mut builder = limb.builder;
    builder.name = name;
    let mut s = 0;
    for (segment, link) in &links {
        for _ in 0..rng.random_range(1..=config.max_sus_per_segment) {
            s += 1;
            builder.sus.push(SuSpec {
                name: format!("su{s}"),
                segment: segment.clone(),
                placement: PlacementSpec::from_isometry(&on_link(&mut rng, link)),
            });
        }
    }
    builder
        .build()
        .map_err(|e| SimulationError::InvalidSetting {
            setting: "robot-like limb",
            reason: e.to_string(),
        })
}

/// The joints' DoF counts for `dofs` DoFs: 1 mostly, 2 or 3 where enough DoFs are left.
fn joint_sizes(rng: &mut ChaCha8Rng, dofs: usize) -> Vec<usize> {
    let mut joints: Vec<usize> = Vec::new();
    let mut left = dofs;
    while left > 0 {
        let k = match rng.random_range(0..10) {
            0..=1 if left >= 3 => 3,
            2..=3 if left >= 2 => 2,
            _ => 1,
        };
        joints.push(k);
        left -= k;
    }
    joints
}

/// The first DoF's frame in the base: its z is the first axis, vertical or horizontal.
fn first_joint(rng: &mut ChaCha8Rng, vertical: bool) -> Isometry3<f64> {
    Isometry3::from_parts(
        Translation3::new(0.0, 0.0, rng.random_range(0.05..0.2)),
        if vertical {
            UnitQuaternion::from_axis_angle(&Vector3::z_axis(), rng.random_range(-PI..PI))
        } else {
            UnitQuaternion::from_axis_angle(&Vector3::y_axis(), FRAC_PI_2)
                * UnitQuaternion::from_axis_angle(&Vector3::z_axis(), rng.random_range(-PI..PI))
        },
    )
}

/// A limb as it is built: its DoFs so far and the segment the next joint hangs on.
struct Limb {
    builder: RobotBuilder,
    parent: String,
    dofs: usize,
}

impl Limb {
    /// Joint `j` of `k` DoFs at `origin` on the current segment: perpendicular, intersecting
    /// DoFs with no link between.
    fn joint(&mut self, rng: &mut ChaCha8Rng, j: usize, k: usize, origin: Isometry3<f64>) {
        for i in 0..k {
            self.dofs += 1;
            let child = if i + 1 == k {
                format!("link{}", j + 1)
            } else {
                format!("link{}_{}", j + 1, i + 1)
            };
            let placement = if i == 0 {
                origin
            } else {
                Isometry3::from_parts(
                    Translation3::identity(),
                    UnitQuaternion::from_axis_angle(&Vector3::x_axis(), FRAC_PI_2)
                        * UnitQuaternion::from_axis_angle(
                            &Vector3::z_axis(),
                            rng.random_range(-PI..PI),
                        ),
                )
            };
            self.builder.dofs.push(DofSpec {
                name: format!("dof{}", self.dofs),
                parent: self.parent.clone(),
                child: child.clone(),
                origin: PlacementSpec::from_isometry(&placement),
                axis: Vector3::z(),
                kind: DofKind::Revolute,
                limits: limits(rng),
                mimic: None,
            });
            self.parent = child;
        }
    }
}

/// The next joint's frame (z: its first axis) in the current DoF's frame (z: its axis).
fn next_joint(rng: &mut ChaCha8Rng, relation: Relation) -> Isometry3<f64> {
    let spin = UnitQuaternion::from_axis_angle(&Vector3::z_axis(), rng.random_range(-PI..PI));
    let length = rng.random_range(0.1..0.4);
    // A direction across the current axis.
    let across = spin * Vector3::x();
    let tilt = UnitQuaternion::from_axis_angle(
        &nalgebra::Unit::new_normalize(spin * Vector3::y()),
        FRAC_PI_2,
    );
    let along_axis = if rng.random_bool(0.5) {
        0.0
    } else {
        rng.random_range(-0.1..0.1)
    };
    match relation {
        Relation::Parallel => Isometry3::from_parts(
            (across * length + Vector3::z() * along_axis).into(),
            UnitQuaternion::from_axis_angle(&Vector3::z_axis(), rng.random_range(-PI..PI)),
        ),
        Relation::Intersecting => Isometry3::from_parts(
            (Vector3::z() * (length * rng.random_range(0.0..1.0f64).round())).into(),
            spin * UnitQuaternion::from_axis_angle(&Vector3::x_axis(), FRAC_PI_2),
        ),
        Relation::Offset => Isometry3::from_parts(
            (across * length + Vector3::z() * along_axis).into(),
            spin * UnitQuaternion::from_axis_angle(&Vector3::x_axis(), FRAC_PI_2),
        ),
        // The new axis points along the link that leaves across the current one.
        Relation::Along => Isometry3::from_parts((across * length).into(), tilt),
    }
}

/// Limits 0.6–3.5 rad wide, asymmetric; a quarter of them exclude 0 (a knee, an elbow).
fn limits(rng: &mut ChaCha8Rng) -> Limits {
    let width: f64 = rng.random_range(0.6..3.5);
    let (lower, upper) = if rng.random_bool(0.25) {
        let lower: f64 = rng.random_range(0.1..0.4) * if rng.random_bool(0.5) { 1.0 } else { -1.0 };
        if lower > 0.0 {
            (lower, (lower + width).min(2.9))
        } else {
            ((lower - width).max(-2.9), lower)
        }
    } else {
        let below: f64 = width * rng.random_range(0.2..0.8);
        ((-below).max(-2.9), (width - below).min(2.9))
    };
    Limits {
        lower,
        upper,
        velocity: Some(2.0),
        acceleration: Some(10.0),
    }
}

/// An SU on the surface of a link from the segment frame's origin to `link`: somewhere along it,
/// 2–8 cm from its centre line; one in five instead within 1.5 cm of the segment frame's z axis
/// (the DoF's). Randomly turned.
fn on_link(rng: &mut ChaCha8Rng, link: &Vector3<f64>) -> Isometry3<f64> {
    let unit = |rng: &mut ChaCha8Rng| -> Vector3<f64> {
        loop {
            let v = Vector3::from_fn(|_, _| rng.random_range(-1.0..1.0));
            let n = v.norm();
            if n > 0.1 && n <= 1.0 {
                break v / n;
            }
        }
    };
    let position = if rng.random_bool(0.2) {
        Vector3::new(
            rng.random_range(-0.015..0.015),
            rng.random_range(-0.015..0.015),
            rng.random_range(-0.1..0.1),
        )
    } else {
        let direction: Vector3<f64> = link.try_normalize(1e-9).unwrap_or_else(Vector3::z);
        let across = direction.cross(&unit(rng)).normalize();
        link * rng.random_range(0.1..0.9) + across * rng.random_range(0.02..0.08)
    };
    let turn = UnitQuaternion::from_scaled_axis(unit(rng) * rng.random_range(0.0..PI));
    Isometry3::from_parts(position.into(), turn)
}

/// A snake of `dofs` revolute DoFs in a row (seed `seed`): each link 8–12 cm long, its axis a
/// quarter turn from the one before (alternately ±90° about the common normal), one SU per
/// segment a few centimetres off its link, turned at random. The longest serial chains a skin
/// covers: what the cost of one chain grows with.
pub fn snake(dofs: usize, seed: u64) -> Result<Robot, SimulationError> {
    let mut rng = ChaCha8Rng::seed_from_u64(seed);
    super::serial_dh_chain(
        format!("snake-{dofs}-{seed}"),
        dofs,
        &mut rng,
        |rng, k| {
            let twist = if k % 2 == 0 { -FRAC_PI_2 } else { FRAC_PI_2 };
            PlacementSpec::dh(
                rng.random_range(-0.3..0.3),
                rng.random_range(-0.02..0.02),
                rng.random_range(0.08..0.12),
                twist,
            )
        },
        |rng| {
            PlacementSpec::dh_sensor(
                rng.random_range(-0.5..0.5),
                rng.random_range(-0.03..0.03),
                rng.random_range(0.03..0.06),
                rng.random_range(-1.5..1.5),
                rng.random_range(-0.5..0.5),
                rng.random_range(-0.02..0.02),
            )
        },
    )
}
