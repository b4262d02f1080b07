//! ECU emulation of the reference bus (`dbc/shimmy_reference.dbc`): which message carries which
//! quantity at which rate, the sensor models (noise, quantisation with a sub-LSB offset, wheel
//! radius errors, braking slip), send-period jitter, rolling counters, checksums and faults
//! (dropped frames, bad checksums, stuck sensors, bus-off periods).
//!
//! Frames are packed through the project's DBC encoder (`shimmy::dbc::Signal::encode_phys`), so
//! the bit layout lives only in the DBC file. Checksums come from
//! `shimmy::signals::checksum::ChecksumKind::Shimmy`.
//!
//! Not here: the plant or the drive cycle (values arrive as a [`Sample`]), nor any output.
//! [`ReferenceBus::poll`] allocates nothing.

use anyhow::{anyhow, bail, Context};
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use rand_distr::{Distribution, StandardNormal};
use shimmy::dbc::Database;
use shimmy::signals::checksum::ChecksumKind;
use shimmy::wire::Frame;

use crate::drive::G;
use crate::scenario::{Faults, Sensors};

/// The reference DBC, embedded so the binary needs no data files.
pub const REFERENCE_DBC: &str = include_str!("../../dbc/shimmy_reference.dbc");

/// Most signals one emulated message fills (besides counter and checksum).
pub const MAX_FIELDS: usize = 8;
/// Most frames one poll can produce (every ECU sends at most once per model step).
pub const MAX_BATCH: usize = 16;

/// A physical quantity an ECU reports.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum Quantity {
    /// Steering-wheel angle (deg, + = left), MODEL.md §8.
    SteerAngleDeg,
    /// Steering-wheel angular rate (deg/s).
    SteerRateDegS,
    /// Master-cylinder brake pressure (bar).
    BrakePressureBar,
    /// Brake light switch (0/1).
    BrakePressed,
    /// Wheel speed (km/h): 0 FL, 1 FR, 2 RL, 3 RR.
    WheelSpeedKmh(u8),
    /// Vehicle reference speed (km/h).
    VehicleSpeedKmh,
    /// Longitudinal acceleration (m/s², + = speeding up).
    LongAccelMps2,
    /// A fixed value (status and quality bits).
    Constant(f64),
}

/// One emulated message: its DBC name, period and which signal carries what.
#[derive(Clone, Copy, Debug)]
pub struct MessageSpec {
    pub message: &'static str,
    pub period_ms: u32,
    pub fields: &'static [(&'static str, Quantity)],
    pub counter: Option<&'static str>,
    pub checksum: Option<&'static str>,
}

/// The ECUs of the reference bus (issue 2 item 7): SAS at 100 Hz, brake and wheel speeds at
/// 50 Hz, vehicle speed and longitudinal acceleration at 50 Hz. The DBC's `GenMsgCycleTime`
/// overrides `period_ms` when present.
pub const REFERENCE_MESSAGES: &[MessageSpec] = &[
    MessageSpec {
        message: "SAS_01",
        period_ms: 10,
        fields: &[
            ("SAS_Angle", Quantity::SteerAngleDeg),
            ("SAS_Rate", Quantity::SteerRateDegS),
            ("SAS_Status", Quantity::Constant(0.0)),
        ],
        counter: Some("SAS_Counter"),
        checksum: Some("SAS_Checksum"),
    },
    MessageSpec {
        message: "BRK_01",
        period_ms: 20,
        fields: &[
            ("BRK_Pressure", Quantity::BrakePressureBar),
            ("BRK_Switch", Quantity::BrakePressed),
            ("BRK_PressureQ", Quantity::Constant(1.0)),
        ],
        counter: Some("BRK_Counter"),
        checksum: Some("BRK_Checksum"),
    },
    MessageSpec {
        message: "WHL_01",
        period_ms: 20,
        fields: &[
            ("WHL_SpeedFL", Quantity::WheelSpeedKmh(0)),
            ("WHL_SpeedFR", Quantity::WheelSpeedKmh(1)),
            ("WHL_SpeedRL", Quantity::WheelSpeedKmh(2)),
            ("WHL_SpeedRR", Quantity::WheelSpeedKmh(3)),
        ],
        counter: None,
        checksum: None,
    },
    MessageSpec {
        message: "VEH_01",
        period_ms: 20,
        fields: &[
            ("VEH_Speed", Quantity::VehicleSpeedKmh),
            ("VEH_LongAccel", Quantity::LongAccelMps2),
        ],
        counter: Some("VEH_Counter"),
        checksum: Some("VEH_Checksum"),
    },
];

