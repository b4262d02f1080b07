//! The daemon's live path under a full bus: the `shimmyd` executable reads `vcan0` (or
//! `SHIMMY_VCAN_IF`) while this test puts 8,000 frames/s on it (`SHIMMY_LIVE_LOAD_FPS`) for
//! 10 s (`SHIMMY_LIVE_LOAD_S`), then stops it with SIGTERM. Two shapes of the same content,
//! firmware-sim's reference bus of `config/scenarios/vcan_0p4mm.toml` (steering angle at 100 Hz,
//! brake, wheel speeds, vehicle speed and acceleration at 50 Hz, with their checksums and
//! counters), looped as long as needed:
//!
//! * **bus**: those messages at their own rates (300 frames/s) plus background traffic up to the
//!   total rate: IDs from 0x400 up, each at 100 Hz, 8 bytes with a per-ID counter, which the
//!   daemon's mapping does not read, so its kernel filter discards them (a car's bus as the
//!   daemon meets it);
//! * **compressed**: only those of the messages the daemon's mapping reads (steering angle,
//!   brake, vehicle speed), time-compressed to the total rate, so every frame passes the kernel
//!   filter and goes through the reader thread and the whole pipeline (the
//!   worst case, as the replay benchmark of docs/BENCHMARKS.md measures it).
//!
//! Checked (behaviour, not timing): for every message the daemon reads, frames sent = frames
//! the daemon decoded, its total frame count is the sum of those, and it counted no kernel drop
//! (`SO_RXQ_OVFL`; the interface's own `rx_dropped` is printed too). Printed for
//! `tests/vcan_vm.rs` and `tests/vcan/live_cost.sh`: `VCAN-COUNTS test=shimmyd_load_<shape> ...`
//! per message, and one `LIVE-COST ...` line with the daemon's CPU share (utime + stime from
//! `/proc/<pid>/stat`, from the first frame sent until the daemon was idle again, over the
//! sending time), its RSS (`VmRSS` at the end of sending, `VmHWM`), its threads' wake-ups
//! (voluntary context switches per second) and the rate actually sent. Those numbers go to
//! docs/BENCHMARKS.md; none is asserted here.
//!
//! `replay_cpu_calibration` (ignored; run by `tests/vcan/live_cost.sh` in the VM and on the
//! host) replays the compressed load from a log with `shimmyd --replay --fast` and prints the
//! CPU time it took: the ratio of the two runs scales the VM's emulated-CPU numbers to the host.
//!
//! Without the interface the load tests print SKIPPED and pass, unless
//! `SHIMMY_REQUIRE_VCAN=1` (the QEMU VM of `tests/vcan/vm.sh`).
#![cfg(target_os = "linux")]

mod e2e_common;
mod vcan_common;

use std::collections::BTreeMap;
use std::path::Path;
use std::thread;
use std::time::{Duration, Instant};

use e2e_common::{generate, replay_command, workspace, write_config, Journal, LiveDaemon};
use shimmy::source::log::LogReader;
use shimmy::source::socketcan::LiveSink;
use shimmy::source::CanSource;
use shimmy::wire::Frame;

const SCENARIO: &str = "vcan_0p4mm";
/// Background IDs: from here up, none of them in dbc/shimmy_reference.dbc.
const BACKGROUND_FIRST_ID: u32 = 0x400;
const BACKGROUND_HZ: f64 = 100.0;
/// The sender's tick: every frame due is sent at each tick.
const TICK: Duration = Duration::from_millis(1);

fn env_f64(name: &str, default: f64) -> f64 {
    match std::env::var(name) {
        Ok(v) => v
            .parse()
            .unwrap_or_else(|_| panic!("{name}={v:?} is not a number")),
        Err(_) => default,
    }
}

#[derive(Clone, Copy, Debug, PartialEq)]
enum Shape {
    Bus,
    Compressed,
}

impl Shape {
    fn name(self) -> &'static str {
        match self {
            Shape::Bus => "bus",
            Shape::Compressed => "compressed",
        }
    }
}

/// firmware-sim's reference bus for the scenario, timestamps from 0.
fn reference_frames(dir: &Path) -> Vec<Frame> {
    let log = generate(SCENARIO, None, dir).log;
    let mut r = LogReader::open(&log).unwrap();
    let mut frames = Vec::new();
    while let Some(f) = r.next_frame().unwrap() {
        frames.push(f);
    }
    assert!(
        frames.len() > 100,
        "firmware-sim wrote {} frames",
        frames.len()
    );
    let t0 = frames[0].t_ns;
    for f in &mut frames {
        f.t_ns -= t0;
    }
    frames
}

