//! The journal on a real, tiny filesystem (a 256 KiB tmpfs): the kernel's own `ENOSPC` when it
//! fills up and `EROFS` when it is read-only, with the journal opened tolerant as shimmyd opens
//! it. Acknowledged records stay, the outage's records reach the disk in order once space
//! returns or the filesystem is writable again, and nothing on disk is torn.
//!
//! Needs root (mount). Without it the test prints `SKIPPED`; with `SHIMMY_REQUIRE_TMPFS=1`
//! it fails instead: the vcan VM suite (`tests/vcan/suite.txt`, run by `tests/vcan_vm.rs`
//! under CI) sets it, so CI always runs it there. The same outages through the fault-injecting
//! layer run everywhere: `tests/journal_faults.rs`.
//!
//! And shimmyd itself, as a process, replaying the demo log with its journal on a tmpfs that
//! fills up: it keeps monitoring (the same events, estimate and alerts in its state as with
//! room to spare), says so on stderr and in its state, and its journal holds no torn line.
//!
//! What it does not show: a filesystem turning read-only while the journal has its file open
//! (the kernel refuses to remount a filesystem with files open for writing, except on its own
//! errors, e.g. ext4's `errors=remount-ro`); that path is the fault layer's test.

#![cfg(target_os = "linux")]

mod e2e_common;

use std::io::Write;
use std::path::{Path, PathBuf};
use std::process::Command;
use std::time::Duration;

use serde_json::json;
use shimmy::journal::{FsyncPolicy, Journal, JournalConfig, Reader, Setup, Tolerance};

fn report(line: &str) {
    let _ = writeln!(std::io::stderr(), "{line}");
}

/// A tmpfs of `size` mounted on a fresh directory, unmounted on drop.
struct Tmpfs {
    dir: PathBuf,
    _parent: tempfile::TempDir,
}

impl Tmpfs {
    fn mount(size: &str) -> Result<Tmpfs, String> {
        let parent = tempfile::tempdir().map_err(|e| e.to_string())?;
        let dir = parent.path().join("fs");
        std::fs::create_dir(&dir).map_err(|e| e.to_string())?;
        mount(
            &["-t", "tmpfs", "-o", &format!("size={size}"), "tmpfs"],
            &dir,
        )?;
        Ok(Tmpfs {
            dir,
            _parent: parent,
        })
    }

    fn remount(&self, opt: &str) {
        mount(&["-o", &format!("remount,{opt}")], &self.dir)
            .unwrap_or_else(|e| panic!("remount {opt}: {e}"));
    }
}

impl Drop for Tmpfs {
    fn drop(&mut self) {
        let _ = Command::new("umount").arg(&self.dir).status();
    }
}

fn mount(args: &[&str], dir: &Path) -> Result<(), String> {
    let out = Command::new("mount")
        .args(args)
        .arg(dir)
        .output()
        .map_err(|e| format!("mount: {e}"))?;
    if out.status.success() {
        Ok(())
    } else {
        Err(String::from_utf8_lossy(&out.stderr).trim().to_string())
    }
}

/// `None` (skip) when this machine cannot mount a tmpfs and the test is not required.
fn tmpfs(size: &str) -> Option<Tmpfs> {
    match Tmpfs::mount(size) {
        Ok(t) => Some(t),
        Err(e) if std::env::var_os("SHIMMY_REQUIRE_TMPFS").is_some() => {
            panic!("SHIMMY_REQUIRE_TMPFS is set but a tmpfs cannot be mounted: {e}")
        }
        Err(e) => {
            report(&format!(
                "SKIPPED journal_tmpfs: cannot mount a tmpfs ({e}); needs root (CI runs it in the vcan VM)"
            ));
            None
        }
    }
}

fn open(dir: &Path) -> Journal {
    Journal::open_with(
        dir,
        JournalConfig {
            fsync: FsyncPolicy::Always,
            rotate_bytes: 64 * 1024,
        },
        Setup {
            tolerance: Some(Tolerance {
                backlog_bytes: 1 << 20,
                retry_every: Duration::ZERO,
            }),
            ..Setup::default()
        },
    )
    .expect("open the journal")
    .0
}

