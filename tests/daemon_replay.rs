//! shimmyd end to end as a process: replay of the real RAV4 log (no braking: no events, no
//! alerts, counters reported), state persisted and resumed across runs, SIGTERM mid-replay
//! stops cleanly with the journal closed and the state saved.

use std::path::{Path, PathBuf};
use std::process::{Command, Stdio};
use std::time::{Duration, Instant};

use shimmy::journal::Reader;

fn workspace() -> &'static Path {
    Path::new(env!("CARGO_MANIFEST_DIR"))
}

fn write_config(dir: &Path, dbc: &Path, mapping: &Path) -> PathBuf {
    let p = dir.join("shimmyd.toml");
    std::fs::write(
        &p,
        format!(
            "[input]\ndbc = {:?}\nmapping = {:?}\n[outputs]\njournal_dir = \"journal\"\nstate_dir = \"state\"\n[log]\ncounters_interval_s = 1\n",
            dbc, mapping
        ),
    )
    .unwrap();
    p
}

fn records(dir: &Path) -> Vec<serde_json::Value> {
    let mut r = Reader::open(dir).unwrap();
    let v: Vec<_> = (&mut r).map(|e| e.unwrap().rec).collect();
    assert_eq!(r.invalid_lines(), 0, "{:?}", r.problems());
    v
}

fn rav4() -> Option<(PathBuf, PathBuf)> {
    let log = shimmy::shared_data::require_file("logs/comma2k19-rav4/rav4_2017_seg40_bus0.log")?;
    let dbc = shimmy::shared_data::require_file("dbc/opendbc/toyota_new_mc_pt_generated.dbc")?;
    Some((log, dbc))
}

/// shimmyd's configuration for the RAV4 log in `dir`: its DBC, the RAV4 profile's mapping.
fn rav4_config(dir: &Path, dbc: &Path) -> PathBuf {
    write_config(
        dir,
        dbc,
        &workspace().join("config/vehicles/toyota_rav4/mapping.toml"),
    )
}

/// shimmyd replaying `log` as fast as it can with `cfg`: whether it succeeded, its stderr.
fn replay_fast(cfg: &Path, log: &Path) -> (bool, String) {
    let out = Command::new(env!("CARGO_BIN_EXE_shimmyd"))
        .arg("--config")
        .arg(cfg)
        .arg("--replay")
        .arg(log)
        .arg("--fast")
        .output()
        .unwrap();
    (
        out.status.success(),
        String::from_utf8_lossy(&out.stderr).to_string(),
    )
}

#[test]
fn rav4_log_raises_nothing_reports_counters_and_state_resumes() {
    let Some((log, dbc)) = rav4() else { return };
    let dir = tempfile::tempdir().unwrap();
    let cfg = rav4_config(dir.path(), &dbc);
    let run = || {
        let (ok, err) = replay_fast(&cfg, &log);
        assert!(ok, "{err}");
        err
    };
    let err = run();
    assert!(
        err.contains("stopped: frames=53800 decode_errors=0 invalid_messages=0 events=0"),
        "{err}"
    );
    let recs = records(&dir.path().join("journal"));
    let types: Vec<&str> = recs.iter().map(|r| r["type"].as_str().unwrap()).collect();
    assert_eq!(types, ["start", "stop"], "no event, no alert");
    let stop = &recs[1];
    assert_eq!(stop["counters"]["frames"], 53800);
    let steer = stop["messages"]
        .as_array()
        .unwrap()
        .iter()
        .find(|m| m["name"] == "STEER_ANGLE_SENSOR")
        .unwrap();
    assert_eq!(steer["accepted"], 4974);
    let odo1 = stop["odometer_km"].as_f64().unwrap();
    // About a minute of driving: the odometer moved, by a plausible amount.
    assert!(odo1 > 0.3 && odo1 < 3.0, "odometer {odo1} km");
    let state: serde_json::Value =
        serde_json::from_slice(&std::fs::read(dir.path().join("state/state.json")).unwrap())
            .unwrap();
    assert_eq!(state["odometer_km"].as_f64(), Some(odo1));

    // Second run resumes the state: the odometer continues, the journal continues.
    run();
    let recs = records(&dir.path().join("journal"));
    assert_eq!(recs.len(), 4);
    assert_eq!(recs[2]["resumed_state"], true);
    assert_eq!(recs[2]["odometer_km"].as_f64(), Some(odo1));
    let odo2 = recs[3]["odometer_km"].as_f64().unwrap();
    assert!((odo2 - 2.0 * odo1).abs() < 1e-6, "{odo2} vs 2 x {odo1}");
}

