//! Frame checksums used by real vehicle buses and by our reference bus: pure byte functions,
//! no policy (which message carries which checksum is the mapping's business, see
//! [`crate::signals::mapping`]).
//!
//! * **Toyota**: `(sum of the data bytes except the last + every byte of the ID + length) & 0xFF`,
//!   stored in the last byte. Holds on every 0x025 and 0x0B4 frame of the real RAV4 log; the
//!   RAV4's 0x0AA (wheel speeds) and 0x224 (brake module) carry no checksum (their last byte is
//!   signal data).
//! * **VW MQB**: AUTOSAR E2E profile 2 style, CRC-8/AUTOSAR (poly 0x2F, init 0xFF, xorout 0xFF,
//!   not reflected) over bytes 1.. of the payload followed by one "data ID" byte that depends on
//!   the message ID and, for some messages, on the 4-bit counter in the low nibble of byte 1. The
//!   CRC is stored in byte 0. The data-ID table ([`vw_mqb_magic`]) covers the messages of the
//!   MQB platform we have real frames for (368 frames in the shared checksum sample).
//! * **Shimmy reference bus** (`dbc/shimmy_reference.dbc`): CRC-8/SAE-J1850 (poly 0x1D, init
//!   0xFF, xorout 0xFF, not reflected) over the ID's low byte, the ID's high byte, then the
//!   payload without its last byte; stored in the last byte. Mixing the ID in catches a frame
//!   sent under the wrong ID as well as corrupted data.
//! * **Honda** (every message with a `CHECKSUM` signal in opendbc's Honda DBCs): a 4-bit sum in
//!   the low nibble of the last byte ([`honda_checksum`]): 8 minus the sum of every hex nibble of
//!   the ID and of every payload nibble except the checksum's own, plus 3 for an extended (29-bit)
//!   ID, modulo 16. Source: opendbc's `honda_checksum` (`opendbc/can/common.cc`, commaai/opendbc);
//!   checked against the known values of opendbc's `test_honda_checksum`
//!   (`opendbc/can/tests/test_checksums.py`).
//! * **Hyundai / Kia** (classic CAN): each message its own ([`hyundai_checksum`]); known for
//!   WHL_SPD11 (0x386), TCS13 (0x394), EMS16 (0x260), SCC12 (0x421) from panda's
//!   `hyundai_compute_checksum` (`board/safety/safety_hyundai.h`, commaai/panda) and for MDPS12
//!   (0x251) from the MDPS12 forwarding code of a community panda fork (`hyundai_mdps12_chksum`;
//!   that fork also meets models whose MDPS12 carries a CRC-8 instead, which is not implemented
//!   here). SAS11's `CheckSum` and ESP12's `ESP12_Checksum` are not verified by opendbc or panda
//!   and their algorithms are not public: [`ChecksumKind::supports`] is false for them.
//!
//! Not here: where a counter lives or how counter sequences are judged (see
//! [`crate::signals::Mapper`]).

use crc::{Crc, CRC_8_AUTOSAR, CRC_8_SAE_J1850};

const CRC8_AUTOSAR: Crc<u8> = Crc::<u8>::new(&CRC_8_AUTOSAR);
const CRC8_J1850: Crc<u8> = Crc::<u8>::new(&CRC_8_SAE_J1850);

/// Which checksum a message carries. Each kind fixes where the checksum byte lives.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash, serde::Serialize, serde::Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum ChecksumKind {
    /// Toyota additive checksum in the last byte ([`toyota_checksum`]).
    Toyota,
    /// VW MQB CRC-8 in byte 0 ([`vw_mqb_crc8`]).
    VwMqb,
    /// Our reference bus CRC-8/SAE-J1850 in the last byte ([`shimmy_crc8`]).
    Shimmy,
    /// Honda 4-bit checksum in the low nibble of the last byte ([`honda_checksum`]).
    Honda,
    /// Hyundai / Kia per-message checksums ([`hyundai_checksum`]; where each lives depends on
    /// the message).
    Hyundai,
}

