//! The monitor pipeline as both shimmyd and `shimmy estimate` run it, from detector samples to
//! the alerts standing: mapped samples → the event stage ([`EventStage`], normally
//! [`ObserverStage`] over the clearance observer) → one [`EventSummary`] and one [`Estimate`]
//! per finished braking event → the alert rules ([`crate::alerts::AlertBook`]).
//!
//! | item | job |
//! |---|---|
//! | [`observer_stage`] | [`ObserverStage`]: the clearance observer behind the [`EventStage`] seam, with a posterior that survives restarts |
//! | [`SpeedIntegrator`] | the odometer: speed integrated over time, the distance the estimator's wear model uses between events |
//! | [`finish_event`] | the step after each finished event: the event stamped with the odometer, the estimate after it, the alert rules run on both |
//! | [`Monitor`] | the three above wired together for an offline run (`shimmy estimate`), ending with the alerts standing |
//! | [`detector_sample`] | one mapped frame's signals as the detector's [`Sample`]: the brake rule, and which rejections mark the steering invalid |
//! | [`feeder`] | frames through the signal mapper into samples ([`feeder::Feeder`]), and the offline pipeline opened from a mapping, DBC, table and settings ([`feeder::Offline`]) |
//!
//! shimmyd uses [`SpeedIntegrator`] and [`finish_event`] directly, because it keeps the odometer
//! and the alert book in its persisted state; `shimmy estimate` uses [`Monitor`], which holds
//! them for one run. Both therefore raise, update and clear alerts after the same events with
//! the same estimates.
//!
//! What it is not: frame decoding or signal mapping (the mapper's; [`feeder`] only runs it),
//! detection or estimation (the observer's), the alert rules themselves ([`crate::alerts`]) or
//! any output (journal, state file, MQTT, JSON report).

pub mod feeder;
pub mod observer_stage;

use crate::alerts::{Alert, AlertBook, AlertsSection, Transition};
use crate::monitor::{Estimate, EventStage, EventSummary, Sample};
use crate::signals::{Outcome, Update, VehicleSignals};

/// One mapped frame as the detector's [`Sample`], the same for shimmyd and `shimmy estimate`:
/// `u` is what the mapper did with the frame, `snap` its signals just after it.
///
/// * The brake counts as applied when the pedal switch says so or the pressure exceeds
///   `brake_on_pa` (`[events] brake_on_bar`); either alone when only one is mapped.
/// * The steering angle, speed, acceleration and steering torque are carried when this frame
///   updated them.
/// * A steering frame that was rejected (checksum, repeated counter, short payload), or
///   accepted with no valid angle, marks the steering invalid (the detector counts it against
///   the event's data quality).
pub fn detector_sample(
    u: &Update,
    snap: &VehicleSignals,
    steer_msg: Option<usize>,
    brake_on_pa: f64,
) -> Sample {
    let brake = match (snap.brake_pressed.valid(), snap.brake_pressure_pa.valid()) {
        (Some(b), Some(p)) => Some(b || p > brake_on_pa),
        (Some(b), None) => Some(b),
        (None, Some(p)) => Some(p > brake_on_pa),
        (None, None) => None,
    };
    let mut s = Sample {
        t_ns: snap.t_ns,
        brake,
        ..Sample::default()
    };
    match u.outcome {
        Outcome::Accepted(ch) => {
            if ch.steer_angle {
                s.steer_rad = snap.steer_angle_rad.valid();
                s.steer_invalid = s.steer_rad.is_none();
            }
            if ch.speed {
                s.speed_mps = snap.speed_mps.valid();
            }
            if ch.accel {
                s.accel_mps2 = snap.accel_mps2.valid();
            }
            if ch.steer_torque {
                s.torque_nm = snap.steer_torque_nm.valid();
            }
        }
        Outcome::Rejected(_) => s.steer_invalid = Some(u.message) == steer_msg,
    }
    s
}

