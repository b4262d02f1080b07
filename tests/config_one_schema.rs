//! One schema for the monitor's settings: shimmyd's file names the monitor's settings file
//! (`monitor`, the file `shimmy estimate --config` reads) instead of repeating it; the earlier
//! layout with `[events]`, `[alerts]` and `[observer.*]` in the daemon's file still loads, with
//! deprecation warnings naming the new place; both at once is an error; docs/CONFIG.md names
//! every key.

use std::path::{Path, PathBuf};

use shimmy::daemon::config::{Config, DEPRECATED_TABLES};
use shimmy::observer::ObserverConfig;

fn workspace() -> &'static Path {
    Path::new(env!("CARGO_MANIFEST_DIR"))
}

fn shipped_observer() -> ObserverConfig {
    let (c, w) =
        ObserverConfig::load_with_warnings(&workspace().join("config/observer.toml")).unwrap();
    assert!(w.is_empty(), "{w:?}");
    c
}

fn old_layout_path() -> PathBuf {
    workspace().join("tests/fixtures/config/shimmyd_old_layout.toml")
}

/// `text` written as `dir/shimmyd.toml`, its `monitor` pointing at `monitor` (absolute).
fn write_daemon(dir: &Path, text: &str, monitor: Option<&Path>) -> PathBuf {
    let profiles = workspace().join("config/vehicles");
    let mut text = text.replace(
        "profile = \"shimmy_reference\"",
        &format!(
            "profile = {:?}",
            profiles.join("shimmy_reference").display().to_string()
        ),
    );
    if let Some(m) = monitor {
        text = format!("monitor = {:?}\n{text}", m.display().to_string());
    }
    let p = dir.join("shimmyd.toml");
    std::fs::write(&p, text).unwrap();
    p
}

/// The shipped daemon file without its `monitor` line.
fn shipped_daemon_text_without_monitor() -> String {
    let t = std::fs::read_to_string(workspace().join("config/shimmyd.toml")).unwrap();
    let line = "monitor = \"observer.toml\"\n";
    assert!(
        t.contains(line),
        "config/shimmyd.toml names no monitor file"
    );
    t.replacen(line, "", 1)
}

#[test]
fn shipped_daemon_configs_read_the_observer_file_and_do_not_repeat_it() {
    let expected = shipped_observer();
    for rel in ["config/shimmyd.toml", "config/demo/shimmyd.toml"] {
        let p = workspace().join(rel);
        let c = Config::load(&p).unwrap();
        assert!(c.warnings.is_empty(), "{rel}: {:?}", c.warnings);
        let m = c.monitor.as_ref().expect("a monitor file");
        assert_eq!(
            m.canonicalize().unwrap(),
            workspace()
                .join("config/observer.toml")
                .canonicalize()
                .unwrap(),
            "{rel}"
        );
        assert_eq!(c.settings, expected, "{rel}");
        assert_eq!(c.alerts, expected.alerts, "{rel}");
        assert_eq!(c.observer.estimator, expected.estimator, "{rel}");
        assert_eq!(c.observer.features, expected.features, "{rel}");
        assert_eq!(
            c.events.max_steer_deg, expected.events.max_steer_deg,
            "{rel}"
        );
        let raw: toml::Table = toml::from_str(&std::fs::read_to_string(&p).unwrap()).unwrap();
        for t in ["events", "alerts", "observer", "features", "estimator"] {
            assert!(!raw.contains_key(t), "{rel} repeats [{t}]");
        }
    }
}

#[test]
fn old_layout_still_loads_with_the_same_values_and_says_where_to_move_each_table() {
    let c = Config::load(&old_layout_path()).unwrap();
    assert_eq!(c.monitor, None);
    assert_eq!(c.settings, shipped_observer());
    let file = old_layout_path().display().to_string();
    for (old, new) in DEPRECATED_TABLES {
        let w = c
            .warnings
            .iter()
            .find(|w| w.contains(&format!("[{old}] ")))
            .unwrap_or_else(|| panic!("no warning for [{old}]: {:?}", c.warnings));
        assert!(w.starts_with(&format!("{file}: ")), "{w}");
        assert!(w.contains("deprecated"), "{w}");
        assert!(
            w.contains(&format!("[{new}] of the monitor's settings file")),
            "{w}"
        );
        assert!(w.contains("monitor = \"observer.toml\""), "{w}");
    }
    assert_eq!(
        c.warnings.len(),
        DEPRECATED_TABLES.len(),
        "{:?}",
        c.warnings
    );
}