/// The IDs the daemon's kernel filter lets through: those its mapping reads.
fn daemon_ids() -> Vec<u32> {
    let ws = workspace();
    let (db, _) = shimmy::dbc::Database::load(ws.join("dbc/shimmy_reference.dbc")).unwrap();
    let mapping = shimmy::signals::mapping::MappingConfig::from_toml_file(
        ws.join("config/vehicles/shimmy_reference/mapping.toml"),
    )
    .unwrap();
    let mapper = shimmy::signals::Mapper::new(&db, &mapping).unwrap();
    mapper.needed_ids().iter().map(|&(id, _)| id).collect()
}

/// The frames to send over `seconds` at `fps` in total, sorted by time (ns from 0).
fn schedule(reference: &[Frame], shape: Shape, seconds: f64, fps: f64) -> Vec<Frame> {
    let read = daemon_ids();
    let kept: Vec<Frame>;
    let reference = match shape {
        Shape::Bus => reference,
        Shape::Compressed => {
            kept = reference
                .iter()
                .filter(|f| read.contains(&f.id))
                .copied()
                .collect();
            &kept[..]
        }
    };
    let n = reference.len() as f64;
    let span_ns = reference.last().unwrap().t_ns as f64;
    // One loop of the log lasts its span plus one mean frame interval.
    let loop_ns = span_ns * n / (n - 1.0);
    let ref_rate = n / (loop_ns * 1e-9);
    let end_ns = seconds * 1e9;
    let looped = |speedup: f64, out: &mut Vec<Frame>| {
        for i in 0.. {
            for f in reference {
                let t = (f.t_ns as f64 + i as f64 * loop_ns) / speedup;
                if t >= end_ns {
                    return;
                }
                let mut g = *f;
                g.t_ns = t as i64;
                out.push(g);
            }
        }
    };
    let mut out = Vec::with_capacity((seconds * fps * 1.01) as usize);
    match shape {
        Shape::Compressed => looped(fps / ref_rate, &mut out),
        Shape::Bus => {
            looped(1.0, &mut out);
            let ids = ((fps - ref_rate) / BACKGROUND_HZ).round().max(0.0) as u32;
            assert!(
                BACKGROUND_FIRST_ID + ids <= 0x7ff,
                "{fps} frames/s needs {ids} background IDs"
            );
            let period_ns = 1e9 / BACKGROUND_HZ;
            for k in 0..ids {
                let id = BACKGROUND_FIRST_ID + k;
                // Staggered over the period, as independent ECUs would be.
                let phase = period_ns * k as f64 / ids as f64;
                let mut seq = 0u32;
                let mut t = phase;
                while t < end_ns {
                    let mut d = [0u8; 8];
                    d[..4].copy_from_slice(&seq.to_le_bytes());
                    d[4..6].copy_from_slice(&(id as u16).to_le_bytes());
                    d[7] = 0x5a;
                    out.push(Frame::classic(t as i64, id, false, &d).unwrap());
                    seq += 1;
                    t += period_ns;
                }
            }
            out.sort_by_key(|f| f.t_ns);
        }
    }
    out
}

/// What `/proc` says about a process and its threads.
#[derive(Clone, Copy, Debug, Default)]
struct ProcSample {
    /// utime + stime, clock ticks.
    cpu_ticks: u64,
    /// Voluntary context switches of all its threads (each is a wake-up after a block).
    wakeups: u64,
    rss_kb: u64,
    hwm_kb: u64,
    threads: u64,
}

fn status_field(text: &str, key: &str) -> u64 {
    text.lines()
        .find_map(|l| l.strip_prefix(key))
        .and_then(|v| v.split_whitespace().next())
        .and_then(|v| v.parse().ok())
        .unwrap_or(0)
}

fn proc_sample(pid: u32) -> ProcSample {
    let stat = std::fs::read_to_string(format!("/proc/{pid}/stat")).expect("read /proc/PID/stat");
    // Fields after the command name (which may hold spaces): state is field 3, utime 14, stime 15.
    let rest = &stat[stat.rfind(')').expect("stat has a comm") + 2..];
    let f: Vec<&str> = rest.split_whitespace().collect();
    let cpu_ticks = f[11].parse::<u64>().unwrap() + f[12].parse::<u64>().unwrap();
    let status = std::fs::read_to_string(format!("/proc/{pid}/status")).unwrap();
    let mut wakeups = 0;
    let mut threads = 0;
    if let Ok(tasks) = std::fs::read_dir(format!("/proc/{pid}/task")) {
        for t in tasks.flatten() {
            if let Ok(s) = std::fs::read_to_string(t.path().join("status")) {
                wakeups += status_field(&s, "voluntary_ctxt_switches:");
                threads += 1;
            }
        }
    }
    ProcSample {
        cpu_ticks,
        wakeups,
        rss_kb: status_field(&status, "VmRSS:"),
        hwm_kb: status_field(&status, "VmHWM:"),
        threads,
    }
}

