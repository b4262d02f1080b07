//! `shimmy fleet-fit`: a car model's correction to its profile's response tables, learned from
//! many of its vehicles' drives at new joints (src/observer/correction.rs has the physics and
//! the statistics). This module is the plumbing: each vehicle's logs through the same pipeline
//! as `shimmy estimate --baseline` (its used events), a cache that lets a stopped run resume,
//! the fit per steering signal, and the correction file.

use std::io::Write;
use std::path::{Path, PathBuf};

use anyhow::{bail, Context};
use serde::{Deserialize, Serialize};

use crate::cli::estimate::{baseline_and_noise_of, BaselineLogs};
use crate::observer::correction::{self, Correction, CorrectionFile, FitEvent};
use crate::observer::features::SteerSignal;
use crate::observer::table::ResponseTable;
use crate::observer::ObserverConfig;
use crate::pipeline::observer_stage::Evidence;
use crate::profile::Profile;

const TOOL: &str = "shimmy fleet-fit";

/// Fit a car model's correction to its response tables from many vehicles at new joints.
///
/// The response tables come from the shimmy model; a real car model's signal may read stronger
/// or weaker than the model's for the same wheel motion (a steering ratio or column transfer the
/// table does not have, a torque sensor's N·m per count off). One vehicle cannot tell that
/// from a clearance; many vehicles of the car model at a known clearance can: their drives with
/// new joints (the car's first drives, or the first after a joint replacement). This command
/// reads each VEHICLE's drives through the same pipeline as `shimmy estimate --baseline`, pools
/// their braking events and fits, per steering signal the profile has a table of (angle,
/// torsion-bar torque), a gain per feature (braking RMS, peak, cruise RMS), its standard error
/// and the vehicles' spread about it (src/observer/correction.rs).
///
/// Output: a TOML file (--out) with one section per signal. Name it in the profile's
/// profile.toml as `correction = "correction.toml"`: every estimate from the profile (shimmy
/// estimate, shimmyd, export, the Python package, firmware-sim fleet) then divides the features
/// by the gains and widens its intervals by the correction's uncertainty. A correction names the
/// table it was fitted against and is refused with another.
///
/// Each VEHICLE is one vehicle: a log file, or a directory whose files are all that vehicle's
/// logs (read in name order). Vehicles without a usable braking event are skipped and counted.
/// The events read are kept in --events-cache as they come (one JSON line per vehicle), so a
/// run stopped half-way resumes where it was; a vehicle is read again when its files changed.
///
/// Assumes the drives' joints are new (--clearance-mm, default 0.03 mm; new joints sit at about
/// 0.02–0.06 mm): a fleet whose "new" joints are worn learns a gain that hides the wear.
#[derive(clap::Args, Debug)]
#[command(verbatim_doc_comment)]
pub struct Args {
    /// The car model's profile (config/vehicles/<NAME>, or a profile folder).
    #[arg(long)]
    pub profile: String,
    /// One vehicle's drives at new joints per argument: a log file or a directory of its logs.
    #[arg(required = true, value_name = "VEHICLE")]
    pub vehicles: Vec<PathBuf>,
    /// The joints' clearance during the drives (mm).
    #[arg(long, default_value_t = 0.03)]
    pub clearance_mm: f64,
    /// Observer settings (config/observer.toml); the estimator's settings must be the ones the
    /// correction will be used with.
    #[arg(long)]
    pub config: Option<PathBuf>,
    /// The correction file to write.
    #[arg(long, short)]
    pub out: PathBuf,
    /// Where the vehicles' events are kept as they are read [default: <OUT>.events.jsonl].
    #[arg(long)]
    pub events_cache: Option<PathBuf>,
    /// Fit only this signal (default: each the profile has a table of).
    #[arg(long, value_enum)]
    pub signal: Option<SignalArg>,
}

#[derive(clap::ValueEnum, Clone, Copy, Debug, PartialEq, Eq)]
pub enum SignalArg {
    Angle,
    Torque,
}

/// One vehicle's events at new joints as [`FitSetup::read_vehicle`] reads them: a line of the
/// events cache, and what the fleet job's executors hand the fit.
#[derive(Clone, Serialize, Deserialize)]
pub struct VehicleEvents {
    /// The vehicle's files with their sizes and modification times: read again when they change.
    pub key: String,
    pub vehicle: String,
    #[serde(default)]
    evidence: Vec<Evidence>,
    /// Why the vehicle gave no event, when it did not.
    #[serde(default)]
    pub skipped: Option<String>,
    /// The steering sensors' noise measured at its stops, per signal.
    #[serde(default)]
    noise: Vec<NoiseSeen>,
}

