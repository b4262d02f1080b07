//! Vehicle files: the shipped default equals MODEL.md §9, and bad values are rejected with the
//! key named.

use shimmy::model::VehicleParams;

fn workspace() -> std::path::PathBuf {
    std::path::PathBuf::from(env!("CARGO_MANIFEST_DIR"))
}

#[test]
fn default_toml_equals_model_md_defaults() {
    let p = VehicleParams::from_toml_file(workspace().join("config/vehicle/default.toml")).unwrap();
    assert_eq!(p, VehicleParams::default());
}

#[test]
fn partial_file_takes_defaults_for_missing_keys() {
    let p = VehicleParams::from_toml_str("[steering]\ncaster_trail_m = 0.03\n").unwrap();
    assert_eq!(p.steering.caster_trail_m, 0.03);
    assert_eq!(p.vehicle.mass_kg, 1350.0);
}

#[test]
fn bad_values_name_their_key() {
    for (text, key) in [
        ("[vehicle]\nmass_kg = -5.0\n", "vehicle.mass_kg"),
        (
            "[steering]\ntie_rod_mass_kg = 0.0\n",
            "steering.tie_rod_mass_kg",
        ),
        ("[joint]\nrestitution = 1.5\n", "joint.restitution"),
        (
            "[tire]\nlateral_stiffness_n_per_m = nan\n",
            "tire.lateral_stiffness_n_per_m",
        ),
    ] {
        let err = format!("{:#}", VehicleParams::from_toml_str(text).unwrap_err());
        assert!(err.contains(key), "{err}");
    }
    let err = format!(
        "{:#}",
        VehicleParams::from_toml_str("[vehicle]\nmas_kg = 1.0\n").unwrap_err()
    );
    assert!(err.contains("mas_kg"), "unknown keys are rejected: {err}");
}
