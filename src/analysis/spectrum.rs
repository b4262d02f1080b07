//! Welch power spectral density, dominant frequency and spectral concentration (MODEL.md §11).
//!
//! What it is: Welch's averaged periodogram with a periodic Hann window, 50 % overlap, the mean
//! of each segment removed, one-sided density scaling (units² / Hz) — the same conventions as
//! SciPy's `signal.welch` defaults, so `Σ P·Δf` equals the signal's variance (Parseval). A
//! signal shorter than one segment is analysed as one segment of its own length (as SciPy does),
//! so a 3.5 s braking window with 4 s segments still gives a spectrum, at 1/3.5 Hz resolution.
//!
//! What it is not: a spectral estimator with interpolated peaks. The dominant frequency is the
//! centre of the highest bin, as the paper and MODEL.md §11 define it, so its resolution is the
//! bin width `fs / nperseg`.

use super::AnalysisError;
use rustfft::num_complex::Complex64;
use rustfft::FftPlanner;
use std::f64::consts::PI;

/// A one-sided power spectral density on an even frequency grid.
#[derive(Debug, Clone, PartialEq)]
pub struct Psd {
    /// Bin centre frequencies (Hz): `k·df` for k = 0..=nfft/2.
    pub freqs_hz: Vec<f64>,
    /// Density (input units² per Hz) at each bin.
    pub density: Vec<f64>,
    /// Bin width (Hz).
    pub df_hz: f64,
    /// Samples per segment actually used.
    pub nperseg: usize,
    /// Number of averaged segments.
    pub segments: usize,
}

impl Psd {
    fn band_bins(&self, lo_hz: f64, hi_hz: f64) -> impl Iterator<Item = usize> + '_ {
        self.freqs_hz
            .iter()
            .enumerate()
            .filter(move |(_, f)| **f >= lo_hz && **f <= hi_hz)
            .map(|(i, _)| i)
    }

    /// Frequency (Hz) of the highest bin within `[lo_hz, hi_hz]`; `None` when the band holds no
    /// bin or no power.
    pub fn dominant_hz(&self, lo_hz: f64, hi_hz: f64) -> Option<f64> {
        let mut best: Option<(usize, f64)> = None;
        for i in self.band_bins(lo_hz, hi_hz) {
            let p = self.density[i];
            if p.is_finite() && p > 0.0 && best.is_none_or(|(_, bp)| p > bp) {
                best = Some((i, p));
            }
        }
        best.map(|(i, _)| self.freqs_hz[i])
    }

    /// Power (input units²) within `[lo_hz, hi_hz]`: `Σ P·Δf` over the bins in the band.
    pub fn band_power(&self, lo_hz: f64, hi_hz: f64) -> f64 {
        self.band_bins(lo_hz, hi_hz)
            .map(|i| self.density[i])
            .sum::<f64>()
            * self.df_hz
    }

    /// Total power over all bins (≈ the variance of the input).
    pub fn total_power(&self) -> f64 {
        self.density.iter().sum::<f64>() * self.df_hz
    }

    /// Spectral concentration (MODEL.md §11): the fraction of the power in `[lo_hz, hi_hz]`
    /// that lies within `±half_width_hz` of `f0_hz`. `None` when the band holds no power.
    /// MODEL.md uses `concentration(fdom, 0.5, 1.0, 40.0)`.
    pub fn concentration(
        &self,
        f0_hz: f64,
        half_width_hz: f64,
        lo_hz: f64,
        hi_hz: f64,
    ) -> Option<f64> {
        let total = self.band_power(lo_hz, hi_hz);
        if !(total > 0.0) {
            return None;
        }
        let near = self.band_power(
            lo_hz.max(f0_hz - half_width_hz),
            hi_hz.min(f0_hz + half_width_hz),
        );
        Some(near / total)
    }

    /// The MODEL.md §11 pair: dominant frequency in 1–40 Hz and the concentration of 1–40 Hz
    /// power within ±0.5 Hz of it.
    pub fn shimmy_features(&self) -> Option<(f64, f64)> {
        let f0 = self.dominant_hz(1.0, 40.0)?;
        Some((f0, self.concentration(f0, 0.5, 1.0, 40.0)?))
    }
}

