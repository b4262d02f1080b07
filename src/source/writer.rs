//! [`LogWriter`]: writes frames as a log file in the format its name asks for — `.mf4` ASAM
//! MDF 4, `.asc` Vector ASC, `.blf` Vector BLF, anything else candump -L — and keeps count of
//! what the format could not hold ([`Losses`]), so a conversion can say what it lost.
//!
//! What each format keeps of a [`Frame`]:
//! - candump -L: everything (ns times, any interface name, error class and detail bytes);
//! - MF4 ([`crate::wire::mf4::write`]): everything (interface names as a value-to-text
//!   conversion on `BusChannel`, error class in `ID`, detail bytes in `DataBytes`);
//! - BLF: ns times from the first frame's millisecond on; interfaces as 1-based channel
//!   numbers (`canN` is channel N+1; other names get the lowest free channel and read back
//!   as `can{channel-1}`); error frames without class or detail bytes;
//! - ASC: as BLF, and times to the microsecond.
//!
//! Not here: the formats themselves ([`crate::wire`]) or reading ([`super::log`]).

use super::recorder::CandumpWriter;
use crate::wire::asc;
use crate::wire::asc::CAN_ERR_PROT;
use crate::wire::blf::BlfWriter;
use crate::wire::mf4::{Mf4Writer, Mf4WriterOptions};
use crate::wire::{Frame, FrameKind, IfaceName};
use std::fs::File;
use std::io::{self, BufWriter, Write};
use std::path::Path;

/// Output formats.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum OutFormat {
    Candump,
    Asc,
    Blf,
    Mf4,
}

impl OutFormat {
    /// The format a file name asks for (by extension, case-insensitive; anything else is
    /// candump -L). `.trc` is refused: PEAK TRC is a format the readers read, not one written
    /// here, and candump text under that name would mislead.
    pub fn from_path(p: &Path) -> io::Result<OutFormat> {
        Ok(
            match p
                .extension()
                .and_then(|e| e.to_str())
                .map(|e| e.to_ascii_lowercase())
                .as_deref()
            {
                Some("mf4") => OutFormat::Mf4,
                Some("asc") => OutFormat::Asc,
                Some("blf") => OutFormat::Blf,
                Some("trc") => {
                    return Err(io::Error::new(
                        io::ErrorKind::InvalidInput,
                        format!(
                            "{}: PEAK TRC is read, not written; use the extension .log \
                             (candump -L), .asc, .blf or .mf4",
                            p.display()
                        ),
                    ))
                }
                _ => OutFormat::Candump,
            },
        )
    }
}

/// What a conversion could not keep (all zero/empty: lossless).
#[derive(Clone, Debug, Default, PartialEq, Eq)]
pub struct Losses {
    /// Frames whose time was rounded (ASC: to the microsecond).
    pub times_rounded: u64,
    /// Frames earlier than the file's start (the first frame's millisecond) or before 1970,
    /// written at the start.
    pub times_clamped: u64,
    /// Error frames whose SocketCAN class or detail bytes were dropped.
    pub error_details: u64,
    /// Interfaces that read back under another name: (name, read back as).
    pub renamed: Vec<(String, String)>,
}

impl Losses {
    pub fn is_empty(&self) -> bool {
        *self == Losses::default()
    }

    /// One line per kind of loss, for a human.
    pub fn describe(&self) -> Vec<String> {
        let mut v = Vec::new();
        if self.times_rounded > 0 {
            v.push(format!(
                "{} frame times rounded to the microsecond (ASC resolution)",
                self.times_rounded
            ));
        }
        if self.times_clamped > 0 {
            v.push(format!(
                "{} frames earlier than the file's start time written at the start",
                self.times_clamped
            ));
        }
        if self.error_details > 0 {
            v.push(format!(
                "{} error frames lost their SocketCAN error class and detail bytes",
                self.error_details
            ));
        }
        for (a, b) in &self.renamed {
            v.push(format!(
                "interface {a} is a channel number here: reads back as {b}"
            ));
        }
        v
    }
}

/// 1-based channel numbers for interface names (ASC and BLF): `canN` is N+1.
#[derive(Default)]
struct Channels {
    names: Vec<(IfaceName, u32)>,
}

