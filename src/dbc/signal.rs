//! One DBC signal: where it sits ([`Layout`]), how its bits become a raw value (unsigned,
//! signed two's complement, IEEE float/double per `SIG_VALTYPE_`) and how the raw value becomes
//! a physical one (`phys = raw * factor + offset`). Encoding is the exact inverse.
//!
//! Not here: multiplexing (which signals are present in a given frame is the
//! [`Message`](super::Message)'s business) and any meaning of the value.

use super::bits::{ByteOrder, Layout};

/// How the raw bits are to be read.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub enum ValueKind {
    Unsigned,
    /// Two's complement of `size` bits.
    Signed,
    /// IEEE 754 single (`SIG_VALTYPE_ … : 1`, 32 bits).
    Float32,
    /// IEEE 754 double (`SIG_VALTYPE_ … : 2`, 64 bits).
    Float64,
}

/// A signal's raw (unscaled) value.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum RawValue {
    Unsigned(u64),
    Signed(i64),
    F32(f32),
    F64(f64),
}

impl RawValue {
    /// The value as `f64` (exact for integers up to 2^53).
    #[inline]
    pub fn as_f64(self) -> f64 {
        match self {
            RawValue::Unsigned(v) => v as f64,
            RawValue::Signed(v) => v as f64,
            RawValue::F32(v) => v as f64,
            RawValue::F64(v) => v,
        }
    }

    /// The value as a non-negative integer, if it is one (multiplexer switch values).
    #[inline]
    pub fn as_u64(self) -> Option<u64> {
        match self {
            RawValue::Unsigned(v) => Some(v),
            RawValue::Signed(v) => u64::try_from(v).ok(),
            RawValue::F32(_) | RawValue::F64(_) => None,
        }
    }
}

impl std::fmt::Display for RawValue {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self {
            RawValue::Unsigned(v) => write!(f, "{v}"),
            RawValue::Signed(v) => write!(f, "{v}"),
            RawValue::F32(v) => write!(f, "{v}"),
            RawValue::F64(v) => write!(f, "{v}"),
        }
    }
}

/// Multiplexing condition of a signal: present only while signal `switch` of the same message
/// has a raw value inside one of `ranges` (inclusive). Plain `mN` signals get the range `N-N`
/// on the message's `M` signal; `SG_MUL_VAL_` gives explicit switches and ranges.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct MuxCondition {
    /// Index of the multiplexer signal in [`Message::signals`](super::Message::signals).
    pub switch: usize,
    /// Inclusive raw value ranges.
    pub ranges: Vec<(u64, u64)>,
}

impl MuxCondition {
    #[inline]
    pub fn matches(&self, value: u64) -> bool {
        self.ranges
            .iter()
            .any(|&(lo, hi)| lo <= value && value <= hi)
    }
}

/// Why a value could not be encoded.
#[derive(Clone, Debug, PartialEq, thiserror::Error)]
pub enum EncodeError {
    #[error("signal {signal}: payload of {len} bytes is too short (needs {needed})")]
    PayloadTooShort {
        signal: String,
        len: usize,
        needed: usize,
    },
    #[error("signal {signal}: raw value {raw} does not fit {size} bits ({kind:?})")]
    RawOutOfRange {
        signal: String,
        raw: String,
        size: u8,
        kind: ValueKind,
    },
    #[error("signal {signal}: value {value} is not a finite number")]
    NotFinite { signal: String, value: f64 },
    #[error("signal {signal}: raw value kind {given:?} does not match the signal's {kind:?}")]
    KindMismatch {
        signal: String,
        given: &'static str,
        kind: ValueKind,
    },
}

/// One signal of a message.
#[derive(Clone, Debug, PartialEq)]
pub struct Signal {
    pub name: String,
    /// DBC start bit (LSB for Intel, MSB for Motorola; see [`super::bits`]).
    pub start_bit: u16,
    /// Size in bits, 1..=64.
    pub size: u8,
    pub byte_order: ByteOrder,
    pub kind: ValueKind,
    pub factor: f64,
    pub offset: f64,
    pub min: f64,
    pub max: f64,
    pub unit: String,
    pub receivers: Vec<String>,
    pub comment: Option<String>,
    /// Value table (`VAL_`): raw value → label. Labels are informational; decoded output keeps
    /// numbers.
    pub choices: Vec<(i64, String)>,
    /// This signal selects which multiplexed signals are present (`M` or `mNM`).
    pub is_multiplexer: bool,
    /// Present only under this condition (`mN`, `SG_MUL_VAL_`); `None` = always present.
    pub multiplexer: Option<MuxCondition>,
    /// DBC line number of the `SG_` line.
    pub line: usize,
    pub(crate) layout: Layout,
}

