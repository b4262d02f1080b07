//! The estimator's math against a synthetic response table with a known law (issue 5 item 3):
//! accumulation over events, credible intervals, the detection limit, wear tracking, the
//! clearance alert's probability, and the table's version check.

use rand::SeedableRng;
use rand_chacha::ChaCha8Rng;
use rand_distr::{Distribution, Normal};
use shimmy::observer::estimator::{Estimator, EstimatorConfig};
use shimmy::observer::table::{Cell, ResponseTable};
use shimmy::observer::ObserverConfig;

#[path = "support/synthetic_table.rs"]
mod synthetic_table;
use synthetic_table::synthetic;

/// A law with a floor like MODEL.md §13's steering wheel: rms = sqrt(0.04² + (0.25·c·s)²) with
/// s = min(v/55, 1) (speed matters), peak = 2.2·rms; ln-normal spread 0.15.
fn law(c_mm: f64, v_kmh: f64) -> (f64, f64) {
    let s = (v_kmh / 55.0).min(1.0);
    let rms = (0.04f64.powi(2) + (0.25 * c_mm * s).powi(2)).sqrt();
    (rms.ln(), (2.2 * rms).ln())
}
const SPREAD: f64 = 0.15;

fn table() -> ResponseTable {
    let nc = 25;
    let clearance_mm: Vec<f64> = (0..nc)
        .map(|i| 0.02 * (0.5f64 / 0.02).powf(i as f64 / (nc - 1) as f64))
        .collect();
    let speed_kmh = vec![20.0, 40.0, 60.0, 80.0, 120.0];
    let decel_g = vec![0.3, 0.8];
    let mut cells = Vec::new();
    for &c in &clearance_mm {
        for &v in &speed_kmh {
            for _ in &decel_g {
                let (a, b) = law(c, v);
                let z = shimmy::observer::features::z(a.exp(), b.exp());
                cells.push(Cell {
                    mean: z,
                    std: [SPREAD, SPREAD],
                    corr: 0.8,
                    cruise: [0.0, 0.0],
                });
            }
        }
    }
    synthetic(clearance_mm, speed_kmh, decel_g, 1, cells)
}

/// Draws one event's (rms, peak) from the law with correlated log-normal noise.
fn draw(rng: &mut ChaCha8Rng, c_mm: f64, v: f64) -> (f64, f64) {
    let n = Normal::new(0.0, 1.0).unwrap();
    let (a, b) = law(c_mm, v);
    let z1: f64 = n.sample(rng);
    let z2: f64 = 0.8 * z1 + 0.6 * n.sample(rng);
    ((a + SPREAD * z1).exp(), (b + SPREAD * z2).exp())
}

fn run(c_mm: f64, events: usize, seed: u64) -> Estimator {
    let t = table();
    let mut e = Estimator::new(&t, EstimatorConfig::mixture()).unwrap();
    let mut rng = ChaCha8Rng::seed_from_u64(seed);
    for k in 0..events {
        let v = 30.0 + (k % 8) as f64 * 10.0;
        let (r, p) = draw(&mut rng, c_mm, v);
        e.update(&t, r, p, v, 0.5, k as f64 * 2000.0);
    }
    e
}

#[test]
fn thirty_events_pin_a_large_clearance_down() {
    for (c, seed) in [(0.15, 1), (0.25, 2), (0.4, 3)] {
        let e = run(c, 30, seed);
        let s = e.summary();
        assert!(s.detectable, "{c}: {s:?}");
        assert!(
            (s.median_mm - c).abs() < 0.15 * c,
            "c = {c}: median {}",
            s.median_mm
        );
        assert!(s.q05_mm < c && c < s.q95_mm, "c = {c}: {s:?}");
        assert_eq!(s.events_used, 30);
    }
}