/// Where a checksum lives in a payload.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
enum Place {
    /// A whole byte.
    Byte(usize),
    /// Bits 0..3 of a byte.
    LowNibble(usize),
    /// Bits 4..7 of a byte.
    HighNibble(usize),
    /// Hyundai WHL_SPD11: bits 0..1 of the value in bits 6..7 of byte `lo`, bits 2..3 in bits
    /// 6..7 of byte `hi`.
    SplitTop2 { lo: usize, hi: usize },
}

impl Place {
    fn last(&self) -> usize {
        match *self {
            Place::Byte(i) | Place::LowNibble(i) | Place::HighNibble(i) => i,
            Place::SplitTop2 { lo, hi } => lo.max(hi),
        }
    }

    fn read(&self, d: &[u8]) -> u8 {
        match *self {
            Place::Byte(i) => d[i],
            Place::LowNibble(i) => d[i] & 0x0F,
            Place::HighNibble(i) => d[i] >> 4,
            Place::SplitTop2 { lo, hi } => ((d[hi] >> 6) << 2) | (d[lo] >> 6),
        }
    }

    fn write(&self, d: &mut [u8], v: u8) {
        match *self {
            Place::Byte(i) => d[i] = v,
            Place::LowNibble(i) => d[i] = (d[i] & 0xF0) | (v & 0x0F),
            Place::HighNibble(i) => d[i] = (d[i] & 0x0F) | (v << 4),
            Place::SplitTop2 { lo, hi } => {
                d[lo] = (d[lo] & 0x3F) | ((v & 0x3) << 6);
                d[hi] = (d[hi] & 0x3F) | (((v >> 2) & 0x3) << 6);
            }
        }
    }
}

/// Why a checksum could not be checked or did not match.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum ChecksumError {
    /// The payload is too short to hold the checksum (and, for VW, the counter).
    TooShort,
    /// VW MQB: no data-ID bytes are known for this message ID.
    UnknownMessage,
    /// Computed and received checksums differ.
    Mismatch { expected: u8, found: u8 },
}

impl std::fmt::Display for ChecksumError {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self {
            ChecksumError::TooShort => f.write_str("payload too short for its checksum"),
            ChecksumError::UnknownMessage => f.write_str(
                "checksum not known for this message ID (VW MQB: no CRC data-ID bytes; \
                 Hyundai: no layout)",
            ),
            ChecksumError::Mismatch { expected, found } => {
                write!(f, "checksum 0x{found:02X}, expected 0x{expected:02X}")
            }
        }
    }
}

impl ChecksumKind {
    /// The checksum `data` should carry under `id`, computed from everything but the checksum
    /// byte. `Err(TooShort)` / `Err(UnknownMessage)` when it cannot be computed.
    pub fn compute(self, id: u32, data: &[u8]) -> Result<u8, ChecksumError> {
        match self {
            ChecksumKind::Toyota => toyota_checksum(id, data).ok_or(ChecksumError::TooShort),
            ChecksumKind::VwMqb => {
                if data.len() < 2 {
                    return Err(ChecksumError::TooShort);
                }
                vw_mqb_crc8(id, data).ok_or(ChecksumError::UnknownMessage)
            }
            ChecksumKind::Shimmy => shimmy_crc8(id, data).ok_or(ChecksumError::TooShort),
            ChecksumKind::Honda => honda_checksum(id, data).ok_or(ChecksumError::TooShort),
            ChecksumKind::Hyundai => {
                let place = hyundai_place(id).ok_or(ChecksumError::UnknownMessage)?;
                if data.len() <= place.last() {
                    return Err(ChecksumError::TooShort);
                }
                hyundai_checksum(id, data).ok_or(ChecksumError::TooShort)
            }
        }
    }

