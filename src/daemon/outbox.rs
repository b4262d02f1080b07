//! The MQTT outbox: a crash-safe, bounded, on-disk FIFO of messages waiting for the broker
//! (so nothing is lost while the broker is unreachable or the daemon restarts).
//!
//! What it is: a [`crate::journal::Journal`] in its own directory (same line format with
//! sequence number and CRC-32C, same fsync-every-record durability, same torn-tail recovery and
//! atomic rotation) plus a small cursor file, `cursor.json`, written atomically
//! ([`super::state::write_atomic`]), that records the first sequence number not yet delivered
//! and the number of messages dropped so far. A message is *queued* once [`Outbox::push`]
//! returns (it is fsynced); it leaves the queue when the broker acknowledged it
//! ([`Outbox::delivered`]) or when the bound forces it out ([`Outbox::push`]'s drop policy).
//!
//! Delivery semantics: at-least-once. A crash after the broker's acknowledgement and before the
//! cursor reaches the disk sends that message again after the restart, with the same id
//! (`<client id>:<seq>`), so a subscriber de-duplicates on the id. Without a crash every message
//! is delivered exactly once, in sequence order.
//!
//! Bound and drop policy: at most `max_messages` messages and `max_bytes` of payload are
//! pending; a push beyond that drops the *oldest* pending messages (the newest state of an alert
//! matters most), counts them in [`Outbox::dropped`] (persisted in the cursor) and reports each
//! drop to the caller, which logs it. Published messages carry the running drop count, so the
//! backend sees that (and, from the sequence gap, which) messages were dropped.
//!
//! A cursor file that does not parse is moved aside (`cursor.json.bad`) and reported; every
//! message still on disk is then sent again (duplicates, never losses).
//!
//! Disk: rotated segments whose messages have all left the queue are deleted, except the newest
//! one (it keeps the sequence numbers continuing after a restart with an empty queue).
//!
//! What it is not: the MQTT client (that is [`super::mqtt`]) or a general message broker.

use std::collections::VecDeque;
use std::fs;
use std::path::{Path, PathBuf};

use anyhow::Context;
use serde::{Deserialize, Serialize};

use crate::journal::{self, FsyncPolicy, Journal, JournalConfig, Reader};

/// Segment size of the outbox's journal (bytes).
const SEGMENT_BYTES: u64 = 1024 * 1024;
const CURSOR: &str = "cursor.json";

/// One queued message.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct Message {
    pub seq: u64,
    pub topic: String,
    /// The payload (JSON text).
    pub payload: String,
}

#[derive(Clone, Copy, Debug, Default, PartialEq, Serialize, Deserialize)]
#[serde(default)]
struct Cursor {
    /// First sequence number still to be delivered.
    next: u64,
    /// Messages dropped by the bound, in total.
    dropped: u64,
}

/// How big the queue may grow.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Limits {
    pub max_messages: usize,
    pub max_bytes: usize,
}

/// What [`Outbox::open`] found.
#[derive(Clone, Debug, Default, PartialEq, Serialize)]
pub struct Opened {
    /// Messages still queued from an earlier run.
    pub pending: usize,
    /// Bytes of a torn or corrupt tail cut off the outbox's current file.
    pub truncated_bytes: u64,
    /// Invalid lines skipped while reading the queue back.
    pub invalid_lines: u64,
    pub dropped_total: u64,
    /// A corrupt cursor file that was moved aside.
    pub problem: Option<String>,
}

/// The queue.
pub struct Outbox {
    dir: PathBuf,
    journal: Journal,
    cursor: Cursor,
    pending: VecDeque<Message>,
    pending_bytes: usize,
    limits: Limits,
}

impl Outbox {
    /// Opens (creating) the outbox in `dir` and reads back the messages still queued.
    pub fn open(dir: &Path, limits: Limits) -> anyhow::Result<(Outbox, Opened)> {
        let (journal, rec) = Journal::open(
            dir,
            JournalConfig {
                fsync: FsyncPolicy::Always,
                rotate_bytes: SEGMENT_BYTES,
            },
        )
        .with_context(|| format!("cannot open the MQTT outbox in {}", dir.display()))?;
        let cursor_path = dir.join(CURSOR);
        let mut problem = None;
        let cursor = match fs::read(&cursor_path) {
            Ok(b) => match serde_json::from_slice::<Cursor>(&b) {
                Ok(c) => c,
                Err(e) => {
                    // Never silently: moved aside, and everything still on disk is sent again
                    // (at-least-once; subscribers de-duplicate on the id).
                    let aside = dir.join(format!("{CURSOR}.bad"));
                    fs::rename(&cursor_path, &aside).with_context(|| {
                        format!("cannot move corrupt {} aside", cursor_path.display())
                    })?;
                    problem = Some(format!(
                        "{} did not parse ({e}); moved to {}, resending every message still on disk",
                        cursor_path.display(),
                        aside.display()
                    ));
                    Cursor::default()
                }
            },
            Err(e) if e.kind() == std::io::ErrorKind::NotFound => Cursor::default(),
            Err(e) => {
                return Err(e).with_context(|| format!("cannot read {}", cursor_path.display()))
            }
        };
        let mut ob = Outbox {
            dir: dir.to_path_buf(),
            journal,
            cursor,
            pending: VecDeque::new(),
            pending_bytes: 0,
            limits,
        };
        let mut reader = Reader::open(dir)?;
        for e in reader.by_ref() {
            let e = e?;
            if e.seq < ob.cursor.next {
                continue;
            }
            match serde_json::from_value::<Message>(e.rec) {
                Ok(m) if m.seq == e.seq => {
                    ob.pending_bytes += m.payload.len();
                    ob.pending.push_back(m);
                }
                _ => {
                    // A valid line that is not a message of ours: skipped, counted below.
                }
            }
        }
        let opened = Opened {
            pending: ob.pending.len(),
            truncated_bytes: rec.truncated_bytes,
            invalid_lines: reader.invalid_lines() + reader.out_of_order(),
            dropped_total: ob.cursor.dropped,
            problem,
        };
        Ok((ob, opened))
    }

