//! The cost of a response table's model events (`shimmy calibrate`), one event at a time
//! against the shared pull-away of `run_model_grid`, measured in one run on the same grid
//! points: CPU seconds of this thread per model event, and the extra cost of measuring the same
//! runs through a second steering angle sensor. Results and the command are in
//! docs/BENCHMARKS.md ("Table build").
//!
//! The grid points: the table's 29 speeds (30-100 km/h) x 3 decelerations at 6 clearances
//! (0.02-0.6 mm), each clearance on another drawn vehicle; one event at a time samples every
//! fifth speed of each clearance (all decelerations), the grid runs them all.

use shimmy::cli::calibrate::nuisance_vehicle;
use shimmy::cli::simulate::thread_cpu_s;
use shimmy::model::VehicleParams;
use shimmy::observer::sensor::SensorModel;
use shimmy::observer::simulate::{
    measure_run, run_model_grid, simulate_event, EventShape, NuisanceRanges,
};
use shimmy::observer::ObserverConfig;

fn main() {
    let p0 = VehicleParams::default();
    let cfg = ObserverConfig::default();
    let reference = SensorModel::default();
    let rav4 = SensorModel {
        rate_hz: 82.9,
        ..reference
    };
    let speeds: Vec<f64> = (0..29).map(|k| (30.0 + 2.5 * k as f64) / 3.6).collect();
    let decels = [0.3, 0.55, 0.8];
    let clearances = [0.02, 0.05, 0.1, 0.2, 0.4, 0.6];
    let (mut cpu_one, mut n_one) = (0.0, 0usize);
    let (mut cpu_grid, mut cpu_second, mut n_grid) = (0.0, 0.0, 0usize);
    let (mut periods, mut periods_alone) = (0u64, 0usize);
    for (ic, &c) in clearances.iter().enumerate() {
        let p = nuisance_vehicle(&p0, &NuisanceRanges::default(), 4_000_000, ic as u32);
        let seeds: Vec<u64> = (0..29).map(|k| 7_000_000 + 100 * ic as u64 + k).collect();
        let t0 = thread_cpu_s();
        for (iv, &v) in speeds.iter().enumerate().skip(ic % 5).step_by(5) {
            for &d in &decels {
                simulate_event(
                    &p,
                    c * 1e-3,
                    v,
                    d,
                    seeds[iv],
                    EventShape::DRIVE,
                    &reference,
                    &cfg,
                )
                .expect("model event");
                n_one += 1;
            }
        }
        cpu_one += thread_cpu_s() - t0;
        let t0 = thread_cpu_s();
        let grid = run_model_grid(
            &p,
            c * 1e-3,
            &speeds,
            &decels,
            &seeds,
            EventShape::DRIVE,
            &cfg,
            None,
        )
        .expect("model runs");
        for (iv, by_decel) in grid.runs.iter().enumerate() {
            for (id, run) in by_decel.iter().enumerate() {
                measure_run(run, &reference, &cfg, seeds[iv] + id as u64).expect("measured");
                n_grid += 1;
            }
        }
        cpu_grid += thread_cpu_s() - t0;
        let t0 = thread_cpu_s();
        for (iv, by_decel) in grid.runs.iter().enumerate() {
            for (id, run) in by_decel.iter().enumerate() {
                measure_run(run, &rav4, &cfg, seeds[iv] + id as u64).expect("measured");
            }
        }
        cpu_second += thread_cpu_s() - t0;
        periods += grid.control_periods;
        periods_alone += grid
            .runs
            .iter()
            .flatten()
            .map(|r| r.sw_rad.len())
            .sum::<usize>();
    }
    let one = cpu_one / n_one as f64;
    let grid = cpu_grid / n_grid as f64;
    let second = cpu_second / n_grid as f64;
    println!("model events: {n_one} one at a time, {n_grid} on the grid");
    println!(
        "CPU per event, one at a time:            {:.1} ms",
        one * 1e3
    );
    println!(
        "CPU per event, shared pull-away (grid):  {:.1} ms",
        grid * 1e3
    );
    println!("ratio:                                   {:.2}", one / grid);
    println!(
        "CPU per event, a second sensor:          {:.2} ms",
        second * 1e3
    );
    println!(
        "model time (1 ms control periods): {periods} on the grid, {periods_alone} if each event ran alone ({:.2}x)",
        periods_alone as f64 / periods as f64
    );
}
