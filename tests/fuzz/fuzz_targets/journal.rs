//! The journal's reading side on arbitrary bytes as `current.jsonl`: the line decoder, the
//! [`shimmy::journal::Reader`] and the recovery of [`shimmy::journal::Journal::open`]. No
//! panic; the reader yields strictly increasing sequence numbers and counts every other line;
//! recovery keeps exactly the valid records and the journal continues after the last of them.
#![no_main]

use std::path::PathBuf;
use std::sync::OnceLock;

use shimmy::journal::{line, FsyncPolicy, Journal, JournalConfig, Reader, CURRENT};

fn dir() -> &'static PathBuf {
    static DIR: OnceLock<PathBuf> = OnceLock::new();
    DIR.get_or_init(|| {
        // One directory per process (libFuzzer may run several), on tmpfs when there is one.
        let base = if std::path::Path::new("/dev/shm").is_dir() {
            PathBuf::from("/dev/shm")
        } else {
            std::env::temp_dir()
        };
        let d = base.join(format!("shimmy-fuzz-journal-{}", std::process::id()));
        std::fs::create_dir_all(&d).expect("fuzz scratch directory");
        d
    })
}

fn read_all(d: &std::path::Path) -> (Vec<u64>, u64, u64) {
    let mut r = Reader::open(d).expect("the directory holds current.jsonl");
    let seqs: Vec<u64> = (&mut r).map(|e| e.expect("local reads").seq).collect();
    (seqs, r.invalid_lines(), r.out_of_order())
}

libfuzzer_sys::fuzz_target!(|data: &[u8]| {
    // The line decoder alone, on every line of the input.
    let lines: Vec<&[u8]> = data.split_inclusive(|&b| b == b'\n').collect();
    let valid_lines = lines.iter().filter(|l| line::decode(l).is_ok()).count() as u64;

    let d = dir();
    let cur = d.join(CURRENT);
    std::fs::write(&cur, data).expect("write scratch journal");

    let (seqs, invalid, ooo) = read_all(d);
    assert!(seqs.windows(2).all(|w| w[0] < w[1]), "reader order {seqs:?}");
    assert_eq!(seqs.len() as u64 + ooo, valid_lines);
    assert_eq!(
        seqs.len() as u64 + ooo + invalid,
        lines.len() as u64,
        "every line is a record, out of order or invalid"
    );

    let cfg = JournalConfig {
        fsync: FsyncPolicy::IntervalMs(60_000),
        rotate_bytes: 1 << 30,
    };
    let mut new = None;
    let corrupt = {
        let (mut j, rec) = Journal::open(d, cfg).expect("recovery of a local file");
        assert_eq!(rec.records, valid_lines);
        let last_valid = lines
            .iter()
            .rev()
            .find_map(|l| line::decode(l).ok())
            .map(|(s, _)| s);
        assert_eq!(rec.last_seq, last_valid);
        let next = j.next_seq();
        // The journal continues after every sequence number it holds.
        assert!(
            seqs.last().is_none_or(|&s| next > s),
            "next {next} after {seqs:?}"
        );
        match j.append(&serde_json::json!({"after": "recovery"})) {
            Ok(s) => new = Some(s),
            // Only a journal whose numbers are exhausted may refuse (with an error).
            Err(e) => assert!(next == u64::MAX, "append after recovery: {e:#}"),
        }
        rec.corrupt_lines
    };
    // After recovery and one append: the old valid records and the new one, in order; the
    // invalid lines left are those before the last valid one (the torn tail is gone).
    let (seqs2, invalid2, _) = read_all(d);
    assert!(seqs2.windows(2).all(|w| w[0] < w[1]));
    assert_eq!(seqs2.last().copied(), new.or(seqs.last().copied()));
    assert_eq!(invalid2, corrupt);
    let _ = std::fs::remove_file(&cur);
});