#[test]
fn sigterm_mid_replay_stops_cleanly() {
    let Some((log, dbc)) = rav4() else { return };
    let dir = tempfile::tempdir().unwrap();
    let cfg = rav4_config(dir.path(), &dbc);
    // Recorded timing: the log lasts about a minute, so the daemon is still running when told
    // to stop.
    let child = Command::new(env!("CARGO_BIN_EXE_shimmyd"))
        .arg("--config")
        .arg(&cfg)
        .arg("--replay")
        .arg(&log)
        .stderr(Stdio::piped())
        .spawn()
        .unwrap();
    std::thread::sleep(Duration::from_millis(1500));
    let t0 = Instant::now();
    let st = Command::new("kill")
        .args(["-TERM", &child.id().to_string()])
        .status()
        .unwrap();
    assert!(st.success());
    let out = child.wait_with_output().unwrap();
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(out.status.success(), "{err}");
    assert!(
        t0.elapsed() < Duration::from_secs(5),
        "took {:?} to stop",
        t0.elapsed()
    );
    assert!(err.contains("SIGTERM: stopping"), "{err}");
    // The periodic counters line (interval 1 s in this config) was logged while running.
    assert!(err.contains("last 1 s: frames="), "{err}");
    let recs = records(&dir.path().join("journal"));
    let stop = recs.last().unwrap();
    assert_eq!(stop["type"], "stop");
    let frames = stop["counters"]["frames"].as_u64().unwrap();
    assert!(
        frames > 100 && frames < 53800,
        "replayed {frames} frames before SIGTERM"
    );
    assert!(dir.path().join("state/state.json").is_file());
}

#[test]
fn corrupt_state_is_moved_aside_and_reported() {
    let Some((log, dbc)) = rav4() else { return };
    let dir = tempfile::tempdir().unwrap();
    let cfg = rav4_config(dir.path(), &dbc);
    std::fs::create_dir_all(dir.path().join("state")).unwrap();
    std::fs::write(
        dir.path().join("state/state.json"),
        b"{\"odometer_km\": 12.5, \"ev",
    )
    .unwrap();
    let (ok, err) = replay_fast(&cfg, &log);
    assert!(ok, "{err}");
    assert!(
        err.contains("did not parse") && err.contains("state.json.bad-"),
        "{err}"
    );
    let aside = std::fs::read_dir(dir.path().join("state"))
        .unwrap()
        .filter(|e| {
            e.as_ref()
                .unwrap()
                .file_name()
                .to_string_lossy()
                .starts_with("state.json.bad-")
        })
        .count();
    assert_eq!(aside, 1);
}

