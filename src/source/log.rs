//! [`LogReader`]: a [`CanSource`] that replays a CAN log file, streaming, in constant memory
//! whatever the file's size. It recognises the format by content, then by extension:
//! an `MDF     ` or `UnFinMF ` identification is ASAM MDF 4 (bus logging, [`crate::wire::mf4`];
//! it needs a seekable file, so not gzip-compressed); a `LOGG` signature is Vector BLF; a Vector
//! ASC header (`date`, `base`, `Begin Triggerblock`)
//! is ASC; a `;$FILEVERSION` line is a PEAK TRC trace; otherwise `.blf` / `.asc` / `.trc`
//! extensions decide, and everything else is read as can-utils `candump -L`. A
//! gzip-compressed file (`.log.gz`, `.asc.gz`) is decompressed on the fly and the same rules
//! applied to its contents.
//!
//! Policy lives here, not in [`crate::wire`]: a malformed line or record is counted in
//! [`SourceStats::malformed`], and the first [`DEFAULT_MAX_REPORTS`] are reported through
//! [`CanSource::take_skips`] as `file:line` with the parser's reason; replay always goes on.
//! A last line without its newline that does not parse is reported as half-written.
//!
//! Not here: what a frame means (decoding), or pacing a replay in real time.

use super::lines::{Line, LineReader};
use super::{CanSource, Skip, SourceStats};
use crate::wire::asc::AscParser;
use crate::wire::blf::{BlfEvent, BlfReader};
use crate::wire::candump::{self, Parsed};
use crate::wire::frame::TextLine;
use crate::wire::mf4::{self, Mf4Reader, Mf4Step};
use crate::wire::trc::TrcParser;
use crate::wire::{Frame, FrameKind};
use std::fs::File;
use std::io::{self, Read, Seek};
use std::path::Path;

/// How many skips a reader reports in detail (all are counted).
pub const DEFAULT_MAX_REPORTS: usize = 100;

/// The log formats [`LogReader`] reads.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum LogFormat {
    /// can-utils `candump -L`.
    Candump,
    /// Vector ASC (text).
    Asc,
    /// Vector BLF (binary, zlib-compressed containers).
    Blf,
    /// ASAM MDF 4 bus logging (`.mf4`).
    Mf4,
    /// PEAK-System TRC trace (text, versions 1.0 to 2.1).
    Trc,
}

impl LogFormat {
    /// Decide the format from the first bytes of the file and its name.
    pub fn detect(name: &Path, head: &[u8]) -> LogFormat {
        if head.starts_with(b"LOGG") {
            return LogFormat::Blf;
        }
        if mf4::is_mdf4(head) {
            return LogFormat::Mf4;
        }
        let text = head.strip_prefix(b"\xEF\xBB\xBF").unwrap_or(head);
        let first = text
            .split(|&b| b == b'\n')
            .map(|l| l.trim_ascii())
            .find(|l| !l.is_empty())
            .unwrap_or(b"");
        let lower = |l: &[u8]| l.to_ascii_lowercase();
        let f = lower(first);
        if f.starts_with(b"date ")
            || f.starts_with(b"base ")
            || f.starts_with(b"begin triggerblock")
            || f.starts_with(b"// version")
        {
            return LogFormat::Asc;
        }
        if f.starts_with(b"(") || f.starts_with(b"dropcount") {
            return LogFormat::Candump;
        }
        if f.starts_with(b";$fileversion") {
            return LogFormat::Trc;
        }
        match name
            .extension()
            .and_then(|e| e.to_str())
            .map(|e| e.to_ascii_lowercase())
            .as_deref()
        {
            Some("blf") => LogFormat::Blf,
            Some("mf4") => LogFormat::Mf4,
            Some("asc") => LogFormat::Asc,
            Some("trc") => LogFormat::Trc,
            _ => LogFormat::Candump,
        }
    }
}

type BoxRead = Box<dyn Read + Send>;

/// A seekable byte source (what MF4 needs).
pub trait ReadSeek: Read + Seek + Send {}
impl<T: Read + Seek + Send> ReadSeek for T {}

enum Kind {
    Candump(LineReader<BoxRead>),
    Asc(LineReader<BoxRead>, AscParser),
    Trc(LineReader<BoxRead>, TrcParser),
    Blf(BlfReader<BoxRead>),
    Mf4(Box<Mf4Reader<Box<dyn ReadSeek>>>),
}

/// Replays a candump, ASC, BLF or MF4 log as a [`CanSource`].
pub struct LogReader {
    name: String,
    format: LogFormat,
    kind: Kind,
    stats: SourceStats,
    skips: Vec<Skip>,
    reported: usize,
    max_reports: usize,
    /// Timestamp of the last delivered frame (`i64::MIN` before the first).
    last_t: i64,
    /// An empty frame with the last interface name: `next_frame` starts from it (keeps the
    /// candump fast path's interface-name cache warm).
    scratch: Frame,
}

