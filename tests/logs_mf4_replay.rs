//! A firmware-sim drive written as MF4 gives the same frames, and so the same braking events,
//! estimate and alerts, as the same drive written as candump -L: through `shimmy estimate` and
//! through shimmyd `--replay` (processes, as a user runs them).

use std::path::Path;
use std::process::Command;

use shimmy::source::log::LogReader;
use shimmy::source::CanSource;

mod e2e_common;
use e2e_common::*;

fn frames(p: &Path) -> Vec<shimmy::wire::Frame> {
    let mut r = LogReader::open(p).unwrap();
    let mut v = Vec::new();
    while let Some(f) = r.next_frame().unwrap() {
        v.push(f);
    }
    assert_eq!(r.stats().malformed, 0);
    v
}

fn sim(out: &Path) {
    let o = Command::new(firmware_sim())
        .arg("--scenario")
        .arg(workspace().join("config/scenarios/worn_0p2mm.toml"))
        .arg("--out")
        .arg(out)
        .arg("--truth")
        .arg(out.with_extension("truth.json"))
        .output()
        .unwrap();
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
}

fn estimate(log: &Path) -> serde_json::Value {
    let ws = workspace();
    let o = Command::new(env!("CARGO_BIN_EXE_shimmy"))
        .arg("estimate")
        .arg("--mapping")
        .arg(ws.join("config/vehicles/shimmy_reference/mapping.toml"))
        .arg("--dbc")
        .arg(ws.join("dbc/shimmy_reference.dbc"))
        .arg("--vehicle")
        .arg(ws.join("config/vehicle/default.toml"))
        .arg("--table")
        .arg(ws.join("config/vehicles/shimmy_reference/table.json"))
        .arg(log)
        .output()
        .unwrap();
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let mut v: serde_json::Value = serde_json::from_slice(&o.stdout).unwrap();
    // The only field allowed to differ: the log's own name.
    strip_paths(&mut v, log);
    v
}

fn strip_paths(v: &mut serde_json::Value, log: &Path) {
    let name = log.display().to_string();
    match v {
        serde_json::Value::String(s) if s.contains(&name) => *s = s.replace(&name, "LOG"),
        serde_json::Value::Array(a) => a.iter_mut().for_each(|x| strip_paths(x, log)),
        serde_json::Value::Object(o) => o.values_mut().for_each(|x| strip_paths(x, log)),
        _ => {}
    }
}

#[test]
fn mf4_drive_gives_the_same_events_estimate_and_alerts_as_candump() {
    let dir = tempfile::tempdir().unwrap();
    let log = dir.path().join("drive.log");
    let mf4 = dir.path().join("drive.mf4");
    sim(&log);
    sim(&mf4);
    assert_eq!(&std::fs::read(&mf4).unwrap()[..8], b"MDF     ");
    let a = frames(&log);
    assert!(a.len() > 5000);
    assert_eq!(a, frames(&mf4), "the MF4 drive holds other frames");

    let (ea, eb) = (estimate(&log), estimate(&mf4));
    assert_eq!(ea, eb, "shimmy estimate differs");
    let text = ea.to_string();
    assert!(
        text.contains("events") || text.contains("estimate"),
        "{text}"
    );

    let cfg_dir = dir.path().join("d");
    std::fs::create_dir_all(cfg_dir.join("a")).unwrap();
    std::fs::create_dir_all(cfg_dir.join("b")).unwrap();
    let mut journals = Vec::new();
    for (sub, input) in [("a", &log), ("b", &mf4)] {
        let d = cfg_dir.join(sub);
        let cfg = write_config(&d, "");
        replay(&cfg, input, &d.join("state"));
        journals.push(Journal::read(&d.join("journal")));
    }
    let (ja, jb) = (&journals[0], &journals[1]);
    assert!(!ja.events.is_empty(), "{}", ja.describe());
    assert_eq!(ja.events, jb.events, "events differ");
    assert_eq!(ja.alerts, jb.alerts, "alerts differ");
    assert_eq!(ja.estimate, jb.estimate, "estimates differ");
    assert!(ja.estimate.is_some(), "{}", ja.describe());
}
