//! The can-utils `candump -L` log line format (also what `canplayer` reads): parse one line,
//! emit one frame.
//!
//! Grammar accepted by [`parse_line`] (one line, with or without its `\n` / `\r\n`):
//!
//! ```text
//! line      := ws* ( frame-line | comment | blank | dropcount ) ws*
//! frame-line:= '(' SEC '.' FRAC ')' ws+ IFACE ws+ FRAME ( ws+ ('R'|'T') )?
//!              SEC = 1–12 decimal digits, FRAC = exactly 6 (µs) or 9 (ns) digits
//!              IFACE = 1–15 bytes of UTF-8 without spaces or tabs
//! ws        := ' ' | '\t'                           (any run of them)
//! comment   := '#' anything ;  blank := nothing
//! dropcount := 'DROPCOUNT' anything, the first decimal number in it is the count
//! FRAME     := ID '#' DATA ( '_' DLC )?               classic data (DLC suffix 9–F needs 8 bytes)
//!            | ID '#' ('R'|'r') LEN? ( '_' DLC )?     remote request, LEN one digit 0–8
//!            | ID '##' FLAGS DATA                     CAN FD; FLAGS one hex digit, 1=BRS 2=ESI 4=FDF
//!            | ID '###' anything                      CAN XL: recognised and skipped
//! ID        := 3 hex digits (standard, ≤ 0x7FF) | 8 hex digits (extended, ≤ 0x1FFFFFFF;
//!              0x20000000 set = error frame whose low bits are the SocketCAN error class)
//! DATA      := ( '.'? HEX HEX )*                     any case
//! ```
//!
//! The digit count of the ID alone decides standard versus extended, as in can-utils.
//!
//! Not here: reading files, counting, or deciding what to do with a bad line; that is
//! [`crate::source::log`]. This module only describes exactly what is wrong with a line.

use super::frame::{fd_dlc_to_len, fd_len_to_dlc, Frame, FrameKind, IfaceName};
use std::io;

/// SocketCAN's error-frame flag in the 32-bit CAN ID (`CAN_ERR_FLAG`).
pub const CAN_ERR_FLAG: u32 = 0x2000_0000;
/// Mask of the error class bits (`CAN_ERR_MASK`).
pub const CAN_ERR_MASK: u32 = 0x1FFF_FFFF;

/// What one line holds.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Parsed {
    /// A CAN frame (data, remote, or error).
    Frame(Frame),
    /// A comment (`# ...`) or a blank line.
    Comment,
    /// A `DROPCOUNT` line: candump reports this many frames dropped by the kernel.
    DropCount(u64),
    /// A CAN XL frame (`ID###...`), recognised but not represented by [`Frame`].
    SkippedXl,
}

/// What is wrong with a line, and where (1-based byte column).
#[derive(Clone, Copy, Debug, PartialEq, Eq, thiserror::Error)]
#[error("column {col}: {kind}")]
pub struct CandumpError {
    pub col: usize,
    pub kind: ErrorKind,
}

/// The ways a candump line can be wrong.
#[derive(Clone, Copy, Debug, PartialEq, Eq, thiserror::Error)]
pub enum ErrorKind {
    #[error("expected '(' opening the timestamp, found {}", show(*.0))]
    NoTimestamp(u8),
    #[error("timestamp seconds: expected 1 to 12 decimal digits")]
    TimestampSeconds,
    #[error("timestamp does not fit 64-bit nanoseconds (beyond the year 2262)")]
    TimestampRange,
    #[error("timestamp: expected '.' after the seconds, found {}", show(*.0))]
    TimestampDot(u8),
    #[error("timestamp fraction must have 6 (µs) or 9 (ns) digits, found {0}")]
    TimestampFraction(usize),
    #[error("timestamp: expected ')' after the fraction, found {}", show(*.0))]
    TimestampClose(u8),
    #[error("missing interface name after the timestamp")]
    NoIface,
    #[error("interface name is {0} bytes; Linux allows at most 15")]
    IfaceTooLong(usize),
    #[error("interface name is not valid UTF-8")]
    IfaceNotUtf8,
    #[error("missing frame after the interface name")]
    NoFrame,
    #[error("frame has no '#' separating the CAN ID from the data")]
    NoHash,
    #[error("CAN ID must be 3 hex digits (standard) or 8 (extended), found {0} characters")]
    IdDigits(usize),
    #[error("invalid hex digit {} in {field}", show(*.found))]
    Hex { field: &'static str, found: u8 },
    #[error("standard CAN ID {0:#05X} is above 0x7FF")]
    StdIdRange(u32),
    #[error("extended CAN ID {0:#010X} has flag bits above bit 29 set (only 0x20000000, the error flag, is allowed)")]
    ExtIdFlags(u32),
    #[error("an error frame cannot be a remote or CAN FD frame")]
    ErrorFrameKind,
    #[error("odd number of hex digits in the data: half a byte at the end")]
    HalfByte,
    #[error("more than {0} data bytes")]
    TooLong(usize),
    #[error("{0} bytes is not a CAN FD length (0-8, 12, 16, 20, 24, 32, 48 or 64)")]
    FdLength(usize),
    #[error("CAN FD frame needs a flags digit after '##'")]
    NoFdFlags,
    #[error("unknown CAN FD flag bits in {0:#X} (known: 1 = BRS, 2 = ESI, 4 = FDF)")]
    FdFlags(u8),
    #[error("remote frame length must be one digit 0-8, found {}", show(*.0))]
    RemoteLen(u8),
    #[error("DLC suffix '_{}' needs exactly 8 data bytes and a DLC of 9 to F", show(*.0))]
    DlcSuffix(u8),
    #[error("unexpected text after the frame (only an R or T direction may follow)")]
    Trailing,
    #[error("DROPCOUNT line without a count")]
    DropCountMissing,
}

fn show(b: u8) -> String {
    if b == 0 {
        "end of line".to_string()
    } else if b.is_ascii_graphic() {
        format!("'{}'", b as char)
    } else {
        format!("byte {b:#04x}")
    }
}

const INVALID: u8 = 0xFF;

/// Hex digit value by byte, `INVALID` for non-hex bytes.
static HEX: [u8; 256] = {
    let mut t = [INVALID; 256];
    let mut i = 0;
    while i < 10 {
        t[b'0' as usize + i] = i as u8;
        i += 1;
    }
    let mut i = 0;
    while i < 6 {
        t[b'a' as usize + i] = 10 + i as u8;
        t[b'A' as usize + i] = 10 + i as u8;
        i += 1;
    }
    t
};

#[inline]
fn is_ws(b: u8) -> bool {
    b == b' ' || b == b'\t'
}

/// A cursor over one line; `peek` gives 0 past the end.
struct Cur<'a> {
    s: &'a [u8],
    i: usize,
}

