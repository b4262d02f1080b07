//! `shimmy calibrate`: builds the observer's response table from the shimmy model (issue 5
//! item 3). Policy lives in [`crate::observer::simulate`] (one event through the sensor,
//! detector and features) and [`crate::observer::table`] (the format); this module is the grid,
//! the parallel sweep and the statistics.

use std::path::PathBuf;
use std::time::Instant;

use anyhow::Context;
use rand::SeedableRng;
use rand_chacha::ChaCha8Rng;

use crate::analysis::sweep::{default_threads, par_map};
use crate::events::median_in_place;
use crate::model::VehicleParams;
use crate::observer::sensor::SensorModel;
use crate::observer::simulate::{perturb, simulate_event, NuisanceRanges, SimulatedEvent};
use crate::observer::table::{vehicle_hash, Cell, ResponseTable, FORMAT};
use crate::observer::ObserverConfig;

/// Build the response table the clearance estimator needs.
///
/// For every clearance × initial speed × deceleration of the grid, runs the shimmy model's
/// braking event (MODEL.md §6) with SEEDS independent draws of the nuisances — unbalance phases
/// and road noise (from the seed), unbalance magnitude (×0.5–2), ±10 % on the steering
/// stiffnesses and dampings — passes the steering-wheel angle through the sensor model (100 Hz,
/// 0.1 deg steps with a random sub-step offset, 0.01 deg noise; MODEL.md §8), runs the same
/// event detector and feature code as `shimmy estimate`, and stores the distribution of
/// (ln RMS, ln peak) of the band-passed angle per cell, plus a calibration of the true
/// steering-wheel amplitude against the measured noise-corrected RMS.
///
/// The table records a hash of the vehicle parameters; `shimmy estimate` refuses a table built
/// for other parameters. Runs on all cores (SHIMMY_THREADS to limit).
///
/// Example:
///   shimmy calibrate --vehicle vehicle.toml --out table.json
#[derive(clap::Args, Debug)]
#[command(verbatim_doc_comment)]
pub struct Args {
    /// Vehicle parameters (TOML, MODEL.md §9 keys); default: MODEL.md §9.
    #[arg(long, value_name = "FILE")]
    pub vehicle: Option<PathBuf>,

    /// Where to write the table (JSON).
    #[arg(long, value_name = "TABLE")]
    pub out: PathBuf,

    /// Number of clearances, log-spaced over --clearance-range.
    #[arg(long, default_value_t = 10)]
    pub clearances: usize,

    /// Clearance range (mm), "LOW,HIGH".
    #[arg(long, value_delimiter = ',', default_value = "0.02,0.5")]
    pub clearance_range: Vec<f64>,

    /// Initial speeds (km/h).
    #[arg(long, value_delimiter = ',', default_value = "30,45,60,80,100,120")]
    pub speeds: Vec<f64>,

    /// Decelerations (g).
    #[arg(long, value_delimiter = ',', default_value = "0.3,0.55,0.8")]
    pub decels: Vec<f64>,

    /// Seeds (nuisance draws) per cell.
    #[arg(long, default_value_t = 3)]
    pub seeds: u32,

    /// First seed (keep tuning, table and validation seeds apart).
    #[arg(long, default_value_t = 1_000_000)]
    pub seed_base: u64,

    /// Observer config (detector and feature settings must match `shimmy estimate`'s).
    #[arg(long, value_name = "FILE")]
    pub config: Option<PathBuf>,

    /// Threads (default: all cores, or SHIMMY_THREADS).
    #[arg(long)]
    pub threads: Option<usize>,
}

/// Smallest spread of ln(feature) stored in a cell.
pub const MIN_STD: f64 = 0.05;

/// Log-spaced grid.
pub fn log_grid(lo: f64, hi: f64, n: usize) -> Vec<f64> {
    if n < 2 {
        return vec![lo];
    }
    (0..n)
        .map(|i| (lo.ln() + (hi.ln() - lo.ln()) * i as f64 / (n - 1) as f64).exp())
        .collect()
}

