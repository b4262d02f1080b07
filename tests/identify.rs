//! `shimmy identify` on real and synthetic logs:
//! * every form of the real RAV4 drive (candump bus 0, all buses, ASC, BLF) → `toyota_rav4`;
//! * real logs of other vehicles and loggers (CSS Electronics MF4, python-can fixtures; what
//!   the log reader cannot read gives no frames) → unknown;
//! * firmware-sim logs of every profile's bus → that profile ([`FIRMWARE_SIM`]);
//! * synthetic buses of the VW, Honda and Hyundai profiles, every mapped message packed with the
//!   DBC encoder, valid counters and checksums, at plausible rates → their profile; the same
//!   with checksums corrupted, with counters frozen, or with the IDs and lengths only (random
//!   payloads) → not identified;
//! * buses of DBCs no profile describes (same maker's other generation included) → unknown.

#[path = "e2e_common/mod.rs"]
mod e2e_common;

use std::io::Write;
use std::path::{Path, PathBuf};
use std::process::Command;

use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use shimmy::dbc::{Database, RawValue};
use shimmy::profile::identify::{self, Candidate, Catalogue, Identification, Options, Verdict};
use shimmy::profile::Profile;
use shimmy::shared_data;
use shimmy::wire::{candump, Frame};

fn repo(rel: &str) -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join(rel)
}

/// The shipped profiles (their DBCs come from the shared data: without it, only the reference).
fn catalogue() -> Catalogue {
    let cat = Catalogue::search_path();
    if shared_data::configured_dir().is_dir() {
        assert!(
            cat.not_loaded.is_empty(),
            "profiles that do not load: {:?}",
            cat.not_loaded
        );
    }
    cat
}

fn identify_file(cat: &Catalogue, log: &Path) -> Identification {
    identify::identify_logs_with(cat, &[log.to_path_buf()], Options::default())
        .unwrap_or_else(|e| panic!("{}: {e:#}", log.display()))
}

fn assert_identified(id: &Identification, profile: &str, what: &str) {
    assert_eq!(
        (id.verdict, id.profile.as_deref()),
        (Verdict::Identified, Some(profile)),
        "{what}: {}\n{:#?}",
        id.summary,
        id.profiles.first()
    );
}

fn assert_not_identified(id: &Identification, what: &str) {
    assert_ne!(id.verdict, Verdict::Identified, "{what}: {}", id.summary);
}

#[test]
fn every_form_of_the_real_rav4_drive_is_the_rav4() {
    let Some(dir) = shared_data::require("the comma2k19 RAV4 logs") else {
        return;
    };
    let cat = catalogue();
    for f in [
        "rav4_2017_seg40_bus0.log",
        "rav4_2017_seg40_allbus.log",
        "rav4_2017_seg40_bus0.asc",
        "rav4_2017_seg40_bus0.blf",
    ] {
        let id = identify_file(&cat, &dir.join("logs/comma2k19-rav4").join(f));
        assert_identified(&id, "toyota_rav4", f);
        let rav4 = id.chosen().unwrap();
        // The mapped messages with a checksum (STEER_ANGLE_SENSOR, KINEMATICS,
        // STEER_TORQUE_SENSOR; the wheel speeds and the brake module carry none) verified on
        // every frame.
        let verified: Vec<_> = rav4
            .messages
            .iter()
            .filter(|m| {
                m.checksum
                    .as_ref()
                    .is_some_and(|c| c.verified == Some(true))
            })
            .collect();
        assert_eq!(verified.len(), 3, "{f}: {rav4:#?}");
        for m in verified {
            let c = m.checksum.as_ref().unwrap();
            assert_eq!(c.passed, c.checked, "{f} {}", m.name);
        }
    }
}

#[test]
fn a_few_seconds_suffice_and_the_window_bounds_what_is_read() {
    let Some(dir) = shared_data::require("the comma2k19 RAV4 log") else {
        return;
    };
    let cat = catalogue();
    let log = dir.join("logs/comma2k19-rav4/rav4_2017_seg40_bus0.log");
    let opts = Options {
        max_seconds: 2.0,
        ..Options::default()
    };
    let id = identify::identify_logs_with(&cat, std::slice::from_ref(&log), opts).unwrap();
    assert_identified(&id, "toyota_rav4", "2 s of the RAV4 log");
    assert!(
        id.seconds_read <= 2.0 && id.seconds_read > 1.9,
        "{}",
        id.seconds_read
    );
    assert!(id.frames_read < 2000, "{}", id.frames_read);
}

