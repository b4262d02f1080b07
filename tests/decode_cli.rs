//! `shimmy decode` end to end: runs the built binary on the real RAV4 log and on a crafted log
//! full of awkward frames, and checks stdout and the stderr summary.

use std::path::{Path, PathBuf};
use std::process::{Command, Output};

fn shimmy(args: &[&str]) -> Output {
    Command::new(env!("CARGO_BIN_EXE_shimmy"))
        .args(args)
        .output()
        .expect("run shimmy")
}

fn tmpdir(name: &str) -> PathBuf {
    let d = std::env::temp_dir().join(format!("shimmy-decode-cli-{}-{name}", std::process::id()));
    std::fs::create_dir_all(&d).unwrap();
    d
}

fn s(p: &Path) -> &str {
    p.to_str().unwrap()
}

#[test]
fn rav4_jsonl_matches_expected_speed_and_counts() {
    let (Some(log), Some(dbc), Some(csv)) = (
        shimmy::shared_data::require_file("logs/comma2k19-rav4/rav4_2017_seg40_bus0.log"),
        shimmy::shared_data::require_file("dbc/opendbc/toyota_new_mc_pt_generated.dbc"),
        shimmy::shared_data::require_file("logs/comma2k19-rav4/expected_decoded_bus0.csv"),
    ) else {
        return;
    };
    let out = shimmy(&["decode", "--dbc", s(&dbc), s(&log)]);
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    let stdout = String::from_utf8(out.stdout).unwrap();
    let stderr = String::from_utf8(out.stderr).unwrap();

    let mut speeds: Vec<(String, f64)> = Vec::new();
    let mut n = 0u64;
    for line in stdout.lines() {
        let v: serde_json::Value = serde_json::from_str(line).unwrap();
        assert!(v["t"].is_f64() && v["id"].is_u64() && v["extended"].is_boolean());
        assert!(v["signals"].is_object() && v.get("raw").is_none());
        if v["msg"] == "SPEED" {
            // The timestamp is printed with the log's 6 decimals.
            let t = line[6..line.find(',').unwrap()].to_string();
            speeds.push((t, v["signals"]["SPEED"].as_f64().unwrap()));
        }
        n += 1;
    }
    let expected: Vec<(String, f64)> = std::fs::read_to_string(csv)
        .unwrap()
        .lines()
        .filter(|l| l.contains(",SPEED,SPEED,"))
        .map(|l| {
            let f: Vec<&str> = l.split(',').collect();
            (f[0].to_string(), f[4].parse().unwrap())
        })
        .collect();
    assert_eq!(speeds.len(), expected.len());
    for (a, b) in speeds.iter().zip(&expected) {
        assert_eq!(a.0, b.0);
        assert!((a.1 - b.1).abs() < 1e-9, "{a:?} vs {b:?}");
    }
    // 53,800 frames in the log; the summary accounts for every one of them.
    assert!(stderr.contains("53800 frames read"), "{stderr}");
    assert!(stderr.contains(&format!("{n} decoded")), "{stderr}");
    let unknown: u64 = stderr
        .split("not decoded: ")
        .nth(1)
        .and_then(|x| x.split_whitespace().next())
        .and_then(|x| x.parse().ok())
        .unwrap();
    assert_eq!(n + unknown, 53_800, "{stderr}");
}

const DBC: &str = "VERSION \"\"\n\nBU_: A\n\
BO_ 256 PLAIN: 4 A\n SG_ U : 0|16@1+ (0.5,10) [0|0] \"\" A\n SG_ S : 23|8@0- (1,0) [0|0] \"\" A\n\
BO_ 257 MUX: 2 A\n SG_ SEL M : 0|8@1+ (1,0) [0|0] \"\" A\n SG_ ONE m1 : 8|8@1+ (1,0) [0|0] \"\" A\n\
BO_ 2566848512 EXT: 8 A\n SG_ D : 0|64@1- (1,0) [0|0] \"\" A\n\
SIG_VALTYPE_ 2566848512 D : 2;\n\
VAL_ 256 U 4 \"FOUR\";\n\
this line is not DBC\n";

fn crafted(test: &str) -> (PathBuf, PathBuf, PathBuf) {
    let d = tmpdir(test);
    let dbc = d.join("test.dbc");
    std::fs::write(&dbc, DBC).unwrap();
    let log = d.join("test.log");
    let nan = f64::NAN.to_bits().to_le_bytes();
    let nan_hex: String = nan.iter().map(|b| format!("{b:02X}")).collect();
    std::fs::write(
        &log,
        format!(
            "(1.000000) can0 100#0400FF00\n\
             (1.001000) can0 100#0400\n\
             (1.002000) can0 101#0107\n\
             (1.003000) can0 101#0207\n\
             (1.004000) can0 7FF#00\n\
             (1.005000) can0 100#R\n\
             this is not candump\n\
             (1.006000) can0 18FF0000#{nan_hex}\n\
             (1.007000) can0 18FF0000#0100000000000000\n"
        ),
    )
    .unwrap();
    (d, dbc, log)
}

