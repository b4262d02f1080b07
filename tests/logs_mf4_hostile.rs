//! Hostile MF4: truncated files, cyclic and out-of-range links, absurd lengths, unknown block
//! types, compressed blocks that would inflate to gigabytes. Each must end in a clear error
//! (the file cannot be opened) or counted skips, never a panic, a hang or unbounded memory.
//! Also: a proptest fuzzer mutating real MF4 files (ours and a logger's), the crafted files kept
//! as a corpus in tests/mf4_corpus/ (rewritten with SHIMMY_WRITE_MF4_CORPUS=1), and no
//! allocation per frame on the read path.

use proptest::prelude::*;
use shimmy::source::log::LogReader;
use shimmy::source::{CanSource, SourceStats};
use shimmy::wire::mf4::{Mf4Compression, Mf4Layout, Mf4WriterOptions};
use shimmy::wire::Frame;
use std::io::Cursor;
use std::path::Path;
use std::time::{Duration, Instant};

#[path = "support/counting_alloc.rs"]
mod counting_alloc;
mod mf4_common;
use mf4_common::*;

/// What reading a file came to.
#[derive(Debug)]
enum Outcome {
    /// Could not be opened: the error's text.
    Refused(String),
    Read(Vec<Frame>, SourceStats, Vec<String>),
}

fn read_any(bytes: Vec<u8>) -> Outcome {
    let t0 = Instant::now();
    let mut r = match LogReader::from_seekable(Cursor::new(bytes), "hostile.mf4") {
        Ok(r) => r,
        Err(e) => return Outcome::Refused(e.to_string()),
    };
    let mut v = Vec::new();
    let mut f = Frame::empty(0);
    while r.read_frame(&mut f).expect("in-memory reads do not fail") {
        v.push(f);
        assert!(v.len() < 10_000_000, "runaway reader");
    }
    assert!(
        t0.elapsed() < Duration::from_secs(20),
        "reading took {:?}",
        t0.elapsed()
    );
    let st = r.stats();
    assert_eq!(st.frames, v.len() as u64);
    let skips = r.take_skips().into_iter().map(|s| s.reason).collect();
    Outcome::Read(v, st, skips)
}

fn frames() -> Vec<Frame> {
    synthetic_frames_on(400, 99, &["can0", "can1"])
}

fn file(layout: Mf4Layout, compression: Mf4Compression) -> Vec<u8> {
    write_mf4(
        &frames(),
        Mf4WriterOptions {
            layout,
            compression,
            block_size: 4 * 1024,
            unfinalized: false,
        },
    )
}

fn u64at(b: &[u8], at: usize) -> u64 {
    u64::from_le_bytes(b[at..at + 8].try_into().unwrap())
}
fn put64(b: &mut [u8], at: usize, v: u64) {
    b[at..at + 8].copy_from_slice(&v.to_le_bytes());
}
/// Address of link `i` of the block at `at`.
fn link_at(at: usize, i: usize) -> usize {
    at + 24 + 8 * i
}
fn link(b: &[u8], at: usize, i: usize) -> usize {
    u64at(b, link_at(at, i)) as usize
}

/// Block addresses of our writer's file: (first DG, its first CG, its first CN, its data).
fn landmarks(b: &[u8]) -> (usize, usize, usize, usize) {
    let dg = link(b, 64, 0);
    let cg = link(b, dg, 1);
    let cn = link(b, cg, 1);
    let data = link(b, dg, 2);
    (dg, cg, cn, data)
}

fn expect_refused(name: &str, bytes: Vec<u8>, what: &str) -> String {
    match read_any(bytes) {
        Outcome::Refused(e) => {
            assert!(
                e.contains(what),
                "{name}: error {e:?} should mention {what:?}"
            );
            e
        }
        Outcome::Read(v, st, s) => panic!(
            "{name}: read {} frames ({st:?}, {s:?}), expected refusal",
            v.len()
        ),
    }
}

