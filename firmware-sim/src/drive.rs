//! The driver's feet: turns a scenario's drive cycle (cruise, brake, stand) into the longitudinal
//! demand the plant integrates each step, the brake pedal state the brake ECU reports, and the
//! list of braking events for the ground truth.
//!
//! Braking follows MODEL.md §6: a linear ramp-in to `decel_g·g`, faded by `min(1, v/v_stop)` so
//! the car comes smoothly to rest; an event with a duration ramps out linearly instead. Between
//! events the driver re-accelerates towards the next cruise speed at `accel_g`, easing in near
//! the target (first-order approach) with a jerk limit, so there are no steps in the demand.
//!
//! Not here: the vehicle dynamics (the plant integrates `v' = −a_dem`) or any sensor.

use crate::scenario::{Drive, Segment};
use shimmy::model::braking::driver::{CRUISE_TAU_S, CRUISE_TOL_MPS, JERK_MPS3, V_STANDSTILL_MPS};

/// Standard gravity (m/s²).
pub const G: f64 = 9.80665;
/// MODEL.md §6: speed below which the plant fades the braking deceleration out linearly (m/s).
pub const V_STOP_MPS: f64 = 0.5;
/// Holding demand while standing (g), faded by the plant like any braking demand.
const HOLD_DECEL_G: f64 = 0.3;

/// What the driver does at one instant.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct DriveCmd {
    /// Demanded longitudinal deceleration (m/s², + = slowing down, − = accelerating). Braking
    /// demand is given before the MODEL.md §6 standstill fade `min(1, v/v_stop)`, which the
    /// plant applies (see [`crate::plant::Plant::set_decel_demand`]).
    pub decel_demand_mps2: f64,
    /// Braking deceleration the pedal asks for (m/s²): what sets the master-cylinder pressure.
    /// 0 when the pedal is released.
    pub pedal_decel_mps2: f64,
    /// Brake light switch.
    pub brake_pressed: bool,
    /// True once every segment has run.
    pub done: bool,
}

/// One braking event as it actually happened.
#[derive(Clone, Debug, PartialEq, serde::Serialize)]
pub struct BrakeEvent {
    /// Index in the scenario's segment list.
    pub segment: usize,
    /// Brake onset (s, simulated time).
    pub t_start_s: f64,
    /// End of deceleration: the stop, or the end of the ramp-out (s).
    pub t_end_s: f64,
    /// Brake pedal released (after the standstill hold for events to a stop) (s).
    pub t_release_s: f64,
    /// Speed at onset (km/h).
    pub v0_kmh: f64,
    /// Speed at `t_end_s` (km/h): 0 for an event to a stop.
    pub v_end_kmh: f64,
    /// Plateau deceleration (g).
    pub decel_g: f64,
    /// Whether the event brakes to a stop.
    pub to_stop: bool,
}

#[derive(Clone, Copy, Debug, PartialEq)]
enum Phase {
    /// Approaching the cruise speed.
    Approach,
    /// Holding it since `t0`.
    Hold { t0: f64 },
    /// Coasting since `t0`.
    Coasting { t0: f64 },
    /// Braking since `t0`.
    Braking { t0: f64 },
    /// Stopped at `t_stop`, pedal still pressed.
    StoppedHold { t_stop: f64 },
    /// Pedal being released since `t0` from `from_mps2`.
    Release { t0: f64, from_mps2: f64 },
    /// Standing since `t0`.
    Standing { t0: f64 },
}

/// The drive-cycle state machine. Call [`Driver::update`] once per control update (every model
/// step `step_s`, or every `control_period_s`: the `dt_s` given to [`Driver::new`]) with the
/// current time and speed.
#[derive(Clone, Debug)]
pub struct Driver {
    drive: Drive,
    seg: usize,
    phase: Phase,
    /// Last non-braking demand (for the jerk limit).
    last_demand: f64,
    events: Vec<BrakeEvent>,
    started: bool,
    /// Interval between calls to `update` (s).
    dt_s: f64,
}

