//! The workshop's "joints replaced" marker (`<state_dir>/joints_replaced`, written with
//! `shimmyd --joints-replaced [MM]`), end to end on firmware-sim logs replayed by the shimmyd
//! executable with one state directory across runs: a worn car raises the clearance alert; after
//! the marker the daemon journals the replacement with the estimate before it, clears the alert
//! (reason `joints_replaced`), collects the next `vehicle.baseline_events` used braking events
//! of the new joints (no clearance claimed meanwhile) and makes them the car's baseline at the
//! marker's clearance, and removes the marker. A marker with bad content is rejected, renamed and
//! logged as an error; a restart in the middle of the collection resumes its count, and a marker
//! already handled (the daemon stopped before removing it) is only removed.

mod e2e_common;

use std::path::{Path, PathBuf};
use std::process::Command;
use std::sync::OnceLock;

use serde_json::Value;

/// The two drives, simulated once per test process: worn joints (0.2 mm, three braking
/// events, the clearance alert) and new joints (0.03 mm, three braking events).
struct Logs {
    _dir: tempfile::TempDir,
    worn: PathBuf,
    new: PathBuf,
}

fn logs() -> &'static Logs {
    static LOGS: OnceLock<Logs> = OnceLock::new();
    LOGS.get_or_init(|| {
        let dir = tempfile::tempdir().unwrap();
        let worn = e2e_common::generate("worn_0p2mm", None, dir.path()).log;
        let new = e2e_common::generate("new_car", None, dir.path()).log;
        Logs {
            _dir: dir,
            worn,
            new,
        }
    })
}

/// A daemon configuration in `dir` (the reference car, journal and state under `dir`) taking
/// `events` braking events as the baseline after a replacement, by default at 0.05 mm.
fn config(dir: &Path, events: u32) -> PathBuf {
    let p = dir.join("shimmyd.toml");
    std::fs::write(
        &p,
        format!(
            "[input]\nprofile = \"shimmy_reference\"\n\
             [vehicle]\nbaseline_events = {events}\nbaseline_clearance_mm = 0.05\n\
             [outputs]\njournal_dir = \"journal\"\nstate_dir = \"state\"\n"
        ),
    )
    .unwrap();
    p
}

/// `shimmyd --config CFG --replay LOG --fast`; its stderr. Panics unless it exits 0.
fn replay(cfg: &Path, log: &Path) -> String {
    let out = e2e_common::replay_command(cfg, log, None)
        .current_dir(e2e_common::workspace())
        .output()
        .unwrap();
    let err = String::from_utf8_lossy(&out.stderr).into_owned();
    assert!(
        out.status.success(),
        "shimmyd --replay {}: {err}",
        log.display()
    );
    err
}

/// `shimmyd --config CFG --joints-replaced [MM]`.
fn mark(cfg: &Path, mm: Option<&str>) -> std::process::Output {
    let mut cmd = Command::new(e2e_common::shimmyd());
    cmd.arg("--config").arg(cfg).arg("--joints-replaced");
    if let Some(mm) = mm {
        cmd.arg(mm);
    }
    cmd.current_dir(e2e_common::workspace()).output().unwrap()
}

/// Every journal record, in order.
fn records(dir: &Path) -> Vec<Value> {
    let mut r = shimmy::journal::Reader::open(&dir.join("journal")).unwrap();
    let recs: Vec<Value> = (&mut r).map(|e| e.unwrap().rec).collect();
    assert_eq!(r.invalid_lines(), 0, "{:?}", r.problems());
    recs
}

fn of<'a>(recs: &'a [Value], kind: &'a str) -> impl Iterator<Item = (usize, &'a Value)> {
    recs.iter()
        .enumerate()
        .filter(move |(_, r)| r["type"] == kind)
}

fn state(dir: &Path) -> Value {
    serde_json::from_str(&std::fs::read_to_string(dir.join("state/state.json")).unwrap()).unwrap()
}

fn marker(dir: &Path) -> PathBuf {
    dir.join("state/joints_replaced")
}

