//! The crash-safe, append-only JSON-lines journal of shimmyd, its durable output: events,
//! alerts and estimates, one record per line.
//!
//! What it is: a directory of segment files. Records go to `current.jsonl`; when it grows past
//! the rotation size it is fsynced, renamed to `seg-<first seq, 20 digits>.jsonl` and the
//! directory is fsynced, then a fresh `current.jsonl` is created (and the directory fsynced
//! again). Every line is a complete JSON object (`jq` reads the files as they are):
//!
//! ```text
//! {"seq":41,"rec":{...},"crc":"8c1f05e2"}
//! ```
//!
//! `crc` is CRC-32C of every byte of the line before `,"crc":`, so a line torn by a power cut
//! or altered on disk is detected ([`line`] is the wire format; this module is the policy).
//!
//! Durability contract: [`Journal::append`] returns the record's sequence number; the record is
//! *acknowledged* once [`Journal::durable_seq`] has reached it. With [`FsyncPolicy::Always`]
//! that is before `append` returns; with [`FsyncPolicy::IntervalMs`] it happens on the first
//! `append` / [`Journal::tick`] at least that long after the previous fsync, or on
//! [`Journal::sync`]. An acknowledged record survives a crash or power cut at any instant
//! (assuming the storage honours fsync).
//!
//! Recovery: [`Journal::open`] scans `current.jsonl`; a torn or corrupt tail (anything after
//! the last valid line) is cut off and reported in [`Recovery`]; sequence numbers continue
//! after the last valid record. [`Reader`] iterates the valid records of all segments in
//! order and counts (never hides) invalid lines.
//!
//! What it is not: a database (no index, no deletion of old segments — retention is the
//! operator's, e.g. logrotate-style pruning of `seg-*.jsonl`).

pub mod line;

use std::fs::{self, File, OpenOptions};
use std::io::{self, BufRead, BufReader, Write};
use std::path::{Path, PathBuf};
use std::time::{Duration, Instant};

use anyhow::{bail, Context};
use serde::{Deserialize, Serialize};

/// Name of the segment being written.
pub const CURRENT: &str = "current.jsonl";

/// When records reach the disk.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case", deny_unknown_fields)]
pub enum FsyncPolicy {
    /// fdatasync after every record: acknowledged when `append` returns.
    Always,
    /// fdatasync at most every N ms (on `append` or `tick`): cheaper, loses at most N ms.
    IntervalMs(u64),
}

/// Journal settings.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct JournalConfig {
    pub fsync: FsyncPolicy,
    /// Rotate `current.jsonl` once it is at least this big (bytes).
    pub rotate_bytes: u64,
}

impl Default for JournalConfig {
    fn default() -> Self {
        JournalConfig {
            fsync: FsyncPolicy::Always,
            rotate_bytes: 16 * 1024 * 1024,
        }
    }
}

/// What [`Journal::open`] found.
#[derive(Clone, Debug, Default, PartialEq, Eq, Serialize)]
pub struct Recovery {
    /// Valid records in `current.jsonl`.
    pub records: u64,
    /// Bytes cut off the end of `current.jsonl` (a torn or corrupt last write).
    pub truncated_bytes: u64,
    /// Invalid lines before the last valid one (left in place, skipped by readers).
    pub corrupt_lines: u64,
    /// Sequence number of the last valid record, if any.
    pub last_seq: Option<u64>,
}

/// The append side.
pub struct Journal {
    dir: PathBuf,
    cfg: JournalConfig,
    file: File,
    size: u64,
    next_seq: u64,
    durable_seq: Option<u64>,
    last_sync: Instant,
    buf: Vec<u8>,
}

fn fsync_dir(dir: &Path) -> io::Result<()> {
    File::open(dir)?.sync_all()
}

fn segment_name(first_seq: u64) -> String {
    format!("seg-{first_seq:020}.jsonl")
}

/// Segment files in read order: rotated segments by first sequence number, then the current
/// one.
pub fn segments(dir: &Path) -> io::Result<Vec<PathBuf>> {
    let mut segs = Vec::new();
    for e in fs::read_dir(dir)? {
        let e = e?;
        let name = e.file_name();
        let name = name.to_string_lossy();
        if name.starts_with("seg-") && name.ends_with(".jsonl") {
            segs.push(e.path());
        }
    }
    segs.sort();
    let cur = dir.join(CURRENT);
    if cur.exists() {
        segs.push(cur);
    }
    Ok(segs)
}

