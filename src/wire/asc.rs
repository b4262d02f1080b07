//! Vector ASC (ASCII log) lines: the header lines that set how events are written
//! (`base hex|dec`, `timestamps absolute|relative`, `Begin Triggerblock <date>`) and the CAN
//! event lines, parsed one at a time by a small stateful [`AscParser`].
//!
//! Events read (`<t>` is seconds, `<ch>` the 1-based channel, `x` after an ID marks it
//! extended):
//!
//! ```text
//! <t> <ch> <id>[x] Rx|Tx d <dlc> <b0> .. <bn> [Length = .. BitCount = .. ID = ..]
//! <t> <ch> <id>[x] Rx|Tx r [<dlc>] [...]
//! <t> <ch> ErrorFrame [...]
//! <t> CANFD <ch> Rx|Tx <id>[x] [<name>] <brs> <esi> <dlc> <len> <b0> .. <bn> [...]
//! <t> CANFD <ch> Rx|Tx ErrorFrame [...]
//! ```
//!
//! Mapping choices (documented because the formats differ from SocketCAN):
//! - channel N becomes interface `can{N-1}` (python-can's convention: channel 1 is `can0`);
//! - an `ErrorFrame` becomes a [`FrameKind::Error`] frame with class `CAN_ERR_PROT` (0x08),
//!   as ASC carries no SocketCAN error class;
//! - a classic `d` line with DLC 9–F and 8 bytes keeps the raw DLC; a DLC or length above 8
//!   with more bytes than 8 is a CAN FD frame (python-can writes FD frames that way);
//! - a `CANFD` line with data length 0 and a non-zero DLC is a remote request, delivered as a
//!   classic remote frame (CAN FD has no remote frames);
//! - frame times are the `Begin Triggerblock` wall-clock time (read as UTC, ms resolution)
//!   plus the event offset, so [`AscParser::start_epoch_ns`] tells the epoch used.
//!
//! Other events (status, statistics, J1939 transport, LIN, system variables...) are
//! recognised as [`AscLine::OtherEvent`]: the caller counts them as skipped.
//!
//! Not here: reading files or deciding what a bad line means ([`crate::source::log`]).

use super::frame::{fd_dlc_to_len, fd_len_to_dlc, ChannelNames, Frame, FrameKind, IfaceName};

/// `CAN_ERR_PROT`: the SocketCAN error class used for ASC/BLF error frames.
pub const CAN_ERR_PROT: u32 = 0x08;

/// What one ASC line holds.
pub type AscLine = super::frame::TextLine;

/// What is wrong with an ASC line.
#[derive(Clone, Debug, PartialEq, Eq, thiserror::Error)]
pub enum AscError {
    #[error("not an ASC header or event line")]
    NotAscLine,
    #[error("bad timestamp {0:?}")]
    Timestamp(String),
    #[error("bad channel {0:?}")]
    Channel(String),
    #[error("bad CAN ID {0:?}")]
    Id(String),
    #[error("CAN ID {0:#X} out of range for a {1}-bit ID")]
    IdRange(u32, u32),
    #[error("expected Rx or Tx, found {0:?}")]
    Direction(String),
    #[error("expected 'd' (data) or 'r' (remote), found {0:?}")]
    FrameType(String),
    #[error("bad DLC {0:?}")]
    Dlc(String),
    #[error("bad data length {0:?}")]
    DataLength(String),
    #[error("expected {expected} data bytes, found {found}")]
    MissingData { expected: usize, found: usize },
    #[error("bad data byte {0:?}")]
    Byte(String),
    #[error("bad BRS/ESI flag {0:?} (expected 0 or 1)")]
    Flag(String),
    #[error("line ends early: missing {0}")]
    Truncated(&'static str),
}

/// Parser state carried from the header to the events.
#[derive(Clone, Debug)]
pub struct AscParser {
    hex: bool,
    relative: bool,
    start_ns: Option<i64>,
    last_t_ns: i64,
    ifaces: ChannelNames,
}

impl Default for AscParser {
    fn default() -> Self {
        Self::new()
    }
}

/// The white-space separated tokens of a text log line (ASC, TRC).
pub(crate) fn tokens(line: &[u8]) -> impl Iterator<Item = &[u8]> {
    line.split(|&b| b == b' ' || b == b'\t')
        .filter(|t| !t.is_empty())
}

/// A token as text for an error message.
pub(crate) fn lossy(t: &[u8]) -> String {
    String::from_utf8_lossy(t).into_owned()
}

impl AscParser {
    /// A parser with the ASC defaults (hex base, absolute timestamps).
    pub fn new() -> AscParser {
        AscParser {
            hex: true,
            relative: false,
            start_ns: None,
            last_t_ns: 0,
            ifaces: ChannelNames::new(),
        }
    }