impl Driver {
    pub fn new(drive: &Drive, dt_s: f64) -> Driver {
        let n_brakes = drive
            .segments
            .iter()
            .filter(|s| matches!(s, Segment::Brake(_)))
            .count();
        Driver {
            drive: drive.clone(),
            seg: 0,
            phase: Phase::Approach,
            last_demand: 0.0,
            events: Vec::with_capacity(n_brakes),
            started: false,
            dt_s,
        }
    }

    /// Braking events so far (complete ones have `t_release_s` set).
    pub fn events(&self) -> &[BrakeEvent] {
        &self.events
    }

    /// Index of the braking event in progress (onset to release), if any.
    pub fn current_event(&self) -> Option<usize> {
        match self.phase {
            Phase::Braking { .. } | Phase::StoppedHold { .. } | Phase::Release { .. }
                if self.seg < self.drive.segments.len() =>
            {
                Some(self.events.len() - 1)
            }
            _ => None,
        }
    }

    /// Index of the braking event that is decelerating the car (onset to `t_end_s`: the stop
    /// or the end of the ramp-out), if any.
    pub fn braking_event(&self) -> Option<usize> {
        match self.phase {
            // (After the last segment the phase is left as it was.)
            Phase::Braking { .. } if self.seg < self.drive.segments.len() => {
                Some(self.events.len() - 1)
            }
            _ => None,
        }
    }

    /// The demand at time `t` (s) with the plant at speed `v` (m/s).
    pub fn update(&mut self, t: f64, v: f64) -> DriveCmd {
        if !self.started {
            self.started = true;
            self.enter(t, v);
        }
        // Advance through finished phases; bounded by the number of segments (each loop either
        // returns or moves to a later phase/segment).
        for _ in 0..(4 * self.drive.segments.len() + 8) {
            if self.seg >= self.drive.segments.len() {
                return DriveCmd {
                    done: true,
                    ..DriveCmd::default()
                };
            }
            match (self.drive.segments[self.seg].clone(), self.phase) {
                (
                    Segment::Cruise {
                        speed_kmh,
                        duration_s,
                    },
                    phase,
                ) => {
                    let target = speed_kmh / 3.6;
                    let t0 = match phase {
                        Phase::Approach => {
                            if (v - target).abs() <= CRUISE_TOL_MPS {
                                self.phase = Phase::Hold { t0: t };
                                t
                            } else {
                                return self.cruise_cmd(v, target);
                            }
                        }
                        Phase::Hold { t0 } => t0,
                        _ => unreachable!("cruise segment in a braking phase"),
                    };
                    if t - t0 >= duration_s {
                        self.next_segment(t, v);
                        continue;
                    }
                    return self.cruise_cmd(v, target);
                }
                (
                    Segment::Coast {
                        duration_s,
                        decel_g,
                    },
                    Phase::Coasting { t0 },
                ) => {
                    if t - t0 >= duration_s {
                        self.next_segment(t, v);
                        continue;
                    }
                    let want = if v <= V_STANDSTILL_MPS {
                        0.0
                    } else {
                        decel_g * G
                    };
                    return self.eased_cmd(want);
                }
                (Segment::Brake(b), Phase::Braking { t0 }) => {
                    let a_max = b.decel_g * G;
                    let tau = t - t0;
                    let ramp_in = if b.ramp_in_s > 0.0 {
                        (tau / b.ramp_in_s).clamp(0.0, 1.0)
                    } else {
                        1.0
                    };
                    let pedal = match b.duration_s {
                        Some(dur) => {
                            if tau >= dur {
                                self.finish_event(t, v, t);
                                self.next_segment(t, v);
                                continue;
                            }
                            let ramp_out = if b.ramp_out_s > 0.0 {
                                ((dur - tau) / b.ramp_out_s).clamp(0.0, 1.0)
                            } else {
                                1.0
                            };
                            a_max * ramp_in.min(ramp_out)
                        }
                        None => {
                            if v <= V_STANDSTILL_MPS {
                                let ev = self.events.last_mut().expect("event started");
                                ev.t_end_s = t;
                                ev.v_end_kmh = 0.0;
                                self.phase = Phase::StoppedHold { t_stop: t };
                                continue;
                            }
                            a_max * ramp_in
                        }
                    };
                    self.last_demand = 0.0;
                    return DriveCmd {
                        decel_demand_mps2: pedal,
                        pedal_decel_mps2: pedal,
                        brake_pressed: true,
                        done: false,
                    };
                }
                (Segment::Brake(b), Phase::StoppedHold { t_stop }) => {
                    let a_max = b.decel_g * G;
                    if t - t_stop >= b.hold_s {
                        self.phase = Phase::Release {
                            t0: t,
                            from_mps2: a_max,
                        };
                        continue;
                    }
                    return DriveCmd {
                        decel_demand_mps2: a_max,
                        pedal_decel_mps2: a_max,
                        brake_pressed: true,
                        done: false,
                    };
                }
                (Segment::Brake(b), Phase::Release { t0, from_mps2 }) => {
                    let frac = if b.ramp_out_s > 0.0 {
                        1.0 - (t - t0) / b.ramp_out_s
                    } else {
                        0.0
                    };
                    if frac <= 0.0 {
                        let ev = self.events.last_mut().expect("event started");
                        ev.t_release_s = t;
                        self.next_segment(t, v);
                        continue;
                    }
                    return DriveCmd {
                        decel_demand_mps2: from_mps2 * frac,
                        pedal_decel_mps2: from_mps2 * frac,
                        brake_pressed: true,
                        done: false,
                    };
                }
                (Segment::Stand { duration_s }, Phase::Standing { t0 }) => {
                    if t - t0 >= duration_s {
                        self.next_segment(t, v);
                        continue;
                    }
                    self.last_demand = 0.0;
                    // The brakes hold the car (and end the last of the §6 fade's creep).
                    return DriveCmd {
                        decel_demand_mps2: HOLD_DECEL_G * G,
                        ..DriveCmd::default()
                    };
                }
                (seg, phase) => unreachable!("segment {seg:?} in phase {phase:?}"),
            }
        }
        // Only reachable with zero-length segments piling up; finish at the next call.
        DriveCmd::default()
    }