/// One signal's noise at a vehicle's stops (src/observer/noise_floor.rs) against the table's.
#[derive(Clone, Copy, Serialize, Deserialize)]
struct NoiseSeen {
    signal: SteerSignal,
    measured_rms: f64,
    assumed_rms: f64,
}

/// The median over the vehicles of a signal's measured / assumed standstill noise, and over how
/// many vehicles; `None` where none measured it.
fn noise_ratio(vehicles: &[VehicleEvents], signal: SteerSignal) -> Option<(f64, f64, usize)> {
    let mut r: Vec<(f64, f64)> = vehicles
        .iter()
        .flat_map(|v| v.noise.iter())
        .filter(|n| n.signal == signal && n.assumed_rms > 0.0 && n.measured_rms.is_finite())
        .map(|n| (n.measured_rms / n.assumed_rms, n.measured_rms))
        .collect();
    if r.is_empty() {
        return None;
    }
    r.sort_by(|a, b| a.0.total_cmp(&b.0));
    let (ratio, measured) = r[r.len() / 2];
    Some((ratio, measured, r.len()))
}

/// The vehicle's logs: the file, or the files of the directory in name order.
pub fn vehicle_logs(v: &Path) -> anyhow::Result<Vec<PathBuf>> {
    if v.is_dir() {
        let mut logs: Vec<PathBuf> = std::fs::read_dir(v)
            .with_context(|| format!("cannot read vehicle directory {}", v.display()))?
            .filter_map(|e| e.ok().map(|e| e.path()))
            .filter(|p| p.is_file())
            .collect();
        logs.sort();
        if logs.is_empty() {
            bail!("vehicle directory {} holds no file", v.display());
        }
        Ok(logs)
    } else if v.is_file() {
        Ok(vec![v.to_path_buf()])
    } else {
        bail!(
            "vehicle {} is neither a log file nor a directory",
            v.display()
        )
    }
}

/// The logs' identity for the cache: paths, sizes and modification times.
pub fn cache_key(logs: &[PathBuf]) -> String {
    logs.iter()
        .map(|p| {
            let (len, mtime) = std::fs::metadata(p)
                .map(|m| {
                    let t = m
                        .modified()
                        .ok()
                        .and_then(|t| t.duration_since(std::time::UNIX_EPOCH).ok())
                        .map_or(0, |d| d.as_nanos());
                    (m.len(), t)
                })
                .unwrap_or((0, 0));
            format!("{}:{len}:{mtime}", p.display())
        })
        .collect::<Vec<_>>()
        .join("|")
}

/// The cached vehicles, by key (lines that do not parse, e.g. one cut by a crash, are dropped).
fn read_cache(path: &Path) -> std::collections::HashMap<String, VehicleEvents> {
    let Ok(text) = std::fs::read_to_string(path) else {
        return Default::default();
    };
    text.lines()
        .filter_map(|l| serde_json::from_str::<VehicleEvents>(l).ok())
        .map(|c| (c.key.clone(), c))
        .collect()
}

/// A signal's events of each vehicle, as the fit takes them.
fn fit_events(vehicles: &[VehicleEvents], signal: SteerSignal) -> Vec<Vec<FitEvent>> {
    vehicles
        .iter()
        .map(|v| {
            v.evidence
                .iter()
                .filter_map(|e| match signal {
                    SteerSignal::AngleDeg => (e.rms_deg.is_finite() && e.peak_deg.is_finite())
                        .then_some(FitEvent {
                            rms: e.rms_deg,
                            peak: e.peak_deg,
                            cruise_rms: e.cruise_rms_deg,
                            v0_kmh: e.v0_kmh,
                            decel_g: e.decel_g,
                        }),
                    SteerSignal::TorqueNm => e.torque_nm.map(|t| FitEvent {
                        rms: t.rms,
                        peak: t.peak,
                        cruise_rms: t.cruise_rms,
                        v0_kmh: e.v0_kmh,
                        decel_g: e.decel_g,
                    }),
                })
                .collect()
        })
        .collect()
}

