//! The calibrated body on the robot's own URDF: each calibrated joint axis line aligned with the
//! URDF's, a kinematic check of the URDF's joints, and the SU frames placed on the URDF's links.
//!
//! **Matching.** A calibrated DoF is the URDF joint of the same name (the measurement set names
//! DoFs after the robot's joints); the segment it moves is that joint's child link. The two trees
//! must agree: a DoF's parent DoF in the calibration is the nearest moving joint above it in the
//! URDF.
//!
//! **Alignment, joint by joint.** Accelerometers tell the axis *lines*, not the frames a URDF
//! hangs on them: a link frame's turn about its joint's axis and its shift along it are the URDF's
//! choice. So the URDF is carried onto the calibration from the root of each limb outwards: `A_d`
//! takes the URDF's coordinates to the calibration's as seen from the link that DoF `d` moves.
//! - A limb's first DoF: where a limb on the static reference segment sits, and how it is turned,
//!   no reading tells; a limb on another limb's segment was fitted with that limb's path and
//!   gravity held, so where it sits carries that limb's gravity uncertainty, which the model does
//!   not keep. `A` takes the URDF's axis line onto the calibrated one, and its turn about and shift
//!   along that line are chosen so that the nearest later axis that tells them robustly agrees
//!   (the common normal's direction and foot, as in a DH table; a parallel axis tells only the
//!   turn, by its offset). This joint is not checked; the next one only in the components that the
//!   choice leaves (the distance and angle between the two axes).
//! - Every other DoF `d` on parent `p`: the URDF's axis line, carried by `A_p`, is moved onto the
//!   calibrated one by the smallest motion — a turn about a line through the URDF joint's origin
//!   perpendicular to the axis (`tilt`), then a shift perpendicular to the axis (`shift`), both
//!   in the URDF joint's frame — and `A_d` is `A_p` with that motion. These 4 components are the
//!   check: an error of the URDF joint's origin that tilts or shifts its axis shows at that joint
//!   alone. A turn of a link frame about its own axis or a shift along it (a zero offset of the
//!   joint's angle, a link length along the axis) moves only what follows: it shows at the next
//!   joint, or, after a limb's last joint, nowhere.
//!
//! **Uncertainty.** The check's components are functions of the calibrated joint lines; their
//! covariance comes from each limb's joint-line covariance ([`JointCovariance`]) through the
//! Jacobian of the whole alignment (central differences; limbs are independent fits). A joint
//! disagrees when its components lie outside the 3σ region (χ² with as many degrees of freedom
//! as components, at the two-sided 3σ probability 0.27 %).

use std::collections::{BTreeSet, HashMap};

use nalgebra::{DMatrix, Isometry3, Translation3, UnitQuaternion, Vector3, Vector4};
use serde::{Deserialize, Serialize};

use crate::estimate::body::BodyModel;
use crate::estimate::ml::JointCovariance;
use crate::model::description::DescriptionError;
use crate::model::urdf::UrdfTree;
use crate::model::{forward_kinematics, DofIndex, DofKind, Robot};

/// Errors of the alignment, the check and the merge.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
#[non_exhaustive]
pub enum AlignError {
    /// The URDF does not read or is not one tree.
    #[error("the URDF: {0}")]
    Urdf(#[from] DescriptionError),
    /// The model file is not a usable model.
    #[error("the model is not usable: {0}")]
    Model(String),
    /// No calibrated DoF is a moving joint of the URDF.
    #[error(
        "no calibrated DoF is a revolute or continuous joint of the URDF (the model has {}; the URDF's are {}): the DoFs must be named after the URDF's joints",
        model.join(", "),
        if urdf.is_empty() { "none".to_string() } else { urdf.join(", ") }
    )]
    NothingInCommon {
        /// The model's DoFs.
        model: Vec<String>,
        /// The URDF's revolute and continuous joints.
        urdf: Vec<String>,
    },
    /// An SU's link or joint name is taken in the URDF.
    #[error(
        "`{0}` is already a link or joint of the URDF: give the SU frames a prefix (`--prefix`)"
    )]
    NameTaken(String),
    /// The text has no `</robot>` to insert before.
    #[error("the URDF text has no closing `</robot>` tag to add the SU frames before")]
    NoRobotEnd,
    /// The merged text does not read back as the URDF plus the SU frames.
    #[error("the URDF with the SU frames added does not read back: {0}")]
    Merged(String),
}

/// The 3σ limit of χ² (two-sided normal probability 0.27 %) for 1–4 degrees of freedom.
const CHI2_3SIGMA: [f64; 4] = [9.0, 11.829, 14.156, 16.251];

/// A URDF axis nearer than this to parallel to the previous one (sine of the angle) tells only
/// the turn about the previous axis, not the foot of the common normal along it.
const PARALLEL: f64 = 0.05;
/// A parallel axis nearer than this to the previous one (m) tells nothing about the turn either.
const COINCIDENT: f64 = 1e-3;
/// An axis this far from parallel (sine of the angle) tells a limb base's turn and shift robustly.
const ROBUST: f64 = 0.3;
/// A parallel axis this far away (m) tells a limb base's turn robustly.
const LEVER: f64 = 0.05;
/// Step of the central differences for the Jacobian (rad and m).
const STEP: f64 = 1e-6;

