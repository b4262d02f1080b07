//! `shimmy fleet-fit`: a car model whose torque sensor reads 30 % high (its mapping's N·m per
//! count wrong) is driven by firmware-sim at new joints, vehicle by vehicle; the fit over the
//! fleet finds the gain, resumes from its events cache, and the profile that names the
//! correction applies it in `shimmy estimate` (and refuses it against another table).

mod e2e_common;

use std::path::{Path, PathBuf};
use std::process::Command;

use serde_json::Value;

/// A copy of the toyota_rav4 profile in `dir` whose mapping reads the steering torque ×1.3, its
/// tables the shipped ones (absolute paths).
fn rav4_reading_torque_high(dir: &Path) -> PathBuf {
    let dst = e2e_common::profile_copy("toyota_rav4", dir, "rav4_torque_high");
    let mapping = std::fs::read_to_string(dst.join("mapping.toml")).unwrap();
    let (head, tail) = mapping
        .split_once("[steer_torque]")
        .expect("the RAV4 maps a steering torque");
    let high = tail.replacen("scale = 0.01\n", "scale = 0.013\n", 1);
    assert_ne!(high, tail, "the RAV4's torque scale moved");
    std::fs::write(
        dst.join("mapping.toml"),
        format!("{head}[steer_torque]{high}"),
    )
    .unwrap();
    dst
}

fn shimmy(args: &[&std::ffi::OsStr]) -> std::process::Output {
    Command::new(env!("CARGO_BIN_EXE_shimmy"))
        .current_dir(e2e_common::workspace())
        .args(args)
        .output()
        .unwrap()
}

fn ok(out: &std::process::Output) -> (String, String) {
    let (so, se) = (
        String::from_utf8_lossy(&out.stdout).into_owned(),
        String::from_utf8_lossy(&out.stderr).into_owned(),
    );
    assert!(out.status.success(), "{so}\n{se}");
    (so, se)
}