impl Signal {
    /// Build a signal; fails when the size/position/kind combination is unusable.
    #[allow(clippy::too_many_arguments)]
    pub fn new(
        name: &str,
        start_bit: u64,
        size: u64,
        byte_order: ByteOrder,
        kind: ValueKind,
        factor: f64,
        offset: f64,
    ) -> Result<Signal, String> {
        let layout = Layout::new(start_bit, size, byte_order).map_err(|e| e.to_string())?;
        match (kind, size) {
            (ValueKind::Float32, 32) | (ValueKind::Float64, 64) => {}
            (ValueKind::Float32, _) | (ValueKind::Float64, _) => {
                return Err(format!(
                    "{kind:?} signal must be {} bits, is {size}",
                    if kind == ValueKind::Float32 { 32 } else { 64 }
                ))
            }
            _ => {}
        }
        if !factor.is_finite() || !offset.is_finite() {
            return Err(format!("factor {factor} / offset {offset} not finite"));
        }
        Ok(Signal {
            name: name.to_string(),
            start_bit: start_bit as u16,
            size: size as u8,
            byte_order,
            kind,
            factor,
            offset,
            min: 0.0,
            max: 0.0,
            unit: String::new(),
            receivers: Vec::new(),
            comment: None,
            choices: Vec::new(),
            is_multiplexer: false,
            multiplexer: None,
            line: 0,
            layout,
        })
    }

    /// Change how the raw bits are read (`SIG_VALTYPE_`); fails if the size does not fit.
    pub fn set_kind(&mut self, kind: ValueKind) -> Result<(), String> {
        let s = Signal::new(
            &self.name,
            self.start_bit as u64,
            self.size as u64,
            self.byte_order,
            kind,
            self.factor,
            self.offset,
        )?;
        self.kind = s.kind;
        Ok(())
    }

    /// Payload length (bytes) the signal needs.
    #[inline]
    pub fn needed_len(&self) -> usize {
        self.layout.needed_len()
    }

    /// The raw bits, without interpretation; `None` if the payload is too short.
    #[inline]
    pub fn raw_bits(&self, data: &[u8]) -> Option<u64> {
        self.layout.extract(data)
    }

    /// Raw value; `None` when the signal does not fit the payload.
    #[inline]
    pub fn raw(&self, data: &[u8]) -> Option<RawValue> {
        let bits = self.layout.extract(data)?;
        Some(self.interpret(bits))
    }

    #[inline]
    fn interpret(&self, bits: u64) -> RawValue {
        match self.kind {
            ValueKind::Unsigned => RawValue::Unsigned(bits),
            ValueKind::Signed => {
                let unused = 64 - self.size as u32;
                RawValue::Signed(((bits << unused) as i64) >> unused)
            }
            ValueKind::Float32 => RawValue::F32(f32::from_bits(bits as u32)),
            ValueKind::Float64 => RawValue::F64(f64::from_bits(bits)),
        }
    }

    /// Physical value of a raw value.
    #[inline]
    pub fn scale(&self, raw: RawValue) -> f64 {
        raw.as_f64() * self.factor + self.offset
    }

    /// The lowest and highest physical value the signal's bits can carry (`factor` × raw +
    /// `offset` over the raw range of `size` bits; a negative factor swaps the ends). Floats:
    /// unbounded.
    pub fn phys_range(&self) -> (f64, f64) {
        let n = i32::from(self.size);
        let (raw_lo, raw_hi) = match self.kind {
            ValueKind::Unsigned => (0.0, 2f64.powi(n) - 1.0),
            ValueKind::Signed => (-(2f64.powi(n - 1)), 2f64.powi(n - 1) - 1.0),
            ValueKind::Float32 | ValueKind::Float64 => return (f64::NEG_INFINITY, f64::INFINITY),
        };
        let (a, b) = (
            raw_lo * self.factor + self.offset,
            raw_hi * self.factor + self.offset,
        );
        (a.min(b), a.max(b))
    }

    /// Physical value; `None` when the signal does not fit the payload.
    #[inline]
    pub fn phys(&self, data: &[u8]) -> Option<f64> {
        self.raw(data).map(|r| self.scale(r))
    }

    /// Label of a raw value in the signal's value table.
    pub fn choice(&self, raw: RawValue) -> Option<&str> {
        let v = match raw {
            RawValue::Unsigned(u) => i64::try_from(u).ok()?,
            RawValue::Signed(s) => s,
            _ => return None,
        };
        self.choices
            .iter()
            .find(|(k, _)| *k == v)
            .map(|(_, s)| s.as_str())
    }

