//! Charts drawn in the page by uPlot (inlined from `assets/uplot`, MIT): each chart is a
//! `<figure class="chart">` whose `data-chart` attribute holds its numbers as JSON ([`Chart`]);
//! one script draws them all. The numbers are therefore in the page's text, where a test or a
//! reader finds them, and a chart never splits across printed pages.

use maud::{html, Markup};
use serde::Serialize;

/// uPlot's script, drawn from the npm package `uplot@1.6.32`.
pub(super) const UPLOT_JS: &str = include_str!("../../assets/uplot/uPlot.iife.min.js");
/// uPlot's style sheet.
pub(super) const UPLOT_CSS: &str = include_str!("../../assets/uplot/uPlot.min.css");

/// How a series is drawn.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize)]
#[serde(rename_all = "snake_case")]
pub(super) enum Mark {
    /// Bars from zero.
    Bars,
    /// Points only.
    Points,
    /// A line through the values.
    Line,
    /// A dashed line (a reference: a bound, a noise floor, `y = x`).
    Dashed,
}

/// One series of a chart; `None` values are gaps (a quantity the data do not have).
#[derive(Debug, Clone, Serialize)]
pub(super) struct Series {
    pub name: String,
    pub mark: Mark,
    pub colour: &'static str,
    pub values: Vec<Option<f64>>,
}

impl Series {
    pub fn new(
        name: impl Into<String>,
        mark: Mark,
        colour: &'static str,
        values: Vec<f64>,
    ) -> Self {
        Self {
            name: name.into(),
            mark,
            colour,
            values: values.into_iter().map(Some).collect(),
        }
    }

    /// A constant reference line at `value` over `n` points.
    pub fn level(name: impl Into<String>, value: f64, n: usize) -> Self {
        Self::new(name, Mark::Dashed, "#000", vec![value; n])
    }
}

/// A chart over one x axis: either named categories (`labels`, one per x) or numbers (`x`).
#[derive(Debug, Clone, Serialize)]
pub(super) struct Chart {
    /// The x axis's title.
    pub x_title: String,
    /// The y axis's title.
    pub y_title: String,
    /// Category names, one per x (bars per SU); empty for a numeric x.
    #[serde(skip_serializing_if = "Vec::is_empty")]
    pub labels: Vec<String>,
    /// The x values (ascending) of a numeric x axis; empty for categories.
    #[serde(skip_serializing_if = "Vec::is_empty")]
    pub x: Vec<f64>,
    pub series: Vec<Series>,
}

impl Chart {
    /// A chart with one value per named category.
    pub fn categories(labels: Vec<String>, x_title: &str, y_title: &str) -> Self {
        Self {
            x_title: x_title.into(),
            y_title: y_title.into(),
            labels,
            x: Vec::new(),
            series: Vec::new(),
        }
    }

    /// A chart over numbers `x` (ascending).
    pub fn numeric(x: Vec<f64>, x_title: &str, y_title: &str) -> Self {
        Self {
            x_title: x_title.into(),
            y_title: y_title.into(),
            labels: Vec::new(),
            x,
            series: Vec::new(),
        }
    }

    pub fn with(mut self, series: Series) -> Self {
        self.series.push(series);
        self
    }

    /// The chart as a figure with its caption.
    pub fn figure(&self, caption: Markup) -> Markup {
        let spec = serde_json::to_string(self).unwrap_or_else(|_| "{}".into());
        html! {
            figure class="chart" {
                div class="plot" data-chart=(spec) {}
                figcaption { (caption) }
            }
        }
    }
}

/// The standard normal quantiles of `n` sorted samples (Blom's plotting positions
/// `(i − 3/8)/(n + 1/4)`), for a normal quantile plot.
pub(super) fn normal_quantiles(n: usize) -> Vec<f64> {
    use statrs::distribution::ContinuousCDF;
    let normal = statrs::distribution::Normal::standard();
    (0..n)
        .map(|i| normal.inverse_cdf((i as f64 + 0.625) / (n as f64 + 0.25)))
        .collect()
}

/// The script that draws every `.plot` of the page with uPlot.
pub(super) const DRAW: &str = r#"(function () {
  function pathsOf(mark) {
    if (mark === 'bars') { return uPlot.paths.bars({ size: [0.7, 40] }); }
    if (mark === 'points') { return function () { return null; }; }
    return undefined;
  }
  // Bars start at zero; points and lines span their values.
  function yRange(spec, fromZero) {
    var lo = Infinity, hi = -Infinity;
    spec.series.forEach(function (s) {
      s.values.forEach(function (v) { if (v !== null && isFinite(v)) { lo = Math.min(lo, v); hi = Math.max(hi, v); } });
    });
    if (!isFinite(lo)) { return [0, 1]; }
    if (fromZero) { lo = Math.min(0, lo); }
    var pad = (hi - lo) * 0.06 || Math.abs(hi) * 0.1 || 1;
    return [fromZero && lo === 0 ? 0 : lo - pad, hi + pad];
  }
  document.querySelectorAll('.plot').forEach(function (el) {
    var spec = JSON.parse(el.getAttribute('data-chart'));
    var categories = spec.labels && spec.labels.length;
    var n = categories ? spec.labels.length : spec.x.length;
    var xs = categories ? spec.labels.map(function (_, i) { return i; }) : spec.x;
    var many = categories && n > 40;
    var series = [{ label: spec.x_title, value: categories ? function (u, i) { return i == null ? '' : spec.labels[i]; } : undefined }];
    spec.series.forEach(function (s) {
      series.push({
        label: s.name, stroke: s.colour, width: s.mark === 'bars' ? 0 : 1.5,
        fill: s.mark === 'bars' ? s.colour : undefined,
        dash: s.mark === 'dashed' ? [6, 4] : undefined,
        paths: pathsOf(s.mark),
        points: { show: s.mark === 'points', size: 4, fill: s.colour, stroke: s.colour },
        spanGaps: false
      });
    });
    var width = Math.min(700, Math.max(360, categories ? 60 + 14 * n : 520));
    var bottom = categories ? (many ? 20 : Math.min(160, 12 + 6.5 * Math.max.apply(null, spec.labels.map(function (l) { return l.length; })))) : 40;
    var axes = [
      { label: spec.x_title, size: bottom,
        values: categories ? function (u, splits) { return splits.map(function (i) { return many ? '' : (spec.labels[i] === undefined ? '' : spec.labels[i]); }); } : undefined,
        splits: categories ? function () { return xs; } : undefined,
        rotate: categories && !many ? -90 : 0, gap: 2 },
      { label: spec.y_title, size: 60 }
    ];
    var opts = {
      width: width, height: 180 + bottom, series: series, axes: axes, legend: { live: true },
      scales: { x: { time: false, range: categories ? [-0.6, n - 0.4] : undefined }, y: { range: yRange(spec, spec.series.some(function (s) { return s.mark === 'bars'; })) } },
      cursor: { points: { show: false } }
    };
    var data = [xs].concat(spec.series.map(function (s) { return s.values; }));
    new uPlot(opts, data, el);
  });
  // How long the page took to draw itself, ms from the start of loading.
  document.documentElement.setAttribute('data-drawn-ms', performance.now().toFixed(0));
})();"#;