/// How a joint compares.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum JointVerdict {
    /// Within the calibration's 3σ region.
    Agrees,
    /// Outside it: the URDF's joint is not where the robot's is.
    Disagrees,
    /// A limb's first DoF: the alignment of the limb is taken from it.
    LimbBase,
    /// Not compared (see the reason).
    NotCompared,
}

/// One joint of the URDF against the calibration.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct JointCheck {
    /// The DoF (= the URDF joint).
    pub dof: String,
    /// The verdict.
    pub verdict: JointVerdict,
    /// What it was checked against or why it was not, in plain words.
    pub note: String,
    /// The angle between the URDF's axis (aligned) and the calibrated one, rad.
    pub angle: f64,
    /// Its standard deviation, rad.
    pub angle_sd: f64,
    /// The distance between the axis lines in the plane through the URDF joint's origin
    /// perpendicular to its axis, m.
    pub distance: f64,
    /// Its standard deviation, m.
    pub distance_sd: f64,
    /// The turn that takes the URDF's axis onto the calibrated one, about a line through the joint
    /// origin: a rotation vector in the URDF joint's frame, rad.
    pub tilt: [f64; 3],
    /// The shift that follows it, in the URDF joint's frame, m.
    pub shift: [f64; 3],
    /// Independent components compared (4; fewer where the limb's alignment used some).
    pub components: usize,
    /// The squared Mahalanobis distance of the components from agreement.
    pub chi2: f64,
}

/// The check of a URDF's joints against a calibration: `skincal check-urdf`.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct UrdfCheck {
    /// The URDF's robot name.
    pub robot: String,
    /// Every calibrated DoF, in the model's order.
    pub joints: Vec<JointCheck>,
    /// The joints that disagree.
    pub disagree: Vec<String>,
}

/// An SU frame placed on a link of the URDF.
#[derive(Debug, Clone, PartialEq)]
pub struct SuOnLink {
    /// The SU.
    pub su: String,
    /// The URDF link.
    pub link: String,
    /// `T_link←SU`.
    pub pose: Isometry3<f64>,
}

/// The calibrated body aligned with a URDF.
#[derive(Debug, Clone)]
pub struct Alignment {
    /// The URDF.
    pub tree: UrdfTree,
    /// The check of every calibrated DoF.
    pub check: UrdfCheck,
    /// The SU frames on the URDF's links.
    pub sus: Vec<SuOnLink>,
    /// SUs that could not be placed, and why.
    pub unplaced: Vec<(String, String)>,
    /// SUs placed with directions of their pose that no reading determines, and which: placed
    /// where the calibration's gauge left them in those directions, not measured.
    pub partial: Vec<(String, String)>,
}

impl Alignment {
    /// Every placed SU's frame at the zero pose, in the URDF's root frame.
    pub fn su_frames(&self) -> std::collections::BTreeMap<String, Isometry3<f64>> {
        self.sus
            .iter()
            .filter_map(|s| Some((s.su.clone(), self.tree.frames.get(&s.link)? * s.pose)))
            .collect()
    }
}

/// What the alignment needs of the URDF, per calibrated DoF.
struct Plan {
    /// Per DoF: the URDF joint's frame with z on its axis, in the URDF root's frame (none: not
    /// compared, with the reason).
    urdf: Vec<Result<Matched, String>>,
    /// Per DoF: its parent DoF in the calibration.
    parent: Vec<Option<DofIndex>>,
    /// Per DoF: the first DoF of a limb that hangs on another limb's segment.
    hangs: Vec<bool>,
    /// Per DoF: it sits on the segment a prismatic DoF moves, whose line (unlike its direction)
    /// no reading places: the alignment starts afresh there.
    after_slide: Vec<bool>,
    /// Per DoF: prismatic. A slide turns nothing, so the segment it moves keeps its parent's
    /// alignment (its line is not measured, its direction is checked), even as a limb's first DoF.
    slides: Vec<bool>,
    /// Per DoF: the DoFs after it, nearest first (for a limb base's turn and shift).
    descendants: Vec<Vec<DofIndex>>,
}

impl Plan {
    /// Whether the alignment starts afresh at `d`: a limb's first DoF.
    fn is_base(&self, d: DofIndex) -> bool {
        self.parent[d].is_none() || self.hangs[d] || self.after_slide[d]
    }
}

/// A calibrated DoF's URDF joint.
struct Matched {
    /// Its index in the tree's joints.
    joint: usize,
    /// Its frame with z on its axis, in the URDF root's frame.
    frame: Isometry3<f64>,
}