    fn cruise_cmd(&mut self, v: f64, target: f64) -> DriveCmd {
        let accel = self.drive.accel_g * G;
        let coast = self.drive.coast_g * G;
        // First-order approach, limited to the driver's acceleration / coasting deceleration.
        let want = ((v - target) / CRUISE_TAU_S).clamp(-accel, coast);
        // Never demand deceleration at standstill.
        let want = if v <= V_STANDSTILL_MPS {
            want.min(0.0)
        } else {
            want
        };
        self.eased_cmd(want)
    }

    /// A demand without the pedal, moved towards `want` (m/s²) under the jerk limit.
    fn eased_cmd(&mut self, want: f64) -> DriveCmd {
        // Jerk limit: `update` is called once per model step of `dt_s`.
        let max_change = JERK_MPS3 * self.dt_s;
        let d = (want - self.last_demand).clamp(-max_change, max_change);
        self.last_demand += d;
        DriveCmd {
            decel_demand_mps2: self.last_demand,
            pedal_decel_mps2: 0.0,
            brake_pressed: false,
            done: false,
        }
    }

    fn finish_event(&mut self, t_end: f64, v: f64, t_release: f64) {
        let ev = self.events.last_mut().expect("event started");
        ev.t_end_s = t_end;
        ev.v_end_kmh = v * 3.6;
        ev.t_release_s = t_release;
    }

    fn next_segment(&mut self, t: f64, v: f64) {
        self.seg += 1;
        self.enter(t, v);
    }

