//! The 3D view of the calibrated body, placed on the reference segment where the robot's URDF puts
//! each limb (or in a layout that says it is one), SUs coloured by their uncertainty or held-out
//! error.

use std::collections::BTreeMap;

use maud::{html, Markup, PreEscaped};
use nalgebra::{Isometry3, Matrix3, Translation3, UnitQuaternion, Vector3};

use crate::estimate::body::BodyModel;
use crate::model::DofKind;

/// The script of the 3D view: forward kinematics of the embedded body and an orthographic
/// drawing on a canvas, turned by dragging.
const VIEW3D: &str = r#"(function () {
  var data = JSON.parse(document.getElementById('body-data').textContent);
  var canvas = document.getElementById('view3d'), ctx = canvas.getContext('2d');
  var q = data.dofs.map(function () { return 0; });
  var yaw = 0.7, pitch = 0.35, zoom = 1;
  function mul(a, b) { // rigid transforms {r: 3x3 row-major, p: [3]}
    var r = [], p = [];
    for (var i = 0; i < 3; i++) {
      for (var j = 0; j < 3; j++) {
        r[3 * i + j] = a.r[3 * i] * b.r[j] + a.r[3 * i + 1] * b.r[3 + j] + a.r[3 * i + 2] * b.r[6 + j];
      }
      p[i] = a.r[3 * i] * b.p[0] + a.r[3 * i + 1] * b.p[1] + a.r[3 * i + 2] * b.p[2] + a.p[i];
    }
    return { r: r, p: p };
  }
  function turn(k, t) { // rotation by t about the unit axis k
    var c = Math.cos(t), s = Math.sin(t), v = 1 - c, x = k[0], y = k[1], z = k[2];
    return { r: [c + x * x * v, x * y * v - z * s, x * z * v + y * s,
                 y * x * v + z * s, c + y * y * v, y * z * v - x * s,
                 z * x * v - y * s, z * y * v + x * s, c + z * z * v], p: [0, 0, 0] };
  }
  function slide(k, t) { // translation by t along the unit axis k
    return { r: [1, 0, 0, 0, 1, 0, 0, 0, 1], p: [k[0] * t, k[1] * t, k[2] * t] };
  }
  function apply(t, v) { return mul(t, { r: [1, 0, 0, 0, 1, 0, 0, 0, 1], p: v }).p; }
  function frames() {
    var seg = [{ r: [1, 0, 0, 0, 1, 0, 0, 0, 1], p: [0, 0, 0] }], joints = [];
    data.dofs.forEach(function (d, i) {
      var j = mul(seg[d.parent], { r: d.r, p: d.o });
      joints[i] = j;
      seg[d.child] = mul(j, d.prismatic ? slide(d.axis, q[i]) : turn(d.axis, q[i]));
    });
    return { seg: seg, joints: joints };
  }
  function project(v) {
    var cy = Math.cos(yaw), sy = Math.sin(yaw), cp = Math.cos(pitch), sp = Math.sin(pitch);
    var x = cy * v[0] + sy * v[1], y = -sy * v[0] + cy * v[1];
    var up = cp * v[2] - sp * y;
    var s = zoom * canvas.height / (2.4 * data.extent);
    return [canvas.width / 2 + s * (x - data.centre[0]), canvas.height / 2 - s * (up - data.centre[2])];
  }
  function line(a, b, colour, width) {
    var p = project(a), r = project(b);
    ctx.strokeStyle = colour; ctx.lineWidth = width;
    ctx.beginPath(); ctx.moveTo(p[0], p[1]); ctx.lineTo(r[0], r[1]); ctx.stroke();
  }
  function draw() {
    var f = frames(), axis = data.extent * 0.08, triad = data.extent * 0.05;
    ctx.clearRect(0, 0, canvas.width, canvas.height);
    data.dofs.forEach(function (d, i) { // the segment: from its parent's joint to this joint
      var from = data.parent_joint[d.parent];
      line(from < 0 ? [0, 0, 0] : f.joints[from].p, f.joints[i].p, '#888', 3);
      var z = apply(f.joints[i], d.axis.map(function (c) { return c * axis; }));
      var back = apply(f.joints[i], d.axis.map(function (c) { return -c * axis; }));
      line(back, z, '#222', 2);
      if (d.parent === 0) { // a limb's base on the reference segment: what no reading places
        var ring = [], n = 24, rr = data.extent * 0.06, a = d.axis;
        var e1 = Math.abs(a[0]) < 0.9 ? [0, a[2], -a[1]] : [-a[2], 0, a[0]];
        var l1 = Math.hypot(e1[0], e1[1], e1[2]); e1 = e1.map(function (c) { return c / l1; });
        var e2 = [a[1] * e1[2] - a[2] * e1[1], a[2] * e1[0] - a[0] * e1[2], a[0] * e1[1] - a[1] * e1[0]];
        for (var t = 0; t <= n; t++) {
          var c = Math.cos(2 * Math.PI * t / n) * rr, s2 = Math.sin(2 * Math.PI * t / n) * rr;
          ring.push(apply(f.joints[i], [c * e1[0] + s2 * e2[0], c * e1[1] + s2 * e2[1], c * e1[2] + s2 * e2[2]]));
        }
        ctx.setLineDash(data.placement === 'urdf' ? [] : [4, 3]);
        for (var t2 = 0; t2 < n; t2++) { line(ring[t2], ring[t2 + 1], '#7b3294', 1.5); }
        ctx.setLineDash([]);
      }
    });
    var s = zoom * canvas.height / (2.4 * data.extent);
    data.sus.forEach(function (u) {
      var t = mul(f.seg[u.seg], { r: u.r, p: u.p }), from = data.parent_joint[u.seg];
      line(from < 0 ? [0, 0, 0] : f.joints[from].p, t.p, '#ccc', 1);
      ['#d62728', '#2ca02c', '#1f77b4'].forEach(function (colour, k) {
        var e = [0, 0, 0]; e[k] = triad; line(t.p, apply(t, e), colour, 2);
      });
      var c = project(t.p), share = data.colour_max > 0 && u.value !== null ? Math.min(1, u.value / data.colour_max) : null;
      ctx.fillStyle = share === null ? '#bbb' : 'hsl(' + (240 - 240 * share).toFixed(0) + ', 75%, 45%)';
      ctx.beginPath(); ctx.arc(c[0], c[1], 3.5, 0, 2 * Math.PI); ctx.fill();
      ctx.strokeStyle = 'rgba(230, 159, 0, 0.9)'; ctx.lineWidth = 1;
      ctx.beginPath(); ctx.arc(c[0], c[1], Math.max(2, u.sd * s), 0, 2 * Math.PI); ctx.stroke();
    });
  }
  var box = document.getElementById('view3d-sliders');
  data.dofs.forEach(function (d, i) {
    var label = document.createElement('label'), input = document.createElement('input');
    input.type = 'range'; input.min = d.lower; input.max = d.upper; input.step = (d.upper - d.lower) / 400; input.value = 0;
    input.addEventListener('input', function () { q[i] = parseFloat(input.value); draw(); });
    label.appendChild(document.createTextNode(d.name + ' '));
    label.appendChild(input);
    box.appendChild(label);
  });
  var dragging = null;
  canvas.addEventListener('mousedown', function (e) { dragging = [e.clientX, e.clientY]; });
  window.addEventListener('mouseup', function () { dragging = null; });
  window.addEventListener('mousemove', function (e) {
    if (!dragging) { return; }
    yaw += (e.clientX - dragging[0]) * 0.01;
    pitch = Math.max(-1.5, Math.min(1.5, pitch + (e.clientY - dragging[1]) * 0.01));
    dragging = [e.clientX, e.clientY];
    draw();
  });
  canvas.addEventListener('wheel', function (e) {
    e.preventDefault(); zoom *= e.deltaY < 0 ? 1.1 : 1 / 1.1; draw();
  }, { passive: false });
  // `#pose=0.3` in the address sets every DoF (for checking the drawing against the model).
  var pose = /pose=([-0-9.e]+)/.exec(location.hash);
  if (pose) {
    q = q.map(function () { return parseFloat(pose[1]); });
    box.querySelectorAll('input').forEach(function (input) { input.value = pose[1]; });
  }
  draw();
  var f = frames();
  document.getElementById('view3d-sus').textContent = JSON.stringify(data.sus.map(function (u) {
    return [u.name, mul(f.seg[u.seg], { r: u.r, p: u.p }).p];
  }));
})();"#;

