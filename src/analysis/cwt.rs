//! Continuous wavelet transform with the Morlet wavelet, computed with FFTs, and the
//! time–frequency (wavelet) entropy the paper uses in its §3.4 (MODEL.md §11 toolkit).
//!
//! What it is: for each analysis frequency f the scale is `s = ω0 / (2π f)` (ω0 = 6, so f is the
//! wavelet's centre frequency), and the coefficient is the inverse FFT of the signal's spectrum
//! times the Morlet's Fourier transform `2·exp(−(sω − ω0)²/2)` on positive frequencies only.
//! That normalisation makes `|W(f, t)|` the local amplitude: a sine of amplitude A at frequency
//! f gives `|W| ≈ A` on its ridge, at every frequency, so maps at different clearances compare
//! directly. The signal's mean is removed and it is zero-padded to a power of two ≥ 2n, so the
//! circular convolution does not wrap; the first and last ~`s` seconds are still affected by the
//! ends (the cone of influence), which [`Cwt::coi_s`] reports.
//!
//! What it is not: a reconstruction-grade transform (no admissibility correction, which is
//! below 1e-8 at ω0 = 6), nor a significance test against red noise.

use super::AnalysisError;
use rustfft::num_complex::Complex64;
use rustfft::FftPlanner;
use std::f64::consts::PI;

/// Morlet centre (angular) frequency, the usual choice: a good balance of time and frequency
/// resolution, and the wavelet is admissible to better than 1e-8.
pub const OMEGA0: f64 = 6.0;

/// A CWT amplitude map `|W(f, t)|` on a frequency grid × (possibly decimated) time grid.
#[derive(Debug, Clone)]
pub struct Cwt {
    /// Analysis frequencies (Hz), as given.
    pub freqs_hz: Vec<f64>,
    /// Times (s) of the kept columns, relative to the first input sample.
    pub times_s: Vec<f64>,
    /// Row-major amplitudes: `amp[i * times_s.len() + j]` is `|W(freqs_hz[i], times_s[j])|`.
    pub amp: Vec<f64>,
}

impl Cwt {
    /// Number of time columns.
    pub fn n_times(&self) -> usize {
        self.times_s.len()
    }

    /// Amplitude at frequency row `i`, time column `j`.
    pub fn at(&self, i: usize, j: usize) -> f64 {
        self.amp[i * self.times_s.len() + j]
    }

    /// One frequency row.
    pub fn row(&self, i: usize) -> &[f64] {
        let n = self.times_s.len();
        &self.amp[i * n..(i + 1) * n]
    }

    /// The e-folding half-width (s) of the wavelet at `f_hz`: `√2 · s`. Columns within this of
    /// either end are influenced by the zero padding.
    pub fn coi_s(f_hz: f64) -> f64 {
        2f64.sqrt() * OMEGA0 / (2.0 * PI * f_hz)
    }

    /// Ridge: for each time column, the frequency with the largest amplitude.
    pub fn ridge_hz(&self) -> Vec<f64> {
        (0..self.n_times())
            .map(|j| {
                let mut best = (0usize, f64::NEG_INFINITY);
                for i in 0..self.freqs_hz.len() {
                    let a = self.at(i, j);
                    if a > best.1 {
                        best = (i, a);
                    }
                }
                self.freqs_hz[best.0]
            })
            .collect()
    }

    /// Time–frequency entropy in bits: Shannon entropy of the energy distribution
    /// `p_ij = |W_ij|² / Σ|W|²` over the whole map. It is 0 for all energy in one cell and
    /// `log2(cells)` for a uniform map; compare values only on the same grid. `None` for a map
    /// without energy.
    pub fn tf_entropy_bits(&self) -> Option<f64> {
        entropy_bits(self.amp.iter().map(|a| a * a))
    }

    /// Wavelet (scale) entropy in bits: Shannon entropy of the energy per frequency row,
    /// `p_i = Σ_t |W_it|² / Σ|W|²` (Rosso et al.'s wavelet entropy). Ignores when in time the
    /// energy sits, so it measures spectral spread only. `None` for a map without energy.
    pub fn scale_entropy_bits(&self) -> Option<f64> {
        entropy_bits((0..self.freqs_hz.len()).map(|i| self.row(i).iter().map(|a| a * a).sum()))
    }

    /// Fraction of the map's energy in rows with `lo_hz ≤ f ≤ hi_hz`.
    pub fn band_energy_fraction(&self, lo_hz: f64, hi_hz: f64) -> Option<f64> {
        let mut total = 0.0;
        let mut band = 0.0;
        for (i, f) in self.freqs_hz.iter().enumerate() {
            let e: f64 = self.row(i).iter().map(|a| a * a).sum();
            total += e;
            if *f >= lo_hz && *f <= hi_hz {
                band += e;
            }
        }
        (total > 0.0).then(|| band / total)
    }
}

fn entropy_bits(weights: impl Iterator<Item = f64> + Clone) -> Option<f64> {
    let total: f64 = weights.clone().sum();
    if !(total > 0.0 && total.is_finite()) {
        return None;
    }
    Some(
        -weights
            .filter(|w| *w > 0.0)
            .map(|w| {
                let p = w / total;
                p * p.log2()
            })
            .sum::<f64>(),
    )
}

/// `n` frequencies spaced evenly on a log scale from `lo_hz` to `hi_hz` inclusive.
pub fn log_freqs(lo_hz: f64, hi_hz: f64, n: usize) -> Vec<f64> {
    if n < 2 {
        return vec![lo_hz; n];
    }
    let r = (hi_hz / lo_hz).ln();
    (0..n)
        .map(|i| lo_hz * (r * i as f64 / (n - 1) as f64).exp())
        .collect()
}

