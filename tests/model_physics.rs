//! Physics checks of the shimmy model that can fail on a wrong sign, frame or unit:
//! energy conservation of the undamped system (MODEL.md §3, §4), exactly zero contact force in
//! free flight (§4), mirror symmetry (§2, §3), and RK4 order ≈ 4 (§10).

use shimmy::model::rhs::{ix, JointMode, Model, State, Switches};
use shimmy::model::{Scenario, Simulator, VehicleParams};

/// Vehicle with every damper off (kingpin, roll, rack, tie-rod yaw) and, for the contact
/// variant, an elastic frictionless joint (restitution 1 removes the LN hysteresis).
fn undamped() -> VehicleParams {
    let mut p = VehicleParams::default();
    p.steering.kingpin_damping_nms_per_rad = 0.0;
    p.steering.restraint_damping_ns_per_m = 0.0;
    p.steering.tie_rod_yaw_damping_nms_per_rad = 0.0;
    p.axle.roll_damping_nms_per_rad = 0.0;
    p.joint.restitution = 1.0;
    p.joint.friction = 0.0;
    p
}

/// Kinetic + elastic energy (J) of the 5 DOF, plus the Hertz potential (2/5)·K·δ^2.5 of the
/// joints when `contact` (the LN force with c_r = 1 is K·δ^1.5, whose potential that is).
fn energy(m: &Model, y: &State, contact: bool) -> f64 {
    let mut e = 0.5 * m.i_w * (y[ix::TH1D].powi(2) + y[ix::TH2D].powi(2))
        + 0.5 * m.k_s * (y[ix::TH1].powi(2) + y[ix::TH2].powi(2))
        + 0.5 * m.i_f * y[ix::TH3D].powi(2)
        + 0.5 * m.k_roll * y[ix::TH3].powi(2)
        + 0.5 * m.m_t * y[ix::XD].powi(2)
        + 0.5 * m.k_eq * y[ix::X].powi(2)
        + 0.5 * m.i_t * y[ix::TH4D].powi(2);
    if contact {
        for (i, (delta, _)) in m.penetrations(y).into_iter().enumerate() {
            if delta > 0.0 {
                e += 0.4 * m.joint[i].k * delta.powf(2.5);
            }
        }
    }
    e
}

fn conservative_scenario(contact: bool) -> Scenario {
    Scenario {
        v0_mps: 55.0 / 3.6, // constant speed: gyroscopic coupling active but workless
        decel_g: 0.0,
        unbalance: false,
        noise: false,
        kick_theta1_rad_s: Some(0.3),
        kick_theta2_rad_s: -0.1,
        duration_s: 1.0,
        switches: Switches {
            tires: false,
            contact,
        },
        ..Scenario::default()
    }
}

fn energy_drift(contact: bool, h: f64) -> (f64, usize) {
    let p = undamped();
    let sc = Scenario {
        h_s: h,
        ..conservative_scenario(contact)
    };
    let mut sim = Simulator::new(&p, &sc).unwrap();
    // Roll and rack motion too, so the gyroscopic pair and eq. (4) take part.
    let e0 = energy(sim.model(), sim.state(), contact);
    let mut worst = 0.0f64;
    let mut contact_steps = 0;
    for _ in 0..(1.0 / h).round() as usize {
        sim.step();
        if sim.in_contact().iter().any(|&c| c) {
            contact_steps += 1;
        }
        let e = energy(sim.model(), sim.state(), contact);
        worst = worst.max((e - e0).abs() / e0);
    }
    (worst, contact_steps)
}

#[test]
fn energy_is_conserved_without_tires_contact_and_damping() {
    let (drift, _) = energy_drift(false, 1e-4);
    assert!(drift < 1e-8, "relative energy drift {drift:e} over 1 s");
}