/// Where the 3D view puts each limb that starts on the reference segment (no accelerometer
/// reading tells where a limb sits on it, nor its turn about a vertical first axis).
#[derive(Debug, Clone, PartialEq)]
pub(super) enum Bases {
    /// Where the robot's URDF puts them: per first DoF of such a limb, the rigid motion from the
    /// calibration's frame to the URDF's root frame.
    Urdf(BTreeMap<String, Isometry3<f64>>),
    /// Side by side along x, a layout for legibility.
    Layout,
}

/// What colours the SUs: a quantity per SU (none: grey) and its name.
pub(super) struct Colouring {
    pub what: String,
    pub values: BTreeMap<String, f64>,
}

/// Per limb on the reference segment, the rigid motion that puts its SUs at the zero pose where
/// the URDF alignment put them (`sus`: each SU's frame in the URDF's root frame): the mean of the
/// SUs' rotations (projected onto a rotation) and of their positions' offsets.
pub(super) fn urdf_bases(
    m: &BodyModel,
    urdf_frames: &BTreeMap<String, Isometry3<f64>>,
) -> BTreeMap<String, Isometry3<f64>> {
    let Ok(robot) = m.check() else {
        return BTreeMap::new();
    };
    let model = &robot.model;
    let k =
        crate::model::forward_kinematics(model, &robot.parameters, &vec![0.0; model.dofs().len()]);
    let mut bases = BTreeMap::new();
    for (d, dof) in model.dofs().iter().enumerate() {
        if dof.parent != 0 {
            continue;
        }
        let pairs: Vec<(Isometry3<f64>, Isometry3<f64>)> = (0..model.sus().len())
            .filter(|&u| model.moves_su(d, u))
            .filter_map(|u| {
                let placed = urdf_frames.get(&model.sus()[u].name)?;
                Some((k.sus[u], *placed))
            })
            .collect();
        if pairs.is_empty() {
            continue;
        }
        let sum: Matrix3<f64> = pairs
            .iter()
            .map(|(cal, urdf)| {
                (urdf.rotation * cal.rotation.inverse())
                    .to_rotation_matrix()
                    .into_inner()
            })
            .sum();
        let rotation = UnitQuaternion::from_matrix(&sum);
        let shift = pairs
            .iter()
            .map(|(cal, urdf)| urdf.translation.vector - rotation * cal.translation.vector)
            .sum::<Vector3<f64>>()
            / pairs.len() as f64;
        bases.insert(
            dof.name.clone(),
            Isometry3::from_parts(Translation3::from(shift), rotation),
        );
    }
    bases
}

