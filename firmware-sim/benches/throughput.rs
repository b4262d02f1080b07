//! firmware-sim throughput: simulated seconds per second when writing a candump log (to an
//! in-memory sink, so the disk is not measured). Target (issue 4): ≥ 100× real time on one
//! core.
//!
//! Run (one core): `taskset -c 0 cargo bench -p firmware-sim --bench throughput`
//!
//! `model_worn_0p2mm` is the real thing: the shimmy model (MODEL.md, the scenario's default
//! integrator, `rk4_adaptive`, on the h = 1e-4 s grid with the default 1 ms control period)
//! driven through the bundled worn_0p2mm drive (24.5 s simulated),
//! with the ECUs and candump formatting. `bus_only` replaces the model by a point-mass plant:
//! the cost of the drive cycle, the ECU emulation (noise, DBC packing, counters, checksums) and
//! candump formatting alone.
//!
//! Before criterion runs, a table is printed with, per configuration, simulated seconds per CPU
//! second of this thread (independent of other load on the machine) and per wall second, over
//! a few whole runs: the default, every other model integrator (each at the default 1 ms control
//! period, and with `control_period_s = step_s`: demand and ECU sampling every model step, the
//! reference bookkeeping), and the scenario's `step_s` knob at 2e-4 s (MODEL.md §10: a few
//! percent from the reference; not the default).

use std::path::PathBuf;
use std::time::Instant;

use criterion::{criterion_group, criterion_main, Criterion};
use firmware_sim::bus::REFERENCE_DBC;
use firmware_sim::plant::{ModelPlant, Plant, PointMass};
use firmware_sim::{FirmwareSim, RunInfo, Scenario};
use shimmy::model::Integrator;

fn scenario() -> Scenario {
    let p = PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../config/scenarios/worn_0p2mm.toml");
    Scenario::load(&p).expect("bundled scenario")
}

/// Run to the end, writing the log into a reused buffer; returns simulated seconds.
fn run<P: Plant>(sim: &mut FirmwareSim<P>, buf: &mut Vec<u8>) -> f64 {
    buf.clear();
    for f in sim.by_ref() {
        shimmy::wire::candump::write_frame(buf, &f).unwrap();
    }
    sim.t_s()
}

/// CPU time of this thread (s): the exact per-thread clock shared with the model bench
/// (`shimmy::cli::simulate::thread_cpu_s`), so the rate does not depend on other load on the
/// machine (the /proc tick counter used before quantised a 0.05 s run to 10 ms steps).
fn thread_cpu_s() -> Option<f64> {
    let t = shimmy::cli::simulate::thread_cpu_s();
    (t > 0.0).then_some(t)
}

/// (simulated s per CPU s, simulated s per wall s) over `n` whole runs, set-up included.
fn rates<P: Plant>(
    n: usize,
    mut make: impl FnMut() -> FirmwareSim<P>,
    buf: &mut Vec<u8>,
) -> (Option<f64>, f64) {
    let c0 = thread_cpu_s();
    let w0 = Instant::now();
    let mut sim_s = 0.0;
    for _ in 0..n {
        sim_s += run(&mut make(), buf);
    }
    let wall = w0.elapsed().as_secs_f64();
    let cpu = c0
        .zip(thread_cpu_s())
        .map(|(a, b)| sim_s / (b - a).max(1e-6));
    (cpu, sim_s / wall)
}

fn model_sim(sc: &Scenario) -> FirmwareSim<ModelPlant> {
    let plant = ModelPlant::new(sc, None).unwrap();
    FirmwareSim::new(sc, plant, REFERENCE_DBC, RunInfo::default()).unwrap()
}

fn bench(c: &mut Criterion) {
    let sc = scenario();
    let mut buf = Vec::with_capacity(1 << 20);
    let point = || {
        let plant = PointMass::new(sc.drive.start_speed_kmh / 3.6, sc.step_s, 0.003, 7.0);
        FirmwareSim::new(&sc, plant, REFERENCE_DBC, RunInfo::default()).unwrap()
    };
    let sim_s = run(&mut point(), &mut buf);
    eprintln!(
        "scenario {} simulates {sim_s:.2} s per run ({} bytes of log)",
        sc.name,
        buf.len()
    );
    eprintln!("configuration | sim s per CPU s | sim s per wall s");
    let row = |name: String, (cpu, wall): (Option<f64>, f64)| {
        let cpu = cpu.map_or("n/a".to_string(), |r| format!("{r:.1}x"));
        eprintln!("{name} | {cpu} | {wall:.1}x");
    };
    let default = sc.integrator;
    row(
        format!("model, {default:?}, h = {} s (default)", sc.step_s),
        rates(3, || model_sim(&sc), &mut buf),
    );
    for integ in Integrator::ALL {
        let mut s = sc.clone();
        s.integrator = integ;
        if integ != default {
            row(
                format!("model, {integ:?}, h = {} s", s.step_s),
                rates(3, || model_sim(&s), &mut buf),
            );
        }
        s.control_period_s = Some(s.step_s);
        row(
            format!(
                "model, {integ:?}, h = {} s, control_period_s = step_s",
                s.step_s
            ),
            rates(3, || model_sim(&s), &mut buf),
        );
    }
    let mut coarse = sc.clone();
    coarse.step_s = 2e-4;
    row(
        format!("model, {default:?}, h = 2e-4 s (step_s knob)"),
        rates(3, || model_sim(&coarse), &mut buf),
    );
    row("bus_only (point mass)".into(), rates(20, point, &mut buf));

    let mut g = c.benchmark_group("firmware_sim");
    g.sample_size(10);
    g.bench_function("model_worn_0p2mm", |b| {
        b.iter(|| run(&mut model_sim(&sc), &mut buf))
    });
    g.bench_function("bus_only_worn_0p2mm", |b| {
        b.iter(|| run(&mut point(), &mut buf))
    });
    g.finish();
}

criterion_group!(benches, bench);
criterion_main!(benches);
