//! The observer's torque route, end to end: firmware-sim drives vehicles with the MODEL.md §15
//! steering column (rim, torsion bar, the driver's hands drawn per braking event) on the
//! reference bus with an EPS torque sensor (profile `shimmy_reference_eps`), and `shimmy
//! estimate`'s chain reads the logs with the profile's angle and torque tables. Where the log
//! carries a live torque the estimate must come from it and tell worn joints from tight ones;
//! a plant without the column (a steady 0 on the torque) must fall back to the angle; and
//! `--angle-only` must leave the torque out.

use std::path::PathBuf;

use clap::Parser;
use firmware_sim::fleet::{run, FleetArgs};
use serde_json::Value;

fn repo(rel: &str) -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR"))
        .join("..")
        .join(rel)
}

/// config/vehicle/default.toml with its [column] enabled.
fn column_plant(dir: &std::path::Path) -> PathBuf {
    let text = std::fs::read_to_string(repo("config/vehicle/default.toml")).unwrap();
    let (head, tail) = text.split_once("[column]").expect("a [column] section");
    let tail = tail.replacen("enabled = false", "enabled = true", 1);
    let path = dir.join("column.toml");
    std::fs::write(&path, format!("{head}[column]{tail}")).unwrap();
    path
}

/// The fleet's per-vehicle results for `vehicles` vehicles at `clearance_mm`.
fn fleet(name: &str, clearance_mm: f64, vehicles: usize, extra: &[String]) -> Vec<Value> {
    let dir = PathBuf::from(env!("CARGO_TARGET_TMPDIR")).join(format!("torque_route_{name}"));
    let _ = std::fs::remove_dir_all(&dir);
    std::fs::create_dir_all(&dir).unwrap();
    let json = dir.join("fleet.json");
    let mut a: Vec<String> = [
        "fleet",
        "--profile",
        "shimmy_reference_eps",
        "--config",
        repo("config/observer.toml").to_str().unwrap(),
        "--vehicles",
        &vehicles.to_string(),
        "--events",
        "30",
        "--seed-base",
        "61000",
        "--clearance-mm",
        &clearance_mm.to_string(),
        "--work-dir",
        dir.to_str().unwrap(),
        "--json",
        json.to_str().unwrap(),
    ]
    .iter()
    .map(|s| s.to_string())
    .collect();
    a.extend(
        extra
            .iter()
            .map(|s| s.replace("{dir}", dir.to_str().unwrap())),
    );
    if a.iter().any(|s| s == "{column}") {
        let plant = column_plant(&dir);
        for s in a.iter_mut().filter(|s| *s == "{column}") {
            *s = plant.display().to_string();
        }
    }
    run(FleetArgs::parse_from(a)).unwrap();
    let v: Value = serde_json::from_str(&std::fs::read_to_string(&json).unwrap()).unwrap();
    v["vehicles"].as_array().unwrap().clone()
}

fn column() -> Vec<String> {
    vec!["--plant".into(), "{column}".into()]
}

#[test]
fn worn_joints_on_a_realistic_steering_are_found_from_the_torque() {
    let worn = fleet("worn", 0.3, 3, &column());
    let tight = fleet("tight", 0.04, 3, &column());
    for v in worn.iter().chain(&tight) {
        let s = &v["signals"];
        assert_eq!(s["estimate_from"], "torque_nm", "{v}");
        assert!(s["events_used_torque"].as_u64().unwrap() >= 25, "{v}");
    }
    for v in &worn {
        assert_eq!(v["clearance_alert"], true, "a 0.3 mm joint: {v}");
        let [lo, hi] = [0, 1].map(|i| v["interval_mm"][i].as_f64().unwrap());
        assert!(lo > 0.1 && hi > 0.2, "{v}");
    }
    for v in &tight {
        assert_eq!(v["clearance_alert"], false, "a 0.04 mm joint: {v}");
        assert!(v["median_mm"].as_f64().unwrap() < 0.08, "{v}");
    }
}

#[test]
fn without_a_torsion_bar_the_estimate_falls_back_to_the_angle() {
    // The 5-DOF plant has no column: its torque sensor reads a steady 0.
    let v = fleet("five_dof", 0.3, 1, &[]).remove(0);
    assert_eq!(v["signals"]["estimate_from"], "angle_deg", "{v}");
    assert_eq!(v["signals"]["events_used_torque"], 0, "{v}");
    assert!(
        v["signals"]["events_without_torque"].as_u64().unwrap() >= 25,
        "{v}"
    );
    assert!(v["events_used"].as_u64().unwrap() >= 25, "{v}");
    // --angle-only: the torque table is not loaded at all.
    let mut a = column();
    a.push("--angle-only".into());
    let v = fleet("angle_only", 0.3, 1, &a).remove(0);
    assert!(v.get("signals").is_none(), "{v}");
}
