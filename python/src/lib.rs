//! `shimmy_monitor._native`: the Rust side of the `shimmy_monitor` Python package. Each function
//! calls the same library code as the `shimmy` command it mirrors and hands Python either JSON
//! (the same serde structs the CLI prints) or Arrow record batches through the Arrow C stream
//! interface (`arrow_array::ffi_stream`, imported by pyarrow without a copy).
//!
//! What it is not: the Python API itself (python/shimmy_monitor/__init__.py wraps these and
//! documents them), or another implementation of decoding, estimation or export. Errors become
//! `shimmy_monitor.ShimmyError` with the Rust error chain as the message; a panic is caught here
//! and raised as `ShimmyError` too, never unwound into Python.

use std::collections::VecDeque;
use std::panic::{catch_unwind, AssertUnwindSafe};
use std::path::PathBuf;
use std::sync::Arc;

use anyhow::Context as _;
use arrow_array::builder::{BooleanBuilder, Float64Builder, StringBuilder, UInt32Builder};
use arrow_array::ffi_stream::FFI_ArrowArrayStream;
use arrow_array::types::TimestampNanosecondType;
use arrow_array::{ArrayRef, PrimitiveArray, RecordBatch, RecordBatchReader};
use arrow_schema::{ArrowError, DataType, Field, Schema, SchemaRef, TimeUnit};
use pyo3::create_exception;
use pyo3::exceptions::PyException;
use pyo3::prelude::*;

use shimmy::cli::fleet_fit::{self, FitSetup, SignalArg, VehicleEvents};
use shimmy::cli::{estimate, export, TextOrJson};
use shimmy::dbc::{Database, DecodeError};
use shimmy::source::log::LogReader;
use shimmy::source::CanSource;
use shimmy::wire::{Frame, FrameKind};

create_exception!(
    _native,
    ShimmyError,
    PyException,
    "An error of shimmy-monitor: bad input (a missing or unreadable log, an unknown profile, a \
     DBC that does not load, ...). The message is the whole error chain."
);

/// Runs `f` (without the GIL), turning its error or a panic into a `ShimmyError`.
fn guarded<T: Send>(py: Python<'_>, f: impl FnOnce() -> anyhow::Result<T> + Send) -> PyResult<T> {
    let r = py.detach(|| catch_unwind(AssertUnwindSafe(f)));
    match r {
        Ok(Ok(v)) => Ok(v),
        Ok(Err(e)) => Err(ShimmyError::new_err(format!("{e:#}"))),
        Err(p) => {
            let what = p
                .downcast_ref::<String>()
                .cloned()
                .or_else(|| p.downcast_ref::<&str>().map(|s| s.to_string()))
                .unwrap_or_else(|| "unknown panic".into());
            Err(ShimmyError::new_err(format!(
                "internal error in shimmy-monitor (please report): {what}"
            )))
        }
    }
}

/// Rows from which a record batch of `decode` closes, at the next frame boundary (bounded
/// memory: one batch is built at a time).
const BATCH_ROWS: usize = 65_536;

/// The schema of `decode`: one row per decoded signal, as `shimmy decode --format csv` prints.
fn decode_schema() -> SchemaRef {
    Arc::new(Schema::new(vec![
        Field::new(
            "t",
            DataType::Timestamp(TimeUnit::Nanosecond, Some("UTC".into())),
            false,
        ),
        Field::new("id", DataType::UInt32, false),
        Field::new("extended", DataType::Boolean, false),
        Field::new("msg", DataType::Utf8, false),
        Field::new("signal", DataType::Utf8, false),
        Field::new("value", DataType::Float64, false),
    ]))
}

/// The logs' frames decoded with a DBC, streamed as record batches of [`BATCH_ROWS`] rows and
/// the rest of the frame that reached it; the same frames and values as `shimmy decode` (src/cli/decode.rs): data frames whose
/// ID the DBC defines, frames whose multiplexer value selects nothing left out.
struct DecodeStream {
    db: Database,
    logs: VecDeque<PathBuf>,
    cur: Option<(PathBuf, LogReader)>,
    frame: Frame,
    schema: SchemaRef,
    t: Vec<i64>,
    id: UInt32Builder,
    ext: BooleanBuilder,
    msg: StringBuilder,
    sig: StringBuilder,
    val: Float64Builder,
    done: bool,
}