    /// Sequence number the next pushed message gets (its id).
    pub fn next_seq(&self) -> u64 {
        self.journal.next_seq()
    }

    /// Queues a message durably (fsynced before returning). Returns the sequence numbers of
    /// older messages dropped to stay within the limits.
    pub fn push(&mut self, topic: &str, payload: String) -> anyhow::Result<Vec<u64>> {
        let seq = self.journal.next_seq();
        let m = Message {
            seq,
            topic: topic.to_string(),
            payload,
        };
        let got = self
            .journal
            .append(&m)
            .context("cannot queue an MQTT message")?;
        debug_assert_eq!(got, seq);
        self.pending_bytes += m.payload.len();
        self.pending.push_back(m);
        let mut dropped = Vec::new();
        while self.pending.len() > self.limits.max_messages
            || (self.pending_bytes > self.limits.max_bytes && self.pending.len() > 1)
        {
            let old = self.pending.pop_front().expect("non-empty");
            self.pending_bytes -= old.payload.len();
            dropped.push(old.seq);
        }
        if !dropped.is_empty() {
            self.cursor.dropped += dropped.len() as u64;
            self.advance()?;
        }
        Ok(dropped)
    }

    /// The oldest queued message.
    pub fn front(&self) -> Option<&Message> {
        self.pending.front()
    }

    /// The broker acknowledged message `seq`: it leaves the queue (durably). An
    /// acknowledgement for a message no longer at the front (dropped meanwhile) is ignored.
    pub fn delivered(&mut self, seq: u64) -> anyhow::Result<bool> {
        if self.pending.front().is_none_or(|m| m.seq != seq) {
            return Ok(false);
        }
        let m = self.pending.pop_front().expect("checked");
        self.pending_bytes -= m.payload.len();
        self.advance()?;
        Ok(true)
    }

    pub fn len(&self) -> usize {
        self.pending.len()
    }

    pub fn is_empty(&self) -> bool {
        self.pending.is_empty()
    }

    /// Messages dropped by the bound, in total (across restarts).
    pub fn dropped(&self) -> u64 {
        self.cursor.dropped
    }

    pub fn dir(&self) -> &Path {
        &self.dir
    }

    /// Persists the cursor after the front moved, then deletes fully delivered segments.
    fn advance(&mut self) -> anyhow::Result<()> {
        self.cursor.next = self
            .pending
            .front()
            .map_or(self.journal.next_seq(), |m| m.seq);
        let bytes = serde_json::to_vec(&self.cursor)?;
        super::state::write_atomic(&self.dir, CURSOR, &bytes)?;
        self.prune()
    }

