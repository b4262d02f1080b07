//! Shared by the shimmyd end-to-end tests (`tests/shimmyd_e2e_scenarios.rs`,
//! `tests/shimmyd_e2e_vcan.rs`, `tests/shimmyd_load_vcan.rs` and others): the two executables
//! run as processes (firmware-sim writes or sends a scenario, shimmyd replays or reads it live,
//! [`LiveDaemon`]), the daemon configuration they use, and
//! what a run left in the journal, summarised for comparison with firmware-sim's ground truth.
//!
//! What it is not: a test, or a second implementation of the alert rules. The only rule here is
//! [`truth_shimmy`], the issue-6 criterion applied to the ground truth with a margin band.
#![allow(dead_code)] // each test crate uses a different subset

use std::path::{Path, PathBuf};
use std::process::{Command, Output};
use std::sync::OnceLock;
use std::time::{Duration, Instant};

use serde_json::Value;
use shimmy::journal::Reader;

#[path = "../support/outside_cargo.rs"]
mod outside_cargo;

pub fn workspace() -> &'static Path {
    Path::new(env!("CARGO_MANIFEST_DIR"))
}

/// The shimmyd executable: cargo's on the build host, else `shimmyd` on the `PATH` (the VM of
/// `tests/vcan/vm.sh`, which puts the suite's static executables there).
pub fn shimmyd() -> PathBuf {
    let p = PathBuf::from(env!("CARGO_BIN_EXE_shimmyd"));
    if p.exists() {
        p
    } else {
        PathBuf::from("shimmyd")
    }
}

/// The firmware-sim executable (another workspace member, so cargo gives this package no
/// `CARGO_BIN_EXE_` for it):
/// 1. `SHIMMY_FWSIM_BIN` when set and not empty (tests/vcan/vm.sh sets it to its static build);
/// 2. else built now with the cargo, target directory and profile that built this test (a
///    no-op when it is up to date, as after `cargo test --workspace`), so a test never runs a
///    stale simulator; without cargo's test variables ([`outside_cargo`]: seen by this inner
///    build, they made ring's build script rerun and ring, rustls and both packages rebuild,
///    and then once more for the next build outside a test);
/// 3. else (no cargo: a copied test executable) `firmware-sim` on the `PATH`.
pub fn firmware_sim() -> PathBuf {
    static BIN: OnceLock<PathBuf> = OnceLock::new();
    BIN.get_or_init(|| {
        if let Some(p) = std::env::var_os("SHIMMY_FWSIM_BIN").filter(|p| !p.is_empty()) {
            return PathBuf::from(p);
        }
        let cargo = PathBuf::from(env!("CARGO"));
        let shimmyd = PathBuf::from(env!("CARGO_BIN_EXE_shimmyd"));
        if !cargo.exists() || !shimmyd.exists() {
            return PathBuf::from("firmware-sim");
        }
        // <target dir>[/<triple>]/<profile dir>/shimmyd
        let profile_dir = shimmyd.parent().expect("shimmyd has a directory");
        let mut target_dir = profile_dir.parent().expect("profile dir has a parent");
        let mut triple = None;
        if !target_dir.join("CACHEDIR.TAG").exists() && target_dir.join("../CACHEDIR.TAG").exists()
        {
            triple = target_dir
                .file_name()
                .map(|t| t.to_string_lossy().into_owned());
            target_dir = target_dir.parent().unwrap();
        }
        let profile = match profile_dir.file_name().and_then(|p| p.to_str()) {
            Some("debug") => "dev",
            Some(p) => p,
            None => "dev",
        };
        let mut cmd = outside_cargo::outside_cargo(Command::new(&cargo));
        cmd.current_dir(workspace())
            .args([
                "build",
                "--quiet",
                "-p",
                "firmware-sim",
                "--bin",
                "firmware-sim",
            ])
            .args(["--profile", profile, "--target-dir"])
            .arg(target_dir)
            .arg("--message-format=json");
        if let Some(t) = &triple {
            cmd.args(["--target", t]);
        }
        let out = cmd
            .output()
            .unwrap_or_else(|e| panic!("cannot run {}: {e}", cargo.display()));
        assert!(
            out.status.success(),
            "building firmware-sim failed: {}",
            String::from_utf8_lossy(&out.stderr)
        );
        String::from_utf8_lossy(&out.stdout)
            .lines()
            .filter_map(|l| serde_json::from_str::<Value>(l).ok())
            .find_map(|m| {
                (m["target"]["name"] == "firmware-sim")
                    .then(|| m["executable"].as_str().map(PathBuf::from))
                    .flatten()
            })
            .expect("cargo reported no firmware-sim executable")
    })
    .clone()
}

