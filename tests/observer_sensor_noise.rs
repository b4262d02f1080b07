//! The steering sensors' noise measured at standstill (src/observer/noise_floor.rs): a steering
//! angle sensor noisier than the response table's makes `shimmy estimate` say that the model
//! does not fit the vehicle, with that reason, the measured and assumed noise and the table to
//! build, and shimmyd's estimate carry the same reason; the sensor the table describes is
//! measured and passes.

mod e2e_common;

use std::path::Path;
use std::process::Command;

use serde_json::Value;

/// A drive of six stops from 50–75 km/h with 1 s at standstill after each, 0.2 mm joints,
/// the steering angle sensor's white noise `noise_deg`; its log.
fn drive(dir: &Path, noise_deg: f64) -> std::path::PathBuf {
    let mut s = format!(
        "seed = 31\n[clearance]\nleft_mm = 0.2\n[sensors]\nsteer_noise_deg = {noise_deg}\n\
         [drive]\nstart_speed_kmh = 50\naccel_g = 0.3\n"
    );
    for v in [50, 55, 60, 65, 70, 75] {
        s += &format!(
            "[[drive.segment]]\nkind = \"cruise\"\nspeed_kmh = {v}\nduration_s = 1.5\n\
             [[drive.segment]]\nkind = \"brake\"\ndecel_g = 0.5\nhold_s = 0.5\n\
             [[drive.segment]]\nkind = \"stand\"\nduration_s = 1.0\n"
        );
    }
    let name = format!("noise_{}", (noise_deg * 1000.0).round());
    let sc = dir.join(format!("{name}.toml"));
    std::fs::write(&sc, s).unwrap();
    let log = dir.join(format!("{name}.log"));
    e2e_common::simulate(&sc, &log, &[]);
    log
}

fn angle_noise(report: &Value) -> &Value {
    report["sensor_noise"]
        .as_array()
        .expect("a measured sensor noise")
        .iter()
        .find(|n| n["signal"] == "angle_deg")
        .expect("the angle's")
}

#[test]
fn a_steering_sensor_noisier_than_the_tables_is_named_as_the_reason_the_model_does_not_fit() {
    let dir = tempfile::tempdir().unwrap();
    // The reference table's sensor: 0.01 deg white noise in 0.1 deg steps, 0.031 deg RMS.
    let ok = e2e_common::estimate_reference(&drive(dir.path(), 0.01), None);
    let n = angle_noise(&ok);
    assert_eq!(n["stops"], 6, "{n}");
    assert_eq!(n["above_assumed"], false, "{n}");
    let (m, a) = (
        n["measured_rms"].as_f64().unwrap(),
        n["assumed_rms"].as_f64().unwrap(),
    );
    assert!(
        (a - (0.1f64.powi(2) / 12.0 + 1e-4).sqrt()).abs() < 1e-9,
        "{n}"
    );
    assert!(m < 1.2 * a, "{n}");
    assert!(ok["model_fit"].get("sensor_noisier").is_none(), "{ok}");
    assert!(!ok["verdict"].as_str().unwrap().contains("noisier"), "{ok}");

    // Eight times that white noise: about 0.085 deg RMS with the steps.
    let noisy = e2e_common::estimate_reference(&drive(dir.path(), 0.08), None);
    let n = angle_noise(&noisy);
    assert_eq!(n["above_assumed"], true, "{n}");
    let m = n["measured_rms"].as_f64().unwrap();
    let want = (0.08f64.powi(2) + 0.1f64.powi(2) / 12.0).sqrt();
    assert!(
        (m / want - 1.0).abs() < 0.2,
        "measured {m}, want about {want}"
    );
    assert_eq!(noisy["model_fit"]["fits"], false, "{noisy}");
    assert_eq!(noisy["model_fit"]["sensor_noisier"], true, "{noisy}");
    let v = noisy["verdict"].as_str().unwrap();
    assert!(
        v.contains("model does not fit")
            && v.contains("steering angle sensor is noisier")
            && v.contains("--sensor-noise-deg"),
        "{v}"
    );
    // The same events are used: the check says how far to trust them, it drops nothing.
    assert_eq!(noisy["events_used"], ok["events_used"]);

    // shimmyd on the same logs: its estimate carries the reason (and raises no clearance
    // alert from it: src/alerts); the matched sensor's carries none.
    let j = e2e_common::replay_reference(&drive(dir.path(), 0.08), &dir.path().join("d1"), None);
    let est = j.estimate.expect("an estimate record");
    let why = est["misfit"].as_str().unwrap_or_default();
    assert!(why.contains("steering angle sensor is noisier"), "{est}");
    assert_eq!(est["sensor_noisier"], true, "{est}");
    let j = e2e_common::replay_reference(&drive(dir.path(), 0.01), &dir.path().join("d2"), None);
    assert!(j.estimate.unwrap().get("misfit").is_none());
}

#[test]
fn the_noise_check_can_be_turned_off() {
    let dir = tempfile::tempdir().unwrap();
    let cfg = dir.path().join("observer.toml");
    std::fs::write(&cfg, "[features]\nnoise_floor_ratio = 0\n").unwrap();
    let r = e2e_common::estimate_reference(&drive(dir.path(), 0.08), Some(&cfg));
    assert_eq!(angle_noise(&r)["above_assumed"], false, "{r}");
    assert!(!r["verdict"].as_str().unwrap().contains("noisier"), "{r}");
    std::fs::write(&cfg, "[features]\nnoise_floor_ratio = -1\n").unwrap();
    let out = Command::new(env!("CARGO_BIN_EXE_shimmy"))
        .current_dir(e2e_common::workspace())
        .args(["estimate", "--profile", "shimmy_reference", "--config"])
        .arg(&cfg)
        .arg(dir.path().join("noise_80.log"))
        .output()
        .unwrap();
    assert!(!out.status.success());
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(err.contains("noise_floor_ratio"), "{err}");
}