/// The result of one run of the alignment.
struct Run {
    /// Per DoF: `A_d` (URDF root coordinates → the body's), where the DoF was aligned.
    a: Vec<Option<Isometry3<f64>>>,
    /// Per DoF: the check's components (tilt x, y; shift x, y in the URDF joint's z-axis frame).
    r: Vec<Option<Vector4<f64>>>,
}

/// A frame with z along `axis` (in `frame`'s coordinates), sharing its origin.
fn z_on(frame: &Isometry3<f64>, axis: &Vector3<f64>) -> Isometry3<f64> {
    let turn = UnitQuaternion::rotation_between(&Vector3::z(), axis).unwrap_or_else(|| {
        UnitQuaternion::from_axis_angle(&Vector3::x_axis(), std::f64::consts::PI)
    });
    frame * Isometry3::from_parts(Translation3::identity(), turn)
}

/// The common normal of the z axis and the line through `p` along `d`: the azimuth of its
/// direction and its foot on the z axis. For a line taken as `parallel`, the azimuth of its offset
/// (none when the lines coincide) and no foot.
fn normal_of(p: &Vector3<f64>, d: &Vector3<f64>, parallel: bool) -> (Option<f64>, Option<f64>) {
    if parallel {
        let offset = p - d * p.dot(d);
        (
            (offset.xy().norm() > COINCIDENT).then(|| offset.y.atan2(offset.x)),
            None,
        )
    } else {
        let n = Vector3::z().cross(d);
        let b = d.z;
        let foot = (p.z - b * p.dot(d)) / (1.0 - b * b).max(1e-300);
        (Some(n.y.atan2(n.x)), Some(foot))
    }
}

fn run(plan: &Plan, cal: &[Isometry3<f64>]) -> Run {
    let n = cal.len();
    let mut a: Vec<Option<Isometry3<f64>>> = vec![None; n];
    let mut r: Vec<Option<Vector4<f64>>> = vec![None; n];
    for d in 0..n {
        let Ok(Matched { frame: u, .. }) = &plan.urdf[d] else {
            continue;
        };
        match plan.parent[d].filter(|_| !plan.is_base(d) || plan.slides[d]) {
            None => a[d] = Some(limb_base(plan, cal, d, u)),
            Some(p) => {
                let Some(ap) = a[p] else { continue };
                let (ad, rd) = carried(&ap, u, &cal[d]);
                // A slide's segment keeps the parent's alignment: no shift onto a line that
                // no reading placed.
                a[d] = Some(if plan.slides[d] { ap } else { ad });
                r[d] = Some(rd);
            }
        }
    }
    Run { a, r }
}

/// `A` of a limb's first DoF `d` (URDF frame `u`): the URDF's axis on the calibrated one, turned
/// about it and shifted along it so that the next axes agree.
fn limb_base(
    plan: &Plan,
    cal: &[Isometry3<f64>],
    d: DofIndex,
    u: &Isometry3<f64>,
) -> Isometry3<f64> {
    // The nearest later axis that tells each robustly (the URDF's geometry decides the case, the
    // calibration follows it): the turn from a common normal's direction (an axis at least
    // ROBUST from parallel) or a parallel axis's offset (at least LEVER away); the shift from a
    // common normal's foot. Failing that, the best there is.
    // (how robustly, value)
    let mut turn: Option<(f64, f64)> = None;
    let mut foot: Option<(f64, f64)> = None;
    for &c in &plan.descendants[d] {
        let Ok(Matched { frame: uc, .. }) = &plan.urdf[c] else {
            continue;
        };
        let on_u = u.inverse() * uc;
        let on_c = cal[d].inverse() * cal[c];
        let (du, dc) = (on_u * Vector3::z(), on_c * Vector3::z());
        let (pu, pc) = (on_u.translation.vector, on_c.translation.vector);
        let sine = Vector3::z().cross(&du).norm();
        let parallel = sine <= PARALLEL;
        let (azimuth_u, foot_u) = normal_of(&pu, &du, parallel);
        let (azimuth_c, foot_c) = normal_of(&pc, &dc, parallel);
        let lever = if parallel {
            (pu - du * pu.dot(&du)).norm() / LEVER
        } else {
            sine / ROBUST
        };
        if let (Some(u), Some(c)) = (azimuth_u, azimuth_c) {
            if turn.is_none_or(|(best, _)| best < 1.0 && lever > best) {
                turn = Some((lever, c - u));
            }
        }
        if let (Some(u), Some(c)) = (foot_u, foot_c) {
            if foot.is_none_or(|(best, _)| best < 1.0 && lever > best) {
                foot = Some((lever, c - u));
            }
        }
        if turn.is_some_and(|(l, _)| l >= 1.0) && foot.is_some_and(|(l, _)| l >= 1.0) {
            break;
        }
    }
    let (turn, foot) = (turn.map(|(_, t)| t), foot.map(|(_, f)| f));
    let z = Isometry3::from_parts(
        Translation3::new(0.0, 0.0, foot.unwrap_or(0.0)),
        UnitQuaternion::from_axis_angle(&Vector3::z_axis(), turn.unwrap_or(0.0)),
    );
    cal[d] * z * u.inverse()
}

