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
//! Names: `log16` is the first 16 hex digits of the log's sha256, `dbc8` of the DBC's (the
//! signal files depend on nothing else); `run16` of the run's hash ([`run_sha256`]: every log's
//! sha256 in order, the DBC, mapping, table and settings), `nnnn` the log's position in the run
//! (the monitor's rows depend on every log before them), `seq` the message's files of that log.
//! Dates are the UTC dates of the frames' timestamps (signals) or of the event's end (tables).
//!
//! One log at a time ([`Exporter::export_log`]): its frames go through the DBC decoder into the
//! signal files and, frame by frame, through the same pipeline as `shimmy estimate`
//! ([`crate::pipeline::feeder::Offline`]: mapper → detector samples → [`crate::pipeline::Monitor`]
//! → alert book) into the monitor's rows. A log's files appear (renamed from hidden temporary
//! names) only when the whole log has been read; a log that fails leaves none of its signal
//! files.
//!
//! What it is not: the pipeline (reused, not copied), a Parquet reader, or a catalogue (no
//! manifest: the file names are the catalogue).

pub mod signals;
pub mod tables;
pub mod write;

use std::io::Read;
use std::path::{Path, PathBuf};

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
    let mut buf = vec![0u8; 1 << 20];
    loop {
        let n = f
            .read(&mut buf)
            .with_context(|| format!("reading {}", path.display()))?;
        if n == 0 {
            break;
        }
        h.update(&buf[..n]);
    }
    Ok(hex(&h.finalize()))
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
    /// sha256 of the mapping file and of the monitor's settings as used (their JSON).
    pub mapping_sha256: String,
    pub settings_sha256: String,
}

/// The run's hash: the model version, every input's hash and every log's sha256, in order.
pub fn run_sha256(inputs: &Inputs, log_sha256: &[String]) -> String {
    let mut h = Sha256::new();
    for part in [
        "shimmy-lake-run-1",
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
    for s in log_sha256 {
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
    pub sha256: String,
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
    run_sha256: String,
    pipe: Offline,
    /// The monitor's rows of the last log, written when the next log starts or at
    /// [`Exporter::finish`] (the end of the run may still close an event).
    pending: Option<(usize, Stamp, MonitorRows)>,
    /// The position and stamp of the last log that reached the monitor.
    last: Option<(usize, Stamp)>,
    /// Whether the decoded signal files are written ([`Exporter::without_signals`]).
    signals: bool,
}

/// Frames between two progress calls.
pub const PROGRESS_FRAMES: u64 = 1 << 18;

impl Exporter {
    /// `run_sha256`: [`run_sha256`] of `inputs` and the run's logs (all of them, hashed before
    /// the first is exported).
    pub fn new(
        lake: PathBuf,
        inputs: Inputs,
        run_sha256: String,
        pipe: Offline,
    ) -> anyhow::Result<Exporter> {
        check_vehicle_id(&inputs.vehicle)?;
        Ok(Exporter {
            lake,
            inputs,
            run_sha256,
            pipe,
            pending: None,
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

    /// Exports log number `index` of the run, whose sha256 is `sha256`; `progress` is called
    /// with the frames read so far every [`PROGRESS_FRAMES`].
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
        sha256: &str,
        progress: &mut dyn FnMut(u64),
    ) -> anyhow::Result<LogDone> {
        let mut files = self.write_pending()?;
        let mut src =
            LogReader::open(path).with_context(|| format!("cannot open log {}", path.display()))?;
        let tag = format!("{}-{}", &sha256[..16], &self.inputs.dbc_sha256[..8]);
        let mut sig = SignalFiles::new(&self.pipe.db, self.lake.join(&self.inputs.vehicle), tag);
        let stamp = Stamp {
            log_sha256: sha256.to_string(),
            run_sha256: self.run_sha256.clone(),
            model_version: model_version(),
            table_sha256: self.inputs.table_sha256.clone(),
            dbc_sha256: self.inputs.dbc_sha256.clone(),
        };
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
        self.pipe.feeder.stats.add_source(&src.stats());
        let skips = src.take_skips();
        let events = rows.finished.len();
        if self.pipe.feeder.stats.mapped_frames > mapped_before {
            self.last = Some((index, stamp.clone()));
        }
        // Rows the monitor made stay with the run, whatever happens to this log's files.
        if !rows.is_empty() {
            self.pending = Some((index, stamp, rows));
        }
        read.with_context(|| format!("log {}", path.display()))?;
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
        let counts = if self.signals {
            let done = sig.finish()?;
            let counts = done.counts.clone();
            files.extend(done.commit()?);
            counts
        } else {
            SignalCounts::default()
        };
        progress(frames);
        Ok(LogDone {
            sha256: sha256.to_string(),
            frames,
            signals: counts,
            events,
            files,
            skips,
        })
    }

    /// Writes the monitor rows held back, under their log's position; returns the files.
    fn write_pending(&mut self) -> anyhow::Result<Vec<PathBuf>> {
        let Some((index, stamp, rows)) = self.pending.take() else {
            return Ok(Vec::new());
        };
        let schemas = [
            tables::events_schema(),
            tables::estimates_schema(),
            tables::alerts_schema(),
        ];
        let mut closed = Vec::new();
        for (day, batches) in rows.batches(&stamp)? {
            let (y, m, d) = civil_date(day);
            for ((name, schema), batch) in TABLES.iter().zip(&schemas).zip(batches) {
                let Some(batch) = batch else { continue };
                let dest = self
                    .lake
                    .join(name)
                    .join(format!("vehicle={}", self.inputs.vehicle))
                    .join(format!("date={y:04}-{m:02}-{d:02}"))
                    .join(format!("{}-{index:04}.parquet", &self.run_sha256[..16]));
                closed.push(write::write_file(dest, schema.clone(), &[batch])?);
            }
        }
        closed.into_iter().map(write::Closed::commit).collect()
    }

    /// End of the run: closes a braking event still open and writes the last monitor rows;
    /// returns the files written now and the pipeline.
    pub fn finish(mut self) -> anyhow::Result<(Vec<PathBuf>, Offline)> {
        if let Some(f) = self.pipe.monitor.finish() {
            match (&mut self.pending, &self.last) {
                (Some((_, _, rows)), _) => rows.finished.push(f),
                (None, Some((index, stamp))) => {
                    let rows = MonitorRows { finished: vec![f] };
                    self.pending = Some((*index, stamp.clone(), rows));
                }
                // No log reached the monitor: it has no event to close.
                (None, None) => {}
            }
        }
        let files = self.write_pending()?;
        Ok((files, self.pipe))
    }
}
