//! Tools that tell periodic from irregular motion: Poincaré sections and the finite-time
//! largest Lyapunov exponent from twin runs (MODEL.md §11).
//!
//! What it is: generic routines on sampled trajectories. A Poincaré section is the set of
//! states where a chosen scalar `g(t)` (e.g. θ1') crosses a level in a chosen direction,
//! linearly interpolated between samples. The Lyapunov estimate follows MODEL.md §11: two runs
//! that differ only by a tiny perturbation (relative 1e-9 on θ1'(0)) and share their noise; the
//! slope of `ln‖Δ(t)‖` of the scaled state difference is fitted by least squares over a window
//! (0.8–3 s), cut where the separation saturates. [`lyapunov_twin_runs`] takes a closure that
//! runs the system, so it works with any model.
//!
//! What it is not: a proof of chaos. A positive finite-time exponent over 2 s of a noisy,
//! decelerating (non-autonomous) system says nearby trajectories separate, not that an
//! attractor is strange; the reproduction reports it as exactly that.

use super::AnalysisError;

/// Which sign change of `g − level` counts as a crossing.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Direction {
    /// From below to above (g rising).
    Up,
    /// From above to below (g falling); with g = x' this picks the maxima of x.
    Down,
    /// Either.
    Both,
}

/// A crossing between samples `index` and `index + 1`, at the fraction `frac ∈ [0, 1)` of the
/// way (linear interpolation of g).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Crossing {
    pub index: usize,
    pub frac: f64,
}

impl Crossing {
    /// The value of another series sampled like g, interpolated at the crossing. Returns NaN when
    /// `x` is too short (a caller mixing series of unequal length).
    pub fn at(&self, x: &[f64]) -> f64 {
        match (x.get(self.index), x.get(self.index + 1)) {
            (Some(a), Some(b)) => a + self.frac * (b - a),
            (Some(a), None) if self.frac == 0.0 => *a,
            _ => f64::NAN,
        }
    }
}

/// All crossings of `g` through `level` in direction `dir`. A sample exactly at the level
/// counts once (at that sample). Non-finite samples break the series: no crossing is reported
/// across them.
pub fn crossings(g: &[f64], level: f64, dir: Direction) -> Vec<Crossing> {
    let mut out = Vec::new();
    for i in 0..g.len().saturating_sub(1) {
        let (a, b) = (g[i] - level, g[i + 1] - level);
        if !(a.is_finite() && b.is_finite()) {
            continue;
        }
        let up = a < 0.0 && b >= 0.0;
        let down = a > 0.0 && b <= 0.0;
        let hit = match dir {
            Direction::Up => up,
            Direction::Down => down,
            Direction::Both => up || down,
        };
        if hit {
            let frac = a / (a - b);
            // A crossing exactly at sample i+1 is reported as (i+1, 0) so it is not lost or
            // doubled when the next interval starts there.
            if frac >= 1.0 {
                out.push(Crossing {
                    index: i + 1,
                    frac: 0.0,
                });
            } else {
                out.push(Crossing { index: i, frac });
            }
        }
    }
    out
}

/// Poincaré section: for each crossing of `g` through `level` in `dir`, the interpolated values
/// of `coords` (one series per coordinate, all sampled like g). Points whose coordinates fail
/// `keep` are dropped (e.g. `|p| p[0] > 0.0` for "θ1 > 0").
pub fn poincare_section(
    g: &[f64],
    level: f64,
    dir: Direction,
    coords: &[&[f64]],
    keep: impl Fn(&[f64]) -> bool,
) -> Vec<Vec<f64>> {
    crossings(g, level, dir)
        .into_iter()
        .map(|c| coords.iter().map(|x| c.at(x)).collect::<Vec<f64>>())
        .filter(|p| p.iter().all(|v| v.is_finite()) && keep(p))
        .collect()
}

/// Number of distinct points in a section: points closer than `tol` (Euclidean) to an earlier
/// cluster's first point join that cluster. A period-k orbit gives k; a quasi-periodic or
/// chaotic one gives many.
pub fn count_distinct(points: &[Vec<f64>], tol: f64) -> usize {
    let mut reps: Vec<&Vec<f64>> = Vec::new();
    for p in points {
        let near = reps.iter().any(|r| {
            r.iter()
                .zip(p.iter())
                .map(|(a, b)| (a - b) * (a - b))
                .sum::<f64>()
                .sqrt()
                <= tol
        });
        if !near {
            reps.push(p);
        }
    }
    reps.len()
}