/// Welch PSD of `x` sampled at `fs_hz`, with segments of `seg_s` seconds (Hann, 50 % overlap,
/// per-segment mean removed, one-sided density). Errors on a bad sampling rate or segment
/// length and on inputs of fewer than 2 samples.
pub fn welch(x: &[f64], fs_hz: f64, seg_s: f64) -> Result<Psd, AnalysisError> {
    if !(fs_hz.is_finite() && fs_hz > 0.0) {
        return Err(AnalysisError::BadSampleRate(fs_hz));
    }
    if !(seg_s.is_finite() && seg_s > 0.0) {
        return Err(AnalysisError::BadParameter(format!(
            "Welch segment length {seg_s} s"
        )));
    }
    if x.len() < 2 {
        return Err(AnalysisError::TooShort(format!(
            "Welch PSD needs at least 2 samples, got {}",
            x.len()
        )));
    }
    let want = (seg_s * fs_hz).round().max(2.0) as usize;
    let nperseg = want.min(x.len());
    let step = nperseg - nperseg / 2;
    let segments = (x.len() - nperseg) / step + 1;

    // Periodic Hann window (SciPy's default `get_window('hann', n)`).
    let window: Vec<f64> = (0..nperseg)
        .map(|i| 0.5 - 0.5 * (2.0 * PI * i as f64 / nperseg as f64).cos())
        .collect();
    let wss: f64 = window.iter().map(|w| w * w).sum();
    let fft = FftPlanner::<f64>::new().plan_fft_forward(nperseg);
    let mut buf = vec![Complex64::new(0.0, 0.0); nperseg];
    let mut scratch = vec![Complex64::new(0.0, 0.0); fft.get_inplace_scratch_len()];
    let nbins = nperseg / 2 + 1;
    let mut acc = vec![0.0; nbins];
    for s in 0..segments {
        let seg = &x[s * step..s * step + nperseg];
        let mean = seg.iter().sum::<f64>() / nperseg as f64;
        for ((b, v), w) in buf.iter_mut().zip(seg).zip(&window) {
            *b = Complex64::new((v - mean) * w, 0.0);
        }
        fft.process_with_scratch(&mut buf, &mut scratch);
        for (a, b) in acc.iter_mut().zip(&buf) {
            *a += b.norm_sqr();
        }
    }
    let scale = 1.0 / (fs_hz * wss * segments as f64);
    let density: Vec<f64> = acc
        .iter()
        .enumerate()
        .map(|(k, a)| {
            // One-sided: double everything except DC and (for even lengths) Nyquist.
            let one_sided = if k == 0 || (nperseg % 2 == 0 && k == nbins - 1) {
                1.0
            } else {
                2.0
            };
            a * scale * one_sided
        })
        .collect();
    let df_hz = fs_hz / nperseg as f64;
    Ok(Psd {
        freqs_hz: (0..nbins).map(|k| k as f64 * df_hz).collect(),
        density,
        df_hz,
        nperseg,
        segments,
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn rejects_bad_input() {
        assert!(welch(&[1.0], 100.0, 1.0).is_err());
        assert!(welch(&[1.0, 2.0], -1.0, 1.0).is_err());
        assert!(welch(&[1.0, 2.0], 100.0, 0.0).is_err());
    }

    #[test]
    fn segment_bookkeeping() {
        let x = vec![0.0; 1000];
        let p = welch(&x, 100.0, 2.0).unwrap();
        assert_eq!(p.nperseg, 200);
        assert_eq!(p.segments, 9); // (1000-200)/100 + 1
        assert_eq!(p.freqs_hz.len(), 101);
        assert_eq!(p.dominant_hz(1.0, 40.0), None);
        assert_eq!(p.concentration(5.0, 0.5, 1.0, 40.0), None);
    }
}
