//! The `firmware-sim` binary refuses a bad clearance or wear setting with exit status 1 and a
//! message naming the key and the file, and writes no log.

use std::process::Command;

const SCENARIO: &str = r#"
seed = 1
[clearance]
left_mm = 0.1
wear_mm_per_1000km = 5.0
[drive]
start_speed_kmh = 50
[[drive.segment]]
kind = "cruise"
speed_kmh = 50
duration_s = 0.2
"#;

fn run_with(name: &str, text: &str) -> (i32, String, bool) {
    let dir = std::env::temp_dir().join(format!("fwsim-cli-{}-{name}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    let sc = dir.join("bad.toml");
    let log = dir.join("bad.log");
    std::fs::write(&sc, text).unwrap();
    let out = Command::new(env!("CARGO_BIN_EXE_firmware-sim"))
        .arg("--scenario")
        .arg(&sc)
        .arg("--out")
        .arg(&log)
        .arg("--quiet")
        .output()
        .unwrap();
    let wrote_log = log.exists();
    std::fs::remove_dir_all(&dir).ok();
    (
        out.status.code().unwrap_or(-1),
        String::from_utf8_lossy(&out.stderr).into_owned(),
        wrote_log,
    )
}

#[test]
fn bad_clearance_and_wear_values_are_refused_naming_the_key() {
    for (name, from, to, key) in [
        (
            "rate",
            "wear_mm_per_1000km = 5.0",
            "wear_mm_per_1000km = -5.0",
            "clearance.wear_mm_per_1000km = -5",
        ),
        (
            "zero",
            "left_mm = 0.1",
            "left_mm = 0.0",
            "clearance.left_mm = 0",
        ),
        (
            "right",
            "left_mm = 0.1",
            "left_mm = 0.1\nright_mm = -0.2",
            "clearance.right_mm = -0.2",
        ),
        (
            "cap",
            "left_mm = 0.1",
            "left_mm = 0.1\nmax_mm = 0.05",
            "clearance.max_mm = 0.05",
        ),
    ] {
        let (code, stderr, wrote_log) = run_with(name, &SCENARIO.replace(from, to));
        assert_eq!(code, 1, "{name}: {stderr}");
        assert!(stderr.contains(key), "{name}: {stderr}");
        assert!(stderr.contains("bad.toml"), "{name}: {stderr}");
        assert!(
            !wrote_log,
            "{name}: a log was written for a refused scenario"
        );
    }
    // The same scenario with valid values runs.
    let (code, stderr, wrote_log) = run_with("ok", SCENARIO);
    assert_eq!(code, 0, "{stderr}");
    assert!(wrote_log);
}