impl DecodeStream {
    fn new(db: Database, logs: Vec<PathBuf>) -> DecodeStream {
        DecodeStream {
            db,
            logs: logs.into(),
            cur: None,
            frame: Frame::empty(0),
            schema: decode_schema(),
            t: Vec::with_capacity(BATCH_ROWS),
            id: UInt32Builder::with_capacity(BATCH_ROWS),
            ext: BooleanBuilder::with_capacity(BATCH_ROWS),
            msg: StringBuilder::new(),
            sig: StringBuilder::new(),
            val: Float64Builder::with_capacity(BATCH_ROWS),
            done: false,
        }
    }

    /// Decodes frames into the builders until a batch is full or the logs end.
    fn fill(&mut self) -> anyhow::Result<()> {
        while self.t.len() < BATCH_ROWS {
            if self.cur.is_none() {
                let Some(p) = self.logs.pop_front() else {
                    return Ok(());
                };
                let r =
                    LogReader::open(&p).with_context(|| format!("opening log {}", p.display()))?;
                self.cur = Some((p, r));
            }
            let (path, src) = self.cur.as_mut().expect("set above");
            let more = src
                .read_frame(&mut self.frame)
                .with_context(|| format!("reading {}", path.display()))?;
            if !more {
                self.cur = None;
                continue;
            }
            let f = &self.frame;
            if f.kind != FrameKind::Data {
                continue;
            }
            let Some(mi) = self.db.message_index(f.id, f.extended) else {
                continue;
            };
            let m = &self.db.messages()[mi];
            let data = f.payload();
            if let Err(DecodeError::UnknownMultiplexerValue { .. }) = m.check_multiplexers(data) {
                continue;
            }
            let (t, id, ext) = (f.t_ns, f.id, f.extended);
            let (tv, idb, extb, msgb, sigb, valb) = (
                &mut self.t,
                &mut self.id,
                &mut self.ext,
                &mut self.msg,
                &mut self.sig,
                &mut self.val,
            );
            // As `shimmy decode`: what the decoder delivers is a row, whatever it returns.
            let _ = m.decode(data, |i, _raw, phys| {
                tv.push(t);
                idb.append_value(id);
                extb.append_value(ext);
                msgb.append_value(&m.name);
                sigb.append_value(&m.signals[i].name);
                valb.append_value(phys);
            });
        }
        Ok(())
    }

    fn take_batch(&mut self) -> Result<RecordBatch, ArrowError> {
        let t = PrimitiveArray::<TimestampNanosecondType>::from(std::mem::take(&mut self.t))
            .with_timezone("UTC");
        let cols: Vec<ArrayRef> = vec![
            Arc::new(t),
            Arc::new(self.id.finish()),
            Arc::new(self.ext.finish()),
            Arc::new(self.msg.finish()),
            Arc::new(self.sig.finish()),
            Arc::new(self.val.finish()),
        ];
        self.t.reserve(BATCH_ROWS);
        RecordBatch::try_new(self.schema.clone(), cols)
    }
}

impl Iterator for DecodeStream {
    type Item = Result<RecordBatch, ArrowError>;

    fn next(&mut self) -> Option<Self::Item> {
        if self.done {
            return None;
        }
        let r = catch_unwind(AssertUnwindSafe(|| self.fill()));
        match r {
            Ok(Ok(())) => {}
            Ok(Err(e)) => {
                self.done = true;
                return Some(Err(ArrowError::ExternalError(format!("{e:#}").into())));
            }
            Err(_) => {
                self.done = true;
                return Some(Err(ArrowError::ExternalError(
                    "internal error in shimmy-monitor's decoder (please report)".into(),
                )));
            }
        }
        if self.t.is_empty() {
            self.done = true;
            return None;
        }
        if self.cur.is_none() && self.logs.is_empty() {
            self.done = true;
        }
        Some(self.take_batch())
    }
}

impl RecordBatchReader for DecodeStream {
    fn schema(&self) -> SchemaRef {
        self.schema.clone()
    }
}

