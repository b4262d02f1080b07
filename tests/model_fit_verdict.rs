//! The goodness-of-fit verdict as a user meets it: `shimmy estimate` on a firmware-sim vehicle
//! with 12 braking events reports `model_fit` (deviance, degrees of freedom, normal score). The
//! vehicle as the table models it fits, and the verdict is the plain estimate. The same vehicle
//! on roads 7.5 times rougher than the table assumes (MODEL.md §7 σ = 1.5 N·m, not 0.2) does
//! not, under any of the profile's angle tables (its own, a scrub radius's, uneven discs'): the
//! verdict says so, with the score and the limit, as one sentence.

mod e2e_common;

use std::path::{Path, PathBuf};
use std::process::Command;

use e2e_common::{estimate_reference, firmware_sim, workspace};

/// One firmware-sim vehicle (seed 77100, 12 events) on the reference bus; `plant` replaces the
/// model's vehicle file.
fn vehicle_log(dir: &Path, plant: Option<&Path>) -> PathBuf {
    let mut cmd = Command::new(firmware_sim());
    cmd.current_dir(workspace()).args([
        "fleet",
        "--profile",
        "shimmy_reference",
        "--vehicles",
        "1",
        "--events",
        "12",
        "--seed-base",
        "77100",
        "--logs-only",
    ]);
    if let Some(p) = plant {
        cmd.arg("--plant").arg(p);
    }
    let out = cmd.arg("--work-dir").arg(dir).output().unwrap();
    assert!(
        out.status.success(),
        "firmware-sim fleet: {}",
        String::from_utf8_lossy(&out.stderr)
    );
    dir.join("fleet_77100.log")
}

#[test]
fn a_vehicle_on_rougher_roads_than_the_table_knows_is_told_the_model_does_not_fit() {
    let dir = tempfile::tempdir().unwrap();
    let fits = estimate_reference(&vehicle_log(&dir.path().join("model"), None), None);
    let fit = &fits["model_fit"];
    assert!(
        fit["dof"].as_f64().unwrap() >= 12.0,
        "{fit}: too few features"
    );
    assert_eq!(fit["fits"], true, "{fit}");
    let verdict = fits["verdict"].as_str().unwrap();
    assert!(!verdict.contains("does not fit"), "{verdict}");

    let model = std::fs::read_to_string(workspace().join("config/vehicle/default.toml")).unwrap();
    let rough = model.replace("noise_std_nm = 0.2 ", "noise_std_nm = 1.5 ");
    assert_ne!(
        rough, model,
        "the road-noise key moved in config/vehicle/default.toml"
    );
    let plant = dir.path().join("rough.toml");
    std::fs::write(&plant, rough).unwrap();
    let misfit = estimate_reference(&vehicle_log(&dir.path().join("rough"), Some(&plant)), None);
    let f = &misfit["model_fit"];
    assert_eq!(f["fits"], false, "{f}");
    let z = f["z"].as_f64().unwrap();
    assert!(z > 4.5, "{f}");
    let v = misfit["verdict"].as_str().unwrap();
    assert!(
        v.contains("; but the model does not fit this vehicle"),
        "{v}"
    );
    assert!(
        v.contains(&format!("z = {z:.1}")) && v.contains("limit 4.5"),
        "{v}"
    );
    assert!(!v.contains("  "), "runs of spaces: {v:?}");

    // The limit is the observer's `[estimator] fit_z_max`: above the score, no verdict.
    let cfg = dir.path().join("observer.toml");
    std::fs::write(&cfg, format!("[estimator]\nfit_z_max = {:.1}\n", z + 1.0)).unwrap();
    let lenient = estimate_reference(&dir.path().join("rough/fleet_77100.log"), Some(&cfg));
    assert_eq!(lenient["model_fit"]["fits"], true);
    assert!(!lenient["verdict"]
        .as_str()
        .unwrap()
        .contains("does not fit"));
    // The check reports; it does not move the estimate.
    assert_eq!(lenient["interval_mm"], misfit["interval_mm"]);
}
