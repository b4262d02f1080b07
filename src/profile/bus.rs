//! `bus.toml`: a car's CAN bus as it is on the road, one entry per message the car sends that
//! matters to the monitor or to recognising the car: its DBC name, the period measured on a real
//! log (or documented for the car), and how an emulated ECU fills it.
//!
//! What it is: the file format and its checks against the profile's DBC. `shimmy identify`
//! compares a log's message periods with `name` and `period_ms`; firmware-sim emulates the bus
//! from the whole file. What it is not: the signal mapping (which signal carries what for the
//! monitor is `mapping.toml`, [`crate::signals::mapping`]). The two are written independently on
//! purpose: the bus states the car's own conventions (units, signs, split fields, checksums), so
//! a wrong mapping shows up against a simulated bus as it would on the real car.
//!
//! ```toml
//! [[message]]
//! name = "STEER_ANGLE_SENSOR"  # DBC message name
//! period_ms = 12.06            # measured or documented (say which in a comment)
//! jitter_ms = 0.5              # send-time jitter of the ECU, SD (default: the scenario's)
//! checksum = "toyota"          # a ChecksumKind, when the car protects the message
//! counter = "COUNTER"          # rolling counter signal; ["LSB", "MSB"] when split
//! payload = "0000000000000008" # bits no field sets (default: zeros)
//! fields = [
//!   # physical value written = scale * quantity + offset, then the form
//!   { signal = "STEER_ANGLE", quantity = "steer_angle_deg", form = "coarse", fine_step = 0.1 },
//!   { signal = "STEER_FRACTION", quantity = "steer_angle_deg", form = "remainder", coarse_step = 1.5 },
//!   { signal = "ACCEL_X", quantity = "long_accel_mps2", scale = -1.0 },
//!   { signal = "STATUS", quantity = "constant", value = 1 },
//! ]
//!
//! [[raw]]                      # background traffic with no DBC entry
//! id = 0x0BA
//! dlc = 4
//! period_ms = 24.13
//! checksum = "toyota"
//! ```
//!
//! Quantities are the plant's, in the units their names say, with the monitor's signs: angles,
//! rates and torques positive to the left (counter-clockwise seen from the driver or from
//! above), accelerations positive forward and to the left. A bus whose signal reads the other
//! way says so with a negative `scale`.

use std::collections::BTreeSet;
use std::path::Path;

use anyhow::{bail, Context};
use serde::{Deserialize, Serialize};

use crate::dbc::{Database, Signal};
use crate::signals::checksum::ChecksumKind;

/// The whole file.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct BusSpec {
    /// The messages, each once.
    #[serde(rename = "message")]
    pub messages: Vec<BusMessage>,
    /// Background messages the DBC does not describe (the real car sends them; a fingerprint
    /// sees them), sent with a constant payload.
    #[serde(default, rename = "raw", skip_serializing_if = "Vec::is_empty")]
    pub raw: Vec<RawMessage>,
}

/// One message of the bus.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct BusMessage {
    /// The DBC message name.
    pub name: String,
    /// Nominal send period (ms).
    pub period_ms: f64,
    /// SD of the ECU's send-time jitter (ms); absent: the simulation's default.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub jitter_ms: Option<f64>,
    /// The payload before any field is written (hex, at most the DBC length); absent: zeros.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub payload: Option<String>,
    /// The rolling counter: one signal, or its parts from the least significant up.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub counter: Option<CounterSpec>,
    /// The counter's last value before it wraps to 0 (default: all its bits set).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub counter_max: Option<u64>,
    /// The checksum the car puts into this message.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub checksum: Option<ChecksumKind>,
    /// Which quantity fills which signal.
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub fields: Vec<BusField>,
}

/// A background message absent from the DBC.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct RawMessage {
    /// A label for reports (default: the ID in hex).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub name: Option<String>,
    pub id: u32,
    #[serde(default)]
    pub extended: bool,
    /// Payload length (bytes, 0..8).
    pub dlc: usize,
    pub period_ms: f64,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub jitter_ms: Option<f64>,
    /// The constant payload (hex, `dlc` bytes at most); absent: zeros.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub payload: Option<String>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub checksum: Option<ChecksumKind>,
}

/// A counter in one signal, or split over several (least significant part first).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(untagged)]
pub enum CounterSpec {
    One(String),
    Split(Vec<String>),
}