#[test]
fn real_logs_of_other_vehicles_and_loggers_are_unknown() {
    let Some(dir) = shared_data::require("the MF4 and python-can logs") else {
        return;
    };
    let cat = catalogue();
    let mut looked = 0;
    for sub in ["logs/mf4-css-electronics", "logs/python-can/test_data"] {
        let mut files: Vec<PathBuf> = std::fs::read_dir(dir.join(sub))
            .unwrap()
            .map(|e| e.unwrap().path())
            .filter(|p| {
                let n = p.file_name().unwrap().to_string_lossy().to_lowercase();
                n.ends_with(".mf4")
                    || n.ends_with(".asc")
                    || n.ends_with(".blf")
                    || n.ends_with(".trc")
                    || n.ends_with(".asc.gz")
            })
            .collect();
        files.sort();
        for f in files {
            // A format the reader refuses outright is skipped; one it reads as nothing is
            // an unknown log with no frames.
            let Ok(id) =
                identify::identify_logs_with(&cat, std::slice::from_ref(&f), Options::default())
            else {
                continue;
            };
            assert_eq!(
                id.verdict,
                Verdict::Unknown,
                "{}: {}",
                f.display(),
                id.summary
            );
            looked += 1;
        }
    }
    assert!(looked >= 20, "only {looked} logs looked at");
}

/// Logs firmware-sim writes for a profile's bus: (profile, firmware-sim arguments). When
/// firmware-sim emulates another profile's bus, add its line here.
const FIRMWARE_SIM: &[(&str, &[&str])] = &[
    (
        "shimmy_reference",
        &["--scenario", "config/scenarios/worn_0p2mm.toml"],
    ),
    (
        "shimmy_reference_eps",
        &[
            "--scenario",
            "config/scenarios/worn_0p2mm.toml",
            "--profile",
            "shimmy_reference_eps",
        ],
    ),
    (
        "toyota_rav4",
        &[
            "--scenario",
            "config/scenarios/worn_0p2mm.toml",
            "--profile",
            "toyota_rav4",
        ],
    ),
    (
        "vw_mqb",
        &[
            "--scenario",
            "config/scenarios/worn_0p1mm.toml",
            "--profile",
            "vw_mqb",
        ],
    ),
    (
        "honda_civic",
        &[
            "--scenario",
            "config/scenarios/worn_0p4mm.toml",
            "--profile",
            "honda_civic",
        ],
    ),
    (
        "hyundai_kia",
        &[
            "--scenario",
            "config/scenarios/new_car.toml",
            "--profile",
            "hyundai_kia",
        ],
    ),
];

#[test]
fn firmware_sim_logs_are_their_profile() {
    let cat = catalogue();
    let id = identify_file(&cat, &repo("tests/fixtures/demo/worn_0p2mm.log"));
    assert_identified(&id, "shimmy_reference", "the demo fixture");
    let dir = tempfile::tempdir().unwrap();
    for (i, (profile, args)) in FIRMWARE_SIM.iter().enumerate() {
        let log = dir.path().join(format!("{i}.log"));
        let out = Command::new(e2e_common::firmware_sim())
            .args(*args)
            .arg("--out")
            .arg(&log)
            .current_dir(repo(""))
            .output()
            .unwrap();
        assert!(
            out.status.success(),
            "firmware-sim {args:?}: {}",
            String::from_utf8_lossy(&out.stderr)
        );
        let id = identify_file(&cat, &log);
        assert_identified(&id, profile, &format!("firmware-sim {args:?}"));
    }
}

/// How a synthetic bus is damaged.
#[derive(Clone, Copy, Debug, PartialEq)]
enum Damage {
    None,
    /// Every declared checksum byte wrong.
    Checksums,
    /// Every declared counter stuck at one value.
    Counters,
    /// The right IDs and lengths, random payloads.
    IdsOnly,
}

/// A plausible physical value for a signal the mapping reads, by its role.
fn value_for(role: &str, t: f64) -> f64 {
    match role {
        "steer" => 3.0 * (0.5 * t).sin(),
        "speed" => 60.0 + 5.0 * (0.1 * t).sin(),
        "accel" => 0.3 * (0.2 * t).sin(),
        "yaw" => 1.0 + 0.5 * (0.5 * t).sin(),
        "lat" => 0.1 * (0.5 * t).sin(),
        _ => 0.0,
    }
}

