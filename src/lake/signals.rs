//! Decoded signals as Arrow record batches and Parquet files, one file set per CAN message in the
//! CSS Electronics layout `<device>/<message>/<yyyy>/<mm>/<dd>/<name>.parquet`: a column `t`
//! (Timestamp µs, UTC) and one Float64 column per signal of the message, in DBC order, holding
//! the physical value (raw × factor + offset) exactly as `shimmy decode` prints it; value-table
//! entries (enums) stay numbers; a signal the frame does not carry (another multiplexer branch, a
//! short frame) is null.
//!
//! Streaming with bounded memory: each message buffers at most [`BATCH_ROWS`] rows before they
//! go to its open file; the open files' row groups in progress hold at most
//! [`ROW_GROUPS_BUDGET_BYTES`] together (past it the largest ends early; each ends at
//! [`super::write::ROW_GROUP_ROWS`] rows anyway), and a file takes at most [`FILE_ROWS`] rows of
//! its message (its footer metadata is kept until it closes).
//!
//! What it is not: DBC decoding ([`crate::dbc::Message::decode`] does it, as for `shimmy
//! decode`), the monitor's tables ([`super::tables`]) or the naming rule ([`super`]).

use std::path::PathBuf;
use std::sync::Arc;

use arrow_array::{ArrayRef, Float64Array, RecordBatch, TimestampMicrosecondArray};
use arrow_schema::ArrowError;
use arrow_schema::{DataType, Field, Schema, SchemaRef, TimeUnit};

use super::write::{signal_properties, Closed, PartFile};
use crate::dbc::{Database, DecodeError, Message};
use crate::wire::{Frame, FrameKind};

/// Rows a message buffers before they are handed to its file (one record batch).
pub const BATCH_ROWS: usize = 8_192;

/// Most memory (bytes) the open files' row groups in progress may hold together: past it the
/// largest ends early (a smaller row group). Without it each open file holds up to
/// [`super::write::ROW_GROUP_ROWS`] rows of encoded pages, and a slow message takes hours of
/// log to fill one, so the memory kept climbing with the log's length towards a bound set by
/// the number of messages times the row group.
pub const ROW_GROUPS_BUDGET_BYTES: usize = 8 << 20;

/// Most rows of one message in one file: past it the message's next file starts (the next
/// sequence number, same day). It bounds the footer metadata a file keeps in memory until it
/// closes (one entry per row group and column), which otherwise grew with the log's length.
pub const FILE_ROWS: usize = 1 << 20;

/// Nanoseconds per day.
pub const DAY_NS: i64 = 86_400 * 1_000_000_000;

/// The Arrow type of every timestamp column of the lake.
pub fn timestamp_type() -> DataType {
    DataType::Timestamp(TimeUnit::Microsecond, Some("UTC".into()))
}

/// The schema of a message's signal files: `t`, then its signals.
pub fn message_schema(msg: &Message) -> SchemaRef {
    let mut fields = vec![Field::new("t", timestamp_type(), false)];
    fields.extend(
        msg.signals
            .iter()
            .map(|s| Field::new(s.name.as_str(), DataType::Float64, true)),
    );
    Arc::new(Schema::new(fields))
}

/// The `yyyy/mm/dd` (civil UTC date) of a day number (days since 1970-01-01).
pub fn civil_date(day: i64) -> (i64, u32, u32) {
    // Howard Hinnant's days_from_civil inverse.
    let z = day + 719_468;
    let era = z.div_euclid(146_097);
    let doe = z - era * 146_097;
    let yoe = (doe - doe / 1460 + doe / 36_524 - doe / 146_096) / 365;
    let y = yoe + era * 400;
    let doy = doe - (365 * yoe + yoe / 4 - yoe / 100);
    let mp = (5 * doy + 2) / 153;
    let d = (doy - (153 * mp + 2) / 5 + 1) as u32;
    let m = if mp < 10 { mp + 3 } else { mp - 9 } as u32;
    (if m <= 2 { y + 1 } else { y }, m, d)
}

/// Counters of the signal files of one log.
#[derive(Clone, Debug, Default, PartialEq, Eq, serde::Serialize)]
pub struct SignalCounts {
    /// Frames decoded into a row.
    pub rows: u64,
    /// Data frames whose ID the DBC does not define.
    pub unknown_id: u64,
    /// Frames refused because a multiplexer value selects nothing.
    pub refused_mux: u64,
    /// Remote and error frames.
    pub non_data: u64,
}