pub use observer_stage::{ObserverStage, Tables};

/// Longest gap between two speed readings that is bridged (s): across a longer gap (a log split
/// in two, a bus that went quiet) the distance is not guessed.
pub const MAX_SPEED_GAP_S: f64 = 1.0;

/// Speed integrated over time (trapezoid), one speed reading at a time. Gaps of
/// [`MAX_SPEED_GAP_S`] or more, and readings out of time order, add nothing.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct SpeedIntegrator {
    /// The last reading: (log time ns, speed m/s).
    pub last: Option<(i64, f64)>,
}

impl SpeedIntegrator {
    /// Continues from a reading saved earlier (a restart within a second of the last reading
    /// continues the integration).
    pub fn resume(last: Option<(i64, f64)>) -> SpeedIntegrator {
        SpeedIntegrator { last }
    }

    /// Takes one speed reading; returns the distance (m) driven since the previous one.
    pub fn advance(&mut self, t_ns: i64, v_mps: f64) -> f64 {
        let mut d = 0.0;
        if let Some((t0, v0)) = self.last {
            let dt = (t_ns - t0) as f64 * 1e-9;
            if dt > 0.0 && dt < MAX_SPEED_GAP_S {
                d = 0.5 * (v_mps + v0) * dt;
            }
        }
        self.last = Some((t_ns, v_mps));
        d
    }
}

/// What one finished braking event produced.
#[derive(Clone, Debug, PartialEq)]
pub struct Finished {
    /// The event, with the odometer at its end.
    pub event: EventSummary,
    /// The stage's clearance estimate after the event (None when it cannot estimate).
    pub estimate: Option<Estimate>,
    /// The alerts the event raised, updated or cleared (at most one per kind).
    pub transitions: Vec<Transition>,
}

/// The step after each finished braking event, the same for shimmyd and `shimmy estimate`:
/// stamps `event` with `odometer_km`, reads the stage's estimate after it, and runs the alert
/// rules on both.
pub fn finish_event(
    stage: &dyn EventStage,
    book: &mut AlertBook,
    rules: &AlertsSection,
    mut event: EventSummary,
    odometer_km: f64,
) -> Finished {
    event.odometer_km = odometer_km;
    let estimate = stage.estimate();
    let transitions = book.on_event(rules, &event, estimate.as_ref());
    Finished {
        event,
        estimate,
        transitions,
    }
}

/// The pipeline from samples to standing alerts for one offline run: the event stage, the
/// odometer and the alert book, fed one [`Sample`] at a time. The odometer starts at 0 km (only
/// distances between events matter to the estimate; the guidance's mileage bands read it).
pub struct Monitor<S: EventStage> {
    stage: S,
    rules: AlertsSection,
    book: AlertBook,
    speed: SpeedIntegrator,
    odometer_km: f64,
}

impl<S: EventStage> Monitor<S> {
    pub fn new(stage: S, rules: AlertsSection) -> Monitor<S> {
        Monitor {
            stage,
            rules,
            book: AlertBook::default(),
            speed: SpeedIntegrator::default(),
            odometer_km: 0.0,
        }
    }

    /// Feeds one sample; returns what the braking event that finished with it produced.
    /// Allocates only when an event finishes.
    pub fn push(&mut self, s: &Sample) -> Option<Finished> {
        if let Some(v) = s.speed_mps {
            self.odometer_km += self.speed.advance(s.t_ns, v) / 1000.0;
        }
        self.stage.odometer_km(self.odometer_km);
        let e = self.stage.push(s)?;
        Some(self.finished(e))
    }

    /// End of input: closes a braking event still open.
    pub fn finish(&mut self) -> Option<Finished> {
        self.stage.odometer_km(self.odometer_km);
        let e = self.stage.finish()?;
        Some(self.finished(e))
    }

    fn finished(&mut self, e: EventSummary) -> Finished {
        finish_event(
            &self.stage,
            &mut self.book,
            &self.rules,
            e,
            self.odometer_km,
        )
    }

