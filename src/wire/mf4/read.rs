//! Streaming MDF 4 bus logging reader.
//!
//! Understood: MDF 4.00–4.11 (and later 4.x files using only these blocks); sorted data groups
//! (one channel group each) and unsorted ones (record IDs of 1, 2, 4 or 8 bytes demultiplexed
//! record by record); data blocks `DT`, `DZ` (deflate, and transposition + deflate), data lists
//! `DL` (chained) and header lists `HL`; `DataBytes` stored in the record, as VLSD records of a
//! channel group of the same data group, or in signal data (`SD`, or `DZ`/`DL`/`HL` of SD);
//! members stored as bit fields (little-endian, or big-endian byte-aligned), floats, or virtual
//! (the record index through a conversion, as newer CANedge firmware writes constant members);
//! conversions identity, linear, value-to-value tables and (for `BusChannel`) value-to-text;
//! unfinalized files (`UnFinMF`): cycle counters ignored, the last DT block read up to the next
//! block or the end of the file, and a record cut by the end of the file reported.
//! Groups of other buses (LIN, FlexRay, Ethernet...) are recognised and their records reported
//! as [`Mf4Step::Other`].
//!
//! Frames come out in time order across data groups (a merge of one cursor per data group), and
//! in file order inside an unsorted data group (the order the logger wrote them).
//!
//! Memory is bounded whatever the file size: the metadata (a few hundred bytes per channel
//! group), one 256 KiB read buffer per data group (and per signal data stream), and one
//! decompressed block per data group, refused above [`MAX_BLOCK`]. Hostile input is an
//! [`Mf4Error`], never a panic: links are range-checked, chains checked for loops, block and
//! record lengths checked against the file and fixed limits, the data blocks of one data group
//! may add up to at most the file's size (a list that names a block twice cannot loop), and a
//! compressed block must inflate to exactly its declared length (at most 1032× its compressed
//! size, deflate's limit).
//!
//! Not here: what a frame means, or counting skips ([`crate::source::log`]).

use super::{ID_UNFINALIZED, UNFIN_CG_COUNTERS, UNFIN_LAST_DT_LENGTH};
use crate::wire::asc::CAN_ERR_PROT;
use crate::wire::frame::{fd_dlc_to_len, fd_len_to_dlc, Frame, FrameKind, IfaceName, MAX_DATA};
use flate2::{Decompress, FlushDecompress, Status};
use std::collections::HashSet;
use std::io::{self, Read, Seek, SeekFrom};

/// Largest data block held in memory once decompressed (asammdf writes at most 4 MiB).
pub const MAX_BLOCK: u64 = 64 << 20;
/// Largest metadata block read (text, conversion, data list).
pub const MAX_META: u64 = 16 << 20;
/// Most metadata blocks visited when opening a file.
pub const MAX_META_BLOCKS: usize = 200_000;
/// Largest VLSD record (a CAN payload is at most 64 bytes; longer records are skipped over).
pub const MAX_VLSD: u64 = 1 << 30;
const CHUNK: usize = 256 * 1024;
/// Deflate cannot expand by more than this factor (plus a small constant).
const MAX_INFLATE_RATIO: u64 = 1032;
/// How often a signal data stream may be rewound (offsets going backwards) before it is refused.
const MAX_REWINDS: u32 = 64;

/// What is wrong with an MDF 4 file.
#[derive(Debug, thiserror::Error)]
pub enum Mf4Error {
    #[error("I/O error: {0}")]
    Io(#[from] io::Error),
    #[error("not an MDF 4 file (identification {0:?})")]
    NotMdf(String),
    #[error("MDF version {0} is not supported (4.00 and later 4.x)")]
    Version(u16),
    #[error("file ends inside a block at byte {0} (truncated file)")]
    TruncatedBlock(u64),
    #[error("link to byte {at} is outside the file ({len} bytes)")]
    OutOfRange { at: u64, len: u64 },
    #[error("expected {want} at byte {at}, found {found:?}")]
    BlockType {
        want: &'static str,
        at: u64,
        found: String,
    },
    #[error("block at byte {at} declares an impossible length {len}")]
    BlockLength { at: u64, len: u64 },
    #[error("the {0} chain loops back on itself")]
    Cycle(&'static str),
    #[error("more than {MAX_META_BLOCKS} metadata blocks")]
    TooManyBlocks,
    #[error("compressed block at byte {at}: {what}")]
    Zip { at: u64, what: String },
    #[error(
        "data block at byte {at} is {size} bytes uncompressed, above the {MAX_BLOCK} byte limit"
    )]
    BlockTooLarge { at: u64, size: u64 },
    #[error(
        "the data blocks of a data group add up to more than the file: a block is listed twice"
    )]
    DataLoop,
    #[error("{0} blocks (MDF 4.2 column storage) are not supported")]
    Unsupported(&'static str),
    #[error("record ID {id} belongs to no channel group of its data group; rest of the data group skipped")]
    UnknownRecord { id: u64 },
    #[error("data ends inside a record of group {group:?} (unfinalized or truncated file)")]
    PartialRecord { group: String },
    #[error("VLSD record of {0} bytes is above the limit; rest of the data group skipped")]
    VlsdTooLong(u64),
    #[error("group {group:?}: no signal data at offset {offset} for a frame's DataBytes")]
    MissingSignalData { group: String, offset: u64 },
    #[error("channel group {group:?}: {what}")]
    Layout { group: String, what: String },
}

/// What one step of the reader produced.
#[derive(Debug)]
pub enum Mf4Step {
    /// A frame, written into the caller's frame.
    Frame,
    /// A record of a non-CAN group (LIN, other buses, plain signals) or of a CAN group that
    /// could not be understood (see [`Mf4Reader::warnings`]).
    Other,
    /// Something wrong; reading goes on after it (the data group concerned may have ended).
    Error(Mf4Error),
    End,
}

// ---------------------------------------------------------------------------------------------
// Metadata

fn u16le(b: &[u8], at: usize) -> u16 {
    u16::from_le_bytes([b[at], b[at + 1]])
}
fn u32le(b: &[u8], at: usize) -> u32 {
    u32::from_le_bytes(b[at..at + 4].try_into().unwrap())
}
fn u64le(b: &[u8], at: usize) -> u64 {
    u64::from_le_bytes(b[at..at + 8].try_into().unwrap())
}

fn uint_le(b: &[u8]) -> u64 {
    let mut a = [0u8; 8];
    a[..b.len()].copy_from_slice(b);
    u64::from_le_bytes(a)
}

/// One metadata block: its links and data section.
struct Block {
    id: [u8; 4],
    links: Vec<u64>,
    data: Vec<u8>,
}

impl Block {
    fn link(&self, i: usize) -> u64 {
        self.links.get(i).copied().unwrap_or(0)
    }
    /// Data bytes `at..at+n`, or zeros past the end (older versions' blocks are shorter).
    fn bytes<const N: usize>(&self, at: usize) -> [u8; N] {
        let mut b = [0u8; N];
        if at < self.data.len() {
            let n = N.min(self.data.len() - at);
            b[..n].copy_from_slice(&self.data[at..at + n]);
        }
        b
    }
    fn u8(&self, at: usize) -> u8 {
        self.bytes::<1>(at)[0]
    }
    fn u16(&self, at: usize) -> u16 {
        u16::from_le_bytes(self.bytes(at))
    }
    fn u32(&self, at: usize) -> u32 {
        u32::from_le_bytes(self.bytes(at))
    }
    fn u64(&self, at: usize) -> u64 {
        u64::from_le_bytes(self.bytes(at))
    }
    fn f64(&self, at: usize) -> f64 {
        f64::from_le_bytes(self.bytes(at))
    }
}

/// File access shared by the metadata walk and the data cursors.
struct Io<R> {
    file: R,
    len: u64,
    /// Where the file position is (avoids a seek per sequential read).
    at: u64,
    meta_read: usize,
    /// Sorted addresses of the metadata blocks read (where an unfinalized DT block ends).
    meta_addrs: Vec<u64>,
}

impl<R: Read + Seek> Io<R> {
    fn check_link(&self, at: u64) -> Result<(), Mf4Error> {
        if at < 64 || at.checked_add(24).is_none_or(|e| e > self.len) {
            return Err(Mf4Error::OutOfRange { at, len: self.len });
        }
        Ok(())
    }

