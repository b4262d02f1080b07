//! `firmware-sim fleet`: validation of the clearance observer on a fleet of simulated vehicles
//! with known clearance.
//!
//! Each vehicle gets a clearance drawn log-uniformly in 0.03–0.4 mm, its own nuisances (±10 %
//! on the steering stiffnesses and dampings, unbalance ×0.5–2, road noise ×0.7–1.4, all drawn
//! from the vehicle's seed; with the MODEL.md §15 column also its rim inertia, torsion bar
//! stiffness and damping, and the driver's hands drawn per braking event, docs/COLUMN.md)
//! and a drive of N braking events to a stop at 30–100 km/h and
//! 0.3–0.8 g. firmware-sim writes its candump log; the whole monitor chain then runs on that
//! file exactly as `shimmy estimate` does (log reader → DBC → signal mapping → events →
//! features → posterior → alerts), with the nominal vehicle's response table. The scores are
//! computed against the ground truth. A vehicle's alerts are those standing at the end of its
//! log under shimmyd's alert lifecycle (`shimmy::alerts::AlertBook`: raised after some event,
//! cleared only below the hysteresis thresholds), so the fleet scores what the daemon does.
//!
//! The bus is the reference bus, or with `--profile` a vehicle profile's (its DBC and
//! `bus.toml`, [`crate::bus::profile_bus`]); the profile also gives the nominal vehicle (its
//! chassis), the mapping the estimate decodes with and the table, each unless given
//! explicitly.
//!
//! Seeds: vehicle k uses `seed_base + k`. Keep `seed_base` away from the table's seeds
//! (`shimmy calibrate --seed-base`, default 1 000 000) and from any seeds used while tuning.
//!
//! Not here: the estimator (`shimmy::observer`) or the simulation (`crate::sim`).

use std::io::{BufWriter, Write};
use std::path::{Path, PathBuf};
use std::time::Instant;

use anyhow::Context;
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use serde::Serialize;

use crate::plant::{ModelPlant, Plant};
use crate::{FirmwareSim, RunInfo, Scenario};
use shimmy::alerts::Kind;
use shimmy::analysis::sweep::{default_threads, par_map};
use shimmy::cli::estimate::{estimate_files_with, BaselineLogs, Estimation};
use shimmy::dbc::Database;
use shimmy::model::VehicleParams;
use shimmy::observer::simulate::{perturb, HandsPrior, NuisanceRanges};
use shimmy::observer::table::{vehicle_hash, ResponseTable};
use shimmy::observer::ObserverConfig;
use shimmy::pipeline::Tables;
use shimmy::profile::bus::BusSpec;
use shimmy::profile::Profile;

/// Validate the clearance observer on a simulated fleet.
///
/// Generates VEHICLES held-out vehicles (clearance log-uniform 0.03–0.4 mm, nuisances drawn per
/// vehicle), simulates EVENTS braking events each (30–100 km/h, 0.3–0.8 g, to a stop) through
/// the reference bus (or the --profile's) into a candump log, runs `shimmy estimate`'s chain on
/// each log with the response table, and prints the scores of issue 5 (alert rates, mean
/// absolute error, interval coverage, "below" reports, shimmy_55kmh agreement). Per-vehicle
/// results go to --json.
///
/// Examples:
///   shimmy calibrate --out table.json
///   firmware-sim fleet --table table.json --vehicles 40 --events 30 --seed-base 5000
///   firmware-sim fleet --profile toyota_rav4 --vehicles 40 --events 30 --seed-base 5000
#[derive(clap::Parser, Debug)]
#[command(name = "firmware-sim fleet", verbatim_doc_comment)]
pub struct FleetArgs {
    /// Response table from `shimmy calibrate`, built for the fleet's nominal vehicle
    /// (`--vehicle`, the profile's chassis, or MODEL.md §9). Default with --profile: the
    /// profile's table.
    #[arg(long, value_name = "FILE")]
    pub table: Option<PathBuf>,
    /// Response table of the EPS torsion-bar torque (`shimmy calibrate --signal torque`, on
    /// the nominal vehicle with its §15 column enabled). Default with --profile: the
    /// profile's `torque_table` when its mapping maps the torque. Events with a live torque
    /// are then estimated from it (`shimmy estimate`'s rule). Given, it replaces the profile's
    /// torque tables, its chassis variants' too.
    #[arg(long, value_name = "FILE", conflicts_with = "angle_only")]
    pub torque_table: Option<PathBuf>,
    /// Estimate from the steering angle alone (no torque table).
    #[arg(long)]
    pub angle_only: bool,
    /// A vehicle profile (name, alias or folder; config/vehicles/): its bus (DBC and bus.toml)
    /// goes on the wire, its chassis is the nominal vehicle, its mapping decodes and its table
    /// estimates, each unless --dbc, --vehicle, --mapping or --table says otherwise.
    #[arg(long, value_name = "NAME")]
    pub profile: Option<String>,
    /// The nominal vehicle the fleet's vehicles are drawn around (TOML, MODEL.md §9 keys;
    /// default: the profile's chassis, or MODEL.md §9), e.g. one with the steering column of
    /// §15 enabled. The table must be built for the same file (`shimmy calibrate --vehicle
    /// FILE`).
    #[arg(long, value_name = "FILE")]
    pub vehicle: Option<PathBuf>,
    /// Simulate the vehicles around this vehicle (TOML, MODEL.md §9 keys) instead, while the
    /// table and the estimate stay the nominal vehicle's: a fleet of cars that are not the
    /// table's model (e.g. a plant with the §15 steering column scored with a 5-DOF table), to
    /// see what the observer says when its model does not fit.
    #[arg(long, value_name = "FILE")]
    pub plant: Option<PathBuf>,
    #[arg(long, default_value_t = 40)]
    pub vehicles: usize,
    #[arg(long, default_value_t = 30)]
    pub events: usize,
    /// Vehicle k uses seed seed_base + k.
    #[arg(long, default_value_t = 5000)]
    pub seed_base: u64,
    /// Signal mapping the estimate decodes with (default: the profile's, or
    /// config/vehicles/shimmy_reference/mapping.toml).
    #[arg(long)]
    pub mapping: Option<PathBuf>,
    /// The bus's DBC, in place of the built-in reference bus (dbc/shimmy_reference.dbc) or the
    /// profile's: the simulated ECUs pack their frames with it and the estimator decodes them
    /// with it. A variant of the reference DBC with another scale factor on SAS_Angle gives a
    /// steering angle sensor with another step (build the table for it with `shimmy calibrate
    /// --sensor-step-deg`).
    #[arg(long, value_name = "FILE")]
    pub dbc: Option<PathBuf>,
    /// Observer config (default: built-in defaults = config/observer.toml).
    #[arg(long)]
    pub config: Option<PathBuf>,
    /// Directory for the logs, truth sidecars and vehicle files (default: a temporary one,
    /// removed afterwards).
    #[arg(long)]
    pub work_dir: Option<PathBuf>,
    /// Write per-vehicle results (JSON) here.
    #[arg(long)]
    pub json: Option<PathBuf>,
    /// Threads (default: all cores, or SHIMMY_THREADS).
    #[arg(long)]
    pub threads: Option<usize>,
    /// Only simulate: write each vehicle's log and truth into --work-dir and stop (no
    /// estimation, no scores). With --reuse, a later run estimates from them, e.g. with a
    /// table finished after the logs were written.
    #[arg(long, requires = "work_dir")]
    pub logs_only: bool,
    /// Reuse a vehicle's log from --work-dir when it and its `.eval.json` are there (written by
    /// an earlier run with the same seed base, vehicles and events) instead of simulating it.
    #[arg(long, requires = "work_dir")]
    pub reuse: bool,
    /// Give every vehicle this clearance (mm, both joints) instead of the drawn one. Its
    /// nuisances and drive stay those of its seed, so two runs with the same seeds and two
    /// values are twin fleets: the same vehicles on the same roads with other joints (the
    /// identifiability check of docs/ACCURACY.md). Use a separate --work-dir per value.
    #[arg(long, value_name = "MM")]
    pub clearance_mm: Option<f64>,
    /// What happens to the difference of each vehicle's two wheel-unbalance phases between
    /// its braking events: none (kept for the whole drive, as the model's wheels roll
    /// together) or per-stop (drawn anew at every stop, as a turn at a junction would). Its
    /// seeds' vehicles and drives stay the same; use a separate --work-dir per value.
    #[arg(long, default_value = "none", value_parser = ["none", "per-stop"])]
    pub phase_change: String,
    /// What precedes each braking event: steady (1.5 s of steady cruise at the event's speed)
    /// or varied (each event, independently with probability 1/2 each: a coast of 1.5–3 s at
    /// 0.03–0.12 g after the cruise, a change of road roughness at brake onset by ×0.5–2, and
    /// a curve of 3–10° on the steering wheel turned in before onset and unwound over
    /// 0.5–2 s), as braking on real roads follows coasting, a turn or a change of surface.
    /// The vehicles, their braking plans and the road noise stay those of their seeds; use a
    /// separate --work-dir per value.
    #[arg(long, default_value = "steady", value_parser = ["steady", "varied"])]
    pub pre_brake: String,
    /// Multiply the white noise of the steering-angle and steering-torque sensors (0.01° and
    /// 0.02 N·m RMS by default) by this factor: a sensor noisier or quieter than the table
    /// assumes. Use a separate --work-dir per value.
    #[arg(long, default_value_t = 1.0, value_name = "F")]
    pub sensor_noise_factor: f64,
    /// Draw each vehicle's steering stiffnesses and dampings (k_s, c_s, k_t, k_g, c_g,
    /// MODEL.md §9) within ±REL of the nominal instead of the profile's (or the default) prior,
    /// the other nuisances as before: vehicles beyond the prior the tables integrate out (0.25
    /// = ±25 %). A profile copy with that prior draws the same vehicles for the same seeds. Use
    /// a separate --work-dir per value.
    #[arg(long, value_name = "REL")]
    pub stiffness_damping_rel: Option<f64>,
    /// Measure the same vehicles again: replicate 0 (the default) is the drive as its seed
    /// draws it; replicate r > 0 keeps everything the seed fixes about the vehicle (clearance,
    /// parameters, unbalance and its two phases, road-noise level, the braking plan) and draws
    /// the road noise, the driver's lane keeping and the sensor's noise and offset anew from
    /// another seed. Repeated drives of one vehicle show what an event's features scatter by
    /// when nothing about the vehicle is unknown (the feature oracle of docs/ACCURACY.md). Use
    /// a separate --work-dir per value.
    #[arg(long, default_value_t = 0)]
    pub replicate: u64,
    /// Give each vehicle a baseline: its log `fleet_<seed>.log` in this directory, written by
    /// an earlier run with the same seed base and `--clearance-mm` (the same vehicles with new
    /// joints, e.g. `--clearance-mm 0.03 --replicate 1 --events 10 --logs-only`), whose events
    /// at that clearance condition the estimate (`shimmy estimate --baseline`).
    #[arg(long, value_name = "DIR")]
    pub baseline_dir: Option<PathBuf>,
    /// The clearance of the --baseline-dir logs (mm).
    #[arg(
        long,
        value_name = "MM",
        default_value_t = 0.03,
        requires = "baseline_dir"
    )]
    pub baseline_clearance_mm: f64,
}

