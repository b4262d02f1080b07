//! The journal on a disk that fills up or turns read-only, and under a wall clock that jumps,
//! through the fault-injecting layer ([`shimmy::journal::fault::DiskFaults`]) over real files:
//! acknowledged records stay; records of the outage wait in the bounded backlog and reach the
//! disk, in order, when it takes writes again, or are counted as dropped and show as a gap;
//! the journal says which state it is in ([`Journal::health`]). The real small filesystem
//! (tmpfs in the VM) is the vcan suite's `journal_tmpfs` step.

use std::time::Duration;

use serde_json::json;
use shimmy::journal::clock::{ManualClock, WallClock};
use shimmy::journal::fault::DiskFaults;
use shimmy::journal::{
    FsyncPolicy, Journal, JournalConfig, Reader, Recovery, Setup, Tolerance, CURRENT,
};

fn cfg(fsync: FsyncPolicy, rotate: u64) -> JournalConfig {
    JournalConfig {
        fsync,
        rotate_bytes: rotate,
    }
}

/// A tolerant journal on `disk`, retrying at every call (no waiting in tests).
fn open(
    dir: &std::path::Path,
    c: JournalConfig,
    disk: &DiskFaults,
    backlog_bytes: usize,
) -> (Journal, Recovery) {
    Journal::open_with(
        dir,
        c,
        Setup {
            tolerance: Some(Tolerance {
                backlog_bytes,
                retry_every: Duration::ZERO,
            }),
            faults: Some(Box::new(disk.clone())),
            clock: None,
        },
    )
    .unwrap()
}

/// (sequence numbers, `n` fields, invalid lines, missing seqs) of what is on disk.
fn on_disk(dir: &std::path::Path) -> (Vec<u64>, Vec<u64>, u64, u64) {
    let mut r = Reader::open(dir).unwrap();
    let mut seqs = Vec::new();
    let mut ns = Vec::new();
    for e in &mut r {
        let e = e.unwrap();
        seqs.push(e.seq);
        ns.push(e.rec["n"].as_u64().unwrap());
    }
    (seqs, ns, r.invalid_lines(), r.missing())
}

#[test]
fn a_full_disk_delays_records_and_loses_none() {
    for fsync in [FsyncPolicy::Always, FsyncPolicy::IntervalMs(0)] {
        let dir = tempfile::tempdir().unwrap();
        let disk = DiskFaults::new();
        let (mut j, _) = open(dir.path(), cfg(fsync, 1 << 30), &disk, 1 << 20);
        for n in 0..10u64 {
            j.append(&json!({ "n": n })).unwrap();
        }
        j.sync().unwrap();
        assert_eq!(j.durable_seq(), Some(10));
        assert!(j.health().writable);
        let before = std::fs::read(dir.path().join(CURRENT)).unwrap();

        // 30 bytes left: the next record is written in part (a torn line), then ENOSPC.
        disk.set_free(Some(30));
        for n in 10..50u64 {
            assert_eq!(j.append(&json!({ "n": n })).unwrap(), n + 1, "{fsync:?}");
        }
        j.sync().unwrap();
        let h = j.health();
        assert!(!h.writable, "{h:?}");
        assert!(
            h.error.as_deref().unwrap().contains("No space left"),
            "{h:?}"
        );
        assert_eq!(h.outages, 1);
        assert_eq!(h.backlog_records, 40, "{h:?}");
        assert_eq!(h.dropped_records, 0);
        assert!(h.write_errors >= 2, "the retries are counted: {h:?}");
        assert_eq!(
            j.durable_seq(),
            Some(10),
            "nothing of the outage is acknowledged"
        );
        // The torn part was cut: the file is exactly what was acknowledged.
        assert_eq!(std::fs::read(dir.path().join(CURRENT)).unwrap(), before);
        let (seqs, _, invalid, _) = on_disk(dir.path());
        assert_eq!((seqs.len(), invalid), (10, 0));

        // Space again: the next sync writes the backlog, in order.
        disk.set_free(None);
        j.append(&json!({ "n": 50 })).unwrap();
        j.sync().unwrap();
        let h = j.health();
        assert!(h.writable, "{h:?}");
        assert_eq!((h.backlog_records, h.outages), (0, 1));
        assert_eq!(h.delayed_records, 41, "{h:?}");
        assert_eq!(j.durable_seq(), Some(51));
        let (seqs, ns, invalid, missing) = on_disk(dir.path());
        assert_eq!(seqs, (1..=51).collect::<Vec<_>>(), "{fsync:?}");
        assert_eq!(ns, (0..=50).collect::<Vec<_>>());
        assert_eq!((invalid, missing), (0, 0));
    }
}

