//! The Python package (python/: `shimmy_monitor`, a PyO3 + maturin abi3 wheel) and its pytest
//! suite (python/tests): `python/ci.sh --test` builds the wheel, installs it into a virtual
//! environment under target/py-venv with pytest, pyarrow, duckdb and pyspark, and runs the
//! suite, which compares the package's decode, estimate, export and events with this build's
//! `shimmy` CLI on the shared real logs and on firmware-sim drives, runs the Spark fleet job on
//! PySpark local[2] over a simulated fleet, and the DuckDB queries over its lake.
//!
//! Outside CI it skips, saying why, when python3 (with venv), java or the shared data is
//! missing, or the pip packages cannot be installed (no network); under CI=true each of those
//! is a failure.

mod e2e_common;
#[path = "support/outside_cargo.rs"]
mod outside_cargo;

use std::process::Command;

use shimmy::shared_data::{configured_dir, in_ci};

fn skip_or_fail(why: &str) {
    if in_ci() {
        panic!("python package test cannot run: {why}");
    }
    eprintln!("SKIPPED python_package: {why}");
}

#[test]
fn python_package_matches_the_cli_and_runs_the_fleet_job() {
    let root = e2e_common::workspace();
    let script = root.join("python/ci.sh");
    let check = Command::new("bash").arg(&script).arg("--check").output();
    match check {
        Ok(o) if o.status.success() => {}
        Ok(o) => {
            return skip_or_fail(String::from_utf8_lossy(&o.stdout).trim());
        }
        Err(e) => return skip_or_fail(&format!("cannot run bash: {e}")),
    }
    let data = configured_dir();
    if !data.is_dir() {
        return skip_or_fail(&format!(
            "shared test data not found at {} (set SHIMMY_DATA_DIR)",
            data.display()
        ));
    }
    // The environment first (a separate step, so that no network outside CI is a skip).
    let venv = outside_cargo::outside_cargo(Command::new("bash"))
        .arg(&script)
        .arg("--venv")
        .status()
        .expect("run python/ci.sh --venv");
    if !venv.success() {
        return skip_or_fail("python/ci.sh --venv failed (pip install: no network?)");
    }
    let out = outside_cargo::outside_cargo(Command::new("bash"))
        .arg(&script)
        .arg("--test")
        .arg("-q")
        .env("SHIMMY_BIN", env!("CARGO_BIN_EXE_shimmy"))
        .env("FIRMWARE_SIM_BIN", e2e_common::firmware_sim())
        .env("SHIMMY_DATA_DIR", &data)
        .output()
        .expect("run python/ci.sh --test");
    let stdout = String::from_utf8_lossy(&out.stdout);
    let stderr = String::from_utf8_lossy(&out.stderr);
    println!("{stdout}");
    eprintln!("{stderr}");
    assert!(
        out.status.success(),
        "python/ci.sh --test failed (status {:?}); pytest's output is above",
        out.status.code()
    );
    // pytest's closing line: something passed, nothing skipped (the suite's skips are for a
    // missing environment, which this test has ruled out).
    let last = stdout
        .lines()
        .rev()
        .find(|l| l.contains(" passed"))
        .unwrap_or("");
    assert!(last.contains(" passed"), "no passing pytest summary line");
    assert!(
        !last.contains("skipped") && !last.contains("failed"),
        "pytest: {last}"
    );
}
