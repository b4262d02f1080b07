//! The Parquet data lake of a fleet: one vehicle's CAN logs → decoded signals in the CSS
//! Electronics layout, and the monitor's own tables (`events`, `estimates`, `alerts`) in Hive
//! partitions, written so that rerunning the same input rewrites the same bytes under the same
//! names. The schema, partitions and rules are documented in docs/FLEET.md; this module is their
//! only implementation.
//!
//! Layout under the lake root:
//!
//! | path | content |
//! |---|---|
//! | `<vehicle>/<message>/<yyyy>/<mm>/<dd>/<log16>-<dbc8>-<seq>.parquet` | decoded signals of one CAN message ([`signals`]) |
//! | `events/vehicle=<vehicle>/date=<yyyy-mm-dd>/<run16>-<nnnn>.parquet` | finished braking events ([`tables`]) |
//! | `estimates/vehicle=<vehicle>/date=<yyyy-mm-dd>/<run16>-<nnnn>.parquet` | the estimate after each event |
//! | `alerts/vehicle=<vehicle>/date=<yyyy-mm-dd>/<run16>-<nnnn>.parquet` | alert transitions |
//!
//! Names: `log16` is the first 16 hex digits of the log's BLAKE3 hash, `dbc8` of the DBC's
//! sha256 (the signal files depend on nothing else); `run16` of the run's hash ([`run_sha256`]:
//! every log's hash in order, the DBC, mapping, table and settings, and the torque table and
//! the profile's correction when the run has them), `nnnn` the log's position
//! in the run (the monitor's rows depend on every log before them), `seq` the message's files
//! of that log.
//! Dates are the UTC dates of the frames' timestamps (signals) or of the event's end (tables).
//!
//! One log at a time ([`Exporter::export_log`]): its frames go through the DBC decoder into the
//! signal files and, frame by frame, through the same pipeline as `shimmy estimate`
//! ([`crate::pipeline::feeder::Offline`]: mapper → detector samples → [`crate::pipeline::Monitor`]
//! → alert book) into the monitor's rows. The log's hash is computed from the bytes the reader
//! reads, in the same pass (an MDF 4 file, read by seeking, is hashed in a pass of its own).
//! Logs are hashed with BLAKE3 (`b3sum` checks it), the small inputs with sha256: a log is the
//! only input whose hash costs, and sha256 was a tenth of an export's CPU time (BENCHMARKS.md).
//! A log's signal files appear (renamed from hidden temporary names to their hash-derived
//! names) only when the whole log has been read; a log that fails leaves none of them. The
//! monitor's rows are held until [`Exporter::finish`], when every log's hash, hence the run's,
//! is known (they are a few rows per braking event).
//!
//! What it is not: the pipeline (reused, not copied), a Parquet reader, or a catalogue (no
//! manifest: the file names are the catalogue).

pub mod signals;
pub mod tables;
pub mod write;

use std::io::{Read, Seek};
use std::path::{Path, PathBuf};
use std::sync::{Arc, Mutex};

use anyhow::{bail, Context};
use sha2::{Digest, Sha256};

use crate::pipeline::feeder::Offline;
use crate::source::log::LogReader;
use crate::source::{CanSource, Skip};
use crate::wire::Frame;
use signals::{civil_date, SignalCounts, SignalFiles};
use tables::{MonitorRows, Stamp, TABLES};

/// Lower-case hex of bytes.
fn hex(bytes: &[u8]) -> String {
    use std::fmt::Write;
    let mut s = String::with_capacity(bytes.len() * 2);
    for b in bytes {
        let _ = write!(s, "{b:02x}");
    }
    s
}

/// sha256 of a file's content, hex.
pub fn sha256_file(path: &Path) -> anyhow::Result<String> {
    let mut f =
        std::fs::File::open(path).with_context(|| format!("cannot open {}", path.display()))?;
    let mut h = Sha256::new();
    hash_to_end(&mut f, |b| h.update(b), path)?;
    Ok(hex(&h.finalize()))
}

/// BLAKE3 of a file's content, hex (what `b3sum` prints): a log's identity in the lake.
pub fn blake3_file(path: &Path) -> anyhow::Result<String> {
    let mut f =
        std::fs::File::open(path).with_context(|| format!("cannot open {}", path.display()))?;
    blake3_to_end(blake3::Hasher::new(), &mut f, path)
}