fn expect_counted(name: &str, bytes: Vec<u8>, what: &str) -> (usize, SourceStats) {
    match read_any(bytes) {
        Outcome::Refused(e) => panic!("{name}: refused ({e}), expected a counted skip"),
        Outcome::Read(v, st, skips) => {
            assert!(
                st.malformed >= 1,
                "{name}: nothing counted ({} frames)",
                v.len()
            );
            assert!(
                skips.iter().any(|s| s.contains(what)),
                "{name}: reports {skips:?} should mention {what:?}"
            );
            (v.len(), st)
        }
    }
}

/// The crafted hostile files: (name, bytes, expected, text the error or report must contain).
fn crafted() -> Vec<(String, Vec<u8>, &'static str, &'static str)> {
    let mut v = Vec::new();
    let unsorted = file(Mf4Layout::Unsorted, Mf4Compression::None);
    let sorted_dz = file(Mf4Layout::Sorted, Mf4Compression::Transposed);
    let (dg, cg, cn, data) = landmarks(&unsorted);
    let mut add = |n: &str, b: Vec<u8>, exp: &'static str, what: &'static str| {
        v.push((n.to_string(), b, exp, what))
    };

    let mut b = unsorted.clone();
    put64(&mut b, link_at(dg, 0), dg as u64);
    add("dg_cycle", b, "refused", "loops");
    let mut b = unsorted.clone();
    put64(&mut b, link_at(cg, 0), cg as u64);
    add("cg_cycle", b, "refused", "loops");
    let mut b = unsorted.clone();
    put64(&mut b, link_at(cn, 0), cn as u64);
    add("cn_cycle", b, "refused", "loops");
    let mut b = unsorted.clone();
    put64(&mut b, link_at(64, 0), unsorted.len() as u64 + 4096);
    add("dg_out_of_range", b, "refused", "outside the file");
    let mut b = unsorted.clone();
    put64(&mut b, link_at(cg, 2), u64::MAX - 7);
    add("name_link_u64_max", b, "refused", "outside the file");
    let mut b = unsorted.clone();
    put64(&mut b, dg + 8, u64::MAX);
    add("dg_length_u64_max", b, "refused", "impossible length");
    let mut b = unsorted.clone();
    put64(&mut b, cg + 16, 1 << 60);
    add("cg_link_count_absurd", b, "refused", "impossible length");
    let mut b = unsorted.clone();
    b[..8].copy_from_slice(b"MDF     ");
    b[28..30].copy_from_slice(&330u16.to_le_bytes());
    add("mdf3_version", b, "refused", "version 330");

    // Data: the DL of the unsorted file lists its blocks; point its first link at itself, then
    // make its chain loop, then point at an unknown block type.
    assert_eq!(&unsorted[data..data + 4], b"##DL");
    let first = link(&unsorted, data, 1);
    let mut b = unsorted.clone();
    put64(&mut b, link_at(data, 0), data as u64);
    add("dl_chain_cycle", b, "counted", "listed twice");
    let mut b = unsorted.clone();
    put64(&mut b, link_at(data, 1), data as u64);
    add("dl_lists_itself", b, "counted", "expected");
    let mut b = unsorted.clone();
    b[first..first + 4].copy_from_slice(b"##QQ");
    add("unknown_data_block", b, "counted", "QQ");
    let mut b = unsorted.clone();
    put64(&mut b, first + 8, 1 << 62);
    add("dt_length_absurd", b, "counted", "");
    // Our finalized files keep their metadata after the data: a cut one cannot be opened.
    let mut b = unsorted.clone();
    let n = 2 * (b.len() - first) / 3;
    b.truncate(first + n);
    add("truncated_finalized", b, "refused", "outside the file");
    // A DT block longer than the file (a file cut inside its data): what is there is read and
    // the cut record reported.
    let mut b = unsorted.clone();
    let last = link(&unsorted, data, 2);
    put64(&mut b, last + 8, unsorted.len() as u64 * 4);
    add("dt_past_end_of_file", b, "counted", "");
    // DZ blocks of the sorted file: declared sizes that cannot be, and a bomb.
    let (_, _, _, sdata) = landmarks(&sorted_dz);
    let dz = if &sorted_dz[sdata..sdata + 4] == b"##DL" {
        link(&sorted_dz, sdata, 1)
    } else {
        sdata
    };
    assert_eq!(&sorted_dz[dz..dz + 4], b"##DZ");
    let mut b = sorted_dz.clone();
    put64(&mut b, dz + 24 + 8, 8 << 30); // org_data_length 8 GiB
    add("dz_declares_8_gib", b, "counted", "limit");
    let mut b = sorted_dz.clone();
    put64(&mut b, dz + 24 + 8, 100); // inflates past its declared length
    add("dz_inflates_past_length", b, "counted", "different length");
    let mut b = sorted_dz.clone();
    b[dz + 48..dz + 52].copy_from_slice(&[0xFF; 4]);
    add("dz_corrupt_stream", b, "counted", "deflate");
    let mut b = sorted_dz.clone();
    b[dz + 26] = 7;
    add("dz_unknown_zip_type", b, "counted", "");
    // A real bomb: 80 MiB of zeros, 80 KiB of deflate, above the 64 MiB block limit.
    let mut bomb = sorted_dz.clone();
    let at = bomb.len().div_ceil(8) * 8;
    bomb.resize(at, 0);
    let mut z = flate2::write::ZlibEncoder::new(Vec::new(), flate2::Compression::best());
    let zeros = vec![0u8; 1 << 20];
    for _ in 0..80 {
        std::io::Write::write_all(&mut z, &zeros).unwrap();
    }
    let z = z.finish().unwrap();
    let mut h = Vec::new();
    h.extend_from_slice(b"##DZ\0\0\0\0");
    h.extend_from_slice(&(48 + z.len() as u64).to_le_bytes());
    h.extend_from_slice(&0u64.to_le_bytes());
    h.extend_from_slice(b"DT\0\0");
    h.extend_from_slice(&0u32.to_le_bytes());
    h.extend_from_slice(&(80u64 << 20).to_le_bytes());
    h.extend_from_slice(&(z.len() as u64).to_le_bytes());
    bomb.extend_from_slice(&h);
    bomb.extend_from_slice(&z);
    let (dg0, _, _, _) = landmarks(&bomb);
    put64(&mut bomb, link_at(dg0, 2), at as u64);
    add("dz_bomb_80_mib_zeros", bomb.clone(), "counted", "limit");
    // The same bomb declared as 1 GiB.
    put64(&mut bomb, at + 32, 1 << 30);
    add("dz_bomb_declared_1_gib", bomb, "counted", "limit");
    v
}

