//! Morlet CWT and time–frequency entropy on signals with known answers.

use shimmy::analysis::cwt::{log_freqs, morlet, Cwt};
use shimmy::analysis::sweep::linspace;
use std::f64::consts::PI;

const FS: f64 = 200.0;

#[test]
fn sine_amplitude_is_read_on_its_ridge() {
    // Amplitude normalisation: |W| ≈ A at the sine's frequency, whatever the frequency.
    for (f0, amp) in [(3.0, 0.5), (7.0, 2.0), (18.0, 1.0)] {
        let x: Vec<f64> = (0..2000)
            .map(|i| amp * (2.0 * PI * f0 * i as f64 / FS).sin())
            .collect();
        let w = morlet(&x, FS, &[f0, f0 * 1.5], 1).unwrap();
        let mid = w.at(0, 1000);
        assert!(
            (mid - amp).abs() < 0.01 * amp,
            "{f0} Hz: |W| {mid} vs {amp}"
        );
        // Off the ridge it follows the Morlet's Gaussian: at 1.5·f0, sω = ω0/1.5 = 4, so the
        // gain is exp(−(4 − 6)²/2) = e^−2.
        let off = w.at(1, 1000);
        let want = amp * (-2.0f64).exp();
        assert!(
            (off - want).abs() < 0.02 * want,
            "{f0} Hz: off-ridge {off} vs {want}"
        );
    }
}

#[test]
fn ridge_tracks_a_linear_chirp() {
    // f(t) = 3 + 1.2 t Hz over 10 s (3 → 15 Hz).
    let n = (10.0 * FS) as usize;
    let x: Vec<f64> = (0..n)
        .map(|i| {
            let t = i as f64 / FS;
            (2.0 * PI * (3.0 * t + 0.6 * t * t)).sin()
        })
        .collect();
    let freqs = linspace(1.0, 20.0, 191); // 0.1 Hz grid
    let w = morlet(&x, FS, &freqs, 10).unwrap();
    let ridge = w.ridge_hz();
    let mut checked = 0;
    for (j, t) in w.times_s.iter().enumerate() {
        let f_true = 3.0 + 1.2 * t;
        // Skip the cone of influence at both ends.
        if *t < Cwt::coi_s(f_true) + 0.5 || *t > 10.0 - Cwt::coi_s(f_true) - 0.5 {
            continue;
        }
        assert!(
            (ridge[j] - f_true).abs() < 0.05 * f_true + 0.1,
            "t={t}: ridge {} vs {f_true}",
            ridge[j]
        );
        checked += 1;
    }
    assert!(checked > 150, "{checked}");
}

#[test]
fn entropy_is_low_for_a_tone_and_high_for_noise_and_rises_with_a_second_tone() {
    let freqs = log_freqs(1.0, 40.0, 48);
    let n = 4000;
    let tone: Vec<f64> = (0..n)
        .map(|i| (2.0 * PI * 7.0 * i as f64 / FS).sin())
        .collect();
    let two: Vec<f64> = tone
        .iter()
        .enumerate()
        .map(|(i, v)| v + (2.0 * PI * 16.0 * i as f64 / FS).sin())
        .collect();
    // Deterministic broadband signal: a logistic-map sequence (chaotic, flat-ish spectrum).
    let mut z = 0.3;
    let noise: Vec<f64> = (0..n)
        .map(|_| {
            z = 4.0 * z * (1.0 - z);
            z - 0.5
        })
        .collect();
    let h = |x: &[f64]| {
        let w = morlet(x, FS, &freqs, 20).unwrap();
        (
            w.tf_entropy_bits().unwrap(),
            w.scale_entropy_bits().unwrap(),
        )
    };
    let (ht, st) = h(&tone);
    let (h2, s2) = h(&two);
    let (hn, sn) = h(&noise);
    assert!(
        ht < h2 && h2 < hn,
        "tf entropy tone {ht}, two tones {h2}, noise {hn}"
    );
    assert!(
        st < s2 && s2 < sn,
        "scale entropy tone {st}, two tones {s2}, noise {sn}"
    );
    // Two equal tones add about one bit of spectral spread.
    assert!((s2 - st - 1.0).abs() < 0.35, "{}", s2 - st);
    // Most of the tone's energy is near 7 Hz.
    let w = morlet(&tone, FS, &freqs, 20).unwrap();
    assert!(w.band_energy_fraction(6.0, 8.2).unwrap() > 0.5);
}
