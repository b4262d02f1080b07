//! The steering sensors' own noise, measured on the vehicle while it stands still.
//!
//! What it is: a per-vehicle measurement of the white noise the steering-angle and torsion-bar
//! torque sensors add (MODEL.md §8's sensor model, §15's torque), compared with what the
//! response table assumed. A table is built with one sensor noise (the profile's `[sensors]`,
//! 0.01° and 0.02 N·m by default); a sensor noisier than that raises every band RMS, at braking
//! and at cruise, and the estimator reads the extra as road roughness or clearance: on
//! simulated RAV4 buses a torque three times as noisy as its table assumes (0.06 N·m) pins
//! most worn cars' estimates near 0.065 mm with narrow intervals. Where the measured RMS
//! exceeds `[features] noise_floor_ratio` times the assumed, the report says the model does not
//! fit the vehicle, with this reason and the table to build (`shimmy calibrate
//! --sensor-noise-deg`). Taking the excess variance out of the features instead was measured
//! and is worse (docs/ACCURACY.md): what remains is the noise's own scatter, which the table's
//! events do not have.
//!
//! How: at standstill (speed below [`STANDSTILL_MPS`] for [`SETTLE_S`], so the stop's own
//! transient has rung down: MODEL.md §6's fade ends at the stop and the free-play modes need
//! braking to be excited, §12) the wheels do not turn and the road does not move the steering,
//! so what the sensors report sample to sample is their noise plus the driver's slow hands.
//! For white noise of variance σ² (quantisation included, q²/12 once σ is about q or more)
//! consecutive samples differ by a variance 2σ²; the driver's hands move the rim and the
//! torsion bar over seconds, far less per 12–20 ms sample. Each stop gives one estimate
//! (mean squared difference / 2 over its consecutive samples, at least [`MIN_PAIRS`]); the
//! vehicle's is the median of its last [`MAX_STOPS`] stops, from [`MIN_STOPS`] on, so a stop
//! where the driver turned the wheel (parking) does not count.
//!
//! What it is not: a model of the signal (the plant's response at standstill is taken to be
//! nil, which MODEL.md's model makes exact and a car with an idling engine's vibration through
//! the column would not: that would read as sensor noise), or a correction for a quieter sensor
//! than assumed (the table's floor then sits slightly above the vehicle's, which errs toward
//! lower estimates at the smallest clearances, the harmless side for the alert).

use serde::{Deserialize, Serialize};

use crate::events::Sample;

/// Below this speed the vehicle stands still (m/s); wheel-speed sensors read 0 there.
pub const STANDSTILL_MPS: f64 = 0.15;
/// Samples count from this long after the vehicle came to stand (s).
pub const SETTLE_S: f64 = 0.3;
/// Two samples further apart than this are not consecutive (s): a dropped frame or a gap.
pub const MAX_GAP_S: f64 = 0.1;
/// Sample pairs one stop needs to give an estimate.
pub const MIN_PAIRS: u32 = 10;
/// Stops the vehicle needs before its noise counts as measured.
pub const MIN_STOPS: usize = 3;
/// Stops kept (the most recent).
pub const MAX_STOPS: usize = 64;

/// The two steering channels.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Channel {
    /// The steering-wheel angle, in deg.
    Angle = 0,
    /// The torsion-bar torque, in N·m.
    Torque = 1,
}

/// One channel's running stop and its kept per-stop estimates.
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
struct ChannelMeter {
    /// Per-stop variance estimates (unit², per sample), oldest first.
    stops: Vec<f64>,
    #[serde(skip)]
    last: Option<(i64, f64)>,
    #[serde(skip)]
    sum_d2: f64,
    #[serde(skip)]
    pairs: u32,
}

impl ChannelMeter {
    fn sample(&mut self, t_ns: i64, x: f64, counting: bool) {
        if !counting || !x.is_finite() {
            self.last = None;
            return;
        }
        if let Some((t0, x0)) = self.last {
            if (t_ns - t0) as f64 * 1e-9 <= MAX_GAP_S {
                self.sum_d2 += (x - x0) * (x - x0);
                self.pairs += 1;
            }
        }
        self.last = Some((t_ns, x));
    }

    /// The vehicle moves again: the stop's estimate is kept if it has enough pairs.
    fn end_stop(&mut self) {
        if self.pairs >= MIN_PAIRS {
            if self.stops.len() == MAX_STOPS {
                self.stops.remove(0);
            }
            self.stops.push(0.5 * self.sum_d2 / self.pairs as f64);
        }
        self.last = None;
        self.sum_d2 = 0.0;
        self.pairs = 0;
    }

    fn variance(&self) -> Option<f64> {
        if self.stops.len() < MIN_STOPS {
            return None;
        }
        let mut v = self.stops.clone();
        v.sort_by(f64::total_cmp);
        let n = v.len();
        Some(if n % 2 == 1 {
            v[n / 2]
        } else {
            0.5 * (v[n / 2 - 1] + v[n / 2])
        })
    }
}

/// The standstill noise meter of one vehicle, fed every detector sample.
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct NoiseFloor {
    channels: [ChannelMeter; 2],
    /// When the vehicle came to stand (ns), while it stands.
    #[serde(skip)]
    stood_since_ns: Option<i64>,
}