/// `h` fed the rest of `r` (the file `path`), finished: BLAKE3 hex.
fn blake3_to_end(mut h: blake3::Hasher, r: &mut impl Read, path: &Path) -> anyhow::Result<String> {
    hash_to_end(
        r,
        |b| {
            h.update(b);
        },
        path,
    )?;
    Ok(h.finalize().to_hex().to_string())
}

/// Feeds the rest of `r` (the file `path`) into `update`.
fn hash_to_end(
    r: &mut impl Read,
    mut update: impl FnMut(&[u8]),
    path: &Path,
) -> anyhow::Result<()> {
    let mut buf = vec![0u8; 1 << 20];
    loop {
        let n = r
            .read(&mut buf)
            .with_context(|| format!("reading {}", path.display()))?;
        if n == 0 {
            return Ok(());
        }
        update(&buf[..n]);
    }
}

/// A reader that hashes what it reads: the log's BLAKE3 in the pass that parses it.
struct HashingReader<R> {
    inner: R,
    state: Arc<Mutex<(blake3::Hasher, u64)>>,
}

impl<R: Read> Read for HashingReader<R> {
    fn read(&mut self, buf: &mut [u8]) -> std::io::Result<usize> {
        let n = self.inner.read(buf)?;
        let mut st = self.state.lock().unwrap_or_else(|e| e.into_inner());
        st.0.update(&buf[..n]);
        st.1 += n as u64;
        Ok(n)
    }
}

/// Opens a log for reading while hashing it. The returned closure gives the file's BLAKE3 once
/// reading has ended: what the reader read, completed from the file when the reader stopped
/// before the end (a container's trailing bytes, a read error). MDF 4 is read by seeking, so it
/// is hashed in a pass of its own.
fn open_hashed(
    path: &Path,
) -> anyhow::Result<(LogReader, Box<dyn FnOnce() -> anyhow::Result<String>>)> {
    let state = Arc::new(Mutex::new((blake3::Hasher::new(), 0u64)));
    let (src, hashed) = LogReader::open_with(path, |inner| HashingReader {
        inner,
        state: Arc::clone(&state),
    })
    .with_context(|| format!("cannot open log {}", path.display()))?;
    if !hashed {
        // MDF 4 is read by seeking: its bytes are hashed in a pass of their own.
        let hash = blake3_file(path)?;
        return Ok((src, Box::new(move || Ok(hash))));
    }
    let path = path.to_path_buf();
    let finish = move || -> anyhow::Result<String> {
        let (h, read) = {
            let st = state.lock().unwrap_or_else(|e| e.into_inner());
            (st.0.clone(), st.1)
        };
        let mut f = std::fs::File::open(&path)
            .with_context(|| format!("cannot open {}", path.display()))?;
        f.seek(std::io::SeekFrom::Start(read))
            .with_context(|| format!("reading {}", path.display()))?;
        blake3_to_end(h, &mut f, &path)
    };
    Ok((src, Box::new(finish)))
}

/// sha256 of bytes, hex.
pub fn sha256_bytes(bytes: &[u8]) -> String {
    hex(&Sha256::digest(bytes))
}

/// The code version every row carries: `shimmy-monitor <version>`.
pub fn model_version() -> String {
    write::created_by()
}

/// What a run's output depends on besides its logs.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct Inputs {
    /// The vehicle ID (the device folder and the `vehicle=` partition).
    pub vehicle: String,
    pub dbc_sha256: String,
    pub table_sha256: Option<String>,
    /// sha256 of the profile's torque table, when the run used one.
    pub torque_table_sha256: Option<String>,
    /// sha256 of the profile's correction file (`correction`, src/observer/correction.rs),
    /// when the profile names one: it changes every estimate.
    pub correction_sha256: Option<String>,
    /// With tables of the profile's chassis variants: sha256 of each variant's name and table
    /// hashes in order (`name \0 torque-sha256 \0 angle:sha256 \0 ...`, each table where the
    /// variant has one and the run uses it); a part of the run's hash only.
    pub variants_sha256: Option<String>,
    /// sha256 of the mapping file and of the monitor's settings as used (their JSON).
    pub mapping_sha256: String,
    pub settings_sha256: String,
}

