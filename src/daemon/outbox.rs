//! The MQTT outbox: which journal records are still to be sent to the broker. The journal
//! ([`crate::journal`]) is the store-and-forward buffer; the outbox keeps no copy of a message
//! on disk, only a cursor.
//!
//! What it is: a reader that follows the daemon's journal directory up to the sequence number
//! the daemon says is durable ([`Outbox::refill`]), turns the records that are messages
//! (`event`, `estimate`, `alert`) into [`Message`]s, and a small cursor file, written
//! atomically ([`super::state::write_atomic`]), holding the first journal sequence number not
//! yet delivered and the number of messages dropped so far. A message leaves the queue when the
//! broker acknowledged it ([`Outbox::delivered`]) or when the bound forces it out. After a
//! restart the queue is read again from the journal, from the cursor on: a message is as
//! durable as its journal record.
//!
//! Delivery semantics: at-least-once. A crash after the broker's acknowledgement and before the
//! cursor reaches the disk sends that message again after the restart, with the same id
//! (`<vehicle>:<journal seq>`), so a subscriber de-duplicates on the id. Without a crash every
//! message is delivered exactly once, in journal order.
//!
//! Bound and drop policy: at most `max_messages` messages and `max_bytes` of payload are
//! pending in memory; beyond that the *oldest* are dropped (the newest state of an alert matters
//! most), counted in [`Outbox::dropped`] (persisted in the cursor) and reported to the caller,
//! which logs them. Every message carries the running drop count, so the backend sees that
//! (and, from the ids it did not get, which) messages were dropped. They stay in the journal.
//!
//! First start (no cursor file): the queue starts at the journal's end, so enabling MQTT on a
//! vehicle with a long journal does not send its whole history. A cursor file that does not
//! parse is moved aside (`.bad`) and reported; the queue then starts at the oldest record still
//! in the journal (duplicates, never losses). A cursor behind the oldest record (segments
//! pruned by the operator) and a cursor ahead of the journal (a journal replaced) are reported.
//!
//! What it is not: the MQTT client (that is [`super::mqtt`]), a second journal, or a general
//! message broker. It never writes to the journal.

use std::collections::VecDeque;
use std::fs::{self, File};
use std::io::{BufRead, BufReader, Seek, SeekFrom};
use std::path::{Path, PathBuf};

use anyhow::Context;
use serde::{Deserialize, Serialize};

use crate::journal::{self, line};

/// One message to send: built from journal record `seq`.
#[derive(Clone, Debug, PartialEq)]
pub struct Message {
    /// The journal record's sequence number (the id's number).
    pub seq: u64,
    /// `event`, `estimate` or `alert`: the topic's last level.
    pub kind: &'static str,
    /// The record's fields that go out (JSON object).
    pub body: serde_json::Map<String, serde_json::Value>,
    /// Size of `body` as JSON (bytes), for the bound.
    pub bytes: usize,
}

#[derive(Clone, Copy, Debug, Default, PartialEq, Serialize, Deserialize)]
#[serde(default)]
struct Cursor {
    /// First journal sequence number still to be delivered.
    next: u64,
    /// Messages dropped by the bound, in total.
    dropped: u64,
}

/// How big the in-memory queue may grow.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Limits {
    pub max_messages: usize,
    pub max_bytes: usize,
}

/// What [`Outbox::open`] found.
#[derive(Clone, Debug, Default, PartialEq, Serialize)]
pub struct Opened {
    /// Journal sequence number the queue starts at.
    pub from_seq: u64,
    pub dropped_total: u64,
    /// Something about the cursor worth a log line (corrupt, behind or ahead of the journal).
    pub problem: Option<String>,
}

/// The file being followed: its path when opened, the reader, the offset of the next line.
struct Tail {
    path: PathBuf,
    r: BufReader<File>,
    off: u64,
}

/// The queue.
pub struct Outbox {
    journal_dir: PathBuf,
    cursor_path: PathBuf,
    cursor: Cursor,
    /// Every record below this has been read (turned into a message or skipped).
    read_to: u64,
    tail: Option<Tail>,
    /// The last rotated segment read to its end.
    done: Option<PathBuf>,
    pending: VecDeque<Message>,
    pending_bytes: usize,
    limits: Limits,
    invalid_lines: u64,
}