    /// Wall-clock start of the trigger block (ns since the Unix epoch, header read as UTC).
    pub fn start_epoch_ns(&self) -> Option<i64> {
        self.start_ns
    }

    /// Parse one line (a trailing `\r` is ignored).
    pub fn parse_line(&mut self, line: &[u8]) -> Result<AscLine, AscError> {
        let line = line.trim_ascii();
        if line.is_empty() || line.starts_with(b"//") {
            return Ok(AscLine::Header);
        }
        let first = line[0];
        if !(first.is_ascii_digit()) {
            return self.header(line);
        }
        let mut tk = tokens(line);
        let t_tok = tk.next().unwrap_or(b"");
        let t_rel = parse_time_ns(t_tok).ok_or_else(|| AscError::Timestamp(lossy(t_tok)))?;
        let t_ns = if self.relative {
            self.last_t_ns.saturating_add(t_rel)
        } else {
            self.start_ns.unwrap_or(0).saturating_add(t_rel)
        };
        self.last_t_ns = t_ns;
        let Some(tok) = tk.next() else {
            return Err(AscError::Truncated("the event after the timestamp"));
        };
        if tok.eq_ignore_ascii_case(b"CANFD") {
            return self.canfd(t_ns, tk);
        }
        if tok.eq_ignore_ascii_case(b"Start") {
            // "Start of measurement"
            return Ok(AscLine::Header);
        }
        if !tok.iter().all(u8::is_ascii_digit) {
            // "CAN 1 Status:...", LIN/system events...
            return Ok(AscLine::OtherEvent);
        }
        let ch = parse_channel(tok)?;
        let Some(id_tok) = tk.next() else {
            return Ok(AscLine::OtherEvent);
        };
        if id_tok.eq_ignore_ascii_case(b"ErrorFrame") {
            return Ok(AscLine::Frame(self.error_frame(t_ns, ch)));
        }
        let Some((id, ext)) = self.parse_id(id_tok) else {
            // Statistic:, J1939TP, ... : not a CAN frame.
            return Ok(AscLine::OtherEvent);
        };
        let mut f = Frame::empty(t_ns);
        f.iface = self.iface(ch);
        set_id(&mut f, id, ext)?;
        let dir = tk.next().ok_or(AscError::Truncated("Rx/Tx"))?;
        if !(dir.eq_ignore_ascii_case(b"Rx") || dir.eq_ignore_ascii_case(b"Tx")) {
            return Err(AscError::Direction(lossy(dir)));
        }
        let ty = tk.next().ok_or(AscError::Truncated("'d' or 'r'"))?;
        match ty {
            b"r" | b"R" => {
                f.kind = FrameKind::Remote;
                if let Some(d) = tk.next() {
                    if let Some(dlc) = self.num(d).filter(|&d| d <= 15) {
                        f.dlc = dlc as u8;
                        f.len = dlc.min(8) as u8;
                    }
                }
                Ok(AscLine::Frame(f))
            }
            b"d" | b"D" => {
                let d = tk.next().ok_or(AscError::Truncated("the DLC"))?;
                let dlc = self.num(d).ok_or_else(|| AscError::Dlc(lossy(d)))? as usize;
                let want = match dlc {
                    0..=8 => dlc,
                    9..=15 => fd_dlc_to_len(dlc as u8),
                    _ if fd_dlc_to_len(fd_len_to_dlc(dlc)) == dlc => dlc,
                    _ => return Err(AscError::Dlc(lossy(d))),
                };
                let n = self.read_bytes(&mut f.data, want, &mut tk)?;
                if n == want && dlc > 8 {
                    f.fd = true;
                    f.len = n as u8;
                    f.dlc = fd_len_to_dlc(n);
                } else if n == 8 && (9..=15).contains(&dlc) {
                    f.len = 8;
                    f.dlc = dlc as u8;
                } else if n == want {
                    f.len = n as u8;
                    f.dlc = n as u8;
                } else {
                    return Err(AscError::MissingData {
                        expected: want,
                        found: n,
                    });
                }
                Ok(AscLine::Frame(f))
            }
            other => Err(AscError::FrameType(lossy(other))),
        }
    }

