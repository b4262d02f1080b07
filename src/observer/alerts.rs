//! `[alerts]`: the one settings schema of the two maintenance alerts (thresholds, windows and
//! hysteresis), read by `shimmy estimate --config` and by shimmyd, plus the deprecated key names
//! still accepted.
//!
//! What it is not: the alert rules. Both commands decide alerts with `crate::alerts::AlertBook`
//! (raise, update and clear with hysteresis, after each finished braking event), which reads
//! this type under the name `crate::alerts::AlertsSection`. It lives here, with the observer's
//! other settings, because config/observer.toml holds all of them in one file.

use serde::{Deserialize, Serialize};

/// Thresholds and hysteresis of the two alerts (`[alerts]` of config/observer.toml, the
/// monitor's settings file). This one table serves every command: `shimmy estimate` and shimmyd
/// run the same alert lifecycle on it (`crate::alerts::AlertBook`, whose `AlertsSection` is this
/// type), raise and clear thresholds alike. The earlier names ([`DEPRECATED_KEYS`]) are still
/// read, with a deprecation warning.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct AlertConfig {
    /// Clearance that raises the clearance alert (mm), article §4: replace beyond 0.1 mm.
    pub clearance_mm: f64,
    /// Raise when P(clearance > clearance_mm) is at least this ...
    pub clearance_probability: f64,
    /// ... clear when it falls below this (hysteresis).
    pub clearance_clear_probability: f64,
    /// The same pair for a vehicle whose steering shakes at the wheels' rotation while braking
    /// (the fit check's wheel-order shake, src/observer/wheel_order.rs: uneven brake discs).
    /// Part of what its posterior reads as clearance may be the discs' shake, so the alert asks
    /// for more: raised at this probability (at least `clearance_probability`) ...
    pub clearance_wheel_order_probability: f64,
    /// ... and cleared below this one. Equal to the two above: such vehicles are judged as
    /// any other (docs/ACCURACY.md, "The uneven-discs variant").
    pub clearance_wheel_order_clear_probability: f64,
    /// Raise only when P(clearance > clearance_mm) has been at least `clearance_probability`
    /// after each of the last `clearance_confirm` braking events that added to the estimate
    /// (1: on the first such event). A probability near the threshold can cross it with one
    /// event and fall back with the next; 2 or more keeps most such alerts from coming and
    /// going (docs/ACCURACY.md, "Confirming the clearance alert").
    pub clearance_confirm: usize,
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
    /// Clear only when at most `shimmy_clear_max` of the last `shimmy_window` events
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
            clearance_wheel_order_probability: 0.85,
            clearance_wheel_order_clear_probability: 0.7,
            clearance_confirm: 2,
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