/// The plant state at one instant, as the ECUs see it.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct Sample {
    pub t_s: f64,
    /// Steering-wheel angle including the driver's input (rad).
    pub steer_rad: f64,
    pub speed_mps: f64,
    pub accel_mps2: f64,
    /// Braking deceleration the pedal asks for (m/s²): sets the brake pressure.
    pub pedal_decel_mps2: f64,
    pub brake_pressed: bool,
}

impl Sample {
    /// Linear interpolation between two samples at time `t_s` (switches from `b`).
    fn lerp(a: &Sample, b: &Sample, t_s: f64) -> Sample {
        let span = b.t_s - a.t_s;
        let w = if span > 0.0 {
            ((t_s - a.t_s) / span).clamp(0.0, 1.0)
        } else {
            1.0
        };
        let l = |x: f64, y: f64| x + (y - x) * w;
        Sample {
            t_s,
            steer_rad: l(a.steer_rad, b.steer_rad),
            speed_mps: l(a.speed_mps, b.speed_mps),
            accel_mps2: l(a.accel_mps2, b.accel_mps2),
            pedal_decel_mps2: l(a.pedal_decel_mps2, b.pedal_decel_mps2),
            brake_pressed: b.brake_pressed,
        }
    }
}

/// Per-message counts, reported in the ground truth.
#[derive(Clone, Debug, Default, PartialEq, Eq, serde::Serialize)]
pub struct MessageStats {
    pub name: String,
    pub id: u32,
    /// Frames the ECU produced (counter advanced).
    pub generated: u64,
    /// Frames that reached the output.
    pub sent: u64,
    /// Lost to `faults.drop_probability`.
    pub dropped: u64,
    /// Not sent because the ECU or bus was bus-off.
    pub bus_off: u64,
    /// Sent with a deliberately wrong checksum.
    pub bad_checksum: u64,
    /// Sent with frozen values (stuck sensor).
    pub stuck: u64,
    /// Values clamped to the DBC range or not encodable.
    pub encode_clamped: u64,
}

/// What the ECU put into one frame, before quantisation (for tests and the ground truth).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct SentValues {
    pub t_ns: i64,
    pub message: usize,
    pub values: [f64; MAX_FIELDS],
    pub n: usize,
}

#[derive(Clone, Debug)]
struct Field {
    signal: usize,
    quantity: Quantity,
}

#[derive(Clone, Debug)]
struct Ecu {
    msg: usize,
    id: u32,
    extended: bool,
    len: usize,
    period_ns: i64,
    fields: Vec<Field>,
    counter: Option<(usize, u64)>,
    checksum: bool,
    /// Nominal send time of the current slot (ns since start) and its jittered send time.
    nominal_ns: i64,
    send_ns: i64,
    counter_value: u64,
    /// Last values (for stuck sensors and the rate signal).
    last: [f64; MAX_FIELDS],
    last_steer_deg: Option<f64>,
    stuck: Vec<(i64, i64)>,
    bus_off: Vec<(i64, i64)>,
    stats: MessageStats,
}

/// All emulated ECUs of one run.
pub struct ReferenceBus {
    db: Database,
    ecus: Vec<Ecu>,
    sensors: Sensors,
    faults: Faults,
    noise: ChaCha8Rng,
    jitter: ChaCha8Rng,
    fault_rng: ChaCha8Rng,
    /// SAS zero-point offset, a fraction of one LSB (MODEL.md §8).
    sas_offset_deg: f64,
    /// Per-wheel rolling-radius scale errors.
    radius_err: [f64; 4],
    t0_ns: i64,
    iface: shimmy::wire::IfaceName,
    prev: Option<Sample>,
    record: Option<Vec<SentValues>>,
}

fn ns(s: f64) -> i64 {
    (s * 1e9).round() as i64
}