    fn read_at(&mut self, at: u64, buf: &mut [u8]) -> Result<(), Mf4Error> {
        if at
            .checked_add(buf.len() as u64)
            .is_none_or(|e| e > self.len)
        {
            return Err(Mf4Error::TruncatedBlock(at));
        }
        if self.at != at {
            self.file.seek(SeekFrom::Start(at))?;
            self.at = at;
        }
        match self.file.read_exact(buf) {
            Ok(()) => {
                self.at += buf.len() as u64;
                Ok(())
            }
            Err(e) if e.kind() == io::ErrorKind::UnexpectedEof => {
                self.at = u64::MAX;
                Err(Mf4Error::TruncatedBlock(at))
            }
            Err(e) => {
                self.at = u64::MAX;
                Err(e.into())
            }
        }
    }

    /// The 24-byte header at `at`: (id, length, link count), with the length checked.
    fn header(&mut self, at: u64) -> Result<([u8; 4], u64, u64), Mf4Error> {
        self.check_link(at)?;
        let mut h = [0u8; 24];
        self.read_at(at, &mut h)?;
        let id: [u8; 4] = h[0..4].try_into().unwrap();
        let len = u64le(&h, 8);
        let links = u64le(&h, 16);
        if len < 24 || links > (len - 24) / 8 {
            return Err(Mf4Error::BlockLength { at, len });
        }
        Ok((id, len, links))
    }

    /// A whole metadata block of one of the `want` types.
    fn block(&mut self, at: u64, want: &'static str) -> Result<Block, Mf4Error> {
        self.meta_read += 1;
        if self.meta_read > MAX_META_BLOCKS {
            return Err(Mf4Error::TooManyBlocks);
        }
        let (id, len, nlinks) = self.header(at)?;
        if !want.split('|').any(|w| w.as_bytes() == &id[2..]) || &id[..2] != b"##" {
            return Err(Mf4Error::BlockType {
                want,
                at,
                found: String::from_utf8_lossy(&id).into_owned(),
            });
        }
        if len > MAX_META {
            return Err(Mf4Error::BlockLength { at, len });
        }
        if at + len > self.len {
            return Err(Mf4Error::TruncatedBlock(at));
        }
        let mut body = vec![0u8; (len - 24) as usize];
        self.read_at(at + 24, &mut body)?;
        let links = (0..nlinks as usize).map(|i| u64le(&body, 8 * i)).collect();
        let data = body.split_off(nlinks as usize * 8);
        self.meta_addrs.push(at);
        Ok(Block { id, links, data })
    }

    /// The text of a TX block (empty for a null link or an MD block).
    fn text(&mut self, at: u64) -> Result<String, Mf4Error> {
        if at == 0 {
            return Ok(String::new());
        }
        let b = self.block(at, "TX|MD")?;
        if &b.id[2..] != b"TX" {
            return Ok(String::new());
        }
        let end = b.data.iter().position(|&c| c == 0).unwrap_or(b.data.len());
        Ok(String::from_utf8_lossy(&b.data[..end.min(4096)]).into_owned())
    }
}

/// How a member's raw value is stored in the record.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
enum Src {
    #[default]
    Absent,
    /// Unsigned or signed integer bit field.
    Int {
        byte: usize,
        nbytes: usize,
        bit: u32,
        count: u32,
        signed: bool,
        be: bool,
    },
    Float {
        byte: usize,
        size: usize,
        be: bool,
    },
    /// No bits: the raw value is the record's index in its group.
    Virtual,
}

#[derive(Clone, Debug, Default, PartialEq)]
enum Conv {
    #[default]
    Identity,
    /// `a + b·x`.
    Linear(f64, f64),
    /// Value-to-value table (with or without interpolation: keys are looked up exactly, and
    /// interpolated between when `interp`).
    Table {
        keys: Vec<f64>,
        vals: Vec<f64>,
        interp: bool,
    },
}

#[derive(Clone, Debug, Default)]
struct Field {
    src: Src,
    conv: Conv,
}

impl Field {
    fn present(&self) -> bool {
        self.src != Src::Absent
    }

    #[inline]
    fn raw_int(rec: &[u8], byte: usize, nbytes: usize, bit: u32, count: u32, be: bool) -> u64 {
        if be {
            let mut v = 0u64;
            for &b in &rec[byte..byte + nbytes] {
                v = v << 8 | b as u64;
            }
            return v;
        }
        if nbytes <= 8 && byte + 8 <= rec.len() {
            let v = u64::from_le_bytes(rec[byte..byte + 8].try_into().unwrap()) >> bit;
            return if count >= 64 {
                v
            } else {
                v & ((1u64 << count) - 1)
            };
        }
        let mut b = [0u8; 16];
        b[..nbytes].copy_from_slice(&rec[byte..byte + nbytes]);
        let v = (u128::from_le_bytes(b) >> bit) as u64;
        if count >= 64 {
            v
        } else {
            v & ((1u64 << count) - 1)
        }
    }

    /// The raw value as f64 (`None` when absent).
    #[inline]
    fn raw_f64(&self, rec: &[u8], idx: u64) -> Option<f64> {
        Some(match self.src {
            Src::Absent => return None,
            Src::Int {
                byte,
                nbytes,
                bit,
                count,
                signed,
                be,
            } => {
                let v = Self::raw_int(rec, byte, nbytes, bit, count, be);
                if signed && count < 64 && v >> (count - 1) & 1 == 1 {
                    (v | !((1u64 << count) - 1)) as i64 as f64
                } else if signed {
                    v as i64 as f64
                } else {
                    v as f64
                }
            }
            Src::Float { byte, size, be } => {
                let s = &rec[byte..byte + size];
                match (size, be) {
                    (4, false) => f32::from_le_bytes(s.try_into().unwrap()) as f64,
                    (4, true) => f32::from_be_bytes(s.try_into().unwrap()) as f64,
                    (8, false) => f64::from_le_bytes(s.try_into().unwrap()),
                    _ => f64::from_be_bytes(s.try_into().unwrap()),
                }
            }
            Src::Virtual => idx as f64,
        })
    }

    /// The converted value as an unsigned integer (rounded, saturating), `None` when absent.
    #[inline]
    fn uint(&self, rec: &[u8], idx: u64) -> Option<u64> {
        if let (
            Src::Int {
                byte,
                nbytes,
                bit,
                count,
                signed: false,
                be,
            },
            Conv::Identity,
        ) = (self.src, &self.conv)
        {
            return Some(Self::raw_int(rec, byte, nbytes, bit, count, be));
        }
        let x = self.raw_f64(rec, idx)?;
        let y = self.conv.apply(x);
        Some(if y.is_finite() && y > 0.0 {
            y.round() as u64
        } else {
            0
        })
    }
}

impl Conv {
    fn apply(&self, x: f64) -> f64 {
        match self {
            Conv::Identity => x,
            Conv::Linear(a, b) => a + b * x,
            Conv::Table { keys, vals, interp } => {
                if keys.is_empty() {
                    return x;
                }
                // Keys are sorted ascending (the format requires it).
                let i = keys.partition_point(|&k| k < x);
                if i < keys.len() && keys[i] == x {
                    return vals[i];
                }
                if i == 0 {
                    return vals[0];
                }
                if i == keys.len() {
                    return vals[keys.len() - 1];
                }
                if *interp {
                    let (k0, k1, v0, v1) = (keys[i - 1], keys[i], vals[i - 1], vals[i]);
                    v0 + (v1 - v0) * (x - k0) / (k1 - k0)
                } else if x - keys[i - 1] <= keys[i] - x {
                    vals[i - 1]
                } else {
                    vals[i]
                }
            }
        }
    }
}

/// The master (time) channel: record → ns since the header's start.
#[derive(Clone, Debug, Default)]
struct Time {
    field: Field,
    /// Exact integer path: ns = raw · mul + off (integer raw, linear conversion whose factor
    /// is a whole number of ns).
    exact: Option<(i64, i64)>,
}

