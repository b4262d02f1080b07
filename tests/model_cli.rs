//! `shimmy simulate` as a user runs it: the JSON summary has the fields issue 3 names, the CSV
//! has one row per millisecond with the named columns, same seed gives the same output, and bad
//! input is a clear error rather than a panic.

use std::process::Command;

fn shimmy(args: &[&str]) -> std::process::Output {
    Command::new(env!("CARGO_BIN_EXE_shimmy"))
        .args(args)
        .output()
        .expect("runs the shimmy binary")
}

#[test]
fn summary_json_has_the_issue_fields_and_is_reproducible() {
    let args = [
        "simulate",
        "--clearance-mm",
        "0.2",
        "--v0-kmh",
        "40",
        "--decel-g",
        "0.8",
        "--duration",
        "2.5",
        "--seed",
        "3",
        "--summary",
        "--lyapunov",
    ];
    let out = shimmy(&args);
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    let v: serde_json::Value = serde_json::from_slice(&out.stdout).unwrap();
    for key in [
        "peak_theta1_deg",
        "peak_theta1_bp_deg",
        "peak_sw_bp_deg",
        "fdom_hz",
        "concentration",
        "max_contact_fx_n",
        "max_contact_fy_n",
        "lyapunov_per_s",
        "cpu_s",
    ] {
        assert!(
            v[key].as_f64().is_some_and(f64::is_finite),
            "{key}: {}",
            v[key]
        );
    }
    assert!(v["peak_theta1_bp_deg"].as_f64().unwrap() > 0.01);
    let again: serde_json::Value = serde_json::from_slice(&shimmy(&args).stdout).unwrap();
    assert_eq!(v["peak_theta1_bp_deg"], again["peak_theta1_bp_deg"]);
    assert_eq!(v["lyapunov_per_s"], again["lyapunov_per_s"]);
}

#[test]
fn csv_has_named_columns_at_1_khz() {
    let dir = std::env::temp_dir().join(format!("shimmy_sim_{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    let path = dir.join("run.csv");
    let out = shimmy(&[
        "simulate",
        "--single",
        "--duration",
        "0.5",
        "--out",
        path.to_str().unwrap(),
    ]);
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    let text = std::fs::read_to_string(&path).unwrap();
    let mut lines = text.lines();
    let header: Vec<&str> = lines.next().unwrap().split(',').collect();
    for col in [
        "t_s",
        "theta1_rad",
        "x_rate_mps",
        "contact_fx_l_n",
        "contact_fy_r_n",
        "penetration_l_m",
        "tire_fy_r_n",
        "delta_sw_deg",
        "column_torque_nm",
    ] {
        assert!(header.contains(&col), "missing {col}");
    }
    let rows: Vec<Vec<f64>> = lines
        .map(|l| l.split(',').map(|x| x.parse().unwrap()).collect())
        .collect();
    assert_eq!(rows.len(), 501);
    assert!(rows.iter().all(|r| r.len() == header.len()));
    assert!((rows[500][0] - 0.5).abs() < 1e-12);
    std::fs::remove_dir_all(&dir).ok();
}

#[test]
fn bad_inputs_are_clear_errors() {
    for (args, needle) in [
        (
            vec!["simulate", "--clearance-mm", "0"],
            "--clearance-mm must be > 0",
        ),
        (
            vec!["simulate", "--clearance-mm", "-0.1"],
            "--clearance-mm must be > 0",
        ),
        (vec!["simulate", "--decel-g", "3"], "--decel-g must lie in"),
        (vec!["simulate", "--h", "0.01"], "--h must lie in"),
        (
            vec!["simulate", "--vehicle", "/nonexistent/v.toml"],
            "reading vehicle file",
        ),
    ] {
        let out = shimmy(&args);
        let err = String::from_utf8_lossy(&out.stderr);
        assert_eq!(out.status.code(), Some(1), "{args:?}: {err}");
        assert!(err.contains(needle), "{args:?}: {err}");
        assert!(!err.contains("panicked"), "{err}");
    }
    let out = shimmy(&["simulate", "--decel-g", "0.9", "--duration", "1.5"]);
    assert!(out.status.success());
    assert!(String::from_utf8_lossy(&out.stderr).contains("outside the studied 0.3–0.8 g"));
}

#[test]
fn integrator_is_selectable_by_name_and_reported() {
    let run = |name: &str| -> serde_json::Value {
        let out = shimmy(&[
            "simulate",
            "--duration",
            "3",
            "--integrator",
            name,
            "--summary",
        ]);
        assert!(
            out.status.success(),
            "{name}: {}",
            String::from_utf8_lossy(&out.stderr)
        );
        serde_json::from_slice(&out.stdout).unwrap()
    };
    let spec = run("rk4");
    assert_eq!(spec["integrator"], "rk4");
    let spec_peak = spec["peak_theta1_bp_deg"].as_f64().unwrap();
    for (name, serde_name) in [
        ("rk4-warm-slip", "rk4_warm_slip"),
        ("rk4-multirate", "rk4_multirate"),
        ("rk4_adaptive", "rk4_adaptive"),
    ] {
        let v = run(name);
        assert_eq!(v["integrator"], serde_name);
        let peak = v["peak_theta1_bp_deg"].as_f64().unwrap();
        assert!(
            (peak - spec_peak).abs() < 0.01 * spec_peak,
            "{name}: {peak} vs rk4 {spec_peak}"
        );
    }
    let bad = shimmy(&["simulate", "--integrator", "euler", "--summary"]);
    assert!(!bad.status.success());
    assert!(String::from_utf8_lossy(&bad.stderr).contains("euler"));
}
