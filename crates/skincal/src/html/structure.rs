//! The structure found: the activity matrix (the paper's Fig. 2) as explored — SUs × DoFs, per
//! base orientation — and merged into segments × joints, and the kinematic tree.

use std::collections::BTreeMap;
use std::fmt::Write as _;

use maud::{html, Markup, PreEscaped};

use super::PALETTE;
use crate::explore::Structure;
use crate::measurements::MeasurementSet;
use crate::show::xml_escape as escape;

/// The alphabet of the SU × DoF matrix's cells: one character per cell, its change in g in
/// steps of a 32nd of the threshold (the last one: twice it or more).
const LEVELS: &[u8; 64] = b"0123456789ABCDEFGHIJKLMNOPQRSTUVWXYZabcdefghijklmnopqrstuvwxyz+/";

pub(super) fn activity(s: &Structure) -> Markup {
    let m = &s.matrix;
    // The change in g of the uncertain entries, by segment and joint.
    let su_segment: BTreeMap<&str, &str> = s
        .segments
        .iter()
        .flat_map(|seg| seg.sus.iter().map(move |su| (su.as_str(), seg.id.as_str())))
        .collect();
    let dof_joint: BTreeMap<&str, &str> = s
        .joints
        .iter()
        .flat_map(|j| j.dofs.iter().map(move |d| (d.as_str(), j.id.as_str())))
        .collect();
    let mut uncertain: BTreeMap<(&str, &str), Vec<String>> = BTreeMap::new();
    for u in &s.uncertain {
        if let (Some(seg), Some(joint)) =
            (su_segment.get(u.su.as_str()), dof_joint.get(u.dof.as_str()))
        {
            uncertain.entry((seg, joint)).or_default().push(format!(
                "{} × {}: {:.3} g ({})",
                u.su,
                u.dof,
                u.change_g,
                if u.active {
                    "counted active"
                } else {
                    "counted still"
                }
            ));
        }
    }
    let sus_of = |id: &str| {
        s.segments
            .iter()
            .find(|seg| seg.id == id)
            .map(|seg| seg.sus.join(", "))
            .unwrap_or_default()
    };
    let dofs_of = |id: &str| {
        s.joints
            .iter()
            .find(|j| j.id == id)
            .map(|j| j.dofs.join(", "))
            .unwrap_or_default()
    };
    html! {
        div id="merged-activity" {
            h3 { "Segments × joints, merged" }
            p class="note" { "Segments × joints, sorted into lower-triangular form: a filled cell means the joint moves the segment's SUs (gravity turned by more than "
                (format!("{:.3}", s.threshold_g)) " g over " (s.orientations) " base orientation(s)). Dashed: within the uncertainty band; hover for the change in g." }
            div class="scroll" { table class="matrix" {
                tr { th {} @for j in &m.joints { th title=(dofs_of(j)) { (j) } } }
                @for (r, seg) in m.segments.iter().enumerate() {
                    tr {
                        th class="name" title=(sus_of(seg)) { (seg) }
                        @for (c, j) in m.joints.iter().enumerate() {
                            @let notes = uncertain.get(&(seg.as_str(), j.as_str()));
                            @let class = match (m.entries[r][c], notes.is_some()) {
                                (true, true) => "on uncertain", (true, false) => "on",
                                (false, true) => "uncertain", (false, false) => "",
                            };
                            td class=(class) title=(notes.map(|n| n.join("; ")).unwrap_or_else(|| format!("{seg} × {j}"))) {}
                        }
                    }
                }
            } }
        }
    }
}

