//! `shimmy export`: one vehicle's CAN logs into a Parquet data lake (decoded signals in the CSS
//! Electronics layout, and the monitor's events, estimates and alerts), each log on its own:
//! a log that fails is reported and the others go on.
//!
//! This module is the command line and the per-log error report; the lake itself (layout,
//! naming, schemas, the pipeline run) is [`crate::lake`].

use std::path::PathBuf;

use anyhow::{bail, Context};

use crate::cli::estimate::Estimation;
use crate::lake::{sha256_bytes, sha256_file, Exporter, Inputs};
use crate::observer::ObserverConfig;
use crate::pipeline::feeder::Offline;
use crate::profile::Profile;

/// Export one vehicle's CAN logs to a Parquet data lake.
///
/// Reads each LOG in turn (candump -L, Vector ASC, BLF, ASAM MDF 4 or PEAK TRC) and writes,
/// under LAKE:
///   <VEHICLE>/<message>/<yyyy>/<mm>/<dd>/*.parquet
///       every frame the profile's DBC defines, one file set per CAN message: a column t
///       (timestamp, µs, UTC) and one column per signal (physical value, Float64; value-table
///       entries stay numbers; null when the frame does not carry the signal), the values
///       `shimmy decode` prints (CSS Electronics' data-lake layout, device = the vehicle ID);
///   events/vehicle=<VEHICLE>/date=<yyyy-mm-dd>/*.parquet     finished braking events
///   estimates/vehicle=<VEHICLE>/date=<yyyy-mm-dd>/*.parquet  the clearance estimate after each
///   alerts/vehicle=<VEHICLE>/date=<yyyy-mm-dd>/*.parquet     alert transitions (raised, updated,
///                                                            cleared)
/// The monitor's tables come from the same pipeline as `shimmy estimate` over the same logs in
/// the same order (every row carries the model version, the BLAKE3 of the log, as `b3sum` prints
/// it, and the sha256 of the run, the response table, the DBC, and the torque table and the
/// profile's correction when it has them). docs/FLEET.md lists every column.
///
/// Appending and rerunning: file names derive from the content of the inputs (the log's BLAKE3
/// for signals; the run's hash, over every log, the DBC, mapping, tables, correction and
/// settings, for the monitor's tables) and the bytes written are reproducible, so exporting the
/// same logs again rewrites the same files and adds none: a failed or interrupted run is resumed
/// by running it again. Files are written under hidden temporary names and renamed when
/// complete.
///
/// Dates: the UTC date of each frame's timestamp (of the event's end for the monitor's tables).
/// A log whose timestamps count from its start rather than from 1970 (e.g. candump written by a
/// simulator from t = 0) lands on 1970-01-01; shift it before export if it has a known start.
///
/// A log that cannot be read, holds no CAN frame, or carries none of the profile's mapped
/// messages (another car) is reported on stderr with the reason; the others are exported, and
/// the exit status is 1 if any failed. Progress goes to stderr on a terminal.
///
/// Examples:
///   shimmy export --profile toyota_rav4 --vehicle rav4-0042 --out /data/lake drive*.log
#[derive(clap::Args, Debug)]
#[command(verbatim_doc_comment)]
pub struct Args {
    /// Vehicle profile (a name under config/vehicles, an alias, or a profile folder): its DBC,
    /// mapping, chassis and response table.
    #[arg(long, value_name = "NAME")]
    pub profile: String,

    /// The vehicle's ID: the lake's device folder and `vehicle=` partition (A-Z a-z 0-9 _ . -).
    #[arg(long, value_name = "ID")]
    pub vehicle: String,

    /// The lake's root folder (created if missing; existing files of other inputs are kept).
    #[arg(long, value_name = "LAKE")]
    pub out: PathBuf,

    /// The monitor's settings (TOML, as config/observer.toml); default: built-in defaults.
    #[arg(long, value_name = "FILE")]
    pub config: Option<PathBuf>,

    /// The vehicle's logs, in time order.
    #[arg(value_name = "LOG", required = true)]
    pub logs: Vec<PathBuf>,
}

const TOOL: &str = "shimmy export";