impl CounterSpec {
    /// The counter's signals, least significant part first.
    pub fn signals(&self) -> &[String] {
        match self {
            CounterSpec::One(s) => std::slice::from_ref(s),
            CounterSpec::Split(v) => v,
        }
    }
}

/// One signal of a message and the quantity that fills it.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct BusField {
    pub signal: String,
    pub quantity: Quantity,
    /// Physical value = `scale` · quantity + `offset`, in the DBC signal's unit (default 1, 0).
    #[serde(default = "one", skip_serializing_if = "is_one")]
    pub scale: f64,
    #[serde(default, skip_serializing_if = "is_zero")]
    pub offset: f64,
    #[serde(default, skip_serializing_if = "Form::is_value")]
    pub form: Form,
    /// The value of a `constant`.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub value: Option<f64>,
    /// `form = "coarse"`: the step the sensor resolves (the remainder signal's step).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub fine_step: Option<f64>,
    /// `form = "remainder"`: the coarse signal's step.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub coarse_step: Option<f64>,
    /// The range the ECU clamps to, in the signal's physical unit (default: what the signal's
    /// bits hold; the DBC's `[min|max]` is not used, opendbc's are often wrong).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub range: Option<[f64; 2]>,
}

fn one() -> f64 {
    1.0
}
fn is_one(x: &f64) -> bool {
    *x == 1.0
}
fn is_zero(x: &f64) -> bool {
    *x == 0.0
}

/// What fills a signal: a plant quantity (in the unit its name says, with the monitor's signs)
/// or a constant.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum Quantity {
    /// Steering-wheel angle (deg, + = left / counter-clockwise), MODEL.md §8.
    SteerAngleDeg,
    /// Steering-wheel angular rate (deg/s, + = turning left).
    SteerRateDegS,
    /// Wheel speeds (km/h).
    WheelSpeedFlKmh,
    WheelSpeedFrKmh,
    WheelSpeedRlKmh,
    WheelSpeedRrKmh,
    /// Vehicle reference speed (km/h).
    VehicleSpeedKmh,
    /// Master-cylinder brake pressure (bar).
    BrakePressureBar,
    /// Brake pedal switch (0/1).
    BrakePressed,
    /// Longitudinal acceleration (m/s², + = speeding up).
    LongAccelMps2,
    /// Lateral acceleration (m/s², + = to the left).
    LatAccelMps2,
    /// Yaw rate (deg/s, + = counter-clockwise seen from above, turning left).
    YawRateDegS,
    /// Torsion-bar (driver) steering torque (N·m, + = the driver turning the wheel left): −T_c
    /// of MODEL.md §15, whose T_c is the torque the column puts on the rim.
    SteerTorqueNm,
    /// A fixed value (`value`), e.g. a status or quality bit.
    Constant,
}

impl Quantity {
    /// Every quantity, in a fixed order ([`Quantity::index`]).
    pub const ALL: [Quantity; 14] = [
        Quantity::SteerAngleDeg,
        Quantity::SteerRateDegS,
        Quantity::WheelSpeedFlKmh,
        Quantity::WheelSpeedFrKmh,
        Quantity::WheelSpeedRlKmh,
        Quantity::WheelSpeedRrKmh,
        Quantity::VehicleSpeedKmh,
        Quantity::BrakePressureBar,
        Quantity::BrakePressed,
        Quantity::LongAccelMps2,
        Quantity::LatAccelMps2,
        Quantity::YawRateDegS,
        Quantity::SteerTorqueNm,
        Quantity::Constant,
    ];

    /// Position in [`Quantity::ALL`].
    pub fn index(self) -> usize {
        Quantity::ALL
            .iter()
            .position(|&q| q == self)
            .unwrap_or(Quantity::ALL.len() - 1)
    }
}

/// How a signal carries its value.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum Form {
    /// The value itself.
    #[default]
    Value,
    /// Its magnitude (a separate `sign` field carries the sign; VW).
    Magnitude,
    /// 1 when the value is negative, else 0.
    Sign,
    /// The value rounded to the signal's own step, after rounding to `fine_step` (Toyota's
    /// 1.5° STEER_ANGLE).
    Coarse,
    /// What the `coarse` signal leaves: the value rounded to this signal's step minus the value
    /// rounded to `coarse_step` (Toyota's 0.1° STEER_FRACTION).
    Remainder,
}

impl Form {
    fn is_value(&self) -> bool {
        *self == Form::Value
    }
}

