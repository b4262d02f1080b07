//! `shimmy estimate LOG` and `shimmyd --replay LOG --fast` run the same monitor: for the demo
//! fixture and for a firmware-sim fleet of ten vehicles, both report the same braking events
//! (field by field, to rounding), the same final clearance estimate, and the same alerts
//! standing at the end of the log. They differ only in what they write (stdout JSON vs the
//! journal).

mod e2e_common;

use std::ffi::{OsStr, OsString};
use std::path::Path;
use std::process::Command;

use e2e_common::{estimate_profile, firmware_sim, replay_profile, workspace};
use serde_json::Value;

/// Equal numbers to `rel` of the larger (or equal JSON where not numbers).
fn same_number(a: &Value, b: &Value, what: &str, rel: f64) {
    match (a.as_f64(), b.as_f64()) {
        (Some(x), Some(y)) => assert!(
            (x - y).abs() <= rel * x.abs().max(y.abs()).max(1e-3),
            "{what}: estimate {x} vs shimmyd {y}"
        ),
        _ => assert_eq!(a, b, "{what}"),
    }
}

/// Events: the same computation on the same samples.
const EVENT_REL: f64 = 1e-9;
/// The estimate: the same evidence; the daemon places each event on its own odometer (kept
/// across restarts), `estimate` on the detector's, which agree to rounding.
const ESTIMATE_REL: f64 = 1e-9;

fn compare(log: &Path, dir: &Path) {
    compare_on("shimmy_reference", log, dir);
}

/// [`compare`] on the vehicle profile `profile`; returns `estimate`'s report.
fn compare_on(profile: &str, log: &Path, dir: &Path) -> Value {
    let e = estimate_profile(profile, log, None);
    let j = replay_profile(profile, log, dir, None);
    let what = log.display();
    let ev = e["events"].as_array().unwrap();
    assert_eq!(ev.len(), j.events.len(), "{what}: events");
    for (k, (a, b)) in ev.iter().zip(&j.events).enumerate() {
        for f in [
            "t_start",
            "t_end",
            "v0_kmh",
            "decel_g",
            "peak_sw_bp_deg",
            "sw_amplitude_deg",
        ] {
            same_number(&a[f], &b[f], &format!("{what}: event {k} {f}"), EVENT_REL);
        }
        assert_eq!(a["used"], b["used"], "{what}: event {k} used");
        assert_eq!(
            a["unused_reason"], b["unused_reason"],
            "{what}: event {k} unused_reason"
        );
    }
    let d = j.estimate.clone().unwrap_or(Value::Null);
    for (fe, fd) in [
        ("clearance_mm", "clearance_mm"),
        ("detectable", "detectable"),
        ("below_mm", "below_mm"),
        ("p_clearance_above_threshold", "p_above"),
        ("events_used", "events_used"),
    ] {
        same_number(
            &e[fe],
            &d[fd],
            &format!("{what}: estimate {fe}"),
            ESTIMATE_REL,
        );
    }
    for i in 0..2 {
        same_number(
            &e["interval_mm"][i],
            &d["interval_mm"][i],
            &format!("{what}: interval {i}"),
            ESTIMATE_REL,
        );
    }
    let mut kinds: Vec<String> = e["alerts"]
        .as_array()
        .unwrap()
        .iter()
        .map(|a| a["kind"].as_str().unwrap().to_string())
        .collect();
    kinds.sort();
    assert_eq!(kinds, j.kinds_standing(), "{what}: alerts at the end");
    e
}

#[test]
fn the_demo_fixture_gives_the_same_events_estimate_and_alerts() {
    let dir = tempfile::tempdir().unwrap();
    compare(
        &workspace().join("tests/fixtures/demo/worn_0p2mm.log"),
        dir.path(),
    );
}

/// `firmware-sim fleet --logs-only` of `vehicles` × `events` from `seed` on `profile`, plus
/// `extra` arguments; the logs' directory.
fn fleet_logs(
    dir: &Path,
    profile: &str,
    vehicles: u32,
    events: u32,
    seed: u64,
    extra: &[&OsStr],
) -> std::path::PathBuf {
    let logs = dir.join("fleet");
    let out = Command::new(firmware_sim())
        .current_dir(workspace())
        .args(["fleet", "--profile", profile, "--logs-only"])
        .args([
            "--vehicles",
            &vehicles.to_string(),
            "--events",
            &events.to_string(),
        ])
        .args(["--seed-base", &seed.to_string()])
        .args(extra)
        .arg("--work-dir")
        .arg(&logs)
        .output()
        .unwrap();
    assert!(
        out.status.success(),
        "firmware-sim fleet: {}",
        String::from_utf8_lossy(&out.stderr)
    );
    logs
}