fn record(n: u64) -> serde_json::Value {
    json!({ "type": "event", "n": n, "pad": "x".repeat(900) })
}

/// (seqs, n fields, invalid lines) of what is on disk.
fn on_disk(dir: &Path) -> (Vec<u64>, Vec<u64>, u64) {
    let mut r = Reader::open(dir).unwrap();
    let (mut seqs, mut ns) = (Vec::new(), Vec::new());
    for e in &mut r {
        let e = e.unwrap();
        seqs.push(e.seq);
        ns.push(e.rec["n"].as_u64().unwrap());
    }
    (seqs, ns, r.invalid_lines())
}

#[test]
fn a_full_then_read_only_tmpfs_loses_no_acknowledged_record() {
    let Some(fs) = tmpfs("256k") else {
        return;
    };
    let jdir = fs.dir.join("journal");
    let mut j = open(&jdir);
    // Fill the disk until the journal notices (a real ENOSPC from the kernel).
    let mut n = 0u64;
    while j.writable() {
        j.append(&record(n)).unwrap();
        n += 1;
        assert!(n < 1000, "a 256 KiB tmpfs never filled up");
    }
    let h = j.health();
    assert!(
        h.error
            .as_deref()
            .unwrap()
            .contains("No space left on device"),
        "{h:?}"
    );
    let acked = j.durable_seq().unwrap();
    report(&format!(
        "journal_tmpfs: disk full after {acked} acknowledged records: {h:?}"
    ));
    // The journal cut its torn line: what is on disk is exactly what was acknowledged.
    let (seqs, _, invalid) = on_disk(&jdir);
    assert_eq!(seqs, (1..=acked).collect::<Vec<_>>());
    assert_eq!(invalid, 0);

    // The outage goes on; then the filesystem turns read-only (the waiting journal holds no
    // file open, so the kernel allows it).
    for _ in 0..20 {
        j.append(&record(n)).unwrap();
        n += 1;
    }
    fs.remount("ro");
    for _ in 0..20 {
        j.append(&record(n)).unwrap();
        n += 1;
    }
    j.sync().unwrap();
    let h = j.health();
    assert!(!h.writable);
    assert!(
        h.error.as_deref().unwrap().contains("No space left")
            || h.error.as_deref().unwrap().contains("Read-only"),
        "{h:?}"
    );
    assert!(h.write_errors >= 2, "{h:?}");
    assert_eq!(j.durable_seq(), Some(acked));

    // Writable again and room made (the operator prunes old segments): all of it lands.
    fs.remount("rw");
    for seg in shimmy::journal::segments(&jdir).unwrap() {
        if seg.file_name().unwrap() != shimmy::journal::CURRENT {
            std::fs::remove_file(seg).unwrap();
            break;
        }
    }
    // The rest of the outage's records may still not fit: keep pruning until they do.
    let mut pruned = 1;
    loop {
        j.sync().unwrap();
        if j.writable() {
            break;
        }
        let segs = shimmy::journal::segments(&jdir).unwrap();
        assert!(segs.len() > 1, "nothing left to prune: {:?}", j.health());
        std::fs::remove_file(&segs[0]).unwrap();
        pruned += 1;
    }
    let h = j.health();
    assert_eq!((h.backlog_records, h.dropped_records), (0, 0), "{h:?}");
    assert_eq!(j.durable_seq(), Some(n));
    let (seqs, ns, invalid) = on_disk(&jdir);
    assert_eq!(invalid, 0);
    // The pruned segments are gone; everything after them is there, in order.
    let first = seqs[0];
    assert_eq!(seqs, (first..=n).collect::<Vec<_>>());
    assert_eq!(ns, (first - 1..n).collect::<Vec<_>>());
    report(&format!(
        "journal_tmpfs: writing again after pruning {pruned} segment(s): {} late records written, last seq {n}",
        h.delayed_records
    ));
}

