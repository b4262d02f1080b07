//! Tests of `shimmy::source::socketcan` against a real kernel CAN bus: `vcan0`, or the
//! interface named by `SHIMMY_VCAN_IF`.
//!
//! Without that interface every test prints a `SKIPPED` line and passes, unless
//! `SHIMMY_REQUIRE_VCAN=1` (set inside the QEMU VM of `tests/vcan/vm.sh` and by its host mode),
//! where a missing interface is a failure. The link down/up test also needs CAP_NET_ADMIN.
//!
//! Tests share the bus, so each uses its own IDs behind kernel filters; the tests that send
//! error frames or take the link down hold the bus exclusively.
//!
//! Lines starting with `VCAN-COUNTS` are machine-readable per-ID counts that
//! `tests/vcan_vm.rs` collects from the VM's console.
#![cfg(target_os = "linux")]

mod vcan_common;

use std::collections::BTreeMap;
use std::io;
use std::process::Command;
use std::sync::atomic::Ordering;
use std::sync::{Arc, Mutex, RwLock};
use std::thread;
use std::time::{Duration, Instant, SystemTime};

use shimmy::source::socketcan::{FilterId, LiveConfig, LiveSink, LiveSource};
use shimmy::source::CanSource;
use shimmy::wire::{Frame, FrameKind};

/// Readers take it shared; tests that disturb the whole bus (error frames, link down) take it
/// exclusively.
static BUS: RwLock<()> = RwLock::new(());

fn bus_shared() -> std::sync::RwLockReadGuard<'static, ()> {
    BUS.read().unwrap_or_else(|e| e.into_inner())
}

fn bus_exclusive() -> std::sync::RwLockWriteGuard<'static, ()> {
    BUS.write().unwrap_or_else(|e| e.into_inner())
}

/// The test interface, or `None` after printing why the test is skipped.
fn vcan(test: &str) -> Option<String> {
    vcan_common::iface(&format!("live_vcan::{test}"))
}

fn now_ns() -> i64 {
    SystemTime::now()
        .duration_since(SystemTime::UNIX_EPOCH)
        .unwrap()
        .as_nanos() as i64
}

/// Collect frames until `want` arrived or `limit` passed.
fn collect(src: &mut LiveSource, want: usize, limit: Duration) -> Vec<Frame> {
    let end = Instant::now() + limit;
    let mut got = Vec::new();
    while got.len() < want && Instant::now() < end {
        match src.next_frame() {
            Ok(Some(f)) => got.push(f),
            Ok(None) => break,
            Err(e) if e.kind() == io::ErrorKind::TimedOut => {}
            Err(e) => panic!("next_frame: {e}"),
        }
    }
    got
}

/// The fields a receiver must see exactly as sent.
fn key(f: &Frame) -> (u32, bool, FrameKind, bool, bool, bool, u8, Vec<u8>) {
    (
        f.id,
        f.extended,
        f.kind,
        f.fd,
        f.brs,
        f.esi,
        f.len,
        f.payload().to_vec(),
    )
}

fn print_counts(test: &str, sent: &BTreeMap<u32, u64>, received: &BTreeMap<u32, u64>) {
    for (id, s) in sent {
        let r = received.get(id).copied().unwrap_or(0);
        println!(
            "VCAN-COUNTS test={test} id={id:#05x} sent={s} received={r} lost={}",
            s.saturating_sub(r)
        );
    }
}

