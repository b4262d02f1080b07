//! Poincaré sections and finite-time Lyapunov exponents on systems with known answers.

use shimmy::analysis::chaos::{
    count_distinct, lyapunov_from_twins, lyapunov_twin_runs, poincare_section, Direction,
    LyapunovOptions, Trajectory,
};
use shimmy::analysis::AnalysisError;
use std::f64::consts::{LN_2, PI};

#[test]
fn poincare_of_a_sine_is_one_point_and_of_period_two_is_two() {
    let dt = 1e-3;
    let t: Vec<f64> = (0..20_000).map(|i| i as f64 * dt).collect();
    let x: Vec<f64> = t.iter().map(|t| (2.0 * PI * 3.0 * t).sin()).collect();
    let v: Vec<f64> = t
        .iter()
        .map(|t| 2.0 * PI * 3.0 * (2.0 * PI * 3.0 * t).cos())
        .collect();
    // Section x' = 0 with x > 0 (the maxima).
    let pts = poincare_section(&v, 0.0, Direction::Down, &[&x, &v], |p| p[0] > 0.0);
    assert_eq!(pts.len(), 60);
    assert_eq!(count_distinct(&pts, 1e-3), 1);
    assert!(pts.iter().all(|p| (p[0] - 1.0).abs() < 1e-4));

    // Sum of a 3 Hz and a 1.5 Hz tone: period-2 in the 3 Hz maxima.
    let y: Vec<f64> = t
        .iter()
        .map(|t| (2.0 * PI * 3.0 * t).sin() + 0.3 * (2.0 * PI * 1.5 * t).sin())
        .collect();
    let dy: Vec<f64> = y.windows(2).map(|w| (w[1] - w[0]) / dt).collect();
    let pts2 = poincare_section(&dy, 0.0, Direction::Down, &[&y[..dy.len()]], |p| p[0] > 0.5);
    assert!(pts2.len() >= 50, "{}", pts2.len());
    assert_eq!(count_distinct(&pts2, 1e-2), 2);
}

fn logistic(x0: f64, n: usize) -> Vec<f64> {
    let mut x = x0;
    (0..n)
        .map(|_| {
            let v = x;
            x = 4.0 * x * (1.0 - x);
            v
        })
        .collect()
}

#[test]
fn logistic_map_r4_has_exponent_ln2() {
    // Twin orbits 1e-9 apart; "time" is the iteration count. Fit from 0 until the separation
    // reaches 1e-3, average over many starts (single finite-time estimates scatter).
    let opts = LyapunovOptions {
        t_start: 0.0,
        t_end: 60.0,
        saturation: 1e-3,
        min_points: 8,
        min_span: 5.0,
    };
    let n = 60;
    let t: Vec<f64> = (0..n).map(|i| i as f64).collect();
    let mut sum = 0.0;
    let mut count = 0;
    for k in 0..200 {
        let x0 = 0.05 + 0.9 * (k as f64 + 0.5) / 200.0;
        let a = logistic(x0, n);
        let b = logistic(x0 * (1.0 + 1e-9), n);
        if let Ok(fit) = lyapunov_from_twins(&t, &[&a], &[&b], &[1.0], &opts) {
            sum += fit.lambda;
            count += 1;
        }
    }
    assert!(count > 150, "{count}");
    let mean = sum / count as f64;
    assert!(
        (mean - LN_2).abs() < 0.08,
        "mean exponent {mean} vs ln 2 = {LN_2}"
    );
}

/// RK4 of the damped oscillator x'' + 2ζω x' + ω² x = 0 from (x0, v0), sampled each step.
fn damped(x0: f64, v0: f64, zeta: f64, omega: f64, dt: f64, n: usize) -> Trajectory {
    let f = |x: f64, v: f64| (v, -2.0 * zeta * omega * v - omega * omega * x);
    let (mut x, mut v) = (x0, v0);
    let mut out = Trajectory {
        t: Vec::with_capacity(n),
        components: vec![Vec::new(), Vec::new()],
    };
    for i in 0..n {
        out.t.push(i as f64 * dt);
        out.components[0].push(x);
        out.components[1].push(v);
        let (k1x, k1v) = f(x, v);
        let (k2x, k2v) = f(x + 0.5 * dt * k1x, v + 0.5 * dt * k1v);
        let (k3x, k3v) = f(x + 0.5 * dt * k2x, v + 0.5 * dt * k2v);
        let (k4x, k4v) = f(x + dt * k3x, v + dt * k3v);
        x += dt / 6.0 * (k1x + 2.0 * k2x + 2.0 * k3x + k4x);
        v += dt / 6.0 * (k1v + 2.0 * k2v + 2.0 * k3v + k4v);
    }
    out
}

#[test]
fn damped_linear_system_has_negative_exponent_equal_to_minus_zeta_omega() {
    let (zeta, omega) = (0.1, 2.0 * PI * 5.0);
    let run = |eps: f64| -> Result<Trajectory, AnalysisError> {
        // Perturb the initial velocity by a relative eps, as MODEL.md §11 does with θ1'(0).
        Ok(damped(0.0, 0.02 * (1.0 + eps), zeta, omega, 1e-3, 3000))
    };
    let fit = lyapunov_twin_runs(run, 1e-9, &LyapunovOptions::default()).unwrap();
    assert!(fit.lambda < 0.0);
    assert!(
        (fit.lambda + zeta * omega).abs() < 0.1 * zeta * omega,
        "λ = {} vs {}",
        fit.lambda,
        -zeta * omega
    );
    assert!(fit.saturated_at.is_none());
}

#[test]
fn unstable_linear_system_has_positive_exponent_until_saturation() {
    // Negative damping: separation grows as e^{0.05·ω t}; with a large perturbation it saturates
    // inside the window and the fit stops there.
    let (zeta, omega) = (-0.05, 2.0 * PI * 5.0);
    let run = |eps: f64| -> Result<Trajectory, AnalysisError> {
        Ok(damped(0.0, 1.0 + eps, zeta, omega, 1e-3, 3000))
    };
    let opts = LyapunovOptions {
        saturation: 0.05,
        ..Default::default()
    };
    let fit = lyapunov_twin_runs(run, 0.05, &opts).unwrap();
    assert!(
        (fit.lambda - 0.05 * omega).abs() < 0.15 * 0.05 * omega,
        "λ = {}",
        fit.lambda
    );
    assert!(fit.saturated_at.is_some(), "{fit:?}");
}
