//! PEAK-System TRC trace parser (PCAN-View, PCAN-Basic and PEAK-Converter traces), one line at
//! a time, file versions 1.0 to 2.1.
//!
//! Every version is text: header and comment lines start with `;` (`;$FILEVERSION=2.1`,
//! `;$STARTTIME=` in days since 1899-12-30 with the time of day as the fraction, `;$COLUMNS=`),
//! and each message is one line whose time offset from the start is in milliseconds. The
//! columns by version:
//!
//! * 1.0: `N) offset ID DLC data...` (no type; ID `FFFFFFFF` is a bus status line);
//! * 1.1: `N) offset type ID DLC data...`, type `Rx`, `Tx`, `Warng` or `Error`;
//! * 1.2: `N) offset bus type ID DLC data...`; 1.3 adds a reserved column before the DLC;
//! * 2.0 and 2.1: the columns `$COLUMNS` names: `N` number, `O` offset, `T` type, `B` bus, `I`
//!   ID, `d` direction, `R` reserved, `L` DLC, `l` data length in bytes, `D` data. Types `DT`
//!   (CAN), `FD`, `FB`, `FE`, `BI` (CAN FD; B: bit-rate switch, E / I: error-state indicator),
//!   `RR` (remote request), `ER` (error frame); `ST`, `EC`, `EV` and other types are status,
//!   error-counter and event lines, not frames.
//!
//! IDs are hex; written with more than 4 digits they are extended (29-bit), as PEAK's tools and
//! python-can read them. A remote frame in 1.x reads `RTR` where the data would be. Bus N
//! becomes interface `can{N-1}`; a version without a bus column is `can0`. Without
//! `$STARTTIME` (version 1.0) times are offsets from an unstated epoch.
//!
//! What this is not: a writer, or policy on bad lines (the log source counts and reports
//! them). A data line allocates nothing.

use super::asc::{lossy, tokens, CAN_ERR_PROT};
use super::frame::{fd_dlc_to_len, fd_len_to_dlc, ChannelNames, Frame, FrameKind, IfaceName};

/// What one TRC line is.
pub type TrcLine = super::frame::TextLine;

/// What is wrong with a TRC line.
#[derive(Clone, Debug, PartialEq, Eq, thiserror::Error)]
pub enum TrcError {
    #[error("TRC file version {0:?} is not one this reader knows (1.0 to 2.1)")]
    Version(String),
    #[error("$COLUMNS {0:?} names a column this reader does not know, or lacks O, T, I or D")]
    Columns(String),
    #[error("line ends early: missing {0}")]
    Truncated(&'static str),
    #[error("bad message number {0:?} (a number and ')' expected)")]
    MessageNumber(String),
    #[error("bad time offset {0:?} (milliseconds expected)")]
    Offset(String),
    #[error("bad bus number {0:?}")]
    Bus(String),
    #[error("bad CAN ID {0:?}")]
    Id(String),
    #[error("bad DLC or data length {0:?}")]
    Dlc(String),
    #[error("bad data byte {0:?}")]
    Byte(String),
    #[error("expected {expected} data bytes, found {found}")]
    MissingData { expected: usize, found: usize },
}

/// A column of a 2.x line.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
enum Col {
    Number,
    Offset,
    Type,
    Bus,
    Id,
    Dir,
    Reserved,
    Dlc,
    Length,
    Data,
}

const MAX_COLS: usize = 12;

/// Parser state carried from the header to the message lines.
#[derive(Clone, Debug)]
pub struct TrcParser {
    /// (major, minor); 1.0 until a `$FILEVERSION` says otherwise.
    version: (u8, u8),
    cols: [Col; MAX_COLS],
    n_cols: usize,
    start_ns: Option<i64>,
    ifaces: ChannelNames,
}

impl Default for TrcParser {
    fn default() -> Self {
        Self::new()
    }
}

/// The 2.0 default columns (`$COLUMNS` absent).
const COLS_20: [Col; 7] = [
    Col::Number,
    Col::Offset,
    Col::Type,
    Col::Id,
    Col::Dir,
    Col::Length,
    Col::Data,
];
/// The 2.1 default columns.
const COLS_21: [Col; 9] = [
    Col::Number,
    Col::Offset,
    Col::Type,
    Col::Bus,
    Col::Id,
    Col::Dir,
    Col::Reserved,
    Col::Dlc,
    Col::Data,
];

impl TrcParser {
    /// A parser for a file that has not yet said its version (1.0 until it does).
    pub fn new() -> TrcParser {
        TrcParser {
            version: (1, 0),
            cols: [Col::Data; MAX_COLS],
            n_cols: 0,
            start_ns: None,
            ifaces: ChannelNames::new(),
        }
    }

