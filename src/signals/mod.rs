//! Vehicle signals: turns decoded CAN frames into the few quantities the monitor needs — the
//! steering-wheel angle δ_sw (MODEL.md §8), the braking state (§6: brake pressure and/or pedal
//! flag), the vehicle speed v and, optionally, the longitudinal acceleration, and for `shimmy
//! doctor`'s consistency checks the yaw rate and the lateral acceleration — in SI units, each
//! with its validity.
//!
//! * [`mapping`]: the per-vehicle TOML file naming DBC messages/signals, compositions, units and
//!   per-message protection.
//! * [`checksum`]: the checksum functions (Toyota, VW MQB, Honda, Hyundai / Kia, our reference
//!   bus).
//! * [`Mapper`]: resolves a mapping against a [`Database`] once (every missing message or signal
//!   is a clear error at start-up), then interprets frames without allocating.
//!
//! Validity policy, per message the mapping reads:
//! * a frame whose checksum does not verify is counted and its values are not used;
//! * a rolling counter that repeats (a frozen sender) is counted as a counter error and the
//!   frame's values are not used; a counter that jumps forward is a gap (lost frames), counted,
//!   and the frame is used (its data are fresh and, where there is one, its checksum holds);
//! * a frame too short for a mapped signal is counted and not used;
//! * once no good frame has arrived for longer than the message's timeout, every quantity read
//!   from it is invalid ([`Validity::TimedOut`]) and one timeout is counted;
//! * time follows the frames: a step back (a log restarting) is not an outage, and counter
//!   tracking starts afresh after it.
//!
//! Not here: decoding bits (that is [`crate::dbc`]), reading frames ([`crate::source`]) or
//! deciding what a braking event is (the daemon's business).

pub mod checksum;
pub mod mapping;

use anyhow::bail;
use serde::Serialize;

use crate::dbc::{Database, Message, Signal};
use crate::wire::{Frame, FrameKind};

use checksum::{ChecksumError, ChecksumKind};
use mapping::{
    AccelUnit, AngleUnit, MappingConfig, PressureUnit, RateUnit, SpeedUnit, TorqueUnit,
    STANDARD_GRAVITY_MPS2,
};

/// Whether a quantity can be used now.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize)]
#[serde(rename_all = "snake_case")]
pub enum Validity {
    /// A good frame arrived within the message's timeout.
    Valid,
    /// The mapping does not provide this quantity.
    NotMapped,
    /// No good frame has arrived yet.
    NoData,
    /// The last good frame is older than the message's timeout.
    TimedOut,
}

/// One quantity at one instant: the last good value (if any), when it arrived, and whether it is
/// valid now.
#[derive(Clone, Copy, Debug, PartialEq, Serialize)]
pub struct Reading<T> {
    pub value: Option<T>,
    /// Receive time of the frame the value came from.
    pub t_ns: Option<i64>,
    pub validity: Validity,
}

impl<T: Copy> Reading<T> {
    /// The value, only when it is valid.
    pub fn valid(&self) -> Option<T> {
        match self.validity {
            Validity::Valid => self.value,
            _ => None,
        }
    }

    fn not_mapped() -> Reading<T> {
        Reading {
            value: None,
            t_ns: None,
            validity: Validity::NotMapped,
        }
    }
}

/// The monitor's view of the vehicle at one instant, SI units.
#[derive(Clone, Copy, Debug, PartialEq, Serialize)]
pub struct VehicleSignals {
    /// The instant this snapshot describes.
    pub t_ns: i64,
    /// Steering-wheel angle, positive counter-clockwise (rad).
    pub steer_angle_rad: Reading<f64>,
    /// Vehicle speed (m/s).
    pub speed_mps: Reading<f64>,
    /// Brake pressure (Pa).
    pub brake_pressure_pa: Reading<f64>,
    /// Brake pedal pressed.
    pub brake_pressed: Reading<bool>,
    /// Longitudinal acceleration, positive forward (m/s²).
    pub accel_mps2: Reading<f64>,
    /// Yaw rate, positive counter-clockwise seen from above (rad/s).
    pub yaw_rate_radps: Reading<f64>,
    /// Lateral acceleration, positive to the left (m/s²).
    pub lat_accel_mps2: Reading<f64>,
    /// The driver's steering torque at the torsion bar, positive turning left (N·m).
    pub steer_torque_nm: Reading<f64>,
}

