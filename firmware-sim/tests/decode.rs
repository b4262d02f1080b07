//! A firmware-sim log written to disk as candump -L, read back with the project's log reader
//! and decoded with the project's DBC decoder, gives the values the ECUs put in (within half an
//! LSB); cantools, with the same DBC, decodes the same file to identical signal values.
//!
//! The cantools half needs `python3` with `cantools` (`pip install cantools`): without them it
//! prints SKIPPED, except under `CI=true`, where it fails.

use std::path::{Path, PathBuf};
use std::process::Command;

use firmware_sim::bus::REFERENCE_DBC;
use firmware_sim::plant::PointMass;
use firmware_sim::{FirmwareSim, RunInfo, Scenario};
use shimmy::dbc::Database;
use shimmy::source::log::LogReader;
use shimmy::source::CanSource;
use shimmy::wire::Frame;

fn workspace() -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("..")
}

/// Simulate a bundled scenario (with the faults scenario's bad checksums and drops, so those
/// frames are in the comparison too) and write it as a candump log.
fn write_log(name: &str) -> (tempfile::TempPath, FirmwareSim<PointMass>, Vec<Frame>) {
    let sc = Scenario::load(&workspace().join(format!("config/scenarios/{name}.toml"))).unwrap();
    let plant = PointMass::new(sc.drive.start_speed_kmh / 3.6, sc.step_s, 0.004, 6.5);
    let mut sim = FirmwareSim::new(&sc, plant, REFERENCE_DBC, RunInfo::default()).unwrap();
    sim.bus_mut().record_values();
    let frames: Vec<Frame> = sim.by_ref().collect();
    // A file of its own per call, removed with it: two tests write the same scenario's log in
    // parallel (threads or, under a runner like nextest, processes).
    let path = tempfile::Builder::new()
        .prefix(&format!("fwsim_decode_{name}_"))
        .suffix(".log")
        .tempfile_in(env!("CARGO_TARGET_TMPDIR"))
        .unwrap()
        .into_temp_path();
    let mut out = Vec::new();
    for f in &frames {
        shimmy::wire::candump::write_frame(&mut out, f).unwrap();
    }
    std::fs::write(&path, out).unwrap();
    (path, sim, frames)
}

fn read_back(path: &Path) -> Vec<Frame> {
    let mut r = LogReader::open(path).unwrap();
    let mut v = Vec::new();
    while let Some(f) = r.next_frame().unwrap() {
        v.push(f);
    }
    assert_eq!(r.stats().malformed, 0);
    v
}

#[test]
fn log_round_trips_and_decodes_to_the_sent_values() {
    let (path, sim, frames) = write_log("faulty_bus");
    let back = read_back(&path);
    assert_eq!(back.len(), frames.len());
    for (a, b) in frames.iter().zip(&back) {
        assert_eq!((a.t_ns, a.id, a.payload()), (b.t_ns, b.id, b.payload()));
    }
    let db = Database::parse(REFERENCE_DBC).0;
    let mut rec = sim.bus().recorded().to_vec();
    rec.sort_by_key(|r| r.t_ns);
    assert_eq!(rec.len(), back.len());
    let mut n = 0;
    for (f, r) in back.iter().zip(&rec) {
        let (mi, sigs) = sim.bus().message_layout(r.message);
        let m = &db.messages()[db.message_index(f.id, f.extended).unwrap()];
        assert_eq!(m.name, db.messages()[mi].name);
        for (k, &si) in sigs.iter().enumerate() {
            let s = &m.signals[si];
            let got = s.phys(f.payload()).unwrap();
            assert!(
                (got - r.values[k]).abs() <= s.factor.abs() / 2.0 + 1e-9,
                "{}.{} at {}: sent {}, decoded {got}",
                m.name,
                s.name,
                f.t_ns,
                r.values[k]
            );
            n += 1;
        }
    }
    assert!(n > 10_000, "{n} values checked");
}

const CANTOOLS_SCRIPT: &str = r#"
import json, sys
import cantools, cantools.logreader
db = cantools.database.load_file(sys.argv[1])
with open(sys.argv[2]) as f:
    for _, fr in cantools.logreader.Parser(f).iterlines(keep_unknowns=True):
        if fr is None:
            print("null"); continue
        sigs = db.decode_message(fr.frame_id, fr.data, decode_choices=False)
        print(json.dumps({"id": fr.frame_id, "data": fr.data.hex(), "signals": sigs}))
"#;

#[test]
fn cantools_decodes_the_log_to_identical_values() {
    let have = Command::new("python3")
        .args(["-c", "import cantools"])
        .output()
        .map(|o| o.status.success())
        .unwrap_or(false);
    if !have {
        if shimmy::shared_data::in_ci() {
            panic!("python3 with cantools is required under CI (pip install cantools)");
        }
        eprintln!(
            "SKIPPED cantools comparison: python3 with cantools not found (pip install cantools)"
        );
        return;
    }
    // A generated run with faults, and the bundled demo log recorded with the real model.
    let (path, _sim, _) = write_log("faulty_bus");
    cantools_agrees(&path, 20_000);
    cantools_agrees(
        &workspace().join("tests/fixtures/demo/worn_0p2mm.log"),
        25_000,
    );
}

fn cantools_agrees(path: &Path, min_values: usize) {
    let back = read_back(path);
    let dbc_path = workspace().join("dbc/shimmy_reference.dbc");
    let out = Command::new("python3")
        .arg("-c")
        .arg(CANTOOLS_SCRIPT)
        .arg(&dbc_path)
        .arg(path)
        .output()
        .unwrap();
    assert!(
        out.status.success(),
        "cantools failed: {}",
        String::from_utf8_lossy(&out.stderr)
    );
    let text = String::from_utf8(out.stdout).unwrap();
    let lines: Vec<&str> = text.lines().collect();
    assert_eq!(
        lines.len(),
        back.len(),
        "cantools saw a different frame count"
    );
    let db = Database::parse(REFERENCE_DBC).0;
    let mut compared = 0;
    for (f, line) in back.iter().zip(&lines) {
        let v: serde_json::Value = serde_json::from_str(line).unwrap();
        assert_eq!(v["id"].as_u64(), Some(f.id as u64));
        let m = db.message(f.id, f.extended).unwrap();
        let sigs = v["signals"].as_object().unwrap();
        assert_eq!(sigs.len(), m.signals.len(), "{}: signal count", m.name);
        m.decode(f.payload(), |i, _raw, phys| {
            let theirs = sigs[&m.signals[i].name].as_f64().unwrap();
            assert!(
                (phys - theirs).abs() <= 1e-9 * theirs.abs().max(1.0),
                "{}.{}: ours {phys}, cantools {theirs}",
                m.name,
                m.signals[i].name
            );
            compared += 1;
        })
        .unwrap();
    }
    assert!(compared > min_values, "{compared} values compared");
    eprintln!(
        "cantools and shimmy::dbc agree on {compared} signal values in {} frames",
        back.len()
    );
}
