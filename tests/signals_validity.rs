//! Validity rules of the Mapper on our reference bus, with frames packed through the DBC:
//! SI conversion, timeouts, checksum and counter failures, short frames, unmapped IDs.

mod signals_common;

use shimmy::dbc::Database;
use shimmy::signals::checksum::ChecksumKind;
use shimmy::signals::{Mapper, Outcome, Reject, Validity};
use shimmy::wire::Frame;
use signals_common::{mapping, reference_db};

const MS: i64 = 1_000_000;

/// Packs reference-bus frames the way firmware-sim does: DBC encoding, counter, CRC.
struct Bus {
    db: Database,
}

impl Bus {
    fn frame(&self, t_ns: i64, msg: &str, values: &[(&str, f64)]) -> Frame {
        let m = &self.db.messages()[self.db.message_by_name(msg).unwrap()];
        let mut d = vec![0u8; m.size_bytes];
        for (name, v) in values {
            let s = &m.signals[m.signal_by_name(name).unwrap()];
            s.encode_phys(*v, &mut d).unwrap();
        }
        if m.signals.iter().any(|s| s.name.ends_with("_Checksum")) {
            ChecksumKind::Shimmy.apply(m.id, &mut d).unwrap();
        }
        Frame::classic(t_ns, m.id, m.extended, &d).unwrap()
    }

    fn sas(&self, t_ns: i64, deg: f64, counter: u8) -> Frame {
        self.frame(
            t_ns,
            "SAS_01",
            &[("SAS_Angle", deg), ("SAS_Counter", counter as f64)],
        )
    }

    fn veh(&self, t_ns: i64, kmh: f64, accel: f64, counter: u8) -> Frame {
        self.frame(
            t_ns,
            "VEH_01",
            &[
                ("VEH_Speed", kmh),
                ("VEH_LongAccel", accel),
                ("VEH_Counter", counter as f64),
            ],
        )
    }

    fn brk(&self, t_ns: i64, bar: f64, switch: bool, counter: u8) -> Frame {
        self.frame(
            t_ns,
            "BRK_01",
            &[
                ("BRK_Pressure", bar),
                ("BRK_Switch", switch as u8 as f64),
                ("BRK_Counter", counter as f64),
            ],
        )
    }
}

fn setup() -> (Bus, Mapper) {
    let db = reference_db();
    let m = Mapper::new(&db, &mapping("shimmy_reference")).unwrap();
    (Bus { db }, m)
}

fn accepted(u: Option<shimmy::signals::Update>) -> bool {
    matches!(u.unwrap().outcome, Outcome::Accepted(_))
}

#[test]
fn values_arrive_in_si_units() {
    let (bus, mut m) = setup();
    let s = m.snapshot(0);
    assert_eq!(s.steer_angle_rad.validity, Validity::NoData);
    assert_eq!(s.speed_mps.valid(), None);

    assert!(accepted(m.on_frame(&bus.sas(0, -12.3, 0))));
    assert!(accepted(m.on_frame(&bus.veh(MS, 72.0, -4.9, 0))));
    assert!(accepted(m.on_frame(&bus.brk(2 * MS, 30.5, true, 0))));
    let s = m.snapshot(3 * MS);
    assert!((s.steer_angle_rad.valid().unwrap() - (-12.3f64).to_radians()).abs() < 1e-12);
    assert!((s.speed_mps.valid().unwrap() - 20.0).abs() < 1e-12);
    assert!((s.accel_mps2.valid().unwrap() + 4.9).abs() < 1e-12);
    assert!((s.brake_pressure_pa.valid().unwrap() - 30.5e5).abs() < 1e-6);
    assert_eq!(s.brake_pressed.valid(), Some(true));
    assert_eq!(s.steer_angle_rad.t_ns, Some(0));
}

