//! shimmyd resumes its clearance estimate after a restart (issue 6 item 4): the posterior, the
//! event history and the odometer persist in the state directory, so replaying log A and then
//! log B in two daemon runs ends with exactly the estimate of one run over A followed by B.

use std::path::{Path, PathBuf};
use std::process::Command;

use serde_json::Value;

fn workspace() -> &'static Path {
    Path::new(env!("CARGO_MANIFEST_DIR"))
}

/// The demo daemon config (with its response table) writing journal and state under `dir`.
fn config(dir: &Path) -> PathBuf {
    let p = dir.join("shimmyd.toml");
    let text = format!(
        "[input]\ndbc = {:?}\nmapping = {:?}\n[vehicle]\ntable = {:?}\n\
         [outputs]\njournal_dir = \"journal\"\nstate_dir = \"state\"\n",
        workspace().join("dbc/shimmy_reference.dbc"),
        workspace().join("config/vehicles/shimmy_reference/mapping.toml"),
        workspace().join("config/vehicles/shimmy_reference/table.json"),
    );
    std::fs::write(&p, text).unwrap();
    p
}

fn replay(cfg: &Path, logs: &[&Path]) -> String {
    let out = Command::new(env!("CARGO_BIN_EXE_shimmyd"))
        .arg("--config")
        .arg(cfg)
        .arg("--replay")
        .args(logs)
        .arg("--fast")
        .output()
        .unwrap();
    let err = String::from_utf8_lossy(&out.stderr).to_string();
    assert!(out.status.success(), "{err}");
    err
}

fn state(dir: &Path) -> Value {
    serde_json::from_str(&std::fs::read_to_string(dir.join("state/state.json")).unwrap()).unwrap()
}

/// Splits the demo log (three braking events at 1.5 s, 8.2 s and 19.9 s) at 16 s, between the
/// second and the third event.
fn split_demo(dir: &Path) -> (PathBuf, PathBuf) {
    let text =
        std::fs::read_to_string(workspace().join("tests/fixtures/demo/worn_0p2mm.log")).unwrap();
    let t_split = 1767225600.0 + 16.0;
    let (mut a, mut b) = (String::new(), String::new());
    for line in text.lines() {
        let t: f64 = line[1..line.find(')').unwrap()].parse().unwrap();
        let out = if t < t_split { &mut a } else { &mut b };
        out.push_str(line);
        out.push('\n');
    }
    assert!(!a.is_empty() && !b.is_empty());
    let (pa, pb) = (dir.join("a.log"), dir.join("b.log"));
    std::fs::write(&pa, a).unwrap();
    std::fs::write(&pb, b).unwrap();
    (pa, pb)
}

#[test]
fn two_runs_over_a_then_b_give_the_estimate_of_one_run_over_a_and_b() {
    let tmp = tempfile::tempdir().unwrap();
    let (a, b) = split_demo(tmp.path());

    let once = tmp.path().join("once");
    std::fs::create_dir(&once).unwrap();
    replay(&config(&once), &[&a, &b]);
    let whole = state(&once);

    let twice = tmp.path().join("twice");
    std::fs::create_dir(&twice).unwrap();
    let cfg = config(&twice);
    replay(&cfg, &[&a]);
    let after_a = state(&twice);
    let err_b = replay(&cfg, &[&b]);
    let resumed = state(&twice);

    // Run A saw two of the three events: its estimate is not yet the whole one.
    assert_eq!(after_a["events_total"], 2, "{after_a:#}");
    assert_ne!(after_a["estimate"], whole["estimate"]);
    assert!(
        err_b.contains("clearance posterior restored from 2 used event(s)"),
        "{err_b}"
    );

    assert_eq!(whole["events_total"], 3);
    assert_eq!(resumed["events_total"], 3);
    assert_eq!(
        resumed["estimate"], whole["estimate"],
        "estimate after A then B differs from A+B"
    );
    assert_eq!(resumed["estimate"]["events_used"], 3);
    assert!(resumed["estimate"]["interval_mm"].is_array());
    assert_eq!(resumed["events"], whole["events"], "event history");
    let (o1, o2) = (
        resumed["odometer_km"].as_f64().unwrap(),
        whole["odometer_km"].as_f64().unwrap(),
    );
    assert!((o1 - o2).abs() < 1e-9, "odometer {o1} vs {o2}");
    assert!(o2 > 0.2, "the demo drives 0.22 km: {o2}");
    assert_eq!(resumed["alerts"], whole["alerts"], "open alerts");
}

#[test]
fn a_state_without_a_posterior_still_resumes() {
    // A state file from before the posterior was saved (no "stage" key) resumes with a fresh
    // estimate, keeping odometer and history.
    let tmp = tempfile::tempdir().unwrap();
    let (a, b) = split_demo(tmp.path());
    let cfg = config(tmp.path());
    replay(&cfg, &[&a]);
    let p = tmp.path().join("state/state.json");
    let mut s = state(tmp.path());
    let odo = s["odometer_km"].as_f64().unwrap();
    s.as_object_mut().unwrap().remove("stage");
    std::fs::write(&p, serde_json::to_vec(&s).unwrap()).unwrap();
    let err = replay(&cfg, &[&b]);
    assert!(!err.contains("posterior restored"), "{err}");
    let s = state(tmp.path());
    assert_eq!(s["events_total"], 3);
    assert_eq!(
        s["estimate"]["events_used"], 1,
        "only B's event in the fresh posterior"
    );
    assert!(s["odometer_km"].as_f64().unwrap() > odo);
}