/// `A` of a DoF with URDF frame `u` from its parent's `ap`, and the check's components: the
/// smallest motion of the carried URDF axis onto the calibrated one (`cal`).
fn carried(
    ap: &Isometry3<f64>,
    u: &Isometry3<f64>,
    cal: &Isometry3<f64>,
) -> (Isometry3<f64>, Vector4<f64>) {
    let nominal = ap * u;
    let local = nominal.inverse() * cal;
    let dir = local * Vector3::z();
    let point = local.translation.vector;
    let tilt = UnitQuaternion::rotation_between(&Vector3::z(), &dir)
        .map_or(Vector3::new(std::f64::consts::PI, 0.0, 0.0), |q| {
            q.scaled_axis()
        });
    let shift = if dir.z.abs() > 1e-9 {
        point - dir * (point.z / dir.z)
    } else {
        Vector3::new(point.x, point.y, 0.0)
    };
    let motion = Isometry3::from_parts(
        Translation3::from(shift),
        UnitQuaternion::from_scaled_axis(tilt),
    );
    (
        nominal * motion * u.inverse(),
        Vector4::new(tilt.x, tilt.y, shift.x, shift.y),
    )
}

/// Aligns a calibrated body with a URDF: the check of its joints and the SU frames on its links.
pub fn align(body: &BodyModel, urdf_text: &str) -> Result<Alignment, AlignError> {
    let tree = UrdfTree::parse(urdf_text)?;
    let robot = body.check().map_err(AlignError::Model)?;
    let model = &robot.model;
    let n = model.dofs().len();
    let k = forward_kinematics(model, &robot.parameters, &vec![0.0; n]);
    let cal: Vec<Isometry3<f64>> = (0..n)
        .map(|d| z_on(&k.joints[d], &model.dofs()[d].axis))
        .collect();
    let plan = plan(body, &robot, &tree)?;
    let nominal = run(&plan, &cal);
    let covariance = check_covariance(body, &robot, &k.joints, &cal, &plan);
    let joints: Vec<JointCheck> = (0..n)
        .map(|d| {
            let covariance = covariance.as_ref().map(|c| &c[d]);
            check_joint(&robot, &tree, &plan, nominal.r[d], covariance, d)
        })
        .collect();
    let disagree = joints
        .iter()
        .filter(|j| j.verdict == JointVerdict::Disagrees)
        .map(|j| j.dof.clone())
        .collect();
    let (sus, unplaced) = place_sus(&robot, &k.sus, &tree, &plan, &nominal.a);
    let partial = partly_placed(body)
        .into_iter()
        .filter(|(su, _)| sus.iter().any(|s| &s.su == su))
        .collect();
    Ok(Alignment {
        check: UrdfCheck {
            robot: tree.name.clone(),
            joints,
            disagree,
        },
        tree,
        sus,
        unplaced,
        partial,
    })
}

/// The SUs whose pose relative to the rest of their limb no reading fully determines: those
/// before the last SU of the limb whose pose relative to the SU before it has an undetermined
/// direction (on an arm with a vertical first axis, the SUs on the first link: how far along and
/// about that axis they sit from the rest). The alignment places a limb by its later axes, so
/// these SUs stay where the calibration's gauge left them in those directions.
pub fn partly_placed(body: &BodyModel) -> Vec<(String, String)> {
    let mut out = Vec::new();
    for limb in &body.limbs {
        let u = &limb.estimate.uncertainty;
        let Some(j) = (1..u.len()).rev().find(|&j| u[j].is_partial()) else {
            continue;
        };
        for before in &u[..j] {
            out.push((
                before.su.clone(),
                format!(
                    "its pose relative to `{}` (limb {}) is not determined by any reading in some directions ({}, in `{}`'s frame): placed where the calibration's gauge left it there, not measured",
                    u[j].su,
                    limb.name,
                    u[j].undetermined(),
                    u[j - 1].su
                ),
            ));
        }
    }
    out
}

/// Per DoF, the covariance of its check's components (none when no limb holds a joint
/// covariance: a model of an older skincal).
fn check_covariance(
    body: &BodyModel,
    robot: &Robot,
    joints: &[Isometry3<f64>],
    cal: &[Isometry3<f64>],
    plan: &Plan,
) -> Option<Vec<DMatrix<f64>>> {
    let mut covariance: Vec<DMatrix<f64>> = vec![DMatrix::zeros(4, 4); cal.len()];
    let mut any = false;
    for limb in &body.limbs {
        let Some(jc) = &limb.estimate.joint_covariance else {
            continue;
        };
        any = true;
        let sigma = DMatrix::from_fn(4 * jc.dofs.len(), 4 * jc.dofs.len(), |i, j| {
            jc.matrix
                .get(i)
                .and_then(|row| row.get(j))
                .copied()
                .unwrap_or(0.0)
        });
        let jacobian = limb_jacobian(robot, joints, cal, plan, jc);
        for (c, jd) in covariance.iter_mut().zip(&jacobian) {
            if let Some(jd) = jd {
                *c += jd * &sigma * jd.transpose();
            }
        }
    }
    any.then_some(covariance)
}

