//! The shipped mappings against their DBCs and against real data: every mapping resolves; the
//! RAV4 mapping on the real RAV4 log gives the composed values of the expected decode; the VW
//! mapping accepts real MQB frames (CRC and counters) and rejects corrupted ones.

mod signals_common;

use std::collections::BTreeMap;

use shimmy::dbc::Database;
use shimmy::shared_data::require_file;
use shimmy::signals::{Mapper, Outcome, Reject, Validity};
use shimmy::wire::Frame;
use signals_common::{hex, log_frames, mapping, reference_db};

#[test]
fn every_shipped_mapping_resolves_against_its_dbc() {
    let cases = [
        (
            "toyota_rav4",
            "dbc/opendbc/toyota_new_mc_pt_generated.dbc",
            5,
        ),
        ("vw_mqb", "dbc/opendbc/vw_mqb.dbc", 5),
        (
            "honda_civic",
            "dbc/opendbc/honda_civic_touring_2016_can_generated.dbc",
            // No KINEMATICS: its acceleration clips at 0.52 g (the mapping's comment).
            4,
        ),
        ("hyundai_kia", "dbc/opendbc/hyundai_can_generated.dbc", 5),
    ];
    for (name, dbc, n_ids) in cases {
        let Some(p) = require_file(dbc) else { return };
        let cfg = mapping(name);
        assert_eq!(cfg.dbc.as_deref(), p.file_name().and_then(|f| f.to_str()));
        let (db, _) = Database::load(&p).unwrap();
        let m = Mapper::new(&db, &cfg).unwrap_or_else(|e| panic!("{name}: {e:#}"));
        assert_eq!(m.needed_ids().len(), n_ids, "{name}");
        assert!(m.warnings().is_empty(), "{name}: {:?}", m.warnings());
    }
    let cfg = mapping("shimmy_reference");
    let m = Mapper::new(&reference_db(), &cfg).unwrap();
    assert_eq!(
        m.needed_ids(),
        &[(0x0A0, false), (0x0D0, false), (0x0B0, false)]
    );
    assert!(m.warnings().is_empty(), "{:?}", m.warnings());
}

#[test]
fn mapping_naming_a_missing_message_or_signal_fails_clearly() {
    let db = reference_db();
    let mut cfg = mapping("shimmy_reference");
    cfg.steer_angle.message = "SAS_99".into();
    cfg.messages.remove("SAS_01");
    let e = format!("{:#}", Mapper::new(&db, &cfg).unwrap_err());
    assert!(
        e.contains("steer_angle.message") && e.contains("SAS_99"),
        "{e}"
    );

    let mut cfg = mapping("shimmy_reference");
    cfg.speed.signal = Some("VEH_Sped".into());
    let e = format!("{:#}", Mapper::new(&db, &cfg).unwrap_err());
    assert!(
        e.contains("speed.signal") && e.contains("VEH_Sped") && e.contains("VEH_Speed"),
        "{e}"
    );

    let mut cfg = mapping("shimmy_reference");
    cfg.messages.get_mut("BRK_01").unwrap().counter_signal = Some("BRK_Cnt".into());
    let e = format!("{:#}", Mapper::new(&db, &cfg).unwrap_err());
    assert!(e.contains("messages.BRK_01.counter_signal"), "{e}");

    let mut cfg = mapping("shimmy_reference");
    cfg.messages.get_mut("SAS_01").unwrap().checksum =
        Some(shimmy::signals::checksum::ChecksumKind::VwMqb);
    let e = format!("{:#}", Mapper::new(&db, &cfg).unwrap_err());
    assert!(e.contains("messages.SAS_01.checksum"), "{e}");
}

#[test]
fn unit_contradicting_the_dbc_is_reported() {
    let mut cfg = mapping("shimmy_reference");
    cfg.speed.unit = shimmy::signals::mapping::SpeedUnit::Mps;
    let m = Mapper::new(&reference_db(), &cfg).unwrap();
    assert_eq!(m.warnings().len(), 1, "{:?}", m.warnings());
    assert!(m.warnings()[0].contains("VEH_Speed") && m.warnings()[0].contains("km/h"));
}

struct Rav4 {
    frames: Vec<Frame>,
    /// (t, message, signal) → value, from expected_decoded_bus0.csv.
    expected: BTreeMap<(String, String), Vec<(f64, f64)>>,
}

