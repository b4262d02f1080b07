//! The workshop's "joints replaced" marker: how a running shimmyd is told that the steering
//! joints were just replaced, without a network listener and without any privilege beyond
//! writing into the daemon's state directory.
//!
//! The marker is the file `<state_dir>/joints_replaced` ([`MARKER`]). Empty (`touch`), the new
//! joints' clearance is `vehicle.baseline_clearance_mm`; otherwise it holds that clearance in
//! millimetres (`0.04`, optionally followed by `mm`). `shimmyd --joints-replaced [MM]` writes it
//! atomically ([`write_marker`]). What the daemon does with it is [`super::run`]'s: it journals a
//! `joints_replaced` record, clears the alerts the old joints raised, resets the clearance
//! estimate and takes the next `vehicle.baseline_events` used braking events as the vehicle's
//! new baseline; the marker is removed once the state recording all that is saved.
//!
//! This module: looking at the marker ([`look`]: one `stat(2)` when there is none, which is the
//! usual case), its content's rules ([`parse_clearance`]), its identity ([`MarkerId`], kept in
//! the state so that a marker seen again after a crash before its removal is not applied
//! twice), renaming a bad one to [`REJECTED`] and removing a handled one.
//!
//! What it is not: the reset or the baseline collection (the event stage's,
//! [`crate::pipeline::ObserverStage::joints_replaced`]) or the journal records (the loop's).

use std::fs;
use std::io::{Read, Write};
use std::path::{Path, PathBuf};
use std::time::{Duration, SystemTime, UNIX_EPOCH};

use anyhow::{bail, Context};
use serde::{Deserialize, Serialize};

/// The marker's file name in the state directory.
pub const MARKER: &str = "joints_replaced";
/// What a marker with bad content is renamed to.
pub const REJECTED: &str = "joints_replaced.rejected";
/// Largest marker read (bytes): a clearance is a few characters.
const MAX_BYTES: u64 = 64;
/// An empty marker younger than this may still be being written (`echo 0.04 > joints_replaced`
/// creates the file before writing it): it is looked at again later.
pub const SETTLE: Duration = Duration::from_secs(1);
/// Largest clearance a marker may give (mm): a larger number is a unit mistake (µm).
pub const MAX_CLEARANCE_MM: f64 = 1.0;

/// Which marker file was handled: its modification time, size and content. The state keeps it,
/// so that the same file, seen again because the daemon stopped between saving its state and
/// removing the marker, is only removed.
#[derive(Clone, Debug, PartialEq, Eq, Serialize, Deserialize)]
pub struct MarkerId {
    /// Modification time, ns since the Unix epoch (0 when the file system has none).
    pub mtime_ns: u64,
    pub bytes: u64,
    /// The content, trimmed.
    pub content: String,
}

impl MarkerId {
    /// The modification time in s since the Unix epoch.
    pub fn mtime_unix_s(&self) -> f64 {
        self.mtime_ns as f64 * 1e-9
    }
}

/// What [`look`] found.
#[derive(Clone, Debug, PartialEq)]
pub enum Seen {
    /// No marker (the usual case).
    Nothing,
    /// An empty marker younger than [`SETTLE`]: perhaps still being written; look again later.
    Settling,
    /// A marker; `clearance_mm` is its content's clearance (`None`: empty, use the default).
    Marker {
        id: MarkerId,
        clearance_mm: Option<f64>,
    },
    /// A marker that cannot be taken, and why (to be renamed to [`REJECTED`]).
    Bad { reason: String },
    /// The state directory cannot be looked at (e.g. permissions): the error.
    Unreadable(String),
}

/// The marker's path in `state_dir`.
pub fn path(state_dir: &Path) -> PathBuf {
    state_dir.join(MARKER)
}

