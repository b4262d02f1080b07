//! Zero-phase Butterworth band-pass as a cascade of second-order sections (MODEL.md §11:
//! "4th-order Butterworth, 3–25 Hz, zero phase").
//!
//! What it is: the textbook design — analog Butterworth low-pass prototype of order N, low-pass
//! to band-pass transform (2N poles), bilinear transform with pre-warped band edges — stored as
//! N second-order sections, and a forward–backward filter with odd edge padding and steady-state
//! initial conditions, the same scheme as SciPy's `sosfiltfilt` (padding length 3·(2N+1)
//! samples). "Order" follows SciPy's `butter(N, [lo, hi], 'bandpass')`: N is the prototype order,
//! so the band-pass has 2N poles and the zero-phase filter's magnitude is the square of the
//! single pass.
//!
//! What it is not: a streaming filter. Forward–backward filtering needs the whole window, which
//! is how MODEL.md §11 uses it (on a recorded braking event).
//!
//! Checked against SciPy 1.17 once (see tests/analysis_filter.rs for the method and numbers);
//! the tests themselves check closed-form properties and need no Python.

use super::AnalysisError;
use rustfft::num_complex::Complex64;
use std::f64::consts::PI;

/// One biquad: `b0 + b1 z⁻¹ + b2 z⁻² / (1 + a1 z⁻¹ + a2 z⁻²)`, as `[b0, b1, b2, 1, a1, a2]`
/// (SciPy's SOS row layout).
pub type Section = [f64; 6];

/// A designed Butterworth band-pass filter.
#[derive(Debug, Clone)]
pub struct Bandpass {
    sections: Vec<Section>,
    fs_hz: f64,
    lo_hz: f64,
    hi_hz: f64,
    order: usize,
}

impl Bandpass {
    /// Design an order-`order` Butterworth band-pass between `lo_hz` and `hi_hz` for samples at
    /// `fs_hz`. Errors on a non-positive sampling rate, a band outside (0, fs/2), or an order
    /// outside 1..=12.
    pub fn new(fs_hz: f64, lo_hz: f64, hi_hz: f64, order: usize) -> Result<Self, AnalysisError> {
        if !(fs_hz.is_finite() && fs_hz > 0.0) {
            return Err(AnalysisError::BadSampleRate(fs_hz));
        }
        if !(lo_hz.is_finite()
            && hi_hz.is_finite()
            && lo_hz > 0.0
            && lo_hz < hi_hz
            && hi_hz < fs_hz / 2.0)
        {
            return Err(AnalysisError::BadBand {
                lo_hz,
                hi_hz,
                fs_hz,
            });
        }
        if !(1..=12).contains(&order) {
            return Err(AnalysisError::BadOrder(order));
        }
        let n = order;
        let fs2 = 2.0 * fs_hz;
        // Pre-warped analog band edges (rad/s) so the digital edges land on lo/hi exactly.
        let w1 = fs2 * (PI * lo_hz / fs_hz).tan();
        let w2 = fs2 * (PI * hi_hz / fs_hz).tan();
        let bw = w2 - w1;
        let w0sq = w1 * w2;

        // Analog prototype poles on the unit circle's left half, low-pass → band-pass, bilinear.
        let mut zpoles: Vec<Complex64> = Vec::with_capacity(2 * n);
        let mut denom = Complex64::new(1.0, 0.0);
        for k in 1..=n {
            let theta = PI * (2 * k + n - 1) as f64 / (2 * n) as f64;
            let p = Complex64::from_polar(1.0, theta);
            let half = p * (bw / 2.0);
            let root = (half * half - w0sq).sqrt();
            for s in [half + root, half - root] {
                denom *= fs2 - s;
                zpoles.push((fs2 + s) / (fs2 - s));
            }
        }
        // N analog zeros at s = 0 map to z = +1; N at infinity map to z = −1.
        let k_digital = (Complex64::new((bw * fs2).powi(n as i32), 0.0) / denom).re;

        // Group the poles into biquads: a complex pole with its conjugate, real poles in pairs.
        let mut denominators: Vec<[f64; 2]> = Vec::with_capacity(n);
        let mut reals: Vec<f64> = Vec::new();
        for p in &zpoles {
            if p.im > 1e-12 {
                denominators.push([-2.0 * p.re, p.norm_sqr()]);
            } else if p.im.abs() <= 1e-12 {
                reals.push(p.re);
            }
        }
        reals.sort_by(|a, b| a.total_cmp(b));
        for pair in reals.chunks(2) {
            let (r1, r2) = (pair[0], *pair.get(1).unwrap_or(&0.0));
            denominators.push([-(r1 + r2), r1 * r2]);
        }
        debug_assert_eq!(denominators.len(), n);
        // Spread the gain evenly over the sections (keeps intermediate values well scaled).
        let g = k_digital.abs().powf(1.0 / n as f64);
        let sections = denominators
            .iter()
            .enumerate()
            .map(|(i, a)| {
                let gi = if i == 0 { g * k_digital.signum() } else { g };
                [gi, 0.0, -gi, 1.0, a[0], a[1]]
            })
            .collect();
        Ok(Self {
            sections,
            fs_hz,
            lo_hz,
            hi_hz,
            order,
        })
    }

