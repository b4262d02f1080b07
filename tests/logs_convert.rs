//! `shimmy convert` and `LogWriter`: the real RAV4 drive through every format and back to
//! candump -L is byte-identical; synthetic frames of every kind survive MF4 and candump whole,
//! and BLF / ASC lose exactly what the writer reports.

use shimmy::shared_data::{require_file, RAV4_LOG};
use shimmy::source::log::LogReader;
use shimmy::source::writer::LogWriter;
use shimmy::source::CanSource;
use shimmy::wire::asc::CAN_ERR_PROT;
use shimmy::wire::mf4::{Mf4Compression, Mf4Layout, Mf4WriterOptions};
use shimmy::wire::{Frame, FrameKind};
use std::path::Path;
use std::process::Command;

mod mf4_common;
use mf4_common::*;

fn shimmy(args: &[&str]) -> std::process::Output {
    Command::new(env!("CARGO_BIN_EXE_shimmy"))
        .args(args)
        .output()
        .unwrap()
}

fn read(p: &Path) -> Vec<Frame> {
    let mut r = LogReader::open(p).unwrap();
    let mut v = Vec::new();
    while let Some(f) = r.next_frame().unwrap() {
        v.push(f);
    }
    assert_eq!(
        r.stats().malformed,
        0,
        "{}: {:?}",
        p.display(),
        r.take_skips()
    );
    v
}

#[test]
fn rav4_through_every_format_and_back_is_byte_identical() {
    let Some(log) = require_file(RAV4_LOG) else {
        return;
    };
    let dir = tempfile::tempdir().unwrap();
    let orig = std::fs::read(&log).unwrap();
    for (out, extra) in [
        ("a.mf4", vec![]),
        (
            "b.mf4",
            vec!["--mf4-layout", "sorted", "--mf4-compression", "transposed"],
        ),
        ("c.mf4", vec!["--mf4-compression", "deflate"]),
        ("d.blf", vec![]),
        ("e.asc", vec![]),
    ] {
        let mid = dir.path().join(out);
        let back = dir.path().join(format!("{out}.log"));
        let mut args = vec![
            "convert",
            log.to_str().unwrap(),
            mid.to_str().unwrap(),
            "--strict",
        ];
        args.extend(extra);
        let o = shimmy(&args);
        assert!(
            o.status.success(),
            "{out}: {}",
            String::from_utf8_lossy(&o.stderr)
        );
        assert!(String::from_utf8_lossy(&o.stderr).contains("lossless"));
        let o = shimmy(&[
            "convert",
            mid.to_str().unwrap(),
            back.to_str().unwrap(),
            "--strict",
        ]);
        assert!(
            o.status.success(),
            "{out}: {}",
            String::from_utf8_lossy(&o.stderr)
        );
        assert!(
            std::fs::read(&back).unwrap() == orig,
            "{out}: round trip differs"
        );
    }
}

#[test]
fn convert_help_is_a_manual() {
    let o = shimmy(&["convert", "--help"]);
    let h = String::from_utf8_lossy(&o.stdout);
    for w in [
        "candump -L",
        "ASC",
        "BLF",
        "MF4",
        "lost",
        "Examples",
        "--mf4-layout",
        "--strict",
    ] {
        assert!(h.contains(w), "help lacks {w}:\n{h}");
    }
}

fn write(frames: &[Frame], p: &Path) -> shimmy::source::writer::Losses {
    let mut w = LogWriter::create(p, Mf4WriterOptions::default()).unwrap();
    for f in frames {
        w.write(f).unwrap();
    }
    w.finish().unwrap()
}

/// Every kind of frame (FD, raw DLC, remote, error with class and data, four interfaces, ns
/// times) through candump and each MF4 layout: identical. Through BLF and ASC: identical but
/// for what the losses name, which are exactly the frames that differ.
#[test]
fn losses_are_reported_exactly() {
    let frames = synthetic_frames(4000, 3);
    let dir = tempfile::tempdir().unwrap();
    for name in ["s.log", "s.mf4"] {
        let p = dir.path().join(name);
        let l = write(&frames, &p);
        assert!(l.is_empty(), "{name}: {l:?}");
        assert_eq!(read(&p), frames, "{name}");
    }
    for (layout, compression) in [
        (Mf4Layout::Sorted, Mf4Compression::Deflate),
        (Mf4Layout::Unsorted, Mf4Compression::Deflate),
    ] {
        let bytes = write_mf4(
            &frames,
            Mf4WriterOptions {
                layout,
                compression,
                ..Default::default()
            },
        );
        assert_eq!(read_mf4(bytes).0, frames);
    }
    for name in ["s.blf", "s.asc"] {
        let p = dir.path().join(name);
        let l = write(&frames, &p);
        let got = read(&p);
        assert_eq!(got.len(), frames.len());
        // Names that are not canN, or whose channel was taken first, read back as another
        // canN: the losses say which, and nothing else may differ.
        let renamed = l.renamed.clone();
        for n in ["vcan0", "slcan3"] {
            assert!(renamed.iter().any(|(a, _)| a == n), "{name}: {renamed:?}");
        }
        let (mut errs, mut rounded) = (0, 0);
        for (g, f) in got.iter().zip(&frames) {
            let mut want = *f;
            if let Some((_, b)) = renamed.iter().find(|(a, _)| a == f.iface.as_str()) {
                want.iface = shimmy::wire::IfaceName::from_str_truncated(b);
            }
            if f.kind == FrameKind::Error {
                errs += (f.id != CAN_ERR_PROT || f.data[..8] != [0; 8]) as u64;
                want.id = CAN_ERR_PROT;
                want.data = [0; 64];
            }
            if name == "s.asc" && (f.t_ns - frames[0].t_ns / 1_000_000 * 1_000_000) % 1000 != 0 {
                rounded += 1;
                let s = frames[0].t_ns / 1_000_000 * 1_000_000;
                want.t_ns = s + ((f.t_ns - s) + 500) / 1000 * 1000;
            }
            assert_eq!(g, &want, "{name}");
        }
        assert_eq!(l.error_details, errs, "{name}");
        assert!(errs > 0);
        assert_eq!(l.times_rounded, rounded, "{name}");
        assert_eq!(l.times_clamped, 0);
    }
}

/// TRC is read, not written: a `.trc` output is refused before anything is created, by the
/// writer every tool uses (not candump text under a TRC name).
#[test]
fn trc_output_is_refused() {
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("out.trc");
    let e = LogWriter::create(&out, Mf4WriterOptions::default())
        .err()
        .expect("a .trc output is refused");
    assert_eq!(e.kind(), std::io::ErrorKind::InvalidInput);
    assert!(
        e.to_string().contains("PEAK TRC is read, not written"),
        "{e}"
    );
    assert!(!out.exists());
    let input = dir.path().join("in.log");
    std::fs::write(&input, "(1.000000) can0 123#11\n").unwrap();
    let o = shimmy(&["convert", input.to_str().unwrap(), out.to_str().unwrap()]);
    assert!(!o.status.success());
    assert!(String::from_utf8_lossy(&o.stderr).contains("PEAK TRC is read, not written"));
    assert!(!out.exists());
}
