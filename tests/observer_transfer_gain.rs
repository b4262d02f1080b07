//! `[estimator] transfer_gain`: a vehicle whose steering wheel moves `g` times as much as the
//! table's vehicle's for the same wheel motion is estimated as the table's vehicle would be,
//! and the events' marginal likelihood (`ln_evidence`) stays a density of what was measured,
//! so that it can be compared between gains.

use shimmy::observer::estimator::{Estimator, EstimatorConfig};
use shimmy::observer::features::{ln_jacobian_gain, Z_FLOOR_DEG};
use shimmy::observer::table::ResponseTable;

#[path = "support/synthetic_events.rs"]
mod synthetic_events;
use synthetic_events::reference_table as table;

/// Thirty events of a worn vehicle on the table's vehicle.
fn events() -> Vec<([f64; 3], f64, f64)> {
    synthetic_events::events(30, 1.0, 0)
}

fn run(t: &ResponseTable, gain: f64, scale: f64) -> Estimator {
    let cfg = EstimatorConfig {
        transfer_gain: gain,
        ..EstimatorConfig::default()
    };
    let mut e = Estimator::new(t, cfg).unwrap();
    for (i, (f, v, d)) in events().into_iter().enumerate() {
        e.update_event(
            t,
            f[0] * scale,
            f[1] * scale,
            Some(f[2] * scale),
            v,
            d,
            1000.0 * i as f64,
        );
    }
    e
}

#[test]
fn a_gain_undoes_the_same_scale_on_the_signal() {
    let t = table();
    let plain = run(&t, 1.0, 1.0);
    for g in [0.5, 1.3] {
        let scaled = run(&t, g, g);
        for (a, b) in plain.probabilities().zip(scaled.probabilities()) {
            assert!((a - b).abs() < 1e-9, "gain {g}: {a} vs {b}");
        }
        assert!((plain.quantile_mm(0.5) - scaled.quantile_mm(0.5)).abs() < 1e-9);
    }
}

#[test]
fn a_steering_wheel_that_moves_more_is_not_read_as_more_clearance() {
    let t = table();
    let plain = run(&t, 1.0, 1.3);
    let corrected = run(&t, 1.3, 1.3);
    assert!(
        corrected.quantile_mm(0.5) < plain.quantile_mm(0.5),
        "{} vs {}",
        corrected.quantile_mm(0.5),
        plain.quantile_mm(0.5)
    );
}

#[test]
fn the_evidence_is_reported_and_its_jacobian_vanishes_at_gain_one_and_far_above_the_floor() {
    let t = table();
    let [tempered, untempered] = run(&t, 1.0, 1.0)
        .ln_evidence()
        .expect("evidence after 30 events");
    assert!(tempered.is_finite() && untempered.is_finite());
    // The power (< 1) flattens the likelihood: the untempered evidence is the larger in size.
    assert!(untempered.abs() > tempered.abs());
    assert_eq!(ln_jacobian_gain(0.1, Z_FLOOR_DEG[0], 1.0), 0.0);
    assert!(ln_jacobian_gain(100.0, Z_FLOOR_DEG[1], 2.0).abs() < 1e-6);
    // Below the floor, a larger gain squeezes the table's statistic: the density falls.
    assert!(ln_jacobian_gain(0.001, Z_FLOOR_DEG[0], 2.0) < -1.0);
    // And the evidence of the same signal read with another gain changes.
    let other = run(&t, 1.3, 1.0).ln_evidence().unwrap()[0];
    assert!((other - tempered).abs() > 1e-6);
}

#[test]
fn a_gain_out_of_range_is_refused_with_its_key() {
    for g in [0.0, -1.0, f64::NAN, 50.0] {
        let cfg = EstimatorConfig {
            transfer_gain: g,
            ..EstimatorConfig::default()
        };
        let err = cfg.validate().unwrap_err().to_string();
        assert!(err.contains("estimator.transfer_gain"), "{err}");
    }
}