#[test]
fn frame_kinds_round_trip_through_kernel_filters() {
    let Some(iface) = vcan("frame_kinds_round_trip_through_kernel_filters") else {
        return;
    };
    let _bus = bus_shared();
    let ids = [
        FilterId::standard(0x120),
        FilterId::extended(0x120),
        FilterId::extended(0x18DA_F110),
        FilterId::standard(0x121),
        FilterId::standard(0x122),
    ];
    let mut src = LiveSource::open(vcan_common::reader_config(&iface, &ids)).unwrap();
    let mut classic_only = LiveSource::open(LiveConfig {
        fd: false,
        ..vcan_common::reader_config(&iface, &ids)
    })
    .unwrap();
    assert!(src.kernel_timestamps(), "kernel timestamps not enabled");

    let mut wanted = Vec::new();
    for len in 0..=8usize {
        let data: Vec<u8> = (0..len as u8).map(|b| b * 17 + len as u8).collect();
        wanted.push(Frame::classic(0, 0x120, false, &data).unwrap());
    }
    wanted.push(Frame::classic(0, 0x120, true, &[0xee; 8]).unwrap());
    wanted.push(Frame::classic(0, 0x18DA_F110, true, &[2, 0x10, 3]).unwrap());
    let mut fd64 = Frame::fd(0, 0x121, false, &(0..64).collect::<Vec<u8>>()).unwrap();
    fd64.brs = true;
    wanted.push(fd64);
    let mut fd12 = Frame::fd(0, 0x18DA_F110, true, &[0x5a; 12]).unwrap();
    fd12.esi = true;
    wanted.push(fd12);
    let mut remote = Frame::classic(0, 0x122, false, &[]).unwrap();
    remote.kind = FrameKind::Remote;
    remote.len = 4;
    remote.dlc = 4;
    wanted.push(remote);
    // Not in the filter list: the kernel must not deliver these.
    let unwanted = [
        Frame::classic(0, 0x123, false, &[1]).unwrap(),
        Frame::classic(0, 0x121, true, &[1]).unwrap(),
        Frame::fd(0, 0x18DA_F111, true, &[1; 8]).unwrap(),
    ];

    let mut sink = LiveSink::open(&iface).unwrap();
    let t_before = now_ns();
    for (i, f) in wanted.iter().enumerate() {
        sink.send(f).unwrap();
        sink.send(&unwanted[i % unwanted.len()]).unwrap();
    }
    let got = collect(&mut src, wanted.len(), Duration::from_secs(5));
    let t_after = now_ns();
    // Anything extra (a leak through the filter) would show up now.
    let extra = collect(&mut src, 1, Duration::from_millis(200));

    let sent_keys: Vec<_> = wanted.iter().map(key).collect();
    let got_keys: Vec<_> = got.iter().map(key).collect();
    assert_eq!(got_keys, sent_keys, "frames differ from what was sent");
    assert!(
        extra.is_empty(),
        "kernel filter let through {:?}",
        extra.iter().map(key).collect::<Vec<_>>()
    );
    let mut last = i64::MIN;
    for f in &got {
        assert_eq!(f.iface.as_str(), iface);
        assert!(
            f.t_ns >= t_before && f.t_ns <= t_after,
            "timestamp {} outside [{t_before}, {t_after}]",
            f.t_ns
        );
        assert!(f.t_ns >= last, "timestamps go backwards");
        last = f.t_ns;
    }
    let stats = src.stats();
    assert_eq!(stats.frames, wanted.len() as u64);
    assert_eq!((stats.dropped, stats.malformed), (0, 0));
    assert_eq!(src.live_stats().clock_timestamps, 0);

    let classic_keys: Vec<_> = wanted.iter().filter(|f| !f.fd).map(key).collect();
    let got_classic = collect(
        &mut classic_only,
        classic_keys.len(),
        Duration::from_secs(5),
    );
    assert_eq!(
        got_classic.iter().map(key).collect::<Vec<_>>(),
        classic_keys,
        "a socket without FD mode must see exactly the classic frames"
    );
    println!(
        "frame kinds: sent {} wanted + {} filtered out, received {}",
        wanted.len(),
        wanted.len(),
        got.len()
    );
}

/// The reference bus: steering angle at 100 Hz and four 50 Hz messages (brake, wheel speeds,
/// vehicle speed, acceleration), as `dbc/shimmy_reference.dbc` lays it out: 300 frames/s.
const REFERENCE_BUS: [(u32, u32); 5] = [
    (0x0A0, 100),
    (0x0B0, 50),
    (0x0C0, 50),
    (0x0D0, 50),
    (0x0E0, 50),
];

/// Payload: the ID and a per-ID sequence number, so loss and reordering are visible.
fn seq_frame(id: u32, seq: u32) -> Frame {
    let mut d = [0u8; 8];
    d[..4].copy_from_slice(&seq.to_le_bytes());
    d[4..6].copy_from_slice(&(id as u16).to_le_bytes());
    d[6] = 0xa5;
    Frame::classic(0, id, false, &d).unwrap()
}

fn seq_of(f: &Frame) -> u32 {
    u32::from_le_bytes(f.data[..4].try_into().unwrap())
}

/// Reads in a thread until `done` says so; returns frames in arrival order and the stats.
fn spawn_reader(
    mut src: LiveSource,
    done: impl Fn(&[Frame], u64) -> bool + Send + 'static,
    limit: Duration,
) -> thread::JoinHandle<(Vec<Frame>, LiveSource)> {
    thread::spawn(move || {
        let end = Instant::now() + limit;
        let mut got = Vec::new();
        while Instant::now() < end && !done(&got, src.stats().dropped) {
            match src.next_frame() {
                Ok(Some(f)) => got.push(f),
                Ok(None) => break,
                Err(e) if e.kind() == io::ErrorKind::TimedOut => {}
                Err(e) => panic!("next_frame: {e}"),
            }
        }
        (got, src)
    })
}