/// The scenario seed of replicate `r` of the vehicle with `seed` (r = 0: the seed itself).
pub fn replicate_seed(seed: u64, r: u64) -> u64 {
    if r == 0 {
        return seed;
    }
    // SplitMix64 of (seed, r): far from any seed base a fleet or table uses.
    let mut z = seed ^ r.wrapping_mul(0x9e37_79b9_7f4a_7c15) ^ 0x5eed_0f_4e91_1ca7e;
    z = (z ^ (z >> 30)).wrapping_mul(0xbf58_476d_1ce4_e5b9);
    z = (z ^ (z >> 27)).wrapping_mul(0x94d0_49bb_1331_11eb);
    z ^ (z >> 31)
}

/// What the scores need from a vehicle's ground truth, kept next to its log for --reuse.
#[derive(Clone, Debug, Serialize, serde::Deserialize)]
pub struct EvalTruth {
    pub seed: u64,
    pub events: usize,
    pub clearance_true_mm: f64,
    /// True steering-wheel amplitudes of the events starting at 50–60 km/h (deg).
    pub sw_amplitudes_55_deg: Vec<f64>,
    pub events_true: usize,
    /// `--phase-change` of the run that wrote the log.
    #[serde(default = "phase_none")]
    pub phase_change: String,
    /// `--replicate` of the run that wrote the log.
    #[serde(default)]
    pub replicate: u64,
    /// `--pre-brake` of the run that wrote the log.
    #[serde(default = "pre_brake_steady")]
    pub pre_brake: String,
    /// `--sensor-noise-factor` of the run that wrote the log.
    #[serde(default = "one")]
    pub sensor_noise_factor: f64,
    /// `--stiffness-damping-rel` of the run that wrote the log; absent when it was not given
    /// (the profile's prior, or a profile copy's: files written before the option do not say).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub stiffness_damping_rel: Option<f64>,
    /// Hash of the nominal vehicle (`--vehicle`) of the run that wrote the log.
    #[serde(default = "default_vehicle_hash")]
    pub nominal_vehicle_hash: String,
    /// `--profile` of the run that wrote the log (whose bus is in it).
    #[serde(default)]
    pub profile: Option<String>,
}

fn phase_none() -> String {
    "none".into()
}

fn pre_brake_steady() -> String {
    "steady".into()
}

fn one() -> f64 {
    1.0
}

fn default_vehicle_hash() -> String {
    vehicle_hash(&VehicleParams::default()).unwrap_or_default()
}

/// The fleet's nominal vehicle (`--vehicle`, the profile's chassis, or MODEL.md §9) and its
/// hash, read once per run.
pub struct Nominal {
    pub params: VehicleParams,
    pub hash: String,
}

impl Nominal {
    /// `--vehicle`, or MODEL.md §9 (see [`Setup::load`] for the profile's chassis).
    pub fn load(args: &FleetArgs) -> anyhow::Result<Nominal> {
        Nominal::load_or(args, None)
    }

    fn load_or(args: &FleetArgs, profile: Option<&Profile>) -> anyhow::Result<Nominal> {
        let params = match (&args.vehicle, profile) {
            (Some(p), _) => return Nominal::from_file(p, "--vehicle"),
            (None, Some(p)) => p.vehicle.clone(),
            (None, None) => VehicleParams::default(),
        };
        Nominal::new(params)
    }

    fn new(params: VehicleParams) -> anyhow::Result<Nominal> {
        let hash = vehicle_hash(&params)?;
        Ok(Nominal { params, hash })
    }

    /// The vehicle of the TOML file `path`, given with the option `flag`.
    fn from_file(path: &Path, flag: &str) -> anyhow::Result<Nominal> {
        let params = VehicleParams::from_toml_file(path)
            .with_context(|| format!("{flag} {}", path.display()))?;
        Nominal::new(params)
    }
}

/// Everything a fleet run fixes once: the profile (if any), the nominal vehicle, the bus on
/// the wire and how the estimate decodes it.
pub struct Setup {
    pub profile: Option<Profile>,
    pub nominal: Nominal,
    /// `--plant`: what the vehicles are drawn around when it is not the nominal vehicle.
    pub plant: Option<Nominal>,
    /// What each vehicle's nuisances are drawn from: the profile's prior (or the default),
    /// with `--stiffness-damping-rel` in place of its stiffness and damping spread.
    pub prior: NuisanceRanges,
    pub db: Database,
    pub bus: BusSpec,
    /// The DBC the estimate decodes with (`None`: the one the mapping names, the reference).
    pub dbc_path: Option<PathBuf>,
    pub mapping: PathBuf,
}

impl Setup {
    pub fn load(args: &FleetArgs) -> anyhow::Result<Setup> {
        let profile = match &args.profile {
            Some(n) => Some(Profile::load(n)?),
            None => None,
        };
        let nominal = Nominal::load_or(args, profile.as_ref())?;
        let mut prior = profile
            .as_ref()
            .map_or_else(NuisanceRanges::default, |p| p.prior);
        if let Some(rel) = args.stiffness_damping_rel {
            prior.stiffness_damping_rel = rel;
            shimmy::profile::check_prior(&prior).context("--stiffness-damping-rel")?;
        }
        let plant = match &args.plant {
            Some(p) => Some(Nominal::from_file(p, "--plant")?),
            None => None,
        };
        let (db, bus, dbc_path) = match &profile {
            Some(p) => {
                let (db, bus) = crate::bus::profile_bus(p, args.dbc.as_deref())?;
                let path = args.dbc.clone().unwrap_or_else(|| p.dbc_path.clone());
                (db, bus, Some(path))
            }
            None => {
                let text = match &args.dbc {
                    Some(p) => std::fs::read_to_string(p)
                        .with_context(|| format!("cannot read DBC {}", p.display()))?,
                    None => crate::bus::REFERENCE_DBC.to_string(),
                };
                (
                    Database::parse(&text).0,
                    crate::bus::reference_bus()?,
                    args.dbc.clone(),
                )
            }
        };
        let mapping = match (&args.mapping, &profile) {
            (Some(m), _) => m.clone(),
            (None, Some(p)) => p.mapping_path.clone(),
            (None, None) => PathBuf::from("config/vehicles/shimmy_reference/mapping.toml"),
        };
        Ok(Setup {
            profile,
            nominal,
            plant,
            prior,
            db,
            bus,
            dbc_path,
            mapping,
        })
    }

    fn profile_name(&self) -> Option<String> {
        self.profile.as_ref().map(|p| p.name.clone())
    }
}

