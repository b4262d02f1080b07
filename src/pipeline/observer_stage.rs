//! The adapter between the pipeline's [`EventStage`] seam and the clearance observer
//! ([`crate::observer::Observer`]): feeds it the pipeline's samples, hands back each newly
//! finished braking event as an [`EventSummary`], and reports the clearance posterior as an
//! [`Estimate`]. shimmyd and `shimmy estimate` both run the observer through it
//! ([`super::Monitor`], [`super::finish_event`]), so the alert rules see the same events and
//! estimates in both.
//!
//! Persistence across restarts (shimmyd's state file): the observer runs caller-fed
//! ([`Observer::new_caller_fed`]): this adapter hands its estimator each used event's features,
//! placed at the caller's odometer at the event's brake onset (the distance the wear model
//! sees), and keeps them. [`EventStage::save`] returns that evidence, one [`Evidence`] per used
//! event, and [`EventStage::restore`] replays it into a fresh estimator, so an estimate
//! keeps accumulating across daemon runs: two runs over logs A then B end with the same
//! posterior as one run over A+B (replaying the evidence is exact). The observer's report and
//! the stage's [`Estimate`] read the same estimator. At most [`MAX_EVIDENCE`] events are kept; past
//! that the oldest are left out of the saved state, counted in [`Saved::evidence_dropped`] and
//! named in the log line at the next start (their weight is already small after the wear
//! model's diffusion over the distance since).
//!
//! What it is not: a detector, an estimator or an alert rule. Detection and the amplitude
//! estimate (MODEL.md §11) are the observer's; the alert rules are [`crate::alerts`]'.

use std::collections::VecDeque;

use anyhow::Context;
use serde::{Deserialize, Serialize};

use crate::monitor::{Estimate, EventStage, EventSummary, RejectionSummary, Sample};
use crate::observer::table::ResponseTable;
use crate::observer::{EventOut, Observer, ObserverConfig};

/// Most used events whose evidence is kept for the posterior's restore.
pub const MAX_EVIDENCE: usize = 2000;

/// One used event as the estimator saw it.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub struct Evidence {
    /// MODEL.md §11 band-passed steering-wheel RMS and peak (deg).
    pub rms_deg: f64,
    pub peak_deg: f64,
    /// Pre-brake cruise RMS (deg), when measured (absent in states written before it existed).
    #[serde(default)]
    pub cruise_rms_deg: Option<f64>,
    pub v0_kmh: f64,
    pub decel_g: f64,
    /// Daemon odometer when the event finished (m).
    pub odometer_m: f64,
}

/// What [`ObserverStage`] saves in the daemon's state.
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
#[serde(default)]
pub struct Saved {
    pub evidence: Vec<Evidence>,
    /// Used events older than the kept evidence (not replayed at restore).
    pub evidence_dropped: u64,
}

/// [`EventStage`] over the real observer.
pub struct ObserverStage {
    obs: Observer,
    /// Events already handed to the daemon (compared with `Observer::events_seen`, which keeps
    /// counting past the observer's bounded event list).
    seen: u64,
    has_table: bool,
    clearance_mm: f64,
    evidence: VecDeque<Evidence>,
    evidence_dropped: u64,
    odometer_km: f64,
}

impl ObserverStage {
    /// Runs the observer on the monitor's settings (`settings`, config/observer.toml's schema;
    /// the estimate's `p_above` is for `settings.alerts.clearance_mm`); `table` is the response
    /// table (without it events and amplitudes still flow, no clearance estimate).
    pub fn new(
        settings: &ObserverConfig,
        table: Option<ResponseTable>,
    ) -> anyhow::Result<ObserverStage> {
        let oc = settings.clone();
        let has_table = table.is_some();
        Ok(ObserverStage {
            obs: Observer::new_caller_fed(oc.clone(), table).context("observer.estimator")?,
            seen: 0,
            has_table,
            clearance_mm: oc.alerts.clearance_mm,
            evidence: VecDeque::new(),
            evidence_dropped: 0,
            odometer_km: 0.0,
        })
    }

    /// The observer behind the stage (its report: events, rejections, its own estimate).
    pub fn observer(&self) -> &Observer {
        &self.obs
    }

    fn take_new(&mut self) -> Option<EventSummary> {
        let n = self.obs.events_seen();
        if n == self.seen {
            return None;
        }
        // The observer finishes at most one event per pushed sample, so `last_event` is it.
        self.seen = n;
        let e = self.obs.last_event()?;
        if let (true, Some(rms), Some(peak)) = (e.used, e.rms_sw_bp_deg, e.peak_sw_bp_deg) {
            let ev = Evidence {
                rms_deg: rms,
                peak_deg: peak,
                cruise_rms_deg: e.cruise_rms_sw_bp_deg,
                v0_kmh: e.v0_kmh,
                decel_g: e.decel_g,
                // The daemon's odometer at the brake onset, as the observer's own estimator
                // places the event: the same distances between events on both paths.
                odometer_m: self.odometer_km * 1000.0 - self.obs.distance_since_last_event_m(),
            };
            self.apply(&ev);
        }
        self.obs.last_event().map(summary)
    }

