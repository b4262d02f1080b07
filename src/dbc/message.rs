//! One DBC message and the decoding of a payload into its signals, honouring simple and extended
//! (`SG_MUL_VAL_`, cascaded) multiplexing the way cantools does:
//!
//! - a signal with no multiplexing condition is always decoded;
//! - a multiplexed signal is decoded when its switch signal is itself present and has a raw value
//!   inside the signal's ranges;
//! - a present switch whose value selects nothing (no child signal and no value-table entry has
//!   that value) makes the whole frame undecodable ([`DecodeError::UnknownMultiplexerValue`]),
//!   which is cantools' "expected multiplexer id …" error.
//!
//! A payload shorter than the message's length is not an error: signals that fit are decoded,
//! the others are counted in [`DecodeSummary::truncated`]. Decoding allocates nothing.

use super::bits::ByteOrder;
use super::signal::{RawValue, Signal, ValueKind};

/// Counts for one decoded frame.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct DecodeSummary {
    /// Signals delivered to the callback.
    pub decoded: u16,
    /// Signals that would be present but do not fit the payload (or whose switch does not).
    pub truncated: u16,
    /// Signals absent because of the multiplexer values.
    pub not_selected: u16,
}

/// Why a frame could not be decoded at all.
#[derive(Clone, Copy, Debug, PartialEq, Eq, thiserror::Error)]
pub enum DecodeError {
    /// The switch (signal index) has a value no signal is defined for.
    #[error("multiplexer signal #{switch} has value {value}, for which no signal is defined")]
    UnknownMultiplexerValue { switch: usize, value: u64 },
}

/// A switch signal and the union of the values that select something under it.
#[derive(Clone, Debug, PartialEq)]
pub(crate) struct SwitchCheck {
    pub switch: usize,
    pub valid: Vec<(u64, u64)>,
}

/// The per-signal numbers the decode loop needs, packed together (a [`Signal`] also carries
/// names, units and tables, which would spread the loop over many cache lines).
#[derive(Clone, Copy, Debug, PartialEq)]
pub(crate) struct Hot {
    /// Right shift of the 8-byte word (little-endian word for Intel, big-endian for Motorola)
    /// that brings the signal's LSB to bit 0; only valid when `needed <= 8`.
    word_shift: u8,
    big_endian: bool,
    needed: u8,
    /// 64 - size: shift pair that sign-extends.
    sign_shift: u8,
    kind: ValueKind,
    mask: u64,
    factor: f64,
    offset: f64,
    /// Index into `[le, be]` of the word the signal is read from.
    word_sel: u8,
    /// Sign-extension shift pair for the integer path: `64 - size` for signed, 0 for unsigned.
    sext: u8,
    signed: bool,
}

impl Hot {
    fn new(s: &Signal) -> Hot {
        let l = s.layout;
        let needed = l.needed_len();
        let word_shift = if needed <= 8 {
            match l.order {
                ByteOrder::LittleEndian => l.first_byte as u32 * 8 + l.shift as u32,
                ByteOrder::BigEndian => (8 - needed as u32) * 8 + l.shift as u32,
            }
        } else {
            0
        };
        Hot {
            word_shift: word_shift as u8,
            big_endian: l.order == ByteOrder::BigEndian,
            needed: needed.min(255) as u8,
            sign_shift: 64 - l.size,
            kind: s.kind,
            mask: l.mask,
            factor: s.factor,
            offset: s.offset,
            word_sel: (l.order == ByteOrder::BigEndian) as u8,
            sext: if s.kind == ValueKind::Signed {
                64 - l.size
            } else {
                0
            },
            signed: s.kind == ValueKind::Signed,
        }
    }

    /// Whether the branch-free integer path applies: signed, or unsigned below 64 bits (so the
    /// raw bits fit an `i64` and convert to `f64` exactly as the `u64` would).
    fn int_path(&self) -> bool {
        match self.kind {
            ValueKind::Signed => true,
            ValueKind::Unsigned => self.sign_shift > 0,
            ValueKind::Float32 | ValueKind::Float64 => false,
        }
    }

    #[inline(always)]
    fn raw(&self, le: u64, be: u64) -> RawValue {
        let w = if self.big_endian { be } else { le };
        let bits = (w >> self.word_shift) & self.mask;
        match self.kind {
            ValueKind::Unsigned => RawValue::Unsigned(bits),
            ValueKind::Signed => {
                RawValue::Signed(((bits << self.sign_shift) as i64) >> self.sign_shift)
            }
            ValueKind::Float32 => RawValue::F32(f32::from_bits(bits as u32)),
            ValueKind::Float64 => RawValue::F64(f64::from_bits(bits)),
        }
    }
}

