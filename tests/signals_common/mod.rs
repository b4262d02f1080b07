//! Helpers shared by the signals tests: where the shipped mappings and DBCs are, and reading a
//! whole log into memory.
#![allow(dead_code)]

use std::path::PathBuf;

use shimmy::dbc::Database;
use shimmy::signals::mapping::MappingConfig;
use shimmy::wire::Frame;

/// The first lines of the small test DBCs: a steering angle (0.1°, signed) in `STEER` and the
/// speed (0.01 km/h) and brake bit in `VEH`; a test appends its own signals to `VEH` or its own
/// messages: `concat!(test_dbc_head!(), " SG_ …\n")`.
#[macro_export]
macro_rules! test_dbc_head {
    () => {
        "\
BO_ 256 STEER: 8 X
 SG_ ANGLE : 0|16@1- (0.1,0) [-3276.8|3276.7] \"deg\" Y
BO_ 257 VEH: 8 X
 SG_ SPEED : 0|16@1+ (0.01,0) [0|655.35] \"km/h\" Y
 SG_ BRAKE : 16|1@1+ (1,0) [0|1] \"\" Y
"
    };
}

/// A mapping of [`test_dbc_head!`]'s DBC: its angle, speed and brake, `steer` extra lines under
/// `[steer_angle]`, then `extra` (the test's own tables).
pub fn test_mapping(steer: &str, extra: &str) -> String {
    format!(
        "[steer_angle]\nmessage = \"STEER\"\nsignal = \"ANGLE\"\nunit = \"deg\"\n{steer}\
         [speed]\nmessage = \"VEH\"\nsignal = \"SPEED\"\nunit = \"km/h\"\n\
         [brake_pressed]\nmessage = \"VEH\"\nsignal = \"BRAKE\"\n{extra}"
    )
}

pub fn repo(rel: &str) -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR")).join(rel)
}

pub fn mapping(name: &str) -> MappingConfig {
    MappingConfig::from_toml_file(repo(&format!("config/vehicles/{name}/mapping.toml"))).unwrap()
}

pub fn reference_db() -> Database {
    let (db, report) = Database::load(repo("dbc/shimmy_reference.dbc")).unwrap();
    assert!(report.skipped.is_empty(), "{:?}", report.skipped);
    db
}

pub fn hex(s: &str) -> Vec<u8> {
    (0..s.len() / 2)
        .map(|i| u8::from_str_radix(&s[2 * i..2 * i + 2], 16).unwrap())
        .collect()
}

/// Every frame of a log file, read with the project's log reader.
pub fn log_frames(path: &std::path::Path) -> Vec<Frame> {
    use shimmy::source::CanSource;
    let mut r = shimmy::source::log::LogReader::open(path).unwrap();
    let mut out = Vec::new();
    while let Some(f) = r.next_frame().unwrap() {
        out.push(f);
    }
    assert_eq!(r.stats().malformed, 0);
    out
}

/// A frame of message `msg` of the DBC text `dbc` with the given physical values (the other
/// bits zero), at `t_ns`.
pub fn encode_frame(dbc: &str, msg: &str, values: &[(&str, f64)], t_ns: i64) -> Frame {
    let (db, _) = Database::parse(dbc);
    let m = &db.messages()[db
        .message_by_name(msg)
        .unwrap_or_else(|| panic!("no message {msg}"))];
    let mut d = [0u8; 8];
    for (name, v) in values {
        m.signals[m
            .signal_by_name(name)
            .unwrap_or_else(|| panic!("no signal {name} in {msg}"))]
        .encode_phys(*v, &mut d)
        .unwrap();
    }
    Frame::classic(t_ns, m.id, m.extended, &d[..m.size_bytes.min(8)]).unwrap()
}