/// The check of DoF `d` from its components `r` and their covariance.
fn check_joint(
    robot: &Robot,
    tree: &UrdfTree,
    plan: &Plan,
    r: Option<Vector4<f64>>,
    covariance: Option<&DMatrix<f64>>,
    d: DofIndex,
) -> JointCheck {
    let model = &robot.model;
    let blank = |verdict, note: String| JointCheck {
        dof: model.dofs()[d].name.clone(),
        verdict,
        note,
        angle: 0.0,
        angle_sd: 0.0,
        distance: 0.0,
        distance_sd: 0.0,
        tilt: [0.0; 3],
        shift: [0.0; 3],
        components: 0,
        chi2: 0.0,
    };
    let (matched, p, r) = match (&plan.urdf[d], plan.parent[d], r) {
        (Err(why), _, _) => return blank(JointVerdict::NotCompared, why.clone()),
        (Ok(_), None, _) => return blank(
            JointVerdict::LimbBase,
            "where a limb sits on the reference segment no reading tells: the URDF is aligned on this axis".into(),
        ),
        (Ok(_), Some(p), _) if plan.after_slide[d] => return blank(
            JointVerdict::LimbBase,
            format!("on the segment prismatic `{}` moves, where a slide's line lies no reading tells (only its direction): the URDF is aligned on this axis", model.dofs()[p].name),
        ),
        (Ok(_), Some(p), _) if plan.hangs[d] && !plan.slides[d] => return blank(
            JointVerdict::LimbBase,
            format!("a limb on `{}`'s segment, fitted with that limb's path and gravity held: where it sits on it carries that limb's gravity uncertainty, which the model does not keep; the URDF is aligned on this axis", model.dofs()[p].name),
        ),
        (Ok(_), Some(p), None) => return blank(
            JointVerdict::NotCompared,
            format!("`{}` before it was not compared", model.dofs()[p].name),
        ),
        (Ok(matched), Some(p), Some(r)) => (matched, p, r),
    };
    // The check's components are in the joint's z-axis frame; tilt and shift are reported in the
    // URDF joint's own frame.
    let turn = z_on(&Isometry3::identity(), &tree.joints[matched.joint].axis).rotation;
    let mut check = JointCheck {
        angle: nalgebra::Vector2::new(r[0], r[1]).norm(),
        distance: nalgebra::Vector2::new(r[2], r[3]).norm(),
        tilt: (turn * Vector3::new(r[0], r[1], 0.0)).into(),
        shift: (turn * Vector3::new(r[2], r[3], 0.0)).into(),
        ..blank(JointVerdict::NotCompared, String::new())
    };
    let parent = &model.dofs()[p].name;
    let Some(c) = covariance else {
        check.note = "the model holds no joint covariance (calibrated by an older skincal): calibrate again to check".into();
        return check;
    };
    let sd_along = |x: f64, y: f64, o: usize| {
        let block = c.fixed_view::<2, 2>(o, o).into_owned();
        match nalgebra::Vector2::new(x, y).try_normalize(1e-15) {
            Some(v) => (v.transpose() * block * v)[0].max(0.0).sqrt(),
            None => block.symmetric_eigenvalues().max().max(0.0).sqrt(),
        }
    };
    if model.dofs()[d].kind == DofKind::Prismatic {
        // A sliding axis has a direction and no line: only its tilt is compared.
        let tilt = c.fixed_view::<2, 2>(0, 0).into_owned();
        let mut only = DMatrix::zeros(4, 4);
        only.fixed_view_mut::<2, 2>(0, 0).copy_from(&tilt);
        (check.chi2, check.components) = mahalanobis(&Vector4::new(r[0], r[1], 0.0, 0.0), &only);
        check.distance = 0.0;
        check.shift = [0.0; 3];
    } else {
        (check.chi2, check.components) = mahalanobis(&r, c);
        check.distance_sd = sd_along(r[2], r[3], 2);
    }
    check.angle_sd = sd_along(r[0], r[1], 0);
    check.verdict = if check.components > 0 && check.chi2 > CHI2_3SIGMA[check.components - 1] {
        JointVerdict::Disagrees
    } else {
        JointVerdict::Agrees
    };
    check.note = if plan.is_base(p) {
        format!("against `{parent}`, the limb's first DoF: only the distance and angle between the two axes tell")
    } else {
        format!("against `{parent}`")
    };
    check
}