/// One message of a database.
#[derive(Clone, Debug, PartialEq)]
pub struct Message {
    pub name: String,
    /// 11- or 29-bit identifier (without DBC's bit-31 extended flag).
    pub id: u32,
    pub extended: bool,
    /// Length declared in the DBC (bytes; up to 64 for CAN FD).
    pub size_bytes: usize,
    pub transmitter: Option<String>,
    pub comment: Option<String>,
    /// `GenMsgCycleTime` attribute, when the DBC gives one.
    pub cycle_time_ms: Option<u32>,
    pub signals: Vec<Signal>,
    /// DBC line number of the `BO_` line.
    pub line: usize,
    /// Switches that can reject a frame; empty for non-multiplexed messages.
    pub(crate) switch_checks: Vec<SwitchCheck>,
    /// Some signal has a multiplexing condition (set by [`Message::finish`]).
    multiplexed: bool,
    /// Packed copies of the signals' layouts and scaling (set by [`Message::finish`]).
    hot: Vec<Hot>,
    /// Every signal lies within the first 8 bytes (the one-word fast path applies).
    within_8: bool,
    /// Every signal takes the branch-free integer path (see `Hot::int_path`).
    int_words: bool,
    /// Payload length that holds every signal.
    max_needed: usize,
}

/// Whether a signal is present in a given payload.
enum Presence {
    Present,
    NotSelected,
    /// A switch it depends on does not fit the payload.
    SwitchTruncated,
}

impl Message {
    /// A message without signals.
    pub fn new(name: &str, id: u32, extended: bool, size_bytes: usize) -> Message {
        Message {
            name: name.to_string(),
            id,
            extended,
            size_bytes,
            transmitter: None,
            comment: None,
            cycle_time_ms: None,
            signals: Vec::new(),
            line: 0,
            switch_checks: Vec::new(),
            multiplexed: false,
            hot: Vec::new(),
            within_8: true,
            int_words: true,
            max_needed: 0,
        }
    }

    /// Index of a signal by name.
    pub fn signal_by_name(&self, name: &str) -> Option<usize> {
        self.signals.iter().position(|s| s.name == name)
    }

    /// True when the message has multiplexed signals.
    pub fn is_multiplexed(&self) -> bool {
        self.multiplexed
    }

    /// Recompute the decoding tables after `signals` changed (decoding reads them, so call
    /// this after any change to `signals`). Returns an error naming
    /// the signal when the conditions form a cycle (such a message cannot be decoded).
    pub fn finish(&mut self) -> Result<(), String> {
        // Cycle check: follow switches at most signals.len() steps.
        for (i, s) in self.signals.iter().enumerate() {
            let mut cur = s.multiplexer.as_ref().map(|m| m.switch);
            let mut steps = 0;
            while let Some(c) = cur {
                if c >= self.signals.len() {
                    return Err(format!("signal {}: switch index out of range", s.name));
                }
                if c == i || steps > self.signals.len() {
                    return Err(format!(
                        "signal {}: multiplexer conditions form a cycle",
                        s.name
                    ));
                }
                cur = self.signals[c].multiplexer.as_ref().map(|m| m.switch);
                steps += 1;
            }
        }
        let mut checks: Vec<SwitchCheck> = Vec::new();
        for (i, s) in self.signals.iter().enumerate() {
            if !s.is_multiplexer {
                continue;
            }
            let mut valid: Vec<(u64, u64)> = self
                .signals
                .iter()
                .filter_map(|c| c.multiplexer.as_ref())
                .filter(|m| m.switch == i)
                .flat_map(|m| m.ranges.iter().copied())
                .collect();
            if valid.is_empty() {
                // A switch without children selects nothing and rejects nothing (cantools).
                continue;
            }
            valid.extend(
                s.choices
                    .iter()
                    .filter_map(|(k, _)| u64::try_from(*k).ok())
                    .map(|k| (k, k)),
            );
            valid.sort_unstable();
            checks.push(SwitchCheck { switch: i, valid });
        }
        self.switch_checks = checks;
        self.multiplexed = self.signals.iter().any(|s| s.multiplexer.is_some());
        self.hot = self.signals.iter().map(Hot::new).collect();
        self.within_8 = self.signals.iter().all(|s| s.needed_len() <= 8);
        self.int_words = self.hot.iter().all(Hot::int_path);
        self.max_needed = self
            .signals
            .iter()
            .map(|s| s.needed_len())
            .max()
            .unwrap_or(0);
        Ok(())
    }

