//! `shimmy decode --mapping`: the mapped quantities with their validity, end to end through the
//! binary, on the real RAV4 log and on a reference-bus log with faults in it.

mod signals_common;

use std::process::Command;

use shimmy::shared_data::require_file;
use shimmy::signals::checksum::ChecksumKind;
use shimmy::source::recorder::CandumpWriter;
use shimmy::wire::Frame;
use signals_common::{reference_db, repo};

fn shimmy(args: &[&str]) -> (bool, String, String) {
    let o = Command::new(env!("CARGO_BIN_EXE_shimmy"))
        .args(args)
        .output()
        .unwrap();
    (
        o.status.success(),
        String::from_utf8(o.stdout).unwrap(),
        String::from_utf8(o.stderr).unwrap(),
    )
}

#[test]
fn rav4_log_prints_every_mapped_frame_with_validity() {
    let (Some(dbc), Some(log)) = (
        require_file("dbc/opendbc/toyota_new_mc_pt_generated.dbc"),
        require_file("logs/comma2k19-rav4/rav4_2017_seg40_bus0.log"),
    ) else {
        return;
    };
    let mapping = repo("config/vehicles/toyota_rav4/mapping.toml");
    let (ok, out, err) = shimmy(&[
        "decode",
        "--dbc",
        dbc.to_str().unwrap(),
        "--mapping",
        mapping.to_str().unwrap(),
        log.to_str().unwrap(),
    ]);
    assert!(ok, "{err}");
    let mut n = 0;
    let (mut lo, mut hi) = (f64::MAX, f64::MIN);
    let mut steer_frames = 0;
    let (mut torque_frames, mut tq_lo, mut tq_hi) = (0, f64::MAX, f64::MIN);
    for line in out.lines() {
        let v: serde_json::Value = serde_json::from_str(line).unwrap();
        n += 1;
        assert!(v.get("rejected").is_none(), "{line}");
        assert_eq!(v["validity"]["brake_pressure"], "not_mapped");
        if v["msg"] == "STEER_ANGLE_SENSOR" {
            steer_frames += 1;
            assert_eq!(v["validity"]["steer_angle"], "valid");
            let a = v["steer_angle_deg"].as_f64().unwrap();
            lo = lo.min(a);
            hi = hi.max(a);
        }
        if v["msg"] == "STEER_TORQUE_SENSOR" {
            torque_frames += 1;
            assert_eq!(v["validity"]["steer_torque"], "valid");
            let t = v["steer_torque_nm"].as_f64().unwrap();
            tq_lo = tq_lo.min(t);
            tq_hi = tq_hi.max(t);
        }
        if let Some(b) = v["brake_pressed"].as_bool() {
            assert!(!b, "no braking in this log");
        }
        if let Some(s) = v["speed_kmh"].as_f64() {
            // The wheel speeds' mean (the speedometer's SPEED reads 29.4-73.1 km/h).
            assert!((28.0..=72.0).contains(&s), "{s}");
        }
    }
    // STEER_ANGLE_SENSOR, WHEEL_SPEEDS and KINEMATICS at 83 Hz, BRAKE_MODULE at 41 Hz,
    // STEER_TORQUE_SENSOR at 50 Hz.
    assert_eq!(n, 4974 + 4974 + 2487 + 4974 + 3000);
    assert_eq!(steer_frames, 4974);
    // STEER_TORQUE_DRIVER spans -149..138 counts, at the mapping's 100 counts per N·m.
    assert_eq!((torque_frames, tq_lo, tq_hi), (3000, -1.49, 1.38));
    assert_eq!((lo, hi), (-4.6, 2.5));
    assert!(
        err.contains("STEER_ANGLE_SENSOR (0x25): 4974 frames, 4974 accepted, 0 checksum errors"),
        "{err}"
    );
    assert!(err.contains("53800 frames read"), "{err}");
}