/// The record `rec` as a message, or None when it is not one (start, stop, ...).
fn message(seq: u64, rec: &serde_json::Value) -> Option<Message> {
    let kind = match rec.get("type")?.as_str()? {
        "event" => "event",
        "estimate" => "estimate",
        "alert" => "alert",
        _ => return None,
    };
    let mut body = match rec {
        serde_json::Value::Object(m) => m.clone(),
        _ => return None,
    };
    body.remove("type");
    // The steering trace around an event stays in the journal: it is for diagnosis on the
    // vehicle, not for the fleet's dashboard.
    body.remove("trace");
    let bytes = serde_json::to_string(&body).map_or(0, |s| s.len());
    Some(Message {
        seq,
        kind,
        body,
        bytes,
    })
}

/// First sequence number of a rotated segment, from its name.
fn first_seq(p: &Path) -> Option<u64> {
    p.file_name()?
        .to_str()?
        .strip_prefix("seg-")?
        .strip_suffix(".jsonl")?
        .parse()
        .ok()
}

impl Outbox {
    /// Opens the queue of `journal_dir` (the daemon's journal, opened already) with its cursor
    /// at `cursor_path`. `journal_next`: the journal's next sequence number (its end).
    pub fn open(
        journal_dir: &Path,
        journal_next: u64,
        cursor_path: &Path,
        limits: Limits,
    ) -> anyhow::Result<(Outbox, Opened)> {
        let mut problem = None;
        let oldest = || -> anyhow::Result<u64> {
            let segs = journal::segments(journal_dir)
                .with_context(|| format!("cannot list {}", journal_dir.display()))?;
            Ok(segs.first().and_then(|p| first_seq(p)).unwrap_or(1))
        };
        let cursor = match fs::read(cursor_path) {
            Ok(b) => match serde_json::from_slice::<Cursor>(&b) {
                Ok(c) => c,
                Err(e) => {
                    let aside = cursor_path.with_extension("json.bad");
                    fs::rename(cursor_path, &aside).with_context(|| {
                        format!("cannot move corrupt {} aside", cursor_path.display())
                    })?;
                    let from = oldest()?;
                    problem = Some(format!(
                        "{} did not parse ({e}); moved to {}, sending the journal again from record {from}",
                        cursor_path.display(),
                        aside.display()
                    ));
                    Cursor {
                        next: from,
                        dropped: 0,
                    }
                }
            },
            Err(e) if e.kind() == std::io::ErrorKind::NotFound => Cursor {
                next: journal_next,
                dropped: 0,
            },
            Err(e) => {
                return Err(e).with_context(|| format!("cannot read {}", cursor_path.display()))
            }
        };
        let mut cursor = cursor;
        if cursor.next > journal_next {
            problem = Some(format!(
                "{}: record {} is not in the journal {} (it ends before {journal_next}: a journal replaced?); sending from its end",
                cursor_path.display(),
                cursor.next,
                journal_dir.display()
            ));
            cursor.next = journal_next;
        } else if cursor.next < oldest()? && cursor.next < journal_next {
            problem = Some(format!(
                "{}: records {}..{} were removed from the journal before they were delivered",
                cursor_path.display(),
                cursor.next,
                oldest()?
            ));
        }
        let ob = Outbox {
            journal_dir: journal_dir.to_path_buf(),
            cursor_path: cursor_path.to_path_buf(),
            cursor,
            read_to: cursor.next,
            tail: None,
            done: None,
            pending: VecDeque::new(),
            pending_bytes: 0,
            limits,
            invalid_lines: 0,
        };
        ob.save()?;
        let opened = Opened {
            from_seq: cursor.next,
            dropped_total: cursor.dropped,
            problem,
        };
        Ok((ob, opened))
    }

