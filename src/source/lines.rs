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