/// `seconds` of a profile's bus: every message it expects at its period (bus.toml, the DBC,
/// else 10 ms for the steering message and 20 ms for the others, with ±0.3 ms jitter), the
/// mapped signals filled with plausible values, counters counting and checksums applied
/// (unless `damage` says otherwise), written as candump -L to `out`.
fn synthesize(profile: &Profile, seconds: f64, damage: Damage, seed: u64, out: &Path) {
    let cand = Candidate::from_profile(profile).unwrap();
    let (db, _) = Database::load(&profile.dbc_path).unwrap();
    let map = &profile.mapping;
    let mut roles: Vec<(&str, &str, &str)> = vec![
        (&map.steer_angle.message, &map.steer_angle.signal, "steer"),
        (
            &map.speed.message,
            map.speed.signal.as_deref().unwrap_or(""),
            "speed",
        ),
    ];
    for w in &map.speed.wheel_signals {
        roles.push((&map.speed.message, w, "speed"));
    }
    if let Some(a) = &map.accel {
        roles.push((&a.message, &a.signal, "accel"));
    }
    if let Some(a) = &map.yaw_rate {
        roles.push((&a.message, &a.signal, "yaw"));
    }
    if let Some(a) = &map.lat_accel {
        roles.push((&a.message, &a.signal, "lat"));
    }
    let mut rng = ChaCha8Rng::seed_from_u64(seed);
    let mut frames: Vec<Frame> = Vec::new();
    for em in &cand.messages {
        let msg = &db.messages()[db.message_by_name(&em.name).unwrap()];
        let period_ms = em
            .period_ms
            .unwrap_or(if em.name == map.steer_angle.message {
                10.0
            } else {
                20.0
            });
        let n = (seconds * 1000.0 / period_ms) as u64;
        let phase = rng.random_range(0.0..period_ms);
        for k in 0..n {
            let t_ms = phase + k as f64 * period_ms + rng.random_range(-0.3..0.3);
            let t = t_ms * 1e-3;
            let mut data = vec![0u8; msg.size_bytes];
            if damage == Damage::IdsOnly {
                rng.fill(&mut data[..]);
            } else {
                for (m, s, role) in &roles {
                    if *m == em.name {
                        if let Some(i) = msg.signal_by_name(s) {
                            let _ = msg.signals[i].encode_phys(value_for(role, t), &mut data);
                        }
                    }
                }
                if let Some((sig, modulus)) = &em.counter {
                    let c = if damage == Damage::Counters { 3 } else { k };
                    sig.encode_raw(RawValue::Unsigned(c % modulus), &mut data)
                        .unwrap();
                }
                if let Some(kind) = em.checksum {
                    kind.apply(em.id, &mut data).unwrap();
                    if damage == Damage::Checksums {
                        let i = kind.byte_index(data.len());
                        data[i] ^= 0x5A;
                    }
                }
            }
            let mut f = Frame::classic((1.7e9 * 1e9 + t * 1e9) as i64, em.id, em.extended, &data)
                .expect("classic frame");
            f.set_iface("can0");
            frames.push(f);
        }
    }
    frames.sort_by_key(|f| f.t_ns);
    let mut w = std::io::BufWriter::new(std::fs::File::create(out).unwrap());
    for f in &frames {
        candump::write_frame(&mut w, f).unwrap();
    }
    w.flush().unwrap();
}