/// Each SU's frame on the URDF link of its segment, or why it has none.
fn place_sus(
    robot: &Robot,
    su_frames: &[Isometry3<f64>],
    tree: &UrdfTree,
    plan: &Plan,
    a: &[Option<Isometry3<f64>>],
) -> (Vec<SuOnLink>, Vec<(String, String)>) {
    let model = &robot.model;
    let mut sus = Vec::new();
    let mut unplaced = Vec::new();
    for (su, frame) in model.sus().iter().zip(su_frames) {
        let Some(d) = model.segments()[su.segment].parent_dof else {
            unplaced.push((
                su.name.clone(),
                "on the static reference segment: only its tilt is known".to_string(),
            ));
            continue;
        };
        let dof = &model.dofs()[d].name;
        let (Some(a), Ok(matched)) = (a[d], &plan.urdf[d]) else {
            let why = match &plan.urdf[d] {
                Err(why) => format!("its DoF `{dof}`: {why}"),
                Ok(_) => format!("its DoF `{dof}` could not be aligned"),
            };
            unplaced.push((su.name.clone(), why));
            continue;
        };
        let joint = &tree.joints[matched.joint];
        sus.push(SuOnLink {
            su: su.name.clone(),
            link: joint.child.clone(),
            pose: tree.frames[&joint.child].inverse() * a.inverse() * frame,
        });
    }
    (sus, unplaced)
}

/// χ² of `r` against covariance `c` over the directions `c` determines, and their number.
fn mahalanobis(r: &Vector4<f64>, c: &DMatrix<f64>) -> (f64, usize) {
    let eig = c.clone().symmetric_eigen();
    let largest = eig.eigenvalues.max();
    if largest <= 0.0 {
        return (0.0, 0);
    }
    let mut chi2 = 0.0;
    let mut components = 0;
    for (i, &e) in eig.eigenvalues.iter().enumerate() {
        if e > largest * 1e-8 {
            let v = eig.eigenvectors.column(i);
            let x: f64 = v.iter().zip(r.iter()).map(|(a, b)| a * b).sum();
            chi2 += x * x / e;
            components += 1;
        }
    }
    (chi2, components)
}

/// Per DoF, the 4 × 4m Jacobian of its check's components with respect to the limb's joint lines
/// (each DoF's 4 components in its own joint frame, as [`JointCovariance`] orders them).
fn limb_jacobian(
    robot: &Robot,
    joints: &[Isometry3<f64>],
    cal: &[Isometry3<f64>],
    plan: &Plan,
    jc: &JointCovariance,
) -> Vec<Option<DMatrix<f64>>> {
    let model = &robot.model;
    let n = cal.len();
    let mut out: Vec<Option<DMatrix<f64>>> = vec![None; n];
    for (slot, name) in jc.dofs.iter().enumerate() {
        let Some(k) = model.dof_index(name) else {
            continue;
        };
        let downstream: Vec<usize> = (0..n)
            .filter(|&j| j == k || model.moves_segment(k, model.dofs()[j].parent))
            .collect();
        for c in 0..4 {
            let moved = |h: f64| {
                let mut x = [0.0; 4];
                x[c] = h;
                let local = Isometry3::from_parts(
                    Translation3::new(x[2], x[3], 0.0),
                    UnitQuaternion::from_scaled_axis(Vector3::new(x[0], x[1], 0.0)),
                );
                let motion = joints[k] * local * joints[k].inverse();
                let mut frames = cal.to_vec();
                for &j in &downstream {
                    frames[j] = motion * frames[j];
                }
                run(plan, &frames).r
            };
            let (plus, minus) = (moved(STEP), moved(-STEP));
            for d in 0..n {
                if let (Some(p), Some(m)) = (plus[d], minus[d]) {
                    let column = (p - m) / (2.0 * STEP);
                    let jd = out[d].get_or_insert_with(|| DMatrix::zeros(4, 4 * jc.dofs.len()));
                    jd.column_mut(4 * slot + c).copy_from(&column);
                }
            }
        }
    }
    out
}

/// Per DoF (of the tree given by each DoF's `parent`), every DoF after it, nearest first.
fn descendants(parent: &[Option<DofIndex>]) -> Vec<Vec<DofIndex>> {
    let n = parent.len();
    (0..n)
        .map(|d| {
            let mut out = Vec::new();
            let mut frontier = vec![d];
            while !frontier.is_empty() {
                let next: Vec<DofIndex> = (0..n)
                    .filter(|&c| parent[c].is_some_and(|p| frontier.contains(&p)))
                    .collect();
                out.extend(&next);
                frontier = next;
            }
            out
        })
        .collect()
}

