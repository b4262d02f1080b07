//! The mapping file: which DBC message and signal carries each quantity the monitor needs, how to
//! compose it, in what unit it arrives, and how its messages are protected (timeout, counter,
//! checksum). TOML, one file per vehicle profile (`config/vehicles/<name>/mapping.toml`, [`crate::profile`]).
//!
//! This module is the file format and its checks only: names are resolved against a DBC, and
//! frames are interpreted, by [`crate::signals::Mapper`]. Units are converted to SI here, once, by
//! the `to_si` functions of the unit enums (the quantities the monitor needs are MODEL.md §8's
//! steering-wheel angle δ_sw, the braking state of §6, and the vehicle speed v).
//!
//! ```toml
//! name = "VW MQB (opendbc vw_mqb.dbc)"
//! default_timeout_ms = 200
//!
//! [steer_angle]                  # required: steering-wheel angle
//! message = "LWI_01"
//! signal = "LWI_Lenkradwinkel"   # magnitude ...
//! sign_signal = "LWI_VZ_Lenkradwinkel"   # ... and a separate sign bit (1 = negative)
//! unit = "deg"
//!
//! [speed]                        # required: one speed signal, or the mean of wheel speeds
//! message = "ESP_19"
//! wheel_signals = ["ESP_VL_Radgeschw_02", "ESP_VR_Radgeschw_02"]
//! unit = "km/h"
//!
//! [brake_pressure]               # at least one of brake_pressure / brake_pressed
//! message = "ESP_05"
//! signal = "ESP_Bremsdruck"
//! unit = "bar"
//!
//! [yaw_rate]                     # optional, for `shimmy doctor`'s steering-sign check
//! message = "ESP_02"
//! signal = "ESP_Gierrate"
//! sign_signal = "ESP_VZ_Gierrate"
//! unit = "deg/s"
//!
//! [steer_torque]                 # optional: the driver's (torsion-bar) torque
//! message = "LH_EPS_03"
//! signal = "EPS_Lenkmoment"
//! sign_signal = "EPS_VZ_Lenkmoment"
//! unit = "cNm"
//!
//! [messages.LWI_01]              # optional per-message protection
//! timeout_ms = 50
//! checksum = "vw_mqb"
//! counter_signal = "COUNTER"
//! ```
//!
//! Every table rejects unknown keys, so a typo fails loudly with the key named.
//!
//! Signs and scales: each signed quantity is positive in the monitor's convention (steering
//! angle and yaw rate counter-clockwise seen from above, i.e. to the left; accelerations forward
//! and to the left). `invert = true` flips a signal whose DBC counts the other way, and
//! `scale` (default 1) multiplies the DBC's physical value before the unit conversion, for a
//! DBC whose factor is wrong for this car. `shimmy doctor` measures both on a log.

use std::collections::BTreeMap;
use std::path::Path;

use anyhow::{bail, Context};
use serde::{Deserialize, Serialize};

use super::checksum::ChecksumKind;

/// A whole mapping file.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct MappingConfig {
    /// Human-readable name of the vehicle / bus.
    #[serde(default)]
    pub name: String,
    /// The DBC file this mapping was written for (informational; the monitor is told which DBC
    /// to load separately).
    #[serde(default)]
    pub dbc: Option<String>,
    /// Timeout for messages without their own `timeout_ms` (default 200 ms).
    #[serde(default = "default_timeout_ms")]
    pub default_timeout_ms: u32,
    /// Steering-wheel angle (required).
    pub steer_angle: SteerAngleMap,
    /// Vehicle speed (required).
    pub speed: SpeedMap,
    /// Brake pressure (optional; at least one of this and `brake_pressed`).
    #[serde(default)]
    pub brake_pressure: Option<PressureMap>,
    /// Brake pedal / switch flag (optional; at least one of this and `brake_pressure`).
    #[serde(default)]
    pub brake_pressed: Option<FlagMap>,
    /// Longitudinal acceleration (optional).
    #[serde(default)]
    pub accel: Option<AccelMap>,
    /// Yaw rate (optional; not used by the estimate, checked against the steering angle by
    /// `shimmy doctor`).
    #[serde(default)]
    pub yaw_rate: Option<YawRateMap>,
    /// Lateral acceleration, positive to the left (optional; used by `shimmy doctor` only).
    #[serde(default)]
    pub lat_accel: Option<AccelMap>,
    /// The driver's steering torque as the EPS torque sensor (torsion bar) reads it, positive
    /// when the driver turns the rim to the left (optional).
    #[serde(default)]
    pub steer_torque: Option<TorqueMap>,
    /// Per-message protection, keyed by DBC message name.
    #[serde(default)]
    pub messages: BTreeMap<String, MessageRules>,
}

