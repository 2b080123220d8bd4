//! Still windows and the motions between them.

use super::fit::{design, Excitation};
use super::timeline::Timeline;
use super::{IngestConfig, LogReport, Span};
use crate::model::sensor::ExcitationPattern;

/// A pause between motions: where every DoF is slower than `quiet_velocity` (servo ringing
/// allowed). Its longest run slower than `still_velocity`, trimmed, is its still window, which
/// gives a static reading when it is at least `min_still` long.
#[derive(Debug, Clone)]
pub(super) struct StillWindow {
    /// Grid range `[start, end)` of the still window (of the whole pause without one).
    pub(super) start: usize,
    pub(super) end: usize,
    /// The mean pose over that range.
    pub(super) pose: Vec<f64>,
    /// Whether the range is a still window for a static reading.
    pub(super) reading: bool,
    /// Whether that window is shorter than `min_still`: a servo that rings through most of a
    /// short hold leaves no longer one. Its station's reading pools it only when the station
    /// has no full one (it may hold the end of the settling motion).
    pub(super) short: bool,
    /// Where the DoFs never were all below `still_velocity` for long enough in the pause: the
    /// speed every DoF stayed below in the window instead, rad/s, the least of
    /// [`creep_limits`]. A servo that settles slower than the program holds still creeps at the
    /// end of a hold (a heavy joint on soft, lightly damped servos: 0.02 rad/s half a second
    /// after a move), and a creep is no acceleration: the window's mean reading is that of its
    /// mean pose, to first order in the pose's change across it. Its station's reading pools it
    /// only when the station has no still one, and no noise is estimated from it.
    pub(super) creeping: Option<f64>,
}

/// A still window may be this many times shorter than `min_still` where its station has no
/// full one.
pub(super) const SHORT_STILL: usize = 3;

/// The speeds below which a pause without a still window is searched for the window in which it
/// crept least ([`StillWindow::creeping`]): `still_velocity` doubled, and doubled again, up to
/// `quiet_velocity`, which ends the list.
fn creep_limits(config: &IngestConfig) -> Vec<f64> {
    let mut limits = Vec::new();
    let mut limit = 2.0 * config.still_velocity;
    while limit < config.quiet_velocity {
        limits.push(limit);
        limit *= 2.0;
    }
    if config.quiet_velocity > config.still_velocity {
        limits.push(config.quiet_velocity);
    }
    limits
}

/// Runs of `true` in `mask` at least `min` long, as `[start, end)`.
fn runs(mask: &[bool], min: usize) -> Vec<(usize, usize)> {
    let mut out = Vec::new();
    let mut i = 0;
    while i < mask.len() {
        if mask[i] {
            let s = i;
            while i < mask.len() && mask[i] {
                i += 1;
            }
            if i - s >= min.max(1) {
                out.push((s, i));
            }
        } else {
            i += 1;
        }
    }
    out
}

#[derive(Debug, Clone)]
pub(super) enum Event {
    Still(usize),
    Excitation(usize),
    Move,
    Transfer,
    Broken,
}

/// The windows of one log.
#[derive(Debug, Clone, Default)]
pub(super) struct Segmentation {
    pub(super) stills: Vec<StillWindow>,
    pub(super) excitations: Vec<Excitation>,
    pub(super) events: Vec<Event>,
    /// Every window's `(start, end, still?, index)`, sorted by start, for routing samples.
    pub(super) routes: Vec<(usize, usize, bool, usize)>,
}

/// A pause and the motion after it, as found on a stretch of a log's timeline (grid points of
/// the whole log).
pub(super) struct Piece {
    /// The pause's grid range.
    pub(super) pause: (usize, usize),
    /// Whether the pause is over (its still window final) within the stretch.
    pub(super) closed: bool,
    still: StillWindow,
    /// The pause's span and the motion's in the report's timeline.
    spans: Vec<Span>,
    /// The motions after the pause, in order (one, unless a pause too short to be found
    /// separated excitations of one DoF after another).
    after: Vec<After>,
}

