//! `shimmy estimate`: one vehicle's CAN logs in, one clearance verdict out (events, estimate
//! and alerts as JSON or text).
//!
//! This module is the plumbing: logs ([`crate::source::log::LogReader`]) → DBC decoding and
//! signal mapping ([`crate::signals::Mapper`]) → [`crate::events::Sample`]s → the monitor
//! pipeline ([`crate::pipeline::Monitor`] over [`crate::pipeline::ObserverStage`]), the same
//! event stage, estimate and alert rules ([`crate::alerts::AlertBook`], with its lifecycle and
//! hysteresis) as shimmyd. Policy (events, features, estimator, alerts) lives in
//! [`crate::events`], [`crate::observer`] and [`crate::alerts`]. The per-frame path allocates
//! nothing.

use std::io::Write;
use std::path::{Path, PathBuf};

use anyhow::{bail, Context};

use crate::alerts::{Alert, AlertCounts};
use crate::model::VehicleParams;
use crate::observer::table::{vehicle_hash, ResponseTable};
use crate::observer::{ObserverConfig, Report};
use crate::pipeline::feeder::Offline;
pub use crate::pipeline::feeder::{resolve_dbc, Feeder, RunStats};
use crate::profile::Profile;
use crate::source::log::LogReader;
use crate::source::CanSource;

/// Estimate steering-joint clearance from one vehicle's CAN logs.
///
/// Reads the LOGs in the order given (candump -L, Vector ASC, BLF, MF4 or PEAK TRC), decodes
/// them with the DBC named by the mapping (or --dbc), finds braking events (brake applied,
/// 0.3–0.8 g, 20–120 km/h, nearly straight; others are listed but not used), measures the
/// steering-wheel shimmy of each (MODEL.md §11: 3–25 Hz band-pass peak over the braking window,
/// plus a noise-corrected amplitude), and, with a response table from `shimmy calibrate`,
/// accumulates the events into a posterior over the joint clearance.
///
/// Output (one JSON object; --format text prints a short summary instead):
///   clearance_mm    posterior median (mm), null when below the detection limit
///   interval_mm     [5 %, 95 %] credible interval (mm)
///   detectable      false when the posterior cannot exclude the detection limit; then
///   below_mm        the clearance is below this (mm), and `verdict` says "below X mm"
///   events          each: t_start, t_end (s, log time), v0_kmh, decel_g, peak_sw_bp_deg, used,
///                   unused_reason, rms_sw_bp_deg, sw_amplitude_deg and data quality
///   alerts          the alerts standing at the end of the logs, decided after each braking
///                   event exactly as shimmyd decides them: kind "clearance" (raised when
///                   P(c > 0.1 mm) >= 70 %, standing until it falls below 50 %) or
///                   "shimmy_55kmh" (raised when the estimated steering-wheel amplitude is above
///                   0.2 deg in at least 2 of the last 5 events starting at 50–60 km/h, standing
///                   until none of them is above 0.15 deg); each with id, t_raised, t_updated,
///                   updates, summary, guidance and evidence (the events and the estimate)
///   rejections      why braking gave nothing: brake applications ignored before recording,
///                   per reason (too_slow, too_light, too_short; accel_while_braking counts
///                   those that read a forward acceleration while the brake was applied, the
///                   mark of an inverted acceleration sign), events recorded, used, and not
///                   used per reason; ignored_applications lists the first 1000 ignored ones
///   verdict         when nothing was estimated, says why and points at the likely cause
/// --format text prints the verdict, the counts, and a `braking:` line with the rejections
/// whenever events were rejected or none were found.
/// Thresholds come from --config (see config/observer.toml for every key and its default).
///
/// The car: --profile NAME (config/vehicles/<NAME>: its DBC, mapping, chassis and response
/// table), or for a custom setup --mapping FILE (with --dbc, --vehicle, --table). With
/// neither, the car is identified from the logs' traffic (`shimmy identify`) and the choice is
/// printed on stderr.
///
/// Examples:
///   shimmy estimate --profile toyota_rav4 drive.log
///   shimmy estimate drive1.log drive2.blf --format text
///   shimmy estimate --mapping my_car/mapping.toml --dbc my_car.dbc --table table.json drive.log
#[derive(clap::Args, Debug)]
#[command(verbatim_doc_comment)]
pub struct Args {
    /// Vehicle profile (a name under config/vehicles, an alias, or a profile folder).
    #[arg(long, value_name = "NAME", conflicts_with = "mapping")]
    pub profile: Option<String>,

