//! Decoding equals cantools 45.1.0 on every expected-decode vector in `vectors/*.jsonl`
//! (raw values exactly, physical values within 1e-9 relative), and where cantools refused a
//! frame (unknown multiplexer value) we refuse it too.

mod dbc_common;

use shimmy::dbc::Database;

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
        let (c, r) = dbc_common::check_vectors(&f, |_| &db);
        checked += c;
        refused += r;
    }
    // Every line is one or the other: 4608 lines in total, 34 refused by cantools.
    assert_eq!(checked + refused, 4608);
    assert_eq!(refused, 34);
}

/// Features the shared vectors do not cover (extended/cascaded multiplexing, CAN FD lengths,
/// negative scaling, 64-bit numbers), decoded by cantools 45.1.0 into a committed fixture
/// (`tests/dbc_fixtures/gen_cantools_vectors.py` regenerates it).
#[test]
fn decoding_matches_cantools_extra_vectors() {
    let Some(dir) = shimmy::shared_data::require("cantools DBC files") else {
        return;
    };
    let fixture = std::path::Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("tests/dbc_fixtures/cantools_extra.vectors.jsonl");
    let mut dbs: std::collections::HashMap<String, Database> = Default::default();
    let text = std::fs::read_to_string(&fixture).unwrap();
    for line in text.lines() {
        let v: serde_json::Value = serde_json::from_str(line).unwrap();
        let f = v["file"].as_str().unwrap().to_string();
        dbs.entry(f.clone())
            .or_insert_with(|| Database::load(dir.join("dbc/cantools").join(&f)).unwrap().0);
    }
    let (checked, refused) =
        dbc_common::check_vectors(&fixture, |v| &dbs[v["file"].as_str().unwrap()]);
    assert_eq!(checked + refused, 1100);
    assert_eq!(refused, 457);
}