impl<'a> Cur<'a> {
    #[inline]
    fn peek(&self) -> u8 {
        self.s.get(self.i).copied().unwrap_or(0)
    }
    #[inline]
    fn err(&self, kind: ErrorKind) -> CandumpError {
        CandumpError {
            col: self.i + 1,
            kind,
        }
    }
    #[inline]
    fn skip_ws(&mut self) -> usize {
        let start = self.i;
        while self.i < self.s.len() && is_ws(self.s[self.i]) {
            self.i += 1;
        }
        self.i - start
    }
    /// The next run of non-whitespace bytes.
    #[inline]
    fn token(&mut self) -> &'a [u8] {
        let start = self.i;
        while self.i < self.s.len() && !is_ws(self.s[self.i]) {
            self.i += 1;
        }
        &self.s[start..self.i]
    }
}

/// Parse one line (its `\n` or `\r\n` may be included).
pub fn parse_line(line: &[u8]) -> Result<Parsed, CandumpError> {
    let mut f = Frame::empty(0);
    if parse_common_into(line, &mut f) {
        return Ok(Parsed::Frame(f));
    }
    parse_line_full(line)
}

/// The fast path for the shape nearly every real log line has,
/// `(SSSSSSSSSS.FFFFFF) IFACE XXX#HEXHEX…` (classic data frame, 3- or 8-digit ID, 0–8 bytes,
/// single spaces, optional `\r`/`\n` at the end), parsed in one pass with table lookups and
/// integer timestamp arithmetic, into a caller-provided frame.
///
/// Returns `true` when `out` now holds exactly the frame [`parse_line`] would return for
/// `line`. Returns `false`, with `out`'s contents unspecified, for anything else (other frame
/// kinds, separators, direction suffixes, comments, and every malformed line): the caller
/// then uses [`parse_line`], whose full grammar gives the precise error.
///
/// Reusing one `out` across lines is what makes this fast: the interface name is only
/// validated when its bytes differ from the name already in `out`, and only the bytes that
/// can change are written (the 64-byte data array is not re-zeroed: `out` must keep the
/// [`Frame`] invariant that bytes past `len` are zero, as every constructor and parser does).
#[inline]
pub fn parse_common_into(line: &[u8], out: &mut Frame) -> bool {
    let mut s = line;
    if let [rest @ .., b'\n'] = s {
        s = rest;
    }
    if let [rest @ .., b'\r'] = s {
        s = rest;
    }
    let n = s.len();
    // Shortest accepted line: "(0.000000) a 000#" = 17 bytes.
    if n < 17 || s[0] != b'(' {
        return false;
    }
    let Some((t_ns, mut i)) = fast_timestamp(s) else {
        return false;
    };
    // Interface name: up to the next space.
    let Some(sp) = memchr::memchr(b' ', &s[i..]) else {
        return false;
    };
    if sp == 0 {
        return false;
    }
    let name = &s[i..i + sp];
    if name != out.iface.as_bytes() {
        if name.contains(&b'\t') {
            return false;
        }
        match IfaceName::from_bytes(name) {
            Some(iface) => out.iface = iface,
            None => return false,
        }
    }
    i += sp + 1;
    // Frame: ID '#' DATA up to the end of the line.
    let fr = &s[i..];
    let Some((id, extended, id_len)) = fast_id(fr) else {
        return false;
    };
    let data = &fr[id_len..];
    // Data: an even number of hex digits, at most 8 bytes, nothing else.
    let len = data.len() / 2;
    if data.len() % 2 != 0 || len > 8 {
        return false;
    }
    let mut bytes = [0u8; 8];
    let mut bad: u8 = 0;
    for k in 0..len {
        let hi = HEX[data[2 * k] as usize];
        let lo = HEX[data[2 * k + 1] as usize];
        bad |= hi | lo;
        bytes[k] = (hi << 4) | (lo & 0x0F);
    }
    if bad & 0xF0 != 0 {
        return false;
    }
    store_classic(out, t_ns, id, extended, &bytes, len);
    true
}