#[test]
fn synthetic_buses_of_the_profiles_are_identified_and_damaged_ones_are_not() {
    if shared_data::require("the opendbc DBCs of the profiles").is_none() {
        return;
    }
    let cat = catalogue();
    let dir = tempfile::tempdir().unwrap();
    for (i, name) in ["vw_mqb", "honda_civic", "hyundai_kia", "toyota_rav4"]
        .iter()
        .enumerate()
    {
        let p = Profile::load(name).unwrap();
        let log = dir.path().join(format!("{name}.log"));
        synthesize(&p, 20.0, Damage::None, i as u64, &log);
        let id = identify_file(&cat, &log);
        eprintln!("{name}: {}", id.summary);
        assert_identified(&id, name, &format!("synthetic {name}"));
        let declares_checksum = p.mapping.messages.values().any(|r| r.checksum.is_some());
        let declares_counter = p
            .mapping
            .messages
            .values()
            .any(|r| r.counter_signal.is_some());
        let mut damages = vec![Damage::IdsOnly];
        if declares_checksum {
            damages.push(Damage::Checksums);
        }
        // Frozen counters are damage enough where nothing but counters protects the bus.
        if declares_counter && !declares_checksum {
            damages.push(Damage::Counters);
        }
        for d in damages {
            synthesize(&p, 20.0, d, 100 + i as u64, &log);
            let id = identify_file(&cat, &log);
            eprintln!("{name} with {d:?}: {}", id.summary);
            assert_not_identified(&id, &format!("{name} with {d:?}"));
            assert_eq!(
                id.closest.as_deref(),
                Some(*name),
                "{name} {d:?}: the closest is still the profile whose IDs these are: {}",
                id.summary
            );
        }
    }
}

#[test]
fn buses_no_profile_describes_are_unknown() {
    let Some(data) = shared_data::require("the opendbc DBCs") else {
        return;
    };
    let cat = catalogue();
    let dir = tempfile::tempdir().unwrap();
    let mut rng = ChaCha8Rng::seed_from_u64(7);
    // Other makers, and another generation of a profiled maker (hyundai_i30 shares IDs with
    // the Hyundai profile's DBC).
    for dbc in [
        "gm_global_a_powertrain_generated.dbc",
        "tesla_model3_party.dbc",
        "psa_aee2010_r3.dbc",
        "hyundai_i30_2014.dbc",
    ] {
        let (db, _) = Database::load(data.join("dbc/opendbc").join(dbc)).unwrap();
        let log = dir.path().join(format!("{dbc}.log"));
        let mut frames = Vec::new();
        for m in db.messages().iter().filter(|m| m.size_bytes <= 8) {
            for k in 0..500u64 {
                let mut d = vec![0u8; m.size_bytes];
                rng.fill(&mut d[..]);
                // A counter-like low nibble that counts, as many real buses have.
                if !d.is_empty() {
                    d[0] = (d[0] & 0xF0) | (k % 16) as u8;
                }
                let t = (1.7e18 as i64) + (k as i64) * 20_000_000 + m.id as i64;
                let mut f = Frame::classic(t, m.id, m.extended, &d).unwrap();
                f.set_iface("can0");
                frames.push(f);
            }
        }
        frames.sort_by_key(|f| f.t_ns);
        let mut w = std::io::BufWriter::new(std::fs::File::create(&log).unwrap());
        for f in &frames {
            candump::write_frame(&mut w, f).unwrap();
        }
        w.flush().unwrap();
        let id = identify_file(&cat, &log);
        eprintln!("{dbc}: {}", id.summary);
        assert_eq!(id.verdict, Verdict::Unknown, "{dbc}: {}", id.summary);
    }
}

#[test]
fn a_log_with_only_some_of_the_ids_is_not_the_car() {
    let Some(dir) = shared_data::require("the comma2k19 RAV4 log") else {
        return;
    };
    let cat = catalogue();
    // The real RAV4 frames of two of its four mapped messages (steering and speed, both with
    // valid checksums), nothing else.
    let text =
        std::fs::read_to_string(dir.join("logs/comma2k19-rav4/rav4_2017_seg40_bus0.log")).unwrap();
    let kept: String = text
        .lines()
        .filter(|l| l.contains(" 025#") || l.contains(" 0B4#"))
        .map(|l| format!("{l}\n"))
        .collect();
    let tmp = tempfile::tempdir().unwrap();
    let log = tmp.path().join("part.log");
    std::fs::write(&log, kept).unwrap();
    let id = identify_file(&cat, &log);
    assert_eq!(id.verdict, Verdict::Unknown, "{}", id.summary);
    assert_eq!(id.closest.as_deref(), Some("toyota_rav4"));
    assert!(id.summary.contains("absent"), "{}", id.summary);
}

