//! The steering angle sensor as the observer assumes it (MODEL.md §8): the continuous
//! steering-wheel angle δ_sw is sampled at a fixed rate, white noise is added, and the result is
//! quantised to the sensor's step after a random zero-point offset of under one step.
//!
//! Used to pass the model's output through the same sensor before computing features, so that
//! the response table ([`super::table`]) describes what a real sensor would report. What it is
//! not: a CAN encoder (firmware-sim does that) or a fit of any particular sensor.

use rand::Rng;
use rand_chacha::ChaCha8Rng;
use rand_distr::{Distribution, StandardNormal};
use serde::{Deserialize, Serialize};

use super::features::SteerSignal;

/// Sensor parameters: recorded in the response table (`sensor`), chosen with `shimmy calibrate
/// --sensor-rate-hz / --sensor-step-deg / --sensor-noise-deg`.
#[derive(Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct SensorModel {
    pub rate_hz: f64,
    pub step_deg: f64,
    pub noise_deg: f64,
    /// The driver's slow lane-keeping corrections at the steering wheel (deg RMS), white noise
    /// through two first-order lags of `drift_tau_s / 2` each. Far below the 3 Hz band edge,
    /// but it moves the angle across the sensor's steps, which changes what the steps do to a
    /// small shimmy (a constant angle between two steps hides it).
    pub drift_rms_deg: f64,
    pub drift_tau_s: f64,
    /// Which steering signal this sensor measures: the angle (deg) unless written; with
    /// `torque_nm` the EPS torsion-bar torque, and every `_deg` field above is in N·m.
    #[serde(skip_serializing_if = "SteerSignal::is_angle")]
    pub signal: SteerSignal,
}

/// Written as the derived form was before the sensor had a `signal`, which an angle sensor
/// leaves out: calibrate's work directories and events files name their sensor this way.
impl std::fmt::Debug for SensorModel {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        let mut d = f.debug_struct("SensorModel");
        d.field("rate_hz", &self.rate_hz)
            .field("step_deg", &self.step_deg)
            .field("noise_deg", &self.noise_deg)
            .field("drift_rms_deg", &self.drift_rms_deg)
            .field("drift_tau_s", &self.drift_tau_s);
        if !self.signal.is_angle() {
            d.field("signal", &self.signal);
        }
        d.finish()
    }
}

impl Default for SensorModel {
    fn default() -> Self {
        SensorModel {
            rate_hz: 100.0,
            step_deg: 0.1,
            noise_deg: 0.01,
            drift_rms_deg: 1.0,
            drift_tau_s: 2.0,
            signal: SteerSignal::AngleDeg,
        }
    }
}

impl SensorModel {
    /// The torsion-bar torque sensor of the Toyota profile's bus (config/vehicles/toyota_rav4:
    /// 50 Hz, 0.01 N·m per count as assumed there, 0.02 N·m white noise as firmware-sim sends
    /// it), with a driver's slow holding torque of 0.3 N·m RMS in place of the angle's drift
    /// (an assumption: far below the band, it only moves the signal across its steps).
    pub const TORQUE_RAV4: SensorModel = SensorModel {
        rate_hz: 50.0,
        step_deg: 0.01,
        noise_deg: 0.02,
        drift_rms_deg: 0.3,
        drift_tau_s: 2.0,
        signal: SteerSignal::TorqueNm,
    };

    /// Checks that the sensor can be simulated and its events detected (the detector needs
    /// more than 50 Hz for the angle's 25 Hz band edge; a torque, whose band ends at 0.4 of its
    /// rate, more than 25 Hz).
    pub fn validate(&self) -> anyhow::Result<()> {
        let ok = |x: f64, lo: f64, hi: f64| x.is_finite() && x >= lo && x <= hi;
        let min_hz = if self.signal.is_angle() { 50.0 } else { 25.0 };
        if !(self.rate_hz > min_hz && self.rate_hz <= 10_000.0) {
            anyhow::bail!(
                "sensor rate {} Hz: must be above {min_hz} and at most 10000",
                self.rate_hz
            );
        }
        if !ok(self.step_deg, 0.0, 10.0) {
            anyhow::bail!(
                "sensor step {} deg: must be 0-10 (0 = not quantised)",
                self.step_deg
            );
        }
        if !ok(self.noise_deg, 0.0, 10.0) || !ok(self.drift_rms_deg, 0.0, 90.0) {
            anyhow::bail!(
                "sensor noise {} / drift {} deg: must be 0-10 / 0-90",
                self.noise_deg,
                self.drift_rms_deg
            );
        }
        if !ok(self.drift_tau_s, 0.0, 1e3) {
            anyhow::bail!("sensor drift_tau_s {}: must be 0-1000", self.drift_tau_s);
        }
        Ok(())
    }

