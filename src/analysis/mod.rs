//! Signal analysis for shimmy (MODEL.md §11): band-pass, peak amplitude, Welch PSD, dominant
//! frequency, spectral concentration, Morlet CWT, Lyapunov exponents. Works on plain slices;
//! knows nothing of CAN or the model's internals.
//!
//! What it is: small, allocation-explicit numerical routines with the exact definitions of
//! MODEL.md §11, each checked against closed-form results (and once against SciPy, see the
//! module docs). What it is not: a general DSP library, nor anything that runs per CAN frame —
//! these work on whole recorded windows.

pub mod chaos;
pub mod cwt;
pub mod features;
pub mod filter;
pub mod sampling;
pub mod spectrum;
pub mod sweep;

pub use filter::{bandpass_zero_phase, Bandpass};
pub use spectrum::{welch, Psd};

/// Why an analysis routine refused its input. Every routine either returns a value or one of
/// these; none panics on user-supplied numbers.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum AnalysisError {
    /// A sampling rate that is zero, negative or not finite.
    #[error("sampling rate must be finite and > 0, got {0} Hz")]
    BadSampleRate(f64),
    /// Band edges outside (0, Nyquist) or not increasing.
    #[error("band {lo_hz}..{hi_hz} Hz is invalid for a sampling rate of {fs_hz} Hz (need 0 < lo < hi < fs/2)")]
    BadBand { lo_hz: f64, hi_hz: f64, fs_hz: f64 },
    /// Filter order outside the supported range.
    #[error("filter order must be 1..=12, got {0}")]
    BadOrder(usize),
    /// A length or duration parameter that makes no sense (zero segment, empty grid, ...).
    #[error("invalid parameter: {0}")]
    BadParameter(String),
    /// Input too short for the requested analysis.
    #[error("input too short: {0}")]
    TooShort(String),
}

/// Largest absolute value of `x` (0 for an empty slice). NaN entries are ignored, so one bad
/// sample cannot hide the peak; use [`count_non_finite`] to report them.
///
/// This is the "peak shimmy angle" of MODEL.md §11 when `x` is the band-passed θ1 restricted to
/// the braking window.
pub fn peak_abs(x: &[f64]) -> f64 {
    x.iter().fold(0.0_f64, |m, v| m.max(v.abs()))
}

/// Number of NaN or infinite samples in `x`.
pub fn count_non_finite(x: &[f64]) -> usize {
    x.iter().filter(|v| !v.is_finite()).count()
}

/// Root mean square of `x` (0 for an empty slice).
pub fn rms(x: &[f64]) -> f64 {
    if x.is_empty() {
        return 0.0;
    }
    (x.iter().map(|v| v * v).sum::<f64>() / x.len() as f64).sqrt()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn peak_abs_takes_the_negative_peak_and_ignores_nan() {
        assert_eq!(peak_abs(&[]), 0.0);
        assert_eq!(peak_abs(&[0.5, -2.0, 1.5]), 2.0);
        assert_eq!(peak_abs(&[f64::NAN, -3.0, 1.0]), 3.0);
        assert_eq!(count_non_finite(&[f64::NAN, 1.0, f64::INFINITY]), 2);
    }

    #[test]
    fn rms_of_constant_and_empty() {
        assert_eq!(rms(&[]), 0.0);
        assert!((rms(&[2.0, -2.0, 2.0]) - 2.0).abs() < 1e-15);
    }
}