/// Options of the finite-time Lyapunov fit (MODEL.md §11 defaults via `Default`).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct LyapunovOptions {
    /// Fit window start (s).
    pub t_start: f64,
    /// Fit window end (s), unless saturation comes first.
    pub t_end: f64,
    /// Separation (in scaled units) at which growth is taken to have saturated; the fit stops
    /// at the first sample reaching it.
    pub saturation: f64,
    /// Fewest samples a fit may use.
    pub min_points: usize,
    /// Shortest fitted span (same unit as t). When the separation saturates sooner after
    /// `t_start` than this, the exponent is instead the mean growth rate from the first sample
    /// to saturation (see [`LyapunovFit::early`]).
    pub min_span: f64,
}

impl Default for LyapunovOptions {
    fn default() -> Self {
        Self {
            t_start: 0.8,
            t_end: 3.0,
            saturation: 0.1,
            min_points: 10,
            min_span: 0.3,
        }
    }
}

/// Result of a finite-time Lyapunov fit.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct LyapunovFit {
    /// Fitted slope of ln‖Δ‖ (1/s, or 1/iteration for maps).
    pub lambda: f64,
    /// Time span actually fitted.
    pub t_from: f64,
    pub t_to: f64,
    /// Samples in the fit.
    pub points: usize,
    /// Coefficient of determination of the straight-line fit.
    pub r2: f64,
    /// When the separation reached the saturation level, if it did inside the window.
    pub saturated_at: Option<f64>,
    /// The separation saturated before the window held `min_span` of growth, so `lambda` is
    /// the mean growth rate `(ln sat − ln‖Δ(t0)‖) / (t_sat − t0)` from the first sample t0 to
    /// saturation (a finite-time exponent over that earlier span); `r2` is NaN then.
    pub early: bool,
}

/// Per-component scales for the state difference: the RMS of each component of the reference
/// run (components with zero RMS get scale 1, so they still count).
pub fn rms_scales(reference: &[&[f64]]) -> Vec<f64> {
    reference
        .iter()
        .map(|x| {
            let r = super::rms(x);
            if r > 0.0 && r.is_finite() {
                r
            } else {
                1.0
            }
        })
        .collect()
}

/// `ln‖Δ‖` per sample, with `Δ_i = (a_i − b_i) / scale_i` over the components. Zero separation
/// gives `-inf`.
pub fn log_separation(
    a: &[&[f64]],
    b: &[&[f64]],
    scales: &[f64],
) -> Result<Vec<f64>, AnalysisError> {
    if a.len() != b.len() || a.len() != scales.len() || a.is_empty() {
        return Err(AnalysisError::BadParameter(format!(
            "twin runs need equal component counts and scales (got {}, {}, {})",
            a.len(),
            b.len(),
            scales.len()
        )));
    }
    let n = a[0].len();
    if a.iter().chain(b.iter()).any(|x| x.len() != n) {
        return Err(AnalysisError::BadParameter(
            "twin-run components differ in length".into(),
        ));
    }
    Ok((0..n)
        .map(|k| {
            let d2: f64 = (0..a.len())
                .map(|c| {
                    let d = (a[c][k] - b[c][k]) / scales[c];
                    d * d
                })
                .sum();
            0.5 * d2.ln()
        })
        .collect())
}

