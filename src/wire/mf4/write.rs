//! MDF 4.11 bus logging writer.
//!
//! Four channel groups, as the ASAM bus logging layout names them: `CAN_DataFrame` (classic
//! data frames, 8 data bytes in the record), `CAN_DataFrame_FD` (CAN FD, 64 bytes; its
//! structure channel is also `CAN_DataFrame`), `CAN_RemoteFrame` and `CAN_ErrorFrame` (the
//! SocketCAN error class in `ID`, the 8 detail bytes in `DataBytes`). Each record is the time
//! (`Timestamp`, signed 64-bit ns through a linear conversion to seconds), `BusChannel`, `ID`,
//! `IDE`, `Dir`, `EDL`, `BRS`, `ESI`, `DLC`, `DataLength` and, but for remote frames,
//! `DataBytes`.
//!
//! Layouts ([`Mf4Layout`]): unsorted (one data group, 1-byte record IDs, records in arrival
//! order, as loggers write) or sorted (one data group per channel group, as asammdf saves).
//! Data goes out in blocks of [`Mf4WriterOptions::block_size`] bytes, as `DT` or `DZ` (deflate;
//! transposition + deflate for sorted files), listed by a `DL` when there are several; the
//! metadata follows the data and the header links are patched at [`Mf4Writer::finish`], so
//! memory stays at one block per group whatever the length of the log.
//!
//! With [`Mf4WriterOptions::unfinalized`] the file is written the way a logger that may lose
//! power writes it: `UnFinMF` identification (flags: cycle counters and last DT length not
//! updated), metadata first, then a single `DT` block whose length is never written. Every
//! prefix of such a file that holds the metadata is a readable file.
//!
//! Interface names: each distinct name gets a `BusChannel` number (`canN` gets N+1 when free,
//! others the lowest free number from 1) and, in a finalized file, a value-to-text conversion
//! on `BusChannel` keeps the names themselves. Not kept: nothing of a [`Frame`] but the order
//! of frames across groups in a sorted file (readers merge by time) and, in an unfinalized
//! file, interface names other than `canN`.
//!
//! Not here: choosing a format from a file name ([`crate::source::log`]).

use crate::wire::frame::{Frame, FrameKind, IfaceName};
use flate2::{Compress, Compression, FlushCompress};
use std::io::{self, Seek, SeekFrom, Write};

/// How records are arranged in data groups.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Mf4Layout {
    /// One data group, record IDs, arrival order (what CANedge loggers write).
    Unsorted,
    /// One data group per channel group, no record IDs (what asammdf saves).
    Sorted,
}

/// Block compression.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Mf4Compression {
    /// `DT` blocks.
    None,
    /// `DZ` blocks, deflate.
    Deflate,
    /// `DZ` blocks, transposition + deflate (sorted layout only; plain deflate otherwise).
    Transposed,
}

/// Writer settings.
#[derive(Clone, Copy, Debug)]
pub struct Mf4WriterOptions {
    pub layout: Mf4Layout,
    pub compression: Mf4Compression,
    /// Uncompressed bytes per data block (at least one record).
    pub block_size: usize,
    /// Write as a logger does (see the module documentation); forces the unsorted layout
    /// without compression.
    pub unfinalized: bool,
}

impl Default for Mf4WriterOptions {
    fn default() -> Self {
        Mf4WriterOptions {
            layout: Mf4Layout::Unsorted,
            compression: Mf4Compression::None,
            block_size: 4 << 20,
            unfinalized: false,
        }
    }
}

/// The channel groups written, in record ID order (record ID = index + 1).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
enum Group {
    Data8,
    Data64,
    Remote,
    Error,
}

const GROUPS: [Group; 4] = [Group::Data8, Group::Data64, Group::Remote, Group::Error];