    /// Signal mapping of a custom setup (TOML, as config/vehicles/*/mapping.toml).
    #[arg(long, value_name = "FILE")]
    pub mapping: Option<PathBuf>,

    /// DBC file. Default: the profile's, or the mapping's `dbc` looked up next to the mapping,
    /// in ./dbc, SHIMMY_DBC_PATH and the shared data's dbc/opendbc.
    #[arg(long, value_name = "FILE")]
    pub dbc: Option<PathBuf>,

    /// Vehicle parameters (TOML, MODEL.md §9 keys); default: the profile's chassis, or
    /// MODEL.md §9. The table must have been built for the same parameters.
    #[arg(long, value_name = "FILE")]
    pub vehicle: Option<PathBuf>,

    /// Response table from `shimmy calibrate`; default: the profile's. Without one, events
    /// and the shimmy alert are reported but the clearance is not estimated.
    /// A profile whose `[[chassis.variants]]` name angle tables (`table`) has those fed
    /// beside it and weighed as the torque's are (`angle_tables` in the JSON); this option
    /// replaces them all with the one file.
    #[arg(long, value_name = "FILE")]
    pub table: Option<PathBuf>,

    /// Response table of the EPS torsion-bar torque (`shimmy calibrate --signal torque`);
    /// default: the profile's `torque_table`, used when the mapping maps a steering torque.
    /// Where the log carries a live torque the estimate comes from it, else from the angle.
    /// A profile with `[[chassis.variants]]` has a torque table per variant too: every one is
    /// fed and the report weighs their readings by how well the events fit each
    /// (`torque_tables` in the JSON);
    /// this option replaces them all with the one file.
    #[arg(long, value_name = "FILE", conflicts_with = "angle_only")]
    pub torque_table: Option<PathBuf>,

    /// Estimate from the steering angle alone, even where a torque table and a torque exist.
    #[arg(long)]
    pub angle_only: bool,

    /// The monitor's settings (TOML, as config/observer.toml: events, features, estimator,
    /// alerts; every key in docs/CONFIG.md); default: built-in defaults.
    #[arg(long, value_name = "FILE")]
    pub config: Option<PathBuf>,

    /// Output format.
    #[arg(long, value_enum, default_value_t = Format::Json)]
    pub format: Format,

    /// A log of this vehicle driven when its joints' clearance was known (its first drives
    /// after the joints were replaced; repeatable). Its braking events become the vehicle's
    /// baseline: they tell the estimator how this car's signals sit against the table's model
    /// (a sensor gain, a transfer the model does not have), which the estimate then takes out
    /// instead of reading it as clearance (docs/ACCURACY.md, "The per-vehicle baseline").
    #[arg(long = "baseline", value_name = "LOG")]
    pub baseline_logs: Vec<PathBuf>,

    /// The joints' clearance during the --baseline logs (mm): new joints sit at about
    /// 0.02-0.06 mm.
    #[arg(
        long,
        value_name = "MM",
        default_value_t = 0.03,
        requires = "baseline_logs"
    )]
    pub baseline_clearance_mm: f64,

    /// The vehicle's logs, in time order.
    #[arg(value_name = "LOG", required = true)]
    pub logs: Vec<PathBuf>,
}

pub use super::TextOrJson as Format;

/// Seconds of the logs' traffic `shimmy estimate` fingerprints when no car is given.
pub const IDENTIFY_SECONDS: f64 = 10.0;

/// The profile whose bus the logs carry (`shimmy identify` on their first
/// [`IDENTIFY_SECONDS`]), said on stderr; an error with the evidence when none or several fit.
pub fn identify_profile(logs: &[PathBuf]) -> anyhow::Result<Profile> {
    use crate::profile::identify::{identify_logs, Verdict};
    let id = identify_logs(logs, IDENTIFY_SECONDS)?;
    match (id.verdict, &id.profile) {
        (Verdict::Identified, Some(name)) => {
            eprintln!(
                "shimmy estimate: no --profile given; identified the car from its bus: {}",
                id.summary
            );
            Profile::load(name)
        }
        _ => bail!(
            "no --profile or --mapping given, and the car could not be identified from its bus: \
             {} (see `shimmy identify`; pass --profile NAME, or --mapping FILE for a custom setup)",
            id.summary
        ),
    }
}

