//! Setup shared by the tests that need a real kernel CAN bus: `tests/live_vcan.rs`,
//! `tests/shimmyd_e2e_vcan.rs` and `firmware-sim/tests/e2e_vcan.rs` (which includes this file
//! with `#[path = "../../tests/vcan_common/mod.rs"]`).
//!
//! What it does: finds the test interface (`SHIMMY_VCAN_IF`, default `vcan0`) or says why the
//! test is skipped (or panics when `SHIMMY_REQUIRE_VCAN=1`, as in the QEMU VM of
//! `tests/vcan/vm.sh`), builds the reader configuration the tests use, and finds the
//! executables a test starts as processes (cargo's path on the build host, the `PATH` in the VM).
//! What it is not: a test, or a wrapper around `shimmy::source::socketcan`.
#![allow(dead_code)] // each test crate uses a different subset

use std::path::{Path, PathBuf};
use std::time::Duration;

use shimmy::source::socketcan::{FilterId, LiveConfig};

/// `SHIMMY_REQUIRE_VCAN=1`: a missing interface is a failure, not a skip.
pub fn required() -> bool {
    std::env::var("SHIMMY_REQUIRE_VCAN").is_ok_and(|v| v == "1")
}

/// The test interface, or `None` after printing why `test` is skipped.
pub fn iface(test: &str) -> Option<String> {
    let name = std::env::var("SHIMMY_VCAN_IF").unwrap_or_else(|_| "vcan0".into());
    if Path::new("/sys/class/net").join(&name).exists() {
        return Some(name);
    }
    let why = format!(
        "no CAN interface {name} (one-time setup: sudo modprobe vcan; sudo ip link add dev {name} \
         type vcan; sudo ip link set up {name}; or let tests/vcan_vm.rs run this in QEMU)"
    );
    if required() {
        panic!("SHIMMY_REQUIRE_VCAN=1 but {why}");
    }
    eprintln!("SKIPPED {test}: {why}");
    None
}

/// A reader of `ids` only (kernel filters), without error frames, returning
/// `ErrorKind::TimedOut` after 50 ms without a frame.
pub fn reader_config(iface: &str, ids: &[FilterId]) -> LiveConfig {
    let mut cfg = LiveConfig::new(iface);
    cfg.ids = Some(ids.to_vec());
    cfg.error_mask = 0;
    cfg.read_timeout = Duration::from_millis(50);
    cfg
}

/// An executable a test runs as a process: `cargo_path` (an `env!("CARGO_BIN_EXE_...")`) when
/// it exists, as on the build host; else `name`, found on the `PATH` (the VM of
/// `tests/vcan/vm.sh` puts the suite's static executables there).
pub fn executable(cargo_path: &str, name: &str) -> PathBuf {
    let p = PathBuf::from(cargo_path);
    if p.exists() {
        p
    } else {
        PathBuf::from(name)
    }
}