#[test]
fn one_event_is_much_less_certain_than_thirty() {
    let one = run(0.2, 1, 7).summary();
    let many = run(0.2, 30, 7).summary();
    let w1 = (one.q95_mm / one.q05_mm).ln();
    let w30 = (many.q95_mm / many.q05_mm).ln();
    assert!(w30 < 0.4 * w1, "interval widths (ln) {w1} vs {w30}");
}

#[test]
fn below_the_floor_it_says_so_and_the_bound_holds() {
    for (c, seed) in [(0.03, 4), (0.05, 5)] {
        let e = run(c, 30, seed);
        let s = e.summary();
        assert!(!s.detectable, "c = {c}: {s:?}");
        assert!(s.q95_mm > c, "'below {}' must hold for c = {c}", s.q95_mm);
        assert!(s.q95_mm < 0.12, "and be informative: {}", s.q95_mm);
        assert!(e.prob_above(0.1) < 0.5);
    }
}

#[test]
fn clearance_probability_separates_worn_from_new() {
    assert!(run(0.25, 30, 8).prob_above(0.1) > 0.99);
    assert!(run(0.04, 30, 9).prob_above(0.1) < 0.05);
}

#[test]
fn posterior_follows_wear_through_the_random_walk() {
    // 40 events at 0.1 mm, then 40 at 0.25 mm, 2 km apart: with wear diffusion the estimate
    // must move to the new value; without it, old evidence holds it back.
    let t = table();
    let go = |wear: f64| {
        let cfg = EstimatorConfig {
            wear_var_per_km: wear,
            ..EstimatorConfig::mixture()
        };
        let mut e = Estimator::new(&t, cfg).unwrap();
        let mut rng = ChaCha8Rng::seed_from_u64(11);
        for k in 0..80 {
            let c = if k < 40 { 0.1 } else { 0.25 };
            let (r, p) = draw(&mut rng, c, 60.0);
            e.update(&t, r, p, 60.0, 0.5, k as f64 * 2000.0);
        }
        e.summary().median_mm
    };
    let with = go(0.01);
    let without = go(0.0);
    assert!((with - 0.25).abs() < 0.04, "with wear diffusion {with}");
    assert!(without < with - 0.02, "without {without} vs with {with}");
}

#[test]
fn quantiles_are_monotone_and_probabilities_sum_to_one() {
    let e = run(0.12, 10, 12);
    let s: f64 = e.probabilities().sum();
    assert!((s - 1.0).abs() < 1e-9);
    let mut prev = 0.0;
    for q in [0.01, 0.05, 0.25, 0.5, 0.75, 0.95, 0.99] {
        let x = e.quantile_mm(q);
        assert!(x > prev, "quantile {q}");
        prev = x;
    }
    assert!((e.prob_above(e.quantile_mm(0.3)) - 0.7).abs() < 1e-6);
}

#[test]
fn a_table_for_other_vehicle_parameters_is_refused() {
    let t = table();
    assert!(t.check_vehicle("0123456789abcdef").is_ok());
    let err = t.check_vehicle("fedcba9876543210").unwrap_err().to_string();
    assert!(err.contains("calibrate"), "{err}");
    let mut bad = t.clone();
    bad.cells.pop();
    assert!(bad.validate().is_err());
}

#[test]
fn the_shipped_config_parses_and_equals_the_defaults() {
    let path = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("config/observer.toml");
    let cfg = ObserverConfig::load(&path).unwrap();
    assert_eq!(cfg, ObserverConfig::default());
    assert!(ObserverConfig::from_toml_str("[alerts]\nshimmy_amplitud_deg = 1").is_err());
}

#[test]
fn isotonic_fit_is_monotone_and_keeps_sorted_data() {
    use shimmy::observer::table::isotonic_in_place;
    let mut y = vec![1.0, 3.0, 2.0, 4.0, 0.0];
    isotonic_in_place(&mut y);
    assert!(y.windows(2).all(|w| w[0] <= w[1]), "{y:?}");
    assert!(
        (y.iter().sum::<f64>() - 10.0).abs() < 1e-12,
        "pooling keeps the sum"
    );
    let mut s = vec![0.1, 0.2, 0.5];
    isotonic_in_place(&mut s);
    assert_eq!(s, vec![0.1, 0.2, 0.5]);
}