/// Loads vehicle parameters (default: MODEL.md §9).
pub fn load_vehicle(path: Option<&Path>) -> anyhow::Result<VehicleParams> {
    match path {
        Some(p) => VehicleParams::from_toml_file(p)
            .with_context(|| format!("vehicle parameters {}", p.display())),
        None => Ok(VehicleParams::default()),
    }
}

/// What `shimmy estimate` answers: the observer's report and the alerts standing at the end of
/// the logs.
#[derive(Clone, Debug, PartialEq, serde::Serialize)]
pub struct Estimation {
    #[serde(flatten)]
    pub report: Report,
    /// The alerts open at the end of the logs (raised after some event and not cleared since),
    /// decided by the same rules and lifecycle as shimmyd's ([`crate::alerts::AlertBook`]).
    pub alerts: Vec<Alert>,
    /// Alerts raised and cleared over the logs, per kind: more raises than standing alerts
    /// means an alert that came and went.
    pub alert_counts: AlertCounts,
    /// The vehicle's baseline, when one was given ([`estimate_files_with`]).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub baseline: Option<BaselineReport>,
}

/// What the baseline gave: its clearance and how many of its events each estimator took.
#[derive(Clone, Copy, Debug, PartialEq, serde::Serialize)]
pub struct BaselineReport {
    pub clearance_mm: f64,
    pub angle_events: u32,
    pub torque_events: u32,
}

/// An [`Estimation`] reads as its report (`e.events`, `e.verdict`, …); only the alerts are its
/// own.
impl std::ops::Deref for Estimation {
    type Target = Report;
    fn deref(&self) -> &Report {
        &self.report
    }
}

/// The whole `estimate` pipeline on files; returns the report with the standing alerts, and
/// the run counters.
pub fn estimate_files(
    mapping_path: &Path,
    dbc: Option<&Path>,
    tables: impl Into<crate::pipeline::Tables>,
    cfg: ObserverConfig,
    logs: &[PathBuf],
) -> anyhow::Result<(Estimation, RunStats)> {
    estimate_files_with(mapping_path, dbc, tables, cfg, None, logs)
}

/// Logs of the vehicle at a known clearance: its baseline ([`estimate_files_with`]).
#[derive(Clone, Debug, PartialEq)]
pub struct BaselineLogs {
    pub logs: Vec<PathBuf>,
    pub clearance_mm: f64,
}

/// [`estimate_files`] with the vehicle's baseline: the `baseline` logs go through the same
/// pipeline first (their events only; no alerts, not in the report's events), and their used
/// events, at the baseline's clearance, condition the estimate from `logs`
/// ([`crate::pipeline::observer_stage::ObserverStage::set_baseline`]). Errors when the
/// baseline logs hold no used event.
pub fn estimate_files_with(
    mapping_path: &Path,
    dbc: Option<&Path>,
    tables: impl Into<crate::pipeline::Tables>,
    cfg: ObserverConfig,
    baseline: Option<&BaselineLogs>,
    logs: &[PathBuf],
) -> anyhow::Result<(Estimation, RunStats)> {
    let tables: crate::pipeline::Tables = tables.into();
    let base = match baseline {
        Some(b) => Some(baseline_of(
            mapping_path,
            dbc,
            tables.clone(),
            cfg.clone(),
            b,
            TOOL,
        )?),
        None => None,
    };
    let mut off = Offline::open(mapping_path, dbc, tables, cfg, TOOL)?;
    let base_use = base.map(|b| off.monitor.stage_mut().set_baseline(b));
    feed_logs(&mut off, logs, "log", TOOL)?;
    let Offline {
        feeder, monitor, ..
    } = off;
    let out = Estimation {
        report: monitor.stage().observer().report(),
        alerts: monitor.standing().to_vec(),
        alert_counts: monitor.book().counts,
        baseline: base_use.map(|u| BaselineReport {
            clearance_mm: baseline.map_or(f64::NAN, |b| b.clearance_mm),
            angle_events: u.angle_events,
            torque_events: u.torque_events,
        }),
    };
    Ok((out, feeder.stats))
}

/// What `shimmy estimate` says its messages are from.
const TOOL: &str = "shimmy estimate";