#[test]
fn a_fleet_of_ten_gives_the_same_events_estimate_and_alerts_on_every_vehicle() {
    let dir = tempfile::tempdir().unwrap();
    let logs = fleet_logs(dir.path(), "shimmy_reference", 10, 5, 77000, &[]);
    for k in 0..10 {
        let log = logs.join(format!("fleet_{}.log", 77000 + k));
        compare(&log, &dir.path().join(format!("run{k}")));
    }
}

/// With a torque table (the reference bus with an EPS torque, vehicles with the MODEL.md §15
/// column): both estimate from the torque, and agree.
#[test]
fn vehicles_with_a_steering_column_give_the_same_torque_estimate() {
    let dir = tempfile::tempdir().unwrap();
    let plant = e2e_common::column_vehicle(dir.path());
    let extra = ["--plant".as_ref(), plant.as_os_str()];
    let logs = fleet_logs(dir.path(), "shimmy_reference_eps", 3, 6, 77100, &extra);
    for k in 0..3 {
        let log = logs.join(format!("fleet_{}.log", 77100 + k));
        let e = compare_on(
            "shimmy_reference_eps",
            &log,
            &dir.path().join(format!("run{k}")),
        );
        assert_eq!(
            e["signals"]["estimate_from"],
            "torque_nm",
            "{}",
            log.display()
        );
    }
}

/// The fleet arguments for vehicles of `vehicle` (a MODEL.md §9 file) with a 10 mm scrub radius,
/// written to `plant`, at 0.2 mm.
fn worn_with_scrub_radius(vehicle: &Path, plant: &Path) -> Vec<OsString> {
    let text = std::fs::read_to_string(vehicle).unwrap();
    let scrub = text.replacen("scrub_radius_m = 0.0 ", "scrub_radius_m = 0.01 ", 1);
    assert_ne!(text, scrub, "the vehicle file sets scrub_radius_m");
    std::fs::write(plant, scrub).unwrap();
    [
        "--plant".into(),
        plant.into(),
        "--clearance-mm".into(),
        "0.2".into(),
    ]
    .to_vec()
}

/// The name of the table `estimate`'s report says it read the estimate mostly with, among its
/// `key` (`torque_tables` or `angle_tables`).
fn chosen_table(e: &Value, key: &str) -> String {
    e[key]
        .as_array()
        .unwrap_or_else(|| panic!("no {key}: {e}"))
        .iter()
        .find(|t| t["chosen"] == true)
        .map(|t| t["name"].as_str().unwrap().to_string())
        .expect("a chosen table")
}

/// The same on the 5-DOF reference bus, whose profile's chassis variants name angle tables:
/// a vehicle with a 10 mm scrub radius is read by both with the variant's angle table, and
/// they agree on the estimate.
#[test]
fn vehicles_with_a_scrub_radius_are_read_with_the_same_angle_variant() {
    let dir = tempfile::tempdir().unwrap();
    let plant = dir.path().join("scrub.toml");
    let default = workspace().join("config/vehicle/default.toml");
    let extra = worn_with_scrub_radius(&default, &plant);
    let extra: Vec<&OsStr> = extra.iter().map(|a| a.as_os_str()).collect();
    let logs = fleet_logs(dir.path(), "shimmy_reference", 1, 20, 77300, &extra);
    let log = logs.join("fleet_77300.log");
    let run = dir.path().join("run0");
    let e = compare_on("shimmy_reference", &log, &run);
    assert!(e.get("torque_tables").is_none(), "{e}");
    let chosen = chosen_table(&e, "angle_tables");
    assert_eq!(chosen, "scrub radius 10 mm", "{}", e["angle_tables"]);
    let j = e2e_common::Journal::read(&run.join("journal"));
    let daemon = j.estimate.unwrap_or(Value::Null)["chassis_variant"].clone();
    assert_eq!(daemon, chosen.as_str(), "{}", log.display());
    assert!(
        e["verdict"].as_str().unwrap().contains(&chosen),
        "{}",
        e["verdict"]
    );
}

