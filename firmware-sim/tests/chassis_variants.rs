//! A profile's chassis variants, end to end: firmware-sim drives vehicles with the MODEL.md §15
//! column on the reference EPS bus, some built with a 10 mm kingpin scrub radius (MODEL.md §14)
//! that the profile's own chassis does not have, and `shimmy estimate`'s chain reads each log
//! with every torque table of profile `shimmy_reference_eps` (its own and its
//! `[[chassis.variants]]` one). A car with the scrub radius must be read with the variant's
//! table, a car without it with the nominal one, and the report must say which and why.

use std::path::{Path, PathBuf};

use clap::Parser;
use firmware_sim::fleet::{run, FleetArgs};
use serde_json::Value;

fn repo(rel: &str) -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR"))
        .join("..")
        .join(rel)
}

/// config/vehicle/default.toml with its [column] enabled and the scrub radius `scrub_m`.
fn plant(dir: &Path, scrub_m: f64) -> PathBuf {
    let text = std::fs::read_to_string(repo("config/vehicle/default.toml")).unwrap();
    let (head, tail) = text.split_once("[column]").expect("a [column] section");
    let tail = tail.replacen("enabled = false", "enabled = true", 1);
    let head = head.replacen(
        "scrub_radius_m = 0.0 ",
        &format!("scrub_radius_m = {scrub_m} "),
        1,
    );
    assert!(head.contains(&format!("scrub_radius_m = {scrub_m} ")));
    let path = dir.join("plant.toml");
    std::fs::write(&path, format!("{head}[column]{tail}")).unwrap();
    path
}

/// The fleet's per-vehicle results: `vehicles` vehicles at `clearance_mm` with a scrub radius
/// of `scrub_m`, read with the profile's torque tables, or with `torque_table` alone.
fn fleet(
    name: &str,
    scrub_m: f64,
    clearance_mm: f64,
    vehicles: usize,
    torque_table: Option<&str>,
) -> Vec<Value> {
    let dir = PathBuf::from(env!("CARGO_TARGET_TMPDIR")).join(format!("chassis_variants_{name}"));
    let _ = std::fs::remove_dir_all(&dir);
    std::fs::create_dir_all(&dir).unwrap();
    let json = dir.join("fleet.json");
    let plant = plant(&dir, scrub_m);
    let mut a: Vec<String> = [
        "fleet",
        "--profile",
        "shimmy_reference_eps",
        "--plant",
        plant.to_str().unwrap(),
        "--config",
        repo("config/observer.toml").to_str().unwrap(),
        "--vehicles",
        &vehicles.to_string(),
        "--events",
        "30",
        "--seed-base",
        "62000",
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
    if let Some(t) = torque_table {
        a.push("--torque-table".into());
        a.push(repo(t).display().to_string());
    }
    run(FleetArgs::parse_from(a)).unwrap();
    let v: Value = serde_json::from_str(&std::fs::read_to_string(&json).unwrap()).unwrap();
    v["vehicles"].as_array().unwrap().clone()
}

const VARIANT: &str = "scrub radius 10 mm";

/// The table a vehicle was read with, after checking the evidence block around it.
fn chosen(v: &Value) -> String {
    let tables = v["torque_tables"].as_array().expect("torque_tables");
    assert_eq!(tables.len(), 2, "{v}");
    let chosen: Vec<&Value> = tables.iter().filter(|t| t["chosen"] == true).collect();
    assert_eq!(chosen.len(), 1, "{v}");
    let weights: f64 = tables.iter().map(|t| t["weight"].as_f64().unwrap()).sum();
    assert!((weights - 1.0).abs() < 1e-9, "{v}");
    assert_eq!(v["torque_table"], chosen[0]["name"], "{v}");
    chosen[0]["name"].as_str().unwrap().to_string()
}

#[test]
fn a_car_with_a_scrub_radius_is_read_with_its_variants_table_and_a_nominal_car_with_its_own() {
    let scrub = fleet("scrub", 0.01, 0.085, 3, None);
    let nominal = fleet("nominal", 0.0, 0.085, 3, None);
    for v in &scrub {
        assert_eq!(chosen(v), VARIANT, "{v}");
        assert_eq!(v["signals"]["estimate_from"], "torque_nm", "{v}");
    }
    for v in &nominal {
        assert_eq!(chosen(v), "nominal", "{v}");
    }
    // Read with the nominal table alone, the scrub radius's steady shake passes for wear: the
    // same cars' estimates sit further from the truth than with the variant's table.
    let alone = fleet(
        "scrub_nominal_only",
        0.01,
        0.085,
        3,
        Some("config/vehicles/shimmy_reference_eps/table_torque.json"),
    );
    let err = |vs: &[Value]| -> f64 {
        vs.iter()
            .map(|v| (v["median_mm"].as_f64().unwrap() / 0.085).ln().abs())
            .sum::<f64>()
    };
    for v in &alone {
        assert!(v.get("torque_tables").is_none(), "{v}");
    }
    assert!(
        err(&scrub) < err(&alone),
        "variant {:?} vs nominal only {:?}",
        scrub.iter().map(|v| &v["median_mm"]).collect::<Vec<_>>(),
        alone.iter().map(|v| &v["median_mm"]).collect::<Vec<_>>()
    );
}
