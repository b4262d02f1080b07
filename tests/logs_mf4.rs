//! MDF 4 reading against the reference: the six real CANedge files (their frames as asammdf
//! 8.8.28 reads them lie beside them), and files written by our own writer, sorted and
//! unsorted, plain and compressed, read back frame for frame; an unfinalized file cut at
//! random points reads as its uncut prefix.

use shimmy::shared_data::require;
use shimmy::source::log::{LogFormat, LogReader};
use shimmy::source::CanSource;
use shimmy::wire::mf4::{Mf4Compression, Mf4Layout, Mf4WriterOptions};
use shimmy::wire::{Frame, FrameKind};
use std::collections::BTreeMap;
use std::io::Read;
use std::path::Path;

mod mf4_common;
use mf4_common::*;

/// One row of an expected-frames CSV.
#[derive(Debug, PartialEq)]
struct Row {
    t_s: String,
    bus: u64,
    id: u32,
    ide: bool,
    dlc: u8,
    data: String,
}

fn expected(csv_gz: &Path) -> BTreeMap<String, Vec<Row>> {
    let mut text = String::new();
    flate2::read::GzDecoder::new(std::fs::File::open(csv_gz).unwrap())
        .read_to_string(&mut text)
        .unwrap();
    let mut by_group: BTreeMap<String, Vec<Row>> = BTreeMap::new();
    for line in text.lines().skip(1) {
        let c: Vec<&str> = line.split(',').collect();
        assert_eq!(c.len(), 7, "{line}");
        by_group.entry(c[1].to_string()).or_default().push(Row {
            t_s: c[0].to_string(),
            bus: c[2].parse().unwrap(),
            id: c[3].parse().unwrap(),
            ide: c[4] == "1",
            dlc: c[5].parse().unwrap(),
            data: c[6].to_string(),
        });
    }
    by_group
}

/// Every file in logs/mf4-css-electronics: same frames, per channel group in the same order,
/// as asammdf read them. Times: the CSV gives seconds from the file's start to 6 decimals, so
/// ours (exact ns) must round to within half a microsecond of it.
#[test]
fn real_canedge_files_match_asammdf_frame_for_frame() {
    let Some(dir) = require("MF4 logger files") else {
        return;
    };
    let dir = dir.join("logs/mf4-css-electronics");
    let mut files: Vec<_> = std::fs::read_dir(&dir)
        .unwrap()
        .map(|e| e.unwrap().path())
        .filter(|p| p.extension().is_some_and(|e| e == "MF4"))
        .collect();
    files.sort();
    assert_eq!(
        files.len(),
        6,
        "expected six MF4 files in {}",
        dir.display()
    );
    let mut total = 0usize;
    for path in files {
        let name = path.file_name().unwrap().to_string_lossy().to_string();
        let csv = path.with_extension("expected_frames.csv.gz");
        let want = expected(&csv);
        let mut r = LogReader::open(&path).unwrap();
        assert_eq!(r.format(), LogFormat::Mf4);
        let start = r.start_epoch_ns().unwrap();
        let mut got: BTreeMap<String, Vec<(Frame, i64)>> = BTreeMap::new();
        let mut f = Frame::empty(0);
        while r.read_frame(&mut f).unwrap() {
            let g = r.mf4_group().unwrap().to_string();
            got.entry(g).or_default().push((f, f.t_ns - start));
        }
        let st = r.stats();
        assert_eq!(st.malformed, 0, "{name}: {:?}", r.take_skips());
        assert_eq!(
            got.keys().collect::<Vec<_>>(),
            want.keys().collect::<Vec<_>>(),
            "{name}: channel groups with frames"
        );
        for (g, rows) in &want {
            let ours = &got[g];
            assert_eq!(ours.len(), rows.len(), "{name} {g}: frame count");
            for (i, ((f, rel), row)) in ours.iter().zip(rows).enumerate() {
                let t: f64 = row.t_s.parse().unwrap();
                assert!(
                    (*rel as f64 - t * 1e9).abs() <= 500.5,
                    "{name} {g} #{i}: t {rel} ns vs {}",
                    row.t_s
                );
                assert_eq!(f.kind, FrameKind::Data);
                let got_row = Row {
                    t_s: row.t_s.clone(),
                    bus: bus_number(f),
                    id: f.id,
                    ide: f.extended,
                    dlc: f.dlc,
                    data: hex(f.payload()),
                };
                assert_eq!(&got_row, row, "{name} {g} frame #{i}");
            }
            total += rows.len();
        }
    }
    assert_eq!(total, 2010 + 5588 + 9600 + 1815 + 4024 + 150_411);
}

fn drive_frames() -> Vec<Frame> {
    synthetic_frames(20_000, 7)
}