/// A firmware-sim run: its log, ground truth and stderr.
pub struct Generated {
    pub log: PathBuf,
    pub truth: Value,
    pub stderr: String,
}

/// Runs `firmware-sim [args] --scenario SCENARIO --out LOG` and asserts it succeeded; its
/// stderr.
pub fn simulate(scenario: &Path, log: &Path, args: &[&str]) -> String {
    let out = Command::new(firmware_sim())
        .args(args)
        .arg("--scenario")
        .arg(scenario)
        .arg("--out")
        .arg(log)
        .output()
        .expect("start firmware-sim");
    let stderr = String::from_utf8_lossy(&out.stderr).into_owned();
    assert!(
        out.status.success(),
        "firmware-sim {}: {stderr}",
        scenario.display()
    );
    stderr
}

/// Runs `firmware-sim --scenario config/scenarios/<name>.toml --out <dir>/<name>.log`, with
/// the scenario's seed or `seed`.
pub fn generate(name: &str, seed: Option<u64>, dir: &Path) -> Generated {
    let scenario = workspace().join(format!("config/scenarios/{name}.toml"));
    let log = dir.join(format!("{name}.log"));
    let truth = dir.join(format!("{name}.truth.json"));
    let mut cmd = Command::new(firmware_sim());
    cmd.arg("--scenario")
        .arg(&scenario)
        .arg("--out")
        .arg(&log)
        .arg("--truth")
        .arg(&truth);
    if let Some(s) = seed {
        cmd.arg("--seed").arg(s.to_string());
    }
    let out = cmd.output().expect("start firmware-sim");
    let stderr = String::from_utf8_lossy(&out.stderr).into_owned();
    assert!(out.status.success(), "firmware-sim {name}: {stderr}");
    let truth = serde_json::from_str(&std::fs::read_to_string(&truth).unwrap()).unwrap();
    Generated { log, truth, stderr }
}

/// config/vehicle/default.toml with its MODEL.md §15 column enabled, written to
/// `dir/column.toml`: a vehicle with a steering column (rim, torsion bar, hands).
pub fn column_vehicle(dir: &Path) -> PathBuf {
    let text = std::fs::read_to_string(workspace().join("config/vehicle/default.toml")).unwrap();
    let (head, tail) = text.split_once("[column]").expect("a [column] section");
    let tail = tail.replacen("enabled = false", "enabled = true", 1);
    let path = dir.join("column.toml");
    std::fs::write(&path, format!("{head}[column]{tail}")).unwrap();
    path
}

/// The documented default alert rule for the 55 km/h shimmy alert (config/shimmyd.toml), written
/// into every test configuration so that [`truth_shimmy`] applies the same numbers.
pub const SHIMMY_CONFIRM: usize = 2;
pub const SHIMMY_WINDOW: usize = 5;

