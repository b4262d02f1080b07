//! Per-event steering-wheel features (the estimator's measurements), computed by one function
//! on measured samples and on the model's output passed through
//! [`super::sensor::SensorModel`], so the response table and the measurements are comparable by
//! construction.
//!
//! Features, all over the braking window of MODEL.md §11 (brake onset to stop/release + 0.3 s),
//! on the 4th-order 3–25 Hz zero-phase Butterworth band-passed steering-wheel angle:
//! * `peak_deg`: max |band-passed δ_sw| (MODEL.md §11's "steering-wheel amplitude", raw: on a
//!   signal in 0.1° steps it reads high);
//! * `rms_deg`: RMS of the band-passed signal;
//! * `noise_rms_deg`: the RMS the sensor alone (quantisation with a random offset, white noise)
//!   puts into the band: `sqrt((q²/12 + σ²) · ENBW/(fs/2))`, ENBW the equivalent noise bandwidth of
//!   the zero-phase filter;
//! * `excess_rms_deg`: `sqrt(max(rms² − noise_rms², 0))`, the part of the RMS the wheel's motion
//!   explains. The estimator and the `shimmy_55kmh` amplitude estimate build on it.
//! * `cruise_rms_deg`: RMS of the same band-passed signal over the [`CRUISE_WINDOW_S`] before
//!   the brake onset (the detector's pre-roll), when the pre-roll holds enough of it. Before
//!   the brake the rattle is not excited (MODEL.md §12: the free-play modes are destabilised by
//!   the braking load transfer), so this is the steering system's response to the wheel
//!   unbalance and road noise (§7) through the joints: with tight joints the unbalance moves
//!   the rack, with a wide clearance the wheel's small motion stays inside the free play and
//!   the steering wheel hardly moves. Beside the braking features it tells a large unbalance
//!   on tight joints (busy before and during the brake) from a rattle on worn ones (quiet
//!   before, busy during), which the braking amplitude alone cannot.
//!
//! Samples are first put on a uniform grid at the rate they were sent at: consecutive samples
//! one period apart whatever the logger's timestamp jitter, a gap spanning its periods
//! (sample-and-hold over it; the event's quality record counts the gaps;
//! [`crate::analysis::sampling`]). Allocation: the extractor owns its buffers; it
//! allocates only when an event is longer than any before (bounded by the detector's ring), and
//! the band-pass allocates once per event, never per frame.

use crate::analysis::filter::Bandpass;
use crate::analysis::AnalysisError;
use serde::{Deserialize, Serialize};

/// MODEL.md §11 band and order.
pub const BAND_HZ: (f64, f64) = (3.0, 25.0);
pub const BAND_ORDER: usize = 4;

/// The band used at sample rate `fs_hz`: MODEL.md §11's, its upper edge lowered to 0.4·fs where
/// the rate cannot carry 25 Hz (a 50 Hz torque signal: 3–20 Hz). Unchanged at the steering
/// angle's rates (the detector needs more than 50 Hz there).
pub fn band_hz(fs_hz: f64) -> (f64, f64) {
    (BAND_HZ.0, BAND_HZ.1.min(0.4 * fs_hz))
}

/// The steering signal whose features a response table describes and the estimator uses.
/// Features, noise and floors are in that signal's unit (deg or N·m).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum SteerSignal {
    /// The steering-wheel angle δ_sw (MODEL.md §8; the rim with the §15 column), in deg.
    #[default]
    AngleDeg,
    /// The EPS torsion-bar torque (MODEL.md §15, −T_c), in N·m.
    TorqueNm,
}

impl SteerSignal {
    /// Factor from the samples' SI unit (rad, N·m) to the features' unit (deg, N·m).
    pub fn from_si(self) -> f64 {
        match self {
            SteerSignal::AngleDeg => 1f64.to_degrees(),
            SteerSignal::TorqueNm => 1.0,
        }
    }

    /// The features' unit, for messages.
    pub fn unit(self) -> &'static str {
        match self {
            SteerSignal::AngleDeg => "deg",
            SteerSignal::TorqueNm => "N·m",
        }
    }

    pub fn is_angle(&self) -> bool {
        *self == SteerSignal::AngleDeg
    }
}

/// Features of one event.
#[derive(Clone, Copy, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct Features {
    pub peak_deg: f64,
    pub rms_deg: f64,
    pub noise_rms_deg: f64,
    pub excess_rms_deg: f64,
    /// Samples in the window after resampling.
    pub n: u32,
    pub fs_hz: f64,
    /// RMS of the band-passed signal before the brake onset (deg); `None` when the pre-roll
    /// holds less than [`CRUISE_MIN_S`] of usable samples.
    #[serde(default)]
    pub cruise_rms_deg: Option<f64>,
    /// Share of the braking band's power in a line at the wheels' rotation beyond the one
    /// before the brake (src/observer/wheel_order.rs); `None` where no vehicle speed was given
    /// or the wheel order stayed out of the band.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub wheel_order_share: Option<f64>,
}