/// Scans one file: (valid records, last valid seq, end offset of the last valid line, invalid
/// lines before it).
fn scan(path: &Path) -> io::Result<(u64, Option<u64>, u64, u64)> {
    let mut r = BufReader::new(File::open(path)?);
    let mut buf = Vec::new();
    let (mut n, mut last, mut end, mut bad_since_good, mut bad_total, mut off) =
        (0u64, None, 0u64, 0u64, 0u64, 0u64);
    loop {
        buf.clear();
        let k = r.read_until(b'\n', &mut buf)? as u64;
        if k == 0 {
            break;
        }
        off += k;
        match line::decode(&buf) {
            Ok((seq, _)) => {
                n += 1;
                last = Some(seq);
                end = off;
                bad_total += bad_since_good;
                bad_since_good = 0;
            }
            Err(_) => bad_since_good += 1,
        }
    }
    Ok((n, last, end, bad_total))
}

impl Journal {
    /// Opens (creating if needed) the journal in `dir`, recovering from a crash: a torn or
    /// corrupt tail of `current.jsonl` is truncated (reported in the returned [`Recovery`]).
    pub fn open(dir: &Path, cfg: JournalConfig) -> anyhow::Result<(Journal, Recovery)> {
        if cfg.rotate_bytes == 0 {
            bail!("journal rotate_bytes must be > 0");
        }
        fs::create_dir_all(dir)
            .with_context(|| format!("cannot create journal directory {}", dir.display()))?;
        let cur = dir.join(CURRENT);
        let mut rec = Recovery::default();
        if cur.exists() {
            let (n, last, end, bad) =
                scan(&cur).with_context(|| format!("cannot read {}", cur.display()))?;
            let len = fs::metadata(&cur)?.len();
            rec.records = n;
            rec.last_seq = last;
            rec.corrupt_lines = bad;
            if len > end {
                rec.truncated_bytes = len - end;
                let f = OpenOptions::new().write(true).open(&cur)?;
                f.set_len(end)
                    .with_context(|| format!("cannot truncate torn tail of {}", cur.display()))?;
                f.sync_all()?;
            }
        }
        // No valid record in current: the last seq is in the newest rotated segment (a crash
        // right after a rotation leaves an empty or missing current.jsonl).
        if rec.last_seq.is_none() {
            let segs = segments(dir)?;
            for s in segs.iter().rev() {
                if s.ends_with(CURRENT) {
                    continue;
                }
                let (_, last, _, _) = scan(s)?;
                if last.is_some() {
                    rec.last_seq = last;
                    break;
                }
            }
        }
        let file = OpenOptions::new()
            .create(true)
            .append(true)
            .open(&cur)
            .with_context(|| format!("cannot open {}", cur.display()))?;
        let size = file.metadata()?.len();
        fsync_dir(dir)?;
        let next_seq = rec.last_seq.map_or(1, |s| s + 1);
        Ok((
            Journal {
                dir: dir.to_path_buf(),
                cfg,
                file,
                size,
                next_seq,
                durable_seq: rec.last_seq,
                last_sync: Instant::now(),
                buf: Vec::with_capacity(4096),
            },
            rec,
        ))
    }

    /// Appends one record (any serialisable value; it lands under `rec`). Returns its sequence
    /// number. The whole line is written with one `write` call.
    pub fn append<T: Serialize>(&mut self, record: &T) -> anyhow::Result<u64> {
        let seq = self.next_seq;
        self.buf.clear();
        line::encode(seq, record, &mut self.buf).context("cannot serialise journal record")?;
        self.file
            .write_all(&self.buf)
            .context("cannot write to the journal")?;
        self.size += self.buf.len() as u64;
        self.next_seq += 1;
        match self.cfg.fsync {
            FsyncPolicy::Always => self.sync()?,
            FsyncPolicy::IntervalMs(_) => self.tick()?,
        }
        if self.size >= self.cfg.rotate_bytes {
            self.rotate()?;
        }
        Ok(seq)
    }

    /// With [`FsyncPolicy::IntervalMs`]: fsyncs if the interval has passed and records are
    /// pending. Call it periodically (the daemon does, once per loop turn).
    pub fn tick(&mut self) -> anyhow::Result<()> {
        if let FsyncPolicy::IntervalMs(ms) = self.cfg.fsync {
            if self.pending() && self.last_sync.elapsed() >= Duration::from_millis(ms) {
                self.sync()?;
            }
        }
        Ok(())
    }

    fn pending(&self) -> bool {
        self.durable_seq.map_or(0, |s| s + 1) < self.next_seq && self.next_seq > 1
    }

    /// fsyncs now: every record appended so far is acknowledged afterwards.
    pub fn sync(&mut self) -> anyhow::Result<()> {
        if self.pending() {
            self.file.sync_data().context("cannot fsync the journal")?;
            self.durable_seq = Some(self.next_seq - 1);
        }
        self.last_sync = Instant::now();
        Ok(())
    }

