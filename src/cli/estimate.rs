//! `shimmy estimate`: one vehicle's CAN logs in, one clearance verdict out (issue 5 item 4).
//!
//! This module is the plumbing: logs ([`crate::source::log::LogReader`]) → DBC decoding and
//! signal mapping ([`crate::signals::Mapper`]) → [`crate::events::Sample`]s → the
//! [`crate::observer::Observer`]. Policy (events, features, estimator, alerts) lives in
//! [`crate::events`] and [`crate::observer`]. The per-frame path allocates nothing.

use std::io::Write;
use std::path::{Path, PathBuf};

use anyhow::{bail, Context};

use crate::dbc::Database;
use crate::events::Sample;
use crate::model::VehicleParams;
use crate::observer::table::{vehicle_hash, ResponseTable};
use crate::observer::{Observer, ObserverConfig, Report};
use crate::signals::mapping::MappingConfig;
use crate::signals::{Mapper, Outcome, Update};
use crate::source::log::LogReader;
use crate::source::{CanSource, SourceStats};
use crate::wire::Frame;

/// Estimate steering-joint clearance from one vehicle's CAN logs.
///
/// Reads the LOGs in the order given (candump -L, Vector ASC or BLF), decodes them with the DBC
/// named by the mapping (or --dbc), finds braking events (brake applied, 0.3–0.8 g, 20–120 km/h,
/// nearly straight; others are listed but not used), measures the steering-wheel shimmy of each
/// (MODEL.md §11: 3–25 Hz band-pass peak over the braking window, plus a noise-corrected
/// amplitude), and, with a response table from `shimmy calibrate`, accumulates the events into a
/// posterior over the joint clearance.
///
/// Output (one JSON object; --format text prints a short summary instead):
///   clearance_mm    posterior median (mm), null when below the detection limit
///   interval_mm     [5 %, 95 %] credible interval (mm)
///   detectable      false when the posterior cannot exclude the detection limit; then
///   below_mm        the clearance is below this (mm), and `verdict` says "below X mm"
///   events          each: t_start, t_end (s, log time), v0_kmh, decel_g, peak_sw_bp_deg, used,
///                   unused_reason, rms_sw_bp_deg, sw_amplitude_deg and data quality
///   alerts          each: kind "clearance" (P(c > 0.1 mm) >= 90 %) or "shimmy_55kmh" (estimated
///                   steering-wheel amplitude above 0.2 deg in at least 2 of the last 5 events
///                   starting at 50–60 km/h), t_raised and evidence
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
/// Example:
///   shimmy calibrate --out table.json
///   shimmy estimate --mapping config/vehicles/shimmy_reference/mapping.toml --table table.json drive.log
#[derive(clap::Args, Debug)]
#[command(verbatim_doc_comment)]
pub struct Args {
    /// Signal mapping (TOML, config/vehicles/*/mapping.toml).
    #[arg(long, value_name = "FILE")]
    pub mapping: PathBuf,

    /// DBC file. Default: the mapping's `dbc`, looked up next to the mapping, in ./dbc and in
    /// the shared data's dbc/opendbc.
    #[arg(long, value_name = "FILE")]
    pub dbc: Option<PathBuf>,

    /// Vehicle parameters (TOML, MODEL.md §9 keys); default: MODEL.md §9. The table must have
    /// been built for the same parameters.
    #[arg(long, value_name = "FILE")]
    pub vehicle: Option<PathBuf>,

    /// Response table from `shimmy calibrate`. Without it, events and the shimmy alert are
    /// reported but the clearance is not estimated.
    #[arg(long, value_name = "FILE")]
    pub table: Option<PathBuf>,

    /// Observer thresholds (TOML, as config/observer.toml); default: built-in defaults.
    #[arg(long, value_name = "FILE")]
    pub config: Option<PathBuf>,

    /// Output format.
    #[arg(long, value_enum, default_value_t = Format::Json)]
    pub format: Format,

    /// The vehicle's logs, in time order.
    #[arg(value_name = "LOG", required = true)]
    pub logs: Vec<PathBuf>,
}

#[derive(clap::ValueEnum, Clone, Copy, Debug, PartialEq, Eq)]
pub enum Format {
    Json,
    Text,
}

/// Finds the DBC a mapping names (see [`crate::profile::resolve_dbc`] for where it looks).
pub fn resolve_dbc(mapping_path: &Path, mapping: &MappingConfig) -> anyhow::Result<PathBuf> {
    let Some(name) = mapping.dbc.as_deref() else {
        bail!(
            "mapping {} names no `dbc`; pass --dbc FILE",
            mapping_path.display()
        );
    };
    let dir = mapping_path.parent().unwrap_or(Path::new("."));
    crate::profile::resolve_dbc(dir, name).with_context(|| {
        format!(
            "the DBC named by mapping {}; pass --dbc FILE",
            mapping_path.display()
        )
    })
}

/// Loads vehicle parameters (default: MODEL.md §9).
pub fn load_vehicle(path: Option<&Path>) -> anyhow::Result<VehicleParams> {
    match path {
        Some(p) => VehicleParams::from_toml_file(p)
            .with_context(|| format!("vehicle parameters {}", p.display())),
        None => Ok(VehicleParams::default()),
    }
}

/// Counters of one run over the logs.
#[derive(Clone, Debug, Default, serde::Serialize)]
pub struct RunStats {
    pub frames: u64,
    pub mapped_frames: u64,
    pub rejected_frames: u64,
    pub log: SourceStats,
}

