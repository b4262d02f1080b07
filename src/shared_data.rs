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

/// The real RAV4 drive (comma2k19, candump -L, bus 0) under the data directory.
pub const RAV4_LOG: &str = "logs/comma2k19-rav4/rav4_2017_seg40_bus0.log";
/// The opendbc DBC that decodes [`RAV4_LOG`].
pub const RAV4_DBC: &str = "dbc/opendbc/toyota_new_mc_pt_generated.dbc";

/// The RAV4 log and its DBC, as (log, dbc) (see [`require`] for what happens when either is
/// missing).
pub fn require_rav4() -> Option<(PathBuf, PathBuf)> {
    Some((require_file(RAV4_LOG)?, require_file(RAV4_DBC)?))
}
