//! MDF 4 files from other writers, and ours read by another reader: asammdf (the reference MF4
//! reader and writer) through tests/mf4_fixtures/asammdf_ref.py. Frame for frame, per channel
//! group, on:
//! - files python-can's MF4Writer wrote at each compression level (0 none, 1 deflate,
//!   2 transposition + deflate), from the real RAV4 drive and from a synthetic log with CAN FD,
//!   remote and error frames;
//! - files asammdf saved (sorted, at each compression level) from real CANedge files and from
//!   one of ours;
//! - files our writer wrote, sorted and unsorted, plain and compressed, and an unfinalized one
//!   cut at random points (asammdf finalizes the cut file its own way; we must agree).
//!
//! Needs python3 with asammdf and python-can (`pip install asammdf python-can`): without them
//! the test prints SKIPPED, except under CI=true, where it fails.

use shimmy::shared_data::{in_ci, require, require_file, RAV4_LOG};
use shimmy::source::log::LogReader;
use shimmy::source::recorder::CandumpWriter;
use shimmy::source::CanSource;
use shimmy::wire::mf4::{Mf4Compression, Mf4Layout, Mf4WriterOptions};
use shimmy::wire::{Frame, FrameKind};
use std::collections::BTreeMap;
use std::path::{Path, PathBuf};
use std::process::Command;

mod mf4_common;
use mf4_common::*;

const SCRIPT: &str = concat!(
    env!("CARGO_MANIFEST_DIR"),
    "/tests/mf4_fixtures/asammdf_ref.py"
);

fn python_ready() -> bool {
    let ok = Command::new("python3")
        .args(["-c", "import asammdf, can"])
        .status()
        .is_ok_and(|s| s.success());
    if !ok {
        if in_ci() {
            panic!(
                "python3 with asammdf and python-can is needed (pip install asammdf python-can)"
            );
        }
        eprintln!("SKIPPED asammdf comparison: python3 -c 'import asammdf, can' failed (pip install asammdf python-can)");
    }
    ok
}

fn run_jobs(dir: &Path, jobs: &[String]) {
    let jf = dir.join("jobs.txt");
    std::fs::write(&jf, jobs.join("\n")).unwrap();
    let out = Command::new("python3")
        .arg(SCRIPT)
        .arg(&jf)
        .output()
        .unwrap();
    assert!(
        out.status.success(),
        "asammdf_ref.py failed: {}",
        String::from_utf8_lossy(&out.stderr)
    );
}

#[derive(Debug)]
struct RefRow {
    t: f64,
    bus: u64,
    id: u32,
    ide: bool,
    dlc: u8,
    data: String,
    edl: bool,
    brs: bool,
    esi: bool,
}

type Key = (String, char);

fn parse_dump(p: &Path) -> BTreeMap<Key, Vec<RefRow>> {
    let text = std::fs::read_to_string(p).unwrap();
    let mut m: BTreeMap<Key, Vec<RefRow>> = BTreeMap::new();
    for line in text.lines().skip(1) {
        let c: Vec<&str> = line.split(',').collect();
        assert_eq!(c.len(), 11, "{line}");
        m.entry((c[0].to_string(), c[1].chars().next().unwrap()))
            .or_default()
            .push(RefRow {
                t: c[2].parse().unwrap(),
                bus: c[3].parse().unwrap(),
                id: c[4].parse().unwrap(),
                ide: c[5] == "1",
                dlc: c[6].parse().unwrap(),
                data: c[7].to_string(),
                edl: c[8] == "1",
                brs: c[9] == "1",
                esi: c[10] == "1",
            });
    }
    m
}

fn ours(p: &Path) -> BTreeMap<Key, Vec<(Frame, i64)>> {
    let mut r = LogReader::open(p).unwrap();
    let start = r.start_epoch_ns().unwrap();
    let mut m: BTreeMap<Key, Vec<(Frame, i64)>> = BTreeMap::new();
    let mut f = Frame::empty(0);
    while r.read_frame(&mut f).unwrap() {
        let k = match f.kind {
            FrameKind::Data => 'D',
            FrameKind::Remote => 'R',
            FrameKind::Error => 'E',
        };
        m.entry((r.mf4_group().unwrap().to_string(), k))
            .or_default()
            .push((f, f.t_ns.wrapping_sub(start)));
    }
    let skips = r.take_skips();
    // A cut file may end inside a record: at most that one report.
    assert!(r.stats().malformed <= 1, "{}: {skips:?}", p.display());
    m
}

/// Compare our frames with asammdf's; returns how many were compared.
fn compare(
    name: &str,
    ours: &BTreeMap<Key, Vec<(Frame, i64)>>,
    refs: &BTreeMap<Key, Vec<RefRow>>,
) -> usize {
    assert_eq!(
        ours.keys().collect::<Vec<_>>(),
        refs.keys().collect::<Vec<_>>(),
        "{name}: groups with frames"
    );
    let mut n = 0;
    for (k, rows) in refs {
        let got = &ours[k];
        assert_eq!(got.len(), rows.len(), "{name} {k:?}: frame count");
        for (i, ((f, rel), r)) in got.iter().zip(rows).enumerate() {
            let at = format!("{name} {k:?} frame #{i}: ours {f:?}, asammdf {r:?}");
            // Same float, or the same integer through a linear conversion: equal to the
            // nanosecond, up to the float's own resolution.
            let tol = 1.0 + r.t.abs() * 1e9 * f64::EPSILON * 2.0;
            assert!((*rel as f64 - r.t * 1e9).abs() <= tol, "time: {at}");
            assert_eq!(
                f.iface.as_str(),
                format!("can{}", r.bus.max(1) - 1),
                "bus: {at}"
            );
            match k.1 {
                'D' => {
                    assert_eq!((f.id, f.extended, f.dlc), (r.id, r.ide, r.dlc), "{at}");
                    assert_eq!(hex(f.payload()), r.data, "{at}");
                    assert_eq!(
                        (f.fd, f.brs, f.esi),
                        (r.edl, r.brs && r.edl, r.esi && r.edl),
                        "{at}"
                    );
                }
                'R' => assert_eq!((f.id, f.extended, f.dlc), (r.id, r.ide, r.dlc), "{at}"),
                _ => {
                    assert_eq!(f.id, r.id, "{at}");
                    assert_eq!(hex(&f.data[..8]), format!("{:0<16}", r.data), "{at}");
                }
            }
            n += 1;
        }
    }
    n
}

