//! `shimmy export`: a firmware-sim drive and the real RAV4 drive exported to a Parquet lake and
//! read back with the parquet crate's reader. Checked against the other commands on the same
//! logs: every decoded value equals `shimmy decode`'s, the events, the last estimate and the
//! alerts standing equal `shimmy estimate --json`'s (the estimate's `misfit` its verdict's
//! reason, also on a vehicle the model does not fit); the partition layout and names; the
//! provenance columns (sha256 of the DBC, the tables and the profile's correction, and the
//! run's hash as docs/FLEET.md defines it); a rerun rewrites byte-identical files and adds
//! none; a profile that names a correction stamps its hash and writes its rows under a run of
//! their own; a corrupt log is reported and the others are still exported.
//!
//! The RAV4 drive comes from the shared data (SHIMMY_DATA_DIR); without it that test skips,
//! except under CI=true where it fails.

mod e2e_common;

use std::collections::{BTreeMap, HashMap};
use std::fs::File;
use std::path::{Path, PathBuf};
use std::process::{Command, Output};

use arrow_array::cast::AsArray;
use arrow_array::types::{Float64Type, TimestampMicrosecondType, UInt32Type, UInt64Type};
use arrow_array::{Array, RecordBatch};
use arrow_schema::DataType;
use parquet::arrow::arrow_reader::ParquetRecordBatchReaderBuilder;
use serde_json::Value;
use sha2::{Digest, Sha256};
use shimmy::observer::table::ResponseTable;
use shimmy::observer::ObserverConfig;
use shimmy::profile::Profile;

fn shimmy(args: &[&std::ffi::OsStr]) -> Output {
    Command::new(env!("CARGO_BIN_EXE_shimmy"))
        .current_dir(e2e_common::workspace())
        .args(args)
        .output()
        .expect("run shimmy")
}

fn export(profile: &str, vehicle: &str, lake: &Path, logs: &[&Path]) -> Output {
    let mut a: Vec<&std::ffi::OsStr> = vec![
        "export".as_ref(),
        "--profile".as_ref(),
        profile.as_ref(),
        "--vehicle".as_ref(),
        vehicle.as_ref(),
        "--out".as_ref(),
        lake.as_os_str(),
    ];
    a.extend(logs.iter().map(|l| l.as_os_str()));
    shimmy(&a)
}

fn sha256_hex(path: &Path) -> String {
    let d = Sha256::digest(std::fs::read(path).unwrap());
    d.iter().map(|b| format!("{b:02x}")).collect()
}

/// The monitor's table folders (everything else in a lake is a vehicle's signal files).
const TABLES_DIRS: [&str; 3] = ["events", "estimates", "alerts"];

/// Every file under `dir` (relative path → bytes).
fn snapshot(dir: &Path) -> BTreeMap<PathBuf, Vec<u8>> {
    let mut out = BTreeMap::new();
    let mut stack = vec![dir.to_path_buf()];
    while let Some(d) = stack.pop() {
        for e in std::fs::read_dir(&d).unwrap() {
            let p = e.unwrap().path();
            if p.is_dir() {
                stack.push(p);
            } else {
                out.insert(
                    p.strip_prefix(dir).unwrap().to_path_buf(),
                    std::fs::read(&p).unwrap(),
                );
            }
        }
    }
    out
}

fn read_parquet(path: &Path) -> Vec<RecordBatch> {
    ParquetRecordBatchReaderBuilder::try_new(File::open(path).unwrap())
        .unwrap()
        .build()
        .unwrap()
        .map(|b| b.unwrap())
        .collect()
}

/// All rows of one table's files (in file-name order) as batches.
fn read_all(lake: &Path, files: &BTreeMap<PathBuf, Vec<u8>>, prefix: &str) -> Vec<RecordBatch> {
    files
        .keys()
        .filter(|p| p.starts_with(prefix))
        .flat_map(|p| read_parquet(&lake.join(p)))
        .collect()
}

fn hex_name(s: &str, len: usize) -> bool {
    s.len() == len
        && s.bytes()
            .all(|b| b.is_ascii_hexdigit() && !b.is_ascii_uppercase())
}