/// What follows a pause.
enum After {
    /// Nothing: no motion, or the stretch ends.
    Nothing,
    /// A motion that cannot be used, and why.
    Broken(String),
    Move,
    /// Several DoFs moved; with the pair that moved alone, one a fixed multiple of the other.
    Transfer(Option<(String, String, f64)>),
    Excitation(Excitation),
}

impl Segmentation {
    /// Adds the next piece of the log (its windows and their report); without its pause's still
    /// window when that was added before (see [`Segmentation::add_pause`]).
    pub(super) fn add(&mut self, mut piece: Piece, with_pause: bool, report: &mut LogReport) {
        if with_pause {
            self.add_pause(&piece, report);
        }
        report.timeline.extend(piece.spans.drain(1..));
        for after in piece.after {
            self.add_motion(after, report);
        }
    }

    /// Adds the motion after a pause.
    fn add_motion(&mut self, after: After, report: &mut LogReport) {
        match after {
            After::Nothing => {}
            After::Broken(why) => {
                report.skipped.push(why);
                self.events.push(Event::Broken);
            }
            After::Move => {
                report.moves += 1;
                self.events.push(Event::Move);
            }
            After::Transfer(pair) => {
                report.transfers += 1;
                self.events.push(Event::Transfer);
                if let Some((leader, follower, multiplier)) = pair {
                    report.add_together(leader, follower, multiplier);
                }
            }
            After::Excitation(x) => {
                report.excitations += 1;
                let w = self.excitations.len();
                self.routes.push((x.start, x.end, false, w));
                self.events.push(Event::Excitation(w));
                self.excitations.push(x);
            }
        }
    }

    /// Adds a piece's pause alone: its still window and its span.
    pub(super) fn add_pause(&mut self, piece: &Piece, report: &mut LogReport) {
        let k = self.stills.len();
        if piece.still.reading {
            self.routes
                .push((piece.still.start, piece.still.end, true, k));
        }
        self.stills.push(piece.still.clone());
        self.events.push(Event::Still(k));
        report.timeline.push(piece.spans[0].clone());
    }

    /// Counts the still windows and pauses once the log is complete.
    pub(super) fn finish(&self, report: &mut LogReport) {
        report.still_windows = self.stills.iter().filter(|s| s.reading).count();
        report.pauses = self.stills.len() - report.still_windows;
    }
}

/// The windows of a whole log's timeline.
pub(super) fn segment(
    timeline: &Timeline,
    dofs: &[String],
    config: &IngestConfig,
    report: &mut LogReport,
) -> Segmentation {
    let mut seg = Segmentation::default();
    for piece in pieces(timeline, dofs, config, true) {
        seg.add(piece, true, report);
    }
    seg.finish(report);
    seg
}

/// The grid points dropped at both ends of a still run, with the filter's half-width `l`: a still
/// point's speed is measured over ±l, so the samples within l of a run's ends may still move.
pub(super) fn trim_points(config: &IngestConfig, dt: f64, l: usize) -> usize {
    ((config.trim / dt).round() as usize).max(l + 1)
}

/// The half-width of the differentiation filter on a grid of period `dt`, grid points.
pub(super) fn filter_points(config: &IngestConfig, dt: f64) -> usize {
    ((config.filter / dt).round() as usize).max(2)
}

