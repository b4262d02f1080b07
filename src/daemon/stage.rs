//! Chooses the event stage for a configuration: the clearance observer
//! ([`super::observer_stage::ObserverStage`]), with the response table of `vehicle.table` when
//! set. Without a table, events and the shimmy-amplitude alert still work; the clearance is
//! not estimated (never a fake estimate).

use anyhow::Context;

use super::config::Config;
use super::observer_stage::ObserverStage;
use super::pipeline::EventStage;
use crate::observer::table::ResponseTable;

pub fn for_config(cfg: &Config) -> anyhow::Result<Box<dyn EventStage>> {
    let table = match &cfg.vehicle.table {
        Some(p) => Some(
            ResponseTable::load(p)
                .with_context(|| format!("vehicle.table: cannot load {}", p.display()))?,
        ),
        None => None,
    };
    Ok(Box::new(ObserverStage::new(cfg, table)?))
}
