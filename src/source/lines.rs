//! A line splitter over any `Read` with one fixed buffer: lines are handed out as slices of
//! that buffer, so reading a file of any size allocates nothing per line and uses constant
//! memory.
//!
//! Not a parser: it only finds line ends, numbers lines, and flags the two ways a line can be
//! unusable before parsing (longer than the buffer; last line without its newline).

use std::io::{self, Read};

/// Default buffer size; also the longest line that can be handed out whole.
pub const DEFAULT_CAPACITY: usize = 256 * 1024;

/// One line as found.
#[derive(Debug, PartialEq, Eq)]
pub enum Line<'a> {
    /// The line's bytes without its `\n` (a `\r` before it is left in place).
    /// `terminated` is false only for a last line that ends at end of input without `\n`.
    Text { bytes: &'a [u8], terminated: bool },
    /// A line longer than the buffer; its bytes were discarded.
    TooLong,
}

pub struct LineReader<R> {
    inner: R,
    buf: Box<[u8]>,
    start: usize,
    end: usize,
    eof: bool,
    discarding: bool,
    line_no: u64,
}

impl<R: Read> LineReader<R> {
    pub fn new(inner: R) -> Self {
        Self::with_capacity(inner, DEFAULT_CAPACITY)
    }

    pub fn with_capacity(inner: R, capacity: usize) -> Self {
        LineReader {
            inner,
            buf: vec![0; capacity.max(16)].into_boxed_slice(),
            start: 0,
            end: 0,
            eof: false,
            discarding: false,
            line_no: 0,
        }
    }

    /// 1-based number of the line last returned.
    pub fn line_no(&self) -> u64 {
        self.line_no
    }

    /// Fast path: if a whole `\n`-terminated line is already in the buffer and `parse`
    /// accepts it (its bytes without the `\n`), consume it and return true. Otherwise consume
    /// nothing and return false (the caller then uses [`LineReader::next_line`]; a line that
    /// spans a refill goes that way, and the refill compacts the buffer so the following lines
    /// are whole again). No per-line enum, no refill check on the hot path.
    #[inline]
    pub fn try_parse_next(&mut self, parse: impl FnOnce(&[u8]) -> bool) -> bool {
        if self.discarding {
            return false;
        }
        let avail = &self.buf[self.start..self.end];
        match memchr::memchr(b'\n', avail) {
            Some(pos) if parse(&avail[..pos]) => {
                self.start += pos + 1;
                self.line_no += 1;
                true
            }
            _ => false,
        }
    }

    /// Faster variant of [`LineReader::try_parse_next`] for parsers that find the line end
    /// themselves: `parse` gets every buffered byte from the start of the next line and returns
    /// how many bytes that line takes including its `\n` (at least 1, only bytes of one whole
    /// line), or `None` to consume nothing. Saves the separate newline search.
    #[inline]
    pub fn try_parse_prefix(&mut self, parse: impl FnOnce(&[u8]) -> Option<usize>) -> bool {
        if self.discarding {
            return false;
        }
        match parse(&self.buf[self.start..self.end]) {
            Some(used) => {
                debug_assert!(used >= 1 && self.buf[self.start + used - 1] == b'\n');
                self.start += used;
                self.line_no += 1;
                true
            }
            None => false,
        }
    }

