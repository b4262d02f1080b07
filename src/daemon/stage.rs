//! Chooses the event stage for a configuration: the clearance observer
//! ([`crate::pipeline::ObserverStage`], on the monitor's settings in effect), with the response table of `vehicle.table` when
//! set. Without a table, events and the shimmy-amplitude alert still work; the clearance is
//! not estimated (never a fake estimate). With `vehicle.torque_table` too, events with a
//! live torsion-bar torque feed the torque's estimator, which the estimate then comes from.
//! A profile's own tables carry the profile's correction (`correction`, src/observer/
//! correction.rs), as every other path that loads them does.

use anyhow::Context;

use super::config::Config;
use crate::monitor::EventStage;
use crate::observer::table::ResponseTable;
use crate::pipeline::ObserverStage;

pub fn for_config(cfg: &Config) -> anyhow::Result<Box<dyn EventStage>> {
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
                Some(with_correction(
                    profile,
                    profile.table_path.as_deref(),
                    p,
                    t,
                )?)
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
                Some(with_correction(
                    profile,
                    profile.torque_table_path.as_deref(),
                    p,
                    t,
                )?)
            } else {
                let v = crate::cli::estimate::load_vehicle(cfg.vehicle.params.as_deref())?;
                t.check_torque_vehicle(&v)
                    .with_context(|| format!("vehicle.torque_table {}", p.display()))?;
                Some(t)
            }
        }
        None => None,
    };
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
    let mut stage = ObserverStage::new(&cfg.settings, table)?.with_torque_table(torque)?;
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

/// The profile's own table (`own`, loaded from `path`) with the profile's correction attached
/// ([`crate::profile::Profile::corrected`]); a table given in its place is another table, which
/// the profile's correction does not describe.
fn with_correction(
    profile: &crate::profile::Profile,
    own: Option<&std::path::Path>,
    path: &std::path::Path,
    t: ResponseTable,
) -> anyhow::Result<ResponseTable> {
    let same = |a: &std::path::Path, b: &std::path::Path| match (a.canonicalize(), b.canonicalize())
    {
        (Ok(a), Ok(b)) => a == b,
        _ => a == b,
    };
    if own.is_some_and(|o| same(o, path)) {
        profile.corrected(t)
    } else {
        Ok(t)
    }
}
