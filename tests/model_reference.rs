//! Agreement with the independent implementation of MODEL.md §13 (means over seeds 0, 1, 2;
//! dual clearance, 0.5 g, RK4 h = 1e-4 s, §11 definitions), and the issue-3 grid: every
//! c × v0 × deceleration combination runs to the end without a non-finite value.
//!
//! Tolerances (why): §13 says single runs differ by seed and only seed means are comparable.
//! - θ1 table: |our mean − §13| ≤ max(25 % of the §13 value, 2 × our seed-to-seed std). §13
//!   gives no θ1 spread; our 3-seed std is itself uncertain (at 25 km/h, where the kick
//!   transient dominates, it reaches 50 % of the mean), so 2σ alone would be meaningless where
//!   the seeds happen to agree. 25 % is the level at which a sign, frame or unit error shows
//!   (such errors change the amplitude by factors, not percent; see tests/model_physics.rs).
//! - Steering wheel at 55 km/h: |our mean − §13| ≤ 2 × max(our std, 0.02°), with 0.02–0.05°
//!   the seed-to-seed std §13 quotes.

use shimmy::model::features::{features, Features};
use shimmy::model::{run, Integrator, Scenario, VehicleParams};
use std::sync::atomic::{AtomicUsize, Ordering};
use std::sync::Mutex;

/// Runs `jobs` on two threads (the machine's two cores), keeping the input order.
fn par_map<J: Sync, R: Send>(jobs: &[J], f: impl Fn(&J) -> R + Sync) -> Vec<R> {
    let next = AtomicUsize::new(0);
    let out: Mutex<Vec<Option<R>>> = Mutex::new((0..jobs.len()).map(|_| None).collect());
    std::thread::scope(|s| {
        for _ in 0..2 {
            s.spawn(|| loop {
                let i = next.fetch_add(1, Ordering::Relaxed);
                if i >= jobs.len() {
                    break;
                }
                let r = f(&jobs[i]);
                out.lock().unwrap()[i] = Some(r);
            });
        }
    });
    out.into_inner()
        .unwrap()
        .into_iter()
        .map(|r| r.unwrap())
        .collect()
}

fn case(c_mm: f64, v_kmh: f64, decel_g: f64, seed: u64) -> Scenario {
    Scenario {
        clearance_m: c_mm * 1e-3,
        v0_mps: v_kmh / 3.6,
        decel_g,
        seed,
        ..Scenario::default()
    }
}

fn mean_std(x: &[f64]) -> (f64, f64) {
    let n = x.len() as f64;
    let m = x.iter().sum::<f64>() / n;
    let v = x.iter().map(|v| (v - m).powi(2)).sum::<f64>() / (n - 1.0);
    (m, v.sqrt())
}

const CS: [f64; 5] = [0.03, 0.05, 0.10, 0.20, 0.40];
const VS: [f64; 5] = [25.0, 40.0, 55.0, 75.0, 95.0];
/// MODEL.md §13, peak band-passed θ1 (deg), rows c, columns v0.
const THETA1_REF: [[f64; 5]; 5] = [
    [0.010, 0.018, 0.022, 0.022, 0.022],
    [0.016, 0.027, 0.030, 0.031, 0.031],
    [0.025, 0.049, 0.054, 0.053, 0.056],
    [0.027, 0.092, 0.105, 0.102, 0.107],
    [0.027, 0.157, 0.196, 0.205, 0.202],
];
/// MODEL.md §13, peak band-passed δ_sw at 55 km/h (deg).
const SW_REF: [(f64, f64); 8] = [
    (0.03, 0.13),
    (0.05, 0.13),
    (0.07, 0.13),
    (0.10, 0.15),
    (0.15, 0.19),
    (0.20, 0.22),
    (0.30, 0.26),
    (0.40, 0.28),
];
const SEEDS: [u64; 3] = [0, 1, 2];

#[test]
fn seed_means_agree_with_model_md_section_13() {
    // RK4 with the warm-started slip inversion: the same statistics as the 8-cold-step
    // variant to all printed digits (docs/BENCHMARKS.md) at half the CPU time.
    agree_with_section_13(Integrator::Rk4WarmSlip);
}

