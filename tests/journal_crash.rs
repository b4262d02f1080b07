//! Crash test (issue 6): a real process appending to the journal is killed with SIGKILL at
//! random moments and restarted, many times. Every record it acknowledged (fsynced, then
//! printed on stdout) must be in the journal afterwards, the sequence must be gap-free, and
//! the journal must always parse.

use std::io::{BufRead, BufReader};
use std::process::{Command, Stdio};
use std::time::Duration;

use rand::{Rng, SeedableRng};
use shimmy::journal::Reader;

#[test]
fn sigkill_at_random_moments_loses_no_acknowledged_record() {
    let dir = tempfile::tempdir().unwrap();
    let jdir = dir.path().join("journal");
    let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(0x5eed);
    let mut max_acked = 0u64;
    let mut kills = 0;
    for round in 0..20 {
        let mut child = Command::new(env!("CARGO_BIN_EXE_shimmyd"))
            .arg("--journal-stress")
            .arg(&jdir)
            .stdout(Stdio::piped())
            .stderr(Stdio::inherit())
            .spawn()
            .expect("spawn shimmyd");
        let stdout = child.stdout.take().unwrap();
        let (started_tx, started_rx) = std::sync::mpsc::channel();
        let reader = std::thread::spawn(move || {
            let mut acked = 0u64;
            let mut recovered = String::new();
            for line in BufReader::new(stdout).lines() {
                let Ok(line) = line else { break };
                if let Some(n) = line.strip_prefix("ack ") {
                    acked = n.parse().unwrap();
                } else if let Some(r) = line.strip_prefix("recovered ") {
                    recovered = r.to_string();
                    let _ = started_tx.send(());
                }
            }
            (acked, recovered)
        });
        // The kill lands at a random moment of the writing, counted from the end of the
        // writer's recovery (on a loaded machine starting the process alone can take longer
        // than the shortest delay).
        let _ = started_rx.recv_timeout(Duration::from_secs(30));
        std::thread::sleep(Duration::from_millis(rng.random_range(1..130)));
        child.kill().expect("SIGKILL"); // Child::kill sends SIGKILL on Unix.
        let status = child.wait().unwrap();
        assert!(
            !status.success(),
            "round {round}: the writer should have been killed"
        );
        kills += 1;
        let (acked, recovered) = reader.join().unwrap();
        assert!(!recovered.is_empty(), "round {round}: writer never started");
        // The restart's recovery saw every record acknowledged before.
        let rec: serde_json::Value = serde_json::from_str(&recovered).unwrap();
        let last = rec["last_seq"].as_u64().unwrap_or(0);
        assert!(
            last >= max_acked,
            "round {round}: restart found last seq {last} < acked {max_acked}"
        );
        max_acked = max_acked.max(acked);

        // After every kill the journal parses and holds 1..=N without gaps, N >= max_acked.
        // (A torn tail of the last write may be present until the next open cuts it.)
        let mut r = Reader::open(&jdir).unwrap();
        let mut expect = 1u64;
        for e in &mut r {
            let e = e.unwrap();
            assert_eq!(e.seq, expect, "round {round}: gap or duplicate");
            assert_eq!(e.rec["n"].as_u64(), Some(e.seq));
            expect += 1;
        }
        assert!(r.invalid_lines() <= 1, "round {round}: {:?}", r.problems());
        assert!(
            expect - 1 >= max_acked,
            "round {round}: lost acknowledged records: have {} acked {max_acked}",
            expect - 1
        );
    }
    assert_eq!(kills, 20);
    assert!(
        max_acked > 100,
        "the writer acknowledged only {max_acked} records"
    );
    // Rotation happened (8 KiB segments) and the reader crossed the segments.
    let segs = shimmy::journal::segments(&jdir).unwrap();
    assert!(segs.len() > 3, "expected rotated segments, got {segs:?}");
}