/// One vehicle's outcome.
#[derive(Clone, Debug, Serialize)]
pub struct VehicleResult {
    pub index: usize,
    pub seed: u64,
    pub clearance_true_mm: f64,
    pub clearance_mm: Option<f64>,
    pub median_mm: Option<f64>,
    pub interval_mm: Option<[f64; 2]>,
    pub detectable: bool,
    pub below_mm: Option<f64>,
    pub clearance_alert: bool,
    /// How many times the clearance alert was raised over the drive (more than 1, or 1 with no
    /// alert standing at the end: an alert that came and went).
    pub clearance_alerts_raised: u32,
    /// Posterior P(c > the clearance threshold) at the end of the drive.
    pub p_clearance_above_threshold: Option<f64>,
    /// Posterior probability that the wheels' phase difference stayed the same (phase
    /// "either").
    pub p_wheel_phase_fixed: Option<f64>,
    /// The estimator's goodness-of-fit check (src/observer/fit.rs).
    pub model_fit: Option<shimmy::observer::fit::ModelFit>,
    /// The report's verdict: the estimate in words, and why the model does not fit when not.
    pub verdict: String,
    pub shimmy_alert: bool,
    /// Mean true steering-wheel amplitude of events starting at 50–60 km/h (deg).
    pub true_sw_55_deg: Option<f64>,
    /// Number of those events (the shimmy_55kmh rule needs `shimmy_confirm` of them).
    pub events_55: usize,
    pub events_true: usize,
    pub events_recorded: usize,
    pub events_used: u32,
    /// With a torque table: the signal the estimate came from and the events the torque's
    /// estimator used.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub signals: Option<shimmy::observer::SignalUse>,
    /// With torque tables of chassis variants: the most probable one (the estimate weighs them
    /// all), and each table's evidence.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub torque_table: Option<String>,
    #[serde(skip_serializing_if = "Vec::is_empty")]
    pub torque_tables: Vec<shimmy::observer::TableEvidence>,
    /// As `torque_table` and `torque_tables`, for the angle tables of chassis variants.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub angle_table: Option<String>,
    #[serde(skip_serializing_if = "Vec::is_empty")]
    pub angle_tables: Vec<shimmy::observer::TableEvidence>,
    pub seconds: f64,
}

/// The scenario TOML of one fleet vehicle; `pre` says what precedes each event (absent: a
/// steady cruise).
#[allow(clippy::too_many_arguments)]
pub fn vehicle_scenario(
    seed: u64,
    clearance_mm: f64,
    vehicle_file: &str,
    unbalance_kgm: f64,
    road_noise_nm: f64,
    phase_per_stop: bool,
    events: &[(f64, f64)],
    pre: &[PreBrake],
) -> String {
    let phase = if phase_per_stop {
        "phase_change = \"per_stop\"\n"
    } else {
        ""
    };
    let mut s = format!(
        "name = \"fleet_{seed}\"\nseed = {seed}\nvehicle = \"{vehicle_file}\"\n\n[clearance]\nmode = \"dual\"\nleft_mm = {clearance_mm}\n\n[excitation]\nunbalance_kgm = {unbalance_kgm}\nroad_noise_nm = {road_noise_nm}\n{phase}\n[drive]\nstart_speed_kmh = {}\naccel_g = 0.35\n",
        events.first().map_or(50.0, |e| e.0)
    );
    for (k, &(v, d)) in events.iter().enumerate() {
        let p = pre.get(k).copied().unwrap_or_default();
        s +=
            &format!("\n[[drive.segment]]\nkind = \"cruise\"\nspeed_kmh = {v}\nduration_s = 1.5\n");
        if let Some((dur, g)) = p.coast {
            s += &format!(
                "\n[[drive.segment]]\nkind = \"coast\"\nduration_s = {dur}\ndecel_g = {g}\n"
            );
        }
        s += &format!("\n[[drive.segment]]\nkind = \"brake\"\ndecel_g = {d}\nhold_s = 0.5\n");
        if p.road_noise_scale != 1.0 {
            s += &format!("road_noise_scale = {}\n", p.road_noise_scale);
        }
        if p.turn_deg != 0.0 {
            s += &format!(
                "turn_deg = {}\nturn_unwind_s = {}\n",
                p.turn_deg, p.turn_unwind_s
            );
        }
    }
    s
}

/// What precedes one braking event of a fleet vehicle (`--pre-brake`); the default is the
/// steady cruise.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct PreBrake {
    /// A coast after the cruise: (duration s, deceleration g).
    pub coast: Option<(f64, f64)>,
    /// Road roughness from brake onset, relative to the cruise's.
    pub road_noise_scale: f64,
    /// A curve on the steering wheel at brake onset (deg) and its unwinding time (s).
    pub turn_deg: f64,
    pub turn_unwind_s: f64,
}

impl Default for PreBrake {
    fn default() -> Self {
        PreBrake {
            coast: None,
            road_noise_scale: 1.0,
            turn_deg: 0.0,
            turn_unwind_s: 1.0,
        }
    }
}

/// The pre-brake situations of `n_events` events of the vehicle with `seed` under
/// `--pre-brake varied` (deterministic, from their own stream: the vehicle's plan and road
/// noise do not change). Each event independently gets, with probability 1/2 each, a coast,
/// a change of road roughness and a curve.
pub fn varied_pre_brake(seed: u64, n_events: usize) -> Vec<PreBrake> {
    let mut rng = ChaCha8Rng::seed_from_u64(seed);
    rng.set_stream(13);
    let round = |x: f64, k: f64| (x * k).round() / k;
    (0..n_events)
        .map(|_| {
            let mut p = PreBrake::default();
            if rng.random::<bool>() {
                p.coast = Some((
                    round(rng.random_range(1.5..3.0), 10.0),
                    round(rng.random_range(0.03..0.12), 100.0),
                ));
            }
            if rng.random::<bool>() {
                p.road_noise_scale = round(rng.random_range(0.5f64.ln()..2f64.ln()).exp(), 100.0);
            }
            if rng.random::<bool>() {
                let side = if rng.random::<bool>() { 1.0 } else { -1.0 };
                p.turn_deg = side * round(rng.random_range(3.0..10.0), 10.0);
                p.turn_unwind_s = round(rng.random_range(0.5..2.0), 10.0);
            }
            p
        })
        .collect()
}

/// The scenario's `[hands]` section: the prior each leg of the drive draws the driver's hands
/// from (MODEL.md §15 column; docs/COLUMN.md).
pub fn hands_section(prior: &HandsPrior) -> anyhow::Result<String> {
    #[derive(Serialize)]
    struct Section<'a> {
        hands: &'a HandsPrior,
    }
    Ok(format!("\n{}", toml::to_string(&Section { hands: prior })?))
}

/// The scenario's `[sensors]` section with the steering angle's and torque's white noise
/// `factor` times the defaults (`--sensor-noise-factor`); empty for 1.
pub fn sensors_section(factor: f64) -> String {
    if factor == 1.0 {
        return String::new();
    }
    let d = crate::scenario::Sensors::default();
    format!(
        "\n[sensors]\nsteer_noise_deg = {}\nsteer_torque_noise_nm = {}\n",
        d.steer_noise_deg * factor,
        d.steer_torque_noise_nm * factor
    )
}

/// What a fleet vehicle is: its clearance, nuisance-drawn parameters, road-noise level and
/// braking events (v0 km/h, decel g), all from its seed.
#[derive(Clone, Debug)]
pub struct VehiclePlan {
    pub clearance_mm: f64,
    pub params: VehicleParams,
    pub road_noise_nm: f64,
    pub events: Vec<(f64, f64)>,
}

/// The plan of the vehicle with `seed` around MODEL.md §9's vehicle (deterministic).
pub fn vehicle_plan(seed: u64, n_events: usize) -> VehiclePlan {
    vehicle_plan_around(&VehicleParams::default(), seed, n_events)
}

/// The plan of the vehicle with `seed` around `nominal` (deterministic): the same draws as
/// [`vehicle_plan`], applied to another vehicle.
pub fn vehicle_plan_around(nominal: &VehicleParams, seed: u64, n_events: usize) -> VehiclePlan {
    vehicle_plan_with(nominal, &NuisanceRanges::default(), seed, n_events)
}

/// [`vehicle_plan_around`] with the nuisances drawn from `prior` (a vehicle profile's
/// `[chassis.prior]`) instead of the default ranges.
pub fn vehicle_plan_with(
    nominal: &VehicleParams,
    prior: &NuisanceRanges,
    seed: u64,
    n_events: usize,
) -> VehiclePlan {
    let mut rng = ChaCha8Rng::seed_from_u64(seed);
    rng.set_stream(7);
    let c_mm = (0.03f64.ln() + rng.random::<f64>() * (0.4f64.ln() - 0.03f64.ln())).exp();
    let p = perturb(nominal, prior, &mut rng);
    let noise = p.excitation.noise_std_nm * rng.random_range(0.7..1.4);
    let events: Vec<(f64, f64)> = (0..n_events)
        .map(|_| {
            let v: f64 = rng.random_range(30.0..100.0);
            let d: f64 = rng.random_range(0.3..0.8);
            ((v * 10.0).round() / 10.0, (d * 100.0).round() / 100.0)
        })
        .collect();
    VehiclePlan {
        clearance_mm: c_mm,
        params: p,
        road_noise_nm: noise,
        events,
    }
}