/// Which quantities a frame updated.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct Changed {
    pub steer_angle: bool,
    pub speed: bool,
    pub brake_pressure: bool,
    pub brake_pressed: bool,
    pub accel: bool,
    pub yaw_rate: bool,
    pub lat_accel: bool,
    pub steer_torque: bool,
}

/// Why a frame of a mapped message was not used.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Reject {
    Checksum(ChecksumError),
    /// The rolling counter did not advance (same value as the previous good frame).
    CounterRepeat {
        counter: u64,
    },
    /// The payload is too short for a mapped signal (or its counter).
    Short {
        len: u8,
    },
}

impl std::fmt::Display for Reject {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self {
            Reject::Checksum(e) => write!(f, "{e}"),
            Reject::CounterRepeat { counter } => write!(f, "counter {counter} repeated"),
            Reject::Short { len } => write!(f, "payload of {len} bytes too short"),
        }
    }
}

/// What [`Mapper::on_frame`] did with a frame of a mapped message.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Outcome {
    Accepted(Changed),
    Rejected(Reject),
}

/// Result of one mapped frame: which message (index into [`Mapper::stats`]'s list) and what
/// happened.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Update {
    pub message: usize,
    pub outcome: Outcome,
}

/// Counters for one mapped message.
#[derive(Clone, Debug, Default, PartialEq, Eq, Serialize)]
pub struct MessageStats {
    pub name: String,
    pub id: u32,
    pub extended: bool,
    pub timeout_ms: u32,
    /// Frames received with this ID.
    pub frames: u64,
    /// Frames whose values were used.
    pub accepted: u64,
    pub checksum_errors: u64,
    /// Repeated counters (frames not used).
    pub counter_errors: u64,
    /// Forward jumps of the counter (frames used).
    pub counter_gaps: u64,
    /// Frames missing according to the counter (sum of jump sizes minus one).
    pub frames_lost: u64,
    /// Frames too short for a mapped signal.
    pub short_frames: u64,
    /// Times the message went silent for longer than its timeout.
    pub timeouts: u64,
}

impl MessageStats {
    /// Frames of this message that were not used.
    pub fn rejected(&self) -> u64 {
        self.checksum_errors + self.counter_errors + self.short_frames
    }
}

/// A DBC signal resolved for per-frame use.
#[derive(Clone, Debug)]
struct Sig {
    signal: Signal,
}

impl Sig {
    #[inline]
    fn phys(&self, data: &[u8]) -> Option<f64> {
        self.signal.phys(data)
    }
}

/// Per-message state.
#[derive(Clone, Debug)]
struct Slot {
    id: u32,
    extended: bool,
    timeout_ns: i64,
    checksum: Option<ChecksumKind>,
    counter: Option<Sig>,
    counter_modulus: u64,
    last_counter: Option<u64>,
    last_good_ns: Option<i64>,
    timed_out: bool,
    stats: MessageStats,
}

#[derive(Clone, Copy, Debug, Default)]
struct Sample<T> {
    value: T,
    t_ns: i64,
}

#[derive(Clone, Debug)]
struct SteerQ {
    slot: usize,
    angle: Sig,
    fraction: Option<Sig>,
    sign: Option<Sig>,
    invert: bool,
    scale: f64,
    unit: AngleUnit,
}

/// A resolved [`mapping::SignedMap`].
#[derive(Clone, Debug)]
struct SignedQ<U> {
    slot: usize,
    sig: Sig,
    sign: Option<Sig>,
    invert: bool,
    scale: f64,
    unit: U,
}

impl<U> SignedQ<U> {
    /// The value in the map's unit: the signal, negated by the sign bit and by `invert`,
    /// times `scale`.
    fn value(&self, data: &[u8]) -> Option<f64> {
        let mut v = self.sig.phys(data)?;
        if let Some(sg) = &self.sign {
            if sg.phys(data)? != 0.0 {
                v = -v;
            }
        }
        if self.invert {
            v = -v;
        }
        Some(self.scale * v)
    }
}

type YawQ = SignedQ<RateUnit>;
type TorqueQ = SignedQ<TorqueUnit>;

#[derive(Clone, Debug)]
enum SpeedSrc {
    Signal(Sig),
    /// Mean of up to four wheel speeds (filled once, at construction).
    Wheels(Vec<Sig>),
}