fn default_timeout_ms() -> u32 {
    200
}

/// Steering-wheel angle: `signal` (+ `fraction_signal`), negated when `sign_signal` is non-zero,
/// negated again when `invert`. Positive is counter-clockwise (left) after these rules.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct SteerAngleMap {
    pub message: String,
    pub signal: String,
    pub unit: AngleUnit,
    /// A finer part added to `signal` (Toyota `STEER_FRACTION`), same message and unit.
    #[serde(default)]
    pub fraction_signal: Option<String>,
    /// A separate sign bit (VW `LWI_VZ_Lenkradwinkel`): non-zero means negative.
    #[serde(default)]
    pub sign_signal: Option<String>,
    /// Flip the sign (for DBCs whose positive direction is clockwise).
    #[serde(default)]
    pub invert: bool,
    /// Multiplies the angle (`signal` + `fraction_signal`) before the unit conversion.
    #[serde(default = "one", skip_serializing_if = "is_one")]
    pub scale: f64,
}

fn one() -> f64 {
    1.0
}

fn is_one(x: &f64) -> bool {
    *x == 1.0
}

/// A signed quantity in one signal: `signal`, negated when `sign_signal` is non-zero, negated
/// again when `invert`, times `scale`, in `unit`.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct SignedMap<U> {
    pub message: String,
    pub signal: String,
    pub unit: U,
    /// A separate sign bit (VW `ESP_VZ_Gierrate`, `EPS_VZ_Lenkmoment`): non-zero means
    /// negative.
    #[serde(default)]
    pub sign_signal: Option<String>,
    #[serde(default)]
    pub invert: bool,
    #[serde(default = "one", skip_serializing_if = "is_one")]
    pub scale: f64,
}

/// Yaw rate ([`SignedMap`]). Positive is counter-clockwise seen from above (turning left) after
/// the sign rules, like the steering angle.
pub type YawRateMap = SignedMap<RateUnit>;

/// Steering torque ([`SignedMap`]). Positive is the driver turning the rim to the left (the
/// torsion bar twisted with the rim ahead of the pinion, counter-clockwise) after the sign
/// rules. Many DBCs give the torque in sensor counts without a unit (Toyota's
/// `STEER_TORQUE_DRIVER`): `scale` then holds N·m per count, and `unit = "Nm"`.
pub type TorqueMap = SignedMap<TorqueUnit>;

/// Vehicle speed: either one `signal`, or the mean of `wheel_signals` (all in `message`).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct SpeedMap {
    pub message: String,
    #[serde(default)]
    pub signal: Option<String>,
    #[serde(default)]
    pub wheel_signals: Vec<String>,
    pub unit: SpeedUnit,
}

/// A pressure signal.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct PressureMap {
    pub message: String,
    pub signal: String,
    pub unit: PressureUnit,
}

/// A boolean flag: true when the signal's value is non-zero (zero when `invert`).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct FlagMap {
    pub message: String,
    pub signal: String,
    #[serde(default)]
    pub invert: bool,
}

