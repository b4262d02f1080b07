//! Log reading throughput: the RAV4 drive repeated to at least 1 M frames, written to a temp
//! file as candump -L, Vector ASC, BLF and ASAM MDF 4 (unsorted DT blocks as loggers write,
//! sorted transposed DZ as asammdf saves), then read back through `LogReader` (file in the page
//! cache; parse only, no decoding). Also the bare candump line parser on in-memory lines, and,
//! in the same run, asammdf reading the same MF4 files (benches/asammdf_read.py, when python3
//! has asammdf) for the ratio.
//!
//! Run: `cargo bench --bench read_logs` (needs the shared data; see docs/BENCHMARKS.md).

use criterion::{criterion_group, criterion_main, Criterion, Throughput};
use shimmy::source::log::LogReader;
use shimmy::source::recorder::CandumpWriter;
use shimmy::source::CanSource;
use shimmy::wire::candump::{parse_common_into, parse_line};
use shimmy::wire::mf4::{Mf4Compression, Mf4Layout, Mf4Writer, Mf4WriterOptions};
use shimmy::wire::Frame;
use std::hint::black_box;
use std::io::Write;
use std::path::Path;

const MIN_FRAMES: usize = 1_000_000;

fn rav4_frames() -> Option<Vec<Frame>> {
    let p = shimmy::shared_data::require_file("logs/comma2k19-rav4/rav4_2017_seg40_bus0.log")?;
    let mut r = LogReader::open(p).unwrap();
    let mut v = Vec::new();
    while let Some(f) = r.next_frame().unwrap() {
        v.push(f);
    }
    Some(v)
}

/// The drive repeated back to back (each copy 60 s later) to at least `MIN_FRAMES`.
fn repeated(base: &[Frame]) -> Vec<Frame> {
    let reps = MIN_FRAMES.div_ceil(base.len());
    let span = base.last().unwrap().t_ns - base[0].t_ns + 1_000_000;
    let mut v = Vec::with_capacity(reps * base.len());
    for r in 0..reps {
        v.extend(base.iter().map(|f| {
            let mut g = *f;
            g.t_ns += r as i64 * span;
            g
        }));
    }
    v
}

fn write_candump(frames: &[Frame], path: &Path) {
    let mut w = CandumpWriter::create(path).unwrap();
    for f in frames {
        w.write(f).unwrap();
    }
    w.flush().unwrap();
}

fn write_asc(frames: &[Frame], path: &Path) {
    let mut w = std::io::BufWriter::new(std::fs::File::create(path).unwrap());
    let t0 = frames[0].t_ns;
    writeln!(w, "date Thu Jan 01 00:00:00.000 1970").unwrap();
    writeln!(w, "base hex  timestamps absolute").unwrap();
    writeln!(w, "Begin Triggerblock Thu Jan 01 00:00:00.000 1970").unwrap();
    for f in frames {
        let dt = f.t_ns - t0;
        write!(
            w,
            " {}.{:06} 1  {:X}{}             Rx   d {}",
            dt / 1_000_000_000,
            dt % 1_000_000_000 / 1000,
            f.id,
            if f.extended { "x" } else { "" },
            f.len
        )
        .unwrap();
        for b in f.payload() {
            write!(w, " {b:02X}").unwrap();
        }
        writeln!(w).unwrap();
    }
    writeln!(w, "End TriggerBlock").unwrap();
}

