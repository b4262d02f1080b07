//! The alert rules of `shimmy estimate`'s report: pure decisions over the estimator's posterior
//! and the recent events' amplitude estimates. No I/O, no allocation after construction.
//!
//! * `clearance`: the posterior gives `P(c > clearance_mm) ≥ probability`.
//! * `shimmy_55kmh`: of the last `window` used events that began at `speed_lo_kmh`–`speed_hi_kmh`,
//!   at least `confirm` show a steering-wheel amplitude above `amplitude_deg`. The amplitude is
//!   the wheel's estimated true amplitude (noise-corrected, see [`super::features`]), not the
//!   raw peak of the stepped signal.

use serde::{Deserialize, Serialize};

/// Thresholds (`[alerts]` of config/observer.toml).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct AlertConfig {
    pub clearance_mm: f64,
    pub clearance_probability: f64,
    pub shimmy_amplitude_deg: f64,
    pub shimmy_speed_lo_kmh: f64,
    pub shimmy_speed_hi_kmh: f64,
    pub shimmy_window: usize,
    pub shimmy_confirm: usize,
}

impl Default for AlertConfig {
    fn default() -> Self {
        AlertConfig {
            clearance_mm: 0.1,
            clearance_probability: 0.9,
            shimmy_amplitude_deg: 0.2,
            shimmy_speed_lo_kmh: 50.0,
            shimmy_speed_hi_kmh: 60.0,
            shimmy_window: 5,
            shimmy_confirm: 2,
        }
    }
}

/// Most events the shimmy rule can look back on.
pub const MAX_WINDOW: usize = 16;

/// The `shimmy_55kmh` rule's memory: the last few amplitudes at 50–60 km/h.
#[derive(Clone, Debug, Default)]
pub struct ShimmyRule {
    recent: heapless::Deque<(f64, f64), MAX_WINDOW>,
}

impl ShimmyRule {
    /// Offers one used event; returns whether it counted (speed in range).
    pub fn offer(
        &mut self,
        cfg: &AlertConfig,
        t_start_s: f64,
        v0_kmh: f64,
        amplitude_deg: f64,
    ) -> bool {
        if !(cfg.shimmy_speed_lo_kmh..=cfg.shimmy_speed_hi_kmh).contains(&v0_kmh) {
            return false;
        }
        let window = cfg.shimmy_window.clamp(1, MAX_WINDOW);
        while self.recent.len() >= window {
            self.recent.pop_front();
        }
        let _ = self.recent.push_back((t_start_s, amplitude_deg));
        true
    }

    /// Events in the window above the threshold.
    pub fn hits(&self, cfg: &AlertConfig) -> usize {
        self.recent
            .iter()
            .filter(|(_, a)| *a > cfg.shimmy_amplitude_deg)
            .count()
    }

    pub fn active(&self, cfg: &AlertConfig) -> bool {
        self.hits(cfg) >= cfg.shimmy_confirm.max(1)
    }

    /// `(t_start_s, amplitude_deg)` of the events in the window, oldest first.
    pub fn recent(&self) -> impl Iterator<Item = &(f64, f64)> {
        self.recent.iter()
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn needs_two_of_the_last_five_in_the_speed_band() {
        let cfg = AlertConfig::default();
        let mut r = ShimmyRule::default();
        assert!(!r.offer(&cfg, 0.0, 80.0, 1.0), "80 km/h is outside 50-60");
        r.offer(&cfg, 1.0, 55.0, 0.3);
        assert!(!r.active(&cfg), "one event is not confirmed");
        r.offer(&cfg, 2.0, 52.0, 0.1);
        r.offer(&cfg, 3.0, 58.0, 0.25);
        assert!(r.active(&cfg));
        for k in 0..4 {
            r.offer(&cfg, 4.0 + k as f64, 55.0, 0.1);
        }
        assert_eq!(r.hits(&cfg), 1, "the 0.3 fell out of the window of 5");
        assert!(!r.active(&cfg));
        r.offer(&cfg, 9.0, 55.0, 0.1);
        assert_eq!(r.hits(&cfg), 0, "and now the 0.25 too");
        assert!(!r.active(&cfg));
    }
}