/// [`parse_common_into`] for a line at the start of a read buffer whose end is not yet known:
/// the line end (`\n`, optionally preceded by one `\r`) is found while the data field is
/// scanned, so the caller needs no separate search for it. Returns the number of bytes the line
/// takes including its `\n`, with `out` holding exactly what [`parse_common_into`] would give
/// for that line. Returns `None` (with `out` unspecified) whenever it cannot show that: any line
/// `parse_common_into` rejects, a new interface name, or a buffer that ends before the `\n`;
/// the caller then falls back to finding the line end and using the line-based parsers.
#[inline]
pub fn parse_common_prefix(s: &[u8], out: &mut Frame) -> Option<usize> {
    let n = s.len();
    if n < 18 || s[0] != b'(' {
        return None;
    }
    let (t_ns, mut i) = fast_timestamp(s)?;
    // Interface name: only the one already in `out` (it holds no space, tab or newline); a
    // different name goes through the line-based parser, which validates it.
    let name = out.iface.as_bytes();
    if name.is_empty() || s.get(i..i + name.len())? != name || *s.get(i + name.len())? != b' ' {
        return None;
    }
    i += name.len() + 1;
    let (id, extended, id_len) = fast_id(&s[i..])?;
    let mut p = i + id_len;
    // Data: hex pairs up to the line end; at most 8 bytes.
    let mut bytes = [0u8; 8];
    let mut len = 0;
    loop {
        let hi = HEX[*s.get(p)? as usize];
        if hi & 0xF0 != 0 {
            break;
        }
        let lo = HEX[*s.get(p + 1)? as usize];
        if lo & 0xF0 != 0 || len == 8 {
            return None;
        }
        bytes[len] = (hi << 4) | lo;
        len += 1;
        p += 2;
    }
    if s[p] == b'\r' {
        p += 1;
    }
    if *s.get(p)? != b'\n' {
        return None;
    }
    store_classic(out, t_ns, id, extended, &bytes, len);
    Some(p + 1)
}

/// The fast paths' timestamp: `(` 1–12 digits `.` 6 or 9 digits `) ` at the start of `s`,
/// which must be at least 17 bytes long. Returns the time in ns and the index just past the
/// `) `; `None` for anything else (the full grammar then decides).
#[inline(always)]
fn fast_timestamp(s: &[u8]) -> Option<(i64, usize)> {
    let n = s.len();
    // Seconds: 1-12 digits (the bound keeps the loop short on garbage).
    let mut i = 1;
    let mut sec: i64 = 0;
    loop {
        let d = s[i].wrapping_sub(b'0');
        if d > 9 {
            break;
        }
        sec = sec * 10 + d as i64;
        i += 1;
        if i > 13 {
            return None;
        }
    }
    if i == 1 || s[i] != b'.' {
        return None;
    }
    i += 1;
    // Fraction: 6 or 9 digits, then ") ": at most 11 bytes from here, all indexed below.
    if i + 11 > n {
        return None;
    }
    let fstart = i;
    let frac_ns = if let Some(us) = six_digits_then_paren(&s[i..i + 8]) {
        // Microseconds, the usual case, read as one word.
        i += 6;
        us * 1000
    } else {
        let mut frac: i64 = 0;
        loop {
            let d = s[i].wrapping_sub(b'0');
            if d > 9 || i - fstart == 9 {
                break;
            }
            frac = frac * 10 + d as i64;
            i += 1;
        }
        match i - fstart {
            6 => frac * 1000,
            9 => frac,
            _ => return None,
        }
    };
    if s[i] != b')' || s[i + 1] != b' ' {
        return None;
    }
    let t_ns = sec.checked_mul(1_000_000_000)?.checked_add(frac_ns)?;
    Some((t_ns, i + 2))
}

/// `w` (8 bytes) starts with exactly six decimal digits followed by `)`: their value, computed
/// on the word at once (digit `k` in byte `k`; pairs, then quads, then all six combined).
#[inline(always)]
fn six_digits_then_paren(w: &[u8]) -> Option<i64> {
    let w = u64::from_le_bytes(w.try_into().ok()?);
    const LOW6: u64 = 0x0000_FFFF_FFFF_FFFF;
    let digits = w & LOW6;
    let nib = digits & 0x0000_0F0F_0F0F_0F0F;
    // Each byte is 0x30-0x39: high nibble 3, and the low nibble plus 6 stays below 16.
    let ok = digits & 0x0000_F0F0_F0F0_F0F0 == 0x0000_3030_3030_3030
        && (nib + 0x0000_0606_0606_0606) & 0x0000_F0F0_F0F0_F0F0 == 0
        && (w >> 48) as u8 == b')';
    if !ok {
        return None;
    }
    // As eight digits "00dddddd": the two leading zeros in bytes 0 and 1.
    let mut v = nib << 16;
    v = (v * 10 + (v >> 8)) & 0x00FF_00FF_00FF_00FF;
    v = (v * 100 + (v >> 16)) & 0x0000_FFFF_0000_FFFF;
    v = (v * 10_000 + (v >> 32)) & 0xFFFF_FFFF;
    Some(v as i64)
}

/// The fast paths' identifier: `XXX#` (standard, ≤ 0x7FF) or `XXXXXXXX#` (extended, no
/// error or flag bits) at the start of `fr`. Returns (id, extended, bytes taken with the `#`).
#[inline(always)]
fn fast_id(fr: &[u8]) -> Option<(u32, bool, usize)> {
    if fr.len() >= 4 && fr[3] == b'#' {
        let (d0, d1, d2) = (
            HEX[fr[0] as usize],
            HEX[fr[1] as usize],
            HEX[fr[2] as usize],
        );
        let v = (d0 as u32) << 8 | (d1 as u32) << 4 | d2 as u32;
        if (d0 | d1 | d2) & 0xF0 != 0 || v > 0x7FF {
            return None;
        }
        Some((v, false, 4))
    } else if fr.len() >= 9 && fr[8] == b'#' {
        let mut v: u32 = 0;
        let mut bad: u8 = 0;
        for &b in &fr[..8] {
            let d = HEX[b as usize];
            bad |= d;
            v = (v << 4) | (d & 0x0F) as u32;
        }
        // Error frames and flag bits take the full parser.
        if bad & 0xF0 != 0 || v & !CAN_ERR_MASK != 0 {
            return None;
        }
        Some((v, true, 9))
    } else {
        None
    }
}

