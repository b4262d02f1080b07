//! The maintenance alert rules, the only implementation of them: lifecycle, hysteresis,
//! de-duplication, evidence and the maintenance guidance of the source study. shimmyd and
//! `shimmy estimate` both run them through the monitor pipeline (`crate::pipeline`), after each
//! finished braking event, on the same [`EventSummary`] and [`Estimate`]; shimmyd journals every
//! transition and keeps the book in its state, `shimmy estimate` reports the alerts open at the
//! end of its logs.
//!
//! Two conditions, both evaluated once per finished braking event:
//! * `shimmy_55kmh`: of the last `shimmy_window` braking events that began inside the speed
//!   window (default 50–60 km/h), at least `shimmy_confirm` show an estimated steering-wheel
//!   shimmy amplitude above `shimmy_deg` (0.2°). It clears only when at most
//!   `shimmy_clear_max` of them exceed the lower `shimmy_clear_deg`.
//! * `clearance`: the observer's posterior gives P(c > `clearance_mm`) ≥
//!   `clearance_probability` (one noisy event cannot do this; the credible interval must) after
//!   each of the last `clearance_confirm` events that added to the estimate. It clears when that
//!   probability falls below `clearance_clear_probability`. While the fit check finds the
//!   steering shaking at the wheels' rotation (uneven brake discs), the pair
//!   `clearance_wheel_order_probability` / `clearance_wheel_order_clear_probability` applies
//!   instead; a sensor noisier than its table raises nothing.
//!
//! De-duplication: while a condition persists there is one open alert of its kind, with a
//! stable id; every new piece of evidence produces an `updated` transition of that alert, not a
//! new alert. The book is serialisable so open alerts survive a restart.
//!
//! Guidance: [`guidance`] quotes only what the article's conclusions say (replacement beyond
//! 0.1 mm, inspection every 30,000 km below 60,000 km and every 15,000 km above, immediate
//! special inspection above 0.2° at 55 km/h, lubrication every 15,000 km); it invents no
//! other number.
//!
//! What it is not: detection or estimation (the observer's), the wiring from samples to events
//! (the pipeline's), the settings schema ([`config`]) or delivery (journal, bus, MQTT, report).

pub mod config;

use std::collections::VecDeque;

use serde::{Deserialize, Serialize};

use crate::monitor::{Estimate, EventSummary};

pub use config::AlertsSection;

#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum Kind {
    /// Steering-wheel shimmy above the threshold while braking in the speed window.
    #[serde(rename = "shimmy_55kmh")]
    Shimmy55,
    /// Estimated joint clearance above the replacement threshold.
    Clearance,
}

impl Kind {
    pub fn as_str(self) -> &'static str {
        match self {
            Kind::Shimmy55 => "shimmy_55kmh",
            Kind::Clearance => "clearance",
        }
    }
}

/// One braking event cited as evidence.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct EventEvidence {
    pub t_start: f64,
    pub t_end: f64,
    pub v0_kmh: f64,
    pub decel_g: f64,
    pub sw_amplitude_deg: Option<f64>,
    pub peak_sw_bp_deg: Option<f64>,
    pub odometer_km: f64,
}

impl From<&EventSummary> for EventEvidence {
    fn from(e: &EventSummary) -> Self {
        EventEvidence {
            t_start: e.t_start,
            t_end: e.t_end,
            v0_kmh: e.v0_kmh,
            decel_g: e.decel_g,
            sw_amplitude_deg: e.sw_amplitude_deg,
            peak_sw_bp_deg: e.peak_sw_bp_deg,
            odometer_km: e.odometer_km,
        }
    }
}

/// Why an alert is raised.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct Evidence {
    /// The braking events behind the condition (for the shimmy alert: the window's events).
    pub events: Vec<EventEvidence>,
    /// The clearance estimate when the alert was last updated.
    pub estimate: Option<Estimate>,
    /// The threshold that was crossed (deg or mm, per kind).
    pub threshold: f64,
    /// Shimmy alert: events above threshold out of events in the window.
    pub hits: Option<[usize; 2]>,
}

#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct Alert {
    pub id: u64,
    pub kind: Kind,
    /// Log time of the event that raised it / last updated it (s).
    pub t_raised: f64,
    pub t_updated: f64,
    pub odometer_km_raised: f64,
    /// Updates since raised (persisting condition, new evidence).
    pub updates: u32,
    pub summary: String,
    pub guidance: String,
    pub evidence: Evidence,
}

