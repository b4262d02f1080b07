//! Small SVG figures for docs/REPRODUCTION.md, drawn with `plotters` (SVG backend only).
//!
//! What it is: a handful of figure shapes (line panels, point panels, CWT heat maps), each a
//! grid of panels in one SVG file, with series decimated (min/max per bucket, so peaks survive)
//! and heat-map cells merged, to keep every file small. What it is not: a plotting library;
//! styles are fixed.

use crate::analysis::cwt::Cwt;
use anyhow::{anyhow, Result};
use plotters::coord::Shift;
use plotters::prelude::*;
use std::path::Path;

/// Colours for up to 6 series, in order.
pub const PALETTE: [RGBColor; 6] = [
    RGBColor(31, 119, 180),
    RGBColor(214, 39, 40),
    RGBColor(44, 160, 44),
    RGBColor(148, 103, 189),
    RGBColor(255, 127, 14),
    RGBColor(100, 100, 100),
];

fn pe<E: std::fmt::Display>(e: E) -> anyhow::Error {
    anyhow!("plotting: {e}")
}

/// One named series of (x, y) points.
#[derive(Debug, Clone)]
pub struct Series {
    pub label: String,
    pub points: Vec<(f64, f64)>,
}

impl Series {
    pub fn new(label: impl Into<String>, xs: &[f64], ys: &[f64]) -> Self {
        Self {
            label: label.into(),
            points: xs.iter().copied().zip(ys.iter().copied()).collect(),
        }
    }
}

/// How a panel draws its series.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Style {
    /// Lines (decimated to ~1200 points).
    Lines,
    /// Lines with a marker at every point (sweeps).
    LinesPoints,
    /// Dots only (Poincaré sections, phase portraits).
    Dots,
}

/// One panel: title, axis labels, series, style, and whether y is logarithmic.
#[derive(Debug, Clone)]
pub struct Panel {
    pub title: String,
    pub x_label: String,
    pub y_label: String,
    pub series: Vec<Series>,
    pub style: Style,
    pub log_y: bool,
}

impl Panel {
    pub fn new(title: impl Into<String>, x_label: &str, y_label: &str, style: Style) -> Self {
        Self {
            title: title.into(),
            x_label: x_label.into(),
            y_label: y_label.into(),
            series: Vec::new(),
            style,
            log_y: false,
        }
    }
    pub fn with(mut self, s: Series) -> Self {
        self.series.push(s);
        self
    }
    pub fn log_y(mut self) -> Self {
        self.log_y = true;
        self
    }
}

/// Keeps at most ~`max` points: per bucket, the first, the min and the max (in time order).
pub fn decimate(points: &[(f64, f64)], max: usize) -> Vec<(f64, f64)> {
    if points.len() <= max || max < 4 {
        return points.to_vec();
    }
    let buckets = max / 2;
    let size = points.len().div_ceil(buckets);
    let mut out = Vec::with_capacity(2 * buckets + 1);
    for chunk in points.chunks(size) {
        let (mut lo, mut hi) = (0usize, 0usize);
        for (i, p) in chunk.iter().enumerate() {
            if p.1 < chunk[lo].1 {
                lo = i;
            }
            if p.1 > chunk[hi].1 {
                hi = i;
            }
        }
        let (a, b) = if lo <= hi { (lo, hi) } else { (hi, lo) };
        out.push(chunk[a]);
        if b != a {
            out.push(chunk[b]);
        }
    }
    out
}

fn range(series: &[Series], log_y: bool) -> ((f64, f64), (f64, f64)) {
    let mut x = (f64::INFINITY, f64::NEG_INFINITY);
    let mut y = (f64::INFINITY, f64::NEG_INFINITY);
    for s in series {
        for &(a, b) in &s.points {
            if !(a.is_finite() && b.is_finite()) || (log_y && b <= 0.0) {
                continue;
            }
            x = (x.0.min(a), x.1.max(a));
            y = (y.0.min(b), y.1.max(b));
        }
    }
    if !x.0.is_finite() {
        x = (0.0, 1.0);
        y = if log_y { (1e-3, 1.0) } else { (0.0, 1.0) };
    }
    if x.1 <= x.0 {
        x = (x.0 - 0.5, x.0 + 0.5);
    }
    if log_y {
        if y.1 <= y.0 {
            y = (y.0 / 2.0, y.0 * 2.0);
        }
        y = (y.0 / 1.5, y.1 * 1.5);
    } else {
        let pad = if y.1 > y.0 {
            0.06 * (y.1 - y.0)
        } else {
            0.5 * y.0.abs().max(1e-12)
        };
        y = (y.0 - pad, y.1 + pad);
    }
    (x, y)
}

