//! Brake-torque variation at wheel order (a disc thickness variation; `braking.
//! torque_variation_rel`): through a scrub radius it shakes the steering wheel at wheel order
//! whatever the clearance, as MODEL.md §14 says (0.3–1.2° at 5–15 % variation; here 1.2° at
//! 10 % with the discs 180° apart, nothing with them in phase); without a variation the model
//! is the one it was, to the bit.

use shimmy::model::features::features;
use shimmy::model::{run, JointMode, Scenario, VehicleParams};

fn peak_sw(p: &VehicleParams, joints: JointMode, c_mm: f64, seed: u64) -> f64 {
    let sc = Scenario {
        joints,
        clearance_m: c_mm * 1e-3,
        seed,
        ..Scenario::default()
    };
    features(&run(p, &sc).unwrap()).unwrap().peak_sw_bp_deg
}

#[test]
fn no_variation_leaves_the_model_unchanged() {
    let base = VehicleParams::default();
    let mut p = base.clone();
    p.braking.torque_variation_phase_deg = [30.0, 120.0];
    assert_eq!(
        peak_sw(&base, JointMode::Dual, 0.2, 1),
        peak_sw(&p, JointMode::Dual, 0.2, 1)
    );
    // Left out of the serialised form at 0: hashes of vehicle files stay the same.
    let json = serde_json::to_string(&base).unwrap();
    assert!(!json.contains("torque_variation"), "{json}");
}

#[test]
fn a_disc_thickness_variation_through_a_scrub_radius_shakes_the_wheel_whatever_the_joints() {
    let mut scrub = VehicleParams::default();
    scrub.steering.scrub_radius_m = 0.010;
    let mut dtv = scrub.clone();
    dtv.braking.torque_variation_rel = [0.10, 0.10];
    dtv.braking.torque_variation_phase_deg = [0.0, 180.0];
    for seed in 0..2 {
        let (a, b) = (
            peak_sw(&scrub, JointMode::Ideal, 0.1, seed),
            peak_sw(&dtv, JointMode::Ideal, 0.1, seed),
        );
        println!("seed {seed}: scrub alone {a:.3} deg, with 10 % variation {b:.3} deg");
        assert!(
            (0.3..1.5).contains(&b) && b > 3.0 * a,
            "seed {seed}: {a} -> {b}"
        );
    }
    // In phase, the discs push toward toe-in and toe-out together: the rack does not feel it.
    let mut toe = dtv.clone();
    toe.braking.torque_variation_phase_deg = [40.0, 40.0];
    let (a, t) = (
        peak_sw(&scrub, JointMode::Ideal, 0.1, 0),
        peak_sw(&toe, JointMode::Ideal, 0.1, 0),
    );
    assert!((t - a).abs() < 0.25 * a, "{a} -> {t}");
    // Without a scrub radius the force has no lever about the kingpin.
    let mut no_lever = dtv.clone();
    no_lever.steering.scrub_radius_m = 0.0;
    let base = peak_sw(&VehicleParams::default(), JointMode::Ideal, 0.1, 0);
    let no = peak_sw(&no_lever, JointMode::Ideal, 0.1, 0);
    assert!((no - base).abs() < 0.2 * base, "{base} -> {no}");
}

#[test]
fn a_variation_outside_its_range_is_refused() {
    let mut p = VehicleParams::default();
    p.braking.torque_variation_rel = [0.6, 0.0];
    let e = p.validate().unwrap_err().to_string();
    assert!(e.contains("braking.torque_variation_rel"), "{e}");
}

#[test]
fn a_prior_with_uneven_discs_draws_them_per_vehicle_and_leaves_the_other_draws_alone() {
    use rand::{Rng, SeedableRng};
    use rand_chacha::ChaCha8Rng;
    use shimmy::observer::simulate::{perturb, NuisanceRanges};

    let mut nominal = VehicleParams::default();
    nominal.column.enabled = true;
    let even = NuisanceRanges::default();
    let discs = NuisanceRanges {
        brake_torque_variation_rel: Some((0.01, 0.05)),
        ..even
    };
    let (mut eps, mut phase) = (Vec::new(), Vec::new());
    for seed in 0..200u64 {
        let mut a = ChaCha8Rng::seed_from_u64(seed);
        let mut b = a.clone();
        let q = perturb(&nominal, &even, &mut a);
        let d = perturb(&nominal, &discs, &mut b);
        // Everything else is drawn as without the discs, and the caller's generator is where
        // it was.
        assert_eq!(q.steering, d.steering);
        assert_eq!(q.excitation, d.excitation);
        assert_eq!(q.column, d.column);
        assert_eq!(a.random::<u64>(), b.random::<u64>());
        assert_eq!(q.braking.torque_variation_rel, [0.0; 2]);
        d.validate().unwrap();
        for i in 0..2 {
            let e = d.braking.torque_variation_rel[i];
            assert!((0.01..=0.05).contains(&e), "{e}");
            eps.push(e);
            phase.push(d.braking.torque_variation_phase_deg[i]);
        }
        // The two discs are drawn independently.
        assert_ne!(
            d.braking.torque_variation_phase_deg[0],
            d.braking.torque_variation_phase_deg[1]
        );
    }
    // The draws cover the ranges.
    let span = |v: &[f64]| {
        (
            v.iter().cloned().fold(f64::INFINITY, f64::min),
            v.iter().cloned().fold(f64::NEG_INFINITY, f64::max),
        )
    };
    let (lo, hi) = span(&eps);
    assert!(lo < 0.014 && hi > 0.046, "{lo} {hi}");
    let (lo, hi) = span(&phase);
    assert!(
        lo >= 0.0 && lo < 20.0 && hi < 360.0 && hi > 340.0,
        "{lo} {hi}"
    );
    // Written in a table's prior only when drawn: tables without it stay byte for byte.
    assert!(!serde_json::to_string(&even)
        .unwrap()
        .contains("brake_torque_variation_rel"));
    let back: NuisanceRanges =
        serde_json::from_str(&serde_json::to_string(&discs).unwrap()).unwrap();
    assert_eq!(back, discs);
}
