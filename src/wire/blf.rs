//! Vector BLF (binary logging format) reader: a 144-byte `LOGG` file header, then `LOBJ`
//! objects, almost always `LOG_CONTAINER`s whose payload is a zlib stream (usually 128 KiB
//! uncompressed) of further objects; an object may straddle two containers.
//!
//! Objects turned into [`Frame`]s: `CAN_MESSAGE` (1), `CAN_MESSAGE2` (86), `CAN_FD_MESSAGE`
//! (100), `CAN_FD_MESSAGE_64` (101), and the error objects `CAN_ERROR` (2) and `CAN_ERROR_EXT`
//! (73) (as [`FrameKind::Error`] with class `CAN_ERR_PROT`, BLF carrying no SocketCAN class).
//! Every other object type is reported as [`BlfEvent::Other`]. Channel N becomes interface
//! `can{N-1}`. Times are the header's measurement start (SYSTEMTIME read as UTC; 0 when the
//! header leaves it empty, as python-can does for non-wall-clock logs) plus the object time
//! (10 µs or 1 ns units, per the object's flags). A `CAN_FD_MESSAGE_64` whose data field
//! (up to its extended data, if any) holds fewer bytes than it declares valid, as some loggers
//! write it, is read as CANoe reads it, the rest as 0 ([`BlfEvent::ZeroFilled`]).
//!
//! Memory is constant: one buffer for a compressed container and one for its decompressed
//! contents (plus the tail of a straddling object), both reused; objects larger than
//! [`MAX_OBJECT`] are refused as malformed.
//!
//! The `ablf` crate was considered and not used: it reads only CAN_MESSAGE2 and CAN_ERROR_EXT
//! (no CAN_MESSAGE or CAN FD objects), panics on a corrupt zlib stream, and allocates per
//! object. Layouts follow the publicly documented structures (python-can, Toby Lorenz'
//! vector_blf); no code was copied.
//!
//! Not here: counting or reporting skips ([`crate::source::log`]).

use super::asc::{days_from_civil, CAN_ERR_PROT};
use super::frame::{fd_dlc_to_len, fd_len_to_dlc, ChannelNames, Frame, FrameKind, IfaceName};
use flate2::{Decompress, FlushDecompress, Status};
use std::io::{self, Read};

/// Largest object (or container) accepted, compressed or not.
pub const MAX_OBJECT: usize = 16 * 1024 * 1024;

const LOG_CONTAINER: u32 = 10;
const CAN_MESSAGE: u32 = 1;
const CAN_ERROR: u32 = 2;
const CAN_ERROR_EXT: u32 = 73;
const CAN_MESSAGE2: u32 = 86;
const CAN_FD_MESSAGE: u32 = 100;
const CAN_FD_MESSAGE_64: u32 = 101;

/// What one object is.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum BlfEvent {
    Frame(Frame),
    /// A `CAN_FD_MESSAGE_64` whose object holds fewer data bytes than it declares valid (some
    /// loggers write 48 of 64): the frame has the declared length, the bytes the object does
    /// not hold are 0, as CANoe, binlog.dll and python-can read it.
    /// `present` is how many data bytes the object held.
    ZeroFilled {
        frame: Frame,
        present: usize,
    },
    /// Any non-CAN object (markers, statistics, other buses).
    Other,
}

/// What is wrong with a BLF file or object.
#[derive(Debug, thiserror::Error)]
pub enum BlfError {
    #[error("not a BLF file (no LOGG signature)")]
    NotBlf,
    #[error("expected an LOBJ object signature at byte {0}; skipped to the next one")]
    NoSignature(u64),
    #[error("bytes inside a log container are not an object; rest of the container skipped")]
    ContainerGarbage,
    #[error("object of {0} bytes is larger than the {max} byte limit", max = MAX_OBJECT)]
    TooLarge(u64),
    #[error("object of type {ty} has {size} bytes, too short for its layout")]
    Short { ty: u32, size: usize },
    #[error("log container uses unknown compression method {0}")]
    Compression(u16),
    #[error("log container: zlib stream is corrupt or truncated: {0}")]
    Zlib(String),
    #[error("file ends inside an object (truncated file)")]
    Truncated,
    #[error("CAN object DLC {0} is out of range (0-15)")]
    Dlc(u8),
    #[error("CAN FD object declares {0} valid data bytes, which no CAN FD frame has (0-8, 12, 16, 20, 24, 32, 48 or 64)")]
    FdLength(usize),
    #[error("unknown object header version {0}")]
    HeaderVersion(u16),
}

