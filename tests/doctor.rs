//! `shimmy doctor` on real and simulated logs:
//! * the real RAV4 drive (bus 0, a highway minute without braking) passes with the shipped
//!   `toyota_rav4` profile, its turning relations judged, its brake check "not enough data";
//! * the same drive under mappings altered in one place each (acceleration sign, steering
//!   sign, steering scale ×10 and ×0.1, lateral acceleration sign) fails, naming the fix;
//! * a few seconds of it are "not enough data" for the turning checks, not pass or fail;
//! * firmware-sim's demo log (reference bus, three stops) passes and lists its braking
//!   candidates, with the reason when one is not used.

use std::path::{Path, PathBuf};
use std::process::Command;

use shimmy::doctor::checks::Status;
use shimmy::doctor::{self, Diagnosis};
use shimmy::observer::ObserverConfig;
use shimmy::profile::Profile;
use shimmy::shared_data;

fn repo(rel: &str) -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join(rel)
}

fn check<'a>(d: &'a Diagnosis, name: &str) -> &'a shimmy::doctor::checks::Check {
    d.checks
        .iter()
        .find(|c| c.name == name)
        .unwrap_or_else(|| panic!("no check {name}: {:#?}", d.checks))
}

fn failed(d: &Diagnosis) -> Vec<String> {
    d.checks
        .iter()
        .filter(|c| c.status == Status::Fail)
        .map(|c| format!("{}: {} [fix: {:?}]", c.name, c.summary, c.fix))
        .collect()
}

fn rav4() -> Option<(PathBuf, Profile)> {
    let (log, _) = shared_data::require_rav4()?;
    Some((log, Profile::load("toyota_rav4").unwrap()))
}

/// The RAV4 profile with its mapping text changed by `edit`, diagnosed on `log`.
fn diagnose_altered(p: &Profile, log: &Path, edit: impl Fn(&str) -> String) -> Diagnosis {
    let text = std::fs::read_to_string(&p.mapping_path).unwrap();
    let altered = edit(&text);
    assert_ne!(altered, text, "the edit changed nothing");
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("mapping.toml");
    std::fs::write(&path, altered).unwrap();
    let mut setup =
        doctor::setup_from_mapping(&path, Some(&p.dbc_path), ObserverConfig::default()).unwrap();
    setup.vehicle = p.vehicle.clone();
    doctor::diagnose(&setup, &[log.to_path_buf()]).unwrap()
}

const STEER_UNIT: &str = "fraction_signal = \"STEER_FRACTION\"\nunit = \"deg\"\n";
const ACCEL_INVERT: &str = "signal = \"ACCEL_X\"\nunit = \"m/s^2\"\ninvert = true\n";
const LAT_INVERT: &str = "signal = \"ACCEL_Y\"\nunit = \"m/s^2\"\ninvert = true\n";

#[test]
fn the_real_rav4_drive_passes_with_its_shipped_profile() {
    let Some((log, p)) = rav4() else {
        return;
    };
    let setup = doctor::setup_from_profile(&p, "test".into(), ObserverConfig::default());
    let d = doctor::diagnose(&setup, &[log]).unwrap();
    assert!(!d.failed(), "{:#?}", failed(&d));
    for name in [
        "accel against d(speed)/dt",
        "steer_angle against turning",
        "yaw_rate against turning",
        "lat_accel against turning",
    ] {
        assert_eq!(
            check(&d, name).status,
            Status::Pass,
            "{:#?}",
            check(&d, name)
        );
    }
    // No braking in this minute: the brake cannot be judged, and nothing is a candidate.
    let b = check(&d, "brake against deceleration");
    assert_eq!(b.status, Status::NotEnoughData, "{b:#?}");
    assert!(b.summary.contains("not enough braking"), "{}", b.summary);
    assert!(d.braking.candidates.is_empty());
    assert_eq!(d.verdict.status, "ok");
    // The relations measured on this drive (see the profile's mapping.toml).
    let yaw = &check(&d, "steer_angle against turning").evidence[0]["fit"];
    let (k, r) = (yaw["slope"].as_f64().unwrap(), yaw["r"].as_f64().unwrap());
    assert!(
        (0.4..0.8).contains(&k) && r > 0.85,
        "yaw against steering: {yaw}"
    );
    let acc = &check(&d, "accel against d(speed)/dt").evidence;
    assert!(acc["slope"].as_f64().unwrap() > 0.6, "{acc}");
    // The speed is the wheel speeds' mean, at their 83 Hz (not the speedometer's SPEED at 41 Hz).
    let speed = d
        .signals
        .iter()
        .find(|s| s.source.starts_with("WHEEL_SPEEDS."))
        .unwrap();
    assert!((speed.rate_hz.unwrap() - 82.9).abs() < 0.2, "{speed:?}");
}

