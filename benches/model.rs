//! Speed of the shimmy model (issue 3 "must show"): one 10 s braking event (MODEL.md §6 defaults:
//! dual clearance 0.1 mm, 55 km/h, 0.5 g, seed 0) at h = 1e-4 s, i.e. 10^5 RK4 steps, on one
//! core. Results and the command are in docs/BENCHMARKS.md ("Shimmy model").
//!
//! `rk4_spec`: MODEL.md §10/§5.3 as written (8 cold Newton steps of the slip inversion per
//! right-hand-side evaluation). `rk4_warm_slip`: the same RK4 with the Newton iteration
//! warm-started and stopped at convergence. `rk4_multirate`: RK4 on the same grid with the
//! tire forces evaluated once per step. `rk4_adaptive`: merged steps in free flight. Every
//! event is advanced in 1 ms chunks (`Simulator::advance(10)`, the 1 kHz output boundaries of
//! `run`), which only matters to `rk4_adaptive`. `run_1khz`: `shimmy::model::run`, i.e. the
//! specified scheme plus the 1 kHz output trace.

use criterion::{criterion_group, Criterion};
use shimmy::model::{run, Integrator, Scenario, Simulator, VehicleParams};
use std::hint::black_box;

fn event(integrator: Integrator) -> f64 {
    let p = VehicleParams::default();
    let sc = Scenario {
        integrator,
        ..Scenario::default()
    };
    let mut sim = Simulator::new(&p, &sc).expect("default scenario is valid");
    for _ in 0..10_000 {
        sim.advance(10);
    }
    sim.state()[0]
}

fn bench(c: &mut Criterion) {
    let mut g = c.benchmark_group("model_10s_event_h1e-4");
    g.sample_size(10);
    g.bench_function("rk4_spec", |b| {
        b.iter(|| black_box(event(black_box(Integrator::Rk4))))
    });
    for integ in &Integrator::ALL[1..] {
        g.bench_function(integ.name(), |b| {
            b.iter(|| black_box(event(black_box(*integ))))
        });
    }
    g.bench_function("run_1khz", |b| {
        b.iter(|| {
            let tr = run(&VehicleParams::default(), &Scenario::default()).unwrap();
            black_box(tr.samples.len())
        })
    });
    g.finish();
}

/// CPU seconds of this thread per 10 s event (median of 5), independent of the machine load
/// that inflates criterion's wall-clock figures on a shared machine.
fn cpu_report() {
    use shimmy::cli::simulate::thread_cpu_s;
    for integ in Integrator::ALL {
        let name = integ.name();
        let mut t: Vec<f64> = (0..5)
            .map(|_| {
                let t0 = thread_cpu_s();
                black_box(event(integ));
                thread_cpu_s() - t0
            })
            .collect();
        t.sort_by(|a, b| a.total_cmp(b));
        println!(
            "cpu-time {name}: median {:.1} ms per 10 s event (min {:.1} ms)",
            t[2] * 1e3,
            t[0] * 1e3
        );
    }
}

criterion_group!(benches, bench);

fn main() {
    cpu_report();
    benches();
    Criterion::default().configure_from_args().final_summary();
}