/// Simulates vehicle `k` into `dir` (log, truth, `.eval.json`), or finds it there (--reuse).
fn vehicle_log(
    k: usize,
    args: &FleetArgs,
    setup: &Setup,
    dir: &Path,
) -> anyhow::Result<(PathBuf, EvalTruth)> {
    // The vehicle simulated: drawn around the plant when one is given, else the nominal.
    let nominal = setup.plant.as_ref().unwrap_or(&setup.nominal);
    let seed = args.seed_base + k as u64;
    let log = dir.join(format!("fleet_{seed}.log"));
    let eval_path = log.with_extension("eval.json");
    let plan = vehicle_plan_with(&nominal.params, &setup.prior, seed, args.events);
    let c_mm = args.clearance_mm.unwrap_or(plan.clearance_mm);
    if args.reuse && log.exists() && eval_path.exists() {
        let text = std::fs::read_to_string(&eval_path)?;
        let e: EvalTruth = serde_json::from_str(&text)
            .with_context(|| format!("{} is not a fleet eval file", eval_path.display()))?;
        if e.clearance_true_mm != c_mm {
            let wanted = match args.clearance_mm {
                Some(c) => format!("--clearance-mm {c}"),
                None => format!("the seed's drawn {c_mm} mm (a --clearance-mm twin?)"),
            };
            anyhow::bail!(
                "{} is for clearance {} mm, not {wanted}",
                eval_path.display(),
                e.clearance_true_mm
            );
        }
        if e.phase_change != args.phase_change {
            anyhow::bail!(
                "{} is for --phase-change {}, not {}",
                eval_path.display(),
                e.phase_change,
                args.phase_change
            );
        }
        if e.nominal_vehicle_hash != nominal.hash {
            anyhow::bail!(
                "{} was written for another nominal vehicle (--vehicle, --plant)",
                eval_path.display()
            );
        }
        if e.profile != setup.profile_name() {
            anyhow::bail!(
                "{} was written with the bus of profile {}, not {}",
                eval_path.display(),
                e.profile.as_deref().unwrap_or("(reference)"),
                setup.profile_name().as_deref().unwrap_or("(reference)")
            );
        }
        if e.sensor_noise_factor != args.sensor_noise_factor {
            anyhow::bail!(
                "{} is for --sensor-noise-factor {}, not {}",
                eval_path.display(),
                e.sensor_noise_factor,
                args.sensor_noise_factor
            );
        }
        if e.stiffness_damping_rel.is_some()
            && e.stiffness_damping_rel != args.stiffness_damping_rel
        {
            anyhow::bail!(
                "{} is for --stiffness-damping-rel {:?}, not {:?}",
                eval_path.display(),
                e.stiffness_damping_rel,
                args.stiffness_damping_rel
            );
        }
        if e.pre_brake != args.pre_brake {
            anyhow::bail!(
                "{} is for --pre-brake {}, not {}",
                eval_path.display(),
                e.pre_brake,
                args.pre_brake
            );
        }
        if e.replicate != args.replicate {
            anyhow::bail!(
                "{} is for --replicate {}, not {}",
                eval_path.display(),
                e.replicate,
                args.replicate
            );
        }
        if e.seed != seed || e.events != args.events {
            anyhow::bail!(
                "{} is for seed {} with {} events, not seed {seed} with {}",
                eval_path.display(),
                e.seed,
                e.events,
                args.events
            );
        }
        return Ok((log, e));
    }
    let (p, noise, events) = (plan.params, plan.road_noise_nm, plan.events);
    let vfile = dir.join(format!("vehicle_{seed}.toml"));
    std::fs::write(&vfile, toml::to_string(&p)?)?;
    let noise_seed = replicate_seed(seed, args.replicate);
    let text = vehicle_scenario(
        noise_seed,
        c_mm,
        &format!("vehicle_{seed}.toml"),
        p.excitation.unbalance_kgm,
        noise,
        args.phase_change == "per-stop",
        &events,
        &if args.pre_brake == "varied" {
            varied_pre_brake(seed, events.len())
        } else {
            Vec::new()
        },
    );
    let text = text + &sensors_section(args.sensor_noise_factor);
    // With the §15 column, the driver's hands are drawn per leg (so per braking event).
    let text = match (&setup.prior.hands, p.column.enabled) {
        (Some(h), true) => text + &hands_section(h)?,
        _ => text,
    };
    let sc_path = dir.join(format!("fleet_{seed}.toml"));
    std::fs::write(&sc_path, &text)?;
    let sc = Scenario::parse(&text, &sc_path.display().to_string())?;
    let mut plant = ModelPlant::new(&sc, Some(&vfile))?;
    if noise_seed != seed {
        // The vehicle's wheels keep the unbalance phases its own seed draws (MODEL.md §7).
        let phases = shimmy::model::excitation::Excitation::phases_of(seed);
        plant.set_unbalance_phases(phases);
    }
    let mut sim = FirmwareSim::with_bus(
        &sc,
        plant,
        setup.db.clone(),
        &setup.bus,
        RunInfo {
            scenario_file: Some(sc_path.display().to_string()),
            vehicle_file: Some(vfile.display().to_string()),
            profile: setup.profile_name(),
        },
    )?;
    sim.set_iface("vcan0");
    let log = dir.join(format!("fleet_{seed}.log"));
    {
        let mut w = BufWriter::new(std::fs::File::create(&log)?);
        for f in sim.by_ref() {
            shimmy::wire::candump::write_frame(&mut w, &f)?;
        }
        w.flush()?;
    }
    let truth = sim.ground_truth();
    std::fs::write(log.with_extension("truth.json"), truth.to_json())?;
    let eval = EvalTruth {
        seed,
        events: args.events,
        clearance_true_mm: c_mm,
        phase_change: args.phase_change.clone(),
        pre_brake: args.pre_brake.clone(),
        sensor_noise_factor: args.sensor_noise_factor,
        stiffness_damping_rel: args.stiffness_damping_rel,
        replicate: args.replicate,
        nominal_vehicle_hash: nominal.hash.clone(),
        profile: setup.profile_name(),
        sw_amplitudes_55_deg: truth
            .events
            .iter()
            .filter(|e| (50.0..=60.0).contains(&e.event.v0_kmh))
            .map(|e| e.sw_amplitude_deg)
            .collect(),
        events_true: truth.events.len(),
    };
    std::fs::write(&eval_path, serde_json::to_string(&eval)?)?;
    Ok((log, eval))
}

fn one_vehicle(
    k: usize,
    args: &FleetArgs,
    setup: &Setup,
    dir: &Path,
    tables: &Tables,
    cfg: &ObserverConfig,
) -> anyhow::Result<VehicleResult> {
    let t0 = Instant::now();
    let seed = args.seed_base + k as u64;
    let (log, eval) = vehicle_log(k, args, setup, dir)?;
    let c_mm = eval.clearance_true_mm;
    let baseline = args.baseline_dir.as_ref().map(|d| BaselineLogs {
        logs: vec![d.join(format!("fleet_{seed}.log"))],
        clearance_mm: args.baseline_clearance_mm,
    });
    let (report, _) = estimate_files_with(
        &setup.mapping,
        setup.dbc_path.as_deref(),
        tables.clone(),
        cfg.clone(),
        baseline.as_ref(),
        std::slice::from_ref(&log),
    )
    .with_context(|| format!("estimating {}", log.display()))?;
    if args.work_dir.is_none() {
        let _ = std::fs::remove_file(&log);
    }
    Ok(result(
        k,
        seed,
        c_mm,
        &report,
        &eval.sw_amplitudes_55_deg,
        eval.events_true,
        t0,
    ))
}

fn result(
    k: usize,
    seed: u64,
    c_mm: f64,
    r: &Estimation,
    amps: &[f64],
    n_true: usize,
    t0: Instant,
) -> VehicleResult {
    VehicleResult {
        index: k,
        seed,
        clearance_true_mm: c_mm,
        clearance_mm: r.clearance_mm,
        median_mm: r.median_mm,
        interval_mm: r.interval_mm,
        detectable: r.detectable,
        below_mm: r.below_mm,
        clearance_alert: r.alerts.iter().any(|a| a.kind == Kind::Clearance),
        clearance_alerts_raised: r.alert_counts.clearance_raised,
        p_clearance_above_threshold: r.p_clearance_above_threshold,
        p_wheel_phase_fixed: r.p_wheel_phase_fixed,
        model_fit: r.model_fit,
        verdict: r.verdict.clone(),
        shimmy_alert: r.alerts.iter().any(|a| a.kind == Kind::Shimmy55),
        events_55: amps.len(),
        true_sw_55_deg: if amps.is_empty() {
            None
        } else {
            Some(amps.iter().sum::<f64>() / amps.len() as f64)
        },
        events_true: n_true,
        events_recorded: r.events.len(),
        events_used: r.events_used,
        signals: r.signals,
        torque_table: chosen_table(&r.torque_tables),
        torque_tables: r.torque_tables.clone(),
        angle_table: chosen_table(&r.angle_tables),
        angle_tables: r.angle_tables.clone(),
        seconds: t0.elapsed().as_secs_f64(),
    }
}

