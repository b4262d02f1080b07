//! shimmyd with the real clearance observer (issue 6 over issue 5), end to end as a process:
//! the firmware-sim demo log (tests/fixtures/demo, 0.2 mm worn joints, three braking events)
//! replayed through the daemon finds and journals the braking events the ground truth lists,
//! and the `shimmy_55kmh` alert follows the truth through the configured confirmation rule;
//! with a response table the shimmy and clearance alerts and the estimate's interval follow the
//! truth; a `vehicle.table` that cannot be loaded stops the daemon at start, naming the key.
//! (The real RAV4 log raising nothing with the observer wired in is tests/daemon_replay.rs.)

use std::path::{Path, PathBuf};
use std::process::Command;

use shimmy::journal::Reader;

fn workspace() -> &'static Path {
    Path::new(env!("CARGO_MANIFEST_DIR"))
}

fn demo() -> (PathBuf, serde_json::Value) {
    let dir = workspace().join("tests/fixtures/demo");
    let truth = std::fs::read_to_string(dir.join("worn_0p2mm.truth.json")).unwrap();
    (
        dir.join("worn_0p2mm.log"),
        serde_json::from_str(&truth).unwrap(),
    )
}

/// A config using the repository's DBC and mapping, plus `extra` TOML lines per table.
fn write_config(dir: &Path, vehicle: &str, alerts: &str) -> PathBuf {
    let p = dir.join("shimmyd.toml");
    let text = format!(
        "[input]\ndbc = {:?}\nmapping = {:?}\n[vehicle]\n{vehicle}\n[alerts]\n{alerts}\n\
         [outputs]\njournal_dir = \"journal\"\nstate_dir = \"state\"\n",
        workspace().join("dbc/shimmy_reference.dbc"),
        workspace().join("config/vehicles/shimmy_reference/mapping.toml"),
    );
    std::fs::write(&p, text).unwrap();
    p
}

fn run(cfg: &Path, state: &Path, log: &Path) -> std::process::Output {
    Command::new(env!("CARGO_BIN_EXE_shimmyd"))
        .arg("--config")
        .arg(cfg)
        .arg("--replay")
        .arg(log)
        .arg("--fast")
        .arg("--state-dir")
        .arg(state)
        .output()
        .unwrap()
}

fn records(dir: &Path) -> Vec<serde_json::Value> {
    let mut r = Reader::open(dir).unwrap();
    let v: Vec<_> = (&mut r).map(|e| e.unwrap().rec).collect();
    assert_eq!(r.invalid_lines(), 0, "{:?}", r.problems());
    v
}

fn f(v: &serde_json::Value) -> f64 {
    v.as_f64().unwrap()
}

/// Replays the demo with `alerts` settings; returns (journalled events, shimmy alert records).
fn replay_demo(alerts: &str) -> (Vec<serde_json::Value>, Vec<serde_json::Value>, String) {
    let (events, alerts, _, err) = replay_demo_with("", alerts);
    let shimmy = alerts
        .into_iter()
        .filter(|r| r["alert"]["kind"] == "shimmy_55kmh")
        .collect();
    (events, shimmy, err)
}

/// Replays the demo; returns (events, alert records, estimate records, stderr).
#[allow(clippy::type_complexity)]
fn replay_demo_with(
    vehicle: &str,
    alerts: &str,
) -> (
    Vec<serde_json::Value>,
    Vec<serde_json::Value>,
    Vec<serde_json::Value>,
    String,
) {
    let (log, _) = demo();
    let dir = tempfile::tempdir().unwrap();
    let cfg = write_config(dir.path(), vehicle, alerts);
    let out = run(&cfg, &dir.path().join("state"), &log);
    let err = String::from_utf8_lossy(&out.stderr).to_string();
    assert!(out.status.success(), "{err}");
    let recs = records(&dir.path().join("journal"));
    let events = recs
        .iter()
        .filter(|r| r["type"] == "event")
        .map(|r| r["event"].clone())
        .collect();
    let of = |t: &str| -> Vec<serde_json::Value> {
        recs.iter().filter(|r| r["type"] == t).cloned().collect()
    };
    (events, of("alert"), of("estimate"), err)
}

#[test]
fn demo_braking_events_are_found_and_journalled_like_the_truth() {
    let (_, truth) = demo();
    let t0 = f(&truth["start_unix_s"]);
    let want = truth["events"].as_array().unwrap();
    let (events, _, err) = replay_demo("");
    assert!(err.contains("event stage: clearance observer"), "{err}");
    assert!(
        err.contains(&format!("events={}", want.len())),
        "counters line: {err}"
    );
    assert_eq!(events.len(), want.len(), "{events:#?}");
    for (got, want) in events.iter().zip(want) {
        let dv = f(&got["v0_kmh"]) - f(&want["v0_kmh"]);
        assert!(dv.abs() < 3.0, "v0 off by {dv} km/h: {got} vs {want}");
        let dt = f(&got["t_start"]) - (t0 + f(&want["t_start_s"]));
        assert!(dt.abs() < 0.3, "onset off by {dt} s: {got} vs {want}");
        let dg = f(&got["decel_g"]) - f(&want["decel_g"]);
        assert!(dg.abs() < 0.05, "decel off by {dg} g: {got} vs {want}");
        // Inside the model's validity range: used, with a measured amplitude.
        assert_eq!(got["used"], true, "{got}");
        let amp = f(&got["sw_amplitude_deg"]);
        assert!(amp > 0.0 && amp < 1.0, "{got}");
        assert!(f(&got["odometer_km"]) > 0.0, "{got}");
    }
}

