//! Where the shared real test material lives (`../shared/data`: production DBCs, real CAN logs,
//! cantools vectors). One setting for every test and benchmark: the environment variable
//! `SHIMMY_DATA_DIR`, defaulting to `<workspace>/../shared/data`.
//!
//! This module is not test policy beyond one rule: when the material is absent, callers skip and
//! say so, except under `CI=true`, where its absence is a failure.

use std::path::PathBuf;

/// The configured data directory, whether or not it exists.
pub fn configured_dir() -> PathBuf {
    match std::env::var_os("SHIMMY_DATA_DIR") {
        Some(p) => PathBuf::from(p),
        None => PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../shared/data"),
    }
}

/// True when running under CI (`CI=true`), where missing material must fail rather than skip.
pub fn in_ci() -> bool {
    std::env::var("CI")
        .map(|v| v == "true" || v == "1")
        .unwrap_or(false)
}

/// The data directory if it exists. When it does not: under CI this panics with the path it
/// looked at; elsewhere it prints a clear skip notice naming `what` and returns `None`.
pub fn require(what: &str) -> Option<PathBuf> {
    let dir = configured_dir();
    if dir.is_dir() {
        return Some(dir);
    }
    if in_ci() {
        panic!(
            "shared test data not found at {} (needed for {what}); set SHIMMY_DATA_DIR",
            dir.display()
        );
    }
    eprintln!(
        "SKIPPED {what}: shared test data not found at {} (set SHIMMY_DATA_DIR)",
        dir.display()
    );
    None
}

/// A file under the data directory (see [`require`] for what happens when it is missing).
pub fn require_file(rel: &str) -> Option<PathBuf> {
    let dir = require(rel)?;
    let p = dir.join(rel);
    if p.exists() {
        return Some(p);
    }
    if in_ci() {
        panic!("shared test file missing: {}", p.display());
    }
    eprintln!("SKIPPED: shared test file missing: {}", p.display());
    None
}