/// The rigid motion of each limb on the reference segment in the view (by its first DoF).
fn placements(
    model: &crate::model::RobotModel,
    k: &crate::model::Kinematics<f64>,
    bases: &Bases,
) -> Vec<Isometry3<f64>> {
    let n = model.dofs().len();
    match bases {
        Bases::Urdf(by_name) => (0..n)
            .map(|d| {
                by_name
                    .get(&model.dofs()[d].name)
                    .copied()
                    .unwrap_or_else(Isometry3::identity)
            })
            .collect(),
        Bases::Layout => {
            // Each limb's extent along x at the zero pose, then side by side about x = 0.
            let extent = |d: usize| -> (f64, f64) {
                let points = (0..n)
                    .filter(|&e| model.moves_segment(d, model.dofs()[e].child))
                    .map(|e| k.joints[e].translation.x)
                    .chain(
                        (0..model.sus().len())
                            .filter(|&u| model.moves_su(d, u))
                            .map(|u| k.sus[u].translation.x),
                    );
                points.fold((f64::MAX, f64::MIN), |(lo, hi), x| (lo.min(x), hi.max(x)))
            };
            let roots: Vec<usize> = (0..n).filter(|&d| model.dofs()[d].parent == 0).collect();
            let spans: Vec<(f64, f64)> = roots.iter().map(|&d| extent(d)).collect();
            let gap = 0.1;
            let total: f64 = spans.iter().map(|(lo, hi)| hi - lo + gap).sum::<f64>() - gap;
            let mut at = -total / 2.0;
            let mut shift = vec![Isometry3::identity(); n];
            for (&d, (lo, hi)) in roots.iter().zip(&spans) {
                shift[d] = Isometry3::translation(at - lo, 0.0, 0.0);
                at += hi - lo + gap;
            }
            shift
        }
    }
}

