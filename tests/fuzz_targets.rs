//! Runs every coverage-guided fuzz target of `tests/fuzz` (cargo-fuzz, libFuzzer; the targets
//! and what each checks are in `tests/fuzz/fuzz_targets/`) for a fixed time budget, starting
//! from the committed seed corpus `tests/fuzz/corpus/<target>/`, and fails on any crash, panic,
//! leak, timeout or out-of-memory input (saved as `target/fuzz/artifacts/<target>/crash-*`,
//! reproducible with `cargo +nightly fuzz run --fuzz-dir tests/fuzz <target> <file>`). The
//! executions of each target are written to stderr even when the test passes.
//!
//! Budget per target: `SHIMMY_FUZZ_SECONDS`, default 20 s under `CI=true` and 5 s otherwise.
//! The targets run one after the other (one core each). Without the nightly toolchain or
//! cargo-fuzz the test prints `SKIPPED` with what is missing, except under `CI=true`, where it
//! fails (`.ci/run` installs both: `tests/fuzz/fuzz.sh --install`, then builds the targets with
//! `--prepare`, so the test itself mostly runs).
//!
//! What it is not: a long fuzzing campaign (run `tests/fuzz/fuzz.sh --run TARGET 3600` for one),
//! nor a replacement for the property tests of `tests/logs_fuzz.rs` (those run on stable).

#![cfg(all(target_os = "linux", target_arch = "x86_64"))]

#[path = "support/outside_cargo.rs"]
mod outside_cargo;

use std::io::Write;
use std::path::PathBuf;
use std::process::Command;
use std::sync::Mutex;

/// One target at a time: each fuzzer takes a core for its whole budget.
static SERIAL: Mutex<()> = Mutex::new(());

fn script() -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("tests/fuzz/fuzz.sh")
}

/// Visible in `cargo test` output even on success (libtest captures only the print macros).
fn report(line: &str) {
    let _ = writeln!(std::io::stderr(), "{line}");
}

fn budget_s() -> u64 {
    match std::env::var("SHIMMY_FUZZ_SECONDS") {
        Ok(s) => s
            .parse()
            .unwrap_or_else(|_| panic!("SHIMMY_FUZZ_SECONDS={s:?} is not a whole number")),
        Err(_) if shimmy::shared_data::in_ci() => 20,
        Err(_) => 5,
    }
}

/// `None` when the tools are missing (and this is not CI).
fn ready(target: &str) -> Option<()> {
    let check = Command::new("bash")
        .arg(script())
        .arg("--check")
        .output()
        .expect("run tests/fuzz/fuzz.sh --check");
    if check.status.success() {
        return Some(());
    }
    let why = String::from_utf8_lossy(&check.stdout).trim().to_string();
    if shimmy::shared_data::in_ci() {
        panic!("CI=true requires the fuzz targets to run, but this machine lacks: {why}");
    }
    report(&format!("SKIPPED fuzz target {target}: missing {why}"));
    None
}

/// `runs=N` of the script's `FUZZ-SUMMARY` line.
fn executions(out: &str) -> Option<u64> {
    let line = out.lines().rev().find(|l| l.starts_with("FUZZ-SUMMARY "))?;
    line.split_whitespace()
        .find_map(|w| w.strip_prefix("runs="))?
        .parse()
        .ok()
}

fn fuzz(target: &str) {
    let _serial = SERIAL.lock().unwrap_or_else(|p| p.into_inner());
    if ready(target).is_none() {
        return;
    }
    let secs = budget_s();
    let t0 = std::time::Instant::now();
    let out = outside_cargo::outside_cargo(Command::new("bash"))
        .arg(script())
        .args(["--run", target, &secs.to_string()])
        .output()
        .expect("run tests/fuzz/fuzz.sh --run");
    let text = format!(
        "{}{}",
        String::from_utf8_lossy(&out.stdout),
        String::from_utf8_lossy(&out.stderr)
    );
    let runs = executions(&text);
    report(&format!(
        "fuzz target {target}: {} executions in {secs} s budget ({:.0} s with the build check), {}",
        runs.map_or("?".to_string(), |r| r.to_string()),
        t0.elapsed().as_secs_f64(),
        out.status
    ));
    if !out.status.success() {
        // The fuzzer's own report (the panic, the input's path) is the useful part.
        let tail: Vec<&str> = text.lines().rev().take(60).collect();
        let tail: Vec<&str> = tail.into_iter().rev().collect();
        panic!(
            "fuzz target {target} failed ({}): a crashing input is in target/fuzz/artifacts/{target}/\n{}",
            out.status,
            tail.join("\n")
        );
    }
    let runs =
        runs.unwrap_or_else(|| panic!("fuzz target {target}: no execution count in:\n{text}"));
    // The seed corpus alone is more than this; fewer means the fuzzer did not really run.
    assert!(runs >= 100, "fuzz target {target}: only {runs} executions");
}

#[test]
fn fuzz_candump_reader() {
    fuzz("candump");
}

#[test]
fn fuzz_asc_reader() {
    fuzz("asc");
}

#[test]
fn fuzz_trc_reader() {
    fuzz("trc");
}

#[test]
fn fuzz_blf_reader() {
    fuzz("blf");
}

#[test]
fn fuzz_dbc_loader() {
    fuzz("dbc");
}

#[test]
fn fuzz_journal_reader() {
    fuzz("journal");
}

#[test]
fn every_target_has_a_test_and_seeds() {
    let list = Command::new("bash")
        .arg(script())
        .arg("--list")
        .output()
        .expect("run tests/fuzz/fuzz.sh --list");
    let targets: Vec<String> = String::from_utf8_lossy(&list.stdout)
        .lines()
        .map(str::to_string)
        .collect();
    assert_eq!(targets, ["candump", "asc", "trc", "blf", "dbc", "journal"]);
    let root = PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("tests/fuzz");
    let mut total = 0u64;
    for t in &targets {
        assert!(root.join(format!("fuzz_targets/{t}.rs")).is_file(), "{t}");
        let seeds: Vec<_> = std::fs::read_dir(root.join("corpus").join(t))
            .unwrap_or_else(|e| panic!("corpus of {t}: {e}"))
            .map(|e| e.unwrap().metadata().unwrap().len())
            .collect();
        assert!(!seeds.is_empty(), "corpus of {t} is empty");
        total += seeds.iter().sum::<u64>();
    }
    assert!(
        total < 1 << 20,
        "seed corpus is {total} bytes; keep it well under 1 MiB"
    );
}