/// The steering angle sensor a bus carries: its message, rate and step.
#[derive(Clone, Debug, PartialEq)]
pub struct SteerSensor {
    pub message: String,
    pub rate_hz: f64,
    /// The smallest angle step the message resolves (deg).
    pub step_deg: f64,
}

/// Parses a hex payload of at most `max` bytes.
pub fn parse_hex(text: &str, max: usize) -> anyhow::Result<Vec<u8>> {
    let t: String = text.chars().filter(|c| !c.is_whitespace()).collect();
    if !t.len().is_multiple_of(2) || !t.chars().all(|c| c.is_ascii_hexdigit()) {
        bail!("payload `{text}`: not an even number of hex digits");
    }
    let bytes: Vec<u8> = (0..t.len() / 2)
        .map(|i| u8::from_str_radix(&t[2 * i..2 * i + 2], 16).unwrap_or(0))
        .collect();
    if bytes.len() > max {
        bail!(
            "payload `{text}`: {} bytes, more than the message's {max}",
            bytes.len()
        );
    }
    Ok(bytes)
}

fn check_period(what: &str, period_ms: f64) -> anyhow::Result<()> {
    if !(period_ms.is_finite() && period_ms > 0.0 && period_ms <= 60_000.0) {
        bail!("{what}: period_ms must be in (0, 60000] (got {period_ms})");
    }
    Ok(())
}

fn check_jitter(what: &str, jitter_ms: Option<f64>) -> anyhow::Result<()> {
    if let Some(j) = jitter_ms {
        if !(j.is_finite() && j >= 0.0) {
            bail!("{what}: jitter_ms must be a number >= 0 (got {j})");
        }
    }
    Ok(())
}

impl BusSpec {
    pub fn from_toml_str(text: &str) -> anyhow::Result<BusSpec> {
        let b: BusSpec = toml::from_str(text)?;
        b.validate()?;
        Ok(b)
    }

    pub fn load(path: &Path) -> anyhow::Result<BusSpec> {
        let text = std::fs::read_to_string(path)
            .with_context(|| format!("cannot read bus description {}", path.display()))?;
        BusSpec::from_toml_str(&text).with_context(|| format!("in {}", path.display()))
    }

    /// The checks serde cannot express (those that need the DBC are in
    /// [`BusSpec::check_against`]).
    pub fn validate(&self) -> anyhow::Result<()> {
        let mut seen = BTreeSet::new();
        for (i, m) in self.messages.iter().enumerate() {
            if !seen.insert(m.name.as_str()) {
                bail!("message[{i}]: `{}` is listed twice", m.name);
            }
            let what = format!("message[{i}] `{}`", m.name);
            check_period(&what, m.period_ms)?;
            check_jitter(&what, m.jitter_ms)?;
            if let Some(p) = &m.payload {
                parse_hex(p, 8).with_context(|| what.clone())?;
            }
            if let Some(c) = &m.counter {
                let n = c.signals().len();
                if !(1..=4).contains(&n) {
                    bail!("{what}: counter: 1 to 4 signals (got {n})");
                }
            }
            for (k, f) in m.fields.iter().enumerate() {
                f.validate()
                    .with_context(|| format!("{what}: fields[{k}] `{}`", f.signal))?;
            }
        }
        let mut ids = BTreeSet::new();
        for (i, r) in self.raw.iter().enumerate() {
            let what = format!("raw[{i}] 0x{:X}", r.id);
            let max_id = if r.extended { 0x1FFF_FFFF } else { 0x7FF };
            if r.id > max_id {
                bail!("{what}: ID above 0x{max_id:X}");
            }
            if !ids.insert((r.id, r.extended)) {
                bail!("{what}: listed twice");
            }
            if r.dlc > 8 {
                bail!("{what}: dlc must be 0 to 8 (got {})", r.dlc);
            }
            check_period(&what, r.period_ms)?;
            check_jitter(&what, r.jitter_ms)?;
            if let Some(p) = &r.payload {
                parse_hex(p, r.dlc).with_context(|| what.clone())?;
            }
        }
        Ok(())
    }

    /// Every message exists in `db`; returns (frame id, extended, DLC, period ms) per message
    /// in file order.
    pub fn resolve(&self, db: &Database) -> anyhow::Result<Vec<(u32, bool, usize, f64)>> {
        self.messages
            .iter()
            .map(|m| {
                let i = db
                    .message_by_name(&m.name)
                    .with_context(|| format!("bus message `{}` is not in the DBC", m.name))?;
                let msg = &db.messages()[i];
                Ok((msg.id, msg.extended, msg.size_bytes, m.period_ms))
            })
            .collect()
    }