#[test]
fn a_read_only_disk_then_writable_again() {
    let dir = tempfile::tempdir().unwrap();
    let disk = DiskFaults::new();
    // Rotation every ~300 bytes: the outage crosses rotations too.
    let (mut j, _) = open(dir.path(), cfg(FsyncPolicy::Always, 300), &disk, 1 << 20);
    for n in 0..20u64 {
        j.append(&json!({ "n": n })).unwrap();
    }
    disk.set_read_only(true);
    for n in 20..60u64 {
        j.append(&json!({ "n": n })).unwrap();
        j.tick().unwrap();
    }
    let h = j.health();
    assert!(!h.writable);
    assert!(
        h.error
            .as_deref()
            .unwrap()
            .contains("Read-only file system"),
        "{h:?}"
    );
    assert_eq!(h.backlog_records, 40);
    assert_eq!(j.durable_seq(), Some(20));
    assert_eq!(on_disk(dir.path()).0, (1..=20).collect::<Vec<_>>());

    disk.set_read_only(false);
    j.tick().unwrap();
    assert!(j.health().writable);
    for n in 60..70u64 {
        j.append(&json!({ "n": n })).unwrap();
    }
    let (seqs, ns, invalid, missing) = on_disk(dir.path());
    assert_eq!(seqs, (1..=70).collect::<Vec<_>>());
    assert_eq!(ns, (0..70).collect::<Vec<_>>());
    assert_eq!((invalid, missing), (0, 0));
    let segs = shimmy::journal::segments(dir.path()).unwrap();
    assert!(
        segs.len() > 5,
        "rotated during and after the outage: {segs:?}"
    );
}

#[test]
fn a_full_backlog_drops_the_oldest_and_says_so() {
    let dir = tempfile::tempdir().unwrap();
    let disk = DiskFaults::new();
    // Room for about 10 records of ~70 bytes.
    let (mut j, _) = open(dir.path(), cfg(FsyncPolicy::Always, 1 << 30), &disk, 700);
    for n in 0..5u64 {
        j.append(&json!({ "n": n })).unwrap();
    }
    disk.set_free(Some(0));
    for n in 5..105u64 {
        j.append(&json!({ "n": n })).unwrap();
    }
    let h = j.health();
    assert!(h.backlog_bytes <= 700, "{h:?}");
    assert_eq!(h.dropped_records + h.backlog_records, 100, "{h:?}");
    assert!(h.dropped_records >= 85, "{h:?}");
    let (first, last) = h.dropped_seqs.unwrap();
    assert_eq!(first, 6, "the oldest go first");
    assert_eq!(last - first + 1, h.dropped_records);

    disk.set_free(None);
    j.sync().unwrap();
    let h2 = j.health();
    assert!(h2.writable);
    assert_eq!(h2.dropped_records, h.dropped_records, "drops stay counted");
    let (seqs, ns, invalid, missing) = on_disk(dir.path());
    assert_eq!(invalid, 0);
    // Every acknowledged record, then the newest of the outage; the gap is the drop.
    assert_eq!(&seqs[..5], &[1, 2, 3, 4, 5]);
    assert_eq!(*seqs.last().unwrap(), 105);
    assert_eq!(*ns.last().unwrap(), 104);
    assert_eq!(missing, h.dropped_records);
    assert_eq!(seqs.len() as u64 + missing, 105);
}