impl Time {
    fn new(field: Field) -> Time {
        let (a, b) = match field.conv {
            Conv::Identity => (0.0, 1.0),
            Conv::Linear(a, b) => (a, b),
            Conv::Table { .. } => return Time { field, exact: None },
        };
        let int = matches!(field.src, Src::Int { .. } | Src::Virtual);
        let mul = b * 1e9;
        let off = a * 1e9;
        let whole = |v: f64| {
            v.is_finite() && v.abs() < 9e18 && (v - v.round()).abs() <= 1e-6 * v.abs().max(1.0)
        };
        let exact = (int && mul >= 0.5 && whole(mul) && whole(off))
            .then(|| (mul.round() as i64, off.round() as i64));
        Time { field, exact }
    }

    #[inline]
    fn ns(&self, rec: &[u8], idx: u64) -> i64 {
        if let (
            Some((mul, off)),
            Src::Int {
                byte,
                nbytes,
                bit,
                count,
                signed: false,
                be,
            },
        ) = (self.exact, self.field.src)
        {
            let raw = Field::raw_int(rec, byte, nbytes, bit, count, be);
            return (raw as i64).saturating_mul(mul).saturating_add(off);
        }
        let x = self.field.raw_f64(rec, idx).unwrap_or(0.0);
        if let Some((mul, off)) = self.exact {
            return (x as i64).saturating_mul(mul).saturating_add(off);
        }
        let s = self.field.conv.apply(x);
        let ns = (s * 1e9).round();
        if ns.is_finite() {
            ns as i64 // saturating cast
        } else {
            0
        }
    }
}

/// Where a CAN group's DataBytes are.
#[derive(Clone, Debug, Default)]
enum Payload {
    #[default]
    None,
    /// In the record.
    Fixed { byte: usize, len: usize },
    /// An offset (`width` bytes, little-endian) in the record into the VLSD records of channel
    /// group `cg` (same data group).
    VlsdCg {
        byte: usize,
        width: usize,
        cg: usize,
    },
    /// An offset in the record into signal data stream `sd`.
    Sd {
        byte: usize,
        width: usize,
        sd: usize,
    },
    /// VLSD without signal data (asammdf writes none for an empty group): any record of the
    /// group is reported.
    Unresolved,
}

#[derive(Clone, Copy, Debug, PartialEq)]
enum CgKind {
    Can(FrameKind),
    /// Variable-length records referenced by another group's VLSD channel.
    Vlsd,
    Other,
}

/// Everything needed to turn one record of a channel group into a frame.
struct Cg {
    name: String,
    kind: CgKind,
    record_id: u64,
    /// Record bytes after the record ID (data + invalidation bytes).
    rec_len: usize,
    cycles: u64,
    time: Time,
    bus: Field,
    bus_names: Vec<(u64, IfaceName)>,
    id: Field,
    ide: Field,
    dlc: Field,
    dlen: Field,
    edl: Field,
    brs: Field,
    esi: Field,
    payload: Payload,
    /// Records seen so far (the raw value of virtual members).
    count: u64,
    /// VLSD groups: stream offset of the next record, and the last few payloads by offset.
    vlsd_next: u64,
    vlsd_ring: Box<[(u64, u8, [u8; MAX_DATA])]>,
    vlsd_head: usize,
}

const RING: usize = 16;
/// How far ahead a frame's VLSD record is looked for (records, bytes).
const PEEK_RECORDS: usize = 64;
const PEEK_BYTES: usize = 64 * 1024;

impl Cg {
    fn blank(name: String, record_id: u64, rec_len: usize, cycles: u64, kind: CgKind) -> Cg {
        Cg {
            name,
            kind,
            record_id,
            rec_len,
            cycles,
            time: Time::default(),
            bus: Field::default(),
            bus_names: Vec::new(),
            id: Field::default(),
            ide: Field::default(),
            dlc: Field::default(),
            dlen: Field::default(),
            edl: Field::default(),
            brs: Field::default(),
            esi: Field::default(),
            payload: Payload::None,
            count: 0,
            vlsd_next: 0,
            vlsd_ring: Box::new([]),
            vlsd_head: 0,
        }
    }

    fn iface(&self, ch: u64) -> IfaceName {
        for (k, n) in &self.bus_names {
            if *k == ch {
                return *n;
            }
        }
        let i = ch.saturating_sub(1);
        let mut buf = [0u8; 24];
        let mut w = &mut buf[..];
        use std::io::Write;
        let _ = write!(w, "can{i}");
        let n = 24 - w.len();
        IfaceName::from_bytes(&buf[..n]).unwrap_or_default()
    }

    /// Fill `out` from one record; `payload` is the resolved VLSD/SD payload, if any.
    #[inline]
    fn decode(&self, rec: &[u8], idx: u64, start_ns: i64, vl: Option<&[u8]>, out: &mut Frame) {
        let CgKind::Can(kind) = self.kind else {
            return;
        };
        out.t_ns = start_ns.saturating_add(self.time.ns(rec, idx));
        out.kind = kind;
        if self.bus.present() {
            let ch = self.bus.uint(rec, idx).unwrap_or(0);
            out.iface = self.iface(ch);
        } else {
            out.iface = self.iface(1);
        }
        let raw_id = self.id.uint(rec, idx).unwrap_or(0);
        let ext = match self.ide.uint(rec, idx) {
            Some(v) => v != 0,
            None => raw_id > 0x7FF,
        } || raw_id & 0x8000_0000 != 0;
        let flag = |f: &Field| f.uint(rec, idx).unwrap_or(0) != 0;
        let fd = kind == FrameKind::Data && flag(&self.edl);
        out.fd = fd;
        out.brs = fd && flag(&self.brs);
        out.esi = fd && flag(&self.esi);
        let payload: &[u8] = match (&self.payload, vl) {
            (_, Some(p)) => p,
            (Payload::Fixed { byte, len }, None) => &rec[*byte..*byte + *len],
            _ => &[],
        };
        out.data = [0; MAX_DATA];
        match kind {
            FrameKind::Error => {
                out.extended = false;
                out.id = if self.id.present() {
                    raw_id as u32 & 0x1FFF_FFFF
                } else {
                    CAN_ERR_PROT
                };
                let n = payload.len().min(8);
                out.data[..n].copy_from_slice(&payload[..n]);
                out.len = 8;
                out.dlc = 8;
                out.fd = false;
                out.brs = false;
                out.esi = false;
            }
            _ => {
                out.extended = ext;
                out.id = (raw_id as u32) & if ext { 0x1FFF_FFFF } else { 0x7FF };
                let dlc = match self.dlc.uint(rec, idx) {
                    Some(d) => d.min(15) as u8,
                    None => {
                        let n = self.dlen.uint(rec, idx).unwrap_or(payload.len() as u64) as usize;
                        if fd {
                            fd_len_to_dlc(n.min(64))
                        } else {
                            n.min(8) as u8
                        }
                    }
                };
                let want = if fd {
                    fd_dlc_to_len(dlc)
                } else {
                    (dlc as usize).min(8)
                };
                if kind == FrameKind::Remote {
                    out.len = want as u8;
                    out.dlc = dlc;
                } else {
                    let n = want.min(payload.len());
                    out.data[..n].copy_from_slice(&payload[..n]);
                    out.len = n as u8;
                    out.dlc = if fd {
                        fd_len_to_dlc(n)
                    } else if n == 8 {
                        dlc
                    } else {
                        n as u8
                    };
                }
            }
        }
    }
}

fn layout_err(group: &str, what: impl Into<String>) -> Mf4Error {
    Mf4Error::Layout {
        group: group.to_string(),
        what: what.into(),
    }
}

/// One channel as read from its CN block (before it is assigned to a member).
struct Cn {
    name: String,
    cn_type: u8,
    sync: u8,
    data_type: u8,
    bit: u32,
    byte: u64,
    count: u32,
    conv_at: u64,
    data_at: u64,
}

