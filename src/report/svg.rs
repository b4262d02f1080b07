//! Tiny hand-written SVG line charts for the workshop report: axes with ticks, polylines, a
//! shaded band, labelled horizontal reference lines. Output is a self-contained `<svg>` string
//! (no scripts, no external fonts or images).
//!
//! What it is not: a plotting library; just enough for three chart kinds.

use std::fmt::Write;

pub struct Chart {
    pub w: f64,
    pub h: f64,
    pub x: (f64, f64),
    pub y: (f64, f64),
    pub x_label: String,
    pub y_label: String,
    pub title: String,
    body: String,
}

const ML: f64 = 62.0;
const MR: f64 = 16.0;
const MT: f64 = 28.0;
const MB: f64 = 44.0;

fn esc(s: &str) -> String {
    s.replace('&', "&amp;")
        .replace('<', "&lt;")
        .replace('>', "&gt;")
}

/// "Nice" tick step for a span.
fn step(span: f64, n: f64) -> f64 {
    let raw = (span / n).max(1e-12);
    let mag = 10f64.powf(raw.log10().floor());
    let f = raw / mag;
    let nice = if f < 1.5 {
        1.0
    } else if f < 3.0 {
        2.0
    } else if f < 7.0 {
        5.0
    } else {
        10.0
    };
    nice * mag
}

fn fmt_tick(v: f64, step: f64) -> String {
    let decimals = (-step.log10().floor()).max(0.0) as usize;
    // Adding 0.0 turns -0.0 into 0.0 so no tick reads "-0".
    let v = if v.abs() < step * 1e-6 { 0.0 } else { v } + 0.0;
    format!("{v:.decimals$}")
}

impl Chart {
    pub fn new(title: &str, x_label: &str, y_label: &str, x: (f64, f64), y: (f64, f64)) -> Chart {
        let fix = |(a, b): (f64, f64)| {
            if !(a.is_finite() && b.is_finite()) {
                (0.0, 1.0)
            } else if b - a <= 1e-12 {
                (a - 0.5, b + 0.5)
            } else {
                (a, b)
            }
        };
        Chart {
            w: 470.0,
            h: 250.0,
            x: fix(x),
            y: fix(y),
            x_label: x_label.into(),
            y_label: y_label.into(),
            title: title.into(),
            body: String::new(),
        }
    }

    fn px(&self, x: f64) -> f64 {
        ML + (x - self.x.0) / (self.x.1 - self.x.0) * (self.w - ML - MR)
    }

    fn py(&self, y: f64) -> f64 {
        let y = y.clamp(self.y.0, self.y.1);
        self.h - MB - (y - self.y.0) / (self.y.1 - self.y.0) * (self.h - MT - MB)
    }

    pub fn line(&mut self, pts: &[(f64, f64)], color: &str, width: f64) {
        if pts.is_empty() {
            return;
        }
        let mut d = String::new();
        for &(x, y) in pts {
            let _ = write!(d, "{:.1},{:.1} ", self.px(x), self.py(y));
        }
        let _ = write!(
            self.body,
            r#"<polyline fill="none" stroke="{color}" stroke-width="{width}" points="{d}"/>"#
        );
    }

    pub fn points(&mut self, pts: &[(f64, f64)], color: &str) {
        for &(x, y) in pts {
            let _ = write!(
                self.body,
                r#"<circle cx="{:.1}" cy="{:.1}" r="3.5" fill="{color}"/>"#,
                self.px(x),
                self.py(y)
            );
        }
    }

    /// Shaded band between `lo` and `hi` at the same x.
    pub fn band(&mut self, pts: &[(f64, f64, f64)], color: &str) {
        if pts.len() < 2 {
            for &(x, lo, hi) in pts {
                let _ = write!(
                    self.body,
                    r#"<line x1="{x:.1}" x2="{x:.1}" y1="{:.1}" y2="{:.1}" stroke="{color}" stroke-width="6"/>"#,
                    self.py(lo),
                    self.py(hi),
                    x = self.px(x)
                );
            }
            return;
        }
        let mut d = String::new();
        for &(x, _, hi) in pts {
            let _ = write!(d, "{:.1},{:.1} ", self.px(x), self.py(hi));
        }
        for &(x, lo, _) in pts.iter().rev() {
            let _ = write!(d, "{:.1},{:.1} ", self.px(x), self.py(lo));
        }
        let _ = write!(
            self.body,
            r#"<polygon fill="{color}" stroke="none" points="{d}"/>"#
        );
    }

    /// A dashed horizontal line at `y` with its label above the line's right end.
    pub fn hline(&mut self, y: f64, color: &str, label: &str) {
        self.hline_labelled(y, color, label, false);
    }

