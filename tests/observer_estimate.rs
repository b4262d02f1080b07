//! `shimmy estimate`'s chain (log → DBC → mapping → events → observer) on real data and on bad
//! input (issue 5 items 4 and "must show": the real RAV4 log has no braking event).

use std::path::{Path, PathBuf};

use shimmy::cli::estimate::estimate_files;
use shimmy::observer::ObserverConfig;

fn root() -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR"))
}

#[test]
fn real_rav4_log_reports_no_events_and_no_alerts() {
    let Some((log, dbc)) = shimmy::shared_data::require_rav4() else {
        return;
    };
    let (report, stats) = estimate_files(
        &root().join("config/vehicles/toyota_rav4/mapping.toml"),
        Some(&dbc),
        None,
        ObserverConfig::default(),
        &[log],
    )
    .unwrap();
    // The chain really read the car's signals ...
    assert!(stats.frames > 50_000, "{stats:?}");
    assert!(stats.mapped_frames > 10_000, "{stats:?}");
    // ... and found no braking: no events, no alerts, no invented clearance.
    assert!(report.events.is_empty(), "{:#?}", report.events);
    assert!(report.alerts.is_empty());
    assert_eq!(report.clearance_mm, None);
    assert!(!report.detectable);
    let json = serde_json::to_value(&report).unwrap();
    for key in [
        "clearance_mm",
        "interval_mm",
        "detectable",
        "events",
        "alerts",
    ] {
        assert!(json.get(key).is_some(), "JSON lacks {key}");
    }
}

#[test]
fn a_missing_log_or_mapping_is_a_clear_error() {
    let err = estimate_files(
        &root().join("config/vehicles/shimmy_reference/mapping.toml"),
        Some(&root().join("dbc/shimmy_reference.dbc")),
        None,
        ObserverConfig::default(),
        &[PathBuf::from("/nonexistent/drive.log")],
    )
    .unwrap_err();
    assert!(
        format!("{err:#}").contains("/nonexistent/drive.log"),
        "{err:#}"
    );
    let err = estimate_files(
        Path::new("/nonexistent/mapping.toml"),
        None,
        None,
        ObserverConfig::default(),
        &[],
    )
    .unwrap_err();
    assert!(format!("{err:#}").contains("mapping"), "{err:#}");
}
