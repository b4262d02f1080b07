//! The daemon → journal → report path on firmware-sim's demo log, with a transparent test
//! double in place of the clearance observer (it marks brake applications as events and
//! reports half the peak-to-peak steering angle; it makes no clearance estimate). What is
//! tested is the plumbing the real observer will use: events with their steering traces in
//! the journal, alerts raised once with evidence, and a report that reads all of it.

use std::path::Path;

use shimmy::daemon::config::Config;
use shimmy::daemon::run::{run, Options};
use shimmy::monitor::{Estimate, EventStage, EventSummary, Sample};

#[derive(Default)]
struct BrakeDouble {
    on: Option<(i64, f64)>,
    last_t: i64,
    speed: f64,
    lo: f64,
    hi: f64,
}

impl EventStage for BrakeDouble {
    fn describe(&self) -> String {
        "test double: brake applications, half peak-to-peak steering".into()
    }
    fn push(&mut self, s: &Sample) -> Option<EventSummary> {
        self.last_t = s.t_ns;
        if let Some(v) = s.speed_mps {
            self.speed = v;
        }
        if let (Some(_), Some(a)) = (self.on, s.steer_rad) {
            self.lo = self.lo.min(a.to_degrees());
            self.hi = self.hi.max(a.to_degrees());
        }
        match (self.on, s.brake) {
            (None, Some(true)) if self.speed > 5.0 => {
                self.on = Some((s.t_ns, self.speed));
                self.lo = f64::MAX;
                self.hi = f64::MIN;
                None
            }
            (Some(_), Some(false)) => self.close(),
            _ => None,
        }
    }
    fn finish(&mut self) -> Option<EventSummary> {
        // A brake still held at the end of the input (the demo's last stop) is closed here.
        self.close()
    }
    fn estimate(&self) -> Option<Estimate> {
        None
    }
}

impl BrakeDouble {
    fn close(&mut self) -> Option<EventSummary> {
        let (t0, v0) = self.on.take()?;
        let dur = (self.last_t - t0) as f64 * 1e-9;
        Some(EventSummary {
            t_start: t0 as f64 * 1e-9,
            t_end: self.last_t as f64 * 1e-9,
            v0_kmh: v0 * 3.6,
            decel_g: (v0 - self.speed) / dur / 9.80665,
            peak_sw_bp_deg: None,
            sw_amplitude_deg: Some(0.5 * (self.hi - self.lo)),
            used: true,
            unused_reason: None,
            odometer_km: 0.0,
            ..Default::default()
        })
    }
}

fn demo_config(dir: &Path) -> std::path::PathBuf {
    let ws = Path::new(env!("CARGO_MANIFEST_DIR"));
    let p = dir.join("shimmyd.toml");
    std::fs::write(
        &p,
        format!(
            "[input]\ndbc = {:?}\nmapping = {:?}\n[alerts]\nshimmy_deg = 0.05\nshimmy_clear_deg = 0.02\nshimmy_confirm = 1\nshimmy_speed_min_kmh = 30.0\nshimmy_speed_max_kmh = 80.0\n[outputs]\njournal_dir = \"journal\"\nstate_dir = \"state\"\n",
            ws.join("dbc/shimmy_reference.dbc"),
            ws.join("config/vehicles/shimmy_reference/mapping.toml")
        ),
    )
    .unwrap();
    p
}

#[test]
fn demo_log_events_traces_and_alert_reach_the_report() {
    let ws = Path::new(env!("CARGO_MANIFEST_DIR"));
    let log = ws.join("tests/fixtures/demo/worn_0p2mm.log");
    let dir = tempfile::tempdir().unwrap();
    let cfg_path = demo_config(dir.path());
    let factory = |_: &Config| -> anyhow::Result<Box<dyn EventStage>> {
        Ok(Box::new(BrakeDouble::default()))
    };
    run(
        Options {
            config: cfg_path.clone(),
            replay: vec![log],
            fast: true,
            ..Options::default()
        },
        &factory,
    )
    .unwrap();
    let cfg = Config::load(&cfg_path).unwrap();
    let data = shimmy::report::from_journal(&dir.path().join("journal"), &cfg.alerts).unwrap();
    // The demo drive has three braking events (75, 55, 40 km/h).
    assert_eq!(data.events.len(), 3, "{:?}", data.events);
    let v: Vec<f64> = data.events.iter().map(|e| e.v0_kmh.round()).collect();
    assert!(
        (v[0] - 75.0).abs() <= 2.0 && (v[1] - 55.0).abs() <= 2.0 && (v[2] - 40.0).abs() <= 2.0,
        "{v:?}"
    );
    // Odometer advanced through the drive (ground truth: 0.29 km in total).
    assert!(data.events[2].odometer_km > 0.15 && data.events[2].odometer_km < 0.3);
    // One alert, raised once and then updated (de-duplicated), with its evidence.
    assert_eq!(data.open_alerts.len(), 1);
    let a = &data.open_alerts[0];
    assert_eq!(a.kind.as_str(), "shimmy_55kmh");
    assert_eq!(a.updates, 2);
    assert!(!a.evidence.events.is_empty());
    assert!(a.guidance.contains("special inspection"));
    let transitions: Vec<&str> = data
        .alert_history
        .iter()
        .map(|r| r["transition"].as_str().unwrap())
        .collect();
    assert_eq!(transitions, ["raised", "updated", "updated"]);
    assert_eq!(data.verdict.condition, "inspect");
    // Worst events carry their steering traces (100 Hz over the event plus 1 s either side).
    assert_eq!(data.worst.len(), 3);
    let tr = data.worst[0].trace.as_ref().expect("trace journaled");
    assert!(tr.t_s.len() > 300, "{} samples", tr.t_s.len());
    assert!(tr.t_s[0] < -0.9 && tr.t_s[0] > -1.1);

    let html = shimmy::report::html(&data);
    let verdict_at = html.find("INSPECT NOW").expect("verdict badge");
    let evidence_at = html.find("Evidence").unwrap();
    assert!(verdict_at < evidence_at, "verdict must come first");
    assert!(
        html.matches("<svg").count() >= 6,
        "trace + spectrum for 3 events"
    );
    assert!(html.contains("0.1 mm: replace") || data.trend.is_empty());
    // Self-contained: no scripts, no external resources.
    assert!(!html.contains("<script"));
    assert!(!html.contains("src=") && !html.contains("href="));
    assert_eq!(
        html.matches("http").count(),
        html.matches("http://www.w3.org/2000/svg").count()
    );
    std::fs::write(dir.path().join("report.html"), &html).unwrap();
    if let Ok(out) = std::env::var("SHIMMY_REPORT_OUT") {
        std::fs::write(out, &html).unwrap();
    }
    let json = serde_json::to_value(&data).unwrap();
    assert_eq!(json["verdict"]["condition"], "inspect");
    assert_eq!(json["events"].as_array().unwrap().len(), 3);
}