    /// Deletes rotated segments all of whose messages are before the cursor, keeping the newest
    /// rotated segment (sequence numbers continue from it when `current.jsonl` is empty).
    fn prune(&mut self) -> anyhow::Result<()> {
        let segs: Vec<PathBuf> = journal::segments(&self.dir)?
            .into_iter()
            .filter(|p| !p.ends_with(journal::CURRENT))
            .collect();
        // Segment names carry their first sequence number; segment k ends before segment k+1.
        let first = |p: &PathBuf| -> Option<u64> {
            p.file_name()?
                .to_str()?
                .strip_prefix("seg-")?
                .strip_suffix(".jsonl")?
                .parse()
                .ok()
        };
        // The newest rotated segment is never `w[0]`, so it is always kept.
        for w in segs.windows(2) {
            if first(&w[1]).is_some_and(|f| f <= self.cursor.next) {
                fs::remove_file(&w[0])
                    .with_context(|| format!("cannot remove {}", w[0].display()))?;
            }
        }
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn limits(n: usize) -> Limits {
        Limits {
            max_messages: n,
            max_bytes: 1 << 20,
        }
    }

    #[test]
    fn queued_messages_survive_a_reopen_and_leave_in_order() {
        let dir = tempfile::tempdir().unwrap();
        {
            let (mut ob, o) = Outbox::open(dir.path(), limits(100)).unwrap();
            assert_eq!(o.pending, 0);
            for k in 0..5 {
                ob.push("t", format!("{{\"k\":{k}}}")).unwrap();
            }
            let s = ob.front().unwrap().seq;
            assert!(ob.delivered(s).unwrap());
            assert!(
                !ob.delivered(s).unwrap(),
                "a second ack of the same message is ignored"
            );
        }
        let (mut ob, o) = Outbox::open(dir.path(), limits(100)).unwrap();
        assert_eq!(o.pending, 4);
        let mut got = Vec::new();
        while let Some(m) = ob.front().cloned() {
            got.push(m.payload.clone());
            ob.delivered(m.seq).unwrap();
        }
        assert_eq!(
            got,
            (1..5).map(|k| format!("{{\"k\":{k}}}")).collect::<Vec<_>>()
        );
        // Sequence numbers keep increasing across a reopen with an empty queue.
        let before = ob.next_seq();
        drop(ob);
        let (ob, o) = Outbox::open(dir.path(), limits(100)).unwrap();
        assert_eq!(o.pending, 0);
        assert_eq!(ob.next_seq(), before);
    }

    #[test]
    fn a_corrupt_cursor_is_moved_aside_and_everything_resent() {
        let dir = tempfile::tempdir().unwrap();
        {
            let (mut ob, _) = Outbox::open(dir.path(), limits(100)).unwrap();
            ob.push("t", "a".into()).unwrap();
            ob.push("t", "b".into()).unwrap();
            ob.delivered(1).unwrap();
        }
        fs::write(dir.path().join(CURSOR), b"{\"next\":").unwrap();
        let (ob, o) = Outbox::open(dir.path(), limits(100)).unwrap();
        assert!(o.problem.unwrap().contains("did not parse"));
        assert!(dir.path().join("cursor.json.bad").is_file());
        assert_eq!(o.pending, 2, "both messages are sent again");
        assert_eq!(ob.front().unwrap().payload, "a");
    }

    #[test]
    fn the_bound_drops_the_oldest_and_counts_it() {
        let dir = tempfile::tempdir().unwrap();
        let (mut ob, _) = Outbox::open(dir.path(), limits(3)).unwrap();
        let mut dropped = Vec::new();
        for k in 0..5 {
            dropped.extend(ob.push("t", format!("{k}")).unwrap());
        }
        assert_eq!(dropped, vec![1, 2]);
        assert_eq!(ob.dropped(), 2);
        assert_eq!(ob.front().unwrap().payload, "2");
        drop(ob);
        let (ob, o) = Outbox::open(dir.path(), limits(3)).unwrap();
        assert_eq!((o.pending, o.dropped_total), (3, 2));
        assert_eq!(ob.front().unwrap().payload, "2");
    }

    #[test]
    fn a_torn_last_message_is_cut_and_the_rest_kept() {
        let dir = tempfile::tempdir().unwrap();
        {
            let (mut ob, _) = Outbox::open(dir.path(), limits(100)).unwrap();
            ob.push("t", "a".into()).unwrap();
            ob.push("t", "b".into()).unwrap();
        }
        let cur = dir.path().join(journal::CURRENT);
        let mut bytes = fs::read(&cur).unwrap();
        bytes.extend_from_slice(b"{\"seq\":3,\"rec\":{\"seq\":3,\"topic\":\"t\",\"pay");
        fs::write(&cur, bytes).unwrap();
        let (ob, o) = Outbox::open(dir.path(), limits(100)).unwrap();
        assert_eq!(o.pending, 2);
        assert!(o.truncated_bytes > 0);
        assert_eq!(ob.next_seq(), 3);
    }

    #[test]
    fn delivered_segments_are_deleted_but_the_newest_is_kept() {
        let dir = tempfile::tempdir().unwrap();
        let roomy = Limits {
            max_messages: 1000,
            max_bytes: 1 << 30,
        };
        let (mut ob, _) = Outbox::open(dir.path(), roomy).unwrap();
        let big = "x".repeat(100_000);
        for _ in 0..35 {
            ob.push("t", big.clone()).unwrap();
        }
        let rotated = |d: &Path| {
            journal::segments(d)
                .unwrap()
                .iter()
                .filter(|p| !p.ends_with(journal::CURRENT))
                .count()
        };
        assert!(rotated(dir.path()) >= 3);
        assert_eq!(ob.dropped(), 0);
        while let Some(s) = ob.front().map(|m| m.seq) {
            ob.delivered(s).unwrap();
        }
        assert_eq!(rotated(dir.path()), 1);
        let next = ob.next_seq();
        drop(ob);
        let (ob, o) = Outbox::open(dir.path(), roomy).unwrap();
        assert_eq!((o.pending, ob.next_seq()), (0, next));
    }
}
