//! Optional cross-check (`#[ignore]`, needs a file generated with cantools, see
//! `tests/dbc_fixtures/gen_cantools_all.py`): every message of every DBC that cantools can load
//! decodes like cantools on random, all-0x00 and all-0xFF payloads. Where cantools cannot
//! unpack a frame because a signal lies past the declared length, we decode what fits and flag
//! the rest (our documented short-frame policy), which this test checks instead.

mod dbc_common;

use std::collections::{BTreeMap, HashMap};

use shimmy::dbc::{Database, DecodeError, RawValue};

/// True when two signals of the message share a bit.
fn overlaps(msg: &shimmy::dbc::Message) -> bool {
    let masks: Vec<Vec<u8>> = msg
        .signals
        .iter()
        .map(|s| {
            let mut d = vec![0u8; 64];
            let ones = match s.kind {
                shimmy::dbc::ValueKind::Float32 => RawValue::F32(f32::from_bits(u32::MAX)),
                shimmy::dbc::ValueKind::Float64 => RawValue::F64(f64::from_bits(u64::MAX)),
                shimmy::dbc::ValueKind::Signed => RawValue::Signed(-1),
                shimmy::dbc::ValueKind::Unsigned => RawValue::Unsigned(u64::MAX >> (64 - s.size)),
            };
            s.encode_raw(ones, &mut d).unwrap();
            d
        })
        .collect();
    (0..masks.len())
        .any(|i| (0..i).any(|j| masks[i].iter().zip(&masks[j]).any(|(a, b)| a & b != 0)))
}

#[test]
#[ignore = "needs SHIMMY_CANTOOLS_ALL=<file from tests/dbc_fixtures/gen_cantools_all.py>"]
fn every_dbc_decodes_like_cantools() {
    let Ok(vectors) = std::env::var("SHIMMY_CANTOOLS_ALL") else {
        panic!("set SHIMMY_CANTOOLS_ALL to the generated JSON-lines file");
    };
    let Some(dir) = shimmy::shared_data::require("DBC corpus") else {
        return;
    };
    let mut dbs: HashMap<String, Database> = HashMap::new();
    let (mut checked, mut refused, mut flagged) = (0, 0, 0);
    for (n, line) in std::fs::read_to_string(&vectors)
        .unwrap()
        .lines()
        .enumerate()
    {
        let v: serde_json::Value = serde_json::from_str(line).unwrap();
        let path = v["path"].as_str().unwrap().to_string();
        let db = dbs
            .entry(path.clone())
            .or_insert_with(|| Database::load(dir.join(&path)).unwrap().0);
        let at = format!("{path} line {}", n + 1);
        let name = v["name"].as_str().unwrap();
        let msg = &db.messages()[db
            .message_by_name(name)
            .unwrap_or_else(|| panic!("{at}: no message {name}"))];
        let data = dbc_common::hex(v["data"].as_str().unwrap());
        let mut got: BTreeMap<String, (RawValue, f64)> = BTreeMap::new();
        let res = msg.decode(&data, |i, raw, phys| {
            got.insert(msg.signals[i].name.clone(), (raw, phys));
        });
        if let Some(err) = v.get("error").and_then(|e| e.as_str()) {
            if err.contains("unpacking failed") {
                // cantools cannot unpack signals past the declared length, nor overlapping
                // ones; we decode what fits (flagging the rest) and decode overlaps as given.
                let sum = res.unwrap();
                assert!(
                    sum.truncated > 0 || overlaps(msg),
                    "{at}: cantools could not unpack, but nothing is truncated or overlapping"
                );
                flagged += 1;
            } else {
                assert!(
                    matches!(res, Err(DecodeError::UnknownMultiplexerValue { .. })),
                    "{at}: cantools refused ({err}) but we decoded {got:?}"
                );
                refused += 1;
            }
            continue;
        }
        res.unwrap_or_else(|e| panic!("{at}: {e}"));
        let (phys, raw) = (
            v["phys"].as_object().unwrap(),
            v["raw"].as_object().unwrap(),
        );
        let mut theirs: Vec<&String> = phys.keys().collect();
        theirs.sort();
        assert_eq!(
            got.keys().collect::<Vec<_>>(),
            theirs,
            "{at}: signal sets differ"
        );
        for (k, (r, p)) in &got {
            assert!(
                dbc_common::raw_equal(*r, &raw[k]),
                "{at}: {k} raw {r:?} vs {}",
                raw[k]
            );
            let want = dbc_common::json_f64(&phys[k]);
            assert!(dbc_common::close(*p, want), "{at}: {k} phys {p} vs {want}");
        }
        checked += 1;
    }
    eprintln!("checked {checked}, refused {refused}, flagged {flagged}");
    assert!(checked > 1000);
}
