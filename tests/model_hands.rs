//! The driver's hands on the steering wheel (MODEL.md §15 eq. 6 with hands inertia, stiffness
//! and damping; docs/COLUMN.md): defaults reproduce the model as it was before the hands
//! existed bit for bit, a firm grip changes the rim and torque the way the physics says, the
//! per-vehicle column draw and the per-event hands draw stay inside their ranges without
//! touching the 5-DOF draws, and bad values are refused with the key named.

use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use shimmy::analysis::{peak_abs, Bandpass};
use shimmy::model::{rhs::ix, run, Hands, JointMode, Scenario, Simulator, VehicleParams};
use shimmy::observer::simulate::{
    event_hands, perturb, run_model_grid, ColumnRanges, EventShape, HandsPrior, HandsState,
    NuisanceRanges,
};
use shimmy::observer::table::vehicle_hash;
use shimmy::observer::ObserverConfig;

/// The whole state after 3 s of MODEL.md §6's event (0.03 mm dual joints, seed 3), as f64 bits.
fn state_bits(p: &VehicleParams, hands: Option<Hands>) -> Vec<u64> {
    let sc = Scenario {
        joints: JointMode::Dual,
        clearance_m: 0.03e-3,
        seed: 3,
        duration_s: 3.5,
        ..Scenario::default()
    };
    let mut s = Simulator::new(p, &sc).unwrap();
    if let Some(h) = hands {
        s.set_hands(&h).unwrap();
    }
    s.advance(30_000);
    s.state().iter().map(|v| v.to_bits()).collect()
}

// Computed by the code before the hands existed (commit 2538b89, the same function).
const OLD_5DOF: [u64; 18] = [
    4544243541931346517,
    13775110128275543224,
    13745379432689652463,
    4512389962017826526,
    4538102239533953312,
    4571489674416657348,
    13788161407424903358,
    13769033721333779509,
    13754037876731363182,
    13784850005112974215,
    13763646727178523690,
    13739025870518580489,
    4615628982451158584,
    4637269984702750193,
    4617208482933594685,
    4535677518360669920,
    0,
    0,
];
const OLD_COLUMN: [u64; 18] = [
    4544347720563513862,
    13774064714824291069,
    13736462573757569163,
    4518725622390467384,
    4539664951828497572,
    4569978658627511846,
    13791890815371703319,
    13768202226204857861,
    13756941613884432538,
    4550587597901208190,
    13762294707484415719,
    4533389173071246844,
    4615628982451158584,
    4637269984702750193,
    4617208482933594685,
    4535677518360669920,
    4549824916979361252,
    13788298507052050227,
];

#[test]
fn defaults_reproduce_the_model_before_the_hands_bit_for_bit() {
    let p5 = VehicleParams::default();
    let mut pc = VehicleParams::default();
    pc.column.enabled = true;
    assert_eq!(state_bits(&p5, None), OLD_5DOF);
    assert_eq!(state_bits(&pc, None), OLD_COLUMN);
    // The old constants put on the rim through set_hands: the same trajectory.
    let old = Hands {
        inertia_kgm2: 0.0,
        stiffness_nm_per_rad: 0.0,
        damping_nms_per_rad: 0.3,
    };
    assert_eq!(state_bits(&pc, Some(old)), OLD_COLUMN);
    // Other hands do change it (the comparison can fail).
    let firm = Hands {
        inertia_kgm2: 0.08,
        stiffness_nm_per_rad: 25.0,
        damping_nms_per_rad: 1.4,
    };
    assert_ne!(state_bits(&pc, Some(firm)), OLD_COLUMN);
    // Vehicle files and hashes are unchanged (tables are keyed by them), and so is the
    // 5-DOF nuisance draw (hash of the drawn vehicle from the code before).
    assert_eq!(vehicle_hash(&p5).unwrap(), "3c110be268fdae2e");
    let mut rng = ChaCha8Rng::seed_from_u64(42);
    let q = perturb(&p5, &NuisanceRanges::default(), &mut rng);
    assert_eq!(vehicle_hash(&q).unwrap(), "abb20d6b8c31170c");
}

/// (rim angle amplitude deg, column torque amplitude N·m) of the 3–25 Hz band over the
/// braking window, 55 km/h, 0.5 g, dual joints of `c_mm`.
fn amplitudes(hands: Hands, c_mm: f64, seed: u64) -> (f64, f64) {
    let mut p = VehicleParams::default();
    p.column.enabled = true;
    p.column.set_hands(hands);
    let sc = Scenario {
        joints: JointMode::Dual,
        clearance_m: c_mm * 1e-3,
        seed,
        ..Scenario::default()
    };
    let tr = run(&p, &sc).unwrap();
    let w = tr.braking_window();
    let bp = Bandpass::new(tr.fs_hz, 3.0, 25.0, 4).unwrap();
    let sw = bp.filtfilt(&tr.column(|o| o.delta_sw_rad));
    let tc = bp.filtfilt(&tr.column(|o| o.column_torque_nm));
    (peak_abs(&sw[w.clone()]).to_degrees(), peak_abs(&tc[w]))
}