#[test]
fn an_inverted_acceleration_sign_is_flagged_with_its_fix() {
    let Some((log, p)) = rav4() else {
        return;
    };
    let d = diagnose_altered(&p, &log, |t| {
        t.replace(ACCEL_INVERT, "signal = \"ACCEL_X\"\nunit = \"m/s^2\"\n")
    });
    let c = check(&d, "accel against d(speed)/dt");
    assert_eq!(c.status, Status::Fail, "{c:#?}");
    assert_eq!(c.fix.as_deref(), Some("set `invert = true` under [accel]"));
    assert_eq!(d.verdict.fixes, vec!["set `invert = true` under [accel]"]);
    assert_eq!(failed(&d).len(), 1, "{:#?}", failed(&d));
}

#[test]
fn an_inverted_steering_sign_is_flagged_on_the_steering_not_on_the_yaw_rate() {
    let Some((log, p)) = rav4() else {
        return;
    };
    let d = diagnose_altered(&p, &log, |t| {
        t.replace(STEER_UNIT, &format!("{STEER_UNIT}invert = true\n"))
    });
    let c = check(&d, "steer_angle against turning");
    assert_eq!(c.status, Status::Fail, "{c:#?}");
    assert_eq!(
        c.fix.as_deref(),
        Some("set `invert = false` under [steer_angle]")
    );
    assert_eq!(check(&d, "yaw_rate against turning").status, Status::Pass);
    assert_eq!(check(&d, "lat_accel against turning").status, Status::Pass);
    assert_eq!(failed(&d).len(), 1, "{:#?}", failed(&d));
}

#[test]
fn an_inverted_lateral_acceleration_is_flagged_on_itself() {
    let Some((log, p)) = rav4() else {
        return;
    };
    let d = diagnose_altered(&p, &log, |t| {
        t.replace(LAT_INVERT, "signal = \"ACCEL_Y\"\nunit = \"m/s^2\"\n")
    });
    let c = check(&d, "lat_accel against turning");
    assert_eq!(c.status, Status::Fail, "{c:#?}");
    assert_eq!(
        c.fix.as_deref(),
        Some("set `invert = true` under [lat_accel]")
    );
    assert_eq!(
        check(&d, "steer_angle against turning").status,
        Status::Pass
    );
}

#[test]
fn a_steering_scale_off_by_ten_is_flagged_with_the_scale_that_fixes_it() {
    let Some((log, p)) = rav4() else {
        return;
    };
    for (scale, fix) in [
        (
            "10.0",
            "remove `scale` under [steer_angle] (or set `scale = 1`)",
        ),
        (
            "0.1",
            "remove `scale` under [steer_angle] (or set `scale = 1`)",
        ),
        (
            "100.0",
            "remove `scale` under [steer_angle] (or set `scale = 1`)",
        ),
    ] {
        let d = diagnose_altered(&p, &log, |t| {
            t.replace(STEER_UNIT, &format!("{STEER_UNIT}scale = {scale}\n"))
        });
        let c = check(&d, "steer_angle against turning");
        assert_eq!(c.status, Status::Fail, "scale {scale}: {c:#?}");
        assert_eq!(c.fix.as_deref(), Some(fix), "scale {scale}: {c:#?}");
        assert!(!c.summary.contains("inverted"), "{}", c.summary);
        assert_eq!(check(&d, "yaw_rate against turning").status, Status::Pass);
    }
}

#[test]
fn degrees_read_as_radians_are_flagged_with_the_unit_to_set() {
    let Some((log, p)) = rav4() else {
        return;
    };
    let d = diagnose_altered(&p, &log, |t| {
        t.replace(
            STEER_UNIT,
            "fraction_signal = \"STEER_FRACTION\"\nunit = \"rad\"\n",
        )
    });
    let c = check(&d, "steer_angle against turning");
    assert_eq!(c.status, Status::Fail, "{c:#?}");
    assert_eq!(
        c.fix.as_deref(),
        Some("set `unit = \"deg\"` under [steer_angle]"),
        "{c:#?}"
    );
}