    /// Wall-clock start (`$STARTTIME`, ns since the Unix epoch, read as UTC), if the file
    /// states one.
    pub fn start_epoch_ns(&self) -> Option<i64> {
        self.start_ns
    }

    /// Parse one line (surrounding white space, a trailing `\r` included, is ignored).
    pub fn parse_line(&mut self, line: &[u8]) -> Result<TrcLine, TrcError> {
        let line = line.trim_ascii();
        if line.is_empty() {
            return Ok(TrcLine::Header);
        }
        if line[0] == b';' {
            return self.header(&line[1..]);
        }
        if self.version.0 >= 2 {
            self.line_v2(line)
        } else {
            self.line_v1(line)
        }
    }

    fn header(&mut self, rest: &[u8]) -> Result<TrcLine, TrcError> {
        let Some(kv) = rest.strip_prefix(b"$") else {
            return Ok(TrcLine::Header);
        };
        let Some(eq) = kv.iter().position(|&b| b == b'=') else {
            return Ok(TrcLine::Header);
        };
        let (key, value) = (kv[..eq].trim_ascii(), kv[eq + 1..].trim_ascii());
        if key.eq_ignore_ascii_case(b"FILEVERSION") {
            self.version = match value {
                b"1.0" => (1, 0),
                b"1.1" => (1, 1),
                b"1.2" => (1, 2),
                b"1.3" => (1, 3),
                b"2.0" => (2, 0),
                b"2.1" => (2, 1),
                v => return Err(TrcError::Version(lossy(v))),
            };
            if self.n_cols == 0 && self.version.0 == 2 {
                let d: &[Col] = if self.version.1 == 0 {
                    &COLS_20
                } else {
                    &COLS_21
                };
                self.cols[..d.len()].copy_from_slice(d);
                self.n_cols = d.len();
            }
        } else if key.eq_ignore_ascii_case(b"STARTTIME") {
            // Days since 1899-12-30 (25,569 days before the Unix epoch).
            if let Some(days) = std::str::from_utf8(value)
                .ok()
                .and_then(|s| s.parse::<f64>().ok())
                .filter(|d| d.is_finite() && *d >= 0.0 && *d < 100_000.0)
            {
                // Stated to about 1e-10 days: kept to the microsecond.
                let whole = days.floor();
                let frac_ns = ((days - whole) * 86_400e6).round() as i64 * 1_000;
                self.start_ns = Some((whole as i64 - 25_569) * 86_400_000_000_000 + frac_ns);
            }
        } else if key.eq_ignore_ascii_case(b"COLUMNS") {
            let mut n = 0;
            for c in value.split(|&b| b == b',').map(|c| c.trim_ascii()) {
                let col = match c {
                    b"N" => Col::Number,
                    b"O" => Col::Offset,
                    b"T" => Col::Type,
                    b"B" => Col::Bus,
                    b"I" => Col::Id,
                    b"d" => Col::Dir,
                    b"R" => Col::Reserved,
                    b"L" => Col::Dlc,
                    b"l" => Col::Length,
                    b"D" => Col::Data,
                    _ => return Err(TrcError::Columns(lossy(value))),
                };
                if n == MAX_COLS {
                    return Err(TrcError::Columns(lossy(value)));
                }
                self.cols[n] = col;
                n += 1;
            }
            let has = |c| self.cols[..n].contains(&c);
            if !(has(Col::Offset) && has(Col::Type) && has(Col::Id) && has(Col::Data)) {
                return Err(TrcError::Columns(lossy(value)));
            }
            self.n_cols = n;
        }
        Ok(TrcLine::Header)
    }

    fn iface(&self, bus: u32) -> IfaceName {
        self.ifaces.get(bus)
    }

