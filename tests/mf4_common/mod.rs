//! Helpers shared by the MF4 tests: synthetic frames of every kind, writing and reading MF4 in
//! memory, and the asammdf reference script.
#![allow(dead_code)]

use shimmy::source::log::LogReader;
use shimmy::source::{CanSource, SourceStats};
use shimmy::wire::frame::fd_dlc_to_len;
use shimmy::wire::mf4::{Mf4Writer, Mf4WriterOptions};
use shimmy::wire::{Frame, FrameKind};
use std::io::Cursor;

pub fn hex(b: &[u8]) -> String {
    b.iter().map(|x| format!("{x:02X}")).collect()
}

/// The MF4 bus channel of a frame read from a file without interface names (`can{N-1}`).
pub fn bus_number(f: &Frame) -> u64 {
    f.iface.as_str()[3..].parse::<u64>().unwrap() + 1
}

/// `n` frames with strictly increasing times: classic standard and extended data frames, raw
/// DLC 9-15, CAN FD (every length, BRS/ESI), remote and error frames, on the given interfaces.
pub fn synthetic_frames_on(n: usize, seed: u64, ifaces: &[&str]) -> Vec<Frame> {
    let mut s = seed.wrapping_mul(0x9E37_79B9_7F4A_7C15) | 1;
    let mut next = move || {
        s ^= s << 13;
        s ^= s >> 7;
        s ^= s << 17;
        s
    };
    let mut t = 1_700_000_000_000_000_000i64;
    let mut v = Vec::with_capacity(n);
    for _ in 0..n {
        t += 1 + (next() % 2_000_000) as i64;
        let r = next();
        let ext = r & 1 == 1;
        let id = if ext {
            (r >> 8) as u32 & 0x1FFF_FFFF
        } else {
            (r >> 8) as u32 & 0x7FF
        };
        let mut data = [0u8; 64];
        for b in data.iter_mut() {
            *b = next() as u8;
        }
        let mut f = match (r >> 40) % 20 {
            0..=11 => Frame::classic(t, id, ext, &data[..((r >> 48) % 9) as usize]).unwrap(),
            12 => {
                let mut f = Frame::classic(t, id, ext, &data[..8]).unwrap();
                f.dlc = 9 + ((r >> 48) % 7) as u8;
                f
            }
            13..=16 => {
                let len = fd_dlc_to_len(((r >> 48) % 16) as u8);
                let mut f = Frame::fd(t, id, ext, &data[..len]).unwrap();
                f.brs = r >> 56 & 1 == 1;
                f.esi = r >> 57 & 1 == 1;
                f
            }
            17 | 18 => {
                let mut f = Frame::classic(t, id, ext, &[]).unwrap();
                f.kind = FrameKind::Remote;
                f.len = ((r >> 48) % 9) as u8;
                f.dlc = f.len;
                f
            }
            _ => {
                let mut f = Frame::classic(t, (r >> 8) as u32 & 0x1FF, false, &data[..8]).unwrap();
                f.kind = FrameKind::Error;
                f
            }
        };
        f.set_iface(ifaces[(r >> 60) as usize % ifaces.len()]);
        v.push(f);
    }
    v
}

pub fn synthetic_frames(n: usize, seed: u64) -> Vec<Frame> {
    synthetic_frames_on(n, seed, &["can0", "can1", "vcan0", "slcan3"])
}

pub fn write_mf4(frames: &[Frame], opts: Mf4WriterOptions) -> Vec<u8> {
    let mut w = Mf4Writer::new(Cursor::new(Vec::new()), opts).unwrap();
    for f in frames {
        w.write(f).unwrap();
    }
    w.finish().unwrap().into_inner()
}

pub fn read_mf4(bytes: Vec<u8>) -> (Vec<Frame>, SourceStats) {
    let mut r = LogReader::from_seekable(Cursor::new(bytes), "mem.mf4").unwrap();
    let mut v = Vec::new();
    while let Some(f) = r.next_frame().unwrap() {
        v.push(f);
    }
    (v, r.stats())
}

/// Where the records of an unfinalized file written by `Mf4Writer` begin (after its one DT
/// block header).
pub fn data_start_of_unfinalized(bytes: &[u8]) -> usize {
    let at = bytes.windows(4).position(|w| w == b"##DT").unwrap();
    at + 24
}

/// Bytes of one record in the writer's unsorted layout (record ID, 16 bytes, payload).
pub fn record_len(f: &Frame) -> usize {
    1 + 16
        + match f.kind {
            FrameKind::Data if f.fd => 64,
            FrameKind::Remote => 0,
            _ => 8,
        }
}

/// How many whole records fit in `n` bytes of records, and 1 if a record is cut there.
pub fn record_count_before(frames: &[Frame], n: usize) -> (usize, usize) {
    let mut used = 0;
    for (i, f) in frames.iter().enumerate() {
        let l = record_len(f);
        if used + l > n {
            return (i, (used < n) as usize);
        }
        used += l;
    }
    (frames.len(), 0)
}