impl<R: Read + Seek> Io<R> {
    /// Every channel of a channel group's tree (compositions followed, depth ≤ 4).
    fn channels(&mut self, first: u64, out: &mut Vec<Cn>) -> Result<(), Mf4Error> {
        let mut seen = HashSet::new();
        let mut stack = vec![(first, 0u32)];
        while let Some((mut at, depth)) = stack.pop() {
            while at != 0 {
                if !seen.insert(at) {
                    return Err(Mf4Error::Cycle("channel"));
                }
                let b = self.block(at, "CN")?;
                let name = self.text(b.link(2))?;
                let comp = b.link(1);
                if comp != 0 && depth < 4 {
                    let (id, _, _) = self.header(comp)?;
                    if &id == b"##CN" {
                        stack.push((comp, depth + 1));
                    }
                }
                out.push(Cn {
                    name,
                    cn_type: b.u8(0),
                    sync: b.u8(1),
                    data_type: b.u8(2),
                    bit: b.u8(3) as u32,
                    byte: b.u32(4) as u64,
                    count: b.u32(8),
                    conv_at: b.link(4),
                    data_at: b.link(5),
                });
                if out.len() > 10_000 {
                    return Err(Mf4Error::TooManyBlocks);
                }
                at = b.link(0);
            }
        }
        Ok(())
    }

    /// A conversion (identity for a null link or an unsupported type), with value-to-text
    /// pairs when `texts` is given.
    fn conv(
        &mut self,
        at: u64,
        group: &str,
        texts: Option<&mut Vec<(u64, IfaceName)>>,
    ) -> Result<Conv, Mf4Error> {
        if at == 0 {
            return Ok(Conv::Identity);
        }
        let b = self.block(at, "CC")?;
        let ty = b.u8(0);
        let nval = b.u16(6) as usize;
        let val = |i: usize| b.f64(24 + 8 * i);
        if 24 + 8 * nval > b.data.len() {
            return Err(layout_err(
                group,
                "conversion block shorter than its value count",
            ));
        }
        Ok(match ty {
            0 => Conv::Identity,
            1 => Conv::Linear(val(0), val(1)),
            4 | 5 => {
                let n = nval / 2;
                let keys: Vec<f64> = (0..n).map(|i| val(2 * i)).collect();
                let vals: Vec<f64> = (0..n).map(|i| val(2 * i + 1)).collect();
                if keys.windows(2).any(|w| w[0] > w[1]) {
                    return Err(layout_err(group, "value table keys are not ascending"));
                }
                Conv::Table {
                    keys,
                    vals,
                    interp: ty == 4,
                }
            }
            7 => {
                if let Some(texts) = texts {
                    for i in 0..nval.min(4096) {
                        let t = self.text(b.link(4 + i))?;
                        if let Some(n) =
                            IfaceName::from_bytes(t.as_bytes()).filter(|n| !n.is_empty())
                        {
                            texts.push((val(i).max(0.0) as u64, n));
                        }
                    }
                }
                Conv::Identity
            }
            t => {
                return Err(layout_err(
                    group,
                    format!("conversion type {t} is not supported for bus logging members"),
                ))
            }
        })
    }

    fn field(&mut self, cn: &Cn, group: &str, rec_data: usize) -> Result<Field, Mf4Error> {
        let src = match cn.cn_type {
            6 | 3 => Src::Virtual,
            0 | 2 | 4 => {
                // The format keeps bit offsets at 0-7; a larger one is read as whole bytes on.
                let bit = cn.bit % 8;
                let count = cn.count;
                let byte = (cn.byte as usize).saturating_add(cn.bit as usize / 8);
                let nbytes = (bit as usize + count as usize).div_ceil(8);
                if count == 0 || count > 64 || byte.saturating_add(nbytes) > rec_data {
                    return Err(layout_err(
                        group,
                        format!(
                            "{} ({count} bits at byte {byte}) lies outside the record",
                            cn.name
                        ),
                    ));
                }
                match cn.data_type {
                    0..=3 => {
                        let be = cn.data_type & 1 == 1;
                        if be && (bit != 0 || !count.is_multiple_of(8)) {
                            return Err(layout_err(
                                group,
                                format!("{}: big-endian bit field not byte-aligned", cn.name),
                            ));
                        }
                        Src::Int {
                            byte,
                            nbytes,
                            bit,
                            count,
                            signed: cn.data_type >= 2,
                            be,
                        }
                    }
                    4 | 5 if bit == 0 && (count == 32 || count == 64) => Src::Float {
                        byte,
                        size: count as usize / 8,
                        be: cn.data_type == 5,
                    },
                    t => {
                        return Err(layout_err(
                            group,
                            format!("{}: data type {t} is not a number", cn.name),
                        ))
                    }
                }
            }
            t => {
                return Err(layout_err(
                    group,
                    format!("{}: channel type {t} is not supported here", cn.name),
                ))
            }
        };
        let conv = self.conv(cn.conv_at, group, None)?;
        Ok(Field { src, conv })
    }
}

// ---------------------------------------------------------------------------------------------
// Data: a byte stream over a data group's (or signal data's) blocks

#[derive(Debug)]
enum Cur {
    None,
    /// Uncompressed block bytes still to read from the file.
    File {
        at: u64,
        left: u64,
    },
    /// Bytes of `zbuf[zpos..]` (a decompressed block).
    Mem,
}

struct DlState {
    next: u64,
    links: Vec<u64>,
    i: usize,
}

struct Stream {
    root: u64,
    /// b"DT" or b"SD".
    kind: [u8; 2],
    started: bool,
    dl: Option<DlState>,
    cur: Cur,
    buf: Vec<u8>,
    pos: usize,
    /// Stream offset of `buf[pos]`.
    offset: u64,
    zin: Vec<u8>,
    zbuf: Vec<u8>,
    zpos: usize,
    tmp: Vec<u8>,
    budget: u64,
    /// Extend the last DT block to the next block or the end of the file.
    unfin_last: bool,
    /// The file ended inside a block that declared more bytes.
    cut: bool,
    rewinds: u32,
    ended: bool,
}

impl Stream {
    fn new(root: u64, kind: [u8; 2], unfin_last: bool, file_len: u64) -> Stream {
        Stream {
            root,
            kind,
            started: false,
            dl: None,
            cur: Cur::None,
            buf: Vec::new(),
            pos: 0,
            offset: 0,
            zin: Vec::new(),
            zbuf: Vec::new(),
            zpos: 0,
            tmp: Vec::new(),
            budget: file_len,
            unfin_last,
            cut: false,
            rewinds: 0,
            ended: root == 0,
        }
    }

    fn rewind(&mut self, file_len: u64) {
        let (root, kind, unfin, rw) = (self.root, self.kind, self.unfin_last, self.rewinds);
        let buf = std::mem::take(&mut self.buf);
        let zin = std::mem::take(&mut self.zin);
        let zbuf = std::mem::take(&mut self.zbuf);
        *self = Stream::new(root, kind, unfin, file_len);
        self.buf = buf;
        self.buf.clear();
        self.zin = zin;
        self.zbuf = zbuf;
        self.rewinds = rw + 1;
    }

    #[inline]
    fn avail(&self) -> &[u8] {
        &self.buf[self.pos..]
    }

    /// Make at least `need` bytes available; `Ok(false)` when the stream ends first.
    #[inline]
    fn fill<R: Read + Seek>(&mut self, io: &mut Io<R>, need: usize) -> Result<bool, Mf4Error> {
        if self.buf.len() - self.pos >= need {
            return Ok(true);
        }
        self.fill_slow(io, need)
    }

    #[inline(never)]
    fn fill_slow<R: Read + Seek>(&mut self, io: &mut Io<R>, need: usize) -> Result<bool, Mf4Error> {
        if self.pos > 0 {
            self.buf.drain(..self.pos);
            self.offset += self.pos as u64;
            self.pos = 0;
        }
        while self.buf.len() < need {
            match self.cur {
                Cur::None => {
                    if self.ended || !self.next_block(io)? {
                        self.ended = true;
                        return Ok(false);
                    }
                }
                Cur::File { at, left } => {
                    let want = (need - self.buf.len()).max(CHUNK).min(left as usize);
                    let have = self.buf.len();
                    self.buf.resize(have + want, 0);
                    if let Err(e) = io.read_at(at, &mut self.buf[have..]) {
                        self.buf.truncate(have);
                        return Err(e);
                    }
                    self.cur = if left == want as u64 {
                        Cur::None
                    } else {
                        Cur::File {
                            at: at + want as u64,
                            left: left - want as u64,
                        }
                    };
                }
                Cur::Mem => {
                    let rest = &self.zbuf[self.zpos..];
                    let k = rest.len().min((need - self.buf.len()).max(CHUNK));
                    self.buf.extend_from_slice(&rest[..k]);
                    self.zpos += k;
                    if self.zpos == self.zbuf.len() {
                        self.cur = Cur::None;
                    }
                }
            }
        }
        Ok(true)
    }