/// What one `shimmy export` run did (the CLI prints it; the Python package returns it as a
/// dict).
#[derive(Clone, Debug, serde::Serialize)]
pub struct ExportSummary {
    /// The lake's root folder.
    pub lake: PathBuf,
    /// The vehicle ID.
    pub vehicle: String,
    /// The profile's name.
    pub profile: String,
    /// The run's hash (`run_sha256` of every row).
    pub run_sha256: String,
    /// Logs given, and exported without error.
    pub logs: usize,
    pub logs_exported: usize,
    /// Every log that failed, with the reason (its error chain).
    pub failed: Vec<FailedLog>,
    /// Frames read from the exported logs, and frames of mapped messages over the run.
    pub frames: u64,
    pub mapped_frames: u64,
    /// Files written (renamed into place), signal and monitor files.
    pub files_written: usize,
    /// Braking events recorded and alerts standing at the end of the run.
    pub events: usize,
    pub alerts_standing: usize,
    /// The estimate at the end of the run: what `shimmy estimate` gives over the logs that
    /// reached the monitor (the same pipeline, the same order).
    pub estimation: Estimation,
}

/// A log `shimmy export` could not export, and why.
#[derive(Clone, Debug, serde::Serialize)]
pub struct FailedLog {
    pub log: PathBuf,
    pub reason: String,
}

/// Exports as `shimmy export` does, without printing the summary: logs that fail are listed in
/// [`ExportSummary::failed`] (and reported on stderr), not an error; an error is a run that
/// could not start (bad vehicle ID, profile, settings, lake folder) or a monitor file that
/// could not be written. `progress`: a progress bar on stderr (hidden when not a terminal);
/// `signals`: false writes only the monitor's tables ([`Exporter::without_signals`]).
pub fn export(args: &Args, progress: bool, signals: bool) -> anyhow::Result<ExportSummary> {
    crate::lake::check_vehicle_id(&args.vehicle)?;
    let cfg = match &args.config {
        Some(p) => ObserverConfig::load(p)?,
        None => ObserverConfig::default(),
    };
    let profile = Profile::load(&args.profile)?;
    let profile_name = profile.name.clone();
    let table = profile.load_table()?;
    let table_sha256 = match (&table, &profile.table_path) {
        (Some(_), Some(p)) => Some(sha256_file(p)?),
        _ => {
            eprintln!(
                "{TOOL}: profile {} has no response table: events only",
                profile.name
            );
            None
        }
    };
    let torque = profile.load_torque_table()?;
    let torque_alternatives = match &torque {
        Some(t) => profile.load_torque_alternatives(t, None)?,
        None => Vec::new(),
    };
    let torque_table_sha256 = match (&torque, &profile.torque_table_path) {
        (Some(_), Some(p)) => Some(sha256_file(p)?),
        _ => None,
    };
    let angle_alternatives = match &table {
        Some(t) => profile.load_angle_alternatives(t, None)?,
        None => Vec::new(),
    };
    let variants_sha256 = variants_sha256(&profile, &torque_alternatives, &angle_alternatives)?;
    // The tables above were loaded with the correction applied (and refused had it been
    // fitted against another table); every estimate depends on it.
    let correction_sha256 = match &profile.correction_path {
        Some(p) => {
            Some(sha256_file(p).with_context(|| format!("profile {}: correction", profile.name))?)
        }
        None => None,
    };
    let settings_json = serde_json::to_vec(&cfg).context("serialising the monitor's settings")?;
    let inputs = Inputs {
        vehicle: args.vehicle.clone(),
        dbc_sha256: sha256_file(&profile.dbc_path)?,
        table_sha256,
        torque_table_sha256,
        correction_sha256,
        variants_sha256,
        mapping_sha256: sha256_file(&profile.mapping_path)?,
        settings_sha256: sha256_bytes(&settings_json),
    };
    let pipe = Offline::open(
        &profile.mapping_path,
        Some(&profile.dbc_path),
        crate::pipeline::Tables {
            angle: table,
            torque,
            torque_alternatives,
            angle_alternatives,
        },
        cfg,
        TOOL,
    )?;

    let mut failed: Vec<FailedLog> = Vec::new();
    std::fs::create_dir_all(&args.out)
        .with_context(|| format!("cannot create the lake {}", args.out.display()))?;
    let mut ex = Exporter::new(args.out.clone(), inputs, pipe)?;
    if !signals {
        ex = ex.without_signals();
    }

    let bar = if progress {
        indicatif::ProgressBar::new(args.logs.len() as u64)
    } else {
        indicatif::ProgressBar::hidden()
    };
    bar.set_style(
        indicatif::ProgressStyle::with_template("{prefix} [{bar:30}] {pos}/{len} logs {msg}")
            .unwrap_or_else(|_| indicatif::ProgressStyle::default_bar()),
    );
    bar.set_prefix(TOOL);
    let (mut files, mut frames, mut ok) = (0usize, 0u64, 0usize);
    for (i, log) in args.logs.iter().enumerate() {
        let name = log.display().to_string();
        let res = ex.export_log(i, log, &mut |n| {
            bar.set_message(format!("{name}: {n} frames"));
        });
        bar.inc(1);
        match res {
            Ok(done) => {
                for s in &done.skips {
                    bar.suspend(|| eprintln!("{TOOL}: skipped {}: {}", s.location, s.reason));
                }
                files += done.files.len();
                frames += done.frames;
                ok += 1;
            }
            Err(e) => {
                bar.suspend(|| eprintln!("{TOOL}: FAILED {}: {e:#}", log.display()));
                failed.push(FailedLog {
                    log: log.clone(),
                    reason: format!("{e:#}"),
                });
            }
        }
    }
    let done = ex.finish()?;
    let (run, pipe) = (done.run_sha256, done.pipe);
    files += done.files.len();
    bar.finish_and_clear();
    let st = &pipe.feeder.stats;
    let estimation = Estimation {
        report: pipe.monitor.stage().observer().report(),
        alerts: pipe.monitor.standing().to_vec(),
        alert_counts: pipe.monitor.book().counts,
        baseline: None,
    };
    Ok(ExportSummary {
        lake: args.out.clone(),
        vehicle: args.vehicle.clone(),
        profile: profile_name,
        run_sha256: run,
        logs: args.logs.len(),
        logs_exported: ok,
        failed,
        frames,
        mapped_frames: st.mapped_frames,
        files_written: files,
        events: estimation.report.events.len(),
        alerts_standing: estimation.alerts.len(),
        estimation,
    })
}