impl ReferenceBus {
    /// Build the bus from DBC text (normally [`REFERENCE_DBC`]). Every message and signal of
    /// [`REFERENCE_MESSAGES`] must exist in it; a missing one is an error naming it.
    pub fn new(
        dbc_text: &str,
        sensors: &Sensors,
        faults: &Faults,
        seed: u64,
        t0_ns: i64,
    ) -> anyhow::Result<ReferenceBus> {
        let (db, _report) = Database::parse(dbc_text);
        let mut setup = ChaCha8Rng::seed_from_u64(seed);
        setup.set_stream(10);
        let mut ecus = Vec::with_capacity(REFERENCE_MESSAGES.len());
        for spec in REFERENCE_MESSAGES {
            let msg = db
                .message_by_name(spec.message)
                .ok_or_else(|| anyhow!("reference DBC has no message {}", spec.message))?;
            let m = &db.messages()[msg];
            let sig = |name: &str| {
                m.signal_by_name(name)
                    .ok_or_else(|| anyhow!("reference DBC message {} has no signal {name}", m.name))
            };
            if spec.fields.len() > MAX_FIELDS {
                bail!("{}: more than {MAX_FIELDS} fields", spec.message);
            }
            let mut fields = Vec::with_capacity(spec.fields.len());
            for (name, q) in spec.fields {
                fields.push(Field {
                    signal: sig(name)?,
                    quantity: *q,
                });
            }
            let counter = match spec.counter {
                Some(c) => {
                    let i = sig(c)?;
                    let size = m.signals[i].size;
                    Some((
                        i,
                        if size >= 64 {
                            u64::MAX
                        } else {
                            (1u64 << size) - 1
                        },
                    ))
                }
                None => None,
            };
            if let Some(c) = spec.checksum {
                sig(c)?;
            }
            let period_ns =
                m.cycle_time_ms.filter(|&p| p > 0).unwrap_or(spec.period_ms) as i64 * 1_000_000;
            // Each ECU starts at a random phase within its period, as on a real bus.
            let phase = setup.random_range(0..period_ns);
            let pick = |list: &mut dyn Iterator<Item = (f64, f64)>| -> Vec<(i64, i64)> {
                list.map(|(a, d)| (ns(a), ns(a + d))).collect()
            };
            let stuck = pick(
                &mut faults
                    .stuck
                    .iter()
                    .filter(|f| f.message == spec.message)
                    .map(|f| (f.start_s, f.duration_s)),
            );
            let bus_off = pick(
                &mut faults
                    .bus_off
                    .iter()
                    .filter(|f| f.message.as_deref().is_none_or(|n| n == spec.message))
                    .map(|f| (f.start_s, f.duration_s)),
            );
            ecus.push(Ecu {
                msg,
                id: m.id,
                extended: m.extended,
                len: m.size_bytes,
                period_ns,
                fields,
                counter,
                checksum: spec.checksum.is_some(),
                nominal_ns: phase,
                send_ns: phase,
                counter_value: 0,
                last: [0.0; MAX_FIELDS],
                last_steer_deg: None,
                stuck,
                bus_off,
                stats: MessageStats {
                    name: m.name.clone(),
                    id: m.id,
                    ..MessageStats::default()
                },
            });
        }
        for f in &faults.stuck {
            if !REFERENCE_MESSAGES.iter().any(|m| m.message == f.message) {
                bail!(
                    "faults.stuck: unknown message {:?} (known: {})",
                    f.message,
                    names()
                );
            }
        }
        for f in &faults.bus_off {
            if let Some(n) = &f.message {
                if !REFERENCE_MESSAGES.iter().any(|m| m.message == n) {
                    bail!("faults.bus_off: unknown message {n:?} (known: {})", names());
                }
            }
        }
        let tol = sensors.wheel_radius_tolerance_pct / 100.0;
        let mut radius_err = [0.0; 4];
        for r in &mut radius_err {
            *r = if tol > 0.0 {
                setup.random_range(-tol..=tol)
            } else {
                0.0
            };
        }
        let sas_offset_deg = setup.random_range(-0.5..0.5) * sas_lsb_deg(&db)?;
        let stream = |n| {
            let mut r = ChaCha8Rng::seed_from_u64(seed);
            r.set_stream(n);
            r
        };
        Ok(ReferenceBus {
            db,
            ecus,
            sensors: sensors.clone(),
            faults: faults.clone(),
            noise: stream(11),
            jitter: stream(12),
            fault_rng: stream(13),
            sas_offset_deg,
            radius_err,
            t0_ns,
            iface: shimmy::wire::IfaceName::from_str_truncated("vcan0"),
            prev: None,
            record: None,
        })
    }

    /// Set the interface name written into frames (default `vcan0`).
    pub fn set_iface(&mut self, name: &str) {
        self.iface = shimmy::wire::IfaceName::from_str_truncated(name);
    }

    /// Keep a copy of every value put into a sent frame (tests; costs memory).
    pub fn record_values(&mut self) {
        self.record = Some(Vec::new());
    }

