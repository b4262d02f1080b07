//! The mapping's optional steering torque (the EPS torsion-bar reading): N·m and centi-N·m, the
//! sign bit, `invert` and `scale` compose as documented; an unmapped torque reads `not_mapped`;
//! and on the real RAV4 log the Toyota profile's mapping reads `STEER_TORQUE_DRIVER` at its
//! 50 Hz with every checksum good.

mod signals_common;

use shimmy::dbc::Database;
use shimmy::profile::Profile;
use shimmy::signals::mapping::MappingConfig;
use shimmy::signals::{Mapper, Outcome, Validity};
use shimmy::source::log::LogReader;
use shimmy::source::CanSource;
use shimmy::wire::Frame;

const DBC: &str = concat!(
    crate::test_dbc_head!(),
    "\
BO_ 258 EPS: 8 X
 SG_ TQ : 0|10@1+ (1,0) [0|1023] \"Unit_centiNewtoMeter\" Y
 SG_ TQ_SIGN : 10|1@1+ (1,0) [0|1] \"\" Y
"
);

fn mapper(torque: &str) -> Mapper {
    let (db, _) = Database::parse(DBC);
    let text = signals_common::test_mapping("", torque);
    Mapper::new(&db, &MappingConfig::from_toml_str(&text).unwrap()).unwrap()
}

/// An EPS frame with torque magnitude `counts` and sign bit `neg`.
fn eps(t_ns: i64, counts: f64, neg: bool) -> Frame {
    let sign = neg as u8 as f64;
    signals_common::encode_frame(DBC, "EPS", &[("TQ", counts), ("TQ_SIGN", sign)], t_ns)
}

#[test]
fn steering_torque_arrives_in_newton_metres_with_sign_bit_invert_and_scale() {
    let base = "[steer_torque]\nmessage = \"EPS\"\nsignal = \"TQ\"\n";
    // (mapping lines, expected N·m for 150 counts with the sign bit set)
    let cases: [(&str, f64); 5] = [
        ("unit = \"cNm\"\nsign_signal = \"TQ_SIGN\"\n", -1.5),
        (
            "unit = \"cNm\"\nsign_signal = \"TQ_SIGN\"\ninvert = true\n",
            1.5,
        ),
        ("unit = \"cNm\"\n", 1.5),
        (
            "unit = \"Nm\"\nscale = 0.01\nsign_signal = \"TQ_SIGN\"\n",
            -1.5,
        ),
        ("unit = \"Nm\"\nscale = 0.02\ninvert = true\n", -3.0),
    ];
    for (opts, want) in cases {
        let mut m = mapper(&format!("{base}{opts}"));
        let u = m.on_frame(&eps(1_000_000, 150.0, true)).unwrap();
        assert!(
            matches!(u.outcome, Outcome::Accepted(c) if c.steer_torque && !c.steer_angle),
            "{opts:?}: {:?}",
            u.outcome
        );
        let got = m.snapshot(1_000_000).steer_torque_nm.valid().unwrap();
        assert!(
            (got - want).abs() < 1e-9,
            "{opts:?}: {got} N·m, want {want}"
        );
        // Like every quantity, it times out with its message (default 200 ms).
        let later = m.snapshot(1_000_000 + 250_000_000).steer_torque_nm;
        assert_eq!(later.validity, Validity::TimedOut, "{opts:?}");
    }
}

#[test]
fn an_unmapped_torque_reads_not_mapped_and_a_misspelt_one_is_refused() {
    let mut m = mapper("");
    assert!(
        m.on_frame(&eps(5, 10.0, false)).is_none(),
        "EPS is not read"
    );
    assert_eq!(m.snapshot(5).steer_torque_nm.validity, Validity::NotMapped);
    // A signal the message lacks is an error naming the key.
    let (db, _) = Database::parse(DBC);
    let text = "[steer_angle]\nmessage = \"STEER\"\nsignal = \"ANGLE\"\nunit = \"deg\"\n\
                [speed]\nmessage = \"VEH\"\nsignal = \"SPEED\"\nunit = \"km/h\"\n\
                [brake_pressed]\nmessage = \"VEH\"\nsignal = \"BRAKE\"\n\
                [steer_torque]\nmessage = \"EPS\"\nsignal = \"TORQUE\"\nunit = \"Nm\"\n";
    let e = format!(
        "{:#}",
        Mapper::new(&db, &MappingConfig::from_toml_str(text).unwrap()).unwrap_err()
    );
    assert!(
        e.contains("steer_torque.signal") && e.contains("TORQUE"),
        "{e}"
    );
    // An unknown unit is refused by the file format.
    let bad = text.replace("unit = \"Nm\"", "unit = \"kgf\"");
    assert!(MappingConfig::from_toml_str(&bad).is_err());
}

/// comma2k19's RAV4 minute: 0x260 at 50 Hz, Toyota checksums good on every frame, the torque
/// within what the raw counts span (−149..138 at the assumed 100 counts per N·m).
#[test]
fn the_rav4_profile_reads_the_real_drivers_torque() {
    let Some((log, _)) = shimmy::shared_data::require_rav4() else {
        return;
    };
    let p = Profile::load("toyota_rav4").unwrap();
    let (db, _) = Database::load(&p.dbc_path).unwrap();
    let mut m = Mapper::new(&db, &p.mapping).unwrap();
    let mut r = LogReader::open(&log).unwrap();
    let mut f = Frame::empty(0);
    let (mut n, mut t0, mut t1, mut lo, mut hi) = (0u64, None, 0i64, f64::MAX, f64::MIN);
    while r.read_frame(&mut f).unwrap() {
        let Some(u) = m.on_frame(&f) else { continue };
        match u.outcome {
            Outcome::Accepted(c) if c.steer_torque => {
                let v = m.snapshot(f.t_ns).steer_torque_nm.valid().unwrap();
                lo = lo.min(v);
                hi = hi.max(v);
                n += 1;
                t0.get_or_insert(f.t_ns);
                t1 = f.t_ns;
            }
            Outcome::Accepted(_) => {}
            Outcome::Rejected(rej) => panic!("0x{:X} rejected: {rej}", f.id),
        }
    }
    let span_s = (t1 - t0.unwrap()) as f64 * 1e-9;
    let rate = (n - 1) as f64 / span_s;
    assert!((rate - 50.0).abs() < 0.5, "{n} torque frames, {rate:.2} Hz");
    assert!(
        (lo - -1.49).abs() < 1e-9 && (hi - 1.38).abs() < 1e-9,
        "torque spans {lo}..{hi} N·m"
    );
    let st = m.stats();
    let t = st.iter().find(|s| s.name == "STEER_TORQUE_SENSOR").unwrap();
    assert_eq!((t.rejected(), t.timeouts), (0, 0), "{t:?}");
}