#[test]
fn reference_bus_load_arrives_complete_and_in_order() {
    let Some(iface) = vcan("reference_bus_load_arrives_complete_and_in_order") else {
        return;
    };
    let _bus = bus_shared();
    let seconds: u32 = std::env::var("SHIMMY_VCAN_LOAD_S")
        .ok()
        .and_then(|s| s.parse().ok())
        .unwrap_or(10);
    let ids: Vec<FilterId> = REFERENCE_BUS
        .iter()
        .map(|&(id, _)| FilterId::standard(id))
        .collect();
    let total: usize = REFERENCE_BUS
        .iter()
        .map(|&(_, hz)| (hz * seconds) as usize)
        .sum();
    let src = LiveSource::open(vcan_common::reader_config(&iface, &ids)).unwrap();
    let reader = spawn_reader(
        src,
        move |got, _| got.len() >= total,
        Duration::from_secs(seconds as u64 + 20),
    );

    // Real-time schedule on a 10 ms tick: the 100 Hz message every tick, the 50 Hz ones on
    // alternate ticks (staggered as ECUs would be). Like an ECU, the sender never bursts to
    // catch up after a stall (a busy host can stall the VM's vCPU): late ticks shift the
    // schedule, so the load never exceeds the reference rate.
    let mut sink = LiveSink::open(&iface).unwrap();
    let mut sent: BTreeMap<u32, u64> = BTreeMap::new();
    let tick_len = Duration::from_millis(10);
    let start = Instant::now();
    let mut due = start;
    let mut late_ticks = 0u32;
    for tick in 0..seconds * 100 {
        let now = Instant::now();
        match due.checked_duration_since(now) {
            Some(w) => thread::sleep(w),
            None if now - due > tick_len => {
                late_ticks += 1;
                due = now;
            }
            None => {}
        }
        due += tick_len;
        for (k, &(id, hz)) in REFERENCE_BUS.iter().enumerate() {
            let every = 100 / hz;
            if (tick + k as u32).is_multiple_of(every) {
                let n = sent.entry(id).or_default();
                sink.send(&seq_frame(id, *n as u32)).unwrap();
                *n += 1;
            }
        }
    }
    let send_s = start.elapsed().as_secs_f64();
    let (got, src) = reader.join().unwrap();

    let mut received: BTreeMap<u32, u64> = BTreeMap::new();
    let mut next_seq: BTreeMap<u32, u32> = BTreeMap::new();
    for f in &got {
        let expect = next_seq.entry(f.id).or_default();
        assert_eq!(seq_of(f), *expect, "ID {:#x}: out of order or lost", f.id);
        *expect += 1;
        *received.entry(f.id).or_default() += 1;
    }
    print_counts("reference_bus_load", &sent, &received);
    println!(
        "reference bus load: {} frames in {send_s:.2} s ({:.0} frames/s, {late_ticks} late ticks), \
         received {}, kernel drops {}",
        sent.values().sum::<u64>(),
        sent.values().sum::<u64>() as f64 / send_s,
        got.len(),
        src.stats().dropped
    );
    assert_eq!(received, sent, "frames lost at the reference bus load");
    assert_eq!(src.stats().dropped, 0);
}

#[test]
fn receive_queue_overflow_is_counted_never_silent() {
    let Some(iface) = vcan("receive_queue_overflow_is_counted_never_silent") else {
        return;
    };
    let _bus = bus_shared();
    const ID: u32 = 0x140;
    const MARK: u32 = 0x141;
    const N: u32 = 3000;
    // A tiny receive queue and a reader that starts late: the kernel must drop frames, and
    // every one of them must show up in the drop counter.
    let mut cfg =
        vcan_common::reader_config(&iface, &[FilterId::standard(ID), FilterId::standard(MARK)]);
    cfg.rcvbuf_bytes = Some(4096);
    let mut src = LiveSource::open(cfg).unwrap();
    let mut sink = LiveSink::open(&iface).unwrap();
    for seq in 0..N {
        sink.send(&seq_frame(ID, seq)).unwrap();
    }
    // The drop counter travels with the next queued frame: drain, then send a marker.
    let mut got = collect(&mut src, N as usize, Duration::from_millis(300));
    sink.send(&seq_frame(MARK, 0)).unwrap();
    got.extend(collect(&mut src, 1, Duration::from_secs(2)));
    assert_eq!(got.last().map(|f| f.id), Some(MARK), "marker not received");
    got.pop();

    let dropped = src.stats().dropped;
    let mut last = None;
    for f in &got {
        let s = seq_of(f);
        assert!(last.is_none_or(|l| s > l), "reordered: {s} after {last:?}");
        last = Some(s);
    }
    let received = got.len() as u64;
    println!(
        "VCAN-COUNTS test=overflow id={ID:#05x} sent={N} received={received} lost={}",
        N as u64 - received
    );
    println!("overflow: kernel-reported drops {dropped}");
    assert!(dropped > 0, "a 4 KiB queue read late should overflow");
    assert_eq!(
        received + dropped,
        N as u64,
        "received + counted drops must equal sent"
    );
}

