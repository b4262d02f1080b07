//! shimmyd configuration: the shipped default parses; broken files fail at start with a
//! message naming the key and the problem.

use std::path::Path;

use shimmy::daemon::config::Config;

fn workspace() -> &'static Path {
    Path::new(env!("CARGO_MANIFEST_DIR"))
}

fn default_text() -> String {
    std::fs::read_to_string(workspace().join("config/shimmyd.toml")).unwrap()
}

fn load(text: &str) -> Result<Config, String> {
    Config::from_toml_str(text, &workspace().join("config")).map_err(|e| format!("{e:#}"))
}

#[test]
fn shipped_default_is_valid_and_read_only() {
    let c = Config::load(&workspace().join("config/shimmyd.toml")).unwrap();
    assert_eq!(c.input.interfaces, ["can0"]);
    assert!(!c.outputs.transmit, "read-only must be the default");
    assert_eq!(c.alerts.shimmy_deg, 0.2);
    assert_eq!(
        (c.alerts.shimmy_speed_min_kmh, c.alerts.shimmy_speed_max_kmh),
        (50.0, 60.0)
    );
    assert_eq!(c.alerts.clearance_mm, 0.1);
    assert!(c.input.dbc.ends_with("shimmy_reference.dbc") && c.input.dbc.is_file());
}

fn broken(from: &str, to: &str) -> String {
    let t = default_text();
    assert!(t.contains(from), "fixture text `{from}` not in the default");
    let e = load(&t.replacen(from, to, 1)).expect_err("should be rejected");
    e
}

#[test]
fn broken_configs_name_the_key_and_the_problem() {
    let cases: &[(&str, &str, &[&str])] = &[
        (
            "shimmy_deg = 0.2",
            "shimmy_deg = -0.2",
            &["alerts.shimmy_deg", "> 0", "-0.2"],
        ),
        (
            "shimmy_deg = 0.2",
            "shimy_deg = 0.2",
            &["unknown field", "shimy_deg"],
        ),
        (
            "fsync = \"always\"",
            "fsync = \"sometimes\"",
            &["outputs.fsync", "sometimes"],
        ),
        (
            "fsync = \"always\"\nfsync_interval_ms = 200",
            "fsync = \"interval\"\nfsync_interval_ms = 0",
            &["outputs.fsync_interval_ms"],
        ),
        (
            "transmit = false",
            "transmit = true",
            &["outputs.transmit_interface", "required"],
        ),
        (
            "shimmy_speed_max_kmh = 60.0",
            "shimmy_speed_max_kmh = 40.0",
            &["alerts.shimmy_speed_min_kmh", "alerts.shimmy_speed_max_kmh"],
        ),
        (
            "clearance_probability = 0.9",
            "clearance_probability = 1.5",
            &["alerts.clearance_probability", "1.5"],
        ),
        (
            "clearance_clear_probability = 0.5",
            "clearance_clear_probability = 0.95",
            &["alerts.clearance_clear_probability", "below"],
        ),
        (
            "shimmy_confirm = 2",
            "shimmy_confirm = 9",
            &["alerts.shimmy_confirm"],
        ),
        (
            "shimmy_clear_deg = 0.15",
            "shimmy_clear_deg = 0.3",
            &["alerts.shimmy_clear_deg", "flap"],
        ),
        (
            "mapping = \"mappings/shimmy_reference.toml\"",
            "mapping = \"mappings/nope.toml\"",
            &["input.mapping", "nope.toml", "does not exist"],
        ),
        (
            "min_decel_g = 0.3",
            "min_decel_g = 0.9",
            &["events.min_decel_g", "events.max_decel_g"],
        ),
        (
            "interfaces = [\"can0\"]",
            "interfaces = [\"can0/x\"]",
            &["input.interfaces[0]"],
        ),
        (
            "interfaces = [\"can0\"]",
            "interfaces = \"can0\"",
            &["interfaces", "sequence"],
        ),
        (
            "counters_interval_s = 60",
            "counters_interval_s = 0",
            &["log.counters_interval_s"],
        ),
        (
            "rotate_mib = 16.0",
            "rotate_mib = 0.0",
            &["outputs.rotate_mib"],
        ),
    ];
    for (from, to, needles) in cases {
        let e = broken(from, to);
        for n in *needles {
            assert!(e.contains(n), "`{to}`: error does not mention `{n}`:\n{e}");
        }
    }
}

#[test]
fn missing_required_table_is_named() {
    let t = default_text();
    let i = t.find("[outputs]").unwrap();
    let j = t.find("[log]").unwrap();
    let e = load(&format!("{}{}", &t[..i], &t[j..])).unwrap_err();
    assert!(e.contains("outputs"), "{e}");
}

#[test]
fn shimmyd_refuses_a_broken_config_at_start() {
    let dir = tempfile::tempdir().unwrap();
    let p = dir.path().join("bad.toml");
    let text = default_text()
        .replace("../dbc/", &format!("{}/dbc/", workspace().display()))
        .replace(
            "mappings/",
            &format!("{}/config/mappings/", workspace().display()),
        )
        .replace(
            "vehicle/default",
            &format!("{}/config/vehicle/default", workspace().display()),
        )
        .replace("clearance_mm = 0.1", "clearance_mm = 0");
    std::fs::write(&p, text).unwrap();
    let out = std::process::Command::new(env!("CARGO_BIN_EXE_shimmyd"))
        .arg("--config")
        .arg(&p)
        .output()
        .unwrap();
    assert_eq!(out.status.code(), Some(1));
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(
        err.contains("alerts.clearance_mm: must be > 0 (got 0)"),
        "{err}"
    );
    assert!(err.contains("bad.toml"), "{err}");
}