    /// Values recorded since [`ReferenceBus::record_values`].
    pub fn recorded(&self) -> &[SentValues] {
        self.record.as_deref().unwrap_or(&[])
    }

    pub fn database(&self) -> &Database {
        &self.db
    }

    /// DBC message index of emulated message `i` and its field signal indices.
    pub fn message_layout(&self, i: usize) -> (usize, Vec<usize>) {
        let e = &self.ecus[i];
        (e.msg, e.fields.iter().map(|f| f.signal).collect())
    }

    pub fn stats(&self) -> Vec<MessageStats> {
        self.ecus.iter().map(|e| e.stats.clone()).collect()
    }

    /// The SAS zero-point offset drawn for this run (deg).
    pub fn sas_offset_deg(&self) -> f64 {
        self.sas_offset_deg
    }

    /// Produce every frame due in `(previous sample, now]`, in time order, into `out`.
    pub fn poll(&mut self, now: &Sample, out: &mut heapless::Vec<Frame, MAX_BATCH>) {
        let prev = self.prev.unwrap_or(*now);
        let now_ns = ns(now.t_s);
        for e in 0..self.ecus.len() {
            while self.ecus[e].send_ns <= now_ns {
                let send_ns = self.ecus[e].send_ns;
                let s = Sample::lerp(&prev, now, send_ns as f64 * 1e-9);
                if let Some(frame) = self.produce(e, send_ns, &s) {
                    if out.push(frame).is_err() {
                        // Cannot happen: one frame per ECU per step; counted, never panics.
                        self.ecus[e].stats.sent -= 1;
                        self.ecus[e].stats.dropped += 1;
                    }
                }
                self.advance(e);
            }
        }
        out.sort_unstable_by_key(|f| f.t_ns);
        self.prev = Some(*now);
    }

    fn advance(&mut self, e: usize) {
        let sd = self.sensors.jitter_ms * 1e6;
        let ecu = &mut self.ecus[e];
        ecu.nominal_ns += ecu.period_ns;
        let j = if sd > 0.0 {
            let z: f64 = StandardNormal.sample(&mut self.jitter);
            let lim = ecu.period_ns as f64 / 4.0;
            (z * sd).clamp(-lim, lim) as i64
        } else {
            0
        };
        ecu.send_ns = ecu.nominal_ns + j;
    }

    fn value(&mut self, e: usize, q: Quantity, s: &Sample) -> f64 {
        let sn = &self.sensors;
        let mut n = |sd: f64| -> f64 {
            if sd > 0.0 {
                let z: f64 = StandardNormal.sample(&mut self.noise);
                z * sd
            } else {
                0.0
            }
        };
        match q {
            Quantity::SteerAngleDeg => {
                s.steer_rad.to_degrees() + self.sas_offset_deg + n(sn.steer_noise_deg)
            }
            Quantity::SteerRateDegS => {
                let deg = s.steer_rad.to_degrees();
                let ecu = &mut self.ecus[e];
                let dt = ecu.period_ns as f64 * 1e-9;
                let r = ecu.last_steer_deg.map_or(0.0, |p| (deg - p) / dt);
                ecu.last_steer_deg = Some(deg);
                r
            }
            Quantity::BrakePressureBar => (s.pedal_decel_mps2 / G * sn.brake_bar_per_g
                + n(sn.brake_pressure_noise_bar))
            .max(0.0),
            Quantity::BrakePressed => {
                if s.brake_pressed {
                    1.0
                } else {
                    0.0
                }
            }
            Quantity::WheelSpeedKmh(w) => {
                let slip = wheel_slip(w, s);
                let v = s.speed_mps * 3.6 * (1.0 + self.radius_err[w as usize]) * (1.0 - slip);
                let noise = n(sn.wheel_speed_noise_kmh);
                if v > 0.0 {
                    (v + noise).max(0.0)
                } else {
                    0.0
                }
            }
            Quantity::VehicleSpeedKmh => {
                let mean_err = self.radius_err.iter().sum::<f64>() / 4.0;
                let v = s.speed_mps * 3.6 * (1.0 + mean_err);
                let noise = n(0.5 * sn.wheel_speed_noise_kmh);
                if v > 0.0 {
                    (v + noise).max(0.0)
                } else {
                    0.0
                }
            }
            Quantity::LongAccelMps2 => s.accel_mps2 + n(sn.accel_noise_mps2),
            Quantity::Constant(c) => c,
        }
    }

