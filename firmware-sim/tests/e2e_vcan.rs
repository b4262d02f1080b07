//! End to end on a real kernel CAN bus: the `firmware-sim` binary sends a scenario on `vcan0`
//! (or `SHIMMY_VCAN_IF`) at N× real time while this test reads the bus live through
//! `shimmy::source::socketcan::LiveSource` and decodes it the way the monitor does
//! (`shimmy::signals::Mapper` with `config/vehicles/shimmy_reference/mapping.toml`). Checked:
//!
//! * per message, frames sent (the binary's ground truth) = received, printed as
//!   `VCAN-COUNTS test=firmware_sim ...` lines (collected by `tests/vcan_vm.rs`);
//! * every received frame equals, byte for byte and in order per message, what the binary
//!   recorded as sent (`--out`), and that recording equals the library's in-process run of the
//!   same scenario and seed where the host is fast enough to do both (not in the slow VM);
//! * the monitor's decoder accepts every frame (checksums, counters, nothing lost), and the
//!   braking events it sees (brake switch edges, speed at onset) are those of the ground truth.
//!
//! Without the interface this prints SKIPPED and passes, unless `SHIMMY_REQUIRE_VCAN=1` (set in
//! the QEMU VM of `tests/vcan/vm.sh` and by its host mode). Speed: `SHIMMY_FWSIM_SPEED`
//! (default 5× real time).
#![cfg(target_os = "linux")]

#[path = "../../tests/vcan_common/mod.rs"]
mod vcan_common;

use std::collections::BTreeMap;
use std::path::PathBuf;
use std::process::Command;
use std::time::{Duration, Instant};

use firmware_sim::bus::{reference_bus, REFERENCE_DBC};
use firmware_sim::plant::ModelPlant;
use firmware_sim::{FirmwareSim, RunInfo, Scenario};
use shimmy::dbc::Database;
use shimmy::signals::mapping::MappingConfig;
use shimmy::signals::Mapper;
use shimmy::source::log::LogReader;
use shimmy::source::socketcan::{FilterId, LiveSource};
use shimmy::source::CanSource;
use shimmy::wire::Frame;

const MAPPING: &str = include_str!("../../config/vehicles/shimmy_reference/mapping.toml");

/// About 5 s of driving: a stop from 40 km/h at 0.5 g, pull away, a slowdown from 15 km/h. The
/// step is 2e-4 s (the model allows up to 5e-4) because the single TCG vCPU of the VM runs the
/// model at a fraction of real time; this test is about the bus, not the physics.
const SCENARIO: &str = r#"
name = "e2e_vcan"
seed = 4242
step_s = 2e-4
[clearance]
left_mm = 0.2
[drive]
start_speed_kmh = 40
accel_g = 0.3
[[drive.segment]]
kind = "cruise"
speed_kmh = 40
duration_s = 0.3
[[drive.segment]]
kind = "brake"
decel_g = 0.5
hold_s = 0.2
ramp_out_s = 0.1
[[drive.segment]]
kind = "stand"
duration_s = 0.2
[[drive.segment]]
kind = "cruise"
speed_kmh = 15
duration_s = 0.2
[[drive.segment]]
kind = "brake"
decel_g = 0.4
duration_s = 0.7
"#;

/// The binary: cargo's path when it exists (host), else `firmware-sim` on PATH (the VM).
fn binary() -> PathBuf {
    vcan_common::executable(env!("CARGO_BIN_EXE_firmware-sim"), "firmware-sim")
}

