//! Measurement (not a test): what the driver's hands do to the steering-wheel (rim) angle and
//! the column torque T_c of MODEL.md §15 on a braking event at 55 km/h, 0.5 g, for a few
//! clearances and seeds, with hands off, a light grip and a firm grip (each at the midpoint of
//! its docs/COLUMN.md range). Amplitudes: peak of the 3–25 Hz, 4th-order zero-phase
//! band-passed signal over the braking window (as §15's table). Prints a Markdown table, then
//! how well each signal tells two clearances apart when the hands change from event to event
//! as the hands prior draws them (off/light/firm with its probabilities): the separation of two
//! 30-event means, d'₃₀ = (μ₂ − μ₁) / √((σ₁² + σ₂²) / 2 / 30), μ and σ² the mean and variance of
//! one event's amplitude over the hands mixture (each state's seed scatter included). One
//! vehicle (the nominal one) known: this is what the signal carries, not what an estimator
//! that must also infer the vehicle gets.
//!
//!   cargo run --release -p firmware-sim --example column_hands [-- SEEDS]

use shimmy::analysis::{peak_abs, Bandpass};
use shimmy::model::{run, JointMode, Scenario, VehicleParams};
use shimmy::observer::simulate::{HandsPrior, HandsState};

fn main() -> anyhow::Result<()> {
    let n_seeds: u64 = match std::env::args().nth(1) {
        Some(s) => s.parse()?,
        None => 3,
    };
    let prior = HandsPrior::default();
    let states = [HandsState::Off, HandsState::Light, HandsState::Firm];
    let mid = |s: HandsState| prior.range(s).midpoint();
    let clearances_mm = [0.03, 0.07, 0.1, 0.15, 0.2, 0.4];
    let mut jobs = Vec::new();
    for &c in &clearances_mm {
        for &s in &states {
            for seed in 0..n_seeds {
                jobs.push((c, s, seed));
            }
        }
    }
    let one = |&(c_mm, s, seed): &(f64, HandsState, u64)| -> anyhow::Result<(f64, f64)> {
        let mut p = VehicleParams::default();
        p.column.enabled = true;
        p.column.set_hands(mid(s));
        let sc = Scenario {
            joints: JointMode::Dual,
            clearance_m: c_mm * 1e-3,
            seed,
            ..Scenario::default()
        };
        let tr = run(&p, &sc)?;
        let w = tr.braking_window();
        let bp = Bandpass::new(tr.fs_hz, 3.0, 25.0, 4)?;
        let sw = bp.filtfilt(&tr.column(|o| o.delta_sw_rad));
        let tc = bp.filtfilt(&tr.column(|o| o.column_torque_nm));
        Ok((peak_abs(&sw[w.clone()]).to_degrees(), peak_abs(&tc[w])))
    };
    // Two threads (the machine is shared).
    let results: Vec<anyhow::Result<(f64, f64)>> = std::thread::scope(|sc| {
        let (a, b) = jobs.split_at(jobs.len() / 2);
        let ha = sc.spawn(|| a.iter().map(one).collect::<Vec<_>>());
        let hb = sc.spawn(|| b.iter().map(one).collect::<Vec<_>>());
        let mut r = ha.join().expect("thread");
        r.extend(hb.join().expect("thread"));
        r
    });
    let results: Vec<(f64, f64)> = results.into_iter().collect::<anyhow::Result<_>>()?;
    let stat = |xs: &[f64]| {
        let m = xs.iter().sum::<f64>() / xs.len() as f64;
        let v = xs.iter().map(|x| (x - m).powi(2)).sum::<f64>() / (xs.len().max(2) - 1) as f64;
        (m, v.sqrt())
    };
    println!("hands (J kg·m², k N·m/rad, c N·m·s/rad at the range midpoints):");
    for &s in &states {
        let h = mid(s);
        println!(
            "  {s:?}: J {:.3}, k {:.1}, c {:.3}",
            h.inertia_kgm2, h.stiffness_nm_per_rad, h.damping_nms_per_rad
        );
    }
    println!();
    println!("| c (mm) | hands | rim δ_sw (deg) | column torque T_c (N·m) | T_c per rim degree (N·m/°) |");
    println!("|---|---|---|---|---|");
    let mut k = 0;
    for &c in &clearances_mm {
        for &s in &states {
            let rs = &results[k..k + n_seeds as usize];
            k += n_seeds as usize;
            let (sw, sw_sd) = stat(&rs.iter().map(|r| r.0).collect::<Vec<_>>());
            let (tc, tc_sd) = stat(&rs.iter().map(|r| r.1).collect::<Vec<_>>());
            println!(
                "| {c} | {} | {sw:.3} ± {sw_sd:.3} | {tc:.3} ± {tc_sd:.3} | {:.2} |",
                format!("{s:?}").to_lowercase(),
                tc / sw
            );
        }
    }

    // The hands mixture per clearance: mean and variance of one event's amplitude.
    let mixture = |ci: usize, pick: fn(&(f64, f64)) -> f64| -> (f64, f64) {
        let (mut m, mut m2) = (0.0, 0.0);
        for (si, &s) in states.iter().enumerate() {
            let w = prior.range(s).probability;
            let k0 = (ci * states.len() + si) * n_seeds as usize;
            let xs: Vec<f64> = results[k0..k0 + n_seeds as usize]
                .iter()
                .map(pick)
                .collect();
            let (mu, sd) = stat(&xs);
            m += w * mu;
            m2 += w * (sd * sd + mu * mu);
        }
        (m, m2 - m * m)
    };
    println!();
    println!(
        "| clearances (mm) | rim: μ₁ → μ₂ (deg), σ over hands | rim d'₃₀ | torque: μ₁ → μ₂ (N·m), σ | torque d'₃₀ |"
    );
    println!("|---|---|---|---|---|");
    for i in 0..clearances_mm.len() - 1 {
        let j = i + 1;
        let d = |pick: fn(&(f64, f64)) -> f64| {
            let ((m1, v1), (m2, v2)) = (mixture(i, pick), mixture(j, pick));
            let dp = (m2 - m1) / ((v1 + v2) / 2.0 / 30.0).sqrt();
            (m1, m2, ((v1 + v2) / 2.0).sqrt(), dp)
        };
        let (r1, r2, rs, rd) = d(|r| r.0);
        let (t1, t2, ts, td) = d(|r| r.1);
        println!(
            "| {} → {} | {r1:.4} → {r2:.4}, {rs:.4} | {rd:.1} | {t1:.3} → {t2:.3}, {ts:.3} | {td:.1} |",
            clearances_mm[i], clearances_mm[j]
        );
    }
    Ok(())
}
