//! The figures of docs/REPRODUCTION.md, one SVG per topic, from the reproduction's results.
//!
//! What it is: data selection (which run, which window, which unit) for each figure; drawing
//! is in `plot`. What it is not: analysis — numbers in the text come from `report`.

use super::plan::V_REF;
use super::plot::{cwt_figure, figure, Panel, Series, Style};
use super::runs::{Case, Outcome, Variant};
use super::Results;
use crate::analysis::spectrum::welch;
use crate::model::JointMode;
use anyhow::Result;
use std::path::Path;

const DEG: f64 = 180.0 / std::f64::consts::PI;

/// A written figure: file name (relative to the figure folder) and caption.
#[derive(Debug, Clone)]
pub struct Figure {
    pub key: &'static str,
    pub file: String,
    pub caption: String,
}

/// The standard case (0.5 g, default vehicle, h = 1e-4, automatic duration) of a clearance,
/// speed and joint mode, any seed.
pub fn standard(c_mm: f64, v_kmh: f64, joints: JointMode) -> impl Fn(&Case) -> bool {
    move |c: &Case| {
        c.clearance_mm == c_mm
            && c.v0_kmh == v_kmh
            && c.joints == joints
            && c.decel_g == 0.5
            && c.variant == Variant::Default
            && c.h_s == 1e-4
            && c.duration_s.is_none()
    }
}

fn traced<'a>(res: &'a Results, c_mm: f64, joints: JointMode) -> Option<&'a Outcome> {
    res.select(standard(c_mm, V_REF, joints))
        .into_iter()
        .find(|o| o.case.seed == 0 && o.trace.is_some())
}

fn col(o: &Outcome, f: impl Fn(&crate::model::Outputs) -> f64) -> (Vec<f64>, Vec<f64>) {
    let tr = o.trace.as_ref().expect("traced outcome");
    (tr.column(|s| s.t_s), tr.column(f))
}

fn window_slice(o: &Outcome, x: &[f64]) -> (std::ops::Range<usize>, Vec<f64>) {
    let tr = o.trace.as_ref().expect("traced outcome");
    let w = tr.braking_window();
    (w.clone(), x[w].to_vec())
}

fn stride_pts(xs: &[f64], ys: &[f64], max: usize) -> Vec<(f64, f64)> {
    let step = xs.len().div_ceil(max.max(1)).max(1);
    xs.iter()
        .zip(ys)
        .step_by(step)
        .map(|(a, b)| (*a, *b))
        .collect()
}

fn mean_curve(
    res: &Results,
    xs: &[f64],
    sel: impl Fn(f64) -> Box<dyn Fn(&Case) -> bool>,
    g: impl Fn(&Outcome) -> f64 + Copy,
) -> Vec<(f64, f64)> {
    xs.iter()
        .filter_map(|&x| res.stat(sel(x), g).map(|m| (x, m.mean)))
        .collect()
}