#[test]
fn old_layout_and_monitor_file_with_the_same_changes_give_the_same_settings() {
    let dir = tempfile::tempdir().unwrap();
    let changes = [
        ("min_speed_kmh = 20.0", "min_speed_kmh = 25.0"),
        ("shimmy_clear_deg = 0.15", "shimmy_clear_deg = 0.1"),
        (
            "clearance_clear_probability = 0.5",
            "clearance_clear_probability = 0.6",
        ),
        ("std_inflation = 1.0", "std_inflation = 1.7"),
        ("noise_deg = 0.01", "noise_deg = 0.02"),
    ];
    let mut old = std::fs::read_to_string(old_layout_path()).unwrap();
    let mut obs = std::fs::read_to_string(workspace().join("config/observer.toml")).unwrap();
    for (from, to) in changes {
        assert!(old.contains(from) && obs.contains(from), "{from}");
        old = old.replacen(from, to, 1);
        obs = obs.replacen(from, to, 1);
    }
    let a = Config::from_toml_str(&old, &workspace().join("config")).unwrap();
    let m = dir.path().join("monitor.toml");
    std::fs::write(&m, obs).unwrap();
    let b = Config::load(&write_daemon(
        dir.path(),
        &shipped_daemon_text_without_monitor(),
        Some(&m),
    ))
    .unwrap();
    assert_eq!(a.settings, b.settings);
    assert_eq!(b.settings.events.min_speed_kmh, 25.0);
    assert_eq!(b.alerts.shimmy_clear_deg, 0.1);
    assert_eq!(b.alerts.clearance_clear_probability, 0.6);
    assert_eq!(b.observer.estimator.std_inflation, 1.7);
    assert_eq!(b.observer.features.sensor.noise_deg, 0.02);
    assert_eq!(
        (&a.events, &a.alerts, &a.observer),
        (&b.events, &b.alerts, &b.observer)
    );
}

#[test]
fn monitor_file_and_a_deprecated_table_together_are_an_error_naming_both() {
    let dir = tempfile::tempdir().unwrap();
    let m = workspace().join("config/observer.toml");
    for (table, key) in [
        ("alerts", "shimmy_deg = 0.3"),
        ("events", "min_speed_kmh = 25.0"),
        ("observer.estimator", "std_inflation = 1.7"),
    ] {
        let text = format!(
            "{}\n[{table}]\n{key}\n",
            shipped_daemon_text_without_monitor()
        );
        let p = write_daemon(dir.path(), &text, Some(&m));
        let e = format!("{:#}", Config::load(&p).unwrap_err());
        assert!(e.contains("monitor = "), "{e}");
        assert!(e.contains(&format!("[{table}]")), "{e}");
        assert!(e.contains("both given"), "{e}");
        assert!(e.contains(&m.display().to_string()), "{e}");
    }
}

#[test]
fn monitor_file_errors_name_the_file_and_the_key() {
    let dir = tempfile::tempdir().unwrap();
    let daemon_text = shipped_daemon_text_without_monitor();
    let missing = dir.path().join("nowhere.toml");
    let e = format!(
        "{:#}",
        Config::load(&write_daemon(dir.path(), &daemon_text, Some(&missing))).unwrap_err()
    );
    assert!(e.contains("monitor") && e.contains("nowhere.toml"), "{e}");

    let m = dir.path().join("monitor.toml");
    for (text, needles) in [
        (
            "[estimator]\nstd_inflation = -1.0\n",
            &["estimator.std_inflation", "> 0"][..],
        ),
        (
            "[alerts]\nshimmy_clear_deg = 0.5\n",
            &["alerts.shimmy_clear_deg", "flap"][..],
        ),
        (
            "[features]\ncrest_factor = 0.0\n",
            &["features.crest_factor"][..],
        ),
        (
            "[alerts]\nshimy_deg = 0.2\n",
            &["unknown field", "shimy_deg"][..],
        ),
    ] {
        std::fs::write(&m, text).unwrap();
        let e = format!(
            "{:#}",
            Config::load(&write_daemon(dir.path(), &daemon_text, Some(&m))).unwrap_err()
        );
        assert!(e.contains("monitor.toml"), "{text}: {e}");
        for n in needles {
            assert!(e.contains(n), "{text}: `{n}` not in {e}");
        }
        assert!(!e.contains("observer.features"), "{text}: {e}");
    }
}

#[test]
fn monitor_files_old_alert_names_are_warned_about_through_the_daemon() {
    let dir = tempfile::tempdir().unwrap();
    let m = dir.path().join("monitor.toml");
    std::fs::write(&m, "[alerts]\nshimmy_amplitude_deg = 0.3\n").unwrap();
    let c = Config::load(&write_daemon(
        dir.path(),
        &shipped_daemon_text_without_monitor(),
        Some(&m),
    ))
    .unwrap();
    assert_eq!(c.alerts.shimmy_deg, 0.3);
    assert_eq!(c.warnings.len(), 1, "{:?}", c.warnings);
    let w = &c.warnings[0];
    assert!(
        w.contains("monitor.toml") && w.contains("shimmy_amplitude_deg"),
        "{w}"
    );
    assert!(w.contains("use shimmy_deg"), "{w}");
}

#[test]
fn shimmyd_prints_the_deprecation_warnings_when_checking_an_old_layout_file() {
    let out = std::process::Command::new(env!("CARGO_BIN_EXE_shimmyd"))
        .arg("--config")
        .arg(old_layout_path())
        .arg("--check")
        .output()
        .unwrap();
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(out.status.success(), "{err}");
    assert!(
        err.contains("warning: ") && err.contains("[observer.estimator] in the daemon's"),
        "{err}"
    );
}

