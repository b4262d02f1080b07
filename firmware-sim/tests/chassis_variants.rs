//! A profile's chassis variants, end to end: firmware-sim drives vehicles with the MODEL.md §15
//! column on the reference EPS bus, some built with a 10 mm kingpin scrub radius (MODEL.md §14)
//! that the profile's own chassis does not have, and `shimmy estimate`'s chain reads each log
//! with every torque table of profile `shimmy_reference_eps` (its own and its
//! `[[chassis.variants]]` ones: a 10 mm scrub radius, a kingpin damping ×1.2 and ×0.8, uneven
//! brake discs). A car with the scrub radius must be read with that variant's table, a car
//! damped 20 % less than the model (beyond the prior's ±10 %) with the ×0.8 table, a car
//! without either with the nominal one, and the report must say which and why. The same for
//! the angle's tables on the 5-DOF reference bus (profile `shimmy_reference`).

mod fleet_common;

use serde_json::Value;

/// The fleet's per-vehicle results: `vehicles` vehicles at `clearance_mm` with a scrub radius
/// of `scrub_m` (none: the profile's chassis), read with the profile's torque tables, or with
/// `torque_table` alone.
fn fleet(
    name: &str,
    scrub_m: Option<f64>,
    clearance_mm: f64,
    vehicles: usize,
    torque_table: Option<&str>,
) -> Vec<Value> {
    let dir = std::path::PathBuf::from(env!("CARGO_TARGET_TMPDIR"))
        .join(format!("chassis_variants_{name}_plant"));
    std::fs::create_dir_all(&dir).unwrap();
    let plant = fleet_common::column_plant(&dir, scrub_m);
    let extra = fleet_common::plant_args(&plant, torque_table);
    fleet_common::fleet(
        &format!("chassis_variants_{name}"),
        "shimmy_reference_eps",
        62000,
        clearance_mm,
        vehicles,
        &extra,
    )
}

const VARIANT: &str = "scrub radius 10 mm";

/// The table a vehicle was read with, after checking the evidence block around it.
fn chosen(v: &Value) -> String {
    let tables = v["torque_tables"].as_array().expect("torque_tables");
    assert_eq!(tables.len(), 5, "{v}");
    let chosen: Vec<&Value> = tables.iter().filter(|t| t["chosen"] == true).collect();
    assert_eq!(chosen.len(), 1, "{v}");
    let weights: f64 = tables.iter().map(|t| t["weight"].as_f64().unwrap()).sum();
    assert!((weights - 1.0).abs() < 1e-9, "{v}");
    assert_eq!(v["torque_table"], chosen[0]["name"], "{v}");
    chosen[0]["name"].as_str().unwrap().to_string()
}

