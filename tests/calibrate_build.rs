//! How `shimmy calibrate` builds tables: one pull-away per vehicle and clearance serves every
//! speed and deceleration (the model time it saves is counted, not timed), one set of model
//! runs serves every sensor of the profiles that share a chassis, a killed build resumes to
//! the same table byte for byte, and the build reports its progress.

use std::path::{Path, PathBuf};
use std::process::{Command, Stdio};
use std::time::{Duration, Instant};

use shimmy::model::VehicleParams;
use shimmy::observer::sensor::SensorModel;
use shimmy::observer::simulate::{measure_run, run_model_grid, EventShape};
use shimmy::observer::ObserverConfig;
use shimmy::profile::Profile;

fn shimmy() -> Command {
    Command::new(env!("CARGO_BIN_EXE_shimmy"))
}

fn repo(rel: &str) -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR")).join(rel)
}

/// A small build: 3 clearances x 18 vehicles = 54 jobs of 2 speeds x 2 decelerations.
const SMALL: [&str; 10] = [
    "--clearances",
    "3",
    "--vehicles",
    "18",
    "--speeds",
    "45,60",
    "--decels",
    "0.4,0.7",
    "--threads",
    "2",
];

#[test]
fn one_pull_away_serves_every_speed_and_deceleration_at_under_half_the_model_time() {
    let p = VehicleParams::default();
    let cfg = ObserverConfig::default();
    let speeds: Vec<f64> = (0..29).map(|k| (30.0 + 2.5 * k as f64) / 3.6).collect();
    let decels = [0.3, 0.55, 0.8];
    let seeds: Vec<u64> = (0..29).map(|k| 123_000 + k).collect();
    let grid = run_model_grid(
        &p,
        0.15e-3,
        &speeds,
        &decels,
        &seeds,
        EventShape::DRIVE,
        &cfg,
        None,
    )
    .unwrap();
    let alone: usize = grid.runs.iter().flatten().map(|r| r.sw_rad.len()).sum();
    assert!(
        2 * grid.control_periods as usize <= alone,
        "{} control periods for runs that alone take {alone}",
        grid.control_periods
    );
    let sensor = SensorModel::default();
    let mut phases = Vec::new();
    for (iv, by_decel) in grid.runs.iter().enumerate() {
        let onset = by_decel[0].pedal.iter().position(|&b| b).unwrap();
        for (id, run) in by_decel.iter().enumerate() {
            // The decelerations of one speed share everything before the brake ...
            assert_eq!(run.pedal.iter().position(|&b| b), Some(onset));
            assert_eq!(run.sw_rad[..onset], by_decel[0].sw_rad[..onset]);
            // ... and each is the event it was asked for, as the detector measures it.
            let e = measure_run(run, &sensor, &cfg, 7 + id as u64).unwrap();
            assert!(
                (e.v0_kmh - speeds[iv] * 3.6).abs() < 1.0,
                "v0 {} for {}",
                e.v0_kmh,
                speeds[iv] * 3.6
            );
            assert!(
                (e.decel_g - decels[id]).abs() < 0.05,
                "decel {} for {}",
                e.decel_g,
                decels[id]
            );
            assert!(e.features.cruise_rms_deg.is_some());
        }
        phases.push(by_decel[0].phase_cos);
        assert_ne!(by_decel[1].sw_rad, by_decel[0].sw_rad);
    }
    // Each speed drives on with its own wheel phases (its own seed), not the trunk's.
    phases.sort_by(f64::total_cmp);
    phases.dedup();
    assert_eq!(phases.len(), speeds.len());
}

/// Runs `shimmy calibrate` to the end; returns its stderr.
fn build(args: &[&str], envs: &[(&str, &str)]) -> String {
    let out = shimmy()
        .arg("calibrate")
        .args(args)
        .envs(envs.iter().copied())
        .output()
        .unwrap();
    let err = String::from_utf8_lossy(&out.stderr).to_string();
    assert!(
        out.status.success(),
        "shimmy calibrate {args:?} failed:\n{err}"
    );
    err
}

fn parts_in(dir: &Path) -> usize {
    std::fs::read_dir(dir)
        .map(|rd| {
            rd.flatten()
                .filter(|e| {
                    let n = e.file_name();
                    let n = n.to_string_lossy();
                    n.starts_with("part-") && n.ends_with(".json")
                })
                .count()
        })
        .unwrap_or(0)
}