/// The SU × DoF activity matrix of each base orientation as the structure experiment read it:
/// every SU's largest change of one axis (g) when each DoF moved, rows and columns in the sorted
/// order of the merged matrix, drawn on a canvas (one character per cell keeps 2000 SUs small).
pub(super) fn su_activity(s: &Structure, set: &MeasurementSet) -> Markup {
    let Some(experiment) = &set.structure else {
        return html! {};
    };
    let sus: Vec<&str> = s
        .matrix
        .segments
        .iter()
        .filter_map(|id| s.segment(id))
        .flat_map(|seg| seg.sus.iter().map(String::as_str))
        .chain(s.unplaced_sus.iter().map(String::as_str))
        .collect();
    let dofs: Vec<&str> = s
        .matrix
        .joints
        .iter()
        .filter_map(|id| s.joint(id))
        .flat_map(|j| j.dofs.iter().map(String::as_str))
        .chain(s.unplaced_dofs.iter().map(String::as_str))
        .collect();
    let su_col: Vec<Option<usize>> = sus
        .iter()
        .map(|su| set.sus.iter().position(|g| g == su))
        .collect();
    let threshold = s.threshold_g * crate::model::sensor::STANDARD_GRAVITY;
    let orientations: Vec<String> = experiment
        .orientations
        .iter()
        .map(|o| {
            let mut cells = String::with_capacity(sus.len() * dofs.len());
            for u in &su_col {
                for d in &dofs {
                    let mv = o.moves.iter().find(|m| m.dof == *d);
                    let level = match (u, mv) {
                        (Some(u), Some(mv)) => {
                            let (a, b) = (mv.readings[*u], o.rest[*u]);
                            let change = (0..3).map(|i| (a[i] - b[i]).abs()).fold(0.0, f64::max);
                            if change.is_finite() {
                                (change / threshold * 32.0).round().clamp(0.0, 63.0) as usize
                            } else {
                                63
                            }
                        }
                        _ => 0,
                    };
                    cells.push(LEVELS[level] as char);
                }
            }
            cells
        })
        .collect();
    let data = serde_json::json!({
        "sus": sus, "dofs": dofs, "threshold_g": s.threshold_g,
        "levels": String::from_utf8_lossy(LEVELS), "orientations": orientations,
    });
    let json = data.to_string().replace("</", "<\\/");
    html! {
        h3 { "SUs × DoFs, as explored (one matrix per base orientation)" }
        p class="note" { "Each cell: the largest change of one axis of the SU's reading when the DoF moved (dark: above the threshold of "
            (format!("{:.3}", s.threshold_g)) " g; grey: below it, lighter the smaller). Rows and columns in the order of the merged matrix below; hover for names and the change." }
        div id="su-activity" {}
        script type="application/json" id="su-activity-data" { (PreEscaped(json)) }
        script { (PreEscaped(SU_ACTIVITY)) }
    }
}

/// Draws the SU × DoF matrices of `#su-activity-data` on canvases.
const SU_ACTIVITY: &str = r#"(function () {
  var data = JSON.parse(document.getElementById('su-activity-data').textContent);
  var box = document.getElementById('su-activity');
  var rows = data.sus.length, cols = data.dofs.length;
  var cw = Math.max(4, Math.min(16, Math.floor(960 / Math.max(1, cols))));
  var ch = Math.max(1, Math.min(12, Math.floor(900 / Math.max(1, rows))));
  var named = rows <= 80 && ch >= 9, labelled = cw >= 10, top = labelled ? 90 : 4, left = named ? 110 : 4;
  data.orientations.forEach(function (cells, o) {
    var figure = document.createElement('figure'), canvas = document.createElement('canvas');
    figure.className = 'chart matrix-figure';
    canvas.width = left + cols * cw + 4; canvas.height = top + rows * ch + 4;
    var ctx = canvas.getContext('2d');
    ctx.font = '10px system-ui, sans-serif'; ctx.fillStyle = '#222';
    if (labelled) {
      data.dofs.forEach(function (d, j) {
        ctx.save(); ctx.translate(left + j * cw + cw * 0.7, top - 4); ctx.rotate(-Math.PI / 2);
        ctx.fillText(d, 0, 0); ctx.restore();
      });
    }
    for (var i = 0; i < rows; i++) {
      if (named) { ctx.fillStyle = '#222'; ctx.textAlign = 'right'; ctx.fillText(data.sus[i], left - 4, top + i * ch + ch - 2); }
      for (var j = 0; j < cols; j++) {
        var level = data.levels.indexOf(cells.charAt(i * cols + j));
        ctx.fillStyle = level >= 32 ? '#222' : 'hsl(0, 0%, ' + (100 - level) + '%)';
        ctx.fillRect(left + j * cw, top + i * ch, cw - (cw > 5 ? 1 : 0), ch - (ch > 3 ? 1 : 0));
      }
    }
    canvas.title = 'orientation ' + (o + 1);
    canvas.addEventListener('mousemove', function (e) {
      var r = canvas.getBoundingClientRect();
      var j = Math.floor((e.clientX - r.left - left) / cw), i = Math.floor((e.clientY - r.top - top) / ch);
      if (i < 0 || j < 0 || i >= rows || j >= cols) { canvas.title = 'orientation ' + (o + 1); return; }
      var level = data.levels.indexOf(cells.charAt(i * cols + j));
      canvas.title = data.sus[i] + ' × ' + data.dofs[j] + ': ' + (level >= 63 ? '≥ ' : '≈ ') + (level / 32 * data.threshold_g).toFixed(3) + ' g';
    });
    var caption = document.createElement('figcaption');
    caption.textContent = 'Base orientation ' + (o + 1) + ': ' + rows + ' SUs × ' + cols + ' DoFs.';
    figure.appendChild(canvas); figure.appendChild(caption); box.appendChild(figure);
  });
})();"#;