/// The run's hash (sha256): the model version, every input's hash and every log's BLAKE3, in
/// order. The torque table's and the correction's hashes are parts only when the run has them,
/// so that a run without them keeps the hash it had before they existed (its lake stays
/// resumable) and a run whose correction changed gets another hash.
pub fn run_sha256(inputs: &Inputs, log_blake3: &[String]) -> String {
    let mut h = Sha256::new();
    for part in [
        "shimmy-lake-run-2",
        &model_version(),
        &inputs.vehicle,
        &inputs.dbc_sha256,
        inputs.table_sha256.as_deref().unwrap_or("-"),
        &inputs.mapping_sha256,
        &inputs.settings_sha256,
    ] {
        h.update(part.as_bytes());
        h.update([0]);
    }
    // A run without a torque table hashes as before there was one.
    if let Some(t) = &inputs.torque_table_sha256 {
        h.update(b"torque:");
        h.update(t.as_bytes());
        h.update([0]);
    }
    // Likewise a run without a correction, and one without chassis variants.
    if let Some(c) = &inputs.correction_sha256 {
        h.update(b"correction:");
        h.update(c.as_bytes());
        h.update([0]);
    }
    if let Some(v) = &inputs.variants_sha256 {
        h.update(b"variants:");
        h.update(v.as_bytes());
        h.update([0]);
    }
    for s in log_blake3 {
        h.update(s.as_bytes());
        h.update([0]);
    }
    hex(&h.finalize())
}

/// A vehicle ID usable as a folder name: 1–64 of `A–Z a–z 0–9 _ . -`, not starting with a dot,
/// and not one of the monitor tables' names.
pub fn check_vehicle_id(id: &str) -> anyhow::Result<()> {
    let ok = !id.is_empty()
        && id.len() <= 64
        && !id.starts_with('.')
        && id
            .bytes()
            .all(|b| b.is_ascii_alphanumeric() || matches!(b, b'_' | b'.' | b'-'));
    if !ok {
        bail!(
            "vehicle ID {id:?} is not usable as a folder name (1-64 of A-Z a-z 0-9 _ . -, not \
             starting with a dot)"
        );
    }
    if TABLES.contains(&id) {
        bail!("vehicle ID {id:?} is the name of a monitor table folder; choose another");
    }
    Ok(())
}

/// What one log gave.
#[derive(Clone, Debug, Default, serde::Serialize)]
pub struct LogDone {
    /// BLAKE3 of the log file, hex.
    pub blake3: String,
    pub frames: u64,
    pub signals: SignalCounts,
    /// Braking events that finished during this log.
    pub events: usize,
    /// Files written (renamed into place), signal and monitor files.
    pub files: Vec<PathBuf>,
    /// What the log reader skipped (malformed lines, …), with where.
    #[serde(skip)]
    pub skips: Vec<Skip>,
}

/// One vehicle's export: the offline pipeline, carried across its logs in order.
pub struct Exporter {
    lake: PathBuf,
    inputs: Inputs,
    pipe: Offline,
    /// Each log's BLAKE3 by position in the run (None: it could not be read to the end).
    hashes: Vec<Option<String>>,
    /// The monitor's rows by the position of the log they finished in, written at
    /// [`Exporter::finish`], when the run's hash is known.
    rows: Vec<(usize, MonitorRows)>,
    /// The position of the last log that reached the monitor (an event the end of the run
    /// closes is filed with it).
    last: Option<usize>,
    /// Whether the decoded signal files are written ([`Exporter::without_signals`]).
    signals: bool,
}

/// What a finished run wrote.
pub struct RunDone {
    /// The monitor's files written at the end of the run.
    pub files: Vec<PathBuf>,
    /// The run's hash ([`run_sha256`] over the logs that could be read).
    pub run_sha256: String,
    /// The pipeline (its counters, the monitor and its standing alerts).
    pub pipe: Offline,
}

/// Frames between two progress calls.
pub const PROGRESS_FRAMES: u64 = 1 << 18;

impl Exporter {
    pub fn new(lake: PathBuf, inputs: Inputs, pipe: Offline) -> anyhow::Result<Exporter> {
        check_vehicle_id(&inputs.vehicle)?;
        Ok(Exporter {
            lake,
            inputs,
            pipe,
            hashes: Vec::new(),
            rows: Vec::new(),
            last: None,
            signals: true,
        })
    }

    /// Writes only the monitor's tables (events, estimates, alerts), no signal files: the same
    /// rows under the same names as a full export's.
    pub fn without_signals(mut self) -> Exporter {
        self.signals = false;
        self
    }

    /// The pipeline (its counters, the monitor and its standing alerts).
    pub fn pipeline(&self) -> &Offline {
        &self.pipe
    }