/// A synthetic table with vehicle-level nuisance: vehicle m scales the wheel's motion by
/// e^{δ_m} (a stiffer or softer steering, a bigger unbalance), the same for all its events, so
/// it is indistinguishable from a clearance e^{δ_m} times larger. `vehicles` = the δ_m of the
/// table (one cell set each, event spread SPREAD); `pooled` = one cell set whose spread also
/// carries the vehicle spread (the old table's "nuisances per event").
fn nuisance_table(deltas: &[f64], pooled_spread: Option<f64>) -> ResponseTable {
    let nc = 25;
    let clearance_mm: Vec<f64> = (0..nc)
        .map(|i| 0.02 * (0.8f64 / 0.02).powf(i as f64 / (nc - 1) as f64))
        .collect();
    let speed_kmh = vec![40.0, 80.0];
    let decel_g = vec![0.5];
    let mut cells = Vec::new();
    for &c in &clearance_mm {
        for &d in deltas {
            for &v in &speed_kmh {
                let (a, b) = law(c * d.exp(), v);
                let s = pooled_spread.unwrap_or(SPREAD);
                cells.push(Cell {
                    mean: shimmy::observer::features::z(a.exp(), b.exp()),
                    std: [s, s],
                    corr: 0.8,
                    cruise: [0.0, 0.0],
                });
            }
        }
    }
    synthetic(clearance_mm, speed_kmh, decel_g, deltas.len() as u32, cells)
}

const VEHICLE_SPREAD: f64 = 0.3;

/// Runs `n` synthetic vehicles (c log-uniform 0.1–0.4 mm, vehicle factor e^δ with δ ~
/// N(0, VEHICLE_SPREAD), 30 events each at 60–90 km/h) through an estimator on `t`; returns
/// (interval coverage, mean ln-width of the 90 % interval).
fn fleet_coverage(t: &ResponseTable, n: usize, seed: u64) -> (f64, f64) {
    let mut rng = ChaCha8Rng::seed_from_u64(seed);
    let nd = Normal::new(0.0, VEHICLE_SPREAD).unwrap();
    let mut inside = 0;
    let mut width = 0.0;
    for _ in 0..n {
        let c = (0.1f64.ln() + rand::Rng::random::<f64>(&mut rng) * 4f64.ln()).exp();
        let d: f64 = nd.sample(&mut rng);
        let mut e = Estimator::new(
            t,
            EstimatorConfig {
                wear_var_per_km: 0.0,
                // The synthetic table's spreads are exact: no model mismatch to widen for.
                std_inflation: 1.0,
                ..EstimatorConfig::mixture()
            },
        )
        .unwrap();
        for k in 0..30 {
            let v = 60.0 + (k % 4) as f64 * 10.0;
            let (r, p) = draw(&mut rng, c * d.exp(), v);
            e.update(t, r, p, v, 0.5, k as f64 * 2000.0);
        }
        let s = e.summary();
        inside += (s.q05_mm <= c && c <= s.q95_mm) as usize;
        width += (s.q95_mm / s.q05_mm).ln();
    }
    (inside as f64 / n as f64, width / n as f64)
}

