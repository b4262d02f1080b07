//! `shimmy calibrate`: builds the observer's response table ([`crate::observer::table`]) from
//! the shimmy model. Policy lives in [`crate::observer::simulate`] (one event through the sensor,
//! detector and features) and [`crate::observer::table`] (the format); this module is the grid,
//! the parallel sweep and the statistics.

use std::path::{Path, PathBuf};
use std::time::Instant;

use anyhow::Context;
use rand::SeedableRng;
use rand_chacha::ChaCha8Rng;
use serde::{Deserialize, Serialize};

use crate::analysis::sweep::default_threads;
use crate::events::median_in_place;
use crate::model::VehicleParams;
use crate::observer::emulate::{coords, draw_coords, emulate_cells, RawEvent, N_COORDS};
use crate::observer::linear::{parse_terms, torque_terms, Term, DEFAULT_TERMS};
use crate::observer::sensor::SensorModel;
use crate::observer::simulate::{perturb_vehicle, EventShape, NuisanceRanges};
use crate::observer::table::{vehicle_hash, Cell, ResponseTable, FORMAT};
use crate::observer::ObserverConfig;
use crate::profile::Profile;

pub mod work;

/// Build the response tables the clearance estimator needs, for vehicle profiles or a custom
/// vehicle.
///
/// Usually: `shimmy calibrate --profile toyota_rav4` (or `--profile all`) builds the table of
/// each profile named (config/vehicles/<name>/table.json) for its chassis, nuisance prior and
/// steering angle sensor. Profiles that share a chassis and prior share one set of model runs:
/// the model's output does not depend on the sensor, so each run is measured through every
/// sensor those profiles have.
///
/// What a table holds: VEHICLES nuisance vehicles drawn from the chassis's prior (default ±10 %
/// on each steering stiffness and damping k_s, c_s, k_t, k_g, c_g; unbalance ×0.5–2,
/// log-uniform; road noise ×0.7–1.4), each simulated at every clearance × initial speed ×
/// deceleration of the grid the way a vehicle on the road sees it (--shape drive: firmware-sim's
/// driver pulls away from a stop at 0.35 g, holds the speed 1.5 s, brakes to a stop; --shape
/// single: MODEL.md §6's event from a kick). One pull-away per vehicle and clearance serves
/// every speed, and each speed's run branches at the brake onset into every deceleration
/// (src/observer/simulate.rs, `run_model_grid`). The steering-wheel angle goes through the
/// sensor model (rate, step with a random sub-step offset, white noise, the driver's slow lane
/// keeping; MODEL.md §8), then through the same event detector and feature code as `shimmy
/// estimate`. From these events the table fits each feature per clearance and speed as a
/// function of the deceleration and the seven nuisance coordinates, nonlinear in the kingpin
/// damping, with its event scatter and per-vehicle misfit (src/observer/linear.rs), and
/// calibrates the true steering-wheel amplitude against the measured noise-corrected RMS (the
/// shimmy_55kmh alert).
///
/// Long builds: a progress bar with an ETA on a terminal, a progress line every 30 s otherwise
/// (SHIMMY_PROGRESS_EVERY_S to change). Every finished job (one vehicle at one clearance) is
/// saved in the work directory; killed and run again with the same arguments, the build
/// resumes there and writes the same table, byte for byte. The work directory is removed after
/// a successful build unless --keep-work is given.
///
/// The table records the chassis's hash, the prior and the sensor; `shimmy estimate` refuses a
/// table built for others. Runs on all cores (SHIMMY_THREADS or --threads to limit). Model
/// events per chassis: CLEARANCES × VEHICLES × speeds × decels × SEEDS.
///
/// Examples:
///   shimmy calibrate --profile all
///   shimmy calibrate --profile toyota_rav4 --threads 2
///   shimmy calibrate --vehicle vehicle.toml --sensor-rate-hz 50 --out table.json
#[derive(clap::Args, Debug)]
#[command(verbatim_doc_comment)]
pub struct Args {
    /// Vehicle profiles to build the tables of (config/vehicles/<NAME>; "all" for every
    /// profile found): each table is written to the file its profile.toml names. Repeat or
    /// separate with commas.
    #[arg(long, value_name = "NAME", value_delimiter = ',', conflicts_with_all = ["vehicle", "out", "refit", "events_in", "events_out", "exact_vehicle", "emulate", "signal"])]
    pub profile: Vec<String>,

    /// Vehicle parameters (TOML, MODEL.md §9 keys) of a custom build; default: MODEL.md §9.
    #[arg(long, value_name = "FILE")]
    pub vehicle: Option<PathBuf>,

    /// Where to write the table of a custom build (JSON); required without --profile.
    #[arg(long, value_name = "TABLE", required_unless_present = "profile")]
    pub out: Option<PathBuf>,

    /// Where finished jobs are kept so that a killed build can resume: in DIR/<hash>, the hash
    /// naming the chassis, grid and sensors (default: `.calibrate-<hash>` beside the first
    /// table written).
    #[arg(long, value_name = "DIR")]
    pub work_dir: Option<PathBuf>,

    /// Keep the work directory after a successful build.
    #[arg(long)]
    pub keep_work: bool,

    /// No progress output.
    #[arg(long)]
    pub quiet: bool,

    /// Number of clearances, log-spaced over --clearance-range.
    #[arg(long, default_value_t = 12)]
    pub clearances: usize,

    /// Clearance range (mm), "LOW,HIGH".
    #[arg(long, value_delimiter = ',', default_value = "0.02,0.6")]
    pub clearance_range: Vec<f64>,

    /// Nuisance vehicles drawn from the prior (the same ones at every clearance).
    #[arg(long, default_value_t = DEFAULT_VEHICLES)]
    pub vehicles: u32,