impl Group {
    fn of(f: &Frame) -> Group {
        match f.kind {
            FrameKind::Data if f.fd => Group::Data64,
            FrameKind::Data => Group::Data8,
            FrameKind::Remote => Group::Remote,
            FrameKind::Error => Group::Error,
        }
    }
    fn payload(self) -> usize {
        match self {
            Group::Data8 | Group::Error => 8,
            Group::Data64 => 64,
            Group::Remote => 0,
        }
    }
    /// Record bytes (without record ID).
    fn rec_len(self) -> usize {
        16 + self.payload()
    }
    fn acq_name(self) -> &'static str {
        match self {
            Group::Data8 => "CAN_DataFrame",
            Group::Data64 => "CAN_DataFrame_FD",
            Group::Remote => "CAN_RemoteFrame",
            Group::Error => "CAN_ErrorFrame",
        }
    }
    fn structure(self) -> &'static str {
        match self {
            Group::Data8 | Group::Data64 => "CAN_DataFrame",
            Group::Remote => "CAN_RemoteFrame",
            Group::Error => "CAN_ErrorFrame",
        }
    }
    fn index(self) -> usize {
        self as usize
    }
}

/// Per channel group (sorted) or for the one data group (unsorted): the open block and the
/// blocks written so far.
#[derive(Default)]
struct Sink {
    buf: Vec<u8>,
    blocks: Vec<(u64, u64)>, // (address, uncompressed length)
}

/// Streaming MDF 4 writer; call [`Mf4Writer::finish`] at the end (a writer dropped without it
/// leaves a file without metadata, except in the unfinalized mode).
pub struct Mf4Writer<W: Write + Seek> {
    w: W,
    opts: Mf4WriterOptions,
    pos: u64,
    started: bool,
    start_ns: i64,
    counts: [u64; 4],
    sinks: Vec<Sink>,
    names: Vec<IfaceName>,
    channels: Vec<u8>,
    z: Compress,
    zout: Vec<u8>,
    tmp: Vec<u8>,
    /// Unfinalized mode: where the single DT block starts.
    dt_at: u64,
}

fn pad8(n: u64) -> u64 {
    n.div_ceil(8) * 8
}

/// One metadata block: header, links, data, padded to 8 bytes.
fn block(id: &[u8; 4], links: &[u64], data: &[u8]) -> Vec<u8> {
    let len = 24 + 8 * links.len() + data.len();
    let mut b = Vec::with_capacity(pad8(len as u64) as usize);
    b.extend_from_slice(id);
    b.extend_from_slice(&[0; 4]);
    b.extend_from_slice(&(len as u64).to_le_bytes());
    b.extend_from_slice(&(links.len() as u64).to_le_bytes());
    for l in links {
        b.extend_from_slice(&l.to_le_bytes());
    }
    b.extend_from_slice(data);
    b.resize(pad8(len as u64) as usize, 0);
    b
}

impl<W: Write + Seek> Mf4Writer<W> {
    /// A writer at the start of `w` (which it overwrites from its current position 0).
    pub fn new(mut w: W, mut opts: Mf4WriterOptions) -> io::Result<Mf4Writer<W>> {
        if opts.unfinalized {
            opts.layout = Mf4Layout::Unsorted;
            opts.compression = Mf4Compression::None;
        }
        opts.block_size = opts.block_size.max(128);
        w.seek(SeekFrom::Start(0))?;
        let nsinks = match opts.layout {
            Mf4Layout::Unsorted => 1,
            Mf4Layout::Sorted => 4,
        };
        let mut wr = Mf4Writer {
            w,
            opts,
            pos: 0,
            started: false,
            start_ns: 0,
            counts: [0; 4],
            sinks: (0..nsinks).map(|_| Sink::default()).collect(),
            names: Vec::new(),
            channels: Vec::new(),
            z: Compress::new(Compression::default(), true),
            zout: Vec::new(),
            tmp: Vec::new(),
            dt_at: 0,
        };
        // Identification and header; the header's links and start time are patched later.
        let mut id = [0u8; 64];
        id[..8].copy_from_slice(if opts.unfinalized {
            super::ID_UNFINALIZED
        } else {
            super::ID_FINALIZED
        });
        id[8..16].copy_from_slice(b"4.11    ");
        id[16..24].copy_from_slice(b"shimmy  ");
        id[28..30].copy_from_slice(&411u16.to_le_bytes());
        if opts.unfinalized {
            let flags = super::UNFIN_CG_COUNTERS | super::UNFIN_LAST_DT_LENGTH;
            id[60..62].copy_from_slice(&flags.to_le_bytes());
        }
        wr.put(&id)?;
        let hd = Self::hd_block(0, 0);
        wr.put(&hd)?;
        Ok(wr)
    }