#[test]
fn vehicle_level_nuisance_gives_honest_intervals_where_independent_events_do_not() {
    // The table's 24 nuisance vehicles are drawn from the prior with their own seed; the test
    // vehicles are fresh draws.
    let mut rng = ChaCha8Rng::seed_from_u64(99);
    let nd = Normal::new(0.0, VEHICLE_SPREAD).unwrap();
    let deltas: Vec<f64> = (0..24).map(|_| nd.sample(&mut rng)).collect();
    let mixture = nuisance_table(&deltas, None);
    // Independent events: the nuisance spread folded into every event's spread.
    let total = (SPREAD * SPREAD + VEHICLE_SPREAD * VEHICLE_SPREAD).sqrt();
    let pooled = nuisance_table(&[0.0], Some(total));
    let (cov_m, w_m) = fleet_coverage(&mixture, 150, 5);
    let (cov_p, w_p) = fleet_coverage(&pooled, 150, 5);
    eprintln!(
        "mixture: coverage {cov_m}, ln-width {w_m}; independent: coverage {cov_p}, ln-width {w_p}"
    );
    assert!(
        w_m > 1.4 * w_p,
        "vehicle-level likelihood must widen the intervals: ln-widths {w_m} vs {w_p}"
    );
    assert!(
        (0.8..=0.98).contains(&cov_m),
        "90 % intervals with the vehicle-level likelihood cover {cov_m}"
    );
    assert!(
        cov_p < 0.6,
        "independent events are overconfident (coverage {cov_p}); if this passes the test \
         case has no vehicle-level nuisance"
    );
}

#[test]
fn the_mixture_learns_which_nuisance_vehicle_it_is() {
    // Two very different nuisance vehicles; the events of one must move the posterior onto it.
    let t = nuisance_table(&[-0.5, 0.5], None);
    let mut e = Estimator::new(&t, EstimatorConfig::mixture()).unwrap();
    let mut rng = ChaCha8Rng::seed_from_u64(3);
    for k in 0..30 {
        // c = 0.2 mm on vehicle 1 (factor e^0.5) at 40 km/h AND 80 km/h: the speed law is the
        // same for both, so only the level identifies c·e^δ; the posterior keeps both
        // (c = 0.2, δ = 0.5) and (c = 0.2·e, δ = −0.5), each a mode.
        let v = if k % 2 == 0 { 40.0 } else { 80.0 };
        let (r, p) = draw(&mut rng, 0.2 * 0.5f64.exp(), v);
        e.update(&t, r, p, v, 0.5, k as f64 * 2000.0);
    }
    let pv: Vec<f64> = e.vehicle_probabilities().collect();
    assert!((pv.iter().sum::<f64>() - 1.0).abs() < 1e-9);
    let s = e.summary();
    // The interval spans both explanations, 0.2 and 0.2·e^1 ≈ 0.54 mm.
    assert!(s.q05_mm < 0.2 && s.q95_mm > 0.5, "{s:?}");
}

#[test]
fn an_old_single_distribution_table_still_loads() {
    let mut t = table();
    t.format = shimmy::observer::table::FORMAT_V1.into();
    assert!(t.validate().is_ok());
    t.vehicles = 2;
    assert!(t.validate().is_err(), "v1 tables have one nuisance set");
}