/// What one step of a reader produced, owned (so the line buffer's borrow can end).
enum Step {
    /// A frame, written into the caller's `out`.
    Frame,
    /// A frame written into `out` with data bytes the log did not hold, as 0.
    ZeroFilled,
    Nothing,
    Dropped(u64),
    Skipped(u64, String),
    Malformed(u64, String),
    End,
}

impl LogReader {
    /// Open a log file, detecting its format.
    pub fn open(path: impl AsRef<Path>) -> io::Result<LogReader> {
        Self::open_with(path, |file| file).map(|(reader, _)| reader)
    }

    /// As [`Self::open`], with the file of a format read as a stream (every format but MDF 4,
    /// which is read by seeking) read through `wrap(file)`: a layer that sees every byte the
    /// parser reads, such as a hash. Returns the reader and whether `wrap` was used.
    pub fn open_with<R: Read + Send + 'static>(
        path: impl AsRef<Path>,
        wrap: impl FnOnce(File) -> R,
    ) -> io::Result<(LogReader, bool)> {
        let path = path.as_ref();
        let mut file = File::open(path).map_err(|e| {
            io::Error::new(e.kind(), format!("cannot open {}: {e}", path.display()))
        })?;
        let mut head = [0u8; 8];
        let n = file.read(&mut head).unwrap_or(0);
        file.rewind()?;
        if mf4::is_mdf4(&head[..n]) {
            return Ok((Self::from_seekable(file, path)?, false));
        }
        Ok((Self::from_reader(wrap(file), path)?, true))
    }

    /// Read a log from a seekable reader (any format; MF4 needs one).
    pub fn from_seekable<R: Read + Seek + Send + 'static>(
        mut reader: R,
        name: impl AsRef<Path>,
    ) -> io::Result<LogReader> {
        let name = name.as_ref();
        let mut head = [0u8; 8];
        let mut n = 0;
        while n < 8 {
            match reader.read(&mut head[n..]) {
                Ok(0) => break,
                Ok(k) => n += k,
                Err(e) if e.kind() == io::ErrorKind::Interrupted => {}
                Err(e) => return Err(e),
            }
        }
        reader.rewind()?;
        if !mf4::is_mdf4(&head[..n]) {
            return Self::from_reader(reader, name);
        }
        let boxed: Box<dyn ReadSeek> = Box::new(reader);
        let m = Mf4Reader::open(boxed).map_err(|e| {
            io::Error::new(
                io::ErrorKind::InvalidData,
                format!("{}: cannot read as MDF 4: {e}", name.display()),
            )
        })?;
        let warnings: Vec<String> = m.warnings().to_vec();
        let mut r = Self::with_kind(Kind::Mf4(Box::new(m)), name, LogFormat::Mf4);
        for w in warnings {
            r.stats.malformed += 1;
            r.report(0, "metadata ", w);
        }
        Ok(r)
    }

    /// Read a log from any reader; `name` is used for format detection (extension) and in
    /// skip reports.
    pub fn from_reader<R: Read + Send + 'static>(
        mut reader: R,
        name: impl AsRef<Path>,
    ) -> io::Result<LogReader> {
        let name = name.as_ref();
        let mut head = vec![0u8; 512];
        let mut n = 0;
        while n < head.len() {
            match reader.read(&mut head[n..]) {
                Ok(0) => break,
                Ok(k) => n += k,
                Err(e) if e.kind() == io::ErrorKind::Interrupted => continue,
                Err(e) => return Err(e),
            }
        }
        head.truncate(n);
        if mf4::is_mdf4(&head) {
            return Err(io::Error::new(
                io::ErrorKind::InvalidInput,
                format!(
                    "{}: an MDF 4 file must be read from a seekable file (not a pipe or gzip)",
                    name.display()
                ),
            ));
        }
        let chained: BoxRead = Box::new(io::Cursor::new(head.clone()).chain(reader));
        if head.starts_with(&[0x1F, 0x8B]) {
            // gzip-compressed log (`.log.gz`, `.asc.gz`...): decompress on the fly (32 KiB
            // window, still constant memory) and detect the format inside.
            let inner = flate2::read::MultiGzDecoder::new(chained);
            let mut r = Self::from_reader(inner, name.with_extension(""))?;
            r.name = name.display().to_string();
            return Ok(r);
        }
        let format = LogFormat::detect(name, &head);
        Ok(Self::with_format(chained, name, format))
    }

    /// Read a log in a known format.
    pub fn with_format(
        reader: Box<dyn Read + Send>,
        name: impl AsRef<Path>,
        format: LogFormat,
    ) -> LogReader {
        let kind = match format {
            LogFormat::Candump => Kind::Candump(LineReader::new(reader)),
            LogFormat::Asc => Kind::Asc(LineReader::new(reader), AscParser::new()),
            LogFormat::Trc => Kind::Trc(LineReader::new(reader), TrcParser::new()),
            LogFormat::Blf => Kind::Blf(BlfReader::new(reader)),
            // Not seekable: read as candump, which reports every record as malformed.
            LogFormat::Mf4 => Kind::Candump(LineReader::new(reader)),
        };
        Self::with_kind(kind, name, format)
    }

    fn with_kind(kind: Kind, name: impl AsRef<Path>, format: LogFormat) -> LogReader {
        LogReader {
            name: name.as_ref().display().to_string(),
            format,
            kind,
            stats: SourceStats::default(),
            skips: Vec::new(),
            reported: 0,
            max_reports: DEFAULT_MAX_REPORTS,
            last_t: i64::MIN,
            scratch: Frame::empty(0),
        }
    }

    /// Report at most `n` skips in detail (all are still counted).
    pub fn with_max_reports(mut self, n: usize) -> LogReader {
        self.max_reports = n;
        self
    }

    /// The detected format.
    pub fn format(&self) -> LogFormat {
        self.format
    }

    /// For ASC, TRC, BLF and MF4: the wall-clock start of the measurement in ns since the Unix
    /// epoch (as the file's header states it, read as UTC), which the frame timestamps include.
    pub fn start_epoch_ns(&self) -> Option<i64> {
        match &self.kind {
            Kind::Candump(_) => None,
            Kind::Asc(_, p) => p.start_epoch_ns(),
            Kind::Trc(_, p) => p.start_epoch_ns(),
            Kind::Blf(b) => b.start_epoch_ns(),
            Kind::Mf4(m) => Some(m.start_epoch_ns()),
        }
    }

    /// For MF4: the acquisition name of the channel group of the last frame read.
    pub fn mf4_group(&self) -> Option<&str> {
        match &self.kind {
            Kind::Mf4(m) => Some(m.last_group()),
            _ => None,
        }
    }

    fn report(&mut self, where_: u64, unit: &str, reason: String) {
        if self.reported < self.max_reports {
            self.reported += 1;
            self.skips.push(Skip {
                location: format!("{}:{unit}{where_}", self.name),
                reason,
            });
        }
    }

    /// One line or record; a frame is written into `out`.
    fn step(&mut self, out: &mut Frame) -> io::Result<Step> {
        match &mut self.kind {
            Kind::Candump(lines) => {
                let (bytes, terminated) = match next_text(lines)? {
                    Ok(text) => text,
                    Err(step) => return Ok(step),
                };
                // Fast path for the common line shape, straight into `out`; every other line
                // (and every error) goes through the full grammar.
                if candump::parse_common_into(bytes, out) {
                    return Ok(Step::Frame);
                }
                Ok(match candump::parse_line_full(bytes) {
                    Ok(Parsed::Frame(f)) => {
                        *out = f;
                        Step::Frame
                    }
                    Ok(Parsed::Comment) => Step::Nothing,
                    Ok(Parsed::DropCount(n)) => Step::Dropped(n),
                    Ok(Parsed::SkippedXl) => {
                        Step::Skipped(lines.line_no(), "CAN XL frame (not supported)".into())
                    }
                    Err(e) => Step::Malformed(lines.line_no(), half_written(e, terminated)),
                })
            }
            Kind::Asc(lines, parser) => {
                let (bytes, terminated) = match next_text(lines)? {
                    Ok(text) => text,
                    Err(step) => return Ok(step),
                };
                Ok(text_step(
                    parser.parse_line(bytes),
                    out,
                    lines.line_no(),
                    terminated,
                ))
            }
            Kind::Trc(lines, parser) => {
                let (bytes, terminated) = match next_text(lines)? {
                    Ok(text) => text,
                    Err(step) => return Ok(step),
                };
                Ok(text_step(
                    parser.parse_line(bytes),
                    out,
                    lines.line_no(),
                    terminated,
                ))
            }
            Kind::Blf(blf) => Ok(match blf.next_event()? {
                Some(Ok(BlfEvent::Frame(f))) => {
                    *out = f;
                    Step::Frame
                }
                Some(Ok(BlfEvent::ZeroFilled { frame, .. })) => {
                    *out = frame;
                    Step::ZeroFilled
                }
                Some(Ok(BlfEvent::Other)) => Step::Skipped(0, String::new()),
                Some(Err(e)) => Step::Malformed(blf.object_index(), e.to_string()),
                None => Step::End,
            }),
            Kind::Mf4(m) => {
                let at = self.stats.frames + self.stats.skipped + self.stats.malformed + 1;
                Ok(match m.next_into(out)? {
                    Mf4Step::Frame => Step::Frame,
                    Mf4Step::Other => Step::Skipped(0, String::new()),
                    Mf4Step::Error(e) => Step::Malformed(at, e.to_string()),
                    Mf4Step::End => Step::End,
                })
            }
        }
    }
}