/// What a fit runs with: the profile, the observer settings, and the tables it corrects (as
/// calibrated: a correction the profile already names is not applied while a new one is fitted;
/// the chassis variants stay out). The same for the CLI, the Python package and the fleet job.
pub struct FitSetup {
    profile: Profile,
    cfg: ObserverConfig,
    angle: Option<ResponseTable>,
    torque: Option<ResponseTable>,
    signal: Option<SignalArg>,
    clearance_mm: f64,
}

/// A fit's result: the correction file's text and what it says.
#[derive(Serialize)]
pub struct FitOutcome {
    /// The correction, as written to the file.
    pub correction: CorrectionFile,
    /// The file's text (a comment header, then TOML).
    #[serde(skip)]
    pub text: String,
    /// One line per fitted signal: gains, ranges, spread, what the fleet said.
    pub summary: Vec<String>,
    /// Signals not fitted, each with the reason.
    pub not_fitted: Vec<String>,
    /// Signals fitted whose correction should not be trusted, each with the reason (their
    /// features' gains disagree: the car differs from the model by more than a gain).
    pub warnings: Vec<String>,
    pub vehicles: usize,
    pub skipped: usize,
}

impl FitSetup {
    /// Loads the profile, its tables and the settings; refuses a clearance that is no clearance
    /// and a profile without a table of the signal asked for.
    pub fn load(
        profile: &str,
        config: Option<&Path>,
        clearance_mm: f64,
        signal: Option<SignalArg>,
    ) -> anyhow::Result<FitSetup> {
        if !(clearance_mm.is_finite() && clearance_mm > 0.0) {
            bail!("--clearance-mm must be a clearance above 0 mm, not {clearance_mm}");
        }
        let cfg = match config {
            Some(p) => ObserverConfig::load(p)?,
            None => ObserverConfig::default(),
        };
        let profile = Profile::load(profile)?;
        let strip = |t: Option<ResponseTable>| {
            t.map(|mut t| {
                t.correction = None;
                t
            })
        };
        let want = |s: SignalArg| signal.is_none_or(|a| a == s);
        let angle = strip(profile.load_table()?);
        let torque = strip(profile.load_torque_table()?);
        if !(angle.is_some() && want(SignalArg::Angle)
            || torque.is_some() && want(SignalArg::Torque))
        {
            bail!(
                "profile {} has no response table {}to correct",
                profile.name,
                match signal {
                    Some(SignalArg::Angle) => "of the steering angle ",
                    Some(SignalArg::Torque) => "of the steering torque (or its mapping maps none) ",
                    None => "",
                }
            );
        }
        Ok(FitSetup {
            profile,
            cfg,
            angle,
            torque,
            signal,
            clearance_mm,
        })
    }

    /// Reads one vehicle's logs (in order) through the same pipeline as `shimmy estimate
    /// --baseline`. Never fails: a vehicle without a usable event comes back skipped, with why.
    pub fn read_vehicle(&self, vehicle: &str, logs: Vec<PathBuf>) -> VehicleEvents {
        let key = cache_key(&logs);
        // Both tables feed the pipeline whichever signal is fitted: the events are the same.
        let tables = crate::pipeline::Tables {
            angle: self.angle.clone(),
            torque: self.torque.clone(),
            torque_alternatives: Vec::new(),
            angle_alternatives: Vec::new(),
        };
        let b = BaselineLogs {
            logs,
            clearance_mm: self.clearance_mm,
        };
        let (evidence, noise, skipped) = match baseline_and_noise_of(
            &self.profile.mapping_path,
            Some(&self.profile.dbc_path),
            tables,
            self.cfg.clone(),
            &b,
            TOOL,
        ) {
            Ok((b, noise)) => (
                b.evidence,
                noise
                    .iter()
                    .map(|n| NoiseSeen {
                        signal: n.signal,
                        measured_rms: n.measured_rms,
                        assumed_rms: n.assumed_rms,
                    })
                    .collect(),
                None,
            ),
            Err(e) => (Vec::new(), Vec::new(), Some(format!("{e:#}"))),
        };
        VehicleEvents {
            key,
            vehicle: vehicle.to_string(),
            evidence,
            skipped,
            noise,
        }
    }