#[test]
fn seed_means_agree_with_model_md_section_13_adaptive_integrator() {
    // The fastest scheme (docs/BENCHMARKS.md), the one recommended to firmware-sim and the
    // observer, must pass the same check.
    agree_with_section_13(Integrator::Rk4Adaptive);
}

fn agree_with_section_13(integrator: Integrator) {
    let p = VehicleParams::default();
    let mut jobs: Vec<(f64, f64, u64)> = Vec::new();
    for &c in &CS {
        for &v in &VS {
            for &s in &SEEDS {
                jobs.push((c, v, s));
            }
        }
    }
    for &(c, _) in &SW_REF {
        if !CS.contains(&c) {
            for &s in &SEEDS {
                jobs.push((c, 55.0, s));
            }
        }
    }
    let res: Vec<Features> = par_map(&jobs, |&(c, v, s)| {
        let sc = Scenario {
            integrator,
            ..case(c, v, 0.5, s)
        };
        features(&run(&p, &sc).unwrap()).unwrap()
    });
    let cell = |c: f64, v: f64, f: fn(&Features) -> f64| -> (f64, f64) {
        let x: Vec<f64> = jobs
            .iter()
            .zip(&res)
            .filter(|((jc, jv, _), _)| *jc == c && *jv == v)
            .map(|(_, r)| f(r))
            .collect();
        assert_eq!(x.len(), SEEDS.len());
        mean_std(&x)
    };
    let mut report = String::from("θ1 peak (deg) ours mean±std vs §13:\n");
    let mut bad = Vec::new();
    for (i, &c) in CS.iter().enumerate() {
        for (j, &v) in VS.iter().enumerate() {
            let (m, s) = cell(c, v, |r| r.peak_theta1_bp_deg);
            let r = THETA1_REF[i][j];
            let tol = (0.25 * r).max(2.0 * s);
            report += &format!("  c={c} v={v}: {m:.4}±{s:.4} vs {r} (tol {tol:.4})\n");
            if (m - r).abs() > tol {
                bad.push(format!("θ1 c={c} mm v0={v} km/h: {m:.4} vs {r}"));
            }
        }
    }
    report += "δ_sw peak at 55 km/h (deg):\n";
    for &(c, r) in &SW_REF {
        let (m, s) = cell(c, 55.0, |r| r.peak_sw_bp_deg);
        let tol = 2.0 * s.max(0.02);
        report += &format!("  c={c}: {m:.3}±{s:.3} vs {r} (tol {tol:.3})\n");
        if (m - r).abs() > tol {
            bad.push(format!("δ_sw c={c} mm: {m:.3} vs {r}"));
        }
    }
    println!("{report}");
    assert!(
        bad.is_empty(),
        "{integrator:?}: disagree with MODEL.md §13: {bad:?}\n{report}"
    );
}

#[test]
fn every_grid_combination_runs_without_failure() {
    // Issue 3: c ∈ {0.03…0.4} mm × v0 ∈ {25…95} km/h × 0.3–0.8 g, full 10 s events.
    let p = VehicleParams::default();
    let mut jobs = Vec::new();
    for &c in &CS {
        for &v in &VS {
            for a in [0.3, 0.5, 0.8] {
                jobs.push((c, v, a));
            }
        }
    }
    let res = par_map(&jobs, |&(c, v, a)| -> Result<(f64, f64), String> {
        let tr = run(&p, &case(c, v, a, 7)).map_err(|e| e.to_string())?;
        if let Some(o) = tr.samples.iter().find(|o| {
            ![
                o.theta1_rad,
                o.theta2_rad,
                o.x_m,
                o.theta4_rad,
                o.contact_fx_n[0],
                o.tire_fy_n[0],
            ]
            .iter()
            .all(|v| v.is_finite())
        }) {
            return Err(format!("non-finite at t = {}", o.t_s));
        }
        let stop = tr.t_stop_s().ok_or("never stopped")?;
        let f = features(&tr).map_err(|e| e.to_string())?;
        Ok((stop, f.peak_theta1_bp_deg))
    });
    let mut failures = Vec::new();
    for (j, r) in jobs.iter().zip(&res) {
        match r {
            Ok((_, peak)) if *peak > 0.0 && *peak < 5.0 => {}
            other => failures.push(format!("{j:?}: {other:?}")),
        }
    }
    assert!(failures.is_empty(), "{failures:#?}");
}
