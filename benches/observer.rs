//! Cost of the clearance observer per braking event (issue 5: target under 20 ms on one core
//! once the response table is built): the detector over one event's samples, the feature
//! extraction (band-pass, peak, RMS, noise correction) and the posterior update, on the
//! shipped table (config/vehicles/shimmy_reference/table.json) with the default method "linear", the
//! update alone on the RAV4 torque table (whose law grids the unbalance too), and the
//! method "mixture"'s update on a synthetic table of 12 clearances x 40 nuisance vehicles x 6
//! speeds x 2 decelerations.
//!
//! Run: cargo bench --bench observer

use criterion::{criterion_group, criterion_main, Criterion};
use std::hint::black_box;

use shimmy::observer::estimator::{Estimator, EstimatorConfig};
use shimmy::observer::table::{Cell, ResponseTable};

#[path = "../tests/support/braking_stream.rs"]
mod braking_stream;
#[path = "../tests/support/synthetic_table.rs"]
mod synthetic_table;
use shimmy::observer::{Observer, ObserverConfig};
use synthetic_table::synthetic;

fn table() -> ResponseTable {
    let clearance_mm: Vec<f64> = (0..12)
        .map(|i| 0.02 * (30f64).powf(i as f64 / 11.0))
        .collect();
    let speed_kmh = vec![30.0, 42.0, 55.0, 70.0, 85.0, 100.0];
    let decel_g = vec![0.3, 0.8];
    let vehicles = 40;
    let mut cells = Vec::new();
    for &c in &clearance_mm {
        for m in 0..vehicles {
            for _ in &speed_kmh {
                for _ in &decel_g {
                    let r = (0.04f64.powi(2) + (0.25 * c * (1.0 + 0.05 * m as f64)).powi(2))
                        .sqrt()
                        .ln();
                    cells.push(Cell {
                        mean: [r, r + 0.8],
                        std: [0.15, 0.15],
                        corr: 0.7,
                        cruise: [r - 0.3, 0.2],
                    });
                }
            }
        }
    }
    synthetic(clearance_mm, speed_kmh, decel_g, vehicles, cells)
}

fn bench(c: &mut Criterion) {
    let shipped = ResponseTable::load(std::path::Path::new(
        "config/vehicles/shimmy_reference/table.json",
    ))
    .expect("the shipped table (run from the package root)");
    let t = &shipped;
    // One stop from 55 km/h at 0.5 g after 2 s of cruise, 1.5 s standing.
    let stream = braking_stream::drive(0.0, 2.0, 55.0, 0.5, 1.5);
    c.bench_function(
        "observer: one braking event end to end (detector+features+posterior, linear)",
        |b| {
            // The observer (and its copy of the table) is made outside the timed part.
            b.iter_batched(
                || Observer::new(ObserverConfig::default(), Some(t.clone())).unwrap(),
                |mut obs| {
                    for s in &stream {
                        obs.push(black_box(s));
                    }
                    obs.finish();
                    assert_eq!(obs.events().len(), 1);
                    black_box(obs.report().median_mm)
                },
                criterion::BatchSize::LargeInput,
            )
        },
    );
    update_bench(
        c,
        "observer: posterior update only, linear (45 clearances x 9 damping points; phase: 8 fixed + 16 per event)",
        t,
        EstimatorConfig::default(),
    );
    let torque = ResponseTable::load(std::path::Path::new(
        "config/vehicles/toyota_rav4/table_torque.json",
    ))
    .expect("the shipped RAV4 torque table (run from the package root)");
    update_bench(
        c,
        "observer: posterior update only, linear, RAV4 torque table (unbalance gridded: 45 clearances x 9 damping x 7 unbalance; phase: 8 fixed + 16 per event)",
        &torque,
        EstimatorConfig::default(),
    );
    update_bench(
        c,
        "observer: posterior update only, mixture (12 clearances x 40 vehicles)",
        &table(),
        EstimatorConfig::mixture(),
    );
}

/// One 57 km/h, 0.45 g event per iteration, 1 km after the previous one.
fn update_bench(c: &mut Criterion, name: &str, t: &ResponseTable, cfg: EstimatorConfig) {
    let mut est = Estimator::new(t, cfg).unwrap();
    let mut odo = 0.0;
    c.bench_function(name, |b| {
        b.iter(|| {
            odo += 1000.0;
            est.update_event(
                t,
                black_box(0.05),
                black_box(0.15),
                Some(0.03),
                57.0,
                0.45,
                odo,
            );
            black_box(est.quantile_mm(0.5))
        })
    });
}

criterion_group!(benches, bench);
criterion_main!(benches);