    /// The fit over the vehicles, per signal (in the vehicles' order: the same vehicles in the
    /// same order give the same bytes). Progress goes to stderr.
    pub fn fit(&self, vehicles: &[VehicleEvents]) -> anyhow::Result<FitOutcome> {
        let n = vehicles.len();
        let skipped = vehicles.iter().filter(|v| v.skipped.is_some()).count();
        let want = |s: SignalArg| self.signal.is_none_or(|a| a == s);
        let mut targets: Vec<(SteerSignal, &ResponseTable)> = Vec::new();
        if let Some(t) = self.angle.as_ref().filter(|_| want(SignalArg::Angle)) {
            targets.push((SteerSignal::AngleDeg, t));
        }
        if let Some(t) = self.torque.as_ref().filter(|_| want(SignalArg::Torque)) {
            targets.push((SteerSignal::TorqueNm, t));
        }
        let mut file = CorrectionFile::default();
        let mut lines = Vec::new();
        let mut not_fitted = Vec::new();
        let mut warnings = Vec::new();
        let mut refused: Vec<&str> = Vec::new();
        for (signal, table) in targets {
            let name = signal_name(signal);
            let events = fit_events(vehicles, signal);
            let with = events.iter().filter(|e| !e.is_empty()).count();
            if with < 2 {
                not_fitted.push(format!(
                    "{name}: {with} vehicle(s) with usable events, at least 2 needed: not fitted"
                ));
                continue;
            }
            // A sensor noisier than its table's reads, at new joints, as a gain; the gain would
            // then take the rattle of worn joints for noise (docs/ACCURACY.md measures it).
            if let Some((ratio, measured, n_noise)) = noise_ratio(vehicles, signal) {
                let limit = self.cfg.features.noise_floor_ratio;
                if limit > 0.0 && ratio > limit {
                    not_fitted.push(format!(
                        "{name}: not fitted: the sensor measures {measured:.4} {} RMS at \
                         standstill, {ratio:.2}× what its table assumes (median over {n_noise} \
                         vehicles; [features] noise_floor_ratio = {limit}). A noisier sensor is \
                         not a gain: rebuild the table for it (`shimmy calibrate \
                         --sensor-noise-deg {measured:.4}`, with `--signal torque` for the \
                         torque) and fit again",
                        signal.unit()
                    ));
                    refused.push(name);
                    continue;
                }
            }
            let ecfg = match signal {
                SteerSignal::AngleDeg => self.cfg.estimator.clone(),
                SteerSignal::TorqueNm => self.cfg.torque_estimator(),
            };
            eprintln!(
                "{TOOL}: {name}: fitting on {with} vehicles, {} events",
                events.iter().map(Vec::len).sum::<usize>()
            );
            let c = correction::fit(table, &ecfg, &events, self.clearance_mm, |k| {
                if k % 50 == 0 {
                    eprintln!("{TOOL}: {name}: {k} likelihood evaluations");
                }
            })
            .with_context(|| format!("fitting the {name} correction"))?;
            lines.push(summary(signal, &c));
            if let Some(p) = c
                .gains_agree_p
                .filter(|&p| p < correction::GAINS_DISAGREE_P)
            {
                warnings.push(format!(
                    "{name}: the features' gains disagree (rms ×{:.3}, peak ×{:.3}, cruise \
                     ×{:.3}; p = {p:.3} that they are one gain): this car model differs from the \
                     table's by more than a signal gain (a scrub radius, brake discs, another \
                     steering column). The correction will not make its intervals honest: build \
                     a table for its chassis (a chassis variant, docs/ADDING_A_CAR.md) rather \
                     than ship this correction",
                    c.gain[0], c.gain[1], c.gain[2]
                ));
            }
            file.set(signal, c);
        }
        if file.angle_deg.is_none() && file.torque_nm.is_none() {
            if !refused.is_empty() {
                bail!(
                    "no correction fitted: the {} sensor is noisier than its table assumes: {}",
                    refused.join(" and "),
                    not_fitted.join("; ")
                );
            }
            bail!(
                "no correction fitted ({skipped} of {n} vehicle(s) gave no usable braking \
                 event): {}",
                not_fitted.join("; ")
            );
        }
        let header = format!(
            "# A car model's correction to profile {}'s response tables, fitted by `shimmy fleet-fit` on\n\
             # {n} vehicle(s) at {} mm ({skipped} skipped for lack of usable events). Name this file in\n\
             # the profile's profile.toml as `correction = \"<file>\"` (src/observer/correction.rs).\n",
            self.profile.name, self.clearance_mm
        );
        let body = toml::to_string_pretty(&file).context("serialising the correction")?;
        let header = warnings.iter().fold(header, |mut h, w| {
            h.push_str(&format!("# WARNING: {w}\n"));
            h
        });
        Ok(FitOutcome {
            correction: file,
            text: format!("{header}{body}"),
            summary: lines,
            not_fitted,
            warnings,
            vehicles: n,
            skipped,
        })
    }
}

