//! The crash-safe, append-only JSON-lines journal of shimmyd, its durable output: events,
//! alerts and estimates, one record per line.
//!
//! What it is: a directory of segment files. Records go to `current.jsonl`; when it grows past
//! the rotation size it is fsynced, renamed to `seg-<first seq, 20 digits>.jsonl` and the
//! directory is fsynced, then a fresh `current.jsonl` is created (and the directory fsynced
//! again). Every line is a complete JSON object (`jq` reads the files as they are):
//!
//! ```text
//! {"seq":41,"wall_ns":1764800000123456789,"rec":{...},"crc":"8c1f05e2"}
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
//! Every line is stamped with the wall-clock time it was written (`wall_ns`, from a
//! [`clock::WallClock`]); order is the sequence number's alone, so a clock that jumps by years
//! (a gateway without RTC set by NTP) neither reorders nor drops records.
//!
//! Disk faults: by default an I/O error is returned to the caller. Opened with a
//! [`Tolerance`] ([`Journal::open_with`]), the journal survives a full (`ENOSPC`) or read-only
//! (`EROFS`) disk instead: a torn partial line is cut off, records not yet fsynced and every
//! record appended during the outage are kept, in order, in a bounded in-memory backlog
//! (beyond it the oldest are dropped and counted: the reader sees the gap in the sequence
//! numbers, [`Reader::missing`]), writing is retried on the monotonic clock and the backlog
//! written when the disk takes it again. [`Journal::health`] says which state it is in.
//! Records acknowledged before the outage are never touched.
//!
//! Recovery: [`Journal::open`] scans `current.jsonl`; a torn or corrupt tail (anything after
//! the last valid line) is cut off and reported in [`Recovery`]; sequence numbers continue
//! after the last valid record. [`Reader`] iterates the valid records of all segments in
//! order and counts (never hides) invalid lines.
//!
//! What it is not: a database (no index, no deletion of old segments — retention is the
//! operator's, e.g. logrotate-style pruning of `seg-*.jsonl`).

pub mod clock;
pub mod fault;
pub mod line;

use std::collections::VecDeque;
use std::fs::{self, File, OpenOptions};
use std::io::{self, BufRead, BufReader, Write};
use std::path::{Path, PathBuf};
use std::time::{Duration, Instant};

use clock::{SystemClock, WallClock};
use fault::{IoFaults, Op};

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

/// How a journal opened with [`Journal::open_with`] rides out a disk that refuses writes.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Tolerance {
    /// Most bytes of records kept in memory while the disk refuses them; beyond, the oldest
    /// are dropped (and counted).
    pub backlog_bytes: usize,
    /// How often writing is tried again during an outage (monotonic clock). An explicit
    /// [`Journal::sync`] always tries.
    pub retry_every: Duration,
}

impl Default for Tolerance {
    fn default() -> Self {
        Tolerance {
            backlog_bytes: 4 * 1024 * 1024,
            retry_every: Duration::from_secs(5),
        }
    }
}

/// Options of [`Journal::open_with`] beyond [`JournalConfig`].
#[derive(Default)]
pub struct Setup {
    /// `None`: every I/O error is returned (the journal of [`Journal::open`]).
    pub tolerance: Option<Tolerance>,
    /// Injected I/O faults (tests, [`fault::DiskFaults`]).
    pub faults: Option<Box<dyn IoFaults>>,
    /// The clock of the `wall_ns` stamps; `None`: the system's.
    pub clock: Option<Box<dyn WallClock>>,
}

/// The journal's state for its owner's log, status and counters.
#[derive(Clone, Debug, Default, PartialEq, Eq, Serialize, Deserialize)]
#[serde(default)]
pub struct Health {
    /// False while the disk refuses writes (records then wait in the backlog).
    pub writable: bool,
    /// The error that started the current outage, e.g. "write: No space left on device
    /// (os error 28)".
    pub error: Option<String>,
    /// Seconds the current outage has lasted (monotonic clock).
    pub outage_s: Option<u64>,
    /// Outages since the journal was opened (each ends when the backlog is written).
    pub outages: u64,
    /// Failed I/O operations since the journal was opened (retries included).
    pub write_errors: u64,
    /// Records waiting in memory, and their size in bytes.
    pub backlog_records: u64,
    pub backlog_bytes: u64,
    /// Records dropped because the backlog was full (their sequence numbers are a gap on disk).
    pub dropped_records: u64,
    /// Sequence numbers of the first and last dropped record.
    pub dropped_seqs: Option<(u64, u64)>,
    /// Records that waited in the backlog and reached the disk later.
    pub delayed_records: u64,
}

