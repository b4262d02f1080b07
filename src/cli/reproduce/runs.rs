//! One simulation case of the reproduction and what is kept of it: the MODEL.md §11 features,
//! contact-force peaks, CWT entropy, optionally the finite-time Lyapunov exponent (twin run) and
//! the full trace for plotting.
//!
//! What it is: the glue between `crate::model` and `crate::analysis` for `shimmy reproduce`.
//! What it is not: a cache on disk; every `reproduce` reruns everything (deterministic seeds).

use crate::analysis::chaos::{count_distinct, poincare_section, Direction};
use crate::analysis::chaos::{lyapunov_twin_runs, LyapunovOptions, Trajectory};
use crate::analysis::cwt::{log_freqs, morlet, Cwt};
use crate::analysis::features::{shimmy_features, ShimmyFeatures};
use crate::analysis::peak_abs;
use crate::model::{run, JointMode, Scenario, Simulator, Trace, VehicleParams};
use anyhow::{Context, Result};

/// A change to the default vehicle (MODEL.md §9) for sweeps.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum Variant {
    Default,
    /// k_t, the tie-rod ("transverse bar") stiffness, N/m.
    TieRodStiffness(f64),
    /// k_g, the steering restraint at the rack, N/m.
    RestraintStiffness(f64),
    /// c_s, kingpin damping, N·m·s/rad.
    KingpinDamping(f64),
}

/// One run: clearance, speed, braking, joints, seed, step, duration, vehicle variant.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Case {
    pub clearance_mm: f64,
    pub v0_kmh: f64,
    pub decel_g: f64,
    pub joints: JointMode,
    pub seed: u64,
    pub h_s: f64,
    /// None: until the stop + 2 s (enough for the §11 window and the filter's tail).
    pub duration_s: Option<f64>,
    pub variant: Variant,
    /// Also run the twin for the Lyapunov exponent.
    pub lyapunov: bool,
    /// Keep the trace for plots.
    pub keep_trace: bool,
}

impl Case {
    pub fn new(clearance_mm: f64, v0_kmh: f64, joints: JointMode, seed: u64) -> Self {
        Self {
            clearance_mm,
            v0_kmh,
            decel_g: 0.5,
            joints,
            seed,
            h_s: 1e-4,
            duration_s: None,
            variant: Variant::Default,
            lyapunov: false,
            keep_trace: false,
        }
    }

    /// Same physics (everything but the output options) as `other`.
    pub fn same_physics(&self, other: &Case) -> bool {
        let strip = |c: &Case| Case {
            lyapunov: false,
            keep_trace: false,
            ..*c
        };
        strip(self) == strip(other)
    }

    fn params(&self) -> VehicleParams {
        let mut p = VehicleParams::default();
        match self.variant {
            Variant::Default => {}
            Variant::TieRodStiffness(k) => p.steering.tie_rod_stiffness_n_per_m = k,
            Variant::RestraintStiffness(k) => p.steering.restraint_stiffness_n_per_m = k,
            Variant::KingpinDamping(c) => p.steering.kingpin_damping_nms_per_rad = c,
        }
        p
    }

    fn scenario(&self, p: &VehicleParams, kick_scale: f64) -> Scenario {
        let v0 = self.v0_kmh / 3.6;
        let a = self.decel_g * 9.81;
        // MODEL.md §6: ramp to full deceleration over t_r, then v falls linearly.
        let t_stop_est = 0.5 + 0.15 + v0 / a.max(0.1);
        let duration = self.duration_s.unwrap_or((t_stop_est + 2.0).min(20.0));
        Scenario {
            clearance_m: self.clearance_mm * 1e-3,
            joints: self.joints,
            seed: self.seed,
            v0_mps: v0,
            decel_g: self.decel_g,
            duration_s: duration,
            h_s: self.h_s,
            kick_theta1_rad_s: Some(p.excitation.kick_rad_per_s * kick_scale),
            ..Scenario::default()
        }
    }
}