#[test]
fn a_firm_grip_holds_the_rim_and_the_torsion_bar_sees_the_pinion() {
    let prior = HandsPrior::default();
    let mid = |s: HandsState| prior.range(s).midpoint();
    let (off, firm) = (mid(HandsState::Off), mid(HandsState::Firm));
    let res: Vec<[(f64, f64); 2]> = std::thread::scope(|s| {
        let hs: Vec<_> = (0..2u64)
            .map(|seed| s.spawn(move || [amplitudes(off, 0.4, seed), amplitudes(firm, 0.4, seed)]))
            .collect();
        hs.into_iter().map(|h| h.join().unwrap()).collect()
    });
    for (seed, [(sw_off, tc_off), (sw_firm, tc_firm)]) in res.into_iter().enumerate() {
        println!(
            "seed {seed}: off rim {sw_off:.4}° T_c {tc_off:.4} N·m; firm rim {sw_firm:.4}° T_c {tc_firm:.4} N·m"
        );
        assert!(
            sw_firm < 0.8 * sw_off,
            "firm grip rim {sw_firm} vs hands off {sw_off}"
        );
        assert!(
            tc_firm / sw_firm > 1.5 * tc_off / sw_off,
            "torque per rim degree: firm {} vs off {}",
            tc_firm / sw_firm,
            tc_off / sw_off
        );
    }
}

#[test]
fn the_column_draw_stays_in_its_ranges_and_leaves_the_5dof_draws_alone() {
    let p5 = VehicleParams::default();
    let mut pc = p5.clone();
    pc.column.enabled = true;
    let r = NuisanceRanges::default();
    let cr = r.column.unwrap();
    let inside = |x: f64, (lo, hi): (f64, f64)| (lo..=hi).contains(&x);
    let mut spread = (f64::INFINITY, f64::NEG_INFINITY);
    for seed in 0..200u64 {
        let mut a = ChaCha8Rng::seed_from_u64(seed);
        a.set_stream(7);
        let mut b = a.clone();
        let q5 = perturb(&p5, &r, &mut a);
        let qc = perturb(&pc, &r, &mut b);
        // The 5-DOF draws are the same and the caller's generator is where it was.
        assert_eq!(q5.steering, qc.steering);
        assert_eq!(q5.excitation, qc.excitation);
        assert_eq!(q5.column, p5.column);
        assert_eq!(a.random::<u64>(), b.random::<u64>());
        let c = &qc.column;
        assert!(inside(c.inertia_kgm2, cr.inertia_kgm2), "{c:?}");
        assert!(
            inside(c.torsion_bar_nm_per_rad, cr.torsion_bar_nm_per_rad),
            "{c:?}"
        );
        assert!(inside(
            c.torsion_bar_damping_nms_per_rad,
            cr.torsion_bar_damping_nms_per_rad
        ));
        qc.validate().unwrap();
        spread = (
            spread.0.min(c.torsion_bar_nm_per_rad),
            spread.1.max(c.torsion_bar_nm_per_rad),
        );
    }
    // The draws cover the range (not stuck at the nominal).
    let (lo, hi) = cr.torsion_bar_nm_per_rad;
    assert!(spread.0 < lo + 0.1 * (hi - lo) && spread.1 > hi - 0.1 * (hi - lo));
    // --exact-vehicle: no column draw.
    let mut g = ChaCha8Rng::seed_from_u64(1);
    assert_eq!(
        perturb(&pc, &NuisanceRanges::NONE, &mut g).column,
        pc.column
    );
}

#[test]
fn the_hands_draw_follows_its_probabilities_and_ranges() {
    let prior = HandsPrior::default();
    prior.validate().unwrap();
    let n = 4000;
    let mut count = [0usize; 3];
    for seed in 0..n as u64 {
        let d = event_hands(&prior, seed);
        assert_eq!(d, event_hands(&prior, seed), "fixed by the seed");
        let r = prior.range(d.state);
        let h = d.hands;
        let inside = |x: f64, (lo, hi): (f64, f64)| (lo..=hi).contains(&x);
        assert!(inside(h.inertia_kgm2, r.inertia_kgm2), "{d:?}");
        assert!(
            inside(h.stiffness_nm_per_rad, r.stiffness_nm_per_rad),
            "{d:?}"
        );
        assert!(
            inside(h.damping_nms_per_rad, r.damping_nms_per_rad),
            "{d:?}"
        );
        count[d.state as usize] += 1;
    }
    for (i, p) in [prior.off, prior.light, prior.firm]
        .iter()
        .map(|r| r.probability)
        .enumerate()
    {
        let f = count[i] as f64 / n as f64;
        assert!((f - p).abs() < 0.03, "state {i}: {f} vs {p}");
    }
}