/// The step of a text log's line (ASC, TRC), `line_no` its number.
fn text_step<E: std::fmt::Display>(
    line: Result<TextLine, E>,
    out: &mut Frame,
    line_no: u64,
    terminated: bool,
) -> Step {
    match line {
        Ok(TextLine::Frame(f)) => {
            *out = f;
            Step::Frame
        }
        Ok(TextLine::Header) => Step::Nothing,
        Ok(TextLine::OtherEvent) => Step::Skipped(0, String::new()),
        Err(e) => Step::Malformed(line_no, half_written(e, terminated)),
    }
}

fn half_written(e: impl std::fmt::Display, terminated: bool) -> String {
    if terminated {
        e.to_string()
    } else {
        format!("half-written last line (no newline at end of file): {e}")
    }
}

impl LogReader {
    /// Count a delivered frame.
    #[inline]
    fn count(&mut self, kind: FrameKind, t_ns: i64) {
        self.stats.frames += 1;
        if kind == FrameKind::Error {
            self.stats.error_frames += 1;
        }
        if t_ns < self.last_t {
            self.stats.backwards_timestamps += 1;
        }
        self.last_t = t_ns;
    }
}

impl CanSource for LogReader {
    fn next_frame(&mut self) -> io::Result<Option<Frame>> {
        // `scratch` is an empty frame carrying the last interface name, so the candump fast
        // path finds its name cache warm and a data array that is already zero.
        let mut f = self.scratch;
        if self.read_frame(&mut f)? {
            self.scratch.iface = f.iface;
            Ok(Some(f))
        } else {
            Ok(None)
        }
    }

