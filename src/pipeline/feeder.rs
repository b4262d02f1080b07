//! Frames into the monitor pipeline, offline: a log's frames through the signal mapper
//! ([`Feeder`]: DBC decoding, mapping, validity) into detector [`Sample`]s, and the whole
//! offline pipeline opened from a mapping, a DBC, a response table and the monitor's settings
//! ([`Offline`]), the one setup that `shimmy estimate`, `shimmy doctor` and `shimmy export` run.
//!
//! What it is not: a log reader ([`crate::source`]), the event stage or the alert rules (the rest
//! of [`crate::pipeline`]), or any output. shimmyd maps frames the same way
//! ([`detector_sample`]) but keeps its own loop, because it persists the odometer and alerts.

use std::path::{Path, PathBuf};

use anyhow::{bail, Context};

use super::{detector_sample, Monitor, ObserverStage};
use crate::dbc::Database;
use crate::events::Sample;
use crate::observer::ObserverConfig;
use crate::signals::mapping::MappingConfig;
use crate::signals::{Mapper, Outcome, Update};
use crate::source::{CanSource, SourceStats};
use crate::wire::Frame;

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

/// Counters of one run over the logs.
#[derive(Clone, Debug, Default, serde::Serialize)]
pub struct RunStats {
    pub frames: u64,
    pub mapped_frames: u64,
    pub rejected_frames: u64,
    pub log: SourceStats,
}

/// Turns mapped frames into detector samples.
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

    /// Reads a whole source, handing each sample it makes to `sink`.
    pub fn feed_source(
        &mut self,
        src: &mut dyn CanSource,
        mut sink: impl FnMut(&Sample),
    ) -> anyhow::Result<()> {
        while let Some(f) = src.next_frame().context("reading log")? {
            if let Some((s, _)) = self.sample(&f) {
                sink(&s);
            }
        }
        self.stats.log.add(&src.stats());
        Ok(())
    }

    /// One frame through the mapper: the detector sample it makes and the mapper's update, or
    /// `None` when the frame belongs to no mapped message. Counts the frame. Allocates nothing.
    pub fn sample(&mut self, f: &Frame) -> Option<(Sample, Update)> {
        self.stats.frames += 1;
        let u = self.mapper.on_frame(f)?;
        self.stats.mapped_frames += 1;
        if matches!(u.outcome, Outcome::Rejected(_)) {
            self.stats.rejected_frames += 1;
        }
        let snap = self.mapper.snapshot(f.t_ns);
        let s = detector_sample(&u, &snap, self.steer_msg, self.brake_on_pa);
        Some((s, u))
    }

    /// The signal mapper (its per-message counters, its latest snapshot).
    pub fn mapper(&self) -> &Mapper {
        &self.mapper
    }
}

/// The offline pipeline of one vehicle: its DBC, the feeder (mapper) and the monitor (event
/// stage, odometer, alert book), ready for the vehicle's logs in time order.
pub struct Offline {
    pub db: Database,
    /// The DBC file it was loaded from.
    pub dbc_path: PathBuf,
    pub mapping: MappingConfig,
    pub feeder: Feeder,
    pub monitor: Monitor<ObserverStage>,
}

impl Offline {
    /// Loads the mapping and the DBC (`dbc`, or the one the mapping names) and builds the
    /// pipeline; the mapper's warnings go to stderr prefixed with `tool`.
    pub fn open(
        mapping_path: &Path,
        dbc: Option<&Path>,
        tables: impl Into<super::Tables>,
        cfg: ObserverConfig,
        tool: &str,
    ) -> anyhow::Result<Offline> {
        let tables = tables.into();
        let mapping = MappingConfig::from_toml_file(mapping_path)
            .with_context(|| format!("mapping {}", mapping_path.display()))?;
        let dbc_path = match dbc {
            Some(p) => p.to_path_buf(),
            None => resolve_dbc(mapping_path, &mapping)?,
        };
        let (db, _report) = Database::load(&dbc_path)?;
        let feeder = Feeder::new(&db, &mapping, &cfg).with_context(|| {
            format!(
                "mapping {} against {}",
                mapping_path.display(),
                dbc_path.display()
            )
        })?;
        for w in feeder.mapper().warnings() {
            eprintln!("{tool}: mapping: {w}");
        }
        let rules = cfg.alerts.clone();
        let stage = ObserverStage::new(&cfg, tables.angle)?
            .with_angle_alternatives(tables.angle_alternatives)?
            .with_torque_tables(tables.torque, tables.torque_alternatives)?;
        let monitor = Monitor::new(stage, rules);
        Ok(Offline {
            db,
            dbc_path,
            mapping,
            feeder,
            monitor,
        })
    }
}