    /// Reads the journal's records up to and including `durable` (the journal's durable
    /// sequence number: complete lines, on disk) into the queue. Returns the sequence numbers
    /// dropped to stay within the limits.
    pub fn refill(&mut self, durable: u64) -> anyhow::Result<Vec<u64>> {
        while self.read_to <= durable {
            let Some((seq, rec)) = self.next_record()? else {
                break;
            };
            if seq < self.read_to {
                continue;
            }
            self.read_to = seq + 1;
            if let Some(m) = message(seq, &rec) {
                self.pending_bytes += m.bytes;
                self.pending.push_back(m);
            }
        }
        let mut dropped = Vec::new();
        while self.pending.len() > self.limits.max_messages
            || (self.pending_bytes > self.limits.max_bytes && self.pending.len() > 1)
        {
            let old = self.pending.pop_front().expect("non-empty");
            self.pending_bytes -= old.bytes;
            dropped.push(old.seq);
        }
        if !dropped.is_empty() {
            self.cursor.dropped += dropped.len() as u64;
            self.advance()?;
        }
        Ok(dropped)
    }

    /// The next valid record of the journal after the tail's position. A rotated segment read
    /// to its end is complete: the segment after it is found from the names (and a
    /// `current.jsonl` that was renamed under the tail is recognised by its inode); the end of
    /// `current.jsonl` is the end of what is written, and a line still being written is read
    /// again later.
    fn next_record(&mut self) -> anyhow::Result<Option<(u64, serde_json::Value)>> {
        use std::os::unix::fs::MetadataExt;
        // Each pass through the listing moves past one file; more than the journal has is a
        // journal changing faster than it can be followed: stop for now, go on next time.
        for _ in 0..64 {
            if self.tail.is_none() {
                self.tail = self.open_tail()?;
                if self.tail.is_none() {
                    return Ok(None);
                }
            }
            let t = self.tail.as_mut().expect("set above");
            let mut buf = Vec::new();
            let k =
                t.r.read_until(b'\n', &mut buf)
                    .with_context(|| format!("cannot read {}", t.path.display()))?;
            if k > 0 && buf.last() == Some(&b'\n') {
                t.off += k as u64;
                match line::decode(&buf) {
                    Ok((seq, rec)) => return Ok(Some((seq, rec))),
                    Err(_) => {
                        self.invalid_lines += 1;
                        continue;
                    }
                }
            }
            if k > 0 {
                t.r.seek(SeekFrom::Start(t.off))?;
            }
            let ino = t.r.get_ref().metadata()?.ino();
            if t.path.ends_with(journal::CURRENT) {
                let still = fs::metadata(&t.path).is_ok_and(|m| m.ino() == ino);
                if still {
                    return Ok(None);
                }
            }
            // A complete segment (rotated, or renamed under us): find its name, go past it.
            let segs = journal::segments(&self.journal_dir)
                .with_context(|| format!("cannot list {}", self.journal_dir.display()))?;
            self.done = segs
                .into_iter()
                .find(|p| first_seq(p).is_some() && fs::metadata(p).is_ok_and(|m| m.ino() == ino))
                .or(self.done.take());
            self.tail = None;
        }
        Ok(None)
    }

    /// Opens the file that holds record `read_to`: among the files after the last segment read
    /// to its end, the last rotated one starting at or before it, else the first.
    fn open_tail(&self) -> anyhow::Result<Option<Tail>> {
        let segs: Vec<PathBuf> = journal::segments(&self.journal_dir)
            .with_context(|| format!("cannot list {}", self.journal_dir.display()))?
            .into_iter()
            .filter(|p| match (&self.done, first_seq(p)) {
                (Some(d), Some(_)) => p > d,
                _ => true,
            })
            .collect();
        let pick = segs
            .iter()
            .rev()
            .find(|p| first_seq(p).is_some_and(|f| f <= self.read_to))
            .or(segs.first());
        let Some(p) = pick else {
            return Ok(None);
        };
        let f = File::open(p).with_context(|| format!("cannot open {}", p.display()))?;
        Ok(Some(Tail {
            path: p.clone(),
            r: BufReader::new(f),
            off: 0,
        }))
    }

