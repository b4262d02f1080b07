//! Measurement (not a test): how well a known vehicle's braking events tell a clearance at the
//! top of the false-alert band (0.07 mm) from the worn clearances (0.15, 0.2, 0.3, 0.4 mm), over
//! the table's event grid (speeds 35–95 km/h × decelerations 0.3 / 0.55 / 0.8 g), for three
//! signals:
//!
//! * the 5-DOF pinion angle δ_sw of MODEL.md §8 (column off: the model the tables are built on),
//! * the rim angle with the MODEL.md §15 column on, the hands drawn per event from the shipped
//!   prior (off / light / firm at their docs/COLUMN.md range midpoints, with their
//!   probabilities),
//! * the torsion-bar torque T_c of §15 under the same hands,
//! * that torque as the Toyota profile's bus carries it: 50 Hz, 0.01 N·m steps, 0.02 N·m noise,
//!   and so a 3–20 Hz band.
//!
//! Features: ln of the RMS and ln of the peak of the 3–25 Hz, 4th-order zero-phase band-passed
//! signal over the braking window (MODEL.md §11: the estimator's braking features). For each
//! event type k and feature, d_k = (μ₂ − μ₁) / √((σ₁² + σ₂²) / 2 / n_k) with μ, σ² the mean and
//! variance of one event's feature over seeds and hands, and n_k = 30 / K (30 events spread
//! evenly over the K usable types); the combined separation d = √Σ d_k² is the best a test
//! that knows the vehicle, the event types and each feature's distribution can do with 30
//! independent events. Such a test, set for ≤ 2 % false alerts at 0.07 mm, alerts at a worn
//! clearance with probability at most Φ(d − z₀.₉₈); averaged over the fleets' log-uniform
//! clearance in 0.15–0.4 mm that bounds the worn-alert rate any estimator reaches on these
//! features. Left out: the pre-brake cruise feature (the model's scenario starts at the brake)
//! and what an estimator loses by having to infer the vehicle: this is an upper bound.
//!
//!   cargo run --release -p firmware-sim --example column_oracle [-- SEEDS]

use shimmy::analysis::{peak_abs, Bandpass};
use shimmy::model::{run, JointMode, Scenario, VehicleParams};
use shimmy::observer::simulate::{HandsPrior, HandsState};

/// The signals measured, in output order.
const SIGNALS: [&str; 4] = [
    "5-DOF pinion angle",
    "rim angle, column + hands",
    "torsion-bar torque, column + hands",
    "torque as the RAV4 sends it (50 Hz, 0.01 N·m, noise 0.02 N·m; 3–20 Hz band)",
];

/// The Toyota profile's torque sensor (config/vehicles/toyota_rav4: 50 Hz, 0.01 N·m per count
/// assumed, firmware-sim's default torque noise 0.02 N·m): `x` (at `fs_hz`) sampled at 50 Hz
/// (every k-th value, no anti-alias filter assumed), noise added, quantised.
fn rav4_torque(x: &[f64], fs_hz: f64, seed: u64) -> (Vec<f64>, usize) {
    let k = (fs_hz / 50.0).round().max(1.0) as usize;
    // xorshift64* and Box–Muller: a fixed, seeded noise without a dependency.
    let mut st = seed.wrapping_mul(0x9E37_79B9_7F4A_7C15) | 1;
    let mut uniform = || {
        st ^= st >> 12;
        st ^= st << 25;
        st ^= st >> 27;
        ((st.wrapping_mul(0x2545_F491_4F6C_DD1D) >> 11) as f64 + 0.5) / (1u64 << 53) as f64
    };
    let out = x
        .iter()
        .step_by(k)
        .map(|&v| {
            let g = (-2.0 * uniform().ln()).sqrt() * (std::f64::consts::TAU * uniform()).cos();
            ((v + 0.02 * g) / 0.01).round() * 0.01
        })
        .collect();
    (out, k)
}

/// The braking features, in output order.
const FEATURES: [&str; 2] = ["ln RMS", "ln peak"];

/// The standard normal distribution function (Abramowitz–Stegun 26.2.17, |error| < 7.5e-8).
fn phi(x: f64) -> f64 {
    let t = 1.0 / (1.0 + 0.231_641_9 * x.abs());
    let poly = t
        * (0.319_381_530
            + t * (-0.356_563_782
                + t * (1.781_477_937 + t * (-1.821_255_978 + t * 1.330_274_429))));
    let tail = (-x * x / 2.0).exp() / (2.0 * std::f64::consts::PI).sqrt() * poly;
    if x >= 0.0 {
        1.0 - tail
    } else {
        tail
    }
}