/// The name of the table a report's estimate was read mostly with, among `tables` (its
/// `torque_tables` or `angle_tables`); `None` without chassis variants.
fn chosen_table(tables: &[shimmy::observer::TableEvidence]) -> Option<String> {
    tables.iter().find(|t| t.chosen).map(|t| t.name.clone())
}

/// The issue-5 scores of a fleet.
#[derive(Clone, Debug, Serialize)]
pub struct Scores {
    pub vehicles: usize,
    /// Alert raised / vehicles with c ≥ 0.15 mm (target ≥ 0.95).
    pub alert_rate_worn: (usize, usize),
    /// Alert raised / vehicles with c ≤ 0.07 mm (target ≤ 0.05).
    pub alert_rate_new: (usize, usize),
    /// Alert raised / vehicles with 0.07 < c < 0.1 mm (the mismatch fleets' target ≤ 0.25).
    pub alert_rate_band: (usize, usize),
    /// With torque tables of chassis variants: vehicles read with each table, by name.
    #[serde(skip_serializing_if = "std::collections::BTreeMap::is_empty")]
    pub torque_tables: std::collections::BTreeMap<String, usize>,
    /// With angle tables of chassis variants: vehicles read with each, by name (the angle's
    /// choice, whichever signal the estimate came from).
    #[serde(skip_serializing_if = "std::collections::BTreeMap::is_empty")]
    pub angle_tables: std::collections::BTreeMap<String, usize>,
    /// Mean |median − c| over vehicles with c ≥ 0.1 mm (target ≤ 0.03 mm on the column fleets; the earlier 0.02 mm is retired, docs/ACCURACY.md).
    pub mae_mm_above_0p1: f64,
    /// Interval contains c / all vehicles (target 0.85–0.95).
    pub coverage: (usize, usize),
    /// Vehicles with c < 0.08 reported "below X" with X ≥ c, or with an interval containing c.
    pub small_ok: (usize, usize),
    /// shimmy_55kmh alert agrees with the truth / vehicles with true mean amplitude at
    /// 50–60 km/h above 0.25° or below 0.15° and at least `shimmy_confirm` events there.
    pub shimmy_agree: (usize, usize),
    /// Vehicles above 0.25° or below 0.15° left out of `shimmy_agree` because they braked
    /// fewer than `shimmy_confirm` times at 50–60 km/h: the issue's "confirmed by at least 2
    /// of the last 5 such events" cannot raise the alert on them. (above 0.25°, below 0.15°)
    pub shimmy_too_few_events: (usize, usize),
    /// The estimator said the model does not fit / vehicles with a fit check.
    pub not_fitting: (usize, usize),
    /// Of the vehicles whose interval misses the truth: said "does not fit" / all of them.
    pub misses_flagged: (usize, usize),
    /// Vehicles whose clearance alert came and went (raised more often than it stands at the
    /// end: raised and cleared, or raised again after clearing) / all vehicles.
    pub clearance_alert_churn: (usize, usize),
}

/// The scores of a fleet; `shimmy_confirm` is the alert rule's confirmation count.
pub fn scores(v: &[VehicleResult], shimmy_confirm: usize) -> Scores {
    let count = |f: &dyn Fn(&VehicleResult) -> Option<bool>| {
        let mut n = 0;
        let mut ok = 0;
        for r in v {
            if let Some(b) = f(r) {
                n += 1;
                ok += b as usize;
            }
        }
        (ok, n)
    };
    let worn = count(&|r| (r.clearance_true_mm >= 0.15).then_some(r.clearance_alert));
    let new = count(&|r| (r.clearance_true_mm <= 0.07).then_some(r.clearance_alert));
    let band = count(&|r| {
        (r.clearance_true_mm > 0.07 && r.clearance_true_mm < 0.1).then_some(r.clearance_alert)
    });
    let by_name = |table: fn(&VehicleResult) -> &Option<String>| {
        let mut n = std::collections::BTreeMap::new();
        for t in v.iter().filter_map(|r| table(r).as_ref()) {
            *n.entry(t.clone()).or_insert(0) += 1;
        }
        n
    };
    let torque_tables = by_name(|r| &r.torque_table);
    let angle_tables = by_name(|r| &r.angle_table);
    let big: Vec<f64> = v
        .iter()
        .filter(|r| r.clearance_true_mm >= 0.1)
        .filter_map(|r| r.median_mm.map(|m| (m - r.clearance_true_mm).abs()))
        .collect();
    let inside = |r: &VehicleResult| {
        r.interval_mm
            .is_some_and(|[a, b]| a <= r.clearance_true_mm && r.clearance_true_mm <= b)
    };
    let coverage = count(&|r| Some(inside(r)));
    let not_fitting = count(&|r| r.model_fit.map(|f| !f.fits));
    let misses_flagged = count(&|r| {
        (r.interval_mm.is_some() && !inside(r)).then(|| r.model_fit.is_some_and(|f| !f.fits))
    });
    let small_ok = count(&|r| {
        (r.clearance_true_mm < 0.08).then(|| {
            inside(r) || (!r.detectable && r.below_mm.is_some_and(|b| b >= r.clearance_true_mm))
        })
    });
    let churn = count(&|r| Some(r.clearance_alerts_raised > u32::from(r.clearance_alert)));
    let judged = |r: &VehicleResult| r.events_55 >= shimmy_confirm;
    let shimmy_agree = count(&|r| match r.true_sw_55_deg {
        Some(a) if a > 0.25 && judged(r) => Some(r.shimmy_alert),
        Some(a) if a < 0.15 && judged(r) => Some(!r.shimmy_alert),
        _ => None,
    });
    let too_few = |above: bool| {
        v.iter()
            .filter(|r| !judged(r))
            .filter(|r| {
                r.true_sw_55_deg
                    .is_some_and(|a| if above { a > 0.25 } else { a < 0.15 })
            })
            .count()
    };
    let shimmy_too_few_events = (too_few(true), too_few(false));
    Scores {
        vehicles: v.len(),
        alert_rate_worn: worn,
        alert_rate_new: new,
        alert_rate_band: band,
        torque_tables,
        angle_tables,
        mae_mm_above_0p1: if big.is_empty() {
            f64::NAN
        } else {
            big.iter().sum::<f64>() / big.len() as f64
        },
        coverage,
        small_ok,
        shimmy_agree,
        shimmy_too_few_events,
        not_fitting,
        misses_flagged,
        clearance_alert_churn: churn,
    }
}

fn frac((a, b): (usize, usize)) -> String {
    if b == 0 {
        "n/a (no vehicles)".into()
    } else {
        format!("{a}/{b} = {:.0} %", 100.0 * a as f64 / b as f64)
    }
}

