//! `bus.toml`: a car's CAN bus as it is on the road, one entry per message the car sends that
//! matters to the monitor or to recognising the car: its DBC name and the period measured on a
//! real log (or documented for the car).
//!
//! What it is: the file format and its checks against the profile's DBC. `shimmy identify`
//! ([`super::identify`]) compares a log's message periods with these; firmware-sim emulates
//! the bus from the same file. What it is not: the signal mapping (which signal carries what
//! for the monitor is `mapping.toml`, [`crate::signals::mapping`]).

use std::path::Path;

use anyhow::{bail, Context};
use serde::{Deserialize, Serialize};

use crate::dbc::Database;

/// The whole file.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct BusSpec {
    /// The messages, each once.
    #[serde(rename = "message")]
    pub messages: Vec<BusMessage>,
}

/// One message of the bus.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct BusMessage {
    /// The DBC message name.
    pub name: String,
    /// Nominal send period (ms).
    pub period_ms: f64,
}

impl BusSpec {
    pub fn from_toml_str(text: &str) -> anyhow::Result<BusSpec> {
        let b: BusSpec = toml::from_str(text)?;
        b.validate()?;
        Ok(b)
    }

    pub fn load(path: &Path) -> anyhow::Result<BusSpec> {
        let text = std::fs::read_to_string(path)
            .with_context(|| format!("cannot read bus description {}", path.display()))?;
        BusSpec::from_toml_str(&text).with_context(|| format!("in {}", path.display()))
    }

    /// The checks serde cannot express.
    pub fn validate(&self) -> anyhow::Result<()> {
        let mut seen = std::collections::BTreeSet::new();
        for (i, m) in self.messages.iter().enumerate() {
            if !seen.insert(m.name.as_str()) {
                bail!("message[{i}]: `{}` is listed twice", m.name);
            }
            if !(m.period_ms.is_finite() && m.period_ms > 0.0 && m.period_ms <= 60_000.0) {
                bail!(
                    "message[{i}] `{}`: period_ms must be in (0, 60000] (got {})",
                    m.name,
                    m.period_ms
                );
            }
        }
        Ok(())
    }

    /// Every message exists in `db`; returns (frame id, extended, DLC, period ms) per message
    /// in file order.
    pub fn resolve(&self, db: &Database) -> anyhow::Result<Vec<(u32, bool, usize, f64)>> {
        self.messages
            .iter()
            .map(|m| {
                let i = db
                    .message_by_name(&m.name)
                    .with_context(|| format!("bus message `{}` is not in the DBC", m.name))?;
                let msg = &db.messages()[i];
                Ok((msg.id, msg.extended, msg.size_bytes, m.period_ms))
            })
            .collect()
    }
}