    /// The next line, or `None` at end of input.
    pub fn next_line(&mut self) -> io::Result<Option<Line<'_>>> {
        loop {
            if let Some(pos) = memchr::memchr(b'\n', &self.buf[self.start..self.end]) {
                let s = self.start;
                self.start += pos + 1;
                self.line_no += 1;
                if self.discarding {
                    self.discarding = false;
                    return Ok(Some(Line::TooLong));
                }
                return Ok(Some(Line::Text {
                    bytes: &self.buf[s..s + pos],
                    terminated: true,
                }));
            }
            if self.eof {
                if self.start < self.end || self.discarding {
                    let s = self.start;
                    let e = self.end;
                    self.start = self.end;
                    self.line_no += 1;
                    if self.discarding {
                        self.discarding = false;
                        return Ok(Some(Line::TooLong));
                    }
                    return Ok(Some(Line::Text {
                        bytes: &self.buf[s..e],
                        terminated: false,
                    }));
                }
                return Ok(None);
            }
            if self.discarding {
                self.start = 0;
                self.end = 0;
            } else if self.start > 0 {
                self.buf.copy_within(self.start..self.end, 0);
                self.end -= self.start;
                self.start = 0;
            } else if self.end == self.buf.len() {
                // A whole buffer without a newline: drop it and the rest of the line.
                self.discarding = true;
                self.start = 0;
                self.end = 0;
            }
            let n = loop {
                match self.inner.read(&mut self.buf[self.end..]) {
                    Ok(n) => break n,
                    Err(e) if e.kind() == io::ErrorKind::Interrupted => continue,
                    Err(e) => return Err(e),
                }
            };
            if n == 0 {
                self.eof = true;
            }
            self.end += n;
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// (line number, Some((bytes, terminated)) or None for an over-long line)
    type Got = Vec<(u64, Option<(Vec<u8>, bool)>)>;

    fn collect(input: &[u8], cap: usize) -> Got {
        let mut r = LineReader::with_capacity(input, cap);
        let mut out = Vec::new();
        while let Some(l) = r.next_line().unwrap() {
            let v = match l {
                Line::Text { bytes, terminated } => Some((bytes.to_vec(), terminated)),
                Line::TooLong => None,
            };
            out.push((r.line_no(), v));
        }
        out
    }

    #[test]
    fn splits_lines_across_refills() {
        let got = collect(b"ab\ncdefgh\n\nxyz", 16);
        assert_eq!(
            got,
            vec![
                (1, Some((b"ab".to_vec(), true))),
                (2, Some((b"cdefgh".to_vec(), true))),
                (3, Some((b"".to_vec(), true))),
                (4, Some((b"xyz".to_vec(), false))),
            ]
        );
    }

    /// The fast path and `next_line` together see every line once, in order, including a
    /// line that spans a refill and lines the fast path declines.
    #[test]
    fn try_parse_next_interleaves_with_next_line() {
        let mut r = LineReader::with_capacity(&b"ab\ncdefgh\n\nxyz1234567890\nok\nend"[..], 16);
        let mut got: Vec<(u64, Vec<u8>, bool)> = Vec::new();
        loop {
            let mut fast = None;
            if r.try_parse_next(|l| {
                fast = Some(l.to_vec());
                !l.is_empty()
            }) {
                got.push((r.line_no(), fast.unwrap(), true));
                continue;
            }
            let bytes = match r.next_line().unwrap() {
                Some(Line::Text { bytes, .. }) => bytes.to_vec(),
                Some(Line::TooLong) => panic!("no line is too long"),
                None => break,
            };
            got.push((r.line_no(), bytes, false));
        }
        let lines: Vec<&[u8]> = got.iter().map(|g| &g.1[..]).collect();
        assert_eq!(
            lines,
            vec![&b"ab"[..], b"cdefgh", b"", b"xyz1234567890", b"ok", b"end"]
        );
        assert_eq!(
            got.iter().map(|g| g.0).collect::<Vec<_>>(),
            vec![1, 2, 3, 4, 5, 6]
        );
        assert!(
            got[1].2 && !got[2].2,
            "a whole buffered line takes the fast path; the empty one is declined"
        );
        assert!(!got[5].2, "unterminated last line goes through next_line");
    }

    #[test]
    fn over_long_line_is_reported_once_and_reading_goes_on() {
        let mut input = vec![b'a'; 100];
        input.extend_from_slice(b"\nok\n");
        input.extend_from_slice(&[b'b'; 40]);
        let got = collect(&input, 16);
        assert_eq!(
            got,
            vec![(1, None), (2, Some((b"ok".to_vec(), true))), (3, None)]
        );
    }
}
