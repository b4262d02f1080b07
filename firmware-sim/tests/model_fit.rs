//! The estimator's goodness-of-fit check (src/observer/fit.rs) through the whole chain: a
//! vehicle the response table's model describes fits, and the same vehicle built with a
//! scrub radius the table's model does not have (`firmware-sim fleet --plant`) is reported as
//! not fitting, instead of only getting an interval that misses its clearance. With the
//! profile's chassis variants, one of which has that scrub radius, it is read with that
//! variant's table and fits.

use std::path::PathBuf;

use clap::Parser;
use firmware_sim::fleet::{run, FleetArgs};

fn repo(rel: &str) -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR"))
        .join("..")
        .join(rel)
}

/// One 30-event vehicle of seed 93237 (clearance 0.34 mm) on the reference bus, scored with
/// the reference table alone (`nominal_only`) or with the profile's tables (its own and its
/// chassis variants'); `plant` replaces the simulated vehicle.
fn vehicle(name: &str, plant: Option<&PathBuf>, nominal_only: bool) -> serde_json::Value {
    let dir = PathBuf::from(env!("CARGO_TARGET_TMPDIR")).join(format!("model_fit_{name}"));
    let _ = std::fs::remove_dir_all(&dir);
    let json = dir.join("fleet.json");
    let mut a: Vec<String> = [
        "fleet",
        "--profile",
        "shimmy_reference",
        "--vehicles",
        "1",
        "--events",
        "30",
        "--seed-base",
        "93237",
        "--threads",
        "1",
    ]
    .iter()
    .map(|s| s.to_string())
    .collect();
    a.extend([
        "--work-dir".into(),
        dir.display().to_string(),
        "--json".into(),
        json.display().to_string(),
    ]);
    if let Some(p) = plant {
        a.extend(["--plant".into(), p.display().to_string()]);
    }
    if nominal_only {
        let t = repo("config/vehicles/shimmy_reference/table.json");
        a.extend(["--table".into(), t.display().to_string()]);
    }
    run(FleetArgs::parse_from(a)).unwrap();
    let v: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(&json).unwrap()).unwrap();
    v["vehicles"][0].clone()
}

#[test]
fn a_vehicle_off_the_model_is_said_not_to_fit() {
    let nominal = vehicle("nominal", None, true);
    let fit = &nominal["model_fit"];
    assert_eq!(fit["fits"], true, "{nominal}");
    assert!(fit["dof"].as_f64().unwrap() >= 60.0, "{nominal}");

    // The same draws around a vehicle with a 10 mm scrub radius (the table's has none).
    let text = std::fs::read_to_string(repo("config/vehicle/default.toml")).unwrap();
    let plant_text = text.replace("scrub_radius_m = 0.0 ", "scrub_radius_m = 0.010 ");
    assert_ne!(text, plant_text, "the scrub radius key moved");
    let plant = PathBuf::from(env!("CARGO_TARGET_TMPDIR")).join("model_fit_scrub10.toml");
    std::fs::write(&plant, plant_text).unwrap();
    let off = vehicle("scrub10", Some(&plant), true);
    let fit = &off["model_fit"];
    assert_eq!(fit["fits"], false, "{off}");
    assert!(
        fit["z"].as_f64().unwrap() > nominal["model_fit"]["z"].as_f64().unwrap() + 3.0,
        "{off} vs {nominal}"
    );
    // The profile's scrub-radius variant describes it.
    let variant = vehicle("scrub10_variants", Some(&plant), false);
    assert_eq!(variant["angle_table"], "scrub radius 10 mm", "{variant}");
    assert_eq!(variant["model_fit"]["fits"], true, "{variant}");
}