/// Morlet CWT amplitude `|W(f, t)|` of `x` (sampled at `fs_hz`) at `freqs_hz`, keeping every
/// `stride`-th time column. Errors on a bad sampling rate, an empty or non-finite input, a
/// frequency outside (0, fs/2), or `stride == 0`.
pub fn morlet(
    x: &[f64],
    fs_hz: f64,
    freqs_hz: &[f64],
    stride: usize,
) -> Result<Cwt, AnalysisError> {
    if !(fs_hz.is_finite() && fs_hz > 0.0) {
        return Err(AnalysisError::BadSampleRate(fs_hz));
    }
    if x.is_empty() {
        return Err(AnalysisError::TooShort("CWT of an empty signal".into()));
    }
    if x.iter().any(|v| !v.is_finite()) {
        return Err(AnalysisError::BadParameter(
            "CWT input holds NaN or infinite samples".into(),
        ));
    }
    if stride == 0 || freqs_hz.is_empty() {
        return Err(AnalysisError::BadParameter(
            "CWT needs stride ≥ 1 and at least one frequency".into(),
        ));
    }
    if let Some(f) = freqs_hz
        .iter()
        .find(|f| !(f.is_finite() && **f > 0.0 && **f < fs_hz / 2.0))
    {
        return Err(AnalysisError::BadParameter(format!(
            "CWT frequency {f} Hz outside (0, {}) Hz",
            fs_hz / 2.0
        )));
    }
    let n = x.len();
    let nfft = (2 * n).next_power_of_two();
    let mut planner = FftPlanner::<f64>::new();
    let fwd = planner.plan_fft_forward(nfft);
    let inv = planner.plan_fft_inverse(nfft);
    let mean = x.iter().sum::<f64>() / n as f64;
    let mut spec = vec![Complex64::new(0.0, 0.0); nfft];
    for (s, v) in spec.iter_mut().zip(x) {
        *s = Complex64::new(v - mean, 0.0);
    }
    fwd.process(&mut spec);

    let dw = 2.0 * PI * fs_hz / nfft as f64;
    let times_s: Vec<f64> = (0..n).step_by(stride).map(|j| j as f64 / fs_hz).collect();
    let nt = times_s.len();
    let mut amp = vec![0.0; freqs_hz.len() * nt];
    let mut buf = vec![Complex64::new(0.0, 0.0); nfft];
    let mut scratch = vec![Complex64::new(0.0, 0.0); inv.get_inplace_scratch_len()];
    for (i, f) in freqs_hz.iter().enumerate() {
        let s = OMEGA0 / (2.0 * PI * f);
        buf.iter_mut().for_each(|b| *b = Complex64::new(0.0, 0.0));
        // Positive frequencies only (the Morlet is analytic); the Gaussian is negligible
        // beyond 8 standard deviations, so only that stretch of bins is touched.
        let k_lo = (((OMEGA0 - 8.0).max(0.0) / s) / dw).floor().max(1.0) as usize;
        let k_hi = ((((OMEGA0 + 8.0) / s) / dw).ceil() as usize).min(nfft / 2);
        for k in k_lo..=k_hi {
            let d = s * k as f64 * dw - OMEGA0;
            buf[k] = spec[k] * (2.0 * (-0.5 * d * d).exp() / nfft as f64);
        }
        inv.process_with_scratch(&mut buf, &mut scratch);
        let row = &mut amp[i * nt..(i + 1) * nt];
        for (r, j) in row.iter_mut().zip((0..n).step_by(stride)) {
            *r = buf[j].norm();
        }
    }
    Ok(Cwt {
        freqs_hz: freqs_hz.to_vec(),
        times_s,
        amp,
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn rejects_bad_input() {
        assert!(morlet(&[], 100.0, &[5.0], 1).is_err());
        assert!(morlet(&[1.0, f64::NAN], 100.0, &[5.0], 1).is_err());
        assert!(morlet(&[1.0, 2.0], 100.0, &[60.0], 1).is_err());
        assert!(morlet(&[1.0, 2.0], 100.0, &[5.0], 0).is_err());
    }

    #[test]
    fn log_grid_ends_exactly() {
        let f = log_freqs(1.0, 40.0, 5);
        assert_eq!(f.len(), 5);
        assert!((f[0] - 1.0).abs() < 1e-12 && (f[4] - 40.0).abs() < 1e-9);
        assert!(f.windows(2).all(|w| w[1] > w[0]));
    }

    #[test]
    fn entropy_of_single_cell_is_zero_and_uniform_is_log2() {
        let one = Cwt {
            freqs_hz: vec![1.0, 2.0],
            times_s: vec![0.0, 1.0],
            amp: vec![0.0, 3.0, 0.0, 0.0],
        };
        assert_eq!(one.tf_entropy_bits(), Some(0.0));
        let flat = Cwt {
            freqs_hz: vec![1.0, 2.0],
            times_s: vec![0.0, 1.0],
            amp: vec![1.0; 4],
        };
        assert!((flat.tf_entropy_bits().unwrap() - 2.0).abs() < 1e-12);
        assert!((flat.scale_entropy_bits().unwrap() - 1.0).abs() < 1e-12);
        let none = Cwt {
            freqs_hz: vec![1.0],
            times_s: vec![0.0],
            amp: vec![0.0],
        };
        assert_eq!(none.tf_entropy_bits(), None);
    }
}