/// Feeds `logs`, in order, through the pipeline `off` and closes an event still open at the
/// end; the readers' skips go to stderr as `tool`'s, and `what` names a log in errors.
fn feed_logs(off: &mut Offline, logs: &[PathBuf], what: &str, tool: &str) -> anyhow::Result<()> {
    for log in logs {
        let mut src = LogReader::open(log)
            .with_context(|| format!("cannot open {what} {}", log.display()))?;
        let monitor = &mut off.monitor;
        off.feeder
            .feed_source(&mut src, |s| {
                monitor.push(s);
            })
            .with_context(|| format!("{what} {}", log.display()))?;
        for s in src.take_skips() {
            eprintln!("{tool}: skipped {}: {}", s.location, s.reason);
        }
        let st = crate::source::CanSource::stats(&src);
        if let Some(note) = st.zero_filled_note() {
            eprintln!("{tool}: {}: {note}", log.display());
        }
        anyhow::ensure!(
            st.frames > 0 || st.malformed == 0,
            "{what} {}: no CAN frame could be read from it ({} line(s) or record(s) not \
             understood): not a log the readers know (candump -L, Vector ASC, BLF, MF4, PEAK \
             TRC), or a corrupt one (the reader's first complaints are above)",
            log.display(),
            st.malformed
        );
    }
    off.monitor.finish();
    Ok(())
}

/// The used events of the baseline logs, through the same pipeline as the logs (shimmyd's
/// `vehicle.baseline_logs` too); `tool` names the command in its messages.
pub fn baseline_of(
    mapping_path: &Path,
    dbc: Option<&Path>,
    tables: crate::pipeline::Tables,
    cfg: ObserverConfig,
    b: &BaselineLogs,
    tool: &str,
) -> anyhow::Result<crate::pipeline::observer_stage::Baseline> {
    Ok(baseline_and_noise_of(mapping_path, dbc, tables, cfg, b, tool)?.0)
}

/// [`baseline_of`], with the steering sensors' noise measured at standstill over the same
/// logs (src/observer/noise_floor.rs).
pub fn baseline_and_noise_of(
    mapping_path: &Path,
    dbc: Option<&Path>,
    tables: crate::pipeline::Tables,
    cfg: ObserverConfig,
    b: &BaselineLogs,
    tool: &str,
) -> anyhow::Result<(
    crate::pipeline::observer_stage::Baseline,
    Vec<crate::observer::noise_floor::MeasuredNoise>,
)> {
    let mut off = Offline::open(mapping_path, dbc, tables, cfg, tool)?;
    feed_logs(&mut off, &b.logs, "baseline log", tool)?;
    let monitor = &off.monitor;
    let evidence: Vec<_> = monitor.stage().evidence().copied().collect();
    if evidence.is_empty() {
        bail!(
            "the baseline logs hold no braking event the estimator can use: {}",
            monitor.stage().observer().report().verdict
        );
    }
    Ok((
        crate::pipeline::observer_stage::Baseline {
            clearance_mm: b.clearance_mm,
            evidence,
        },
        monitor.stage().observer().measured_noise(),
    ))
}

/// What `shimmy estimate` prints: the observer's report with the alerts standing, and the
/// profile it used.
#[derive(serde::Serialize)]
struct Output<'a> {
    /// The vehicle profile used (null for a custom --mapping setup).
    profile: Option<&'a str>,
    #[serde(flatten)]
    report: &'a Estimation,
}

/// The JSON document `shimmy estimate --format json` prints for `profile` and `est`: the
/// profile's name (null for a custom --mapping setup) and the flattened [`Estimation`]. The
/// Python package (`shimmy_monitor.estimate`) returns exactly this document.
pub fn output_json(profile: Option<&Profile>, est: &Estimation) -> serde_json::Result<String> {
    serde_json::to_string_pretty(&Output {
        profile: profile.map(|p| p.name.as_str()),
        report: est,
    })
}