fn main() -> anyhow::Result<()> {
    let n_seeds: u64 = match std::env::args().nth(1) {
        Some(s) => s.parse()?,
        None => 6,
    };
    let prior = HandsPrior::default();
    let states = [HandsState::Off, HandsState::Light, HandsState::Firm];
    let clearances_mm = [0.07, 0.15, 0.2, 0.3, 0.4];
    let speeds_kmh = [35.0, 55.0, 75.0, 95.0];
    let decels_g = [0.3, 0.55, 0.8];
    // A job: (clearance, speed, decel, hands state or None for the 5-DOF run, seed).
    let mut jobs = Vec::new();
    for &c in &clearances_mm {
        for &v in &speeds_kmh {
            for &a in &decels_g {
                for s in std::iter::once(None).chain(states.iter().copied().map(Some)) {
                    for seed in 0..n_seeds {
                        jobs.push((c, v, a, s, seed));
                    }
                }
            }
        }
    }
    // One run: [ln rms, ln peak] of the pinion angle (5-DOF) or of the rim and the torque.
    type Job = (f64, f64, f64, Option<HandsState>, u64);
    let one = |&(c_mm, v_kmh, a_g, s, seed): &Job| -> anyhow::Result<[f64; 6]> {
        let mut p = VehicleParams::default();
        if let Some(s) = s {
            p.column.enabled = true;
            p.column.set_hands(prior.range(s).midpoint());
        }
        let sc = Scenario {
            joints: JointMode::Dual,
            clearance_m: c_mm * 1e-3,
            v0_mps: v_kmh / 3.6,
            decel_g: a_g,
            seed,
            ..Scenario::default()
        };
        let tr = run(&p, &sc)?;
        let w = tr.braking_window();
        let bp = Bandpass::new(tr.fs_hz, 3.0, 25.0, 4)?;
        let feats = |x: &[f64]| {
            let x = &x[w.clone()];
            let rms = (x.iter().map(|v| v * v).sum::<f64>() / x.len().max(1) as f64).sqrt();
            [rms.ln(), peak_abs(x).ln()]
        };
        let sw = feats(&bp.filtfilt(&tr.column(|o| o.delta_sw_rad)));
        let (tc, t50) = if s.is_some() {
            let tq = tr.column(|o| o.column_torque_nm);
            let (x50, k) = rav4_torque(&tq, tr.fs_hz, seed ^ (c_mm * 1e6) as u64 ^ v_kmh as u64);
            let bp50 = Bandpass::new(50.0, 3.0, 20.0, 4)?;
            let y = bp50.filtfilt(&x50);
            let w50 = (w.start / k).min(y.len())..(w.end / k).min(y.len());
            let y = &y[w50];
            let rms = (y.iter().map(|v| v * v).sum::<f64>() / y.len().max(1) as f64).sqrt();
            (feats(&bp.filtfilt(&tq)), [rms.ln(), peak_abs(y).ln()])
        } else {
            ([f64::NAN; 2], [f64::NAN; 2])
        };
        Ok([sw[0], sw[1], tc[0], tc[1], t50[0], t50[1]])
    };
    // Two threads (the machine is shared).
    let results: Vec<anyhow::Result<[f64; 6]>> = std::thread::scope(|sc| {
        let (a, b) = jobs.split_at(jobs.len() / 2);
        let ha = sc.spawn(|| a.iter().map(one).collect::<Vec<_>>());
        let hb = sc.spawn(|| b.iter().map(one).collect::<Vec<_>>());
        let mut r = ha.join().expect("thread");
        r.extend(hb.join().expect("thread"));
        r
    });
    let results: Vec<[f64; 6]> = results.into_iter().collect::<anyhow::Result<_>>()?;
    let per_cell = (1 + states.len()) * n_seeds as usize;
    let stat = |xs: &[f64]| {
        let m = xs.iter().sum::<f64>() / xs.len() as f64;
        let v = xs.iter().map(|x| (x - m).powi(2)).sum::<f64>() / (xs.len().max(2) - 1) as f64;
        (m, v)
    };
    // Mean and variance of one event's feature `f` of signal `sig` at cell (clearance ci,
    // event type k): over seeds for the 5-DOF, over the hands mixture otherwise.
    let moments = |ci: usize, k: usize, sig: usize, f: usize| -> (f64, f64) {
        let base = (ci * speeds_kmh.len() * decels_g.len() + k) * per_cell;
        let pick = |r: &[f64; 6]| if sig >= 2 { r[2 * (sig - 1) + f] } else { r[f] };
        let seeds = n_seeds as usize;
        if sig == 0 {
            let xs: Vec<f64> = results[base..base + seeds].iter().map(pick).collect();
            return stat(&xs);
        }
        let (mut m, mut m2) = (0.0, 0.0);
        for (si, &s) in states.iter().enumerate() {
            let w = prior.range(s).probability;
            let k0 = base + (1 + si) * seeds;
            let xs: Vec<f64> = results[k0..k0 + seeds].iter().map(pick).collect();
            let (mu, var) = stat(&xs);
            m += w * mu;
            m2 += w * (var + mu * mu);
        }
        (m, m2 - m * m)
    };
    let n_types = speeds_kmh.len() * decels_g.len();
    // An event type whose braking window is too short for the band-pass (a stop from 35 km/h
    // at 0.55 g or harder) gives no feature: it is left out and its events go to the others.
    let usable = |k: usize| {
        (0..clearances_mm.len()).all(|ci| {
            (0..SIGNALS.len()).all(|sig| (0..2).all(|f| moments(ci, k, sig, f).0.is_finite()))
        })
    };
    let types: Vec<usize> = (0..n_types).filter(|&k| usable(k)).collect();
    let n_k = 30.0 / types.len() as f64;
    println!(
        "one known vehicle (nominal), {n_seeds} seeds per cell, {} runs; {} of {n_types} event \
         types usable, {n_k:.1} events each",
        jobs.len(),
        types.len()
    );
    println!();
    // d of 0.07 mm against clearance ci, signal sig, feature f: per event type, and combined.
    let d_of = |ci: usize, sig: usize, f: usize| -> (Vec<f64>, f64) {
        let mut ds = Vec::new();
        for k in 0..n_types {
            let (m1, v1) = moments(0, k, sig, f);
            let (m2, v2) = moments(ci, k, sig, f);
            ds.push((m2 - m1) / ((v1 + v2) / 2.0 / n_k).sqrt());
        }
        let comb = types.iter().map(|&k| ds[k] * ds[k]).sum::<f64>().sqrt();
        (ds, comb)
    };
    println!(
        "0.07 mm against 0.15 mm, per event type (35 / 55 / 75 / 95 km/h, each 0.3 / 0.55 / 0.8 g):"
    );
    println!();
    println!("| signal | feature | d per event type | combined d, 30 events |");
    println!("|---|---|---|---|");
    for (sig, name) in SIGNALS.iter().enumerate() {
        for (f, fname) in FEATURES.iter().enumerate() {
            let (ds, comb) = d_of(1, sig, f);
            let cells: Vec<String> = ds
                .chunks(decels_g.len())
                .map(|c| {
                    c.iter()
                        .map(|d| {
                            if d.is_finite() {
                                format!("{d:.1}")
                            } else {
                                "–".into()
                            }
                        })
                        .collect::<Vec<_>>()
                        .join(" ")
                })
                .collect();
            println!("| {name} | {fname} | {} | {comb:.1} |", cells.join(" / "));
        }
    }
    // The best alert rate a known-vehicle test can reach at each worn clearance with at most
    // 2 % false alerts at 0.07 mm: Φ(d − z₀.₉₈) for the better feature, and its mean over the
    // fleets' log-uniform clearance in 0.15–0.4 mm (d interpolated linearly in ln c).
    let z98 = 2.054;
    println!();
    println!(
        "0.07 mm against each worn clearance, better feature, 30 events; the alert rate bound \
         Φ(d − {z98}) at ≤ 2 % false alerts, and its mean over log-uniform c in 0.15–0.4 mm:"
    );
    println!();
    let worn: Vec<f64> = clearances_mm[1..].to_vec();
    let head: Vec<String> = worn.iter().map(|c| format!("{c} mm")).collect();
    println!("| signal | {} | worn alerted, bound |", head.join(" | "));
    println!("|---|{}---|", "---|".repeat(worn.len()));
    for (sig, name) in SIGNALS.iter().enumerate() {
        let ds: Vec<f64> = (1..clearances_mm.len())
            .map(|ci| {
                (0..FEATURES.len())
                    .map(|f| d_of(ci, sig, f).1)
                    .fold(0.0, f64::max)
            })
            .collect();
        let n = 400;
        let (a, b) = (worn[0].ln(), worn[worn.len() - 1].ln());
        let mut rate = 0.0;
        for i in 0..n {
            let x = a + (b - a) * (i as f64 + 0.5) / n as f64;
            let j = worn
                .windows(2)
                .position(|w| x <= w[1].ln())
                .unwrap_or(worn.len() - 2);
            let w = (x - worn[j].ln()) / (worn[j + 1].ln() - worn[j].ln());
            rate += phi(ds[j] + w * (ds[j + 1] - ds[j]) - z98) / n as f64;
        }
        let cells: Vec<String> = ds
            .iter()
            .map(|d| format!("d {d:.1}, {:.0} %", 100.0 * phi(d - z98)))
            .collect();
        println!("| {name} | {} | {:.0} % |", cells.join(" | "), 100.0 * rate);
    }
    Ok(())
}