/// Streaming BLF reader.
pub struct BlfReader<R> {
    inner: R,
    started: bool,
    start_ns: Option<i64>,
    comp: Vec<u8>,
    data: Vec<u8>,
    pos: usize,
    z: Decompress,
    file_offset: u64,
    objects: u64,
    ifaces: ChannelNames,
    done: bool,
    /// An object header found by resynchronisation, to be read next.
    pending: Option<[u8; 16]>,
}

fn u16le(b: &[u8], at: usize) -> u16 {
    u16::from_le_bytes([b[at], b[at + 1]])
}
fn u32le(b: &[u8], at: usize) -> u32 {
    u32::from_le_bytes(b[at..at + 4].try_into().unwrap())
}
fn u64le(b: &[u8], at: usize) -> u64 {
    u64::from_le_bytes(b[at..at + 8].try_into().unwrap())
}

/// Fill `buf` completely; `Ok(false)` at a clean end of input before any byte.
fn read_full<R: Read>(r: &mut R, buf: &mut [u8]) -> io::Result<Result<bool, BlfError>> {
    let mut n = 0;
    while n < buf.len() {
        match r.read(&mut buf[n..]) {
            Ok(0) => {
                return Ok(if n == 0 {
                    Ok(false)
                } else {
                    Err(BlfError::Truncated)
                })
            }
            Ok(k) => n += k,
            Err(e) if e.kind() == io::ErrorKind::Interrupted => {}
            Err(e) => return Err(e),
        }
    }
    Ok(Ok(true))
}

impl<R: Read> BlfReader<R> {
    pub fn new(inner: R) -> Self {
        BlfReader {
            inner,
            started: false,
            start_ns: None,
            comp: Vec::new(),
            data: Vec::new(),
            pos: 0,
            z: Decompress::new(true),
            file_offset: 0,
            objects: 0,
            ifaces: ChannelNames::new(),
            done: false,
            pending: None,
        }
    }

    /// Measurement start from the file header (ns since the Unix epoch, UTC), if it has one.
    pub fn start_epoch_ns(&self) -> Option<i64> {
        self.start_ns
    }

    /// 1-based index of the last object looked at (containers and the objects inside them).
    pub fn object_index(&self) -> u64 {
        self.objects
    }

    fn header(&mut self) -> io::Result<Result<(), BlfError>> {
        let mut h = [0u8; 144];
        match read_full(&mut self.inner, &mut h)? {
            Ok(true) => {}
            Ok(false) | Err(_) => return Ok(Err(BlfError::NotBlf)),
        }
        if &h[0..4] != b"LOGG" {
            return Ok(Err(BlfError::NotBlf));
        }
        let size = u32le(&h, 4) as usize;
        if size > 144 {
            let mut rest = size - 144;
            let mut skip = [0u8; 256];
            while rest > 0 {
                let k = rest.min(skip.len());
                if let Ok(false) | Err(_) = read_full(&mut self.inner, &mut skip[..k])? {
                    return Ok(Err(BlfError::Truncated));
                }
                rest -= k;
            }
        }
        self.file_offset = size.max(144) as u64;
        let st: [u16; 8] = std::array::from_fn(|i| u16le(&h, 40 + 2 * i));
        let (y, mo, d, hh, mi, ss, ms) = (st[0], st[1], st[3], st[4], st[5], st[6], st[7]);
        if (1970..=2200).contains(&y) && (1..=12).contains(&mo) && (1..=31).contains(&d) {
            let days = days_from_civil(y as i64, mo as u32, d as u32);
            let s = days * 86_400 + hh as i64 * 3600 + mi as i64 * 60 + ss as i64;
            self.start_ns = Some(s * 1_000_000_000 + ms as i64 * 1_000_000);
        }
        Ok(Ok(()))
    }