/// An acceleration: longitudinal positive forward (braking negative), lateral positive to the
/// left, after `invert` and `scale`.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct AccelMap {
    pub message: String,
    pub signal: String,
    pub unit: AccelUnit,
    #[serde(default)]
    pub invert: bool,
    /// Multiplies the DBC's value before the unit conversion.
    #[serde(default = "one", skip_serializing_if = "is_one")]
    pub scale: f64,
}

/// How one message is protected.
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct MessageRules {
    /// The message is invalid once no good frame has arrived for this long.
    #[serde(default)]
    pub timeout_ms: Option<u32>,
    /// Checksum the frames carry (its position is fixed by the kind).
    #[serde(default)]
    pub checksum: Option<ChecksumKind>,
    /// Rolling counter signal (its width comes from the DBC).
    #[serde(default)]
    pub counter_signal: Option<String>,
}

/// Angle units.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
pub enum AngleUnit {
    #[serde(rename = "deg")]
    Deg,
    #[serde(rename = "rad")]
    Rad,
}

impl AngleUnit {
    pub fn to_si(self, v: f64) -> f64 {
        match self {
            AngleUnit::Deg => v.to_radians(),
            AngleUnit::Rad => v,
        }
    }
}

/// Angular rate units.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
pub enum RateUnit {
    #[serde(rename = "deg/s")]
    DegPerS,
    #[serde(rename = "rad/s")]
    RadPerS,
}

impl RateUnit {
    pub fn to_si(self, v: f64) -> f64 {
        match self {
            RateUnit::DegPerS => v.to_radians(),
            RateUnit::RadPerS => v,
        }
    }
}

/// Torque units.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
pub enum TorqueUnit {
    #[serde(rename = "Nm", alias = "N.m", alias = "N*m")]
    Nm,
    /// Centinewton-metres (VW's `Unit_centiNewtoMeter`).
    #[serde(rename = "cNm")]
    CNm,
}

impl TorqueUnit {
    pub fn to_si(self, v: f64) -> f64 {
        match self {
            TorqueUnit::Nm => v,
            TorqueUnit::CNm => v * 0.01,
        }
    }
}

/// Speed units.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
pub enum SpeedUnit {
    #[serde(rename = "km/h", alias = "kmh", alias = "kph")]
    Kmh,
    #[serde(rename = "m/s", alias = "mps")]
    Mps,
    #[serde(rename = "mph")]
    Mph,
}

impl SpeedUnit {
    pub fn to_si(self, v: f64) -> f64 {
        match self {
            SpeedUnit::Kmh => v / 3.6,
            SpeedUnit::Mps => v,
            SpeedUnit::Mph => v * 0.447_04,
        }
    }
}

/// Pressure units.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
pub enum PressureUnit {
    #[serde(rename = "bar")]
    Bar,
    #[serde(rename = "Pa")]
    Pa,
    #[serde(rename = "kPa")]
    KPa,
}

impl PressureUnit {
    pub fn to_si(self, v: f64) -> f64 {
        match self {
            PressureUnit::Bar => v * 1e5,
            PressureUnit::Pa => v,
            PressureUnit::KPa => v * 1e3,
        }
    }
}

/// Standard gravity (m/s²): the unit "g".
pub const STANDARD_GRAVITY_MPS2: f64 = 9.806_65;

/// Acceleration units.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
pub enum AccelUnit {
    #[serde(rename = "m/s^2", alias = "m/s2", alias = "mps2")]
    Mps2,
    /// Standard gravity, 9.80665 m/s².
    #[serde(rename = "g")]
    G,
}

impl AccelUnit {
    pub fn to_si(self, v: f64) -> f64 {
        match self {
            AccelUnit::Mps2 => v,
            AccelUnit::G => v * STANDARD_GRAVITY_MPS2,
        }
    }
}

impl MappingConfig {
    /// Parse and check a mapping from TOML text. Errors name the offending key.
    pub fn from_toml_str(text: &str) -> anyhow::Result<MappingConfig> {
        let cfg: MappingConfig = toml::from_str(text).map_err(|e| anyhow::anyhow!("{e}"))?;
        cfg.validate()?;
        Ok(cfg)
    }

