//! The estimator's method "linear" (src/observer/marginal.rs) on data drawn from its own model:
//! a linear nuisance law with event scatter and a per-vehicle misfit. With the model right, its
//! 90 % intervals must hold the truth about 90 % of the time and its estimates must sit close;
//! a table without the linear model must be refused, not silently estimated with another
//! method.

use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use rand_distr::{Distribution, Normal};
use shimmy::observer::estimator::{Estimator, EstimatorConfig};
use shimmy::observer::linear::{parse_terms, LinearModel};
use shimmy::observer::table::{Cell, ResponseTable};

#[path = "support/synthetic_table.rs"]
mod synthetic_table;
use synthetic_table::synthetic;

const CLEARANCES: usize = 9;
const SPEEDS: [f64; 2] = [30.0, 100.0];
/// Slopes of (ln RMS, ln peak, cruise) in the seven nuisance coordinates at the low speed; at
/// the high speed they are [`HIGH_SPEED_SLOPE`] times these, so events at both speeds tell the
/// nuisances from the clearance (as speed does in the shimmy model).
const B: [[f64; 7]; 3] = [
    [0.0, 0.3, 0.0, 0.05, 0.0, 0.2, 0.05],
    [0.0, 0.3, 0.0, 0.05, 0.0, 0.25, 0.05],
    [0.1, 0.0, 0.0, 0.0, 0.0, 0.4, 0.1],
];
const HIGH_SPEED_SLOPE: f64 = 0.3;
const EVENT_STD: f64 = 0.15;
/// Effect of ψ = cos(φ_R − φ_L) on (ln RMS, ln peak, cruise) at the low speed; at the high
/// speed it is [`HIGH_SPEED_PHASE`] times this (another speed profile than the clearance's, as
/// in the shimmy model, so that a kept phase difference can be told from the clearance).
const PHASE: [f64; 3] = [-0.25, -0.25, 0.1];
const HIGH_SPEED_PHASE: f64 = -0.5;

fn phase_slope(f: usize, iv: usize) -> f64 {
    PHASE[f] * if iv == 0 { 1.0 } else { HIGH_SPEED_PHASE }
}

fn slope(f: usize, iv: usize, j: usize) -> f64 {
    B[f][j] * if iv == 0 { 1.0 } else { HIGH_SPEED_SLOPE }
}
const MISFIT_STD: f64 = 0.03;

fn clearances() -> Vec<f64> {
    (0..CLEARANCES)
        .map(|i| 0.03 * (0.4f64 / 0.03).powf(i as f64 / (CLEARANCES - 1) as f64))
        .collect()
}

/// Feature means at ξ = 0: linear in ln c (so the grid's interpolation is exact).
fn a(c_mm: f64, iv: usize, decel_g: f64) -> [f64; 3] {
    let l = (c_mm / 0.1).ln();
    let d = (decel_g - 0.55) / 0.25;
    [
        -1.2 + 0.9 * l + 0.1 * iv as f64 + 0.05 * d,
        -0.4 + 0.9 * l + 0.1 * iv as f64 + 0.05 * d,
        -2.5 - 0.5 * l + 0.2 * iv as f64,
    ]
}

fn table(with_linear: bool) -> ResponseTable {
    table_with(with_linear, false)
}

/// [`table`], with the ψ term of [`PHASE`] in the model when `phase`.
fn table_with(with_linear: bool, phase: bool) -> ResponseTable {
    let cl = clearances();
    let cells = vec![
        Cell {
            mean: [-2.0, -1.0],
            std: [0.2, 0.2],
            corr: 0.5,
            cruise: [-2.5, 0.2],
        };
        CLEARANCES * SPEEDS.len() * 2
    ];
    let mut t = synthetic(cl.clone(), SPEEDS.to_vec(), vec![0.3, 0.8], 1, cells);
    if with_linear {
        let mut coef = Vec::new();
        for &c in &cl {
            for iv in 0..SPEEDS.len() {
                let a0 = a(c, iv, 0.55);
                let a1 = a(c, iv, 0.8);
                for f in 0..3 {
                    // Terms 1, d, x0..x6 (and u) (below).
                    coef.push(a0[f]);
                    coef.push(a1[f] - a0[f]);
                    for j in 0..7 {
                        coef.push(slope(f, iv, j));
                    }
                    if phase {
                        coef.push(phase_slope(f, iv));
                    }
                }
            }
        }
        let v = EVENT_STD * EVENT_STD;
        let within = [[v, 0.8 * v, 0.0], [0.8 * v, v, 0.0], [0.0, 0.0, v]];
        let m = MISFIT_STD * MISFIT_STD;
        let between = [[m, 0.0, 0.0], [0.0, m, 0.0], [0.0, 0.0, m]];
        t.linear = Some(std::sync::Arc::new(LinearModel {
            vehicles: 40,
            terms: parse_terms(if phase {
                "1,d,x0,x1,x2,x3,x4,x5,x6,u"
            } else {
                "1,d,x0,x1,x2,x3,x4,x5,x6"
            })
            .unwrap(),
            gridded: vec![],
            coef,
            total_std: vec![[0.2; 3]; CLEARANCES],
            total_corr: vec![0.5; CLEARANCES],
            within: vec![within; CLEARANCES],
            between: vec![between; CLEARANCES],
        }));
    }
    t.validate().unwrap();
    t
}