/// Mean, std (floored) and correlation of paired samples.
fn cell_stats(z: &[[f64; 2]]) -> Cell {
    let n = z.len().max(1) as f64;
    let m = [
        z.iter().map(|p| p[0]).sum::<f64>() / n,
        z.iter().map(|p| p[1]).sum::<f64>() / n,
    ];
    let dof = (z.len() as f64 - 1.0).max(1.0);
    let var = |k: usize| z.iter().map(|p| (p[k] - m[k]).powi(2)).sum::<f64>() / dof;
    let cov = z.iter().map(|p| (p[0] - m[0]) * (p[1] - m[1])).sum::<f64>() / dof;
    let (s0, s1) = (var(0).sqrt(), var(1).sqrt());
    let corr = if s0 > 0.0 && s1 > 0.0 {
        (cov / (s0 * s1)).clamp(-0.95, 0.95)
    } else {
        0.0
    };
    Cell {
        mean: m,
        std: [s0.max(MIN_STD), s1.max(MIN_STD)],
        corr,
    }
}

/// Replaces each cell's spread and correlation by the pooled values over all cells of the
/// same clearance (`per_clearance` consecutive cells): with a few seeds per cell, one cell's
/// standard deviation is a poor estimate, while the spread in ln(feature) changes little with
/// speed and deceleration. Means stay per cell.
fn pool_spread(cells: &mut [Cell], per_clearance: usize) {
    for group in cells.chunks_mut(per_clearance.max(1)) {
        let n = group.len() as f64;
        let v0 = group.iter().map(|c| c.std[0].powi(2)).sum::<f64>() / n;
        let v1 = group.iter().map(|c| c.std[1].powi(2)).sum::<f64>() / n;
        let r = group.iter().map(|c| c.corr).sum::<f64>() / n;
        for c in group.iter_mut() {
            c.std = [v0.sqrt().max(MIN_STD), v1.sqrt().max(MIN_STD)];
            c.corr = r.clamp(-0.95, 0.95);
        }
    }
}

/// The amplitude calibration: bins of measured excess RMS (equal counts) → median true peak,
/// made non-decreasing.
fn amp_map(pairs: &mut [(f64, f64)], bins: usize) -> Vec<[f64; 2]> {
    pairs.sort_by(|a, b| a.0.total_cmp(&b.0));
    let n = pairs.len();
    let mut out: Vec<[f64; 2]> = Vec::new();
    if n == 0 {
        return out;
    }
    let bins = bins.clamp(1, n);
    for b in 0..bins {
        let (i0, i1) = (b * n / bins, ((b + 1) * n / bins).max(b * n / bins + 1));
        let mut xs: Vec<f64> = pairs[i0..i1].iter().map(|p| p.0).collect();
        let mut ys: Vec<f64> = pairs[i0..i1].iter().map(|p| p.1).collect();
        let x = median_in_place(&mut xs).unwrap_or(0.0);
        let y = median_in_place(&mut ys).unwrap_or(0.0);
        if let Some(last) = out.last() {
            if x <= last[0] {
                continue;
            }
            out.push([x, y.max(last[1])]);
        } else {
            out.push([x, y]);
        }
    }
    out
}

