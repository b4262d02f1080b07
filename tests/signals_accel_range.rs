//! A mapped longitudinal acceleration too narrow for hard braking: the mapper reads it not at
//! all (the detector then differentiates the speed) and says why; a wide enough one is read.

mod signals_common;

use shimmy::dbc::Database;
use shimmy::signals::mapping::MappingConfig;
use shimmy::signals::Mapper;
use shimmy::wire::Frame;

/// `NARROW` is Honda's KINEMATICS.LONG_ACCEL layout: 9 signed bits of -0.02 m/s², ±5.1 m/s².
const DBC: &str = concat!(
    crate::test_dbc_head!(),
    "\
 SG_ NARROW : 24|9@1- (-0.02,0) [-20|20] \"m/s2\" Y
 SG_ WIDE : 40|10@1+ (0.03125,-16) [-16|15.97] \"m/s2\" Y
 SG_ WIDE_G : 56|8@1+ (0.01,-1.27) [-1.27|1.28] \"g\" Y
"
);

fn mapper(accel: &str, invert: bool) -> Mapper {
    let (db, _) = Database::parse(DBC);
    let unit = if accel == "WIDE_G" { "g" } else { "m/s^2" };
    let toml = signals_common::test_mapping(
        "",
        &format!(
            "[accel]\nmessage = \"VEH\"\nsignal = \"{accel}\"\nunit = \"{unit}\"\ninvert = {invert}\n"
        ),
    );
    Mapper::new(&db, &MappingConfig::from_toml_str(&toml).unwrap()).unwrap()
}

fn frame(accel: &str, v: f64) -> Frame {
    let (db, _) = Database::parse(DBC);
    let m = &db.messages()[db.message_by_name("VEH").unwrap()];
    let mut d = [0u8; 8];
    for (name, x) in [("SPEED", 50.0), (accel, v)] {
        m.signals[m.signal_by_name(name).unwrap()]
            .encode_phys(x, &mut d)
            .unwrap();
    }
    Frame::classic(1_000_000, 257, false, &d).unwrap()
}

#[test]
fn an_acceleration_that_clips_below_0p8_g_of_braking_is_not_read_and_the_mapper_says_why() {
    let mut m = mapper("NARROW", false);
    let w = m.warnings().join("\n");
    assert!(
        w.contains("VEH.NARROW") && w.contains("0.52 g") && w.contains("speed's derivative"),
        "{w}"
    );
    m.on_frame(&frame("NARROW", -4.0)).unwrap();
    assert!(m.snapshot(1_000_000).accel_mps2.valid().is_none());
    assert!(m.snapshot(1_000_000).speed_mps.valid().is_some());
}

#[test]
fn wide_signals_are_read_in_si_whatever_their_unit_and_sign() {
    for (sig, invert, raw, want) in [
        ("WIDE", false, -7.0, -7.0),
        // ±15.97 m/s² either way: inverted, braking still fits.
        ("WIDE", true, 7.0, -7.0),
        ("WIDE_G", false, -0.9, -0.9 * 9.80665),
    ] {
        let mut m = mapper(sig, invert);
        assert!(m.warnings().is_empty(), "{sig}: {:?}", m.warnings());
        m.on_frame(&frame(sig, raw)).unwrap();
        let got = m.snapshot(1_000_000).accel_mps2.valid().unwrap();
        assert!((got - want).abs() < 0.04, "{sig}: {got} vs {want}");
    }
}

#[test]
fn the_range_is_judged_after_inversion() {
    // NARROW inverted reads up to +5.12 forward and -5.1 backward either way: still refused.
    assert!(!mapper("NARROW", true).warnings().is_empty());
}
