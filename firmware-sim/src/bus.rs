//! ECU emulation of a vehicle bus described by a `bus.toml` ([`BusSpec`],
//! `shimmy::profile::bus`): which message carries which quantity at which rate and in which
//! form (sign, scale, split fields), the sensor models (noise, quantisation with a sub-LSB
//! offset, wheel radius errors, braking slip), send-period jitter, rolling counters (split ones
//! too), checksums, background traffic with constant payloads, and faults (dropped frames, bad
//! checksums, stuck sensors, bus-off periods).
//!
//! The default is our reference bus (`dbc/shimmy_reference.dbc` with
//! `config/vehicles/shimmy_reference/bus.toml`, both embedded); a vehicle profile brings its own
//! DBC and `bus.toml`. Frames are packed through the project's DBC encoder
//! (`shimmy::dbc::Signal::encode_phys`), so the bit layout lives only in the DBC file;
//! checksums come from `shimmy::signals::checksum::ChecksumKind`. The bus is never derived from
//! a signal mapping: it states the car's conventions itself.
//!
//! Steering torque (`steer_torque_nm`, where a bus carries one): the torsion-bar reading −T_c
//! of MODEL.md §15 when the vehicle's `[column]` is enabled; with the default 5-DOF model there is
//! no torsion bar (the rim and the hands are lumped into the rack restraint k_g), so it is 0 plus
//! the scenario's `steer_torque_noise_nm`. Yaw rate and lateral acceleration are kinematic (see
//! `crate::sim`).
//!
//! Not here: the plant or the drive cycle (values arrive as a [`Sample`]), nor any output.
//! [`Bus::poll`] allocates nothing.

use anyhow::{anyhow, bail, Context};
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use rand_distr::{Distribution, StandardNormal};
use shimmy::dbc::{Database, RawValue, ValueKind};
use shimmy::profile::bus::{parse_hex, BusSpec, Form, SteerSensor};
use shimmy::signals::checksum::ChecksumKind;
use shimmy::wire::Frame;

use crate::drive::G;
use crate::scenario::{Faults, Sensors};

pub use shimmy::profile::bus::Quantity;

/// The reference DBC, embedded so the binary needs no data files.
pub const REFERENCE_DBC: &str = include_str!("../../dbc/shimmy_reference.dbc");

/// The reference bus description (`config/vehicles/shimmy_reference/bus.toml`), embedded.
pub const REFERENCE_BUS: &str = include_str!("../../config/vehicles/shimmy_reference/bus.toml");

/// The reference bus description, parsed.
pub fn reference_bus() -> anyhow::Result<BusSpec> {
    BusSpec::from_toml_str(REFERENCE_BUS).context("the embedded reference bus.toml")
}

/// Most signals one emulated message fills (besides counter and checksum).
pub const MAX_FIELDS: usize = 12;
/// Most frames one poll can produce: every ECU sends at most once per control step (periods
/// are at least 1 ms, the longest control step), so this is also the most ECUs a bus may have.
pub const MAX_BATCH: usize = 128;

/// The plant state at one instant, as the ECUs see it.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct Sample {
    pub t_s: f64,
    /// Steering-wheel angle including the driver's input (rad, + = left).
    pub steer_rad: f64,
    pub speed_mps: f64,
    pub accel_mps2: f64,
    /// Braking deceleration the pedal asks for (m/s²): sets the brake pressure.
    pub pedal_decel_mps2: f64,
    pub brake_pressed: bool,
    /// Yaw rate (rad/s, + = turning left), kinematic (see `crate::sim`).
    pub yaw_rate_rps: f64,
    /// Lateral acceleration (m/s², + = to the left), `v · yaw rate`.
    pub lat_accel_mps2: f64,
    /// Torsion-bar torque (N·m), + when the rim is turned left of the pinion (the driver
    /// steering left): −T_c of MODEL.md §15, whose T_c is the torque the column puts on the rim.
    pub steer_torque_nm: f64,
    /// Whether the plant has a torsion bar (the MODEL.md §15 column). Without one there is
    /// nothing for a torque sensor to measure: it sends a steady 0, no noise, which the
    /// observer takes for a bus without a live torque (it then estimates from the angle).
    pub torsion_bar: bool,
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
            yaw_rate_rps: l(a.yaw_rate_rps, b.yaw_rate_rps),
            lat_accel_mps2: l(a.lat_accel_mps2, b.lat_accel_mps2),
            steer_torque_nm: l(a.steer_torque_nm, b.steer_torque_nm),
            torsion_bar: b.torsion_bar,
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
    /// Values clamped to what the signal's bits hold (or the bus's stated `range`), or not
    /// encodable.
    pub encode_clamped: u64,
}