#[test]
fn a_fleet_at_new_joints_reveals_a_torque_read_30_percent_high() {
    let dir = tempfile::tempdir().unwrap();
    let plant = e2e_common::column_vehicle(dir.path());
    let profile = rav4_reading_torque_high(dir.path());
    let logs = dir.path().join("new_joints");
    let out = Command::new(e2e_common::firmware_sim())
        .args(["fleet", "--profile"])
        .arg(&profile)
        .arg("--plant")
        .arg(&plant)
        .args(["--vehicles", "16", "--events", "8", "--seed-base", "7100"])
        .args(["--clearance-mm", "0.03", "--logs-only", "--work-dir"])
        .arg(&logs)
        .output()
        .unwrap();
    ok(&out);
    let mut vehicles: Vec<PathBuf> = std::fs::read_dir(&logs)
        .unwrap()
        .map(|e| e.unwrap().path())
        .filter(|p| p.extension().is_some_and(|x| x == "log"))
        .collect();
    vehicles.sort();
    assert_eq!(vehicles.len(), 16);
    let corr = profile.join("correction.toml");
    let mut args: Vec<&std::ffi::OsStr> = vec![
        "fleet-fit".as_ref(),
        "--profile".as_ref(),
        profile.as_os_str(),
        "--signal".as_ref(),
        "torque".as_ref(),
        "-o".as_ref(),
        corr.as_os_str(),
    ];
    args.extend(vehicles.iter().map(|p| p.as_os_str()));
    let (stdout, stderr) = ok(&shimmy(&args));
    assert!(stdout.contains("torque: rms ×"), "{stdout}");
    // A torque read 30 % high is a gain on every feature alike: no warning that it is not.
    assert!(stdout.contains("the gains agree"), "{stdout}");
    assert!(!stderr.contains("gains disagree"), "{stderr}");
    assert!(stderr.contains("vehicle 16/16"), "{stderr}");
    let text = std::fs::read_to_string(&corr).unwrap();
    let file: toml::Value = toml::from_str(&text).unwrap();
    let t = &file["torque_nm"];
    assert!(file.get("angle_deg").is_none(), "{text}");
    let gain = |i: usize| t["gain"][i].as_float().unwrap();
    let se = |i: usize| t["gain_se_ln"][i].as_float().unwrap();
    for f in 0..2 {
        assert!(
            (1.15..1.45).contains(&gain(f)),
            "feature {f}: gain {} (the sensor reads ×1.3)\n{text}",
            gain(f)
        );
        assert!(
            gain(f) * (-1.645 * se(f)).exp() > 1.0,
            "feature {f}: its 90 % range reaches 1\n{text}"
        );
    }
    assert_eq!(t["vehicles"].as_integer(), Some(16));

    // Resumed: the events come from the cache, the fit is the same.
    let (_, stderr) = ok(&shimmy(&args));
    assert!(
        stderr.contains("16 vehicle(s) read from the events cache"),
        "{stderr}"
    );
    assert_eq!(std::fs::read_to_string(&corr).unwrap(), text);

    // The profile names it: the estimate applies it and says so.
    let prof = std::fs::read_to_string(profile.join("profile.toml")).unwrap();
    std::fs::write(
        profile.join("profile.toml"),
        format!("correction = \"correction.toml\"\n{prof}"),
    )
    .unwrap();
    let estimate = |log: &Path| {
        shimmy(&[
            "estimate".as_ref(),
            "--profile".as_ref(),
            profile.as_os_str(),
            log.as_os_str(),
        ])
    };
    let (stdout, _) = ok(&estimate(&vehicles[0]));
    let report: Value = serde_json::from_str(&stdout).unwrap();
    let applied = &report["correction"];
    assert_eq!(
        applied["gain"][0].as_f64(),
        Some(gain(0)),
        "{}",
        serde_json::to_string_pretty(&report["correction"]).unwrap()
    );
    assert_eq!(report["signals"]["estimate_from"], "torque_nm");
    // shimmyd on the same profile applies it too: the same estimate.
    let journal = e2e_common::replay_profile(
        profile.to_str().unwrap(),
        &vehicles[0],
        &dir.path().join("shimmyd"),
        None,
    );
    let d = journal.estimate.expect("shimmyd estimated");
    let close = |a: &Value, b: &Value, what: &str| {
        let (a, b) = (a.as_f64(), b.as_f64());
        assert!(
            matches!((a, b), (Some(a), Some(b)) if (a - b).abs() <= 1e-9 * a.abs().max(1e-3)),
            "{what}: estimate {a:?}, shimmyd {b:?}"
        );
    };
    close(&report["p_clearance_above_threshold"], &d["p_above"], "P");
    for i in 0..2 {
        close(&report["interval_mm"][i], &d["interval_mm"][i], "interval");
    }
    // Without the correction the same drive reads otherwise.
    let plain = e2e_common::estimate_profile("toyota_rav4", &vehicles[0], None);
    assert!(plain.get("correction").is_none());
    assert_ne!(plain["interval_mm"], report["interval_mm"]);

    // Against another table it is refused, naming the command that fits it again.
    std::fs::write(
        &corr,
        text.replacen("table_fingerprint = \"", "table_fingerprint = \"0", 1),
    )
    .unwrap();
    let out = estimate(&vehicles[0]);
    assert!(!out.status.success());
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(
        err.contains("fitted against another torque table (fingerprint 0")
            && err.contains("shimmy fleet-fit"),
        "{err}"
    );
}

#[test]
fn vehicles_without_events_are_counted_and_too_few_are_refused() {
    let dir = tempfile::tempdir().unwrap();
    let empty = dir.path().join("parked.log");
    // A candump log with frames but no braking.
    std::fs::write(&empty, "(0.000000) can0 025#0000000000000000\n").unwrap();
    let corr = dir.path().join("c.toml");
    let out = shimmy(&[
        "fleet-fit".as_ref(),
        "--profile".as_ref(),
        "toyota_rav4".as_ref(),
        "-o".as_ref(),
        corr.as_os_str(),
        empty.as_os_str(),
        empty.as_os_str(),
    ]);
    assert!(!out.status.success());
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(
        err.contains("vehicle 1/2") && err.contains("skipped"),
        "{err}"
    );
    assert!(
        err.contains("2 of 2 vehicle(s) gave no usable braking event"),
        "{err}"
    );
    assert!(!corr.exists());
}

#[test]
fn a_sensor_noisier_than_its_table_is_refused_not_taken_for_a_gain() {
    let dir = tempfile::tempdir().unwrap();
    let plant = e2e_common::column_vehicle(dir.path());
    let logs = dir.path().join("noisy");
    let out = Command::new(e2e_common::firmware_sim())
        .args(["fleet", "--profile", "toyota_rav4", "--plant"])
        .arg(&plant)
        .args(["--vehicles", "6", "--events", "6", "--seed-base", "7200"])
        .args(["--sensor-noise-factor", "3"])
        .args(["--clearance-mm", "0.03", "--logs-only", "--work-dir"])
        .arg(&logs)
        .output()
        .unwrap();
    ok(&out);
    let corr = dir.path().join("c.toml");
    let mut args: Vec<std::ffi::OsString> = vec![
        "fleet-fit".into(),
        "--profile".into(),
        "toyota_rav4".into(),
        "--signal".into(),
        "torque".into(),
        "-o".into(),
        corr.clone().into(),
    ];
    for e in std::fs::read_dir(&logs).unwrap() {
        let p = e.unwrap().path();
        if p.extension().is_some_and(|x| x == "log") {
            args.push(p.into());
        }
    }
    let args: Vec<&std::ffi::OsStr> = args.iter().map(|a| a.as_os_str()).collect();
    let out = shimmy(&args);
    assert!(!out.status.success());
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(
        err.contains("torque: not fitted: the sensor measures")
            && err.contains("A noisier sensor is not a gain")
            && err.contains("shimmy calibrate --sensor-noise-deg"),
        "{err}"
    );
    assert!(!corr.exists());
}

