//! `shimmy decode`: print the signals of every frame of one or more CAN logs, decoded with a DBC
//! file, the way `cantools decode` does; a summary of what could not be decoded goes to stderr.
//!
//! This module is output policy only: reading logs is [`crate::source`]'s job and decoding
//! [`crate::dbc`]'s. The per-frame path writes straight into a buffered writer and allocates
//! nothing.

use std::collections::HashSet;
use std::io::{self, Write};
use std::path::PathBuf;

use anyhow::Context as _;

use crate::dbc::{Database, DecodeError, Message, RawValue};
use crate::signals::mapping::MappingConfig;
use crate::signals::{Mapper, Outcome, Reject, Validity, VehicleSignals};
use crate::source::{CanSource, Skip, SourceStats};
use crate::wire::{Frame, FrameKind};

/// The manual part of `shimmy decode --help`.
const MANUAL: &str = "\
Reads each LOG in turn (candump -L, Vector ASC, BLF, ASAM MDF 4 or PEAK TRC, detected from
the content) and prints one record per frame whose ID the DBC defines. Value-table entries stay
numbers. At the end a summary goes to stderr: frames read, decoded, with unknown IDs, refused (a
multiplexer value the DBC does not define, as cantools refuses them), short frames whose
missing signals were left out, remote/error frames, and what the log reader skipped (with
file:line).

JSON lines (default), one object per decoded frame:
  {\"t\": 46408.584954, \"id\": 180, \"extended\": false, \"msg\": \"SPEED\",
   \"signals\": {\"ENCODER\": 29, \"SPEED\": 29.38, \"CHECKSUM\": 94}}
With --raw also \"raw\": {...} holding the unscaled values. Non-finite values (a float signal
holding NaN or infinity) are written as null.

CSV: a header t,id,extended,msg,signal,value (plus raw with --raw), then one row per decoded
signal.

Example:
  shimmy decode --dbc toyota_new_mc_pt_generated.dbc rav4_2017_seg40_bus0.log | head";

/// Arguments of `shimmy decode`.
#[derive(clap::Args, Debug)]
#[command(after_long_help = MANUAL)]
pub struct Args {
    /// DBC file describing the bus (UTF-8 or Windows-1252). Statements it cannot use are
    /// skipped and counted; see --dbc-report.
    #[arg(long, value_name = "FILE")]
    pub dbc: PathBuf,

    /// Signal mapping (TOML, e.g. config/vehicles/*/mapping.toml) to print the monitor's quantities instead
    /// of raw signals: one record per frame of a mapped message, with steering-wheel angle
    /// (deg), speed (km/h), brake pressure (bar), brake pressed, longitudinal acceleration
    /// (m/s^2), the driver's steering torque (N·m), each with its validity (valid, no_data,
    /// timed_out, not_mapped; a value is printed only while valid), and why the frame was
    /// rejected if it was (checksum, counter, short). The summary lists, per message, frames, accepted, checksum and counter errors,
    /// counter gaps, short frames and timeouts.
    #[arg(long, value_name = "FILE")]
    pub mapping: Option<PathBuf>,

    /// Output format.
    #[arg(long, value_enum, default_value_t = Format::Jsonl)]
    pub format: Format,

    /// Also print the raw (unscaled) signal values.
    #[arg(long)]
    pub raw: bool,

    /// List every DBC statement that was skipped, and every note, on stderr before decoding.
    #[arg(long)]
    pub dbc_report: bool,

    /// Log files to decode, in order.
    #[arg(value_name = "LOG", required = true)]
    pub logs: Vec<PathBuf>,
}

/// Output formats of `shimmy decode`.
#[derive(clap::ValueEnum, Clone, Copy, Debug, PartialEq, Eq)]
pub enum Format {
    /// One JSON object per decoded frame.
    Jsonl,
    /// One CSV row per decoded signal.
    Csv,
}

/// Options of [`decode_source`].
#[derive(Clone, Copy, Debug)]
pub struct Options {
    pub format: Format,
    pub raw: bool,
}