/// A daemon configuration in `dir` with the repository's reference DBC and mapping, the
/// default vehicle and its response table (config/vehicle/), journal and state under `dir`,
/// the documented default alert thresholds and `input` as the `[input]` table's extra lines.
pub fn write_config(dir: &Path, input: &str) -> PathBuf {
    let ws = workspace();
    let p = dir.join("shimmyd.toml");
    let text = format!(
        "[input]\ndbc = {:?}\nmapping = {:?}\n{input}\n\
         [vehicle]\nparams = {:?}\ntable = {:?}\n\
         [alerts]\nshimmy_deg = 0.2\nshimmy_speed_min_kmh = 50.0\nshimmy_speed_max_kmh = 60.0\n\
         shimmy_confirm = {SHIMMY_CONFIRM}\nshimmy_window = {SHIMMY_WINDOW}\n\
         clearance_mm = 0.1\nclearance_probability = 0.7\n\
         [outputs]\njournal_dir = \"journal\"\nstate_dir = \"state\"\n\
         [log]\ncounters_interval_s = 1\n",
        ws.join("dbc/shimmy_reference.dbc"),
        ws.join("config/vehicles/shimmy_reference/mapping.toml"),
        ws.join("config/vehicle/default.toml"),
        ws.join("config/vehicles/shimmy_reference/table.json"),
    );
    std::fs::write(&p, text).unwrap();
    p
}

/// `shimmy estimate --profile shimmy_reference [--config SETTINGS] LOG`, its JSON; panics
/// unless it exits 0.
pub fn estimate_reference(log: &Path, settings: Option<&Path>) -> Value {
    estimate_profile("shimmy_reference", log, settings)
}

/// [`estimate_reference`] with the vehicle profile `profile`.
pub fn estimate_profile(profile: &str, log: &Path, settings: Option<&Path>) -> Value {
    let mut cmd = Command::new(env!("CARGO_BIN_EXE_shimmy"));
    cmd.current_dir(workspace())
        .args(["estimate", "--profile", profile]);
    if let Some(s) = settings {
        cmd.arg("--config").arg(s);
    }
    let out = cmd.arg(log).output().unwrap();
    assert!(
        out.status.success(),
        "shimmy estimate {}: {}",
        log.display(),
        String::from_utf8_lossy(&out.stderr)
    );
    serde_json::from_slice(&out.stdout).unwrap()
}

/// `shimmyd --replay LOG --fast` with the reference profile and nothing else configured but
/// the monitor's settings file `settings` when given; its journal (under `dir`).
pub fn replay_reference(log: &Path, dir: &Path, settings: Option<&Path>) -> Journal {
    replay_profile("shimmy_reference", log, dir, settings)
}

/// [`replay_reference`] with the vehicle profile `profile`.
pub fn replay_profile(profile: &str, log: &Path, dir: &Path, settings: Option<&Path>) -> Journal {
    std::fs::create_dir_all(dir).unwrap();
    let cfg = dir.join("shimmyd.toml");
    let monitor = settings.map_or(String::new(), |s| {
        format!("monitor = {:?}\n", s.display().to_string())
    });
    std::fs::write(
        &cfg,
        format!(
            "{monitor}[input]\nprofile = \"{profile}\"\n\
             [outputs]\njournal_dir = \"journal\"\nstate_dir = \"state\"\n"
        ),
    )
    .unwrap();
    let out = replay_command(&cfg, log, None)
        .current_dir(workspace())
        .output()
        .unwrap();
    assert!(
        out.status.success(),
        "shimmyd --replay {}: {}",
        log.display(),
        String::from_utf8_lossy(&out.stderr)
    );
    Journal::read(&dir.join("journal"))
}

/// `shimmyd --config CFG --replay LOG --fast --state-dir DIR`; panics unless it exits 0.
pub fn replay(cfg: &Path, log: &Path, state: &Path) -> Output {
    let out = replay_command(cfg, log, Some(state))
        .output()
        .expect("start shimmyd");
    assert!(
        out.status.success(),
        "shimmyd --replay {} failed: {}",
        log.display(),
        String::from_utf8_lossy(&out.stderr)
    );
    out
}

/// What one daemon run left in its journal.
#[derive(Debug)]
pub struct Journal {
    pub events: Vec<Value>,
    /// (transition, kind) of every alert record, in order.
    pub alerts: Vec<(String, String)>,
    /// The last estimate record's `estimate`.
    pub estimate: Option<Value>,
    /// The `stop` record (counters, per-message statistics).
    pub stop: Value,
}