fn linear_cfg() -> EstimatorConfig {
    // Data drawn from the model itself: nothing shared between events is missing, so the
    // events count in full.
    EstimatorConfig {
        evidence_power: 1.0,
        ..EstimatorConfig::default()
    }
}

/// A vehicle's own nuisances: the seven coordinates, the per-feature misfit and how its
/// wheels' unbalance phase difference behaves (tables with the ψ term only).
struct Nuisances {
    xi: [f64; 7],
    eta: [f64; 3],
    phase: Phase,
}

#[derive(Clone, Copy, PartialEq)]
enum Phase {
    /// ψ the same in every event.
    Kept(f64),
    /// ψ drawn anew in every event.
    PerEvent,
}

/// ψ of a phase difference uniform in [0, 2π).
fn draw_psi(rng: &mut ChaCha8Rng) -> f64 {
    (rng.random::<f64>() * std::f64::consts::TAU).cos()
}

fn draw_nuisances(rng: &mut ChaCha8Rng) -> Nuisances {
    let n = Normal::new(0.0, 1.0).unwrap();
    Nuisances {
        xi: std::array::from_fn(|_| rng.random_range(-1.0..=1.0)),
        eta: std::array::from_fn(|_| MISFIT_STD * n.sample(rng)),
        phase: Phase::Kept(draw_psi(rng)),
    }
}

/// `events` events of a vehicle with nuisances `v` and clearance `c_mm`, 1 km apart from
/// odometer `odo0_m` on, into `est`.
#[allow(clippy::too_many_arguments)]
fn drive(
    est: &mut Estimator,
    t: &ResponseTable,
    v: &Nuisances,
    c_mm: f64,
    events: usize,
    odo0_m: f64,
    rng: &mut ChaCha8Rng,
) {
    let n = Normal::new(0.0, 1.0).unwrap();
    for e in 0..events {
        let iv = e % 2;
        let d = if e % 3 == 0 { 0.3 } else { 0.8 };
        let g1: f64 = n.sample(rng);
        let g2 = 0.8 * g1 + 0.6 * n.sample(rng);
        let g3: f64 = n.sample(rng);
        let am = a(c_mm, iv, d);
        let psi = match v.phase {
            Phase::Kept(p) => p,
            Phase::PerEvent => draw_psi(rng),
        };
        let with_phase = t.linear.as_ref().is_some_and(|m| m.has_phase());
        let z: [f64; 3] = std::array::from_fn(|f| {
            let s: f64 = (0..7).map(|j| slope(f, iv, j) * v.xi[j]).sum();
            let ph = if with_phase {
                phase_slope(f, iv) * psi
            } else {
                0.0
            };
            am[f] + s + ph + v.eta[f] + EVENT_STD * [g1, g2, g3][f]
        });
        // Invert the floored logs of features::z / z_cruise.
        let un = |z: f64, floor: f64| ((2.0 * z).exp() - floor * floor).max(1e-12).sqrt();
        est.update_event(
            t,
            un(z[0], 0.02),
            un(z[1], 0.05),
            Some(un(z[2], 0.02)),
            SPEEDS[iv],
            d,
            odo0_m + 1000.0 * e as f64,
        );
    }
}

/// One vehicle of clearance `c_mm` with its own nuisances, `events` events; the estimator
/// after them.
fn vehicle(t: &ResponseTable, c_mm: f64, events: usize, rng: &mut ChaCha8Rng) -> Estimator {
    let v = draw_nuisances(rng);
    let mut est = Estimator::new(t, linear_cfg()).unwrap();
    drive(&mut est, t, &v, c_mm, events, 0.0, rng);
    est
}