/// The pauses of a stretch of a log's timeline and the motions between them; the stretch is the
/// log's start when `timeline.first` is 0, and its end when `at_end`. Elsewhere the stretch's
/// edges are not pauses: a quiet run cut by them is one only when long enough, and the last
/// piece's pause may go on beyond the stretch.
pub(super) fn pieces(
    timeline: &Timeline,
    dofs: &[String],
    config: &IngestConfig,
    at_end: bool,
) -> Vec<Piece> {
    let n = timeline.len();
    let dt = timeline.grid.dt;
    let l = filter_points(config, dt);
    let trim = trim_points(config, dt, l);
    let min_still = ((config.min_still / dt).round() as usize).max(1);
    let first = timeline.first;
    let slow = Slow::new(timeline, dofs, config, l);
    let still = slow.below(config.still_velocity);
    let pauses = pauses(timeline, config, &slow, l, at_end);
    // The masks of the creep limits, made where a pause first needs them.
    let limits = creep_limits(config);
    let mut creep: Vec<Option<Vec<bool>>> = vec![None; limits.len()];
    let mut out = Vec::with_capacity(pauses.len());
    for (k, &(s, e)) in pauses.iter().enumerate() {
        // The longest still run of the pause, trimmed, gives the static reading; one shorter than
        // `min_still` (but a third of it at least) only where its station has no other; where
        // there is none, the longest run below the least creep limit that has one.
        let longest = |mask: &[bool]| {
            runs(&mask[s..e], min_still.div_ceil(SHORT_STILL) + 2 * trim)
                .into_iter()
                .max_by_key(|(a, b)| b - a)
                .map(|(a, b)| (s + a + trim, s + b - trim))
        };
        let mut reading = longest(&still);
        let mut creeping = None;
        for (limit, mask) in limits.iter().zip(creep.iter_mut()) {
            if reading.is_some() {
                break;
            }
            reading = longest(mask.get_or_insert_with(|| slow.below(*limit)));
            creeping = reading.map(|_| *limit);
        }
        let short = reading.is_some_and(|(a, b)| b - a < min_still);
        let (a, b) = reading.unwrap_or((s, e));
        let pose = timeline
            .theta
            .iter()
            .map(|th| th[a..b].iter().sum::<f64>() / (b - a) as f64)
            .collect();
        let mut spans = vec![span(
            timeline,
            dofs,
            if reading.is_some() { "still" } else { "pause" },
            None,
            s,
            e,
        )];
        let after = match pauses.get(k + 1) {
            None => Vec::new(),
            Some(&(next_s, _)) => motions(timeline, dofs, config, l, (e, next_s), &mut spans),
        };
        out.push(Piece {
            pause: (first + s, first + e),
            closed: at_end || e + l < n,
            still: StillWindow {
                start: first + a,
                end: first + b,
                pose,
                reading: reading.is_some(),
                short,
                creeping,
            },
            spans,
            after,
        });
    }
    out
}

/// Where every DoF of a stretch is slower than a speed: each DoF's change over ±`filter` grid
/// points, against that speed over the span and its encoder's flicker. A prismatic DoF's speeds
/// are compared in its pattern's units ([`IngestConfig::speed_scale`]).
struct Slow<'a> {
    timeline: &'a Timeline,
    l: usize,
    span: f64,
    /// Per DoF, what its encoder may read at a still joint over the span.
    flicker: Vec<f64>,
    /// Per DoF, its speeds' scale.
    scale: Vec<f64>,
}

impl<'a> Slow<'a> {
    fn new(timeline: &'a Timeline, dofs: &[String], config: &IngestConfig, l: usize) -> Self {
        // A still DoF's encoder may read a count either way at both ends of the span: two
        // counts over it are no motion (a flickering 0.044° encoder at ±50 ms reads 0.015 rad/s).
        let flicker = (0..timeline.theta.len())
            .map(|e| 2.0 * timeline.grid.count.get(e).copied().unwrap_or(0.0))
            .collect();
        let scale = (0..timeline.theta.len())
            .map(|e| dofs.get(e).map_or(1.0, |d| config.speed_scale(d)))
            .collect();
        Self {
            timeline,
            l,
            span: 2.0 * l as f64 * timeline.grid.dt,
            flicker,
            scale,
        }
    }

    /// Grid points where every DoF is slower than `limit`.
    fn below(&self, limit: f64) -> Vec<bool> {
        self.slow_or_within(limit, None)
    }

    /// Grid points where every DoF is slower than `limit` or, ringing, stays within `within` of
    /// where it is over twice the span: a DoF that has not moved by
    /// [`IngestConfig::motion_threshold`] has not moved, however fast it rings. Only a slide's
    /// speeds are low enough for that to matter at the defaults (0.005 m/s, half a millimetre
    /// over the span, against 2 mm): a lift carrying an arm bounces as the arm's servos ring, a
    /// few tenths of a millimetre at 4 Hz, 6 mm/s.
    fn quiet(&self, limit: f64, within: f64) -> Vec<bool> {
        self.slow_or_within(limit, Some(within))
    }

