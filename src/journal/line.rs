//! The journal's line format, nothing else: `{"seq":N,"rec":<json>,"crc":"xxxxxxxx"}\n`, where
//! `crc` is the CRC-32C (Castagnoli) of every byte before `,"crc":`, in lower-case hex.
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

/// Appends one encoded line (with the trailing newline) to `out`.
pub fn encode<T: Serialize>(seq: u64, rec: &T, out: &mut Vec<u8>) -> serde_json::Result<()> {
    let start = out.len();
    out.extend_from_slice(b"{\"seq\":");
    out.extend_from_slice(seq.to_string().as_bytes());
    out.extend_from_slice(b",\"rec\":");
    serde_json::to_writer(&mut *out, rec)?;
    let crc = CRC.checksum(&out[start..]);
    out.extend_from_slice(format!(",\"crc\":\"{crc:08x}\"}}\n").as_bytes());
    Ok(())
}

/// Checks and parses one line (including its `\n`). Returns the sequence number and the record.
pub fn decode(line: &[u8]) -> Result<(u64, serde_json::Value), LineError> {
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
    let rec = v
        .get_mut("rec")
        .map(serde_json::Value::take)
        .unwrap_or(serde_json::Value::Null);
    Ok((seq, rec))
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
}
