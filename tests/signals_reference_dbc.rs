//! Our reference DBC (`dbc/shimmy_reference.dbc`) loads cleanly with our loader and with
//! cantools, both read the same layout, and frames we pack (as firmware-sim does) decode to the
//! same values in cantools. cantools runs through `python3`; where it is not installed the
//! cantools part is skipped with a notice, except under CI=true, where it must run.

mod signals_common;

use std::process::Command;

use shimmy::shared_data::in_ci;
use shimmy::signals::checksum::{shimmy_crc8, ChecksumKind};
use signals_common::{reference_db, repo};

#[test]
fn loads_cleanly_with_cycle_times_and_comments() {
    let db = reference_db(); // asserts nothing was skipped
    let want = [
        ("SAS_01", 0x0A0, 10),
        ("BRK_01", 0x0B0, 20),
        ("WHL_01", 0x0C0, 20),
        ("VEH_01", 0x0D0, 20),
        ("SHIMMY_01", 0x3A0, 100),
    ];
    assert_eq!(db.messages().len(), want.len());
    for (name, id, cycle) in want {
        let m = &db.messages()[db.message_by_name(name).unwrap()];
        assert_eq!((m.id, m.extended, m.size_bytes), (id, false, 8), "{name}");
        assert_eq!(m.cycle_time_ms, Some(cycle), "{name}");
        assert!(m.comment.as_deref().is_some_and(|c| c.len() > 20), "{name}");
        for s in &m.signals {
            assert!(s.comment.is_some(), "{name}.{} has no comment", s.name);
        }
        // Counter + checksum where the issue asks for them (not on the full wheel-speed frame).
        let protected = m.signals.iter().any(|s| s.name.ends_with("_Checksum"));
        assert_eq!(protected, name != "WHL_01", "{name}");
        if protected {
            let c = m
                .signals
                .iter()
                .find(|s| s.name.ends_with("_Checksum"))
                .unwrap();
            assert_eq!((c.start_bit, c.size), (56, 8), "{name}: checksum in byte 7");
        }
    }
    // 0.1 deg resolution, signed steering angle.
    let sas = &db.messages()[db.message_by_name("SAS_01").unwrap()];
    let a = &sas.signals[sas.signal_by_name("SAS_Angle").unwrap()];
    assert_eq!((a.factor, a.unit.as_str()), (0.1, "deg"));
    assert_eq!(a.kind, shimmy::dbc::ValueKind::Signed);
    // The documented checksum is the one the code computes.
    assert!(db.comment.as_deref().unwrap().contains("CRC-8/SAE-J1850"));
}

/// Run a Python snippet; `None` (after printing why) when python3 or cantools is missing.
fn python(script: &str) -> Option<String> {
    let out = Command::new("python3").arg("-c").arg(script).output();
    match out {
        Ok(o) if o.status.success() => Some(String::from_utf8(o.stdout).unwrap()),
        Ok(o) => {
            let err = String::from_utf8_lossy(&o.stderr).to_string();
            if !in_ci() && err.contains("No module named 'cantools'") {
                eprintln!("SKIPPED cantools check: cantools not installed (pip install cantools)");
                return None;
            }
            panic!("python3 failed: {err}");
        }
        Err(e) => {
            if in_ci() {
                panic!("python3 not runnable under CI: {e}");
            }
            eprintln!("SKIPPED cantools check: python3 not runnable: {e}");
            None
        }
    }
}