    fn slow_or_within(&self, limit: f64, within: Option<f64>) -> Vec<bool> {
        let (timeline, l) = (self.timeline, self.l);
        let n = timeline.len();
        let ringing = |th: &[f64], i: usize, allowed: f64| {
            within.is_some_and(|within| {
                allowed < within && {
                    let around = &th[i.saturating_sub(2 * l)..(i + 2 * l + 1).min(n)];
                    let (low, high) = around
                        .iter()
                        .fold((f64::INFINITY, f64::NEG_INFINITY), |(a, b), &x| {
                            (a.min(x), b.max(x))
                        });
                    high - low <= within
                }
            })
        };
        (0..n)
            .map(|i| {
                if i < l || i + l >= n || timeline.invalid[i] {
                    return false;
                }
                timeline
                    .theta
                    .iter()
                    .zip(&self.flicker)
                    .zip(&self.scale)
                    .all(|((th, f), s)| {
                        let allowed = limit * s * self.span + f;
                        (th[i + l] - th[i - l]).abs() < allowed || ringing(th, i, allowed)
                    })
            })
            .collect()
    }
}

/// The pauses of a stretch (see [`pieces`]): runs where every DoF is slower than
/// `quiet_velocity`.
fn pauses(
    timeline: &Timeline,
    config: &IngestConfig,
    slow: &Slow,
    l: usize,
    at_end: bool,
) -> Vec<(usize, usize)> {
    let n = timeline.len();
    let dt = timeline.grid.dt;
    let quiet = slow.quiet(config.quiet_velocity, config.motion_threshold);
    let min_pause = (config.min_pause / dt).round() as usize;
    let mut pauses = runs(&quiet, min_pause.max(4 * l + 1));
    // The recording's ends close a motion too: a quiet run that reaches the first or the last grid
    // point the filter can judge is a pause even when shorter (the log started or stopped in it).
    let short = runs(&quiet, 2 * l + 1);
    if let Some(&last) = short.last() {
        if at_end && last.1 + l >= n && pauses.last() != Some(&last) {
            pauses.push(last);
        }
    }
    if let Some(&start) = short.first() {
        if timeline.first == 0 && start.0 <= l && pauses.first() != Some(&start) {
            pauses.insert(0, start);
        }
    }
    pauses
}

/// A span of the report's timeline over local grid points `[from, to)`.
fn span(
    timeline: &Timeline,
    dofs: &[String],
    kind: &str,
    dof: Option<usize>,
    from: usize,
    to: usize,
) -> Span {
    Span {
        kind: kind.into(),
        dof: dof.map(|d| dofs[d].clone()),
        start: timeline.time(from),
        end: timeline.time(to),
    }
}

/// What the motions over local grid points `[ms, me)`, between two pauses, were; their spans are
/// added to `spans`. One motion, unless DoFs that all came back did so one after another: then
/// each was excited alone and the pause between them was too short to be found (a servo that
/// rings through a short pause), and each is a motion of its own.
fn motions(
    timeline: &Timeline,
    dofs: &[String],
    config: &IngestConfig,
    l: usize,
    (ms, me): (usize, usize),
    spans: &mut Vec<Span>,
) -> Vec<After> {
    let motion = classify(timeline, dofs, ms, me, config);
    let parts = match &motion {
        Motion::Excitation(excited) if excited.len() > 1 => {
            one_after_another(timeline, excited, (ms, me), l)
        }
        _ => None,
    };
    // An excitation window reaches 2l into the pauses at its ends; at a cut, it ends there.
    let window = |a: usize, b: usize| {
        (
            if a == ms { a.saturating_sub(2 * l) } else { a },
            if b == me {
                (b + 2 * l).min(timeline.len())
            } else {
                b
            },
        )
    };
    let Some(cuts) = parts else {
        let window = window(ms, me);
        return vec![motion_after(
            timeline,
            dofs,
            l,
            ((ms, me), window),
            motion,
            spans,
        )];
    };
    let bounds: Vec<usize> = std::iter::once(ms)
        .chain(cuts)
        .chain(std::iter::once(me))
        .collect();
    bounds
        .windows(2)
        .map(|w| {
            let part = classify(timeline, dofs, w[0], w[1], config);
            let window = window(w[0], w[1]);
            motion_after(timeline, dofs, l, ((w[0], w[1]), window), part, spans)
        })
        .collect()
}