/// Two nuisance vehicles that the braking features cannot tell apart: vehicle 0 (a large
/// unbalance) shakes at a new joint's clearance as much as vehicle 1 does with worn joints.
/// Before the brake, vehicle 0's steering is busy at every clearance, vehicle 1's goes quiet
/// as the free play grows. A v3 table with the cruise statistic must then name the worn joint;
/// the same table without it must stay undecided.
#[test]
fn the_cruise_statistic_separates_what_the_braking_amplitude_confuses() {
    let clearance_mm: Vec<f64> = (0..8)
        .map(|i| 0.03 * (0.4f64 / 0.03).powf(i as f64 / 7.0))
        .collect();
    let speed_kmh = vec![40.0, 80.0];
    let decel_g = vec![0.5];
    // Braking RMS (deg): vehicle 0 at c equals vehicle 1 at 4c.
    let brake = |c: f64, m: usize| 0.03 + 0.4 * if m == 0 { 4.0 * c } else { c };
    let cruise = |c: f64, m: usize| {
        if m == 0 {
            0.15
        } else {
            0.15 / (1.0 + 40.0 * c)
        }
    };
    let mut cells = Vec::new();
    for &c in &clearance_mm {
        for m in 0..2 {
            for _ in &speed_kmh {
                let z = shimmy::observer::features::z(brake(c, m), 3.0 * brake(c, m));
                cells.push(Cell {
                    mean: z,
                    std: [0.15, 0.15],
                    corr: 0.8,
                    cruise: [shimmy::observer::features::z_cruise(cruise(c, m)), 0.15],
                });
            }
        }
    }
    let t = synthetic(clearance_mm, speed_kmh, decel_g, 2, cells);
    // Vehicle 1 with 0.25 mm joints: braking RMS 0.13 deg, cruise 0.014 deg (noise-free).
    let run = |use_cruise: bool| {
        let cfg = EstimatorConfig {
            cruise: use_cruise,
            std_inflation: 1.0,
            ..EstimatorConfig::mixture()
        };
        let mut e = Estimator::new(&t, cfg).unwrap();
        for k in 0..20 {
            let r = brake(0.25, 1);
            e.update_event(&t, r, 3.0 * r, Some(cruise(0.25, 1)), 60.0, 0.5, k as f64);
        }
        (e.prob_above(0.1), e.summary())
    };
    let (p_with, s_with) = run(true);
    let (p_without, _) = run(false);
    assert!(
        p_with > 0.99,
        "with the cruise statistic: P(c > 0.1) = {p_with}, {s_with:?}"
    );
    assert!(
        (0.15..0.4).contains(&s_with.median_mm),
        "median {} for a true 0.25 mm",
        s_with.median_mm
    );
    assert!(
        p_without < 0.9,
        "without it the large-unbalance explanation must stay open: P = {p_without}"
    );
}

/// The report's posterior over several tables (chassis variants): a mixture weighs each
/// table's posterior by its probability; a table that carries (nearly) all the weight gives
/// its own reading unchanged, and two tables that disagree give an interval spanning both.
#[test]
fn a_mixture_of_posteriors_spans_the_tables_it_weighs() {
    use shimmy::observer::posterior::Posterior;
    let low = run(0.12, 30, 11);
    let high = run(0.3, 30, 12);
    let (sl, sh) = (low.summary(), high.summary());
    assert!(
        sl.q95_mm < sh.q05_mm,
        "the two readings separate: {sl:?} {sh:?}"
    );

    // All the weight on one table: its summary and alert probability.
    let one = Posterior::mixture([(1.0, &low), (1e-9, &high)]).unwrap();
    assert_eq!(one.len(), 1);
    assert_eq!(one.summary(), sl);
    assert_eq!(one.prob_above(0.1), low.prob_above(0.1));

    // Even odds: the probability is the mean, the interval spans both readings, the median
    // lies between them, and each quantile is where the mixture's CDF reaches it.
    let mix = Posterior::mixture([(2.0, &low), (2.0, &high)]).unwrap();
    let s = mix.summary();
    for c in [0.1, 0.15, 0.2] {
        let want = 0.5 * (low.prob_above(c) + high.prob_above(c));
        assert!((mix.prob_above(c) - want).abs() < 1e-12, "{c}");
    }
    assert!(s.q05_mm < sl.median_mm && s.q95_mm > sh.median_mm, "{s:?}");
    assert!(
        sl.median_mm < s.median_mm && s.median_mm < sh.median_mm,
        "{s:?}"
    );
    for q in [0.05, 0.5, 0.95] {
        let x = mix.quantile_mm(q);
        assert!(
            (1.0 - mix.prob_above(x) - q).abs() < 1e-6,
            "q {q}: cdf at {x}"
        );
    }
    assert_eq!(s.events_used, 30);

    // Weights that are not finite and positive are left out; none left is no posterior.
    assert!(Posterior::mixture([(0.0, &low), (f64::NAN, &high)]).is_none());
    let nan = Posterior::mixture([(f64::NAN, &low), (1.0, &high)]).unwrap();
    assert_eq!(nan.summary(), sh);
}