fn rav4() -> Option<Rav4> {
    let log = require_file("logs/comma2k19-rav4/rav4_2017_seg40_bus0.log")?;
    let csv = require_file("logs/comma2k19-rav4/expected_decoded_bus0.csv")?;
    let frames = log_frames(&log);
    let mut expected: BTreeMap<(String, String), Vec<(f64, f64)>> = BTreeMap::new();
    for line in std::fs::read_to_string(csv).unwrap().lines().skip(1) {
        let f: Vec<&str> = line.split(',').collect();
        expected
            .entry((f[2].to_string(), f[3].to_string()))
            .or_default()
            .push((f[0].parse().unwrap(), f[4].parse().unwrap()));
    }
    Some(Rav4 { frames, expected })
}

fn rav4_mapper() -> Option<Mapper> {
    let p = require_file("dbc/opendbc/toyota_new_mc_pt_generated.dbc")?;
    let (db, _) = Database::load(p).unwrap();
    Some(Mapper::new(&db, &mapping("toyota_rav4")).unwrap())
}

#[test]
fn rav4_mapping_on_the_real_log_matches_the_expected_decode() {
    let (Some(data), Some(mut m)) = (rav4(), rav4_mapper()) else {
        return;
    };
    let (mut steer, mut speed, mut accel, mut pressed) = (vec![], vec![], vec![], vec![]);
    for f in &data.frames {
        let Some(u) = m.on_frame(f) else { continue };
        let Outcome::Accepted(c) = u.outcome else {
            panic!("frame rejected: {u:?} {f:?}");
        };
        let s = m.snapshot(f.t_ns);
        if c.steer_angle {
            steer.push(s.steer_angle_rad.valid().unwrap().to_degrees());
        }
        if c.speed {
            speed.push((f.t_s(), s.speed_mps.valid().unwrap()));
        }
        if c.accel {
            accel.push((f.t_s(), s.accel_mps2.valid().unwrap()));
        }
        if c.brake_pressed {
            pressed.push(s.brake_pressed.valid().unwrap());
        }
    }

    // Composed steering angle = STEER_ANGLE + STEER_FRACTION, frame by frame.
    let coarse = &data.expected[&("STEER_ANGLE_SENSOR".into(), "STEER_ANGLE".into())];
    let fine = &data.expected[&("STEER_ANGLE_SENSOR".into(), "STEER_FRACTION".into())];
    assert_eq!(steer.len(), 4974);
    assert_eq!(coarse.len(), steer.len());
    for (i, got) in steer.iter().enumerate() {
        let want = coarse[i].1 + fine[i].1;
        assert!((got - want).abs() < 1e-9, "steer #{i}: {got} vs {want}");
    }
    let (lo, hi) = steer
        .iter()
        .fold((f64::MAX, f64::MIN), |(a, b), &v| (a.min(v), b.max(v)));
    // STEER_ANGLE alone spans -4.5..+3.0 deg (1.5 deg steps); with the fraction, -4.6..+2.5.
    let (clo, chi) = coarse
        .iter()
        .fold((f64::MAX, f64::MIN), |(a, b), &(_, v)| (a.min(v), b.max(v)));
    assert_eq!((clo, chi), (-4.5, 3.0));
    assert!(
        (lo + 4.6).abs() < 1e-9 && (hi - 2.5).abs() < 1e-9,
        "{lo}..{hi}"
    );

    // Speed in m/s = the mean of the four WHEEL_SPEEDS km/h / 3.6, frame by frame; 28-72 km/h
    // (the speedometer's SPEED reads 29-73 km/h, 2 % above the wheels).
    let wheels: Vec<&Vec<(f64, f64)>> = ["FL", "FR", "RL", "RR"]
        .iter()
        .map(|w| &data.expected[&("WHEEL_SPEEDS".into(), format!("WHEEL_SPEED_{w}"))])
        .collect();
    assert_eq!(speed.len(), 4974);
    for (i, (_, got)) in speed.iter().enumerate() {
        let w = wheels.iter().map(|v| v[i].1).sum::<f64>() / 4.0;
        assert!(
            (got * 3.6 - w).abs() < 1e-9,
            "speed #{i}: {} vs {w}",
            got * 3.6
        );
    }
    let kmh: Vec<f64> = speed.iter().map(|(_, v)| v * 3.6).collect();
    let (vlo, vhi) = kmh
        .iter()
        .fold((f64::MAX, f64::MIN), |(a, b), &v| (a.min(v), b.max(v)));
    assert!(
        vlo >= 28.0 && vhi <= 72.0 && vlo < 29.0 && vhi > 71.0,
        "{vlo}..{vhi}"
    );
    let speedo = &data.expected[&("SPEED".into(), "SPEED".into())];
    let speedo_mean = speedo.iter().map(|x| x.1).sum::<f64>() / speedo.len() as f64;
    let wheel_mean = kmh.iter().sum::<f64>() / kmh.len() as f64;
    assert!(
        (speedo_mean / wheel_mean - 1.0214).abs() < 0.003,
        "{speedo_mean} / {wheel_mean}"
    );

    // No braking in this minute (a negative control).
    assert_eq!(pressed.len(), 2487);
    assert!(pressed.iter().all(|p| !p));

    // Acceleration (inverted ACCEL_X) agrees in sign with the derivative of speed.
    let corr = accel_speed_correlation(&accel, &speed);
    assert!(corr > 0.7, "correlation {corr}");

    // Nothing rejected, no timeouts.
    for s in m.stats() {
        assert_eq!(s.rejected(), 0, "{s:?}");
        assert_eq!(s.timeouts, 0, "{s:?}");
        assert_eq!(s.frames, s.accepted);
    }
    let last = data.frames.last().unwrap().t_ns;
    let snap = m.snapshot(last);
    assert_eq!(snap.steer_angle_rad.validity, Validity::Valid);
    assert_eq!(snap.brake_pressure_pa.validity, Validity::NotMapped);
    let later = m.snapshot(last + 1_000_000_000);
    assert_eq!(later.steer_angle_rad.validity, Validity::TimedOut);
    assert_eq!(later.steer_angle_rad.valid(), None);
}

