//! Chooses the event stage for a configuration: the clearance observer
//! ([`crate::pipeline::ObserverStage`], on the monitor's settings in effect), with the response table of `vehicle.table` when
//! set. Without a table, events and the shimmy-amplitude alert still work; the clearance is
//! not estimated (never a fake estimate). With `vehicle.torque_table` too, events with a
//! live torsion-bar torque feed the torque's estimator, which the estimate then comes from.
//! A profile's own tables carry the profile's correction (`correction`, src/observer/
//! correction.rs), as every other path that loads them does.
//!
//! [`DaemonStage`] is what the daemon asks of its stage beyond [`EventStage`]: being told that
//! the joints were replaced (reset, then collect a new baseline), and restoring with the
//! precedence between a configured baseline and one a replacement made. [`ObserverStage`] does
//! all of it; any other [`EventStage`] (a test double) runs as a [`DaemonStage`] that cannot
//! take a joint replacement.
//!
//! What it is not: the marker file or the journal records of a replacement ([`super::joints`],
//! [`super::run`]).

use anyhow::Context;
use serde::Serialize;

use super::config::Config;
use crate::monitor::{Estimate, EventStage, EventSummary, RejectionSummary, Sample};
use crate::observer::table::ResponseTable;
use crate::pipeline::observer_stage::BaselineUse;
use crate::pipeline::ObserverStage;

/// A baseline collection in progress after a joint replacement.
#[derive(Clone, Copy, Debug, PartialEq, Serialize)]
pub struct Collection {
    /// Used braking events collected so far.
    pub collected: u32,
    /// How many make the baseline.
    pub events: u32,
    /// The new joints' clearance (mm).
    pub clearance_mm: f64,
}

impl Collection {
    /// What the estimate is meanwhile, in words.
    pub fn text(&self) -> String {
        format!(
            "collecting a baseline after a joint replacement: {} of {} events (at {} mm); no \
             clearance estimate until it is complete",
            self.collected, self.events, self.clearance_mm
        )
    }
}

/// A baseline just completed from a joint replacement's collection.
#[derive(Clone, Copy, Debug, PartialEq, Serialize)]
pub struct Completed {
    /// Events collected.
    pub events: u32,
    pub clearance_mm: f64,
    /// How many of them each estimator took.
    #[serde(flatten)]
    pub used: BaselineUse,
}

/// What shimmyd asks of its event stage beyond [`EventStage`]. The provided methods are those
/// of a stage that estimates nothing a joint replacement could reset.
pub trait DaemonStage: EventStage {
    /// The joints were just replaced (new clearance `clearance_mm`): forget what was learnt
    /// from the old ones and collect the next `events` used braking events as the new baseline
    /// ([`ObserverStage::joints_replaced`]). An error says why it cannot.
    fn joints_replaced(&mut self, _clearance_mm: f64, _events: u32) -> anyhow::Result<()> {
        anyhow::bail!("this event stage estimates no clearance: nothing to reset or collect")
    }
    /// The baseline collection in progress, if any.
    fn baseline_collection(&self) -> Option<Collection> {
        None
    }
    /// A collection completed since the last call (once per completion).
    fn take_completed_baseline(&mut self) -> Option<Completed> {
        None
    }
    /// [`EventStage::restore`], with a baseline given at start newer than a replacement's in
    /// the saved state when `given_is_newer` ([`ObserverStage::restore_with`]).
    fn restore_with(
        &mut self,
        saved: &serde_json::Value,
        _given_is_newer: bool,
    ) -> anyhow::Result<Option<String>> {
        self.restore(saved)
    }
    /// The stage as the daemon keeps it.
    fn into_daemon_stage(self: Box<Self>) -> Box<dyn DaemonStage>;
}

