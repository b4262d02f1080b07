//! Band-pass filter (MODEL.md §11): gain against the closed-form Butterworth magnitude, zero
//! phase, and agreement with SciPy's `sosfiltfilt` on a recorded reference.
//!
//! SciPy cross-check (done once, SciPy 1.17.1; Python is not needed to run these tests):
//! ```python
//! sos = scipy.signal.butter(4, [3, 25], 'bandpass', fs=1000.0, output='sos')
//! ys = scipy.signal.sosfiltfilt(sos, x)   # x = test_signal() below
//! ```
//! The whole 3600-sample output agreed with ours to 1.5e-13 (edges included), `sosfreqz`
//! magnitudes at 1/3/7/25/60 Hz to all printed digits, and `signal.welch` densities (1 s
//! segments; and 4 s segments on this 3.6 s signal, where SciPy falls back to one segment) to
//! 2e-16 relative. A few of SciPy's output samples are pinned below.

use shimmy::analysis::filter::{bandpass_zero_phase, shimmy_bandpass, Bandpass};
use std::f64::consts::PI;

const FS: f64 = 1000.0;

fn sine(f_hz: f64, n: usize, phase: f64) -> Vec<f64> {
    (0..n)
        .map(|i| (2.0 * PI * f_hz * i as f64 / FS + phase).sin())
        .collect()
}

fn test_signal() -> Vec<f64> {
    (0..3600)
        .map(|i| {
            let t = i as f64 / FS;
            (2.0 * PI * 7.0 * t).sin()
                + 0.5 * (2.0 * PI * 1.0 * t).sin()
                + 0.3 * (2.0 * PI * 60.0 * t).sin()
                + 0.2 * t
                + 0.1 * ((i * i) as f64 * 0.001).sin()
        })
        .collect()
}

#[test]
fn design_matches_closed_form_butterworth_magnitude() {
    let f = Bandpass::new(FS, 3.0, 25.0, 4).unwrap();
    // Band edges are -3 dB per pass, centre is exactly 1.
    assert!((f.response(3.0).norm() - 0.5f64.sqrt()).abs() < 1e-9);
    assert!((f.response(25.0).norm() - 0.5f64.sqrt()).abs() < 1e-9);
    let c = f.centre_hz();
    assert!(c > 8.0 && c < 9.0, "centre {c}");
    assert!((f.response(c).norm() - 1.0).abs() < 1e-9);
    for k in 1..400 {
        let fr = k as f64 * 0.25;
        let got = f.response(fr).norm();
        let want = f.ideal_magnitude(fr);
        assert!(
            (got - want).abs() < 1e-9 * want.max(1e-6) + 1e-12,
            "{fr} Hz: {got} vs {want}"
        );
    }
    // Well attenuated outside: one pass ≈ 0.0078 at 1 Hz and 0.019 at 60 Hz (SciPy: 0.00781873,
    // 0.01888408); the zero-phase filter squares these.
    assert!((f.response(1.0).norm() - 0.00781873).abs() < 1e-8);
    assert!((f.response(60.0).norm() - 0.01888408).abs() < 1e-8);
}

#[test]
fn filtfilt_gain_is_squared_magnitude_in_steady_state() {
    let f = Bandpass::new(FS, 3.0, 25.0, 4).unwrap();
    for &fr in &[1.0, 2.0, 5.0, 8.66, 12.0, 30.0, 60.0] {
        let x = sine(fr, 20_000, 0.3);
        let y = f.filtfilt(&x);
        // Amplitude in the middle, away from the edges.
        let amp = y[5000..15000].iter().fold(0.0f64, |m, v| m.max(v.abs()));
        let want = f.ideal_magnitude(fr).powi(2);
        assert!(
            (amp - want).abs() < 2e-3 * want.max(1e-3),
            "{fr} Hz: {amp} vs {want}"
        );
    }
}

#[test]
fn filtfilt_is_zero_phase() {
    // A 7 Hz sine: the filtered peaks sit where the input's peaks are (single sample), while a
    // causal pass shifts them by its group delay.
    let x = sine(7.0, 6000, 0.0);
    let f = Bandpass::new(FS, 3.0, 25.0, 4).unwrap();
    let y = f.filtfilt(&x);
    let causal = f.filter(&x);
    let argmax =
        |v: &[f64], lo: usize, hi: usize| (lo..hi).max_by(|&a, &b| v[a].total_cmp(&v[b])).unwrap();
    // Input peaks at t = (0.25 + k)/7 s; check one in the middle.
    let (lo, hi) = (2900, 3050);
    let px = argmax(&x, lo, hi);
    let py = argmax(&y, lo, hi);
    assert!(
        px.abs_diff(py) <= 1,
        "input peak {px}, zero-phase peak {py}"
    );
    let pc = argmax(&causal, px - 70, px + 70);
    assert!(
        pc.abs_diff(px) > 5,
        "a causal pass should shift the peak: {pc} vs {px}"
    );
    // And the whole interior is the same sine within the pass-band gain.
    let g = f.ideal_magnitude(7.0).powi(2);
    for i in 1500..4500 {
        assert!((y[i] - g * x[i]).abs() < 1e-3, "sample {i}");
    }
}

#[test]
fn removes_offset_and_trend() {
    let x: Vec<f64> = (0..5000).map(|i| 3.0 + 0.5 * i as f64 / FS).collect();
    let y = shimmy_bandpass(&x, FS).unwrap();
    // An offset of 3 and a ramp rising 2.5 leave only a small start-up transient near the ends
    // (the steady-state start is exact for a step, not for a ramp) and nothing in the middle.
    let max = |v: &[f64]| v.iter().fold(0.0f64, |m, a| m.max(a.abs()));
    assert!(max(&y) < 5e-3, "edges {}", max(&y));
    assert!(
        max(&y[1500..3500]) < 1e-5,
        "interior {}",
        max(&y[1500..3500])
    );
}

#[test]
fn agrees_with_scipy_sosfiltfilt_reference() {
    let y = bandpass_zero_phase(&test_signal(), FS, 3.0, 25.0, 4).unwrap();
    let reference = [
        (0, 0.17413964974185192),
        (5, 0.3885362082638127),
        (100, -1.0109242430513037),
        (1800, -0.5878044305467236),
        (3590, 0.3134506129165465),
        (3599, 0.19046691569834842),
    ];
    for (i, want) in reference {
        assert!(
            (y[i] - want).abs() < 1e-10,
            "sample {i}: {} vs {want}",
            y[i]
        );
    }
}