/// Where the tree's nodes go: depth-first, leaves a row apart in order, inner nodes at the mean
/// of their children; columns by depth.
struct TreeLayout {
    row: BTreeMap<String, f64>,
    depth: BTreeMap<String, usize>,
    leaves: f64,
}

impl TreeLayout {
    const DX: f64 = 150.0;
    const DY: f64 = 30.0;
    const MARGIN: f64 = 20.0;

    fn of(s: &Structure) -> Self {
        let mut layout = Self {
            row: BTreeMap::new(),
            depth: BTreeMap::new(),
            leaves: 0.0,
        };
        layout.place(s, &s.root, 0);
        layout
    }

    fn place(&mut self, s: &Structure, id: &str, level: usize) -> f64 {
        self.depth.insert(id.to_string(), level);
        let kids: Vec<&str> = s
            .joints
            .iter()
            .filter(|j| j.parent == id)
            .map(|j| j.child.as_str())
            .collect();
        let at = if kids.is_empty() {
            self.leaves += 1.0;
            self.leaves - 1.0
        } else {
            let rows: Vec<f64> = kids.iter().map(|k| self.place(s, k, level + 1)).collect();
            rows.iter().sum::<f64>() / rows.len() as f64
        };
        self.row.insert(id.to_string(), at);
        at
    }

    /// Width and height of the drawing, px.
    fn size(&self) -> (f64, f64) {
        let levels = self.depth.values().max().copied().unwrap_or(0) as f64;
        (
            levels * Self::DX + 2.0 * Self::MARGIN + 140.0,
            self.leaves.max(1.0) * Self::DY + 2.0 * Self::MARGIN,
        )
    }

    /// A node's centre, px.
    fn at(&self, id: &str) -> (f64, f64) {
        (
            Self::MARGIN + self.depth.get(id).copied().unwrap_or(0) as f64 * Self::DX,
            Self::MARGIN + Self::DY / 2.0 + self.row.get(id).copied().unwrap_or(0.0) * Self::DY,
        )
    }
}

/// A joint as an elbow out of its parent, down (or up) to its child's row and along it, with its
/// DoF on the row (a multi-DoF joint's id and count; its DoFs on hover).
fn tree_joint(
    svg: &mut String,
    j: &crate::explore::JointNode,
    (x1, y1): (f64, f64),
    (x2, y2): (f64, f64),
    colour: &str,
) {
    let elbow = x1 + 0.2 * (x2 - x1);
    let _ = write!(
        svg,
        "<path class=\"joint\" d=\"M{x1:.1} {y1:.1}H{elbow:.1}V{y2:.1}H{x2:.1}\" fill=\"none\" stroke=\"{colour}\" stroke-width=\"3\"><title>{} ({})</title></path>",
        escape(&j.id),
        escape(&j.dofs.join(", "))
    );
    let label = match j.dofs.as_slice() {
        [one] => one.clone(),
        many => format!("{} ({} DoFs)", j.id, many.len()),
    };
    let _ = write!(
        svg,
        "<text x=\"{:.1}\" y=\"{:.1}\" fill=\"#555\">{}</text>",
        elbow + 4.0,
        y2 - 4.0,
        escape(&label)
    );
}

