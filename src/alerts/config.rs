//! The alert rules' settings (`[alerts]`): the thresholds, windows and hysteresis of the two
//! maintenance alerts ([`super::Kind`]), with the defaults of the source study.
//!
//! What it is not: the loading or validation of a configuration file. `shimmyd`'s file embeds
//! this table as its `[alerts]` and checks the values when it loads (`daemon::config`).

use serde::{Deserialize, Serialize};

/// `[alerts]`: the two maintenance alerts and their hysteresis.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct AlertsSection {
    /// Steering-wheel shimmy amplitude that raises the shimmy alert (deg), article §4: 0.2°.
    pub shimmy_deg: f64,
    /// Initial-speed window of the braking events the shimmy alert looks at (km/h).
    pub shimmy_speed_min_kmh: f64,
    pub shimmy_speed_max_kmh: f64,
    /// Raise when at least `shimmy_confirm` of the last `shimmy_window` events in the speed
    /// window are above `shimmy_deg`.
    pub shimmy_confirm: usize,
    pub shimmy_window: usize,
    /// Clear only when at most `shimmy_clear_max` of the last `shimmy_window` events are above
    /// `shimmy_clear_deg` (hysteresis: lower than `shimmy_deg`).
    pub shimmy_clear_deg: f64,
    pub shimmy_clear_max: usize,
    /// Clearance that raises the clearance alert (mm), article §4: replace beyond 0.1 mm.
    pub clearance_mm: f64,
    /// Raise when P(clearance > clearance_mm) is at least this ...
    pub clearance_probability: f64,
    /// ... clear when it falls below this (hysteresis).
    pub clearance_clear_probability: f64,
}

impl Default for AlertsSection {
    fn default() -> Self {
        AlertsSection {
            shimmy_deg: 0.2,
            shimmy_speed_min_kmh: 50.0,
            shimmy_speed_max_kmh: 60.0,
            shimmy_confirm: 2,
            shimmy_window: 5,
            shimmy_clear_deg: 0.15,
            shimmy_clear_max: 0,
            clearance_mm: 0.1,
            clearance_probability: 0.9,
            clearance_clear_probability: 0.5,
        }
    }
}