/// Wear: the same vehicle at 0.05 mm, then 40 000 km later at 0.25 mm. With a 5000 km
/// half-life the old events have faded (to 2⁻⁸) and the estimate follows the joints. Without fading
/// (half-life 0) the two drives are pooled and the estimate stays between them.
#[test]
fn old_evidence_fades_so_the_estimate_follows_wear() {
    let t = table(true);
    let run = |half_life_km: f64| {
        let mut rng = ChaCha8Rng::seed_from_u64(8);
        let v = draw_nuisances(&mut rng);
        let cfg = EstimatorConfig {
            evidence_half_life_km: half_life_km,
            ..linear_cfg()
        };
        let mut est = Estimator::new(&t, cfg).unwrap();
        drive(&mut est, &t, &v, 0.05, 30, 0.0, &mut rng);
        drive(&mut est, &t, &v, 0.25, 30, 4.0e7, &mut rng);
        est.summary()
    };
    let fading = run(5000.0);
    assert!(
        fading.q05_mm <= 0.25
            && 0.25 <= fading.q95_mm
            && (fading.median_mm / 0.25 - 1.0).abs() < 0.2,
        "{fading:?}"
    );
    let pooled = run(0.0);
    assert!(
        pooled.median_mm < 0.8 * fading.median_mm,
        "pooled {pooled:?} fading {fading:?}"
    );
}

#[test]
fn intervals_cover_the_truth_and_estimates_sit_close_when_the_model_is_right() {
    let t = table(true);
    let mut rng = ChaCha8Rng::seed_from_u64(21);
    let (mut covered, mut rel_err, n) = (0, 0.0, 80);
    for _ in 0..n {
        let c = 0.05 * (6.0f64).powf(rng.random::<f64>());
        let s = vehicle(&t, c, 30, &mut rng).summary();
        if s.q05_mm <= c && c <= s.q95_mm {
            covered += 1;
        }
        rel_err += (s.median_mm / c - 1.0).abs() / n as f64;
    }
    let cov = covered as f64 / n as f64;
    assert!((0.8..=0.98).contains(&cov), "coverage {cov}");
    assert!(rel_err < 0.12, "mean relative error {rel_err}");
}

#[test]
fn more_events_narrow_the_interval() {
    let t = table(true);
    let width = |events| {
        let mut rng = ChaCha8Rng::seed_from_u64(5);
        let s = vehicle(&t, 0.15, events, &mut rng).summary();
        (s.q95_mm / s.q05_mm).ln()
    };
    let (w3, w30) = (width(3), width(30));
    assert!(w30 < 0.6 * w3, "3 events: {w3}, 30 events: {w30}");
}

#[test]
fn method_linear_needs_a_table_with_the_linear_model() {
    let e = Estimator::new(&table(false), linear_cfg())
        .err()
        .expect("refused");
    assert!(e.to_string().contains("linear nuisance model"), "{e}");
    let bad = EstimatorConfig {
        method: "kalman".into(),
        ..EstimatorConfig::default()
    };
    let e = Estimator::new(&table(true), bad).err().expect("refused");
    assert!(e.to_string().contains("mixture or linear"), "{e}");
}

/// Estimates of `n` vehicles (clearance log-uniform 0.05-0.3 mm, 30 events) whose phase
/// difference behaves as `phase`, with the estimator's `phase` setting `mode`: (coverage of
/// the 90 % interval, mean relative error of the median, mean P(phase kept)).
fn phase_fleet(mode: &str, phase: Option<Phase>, n: usize, seed: u64) -> (f64, f64, f64) {
    let t = table_with(true, true);
    let mut rng = ChaCha8Rng::seed_from_u64(seed);
    let (mut covered, mut rel_err, mut p_kept) = (0, 0.0, 0.0);
    for _ in 0..n {
        let c = 0.05 * (6.0f64).powf(rng.random::<f64>());
        let mut v = draw_nuisances(&mut rng);
        if let Some(p) = phase {
            v.phase = p;
        }
        let cfg = EstimatorConfig {
            phase: mode.into(),
            ..linear_cfg()
        };
        let mut est = Estimator::new(&t, cfg).unwrap();
        drive(&mut est, &t, &v, c, 30, 0.0, &mut rng);
        let s = est.summary();
        covered += (s.q05_mm <= c && c <= s.q95_mm) as usize;
        rel_err += (s.median_mm / c - 1.0).abs() / n as f64;
        p_kept += est.phase_fixed_probability().unwrap_or(f64::NAN) / n as f64;
    }
    (covered as f64 / n as f64, rel_err, p_kept)
}