#[test]
fn a_car_with_a_scrub_radius_is_read_with_its_variants_table_and_a_nominal_car_with_its_own() {
    let scrub = fleet("scrub", Some(0.01), 0.085, 3, None);
    let nominal = fleet("nominal", None, 0.085, 3, None);
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
        Some(0.01),
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

/// A car model whose kingpin damping is 20 % below MODEL.md §9's (each vehicle within ±10 % of
/// that, so beyond the profile's prior) with worn joints: the nominal table, which has no
/// damping that low, reads the loud rattle as far more wear than there is; the events favour
/// the ×0.8 variant by far more than its 0.02 prior holds back, and its estimate is the nearer.
#[test]
fn a_car_damped_beyond_the_prior_is_read_with_the_damping_variant() {
    let dir = std::path::PathBuf::from(env!("CARGO_TARGET_TMPDIR"))
        .join("chassis_variants_damping_plant");
    std::fs::create_dir_all(&dir).unwrap();
    let plant = fleet_common::column_plant(&dir, None);
    let text = std::fs::read_to_string(&plant).unwrap();
    let low = text.replacen(
        "kingpin_damping_nms_per_rad = 30.0 ",
        "kingpin_damping_nms_per_rad = 24.0 ",
        1,
    );
    assert_ne!(
        low, text,
        "no kingpin_damping_nms_per_rad = 30.0 in the plant"
    );
    let plant = dir.join("plant_damping_080.toml");
    std::fs::write(&plant, low).unwrap();
    let run = |name: &str, torque_table: Option<&str>| {
        let extra = fleet_common::plant_args(&plant, torque_table);
        fleet_common::fleet(name, "shimmy_reference_eps", 62100, 0.3, 3, &extra)
    };
    let read = run("chassis_variants_damping", None);
    for v in &read {
        assert_eq!(chosen(v), "kingpin damping x0.8", "{v}");
    }
    let alone = run(
        "chassis_variants_damping_nominal_only",
        Some("config/vehicles/shimmy_reference_eps/table_torque.json"),
    );
    let err = |vs: &[Value]| -> f64 {
        vs.iter()
            .map(|v| (v["median_mm"].as_f64().unwrap() / 0.3).ln().abs())
            .sum::<f64>()
    };
    assert!(
        err(&read) < err(&alone),
        "variant {:?} vs nominal only {:?}",
        read.iter().map(|v| &v["median_mm"]).collect::<Vec<_>>(),
        alone.iter().map(|v| &v["median_mm"]).collect::<Vec<_>>()
    );
}

/// The angle's chassis variants, on the 5-DOF reference bus (profile `shimmy_reference`, no
/// column and no torque): its `[[chassis.variants]]` name angle tables (a 10 mm scrub radius,
/// uneven brake discs on it), and the estimate, which comes from the angle, weighs them. A car
/// with the scrub radius is read with that variant's angle table and lands nearer its
/// clearance than with the nominal table alone, whose steady shake it would read as wear; a
/// car of the profile's own chassis is read with the nominal table.
#[test]
fn a_5dof_car_with_a_scrub_radius_is_read_with_the_angle_variant() {
    let dir = std::path::PathBuf::from(env!("CARGO_TARGET_TMPDIR")).join("angle_variants_plant");
    std::fs::create_dir_all(&dir).unwrap();
    let text = std::fs::read_to_string(fleet_common::repo("config/vehicle/default.toml")).unwrap();
    let scrubbed = text.replacen("scrub_radius_m = 0.0 ", "scrub_radius_m = 0.01 ", 1);
    assert_ne!(
        scrubbed, text,
        "no scrub_radius_m = 0.0 in the default vehicle"
    );
    let plant = dir.join("plant_scrub10.toml");
    std::fs::write(&plant, scrubbed).unwrap();
    let plant_arg = vec!["--plant".to_string(), plant.display().to_string()];
    let chosen = |v: &Value| -> String {
        assert!(v.get("torque_tables").is_none(), "{v}");
        let tables = v["angle_tables"].as_array().expect("angle_tables");
        assert_eq!(tables.len(), 3, "{v}");
        let chosen: Vec<&Value> = tables.iter().filter(|t| t["chosen"] == true).collect();
        assert_eq!(chosen.len(), 1, "{v}");
        assert_eq!(v["angle_table"], chosen[0]["name"], "{v}");
        chosen[0]["name"].as_str().unwrap().to_string()
    };
    let scrub = fleet_common::fleet(
        "angle_variants_scrub",
        "shimmy_reference",
        62200,
        0.085,
        3,
        &plant_arg,
    );
    let nominal = fleet_common::fleet(
        "angle_variants_nominal",
        "shimmy_reference",
        62200,
        0.085,
        3,
        &[],
    );
    for v in &scrub {
        assert_eq!(chosen(v), VARIANT, "{v}");
        assert!(
            v["verdict"]
                .as_str()
                .unwrap()
                .contains(&format!("read mostly with the angle table for {VARIANT}")),
            "{v}"
        );
    }
    for v in &nominal {
        assert_eq!(chosen(v), "nominal", "{v}");
    }
    let mut alone_args = plant_arg.clone();
    alone_args.extend([
        "--table".to_string(),
        fleet_common::repo("config/vehicles/shimmy_reference/table.json")
            .display()
            .to_string(),
    ]);
    let alone = fleet_common::fleet(
        "angle_variants_scrub_nominal_only",
        "shimmy_reference",
        62200,
        0.085,
        3,
        &alone_args,
    );
    for v in &alone {
        assert!(v.get("angle_tables").is_none(), "{v}");
    }
    let err = |vs: &[Value]| -> f64 {
        vs.iter()
            .map(|v| (v["median_mm"].as_f64().unwrap() / 0.085).ln().abs())
            .sum::<f64>()
    };
    assert!(
        err(&scrub) < err(&alone),
        "variant {:?} vs nominal only {:?}",
        scrub.iter().map(|v| &v["median_mm"]).collect::<Vec<_>>(),
        alone.iter().map(|v| &v["median_mm"]).collect::<Vec<_>>()
    );
}
