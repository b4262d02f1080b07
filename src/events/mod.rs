//! Braking-event detection over the mapped signal stream: the first stage of the clearance
//! observer's input.
//!
//! What it is: a streaming state machine fed one [`Sample`] per mapped update (normally one per
//! CAN frame the signal mapper accepted). It finds brake applications, keeps the steering-wheel
//! angle samples of the current application (plus a pre-roll before the brake onset, so the
//! zero-phase band-pass of MODEL.md §11 starts before the window), and, when the application
//! ends, hands out one [`EventRecord`]: when it happened, the initial speed, a deceleration
//! profile summary, the duration, data quality, and whether the event lies inside the model's
//! validity range (MODEL.md §6, article §2.1.2: braking 0.3–0.8 g from 20–120 km/h, straight
//! ahead). Events outside that range are still recorded, flagged `used = false` with the reason.
//!
//! Memory is bounded and fixed at construction: the steering samples live in a preallocated
//! ring ([`EventConfig::max_samples`]), the steering torque's (where the bus carries one) in a
//! second of the same size, the deceleration samples in another, the speed
//! differentiator in a `heapless` ring. Nothing allocates per sample.
//!
//! What it is not: a feature extractor (that is [`crate::observer::features`]) or a clearance
//! estimator. It knows nothing about CAN or DBCs: [`Sample`] is plain SI values.

use std::collections::VecDeque;

use serde::{Deserialize, Serialize};

const G: f64 = 9.80665;

/// How long before the brake onset the steering wheel must already be held for
/// [`EventConfig::max_steer_change_deg`] (s): the observer's pre-brake cruise window and its
/// guard (`observer::features::CRUISE_WINDOW_S + CRUISE_GUARD_S`, checked by a test there).
pub const STEER_HELD_BEFORE_S: f64 = 1.25;

/// One update of the mapped signals. Fields are `Some` only when that quantity was freshly
/// received with this update (so the detector sees each steering sample once); `brake` is the
/// current braking state when known.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct Sample {
    pub t_ns: i64,
    /// A new steering-wheel angle sample (rad), MODEL.md §8 δ_sw.
    pub steer_rad: Option<f64>,
    /// A new vehicle speed sample (m/s).
    pub speed_mps: Option<f64>,
    /// A new longitudinal acceleration sample (m/s², positive forward, braking negative).
    pub accel_mps2: Option<f64>,
    /// Whether the brake is applied now (from pedal flag or pressure), if known.
    pub brake: Option<bool>,
    /// A steering frame was rejected (checksum, counter, short) or the steering signal timed
    /// out with this update: counted against the event's data quality.
    pub steer_invalid: bool,
    /// A new torsion-bar (driver) steering torque sample (N·m, + turning left), MODEL.md §15's
    /// −T_c, where the bus carries it.
    pub torque_nm: Option<f64>,
}

/// Detection thresholds (`[events]` of config/observer.toml).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct EventConfig {
    /// Brake pressure above which the brake counts as applied (bar), when only pressure is mapped.
    pub brake_on_bar: f64,
    /// Model validity range of the initial speed (km/h).
    pub min_speed_kmh: f64,
    pub max_speed_kmh: f64,
    /// Model validity range of the plateau deceleration (g).
    pub min_decel_g: f64,
    pub max_decel_g: f64,
    /// Largest |steering-wheel angle| during the window for a "nearly straight" event (deg).
    pub max_steer_deg: f64,
    /// Largest change of the steering-wheel angle within any 1 s of the window and of the
    /// pre-brake cruise window before it (deg): the wheel held, not turned. A wheel turned
    /// through the sensor's steps makes its quantisation a noise in the band, and an unwinding
    /// curve a transient (curves of 6–10° unwound while braking doubled the band-passed peak
    /// of tight joints: docs/ACCURACY.md).
    pub max_steer_change_deg: f64,
    /// Brake applications are recorded at all only from this initial speed (km/h) ...
    pub record_min_speed_kmh: f64,
    /// ... and this peak deceleration (g); lighter touches are ignored.
    pub record_min_decel_g: f64,
    /// Shortest brake application recorded (s).
    pub min_duration_s: f64,
    /// Steering samples kept before the brake onset (s): the band-pass filter's run-in and the
    /// observer's pre-brake ("cruise") feature (`observer::features::CRUISE_WINDOW_S`).
    pub pre_roll_s: f64,
    /// MODEL.md §11: the window ends this long after the stop / brake release (s).
    pub tail_s: f64,
    /// Below this speed the vehicle has stopped (m/s), MODEL.md §6 v_stop.
    pub stop_speed_mps: f64,
    /// Capacity of the steering-sample ring (pre-roll + event + tail). Longer events are
    /// closed early and flagged.
    pub max_samples: usize,
    /// Smallest steering sample rate for a usable event (Hz); the 25 Hz band edge needs > 50.
    pub min_sample_hz: f64,
    /// Largest tolerated fraction of missing / invalid steering samples in a used event.
    pub max_missing_fraction: f64,
    /// Span of the speed differentiator when no acceleration signal is mapped (s).
    pub diff_span_s: f64,
}

