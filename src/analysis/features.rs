//! The shimmy features of MODEL.md §11 computed from plain sampled series: band-passed peak
//! wheel and steering-wheel angles, the paper's raw peak |θ1|, dominant frequency and spectral
//! concentration over the braking window.
//!
//! What it is: one place that applies the §11 definitions in the same way for `shimmy simulate
//! --summary`, `shimmy reproduce` and the observer. The band-pass runs over the whole record and
//! the window is cut afterwards, so the window's edges carry no filter start-up transient; the
//! PSD is of θ1 inside the window (mean removed per segment). What it is not: anything that
//! knows where the window is — the caller passes it (the model's trace knows t_b and t_stop).

use super::filter::Bandpass;
use super::spectrum::welch;
use super::{peak_abs, AnalysisError};
use std::ops::Range;

/// Welch segment length of MODEL.md §11 (s).
pub const WELCH_SEGMENT_S: f64 = 4.0;

/// MODEL.md §11 features of one run. Angles in radians (convert at the edges).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct ShimmyFeatures {
    /// max |band-passed θ1| in the window.
    pub peak_theta1_bp_rad: f64,
    /// max |θ1| in the window, unfiltered (the paper's "peak |θ1|").
    pub peak_theta1_rad: f64,
    /// max |band-passed δ_sw| in the window.
    pub peak_sw_bp_rad: f64,
    /// Dominant frequency of θ1 in 1–40 Hz (Hz).
    pub fdom_hz: f64,
    /// Fraction of 1–40 Hz power within ±0.5 Hz of `fdom_hz`.
    pub concentration: f64,
    /// Frequency resolution of the PSD behind `fdom_hz` (Hz).
    pub df_hz: f64,
}

/// Computes [`ShimmyFeatures`] for series sampled at `fs_hz`, restricted to sample range
/// `window`. Errors when the window is empty or out of range, the series differ in length, or
/// the window holds no oscillation power.
pub fn shimmy_features(
    fs_hz: f64,
    window: Range<usize>,
    theta1: &[f64],
    delta_sw: &[f64],
) -> Result<ShimmyFeatures, AnalysisError> {
    if theta1.len() != delta_sw.len() {
        return Err(AnalysisError::BadParameter(format!(
            "θ1 has {} samples but δ_sw has {}",
            theta1.len(),
            delta_sw.len()
        )));
    }
    if window.start >= window.end || window.end > theta1.len() {
        return Err(AnalysisError::BadParameter(format!(
            "window {:?} is empty or outside the {} samples",
            window,
            theta1.len()
        )));
    }
    let bp = Bandpass::new(fs_hz, 3.0, 25.0, 4)?;
    let th_bp = bp.filtfilt(theta1);
    let sw_bp = bp.filtfilt(delta_sw);
    let w = window.clone();
    let psd = welch(&theta1[w.clone()], fs_hz, WELCH_SEGMENT_S)?;
    let (fdom_hz, concentration) = psd.shimmy_features().ok_or_else(|| {
        AnalysisError::TooShort("θ1 holds no 1–40 Hz power in the braking window".into())
    })?;
    Ok(ShimmyFeatures {
        peak_theta1_bp_rad: peak_abs(&th_bp[w.clone()]),
        peak_theta1_rad: peak_abs(&theta1[w.clone()]),
        peak_sw_bp_rad: peak_abs(&sw_bp[w]),
        fdom_hz,
        concentration,
        df_hz: psd.df_hz,
    })
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::f64::consts::PI;

    #[test]
    fn features_of_a_sine_burst_on_a_trend() {
        let fs = 1000.0;
        let n = 6000;
        // 6 Hz at 0.01 rad between 1 s and 5 s, on a slow drift the band-pass must remove.
        let th: Vec<f64> = (0..n)
            .map(|i| {
                let t = i as f64 / fs;
                let burst = if (1.0..5.0).contains(&t) {
                    0.01 * (2.0 * PI * 6.0 * t).sin()
                } else {
                    0.0
                };
                burst + 0.002 * t
            })
            .collect();
        let sw: Vec<f64> = th.iter().map(|v| 15.5 * v).collect();
        let f = shimmy_features(fs, 1000..5000, &th, &sw).unwrap();
        assert!(
            (f.peak_theta1_bp_rad - 0.01).abs() < 0.0005,
            "{}",
            f.peak_theta1_bp_rad
        );
        assert!((f.peak_sw_bp_rad / f.peak_theta1_bp_rad - 15.5).abs() < 1e-9);
        assert!(f.peak_theta1_rad > 0.01 + 0.002 * 4.0);
        assert!((f.fdom_hz - 6.0).abs() <= f.df_hz / 2.0 + 1e-12);
        assert!(f.concentration > 0.9, "{}", f.concentration);
    }

    #[test]
    fn bad_windows_are_errors() {
        let x = vec![0.0; 100];
        assert!(shimmy_features(1000.0, 50..50, &x, &x).is_err());
        assert!(shimmy_features(1000.0, 0..101, &x, &x).is_err());
        assert!(shimmy_features(1000.0, 0..100, &x, &x[..99]).is_err());
        // All-zero: no power, a clear error rather than a NaN frequency.
        assert!(matches!(
            shimmy_features(1000.0, 0..100, &x, &x),
            Err(AnalysisError::TooShort(_))
        ));
    }
}