/// The calibrated body for the 3D view: every DoF's joint frame on its parent segment and axis,
/// every SU's frame on its segment and position uncertainty, at the zero pose.
fn body_data(m: &BodyModel, bases: &Bases, colouring: &Colouring) -> Option<serde_json::Value> {
    let robot = m.check().ok()?;
    let model = &robot.model;
    let mut k =
        crate::model::forward_kinematics(model, &robot.parameters, &vec![0.0; model.dofs().len()]);
    // Each limb on the reference segment moved where `bases` puts it, with everything after it.
    let place = placements(model, &k, bases);
    for (d, dof) in model.dofs().iter().enumerate() {
        if dof.parent != 0 {
            continue;
        }
        for e in 0..model.dofs().len() {
            if model.moves_segment(d, model.dofs()[e].child) {
                k.joints[e] = place[d] * k.joints[e];
                let child = model.dofs()[e].child;
                k.segments[child] = place[d] * k.segments[child];
            }
        }
        for u in 0..model.sus().len() {
            if model.moves_su(d, u) {
                k.sus[u] = place[d] * k.sus[u];
            }
        }
    }
    let frame = |t: &nalgebra::Isometry3<f64>| {
        let r = t.rotation.to_rotation_matrix();
        let r: Vec<f64> = (0..9).map(|i| r[(i / 3, i % 3)]).collect();
        (r, t.translation.vector)
    };
    // DoFs in the order their parents are known (segments are topological).
    let mut order: Vec<usize> = (0..model.dofs().len()).collect();
    order.sort_by_key(|&d| model.dofs()[d].child);
    let mut parent_joint = vec![-1i64; model.segments().len()];
    let mut dofs = Vec::new();
    for (i, &d) in order.iter().enumerate() {
        let dof = &model.dofs()[d];
        parent_joint[dof.child] = i as i64;
        let (r, o) = frame(&(k.segments[dof.parent].inverse() * k.joints[d]));
        let finite = |v: f64, or: f64| if v.is_finite() { v } else { or };
        dofs.push(serde_json::json!({
            "name": dof.name, "parent": dof.parent, "child": dof.child,
            "r": r, "o": [o.x, o.y, o.z], "axis": dof.axis.as_ref().as_slice(),
            "prismatic": dof.kind == DofKind::Prismatic,
            "lower": finite(dof.limits.lower, -std::f64::consts::PI),
            "upper": finite(dof.limits.upper, std::f64::consts::PI),
        }));
    }
    let sd: BTreeMap<&str, f64> = m
        .limbs
        .iter()
        .flat_map(|l| {
            l.estimate
                .uncertainty
                .iter()
                .map(|u| (u.su.as_str(), u.position_sd))
        })
        .collect();
    let sus: Vec<serde_json::Value> = model
        .sus()
        .iter()
        .enumerate()
        .map(|(u, su)| {
            let (r, p) = frame(&(k.segments[su.segment].inverse() * k.sus[u]));
            serde_json::json!({
                "name": su.name, "seg": su.segment, "r": r, "p": [p.x, p.y, p.z],
                "sd": sd.get(su.name.as_str()).copied().unwrap_or(0.0),
                "value": colouring.values.get(&su.name),
            })
        })
        .collect();
    let points: Vec<nalgebra::Vector3<f64>> = k
        .joints
        .iter()
        .chain(&k.sus)
        .map(|t| t.translation.vector)
        .chain(std::iter::once(nalgebra::Vector3::zeros()))
        .collect();
    let (lo, hi) = points.iter().fold(
        (
            nalgebra::Vector3::repeat(f64::MAX),
            nalgebra::Vector3::repeat(f64::MIN),
        ),
        |(lo, hi), p| (lo.inf(p), hi.sup(p)),
    );
    let centre = (lo + hi) / 2.0;
    let colour_max = colouring.values.values().copied().fold(0.0, f64::max);
    Some(serde_json::json!({
        "dofs": dofs, "sus": sus, "parent_joint": parent_joint,
        "placement": match bases { Bases::Urdf(_) => "urdf", Bases::Layout => "layout" },
        "colour_by": colouring.what, "colour_max": colour_max,
        "centre": [centre.x, centre.y, centre.z],
        "extent": ((hi - lo).amax() / 2.0).max(0.05),
    }))
}

pub(super) fn view3d(m: &BodyModel, bases: &Bases, colouring: &Colouring) -> Markup {
    let Some(data) = body_data(m, bases, colouring) else {
        return html! {};
    };
    // Inside a script element only `</` could end it early.
    let json = data.to_string().replace("</", "<\\/");
    html! {
        section id="view3d-section" {
            h2 { "The calibrated body" }
            p class="note" { "At the zero pose, in the body frame (z up): segments grey, joint axes black, each SU's frame as a triad (x red, y green, z blue), its position uncertainty as an orange circle (to scale), its dot coloured by "
                (colouring.what) " (blue: small, red: the largest; grey: none). Drag to turn, wheel to zoom; a slider per DoF." }
            @match bases {
                Bases::Urdf(_) => p class="note" { "Where each limb sits on the reference segment, and how it is turned about a vertical first axis, no accelerometer reading tells: the limbs are placed where the robot's URDF puts them (purple rings: the limbs' bases)." },
                Bases::Layout => p class="note" { span class="bad" { "Layout: " } "where each limb sits on the reference segment, and how it is turned about a vertical first axis, no accelerometer reading tells, so the limbs are set side by side for legibility (dashed purple rings: the limbs' bases, placed by this layout, not measured). Give the robot's URDF (" code { "report --urdf" } ") to see them where it puts them." },
            }
            canvas id="view3d" width="900" height="600" style="border: 1px solid #ddd; cursor: grab" {}
            div id="view3d-sliders" style="columns: 3; font-size: 12px" {}
            // Where the drawing put every SU, for checking it against the model.
            pre id="view3d-sus" hidden {}
            script type="application/json" id="body-data" { (PreEscaped(json)) }
            script { (PreEscaped(VIEW3D)) }
        }
    }
}