    /// Every message, signal and counter exists in `db` and fits; every checksum can protect
    /// its message; no raw message takes an ID the DBC describes or another raw message uses.
    pub fn check_against(&self, db: &Database) -> anyhow::Result<()> {
        let mut ids = BTreeSet::new();
        for m in &self.messages {
            let i = db
                .message_by_name(&m.name)
                .with_context(|| format!("bus message `{}` is not in the DBC", m.name))?;
            let msg = &db.messages()[i];
            let what = format!("bus message `{}`", m.name);
            if msg.size_bytes > 8 {
                bail!(
                    "{what}: {} bytes; only classic CAN is emulated",
                    msg.size_bytes
                );
            }
            if !ids.insert((msg.id, msg.extended)) {
                bail!("{what}: its ID 0x{:X} is listed twice", msg.id);
            }
            if let Some(p) = &m.payload {
                parse_hex(p, msg.size_bytes).with_context(|| what.clone())?;
            }
            let sig = |name: &str| -> anyhow::Result<&Signal> {
                let k = msg.signal_by_name(name).with_context(|| {
                    format!("{what}: signal `{name}` is not in the DBC message")
                })?;
                let s = &msg.signals[k];
                if s.multiplexer.is_some() {
                    bail!("{what}: signal `{name}` is multiplexed; not supported");
                }
                if s.needed_len() > msg.size_bytes {
                    bail!("{what}: signal `{name}` does not fit the message");
                }
                Ok(s)
            };
            if let Some(c) = &m.counter {
                let mut bits = 0u32;
                for name in c.signals() {
                    let s = sig(name)?;
                    if s.kind != crate::dbc::ValueKind::Unsigned {
                        bail!("{what}: counter signal `{name}` is not an unsigned integer");
                    }
                    bits += u32::from(s.size);
                }
                if bits > 32 {
                    bail!("{what}: counter of {bits} bits; at most 32");
                }
                if let Some(max) = m.counter_max {
                    if max == 0 || max >= 1u64 << bits {
                        bail!("{what}: counter_max {max} does not fit {bits} bits");
                    }
                }
            }
            for f in &m.fields {
                let s = sig(&f.signal)?;
                if matches!(
                    s.kind,
                    crate::dbc::ValueKind::Float32 | crate::dbc::ValueKind::Float64
                ) && matches!(f.form, Form::Coarse | Form::Remainder)
                {
                    bail!(
                        "{what}: `{}`: coarse/remainder need an integer signal",
                        f.signal
                    );
                }
            }
            if let Some(k) = m.checksum {
                if !k.supports(msg.id) {
                    bail!(
                        "{what}: checksum {k:?} is not known for 0x{:X} (no data-ID bytes or \
                         layout)",
                        msg.id
                    );
                }
                if msg.size_bytes < 2 {
                    bail!("{what}: too short for a checksum");
                }
            }
        }
        for r in &self.raw {
            if db.message_index(r.id, r.extended).is_some() {
                bail!(
                    "raw 0x{:X}: the DBC describes this ID; list it as a [[message]]",
                    r.id
                );
            }
            if !ids.insert((r.id, r.extended)) {
                bail!("raw 0x{:X}: listed twice", r.id);
            }
            if let Some(k) = r.checksum {
                if !k.supports(r.id) || r.dlc < 2 {
                    bail!("raw 0x{:X}: checksum {k:?} cannot protect it", r.id);
                }
            }
        }
        Ok(())
    }

