//! `shimmy estimate --baseline LOG` and shimmyd's `vehicle.baseline_logs`: a drive of the same
//! car with new joints, given with the logs, conditions the estimate on what its events say
//! about the car, the same in both; its use is reported, and a baseline the estimator cannot
//! use is an error that says why.

mod e2e_common;

use std::process::Command;

use serde_json::Value;

fn estimate(args: &[&std::ffi::OsStr]) -> std::process::Output {
    Command::new(env!("CARGO_BIN_EXE_shimmy"))
        .current_dir(e2e_common::workspace())
        .args(["estimate", "--profile", "shimmy_reference"])
        .args(args)
        .output()
        .unwrap()
}

#[test]
fn a_baseline_drive_conditions_the_estimate_and_is_reported() {
    let dir = tempfile::tempdir().unwrap();
    let new = e2e_common::generate("new_car", None, dir.path());
    let worn = e2e_common::generate("worn_0p2mm", None, dir.path());
    let plain = e2e_common::estimate_reference(&worn.log, None);
    assert!(plain.get("baseline").is_none(), "{plain}");
    let out = estimate(&[
        "--baseline".as_ref(),
        new.log.as_os_str(),
        "--baseline-clearance-mm".as_ref(),
        "0.03".as_ref(),
        worn.log.as_os_str(),
    ]);
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    let with: Value = serde_json::from_slice(&out.stdout).unwrap();
    let base = &with["baseline"];
    assert_eq!(base["clearance_mm"], 0.03);
    let n_new = new.truth["events"].as_array().unwrap().len() as u64;
    let taken = base["angle_events"].as_u64().unwrap();
    assert!(taken >= 1 && taken <= n_new, "{base} of {n_new} events");
    // The baseline's events are not the report's, and the same events are used.
    assert_eq!(with["events"], plain["events"]);
    assert_eq!(with["events_used"], plain["events_used"]);
    assert_ne!(
        with["interval_mm"], plain["interval_mm"],
        "the baseline changed nothing"
    );
}

#[test]
fn a_baseline_without_usable_events_or_clearance_is_refused() {
    let dir = tempfile::tempdir().unwrap();
    let worn = e2e_common::generate("worn_0p2mm", None, dir.path());
    // A log with frames but no braking: its first lines.
    let text = std::fs::read_to_string(&worn.log).unwrap();
    let short = dir.path().join("parked.log");
    std::fs::write(
        &short,
        text.lines().take(200).collect::<Vec<_>>().join("\n") + "\n",
    )
    .unwrap();
    let out = estimate(&[
        "--baseline".as_ref(),
        short.as_os_str(),
        worn.log.as_os_str(),
    ]);
    assert!(!out.status.success());
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(err.contains("baseline logs hold no braking event"), "{err}");
    let out = estimate(&[
        "--baseline".as_ref(),
        worn.log.as_os_str(),
        "--baseline-clearance-mm".as_ref(),
        "0".as_ref(),
        worn.log.as_os_str(),
    ]);
    assert!(!out.status.success());
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(err.contains("--baseline-clearance-mm"), "{err}");
}

/// shimmyd with `vehicle.baseline_logs` estimates what `shimmy estimate --baseline` does, says
/// so at start, and keeps the baseline in its state.
#[test]
fn shimmyd_takes_the_same_baseline_from_its_config() {
    let dir = tempfile::tempdir().unwrap();
    let new = e2e_common::generate("new_car", None, dir.path());
    let worn = e2e_common::generate("worn_0p2mm", None, dir.path());
    let out = estimate(&[
        "--baseline".as_ref(),
        new.log.as_os_str(),
        worn.log.as_os_str(),
    ]);
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    let est: Value = serde_json::from_slice(&out.stdout).unwrap();
    let run = dir.path().join("daemon");
    std::fs::create_dir_all(&run).unwrap();
    let cfg = run.join("shimmyd.toml");
    std::fs::write(
        &cfg,
        format!(
            "[input]\nprofile = \"shimmy_reference\"\n\
             [vehicle]\nbaseline_logs = [{:?}]\nbaseline_clearance_mm = 0.03\n\
             [outputs]\njournal_dir = \"journal\"\nstate_dir = \"state\"\n",
            new.log.display().to_string()
        ),
    )
    .unwrap();
    let out = e2e_common::replay_command(&cfg, &worn.log, None)
        .current_dir(e2e_common::workspace())
        .output()
        .unwrap();
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert!(out.status.success(), "{stderr}");
    assert!(stderr.contains("baseline:"), "{stderr}");
    let j = e2e_common::Journal::read(&run.join("journal"));
    let d = j.estimate.expect("an estimate record");
    for i in 0..2 {
        let (a, b) = (
            est["interval_mm"][i].as_f64().unwrap(),
            d["interval_mm"][i].as_f64().unwrap(),
        );
        assert!((a - b).abs() <= 1e-9 * a.max(b), "interval {i}: {a} vs {b}");
    }
    let state = std::fs::read_to_string(run.join("state/state.json")).unwrap_or_default();
    assert!(
        state.contains("\"baseline\""),
        "the state keeps no baseline"
    );
}