    /// Initial speeds (km/h). Events outside are predicted from the nearest speed. The
    /// unbalance response has narrow resonances (near 45 km/h the wheel turns at the steering
    /// mode's frequency), hence the 2.5 km/h steps.
    #[arg(
        long,
        value_delimiter = ',',
        default_value = "30,32.5,35,37.5,40,42.5,45,47.5,50,52.5,55,57.5,60,62.5,65,67.5,70,72.5,\
                         75,77.5,80,82.5,85,87.5,90,92.5,95,97.5,100"
    )]
    pub speeds: Vec<f64>,

    /// Decelerations (g). The nuisance model is linear in the deceleration (its term `d`), so
    /// the two ends of the detector's validity range pin it best; a third, middle one was
    /// measured to change no held-out score (docs/ACCURACY.md) and costs a third more.
    #[arg(long, value_delimiter = ',', default_value = "0.3,0.8")]
    pub decels: Vec<f64>,

    /// Independent replicates (pull-aways with their own unbalance phases and road noise) per
    /// vehicle and cell. The decelerations of one speed share their pre-brake history, so a
    /// table whose cells describe single vehicles (few vehicles, --per-vehicle) needs 2 or more
    /// to measure one vehicle's event scatter.
    #[arg(long, default_value_t = 1)]
    pub seeds: u32,

    /// How each event starts: drive (cruise first, as on the road) or single (MODEL.md §6).
    #[arg(long, default_value = "drive", value_parser = ["drive", "single"])]
    pub shape: String,

    /// First seed (keep tuning, table and validation seeds apart).
    #[arg(long, default_value_t = 4_000_000)]
    pub seed_base: u64,

    /// Observer config (detector and feature settings must match `shimmy estimate`'s).
    #[arg(long, value_name = "FILE")]
    pub config: Option<PathBuf>,

    /// Threads (default: all cores, or SHIMMY_THREADS).
    #[arg(long)]
    pub threads: Option<usize>,

    /// Which steering signal the table describes: `angle` (the steering-wheel angle) or
    /// `torque` (the EPS torsion-bar torque, MODEL.md §15; the vehicle needs its [column]
    /// enabled). A torque table goes beside a profile's angle table (`torque_table` in its
    /// profile.toml); the observer then estimates from the torque where the bus carries it.
    #[arg(long, default_value = "angle", value_parser = ["angle", "torque"])]
    pub signal: String,

    /// The vehicle's steering sensor: sample rate (Hz; default 100 for the angle, 50 for the
    /// torque). The table predicts what this sensor reports (MODEL.md §8,
    /// src/observer/sensor.rs) and `shimmy estimate` does not use events measured at another
    /// rate.
    #[arg(long, value_name = "HZ")]
    pub sensor_rate_hz: Option<f64>,

    /// The steering sensor's quantisation step (deg, or N·m for the torque; default 0.1 deg,
    /// 0.01 N·m): the signal's scale factor in the DBC (0.1 on the reference bus). Events with
    /// another step are not used either.
    #[arg(long, value_name = "DEG")]
    pub sensor_step_deg: Option<f64>,

    /// White noise of the steering sensor before quantisation (deg RMS, or N·m for the torque;
    /// default 0.01 deg, 0.02 N·m).
    #[arg(long, value_name = "DEG")]
    pub sensor_noise_deg: Option<f64>,

    /// No model runs: read this table (built by an earlier `shimmy calibrate` with per-vehicle
    /// means) and re-fit its cell means with the additive vehicle model (see --per-vehicle).
    #[arg(long, value_name = "TABLE")]
    pub refit: Option<PathBuf>,

    /// Keep each nuisance vehicle's own mean per cell (noisy with few events per cell) instead of
    /// the additive vehicle model: mean(c, vehicle, speed) = nominal(c, speed) + offset(c,
    /// vehicle), whose vehicle × speed remainder is added to the event spread.
    #[arg(long)]
    pub per_vehicle: bool,

    /// Emulated nuisance vehicles (0 = off): fit each feature's dependence on the drawn
    /// vehicles' nuisance parameters (linear regression per clearance and speed, see
    /// src/observer/emulate.rs) and write N new vehicles drawn from the same prior with the
    /// fit's predictions as their means and the fit's residual as the event spread. The table
    /// then has N vehicles. Needs VEHICLES × decels × SEEDS above 9 per clearance and speed.
    #[arg(long, default_value_t = 0, value_name = "N", conflicts_with_all = ["refit", "per_vehicle"])]
    pub emulate: u32,

    /// Draw each table vehicle's brake discs: each front disc's torque variation ε uniform in
    /// LOW..HIGH (relative to the brake force; a disc thickness variation, MODEL.md §14) with
    /// its thickest point anywhere on the wheel. For a `[[chassis.variants]]` table of cars
    /// with uneven discs (the variant's `brake_torque_variation_rel`, on a chassis with a
    /// scrub radius: without one the rack feels nothing); a profile's own tables are built on
    /// even discs. Recorded in the table's prior.
    #[arg(long, value_delimiter = ',', value_name = "LOW,HIGH", conflicts_with_all = ["exact_vehicle", "refit"])]
    pub brake_torque_variation_rel: Option<Vec<f64>>,

    /// A table for exactly the --vehicle given: no nuisance spread (every drawn vehicle is the
    /// vehicle itself), so only the event-to-event randomness remains. For diagnosis: with
    /// --vehicles 1 --seeds 4 --per-vehicle it is the "oracle" of docs/ACCURACY.md, what the
    /// estimator could do if it knew the vehicle's stiffnesses, dampings, unbalance and road
    /// noise.
    #[arg(long, conflicts_with = "refit")]
    pub exact_vehicle: bool,

    /// Also write every simulated event (grid position, seed, features, unbalance phase
    /// difference) to this JSON file, so that the table can be re-fitted later with
    /// --events-in without running the model again.
    #[arg(long, value_name = "FILE", conflicts_with_all = ["refit", "events_in"])]
    pub events_out: Option<PathBuf>,

    /// No model runs: build the table from the events an earlier `--events-out` wrote. The
    /// vehicle, grid, sampling options and detector settings must be the same as then (the
    /// file records them and a mismatch is refused).
    #[arg(long, value_name = "FILE", conflicts_with = "refit")]
    pub events_in: Option<PathBuf>,

    /// Terms of the nuisance model (comma-separated monomials of d, the deceleration; x0-x6, the
    /// nuisance coordinates k_s, c_s, k_t, k_g, c_g, unbalance, road noise; x7-x9 the §15
    /// column's J_sw, k_tb, c_tb; u, the cosine of the wheels' unbalance phase difference), e.g.
    /// "1,d,x0,x1,x1^2,u,x5*u". The first must be "1". Default with `--signal torque`: these
    /// and "x7,x8,x9,x1*x8,x5^2". See src/observer/linear.rs.
    #[arg(long, default_value = DEFAULT_TERMS, value_name = "TERMS")]
    pub terms: String,

    /// Keep the per-vehicle cells of this many drawn vehicles for the estimator method
    /// "mixture" (0: none, the table then serves method "linear" only). They make the table
    /// file grow with vehicles × speeds. Tables without the nuisance model (fewer drawn vehicles
    /// than its terms, --exact-vehicle, --emulate) keep all their cells.
    #[arg(long, default_value_t = 0, value_name = "N")]
    pub mixture_vehicles: u32,
}

/// Nuisance vehicles of a default build.
pub const DEFAULT_VEHICLES: u32 = 60;

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

/// Mean of paired samples.
fn mean2(z: &[[f64; 2]]) -> [f64; 2] {
    let n = z.len().max(1) as f64;
    [
        z.iter().map(|p| p[0]).sum::<f64>() / n,
        z.iter().map(|p| p[1]).sum::<f64>() / n,
    ]
}