#[test]
fn a_few_seconds_of_driving_are_not_enough_data_rather_than_a_verdict() {
    let Some((log, p)) = rav4() else {
        return;
    };
    let text = std::fs::read_to_string(&log).unwrap();
    let first: f64 = text[1..text.find(')').unwrap()].parse().unwrap();
    let short: String = text
        .lines()
        .filter(|l| {
            let t: f64 = l[1..l.find(')').unwrap()].parse().unwrap();
            t - first < 6.0
        })
        .map(|l| format!("{l}\n"))
        .collect();
    let dir = tempfile::tempdir().unwrap();
    let short_log = dir.path().join("short.log");
    std::fs::write(&short_log, short).unwrap();
    // Even with the steering inverted, 6 s cannot tell.
    let d = diagnose_altered(&p, &short_log, |t| {
        t.replace(STEER_UNIT, &format!("{STEER_UNIT}invert = true\n"))
    });
    let c = check(&d, "steer_angle against turning");
    assert_eq!(c.status, Status::NotEnoughData, "{c:#?}");
    assert!(c.summary.starts_with("not enough turning"), "{}", c.summary);
    assert_eq!(
        check(&d, "accel against d(speed)/dt").status,
        Status::NotEnoughData
    );
    assert!(!d.failed(), "{:#?}", failed(&d));
}

#[test]
fn the_demo_log_passes_and_lists_its_braking_candidates() {
    let p = Profile::load("shimmy_reference").unwrap();
    let log = repo("tests/fixtures/demo/worn_0p2mm.log");
    let setup = doctor::setup_from_profile(&p, "test".into(), ObserverConfig::default());
    let d = doctor::diagnose(&setup, std::slice::from_ref(&log)).unwrap();
    assert!(!d.failed(), "{:#?}", failed(&d));
    assert_eq!(check(&d, "brake against deceleration").status, Status::Pass);
    assert_eq!(check(&d, "accel against d(speed)/dt").status, Status::Pass);
    assert_eq!(
        check(&d, "steer_angle against turning").status,
        Status::NotChecked
    );
    let used: Vec<_> = d
        .braking
        .candidates
        .iter()
        .map(|c| (c.outcome, c.v0_kmh.round()))
        .collect();
    assert_eq!(
        used,
        vec![("used", 75.0), ("used", 55.0), ("used", 40.0)],
        "{:#?}",
        d.braking
    );

    // With a narrower deceleration range the 0.6 g stop is recorded but not used, and says why.
    let mut cfg = ObserverConfig::default();
    cfg.events.max_decel_g = 0.55;
    let setup = doctor::setup_from_profile(&p, "test".into(), cfg);
    let d = doctor::diagnose(&setup, &[log]).unwrap();
    let first = &d.braking.candidates[0];
    assert_eq!(first.outcome, "not used", "{first:#?}");
    assert!(
        first.reason.contains("deceleration outside 0.3-0.55 g") && first.reason.contains("0.60 g"),
        "{}",
        first.reason
    );
    assert_eq!(d.braking.rejections.unused_by_reason.decel_out_of_range, 1);
}

#[test]
fn the_command_exits_1_on_a_failed_check_and_0_otherwise() {
    let demo = repo("tests/fixtures/demo/worn_0p2mm.log");
    let run = |args: &[&str]| {
        Command::new(env!("CARGO_BIN_EXE_shimmy"))
            .arg("doctor")
            .args(args)
            .arg(&demo)
            .output()
            .unwrap()
    };
    // No profile or mapping: the log is identified first.
    let out = run(&["--format", "json"]);
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    let v: serde_json::Value = serde_json::from_slice(&out.stdout).unwrap();
    assert_eq!(v["profile"], "shimmy_reference");
    assert!(v["chosen_by"].as_str().unwrap().contains("identified"));
    assert_eq!(v["verdict"]["status"], "ok");
    assert_eq!(v["braking"]["candidates"].as_array().unwrap().len(), 3);

    let dir = tempfile::tempdir().unwrap();
    let text = std::fs::read_to_string(repo("config/vehicles/shimmy_reference/mapping.toml"))
        .unwrap()
        .replace(
            "signal = \"VEH_LongAccel\"\nunit = \"m/s^2\"\n",
            "signal = \"VEH_LongAccel\"\nunit = \"m/s^2\"\ninvert = true\n",
        );
    let m = dir.path().join("m.toml");
    std::fs::write(&m, text).unwrap();
    let dbc = repo("dbc/shimmy_reference.dbc");
    let out = run(&[
        "--mapping",
        m.to_str().unwrap(),
        "--dbc",
        dbc.to_str().unwrap(),
    ]);
    let text = String::from_utf8_lossy(&out.stdout);
    assert_eq!(out.status.code(), Some(1), "{text}");
    assert!(
        text.contains("fix: set `invert = false` under [accel]"),
        "{text}"
    );
    assert!(text.contains("ignored: peak deceleration"), "{text}");
    assert!(text.contains("acceleration sign?"), "{text}");
}