/// `shimmy calibrate`'s model events: with the column, each speed's run carries the hands its
/// seed draws (and they change the run); a 5-DOF vehicle or no prior: none.
#[test]
fn the_table_builds_model_events_draw_hands_per_event_with_the_column() {
    let cfg = ObserverConfig::default();
    let prior = HandsPrior::default();
    let mut pc = VehicleParams::default();
    pc.column.enabled = true;
    let speeds = [40.0 / 3.6, 60.0 / 3.6];
    // One seed per speed: the trunk's hands, then the branch's own.
    let seeds = [11u64, 12];
    let grid = |p: &VehicleParams, h: Option<&HandsPrior>| {
        run_model_grid(
            p,
            0.2e-3,
            &speeds,
            &[0.5],
            &seeds,
            EventShape::DRIVE,
            &cfg,
            h,
        )
        .unwrap()
        .runs
    };
    let with = grid(&pc, Some(&prior));
    for (i, by_decel) in with.iter().enumerate() {
        assert_eq!(by_decel[0].hands, Some(event_hands(&prior, seeds[i])));
    }
    let without = grid(&pc, None);
    assert!(without.iter().flatten().all(|r| r.hands.is_none()));
    assert_ne!(
        with[1][0].sw_rad, without[1][0].sw_rad,
        "the hands reach the rim"
    );
    let five = grid(&VehicleParams::default(), Some(&prior));
    assert!(five.iter().flatten().all(|r| r.hands.is_none()));
}

#[test]
fn bad_hands_and_ranges_are_refused_with_the_key() {
    let e = VehicleParams::from_toml_str("[column]\nhands_inertia_kgm2 = -0.1\n").unwrap_err();
    assert!(
        format!("{e:#}").contains("column.hands_inertia_kgm2"),
        "{e:#}"
    );
    let e =
        VehicleParams::from_toml_str("[column]\nhands_stiffness_nm_per_rad = nan\n").unwrap_err();
    assert!(
        format!("{e:#}").contains("column.hands_stiffness_nm_per_rad"),
        "{e:#}"
    );
    let e = VehicleParams::from_toml_str("[column]\nhands_grip = 1\n").unwrap_err();
    assert!(format!("{e:#}").contains("hands_grip"), "{e:#}");

    let mut p = VehicleParams::default();
    p.column.enabled = true;
    let mut s = Simulator::new(&p, &Scenario::default()).unwrap();
    let before = s.hands();
    let bad = Hands {
        inertia_kgm2: 0.05,
        stiffness_nm_per_rad: f64::NAN,
        damping_nms_per_rad: 1.0,
    };
    let e = s.set_hands(&bad).unwrap_err();
    assert!(
        e.to_string().contains("column.hands_stiffness_nm_per_rad"),
        "{e}"
    );
    assert_eq!(s.hands(), before, "a refused value changes nothing");
    assert_eq!(s.state()[ix::SW], 0.0);

    let mut h = HandsPrior::default();
    h.firm.probability = 0.15;
    let e = h.validate().unwrap_err();
    assert!(e.to_string().contains("must sum to 1"), "{e}");
    let mut h = HandsPrior::default();
    h.light.stiffness_nm_per_rad = (5.0, 1.0);
    let e = h.validate().unwrap_err();
    assert!(
        e.to_string().contains("hands.light.stiffness_nm_per_rad"),
        "{e}"
    );
    let mut c = ColumnRanges::PUBLISHED;
    c.inertia_kgm2 = (0.0, 0.05);
    let e = c.validate().unwrap_err();
    assert!(e.to_string().contains("column.inertia_kgm2"), "{e}");
    // A table prior written before the column and hands existed loads with the defaults.
    let old: NuisanceRanges = serde_json::from_str(
        r#"{"stiffness_damping_rel":0.1,"unbalance_factor":[0.5,2.0],"road_noise_factor":[0.7,1.4]}"#,
    )
    .unwrap();
    assert_eq!(old, NuisanceRanges::default());
    // ... and a default prior is written as before (tables byte for byte); another one in full.
    let text = serde_json::to_string(&NuisanceRanges::default()).unwrap();
    assert_eq!(
        text,
        r#"{"stiffness_damping_rel":0.1,"unbalance_factor":[0.5,2.0],"road_noise_factor":[0.7,1.4]}"#
    );
    let mut other = NuisanceRanges::default();
    other.hands.as_mut().unwrap().firm.probability = 0.5;
    other.hands.as_mut().unwrap().light.probability = 0.35;
    let back: NuisanceRanges =
        serde_json::from_str(&serde_json::to_string(&other).unwrap()).unwrap();
    assert_eq!(back, other);
}