/// Counters of a decode run.
#[derive(Clone, Debug, Default, PartialEq, Eq)]
pub struct Summary {
    /// Frames delivered by the sources.
    pub frames: u64,
    /// Frames decoded and printed.
    pub decoded: u64,
    /// Data frames whose ID the DBC does not define.
    pub unknown_id: u64,
    /// Distinct unknown IDs (extended ones with bit 31 set).
    pub unknown_ids: HashSet<u32>,
    /// Frames refused because a multiplexer value selects nothing.
    pub refused_mux: u64,
    /// Decoded frames shorter than their signals need.
    pub short_frames: u64,
    /// Signals left out of short frames.
    pub missing_signals: u64,
    /// Remote and error frames (not decoded).
    pub non_data: u64,
    /// Reader counters, summed over the logs.
    pub source: SourceStats,
    /// Reader skip reports (bounded by the reader).
    pub skips: Vec<Skip>,
}

impl Summary {
    /// The human summary printed at the end.
    pub fn report(&self) -> String {
        let mut s = format!(
            "decode summary: {} frames read, {} decoded; not decoded: {} with unknown IDs ({} distinct), \
             {} refused (unknown multiplexer value), {} remote/error frames; \
             {} short frames missing {} signals; log reader: {} malformed, {} skipped, {} dropped, \
             {} backwards timestamps",
            self.frames,
            self.decoded,
            self.unknown_id,
            self.unknown_ids.len(),
            self.refused_mux,
            self.non_data,
            self.short_frames,
            self.missing_signals,
            self.source.malformed,
            self.source.skipped,
            self.source.dropped,
            self.source.backwards_timestamps,
        );
        if let Some(note) = self.source.zero_filled_note() {
            s.push_str(&format!("\n  {note}"));
        }
        for k in &self.skips {
            s.push_str(&format!("\n  skipped {}: {}", k.location, k.reason));
        }
        s
    }
}

/// Pre-escaped names so that the per-frame path only copies bytes.
struct Names {
    /// Per message: JSON-escaped message name, and JSON-escaped signal names.
    msgs: Vec<(String, Vec<String>)>,
}

fn json_str(s: &str) -> String {
    serde_json::to_string(s).unwrap_or_else(|_| "\"?\"".into())
}

fn csv_str(s: &str) -> String {
    if s.contains([',', '"', '\n', '\r']) {
        format!("\"{}\"", s.replace('"', "\"\""))
    } else {
        s.to_string()
    }
}

impl Names {
    fn new(db: &Database, format: Format) -> Names {
        let esc = |s: &str| match format {
            Format::Jsonl => json_str(s),
            Format::Csv => csv_str(s),
        };
        Names {
            msgs: db
                .messages()
                .iter()
                .map(|m| {
                    (
                        esc(&m.name),
                        m.signals.iter().map(|s| esc(&s.name)).collect(),
                    )
                })
                .collect(),
        }
    }
}

/// A number as JSON/CSV: integers without a fraction, others in shortest round-trip form,
/// non-finite as `null` (JSON) or empty (CSV).
fn write_num<W: Write>(w: &mut W, v: f64, format: Format) -> io::Result<()> {
    if !v.is_finite() {
        return match format {
            Format::Jsonl => w.write_all(b"null"),
            Format::Csv => Ok(()),
        };
    }
    if v.fract() == 0.0 && v.abs() < 1e15 {
        write!(w, "{}", v as i64)
    } else {
        write!(w, "{v:?}")
    }
}

fn write_raw<W: Write>(w: &mut W, r: RawValue, format: Format) -> io::Result<()> {
    match r {
        RawValue::Unsigned(u) => write!(w, "{u}"),
        RawValue::Signed(i) => write!(w, "{i}"),
        RawValue::F32(_) | RawValue::F64(_) => write_num(w, r.as_f64(), format),
    }
}

fn write_time<W: Write>(w: &mut W, t_ns: i64) -> io::Result<()> {
    let sign = if t_ns < 0 { "-" } else { "" };
    let a = t_ns.unsigned_abs();
    let (s, ns) = (a / 1_000_000_000, a % 1_000_000_000);
    if ns % 1000 == 0 {
        write!(w, "{sign}{s}.{:06}", ns / 1000)
    } else {
        write!(w, "{sign}{s}.{ns:09}")
    }
}