/// Checks every file's path against the documented layout; returns the signal files' dates
/// (yyyy/mm/dd) and the tables' dates (yyyy-mm-dd).
fn check_layout(files: &BTreeMap<PathBuf, Vec<u8>>, vehicle: &str) -> (Vec<String>, Vec<String>) {
    let (mut sig_dates, mut table_dates) = (Vec::new(), Vec::new());
    for p in files.keys() {
        let parts: Vec<&str> = p.iter().map(|c| c.to_str().unwrap()).collect();
        let name = parts.last().unwrap();
        assert!(!name.starts_with('.'), "a temporary file was left: {p:?}");
        let stem = name.strip_suffix(".parquet").expect("only parquet files");
        if ["events", "estimates", "alerts"].contains(&parts[0]) {
            assert_eq!(parts.len(), 4, "{p:?}");
            assert_eq!(parts[1], format!("vehicle={vehicle}"));
            let date = parts[2].strip_prefix("date=").expect("date= partition");
            assert_eq!(date.len(), 10, "{p:?}");
            let (run, idx) = stem.split_once('-').unwrap();
            assert!(hex_name(run, 16) && idx.len() == 4, "{p:?}");
            table_dates.push(date.to_string());
        } else {
            assert_eq!(parts.len(), 6, "{p:?}: <device>/<message>/yyyy/mm/dd/file");
            assert_eq!(parts[0], vehicle);
            let f: Vec<&str> = stem.split('-').collect();
            assert!(
                f.len() == 3 && hex_name(f[0], 16) && hex_name(f[1], 8) && f[2].len() == 3,
                "{p:?}"
            );
            sig_dates.push(format!("{}/{}/{}", parts[2], parts[3], parts[4]));
        }
    }
    sig_dates.sort();
    sig_dates.dedup();
    table_dates.sort();
    table_dates.dedup();
    (sig_dates, table_dates)
}

fn f64s(b: &RecordBatch, name: &str) -> Vec<Option<f64>> {
    let c = b
        .column_by_name(name)
        .unwrap_or_else(|| panic!("column {name}"));
    let a = c.as_primitive::<Float64Type>();
    (0..a.len())
        .map(|i| (!a.is_null(i)).then(|| a.value(i)))
        .collect()
}

fn strs(b: &RecordBatch, name: &str) -> Vec<Option<String>> {
    let a = b.column_by_name(name).unwrap().as_string::<i32>();
    (0..a.len())
        .map(|i| (!a.is_null(i)).then(|| a.value(i).to_string()))
        .collect()
}

fn bools(b: &RecordBatch, name: &str) -> Vec<bool> {
    let a = b.column_by_name(name).unwrap().as_boolean();
    (0..a.len()).map(|i| a.value(i)).collect()
}

fn json_f64(v: &Value) -> Option<f64> {
    v.as_f64()
}

/// Every decoded frame of `shimmy decode` equals a row of its message's files, in order.
fn check_signals_equal_decode(
    lake: &Path,
    files: &BTreeMap<PathBuf, Vec<u8>>,
    vehicle: &str,
    dbc: &Path,
    log: &Path,
) -> usize {
    let out = shimmy(&[
        "decode".as_ref(),
        "--dbc".as_ref(),
        dbc.as_os_str(),
        log.as_os_str(),
    ]);
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    // message → [(t µs, signals)]
    let mut want: HashMap<String, Vec<(i64, serde_json::Map<String, Value>)>> = HashMap::new();
    for line in out.stdout.split(|&b| b == b'\n').filter(|l| !l.is_empty()) {
        let v: Value = serde_json::from_slice(line).unwrap();
        let t = v["t"].as_f64().unwrap();
        // decode prints µs (or ns) decimals; the lake keeps µs (floor)
        let text = std::str::from_utf8(line).unwrap();
        let t_txt = text
            .split("\"t\": ")
            .nth(1)
            .unwrap()
            .split(',')
            .next()
            .unwrap();
        let (s, frac) = t_txt.split_once('.').unwrap();
        let us = s.parse::<i64>().unwrap() * 1_000_000 + frac[..6].parse::<i64>().unwrap();
        assert!((us as f64 * 1e-6 - t).abs() < 1e-3);
        want.entry(v["msg"].as_str().unwrap().to_string())
            .or_default()
            .push((us, v["signals"].as_object().unwrap().clone()));
    }
    let mut checked = 0;
    for (msg, rows) in &want {
        let batches = read_all(lake, files, &format!("{vehicle}/{msg}/"));
        let mut got = Vec::new();
        for b in &batches {
            let t = b.column(0).as_primitive::<TimestampMicrosecondType>();
            for i in 0..b.num_rows() {
                got.push((b, i, t.value(i)));
            }
        }
        assert_eq!(got.len(), rows.len(), "rows of {msg}");
        for ((b, i, t), (want_t, sigs)) in got.iter().zip(rows) {
            assert_eq!(t, want_t, "{msg}: timestamp");
            let schema = b.schema();
            for (k, field) in schema.fields().iter().enumerate().skip(1) {
                let col = b.column(k).as_primitive::<Float64Type>();
                let lake_v = (!col.is_null(*i)).then(|| col.value(*i));
                match sigs.get(field.name()) {
                    None => assert_eq!(lake_v, None, "{msg}.{} not decoded", field.name()),
                    Some(Value::Null) => assert!(lake_v.is_some_and(|v| !v.is_finite())),
                    Some(v) => assert_eq!(lake_v, json_f64(v), "{msg}.{} at {t}", field.name()),
                }
            }
            assert_eq!(schema.fields().len() - 1 >= sigs.len(), true);
            checked += 1;
        }
    }
    checked
}

