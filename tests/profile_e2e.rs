//! The car as the unit a user deals with, end to end: a simulated drive on a real car's bus
//! (firmware-sim `--profile`) gets a clearance estimate from the shipped profile without any
//! calibration step, named by profile or found by identifying the bus, by `shimmy estimate`,
//! by shimmyd with `[input] profile` and by shimmyd that is told nothing about the car.

#[path = "e2e_common/mod.rs"]
mod e2e_common;

use std::path::{Path, PathBuf};
use std::process::Command;

use e2e_common::{firmware_sim, shimmyd, workspace, Journal};
use serde_json::Value;

/// firmware-sim's worn_0p2mm drive (0.2 mm joints, three stops) on `profile`'s bus.
fn drive(profile: &str, dir: &Path) -> PathBuf {
    let log = dir.join(format!("{profile}.log"));
    let out = Command::new(firmware_sim())
        .current_dir(workspace())
        .args([
            "--scenario",
            "config/scenarios/worn_0p2mm.toml",
            "--profile",
            profile,
            "--out",
        ])
        .arg(&log)
        .output()
        .unwrap();
    assert!(
        out.status.success(),
        "firmware-sim --profile {profile}: {}",
        String::from_utf8_lossy(&out.stderr)
    );
    log
}

fn estimate(args: &[&str], log: &Path) -> (Value, String) {
    let out = Command::new(env!("CARGO_BIN_EXE_shimmy"))
        .current_dir(workspace())
        .arg("estimate")
        .args(args)
        .arg(log)
        .output()
        .unwrap();
    let err = String::from_utf8_lossy(&out.stderr).to_string();
    assert!(out.status.success(), "shimmy estimate {args:?}: {err}");
    (serde_json::from_slice(&out.stdout).unwrap(), err)
}

/// The RAV4 drive is estimated with the RAV4 profile as shipped: its table fits the bus's
/// 82.9 Hz sensor (no event is refused), the 0.2 mm joints read as worn, and without
/// `--profile` the car is identified and the answer is the same.
#[test]
fn a_rav4_drive_gets_a_clearance_estimate_from_the_shipped_profile() {
    if shimmy::shared_data::require("the RAV4 profile's opendbc DBC").is_none() {
        return;
    }
    let dir = tempfile::tempdir().unwrap();
    let log = drive("toyota_rav4", dir.path());
    let (r, _) = estimate(&["--profile", "toyota_rav4"], &log);
    assert_eq!(r["profile"], "toyota_rav4");
    assert_eq!(r["events_used"], 3, "{}", r["verdict"]);
    assert_eq!(r["events_sensor_mismatch"], 0);
    let [lo, hi] = [r["interval_mm"][0].as_f64(), r["interval_mm"][1].as_f64()];
    let (lo, hi) = (lo.expect("an interval"), hi.expect("an interval"));
    assert!(lo < 0.2 && 0.2 < hi, "0.2 mm outside [{lo}, {hi}]");
    assert!(
        r["p_clearance_above_threshold"].as_f64().unwrap() > 0.5,
        "{}",
        r["verdict"]
    );
    let (found, err) = estimate(&[], &log);
    assert!(err.contains("identified: toyota_rav4"), "{err}");
    assert_eq!(found["profile"], "toyota_rav4");
    assert_eq!(found["median_mm"], r["median_mm"]);
}

/// Every shipped profile's bus, simulated, yields its braking events through its own profile.
#[test]
fn every_profile_finds_the_braking_events_on_its_own_bus() {
    if shimmy::shared_data::require("the profiles' opendbc DBCs").is_none() {
        return;
    }
    let dir = tempfile::tempdir().unwrap();
    for p in ["vw_mqb", "honda_civic", "hyundai_kia"] {
        let log = drive(p, dir.path());
        let (r, _) = estimate(&["--profile", p], &log);
        assert_eq!(r["profile"], p);
        assert_eq!(r["events_used"], 3, "{p}: {}", r["verdict"]);
        assert!(r["interval_mm"][0].is_number(), "{p}: {}", r["verdict"]);
    }
}

fn write_config(dir: &Path, input: &str) -> PathBuf {
    let p = dir.join("shimmyd.toml");
    std::fs::write(
        &p,
        format!(
            "[input]\n{input}\n[outputs]\njournal_dir = \"journal\"\nstate_dir = \"state\"\n\
             [log]\ncounters_interval_s = 1\n"
        ),
    )
    .unwrap();
    p
}

fn replay(cfg: &Path, log: &Path) -> String {
    let out = Command::new(shimmyd())
        .current_dir(workspace())
        .arg("--config")
        .arg(cfg)
        .arg("--replay")
        .arg(log)
        .arg("--fast")
        .output()
        .unwrap();
    let err = String::from_utf8_lossy(&out.stderr).to_string();
    assert!(out.status.success(), "shimmyd: {err}");
    err
}

/// shimmyd with `[input] profile = "toyota_rav4"`, and shimmyd told nothing about the car,
/// which identifies it from the replayed bus, say so, and journal the same estimate.
#[test]
fn shimmyd_runs_on_a_profile_named_or_identified_from_the_bus() {
    if shimmy::shared_data::require("the RAV4 profile's opendbc DBC").is_none() {
        return;
    }
    let dir = tempfile::tempdir().unwrap();
    let log = drive("toyota_rav4", dir.path());
    let named = dir.path().join("named");
    let unnamed = dir.path().join("unnamed");
    std::fs::create_dir_all(&named).unwrap();
    std::fs::create_dir_all(&unnamed).unwrap();
    let err = replay(&write_config(&named, "profile = \"toyota_rav4\""), &log);
    assert!(err.contains("vehicle profile: toyota_rav4"), "{err}");
    let err_id = replay(&write_config(&unnamed, ""), &log);
    assert!(
        err_id.contains("car identified from its bus: identified: toyota_rav4"),
        "{err_id}"
    );
    let a = Journal::read(&named.join("journal"));
    let b = Journal::read(&unnamed.join("journal"));
    assert_eq!(a.events.len(), 3);
    assert_eq!(a.events.len(), b.events.len());
    let est = |j: &Journal| j.estimate.clone().expect("an estimate");
    // Three events of a car whose bus has no live torque: the angle's tables, mixed; the
    // interval holds the drive's 0.2 mm.
    let e = est(&a);
    let [lo, hi] = [e["interval_mm"][0].as_f64(), e["interval_mm"][1].as_f64()];
    let (lo, hi) = (lo.expect("an interval"), hi.expect("an interval"));
    assert!(lo < 0.2 && 0.2 < hi, "0.2 mm outside [{lo}, {hi}]: {e}");
    assert_eq!(est(&a), est(&b));
}