/// Event-to-event spread of one vehicle, pooled over all cells of one clearance: the residuals
/// of the events about their (smoothed) cell means, with `groups` means fitted, widened by
/// `sqrt(1 + 1/per_group)` for the error of a cell mean estimated from `per_group` events (the
/// predictive spread of a new event). Returns (std, corr), std floored at [`MIN_STD`].
fn pooled_spread(res: &[[f64; 2]], groups: usize, per_group: usize) -> ([f64; 2], f64) {
    let dof = pooled_dof(res.len(), groups);
    let v0 = res.iter().map(|r| r[0] * r[0]).sum::<f64>() / dof;
    let v1 = res.iter().map(|r| r[1] * r[1]).sum::<f64>() / dof;
    let c = res.iter().map(|r| r[0] * r[1]).sum::<f64>() / dof;
    let corr = if v0 > 0.0 && v1 > 0.0 {
        (c / (v0 * v1).sqrt()).clamp(-0.95, 0.95)
    } else {
        0.0
    };
    (
        [predictive_std(v0, per_group), predictive_std(v1, per_group)],
        corr,
    )
}

/// [`pooled_spread`] of one feature (the cruise statistic, independent of the other two).
fn pooled_std(res: &[f64], groups: usize, per_group: usize) -> f64 {
    let v = res.iter().map(|r| r * r).sum::<f64>() / pooled_dof(res.len(), groups);
    predictive_std(v, per_group)
}

/// Degrees of freedom of `n` residuals about `groups` fitted means.
fn pooled_dof(n: usize, groups: usize) -> f64 {
    (n as f64 - groups as f64).max(1.0)
}

/// The predictive spread of a new event from the residual variance `v` about cell means of
/// `per_group` events, floored at [`MIN_STD`].
fn predictive_std(v: f64, per_group: usize) -> f64 {
    let k = (1.0 + 1.0 / per_group.max(1) as f64).sqrt();
    (v.sqrt() * k).max(MIN_STD)
}

/// Re-fits the cell means of `t` (already averaged over deceleration) with the additive vehicle
/// model, per clearance and feature: mean(m, v) = nominal(v) + offset(m), nominal the mean over
/// the nuisance vehicles, offset the vehicle's mean deviation over the speeds. Each vehicle's
/// level then rests on all its events (nv · per_cell of them) instead of the per_cell events of
/// one cell. What the fit leaves (the vehicle × speed interaction, less the cells' own sampling
/// noise) is added to the event spread, together with the fit's sampling error. `per_cell` is
/// the number of events behind each (vehicle, speed) mean; the stored spreads are taken as
/// σ·sqrt(1 + 1/per_cell), as [`pooled_spread`] writes them. Then isotonic in clearance again.
pub fn fit_additive(t: &mut ResponseTable, per_cell: usize) {
    let (nc, nm, nv, nd) = (
        t.clearance_mm.len(),
        t.n_vehicles(),
        t.speed_kmh.len(),
        t.decel_g.len(),
    );
    if nm < 2 || nv < 2 {
        return;
    }
    let ne = per_cell.max(1) as f64;
    let idx = |ic: usize, im: usize, iv: usize, id: usize| ((ic * nm + im) * nv + iv) * nd + id;
    for ic in 0..nc {
        for k in 0..t.n_features() {
            let m = |im: usize, iv: usize| t.cells[idx(ic, im, iv, 0)].feat_mean(k);
            let nominal: Vec<f64> = (0..nv)
                .map(|iv| (0..nm).map(|im| m(im, iv)).sum::<f64>() / nm as f64)
                .collect();
            let offset: Vec<f64> = (0..nm)
                .map(|im| (0..nv).map(|iv| m(im, iv) - nominal[iv]).sum::<f64>() / nv as f64)
                .collect();
            let mut r2 = 0.0;
            for im in 0..nm {
                for (iv, nom) in nominal.iter().enumerate() {
                    r2 += (m(im, iv) - nom - offset[im]).powi(2);
                }
            }
            let resid_var = r2 / ((nm - 1) * (nv - 1)) as f64;
            let s = t.cells[idx(ic, 0, 0, 0)].feat_std(k);
            let within_var = s * s / (1.0 + 1.0 / ne);
            let interaction = (resid_var - within_var / ne).max(0.0);
            let pred = (within_var * (1.0 + 1.0 / (nm as f64 * ne) + 1.0 / (nv as f64 * ne))
                + interaction)
                .sqrt()
                .max(MIN_STD);
            for im in 0..nm {
                for (iv, nom) in nominal.iter().enumerate() {
                    for id in 0..nd {
                        t.cells[idx(ic, im, iv, id)].set_feat(k, nom + offset[im], pred);
                    }
                }
            }
        }
    }
    t.smooth();
}