    /// Skip `n` available bytes.
    #[inline]
    fn consume(&mut self, n: usize) {
        self.pos += n;
    }

    /// Skip `n` bytes, reading through as much as needed; `Ok(false)` if the stream ends.
    fn skip<R: Read + Seek>(&mut self, io: &mut Io<R>, mut n: u64) -> Result<bool, Mf4Error> {
        while n > 0 {
            let have = (self.buf.len() - self.pos) as u64;
            if have == 0 && !self.fill(io, 1)? {
                return Ok(false);
            }
            let have = (self.buf.len() - self.pos) as u64;
            let k = have.min(n);
            self.pos += k as usize;
            n -= k;
        }
        Ok(true)
    }

    /// The next data block of the list; `Ok(false)` at the end.
    fn next_block<R: Read + Seek>(&mut self, io: &mut Io<R>) -> Result<bool, Mf4Error> {
        loop {
            let (at, last) = if !self.started {
                self.started = true;
                let (id, _, _) = io.header(self.root)?;
                match &id {
                    b"##DL" => {
                        self.load_dl(io, self.root)?;
                        continue;
                    }
                    b"##HL" => {
                        let hl = io.block(self.root, "HL")?;
                        let first = hl.link(0);
                        if first == 0 {
                            return Ok(false);
                        }
                        self.load_dl(io, first)?;
                        continue;
                    }
                    _ => (self.root, true),
                }
            } else if let Some(dl) = &mut self.dl {
                if dl.i < dl.links.len() && dl.links[dl.i] != 0 {
                    let at = dl.links[dl.i];
                    dl.i += 1;
                    let last = dl.next == 0 && (dl.i == dl.links.len() || dl.links[dl.i] == 0);
                    (at, last)
                } else if dl.next != 0 {
                    let next = dl.next;
                    self.load_dl(io, next)?;
                    continue;
                } else {
                    return Ok(false);
                }
            } else {
                return Ok(false);
            };
            self.open_block(io, at, last)?;
            if !matches!(self.cur, Cur::None) {
                return Ok(true);
            }
        }
    }

    fn load_dl<R: Read + Seek>(&mut self, io: &mut Io<R>, at: u64) -> Result<(), Mf4Error> {
        let (_, len, _) = io.header(at)?;
        self.spend(len)?;
        let b = io.block(at, "DL")?;
        let links = b.links.get(1..).unwrap_or(&[]).to_vec();
        self.dl = Some(DlState {
            next: b.link(0),
            links,
            i: 0,
        });
        Ok(())
    }

    fn spend(&mut self, len: u64) -> Result<(), Mf4Error> {
        self.budget = self.budget.checked_sub(len).ok_or(Mf4Error::DataLoop)?;
        Ok(())
    }

    fn open_block<R: Read + Seek>(
        &mut self,
        io: &mut Io<R>,
        at: u64,
        last: bool,
    ) -> Result<(), Mf4Error> {
        let (id, len, nlinks) = io.header(at)?;
        let data_at = at + 24 + 8 * nlinks;
        if &id[..2] != b"##" {
            return Err(Mf4Error::BlockType {
                want: "a data block",
                at,
                found: String::from_utf8_lossy(&id).into_owned(),
            });
        }
        match &id[2..] {
            t if t == self.kind => {
                let mut end = at.saturating_add(len);
                if self.unfin_last && last {
                    // Length not written yet: the block runs to the next block or the file's end.
                    let i = io.meta_addrs.partition_point(|&a| a <= at);
                    end = io.meta_addrs.get(i).copied().unwrap_or(io.len).min(io.len);
                }
                if end > io.len {
                    self.cut = true;
                    end = io.len;
                }
                self.spend(end - at)?;
                if end > data_at {
                    self.cur = Cur::File {
                        at: data_at,
                        left: end - data_at,
                    };
                }
                Ok(())
            }
            b"DZ" => {
                self.spend(len)?;
                if at + len > io.len {
                    self.cut = true;
                    return Err(Mf4Error::TruncatedBlock(at));
                }
                let mut h = [0u8; 24];
                io.read_at(data_at, &mut h)?;
                let org = [h[0], h[1]];
                let zip = h[2];
                let param = u32le(&h, 4) as usize;
                let org_len = u64le(&h, 8);
                let z_len = u64le(&h, 16);
                let zerr = |what: String| Mf4Error::Zip { at, what };
                if org != self.kind {
                    return Err(zerr(format!(
                        "holds a {:?} block where {:?} data was expected",
                        String::from_utf8_lossy(&org),
                        String::from_utf8_lossy(&self.kind)
                    )));
                }
                if data_at + 24 + z_len > at + len {
                    return Err(zerr(format!(
                        "{z_len} compressed bytes do not fit in the block"
                    )));
                }
                if org_len > MAX_BLOCK {
                    return Err(Mf4Error::BlockTooLarge { at, size: org_len });
                }
                if org_len > z_len.saturating_mul(MAX_INFLATE_RATIO) + 64 {
                    return Err(zerr(format!(
                        "declares {org_len} bytes from {z_len}, more than deflate can expand"
                    )));
                }
                self.zin.resize(z_len as usize, 0);
                io.read_at(data_at + 24, &mut self.zin)?;
                self.zbuf.clear();
                self.zbuf.resize(org_len as usize, 0);
                let mut z = Decompress::new(true);
                let res = z.decompress(&self.zin, &mut self.zbuf, FlushDecompress::Finish);
                let out = z.total_out();
                match res {
                    Ok(Status::StreamEnd) if out == org_len => {}
                    Ok(_) => {
                        return Err(zerr(format!(
                            "inflates to a different length than its declared {org_len} bytes"
                        )))
                    }
                    Err(e) => return Err(zerr(format!("corrupt deflate stream: {e}"))),
                }
                match zip {
                    0 => {}
                    1 => {
                        if param > 0 {
                            let cols = param;
                            let rows = self.zbuf.len() / cols;
                            let n = rows * cols;
                            self.tmp.clear();
                            self.tmp.resize(n, 0);
                            // Stored column by column: byte c of every row, then byte c+1...
                            // Undone in tiles of 256 rows so the writes stay in L1.
                            for r0 in (0..rows).step_by(256) {
                                let r1 = (r0 + 256).min(rows);
                                let out = &mut self.tmp[r0 * cols..r1 * cols];
                                for c in 0..cols {
                                    let col = &self.zbuf[c * rows + r0..c * rows + r1];
                                    for (i, &b) in col.iter().enumerate() {
                                        out[i * cols + c] = b;
                                    }
                                }
                            }
                            self.zbuf[..n].copy_from_slice(&self.tmp);
                        }
                    }
                    z => return Err(zerr(format!("unknown compression type {z}"))),
                }
                self.zpos = 0;
                if !self.zbuf.is_empty() {
                    self.cur = Cur::Mem;
                }
                Ok(())
            }
            b"DV" | b"DI" => Err(Mf4Error::Unsupported("DV/DI")),
            b"RD" | b"RV" | b"RI" => Err(Mf4Error::Unsupported("RD/RV/RI")),
            _ => Err(Mf4Error::BlockType {
                want: if self.kind == *b"DT" {
                    "a DT, DZ, DL or HL block"
                } else {
                    "an SD, DZ, DL or HL block"
                },
                at,
                found: String::from_utf8_lossy(&id).into_owned(),
            }),
        }
    }
}

/// One data group being read.
struct Dg {
    rec_id_size: usize,
    stream: Stream,
    /// Channel groups of this data group (indices into `Mf4Reader::cgs`), by record ID.
    cgs: Vec<usize>,
    /// Record ID → index into `cgs` for IDs below 256.
    small: [u16; 256],
    /// Records left by the cycle counter (sorted, finalized data groups only).
    left: Option<u64>,
    done: bool,
    /// Frame decoded ahead for the time merge.
    head: Option<(Frame, usize)>,
}

/// Streaming reader of the CAN frames in an MDF 4 file.
pub struct Mf4Reader<R> {
    io: Io<R>,
    version: u16,
    unfinalized: bool,
    unfin_flags: u16,
    start_ns: i64,
    cgs: Vec<Cg>,
    dgs: Vec<Dg>,
    sds: Vec<Stream>,
    warnings: Vec<String>,
    last_group: usize,
    scratch: [u8; MAX_DATA],
}