impl Journal {
    /// Reads `dir`; panics on a record the reader rejects.
    pub fn read(dir: &Path) -> Journal {
        let mut r = Reader::open(dir).unwrap();
        let recs: Vec<Value> = (&mut r).map(|e| e.unwrap().rec).collect();
        assert_eq!(r.invalid_lines(), 0, "{:?}", r.problems());
        let of = |t: &'static str| recs.iter().filter(move |r| r["type"] == t);
        Journal {
            events: of("event").map(|r| r["event"].clone()).collect(),
            alerts: of("alert")
                .map(|r| {
                    (
                        r["transition"].as_str().unwrap_or("?").to_string(),
                        r["alert"]["kind"].as_str().unwrap_or("?").to_string(),
                    )
                })
                .collect(),
            estimate: of("estimate").next_back().map(|r| r["estimate"].clone()),
            stop: of("stop").next_back().cloned().expect("a stop record"),
        }
    }

    /// Whether an alert of `kind` was raised at any time.
    pub fn raised(&self, kind: &str) -> bool {
        self.alerts.iter().any(|(t, k)| t == "raised" && k == kind)
    }

    /// The alert kinds raised, sorted, without repeats.
    pub fn kinds_raised(&self) -> Vec<String> {
        let mut k: Vec<String> = self
            .alerts
            .iter()
            .filter(|(t, _)| t == "raised")
            .map(|(_, k)| k.clone())
            .collect();
        k.sort();
        k.dedup();
        k
    }

    /// The alert kinds standing at the end (raised or updated, not cleared since), sorted.
    pub fn kinds_standing(&self) -> Vec<String> {
        let mut last: Vec<(String, String)> = Vec::new();
        for (t, k) in &self.alerts {
            last.retain(|(kk, _)| kk != k);
            last.push((k.clone(), t.clone()));
        }
        let mut k: Vec<String> = last
            .into_iter()
            .filter(|(_, t)| t != "cleared")
            .map(|(k, _)| k)
            .collect();
        k.sort();
        k
    }

    /// One line for test output: events, estimate, alerts.
    pub fn describe(&self) -> String {
        let n = |v: &Value| v.as_f64().map_or("-".to_string(), |x| format!("{x:.3}"));
        let est = self
            .estimate
            .as_ref()
            .map_or("no estimate".to_string(), |e| {
                format!(
                    "estimate median {} mm, 90 % interval {}-{} mm, below {} mm, P(c > 0.1 mm) {}",
                    n(&e["clearance_mm"]),
                    n(&e["interval_mm"][0]),
                    n(&e["interval_mm"][1]),
                    n(&e["below_mm"]),
                    n(&e["p_above"])
                )
            });
        let amps: Vec<String> = self
            .events
            .iter()
            .map(|e| {
                format!(
                    "{:.0}:{}",
                    e["v0_kmh"].as_f64().unwrap_or(f64::NAN),
                    n(&e["sw_amplitude_deg"])
                )
            })
            .collect();
        format!(
            "{} events ({} used); {est}; measured amplitudes (km/h:deg) [{}]; alerts {:?}",
            self.events.len(),
            self.events.iter().filter(|e| e["used"] == true).count(),
            amps.join(" "),
            self.alerts
        )
    }
}

/// What the ground truth says about the 55 km/h shimmy alert.
#[derive(Debug, PartialEq)]
pub enum Expect {
    /// Clearly above the 0.2° threshold (> 0.25°): the alert must be raised.
    Alert,
    /// Clearly below (< 0.15°): it must not.
    NoAlert,
    /// Inside the margin band: either outcome is acceptable.
    Either,
}