#[test]
fn a_failed_fsync_writes_the_unacknowledged_records_again() {
    let dir = tempfile::tempdir().unwrap();
    let disk = DiskFaults::new();
    let (mut j, _) = open(
        dir.path(),
        cfg(FsyncPolicy::IntervalMs(60_000), 1 << 30),
        &disk,
        1 << 20,
    );
    for n in 0..3u64 {
        j.append(&json!({ "n": n })).unwrap();
    }
    j.sync().unwrap();
    for n in 3..8u64 {
        j.append(&json!({ "n": n })).unwrap();
    }
    disk.fail_syncs(1);
    j.sync().unwrap();
    let h = j.health();
    assert!(!h.writable, "{h:?}");
    assert!(h.error.as_deref().unwrap().contains("fsync"), "{h:?}");
    assert_eq!(
        h.backlog_records, 5,
        "the five unsynced records wait: {h:?}"
    );
    assert_eq!(j.durable_seq(), Some(3));
    j.sync().unwrap();
    assert!(j.health().writable);
    assert_eq!(j.durable_seq(), Some(8));
    let (seqs, _, invalid, _) = on_disk(dir.path());
    assert_eq!(seqs, (1..=8).collect::<Vec<_>>(), "no duplicate, no loss");
    assert_eq!(invalid, 0);
}

#[test]
fn retries_wait_for_the_interval_but_an_explicit_sync_tries_at_once() {
    let dir = tempfile::tempdir().unwrap();
    let disk = DiskFaults::new();
    let (mut j, _) = Journal::open_with(
        dir.path(),
        cfg(FsyncPolicy::Always, 1 << 30),
        Setup {
            tolerance: Some(Tolerance {
                backlog_bytes: 1 << 20,
                retry_every: Duration::from_secs(3600),
            }),
            faults: Some(Box::new(disk.clone())),
            clock: None,
        },
    )
    .unwrap();
    disk.set_read_only(true);
    j.append(&json!({ "n": 0 })).unwrap();
    let tried = disk.injected();
    disk.set_read_only(false);
    j.append(&json!({ "n": 1 })).unwrap();
    j.tick().unwrap();
    assert!(!j.health().writable, "no retry before retry_every");
    assert_eq!(disk.injected(), tried);
    j.sync().unwrap();
    assert!(j.health().writable);
    assert_eq!(on_disk(dir.path()).0, vec![1, 2]);
}

#[test]
fn a_disk_read_only_at_start_still_opens_and_catches_up() {
    let dir = tempfile::tempdir().unwrap();
    {
        let (mut j, _) = Journal::open(dir.path(), cfg(FsyncPolicy::Always, 1 << 30)).unwrap();
        for n in 0..4u64 {
            j.append(&json!({ "n": n })).unwrap();
        }
    }
    // A torn tail that recovery cannot cut while the disk is read-only.
    std::fs::OpenOptions::new()
        .append(true)
        .open(dir.path().join(CURRENT))
        .and_then(|mut f| std::io::Write::write_all(&mut f, b"{\"seq\":5,\"rec\":{\"n\""))
        .unwrap();
    let disk = DiskFaults::new();
    disk.set_read_only(true);
    let (mut j, rec) = open(
        dir.path(),
        cfg(FsyncPolicy::Always, 1 << 30),
        &disk,
        1 << 20,
    );
    assert_eq!(rec.last_seq, Some(4));
    assert!(rec.truncated_bytes > 0);
    assert!(!j.health().writable);
    assert_eq!(j.append(&json!({ "n": 4 })).unwrap(), 5);
    disk.set_read_only(false);
    j.sync().unwrap();
    assert!(j.health().writable);
    let (seqs, ns, invalid, _) = on_disk(dir.path());
    assert_eq!(seqs, vec![1, 2, 3, 4, 5]);
    assert_eq!(ns, vec![0, 1, 2, 3, 4]);
    assert_eq!(invalid, 0, "the torn tail was cut on the retry");
}