    /// The second-order sections, `[b0, b1, b2, 1, a1, a2]` each.
    pub fn sections(&self) -> &[Section] {
        &self.sections
    }

    /// Sampling rate the filter was designed for (Hz).
    pub fn fs_hz(&self) -> f64 {
        self.fs_hz
    }

    /// Band edges (Hz) and prototype order.
    pub fn band(&self) -> (f64, f64, usize) {
        (self.lo_hz, self.hi_hz, self.order)
    }

    /// Complex response of ONE forward pass at `f_hz`.
    pub fn response(&self, f_hz: f64) -> Complex64 {
        let z1 = Complex64::from_polar(1.0, -2.0 * PI * f_hz / self.fs_hz);
        let z2 = z1 * z1;
        self.sections.iter().fold(Complex64::new(1.0, 0.0), |h, s| {
            h * (s[0] + s[1] * z1 + s[2] * z2) / (1.0 + s[4] * z1 + s[5] * z2)
        })
    }

    /// Closed-form magnitude of one pass of the ideal digital Butterworth band-pass at `f_hz`:
    /// `1/sqrt(1 + w^(2N))` with `w = (Ω² − Ω1Ω2) / (Ω (Ω2 − Ω1))` and `Ω = 2 fs tan(π f / fs)`.
    /// Used to check the design; the zero-phase filter's gain is the square of this.
    pub fn ideal_magnitude(&self, f_hz: f64) -> f64 {
        let warp = |f: f64| 2.0 * self.fs_hz * (PI * f / self.fs_hz).tan();
        let (w1, w2, om) = (warp(self.lo_hz), warp(self.hi_hz), warp(f_hz));
        let w = (om * om - w1 * w2) / (om * (w2 - w1));
        1.0 / (1.0 + w.powi(2 * self.order as i32)).sqrt()
    }

    /// Centre frequency (Hz) where the single-pass gain is exactly 1: the digital image of the
    /// analog geometric centre.
    pub fn centre_hz(&self) -> f64 {
        let warp = |f: f64| 2.0 * self.fs_hz * (PI * f / self.fs_hz).tan();
        let w0 = (warp(self.lo_hz) * warp(self.hi_hz)).sqrt();
        self.fs_hz / PI * (w0 / (2.0 * self.fs_hz)).atan()
    }

    /// Steady-state section states for a unit step input (SciPy `sosfilt_zi`): multiply by the
    /// first sample to start the filter without a transient.
    fn step_states(&self) -> Vec<[f64; 2]> {
        let mut scale = 1.0;
        self.sections
            .iter()
            .map(|s| {
                let (b0, b1, b2, a1, a2) = (s[0], s[1], s[2], s[4], s[5]);
                let g = (b0 + b1 + b2) / (1.0 + a1 + a2);
                let z1 = b2 - a2 * g;
                let z0 = b1 - a1 * g + z1;
                let out = [scale * z0, scale * z1];
                scale *= g;
                out
            })
            .collect()
    }