    fn hd_block(first_dg: u64, start_ns: i64) -> Vec<u8> {
        let mut data = [0u8; 32];
        data[..8].copy_from_slice(&(start_ns.max(0) as u64).to_le_bytes());
        // Time flags 0: UTC, no offsets.
        block(b"##HD", &[first_dg, 0, 0, 0, 0, 0], &data)
    }

    fn put(&mut self, b: &[u8]) -> io::Result<u64> {
        let at = self.pos;
        self.w.write_all(b)?;
        self.pos += b.len() as u64;
        Ok(at)
    }

    /// The bus channel number of an interface name (assigned on first sight).
    fn channel(&mut self, name: IfaceName) -> io::Result<u8> {
        if let Some(i) = self.names.iter().position(|n| *n == name) {
            return Ok(self.channels[i]);
        }
        if self.names.len() >= 255 {
            return Err(io::Error::new(
                io::ErrorKind::InvalidInput,
                "more than 255 interfaces: MF4 BusChannel is one byte here",
            ));
        }
        let s = name.as_str();
        let want = s
            .strip_prefix("can")
            .and_then(|d| d.parse::<u8>().ok())
            .filter(|&k| k < 255 && (d_is_canonical(s)))
            .map(|k| k + 1);
        let ch = match want {
            Some(c) if !self.channels.contains(&c) => c,
            _ => (1..=255u8).find(|c| !self.channels.contains(c)).unwrap(),
        };
        self.names.push(name);
        self.channels.push(ch);
        Ok(ch)
    }

    /// Write one frame. `InvalidInput` for a frame the layout cannot hold (a 256th interface).
    pub fn write(&mut self, f: &Frame) -> io::Result<()> {
        if !self.started {
            self.started = true;
            self.start_ns = f.t_ns;
            if self.opts.unfinalized {
                self.begin_unfinalized()?;
            }
        }
        let g = Group::of(f);
        let ch = self.channel(f.iface)?;
        let sink = match self.opts.layout {
            Mf4Layout::Unsorted => 0,
            Mf4Layout::Sorted => g.index(),
        };
        let s = &mut self.sinks[sink];
        if self.opts.layout == Mf4Layout::Unsorted {
            s.buf.push(g.index() as u8 + 1);
        }
        let rel = f.t_ns.wrapping_sub(self.start_ns);
        s.buf.extend_from_slice(&rel.to_le_bytes());
        s.buf.push(ch);
        let (id, ide) = match f.kind {
            FrameKind::Error => (f.id & 0x1FFF_FFFF, false),
            _ => (f.id, f.extended),
        };
        s.buf.extend_from_slice(&id.to_le_bytes());
        let flags = ide as u8 | (f.fd as u8) << 2 | (f.brs as u8) << 3 | (f.esi as u8) << 4;
        s.buf.push(flags);
        s.buf.push(f.dlc & 0x0F);
        let n = g.payload();
        s.buf.push(if n == 0 { f.len.min(8) } else { f.len });
        if n > 0 {
            let k = (f.len as usize).min(n);
            s.buf.extend_from_slice(&f.data[..k]);
            s.buf.resize(s.buf.len() + (n - k), 0);
        }
        self.counts[g.index()] += 1;
        if s.buf.len() >= self.opts.block_size {
            if self.opts.unfinalized {
                let buf = std::mem::take(&mut self.sinks[0].buf);
                self.put(&buf)?;
                self.sinks[0].buf = buf;
                self.sinks[0].buf.clear();
            } else {
                self.flush_block(sink, g)?;
            }
        }
        Ok(())
    }