/// A reference-bus log of 1 s: 100 Hz steering with a bad checksum at frame 30, a repeated
/// counter at frame 60 and an outage from 700 to 800 ms; 50 Hz speed.
fn faulty_reference_log(path: &std::path::Path) {
    let db = reference_db();
    let msg = |n: &str| db.messages()[db.message_by_name(n).unwrap()].clone();
    let (sas, veh) = (msg("SAS_01"), msg("VEH_01"));
    let mut w = CandumpWriter::create(path)
        .unwrap()
        .with_default_iface("vcan0");
    let pack = |m: &shimmy::dbc::Message, vals: &[(&str, f64)]| {
        let mut d = [0u8; 8];
        for (s, v) in vals {
            m.signals[m.signal_by_name(s).unwrap()]
                .encode_phys(*v, &mut d)
                .unwrap();
        }
        ChecksumKind::Shimmy.apply(m.id, &mut d).unwrap();
        d
    };
    let mut counter = 0u8;
    for k in 0..100i64 {
        let t = 1_000_000_000 + k * 10_000_000;
        if !(70..80).contains(&k) {
            let c = if k == 60 {
                counter.wrapping_sub(1) % 16
            } else {
                counter
            };
            let mut d = pack(&sas, &[("SAS_Angle", 1.5), ("SAS_Counter", c as f64)]);
            if k == 30 {
                d[0] ^= 1;
            }
            w.write(&Frame::classic(t, sas.id, false, &d).unwrap())
                .unwrap();
            if k != 60 {
                counter = (counter + 1) % 16;
            }
        }
        if k % 2 == 0 {
            let d = pack(
                &veh,
                &[("VEH_Speed", 55.0), ("VEH_Counter", ((k / 2) % 16) as f64)],
            );
            w.write(&Frame::classic(t + 1_000_000, veh.id, false, &d).unwrap())
                .unwrap();
        }
    }
    w.flush().unwrap();
}

#[test]
fn faults_are_shown_per_frame_and_counted_in_the_summary() {
    let dir = std::env::temp_dir().join(format!("shimmy-signals-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    let log = dir.join("faulty.log");
    faulty_reference_log(&log);
    let (ok, out, err) = shimmy(&[
        "decode",
        "--dbc",
        repo("dbc/shimmy_reference.dbc").to_str().unwrap(),
        "--mapping",
        repo("config/vehicles/shimmy_reference/mapping.toml")
            .to_str()
            .unwrap(),
        "--format",
        "csv",
        log.to_str().unwrap(),
    ]);
    std::fs::remove_dir_all(&dir).ok();
    assert!(ok, "{err}");
    let rows: Vec<Vec<&str>> = out.lines().map(|l| l.split(',').collect()).collect();
    assert_eq!(rows[0][0], "t");
    assert_eq!(rows[0].len(), 15);
    assert_eq!(rows[0][14], "rejected");
    let rejected: Vec<&Vec<&str>> = rows[1..].iter().filter(|r| !r[14].is_empty()).collect();
    assert_eq!(rejected.len(), 2, "{rejected:?}");
    assert!(rejected[0][14].starts_with("checksum"), "{:?}", rejected[0]);
    assert!(rejected[1][14].contains("repeated"), "{:?}", rejected[1]);
    // The reference bus carries no torque: the column says so on every row.
    assert!(rows[1..].iter().all(|r| r[13] == "not_mapped"));
    // During the outage the speed rows show the steering angle timed out, and no value.
    let timed_out: Vec<&Vec<&str>> = rows[1..].iter().filter(|r| r[3] == "timed_out").collect();
    assert!(!timed_out.is_empty());
    assert!(timed_out
        .iter()
        .all(|r| r[1] == "VEH_01" && r[2].is_empty()));
    // Brake never sent: no data, never received.
    assert!(rows[1..].iter().all(|r| r[9] == "no_data"));
    assert!(
        err.contains("BRK_01 (0xB0): 0 frames") && err.contains("NEVER RECEIVED"),
        "{err}"
    );
    assert!(
        err.contains("SAS_01 (0xA0): 90 frames, 88 accepted, 1 checksum errors, 1 counter errors"),
        "{err}"
    );
    assert!(err.contains("1 timeouts (> 50 ms)"), "{err}");
}

#[test]
fn a_mapping_that_does_not_fit_the_dbc_is_a_clear_error() {
    let dir = std::env::temp_dir().join(format!("shimmy-signals-bad-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    let bad = dir.join("bad.toml");
    let text = std::fs::read_to_string(repo("config/vehicles/shimmy_reference/mapping.toml"))
        .unwrap()
        .replace("signal = \"VEH_Speed\"", "signal = \"VEH_Spede\"");
    std::fs::write(&bad, text).unwrap();
    let log = dir.join("empty.log");
    std::fs::write(&log, "").unwrap();
    let dbc = repo("dbc/shimmy_reference.dbc");
    let (ok, _, err) = shimmy(&[
        "decode",
        "--dbc",
        dbc.to_str().unwrap(),
        "--mapping",
        bad.to_str().unwrap(),
        log.to_str().unwrap(),
    ]);
    assert!(!ok);
    assert!(
        err.contains("speed.signal") && err.contains("VEH_Spede"),
        "{err}"
    );
    let (ok, _, err) = shimmy(&[
        "decode",
        "--dbc",
        dbc.to_str().unwrap(),
        "--mapping",
        repo("config/vehicles/shimmy_reference/mapping.toml")
            .to_str()
            .unwrap(),
        "--raw",
        log.to_str().unwrap(),
    ]);
    std::fs::remove_dir_all(&dir).ok();
    assert!(!ok);
    assert!(err.contains("--raw"), "{err}");
}