    /// The next object: a frame, another object, a described problem (reading goes on after
    /// it), or `None` at the end. `Err` only for I/O failures.
    pub fn next_event(&mut self) -> io::Result<Option<Result<BlfEvent, BlfError>>> {
        if self.done {
            return Ok(None);
        }
        if !self.started {
            self.started = true;
            if let Err(e) = self.header()? {
                self.done = true;
                return Ok(Some(Err(e)));
            }
        }
        loop {
            // Objects left in the current container.
            if let Some(ev) = self.next_in_container() {
                return Ok(Some(ev));
            }
            // Next top-level object.
            let mut base = [0u8; 16];
            if let Some(h) = self.pending.take() {
                base = h;
            } else {
                match read_full(&mut self.inner, &mut base)? {
                    Ok(true) => {}
                    Ok(false) => {
                        self.done = true;
                        if self.pos < self.data.len() {
                            self.data.clear();
                            self.pos = 0;
                            return Ok(Some(Err(BlfError::Truncated)));
                        }
                        return Ok(None);
                    }
                    Err(e) => {
                        self.done = true;
                        return Ok(Some(Err(e)));
                    }
                }
            }
            let at = self.file_offset;
            if &base[0..4] != b"LOBJ" {
                self.objects += 1;
                if !self.resync(base)? {
                    self.done = true;
                }
                return Ok(Some(Err(BlfError::NoSignature(at))));
            }
            let size = u32le(&base, 8) as usize;
            let ty = u32le(&base, 12);
            if size > MAX_OBJECT {
                self.objects += 1;
                self.done = true;
                return Ok(Some(Err(BlfError::TooLarge(size as u64))));
            }
            if size < 16 {
                self.objects += 1;
                self.done = true;
                return Ok(Some(Err(BlfError::Short { ty, size })));
            }
            self.comp.clear();
            self.comp.extend_from_slice(&base);
            self.comp.resize(size, 0);
            match read_full(&mut self.inner, &mut self.comp[16..size])? {
                Ok(true) => {}
                Ok(false) | Err(_) => {
                    self.objects += 1;
                    self.done = true;
                    return Ok(Some(Err(BlfError::Truncated)));
                }
            }
            // Padding (object size mod 4 bytes); a missing pad at the very end is harmless.
            let mut pad = [0u8; 4];
            let _ = read_full(&mut self.inner, &mut pad[..size % 4])?;
            self.file_offset += (size + size % 4) as u64;
            if ty == LOG_CONTAINER {
                self.objects += 1;
                if let Err(e) = self.inflate(size) {
                    return Ok(Some(Err(e)));
                }
                continue;
            }
            self.objects += 1;
            let comp = std::mem::take(&mut self.comp);
            let ev = self.parse_object(&comp[..size]);
            self.comp = comp;
            return Ok(Some(ev));
        }
    }

    /// After a bad signature: slide forward until `LOBJ` and queue that header.
    /// `Ok(false)` at end of input.
    fn resync(&mut self, first: [u8; 16]) -> io::Result<bool> {
        let mut window = [0u8; 32];
        window[..16].copy_from_slice(&first);
        let mut have = 16usize;
        loop {
            if let Some(i) = window[..have].windows(4).position(|w| w == b"LOBJ") {
                window.copy_within(i..have, 0);
                have -= i;
                self.file_offset += i as u64;
                if have < 16 {
                    if let Ok(false) | Err(_) = read_full(&mut self.inner, &mut window[have..16])? {
                        return Ok(false);
                    }
                }
                let mut h = [0u8; 16];
                h.copy_from_slice(&window[..16]);
                self.pending = Some(h);
                return Ok(true);
            }
            let keep = have.min(3);
            window.copy_within(have - keep..have, 0);
            self.file_offset += (have - keep) as u64;
            have = keep;
            let n = loop {
                match self.inner.read(&mut window[have..]) {
                    Ok(n) => break n,
                    Err(e) if e.kind() == io::ErrorKind::Interrupted => {}
                    Err(e) => return Err(e),
                }
            };
            if n == 0 {
                return Ok(false);
            }
            have += n;
        }
    }

