//! Read + decode benchmark (issue 2): a candump -L log of at least 1 M frames (the RAV4 bus-0
//! log repeated, timestamps shifted by 60 s per repetition, written to a temp dir) is read with
//! `LogReader` and every frame decoded with `toyota_new_mc_pt_generated.dbc`.
//!
//! One run prints, side by side:
//! - criterion measurements of read+decode of the 1 M-frame file and of decode alone (frames
//!   already in memory);
//! - frames/s of ours (best of 3 passes) and of cantools (`benches/cantools_decode.py`, same
//!   file, same DBC), and the ratio;
//! - peak RSS (VmHWM) of a child process reading + decoding the 1 M and the 4 M-frame files.
//!
//! ```text
//! pip install cantools
//! cargo bench --bench decode
//! ```
//! `SHIMMY_BENCH_NO_CANTOOLS=1` skips the cantools side; `SHIMMY_BENCH_4M=0` skips the 4 M file.

use std::io::{BufRead, Write};
use std::path::{Path, PathBuf};
use std::time::Instant;

use criterion::{Criterion, Throughput};
use shimmy::dbc::Database;
use shimmy::source::log::LogReader;
use shimmy::source::CanSource;
use shimmy::wire::Frame;

/// Counters of one pass; `checksum` keeps the decoded values observable.
#[derive(Default, Debug)]
struct Pass {
    frames: u64,
    decoded: u64,
    checksum: f64,
}

#[inline]
fn decode_frame(db: &Database, f: &Frame, p: &mut Pass) {
    p.frames += 1;
    if let Some(i) = db.message_index(f.id, f.extended) {
        let m = &db.messages()[i];
        let mut acc = 0.0;
        if m.decode(f.payload(), |_, _, phys| acc += phys).is_ok() {
            p.decoded += 1;
            p.checksum += acc;
        }
    }
}

fn read_decode(db: &Database, path: &Path) -> Pass {
    let mut r = LogReader::open(path).expect("open log");
    let mut p = Pass::default();
    // One reused frame, filled in place (no ~100-byte frame returned by value per call).
    let mut f = shimmy::wire::Frame::empty(0);
    while r.read_frame(&mut f).expect("read") {
        decode_frame(db, &f, &mut p);
    }
    p
}

/// Write `reps` copies of the log, shifting timestamps by 60 s per copy. Returns frames written.
fn make_log(src: &[String], reps: usize, out: &Path) -> u64 {
    let mut w = std::io::BufWriter::new(std::fs::File::create(out).unwrap());
    let mut n = 0;
    for rep in 0..reps {
        for line in src {
            let Some(rest) = line.strip_prefix('(') else {
                continue;
            };
            let (sec, tail) = rest.split_once('.').unwrap();
            let sec: u64 = sec.parse().unwrap();
            writeln!(w, "({}.{tail}", sec + 60 * rep as u64).unwrap();
            n += 1;
        }
    }
    w.flush().unwrap();
    n
}

/// CPU time of this thread so far (ns), from the scheduler's accounting; `None` off Linux.
/// On a loaded machine wall time includes waiting for a core, CPU time does not.
fn thread_cpu_ns() -> Option<u64> {
    std::fs::read_to_string("/proc/thread-self/schedstat")
        .ok()?
        .split_whitespace()
        .next()?
        .parse()
        .ok()
}

fn read_only(path: &Path) -> u64 {
    let mut r = LogReader::open(path).expect("open log");
    let mut n = 0u64;
    let mut f = shimmy::wire::Frame::empty(0);
    while r.read_frame(&mut f).expect("read") {
        n += f.len as u64;
    }
    n
}

fn vm_hwm_kb() -> Option<u64> {
    let s = std::fs::read_to_string("/proc/self/status").ok()?;
    s.lines()
        .find_map(|l| l.strip_prefix("VmHWM:"))
        .and_then(|v| v.split_whitespace().next()?.parse().ok())
}

/// Child mode: read + decode one file, report frames and peak RSS.
fn child(dbc: &str, log: &str) {
    let (db, _) = Database::load(dbc).unwrap();
    let p = read_decode(&db, Path::new(log));
    println!("frames={} vmhwm_kb={}", p.frames, vm_hwm_kb().unwrap_or(0));
}

fn peak_rss(dbc: &Path, log: &Path) -> (u64, u64) {
    let out = std::process::Command::new(std::env::current_exe().unwrap())
        .env("SHIMMY_BENCH_RSS_CHILD", "1")
        .env("SHIMMY_BENCH_DBC", dbc)
        .env("SHIMMY_BENCH_LOG", log)
        .output()
        .expect("re-run bench binary");
    let s = String::from_utf8_lossy(&out.stdout);
    let get = |k: &str| -> u64 {
        s.split_whitespace()
            .find_map(|t| t.strip_prefix(k))
            .and_then(|v| v.parse().ok())
            .unwrap_or(0)
    };
    (get("frames="), get("vmhwm_kb="))
}

fn cantools(dbc: &Path, log: &Path) -> Option<serde_json::Value> {
    let script = Path::new(env!("CARGO_MANIFEST_DIR")).join("benches/cantools_decode.py");
    let out = std::process::Command::new("python3")
        .arg(script)
        .arg(dbc)
        .arg(log)
        .output()
        .ok()?;
    if !out.status.success() {
        eprintln!(
            "cantools side failed (pip install cantools?): {}",
            String::from_utf8_lossy(&out.stderr)
        );
        return None;
    }
    serde_json::from_slice(&out.stdout).ok()
}