/// One signal's values in progress: plain vectors, moved into Arrow arrays without a copy when
/// the batch is handed over (Arrow's builders start from no capacity after each `finish`, so
/// every batch would regrow them value by value).
struct Column {
    vals: Vec<f64>,
    valid: Vec<bool>,
    nulls: usize,
}

impl Column {
    fn new() -> Column {
        Column {
            vals: Vec::with_capacity(BATCH_ROWS),
            valid: Vec::with_capacity(BATCH_ROWS),
            nulls: 0,
        }
    }

    fn take(&mut self) -> Float64Array {
        let vals = std::mem::replace(&mut self.vals, Vec::with_capacity(BATCH_ROWS));
        let nulls = (self.nulls > 0).then(|| self.valid.as_slice().into());
        self.valid.clear();
        self.nulls = 0;
        Float64Array::new(vals.into(), nulls)
    }
}

/// One message's rows in progress and its open file.
struct MsgTable {
    schema: SchemaRef,
    /// Timestamps (µs since the epoch, UTC).
    t: Vec<i64>,
    cols: Vec<Column>,
    /// Day (since the epoch) of the open file, and the file.
    open: Option<(i64, PartFile)>,
    /// Files opened so far for this message (the file name's sequence number).
    seq: u32,
    /// Rows given to the open file so far (buffered ones included).
    file_rows: usize,
}

impl MsgTable {
    fn new(msg: &Message) -> MsgTable {
        MsgTable {
            schema: message_schema(msg),
            t: Vec::with_capacity(BATCH_ROWS),
            cols: msg.signals.iter().map(|_| Column::new()).collect(),
            open: None,
            seq: 0,
            file_rows: 0,
        }
    }

    fn batch(&mut self) -> anyhow::Result<RecordBatch> {
        let t = std::mem::replace(&mut self.t, Vec::with_capacity(BATCH_ROWS));
        let mut cols: Vec<ArrayRef> = Vec::with_capacity(1 + self.cols.len());
        cols.push(Arc::new(
            TimestampMicrosecondArray::new(t.into(), None).with_timezone("UTC"),
        ));
        for c in &mut self.cols {
            cols.push(Arc::new(c.take()));
        }
        RecordBatch::try_new(Arc::clone(&self.schema), cols)
            .map_err(|e: ArrowError| anyhow::anyhow!("signal batch: {e}"))
    }

    /// Hands the buffered rows to the open file.
    fn flush(&mut self) -> anyhow::Result<()> {
        if self.t.is_empty() {
            return Ok(());
        }
        let b = self.batch()?;
        let (_, f) = self.open.as_mut().expect("rows only while a file is open");
        f.write(&b)
    }
}

/// The decoded-signal files of one log, under `<lake>/<device>/`, named
/// `<tag>-<seq>.parquet` (`tag`: derived from the log's and the DBC's content, see [`super`],
/// given at [`Finished::commit`] once the whole log has been read; `seq`: the message's files of
/// this log, from 0, a new one whenever the date changes or the file holds [`FILE_ROWS`] rows).
/// Until then they are written under hidden temporary names made from `tmp_key`.
pub struct SignalFiles<'db> {
    db: &'db Database,
    root: PathBuf,
    tmp_key: String,
    msgs: Vec<Option<MsgTable>>,
    /// Per signal of the message being decoded: its value, and whether the frame carried it.
    vals: Vec<f64>,
    seen: Vec<bool>,
    closed: Vec<Closed>,
    limits: Limits,
    pub counts: SignalCounts,
}

/// The memory bounds of [`SignalFiles`]: [`FILE_ROWS`] and [`ROW_GROUPS_BUDGET_BYTES`] unless
/// set otherwise ([`SignalFiles::with_limits`]).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Limits {
    pub file_rows: usize,
    pub row_groups_bytes: usize,
}

impl Default for Limits {
    fn default() -> Limits {
        Limits {
            file_rows: FILE_ROWS,
            row_groups_bytes: ROW_GROUPS_BUDGET_BYTES,
        }
    }
}