    /// Where the checksum of message `id` lives in a payload of `len` bytes; `None` when it
    /// cannot (unknown message, payload too short).
    fn place(self, id: u32, len: usize) -> Option<Place> {
        let p = match self {
            ChecksumKind::VwMqb => Place::Byte(0),
            ChecksumKind::Toyota | ChecksumKind::Shimmy => Place::Byte(len.checked_sub(1)?),
            ChecksumKind::Honda => Place::LowNibble(len.checked_sub(1)?),
            ChecksumKind::Hyundai => hyundai_place(id)?,
        };
        (p.last() < len).then_some(p)
    }

    /// Index of the checksum byte in a payload of `len` bytes (for Hyundai, whose checksum's
    /// place depends on the message, see [`ChecksumKind::stored`] and
    /// [`ChecksumKind::write`]; this returns the last byte for it).
    pub fn byte_index(self, len: usize) -> usize {
        match self {
            ChecksumKind::VwMqb => 0,
            ChecksumKind::Toyota
            | ChecksumKind::Shimmy
            | ChecksumKind::Honda
            | ChecksumKind::Hyundai => len.saturating_sub(1),
        }
    }

    /// Width of the checksum of message `id` in bits (8, or 4 for the nibble checksums).
    pub fn width_bits(self, id: u32) -> u32 {
        match self {
            ChecksumKind::Toyota | ChecksumKind::VwMqb | ChecksumKind::Shimmy => 8,
            ChecksumKind::Honda => 4,
            ChecksumKind::Hyundai => match hyundai_place(id) {
                Some(Place::Byte(_)) => 8,
                _ => 4,
            },
        }
    }

    /// The checksum `data` carries under `id`.
    pub fn stored(self, id: u32, data: &[u8]) -> Result<u8, ChecksumError> {
        if self == ChecksumKind::Hyundai && hyundai_place(id).is_none() {
            return Err(ChecksumError::UnknownMessage);
        }
        let p = self.place(id, data.len()).ok_or(ChecksumError::TooShort)?;
        Ok(p.read(data))
    }

    /// Write `value` (its low [`ChecksumKind::width_bits`] bits) as the checksum of `data`,
    /// leaving the other bits of its byte(s) alone: [`ChecksumKind::apply`] writes the right
    /// one, a sender simulating a fault writes another.
    pub fn write(self, id: u32, data: &mut [u8], value: u8) -> Result<(), ChecksumError> {
        if self == ChecksumKind::Hyundai && hyundai_place(id).is_none() {
            return Err(ChecksumError::UnknownMessage);
        }
        let p = self.place(id, data.len()).ok_or(ChecksumError::TooShort)?;
        p.write(data, value);
        Ok(())
    }

    /// Check a received payload.
    pub fn verify(self, id: u32, data: &[u8]) -> Result<(), ChecksumError> {
        let expected = self.compute(id, data)?;
        let found = self.stored(id, data)?;
        if expected == found {
            Ok(())
        } else {
            Err(ChecksumError::Mismatch { expected, found })
        }
    }

    /// Write the checksum into `data` (for senders such as firmware-sim).
    pub fn apply(self, id: u32, data: &mut [u8]) -> Result<(), ChecksumError> {
        let c = self.compute(id, data)?;
        self.write(id, data, c)
    }

    /// Whether this kind can protect message `id` at all (VW needs a known data-ID table,
    /// Hyundai a known layout).
    pub fn supports(self, id: u32) -> bool {
        match self {
            ChecksumKind::VwMqb => vw_mqb_magic(id, 0).is_some(),
            ChecksumKind::Hyundai => hyundai_place(id).is_some(),
            _ => true,
        }
    }
}

/// Toyota checksum of `data` (all bytes but the last, plus every byte of `id`, plus the length),
/// i.e. what the last byte should hold. `None` for an empty payload.
pub fn toyota_checksum(id: u32, data: &[u8]) -> Option<u8> {
    let (_, body) = data.split_last()?;
    let mut s = data.len() as u32;
    for b in id.to_le_bytes() {
        s += b as u32;
    }
    for &b in body {
        s += b as u32;
    }
    Some((s & 0xFF) as u8)
}