#[test]
fn energy_is_conserved_with_elastic_frictionless_contact() {
    // Stronger than the issue asks: the joint forces and their moments on arms and tie rod
    // (§4) must do no net work, which fails on any wrong lever arm or sign. The impacts of
    // this hard kick (kN, ω·h ≈ 1.6 on the tie-rod yaw at h = 1e-4 s) are only resolved at
    // h ≈ 1e-5 s, and the δ^1.5 onset is not smooth, so the drift falls with h at order ≈ 1.4
    // (measured: 0.47 / 0.031 / 1.2e-3 / 4.4e-4 at h = 4e-5 / 2e-5 / 1e-5 / 5e-6 s). A
    // physical error (a wrong lever or sign) would leave a drift that does not vanish.
    let (drift1, contact_steps) = energy_drift(true, 1e-5);
    let (drift2, _) = energy_drift(true, 5e-6);
    assert!(
        contact_steps > 1000,
        "the case must actually impact ({contact_steps} steps)"
    );
    assert!(
        drift1 < 3e-3,
        "relative energy drift {drift1:e} over 1 s at h = 1e-5 s"
    );
    assert!(
        drift2 < 0.5 * drift1,
        "drift must vanish with h: {drift1:e} -> {drift2:e}"
    );
    assert!(
        drift2 < 1e-3,
        "relative energy drift {drift2:e} over 1 s at h = 5e-6 s"
    );
}

#[test]
fn damping_dissipates_energy() {
    // Control for the two tests above: with the default dampers energy must fall.
    let p = VehicleParams::default();
    let sc = conservative_scenario(false);
    let mut sim = Simulator::new(&p, &sc).unwrap();
    let e0 = energy(sim.model(), sim.state(), false);
    for _ in 0..10_000 {
        sim.step();
    }
    assert!(energy(sim.model(), sim.state(), false) < 0.5 * e0);
}

#[test]
fn contact_force_is_exactly_zero_while_inside_the_clearance() {
    let p = VehicleParams::default();
    let sc = Scenario {
        duration_s: 3.0,
        ..Scenario::default()
    };
    let mut sim = Simulator::new(&p, &sc).unwrap();
    let (mut free, mut touching) = (0, 0);
    for _ in 0..30_000 {
        sim.step();
        let o = sim.outputs();
        for i in 0..2 {
            if o.penetration_m[i] <= 0.0 {
                free += 1;
                assert_eq!(o.contact_fx_n[i], 0.0, "t={} side {i}", o.t_s);
                assert_eq!(o.contact_fy_n[i], 0.0, "t={} side {i}", o.t_s);
            } else if o.contact_fx_n[i] != 0.0 || o.contact_fy_n[i] != 0.0 {
                touching += 1;
            }
        }
    }
    assert!(
        free > 1000 && touching > 100,
        "free {free}, touching {touching}"
    );
}

fn mirror_run(joints: JointMode) -> (f64, f64, f64) {
    let p = VehicleParams::default();
    let sc = Scenario {
        joints,
        unbalance: false,
        noise: false,
        kick_theta1_rad_s: Some(0.05),
        kick_theta2_rad_s: -0.05,
        duration_s: 3.0,
        ..Scenario::default()
    };
    let mut sim = Simulator::new(&p, &sc).unwrap();
    let (mut max_th, mut max_asym, mut max_rack) = (0.0f64, 0.0f64, 0.0f64);
    for _ in 0..30_000 {
        sim.step();
        let y = sim.state();
        max_th = max_th.max(y[ix::TH1].abs());
        max_asym = max_asym.max((y[ix::TH1] + y[ix::TH2]).abs());
        max_rack = max_rack
            .max(y[ix::X].abs() / 0.13)
            .max(y[ix::TH3].abs())
            .max(y[ix::TH4].abs());
    }
    (max_th, max_asym, max_rack)
}

#[test]
fn mirror_symmetric_start_stays_symmetric() {
    // θ1 = −θ2 (toe-in/out) is the mirror image of itself about the car's centre line: X, θ3
    // and θ4 must stay zero and θ1 + θ2 = 0 during braking, for ideal and clearance joints.
    for joints in [JointMode::Ideal, JointMode::Dual] {
        let (max_th, max_asym, max_rack) = mirror_run(joints);
        assert!(max_th > 1e-5, "{joints:?}: the case must move ({max_th})");
        assert!(
            max_asym < 1e-9 * max_th,
            "{joints:?}: θ1+θ2 reached {max_asym:e}"
        );
        assert!(
            max_rack < 1e-9 * max_th,
            "{joints:?}: X/θ3/θ4 reached {max_rack:e}"
        );
    }
}