    /// Exports log number `index` of the run (positions must increase from call to call);
    /// `progress` is called with the frames read so far every [`PROGRESS_FRAMES`].
    ///
    /// Errors: the log cannot be opened or read, it holds no CAN frame, none of its frames
    /// belongs to the profile's mapped messages (another car), or a file cannot be written. A
    /// failed log leaves no signal file; frames it delivered before a read error did reach
    /// the monitor (as a bus that stopped would), and the events they finished are written
    /// with the next log's or the run's end.
    pub fn export_log(
        &mut self,
        index: usize,
        path: &Path,
        progress: &mut dyn FnMut(u64),
    ) -> anyhow::Result<LogDone> {
        if self.hashes.len() > index {
            bail!("log position {index} exported twice (positions must increase)");
        }
        self.hashes.resize(index + 1, None);
        let (mut src, hashed) = open_hashed(path)?;
        // Temporary names until the log's hash is known: derived from the log's path, so a
        // rerun of a crashed export overwrites what it left.
        let tmp_key = sha256_bytes(path.as_os_str().as_encoded_bytes());
        let mut sig = SignalFiles::new(
            &self.pipe.db,
            self.lake.join(&self.inputs.vehicle),
            tmp_key[..16].to_string(),
        );
        let mut rows = MonitorRows::default();
        let mapped_before = self.pipe.feeder.stats.mapped_frames;
        let mut frame = Frame::empty(0);
        let mut frames = 0u64;
        let read = (|| -> anyhow::Result<()> {
            while src.read_frame(&mut frame).context("reading log")? {
                frames += 1;
                if self.signals {
                    sig.push(&frame)?;
                }
                if let Some((s, _)) = self.pipe.feeder.sample(&frame) {
                    if let Some(f) = self.pipe.monitor.push(&s) {
                        rows.finished.push(f);
                    }
                }
                if frames.is_multiple_of(PROGRESS_FRAMES) {
                    progress(frames);
                }
            }
            Ok(())
        })();
        self.pipe.feeder.stats.log.add(&src.stats());
        let skips = src.take_skips();
        drop(src);
        let events = rows.finished.len();
        if self.pipe.feeder.stats.mapped_frames > mapped_before {
            self.last = Some(index);
        }
        // Rows the monitor made stay with the run, whatever happens to this log's files.
        if !rows.is_empty() {
            self.rows.push((index, rows));
        }
        // The hash of a log that could not be read to its end is left out of the run's.
        let hash = hashed();
        if let Ok(h) = &hash {
            self.hashes[index] = Some(h.clone());
        }
        read.with_context(|| format!("log {}", path.display()))?;
        let hash = hash?;
        if frames == 0 {
            bail!(
                "log {}: no CAN frames (empty, or not a CAN log{})",
                path.display(),
                skips
                    .first()
                    .map(|s| format!("; first problem: {}: {}", s.location, s.reason))
                    .unwrap_or_default()
            );
        }
        if self.pipe.feeder.stats.mapped_frames == mapped_before {
            bail!(
                "log {}: none of its {frames} frames carries a message the profile maps (another \
                 car, or another bus of this car?); see `shimmy identify`",
                path.display()
            );
        }
        let mut files = Vec::new();
        let counts = if self.signals {
            let done = sig.finish()?;
            let counts = done.counts.clone();
            let tag = format!("{}-{}", &hash[..16], &self.inputs.dbc_sha256[..8]);
            files.extend(done.commit(&tag)?);
            counts
        } else {
            SignalCounts::default()
        };
        progress(frames);
        Ok(LogDone {
            blake3: hash,
            frames,
            signals: counts,
            events,
            files,
            skips,
        })
    }

    /// Writes the monitor rows, each under its log's position; returns the files.
    fn write_rows(&mut self, run: &str) -> anyhow::Result<Vec<PathBuf>> {
        let schemas = [
            tables::events_schema(),
            tables::estimates_schema(),
            tables::alerts_schema(),
        ];
        let mut closed = Vec::new();
        for (index, rows) in std::mem::take(&mut self.rows) {
            let stamp = Stamp {
                // A log that failed part-way keeps the rows its frames made; its hash is then
                // unknown.
                log_blake3: self.hashes[index].clone().unwrap_or_default(),
                run_sha256: run.to_string(),
                model_version: model_version(),
                table_sha256: self.inputs.table_sha256.clone(),
                dbc_sha256: self.inputs.dbc_sha256.clone(),
                torque_table_sha256: self.inputs.torque_table_sha256.clone(),
                correction_sha256: self.inputs.correction_sha256.clone(),
            };
            closed.extend(self.write_log_rows(index, &stamp, &rows, &schemas)?);
        }
        closed.into_iter().map(write::Closed::commit).collect()
    }