#[derive(Clone, Debug)]
struct SpeedQ {
    slot: usize,
    src: SpeedSrc,
    unit: SpeedUnit,
}

#[derive(Clone, Debug)]
struct PressureQ {
    slot: usize,
    sig: Sig,
    unit: PressureUnit,
}

#[derive(Clone, Debug)]
struct FlagQ {
    slot: usize,
    sig: Sig,
    invert: bool,
}

#[derive(Clone, Debug)]
struct AccelQ {
    slot: usize,
    sig: Sig,
    unit: AccelUnit,
    invert: bool,
    scale: f64,
}

/// The hardest braking a mapped acceleration must read without clipping (m/s²): 0.8 g, the top
/// of the deceleration range the model covers (MODEL.md §6). A narrower signal (Honda's 9-bit
/// `KINEMATICS.LONG_ACCEL` holds ±5.1 m/s²) would flatten every harder plateau to its limit.
const BRAKING_DECEL_MPS2: f64 = 0.8 * STANDARD_GRAVITY_MPS2;

impl AccelQ {
    /// A physical value of the signal as the monitor's acceleration (m/s², forward positive).
    fn si(&self, phys: f64) -> f64 {
        let v = self.unit.to_si(self.scale * phys);
        if self.invert {
            -v
        } else {
            v
        }
    }

    /// The lowest and highest acceleration (m/s², forward positive) the signal's bits can
    /// carry ([`Signal::phys_range`] through [`Self::si`]); unbounded for floats.
    fn range_mps2(&self) -> (f64, f64) {
        let (lo, hi) = self.sig.signal.phys_range();
        let (a, b) = (self.si(lo), self.si(hi));
        (a.min(b), a.max(b))
    }

    fn value(&self, data: &[u8]) -> Option<f64> {
        Some(self.si(self.sig.phys(data)?))
    }
}

/// Values decoded from one frame before they are committed (all or nothing).
#[derive(Default)]
struct Pending {
    steer: Option<f64>,
    speed: Option<f64>,
    pressure: Option<f64>,
    pressed: Option<bool>,
    accel: Option<f64>,
    yaw: Option<f64>,
    torque: Option<f64>,
    lat: Option<f64>,
}

/// Interprets frames according to a [`MappingConfig`] resolved against a [`Database`].
#[derive(Clone, Debug)]
pub struct Mapper {
    slots: Vec<Slot>,
    needed: Vec<(u32, bool)>,
    steer: SteerQ,
    speed: SpeedQ,
    pressure: Option<PressureQ>,
    pressed: Option<FlagQ>,
    accel: Option<AccelQ>,
    yaw: Option<YawQ>,
    torque: Option<TorqueQ>,
    lat: Option<AccelQ>,
    v_steer: Option<Sample<f64>>,
    v_speed: Option<Sample<f64>>,
    v_pressure: Option<Sample<f64>>,
    v_pressed: Option<Sample<bool>>,
    v_accel: Option<Sample<f64>>,
    v_yaw: Option<Sample<f64>>,
    v_torque: Option<Sample<f64>>,
    v_lat: Option<Sample<f64>>,
    warnings: Vec<String>,
    /// Latest frame time seen (drives timeouts).
    now_ns: Option<i64>,
    /// No slot can time out before this (ns): a lower bound on `last_good_ns + timeout_ns` over
    /// the slots not timed out, so most frames skip the per-slot timeout pass.
    deadline_ns: i64,
    /// Slot index + 1 of each standard (11-bit) ID, 0 for an ID no slot reads: the lookup of
    /// every frame on the bus, most of which the mapping does not read.
    std_slot: Vec<u8>,
    ignored_frames: u64,
}

/// Resolution context: the database, and the slot list being built.
struct Resolver<'a> {
    db: &'a Database,
    cfg: &'a MappingConfig,
    slots: Vec<Slot>,
    names: Vec<String>,
    warnings: Vec<String>,
}