impl Default for EventConfig {
    fn default() -> Self {
        EventConfig {
            brake_on_bar: 3.0,
            min_speed_kmh: 20.0,
            max_speed_kmh: 120.0,
            min_decel_g: 0.3,
            max_decel_g: 0.8,
            max_steer_deg: 15.0,
            max_steer_change_deg: 3.0,
            record_min_speed_kmh: 10.0,
            record_min_decel_g: 0.15,
            min_duration_s: 0.5,
            pre_roll_s: 2.0,
            tail_s: 0.3,
            stop_speed_mps: 0.5,
            max_samples: 4096,
            min_sample_hz: 60.0,
            max_missing_fraction: 0.05,
            diff_span_s: 0.2,
        }
    }
}

/// Why an event is not used for estimation.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize)]
#[serde(rename_all = "snake_case")]
pub enum Unused {
    SpeedOutOfRange,
    DecelOutOfRange,
    NotStraight,
    TooShort,
    LowSampleRate,
    MissingData,
    /// The event outgrew the sample ring and was closed early.
    Truncated,
    /// The steering angle came through a sensor (sample rate or quantisation step) other than
    /// the one the response table predicts (`shimmy calibrate --sensor-*`): its features are
    /// not comparable with the table's.
    SensorMismatch,
}

/// Why a brake application was not recorded at all (below the recording thresholds
/// `record_min_speed_kmh`, `record_min_decel_g`, half of `min_duration_s`). One application can
/// have several reasons.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize)]
#[serde(rename_all = "snake_case")]
pub enum Ignored {
    /// Initial speed below `record_min_speed_kmh`.
    TooSlow,
    /// Peak deceleration below `record_min_decel_g`.
    TooLight,
    /// Shorter than half of `min_duration_s`.
    TooShort,
}

/// Brake applications ignored before recording, counted per reason (an application with
/// several reasons counts under each), plus how many of them read a forward acceleration of at
/// least `record_min_decel_g` while the brake was applied: the mark of an acceleration signal
/// whose sign is inverted.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize)]
pub struct IgnoredCounts {
    pub too_slow: u64,
    pub too_light: u64,
    pub too_short: u64,
    pub accel_while_braking: u64,
}

/// One brake application ignored before recording: what the detector measured, and why.
#[derive(Clone, Copy, Debug, PartialEq, Serialize)]
pub struct IgnoredApplication {
    /// Brake onset and end (s, log time).
    pub t_start_s: f64,
    pub t_end_s: f64,
    /// Speed at the brake onset (km/h).
    pub v0_kmh: f64,
    /// Largest deceleration during the application (g; 0 when it never decelerated).
    pub peak_decel_g: f64,
    /// Largest forward acceleration during the application (g; 0 when it never sped up).
    pub peak_accel_g: f64,
    pub too_slow: bool,
    pub too_light: bool,
    pub too_short: bool,
}

impl IgnoredApplication {
    /// The reasons, in a fixed order.
    pub fn reasons(&self) -> impl Iterator<Item = Ignored> + '_ {
        [
            (self.too_slow, Ignored::TooSlow),
            (self.too_light, Ignored::TooLight),
            (self.too_short, Ignored::TooShort),
        ]
        .into_iter()
        .filter(|x| x.0)
        .map(|x| x.1)
    }
}