    /// Decompress the container in `comp[..size]`, appending to the unparsed tail in `data`.
    fn inflate(&mut self, size: usize) -> Result<(), BlfError> {
        if size < 32 {
            return Err(BlfError::Short {
                ty: LOG_CONTAINER,
                size,
            });
        }
        let method = u16le(&self.comp, 16);
        let usize_ = u32le(&self.comp, 24) as usize;
        let payload = &self.comp[32..size];
        // Keep the unparsed tail (an object straddling containers).
        self.data.drain(..self.pos);
        self.pos = 0;
        let tail = self.data.len();
        if tail > MAX_OBJECT {
            self.data.clear();
            return Err(BlfError::TooLarge(tail as u64));
        }
        match method {
            0 => {
                self.data.extend_from_slice(payload);
                Ok(())
            }
            2 => {
                if usize_ > MAX_OBJECT {
                    return Err(BlfError::TooLarge(usize_ as u64));
                }
                self.data.resize(tail + usize_, 0);
                self.z.reset(true);
                let res =
                    self.z
                        .decompress(payload, &mut self.data[tail..], FlushDecompress::Finish);
                let out = self.z.total_out() as usize;
                match res {
                    Ok(Status::StreamEnd) if out == usize_ => Ok(()),
                    // A damaged container is dropped whole (with any object it was to complete):
                    // its bytes cannot be trusted.
                    Ok(_) => {
                        self.data.clear();
                        Err(BlfError::Zlib(format!(
                            "stream ended after {out} of {usize_} bytes, or its checksum failed"
                        )))
                    }
                    Err(e) => {
                        self.data.clear();
                        Err(BlfError::Zlib(e.to_string()))
                    }
                }
            }
            m => Err(BlfError::Compression(m)),
        }
    }

    /// The next complete object in `data[pos..]`, or `None` when more input is needed.
    fn next_in_container(&mut self) -> Option<Result<BlfEvent, BlfError>> {
        let avail = &self.data[self.pos..];
        if avail.len() < 16 {
            return None;
        }
        // Objects are padded to 4 bytes; find the signature within the next 8 bytes.
        let skip = match avail[..avail.len().min(12)]
            .windows(4)
            .position(|w| w == b"LOBJ")
        {
            Some(s) if s < 8 => s,
            _ => {
                // Garbage: drop what is left of this container.
                self.objects += 1;
                self.pos = self.data.len();
                return Some(Err(BlfError::ContainerGarbage));
            }
        };
        let avail = &avail[skip..];
        if avail.len() < 16 {
            return None;
        }
        let size = u32le(avail, 8) as usize;
        if !(16..=MAX_OBJECT).contains(&size) {
            self.objects += 1;
            self.pos = self.data.len();
            return Some(Err(if size < 16 {
                BlfError::Short {
                    ty: u32le(avail, 12),
                    size,
                }
            } else {
                BlfError::TooLarge(size as u64)
            }));
        }
        if avail.len() < size {
            return None;
        }
        let start = self.pos + skip;
        self.pos = start + size;
        self.objects += 1;
        let data = std::mem::take(&mut self.data);
        let ev = self.parse_object(&data[start..start + size]);
        self.data = data;
        Some(ev)
    }

    fn iface(&self, ch: u32) -> IfaceName {
        self.ifaces.get(ch)
    }