/// The monitor's tables against `shimmy estimate --json` on the same log and profile.
fn check_tables_equal_estimate(
    lake: &Path,
    files: &BTreeMap<PathBuf, Vec<u8>>,
    est: &Value,
    profile: &Profile,
) {
    let events = read_all(lake, files, "events");
    let mut rows: Vec<(
        f64,
        f64,
        f64,
        f64,
        Option<f64>,
        Option<f64>,
        bool,
        Option<String>,
    )> = Vec::new();
    for b in &events {
        let (t0, t1, v0, dec, peak, amp, used, why) = (
            f64s(b, "t_start_s"),
            f64s(b, "t_end_s"),
            f64s(b, "v0_kmh"),
            f64s(b, "decel_g"),
            f64s(b, "peak_sw_bp_deg"),
            f64s(b, "sw_amplitude_deg"),
            bools(b, "used"),
            strs(b, "unused_reason"),
        );
        for i in 0..b.num_rows() {
            rows.push((
                t0[i].unwrap(),
                t1[i].unwrap(),
                v0[i].unwrap(),
                dec[i].unwrap(),
                peak[i],
                amp[i],
                used[i],
                why[i].clone(),
            ));
        }
        // provenance
        let dbc = sha256_hex(&profile.dbc_path);
        let table = sha256_hex(profile.table_path.as_ref().unwrap());
        assert!(strs(b, "dbc_sha256")
            .iter()
            .all(|s| s.as_deref() == Some(dbc.as_str())));
        assert!(strs(b, "table_sha256")
            .iter()
            .all(|s| s.as_deref() == Some(table.as_str())));
        assert!(strs(b, "model_version")
            .iter()
            .all(|s| s.as_deref() == Some(concat!("shimmy-monitor ", env!("CARGO_PKG_VERSION")))));
        // The row's log is one whose signal files the lake holds (named by its hash's start).
        for h in strs(b, "log_blake3") {
            let h = h.unwrap();
            assert!(
                h.len() == 64 && h.bytes().all(|c| c.is_ascii_hexdigit()),
                "log_blake3 {h:?}"
            );
            assert!(
                files
                    .keys()
                    .any(|p| !TABLES_DIRS.iter().any(|t| p.starts_with(t))
                        && p.file_name()
                            .unwrap()
                            .to_string_lossy()
                            .starts_with(&h[..16])),
                "no signal file of the log {h}"
            );
        }
    }
    // Every table's stamp: the torque table's and the correction's hashes (null without them),
    // each a nullable Utf8, the correction's right after the torque table's.
    let torque = profile.torque_table_path.as_deref().map(sha256_hex);
    let correction = profile.correction_path.as_deref().map(sha256_hex);
    for t in TABLES_DIRS {
        for b in read_all(lake, files, t) {
            let schema = b.schema();
            let k = schema.index_of("torque_table_sha256").unwrap();
            let f = schema.field(k + 1);
            assert_eq!(f.name(), "correction_sha256", "{t}");
            assert!(
                f.is_nullable() && f.data_type() == &DataType::Utf8,
                "{t}: {f:?}"
            );
            assert!(
                strs(&b, "torque_table_sha256") == vec![torque.clone(); b.num_rows()],
                "{t}: torque_table_sha256"
            );
            assert!(
                strs(&b, "correction_sha256") == vec![correction.clone(); b.num_rows()],
                "{t}: correction_sha256, want {correction:?}"
            );
        }
    }
    rows.sort_by(|a, b| a.1.total_cmp(&b.1));
    let want = est["events"].as_array().unwrap();
    assert_eq!(rows.len(), want.len(), "events");
    for (r, w) in rows.iter().zip(want) {
        assert_eq!(r.0, w["t_start"].as_f64().unwrap());
        assert_eq!(r.1, w["t_end"].as_f64().unwrap());
        assert_eq!(r.2, w["v0_kmh"].as_f64().unwrap());
        assert_eq!(r.3, w["decel_g"].as_f64().unwrap());
        assert_eq!(r.4, w["peak_sw_bp_deg"].as_f64());
        assert_eq!(r.5, w["sw_amplitude_deg"].as_f64());
        assert_eq!(r.6, w["used"].as_bool().unwrap());
        assert_eq!(r.7.as_deref(), w["unused_reason"].as_str());
    }
    // The last estimate is the report's.
    let mut last: Option<(f64, RecordBatch, usize)> = None;
    for b in read_all(lake, files, "estimates") {
        let f = b.schema().field_with_name("misfit").unwrap().clone();
        assert!(f.is_nullable() && f.data_type() == &DataType::Utf8, "{f:?}");
        for (i, t) in f64s(&b, "t_event_end_s").into_iter().enumerate() {
            if last.as_ref().is_none_or(|(lt, _, _)| t.unwrap() >= *lt) {
                last = Some((t.unwrap(), b.clone(), i));
            }
        }
    }
    if let Some((_, b, i)) = &last {
        assert_eq!(f64s(b, "clearance_mm")[*i], est["clearance_mm"].as_f64());
        assert_eq!(
            f64s(b, "interval_lo_mm")[*i],
            est["interval_mm"][0].as_f64()
        );
        assert_eq!(
            f64s(b, "interval_hi_mm")[*i],
            est["interval_mm"][1].as_f64()
        );
        assert_eq!(f64s(b, "below_mm")[*i], est["below_mm"].as_f64());
        assert_eq!(
            bools(b, "detectable")[*i],
            est["detectable"].as_bool().unwrap()
        );
        assert_eq!(
            f64s(b, "p_above")[*i],
            est["p_clearance_above_threshold"].as_f64()
        );
        let used = b
            .column_by_name("events_used")
            .unwrap()
            .as_primitive::<UInt32Type>();
        assert_eq!(used.value(*i) as u64, est["events_used"].as_u64().unwrap());
        // Why the model does not fit: the reason the verdict gives, null when it fits.
        let verdict = est["verdict"].as_str().unwrap();
        let why = verdict
            .split_once("; but the model does not fit this vehicle: ")
            .map(|(_, why)| why);
        assert_eq!(strs(b, "misfit")[*i].as_deref(), why, "verdict {verdict:?}");
        assert_eq!(
            why.is_some(),
            est["model_fit"]["fits"] == false,
            "{}",
            est["model_fit"]
        );
    } else {
        assert!(est["clearance_mm"].is_null() && est["interval_mm"].is_null());
    }
    // The alerts standing after the transitions, in order, are estimate's.
    let mut trans = Vec::new();
    for b in read_all(lake, files, "alerts") {
        let ids = b
            .column_by_name("alert_id")
            .unwrap()
            .as_primitive::<UInt64Type>();
        let upd = b
            .column_by_name("updates")
            .unwrap()
            .as_primitive::<UInt32Type>();
        let (t, tr, kind, sum, tr_s, tu_s) = (
            f64s(&b, "t_event_end_s"),
            strs(&b, "transition"),
            strs(&b, "kind"),
            strs(&b, "summary"),
            f64s(&b, "t_raised_s"),
            f64s(&b, "t_updated_s"),
        );
        for i in 0..b.num_rows() {
            trans.push((
                t[i].unwrap(),
                tr[i].clone().unwrap(),
                ids.value(i),
                kind[i].clone().unwrap(),
                upd.value(i),
                sum[i].clone().unwrap(),
                tr_s[i].unwrap(),
                tu_s[i].unwrap(),
            ));
        }
    }
    trans.sort_by(|a, b| a.0.total_cmp(&b.0));
    let mut open: BTreeMap<u64, Value> = BTreeMap::new();
    for (_, tr, id, kind, updates, summary, t_raised, t_updated) in trans {
        if tr == "cleared" {
            open.remove(&id);
        } else {
            open.insert(id, serde_json::json!({"id": id, "kind": kind, "updates": updates, "summary": summary, "t_raised": t_raised, "t_updated": t_updated}));
        }
    }
    let want: Vec<Value> = est["alerts"]
        .as_array()
        .unwrap()
        .iter()
        .map(|a| serde_json::json!({"id": a["id"], "kind": a["kind"], "updates": a["updates"], "summary": a["summary"], "t_raised": a["t_raised"], "t_updated": a["t_updated"]}))
        .collect();
    assert_eq!(
        open.into_values().collect::<Vec<_>>(),
        want,
        "alerts standing"
    );
}