/// Our writer, every layout and compression, and the reader give back exactly what went in
/// (frames in time order: the synthetic drive's times increase).
#[test]
fn own_writer_round_trips_every_layout() {
    let frames = drive_frames();
    for layout in [Mf4Layout::Unsorted, Mf4Layout::Sorted] {
        for compression in [
            Mf4Compression::None,
            Mf4Compression::Deflate,
            Mf4Compression::Transposed,
        ] {
            let opts = Mf4WriterOptions {
                layout,
                compression,
                block_size: 64 * 1024,
                unfinalized: false,
            };
            let bytes = write_mf4(&frames, opts);
            let (got, st) = read_mf4(bytes);
            assert_eq!(st.malformed, 0, "{layout:?} {compression:?}");
            assert_eq!(got.len(), frames.len(), "{layout:?} {compression:?}");
            for (i, (a, b)) in got.iter().zip(&frames).enumerate() {
                assert_eq!(a, b, "{layout:?} {compression:?} frame #{i}");
            }
        }
    }
}

/// A file written the way a logger writes (unfinalized, DT length never written), cut at random
/// points: every cut past the metadata reads as the frames wholly before the cut, and a cut
/// inside a record is reported once.
#[test]
fn unfinalized_file_cut_anywhere_reads_its_prefix() {
    // An unfinalized file keeps bus channel numbers only, so interfaces are named canN.
    let frames = synthetic_frames_on(20_000, 11, &["can0", "can1", "can7"]);
    let opts = Mf4WriterOptions {
        unfinalized: true,
        ..Default::default()
    };
    let bytes = write_mf4(&frames, opts);
    let (all, st) = read_mf4(bytes.clone());
    assert_eq!(st.malformed, 0);
    assert_eq!(all, frames);
    let data_start = data_start_of_unfinalized(&bytes);
    let mut rng = 0x9E37_79B9_7F4A_7C15u64;
    for _ in 0..40 {
        rng ^= rng << 13;
        rng ^= rng >> 7;
        rng ^= rng << 17;
        let cut = data_start + (rng % (bytes.len() - data_start) as u64) as usize;
        let (got, st) = read_mf4(bytes[..cut].to_vec());
        let whole = record_count_before(&frames, cut - data_start);
        assert_eq!(got.len(), whole.0, "cut at {cut}");
        assert_eq!(&got[..], &frames[..whole.0], "cut at {cut}");
        assert_eq!(st.malformed, whole.1 as u64, "cut at {cut}");
    }
}

/// The real RAV4 drive, candump → MF4 (each layout) → frames: identical to the candump frames.
#[test]
fn rav4_candump_to_mf4_and_back_is_identical() {
    let Some(p) = shimmy::shared_data::require_file(shimmy::shared_data::RAV4_LOG) else {
        return;
    };
    let mut r = LogReader::open(p).unwrap();
    let mut frames = Vec::new();
    while let Some(f) = r.next_frame().unwrap() {
        frames.push(f);
    }
    assert_eq!(frames.len(), 53_800);
    for layout in [Mf4Layout::Unsorted, Mf4Layout::Sorted] {
        let opts = Mf4WriterOptions {
            layout,
            compression: Mf4Compression::Transposed,
            ..Default::default()
        };
        let (got, st) = read_mf4(write_mf4(&frames, opts));
        assert_eq!(st.malformed, 0);
        assert_eq!(got, frames, "{layout:?}");
    }
}

/// A header list (`HL`) in front of the data list, as MDF 4.1 writers may put it: same frames.
#[test]
fn header_list_in_front_of_the_data_list_reads_the_same() {
    let frames = drive_frames();
    let opts = Mf4WriterOptions {
        layout: Mf4Layout::Unsorted,
        compression: Mf4Compression::Deflate,
        block_size: 16 * 1024,
        unfinalized: false,
    };
    let mut b = write_mf4(&frames, opts);
    let u64at = |b: &[u8], at: usize| u64::from_le_bytes(b[at..at + 8].try_into().unwrap());
    let dg = u64at(&b, 64 + 24) as usize;
    let dl = u64at(&b, dg + 24 + 16);
    assert_eq!(&b[dl as usize..dl as usize + 4], b"##DL");
    let hl = b.len().div_ceil(8) * 8;
    b.resize(hl, 0);
    b.extend_from_slice(b"##HL\0\0\0\0");
    b.extend_from_slice(&40u64.to_le_bytes());
    b.extend_from_slice(&1u64.to_le_bytes());
    b.extend_from_slice(&dl.to_le_bytes());
    b.extend_from_slice(&[0u8; 8]); // flags, zip type (deflate), reserved
    b[dg + 24 + 16..dg + 24 + 24].copy_from_slice(&(hl as u64).to_le_bytes());
    let (got, st) = read_mf4(b);
    assert_eq!(st.malformed, 0);
    assert_eq!(got, frames);
}