    /// Whether an event measured at `fs_hz` with quantisation step `step_deg` (both as the
    /// detector measured them; step 0 when no step was seen) came through a sensor like this
    /// one: the rate within 5 %, the step within 5 % (a step the signal never crossed, 0, is
    /// accepted; an unquantised sensor, step 0, accepts steps under 0.001°).
    pub fn matches(&self, fs_hz: f64, step_deg: f64) -> bool {
        let close = |a: f64, b: f64| (a - b).abs() <= 0.05 * b.abs();
        let step_ok = if self.step_deg == 0.0 {
            step_deg < 1e-3
        } else {
            step_deg == 0.0 || close(step_deg, self.step_deg)
        };
        close(fs_hz, self.rate_hz) && step_ok
    }

    /// Sample `x_rad` (uniform at `fs_in_hz`, starting at t = 0) into `out` as `(t_ns, rad)`.
    /// The sampling phase and the zero offset are drawn from `rng`. A torque sensor takes and
    /// gives N·m instead of rad.
    pub fn sample_into(
        &self,
        x_rad: &[f64],
        fs_in_hz: f64,
        rng: &mut ChaCha8Rng,
        out: &mut Vec<(i64, f64)>,
    ) {
        out.clear();
        let offset = rng.random_range(-0.5..0.5) * self.step_deg;
        let dt_in = 1.0 / fs_in_hz;
        let period = 1.0 / self.rate_hz;
        let mut t = rng.random_range(0.0..period);
        // Two-stage lag driven by unit white noise (stage 1 is an exact-discretised OU process
        // of unit variance; two equal stages halve it, hence the √2).
        let a = if self.drift_tau_s > 0.0 {
            (-period / (0.5 * self.drift_tau_s)).exp()
        } else {
            0.0
        };
        let drive = (1.0 - a * a).sqrt();
        let (mut x1, mut x2) = (0.0f64, 0.0f64);
        let mut drift = |rng: &mut ChaCha8Rng| {
            let w: f64 = StandardNormal.sample(rng);
            let x1p = x1;
            x1 = a * x1 + drive * w;
            x2 = a * x2 + (1.0 - a) * x1p;
            x2 * self.drift_rms_deg * std::f64::consts::SQRT_2
        };
        let warm = if a > 0.0 {
            (10.0 / (1.0 - a)) as usize
        } else {
            0
        };
        for _ in 0..warm.min(100_000) {
            drift(rng);
        }
        let t_end = (x_rad.len().saturating_sub(1)) as f64 * dt_in;
        while t <= t_end {
            let pos = t / dt_in;
            let k = pos.floor() as usize;
            let fr = pos - k as f64;
            let v = if k + 1 < x_rad.len() {
                x_rad[k] * (1.0 - fr) + x_rad[k + 1] * fr
            } else {
                x_rad[k]
            };
            let n: f64 = StandardNormal.sample(rng);
            let angle = self.signal.is_angle();
            let x = if angle { v.to_degrees() } else { v };
            let deg = x + offset + self.noise_deg * n + drift(rng);
            let q = if self.step_deg > 0.0 {
                (deg / self.step_deg).round() * self.step_deg
            } else {
                deg
            };
            out.push((
                (t * 1e9).round() as i64,
                if angle { q.to_radians() } else { q },
            ));
            t += period;
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn an_event_matches_the_sensor_it_came_through_and_no_other() {
        let s = SensorModel::default();
        assert!(s.matches(100.0, 0.1));
        assert!(s.matches(99.0, 0.1000001));
        // A still wheel shows no step at all; that says nothing against the sensor.
        assert!(s.matches(100.0, 0.0));
        assert!(!s.matches(50.0, 0.1));
        assert!(!s.matches(100.0, 0.01));
        assert!(!s.matches(100.0, 0.2));
        let float = SensorModel { step_deg: 0.0, ..s };
        assert!(float.matches(100.0, 1e-6) && !float.matches(100.0, 0.1));
        assert!(s.validate().is_ok());
        for bad in [
            SensorModel { rate_hz: 50.0, ..s },
            SensorModel {
                rate_hz: f64::NAN,
                ..s
            },
            SensorModel {
                step_deg: -0.1,
                ..s
            },
            SensorModel {
                noise_deg: f64::INFINITY,
                ..s
            },
        ] {
            assert!(bad.validate().is_err(), "{bad:?}");
        }
    }
}