#[test]
fn crafted_log_jsonl_and_summary() {
    let (_d, dbc, log) = crafted("jsonl");
    let out = shimmy(&["decode", "--dbc", s(&dbc), "--raw", s(&log)]);
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    let stdout = String::from_utf8(out.stdout).unwrap();
    let stderr = String::from_utf8(out.stderr).unwrap();
    let lines: Vec<serde_json::Value> = stdout
        .lines()
        .map(|l| serde_json::from_str(l).unwrap())
        .collect();
    assert_eq!(lines.len(), 5, "{stdout}");
    // Full frame: U = 4 * 0.5 + 10 (value-table entry stays a number), S = -1.
    assert_eq!(lines[0]["t"], 1.0);
    assert_eq!(lines[0]["id"], 256);
    assert_eq!(lines[0]["signals"]["U"], 12);
    assert_eq!(lines[0]["raw"]["U"], 4);
    assert_eq!(lines[0]["signals"]["S"], -1);
    // Short frame: U decoded, S left out and counted.
    assert_eq!(lines[1]["signals"].as_object().unwrap().len(), 1);
    // Multiplexed: SEL=1 selects ONE; SEL=2 selects nothing and is refused (not printed).
    assert_eq!(lines[2]["signals"]["ONE"], 7);
    // Extended ID, double: NaN is written as null, then a normal value.
    assert_eq!(lines[3]["extended"], true);
    assert_eq!(lines[3]["id"], 0x18FF_0000u32);
    assert!(lines[3]["signals"]["D"].is_null());
    assert_eq!(lines[4]["signals"]["D"], 5e-324);
    for want in [
        "8 frames read, 5 decoded",
        "1 with unknown IDs (1 distinct)",
        "1 refused",
        "1 remote/error frames",
        "1 short frames missing 1 signals",
        "1 malformed",
        "test.log:7",
        "1 DBC statements skipped",
    ] {
        assert!(stderr.contains(want), "missing {want:?} in {stderr}");
    }
}

#[test]
fn crafted_log_csv() {
    let (_d, dbc, log) = crafted("csv");
    let out = shimmy(&["decode", "--dbc", s(&dbc), "--format", "csv", s(&log)]);
    assert!(out.status.success());
    let stdout = String::from_utf8(out.stdout).unwrap();
    let rows: Vec<&str> = stdout.lines().collect();
    assert_eq!(rows[0], "t,id,extended,msg,signal,value");
    assert_eq!(rows[1], "1.000000,256,false,PLAIN,U,12");
    assert_eq!(rows[2], "1.000000,256,false,PLAIN,S,-1");
    assert_eq!(rows[3], "1.001000,256,false,PLAIN,U,12");
    // 2 + 1 + 2 + 1 + 1 signal rows.
    assert_eq!(rows.len(), 1 + 7, "{stdout}");
}

#[test]
fn dbc_report_lists_skipped_statements() {
    let (_d, dbc, log) = crafted("report");
    let out = shimmy(&["decode", "--dbc", s(&dbc), "--dbc-report", s(&log)]);
    let stderr = String::from_utf8(out.stderr).unwrap();
    assert!(stderr.contains("skipped line 14"), "{stderr}");
}

#[test]
fn mapping_is_refused_clearly_and_errors_exit_nonzero() {
    let (_d, dbc, log) = crafted("errors");
    let out = shimmy(&["decode", "--dbc", s(&dbc), "--mapping", "x.toml", s(&log)]);
    assert!(!out.status.success());
    // A mapping file that cannot be read is named in the error.
    assert!(String::from_utf8_lossy(&out.stderr).contains("reading mapping x.toml"));

    let out = shimmy(&["decode", "--dbc", "/nonexistent.dbc", s(&log)]);
    assert!(!out.status.success());
    assert!(String::from_utf8_lossy(&out.stderr).contains("/nonexistent.dbc"));

    let out = shimmy(&["decode", "--dbc", s(&dbc), "/nonexistent.log"]);
    assert!(!out.status.success());
    assert!(String::from_utf8_lossy(&out.stderr).contains("/nonexistent.log"));
}

/// The candump, ASC and BLF versions of the RAV4 log decode to the same records (the time base
/// differs between formats, so `t` is left out of the comparison).
#[test]
fn rav4_candump_asc_blf_decode_identically() {
    let Some(dbc) = shimmy::shared_data::require_file("dbc/opendbc/toyota_new_mc_pt_generated.dbc")
    else {
        return;
    };
    let mut outputs = Vec::new();
    for ext in ["log", "asc", "blf"] {
        let Some(log) = shimmy::shared_data::require_file(&format!(
            "logs/comma2k19-rav4/rav4_2017_seg40_bus0.{ext}"
        )) else {
            return;
        };
        let out = shimmy(&["decode", "--dbc", s(&dbc), "--raw", s(&log)]);
        assert!(out.status.success());
        let text = String::from_utf8(out.stdout).unwrap();
        let without_t: Vec<String> = text
            .lines()
            .map(|l| l[l.find(", \"id\"").unwrap()..].to_string())
            .collect();
        assert!(without_t.len() > 38_000, "{ext}: {}", without_t.len());
        outputs.push(without_t);
    }
    assert_eq!(outputs[0], outputs[1], "candump vs ASC");
    assert_eq!(outputs[0], outputs[2], "candump vs BLF");
}