#[test]
fn crafted_hostile_files_end_in_a_clear_error_or_counted_skips() {
    for (name, bytes, expected, what) in crafted() {
        match expected {
            "refused" => {
                expect_refused(&name, bytes, what);
            }
            _ => {
                expect_counted(&name, bytes, what);
            }
        }
    }
}

/// The crafted files are kept in tests/mf4_corpus/ (small: a few KB each); every file there
/// reads without panic, and the crafted ones as `crafted()` says.
#[test]
fn corpus_reads_without_panic() {
    let dir = Path::new(env!("CARGO_MANIFEST_DIR")).join("tests/mf4_corpus");
    if std::env::var_os("SHIMMY_WRITE_MF4_CORPUS").is_some() {
        std::fs::create_dir_all(&dir).unwrap();
        for (name, bytes, _, _) in crafted() {
            if bytes.len() < 200_000 {
                std::fs::write(dir.join(format!("{name}.mf4")), bytes).unwrap();
            }
        }
    }
    let mut n = 0;
    for e in std::fs::read_dir(&dir).unwrap() {
        let p = e.unwrap().path();
        let _ = read_any(std::fs::read(&p).unwrap());
        n += 1;
    }
    assert!(n >= 10, "corpus has {n} files");
}

/// Every truncation point of a small sorted DZ file and an unsorted DT file: a clear error or
/// what was readable, never a panic.
#[test]
fn every_truncation_is_an_error_or_a_prefix() {
    let all = frames();
    for (layout, comp) in [
        (Mf4Layout::Unsorted, Mf4Compression::None),
        (Mf4Layout::Sorted, Mf4Compression::Transposed),
    ] {
        let b = file(layout, comp);
        let step = (b.len() / 400).max(1);
        for cut in (0..b.len()).step_by(step) {
            if let Outcome::Read(v, _, _) = read_any(b[..cut].to_vec()) {
                // Whatever was read is real frames of the file.
                for f in &v {
                    assert!(all.contains(f), "{layout:?} cut {cut}: invented {f:?}");
                }
            }
        }
    }
}