/// Matches the calibrated DoFs with the URDF's joints and checks that the trees agree.
fn plan(body: &BodyModel, robot: &Robot, tree: &UrdfTree) -> Result<Plan, AlignError> {
    use urdf_rs::JointType as J;
    let model = &robot.model;
    let moving: HashMap<&str, (usize, &crate::model::urdf::UrdfJoint)> = tree
        .joints
        .iter()
        .enumerate()
        .filter(|(_, j)| matches!(j.kind, J::Revolute | J::Continuous | J::Prismatic))
        .map(|(i, j)| (j.name.as_str(), (i, j)))
        .collect();
    let n = model.dofs().len();
    let parent: Vec<Option<DofIndex>> = model
        .dofs()
        .iter()
        .map(|dof| model.segments()[dof.parent].parent_dof)
        .collect();
    let mut urdf = Vec::with_capacity(n);
    for (d, dof) in model.dofs().iter().enumerate() {
        let sliding = |j: &crate::model::urdf::UrdfJoint| matches!(j.kind, J::Prismatic);
        let entry = match moving.get(dof.name.as_str()) {
            None => Err(match tree.joints.iter().find(|j| j.name == dof.name) {
                Some(j) => format!(
                    "the URDF's joint of this name is {:?}, not revolute, continuous or prismatic",
                    j.kind
                )
                .to_lowercase(),
                None => "the URDF has no joint of this name".to_string(),
            }),
            Some(&(_, j)) if sliding(j) != (dof.kind == DofKind::Prismatic) => Err(format!(
                "the URDF's joint of this name is {}, the calibrated DoF {}",
                if sliding(j) { "prismatic" } else { "revolute" },
                dof.kind.name()
            )),
            Some(&(index, j)) => {
                let above = tree.moving_joint_above(&j.parent).map(|a| a.name.as_str());
                match parent[d] {
                    Some(p) if above != Some(model.dofs()[p].name.as_str()) => Err(format!(
                        "the URDF moves it after {}, the calibration after `{}`",
                        above.map_or("nothing".to_string(), |a| format!("`{a}`")),
                        model.dofs()[p].name
                    )),
                    _ => Ok(Matched {
                        joint: index,
                        frame: z_on(&(tree.frames[&j.parent] * j.origin), &j.axis),
                    }),
                }
            }
        };
        urdf.push(entry);
    }
    if urdf.iter().all(Result::is_err) {
        return Err(AlignError::NothingInCommon {
            model: model.dof_names(),
            urdf: moving
                .keys()
                .map(|s| s.to_string())
                .collect::<BTreeSet<_>>()
                .into_iter()
                .collect(),
        });
    }
    let descendants = descendants(&parent);
    let hangs = model
        .dofs()
        .iter()
        .map(|dof| {
            body.limbs
                .iter()
                .any(|l| l.parent.is_some() && l.dofs.first() == Some(&dof.name))
        })
        .collect();
    let after_slide = parent
        .iter()
        .map(|p| p.is_some_and(|p| model.dofs()[p].kind == DofKind::Prismatic))
        .collect();
    let slides = model
        .dofs()
        .iter()
        .map(|dof| dof.kind == DofKind::Prismatic)
        .collect();
    Ok(Plan {
        urdf,
        parent,
        hangs,
        after_slide,
        slides,
        descendants,
    })
}

/// The URDF text with one link per placed SU, each on its link by a fixed joint `<prefix><su>_mount`
/// (origin only), inserted before `</robot>`; everything else of the text is kept as it is. With
/// `snippet`, only the added elements, as a xacro-includable `<robot>` file.
pub fn merge_sus(
    alignment: &Alignment,
    urdf_text: &str,
    prefix: &str,
    snippet: bool,
) -> Result<String, AlignError> {
    use crate::show::xml_escape;
    let taken: BTreeSet<&str> = alignment
        .tree
        .links
        .iter()
        .map(String::as_str)
        .chain(alignment.tree.joints.iter().map(|j| j.name.as_str()))
        .collect();
    let newline = if urdf_text.contains("\r\n") {
        "\r\n"
    } else {
        "\n"
    };
    let mut block = String::new();
    block.push_str(&format!(
        "  <!-- Skin: {} SU frames calibrated by skincal, each on the link its segment corresponds to (kinematics only). -->{newline}",
        alignment.sus.len()
    ));
    for s in &alignment.sus {
        let link = format!("{prefix}{}", s.su);
        let joint = format!("{link}_mount");
        if alignment.partial.iter().any(|(su, _)| su == &s.su) {
            block.push_str(&format!(
                "  <!-- {}: partly measured: see the note of `skincal export-urdf` (its pose along some directions is the calibration's gauge, not a measurement). -->{newline}",
                xml_escape(&s.su).replace("--", "- -")
            ));
        }
        for name in [&link, &joint] {
            if taken.contains(name.as_str()) {
                return Err(AlignError::NameTaken(name.clone()));
            }
        }
        let (r, p, y) = s.pose.rotation.euler_angles();
        let v = s.pose.translation.vector;
        block.push_str(&format!(
            "  <link name=\"{l}\"/>{newline}  <joint name=\"{j}\" type=\"fixed\">{newline}    <origin xyz=\"{} {} {}\" rpy=\"{r} {p} {y}\"/>{newline}    <parent link=\"{}\"/>{newline}    <child link=\"{l}\"/>{newline}  </joint>{newline}",
            v.x,
            v.y,
            v.z,
            xml_escape(&s.link),
            l = xml_escape(&link),
            j = xml_escape(&joint),
        ));
    }
    // MuJoCo's URDF reader would fuse the SU links into their parents: its block says not to,
    // unless the robot's own says otherwise.
    let urdf_text = &with_compiler_attribute(urdf_text, "fusestatic", "false");
    if !snippet && !urdf_text.contains("<mujoco") {
        block.push_str(&format!(
            "  <mujoco><compiler fusestatic=\"false\"/></mujoco>{newline}"
        ));
    }
    if snippet {
        return Ok(format!(
            "<?xml version=\"1.0\"?>{newline}<!-- Include inside your robot's xacro: <xacro:include filename=\"this file\"/> -->{newline}<robot xmlns:xacro=\"http://www.ros.org/wiki/xacro\">{newline}{block}</robot>{newline}"
        ));
    }
    let text = insert_before_end(urdf_text, &block, newline)?;
    // The result must read back as the URDF with the SU frames on their links.
    let merged = UrdfTree::parse(&text).map_err(|e| AlignError::Merged(e.to_string()))?;
    for s in &alignment.sus {
        let joint = format!("{prefix}{}_mount", s.su);
        if !merged
            .joints
            .iter()
            .any(|j| j.name == joint && j.parent == s.link)
        {
            return Err(AlignError::Merged(format!(
                "`{joint}` is not on `{}` (is `</robot>` inside a comment?)",
                s.link
            )));
        }
    }
    Ok(text)
}