#[test]
fn sighup_reloads_alerts_and_keeps_running_config_when_broken() {
    let Some((log, dbc)) = rav4() else { return };
    let dir = tempfile::tempdir().unwrap();
    let cfg = rav4_config(dir.path(), &dbc);
    let good = std::fs::read_to_string(&cfg).unwrap();
    let mut child = Command::new(env!("CARGO_BIN_EXE_shimmyd"))
        .arg("--config")
        .arg(&cfg)
        .arg("--replay")
        .arg(&log)
        .stderr(Stdio::piped())
        .spawn()
        .unwrap();
    let signal = |sig: &str| {
        assert!(Command::new("kill")
            .args([sig, &child.id().to_string()])
            .status()
            .unwrap()
            .success())
    };
    std::thread::sleep(Duration::from_millis(800));
    std::fs::write(
        &cfg,
        good.replace("[log]", "[alerts]\nshimmy_deg = -1\n[log]"),
    )
    .unwrap();
    signal("-HUP");
    std::thread::sleep(Duration::from_millis(600));
    std::fs::write(
        &cfg,
        good.replace("[log]", "[alerts]\nshimmy_deg = 0.3\n[log]"),
    )
    .unwrap();
    signal("-HUP");
    std::thread::sleep(Duration::from_millis(600));
    signal("-TERM");
    let status = child.wait().unwrap();
    let mut err = String::new();
    std::io::Read::read_to_string(child.stderr.as_mut().unwrap(), &mut err).unwrap();
    assert!(status.success(), "{err}");
    assert!(
        err.contains("SIGHUP: configuration not reloaded")
            && err.contains("alerts.shimmy_deg: must be > 0"),
        "{err}"
    );
    assert!(err.contains("SIGHUP: configuration reloaded"), "{err}");
    let recs = records(&dir.path().join("journal"));
    let reload = recs
        .iter()
        .find(|r| r["type"] == "reload")
        .expect("reload journaled");
    assert_eq!(reload["alerts"]["shimmy_deg"], 0.3);
}

/// Recorded-timing replay keeps the log's timing while pacing in slices: 2 s of frames at
/// 8,000 frames/s (1 Mbit/s classic CAN) take about 2 s, none is lost, and the counters line
/// of the first second has seen only part of them.
#[test]
fn recorded_timing_replay_keeps_the_logs_pace_at_bus_rate() {
    let dir = tempfile::tempdir().unwrap();
    let log = dir.path().join("busload.log");
    let mut text = String::new();
    for k in 0..16_000u32 {
        let t = 1_767_225_600.0 + f64::from(k) * 125e-6;
        text += &format!("({t:.6}) vcan0 123#{:08X}\n", k);
    }
    std::fs::write(&log, text).unwrap();
    let cfg = write_config(
        dir.path(),
        &workspace().join("dbc/shimmy_reference.dbc"),
        &workspace().join("config/vehicles/shimmy_reference/mapping.toml"),
    );
    let t0 = Instant::now();
    let out = Command::new(env!("CARGO_BIN_EXE_shimmyd"))
        .arg("--config")
        .arg(&cfg)
        .arg("--replay")
        .arg(&log)
        .output()
        .unwrap();
    let took = t0.elapsed();
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(out.status.success(), "{err}");
    assert!(
        took >= Duration::from_millis(1950) && took < Duration::from_secs(8),
        "2 s of log replayed in {took:?}"
    );
    assert!(err.contains("stopped: frames=16000 "), "{err}");
    let first = err
        .lines()
        .find(|l| l.contains("last 1 s: frames="))
        .unwrap_or_else(|| panic!("no counters line: {err}"));
    let n: u64 = first
        .split("frames=")
        .nth(1)
        .and_then(|s| s.split_whitespace().next())
        .and_then(|s| s.parse().ok())
        .unwrap();
    assert!(n < 16_000, "first second already saw {n} frames: {first}");
}

/// `outputs.transmit = true` on a replay sends nothing and says so; the car's DBC need not carry
/// SHIMMY_01 then (only a live bus is sent on), and the replay reads as it does without it.
#[test]
fn transmit_on_a_replay_sends_nothing_and_says_so() {
    let Some((log, dbc)) = rav4() else { return };
    let dir = tempfile::tempdir().unwrap();
    let cfg = rav4_config(dir.path(), &dbc);
    let text = std::fs::read_to_string(&cfg).unwrap().replace(
        "[outputs]\n",
        "[outputs]\ntransmit = true\ntransmit_interface = \"vcan0\"\n",
    );
    std::fs::write(&cfg, text).unwrap();
    let (ok, err) = replay_fast(&cfg, &log);
    assert!(ok, "{err}");
    assert!(
        err.contains("outputs.transmit is set but this is a replay: nothing is sent"),
        "{err}"
    );
    assert!(!err.contains("transmitting SHIMMY_01"), "{err}");
    assert!(!records(&dir.path().join("journal")).is_empty());
}