/// The real logger files truncated at 50 points each.
#[test]
fn real_files_truncated() {
    let Some(dir) = shimmy::shared_data::require("MF4 logger files") else {
        return;
    };
    for e in std::fs::read_dir(dir.join("logs/mf4-css-electronics")).unwrap() {
        let p = e.unwrap().path();
        if p.extension().is_none_or(|e| e != "MF4") {
            continue;
        }
        let b = std::fs::read(&p).unwrap();
        for i in 1..50 {
            let _ = read_any(b[..b.len() * i / 50].to_vec());
        }
    }
}

fn seed_files() -> Vec<Vec<u8>> {
    let mut v = vec![
        file(Mf4Layout::Unsorted, Mf4Compression::None),
        file(Mf4Layout::Sorted, Mf4Compression::Transposed),
        file(Mf4Layout::Unsorted, Mf4Compression::Deflate),
    ];
    if let Some(dir) = shimmy::shared_data::require("MF4 logger files") {
        let p = dir.join(
            "logs/mf4-css-electronics/data-processing_LOG_FCBF0606_00003482_00000001-60B621D9.MF4",
        );
        v.push(std::fs::read(p).unwrap());
    }
    v
}

proptest! {
    // 256 cases by default; PROPTEST_CASES=N for a longer run.
    #![proptest_config(ProptestConfig::with_cases(
        std::env::var("PROPTEST_CASES").ok().and_then(|v| v.parse().ok()).unwrap_or(256)
    ))]

    /// Mutations of real files: byte flips, 8-byte overwrites with special values at 8-aligned
    /// offsets (links and lengths), and a truncation.
    #[test]
    fn mutated_files_never_panic(
        which in 0usize..4,
        flips in prop::collection::vec((any::<usize>(), any::<u8>()), 0..8),
        words in prop::collection::vec((any::<usize>(), prop_oneof![
            Just(0u64), Just(1), Just(24), Just(u64::MAX), Just(1 << 40), Just(64), any::<u64>()
        ]), 0..4),
        cut in prop::option::of(any::<usize>()),
    ) {
        let seeds = seed_files();
        let mut b = seeds[which % seeds.len()].clone();
        for (at, x) in flips {
            let i = at % b.len();
            b[i] ^= x;
        }
        for (at, w) in words {
            let i = (at % (b.len() / 8)) * 8;
            put64(&mut b, i, w);
        }
        if let Some(c) = cut {
            b.truncate(c % (b.len() + 1));
        }
        let _ = read_any(b);
    }
}

/// Reading allocates per block, never per frame.
#[test]
fn no_allocation_per_frame() {
    for (layout, comp, max) in [
        (Mf4Layout::Unsorted, Mf4Compression::None, 0),
        (Mf4Layout::Sorted, Mf4Compression::Transposed, 200),
    ] {
        let many = synthetic_frames_on(30_000, 4, &["can0"]);
        let b = write_mf4(
            &many,
            Mf4WriterOptions {
                layout,
                compression: comp,
                block_size: 256 * 1024,
                unfinalized: false,
            },
        );
        let mut r = LogReader::from_seekable(Cursor::new(b), "x.mf4").unwrap();
        let mut f = Frame::empty(0);
        for _ in 0..2000 {
            assert!(r.read_frame(&mut f).unwrap());
        }
        let a0 = counting_alloc::allocations();
        let mut n = 0;
        while r.read_frame(&mut f).unwrap() {
            n += 1;
        }
        let a = counting_alloc::allocations() - a0;
        assert_eq!(n, 28_000);
        assert!(
            a <= max,
            "{layout:?} {comp:?}: {a} allocations for {n} frames"
        );
    }
}