    fn write_log_rows(
        &self,
        index: usize,
        stamp: &Stamp,
        rows: &MonitorRows,
        schemas: &[arrow_schema::SchemaRef; 3],
    ) -> anyhow::Result<Vec<write::Closed>> {
        let mut closed = Vec::new();
        for (day, batches) in rows.batches(stamp)? {
            let (y, m, d) = civil_date(day);
            for ((name, schema), batch) in TABLES.iter().zip(schemas).zip(batches) {
                let Some(batch) = batch else { continue };
                let dest = self
                    .lake
                    .join(name)
                    .join(format!("vehicle={}", self.inputs.vehicle))
                    .join(format!("date={y:04}-{m:02}-{d:02}"))
                    .join(format!("{}-{index:04}.parquet", &stamp.run_sha256[..16]));
                closed.push(write::write_file(dest, schema.clone(), &[batch])?);
            }
        }
        Ok(closed)
    }

    /// End of the run: closes a braking event still open (filed with the last log that
    /// reached the monitor), computes the run's hash and writes the monitor's rows.
    pub fn finish(mut self) -> anyhow::Result<RunDone> {
        if let Some(f) = self.pipe.monitor.finish() {
            match (self.rows.last_mut(), self.last) {
                (Some((i, rows)), Some(last)) if *i == last => rows.finished.push(f),
                (_, Some(last)) => self.rows.push((last, MonitorRows { finished: vec![f] })),
                // No log reached the monitor: it has no event to close.
                (_, None) => {}
            }
        }
        let hashes: Vec<String> = self.hashes.iter().flatten().cloned().collect();
        let run = run_sha256(&self.inputs, &hashes);
        let files = self.write_rows(&run)?;
        Ok(RunDone {
            files,
            run_sha256: run,
            pipe: self.pipe,
        })
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn inputs() -> Inputs {
        Inputs {
            vehicle: "rav4-1".into(),
            dbc_sha256: "d".repeat(64),
            table_sha256: Some("t".repeat(64)),
            torque_table_sha256: Some("q".repeat(64)),
            correction_sha256: None,
            variants_sha256: None,
            mapping_sha256: "m".repeat(64),
            settings_sha256: "s".repeat(64),
        }
    }

    /// The run's hash as it was before corrections existed (docs/FLEET.md's formula).
    fn before_corrections(i: &Inputs, logs: &[String]) -> String {
        let mut h = Sha256::new();
        let v = model_version();
        let mut parts = vec![
            "shimmy-lake-run-2".to_string(),
            v,
            i.vehicle.clone(),
            i.dbc_sha256.clone(),
            i.table_sha256.clone().unwrap_or("-".into()),
            i.mapping_sha256.clone(),
            i.settings_sha256.clone(),
        ];
        if let Some(t) = &i.torque_table_sha256 {
            parts.push(format!("torque:{t}"));
        }
        parts.extend(logs.iter().cloned());
        for p in parts {
            h.update(p.as_bytes());
            h.update([0]);
        }
        hex(&h.finalize())
    }

    #[test]
    fn a_run_without_a_correction_keeps_its_hash_and_a_correction_changes_it() {
        let logs = vec!["a".repeat(64), "b".repeat(64)];
        let mut i = inputs();
        let plain = run_sha256(&i, &logs);
        assert_eq!(plain, before_corrections(&i, &logs));
        i.torque_table_sha256 = None;
        assert_eq!(run_sha256(&i, &logs), before_corrections(&i, &logs));
        i.torque_table_sha256 = inputs().torque_table_sha256;
        i.correction_sha256 = Some("c".repeat(64));
        let corrected = run_sha256(&i, &logs);
        assert_ne!(corrected, plain);
        i.correction_sha256 = Some("e".repeat(64));
        let other = run_sha256(&i, &logs);
        assert_ne!(other, corrected);
        assert_ne!(other, plain);
        // Chassis variants are a run of their own too.
        i.variants_sha256 = Some("v".repeat(64));
        let variants = run_sha256(&i, &logs);
        assert_ne!(variants, other);
    }
}