fn estimate_json(profile: &str, log: &Path) -> Value {
    let out = shimmy(&[
        "estimate".as_ref(),
        "--profile".as_ref(),
        profile.as_ref(),
        log.as_os_str(),
    ]);
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    serde_json::from_slice(&out.stdout).unwrap()
}

#[test]
fn a_simulated_drive_exports_what_decode_and_estimate_say_and_a_rerun_changes_nothing() {
    let dir = tempfile::tempdir().unwrap();
    let sim = e2e_common::generate("worn_0p2mm", None, dir.path());
    let corrupt = dir.path().join("corrupt.blf");
    // A BLF signature followed by garbage, then random-looking bytes.
    let mut junk = b"LOGG".to_vec();
    junk.extend((0..4096u32).map(|i| (i.wrapping_mul(2_654_435_761) >> 13) as u8));
    std::fs::write(&corrupt, &junk).unwrap();
    let lake = dir.path().join("lake");

    let out = export("shimmy_reference", "sim-1", &lake, &[&corrupt, &sim.log]);
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert_eq!(
        out.status.code(),
        Some(1),
        "a failed log makes the exit status 1: {stderr}"
    );
    assert!(
        stderr.contains("FAILED") && stderr.contains("corrupt.blf"),
        "{stderr}"
    );
    assert!(stderr.contains("1 of 2 logs failed"), "{stderr}");
    let stdout = String::from_utf8_lossy(&out.stdout);
    assert!(stdout.contains("1 of 2 logs exported"), "{stdout}");

    let files = snapshot(&lake);
    let (sig_dates, table_dates) = check_layout(&files, "sim-1");
    // firmware-sim's drives start at 2026-01-01T00:00:00Z.
    assert_eq!(sig_dates, ["2026/01/01"]);
    assert_eq!(table_dates, ["2026-01-01"]);
    for t in ["events", "estimates"] {
        assert!(files.keys().any(|p| p.starts_with(t)), "no {t} files");
    }

    let profile = Profile::load("shimmy_reference").unwrap();
    let n = check_signals_equal_decode(&lake, &files, "sim-1", &profile.dbc_path, &sim.log);
    assert!(n > 1000, "{n} frames compared");
    let est = estimate_json("shimmy_reference", &sim.log);
    assert!(!est["events"].as_array().unwrap().is_empty());
    check_tables_equal_estimate(&lake, &files, &est, &profile);

    // Rerun: the same files, byte for byte, and no others.
    let again = export("shimmy_reference", "sim-1", &lake, &[&corrupt, &sim.log]);
    assert_eq!(again.status.code(), Some(1));
    assert!(snapshot(&lake) == files, "a rerun changed the lake");
}