/// One encoded line, with its sequence number.
struct Pending {
    seq: u64,
    line: Vec<u8>,
}

/// The outage machinery of a tolerant journal.
struct Outages {
    tol: Tolerance,
    /// Lines written since the last successful fsync (written again after a failed one).
    unsynced: VecDeque<Pending>,
    /// Lines the disk has not taken (in sequence order).
    backlog: VecDeque<Pending>,
    backlog_bytes: usize,
    /// (when it started, why) while the disk refuses writes.
    down: Option<(Instant, String)>,
    last_try: Instant,
    health: Health,
}

/// The append side.
pub struct Journal {
    dir: PathBuf,
    cfg: JournalConfig,
    /// `None` after a failed create (tolerant journals only): reopened on the next retry.
    file: Option<File>,
    /// Bytes of `current.jsonl` written through this journal's view.
    size: u64,
    /// Length of `current.jsonl` covered by the last fsync.
    durable_size: u64,
    next_seq: u64,
    durable_seq: Option<u64>,
    last_sync: Instant,
    buf: Vec<u8>,
    clock: Box<dyn WallClock>,
    faults: Option<Box<dyn IoFaults>>,
    outages: Option<Outages>,
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

/// What [`scan`] found in one file.
struct Scan {
    records: u64,
    /// Highest valid sequence number.
    max_seq: Option<u64>,
    /// Sequence number of the last valid line.
    last_seq: Option<u64>,
    /// End offset of the last valid line.
    end: u64,
    /// Invalid lines before it.
    corrupt: u64,
}

/// Scans one file.
fn scan(path: &Path) -> io::Result<Scan> {
    let mut r = BufReader::new(File::open(path)?);
    let mut buf = Vec::new();
    let mut s = Scan {
        records: 0,
        max_seq: None,
        last_seq: None,
        end: 0,
        corrupt: 0,
    };
    let (mut bad_since_good, mut off) = (0u64, 0u64);
    loop {
        buf.clear();
        let k = r.read_until(b'\n', &mut buf)? as u64;
        if k == 0 {
            break;
        }
        off += k;
        match line::decode(&buf) {
            Ok((seq, _)) => {
                s.records += 1;
                s.last_seq = Some(seq);
                s.max_seq = s.max_seq.max(Some(seq));
                s.end = off;
                s.corrupt += bad_since_good;
                bad_since_good = 0;
            }
            Err(_) => bad_since_good += 1,
        }
    }
    Ok(s)
}

impl Journal {
    /// Opens (creating if needed) the journal in `dir`, recovering from a crash: a torn or
    /// corrupt tail of `current.jsonl` is truncated (reported in the returned [`Recovery`]).
    /// I/O errors, then and later, are returned.
    pub fn open(dir: &Path, cfg: JournalConfig) -> anyhow::Result<(Journal, Recovery)> {
        Journal::open_with(dir, cfg, Setup::default())
    }