/// Fit the finite-time largest Lyapunov exponent to `ln‖Δ‖` sampled at times `t`: least
/// squares over `[t_start, t_end]` up to saturation, or, when saturation comes within
/// `min_span` of `t_start`, the mean growth rate up to saturation ([`LyapunovFit::early`]).
pub fn fit_log_separation(
    t: &[f64],
    ln_d: &[f64],
    opts: &LyapunovOptions,
) -> Result<LyapunovFit, AnalysisError> {
    let windowed = fit_window(t, ln_d, opts);
    let short = match &windowed {
        Ok(f) => f.saturated_at.is_some() && f.t_to - f.t_from < opts.min_span,
        Err(_) => true,
    };
    if !short {
        return windowed;
    }
    let ln_sat = opts.saturation.ln();
    let first = t.iter().zip(ln_d).position(|(_, y)| y.is_finite());
    let sat = t
        .iter()
        .zip(ln_d)
        .position(|(ti, y)| *y >= ln_sat && *ti <= opts.t_start + opts.min_span);
    match (first, sat) {
        (Some(k0), Some(ks)) if ks > k0 && t[ks] > t[k0] => Ok(LyapunovFit {
            lambda: (ln_sat - ln_d[k0]) / (t[ks] - t[k0]),
            t_from: t[k0],
            t_to: t[ks],
            points: 2,
            r2: f64::NAN,
            saturated_at: Some(t[ks]),
            early: true,
        }),
        _ => windowed,
    }
}

fn fit_window(
    t: &[f64],
    ln_d: &[f64],
    opts: &LyapunovOptions,
) -> Result<LyapunovFit, AnalysisError> {
    if t.len() != ln_d.len() {
        return Err(AnalysisError::BadParameter(
            "time and separation lengths differ".into(),
        ));
    }
    let ln_sat = opts.saturation.ln();
    let mut saturated_at = None;
    let (mut sx, mut sy, mut sxx, mut sxy, mut syy, mut m) = (0.0, 0.0, 0.0, 0.0, 0.0, 0usize);
    let (mut t_from, mut t_to) = (f64::NAN, f64::NAN);
    for (&ti, &yi) in t.iter().zip(ln_d) {
        if ti < opts.t_start {
            continue;
        }
        if ti > opts.t_end {
            break;
        }
        if yi >= ln_sat {
            saturated_at = Some(ti);
            break;
        }
        if !yi.is_finite() {
            // Twins identical to machine precision at this sample: no information.
            continue;
        }
        if m == 0 {
            t_from = ti;
        }
        t_to = ti;
        sx += ti;
        sy += yi;
        sxx += ti * ti;
        sxy += ti * yi;
        syy += yi * yi;
        m += 1;
    }
    if m < opts.min_points.max(2) {
        return Err(AnalysisError::TooShort(format!(
            "Lyapunov fit over {}..{} s has {m} usable samples (need {}){}",
            opts.t_start,
            opts.t_end,
            opts.min_points.max(2),
            if saturated_at.is_some() {
                "; the separation saturated early"
            } else {
                ""
            }
        )));
    }
    let mf = m as f64;
    let cov = sxy - sx * sy / mf;
    let varx = sxx - sx * sx / mf;
    let vary = syy - sy * sy / mf;
    if !(varx > 0.0) {
        return Err(AnalysisError::TooShort(
            "Lyapunov fit window spans no time".into(),
        ));
    }
    let lambda = cov / varx;
    let r2 = if vary > 0.0 {
        cov * cov / (varx * vary)
    } else {
        1.0
    };
    Ok(LyapunovFit {
        lambda,
        t_from,
        t_to,
        points: m,
        r2,
        saturated_at,
        early: false,
    })
}

/// Finite-time largest Lyapunov exponent from two sampled trajectories of the same system
/// (components `a` and `b`, sampled at `t`): scale each component by `scales` (e.g.
/// [`rms_scales`] of `a`), then [`fit_log_separation`].
pub fn lyapunov_from_twins(
    t: &[f64],
    a: &[&[f64]],
    b: &[&[f64]],
    scales: &[f64],
    opts: &LyapunovOptions,
) -> Result<LyapunovFit, AnalysisError> {
    fit_log_separation(t, &log_separation(a, b, scales)?, opts)
}

/// A sampled trajectory as the Lyapunov routines need it: times and state components.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct Trajectory {
    pub t: Vec<f64>,
    pub components: Vec<Vec<f64>>,
}