/// What happened to an alert with one event.
#[derive(Clone, Debug, PartialEq, Serialize)]
#[serde(tag = "transition", rename_all = "snake_case")]
pub enum Transition {
    Raised(Alert),
    Updated(Alert),
    Cleared(Alert),
}

impl Transition {
    /// `("raised" | "updated" | "cleared", the alert)`, as the journal and MQTT name them.
    pub fn parts(&self) -> (&'static str, &Alert) {
        match self {
            Transition::Raised(a) => ("raised", a),
            Transition::Updated(a) => ("updated", a),
            Transition::Cleared(a) => ("cleared", a),
        }
    }
}

/// The open alerts and the memory the rules need.
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
#[serde(default)]
pub struct AlertBook {
    pub open: Vec<Alert>,
    pub next_id: u64,
    /// The last events in the shimmy speed window (bounded by the configured window).
    pub shimmy_window: VecDeque<EventEvidence>,
    /// Clearance rule: how many estimates in a row, each resting on other braking events than
    /// the one before (more of them, or another steering signal's estimator taking over), have
    /// had P(c > clearance_mm) at or above the raise threshold.
    pub clearance_streak: usize,
    /// The events behind the last estimate the streak counted (an event the estimator left
    /// out brings no new evidence and does not count again).
    pub clearance_streak_events: u32,
    /// Alerts raised and cleared since the book began, per kind.
    pub counts: AlertCounts,
}

/// Alerts raised and cleared since the alert book began, per kind. An alert that is raised
/// again after it cleared (a condition near its threshold) shows as more than one raise.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize, Deserialize)]
#[serde(default)]
pub struct AlertCounts {
    pub shimmy_55kmh_raised: u32,
    pub shimmy_55kmh_cleared: u32,
    pub clearance_raised: u32,
    pub clearance_cleared: u32,
}

impl AlertCounts {
    fn count(&mut self, kind: Kind, raised: bool) {
        let n = match (kind, raised) {
            (Kind::Shimmy55, true) => &mut self.shimmy_55kmh_raised,
            (Kind::Shimmy55, false) => &mut self.shimmy_55kmh_cleared,
            (Kind::Clearance, true) => &mut self.clearance_raised,
            (Kind::Clearance, false) => &mut self.clearance_cleared,
        };
        *n += 1;
    }
}

/// Maintenance guidance of the source study's conclusions, for an alert of `kind` at odometer
/// `odometer_km`.
pub fn guidance(kind: Kind, cfg: &AlertsSection, odometer_km: f64) -> String {
    let interval = if odometer_km < 60_000.0 {
        "every 30,000 km (vehicle below 60,000 km)"
    } else {
        "every 15,000 km (vehicle above 60,000 km)"
    };
    let head = match kind {
        Kind::Shimmy55 => format!(
            "Steering-wheel shimmy above {:.2} deg while braking at {:.0}-{:.0} km/h: the study \
             calls for an immediate special inspection of the steering joint clearances.",
            cfg.shimmy_deg, cfg.shimmy_speed_min_kmh, cfg.shimmy_speed_max_kmh
        ),
        Kind::Clearance => format!(
            "Estimated steering-joint clearance above {:.2} mm: the study recommends replacing \
             the tie-rod / trapezoid-arm joints once wear clearance exceeds 0.1 mm.",
            cfg.clearance_mm
        ),
    };
    format!(
        "{head} Routine: inspect steering clearances {interval}; lubricate the clearance joints \
         every 15,000 km to slow clearance growth. New-joint manufacturing clearance should be \
         within 0.07 mm (the study's bifurcation threshold)."
    )
}

/// The study's maintenance recommendations, stated conditionally (for reports without an alert).
pub fn routine_guidance(cfg: &AlertsSection, odometer_km: f64) -> Vec<String> {
    let interval = if odometer_km < 60_000.0 {
        "every 30,000 km while the vehicle is below 60,000 km (then every 15,000 km)"
    } else {
        "every 15,000 km (vehicle above 60,000 km)"
    };
    vec![
        "Replace the tie-rod / trapezoid-arm joints promptly once their wear clearance exceeds 0.1 mm.".into(),
        format!(
            "Inspect the steering clearances at once if steering-wheel shimmy exceeds {:.2} deg when braking at {:.0}-{:.0} km/h (the study: 0.2 deg at 55 km/h).",
            cfg.shimmy_deg, cfg.shimmy_speed_min_kmh, cfg.shimmy_speed_max_kmh
        ),
        format!("Inspect the steering clearances {interval}."),
        "Lubricate the clearance joints every 15,000 km to slow clearance growth.".into(),
        "New joints: manufacturing clearance within 0.07 mm (the study's bifurcation threshold).".into(),
    ]
}