    fn presence(&self, idx: usize, data: &[u8]) -> Presence {
        let mut cur = idx;
        // Bounded by the cycle check in `finish`; the bound keeps a hand-built message safe.
        for _ in 0..=self.signals.len() {
            let Some(cond) = &self.signals[cur].multiplexer else {
                return Presence::Present;
            };
            let sw = &self.signals[cond.switch];
            let Some(raw) = sw.raw(data) else {
                return Presence::SwitchTruncated;
            };
            match raw.as_u64() {
                Some(v) if cond.matches(v) => cur = cond.switch,
                _ => return Presence::NotSelected,
            }
        }
        Presence::NotSelected
    }

    /// Check the switches of a payload (cantools' unknown-multiplexer rule).
    pub fn check_multiplexers(&self, data: &[u8]) -> Result<(), DecodeError> {
        for chk in &self.switch_checks {
            if !matches!(self.presence(chk.switch, data), Presence::Present) {
                continue;
            }
            let Some(raw) = self.signals[chk.switch].raw(data) else {
                continue;
            };
            let ok = match raw.as_u64() {
                Some(v) => chk.valid.iter().any(|&(lo, hi)| lo <= v && v <= hi),
                None => false,
            };
            if !ok {
                return Err(DecodeError::UnknownMultiplexerValue {
                    switch: chk.switch,
                    value: raw.as_u64().unwrap_or(u64::MAX),
                });
            }
        }
        Ok(())
    }

    /// Decode a payload: calls `f(signal_index, raw, phys)` for every present signal that fits,
    /// in signal order. Nothing is delivered when a switch value is unknown.
    #[inline]
    pub fn decode<F: FnMut(usize, RawValue, f64)>(
        &self,
        data: &[u8],
        mut f: F,
    ) -> Result<DecodeSummary, DecodeError> {
        let mut sum = DecodeSummary::default();
        if !self.multiplexed
            && self.switch_checks.is_empty()
            && self.within_8
            && self.hot.len() == self.signals.len()
        {
            // Fast path: one 8-byte word, one shift and mask per signal.
            let mut buf = [0u8; 8];
            let n = data.len().min(8);
            buf[..n].copy_from_slice(&data[..n]);
            let (le, be) = (u64::from_le_bytes(buf), u64::from_be_bytes(buf));
            if self.int_words && data.len() >= self.max_needed {
                // Every signal fits and is an integer: no per-signal length check and no
                // branch on byte order or value kind (word picked by index, sign extension by
                // a shift pair that is 0 for unsigned signals).
                let words = [le, be];
                for (i, h) in self.hot.iter().enumerate() {
                    let bits = (words[(h.word_sel & 1) as usize] >> h.word_shift) & h.mask;
                    let v = ((bits << h.sext) as i64) >> h.sext;
                    let raw = if h.signed {
                        RawValue::Signed(v)
                    } else {
                        RawValue::Unsigned(bits)
                    };
                    f(i, raw, v as f64 * h.factor + h.offset);
                }
                sum.decoded += self.hot.len() as u16;
                return Ok(sum);
            }
            for (i, h) in self.hot.iter().enumerate() {
                if h.needed as usize > data.len() {
                    sum.truncated += 1;
                    continue;
                }
                let raw = h.raw(le, be);
                f(i, raw, raw.as_f64() * h.factor + h.offset);
                sum.decoded += 1;
            }
            return Ok(sum);
        }
        if !self.multiplexed && self.switch_checks.is_empty() {
            for (i, s) in self.signals.iter().enumerate() {
                match s.raw(data) {
                    Some(raw) => {
                        f(i, raw, s.scale(raw));
                        sum.decoded += 1;
                    }
                    None => sum.truncated += 1,
                }
            }
            return Ok(sum);
        }
        self.check_multiplexers(data)?;
        for (i, s) in self.signals.iter().enumerate() {
            match self.presence(i, data) {
                Presence::NotSelected => sum.not_selected += 1,
                Presence::SwitchTruncated => sum.truncated += 1,
                Presence::Present => match s.raw(data) {
                    Some(raw) => {
                        f(i, raw, s.scale(raw));
                        sum.decoded += 1;
                    }
                    None => sum.truncated += 1,
                },
            }
        }
        Ok(sum)
    }
}