    /// Write the sink's buffered records as one DT or DZ block.
    fn flush_block(&mut self, sink: usize, g: Group) -> io::Result<()> {
        let mut buf = std::mem::take(&mut self.sinks[sink].buf);
        if buf.is_empty() {
            self.sinks[sink].buf = buf;
            return Ok(());
        }
        let org_len = buf.len() as u64;
        let at = self.pos;
        match self.opts.compression {
            Mf4Compression::None => {
                let mut h = Vec::with_capacity(24);
                h.extend_from_slice(b"##DT\0\0\0\0");
                h.extend_from_slice(&(24 + org_len).to_le_bytes());
                h.extend_from_slice(&0u64.to_le_bytes());
                self.put(&h)?;
                self.put(&buf)?;
                let pad = pad8(self.pos) - self.pos;
                self.put(&[0u8; 8][..pad as usize])?;
            }
            c => {
                let transposed =
                    c == Mf4Compression::Transposed && self.opts.layout == Mf4Layout::Sorted;
                let cols = g.rec_len();
                let mut param = 0u32;
                let src: &[u8] = if transposed && buf.len() >= 2 * cols {
                    let rows = buf.len() / cols;
                    let n = rows * cols;
                    self.tmp.clear();
                    self.tmp.resize(buf.len(), 0);
                    for r in 0..rows {
                        for c in 0..cols {
                            self.tmp[c * rows + r] = buf[r * cols + c];
                        }
                    }
                    self.tmp[n..].copy_from_slice(&buf[n..]);
                    param = cols as u32;
                    &self.tmp
                } else {
                    &buf
                };
                self.zout.clear();
                self.zout.reserve(src.len() / 2 + 1024);
                self.z.reset();
                loop {
                    let before = self.z.total_in() as usize;
                    let st = self
                        .z
                        .compress_vec(&src[before..], &mut self.zout, FlushCompress::Finish)
                        .map_err(io::Error::other)?;
                    if st == flate2::Status::StreamEnd {
                        break;
                    }
                    self.zout.reserve(self.zout.capacity().max(4096));
                }
                let zlen = self.zout.len() as u64;
                let mut h = Vec::with_capacity(48);
                h.extend_from_slice(b"##DZ\0\0\0\0");
                h.extend_from_slice(&(48 + zlen).to_le_bytes());
                h.extend_from_slice(&0u64.to_le_bytes());
                h.extend_from_slice(b"DT");
                h.push(if param > 0 { 1 } else { 0 });
                h.push(0);
                h.extend_from_slice(&param.to_le_bytes());
                h.extend_from_slice(&org_len.to_le_bytes());
                h.extend_from_slice(&zlen.to_le_bytes());
                self.put(&h)?;
                let z = std::mem::take(&mut self.zout);
                self.put(&z)?;
                self.zout = z;
                let pad = pad8(self.pos) - self.pos;
                self.put(&[0u8; 8][..pad as usize])?;
            }
        }
        self.sinks[sink].blocks.push((at, org_len));
        buf.clear();
        self.sinks[sink].buf = buf;
        Ok(())
    }

    fn begin_unfinalized(&mut self) -> io::Result<()> {
        // Metadata first, pointing at the DT block that follows it.
        let meta_at = self.pos;
        let first_dg = self.metadata(&[0], false)?;
        let dt_at = self.pos;
        self.dt_at = dt_at;
        let mut h = Vec::with_capacity(24);
        h.extend_from_slice(b"##DT\0\0\0\0");
        h.extend_from_slice(&24u64.to_le_bytes());
        h.extend_from_slice(&0u64.to_le_bytes());
        self.put(&h)?;
        // Patch the DG's data link and the header.
        let end = self.pos;
        self.w.seek(SeekFrom::Start(first_dg + 24 + 16))?;
        self.w.write_all(&dt_at.to_le_bytes())?;
        self.w.seek(SeekFrom::Start(64))?;
        self.w.write_all(&Self::hd_block(first_dg, self.start_ns))?;
        self.w.seek(SeekFrom::Start(end))?;
        let _ = meta_at;
        Ok(())
    }