impl<'a> Resolver<'a> {
    fn message(&self, key: &str, name: &str) -> anyhow::Result<&'a Message> {
        match self.db.message_by_name(name) {
            Some(i) => Ok(&self.db.messages()[i]),
            None => bail!("{key}: message `{name}` is not in the DBC"),
        }
    }

    fn signal(&self, key: &str, msg: &Message, name: &str) -> anyhow::Result<Sig> {
        let Some(i) = msg.signal_by_name(name) else {
            let names: Vec<&str> = msg.signals.iter().map(|s| s.name.as_str()).collect();
            bail!(
                "{key}: signal `{name}` is not in message `{}` (it has: {})",
                msg.name,
                names.join(", ")
            );
        };
        let s = &msg.signals[i];
        if s.multiplexer.is_some() {
            bail!(
                "{key}: signal `{name}` of `{}` is multiplexed; mapping multiplexed signals is not supported",
                msg.name
            );
        }
        Ok(Sig { signal: s.clone() })
    }

    /// The slot for message `name`, creating it (with its protection rules) on first use.
    fn slot(&mut self, key: &str, name: &str) -> anyhow::Result<(usize, &'a Message)> {
        let msg = self.message(key, name)?;
        if let Some(i) = self.names.iter().position(|n| n == name) {
            return Ok((i, msg));
        }
        let rules = self.cfg.rules(name);
        let timeout_ms = self.cfg.timeout_ms(name);
        let mkey = format!("messages.{name}");
        if let Some(kind) = rules.checksum {
            if !kind.supports(msg.id) {
                bail!(
                    "{mkey}.checksum: {kind:?} is not known for `{name}` (0x{:X}): no data-ID bytes or layout",
                    msg.id
                );
            }
            if msg.size_bytes < 2 {
                bail!(
                    "{mkey}.checksum: `{name}` is {} byte(s) long, too short for a checksum",
                    msg.size_bytes
                );
            }
        }
        let counter = match &rules.counter_signal {
            Some(c) => Some(self.signal(&format!("{mkey}.counter_signal"), msg, c)?),
            None => None,
        };
        let counter_modulus = match &counter {
            Some(c) if c.signal.size >= 64 => u64::MAX,
            Some(c) => 1u64 << c.signal.size,
            None => 0,
        };
        self.slots.push(Slot {
            id: msg.id,
            extended: msg.extended,
            timeout_ns: timeout_ms as i64 * 1_000_000,
            checksum: rules.checksum,
            counter,
            counter_modulus,
            last_counter: None,
            last_good_ns: None,
            timed_out: false,
            stats: MessageStats {
                name: name.to_string(),
                id: msg.id,
                extended: msg.extended,
                timeout_ms,
                ..MessageStats::default()
            },
        });
        self.names.push(name.to_string());
        Ok((self.slots.len() - 1, msg))
    }

    /// Note when the DBC's unit for a signal contradicts the mapping's.
    /// Resolves a [`mapping::SignedMap`] under the mapping key `key`.
    fn signed<U: Copy>(
        &mut self,
        key: &str,
        m: &mapping::SignedMap<U>,
    ) -> anyhow::Result<SignedQ<U>> {
        let (slot, msg) = self.slot(&format!("{key}.message"), &m.message)?;
        let sig = self.signal(&format!("{key}.signal"), msg, &m.signal)?;
        let sign = match &m.sign_signal {
            Some(s) => Some(self.signal(&format!("{key}.sign_signal"), msg, s)?),
            None => None,
        };
        Ok(SignedQ {
            slot,
            sig,
            sign,
            invert: m.invert,
            scale: m.scale,
            unit: m.unit,
        })
    }

    fn check_unit(&mut self, key: &str, sig: &Sig, declared: &str, accepted: &[&str]) {
        let u = sig.signal.unit.trim();
        let known = [
            "deg", "rad", "km/h", "kph", "kmh", "m/s", "mph", "bar", "pa", "kpa", "m/s^2", "m/s2",
            "g", "deg/s", "rad/s",
        ];
        let ul = u.to_ascii_lowercase();
        if known.contains(&ul.as_str()) && !accepted.iter().any(|a| a.eq_ignore_ascii_case(u)) {
            self.warnings.push(format!(
                "{key}: mapping says `{declared}` but the DBC gives `{}` the unit `{u}`",
                sig.signal.name
            ));
        }
    }
}