/// Issue 6's "the 0.2°-at-55 km/h alert follows the ground-truth amplitude", with the margin
/// band the observer's fleet check uses (docs/ACCURACY.md). The daemon's rule is "at least
/// `confirm` of the last `window` braking events starting at 50–60 km/h above 0.2°", checked
/// after each such event; so after each one, what decides is the `confirm`-th largest true
/// amplitude in the window. The alert must be raised if that amplitude is > 0.25° after some
/// event, must not be if it stays < 0.15° after every event, and either is acceptable
/// otherwise. Returns the verdict with the largest deciding amplitude of the drive (`None`
/// when there are never `confirm` events in the window: no alert is possible).
pub fn truth_shimmy(truth: &Value, confirm: usize, window: usize) -> (Expect, Option<f64>) {
    let in_window: Vec<f64> = truth["events"]
        .as_array()
        .unwrap()
        .iter()
        .filter(|e| (50.0..=60.0).contains(&e["v0_kmh"].as_f64().unwrap()))
        .map(|e| e["sw_amplitude_deg"].as_f64().unwrap())
        .collect();
    let deciding = (1..=in_window.len())
        .filter_map(|end| {
            let mut last = in_window[end.saturating_sub(window)..end].to_vec();
            last.sort_by(|a, b| b.total_cmp(a));
            last.get(confirm - 1).copied()
        })
        .max_by(f64::total_cmp);
    match deciding {
        None => (Expect::NoAlert, None),
        Some(a) if a > 0.25 => (Expect::Alert, Some(a)),
        Some(a) if a < 0.15 => (Expect::NoAlert, Some(a)),
        Some(a) => (Expect::Either, Some(a)),
    }
}

/// `shimmyd --config CFG --replay LOG --fast [--state-dir STATE]`, not yet run: the caller adds
/// what it needs (a working directory) and decides what a failure means.
pub fn replay_command(cfg: &Path, log: &Path, state: Option<&Path>) -> Command {
    let mut cmd = Command::new(shimmyd());
    cmd.arg("--config")
        .arg(cfg)
        .arg("--replay")
        .arg(log)
        .arg("--fast");
    if let Some(s) = state {
        cmd.arg("--state-dir").arg(s);
    }
    cmd
}

/// A file's text as far as it is UTF-8 (a daemon's stderr while it is still writing); empty
/// when it does not exist yet.
pub fn read_lossy(p: &Path) -> String {
    String::from_utf8_lossy(&std::fs::read(p).unwrap_or_default()).into_owned()
}

/// shimmyd running live (reading `[input] interfaces`) as a child process, its stderr in a
/// file; killed if the test panics before [`LiveDaemon::stop`].
pub struct LiveDaemon {
    child: std::process::Child,
    err_path: PathBuf,
}

impl LiveDaemon {
    /// Starts `shimmyd --config CFG` in `dir` (stderr to `dir/shimmyd.stderr`) and waits up to
    /// 60 s for its "started (live" line; panics with its stderr if it exits or is slower.
    pub fn start(cfg: &Path, dir: &Path) -> LiveDaemon {
        let err_path = dir.join("shimmyd.stderr");
        let child = Command::new(shimmyd())
            .arg("--config")
            .arg(cfg)
            .current_dir(dir)
            .stdout(std::process::Stdio::null())
            .stderr(std::fs::File::create(&err_path).unwrap())
            .spawn()
            .expect("start shimmyd");
        let mut d = LiveDaemon { child, err_path };
        let t = Instant::now();
        while !d.stderr().contains("started (live") {
            if d.child.try_wait().unwrap().is_some() || t.elapsed() > Duration::from_secs(60) {
                panic!("shimmyd did not start: {}", d.stderr());
            }
            std::thread::sleep(Duration::from_millis(20));
        }
        d
    }

    pub fn pid(&self) -> u32 {
        self.child.id()
    }

    /// Its stderr so far.
    pub fn stderr(&self) -> String {
        read_lossy(&self.err_path)
    }

