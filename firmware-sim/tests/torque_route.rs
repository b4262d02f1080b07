//! The observer's torque route, end to end: firmware-sim drives vehicles with the MODEL.md §15
//! steering column (rim, torsion bar, the driver's hands drawn per braking event) on the
//! reference bus with an EPS torque sensor (profile `shimmy_reference_eps`), and `shimmy
//! estimate`'s chain reads the logs with the profile's angle and torque tables. Where the log
//! carries a live torque the estimate must come from it and tell worn joints from tight ones;
//! a plant without the column (a steady 0 on the torque) must fall back to the angle; and
//! `--angle-only` must leave the torque out.

mod fleet_common;

/// The fleet's per-vehicle results for `vehicles` vehicles at `clearance_mm`.
fn fleet(
    name: &str,
    clearance_mm: f64,
    vehicles: usize,
    extra: &[String],
) -> Vec<serde_json::Value> {
    fleet_common::fleet(
        &format!("torque_route_{name}"),
        "shimmy_reference_eps",
        61000,
        clearance_mm,
        vehicles,
        extra,
    )
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