fn clock_ticks_per_s() -> f64 {
    // SAFETY: sysconf has no preconditions.
    (unsafe { libc::sysconf(libc::_SC_CLK_TCK) }) as f64
}

fn iface_counter(iface: &str, name: &str) -> u64 {
    std::fs::read_to_string(format!("/sys/class/net/{iface}/statistics/{name}"))
        .ok()
        .and_then(|s| s.trim().parse().ok())
        .unwrap_or(0)
}

fn run_load(shape: Shape) {
    let test = format!("shimmyd_load_{}", shape.name());
    let Some(ifname) = vcan_common::iface(&test) else {
        return;
    };
    let seconds = env_f64("SHIMMY_LIVE_LOAD_S", 10.0);
    let fps = env_f64("SHIMMY_LIVE_LOAD_FPS", 8000.0);
    let dir = tempfile::tempdir().unwrap();
    let frames = schedule(&reference_frames(dir.path()), shape, seconds, fps);

    let cfg = write_config(dir.path(), &format!("interfaces = [{ifname:?}]"));
    let daemon = LiveDaemon::start(&cfg, dir.path());
    let pid = daemon.pid();
    let idle = proc_sample(pid);

    // The frames on a 1 ms tick. Like ECUs, the sender never bursts to catch up after a stall
    // (the VM's one emulated CPU is shared with the daemon and the host's other work): a late
    // tick shifts the rest of the schedule, so the rate never exceeds the one asked for, and
    // the rate actually sent is reported.
    let rx_dropped_before = iface_counter(&ifname, "rx_dropped");
    let mut sink = LiveSink::open(&ifname).expect("open the CAN interface for sending");
    let mut sent: BTreeMap<u32, u64> = BTreeMap::new();
    let before = proc_sample(pid);
    let start = Instant::now();
    let mut shift = Duration::ZERO;
    let mut late_ticks = 0u64;
    let mut next = 0;
    let mut tick = Duration::ZERO;
    while next < frames.len() {
        tick += TICK;
        let due = start + shift + tick;
        let now = Instant::now();
        if due > now {
            thread::sleep(due - now);
        } else if now - due > TICK {
            late_ticks += 1;
            shift += now - due;
        }
        let tick_ns = tick.as_nanos() as i64;
        while next < frames.len() && frames[next].t_ns < tick_ns {
            let f = &frames[next];
            sink.send(f).expect("send on the CAN interface");
            *sent.entry(f.id).or_default() += 1;
            next += 1;
        }
    }
    let send_s = start.elapsed().as_secs_f64();
    let loaded = proc_sample(pid);

    // Wait until the daemon's per-second counters have twice said it read nothing, then stop
    // it as systemd would (SIGTERM: frames already read are processed, none lost).
    let t = Instant::now();
    daemon.wait_idle(Duration::from_secs(120));
    let caught_up = proc_sample(pid);
    let rx_dropped = iface_counter(&ifname, "rx_dropped") - rx_dropped_before;
    let (status, log) = daemon.stop(Duration::from_secs(60));
    assert!(status.success(), "shimmyd exited with {status}: {log}");

    let journal = Journal::read(&dir.path().join("journal"));
    let stop = &journal.stop;
    let messages = stop["messages"].as_array().expect("stop record: messages");
    let total_sent: u64 = sent.values().sum();
    let mut read_sent = 0;
    let mut lost = Vec::new();
    for m in messages {
        let id = m["id"].as_u64().unwrap() as u32;
        let s = sent.get(&id).copied().unwrap_or(0);
        let received = m["frames"].as_u64().unwrap();
        read_sent += s;
        println!(
            "VCAN-COUNTS test={test} id={id:#05x} name={} sent={s} received={received} lost={}",
            m["name"].as_str().unwrap_or("?"),
            s.saturating_sub(received)
        );
        if received != s {
            lost.push(format!("{}: sent {s}, decoded {received}", m["name"]));
        }
    }
    let counters = &stop["counters"];
    let hz = clock_ticks_per_s();
    let cpu_s = (caught_up.cpu_ticks - before.cpu_ticks) as f64 / hz;
    let cpu_send_s = (loaded.cpu_ticks - before.cpu_ticks) as f64 / hz;
    println!(
        "LIVE-COST test={test} fps_asked={fps:.0} seconds_asked={seconds} sent={total_sent} \
         send_s={send_s:.2} fps_sent={:.0} late_ticks={late_ticks} read_by_daemon={read_sent} \
         cpu_s={cpu_s:.2} cpu_pct={:.2} cpu_during_send_pct={:.2} catch_up_s={:.1} \
         wakeups_per_s={:.0} rss_kb={} hwm_kb={} idle_rss_kb={} threads={} kernel_drops={} \
         iface_rx_dropped={rx_dropped}",
        total_sent as f64 / send_s,
        100.0 * cpu_s / send_s,
        100.0 * cpu_send_s / send_s,
        t.elapsed().as_secs_f64(),
        (loaded.wakeups - before.wakeups) as f64 / send_s,
        loaded.rss_kb,
        caught_up.hwm_kb,
        idle.rss_kb,
        loaded.threads,
        counters["dropped"],
    );
    assert!(
        read_sent > 0,
        "the daemon reads none of the messages sent: {stop}"
    );
    assert!(lost.is_empty(), "frames lost: {lost:?}\ndaemon log: {log}");
    assert_eq!(counters["frames"], read_sent, "{counters}\n{log}");
    assert_eq!(counters["dropped"], 0, "kernel drops: {counters}\n{log}");
    assert_eq!(counters["decode_errors"], 0, "{counters}");
    if shape == Shape::Bus {
        assert!(
            read_sent < total_sent,
            "the background frames must be on the bus too"
        );
    } else {
        assert_eq!(read_sent, total_sent, "every frame is one the daemon reads");
    }
}

