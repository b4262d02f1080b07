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
            ChecksumError::UnknownMessage => {
                f.write_str("no VW MQB CRC data-ID bytes known for this message ID")
            }
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
        }
    }

    /// Index of the checksum byte in a payload of `len` bytes.
    pub fn byte_index(self, len: usize) -> usize {
        match self {
            ChecksumKind::VwMqb => 0,
            ChecksumKind::Toyota | ChecksumKind::Shimmy => len.saturating_sub(1),
        }
    }

    /// Check a received payload.
    pub fn verify(self, id: u32, data: &[u8]) -> Result<(), ChecksumError> {
        let expected = self.compute(id, data)?;
        let found = data[self.byte_index(data.len())];
        if expected == found {
            Ok(())
        } else {
            Err(ChecksumError::Mismatch { expected, found })
        }
    }

    /// Write the checksum into `data` (for senders such as firmware-sim).
    pub fn apply(self, id: u32, data: &mut [u8]) -> Result<(), ChecksumError> {
        let c = self.compute(id, data)?;
        let i = self.byte_index(data.len());
        data[i] = c;
        Ok(())
    }

    /// Whether this kind can protect message `id` at all (VW needs a known data-ID table).
    pub fn supports(self, id: u32) -> bool {
        match self {
            ChecksumKind::VwMqb => vw_mqb_magic(id, 0).is_some(),
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
        ] {
            let id = if kind == ChecksumKind::VwMqb {
                0xFD
            } else {
                0x0A0
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
}