/// Write the CSV header for the options.
pub fn write_header<W: Write>(w: &mut W, opts: Options) -> io::Result<()> {
    if opts.format == Format::Csv {
        w.write_all(if opts.raw {
            b"t,id,extended,msg,signal,value,raw\n"
        } else {
            b"t,id,extended,msg,signal,value\n"
        })?;
    }
    Ok(())
}

/// Decode every frame of `source` into `out`, updating `summary`.
pub fn decode_source<W: Write>(
    db: &Database,
    source: &mut dyn CanSource,
    out: &mut W,
    opts: Options,
    summary: &mut Summary,
) -> io::Result<()> {
    let names = Names::new(db, opts.format);
    // One reused frame, filled in place by the source (see `CanSource::read_frame`).
    let mut frame = Frame::empty(0);
    while source.read_frame(&mut frame)? {
        summary.frames += 1;
        decode_frame(db, &names, &frame, out, opts, summary)?;
    }
    summary.source.add(&source.stats());
    summary.skips.extend(source.take_skips());
    Ok(())
}

fn decode_frame<W: Write>(
    db: &Database,
    names: &Names,
    frame: &Frame,
    out: &mut W,
    opts: Options,
    summary: &mut Summary,
) -> io::Result<()> {
    if frame.kind != FrameKind::Data {
        summary.non_data += 1;
        return Ok(());
    }
    let Some(mi) = db.message_index(frame.id, frame.extended) else {
        summary.unknown_id += 1;
        summary
            .unknown_ids
            .insert(frame.id | (frame.extended as u32) << 31);
        return Ok(());
    };
    let msg = &db.messages()[mi];
    let data = frame.payload();
    // Check the multiplexers first so that a refused frame prints nothing.
    if let Err(DecodeError::UnknownMultiplexerValue { .. }) = msg.check_multiplexers(data) {
        summary.refused_mux += 1;
        return Ok(());
    }
    let (mname, snames) = &names.msgs[mi];
    let res = match opts.format {
        Format::Jsonl => write_jsonl(msg, frame, mname, snames, out, opts),
        Format::Csv => write_csv(msg, frame, mname, snames, out, opts),
    }?;
    match res {
        Ok(sum) => {
            summary.decoded += 1;
            if sum.truncated > 0 {
                summary.short_frames += 1;
                summary.missing_signals += sum.truncated as u64;
            }
        }
        Err(_) => summary.refused_mux += 1,
    }
    Ok(())
}

type DecodeResult = Result<crate::dbc::DecodeSummary, DecodeError>;

fn write_jsonl<W: Write>(
    msg: &Message,
    frame: &Frame,
    mname: &str,
    snames: &[String],
    out: &mut W,
    opts: Options,
) -> io::Result<DecodeResult> {
    out.write_all(b"{\"t\": ")?;
    write_time(out, frame.t_ns)?;
    write!(
        out,
        ", \"id\": {}, \"extended\": {}, \"msg\": {mname}, \"signals\": {{",
        frame.id, frame.extended
    )?;
    let data = frame.payload();
    let res = write_signal_map(msg, data, snames, out, |o, _raw, phys| {
        write_num(o, phys, Format::Jsonl)
    })?;
    out.write_all(b"}")?;
    if opts.raw {
        out.write_all(b", \"raw\": {")?;
        let _ = write_signal_map(msg, data, snames, out, |o, raw, _phys| {
            write_raw(o, raw, Format::Jsonl)
        })?;
        out.write_all(b"}")?;
    }
    out.write_all(b"}\n")?;
    Ok(res)
}

/// Writes `"name": value, …` for every signal `msg.decode` delivers (multiplexing honoured),
/// the value written by `value` from the raw and physical values. Returns what the decoder
/// returned; the first write error stops the output.
fn write_signal_map<W: Write>(
    msg: &Message,
    data: &[u8],
    snames: &[String],
    out: &mut W,
    mut value: impl FnMut(&mut W, RawValue, f64) -> io::Result<()>,
) -> io::Result<DecodeResult> {
    let mut err: io::Result<()> = Ok(());
    let mut first = true;
    let res = msg.decode(data, |i, raw, phys| {
        if err.is_ok() {
            err = (|| {
                if !first {
                    out.write_all(b", ")?;
                }
                first = false;
                out.write_all(snames[i].as_bytes())?;
                out.write_all(b": ")?;
                value(out, raw, phys)
            })();
        }
    });
    err?;
    Ok(res)
}

