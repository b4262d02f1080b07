//! The shipped vehicle profiles (config/vehicles): each loads, its mapping fits its DBC, and the
//! lookup by name, alias and path finds it.

use shimmy::dbc::Database;
use shimmy::profile::{self, Profile};
use shimmy::signals::Mapper;

const SHIPPED: [&str; 6] = [
    "shimmy_reference",
    "shimmy_reference_eps",
    "toyota_rav4",
    "vw_mqb",
    "honda_civic",
    "hyundai_kia",
];

fn repo(rel: &str) -> std::path::PathBuf {
    std::path::PathBuf::from(env!("CARGO_MANIFEST_DIR")).join(rel)
}

#[test]
fn every_shipped_profile_loads_and_its_mapping_fits_its_dbc() {
    // The opendbc DBCs live in the shared data; without it only the reference profile loads.
    let have_data = shimmy::shared_data::require("the opendbc DBCs of the profiles").is_some();
    for name in SHIPPED {
        if !have_data && !name.starts_with("shimmy_reference") {
            continue;
        }
        let p = Profile::load_dir(&repo(&format!("config/vehicles/{name}")))
            .unwrap_or_else(|e| panic!("{name}: {e:#}"));
        assert_eq!(p.name, name);
        let (db, _) = Database::load(&p.dbc_path).unwrap();
        let m = Mapper::new(&db, &p.mapping).unwrap_or_else(|e| panic!("{name}: {e:#}"));
        assert!(m.warnings().is_empty(), "{name}: {:?}", m.warnings());
        p.sensor.validate().unwrap();
        // Out of the box: the profile ships its table, built for its chassis, prior and sensor.
        let t = p
            .load_table()
            .unwrap_or_else(|e| panic!("{name}: {e:#}"))
            .unwrap_or_else(|| panic!("{name}: no table"));
        assert_eq!(t.sensor, p.sensor, "{name}");
        // A profile naming a torque table ships it, built for the torque its bus sends.
        if p.file.torque_table.is_some() {
            assert!(
                p.mapping.steer_torque.is_some(),
                "{name}: torque table, no torque"
            );
            let tt = p
                .load_torque_table()
                .unwrap_or_else(|e| panic!("{name}: {e:#}"))
                .unwrap_or_else(|| panic!("{name}: no torque table"));
            let sent = p
                .file
                .sensors
                .steer_torque
                .as_ref()
                .expect("[sensors.steer_torque]");
            assert_eq!(tt.sensor.rate_hz, sent.rate_hz, "{name}");
            assert_eq!(tt.clearance_mm, t.clearance_mm, "{name}");
        }
    }
}

/// A torque table is refused where it does not belong: as an angle table, for a chassis
/// without the column's hash, or for a torque sent at another rate.
#[test]
fn a_torque_table_is_checked_against_the_profiles_torque() {
    let p = Profile::load("shimmy_reference_eps").unwrap();
    let t = p.load_torque_table().unwrap().expect("shipped");
    p.check_torque_table(&t).unwrap();
    let e = format!("{:#}", p.check_table(&t).unwrap_err());
    assert!(e.contains("hash") || e.contains("vehicle"), "{e}");
    let angle = p.load_table().unwrap().unwrap();
    let e = format!("{:#}", p.check_torque_table(&angle).unwrap_err());
    assert!(e.contains("not of the torque"), "{e}");
    let mut slow = p.clone();
    slow.file.sensors.steer_torque.as_mut().unwrap().rate_hz = 50.0;
    let e = format!("{:#}", slow.check_torque_table(&t).unwrap_err());
    assert!(e.contains("50 Hz"), "{e}");
    let mut other = p.clone();
    other.vehicle.steering.kingpin_stiffness_nm_per_rad *= 1.5;
    let e = format!("{:#}", other.check_torque_table(&t).unwrap_err());
    assert!(e.contains("[column] enabled"), "{e}");
    // A profile whose mapping maps no torque loads no torque table: nothing would feed it.
    let mut none = p.clone();
    none.mapping.steer_torque = None;
    assert!(none.load_torque_table().unwrap().is_none());
}

#[test]
fn a_profile_is_found_by_name_alias_and_path_and_an_unknown_name_lists_the_known_ones() {
    let dir = profile::find("shimmy_reference").unwrap();
    assert!(dir.join("profile.toml").is_file());
    assert_eq!(
        profile::find("reference").unwrap().canonicalize().unwrap(),
        dir.canonicalize().unwrap()
    );
    let by_path = repo("config/vehicles/shimmy_reference/profile.toml");
    assert!(profile::find(by_path.to_str().unwrap()).is_ok());
    let e = profile::find("no_such_car").unwrap_err().to_string();
    assert!(e.contains("no vehicle profile `no_such_car`"), "{e}");
    assert!(
        e.contains("toyota_rav4") && e.contains("shimmy_reference"),
        "{e}"
    );
}

#[test]
fn the_reference_profile_table_fits_its_chassis_and_sensor_and_another_sensor_is_refused() {
    let p = Profile::load("shimmy_reference").unwrap();
    let t = p
        .load_table()
        .unwrap()
        .expect("the reference profile ships a table");
    let mut other = p.clone();
    other.sensor.rate_hz = 83.0;
    let e = other.check_table(&t).unwrap_err().to_string();
    assert!(
        e.contains("83 Hz") && e.contains("shimmy calibrate --profile"),
        "{e}"
    );
}