fn write_blf(frames: &[Frame], path: &Path) {
    let mut out = std::io::BufWriter::new(std::fs::File::create(path).unwrap());
    let mut h = vec![0u8; 144];
    h[..4].copy_from_slice(b"LOGG");
    h[4..8].copy_from_slice(&144u32.to_le_bytes());
    out.write_all(&h).unwrap();
    let t0 = frames[0].t_ns;
    let mut chunk = Vec::with_capacity(128 * 1024 + 64);
    let flush = |chunk: &mut Vec<u8>, out: &mut std::io::BufWriter<std::fs::File>| {
        let mut e = flate2::write::ZlibEncoder::new(Vec::new(), flate2::Compression::default());
        e.write_all(chunk).unwrap();
        let z = e.finish().unwrap();
        let size = 32 + z.len();
        let mut c = b"LOBJ".to_vec();
        c.extend_from_slice(&16u16.to_le_bytes());
        c.extend_from_slice(&1u16.to_le_bytes());
        c.extend_from_slice(&(size as u32).to_le_bytes());
        c.extend_from_slice(&10u32.to_le_bytes());
        c.extend_from_slice(&2u16.to_le_bytes());
        c.extend_from_slice(&[0; 6]);
        c.extend_from_slice(&(chunk.len() as u32).to_le_bytes());
        c.extend_from_slice(&[0; 4]);
        c.extend_from_slice(&z);
        c.extend(std::iter::repeat_n(0u8, size % 4));
        out.write_all(&c).unwrap();
        chunk.clear();
    };
    for f in frames {
        // CAN_MESSAGE, header v1, ns timestamps: 48 bytes, no padding needed.
        chunk.extend_from_slice(b"LOBJ");
        chunk.extend_from_slice(&32u16.to_le_bytes());
        chunk.extend_from_slice(&1u16.to_le_bytes());
        chunk.extend_from_slice(&48u32.to_le_bytes());
        chunk.extend_from_slice(&1u32.to_le_bytes());
        chunk.extend_from_slice(&2u32.to_le_bytes());
        chunk.extend_from_slice(&[0; 4]);
        chunk.extend_from_slice(&((f.t_ns - t0) as u64).to_le_bytes());
        chunk.extend_from_slice(&1u16.to_le_bytes());
        chunk.push(0);
        chunk.push(f.len);
        let id = f.id | if f.extended { 0x8000_0000 } else { 0 };
        chunk.extend_from_slice(&id.to_le_bytes());
        let mut d = [0u8; 8];
        d[..f.len as usize].copy_from_slice(f.payload());
        chunk.extend_from_slice(&d);
        if chunk.len() >= 128 * 1024 {
            flush(&mut chunk, &mut out);
        }
    }
    if !chunk.is_empty() {
        flush(&mut chunk, &mut out);
    }
}

fn write_mf4(frames: &[Frame], path: &Path, layout: Mf4Layout, compression: Mf4Compression) {
    let f = std::io::BufWriter::new(std::fs::File::create(path).unwrap());
    let opts = Mf4WriterOptions {
        layout,
        compression,
        ..Default::default()
    };
    let mut w = Mf4Writer::new(f, opts).unwrap();
    for f in frames {
        w.write(f).unwrap();
    }
    w.finish().unwrap();
}

/// asammdf's (or, with `python_can`, python-can's MF4Reader's) frames per CPU second on
/// `path` (best of 3), if python3 has them.
fn asammdf_rate(path: &Path, python_can: bool) -> Option<f64> {
    let script = concat!(env!("CARGO_MANIFEST_DIR"), "/benches/asammdf_read.py");
    let mut cmd = std::process::Command::new("python3");
    cmd.arg(script);
    if python_can {
        cmd.arg("--python-can");
    }
    let out = cmd.arg(path).arg("3").output().ok()?;
    if !out.status.success() {
        eprintln!("asammdf_read.py: {}", String::from_utf8_lossy(&out.stderr));
        return None;
    }
    let s = String::from_utf8_lossy(&out.stdout);
    let mut it = s.split_whitespace();
    let n: f64 = it.next()?.parse().ok()?;
    let cpu: f64 = it.next()?.parse().ok()?;
    Some(n / cpu)
}

fn count_frames(path: &Path) -> u64 {
    let mut r = LogReader::open(path).unwrap();
    let mut n = 0u64;
    let mut x = 0u32;
    while let Some(f) = r.next_frame().unwrap() {
        n += 1;
        x ^= f.id ^ f.data[0] as u32;
    }
    black_box(x);
    assert_eq!(r.stats().malformed, 0);
    n
}

