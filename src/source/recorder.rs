//! Recording frames as `candump -L` logs: [`CandumpWriter`] writes frames (firmware-sim and the
//! tests record with it), and [`Recorder`] is a layer that tees any [`CanSource`] into such a
//! writer while passing every frame on unchanged.
//!
//! Not here: the line format itself ([`crate::wire::candump`]) or any filtering.

use super::{CanSource, Skip, SourceStats};
use crate::wire::candump::format_frame;
use crate::wire::{Frame, IfaceName};
use std::fs::File;
use std::io::{self, BufWriter, Write};
use std::path::Path;

/// Writes frames as canonical `candump -L` lines through a 64 KiB buffer (no allocation per
/// frame). Call [`CandumpWriter::flush`] (or drop it) to push out the last lines.
pub struct CandumpWriter<W: Write> {
    w: BufWriter<W>,
    default_iface: Option<IfaceName>,
    frames: u64,
}

impl CandumpWriter<File> {
    /// Create (truncate) a log file.
    pub fn create(path: impl AsRef<Path>) -> io::Result<Self> {
        let path = path.as_ref();
        let f = File::create(path).map_err(|e| {
            io::Error::new(e.kind(), format!("cannot create {}: {e}", path.display()))
        })?;
        Ok(Self::new(f))
    }
}

impl<W: Write> CandumpWriter<W> {
    pub fn new(w: W) -> Self {
        CandumpWriter {
            w: BufWriter::with_capacity(64 * 1024, w),
            default_iface: None,
            frames: 0,
        }
    }

    /// Interface name written for frames that carry none (candump needs one); without it such
    /// frames are refused with `InvalidInput`.
    pub fn with_default_iface(mut self, name: &str) -> Self {
        self.default_iface = Some(IfaceName::from_str_truncated(name));
        self
    }

    /// Write one frame. `InvalidInput` for a frame the format cannot hold (negative
    /// timestamp, no interface name and no default); nothing is written then.
    pub fn write(&mut self, f: &Frame) -> io::Result<()> {
        let mut buf = [0u8; 256];
        let n = if f.iface.is_empty() {
            match self.default_iface {
                Some(name) => {
                    let mut g = *f;
                    g.iface = name;
                    format_frame(&g, &mut buf)?
                }
                None => format_frame(f, &mut buf)?,
            }
        } else {
            format_frame(f, &mut buf)?
        };
        self.w.write_all(&buf[..n])?;
        self.frames += 1;
        Ok(())
    }

    /// Write a `# comment` line (newlines in `text` are replaced by spaces).
    pub fn write_comment(&mut self, text: &str) -> io::Result<()> {
        self.w.write_all(b"# ")?;
        for part in text.split(['\n', '\r']) {
            self.w.write_all(part.as_bytes())?;
            self.w.write_all(b" ")?;
        }
        self.w.write_all(b"\n")
    }

    /// Frames written so far.
    pub fn frames_written(&self) -> u64 {
        self.frames
    }

    pub fn flush(&mut self) -> io::Result<()> {
        self.w.flush()
    }

    /// Flush and return the underlying writer.
    pub fn into_inner(self) -> io::Result<W> {
        self.w.into_inner().map_err(|e| e.into_error())
    }
}

/// A layer that records every frame its source yields, then passes it on.
///
/// Frames the candump format cannot hold are passed on but not recorded; they are counted
/// ([`Recorder::not_recorded`]) and reported through `take_skips` with location `recorder`.
/// A failing write (disk full...) is returned as the `Err` of `next_frame`.
pub struct Recorder<S, W: Write> {
    inner: S,
    writer: CandumpWriter<W>,
    not_recorded: u64,
    skips: Vec<Skip>,
}

impl<S: CanSource, W: Write> Recorder<S, W> {
    pub fn new(inner: S, writer: CandumpWriter<W>) -> Self {
        Recorder {
            inner,
            writer,
            not_recorded: 0,
            skips: Vec::new(),
        }
    }

    /// Frames passed on but not recorded.
    pub fn not_recorded(&self) -> u64 {
        self.not_recorded
    }

    /// Frames recorded.
    pub fn recorded(&self) -> u64 {
        self.writer.frames_written()
    }

    /// Flush the log and return the source and the writer.
    pub fn finish(mut self) -> io::Result<(S, CandumpWriter<W>)> {
        self.writer.flush()?;
        Ok((self.inner, self.writer))
    }
}

impl<S: CanSource, W: Write> CanSource for Recorder<S, W> {
    fn next_frame(&mut self) -> io::Result<Option<Frame>> {
        let Some(f) = self.inner.next_frame()? else {
            self.writer.flush()?;
            return Ok(None);
        };
        match self.writer.write(&f) {
            Ok(()) => {}
            Err(e) if e.kind() == io::ErrorKind::InvalidInput => {
                self.not_recorded += 1;
                if self.skips.len() < super::log::DEFAULT_MAX_REPORTS {
                    self.skips.push(Skip {
                        location: "recorder".into(),
                        reason: format!("frame at t={} ns not recorded: {e}", f.t_ns),
                    });
                }
            }
            Err(e) => return Err(e),
        }
        Ok(Some(f))
    }

    fn stats(&self) -> SourceStats {
        self.inner.stats()
    }

    fn take_skips(&mut self) -> Vec<Skip> {
        let mut v = self.inner.take_skips();
        v.append(&mut self.skips);
        v
    }
}
