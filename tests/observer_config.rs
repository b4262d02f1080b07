//! config/observer.toml's `[alerts]` keys: shimmyd's names are the canonical ones; the earlier
//! names still load, with the same values and a deprecation warning naming the new key.

use std::path::Path;

use shimmy::alerts::AlertsSection;
use shimmy::observer::alerts::DEPRECATED_KEYS;
use shimmy::observer::ObserverConfig;

const NEW: &str = "[alerts]
clearance_mm = 0.12
clearance_probability = 0.8
shimmy_deg = 0.25
shimmy_speed_min_kmh = 45.0
shimmy_speed_max_kmh = 65.0
shimmy_window = 6
shimmy_confirm = 3
";

const OLD: &str = "[alerts]
clearance_mm = 0.12
clearance_probability = 0.8
shimmy_amplitude_deg = 0.25
shimmy_speed_lo_kmh = 45.0
shimmy_speed_hi_kmh = 65.0
shimmy_window = 6
shimmy_confirm = 3
";

#[test]
fn new_keys_load_without_warnings() {
    let (c, w) = ObserverConfig::from_toml_str_with_warnings(NEW).unwrap();
    assert!(w.is_empty(), "{w:?}");
    let a = &c.alerts;
    assert_eq!(
        (a.shimmy_deg, a.shimmy_speed_min_kmh, a.shimmy_speed_max_kmh),
        (0.25, 45.0, 65.0)
    );
    assert_eq!((a.clearance_mm, a.clearance_probability), (0.12, 0.8));
    assert_eq!((a.shimmy_window, a.shimmy_confirm), (6, 3));
}

#[test]
fn old_keys_load_the_same_values_with_a_warning_naming_the_new_key() {
    let (new, _) = ObserverConfig::from_toml_str_with_warnings(NEW).unwrap();
    let (old, w) = ObserverConfig::from_toml_str_with_warnings(OLD).unwrap();
    assert_eq!(old, new);
    assert_eq!(w.len(), DEPRECATED_KEYS.len(), "{w:?}");
    for ((old_key, new_key), msg) in DEPRECATED_KEYS.iter().zip(&w) {
        assert!(msg.contains(old_key) && msg.contains(new_key), "{msg}");
        assert!(msg.contains("deprecated"), "{msg}");
    }
    // One old key among new ones: one warning, for that key.
    let mixed = NEW.replace("shimmy_speed_max_kmh", "shimmy_speed_hi_kmh");
    let (c, w) = ObserverConfig::from_toml_str_with_warnings(&mixed).unwrap();
    assert_eq!(c, new);
    assert_eq!(w.len(), 1, "{w:?}");
    assert!(w[0].contains("shimmy_speed_hi_kmh") && w[0].contains("use shimmy_speed_max_kmh"));
}

#[test]
fn loading_a_file_names_it_in_the_warnings() {
    let dir = tempfile::tempdir().unwrap();
    let p = dir.path().join("observer.toml");
    std::fs::write(&p, OLD).unwrap();
    let (c, w) = ObserverConfig::load_with_warnings(&p).unwrap();
    assert_eq!(c.alerts.shimmy_deg, 0.25);
    assert_eq!(w.len(), DEPRECATED_KEYS.len());
    assert!(
        w.iter().all(|m| m.starts_with(&p.display().to_string())),
        "{w:?}"
    );
    // `load` prints them and returns the same configuration.
    assert_eq!(ObserverConfig::load(&p).unwrap(), c);
}

#[test]
fn unknown_or_doubled_keys_are_errors() {
    let typo = NEW.replace("shimmy_deg", "shimmy_degs");
    let e = format!("{:#}", ObserverConfig::from_toml_str(&typo).unwrap_err());
    assert!(e.contains("shimmy_degs"), "{e}");
    // The old and the new name of one setting together: which one counts would be a guess.
    let both = format!("{NEW}shimmy_amplitude_deg = 0.3\n");
    let e = format!("{:#}", ObserverConfig::from_toml_str(&both).unwrap_err());
    assert!(e.contains("shimmy_deg"), "{e}");
}

#[test]
fn shipped_config_uses_the_new_names_and_the_defaults() {
    let p = Path::new(env!("CARGO_MANIFEST_DIR")).join("config/observer.toml");
    let (c, w) = ObserverConfig::load_with_warnings(&p).unwrap();
    assert!(w.is_empty(), "{w:?}");
    assert_eq!(c, ObserverConfig::default());
}

#[test]
fn observer_and_daemon_alert_keys_are_the_same_names_with_the_same_defaults() {
    // Every key of the observer's [alerts] is a key of shimmyd's [alerts], same default.
    let obs = toml::Value::try_from(ObserverConfig::default().alerts).unwrap();
    let daemon = toml::Value::try_from(AlertsSection::default()).unwrap();
    let (obs, daemon) = (obs.as_table().unwrap(), daemon.as_table().unwrap());
    for (k, v) in obs {
        assert_eq!(daemon.get(k), Some(v), "observer [alerts] {k}");
    }
}