pub fn run(args: Args) -> anyhow::Result<()> {
    let s = export(&args, true, true)?;
    println!(
        "{TOOL}: {} of {} logs exported to {} ({} frames, {} mapped, {} files written; run {}); \
         {} braking events, {} alerts standing",
        s.logs_exported,
        s.logs,
        s.lake.display(),
        s.frames,
        s.mapped_frames,
        s.files_written,
        &s.run_sha256[..16],
        s.events,
        s.alerts_standing,
    );
    if !s.failed.is_empty() {
        for f in &s.failed {
            eprintln!("{TOOL}: failed: {}: {}", f.log.display(), f.reason);
        }
        bail!(
            "{} of {} logs failed (listed above)",
            s.failed.len(),
            s.logs
        );
    }
    Ok(())
}

/// With chassis variants in use: the sha256 of each variant's name and table hashes in order,
/// each followed by a zero byte ([`Inputs::variants_sha256`]); `None` without.
fn variants_sha256(
    profile: &Profile,
    torque: &[crate::observer::Alternative],
    angle: &[crate::observer::Alternative],
) -> anyhow::Result<Option<String>> {
    if torque.is_empty() && angle.is_empty() {
        return Ok(None);
    }
    let mut parts = Vec::new();
    for v in &profile.file.chassis.variants {
        parts.extend_from_slice(v.name.as_bytes());
        parts.push(0);
        if let (false, Some(t)) = (torque.is_empty(), &v.torque_table) {
            parts.extend_from_slice(sha256_file(&profile.dir.join(t))?.as_bytes());
            parts.push(0);
        }
        // An angle table is a part only where there is one, so that a profile whose variants
        // have torque tables alone keeps the hash it had before angle variants existed.
        if let (false, Some(t)) = (angle.is_empty(), &v.table) {
            parts.extend_from_slice(b"angle:");
            parts.extend_from_slice(sha256_file(&profile.dir.join(t))?.as_bytes());
            parts.push(0);
        }
    }
    Ok(Some(sha256_bytes(&parts)))
}