/// The URDF `text`, read from the folder `from`, made to load from any other folder as it loaded
/// from there: its relative file names (meshes, textures) made absolute (`package://` and
/// `file://` names, which do not depend on the file's folder, are kept), and, when it names files,
/// the `<compiler>` of its `<mujoco>` block given `meshdir="from"` when it has none: with
/// `strippath`, MuJoCo's URDF reader cuts file names to their last part and looks for them in
/// `meshdir`, beside the model by default, so a robot whose meshes lie beside its URDF is found
/// there again.
pub fn relocated(text: &str, from: &std::path::Path) -> String {
    let text = absolute_file_names(text, from);
    if !text.contains("filename=\"") {
        // No file to find: the text stays as the robot's.
        return text;
    }
    with_compiler_attribute(&text, "meshdir", &from.to_string_lossy())
}

/// `text` with `name="value"` on the `<compiler>` of its `<mujoco>` block (one made when the
/// block has none) unless the compiler sets it already; as it is without a `<mujoco>` block.
fn with_compiler_attribute(text: &str, name: &str, value: &str) -> String {
    let Some(block) = text.find("<mujoco") else {
        return text.to_string();
    };
    let block_end = text[block..]
        .find("</mujoco>")
        .map_or(text.len(), |i| block + i);
    let attribute = format!(" {name}=\"{}\"", crate::show::xml_escape(value));
    let Some(at) = text[block..block_end].find("<compiler").map(|i| block + i) else {
        // No compiler: one right after the block's opening tag.
        let Some(open) = text[block..].find('>').map(|i| block + i + 1) else {
            return text.to_string();
        };
        if text[..open].ends_with("/>") {
            return text.to_string();
        }
        return format!("{}<compiler{attribute}/>{}", &text[..open], &text[open..]);
    };
    let end = text[at..].find('>').map_or(text.len(), |i| at + i);
    let set = format!("{name}=");
    if text[at..end]
        .split_whitespace()
        .any(|word| word.starts_with(&set))
    {
        return text.to_string();
    }
    let at = at + "<compiler".len();
    format!("{}{attribute}{}", &text[..at], &text[at..])
}

/// The URDF `text`, read from the folder `from`, with its relative file names made absolute.
fn absolute_file_names(text: &str, from: &std::path::Path) -> String {
    const KEY: &str = "filename=\"";
    let mut out = String::with_capacity(text.len());
    let mut rest = text;
    while let Some(at) = rest.find(KEY) {
        let (head, tail) = rest.split_at(at + KEY.len());
        out.push_str(head);
        let end = tail.find('"').unwrap_or(tail.len());
        let name = &tail[..end];
        if name.contains("://") || std::path::Path::new(name).is_absolute() || name.is_empty() {
            out.push_str(name);
        } else {
            out.push_str(&crate::show::xml_escape(&from.join(name).to_string_lossy()));
        }
        rest = &tail[end..];
    }
    out.push_str(rest);
    out
}

/// `text` with `block` inserted before its last `</robot>`, on a line of its own.
fn insert_before_end(text: &str, block: &str, newline: &str) -> Result<String, AlignError> {
    let end = text.rfind("</robot>").ok_or(AlignError::NoRobotEnd)?;
    // Keep the indentation of the closing tag's line.
    let line_start = text[..end].rfind('\n').map_or(0, |i| i + 1);
    let at = if text[line_start..end].trim().is_empty() {
        line_start
    } else {
        end
    };
    let mut out = String::with_capacity(text.len() + block.len() + newline.len());
    out.push_str(&text[..at]);
    if at == end {
        out.push_str(newline);
    }
    out.push_str(block);
    out.push_str(&text[at..]);
    Ok(out)
}