    /// Waits until its per-second counters line has twice more said it read no frame: it has
    /// caught up with the bus (frames still in the kernel's socket buffer are not read after
    /// SIGTERM, so a test waits for this before stopping it). Panics after `limit`.
    pub fn wait_idle(&self, limit: Duration) {
        let quiet = |text: &str| text.matches("last 1 s: frames=0 ").count();
        let before = quiet(&self.stderr());
        let t = Instant::now();
        while quiet(&self.stderr()) < before + 2 {
            assert!(
                t.elapsed() < limit,
                "shimmyd still busy {limit:?} after the last frame: {}",
                self.stderr()
            );
            std::thread::sleep(Duration::from_millis(100));
        }
    }

    /// Stops it as systemd would (SIGTERM) and waits up to `limit` for its exit; its exit
    /// status and stderr. Panics (after killing it) when it does not exit in time.
    pub fn stop(mut self, limit: Duration) -> (std::process::ExitStatus, String) {
        // SAFETY: kill(2) on the pid of a child we spawned and have not yet reaped.
        let rc = unsafe { libc::kill(self.child.id() as libc::pid_t, libc::SIGTERM) };
        assert_eq!(rc, 0, "kill(SIGTERM)");
        let end = Instant::now() + limit;
        loop {
            if let Some(s) = self.child.try_wait().expect("wait") {
                return (s, self.stderr());
            }
            assert!(
                Instant::now() < end,
                "shimmyd did not exit within {limit:?} of SIGTERM"
            );
            std::thread::sleep(Duration::from_millis(20));
        }
    }
}

impl Drop for LiveDaemon {
    fn drop(&mut self) {
        if let Ok(None) = self.child.try_wait() {
            let _ = self.child.kill();
            let _ = self.child.wait();
        }
    }
}

/// A copy of the shipped profile `profile` in `dir/name` (its bus, mapping and profile files)
/// whose tables are the shipped ones by absolute path: a profile to change (its mapping, a
/// correction) without rebuilding tables.
pub fn profile_copy(profile: &str, dir: &Path, name: &str) -> PathBuf {
    let src = workspace().join("config/vehicles").join(profile);
    let dst = dir.join(name);
    std::fs::create_dir_all(&dst).unwrap();
    for f in ["bus.toml", "mapping.toml", "profile.toml"] {
        std::fs::copy(src.join(f), dst.join(f)).unwrap();
    }
    let abs = |name: &str| src.join(name).display().to_string();
    let text = std::fs::read_to_string(dst.join("profile.toml")).unwrap();
    let mut rewritten = text.clone();
    // The tables: the profile's own and its chassis variants', angle and torque (`table = "…"`
    // and `torque_table = "…"` lines with a path relative to the profile's folder).
    for key in ["table", "torque_table"] {
        let start = format!("{key} = \"");
        let lines: Vec<String> = text
            .lines()
            .filter(|l| l.starts_with(&start) && !l.starts_with(&format!("{start}/")))
            .map(str::to_string)
            .collect();
        for line in lines {
            let file = line.split('"').nth(1).unwrap();
            rewritten = rewritten.replacen(&line, &format!("{key} = {:?}", abs(file)), 1);
        }
    }
    assert!(
        rewritten.contains(&abs("table.json")),
        "profile {profile}'s table key moved"
    );
    std::fs::write(dst.join("profile.toml"), rewritten).unwrap();
    dst
}

/// [`profile_copy`] of `profile` in `dir/name` that names `correction.toml` (a top-level key),
/// with `correction` as that file's content.
pub fn profile_copy_with_correction(
    profile: &str,
    dir: &Path,
    name: &str,
    correction: &str,
) -> PathBuf {
    let dst = profile_copy(profile, dir, name);
    let text = std::fs::read_to_string(dst.join("profile.toml")).unwrap();
    std::fs::write(
        dst.join("profile.toml"),
        format!("correction = \"correction.toml\"\n{text}"),
    )
    .unwrap();
    std::fs::write(dst.join("correction.toml"), correction).unwrap();
    dst
}