fn write_csv<W: Write>(
    msg: &Message,
    frame: &Frame,
    mname: &str,
    snames: &[String],
    out: &mut W,
    opts: Options,
) -> io::Result<DecodeResult> {
    let mut err: io::Result<()> = Ok(());
    let res = msg.decode(frame.payload(), |i, raw, phys| {
        if err.is_ok() {
            err = (|| {
                write_time(out, frame.t_ns)?;
                write!(out, ",{},{},{mname},", frame.id, frame.extended)?;
                out.write_all(snames[i].as_bytes())?;
                out.write_all(b",")?;
                write_num(out, phys, Format::Csv)?;
                if opts.raw {
                    out.write_all(b",")?;
                    write_raw(out, raw, Format::Csv)?;
                }
                out.write_all(b"\n")
            })();
        }
    });
    err?;
    Ok(res)
}

/// Open a log file as a frame source.
fn open_log(path: &std::path::Path) -> anyhow::Result<Box<dyn CanSource>> {
    let r = crate::source::log::LogReader::open(path)
        .with_context(|| format!("opening log {}", path.display()))?;
    Ok(Box::new(r))
}

pub fn run(args: Args) -> anyhow::Result<()> {
    let (db, report) = Database::load(&args.dbc)?;
    if args.dbc_report {
        eprint!("{}: {report}", args.dbc.display());
    } else if !report.skipped.is_empty() {
        eprintln!(
            "{}: {} DBC statements skipped (--dbc-report lists them)",
            args.dbc.display(),
            report.skipped.len()
        );
    }
    if let Some(mapping) = &args.mapping {
        return run_mapped(&args, &db, mapping);
    }
    let opts = Options {
        format: args.format,
        raw: args.raw,
    };
    let stdout = io::stdout();
    let mut out = io::BufWriter::with_capacity(1 << 16, stdout.lock());
    let mut summary = Summary::default();
    let result = (|| -> anyhow::Result<()> {
        write_header(&mut out, opts)?;
        for log in &args.logs {
            let mut src = open_log(log)?;
            decode_source(&db, src.as_mut(), &mut out, opts, &mut summary)
                .with_context(|| format!("reading {}", log.display()))?;
        }
        out.flush()?;
        Ok(())
    })();
    eprintln!("{}", summary.report());
    match result {
        // A closed pipe (`| head`) is a normal way to stop.
        Err(e)
            if e.downcast_ref::<io::Error>()
                .is_some_and(|io| io.kind() == io::ErrorKind::BrokenPipe) =>
        {
            Ok(())
        }
        other => other,
    }
}

// --- `--mapping`: the monitor's quantities instead of DBC signals ---------------------------

/// Counters of a `--mapping` run (the per-message ones live in the [`Mapper`]).
#[derive(Clone, Debug, Default)]
pub struct MappedSummary {
    /// Frames delivered by the sources.
    pub frames: u64,
    /// Frames of mapped messages (accepted or rejected), one record each.
    pub mapped: u64,
    /// Reader counters, summed over the logs.
    pub source: SourceStats,
    /// Reader skip reports (bounded by the reader).
    pub skips: Vec<Skip>,
}