impl<R: Read + Seek> Mf4Reader<R> {
    /// Read the identification, header and every data group's channel layout. Errors here mean
    /// the file cannot be read at all; a channel group whose layout is not understood becomes a
    /// warning and its records [`Mf4Step::Other`].
    pub fn open(mut file: R) -> Result<Mf4Reader<R>, Mf4Error> {
        let len = file.seek(SeekFrom::End(0))?;
        let mut io = Io {
            file,
            len,
            at: u64::MAX,
            meta_read: 0,
            meta_addrs: Vec::new(),
        };
        let mut id = [0u8; 64];
        if len < 64 {
            return Err(Mf4Error::NotMdf("file shorter than 64 bytes".into()));
        }
        io.read_at(0, &mut id)?;
        if !super::is_mdf4(&id) {
            return Err(Mf4Error::NotMdf(
                String::from_utf8_lossy(&id[..8]).into_owned(),
            ));
        }
        let version = u16le(&id, 28);
        if !(400..500).contains(&version) {
            return Err(Mf4Error::Version(version));
        }
        let unfinalized = &id[..8] == ID_UNFINALIZED;
        let unfin_flags = if unfinalized { u16le(&id, 60) } else { 0 };
        let hd = io.block(64, "HD")?;
        let start_ns = hd.u64(0).min(i64::MAX as u64) as i64;
        let mut r = Mf4Reader {
            io,
            version,
            unfinalized,
            unfin_flags,
            start_ns,
            cgs: Vec::new(),
            dgs: Vec::new(),
            sds: Vec::new(),
            warnings: Vec::new(),
            last_group: 0,
            scratch: [0; MAX_DATA],
        };
        let mut dg_seen = HashSet::new();
        let mut at = hd.link(0);
        let mut pending_vlsd: Vec<(usize, usize, u64)> = Vec::new(); // (cg, dg, target addr)
        let mut cg_addr: Vec<u64> = Vec::new();
        while at != 0 {
            if !dg_seen.insert(at) {
                return Err(Mf4Error::Cycle("data group"));
            }
            let dg = r.io.block(at, "DG")?;
            let rec_id_size = dg.u8(0) as usize;
            if ![0, 1, 2, 4, 8].contains(&rec_id_size) {
                return Err(Mf4Error::Layout {
                    group: String::new(),
                    what: format!("record ID size {rec_id_size} in data group at byte {at}"),
                });
            }
            let dg_index = r.dgs.len();
            let mut members = Vec::new();
            let mut cg_seen = HashSet::new();
            let mut c = dg.link(1);
            while c != 0 {
                if !cg_seen.insert(c) {
                    return Err(Mf4Error::Cycle("channel group"));
                }
                let cgb = r.io.block(c, "CG")?;
                let idx = r.cgs.len();
                let (cg, vlsd_target) = r.read_cg(&cgb)?;
                if let Some(t) = vlsd_target {
                    pending_vlsd.push((idx, dg_index, t));
                }
                r.cgs.push(cg);
                cg_addr.push(c);
                members.push(idx);
                c = cgb.link(0);
            }
            if rec_id_size == 0 && members.len() > 1 {
                return Err(Mf4Error::Layout {
                    group: String::new(),
                    what: format!(
                        "data group at byte {at} has {} channel groups but no record IDs",
                        members.len()
                    ),
                });
            }
            let mut small = [u16::MAX; 256];
            for (i, &m) in members.iter().enumerate() {
                let rid = r.cgs[m].record_id;
                if rec_id_size > 0 && rid < 256 && small[rid as usize] == u16::MAX {
                    small[rid as usize] = i as u16;
                }
            }
            let left = (rec_id_size == 0 && !(unfinalized && unfin_flags & UNFIN_CG_COUNTERS != 0))
                .then(|| members.first().map(|&m| r.cgs[m].cycles).unwrap_or(0));
            let unfin_last = unfinalized && unfin_flags & UNFIN_LAST_DT_LENGTH != 0;
            r.dgs.push(Dg {
                rec_id_size,
                stream: Stream::new(dg.link(2), *b"DT", unfin_last, len),
                cgs: members,
                small,
                left,
                done: false,
                head: None,
            });
            at = dg.link(0);
        }
        // Resolve VLSD DataBytes: a channel group of the same data group, or signal data.
        for (cg, dg, target) in pending_vlsd {
            let group = r.cgs[cg].name.clone();
            let (byte, width) = match r.cgs[cg].payload {
                Payload::VlsdCg { byte, width, .. } => (byte, width),
                _ => continue,
            };
            let res = (|| -> Result<Payload, Mf4Error> {
                let (id, _, _) = r.io.header(target)?;
                if &id == b"##CG" {
                    let t = r.dgs[dg]
                        .cgs
                        .iter()
                        .copied()
                        .find(|&i| cg_addr[i] == target && r.cgs[i].kind == CgKind::Vlsd)
                        .ok_or_else(|| {
                            layout_err(
                                &group,
                                "DataBytes refers to a VLSD group of another data group",
                            )
                        })?;
                    Ok(Payload::VlsdCg { byte, width, cg: t })
                } else {
                    let sd = r.sds.len();
                    r.sds.push(Stream::new(target, *b"SD", false, len));
                    Ok(Payload::Sd { byte, width, sd })
                }
            })();
            match res {
                Ok(p) => r.cgs[cg].payload = p,
                Err(Mf4Error::Io(e)) => return Err(Mf4Error::Io(e)),
                Err(e) => {
                    r.warnings.push(e.to_string());
                    r.cgs[cg].kind = CgKind::Other;
                }
            }
        }
        r.io.meta_addrs.sort_unstable();
        r.io.meta_addrs.dedup();
        Ok(r)
    }

    /// One channel group's layout; for a group whose DataBytes are VLSD, the link to resolve.
    fn read_cg(&mut self, b: &Block) -> Result<(Cg, Option<u64>), Mf4Error> {
        let record_id = b.u64(0);
        let cycles = b.u64(8);
        let flags = b.u16(16);
        let data_bytes = b.u32(24) as usize;
        let inval = b.u32(28) as usize;
        let acq = self.io.text(b.link(2))?;
        if flags & 1 != 0 {
            let mut cg = Cg::blank(acq, record_id, 0, cycles, CgKind::Vlsd);
            cg.vlsd_ring = vec![(u64::MAX, 0u8, [0u8; MAX_DATA]); RING].into_boxed_slice();
            return Ok((cg, None));
        }
        let rec_len = data_bytes
            .checked_add(inval)
            .filter(|&n| n as u64 <= MAX_BLOCK)
            .ok_or_else(|| layout_err(&acq, "record length above the limit"))?;
        let mut cns = Vec::new();
        self.io.channels(b.link(1), &mut cns)?;
        let mut kind = None;
        for cn in &cns {
            if let Some((prefix, _)) = cn.name.split_once('.') {
                kind = match prefix {
                    "CAN_DataFrame" => Some(FrameKind::Data),
                    "CAN_RemoteFrame" => Some(FrameKind::Remote),
                    "CAN_ErrorFrame" => Some(FrameKind::Error),
                    _ => continue,
                };
                break;
            }
        }
        let name = if acq.is_empty() {
            match kind {
                Some(FrameKind::Data) => "CAN_DataFrame".to_string(),
                Some(FrameKind::Remote) => "CAN_RemoteFrame".to_string(),
                Some(FrameKind::Error) => "CAN_ErrorFrame".to_string(),
                None => String::new(),
            }
        } else {
            acq
        };
        let Some(kind) = kind else {
            return Ok((
                Cg::blank(name, record_id, rec_len, cycles, CgKind::Other),
                None,
            ));
        };
        let mut cg = Cg::blank(name.clone(), record_id, rec_len, cycles, CgKind::Can(kind));
        match self.can_layout(&mut cg, &cns, data_bytes) {
            Ok(v) => Ok((cg, v)),
            Err(Mf4Error::Io(e)) => Err(Mf4Error::Io(e)),
            Err(e @ (Mf4Error::TooManyBlocks | Mf4Error::Cycle(_))) => Err(e),
            Err(e) => {
                self.warnings.push(e.to_string());
                cg.kind = CgKind::Other;
                Ok((cg, None))
            }
        }
    }