#[test]
fn a_build_killed_at_random_resumes_to_the_same_table_and_reports_progress() {
    let tmp = tempfile::tempdir().unwrap();
    let d = tmp.path();
    let (out_a, out_b) = (d.join("a.json"), d.join("b.json"));
    let (work_a, work_b) = (d.join("wa"), d.join("wb"));
    // The uninterrupted build, printing a progress line after every job.
    let mut args: Vec<&str> = SMALL.to_vec();
    let oa = out_a.to_str().unwrap();
    let wa = work_a.to_str().unwrap();
    args.extend(["--out", oa, "--work-dir", wa]);
    let err = build(&args, &[("SHIMMY_PROGRESS_EVERY_S", "0")]);
    let done: Vec<usize> = err
        .lines()
        .filter(|l| l.contains(" jobs (") && l.contains("ETA"))
        .map(|l| {
            let k = l.split_whitespace().nth(2).unwrap();
            k.split('/').next().unwrap().parse().unwrap()
        })
        .collect();
    assert!(done.len() >= 10, "progress lines:\n{err}");
    assert!(done.windows(2).all(|w| w[0] < w[1]), "{done:?}");
    assert_eq!(*done.last().unwrap(), 54, "{err}");
    assert!(err.contains("54/54 jobs (100.0 %)"), "{err}");
    assert_eq!(
        std::fs::read_dir(&work_a).unwrap().count(),
        0,
        "the build's work directory is removed after success"
    );

    // The same build killed after a random number of finished jobs, then run again.
    let nanos = std::time::SystemTime::now()
        .duration_since(std::time::UNIX_EPOCH)
        .unwrap()
        .subsec_nanos() as usize;
    let kill_after = 3 + (nanos ^ std::process::id() as usize) % 40;
    let ob = out_b.to_str().unwrap();
    let wb = work_b.to_str().unwrap();
    let mut args_b: Vec<&str> = SMALL.to_vec();
    args_b.extend(["--out", ob, "--work-dir", wb, "--quiet"]);
    let mut child = shimmy()
        .arg("calibrate")
        .args(&args_b)
        .stderr(Stdio::null())
        .spawn()
        .unwrap();
    let t0 = Instant::now();
    loop {
        let n = std::fs::read_dir(&work_b)
            .ok()
            .and_then(|mut rd| rd.next())
            .and_then(|e| e.ok())
            .map_or(0, |e| parts_in(&e.path()));
        if n >= kill_after || t0.elapsed() > Duration::from_secs(300) {
            break;
        }
        if child.try_wait().unwrap().is_some() {
            break;
        }
        std::thread::sleep(Duration::from_millis(5));
    }
    child.kill().ok();
    child.wait().unwrap();
    assert!(
        !out_b.exists(),
        "killed after {kill_after} jobs, before the table"
    );
    args_b.retain(|a| *a != "--quiet");
    let err = build(&args_b, &[]);
    assert!(err.contains("resuming: "), "{err}");
    let a = std::fs::read(&out_a).unwrap();
    let b = std::fs::read(&out_b).unwrap();
    assert!(
        a == b,
        "the resumed table differs (killed after {kill_after} jobs)"
    );
}

#[test]
fn profiles_sharing_a_chassis_share_the_model_runs_and_each_gets_its_sensor_table() {
    let tmp = tempfile::tempdir().unwrap();
    let root = tmp.path().join("vehicles");
    let src = repo("config/vehicles/shimmy_reference");
    for (name, rate) in [("ref100", "100.0"), ("ref83", "82.9")] {
        let dir = root.join(name);
        std::fs::create_dir_all(&dir).unwrap();
        std::fs::copy(src.join("mapping.toml"), dir.join("mapping.toml")).unwrap();
        let text = std::fs::read_to_string(src.join("profile.toml"))
            .unwrap()
            .replace("rate_hz = 100.0", &format!("rate_hz = {rate}"))
            .replace("aliases = [\"reference\"]", "aliases = []")
            .replace("bus = \"bus.toml\"\n", "");
        std::fs::write(dir.join("profile.toml"), text).unwrap();
    }
    let mut args: Vec<&str> = SMALL.to_vec();
    args.extend(["--profile", "ref100,ref83"]);
    let err = build(&args, &[("SHIMMY_PROFILES", root.to_str().unwrap())]);
    assert!(err.contains("measured through 2 sensor(s)"), "{err}");
    assert_eq!(
        err.matches(" jobs x ").count(),
        1,
        "one set of model runs:\n{err}"
    );
    for name in ["ref100", "ref83"] {
        let p = Profile::load_dir(&root.join(name)).unwrap();
        let t = p.load_table().unwrap().expect("written");
        assert_eq!(t.sensor, p.sensor);
        assert!(err.contains(&format!("for profile {name}")), "{err}");
    }
}