impl DaemonStage for ObserverStage {
    fn joints_replaced(&mut self, clearance_mm: f64, events: u32) -> anyhow::Result<()> {
        ObserverStage::joints_replaced(self, clearance_mm, events)
    }
    fn baseline_collection(&self) -> Option<Collection> {
        self.collecting().map(|c| Collection {
            collected: c.collected(),
            events: c.target,
            clearance_mm: c.clearance_mm,
        })
    }
    fn take_completed_baseline(&mut self) -> Option<Completed> {
        let used = ObserverStage::take_completed_baseline(self)?;
        let b = self.baseline()?;
        Some(Completed {
            events: u32::try_from(b.evidence.len()).unwrap_or(u32::MAX),
            clearance_mm: b.clearance_mm,
            used,
        })
    }
    fn restore_with(
        &mut self,
        saved: &serde_json::Value,
        given_is_newer: bool,
    ) -> anyhow::Result<Option<String>> {
        ObserverStage::restore_with(self, saved, given_is_newer)
    }
    fn into_daemon_stage(self: Box<Self>) -> Box<dyn DaemonStage> {
        self
    }
}

/// Any [`EventStage`] (a factory's `Box<dyn EventStage>`) runs as a stage that cannot take a
/// joint replacement.
impl DaemonStage for dyn EventStage {
    fn into_daemon_stage(self: Box<Self>) -> Box<dyn DaemonStage> {
        Box::new(Plain(self))
    }
}

/// An [`EventStage`] that is only that.
struct Plain(Box<dyn EventStage>);

impl EventStage for Plain {
    fn describe(&self) -> String {
        self.0.describe()
    }
    fn push(&mut self, s: &Sample) -> Option<EventSummary> {
        self.0.push(s)
    }
    fn finish(&mut self) -> Option<EventSummary> {
        self.0.finish()
    }
    fn estimate(&self) -> Option<Estimate> {
        self.0.estimate()
    }
    fn odometer_km(&mut self, km: f64) {
        self.0.odometer_km(km)
    }
    fn save(&self) -> Option<serde_json::Value> {
        self.0.save()
    }
    fn rejections(&self) -> Option<RejectionSummary> {
        self.0.rejections()
    }
    fn restore(&mut self, saved: &serde_json::Value) -> anyhow::Result<Option<String>> {
        self.0.restore(saved)
    }
}

impl DaemonStage for Plain {
    fn into_daemon_stage(self: Box<Self>) -> Box<dyn DaemonStage> {
        self
    }
}

/// [`for_daemon`] as a plain [`EventStage`] (for callers that need nothing more).
pub fn for_config(cfg: &Config) -> anyhow::Result<Box<dyn EventStage>> {
    Ok(for_daemon(cfg)?)
}