    /// Write the metadata (text, conversion, source, channel, channel group and data group
    /// blocks) at the current position; `data` holds each data group's data link. Returns the
    /// first data group's address.
    fn metadata(&mut self, data: &[u64], names: bool) -> io::Result<u64> {
        let unsorted = self.opts.layout == Mf4Layout::Unsorted;
        // Shared blocks.
        let si_name = self.put(&tx("CAN"))?;
        let mut si = [0u8; 8];
        si[0] = 2; // source type: bus
        si[1] = 2; // bus type: CAN
        let si_at = self.put(&block(b"##SI", &[si_name, si_name, 0], &si))?;
        let mut cc = Vec::new();
        cc.extend_from_slice(&[1, 0]);
        cc.extend_from_slice(&0u16.to_le_bytes());
        cc.extend_from_slice(&0u16.to_le_bytes());
        cc.extend_from_slice(&2u16.to_le_bytes());
        cc.extend_from_slice(&[0u8; 16]);
        cc.extend_from_slice(&0f64.to_le_bytes());
        cc.extend_from_slice(&1e-9f64.to_le_bytes());
        let unit = self.put(&tx("s"))?;
        let time_cc = self.put(&block(b"##CC", &[0, unit, 0, 0], &cc))?;
        let bus_cc = if names && !self.names.is_empty() {
            let mut texts = Vec::new();
            for n in self.names.clone() {
                texts.push(self.put(&tx(n.as_str()))?);
            }
            texts.push(0); // default
            let mut d = Vec::new();
            d.extend_from_slice(&[7, 0]);
            d.extend_from_slice(&0u16.to_le_bytes());
            d.extend_from_slice(&(texts.len() as u16).to_le_bytes());
            d.extend_from_slice(&(self.names.len() as u16).to_le_bytes());
            d.extend_from_slice(&[0u8; 16]);
            for &c in &self.channels {
                d.extend_from_slice(&(c as f64).to_le_bytes());
            }
            let mut links = vec![0u64, 0, 0, 0];
            links.extend_from_slice(&texts);
            self.put(&block(b"##CC", &links, &d))?
        } else {
            0
        };
        let mut cg_addrs = Vec::new();
        for g in GROUPS {
            let cn_first = self.channels_of(g, time_cc, bus_cc)?;
            let acq = self.put(&tx(g.acq_name()))?;
            let mut d = Vec::new();
            d.extend_from_slice(&(g.index() as u64 + 1).to_le_bytes());
            d.extend_from_slice(&self.counts[g.index()].to_le_bytes());
            d.extend_from_slice(&0x6u16.to_le_bytes()); // bus event, plain bus event
            d.extend_from_slice(&(b'.' as u16).to_le_bytes());
            d.extend_from_slice(&[0u8; 4]);
            d.extend_from_slice(&(g.rec_len() as u32).to_le_bytes());
            d.extend_from_slice(&0u32.to_le_bytes());
            cg_addrs.push((cn_first, acq, d));
        }
        // Channel groups (chained within a data group), then data groups, last first.
        let mut next_dg = 0u64;
        if unsorted {
            let mut next_cg = 0u64;
            for (cn, acq, d) in cg_addrs.into_iter().rev() {
                next_cg = self.put(&block(b"##CG", &[next_cg, cn, acq, si_at, 0, 0], &d))?;
            }
            let mut dd = [0u8; 8];
            dd[0] = 1;
            next_dg = self.put(&block(b"##DG", &[0, next_cg, data[0], 0], &dd))?;
        } else {
            for (i, (cn, acq, d)) in cg_addrs.into_iter().enumerate().rev() {
                let cg = self.put(&block(b"##CG", &[0, cn, acq, si_at, 0, 0], &d))?;
                next_dg = self.put(&block(b"##DG", &[next_dg, cg, data[i], 0], &[0u8; 8]))?;
            }
        }
        Ok(next_dg)
    }

    /// The channel tree of one group: master, then the structure channel and its members.
    fn channels_of(&mut self, g: Group, time_cc: u64, bus_cc: u64) -> io::Result<u64> {
        let s = g.structure();
        // (member, byte, bit, bits, data type)
        let mut members: Vec<(&str, u32, u8, u32, u8)> = vec![
            ("BusChannel", 8, 0, 8, 0),
            ("ID", 9, 0, 29, 0),
            ("IDE", 13, 0, 1, 0),
            ("Dir", 13, 1, 1, 0),
        ];
        if g != Group::Remote {
            members.push(("EDL", 13, 2, 1, 0));
            members.push(("BRS", 13, 3, 1, 0));
            members.push(("ESI", 13, 4, 1, 0));
        }
        members.push(("DLC", 14, 0, 4, 0));
        members.push(("DataLength", 15, 0, 7, 0));
        if g.payload() > 0 {
            members.push(("DataBytes", 16, 0, 8 * g.payload() as u32, 10));
        }
        let mut next = 0u64;
        for &(m, byte, bit, bits, dt) in members.iter().rev() {
            let name = self.put(&tx(&format!("{s}.{m}")))?;
            let cc = if m == "BusChannel" { bus_cc } else { 0 };
            next = self.put(&cn_block(next, 0, name, cc, 0, dt, bit, byte, bits, 0x400))?;
        }
        let sname = self.put(&tx(s))?;
        let structure = self.put(&cn_block(
            0,
            next,
            sname,
            0,
            0,
            10,
            0,
            8,
            8 * (g.rec_len() as u32 - 8),
            0x400,
        ))?;
        let tname = self.put(&tx("Timestamp"))?;
        let mut master = cn_block(structure, 0, tname, time_cc, 2, 2, 0, 0, 64, 0);
        master[24 + 64 + 1] = 1; // sync type: time
        self.put(&master)
    }