/// The VW MQB CRC data-ID byte for message `id` at `counter` (low nibble of byte 1), or `None`
/// when the message is not one we know. Most messages use one constant; a few vary per counter.
pub fn vw_mqb_magic(id: u32, counter: u8) -> Option<u8> {
    let c = (counter & 0x0F) as usize;
    let per_counter: &[u8; 16] = match id {
        0x040 => return Some(0x40), // Airbag_01
        0x086 => return Some(0x86), // LWI_01 steering angle
        0x09F => return Some(0xF5), // LH_EPS_03
        0x101 => return Some(0xAA), // ESP_02 accelerations, yaw rate
        0x106 => return Some(0x07), // ESP_05 brake pressure, brake switch
        0x116 => return Some(0xAC), // ESP_10
        0x117 => return Some(0x16), // ACC_10
        0x126 => return Some(0xDA), // HCA_01
        0x30C => return Some(0x0F), // ACC_02
        0x30F => return Some(0x0C), // SWA_01
        0x324 => return Some(0x27), // ACC_04
        0x3C0 => return Some(0xC3), // Klemmen_Status_01
        0x0AD => &VW_GETRIEBE_11,
        0x0FD => &VW_ESP_21,
        0x120 => &VW_TSK_06,
        0x121 => &VW_MOTOR_20,
        0x122 => &VW_ACC_06,
        0x12B => &VW_GRA_ACC_01,
        0x12E => &VW_ACC_07,
        0x187 => &VW_MOTOR_EV_01,
        0x1AB => &VW_ESP_33,
        0x3D5 => &VW_LICHT_ANF_01,
        0x65D => &VW_ESP_20,
        _ => return None,
    };
    Some(per_counter[c])
}

// Per-counter data-ID bytes (index = counter 0..15).
const VW_GETRIEBE_11: [u8; 16] = [
    0x3F, 0x69, 0x39, 0xDC, 0x94, 0xF9, 0x14, 0x64, 0xD8, 0x6A, 0x34, 0xCE, 0xA2, 0x55, 0xB5, 0x2C,
];
const VW_ESP_21: [u8; 16] = [
    0xB4, 0xEF, 0xF8, 0x49, 0x1E, 0xE5, 0xC2, 0xC0, 0x97, 0x19, 0x3C, 0xC9, 0xF1, 0x98, 0xD6, 0x61,
];
const VW_TSK_06: [u8; 16] = [
    0xC4, 0xE2, 0x4F, 0xE4, 0xF8, 0x2F, 0x56, 0x81, 0x9F, 0xE5, 0x83, 0x44, 0x05, 0x3F, 0x97, 0xDF,
];
const VW_MOTOR_20: [u8; 16] = [
    0xE9, 0x65, 0xAE, 0x6B, 0x7B, 0x35, 0xE5, 0x5F, 0x4E, 0xC7, 0x86, 0xA2, 0xBB, 0xDD, 0xEB, 0xB4,
];
const VW_ACC_06: [u8; 16] = [
    0x37, 0x7D, 0xF3, 0xA9, 0x18, 0x46, 0x6D, 0x4D, 0x3D, 0x71, 0x92, 0x9C, 0xE5, 0x32, 0x10, 0xB9,
];
const VW_GRA_ACC_01: [u8; 16] = [
    0x6A, 0x38, 0xB4, 0x27, 0x22, 0xEF, 0xE1, 0xBB, 0xF8, 0x80, 0x84, 0x49, 0xC7, 0x9E, 0x1E, 0x2B,
];
const VW_ACC_07: [u8; 16] = [
    0xF8, 0xE5, 0x97, 0xC9, 0xD6, 0x07, 0x47, 0x21, 0x66, 0xDD, 0xCF, 0x6F, 0xA1, 0x94, 0x74, 0x63,
];
const VW_MOTOR_EV_01: [u8; 16] = [
    0x7F, 0xED, 0x17, 0xC2, 0x7C, 0xEB, 0x44, 0x21, 0x01, 0xFA, 0xDB, 0x15, 0x4A, 0x6B, 0x23, 0x05,
];
const VW_ESP_33: [u8; 16] = [
    0x13, 0x21, 0x9B, 0x6A, 0x9A, 0x62, 0xD4, 0x65, 0x18, 0xF1, 0xAB, 0x16, 0x32, 0x89, 0xE7, 0x26,
];
const VW_LICHT_ANF_01: [u8; 16] = [
    0xC5, 0x39, 0xC7, 0xF9, 0x92, 0xD8, 0x24, 0xCE, 0xF1, 0xB5, 0x7A, 0xC4, 0xBC, 0x60, 0xE3, 0xD1,
];
const VW_ESP_20: [u8; 16] = [
    0xAC, 0xB3, 0xAB, 0xEB, 0x7A, 0xE1, 0x3B, 0xF7, 0x73, 0xBA, 0x7C, 0x9E, 0x06, 0x5F, 0x02, 0xD9,
];