    /// Read, parse and check a mapping file; errors name the file and the offending key.
    pub fn from_toml_file(path: impl AsRef<Path>) -> anyhow::Result<MappingConfig> {
        let path = path.as_ref();
        let text = std::fs::read_to_string(path)
            .with_context(|| format!("reading mapping {}", path.display()))?;
        MappingConfig::from_toml_str(&text)
            .with_context(|| format!("invalid mapping {}", path.display()))
    }

    /// Checks that serde cannot express (the file parsed, but does it make sense?).
    pub fn validate(&self) -> anyhow::Result<()> {
        let s = &self.speed;
        match (&s.signal, s.wheel_signals.is_empty()) {
            (Some(_), false) => {
                bail!("speed: set either `signal` or `wheel_signals`, not both")
            }
            (None, true) => bail!("speed: set `signal` or `wheel_signals`"),
            _ => {}
        }
        if s.wheel_signals.len() > 4 {
            bail!(
                "speed.wheel_signals: at most 4 wheel speeds, got {}",
                s.wheel_signals.len()
            );
        }
        if self.brake_pressure.is_none() && self.brake_pressed.is_none() {
            bail!("brake: set `[brake_pressure]` and/or `[brake_pressed]`");
        }
        if self.default_timeout_ms == 0 {
            bail!("default_timeout_ms: must be greater than 0");
        }
        let scales = [
            ("steer_angle", Some(self.steer_angle.scale)),
            ("accel", self.accel.as_ref().map(|a| a.scale)),
            ("yaw_rate", self.yaw_rate.as_ref().map(|a| a.scale)),
            ("lat_accel", self.lat_accel.as_ref().map(|a| a.scale)),
            ("steer_torque", self.steer_torque.as_ref().map(|a| a.scale)),
        ];
        for (key, scale) in scales {
            if let Some(k) = scale {
                if !(k.is_finite() && k > 0.0) {
                    bail!("{key}.scale: must be a positive number (use `invert` for the sign), got {k}");
                }
            }
        }
        let used = self.used_messages();
        for (name, rules) in &self.messages {
            if rules.timeout_ms == Some(0) {
                bail!("messages.{name}.timeout_ms: must be greater than 0");
            }
            if !used.contains(&name.as_str()) {
                bail!(
                    "messages.{name}: no quantity uses this message (used: {})",
                    used.join(", ")
                );
            }
        }
        Ok(())
    }

    /// Names of the messages the quantities read, in order of first use, without repeats.
    pub fn used_messages(&self) -> Vec<&str> {
        let mut v: Vec<&str> = Vec::new();
        let all = [
            Some(self.steer_angle.message.as_str()),
            Some(self.speed.message.as_str()),
            self.brake_pressure.as_ref().map(|b| b.message.as_str()),
            self.brake_pressed.as_ref().map(|b| b.message.as_str()),
            self.accel.as_ref().map(|a| a.message.as_str()),
            self.yaw_rate.as_ref().map(|a| a.message.as_str()),
            self.lat_accel.as_ref().map(|a| a.message.as_str()),
            self.steer_torque.as_ref().map(|a| a.message.as_str()),
        ];
        for m in all.into_iter().flatten() {
            if !v.contains(&m) {
                v.push(m);
            }
        }
        v
    }

    /// The rules for `message` (defaults when the file has no `[messages.NAME]` table).
    pub fn rules(&self, message: &str) -> MessageRules {
        self.messages.get(message).cloned().unwrap_or_default()
    }