    fn header(&mut self, line: &[u8]) -> Result<AscLine, AscError> {
        let lower = line.to_ascii_lowercase();
        if lower.starts_with(b"base ") {
            let mut tk = tokens(&lower).skip(1);
            if let Some(b) = tk.next() {
                self.hex = b != b"dec";
            }
            if let (Some(b"timestamps"), Some(mode)) = (tk.next(), tk.next()) {
                self.relative = mode == b"relative";
            }
            return Ok(AscLine::Header);
        }
        if lower.starts_with(b"begin triggerblock") {
            let rest = &line[b"begin triggerblock".len()..];
            if let Some(t) = parse_date(rest) {
                self.start_ns = Some(t);
            }
            self.last_t_ns = self.start_ns.unwrap_or(0);
            return Ok(AscLine::Header);
        }
        if lower.starts_with(b"date ") {
            if self.start_ns.is_none() {
                self.start_ns = parse_date(&line[5..]);
                self.last_t_ns = self.start_ns.unwrap_or(0);
            }
            return Ok(AscLine::Header);
        }
        if lower.starts_with(b"end triggerblock")
            || lower.ends_with(b"internal events logged")
            || lower.starts_with(b"start of measurement")
        {
            return Ok(AscLine::Header);
        }
        Err(AscError::NotAscLine)
    }

    fn iface(&self, ch: u32) -> IfaceName {
        self.ifaces.get(ch)
    }

    fn error_frame(&self, t_ns: i64, ch: u32) -> Frame {
        let mut f = Frame::empty(t_ns);
        f.iface = self.iface(ch);
        f.kind = FrameKind::Error;
        f.id = CAN_ERR_PROT;
        f.len = 8;
        f.dlc = 8;
        f
    }

    fn num(&self, t: &[u8]) -> Option<u32> {
        parse_uint(t, if self.hex { 16 } else { 10 })
    }

    fn parse_id(&self, t: &[u8]) -> Option<(u32, bool)> {
        let (digits, ext) = match t.last() {
            Some(b'x' | b'X') => (&t[..t.len() - 1], true),
            _ => (t, false),
        };
        Some((self.num(digits)?, ext))
    }

    fn read_bytes<'a>(
        &self,
        out: &mut [u8; 64],
        want: usize,
        tk: &mut impl Iterator<Item = &'a [u8]>,
    ) -> Result<usize, AscError> {
        let mut n = 0;
        while n < want {
            let Some(b) = tk.next() else { break };
            match self.num(b).filter(|&v| v <= 0xFF && b.len() <= 3) {
                Some(v) => out[n] = v as u8,
                // "Length = ..." after 8 bytes of a DLC 9–F classic frame ends the data.
                None if n == 8 => break,
                None => return Err(AscError::Byte(lossy(b))),
            }
            n += 1;
        }
        Ok(n)
    }