    /// Versions 1.0 to 1.3: fixed columns.
    fn line_v1(&self, line: &[u8]) -> Result<TrcLine, TrcError> {
        let mut tk = tokens(line);
        let n = tk.next().ok_or(TrcError::Truncated("the message number"))?;
        if !n.ends_with(b")") {
            return Err(TrcError::MessageNumber(lossy(n)));
        }
        let o = tk.next().ok_or(TrcError::Truncated("the time offset"))?;
        let t_ns = self.time(o)?;
        let minor = self.version.1;
        let bus = if minor >= 2 {
            let b = tk.next().ok_or(TrcError::Truncated("the bus"))?;
            parse_bus(b)?
        } else {
            1
        };
        if minor >= 1 {
            let ty = tk.next().ok_or(TrcError::Truncated("the type"))?;
            if !(ty.eq_ignore_ascii_case(b"Rx") || ty.eq_ignore_ascii_case(b"Tx")) {
                // Warng, Error: bus status.
                return Ok(TrcLine::OtherEvent);
            }
        }
        let id_tok = tk.next().ok_or(TrcError::Truncated("the ID"))?;
        if minor == 0 && id_tok.eq_ignore_ascii_case(b"FFFFFFFF") {
            return Ok(TrcLine::OtherEvent);
        }
        let mut f = Frame::empty(t_ns);
        f.iface = self.iface(bus);
        set_id(&mut f, id_tok)?;
        if minor >= 3 {
            tk.next()
                .ok_or(TrcError::Truncated("the reserved column"))?;
        }
        let d = tk.next().ok_or(TrcError::Truncated("the DLC"))?;
        let dlc = parse_dec(d)
            .filter(|&v| v <= 8)
            .ok_or_else(|| TrcError::Dlc(lossy(d)))?;
        let mut rest = tk.peekable();
        if rest.peek().is_some_and(|t| t.eq_ignore_ascii_case(b"RTR")) {
            f.kind = FrameKind::Remote;
            f.dlc = dlc as u8;
            f.len = dlc as u8;
            return Ok(TrcLine::Frame(f));
        }
        read_data(&mut f, dlc as usize, &mut rest)?;
        f.dlc = dlc as u8;
        Ok(TrcLine::Frame(f))
    }

    /// Versions 2.0 and 2.1: the `$COLUMNS` order.
    fn line_v2(&self, line: &[u8]) -> Result<TrcLine, TrcError> {
        if self.n_cols == 0 {
            return Err(TrcError::Columns(String::new()));
        }
        let mut tk = tokens(line);
        let (mut t_ns, mut bus, mut fd, mut remote) = (None, 1, false, false);
        let (mut id_tok, mut dlc, mut length): (Option<&[u8]>, Option<u32>, Option<u32>) =
            (None, None, None);
        let mut f = Frame::empty(0);
        let mut error = false;
        for &col in &self.cols[..self.n_cols] {
            if col == Col::Data {
                break;
            }
            if error {
                // An error frame: only its bus matters; the columns after it may be blank.
                if col == Col::Bus {
                    if let Some(b) = tk.next() {
                        bus = parse_bus(b)?;
                    }
                    break;
                }
                tk.next();
                continue;
            }
            let tok = tk.next().ok_or(TrcError::Truncated(col_name(col)))?;
            match col {
                Col::Offset => t_ns = Some(self.time(tok)?),
                Col::Type => match tok {
                    b"DT" => {}
                    b"FD" => fd = true,
                    b"FB" => (fd, f.brs) = (true, true),
                    b"FE" => (fd, f.esi) = (true, true),
                    b"BI" => (fd, f.brs, f.esi) = (true, true, true),
                    b"RR" => remote = true,
                    b"ER" => error = true,
                    // ST (status), EC (error counter), EV (event) and anything newer.
                    _ => return Ok(TrcLine::OtherEvent),
                },
                Col::Bus => bus = parse_bus(tok)?,
                Col::Id => id_tok = Some(tok),
                Col::Dlc => {
                    dlc = Some(
                        parse_dec(tok)
                            .filter(|&v| v <= 15)
                            .ok_or_else(|| TrcError::Dlc(lossy(tok)))?,
                    )
                }
                Col::Length => {
                    length = Some(
                        parse_dec(tok)
                            .filter(|&v| v <= 64)
                            .ok_or_else(|| TrcError::Dlc(lossy(tok)))?,
                    )
                }
                Col::Number | Col::Dir | Col::Reserved | Col::Data => {}
            }
        }
        if error {
            let mut e = Frame::empty(t_ns.ok_or(TrcError::Truncated("the time offset"))?);
            e.iface = self.iface(bus);
            e.kind = FrameKind::Error;
            e.id = CAN_ERR_PROT;
            (e.len, e.dlc) = (8, 8);
            return Ok(TrcLine::Frame(e));
        }
        f.t_ns = t_ns.ok_or(TrcError::Truncated("the time offset"))?;
        f.iface = self.iface(bus);
        set_id(&mut f, id_tok.ok_or(TrcError::Truncated("the ID"))?)?;
        f.fd = fd;
        // Bytes: the data length if given, else from the DLC (CAN FD's codes above 8).
        let n = match (length, dlc) {
            (Some(l), _) => l as usize,
            (None, Some(d)) if fd => fd_dlc_to_len(d as u8),
            (None, Some(d)) => (d as usize).min(8),
            (None, None) => return Err(TrcError::Truncated("the DLC or data length")),
        };
        if remote {
            f.kind = FrameKind::Remote;
            f.dlc = dlc.map_or(n.min(15) as u8, |d| d as u8);
            f.len = n.min(8) as u8;
            return Ok(TrcLine::Frame(f));
        }
        if (!fd && n > 8) || (fd && fd_dlc_to_len(fd_len_to_dlc(n)) != n) {
            return Err(TrcError::Dlc(n.to_string()));
        }
        read_data(&mut f, n, &mut tk.peekable())?;
        f.dlc = match dlc {
            Some(d) if !fd && n == 8 && d > 8 => d as u8,
            _ if fd => fd_len_to_dlc(n),
            _ => n as u8,
        };
        Ok(TrcLine::Frame(f))
    }