fn in_window(cfg: &AlertsSection, e: &EventSummary) -> bool {
    e.used && (cfg.shimmy_speed_min_kmh..=cfg.shimmy_speed_max_kmh).contains(&e.v0_kmh)
}

impl AlertBook {
    fn open_index(&self, kind: Kind) -> Option<usize> {
        self.open.iter().position(|a| a.kind == kind)
    }

    pub fn is_open(&self, kind: Kind) -> bool {
        self.open_index(kind).is_some()
    }

    /// Clears every open alert at once, for a reason outside the rules (the joints that raised
    /// them were replaced): each leaves the open alerts, its summary saying `reason` and what
    /// it said before, `t_updated` set to `t` when known; the shimmy window forgets its events.
    /// Returns the cleared alerts, for the caller to report as `cleared` transitions.
    pub fn clear_all(&mut self, t: Option<f64>, reason: &str) -> Vec<Alert> {
        self.shimmy_window.clear();
        self.clearance_streak = 0;
        self.clearance_streak_events = 0;
        let mut cleared: Vec<Alert> = self.open.drain(..).collect();
        for a in &mut cleared {
            self.counts.count(a.kind, false);
            if let Some(t) = t {
                a.t_updated = t;
            }
            a.summary = format!("cleared: {reason}; before: {}", a.summary);
        }
        cleared
    }

    /// Evaluates both rules after one finished event, with the estimate after it. Returns the
    /// transitions (at most one per kind).
    pub fn on_event(
        &mut self,
        cfg: &AlertsSection,
        ev: &EventSummary,
        est: Option<&Estimate>,
    ) -> Vec<Transition> {
        let mut out = Vec::new();
        if in_window(cfg, ev) && ev.sw_amplitude_deg.is_some() {
            // shimmyd's configuration check keeps the window at 1 or more and the confirmation
            // count at 1 or more; settings read unchecked must not hang or raise on nothing.
            let window = cfg.shimmy_window.max(1);
            while self.shimmy_window.len() >= window {
                self.shimmy_window.pop_front();
            }
            self.shimmy_window.push_back(ev.into());
            let amp = |e: &EventEvidence| e.sw_amplitude_deg.unwrap_or(0.0);
            let n = self.shimmy_window.len();
            let hits = self
                .shimmy_window
                .iter()
                .filter(|e| amp(e) > cfg.shimmy_deg)
                .count();
            let soft = self
                .shimmy_window
                .iter()
                .filter(|e| amp(e) > cfg.shimmy_clear_deg)
                .count();
            let evidence = Evidence {
                events: self.shimmy_window.iter().cloned().collect(),
                estimate: est.cloned(),
                threshold: cfg.shimmy_deg,
                hits: Some([hits, n]),
            };
            let summary = format!(
                "{hits} of the last {n} braking events at {:.0}-{:.0} km/h show steering-wheel \
                 shimmy above {:.2} deg (largest {:.2} deg)",
                cfg.shimmy_speed_min_kmh,
                cfg.shimmy_speed_max_kmh,
                cfg.shimmy_deg,
                self.shimmy_window.iter().map(amp).fold(0.0, f64::max)
            );
            let raise = hits >= cfg.shimmy_confirm.max(1);
            let clear = soft <= cfg.shimmy_clear_max;
            out.extend(self.apply(cfg, Kind::Shimmy55, raise, clear, ev, summary, evidence));
        }
        if let Some(e) = est {
            if let Some(p) = e.p_above {
                // A steering that shakes at the wheels' rotation while braking (uneven brake
                // discs) puts a shake the joints did not make into the features: its alert is
                // raised and kept on a stricter pair of probabilities.
                let (p_raise, p_clear) = if e.wheel_order_shake {
                    (
                        cfg.clearance_wheel_order_probability,
                        cfg.clearance_wheel_order_clear_probability,
                    )
                } else {
                    (cfg.clearance_probability, cfg.clearance_clear_probability)
                };
                // A steering sensor measured noisier than its table assumes is a monitor not
                // set up for this car (src/observer/noise_floor.rs): the estimate reads the extra
                // noise as clearance, so it raises no alert, and an open one is cleared, saying
                // why (the report then sends the mechanic to inspect by hand and names the table
                // to build).
                let (raise, clear) = if e.sensor_noisier {
                    self.clearance_streak = 0;
                    (false, true)
                } else {
                    if p < p_raise {
                        self.clearance_streak = 0;
                    } else if e.events_used != self.clearance_streak_events
                        || self.clearance_streak == 0
                    {
                        self.clearance_streak += 1;
                    }
                    self.clearance_streak_events = e.events_used;
                    (
                        self.clearance_streak >= cfg.clearance_confirm.max(1),
                        p < p_clear,
                    )
                };
                let summary = match (e.clearance_mm, e.interval_mm) {
                    (Some(c), Some([lo, hi])) => format!(
                        "estimated clearance {c:.3} mm (90 % interval {lo:.3}-{hi:.3} mm), \
                         P(> {:.2} mm) = {:.0} % over {} braking events",
                        cfg.clearance_mm,
                        p * 100.0,
                        e.events_used
                    ),
                    _ => format!(
                        "P(clearance > {:.2} mm) = {:.0} % over {} braking events",
                        cfg.clearance_mm,
                        p * 100.0,
                        e.events_used
                    ),
                };
                let summary = match &e.misfit {
                    Some(why) => {
                        format!("{summary}; but the model does not fit this vehicle: {why}")
                    }
                    None => summary,
                };
                let evidence = Evidence {
                    events: vec![ev.into()],
                    estimate: Some(e.clone()),
                    threshold: cfg.clearance_mm,
                    hits: None,
                };
                out.extend(self.apply(cfg, Kind::Clearance, raise, clear, ev, summary, evidence));
            }
        }
        out
    }