/// Where to cut a motion of the DoFs `excited` (all came back) into motions of one DoF each,
/// when each moved alone in turn: every DoF is active (beyond half its largest excursion) in a
/// stretch that ends before the next one's begins, and each cut is at the slowest point between
/// them, with room for the filter on both sides. `None`: they moved at the same time.
fn one_after_another(
    timeline: &Timeline,
    excited: &[usize],
    (ms, me): (usize, usize),
    l: usize,
) -> Option<Vec<usize>> {
    let mut active: Vec<(usize, usize)> = excited
        .iter()
        .map(|&e| {
            let th = &timeline.theta[e];
            let excursion = th[ms..me]
                .iter()
                .fold(0.0f64, |m, q| m.max((q - th[ms]).abs()));
            let beyond = |i: &usize| (th[*i] - th[ms]).abs() > 0.5 * excursion;
            let first = (ms..me).find(beyond).unwrap_or(ms);
            let last = (ms..me).rev().find(beyond).unwrap_or(me);
            (first, last)
        })
        .collect();
    active.sort_unstable();
    let speed = |i: usize| {
        timeline
            .theta
            .iter()
            .map(|th| (th[(i + l).min(me)] - th[i.saturating_sub(l).max(ms)]).abs())
            .fold(0.0f64, f64::max)
    };
    let mut cuts = Vec::with_capacity(active.len() - 1);
    let mut from = ms;
    for pair in active.windows(2) {
        let (end, next) = (pair[0].1, pair[1].0);
        if end >= next {
            return None;
        }
        let cut = (end..=next).min_by(|&a, &b| speed(a).total_cmp(&speed(b)))?;
        // Each part's excitation window must hold the fit's filter on both sides.
        if cut < from + 2 * l + 1 || cut + 2 * l + 1 > me {
            return None;
        }
        cuts.push(cut);
        from = cut;
    }
    Some(cuts)
}

/// What the motion over local grid points `[ms, me)` was, classified as `motion`; its spans are
/// added to `spans`; `[start, end)` is the window an excitation is fitted over.
fn motion_after(
    timeline: &Timeline,
    dofs: &[String],
    l: usize,
    ((ms, me), (start, end)): ((usize, usize), (usize, usize)),
    motion: Motion,
    spans: &mut Vec<Span>,
) -> After {
    let at = timeline.time(ms);
    let mut span =
        |kind: &str, dof: Option<usize>| spans.push(span(timeline, dofs, kind, dof, ms, me));
    if timeline.invalid[ms..me].iter().any(|&x| x) {
        span("broken", None);
        return After::Broken(format!("motion at {at:.3} s: joint states missing (gap)"));
    }
    match motion {
        Motion::None => After::Nothing,
        Motion::Move(d) => {
            span("move", Some(d));
            After::Move
        }
        Motion::Transfer => {
            span("transfer", None);
            let pair = in_proportion(timeline, ms, me);
            After::Transfer(pair.map(|(a, b, m)| (dofs[a].clone(), dofs[b].clone(), m)))
        }
        Motion::Excitation(excited) => match design(timeline, &excited, start, end, l) {
            Some(mut x) => {
                for &d in &excited {
                    span("excitation", Some(d));
                }
                x.start += timeline.first;
                x.end += timeline.first;
                After::Excitation(x)
            }
            None => {
                span("broken", Some(excited[0]));
                let names = excited
                    .iter()
                    .map(|&d| format!("`{}`", dofs[d]))
                    .collect::<Vec<_>>()
                    .join(" and ");
                After::Broken(format!(
                    "excitation of {names} at {at:.3} s: too short or no acceleration to fit \
                         against"
                ))
            }
        },
    }
}