/// What the ECU put into one frame, before quantisation (for tests and the ground truth), and
/// the plant state it was taken from.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct SentValues {
    pub t_ns: i64,
    pub message: usize,
    pub values: [f64; MAX_FIELDS],
    pub n: usize,
    /// The plant state the frame's values were computed from (interpolated to its send time).
    pub sample: Sample,
}

/// One field of an emulated message, resolved against the DBC.
#[derive(Clone, Copy, Debug)]
struct Field {
    signal: usize,
    quantity: Quantity,
    value: f64,
    scale: f64,
    offset: f64,
    form: Form,
    /// Steps for `coarse` / `remainder`: the fine step the sensor resolves and the coarse one.
    fine: f64,
    coarse: f64,
    /// The range the ECU clamps to (physical unit), and half a step: a value within half a step
    /// outside it rounds onto its edge and is not counted as clamped.
    lo: f64,
    hi: f64,
    half_step: f64,
}

impl Field {
    /// The physical value this field's signal carries for quantity value `q`.
    fn shape(&self, q: f64) -> f64 {
        let v = self.scale * q + self.offset;
        match self.form {
            Form::Value => v,
            Form::Magnitude => v.abs(),
            Form::Sign => {
                if v < 0.0 {
                    1.0
                } else {
                    0.0
                }
            }
            Form::Coarse => {
                let fine = (v / self.fine).round() * self.fine;
                (fine / self.coarse).round() * self.coarse
            }
            Form::Remainder => {
                let fine = (v / self.fine).round() * self.fine;
                fine - (fine / self.coarse).round() * self.coarse
            }
        }
    }
}

/// A rolling counter, possibly split over several signals.
#[derive(Clone, Debug)]
struct Counter {
    /// (signal, bits), least significant part first.
    parts: Vec<(usize, u32)>,
    max: u64,
}

#[derive(Clone, Debug)]
struct Ecu {
    /// DBC message index (`None` for a raw background message).
    msg: Option<usize>,
    id: u32,
    extended: bool,
    len: usize,
    period_ns: i64,
    jitter_sd_ns: f64,
    base: [u8; 8],
    fields: Vec<Field>,
    counter: Option<Counter>,
    checksum: Option<ChecksumKind>,
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
pub struct Bus {
    db: Database,
    ecus: Vec<Ecu>,
    sensors: Sensors,
    faults: Faults,
    noise: ChaCha8Rng,
    jitter: ChaCha8Rng,
    fault_rng: ChaCha8Rng,
    /// SAS zero-point offset, a fraction of one LSB (MODEL.md §8).
    sas_offset_deg: f64,
    steer_sensor: Option<SteerSensor>,
    /// Per-wheel rolling-radius scale errors.
    radius_err: [f64; 4],
    t0_ns: i64,
    iface: shimmy::wire::IfaceName,
    prev: Option<Sample>,
    record: Option<Vec<SentValues>>,
}

/// Fault windows `[start, end)` (ns since the start of the run).
type Windows = Vec<(i64, i64)>;

fn ns(s: f64) -> i64 {
    (s * 1e9).round() as i64
}

impl Bus {
    /// The reference bus ([`REFERENCE_BUS`]) packed with the DBC in `dbc_text` (normally
    /// [`REFERENCE_DBC`]; a variant must define the same messages and signals).
    pub fn reference(
        dbc_text: &str,
        sensors: &Sensors,
        faults: &Faults,
        seed: u64,
        t0_ns: i64,
    ) -> anyhow::Result<Bus> {
        let (db, _report) = Database::parse(dbc_text);
        Bus::new(db, &reference_bus()?, sensors, faults, seed, t0_ns)
    }