#[test]
fn a_silent_message_times_out_and_recovers() {
    let (bus, mut m) = setup();
    // 100 Hz steering and 50 Hz speed for 0.5 s, steering silent from 200 to 300 ms.
    let mut sas_counter = 0u8;
    let mut veh_counter = 0u8;
    let mut steer_invalid_at = None;
    for k in 0..50i64 {
        let t = k * 10 * MS;
        if !(200..300).contains(&(k * 10)) {
            assert!(accepted(m.on_frame(&bus.sas(t, 1.0, sas_counter))));
            sas_counter = (sas_counter + 1) % 16;
        }
        if k % 2 == 0 {
            assert!(accepted(m.on_frame(&bus.veh(
                t + MS,
                50.0,
                0.0,
                veh_counter
            ))));
            veh_counter = (veh_counter + 1) % 16;
        }
        let s = m.snapshot(t + MS);
        if s.steer_angle_rad.validity == Validity::TimedOut && steer_invalid_at.is_none() {
            steer_invalid_at = Some(t + MS);
        }
        assert_eq!(s.speed_mps.validity, Validity::Valid, "t={t}");
    }
    // Last steering frame at 190 ms, timeout 50 ms: invalid from just after 240 ms.
    assert_eq!(steer_invalid_at, Some(241 * MS));
    let st = &m.stats()[0];
    assert_eq!(st.name, "SAS_01");
    assert_eq!(st.timeouts, 1);
    // After the outage the counter restarts where the sender likes: no gap, no error.
    assert_eq!((st.counter_gaps, st.counter_errors), (0, 0));
    assert_eq!(
        m.snapshot(490 * MS).steer_angle_rad.validity,
        Validity::Valid
    );
    // The brake message never came: no data, and it says so.
    let s = m.snapshot(490 * MS);
    assert_eq!(s.brake_pressed.validity, Validity::NoData);
    assert_eq!(m.stats()[2].frames, 0);
}

#[test]
fn a_quiet_bus_times_out_through_advance() {
    let (bus, mut m) = setup();
    m.on_frame(&bus.sas(0, 1.0, 0));
    m.advance(40 * MS);
    assert_eq!(m.stats()[0].timeouts, 0);
    m.advance(60 * MS);
    assert_eq!(m.stats()[0].timeouts, 1);
    m.advance(70 * MS);
    assert_eq!(m.stats()[0].timeouts, 1, "counted once per outage");
}

#[test]
fn bad_checksum_is_counted_and_the_value_not_used() {
    let (bus, mut m) = setup();
    assert!(accepted(m.on_frame(&bus.sas(0, 5.0, 0))));
    let mut f = bus.sas(10 * MS, 99.0, 1);
    f.data[7] ^= 0x01;
    let u = m.on_frame(&f).unwrap();
    assert!(matches!(u.outcome, Outcome::Rejected(Reject::Checksum(_))));
    let v = m.snapshot(10 * MS).steer_angle_rad.valid().unwrap();
    assert!(
        (v - 5f64.to_radians()).abs() < 1e-12,
        "kept the last good value"
    );
    // A frame sent under the wrong ID fails too: the CRC covers the ID.
    let mut wrong = bus.brk(11 * MS, 10.0, true, 0);
    wrong.id = 0x0A0;
    assert!(matches!(
        m.on_frame(&wrong).unwrap().outcome,
        Outcome::Rejected(Reject::Checksum(_))
    ));
    assert_eq!(m.stats()[0].checksum_errors, 2);
    assert_eq!(m.stats()[0].accepted, 1);
}

#[test]
fn counters_repeat_is_rejected_and_jump_is_a_counted_gap() {
    let (bus, mut m) = setup();
    assert!(accepted(m.on_frame(&bus.sas(0, 1.0, 14))));
    assert!(accepted(m.on_frame(&bus.sas(10 * MS, 2.0, 15))));
    assert!(accepted(m.on_frame(&bus.sas(20 * MS, 3.0, 0)))); // wraps
    let u = m.on_frame(&bus.sas(30 * MS, 4.0, 0)).unwrap();
    assert_eq!(
        u.outcome,
        Outcome::Rejected(Reject::CounterRepeat { counter: 0 })
    );
    assert!((m.snapshot(30 * MS).steer_angle_rad.value.unwrap() - 3f64.to_radians()).abs() < 1e-12);
    assert!(accepted(m.on_frame(&bus.sas(40 * MS, 5.0, 3)))); // 1 and 2 lost
    let s = &m.stats()[0];
    assert_eq!((s.counter_errors, s.counter_gaps, s.frames_lost), (1, 1, 2));
    assert_eq!((s.frames, s.accepted), (5, 4));
}