/// VW MQB CRC-8 that byte 0 of `data` should hold. `None` when the payload is shorter than two
/// bytes or the message's data-ID bytes are unknown.
pub fn vw_mqb_crc8(id: u32, data: &[u8]) -> Option<u8> {
    if data.len() < 2 {
        return None;
    }
    let magic = vw_mqb_magic(id, data[1] & 0x0F)?;
    let mut d = CRC8_AUTOSAR.digest();
    d.update(&data[1..]);
    d.update(&[magic]);
    Some(d.finalize())
}

/// Our reference bus CRC-8/SAE-J1850 that the last byte of `data` should hold: over the ID's
/// low byte, the ID's high byte (11-bit IDs: bits 8..10), then every payload byte but the last.
/// `None` for an empty payload.
pub fn shimmy_crc8(id: u32, data: &[u8]) -> Option<u8> {
    let (_, body) = data.split_last()?;
    let mut d = CRC8_J1850.digest();
    d.update(&[(id & 0xFF) as u8, ((id >> 8) & 0xFF) as u8]);
    d.update(body);
    Some(d.finalize())
}

/// Honda's 4-bit checksum that the low nibble of `data`'s last byte should hold: 8 minus the sum
/// of the hex nibbles of `id` and of every nibble of `data` except that one, plus 3 when `id` is
/// an extended (29-bit) ID, modulo 16 (opendbc `honda_checksum`). `None` for an empty payload.
pub fn honda_checksum(id: u32, data: &[u8]) -> Option<u8> {
    let (&last, body) = data.split_last()?;
    let mut s: i64 = 0;
    let mut a = id;
    while a != 0 {
        s += i64::from(a & 0xF);
        a >>= 4;
    }
    for &b in body {
        s += i64::from(b & 0xF) + i64::from(b >> 4);
    }
    s += i64::from(last >> 4);
    let mut c = 8 - s;
    if id > 0x7FF {
        c += 3;
    }
    Some(c.rem_euclid(16) as u8)
}

/// Where the Hyundai checksum of message `id` lives, for the messages whose algorithm is known.
fn hyundai_place(id: u32) -> Option<Place> {
    Some(match id {
        0x251 => Place::Byte(3),                    // MDPS12 CF_Mdps_Chksum2
        0x260 => Place::LowNibble(7),               // EMS16 Checksum
        0x386 => Place::SplitTop2 { lo: 5, hi: 7 }, // WHL_SPD11 Checksum_LSB/_MSB
        0x394 => Place::LowNibble(6),               // TCS13 CheckSum_TCS3
        0x421 => Place::HighNibble(7),              // SCC12 CR_VSM_ChkSum
        _ => return None,
    })
}

