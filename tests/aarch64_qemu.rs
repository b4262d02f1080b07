//! Runs a fixed subset of the test suite on aarch64 (the gateway's CPU) under QEMU user
//! emulation: `tests/aarch64/qemu.sh` cross-builds it for `aarch64-unknown-linux-gnu`, linked
//! dynamically against Debian's arm64 glibc as the shipped package is, into its own target
//! directory (`target/aarch64`, so it never waits for the lock of the build running this test),
//! and runs it with `cargo test --target aarch64-unknown-linux-gnu` through the QEMU runner of
//! `.cargo/config.toml`.
//!
//! The subset (`tests/aarch64/qemu.sh --list`), chosen for what a gateway does and what could
//! differ on another CPU (alignment, `c_char` signedness, the C and assembly that can-dbc's
//! parser pulls in, the libc structures of file I/O and signals), and because each needs no
//! network, no VM and no Python:
//! - `dbc_vectors`: decoding equals cantools' committed vectors, bit for bit;
//! - `logs_candump`, `logs_vector`, `logs_mf4`: the log readers (candump -L, ASC/BLF, MDF 4
//!   with deflate) on real files;
//! - `daemon_replay`: shimmyd end to end as a process on the real RAV4 log, state resumed,
//!   SIGTERM mid-replay;
//! - `journal_crash`: shimmyd's journal appended by a process killed with SIGKILL many times.
//!
//! The two process tests start the aarch64 `shimmyd` themselves, so the kernel must hand
//! aarch64 executables to QEMU (binfmt_misc; `tests/aarch64/qemu.sh --binfmt`, which `.ci/run`
//! does). Each test's pass count, and the build and run times, are written to stderr even when
//! the test passes. Without the cross linker, the arm64 glibc, Rust's aarch64 std, QEMU or the
//! binfmt handler the test prints `SKIPPED` with the reason, except under `CI=true`, where it
//! fails: CI must really run it (`.ci/run` installs and prepares all of it).
//!
//! What it is not: a test of the live CAN path on aarch64 (that needs a CAN bus: the vcan suite
//! runs on x86_64 only), nor a benchmark (emulated time says nothing of a gateway's speed).

#![cfg(all(target_os = "linux", target_arch = "x86_64"))]

#[path = "support/outside_cargo.rs"]
mod outside_cargo;

use std::io::{BufRead, BufReader, Write};
use std::path::PathBuf;
use std::process::{Command, Stdio};

fn workspace() -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR"))
}

/// Visible in `cargo test` output even on success (libtest captures only the print macros).
fn report(line: &str) {
    let _ = writeln!(std::io::stderr(), "{line}");
}

/// One test executable's closing line, as libtest prints it.
#[derive(Debug)]
struct Outcome {
    target: String,
    passed: u32,
    failed: u32,
    ignored: u32,
    line: String,
}

/// `N passed; M failed; K ignored` from a libtest `test result:` line.
fn counts(line: &str) -> Option<(u32, u32, u32)> {
    let rest = &line[line.find("test result:")?..];
    let num = |word: &str| -> Option<u32> {
        let end = rest.find(word)?;
        rest[..end].trim_end().rsplit(' ').next()?.parse().ok()
    };
    Some((num(" passed")?, num(" failed")?, num(" ignored")?))
}

#[test]
fn aarch64_subset_passes_under_qemu() {
    let root = workspace();
    let script = root.join("tests/aarch64/qemu.sh");
    let check = Command::new("bash")
        .arg(&script)
        .arg("--check")
        .output()
        .expect("run tests/aarch64/qemu.sh --check");
    if !check.status.success() {
        let why = String::from_utf8_lossy(&check.stdout)
            .trim()
            .replace('\n', "; ");
        if shimmy::shared_data::in_ci() {
            panic!("CI=true requires the aarch64 tests to run, but this machine lacks: {why}");
        }
        report(&format!("SKIPPED aarch64_qemu: missing {why}"));
        return;
    }
    let list = Command::new("bash")
        .arg(&script)
        .arg("--list")
        .output()
        .expect("run tests/aarch64/qemu.sh --list");
    let expected: Vec<String> = String::from_utf8_lossy(&list.stdout)
        .lines()
        .map(str::to_string)
        .collect();
    assert!(!expected.is_empty(), "qemu.sh --list printed no tests");
    report(&format!(
        "aarch64_qemu: building and running under QEMU: {}",
        expected.join(" ")
    ));

    let mut child = outside_cargo::outside_cargo(Command::new("bash"))
        .arg(&script)
        .arg("--run")
        .current_dir(&root)
        .stdout(Stdio::piped())
        .stderr(Stdio::inherit())
        .spawn()
        .expect("start tests/aarch64/qemu.sh");
    let mut outcomes: Vec<Outcome> = Vec::new();
    let mut running: Option<String> = None;
    let mut summary = None;
    for line in BufReader::new(child.stdout.take().unwrap()).lines() {
        let line = line.expect("read qemu.sh output");
        // Everything goes to the captured output (shown when the test fails).
        println!("{line}");
        let t = line.trim();
        if let Some(r) = t.strip_prefix("Running ") {
            // `Running tests/dbc_vectors.rs (target/aarch64/.../dbc_vectors-0123abcd)`
            running = r
                .split_whitespace()
                .next()
                .and_then(|p| p.strip_prefix("tests/"))
                .and_then(|p| p.strip_suffix(".rs"))
                .map(str::to_string);
        } else if let Some((passed, failed, ignored)) = counts(t) {
            outcomes.push(Outcome {
                target: running.take().unwrap_or_else(|| "?".into()),
                passed,
                failed,
                ignored,
                line: t.to_string(),
            });
        } else if t.starts_with("AARCH64-SUMMARY ") {
            summary = Some(t.to_string());
        }
    }
    let status = child.wait().expect("wait for tests/aarch64/qemu.sh");

    report("aarch64_qemu: results on aarch64-unknown-linux-gnu (QEMU user emulation):");
    for o in &outcomes {
        report(&format!(
            "  {:<14} {} passed, {} failed, {} ignored",
            o.target, o.passed, o.failed, o.ignored
        ));
    }
    let (passed, failed): (u32, u32) = outcomes
        .iter()
        .fold((0, 0), |(p, f), o| (p + o.passed, f + o.failed));
    report(&format!("  total: {passed} passed, {failed} failed"));
    report(&format!(
        "  {}",
        summary.as_deref().unwrap_or("no AARCH64-SUMMARY line")
    ));

    assert!(
        status.success(),
        "the aarch64 subset failed ({status}); see the output above"
    );
    for name in &expected {
        let o = outcomes
            .iter()
            .find(|o| &o.target == name)
            .unwrap_or_else(|| panic!("{name} did not run on aarch64 (no result line)"));
        assert_eq!(o.failed, 0, "{name} failed on aarch64: {}", o.line);
        assert!(o.passed > 0, "{name} ran no test on aarch64: {}", o.line);
    }
    assert!(summary.is_some(), "qemu.sh printed no AARCH64-SUMMARY line");
}

#[test]
fn result_lines_are_parsed() {
    let l = "test result: ok. 5 passed; 0 failed; 1 ignored; 0 measured; 0 filtered out; finished in 3.21s";
    assert_eq!(counts(l), Some((5, 0, 1)));
    let l = "test result: FAILED. 3 passed; 2 failed; 0 ignored; 0 measured; 0 filtered out";
    assert_eq!(counts(l), Some((3, 2, 0)));
    assert_eq!(counts("running 5 tests"), None);
}