#[test]
fn the_real_rav4_drive_exports_what_decode_and_estimate_say() {
    let Some(log) = shimmy::shared_data::require_file(shimmy::shared_data::RAV4_LOG) else {
        return;
    };
    let dir = tempfile::tempdir().unwrap();
    let lake = dir.path().join("lake");
    let out = export("toyota_rav4", "rav4-1", &lake, &[&log]);
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    let files = snapshot(&lake);
    let (sig_dates, _) = check_layout(&files, "rav4-1");
    // comma2k19 logs count seconds from boot: the documented rule puts them on 1970-01-01.
    assert_eq!(sig_dates, ["1970/01/01"]);
    let profile = Profile::load("toyota_rav4").unwrap();
    let n = check_signals_equal_decode(&lake, &files, "rav4-1", &profile.dbc_path, &log);
    assert!(n > 30_000, "{n} frames compared");
    let est = estimate_json("toyota_rav4", &log);
    check_tables_equal_estimate(&lake, &files, &est, &profile);
    let again = export("toyota_rav4", "rav4-1", &lake, &[&log]);
    assert!(again.status.success());
    assert!(snapshot(&lake) == files, "a rerun changed the lake");
}

/// The log's BLAKE3 is taken in the pass that reads it (an MDF 4 file in a pass of its own):
/// whatever the format, the signal files are named by the BLAKE3 of the file as it is on disk
/// (what `b3sum` prints), and the monitor's rows carry it whole.
#[test]
fn signal_files_are_named_by_the_blake3_of_the_log_file_in_every_format() {
    let Some(log) = shimmy::shared_data::require_file(shimmy::shared_data::RAV4_LOG) else {
        return;
    };
    let dir = tempfile::tempdir().unwrap();
    let mut logs = vec![log.clone()];
    for rel in [
        "logs/comma2k19-rav4/rav4_2017_seg40_bus0.asc",
        "logs/comma2k19-rav4/rav4_2017_seg40_bus0.blf",
    ] {
        logs.extend(shimmy::shared_data::require_file(rel));
    }
    // gzip: the hash is of the compressed file, not of the text inside it.
    let gz = dir.path().join("drive.log.gz");
    {
        use std::io::Write;
        let mut w = flate2::write::GzEncoder::new(File::create(&gz).unwrap(), Default::default());
        w.write_all(&std::fs::read(&log).unwrap()).unwrap();
        w.finish().unwrap();
    }
    logs.push(gz);
    let mf4 = dir.path().join("drive.mf4");
    let conv = shimmy(&["convert".as_ref(), log.as_os_str(), mf4.as_os_str()]);
    assert!(
        conv.status.success(),
        "{}",
        String::from_utf8_lossy(&conv.stderr)
    );
    logs.push(mf4);
    assert!(logs.len() >= 3, "{logs:?}");
    for (i, l) in logs.iter().enumerate() {
        let lake = dir.path().join(format!("lake{i}"));
        let out = export("toyota_rav4", "rav4-1", &lake, &[l]);
        assert!(
            out.status.success(),
            "{}",
            String::from_utf8_lossy(&out.stderr)
        );
        let want = blake3::hash(&std::fs::read(l).unwrap()).to_hex()[..16].to_string();
        let files = snapshot(&lake);
        let names: Vec<String> = files
            .keys()
            .filter(|p| p.starts_with("rav4-1"))
            .map(|p| p.file_name().unwrap().to_string_lossy().into_owned())
            .collect();
        assert!(names.len() > 20, "{}: {names:?}", l.display());
        for n in &names {
            assert!(
                n.starts_with(&want),
                "{}: file {n}, BLAKE3 {want}",
                l.display()
            );
        }
        // No temporary file is left behind.
        assert!(
            files
                .keys()
                .all(|p| !p.file_name().unwrap().to_string_lossy().starts_with('.')),
            "{:?}",
            files.keys().collect::<Vec<_>>()
        );
    }
}