/// Like `count_frames`, through `read_frame` into one reused frame (no per-frame copy out).
fn count_frames_in_place(path: &Path) -> u64 {
    let mut r = LogReader::open(path).unwrap();
    let mut f = Frame::empty(0);
    let mut n = 0u64;
    let mut x = 0u32;
    while r.read_frame(&mut f).unwrap() {
        n += 1;
        x ^= f.id ^ f.data[0] as u32;
    }
    black_box(x);
    assert_eq!(r.stats().malformed, 0);
    n
}

/// CPU seconds used by this thread so far (utime + stime from /proc, 10 ms ticks), so the
/// rates below do not depend on how loaded the machine is; `None` off Linux.
fn thread_cpu_s() -> Option<f64> {
    let s = std::fs::read_to_string("/proc/thread-self/stat").ok()?;
    let rest = &s[s.rfind(')')? + 2..];
    let f: Vec<&str> = rest.split(' ').collect();
    Some((f.get(11)?.parse::<f64>().ok()? + f.get(12)?.parse::<f64>().ok()?) / 100.0)
}

/// Frames per CPU second for `reps` reads of `path` (printed next to criterion's wall-clock
/// figures).
fn cpu_rate(name: &str, reps: u32, mut once: impl FnMut() -> u64) {
    let Some(c0) = thread_cpu_s() else { return };
    let mut n = 0u64;
    for _ in 0..reps {
        n += once();
    }
    let Some(c1) = thread_cpu_s() else { return };
    println!(
        "cpu-time rate {name}: {:.2} M frames per CPU second ({n} frames, {:.2} CPU s)",
        n as f64 / (c1 - c0) / 1e6,
        c1 - c0
    );
}