impl Channels {
    fn get(&mut self, name: IfaceName, losses: &mut Losses) -> u32 {
        if let Some(&(_, c)) = self.names.iter().find(|(n, _)| *n == name) {
            return c;
        }
        let s = name.as_str();
        let want = s
            .strip_prefix("can")
            .filter(|d| !d.is_empty() && d.bytes().all(|b| b.is_ascii_digit()))
            .filter(|d| *d == "0" || !d.starts_with('0'))
            .and_then(|d| d.parse::<u32>().ok())
            .filter(|&k| k < 65_534)
            .map(|k| k + 1);
        let taken = |c: u32, names: &[(IfaceName, u32)]| names.iter().any(|&(_, x)| x == c);
        let ch = match want {
            Some(c) if !taken(c, &self.names) => c,
            _ => (1..).find(|&c| !taken(c, &self.names)).unwrap(),
        };
        if want != Some(ch) {
            losses
                .renamed
                .push((s.to_string(), format!("can{}", ch - 1)));
        }
        self.names.push((name, ch));
        ch
    }
}

enum Kind {
    Candump(CandumpWriter<File>),
    Asc {
        w: BufWriter<File>,
        start: Option<i64>,
        line: Vec<u8>,
    },
    Blf(BlfWriter<BufWriter<File>>),
    Mf4(Box<Mf4Writer<BufWriter<File>>>),
}

/// Writes a log in the format chosen by the file name.
pub struct LogWriter {
    kind: Kind,
    format: OutFormat,
    channels: Channels,
    losses: Losses,
    frames: u64,
}

impl LogWriter {
    /// Create (truncate) `path`, in the format its extension names; MF4 with `mf4` options.
    pub fn create(path: &Path, mf4: Mf4WriterOptions) -> io::Result<LogWriter> {
        let format = OutFormat::from_path(path)?;
        let file = || {
            File::create(path).map_err(|e| {
                io::Error::new(e.kind(), format!("cannot create {}: {e}", path.display()))
            })
        };
        let kind = match format {
            OutFormat::Candump => Kind::Candump(CandumpWriter::create(path)?),
            OutFormat::Asc => Kind::Asc {
                w: BufWriter::with_capacity(64 * 1024, file()?),
                start: None,
                line: Vec::with_capacity(256),
            },
            OutFormat::Blf => {
                Kind::Blf(BlfWriter::new(BufWriter::with_capacity(64 * 1024, file()?)))
            }
            OutFormat::Mf4 => Kind::Mf4(Box::new(Mf4Writer::new(
                BufWriter::with_capacity(256 * 1024, file()?),
                mf4,
            )?)),
        };
        Ok(LogWriter {
            kind,
            format,
            channels: Channels::default(),
            losses: Losses::default(),
            frames: 0,
        })
    }

    pub fn format(&self) -> OutFormat {
        self.format
    }

    /// Write one frame (in order of arrival).
    pub fn write(&mut self, f: &Frame) -> io::Result<()> {
        let lossy_error = f.kind == FrameKind::Error
            && (f.id != CAN_ERR_PROT || f.data[..8].iter().any(|&b| b != 0));
        match &mut self.kind {
            Kind::Candump(w) => w.write(f)?,
            Kind::Mf4(w) => w.write(f)?,
            Kind::Blf(w) => {
                let ch = self.channels.get(f.iface, &mut self.losses);
                let ch = u16::try_from(ch).map_err(|_| {
                    io::Error::new(io::ErrorKind::InvalidInput, "too many interfaces for BLF")
                })?;
                if let Some(s) = w.start_ns() {
                    self.losses.times_clamped += (f.t_ns < s) as u64;
                }
                self.losses.error_details += lossy_error as u64;
                w.write(f, ch)?;
            }
            Kind::Asc { w, start, line } => {
                let ch = self.channels.get(f.iface, &mut self.losses);
                let s = match *start {
                    Some(s) => s,
                    None => {
                        let s = f.t_ns.max(0) / 1_000_000 * 1_000_000;
                        w.write_all(asc::format_header(s).as_bytes())?;
                        *start = Some(s);
                        s
                    }
                };
                let off = f.t_ns - s;
                if off < 0 {
                    self.losses.times_clamped += 1;
                } else if off % 1000 != 0 {
                    self.losses.times_rounded += 1;
                }
                self.losses.error_details += lossy_error as u64;
                line.clear();
                asc::format_frame(f, off, ch, line);
                w.write_all(line)?;
            }
        }
        self.frames += 1;
        Ok(())
    }

    /// Frames written.
    pub fn frames(&self) -> u64 {
        self.frames
    }

    /// Finish the file (trailer, metadata, header patches) and report what was lost.
    pub fn finish(self) -> io::Result<Losses> {
        match self.kind {
            Kind::Candump(mut w) => w.flush()?,
            Kind::Mf4(w) => {
                w.finish()?.flush()?;
            }
            Kind::Blf(w) => {
                w.finish()?;
            }
            Kind::Asc { mut w, start, .. } => {
                if start.is_none() {
                    w.write_all(asc::format_header(0).as_bytes())?;
                }
                w.write_all(asc::FOOTER.as_bytes())?;
                w.flush()?;
            }
        }
        Ok(self.losses)
    }
}