/// With a chassis variant (the reference EPS profile's 10 mm scrub radius) on vehicles that
/// have it: both read the same table, `estimate`'s report naming it among its torque tables
/// and shimmyd's estimate carrying it as the chassis variant, and agree on the estimate.
#[test]
fn vehicles_with_a_scrub_radius_are_read_with_the_same_chassis_variant() {
    let dir = tempfile::tempdir().unwrap();
    let plant = e2e_common::column_vehicle(dir.path());
    let extra = worn_with_scrub_radius(&plant, &plant);
    let extra: Vec<&OsStr> = extra.iter().map(|a| a.as_os_str()).collect();
    let logs = fleet_logs(dir.path(), "shimmy_reference_eps", 2, 20, 77200, &extra);
    let mut variants = 0;
    for k in 0..2 {
        let log = logs.join(format!("fleet_{}.log", 77200 + k));
        let run = dir.path().join(format!("run{k}"));
        let e = compare_on("shimmy_reference_eps", &log, &run);
        let chosen = chosen_table(&e, "torque_tables");
        let j = e2e_common::Journal::read(&run.join("journal"));
        let daemon = j.estimate.unwrap_or(Value::Null)["chassis_variant"].clone();
        if chosen == "nominal" {
            assert!(daemon.is_null(), "{}: {daemon}", log.display());
        } else {
            assert_eq!(daemon, chosen.as_str(), "{}", log.display());
            assert!(
                e["verdict"].as_str().unwrap().contains(&chosen),
                "{}",
                e["verdict"]
            );
            variants += 1;
        }
    }
    assert!(
        variants >= 1,
        "no vehicle with a scrub radius read with its variant's table"
    );
}

/// A profile whose chassis variants carry an angle table beside their torque table (the VW
/// MQB's, whose angle tables are the reference bus's): a 5-DOF car with a scrub radius, whose
/// bus has no live torque, is read by both with the variant's angle table; a car with the
/// MODEL.md §15 column, whose torque is live from its first event, is read from the torque,
/// and the angle's variants are never built (the report lists no angle tables), as the
/// torque's are not on the first car.
#[test]
fn a_torque_profile_reads_a_car_without_live_torque_with_its_angle_variants() {
    let dir = tempfile::tempdir().unwrap();
    let plant = dir.path().join("scrub.toml");
    let default = workspace().join("config/vehicle/default.toml");
    let extra = worn_with_scrub_radius(&default, &plant);
    let extra: Vec<&OsStr> = extra.iter().map(|a| a.as_os_str()).collect();
    let logs = fleet_logs(dir.path(), "vw_mqb", 1, 20, 77400, &extra);
    let log = logs.join("fleet_77400.log");
    let run = dir.path().join("run0");
    let e = compare_on("vw_mqb", &log, &run);
    assert_eq!(
        e["signals"]["estimate_from"], "angle_deg",
        "{}",
        e["signals"]
    );
    // The torque's variants are built at its first event: none here.
    assert!(e.get("torque_tables").is_none(), "{}", e["torque_tables"]);
    let chosen = chosen_table(&e, "angle_tables");
    assert_eq!(chosen, "scrub radius 10 mm", "{}", e["angle_tables"]);
    let j = e2e_common::Journal::read(&run.join("journal"));
    let daemon = j.estimate.unwrap_or(Value::Null)["chassis_variant"].clone();
    assert_eq!(daemon, chosen.as_str(), "{}", log.display());

    let dir = tempfile::tempdir().unwrap();
    let plant = e2e_common::column_vehicle(dir.path());
    let extra = ["--plant".as_ref(), plant.as_os_str()];
    let logs = fleet_logs(dir.path(), "vw_mqb", 1, 6, 77500, &extra);
    let log = logs.join("fleet_77500.log");
    let e = compare_on("vw_mqb", &log, &dir.path().join("run0"));
    assert_eq!(
        e["signals"]["estimate_from"], "torque_nm",
        "{}",
        e["signals"]
    );
    assert!(e.get("torque_tables").is_some(), "{e}");
    assert!(e.get("angle_tables").is_none(), "{}", e["angle_tables"]);
}