/// A segment as a node: a square where the tree branches, a ringed circle at an end effector;
/// its SUs on hover.
fn tree_segment(
    svg: &mut String,
    s: &Structure,
    seg: &crate::explore::SegmentNode,
    (cx, cy): (f64, f64),
    fill: &str,
) {
    let end = s.end_effectors.contains(&seg.id);
    let shape = if s.branching.contains(&seg.id) {
        format!(
            "<rect x=\"{:.1}\" y=\"{:.1}\" width=\"16\" height=\"16\" fill=\"{fill}\"/>",
            cx - 8.0,
            cy - 8.0
        )
    } else {
        format!(
            "<circle cx=\"{cx:.1}\" cy=\"{cy:.1}\" r=\"{}\" fill=\"{fill}\"{}/>",
            if end { 9 } else { 7 },
            if end {
                " stroke=\"#000\" stroke-width=\"2\""
            } else {
                ""
            }
        )
    };
    let _ = write!(
        svg,
        "<g class=\"segment\"><title>{}: {}</title>{shape}<text x=\"{:.1}\" y=\"{:.1}\">{}</text></g>",
        escape(&seg.id),
        escape(&if seg.sus.is_empty() {
            "no SU".to_string()
        } else {
            seg.sus.join(", ")
        }),
        cx + 9.0,
        cy + 13.0,
        escape(&seg.id)
    );
}

/// The tree as SVG, root at the left: each segment a node at (depth, leaf order), each joint an
/// elbow labelled with its DoFs, coloured by the limb it belongs to. Leaves are a row apart, so
/// labels never overlap however many DoFs the robot has.
pub(super) fn tree(s: &Structure) -> Markup {
    let layout = TreeLayout::of(s);
    let limb_of: BTreeMap<&str, usize> = s
        .limbs
        .iter()
        .enumerate()
        .flat_map(|(i, l)| l.segments.iter().map(move |seg| (seg.as_str(), i)))
        .collect();
    let colour_of = |segment: &str| {
        limb_of
            .get(segment)
            .map_or("#999", |&i| PALETTE[i % PALETTE.len()])
    };
    let (width, height) = layout.size();
    let mut svg = String::new();
    let _ = write!(
        svg,
        "<svg xmlns=\"http://www.w3.org/2000/svg\" width=\"{width:.0}\" height=\"{height:.0}\" viewBox=\"0 0 {width:.0} {height:.0}\">"
    );
    for j in &s.joints {
        tree_joint(
            &mut svg,
            j,
            layout.at(&j.parent),
            layout.at(&j.child),
            colour_of(&j.child),
        );
    }
    for seg in &s.segments {
        let fill = if seg.id == s.root {
            "#000"
        } else {
            colour_of(&seg.id)
        };
        tree_segment(&mut svg, s, seg, layout.at(&seg.id), fill);
    }
    svg.push_str("</svg>");
    html! {
        section id="tree" {
            h2 { "Kinematic tree" }
            p class="note" { "Root (black) at the left; a colour per limb; end effectors ringed, branching segments square. Hover for the SUs of a segment and the DoFs of a joint." }
            div class="scroll" { (PreEscaped(svg)) }
            @if !s.unplaced_dofs.is_empty() || !s.unplaced_sus.is_empty() {
                p class="bad" { "Left out: DoFs " (s.unplaced_dofs.join(", ")) "; SUs " (s.unplaced_sus.join(", ")) "." }
            }
        }
    }
}
