//! Chooses the event stage for a configuration. Today: [`NoObserver`] (no detection, no
//! estimate — never a fake one); the clearance observer plugs in here once it is on main.

use super::config::Config;
use super::pipeline::{EventStage, NoObserver};

pub fn for_config(_cfg: &Config) -> anyhow::Result<Box<dyn EventStage>> {
    Ok(Box::new(NoObserver))
}
