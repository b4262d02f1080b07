//! Runs the vcan suite (`tests/vcan/suite.txt`: `live_vcan`, firmware-sim's `e2e_vcan`,
//! `shimmyd_e2e_vcan`, the daemon's live path, and `shimmyd_load_vcan`, that path at 8,000
//! frames/s) against a real kernel CAN bus, wherever this machine can provide one:
//!
//! 1. the host has a CAN interface (`SHIMMY_VCAN_IF`, default `vcan0`), or can create `vcan0`
//!    (root and a kernel with the vcan module): `tests/vcan/vm.sh --host` builds the suite
//!    (the workspace's release test build) and runs it here with `SHIMMY_REQUIRE_VCAN=1`;
//! 2. otherwise, if QEMU and a static busybox are installed: `tests/vcan/vm.sh --vm` boots
//!    Debian's kernel with its CAN modules in QEMU and runs the suite there;
//! 3. otherwise the test prints `SKIPPED` with the reason, except under `CI=true`, where it
//!    fails: CI must really run the vcan tests (`.ci/run` installs what the VM needs).
//!
//! The per-ID frame counts (`VCAN-COUNTS` lines), each step's result and the boot/run times are
//! written to stderr even when the test passes.

#![cfg(target_os = "linux")]

#[path = "support/outside_cargo.rs"]
mod outside_cargo;

use std::io::{BufRead, BufReader, Write};
use std::path::{Path, PathBuf};
use std::process::{Command, Stdio};

fn workspace() -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR"))
}

/// Visible in `cargo test` output even on success (libtest captures only the print macros).
fn report(line: &str) {
    let _ = writeln!(std::io::stderr(), "{line}");
}

fn run_ok(cmd: &str, args: &[&str]) -> bool {
    Command::new(cmd)
        .args(args)
        .stdout(Stdio::null())
        .stderr(Stdio::null())
        .status()
        .is_ok_and(|s| s.success())
}

fn is_root() -> bool {
    std::fs::read_to_string("/proc/self/status")
        .ok()
        .and_then(|s| {
            s.lines()
                .find(|l| l.starts_with("Uid:"))
                .map(|l| l.split_whitespace().nth(2) == Some("0"))
        })
        .unwrap_or(false)
}

/// True when the host has (or, as root, could create) the CAN interface.
fn host_vcan(iface: &str) -> bool {
    let present = |i: &str| Path::new("/sys/class/net").join(i).exists();
    if present(iface) {
        return true;
    }
    if iface != "vcan0" || !is_root() {
        return false;
    }
    let _ = run_ok("modprobe", &["vcan"]);
    run_ok("ip", &["link", "add", "dev", "vcan0", "type", "vcan"])
        && run_ok("ip", &["link", "set", "up", "vcan0"])
        && present("vcan0")
}

/// Why the VM cannot run here, or `None` when it can.
fn vm_missing(script: &Path) -> Option<String> {
    match Command::new("bash").arg(script).arg("--check").output() {
        Ok(o) if o.status.success() => None,
        Ok(o) => Some(
            String::from_utf8_lossy(&o.stdout)
                .trim()
                .replace('\n', "; "),
        ),
        Err(e) => Some(format!("cannot run bash: {e}")),
    }
}

#[test]
fn vcan_suite_on_a_real_can_bus() {
    let root = workspace();
    let script = root.join("tests/vcan/vm.sh");
    let iface = std::env::var("SHIMMY_VCAN_IF").unwrap_or_else(|_| "vcan0".into());
    let mode = if host_vcan(&iface) {
        "--host"
    } else if let Some(missing) = vm_missing(&script) {
        let why = format!(
            "no {iface} on this host (kernel without vcan, or not root) and no QEMU VM: {missing}"
        );
        if shimmy::shared_data::in_ci() {
            panic!("CI=true requires the vcan tests to run, but {why}");
        }
        report(&format!("SKIPPED vcan_vm: {why}"));
        return;
    } else {
        "--vm"
    };
    report(&format!(
        "vcan_vm: running the vcan suite with {script:?} {mode}"
    ));

    let mut child = outside_cargo::outside_cargo(Command::new("bash"))
        .arg(&script)
        .arg(mode)
        .current_dir(&root)
        .stdout(Stdio::piped())
        .stderr(Stdio::inherit())
        .spawn()
        .expect("start tests/vcan/vm.sh");
    let mut counts = Vec::new();
    let mut results = Vec::new();
    let mut summary = None;
    for line in BufReader::new(child.stdout.take().unwrap()).lines() {
        let line = line.expect("read harness output");
        // The whole console goes to the captured output (shown when the test fails).
        println!("{line}");
        // Markers may follow terminal escapes from the VM firmware on the same line.
        let marked = |m: &str| line.find(m).map(|i| line[i..].trim_end().to_string());
        if let Some(l) = marked("VCAN-COUNTS ") {
            counts.push(l);
        } else if let Some(l) = marked("SHIMMY-VM-RESULT ").or_else(|| marked("SHIMMY-VM-BOOTED "))
        {
            results.push(l);
        } else if let Some(l) = marked("SHIMMY-VM-SUMMARY ") {
            summary = Some(l);
        }
    }
    let status = child.wait().expect("wait for tests/vcan/vm.sh");

    report("vcan_vm: frames per message (sent / received / lost):");
    for c in &counts {
        report(&format!("  {c}"));
    }
    for r in &results {
        report(&format!("  {r}"));
    }
    report(&format!(
        "  {}",
        summary.as_deref().unwrap_or("no SHIMMY-VM-SUMMARY line")
    ));

    assert!(
        status.success(),
        "vcan suite failed ({status}); see the output above"
    );
    assert!(
        counts.iter().any(|c| c.contains("test=reference_bus_load")),
        "the suite printed no reference bus counts"
    );
    assert!(
        counts.iter().any(|c| c.contains("test=shimmyd_live")),
        "the suite printed no counts of the daemon's live run"
    );
    assert!(
        counts
            .iter()
            .any(|c| c.contains("test=shimmyd_load_compressed")),
        "the suite printed no counts of the daemon under a full bus"
    );
    // Every message of every test arrives complete, except in the test that overflows a
    // receive queue on purpose (its drops are counted, which it checks itself).
    for c in counts.iter().filter(|c| !c.contains("test=overflow")) {
        assert!(c.ends_with(" lost=0"), "frames lost: {c}");
    }
}