#[test]
fn the_command_prints_the_verdict_and_its_exit_status_says_whether_it_named_a_profile() {
    let demo = repo("tests/fixtures/demo/worn_0p2mm.log");
    let out = Command::new(env!("CARGO_BIN_EXE_shimmy"))
        .args(["identify", "--format", "json"])
        .arg(&demo)
        .output()
        .unwrap();
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    let v: serde_json::Value = serde_json::from_slice(&out.stdout).unwrap();
    assert_eq!(v["verdict"], "identified");
    assert_eq!(v["profile"], "shimmy_reference");
    assert_eq!(v["profiles"][0]["fits"], true);
    assert!(v["profiles"][0]["messages"][0]["checksum"]["verified"] == true);

    let tmp = tempfile::tempdir().unwrap();
    let other = tmp.path().join("other.log");
    std::fs::write(&other, "(1.000000) can0 123#0011223344556677\n").unwrap();
    let out = Command::new(env!("CARGO_BIN_EXE_shimmy"))
        .arg("identify")
        .arg(&demo)
        .arg(&other)
        .output()
        .unwrap();
    let text = String::from_utf8_lossy(&out.stdout);
    assert_eq!(out.status.code(), Some(3), "{text}");
    assert!(text.contains("identified: shimmy_reference"), "{text}");
    assert!(text.contains("unknown: none of the"), "{text}");

    let help = Command::new(env!("CARGO_BIN_EXE_shimmy"))
        .args(["identify", "--help"])
        .output()
        .unwrap();
    let help = String::from_utf8_lossy(&help.stdout);
    assert!(
        help.contains("Exit status") && help.contains("checksum"),
        "{help}"
    );
}

/// A copy of the reference profile in `dir/name`, with `bus` as its bus.toml when given.
fn reference_copy(dir: &Path, name: &str, bus: Option<&str>) -> Profile {
    let src = repo("config/vehicles/shimmy_reference");
    let dst = dir.join(name);
    std::fs::create_dir_all(&dst).unwrap();
    // Without its table, and so without its chassis variants' (they need it beside them).
    let text = std::fs::read_to_string(src.join("profile.toml")).unwrap();
    let mut in_variant = false;
    let kept: Vec<&str> = text
        .lines()
        .filter(|l| {
            if l.starts_with('[') {
                in_variant = l.starts_with("[[chassis.variants]]");
            }
            !in_variant
        })
        .collect();
    let mut profile = (kept.join("\n") + "\n")
        .replace("table = \"table.json\"\n", "")
        .replace(
            "dbc = \"shimmy_reference.dbc\"",
            &format!("dbc = {:?}", repo("dbc/shimmy_reference.dbc")),
        );
    // The shipped profile names its bus.toml; the copy gets the one given, or none.
    match bus {
        Some(b) => std::fs::write(dst.join("bus.toml"), b).unwrap(),
        None => profile = profile.replace("bus = \"bus.toml\"\n", ""),
    }
    std::fs::write(dst.join("profile.toml"), profile).unwrap();
    std::fs::copy(src.join("mapping.toml"), dst.join("mapping.toml")).unwrap();
    Profile::load_dir(&dst).unwrap()
}

const REFERENCE_BUS: &str = "\
[[message]]\nname = \"SAS_01\"\nperiod_ms = 10\n\
[[message]]\nname = \"BRK_01\"\nperiod_ms = 20\n\
[[message]]\nname = \"WHL_01\"\nperiod_ms = 20\n\
[[message]]\nname = \"VEH_01\"\nperiod_ms = 20\n";

#[test]
fn a_bus_description_adds_its_messages_and_periods_to_the_evidence() {
    let dir = tempfile::tempdir().unwrap();
    let demo = repo("tests/fixtures/demo/worn_0p2mm.log");
    let good = reference_copy(dir.path(), "with_bus", Some(REFERENCE_BUS));
    let cat = Catalogue::of(std::slice::from_ref(&good)).unwrap();
    let id = identify_file(&cat, &demo);
    assert_identified(&id, "with_bus", "the demo against a profile with bus.toml");
    let ev = id.chosen().unwrap();
    let whl = ev.messages.iter().find(|m| m.name == "WHL_01").unwrap();
    assert!(whl.in_bus && !whl.mapped && whl.frames > 1000, "{whl:?}");
    assert!(ev
        .messages
        .iter()
        .all(|m| m.period_ok == Some(true) && m.period_from == Some("bus.toml")));

    // A bus whose steering is sent every 50 ms is not this one.
    let slow = reference_copy(
        dir.path(),
        "slow_steering",
        Some(&REFERENCE_BUS.replace("period_ms = 10", "period_ms = 50")),
    );
    let cat = Catalogue::of(&[slow]).unwrap();
    let id = identify_file(&cat, &demo);
    assert_eq!(id.verdict, Verdict::Unknown, "{}", id.summary);
    assert!(
        id.summary.contains("SAS_01") && id.summary.contains("50 ms"),
        "{}",
        id.summary
    );

    // A bus with a message the log lacks (two of them: more than a fifth absent).
    let more = format!("{REFERENCE_BUS}[[message]]\nname = \"SHIMMY_01\"\nperiod_ms = 100\n");
    let extra = reference_copy(dir.path(), "extra", Some(&more));
    let cat = Catalogue::of(&[extra]).unwrap();
    let id = identify_file(&cat, &demo);
    assert_eq!(id.verdict, Verdict::Unknown, "{}", id.summary);
    assert!(
        id.summary.contains("bus.toml messages are absent"),
        "{}",
        id.summary
    );
}

