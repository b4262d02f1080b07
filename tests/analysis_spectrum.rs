//! Welch PSD, dominant frequency and spectral concentration (MODEL.md §11) on signals whose
//! answers are known in closed form. (SciPy cross-check: see tests/analysis_filter.rs.)

use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use shimmy::analysis::spectrum::welch;
use std::f64::consts::PI;

const FS: f64 = 1000.0;

fn sine(f_hz: f64, amp: f64, secs: f64) -> Vec<f64> {
    let n = (secs * FS) as usize;
    (0..n)
        .map(|i| amp * (2.0 * PI * f_hz * i as f64 / FS + 0.4).sin())
        .collect()
}

fn white(n: usize, sigma: f64, seed: u64) -> Vec<f64> {
    // Sum of 12 uniforms − 6: unit-variance, near-Gaussian, no extra crate needed.
    let mut rng = ChaCha8Rng::seed_from_u64(seed);
    (0..n)
        .map(|_| sigma * ((0..12).map(|_| rng.random::<f64>()).sum::<f64>() - 6.0))
        .collect()
}

#[test]
fn finds_sine_frequency_and_power() {
    // 6.75 Hz sits exactly on a bin with 4 s segments (0.25 Hz bins).
    let x = sine(6.75, 2.0, 20.0);
    let p = welch(&x, FS, 4.0).unwrap();
    assert_eq!(p.nperseg, 4000);
    assert_eq!(p.segments, 9);
    assert_eq!(p.dominant_hz(1.0, 40.0), Some(6.75));
    // Parseval: power = amp²/2 = 2.
    assert!(
        (p.total_power() - 2.0).abs() < 0.01,
        "total {}",
        p.total_power()
    );
    assert!((p.band_power(1.0, 40.0) - 2.0).abs() < 0.01);
    // A sine off the grid still lands in the nearest bin.
    let q = welch(&sine(7.1, 1.0, 20.0), FS, 4.0).unwrap();
    assert_eq!(q.dominant_hz(1.0, 40.0), Some(7.0));
    // The band limits are honoured.
    let two = x
        .iter()
        .zip(sine(20.0, 5.0, 20.0))
        .map(|(a, b)| a + b)
        .collect::<Vec<_>>();
    let p2 = welch(&two, FS, 4.0).unwrap();
    assert_eq!(p2.dominant_hz(1.0, 40.0), Some(20.0));
    assert_eq!(p2.dominant_hz(1.0, 10.0), Some(6.75));
}

#[test]
fn white_noise_density_is_flat_at_variance_over_nyquist() {
    let sigma = 0.5;
    let x = white(200_000, sigma, 7);
    let p = welch(&x, FS, 1.0).unwrap();
    let expected = sigma * sigma / (FS / 2.0);
    let mid: Vec<f64> = p.density[50..450].to_vec();
    let mean = mid.iter().sum::<f64>() / mid.len() as f64;
    assert!(
        (mean / expected - 1.0).abs() < 0.03,
        "mean density {mean} vs {expected}"
    );
    assert!((p.total_power() / (sigma * sigma) - 1.0).abs() < 0.02);
}

#[test]
fn concentration_of_sine_is_near_one_and_of_noise_small() {
    let x = sine(6.75, 1.0, 20.0);
    let p = welch(&x, FS, 4.0).unwrap();
    let (f0, conc) = p.shimmy_features().unwrap();
    assert_eq!(f0, 6.75);
    assert!(conc > 0.99, "sine concentration {conc}");

    let n = white(20_000, 1.0, 3);
    let pn = welch(&n, FS, 4.0).unwrap();
    let (_, cn) = pn.shimmy_features().unwrap();
    // ±0.5 Hz of 39 Hz is ~1/39 of the band for a flat spectrum.
    assert!(cn < 0.06, "noise concentration {cn}");

    // A mixture sits in between, in proportion to the power near the peak.
    let mix: Vec<f64> = x.iter().zip(&n).map(|(a, b)| a + 0.3 * b).collect();
    let pm = welch(&mix, FS, 4.0).unwrap();
    let (_, cm) = pm.shimmy_features().unwrap();
    assert!(cm > cn && cm < conc, "mixture {cm}");
}

#[test]
fn short_window_is_one_segment_of_its_own_length() {
    // A 3.5 s braking window with 4 s segments: one segment, 1/3.5 Hz bins, still right.
    let x = sine(6.0, 1.0, 3.5);
    let p = welch(&x, FS, 4.0).unwrap();
    assert_eq!(p.nperseg, 3500);
    assert_eq!(p.segments, 1);
    let f0 = p.dominant_hz(1.0, 40.0).unwrap();
    assert!((f0 - 6.0).abs() <= p.df_hz / 2.0 + 1e-12, "{f0}");
    assert!((p.total_power() - 0.5).abs() < 0.02);
}