/// The Hyundai / Kia checksum `data` should carry under `id`, or `None` for a message whose
/// algorithm is not known (see the module docs) or a payload too short for it:
///
/// * WHL_SPD11 (0x386): the number of set bits in the 8 bytes, leaving out bits 6..7 of bytes
///   1, 3, 5, 7 (the split counter and checksum), XOR 9, modulo 16;
/// * TCS13 (0x394), EMS16 (0x260), SCC12 (0x421): 16 minus the sum of the payload's nibbles
///   (the checksum nibble left out; TCS13 sums bytes 0..6 only), modulo 16;
/// * MDPS12 (0x251): the sum of the 8 bytes with byte 3 (the checksum) taken as 0, modulo 256.
pub fn hyundai_checksum(id: u32, data: &[u8]) -> Option<u8> {
    let place = hyundai_place(id)?;
    if data.len() <= place.last() {
        return None;
    }
    match id {
        0x386 => {
            let mut n: u32 = 0;
            for (i, &b) in data.iter().enumerate() {
                let b = if i % 2 == 1 && i <= 7 { b & 0x3F } else { b };
                n += b.count_ones();
            }
            Some(((n ^ 9) & 15) as u8)
        }
        0x251 => {
            let mut s: u32 = 0;
            for (i, &b) in data.iter().enumerate() {
                if i != 3 {
                    s += u32::from(b);
                }
            }
            Some((s & 0xFF) as u8)
        }
        _ => {
            let end = if id == 0x394 { 7 } else { data.len() };
            let mut s: u32 = 0;
            for (i, &b) in data.iter().enumerate().take(end) {
                let b = match place {
                    Place::LowNibble(j) if j == i => b & 0xF0,
                    Place::HighNibble(j) if j == i => b & 0x0F,
                    _ => b,
                };
                s += u32::from(b & 0xF) + u32::from(b >> 4);
            }
            Some(((16 - s % 16) % 16) as u8)
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn crc_catalog_parameters_are_the_documented_ones() {
        // Standard check values ("123456789") of the two catalogue CRCs we rely on.
        assert_eq!(CRC8_AUTOSAR.checksum(b"123456789"), 0xDF);
        assert_eq!(CRC8_J1850.checksum(b"123456789"), 0x4B);
    }

    #[test]
    fn toyota_known_frame() {
        // 0x0B4 SPEED frame from the real RAV4 log: 000000001D0B7A5E.
        let d = [0x00, 0x00, 0x00, 0x00, 0x1D, 0x0B, 0x7A, 0x5E];
        assert_eq!(toyota_checksum(0xB4, &d), Some(0x5E));
        assert_eq!(ChecksumKind::Toyota.verify(0xB4, &d), Ok(()));
        assert_eq!(toyota_checksum(0xB4, &[]), None);
    }

    #[test]
    fn vw_known_frame_and_unknown_id() {
        // LWI_01 frame from the shared sample: 6b00bd0000000000.
        let d = [0x6B, 0x00, 0xBD, 0, 0, 0, 0, 0];
        assert_eq!(vw_mqb_crc8(0x86, &d), Some(0x6B));
        assert_eq!(vw_mqb_crc8(0x7FF, &d), None);
        assert_eq!(
            ChecksumKind::VwMqb.verify(0x7FF, &d),
            Err(ChecksumError::UnknownMessage)
        );
        assert_eq!(
            ChecksumKind::VwMqb.verify(0x86, &d[..1]),
            Err(ChecksumError::TooShort)
        );
    }

    #[test]
    fn apply_then_verify_round_trips_for_every_kind() {
        for kind in [
            ChecksumKind::Toyota,
            ChecksumKind::VwMqb,
            ChecksumKind::Shimmy,
            ChecksumKind::Honda,
            ChecksumKind::Hyundai,
        ] {
            let id = match kind {
                ChecksumKind::VwMqb => 0xFD,
                ChecksumKind::Hyundai => 0x386,
                _ => 0x0A0,
            };
            for counter in 0..16u8 {
                let mut d = [0x12, counter, 0x34, 0x56, 0x78, 0x9A, 0xBC, 0x00];
                kind.apply(id, &mut d).unwrap();
                assert_eq!(kind.verify(id, &d), Ok(()), "{kind:?} counter {counter}");
            }
        }
    }

    #[test]
    fn shimmy_crc_depends_on_id() {
        let d = [1, 2, 3, 4, 5, 6, 7, 0];
        assert_ne!(shimmy_crc8(0x0A0, &d), shimmy_crc8(0x0B0, &d));
        assert_ne!(shimmy_crc8(0x0A0, &d), shimmy_crc8(0x1A0, &d));
    }

    /// opendbc's `test_honda_checksum`: LKAS_HUD (0x33D) and LKAS_HUD_A (0x33DA, extended) with
    /// SET_ME_X41 = 0x41, STEERING_REQUIRED = 1, SOLID_LANES = 1 (payload 41 05 00 00 c0, the
    /// counter c in bits 4..5 of byte 4, as `_bosch_2018.dbc` lays LKAS_HUD_A out) carry the
    /// checksums 11, 10, 9, 8 and 4, 3, 2, 1 for counters 0..3.
    #[test]
    fn honda_known_vectors_from_opendbc() {
        for c in 0..4u8 {
            let d = [0x41, 0x05, 0x00, 0x00, c << 4];
            assert_eq!(honda_checksum(0x33D, &d), Some(11 - c), "std, counter {c}");
            assert_eq!(honda_checksum(0x33DA, &d), Some(4 - c), "ext, counter {c}");
            let mut with = d;
            ChecksumKind::Honda.apply(0x33D, &mut with).unwrap();
            assert_eq!(with[4], (c << 4) | (11 - c));
            assert_eq!(ChecksumKind::Honda.verify(0x33D, &with), Ok(()));
        }
    }

    #[test]
    fn hyundai_layouts_and_single_bit_errors() {
        for id in [0x251u32, 0x260, 0x386, 0x394, 0x421] {
            assert!(ChecksumKind::Hyundai.supports(id));
            let mut d = [0x5A, 0xC3, 0x11, 0x00, 0x7E, 0x01, 0x80, 0x00];
            ChecksumKind::Hyundai.apply(id, &mut d).unwrap();
            assert_eq!(ChecksumKind::Hyundai.verify(id, &d), Ok(()), "0x{id:X}");
            let w = ChecksumKind::Hyundai.width_bits(id);
            // Every single flipped bit that the checksum covers is caught.
            for bit in 0..64 {
                let mut bad = d;
                bad[bit / 8] ^= 1 << (bit % 8);
                let covered = match id {
                    // The split counter (bits 6..7 of bytes 1 and 3) is not covered.
                    0x386 => !(bit / 8 == 1 || bit / 8 == 3) || bit % 8 < 6,
                    // TCS13's byte 7 is not covered.
                    0x394 => bit / 8 != 7,
                    _ => true,
                };
                if covered {
                    assert!(
                        ChecksumKind::Hyundai.verify(id, &bad).is_err(),
                        "0x{id:X} ({w} bits): flipped bit {bit} not caught"
                    );
                }
            }
        }
        // WHL_SPD11's checksum is split over the top bits of bytes 5 and 7.
        let mut d = [0u8; 8];
        ChecksumKind::Hyundai.write(0x386, &mut d, 0b1110).unwrap();
        assert_eq!((d[5], d[7]), (0b1000_0000, 0b1100_0000));
        assert_eq!(ChecksumKind::Hyundai.stored(0x386, &d), Ok(0b1110));
        // All zero: 0 bits set, 0 ^ 9 = 9.
        assert_eq!(hyundai_checksum(0x386, &[0u8; 8]), Some(9));
        // MDPS12: the byte sum without byte 3.
        assert_eq!(
            hyundai_checksum(0x251, &[1, 2, 3, 0xFF, 4, 5, 6, 7]),
            Some(28)
        );
        // Unknown messages (SAS11 0x2B0, ESP12 0x220) are refused, not guessed.
        for id in [0x2B0u32, 0x220] {
            assert!(!ChecksumKind::Hyundai.supports(id));
            assert_eq!(
                ChecksumKind::Hyundai.verify(id, &[0u8; 8]),
                Err(ChecksumError::UnknownMessage)
            );
        }
        assert_eq!(
            ChecksumKind::Hyundai.verify(0x394, &[0u8; 5]),
            Err(ChecksumError::TooShort)
        );
    }
}