/// What the truth implies for the shimmy alert under "`confirm` of the last `window` events
/// in the speed window above `deg`".
fn truth_says_shimmy(truth: &serde_json::Value, confirm: usize, window: usize) -> bool {
    let in_window: Vec<f64> = truth["events"]
        .as_array()
        .unwrap()
        .iter()
        .filter(|e| (50.0..=60.0).contains(&f(&e["v0_kmh"])))
        .map(|e| f(&e["sw_amplitude_deg"]))
        .collect();
    let last = &in_window[in_window.len().saturating_sub(window)..];
    last.iter().filter(|&&a| a > 0.2).count() >= confirm
}

#[test]
fn shimmy_alert_follows_the_truth_through_the_default_confirmation_rule() {
    let (_, truth) = demo();
    // The demo has one braking event at 55 km/h and its true amplitude is above 0.2 deg ...
    let at55: Vec<_> = truth["events"]
        .as_array()
        .unwrap()
        .iter()
        .filter(|e| (50.0..=60.0).contains(&f(&e["v0_kmh"])))
        .collect();
    assert_eq!(at55.len(), 1);
    assert!(f(&at55[0]["sw_amplitude_deg"]) > 0.2);
    // ... so under the default "2 of the last 5" one event must not raise the alert.
    let expected = truth_says_shimmy(&truth, 2, 5);
    assert!(!expected);
    let (events, shimmy, _) = replay_demo("shimmy_confirm = 2\nshimmy_window = 5");
    assert_eq!(events.len(), 3);
    assert_eq!(!shimmy.is_empty(), expected, "{shimmy:#?}");
}

#[test]
fn a_vehicle_table_that_cannot_be_loaded_stops_shimmyd_at_start() {
    let (log, _) = demo();
    let dir = tempfile::tempdir().unwrap();
    let cfg = write_config(dir.path(), "table = \"no_such_table.json\"", "");
    let out = run(&cfg, &dir.path().join("state"), &log);
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(!out.status.success());
    assert!(err.contains("vehicle.table"), "{err}");
    assert!(
        !dir.path().join("journal").exists()
            || records(&dir.path().join("journal"))
                .iter()
                .all(|r| r["type"] != "event")
    );
}

/// With a response table (a small one built by `shimmy calibrate` from the model, seconds in a
/// release build) the amplitude is calibrated: under a 1-of-5 rule the truth's 0.25 deg at
/// 55 km/h must raise the shimmy alert, and the 0.2 mm joints (>= 0.12 mm, issue 6) must
/// raise the clearance alert with an interval that covers the true clearance.
#[test]
fn with_a_table_the_shimmy_and_clearance_alerts_follow_the_truth() {
    let (_, truth) = demo();
    let dir = tempfile::tempdir().unwrap();
    let table = dir.path().join("table.json");
    // One nuisance vehicle keeps the build small (2 pull-aways per clearance: the decelerations
    // of one speed share their pre-brake history, so it takes independent replicates, not
    // decelerations, to measure a one-vehicle cell's event scatter); with many the
    // vehicle-level likelihood (honestly) needs more than the demo's 3 events for 90 %.
    // The seed base is pinned: a one-vehicle table is a few draws of the wheels' unbalance
    // phases, and 3 events on it are decided by them (with the one-run-per-event generator
    // before the shared pull-away, six of seven bases tried gave P(c > 0.1 mm) >= 0.9).
    let out = Command::new(env!("CARGO_BIN_EXE_shimmy"))
        .args([
            "calibrate",
            "--clearances",
            "4",
            "--vehicles",
            "1",
            "--speeds",
            "40,55,75",
        ])
        .args([
            "--decels",
            "0.4,0.5,0.6",
            "--seeds",
            "2",
            "--seed-base",
            "1000000",
            "--threads",
            "2",
            "--out",
        ])
        .arg(&table)
        .output()
        .unwrap();
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );

    let expected = truth_says_shimmy(&truth, 1, 5);
    assert!(expected, "the demo's 55 km/h event is above 0.2 deg");
    // A one-vehicle table has no linear nuisance model and no nuisance mixture to widen it:
    // the mixture's tuned spread inflation (for the 40-vehicle table) would double-count, so
    // this test states the estimator's method and settings for its own table.
    let (events, alerts, estimates, err) = replay_demo_with(
        &format!("table = {table:?}"),
        "shimmy_confirm = 1\nshimmy_window = 5\n[observer.estimator]\nmethod = \"mixture\"\nstd_inflation = 1.0",
    );
    assert!(err.contains("clearance estimate"), "{err}");
    assert_eq!(events.len(), 3, "{events:#?}");
    let raised = |kind: &str| {
        alerts
            .iter()
            .filter(|r| r["alert"]["kind"] == kind && r["transition"] == "raised")
            .count()
    };
    assert_eq!(raised("shimmy_55kmh"), expected as usize, "{alerts:#?}");
    let c_true = f(&truth["clearance"]["left_mm_end"]);
    assert!(c_true >= 0.12);
    assert_eq!(
        raised("clearance"),
        1,
        "one alert, updated, not a storm: {alerts:#?}"
    );
    let last = &estimates.last().expect("an estimate per used event")["estimate"];
    assert_eq!(last["events_used"], 3, "{last}");
    let [lo, hi] = [f(&last["interval_mm"][0]), f(&last["interval_mm"][1])];
    assert!(lo <= c_true && c_true <= hi, "{last}");
    assert!(f(&last["p_above"]) >= 0.9, "{last}");
}