/// Data quality of one event's steering signal.
#[derive(Clone, Copy, Debug, Default, PartialEq, Serialize)]
pub struct Quality {
    /// Steering samples in the window (pre-roll excluded).
    pub steer_samples: u32,
    /// Median steering sample rate (Hz).
    pub sample_hz: f64,
    /// Largest gap between steering samples (s).
    pub max_gap_s: f64,
    /// Steering samples missing according to the median interval.
    pub missing_samples: u32,
    /// Rejected / timed-out steering updates during the event.
    pub invalid_updates: u32,
    /// Smallest non-zero step between consecutive steering samples (deg): the quantisation.
    pub quant_step_deg: f64,
    /// Whether deceleration came from an acceleration signal (else from differentiated speed).
    pub decel_from_accel: bool,
}

/// One recorded brake application.
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct EventRecord {
    /// Brake onset and end (brake release or stop) (s, log time).
    pub t_start_s: f64,
    pub t_end_s: f64,
    /// Speed at the brake onset (km/h).
    pub v0_kmh: f64,
    /// Plateau deceleration: median over the part of the event after the ramp-in (g).
    pub decel_g: f64,
    /// Peak deceleration (g).
    pub peak_decel_g: f64,
    /// Time from onset to 90 % of the plateau (s).
    pub ramp_s: f64,
    /// Whether the vehicle came to a stop.
    pub stopped: bool,
    /// Largest |steering-wheel angle| in the window (deg).
    pub max_abs_steer_deg: f64,
    /// Largest change of the steering-wheel angle within 1 s over the cruise window and the
    /// event's (deg).
    #[serde(default)]
    pub max_steer_change_deg: f64,
    /// Distance driven before the brake onset since the detector started (m).
    pub odometer_m: f64,
    pub quality: Quality,
    /// Whether the event is inside the model's validity range and of good quality.
    pub used: bool,
    pub unused_reason: Option<Unused>,
}

impl EventRecord {
    pub fn duration_s(&self) -> f64 {
        self.t_end_s - self.t_start_s
    }
}

/// A finished event: its record and its steering samples `(t_ns, angle_rad)`, pre-roll first.
/// `window` indexes the samples of `[t_start, t_end + tail]`. `torque` holds the steering
/// torque samples `(t_ns, torque_nm)` over the same span (pre-roll first; empty when the bus
/// carries no torque). `speed` holds the vehicle speed samples `(t_ns, speed_mps)` over the same
/// span (pre-roll first): where the wheels were in their rotation, for a shake locked to it.
pub struct Finished<'a> {
    pub record: EventRecord,
    pub samples: &'a [(i64, f64)],
    pub window: (usize, usize),
    pub torque: &'a [(i64, f64)],
    pub speed: &'a [(i64, f64)],
}

#[derive(Clone, Copy, Debug, PartialEq)]
enum State {
    Idle,
    /// Brake applied; collecting.
    Braking,
    /// Brake released or stopped at `t_end_ns`; collecting the tail.
    Tail {
        t_end_ns: i64,
        stopped: bool,
    },
}

/// The streaming detector. See the module docs.
pub struct Detector {
    cfg: EventConfig,
    state: State,
    steer: VecDeque<(i64, f64)>,
    /// Steering torque samples, kept over the same span as `steer` (its own ring: the torque
    /// comes in its own message at its own rate).
    torque: VecDeque<(i64, f64)>,
    /// Vehicle speed samples over the same span as `steer` (its own ring, as the torque's).
    speed: VecDeque<(i64, f64)>,
    decel: VecDeque<(i64, f64)>,
    scratch: Vec<f64>,
    speed_hist: heapless::Deque<(i64, f64), 64>,
    last_speed: Option<(i64, f64)>,
    last_decel: Option<f64>,
    /// The time `last_decel` stands for: the acceleration sample's, or the middle of the speed
    /// differences' span (a backward difference would lag by half the span and, as samples are
    /// taken from the onset to the end only, bias the plateau low).
    last_decel_t_ns: i64,
    odometer_m: f64,
    // current event
    t_start_ns: i64,
    v0_mps: f64,
    odo_start: f64,
    invalid: u32,
    from_accel: bool,
    truncated: bool,
    /// Brake state of the previous update: events start on a rising edge only.
    prev_brake: bool,
    // finished event storage
    finished: Option<EventRecord>,
    finished_window: (usize, usize),
    /// Brake applications ignored (below the recording thresholds).
    pub ignored: u64,
    /// The same, per reason.
    pub ignored_by_reason: IgnoredCounts,
    /// The most recent ignored application.
    last_ignored: Option<IgnoredApplication>,
}