/// Writes every figure into `dir` and returns them in document order.
pub fn write_all(res: &Results, dir: &Path) -> Result<Vec<Figure>> {
    let plan = &res.plan;
    let mut figs = Vec::new();
    let mut put = |key: &'static str, file: &str, caption: String| {
        figs.push(Figure {
            key,
            file: file.to_string(),
            caption,
        });
    };
    let plot_c: Vec<f64> = plan
        .plot_c
        .iter()
        .copied()
        .filter(|c| traced(res, *c, JointMode::Dual).is_some())
        .collect();
    let grid = |n: usize| -> (usize, usize) {
        if n <= 1 {
            (1, 1)
        } else if n == 2 {
            (1, 2)
        } else {
            (n.div_ceil(2), 2)
        }
    };

    // §3.1 convergence: θ1 at each step size.
    let conv: Vec<&Outcome> = res.select(|c| c.duration_s.is_some() && c.keep_trace);
    if !conv.is_empty() {
        let mut full = Panel::new(
            "θ1, 0.1 mm, 55 km/h, dual",
            "t (s)",
            "θ1 (deg)",
            Style::Lines,
        );
        let mut zoom = Panel::new("zoom 1.5–2.0 s", "t (s)", "θ1 (deg)", Style::Lines);
        let mut sorted = conv.clone();
        sorted.sort_by(|a, b| b.case.h_s.total_cmp(&a.case.h_s));
        for o in sorted {
            let (t, th) = col(o, |s| s.theta1_rad * DEG);
            let label = format!("h = {:.0e} s", o.case.h_s);
            full = full.with(Series::new(label.clone(), &t, &th));
            let (tz, thz): (Vec<f64>, Vec<f64>) = t
                .iter()
                .zip(&th)
                .filter(|(t, _)| (1.5..=2.0).contains(*t))
                .map(|(a, b)| (*a, *b))
                .unzip();
            zoom = zoom.with(Series::new(label, &tz, &thz));
        }
        figure(
            &dir.join("convergence.svg"),
            1,
            2,
            (460, 300),
            &[full, zoom],
        )?;
        put(
            "convergence",
            "convergence.svg",
            "Left-wheel angle θ1 at the three step sizes (0.1 mm, 55 km/h, 0.5 g, seed 0).".into(),
        );
    }

    // Clearance sweep: time histories, PSD, phase portraits, Poincaré sections, CWT maps.
    if !plot_c.is_empty() {
        let (r, cgrid) = grid(plot_c.len());
        let mut time = Vec::new();
        let mut phase = Vec::new();
        let mut poinc = Vec::new();
        let mut psd = Panel::new(
            "PSD of θ1 over the braking window, 55 km/h",
            "f (Hz)",
            "deg²/Hz",
            Style::Lines,
        )
        .log_y();
        let mut maps = Vec::new();
        for &c in &plot_c {
            let o = traced(res, c, JointMode::Dual).expect("filtered above");
            let (t, th) = col(o, |s| s.theta1_rad * DEG);
            let (_, rate) = col(o, |s| s.theta1_rate_rad_s * DEG);
            let t_end = o.window_s.1 + 0.5;
            let (tt, tth): (Vec<f64>, Vec<f64>) = t
                .iter()
                .zip(&th)
                .filter(|(t, _)| **t <= t_end)
                .map(|(a, b)| (*a, *b))
                .unzip();
            time.push(
                Panel::new(format!("θ1, c = {c} mm"), "t (s)", "θ1 (deg)", Style::Lines)
                    .with(Series::new("", &tt, &tth)),
            );
            let (_, thw) = window_slice(o, &th);
            let (_, rw) = window_slice(o, &rate);
            let mut ph = Panel::new(
                format!("phase portrait, c = {c} mm"),
                "θ1 (deg)",
                "θ1' (deg/s)",
                Style::Lines,
            );
            ph.series.push(Series {
                label: String::new(),
                points: stride_pts(&thw, &rw, 1100),
            });
            phase.push(ph);
            let mut pp = Panel::new(
                format!("Poincaré θ1'=0, θ1>0: c = {c} mm"),
                "θ1 band-passed (deg)",
                "θ2 band-passed (deg)",
                Style::Dots,
            );
            let mut seeds = res.select(standard(c, V_REF, JointMode::Dual));
            seeds.sort_by_key(|o| o.case.seed);
            for so in seeds {
                let pts: Vec<(f64, f64)> = so
                    .poincare
                    .iter()
                    .map(|(a, b)| (a * DEG, b * DEG))
                    .collect();
                pp.series.push(Series {
                    label: format!("seed {}", so.case.seed),
                    points: pts,
                });
            }
            poinc.push(pp);
            if let Ok(p) = welch(
                &thw,
                o.trace.as_ref().map(|t| t.fs_hz).unwrap_or(1000.0),
                4.0,
            ) {
                let (f, d): (Vec<f64>, Vec<f64>) = p
                    .freqs_hz
                    .iter()
                    .zip(&p.density)
                    .filter(|(f, _)| **f >= 0.5 && **f <= 30.0)
                    .map(|(a, b)| (*a, *b))
                    .unzip();
                psd = psd.with(Series::new(format!("{c} mm"), &f, &d));
            }
            if let Some(w) = o.cwt.as_ref() {
                maps.push((format!("CWT |W| of δ_sw, c = {c} mm"), w));
            }
        }
        figure(&dir.join("clearance_time.svg"), r, cgrid, (440, 230), &time)?;
        put(
            "time",
            "clearance_time.svg",
            "θ1(t) at 55 km/h, 0.5 g, dual clearance, seed 0; braking starts at 0.5 s.".into(),
        );
        figure(&dir.join("clearance_psd.svg"), 1, 1, (700, 340), &[psd])?;
        put("psd", "clearance_psd.svg", "Welch PSD (Hann, 4 s segments or the whole window if shorter) of θ1 over the braking window, seed 0.".into());
        figure(
            &dir.join("clearance_phase.svg"),
            r,
            cgrid,
            (400, 280),
            &phase,
        )?;
        put(
            "phase",
            "clearance_phase.svg",
            "Phase portraits θ1–θ1' over the braking window (seed 0).".into(),
        );
        figure(
            &dir.join("clearance_poincare.svg"),
            r,
            cgrid,
            (400, 280),
            &poinc,
        )?;
        put("poincare", "clearance_poincare.svg", "Poincaré sections: band-passed (θ1, θ2) at the maxima of θ1 (θ1' = 0, θ1 > 0) over the braking window, one colour per seed.".into());
        let refs: Vec<(String, &crate::analysis::cwt::Cwt)> =
            maps.iter().map(|(s, w)| (s.clone(), *w)).collect();
        cwt_figure(
            &dir.join("clearance_cwt.svg"),
            r,
            cgrid,
            (420, 250),
            &refs,
            10,
        )?;
        put("cwt", "clearance_cwt.svg", "Morlet CWT amplitude of the steering-wheel angle δ_sw over the braking window (time from brake onset), each map scaled to its own maximum, 10 colour levels.".into());
    }

    // Sweep curves vs clearance (means over seeds), dual and single.
    let cs = plan.sweep_c.clone();
    let sel = |mode: JointMode| {
        move |c: f64| -> Box<dyn Fn(&Case) -> bool> { Box::new(standard(c, V_REF, mode)) }
    };
    let panel = |title: &str, y: &str, g: fn(&Outcome) -> f64| {
        Panel::new(title, "clearance (mm)", y, Style::LinesPoints)
            .with(Series {
                label: "dual".into(),
                points: mean_curve(res, &cs, sel(JointMode::Dual), g),
            })
            .with(Series {
                label: "single".into(),
                points: mean_curve(res, &cs, sel(JointMode::Single), g),
            })
    };
    let sweep_panels = [
        panel("peak band-passed θ1, 55 km/h", "deg", |o| {
            o.features.peak_theta1_bp_rad * DEG
        }),
        panel("spectral concentration (±0.5 Hz)", "fraction", |o| {
            o.features.concentration
        }),
        panel("finite-time Lyapunov exponent", "1/s", |o| {
            o.lyapunov_per_s.unwrap_or(f64::NAN)
        }),
        panel("CWT time–frequency entropy of δ_sw", "bits", |o| {
            o.tf_entropy_bits
        }),
    ];
    figure(
        &dir.join("clearance_sweep.svg"),
        2,
        2,
        (430, 270),
        &sweep_panels,
    )?;
    put(
        "sweep",
        "clearance_sweep.svg",
        format!(
            "Clearance sweep at 55 km/h, 0.5 g: means over {} seed(s).",
            plan.seeds.len()
        ),
    );

    // Dual vs single at the largest plotted clearance.
    if let Some(&c) = plot_c
        .iter()
        .rev()
        .find(|c| traced(res, **c, JointMode::Single).is_some())
    {
        let d = traced(res, c, JointMode::Dual).expect("dual traced");
        let s = traced(res, c, JointMode::Single).expect("single traced");
        let t_end = d.window_s.1;
        let cut = |o: &Outcome, f: fn(&crate::model::Outputs) -> f64| {
            let (t, y) = col(o, f);
            let (a, b): (Vec<f64>, Vec<f64>) = t
                .iter()
                .zip(&y)
                .filter(|(t, _)| **t <= t_end)
                .map(|(a, b)| (*a, *b))
                .unzip();
            (a, b)
        };
        let (td, yd) = cut(d, |o| o.theta1_rad * DEG);
        let (ts, ys) = cut(s, |o| o.theta1_rad * DEG);
        let (tfd, fd) = cut(d, |o| o.contact_fx_n[0]);
        let (tfs, fs) = cut(s, |o| o.contact_fx_n[0]);
        let p1 = Panel::new(
            format!("θ1, c = {c} mm, 55 km/h"),
            "t (s)",
            "deg",
            Style::Lines,
        )
        .with(Series::new("dual", &td, &yd))
        .with(Series::new("single", &ts, &ys));
        let p2 = Panel::new("left joint contact force X", "t (s)", "N", Style::Lines)
            .with(Series::new("dual", &tfd, &fd))
            .with(Series::new("single", &tfs, &fs));
        figure(&dir.join("dual_single.svg"), 1, 2, (460, 300), &[p1, p2])?;
        put(
            "dual",
            "dual_single.svg",
            format!("Dual versus single clearance at {c} mm, 55 km/h, seed 0."),
        );

        // X vs Y contact force at the same run.
        let (tx, fx) = cut(d, |o| o.contact_fx_n[0]);
        let (ty, fy) = cut(d, |o| o.contact_fy_n[0]);
        let p3 = Panel::new(
            format!("left joint contact force, c = {c} mm"),
            "t (s)",
            "N",
            Style::Lines,
        )
        .with(Series::new("X (across, along the tie rod)", &tx, &fx))
        .with(Series::new("Y (fore-aft)", &ty, &fy));
        let ratio = |o: &Outcome| {
            o.max_fx_n[0].max(o.max_fx_n[1]) / o.max_fy_n[0].max(o.max_fy_n[1]).max(1e-9)
        };
        let p4 = Panel::new(
            "max |F_X| / max |F_Y| (both joints)",
            "clearance (mm)",
            "ratio",
            Style::LinesPoints,
        )
        .with(Series {
            label: "dual".into(),
            points: mean_curve(res, &cs, sel(JointMode::Dual), ratio),
        });
        figure(&dir.join("contact_xy.svg"), 1, 2, (460, 300), &[p3, p4])?;
        put("xy", "contact_xy.svg", "Contact force components at the left clearance joint (X across the car, Y fore-aft; plotted at the 1 kHz output rate, so most impact peaks fall between samples) and the ratio of their peaks taken at every integration step over the clearance sweep (55 km/h).".into());
    }

    // Speed sweep.
    let vs = plan.speeds.clone();
    let mut sp = Panel::new(
        "peak band-passed θ1 vs initial speed",
        "v0 (km/h)",
        "deg",
        Style::LinesPoints,
    );
    let mut sf = Panel::new(
        "peak contact force (X or Y, either joint)",
        "v0 (km/h)",
        "N",
        Style::LinesPoints,
    );
    for &c in &plan.speed_c {
        let s =
            |v: f64| -> Box<dyn Fn(&Case) -> bool> { Box::new(standard(c, v, JointMode::Dual)) };
        sp.series.push(Series {
            label: format!("{c} mm"),
            points: mean_curve(res, &vs, s, |o| o.features.peak_theta1_bp_rad * DEG),
        });
        let s2 =
            |v: f64| -> Box<dyn Fn(&Case) -> bool> { Box::new(standard(c, v, JointMode::Dual)) };
        sf.series.push(Series {
            label: format!("{c} mm"),
            points: mean_curve(res, &vs, s2, |o| {
                o.max_fx_n
                    .iter()
                    .chain(&o.max_fy_n)
                    .fold(0.0f64, |m, v| m.max(*v))
            }),
        });
    }
    figure(&dir.join("speed_sweep.svg"), 1, 2, (460, 300), &[sp, sf])?;
    put(
        "speed",
        "speed_sweep.svg",
        format!(
            "Speed sweep, dual clearance, 0.5 g: means over {} seed(s).",
            plan.seeds.len()
        ),
    );

    // Stiffness sweeps.
    let stiff = |vals: &[f64], mk: fn(f64) -> Variant, title: &str, unit_scale: f64, xl: &str| {
        let pts: Vec<(f64, f64)> = vals
            .iter()
            .filter_map(|&k| {
                res.stat(
                    |c| {
                        c.variant == mk(k)
                            && c.clearance_mm == 0.1
                            && c.v0_kmh == V_REF
                            && c.duration_s.is_none()
                    },
                    |o| o.features.peak_theta1_bp_rad * DEG,
                )
                .map(|m| (k * unit_scale, m.mean))
            })
            .collect();
        Panel::new(title, xl, "peak band-passed θ1 (deg)", Style::LinesPoints).with(Series {
            label: String::new(),
            points: pts,
        })
    };
    let k1 = stiff(
        &plan.k_t,
        Variant::TieRodStiffness,
        "tie-rod stiffness k_t (0.1 mm, 55 km/h)",
        1e-6,
        "k_t (1e6 N/m)",
    );
    let k2 = stiff(
        &plan.k_g,
        Variant::RestraintStiffness,
        "steering restraint k_g (0.1 mm, 55 km/h)",
        1e-5,
        "k_g (1e5 N/m)",
    );
    figure(&dir.join("stiffness.svg"), 1, 2, (460, 300), &[k1, k2])?;
    put(
        "stiffness",
        "stiffness.svg",
        format!("Stiffness sweeps: means over {} seed(s).", plan.seeds.len()),
    );
    Ok(figs)
}