/// The largest change of position that a DoF's servo sag explains, in motion thresholds.
const SAG_STEPS: f64 = 10.0;

/// A motion whose DoFs all end within this fraction of their largest excursion from where they
/// started came back (an excitation); one that ends farther went somewhere (a move or a transfer).
/// A structure move ends at its farthest point (its overshoot is a few percent on a servo damped
/// at 0.5 or more); a pattern that a slow servo lags ends a few percent of its excursion off.
const RETURN_FRACTION: f64 = 0.5;
/// A DoF that went this share of its excursion to the other side of its start too went both
/// ways: more than a servo's overshoot at the end of a pattern.
const OTHER_SIDE_FRACTION: f64 = 0.3;

/// A DoF moved with another in a transfer when its excursion is at least this share of the
/// largest one.
const TOGETHER_FRACTION: f64 = 0.1;
/// Two DoFs moved in proportion when the second's path leaves at most this share of its
/// excursion (RMS) from a fixed multiple of the first's.
const PROPORTION_MISFIT: f64 = 0.01;

/// The two DoFs that alone moved over grid `[ms, me]`, the second a fixed multiple of the first
/// throughout (a mimic joint and its leader, when ingest was not told of them): `(first, second,
/// multiple)`, the first in the log's order; `None` for any other motion.
fn in_proportion(timeline: &Timeline, ms: usize, me: usize) -> Option<(usize, usize, f64)> {
    let paths: Vec<Vec<f64>> = timeline
        .theta
        .iter()
        .map(|th| th[ms..=me].iter().map(|q| q - th[ms]).collect())
        .collect();
    let excursion: Vec<f64> = paths
        .iter()
        .map(|p| p.iter().fold(0.0f64, |m, x| m.max(x.abs())))
        .collect();
    let largest = excursion.iter().copied().fold(0.0, f64::max);
    let moved: Vec<usize> = (0..paths.len())
        .filter(|&e| largest > 0.0 && excursion[e] >= TOGETHER_FRACTION * largest)
        .collect();
    let &[a, b] = moved.as_slice() else {
        return None;
    };
    let (xx, xy) = paths[a]
        .iter()
        .zip(&paths[b])
        .fold((0.0, 0.0), |(xx, xy), (x, y)| (xx + x * x, xy + x * y));
    let multiple = xy / xx;
    let misfit = (paths[a]
        .iter()
        .zip(&paths[b])
        .map(|(x, y)| (y - multiple * x).powi(2))
        .sum::<f64>()
        / paths[a].len() as f64)
        .sqrt();
    (misfit <= PROPORTION_MISFIT * excursion[b]).then_some((a, b, multiple))
}

/// What a motion between two still windows was.
enum Motion {
    /// No DoF left its position.
    None,
    /// One DoF moved to a new position (a structure move).
    Move(usize),
    /// Several DoFs moved.
    Transfer,
    /// One DoF (or several together, the one that moved most first) moved and came back.
    Excitation(Vec<usize>),
}

