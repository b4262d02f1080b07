//! The monitor's own tables as Arrow record batches: `events` (one row per finished braking
//! event), `estimates` (the clearance estimate after each event) and `alerts` (every alert
//! transition: raised, updated, cleared), each row stamped with where it came from
//! ([`Stamp`]: the log, the run, the model version, the response table's, the DBC's, the torque
//! table's and the correction's hashes). Rows are grouped by the UTC date of the event's end,
//! the tables' Hive partition.
//!
//! What it is not: the pipeline that makes the rows ([`crate::pipeline::Monitor`] does, the same
//! one `shimmy estimate` runs), file naming ([`super`]) or Parquet writing ([`super::write`]).

use std::collections::BTreeMap;
use std::sync::Arc;

use arrow_array::builder::{
    BooleanBuilder, Float64Builder, StringBuilder, TimestampMicrosecondBuilder, UInt32Builder,
    UInt64Builder,
};
use arrow_array::{ArrayRef, RecordBatch};
use arrow_schema::{DataType, Field, Schema, SchemaRef};

use super::signals::{timestamp_type, DAY_NS};
use crate::pipeline::Finished;

/// Where a row came from; the same for every row of one log's files.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct Stamp {
    /// BLAKE3 of the log file (hex, as `b3sum` prints it).
    pub log_blake3: String,
    /// The run's hash (hex, [`super::run_sha256`]).
    pub run_sha256: String,
    /// The code that computed the row: `shimmy-monitor <version>`.
    pub model_version: String,
    /// sha256 of the response table file (hex); None when the run had no table.
    pub table_sha256: Option<String>,
    /// sha256 of the DBC file (hex).
    pub dbc_sha256: String,
    /// sha256 of the torque table file (hex); None when the run had none.
    pub torque_table_sha256: Option<String>,
    /// sha256 of the profile's correction file (hex); None when the profile names none.
    pub correction_sha256: Option<String>,
}

/// The three tables' names, as their folders under the lake are named.
pub const TABLES: [&str; 3] = ["events", "estimates", "alerts"];

fn stamp_fields() -> Vec<Field> {
    vec![
        Field::new("log_blake3", DataType::Utf8, false),
        Field::new("run_sha256", DataType::Utf8, false),
        Field::new("model_version", DataType::Utf8, false),
        Field::new("table_sha256", DataType::Utf8, true),
        Field::new("dbc_sha256", DataType::Utf8, false),
        Field::new("torque_table_sha256", DataType::Utf8, true),
        Field::new("correction_sha256", DataType::Utf8, true),
    ]
}

fn f64n(name: &str) -> Field {
    Field::new(name, DataType::Float64, true)
}

fn f64v(name: &str) -> Field {
    Field::new(name, DataType::Float64, false)
}

/// Schema of `events`.
pub fn events_schema() -> SchemaRef {
    let mut f = vec![
        Field::new("t", timestamp_type(), false),
        f64v("t_start_s"),
        f64v("t_end_s"),
        f64v("v0_kmh"),
        f64v("decel_g"),
        f64n("peak_sw_bp_deg"),
        f64n("sw_amplitude_deg"),
        Field::new("used", DataType::Boolean, false),
        Field::new("unused_reason", DataType::Utf8, true),
        f64v("odometer_km"),
        f64n("peak_torque_bp_nm"),
        Field::new("torque_used", DataType::Boolean, true),
    ];
    f.extend(stamp_fields());
    Arc::new(Schema::new(f))
}

/// Schema of `estimates`.
pub fn estimates_schema() -> SchemaRef {
    let mut f = vec![
        Field::new("t", timestamp_type(), false),
        f64v("t_event_end_s"),
        f64n("clearance_mm"),
        f64n("interval_lo_mm"),
        f64n("interval_hi_mm"),
        Field::new("detectable", DataType::Boolean, false),
        f64n("below_mm"),
        f64n("p_above"),
        Field::new("events_used", DataType::UInt32, false),
        Field::new("misfit", DataType::Utf8, true),
    ];
    f.extend(stamp_fields());
    Arc::new(Schema::new(f))
}