    fn enter(&mut self, t: f64, v: f64) {
        let Some(seg) = self.drive.segments.get(self.seg) else {
            return;
        };
        self.phase = match seg {
            Segment::Cruise { .. } => Phase::Approach,
            Segment::Brake(b) => {
                self.events.push(BrakeEvent {
                    segment: self.seg,
                    t_start_s: t,
                    t_end_s: f64::NAN,
                    t_release_s: f64::NAN,
                    v0_kmh: v * 3.6,
                    v_end_kmh: f64::NAN,
                    decel_g: b.decel_g,
                    to_stop: b.duration_s.is_none(),
                });
                Phase::Braking { t0: t }
            }
            Segment::Coast { .. } => Phase::Coasting { t0: t },
            Segment::Stand { .. } => Phase::Standing { t0: t },
        };
    }

    /// The steering-wheel angle (deg) of a braking event's `turn_deg` at time `t`: turned in
    /// linearly over the cruise or coast just before the event, held at brake onset, returned
    /// to 0 over `turn_unwind_s` after it; 0 elsewhere.
    pub fn turn_deg(&self, t: f64) -> f64 {
        let segs = &self.drive.segments;
        let Some(seg) = segs.get(self.seg) else {
            return 0.0;
        };
        match (seg, self.phase) {
            (
                Segment::Brake(b),
                Phase::Braking { .. } | Phase::StoppedHold { .. } | Phase::Release { .. },
            ) if b.turn_deg != 0.0 => {
                let t0 = self.events.last().map_or(t, |e| e.t_start_s);
                b.turn_deg * (1.0 - (t - t0) / b.turn_unwind_s).clamp(0.0, 1.0)
            }
            (Segment::Cruise { duration_s: d, .. }, Phase::Hold { t0 })
            | (Segment::Coast { duration_s: d, .. }, Phase::Coasting { t0 }) => {
                match segs.get(self.seg + 1) {
                    Some(Segment::Brake(b)) if b.turn_deg != 0.0 => {
                        let frac = if *d > 0.0 { (t - t0) / d } else { 1.0 };
                        b.turn_deg * frac.clamp(0.0, 1.0)
                    }
                    _ => 0.0,
                }
            }
            _ => 0.0,
        }
    }

