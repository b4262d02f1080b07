//! shimmyd's persisted state, what survives a restart: clearance estimate, recent event history,
//! odometer, open alerts and the last joint replacement the workshop marked ([`Replacement`]),
//! in `<state_dir>/state.json`, written atomically.
//!
//! Atomic write: the new content goes to `state.json.tmp`, which is fsynced, renamed over
//! `state.json`, and the directory is fsynced; a crash at any instant leaves either the old or
//! the new file, never a mix. A state file that does not parse is moved aside
//! (`state.json.bad-<unix time>`) and reported, never silently overwritten.
//!
//! What it is not: the event journal (the journal is the complete record; the state is what the
//! daemon needs to resume quickly).

use std::fs::{self, File};
use std::io::Write;
use std::path::{Path, PathBuf};

use anyhow::Context;
use serde::{Deserialize, Serialize};

use crate::alerts::AlertBook;
use crate::monitor::{Estimate, EventSummary};

/// Most events kept in the state's history (the journal keeps all of them).
pub const HISTORY: usize = 200;

#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
#[serde(default)]
pub struct State {
    pub version: u32,
    pub odometer_km: f64,
    pub estimate: Option<Estimate>,
    pub events: Vec<EventSummary>,
    pub events_total: u64,
    pub alerts: AlertBook,
    /// Last journal sequence number covered by this state.
    pub journal_seq: Option<u64>,
    /// The event stage's own state (the clearance posterior's evidence), see
    /// [`crate::monitor::EventStage::save`].
    pub stage: Option<serde_json::Value>,
    /// Last speed sample (log time ns, m/s), so the odometer integration continues across a
    /// restart when the input continues within a second (a log split in two).
    pub last_speed: Option<(i64, f64)>,
    /// The journal's health when the state was saved ([`crate::journal::Health`]): whether it
    /// writes, its backlog and drops during a disk outage.
    pub journal: Option<crate::journal::Health>,
    /// The last joint replacement the workshop marked (`<state_dir>/joints_replaced`,
    /// [`super::joints`]). The baseline collection it started, and the baseline it made, are
    /// the event stage's (`stage`).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub replacement: Option<Replacement>,
}

/// A joint replacement the daemon was told of with the marker file.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct Replacement {
    /// The marker file handled: the same file seen again (the daemon stopped after saving this
    /// state but before removing it) is only removed.
    pub marker: super::joints::MarkerId,
    /// Log time (the input's clock, s) when the daemon took it; `None` before the first frame.
    pub t: Option<f64>,
    /// Wall clock when the daemon took it (s since the Unix epoch; information only).
    pub wall_unix_s: f64,
    pub odometer_km: f64,
    /// The new joints' clearance (mm): the marker's, else `vehicle.baseline_clearance_mm`.
    pub clearance_mm: f64,
    /// Used braking events asked for the new baseline (`vehicle.baseline_events` then).
    pub baseline_events: u32,
    /// `vehicle.baseline_logs` and `vehicle.baseline_clearance_mm` then: when the logs
    /// configured at a later start differ, they are newer than this replacement and their
    /// baseline is used.
    pub baseline_logs: Vec<PathBuf>,
    pub baseline_clearance_mm: f64,
}

impl Replacement {
    /// Whether the baseline configured now (`logs` at `clearance_mm`) was configured after this
    /// replacement: set, and not what was configured when it was marked.
    pub fn configured_baseline_is_newer(&self, logs: &[PathBuf], clearance_mm: f64) -> bool {
        !logs.is_empty()
            && (logs != self.baseline_logs.as_slice() || clearance_mm != self.baseline_clearance_mm)
    }
}

impl State {
    pub fn push_event(&mut self, e: EventSummary) {
        if self.events.len() >= HISTORY {
            self.events.remove(0);
        }
        self.events.push(e);
        self.events_total += 1;
    }
}

fn path(dir: &Path) -> PathBuf {
    dir.join("state.json")
}

/// Loads the state; `Ok(None)` when there is none. A corrupt file is moved aside and reported
/// through the returned message.
pub fn load(dir: &Path) -> anyhow::Result<(Option<State>, Option<String>)> {
    let p = path(dir);
    let text = match fs::read(&p) {
        Ok(t) => t,
        Err(e) if e.kind() == std::io::ErrorKind::NotFound => return Ok((None, None)),
        Err(e) => return Err(e).with_context(|| format!("cannot read {}", p.display())),
    };
    match serde_json::from_slice::<State>(&text) {
        Ok(s) => Ok((Some(s), None)),
        Err(e) => {
            let secs = std::time::SystemTime::now()
                .duration_since(std::time::UNIX_EPOCH)
                .map_or(0, |d| d.as_secs());
            let aside = dir.join(format!("state.json.bad-{secs}"));
            fs::rename(&p, &aside)
                .with_context(|| format!("cannot move corrupt {} aside", p.display()))?;
            Ok((
                None,
                Some(format!(
                    "{} did not parse ({e}); moved to {} and starting fresh",
                    p.display(),
                    aside.display()
                )),
            ))
        }
    }
}

/// Writes `bytes` to `dir/name` atomically (temp file, fsync, rename, fsync directory).
pub fn write_atomic(dir: &Path, name: &str, bytes: &[u8]) -> anyhow::Result<()> {
    fs::create_dir_all(dir).with_context(|| format!("cannot create {}", dir.display()))?;
    let tmp = dir.join(format!("{name}.tmp"));
    let dst = dir.join(name);
    {
        let mut f =
            File::create(&tmp).with_context(|| format!("cannot create {}", tmp.display()))?;
        f.write_all(bytes)?;
        f.sync_all()
            .with_context(|| format!("cannot fsync {}", tmp.display()))?;
    }
    fs::rename(&tmp, &dst).with_context(|| format!("cannot rename to {}", dst.display()))?;
    File::open(dir)?.sync_all()?;
    Ok(())
}

pub fn save(dir: &Path, s: &State) -> anyhow::Result<()> {
    let bytes = serde_json::to_vec_pretty(s)?;
    write_atomic(dir, "state.json", &bytes)
}