    // `#[inline]` lets callers in other crates (benchmarks, the daemon) inline the hot path;
    // the general path stays in the out-of-line `read_frame_slow`.
    #[inline]
    fn read_frame(&mut self, out: &mut Frame) -> io::Result<bool> {
        // Candump hot path: parse the common line shape straight out of the read buffer into
        // `out`. Anything else (comments, DROPCOUNT, errors, CAN XL, a line spanning a refill,
        // end of input) falls through to the general step below, which sees the same line.
        if let Kind::Candump(lines) = &mut self.kind {
            if lines.try_parse_prefix(|b| candump::parse_common_prefix(b, out))
                || lines.try_parse_next(|l| candump::parse_common_into(l, out))
            {
                self.count(out.kind, out.t_ns);
                return Ok(true);
            }
        }
        self.read_frame_slow(out)
    }

    fn stats(&self) -> SourceStats {
        self.stats.clone()
    }

    fn take_skips(&mut self) -> Vec<Skip> {
        std::mem::take(&mut self.skips)
    }
}

impl LogReader {
    /// Everything but the candump fast path: one line or record at a time until a frame.
    #[inline(never)]
    fn read_frame_slow(&mut self, out: &mut Frame) -> io::Result<bool> {
        loop {
            match self.step(out)? {
                Step::Frame => {
                    self.count(out.kind, out.t_ns);
                    return Ok(true);
                }
                Step::ZeroFilled => {
                    self.stats.zero_filled += 1;
                    self.count(out.kind, out.t_ns);
                    return Ok(true);
                }
                Step::Nothing => {}
                Step::Dropped(n) => self.stats.dropped = self.stats.dropped.saturating_add(n),
                Step::Skipped(at, reason) => {
                    self.stats.skipped += 1;
                    if !reason.is_empty() {
                        self.report(at, "", reason);
                    }
                }
                Step::Malformed(at, reason) => {
                    self.stats.malformed += 1;
                    let unit = match self.format {
                        LogFormat::Blf => "object ",
                        LogFormat::Mf4 => "record ",
                        _ => "",
                    };
                    self.report(at, unit, reason);
                }
                Step::End => return Ok(false),
            }
        }
    }
}

/// The next text line of a line-based log with whether it ended in a newline, or the step
/// to report instead (end of input, or a line too long to hold).
fn next_text(lines: &mut LineReader<BoxRead>) -> io::Result<Result<(&[u8], bool), Step>> {
    // Every line the reader returns, a too-long one included, advances the count by one.
    let line_no = lines.line_no() + 1;
    Ok(match lines.next_line()? {
        None => Err(Step::End),
        Some(Line::TooLong) => Err(Step::Malformed(line_no, "line longer than 256 KiB".into())),
        Some(Line::Text { bytes, terminated }) => Ok((bytes, terminated)),
    })
}