    /// [`Journal::open`] with the options of [`Setup`]. With a [`Tolerance`], a disk that
    /// refuses to create `current.jsonl` or to cut its torn tail does not stop the opening:
    /// the journal starts in an outage (see [`Journal::health`]); reading it must still work.
    pub fn open_with(
        dir: &Path,
        cfg: JournalConfig,
        setup: Setup,
    ) -> anyhow::Result<(Journal, Recovery)> {
        if cfg.rotate_bytes == 0 {
            bail!("journal rotate_bytes must be > 0");
        }
        let Setup {
            tolerance,
            faults,
            clock,
        } = setup;
        let now = Instant::now();
        let mut j = Journal {
            dir: dir.to_path_buf(),
            cfg,
            file: None,
            size: 0,
            durable_size: 0,
            next_seq: 1,
            durable_seq: None,
            last_sync: now,
            buf: Vec::with_capacity(4096),
            clock: clock.unwrap_or_else(|| Box::new(SystemClock)),
            faults,
            outages: tolerance.map(|tol| Outages {
                tol,
                unsynced: VecDeque::new(),
                backlog: VecDeque::new(),
                backlog_bytes: 0,
                down: None,
                last_try: now,
                health: Health {
                    writable: true,
                    ..Health::default()
                },
            }),
        };
        if let Err(e) = fs::create_dir_all(dir) {
            let e = anyhow::Error::new(e)
                .context(format!("cannot create journal directory {}", dir.display()));
            if j.outages.is_none() {
                return Err(e);
            }
            j.fail(&e);
            return Ok((j, Recovery::default()));
        }
        let cur = dir.join(CURRENT);
        let mut rec = Recovery::default();
        // The highest sequence number on disk: the journal continues after it.
        let mut max_seq = None;
        if cur.exists() {
            let sc = scan(&cur).with_context(|| format!("cannot read {}", cur.display()))?;
            let len = fs::metadata(&cur)?.len();
            rec.records = sc.records;
            rec.last_seq = sc.last_seq;
            rec.corrupt_lines = sc.corrupt;
            max_seq = sc.max_seq;
            j.size = len;
            // What recovery keeps is what a retry after a failed cut may cut back to.
            j.durable_size = sc.end;
            if len > sc.end {
                rec.truncated_bytes = len - sc.end;
                match j.cut_tail(sc.end) {
                    Ok(()) => {}
                    Err(e) if j.outages.is_some() => j.fail(&e),
                    Err(e) => return Err(e),
                }
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
                let sc = scan(s)?;
                if sc.last_seq.is_some() {
                    rec.last_seq = sc.last_seq;
                    max_seq = sc.max_seq;
                    break;
                }
            }
        }
        j.next_seq = match max_seq {
            None => 1,
            Some(s) => s.checked_add(1).with_context(|| {
                format!("journal {} has used every sequence number", dir.display())
            })?,
        };
        j.durable_seq = max_seq;
        if j.outages.as_ref().is_none_or(|o| o.down.is_none()) {
            match j.reopen() {
                Ok(()) => {}
                Err(e) if j.outages.is_some() => j.fail(&e),
                Err(e) => return Err(e),
            }
        }
        Ok((j, rec))
    }

    /// Asks the fault layer about `op`: `Err` when it must fail before doing anything.
    fn check(&mut self, op: Op) -> io::Result<()> {
        match self.faults.as_mut().and_then(|f| f.inject(op)) {
            Some((_, e)) => Err(e),
            None => Ok(()),
        }
    }

    /// Opens `current.jsonl` for appending (after a failed create or a rotation).
    fn reopen(&mut self) -> anyhow::Result<()> {
        let cur = self.dir.join(CURRENT);
        self.check(Op::Create)
            .with_context(|| format!("cannot open {}", cur.display()))?;
        let file = OpenOptions::new()
            .create(true)
            .append(true)
            .open(&cur)
            .with_context(|| format!("cannot open {}", cur.display()))?;
        let len = file.metadata()?.len();
        fsync_dir(&self.dir)
            .with_context(|| format!("cannot fsync directory {}", self.dir.display()))?;
        self.file = Some(file);
        // Its durable length stays what the caller knows (recovery's or the last fsync's):
        // anything beyond it is a torn or unacknowledged tail, cut before the next write.
        self.size = len;
        Ok(())
    }

    /// Cuts `current.jsonl` back to `len` bytes (a torn tail) and makes that durable.
    fn cut_tail(&mut self, len: u64) -> anyhow::Result<()> {
        let cur = self.dir.join(CURRENT);
        let freed = self.size.saturating_sub(len);
        self.check(Op::Truncate { freed })
            .with_context(|| format!("cannot truncate torn tail of {}", cur.display()))?;
        let f = match &self.file {
            Some(f) => f.try_clone()?,
            None => OpenOptions::new().write(true).open(&cur)?,
        };
        f.set_len(len)
            .with_context(|| format!("cannot truncate torn tail of {}", cur.display()))?;
        f.sync_all()
            .with_context(|| format!("cannot fsync {}", cur.display()))?;
        self.size = len;
        Ok(())
    }