/// Replaces every cell's spread and correlation by their pooled values over the whole table
/// (root mean square of the spreads, mean correlation). The event-to-event spread estimated
/// per clearance is noisy, and the likelihood's normalising term turns spread differences
/// between clearances into evidence: over 30 events a clearance whose estimated spread happens
/// to be a factor 2 smaller gains ~20 nats whatever the data. One spread leaves the
/// identification to the means.
pub fn pool_spread_globally(t: &mut ResponseTable) {
    let n = t.cells.len().max(1) as f64;
    let v0 = t.cells.iter().map(|c| c.std[0].powi(2)).sum::<f64>() / n;
    let v1 = t.cells.iter().map(|c| c.std[1].powi(2)).sum::<f64>() / n;
    let vc = t.cells.iter().map(|c| c.cruise[1].powi(2)).sum::<f64>() / n;
    let r = t.cells.iter().map(|c| c.corr).sum::<f64>() / n;
    let cruise = t.cruise;
    for c in &mut t.cells {
        c.std = [v0.sqrt().max(MIN_STD), v1.sqrt().max(MIN_STD)];
        c.corr = r.clamp(-0.95, 0.95);
        if cruise {
            c.cruise[1] = vc.sqrt().max(MIN_STD);
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

/// The grid and sampling of a table build.
#[derive(Clone, Debug)]
pub struct Grid {
    pub clearance_mm: Vec<f64>,
    pub speed_kmh: Vec<f64>,
    pub decel_g: Vec<f64>,
    /// Nuisance vehicles M.
    pub vehicles: u32,
    /// Events per vehicle and cell.
    pub seeds: u32,
    pub shape: EventShape,
    pub seed_base: u64,
    /// Fit the additive vehicle model ([`fit_additive`]) to the cell means.
    pub additive: bool,
    /// Emulated vehicles written instead of the drawn ones (0 = off, [`crate::observer::emulate`]).
    pub emulate: u32,
    /// Nuisance prior: [`NuisanceRanges::default`], or [`NuisanceRanges::NONE`] for
    /// `--exact-vehicle`.
    pub ranges: NuisanceRanges,
    /// Terms of the nuisance model ([`crate::observer::linear`]).
    pub terms: Vec<Term>,
    /// Drawn vehicles whose cells the table keeps for method "mixture" (see
    /// [`keep_mixture_vehicles`]).
    pub mixture_vehicles: u32,
    /// The steering angle sensor the table's events are measured through.
    pub sensor: SensorModel,
}

impl Grid {
    pub fn n_events(&self) -> usize {
        self.clearance_mm.len()
            * self.vehicles as usize
            * self.speed_kmh.len()
            * self.decel_g.len()
            * self.seeds as usize
    }
}

/// The nuisance vehicle `im` of a table built from `seed_base` (the same at every clearance).
pub fn nuisance_vehicle(
    nominal: &VehicleParams,
    ranges: &NuisanceRanges,
    seed_base: u64,
    im: u32,
) -> VehicleParams {
    let mut rng = ChaCha8Rng::seed_from_u64(seed_base.wrapping_add(im as u64));
    rng.set_stream(11);
    perturb_vehicle(nominal, ranges, &mut rng)
}

/// One table event as simulated: its grid position and statistics ([`RawEvent`]), its seed and
/// the amplitude-calibration pair. What `--events-out` writes and `--events-in` reads back.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub struct TableEvent {
    pub raw: RawEvent,
    pub seed: u64,
    /// Measured noise-corrected excess RMS (deg).
    pub excess_rms_deg: f64,
    /// MODEL.md §11 steering-wheel amplitude of the continuous δ_sw (deg).
    pub true_peak_deg: f64,
}

/// Format tag of an events file.
pub const EVENTS_FORMAT: &str = "shimmy calibrate events v1";

/// A table build's simulated events with what they were simulated for.
#[derive(Serialize, Deserialize)]
struct EventsFile {
    format: String,
    vehicle_hash: String,
    /// [`grid_fingerprint`] of the build.
    grid: String,
    events: Vec<TableEvent>,
}

/// How the model events of a build are generated (`run_model_grid`: one pull-away per drawn
/// vehicle and clearance, branching into every speed and deceleration). Events files and work
/// directories of other generators are refused.
const GENERATOR: &str = "pull-away tree v2";

/// Everything that decides the model runs of one job (one drawn vehicle at one clearance): the
/// generator, the grid's axes, its shape and seeds, the nuisance prior and the detector
/// settings; not how many vehicles or replicates a build draws (a job's events do not depend
/// on them, [`work::event_seed`]), nor the sensor, nor how the events are fitted afterwards.
/// A work directory is kept per model fingerprint and sensor set.
fn model_fingerprint(grid: &Grid, cfg: &ObserverConfig) -> anyhow::Result<String> {
    Ok(format!(
        "{GENERATOR}: clearance_mm {:?}, speed_kmh {:?}, decel_g {:?}, shape {:?}, seed_base {}, \
         ranges {:?}; events {}",
        grid.clearance_mm,
        grid.speed_kmh,
        grid.decel_g,
        grid.shape,
        grid.seed_base,
        ranges_fingerprint(&grid.ranges),
        serde_json::to_string(&cfg.events)?
    ))
}

/// The prior as the fingerprint names it: without brake discs, as it read before they could
/// be drawn (so earlier work directories and events files still resume).
fn ranges_fingerprint(r: &NuisanceRanges) -> String {
    let mut s = format!(
        "NuisanceRanges {{ stiffness_damping_rel: {:?}, unbalance_factor: {:?}, \
         road_noise_factor: {:?}, column: {:?}, hands: {:?}",
        r.stiffness_damping_rel, r.unbalance_factor, r.road_noise_factor, r.column, r.hands
    );
    if let Some(b) = r.brake_torque_variation_rel {
        s += &format!(", brake_torque_variation_rel: {b:?}");
    }
    s + " }"
}

/// [`model_fingerprint`], the vehicles and replicates, and the sensor the events were measured
/// through: what an events file records.
fn grid_fingerprint(grid: &Grid, cfg: &ObserverConfig) -> anyhow::Result<String> {
    Ok(model_fingerprint(grid, cfg)?
        + &format!(
            "; vehicles {}, seeds {}; sensor {:?}",
            grid.vehicles, grid.seeds, grid.sensor
        ))
}

/// The nuisance vehicles of a build.
fn drawn_vehicles(vehicle: &VehicleParams, grid: &Grid) -> Vec<VehicleParams> {
    (0..grid.vehicles)
        .map(|im| nuisance_vehicle(vehicle, &grid.ranges, grid.seed_base, im))
        .collect()
}

/// Runs the model for every event of `grid` on `threads` threads and measures them through
/// `grid.sensor` (the expensive part of `shimmy calibrate`; no work directory, no progress).
pub fn simulate_table_events(
    vehicle: &VehicleParams,
    grid: &Grid,
    cfg: &ObserverConfig,
    threads: usize,
) -> anyhow::Result<Vec<TableEvent>> {
    let vehicles = drawn_vehicles(vehicle, grid);
    let mut per_sensor = work::run_all(
        &vehicles,
        &vehicle_hash(vehicle)?,
        grid,
        &model_fingerprint(grid, cfg)?,
        cfg,
        &[grid.sensor],
        threads,
        None,
        true,
    )?;
    Ok(per_sensor.remove(0))
}

/// Writes a build's events (`--events-out`).
pub fn save_events(
    path: &std::path::Path,
    vehicle: &VehicleParams,
    grid: &Grid,
    cfg: &ObserverConfig,
    events: &[TableEvent],
) -> anyhow::Result<()> {
    let file = EventsFile {
        format: EVENTS_FORMAT.into(),
        vehicle_hash: vehicle_hash(vehicle)?,
        grid: grid_fingerprint(grid, cfg)?,
        events: events.to_vec(),
    };
    std::fs::write(path, serde_json::to_string(&file)?)
        .with_context(|| format!("cannot write {}", path.display()))
}

/// Reads a build's events (`--events-in`), refusing events simulated for another vehicle, grid
/// or detector.
pub fn load_events(
    path: &std::path::Path,
    vehicle: &VehicleParams,
    grid: &Grid,
    cfg: &ObserverConfig,
) -> anyhow::Result<Vec<TableEvent>> {
    let text =
        std::fs::read_to_string(path).with_context(|| format!("cannot read {}", path.display()))?;
    let file: EventsFile = serde_json::from_str(&text)
        .with_context(|| format!("{} is not a calibrate events file", path.display()))?;
    if file.format != EVENTS_FORMAT {
        anyhow::bail!(
            "{}: format \"{}\", expected \"{EVENTS_FORMAT}\"",
            path.display(),
            file.format
        );
    }
    if file.vehicle_hash != vehicle_hash(vehicle)? {
        anyhow::bail!(
            "{} was simulated for other vehicle parameters",
            path.display()
        );
    }
    let want = grid_fingerprint(grid, cfg)?;
    if file.grid != want {
        anyhow::bail!(
            "{} was simulated for another grid or detector:\n  file: {}\n  now:  {want}",
            path.display(),
            file.grid
        );
    }
    Ok(file.events)
}

/// Builds the table (the work of `shimmy calibrate`), on `threads` threads.
pub fn build_table(
    vehicle: &VehicleParams,
    grid: &Grid,
    cfg: &ObserverConfig,
    threads: usize,
) -> anyhow::Result<ResponseTable> {
    let events = simulate_table_events(vehicle, grid, cfg, threads)?;
    assemble_table(vehicle, grid, &events)
}

/// The table from a build's simulated events (in [`jobs`] order).
pub fn assemble_table(
    vehicle: &VehicleParams,
    grid: &Grid,
    events: &[TableEvent],
) -> anyhow::Result<ResponseTable> {
    let sensor = grid.sensor;
    let ranges = grid.ranges;
    let vehicles = drawn_vehicles(vehicle, grid);
    let (nm, nv, nd, ns) = (
        grid.vehicles as usize,
        grid.speed_kmh.len(),
        grid.decel_g.len(),
        grid.seeds as usize,
    );
    let in_order = events.len() == grid.n_events()
        && events.iter().enumerate().all(|(k, e)| {
            let rep = k % ns;
            let id = (k / ns) % nd;
            e.seed == work::event_seed(grid, e.raw.ic, e.raw.im, e.raw.iv, id, rep)
                && e.raw.iv == (k / (ns * nd)) % nv
                && e.raw.im == (k / (ns * nd * nv)) % nm
        });
    if !in_order {
        anyhow::bail!(
            "{} events do not match the grid's {} events",
            events.len(),
            grid.n_events()
        );
    }
    let z_all: Vec<[f64; 2]> = events.iter().map(|e| [e.raw.z[0], e.raw.z[1]]).collect();
    let zc_all: Vec<f64> = events.iter().map(|e| e.raw.z[2]).collect();
    let mut pairs: Vec<(f64, f64)> = events
        .iter()
        .map(|e| (e.excess_rms_deg, e.true_peak_deg))
        .collect();
    let mut cells: Vec<Cell> = z_all
        .chunks(ns)
        .zip(zc_all.chunks(ns))
        .map(|(z, zc)| Cell {
            mean: mean2(z),
            std: [1.0, 1.0],
            corr: 0.0,
            cruise: [zc.iter().sum::<f64>() / zc.len() as f64, 1.0],
        })
        .collect();
    let amp = amp_map(&mut pairs, 24);
    let mut t = ResponseTable {
        format: FORMAT.into(),
        vehicle_hash: vehicle_hash(vehicle)?,
        sensor,
        clearance_mm: grid.clearance_mm.clone(),
        speed_kmh: grid.speed_kmh.clone(),
        decel_g: grid.decel_g.clone(),
        vehicles: grid.vehicles,
        seeds: grid.seeds,
        cruise: true,
        cells: std::mem::take(&mut cells),
        amp_map: amp,
        provenance: provenance(grid, &ranges),
        linear: None,
        prior: ranges,
        fingerprint: String::new(),
        correction: None,
    };
    let raw: Vec<RawEvent> = events.iter().map(|e| e.raw).collect();
    let table_coords: Vec<_> = vehicles
        .iter()
        .map(|v| coords(vehicle, v, &ranges))
        .collect();
    if grid.emulate > 0 {
        emulate_into(&mut t, &raw, &table_coords, grid)?;
        for (ic, c) in grid.clearance_mm.iter().enumerate() {
            let cell = t.cell(ic, 0, 0, 0);
            eprintln!(
                "shimmy calibrate: emulator residual spread at {c:.3} mm: ln RMS {:.3}, ln peak \
                 {:.3}, cruise {:.3}",
                cell.std[0], cell.std[1], cell.cruise[1]
            );
        }
        return Ok(t);
    }
    // Means: averaged over deceleration, monotone in clearance, per vehicle and speed.
    t.smooth();
    // Spread of one vehicle's events about its smoothed means, pooled per clearance.
    let per_clearance = nm * nv * nd;
    for ic in 0..grid.clearance_mm.len() {
        let cell0 = ic * per_clearance;
        // Residuals of the braking features and of the cruise statistic (its mean is per
        // vehicle and speed, averaged over deceleration like the others).
        let mut res = Vec::with_capacity(per_clearance * ns);
        let mut res_c = Vec::with_capacity(per_clearance * ns);
        for k in cell0..cell0 + per_clearance {
            let cell = &t.cells[k];
            for (z, zc) in z_all[k * ns..(k + 1) * ns]
                .iter()
                .zip(&zc_all[k * ns..(k + 1) * ns])
            {
                res.push([z[0] - cell.mean[0], z[1] - cell.mean[1]]);
                res_c.push(zc - cell.cruise[0]);
            }
        }
        let (std, corr) = pooled_spread(&res, nm * nv, nd * ns);
        let std_c = pooled_std(&res_c, nm * nv, nd * ns);
        for c in &mut t.cells[cell0..cell0 + per_clearance] {
            c.std = std;
            c.corr = corr;
            c.cruise[1] = std_c;
        }
    }
    if grid.additive {
        fit_additive(&mut t, nd * ns);
        t.provenance += "; additive vehicle model";
    }
    pool_spread_globally(&mut t);
    t.provenance += "; one pooled spread";
    // The nuisance model needs drawn vehicles spread over the prior, more of them than its
    // terms.
    if nm > grid.terms.len() && ranges.stiffness_damping_rel > 0.0 {
        t.linear = Some(std::sync::Arc::new(crate::observer::linear::fit(
            &raw,
            &table_coords,
            grid.clearance_mm.len(),
            nv,
            &grid.terms,
            MIN_STD,
        )?));
        t.provenance += &format!(
            "; nuisance model of {} terms (leave-one-vehicle-out misfit)",
            grid.terms.len()
        );
    }
    keep_mixture_vehicles(&mut t, grid.mixture_vehicles);
    t.validate()?;
    Ok(t)
}

/// Keeps the cells of the first `keep` drawn vehicles (all when `keep` is at least their
/// number, or when the table has no nuisance model, e.g. `--exact-vehicle`; `--emulate`
/// tables do not come here). The cells serve method "mixture" only and grow with vehicles ×
/// speeds; a table whose nuisance model describes the vehicles can do without them
/// (`keep = 0`).
fn keep_mixture_vehicles(t: &mut ResponseTable, keep: u32) {
    let nm = t.vehicles;
    if keep >= nm || t.linear.is_none() {
        // Without the nuisance model the cells are all the table has.
        return;
    }
    let per_vehicle = t.speed_kmh.len() * t.decel_g.len();
    let per_clearance = nm as usize * per_vehicle;
    let keep_n = keep as usize * per_vehicle;
    let mut cells = Vec::with_capacity(t.clearance_mm.len() * keep_n);
    for chunk in t.cells.chunks(per_clearance) {
        cells.extend_from_slice(&chunk[..keep_n]);
    }
    t.cells = cells;
    t.vehicles = keep;
    t.provenance += &format!("; mixture cells of {keep} of the {nm} vehicles");
}

/// What a table records of how it was built.
fn provenance(grid: &Grid, ranges: &NuisanceRanges) -> String {
    let vehicles = match grid.emulate {
        0 => format!("{} nuisance vehicles", grid.vehicles),
        n => format!(
            "{n} emulated vehicles fitted on {} drawn nuisance vehicles",
            grid.vehicles
        ),
    };
    format!(
        "shimmy calibrate {}; {vehicles} (unbalance x{:?}, stiffness/damping ±{:.0} %, road noise \
         x{:?}), {} events per vehicle and cell, shape {:?}, seed_base {}",
        env!("CARGO_PKG_VERSION"),
        ranges.unbalance_factor,
        ranges.stiffness_damping_rel * 100.0,
        ranges.road_noise_factor,
        grid.seeds,
        grid.shape,
        grid.seed_base
    ) + &match ranges.brake_torque_variation_rel {
        Some((lo, hi)) => format!(", brake discs' variation {lo}-{hi} of the brake force"),
        None => String::new(),
    }
}

/// Replaces the drawn vehicles of `t` by `grid.emulate` emulated ones
/// ([`crate::observer::emulate`]), fitted on the drawn `vehicles`' events `raw`. The means
/// stay as the fit predicts them: no `smooth()`, because the regression already pools the
/// seed noise and keeps the deceleration term that smoothing would average away.
fn emulate_into(
    t: &mut ResponseTable,
    raw: &[RawEvent],
    table_coords: &[[f64; N_COORDS]],
    grid: &Grid,
) -> anyhow::Result<()> {
    let synth = draw_coords(grid.emulate as usize, grid.seed_base);
    t.cells = emulate_cells(
        raw,
        table_coords,
        grid.clearance_mm.len(),
        grid.speed_kmh.len(),
        &grid.decel_g,
        &synth,
        &grid.terms,
        MIN_STD,
    )?;
    t.vehicles = grid.emulate;
    t.validate()
}

/// `--brake-torque-variation-rel`, checked.
fn brake_variation_arg(args: &Args) -> anyhow::Result<Option<(f64, f64)>> {
    let Some(v) = &args.brake_torque_variation_rel else {
        return Ok(None);
    };
    let [lo, hi] = v[..] else {
        anyhow::bail!("--brake-torque-variation-rel takes LOW,HIGH");
    };
    crate::observer::simulate::check_brake_torque_variation(
        "--brake-torque-variation-rel",
        (lo, hi),
    )?;
    Ok(Some((lo, hi)))
}

/// The build's grid from the command line (checked), with the nuisance prior `ranges` (a
/// profile's, or the default) unless `--exact-vehicle` asks for none.
fn grid_from(args: &Args, ranges: NuisanceRanges) -> anyhow::Result<Grid> {
    let [lo, hi] = args.clearance_range[..] else {
        anyhow::bail!("--clearance-range takes LOW,HIGH");
    };
    if !(lo > 0.0 && hi > lo) {
        anyhow::bail!("--clearance-range must satisfy 0 < LOW < HIGH");
    }
    let grid = Grid {
        clearance_mm: log_grid(lo, hi, args.clearances),
        speed_kmh: args.speeds.clone(),
        decel_g: args.decels.clone(),
        vehicles: args.vehicles,
        seeds: args.seeds,
        shape: if args.shape == "single" {
            EventShape::Single
        } else {
            EventShape::DRIVE
        },
        seed_base: args.seed_base,
        additive: !args.per_vehicle,
        emulate: args.emulate,
        ranges: if args.exact_vehicle {
            NuisanceRanges::NONE
        } else {
            NuisanceRanges {
                brake_torque_variation_rel: brake_variation_arg(args)?,
                ..ranges
            }
        },
        // A torque table's default law adds the column's coordinates and the unbalance squared.
        terms: if args.signal == "torque" && args.terms == DEFAULT_TERMS {
            torque_terms()
        } else {
            parse_terms(&args.terms)
        }
        .context("--terms")?,
        mixture_vehicles: args.mixture_vehicles,
        sensor: {
            let base = if args.signal == "torque" {
                SensorModel::TORQUE_RAV4
            } else {
                SensorModel::default()
            };
            SensorModel {
                rate_hz: args.sensor_rate_hz.unwrap_or(base.rate_hz),
                step_deg: args.sensor_step_deg.unwrap_or(base.step_deg),
                noise_deg: args.sensor_noise_deg.unwrap_or(base.noise_deg),
                ..base
            }
        },
    };
    grid.sensor
        .validate()
        .context("--sensor-rate-hz / --sensor-step-deg / --sensor-noise-deg")?;
    // The radices of `work::event_seed`.
    if grid.vehicles >= 100_000
        || grid.speed_kmh.len() >= 1_000
        || grid.decel_g.len() >= 100
        || grid.seeds >= 100
        || grid.clearance_mm.len() >= 10_000
    {
        anyhow::bail!(
            "grid too large: at most 99999 vehicles, 999 speeds, 99 decelerations, 99 seeds and \
             9999 clearances"
        );
    }
    Ok(grid)
}

/// The work directory of a build: `--work-dir`, else `.calibrate-<hash>` beside `first_out`;
/// the hash names the chassis and the model runs, so another build never resumes from it
/// (one of the same runs through fewer sensors, or with fewer vehicles, does).
fn work_dir_for(
    args: &Args,
    first_out: &Path,
    vehicle_hash: &str,
    fingerprint: &str,
) -> anyhow::Result<PathBuf> {
    let key = crate::observer::table::fnv1a_hex(format!("{vehicle_hash}|{fingerprint}").as_bytes());
    Ok(match &args.work_dir {
        Some(d) => d.join(&key),
        None => first_out
            .parent()
            .filter(|p| !p.as_os_str().is_empty())
            .unwrap_or(Path::new("."))
            .join(format!(".calibrate-{key}")),
    })
}

/// Writes `table` to `path` (through a temporary file).
fn write_table(path: &Path, table: &ResponseTable) -> anyhow::Result<usize> {
    let json = serde_json::to_string(table)?;
    work::write_atomic(path, json.as_bytes())?;
    Ok(json.len())
}

/// The model runs of one chassis: resumed from / checkpointed into its work directory, with
/// progress; returns the events per sensor and the work directory.
#[allow(clippy::too_many_arguments)]
fn model_runs(
    args: &Args,
    vehicle: &VehicleParams,
    grid: &Grid,
    cfg: &ObserverConfig,
    sensors: &[SensorModel],
    threads: usize,
    first_out: &Path,
) -> anyhow::Result<(Vec<Vec<TableEvent>>, PathBuf)> {
    let hash = vehicle_hash(vehicle)?;
    let fingerprint = model_fingerprint(grid, cfg)?;
    let dir = work_dir_for(args, first_out, &hash, &fingerprint)?;
    if !args.quiet {
        eprintln!(
            "shimmy calibrate: {} jobs x {} model events ({} in all) on {threads} threads, \
             measured through {} sensor(s); work directory {}",
            work::jobs(grid).len(),
            grid.speed_kmh.len() * grid.decel_g.len(),
            grid.n_events(),
            sensors.len(),
            dir.display()
        );
    }
    let vehicles = drawn_vehicles(vehicle, grid);
    let events = work::run_all(
        &vehicles,
        &hash,
        grid,
        &fingerprint,
        cfg,
        sensors,
        threads,
        Some(&dir),
        args.quiet,
    )?;
    Ok((events, dir))
}

/// Removes a finished build's work directory unless `--keep-work`.
fn finish_work(args: &Args, dir: &Path) {
    if args.keep_work {
        return;
    }
    if let Err(e) = std::fs::remove_dir_all(dir) {
        eprintln!(
            "shimmy calibrate: could not remove the work directory {}: {e}",
            dir.display()
        );
    }
}

/// `--profile`: the tables of the profiles named, one set of model runs per chassis and prior.
fn run_profiles(args: &Args, cfg: &ObserverConfig, threads: usize) -> anyhow::Result<()> {
    let t0 = Instant::now();
    if args.brake_torque_variation_rel.is_some() {
        anyhow::bail!(
            "--brake-torque-variation-rel: a profile's own tables are built on even brake discs; \
             build a chassis variant's table with --vehicle and --out (docs/ADDING_A_CAR.md)"
        );
    }
    let mut profiles = Vec::new();
    if args.profile.iter().any(|p| p == "all") {
        for p in crate::profile::load_all() {
            profiles.push(p?);
        }
        if profiles.is_empty() {
            anyhow::bail!(
                "--profile all: no vehicle profile found (searched {})",
                crate::profile::search_dirs()
                    .iter()
                    .map(|d| d.display().to_string())
                    .collect::<Vec<_>>()
                    .join(", ")
            );
        }
    } else {
        for name in &args.profile {
            profiles.push(Profile::load(name)?);
        }
    }
    // Group by chassis and prior: each group is one set of model runs.
    let mut groups: Vec<(String, Vec<Profile>)> = Vec::new();
    for p in profiles {
        if p.table_path.is_none() {
            anyhow::bail!(
                "profile {} names no table file (`table = \"table.json\"` in its profile.toml)",
                p.name
            );
        }
        let key = format!("{}|{}", p.chassis_hash()?, serde_json::to_string(&p.prior)?);
        match groups.iter_mut().find(|(k, _)| *k == key) {
            Some((_, g)) => g.push(p),
            None => groups.push((key, vec![p])),
        }
    }
    for (_, group) in &groups {
        let lead = &group[0];
        let mut grid = grid_from(args, lead.prior)?;
        let mut sensors: Vec<SensorModel> = Vec::new();
        for p in group {
            if !sensors.contains(&p.sensor) {
                sensors.push(p.sensor);
            }
        }
        if !args.quiet {
            eprintln!(
                "shimmy calibrate: chassis of {} ({}): profiles {}",
                lead.name,
                lead.vehicle_source,
                group
                    .iter()
                    .map(|p| p.name.as_str())
                    .collect::<Vec<_>>()
                    .join(", ")
            );
        }
        let first_out = lead.table_path.clone().expect("checked above");
        let (per_sensor, dir) = model_runs(
            args,
            &lead.vehicle,
            &grid,
            cfg,
            &sensors,
            threads,
            &first_out,
        )?;
        for (sensor, events) in sensors.iter().zip(&per_sensor) {
            grid.sensor = *sensor;
            let table = assemble_table(&lead.vehicle, &grid, events)?;
            for p in group.iter().filter(|p| p.sensor == *sensor) {
                let path = p.table_path.as_ref().expect("checked above");
                let bytes = write_table(path, &table)?;
                eprintln!(
                    "shimmy calibrate: wrote {} for profile {} ({bytes} bytes)",
                    path.display(),
                    p.name
                );
            }
        }
        finish_work(args, &dir);
    }
    eprintln!(
        "shimmy calibrate: done in {:.1} s",
        t0.elapsed().as_secs_f64()
    );
    Ok(())
}

pub fn run(args: Args) -> anyhow::Result<()> {
    let cfg = match &args.config {
        Some(p) => ObserverConfig::load(p)?,
        None => ObserverConfig::default(),
    };
    let threads = args.threads.unwrap_or_else(default_threads);
    if !args.profile.is_empty() {
        return run_profiles(&args, &cfg, threads);
    }
    let out = args
        .out
        .clone()
        .context("--out TABLE is required without --profile")?;
    let vehicle = super::estimate::load_vehicle(args.vehicle.as_deref())?;
    let t0 = Instant::now();
    if let Some(src) = &args.refit {
        let mut t = ResponseTable::load(src)?;
        t.check_vehicle(&vehicle_hash(&vehicle)?)?;
        if t.provenance.contains("additive") {
            anyhow::bail!("{} already has the additive vehicle model", src.display());
        }
        let per_cell = t.decel_g.len() * t.seeds.max(1) as usize;
        fit_additive(&mut t, per_cell);
        pool_spread_globally(&mut t);
        t.provenance += "; additive vehicle model (refit); one pooled spread";
        t.validate()?;
        write_table(&out, &t)?;
        eprintln!(
            "shimmy calibrate: refitted {} into {}",
            src.display(),
            out.display()
        );
        return Ok(());
    }
    let grid = grid_from(&args, NuisanceRanges::default())?;
    let (events, dir) = match &args.events_in {
        Some(path) => {
            let ev = load_events(path, &vehicle, &grid, &cfg)?;
            eprintln!(
                "shimmy calibrate: {} simulated events from {}",
                ev.len(),
                path.display()
            );
            (ev, None)
        }
        None => {
            let (mut per_sensor, dir) =
                model_runs(&args, &vehicle, &grid, &cfg, &[grid.sensor], threads, &out)?;
            (per_sensor.remove(0), Some(dir))
        }
    };
    if let Some(path) = &args.events_out {
        save_events(path, &vehicle, &grid, &cfg, &events)?;
    }
    let table = assemble_table(&vehicle, &grid, &events)?;
    let bytes = write_table(&out, &table)?;
    if let Some(dir) = dir {
        finish_work(&args, &dir);
    }
    eprintln!(
        "shimmy calibrate: wrote {} ({bytes} bytes, {} cells) in {:.1} s",
        out.display(),
        table.cells.len(),
        t0.elapsed().as_secs_f64()
    );
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A table whose per-vehicle means are nominal(v) + offset(m) + interaction(m, v).
    fn table(interaction: f64) -> ResponseTable {
        let (nm, nv) = (4usize, 3usize);
        let mut cells = Vec::new();
        for ic in 0..2 {
            for im in 0..nm {
                for iv in 0..nv {
                    let inter = if (im + iv) % 2 == 0 {
                        interaction
                    } else {
                        -interaction
                    };
                    let m = ic as f64 + 0.1 * iv as f64 + 0.2 * im as f64 + inter;
                    cells.push(Cell {
                        mean: [m, m + 1.0],
                        std: [0.2, 0.2],
                        corr: 0.5,
                        cruise: [-m, 0.2],
                    });
                }
            }
        }
        ResponseTable {
            format: FORMAT.into(),
            vehicle_hash: "x".into(),
            sensor: SensorModel::default(),
            clearance_mm: vec![0.1, 0.2],
            speed_kmh: vec![40.0, 60.0, 80.0],
            decel_g: vec![0.5],
            vehicles: nm as u32,
            seeds: 2,
            cruise: true,
            cells,
            amp_map: vec![],
            provenance: String::new(),
            linear: None,
            prior: NuisanceRanges::default(),
            fingerprint: String::new(),
            correction: None,
        }
    }

    /// Options that would be silently ignored together are refused by the parser.
    #[test]
    fn emulate_and_exact_vehicle_refuse_the_options_they_cannot_honour() {
        use clap::Parser;
        #[derive(clap::Parser)]
        struct Cli {
            #[command(flatten)]
            args: Args,
        }
        let parse = |extra: &[&str]| {
            let mut a = vec!["calibrate", "--out", "t.json"];
            a.extend_from_slice(extra);
            Cli::try_parse_from(a).map(|c| c.args)
        };
        assert_eq!(parse(&["--emulate", "120"]).unwrap().emulate, 120);
        assert!(parse(&["--exact-vehicle"]).unwrap().exact_vehicle);
        for bad in [
            &["--emulate", "120", "--per-vehicle"][..],
            &["--emulate", "120", "--refit", "old.json"],
            &["--exact-vehicle", "--refit", "old.json"],
            &["--profile", "toyota_rav4"],
        ] {
            let e = parse(bad).err().unwrap().to_string();
            assert!(e.contains("cannot be used with"), "{bad:?}: {e}");
        }
    }

    /// `--sensor-*` chooses the sensor the table's events go through; the table records it, and
    /// so does an events file.
    #[test]
    fn the_table_is_built_for_the_sensor_asked_for() {
        use clap::Parser;
        #[derive(clap::Parser)]
        struct Cli {
            #[command(flatten)]
            args: Args,
        }
        let grid = |extra: &[&str]| {
            let mut a = vec![
                "calibrate",
                "--out",
                "t.json",
                "--clearances",
                "2",
                "--vehicles",
                "1",
                "--speeds",
                "55",
                "--decels",
                "0.5",
            ];
            a.extend_from_slice(extra);
            grid_from(
                &Cli::try_parse_from(a).unwrap().args,
                NuisanceRanges::default(),
            )
        };
        let cfg = ObserverConfig::default();
        let reference = grid(&[]).unwrap();
        assert_eq!(reference.sensor, SensorModel::default());
        assert!(!model_fingerprint(&reference, &cfg)
            .unwrap()
            .contains("sensor"));
        let fine = grid(&["--sensor-step-deg", "0.01", "--sensor-rate-hz", "200"]).unwrap();
        assert_eq!((fine.sensor.step_deg, fine.sensor.rate_hz), (0.01, 200.0));
        assert!(grid_fingerprint(&fine, &cfg)
            .unwrap()
            .contains("step_deg: 0.01"));
        let e = grid(&["--sensor-rate-hz", "40"]).unwrap_err();
        assert!(format!("{e:#}").contains("--sensor-rate-hz"), "{e:#}");
        // Uneven brake discs: drawn per vehicle and part of the prior and the work directory's
        // name; without them the fingerprint reads as it did before they could be drawn.
        assert!(!model_fingerprint(&reference, &cfg)
            .unwrap()
            .contains("torque_variation"));
        let r = NuisanceRanges::default();
        assert_eq!(
            ranges_fingerprint(&r),
            format!("{r:?}").replace(", brake_torque_variation_rel: None", "")
        );
        let discs = grid(&["--brake-torque-variation-rel", "0,0.05"]).unwrap();
        assert_eq!(discs.ranges.brake_torque_variation_rel, Some((0.0, 0.05)));
        assert!(model_fingerprint(&discs, &cfg)
            .unwrap()
            .contains("brake_torque_variation_rel: (0.0, 0.05)"));
        let drawn = drawn_vehicles(&vehicle_scrub(), &discs);
        assert!(
            drawn[0].braking.torque_variation_rel[0] > 0.0,
            "{:?}",
            drawn[0].braking
        );
        for bad in ["0.05,0.01", "0,0.5", "0.02"] {
            let e = grid(&["--brake-torque-variation-rel", bad]).unwrap_err();
            assert!(
                format!("{e:#}").contains("--brake-torque-variation-rel"),
                "{bad}: {e:#}"
            );
        }
        // The build puts the events through that sensor and says so in the table.
        let vehicle = VehicleParams::default();
        let ev = simulate_table_events(&vehicle, &fine, &cfg, 2).unwrap();
        let t = assemble_table(&vehicle, &fine, &ev).unwrap();
        assert_eq!(t.sensor, fine.sensor);
        let ev_ref = simulate_table_events(&vehicle, &reference, &cfg, 2).unwrap();
        // The same model runs seen through the other sensor: every event's statistics move.
        assert_eq!(ev.len(), ev_ref.len());
        assert!(ev
            .iter()
            .zip(&ev_ref)
            .all(|(a, b)| a.seed == b.seed && a.raw.z != b.raw.z));
    }

    fn vehicle_scrub() -> VehicleParams {
        let mut v = VehicleParams::default();
        v.steering.scrub_radius_m = 0.01;
        v
    }

    #[test]
    fn an_exact_vehicle_table_draws_the_vehicle_itself() {
        let nominal = VehicleParams::default();
        for im in 0..3 {
            let v = nuisance_vehicle(&nominal, &NuisanceRanges::NONE, 1_000_000, im);
            assert_eq!(v, nominal);
        }
        let drawn = nuisance_vehicle(&nominal, &NuisanceRanges::default(), 1_000_000, 0);
        assert_ne!(drawn, nominal);
    }

    #[test]
    fn additive_fit_keeps_an_additive_law_and_moves_interaction_into_the_spread() {
        let mut t = table(0.0);
        let before = t.clone();
        fit_additive(&mut t, 2);
        for (a, b) in t.cells.iter().zip(&before.cells) {
            assert!((a.mean[0] - b.mean[0]).abs() < 1e-12, "{a:?} vs {b:?}");
            // Only the fit's sampling error is added: 0.2 · sqrt((1 + 1/8 + 1/6) / 1.5).
            let want = 0.2 * ((1.0 + 1.0 / 8.0 + 1.0 / 6.0) / 1.5f64).sqrt();
            assert!((a.std[0] - want).abs() < 1e-9, "{}", a.std[0]);
        }
        let mut u = table(0.3);
        fit_additive(&mut u, 2);
        assert!(u.cells[0].std[0] > 0.3, "interaction goes into the spread");
        // The fitted means are additive: vehicle differences are the same at every speed.
        let m = |t: &ResponseTable, im: usize, iv: usize| t.cells[im * 3 + iv].mean[0];
        let d0 = m(&u, 1, 0) - m(&u, 0, 0);
        assert!((m(&u, 1, 2) - m(&u, 0, 2) - d0).abs() < 1e-9);
        u.validate().unwrap();
    }
}