/// What is kept of one run.
#[derive(Debug, Clone)]
pub struct Outcome {
    pub case: Case,
    pub features: ShimmyFeatures,
    /// max |band-passed θ2| in the window (rad).
    pub peak_theta2_bp_rad: f64,
    /// max |θ1| over the whole run (rad): the paper's §3.1 "peak angle".
    pub peak_theta1_all_rad: f64,
    /// max |contact force| components in the window, left/right, over every integration step (N).
    pub max_fx_n: [f64; 2],
    pub max_fy_n: [f64; 2],
    /// max normal contact force magnitude at the left joint over the whole run, every step (N): §3.1.
    pub max_fn_left_all_n: f64,
    /// Time-frequency and scale entropy (bits) of the CWT of δ_sw over the window.
    pub tf_entropy_bits: f64,
    pub scale_entropy_bits: f64,
    /// Fraction of the CWT energy of δ_sw in 15–18 Hz.
    pub band_15_18: f64,
    /// Poincaré section of the band-passed wheel angles in the window: (θ1, θ2) in rad where
    /// θ1' crosses 0 downwards with θ1 > 0 (the maxima of θ1).
    pub poincare: Vec<(f64, f64)>,
    /// Distinct section points (10 % of the peak amplitude apart) over all section points.
    pub poincare_distinct: (usize, usize),
    /// Finite-time Lyapunov exponent (1/s), if asked for and the fit succeeded.
    pub lyapunov_per_s: Option<f64>,
    /// The twins separated to saturation before the fit window held 0.3 s, so the exponent is
    /// the mean growth rate from t = 0 (see `analysis::chaos::LyapunovFit::early`).
    pub lyapunov_early: bool,
    /// Thread CPU time of the main run (s).
    pub cpu_s: f64,
    /// Window [t_b, t_stop + 0.3 s] in seconds.
    pub window_s: (f64, f64),
    pub trace: Option<Trace>,
    pub cwt: Option<Cwt>,
}

use crate::cli::simulate::thread_cpu_s;

/// The CWT frequency grid used for maps and entropies: 48 log-spaced frequencies, 1–40 Hz.
pub fn cwt_grid() -> Vec<f64> {
    log_freqs(1.0, 40.0, 48)
}

/// The state MODEL.md §11 compares in twin runs: θ1, θ2, θ1', θ2', X, X'.
fn lyapunov_state(tr: &Trace) -> Trajectory {
    Trajectory {
        t: tr.column(|o| o.t_s),
        components: vec![
            tr.column(|o| o.theta1_rad),
            tr.column(|o| o.theta2_rad),
            tr.column(|o| o.theta1_rate_rad_s),
            tr.column(|o| o.theta2_rate_rad_s),
            tr.column(|o| o.x_m),
            tr.column(|o| o.x_rate_mps),
        ],
    }
}

/// Per output interval, the largest contact-force magnitudes seen at any integration step in
/// it: |F_x| L, R, |F_y| L, R, |F_n| L. Impacts last about a millisecond, so the 1 kHz samples
/// alone would miss most force peaks.
type StepPeaks = [f64; 5];

/// Runs the scenario like `model::run` (1 kHz samples) and also records [`StepPeaks`] for each
/// sample interval (costs one extra right-hand-side evaluation per step).
fn simulate_with_peaks(p: &VehicleParams, sc: &Scenario) -> Result<(Trace, Vec<StepPeaks>)> {
    let mut sim = Simulator::new(p, sc)?;
    let n_steps = (sc.duration_s / sc.h_s).round() as u64;
    let stride = ((1e-3 / sc.h_s).round() as u64).max(1);
    let mut samples = Vec::with_capacity((n_steps / stride + 1) as usize);
    let mut peaks = Vec::with_capacity(samples.capacity());
    let first = sim.outputs();
    samples.push(first);
    peaks.push([0.0; 5]);
    let mut acc = [0.0f64; 5];
    for k in 1..=n_steps {
        sim.step();
        let o = sim.outputs();
        let v = [
            o.contact_fx_n[0].abs(),
            o.contact_fx_n[1].abs(),
            o.contact_fy_n[0].abs(),
            o.contact_fy_n[1].abs(),
            o.contact_fx_n[0].hypot(o.contact_fy_n[0]),
        ];
        for (a, b) in acc.iter_mut().zip(v) {
            *a = a.max(b);
        }
        if k % stride == 0 {
            samples.push(o);
            peaks.push(acc);
            acc = [0.0; 5];
        }
    }
    let tr = Trace {
        fs_hz: 1.0 / (stride as f64 * sc.h_s),
        samples,
        brake_onset_s: p.braking.onset_s,
    };
    Ok((tr, peaks))
}