/// Appends `x` to a ring of fixed capacity: when full, the oldest sample makes room while no
/// event is being collected (`idle`); during an event the sample is dropped.
fn push_ring(ring: &mut VecDeque<(i64, f64)>, idle: bool, x: (i64, f64)) {
    if ring.len() == ring.capacity() && idle {
        ring.pop_front();
    }
    if ring.len() < ring.capacity() {
        ring.push_back(x);
    }
}

fn secs(t_ns: i64) -> f64 {
    t_ns as f64 * 1e-9
}

impl Detector {
    /// Distance driven since the first sample (m): the speed integrated (trapezoid).
    pub fn odometer_m(&self) -> f64 {
        self.odometer_m
    }

    /// Allocates every buffer once, here.
    pub fn new(cfg: EventConfig) -> Detector {
        let cap = cfg.max_samples.max(16);
        Detector {
            state: State::Idle,
            steer: VecDeque::with_capacity(cap),
            torque: VecDeque::with_capacity(cap),
            speed: VecDeque::with_capacity(cap),
            decel: VecDeque::with_capacity(cap),
            scratch: Vec::with_capacity(cap),
            speed_hist: heapless::Deque::new(),
            last_speed: None,
            last_decel: None,
            last_decel_t_ns: 0,
            odometer_m: 0.0,
            t_start_ns: 0,
            v0_mps: 0.0,
            odo_start: 0.0,
            invalid: 0,
            from_accel: false,
            truncated: false,
            prev_brake: true,
            finished: None,
            finished_window: (0, 0),
            ignored: 0,
            ignored_by_reason: IgnoredCounts::default(),
            last_ignored: None,
            cfg,
        }
    }

    pub fn config(&self) -> &EventConfig {
        &self.cfg
    }

    /// Whether the deceleration has come from an acceleration signal (else from the speed's
    /// derivative).
    pub fn decel_from_accel(&self) -> bool {
        self.from_accel
    }

    /// The most recently ignored brake application (see [`Detector::ignored`]).
    pub fn last_ignored(&self) -> Option<&IgnoredApplication> {
        self.last_ignored.as_ref()
    }

    /// Whether a brake application is being collected.
    pub fn in_event(&self) -> bool {
        self.state != State::Idle
    }

