//! The clearance observer's hot paths allocate nothing per frame (issue 5: "everything runs
//! without allocation per frame and within bounded memory on the gateway"), counted with a
//! global allocator wrapper:
//! * the estimator's update, summary and alert probabilities on the shipped tables (method
//!   "linear", both wheel-phase hypotheses; the reference angle table, and the RAV4 torque
//!   table whose law grids the unbalance) allocate nothing at all;
//! * the observer allocates nothing per frame outside braking events, and per braking event a
//!   fixed number of times that does not grow with the event's length in frames (4 on
//!   2026-12-02, for stops of 827 and 1692 samples).

use std::path::Path;

use shimmy::observer::estimator::{Estimator, EstimatorConfig};
use shimmy::observer::table::ResponseTable;
use shimmy::observer::{Observer, ObserverConfig};

#[path = "support/braking_stream.rs"]
mod braking_stream;
#[path = "support/counting_alloc.rs"]
mod counting_alloc;
use braking_stream::drive;
use counting_alloc::counted;

fn shipped_table() -> ResponseTable {
    load("config/vehicles/shimmy_reference/table.json")
}

fn load(path: &str) -> ResponseTable {
    ResponseTable::load(&Path::new(env!("CARGO_MANIFEST_DIR")).join(path))
        .unwrap_or_else(|e| panic!("the shipped table {path}: {e:#}"))
}

#[test]
fn estimator_updates_and_summaries_do_not_allocate() {
    for path in [
        "config/vehicles/shimmy_reference/table.json",
        "config/vehicles/toyota_rav4/table_torque.json",
    ] {
        let table = load(path);
        let cfg = EstimatorConfig::default();
        assert_eq!(cfg.method, "linear");
        assert_eq!(cfg.phase, "either");
        let mut est = Estimator::new(&table, cfg).unwrap();
        let ((), n) = counted(|| {
            for k in 0..30 {
                let v0 = 30.0 + 70.0 * (k as f64 * 0.37).fract();
                let decel = 0.3 + 0.5 * (k as f64 * 0.61).fract();
                est.update_event(
                    &table,
                    0.04 + 0.002 * k as f64,
                    0.15,
                    Some(0.03),
                    v0,
                    decel,
                    1000.0 * k as f64,
                );
                let s = est.summary();
                assert!(s.q05_mm <= s.median_mm && s.median_mm <= s.q95_mm);
                assert!((0.0..=1.0).contains(&est.prob_above(0.1)));
                let _ = est.phase_fixed_probability();
            }
        });
        assert_eq!(est.events_used(), 30, "{path}");
        assert_eq!(
            n, 0,
            "{path}: the estimator allocated {n} times over 30 events"
        );
    }
}

#[test]
fn the_observer_allocates_nothing_per_frame() {
    let mut obs = Observer::new(ObserverConfig::default(), Some(shipped_table())).unwrap();
    // Warm-up: the first events size the extractor's buffers (the longest event so far).
    let mut t = 0.0;
    for _ in 0..2 {
        let d = drive(t, 3.0, 100.0, 0.3, 1.0);
        t += 40.0;
        for s in &d {
            obs.push(s);
        }
    }
    assert_eq!(obs.events().len(), 2, "{:?}", obs.events());

    // Cruise only (no brake): nothing per frame.
    let cruise = drive(t, 20.0, 80.0, 0.0, 0.0);
    t += 40.0;
    let ((), n) = counted(|| {
        for s in &cruise {
            obs.push(s);
        }
    });
    assert_eq!(n, 0, "{} cruise frames, {n} allocations", cruise.len());

    // One short and one long stop (both shorter than the warm-up's): the allocations per event
    // do not grow with its frames.
    let mut per_event = Vec::new();
    for (v0, decel) in [(40.0, 0.75), (90.0, 0.35)] {
        let d = drive(t, 3.0, v0, decel, 1.0);
        t += 40.0;
        let before = obs.events().len();
        let ((), n) = counted(|| {
            for s in &d {
                obs.push(s);
            }
        });
        assert_eq!(obs.events().len(), before + 1, "one stop, one event");
        assert!(
            obs.events().last().unwrap().used,
            "{:?}",
            obs.events().last()
        );
        per_event.push((d.len(), n));
    }
    eprintln!("frames, allocations per event: {per_event:?}");
    let (short, long) = (per_event[0], per_event[1]);
    assert!(long.0 > 2 * short.0, "{per_event:?}");
    assert_eq!(
        short.1, long.1,
        "allocations per event (frames, allocations): {per_event:?}"
    );
    assert!(short.1 <= 8, "allocations per event: {per_event:?}");
}