/// Runs one case and extracts everything the report needs.
pub fn run_case(case: &Case) -> Result<Outcome> {
    let p = case.params();
    let sc = case.scenario(&p, 1.0);
    let c0 = thread_cpu_s();
    let (tr, step_peaks) =
        simulate_with_peaks(&p, &sc).with_context(|| format!("simulating {case:?}"))?;
    let cpu_s = thread_cpu_s() - c0;

    let th1 = tr.column(|o| o.theta1_rad);
    let th2 = tr.column(|o| o.theta2_rad);
    let sw = tr.column(|o| o.delta_sw_rad);
    if th1.iter().chain(&sw).any(|v| !v.is_finite()) {
        anyhow::bail!("{case:?}: the simulation diverged (non-finite angles)");
    }
    let w = tr.braking_window();
    let fs = tr.fs_hz;
    let features = shimmy_features(fs, w.clone(), &th1, &sw)
        .with_context(|| format!("features of {case:?}"))?;
    let th1_bp = crate::analysis::filter::shimmy_bandpass(&th1, fs)?;
    let th2_bp = crate::analysis::filter::shimmy_bandpass(&th2, fs)?;
    // Peaks over every integration step: in the window (intervals ending inside it) and, for
    // the §3.1 table, over the whole run.
    let mut max_fx = [0.0f64; 2];
    let mut max_fy = [0.0f64; 2];
    for pk in &step_peaks[w.start.saturating_add(1).min(w.end)..w.end] {
        for k in 0..2 {
            max_fx[k] = max_fx[k].max(pk[k]);
            max_fy[k] = max_fy[k].max(pk[2 + k]);
        }
    }
    let max_fn_left_all_n = step_peaks.iter().map(|pk| pk[4]).fold(0.0f64, f64::max);

    let cwt = morlet(&sw[w.clone()], fs, &cwt_grid(), 10)?;
    let tf_entropy_bits = cwt.tf_entropy_bits().unwrap_or(f64::NAN);
    let scale_entropy_bits = cwt.scale_entropy_bits().unwrap_or(f64::NAN);
    let band_15_18 = cwt.band_energy_fraction(15.0, 18.0).unwrap_or(f64::NAN);

    let th1w = &th1_bp[w.clone()];
    let th2w = &th2_bp[w.clone()];
    let rate: Vec<f64> = (0..th1w.len())
        .map(|i| {
            let (a, b) = (i.saturating_sub(1), (i + 1).min(th1w.len() - 1));
            (th1w[b] - th1w[a]) * fs / (b - a).max(1) as f64
        })
        .collect();
    let pts = poincare_section(&rate, 0.0, Direction::Down, &[th1w, th2w], |p| p[0] > 0.0);
    let tol = 0.1 * features.peak_theta1_bp_rad;
    let poincare_distinct = (count_distinct(&pts, tol), pts.len());
    let poincare: Vec<(f64, f64)> = pts.iter().map(|p| (p[0], p[1])).collect();

    let lyap_fit = if case.lyapunov {
        let reference = lyapunov_state(&tr);
        let runner = |eps: f64| -> Result<Trajectory> {
            if eps == 0.0 {
                return Ok(reference.clone());
            }
            let twin = run(&p, &case.scenario(&p, 1.0 + eps))?;
            Ok(lyapunov_state(&twin))
        };
        lyapunov_twin_runs(runner, 1e-9, &LyapunovOptions::default()).ok()
    } else {
        None
    };
    let t0 = tr.samples[w.start].t_s;
    let t1 = tr.samples[w.end - 1].t_s;
    Ok(Outcome {
        case: *case,
        features,
        peak_theta2_bp_rad: peak_abs(&th2_bp[w.clone()]),
        peak_theta1_all_rad: peak_abs(&th1),
        max_fx_n: max_fx,
        max_fy_n: max_fy,
        max_fn_left_all_n,
        tf_entropy_bits,
        scale_entropy_bits,
        band_15_18,
        poincare,
        poincare_distinct,
        lyapunov_per_s: lyap_fit.map(|f| f.lambda),
        lyapunov_early: lyap_fit.is_some_and(|f| f.early),
        cpu_s,
        window_s: (t0, t1),
        trace: case.keep_trace.then_some(tr),
        cwt: case.keep_trace.then_some(cwt),
    })
}