/// Looks for the marker in `state_dir`: one `lstat(2)` when there is none; when there is, it is
/// read (at most 64 bytes, without following a symbolic link or blocking on a FIFO).
pub fn look(state_dir: &Path) -> Seen {
    let p = path(state_dir);
    let meta = match fs::symlink_metadata(&p) {
        Ok(m) => m,
        Err(e) if e.kind() == std::io::ErrorKind::NotFound => return Seen::Nothing,
        Err(e) => return Seen::Unreadable(format!("cannot look at {}: {e}", p.display())),
    };
    if !meta.file_type().is_file() {
        return Seen::Bad {
            reason: "it is not a regular file (a symbolic link, directory or other)".into(),
        };
    }
    if meta.len() > MAX_BYTES {
        return Seen::Bad {
            reason: format!(
                "it holds {} bytes; it should be empty or hold the new joints' clearance in mm \
                 (e.g. 0.04)",
                meta.len()
            ),
        };
    }
    let mut text = Vec::with_capacity(MAX_BYTES as usize + 1);
    let read = open_no_follow(&p).and_then(|f| f.take(MAX_BYTES + 1).read_to_end(&mut text));
    match read {
        Ok(_) => {}
        // Removed between the two looks: nothing there now.
        Err(e) if e.kind() == std::io::ErrorKind::NotFound => return Seen::Nothing,
        Err(e) => return Seen::Unreadable(format!("cannot read {}: {e}", p.display())),
    }
    let Ok(text) = String::from_utf8(text) else {
        return Seen::Bad {
            reason: "its content is not text; it should be empty or hold the new joints' \
                     clearance in mm (e.g. 0.04)"
                .into(),
        };
    };
    let content = text.trim().to_string();
    let mtime = meta.modified().ok();
    if content.is_empty() {
        let young = mtime
            .and_then(|m| SystemTime::now().duration_since(m).ok())
            .is_some_and(|age| age < SETTLE);
        if young {
            return Seen::Settling;
        }
    }
    let id = MarkerId {
        mtime_ns: mtime
            .and_then(|m| m.duration_since(UNIX_EPOCH).ok())
            .map_or(0, |d| u64::try_from(d.as_nanos()).unwrap_or(u64::MAX)),
        bytes: text.len() as u64,
        content,
    };
    match parse_clearance(&id.content) {
        Ok(clearance_mm) => Seen::Marker { id, clearance_mm },
        Err(reason) => Seen::Bad { reason },
    }
}

#[cfg(target_os = "linux")]
fn open_no_follow(p: &Path) -> std::io::Result<fs::File> {
    use std::os::unix::fs::OpenOptionsExt;
    fs::OpenOptions::new()
        .read(true)
        .custom_flags(libc::O_NOFOLLOW | libc::O_NONBLOCK)
        .open(p)
}

#[cfg(not(target_os = "linux"))]
fn open_no_follow(p: &Path) -> std::io::Result<fs::File> {
    fs::File::open(p)
}

/// The clearance a marker's (trimmed) content gives: `None` for an empty marker (the default
/// applies), else a number of millimetres above 0 and at most [`MAX_CLEARANCE_MM`], optionally
/// followed by `mm`. The error says what is wrong and what is expected.
pub fn parse_clearance(content: &str) -> Result<Option<f64>, String> {
    let t = content.trim();
    if t.is_empty() {
        return Ok(None);
    }
    let number = t
        .strip_suffix("mm")
        .or_else(|| t.strip_suffix("MM"))
        .unwrap_or(t)
        .trim_end();
    let shown: String = t.chars().take(32).collect();
    let Ok(c) = number.parse::<f64>() else {
        return Err(format!(
            "its content {shown:?} is not a clearance in mm; it should be empty (the clearance \
             is then vehicle.baseline_clearance_mm) or a number such as 0.04"
        ));
    };
    if !c.is_finite() || c <= 0.0 {
        return Err(format!(
            "its content {shown:?} is not a clearance above 0 mm (new joints: about 0.02-0.06 mm)"
        ));
    }
    if c > MAX_CLEARANCE_MM {
        return Err(format!(
            "its content {shown:?} is above {MAX_CLEARANCE_MM} mm: the clearance is in \
             millimetres (new joints: about 0.02-0.06 mm)"
        ));
    }
    Ok(Some(c))
}

/// Renames a bad marker to [`REJECTED`] (replacing an earlier one); the new path.
pub fn reject(state_dir: &Path) -> anyhow::Result<PathBuf> {
    let (from, to) = (path(state_dir), state_dir.join(REJECTED));
    fs::rename(&from, &to).with_context(|| {
        format!(
            "cannot rename {} to {}; remove it by hand",
            from.display(),
            to.display()
        )
    })?;
    sync_dir(state_dir);
    Ok(to)
}

/// Removes the handled marker `id` from `state_dir`, unless the file there is no longer that
/// one (a new marker written meanwhile is left for the next look). Returns whether it removed
/// it.
pub fn remove(state_dir: &Path, id: &MarkerId) -> anyhow::Result<bool> {
    match look(state_dir) {
        Seen::Marker { id: now, .. } if &now == id => {}
        _ => return Ok(false),
    }
    let p = path(state_dir);
    match fs::remove_file(&p) {
        Ok(()) => {}
        Err(e) if e.kind() == std::io::ErrorKind::NotFound => return Ok(false),
        Err(e) => return Err(e).with_context(|| format!("cannot remove {}", p.display())),
    }
    sync_dir(state_dir);
    Ok(true)
}

/// fsyncs a directory after a rename or removal in it (best effort: the marker's fate is also
/// recorded in the state, which is written with a directory fsync).
fn sync_dir(dir: &Path) {
    if let Ok(d) = fs::File::open(dir) {
        let _ = d.sync_all();
    }
}