    /// The oldest queued message.
    pub fn front(&self) -> Option<&Message> {
        self.pending.front()
    }

    /// The broker acknowledged message `seq`: it leaves the queue and the cursor moves past it
    /// (durably). An acknowledgement for a message no longer at the front is ignored.
    pub fn delivered(&mut self, seq: u64) -> anyhow::Result<bool> {
        if self.pending.front().is_none_or(|m| m.seq != seq) {
            return Ok(false);
        }
        let m = self.pending.pop_front().expect("checked");
        self.pending_bytes -= m.bytes;
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

    /// Journal lines that did not decode while following it (skipped).
    pub fn invalid_lines(&self) -> u64 {
        self.invalid_lines
    }

    pub fn cursor_path(&self) -> &Path {
        &self.cursor_path
    }

    /// The cursor after the front moved: the front's record, or everything read.
    fn advance(&mut self) -> anyhow::Result<()> {
        self.cursor.next = self.pending.front().map_or(self.read_to, |m| m.seq);
        self.save()
    }

    fn save(&self) -> anyhow::Result<()> {
        let bytes = serde_json::to_vec(&self.cursor)?;
        let dir = self.cursor_path.parent().unwrap_or(Path::new("."));
        let name = self
            .cursor_path
            .file_name()
            .and_then(|n| n.to_str())
            .context("mqtt cursor file name")?;
        fs::create_dir_all(dir).with_context(|| format!("cannot create {}", dir.display()))?;
        super::state::write_atomic(dir, name, &bytes)
            .with_context(|| format!("cannot save {}", self.cursor_path.display()))
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::journal::{FsyncPolicy, Journal, JournalConfig};
    use serde_json::json;

    fn limits(n: usize) -> Limits {
        Limits {
            max_messages: n,
            max_bytes: 1 << 20,
        }
    }

    fn journal(dir: &Path, rotate: u64) -> Journal {
        Journal::open(
            dir,
            JournalConfig {
                fsync: FsyncPolicy::Always,
                rotate_bytes: rotate,
            },
        )
        .unwrap()
        .0
    }

    fn event(j: &mut Journal, k: u64) -> u64 {
        j.append(&json!({"type": "event", "event": {"k": k}, "trace": [1, 2, 3]}))
            .unwrap()
    }

    fn drain(ob: &mut Outbox) -> Vec<u64> {
        let mut got = Vec::new();
        while let Some(m) = ob.front().cloned() {
            got.push(m.body["event"]["k"].as_u64().unwrap());
            assert!(!m.body.contains_key("trace"));
            assert!(ob.delivered(m.seq).unwrap());
        }
        got
    }

    #[test]
    fn records_after_the_cursor_are_sent_once_across_restarts_and_no_copy_is_kept() {
        let dir = tempfile::tempdir().unwrap();
        let jdir = dir.path().join("journal");
        let cur = dir.path().join("state/mqtt-cursor.json");
        let mut j = journal(&jdir, 1 << 20);
        j.append(&json!({"type": "start"})).unwrap();
        // Before the first open: history, not sent.
        event(&mut j, 0);
        let (mut ob, o) = Outbox::open(&jdir, j.next_seq(), &cur, limits(100)).unwrap();
        assert_eq!(o.from_seq, j.next_seq());
        for k in 1..=4 {
            event(&mut j, k);
        }
        j.append(&json!({"type": "stop"})).unwrap();
        ob.refill(j.durable_seq().unwrap()).unwrap();
        assert_eq!(ob.len(), 4);
        let s = ob.front().unwrap().seq;
        assert!(ob.delivered(s).unwrap());
        assert!(!ob.delivered(s).unwrap(), "a second ack is ignored");
        drop(ob);
        // Only the cursor file sits beside the state: no copy of a message.
        let files: Vec<_> = fs::read_dir(cur.parent().unwrap())
            .unwrap()
            .map(|e| e.unwrap().file_name())
            .collect();
        assert_eq!(files, ["mqtt-cursor.json"]);
        let (mut ob, o) = Outbox::open(&jdir, j.next_seq(), &cur, limits(100)).unwrap();
        assert_eq!(o.from_seq, s + 1);
        ob.refill(j.durable_seq().unwrap()).unwrap();
        assert_eq!(drain(&mut ob), [2, 3, 4]);
        event(&mut j, 5);
        ob.refill(j.durable_seq().unwrap()).unwrap();
        assert_eq!(drain(&mut ob), [5]);
    }

    #[test]
    fn following_the_journal_across_rotations() {
        let dir = tempfile::tempdir().unwrap();
        let jdir = dir.path().join("journal");
        let cur = dir.path().join("cursor.json");
        let mut j = journal(&jdir, 300);
        let (mut ob, _) = Outbox::open(&jdir, j.next_seq(), &cur, limits(1000)).unwrap();
        let mut want = Vec::new();
        for k in 0..40 {
            event(&mut j, k);
            want.push(k);
            if k % 7 == 0 {
                ob.refill(j.durable_seq().unwrap()).unwrap();
            }
        }
        assert!(journal::segments(&jdir).unwrap().len() > 3, "rotated");
        ob.refill(j.durable_seq().unwrap()).unwrap();
        assert_eq!(drain(&mut ob), want);
        // A restart in the middle of the rotated segments.
        drop(ob);
        fs::write(&cur, br#"{"next":12,"dropped":0}"#).unwrap();
        let (mut ob, _) = Outbox::open(&jdir, j.next_seq(), &cur, limits(1000)).unwrap();
        ob.refill(j.durable_seq().unwrap()).unwrap();
        assert_eq!(drain(&mut ob), (11..40).collect::<Vec<_>>());
    }

    #[test]
    fn a_corrupt_cursor_is_moved_aside_and_the_journal_sent_again() {
        let dir = tempfile::tempdir().unwrap();
        let jdir = dir.path().join("journal");
        let cur = dir.path().join("cursor.json");
        let mut j = journal(&jdir, 1 << 20);
        for k in 0..3 {
            event(&mut j, k);
        }
        fs::write(&cur, b"{\"next\":").unwrap();
        let (mut ob, o) = Outbox::open(&jdir, j.next_seq(), &cur, limits(100)).unwrap();
        assert!(o.problem.unwrap().contains("did not parse"));
        assert!(dir.path().join("cursor.json.bad").is_file());
        ob.refill(j.durable_seq().unwrap()).unwrap();
        assert_eq!(drain(&mut ob), [0, 1, 2]);
    }

    #[test]
    fn the_bound_drops_the_oldest_and_counts_it() {
        let dir = tempfile::tempdir().unwrap();
        let jdir = dir.path().join("journal");
        let cur = dir.path().join("cursor.json");
        let mut j = journal(&jdir, 1 << 20);
        let (mut ob, _) = Outbox::open(&jdir, j.next_seq(), &cur, limits(3)).unwrap();
        let mut dropped = Vec::new();
        for k in 0..5 {
            event(&mut j, k);
            dropped.extend(ob.refill(j.durable_seq().unwrap()).unwrap());
        }
        assert_eq!(dropped, vec![1, 2]);
        assert_eq!(ob.dropped(), 2);
        drop(ob);
        let (mut ob, o) = Outbox::open(&jdir, j.next_seq(), &cur, limits(3)).unwrap();
        assert_eq!(o.dropped_total, 2);
        ob.refill(j.durable_seq().unwrap()).unwrap();
        assert_eq!(drain(&mut ob), [2, 3, 4]);
    }

    #[test]
    fn a_cursor_ahead_of_the_journal_is_reported() {
        let dir = tempfile::tempdir().unwrap();
        let jdir = dir.path().join("journal");
        let cur = dir.path().join("cursor.json");
        let mut j = journal(&jdir, 1 << 20);
        event(&mut j, 0);
        fs::write(&cur, br#"{"next":500,"dropped":0}"#).unwrap();
        let (_, o) = Outbox::open(&jdir, j.next_seq(), &cur, limits(3)).unwrap();
        assert!(o.problem.unwrap().contains("not in the journal"));
        assert_eq!(o.from_seq, j.next_seq());
    }
}