/// A car with the MODEL.md §15 column on the reference bus with an EPS torque: the lake's
/// events carry the torque's peak and use as `estimate` reports them, and every row names the
/// torque table it was estimated with.
#[test]
fn a_drive_with_a_torque_exports_the_torque_and_its_table() {
    let dir = tempfile::tempdir().unwrap();
    let ws = e2e_common::workspace();
    let vehicle = e2e_common::column_vehicle(dir.path());
    let scenario = std::fs::read_to_string(ws.join("config/scenarios/worn_0p2mm.toml")).unwrap();
    let scenario = scenario.replacen(
        "seed = 20\n",
        &format!("seed = 20\nvehicle = {:?}\n", vehicle.display().to_string()),
        1,
    );
    let sc = dir.path().join("column_worn.toml");
    std::fs::write(&sc, scenario).unwrap();
    let log = dir.path().join("column_worn.log");
    e2e_common::simulate(&sc, &log, &["--profile", "shimmy_reference_eps"]);

    let lake = dir.path().join("lake");
    let out = export("shimmy_reference_eps", "eps-1", &lake, &[&log]);
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    let files = snapshot(&lake);
    let est = estimate_json("shimmy_reference_eps", &log);
    assert_eq!(est["signals"]["estimate_from"], "torque_nm", "{est}");
    let want: Vec<(Option<f64>, Option<bool>)> = est["events"]
        .as_array()
        .unwrap()
        .iter()
        .map(|e| {
            (
                json_f64(&e["torque"]["peak_bp_nm"]),
                e["torque"]["used"].as_bool(),
            )
        })
        .collect();
    assert!(want.iter().any(|w| w.1 == Some(true)), "{want:?}");
    let mut got = Vec::new();
    let torque_sha = sha256_hex(&ws.join("config/vehicles/shimmy_reference_eps/table_torque.json"));
    for b in read_all(&lake, &files, "events") {
        let peak = f64s(&b, "peak_torque_bp_nm");
        let used = b
            .column_by_name("torque_used")
            .unwrap()
            .as_boolean()
            .clone();
        for i in 0..b.num_rows() {
            got.push((peak[i], (!used.is_null(i)).then(|| used.value(i))));
        }
        assert!(strs(&b, "torque_table_sha256")
            .iter()
            .all(|s| s.as_deref() == Some(torque_sha.as_str())));
    }
    assert_eq!(got.len(), want.len());
    for (g, w) in got.iter().zip(&want) {
        assert_eq!(g.1, w.1);
        match (g.0, w.0) {
            (Some(a), Some(b)) => assert!((a - b).abs() <= 1e-9 * b.abs().max(1e-6), "{a} {b}"),
            (a, b) => assert_eq!(a, b),
        }
    }
}

/// A vehicle on roads 7.5 times rougher than the table assumes (tests/model_fit_verdict.rs):
/// `estimate` says the model does not fit it, and the lake's estimates say why, in `misfit`
/// (null while the events were too few to tell).
#[test]
fn an_estimate_the_model_does_not_fit_carries_the_reason() {
    let dir = tempfile::tempdir().unwrap();
    let ws = e2e_common::workspace();
    let model = std::fs::read_to_string(ws.join("config/vehicle/default.toml")).unwrap();
    // Rough enough that none of the profile's angle tables (its own, a scrub radius's, uneven
    // discs') fits: at 5 times, the scrub radius's table took the car in.
    let rough = model.replace("noise_std_nm = 0.2 ", "noise_std_nm = 1.5 ");
    assert_ne!(
        rough, model,
        "the road-noise key moved in config/vehicle/default.toml"
    );
    let plant = dir.path().join("rough.toml");
    std::fs::write(&plant, rough).unwrap();
    let sim = dir.path().join("sim");
    let out = Command::new(e2e_common::firmware_sim())
        .current_dir(ws)
        .args(["fleet", "--profile", "shimmy_reference", "--vehicles", "1"])
        .args([
            "--events",
            "12",
            "--seed-base",
            "77100",
            "--logs-only",
            "--plant",
        ])
        .arg(&plant)
        .arg("--work-dir")
        .arg(&sim)
        .output()
        .unwrap();
    assert!(
        out.status.success(),
        "firmware-sim fleet: {}",
        String::from_utf8_lossy(&out.stderr)
    );
    let log = sim.join("fleet_77100.log");

    let lake = dir.path().join("lake");
    let out = export("shimmy_reference", "rough-1", &lake, &[&log]);
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    let files = snapshot(&lake);
    let est = estimate_json("shimmy_reference", &log);
    assert_eq!(est["model_fit"]["fits"], false, "{}", est["model_fit"]);
    // The last estimate's misfit is the verdict's reason (checked there).
    let profile = Profile::load("shimmy_reference").unwrap();
    check_tables_equal_estimate(&lake, &files, &est, &profile);
    let misfits: Vec<Option<String>> = read_all(&lake, &files, "estimates")
        .iter()
        .flat_map(|b| strs(b, "misfit"))
        .collect();
    assert!(misfits.len() >= 2, "{misfits:?}");
    let last = misfits.last().unwrap().as_deref().unwrap();
    assert!(last.contains("goodness of fit z = "), "{last}");
    // Before the fit check has degrees of freedom enough, the model is not said not to fit.
    assert_eq!(misfits[0], None, "{misfits:?}");
}