    /// The alerts open now (raised and not cleared since), oldest first.
    pub fn standing(&self) -> &[Alert] {
        &self.book.open
    }

    /// The alert book: the open alerts and the rules' memory.
    pub fn book(&self) -> &AlertBook {
        &self.book
    }

    /// The event stage.
    pub fn stage(&self) -> &S {
        &self.stage
    }

    /// The event stage, to change (e.g. give its estimator a baseline before the logs).
    pub fn stage_mut(&mut self) -> &mut S {
        &mut self.stage
    }

    /// The odometer now (km since the start of the run).
    pub fn odometer_km(&self) -> f64 {
        self.odometer_km
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::alerts::Kind;
    use crate::signals::{Changed, Reading, Reject, Validity};

    fn reading<T: Copy>(v: Option<T>) -> Reading<T> {
        Reading {
            value: v,
            t_ns: v.map(|_| 0),
            validity: if v.is_some() {
                Validity::Valid
            } else {
                Validity::NotMapped
            },
        }
    }

    fn snap(pressed: Option<bool>, pressure_bar: Option<f64>) -> VehicleSignals {
        VehicleSignals {
            t_ns: 5,
            steer_angle_rad: reading(Some(0.01)),
            speed_mps: reading(Some(20.0)),
            brake_pressure_pa: reading(pressure_bar.map(|b| b * 1e5)),
            brake_pressed: reading(pressed),
            accel_mps2: reading(Some(-3.0)),
            yaw_rate_radps: reading(None),
            lat_accel_mps2: reading(None),
            steer_torque_nm: reading(None),
        }
    }

    #[test]
    fn the_brake_is_the_switch_or_the_pressure_above_the_configured_limit() {
        let u = Update {
            message: 1,
            outcome: Outcome::Accepted(Changed::default()),
        };
        let brake = |pressed, bar| detector_sample(&u, &snap(pressed, bar), Some(0), 3e5).brake;
        assert_eq!(brake(Some(false), Some(5.0)), Some(true), "pressure alone");
        assert_eq!(brake(Some(true), Some(1.0)), Some(true), "switch alone");
        assert_eq!(brake(Some(false), Some(1.0)), Some(false));
        assert_eq!(brake(None, Some(3.5)), Some(true));
        assert_eq!(brake(Some(true), None), Some(true));
        assert_eq!(brake(None, None), None);
        // The limit is the caller's ([events] brake_on_bar), not a constant.
        assert_eq!(
            detector_sample(&u, &snap(None, Some(3.5)), Some(0), 4e5).brake,
            Some(false)
        );
    }

    #[test]
    fn only_what_the_frame_updated_is_carried_and_a_rejected_steering_frame_is_invalid() {
        let ch = Changed {
            speed: true,
            ..Changed::default()
        };
        let s = detector_sample(
            &Update {
                message: 1,
                outcome: Outcome::Accepted(ch),
            },
            &snap(Some(false), None),
            Some(0),
            3e5,
        );
        assert_eq!((s.t_ns, s.speed_mps), (5, Some(20.0)));
        assert_eq!(
            (s.steer_rad, s.accel_mps2, s.steer_invalid),
            (None, None, false)
        );
        let rejected = |message| {
            detector_sample(
                &Update {
                    message,
                    outcome: Outcome::Rejected(Reject::CounterRepeat { counter: 3 }),
                },
                &snap(None, None),
                Some(0),
                3e5,
            )
        };
        assert!(rejected(0).steer_invalid, "the steering message");
        assert!(!rejected(1).steer_invalid, "another message");
    }

    /// A stage that finishes one used event per sample with `brake: Some(true)` and then
    /// reports the next scripted P(c > threshold).
    struct Scripted {
        p: Vec<f64>,
        done: usize,
        odometer_km: f64,
    }

    impl EventStage for Scripted {
        fn describe(&self) -> String {
            "scripted".into()
        }
        fn push(&mut self, s: &Sample) -> Option<EventSummary> {
            if s.brake != Some(true) {
                return None;
            }
            self.done += 1;
            let t = s.t_ns as f64 * 1e-9;
            Some(EventSummary {
                t_start: t - 2.0,
                t_end: t,
                v0_kmh: 80.0,
                decel_g: 0.5,
                peak_sw_bp_deg: Some(0.05),
                sw_amplitude_deg: Some(0.05),
                used: true,
                unused_reason: None,
                odometer_km: -1.0,
                ..Default::default()
            })
        }
        fn finish(&mut self) -> Option<EventSummary> {
            None
        }
        fn odometer_km(&mut self, km: f64) {
            self.odometer_km = km;
        }
        fn estimate(&self) -> Option<Estimate> {
            let p = *self.p.get(self.done.checked_sub(1)?)?;
            Some(Estimate {
                clearance_mm: Some(0.12),
                interval_mm: Some([0.05, 0.2]),
                detectable: true,
                below_mm: None,
                p_above: Some(p),
                events_used: self.done as u32,
                misfit: None,
                chassis_variant: None,
                chassis_variant_inspect: None,
                wheel_order_shake: false,
                wheel_order_discs_ruled_out: false,
                sensor_noisier: false,
            })
        }
    }

    fn sample(t_s: f64, brake: bool) -> Sample {
        Sample {
            t_ns: (t_s * 1e9) as i64,
            speed_mps: Some(20.0),
            brake: Some(brake),
            ..Sample::default()
        }
    }

    /// The clearance alert is raised at P >= clearance_probability (0.7) (here after one
    /// estimate: `clearance_confirm` 1), stands while P is between clearance_clear_probability
    /// (0.5) and 0.7, and clears below 0.5.
    #[test]
    fn the_clearance_alert_stands_inside_the_hysteresis_band_and_clears_below_it() {
        let stage = Scripted {
            p: vec![0.6, 0.8, 0.6, 0.55, 0.4],
            done: 0,
            odometer_km: 0.0,
        };
        let rules = AlertsSection {
            clearance_confirm: 1,
            ..AlertsSection::default()
        };
        let mut m = Monitor::new(stage, rules);
        let mut standing = Vec::new();
        let mut t = 0.0;
        for _ in 0..5 {
            for _ in 0..10 {
                t += 0.1;
                assert!(m.push(&sample(t, false)).is_none());
            }
            t += 0.1;
            let f = m.push(&sample(t, true)).expect("an event");
            assert!((f.event.odometer_km - m.odometer_km()).abs() < 1e-12);
            assert!(f.event.odometer_km > 0.0, "stamped with the odometer");
            standing.push(m.book().is_open(Kind::Clearance));
        }
        assert_eq!(standing, [false, true, true, true, false]);
        assert!(m.standing().is_empty());
        assert_eq!(
            m.stage().odometer_km,
            m.odometer_km(),
            "the stage is told the odometer"
        );
        // 5 events of 11 samples 0.1 s apart at 20 m/s, the first reading starting the count.
        assert!((m.odometer_km() - (55.0 - 1.0) * 0.1 * 20.0 / 1000.0).abs() < 1e-9);
    }

    #[test]
    fn speed_integrates_by_trapezoid_and_does_not_bridge_gaps() {
        let mut s = SpeedIntegrator::default();
        assert_eq!(
            s.advance(0, 10.0),
            0.0,
            "the first reading has no predecessor"
        );
        assert!((s.advance(500_000_000, 20.0) - 7.5).abs() < 1e-12);
        assert_eq!(
            s.advance(1_500_000_000, 20.0),
            0.0,
            "a 1 s gap is not bridged"
        );
        assert_eq!(s.advance(1_400_000_000, 20.0), 0.0, "backwards in time");
        assert!((s.advance(1_500_000_000, 20.0) - 2.0).abs() < 1e-12);
    }
}
