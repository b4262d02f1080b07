//! `shimmy convert`: one CAN log format to another (candump -L, Vector ASC, BLF, ASAM MDF 4;
//! PEAK TRC as input only),
//! streaming, like python-can's `can.logconvert`.

use std::path::PathBuf;

use anyhow::{bail, Context};
use clap::ValueEnum;

use crate::source::log::LogReader;
use crate::source::writer::LogWriter;
use crate::source::CanSource;
use crate::wire::mf4::{Mf4Compression, Mf4Layout, Mf4WriterOptions};
use crate::wire::Frame;

#[derive(Clone, Copy, Debug, ValueEnum)]
pub enum Layout {
    /// One data group, records in arrival order (as CAN loggers write).
    Unsorted,
    /// One data group per frame type (as asammdf saves).
    Sorted,
}

#[derive(Clone, Copy, Debug, ValueEnum)]
pub enum Compression {
    None,
    /// DZ blocks, deflate.
    Deflate,
    /// DZ blocks, transposition + deflate (sorted layout; deflate otherwise).
    Transposed,
}

const MANUAL: &str = "\
Converts a CAN log from one format to another, frame by frame in constant memory. The input
format is recognised by content (as `shimmy decode` does: candump -L, Vector ASC, BLF, ASAM
MDF 4 `.mf4` including unfinalized logger files, PEAK TRC 1.0-2.1, gzip-compressed text); the
output format by OUT's extension: `.mf4`, `.asc`, `.blf`, anything else but `.trc` candump -L.

Lossless where the output format allows; at the end it prints what it could not keep:
  candump -L, MF4   everything a frame holds (ns times, interface names, CAN FD flags,
                    raw DLC 9-15, remote and error frames with class and detail bytes)
  BLF               interfaces become channel numbers (canN is channel N+1; other names
                    read back as can<channel-1>); error frames keep only their time and
                    channel; frames earlier than the first one's millisecond are clamped
  ASC               as BLF, and times are rounded to the microsecond
Skipped or malformed input (counted, first ones reported) is printed too; with --strict
any loss or skip makes the command fail (the output is still written).

Examples:
  shimmy convert drive.log drive.mf4
  shimmy convert 00000001.MF4 bus.log                        # a CANedge file to candump -L
  shimmy convert drive.blf drive.mf4 --mf4-layout sorted --mf4-compression transposed";

/// Arguments of `shimmy convert`.
#[derive(clap::Args, Debug)]
#[command(after_long_help = MANUAL)]
pub struct Args {
    /// Input log.
    #[arg(value_name = "IN")]
    pub input: PathBuf,
    /// Output log (format from the extension).
    #[arg(value_name = "OUT")]
    pub output: PathBuf,
    /// MF4 output: how records are arranged.
    #[arg(long, value_enum, default_value = "unsorted")]
    pub mf4_layout: Layout,
    /// MF4 output: block compression.
    #[arg(long, value_enum, default_value = "none")]
    pub mf4_compression: Compression,
    /// Fail if anything was lost, skipped or malformed.
    #[arg(long)]
    pub strict: bool,
}

pub fn run(args: Args) -> anyhow::Result<()> {
    if args.input == args.output {
        bail!("IN and OUT are the same file");
    }
    let out_format = crate::source::writer::OutFormat::from_path(&args.output)?;
    let mut r = LogReader::open(&args.input)
        .with_context(|| format!("cannot read {}", args.input.display()))?;
    let opts = Mf4WriterOptions {
        layout: match args.mf4_layout {
            Layout::Unsorted => Mf4Layout::Unsorted,
            Layout::Sorted => Mf4Layout::Sorted,
        },
        compression: match args.mf4_compression {
            Compression::None => Mf4Compression::None,
            Compression::Deflate => Mf4Compression::Deflate,
            Compression::Transposed => Mf4Compression::Transposed,
        },
        ..Default::default()
    };
    let mut w = LogWriter::create(&args.output, opts)?;
    let mut f = Frame::empty(0);
    while r.read_frame(&mut f)? {
        w.write(&f)
            .with_context(|| format!("cannot write {}", args.output.display()))?;
    }
    let frames = w.frames();
    let losses = w.finish()?;
    let st = r.stats();
    eprintln!(
        "shimmy convert: {frames} frames {:?} -> {:?}",
        r.format(),
        out_format
    );
    for s in r.take_skips() {
        eprintln!("  skipped {}: {}", s.location, s.reason);
    }
    if st.malformed + st.skipped > 0 {
        eprintln!(
            "  input: {} malformed, {} skipped (non-CAN or unsupported records)",
            st.malformed, st.skipped
        );
    }
    if let Some(note) = st.zero_filled_note() {
        eprintln!("  input: {note}");
    }
    let lost = losses.describe();
    if lost.is_empty() {
        eprintln!("  lossless");
    }
    for l in &lost {
        eprintln!("  lost: {l}");
    }
    if args.strict && (!lost.is_empty() || st.malformed + st.skipped > 0) {
        bail!("--strict: the conversion was not lossless");
    }
    Ok(())
}