fn draw_panel(area: &DrawingArea<SVGBackend, Shift>, p: &Panel) -> Result<()> {
    let ((x0, x1), (y0, y1)) = range(&p.series, p.log_y);
    let mut b = ChartBuilder::on(area);
    b.caption(&p.title, ("sans-serif", 14))
        .margin(6)
        .x_label_area_size(32)
        .y_label_area_size(56);
    macro_rules! body {
        ($chart:ident) => {{
            $chart
                .configure_mesh()
                .x_desc(p.x_label.as_str())
                .y_desc(p.y_label.as_str())
                .x_labels(6)
                .y_labels(6)
                .light_line_style(WHITE)
                .label_style(("sans-serif", 11))
                .draw()
                .map_err(pe)?;
            for (i, s) in p.series.iter().enumerate() {
                let c = PALETTE[i % PALETTE.len()];
                let pts: Vec<(f64, f64)> = s
                    .points
                    .iter()
                    .copied()
                    .filter(|(a, b)| a.is_finite() && b.is_finite() && (!p.log_y || *b > 0.0))
                    .collect();
                let anno = match p.style {
                    Style::Lines => $chart
                        .draw_series(LineSeries::new(decimate(&pts, 1200), c.stroke_width(1)))
                        .map_err(pe)?,
                    Style::LinesPoints => {
                        $chart
                            .draw_series(LineSeries::new(pts.clone(), c.stroke_width(1)))
                            .map_err(pe)?;
                        $chart
                            .draw_series(pts.iter().map(|&q| Circle::new(q, 3, c.filled())))
                            .map_err(pe)?
                    }
                    Style::Dots => $chart
                        .draw_series(pts.iter().map(|&q| Circle::new(q, 2, c.filled())))
                        .map_err(pe)?,
                };
                if !s.label.is_empty() {
                    anno.label(s.label.as_str()).legend(move |(x, y)| {
                        PathElement::new(vec![(x, y), (x + 16, y)], c.stroke_width(2))
                    });
                }
            }
            if p.series.iter().any(|s| !s.label.is_empty()) {
                $chart
                    .configure_series_labels()
                    .position(SeriesLabelPosition::UpperRight)
                    .background_style(WHITE.mix(0.85))
                    .border_style(BLACK.mix(0.3))
                    .label_font(("sans-serif", 11))
                    .draw()
                    .map_err(pe)?;
            }
        }};
    }
    if p.log_y {
        let mut chart = b
            .build_cartesian_2d(x0..x1, (y0..y1).log_scale())
            .map_err(pe)?;
        body!(chart);
    } else {
        let mut chart = b.build_cartesian_2d(x0..x1, y0..y1).map_err(pe)?;
        body!(chart);
    }
    Ok(())
}

/// Writes `panels` as a `rows × cols` grid into an SVG at `path`, each panel `panel_px` big.
pub fn figure(
    path: &Path,
    rows: usize,
    cols: usize,
    panel_px: (u32, u32),
    panels: &[Panel],
) -> Result<()> {
    let size = (panel_px.0 * cols as u32, panel_px.1 * rows as u32);
    let root = SVGBackend::new(path, size).into_drawing_area();
    root.fill(&WHITE).map_err(pe)?;
    let areas = root.split_evenly((rows, cols));
    for (area, p) in areas.iter().zip(panels) {
        draw_panel(area, p)?;
    }
    root.present().map_err(pe)?;
    Ok(())
}