/// Correlation of 1 s moving averages of acceleration and of d(speed)/dt.
fn accel_speed_correlation(accel: &[(f64, f64)], speed: &[(f64, f64)]) -> f64 {
    let mut pairs = Vec::new();
    let mut t = speed[0].0 + 1.0;
    let end = speed.last().unwrap().0 - 1.0;
    let mean = |xs: &[(f64, f64)], a: f64, b: f64| {
        let v: Vec<f64> = xs
            .iter()
            .filter(|(t, _)| *t >= a && *t < b)
            .map(|x| x.1)
            .collect();
        v.iter().sum::<f64>() / v.len() as f64
    };
    while t < end {
        let dv = (mean(speed, t, t + 0.5) - mean(speed, t - 0.5, t)) / 0.5;
        pairs.push((mean(accel, t - 0.5, t + 0.5), dv));
        t += 0.25;
    }
    let n = pairs.len() as f64;
    let (ma, mb) = (
        pairs.iter().map(|p| p.0).sum::<f64>() / n,
        pairs.iter().map(|p| p.1).sum::<f64>() / n,
    );
    let cov: f64 = pairs.iter().map(|p| (p.0 - ma) * (p.1 - mb)).sum();
    let va: f64 = pairs.iter().map(|p| (p.0 - ma).powi(2)).sum();
    let vb: f64 = pairs.iter().map(|p| (p.1 - mb).powi(2)).sum();
    cov / (va * vb).sqrt()
}

#[test]
fn rav4_corrupted_steering_frames_are_counted_and_not_used() {
    let (Some(data), Some(mut m)) = (rav4(), rav4_mapper()) else {
        return;
    };
    let mut n_steer = 0;
    let mut corrupted = 0;
    let mut steer_updates = 0;
    for f in &data.frames {
        let mut f = *f;
        if f.id == 0x025 {
            n_steer += 1;
            if n_steer % 10 == 0 {
                f.data[1] ^= 0x04; // one bit of STEER_ANGLE
                corrupted += 1;
            }
        }
        if let Some(u) = m.on_frame(&f) {
            match u.outcome {
                Outcome::Accepted(c) => steer_updates += c.steer_angle as usize,
                Outcome::Rejected(r) => assert!(matches!(r, Reject::Checksum(_)), "{r:?}"),
            }
        }
    }
    let s = &m.stats()[0];
    assert_eq!(s.name, "STEER_ANGLE_SENSOR");
    assert_eq!(s.checksum_errors, corrupted);
    assert_eq!(steer_updates as u64, n_steer - corrupted);
    // One lost frame in ten never leaves a gap longer than the 50 ms timeout.
    assert_eq!(s.timeouts, 0);
}

