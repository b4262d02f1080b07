//! The response table's model events (issue 5 item 3) as the fleet's vehicles see them: a
//! drive-shaped event (cruise first, no initial kick, the driver's pedal law) is found by the
//! same detector as a measured one, with the requested speed and deceleration, and its
//! steering-wheel features grow with clearance; the nuisance vehicles of a table are drawn
//! from issue 5's prior and are the same at every clearance.

use shimmy::cli::calibrate::nuisance_vehicle;
use shimmy::model::VehicleParams;
use shimmy::observer::sensor::SensorModel;
use shimmy::observer::simulate::{simulate_event, EventShape, NuisanceRanges};
use shimmy::observer::ObserverConfig;

#[test]
fn a_drive_shaped_event_is_detected_as_requested_and_grows_with_clearance() {
    let p = VehicleParams::default();
    let cfg = ObserverConfig::default();
    let run = |c_mm: f64| {
        simulate_event(
            &p,
            c_mm * 1e-3,
            60.0 / 3.6,
            0.7,
            31,
            EventShape::DRIVE,
            &SensorModel::default(),
            &cfg,
        )
        .unwrap()
    };
    let small = run(0.03);
    let large = run(0.5);
    for e in [&small, &large] {
        assert!(e.used, "{e:?}");
        assert!((e.v0_kmh - 60.0).abs() < 2.0, "v0 {}", e.v0_kmh);
        assert!((e.decel_g - 0.7).abs() < 0.1, "decel {}", e.decel_g);
    }
    assert!(
        large.true_peak_deg > 1.5 * small.true_peak_deg,
        "0.5 mm {} deg vs 0.03 mm {} deg",
        large.true_peak_deg,
        small.true_peak_deg
    );
    assert!(large.features.rms_deg > small.features.rms_deg);
}

#[test]
fn nuisance_vehicles_follow_the_issue_prior_and_are_reproducible() {
    let nominal = VehicleParams::default();
    let r = NuisanceRanges::default();
    let mut u = Vec::new();
    for m in 0..40 {
        let a = nuisance_vehicle(&nominal, &r, 1_000_000, m);
        let b = nuisance_vehicle(&nominal, &r, 1_000_000, m);
        assert_eq!(a, b, "vehicle {m} must be the same at every clearance");
        let ks =
            a.steering.kingpin_stiffness_nm_per_rad / nominal.steering.kingpin_stiffness_nm_per_rad;
        assert!((0.9..=1.1).contains(&ks), "k_s factor {ks}");
        let un = a.excitation.unbalance_kgm / nominal.excitation.unbalance_kgm;
        assert!((0.5..=2.0).contains(&un), "unbalance factor {un}");
        let rn = a.excitation.noise_std_nm / nominal.excitation.noise_std_nm;
        assert!((0.7..=1.4).contains(&rn), "road-noise factor {rn}");
        u.push(un);
    }
    // Spread over the range, not one value.
    let lo = u.iter().cloned().fold(f64::INFINITY, f64::min);
    let hi = u.iter().cloned().fold(0.0, f64::max);
    assert!(lo < 0.8 && hi > 1.4, "unbalance factors {lo}..{hi}");
}