    /// Adds one used event to the posterior and to the kept evidence.
    fn apply(&mut self, ev: &Evidence) {
        let Some((est, table)) = self.obs.estimator_mut() else {
            return;
        };
        est.update_event(
            table,
            ev.rms_deg,
            ev.peak_deg,
            ev.cruise_rms_deg,
            ev.v0_kmh,
            ev.decel_g,
            ev.odometer_m,
        );
        if self.evidence.len() >= MAX_EVIDENCE {
            self.evidence.pop_front();
            self.evidence_dropped += 1;
        }
        self.evidence.push_back(*ev);
    }
}

fn summary(e: &EventOut) -> EventSummary {
    EventSummary {
        t_start: e.t_start,
        t_end: e.t_end,
        v0_kmh: e.v0_kmh,
        decel_g: e.decel_g,
        peak_sw_bp_deg: e.peak_sw_bp_deg,
        sw_amplitude_deg: e.sw_amplitude_deg,
        used: e.used,
        unused_reason: e
            .unused_reason
            .and_then(|r| serde_json::to_value(r).ok())
            .and_then(|v| v.as_str().map(str::to_owned)),
        // Filled in by the pipeline from its odometer (`super::finish_event`).
        odometer_km: 0.0,
    }
}

impl EventStage for ObserverStage {
    fn describe(&self) -> String {
        if self.has_table {
            "clearance observer: braking events, shimmy amplitude and clearance estimate".into()
        } else {
            "clearance observer without a response table (vehicle.table unset): braking events \
             and shimmy amplitude, no clearance estimate"
                .into()
        }
    }

    fn push(&mut self, s: &Sample) -> Option<EventSummary> {
        self.obs.push(s);
        self.take_new()
    }

    fn finish(&mut self) -> Option<EventSummary> {
        self.obs.finish();
        self.take_new()
    }

    fn odometer_km(&mut self, km: f64) {
        self.odometer_km = km;
    }

    fn rejections(&self) -> Option<RejectionSummary> {
        Some(RejectionSummary {
            counts: self.obs.rejections(),
            text: self.obs.explain_rejections(true),
        })
    }

    fn save(&self) -> Option<serde_json::Value> {
        if !self.has_table {
            return None;
        }
        serde_json::to_value(Saved {
            evidence: self.evidence.iter().copied().collect(),
            evidence_dropped: self.evidence_dropped,
        })
        .ok()
    }

    fn restore(&mut self, saved: &serde_json::Value) -> anyhow::Result<Option<String>> {
        if !self.has_table {
            return Ok(Some(
                "the saved clearance posterior is not restored: no response table (vehicle.table)"
                    .into(),
            ));
        }
        let saved: Saved = serde_json::from_value(saved.clone())
            .context("the state's saved posterior does not parse")?;
        self.obs.reset_estimator()?;
        self.evidence.clear();
        self.evidence_dropped = saved.evidence_dropped;
        for ev in &saved.evidence {
            if [
                ev.rms_deg,
                ev.peak_deg,
                ev.v0_kmh,
                ev.decel_g,
                ev.odometer_m,
            ]
            .iter()
            .all(|x| x.is_finite())
            {
                self.apply(ev);
            } else {
                self.evidence_dropped += 1;
            }
        }
        let mut msg = format!(
            "clearance posterior restored from {} used event(s)",
            self.evidence.len()
        );
        if self.evidence_dropped > 0 {
            msg += &format!(
                " ({} older used event(s) not kept in the state and not replayed)",
                self.evidence_dropped
            );
        }
        Ok(Some(msg))
    }

    fn estimate(&self) -> Option<Estimate> {
        let est = self.obs.estimator()?;
        let s = est.summary();
        let used = s.events_used > 0;
        Some(Estimate {
            clearance_mm: (used && s.detectable).then_some(s.median_mm),
            interval_mm: used.then_some([s.q05_mm, s.q95_mm]),
            detectable: used && s.detectable,
            below_mm: (used && !s.detectable).then_some(s.below_mm),
            p_above: used.then(|| est.prob_above(self.clearance_mm)),
            events_used: s.events_used,
        })
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Brake applications of 0.8 s at 0.5 g at 72 km/h, one every 2 s, sampled at 10 Hz
    /// (too slow for estimation: cheap events that are still detected and reported).
    fn feed(stage: &mut ObserverStage, cycles: usize) -> usize {
        let mut found = 0;
        for k in 0..cycles * 20 {
            let t = k as f64 * 0.1;
            // Brake off first: the detector needs to see the onset.
            let braking = (k % 20) >= 12;
            let s = Sample {
                t_ns: (t * 1e9) as i64,
                steer_rad: Some(0.0),
                speed_mps: Some(20.0),
                accel_mps2: Some(if braking { -4.9 } else { 0.0 }),
                brake: Some(braking),
                steer_invalid: false,
            };
            found += stage.push(&s).is_some() as usize;
        }
        found + stage.finish().is_some() as usize
    }

    #[test]
    fn events_past_the_observers_report_cap_still_reach_the_daemon() {
        let mut stage = ObserverStage::new(&ObserverConfig::default(), None).unwrap();
        let cycles = crate::observer::MAX_EVENTS_KEPT + 5;
        assert_eq!(feed(&mut stage, cycles), cycles);
        assert_eq!(stage.obs.events().len(), crate::observer::MAX_EVENTS_KEPT);
        assert!(stage.estimate().is_none(), "no table: no estimate");
    }
}
