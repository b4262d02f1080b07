//! shimmyd configuration: the shipped default parses; broken files fail at start with a
//! message naming the key and the problem.

use std::path::Path;

use shimmy::daemon::config::Config;

fn workspace() -> &'static Path {
    Path::new(env!("CARGO_MANIFEST_DIR"))
}

/// A daemon file with every table written out: config/shimmyd.toml as it was before it named
/// the monitor's settings file (`monitor`), with `[events]`, `[alerts]` and `[observer.*]` in
/// it. That layout is still read (with deprecation warnings), and it holds every key the broken
/// cases below change.
fn default_text() -> String {
    std::fs::read_to_string(workspace().join("tests/fixtures/config/shimmyd_old_layout.toml"))
        .unwrap()
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
    let dbc = c.input.dbc.as_ref().expect("the profile's DBC");
    assert!(dbc.ends_with("shimmy_reference.dbc") && dbc.is_file());
    assert_eq!(c.profile.as_ref().unwrap().name, "shimmy_reference");
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
            "clearance_probability = 0.7",
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
            "profile = \"shimmy_reference\"",
            "profile = \"nope\"",
            &["input.profile", "no vehicle profile `nope`", "toyota_rav4"],
        ),
        (
            "profile = \"shimmy_reference\"",
            "dbc = \"../dbc/shimmy_reference.dbc\"",
            &["input.dbc and input.mapping", "both"],
        ),
        (
            "profile = \"shimmy_reference\"",
            "dbc = \"../dbc/shimmy_reference.dbc\"\nmapping = \"vehicles/nope.toml\"",
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
        (
            "std_inflation = 1.0",
            "std_inflation = 0.0",
            &["observer.estimator.std_inflation", "> 0"],
        ),
        (
            "features = \"both\"",
            "features = \"all\"",
            &["observer.estimator.features", "all"],
        ),
        (
            "method = \"linear\"",
            "method = \"kalman\"",
            &["observer.estimator.method", "kalman"],
        ),
        (
            "evidence_power = 0.275",
            "evidence_power = 1.5",
            &["observer.estimator.evidence_power", "(0, 1]"],
        ),
        (
            "damping_grid = 9",
            "damping_grid = 0",
            &["observer.estimator.damping_grid", "1-64"],
        ),
        (
            "phase = \"either\"",
            "phase = \"wheel\"",
            &["observer.estimator.phase", "wheel"],
        ),
        (
            "phase_grid = 8",
            "phase_grid = 100",
            &["observer.estimator.phase_grid", "1-64"],
        ),
        (
            "wear_var_per_km = 0.0001",
            "wear_var_per_km = -1.0",
            &["observer.estimator.wear_var_per_km", ">= 0"],
        ),
        (
            "std_inflation = 1.0",
            "std_inflaton = 1.0",
            &["unknown field", "std_inflaton"],
        ),
        (
            "crest_factor = 2.2",
            "crest_factor = -2.2",
            &["observer.features.crest_factor"],
        ),
        (
            "noise_deg = 0.01",
            "noise_deg = -0.01",
            &["observer.features.sensor.noise_deg"],
        ),
        (
            "enabled = false\nhost = \"\"",
            "enabled = true\nhost = \"\"",
            &["mqtt.host", "required"],
        ),
        (
            "enabled = false\nhost = \"\"",
            "enabled = true\nhost = \"broker\"",
            &["mqtt.client_id", "required"],
        ),
        ("qos = 1 ", "qos = 3 ", &["mqtt.qos", "0, 1 or 2"]),
        (
            "queue_max_messages = 10000",
            "queue_max_mesages = 10000",
            &["unknown field", "queue_max_mesages"],
        ),
    ];
    for (from, to, needles) in cases {
        let e = broken(from, to);
        for n in *needles {
            assert!(e.contains(n), "`{to}`: error does not mention `{n}`:\n{e}");
        }
    }
}