    /// The road-noise scale (`road_noise_scale`) of the braking event in progress (onset to
    /// the pedal's release), 1 otherwise.
    pub fn road_noise_scale(&self) -> f64 {
        match (self.drive.segments.get(self.seg), self.phase) {
            (
                Some(Segment::Brake(b)),
                Phase::Braking { .. } | Phase::StoppedHold { .. } | Phase::Release { .. },
            ) => b.road_noise_scale,
            _ => 1.0,
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::scenario::Scenario;

    /// Integrate `v' = −a_dem` with the driver in the loop, as the plant would.
    fn run(text: &str) -> (Driver, Vec<(f64, f64, DriveCmd)>) {
        let sc = Scenario::parse(text, "test").unwrap();
        let h = 1e-3;
        let mut d = Driver::new(&sc.drive, h);
        let mut v = sc.drive.start_speed_kmh / 3.6;
        let mut out = Vec::new();
        for n in 0..200_000 {
            let t = n as f64 * h;
            let cmd = d.update(t, v);
            if cmd.done {
                return (d, out);
            }
            out.push((t, v, cmd));
            // The plant's MODEL.md §6 fade of braking demand.
            let a = if cmd.decel_demand_mps2 > 0.0 {
                cmd.decel_demand_mps2 * (v / V_STOP_MPS).min(1.0)
            } else {
                cmd.decel_demand_mps2
            };
            v = (v - a * h).max(0.0);
        }
        panic!("drive cycle did not end");
    }

    const CYCLE: &str = r#"
seed = 1
[clearance]
left_mm = 0.1
[drive]
start_speed_kmh = 30
accel_g = 0.25
[[drive.segment]]
kind = "cruise"
speed_kmh = 55
duration_s = 1.0
[[drive.segment]]
kind = "brake"
decel_g = 0.5
hold_s = 0.5
[[drive.segment]]
kind = "stand"
duration_s = 0.5
[[drive.segment]]
kind = "cruise"
speed_kmh = 75
duration_s = 0.5
[[drive.segment]]
kind = "brake"
decel_g = 0.6
duration_s = 2.0
"#;

    #[test]
    fn events_start_at_the_cruise_speed_and_reach_their_plateau() {
        let (d, trace) = run(CYCLE);
        let ev = d.events();
        assert_eq!(ev.len(), 2);
        // Stop from 55 km/h at 0.5 g.
        assert!((ev[0].v0_kmh - 55.0).abs() < 0.5, "{:?}", ev[0]);
        assert!(ev[0].to_stop && ev[0].v_end_kmh == 0.0);
        // MODEL.md §6: 55 km/h at 0.5 g stops about 3.3 s after onset (0.3 s ramp + fade).
        let dur = ev[0].t_end_s - ev[0].t_start_s;
        assert!((3.1..3.6).contains(&dur), "stop took {dur} s");
        assert!((ev[0].t_release_s - ev[0].t_end_s - 0.5 - 0.3).abs() < 0.01);
        // Slowdown from 75 km/h at 0.6 g for 2 s: about 0.6·g·1.7 s = 36 km/h less.
        assert!((ev[1].v0_kmh - 75.0).abs() < 0.5, "{:?}", ev[1]);
        assert!((ev[1].t_end_s - ev[1].t_start_s - 2.0).abs() < 0.01);
        assert!((ev[1].v_end_kmh - (75.0 - 0.6 * G * 1.7 * 3.6)).abs() < 1.0);
        let peak = trace
            .iter()
            .filter(|(t, _, _)| *t >= ev[0].t_start_s && *t < ev[0].t_end_s)
            .map(|(_, _, c)| c.pedal_decel_mps2)
            .fold(0.0, f64::max);
        assert!((peak - 0.5 * G).abs() < 1e-9);
    }

    #[test]
    fn ramp_in_is_linear_over_its_time() {
        let (d, trace) = run(CYCLE);
        let t0 = d.events()[0].t_start_s;
        let at = |dt: f64| {
            trace
                .iter()
                .find(|(t, _, _)| *t >= t0 + dt - 1e-9)
                .unwrap()
                .2
                .decel_demand_mps2
        };
        assert!((at(0.15) - 0.25 * G).abs() < 0.05);
        assert!((at(0.3) - 0.5 * G).abs() < 0.05);
    }

    #[test]
    fn non_braking_demand_is_jerk_limited_and_within_driver_limits() {
        let (_, trace) = run(CYCLE);
        for w in trace.windows(2) {
            let (a, b) = (&w[0].2, &w[1].2);
            // (Standing still, the holding demand is faded away by the plant: no jerk there.)
            if !a.brake_pressed && !b.brake_pressed && w[0].1 > V_STOP_MPS {
                let jerk = (b.decel_demand_mps2 - a.decel_demand_mps2).abs() / 1e-3;
                assert!(jerk <= JERK_MPS3 + 1e-6, "jerk {jerk}");
                assert!(b.decel_demand_mps2 >= -0.25 * G - 1e-9);
            }
        }
    }

    #[test]
    fn brake_switch_covers_the_whole_event() {
        let (d, trace) = run(CYCLE);
        let ev = &d.events()[0];
        for (t, _, c) in &trace {
            let inside = *t >= ev.t_start_s && *t < ev.t_release_s - 1e-3;
            if inside {
                assert!(c.brake_pressed, "switch open at {t}");
                assert!(c.pedal_decel_mps2 > 0.0 || *t < ev.t_start_s + 1e-3);
            }
        }
        // Standing between the events: no demand, switch open.
        let stand = trace
            .iter()
            .find(|(t, _, _)| *t > ev.t_release_s + 0.1)
            .unwrap();
        assert!(!stand.2.brake_pressed && stand.1 < 0.01);
    }
}