#[test]
fn shimmyd_reads_a_full_bus_without_loss() {
    run_load(Shape::Bus);
}

#[test]
fn shimmyd_reads_8000_frames_per_s_of_its_messages_without_loss() {
    run_load(Shape::Compressed);
}

/// CPU time (user + system, s) of the children reaped so far.
fn children_cpu_s() -> f64 {
    // SAFETY: getrusage writes into the struct it is given.
    let mut ru: libc::rusage = unsafe { std::mem::zeroed() };
    assert_eq!(
        unsafe { libc::getrusage(libc::RUSAGE_CHILDREN, &mut ru) },
        0
    );
    let s = |t: libc::timeval| t.tv_sec as f64 + t.tv_usec as f64 * 1e-6;
    s(ru.ru_utime) + s(ru.ru_stime)
}

#[test]
#[ignore = "a CPU-speed reference for tests/vcan/live_cost.sh, not a check"]
fn replay_cpu_calibration() {
    let dir = tempfile::tempdir().unwrap();
    let seconds = env_f64("SHIMMY_LIVE_LOAD_S", 10.0);
    let fps = env_f64("SHIMMY_LIVE_LOAD_FPS", 8000.0);
    let frames = schedule(
        &reference_frames(dir.path()),
        Shape::Compressed,
        seconds,
        fps,
    );
    let log = dir.path().join("load.log");
    let mut w = shimmy::source::writer::LogWriter::create(&log, Default::default()).unwrap();
    for f in &frames {
        let mut f = *f;
        f.t_ns += 1_700_000_000_000_000_000;
        f.iface = shimmy::wire::IfaceName::from_str_truncated("vcan0");
        w.write(&f).unwrap();
    }
    w.finish().unwrap();
    let cfg = write_config(dir.path(), "");
    let mut runs = Vec::new();
    for i in 0..3 {
        let state = dir.path().join(format!("state{i}"));
        let before = children_cpu_s();
        let t = Instant::now();
        let out = replay_command(&cfg, &log, Some(&state))
            .current_dir(dir.path())
            .output()
            .expect("start shimmyd");
        assert!(
            out.status.success(),
            "shimmyd --replay: {}",
            String::from_utf8_lossy(&out.stderr)
        );
        runs.push((children_cpu_s() - before, t.elapsed().as_secs_f64()));
    }
    let best = runs.iter().map(|r| r.0).fold(f64::INFINITY, f64::min);
    println!(
        "LIVE-CALIBRATION frames={} replay_cpu_s_best={best:.3} runs={:?}",
        frames.len(),
        runs.iter()
            .map(|(c, w)| format!("{c:.3}s cpu/{w:.3}s wall"))
            .collect::<Vec<_>>()
    );
}