    /// Feed one update. Returns a finished event when this update closed one; the samples it
    /// borrows stay valid until the next call.
    pub fn push(&mut self, s: &Sample) -> Option<Finished<'_>> {
        if self.finished.take().is_some() {
            // The previous event's samples were lent out; drop them now.
            self.clear_rings();
        }
        self.update_kinematics(s);
        if let Some(a) = s.steer_rad {
            if self.steer.len() == self.steer.capacity() {
                match self.state {
                    State::Idle => {
                        self.steer.pop_front();
                    }
                    _ => self.truncated = true,
                }
            }
            if self.steer.len() < self.steer.capacity() {
                self.steer.push_back((s.t_ns, a));
            }
        }
        // The torque's and the speed's rings are as long as the angle's; both are sent no
        // faster than the angle on the buses mapped, so a full ring mid-event is the angle's
        // truncation too.
        let idle = self.state == State::Idle;
        if let Some(m) = s.torque_nm {
            push_ring(&mut self.torque, idle, (s.t_ns, m));
        }
        if let Some(v) = s.speed_mps {
            push_ring(&mut self.speed, idle, (s.t_ns, v));
        }
        if s.steer_invalid && self.state != State::Idle {
            self.invalid += 1;
        }
        let braking = s.brake.unwrap_or(false);
        let rising = braking && !self.prev_brake;
        if s.brake.is_some() {
            self.prev_brake = braking;
        }
        match self.state {
            State::Idle => {
                self.trim_pre_roll(s.t_ns);
                if rising {
                    self.start(s.t_ns);
                }
            }
            State::Braking => {
                self.collect_decel(s, s.t_ns);
                let stopped = self
                    .last_speed
                    .is_some_and(|(_, v)| v < self.cfg.stop_speed_mps);
                if !braking || stopped || self.truncated {
                    self.state = State::Tail {
                        t_end_ns: s.t_ns,
                        stopped,
                    };
                }
            }
            State::Tail { t_end_ns, stopped } => {
                self.collect_decel(s, t_end_ns);
                let tail_ns = (self.cfg.tail_s * 1e9) as i64;
                if s.t_ns >= t_end_ns + tail_ns || self.truncated {
                    return self.finish(t_end_ns, stopped);
                }
            }
        }
        None
    }

    /// Close an event still open at the end of the input (its tail may be short).
    pub fn flush(&mut self) -> Option<Finished<'_>> {
        if self.finished.take().is_some() {
            self.clear_rings();
        }
        match self.state {
            State::Idle => None,
            State::Braking => {
                let t_end = self.steer.back().map_or(self.t_start_ns, |x| x.0);
                let stopped = self
                    .last_speed
                    .is_some_and(|(_, v)| v < self.cfg.stop_speed_mps);
                self.finish(t_end, stopped)
            }
            State::Tail { t_end_ns, stopped } => self.finish(t_end_ns, stopped),
        }
    }

    fn update_kinematics(&mut self, s: &Sample) {
        if let Some(v) = s.speed_mps {
            if let Some((t0, v0)) = self.last_speed {
                let dt = secs(s.t_ns - t0);
                if dt > 0.0 && dt < 1.0 {
                    self.odometer_m += 0.5 * (v + v0) * dt;
                }
            }
            self.last_speed = Some((s.t_ns, v));
            if self.speed_hist.is_full() {
                self.speed_hist.pop_front();
            }
            let _ = self.speed_hist.push_back((s.t_ns, v));
            // Drop samples older than the differentiation span (keep one older as anchor).
            let span_ns = (self.cfg.diff_span_s * 1e9) as i64;
            while self.speed_hist.len() > 2
                && self
                    .speed_hist
                    .iter()
                    .nth(1)
                    .is_some_and(|&(t, _)| s.t_ns - t >= span_ns)
            {
                self.speed_hist.pop_front();
            }
            if !self.from_accel_now() {
                if let (Some(&(ta, va)), Some(&(tb, vb))) =
                    (self.speed_hist.front(), self.speed_hist.back())
                {
                    let dt = secs(tb - ta);
                    if dt >= 0.5 * self.cfg.diff_span_s {
                        self.last_decel = Some((va - vb) / dt);
                        self.last_decel_t_ns = ta + (tb - ta) / 2;
                    }
                }
            }
        }
        if let Some(a) = s.accel_mps2 {
            self.from_accel = true;
            self.last_decel = Some(-a);
            self.last_decel_t_ns = s.t_ns;
        }
    }

    /// Keeps the deceleration this update brought when the time it stands for lies between the
    /// onset and `until_ns` (the end of the application).
    fn collect_decel(&mut self, s: &Sample, until_ns: i64) {
        if s.speed_mps.is_none() && s.accel_mps2.is_none() {
            return;
        }
        let t = self.last_decel_t_ns;
        if let Some(d) = self.last_decel {
            let fresh = self.decel.back().is_none_or(|&(tp, _)| t > tp);
            if fresh
                && (self.t_start_ns..=until_ns).contains(&t)
                && self.decel.len() < self.decel.capacity()
            {
                self.decel.push_back((t, d));
            }
        }
    }

    fn from_accel_now(&self) -> bool {
        self.from_accel
    }

    fn trim_pre_roll(&mut self, now_ns: i64) {
        let keep_ns = (self.cfg.pre_roll_s * 1e9) as i64;
        for ring in [&mut self.steer, &mut self.torque, &mut self.speed] {
            while ring.front().is_some_and(|&(t, _)| now_ns - t > keep_ns) {
                ring.pop_front();
            }
        }
    }

    /// Drops the samples of the sample rings (an event lent out, or one not recorded).
    fn clear_rings(&mut self) {
        self.steer.clear();
        self.torque.clear();
        self.speed.clear();
        self.decel.clear();
    }

    fn start(&mut self, t_ns: i64) {
        self.state = State::Braking;
        self.t_start_ns = t_ns;
        self.v0_mps = self.last_speed.map_or(0.0, |x| x.1);
        self.odo_start = self.odometer_m;
        self.invalid = 0;
        self.truncated = false;
        self.decel.clear();
    }

    fn finish(&mut self, t_end_ns: i64, stopped: bool) -> Option<Finished<'_>> {
        self.state = State::Idle;
        let cfg = &self.cfg;
        let t_start_ns = self.t_start_ns;
        let duration_s = secs(t_end_ns - t_start_ns);
        let v0_kmh = self.v0_mps * 3.6;

        // Deceleration profile.
        let peak = self.decel.iter().map(|x| x.1).fold(0.0f64, f64::max);
        if v0_kmh < cfg.record_min_speed_kmh
            || peak < cfg.record_min_decel_g * G
            || duration_s < 0.5 * cfg.min_duration_s
        {
            let trough = self.decel.iter().map(|x| x.1).fold(0.0f64, f64::min);
            let app = IgnoredApplication {
                t_start_s: secs(t_start_ns),
                t_end_s: secs(t_end_ns),
                v0_kmh,
                peak_decel_g: peak / G,
                peak_accel_g: -trough / G,
                too_slow: v0_kmh < cfg.record_min_speed_kmh,
                too_light: peak < cfg.record_min_decel_g * G,
                too_short: duration_s < 0.5 * cfg.min_duration_s,
            };
            let c = &mut self.ignored_by_reason;
            c.too_slow += app.too_slow as u64;
            c.too_light += app.too_light as u64;
            c.too_short += app.too_short as u64;
            c.accel_while_braking += (-trough >= cfg.record_min_decel_g * G) as u64;
            self.last_ignored = Some(app);
            self.ignored += 1;
            self.clear_rings();
            return None;
        }
        // Plateau: samples at or above half the peak, median.
        self.scratch.clear();
        self.scratch
            .extend(self.decel.iter().map(|x| x.1).filter(|&d| d >= 0.5 * peak));
        let plateau = median_in_place(&mut self.scratch).unwrap_or(peak);
        let ramp_s = self
            .decel
            .iter()
            .find(|x| x.1 >= 0.9 * plateau)
            .map_or(0.0, |x| secs(x.0 - t_start_ns));

        // Window and steering quality.
        let tail_end = t_end_ns + (cfg.tail_s * 1e9) as i64;
        let steer = self.steer.make_contiguous();
        let i0 = steer.partition_point(|x| x.0 < t_start_ns);
        let i1 = steer.partition_point(|x| x.0 <= tail_end);
        let win = &steer[i0..i1];
        // The largest change within 1 s, from the cruise window before the onset on.
        let c0 = steer.partition_point(|x| x.0 < t_start_ns - (STEER_HELD_BEFORE_S * 1e9) as i64);
        let max_change_deg = max_change_within(&steer[c0..i1], 1_000_000_000).to_degrees();
        let mut max_abs = 0.0f64;
        let mut qstep = f64::INFINITY;
        let mut max_gap = 0.0f64;
        for (k, &(t, a)) in win.iter().enumerate() {
            max_abs = max_abs.max(a.abs());
            if k > 0 {
                let (tp, ap) = win[k - 1];
                let d = (a - ap).abs();
                if d > 1e-9 {
                    qstep = qstep.min(d);
                }
                max_gap = max_gap.max(secs(t - tp));
            }
        }
        // The steering signal's period, robust to timestamp jitter; gaps longer than any
        // jitter count as missing samples (crate::analysis::sampling).
        let fit = crate::analysis::sampling::fit(win.iter().map(|x| x.0));
        let period_s = fit.map_or(0.0, |f| f.period_ns * 1e-9);
        let sample_hz = if period_s > 0.0 { 1.0 / period_s } else { 0.0 };
        let span_s = secs(tail_end - t_start_ns);
        let expected = if period_s > 0.0 {
            (span_s / period_s).round() as i64
        } else {
            0
        };
        let missing = (expected - win.len() as i64).max(0) as u32;
        let quality = Quality {
            steer_samples: win.len() as u32,
            sample_hz,
            max_gap_s: max_gap,
            missing_samples: missing,
            invalid_updates: self.invalid,
            quant_step_deg: if qstep.is_finite() {
                qstep.to_degrees()
            } else {
                0.0
            },
            decel_from_accel: self.from_accel,
        };
        let decel_g = plateau / G;
        let max_steer_deg = max_abs.to_degrees();
        let bad_fraction = if expected > 0 {
            (missing + self.invalid) as f64 / expected as f64
        } else {
            1.0
        };
        let unused_reason = if self.truncated {
            Some(Unused::Truncated)
        } else if !(cfg.min_speed_kmh..=cfg.max_speed_kmh).contains(&v0_kmh) {
            Some(Unused::SpeedOutOfRange)
        } else if !(cfg.min_decel_g..=cfg.max_decel_g).contains(&decel_g) {
            Some(Unused::DecelOutOfRange)
        } else if duration_s < cfg.min_duration_s {
            Some(Unused::TooShort)
        } else if max_steer_deg > cfg.max_steer_deg || max_change_deg > cfg.max_steer_change_deg {
            Some(Unused::NotStraight)
        } else if sample_hz < cfg.min_sample_hz {
            Some(Unused::LowSampleRate)
        } else if bad_fraction > cfg.max_missing_fraction {
            Some(Unused::MissingData)
        } else {
            None
        };
        let record = EventRecord {
            t_start_s: secs(t_start_ns),
            t_end_s: secs(t_end_ns),
            v0_kmh,
            decel_g,
            peak_decel_g: peak / G,
            ramp_s,
            stopped,
            max_abs_steer_deg: max_steer_deg,
            max_steer_change_deg: max_change_deg,
            odometer_m: self.odo_start,
            quality,
            used: unused_reason.is_none(),
            unused_reason,
        };
        self.finished = Some(record.clone());
        self.finished_window = (i0, i1);
        self.truncated = false;
        self.torque.make_contiguous();
        self.speed.make_contiguous();
        Some(Finished {
            record,
            samples: self.steer.as_slices().0,
            window: (i0, i1),
            torque: self.torque.as_slices().0,
            speed: self.speed.as_slices().0,
        })
    }
}