/// A correction whose fit found the features' gains unequal (`gains_agree_p` below 0.05, as
/// `shimmy fleet-fit` writes it for a scrub radius or brake discs the table lacks) makes the
/// estimate say the model does not fit this vehicle, naming the correction and what to build,
/// in `shimmy estimate` and in shimmyd alike; its numbers stay the correction's. The same
/// correction with gains that agree adds no such clause.
#[test]
fn a_correction_whose_gains_disagree_says_the_model_does_not_fit() {
    let dir = tempfile::tempdir().unwrap();
    let plant = e2e_common::column_vehicle(dir.path());
    let logs = dir.path().join("drive");
    let out = Command::new(e2e_common::firmware_sim())
        .args(["fleet", "--profile", "toyota_rav4", "--plant"])
        .arg(&plant)
        .args(["--vehicles", "1", "--events", "12", "--seed-base", "7300"])
        .args(["--clearance-mm", "0.05", "--logs-only", "--work-dir"])
        .arg(&logs)
        .output()
        .unwrap();
    ok(&out);
    let log = logs.join("fleet_7300.log");
    let table = e2e_common::workspace().join("config/vehicles/toyota_rav4/table_torque.json");
    let fp = shimmy::observer::table::ResponseTable::load(&table)
        .unwrap()
        .fingerprint;
    let with_p = |name: &str, p: f64| {
        e2e_common::profile_copy_with_correction(
            "toyota_rav4",
            dir.path(),
            name,
            &format!(
                "[torque_nm]\ngain = [1.0, 1.25, 1.0]\ngain_se_ln = [0.05, 0.05, 0.07]\n\
                 spread_ln = 0.1\nvehicles = 40\nevents = 400\nclearance_mm = 0.03\n\
                 table_fingerprint = {fp:?}\ngains_agree_p = {p:?}\n"
            ),
        )
    };
    let agree = with_p("rav4_agree", 0.5);
    let disagree = with_p("rav4_disagree", 0.001);
    let estimate = |profile: &Path| {
        let (stdout, _) = ok(&shimmy(&[
            "estimate".as_ref(),
            "--profile".as_ref(),
            profile.as_os_str(),
            log.as_os_str(),
        ]));
        serde_json::from_str::<Value>(&stdout).unwrap()
    };
    let a = estimate(&agree);
    let d = estimate(&disagree);
    assert_eq!(a["signals"]["estimate_from"], "torque_nm");
    assert!(a["model_fit"].get("correction_gains_disagree").is_none());
    let verdict = a["verdict"].as_str().unwrap();
    assert!(!verdict.contains("gains unequal"), "{verdict}");

    let fit = &d["model_fit"];
    assert_eq!(fit["fits"], false, "{fit}");
    assert_eq!(fit["correction_gains_disagree"], true, "{fit}");
    let verdict = d["verdict"].as_str().unwrap();
    assert!(
        verdict.contains("does not fit")
            && verdict.contains("gains unequal")
            && verdict.contains("peak ×1.25")
            && verdict.contains("p = 0.001")
            && verdict.contains("build a table for its chassis"),
        "{verdict}"
    );
    // The clause is a verdict on the car model, not another estimate.
    assert_eq!(a["interval_mm"], d["interval_mm"]);
    assert_eq!(
        a["p_clearance_above_threshold"],
        d["p_clearance_above_threshold"]
    );

    // shimmyd on the same profile says the same.
    let journal = e2e_common::replay_profile(
        disagree.to_str().unwrap(),
        &log,
        &dir.path().join("shimmyd"),
        None,
    );
    let est = journal.estimate.expect("shimmyd estimated");
    let misfit = est["misfit"].as_str().unwrap_or_default();
    assert!(misfit.contains("gains unequal"), "{est}");
}