/// The clearance observer for `cfg`, as shimmyd runs it.
pub fn for_daemon(cfg: &Config) -> anyhow::Result<Box<ObserverStage>> {
    let table = match &cfg.vehicle.table {
        Some(p) => {
            let t = ResponseTable::load(p)
                .with_context(|| format!("vehicle.table: cannot load {}", p.display()))?;
            // A profile's table must fit the profile's chassis and sensor; a custom setup's
            // the vehicle parameters given.
            if let Some(profile) = &cfg.profile {
                profile.check_table(&t).with_context(|| {
                    format!("vehicle.table {} for profile {}", p.display(), profile.name)
                })?;
                Some(with_correction(profile, p, t)?)
            } else {
                if let Some(params) = &cfg.vehicle.params {
                    let v = crate::cli::estimate::load_vehicle(Some(params))?;
                    t.check_vehicle(&crate::observer::table::vehicle_hash(&v)?)
                        .with_context(|| format!("vehicle.table {}", p.display()))?;
                }
                Some(t)
            }
        }
        None => None,
    };
    let torque = match &cfg.vehicle.torque_table {
        Some(p) => {
            let t = ResponseTable::load(p)
                .with_context(|| format!("vehicle.torque_table: cannot load {}", p.display()))?;
            if let Some(profile) = &cfg.profile {
                profile.check_torque_table(&t).with_context(|| {
                    format!(
                        "vehicle.torque_table {} for profile {}",
                        p.display(),
                        profile.name
                    )
                })?;
                Some(with_correction(profile, p, t)?)
            } else {
                let v = crate::cli::estimate::load_vehicle(cfg.vehicle.params.as_deref())?;
                t.check_torque_vehicle(&v)
                    .with_context(|| format!("vehicle.torque_table {}", p.display()))?;
                Some(t)
            }
        }
        None => None,
    };
    // The profile's chassis variants ride with its own tables, not with others given in their
    // place.
    let torque_alternatives = match (&torque, &cfg.profile) {
        (Some(t), Some(profile)) => {
            profile.load_torque_alternatives(t, cfg.vehicle.torque_table.as_deref())?
        }
        _ => Vec::new(),
    };
    if !torque_alternatives.is_empty() {
        eprintln!(
            "shimmyd: {} torque table(s) of chassis variants beside the nominal one ({}): the \
             estimate weighs each by how well the events fit it",
            torque_alternatives.len(),
            crate::observer::Alternative::names(&torque_alternatives)
        );
    }
    let angle_alternatives = match (&table, &cfg.profile) {
        (Some(t), Some(profile)) => {
            profile.load_angle_alternatives(t, cfg.vehicle.table.as_deref())?
        }
        _ => Vec::new(),
    };
    if !angle_alternatives.is_empty() {
        eprintln!(
            "shimmyd: {} angle table(s) of chassis variants beside the nominal one ({}): the \
             angle's estimate weighs each by how well the events fit it",
            angle_alternatives.len(),
            crate::observer::Alternative::names(&angle_alternatives)
        );
    }
    // A baseline is read before the stage takes the tables (they are cloned only for it).
    let baseline = if cfg.vehicle.baseline_logs.is_empty() {
        None
    } else {
        anyhow::ensure!(
            table.is_some() || torque.is_some(),
            "vehicle.baseline_logs: a baseline needs a response table (vehicle.table or \
             vehicle.torque_table)"
        );
        let (dbc, mapping) = cfg.bus_files().ok_or_else(|| {
            anyhow::anyhow!(
                "vehicle.baseline_logs: the car's DBC and mapping must be known (input.profile, \
                 or input.dbc and input.mapping) to read them"
            )
        })?;
        let logs = crate::cli::estimate::BaselineLogs {
            logs: cfg.vehicle.baseline_logs.clone(),
            clearance_mm: cfg.vehicle.baseline_clearance_mm,
        };
        let tables = crate::pipeline::Tables {
            angle: table.clone(),
            torque: torque.clone(),
            torque_alternatives: torque_alternatives.clone(),
            angle_alternatives: angle_alternatives.clone(),
        };
        Some(
            crate::cli::estimate::baseline_of(
                mapping,
                Some(dbc),
                tables,
                cfg.settings.clone(),
                &logs,
                "shimmyd",
            )
            .context("vehicle.baseline_logs")?,
        )
    };
    let mut stage = ObserverStage::new(&cfg.settings, table)?
        .with_angle_alternatives(angle_alternatives)?
        .with_torque_tables(torque, torque_alternatives)?;
    if let Some(b) = baseline {
        let used = stage.set_baseline(b);
        eprintln!(
            "shimmyd: baseline: {} event(s) of vehicle.baseline_logs at {} mm (angle {}, \
             torque {})",
            used.angle_events.max(used.torque_events),
            cfg.vehicle.baseline_clearance_mm,
            used.angle_events,
            used.torque_events
        );
    }
    Ok(Box::new(stage))
}

/// The table loaded from `path` with the profile's correction attached
/// ([`crate::profile::Profile::corrected`]) when it is the profile's own; a table given in its
/// place is another table, which the profile's correction does not describe.
fn with_correction(
    profile: &crate::profile::Profile,
    path: &std::path::Path,
    t: ResponseTable,
) -> anyhow::Result<ResponseTable> {
    if profile.is_own_table(path) {
        profile.corrected(t)
    } else {
        Ok(t)
    }
}