/// Writes a classic data frame into a reused `out`, touching only the bytes that can change
/// (bytes past 8 are zeroed only when the previous frame was longer).
#[inline(always)]
fn store_classic(out: &mut Frame, t_ns: i64, id: u32, extended: bool, bytes: &[u8; 8], len: usize) {
    if out.len > 8 {
        out.data[8..].fill(0);
    }
    out.data[..8].copy_from_slice(bytes);
    out.t_ns = t_ns;
    out.id = id;
    out.extended = extended;
    out.kind = FrameKind::Data;
    out.fd = false;
    out.brs = false;
    out.esi = false;
    out.len = len as u8;
    out.dlc = len as u8;
}

/// The full grammar (every frame kind, precise errors); [`parse_line`] without the fast path.
pub fn parse_line_full(line: &[u8]) -> Result<Parsed, CandumpError> {
    let mut end = line.len();
    while end > 0 && matches!(line[end - 1], b'\n' | b'\r' | b' ' | b'\t') {
        end -= 1;
    }
    let mut c = Cur {
        s: &line[..end],
        i: 0,
    };
    c.skip_ws();
    match c.peek() {
        0 | b'#' => return Ok(Parsed::Comment),
        b'(' => {}
        b'D' if c.s[c.i..].starts_with(b"DROPCOUNT") => return parse_dropcount(&mut c),
        other => return Err(c.err(ErrorKind::NoTimestamp(other))),
    }
    c.i += 1;
    let t_ns = parse_timestamp(&mut c)?;

    if c.skip_ws() == 0 || c.i >= c.s.len() {
        return Err(c.err(ErrorKind::NoIface));
    }
    let iface_col = c.i;
    let iface_tok = c.token();
    let iface = match IfaceName::from_bytes(iface_tok) {
        Some(n) => n,
        None => {
            let kind = if iface_tok.len() > 15 {
                ErrorKind::IfaceTooLong(iface_tok.len())
            } else {
                ErrorKind::IfaceNotUtf8
            };
            return Err(CandumpError {
                col: iface_col + 1,
                kind,
            });
        }
    };
    if c.skip_ws() == 0 || c.i >= c.s.len() {
        return Err(c.err(ErrorKind::NoFrame));
    }
    let mut frame = Frame::empty(t_ns);
    frame.iface = iface;
    let frame_start = c.i;
    let frame_end = frame_start + c.token().len();
    let mut fc = Cur {
        s: &c.s[..frame_end],
        i: frame_start,
    };
    if parse_frame(&mut fc, &mut frame)? {
        return Ok(Parsed::SkippedXl);
    }
    c.i = frame_end;
    // Optional direction.
    if c.skip_ws() > 0 && c.i < c.s.len() {
        match c.peek() {
            b'R' | b'T' | b'r' | b't' => c.i += 1,
            _ => return Err(c.err(ErrorKind::Trailing)),
        }
        c.skip_ws();
    }
    if c.i < c.s.len() {
        return Err(c.err(ErrorKind::Trailing));
    }
    Ok(Parsed::Frame(frame))
}

fn parse_dropcount(c: &mut Cur) -> Result<Parsed, CandumpError> {
    let rest = &c.s[c.i..];
    let Some(start) = rest.iter().position(u8::is_ascii_digit) else {
        c.i = c.s.len();
        return Err(c.err(ErrorKind::DropCountMissing));
    };
    let mut n: u64 = 0;
    for &b in rest[start..].iter().take_while(|b| b.is_ascii_digit()) {
        n = n.saturating_mul(10).saturating_add((b - b'0') as u64);
    }
    Ok(Parsed::DropCount(n))
}

#[inline]
fn parse_timestamp(c: &mut Cur) -> Result<i64, CandumpError> {
    let start = c.i;
    let mut sec: i64 = 0;
    while c.peek().is_ascii_digit() {
        if c.i - start >= 12 {
            return Err(c.err(ErrorKind::TimestampSeconds));
        }
        sec = sec * 10 + (c.peek() - b'0') as i64;
        c.i += 1;
    }
    if c.i == start {
        return Err(c.err(ErrorKind::TimestampSeconds));
    }
    if c.peek() != b'.' {
        return Err(c.err(ErrorKind::TimestampDot(c.peek())));
    }
    c.i += 1;
    let fstart = c.i;
    let mut frac: i64 = 0;
    while c.peek().is_ascii_digit() && c.i - fstart < 10 {
        frac = frac * 10 + (c.peek() - b'0') as i64;
        c.i += 1;
    }
    let n = c.i - fstart;
    let frac_ns = match n {
        6 => frac * 1000,
        9 => frac,
        _ => {
            return Err(CandumpError {
                col: fstart + 1,
                kind: ErrorKind::TimestampFraction(n),
            })
        }
    };
    if c.peek() != b')' {
        return Err(c.err(ErrorKind::TimestampClose(c.peek())));
    }
    c.i += 1;
    sec.checked_mul(1_000_000_000)
        .and_then(|ns| ns.checked_add(frac_ns))
        .ok_or(CandumpError {
            col: start + 1,
            kind: ErrorKind::TimestampRange,
        })
}

/// Parse hex digits `s` (already length-checked) as an ID.
#[inline]
fn hex_id(c: &Cur, start: usize, n: usize) -> Result<u32, CandumpError> {
    let mut v: u32 = 0;
    for k in 0..n {
        let b = c.s[start + k];
        let d = HEX[b as usize];
        if d == INVALID {
            return Err(CandumpError {
                col: start + k + 1,
                kind: ErrorKind::Hex {
                    field: "the CAN ID",
                    found: b,
                },
            });
        }
        v = (v << 4) | d as u32;
    }
    Ok(v)
}