    fn produce(&mut self, e: usize, send_ns: i64, s: &Sample) -> Option<Frame> {
        let nf = self.ecus[e].fields.len();
        let mut values = [0.0; MAX_FIELDS];
        for (i, v) in values.iter_mut().enumerate().take(nf) {
            let q = self.ecus[e].fields[i].quantity;
            *v = self.value(e, q, s);
        }
        let in_window = |w: &[(i64, i64)]| w.iter().any(|&(a, b)| send_ns >= a && send_ns < b);
        {
            let ecu = &mut self.ecus[e];
            ecu.stats.generated += 1;
            if in_window(&ecu.stuck) {
                values = ecu.last;
                ecu.stats.stuck += 1;
            } else {
                ecu.last = values;
            }
        }
        let counter = self.ecus[e].counter_value;
        if let Some((_, max)) = self.ecus[e].counter {
            self.ecus[e].counter_value = if counter >= max { 0 } else { counter + 1 };
        }
        // Faults decided with their own random stream so that enabling one does not change the
        // sensor noise of the run.
        let drop = self.faults.drop_probability > 0.0
            && self.fault_rng.random::<f64>() < self.faults.drop_probability;
        let corrupt = self.faults.bad_checksum_probability > 0.0
            && self.fault_rng.random::<f64>() < self.faults.bad_checksum_probability;
        if in_window(&self.ecus[e].bus_off) {
            self.ecus[e].stats.bus_off += 1;
            return None;
        }
        if drop {
            self.ecus[e].stats.dropped += 1;
            return None;
        }
        let ecu = &self.ecus[e];
        let msg = &self.db.messages()[ecu.msg];
        let mut data = [0u8; 8];
        let len = ecu.len.min(8);
        let payload = &mut data[..len];
        let mut clamped = 0;
        for (i, f) in ecu.fields.iter().enumerate() {
            let sig = &msg.signals[f.signal];
            let mut v = values[i];
            if sig.min < sig.max && (v < sig.min || v > sig.max) {
                v = v.clamp(sig.min, sig.max);
                clamped += 1;
            }
            if sig.encode_phys(v, payload).is_err() {
                clamped += 1;
            }
        }
        if let Some((ci, _)) = ecu.counter {
            if msg.signals[ci]
                .encode_raw(shimmy::dbc::RawValue::Unsigned(counter), payload)
                .is_err()
            {
                clamped += 1;
            }
        }
        let mut bad = false;
        if ecu.checksum {
            if ChecksumKind::Shimmy.apply(ecu.id, payload).is_err() {
                clamped += 1;
            }
            if corrupt {
                let i = ChecksumKind::Shimmy.byte_index(len);
                payload[i] ^= self.fault_rng.random_range(1..=255u8);
                bad = true;
            }
        }
        let t_ns = self.t0_ns + send_ns;
        let mut frame = Frame::classic(t_ns, ecu.id, ecu.extended, payload)?;
        frame.iface = self.iface;
        let ecu = &mut self.ecus[e];
        ecu.stats.encode_clamped += clamped;
        ecu.stats.sent += 1;
        if bad {
            ecu.stats.bad_checksum += 1;
        }
        if let Some(rec) = &mut self.record {
            rec.push(SentValues {
                t_ns,
                message: e,
                values,
                n: nf,
            });
        }
        Some(frame)
    }
}

/// Longitudinal wheel slip while braking: a few percent at 0.5 g, front wheels (70 % of the
/// brake force, MODEL.md §6) more than rear. A linear tyre slip stiffness of about 20 per unit of
/// μ is typical.
fn wheel_slip(w: u8, s: &Sample) -> f64 {
    let share = if w < 2 { 0.70 } else { 0.30 };
    let mu = s.pedal_decel_mps2.max(0.0) / G * share / if w < 2 { 0.6 } else { 0.4 };
    (mu / 20.0).min(0.2)
}

fn names() -> String {
    REFERENCE_MESSAGES
        .iter()
        .map(|m| m.message)
        .collect::<Vec<_>>()
        .join(", ")
}

/// The steering-angle LSB (deg) from the DBC's factor.
fn sas_lsb_deg(db: &Database) -> anyhow::Result<f64> {
    let spec = &REFERENCE_MESSAGES[0];
    let m = &db.messages()[db
        .message_by_name(spec.message)
        .with_context(|| format!("reference DBC has no message {}", spec.message))?];
    let s = &m.signals[m
        .signal_by_name(spec.fields[0].0)
        .with_context(|| format!("no signal {}", spec.fields[0].0))?];
    Ok(s.factor.abs())
}