    /// [`Self::hline`] with the label above (`below = false`) or below the line, so two close
    /// lines keep readable labels.
    pub fn hline_labelled(&mut self, y: f64, color: &str, label: &str, below: bool) {
        let py = self.py(y);
        let _ = write!(
            self.body,
            r#"<line x1="{ml}" x2="{xr:.1}" y1="{py:.1}" y2="{py:.1}" stroke="{color}" stroke-width="1.5" stroke-dasharray="6 4"/><text x="{tx:.1}" y="{ty:.1}" fill="{color}" font-size="11" text-anchor="end">{l}</text>"#,
            ml = ML,
            xr = self.w - MR,
            tx = self.w - MR - 2.0,
            ty = if below { py + 12.0 } else { py - 4.0 },
            l = esc(label)
        );
    }

    pub fn vline(&mut self, x: f64, color: &str) {
        let px = self.px(x);
        let _ = write!(
            self.body,
            r#"<line x1="{px:.1}" x2="{px:.1}" y1="{mt}" y2="{yb:.1}" stroke="{color}" stroke-width="1" stroke-dasharray="3 3"/>"#,
            mt = MT,
            yb = self.h - MB
        );
    }

    pub fn render(&self) -> String {
        let mut s = String::new();
        let _ = write!(
            s,
            r#"<svg xmlns="http://www.w3.org/2000/svg" width="{w}" height="{h}" viewBox="0 0 {w} {h}" font-family="sans-serif" role="img"><title>{t}</title><rect width="100%" height="100%" fill="white"/>"#,
            w = self.w,
            h = self.h,
            t = esc(&self.title)
        );
        let _ = write!(
            s,
            r#"<text x="{ml}" y="18" font-size="13" font-weight="bold">{t}</text>"#,
            ml = ML,
            t = esc(&self.title)
        );
        // Grid and ticks.
        let xs = step(self.x.1 - self.x.0, 6.0);
        let mut v = (self.x.0 / xs).ceil() * xs;
        while v <= self.x.1 + xs * 1e-6 {
            let px = self.px(v);
            let _ = write!(
                s,
                r##"<line x1="{px:.1}" x2="{px:.1}" y1="{mt}" y2="{yb:.1}" stroke="#e4e4e4"/><text x="{px:.1}" y="{ty:.1}" font-size="11" text-anchor="middle">{l}</text>"##,
                mt = MT,
                yb = self.h - MB,
                ty = self.h - MB + 15.0,
                l = fmt_tick(v, xs)
            );
            v += xs;
        }
        let ys = step(self.y.1 - self.y.0, 5.0);
        let mut v = (self.y.0 / ys).ceil() * ys;
        while v <= self.y.1 + ys * 1e-6 {
            let py = self.py(v);
            let _ = write!(
                s,
                r##"<line x1="{ml}" x2="{xr:.1}" y1="{py:.1}" y2="{py:.1}" stroke="#e4e4e4"/><text x="{tx}" y="{ty:.1}" font-size="11" text-anchor="end">{l}</text>"##,
                ml = ML,
                xr = self.w - MR,
                tx = ML - 5.0,
                ty = py + 4.0,
                l = fmt_tick(v, ys)
            );
            v += ys;
        }
        let _ = write!(
            s,
            r##"<rect x="{ml}" y="{mt}" width="{pw:.1}" height="{ph:.1}" fill="none" stroke="#888"/>"##,
            ml = ML,
            mt = MT,
            pw = self.w - ML - MR,
            ph = self.h - MT - MB
        );
        s.push_str(&self.body);
        let _ = write!(
            s,
            r#"<text x="{cx:.1}" y="{by:.1}" font-size="12" text-anchor="middle">{xl}</text><text transform="translate(14 {cy:.1}) rotate(-90)" font-size="12" text-anchor="middle">{yl}</text></svg>"#,
            cx = ML + (self.w - ML - MR) / 2.0,
            by = self.h - 8.0,
            xl = esc(&self.x_label),
            cy = MT + (self.h - MT - MB) / 2.0,
            yl = esc(&self.y_label)
        );
        s
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn renders_balanced_svg_with_escaped_text() {
        let mut c = Chart::new("a < b", "x", "y", (0.0, 10.0), (0.0, 0.2));
        c.line(&[(0.0, 0.0), (10.0, 0.1)], "blue", 1.5);
        c.hline(0.1, "red", "0.1 mm");
        let s = c.render();
        assert!(s.starts_with("<svg") && s.ends_with("</svg>"));
        assert!(s.contains("a &lt; b"));
        assert!(s.contains("<polyline"));
        assert_eq!(s.matches("<svg").count(), 1);
    }
}
