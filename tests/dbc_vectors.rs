//! Decoding equals cantools 45.1.0 on every expected-decode vector in `vectors/*.jsonl`
//! (raw values exactly, physical values within 1e-9 relative), and where cantools refused a
//! frame (unknown multiplexer value) we refuse it too.

use std::collections::BTreeMap;

use shimmy::dbc::{Database, DecodeError, RawValue};

fn hex(s: &str) -> Vec<u8> {
    (0..s.len() / 2)
        .map(|i| u8::from_str_radix(&s[2 * i..2 * i + 2], 16).unwrap())
        .collect()
}

fn json_f64(v: &serde_json::Value) -> f64 {
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

fn raw_equal(ours: RawValue, theirs: &serde_json::Value) -> bool {
    match ours {
        RawValue::Unsigned(u) => theirs.as_u64() == Some(u),
        RawValue::Signed(i) => theirs.as_i64() == Some(i),
        RawValue::F32(_) | RawValue::F64(_) => {
            let (a, b) = (ours.as_f64(), json_f64(theirs));
            (a.is_nan() && b.is_nan()) || a == b
        }
    }
}

fn close(a: f64, b: f64) -> bool {
    if a.is_nan() || b.is_nan() {
        return a.is_nan() && b.is_nan();
    }
    a == b || (a - b).abs() <= 1e-9 * a.abs().max(b.abs())
}

#[test]
fn decoding_matches_cantools_vectors() {
    let Some(dir) = shimmy::shared_data::require("cantools vectors") else {
        return;
    };
    let mut files: Vec<_> = std::fs::read_dir(dir.join("vectors"))
        .unwrap()
        .map(|e| e.unwrap().path())
        .filter(|p| p.to_string_lossy().ends_with(".vectors.jsonl"))
        .collect();
    files.sort();
    assert!(
        files.len() >= 8,
        "expected the 8 vector files, found {files:?}"
    );
    let (mut checked, mut refused) = (0usize, 0usize);
    for f in files {
        let stem = f
            .file_name()
            .unwrap()
            .to_string_lossy()
            .trim_end_matches(".vectors.jsonl")
            .to_string();
        let (db, _report) = Database::load(dir.join(format!("dbc/cantools/{stem}.dbc"))).unwrap();
        for (n, line) in std::fs::read_to_string(&f).unwrap().lines().enumerate() {
            let v: serde_json::Value = serde_json::from_str(line).unwrap();
            let at = format!("{}:{}", f.display(), n + 1);
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
            let theirs: Vec<&String> = phys.keys().collect();
            let ours: Vec<&String> = got.keys().collect();
            let mut theirs_sorted = theirs.clone();
            theirs_sorted.sort();
            assert_eq!(ours, theirs_sorted, "{at}: signal sets differ");
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
    }
    // Every line is one or the other: 4608 lines in total, 34 refused by cantools.
    assert_eq!(checked + refused, 4608);
    assert_eq!(refused, 34);
}