#[test]
fn error_frames_are_counted_and_bus_off_reconnects() {
    let Some(iface) = vcan("error_frames_are_counted_and_bus_off_reconnects") else {
        return;
    };
    let _bus = bus_exclusive();
    const ID: u32 = 0x150;
    let mut cfg = vcan_common::reader_config(&iface, &[FilterId::standard(ID)]);
    cfg.error_mask = u32::MAX;
    cfg.backoff_initial = Duration::from_millis(20);
    let mut src = LiveSource::open(cfg).unwrap();
    let log = Arc::new(Mutex::new(Vec::<String>::new()));
    let log2 = log.clone();
    src.on_event(move |e| log2.lock().unwrap().push(e.to_string()));
    let mut no_errors = LiveSource::open(vcan_common::reader_config(
        &iface,
        &[FilterId::standard(ID)],
    ))
    .unwrap();

    let mut sink = LiveSink::open(&iface).unwrap();
    // Controller problem (CAN_ERR_CRTL) with "RX error warning" detail.
    let mut ctrl = Frame::classic(0, 0x004, false, &[0, 0x04, 0, 0, 0, 0, 0, 0]).unwrap();
    ctrl.kind = FrameKind::Error;
    sink.send(&ctrl).unwrap();
    let got = collect(&mut src, 1, Duration::from_secs(2));
    assert_eq!(got.len(), 1, "error frame not received");
    assert_eq!((got[0].kind, got[0].id), (FrameKind::Error, 0x004));
    assert_eq!(got[0].data[1], 0x04);
    assert_eq!(src.stats().error_frames, 1);

    // Bus-off: delivered, counted, then the source reconnects by itself.
    let mut busoff = ctrl;
    busoff.id = 0x040;
    busoff.data = [0; 64];
    sink.send(&busoff).unwrap();
    let got = collect(&mut src, 1, Duration::from_secs(2));
    assert_eq!(
        got.first().map(|f| (f.kind, f.id)),
        Some((FrameKind::Error, 0x040))
    );
    assert_eq!(src.live_stats().bus_off, 1);
    assert!(!src.is_connected(), "bus-off should close the socket");
    let end = Instant::now() + Duration::from_secs(5);
    while !src.is_connected() && Instant::now() < end {
        let _ = src.next_frame();
    }
    assert!(src.is_connected(), "no reconnect after bus-off");
    sink.send(&seq_frame(ID, 7)).unwrap();
    let got = collect(&mut src, 1, Duration::from_secs(2));
    assert_eq!(got.first().map(seq_of), Some(7), "no data after reconnect");
    let st = src.live_stats();
    assert_eq!((st.disconnects, st.reconnects), (1, 1));
    let log = log.lock().unwrap().join("\n");
    assert!(log.contains("disconnected (bus-off"), "{log}");
    assert!(log.contains("reconnected after 1 attempt"), "{log}");

    // Error mask 0: the same bus, no error frames.
    let got = collect(&mut no_errors, 3, Duration::from_millis(500));
    assert_eq!(
        got.iter().map(|f| f.kind).collect::<Vec<_>>(),
        [FrameKind::Data]
    );
    assert_eq!(no_errors.stats().error_frames, 0);
    println!("error frames: 2 sent, 2 received and counted; bus-off reconnect ok\n{log}");
}

fn ip_link(iface: &str, state: &str) -> io::Result<std::process::Output> {
    Command::new("ip")
        .args(["link", "set", "dev", iface, state])
        .output()
}