impl<'db> SignalFiles<'db> {
    pub fn new(db: &'db Database, device_root: PathBuf, tmp_key: String) -> SignalFiles<'db> {
        let most = db
            .messages()
            .iter()
            .map(|m| m.signals.len())
            .max()
            .unwrap_or(0);
        SignalFiles {
            db,
            root: device_root,
            tmp_key,
            msgs: db.messages().iter().map(|_| None).collect(),
            vals: vec![0.0; most],
            seen: vec![false; most],
            closed: Vec::new(),
            limits: Limits::default(),
            counts: SignalCounts::default(),
        }
    }

    /// The same, with other memory bounds (a file's rows, the row groups' bytes); the lake's
    /// layout depends on them, so the exporter keeps the defaults.
    pub fn with_limits(mut self, limits: Limits) -> SignalFiles<'db> {
        self.limits = limits;
        self
    }

    /// Decodes one frame into its message's rows (a frame of no DBC message, or one refused,
    /// is counted and left out, as `shimmy decode` leaves it out).
    pub fn push(&mut self, frame: &Frame) -> anyhow::Result<()> {
        if frame.kind != FrameKind::Data {
            self.counts.non_data += 1;
            return Ok(());
        }
        let Some(mi) = self.db.message_index(frame.id, frame.extended) else {
            self.counts.unknown_id += 1;
            return Ok(());
        };
        let msg = &self.db.messages()[mi];
        let data = frame.payload();
        if let Err(DecodeError::UnknownMultiplexerValue { .. }) = msg.check_multiplexers(data) {
            self.counts.refused_mux += 1;
            return Ok(());
        }
        let n = msg.signals.len();
        let (vals, seen) = (&mut self.vals[..n], &mut self.seen[..n]);
        seen.fill(false);
        if msg
            .decode(data, |i, _raw, phys| {
                vals[i] = phys;
                seen[i] = true;
            })
            .is_err()
        {
            self.counts.refused_mux += 1;
            return Ok(());
        }
        let day = frame.t_ns.div_euclid(DAY_NS);
        let table = self.msgs[mi].get_or_insert_with(|| MsgTable::new(msg));
        if table.open.as_ref().map(|(d, _)| *d) != Some(day)
            || table.file_rows >= self.limits.file_rows
        {
            table.flush()?;
            if let Some((_, f)) = table.open.take() {
                self.closed.push(f.close()?);
            }
            let (y, m, d) = civil_date(day);
            let dest = self
                .root
                .join(&msg.name)
                .join(format!("{y:04}"))
                .join(format!("{m:02}"))
                .join(format!("{d:02}"))
                .join(format!("{}-{:03}.parquet", self.tmp_key, table.seq));
            table.seq += 1;
            table.file_rows = 0;
            table.open = Some((
                day,
                PartFile::create_with(dest, Arc::clone(&table.schema), signal_properties())?,
            ));
        }
        table.t.push(frame.t_ns.div_euclid(1000));
        table.file_rows += 1;
        for (c, (&v, &s)) in table.cols.iter_mut().zip(vals.iter().zip(seen.iter())) {
            // A null's slot holds 0 (Arrow leaves it unspecified; a fixed value keeps reruns'
            // bytes equal).
            c.vals.push(if s { v } else { 0.0 });
            c.valid.push(s);
            c.nulls += usize::from(!s);
        }
        self.counts.rows += 1;
        if table.t.len() >= BATCH_ROWS {
            table.flush()?;
            self.keep_budget()?;
        }
        Ok(())
    }

    /// Ends the largest row groups in progress until together they hold at most
    /// [`ROW_GROUPS_BUDGET_BYTES`]. Depends on the log's content only, so a rerun cuts the
    /// same row groups.
    fn keep_budget(&mut self) -> anyhow::Result<()> {
        let budget = self.limits.row_groups_bytes;
        loop {
            let mut total = 0;
            let mut largest: Option<(usize, usize)> = None;
            for (i, t) in self.msgs.iter().enumerate() {
                if let Some((_, f)) = t.as_ref().and_then(|t| t.open.as_ref()) {
                    let b = f.in_progress_bytes();
                    total += b;
                    if largest.is_none_or(|(_, lb)| b > lb) {
                        largest = Some((i, b));
                    }
                }
            }
            let Some((i, b)) = largest else {
                return Ok(());
            };
            if total <= budget || b == 0 {
                return Ok(());
            }
            if let Some((_, f)) = self.msgs[i].as_mut().and_then(|t| t.open.as_mut()) {
                f.end_row_group()?;
            }
        }
    }

    /// Finishes every file (still under temporary names; [`Finished::commit`] makes them
    /// visible). Dropping `self` instead removes them.
    pub fn finish(mut self) -> anyhow::Result<Finished> {
        for t in self.msgs.iter_mut().flatten() {
            t.flush()?;
            if let Some((_, f)) = t.open.take() {
                self.closed.push(f.close()?);
            }
        }
        Ok(Finished {
            files: std::mem::take(&mut self.closed),
            tmp_key: std::mem::take(&mut self.tmp_key),
            counts: self.counts.clone(),
        })
    }
}

