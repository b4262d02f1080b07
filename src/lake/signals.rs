//! Decoded signals as Arrow record batches and Parquet files, one file set per CAN message in the
//! CSS Electronics layout `<device>/<message>/<yyyy>/<mm>/<dd>/<name>.parquet`: a column `t`
//! (Timestamp µs, UTC) and one Float64 column per signal of the message, in DBC order, holding
//! the physical value (raw × factor + offset) exactly as `shimmy decode` prints it; value-table
//! entries (enums) stay numbers; a signal the frame does not carry (another multiplexer branch, a
//! short frame) is null.
//!
//! Streaming with bounded memory: each message buffers at most [`BATCH_ROWS`] rows before they
//! go to its open file, whose row group is bounded by [`super::write::ROW_GROUP_ROWS`]; memory
//! grows with the number of messages, not with the log's length.
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
}

impl MsgTable {
    fn new(msg: &Message) -> MsgTable {
        MsgTable {
            schema: message_schema(msg),
            t: Vec::with_capacity(BATCH_ROWS),
            cols: msg.signals.iter().map(|_| Column::new()).collect(),
            open: None,
            seq: 0,
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
/// this log, from 0, a new one whenever the date changes). Until then they are written under
/// hidden temporary names made from `tmp_key`.
pub struct SignalFiles<'db> {
    db: &'db Database,
    root: PathBuf,
    tmp_key: String,
    msgs: Vec<Option<MsgTable>>,
    /// Per signal of the message being decoded: its value, and whether the frame carried it.
    vals: Vec<f64>,
    seen: Vec<bool>,
    closed: Vec<Closed>,
    pub counts: SignalCounts,
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
            counts: SignalCounts::default(),
        }
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
        if table.open.as_ref().map(|(d, _)| *d) != Some(day) {
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
            table.open = Some((
                day,
                PartFile::create_with(dest, Arc::clone(&table.schema), signal_properties())?,
            ));
        }
        table.t.push(frame.t_ns.div_euclid(1000));
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
        }
        Ok(())
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
    use super::civil_date;

    #[test]
    fn civil_dates_of_day_numbers() {
        assert_eq!(civil_date(0), (1970, 1, 1));
        assert_eq!(civil_date(-1), (1969, 12, 31));
        assert_eq!(civil_date(11_016), (2000, 2, 29));
        assert_eq!(civil_date(20_425), (2025, 12, 3));
    }
}