/// A worn car's alert, then the marker and the new joints' drive: the replacement is journaled,
/// the alert cleared, the estimate reset, the baseline collected and then used.
#[test]
fn a_marker_clears_the_alert_resets_and_collects_a_new_baseline() {
    let tmp = tempfile::tempdir().unwrap();
    let dir = tmp.path();
    let cfg = config(dir, 2);
    replay(&cfg, &logs().worn);
    let j = e2e_common::Journal::read(&dir.join("journal"));
    assert_eq!(j.kinds_standing(), ["clearance"], "{}", j.describe());

    let out = mark(&cfg, Some("0.04"));
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    assert_eq!(std::fs::read_to_string(marker(dir)).unwrap().trim(), "0.04");

    let err = replay(&cfg, &logs().new);
    assert!(err.contains("joints replaced"), "{err}");
    assert!(!marker(dir).exists(), "the marker was not removed: {err}");

    let recs = records(dir);
    let mut jr = of(&recs, "joints_replaced");
    let (at, rec) = jr.next().expect("a joints_replaced record");
    assert!(jr.next().is_none(), "one replacement");
    assert_eq!(rec["clearance_mm"], 0.04, "{rec}");
    assert_eq!(rec["clearance_from"], "marker");
    assert_eq!(rec["baseline_events"], 2);
    assert_eq!(rec["baseline"], "collecting");
    assert!(rec["wall_unix_s"].as_f64().unwrap() > 0.0, "{rec}");
    // The estimate before it is the worn joints' (it raised the alert).
    let before = &rec["estimate_before"];
    assert!(before["p_above"].as_f64().unwrap() >= 0.7, "{rec}");

    // The clearance alert cleared through the alert lifecycle, for that reason.
    let cleared: Vec<&Value> = of(&recs, "alert")
        .filter(|(i, r)| *i > at && r["transition"] == "cleared")
        .map(|(_, r)| r)
        .collect();
    assert_eq!(cleared.len(), 1, "{cleared:?}");
    assert_eq!(cleared[0]["alert"]["kind"], "clearance");
    assert_eq!(cleared[0]["reason"], "joints_replaced");
    assert_eq!(
        rec["alerts_cleared"],
        serde_json::json!([cleared[0]["alert"]["id"]])
    );
    // Nothing raises it again: the new joints' events go to the baseline, then the estimate.
    assert!(
        !of(&recs, "alert").any(|(i, r)| i > at && r["transition"] == "raised"),
        "{recs:?}"
    );

    // While collecting, the estimates claim no clearance and say how far the collection is.
    let (b_at, base) = of(&recs, "baseline").next().expect("a baseline record");
    assert_eq!(base["source"], "joints_replaced");
    assert_eq!(base["baseline"]["events"], 2);
    assert_eq!(base["baseline"]["clearance_mm"], 0.04);
    assert!(
        base["baseline"]["angle_events"].as_u64().unwrap() >= 1,
        "{base}"
    );
    let collecting: Vec<&Value> = of(&recs, "estimate")
        .filter(|(i, _)| *i > at && *i < b_at)
        .map(|(_, r)| r)
        .collect();
    let counts: Vec<u64> = collecting
        .iter()
        .map(|r| r["baseline_collection"]["collected"].as_u64().unwrap())
        .collect();
    assert_eq!(counts, [0, 1], "{collecting:?}");
    for r in &collecting {
        let e = &r["estimate"];
        assert_eq!(e["events_used"], 0, "{r}");
        assert!(
            e["clearance_mm"].is_null() && e["interval_mm"].is_null(),
            "{r}"
        );
        assert!(e["p_above"].is_null(), "{r}");
        assert_eq!(r["baseline_collection"]["events"], 2);
        assert!(r["baseline_collection"]["text"]
            .as_str()
            .unwrap()
            .contains("collecting a baseline after a joint replacement"));
    }
    // After it, the estimate goes on, conditioned on the baseline.
    let after: Vec<&Value> = of(&recs, "estimate")
        .filter(|(i, _)| *i > b_at)
        .map(|(_, r)| r)
        .collect();
    assert!(after.iter().all(|r| r.get("baseline_collection").is_none()));
    let last = after.last().expect("an estimate after the baseline");
    assert!(
        last["estimate"]["events_used"].as_u64().unwrap() >= 1,
        "{last}"
    );
    assert!(last["estimate"]["interval_mm"].is_array(), "{last}");

    let st = state(dir);
    let b = &st["stage"]["baseline"];
    assert_eq!(b["clearance_mm"], 0.04);
    assert_eq!(b["evidence"].as_array().unwrap().len(), 2);
    assert_eq!(st["stage"]["from_replacement"], true);
    assert!(st["stage"].get("collecting").is_none());
    assert_eq!(st["replacement"]["marker"]["content"], "0.04");
    assert_eq!(st["replacement"]["clearance_mm"], 0.04);
    assert_eq!(st["alerts"]["open"], serde_json::json!([]));

    // The workshop report is about the new joints.
    let out = Command::new(env!("CARGO_BIN_EXE_shimmy"))
        .args(["report", "--format", "json", "--journal"])
        .arg(dir.join("journal"))
        .output()
        .unwrap();
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    let report: Value = serde_json::from_slice(&out.stdout).unwrap();
    assert_eq!(report["joints_replaced"]["clearance_mm"], 0.04);
    assert_ne!(report["verdict"]["condition"], "replace", "{report}");
    assert_eq!(report["open_alerts"], serde_json::json!([]));
}