#[test]
fn interface_down_up_reconnects_with_backoff() {
    let Some(iface) = vcan("interface_down_up_reconnects_with_backoff") else {
        return;
    };
    let _bus = bus_exclusive();
    // Needs CAP_NET_ADMIN: find out by setting the link up (a no-op when it already is).
    match ip_link(&iface, "up") {
        Ok(o) if o.status.success() => {}
        other => {
            let why = match other {
                Ok(o) => String::from_utf8_lossy(&o.stderr).trim().to_string(),
                Err(e) => format!("cannot run ip: {e}"),
            };
            if vcan_common::required() {
                panic!("SHIMMY_REQUIRE_VCAN=1 but `ip link set` failed: {why}");
            }
            eprintln!(
                "SKIPPED live_vcan::interface_down_up_reconnects_with_backoff: needs \
                 CAP_NET_ADMIN to take {iface} down ({why})"
            );
            return;
        }
    }
    const ID: u32 = 0x160;
    let mut cfg = vcan_common::reader_config(&iface, &[FilterId::standard(ID)]);
    cfg.backoff_initial = Duration::from_millis(10);
    cfg.backoff_max = Duration::from_millis(80);
    let mut src = LiveSource::open(cfg).unwrap();
    let log = Arc::new(Mutex::new(Vec::<String>::new()));
    let log2 = log.clone();
    src.on_event(move |e| log2.lock().unwrap().push(e.to_string()));
    let stop = src.stop_handle();
    let got = Arc::new(Mutex::new(Vec::new()));
    let got2 = got.clone();
    let reader = thread::spawn(move || {
        loop {
            match src.next_frame() {
                Ok(Some(f)) => got2.lock().unwrap().push(seq_of(&f)),
                Ok(None) => break,
                Err(e) if e.kind() == io::ErrorKind::TimedOut => {}
                Err(e) => panic!("next_frame returned an error instead of reconnecting: {e}"),
            }
        }
        src
    });
    let wait_for = |what: &str| {
        let end = Instant::now() + Duration::from_secs(5);
        while Instant::now() < end {
            if log.lock().unwrap().iter().any(|l| l.contains(what)) {
                return true;
            }
            thread::sleep(Duration::from_millis(5));
        }
        false
    };

    let mut sink = LiveSink::open(&iface).unwrap();
    sink.send(&seq_frame(ID, 1)).unwrap();
    thread::sleep(Duration::from_millis(100));
    let down = ip_link(&iface, "down").unwrap();
    assert!(down.status.success(), "ip link set down failed");
    let saw_down = wait_for("disconnected");
    // Stay down long enough for several failed attempts with growing delays.
    thread::sleep(Duration::from_millis(300));
    let up = ip_link(&iface, "up").unwrap();
    assert!(up.status.success(), "ip link set up failed");
    assert!(
        saw_down,
        "no disconnect reported: {:?}",
        log.lock().unwrap()
    );
    assert!(
        wait_for("reconnected"),
        "no reconnect: {:?}",
        log.lock().unwrap()
    );
    drop(sink); // its socket was bound before the link went down
    let mut sink = LiveSink::open(&iface).unwrap();
    sink.send(&seq_frame(ID, 2)).unwrap();
    let end = Instant::now() + Duration::from_secs(5);
    while Instant::now() < end && got.lock().unwrap().len() < 2 {
        thread::sleep(Duration::from_millis(10));
    }
    stop.store(true, Ordering::Relaxed);
    let src = reader.join().unwrap();
    let got = got.lock().unwrap().clone();
    let log = log.lock().unwrap().join("\n");
    println!("link down/up:\n{log}");
    assert_eq!(got, [1, 2], "frames before and after the link bounce");
    let st = src.live_stats();
    assert_eq!((st.disconnects, st.reconnects), (1, 1));
    assert!(
        st.failed_attempts >= 2,
        "backoff retries while down: {st:?}"
    );
    assert!(log.contains("interface is down"), "{log}");
}

#[test]
fn read_timeout_and_stop_flag() {
    let Some(iface) = vcan("read_timeout_and_stop_flag") else {
        return;
    };
    let _bus = bus_shared();
    let mut cfg = vcan_common::reader_config(&iface, &[FilterId::standard(0x170)]);
    cfg.read_timeout = Duration::from_millis(100);
    let mut src = LiveSource::open(cfg).unwrap();
    let t = Instant::now();
    let e = src.next_frame().unwrap_err();
    let waited = t.elapsed();
    assert_eq!(e.kind(), io::ErrorKind::TimedOut);
    assert!(
        waited >= Duration::from_millis(90) && waited < Duration::from_secs(5),
        "timeout after {waited:?}"
    );
    src.stop_handle().store(true, Ordering::Relaxed);
    assert!(src.next_frame().unwrap().is_none());
    assert_eq!(src.live_stats().timeouts, 1);
}
