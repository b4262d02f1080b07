//! firmware-sim throughput: simulated seconds per wall-clock second when writing a candump log
//! (to an in-memory sink, so the disk is not measured). Target (issue 4): ≥ 100× real time on
//! one core.
//!
//! Run: `cargo bench -p firmware-sim --bench throughput`
//!
//! `model_worn_0p2mm` is the real thing: the shimmy model (MODEL.md, RK4 at the scenario's
//! h = 1e-4 s) driven through the bundled worn_0p2mm drive (29.8 s simulated), with the ECUs and
//! candump formatting. `bus_only` replaces the model by a point-mass plant: the cost of the
//! drive cycle, the ECU emulation (noise, DBC packing, counters, checksums) and candump
//! formatting alone.

use std::path::PathBuf;

use criterion::{criterion_group, criterion_main, Criterion};
use firmware_sim::bus::REFERENCE_DBC;
use firmware_sim::plant::{ModelPlant, Plant, PointMass};
use firmware_sim::{FirmwareSim, RunInfo, Scenario};

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

/// CPU time of this thread (s) from /proc/thread-self/stat (utime + stime, 100 ticks/s on
/// Linux), so the rate does not depend on other load on the machine. None elsewhere.
fn thread_cpu_s() -> Option<f64> {
    let stat = std::fs::read_to_string("/proc/thread-self/stat").ok()?;
    let rest = &stat[stat.rfind(')')? + 2..];
    let f: Vec<&str> = rest.split_whitespace().collect();
    let ticks: f64 = f.get(11)?.parse::<f64>().ok()? + f.get(12)?.parse::<f64>().ok()?;
    Some(ticks / 100.0)
}

/// Simulated seconds per CPU second over `n` full runs.
fn cpu_rate<P: Plant>(
    n: usize,
    mut make: impl FnMut() -> FirmwareSim<P>,
    buf: &mut Vec<u8>,
) -> Option<f64> {
    let c0 = thread_cpu_s()?;
    let mut sim_s = 0.0;
    for _ in 0..n {
        sim_s += run(&mut make(), buf);
    }
    let c1 = thread_cpu_s()?;
    Some(sim_s / (c1 - c0).max(0.01))
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
        "bus_only: scenario {} simulates {sim_s:.2} s per iteration ({} bytes of log)",
        sc.name,
        buf.len()
    );
    let model = || {
        let plant = ModelPlant::new(&sc, None).unwrap();
        FirmwareSim::new(&sc, plant, REFERENCE_DBC, RunInfo::default()).unwrap()
    };
    if let (Some(m), Some(p)) = (cpu_rate(3, model, &mut buf), cpu_rate(20, point, &mut buf)) {
        eprintln!(
            "simulated seconds per CPU second: model {m:.1}x real time, bus_only {p:.0}x real time"
        );
    }
    let mut g = c.benchmark_group("firmware_sim");
    g.sample_size(10);
    g.bench_function("model_worn_0p2mm", |b| {
        b.iter(|| run(&mut model(), &mut buf))
    });
    g.bench_function("bus_only_worn_0p2mm", |b| {
        b.iter(|| run(&mut point(), &mut buf))
    });
    g.finish();
}

criterion_group!(benches, bench);
criterion_main!(benches);