/// A perceptually ordered colour ramp (dark blue → teal → yellow), `t ∈ [0, 1]`.
fn ramp(t: f64) -> RGBColor {
    const STOPS: [(f64, (f64, f64, f64)); 5] = [
        (0.0, (255.0, 255.0, 255.0)),
        (0.25, (65.0, 68.0, 135.0)),
        (0.5, (42.0, 120.0, 142.0)),
        (0.75, (34.0, 168.0, 132.0)),
        (1.0, (253.0, 231.0, 37.0)),
    ];
    let t = t.clamp(0.0, 1.0);
    for w in STOPS.windows(2) {
        let ((t0, c0), (t1, c1)) = (w[0], w[1]);
        if t <= t1 {
            let u = (t - t0) / (t1 - t0);
            let m = |a: f64, b: f64| (a + u * (b - a)).round() as u8;
            return RGBColor(m(c0.0, c1.0), m(c0.1, c1.1), m(c0.2, c1.2));
        }
    }
    RGBColor(253, 231, 37)
}

/// CWT amplitude maps, one panel each, frequency on a log axis, each normalised to its own
/// maximum and quantised to `levels` colours (cells of equal colour are merged).
pub fn cwt_figure(
    path: &Path,
    rows: usize,
    cols: usize,
    panel_px: (u32, u32),
    maps: &[(String, &Cwt)],
    levels: usize,
) -> Result<()> {
    let size = (panel_px.0 * cols as u32, panel_px.1 * rows as u32);
    let root = SVGBackend::new(path, size).into_drawing_area();
    root.fill(&WHITE).map_err(pe)?;
    let areas = root.split_evenly((rows, cols));
    for (area, (title, w)) in areas.iter().zip(maps) {
        let nf = w.freqs_hz.len();
        let nt = w.n_times();
        if nf < 2 || nt < 2 {
            continue;
        }
        let (t0, t1) = (w.times_s[0], w.times_s[nt - 1]);
        let f_edge = |i: usize| -> f64 {
            // Geometric midpoints between rows; outer edges extrapolated.
            if i == 0 {
                w.freqs_hz[0] * (w.freqs_hz[0] / w.freqs_hz[1]).sqrt()
            } else if i == nf {
                w.freqs_hz[nf - 1] * (w.freqs_hz[nf - 1] / w.freqs_hz[nf - 2]).sqrt()
            } else {
                (w.freqs_hz[i - 1] * w.freqs_hz[i]).sqrt()
            }
        };
        let mut chart = ChartBuilder::on(area)
            .caption(title.as_str(), ("sans-serif", 14))
            .margin(6)
            .x_label_area_size(32)
            .y_label_area_size(50)
            .build_cartesian_2d(t0..t1, (f_edge(0)..f_edge(nf)).log_scale())
            .map_err(pe)?;
        chart
            .configure_mesh()
            .disable_mesh()
            .x_desc("t (s)")
            .y_desc("f (Hz)")
            .label_style(("sans-serif", 11))
            .draw()
            .map_err(pe)?;
        let max = w.amp.iter().fold(0.0f64, |m, v| m.max(*v));
        if max <= 0.0 {
            continue;
        }
        let dt = (t1 - t0) / (nt - 1) as f64;
        let level = |v: f64| ((v / max) * levels as f64).floor().min(levels as f64 - 1.0) as usize;
        let mut rects = Vec::new();
        for i in 0..nf {
            let mut j = 0;
            while j < nt {
                let l = level(w.at(i, j));
                let mut k = j + 1;
                while k < nt && level(w.at(i, k)) == l {
                    k += 1;
                }
                if l > 0 {
                    let c = ramp((l as f64 + 0.5) / levels as f64);
                    let xa = (t0 + (j as f64 - 0.5) * dt).max(t0);
                    let xb = (t0 + (k as f64 - 0.5) * dt).min(t1);
                    rects.push(Rectangle::new(
                        [(xa, f_edge(i)), (xb, f_edge(i + 1))],
                        c.filled(),
                    ));
                }
                j = k;
            }
        }
        chart.draw_series(rects).map_err(pe)?;
    }
    root.present().map_err(pe)?;
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn decimation_keeps_extremes_and_bounds_size() {
        let pts: Vec<(f64, f64)> = (0..10_000)
            .map(|i| (i as f64, ((i * 37) % 101) as f64))
            .collect();
        let d = decimate(&pts, 500);
        assert!(d.len() <= 520);
        let max = d.iter().fold(f64::MIN, |m, p| m.max(p.1));
        let min = d.iter().fold(f64::MAX, |m, p| m.min(p.1));
        assert_eq!((min, max), (0.0, 100.0));
        assert!(d.windows(2).all(|w| w[1].0 > w[0].0));
    }
}