fn angle_units(u: AngleUnit) -> (&'static str, &'static [&'static str]) {
    match u {
        AngleUnit::Deg => ("deg", &["deg"]),
        AngleUnit::Rad => ("rad", &["rad"]),
    }
}

fn speed_units(u: SpeedUnit) -> (&'static str, &'static [&'static str]) {
    match u {
        SpeedUnit::Kmh => ("km/h", &["km/h", "kph", "kmh"]),
        SpeedUnit::Mps => ("m/s", &["m/s"]),
        SpeedUnit::Mph => ("mph", &["mph"]),
    }
}

fn pressure_units(u: PressureUnit) -> (&'static str, &'static [&'static str]) {
    match u {
        PressureUnit::Bar => ("bar", &["bar"]),
        PressureUnit::Pa => ("Pa", &["pa"]),
        PressureUnit::KPa => ("kPa", &["kpa"]),
    }
}

fn rate_units(u: RateUnit) -> (&'static str, &'static [&'static str]) {
    match u {
        RateUnit::DegPerS => ("deg/s", &["deg/s"]),
        RateUnit::RadPerS => ("rad/s", &["rad/s"]),
    }
}

fn accel_units(u: AccelUnit) -> (&'static str, &'static [&'static str]) {
    match u {
        AccelUnit::Mps2 => ("m/s^2", &["m/s^2", "m/s2"]),
        AccelUnit::G => ("g", &["g"]),
    }
}

impl Mapper {
    /// Resolve `cfg` against `db`. Fails with the mapping key and the missing message or signal
    /// named, or when a checksum cannot protect the message it is asked to.
    pub fn new(db: &Database, cfg: &MappingConfig) -> anyhow::Result<Mapper> {
        cfg.validate()?;
        let mut r = Resolver {
            db,
            cfg,
            slots: Vec::new(),
            names: Vec::new(),
            warnings: Vec::new(),
        };

        let s = &cfg.steer_angle;
        let (slot, msg) = r.slot("steer_angle.message", &s.message)?;
        let angle = r.signal("steer_angle.signal", msg, &s.signal)?;
        let (name, ok) = angle_units(s.unit);
        r.check_unit("steer_angle.unit", &angle, name, ok);
        let fraction = match &s.fraction_signal {
            Some(f) => Some(r.signal("steer_angle.fraction_signal", msg, f)?),
            None => None,
        };
        let sign = match &s.sign_signal {
            Some(f) => Some(r.signal("steer_angle.sign_signal", msg, f)?),
            None => None,
        };
        let steer = SteerQ {
            slot,
            angle,
            fraction,
            sign,
            invert: s.invert,
            scale: s.scale,
            unit: s.unit,
        };

        let sp = &cfg.speed;
        let (slot, msg) = r.slot("speed.message", &sp.message)?;
        let (uname, ok) = speed_units(sp.unit);
        let src = match &sp.signal {
            Some(name) => {
                let sig = r.signal("speed.signal", msg, name)?;
                r.check_unit("speed.unit", &sig, uname, ok);
                SpeedSrc::Signal(sig)
            }
            None => {
                let mut v = Vec::with_capacity(sp.wheel_signals.len());
                for w in &sp.wheel_signals {
                    let sig = r.signal("speed.wheel_signals", msg, w)?;
                    r.check_unit("speed.unit", &sig, uname, ok);
                    v.push(sig);
                }
                SpeedSrc::Wheels(v)
            }
        };
        let speed = SpeedQ {
            slot,
            src,
            unit: sp.unit,
        };

        let pressure = match &cfg.brake_pressure {
            Some(p) => {
                let (slot, msg) = r.slot("brake_pressure.message", &p.message)?;
                let sig = r.signal("brake_pressure.signal", msg, &p.signal)?;
                let (name, ok) = pressure_units(p.unit);
                r.check_unit("brake_pressure.unit", &sig, name, ok);
                Some(PressureQ {
                    slot,
                    sig,
                    unit: p.unit,
                })
            }
            None => None,
        };
        let pressed = match &cfg.brake_pressed {
            Some(p) => {
                let (slot, msg) = r.slot("brake_pressed.message", &p.message)?;
                let sig = r.signal("brake_pressed.signal", msg, &p.signal)?;
                Some(FlagQ {
                    slot,
                    sig,
                    invert: p.invert,
                })
            }
            None => None,
        };
        let mut accel_q = |key: &str, a: &Option<mapping::AccelMap>| -> anyhow::Result<_> {
            let Some(a) = a else {
                return Ok(None);
            };
            let (slot, msg) = r.slot(&format!("{key}.message"), &a.message)?;
            let sig = r.signal(&format!("{key}.signal"), msg, &a.signal)?;
            let (name, ok) = accel_units(a.unit);
            r.check_unit(&format!("{key}.unit"), &sig, name, ok);
            Ok(Some(AccelQ {
                slot,
                sig,
                unit: a.unit,
                invert: a.invert,
                scale: a.scale,
            }))
        };
        let mut accel = accel_q("accel", &cfg.accel)?;
        let lat = accel_q("lat_accel", &cfg.lat_accel)?;
        if let (Some(q), Some(a)) = (&accel, &cfg.accel) {
            let (min_mps2, _) = q.range_mps2();
            if -min_mps2 < BRAKING_DECEL_MPS2 {
                r.warnings.push(format!(
                    "accel: {}.{} reads at most {:.2} m/s² ({:.2} g) of deceleration, less than the \
                     {:.2} g of the hardest braking the model covers, so braking would clip; the \
                     deceleration is taken from the speed's derivative instead (map a wider \
                     signal, or remove [accel], to silence this)",
                    a.message,
                    a.signal,
                    -min_mps2,
                    -min_mps2 / STANDARD_GRAVITY_MPS2,
                    BRAKING_DECEL_MPS2 / STANDARD_GRAVITY_MPS2,
                ));
                accel = None;
            }
        }
        let yaw = match &cfg.yaw_rate {
            Some(y) => {
                let q: YawQ = r.signed("yaw_rate", y)?;
                let (name, ok) = rate_units(y.unit);
                r.check_unit("yaw_rate.unit", &q.sig, name, ok);
                Some(q)
            }
            None => None,
        };
        let torque: Option<TorqueQ> = match &cfg.steer_torque {
            Some(q) => Some(r.signed("steer_torque", q)?),
            None => None,
        };

        let needed = r.slots.iter().map(|s| (s.id, s.extended)).collect();
        let mut std_slot = vec![0u8; 1 << 11];
        for (i, s) in r.slots.iter().enumerate().rev() {
            if !s.extended && s.id < (1 << 11) && i < usize::from(u8::MAX) {
                std_slot[s.id as usize] = i as u8 + 1;
            }
        }
        Ok(Mapper {
            slots: r.slots,
            needed,
            steer,
            speed,
            pressure,
            pressed,
            accel,
            yaw,
            lat,
            torque,
            v_steer: None,
            v_speed: None,
            v_pressure: None,
            v_pressed: None,
            v_accel: None,
            v_yaw: None,
            v_torque: None,
            v_lat: None,
            warnings: r.warnings,
            now_ns: None,
            deadline_ns: i64::MAX,
            std_slot,
            ignored_frames: 0,
        })
    }

    /// The (ID, extended) pairs of every message the mapping reads: what a kernel filter needs.
    pub fn needed_ids(&self) -> &[(u32, bool)] {
        &self.needed
    }

    /// Doubts found while resolving (e.g. the DBC's unit contradicts the mapping's).
    pub fn warnings(&self) -> &[String] {
        &self.warnings
    }

    /// Per-message counters, in the order of [`Update::message`].
    pub fn stats(&self) -> Vec<MessageStats> {
        self.slots.iter().map(|s| s.stats.clone()).collect()
    }

    /// Counters of one message (index as in [`Update::message`]).
    pub fn message_stats(&self, i: usize) -> Option<&MessageStats> {
        self.slots.get(i).map(|s| &s.stats)
    }

    /// Frames given to [`Mapper::on_frame`] that belong to no mapped message (or are not data
    /// frames).
    pub fn ignored_frames(&self) -> u64 {
        self.ignored_frames
    }

    /// Advance the clock to `t_ns` without a frame (e.g. a live source that went quiet), so that
    /// silent messages are marked timed out and counted. Frames advance it themselves.
    ///
    /// The clock follows the frames even backwards (logs restart, sources get concatenated): a
    /// message last seen "in the future" is not timed out, so a step back in time never counts
    /// as an outage. It does restart counter tracking: what follows is another recording.
    pub fn advance(&mut self, t_ns: i64) {
        let now = t_ns;
        let went_back = self.now_ns.is_some_and(|prev| now < prev);
        self.now_ns = Some(now);
        if !went_back && now <= self.deadline_ns {
            return;
        }
        let mut deadline = i64::MAX;
        for s in &mut self.slots {
            if went_back {
                s.last_counter = None;
            }
            if let Some(last) = s.last_good_ns {
                if !s.timed_out && now - last > s.timeout_ns {
                    s.timed_out = true;
                    s.stats.timeouts += 1;
                    // A sender that went away restarts its counter wherever it likes.
                    s.last_counter = None;
                }
                if !s.timed_out {
                    deadline = deadline.min(last.saturating_add(s.timeout_ns));
                }
            }
        }
        self.deadline_ns = deadline;
    }

    /// The slot reading (`id`, `extended`), if any.
    #[inline]
    fn slot_of(&self, id: u32, extended: bool) -> Option<usize> {
        if !extended && self.slots.len() < usize::from(u8::MAX) {
            if let Some(&k) = self.std_slot.get(id as usize) {
                return usize::from(k).checked_sub(1);
            }
        }
        self.slots
            .iter()
            .position(|s| s.id == id && s.extended == extended)
    }

    /// Interpret one frame. `None` when it belongs to no mapped message. Allocates nothing.
    pub fn on_frame(&mut self, f: &Frame) -> Option<Update> {
        self.advance(f.t_ns);
        if f.kind != FrameKind::Data {
            self.ignored_frames += 1;
            return None;
        }
        let Some(i) = self.slot_of(f.id, f.extended) else {
            self.ignored_frames += 1;
            return None;
        };
        let data = f.payload();
        let outcome = match self.check(i, f) {
            Err(rej) => Outcome::Rejected(rej),
            Ok(()) => match self.decode(i, data) {
                None => {
                    self.slots[i].stats.short_frames += 1;
                    Outcome::Rejected(Reject::Short { len: f.len })
                }
                Some(p) => Outcome::Accepted(self.commit(i, f.t_ns, p)),
            },
        };
        Some(Update {
            message: i,
            outcome,
        })
    }

    /// Checksum and counter checks; updates counters and the slot's counter state.
    fn check(&mut self, i: usize, f: &Frame) -> Result<(), Reject> {
        let s = &mut self.slots[i];
        s.stats.frames += 1;
        let data = f.payload();
        if let Some(kind) = s.checksum {
            if let Err(e) = kind.verify(f.id, data) {
                s.stats.checksum_errors += 1;
                return Err(Reject::Checksum(e));
            }
        }
        if let Some(c) = &s.counter {
            let Some(v) = c.signal.raw(data).and_then(|r| r.as_u64()) else {
                s.stats.short_frames += 1;
                return Err(Reject::Short { len: f.len });
            };
            if let Some(prev) = s.last_counter {
                let step = v.wrapping_sub(prev) % s.counter_modulus;
                if step == 0 {
                    s.stats.counter_errors += 1;
                    return Err(Reject::CounterRepeat { counter: v });
                }
                if step != 1 {
                    s.stats.counter_gaps += 1;
                    s.stats.frames_lost += step - 1;
                }
            }
            s.last_counter = Some(v);
        }
        Ok(())
    }

    /// Decode every mapped quantity of message `i`; `None` if any does not fit the payload.
    fn decode(&self, i: usize, data: &[u8]) -> Option<Pending> {
        let mut p = Pending::default();
        let st = &self.steer;
        if st.slot == i {
            let mut v = st.angle.phys(data)?;
            if let Some(fr) = &st.fraction {
                v += fr.phys(data)?;
            }
            if let Some(sg) = &st.sign {
                if sg.phys(data)? != 0.0 {
                    v = -v;
                }
            }
            if st.invert {
                v = -v;
            }
            p.steer = Some(st.unit.to_si(st.scale * v));
        }
        let sp = &self.speed;
        if sp.slot == i {
            let v = match &sp.src {
                SpeedSrc::Signal(s) => s.phys(data)?,
                SpeedSrc::Wheels(ws) => {
                    let mut sum = 0.0;
                    for w in ws {
                        sum += w.phys(data)?;
                    }
                    sum / ws.len() as f64
                }
            };
            p.speed = Some(sp.unit.to_si(v));
        }
        if let Some(q) = &self.pressure {
            if q.slot == i {
                p.pressure = Some(q.unit.to_si(q.sig.phys(data)?));
            }
        }
        if let Some(q) = &self.pressed {
            if q.slot == i {
                p.pressed = Some((q.sig.phys(data)? != 0.0) != q.invert);
            }
        }
        if let Some(q) = &self.accel {
            if q.slot == i {
                p.accel = Some(q.value(data)?);
            }
        }
        if let Some(q) = &self.lat {
            if q.slot == i {
                p.lat = Some(q.value(data)?);
            }
        }
        if let Some(q) = &self.yaw {
            if q.slot == i {
                p.yaw = Some(q.unit.to_si(q.value(data)?));
            }
        }
        if let Some(q) = &self.torque {
            if q.slot == i {
                p.torque = Some(q.unit.to_si(q.value(data)?));
            }
        }
        Some(p)
    }

    fn commit(&mut self, i: usize, t_ns: i64, p: Pending) -> Changed {
        let s = &mut self.slots[i];
        s.stats.accepted += 1;
        s.last_good_ns = Some(t_ns);
        s.timed_out = false;
        self.deadline_ns = self.deadline_ns.min(t_ns.saturating_add(s.timeout_ns));
        let mut c = Changed::default();
        if let Some(v) = p.steer {
            self.v_steer = Some(Sample { value: v, t_ns });
            c.steer_angle = true;
        }
        if let Some(v) = p.speed {
            self.v_speed = Some(Sample { value: v, t_ns });
            c.speed = true;
        }
        if let Some(v) = p.pressure {
            self.v_pressure = Some(Sample { value: v, t_ns });
            c.brake_pressure = true;
        }
        if let Some(v) = p.pressed {
            self.v_pressed = Some(Sample { value: v, t_ns });
            c.brake_pressed = true;
        }
        if let Some(v) = p.accel {
            self.v_accel = Some(Sample { value: v, t_ns });
            c.accel = true;
        }
        if let Some(v) = p.yaw {
            self.v_yaw = Some(Sample { value: v, t_ns });
            c.yaw_rate = true;
        }
        if let Some(v) = p.lat {
            self.v_lat = Some(Sample { value: v, t_ns });
            c.lat_accel = true;
        }
        if let Some(v) = p.torque {
            self.v_torque = Some(Sample { value: v, t_ns });
            c.steer_torque = true;
        }
        c
    }

    fn reading<T: Copy>(&self, slot: usize, v: Option<Sample<T>>, t_ns: i64) -> Reading<T> {
        let s = &self.slots[slot];
        let validity = match s.last_good_ns {
            None => Validity::NoData,
            Some(last) if t_ns - last > s.timeout_ns => Validity::TimedOut,
            Some(_) => Validity::Valid,
        };
        Reading {
            value: v.map(|x| x.value),
            t_ns: v.map(|x| x.t_ns),
            validity,
        }
    }

    /// The quantities as of `t_ns` (normally the latest frame time, see [`Mapper::now_ns`]).
    pub fn snapshot(&self, t_ns: i64) -> VehicleSignals {
        VehicleSignals {
            t_ns,
            steer_angle_rad: self.reading(self.steer.slot, self.v_steer, t_ns),
            speed_mps: self.reading(self.speed.slot, self.v_speed, t_ns),
            brake_pressure_pa: match &self.pressure {
                Some(q) => self.reading(q.slot, self.v_pressure, t_ns),
                None => Reading::not_mapped(),
            },
            brake_pressed: match &self.pressed {
                Some(q) => self.reading(q.slot, self.v_pressed, t_ns),
                None => Reading::not_mapped(),
            },
            accel_mps2: match &self.accel {
                Some(q) => self.reading(q.slot, self.v_accel, t_ns),
                None => Reading::not_mapped(),
            },
            yaw_rate_radps: match &self.yaw {
                Some(q) => self.reading(q.slot, self.v_yaw, t_ns),
                None => Reading::not_mapped(),
            },
            lat_accel_mps2: match &self.lat {
                Some(q) => self.reading(q.slot, self.v_lat, t_ns),
                None => Reading::not_mapped(),
            },
            steer_torque_nm: match &self.torque {
                Some(q) => self.reading(q.slot, self.v_torque, t_ns),
                None => Reading::not_mapped(),
            },
        }
    }

    /// Time of the last frame (or of the last [`Mapper::advance`]).
    pub fn now_ns(&self) -> Option<i64> {
        self.now_ns
    }
}
