//! The DBC loader ([`shimmy::dbc::Database::parse`]) on arbitrary text: it never fails as a
//! whole and never panics; every message it keeps is found by its own id and decodes payloads
//! of every length up to 64 bytes (bytes taken from the input) without panicking.
#![no_main]

use shimmy::dbc::Database;

libfuzzer_sys::fuzz_target!(|data: &[u8]| {
    let Ok(text) = std::str::from_utf8(data) else {
        return;
    };
    let (db, _report) = Database::parse(text);
    let mut payload = [0u8; 64];
    for (i, b) in payload.iter_mut().enumerate() {
        *b = data.get(i).copied().unwrap_or(0xA5);
    }
    for m in db.messages() {
        assert_eq!(
            db.message(m.id, m.extended).map(|x| x.name.as_str()),
            Some(m.name.as_str()),
            "message {} not found by its own id",
            m.name
        );
        for len in [0, 1, 8, m.size_bytes.min(64), 64] {
            let _ = m.decode(&payload[..len], |i, _raw, _phys| {
                assert!(i < m.signals.len());
            });
        }
    }
});
