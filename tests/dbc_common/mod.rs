//! Shared by the DBC tests: comparison of our decoding with cantools' JSON-lines vectors.
#![allow(dead_code)]

use std::collections::BTreeMap;

use shimmy::dbc::{Database, DecodeError, RawValue};

pub fn hex(s: &str) -> Vec<u8> {
    (0..s.len() / 2)
        .map(|i| u8::from_str_radix(&s[2 * i..2 * i + 2], 16).unwrap())
        .collect()
}

pub fn json_f64(v: &serde_json::Value) -> f64 {
    match v {
        serde_json::Value::Number(n) => n.as_f64().unwrap(),
        serde_json::Value::String(s) => match s.as_str() {
            "nan" => f64::NAN,
            "inf" => f64::INFINITY,
            "-inf" => f64::NEG_INFINITY,
            other => panic!("unexpected value string {other}"),
        },
        other => panic!("unexpected value {other}"),
    }
}

pub fn raw_equal(ours: RawValue, theirs: &serde_json::Value) -> bool {
    match ours {
        RawValue::Unsigned(u) => theirs.as_u64() == Some(u),
        RawValue::Signed(i) => theirs.as_i64() == Some(i),
        RawValue::F32(_) | RawValue::F64(_) => {
            let (a, b) = (ours.as_f64(), json_f64(theirs));
            (a.is_nan() && b.is_nan()) || a == b
        }
    }
}

pub fn close(a: f64, b: f64) -> bool {
    if a.is_nan() || b.is_nan() {
        return a.is_nan() && b.is_nan();
    }
    a == b || (a - b).abs() <= 1e-9 * a.abs().max(b.abs())
}

/// Check every line of a cantools vector file against `db`; returns (decoded, refused) counts.
/// `db_for` maps a JSON line to the database to use.
pub fn check_vectors<'a>(
    path: &std::path::Path,
    mut db_for: impl FnMut(&serde_json::Value) -> &'a Database,
) -> (usize, usize) {
    let (mut checked, mut refused) = (0usize, 0usize);
    for (n, line) in std::fs::read_to_string(path).unwrap().lines().enumerate() {
        let v: serde_json::Value = serde_json::from_str(line).unwrap();
        let db = db_for(&v);
        let at = format!("{}:{}", path.display(), n + 1);
        let id = v["frame_id"].as_u64().unwrap() as u32;
        let ext = v["is_extended"].as_bool().unwrap();
        let msg = db
            .message(id, ext)
            .unwrap_or_else(|| panic!("{at}: no message 0x{id:X}"));
        assert_eq!(msg.name, v["name"].as_str().unwrap(), "{at}");
        let data = hex(v["data"].as_str().unwrap());
        let mut got: BTreeMap<String, (RawValue, f64)> = BTreeMap::new();
        let res = msg.decode(&data, |i, raw, phys| {
            got.insert(msg.signals[i].name.clone(), (raw, phys));
        });
        if let Some(err) = v.get("error") {
            let err = err.as_str().unwrap();
            assert!(err.contains("multiplexer"), "{at}: unexpected policy {err}");
            assert!(
                matches!(res, Err(DecodeError::UnknownMultiplexerValue { .. })),
                "{at}: cantools refused ({err}) but we decoded {got:?}"
            );
            assert!(got.is_empty(), "{at}: refused frame must deliver nothing");
            refused += 1;
            continue;
        }
        let sum = res.unwrap_or_else(|e| panic!("{at}: {e}"));
        assert_eq!(sum.truncated, 0, "{at}");
        let phys = v["phys"].as_object().unwrap();
        let raw = v["raw"].as_object().unwrap();
        let mut theirs: Vec<&String> = phys.keys().collect();
        theirs.sort();
        let ours: Vec<&String> = got.keys().collect();
        assert_eq!(ours, theirs, "{at}: signal sets differ");
        for (name, (r, p)) in &got {
            assert!(
                raw_equal(*r, &raw[name]),
                "{at}: {name} raw {r:?} vs cantools {}",
                raw[name]
            );
            let want = json_f64(&phys[name]);
            assert!(close(*p, want), "{at}: {name} phys {p} vs cantools {want}");
        }
        checked += 1;
    }
    (checked, refused)
}