/// MODEL.md §11 twin-run recipe around any simulator: `run(eps)` must run the system with the
/// initial condition perturbed by the relative amount `eps` (0 for the reference) and the SAME
/// noise, returning the trajectory of the state components to compare (for the shimmy model:
/// θ1, θ2, θ1', θ2', X, X'). Scales are the reference run's RMS over the fit window.
pub fn lyapunov_twin_runs<E>(
    run: impl Fn(f64) -> Result<Trajectory, E>,
    rel_eps: f64,
    opts: &LyapunovOptions,
) -> Result<LyapunovFit, E>
where
    E: From<AnalysisError>,
{
    let a = run(0.0)?;
    let b = run(rel_eps)?;
    let window: Vec<usize> =
        a.t.iter()
            .enumerate()
            .filter(|(_, t)| **t >= opts.t_start && **t <= opts.t_end)
            .map(|(i, _)| i)
            .collect();
    let scales: Vec<f64> = match (window.first(), window.last()) {
        (Some(&i0), Some(&i1)) => {
            let comps: Vec<&[f64]> = a
                .components
                .iter()
                .map(|c| &c[i0..=i1.min(c.len() - 1)])
                .collect();
            rms_scales(&comps)
        }
        _ => vec![1.0; a.components.len()],
    };
    let ar: Vec<&[f64]> = a.components.iter().map(|c| c.as_slice()).collect();
    let br: Vec<&[f64]> = b.components.iter().map(|c| c.as_slice()).collect();
    Ok(lyapunov_from_twins(&a.t, &ar, &br, &scales, opts)?)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn crossing_exactly_on_a_sample_counts_once() {
        let g = [-1.0, 0.0, 1.0, 0.0, -1.0];
        let up = crossings(&g, 0.0, Direction::Up);
        assert_eq!(
            up,
            vec![Crossing {
                index: 1,
                frac: 0.0
            }]
        );
        let down = crossings(&g, 0.0, Direction::Down);
        assert_eq!(
            down,
            vec![Crossing {
                index: 3,
                frac: 0.0
            }]
        );
        assert_eq!(crossings(&g, 0.0, Direction::Both).len(), 2);
    }

    #[test]
    fn interpolates_other_coordinates() {
        let g = [1.0, -1.0];
        let c = crossings(&g, 0.0, Direction::Down);
        assert_eq!(c.len(), 1);
        assert!((c[0].at(&[10.0, 20.0]) - 15.0).abs() < 1e-12);
        assert!(c[0].at(&[10.0]).is_nan());
    }

    #[test]
    fn nan_breaks_the_series() {
        assert!(crossings(&[-1.0, f64::NAN, 1.0], 0.0, Direction::Both).is_empty());
    }

    #[test]
    fn mismatched_twins_are_errors() {
        let a = [1.0, 2.0];
        let b = [1.0];
        assert!(log_separation(&[&a], &[&b], &[1.0]).is_err());
        assert!(log_separation(&[&a], &[&a], &[]).is_err());
    }

    #[test]
    fn fit_recovers_a_straight_line_and_stops_at_saturation() {
        let t: Vec<f64> = (0..400).map(|i| i as f64 * 0.01).collect();
        let y: Vec<f64> = t.iter().map(|t| -20.0 + 7.0 * t).collect();
        let opts = LyapunovOptions::default();
        let fit = fit_log_separation(&t, &y, &opts).unwrap();
        assert!((fit.lambda - 7.0).abs() < 1e-9);
        assert!(fit.r2 > 0.999_999);
        // ln(0.1) = -2.30 is reached at t = 2.53 s.
        let sat = fit.saturated_at.unwrap();
        assert!((sat - 2.53).abs() < 0.011, "{sat}");
        assert!(fit.t_to < sat);
        assert!(!fit.early);
    }

    #[test]
    fn early_saturation_falls_back_to_growth_rate_from_the_start() {
        // ln‖Δ‖ = -20 + 25 t reaches ln 0.1 at t = 0.708 s, before the 0.8 s window opens.
        let t: Vec<f64> = (0..400).map(|i| i as f64 * 0.01).collect();
        let y: Vec<f64> = t.iter().map(|t| (-20.0 + 25.0 * t).min(-1.0)).collect();
        let fit = fit_log_separation(&t, &y, &LyapunovOptions::default()).unwrap();
        assert!(fit.early);
        assert!((fit.lambda - 25.0).abs() < 1.0, "{}", fit.lambda);
        assert!(fit.r2.is_nan());
    }
}
