//! `shimmy estimate` says why braking gave nothing: on firmware-sim's demo log (three braking
//! events on the reference bus) under a mapping whose acceleration sign is inverted, every brake
//! application is ignored as too light; the report counts them per reason, the verdict names
//! the likely cause, and `--format text` prints the counts. Under the shipped mapping the same
//! log has nothing to explain.

use std::path::{Path, PathBuf};
use std::process::Command;

use shimmy::cli::estimate::estimate_files;
use shimmy::observer::ObserverConfig;

fn repo(rel: &str) -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join(rel)
}

const DEMO: &str = "tests/fixtures/demo/worn_0p2mm.log";
const MAPPING: &str = "config/vehicles/shimmy_reference/mapping.toml";

/// The reference mapping with `invert = true` under [accel], written into `dir`.
fn inverted_accel_mapping(dir: &Path) -> PathBuf {
    let text = std::fs::read_to_string(repo(MAPPING)).unwrap();
    let marker = "signal = \"VEH_LongAccel\"\nunit = \"m/s^2\"\n";
    assert!(
        text.contains(marker),
        "the reference mapping changed: {text}"
    );
    let text = text.replace(marker, &format!("{marker}invert = true\n"));
    let p = dir.join("mapping.toml");
    std::fs::write(&p, text).unwrap();
    p
}

fn dbc() -> PathBuf {
    repo("dbc/shimmy_reference.dbc")
}

#[test]
fn an_inverted_accel_sign_is_counted_and_explained_in_the_report() {
    let dir = tempfile::tempdir().unwrap();
    let mapping = inverted_accel_mapping(dir.path());
    let (report, _) = estimate_files(
        &mapping,
        Some(&dbc()),
        None,
        ObserverConfig::default(),
        &[repo(DEMO)],
    )
    .unwrap();
    let r = &report.rejections;
    assert_eq!(report.events.len(), 0, "{:#?}", report.events);
    assert_eq!(r.ignored, 3, "{r:?}");
    assert_eq!(r.ignored_by_reason.too_light, 3, "{r:?}");
    assert_eq!(r.ignored_by_reason.accel_while_braking, 3, "{r:?}");
    assert_eq!(report.ignored_applications.len(), 3);
    for a in &report.ignored_applications {
        assert!(a.too_light && a.peak_accel_g > 0.3, "{a:?}");
    }
    assert!(
        report.verdict.contains("3 brake applications ignored")
            && report.verdict.contains("invert")
            && report.verdict.contains("shimmy doctor"),
        "{}",
        report.verdict
    );
    let json = serde_json::to_value(&report).unwrap();
    assert_eq!(json["rejections"]["ignored_by_reason"]["too_light"], 3);
    assert_eq!(json["rejections"]["recorded"], 0);
    assert_eq!(json["ignored_applications"].as_array().unwrap().len(), 3);
}

#[test]
fn the_shipped_mapping_records_the_demo_events_with_nothing_ignored() {
    let (report, _) = estimate_files(
        &repo(MAPPING),
        Some(&dbc()),
        None,
        ObserverConfig::default(),
        &[repo(DEMO)],
    )
    .unwrap();
    let r = &report.rejections;
    assert_eq!((r.ignored, r.recorded, r.used), (0, 3, 3), "{r:?}");
    assert!(!r.worth_reporting());
    assert_eq!(r.unused_by_reason.total(), 0);
}

#[test]
fn estimate_text_prints_the_counts_and_the_hint() {
    let dir = tempfile::tempdir().unwrap();
    let mapping = inverted_accel_mapping(dir.path());
    let out = Command::new(env!("CARGO_BIN_EXE_shimmy"))
        .args(["estimate", "--format", "text", "--mapping"])
        .arg(&mapping)
        .arg("--dbc")
        .arg(dbc())
        .arg(repo(DEMO))
        .output()
        .unwrap();
    let text = String::from_utf8_lossy(&out.stdout);
    assert!(
        out.status.success(),
        "{text}\n{}",
        String::from_utf8_lossy(&out.stderr)
    );
    assert!(
        text.contains("braking: 3 brake applications ignored (peak deceleration below 0.15 g: 3)"),
        "{text}"
    );
    assert!(text.contains("toggle `invert` under [accel]"), "{text}");
}

#[test]
fn shimmyd_logs_and_journals_the_rejections() {
    let dir = tempfile::tempdir().unwrap();
    let mapping = inverted_accel_mapping(dir.path());
    let cfg = dir.path().join("shimmyd.toml");
    std::fs::write(
        &cfg,
        format!(
            "[input]\ndbc = {:?}\nmapping = {:?}\n[outputs]\njournal_dir = \"journal\"\n\
             state_dir = \"state\"\n",
            dbc(),
            mapping
        ),
    )
    .unwrap();
    let out = Command::new(env!("CARGO_BIN_EXE_shimmyd"))
        .arg("--config")
        .arg(&cfg)
        .arg("--replay")
        .arg(repo(DEMO))
        .arg("--fast")
        .arg("--state-dir")
        .arg(dir.path().join("state"))
        .current_dir(dir.path())
        .output()
        .unwrap();
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(out.status.success(), "{err}");
    assert!(
        err.contains("braking: 3 brake applications ignored") && err.contains("[accel]"),
        "{err}"
    );
    let mut r = shimmy::journal::Reader::open(&dir.path().join("journal")).unwrap();
    let stop = (&mut r)
        .map(|e| e.unwrap().rec)
        .find(|rec| rec["type"] == "stop")
        .expect("a stop record");
    assert_eq!(
        stop["rejections"]["ignored_by_reason"]["too_light"], 3,
        "{stop}"
    );
}

/// A file that is not a CAN log at all (text of another kind) is an error naming the file and
/// what it is not, rather than an estimate that found no braking.
#[test]
fn a_file_that_is_not_a_can_log_is_an_error_not_an_empty_estimate() {
    let dir = tempfile::tempdir().unwrap();
    let csv = dir.path().join("speeds.csv");
    std::fs::write(&csv, "t,speed_kmh\n0.0,50.0\n0.1,49.5\n").unwrap();
    let err = estimate_files(
        &repo(MAPPING),
        Some(&dbc()),
        None,
        ObserverConfig::default(),
        &[repo(DEMO), csv.clone()],
    )
    .map(|_| ())
    .unwrap_err();
    let msg = format!("{err:#}");
    assert!(msg.contains("speeds.csv"), "{msg}");
    assert!(msg.contains("no CAN frame could be read"), "{msg}");
    // An empty log is no error: nothing in it to misread.
    let empty = dir.path().join("empty.log");
    std::fs::write(&empty, "").unwrap();
    estimate_files(
        &repo(MAPPING),
        Some(&dbc()),
        None,
        ObserverConfig::default(),
        &[empty],
    )
    .unwrap();
}