    fn canfd<'a>(
        &self,
        t_ns: i64,
        mut tk: impl Iterator<Item = &'a [u8]>,
    ) -> Result<AscLine, AscError> {
        let ch_tok = tk.next().ok_or(AscError::Truncated("the channel"))?;
        let ch = parse_channel(ch_tok)?;
        let dir = tk.next().ok_or(AscError::Truncated("Rx/Tx"))?;
        if !(dir.eq_ignore_ascii_case(b"Rx") || dir.eq_ignore_ascii_case(b"Tx")) {
            return Err(AscError::Direction(lossy(dir)));
        }
        let id_tok = tk.next().ok_or(AscError::Truncated("the CAN ID"))?;
        if id_tok.eq_ignore_ascii_case(b"ErrorFrame") {
            return Ok(AscLine::Frame(self.error_frame(t_ns, ch)));
        }
        let (id, ext) = self
            .parse_id(id_tok)
            .ok_or_else(|| AscError::Id(lossy(id_tok)))?;
        let mut f = Frame::empty(t_ns);
        f.iface = self.iface(ch);
        set_id(&mut f, id, ext)?;
        // An optional symbolic name sits before the BRS flag; flags are single digits.
        let mut brs = tk.next().ok_or(AscError::Truncated("BRS"))?;
        if !brs.iter().all(u8::is_ascii_digit) {
            brs = tk.next().ok_or(AscError::Truncated("BRS"))?;
        }
        let esi = tk.next().ok_or(AscError::Truncated("ESI"))?;
        let flag = |t: &[u8]| match t {
            b"0" => Ok(false),
            b"1" => Ok(true),
            _ => Err(AscError::Flag(lossy(t))),
        };
        f.brs = flag(brs)?;
        f.esi = flag(esi)?;
        let d = tk.next().ok_or(AscError::Truncated("the DLC"))?;
        let dlc = parse_uint(d, 16)
            .filter(|&v| v <= 15)
            .ok_or_else(|| AscError::Dlc(lossy(d)))?;
        let l = tk.next().ok_or(AscError::Truncated("the data length"))?;
        // A CAN FD frame carries 0–8, 12, 16, 20, 24, 32, 48 or 64 bytes; any other length
        // cannot have been on the bus.
        let len = parse_uint(l, 10)
            .filter(|&v| v <= 64 && fd_dlc_to_len(fd_len_to_dlc(v as usize)) == v as usize)
            .ok_or_else(|| AscError::DataLength(lossy(l)))? as usize;
        if len == 0 && dlc > 0 {
            f.kind = FrameKind::Remote;
            f.brs = false;
            f.esi = false;
            f.dlc = dlc as u8;
            f.len = dlc.min(8) as u8;
            return Ok(AscLine::Frame(f));
        }
        let mut n = 0;
        while n < len {
            let Some(b) = tk.next() else { break };
            f.data[n] = parse_uint(b, if self.hex { 16 } else { 10 })
                .filter(|&v| v <= 0xFF)
                .ok_or_else(|| AscError::Byte(lossy(b)))? as u8;
            n += 1;
        }
        if n < len {
            return Err(AscError::MissingData {
                expected: len,
                found: n,
            });
        }
        f.fd = true;
        f.len = len as u8;
        f.dlc = fd_len_to_dlc(len);
        Ok(AscLine::Frame(f))
    }
}

fn set_id(f: &mut Frame, id: u32, ext: bool) -> Result<(), AscError> {
    let max = if ext { 0x1FFF_FFFF } else { 0x7FF };
    if id > max {
        return Err(AscError::IdRange(id, if ext { 29 } else { 11 }));
    }
    f.id = id;
    f.extended = ext;
    Ok(())
}

fn parse_channel(t: &[u8]) -> Result<u32, AscError> {
    parse_uint(t, 10)
        .filter(|&c| c >= 1)
        .ok_or_else(|| AscError::Channel(lossy(t)))
}

fn parse_uint(t: &[u8], radix: u32) -> Option<u32> {
    if t.is_empty() || t.len() > 10 {
        return None;
    }
    let mut v: u64 = 0;
    for &b in t {
        let d = (b as char).to_digit(radix)? as u64;
        v = v * radix as u64 + d;
    }
    u32::try_from(v).ok()
}

/// `S[.F]` seconds (`.` or `,` as decimal mark, up to 9 fraction digits) to ns.
fn parse_time_ns(t: &[u8]) -> Option<i64> {
    let mut parts = t.splitn(2, |&b| b == b'.' || b == b',');
    let s = parts.next()?;
    if s.is_empty() || s.len() > 12 || !s.iter().all(u8::is_ascii_digit) {
        return None;
    }
    let mut ns: i64 = 0;
    for &b in s {
        ns = ns * 10 + (b - b'0') as i64;
    }
    let mut ns = ns.checked_mul(1_000_000_000)?;
    if let Some(f) = parts.next() {
        if f.len() > 9 || !f.iter().all(u8::is_ascii_digit) {
            return None;
        }
        let mut frac: i64 = 0;
        for &b in f {
            frac = frac * 10 + (b - b'0') as i64;
        }
        ns = ns.checked_add(frac * 10i64.pow(9 - f.len() as u32))?;
    }
    Some(ns)
}