#[test]
fn a_tmpfs_read_only_at_start_is_caught_up_when_writable() {
    let Some(fs) = tmpfs("256k") else {
        return;
    };
    let jdir = fs.dir.join("journal");
    {
        let mut j = open(&jdir);
        for n in 0..5 {
            j.append(&record(n)).unwrap();
        }
    }
    fs.remount("ro");
    let mut j = open(&jdir);
    let h = j.health();
    assert!(!h.writable, "{h:?}");
    assert!(
        h.error
            .as_deref()
            .unwrap()
            .contains("Read-only file system"),
        "{h:?}"
    );
    for n in 5..10 {
        assert_eq!(j.append(&record(n)).unwrap(), n + 1);
    }
    j.sync().unwrap();
    assert!(!j.writable());
    fs.remount("rw");
    j.sync().unwrap();
    assert!(j.writable(), "{:?}", j.health());
    drop(j);
    let (seqs, ns, invalid) = on_disk(&jdir);
    assert_eq!(seqs, (1..=10).collect::<Vec<_>>());
    assert_eq!(ns, (0..10).collect::<Vec<_>>());
    assert_eq!(invalid, 0);
}

/// `shimmyd --replay` of the demo log with the journal in `journal`; (exit ok, stderr, state).
fn shimmyd_replay(dir: &Path, journal: &Path) -> (bool, String, serde_json::Value) {
    let cfg = e2e_common::write_config(dir, "");
    let text = std::fs::read_to_string(&cfg).unwrap().replace(
        "journal_dir = \"journal\"",
        &format!("journal_dir = {:?}", journal.display().to_string()),
    );
    std::fs::write(&cfg, text).unwrap();
    let log = e2e_common::workspace().join("tests/fixtures/demo/worn_0p2mm.log");
    let state = dir.join("state");
    let out = e2e_common::replay_command(&cfg, &log, Some(&state))
        .output()
        .expect("start shimmyd");
    let st = serde_json::from_slice(&std::fs::read(state.join("state.json")).unwrap()).unwrap();
    (
        out.status.success(),
        String::from_utf8_lossy(&out.stderr).into_owned(),
        st,
    )
}

#[test]
fn shimmyd_keeps_monitoring_when_its_journal_disk_is_full() {
    let Some(fs) = tmpfs("64k") else {
        return;
    };
    // Room for the start record and little more.
    std::fs::write(fs.dir.join("filler"), vec![0u8; 60 * 1024]).unwrap();
    let tmp = tempfile::tempdir().unwrap();
    let (ok, err, full) = shimmyd_replay(tmp.path(), &fs.dir.join("journal"));
    assert!(ok, "shimmyd failed on a full journal disk:\n{err}");
    let roomy = tempfile::tempdir().unwrap();
    let (ok2, err2, normal) = shimmyd_replay(roomy.path(), &roomy.path().join("journal"));
    assert!(ok2, "{err2}");

    // Monitoring went on: the same events, estimate and alerts as with room to spare.
    assert!(normal["events_total"].as_u64().unwrap() >= 3, "{normal}");
    for k in [
        "events_total",
        "events",
        "estimate",
        "alerts",
        "odometer_km",
    ] {
        assert_eq!(
            full[k], normal[k],
            "state.{k} differs with a full journal disk"
        );
    }
    // Said in the log and in the state.
    assert!(
        err.contains("journal: the disk refuses writes (cannot write to the journal: No space left on device"),
        "{err}"
    );
    assert!(err.contains("still refused by the disk at exit"), "{err}");
    assert!(err.contains("journal_errors="), "counters line: {err}");
    let h = &full["journal"];
    assert_eq!(h["writable"], false, "{h}");
    assert!(h["backlog_records"].as_u64().unwrap() > 0, "{h}");
    assert_eq!(normal["journal"]["writable"], true);
    assert_eq!(normal["journal"]["write_errors"], 0);
    // What reached the disk is whole: the start record at least, no torn line.
    let mut r = Reader::open(&fs.dir.join("journal")).unwrap();
    let recs: Vec<_> = (&mut r).map(|e| e.unwrap()).collect();
    assert_eq!(recs[0].rec["type"], "start");
    assert_eq!(r.invalid_lines(), 0);
    report(&format!(
        "journal_tmpfs: shimmyd on a full journal disk: {} record(s) on disk, health {h}",
        recs.len()
    ));
}