#[test]
fn a_strict_journal_still_returns_the_error() {
    let dir = tempfile::tempdir().unwrap();
    let disk = DiskFaults::new();
    let (mut j, _) = Journal::open_with(
        dir.path(),
        cfg(FsyncPolicy::Always, 1 << 30),
        Setup {
            faults: Some(Box::new(disk.clone())),
            ..Setup::default()
        },
    )
    .unwrap();
    j.append(&json!({ "n": 0 })).unwrap();
    disk.set_free(Some(0));
    let e = j.append(&json!({ "n": 1 })).unwrap_err();
    assert!(format!("{e:#}").contains("No space left"), "{e:#}");
}

/// A gateway without RTC: the clock starts at 1970, NTP sets it forward by 56 years, a bad
/// source sets it back to 2000, then forward again. Sequence order and completeness hold; the
/// stamps are what the clock said; the reader counts the backward jumps.
#[test]
fn wall_clock_jumps_neither_reorder_nor_drop_records() {
    const S: i64 = 1_000_000_000;
    let dir = tempfile::tempdir().unwrap();
    let clock = ManualClock::new(5 * S);
    let (mut j, _) = Journal::open_with(
        dir.path(),
        cfg(FsyncPolicy::IntervalMs(10), 400),
        Setup {
            tolerance: Some(Tolerance::default()),
            faults: None,
            clock: Some(Box::new(clock.clone())),
        },
    )
    .unwrap();
    let mut expect_wall = Vec::new();
    for n in 0..200u64 {
        match n {
            50 => clock.set(1_764_800_000 * S),  // NTP: 1970 → 2026
            100 => clock.set(946_684_800 * S),   // back to 2000-01-01
            150 => clock.set(1_764_800_100 * S), // forward again
            _ => clock.advance(S / 100),
        }
        expect_wall.push(clock.now_ns());
        j.append(&json!({ "n": n })).unwrap();
        j.tick().unwrap();
    }
    drop(j);
    // Reopened after the jumps: the sequence continues, whatever the clock says.
    clock.set(0);
    let (mut j, rec) = Journal::open_with(
        dir.path(),
        cfg(FsyncPolicy::Always, 400),
        Setup {
            clock: Some(Box::new(clock.clone())),
            ..Setup::default()
        },
    )
    .unwrap();
    assert_eq!(j.next_seq(), 201, "{rec:?}");
    j.append(&json!({ "n": 200 })).unwrap();
    expect_wall.push(0);
    drop(j);

    let mut r = Reader::open(dir.path()).unwrap();
    let entries: Vec<_> = (&mut r).map(|e| e.unwrap()).collect();
    assert_eq!(
        entries.iter().map(|e| e.seq).collect::<Vec<_>>(),
        (1..=201).collect::<Vec<_>>()
    );
    assert_eq!(
        entries
            .iter()
            .map(|e| e.rec["n"].as_u64().unwrap())
            .collect::<Vec<_>>(),
        (0..=200).collect::<Vec<_>>()
    );
    assert_eq!(
        entries
            .iter()
            .map(|e| e.wall_ns.unwrap())
            .collect::<Vec<_>>(),
        expect_wall
    );
    assert_eq!(
        r.wall_clock_jumps_back(),
        2,
        "2026 → 2000 and the reopen at 1970"
    );
    assert_eq!(
        (r.invalid_lines(), r.out_of_order(), r.missing()),
        (0, 0, 0)
    );
    assert!(shimmy::journal::segments(dir.path()).unwrap().len() > 10);
}
