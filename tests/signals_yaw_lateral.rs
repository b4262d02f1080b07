//! The mapping's optional yaw rate and lateral acceleration, and the `scale` key: SI units,
//! sign bit, `invert` and `scale` compose as documented; an unmapped quantity reads
//! `not_mapped`; a scale that is not a positive number is refused with its key named.

mod signals_common;

use shimmy::dbc::Database;
use shimmy::signals::mapping::MappingConfig;
use shimmy::signals::{Mapper, Validity};
use shimmy::wire::Frame;
use signals_common::test_mapping as mapping;

const DBC: &str = concat!(
    crate::test_dbc_head!(),
    "\
 SG_ YAW : 24|14@1+ (0.01,0) [0|163.83] \"deg/s\" Y
 SG_ YAW_SIGN : 38|1@1+ (1,0) [0|1] \"\" Y
 SG_ AY : 40|8@1+ (0.01,-1.27) [-1.27|1.28] \"g\" Y
"
);

fn mapper(steer: &str, extra: &str) -> Mapper {
    let (db, _) = Database::parse(DBC);
    Mapper::new(
        &db,
        &MappingConfig::from_toml_str(&mapping(steer, extra)).unwrap(),
    )
    .unwrap()
}

/// A VEH frame with yaw magnitude `yaw_deg_s` and sign bit `neg`, lateral `ay_g`.
fn veh(t_ns: i64, yaw_deg_s: f64, neg: bool, ay_g: f64) -> Frame {
    let values = [
        ("SPEED", 36.0),
        ("YAW", yaw_deg_s),
        ("YAW_SIGN", neg as u8 as f64),
        ("AY", ay_g),
    ];
    signals_common::encode_frame(DBC, "VEH", &values, t_ns)
}

#[test]
fn yaw_rate_and_lateral_acceleration_arrive_in_si_with_sign_bit_invert_and_scale() {
    let yaw = "[yaw_rate]\nmessage = \"VEH\"\nsignal = \"YAW\"\nsign_signal = \"YAW_SIGN\"\n\
               unit = \"deg/s\"\n";
    let lat = "[lat_accel]\nmessage = \"VEH\"\nsignal = \"AY\"\nunit = \"g\"\n";
    let cases: [(&str, f64, f64); 4] = [
        ("", 1.0, 1.0),
        ("invert = true\n", -1.0, -1.0),
        ("scale = 2.0\n", 2.0, 2.0),
        ("invert = true\nscale = 0.5\n", -0.5, -0.5),
    ];
    for (opts, yaw_k, lat_k) in cases {
        let mut m = mapper("", &format!("{yaw}{opts}{lat}{opts}"));
        let u = m.on_frame(&veh(1_000_000, 10.0, true, 0.5)).unwrap();
        let s = m.snapshot(1_000_000);
        let want_yaw = yaw_k * -(10.0f64.to_radians());
        let got = s.yaw_rate_radps.valid().unwrap();
        assert!(
            (got - want_yaw).abs() < 1e-9,
            "{opts:?}: {got} vs {want_yaw}"
        );
        let got = s.lat_accel_mps2.valid().unwrap();
        let want = lat_k * 0.5 * 9.80665;
        assert!((got - want).abs() < 1e-6, "{opts:?}: {got} vs {want}");
        assert!(matches!(
            u.outcome,
            shimmy::signals::Outcome::Accepted(c) if c.yaw_rate && c.lat_accel && c.speed
        ));
    }
}

#[test]
fn unmapped_yaw_and_lateral_read_not_mapped_and_steer_scale_applies() {
    let mut m = mapper("scale = 0.1\n", "");
    let (db, _) = Database::parse(DBC);
    let st = &db.messages()[db.message_by_name("STEER").unwrap()];
    let mut d = [0u8; 8];
    st.signals[0].encode_phys(100.0, &mut d).unwrap();
    m.on_frame(&Frame::classic(5, 256, false, &d).unwrap());
    m.on_frame(&veh(6, 1.0, false, 0.0));
    let s = m.snapshot(6);
    assert_eq!(s.yaw_rate_radps.validity, Validity::NotMapped);
    assert_eq!(s.lat_accel_mps2.validity, Validity::NotMapped);
    let a = s.steer_angle_rad.valid().unwrap().to_degrees();
    assert!((a - 10.0).abs() < 1e-9, "scale 0.1 on 100 deg: {a}");
}

#[test]
fn a_scale_that_is_not_positive_is_refused_with_its_key() {
    for bad in ["0.0", "-1.0", "nan"] {
        let text = mapping(
            "",
            &format!("[accel]\nmessage = \"VEH\"\nsignal = \"AY\"\nunit = \"g\"\nscale = {bad}\n"),
        );
        let e = format!("{:#}", MappingConfig::from_toml_str(&text).unwrap_err());
        assert!(e.contains("accel.scale"), "{bad}: {e}");
    }
}