    /// Write a raw value. Integers must fit the signal's size and signedness (a non-negative
    /// `Signed` into an unsigned signal and an in-range `Unsigned` into a signed one are
    /// accepted); floats must match the signal's float kind.
    pub fn encode_raw(&self, raw: RawValue, data: &mut [u8]) -> Result<(), EncodeError> {
        let out_of_range = || EncodeError::RawOutOfRange {
            signal: self.name.clone(),
            raw: raw.to_string(),
            size: self.size,
            kind: self.kind,
        };
        let bits = match (self.kind, raw) {
            (ValueKind::Unsigned, RawValue::Unsigned(u)) => {
                if u & !self.layout.mask != 0 {
                    return Err(out_of_range());
                }
                u
            }
            (ValueKind::Unsigned, RawValue::Signed(s)) => {
                let u = u64::try_from(s).map_err(|_| out_of_range())?;
                if u & !self.layout.mask != 0 {
                    return Err(out_of_range());
                }
                u
            }
            (ValueKind::Signed, RawValue::Signed(s)) => {
                self.signed_bits(s).ok_or_else(out_of_range)?
            }
            (ValueKind::Signed, RawValue::Unsigned(u)) => {
                let s = i64::try_from(u).map_err(|_| out_of_range())?;
                self.signed_bits(s).ok_or_else(out_of_range)?
            }
            (ValueKind::Float32, RawValue::F32(f)) => f.to_bits() as u64,
            (ValueKind::Float64, RawValue::F64(f)) => f.to_bits(),
            (kind, given) => {
                return Err(EncodeError::KindMismatch {
                    signal: self.name.clone(),
                    given: match given {
                        RawValue::Unsigned(_) => "Unsigned",
                        RawValue::Signed(_) => "Signed",
                        RawValue::F32(_) => "F32",
                        RawValue::F64(_) => "F64",
                    },
                    kind,
                })
            }
        };
        if !self.layout.insert(bits, data) {
            return Err(EncodeError::PayloadTooShort {
                signal: self.name.clone(),
                len: data.len(),
                needed: self.needed_len(),
            });
        }
        Ok(())
    }

    fn signed_bits(&self, s: i64) -> Option<u64> {
        let size = self.size as u32;
        if size < 64 {
            let lo = -(1i64 << (size - 1));
            let hi = (1i64 << (size - 1)) - 1;
            if s < lo || s > hi {
                return None;
            }
        }
        Some(s as u64 & self.layout.mask)
    }

    /// Raw value for a physical value: `(value - offset) / factor`, rounded to the nearest
    /// integer for integer signals.
    pub fn phys_to_raw(&self, value: f64) -> Result<RawValue, EncodeError> {
        if !value.is_finite() {
            return Err(EncodeError::NotFinite {
                signal: self.name.clone(),
                value,
            });
        }
        let x = (value - self.offset) / self.factor;
        let out_of_range = || EncodeError::RawOutOfRange {
            signal: self.name.clone(),
            raw: format!("{x}"),
            size: self.size,
            kind: self.kind,
        };
        if !x.is_finite() {
            return Err(out_of_range());
        }
        Ok(match self.kind {
            ValueKind::Float32 => RawValue::F32(x as f32),
            ValueKind::Float64 => RawValue::F64(x),
            ValueKind::Unsigned => {
                let r = x.round();
                // 2^64 is the first value that does not fit.
                if !(0.0..18_446_744_073_709_551_616.0).contains(&r) {
                    return Err(out_of_range());
                }
                RawValue::Unsigned(r as u64)
            }
            ValueKind::Signed => {
                let r = x.round();
                if !(-9_223_372_036_854_775_808.0..9_223_372_036_854_775_808.0).contains(&r) {
                    return Err(out_of_range());
                }
                RawValue::Signed(r as i64)
            }
        })
    }

    /// Write a physical value (see [`Signal::phys_to_raw`] and [`Signal::encode_raw`]).
    pub fn encode_phys(&self, value: f64, data: &mut [u8]) -> Result<(), EncodeError> {
        let raw = self.phys_to_raw(value)?;
        self.encode_raw(raw, data)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn signed_and_negative_factor() {
        let s = Signal::new(
            "a",
            0,
            12,
            ByteOrder::LittleEndian,
            ValueKind::Signed,
            -0.5,
            1.0,
        )
        .unwrap();
        let mut d = [0u8; 2];
        s.encode_raw(RawValue::Signed(-3), &mut d).unwrap();
        assert_eq!(s.raw(&d), Some(RawValue::Signed(-3)));
        assert_eq!(s.phys(&d), Some(2.5));
        assert!(s.encode_raw(RawValue::Signed(2048), &mut d).is_err());
        s.encode_phys(-9.0, &mut d).unwrap();
        assert_eq!(s.raw(&d), Some(RawValue::Signed(20)));
    }

    #[test]
    fn float_needs_matching_size() {
        assert!(Signal::new(
            "f",
            0,
            16,
            ByteOrder::LittleEndian,
            ValueKind::Float32,
            1.0,
            0.0
        )
        .is_err());
        let s = Signal::new(
            "f",
            7,
            32,
            ByteOrder::BigEndian,
            ValueKind::Float32,
            1.0,
            0.0,
        )
        .unwrap();
        let mut d = [0u8; 4];
        s.encode_phys(1.5, &mut d).unwrap();
        assert_eq!(d, 1.5f32.to_be_bytes());
        assert_eq!(s.phys(&d), Some(1.5));
    }

    #[test]
    fn short_payload_is_reported() {
        let s = Signal::new(
            "a",
            8,
            8,
            ByteOrder::LittleEndian,
            ValueKind::Unsigned,
            1.0,
            0.0,
        )
        .unwrap();
        assert_eq!(s.raw(&[1]), None);
        let mut d = [0u8; 1];
        assert!(matches!(
            s.encode_raw(RawValue::Unsigned(1), &mut d),
            Err(EncodeError::PayloadTooShort { .. })
        ));
    }
}