/// Everything `shimmy estimate` does but printing: the car (profile, mapping, DBC, table) as the
/// arguments say, then [`estimate_files`] over the logs. Returns the profile used (none for a
/// custom --mapping setup), the estimation and the run counters.
pub fn evaluate(args: &Args) -> anyhow::Result<(Option<Profile>, Estimation, RunStats)> {
    let cfg = match &args.config {
        Some(p) => ObserverConfig::load(p)?,
        None => ObserverConfig::default(),
    };
    let profile = match (&args.profile, &args.mapping) {
        (Some(name), _) => Some(Profile::load(name)?),
        (None, Some(_)) => None,
        (None, None) => Some(identify_profile(&args.logs)?),
    };
    let table = match (&args.table, &profile) {
        (Some(p), _) => {
            let t = ResponseTable::load(p)?;
            let vehicle = match (&args.vehicle, &profile) {
                (None, Some(prof)) => prof.vehicle.clone(),
                (v, _) => load_vehicle(v.as_deref())?,
            };
            t.check_vehicle(&vehicle_hash(&vehicle)?)
                .with_context(|| format!("table {}", p.display()))?;
            Some(t)
        }
        (None, Some(prof)) => {
            let t = prof.load_table()?;
            if t.is_none() {
                eprintln!(
                    "shimmy estimate: profile {} has no response table: events only",
                    prof.name
                );
            }
            t
        }
        (None, None) => None,
    };
    let torque = match (&args.torque_table, &profile) {
        _ if args.angle_only => None,
        (Some(p), _) => {
            let t = ResponseTable::load(p)?;
            let ctx = || format!("torque table {}", p.display());
            match (&args.vehicle, &profile) {
                (None, Some(prof)) => prof.check_torque_table(&t).with_context(ctx)?,
                (v, _) => t
                    .check_torque_vehicle(&load_vehicle(v.as_deref())?)
                    .with_context(ctx)?,
            }
            Some(t)
        }
        (None, Some(prof)) => prof.load_torque_table()?,
        (None, None) => None,
    };
    // The profile's chassis variants ride with its own tables only: a table given is read alone.
    let torque_alternatives = match (&args.torque_table, &profile, &torque) {
        (None, Some(prof), Some(t)) => prof.load_torque_alternatives(t, None)?,
        _ => Vec::new(),
    };
    let angle_alternatives = match (&args.table, &profile, &table) {
        (None, Some(prof), Some(t)) => prof.load_angle_alternatives(t, None)?,
        _ => Vec::new(),
    };
    let tables = crate::pipeline::Tables {
        angle: table,
        torque,
        torque_alternatives,
        angle_alternatives,
    };
    let (mapping_path, dbc) = match &profile {
        Some(p) => (
            p.mapping_path.clone(),
            Some(args.dbc.clone().unwrap_or_else(|| p.dbc_path.clone())),
        ),
        None => (
            args.mapping.clone().expect("checked above"),
            args.dbc.clone(),
        ),
    };
    if !(args.baseline_clearance_mm > 0.0 && args.baseline_clearance_mm.is_finite()) {
        bail!(
            "--baseline-clearance-mm must be a clearance above 0 mm, not {}",
            args.baseline_clearance_mm
        );
    }
    let baseline = (!args.baseline_logs.is_empty()).then(|| BaselineLogs {
        logs: args.baseline_logs.clone(),
        clearance_mm: args.baseline_clearance_mm,
    });
    let (report, stats) = estimate_files_with(
        &mapping_path,
        dbc.as_deref(),
        tables,
        cfg,
        baseline.as_ref(),
        &args.logs,
    )?;
    Ok((profile, report, stats))
}

pub fn run(args: Args) -> anyhow::Result<()> {
    let cfg_events = match &args.config {
        Some(p) => ObserverConfig::load(p)?.events,
        None => ObserverConfig::default().events,
    };
    let (profile, report, stats) = evaluate(&args)?;
    let mut out = std::io::stdout().lock();
    match args.format {
        Format::Json => {
            writeln!(out, "{}", output_json(profile.as_ref(), &report)?)?;
        }
        Format::Text => {
            if let Some(p) = &profile {
                writeln!(out, "vehicle: {}", p.label())?;
            }
            let alerts = &report.alerts;
            let report = &report.report;
            writeln!(out, "{}", report.verdict)?;
            writeln!(
                out,
                "events: {} recorded, {} used; frames: {} read, {} mapped, {} rejected",
                report.events.len(),
                report.events_used,
                stats.frames,
                stats.mapped_frames,
                stats.rejected_frames
            )?;
            let rej = &report.rejections;
            if rej.worth_reporting() {
                writeln!(out, "braking: {}", rej.counts_text(&cfg_events))?;
            }
            for a in alerts {
                writeln!(
                    out,
                    "ALERT {} raised at t = {:.1} s: {}",
                    a.kind.as_str(),
                    a.t_raised,
                    a.summary
                )?;
            }
        }
    }
    Ok(())
}