/// `shimmyd --joints-replaced [MM]`: writes the marker into `state_dir` for the daemon that
/// uses it, atomically (a temporary file renamed into place, so the daemon never reads a
/// half-written marker); `clearance` is the content (empty: the daemon's
/// `vehicle.baseline_clearance_mm`), checked by the daemon's own rules first. The state
/// directory must exist (the daemon creates it with its owner; creating it here, perhaps as
/// another user, could lock the daemon out). The marker is made readable by all (mode 0644):
/// the daemon, under its own user, reads it and, owning the directory, removes it. Returns the
/// marker's path.
pub fn write_marker(state_dir: &Path, clearance: &str) -> anyhow::Result<PathBuf> {
    let content = clearance.trim();
    parse_clearance(content).map_err(|e| anyhow::anyhow!("--joints-replaced: {e}"))?;
    if !state_dir.is_dir() {
        bail!(
            "outputs.state_dir {} does not exist: has shimmyd run with this configuration? \
             (give --state-dir when it runs with another)",
            state_dir.display()
        );
    }
    let tmp = state_dir.join(format!(".{MARKER}.{}.tmp", std::process::id()));
    let dst = path(state_dir);
    let write = || -> anyhow::Result<()> {
        let mut f =
            fs::File::create(&tmp).with_context(|| format!("cannot create {}", tmp.display()))?;
        if !content.is_empty() {
            writeln!(f, "{content}")?;
        }
        // Readable by the daemon's user whatever the writer's umask (root's may be 077).
        #[cfg(unix)]
        {
            use std::os::unix::fs::PermissionsExt;
            f.set_permissions(fs::Permissions::from_mode(0o644))
                .with_context(|| format!("cannot set the mode of {}", tmp.display()))?;
        }
        f.sync_all()
            .with_context(|| format!("cannot fsync {}", tmp.display()))?;
        fs::rename(&tmp, &dst).with_context(|| format!("cannot rename to {}", dst.display()))?;
        Ok(())
    };
    if let Err(e) = write() {
        let _ = fs::remove_file(&tmp);
        return Err(e);
    }
    sync_dir(state_dir);
    Ok(dst)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn content_rules() {
        assert_eq!(parse_clearance(""), Ok(None));
        assert_eq!(parse_clearance(" \n"), Ok(None));
        assert_eq!(parse_clearance("0.04\n"), Ok(Some(0.04)));
        assert_eq!(parse_clearance("0.05 mm"), Ok(Some(0.05)));
        assert_eq!(parse_clearance("0.05mm"), Ok(Some(0.05)));
        for bad in ["abc", "0", "-0.02", "NaN", "inf", "40", "0.04 inch"] {
            let e = parse_clearance(bad).unwrap_err();
            assert!(e.contains(&format!("{bad:?}")), "{bad}: {e}");
        }
        assert!(parse_clearance("30").unwrap_err().contains("millimetres"));
    }

    #[test]
    fn look_reject_remove_and_write() {
        let dir = tempfile::tempdir().unwrap();
        let d = dir.path();
        assert_eq!(look(d), Seen::Nothing);
        // A fresh empty marker may still be being written.
        fs::write(path(d), "").unwrap();
        assert_eq!(look(d), Seen::Settling);
        let old = SystemTime::now() - Duration::from_secs(5);
        fs::File::options()
            .write(true)
            .open(path(d))
            .unwrap()
            .set_modified(old)
            .unwrap();
        let Seen::Marker { id, clearance_mm } = look(d) else {
            panic!("{:?}", look(d))
        };
        assert_eq!(clearance_mm, None);
        assert!(id.mtime_ns > 0 && id.content.is_empty());
        // A marker written again in between is a new one, and is not removed.
        write_marker(d, "0.045").unwrap();
        assert!(!remove(d, &id).unwrap());
        let Seen::Marker { id, clearance_mm } = look(d) else {
            panic!("{:?}", look(d))
        };
        assert_eq!(clearance_mm, Some(0.045));
        assert!(remove(d, &id).unwrap());
        assert_eq!(look(d), Seen::Nothing);
        fs::write(path(d), "zero").unwrap();
        assert!(matches!(look(d), Seen::Bad { .. }));
        assert_eq!(reject(d).unwrap(), d.join(REJECTED));
        assert_eq!(look(d), Seen::Nothing);
        assert!(write_marker(d, "-1").is_err());
        assert!(write_marker(&d.join("missing"), "").is_err());
        assert_eq!(look(d), Seen::Nothing);
    }

    #[cfg(unix)]
    #[test]
    fn a_symbolic_link_is_not_followed() {
        let dir = tempfile::tempdir().unwrap();
        let target = dir.path().join("elsewhere");
        fs::write(&target, "0.04").unwrap();
        std::os::unix::fs::symlink(&target, path(dir.path())).unwrap();
        assert!(matches!(look(dir.path()), Seen::Bad { .. }));
    }
}
