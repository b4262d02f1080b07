//! The alert rules of `shimmy estimate`'s report: pure decisions over the estimator's posterior
//! and the recent events' amplitude estimates. No I/O, no allocation after construction.
//!
//! * `clearance`: the posterior gives `P(c > clearance_mm) ≥ clearance_probability`.
//! * `shimmy_55kmh`: of the last `shimmy_window` used events that began at
//!   `shimmy_speed_min_kmh`–`shimmy_speed_max_kmh`, at least `shimmy_confirm` show a
//!   steering-wheel amplitude above `shimmy_deg`. The amplitude is
//!   the wheel's estimated true amplitude (noise-corrected, see [`super::features`]), not the
//!   raw peak of the stepped signal.

use serde::{Deserialize, Serialize};

/// Thresholds and hysteresis of the two alerts (`[alerts]` of config/observer.toml, the
/// monitor's settings file). This one table serves every command: `shimmy estimate` applies the
/// raise thresholds, shimmyd's alert lifecycle ([`crate::alerts`], whose `AlertsSection` is this
/// type) also the clear thresholds. The earlier names ([`DEPRECATED_KEYS`]) are still read, with
/// a deprecation warning.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct AlertConfig {
    /// Clearance that raises the clearance alert (mm), article §4: replace beyond 0.1 mm.
    pub clearance_mm: f64,
    /// Raise when P(clearance > clearance_mm) is at least this ...
    pub clearance_probability: f64,
    /// ... clear (shimmyd) when it falls below this (hysteresis).
    pub clearance_clear_probability: f64,
    /// Steering-wheel shimmy amplitude that raises the shimmy alert (deg), article §4: 0.2°.
    #[serde(alias = "shimmy_amplitude_deg")]
    pub shimmy_deg: f64,
    /// Initial-speed window of the braking events the shimmy alert looks at (km/h).
    #[serde(alias = "shimmy_speed_lo_kmh")]
    pub shimmy_speed_min_kmh: f64,
    #[serde(alias = "shimmy_speed_hi_kmh")]
    pub shimmy_speed_max_kmh: f64,
    /// Raise when at least `shimmy_confirm` of the last `shimmy_window` events in the speed
    /// window are above `shimmy_deg`.
    pub shimmy_window: usize,
    pub shimmy_confirm: usize,
    /// Clear (shimmyd) only when at most `shimmy_clear_max` of the last `shimmy_window` events
    /// are above `shimmy_clear_deg` (hysteresis: lower than `shimmy_deg`).
    pub shimmy_clear_deg: f64,
    pub shimmy_clear_max: usize,
}

impl Default for AlertConfig {
    fn default() -> Self {
        AlertConfig {
            clearance_mm: 0.1,
            clearance_probability: 0.7,
            clearance_clear_probability: 0.5,
            shimmy_deg: 0.2,
            shimmy_speed_min_kmh: 50.0,
            shimmy_speed_max_kmh: 60.0,
            shimmy_window: 5,
            shimmy_confirm: 2,
            shimmy_clear_deg: 0.15,
            shimmy_clear_max: 0,
        }
    }
}

/// `[alerts]` keys of config/observer.toml that were renamed to shimmyd's names: (old, new).
/// The old names are accepted for one release, with a warning naming the new key.
pub const DEPRECATED_KEYS: &[(&str, &str)] = &[
    ("shimmy_amplitude_deg", "shimmy_deg"),
    ("shimmy_speed_lo_kmh", "shimmy_speed_min_kmh"),
    ("shimmy_speed_hi_kmh", "shimmy_speed_max_kmh"),
];

/// The deprecation warnings for an `[alerts]` table as written: one per old key it uses,
/// naming the key that replaces it.
pub fn deprecations(alerts: &toml::Table) -> Vec<String> {
    DEPRECATED_KEYS
        .iter()
        .filter(|(old, _)| alerts.contains_key(*old))
        .map(|(old, new)| {
            format!(
                "[alerts] {old} is deprecated and will be removed in the next release; \
                 use {new} (same meaning, same value)"
            )
        })
        .collect()
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
        if !(cfg.shimmy_speed_min_kmh..=cfg.shimmy_speed_max_kmh).contains(&v0_kmh) {
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
            .filter(|(_, a)| *a > cfg.shimmy_deg)
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