/// Schema of `alerts`.
pub fn alerts_schema() -> SchemaRef {
    let mut f = vec![
        Field::new("t", timestamp_type(), false),
        f64v("t_event_end_s"),
        Field::new("transition", DataType::Utf8, false),
        Field::new("alert_id", DataType::UInt64, false),
        Field::new("kind", DataType::Utf8, false),
        f64v("t_raised_s"),
        f64v("t_updated_s"),
        f64v("odometer_km_raised"),
        Field::new("updates", DataType::UInt32, false),
        Field::new("summary", DataType::Utf8, false),
        Field::new("guidance", DataType::Utf8, false),
        Field::new("evidence_json", DataType::Utf8, false),
    ];
    f.extend(stamp_fields());
    Arc::new(Schema::new(f))
}

/// Seconds of log time as the lake's microseconds (floor).
fn micros(t_s: f64) -> i64 {
    (t_s * 1e6).floor() as i64
}

/// The day (since 1970-01-01, UTC) of a log time in seconds.
pub fn day_of(t_s: f64) -> i64 {
    micros(t_s).div_euclid(DAY_NS / 1000)
}

/// What the monitor produced during one log, kept until the log's files are written (a few rows
/// per minute of driving).
#[derive(Clone, Debug, Default)]
pub struct MonitorRows {
    pub finished: Vec<Finished>,
}

impl MonitorRows {
    pub fn is_empty(&self) -> bool {
        self.finished.is_empty()
    }

    /// The three tables' batches, per day: `(day, [events, estimates, alerts])`, a table with
    /// no row on that day left out (None).
    pub fn batches(&self, stamp: &Stamp) -> anyhow::Result<Vec<(i64, [Option<RecordBatch>; 3])>> {
        let mut by_day: BTreeMap<i64, Vec<&Finished>> = BTreeMap::new();
        for f in &self.finished {
            by_day.entry(day_of(f.event.t_end)).or_default().push(f);
        }
        by_day
            .into_iter()
            .map(|(day, rows)| {
                Ok((
                    day,
                    [
                        events_batch(&rows, stamp)?,
                        estimates_batch(&rows, stamp)?,
                        alerts_batch(&rows, stamp)?,
                    ],
                ))
            })
            .collect()
    }
}

fn stamp_columns(stamp: &Stamp, n: usize) -> Vec<ArrayRef> {
    let col = |v: Option<&str>| -> ArrayRef {
        let mut b = StringBuilder::with_capacity(n, n * 64);
        for _ in 0..n {
            b.append_option(v);
        }
        Arc::new(b.finish())
    };
    vec![
        col(Some(&stamp.log_blake3)),
        col(Some(&stamp.run_sha256)),
        col(Some(&stamp.model_version)),
        col(stamp.table_sha256.as_deref()),
        col(Some(&stamp.dbc_sha256)),
        col(stamp.torque_table_sha256.as_deref()),
        col(stamp.correction_sha256.as_deref()),
    ]
}

fn ts() -> TimestampMicrosecondBuilder {
    TimestampMicrosecondBuilder::new().with_timezone("UTC")
}

fn finish(
    schema: SchemaRef,
    mut cols: Vec<ArrayRef>,
    stamp: &Stamp,
    n: usize,
) -> anyhow::Result<Option<RecordBatch>> {
    if n == 0 {
        return Ok(None);
    }
    cols.extend(stamp_columns(stamp, n));
    Ok(Some(RecordBatch::try_new(schema, cols)?))
}

fn events_batch(rows: &[&Finished], stamp: &Stamp) -> anyhow::Result<Option<RecordBatch>> {
    let (mut t, mut t0, mut t1, mut v0, mut dec, mut peak, mut amp, mut used, mut why, mut odo) = (
        ts(),
        Float64Builder::new(),
        Float64Builder::new(),
        Float64Builder::new(),
        Float64Builder::new(),
        Float64Builder::new(),
        Float64Builder::new(),
        BooleanBuilder::new(),
        StringBuilder::new(),
        Float64Builder::new(),
    );
    let (mut tq_peak, mut tq_used) = (Float64Builder::new(), BooleanBuilder::new());
    for f in rows {
        let e = &f.event;
        t.append_value(micros(e.t_end));
        t0.append_value(e.t_start);
        t1.append_value(e.t_end);
        v0.append_value(e.v0_kmh);
        dec.append_value(e.decel_g);
        peak.append_option(e.peak_sw_bp_deg);
        amp.append_option(e.sw_amplitude_deg);
        used.append_value(e.used);
        why.append_option(e.unused_reason.as_deref());
        odo.append_value(e.odometer_km);
        tq_peak.append_option(e.peak_torque_bp_nm);
        tq_used.append_option(e.torque_used);
    }
    let cols: Vec<ArrayRef> = vec![
        Arc::new(t.finish()),
        Arc::new(t0.finish()),
        Arc::new(t1.finish()),
        Arc::new(v0.finish()),
        Arc::new(dec.finish()),
        Arc::new(peak.finish()),
        Arc::new(amp.finish()),
        Arc::new(used.finish()),
        Arc::new(why.finish()),
        Arc::new(odo.finish()),
        Arc::new(tq_peak.finish()),
        Arc::new(tq_used.finish()),
    ];
    finish(events_schema(), cols, stamp, rows.len())
}