/// A log's signal files, written and synced, not yet visible.
pub struct Finished {
    files: Vec<Closed>,
    tmp_key: String,
    pub counts: SignalCounts,
}

impl Finished {
    /// Renames every file to its final name `<tag>-<seq>.parquet`; returns the names.
    pub fn commit(self, tag: &str) -> anyhow::Result<Vec<PathBuf>> {
        let key = self.tmp_key;
        self.files
            .into_iter()
            .map(|f| {
                let dest = f.dest();
                let name = dest
                    .file_name()
                    .map(|n| n.to_string_lossy().into_owned())
                    .unwrap_or_default();
                let seq = name.strip_prefix(key.as_str()).unwrap_or(&name);
                let dest = dest.with_file_name(format!("{tag}{seq}"));
                f.commit_to(dest)
            })
            .collect()
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use parquet::file::reader::{FileReader, SerializedFileReader};

    /// Two messages, 20,000 frames each, interleaved, through `SignalFiles` with `limits`;
    /// returns each committed file's row-group row counts, by message name.
    fn export(limits: Limits) -> Vec<(String, Vec<i64>)> {
        let (db, _) = Database::parse(
            "BO_ 256 A: 8 X\n SG_ X : 0|16@1+ (1,0) [0|65535] \"\" Y\n\
             BO_ 257 B: 8 X\n SG_ Y : 0|16@1+ (1,0) [0|65535] \"\" Y\n\
             \x20SG_ Z : 16|16@1+ (1,0) [0|65535] \"\" Y\n",
        );
        let dir = tempfile::tempdir().unwrap();
        let mut sig = SignalFiles::new(&db, dir.path().join("dev"), "k".into()).with_limits(limits);
        for k in 0..40_000u32 {
            let mut data = [0u8; 8];
            data[..4].copy_from_slice(&k.to_le_bytes());
            let f = Frame::classic(i64::from(k) * 1_000_000, 256 + (k % 2), false, &data).unwrap();
            sig.push(&f).unwrap();
        }
        let files = sig.finish().unwrap().commit("tag").unwrap();
        let mut out = Vec::new();
        for p in files {
            let r = SerializedFileReader::new(std::fs::File::open(&p).unwrap()).unwrap();
            let rows = r
                .metadata()
                .row_groups()
                .iter()
                .map(|g| g.num_rows())
                .collect();
            let msg = p.components().rev().nth(4).unwrap();
            out.push((msg.as_os_str().to_string_lossy().into_owned(), rows));
        }
        out.sort();
        out
    }

    #[test]
    fn a_message_past_its_file_rows_continues_in_its_next_file() {
        let files = export(Limits {
            file_rows: 7_000,
            ..Limits::default()
        });
        // 20,000 rows per message: files of 7,000, 7,000 and 6,000 rows.
        for msg in ["A", "B"] {
            let mut rows: Vec<i64> = files
                .iter()
                .filter(|(m, _)| m == msg)
                .map(|(_, g)| g.iter().sum())
                .collect();
            rows.sort();
            assert_eq!(rows, [6_000, 7_000, 7_000], "{msg}: {files:?}");
        }
    }

    #[test]
    fn the_row_group_budget_ends_row_groups_early_and_loses_no_row() {
        let whole = export(Limits::default());
        assert!(whole.iter().all(|(_, g)| g.len() == 1), "{whole:?}");
        // No budget: every batch handed to a file ends its row group at once.
        let cut = export(Limits {
            row_groups_bytes: 0,
            ..Limits::default()
        });
        for (msg, groups) in &cut {
            assert!(groups.len() >= 3, "{msg}: {groups:?}");
            assert!(
                groups.iter().all(|&n| n as usize <= BATCH_ROWS),
                "{msg}: {groups:?}"
            );
            assert_eq!(groups.iter().sum::<i64>(), 20_000, "{msg}");
        }
    }

    #[test]
    fn civil_dates_of_day_numbers() {
        assert_eq!(civil_date(0), (1970, 1, 1));
        assert_eq!(civil_date(-1), (1969, 12, 31));
        assert_eq!(civil_date(11_016), (2000, 2, 29));
        assert_eq!(civil_date(20_425), (2025, 12, 3));
    }
}