/// Decodes `logs` with `dbc`; returns the address of an `ArrowArrayStream` the caller must
/// import at once (pyarrow's `RecordBatchReader._import_from_c`), and the DBC's count of skipped
/// statements.
#[pyfunction]
fn decode_stream(py: Python<'_>, logs: Vec<PathBuf>, dbc: PathBuf) -> PyResult<Py<StreamHandle>> {
    let stream = guarded(py, move || {
        let (db, _report) = Database::load(&dbc)?;
        // Every log must open now: a missing or unrecognisable file is an error of the call,
        // not of the first read.
        for p in &logs {
            LogReader::open(p).with_context(|| format!("opening log {}", p.display()))?;
        }
        let reader: Box<dyn RecordBatchReader + Send> = Box::new(DecodeStream::new(db, logs));
        Ok(FFI_ArrowArrayStream::new(reader))
    })?;
    Py::new(
        py,
        StreamHandle {
            stream: Box::new(stream),
        },
    )
}

/// Owns an exported `ArrowArrayStream` until pyarrow moves it out (`address`); dropping it
/// afterwards is a no-op (pyarrow clears the moved-from struct's release callback).
// unsendable: the raw stream is not Sync; the handle lives only for the import in `decode`.
#[pyclass(unsendable, module = "shimmy_monitor._native")]
struct StreamHandle {
    stream: Box<FFI_ArrowArrayStream>,
}

#[pymethods]
impl StreamHandle {
    /// The address of the `ArrowArrayStream` struct.
    fn address(&mut self) -> usize {
        &mut *self.stream as *mut FFI_ArrowArrayStream as usize
    }
}

fn estimate_args_with(
    logs: Vec<PathBuf>,
    profile: String,
    config: Option<PathBuf>,
    baseline_logs: Vec<PathBuf>,
    baseline_clearance_mm: f64,
) -> estimate::Args {
    estimate::Args {
        profile: Some(profile),
        mapping: None,
        dbc: None,
        vehicle: None,
        table: None,
        torque_table: None,
        angle_only: false,
        config,
        format: TextOrJson::Json,
        baseline_logs,
        baseline_clearance_mm,
        logs,
    }
}

/// `shimmy estimate --profile PROFILE [--config CONFIG] [--baseline B ...
/// --baseline-clearance-mm C] --format json LOG...`: the JSON document.
#[pyfunction]
#[pyo3(signature = (logs, profile, config=None, baseline=Vec::new(), baseline_clearance_mm=0.03))]
fn estimate_json(
    py: Python<'_>,
    logs: Vec<PathBuf>,
    profile: String,
    config: Option<PathBuf>,
    baseline: Vec<PathBuf>,
    baseline_clearance_mm: f64,
) -> PyResult<String> {
    guarded(py, move || {
        anyhow::ensure!(!logs.is_empty(), "no logs given");
        anyhow::ensure!(
            baseline_clearance_mm > 0.0 && baseline_clearance_mm.is_finite(),
            "baseline_clearance_mm must be a clearance above 0 mm, not {baseline_clearance_mm}"
        );
        let args = estimate_args_with(logs, profile, config, baseline, baseline_clearance_mm);
        let (profile, est, _stats) = estimate::evaluate(&args)?;
        Ok(estimate::output_json(profile.as_ref(), &est)?)
    })
}

/// `shimmy export`: the run's summary as JSON (failed logs listed in it, not raised).
#[pyfunction]
#[pyo3(signature = (logs, profile, vehicle, out, config=None, signals=true))]
fn export_json(
    py: Python<'_>,
    logs: Vec<PathBuf>,
    profile: String,
    vehicle: String,
    out: PathBuf,
    config: Option<PathBuf>,
    signals: bool,
) -> PyResult<String> {
    guarded(py, move || {
        anyhow::ensure!(!logs.is_empty(), "no logs given");
        let args = export::Args {
            profile,
            vehicle,
            out,
            config,
            logs,
        };
        let s = export::export(&args, false, signals)?;
        Ok(serde_json::to_string(&s)?)
    })
}

fn signal_arg(signal: Option<&str>) -> anyhow::Result<Option<SignalArg>> {
    match signal {
        None => Ok(None),
        Some("angle") => Ok(Some(SignalArg::Angle)),
        Some("torque") => Ok(Some(SignalArg::Torque)),
        Some(other) => anyhow::bail!("signal must be \"angle\" or \"torque\", not {other:?}"),
    }
}

fn fit_setup(
    profile: &str,
    config: Option<&std::path::Path>,
    clearance_mm: f64,
    signal: Option<&str>,
) -> anyhow::Result<FitSetup> {
    FitSetup::load(profile, config, clearance_mm, signal_arg(signal)?)
}