    /// One whole object (`obj` starts with its `LOBJ` base header).
    fn parse_object(&self, obj: &[u8]) -> Result<BlfEvent, BlfError> {
        let ty = u32le(obj, 12);
        let short = || BlfError::Short {
            ty,
            size: obj.len(),
        };
        if !matches!(
            ty,
            CAN_MESSAGE
                | CAN_MESSAGE2
                | CAN_FD_MESSAGE
                | CAN_FD_MESSAGE_64
                | CAN_ERROR
                | CAN_ERROR_EXT
        ) {
            return Ok(BlfEvent::Other);
        }
        let hdr_size = u16le(obj, 4) as usize;
        let version = u16le(obj, 6);
        let body_at = match version {
            1 => 32,
            2 => 40,
            v => return Err(BlfError::HeaderVersion(v)),
        };
        let body_at = body_at.max(hdr_size);
        if obj.len() < body_at {
            return Err(short());
        }
        let flags = u32le(obj, 16);
        let ts = u64le(obj, 24) as i64;
        let ts_ns = if flags & 1 != 0 {
            ts.saturating_mul(10_000)
        } else {
            ts
        };
        let t_ns = self.start_ns.unwrap_or(0).saturating_add(ts_ns);
        let b = &obj[body_at..];
        let mut f = Frame::empty(t_ns);
        match ty {
            CAN_MESSAGE | CAN_MESSAGE2 => {
                if b.len() < 16 {
                    return Err(short());
                }
                f.iface = self.iface(u16le(b, 0) as u32);
                let mflags = b[2];
                let dlc = b[3];
                if dlc > 15 {
                    return Err(BlfError::Dlc(dlc));
                }
                set_id(&mut f, u32le(b, 4));
                f.dlc = dlc;
                f.len = dlc.min(8);
                if mflags & 0x80 != 0 {
                    f.kind = FrameKind::Remote;
                } else {
                    f.data[..f.len as usize].copy_from_slice(&b[8..8 + f.len as usize]);
                }
            }
            CAN_FD_MESSAGE => {
                if b.len() < 84 {
                    return Err(short());
                }
                f.iface = self.iface(u16le(b, 0) as u32);
                let mflags = b[2];
                let dlc = b[3];
                set_id(&mut f, u32le(b, 4));
                let fdf = b[13];
                let valid = b[14] as usize;
                f.fd = fdf & 1 != 0;
                f.brs = fdf & 2 != 0;
                f.esi = fdf & 4 != 0;
                self.fill(&mut f, mflags & 0x80 != 0, dlc, valid, &b[20..84])?;
            }
            CAN_FD_MESSAGE_64 => {
                if b.len() < 40 {
                    return Err(short());
                }
                f.iface = self.iface(b[0] as u32);
                let dlc = b[1];
                let valid = b[2] as usize;
                set_id(&mut f, u32le(b, 4));
                let fl = u32le(b, 12);
                f.fd = fl & 0x1000 != 0;
                f.brs = fl & 0x2000 != 0;
                f.esi = fl & 0x4000 != 0;
                // The data field ends where the extended data starts (an offset from the
                // object's start; 0: none) or with the object.
                let ext = b[35] as usize;
                let end = if ext > body_at + 40 {
                    (ext - body_at).min(b.len())
                } else {
                    b.len()
                };
                let payload = &b[40..end];
                let want = valid.min(64);
                if payload.len() < want && fl & 0x10 == 0 {
                    let mut padded = [0u8; 64];
                    padded[..payload.len()].copy_from_slice(payload);
                    self.fill(&mut f, false, dlc, valid, &padded[..want])?;
                    return Ok(BlfEvent::ZeroFilled {
                        frame: f,
                        present: payload.len(),
                    });
                }
                self.fill(&mut f, fl & 0x10 != 0, dlc, valid, payload)?;
            }
            _ => {
                // CAN_ERROR / CAN_ERROR_EXT: channel is the first u16 of both.
                if b.len() < 4 {
                    return Err(short());
                }
                f.iface = self.iface(u16le(b, 0) as u32);
                f.kind = FrameKind::Error;
                f.id = CAN_ERR_PROT;
                f.len = 8;
                f.dlc = 8;
            }
        }
        Ok(BlfEvent::Frame(f))
    }

    fn fill(
        &self,
        f: &mut Frame,
        remote: bool,
        dlc: u8,
        valid: usize,
        payload: &[u8],
    ) -> Result<(), BlfError> {
        if dlc > 15 {
            return Err(BlfError::Dlc(dlc));
        }
        if remote && !f.fd {
            f.kind = FrameKind::Remote;
            f.brs = false;
            f.esi = false;
            f.dlc = dlc;
            f.len = dlc.min(8);
            return Ok(());
        }
        let max = if f.fd { 64 } else { 8 };
        let len = valid.min(max).min(payload.len());
        // A CAN FD frame carries one of 16 lengths; any other count of valid bytes (e.g. 19)
        // is an inconsistent object, reported rather than delivered as a frame no bus can carry.
        if f.fd && fd_dlc_to_len(fd_len_to_dlc(len)) != len {
            return Err(BlfError::FdLength(len));
        }
        f.data[..len].copy_from_slice(&payload[..len]);
        f.len = len as u8;
        f.dlc = if f.fd {
            fd_len_to_dlc(len)
        } else if len == 8 && dlc > 8 {
            dlc
        } else {
            len as u8
        };
        Ok(())
    }
}