/// Parse the frame token into `f`. Returns `Ok(true)` for a CAN XL frame (skipped).
#[inline]
fn parse_frame(c: &mut Cur, f: &mut Frame) -> Result<bool, CandumpError> {
    let start = c.i;
    let tok = &c.s[start..];
    let Some(hash) = memchr::memchr(b'#', tok) else {
        return Err(c.err(ErrorKind::NoHash));
    };
    if tok[hash..].starts_with(b"###") {
        return Ok(true);
    }
    let id = match hash {
        3 | 8 => hex_id(c, start, hash)?,
        n => return Err(c.err(ErrorKind::IdDigits(n))),
    };
    if hash == 3 {
        if id > 0x7FF {
            return Err(c.err(ErrorKind::StdIdRange(id)));
        }
        f.id = id;
    } else if id & !CAN_ERR_MASK == CAN_ERR_FLAG {
        f.kind = FrameKind::Error;
        f.id = id & CAN_ERR_MASK;
    } else if id & !CAN_ERR_MASK != 0 {
        return Err(c.err(ErrorKind::ExtIdFlags(id)));
    } else {
        f.id = id;
        f.extended = true;
    }
    c.i = start + hash + 1;
    let is_err = f.kind == FrameKind::Error;
    match c.peek() {
        b'#' => {
            if is_err {
                return Err(c.err(ErrorKind::ErrorFrameKind));
            }
            c.i += 1;
            let b = c.peek();
            let flags = HEX[b as usize];
            if b == 0 {
                return Err(c.err(ErrorKind::NoFdFlags));
            }
            if flags == INVALID {
                return Err(c.err(ErrorKind::Hex {
                    field: "the CAN FD flags",
                    found: b,
                }));
            }
            if flags > 7 {
                return Err(c.err(ErrorKind::FdFlags(flags)));
            }
            c.i += 1;
            f.fd = true;
            f.brs = flags & 1 != 0;
            f.esi = flags & 2 != 0;
            let len = parse_data(c, f, 64)?;
            // Only the lengths a DLC can express exist on the bus.
            if fd_dlc_to_len(fd_len_to_dlc(len)) != len {
                return Err(CandumpError {
                    col: start + hash + 4,
                    kind: ErrorKind::FdLength(len),
                });
            }
            f.len = len as u8;
            f.dlc = fd_len_to_dlc(len);
            if c.i < c.s.len() {
                return Err(c.err(ErrorKind::Hex {
                    field: "the data",
                    found: c.peek(),
                }));
            }
        }
        b'R' | b'r' => {
            if is_err {
                return Err(c.err(ErrorKind::ErrorFrameKind));
            }
            c.i += 1;
            f.kind = FrameKind::Remote;
            let b = c.peek();
            let mut len = 0u8;
            if b != 0 && b != b'_' {
                if !(b'0'..=b'8').contains(&b) {
                    return Err(c.err(ErrorKind::RemoteLen(b)));
                }
                len = b - b'0';
                c.i += 1;
            }
            f.len = len;
            f.dlc = len;
            parse_dlc_suffix(c, f)?;
        }
        _ => {
            let len = parse_data(c, f, 8)?;
            f.len = len as u8;
            f.dlc = len as u8;
            parse_dlc_suffix(c, f)?;
        }
    }
    Ok(false)
}

#[inline]
fn parse_dlc_suffix(c: &mut Cur, f: &mut Frame) -> Result<(), CandumpError> {
    match c.peek() {
        0 => Ok(()),
        b'_' => {
            c.i += 1;
            let b = c.peek();
            let d = HEX[b as usize];
            if f.len != 8 || f.kind == FrameKind::Error || d == INVALID || d < 9 {
                return Err(c.err(ErrorKind::DlcSuffix(b)));
            }
            c.i += 1;
            f.dlc = d;
            if c.i < c.s.len() {
                return Err(c.err(ErrorKind::Trailing));
            }
            Ok(())
        }
        b => Err(c.err(ErrorKind::Hex {
            field: "the data",
            found: b,
        })),
    }
}

/// Data bytes with optional '.' separators, up to `max`; stops at '_' or the end.
#[inline]
fn parse_data(c: &mut Cur, f: &mut Frame, max: usize) -> Result<usize, CandumpError> {
    let s = c.s;
    let mut i = c.i;
    let mut n = 0usize;
    loop {
        if i < s.len() && s[i] == b'.' {
            i += 1;
        }
        if i >= s.len() {
            break;
        }
        let hi = HEX[s[i] as usize];
        if hi == INVALID {
            break;
        }
        if i + 1 >= s.len() {
            c.i = i;
            return Err(c.err(ErrorKind::HalfByte));
        }
        let lo = HEX[s[i + 1] as usize];
        if lo == INVALID {
            c.i = i + 1;
            let b = s[i + 1];
            if b == b'.' || b == b'_' {
                return Err(c.err(ErrorKind::HalfByte));
            }
            return Err(c.err(ErrorKind::Hex {
                field: "the data",
                found: b,
            }));
        }
        if n == max {
            c.i = i;
            return Err(c.err(ErrorKind::TooLong(max)));
        }
        f.data[n] = (hi << 4) | lo;
        n += 1;
        i += 2;
    }
    c.i = i;
    Ok(n)
}

const HEX_UPPER: &[u8; 16] = b"0123456789ABCDEF";

