//! The adapter between shimmyd's [`EventStage`] seam and the clearance observer
//! ([`crate::observer::Observer`], issue 5): converts the daemon's samples, hands each newly
//! finished braking event to the daemon, and reports the estimator's posterior.
//!
//! What it is not: a detector, an estimator or an alert rule. Detection and the amplitude
//! estimate (MODEL.md §11) are the observer's; the alerts the daemon raises are
//! [`crate::alerts`]' (the observer's own alert state is not used here).

use super::config::Config;
use super::pipeline::{Estimate, EventStage, EventSummary, Sample};
use crate::events;
use crate::observer::alerts::MAX_WINDOW;
use crate::observer::table::ResponseTable;
use crate::observer::{EventOut, Observer, ObserverConfig};

/// [`EventStage`] over the real observer.
pub struct ObserverStage {
    obs: Observer,
    /// Events already handed to the daemon (compared with `Observer::events_seen`, which keeps
    /// counting past the observer's bounded event list).
    seen: u64,
    has_table: bool,
    clearance_mm: f64,
}

impl ObserverStage {
    /// Copies `[events]` and `[alerts]` into the observer's configuration; `table` is the loaded
    /// `vehicle.table` (without it events and amplitudes still flow, no clearance estimate).
    pub fn new(cfg: &Config, table: Option<ResponseTable>) -> anyhow::Result<ObserverStage> {
        let mut oc = ObserverConfig::default();
        let (e, a) = (&cfg.events, &cfg.alerts);
        oc.events.min_speed_kmh = e.min_speed_kmh;
        oc.events.max_speed_kmh = e.max_speed_kmh;
        oc.events.min_decel_g = e.min_decel_g;
        oc.events.max_decel_g = e.max_decel_g;
        oc.events.max_steer_deg = e.max_steer_deg;
        oc.alerts.clearance_mm = a.clearance_mm;
        oc.alerts.clearance_probability = a.clearance_probability;
        oc.alerts.shimmy_amplitude_deg = a.shimmy_deg;
        oc.alerts.shimmy_speed_lo_kmh = a.shimmy_speed_min_kmh;
        oc.alerts.shimmy_speed_hi_kmh = a.shimmy_speed_max_kmh;
        // The observer's own rule looks back at most MAX_WINDOW events; the daemon's alert
        // state (crate::alerts) applies the configured window in full.
        oc.alerts.shimmy_window = a.shimmy_window.min(MAX_WINDOW);
        oc.alerts.shimmy_confirm = a.shimmy_confirm.min(oc.alerts.shimmy_window);
        let has_table = table.is_some();
        Ok(ObserverStage {
            obs: Observer::new(oc, table)?,
            seen: 0,
            has_table,
            clearance_mm: a.clearance_mm,
        })
    }

    fn take_new(&mut self) -> Option<EventSummary> {
        let n = self.obs.events_seen();
        if n == self.seen {
            return None;
        }
        // The observer finishes at most one event per pushed sample, so `last_event` is it.
        self.seen = n;
        self.obs.last_event().map(summary)
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
        // Filled in by the daemon from its own speed integration.
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
        self.obs.push(&events::Sample {
            t_ns: s.t_ns,
            steer_rad: s.steer_rad,
            speed_mps: s.speed_mps,
            accel_mps2: s.accel_mps2,
            brake: s.brake,
            steer_invalid: s.steer_invalid,
        });
        self.take_new()
    }

    fn finish(&mut self) -> Option<EventSummary> {
        self.obs.finish();
        self.take_new()
    }

    fn estimate(&self) -> Option<Estimate> {
        let est = self.obs.estimator()?;
        let s = est.summary();
        let used = s.events_used > 0;
        Some(Estimate {
            clearance_mm: (used && s.detectable).then_some(s.median_mm),
            interval_mm: used.then_some([s.q05_mm, s.q95_mm]),
            detectable: used && s.detectable,
            below_mm: (used && !s.detectable).then_some(s.q95_mm),
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
        let root = std::path::Path::new(env!("CARGO_MANIFEST_DIR"));
        let cfg = Config::load(&root.join("config/shimmyd.toml")).unwrap();
        let mut stage = ObserverStage::new(&cfg, None).unwrap();
        let cycles = crate::observer::MAX_EVENTS_KEPT + 5;
        assert_eq!(feed(&mut stage, cycles), cycles);
        assert_eq!(stage.obs.events().len(), crate::observer::MAX_EVENTS_KEPT);
        assert!(stage.estimate().is_none(), "no table: no estimate");
    }
}