fn main() {
    if std::env::var_os("SHIMMY_BENCH_RSS_CHILD").is_some() {
        child(
            &std::env::var("SHIMMY_BENCH_DBC").unwrap(),
            &std::env::var("SHIMMY_BENCH_LOG").unwrap(),
        );
        return;
    }
    let (Some(log), Some(dbc)) = (
        shimmy::shared_data::require_file("logs/comma2k19-rav4/rav4_2017_seg40_bus0.log"),
        shimmy::shared_data::require_file("dbc/opendbc/toyota_new_mc_pt_generated.dbc"),
    ) else {
        return;
    };
    let (db, _) = Database::load(&dbc).unwrap();
    let src: Vec<String> = std::io::BufReader::new(std::fs::File::open(&log).unwrap())
        .lines()
        .map(|l| l.unwrap())
        .collect();
    let dir: PathBuf =
        std::env::temp_dir().join(format!("shimmy-bench-decode-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    let log1 = dir.join("rav4_x19.log");
    let n1 = make_log(&src, 19, &log1);
    assert!(n1 >= 1_000_000);

    // In-memory frames for the decode-only measurement.
    let frames: Vec<Frame> = {
        let mut r = LogReader::open(&log).unwrap();
        std::iter::from_fn(|| r.next_frame().unwrap()).collect()
    };

    let mut c = Criterion::default().configure_from_args().sample_size(10);
    {
        let mut g = c.benchmark_group("read_decode");
        g.throughput(Throughput::Elements(n1));
        g.bench_function("candump_1M_frames_rav4", |b| {
            b.iter(|| read_decode(&db, &log1))
        });
        g.finish();
        let mut g = c.benchmark_group("decode_only");
        g.throughput(Throughput::Elements(frames.len() as u64));
        g.bench_function("rav4_53800_frames_in_memory", |b| {
            b.iter(|| {
                let mut p = Pass::default();
                for f in &frames {
                    decode_frame(&db, f, &mut p);
                }
                p
            })
        });
        g.finish();
    }

    // Side by side, same file, one run. Best of 3 passes, wall and CPU time.
    let timed = |f: &mut dyn FnMut()| -> (f64, f64) {
        let (mut wall, mut cpu) = (f64::INFINITY, f64::INFINITY);
        for _ in 0..3 {
            let (t, c) = (Instant::now(), thread_cpu_ns());
            f();
            wall = wall.min(t.elapsed().as_secs_f64());
            if let (Some(c0), Some(c1)) = (c, thread_cpu_ns()) {
                cpu = cpu.min((c1 - c0) as f64 * 1e-9);
            }
        }
        (wall, cpu)
    };
    let mut pass = Pass::default();
    let (wall, cpu) = timed(&mut || pass = read_decode(&db, &log1));
    let (rwall, rcpu) = timed(&mut || {
        std::hint::black_box(read_only(&log1));
    });
    let mem: Vec<Frame> = {
        let mut r = LogReader::open(&log1).unwrap();
        std::iter::from_fn(|| r.next_frame().unwrap()).collect()
    };
    let (dwall, dcpu) = timed(&mut || {
        let mut p = Pass::default();
        for f in &mem {
            decode_frame(&db, f, &mut p);
        }
        std::hint::black_box(p);
    });
    drop(mem);
    let n = pass.frames as f64;
    println!(
        "\nours:     {} frames ({} decoded): read+decode {:.3} s wall / {:.3} s CPU = {:.2} / {:.2} M frames/s",
        pass.frames, pass.decoded, wall, cpu, n / wall / 1e6, n / cpu / 1e6
    );
    println!(
        "          of which read only {:.3} s wall / {:.3} s CPU ({:.2} M frames/s CPU); decode only {:.3} s / {:.3} s CPU ({:.2} M frames/s CPU)",
        rwall, rcpu, n / rcpu / 1e6, dwall, dcpu, n / dcpu / 1e6
    );
    if std::env::var_os("SHIMMY_BENCH_NO_CANTOOLS").is_none() {
        if let Some(v) = cantools(&dbc, &log1) {
            let (cw, cc) = (
                v["seconds"].as_f64().unwrap_or(f64::NAN),
                v["cpu_seconds"].as_f64().unwrap_or(f64::NAN),
            );
            println!(
                "cantools: {} frames ({} decoded): read+decode {:.3} s wall / {:.3} s CPU = {:.3} / {:.3} M frames/s (cantools {})",
                v["frames"], v["decoded"], cw, cc, n / cw / 1e6, n / cc / 1e6, v["cantools_version"]
            );
            assert_eq!(v["frames"].as_u64(), Some(pass.frames), "same frames read");
            assert_eq!(
                v["decoded"].as_u64(),
                Some(pass.decoded),
                "same frames decoded"
            );
            println!(
                "ratio:    {:.1}x cantools (wall), {:.1}x (CPU)",
                cw / wall,
                cc / cpu
            );
        }
    }
    let (f, kb) = peak_rss(&dbc, &log1);
    println!("peak RSS: {} frames -> {} KiB", f, kb);
    if std::env::var("SHIMMY_BENCH_4M").as_deref() != Ok("0") {
        let log4 = dir.join("rav4_x75.log");
        make_log(&src, 75, &log4);
        let (f, kb) = peak_rss(&dbc, &log4);
        println!("peak RSS: {} frames -> {} KiB", f, kb);
    }
    let _ = std::fs::remove_dir_all(&dir);
    c.final_summary();
}