    /// The start plus an offset in ms ("17535.400", "17535").
    fn time(&self, t: &[u8]) -> Result<i64, TrcError> {
        let off = parse_ms_ns(t).ok_or_else(|| TrcError::Offset(lossy(t)))?;
        Ok(self.start_ns.unwrap_or(0).saturating_add(off))
    }
}

fn col_name(c: Col) -> &'static str {
    match c {
        Col::Number => "the message number",
        Col::Offset => "the time offset",
        Col::Type => "the type",
        Col::Bus => "the bus",
        Col::Id => "the ID",
        Col::Dir => "the direction",
        Col::Reserved => "the reserved column",
        Col::Dlc => "the DLC",
        Col::Length => "the data length",
        Col::Data => "the data",
    }
}

/// Milliseconds with up to 6 decimals, as ns, exactly.
fn parse_ms_ns(t: &[u8]) -> Option<i64> {
    let (int, frac) = match t.iter().position(|&b| b == b'.') {
        Some(p) => (&t[..p], &t[p + 1..]),
        None => (t, &b""[..]),
    };
    if int.is_empty() || int.len() > 12 || frac.len() > 6 {
        return None;
    }
    if !int.iter().chain(frac).all(u8::is_ascii_digit) {
        return None;
    }
    let mut ms: i64 = 0;
    for &b in int {
        ms = ms * 10 + i64::from(b - b'0');
    }
    let mut sub: i64 = 0;
    for i in 0..6 {
        sub = sub * 10 + frac.get(i).map_or(0, |&b| i64::from(b - b'0'));
    }
    Some(ms * 1_000_000 + sub)
}

fn parse_dec(t: &[u8]) -> Option<u32> {
    if t.is_empty() || t.len() > 9 || !t.iter().all(u8::is_ascii_digit) {
        return None;
    }
    Some(t.iter().fold(0, |v, &b| v * 10 + u32::from(b - b'0')))
}

fn parse_bus(t: &[u8]) -> Result<u32, TrcError> {
    parse_dec(t)
        .filter(|&b| b >= 1)
        .ok_or_else(|| TrcError::Bus(lossy(t)))
}

fn hex_val(b: u8) -> Option<u8> {
    match b {
        b'0'..=b'9' => Some(b - b'0'),
        b'a'..=b'f' => Some(b - b'a' + 10),
        b'A'..=b'F' => Some(b - b'A' + 10),
        _ => None,
    }
}

/// The ID: hex, more than 4 digits extended.
fn set_id(f: &mut Frame, t: &[u8]) -> Result<(), TrcError> {
    if t.is_empty() || t.len() > 8 {
        return Err(TrcError::Id(lossy(t)));
    }
    let mut id: u32 = 0;
    for &b in t {
        id = id << 4 | u32::from(hex_val(b).ok_or_else(|| TrcError::Id(lossy(t)))?);
    }
    let ext = t.len() > 4;
    if id > if ext { 0x1FFF_FFFF } else { 0x7FF } {
        return Err(TrcError::Id(lossy(t)));
    }
    f.id = id;
    f.extended = ext;
    Ok(())
}