/// A vehicle given as a path, as `shimmy fleet-fit` takes it: the log file, or the files of the
/// folder in name order.
#[pyfunction]
fn fleet_vehicle_logs(py: Python<'_>, vehicle: PathBuf) -> PyResult<Vec<PathBuf>> {
    guarded(py, move || fleet_fit::vehicle_logs(&vehicle))
}

/// `shimmy fleet-fit`'s reading of one vehicle's drives at new joints: its events as one JSON
/// object (a line of the CLI's events cache). With `cache`, the object is kept in that file and
/// read back while the logs are unchanged (sizes and modification times), so a fleet job that
/// stopped resumes.
#[pyfunction]
#[pyo3(signature = (vehicle, logs, profile, config=None, clearance_mm=0.03, signal=None, cache=None))]
#[allow(clippy::too_many_arguments)]
fn fleet_fit_vehicle_json(
    py: Python<'_>,
    vehicle: String,
    logs: Vec<PathBuf>,
    profile: String,
    config: Option<PathBuf>,
    clearance_mm: f64,
    signal: Option<String>,
    cache: Option<PathBuf>,
) -> PyResult<String> {
    guarded(py, move || {
        anyhow::ensure!(!logs.is_empty(), "vehicle {vehicle:?}: no logs given");
        let key = fleet_fit::cache_key(&logs);
        if let Some(c) = &cache {
            if let Ok(text) = std::fs::read_to_string(c) {
                if serde_json::from_str::<VehicleEvents>(&text).is_ok_and(|v| v.key == key) {
                    return Ok(text);
                }
            }
        }
        let setup = fit_setup(&profile, config.as_deref(), clearance_mm, signal.as_deref())?;
        let v = setup.read_vehicle(&vehicle, logs);
        let text = serde_json::to_string(&v)?;
        if let Some(c) = &cache {
            if let Some(dir) = c.parent().filter(|d| !d.as_os_str().is_empty()) {
                std::fs::create_dir_all(dir)
                    .with_context(|| format!("cannot create {}", dir.display()))?;
            }
            fleet_fit::write_atomic(c, &text)?;
        }
        Ok(text)
    })
}

/// `shimmy fleet-fit`'s fit over vehicles read by `fleet_fit_vehicle_json` (in the order
/// given): writes the correction file `out` and returns what the fit says as JSON.
#[pyfunction]
#[pyo3(signature = (profile, vehicles, out, config=None, clearance_mm=0.03, signal=None))]
fn fleet_fit_json(
    py: Python<'_>,
    profile: String,
    vehicles: Vec<String>,
    out: PathBuf,
    config: Option<PathBuf>,
    clearance_mm: f64,
    signal: Option<String>,
) -> PyResult<String> {
    guarded(py, move || {
        let vehicles: Vec<VehicleEvents> = vehicles
            .iter()
            .enumerate()
            .map(|(i, v)| {
                serde_json::from_str(v)
                    .with_context(|| format!("vehicle {i}: not a vehicle's events"))
            })
            .collect::<anyhow::Result<_>>()?;
        anyhow::ensure!(!vehicles.is_empty(), "no vehicles given");
        let setup = fit_setup(&profile, config.as_deref(), clearance_mm, signal.as_deref())?;
        let outcome = setup.fit(&vehicles)?;
        fleet_fit::write_atomic(&out, &outcome.text)?;
        Ok(serde_json::to_string(&outcome)?)
    })
}

/// The crate version (`shimmy-monitor <version>` is the lake's `model_version`).
#[pyfunction]
fn model_version() -> String {
    shimmy::lake::model_version()
}

#[pymodule]
fn _native(m: &Bound<'_, PyModule>) -> PyResult<()> {
    m.add("ShimmyError", m.py().get_type::<ShimmyError>())?;
    m.add_class::<StreamHandle>()?;
    m.add_function(wrap_pyfunction!(decode_stream, m)?)?;
    m.add_function(wrap_pyfunction!(estimate_json, m)?)?;
    m.add_function(wrap_pyfunction!(export_json, m)?)?;
    m.add_function(wrap_pyfunction!(fleet_vehicle_logs, m)?)?;
    m.add_function(wrap_pyfunction!(fleet_fit_vehicle_json, m)?)?;
    m.add_function(wrap_pyfunction!(fleet_fit_json, m)?)?;
    m.add_function(wrap_pyfunction!(model_version, m)?)?;
    Ok(())
}