/// A simulated RAV4 drive (firmware-sim, 4 braking events).
fn rav4_sim_log(dir: &Path) -> PathBuf {
    let work = dir.join("rav4_sim");
    let out = Command::new(e2e_common::firmware_sim())
        .current_dir(e2e_common::workspace())
        .args(["fleet", "--profile", "toyota_rav4", "--vehicles", "1"])
        .args([
            "--events",
            "4",
            "--seed-base",
            "7100",
            "--logs-only",
            "--work-dir",
        ])
        .arg(&work)
        .output()
        .unwrap();
    assert!(
        out.status.success(),
        "firmware-sim fleet: {}",
        String::from_utf8_lossy(&out.stderr)
    );
    work.join("fleet_7100.log")
}

/// A torque correction of the shipped RAV4 torque table (fitted against it: its fingerprint)
/// with the vehicles' spread `spread_ln`.
fn rav4_torque_correction(spread_ln: f64) -> String {
    let table = e2e_common::workspace().join("config/vehicles/toyota_rav4/table_torque.json");
    let fp = ResponseTable::load(&table).unwrap().fingerprint;
    format!(
        "[torque_nm]\ngain = [1.0, 1.0, 1.0]\ngain_se_ln = [0.0, 0.0, 0.0]\n\
         spread_ln = {spread_ln:?}\nvehicles = 2\nevents = 20\nclearance_mm = 0.03\n\
         table_fingerprint = {fp:?}\n"
    )
}

/// The run's hash as docs/FLEET.md defines it: sha256 over the parts, each followed by a zero
/// byte, the torque table's, the correction's and the chassis variants' only when the run has them.
fn documented_run_sha256(profile: &Profile, vehicle: &str, logs: &[&Path]) -> String {
    let settings = serde_json::to_vec(&ObserverConfig::default()).unwrap();
    let settings = Sha256::digest(&settings)
        .iter()
        .map(|b| format!("{b:02x}"))
        .collect::<String>();
    let mut parts = vec![
        "shimmy-lake-run-2".to_string(),
        concat!("shimmy-monitor ", env!("CARGO_PKG_VERSION")).to_string(),
        vehicle.to_string(),
        sha256_hex(&profile.dbc_path),
        profile
            .table_path
            .as_deref()
            .map(sha256_hex)
            .unwrap_or("-".into()),
        sha256_hex(&profile.mapping_path),
        settings,
    ];
    if let Some(t) = &profile.torque_table_path {
        parts.push(format!("torque:{}", sha256_hex(t)));
    }
    if let Some(c) = &profile.correction_path {
        parts.push(format!("correction:{}", sha256_hex(c)));
    }
    // Chassis variants beside the torque table and the angle table: each name and its tables'
    // sha256 (an angle table's marked `angle:`).
    let variants = &profile.file.chassis.variants;
    let torque_variants =
        profile.torque_table_path.is_some() && variants.iter().any(|c| c.torque_table.is_some());
    let angle_variants = profile.table_path.is_some() && variants.iter().any(|c| c.table.is_some());
    if torque_variants || angle_variants {
        let mut v = Vec::new();
        for c in variants {
            v.extend_from_slice(c.name.as_bytes());
            v.push(0);
            if let (true, Some(t)) = (torque_variants, &c.torque_table) {
                v.extend_from_slice(sha256_hex(&profile.dir.join(t)).as_bytes());
                v.push(0);
            }
            if let (true, Some(t)) = (angle_variants, &c.table) {
                v.extend_from_slice(b"angle:");
                v.extend_from_slice(sha256_hex(&profile.dir.join(t)).as_bytes());
                v.push(0);
            }
        }
        let v: String = Sha256::digest(&v)
            .iter()
            .map(|b| format!("{b:02x}"))
            .collect();
        parts.push(format!("variants:{v}"));
    }
    parts.extend(logs.iter().map(|l| {
        blake3::hash(&std::fs::read(l).unwrap())
            .to_hex()
            .to_string()
    }));
    let mut h = Sha256::new();
    for p in parts {
        h.update(p.as_bytes());
        h.update([0]);
    }
    h.finalize().iter().map(|b| format!("{b:02x}")).collect()
}