    /// Writes one whole line (a partial write on a full disk leaves a torn tail, which the
    /// caller cuts off).
    fn write_line(&mut self, line: &[u8]) -> anyhow::Result<()> {
        let injected = self
            .faults
            .as_mut()
            .and_then(|f| f.inject(Op::Write { len: line.len() }));
        let Some(file) = self.file.as_mut() else {
            bail!("cannot write to the journal: {CURRENT} is not open");
        };
        match injected {
            Some((done, e)) => {
                let done = done.min(line.len());
                file.write_all(&line[..done])
                    .context("cannot write to the journal")?;
                self.size += done as u64;
                Err(anyhow::Error::new(e).context("cannot write to the journal"))
            }
            None => match file.write_all(line) {
                Ok(()) => {
                    self.size += line.len() as u64;
                    Ok(())
                }
                Err(e) => {
                    // A full disk takes part of the line before it refuses the rest: the
                    // file's length says how much (the torn part is cut by the caller).
                    self.size = file
                        .metadata()
                        .map_or(self.size + line.len() as u64, |m| m.len());
                    Err(anyhow::Error::new(e).context("cannot write to the journal"))
                }
            },
        }
    }

    /// fdatasync of `current.jsonl`.
    fn fsync(&mut self) -> anyhow::Result<()> {
        self.check(Op::Sync).context("cannot fsync the journal")?;
        let Some(file) = self.file.as_mut() else {
            bail!("cannot fsync the journal: {CURRENT} is not open");
        };
        file.sync_data().context("cannot fsync the journal")?;
        self.durable_size = self.size;
        Ok(())
    }

    /// Appends one record (any serialisable value; it lands under `rec`). Returns its sequence
    /// number. The whole line is written with one `write` call. A tolerant journal
    /// ([`Journal::open_with`]) returns an error only for a record that cannot be serialised;
    /// a refused write starts an outage instead (see [`Journal::health`]).
    pub fn append<T: Serialize>(&mut self, record: &T) -> anyhow::Result<u64> {
        let seq = self.next_seq;
        let after = seq
            .checked_add(1)
            .context("the journal has used every sequence number")?;
        self.buf.clear();
        let wall = self.clock.now_ns();
        line::encode_stamped(seq, Some(wall), record, &mut self.buf)
            .context("cannot serialise journal record")?;
        self.next_seq = after;
        if self.outages.is_none() {
            let line = std::mem::take(&mut self.buf);
            let r = self.write_line(&line);
            self.buf = line;
            r?;
            match self.cfg.fsync {
                FsyncPolicy::Always => self.sync()?,
                FsyncPolicy::IntervalMs(_) => self.tick()?,
            }
            if self.size >= self.cfg.rotate_bytes {
                self.rotate()?;
            }
            return Ok(seq);
        }
        let line = self.buf.clone();
        let down = self.outages.as_ref().is_some_and(|o| o.down.is_some());
        if down {
            self.push_backlog(Pending { seq, line });
            self.retry_if_due();
            return Ok(seq);
        }
        match self.write_line(&line) {
            Ok(()) => {
                if let Some(o) = self.outages.as_mut() {
                    o.unsynced.push_back(Pending { seq, line });
                }
            }
            Err(e) => {
                self.push_backlog(Pending { seq, line });
                self.fail(&e);
                return Ok(seq);
            }
        }
        match self.cfg.fsync {
            FsyncPolicy::Always => self.sync()?,
            FsyncPolicy::IntervalMs(_) => self.tick()?,
        }
        if self.size >= self.cfg.rotate_bytes && self.writable() {
            if let Err(e) = self.rotate() {
                self.fail(&e);
            }
        }
        Ok(seq)
    }