    fn can_layout(
        &mut self,
        cg: &mut Cg,
        cns: &[Cn],
        data_bytes: usize,
    ) -> Result<Option<u64>, Mf4Error> {
        let group = cg.name.clone();
        let mut vlsd = None;
        let mut have_time = false;
        for cn in cns {
            if cn.cn_type == 2 || cn.cn_type == 3 {
                if cn.sync != 1 {
                    return Err(layout_err(&group, "master channel is not time"));
                }
                let f = self.io.field(cn, &group, data_bytes)?;
                cg.time = Time::new(f);
                have_time = true;
                continue;
            }
            let Some((_, member)) = cn.name.rsplit_once('.') else {
                continue;
            };
            let slot = match member {
                "BusChannel" => {
                    let mut names = Vec::new();
                    let conv_at = cn.conv_at;
                    // A value-to-text conversion names the interfaces.
                    let f = if conv_at != 0 && self.io.header(conv_at)?.0 == *b"##CC" {
                        let probe = self.io.block(conv_at, "CC")?;
                        if probe.u8(0) == 7 {
                            self.io.conv(conv_at, &group, Some(&mut names))?;
                            let mut f = self.io.field(
                                &Cn {
                                    conv_at: 0,
                                    name: cn.name.clone(),
                                    ..*cn
                                },
                                &group,
                                data_bytes,
                            )?;
                            f.conv = Conv::Identity;
                            f
                        } else {
                            self.io.field(cn, &group, data_bytes)?
                        }
                    } else {
                        self.io.field(cn, &group, data_bytes)?
                    };
                    cg.bus = f;
                    cg.bus_names = names;
                    continue;
                }
                "ID" => &mut cg.id,
                "IDE" => &mut cg.ide,
                "DLC" => &mut cg.dlc,
                "DataLength" => &mut cg.dlen,
                "EDL" | "FDF" => &mut cg.edl,
                "BRS" => &mut cg.brs,
                "ESI" => &mut cg.esi,
                "DataBytes" => {
                    match cn.cn_type {
                        0 if cn.data_type == 10 || cn.data_type <= 1 => {
                            let byte = cn.byte as usize;
                            let len = (cn.count / 8) as usize;
                            if cn.bit != 0 || byte.saturating_add(len) > data_bytes {
                                return Err(layout_err(
                                    &group,
                                    "DataBytes lies outside the record",
                                ));
                            }
                            cg.payload = Payload::Fixed {
                                byte,
                                len: len.min(MAX_DATA),
                            };
                        }
                        1 => {
                            let byte = cn.byte as usize;
                            let width = cn.count as usize / 8;
                            if !cn.count.is_multiple_of(8)
                                || !(1..=8).contains(&width)
                                || cn.bit != 0
                                || byte + width > data_bytes
                            {
                                return Err(layout_err(
                                    &group,
                                    "VLSD DataBytes offset is not a whole-byte field in the record",
                                ));
                            }
                            if cn.data_at == 0 {
                                cg.payload = Payload::Unresolved;
                            } else {
                                cg.payload = Payload::VlsdCg { byte, width, cg: 0 };
                                vlsd = Some(cn.data_at);
                            }
                        }
                        t => {
                            return Err(layout_err(
                                &group,
                                format!("DataBytes of channel type {t} is not supported"),
                            ))
                        }
                    }
                    continue;
                }
                _ => continue,
            };
            *slot = self.io.field(cn, &group, data_bytes)?;
        }
        if !have_time {
            return Err(layout_err(&group, "no time master channel"));
        }
        if cg.kind != CgKind::Can(FrameKind::Error) && !cg.id.present() {
            return Err(layout_err(&group, "no ID member"));
        }
        if cg.kind == CgKind::Can(FrameKind::Data) && matches!(cg.payload, Payload::None) {
            return Err(layout_err(&group, "no DataBytes member"));
        }
        Ok(vlsd)
    }

    /// The MDF version number (e.g. 411).
    pub fn version(&self) -> u16 {
        self.version
    }

    /// Whether the file says it is unfinalized (`UnFinMF`), and its unfinalized flags.
    pub fn unfinalized(&self) -> Option<u16> {
        self.unfinalized.then_some(self.unfin_flags)
    }

    /// The measurement start (ns since the Unix epoch, as the header states it), which frame
    /// times include.
    pub fn start_epoch_ns(&self) -> i64 {
        self.start_ns
    }

    /// Channel groups whose layout was not understood (their records are [`Mf4Step::Other`]).
    pub fn warnings(&self) -> &[String] {
        &self.warnings
    }

    /// Acquisition name of the channel group of the last frame.
    pub fn last_group(&self) -> &str {
        self.cgs
            .get(self.last_group)
            .map_or("", |c| c.name.as_str())
    }

    /// The next frame (into `out`), other record, problem or end.
    #[inline]
    pub fn next_into(&mut self, out: &mut Frame) -> io::Result<Mf4Step> {
        if self.dgs.len() == 1 {
            let step = self.dg_step(0, out);
            return Self::lift(step);
        }
        self.merged(out)
    }

    fn lift(step: Result<Option<usize>, Mf4Error>) -> io::Result<Mf4Step> {
        match step {
            Ok(Some(usize::MAX)) => Ok(Mf4Step::End),
            Ok(Some(_)) => Ok(Mf4Step::Frame),
            Ok(None) => Ok(Mf4Step::Other),
            Err(Mf4Error::Io(e)) => Err(e),
            Err(e) => Ok(Mf4Step::Error(e)),
        }
    }

    /// Several data groups: fill every group's head frame, deliver the earliest.
    fn merged(&mut self, out: &mut Frame) -> io::Result<Mf4Step> {
        for d in 0..self.dgs.len() {
            while self.dgs[d].head.is_none() && !self.dgs[d].done {
                let mut f = *out;
                match self.dg_step(d, &mut f) {
                    Ok(Some(usize::MAX)) => {}
                    Ok(Some(cg)) => self.dgs[d].head = Some((f, cg)),
                    Ok(None) => return Ok(Mf4Step::Other),
                    Err(Mf4Error::Io(e)) => return Err(e),
                    Err(e) => return Ok(Mf4Step::Error(e)),
                }
            }
        }
        let best = (0..self.dgs.len())
            .filter_map(|d| self.dgs[d].head.as_ref().map(|(f, _)| (f.t_ns, d)))
            .min();
        match best {
            Some((_, d)) => {
                let (f, cg) = self.dgs[d].head.take().unwrap();
                *out = f;
                self.last_group = cg;
                Ok(Mf4Step::Frame)
            }
            None => Ok(Mf4Step::End),
        }
    }

    /// One record of data group `d`: `Some(cg)` for a frame of channel group `cg`, `None` for
    /// another record, `Some(usize::MAX)` at the end.
    #[inline]
    fn dg_step(&mut self, d: usize, out: &mut Frame) -> Result<Option<usize>, Mf4Error> {
        let dg = &mut self.dgs[d];
        if dg.done {
            return Ok(Some(usize::MAX));
        }
        let res = Self::record(
            dg,
            &mut self.cgs,
            &mut self.sds,
            &mut self.io,
            self.start_ns,
            &mut self.scratch,
            out,
        );
        match res {
            Ok(Some(cg)) if cg != usize::MAX => {
                self.last_group = cg;
                Ok(Some(cg))
            }
            Ok(r) => Ok(r),
            Err(e) => {
                if !matches!(e, Mf4Error::MissingSignalData { .. }) {
                    self.dgs[d].done = true;
                }
                Err(e)
            }
        }
    }

