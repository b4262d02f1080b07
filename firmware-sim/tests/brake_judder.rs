//! The wheel-order check, end to end (src/observer/wheel_order.rs): firmware-sim drives RAV4s
//! with the MODEL.md §15 column and a 10 mm kingpin scrub radius, some with a brake-torque
//! variation at wheel order (a disc thickness variation of 10 %, the middle of MODEL.md §14's
//! 5-15 %), and `shimmy estimate`'s chain reads their logs on the toyota_rav4 profile. A car whose discs vary must
//! be told not to fit the model, with the brake discs named, and its workshop report
//! (`shimmy report` on its log) must send the mechanic to the discs; the same car with even
//! discs must not.

mod fleet_common;

use serde_json::Value;

/// `vehicles` cars at `clearance_mm`, a 10 mm scrub radius, and a brake-torque variation of
/// `variation` on both discs, 180° apart (0: even discs), read with the profile's torque tables.
fn fleet(name: &str, variation: f64, clearance_mm: f64, vehicles: usize) -> Vec<Value> {
    fleet_read(name, variation, clearance_mm, vehicles, None)
}

/// As [`fleet`], read with `torque_table` alone where given.
fn fleet_read(
    name: &str,
    variation: f64,
    clearance_mm: f64,
    vehicles: usize,
    torque_table: Option<&str>,
) -> Vec<Value> {
    let dir = std::path::PathBuf::from(env!("CARGO_TARGET_TMPDIR"))
        .join(format!("brake_judder_{name}_plant"));
    std::fs::create_dir_all(&dir).unwrap();
    let plant = fleet_common::column_plant(&dir, Some(0.01));
    let text = std::fs::read_to_string(&plant).unwrap();
    let text = text
        .replacen(
            "torque_variation_rel = [0.0, 0.0]",
            &format!("torque_variation_rel = [{variation}, {variation}]"),
            1,
        )
        .replacen(
            "torque_variation_phase_deg = [0.0, 0.0]",
            "torque_variation_phase_deg = [0.0, 180.0]",
            1,
        );
    assert!(
        text.contains("[0.0, 180.0]"),
        "no torque_variation_phase_deg"
    );
    std::fs::write(&plant, text).unwrap();
    let extra = fleet_common::plant_args(&plant, torque_table);
    fleet_common::fleet(
        &format!("brake_judder_{name}"),
        "toyota_rav4",
        64000,
        clearance_mm,
        vehicles,
        &extra,
    )
}

/// `shimmy report --profile toyota_rav4 --format json` on vehicle `seed`'s log of fleet `name`.
fn workshop_report(name: &str, seed: u64) -> Value {
    use clap::Parser;
    #[derive(Parser)]
    struct Report {
        #[command(flatten)]
        args: shimmy::cli::report::Args,
    }
    let dir =
        std::path::PathBuf::from(env!("CARGO_TARGET_TMPDIR")).join(format!("brake_judder_{name}"));
    let out = dir.join(format!("report_{seed}.json"));
    let log = dir.join(format!("fleet_{seed}.log"));
    let r = Report::parse_from([
        "report",
        "--profile",
        "toyota_rav4",
        "--format",
        "json",
        "--out",
        out.to_str().unwrap(),
        log.to_str().unwrap(),
    ]);
    shimmy::cli::report::run(r.args).unwrap();
    serde_json::from_str(&std::fs::read_to_string(&out).unwrap()).unwrap()
}

fn share(v: &Value) -> f64 {
    v["model_fit"]["wheel_order_share"]
        .as_f64()
        .unwrap_or_else(|| panic!("no wheel_order_share: {v}"))
}

#[test]
fn a_car_whose_brake_discs_vary_is_told_to_check_them_and_the_same_car_with_even_discs_is_not() {
    let judder = fleet("uneven", 0.10, 0.05, 2);
    let even = fleet("even", 0.0, 0.05, 2);
    for (j, e) in judder.iter().zip(&even) {
        assert_eq!(j["signals"]["estimate_from"], "torque_nm", "{j}");
        assert_eq!(j["model_fit"]["wheel_order_shake"], true, "{j}");
        assert_eq!(j["model_fit"]["fits"], false, "{j}");
        let verdict = j["verdict"].as_str().unwrap();
        assert!(
            verdict.contains("brake discs"),
            "the verdict does not name the discs: {j}"
        );
        assert!(
            !e["verdict"].as_str().unwrap().contains("brake discs"),
            "{e}"
        );
        assert!(e["model_fit"].get("wheel_order_shake").is_none(), "{e}");
        assert!(
            share(j) > share(e) + 0.2,
            "uneven discs {} vs even {}",
            share(j),
            share(e)
        );
    }
    let j = workshop_report("uneven", judder[0]["seed"].as_u64().unwrap());
    let headline = j["verdict"]["headline"].as_str().unwrap();
    assert!(headline.contains("brake discs"), "{}", j["verdict"]);
    let e = workshop_report("even", even[0]["seed"].as_u64().unwrap());
    assert!(
        !e["verdict"]["headline"]
            .as_str()
            .unwrap()
            .contains("brake discs"),
        "{}",
        e["verdict"]
    );
}

/// Cars at new joints (0.05 mm) whose discs vary by 3 % each, 180° apart, through the 10 mm
/// scrub radius: the profile's "uneven brake discs" variant, whose table drew such discs, reads
/// them, raises no clearance alert and comes nearer the truth than the nominal table alone,
/// which takes the discs' shake for wear.
#[test]
fn a_car_with_uneven_discs_is_read_with_the_disc_variant_and_not_sent_to_replace_its_joints() {
    let read = fleet("variant", 0.03, 0.05, 3);
    let even_table = fleet_read(
        "variant_nominal_only",
        0.03,
        0.05,
        3,
        Some("config/vehicles/toyota_rav4/table_torque.json"),
    );
    for v in &read {
        assert_eq!(v["signals"]["estimate_from"], "torque_nm", "{v}");
        assert_eq!(v["torque_table"], "uneven brake discs", "{v}");
        assert_eq!(v["clearance_alert"], false, "{v}");
    }
    let err = |vs: &[Value]| -> f64 {
        vs.iter()
            .map(|v| (v["median_mm"].as_f64().unwrap() / 0.05).ln().abs())
            .sum::<f64>()
    };
    assert!(
        err(&read) < err(&even_table),
        "disc variant {:?} vs the nominal table alone {:?}",
        read.iter().map(|v| &v["median_mm"]).collect::<Vec<_>>(),
        even_table
            .iter()
            .map(|v| &v["median_mm"])
            .collect::<Vec<_>>()
    );
}