/// Checks that only bite when MQTT is on.
#[test]
fn enabled_mqtt_settings_are_checked() {
    let on = default_text().replacen(
        "enabled = false\nhost = \"\"",
        "enabled = true\nhost = \"localhost\"",
        1,
    );
    let on = on.replacen(
        "client_id = \"\"",
        "client_id = \"van-17\"\nfleet = \"f\"",
        1,
    );
    let on = on.replacen("port = 1883", "port = 1883\ntransport = \"tcp\"", 1);
    let c = load(&on).unwrap();
    assert!(c.mqtt.enabled);
    assert_eq!((c.mqtt.port(), c.mqtt.qos), (1883, 1));
    for (from, to, needle) in [
        (
            "client_id = \"van-17\"",
            "client_id = \"van/17\"",
            "mqtt.client_id",
        ),
        (
            "topic_prefix = \"shimmy\"",
            "topic_prefix = \"fleet/#\"",
            "mqtt.topic_prefix",
        ),
        ("reconnect_s = 2.0", "reconnect_s = 0.0", "mqtt.reconnect_s"),
        (
            "queue_max_messages = 10000",
            "queue_max_messages = 0",
            "mqtt.queue_max_messages",
        ),
        (
            "queue_max_mib = 8.0",
            "queue_max_mib = -1.0",
            "mqtt.queue_max_mib",
        ),
        ("port = 1883", "port = 70000", "port"),
    ] {
        assert!(on.contains(from), "{from}");
        let e = load(&on.replacen(from, to, 1)).expect_err(to);
        assert!(
            e.contains(needle),
            "`{to}`: error does not mention `{needle}`:\n{e}"
        );
    }
}

#[test]
fn observer_settings_reach_the_config_and_default_to_the_observers() {
    let c = load(&default_text()).unwrap();
    assert!(!c.mqtt.enabled, "MQTT must be off by default");
    assert_eq!(c.observer.estimator, Default::default());
    assert_eq!(c.observer.features, Default::default());
    let t = default_text().replacen("std_inflation = 1.0", "std_inflation = 1.7", 1);
    let c = load(&t).unwrap();
    assert_eq!(c.observer.estimator.std_inflation, 1.7);
    // Without an [observer] table at all the observer's defaults apply.
    let t = default_text();
    let i = t.find("[observer.features]").unwrap();
    let j = t.find("[mqtt]").unwrap();
    let c = load(&format!("{}{}", &t[..i], &t[j..])).unwrap();
    assert_eq!(c.observer, Default::default());
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
            "vehicles/",
            &format!("{}/config/vehicles/", workspace().display()),
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

/// Plain text only when written: an enabled client needs TLS settings or `transport = "tcp"`;
/// TLS needs the CA; a client certificate comes with its key; the files must exist.
#[test]
fn mqtt_sends_in_plain_text_only_when_the_file_says_so() {
    let dir = tempfile::tempdir().unwrap();
    for f in ["ca.pem", "van.pem", "van.key"] {
        std::fs::write(dir.path().join(f), "").unwrap();
    }
    let on = default_text()
        .replacen(
            "enabled = false\nhost = \"\"",
            "enabled = true\nhost = \"broker.example\"",
            1,
        )
        .replacen(
            "client_id = \"\"",
            "client_id = \"van-17\"\nfleet = \"f\"",
            1,
        )
        .replacen("port = 1883\n", "", 1);
    let with = |extra: &str| on.replacen("[mqtt]\n", &format!("[mqtt]\n{extra}\n"), 1);
    let p = |f: &str| format!("{:?}", dir.path().join(f).display().to_string());

    let e = load(&on).expect_err("enabled without TLS settings or transport = \"tcp\"");
    assert!(
        e.contains("mqtt.transport") && e.contains("ca_file") && e.contains("transport = \"tcp\""),
        "{e}"
    );
    let c = load(&with("transport = \"tcp\"")).unwrap();
    assert_eq!(c.mqtt.port(), 1883);
    // TLS without a CA.
    let e = load(&with("transport = \"tls\"")).unwrap_err();
    assert!(e.contains("mqtt.ca_file") && e.contains("required"), "{e}");
    // The CA alone means TLS, on 8883.
    let c = load(&with(&format!("ca_file = {}", p("ca.pem")))).unwrap();
    assert_eq!(
        (c.mqtt.transport(), c.mqtt.port()),
        (Some(shimmy::daemon::config::Transport::Tls), 8883)
    );
    let mtls = format!(
        "ca_file = {}\ncert_file = {}\nkey_file = {}",
        p("ca.pem"),
        p("van.pem"),
        p("van.key")
    );
    load(&with(&mtls)).unwrap();
    for (extra, needles) in [
        (
            format!("ca_file = {}\ncert_file = {}", p("ca.pem"), p("van.pem")),
            &["mqtt.cert_file and mqtt.key_file", "both"][..],
        ),
        (
            format!("transport = \"tcp\"\n{mtls}"),
            &["mqtt.ca_file", "transport = \"tcp\""][..],
        ),
        (
            format!("ca_file = {}", p("nope.pem")),
            &["mqtt.ca_file", "does not exist"][..],
        ),
        (
            "transport = \"ssl\"".to_string(),
            &["transport", "unknown variant"][..],
        ),
    ] {
        let e = load(&with(&extra)).expect_err(&extra);
        for n in needles {
            assert!(
                e.contains(n),
                "`{extra}`: error does not mention `{n}`:\n{e}"
            );
        }
    }
}