    #[inline]
    fn record(
        dg: &mut Dg,
        cgs: &mut [Cg],
        sds: &mut [Stream],
        io: &mut Io<R>,
        start_ns: i64,
        scratch: &mut [u8; MAX_DATA],
        out: &mut Frame,
    ) -> Result<Option<usize>, Mf4Error> {
        if dg.left == Some(0) {
            dg.done = true;
            return Ok(Some(usize::MAX));
        }
        let ids = dg.rec_id_size;
        // Record ID.
        let ci = if ids == 0 {
            if dg.cgs.is_empty() {
                dg.done = true;
                return Ok(Some(usize::MAX));
            }
            dg.cgs[0]
        } else {
            if !dg.stream.fill(io, ids)? {
                return Self::end_of(dg, cgs, None);
            }
            let a = dg.stream.avail();
            let rid = match ids {
                1 => a[0] as u64,
                2 => u16le(a, 0) as u64,
                4 => u32le(a, 0) as u64,
                _ => u64le(a, 0),
            };
            let k = if rid < 256 {
                dg.small[rid as usize] as usize
            } else {
                dg.cgs
                    .iter()
                    .position(|&c| cgs[c].record_id == rid)
                    .unwrap_or(u16::MAX as usize)
            };
            if k == u16::MAX as usize || k >= dg.cgs.len() {
                dg.done = true;
                return Err(Mf4Error::UnknownRecord { id: rid });
            }
            dg.cgs[k]
        };
        let cg = &mut cgs[ci];
        match cg.kind {
            CgKind::Vlsd => {
                if !dg.stream.fill(io, ids + 4)? {
                    return Self::end_of(dg, cgs, Some(ci));
                }
                let n = u32le(dg.stream.avail(), ids) as u64;
                if n > MAX_VLSD {
                    dg.done = true;
                    return Err(Mf4Error::VlsdTooLong(n));
                }
                let keep = (n as usize).min(MAX_DATA);
                if !dg.stream.fill(io, ids + 4 + keep)? {
                    return Self::end_of(dg, cgs, Some(ci));
                }
                let a = dg.stream.avail();
                let slot = &mut cg.vlsd_ring[cg.vlsd_head];
                slot.0 = cg.vlsd_next;
                slot.1 = keep as u8;
                slot.2[..keep].copy_from_slice(&a[ids + 4..ids + 4 + keep]);
                cg.vlsd_head = (cg.vlsd_head + 1) % RING;
                cg.vlsd_next += 4 + n;
                dg.stream.consume(ids + 4 + keep);
                if !dg.stream.skip(io, n - keep as u64)? {
                    return Self::end_of(dg, cgs, Some(ci));
                }
                cg.count += 1;
                Ok(None)
            }
            CgKind::Other => {
                let need = ids + cg.rec_len;
                if !dg.stream.skip(io, need as u64)? {
                    return Self::end_of(dg, cgs, Some(ci));
                }
                cg.count += 1;
                if let Some(l) = &mut dg.left {
                    *l -= 1;
                }
                Ok(None)
            }
            CgKind::Can(_) => {
                let need = ids + cg.rec_len;
                if !dg.stream.fill(io, need)? {
                    return Self::end_of(dg, cgs, Some(ci));
                }
                let idx = cg.count;
                cg.count += 1;
                let rec = &dg.stream.buf[dg.stream.pos + ids..dg.stream.pos + need];
                let cg = &cgs[ci];
                let vl: Option<&[u8]> = match cg.payload {
                    Payload::VlsdCg { byte, width, cg: t } => {
                        let off = uint_le(&rec[byte..byte + width]);
                        let ring = &cgs[t].vlsd_ring;
                        match ring.iter().find(|s| s.0 == off) {
                            Some(s) => {
                                scratch[..s.1 as usize].copy_from_slice(&s.2[..s.1 as usize]);
                                Some(&scratch[..s.1 as usize])
                            }
                            // Loggers write the frame's record before its VLSD record: look
                            // ahead for it (without consuming).
                            None => match Self::peek_vlsd(dg, cgs, io, need, t, off, scratch)? {
                                Some(n) => Some(&scratch[..n]),
                                None => {
                                    dg.stream.consume(need);
                                    return Err(Mf4Error::MissingSignalData {
                                        group: cgs[ci].name.clone(),
                                        offset: off,
                                    });
                                }
                            },
                        }
                    }
                    Payload::Sd { byte, width, sd } => {
                        let off = uint_le(&rec[byte..byte + width]);
                        match Self::sd_payload(&mut sds[sd], io, off, scratch) {
                            Ok(Some(n)) => Some(&scratch[..n]),
                            Ok(None) => {
                                dg.stream.consume(need);
                                return Err(Mf4Error::MissingSignalData {
                                    group: cg.name.clone(),
                                    offset: off,
                                });
                            }
                            Err(e) => return Err(e),
                        }
                    }
                    Payload::Unresolved => {
                        dg.stream.consume(need);
                        return Err(Mf4Error::MissingSignalData {
                            group: cg.name.clone(),
                            offset: 0,
                        });
                    }
                    _ => None,
                };
                let rec = &dg.stream.buf[dg.stream.pos + ids..dg.stream.pos + need];
                cg.decode(rec, idx, start_ns, vl, out);
                dg.stream.consume(need);
                if let Some(l) = &mut dg.left {
                    *l -= 1;
                }
                Ok(Some(ci))
            }
        }
    }

    /// Look ahead of the current record (`skip` bytes long) for the VLSD record at offset `off`
    /// of channel group `target`; its payload goes to `scratch`. Bounded: at most
    /// [`PEEK_RECORDS`] records or [`PEEK_BYTES`] bytes.
    #[allow(clippy::too_many_arguments)]
    fn peek_vlsd(
        dg: &mut Dg,
        cgs: &[Cg],
        io: &mut Io<R>,
        skip: usize,
        target: usize,
        off: u64,
        scratch: &mut [u8; MAX_DATA],
    ) -> Result<Option<usize>, Mf4Error> {
        let ids = dg.rec_id_size;
        if ids == 0 || off < cgs[target].vlsd_next {
            return Ok(None);
        }
        let mut next = cgs[target].vlsd_next;
        let mut at = skip;
        for _ in 0..PEEK_RECORDS {
            if at > PEEK_BYTES || !dg.stream.fill(io, at + ids + 4)? {
                return Ok(None);
            }
            let a = dg.stream.avail();
            let rid = match ids {
                1 => a[at] as u64,
                2 => u16le(a, at) as u64,
                4 => u32le(a, at) as u64,
                _ => u64le(a, at),
            };
            let Some(&c) = dg.cgs.iter().find(|&&c| cgs[c].record_id == rid) else {
                return Ok(None);
            };
            if cgs[c].kind == CgKind::Vlsd {
                let n = u32le(a, at + ids) as u64;
                if c == target {
                    if next == off {
                        let keep = (n as usize).min(MAX_DATA);
                        if !dg.stream.fill(io, at + ids + 4 + keep)? {
                            return Ok(None);
                        }
                        let a = dg.stream.avail();
                        scratch[..keep].copy_from_slice(&a[at + ids + 4..at + ids + 4 + keep]);
                        return Ok(Some(keep));
                    }
                    next += 4 + n;
                    if next > off {
                        return Ok(None);
                    }
                }
                at += ids + 4 + n as usize;
            } else {
                at += ids + cgs[c].rec_len;
            }
        }
        Ok(None)
    }

    /// The payload at `off` of a signal data stream, copied into `scratch` (≤ 64 bytes).
    fn sd_payload(
        s: &mut Stream,
        io: &mut Io<R>,
        off: u64,
        scratch: &mut [u8; MAX_DATA],
    ) -> Result<Option<usize>, Mf4Error> {
        let here = s.offset + s.pos as u64;
        if off < here {
            if s.rewinds >= MAX_REWINDS {
                return Ok(None);
            }
            s.rewind(io.len);
        }
        let here = s.offset + s.pos as u64;
        if !s.skip(io, off - here)? || !s.fill(io, 4)? {
            return Ok(None);
        }
        let n = u32le(s.avail(), 0) as usize;
        let keep = n.min(MAX_DATA);
        if !s.fill(io, 4 + keep)? {
            return Ok(None);
        }
        scratch[..keep].copy_from_slice(&s.avail()[4..4 + keep]);
        s.consume(4 + keep);
        Ok(Some(keep))
    }

    /// The stream ended before a whole record: the end, or a cut record.
    fn end_of(dg: &mut Dg, cgs: &[Cg], cg: Option<usize>) -> Result<Option<usize>, Mf4Error> {
        dg.done = true;
        let partial = !dg.stream.avail().is_empty();
        if partial || dg.left.is_some_and(|l| l > 0) {
            let group = cg.map(|c| cgs[c].name.clone()).unwrap_or_default();
            return Err(Mf4Error::PartialRecord { group });
        }
        Ok(Some(usize::MAX))
    }
}
