//! What the fleet tests share: the repository's paths, the realistic plant file (MODEL.md §15
//! column enabled, optionally a scrub radius) and one `firmware-sim fleet` run read back as its
//! per-vehicle results.

#![allow(dead_code)]

use std::path::{Path, PathBuf};

use clap::Parser;
use firmware_sim::fleet::{run, FleetArgs};
use serde_json::Value;

pub fn repo(rel: &str) -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR"))
        .join("..")
        .join(rel)
}

/// config/vehicle/default.toml with its [column] enabled and, when given, the scrub radius
/// `scrub_m` (m), written as `dir/plant.toml`.
pub fn column_plant(dir: &Path, scrub_m: Option<f64>) -> PathBuf {
    let text = std::fs::read_to_string(repo("config/vehicle/default.toml")).unwrap();
    let (head, tail) = text.split_once("[column]").expect("a [column] section");
    let tail = tail.replacen("enabled = false", "enabled = true", 1);
    let head = match scrub_m {
        Some(s) => {
            let h = head.replacen(
                "scrub_radius_m = 0.0 ",
                &format!("scrub_radius_m = {s} "),
                1,
            );
            assert!(
                h.contains(&format!("scrub_radius_m = {s} ")),
                "no scrub_radius_m"
            );
            h
        }
        None => head.to_string(),
    };
    let path = dir.join("plant.toml");
    std::fs::write(&path, format!("{head}[column]{tail}")).unwrap();
    path
}

/// The fleet's arguments for simulating around `plant` and, where given, reading with the
/// repository's `torque_table` alone (`--plant FILE [--torque-table FILE]`).
pub fn plant_args(plant: &Path, torque_table: Option<&str>) -> Vec<String> {
    let mut args = vec!["--plant".to_string(), plant.display().to_string()];
    if let Some(t) = torque_table {
        args.push("--torque-table".into());
        args.push(repo(t).display().to_string());
    }
    args
}

/// `firmware-sim fleet --profile PROFILE --config config/observer.toml --vehicles N --events
/// 30 --seed-base SEED --clearance-mm C` in a fresh work directory named `name`, plus `extra`
/// (where `{column}` stands for [`column_plant`]'s file without a scrub radius); the
/// per-vehicle results of its JSON.
pub fn fleet(
    name: &str,
    profile: &str,
    seed: u64,
    clearance_mm: f64,
    vehicles: usize,
    extra: &[String],
) -> Vec<Value> {
    let dir = PathBuf::from(env!("CARGO_TARGET_TMPDIR")).join(name);
    let _ = std::fs::remove_dir_all(&dir);
    std::fs::create_dir_all(&dir).unwrap();
    let json = dir.join("fleet.json");
    let mut a: Vec<String> = [
        "fleet",
        "--profile",
        profile,
        "--config",
        repo("config/observer.toml").to_str().unwrap(),
        "--vehicles",
        &vehicles.to_string(),
        "--events",
        "30",
        "--seed-base",
        &seed.to_string(),
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
    a.extend(extra.iter().cloned());
    if a.iter().any(|s| s == "{column}") {
        let plant = column_plant(&dir, None);
        for s in a.iter_mut().filter(|s| *s == "{column}") {
            *s = plant.display().to_string();
        }
    }
    run(FleetArgs::parse_from(a)).unwrap();
    let v: Value = serde_json::from_str(&std::fs::read_to_string(&json).unwrap()).unwrap();
    v["vehicles"].as_array().unwrap().clone()
}