#[test]
fn cantools_reads_the_same_layout_and_decodes_our_frames_identically() {
    let db = reference_db();
    // Frames packed with our encoder and checksum, as firmware-sim will.
    let mut frames = Vec::new();
    let values: &[(&str, &[(&str, f64)])] = &[
        (
            "SAS_01",
            &[
                ("SAS_Angle", -123.4),
                ("SAS_Rate", 56.7),
                ("SAS_Status", 0.0),
                ("SAS_Counter", 7.0),
            ],
        ),
        (
            "BRK_01",
            &[
                ("BRK_Pressure", 85.3),
                ("BRK_Switch", 1.0),
                ("BRK_PressureQ", 1.0),
                ("BRK_Counter", 15.0),
            ],
        ),
        (
            "WHL_01",
            &[
                ("WHL_SpeedFL", 55.55),
                ("WHL_SpeedFR", 55.61),
                ("WHL_SpeedRL", 55.0),
                ("WHL_SpeedRR", 54.99),
            ],
        ),
        (
            "VEH_01",
            &[
                ("VEH_Speed", 55.3),
                ("VEH_LongAccel", -4.91),
                ("VEH_Counter", 3.0),
            ],
        ),
        (
            "SHIMMY_01",
            &[
                ("SHM_AlertState", 3.0),
                ("SHM_EventCount", 12.0),
                ("SHM_Clearance", 0.2),
                ("SHM_Amplitude", 0.118),
                ("SHM_Confidence", 80.5),
                ("SHM_Counter", 9.0),
            ],
        ),
    ];
    for (name, vals) in values {
        let m = &db.messages()[db.message_by_name(name).unwrap()];
        let mut d = [0u8; 8];
        for (s, v) in *vals {
            m.signals[m.signal_by_name(s).unwrap()]
                .encode_phys(*v, &mut d)
                .unwrap();
        }
        if *name != "WHL_01" {
            ChecksumKind::Shimmy.apply(m.id, &mut d).unwrap();
            assert_eq!(shimmy_crc8(m.id, &d), Some(d[7]));
        }
        let hex: String = d.iter().map(|b| format!("{b:02x}")).collect();
        frames.push((name.to_string(), m.id, hex));
    }
    let frames_py: Vec<String> = frames
        .iter()
        .map(|(_, id, h)| format!("({id}, '{h}')"))
        .collect();
    let script = format!(
        r#"
import json, cantools
db = cantools.database.load_file({path:?}, strict=True)
out = {{"messages": [], "decoded": []}}
for m in db.messages:
    out["messages"].append({{"name": m.name, "id": m.frame_id, "len": m.length,
        "cycle": m.cycle_time, "comment": m.comment,
        "signals": [[s.name, s.start, s.length, s.byte_order, s.is_signed, s.scale, s.offset,
                     s.minimum, s.maximum, s.unit or ""] for s in m.signals]}})
for fid, h in [{frames}]:
    out["decoded"].append(db.decode_message(fid, bytes.fromhex(h), decode_choices=False))
print(json.dumps(out))
"#,
        path = repo("dbc/shimmy_reference.dbc").to_str().unwrap(),
        frames = frames_py.join(", ")
    );
    let Some(out) = python(&script) else { return };
    let v: serde_json::Value = serde_json::from_str(&out).unwrap();

    let msgs = v["messages"].as_array().unwrap();
    assert_eq!(msgs.len(), db.messages().len());
    for cm in msgs {
        let m = &db.messages()[db.message_by_name(cm["name"].as_str().unwrap()).unwrap()];
        assert_eq!(cm["id"].as_u64(), Some(m.id as u64));
        assert_eq!(cm["len"].as_u64(), Some(m.size_bytes as u64));
        assert_eq!(cm["cycle"].as_u64(), m.cycle_time_ms.map(|c| c as u64));
        assert_eq!(cm["comment"].as_str(), m.comment.as_deref());
        let sigs = cm["signals"].as_array().unwrap();
        assert_eq!(sigs.len(), m.signals.len());
        for (cs, s) in sigs.iter().zip(&m.signals) {
            assert_eq!(cs[0].as_str(), Some(s.name.as_str()));
            assert_eq!(cs[1].as_u64(), Some(s.start_bit as u64), "{}", s.name);
            assert_eq!(cs[2].as_u64(), Some(s.size as u64), "{}", s.name);
            assert_eq!(cs[3].as_str(), Some("little_endian"), "{}", s.name);
            assert_eq!(
                cs[4].as_bool(),
                Some(s.kind == shimmy::dbc::ValueKind::Signed),
                "{}",
                s.name
            );
            assert_eq!(cs[5].as_f64(), Some(s.factor), "{}", s.name);
            assert_eq!(cs[6].as_f64(), Some(s.offset), "{}", s.name);
            assert_eq!(cs[7].as_f64(), Some(s.min), "{}", s.name);
            assert_eq!(cs[8].as_f64(), Some(s.max), "{}", s.name);
            assert_eq!(cs[9].as_str(), Some(s.unit.as_str()), "{}", s.name);
        }
    }

    let decoded = v["decoded"].as_array().unwrap();
    for ((name, _, hex), dec) in frames.iter().zip(decoded) {
        let m = &db.messages()[db.message_by_name(name).unwrap()];
        let data = signals_common::hex(hex);
        for s in &m.signals {
            let ours = s.phys(&data).unwrap();
            let theirs = dec[&s.name].as_f64().unwrap();
            assert!(
                (ours - theirs).abs() <= 1e-9 * theirs.abs().max(1.0),
                "{name}.{}: ours {ours}, cantools {theirs}",
                s.name
            );
        }
        // And the values are the ones packed (within one resolution step).
        let (_, vals) = values.iter().find(|(n, _)| n == name).unwrap();
        for (s, v) in *vals {
            let sig = &m.signals[m.signal_by_name(s).unwrap()];
            assert!(
                (sig.phys(&data).unwrap() - v).abs() <= sig.factor / 2.0 + 1e-12,
                "{name}.{s}"
            );
        }
    }
}
