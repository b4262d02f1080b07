//! MODEL.md §11 features of one simulated run: band-passed peak wheel and steering-wheel
//! angles over the braking window, the paper's raw peak |θ1|, dominant frequency, spectral
//! concentration, peak contact forces and (optionally) the finite-time largest Lyapunov
//! exponent from twin runs.
//!
//! What it is: glue between a [`Trace`] and `crate::analysis` (which owns the filter, Welch
//! PSD and Lyapunov fit). What it is not: a second implementation of those definitions.

use super::params::VehicleParams;
use super::sim::{run, Scenario, Trace};
use crate::analysis::chaos::{lyapunov_from_twins, rms_scales, LyapunovOptions};
use crate::analysis::{peak_abs, welch, Bandpass};
use serde::Serialize;

/// The summary `shimmy simulate --summary` prints (degrees at this edge, as named).
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
pub struct Features {
    /// max |θ1| in the window (the paper's peak).
    pub peak_theta1_deg: f64,
    /// max |3–25 Hz band-passed θ1| in the window.
    pub peak_theta1_bp_deg: f64,
    /// max |3–25 Hz band-passed δ_sw| in the window.
    pub peak_sw_bp_deg: f64,
    /// Dominant frequency of θ1 (Welch, 4 s Hann segments, 1–40 Hz).
    pub fdom_hz: f64,
    /// Fraction of 1–40 Hz power within ±0.5 Hz of `fdom_hz`.
    pub concentration: f64,
    /// Largest |contact force| x and y over both joints in the window.
    pub max_contact_fx_n: f64,
    pub max_contact_fy_n: f64,
    /// Braking window used (s).
    pub window_start_s: f64,
    pub window_end_s: f64,
}

/// Computes the §11 features of a trace (band-pass over the whole record, window cut after).
pub fn features(trace: &Trace) -> anyhow::Result<Features> {
    let w = trace.braking_window();
    anyhow::ensure!(
        w.len() > 10,
        "braking window has only {} samples (duration too short?)",
        w.len()
    );
    let th = trace.column(|o| o.theta1_rad);
    let sw = trace.column(|o| o.delta_sw_rad);
    let bp = Bandpass::new(trace.fs_hz, 3.0, 25.0, 4)?;
    let th_bp = bp.filtfilt(&th);
    let sw_bp = bp.filtfilt(&sw);
    let psd = welch(&th[w.clone()], trace.fs_hz, 4.0)?;
    let (fdom_hz, concentration) = psd.shimmy_features().unwrap_or((f64::NAN, f64::NAN));
    let s = &trace.samples[w.clone()];
    let max_fx = s.iter().fold(0.0f64, |m, o| {
        m.max(o.contact_fx_n[0].abs()).max(o.contact_fx_n[1].abs())
    });
    let max_fy = s.iter().fold(0.0f64, |m, o| {
        m.max(o.contact_fy_n[0].abs()).max(o.contact_fy_n[1].abs())
    });
    Ok(Features {
        peak_theta1_deg: peak_abs(&th[w.clone()]).to_degrees(),
        peak_theta1_bp_deg: peak_abs(&th_bp[w.clone()]).to_degrees(),
        peak_sw_bp_deg: peak_abs(&sw_bp[w.clone()]).to_degrees(),
        fdom_hz,
        concentration,
        max_contact_fx_n: max_fx,
        max_contact_fy_n: max_fy,
        window_start_s: w.start as f64 / trace.fs_hz,
        window_end_s: (w.end - 1) as f64 / trace.fs_hz,
    })
}

/// MODEL.md §11 finite-time largest Lyapunov exponent (1/s): a twin run with θ1'(0) perturbed
/// by a relative 1e-9 and identical noise (same seed), separation of the scaled state
/// (θ1, θ2, θ1', θ2', X, X') fitted over 0.8–3 s up to saturation. `reference` is the run of
/// `sc` itself.
pub fn lyapunov_per_s(p: &VehicleParams, sc: &Scenario, reference: &Trace) -> anyhow::Result<f64> {
    let kick = sc.kick_theta1_rad_s.unwrap_or(p.excitation.kick_rad_per_s);
    let twin_sc = Scenario {
        kick_theta1_rad_s: Some(kick * (1.0 + 1e-9) + if kick == 0.0 { 1e-12 } else { 0.0 }),
        ..sc.clone()
    };
    let twin = run(p, &twin_sc)?;
    let comps = |t: &Trace| -> Vec<Vec<f64>> {
        vec![
            t.column(|o| o.theta1_rad),
            t.column(|o| o.theta2_rad),
            t.column(|o| o.theta1_rate_rad_s),
            t.column(|o| o.theta2_rate_rad_s),
            t.column(|o| o.x_m),
            t.column(|o| o.x_rate_mps),
        ]
    };
    let a = comps(reference);
    let b = comps(&twin);
    let opts = LyapunovOptions::default();
    let t = reference.column(|o| o.t_s);
    let i0 = t.iter().position(|&x| x >= opts.t_start).unwrap_or(0);
    let i1 = t
        .iter()
        .rposition(|&x| x <= opts.t_end)
        .unwrap_or(t.len() - 1);
    anyhow::ensure!(i1 > i0, "Lyapunov fit window 0.8–3 s lies outside the run");
    let win: Vec<&[f64]> = a.iter().map(|c| &c[i0..=i1]).collect();
    let scales = rms_scales(&win);
    let ar: Vec<&[f64]> = a.iter().map(|c| c.as_slice()).collect();
    let br: Vec<&[f64]> = b.iter().map(|c| c.as_slice()).collect();
    Ok(lyapunov_from_twins(&t, &ar, &br, &scales, &opts)?.lambda)
}
