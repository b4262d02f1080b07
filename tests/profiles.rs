//! The shipped vehicle profiles (config/vehicles): each loads, its mapping fits its DBC, and the
//! lookup by name, alias and path finds it.

use shimmy::dbc::Database;
use shimmy::observer::linear::{torque_terms, Term};
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

/// The law (`LinearModel::terms`) of a torque table, `x5^2` and all.
fn terms(t: &shimmy::observer::table::ResponseTable) -> &[Term] {
    let m = t
        .linear
        .as_ref()
        .expect("a torque table carries its nuisance model");
    &m.terms
}

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
            // Its chassis variants' tables load, each for the same torque sensor, and each
            // (the nominal one too) fits the law `shimmy calibrate --signal torque` fits by
            // default, so that the command in the profile's comment rebuilds it and one
            // mixture never mixes two laws.
            let law = torque_terms().unwrap();
            assert_eq!(terms(&tt), law, "{name}: nominal torque table");
            let alts = p
                .load_torque_alternatives(&tt, None)
                .unwrap_or_else(|e| panic!("{name}: {e:#}"));
            let with_torque = p.file.chassis.variants.iter();
            assert_eq!(
                alts.len(),
                with_torque.filter(|v| v.torque_table.is_some()).count(),
                "{name}"
            );
            for a in &alts {
                assert_eq!(a.table.sensor, tt.sensor, "{name}: {}", a.name);
                assert_eq!(terms(&a.table), law, "{name}: {}", a.name);
            }
        }
        // Its chassis variants' angle tables load, each for the profile's angle sensor and
        // clearance grid, and with the nominal table's law.
        let alts = p
            .load_angle_alternatives(&t, None)
            .unwrap_or_else(|e| panic!("{name}: {e:#}"));
        let with_angle = p.file.chassis.variants.iter();
        assert_eq!(
            alts.len(),
            with_angle.filter(|v| v.table.is_some()).count(),
            "{name}"
        );
        for a in &alts {
            assert_eq!(a.table.sensor, t.sensor, "{name}: {}", a.name);
            assert_eq!(a.table.clearance_mm, t.clearance_mm, "{name}: {}", a.name);
            assert_eq!(terms(&a.table), terms(&t), "{name}: {}", a.name);
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

/// A copy of profile `name` in a fresh folder, every file it names made absolute, with
/// `profile.toml` passed through `edit`.
fn profile_copy(name: &str, edit: impl Fn(String) -> String) -> std::path::PathBuf {
    let src = repo(&format!("config/vehicles/{name}"));
    let dir = std::path::PathBuf::from(env!("CARGO_TARGET_TMPDIR"))
        .join(format!("profile_copy_{name}_{}", std::process::id()))
        .join(format!("{:x}", rand_tag()));
    std::fs::create_dir_all(&dir).unwrap();
    let mut text = std::fs::read_to_string(src.join("profile.toml")).unwrap();
    for key in ["mapping", "table", "torque_table", "bus"] {
        let line = text
            .lines()
            .find(|l| l.starts_with(&format!("{key} = ")))
            .map(str::to_string);
        if let Some(line) = line {
            let file = line.split('"').nth(1).unwrap();
            let abs = src.join(file).canonicalize().unwrap();
            text = text.replace(&line, &format!("{key} = \"{}\"", abs.display()));
        }
    }
    // The chassis variants' tables too.
    let abs = |f: &str| src.join(f).canonicalize().unwrap().display().to_string();
    let lines: Vec<String> = text
        .lines()
        .map(|l| {
            for key in ["torque_table", "table"] {
                let rel = l
                    .strip_prefix(&format!("{key} = \""))
                    .and_then(|r| r.strip_suffix('"'));
                if let Some(f) = rel.filter(|f| !f.starts_with('/')) {
                    return format!("{key} = \"{}\"", abs(f));
                }
            }
            l.to_string()
        })
        .collect();
    text = lines.join("\n") + "\n";
    std::fs::write(dir.join("profile.toml"), edit(text)).unwrap();
    dir
}

fn rand_tag() -> u128 {
    std::time::SystemTime::now()
        .duration_since(std::time::UNIX_EPOCH)
        .unwrap()
        .as_nanos()
}

/// A chassis variant's torque table is checked against the variant's chassis (the profile's
/// with the variant's scrub radius or kingpin damping, and the prior with its brake discs), not
/// the profile's own; the nominal table is not the variant's, and a variant whose scrub radius,
/// damping or discs are not its table's is refused, as are a variant that changes nothing, priors that leave the profile's own
/// chassis nothing and a variant without the nominal table.
#[test]
fn chassis_variants_are_checked_against_their_own_chassis() {
    let p = Profile::load("shimmy_reference_eps").unwrap();
    let nominal = p.load_torque_table().unwrap().unwrap();
    let alts = p.load_torque_alternatives(&nominal, None).unwrap();
    let names: Vec<&str> = alts.iter().map(|a| a.name.as_str()).collect();
    assert_eq!(
        names,
        [
            "scrub radius 10 mm",
            "kingpin damping x1.2",
            "kingpin damping x0.8",
            "uneven brake discs"
        ]
    );
    let a = &alts[0];
    assert_eq!(a.prior, profile::DEFAULT_VARIANT_PRIOR);
    assert!(a.inspect.as_deref().unwrap().contains("wheels' offset"));
    for a in &alts {
        assert_eq!(a.table.sensor, nominal.sensor);
        assert_eq!(a.table.clearance_mm, nominal.clearance_mm);
        // No variant's table is the profile's own chassis's.
        let e = format!("{:#}", p.check_torque_table(&a.table).unwrap_err());
        assert!(e.contains("[column] enabled"), "{}: {e}", a.name);
    }
    // The damping variants are the car model's own, nothing to inspect.
    assert!(alts[1].inspect.is_none() && alts[2].inspect.is_none());
    // The uneven discs' table drew its vehicles' discs, and sends the mechanic to them.
    assert_eq!(
        alts[3].table.prior.brake_torque_variation_rel,
        Some((0.0, 0.05))
    );
    assert!(alts[3].inspect.as_deref().unwrap().contains("brake discs"));
    let even = profile_copy("shimmy_reference_eps", |t| {
        t.replace("brake_torque_variation_rel = [0.0, 0.05]\n", "")
    });
    let ep = Profile::load_dir(&even).unwrap();
    let e = format!(
        "{:#}",
        ep.load_torque_alternatives(&nominal, None).unwrap_err()
    );
    assert!(
        e.contains("chassis variant `uneven brake discs`") && e.contains("nuisance prior"),
        "{e}"
    );

    // Each damping table is checked against its own scale.
    let swapped = profile_copy("shimmy_reference_eps", |t| {
        t.replace("kingpin_damping_scale = 1.2", "kingpin_damping_scale = 1.1")
    });
    let sp = Profile::load_dir(&swapped).unwrap();
    let e = format!(
        "{:#}",
        sp.load_torque_alternatives(&nominal, None).unwrap_err()
    );
    assert!(e.contains("chassis variant `kingpin damping x1.2`"), "{e}");
    // A variant that changes nothing is refused.
    let idle = profile_copy("shimmy_reference_eps", |t| {
        t.replace("kingpin_damping_scale = 0.8\n", "")
    });
    let e = format!("{:#}", Profile::load_dir(&idle).unwrap_err());
    assert!(e.contains("changes nothing"), "{e}");

    let wrong = profile_copy("shimmy_reference_eps", |t| {
        t.replacen("scrub_radius_mm = 10.0", "scrub_radius_mm = 5.0", 1)
    });
    let wp = Profile::load_dir(&wrong).unwrap();
    let e = format!(
        "{:#}",
        wp.load_torque_alternatives(&nominal, None).unwrap_err()
    );
    assert!(e.contains("chassis variant `scrub radius 10 mm`"), "{e}");

    // A variant of cars with uneven brake discs is read only with a table whose vehicles had
    // them drawn, and its range is checked.
    let discs = profile_copy("shimmy_reference_eps", |t| {
        t.replacen(
            "scrub_radius_mm = 10.0",
            "scrub_radius_mm = 10.0\nbrake_torque_variation_rel = [0.0, 0.05]",
            1,
        )
    });
    let dp = Profile::load_dir(&discs).unwrap();
    let e = format!(
        "{:#}",
        dp.load_torque_alternatives(&nominal, None).unwrap_err()
    );
    assert!(
        e.contains("chassis variant `scrub radius 10 mm`") && e.contains("nuisance prior"),
        "{e}"
    );
    let inverted = profile_copy("shimmy_reference_eps", |t| {
        t.replacen(
            "scrub_radius_mm = 10.0",
            "scrub_radius_mm = 10.0\nbrake_torque_variation_rel = [0.05, 0.01]",
            1,
        )
    });
    let e = format!("{:#}", Profile::load_dir(&inverted).unwrap_err());
    assert!(e.contains("brake_torque_variation_rel"), "{e}");

    let greedy = profile_copy("shimmy_reference_eps", |t| {
        t.replacen(
            "scrub_radius_mm = 10.0",
            "scrub_radius_mm = 10.0\nprior_probability = 1.0",
            1,
        )
    });
    let e = format!("{:#}", Profile::load_dir(&greedy).unwrap_err());
    assert!(
        e.contains("prior_probability") || e.contains("add up"),
        "{e}"
    );

    let alone = profile_copy("shimmy_reference_eps", |t| {
        t.lines()
            .filter(|l| !(l.starts_with("torque_table = ") && l.ends_with("table_torque.json\"")))
            .collect::<Vec<_>>()
            .join("\n")
    });
    let e = format!("{:#}", Profile::load_dir(&alone).unwrap_err());
    assert!(e.contains("needs the nominal torque_table"), "{e}");

    // Without a torque table the list is empty, and a profile whose mapping maps no torque has
    // none.
    let plain = Profile::load("shimmy_reference").unwrap();
    assert!(plain
        .load_torque_alternatives(&nominal, None)
        .unwrap()
        .is_empty());
    let mut no_torque = p.clone();
    no_torque.mapping.steer_torque = None;
    assert!(no_torque
        .load_torque_alternatives(&nominal, None)
        .unwrap()
        .is_empty());
}

/// A chassis variant's angle table is checked against the variant's chassis and prior, as its
/// torque table is: the 5-DOF reference profile's variants (a 10 mm scrub radius, uneven discs
/// on it) load with their angle tables, none of which is the profile's own chassis's; the
/// nominal table named as a variant's is refused, as are a variant that names no table and an
/// angle variant without the nominal angle table. A profile whose variants name torque tables
/// alone has no angle alternatives.
#[test]
fn angle_chassis_variants_are_checked_against_their_own_chassis() {
    let p = Profile::load("shimmy_reference").unwrap();
    let nominal = p.load_table().unwrap().unwrap();
    let alts = p.load_angle_alternatives(&nominal, None).unwrap();
    let names: Vec<&str> = alts.iter().map(|a| a.name.as_str()).collect();
    assert_eq!(names, ["scrub radius 10 mm", "uneven brake discs"]);
    for a in &alts {
        assert_eq!(a.table.sensor, nominal.sensor);
        let e = format!("{:#}", p.check_table(&a.table).unwrap_err());
        assert!(
            e.contains("vehicle") || e.contains("chassis"),
            "{}: {e}",
            a.name
        );
    }
    assert_eq!(
        alts[1].table.prior.brake_torque_variation_rel,
        Some((0.0, 0.05))
    );
    assert!(alts[1].inspect.as_deref().unwrap().contains("brake discs"));
    assert!(p
        .load_torque_alternatives(&nominal, None)
        .unwrap()
        .is_empty());

    // The variants go with the profile's own table, however its path is written (shimmyd's
    // `vehicle.table`), and not with another file given in its place, even an identical copy.
    let own_path = p.table_path.clone().unwrap();
    let roundabout = own_path
        .parent()
        .unwrap()
        .join("../shimmy_reference/table.json");
    assert!(p.is_own_table(&roundabout));
    let via_path = p
        .load_angle_alternatives(&nominal, Some(&roundabout))
        .unwrap();
    assert_eq!(via_path.len(), alts.len());
    let dir = tempfile::tempdir().unwrap();
    let copy = dir.path().join("table.json");
    std::fs::copy(&own_path, &copy).unwrap();
    assert!(!p.is_own_table(&copy));
    assert!(p
        .load_angle_alternatives(&nominal, Some(&copy))
        .unwrap()
        .is_empty());

    // The nominal table named as the scrub variant's: built without the scrub radius.
    let own = profile_copy("shimmy_reference", |t| {
        t.lines()
            .map(|l| {
                if l.starts_with("table = ") && l.contains("table_scrub10mm.json") {
                    let nominal = repo("config/vehicles/shimmy_reference/table.json");
                    format!("table = \"{}\"", nominal.display())
                } else {
                    l.to_string()
                }
            })
            .collect::<Vec<_>>()
            .join("\n")
    });
    let op = Profile::load_dir(&own).unwrap();
    let e = format!(
        "{:#}",
        op.load_angle_alternatives(&nominal, None).unwrap_err()
    );
    assert!(e.contains("chassis variant `scrub radius 10 mm`"), "{e}");

    let tableless = profile_copy("shimmy_reference", |t| {
        t.lines()
            .filter(|l| !(l.starts_with("table = ") && l.contains("table_scrub10mm.json")))
            .collect::<Vec<_>>()
            .join("\n")
    });
    let e = format!("{:#}", Profile::load_dir(&tableless).unwrap_err());
    assert!(e.contains("names no table"), "{e}");

    let alone = profile_copy("shimmy_reference", |t| {
        t.lines()
            .filter(|l| !(l.starts_with("table = ") && l.ends_with("/table.json\"")))
            .collect::<Vec<_>>()
            .join("\n")
    });
    let e = format!("{:#}", Profile::load_dir(&alone).unwrap_err());
    assert!(e.contains("needs the nominal (angle) table"), "{e}");

    let rav4_like = Profile::load("shimmy_reference_eps").unwrap();
    let t = rav4_like.load_table().unwrap().unwrap();
    assert!(rav4_like
        .load_angle_alternatives(&t, None)
        .unwrap()
        .is_empty());

    // The car profiles, for a bus without a live torque: the same two variants beside their
    // torque tables, each for the profile's own angle sensor (the RAV4's 82.9 Hz tables are its
    // own, the others share the reference's) and the variant's chassis.
    for name in ["toyota_rav4", "vw_mqb", "honda_civic", "hyundai_kia"] {
        let p = Profile::load(name).unwrap();
        let nominal = p.load_table().unwrap().unwrap();
        let alts = p.load_angle_alternatives(&nominal, None).unwrap();
        let names: Vec<&str> = alts.iter().map(|a| a.name.as_str()).collect();
        assert_eq!(
            names,
            ["scrub radius 10 mm", "uneven brake discs"],
            "{name}"
        );
        for a in &alts {
            assert_eq!(
                a.table.sensor.rate_hz, p.sensor.rate_hz,
                "{name}: {}",
                a.name
            );
            assert!(p.check_table(&a.table).is_err(), "{name}: {}", a.name);
        }
        let torque = p.load_torque_table().unwrap().unwrap();
        assert_eq!(
            p.load_torque_alternatives(&torque, None).unwrap().len(),
            4,
            "{name}"
        );
    }
}