    /// Highest acknowledged (fsynced) sequence number.
    pub fn durable_seq(&self) -> Option<u64> {
        self.durable_seq
    }

    /// Sequence number the next record will get.
    pub fn next_seq(&self) -> u64 {
        self.next_seq
    }

    pub fn dir(&self) -> &Path {
        &self.dir
    }

    /// Closes `current.jsonl` as a numbered segment and starts a new one. Every step is atomic
    /// (rename) and made durable (fsync of the file, then of the directory), so a crash between
    /// steps leaves either the old or the new layout, never a half-written file.
    fn rotate(&mut self) -> anyhow::Result<()> {
        self.sync()?;
        self.file.sync_all()?;
        let cur = self.dir.join(CURRENT);
        let first = first_seq(&cur)?.unwrap_or(self.next_seq);
        let seg = self.dir.join(segment_name(first));
        fs::rename(&cur, &seg)
            .with_context(|| format!("cannot rotate journal to {}", seg.display()))?;
        fsync_dir(&self.dir)?;
        self.file = OpenOptions::new().create(true).append(true).open(&cur)?;
        fsync_dir(&self.dir)?;
        self.size = 0;
        Ok(())
    }
}

impl Drop for Journal {
    fn drop(&mut self) {
        let _ = self.sync();
    }
}

fn first_seq(path: &Path) -> io::Result<Option<u64>> {
    let mut r = BufReader::new(File::open(path)?);
    let mut buf = Vec::new();
    loop {
        buf.clear();
        if r.read_until(b'\n', &mut buf)? == 0 {
            return Ok(None);
        }
        if let Ok((seq, _)) = line::decode(&buf) {
            return Ok(Some(seq));
        }
    }
}

/// One valid record read back.
#[derive(Clone, Debug, PartialEq)]
pub struct Entry {
    pub seq: u64,
    pub rec: serde_json::Value,
}

/// Iterates the valid records of a journal directory in sequence order, across rotated
/// segments. Invalid lines are skipped and counted ([`Reader::invalid_lines`]), with the first
/// few locations in [`Reader::problems`].
pub struct Reader {
    files: std::vec::IntoIter<PathBuf>,
    cur: Option<(PathBuf, BufReader<File>, u64)>,
    buf: Vec<u8>,
    invalid: u64,
    problems: Vec<String>,
    last_seq: Option<u64>,
    out_of_order: u64,
}

impl Reader {
    pub fn open(dir: &Path) -> anyhow::Result<Reader> {
        let files = segments(dir)
            .with_context(|| format!("cannot list journal directory {}", dir.display()))?;
        if files.is_empty() {
            bail!(
                "{} holds no journal (no {CURRENT} or seg-*.jsonl)",
                dir.display()
            );
        }
        Ok(Reader {
            files: files.into_iter(),
            cur: None,
            buf: Vec::new(),
            invalid: 0,
            problems: Vec::new(),
            last_seq: None,
            out_of_order: 0,
        })
    }

    /// Lines that failed the CRC or did not parse.
    pub fn invalid_lines(&self) -> u64 {
        self.invalid
    }

    /// Records whose sequence number did not increase (skipped).
    pub fn out_of_order(&self) -> u64 {
        self.out_of_order
    }

    /// `file:line: reason` for the first invalid lines.
    pub fn problems(&self) -> &[String] {
        &self.problems
    }

    fn next_entry(&mut self) -> anyhow::Result<Option<Entry>> {
        loop {
            if self.cur.is_none() {
                let Some(p) = self.files.next() else {
                    return Ok(None);
                };
                let f = File::open(&p).with_context(|| format!("cannot open {}", p.display()))?;
                self.cur = Some((p, BufReader::new(f), 0));
            }
            let (path, r, lineno) = self.cur.as_mut().expect("set above");
            self.buf.clear();
            let k = r
                .read_until(b'\n', &mut self.buf)
                .with_context(|| format!("cannot read {}", path.display()))?;
            if k == 0 {
                self.cur = None;
                continue;
            }
            *lineno += 1;
            match line::decode(&self.buf) {
                Ok((seq, rec)) => {
                    if self.last_seq.is_some_and(|l| seq <= l) {
                        self.out_of_order += 1;
                        continue;
                    }
                    self.last_seq = Some(seq);
                    return Ok(Some(Entry { seq, rec }));
                }
                Err(e) => {
                    self.invalid += 1;
                    if self.problems.len() < 20 {
                        self.problems
                            .push(format!("{}:{}: {e}", path.display(), lineno));
                    }
                }
            }
        }
    }
}

impl Iterator for Reader {
    type Item = anyhow::Result<Entry>;
    fn next(&mut self) -> Option<Self::Item> {
        self.next_entry().transpose()
    }
}