#[test]
// The child is reaped by `try_wait` in the loop (or killed and waited on at the time limit).
#[allow(clippy::zombie_processes)]
fn firmware_sim_on_vcan_is_read_and_decoded_live() {
    let Some(ifname) = vcan_common::iface("e2e_vcan") else {
        return;
    };
    let speed: f64 = std::env::var("SHIMMY_FWSIM_SPEED")
        .ok()
        .and_then(|s| s.parse().ok())
        .unwrap_or(5.0);
    let dir = std::env::temp_dir().join(format!("fwsim_e2e_{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    let sc_path = dir.join("e2e_vcan.toml");
    let truth_path = dir.join("e2e_vcan.truth.json");
    let sent_path = dir.join("e2e_vcan_sent.log");
    std::fs::write(&sc_path, SCENARIO).unwrap();

    let db = Database::parse(REFERENCE_DBC).0;
    let bus = reference_bus().unwrap();
    let ids: Vec<(u32, &str)> = bus
        .messages
        .iter()
        .map(|m| {
            let i = db.message_by_name(&m.name).unwrap();
            (db.messages()[i].id, m.name.as_str())
        })
        .collect();
    let filter: Vec<FilterId> = ids.iter().map(|&(id, _)| FilterId::standard(id)).collect();
    let mut src = LiveSource::open(vcan_common::reader_config(&ifname, &filter))
        .expect("open the CAN interface for reading");

    let started = Instant::now();
    let mut child = Command::new(binary())
        .arg("--scenario")
        .arg(&sc_path)
        .arg("--iface")
        .arg(&ifname)
        .arg("--speed")
        .arg(speed.to_string())
        .arg("--truth")
        .arg(&truth_path)
        .arg("--out")
        .arg(&sent_path)
        .spawn()
        .expect("start firmware-sim");
    let mut got: Vec<Frame> = Vec::new();
    let mut exited = None;
    let mut idle_since = Instant::now();
    loop {
        match src.next_frame() {
            Ok(Some(f)) => {
                got.push(f);
                idle_since = Instant::now();
            }
            Ok(None) => {}
            // The read timeout: nothing on the bus for 50 ms.
            Err(e) if e.kind() == std::io::ErrorKind::TimedOut => {}
            Err(e) => panic!("reading {ifname}: {e}"),
        }
        if exited.is_none() {
            exited = child.try_wait().expect("wait for firmware-sim");
        }
        // After the sender exits, drain until the bus has been quiet for half a second.
        if exited.is_some() && idle_since.elapsed() > Duration::from_millis(500) {
            break;
        }
        if started.elapsed() > Duration::from_secs(240) {
            let _ = child.kill();
            let _ = child.wait();
            panic!("firmware-sim did not finish within 240 s");
        }
    }
    let status = exited.unwrap();
    assert!(status.success(), "firmware-sim failed: {status}");
    let wall = started.elapsed().as_secs_f64();

    let truth: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(&truth_path).unwrap()).unwrap();
    let sent: BTreeMap<u32, u64> = truth["messages"]
        .as_array()
        .unwrap()
        .iter()
        .map(|m| {
            (
                m["id"].as_u64().unwrap() as u32,
                m["sent"].as_u64().unwrap(),
            )
        })
        .collect();
    let mut lost_total = 0;
    for &(id, name) in &ids {
        let received = got.iter().filter(|f| f.id == id).count() as u64;
        let s = sent[&id];
        let lost = s.saturating_sub(received);
        lost_total += lost;
        eprintln!(
            "VCAN-COUNTS test=firmware_sim id={id:#05x} name={name} sent={s} received={received} lost={lost}"
        );
    }
    eprintln!(
        "e2e_vcan: {} frames, {:.1} s simulated, {wall:.1} s wall at --speed {speed}",
        got.len(),
        truth["duration_s"].as_f64().unwrap()
    );
    assert_eq!(lost_total, 0, "frames lost on {ifname}");
    assert_eq!(got.len() as u64, truth["frames_sent"].as_u64().unwrap());

    // What arrived is what was sent, message by message (arrival order across messages may
    // differ by a frame when two are due at nearly the same instant).
    let mut sent_log = LogReader::open(&sent_path).unwrap();
    let mut recorded = Vec::new();
    while let Some(f) = sent_log.next_frame().unwrap() {
        recorded.push(f);
    }
    assert_eq!(recorded.len(), got.len());
    let same = |a: &[Frame], b: &[Frame], id: u32| {
        let pa = a.iter().filter(|f| f.id == id).map(|f| f.payload());
        let pb = b.iter().filter(|f| f.id == id).map(|f| f.payload());
        pa.eq(pb)
    };
    for &(id, name) in &ids {
        assert!(
            same(&got, &recorded, id),
            "{name}: received payloads differ from those sent"
        );
    }
    // And what was sent is the library's deterministic run of the scenario (skipped in the VM,
    // where simulating twice would double the slowest part of the suite).
    if !vcan_common::required() {
        let sc = Scenario::parse(SCENARIO, "e2e").unwrap();
        let expected: Vec<Frame> = FirmwareSim::new(
            &sc,
            ModelPlant::new(&sc, None).unwrap(),
            REFERENCE_DBC,
            RunInfo::default(),
        )
        .unwrap()
        .collect();
        for &(id, name) in &ids {
            assert!(
                same(&expected, &recorded, id),
                "{name}: differs from the in-process run"
            );
        }
    }

    // The monitor's decoding: everything accepted, and the braking events of the truth.
    let mapping = MappingConfig::from_toml_str(MAPPING).unwrap();
    let mut mapper = Mapper::new(&db, &mapping).unwrap();
    let mut pressed = false;
    let mut onsets_kmh = Vec::new();
    for f in &got {
        mapper.on_frame(f);
        let snap = mapper.snapshot(f.t_ns);
        // Last decoded values, not their timeout validity: in the VM the sender runs slower
        // than real time, so the 50–100 ms message timeouts trip between frames.
        let now = snap.brake_pressed.value.unwrap_or(false);
        if now && !pressed {
            onsets_kmh.push(snap.speed_mps.value.map(|v| v * 3.6));
        }
        pressed = now;
    }
    for m in mapper.stats() {
        assert_eq!(m.frames, m.accepted, "{m:?}");
        assert_eq!(
            m.checksum_errors + m.counter_errors + m.frames_lost,
            0,
            "{m:?}"
        );
    }
    let events = truth["events"].as_array().unwrap();
    assert_eq!(
        onsets_kmh.len(),
        events.len(),
        "brake-switch edges vs truth events"
    );
    for (e, v) in events.iter().zip(&onsets_kmh) {
        let v0 = e["v0_kmh"].as_f64().unwrap();
        let v = v.expect("speed decoded before brake onset");
        assert!(
            (v - v0).abs() < 1.0,
            "speed {v} km/h at onset, truth v0 {v0}"
        );
    }
    let _ = std::fs::remove_dir_all(&dir);
}