/// One channel's measurement, for the report.
#[derive(Clone, Copy, Debug, PartialEq, Serialize)]
pub struct MeasuredNoise {
    /// `"angle_deg"` or `"torque_nm"`.
    pub signal: super::features::SteerSignal,
    /// The sensor's noise measured at standstill (RMS, in the signal's unit).
    pub measured_rms: f64,
    /// What the response table assumes (RMS: white noise and quantisation).
    pub assumed_rms: f64,
    /// Stops it was measured over.
    pub stops: usize,
    /// Whether the measured RMS exceeds `[features] noise_floor_ratio` times the assumed: the
    /// table does not describe this sensor.
    pub above_assumed: bool,
}

impl NoiseFloor {
    /// Feeds one detector sample.
    pub fn push(&mut self, s: &Sample) {
        if let Some(v) = s.speed_mps {
            if v.abs() < STANDSTILL_MPS {
                self.stood_since_ns.get_or_insert(s.t_ns);
            } else if self.stood_since_ns.take().is_some() {
                self.channels.iter_mut().for_each(ChannelMeter::end_stop);
            }
        }
        let counting = self
            .stood_since_ns
            .is_some_and(|t0| (s.t_ns - t0) as f64 * 1e-9 >= SETTLE_S);
        if let Some(a) = s.steer_rad {
            self.channels[Channel::Angle as usize].sample(s.t_ns, a.to_degrees(), counting);
        }
        if let Some(t) = s.torque_nm {
            self.channels[Channel::Torque as usize].sample(s.t_ns, t, counting);
        }
    }

    /// The input ended (a log's end): a stop still open counts as if the vehicle had moved
    /// off.
    pub fn end_of_input(&mut self) {
        if self.stood_since_ns.take().is_some() {
            self.channels.iter_mut().for_each(ChannelMeter::end_stop);
        }
    }

    /// The channel's measured noise variance (unit², per sample: deg² or (N·m)²), once
    /// [`MIN_STOPS`] stops gave one.
    pub fn variance(&self, ch: Channel) -> Option<f64> {
        self.channels[ch as usize].variance()
    }

    /// Stops the channel's measurement rests on.
    pub fn stops(&self, ch: Channel) -> usize {
        self.channels[ch as usize].stops.len()
    }

    /// Whether the measured RMS exceeds `ratio` times the assumed RMS (`assumed_var` its
    /// square); never with `ratio` 0, which turns the check off, or without a measurement.
    pub fn exceeds(&self, ch: Channel, assumed_var: f64, ratio: f64) -> bool {
        self.variance(ch)
            .is_some_and(|m| ratio > 0.0 && m > ratio * ratio * assumed_var)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use rand::{Rng, SeedableRng};
    use rand_chacha::ChaCha8Rng;
    use rand_distr::StandardNormal;

    /// `stops` stops of 1 s at 50 Hz with torque noise `sigma`, separated by 2 s of driving at
    /// 15 m/s whose torque swings by 1 N·m (which must not count).
    fn drive(meter: &mut NoiseFloor, stops: usize, sigma: f64, turn_at_stop: Option<usize>) {
        let mut rng = ChaCha8Rng::seed_from_u64(3);
        let mut t = 0i64;
        let dt = 20_000_000i64;
        for k in 0..stops {
            for i in 0..100 {
                let x = (i as f64 * 0.3).sin();
                meter.push(&Sample {
                    t_ns: t,
                    speed_mps: Some(15.0),
                    torque_nm: Some(x),
                    ..Sample::default()
                });
                t += dt;
            }
            for i in 0..50 {
                let n: f64 = rng.sample(StandardNormal);
                // A driver turning the wheel while parked: 2 N·m over the stop.
                let hands = if turn_at_stop == Some(k) {
                    2.0 * i as f64 / 50.0 * (i as f64).sin()
                } else {
                    0.3
                };
                meter.push(&Sample {
                    t_ns: t,
                    speed_mps: Some(0.0),
                    torque_nm: Some(hands + sigma * n),
                    ..Sample::default()
                });
                t += dt;
            }
        }
        meter.push(&Sample {
            t_ns: t,
            speed_mps: Some(15.0),
            ..Sample::default()
        });
    }

    #[test]
    fn the_noise_is_measured_at_standstill_only_and_a_parking_turn_does_not_count() {
        let mut m = NoiseFloor::default();
        drive(&mut m, 2, 0.06, None);
        assert_eq!(
            m.variance(Channel::Torque),
            None,
            "two stops are not enough"
        );
        let mut m = NoiseFloor::default();
        drive(&mut m, 9, 0.06, Some(4));
        assert_eq!(m.stops(Channel::Torque), 9);
        let rms = m.variance(Channel::Torque).unwrap().sqrt();
        assert!((rms / 0.06 - 1.0).abs() < 0.1, "{rms}");
        assert_eq!(m.variance(Channel::Angle), None);
        // Above a table's 0.02 N·m × 1.5; not above 0.05 N·m × 1.5, nor with the check off, nor
        // on a channel without a measurement.
        let assumed = 0.02f64 * 0.02;
        assert!(m.exceeds(Channel::Torque, assumed, 1.5));
        assert!(!m.exceeds(Channel::Torque, 0.05 * 0.05, 1.5));
        assert!(!m.exceeds(Channel::Torque, assumed, 0.0));
        assert!(!m.exceeds(Channel::Angle, 1e-12, 1.5));
    }

    #[test]
    fn the_kept_stops_survive_a_save_and_restore() {
        let mut m = NoiseFloor::default();
        drive(&mut m, 5, 0.04, None);
        let text = serde_json::to_string(&m).unwrap();
        let back: NoiseFloor = serde_json::from_str(&text).unwrap();
        assert_eq!(back.variance(Channel::Torque), m.variance(Channel::Torque));
        assert_eq!(back.stops(Channel::Torque), 5);
    }
}