/// The pre-brake ("cruise") window: it ends [`CRUISE_GUARD_S`] before the brake onset and spans
/// up to this long (s).
pub const CRUISE_WINDOW_S: f64 = 1.2;
/// Gap between the cruise window and the brake onset (s): the pedal's first ramp stays out.
pub const CRUISE_GUARD_S: f64 = 0.05;
/// Samples this close to the start of the pre-roll are left out of the cruise window (s): the
/// zero-phase filter's start-up transient.
pub const CRUISE_EDGE_S: f64 = 0.4;
/// Shortest usable cruise window (s).
pub const CRUISE_MIN_S: f64 = 0.6;

/// What the sensor is assumed to add (used for the noise correction).
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct SensorNoise {
    /// Quantisation step (deg); 0 takes the step measured on the event.
    pub quant_step_deg: f64,
    /// White noise before quantisation (deg RMS).
    pub noise_deg: f64,
}

impl Default for SensorNoise {
    fn default() -> Self {
        SensorNoise {
            quant_step_deg: 0.0,
            noise_deg: 0.01,
        }
    }
}

/// Reusable feature extractor (keeps the filter design and buffers between events).
pub struct Extractor {
    filt: Option<(f64, Bandpass, f64)>,
    grid: Vec<f64>,
    /// The last event's band-passed signal and its windows ([`Self::last_windowed`]).
    last: Option<(Vec<f64>, super::wheel_order::Grid)>,
}

impl Default for Extractor {
    fn default() -> Self {
        Self::new()
    }
}

impl Extractor {
    pub fn new() -> Extractor {
        Extractor {
            filt: None,
            grid: Vec::with_capacity(4096),
            last: None,
        }
    }

    fn filter(&mut self, fs_hz: f64) -> Result<(&Bandpass, f64), AnalysisError> {
        let stale = self
            .filt
            .as_ref()
            .is_none_or(|(f, _, _)| (f - fs_hz).abs() > 1e-9);
        if stale {
            let (lo, hi) = band_hz(fs_hz);
            let bp = Bandpass::new(fs_hz, lo, hi, BAND_ORDER)?;
            let enbw = enbw_fraction(&bp);
            self.filt = Some((fs_hz, bp, enbw));
        }
        let (_, bp, e) = self.filt.as_ref().expect("set above");
        Ok((bp, *e))
    }

    /// The band-passed signal of the last event [`Self::extract_signal`] measured, on its
    /// uniform grid, with its braking and cruise windows: what the wheel-order check
    /// ([`super::wheel_order`]) reads. `None` before the first event or after one that failed.
    pub fn last_windowed(&self) -> Option<super::wheel_order::Windowed<'_>> {
        self.last
            .as_ref()
            .map(|(y, grid)| super::wheel_order::Windowed { y, grid: *grid })
    }

    /// Features of `samples` (`(t_ns, angle_rad)`, increasing time) over the window
    /// `[t0_ns, t1_ns]`; samples before `t0_ns` are pre-roll for the filter. `quant_step_deg`
    /// is the measured step when `noise.quant_step_deg` is 0.
    pub fn extract(
        &mut self,
        samples: &[(i64, f64)],
        t0_ns: i64,
        t1_ns: i64,
        noise: SensorNoise,
        quant_step_deg: f64,
    ) -> Result<Features, AnalysisError> {
        self.extract_signal(
            SteerSignal::AngleDeg,
            samples,
            t0_ns,
            t1_ns,
            noise,
            quant_step_deg,
        )
    }

    /// [`Self::extract`] for the steering signal `signal`: `samples` in its SI unit (rad,
    /// N·m), the features, `noise` and `quant_step` in its feature unit (deg, N·m; the
    /// fields' `_deg` names then stand for N·m).
    pub fn extract_signal(
        &mut self,
        signal: SteerSignal,
        samples: &[(i64, f64)],
        t0_ns: i64,
        t1_ns: i64,
        noise: SensorNoise,
        quant_step_deg: f64,
    ) -> Result<Features, AnalysisError> {
        let to_unit = signal.from_si();
        self.last = None;
        if samples.len() < 8 {
            return Err(AnalysisError::TooShort(format!(
                "{} steering samples, need 8",
                samples.len()
            )));
        }
        // The period the samples were sent at, robust to the logger's jitter
        // (crate::analysis::sampling), and a grid on which consecutive samples sit one period
        // apart and a gap spans its periods (sample-and-hold over it).
        let fit = crate::analysis::sampling::fit(samples.iter().map(|s| s.0))
            .ok_or_else(|| AnalysisError::TooShort("steering samples all at one time".into()))?;
        let fs_hz = (1e9 / fit.period_ns * 10.0).round() / 10.0;
        let cap = 4 * samples.len() + 4096;
        self.grid.clear();
        let (mut i0, mut i1) = (None, 0usize);
        for (k, &(t, a)) in samples.iter().enumerate() {
            if k > 0 {
                let hold = self.grid.last().copied().unwrap_or(0.0);
                let extra = fit.slots(t - samples[k - 1].0) - 1;
                if self.grid.len() + extra >= cap {
                    return Err(AnalysisError::BadParameter(format!(
                        "a gap of {:.1} s in the steering samples",
                        (t - samples[k - 1].0) as f64 * 1e-9
                    )));
                }
                self.grid.extend(std::iter::repeat_n(hold, extra));
            }
            if i0.is_none() && t >= t0_ns {
                i0 = Some(self.grid.len());
            }
            self.grid.push(a * to_unit);
            if t <= t1_ns {
                i1 = self.grid.len();
            }
        }
        let i0 = i0.unwrap_or(self.grid.len());
        if i1 <= i0 + 4 {
            return Err(AnalysisError::TooShort(format!(
                "{} samples in the window, need 5",
                i1.saturating_sub(i0)
            )));
        }
        let grid = std::mem::take(&mut self.grid);
        let (bp, enbw) = self.filter(fs_hz)?;
        let y = bp.filtfilt(&grid);
        self.grid = grid;
        let w = &y[i0..i1];
        let peak = crate::analysis::peak_abs(w);
        let rms = crate::analysis::rms(w);
        let per_s = 1e9 / fit.period_ns;
        let c1 = i0.saturating_sub((CRUISE_GUARD_S * per_s).round() as usize);
        let c0 = c1
            .saturating_sub((CRUISE_WINDOW_S * per_s).round() as usize)
            .max((CRUISE_EDGE_S * per_s).round() as usize);
        let cruise_rms_deg = (c1 > c0 && (c1 - c0) as f64 >= CRUISE_MIN_S * per_s)
            .then(|| crate::analysis::rms(&y[c0..c1]));
        let q = if noise.quant_step_deg > 0.0 {
            noise.quant_step_deg
        } else {
            quant_step_deg
        };
        let noise_var = (q * q / 12.0 + noise.noise_deg * noise.noise_deg) * enbw;
        let excess = (rms * rms - noise_var).max(0.0).sqrt();
        let band_hz = band_hz(fs_hz);
        let grid = super::wheel_order::Grid {
            t0_ns: samples[0].0,
            period_ns: fit.period_ns,
            braking: (i0, i1),
            cruise: (c0, c1),
            band_hz,
        };
        self.last = Some((y, grid));
        Ok(Features {
            peak_deg: peak,
            rms_deg: rms,
            noise_rms_deg: noise_var.sqrt(),
            excess_rms_deg: excess,
            n: (i1 - i0) as u32,
            fs_hz,
            cruise_rms_deg,
            wheel_order_share: None,
        })
    }
}