fn set_id(f: &mut Frame, raw: u32) {
    f.extended = raw & 0x8000_0000 != 0;
    f.id = if f.extended {
        raw & 0x1FFF_FFFF
    } else {
        raw & 0x7FF
    };
}

/// Streaming BLF writer: a 144-byte `LOGG` header (measurement start as a UTC SYSTEMTIME, to
/// the millisecond; object count and file size patched by [`BlfWriter::finish`]), then
/// `LOG_CONTAINER`s of zlib-compressed objects (128 KiB uncompressed each), as python-can and
/// Vector tools write them. Objects: `CAN_MESSAGE` (classic data and remote frames),
/// `CAN_FD_MESSAGE_64` (CAN FD) and `CAN_ERROR_EXT` (error frames: BLF has no place for the
/// SocketCAN class or detail bytes). Object times are ns after the start (lossless).
pub struct BlfWriter<W: io::Write + io::Seek> {
    w: W,
    start_ns: Option<i64>,
    chunk: Vec<u8>,
    z: Vec<u8>,
    objects: u32,
    size: u64,
    uncompressed: u64,
    last_ns: i64,
}

const CONTAINER_BYTES: usize = 128 * 1024;

fn systemtime(epoch_ns: i64) -> [u8; 16] {
    let ms = epoch_ns.max(0) / 1_000_000;
    let days = ms.div_euclid(86_400_000);
    let rem = ms.rem_euclid(86_400_000);
    let (y, m, d) = super::asc::civil_from_days(days);
    let dow = (days + 4).rem_euclid(7); // 1970-01-01 was a Thursday (4)
    let v = [
        y as u16,
        m as u16,
        dow as u16,
        d as u16,
        (rem / 3_600_000) as u16,
        (rem / 60_000 % 60) as u16,
        (rem / 1000 % 60) as u16,
        (rem % 1000) as u16,
    ];
    let mut b = [0u8; 16];
    for (i, x) in v.iter().enumerate() {
        b[2 * i..2 * i + 2].copy_from_slice(&x.to_le_bytes());
    }
    b
}

impl<W: io::Write + io::Seek> BlfWriter<W> {
    pub fn new(w: W) -> BlfWriter<W> {
        BlfWriter {
            w,
            start_ns: None,
            chunk: Vec::with_capacity(CONTAINER_BYTES + 256),
            z: Vec::new(),
            objects: 0,
            size: 0,
            uncompressed: 0,
            last_ns: 0,
        }
    }

    fn header(&self, stop_ns: i64) -> [u8; 144] {
        let mut h = [0u8; 144];
        h[..4].copy_from_slice(b"LOGG");
        h[4..8].copy_from_slice(&144u32.to_le_bytes());
        h[8] = 5; // application: "other"
        h[16..24].copy_from_slice(&self.size.to_le_bytes());
        h[24..32].copy_from_slice(&self.uncompressed.to_le_bytes());
        h[32..36].copy_from_slice(&self.objects.to_le_bytes());
        let start = self.start_ns.unwrap_or(0);
        h[40..56].copy_from_slice(&systemtime(start));
        h[56..72].copy_from_slice(&systemtime(stop_ns));
        h
    }

    /// The measurement start the object times count from (the first frame's time truncated
    /// to the millisecond), once a frame was written.
    pub fn start_ns(&self) -> Option<i64> {
        self.start_ns
    }

