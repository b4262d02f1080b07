//! The monitor's settings file is checked wherever it is read, not only by shimmyd: `shimmy
//! estimate --config FILE` refuses a file whose alert would flap (clear threshold at or past
//! the raise threshold), whose probability is not one, or whose speed range is upside down,
//! naming the file, the key and the value; the shipped file passes.

use std::path::PathBuf;
use std::process::Command;

use shimmy::observer::ObserverConfig;

fn workspace() -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR"))
}

fn shipped() -> String {
    std::fs::read_to_string(workspace().join("config/observer.toml")).unwrap()
}

#[test]
fn the_shipped_settings_pass_and_broken_ones_name_the_key() {
    ObserverConfig::load(&workspace().join("config/observer.toml")).unwrap();
    let dir = tempfile::tempdir().unwrap();
    let cases = [
        (
            "clearance_clear_probability = 0.5",
            "clearance_clear_probability = 0.8",
            "alerts.clearance_clear_probability (0.8) must be below alerts.clearance_probability",
        ),
        (
            "clearance_probability = 0.7",
            "clearance_probability = 1.0",
            "alerts.clearance_probability: must be a probability",
        ),
        (
            "clearance_wheel_order_probability = 0.85",
            "clearance_wheel_order_probability = 0.6",
            "alerts.clearance_probability (0.7) must be at most \
             alerts.clearance_wheel_order_probability (0.6)",
        ),
        (
            "clearance_wheel_order_clear_probability = 0.7",
            "clearance_wheel_order_clear_probability = 0.9",
            "alerts.clearance_wheel_order_clear_probability (0.9) must be below \
             alerts.clearance_wheel_order_probability (0.85)",
        ),
        (
            "clearance_wheel_order_clear_probability = 0.7",
            "clearance_wheel_order_clear_probability = 0.4",
            "alerts.clearance_clear_probability (0.5) must be at most \
             alerts.clearance_wheel_order_clear_probability (0.4)",
        ),
        (
            "clearance_confirm = 2",
            "clearance_confirm = 0",
            "alerts.clearance_confirm: must be 1..=64 braking events (got 0)",
        ),
        (
            "max_speed_kmh = 120.0",
            "max_speed_kmh = 15.0",
            "events.min_speed_kmh (20) must be below events.max_speed_kmh (15)",
        ),
        (
            "evidence_power = 0.275",
            "evidence_power = 0",
            "estimator.evidence_power",
        ),
    ];
    for (from, to, needle) in cases {
        let text = shipped();
        assert!(text.contains(from), "config/observer.toml lost `{from}`");
        let p = dir.path().join("observer.toml");
        std::fs::write(&p, text.replacen(from, to, 1)).unwrap();
        let e = format!("{:#}", ObserverConfig::load(&p).unwrap_err());
        assert!(
            e.contains(needle) && e.contains(&p.display().to_string()),
            "{to}: {e}"
        );

        let out = Command::new(env!("CARGO_BIN_EXE_shimmy"))
            .current_dir(workspace())
            .args(["estimate", "--profile", "shimmy_reference", "--config"])
            .arg(&p)
            .arg("tests/fixtures/demo/worn_0p2mm.log")
            .output()
            .unwrap();
        assert!(!out.status.success(), "{to}: shimmy estimate accepted it");
        let err = String::from_utf8_lossy(&out.stderr);
        assert!(err.contains(needle), "{to}: {err}");
    }
}