impl MappedSummary {
    /// The human summary printed at the end: totals, then one line per mapped message.
    pub fn report(&self, mapper: &Mapper) -> String {
        let mut s = format!(
            "mapping summary: {} frames read, {} of mapped messages, {} of other messages; \
             log reader: {} malformed, {} skipped, {} dropped, {} backwards timestamps",
            self.frames,
            self.mapped,
            mapper.ignored_frames(),
            self.source.malformed,
            self.source.skipped,
            self.source.dropped,
            self.source.backwards_timestamps,
        );
        for m in mapper.stats() {
            s.push_str(&format!(
                "\n  {} (0x{:X}{}): {} frames, {} accepted, {} checksum errors, {} counter errors, \
                 {} counter gaps ({} frames lost), {} short, {} timeouts (> {} ms){}",
                m.name,
                m.id,
                if m.extended { " ext" } else { "" },
                m.frames,
                m.accepted,
                m.checksum_errors,
                m.counter_errors,
                m.counter_gaps,
                m.frames_lost,
                m.short_frames,
                m.timeouts,
                m.timeout_ms,
                if m.frames == 0 { ", NEVER RECEIVED" } else { "" },
            ));
        }
        if let Some(note) = self.source.zero_filled_note() {
            s.push_str(&format!("\n  {note}"));
        }
        for k in &self.skips {
            s.push_str(&format!("\n  skipped {}: {}", k.location, k.reason));
        }
        s
    }
}

fn validity_str(v: Validity) -> &'static str {
    match v {
        Validity::Valid => "valid",
        Validity::NotMapped => "not_mapped",
        Validity::NoData => "no_data",
        Validity::TimedOut => "timed_out",
    }
}

/// Write the CSV header of the `--mapping` output.
pub fn write_mapped_header<W: Write>(w: &mut W, format: Format) -> io::Result<()> {
    if format == Format::Csv {
        w.write_all(
            b"t,msg,steer_angle_deg,steer_angle_validity,speed_kmh,speed_validity,\
brake_pressure_bar,brake_pressure_validity,brake_pressed,brake_pressed_validity,\
accel_mps2,accel_validity,steer_torque_nm,steer_torque_validity,rejected\n",
        )?;
    }
    Ok(())
}

/// Interpret every frame of `source` with `mapper` and write one record per frame of a mapped
/// message into `out`. Allocates nothing per frame.
pub fn decode_mapped<W: Write>(
    mapper: &mut Mapper,
    source: &mut dyn CanSource,
    out: &mut W,
    format: Format,
    summary: &mut MappedSummary,
) -> io::Result<()> {
    let names: Vec<String> = mapper
        .stats()
        .iter()
        .map(|m| match format {
            Format::Jsonl => json_str(&m.name),
            Format::Csv => csv_str(&m.name),
        })
        .collect();
    while let Some(frame) = source.next_frame()? {
        summary.frames += 1;
        let Some(u) = mapper.on_frame(&frame) else {
            continue;
        };
        summary.mapped += 1;
        let snap = mapper.snapshot(frame.t_ns);
        let rejected = match u.outcome {
            Outcome::Accepted(_) => None,
            Outcome::Rejected(r) => Some(r),
        };
        write_mapped(out, &frame, &names[u.message], &snap, rejected, format)?;
    }
    summary.source.add(&source.stats());
    summary.skips.extend(source.take_skips());
    Ok(())
}

/// A mapped quantity as printed: JSON key, validity key, value in edge units, validity.
type Quantity = (&'static str, &'static str, Option<f64>, Validity);