    /// Write the remaining data and the metadata, patch the header, and return the inner
    /// writer (flushed). In the unfinalized mode only the buffered records are written.
    pub fn finish(mut self) -> io::Result<W> {
        if self.opts.unfinalized {
            if !self.started {
                self.started = true;
                self.begin_unfinalized()?;
            }
            let buf = std::mem::take(&mut self.sinks[0].buf);
            self.put(&buf)?;
            self.w.flush()?;
            return Ok(self.w);
        }
        let nsinks = self.sinks.len();
        for (s, &g) in GROUPS.iter().enumerate().take(nsinks) {
            // Unsorted: one sink; the group only matters for transposition (sorted only).
            self.flush_block(s, g)?;
        }
        let mut data = Vec::new();
        for s in 0..nsinks {
            let blocks = std::mem::take(&mut self.sinks[s].blocks);
            data.push(match blocks.len() {
                0 => 0,
                1 => blocks[0].0,
                n => {
                    let links: Vec<u64> = std::iter::once(0)
                        .chain(blocks.iter().map(|b| b.0))
                        .collect();
                    let mut d = Vec::with_capacity(8 + 8 * n);
                    d.extend_from_slice(&[0u8; 4]); // flags 0: offsets given
                    d.extend_from_slice(&(n as u32).to_le_bytes());
                    let mut off = 0u64;
                    for b in &blocks {
                        d.extend_from_slice(&off.to_le_bytes());
                        off += b.1;
                    }
                    self.put(&block(b"##DL", &links, &d))?
                }
            });
        }
        let first_dg = self.metadata(&data, true)?;
        self.w.seek(SeekFrom::Start(64))?;
        self.w.write_all(&Self::hd_block(first_dg, self.start_ns))?;
        self.w.seek(SeekFrom::Start(self.pos))?;
        self.w.flush()?;
        Ok(self.w)
    }

    /// Frames written so far.
    pub fn frames(&self) -> u64 {
        self.counts.iter().sum()
    }
}

/// `canN` written canonically (no leading zeros, no sign), so the number round-trips.
fn d_is_canonical(s: &str) -> bool {
    let d = &s[3..];
    !d.is_empty() && d.bytes().all(|b| b.is_ascii_digit()) && (d == "0" || !d.starts_with('0'))
}

fn tx(s: &str) -> Vec<u8> {
    let mut d = s.as_bytes().to_vec();
    d.push(0);
    block(b"##TX", &[], &d)
}

#[allow(clippy::too_many_arguments)]
fn cn_block(
    next: u64,
    composition: u64,
    name: u64,
    cc: u64,
    cn_type: u8,
    data_type: u8,
    bit: u8,
    byte: u32,
    bits: u32,
    flags: u32,
) -> Vec<u8> {
    let mut d = Vec::with_capacity(72);
    d.push(cn_type);
    d.push(0); // sync type
    d.push(data_type);
    d.push(bit);
    d.extend_from_slice(&byte.to_le_bytes());
    d.extend_from_slice(&bits.to_le_bytes());
    d.extend_from_slice(&flags.to_le_bytes());
    d.extend_from_slice(&0u32.to_le_bytes()); // invalidation bit
    d.push(0); // precision
    d.push(0);
    d.extend_from_slice(&0u16.to_le_bytes()); // attachments
    d.extend_from_slice(&[0u8; 48]); // ranges and limits
    block(b"##CN", &[next, composition, name, 0, cc, 0, 0, 0], &d)
}