/// A phase difference the wheels keep shifts every event of the vehicle the same way. Taken as
/// the vehicle's ("vehicle") it is learned from the events' speed profile and the estimate
/// stays right; taken as new in every event ("event") it is noise that the vehicle's events
/// do not average out, and the estimate is worse.
#[test]
fn a_kept_phase_difference_is_learned_not_taken_for_clearance() {
    let (cov_v, err_v, _) = phase_fleet("vehicle", None, 60, 31);
    let (_, err_e, _) = phase_fleet("event", None, 60, 31);
    assert!((0.8..=0.98).contains(&cov_v), "coverage {cov_v}");
    assert!(err_v < 0.12, "mean relative error {err_v}");
    assert!(err_v < 0.8 * err_e, "vehicle {err_v} vs event {err_e}");
}

/// `phase = "either"` lets the events decide: a kept phase difference is recognised as such,
/// one that changes between events as changing, and the intervals hold the truth either way.
#[test]
fn either_tells_a_kept_phase_difference_from_a_changing_one() {
    let (cov_k, err_k, p_k) = phase_fleet("either", None, 50, 41);
    let (cov_c, err_c, p_c) = phase_fleet("either", Some(Phase::PerEvent), 50, 42);
    assert!(p_k > 0.8, "kept: P(kept) {p_k}");
    assert!(p_c < 0.2, "changing: P(kept) {p_c}");
    for (cov, err) in [(cov_k, err_k), (cov_c, err_c)] {
        assert!((0.8..=1.0).contains(&cov), "coverage {cov}");
        assert!(err < 0.15, "mean relative error {err}");
    }
}

/// `prior_range_mm`: before any event the estimate is the prior's (its median the range's
/// geometric middle, its interval inside the range when cut off there); events move it as
/// before; a range holding none of the table's clearances, or a reversed one, is refused.
#[test]
fn the_clearance_prior_is_what_the_posterior_starts_from_and_events_outweigh_it() {
    let t = table(true);
    let cut = EstimatorConfig {
        prior_range_mm: Some([0.05, 0.2]),
        ..linear_cfg()
    };
    let s = Estimator::new(&t, cut.clone()).unwrap().summary();
    assert!((s.median_mm / 0.1 - 1.0).abs() < 0.1, "{s:?}");
    // The quantiles spread each grid point's mass over its cell (a grid step is ×1.38 here).
    assert!(s.q05_mm > 0.04 && s.q95_mm < 0.25, "{s:?}");
    let flat = Estimator::new(&t, linear_cfg()).unwrap().summary();
    assert!(
        flat.q95_mm / flat.q05_mm > 2.0 * s.q95_mm / s.q05_mm,
        "{flat:?} {s:?}"
    );
    // A soft fall-off leaves mass outside the range.
    let soft = EstimatorConfig {
        prior_tail: 0.5,
        ..cut.clone()
    };
    let s2 = Estimator::new(&t, soft.clone()).unwrap().summary();
    assert!(s2.q95_mm > s.q95_mm && s2.q05_mm < s.q05_mm, "{s2:?} {s:?}");
    // 30 events of a 0.3 mm vehicle: the soft prior follows them out of the range.
    let mut rng = ChaCha8Rng::seed_from_u64(3);
    let v = draw_nuisances(&mut rng);
    let mut est = Estimator::new(&t, soft).unwrap();
    drive(&mut est, &t, &v, 0.3, 30, 0.0, &mut rng);
    let s3 = est.summary();
    assert!(s3.median_mm > 0.2 && s3.q95_mm >= 0.3, "{s3:?}");
    for (range, msg) in [
        ([0.7, 0.9], "holds none of the table's clearances"),
        ([0.2, 0.05], "0 < low < high"),
    ] {
        let bad = EstimatorConfig {
            prior_range_mm: Some(range),
            ..linear_cfg()
        };
        let e = Estimator::new(&t, bad).err().expect("refused");
        assert!(e.to_string().contains(msg), "{e}");
    }
}