/// A marker that is not a clearance is an error in the log, renamed, and changes nothing; the
/// command-line flag refuses one before writing it.
#[test]
fn a_marker_with_bad_content_is_rejected_and_renamed() {
    let tmp = tempfile::tempdir().unwrap();
    let dir = tmp.path();
    let cfg = config(dir, 2);
    std::fs::create_dir_all(dir.join("state")).unwrap();
    std::fs::write(marker(dir), "twelve\n").unwrap();
    let err = replay(&cfg, &logs().worn);
    assert!(
        err.contains("error: joints_replaced") && err.contains("rejected"),
        "{err}"
    );
    assert!(
        err.contains("\"twelve\""),
        "the log names the content: {err}"
    );
    assert!(!marker(dir).exists());
    let rejected = dir.join("state/joints_replaced.rejected");
    assert_eq!(std::fs::read_to_string(&rejected).unwrap(), "twelve\n");
    let recs = records(dir);
    assert_eq!(of(&recs, "joints_replaced").count(), 0);
    let (_, r) = of(&recs, "joints_replaced_rejected")
        .next()
        .expect("a joints_replaced_rejected record");
    assert!(
        r["reason"].as_str().unwrap().contains("not a clearance"),
        "{r}"
    );
    // Nothing was reset: the worn joints' alert is raised and stands.
    let j = e2e_common::Journal::read(&dir.join("journal"));
    assert_eq!(j.kinds_standing(), ["clearance"], "{}", j.describe());
    assert!(state(dir).get("replacement").is_none());

    for bad in ["0", "abc", "25"] {
        let out = mark(&cfg, Some(bad));
        let err = String::from_utf8_lossy(&out.stderr);
        assert!(!out.status.success(), "{bad}: {err}");
        assert!(err.contains("--joints-replaced"), "{bad}: {err}");
        assert!(!marker(dir).exists(), "{bad}: a marker was written");
    }
}

/// `baseline_events = 5` and a drive of three: the collection is saved, and the next run
/// resumes it at 3 of 5 and completes it. The marker seen again with the same identity (the
/// daemon stopped after saving its state, before removing it) is not applied twice.
#[test]
fn a_restart_in_the_middle_of_the_collection_resumes_it() {
    let tmp = tempfile::tempdir().unwrap();
    let dir = tmp.path();
    let cfg = config(dir, 5);
    replay(&cfg, &logs().worn);
    // An empty marker (the configured clearance, 0.05 mm), written a while ago.
    let settled = std::time::SystemTime::now() - std::time::Duration::from_secs(30);
    std::fs::File::create(marker(dir))
        .unwrap()
        .set_modified(settled)
        .unwrap();

    let err = replay(&cfg, &logs().new);
    assert!(err.contains("joints replaced"), "{err}");
    assert!(!marker(dir).exists());
    let st = state(dir);
    let c = &st["stage"]["collecting"];
    assert_eq!(c["target"], 5, "{st:#}");
    assert_eq!(c["clearance_mm"], 0.05);
    let first = c["evidence"].as_array().unwrap().len();
    assert!((1..5).contains(&first), "{first} events collected of 5");
    assert!(st["stage"]["baseline"].is_null(), "{st:#}");
    let recs = records(dir);
    let (_, rec) = of(&recs, "joints_replaced").next().unwrap();
    assert_eq!(rec["clearance_from"], "vehicle.baseline_clearance_mm");
    assert_eq!(rec["clearance_mm"], 0.05);

    // The same marker again, as if the daemon had died before removing it.
    let mtime_ns = st["replacement"]["marker"]["mtime_ns"].as_u64().unwrap();
    std::fs::File::create(marker(dir))
        .unwrap()
        .set_modified(std::time::UNIX_EPOCH + std::time::Duration::from_nanos(mtime_ns))
        .unwrap();

    let err = replay(&cfg, &logs().new);
    assert!(
        err.contains(&format!(
            "collecting a baseline after a joint replacement: {first} of 5"
        )),
        "the restart did not resume the collection: {err}"
    );
    assert!(err.contains("already handled"), "{err}");
    assert!(!marker(dir).exists());
    let recs = records(dir);
    assert_eq!(of(&recs, "joints_replaced").count(), 1, "applied twice");
    let (_, base) = of(&recs, "baseline")
        .next()
        .expect("the baseline completed");
    assert_eq!(base["baseline"]["events"], 5);
    assert_eq!(base["baseline"]["clearance_mm"], 0.05);
    let st = state(dir);
    assert!(st["stage"].get("collecting").is_none(), "{st:#}");
    let b = &st["stage"]["baseline"];
    assert_eq!(b["evidence"].as_array().unwrap().len(), 5);
    assert_eq!(b["clearance_mm"], 0.05);
}

/// `vehicle.baseline_events` is checked: at least one event.
#[test]
fn baseline_events_must_be_at_least_one() {
    let tmp = tempfile::tempdir().unwrap();
    let cfg = config(tmp.path(), 0);
    let out = Command::new(e2e_common::shimmyd())
        .arg("--config")
        .arg(&cfg)
        .arg("--check")
        .current_dir(e2e_common::workspace())
        .output()
        .unwrap();
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(!out.status.success(), "{err}");
    assert!(
        err.contains("vehicle.baseline_events: must be 1..=1000 (got 0)"),
        "{err}"
    );
}