    /// Build the ECUs of `spec` against `db`. Every message, signal, counter and checksum must
    /// exist and fit (an error names the first that does not).
    pub fn new(
        db: Database,
        spec: &BusSpec,
        sensors: &Sensors,
        faults: &Faults,
        seed: u64,
        t0_ns: i64,
    ) -> anyhow::Result<Bus> {
        spec.validate()?;
        spec.check_against(&db)?;
        let n_ecus = spec.messages.len() + spec.raw.len();
        if n_ecus > MAX_BATCH {
            bail!("the bus has {n_ecus} messages; firmware-sim emulates at most {MAX_BATCH}");
        }
        let mut setup = ChaCha8Rng::seed_from_u64(seed);
        setup.set_stream(10);
        let pick = |name: &str| -> (Windows, Windows) {
            let w = |a: f64, d: f64| (ns(a), ns(a + d));
            let stuck = faults
                .stuck
                .iter()
                .filter(|f| f.message == name)
                .map(|f| w(f.start_s, f.duration_s))
                .collect();
            let bus_off = faults
                .bus_off
                .iter()
                .filter(|f| f.message.as_deref().is_none_or(|n| n == name))
                .map(|f| w(f.start_s, f.duration_s))
                .collect();
            (stuck, bus_off)
        };
        let jitter_ns = |j: Option<f64>| j.unwrap_or(sensors.jitter_ms) * 1e6;
        let mut ecus = Vec::with_capacity(n_ecus);
        for spec_m in &spec.messages {
            let mi = db
                .message_by_name(&spec_m.name)
                .ok_or_else(|| anyhow!("the DBC has no message {}", spec_m.name))?;
            let m = &db.messages()[mi];
            let sig = |name: &str| {
                m.signal_by_name(name)
                    .ok_or_else(|| anyhow!("DBC message {} has no signal {name}", m.name))
            };
            if spec_m.fields.len() > MAX_FIELDS {
                bail!("{}: more than {MAX_FIELDS} fields", spec_m.name);
            }
            let mut fields = Vec::with_capacity(spec_m.fields.len());
            for f in &spec_m.fields {
                let si = sig(&f.signal)?;
                let s = &m.signals[si];
                let (blo, bhi) = s.phys_range();
                // What the bits hold, or the range the bus states. Not the DBC's `[min|max]`:
                // opendbc's are often wrong (the RAV4's ACCEL_X says [0|65535] while the real
                // car sends -3.9..2.3 m/s²).
                let (lo, hi) = match f.range {
                    Some([a, b]) if a.max(blo) <= b.min(bhi) => (a.max(blo), b.min(bhi)),
                    _ => (blo, bhi),
                };
                let own = s.factor.abs();
                let (fine, coarse) = match f.form {
                    Form::Coarse => (f.fine_step.unwrap_or(own), own),
                    Form::Remainder => (own, f.coarse_step.unwrap_or(own)),
                    _ => (own, own),
                };
                let half_step = match s.kind {
                    ValueKind::Unsigned | ValueKind::Signed => 0.5 * own,
                    ValueKind::Float32 | ValueKind::Float64 => 0.0,
                };
                fields.push(Field {
                    signal: si,
                    quantity: f.quantity,
                    value: f.value.unwrap_or(0.0),
                    scale: f.scale,
                    offset: f.offset,
                    form: f.form,
                    fine,
                    coarse,
                    lo,
                    hi,
                    half_step,
                });
            }
            let counter = match &spec_m.counter {
                Some(c) => {
                    let mut parts = Vec::with_capacity(c.signals().len());
                    let mut bits = 0u32;
                    for name in c.signals() {
                        let i = sig(name)?;
                        let b = u32::from(m.signals[i].size);
                        parts.push((i, b));
                        bits += b;
                    }
                    let full = if bits >= 64 {
                        u64::MAX
                    } else {
                        (1u64 << bits) - 1
                    };
                    Some(Counter {
                        parts,
                        max: spec_m.counter_max.unwrap_or(full).min(full),
                    })
                }
                None => None,
            };
            let mut base = [0u8; 8];
            if let Some(p) = &spec_m.payload {
                let b = parse_hex(p, m.size_bytes)?;
                base[..b.len()].copy_from_slice(&b);
            }
            let period_ns = ns(spec_m.period_ms * 1e-3);
            // Each ECU starts at a random phase within its period, as on a real bus.
            let phase = setup.random_range(0..period_ns);
            let (stuck, bus_off) = pick(&spec_m.name);
            ecus.push(Ecu {
                msg: Some(mi),
                id: m.id,
                extended: m.extended,
                len: m.size_bytes.min(8),
                period_ns,
                jitter_sd_ns: jitter_ns(spec_m.jitter_ms),
                base,
                fields,
                counter,
                checksum: spec_m.checksum,
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
        for r in &spec.raw {
            let name = r.name.clone().unwrap_or_else(|| format!("0x{:03X}", r.id));
            let mut base = [0u8; 8];
            if let Some(p) = &r.payload {
                let b = parse_hex(p, r.dlc)?;
                base[..b.len()].copy_from_slice(&b);
            }
            let period_ns = ns(r.period_ms * 1e-3);
            let phase = setup.random_range(0..period_ns);
            let (stuck, bus_off) = pick(&name);
            ecus.push(Ecu {
                msg: None,
                id: r.id,
                extended: r.extended,
                len: r.dlc,
                period_ns,
                jitter_sd_ns: jitter_ns(r.jitter_ms),
                base,
                fields: Vec::new(),
                counter: None,
                checksum: r.checksum,
                nominal_ns: phase,
                send_ns: phase,
                counter_value: 0,
                last: [0.0; MAX_FIELDS],
                last_steer_deg: None,
                stuck,
                bus_off,
                stats: MessageStats {
                    name,
                    id: r.id,
                    ..MessageStats::default()
                },
            });
        }
        let known = |n: &str| ecus.iter().any(|e| e.stats.name == n);
        let names = || {
            ecus.iter()
                .map(|e| e.stats.name.as_str())
                .collect::<Vec<_>>()
                .join(", ")
        };
        for f in &faults.stuck {
            if !known(&f.message) {
                bail!(
                    "faults.stuck: unknown message {:?} (known: {})",
                    f.message,
                    names()
                );
            }
        }
        for f in &faults.bus_off {
            if let Some(n) = &f.message {
                if !known(n) {
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
        let steer_sensor = spec.steer_sensor(&db)?;
        let sas_offset_deg = match &steer_sensor {
            Some(s) => setup.random_range(-0.5..0.5) * s.step_deg,
            None => 0.0,
        };
        let stream = |n| {
            let mut r = ChaCha8Rng::seed_from_u64(seed);
            r.set_stream(n);
            r
        };
        Ok(Bus {
            db,
            ecus,
            sensors: sensors.clone(),
            faults: faults.clone(),
            noise: stream(11),
            jitter: stream(12),
            fault_rng: stream(13),
            sas_offset_deg,
            steer_sensor,
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

    /// Values recorded since [`Bus::record_values`].
    pub fn recorded(&self) -> &[SentValues] {
        self.record.as_deref().unwrap_or(&[])
    }

    pub fn database(&self) -> &Database {
        &self.db
    }

    /// Number of emulated messages (DBC ones first, in file order, then the raw ones).
    pub fn len(&self) -> usize {
        self.ecus.len()
    }

    pub fn is_empty(&self) -> bool {
        self.ecus.is_empty()
    }

    /// DBC message index of emulated message `i` and its field signal indices (`usize::MAX`
    /// and none for a raw background message).
    pub fn message_layout(&self, i: usize) -> (usize, Vec<usize>) {
        let e = &self.ecus[i];
        (
            e.msg.unwrap_or(usize::MAX),
            e.fields.iter().map(|f| f.signal).collect(),
        )
    }

    /// (frame ID, extended, payload length, period in ms) of emulated message `i`.
    pub fn message_frame(&self, i: usize) -> (u32, bool, usize, f64) {
        let e = &self.ecus[i];
        (e.id, e.extended, e.len, e.period_ns as f64 * 1e-6)
    }

    pub fn stats(&self) -> Vec<MessageStats> {
        self.ecus.iter().map(|e| e.stats.clone()).collect()
    }

    /// The SAS zero-point offset drawn for this run (deg).
    pub fn sas_offset_deg(&self) -> f64 {
        self.sas_offset_deg
    }

    /// The steering angle sensor this bus emulates (rate and step from the bus and DBC).
    pub fn steer_sensor(&self) -> Option<&SteerSensor> {
        self.steer_sensor.as_ref()
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
                        // More frames due in one step than the batch holds (the bus's size is
                        // checked against it): counted, never panics.
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
        let ecu = &mut self.ecus[e];
        let sd = ecu.jitter_sd_ns;
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
        let wheel = |w: usize| match w {
            0 => Quantity::WheelSpeedFlKmh,
            1 => Quantity::WheelSpeedFrKmh,
            2 => Quantity::WheelSpeedRlKmh,
            _ => Quantity::WheelSpeedRrKmh,
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
            Quantity::WheelSpeedFlKmh
            | Quantity::WheelSpeedFrKmh
            | Quantity::WheelSpeedRlKmh
            | Quantity::WheelSpeedRrKmh => {
                let w = (0..4).find(|&w| wheel(w) == q).unwrap_or(0);
                let slip = wheel_slip(w as u8, s);
                let v = s.speed_mps * 3.6 * (1.0 + self.radius_err[w]) * (1.0 - slip);
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
            Quantity::LatAccelMps2 => s.lat_accel_mps2 + n(sn.accel_noise_mps2),
            Quantity::YawRateDegS => s.yaw_rate_rps.to_degrees() + n(sn.yaw_rate_noise_deg_s),
            Quantity::SteerTorqueNm => {
                // Drawn either way, so the other signals' noise is the same with or without.
                let noise = n(sn.steer_torque_noise_nm);
                if s.torsion_bar {
                    s.steer_torque_nm + noise
                } else {
                    0.0
                }
            }
            // Constants are per field (`Field::value`), never asked for here.
            Quantity::Constant => 0.0,
        }
    }

    fn produce(&mut self, e: usize, send_ns: i64, s: &Sample) -> Option<Frame> {
        let nf = self.ecus[e].fields.len();
        let mut values = [0.0; MAX_FIELDS];
        // Each quantity is measured once per frame, so split fields (coarse and remainder,
        // magnitude and sign) carry the same reading.
        let mut seen = [f64::NAN; Quantity::ALL.len()];
        for (i, v) in values.iter_mut().enumerate().take(nf) {
            let f = self.ecus[e].fields[i];
            let q = if f.quantity == Quantity::Constant {
                f.value
            } else {
                let k = f.quantity.index();
                if seen[k].is_nan() {
                    seen[k] = self.value(e, f.quantity, s);
                }
                seen[k]
            };
            *v = f.shape(q);
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
        if let Some(c) = &self.ecus[e].counter {
            let max = c.max;
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
        let mut data = ecu.base;
        let len = ecu.len.min(8);
        let payload = &mut data[..len];
        let mut clamped = 0;
        if let Some(mi) = ecu.msg {
            let msg = &self.db.messages()[mi];
            for (i, f) in ecu.fields.iter().enumerate() {
                let sig = &msg.signals[f.signal];
                let mut v = values[i];
                if !v.is_finite() {
                    clamped += 1;
                    continue;
                }
                if v < f.lo || v > f.hi {
                    if v < f.lo - f.half_step || v > f.hi + f.half_step {
                        clamped += 1;
                    }
                    v = v.clamp(f.lo, f.hi);
                }
                if sig.encode_phys(v, payload).is_err() {
                    clamped += 1;
                }
            }
            if let Some(c) = &ecu.counter {
                let mut shift = 0;
                for &(si, bits) in &c.parts {
                    let part = (counter >> shift) & ((1u64 << bits) - 1);
                    shift += bits;
                    if msg.signals[si]
                        .encode_raw(RawValue::Unsigned(part), payload)
                        .is_err()
                    {
                        clamped += 1;
                    }
                }
            }
        }
        let mut bad = false;
        if let Some(kind) = ecu.checksum {
            if kind.apply(ecu.id, payload).is_err() {
                clamped += 1;
            }
            if corrupt {
                // Any other value: XOR with a non-zero pattern of the checksum's width.
                let mask = ((1u32 << kind.width_bits(ecu.id)) - 1) as u8;
                let r = self.fault_rng.random_range(1..=mask);
                if let Ok(c) = kind.stored(ecu.id, payload) {
                    if kind.write(ecu.id, payload, c ^ r).is_ok() {
                        bad = true;
                    }
                }
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
                sample: *s,
            });
        }
        Some(frame)
    }
}

/// A vehicle profile's bus, ready to emulate: its DBC (or `dbc`, a custom one in its place) and
/// its `bus.toml`, checked against each other and against the profile's steering angle sensor
/// (`[sensors.steer_angle]` in profile.toml): the bus's steering message must come at the
/// profile's rate (within 1 %) with the profile's step, or the profile's table (built for that
/// sensor) would be judged against another one.
pub fn profile_bus(
    profile: &shimmy::profile::Profile,
    dbc: Option<&std::path::Path>,
) -> anyhow::Result<(Database, BusSpec)> {
    let spec = profile.load_bus()?.with_context(|| {
        format!(
            "vehicle profile {} has no bus description (`bus = \"bus.toml\"` in its profile.toml)",
            profile.name
        )
    })?;
    let path = dbc.unwrap_or(&profile.dbc_path);
    let (db, _report) = Database::load(path)?;
    spec.check_against(&db)
        .with_context(|| format!("bus of profile {} against {}", profile.name, path.display()))?;
    let s = spec.steer_sensor(&db)?.with_context(|| {
        format!(
            "profile {}: its bus.toml has no steer_angle_deg field, so no steering angle sensor",
            profile.name
        )
    })?;
    let want = &profile.sensor;
    if (s.rate_hz - want.rate_hz).abs() > 0.01 * want.rate_hz
        || (s.step_deg - want.step_deg).abs() > 1e-9
    {
        bail!(
            "profile {}: its bus sends {} at {:.2} Hz in {} deg steps, but [sensors.steer_angle] \
             says {} Hz, {} deg; make profile.toml and bus.toml agree",
            profile.name,
            s.message,
            s.rate_hz,
            s.step_deg,
            want.rate_hz,
            want.step_deg
        );
    }
    Ok((db, spec))
}

/// Longitudinal wheel slip while braking: a few percent at 0.5 g, front wheels (70 % of the
/// brake force, MODEL.md §6) more than rear. A linear tyre slip stiffness of about 20 per unit of
/// μ is typical.
fn wheel_slip(w: u8, s: &Sample) -> f64 {
    let share = if w < 2 { 0.70 } else { 0.30 };
    let mu = s.pedal_decel_mps2.max(0.0) / G * share / if w < 2 { 0.6 } else { 0.4 };
    (mu / 20.0).min(0.2)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_embedded_reference_bus_parses_and_fits_the_reference_dbc() {
        let b = reference_bus().unwrap();
        let (db, _) = Database::parse(REFERENCE_DBC);
        b.check_against(&db).unwrap();
        let s = b.steer_sensor(&db).unwrap().unwrap();
        assert_eq!(
            (s.message.as_str(), s.rate_hz, s.step_deg),
            ("SAS_01", 100.0, 0.1)
        );
        // The DBC's own cycle times agree with the bus description.
        for m in &b.messages {
            let dm = &db.messages()[db.message_by_name(&m.name).unwrap()];
            assert_eq!(
                dm.cycle_time_ms.map(f64::from),
                Some(m.period_ms),
                "{}",
                m.name
            );
        }
    }

    #[test]
    fn split_forms_reassemble_the_value() {
        let f = |form, fine, coarse| Field {
            signal: 0,
            quantity: Quantity::SteerAngleDeg,
            value: 0.0,
            scale: 1.0,
            offset: 0.0,
            form,
            fine,
            coarse,
            lo: f64::NEG_INFINITY,
            hi: f64::INFINITY,
            half_step: 0.0,
        };
        let c = f(Form::Coarse, 0.1, 1.5);
        let r = f(Form::Remainder, 0.1, 1.5);
        for x in [-3.8, -3.7, -0.04, 0.0, 0.8, 2.44, 12.35] {
            let (a, b) = (c.shape(x), r.shape(x));
            assert!(((a + b) - (x / 0.1).round() * 0.1).abs() < 1e-9, "{x}");
            assert!(((a / 1.5).round() * 1.5 - a).abs() < 1e-9 && b.abs() <= 0.7 + 1e-9);
        }
        let m = f(Form::Magnitude, 0.1, 0.1);
        let s = f(Form::Sign, 0.1, 0.1);
        assert_eq!((m.shape(-2.5), s.shape(-2.5)), (2.5, 1.0));
        assert_eq!((m.shape(2.5), s.shape(2.5)), (2.5, 0.0));
    }
}
