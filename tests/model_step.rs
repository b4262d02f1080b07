//! The stepping API firmware-sim relies on: `Simulator::step` allocates nothing (counted with a
//! global allocator), and an external longitudinal demand drives whole drive cycles.

use shimmy::model::{Integrator, Scenario, Simulator, VehicleParams};

// Counted per thread (tests/support/counting_alloc.rs): the harness runs the other tests of
// this file on other threads at the same time.
#[path = "support/counting_alloc.rs"]
mod counting_alloc;
use counting_alloc::allocations as allocs;

#[test]
fn step_and_outputs_do_not_allocate() {
    let p = VehicleParams::default();
    for integrator in Integrator::ALL {
        let sc = Scenario {
            integrator,
            ..Scenario::default()
        };
        let mut sim = Simulator::new(&p, &sc).unwrap();
        let before = allocs();
        let mut acc = 0.0;
        for k in 0..2_000 {
            // `advance` is where Rk4Adaptive merges free-flight steps (and saves/restores
            // the noise generator on a rejected step): it must not allocate either.
            if k % 2 == 0 {
                sim.advance(10);
            } else {
                for _ in 0..10 {
                    sim.step();
                }
            }
            acc += sim.outputs().contact_fx_n[0];
            if k == 1_200 {
                sim.set_decel_demand(3.0);
            }
        }
        if integrator == Integrator::Rk4Adaptive {
            let (merged, rejected) = sim.merge_stats();
            assert!(merged > 100 && rejected > 0, "{merged} {rejected}");
        }
        let after = allocs();
        assert!(acc.is_finite());
        assert_eq!(
            after - before,
            0,
            "{integrator:?}: allocations in the step loop"
        );
    }
}

#[test]
fn external_demand_drives_cruise_brake_and_acceleration() {
    let p = VehicleParams::default();
    let sc = Scenario {
        v0_mps: 20.0,
        ..Scenario::default()
    };
    let mut sim = Simulator::new(&p, &sc).unwrap();
    let steps = |sim: &mut Simulator, n: usize| {
        for _ in 0..n {
            sim.step();
        }
    };
    sim.set_decel_demand(0.0); // cruise: the §6 event must no longer apply
    steps(&mut sim, 10_000);
    assert!((sim.outputs().speed_mps - 20.0).abs() < 1e-9);
    sim.set_decel_demand(4.0); // brake 1 s at 4 m/s²
    steps(&mut sim, 10_000);
    let o = sim.outputs();
    assert!((o.speed_mps - 16.0).abs() < 1e-6, "{}", o.speed_mps);
    assert!(o.tire_fx_n[0] > 0.0 && o.decel_filtered_mps2 > 2.0);
    sim.set_decel_demand(-2.0); // accelerate 1 s (front-wheel drive: negative F_x)
    steps(&mut sim, 10_000);
    let o = sim.outputs();
    assert!((o.speed_mps - 18.0).abs() < 1e-6, "{}", o.speed_mps);
    assert!(o.tire_fx_n[0] < 0.0);
    sim.set_decel_demand(8.0); // brake to a standstill: fades, never reverses
    steps(&mut sim, 40_000);
    let v = sim.outputs().speed_mps;
    assert!((0.0..0.01).contains(&v), "{v}");
    assert!((sim.t() - 7.0).abs() < 1e-9);
}