    /// With [`FsyncPolicy::IntervalMs`]: fsyncs if the interval has passed and records are
    /// pending. A tolerant journal in an outage also tries writing again here (at most every
    /// [`Tolerance::retry_every`]). Call it periodically (the daemon does, once per loop
    /// turn).
    pub fn tick(&mut self) -> anyhow::Result<()> {
        if !self.writable() {
            self.retry_if_due();
            return Ok(());
        }
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

    /// fsyncs now: every record appended so far is acknowledged afterwards. A tolerant journal
    /// in an outage tries to write its backlog first; if the disk still refuses, the call
    /// succeeds and the records stay in the backlog (not acknowledged).
    pub fn sync(&mut self) -> anyhow::Result<()> {
        if !self.writable() {
            self.retry();
            return Ok(());
        }
        if self.pending() {
            if let Err(e) = self.fsync() {
                if self.outages.is_none() {
                    return Err(e);
                }
                self.fail(&e);
                return Ok(());
            }
            self.durable_seq = Some(self.next_seq - 1);
            if let Some(o) = self.outages.as_mut() {
                o.unsynced.clear();
            }
        }
        self.last_sync = Instant::now();
        Ok(())
    }

    /// Highest acknowledged (fsynced) sequence number. In a tolerant journal every record up
    /// to it is on disk, except those reported dropped ([`Health::dropped_seqs`]).
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

    /// False while a tolerant journal's disk refuses writes.
    pub fn writable(&self) -> bool {
        self.outages.as_ref().is_none_or(|o| o.down.is_none())
    }

    /// The outage state and its counters (a journal opened without [`Tolerance`] is always
    /// reported writable, with zero counts: its errors go to the caller).
    pub fn health(&self) -> Health {
        match &self.outages {
            None => Health {
                writable: true,
                ..Health::default()
            },
            Some(o) => {
                let mut h = o.health.clone();
                h.writable = o.down.is_none();
                h.error = o.down.as_ref().map(|(_, e)| e.clone());
                h.outage_s = o.down.as_ref().map(|(t, _)| t.elapsed().as_secs());
                h.backlog_records = o.backlog.len() as u64;
                h.backlog_bytes = o.backlog_bytes as u64;
                h
            }
        }
    }

    /// A refused I/O operation of a tolerant journal: the outage starts (or goes on). Lines
    /// written since the last fsync go back to the front of the backlog (they are not
    /// acknowledged and may be torn or lost), and the file is cut back to its last durable
    /// length when the disk allows it.
    fn fail(&mut self, e: &anyhow::Error) {
        let Some(o) = self.outages.as_mut() else {
            return;
        };
        o.health.write_errors += 1;
        if o.down.is_none() {
            o.health.outages += 1;
            o.down = Some((Instant::now(), format!("{e:#}")));
        }
        o.last_try = Instant::now();
        while let Some(p) = o.unsynced.pop_back() {
            o.backlog_bytes += p.line.len();
            o.backlog.push_front(p);
        }
        self.enforce_backlog_limit();
        if self.file.is_some() && self.size > self.durable_size {
            let keep = self.durable_size;
            if self.cut_tail(keep).is_err() {
                // Read-only: cut on the next successful retry (recovery at the next open
                // would cut it too: it is a torn or unacknowledged tail).
                if let Some(o) = self.outages.as_mut() {
                    o.health.write_errors += 1;
                }
            }
        }
        // Closed during the outage (each retry reopens it): a journal waiting for its disk
        // holds no file open for writing, so the filesystem can be remounted or repaired.
        self.file = None;
    }

    fn push_backlog(&mut self, p: Pending) {
        if let Some(o) = self.outages.as_mut() {
            o.backlog_bytes += p.line.len();
            o.backlog.push_back(p);
        }
        self.enforce_backlog_limit();
    }

    /// Drops the oldest waiting records beyond the backlog's size (the newest one is always
    /// kept), counting them.
    fn enforce_backlog_limit(&mut self) {
        let Some(o) = self.outages.as_mut() else {
            return;
        };
        while o.backlog_bytes > o.tol.backlog_bytes && o.backlog.len() > 1 {
            let p = o.backlog.pop_front().expect("len > 1");
            o.backlog_bytes -= p.line.len();
            o.health.dropped_records += 1;
            o.health.dropped_seqs = Some(match o.health.dropped_seqs {
                None => (p.seq, p.seq),
                Some((a, b)) => (a.min(p.seq), b.max(p.seq)),
            });
        }
    }

    fn retry_if_due(&mut self) {
        if self
            .outages
            .as_ref()
            .is_some_and(|o| o.down.is_some() && o.last_try.elapsed() >= o.tol.retry_every)
        {
            self.retry();
        }
    }

    /// One attempt to end an outage: reopen `current.jsonl`, cut what an earlier failure left
    /// past the last fsync, write the backlog in order, fsync. On success the backlog's
    /// records are acknowledged; on failure the outage goes on with everything still waiting.
    fn retry(&mut self) {
        let Some(o) = self.outages.as_mut() else {
            return;
        };
        o.last_try = Instant::now();
        let r = (|| -> anyhow::Result<()> {
            let keep = self.durable_size;
            self.file = None;
            self.reopen()?;
            if self.size > keep {
                self.cut_tail(keep)?;
            }
            self.durable_size = self.size;
            while let Some(p) = self.outages.as_mut().and_then(|o| o.backlog.pop_front()) {
                let o = self.outages.as_mut().expect("tolerant");
                o.backlog_bytes -= p.line.len();
                let r = self.write_line(&p.line);
                self.outages
                    .as_mut()
                    .expect("tolerant")
                    .unsynced
                    .push_back(p);
                r?;
            }
            self.fsync()
        })();
        match r {
            Ok(()) => {
                let o = self.outages.as_mut().expect("tolerant");
                o.health.delayed_records += o.unsynced.len() as u64;
                o.unsynced.clear();
                o.down = None;
                self.durable_seq = self.next_seq.checked_sub(1).filter(|&s| s > 0);
                self.last_sync = Instant::now();
                if self.size >= self.cfg.rotate_bytes {
                    if let Err(e) = self.rotate() {
                        self.fail(&e);
                    }
                }
            }
            Err(e) => self.fail(&e),
        }
    }

    /// Closes `current.jsonl` as a numbered segment and starts a new one. Every step is atomic
    /// (rename) and made durable (fsync of the file, then of the directory), so a crash between
    /// steps leaves either the old or the new layout, never a half-written file.
    fn rotate(&mut self) -> anyhow::Result<()> {
        self.sync()?;
        if !self.writable() {
            return Ok(());
        }
        if let Some(f) = &self.file {
            f.sync_all().context("cannot fsync the journal")?;
        }
        let cur = self.dir.join(CURRENT);
        let first = first_seq(&cur)?.unwrap_or(self.next_seq);
        let seg = self.dir.join(segment_name(first));
        self.check(Op::Rename)
            .with_context(|| format!("cannot rotate journal to {}", seg.display()))?;
        fs::rename(&cur, &seg)
            .with_context(|| format!("cannot rotate journal to {}", seg.display()))?;
        fsync_dir(&self.dir)?;
        // The renamed file is complete and durable; what follows goes to a new current.
        self.file = None;
        self.size = 0;
        self.durable_size = 0;
        self.reopen()
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
    /// When it was written (wall clock, ns since the Unix epoch), if stamped: information,
    /// not order (the clock may have jumped).
    pub wall_ns: Option<i64>,
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
    missing: u64,
    last_wall: Option<i64>,
    jumps_back: u64,
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
            missing: 0,
            last_wall: None,
            jumps_back: 0,
        })
    }

    /// Sequence numbers absent between the first and the last record read so far: records
    /// dropped during a disk outage ([`Health::dropped_seqs`]) or lost with a damaged line.
    pub fn missing(&self) -> u64 {
        self.missing
    }

    /// Records stamped earlier than the record before them: the wall clock was set back
    /// while the journal was written (they are still delivered in sequence order).
    pub fn wall_clock_jumps_back(&self) -> u64 {
        self.jumps_back
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
            match line::decode_full(&self.buf) {
                Ok(line::Decoded { seq, wall_ns, rec }) => {
                    if let Some(l) = self.last_seq {
                        if seq <= l {
                            self.out_of_order += 1;
                            continue;
                        }
                        self.missing += seq - l - 1;
                    }
                    self.last_seq = Some(seq);
                    if let Some(w) = wall_ns {
                        if self.last_wall.is_some_and(|lw| w < lw) {
                            self.jumps_back += 1;
                        }
                        self.last_wall = Some(w);
                    }
                    return Ok(Some(Entry { seq, wall_ns, rec }));
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