#[test]
fn asammdf_and_we_read_the_same_frames_from_every_writer() {
    let (Some(data), Some(rav4)) = (require("MF4 logger files"), require_file(RAV4_LOG)) else {
        return;
    };
    if !python_ready() {
        return;
    }
    let tmp = tempfile::tempdir().unwrap();
    let d = tmp.path();
    let p = |n: &str| d.join(n).display().to_string();
    let mut files: Vec<PathBuf> = Vec::new();
    let mut jobs = Vec::new();

    // A synthetic candump log for python-can (it reads candump -L with FD, remote and error
    // frames); interfaces canN so bus numbers compare directly.
    // (python-can's candump reader knows no raw DLC suffix `_D`: those frames get DLC 8.)
    let mut synth = synthetic_frames_on(3000, 21, &["can0", "can1"]);
    for f in synth.iter_mut().filter(|f| !f.fd && f.dlc > 8) {
        f.dlc = 8;
    }
    let mut w = CandumpWriter::create(d.join("synth.log")).unwrap();
    for f in &synth {
        w.write(f).unwrap();
    }
    w.flush().unwrap();
    for level in 0..3 {
        jobs.push(format!(
            "pycan {} {} {level}",
            rav4.display(),
            p(&format!("pc_rav4_{level}.mf4"))
        ));
        jobs.push(format!(
            "pycan {} {} {level}",
            p("synth.log"),
            p(&format!("pc_synth_{level}.mf4"))
        ));
        files.push(d.join(format!("pc_rav4_{level}.mf4")));
        files.push(d.join(format!("pc_synth_{level}.mf4")));
    }

    // Ours, every layout; one cut unfinalized file per seed.
    let frames = synthetic_frames_on(5000, 5, &["can0", "can1", "can2"]);
    for (tag, layout, compression) in [
        ("u_none", Mf4Layout::Unsorted, Mf4Compression::None),
        ("u_defl", Mf4Layout::Unsorted, Mf4Compression::Deflate),
        ("s_none", Mf4Layout::Sorted, Mf4Compression::None),
        ("s_trans", Mf4Layout::Sorted, Mf4Compression::Transposed),
    ] {
        let opts = Mf4WriterOptions {
            layout,
            compression,
            block_size: 32 * 1024,
            unfinalized: false,
        };
        let f = d.join(format!("ours_{tag}.mf4"));
        std::fs::write(&f, write_mf4(&frames, opts)).unwrap();
        files.push(f);
    }
    let unfin = write_mf4(
        &frames,
        Mf4WriterOptions {
            unfinalized: true,
            ..Default::default()
        },
    );
    let start = data_start_of_unfinalized(&unfin);
    for (i, frac) in [0.0, 0.13, 0.5, 0.77, 1.0].iter().enumerate() {
        let cut = start + ((unfin.len() - start) as f64 * frac) as usize + i % 3;
        let f = d.join(format!("ours_unfin_cut{i}.mf4"));
        std::fs::write(&f, &unfin[..cut.min(unfin.len())]).unwrap();
        files.push(f);
    }

    // asammdf saves: real CANedge files (one with VLSD DataBytes, one with per-bus FD groups) and
    // one of ours.
    let css = data.join("logs/mf4-css-electronics");
    for (src, levels) in [
        (
            css.join("data-processing_LOG_2F6913DB_00000004_00000001.MF4"),
            vec![0, 1, 2],
        ),
        (css.join("other_asammdf-basics_input_00000001.MF4"), vec![2]),
        (d.join("ours_u_none.mf4"), vec![1]),
    ] {
        for level in levels {
            let stem = src.file_stem().unwrap().to_string_lossy().to_string();
            let out = d.join(format!("asam_{stem}_{level}.mf4"));
            jobs.push(format!(
                "resave {} {} {level}",
                src.display(),
                out.display()
            ));
            files.push(out);
        }
    }
    for f in &files {
        jobs.push(format!("dump {} {}.csv", f.display(), f.display()));
    }
    run_jobs(d, &jobs);

    let mut total = 0;
    for f in &files {
        let name = f.file_name().unwrap().to_string_lossy().to_string();
        let refs = parse_dump(Path::new(&format!("{}.csv", f.display())));
        let n = compare(&name, &ours(f), &refs);
        assert!(n > 0 || name.contains("cut0"), "{name}: no frames compared");
        total += n;
    }
    // 3 × 53,800 (RAV4) + 3 × 3000 + 4 × 5000 + the cuts + 3 × 5588 + 150,411 + 5000.
    assert!(
        total > 3 * 53_800 + 9000 + 20_000 + 3 * 5588 + 150_411,
        "{total}"
    );
}