/// Builds the table (the work of `shimmy calibrate`), on `threads` threads.
#[allow(clippy::too_many_arguments)]
pub fn build_table(
    vehicle: &VehicleParams,
    clearance_mm: Vec<f64>,
    speed_kmh: Vec<f64>,
    decel_g: Vec<f64>,
    seeds: u32,
    seed_base: u64,
    cfg: &ObserverConfig,
    threads: usize,
) -> anyhow::Result<ResponseTable> {
    let sensor = SensorModel::default();
    let ranges = NuisanceRanges::default();
    let mut jobs = Vec::new();
    for (ic, &c) in clearance_mm.iter().enumerate() {
        for (iv, &v) in speed_kmh.iter().enumerate() {
            for (id, &d) in decel_g.iter().enumerate() {
                for s in 0..seeds {
                    let seed = seed_base
                        + (((ic * speed_kmh.len() + iv) * decel_g.len() + id) as u64)
                            * seeds as u64
                        + s as u64;
                    jobs.push((c, v, d, seed));
                }
            }
        }
    }
    let results: Vec<anyhow::Result<SimulatedEvent>> =
        par_map(&jobs, threads, |&(c, v, d, seed)| {
            let mut rng = ChaCha8Rng::seed_from_u64(seed);
            let p = perturb(vehicle, &ranges, &mut rng);
            simulate_event(&p, c * 1e-3, v / 3.6, d, seed, &sensor, cfg)
        });
    let per_cell = seeds as usize;
    let mut cells = Vec::with_capacity(jobs.len() / per_cell.max(1));
    let mut pairs = Vec::with_capacity(jobs.len());
    for (k, chunk) in results.chunks(per_cell).enumerate() {
        let mut z = Vec::with_capacity(per_cell);
        for (j, r) in chunk.iter().enumerate() {
            let (c, v, d, seed) = jobs[k * per_cell + j];
            let e = r
                .as_ref()
                .map_err(|e| anyhow::anyhow!("{e:#}"))
                .with_context(|| format!("simulating c = {c} mm, {v} km/h, {d} g, seed {seed}"))?;
            let f = &e.features;
            z.push(crate::observer::features::z(f.rms_deg, f.peak_deg));
            pairs.push((f.excess_rms_deg, e.true_peak_deg));
        }
        cells.push(cell_stats(&z));
    }
    pool_spread(&mut cells, speed_kmh.len() * decel_g.len());
    let amp = amp_map(&mut pairs, 24);
    let mut t = ResponseTable {
        format: FORMAT.into(),
        vehicle_hash: vehicle_hash(vehicle)?,
        sensor,
        clearance_mm,
        speed_kmh,
        decel_g,
        seeds,
        cells,
        amp_map: amp,
        provenance: format!(
            "shimmy calibrate {}; nuisances: unbalance x{:?}, stiffness/damping ±{:.0} %, seed_base {seed_base}",
            env!("CARGO_PKG_VERSION"),
            ranges.unbalance_factor,
            ranges.stiffness_damping_rel * 100.0
        ),
    };
    t.smooth();
    t.validate()?;
    Ok(t)
}

pub fn run(args: Args) -> anyhow::Result<()> {
    let vehicle = super::estimate::load_vehicle(args.vehicle.as_deref())?;
    let cfg = match &args.config {
        Some(p) => ObserverConfig::load(p)?,
        None => ObserverConfig::default(),
    };
    let [lo, hi] = args.clearance_range[..] else {
        anyhow::bail!("--clearance-range takes LOW,HIGH");
    };
    if !(lo > 0.0 && hi > lo) {
        anyhow::bail!("--clearance-range must satisfy 0 < LOW < HIGH");
    }
    let threads = args.threads.unwrap_or_else(default_threads);
    let t0 = Instant::now();
    let n_runs = args.clearances * args.speeds.len() * args.decels.len() * args.seeds as usize;
    eprintln!("shimmy calibrate: {n_runs} model runs on {threads} threads");
    let table = build_table(
        &vehicle,
        log_grid(lo, hi, args.clearances),
        args.speeds.clone(),
        args.decels.clone(),
        args.seeds,
        args.seed_base,
        &cfg,
        threads,
    )?;
    let json = serde_json::to_string(&table)?;
    std::fs::write(&args.out, &json)
        .with_context(|| format!("cannot write {}", args.out.display()))?;
    eprintln!(
        "shimmy calibrate: wrote {} ({} bytes, {} cells) in {:.1} s",
        args.out.display(),
        json.len(),
        table.cells.len(),
        t0.elapsed().as_secs_f64()
    );
    Ok(())
}