    #[allow(clippy::too_many_arguments)]
    fn apply(
        &mut self,
        cfg: &AlertsSection,
        kind: Kind,
        raise: bool,
        clear: bool,
        ev: &EventSummary,
        summary: String,
        evidence: Evidence,
    ) -> Option<Transition> {
        match self.open_index(kind) {
            None if raise => {
                self.next_id += 1;
                let a = Alert {
                    id: self.next_id,
                    kind,
                    t_raised: ev.t_end,
                    t_updated: ev.t_end,
                    odometer_km_raised: ev.odometer_km,
                    updates: 0,
                    summary,
                    guidance: guidance(kind, cfg, ev.odometer_km),
                    evidence,
                };
                self.open.push(a.clone());
                self.counts.count(kind, true);
                Some(Transition::Raised(a))
            }
            None => None,
            Some(i) if clear => {
                let mut a = self.open.remove(i);
                self.counts.count(kind, false);
                a.t_updated = ev.t_end;
                a.summary = summary;
                a.evidence = evidence;
                Some(Transition::Cleared(a))
            }
            Some(i) => {
                let a = &mut self.open[i];
                a.t_updated = ev.t_end;
                a.updates += 1;
                a.summary = summary;
                a.evidence = evidence;
                a.guidance = guidance(kind, cfg, ev.odometer_km);
                Some(Transition::Updated(a.clone()))
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn ev(t: f64, v: f64, amp: f64) -> EventSummary {
        EventSummary {
            t_start: t,
            t_end: t + 2.0,
            v0_kmh: v,
            decel_g: 0.5,
            peak_sw_bp_deg: Some(amp * 1.2),
            sw_amplitude_deg: Some(amp),
            used: true,
            unused_reason: None,
            odometer_km: t / 100.0,
            ..Default::default()
        }
    }

    /// An estimate of 0.15 mm (0.12-0.19) over 7 events with P(above) `p`, its sensor
    /// measured noisier than its table (`noisy`, with the reason) or not.
    fn estimate(p: f64, noisy: bool) -> Estimate {
        Estimate {
            clearance_mm: Some(0.15),
            interval_mm: Some([0.12, 0.19]),
            detectable: true,
            below_mm: None,
            p_above: Some(p),
            events_used: 7,
            misfit: noisy.then(|| "its steering torque sensor is noisier".to_string()),
            chassis_variant: None,
            chassis_variant_inspect: None,
            wheel_order_shake: false,
            wheel_order_discs_ruled_out: false,
            sensor_noisier: noisy,
        }
    }

    fn kinds(ts: &[Transition]) -> Vec<(&'static str, Kind)> {
        ts.iter()
            .map(|t| match t {
                Transition::Raised(a) => ("raised", a.kind),
                Transition::Updated(a) => ("updated", a.kind),
                Transition::Cleared(a) => ("cleared", a.kind),
            })
            .collect()
    }

    #[test]
    fn shimmy_needs_confirmation_then_is_one_alert_then_clears_with_hysteresis() {
        let cfg = AlertsSection::default();
        let mut b = AlertBook::default();
        assert!(b.on_event(&cfg, &ev(0.0, 55.0, 0.3), None).is_empty());
        // Outside the speed window: ignored.
        assert!(b.on_event(&cfg, &ev(10.0, 80.0, 0.5), None).is_empty());
        let t = b.on_event(&cfg, &ev(20.0, 52.0, 0.25), None);
        assert_eq!(kinds(&t), [("raised", Kind::Shimmy55)]);
        let id = b.open[0].id;
        for k in 0..6 {
            let t = b.on_event(&cfg, &ev(30.0 + k as f64, 55.0, 0.17), None);
            // 0.17 deg is below the raise threshold but above the clear threshold: the alert
            // persists as long as any event in the window is above 0.15 deg.
            assert_eq!(kinds(&t), [("updated", Kind::Shimmy55)], "step {k}");
            assert_eq!(b.open.len(), 1);
            assert_eq!(b.open[0].id, id);
        }
        for k in 0..4 {
            let t = b.on_event(&cfg, &ev(40.0 + k as f64, 55.0, 0.05), None);
            assert_eq!(kinds(&t), [("updated", Kind::Shimmy55)]);
        }
        let t = b.on_event(&cfg, &ev(50.0, 55.0, 0.05), None);
        assert_eq!(kinds(&t), [("cleared", Kind::Shimmy55)]);
        assert!(b.open.is_empty());
    }

    #[test]
    fn clear_all_empties_the_book_and_its_shimmy_window_and_says_why() {
        let cfg = AlertsSection::default();
        let mut b = AlertBook::default();
        b.on_event(&cfg, &ev(0.0, 55.0, 0.3), None);
        b.on_event(&cfg, &ev(10.0, 55.0, 0.3), None);
        assert!(b.is_open(Kind::Shimmy55));
        let before = b.open[0].summary.clone();
        let cleared = b.clear_all(Some(99.0), "the joints were replaced");
        assert_eq!(cleared.len(), 1);
        assert_eq!(cleared[0].t_updated, 99.0);
        assert_eq!(
            cleared[0].summary,
            format!("cleared: the joints were replaced; before: {before}")
        );
        assert!(b.open.is_empty() && b.shimmy_window.is_empty());
        // The old events are forgotten: one new event above the threshold does not raise.
        assert!(b.on_event(&cfg, &ev(20.0, 55.0, 0.3), None).is_empty());
    }

    #[test]
    fn clearance_follows_probability_with_hysteresis_and_carries_evidence() {
        // Raised on the first estimate above the threshold (the confirmation has its own test).
        let cfg = AlertsSection {
            clearance_confirm: 1,
            ..AlertsSection::default()
        };
        let mut b = AlertBook::default();
        let est = |p: f64| estimate(p, false);
        // Just below the raise probability: nothing.
        let below = cfg.clearance_probability - 0.01;
        assert!(below > cfg.clearance_clear_probability);
        assert!(b
            .on_event(&cfg, &ev(0.0, 80.0, 0.1), Some(&est(below)))
            .is_empty());
        let t = b.on_event(&cfg, &ev(1.0, 80.0, 0.1), Some(&est(0.95)));
        assert_eq!(kinds(&t), [("raised", Kind::Clearance)]);
        let Transition::Raised(a) = &t[0] else {
            panic!()
        };
        assert_eq!(
            a.evidence.estimate.as_ref().unwrap().interval_mm,
            Some([0.12, 0.19])
        );
        assert_eq!(a.evidence.events[0].v0_kmh, 80.0);
        assert!(a.guidance.contains("0.1 mm"));
        assert!(a.summary.contains("0.120-0.190"));
        // Between the clear and the raise probability: still open (hysteresis).
        let between = 0.5 * (cfg.clearance_clear_probability + cfg.clearance_probability);
        let t = b.on_event(&cfg, &ev(2.0, 80.0, 0.1), Some(&est(between)));
        assert_eq!(kinds(&t), [("updated", Kind::Clearance)]);
        let t = b.on_event(
            &cfg,
            &ev(3.0, 80.0, 0.1),
            Some(&est(cfg.clearance_clear_probability - 0.1)),
        );
        assert_eq!(kinds(&t), [("cleared", Kind::Clearance)]);
    }

    #[test]
    fn clearance_confirm_waits_for_the_probability_to_hold_over_new_events() {
        let cfg = AlertsSection {
            clearance_confirm: 3,
            ..AlertsSection::default()
        };
        let mut b = AlertBook::default();
        let est = |p: f64, n: u32| Estimate {
            events_used: n,
            ..estimate(p, false)
        };
        // Above the raise probability after events 2 and 3, below after 4: a flap, no alert.
        assert!(b
            .on_event(&cfg, &ev(0.0, 80.0, 0.1), Some(&est(0.75, 2)))
            .is_empty());
        assert!(b
            .on_event(&cfg, &ev(1.0, 80.0, 0.1), Some(&est(0.72, 3)))
            .is_empty());
        assert!(b
            .on_event(&cfg, &ev(2.0, 80.0, 0.1), Some(&est(0.6, 4)))
            .is_empty());
        // Above again: the count starts over. An event the estimator left out (the same
        // events behind the estimate) confirms nothing.
        assert!(b
            .on_event(&cfg, &ev(3.0, 80.0, 0.1), Some(&est(0.8, 5)))
            .is_empty());
        assert!(b
            .on_event(&cfg, &ev(4.0, 80.0, 0.1), Some(&est(0.8, 5)))
            .is_empty());
        assert!(b
            .on_event(&cfg, &ev(5.0, 80.0, 0.1), Some(&est(0.85, 6)))
            .is_empty());
        let t = b.on_event(&cfg, &ev(6.0, 80.0, 0.1), Some(&est(0.9, 7)));
        assert_eq!(kinds(&t), [("raised", Kind::Clearance)]);
        // Clearing is not delayed: below the clear probability once clears it.
        let t = b.on_event(&cfg, &ev(7.0, 80.0, 0.1), Some(&est(0.4, 8)));
        assert_eq!(kinds(&t), [("cleared", Kind::Clearance)]);
        assert_eq!(
            (b.counts.clearance_raised, b.counts.clearance_cleared),
            (1, 1)
        );
        // The torque's estimator taking over from the angle's (fewer events behind it) is new
        // evidence and counts.
        let mut b = AlertBook::default();
        assert!(b
            .on_event(&cfg, &ev(0.0, 80.0, 0.1), Some(&est(0.8, 6)))
            .is_empty());
        assert!(b
            .on_event(&cfg, &ev(1.0, 80.0, 0.1), Some(&est(0.8, 1)))
            .is_empty());
        let t = b.on_event(&cfg, &ev(2.0, 80.0, 0.1), Some(&est(0.8, 2)));
        assert_eq!(kinds(&t), [("raised", Kind::Clearance)]);
        // With 1 the first estimate above the threshold raises it.
        let mut b = AlertBook::default();
        let once = AlertsSection {
            clearance_confirm: 1,
            ..AlertsSection::default()
        };
        let t = b.on_event(&once, &ev(0.0, 80.0, 0.1), Some(&est(0.75, 2)));
        assert_eq!(kinds(&t), [("raised", Kind::Clearance)]);
    }

    #[test]
    fn a_sensor_noisier_than_its_table_raises_no_clearance_alert_and_clears_an_open_one() {
        // Raised on the first estimate above the threshold (the confirmation has its own test).
        let cfg = AlertsSection {
            clearance_confirm: 1,
            ..AlertsSection::default()
        };
        let mut b = AlertBook::default();
        let est = estimate;
        // Certain, but from a sensor the table does not describe: nothing.
        assert!(b
            .on_event(&cfg, &ev(0.0, 80.0, 0.1), Some(&est(0.99, true)))
            .is_empty());
        // Raised while the noise was not yet measured, then the noise shows: cleared, saying why.
        let t = b.on_event(&cfg, &ev(1.0, 80.0, 0.1), Some(&est(0.99, false)));
        assert_eq!(kinds(&t), [("raised", Kind::Clearance)]);
        let t = b.on_event(&cfg, &ev(2.0, 80.0, 0.1), Some(&est(0.99, true)));
        assert_eq!(kinds(&t), [("cleared", Kind::Clearance)]);
        let Transition::Cleared(a) = &t[0] else {
            panic!()
        };
        assert!(a.summary.contains("sensor is noisier"), "{}", a.summary);
        assert!(!b.is_open(Kind::Clearance));
        // The shimmy rule, a measured amplitude, does not depend on the table and still raises.
        for k in 0..2 {
            b.on_event(&cfg, &ev(3.0 + k as f64, 55.0, 0.3), Some(&est(0.99, true)));
        }
        assert!(b.is_open(Kind::Shimmy55) && !b.is_open(Kind::Clearance));
    }

    #[test]
    fn a_steering_shaking_at_wheel_order_is_judged_on_the_stricter_probabilities() {
        let cfg = AlertsSection::default();
        assert!(cfg.clearance_wheel_order_probability > cfg.clearance_probability);
        assert!(cfg.clearance_wheel_order_clear_probability > cfg.clearance_clear_probability);
        let est = |p: f64, n: u32, shake: bool| Estimate {
            events_used: n,
            wheel_order_shake: shake,
            wheel_order_discs_ruled_out: false,
            ..estimate(p, false)
        };
        let between = 0.5 * (cfg.clearance_probability + cfg.clearance_wheel_order_probability);
        // Between the two raise probabilities over three new events: raised without the shake,
        // not with it.
        let mut plain = AlertBook::default();
        let mut shaking = AlertBook::default();
        for n in 1..=3 {
            plain.on_event(
                &cfg,
                &ev(n as f64, 80.0, 0.1),
                Some(&est(between, n, false)),
            );
            shaking.on_event(&cfg, &ev(n as f64, 80.0, 0.1), Some(&est(between, n, true)));
        }
        assert!(plain.is_open(Kind::Clearance));
        assert!(!shaking.is_open(Kind::Clearance));
        // Above the stricter one over two new events: raised with the shake too.
        for n in 4..=5 {
            shaking.on_event(&cfg, &ev(n as f64, 80.0, 0.1), Some(&est(0.95, n, true)));
        }
        assert!(shaking.is_open(Kind::Clearance));
        // Between the two clear probabilities: kept without the shake, cleared with it.
        let mid =
            0.5 * (cfg.clearance_clear_probability + cfg.clearance_wheel_order_clear_probability);
        plain.on_event(&cfg, &ev(6.0, 80.0, 0.1), Some(&est(mid, 6, false)));
        let t = shaking.on_event(&cfg, &ev(6.0, 80.0, 0.1), Some(&est(mid, 6, true)));
        assert!(plain.is_open(Kind::Clearance));
        assert_eq!(kinds(&t), [("cleared", Kind::Clearance)]);
        // Set equal to the plain pair, the shake changes nothing.
        let same = AlertsSection {
            clearance_wheel_order_probability: cfg.clearance_probability,
            clearance_wheel_order_clear_probability: cfg.clearance_clear_probability,
            ..cfg.clone()
        };
        let mut b = AlertBook::default();
        for n in 1..=3 {
            b.on_event(
                &same,
                &ev(n as f64, 80.0, 0.1),
                Some(&est(between, n, true)),
            );
        }
        assert!(b.is_open(Kind::Clearance));
    }

    #[test]
    fn a_zero_window_or_confirmation_count_neither_hangs_nor_raises_on_nothing() {
        let cfg = AlertsSection {
            shimmy_window: 0,
            shimmy_confirm: 0,
            ..AlertsSection::default()
        };
        let mut b = AlertBook::default();
        assert!(b.on_event(&cfg, &ev(0.0, 55.0, 0.05), None).is_empty());
        assert_eq!(b.shimmy_window.len(), 1);
        let t = b.on_event(&cfg, &ev(10.0, 55.0, 0.3), None);
        assert_eq!(kinds(&t), [("raised", Kind::Shimmy55)]);
        assert_eq!(b.shimmy_window.len(), 1);
    }

    #[test]
    fn guidance_interval_follows_mileage() {
        let cfg = AlertsSection::default();
        assert!(guidance(Kind::Clearance, &cfg, 10_000.0).contains("every 30,000 km"));
        assert!(
            guidance(Kind::Clearance, &cfg, 90_000.0).contains("every 15,000 km (vehicle above")
        );
    }
}