fn smooth_final_state(h: f64) -> State {
    // Contact off (wheels free of the tie rod, the §12 "decoupled" case), tires, braking and
    // unbalance on, no noise: a smooth, non-stiff right-hand side whose shimmy grows, so the
    // errors stay far above round-off. The braking-ramp kinks fall on step boundaries.
    let p = VehicleParams::default();
    let sc = Scenario {
        noise: false,
        h_s: h,
        duration_s: 2.0,
        kick_theta1_rad_s: Some(0.5),
        switches: Switches {
            tires: true,
            contact: false,
        },
        ..Scenario::default()
    };
    let mut sim = Simulator::new(&p, &sc).unwrap();
    let n = (2.0 / h).round() as usize;
    for _ in 0..n {
        sim.step();
    }
    *sim.state()
}

#[test]
fn rk4_converges_with_order_four_on_a_smooth_case() {
    let hs = [1e-3, 5e-4, 2.5e-4];
    let ys: Vec<State> = hs.iter().map(|&h| smooth_final_state(h)).collect();
    for k in [ix::TH1, ix::TH2, ix::TH3, ix::AL] {
        let d1 = (ys[0][k] - ys[1][k]).abs();
        let d2 = (ys[1][k] - ys[2][k]).abs();
        let p = (d1 / d2).log2();
        assert!(
            (p - 4.0).abs() < 0.5,
            "state {k}: observed order {p:.2} ({d1:e}, {d2:e})"
        );
    }
}

#[test]
fn unequal_clearances_break_the_mirror_symmetry_and_equal_ones_do_not() {
    // Each joint has its own clearance (unequal wear, firmware-sim's L/R option). Setting the
    // right clearance equal to the left must give the very same run; a larger right clearance
    // must make the mirror-symmetric start of `mirror_run` asymmetric.
    let p = VehicleParams::default();
    let base = Scenario {
        unbalance: false,
        noise: false,
        kick_theta1_rad_s: Some(0.05),
        kick_theta2_rad_s: -0.05,
        duration_s: 3.0,
        ..Scenario::default()
    };
    let run = |sc: &Scenario| {
        let mut sim = Simulator::new(&p, sc).unwrap();
        let mut max_asym = 0.0f64;
        for _ in 0..30_000 {
            sim.step();
            let y = sim.state();
            max_asym = max_asym.max((y[ix::TH1] + y[ix::TH2]).abs());
        }
        (*sim.state(), max_asym)
    };
    let (y0, a0) = run(&base);
    let same = Scenario {
        clearance_right_m: Some(base.clearance_m),
        ..base.clone()
    };
    let (y1, a1) = run(&same);
    assert_eq!(y0, y1, "right = left must not change the run");
    assert!(a0 == a1);
    let unequal = Scenario {
        clearance_right_m: Some(0.3e-3),
        ..base.clone()
    };
    let (_, a2) = run(&unequal);
    assert!(a2 > 1e3 * a0.max(1e-15), "asymmetry {a2:e} vs {a0:e}");

    // The setter mid-run: back to equal clearances gives back a symmetric motion's structure
    // (no error), and it refuses nonsense without changing the joints.
    let mut sim = Simulator::new(&p, &unequal).unwrap();
    assert_eq!(sim.clearance_m(), [0.1e-3, 0.3e-3]);
    assert!(sim.set_clearance(f64::NAN, 0.1e-3).is_err());
    assert!(sim.set_clearance(0.1e-3, -1.0).is_err());
    assert_eq!(sim.clearance_m(), [0.1e-3, 0.3e-3]);
    sim.set_clearance(0.12e-3, 0.15e-3).unwrap();
    assert_eq!(sim.clearance_m(), [0.12e-3, 0.15e-3]);
    assert!(Simulator::new(
        &p,
        &Scenario {
            clearance_right_m: Some(0.0),
            ..base
        }
    )
    .is_err());
}