/// Turns mapped frames into detector samples and feeds the observer.
pub struct Feeder {
    mapper: Mapper,
    steer_msg: Option<usize>,
    brake_on_pa: f64,
    pub stats: RunStats,
}

impl Feeder {
    pub fn new(
        db: &Database,
        mapping: &MappingConfig,
        cfg: &ObserverConfig,
    ) -> anyhow::Result<Feeder> {
        let mapper = Mapper::new(db, mapping)?;
        let steer_msg = mapper
            .stats()
            .iter()
            .position(|m| m.name == mapping.steer_angle.message);
        Ok(Feeder {
            mapper,
            steer_msg,
            brake_on_pa: cfg.events.brake_on_bar * 1e5,
            stats: RunStats::default(),
        })
    }

    /// Reads a whole source into `obs`.
    pub fn feed_source(
        &mut self,
        src: &mut dyn CanSource,
        obs: &mut Observer,
    ) -> anyhow::Result<()> {
        while let Some(f) = src.next_frame().context("reading log")? {
            if let Some((s, _)) = self.sample(&f) {
                obs.push(&s);
            }
        }
        let st = src.stats();
        self.stats.log.frames += st.frames;
        self.stats.log.malformed += st.malformed;
        self.stats.log.skipped += st.skipped;
        self.stats.log.error_frames += st.error_frames;
        self.stats.log.backwards_timestamps += st.backwards_timestamps;
        self.stats.log.dropped += st.dropped;
        Ok(())
    }
}

impl Feeder {
    /// One frame through the mapper: the detector sample it makes and the mapper's update, or
    /// `None` when the frame belongs to no mapped message. Counts the frame. Allocates nothing.
    pub fn sample(&mut self, f: &Frame) -> Option<(Sample, Update)> {
        self.stats.frames += 1;
        let u = self.mapper.on_frame(f)?;
        self.stats.mapped_frames += 1;
        let snap = self.mapper.snapshot(f.t_ns);
        let brake = match (snap.brake_pressed.valid(), snap.brake_pressure_pa.valid()) {
            (Some(b), Some(p)) => Some(b || p > self.brake_on_pa),
            (Some(b), None) => Some(b),
            (None, Some(p)) => Some(p > self.brake_on_pa),
            (None, None) => None,
        };
        let mut s = Sample {
            t_ns: f.t_ns,
            brake,
            ..Default::default()
        };
        match u.outcome {
            Outcome::Accepted(ch) => {
                if ch.steer_angle {
                    s.steer_rad = snap.steer_angle_rad.valid();
                    s.steer_invalid = s.steer_rad.is_none();
                }
                if ch.speed {
                    s.speed_mps = snap.speed_mps.valid();
                }
                if ch.accel {
                    s.accel_mps2 = snap.accel_mps2.valid();
                }
            }
            Outcome::Rejected(_) => {
                self.stats.rejected_frames += 1;
                s.steer_invalid = Some(u.message) == self.steer_msg;
            }
        }
        Some((s, u))
    }

    /// The signal mapper (its per-message counters, its latest snapshot).
    pub fn mapper(&self) -> &Mapper {
        &self.mapper
    }
}

/// The whole `estimate` pipeline on files; returns the report and the run counters.
pub fn estimate_files(
    mapping_path: &Path,
    dbc: Option<&Path>,
    table: Option<ResponseTable>,
    cfg: ObserverConfig,
    logs: &[PathBuf],
) -> anyhow::Result<(Report, RunStats)> {
    let mapping = MappingConfig::from_toml_file(mapping_path)
        .with_context(|| format!("mapping {}", mapping_path.display()))?;
    let dbc_path = match dbc {
        Some(p) => p.to_path_buf(),
        None => resolve_dbc(mapping_path, &mapping)?,
    };
    let (db, _report) = Database::load(&dbc_path)?;
    let mut feeder = Feeder::new(&db, &mapping, &cfg).with_context(|| {
        format!(
            "mapping {} against {}",
            mapping_path.display(),
            dbc_path.display()
        )
    })?;
    let mut obs = Observer::new(cfg, table)?;
    for log in logs {
        let mut src =
            LogReader::open(log).with_context(|| format!("cannot open log {}", log.display()))?;
        feeder
            .feed_source(&mut src, &mut obs)
            .with_context(|| format!("log {}", log.display()))?;
        for s in src.take_skips() {
            eprintln!("shimmy estimate: skipped {}: {}", s.location, s.reason);
        }
    }
    obs.finish();
    Ok((obs.report(), feeder.stats))
}

pub fn run(args: Args) -> anyhow::Result<()> {
    let cfg = match &args.config {
        Some(p) => ObserverConfig::load(p)?,
        None => ObserverConfig::default(),
    };
    let table = match &args.table {
        Some(p) => {
            let t = ResponseTable::load(p)?;
            let vehicle = load_vehicle(args.vehicle.as_deref())?;
            t.check_vehicle(&vehicle_hash(&vehicle)?)
                .with_context(|| format!("table {}", p.display()))?;
            Some(t)
        }
        None => None,
    };
    let cfg_events = cfg.events.clone();
    let (report, stats) =
        estimate_files(&args.mapping, args.dbc.as_deref(), table, cfg, &args.logs)?;
    let mut out = std::io::stdout().lock();
    match args.format {
        Format::Json => {
            serde_json::to_writer_pretty(&mut out, &report)?;
            writeln!(out)?;
        }
        Format::Text => {
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
            for a in &report.alerts {
                writeln!(
                    out,
                    "ALERT {} at t = {:.1} s: {}",
                    a.kind, a.t_raised, a.evidence
                )?;
            }
        }
    }
    Ok(())
}