    /// Timeout of `message` in milliseconds.
    pub fn timeout_ms(&self, message: &str) -> u32 {
        self.messages
            .get(message)
            .and_then(|r| r.timeout_ms)
            .unwrap_or(self.default_timeout_ms)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    const MINIMAL: &str = r#"
        [steer_angle]
        message = "SAS"
        signal = "ANGLE"
        unit = "deg"
        [speed]
        message = "VEH"
        signal = "SPEED"
        unit = "km/h"
        [brake_pressed]
        message = "BRK"
        signal = "SWITCH"
    "#;

    #[test]
    fn minimal_file_parses_with_defaults() {
        let c = MappingConfig::from_toml_str(MINIMAL).unwrap();
        assert_eq!(c.default_timeout_ms, 200);
        assert_eq!(c.timeout_ms("SAS"), 200);
        assert_eq!(c.used_messages(), vec!["SAS", "VEH", "BRK"]);
        assert!(c.accel.is_none());
    }

    #[test]
    fn unknown_key_is_named() {
        let text = MINIMAL.replace("unit = \"deg\"", "unit = \"deg\"\nfracton_signal = \"X\"");
        let e = format!("{:#}", MappingConfig::from_toml_str(&text).unwrap_err());
        assert!(e.contains("fracton_signal"), "{e}");
    }

    #[test]
    fn bad_unit_is_named() {
        let text = MINIMAL.replace("\"km/h\"", "\"furlongs\"");
        let e = format!("{:#}", MappingConfig::from_toml_str(&text).unwrap_err());
        assert!(e.contains("furlongs") && e.contains("km/h"), "{e}");
    }

    #[test]
    fn missing_required_table_is_named() {
        let text = MINIMAL.replace("[speed]", "[speeed]");
        let e = format!("{:#}", MappingConfig::from_toml_str(&text).unwrap_err());
        assert!(e.contains("speeed") || e.contains("speed"), "{e}");
    }

    #[test]
    fn semantic_errors_name_the_key() {
        let both = MINIMAL.replace(
            "signal = \"SPEED\"",
            "signal = \"SPEED\"\nwheel_signals = [\"FL\"]",
        );
        let e = format!("{:#}", MappingConfig::from_toml_str(&both).unwrap_err());
        assert!(e.contains("speed") && e.contains("not both"), "{e}");

        let no_brake = MINIMAL.replace("[brake_pressed]", "[accel]\nunit = \"g\"");
        let e = format!("{:#}", MappingConfig::from_toml_str(&no_brake).unwrap_err());
        assert!(e.contains("brake"), "{e}");

        let stray = format!("{MINIMAL}\n[messages.NOPE]\ntimeout_ms = 10\n");
        let e = format!("{:#}", MappingConfig::from_toml_str(&stray).unwrap_err());
        assert!(e.contains("messages.NOPE"), "{e}");

        let zero = format!("{MINIMAL}\n[messages.SAS]\ntimeout_ms = 0\n");
        let e = format!("{:#}", MappingConfig::from_toml_str(&zero).unwrap_err());
        assert!(e.contains("messages.SAS.timeout_ms"), "{e}");

        let bad_ck = format!("{MINIMAL}\n[messages.SAS]\nchecksum = \"crc99\"\n");
        let e = format!("{:#}", MappingConfig::from_toml_str(&bad_ck).unwrap_err());
        assert!(e.contains("crc99") && e.contains("toyota"), "{e}");
    }

    #[test]
    fn unit_conversions_to_si() {
        assert!((AngleUnit::Deg.to_si(180.0) - std::f64::consts::PI).abs() < 1e-12);
        assert!((SpeedUnit::Kmh.to_si(36.0) - 10.0).abs() < 1e-12);
        assert!((SpeedUnit::Mph.to_si(1.0) - 0.44704).abs() < 1e-12);
        assert_eq!(PressureUnit::Bar.to_si(2.0), 2e5);
        assert_eq!(PressureUnit::KPa.to_si(2.0), 2e3);
        assert!((AccelUnit::G.to_si(-0.5) + 4.903325).abs() < 1e-12);
        let aliases: SpeedMap =
            toml::from_str("message = \"M\"\nsignal = \"S\"\nunit = \"kph\"").unwrap();
        assert_eq!(aliases.unit, SpeedUnit::Kmh);
    }
}