    /// One causal pass over `x` in place (transposed direct form II per section) starting from
    /// states `zi` scaled by `x0`.
    fn pass(&self, x: &mut [f64], zi: &[[f64; 2]], x0: f64) {
        let mut z: Vec<[f64; 2]> = zi.iter().map(|s| [s[0] * x0, s[1] * x0]).collect();
        for v in x.iter_mut() {
            let mut u = *v;
            for (s, st) in self.sections.iter().zip(z.iter_mut()) {
                let y = s[0] * u + st[0];
                st[0] = s[1] * u - s[4] * y + st[1];
                st[1] = s[2] * u - s[5] * y;
                u = y;
            }
            *v = u;
        }
    }

    /// Causal (single pass, phase-shifting) filtering with zero initial state.
    pub fn filter(&self, x: &[f64]) -> Vec<f64> {
        let mut y = x.to_vec();
        let zi = vec![[0.0; 2]; self.sections.len()];
        self.pass(&mut y, &zi, 0.0);
        y
    }

    /// Zero-phase forward–backward filtering of `x` (SciPy `sosfiltfilt` scheme: odd extension
    /// of `3·(2N+1)` samples at each end, steady-state initial conditions). Inputs shorter than
    /// the padding use a padding of `len − 1` samples (SciPy refuses them). Empty in, empty
    /// out. NaN samples propagate; check with [`super::count_non_finite`].
    pub fn filtfilt(&self, x: &[f64]) -> Vec<f64> {
        let n = x.len();
        if n == 0 {
            return Vec::new();
        }
        let edge = (3 * (2 * self.sections.len() + 1)).min(n - 1);
        let mut ext = Vec::with_capacity(n + 2 * edge);
        let (first, last) = (x[0], x[n - 1]);
        ext.extend((1..=edge).rev().map(|i| 2.0 * first - x[i]));
        ext.extend_from_slice(x);
        ext.extend((1..=edge).map(|i| 2.0 * last - x[n - 1 - i]));
        let zi = self.step_states();
        let x0 = ext[0];
        self.pass(&mut ext, &zi, x0);
        ext.reverse();
        let y0 = ext[0];
        self.pass(&mut ext, &zi, y0);
        ext.reverse();
        ext.drain(..edge);
        ext.truncate(n);
        ext
    }
}

/// Zero-phase Butterworth band-pass of `x` (MODEL.md §11): design with [`Bandpass::new`] and run
/// [`Bandpass::filtfilt`]. For repeated use on many windows, keep a [`Bandpass`].
pub fn bandpass_zero_phase(
    x: &[f64],
    fs_hz: f64,
    lo_hz: f64,
    hi_hz: f64,
    order: usize,
) -> Result<Vec<f64>, AnalysisError> {
    Ok(Bandpass::new(fs_hz, lo_hz, hi_hz, order)?.filtfilt(x))
}

/// The shimmy band-pass of MODEL.md §11: 4th order, 3–25 Hz, zero phase.
pub fn shimmy_bandpass(x: &[f64], fs_hz: f64) -> Result<Vec<f64>, AnalysisError> {
    bandpass_zero_phase(x, fs_hz, 3.0, 25.0, 4)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn rejects_bad_designs() {
        assert!(matches!(
            Bandpass::new(0.0, 3.0, 25.0, 4),
            Err(AnalysisError::BadSampleRate(_))
        ));
        assert!(matches!(
            Bandpass::new(1000.0, 25.0, 3.0, 4),
            Err(AnalysisError::BadBand { .. })
        ));
        assert!(matches!(
            Bandpass::new(40.0, 3.0, 25.0, 4),
            Err(AnalysisError::BadBand { .. })
        ));
        assert!(matches!(
            Bandpass::new(1000.0, 3.0, 25.0, 0),
            Err(AnalysisError::BadOrder(0))
        ));
    }

    #[test]
    fn odd_orders_design_too() {
        for order in 1..=7 {
            let f = Bandpass::new(1000.0, 3.0, 25.0, order).unwrap();
            assert_eq!(f.sections().len(), order);
            let c = f.centre_hz();
            assert!((f.response(c).norm() - 1.0).abs() < 1e-9, "order {order}");
        }
    }

    #[test]
    fn short_inputs_do_not_panic() {
        let f = Bandpass::new(1000.0, 3.0, 25.0, 4).unwrap();
        assert!(f.filtfilt(&[]).is_empty());
        assert_eq!(f.filtfilt(&[1.0]).len(), 1);
        assert_eq!(f.filtfilt(&[1.0, 2.0, 3.0]).len(), 3);
    }
}