#[test]
fn vw_mapping_accepts_real_mqb_frames_and_rejects_corrupted_ones() {
    let Some(dbc) = require_file("dbc/opendbc/vw_mqb.dbc") else {
        return;
    };
    let Some(sample) = require_file("checksums/opendbc_checksum_sample_frames.json") else {
        return;
    };
    let (db, _) = Database::load(dbc).unwrap();
    let mut m = Mapper::new(&db, &mapping("vw_mqb")).unwrap();
    let v: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(sample).unwrap()).unwrap();
    let mut by_msg: BTreeMap<String, (u32, Vec<Vec<u8>>)> = BTreeMap::new();
    for e in v.as_array().unwrap() {
        let frames = e["frames"].as_array().unwrap();
        by_msg.insert(
            e["message"].as_str().unwrap().to_string(),
            (
                e["address"].as_u64().unwrap() as u32,
                frames.iter().map(|f| hex(f.as_str().unwrap())).collect(),
            ),
        );
    }
    let used = ["LWI_01", "ESP_21", "ESP_05", "ESP_02", "LH_EPS_03"];
    let eps = db.messages()[db.message_by_name("LH_EPS_03").unwrap()].clone();
    let tq = &eps.signals[eps.signal_by_name("EPS_Lenkmoment").unwrap()];
    let tq_vz = &eps.signals[eps.signal_by_name("EPS_VZ_Lenkmoment").unwrap()];
    let lwi = db.messages()[db.message_by_name("LWI_01").unwrap()].clone();
    let mag = &lwi.signals[lwi.signal_by_name("LWI_Lenkradwinkel").unwrap()];
    let vz = &lwi.signals[lwi.signal_by_name("LWI_VZ_Lenkradwinkel").unwrap()];
    let mut t = 0i64;
    let mut negative_seen = false;
    for k in 0..16 {
        for name in used {
            let (id, frames) = &by_msg[name];
            t += 5_000_000;
            let f = Frame::classic(t, *id, false, &frames[k]).unwrap();
            let u = m.on_frame(&f).unwrap();
            assert!(
                matches!(u.outcome, Outcome::Accepted(_)),
                "{name} #{k}: {u:?}"
            );
            if name == "LWI_01" {
                let d = &frames[k];
                let want = mag.phys(d).unwrap()
                    * if vz.phys(d).unwrap() != 0.0 {
                        -1.0
                    } else {
                        1.0
                    };
                negative_seen |= want < 0.0;
                let got = m.snapshot(t).steer_angle_rad.valid().unwrap().to_degrees();
                assert!((got - want).abs() < 1e-9, "LWI_01 #{k}: {got} vs {want}");
            }
            if name == "LH_EPS_03" {
                // centi-N·m magnitude and a sign bit (1 = to the right).
                let d = &frames[k];
                let sign = if tq_vz.phys(d).unwrap() != 0.0 {
                    -1.0
                } else {
                    1.0
                };
                let want = 0.01 * tq.phys(d).unwrap() * sign;
                let got = m.snapshot(t).steer_torque_nm.valid().unwrap();
                assert!((got - want).abs() < 1e-9, "LH_EPS_03 #{k}: {got} vs {want}");
            }
        }
    }
    assert!(negative_seen, "the sample has right-hand (negative) angles");
    for s in m.stats() {
        assert_eq!((s.frames, s.accepted, s.counter_gaps), (16, 16, 0), "{s:?}");
    }
    let snap = m.snapshot(t);
    assert!(snap.brake_pressure_pa.valid().is_some());
    assert!(snap.brake_pressed.valid().is_some());
    assert!(snap.accel_mps2.valid().is_some());
    assert!(snap.speed_mps.valid().is_some());

    // A corrupted frame (one bit of the angle) is rejected by the CRC.
    let (id, frames) = &by_msg["LWI_01"];
    let mut bad = frames[0].clone();
    bad[2] ^= 0x10;
    let u = m.on_frame(&Frame::classic(t + 5_000_000, *id, false, &bad).unwrap());
    assert!(matches!(
        u.unwrap().outcome,
        Outcome::Rejected(Reject::Checksum(_))
    ));
    // The same good frame twice: the second is a repeated counter.
    let good = Frame::classic(t + 10_000_000, *id, false, &frames[0]).unwrap();
    assert!(matches!(
        m.on_frame(&good).unwrap().outcome,
        Outcome::Accepted(_)
    ));
    let again = Frame::classic(t + 15_000_000, *id, false, &frames[0]).unwrap();
    assert!(matches!(
        m.on_frame(&again).unwrap().outcome,
        Outcome::Rejected(Reject::CounterRepeat { counter: 0 })
    ));
    let s = &m.stats()[0];
    assert_eq!((s.checksum_errors, s.counter_errors), (1, 1));
}