/// The `run_sha256` of every monitor row among `files` (sorted, deduplicated).
fn runs(lake: &Path, files: &BTreeMap<PathBuf, Vec<u8>>) -> Vec<String> {
    let mut out: Vec<String> = TABLES_DIRS
        .iter()
        .flat_map(|t| read_all(lake, files, t))
        .flat_map(|b| strs(&b, "run_sha256"))
        .map(Option::unwrap)
        .collect();
    out.sort();
    out.dedup();
    out
}

/// A profile that names a correction: every row carries the correction file's sha256 (null
/// without one, the run's hash then as it was before corrections existed, so older lakes stay
/// resumable), and the run's hash includes it: exported into the same lake, the corrected
/// run's monitor rows land beside the uncorrected run's, which stay as they were, and a
/// changed correction is another run again.
#[test]
fn a_profile_with_a_correction_stamps_its_hash_and_is_a_run_of_its_own() {
    let dir = tempfile::tempdir().unwrap();
    let log = rav4_sim_log(dir.path());
    let lake = dir.path().join("lake");

    // The shipped profile names no correction.
    let shipped = Profile::load("toyota_rav4").unwrap();
    assert_eq!(shipped.correction_path, None);
    let out = export("toyota_rav4", "rav4-1", &lake, &[&log]);
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    let plain = snapshot(&lake);
    check_tables_equal_estimate(&lake, &plain, &estimate_json("toyota_rav4", &log), &shipped);
    let plain_run = documented_run_sha256(&shipped, "rav4-1", &[&log]);
    assert_eq!(runs(&lake, &plain), [plain_run.clone()]);

    // The same profile with a correction of its torque table.
    let copy = e2e_common::profile_copy_with_correction(
        "toyota_rav4",
        dir.path(),
        "rav4_corrected",
        &rav4_torque_correction(0.0),
    );
    let corrected = Profile::load_dir(&copy).unwrap();
    let corr_file = copy.join("correction.toml");
    assert_eq!(
        corrected.correction_path.as_deref(),
        Some(corr_file.as_path())
    );
    let name = copy.to_str().unwrap();
    let out = export(name, "rav4-1", &lake, &[&log]);
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    let both = snapshot(&lake);
    for (p, bytes) in &plain {
        assert!(both.get(p) == Some(bytes), "{p:?} changed or vanished");
    }
    let corr_run = documented_run_sha256(&corrected, "rav4-1", &[&log]);
    assert_ne!(corr_run, plain_run);
    let added: Vec<&PathBuf> = both.keys().filter(|p| !plain.contains_key(*p)).collect();
    assert!(!added.is_empty());
    for p in &added {
        assert!(TABLES_DIRS.iter().any(|t| p.starts_with(t)), "{p:?}");
        let stem = p.file_name().unwrap().to_string_lossy();
        assert!(stem.starts_with(&corr_run[..16]), "{p:?}, run {corr_run}");
    }
    // The corrected run's rows (with the log's signal files) against its own estimate: the
    // correction's hash in every row.
    let own: BTreeMap<PathBuf, Vec<u8>> = both
        .iter()
        .filter(|(p, _)| !TABLES_DIRS.iter().any(|t| p.starts_with(t)) || added.contains(p))
        .map(|(p, b)| (p.clone(), b.clone()))
        .collect();
    assert_eq!(runs(&lake, &own), [corr_run.clone()]);
    let est = estimate_json(name, &log);
    assert!(
        est["events"].as_array().is_some_and(|e| !e.is_empty()),
        "{est}"
    );
    check_tables_equal_estimate(&lake, &own, &est, &corrected);
    let corr_sha = sha256_hex(&corr_file);
    for t in TABLES_DIRS {
        for b in read_all(&lake, &own, t) {
            assert!(strs(&b, "correction_sha256")
                .iter()
                .all(|s| s.as_deref() == Some(corr_sha.as_str())));
        }
    }

    // A rerun is a resume: nothing changes.
    let again = export(name, "rav4-1", &lake, &[&log]);
    assert!(again.status.success());
    assert!(snapshot(&lake) == both, "a rerun changed the lake");

    // A changed correction is another run.
    std::fs::write(&corr_file, rav4_torque_correction(0.1)).unwrap();
    let changed = Profile::load_dir(&copy).unwrap();
    let changed_run = documented_run_sha256(&changed, "rav4-1", &[&log]);
    assert!(changed_run != corr_run && changed_run != plain_run);
    let out = export(name, "rav4-1", &lake, &[&log]);
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    let three = snapshot(&lake);
    assert!(three.keys().filter(|p| !both.contains_key(*p)).all(|p| p
        .file_name()
        .unwrap()
        .to_string_lossy()
        .starts_with(&changed_run[..16])));
    assert_eq!(runs(&lake, &three), {
        let mut r = vec![plain_run, corr_run, changed_run];
        r.sort();
        r
    });
}
