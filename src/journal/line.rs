//! The journal's line format, nothing else: `{"seq":N,"wall_ns":W,"rec":<json>,"crc":"xxxxxxxx"}\n`,
//! where `crc` is the CRC-32C (Castagnoli) of every byte before `,"crc":`, in lower-case hex, and
//! `wall_ns` (optional: lines without it are valid) the wall-clock time the line was written,
//! ns since the Unix epoch: information, never an ordering key (the clock may jump; `seq` does
//! not).
//!
//! Not here: files, fsync or rotation (see [`super`]).

use serde::Serialize;

const CRC: crc::Crc<u32> = crc::Crc::<u32>::new(&crc::CRC_32_ISCSI);
/// `,"crc":"` + 8 hex digits + `"}`.
const TRAILER_LEN: usize = 8 + 8 + 2;

/// Why a line is not a valid record.
#[derive(Debug, thiserror::Error, PartialEq, Eq)]
pub enum LineError {
    #[error("line is not terminated by a newline (torn write)")]
    Unterminated,
    #[error("line has no CRC trailer")]
    NoTrailer,
    #[error("CRC mismatch (stored {stored:08x}, computed {computed:08x})")]
    Crc { stored: u32, computed: u32 },
    #[error("record is not valid JSON: {0}")]
    Json(String),
    #[error("record has no numeric `seq`")]
    NoSeq,
}

/// Appends one encoded line (with the trailing newline) to `out`, without a wall-clock stamp.
pub fn encode<T: Serialize>(seq: u64, rec: &T, out: &mut Vec<u8>) -> serde_json::Result<()> {
    encode_stamped(seq, None, rec, out)
}

/// Appends one encoded line (with the trailing newline) to `out`, stamped with `wall_ns` when
/// given.
pub fn encode_stamped<T: Serialize>(
    seq: u64,
    wall_ns: Option<i64>,
    rec: &T,
    out: &mut Vec<u8>,
) -> serde_json::Result<()> {
    let start = out.len();
    out.extend_from_slice(b"{\"seq\":");
    out.extend_from_slice(seq.to_string().as_bytes());
    if let Some(w) = wall_ns {
        out.extend_from_slice(b",\"wall_ns\":");
        out.extend_from_slice(w.to_string().as_bytes());
    }
    out.extend_from_slice(b",\"rec\":");
    serde_json::to_writer(&mut *out, rec)?;
    let crc = CRC.checksum(&out[start..]);
    out.extend_from_slice(format!(",\"crc\":\"{crc:08x}\"}}\n").as_bytes());
    Ok(())
}

/// One decoded line.
#[derive(Clone, Debug, PartialEq)]
pub struct Decoded {
    pub seq: u64,
    /// When the line was written (wall clock, ns since the Unix epoch), if stamped.
    pub wall_ns: Option<i64>,
    pub rec: serde_json::Value,
}

/// Checks and parses one line (including its `\n`). Returns the sequence number and the record.
pub fn decode(line: &[u8]) -> Result<(u64, serde_json::Value), LineError> {
    decode_full(line).map(|d| (d.seq, d.rec))
}

/// Checks and parses one line (including its `\n`), with its wall-clock stamp.
pub fn decode_full(line: &[u8]) -> Result<Decoded, LineError> {
    let Some(body) = line.strip_suffix(b"\n") else {
        return Err(LineError::Unterminated);
    };
    if body.len() < TRAILER_LEN || !body.ends_with(b"\"}") {
        return Err(LineError::NoTrailer);
    }
    let (head, trailer) = body.split_at(body.len() - TRAILER_LEN);
    let Some(hex) = trailer
        .strip_prefix(b",\"crc\":\"")
        .and_then(|t| t.strip_suffix(b"\"}"))
    else {
        return Err(LineError::NoTrailer);
    };
    let stored = std::str::from_utf8(hex)
        .ok()
        .and_then(|h| u32::from_str_radix(h, 16).ok())
        .ok_or(LineError::NoTrailer)?;
    let computed = CRC.checksum(head);
    if stored != computed {
        return Err(LineError::Crc { stored, computed });
    }
    let mut v: serde_json::Value =
        serde_json::from_slice(body).map_err(|e| LineError::Json(e.to_string()))?;
    let seq = v
        .get("seq")
        .and_then(|s| s.as_u64())
        .ok_or(LineError::NoSeq)?;
    let wall_ns = v.get("wall_ns").and_then(|w| w.as_i64());
    let rec = v
        .get_mut("rec")
        .map(serde_json::Value::take)
        .unwrap_or(serde_json::Value::Null);
    Ok(Decoded { seq, wall_ns, rec })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn round_trip_and_every_single_byte_flip_is_caught() {
        let mut out = Vec::new();
        encode(
            7,
            &serde_json::json!({"kind": "event", "v0_kmh": 55.2}),
            &mut out,
        )
        .unwrap();
        let (seq, rec) = decode(&out).unwrap();
        assert_eq!(seq, 7);
        assert_eq!(rec["v0_kmh"], 55.2);
        for i in 0..out.len() - 1 {
            let mut bad = out.clone();
            bad[i] ^= 0x01;
            assert!(decode(&bad).is_err(), "flip at byte {i} not detected");
        }
        for cut in 0..out.len() {
            assert!(decode(&out[..cut]).is_err(), "truncation at {cut} accepted");
        }
    }

    #[test]
    fn wall_clock_stamp_round_trips_and_is_covered_by_the_crc() {
        for wall in [-5_000_000_000i64, 0, 946_684_800_000_000_000, i64::MAX] {
            let mut out = Vec::new();
            encode_stamped(3, Some(wall), &serde_json::json!({"k": 1}), &mut out).unwrap();
            let d = decode_full(&out).unwrap();
            assert_eq!((d.seq, d.wall_ns), (3, Some(wall)));
            let text = String::from_utf8(out.clone()).unwrap();
            let w = wall.to_string();
            let at = text.find(&w).unwrap();
            let mut bad = out.clone();
            bad[at] = if bad[at] == b'1' { b'2' } else { b'1' };
            assert!(decode_full(&bad).is_err(), "stamp change not detected");
        }
        let mut plain = Vec::new();
        encode(4, &1, &mut plain).unwrap();
        assert_eq!(decode_full(&plain).unwrap().wall_ns, None);
    }
}