/// Format `f` as one canonical `candump -L` line (with `\n`) into `out`; returns its length.
///
/// Canonical means: 6 fraction digits when the timestamp is a whole microsecond, else 9;
/// upper-case hex; 3-digit IDs for standard and 8-digit for extended frames; no byte
/// separators; the `_<dlc>` suffix only when the DLC is 9–F. Fails (`InvalidInput`) for what the
/// format cannot hold: a negative timestamp or an empty interface name.
pub fn format_frame(f: &Frame, out: &mut [u8; 256]) -> io::Result<usize> {
    if f.t_ns < 0 {
        return Err(io::Error::new(
            io::ErrorKind::InvalidInput,
            "candump format cannot hold a negative timestamp",
        ));
    }
    if f.iface.is_empty() {
        return Err(io::Error::new(
            io::ErrorKind::InvalidInput,
            "candump format needs an interface name; the frame has none",
        ));
    }
    let mut n = 0usize;
    let mut put = |b: u8| {
        out[n] = b;
        n += 1;
    };
    put(b'(');
    let sec = (f.t_ns / 1_000_000_000) as u64;
    let ns = (f.t_ns % 1_000_000_000) as u64;
    let mut digits = [0u8; 20];
    let mut k = 0;
    let mut s = sec;
    loop {
        digits[k] = b'0' + (s % 10) as u8;
        k += 1;
        s /= 10;
        if s == 0 {
            break;
        }
    }
    while k > 0 {
        k -= 1;
        put(digits[k]);
    }
    put(b'.');
    let (frac, nd) = if ns.is_multiple_of(1000) {
        (ns / 1000, 6)
    } else {
        (ns, 9)
    };
    let mut div = 10u64.pow(nd - 1);
    for _ in 0..nd {
        put(b'0' + ((frac / div) % 10) as u8);
        div /= 10;
    }
    put(b')');
    put(b' ');
    for &b in f.iface.as_bytes() {
        put(b);
    }
    put(b' ');
    let (id, idlen) = match f.kind {
        FrameKind::Error => ((f.id & CAN_ERR_MASK) | CAN_ERR_FLAG, 8),
        _ if f.extended => (f.id & CAN_ERR_MASK, 8),
        _ => (f.id & 0x7FF, 3),
    };
    for k in (0..idlen).rev() {
        put(HEX_UPPER[((id >> (4 * k)) & 0xF) as usize]);
    }
    put(b'#');
    let len = (f.len as usize).min(if f.fd { 64 } else { 8 });
    match f.kind {
        FrameKind::Remote if !f.fd => {
            put(b'R');
            if len > 0 {
                put(b'0' + len as u8);
            }
        }
        _ => {
            if f.fd {
                put(b'#');
                put(HEX_UPPER[(f.brs as usize) | ((f.esi as usize) << 1)]);
            }
            for &b in &f.data[..len] {
                put(HEX_UPPER[(b >> 4) as usize]);
                put(HEX_UPPER[(b & 0xF) as usize]);
            }
        }
    }
    if !f.fd && f.kind != FrameKind::Error && len == 8 && (9..=15).contains(&f.dlc) {
        put(b'_');
        put(HEX_UPPER[f.dlc as usize]);
    }
    put(b'\n');
    Ok(n)
}

