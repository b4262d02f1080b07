//! The checks of the monitor's settings that serde cannot express: ranges, orderings and the
//! alert rules' hysteresis (a clear threshold past its raise threshold would make an alert flap).
//! Every command that reads the settings runs them: `shimmy estimate --config`, firmware-sim's
//! fleets and shimmyd (whose errors name the keys as its own file spells them).
//!
//! What it is not: parsing (serde's, with unknown keys refused) or the daemon's own settings
//! (interfaces, outputs, MQTT: `crate::daemon::config`).

use anyhow::bail;

use super::ObserverConfig;

impl ObserverConfig {
    /// Fails with the offending key and value. `observer_prefix` is put before the
    /// `features.` and `estimator.` keys (`"observer."` where they come from a daemon file's
    /// `[observer]` table, `""` in the monitor's settings file).
    pub fn validate(&self, observer_prefix: &str) -> anyhow::Result<()> {
        let pre = observer_prefix;
        let e = &self.events;
        positive("events.min_speed_kmh", e.min_speed_kmh)?;
        positive("events.min_decel_g", e.min_decel_g)?;
        positive("events.max_steer_deg", e.max_steer_deg)?;
        positive("events.max_steer_change_deg", e.max_steer_change_deg)?;
        ordered(
            "events.min_speed_kmh",
            e.min_speed_kmh,
            "events.max_speed_kmh",
            e.max_speed_kmh,
        )?;
        ordered(
            "events.min_decel_g",
            e.min_decel_g,
            "events.max_decel_g",
            e.max_decel_g,
        )?;
        self.features
            .wheel_order
            .validate()
            .map_err(|e| anyhow::anyhow!("{pre}{e}"))?;
        let a = &self.alerts;
        positive("alerts.shimmy_deg", a.shimmy_deg)?;
        positive("alerts.shimmy_clear_deg", a.shimmy_clear_deg)?;
        if a.shimmy_clear_deg > a.shimmy_deg {
            bail!(
                "alerts.shimmy_clear_deg ({}) must not exceed alerts.shimmy_deg ({}): the alert would flap",
                a.shimmy_clear_deg,
                a.shimmy_deg
            );
        }
        positive("alerts.shimmy_speed_min_kmh", a.shimmy_speed_min_kmh)?;
        ordered(
            "alerts.shimmy_speed_min_kmh",
            a.shimmy_speed_min_kmh,
            "alerts.shimmy_speed_max_kmh",
            a.shimmy_speed_max_kmh,
        )?;
        if a.shimmy_window == 0 || a.shimmy_window > 64 {
            bail!(
                "alerts.shimmy_window: must be 1..=64 (got {})",
                a.shimmy_window
            );
        }
        if a.shimmy_confirm == 0 || a.shimmy_confirm > a.shimmy_window {
            bail!(
                "alerts.shimmy_confirm: must be 1..=alerts.shimmy_window ({}) (got {})",
                a.shimmy_window,
                a.shimmy_confirm
            );
        }
        if a.shimmy_clear_max >= a.shimmy_confirm {
            bail!(
                "alerts.shimmy_clear_max ({}) must be below alerts.shimmy_confirm ({}): the alert would flap",
                a.shimmy_clear_max,
                a.shimmy_confirm
            );
        }
        positive("alerts.clearance_mm", a.clearance_mm)?;
        let pairs = [
            ("alerts.clearance_probability", a.clearance_probability),
            (
                "alerts.clearance_clear_probability",
                a.clearance_clear_probability,
            ),
            (
                "alerts.clearance_wheel_order_probability",
                a.clearance_wheel_order_probability,
            ),
            (
                "alerts.clearance_wheel_order_clear_probability",
                a.clearance_wheel_order_clear_probability,
            ),
        ];
        for (key, p) in pairs {
            probability(key, p)?;
        }
        let [(raise_k, raise), (clear_k, clear), (wo_raise_k, wo_raise), (wo_clear_k, wo_clear)] =
            pairs;
        // Each pair clears below where it raises (hysteresis), and the wheel-order pair is the
        // stricter one at both ends.
        ordered(clear_k, clear, raise_k, raise)?;
        at_most(raise_k, raise, wo_raise_k, wo_raise)?;
        at_most(clear_k, clear, wo_clear_k, wo_clear)?;
        ordered(wo_clear_k, wo_clear, wo_raise_k, wo_raise)?;
        if a.clearance_confirm == 0 || a.clearance_confirm > 64 {
            bail!(
                "alerts.clearance_confirm: must be 1..=64 braking events (got {})",
                a.clearance_confirm
            );
        }
        let f = &self.features;
        positive(&format!("{pre}features.crest_factor"), f.crest_factor)?;
        if !(f.sensor.quant_step_deg.is_finite() && f.sensor.quant_step_deg >= 0.0) {
            bail!(
                "{pre}features.sensor.quant_step_deg: must be >= 0 (0 = measured per event) (got {})",
                f.sensor.quant_step_deg
            );
        }
        if !(f.noise_floor_ratio.is_finite() && (0.0..=100.0).contains(&f.noise_floor_ratio)) {
            bail!(
                "{pre}features.noise_floor_ratio: must be in [0, 100] (0 = off) (got {})",
                f.noise_floor_ratio
            );
        }
        if !(f.sensor.noise_deg.is_finite() && f.sensor.noise_deg >= 0.0) {
            bail!(
                "{pre}features.sensor.noise_deg: must be >= 0 (got {})",
                f.sensor.noise_deg
            );
        }
        self.estimator
            .validate()
            .map_err(|e| anyhow::anyhow!("{pre}{e}"))?;
        Ok(())
    }
}

fn positive(key: &str, v: f64) -> anyhow::Result<()> {
    if !(v.is_finite() && v > 0.0) {
        bail!("{key}: must be > 0 (got {v})");
    }
    Ok(())
}

fn ordered(lo_key: &str, lo: f64, hi_key: &str, hi: f64) -> anyhow::Result<()> {
    if !(lo < hi) {
        bail!("{lo_key} ({lo}) must be below {hi_key} ({hi})");
    }
    Ok(())
}

fn at_most(lo_key: &str, lo: f64, hi_key: &str, hi: f64) -> anyhow::Result<()> {
    if lo > hi {
        bail!("{lo_key} ({lo}) must be at most {hi_key} ({hi})");
    }
    Ok(())
}

fn probability(key: &str, p: f64) -> anyhow::Result<()> {
    if !(p > 0.0 && p < 1.0) {
        bail!("{key}: must be a probability strictly between 0 and 1 (got {p})");
    }
    Ok(())
}