/// `[weekday] Mon DD hh:mm:ss[.mmm] [am|pm] YYYY` as ns since the Unix epoch (UTC).
/// English and German month abbreviations.
pub fn parse_date(s: &[u8]) -> Option<i64> {
    let toks: Vec<String> = tokens(s)
        .map(|t| String::from_utf8_lossy(t).to_ascii_lowercase())
        .collect();
    let month_of = |m: &str| -> Option<u32> {
        Some(match m.get(..3)? {
            "jan" => 1,
            "feb" => 2,
            "mar" | "mär" | "mrz" => 3,
            "apr" => 4,
            "may" | "mai" => 5,
            "jun" => 6,
            "jul" => 7,
            "aug" => 8,
            "sep" => 9,
            "oct" | "okt" => 10,
            "nov" => 11,
            "dec" | "dez" => 12,
            _ => return None,
        })
    };
    let mi = toks.iter().position(|t| month_of(t).is_some())?;
    let month = month_of(&toks[mi])?;
    let day: u32 = toks.get(mi + 1)?.parse().ok()?;
    let time = toks.get(mi + 2)?;
    let mut rest = toks[mi + 3..].iter();
    let mut next = rest.next()?;
    let mut ampm = None;
    if next == "am" || next == "pm" {
        ampm = Some(next == "pm");
        next = rest.next()?;
    }
    let year: i64 = next.parse().ok().filter(|y| (1..=9999).contains(y))?;
    let mut tp = time.split(':');
    let mut h: i64 = tp.next()?.parse().ok()?;
    let m: i64 = tp.next()?.parse().ok()?;
    let sec_tok = tp.next()?;
    let sec_ns = parse_time_ns(sec_tok.as_bytes())?;
    if let Some(pm) = ampm {
        h %= 12;
        if pm {
            h += 12;
        }
    }
    if !(1..=31).contains(&day) || h > 23 || m > 59 {
        return None;
    }
    let days = days_from_civil(year, month, day);
    (days * 86_400 + h * 3600 + m * 60)
        .checked_mul(1_000_000_000)?
        .checked_add(sec_ns)
}

/// Days since 1970-01-01 of a proleptic Gregorian date.
pub fn days_from_civil(y: i64, m: u32, d: u32) -> i64 {
    let y = if m <= 2 { y - 1 } else { y };
    let era = y.div_euclid(400);
    let yoe = y - era * 400;
    let m = m as i64;
    let doy = (153 * (if m > 2 { m - 3 } else { m + 9 }) + 2) / 5 + d as i64 - 1;
    let doe = yoe * 365 + yoe / 4 - yoe / 100 + doy;
    era * 146_097 + doe - 719_468
}

/// Civil date (year, month, day) of a day count since 1970-01-01 (inverse of
/// [`days_from_civil`]).
pub fn civil_from_days(z: i64) -> (i64, u32, u32) {
    let z = z + 719_468;
    let era = z.div_euclid(146_097);
    let doe = z - era * 146_097;
    let yoe = (doe - doe / 1460 + doe / 36_524 - doe / 146_096) / 365;
    let doy = doe - (365 * yoe + yoe / 4 - yoe / 100);
    let mp = (5 * doy + 2) / 153;
    let d = (doy - (153 * mp + 2) / 5 + 1) as u32;
    let m = if mp < 10 { mp + 3 } else { mp - 9 } as u32;
    let y = yoe + era * 400 + (m <= 2) as i64;
    (y, m, d)
}

/// `Thu Jan 01 00:00:00.000 1970`: an ASC date (UTC, millisecond resolution; `epoch_ns` is
/// truncated to the millisecond, and must not be negative).
pub fn format_date(epoch_ns: i64) -> String {
    const WD: [&str; 7] = ["Thu", "Fri", "Sat", "Sun", "Mon", "Tue", "Wed"];
    const MO: [&str; 12] = [
        "Jan", "Feb", "Mar", "Apr", "May", "Jun", "Jul", "Aug", "Sep", "Oct", "Nov", "Dec",
    ];
    let ms = epoch_ns.max(0) / 1_000_000;
    let days = ms.div_euclid(86_400_000);
    let rem = ms.rem_euclid(86_400_000);
    let (y, m, d) = civil_from_days(days);
    format!(
        "{} {} {:02} {:02}:{:02}:{:02}.{:03} {}",
        WD[days.rem_euclid(7) as usize],
        MO[m as usize - 1],
        d,
        rem / 3_600_000,
        rem / 60_000 % 60,
        rem / 1000 % 60,
        rem % 1000,
        y
    )
}