/// The largest |x(t₂) − x(t₁)| over samples (`(t_ns, x)`, increasing time) at most `span_ns`
/// apart: how far the signal moves within that span. 0 for fewer than two samples.
pub fn max_change_within(x: &[(i64, f64)], span_ns: i64) -> f64 {
    // For each sample, the extremes of the samples in the span before it (a monotone deque
    // would be O(n); the windows here hold at most a few hundred samples, so a scan back
    // from the newest is as fast and needs no buffer).
    let mut best = 0.0f64;
    let mut j = 0;
    for k in 0..x.len() {
        while x[k].0 - x[j].0 > span_ns {
            j += 1;
        }
        for p in &x[j..k] {
            best = best.max((x[k].1 - p.1).abs());
        }
    }
    best
}

/// Median of `x` (reorders it). None when empty.
pub fn median_in_place(x: &mut [f64]) -> Option<f64> {
    if x.is_empty() {
        return None;
    }
    let n = x.len();
    let (_, m, _) = x.select_nth_unstable_by(n / 2, |a, b| a.total_cmp(b));
    let hi = *m;
    if n % 2 == 1 {
        Some(hi)
    } else {
        let lo = x[..n / 2].iter().copied().fold(f64::NEG_INFINITY, f64::max);
        Some(0.5 * (lo + hi))
    }
}