/// Writes `text` to `path` through a temporary file beside it, so that a crash leaves the old
/// file or the new one, never half of one.
pub fn write_atomic(path: &Path, text: &str) -> anyhow::Result<()> {
    let mut tmp = path.as_os_str().to_owned();
    tmp.push(".tmp");
    let tmp = PathBuf::from(tmp);
    std::fs::write(&tmp, text).with_context(|| format!("cannot write {}", tmp.display()))?;
    std::fs::rename(&tmp, path).with_context(|| format!("cannot write {}", path.display()))
}

pub fn run(args: Args) -> anyhow::Result<()> {
    let setup = FitSetup::load(
        &args.profile,
        args.config.as_deref(),
        args.clearance_mm,
        args.signal,
    )?;
    let cache_path = args.events_cache.clone().unwrap_or_else(|| {
        let mut p = args.out.clone().into_os_string();
        p.push(".events.jsonl");
        PathBuf::from(p)
    });
    let mut cached = read_cache(&cache_path);
    let mut cache = std::fs::OpenOptions::new()
        .create(true)
        .append(true)
        .open(&cache_path)
        .with_context(|| format!("cannot open the events cache {}", cache_path.display()))?;

    let n = args.vehicles.len();
    let mut vehicles: Vec<VehicleEvents> = Vec::with_capacity(n);
    let mut resumed = 0usize;
    for (i, v) in args.vehicles.iter().enumerate() {
        let logs = vehicle_logs(v)?;
        let key = cache_key(&logs);
        let entry = match cached.remove(&key) {
            Some(c) => {
                resumed += 1;
                c
            }
            None => {
                let c = setup.read_vehicle(&v.display().to_string(), logs);
                let line = serde_json::to_string(&c).context("serialising the events cache")?;
                writeln!(cache, "{line}").with_context(|| {
                    format!("writing the events cache {}", cache_path.display())
                })?;
                c
            }
        };
        match &entry.skipped {
            Some(why) => eprintln!(
                "{TOOL}: vehicle {}/{n} {}: skipped: {why}",
                i + 1,
                entry.vehicle
            ),
            None => eprintln!(
                "{TOOL}: vehicle {}/{n} {}: {} event(s)",
                i + 1,
                entry.vehicle,
                entry.evidence.len()
            ),
        }
        vehicles.push(entry);
    }
    if resumed > 0 {
        eprintln!(
            "{TOOL}: {resumed} vehicle(s) read from the events cache {}",
            cache_path.display()
        );
    }
    let out = setup.fit(&vehicles)?;
    for l in &out.not_fitted {
        eprintln!("{TOOL}: {l}");
    }
    write_atomic(&args.out, &out.text)?;
    for l in &out.summary {
        println!("{l}");
    }
    for w in &out.warnings {
        eprintln!("{TOOL}: warning: {w}");
    }
    println!(
        "{n} vehicle(s), {} skipped; written to {}",
        out.skipped,
        args.out.display()
    );
    Ok(())
}

fn signal_name(s: SteerSignal) -> &'static str {
    match s {
        SteerSignal::AngleDeg => "angle",
        SteerSignal::TorqueNm => "torque",
    }
}

/// One line per signal: gains with their 90 % ranges, the spread, what the fleet said.
fn summary(signal: SteerSignal, c: &Correction) -> String {
    let names = ["rms", "peak", "cruise"];
    let gains: Vec<String> = (0..3)
        .map(|i| {
            let (g, se) = (c.gain[i], c.gain_se_ln[i]);
            if se > 0.0 {
                format!(
                    "{} ×{g:.3} [{:.3}–{:.3}]",
                    names[i],
                    g * (-1.645 * se).exp(),
                    g * (1.645 * se).exp()
                )
            } else {
                format!("{} ×{g:.3} (not observed)", names[i])
            }
        })
        .collect();
    let agree = match c.gains_agree_p {
        Some(p) if p < correction::GAINS_DISAGREE_P => format!("; the gains disagree (p {p:.3})"),
        Some(p) => format!("; the gains agree (p {p:.2})"),
        None => String::new(),
    };
    format!(
        "{}: {}{agree}; spread {:.3} (ln); {} vehicles, {} events; ln-likelihood +{:.1} over none",
        signal_name(signal),
        gains.join(", "),
        c.spread_ln,
        c.vehicles,
        c.events,
        c.ln_likelihood_gain
    )
}
