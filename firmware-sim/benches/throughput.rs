//! firmware-sim throughput: simulated seconds per wall-clock second when writing a candump log
//! (to an in-memory sink, so the disk is not measured). Target (issue 4): ≥ 100× real time on
//! one core.
//!
//! Run: `cargo bench -p firmware-sim --bench throughput`
//!
//! `bus_only` uses a point-mass plant: the cost of the drive cycle, the ECU emulation (noise,
//! DBC packing, counters, checksums) and candump formatting alone.

use std::path::PathBuf;

use criterion::{criterion_group, criterion_main, Criterion};
use firmware_sim::bus::REFERENCE_DBC;
use firmware_sim::plant::{Plant, PointMass};
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
    let mut g = c.benchmark_group("firmware_sim");
    g.sample_size(10);
    g.bench_function("bus_only_worn_0p2mm", |b| {
        b.iter(|| run(&mut point(), &mut buf))
    });
    g.finish();
}

criterion_group!(benches, bench);
criterion_main!(benches);