/// `n` hex bytes into the frame.
fn read_data<'a>(
    f: &mut Frame,
    n: usize,
    tk: &mut std::iter::Peekable<impl Iterator<Item = &'a [u8]>>,
) -> Result<(), TrcError> {
    for i in 0..n {
        let Some(b) = tk.next() else {
            return Err(TrcError::MissingData {
                expected: n,
                found: i,
            });
        };
        let v = match b {
            [h, l] => hex_val(*h).zip(hex_val(*l)).map(|(h, l)| h << 4 | l),
            _ => None,
        };
        f.data[i] = v.ok_or_else(|| TrcError::Byte(lossy(b)))?;
    }
    f.len = n as u8;
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    fn parse(p: &mut TrcParser, l: &str) -> TrcLine {
        p.parse_line(l.as_bytes()).unwrap()
    }

    #[test]
    fn v21_data_fd_remote_and_status_lines() {
        let mut p = TrcParser::new();
        for h in [
            ";$FILEVERSION=2.1",
            ";$STARTTIME=25569.5",
            ";$COLUMNS=N,O,T,B,I,d,R,L,D",
            ";   comment",
        ] {
            assert_eq!(parse(&mut p, h), TrcLine::Header);
        }
        let TrcLine::Frame(f) = parse(&mut p, "  1   2501.125 DT 2  00C8 Tx -  3  09 08 0a") else {
            panic!()
        };
        assert_eq!(f.t_ns, 43_200_000_000_000 + 2_501_125_000);
        assert_eq!((f.iface.as_str(), f.id, f.extended), ("can1", 0xC8, false));
        assert_eq!((f.len, f.dlc, &f.data[..3]), (3, 3, &[9, 8, 10][..]));
        let TrcLine::Frame(f) = parse(
            &mut p,
            "2 3.0 FB 1 18FF0102 Rx - 9 00 01 02 03 04 05 06 07 08 09 0A 0B",
        ) else {
            panic!()
        };
        assert!(f.fd && f.brs && !f.esi && f.extended);
        assert_eq!((f.id, f.len, f.dlc, f.data[11]), (0x18FF0102, 12, 9, 11));
        let TrcLine::Frame(f) = parse(&mut p, "3 4.0 RR 1 0704 Rx - 1") else {
            panic!()
        };
        assert_eq!((f.kind, f.dlc), (FrameKind::Remote, 1));
        assert_eq!(
            parse(&mut p, "4 5.0 ST 1 - Rx - 4 00 00 00 08"),
            TrcLine::OtherEvent
        );
        let TrcLine::Frame(f) = parse(&mut p, "5 6.0 ER 2 - Rx - 0") else {
            panic!()
        };
        assert_eq!((f.kind, f.iface.as_str()), (FrameKind::Error, "can1"));
    }

    #[test]
    fn v1_lines_by_version() {
        let mut p = TrcParser::new();
        let TrcLine::Frame(f) = parse(&mut p, "1)  17535  00000100  8  00 01 02 03 04 05 06 07")
        else {
            panic!()
        };
        assert_eq!(
            (f.t_ns, f.id, f.extended, f.data[7]),
            (17_535_000_000, 0x100, true, 7)
        );
        assert_eq!(
            parse(
                &mut p,
                "2) 17540 FFFFFFFF 4 00 00 00 08 -- -- -- -- BUSHEAVY"
            ),
            TrcLine::OtherEvent
        );
        parse(&mut p, ";$FILEVERSION=1.3");
        let TrcLine::Frame(f) = parse(&mut p, "12)  48937.600 2  Rx  0704 -  1  RTR") else {
            panic!()
        };
        assert_eq!(
            (f.kind, f.iface.as_str(), f.t_ns),
            (FrameKind::Remote, "can1", 48_937_600_000)
        );
        assert_eq!(
            parse(
                &mut p,
                "2) 17540.3 1 Warng FFFFFFFF - 4 00 00 00 08 BUSHEAVY"
            ),
            TrcLine::OtherEvent
        );
    }

    #[test]
    fn bad_lines_say_what_is_wrong() {
        let mut p = TrcParser::new();
        parse(&mut p, ";$FILEVERSION=2.0");
        let e = |p: &mut TrcParser, l: &str| p.parse_line(l.as_bytes()).unwrap_err().to_string();
        assert!(e(&mut p, "1 1.0 DT 0100 Rx 8 00 01").contains("expected 8 data bytes, found 2"));
        assert!(e(&mut p, "1 x DT 0100 Rx 1 00").contains("time offset"));
        assert!(
            e(&mut p, "1 1.0 DT 0900 Rx 1 00").contains("CAN ID"),
            "11-bit range"
        );
        assert!(e(&mut p, "1 1.0 DT 0100 Rx 9 00").contains("DLC"));
        assert!(e(&mut p, ";$FILEVERSION=3.0").contains("version"));
        assert!(e(&mut p, ";$COLUMNS=N,O,X").contains("COLUMNS"));
        // Version 1: the message number ends in ')'; a line without it says so, not that it
        // ended early.
        let mut p = TrcParser::new();
        parse(&mut p, ";$FILEVERSION=1.1");
        let msg = e(&mut p, "1  17535.4 Rx 0100 1 00");
        assert!(msg.contains("bad message number \"1\""), "{msg}");
        assert!(e(&mut p, "1)").contains("line ends early: missing the time offset"));
    }
}