/// The cruise statistic of the table and the estimator: `ln √(cruise_rms² + f₀²)`, floored
/// like the braking RMS.
pub fn z_cruise(cruise_rms_deg: f64) -> f64 {
    0.5 * (cruise_rms_deg * cruise_rms_deg + Z_FLOOR_DEG[0] * Z_FLOOR_DEG[0]).ln()
}

/// Floors (deg) added in quadrature before taking logs in [`z`]: about the sensor's own
/// contribution, so events whose quantised signal barely moves do not make a long lower tail.
pub const Z_FLOOR_DEG: [f64; 2] = [0.02, 0.05];

/// The statistic the response table and the estimator work with:
/// `(ln √(rms² + f₀²), ln √(peak² + f₁²))`.
pub fn z(rms_deg: f64, peak_deg: f64) -> [f64; 2] {
    [
        0.5 * (rms_deg * rms_deg + Z_FLOOR_DEG[0] * Z_FLOOR_DEG[0]).ln(),
        0.5 * (peak_deg * peak_deg + Z_FLOOR_DEG[1] * Z_FLOOR_DEG[1]).ln(),
    ]
}

/// ln of the Jacobian dz_table/dz_measured of one feature (a braking RMS or peak, or the cruise
/// RMS, `x_deg` as measured, `floor_deg` its entry of [`Z_FLOOR_DEG`]) when the table is asked
/// about `x / gain` ([`super::estimator::EstimatorConfig::transfer_gain`]): the factor that
/// keeps the events' likelihood a density of what was measured, so that likelihoods under
/// different gains can be compared. 0 at gain 1 and for signals far above the floor.
pub fn ln_jacobian_gain(x_deg: f64, floor_deg: f64, gain: f64) -> f64 {
    let (x2, f2) = (x_deg * x_deg, floor_deg * floor_deg);
    (x2 + f2).ln() - (x2 + gain * gain * f2).ln()
}

/// Power gain of the zero-phase filter (|H|⁴ of the single pass) integrated over 0..fs/2,
/// as a fraction of fs/2: the share of white noise's variance that passes.
pub fn enbw_fraction(bp: &Bandpass) -> f64 {
    let nyq = bp.fs_hz() / 2.0;
    let m = 4000;
    let mut s = 0.0;
    for k in 0..m {
        let f = (k as f64 + 0.5) / m as f64 * nyq;
        let h = bp.response(f).norm_sqr();
        s += h * h;
    }
    s / m as f64
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_detector_checks_the_steering_over_the_cruise_window() {
        let w = CRUISE_WINDOW_S + CRUISE_GUARD_S;
        assert!((crate::events::STEER_HELD_BEFORE_S - w).abs() < 1e-12);
    }
}
