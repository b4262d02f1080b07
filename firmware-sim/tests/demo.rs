//! The bundled demo log (`tests/fixtures/demo/`, recorded with
//! `firmware-sim --scenario config/scenarios/worn_0p2mm.toml --out tests/fixtures/demo/worn_0p2mm.log
//! --truth tests/fixtures/demo/worn_0p2mm.truth.json`) is intact and agrees with its sidecar: it
//! reads without a malformed line, every counter and checksum is right, and the braking events
//! the sidecar lists are where the bus shows them, at the speeds it says.

use std::path::PathBuf;

use shimmy::dbc::Database;
use shimmy::signals::checksum::ChecksumKind;
use shimmy::source::log::LogReader;
use shimmy::source::CanSource;
use shimmy::wire::Frame;

fn fixture(name: &str) -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR"))
        .join("../tests/fixtures/demo")
        .join(name)
}

#[test]
fn demo_log_is_intact_and_matches_its_ground_truth() {
    let mut r = LogReader::open(fixture("worn_0p2mm.log")).unwrap();
    let mut frames: Vec<Frame> = Vec::new();
    while let Some(f) = r.next_frame().unwrap() {
        frames.push(f);
    }
    assert_eq!(r.stats().malformed, 0);
    assert!(frames.len() > 5000);
    let truth: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(fixture("worn_0p2mm.truth.json")).unwrap())
            .unwrap();
    assert_eq!(truth["format"], "firmware-sim ground truth v1");
    assert_eq!(truth["frames_sent"].as_u64(), Some(frames.len() as u64));
    assert_eq!(truth["clearance"]["left_mm_start"].as_f64(), Some(0.2));

    let db = Database::parse(firmware_sim::bus::REFERENCE_DBC).0;
    let sig = |msg: &str, s: &str| {
        let m = &db.messages()[db.message_by_name(msg).unwrap()];
        (m.id, m.signals[m.signal_by_name(s).unwrap()].clone())
    };
    for f in frames
        .iter()
        .filter(|f| f.id != sig("WHL_01", "WHL_SpeedFL").0)
    {
        ChecksumKind::Shimmy.verify(f.id, f.payload()).unwrap();
    }
    let t0 = truth["start_unix_s"].as_f64().unwrap();
    let (brk, switch) = sig("BRK_01", "BRK_Switch");
    let (veh, speed) = sig("VEH_01", "VEH_Speed");
    let events = truth["events"].as_array().unwrap();
    assert!(events.len() >= 3);
    assert!(events
        .iter()
        .any(|e| (e["v0_kmh"].as_f64().unwrap() - 55.0).abs() < 1.0));
    for e in events {
        let t_start = e["t_start_s"].as_f64().unwrap();
        // The first brake-switch frame after onset comes within one 20 ms period.
        let first = frames
            .iter()
            .filter(|f| f.id == brk && switch.phys(f.payload()) == Some(1.0))
            .map(|f| f.t_s() - t0)
            .find(|&t| t >= t_start - 1e-6)
            .unwrap();
        assert!(
            first - t_start < 0.021,
            "switch at {first}, onset {t_start}"
        );
        // The reported vehicle speed at onset is v0 (within noise and radius errors).
        let v = frames
            .iter()
            .filter(|f| f.id == veh && f.t_s() - t0 >= t_start)
            .map(|f| speed.phys(f.payload()).unwrap())
            .next()
            .unwrap();
        let v0 = e["v0_kmh"].as_f64().unwrap();
        assert!((v - v0).abs() < 0.01 * v0 + 0.3, "speed {v} vs v0 {v0}");
        assert!(e["sw_amplitude_deg"].as_f64().unwrap() > 0.0);
    }
    assert!(std::fs::metadata(fixture("worn_0p2mm.log")).unwrap().len() < 2 * 1024 * 1024);
}