#[test]
fn two_profiles_of_the_same_bus_are_ambiguous_and_the_better_described_one_wins() {
    let dir = tempfile::tempdir().unwrap();
    let demo = repo("tests/fixtures/demo/worn_0p2mm.log");
    let a = reference_copy(dir.path(), "twin_a", None);
    let b = reference_copy(dir.path(), "twin_b", None);
    let cat = Catalogue::of(&[a.clone(), b]).unwrap();
    let id = identify_file(&cat, &demo);
    assert_eq!(id.verdict, Verdict::Ambiguous, "{}", id.summary);
    assert_eq!(id.candidates, vec!["twin_a", "twin_b"]);
    // The same twins, one with a bus description whose periods match: more evidence, named.
    let c = reference_copy(dir.path(), "twin_c", Some(REFERENCE_BUS));
    let cat = Catalogue::of(&[a, c]).unwrap();
    let id = identify_file(&cat, &demo);
    assert_identified(&id, "twin_c", "twins, one with a bus.toml");
}

#[test]
fn the_frames_of_the_real_mf4_logs_are_unknown_whatever_reads_them() {
    // The frames an MF4 reader gives (asammdf's, shipped beside each file), as candump: real
    // OBD2/UDS and J1939 traffic of other vehicles.
    let Some(dir) = shared_data::require("the MF4 logs' expected frames") else {
        return;
    };
    use std::io::Read;
    let cat = catalogue();
    let tmp = tempfile::tempdir().unwrap();
    let mut looked = 0;
    for e in std::fs::read_dir(dir.join("logs/mf4-css-electronics")).unwrap() {
        let p = e.unwrap().path();
        if !p.to_string_lossy().ends_with(".expected_frames.csv.gz") {
            continue;
        }
        let mut text = String::new();
        flate2::read::GzDecoder::new(std::fs::File::open(&p).unwrap())
            .read_to_string(&mut text)
            .unwrap();
        let mut frames: Vec<Frame> = Vec::new();
        for line in text.lines().skip(1) {
            let c: Vec<&str> = line.split(',').collect();
            let t: f64 = c[0].parse().unwrap();
            let data: Vec<u8> = (0..c[6].len() / 2)
                .map(|i| u8::from_str_radix(&c[6][2 * i..2 * i + 2], 16).unwrap())
                .collect();
            let (id, ext) = (c[3].parse().unwrap(), c[4] == "1");
            let f = if data.len() <= 8 {
                Frame::classic((t * 1e9) as i64, id, ext, &data)
            } else {
                Frame::fd((t * 1e9) as i64, id, ext, &data)
            };
            let Some(mut f) = f else {
                continue;
            };
            f.set_iface(&format!("can{}", c[2]));
            frames.push(f);
        }
        frames.sort_by_key(|f| f.t_ns);
        let log = tmp.path().join("mf4.log");
        let mut w = std::io::BufWriter::new(std::fs::File::create(&log).unwrap());
        for f in &frames {
            candump::write_frame(&mut w, f).unwrap();
        }
        w.flush().unwrap();
        drop(w);
        let id = identify_file(&cat, &log);
        assert!(id.frames_read > 0, "{}", p.display());
        assert_eq!(
            id.verdict,
            Verdict::Unknown,
            "{}: {}",
            p.display(),
            id.summary
        );
        looked += 1;
    }
    assert_eq!(looked, 6);
}
