//! A command a test runs that starts its own cargo build (the Python wheel, the fuzz targets,
//! the VM's static binaries, the aarch64 subset, the Debian package, the firmware-sim the
//! end-to-end tests run), freed of the variables cargo sets for the test itself.
//!
//! What it is for: `.ci/run` builds those artifacts before `cargo test` runs; seen by the inner
//! build, cargo's test variables (`CARGO_*` but `CARGO_HOME`, and `OUT_DIR`, which cargo sets
//! for the tests of a package with a build script) change what build scripts see (ring's asks
//! to rerun when `OUT_DIR` or `CARGO_MANIFEST_DIR` differ from the outer cargo's), so they rerun
//! and the inner build recompiles ring and everything above it instead of reusing that work.

use std::process::Command;

/// `cmd` without cargo's test variables (`CARGO_*` but `CARGO_HOME`, and `OUT_DIR`).
pub fn outside_cargo(mut cmd: Command) -> Command {
    for (k, _) in std::env::vars_os() {
        let k = k.to_string_lossy().into_owned();
        if (k.starts_with("CARGO") && k != "CARGO_HOME") || k == "OUT_DIR" {
            cmd.env_remove(k);
        }
    }
    cmd
}