/// Write `f` as one canonical `candump -L` line (see [`format_frame`]).
pub fn write_frame<W: io::Write>(w: &mut W, f: &Frame) -> io::Result<()> {
    let mut buf = [0u8; 256];
    let n = format_frame(f, &mut buf)?;
    w.write_all(&buf[..n])
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Every seed line, and each line one edit away from a seed: every byte replaced by each
    /// byte of `subst`, every byte removed and, with `duplicate`, every byte doubled.
    fn one_byte_variants(seeds: &[&[u8]], subst: &[u8], duplicate: bool) -> Vec<Vec<u8>> {
        let mut variants = Vec::new();
        for seed in seeds {
            variants.push(seed.to_vec());
            for i in 0..seed.len() {
                for &b in subst {
                    let mut v = seed.to_vec();
                    v[i] = b;
                    variants.push(v);
                }
                let mut v = seed.to_vec();
                v.remove(i);
                variants.push(v);
                if duplicate {
                    let mut v = seed.to_vec();
                    v.insert(i, seed[i]);
                    variants.push(v);
                }
            }
        }
        variants
    }

    /// The word-at-once microseconds equal the digit-by-digit reading: for every value's
    /// stride through 0-999999 and for every byte value at each of the seven positions.
    #[test]
    fn six_digit_word_reads_as_the_digits_do() {
        let naive = |w: &[u8]| -> Option<i64> {
            let ok = w[..6].iter().all(u8::is_ascii_digit) && w[6] == b')';
            ok.then(|| {
                w[..6]
                    .iter()
                    .fold(0i64, |a, &d| a * 10 + i64::from(d - b'0'))
            })
        };
        for v in (0..1_000_000).step_by(7).chain([999_999, 100_000, 9]) {
            let w = format!("{v:06}) x");
            assert_eq!(six_digits_then_paren(&w.as_bytes()[..8]), Some(v), "{w}");
        }
        for pos in 0..8 {
            for b in 0..=255u8 {
                let mut w = *b"123456) ";
                w[pos] = b;
                assert_eq!(six_digits_then_paren(&w), naive(&w), "{w:?}");
            }
        }
    }

    fn frame(line: &str) -> Frame {
        match parse_line(line.as_bytes()) {
            Ok(Parsed::Frame(f)) => f,
            other => panic!("{line:?}: {other:?}"),
        }
    }

    fn err(line: &str) -> ErrorKind {
        match parse_line(line.as_bytes()) {
            Err(e) => e.kind,
            other => panic!("{line:?} parsed: {other:?}"),
        }
    }

    #[test]
    fn classic_standard_and_extended() {
        let f = frame("(46408.584930) can0 260#08FFFB0000001884\n");
        assert_eq!(f.t_ns, 46_408_584_930_000);
        assert_eq!(f.iface.as_str(), "can0");
        assert_eq!((f.id, f.extended, f.len, f.dlc), (0x260, false, 8, 8));
        assert_eq!(f.payload(), &[0x08, 0xFF, 0xFB, 0, 0, 0, 0x18, 0x84]);
        let f = frame("(1.000000000) vcan0 0000012A#\r\n");
        assert_eq!(
            (f.id, f.extended, f.len, f.t_ns),
            (0x12A, true, 0, 1_000_000_000)
        );
        // Digit count decides: 8 digits is extended even for a small value.
        let f = frame("(0.000001) c 00000001#01");
        assert!(f.extended);
        assert_eq!(f.t_ns, 1000);
    }

    #[test]
    fn separators_case_whitespace_direction() {
        let f = frame("  (1.500000)\t\tcan1   1aB#de.AD.be.ef  T  ");
        assert_eq!(f.id, 0x1AB);
        assert_eq!(f.payload(), &[0xDE, 0xAD, 0xBE, 0xEF]);
        let f = frame("(1.500000) can1 1AB#DEAD R");
        assert_eq!(f.len, 2);
    }

    #[test]
    fn remote_frames() {
        let f = frame("(1.000000) can0 123#R");
        assert_eq!((f.kind, f.len), (FrameKind::Remote, 0));
        let f = frame("(1.000000) can0 123#r8");
        assert_eq!((f.kind, f.len, f.dlc), (FrameKind::Remote, 8, 8));
        let f = frame("(1.000000) can0 123#R8_E");
        assert_eq!((f.len, f.dlc), (8, 14));
        assert_eq!(err("(1.000000) can0 123#R9"), ErrorKind::RemoteLen(b'9'));
    }

    #[test]
    fn dlc_suffix() {
        let f = frame("(1.000000) can0 123#1122334455667788_9");
        assert_eq!((f.len, f.dlc), (8, 9));
        let f = frame("(1.000000) can0 123#1122334455667788_f");
        assert_eq!(f.dlc, 15);
        assert_eq!(err("(1.000000) can0 123#11_9"), ErrorKind::DlcSuffix(b'9'));
        assert_eq!(
            err("(1.000000) can0 123#1122334455667788_8"),
            ErrorKind::DlcSuffix(b'8')
        );
    }

    #[test]
    fn can_fd() {
        let f = frame("(1.000000) can0 123##1112233");
        assert!(f.fd && f.brs && !f.esi);
        assert_eq!(f.payload(), &[0x11, 0x22, 0x33]);
        let f = frame("(1.000000) can0 12345678##3");
        assert!(f.fd && f.brs && f.esi && f.extended);
        let f = frame("(1.000000) can0 123##4000102030405060708090A0B");
        assert_eq!((f.len, f.dlc), (12, 9));
        assert!(!f.brs);
        assert_eq!(
            err("(1.000000) can0 123##0000102030405060708"),
            ErrorKind::FdLength(9)
        );
        assert_eq!(err("(1.000000) can0 123##8"), ErrorKind::FdFlags(8));
        assert_eq!(err("(1.000000) can0 123##"), ErrorKind::NoFdFlags);
        let long = format!("(1.000000) can0 123##0{}", "00".repeat(65));
        assert_eq!(err(&long), ErrorKind::TooLong(64));
    }

    #[test]
    fn error_frames() {
        let f = frame("(1.000000) can0 20000080#0000000000000000");
        assert_eq!(f.kind, FrameKind::Error);
        assert_eq!(f.id, 0x80);
        assert!(!f.extended);
        assert_eq!(err("(1.000000) can0 20000080#R"), ErrorKind::ErrorFrameKind);
        assert_eq!(
            err("(1.000000) can0 40000080#00"),
            ErrorKind::ExtIdFlags(0x4000_0080)
        );
    }

    #[test]
    fn other_lines() {
        assert_eq!(parse_line(b"").unwrap(), Parsed::Comment);
        assert_eq!(parse_line(b"  \r\n").unwrap(), Parsed::Comment);
        assert_eq!(parse_line(b"# hello").unwrap(), Parsed::Comment);
        assert_eq!(
            parse_line(b"DROPCOUNT: dropped 3 CAN frames on 'can0' socket (total drops 7)\n")
                .unwrap(),
            Parsed::DropCount(3)
        );
        assert_eq!(
            parse_line(b"(1.000000) can0 123###80:00:00000000#AA").unwrap(),
            Parsed::SkippedXl
        );
    }

    #[test]
    fn errors_say_what_is_wrong() {
        assert_eq!(err("1.000000 can0 123#"), ErrorKind::NoTimestamp(b'1'));
        assert_eq!(err("(1.0000) can0 123#"), ErrorKind::TimestampFraction(4));
        assert_eq!(err("(1,000000) can0 123#"), ErrorKind::TimestampDot(b','));
        assert_eq!(err("(1.000000 can0 123#"), ErrorKind::TimestampClose(b' '));
        assert_eq!(err("(1.000000)"), ErrorKind::NoIface);
        assert_eq!(err("(1.000000) can0"), ErrorKind::NoFrame);
        assert_eq!(err("(1.000000) can0 123"), ErrorKind::NoHash);
        assert_eq!(err("(1.000000) can0 1234#00"), ErrorKind::IdDigits(4));
        assert_eq!(err("(1.000000) can0 800#00"), ErrorKind::StdIdRange(0x800));
        assert_eq!(err("(1.000000) can0 123#112"), ErrorKind::HalfByte);
        assert_eq!(
            err("(1.000000) can0 123#11G2"),
            ErrorKind::Hex {
                field: "the data",
                found: b'G'
            }
        );
        assert_eq!(
            err("(1.000000) can0 12G#11"),
            ErrorKind::Hex {
                field: "the CAN ID",
                found: b'G'
            }
        );
        assert_eq!(
            err("(1.000000) can0 123#112233445566778899"),
            ErrorKind::TooLong(8)
        );
        assert_eq!(err("(1.000000) can0 123#11 X"), ErrorKind::Trailing);
        assert_eq!(
            err("(1.000000) averyveryverylongname 123#11"),
            ErrorKind::IfaceTooLong(21)
        );
        // A half-written line is malformed, and the message names the column.
        let e = parse_line(b"(1.000000) can0 123#11223").unwrap_err();
        assert_eq!(
            e.to_string(),
            "column 25: odd number of hex digits in the data: half a byte at the end"
        );
    }

    #[test]
    fn writer_is_canonical() {
        let f = frame("(1.500000) can1 1ab#de.ad  T");
        let mut out = Vec::new();
        write_frame(&mut out, &f).unwrap();
        assert_eq!(out, b"(1.500000) can1 1AB#DEAD\n");
        for line in [
            "(1.000000001) can0 12345678##3AABB\n",
            "(0.000000) can0 123#R8_E\n",
            "(7.000000) can0 20000004#0000080000000000\n",
            "(7.000000) can0 7FF#1122334455667788_9\n",
            "(7.000000) can0 000#R\n",
        ] {
            let mut out = Vec::new();
            write_frame(&mut out, &frame(line)).unwrap();
            assert_eq!(String::from_utf8(out).unwrap(), line);
        }
        let mut f = frame("(1.000000) can0 123#");
        f.t_ns = -1;
        assert!(write_frame(&mut Vec::new(), &f).is_err());
    }

    /// The fast path must accept the common shapes, and whatever it accepts must be exactly
    /// what the full grammar returns, whatever frame `out` held before (a reused FD frame, a
    /// different interface). Checked over every single-byte substitution, deletion and
    /// duplication of a set of seed lines.
    #[test]
    fn fast_path_agrees_with_full_grammar() {
        let seeds: [&[u8]; 8] = [
            b"(46408.584930) can0 260#08FFFB0000001884",
            b"(1700000000.123456789) vcan12 1FFFFFFF#0102\r\n",
            b"(0.000001) can1 000#",
            b"(999999999999.999999) c 7FF#AABBCCDDEEFF0011\n",
            b"(12.000000) can0 00000123#de",
            b"(12.000000) can0 123#de.ad",
            b"(12.000000)  can0 123#11 R",
            b"(12.000000) can0 123#1122334455667788_9",
        ];
        // Seed 3 overflows 64-bit ns; 5-7 use separators, extra spaces, a direction, a DLC.
        let fast = [true, true, true, false, true, false, false, false];
        for (seed, fast) in seeds.iter().zip(fast) {
            assert_eq!(
                parse_common_into(seed, &mut Frame::empty(0)),
                fast,
                "fast path acceptance of {:?}",
                String::from_utf8_lossy(seed)
            );
        }
        let mut fd = Frame::fd(5, 0x10, false, &[0x55; 64]).unwrap();
        fd.set_iface("vcan0");
        let priors = [Frame::empty(0), fd, {
            let mut f = Frame::classic(1, 1, false, &[1; 8]).unwrap();
            f.set_iface("can0");
            f
        }];
        let variants = one_byte_variants(&seeds, b"0189aAfFgG#._ \t\r\n()R-\xff\xc3", true);
        let mut accepted = 0;
        for v in &variants {
            for prior in &priors {
                let mut out = *prior;
                if parse_common_into(v, &mut out) {
                    accepted += 1;
                    assert_eq!(
                        parse_line_full(v),
                        Ok(Parsed::Frame(out)),
                        "line {:?}",
                        String::from_utf8_lossy(v)
                    );
                }
                assert_eq!(parse_line(v), parse_line_full(v));
            }
        }
        assert!(
            accepted > 1000,
            "fast path accepted only {accepted} variants"
        );
    }

    /// The buffer-prefix parser agrees with the line parser: on every variant (followed by a
    /// next line, and cut short) it either declines or consumes exactly the line and its `\n`
    /// and yields exactly the frame `parse_common_into` gives; and it does take the common
    /// lines when the interface name is already known.
    #[test]
    fn prefix_parser_agrees_with_line_parser() {
        let seeds: [&[u8]; 5] = [
            b"(46408.584930) can0 260#08FFFB0000001884",
            b"(1700000000.123456789) can0 1FFFFFFF#0102\r",
            b"(0.000001) can0 000#",
            b"(12.000000) can0 00000123#de",
            b"(12.000000) can0 123#de.ad",
        ];
        let variants = one_byte_variants(&seeds, b"0189aAfFgG#._ \t\r\n()R-\xff", false);
        let mut prior = Frame::classic(1, 1, false, &[1; 8]).unwrap();
        prior.set_iface("can0");
        let mut taken = 0;
        for v in &variants {
            let mut buf = v.clone();
            buf.extend_from_slice(b"\n(1.000000) can0 123#11\n");
            for cut in [buf.len(), v.len() + 1, v.len()] {
                let mut got = prior;
                if let Some(used) = parse_common_prefix(&buf[..cut], &mut got) {
                    taken += 1;
                    let line_end = memchr::memchr(b'\n', &buf).unwrap();
                    assert_eq!(used, line_end + 1, "line {:?}", String::from_utf8_lossy(v));
                    let mut want = prior;
                    assert!(parse_common_into(&buf[..line_end], &mut want));
                    assert_eq!(got, want, "line {:?}", String::from_utf8_lossy(v));
                }
            }
        }
        assert!(taken > 200, "prefix parser took only {taken} lines");
        let mut f = prior;
        assert_eq!(
            parse_common_prefix(b"(1.000000) can0 123#11\n", &mut f),
            Some(23)
        );
        assert_eq!((f.id, f.len, f.data[0]), (0x123, 1, 0x11));
        assert_eq!(parse_common_prefix(b"(1.000000) can0 123#11", &mut f), None);
        assert_eq!(
            parse_common_prefix(b"(1.000000) can1 123#11\n", &mut f),
            None
        );
    }
}