fn estimates_batch(rows: &[&Finished], stamp: &Stamp) -> anyhow::Result<Option<RecordBatch>> {
    let mut t = ts();
    let mut tend = Float64Builder::new();
    let (mut c, mut lo, mut hi, mut below, mut p) = (
        Float64Builder::new(),
        Float64Builder::new(),
        Float64Builder::new(),
        Float64Builder::new(),
        Float64Builder::new(),
    );
    let mut det = BooleanBuilder::new();
    let mut used = UInt32Builder::new();
    let mut misfit = StringBuilder::new();
    let mut n = 0;
    for f in rows {
        let Some(e) = &f.estimate else { continue };
        n += 1;
        t.append_value(micros(f.event.t_end));
        tend.append_value(f.event.t_end);
        c.append_option(e.clearance_mm);
        lo.append_option(e.interval_mm.map(|i| i[0]));
        hi.append_option(e.interval_mm.map(|i| i[1]));
        det.append_value(e.detectable);
        below.append_option(e.below_mm);
        p.append_option(e.p_above);
        used.append_value(e.events_used);
        misfit.append_option(e.misfit.as_deref());
    }
    let cols: Vec<ArrayRef> = vec![
        Arc::new(t.finish()),
        Arc::new(tend.finish()),
        Arc::new(c.finish()),
        Arc::new(lo.finish()),
        Arc::new(hi.finish()),
        Arc::new(det.finish()),
        Arc::new(below.finish()),
        Arc::new(p.finish()),
        Arc::new(used.finish()),
        Arc::new(misfit.finish()),
    ];
    finish(estimates_schema(), cols, stamp, n)
}

fn alerts_batch(rows: &[&Finished], stamp: &Stamp) -> anyhow::Result<Option<RecordBatch>> {
    let mut t = ts();
    let mut tend = Float64Builder::new();
    let (mut tr, mut kind, mut summary, mut guidance, mut evidence) = (
        StringBuilder::new(),
        StringBuilder::new(),
        StringBuilder::new(),
        StringBuilder::new(),
        StringBuilder::new(),
    );
    let mut id = UInt64Builder::new();
    let (mut traised, mut tupd, mut odo) = (
        Float64Builder::new(),
        Float64Builder::new(),
        Float64Builder::new(),
    );
    let mut updates = UInt32Builder::new();
    let mut n = 0;
    for f in rows {
        for x in &f.transitions {
            let (what, a) = x.parts();
            n += 1;
            t.append_value(micros(f.event.t_end));
            tend.append_value(f.event.t_end);
            tr.append_value(what);
            id.append_value(a.id);
            kind.append_value(a.kind.as_str());
            traised.append_value(a.t_raised);
            tupd.append_value(a.t_updated);
            odo.append_value(a.odometer_km_raised);
            updates.append_value(a.updates);
            summary.append_value(&a.summary);
            guidance.append_value(&a.guidance);
            evidence.append_value(serde_json::to_string(&a.evidence)?);
        }
    }
    let cols: Vec<ArrayRef> = vec![
        Arc::new(t.finish()),
        Arc::new(tend.finish()),
        Arc::new(tr.finish()),
        Arc::new(id.finish()),
        Arc::new(kind.finish()),
        Arc::new(traised.finish()),
        Arc::new(tupd.finish()),
        Arc::new(odo.finish()),
        Arc::new(updates.finish()),
        Arc::new(summary.finish()),
        Arc::new(guidance.finish()),
        Arc::new(evidence.finish()),
    ];
    finish(alerts_schema(), cols, stamp, n)
}