pub fn run(args: FleetArgs) -> anyhow::Result<()> {
    if let Some(c) = args.clearance_mm {
        if !(c.is_finite() && c > 0.0 && c <= 2.0) {
            anyhow::bail!("--clearance-mm must be in (0, 2] mm, not {c}");
        }
    }
    let f = args.sensor_noise_factor;
    if !(f.is_finite() && (0.0..=100.0).contains(&f)) {
        anyhow::bail!("--sensor-noise-factor must be in [0, 100], not {f}");
    }
    let setup = Setup::load(&args)?;
    let table = match (&args.table, &setup.profile) {
        (Some(t), _) => ResponseTable::load(t)?,
        (None, Some(p)) => p.load_table()?.with_context(|| {
            format!(
                "profile {} names no table; give --table FILE or build it with `shimmy \
                 calibrate --profile {}`",
                p.name, p.name
            )
        })?,
        (None, None) => anyhow::bail!("give --table FILE, or --profile NAME to use its table"),
    };
    let nominal = &setup.nominal;
    table
        .check_vehicle(&nominal.hash)
        .with_context(|| match (&args.vehicle, &setup.profile) {
            (Some(p), _) => format!("the fleet's nominal vehicle is {}", p.display()),
            (None, Some(p)) => format!(
                "the fleet's nominal vehicle is profile {}'s chassis ({})",
                p.name, p.vehicle_source
            ),
            (None, None) => "the fleet's nominal vehicle is MODEL.md §9 (--vehicle)".into(),
        })?;
    let torque = match (&args.torque_table, &setup.profile) {
        _ if args.angle_only => None,
        (Some(p), _) => {
            let t = ResponseTable::load(p)?;
            // As --table: built for the nominal vehicle (with its column), whatever the prior.
            t.check_torque_vehicle(&nominal.params)
                .with_context(|| format!("torque table {}", p.display()))?;
            Some(t)
        }
        (None, Some(p)) => p.load_torque_table()?,
        (None, None) => None,
    };
    if let Some(t) = &torque {
        eprintln!(
            "fleet: torque table at {} Hz: events with a live steering torque are estimated \
             from it",
            t.sensor.rate_hz
        );
    }
    // The profile's chassis variants ride with its own tables only: a table given is read alone.
    let torque_alternatives = match (&args.torque_table, &setup.profile, &torque) {
        (None, Some(p), Some(t)) => p.load_torque_alternatives(t, None)?,
        _ => Vec::new(),
    };
    if !torque_alternatives.is_empty() {
        eprintln!(
            "fleet: torque tables of the profile's chassis variants beside the nominal one: {} \
             (each vehicle's estimate weighs them by how well its events fit each)",
            shimmy::observer::Alternative::names(&torque_alternatives)
        );
    }
    let angle_alternatives = match (&args.table, &setup.profile) {
        (None, Some(p)) => p.load_angle_alternatives(&table, None)?,
        _ => Vec::new(),
    };
    if !angle_alternatives.is_empty() {
        eprintln!(
            "fleet: angle tables of the profile's chassis variants beside the nominal one: {} \
             (while an estimate comes from the angle it weighs them by how well its events fit \
             each)",
            shimmy::observer::Alternative::names(&angle_alternatives)
        );
    }
    let tables = Tables {
        angle: Some(table),
        torque,
        torque_alternatives,
        angle_alternatives,
    };
    let cfg = match &args.config {
        Some(p) => ObserverConfig::load(p)?,
        None => ObserverConfig::default(),
    };
    let tmp;
    let dir = match &args.work_dir {
        Some(d) => {
            std::fs::create_dir_all(d)?;
            d.clone()
        }
        None => {
            tmp = std::env::temp_dir().join(format!("firmware-sim-fleet-{}", std::process::id()));
            std::fs::create_dir_all(&tmp)?;
            tmp.clone()
        }
    };
    let threads = args.threads.unwrap_or_else(default_threads);
    let t0 = Instant::now();
    let ks: Vec<usize> = (0..args.vehicles).collect();
    if args.logs_only {
        let done = par_map(&ks, threads, |&k| {
            let r = vehicle_log(k, &args, &setup, &dir);
            if r.is_ok() {
                eprintln!("vehicle {k:>3}: log written");
            }
            r
        });
        for (k, r) in done.into_iter().enumerate() {
            r.with_context(|| format!("fleet vehicle {k}"))?;
        }
        println!(
            "fleet: {} vehicle logs x {} events, seed base {}, in {} ({:.0} s); no estimation (--logs-only)",
            args.vehicles,
            args.events,
            args.seed_base,
            dir.display(),
            t0.elapsed().as_secs_f64()
        );
        return Ok(());
    }
    let results = par_map(&ks, threads, |&k| {
        let r = one_vehicle(k, &args, &setup, &dir, &tables, &cfg);
        if let Ok(v) = &r {
            eprintln!(
                "vehicle {:>3}: c = {:.3} mm -> {} [{}] alerts: clearance {} shimmy {} ({} events used, {:.0} s)",
                v.index,
                v.clearance_true_mm,
                v.median_mm.map_or("-".into(), |m| format!("{m:.3}")),
                v.interval_mm.map_or("-".into(), |[a, b]| format!("{a:.3}-{b:.3}")),
                v.clearance_alert,
                v.shimmy_alert,
                v.events_used,
                v.seconds
            );
        }
        r
    });
    let mut ok = Vec::new();
    for (k, r) in results.into_iter().enumerate() {
        ok.push(r.with_context(|| format!("fleet vehicle {k}"))?);
    }
    if args.work_dir.is_none() {
        let _ = std::fs::remove_dir_all(&dir);
    }
    let s = scores(&ok, cfg.alerts.shimmy_confirm);
    if let Some(p) = &args.json {
        std::fs::write(
            p,
            serde_json::to_string_pretty(&serde_json::json!({"scores": s, "vehicles": ok}))?,
        )?;
    }
    println!(
        "fleet: {} vehicles x {} events, seed base {}, {:.0} s",
        s.vehicles,
        args.events,
        args.seed_base,
        t0.elapsed().as_secs_f64()
    );
    println!(
        "clearance alert, c >= 0.15 mm (target >= 95 %): {}",
        frac(s.alert_rate_worn)
    );
    println!(
        "clearance alert, c <= 0.07 mm (target <= 5 %):  {}",
        frac(s.alert_rate_new)
    );
    println!(
        "clearance alert, 0.07 < c < 0.1 mm (mismatch target <= 25 %): {}",
        frac(s.alert_rate_band)
    );
    for (signal, tables) in [("torque", &s.torque_tables), ("angle", &s.angle_tables)] {
        if !tables.is_empty() {
            println!(
                "most probable {signal} table: {}",
                tables
                    .iter()
                    .map(|(n, k)| format!("{n} {k}"))
                    .collect::<Vec<_>>()
                    .join(", ")
            );
        }
    }
    println!(
        "mean absolute error, c >= 0.1 mm (target <= 0.030 mm): {:.3} mm",
        s.mae_mm_above_0p1
    );
    println!(
        "90 % interval contains truth (target 85-95 %): {}",
        frac(s.coverage)
    );
    println!(
        "c < 0.08 mm reported below / interval contains truth: {}",
        frac(s.small_ok)
    );
    println!(
        "model does not fit (goodness-of-fit check): {}; of the intervals that miss: {}",
        frac(s.not_fitting),
        frac(s.misses_flagged)
    );
    println!(
        "clearance alert came and went (raised, later cleared or raised again): {}",
        frac(s.clearance_alert_churn)
    );
    println!(
        "shimmy_55kmh agrees with truth (>0.25 or <0.15 deg): {}",
        frac(s.shimmy_agree)
    );
    let (up, down) = s.shimmy_too_few_events;
    if up + down > 0 {
        println!(
            "  not judged: {} vehicle(s) with fewer than {} braking events at 50-60 km/h \
             ({up} above 0.25 deg, {down} below 0.15 deg; the alert needs {} of the last {})",
            up + down,
            cfg.alerts.shimmy_confirm,
            cfg.alerts.shimmy_confirm,
            cfg.alerts.shimmy_window
        );
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;
    use shimmy::cli::estimate::estimate_files;

    #[test]
    fn a_vehicle_plan_is_fixed_by_its_seed_and_within_the_issue_ranges() {
        let a = vehicle_plan(12345, 30);
        let b = vehicle_plan(12345, 30);
        assert_eq!(a.events, b.events);
        assert_eq!(a.clearance_mm, b.clearance_mm);
        assert!((0.03..=0.4).contains(&a.clearance_mm));
        assert!(a
            .events
            .iter()
            .all(|&(v, d)| (30.0..=100.0).contains(&v) && (0.3..=0.8).contains(&d)));
        assert_ne!(vehicle_plan(12346, 30).events, a.events);
    }

    #[test]
    fn generated_scenarios_parse() {
        let t = vehicle_scenario(
            3,
            0.1,
            "v.toml",
            2e-3,
            0.2,
            false,
            &[(55.0, 0.5), (80.0, 0.3)],
            &[],
        );
        let sc = Scenario::parse(&t, "test").unwrap();
        assert_eq!(sc.drive.segments.len(), 4);
    }

    #[test]
    fn varied_pre_brake_draws_each_situation_for_about_half_the_events() {
        let n = 400;
        let p = varied_pre_brake(77, n);
        assert_eq!(p, varied_pre_brake(77, n));
        assert_ne!(p, varied_pre_brake(78, n));
        let share =
            |f: &dyn Fn(&PreBrake) -> bool| p.iter().filter(|x| f(x)).count() as f64 / n as f64;
        for (name, s) in [
            ("coast", share(&|x| x.coast.is_some())),
            ("road", share(&|x| x.road_noise_scale != 1.0)),
            ("curve", share(&|x| x.turn_deg != 0.0)),
        ] {
            assert!((0.4..0.6).contains(&s), "{name}: {s}");
        }
        assert!(p.iter().all(|x| {
            x.coast
                .is_none_or(|(d, g)| (1.5..=3.0).contains(&d) && (0.03..=0.12).contains(&g))
                && (0.5..=2.0).contains(&x.road_noise_scale)
                && (x.turn_deg == 0.0 || (3.0..=10.0).contains(&x.turn_deg.abs()))
        }));
        // Left and right curves.
        assert!(p.iter().any(|x| x.turn_deg > 0.0) && p.iter().any(|x| x.turn_deg < 0.0));
        // Every draw makes a scenario that parses, one segment more per coast.
        let events: Vec<(f64, f64)> = (0..n).map(|_| (60.0, 0.5)).collect();
        let t = vehicle_scenario(3, 0.1, "v.toml", 2e-3, 0.2, false, &events, &p);
        let sc = Scenario::parse(&t, "test").unwrap();
        let coasts = p.iter().filter(|x| x.coast.is_some()).count();
        assert_eq!(sc.drive.segments.len(), 2 * n + coasts);
    }

    #[test]
    fn the_sensor_noise_factor_scales_the_steering_sensors_only() {
        assert_eq!(sensors_section(1.0), "");
        let base = "seed = 1\n[clearance]\nleft_mm = 0.1\n[drive]\nstart_speed_kmh = 50\n\
                    [[drive.segment]]\nkind = \"cruise\"\nspeed_kmh = 50\nduration_s = 1\n";
        let sc = Scenario::parse(&format!("{base}{}", sensors_section(3.0)), "t").unwrap();
        let d = crate::scenario::Sensors::default();
        assert!((sc.sensors.steer_noise_deg - 3.0 * d.steer_noise_deg).abs() < 1e-12);
        assert!((sc.sensors.steer_torque_noise_nm - 3.0 * d.steer_torque_noise_nm).abs() < 1e-12);
        assert_eq!(sc.sensors.wheel_speed_noise_kmh, d.wheel_speed_noise_kmh);
    }

    fn args(extra: &[&str], dir: &Path) -> FleetArgs {
        use clap::Parser;
        let mut a = vec![
            "fleet",
            "--table",
            "unused.json",
            "--vehicles",
            "1",
            "--events",
            "1",
        ];
        a.extend_from_slice(&["--seed-base", "4242", "--work-dir", dir.to_str().unwrap()]);
        a.extend_from_slice(extra);
        FleetArgs::parse_from(a)
    }

    /// Vehicle 0's log as `run` writes it: the nominal vehicle read from `args`, then the log.
    fn log0(args: &FleetArgs, dir: &Path) -> anyhow::Result<(PathBuf, EvalTruth)> {
        vehicle_log(0, args, &Setup::load(args)?, dir)
    }

    /// Vehicle 0 of seed 4242 as drawn (in `base/a`) and with `extra` options (in `base/b`):
    /// (base, [(dir, log, truth); 2]).
    fn drawn_and(tag: &str, extra: &[&str]) -> (PathBuf, [(PathBuf, PathBuf, EvalTruth); 2]) {
        let base = std::env::temp_dir().join(format!("fleet-{tag}-{}", std::process::id()));
        let run = |sub: &str, opts: &[&str]| {
            let d = base.join(sub);
            std::fs::create_dir_all(&d).unwrap();
            let (log, e) = log0(&args(opts, &d), &d).unwrap();
            (d, log, e)
        };
        let a = run("a", &[]);
        let b = run("b", extra);
        (base, [a, b])
    }

    /// `--clearance-mm` makes a twin: the same vehicle (nuisances) and the same drive as the
    /// drawn fleet, with only the joints changed.
    #[test]
    fn a_twin_vehicle_differs_only_in_its_clearance() {
        let (base, [(da, _, ea), (db, _, eb)]) = drawn_and("twin", &["--clearance-mm", "0.25"]);
        assert_eq!(ea.clearance_true_mm, vehicle_plan(4242, 1).clearance_mm);
        assert_eq!(eb.clearance_true_mm, 0.25);
        let read = |d: &Path, f: &str| std::fs::read_to_string(d.join(f)).unwrap();
        assert_eq!(
            read(&da, "vehicle_4242.toml"),
            read(&db, "vehicle_4242.toml")
        );
        let (sa, sb) = (read(&da, "fleet_4242.toml"), read(&db, "fleet_4242.toml"));
        assert_ne!(sa, sb);
        fn strip(s: &str) -> Vec<&str> {
            s.lines().filter(|l| !l.starts_with("left_mm")).collect()
        }
        assert_eq!(strip(&sa), strip(&sb));
        // --reuse refuses a log made for another clearance.
        let e = log0(&args(&["--clearance-mm", "0.3", "--reuse"], &db), &db).unwrap_err();
        assert!(e.to_string().contains("not --clearance-mm 0.3"), "{e}");
        let e = log0(&args(&["--reuse"], &db), &db).unwrap_err();
        assert!(e.to_string().contains("(a --clearance-mm twin?)"), "{e}");
        std::fs::remove_dir_all(&base).unwrap();
    }

    /// `--vehicle` draws the same nuisances around another nominal vehicle (here one with the
    /// MODEL.md §15 column), writes that vehicle's file, and --reuse tells the two apart.
    #[test]
    fn a_fleet_around_another_vehicle_keeps_the_draws_and_the_vehicle() {
        let base = std::env::temp_dir().join(format!("fleet-nominal-{}", std::process::id()));
        std::fs::create_dir_all(&base).unwrap();
        let mut col = VehicleParams::default();
        col.column.enabled = true;
        let vfile = base.join("col.toml");
        std::fs::write(&vfile, toml::to_string(&col).unwrap()).unwrap();
        let a = vehicle_plan(4242, 3);
        let b = vehicle_plan_around(&col, 4242, 3);
        assert_eq!((a.clearance_mm, &a.events), (b.clearance_mm, &b.events));
        assert_eq!(
            a.params.steering.kingpin_damping_nms_per_rad,
            b.params.steering.kingpin_damping_nms_per_rad
        );
        assert!(b.params.column.enabled && !a.params.column.enabled);

        let d = base.join("run");
        std::fs::create_dir_all(&d).unwrap();
        let opts = ["--vehicle", vfile.to_str().unwrap()];
        let (_, e) = log0(&args(&opts, &d), &d).unwrap();
        assert_eq!(e.nominal_vehicle_hash, vehicle_hash(&col).unwrap());
        let written = VehicleParams::from_toml_file(d.join("vehicle_4242.toml")).unwrap();
        assert!(written.column.enabled);
        // The same log is not reused for the default vehicle, but is for its own.
        let e = log0(&args(&["--reuse"], &d), &d).unwrap_err();
        assert!(e.to_string().contains("another nominal vehicle"), "{e}");
        let mut again = opts.to_vec();
        again.push("--reuse");
        log0(&args(&again, &d), &d).unwrap();
        // A missing file is a clear error.
        let bad = ["--vehicle", "/nonexistent/vehicle.toml"];
        let e = log0(&args(&bad, &d), &d).unwrap_err();
        assert!(
            format!("{e:#}").contains("--vehicle /nonexistent/vehicle.toml"),
            "{e:#}"
        );
        std::fs::remove_dir_all(&base).unwrap();
    }

    /// A fleet around a vehicle with the §15 column draws the driver's hands per braking event
    /// and records them in the truth sidecar, inside the documented ranges; a 5-DOF fleet
    /// records none.
    #[test]
    fn a_column_fleet_records_the_hands_of_every_event() {
        let base = std::env::temp_dir().join(format!("fleet-hands-{}", std::process::id()));
        let d = base.join("col");
        std::fs::create_dir_all(&d).unwrap();
        let mut col = VehicleParams::default();
        col.column.enabled = true;
        let vfile = base.join("col.toml");
        std::fs::write(&vfile, toml::to_string(&col).unwrap()).unwrap();
        let mut a = args(&["--vehicle", vfile.to_str().unwrap()], &d);
        a.events = 6;
        let (log, e) = log0(&a, &d).unwrap();
        assert_eq!(e.events_true, 6);
        let truth: serde_json::Value = serde_json::from_str(
            &std::fs::read_to_string(log.with_extension("truth.json")).unwrap(),
        )
        .unwrap();
        let prior = HandsPrior::default();
        let mut states = Vec::new();
        for ev in truth["events"].as_array().unwrap() {
            let h = &ev["hands"];
            let state: shimmy::observer::simulate::HandsState =
                serde_json::from_value(h["state"].clone()).unwrap();
            let r = prior.range(state);
            for (key, (lo, hi)) in [
                ("inertia_kgm2", r.inertia_kgm2),
                ("stiffness_nm_per_rad", r.stiffness_nm_per_rad),
                ("damping_nms_per_rad", r.damping_nms_per_rad),
            ] {
                let v = h[key].as_f64().unwrap();
                assert!(
                    (lo..=hi).contains(&v),
                    "{state:?} {key} = {v} outside [{lo}, {hi}]"
                );
            }
            states.push((state, h["damping_nms_per_rad"].as_f64().unwrap()));
        }
        assert_eq!(states.len(), 6);
        // A new draw per event, not one for the whole drive.
        assert!(states.windows(2).any(|w| w[0] != w[1]), "{states:?}");
        // The vehicle's column itself was drawn within the published ranges.
        let v = VehicleParams::from_toml_file(d.join("vehicle_4242.toml")).unwrap();
        let cr = shimmy::observer::simulate::ColumnRanges::PUBLISHED;
        assert!((cr.inertia_kgm2.0..=cr.inertia_kgm2.1).contains(&v.column.inertia_kgm2));
        assert_ne!(
            v.column.torsion_bar_nm_per_rad,
            col.column.torsion_bar_nm_per_rad
        );

        // 5-DOF: no hands anywhere in the truth.
        let d5 = base.join("5dof");
        std::fs::create_dir_all(&d5).unwrap();
        let mut a5 = args(&[], &d5);
        a5.events = 2;
        let (log5, _) = log0(&a5, &d5).unwrap();
        let t5 = std::fs::read_to_string(log5.with_extension("truth.json")).unwrap();
        assert!(!t5.contains("\"hands\""));
        std::fs::remove_dir_all(&base).unwrap();
    }

    /// `--replicate 1` drives the same vehicle again: vehicle file, plan, clearance and wheel
    /// phases are the seed's; only the noise seed (and so the frames) differ.
    #[test]
    fn a_replicate_keeps_the_vehicle_and_redraws_only_the_noise() {
        let (base, [(da, la, ea), (db, lb, eb)]) = drawn_and("rep", &["--replicate", "1"]);
        assert_eq!(ea.clearance_true_mm, eb.clearance_true_mm);
        assert_eq!((ea.replicate, eb.replicate), (0, 1));
        let read = |d: &Path, f: &str| std::fs::read_to_string(d.join(f)).unwrap();
        assert_eq!(
            read(&da, "vehicle_4242.toml"),
            read(&db, "vehicle_4242.toml")
        );
        let (sa, sb) = (read(&da, "fleet_4242.toml"), read(&db, "fleet_4242.toml"));
        fn strip(s: &str) -> Vec<&str> {
            s.lines()
                .filter(|l| !l.starts_with("seed") && !l.starts_with("name"))
                .collect()
        }
        assert_ne!(sa, sb);
        assert_eq!(strip(&sa), strip(&sb));
        assert!(sb.contains(&format!("seed = {}", replicate_seed(4242, 1))));
        assert_ne!(std::fs::read(&la).unwrap(), std::fs::read(&lb).unwrap());
        let phase = |d: &Path| -> Vec<f64> {
            let t: serde_json::Value =
                serde_json::from_str(&read(d, "fleet_4242.truth.json")).unwrap();
            t["events"]
                .as_array()
                .unwrap()
                .iter()
                .map(|e| e["unbalance_phase_cos"].as_f64().unwrap())
                .collect()
        };
        assert_eq!(phase(&da), phase(&db));
        // A replicate seed is none of the first million seeds, and --reuse tells replicates apart.
        assert!((1..50).all(|r| replicate_seed(4242, r) > 1 << 20));
        let e = log0(&args(&["--reuse"], &db), &db).unwrap_err();
        assert!(e.to_string().contains("not 0"), "{e}");
        std::fs::remove_dir_all(&base).unwrap();
    }

    /// `--dbc` puts another bus on the wire: with SAS_Angle in 0.01 deg steps the simulated
    /// sensor has that step, and the shipped table (built for 0.1 deg) refuses its events,
    /// counted and named, instead of comparing them with predictions for another sensor.
    #[test]
    fn a_bus_with_another_steering_sensor_is_not_scored_against_the_wrong_table() {
        let reference_dbc = crate::bus::REFERENCE_DBC;
        let fine = reference_dbc.replace(
            "SG_ SAS_Angle : 0|16@1- (0.1,0) [-3276.8|3276.7]",
            "SG_ SAS_Angle : 0|16@1- (0.01,0) [-327.68|327.67]",
        );
        assert_ne!(fine, reference_dbc);
        let base = std::env::temp_dir().join(format!("fleet-dbc-{}", std::process::id()));
        std::fs::create_dir_all(&base).unwrap();
        let dbc = base.join("fine.dbc");
        std::fs::write(&dbc, fine).unwrap();
        let (base, [(da, la, _), (db, lb, _)]) =
            drawn_and("dbc", &["--dbc", dbc.to_str().unwrap()]);
        let root = Path::new(env!("CARGO_MANIFEST_DIR")).join("..");
        let table =
            ResponseTable::load(&root.join("config/vehicles/shimmy_reference/table.json")).unwrap();
        let estimate = |log: &Path, dbc: Option<&Path>| {
            estimate_files(
                &root.join("config/vehicles/shimmy_reference/mapping.toml"),
                dbc,
                Some(table.clone()),
                ObserverConfig::default(),
                std::slice::from_ref(&log.to_path_buf()),
            )
            .unwrap()
            .0
        };
        let reference = estimate(&la, None);
        assert!(reference.events_used > 0, "{:?}", reference.verdict);
        assert_eq!(reference.events_sensor_mismatch, 0);
        let other = estimate(&lb, Some(&dbc));
        assert!(!other.events.is_empty());
        assert_eq!(other.events_used, 0);
        assert_eq!(other.events_sensor_mismatch, other.events.len() as u64);
        assert!(other.events.iter().all(|e| e.unused_reason
            == Some(shimmy::events::Unused::SensorMismatch)
            && (e.quant_step_deg - 0.01).abs() < 1e-6));
        assert!(
            other.verdict.contains("--sensor-step-deg"),
            "{}",
            other.verdict
        );
        assert_eq!(other.clearance_mm, None);
        drop((da, db));
        std::fs::remove_dir_all(&base).unwrap();
    }

    #[test]
    fn an_impossible_twin_clearance_is_refused_before_any_work() {
        let d = std::env::temp_dir();
        let e = run(args(&["--clearance-mm=-1"], &d)).unwrap_err();
        assert!(
            e.to_string()
                .contains("--clearance-mm must be in (0, 2] mm"),
            "{e}"
        );
    }

    #[test]
    fn the_shimmy_score_leaves_out_vehicles_the_confirmation_rule_cannot_judge() {
        let v = |k: usize, amp: f64, n55: usize, alert: bool| VehicleResult {
            index: k,
            seed: k as u64,
            clearance_true_mm: 0.2,
            clearance_mm: Some(0.2),
            median_mm: Some(0.2),
            interval_mm: Some([0.15, 0.25]),
            detectable: true,
            below_mm: None,
            clearance_alert: true,
            clearance_alerts_raised: 1,
            p_clearance_above_threshold: Some(0.99),
            p_wheel_phase_fixed: None,
            model_fit: None,
            verdict: String::new(),
            shimmy_alert: alert,
            events_55: n55,
            true_sw_55_deg: Some(amp),
            events_true: 30,
            events_recorded: 30,
            events_used: 30,
            signals: None,
            torque_table: None,
            torque_tables: Vec::new(),
            angle_table: None,
            angle_tables: Vec::new(),
            seconds: 0.0,
        };
        let fleet = [
            v(0, 0.4, 3, true),  // judged, agrees
            v(1, 0.4, 1, false), // one event at 50-60 km/h: 2-of-5 cannot raise
            v(2, 0.1, 2, true),  // judged, disagrees
            v(3, 0.2, 4, false), // between 0.15 and 0.25 deg: not scored
        ];
        let s = scores(&fleet, 2);
        assert_eq!(s.shimmy_agree, (1, 2));
        assert_eq!(s.shimmy_too_few_events, (1, 0));
        // With a 1-of-5 rule every vehicle with an event is judged.
        let s = scores(&fleet, 1);
        assert_eq!(s.shimmy_agree, (1, 3));
        assert_eq!(s.shimmy_too_few_events, (0, 0));
    }

    /// The 0.07-0.1 mm band counts the vehicles strictly between the two limits, and the
    /// tables read are counted by name.
    #[test]
    fn the_band_score_and_the_tables_read_are_counted() {
        let v = |c: f64, alert: bool, table: Option<&str>| VehicleResult {
            index: 0,
            seed: 0,
            clearance_true_mm: c,
            clearance_mm: Some(c),
            median_mm: Some(c),
            interval_mm: Some([0.5 * c, 2.0 * c]),
            detectable: true,
            below_mm: None,
            clearance_alert: alert,
            clearance_alerts_raised: u32::from(alert),
            p_clearance_above_threshold: None,
            p_wheel_phase_fixed: None,
            model_fit: None,
            verdict: String::new(),
            shimmy_alert: false,
            events_55: 0,
            true_sw_55_deg: None,
            events_true: 30,
            events_recorded: 30,
            events_used: 30,
            signals: None,
            torque_table: table.map(str::to_string),
            torque_tables: Vec::new(),
            angle_table: None,
            angle_tables: Vec::new(),
            seconds: 0.0,
        };
        let fleet = [
            v(0.07, true, Some("nominal")), // c <= 0.07: not the band
            v(0.071, true, Some("scrub")),
            v(0.09, false, Some("scrub")),
            v(0.1, true, None), // c = 0.1: not the band
        ];
        let s = scores(&fleet, 2);
        assert_eq!(s.alert_rate_band, (1, 2));
        assert_eq!(s.alert_rate_new, (1, 1));
        assert_eq!(s.torque_tables.get("scrub"), Some(&2));
        assert_eq!(s.torque_tables.get("nominal"), Some(&1));
        assert_eq!(s.torque_tables.len(), 2);
        assert_eq!(
            s.clearance_alert_churn,
            (0, 4),
            "one raise each, all standing"
        );

        // An alert raised and cleared, and one raised twice that stands: both came and went.
        let mut fleet = fleet;
        fleet[2].clearance_alerts_raised = 1;
        fleet[3].clearance_alerts_raised = 2;
        assert_eq!(scores(&fleet, 2).clearance_alert_churn, (2, 4));
    }
}