    /// Write one frame on 1-based channel `ch`. A frame before the start (or before 1970) is
    /// written at the start; the caller counts that.
    pub fn write(&mut self, f: &Frame, ch: u16) -> io::Result<()> {
        let start = match self.start_ns {
            Some(s) => s,
            None => {
                let s = f.t_ns.max(0) / 1_000_000 * 1_000_000;
                self.start_ns = Some(s);
                let h = self.header(s);
                self.w.write_all(&h)?;
                self.size = 144;
                s
            }
        };
        let t = (f.t_ns - start).max(0) as u64;
        self.last_ns = self.last_ns.max(f.t_ns);
        let (ty, body): (u32, usize) = match f.kind {
            FrameKind::Data if f.fd => (CAN_FD_MESSAGE_64, 40 + 64),
            FrameKind::Error => (CAN_ERROR_EXT, 32),
            _ => (CAN_MESSAGE, 16),
        };
        let size = 32 + body;
        let c = &mut self.chunk;
        c.extend_from_slice(b"LOBJ");
        c.extend_from_slice(&32u16.to_le_bytes());
        c.extend_from_slice(&1u16.to_le_bytes());
        c.extend_from_slice(&(size as u32).to_le_bytes());
        c.extend_from_slice(&ty.to_le_bytes());
        c.extend_from_slice(&2u32.to_le_bytes()); // timestamps in ns
        c.extend_from_slice(&[0; 4]);
        c.extend_from_slice(&t.to_le_bytes());
        let raw_id = f.id | if f.extended { 0x8000_0000 } else { 0 };
        match ty {
            CAN_MESSAGE => {
                c.extend_from_slice(&ch.to_le_bytes());
                c.push(if f.kind == FrameKind::Remote { 0x80 } else { 0 });
                c.push(f.dlc);
                c.extend_from_slice(&raw_id.to_le_bytes());
                let mut d = [0u8; 8];
                if f.kind == FrameKind::Data {
                    d[..f.len.min(8) as usize].copy_from_slice(&f.data[..f.len.min(8) as usize]);
                }
                c.extend_from_slice(&d);
            }
            CAN_FD_MESSAGE_64 => {
                c.push(ch.min(255) as u8);
                c.push(f.dlc);
                c.push(f.len);
                c.push(0);
                c.extend_from_slice(&raw_id.to_le_bytes());
                c.extend_from_slice(&0u32.to_le_bytes()); // frame length (ns)
                let fl = 0x1000 | if f.brs { 0x2000 } else { 0 } | if f.esi { 0x4000 } else { 0 };
                c.extend_from_slice(&(fl as u32).to_le_bytes());
                c.extend_from_slice(&[0u8; 24]);
                c.extend_from_slice(&f.data);
            }
            _ => {
                c.extend_from_slice(&ch.to_le_bytes());
                c.extend_from_slice(&[0u8; 30]);
            }
        }
        self.objects += 1;
        if self.chunk.len() >= CONTAINER_BYTES {
            self.flush_container()?;
        }
        Ok(())
    }

    fn flush_container(&mut self) -> io::Result<()> {
        if self.chunk.is_empty() {
            return Ok(());
        }
        let mut e = flate2::write::ZlibEncoder::new(
            std::mem::take(&mut self.z),
            flate2::Compression::default(),
        );
        io::Write::write_all(&mut e, &self.chunk)?;
        let z = e.finish()?;
        let size = 32 + z.len();
        let mut h = Vec::with_capacity(32);
        h.extend_from_slice(b"LOBJ");
        h.extend_from_slice(&16u16.to_le_bytes());
        h.extend_from_slice(&1u16.to_le_bytes());
        h.extend_from_slice(&(size as u32).to_le_bytes());
        h.extend_from_slice(&LOG_CONTAINER.to_le_bytes());
        h.extend_from_slice(&2u16.to_le_bytes());
        h.extend_from_slice(&[0; 6]);
        h.extend_from_slice(&(self.chunk.len() as u32).to_le_bytes());
        h.extend_from_slice(&[0; 4]);
        self.w.write_all(&h)?;
        self.w.write_all(&z)?;
        self.w.write_all(&[0u8; 4][..size % 4])?;
        self.size += (size + size % 4) as u64;
        self.uncompressed += self.chunk.len() as u64 + 32;
        self.chunk.clear();
        self.z = z;
        self.z.clear();
        Ok(())
    }

    /// Write the last container and patch the header; returns the inner writer.
    pub fn finish(mut self) -> io::Result<W> {
        if self.start_ns.is_none() {
            self.start_ns = Some(0);
            let h = self.header(0);
            self.w.write_all(&h)?;
            self.size = 144;
        }
        self.flush_container()?;
        let h = self.header(self.last_ns);
        self.w.seek(io::SeekFrom::Start(0))?;
        self.w.write_all(&h)?;
        self.w.seek(io::SeekFrom::End(0))?;
        self.w.flush()?;
        Ok(self.w)
    }
}