fn bench(c: &mut Criterion) {
    let Some(base) = rav4_frames() else { return };
    let frames = repeated(&base);
    let n = frames.len();
    let dir = tempfile::tempdir().unwrap();
    let cd = dir.path().join("rav4_x19.log");
    let asc = dir.path().join("rav4_x19.asc");
    let blf = dir.path().join("rav4_x19.blf");
    write_candump(&frames, &cd);
    write_asc(&frames, &asc);
    write_blf(&frames, &blf);
    let mf4_dt = dir.path().join("rav4_x19_unsorted_dt.mf4");
    let mf4_dz = dir.path().join("rav4_x19_sorted_dz.mf4");
    write_mf4(&frames, &mf4_dt, Mf4Layout::Unsorted, Mf4Compression::None);
    write_mf4(
        &frames,
        &mf4_dz,
        Mf4Layout::Sorted,
        Mf4Compression::Transposed,
    );
    for p in [&cd, &asc, &blf, &mf4_dt, &mf4_dz] {
        assert_eq!(count_frames(p), n as u64, "{}", p.display());
    }
    for p in [&mf4_dt, &mf4_dz] {
        println!(
            "{}: {} bytes",
            p.file_name().unwrap().to_string_lossy(),
            std::fs::metadata(p).unwrap().len()
        );
    }
    if std::env::var_os("SHIMMY_BENCH_KEEP").is_some() {
        // Keep the MF4 files for a peak-memory run (docs/BENCHMARKS.md).
        for p in [&cd, &mf4_dt, &mf4_dz] {
            std::fs::copy(p, std::env::temp_dir().join(p.file_name().unwrap())).unwrap();
        }
    }

    // MF4: ours and asammdf's on the same files, in this run.
    for (name, p) in [
        ("MF4 unsorted DT", &mf4_dt),
        ("MF4 sorted DZ (transposed)", &mf4_dz),
    ] {
        let Some(c0) = thread_cpu_s() else { break };
        let mut m = 0u64;
        for _ in 0..5 {
            m += count_frames_in_place(p);
        }
        let ours = m as f64 / (thread_cpu_s().unwrap() - c0);
        println!(
            "cpu-time rate {name} file, read_frame in place: {:.2} M frames per CPU second",
            ours / 1e6
        );
        match asammdf_rate(p, false) {
            Some(r) => println!(
                "cpu-time rate {name} file, asammdf: {:.3} M frames per CPU second; ours / asammdf = {:.0}x",
                r / 1e6,
                ours / r
            ),
            None => println!("asammdf not available: no ratio for {name}"),
        }
    }

    cpu_rate("candump file", 5, || count_frames(&cd));
    cpu_rate("candump file, read_frame in place", 5, || {
        count_frames_in_place(&cd)
    });
    cpu_rate("ASC file", 5, || count_frames(&asc));
    cpu_rate("BLF file", 5, || count_frames(&blf));

    // python-can's MF4Reader reads only what its MF4Writer wrote: the RAV4 drive (53,800
    // frames) written by python-can, read by it and by us.
    let pc = dir.path().join("rav4_python_can.mf4");
    let jobs = dir.path().join("jobs.txt");
    let rav4 = shimmy::shared_data::require_file(shimmy::shared_data::RAV4_LOG).unwrap();
    std::fs::write(
        &jobs,
        format!("pycan {} {} 0\n", rav4.display(), pc.display()),
    )
    .unwrap();
    let made = std::process::Command::new("python3")
        .arg(concat!(
            env!("CARGO_MANIFEST_DIR"),
            "/tests/mf4_fixtures/asammdf_ref.py"
        ))
        .arg(&jobs)
        .status()
        .is_ok_and(|s| s.success());
    if let (true, Some(c0)) = (made, thread_cpu_s()) {
        let mut m = 0u64;
        for _ in 0..40 {
            m += count_frames_in_place(&pc);
        }
        let ours = m as f64 / (thread_cpu_s().unwrap() - c0);
        println!("cpu-time rate python-can-written MF4 (53,800 frames), ours: {:.2} M frames per CPU second", ours / 1e6);
        if let Some(r) = asammdf_rate(&pc, true) {
            println!(
                "cpu-time rate python-can-written MF4, python-can MF4Reader: {:.3} M frames per CPU second; ours / python-can = {:.0}x",
                r / 1e6,
                ours / r
            );
        }
        if let Some(r) = asammdf_rate(&pc, false) {
            println!(
                "cpu-time rate python-can-written MF4, asammdf: {:.3} M frames per CPU second; ours / asammdf = {:.0}x",
                r / 1e6,
                ours / r
            );
        }
    }

    let mut g = c.benchmark_group("read_logs");
    g.sample_size(10);
    g.throughput(Throughput::Elements(n as u64));
    g.bench_function(format!("candump_file_{n}_frames"), |b| {
        b.iter(|| count_frames(&cd))
    });
    g.bench_function(format!("asc_file_{n}_frames"), |b| {
        b.iter(|| count_frames(&asc))
    });
    g.bench_function(format!("blf_file_{n}_frames"), |b| {
        b.iter(|| count_frames(&blf))
    });
    g.bench_function(format!("mf4_unsorted_dt_file_{n}_frames"), |b| {
        b.iter(|| count_frames(&mf4_dt))
    });
    g.bench_function(format!("mf4_sorted_dz_file_{n}_frames"), |b| {
        b.iter(|| count_frames(&mf4_dz))
    });
    g.finish();

    // The bare line parser over the candump text already in memory.
    let text = std::fs::read(&cd).unwrap();
    let lines: Vec<&[u8]> = text
        .split(|&b| b == b'\n')
        .filter(|l| !l.is_empty())
        .collect();
    cpu_rate("candump parse_line in memory", 5, || {
        lines
            .iter()
            .filter(|l| parse_line(black_box(l)).is_ok())
            .count() as u64
    });
    cpu_rate("candump parse_common_into in memory", 5, || {
        let mut f = Frame::empty(0);
        lines
            .iter()
            .filter(|l| parse_common_into(black_box(l), &mut f))
            .count() as u64
    });
    let mut g = c.benchmark_group("candump_parse_line");
    g.sample_size(10);
    g.throughput(Throughput::Elements(lines.len() as u64));
    g.bench_function(format!("{}_lines_in_memory", lines.len()), |b| {
        b.iter(|| {
            let mut ok = 0u32;
            for l in &lines {
                ok += parse_line(black_box(l)).is_ok() as u32;
            }
            ok
        })
    });
    g.finish();
}

criterion_group!(benches, bench);
criterion_main!(benches);