/// The header lines of an ASC file whose trigger block starts at `start_ns` (hex base,
/// absolute timestamps), as Vector tools and python-can write it.
pub fn format_header(start_ns: i64) -> String {
    let date = format_date(start_ns);
    format!(
        "date {date}\nbase hex  timestamps absolute\ninternal events logged\n// version 9.0.0\n\
         Begin Triggerblock {date}\n   0.000000 Start of measurement\n"
    )
}

/// The closing line of an ASC file.
pub const FOOTER: &str = "End TriggerBlock\n";

/// One event line for `f` at `offset_ns` after the trigger block's start, on 1-based channel
/// `ch`, appended to `out`. Times are written to the microsecond (the format's resolution,
/// rounded); an error frame is written as `ErrorFrame` (its SocketCAN class and detail bytes
/// have no place in the format).
pub fn format_frame(f: &Frame, offset_ns: i64, ch: u32, out: &mut Vec<u8>) {
    use std::io::Write;
    let us = (offset_ns.max(0) + 500) / 1000;
    let _ = write!(out, "{:>4}.{:06} ", us / 1_000_000, us % 1_000_000);
    let id = format!("{:X}{}", f.id, if f.extended { "x" } else { "" });
    match f.kind {
        FrameKind::Error => {
            let _ = writeln!(out, "{ch}  ErrorFrame");
        }
        FrameKind::Remote => {
            let _ = writeln!(out, "{ch}  {id:<15} Rx   r {:X}", f.dlc);
        }
        FrameKind::Data if f.fd => {
            let _ = write!(
                out,
                "CANFD {ch:>3} Rx {id:>8} {:>32} {} {} {:X} {:>2}",
                "", f.brs as u8, f.esi as u8, f.dlc, f.len
            );
            for b in f.payload() {
                let _ = write!(out, " {b:02X}");
            }
            out.push(b'\n');
        }
        FrameKind::Data => {
            let _ = write!(out, "{ch}  {id:<15} Rx   d {:X}", f.dlc);
            for b in f.payload() {
                let _ = write!(out, " {b:02X}");
            }
            out.push(b'\n');
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn dates() {
        assert_eq!(days_from_civil(1970, 1, 1), 0);
        assert_eq!(days_from_civil(2000, 3, 1), 11_017);
        assert_eq!(
            parse_date(b" Thu Jan 01 12:53:28.584 1970"),
            Some(46_408_584_000_000)
        );
        let pm = parse_date(b"Sat Sep 30 10:06:13.191 PM 2017").unwrap();
        let de = parse_date(b"Sam Sep 30 22:06:13.191 2017").unwrap();
        assert_eq!(pm, de);
        let am12 = parse_date(b"Thu Apr 28 12:00:00.000 am 2022").unwrap();
        assert_eq!(am12 % (86_400 * 1_000_000_000), 0);
    }

    fn frame(p: &mut AscParser, l: &str) -> Frame {
        match p.parse_line(l.as_bytes()) {
            Ok(AscLine::Frame(f)) => f,
            other => panic!("{l:?}: {other:?}"),
        }
    }

    #[test]
    fn relative_and_decimal() {
        let mut p = AscParser::new();
        p.parse_line(b"base dec  timestamps relative").unwrap();
        p.parse_line(b"Begin Triggerblock Thu Jan 01 00:00:01.000 1970")
            .unwrap();
        let a = frame(&mut p, "0.5 1 100 Rx d 2 255 16");
        let b = frame(&mut p, "0.25 2 2000x Tx d 1 7");
        assert_eq!(a.t_ns, 1_500_000_000);
        assert_eq!(b.t_ns, 1_750_000_000);
        assert_eq!((a.id, a.payload()), (100, &[255u8, 16][..]));
        assert_eq!((b.id, b.extended, b.iface.as_str()), (2000, true, "can1"));
    }

    #[test]
    fn errors_name_the_problem() {
        let mut p = AscParser::new();
        assert_eq!(
            p.parse_line(b"1.0 1 123 Rx d 8 01 02"),
            Err(AscError::MissingData {
                expected: 8,
                found: 2
            })
        );
        assert_eq!(
            p.parse_line(b"1.0 1 800 Rx d 0"),
            Err(AscError::IdRange(0x800, 11))
        );
        assert_eq!(
            p.parse_line(b"1.0 1 123 Qx d 0"),
            Err(AscError::Direction("Qx".into()))
        );
        assert_eq!(p.parse_line(b"hello"), Err(AscError::NotAscLine));
    }
}
