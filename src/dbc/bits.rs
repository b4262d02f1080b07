//! Bit layout of one DBC signal inside a payload: where its bits are, and how to read and write
//! them as an unsigned integer. This is the wire format only: no sign, no scaling, no policy.
//!
//! Conventions (the DBC ones, as cantools applies them):
//! - Bits are numbered LSB-first inside each byte: bit `k` is `data[k / 8] >> (k % 8) & 1`.
//! - Intel (`@1`, little endian): the start bit is the signal's least significant bit; the signal
//!   runs towards higher bit numbers, continuing in the next byte.
//! - Motorola (`@0`, big endian): the start bit is the signal's *most* significant bit; the signal
//!   runs towards lower bit numbers inside a byte and continues at bit 7 of the next byte
//!   ("sawtooth" numbering). Equivalently, with the payload seen as one big-endian bit string in
//!   which position 0 is the MSB of byte 0, the MSB sits at `8 * (s / 8) + 7 - s % 8` and the
//!   signal occupies the next `size` positions.
//!
//! A signal of up to 64 bits spans at most 9 bytes; reading goes through a `u128` window.

/// Byte order of a signal.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub enum ByteOrder {
    /// Intel, `@1`.
    LittleEndian,
    /// Motorola, `@0`.
    BigEndian,
}

/// Precomputed position of a signal's bits: the bytes it touches and the shift inside them.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Layout {
    /// First payload byte the signal touches.
    pub first_byte: u8,
    /// Number of bytes touched (1..=9).
    pub n_bytes: u8,
    /// Right shift of the assembled window that brings the signal's LSB to bit 0.
    pub shift: u8,
    /// Size in bits (1..=64).
    pub size: u8,
    pub order: ByteOrder,
    /// `size` low bits set.
    pub mask: u64,
}

/// Why a layout is unusable.
#[derive(Clone, Debug, PartialEq, Eq, thiserror::Error)]
pub enum LayoutError {
    #[error("signal size {0} bits is outside 1..=64")]
    BadSize(u64),
    #[error("signal at start bit {start} with {size} bits does not fit a 64-byte CAN FD payload")]
    OutOfRange { start: u64, size: u64 },
}

impl Layout {
    /// Layout for a DBC start bit, size and byte order; payloads up to 64 bytes.
    pub fn new(start_bit: u64, size: u64, order: ByteOrder) -> Result<Layout, LayoutError> {
        if size == 0 || size > 64 {
            return Err(LayoutError::BadSize(size));
        }
        let oor = LayoutError::OutOfRange {
            start: start_bit,
            size,
        };
        if start_bit >= 512 {
            return Err(oor);
        }
        let (first_bit, last_bit, shift) = match order {
            ByteOrder::LittleEndian => {
                let last = start_bit + size - 1;
                (start_bit, last, start_bit % 8)
            }
            ByteOrder::BigEndian => {
                // Positions in the big-endian bit string (0 = MSB of byte 0).
                let msb = 8 * (start_bit / 8) + 7 - start_bit % 8;
                let lsb = msb + size - 1;
                (msb, lsb, 7 - lsb % 8)
            }
        };
        if last_bit >= 512 {
            return Err(oor);
        }
        let first_byte = first_bit / 8;
        let last_byte = last_bit / 8;
        Ok(Layout {
            first_byte: first_byte as u8,
            n_bytes: (last_byte - first_byte + 1) as u8,
            shift: shift as u8,
            size: size as u8,
            order,
            mask: if size == 64 {
                u64::MAX
            } else {
                (1u64 << size) - 1
            },
        })
    }

    /// Payload length (bytes) needed to hold the whole signal.
    #[inline]
    pub fn needed_len(&self) -> usize {
        self.first_byte as usize + self.n_bytes as usize
    }

    /// The signal's bits as an unsigned integer, or `None` when the payload is too short.
    #[inline]
    pub fn extract(&self, data: &[u8]) -> Option<u64> {
        let first = self.first_byte as usize;
        let bytes = data.get(first..first + self.n_bytes as usize)?;
        let window: u128 = match self.order {
            ByteOrder::LittleEndian => {
                let mut w = 0u128;
                for (i, &b) in bytes.iter().enumerate() {
                    w |= (b as u128) << (8 * i);
                }
                w
            }
            ByteOrder::BigEndian => {
                let mut w = 0u128;
                for &b in bytes {
                    w = (w << 8) | b as u128;
                }
                w
            }
        };
        Some((window >> self.shift) as u64 & self.mask)
    }

    /// Write the low `size` bits of `bits` into the payload, leaving every other bit untouched.
    /// Returns `false` (and writes nothing) when the payload is too short.
    pub fn insert(&self, bits: u64, data: &mut [u8]) -> bool {
        let first = self.first_byte as usize;
        let n = self.n_bytes as usize;
        let Some(bytes) = data.get_mut(first..first + n) else {
            return false;
        };
        let field = (
            (self.mask as u128) << self.shift,
            ((bits & self.mask) as u128) << self.shift,
        );
        match self.order {
            ByteOrder::LittleEndian => {
                for (i, b) in bytes.iter_mut().enumerate() {
                    let m = (field.0 >> (8 * i)) as u8;
                    let v = (field.1 >> (8 * i)) as u8;
                    *b = (*b & !m) | v;
                }
            }
            ByteOrder::BigEndian => {
                for (i, b) in bytes.iter_mut().enumerate() {
                    let sh = 8 * (n - 1 - i);
                    let m = (field.0 >> sh) as u8;
                    let v = (field.1 >> sh) as u8;
                    *b = (*b & !m) | v;
                }
            }
        }
        true
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn intel_across_bytes() {
        // 12 bits starting at bit 4: low nibble from byte 0's high nibble, then byte 1.
        let l = Layout::new(4, 12, ByteOrder::LittleEndian).unwrap();
        assert_eq!(l.extract(&[0xA0, 0xCB]), Some(0xCBA));
        assert_eq!(l.extract(&[0xA0]), None);
    }

    #[test]
    fn motorola_sawtooth() {
        // Motorola 12 bits with MSB at bit 7 of byte 0: byte0 then high nibble of byte1.
        let l = Layout::new(7, 12, ByteOrder::BigEndian).unwrap();
        assert_eq!(l.extract(&[0xAB, 0xC0]), Some(0xABC));
        // MSB at bit 3 of byte 0, 8 bits: low nibble of byte 0, high nibble of byte 1.
        let l = Layout::new(3, 8, ByteOrder::BigEndian).unwrap();
        assert_eq!(l.extract(&[0x0D, 0xE0]), Some(0xDE));
    }

    #[test]
    fn sixty_four_bits_unaligned() {
        let l = Layout::new(4, 64, ByteOrder::LittleEndian).unwrap();
        assert_eq!(l.n_bytes, 9);
        let mut d = [0u8; 9];
        assert!(l.insert(0xDEAD_BEEF_0123_4567, &mut d));
        assert_eq!(l.extract(&d), Some(0xDEAD_BEEF_0123_4567));
        assert_eq!(d[0] & 0x0F, 0);
    }

    #[test]
    fn rejects_bad_sizes() {
        assert!(Layout::new(0, 0, ByteOrder::LittleEndian).is_err());
        assert!(Layout::new(0, 65, ByteOrder::LittleEndian).is_err());
        assert!(Layout::new(510, 8, ByteOrder::LittleEndian).is_err());
    }
}