fn write_mapped<W: Write>(
    out: &mut W,
    frame: &Frame,
    name: &str,
    s: &VehicleSignals,
    rejected: Option<Reject>,
    format: Format,
) -> io::Result<()> {
    // Back to the edge units, rounded to 1e-9 so that SI round trips print as the bus sent
    // them (29.38 km/h, not 29.380000000000003): far below any sensor's resolution.
    let edge = |v: f64| (v * 1e9).round() / 1e9;
    let steer = s.steer_angle_rad.valid().map(|v| edge(v.to_degrees()));
    let speed = s.speed_mps.valid().map(|v| edge(v * 3.6));
    let pressure = s.brake_pressure_pa.valid().map(|v| edge(v * 1e-5));
    let nums = [
        (
            "steer_angle_deg",
            "steer_angle",
            steer,
            s.steer_angle_rad.validity,
        ),
        ("speed_kmh", "speed", speed, s.speed_mps.validity),
        (
            "brake_pressure_bar",
            "brake_pressure",
            pressure,
            s.brake_pressure_pa.validity,
        ),
    ];
    // The quantities after `brake_pressed`, in the same shape.
    let more = [
        (
            "accel_mps2",
            "accel",
            s.accel_mps2.valid().map(edge),
            s.accel_mps2.validity,
        ),
        (
            "steer_torque_nm",
            "steer_torque",
            s.steer_torque_nm.valid().map(edge),
            s.steer_torque_nm.validity,
        ),
    ];
    let pressed = s.brake_pressed.valid();
    match format {
        Format::Jsonl => {
            out.write_all(b"{\"t\": ")?;
            write_time(out, frame.t_ns)?;
            write!(out, ", \"msg\": {name}")?;
            let values = |out: &mut W, quantities: &[Quantity]| -> io::Result<()> {
                for &(key, _, v, _) in quantities {
                    write!(out, ", \"{key}\": ")?;
                    match v {
                        Some(v) => write_num(out, v, format)?,
                        None => out.write_all(b"null")?,
                    }
                }
                Ok(())
            };
            values(out, &nums)?;
            match pressed {
                Some(p) => write!(out, ", \"brake_pressed\": {p}")?,
                None => out.write_all(b", \"brake_pressed\": null")?,
            }
            values(out, &more)?;
            out.write_all(b", \"validity\": {")?;
            for (_, quantity, _, v) in nums {
                write!(out, "\"{quantity}\": \"{}\", ", validity_str(v))?;
            }
            write!(
                out,
                "\"brake_pressed\": \"{}\"",
                validity_str(s.brake_pressed.validity)
            )?;
            for (_, quantity, _, v) in more {
                write!(out, ", \"{quantity}\": \"{}\"", validity_str(v))?;
            }
            out.write_all(b"}")?;
            if let Some(r) = rejected {
                // Reject texts hold no characters that need JSON escaping.
                write!(out, ", \"rejected\": \"{r}\"")?;
            }
            out.write_all(b"}\n")
        }
        Format::Csv => {
            write_time(out, frame.t_ns)?;
            write!(out, ",{name}")?;
            let columns = |out: &mut W, quantities: &[Quantity]| -> io::Result<()> {
                for &(_, _, v, validity) in quantities {
                    out.write_all(b",")?;
                    if let Some(v) = v {
                        write_num(out, v, format)?;
                    }
                    write!(out, ",{}", validity_str(validity))?;
                }
                Ok(())
            };
            columns(out, &nums)?;
            match pressed {
                Some(p) => write!(out, ",{}", p as u8)?,
                None => out.write_all(b",")?,
            }
            write!(out, ",{}", validity_str(s.brake_pressed.validity))?;
            columns(out, &more)?;
            out.write_all(b",")?;
            if let Some(r) = rejected {
                // Reject texts hold no commas or quotes.
                write!(out, "{r}")?;
            }
            out.write_all(b"\n")
        }
    }
}

fn run_mapped(args: &Args, db: &Database, mapping: &std::path::Path) -> anyhow::Result<()> {
    if args.raw {
        anyhow::bail!(
            "--raw has no meaning with --mapping (mapped quantities are physical values)"
        );
    }
    let cfg = MappingConfig::from_toml_file(mapping)?;
    let mut mapper = Mapper::new(db, &cfg).with_context(|| {
        format!(
            "mapping {} does not fit DBC {}",
            mapping.display(),
            args.dbc.display()
        )
    })?;
    for w in mapper.warnings() {
        eprintln!("{}: warning: {w}", mapping.display());
    }
    let stdout = io::stdout();
    let mut out = io::BufWriter::with_capacity(1 << 16, stdout.lock());
    let mut summary = MappedSummary::default();
    let result = (|| -> anyhow::Result<()> {
        write_mapped_header(&mut out, args.format)?;
        for log in &args.logs {
            let mut src = open_log(log)?;
            decode_mapped(
                &mut mapper,
                src.as_mut(),
                &mut out,
                args.format,
                &mut summary,
            )
            .with_context(|| format!("reading {}", log.display()))?;
        }
        out.flush()?;
        Ok(())
    })();
    eprintln!("{}", summary.report(&mapper));
    match result {
        Err(e)
            if e.downcast_ref::<io::Error>()
                .is_some_and(|io| io.kind() == io::ErrorKind::BrokenPipe) =>
        {
            Ok(())
        }
        other => other,
    }
}