    /// The steering angle sensor: the first message (in file order) with a `steer_angle_deg`
    /// field other than a sign bit; its rate is 1000 / `period_ms`, its step the finest the
    /// message resolves (a `coarse` field's `fine_step`, otherwise the DBC factor over
    /// `scale`). `None` when no message carries the angle.
    pub fn steer_sensor(&self, db: &Database) -> anyhow::Result<Option<SteerSensor>> {
        for m in &self.messages {
            let mut step = f64::INFINITY;
            for f in &m.fields {
                if f.quantity != Quantity::SteerAngleDeg || f.form == Form::Sign {
                    continue;
                }
                let i = db
                    .message_by_name(&m.name)
                    .with_context(|| format!("bus message `{}` is not in the DBC", m.name))?;
                let msg = &db.messages()[i];
                let k = msg.signal_by_name(&f.signal).with_context(|| {
                    format!("bus message `{}`: no signal `{}`", m.name, f.signal)
                })?;
                let s = match f.form {
                    Form::Coarse => f.fine_step.unwrap_or(f64::INFINITY),
                    _ => msg.signals[k].factor.abs(),
                } / f.scale.abs();
                step = step.min(s);
            }
            if step.is_finite() {
                return Ok(Some(SteerSensor {
                    message: m.name.clone(),
                    rate_hz: 1000.0 / m.period_ms,
                    step_deg: step,
                }));
            }
        }
        Ok(None)
    }
}

impl BusField {
    fn validate(&self) -> anyhow::Result<()> {
        if !(self.scale.is_finite() && self.scale != 0.0) {
            bail!(
                "scale must be a finite, non-zero number (got {})",
                self.scale
            );
        }
        if !self.offset.is_finite() {
            bail!("offset must be finite (got {})", self.offset);
        }
        match (self.quantity, self.value) {
            (Quantity::Constant, None) => bail!("a constant needs `value`"),
            (Quantity::Constant, Some(v)) if !v.is_finite() => {
                bail!("value must be finite (got {v})")
            }
            (q, Some(_)) if q != Quantity::Constant => {
                bail!("`value` is only for quantity = \"constant\"")
            }
            _ => {}
        }
        let step_ok = |s: Option<f64>| s.is_some_and(|s| s.is_finite() && s > 0.0);
        match self.form {
            Form::Coarse if !step_ok(self.fine_step) => {
                bail!("form = \"coarse\" needs fine_step > 0")
            }
            Form::Remainder if !step_ok(self.coarse_step) => {
                bail!("form = \"remainder\" needs coarse_step > 0")
            }
            _ => {}
        }
        if self.fine_step.is_some() && self.form != Form::Coarse {
            bail!("fine_step is only for form = \"coarse\"");
        }
        if self.coarse_step.is_some() && self.form != Form::Remainder {
            bail!("coarse_step is only for form = \"remainder\"");
        }
        if let Some([lo, hi]) = self.range {
            if !(lo.is_finite() && hi.is_finite() && lo <= hi) {
                bail!("range must be [low, high] with low <= high (got [{lo}, {hi}])");
            }
        }
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_full_message_parses_and_bad_keys_are_named() {
        let b = BusSpec::from_toml_str(
            r#"
            [[message]]
            name = "A"
            period_ms = 10
            counter = ["LO", "HI"]
            checksum = "honda"
            fields = [
              { signal = "X", quantity = "steer_angle_deg", form = "coarse", fine_step = 0.1 },
              { signal = "Y", quantity = "constant", value = 1 },
            ]
            [[raw]]
            id = 0x123
            dlc = 2
            period_ms = 1000
            payload = "0102"
            "#,
        )
        .unwrap();
        assert_eq!(
            b.messages[0].counter.as_ref().unwrap().signals(),
            ["LO", "HI"]
        );
        assert_eq!(b.raw[0].id, 0x123);
        for (bad, key) in [
            (
                "fields = [{ signal = \"X\", quantity = \"speed\" }]",
                "speed",
            ),
            (
                "fields = [{ signal = \"X\", quantity = \"constant\" }]",
                "value",
            ),
            (
                "fields = [{ signal = \"X\", quantity = \"steer_angle_deg\", form = \"coarse\" }]",
                "fine_step",
            ),
            ("jitter_ms = -1", "jitter_ms"),
            ("payload = \"0g\"", "hex"),
            ("counter = []", "counter"),
            ("colour = 1", "colour"),
        ] {
            let t = format!("[[message]]\nname = \"A\"\nperiod_ms = 10\n{bad}\n");
            let e = format!("{:#}", BusSpec::from_toml_str(&t).unwrap_err());
            assert!(e.contains(key), "{bad}: {e}");
        }
        let e = BusSpec::from_toml_str("message = []\n[[raw]]\nid = 1\ndlc = 9\nperiod_ms = 1")
            .unwrap_err();
        assert!(format!("{e:#}").contains("dlc"), "{e:#}");
    }

    #[test]
    fn quantity_indices_are_distinct() {
        for (i, q) in Quantity::ALL.iter().enumerate() {
            assert_eq!(q.index(), i);
        }
    }
}