// ---- docs/CONFIG.md names every key ----

/// (table, key) of every leaf of `v`; `table` is dotted, "" for the top level.
fn leaves(prefix: &str, v: &toml::Table, out: &mut Vec<(String, String)>) {
    for (k, v) in v {
        match v {
            toml::Value::Table(t) => {
                let p = if prefix.is_empty() {
                    k.clone()
                } else {
                    format!("{prefix}.{k}")
                };
                leaves(&p, t, out);
            }
            _ => out.push((prefix.to_string(), k.clone())),
        }
    }
}

/// The text of `part` (a `## ` heading) of the doc.
fn part<'a>(doc: &'a str, heading: &str) -> &'a str {
    let start = doc
        .find(&format!("\n## {heading}"))
        .unwrap_or_else(|| panic!("docs/CONFIG.md has no `## {heading}`"));
    let rest = &doc[start + 1..];
    &rest[..rest[3..].find("\n## ").map_or(rest.len(), |i| i + 3)]
}

/// The text of the `### `[table]`` heading's section within `part` (`### Top-level keys` for "").
fn section<'a>(part: &'a str, table: &str) -> Option<&'a str> {
    let h = if table.is_empty() {
        "\n### Top-level keys".to_string()
    } else {
        format!("\n### `[{table}]`")
    };
    let start = part.find(&h)?;
    let rest = &part[start + 1..];
    Some(&rest[..rest[4..].find("\n### ").map_or(rest.len(), |i| i + 4)])
}

fn check_documented(doc: &str, heading: &str, value: toml::Table, skip: &[&str]) -> usize {
    let p = part(doc, heading);
    let mut keys = Vec::new();
    leaves("", &value, &mut keys);
    let mut missing = Vec::new();
    for (table, key) in &keys {
        if skip
            .iter()
            .any(|s| table == s || table.starts_with(&format!("{s}.")))
        {
            continue;
        }
        match section(p, table) {
            Some(s) if s.contains(&format!("`{key}`")) => {}
            _ => missing.push(format!("[{table}] {key}")),
        }
    }
    assert!(
        missing.is_empty(),
        "docs/CONFIG.md `## {heading}` does not document: {missing:?}"
    );
    keys.len()
}

#[test]
fn config_doc_names_every_key_of_both_files() {
    let doc = std::fs::read_to_string(workspace().join("docs/CONFIG.md")).unwrap();
    // The defaults, with the optional keys (absent by default) given.
    let obs = ObserverConfig::from_toml_str("[estimator]\nprior_range_mm = [0.03, 0.4]\n").unwrap();
    let obs = toml::Value::try_from(&obs).unwrap();
    let n = check_documented(
        &doc,
        "The monitor's settings",
        obs.as_table().unwrap().clone(),
        &[],
    );
    assert!(n > 40, "only {n} monitor keys walked");
    let daemon: Config = toml::from_str(
        r#"
monitor = "observer.toml"
[input]
profile = "p"
dbc = "a.dbc"
mapping = "m.toml"
[vehicle]
params = "v.toml"
table = "t.json"
[outputs]
journal_dir = "j"
state_dir = "s"
transmit_interface = "can0"
[mqtt]
cursor_file = "q"
port = 8883
transport = "tls"
ca_file = "ca.pem"
cert_file = "v.pem"
key_file = "v.key"
"#,
    )
    .unwrap();
    let daemon = toml::Value::try_from(&daemon).unwrap();
    // [events], [alerts] and [observer] in the daemon's file are the deprecated copies of the
    // monitor's tables: the doc lists them as such, below.
    let n = check_documented(
        &doc,
        "The daemon's file",
        daemon.as_table().unwrap().clone(),
        &["events", "alerts", "observer"],
    );
    assert!(n > 25, "only {n} daemon keys walked");
    let dep = part(&doc, "Deprecated");
    for (old, new) in DEPRECATED_TABLES {
        assert!(
            dep.contains(&format!("`[{old}]`")) && dep.contains(&format!("`[{new}]`")),
            "docs/CONFIG.md `## Deprecated` lacks [{old}] -> [{new}]"
        );
    }
    for (old, new) in shimmy::observer::alerts::DEPRECATED_KEYS {
        assert!(
            dep.contains(&format!("`{old}`")) && dep.contains(&format!("`{new}`")),
            "docs/CONFIG.md `## Deprecated` lacks {old} -> {new}"
        );
    }
}

#[test]
fn readme_and_help_point_to_the_config_doc() {
    let readme = std::fs::read_to_string(workspace().join("README.md")).unwrap();
    assert!(readme.contains("docs/CONFIG.md"));
    let out = std::process::Command::new(env!("CARGO_BIN_EXE_shimmyd"))
        .arg("--help")
        .output()
        .unwrap();
    assert!(String::from_utf8_lossy(&out.stdout).contains("docs/CONFIG.md"));
    let out = std::process::Command::new(env!("CARGO_BIN_EXE_shimmy"))
        .args(["estimate", "--help"])
        .output()
        .unwrap();
    assert!(String::from_utf8_lossy(&out.stdout).contains("docs/CONFIG.md"));
}
