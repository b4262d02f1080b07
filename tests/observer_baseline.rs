//! Baseline events (`Estimator::update_baseline`): events of the same vehicle at a known
//! clearance (its first ones after a joint replacement) tell the estimator how the vehicle's
//! features sit against the table's model, so that an offset the model does not know (a
//! sensor reading 30 % high, a stiffer transfer to the rim) is not read as clearance.

use shimmy::observer::estimator::{Estimator, EstimatorConfig};
use shimmy::observer::table::ResponseTable;

#[path = "support/synthetic_events.rs"]
mod synthetic_events;
use synthetic_events::{events, reference_table as table};

/// The estimator after `base` events at clearance `c_base_mm` (as baseline) and `now` events,
/// every feature read `scale` times as large.
fn run(t: &ResponseTable, base: &[([f64; 3], f64, f64)], c_base_mm: f64, scale: f64) -> Estimator {
    let mut e = Estimator::new(t, EstimatorConfig::default()).unwrap();
    for (f, v, d) in base {
        assert!(e.update_baseline(
            t,
            f[0] * scale,
            f[1] * scale,
            Some(f[2] * scale),
            *v,
            *d,
            c_base_mm
        ));
    }
    for (i, (f, v, d)) in events(30, 1.0, 0).into_iter().enumerate() {
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
fn a_baseline_alone_leaves_the_prior_and_counts_apart() {
    let t = table();
    let fresh = Estimator::new(&t, EstimatorConfig::default()).unwrap();
    let mut e = Estimator::new(&t, EstimatorConfig::default()).unwrap();
    for (f, v, d) in events(10, 0.6, 3) {
        assert!(e.update_baseline(&t, f[0], f[1], Some(f[2]), v, d, 0.03));
    }
    assert_eq!((e.events_used(), e.baseline_events()), (0, 10));
    for (a, b) in fresh.probabilities().zip(e.probabilities()) {
        assert!((a - b).abs() < 1e-9, "{a} vs {b}");
    }
    assert!(
        e.fit().is_none(),
        "no event of its own yet: no goodness of fit"
    );
}

/// A sensor reading 30 % high (a wrong N·m or degrees per count) moves the plain estimate up
/// by the gain's ln; with a baseline of the same vehicle at new joints, read through the same
/// sensor, most of that shift is taken out.
#[test]
fn a_baseline_takes_out_most_of_a_sensor_gain() {
    let t = table();
    let base = events(10, 0.6, 3);
    let median = |b: &[([f64; 3], f64, f64)], scale| run(&t, b, 0.03, scale).quantile_mm(0.5);
    let shift_plain = (median(&[], 1.3) / median(&[], 1.0)).ln();
    let shift_base = (median(&base, 1.3) / median(&base, 1.0)).ln();
    assert!(
        shift_plain > 0.1,
        "the gain moves the plain estimate by ln {shift_plain:.3}"
    );
    assert!(
        shift_base.abs() < 0.5 * shift_plain,
        "with the baseline the gain moves the estimate by ln {shift_base:.3}, without by ln \
         {shift_plain:.3}"
    );
}