#[test]
fn short_frames_are_counted_and_unmapped_ids_ignored() {
    let (bus, mut m) = setup();
    let full = bus.sas(0, 1.0, 0);
    let short = Frame::classic(0, full.id, false, &full.data[..1]).unwrap();
    let u = m.on_frame(&short).unwrap();
    // The one-byte payload fails its checksum first (the CRC covers the length implicitly).
    assert!(matches!(u.outcome, Outcome::Rejected(_)));

    // A short frame of an unprotected message (checksum and counter off) is a short frame.
    let db = reference_db();
    let mut cfg = mapping("shimmy_reference");
    cfg.messages.remove("SAS_01");
    let mut m2 = Mapper::new(&db, &cfg).unwrap();
    let short = Frame::classic(0, full.id, false, &full.data[..1]).unwrap();
    assert_eq!(
        m2.on_frame(&short).unwrap().outcome,
        Outcome::Rejected(Reject::Short { len: 1 })
    );
    assert_eq!(m2.stats()[0].short_frames, 1);

    let other = bus.frame(0, "WHL_01", &[("WHL_SpeedFL", 10.0)]);
    assert!(m.on_frame(&other).is_none());
    let ext = Frame::classic(0, 0x0A0, true, &full.data[..8]).unwrap();
    assert!(
        m.on_frame(&ext).is_none(),
        "extended 0x0A0 is another message"
    );
    assert_eq!(m.ignored_frames(), 2);
}

#[test]
fn speed_from_the_mean_of_wheel_speeds() {
    let db = reference_db();
    let mut cfg = mapping("shimmy_reference");
    cfg.speed = toml::from_str(
        r#"
        message = "WHL_01"
        wheel_signals = ["WHL_SpeedFL", "WHL_SpeedFR", "WHL_SpeedRL", "WHL_SpeedRR"]
        unit = "km/h"
        "#,
    )
    .unwrap();
    cfg.messages.remove("VEH_01");
    cfg.accel = None;
    let mut m = Mapper::new(&db, &cfg).unwrap();
    let bus = Bus { db };
    let f = bus.frame(
        0,
        "WHL_01",
        &[
            ("WHL_SpeedFL", 70.0),
            ("WHL_SpeedFR", 72.0),
            ("WHL_SpeedRL", 71.0),
            ("WHL_SpeedRR", 75.0),
        ],
    );
    assert!(accepted(m.on_frame(&f)));
    let v = m.snapshot(0).speed_mps.valid().unwrap();
    assert!((v * 3.6 - 72.0).abs() < 1e-9, "{}", v * 3.6);
}

#[test]
fn sign_flip_and_units_compose() {
    let db = reference_db();
    let mut cfg = mapping("shimmy_reference");
    cfg.steer_angle.invert = true;
    cfg.accel.as_mut().unwrap().unit = shimmy::signals::mapping::AccelUnit::G;
    cfg.brake_pressure.as_mut().unwrap().unit = shimmy::signals::mapping::PressureUnit::KPa;
    let mut m = Mapper::new(&db, &cfg).unwrap();
    let bus = Bus { db };
    m.on_frame(&bus.sas(0, 10.0, 0));
    m.on_frame(&bus.veh(0, 36.0, -0.5, 0));
    m.on_frame(&bus.brk(0, 100.0, false, 0));
    let s = m.snapshot(0);
    assert!((s.steer_angle_rad.valid().unwrap() + 10f64.to_radians()).abs() < 1e-12);
    assert!((s.accel_mps2.valid().unwrap() + 0.5 * 9.80665).abs() < 1e-12);
    assert!((s.brake_pressure_pa.valid().unwrap() - 100e3).abs() < 1e-9);
    assert_eq!(s.brake_pressed.valid(), Some(false));
}

#[test]
fn timestamps_going_backwards_are_not_outages() {
    // A log replayed twice back to back: time jumps back by 1 s between the copies.
    let (bus, mut m) = setup();
    let mut c = 0u8;
    for copy in 0..2 {
        for k in 0..100i64 {
            let t = k * 10 * MS;
            assert!(
                accepted(m.on_frame(&bus.sas(t, 1.0, c))),
                "copy {copy} frame {k}"
            );
            c = (c + 1) % 16;
            if k % 2 == 0 {
                m.on_frame(&bus.veh(t + MS, 50.0, 0.0, ((k / 2) % 16) as u8));
            }
            assert_eq!(m.snapshot(t).steer_angle_rad.validity, Validity::Valid);
        }
    }
    assert!(m.stats().iter().all(|s| s.timeouts == 0), "{:?}", m.stats());
    // The VEH counter restarts at 0 in the second copy: a new recording, not a gap.
    assert!(
        m.stats()
            .iter()
            .all(|s| s.counter_gaps == 0 && s.counter_errors == 0),
        "{:?}",
        m.stats()
    );
}