/// The motion over grid `[ms, me]`, told by each DoF's largest excursion from its start: DoFs that
/// moved less than `coupled_fraction` of the one that moved most only followed it (servo
/// compliance, reaction torques, ringing), and so do their changes of position at the end
/// (the sag of a compliant servo under a changed load). DoFs that moved more and all came back
/// were excited together (a plan's parallel limbs). Mimic DoFs (`config.mimic`) move with their
/// leaders and tell nothing of their own.
fn classify(
    timeline: &Timeline,
    dofs: &[String],
    ms: usize,
    me: usize,
    config: &IngestConfig,
) -> Motion {
    let own = |e: usize| !timeline.follows(e);
    // Excursions are compared with each other in the pattern's units: a slide's pattern runs
    // a tenth of a metre per radian (`IngestConfig::speed_scale`), so that a lift excited with
    // an arm's joint (6.8 mm against 0.07 rad) is excited, not following it.
    let unit: Vec<f64> = (0..timeline.theta.len())
        .map(|e| dofs.get(e).map_or(1.0, |d| 1.0 / config.speed_scale(d)))
        .collect();
    let excursion: Vec<f64> = timeline
        .theta
        .iter()
        .enumerate()
        .map(|(e, th)| {
            if !own(e) {
                return 0.0;
            }
            th[ms..=me]
                .iter()
                .fold(0.0f64, |m, q| m.max((q - th[ms]).abs()))
        })
        .collect();
    let Some(main) = (0..excursion.len())
        .max_by(|&a, &b| (excursion[a] * unit[a]).total_cmp(&(excursion[b] * unit[b])))
    else {
        return Motion::None;
    };
    if excursion.iter().all(|&x| x <= config.motion_threshold) {
        return Motion::None;
    }
    let largest = excursion[main] * unit[main];
    // DoF `e`, gone `x` (its own units), did not move, or only followed a DoF gone `of` (the
    // pattern's units).
    let followed = |e: usize, x: f64, of: f64| {
        x <= config.motion_threshold || x * unit[e] <= config.coupled_fraction * of
    };
    let net = |th: &[f64]| (th[me] - th[ms]).abs();
    let mut leading = vec![main];
    leading
        .extend((0..excursion.len()).filter(|&e| e != main && !followed(e, excursion[e], largest)));
    // A DoF came back when it ends nearer its start than its farthest point: a servo that lags
    // a pattern or sags under its changed load ends a few mrad off, a move ends where it went.
    let came_back = |e: usize| {
        net(&timeline.theta[e]) <= config.motion_threshold.max(RETURN_FRACTION * excursion[e])
    };
    // A pattern moves a DoF to one side of its pose and back (ringing aside): DoFs that went far
    // to both sides together followed a path (a continuous program's sweep), not patterns.
    let both_sides = |e: usize| {
        let th = &timeline.theta[e][ms..=me];
        let (up, down) = th.iter().fold((0.0f64, 0.0f64), |(u, d), q| {
            (u.max(q - th[0]), d.max(th[0] - q))
        });
        up.min(down)
            > config
                .motion_threshold
                .max(OTHER_SIDE_FRACTION * up.max(down))
    };
    if leading.len() > 1 && leading.iter().filter(|&&e| both_sides(e)).count() > 1 {
        return Motion::Transfer;
    }
    if leading.iter().all(|&e| came_back(e)) {
        return Motion::Excitation(leading);
    }
    if leading.len() > 1 {
        return Motion::Transfer;
    }
    let moved = net(&timeline.theta[main]) * unit[main];
    // A compliant servo's sag under a changed load is small in itself, not only beside the move:
    // a DoF that ends a tenth of a radian away was moved too.
    let sag = SAG_STEPS * config.motion_threshold;
    if timeline.theta.iter().enumerate().any(|(e, th)| {
        e != main && own(e) && !followed(e, net(th), moved.min(sag / config.coupled_fraction))
    }) {
        Motion::Transfer
    } else {
        Motion::Move(main)
    }
}

/// The nominal pattern from the measured motion of every excitation: the median peak speed is `A`,
/// the median peak acceleration `2πfA`.
pub(super) fn estimate_pattern(plans: &[Segmentation]) -> Option<(ExcitationPattern, String)> {
    let mut v: Vec<f64> = Vec::new();
    let mut a: Vec<f64> = Vec::new();
    for p in plans {
        for x in &p.excitations {
            v.push(x.peak_velocity);
            a.push(x.peak_acceleration);
        }
    }
    if v.is_empty() {
        return None;
    }
    let median = |x: &mut Vec<f64>| {
        x.sort_by(f64::total_cmp);
        x[x.len() / 2]
    };
    let (amplitude, peak) = (median(&mut v), median(&mut a));
    let pattern = ExcitationPattern {
        amplitude,
        frequency: peak / (2.0 * std::f64::consts::PI * amplitude),
    };
    pattern.is_valid().then(|| {
        (
            pattern,
            format!(
                "estimated from {} excitations (median peak speed and acceleration)",
                v.len()
            ),
        )
    })
}
