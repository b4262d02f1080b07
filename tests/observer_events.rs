//! Braking-event detection and per-event features on synthetic signal streams with known
//! answers (issue 5 items 1–2).

use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use shimmy::events::{Detector, EventConfig, EventRecord, Sample, Unused};
use shimmy::observer::features::{Extractor, SensorNoise};

const G: f64 = 9.80665;

/// A synthetic drive: cruise at `v0_kmh` for 3 s, brake at `decel_g` (0.3 s ramp) until stop or
/// `brake_s`, then 2 s more. Steering at 100 Hz: `steer_offset_deg` + a 6 Hz sine of
/// `amp_deg` during braking (and an 8 Hz sine of `cruise_amp_deg` before it), quantised to
/// `step_deg` after a sub-step offset; speed at 50 Hz;
/// acceleration at 50 Hz when `with_accel`. `drop` is the fraction of steering frames lost, in
/// runs of `drop_run` consecutive frames (an overloaded gateway). Lone lost frames at random
/// are, from the timestamps alone, a slower sensor with jitter (`analysis::sampling`), which the
/// response table's sensor check refuses; runs are gaps the detector counts.
#[derive(Clone)]
struct Drive {
    v0_kmh: f64,
    decel_g: f64,
    brake_s: f64,
    amp_deg: f64,
    cruise_amp_deg: f64,
    steer_offset_deg: f64,
    /// The wheel turned at this rate (deg/s) from 1 s before the brake to 1.5 s after it (a
    /// curve unwound while braking).
    steer_rate_deg_s: f64,
    step_deg: f64,
    with_accel: bool,
    drop: f64,
    drop_run: usize,
    seed: u64,
}

impl Default for Drive {
    fn default() -> Self {
        Drive {
            v0_kmh: 55.0,
            decel_g: 0.5,
            brake_s: 100.0,
            amp_deg: 0.3,
            cruise_amp_deg: 0.0,
            steer_offset_deg: 1.0,
            steer_rate_deg_s: 0.0,
            step_deg: 0.1,
            with_accel: false,
            drop: 0.0,
            drop_run: 1,
            seed: 1,
        }
    }
}

const T_BRAKE: f64 = 3.0;

fn samples(d: &Drive) -> Vec<Sample> {
    let mut rng = ChaCha8Rng::seed_from_u64(d.seed);
    let offset = rng.random_range(-0.5..0.5) * d.step_deg;
    let dt = 1e-3;
    let mut v = d.v0_kmh / 3.6;
    let mut out = Vec::new();
    let mut t_stop = None;
    let mut dropping = 0usize;
    let n = 30_000;
    for k in 0..n {
        let t = k as f64 * dt;
        let braking_cmd = t >= T_BRAKE && t < T_BRAKE + d.brake_s;
        let a = if braking_cmd && v > 0.0 {
            d.decel_g * G * ((t - T_BRAKE) / 0.3).min(1.0)
        } else {
            0.0
        };
        v = (v - a * dt).max(0.0);
        if v == 0.0 && t_stop.is_none() && t > T_BRAKE {
            t_stop = Some(t);
        }
        if t_stop.is_some_and(|ts| t > ts + 2.0) || t > T_BRAKE + d.brake_s + 2.0 {
            break;
        }
        let t_ns = (t * 1e9).round() as i64;
        let mut s = Sample {
            t_ns,
            brake: Some(braking_cmd),
            ..Default::default()
        };
        let mut any = false;
        if k % 10 == 0 && dropping == 0 && rng.random::<f64>() < d.drop / d.drop_run as f64 {
            dropping = d.drop_run;
        }
        let lost = k % 10 == 0 && dropping > 0;
        if lost {
            dropping -= 1;
        }
        if k % 10 == 0 && !lost {
            let shimmy = if braking_cmd && v > 0.0 {
                d.amp_deg * (2.0 * std::f64::consts::PI * 6.0 * t).sin()
            } else if t < T_BRAKE {
                d.cruise_amp_deg * (2.0 * std::f64::consts::PI * 8.0 * t).sin()
            } else {
                0.0
            };
            let turn = d.steer_rate_deg_s * (t - (T_BRAKE - 1.0)).clamp(0.0, 2.5);
            let deg = d.steer_offset_deg + turn + shimmy + offset;
            let q = (deg / d.step_deg).round() * d.step_deg;
            s.steer_rad = Some(q.to_radians());
            any = true;
        }
        if k % 20 == 5 {
            s.speed_mps = Some(v);
            if d.with_accel {
                s.accel_mps2 = Some(-a);
            }
            any = true;
        }
        if any {
            out.push(s);
        }
    }
    out
}

fn detect(d: &Drive, cfg: EventConfig) -> (Vec<EventRecord>, Detector) {
    let mut det = Detector::new(cfg);
    let mut recs = Vec::new();
    for s in samples(d) {
        if let Some(f) = det.push(&s) {
            recs.push(f.record);
        }
    }
    if let Some(f) = det.flush() {
        recs.push(f.record);
    }
    (recs, det)
}

#[test]
fn a_stop_from_55_at_half_g_is_one_used_event_with_its_numbers() {
    let (ev, _) = detect(&Drive::default(), EventConfig::default());
    assert_eq!(ev.len(), 1, "{ev:#?}");
    let e = &ev[0];
    assert!(e.used, "{e:#?}");
    assert!(
        (e.t_start_s - T_BRAKE).abs() < 0.02,
        "onset {}",
        e.t_start_s
    );
    assert!((e.v0_kmh - 55.0).abs() < 0.5, "v0 {}", e.v0_kmh);
    assert!((e.decel_g - 0.5).abs() < 0.03, "decel {}", e.decel_g);
    assert!(e.stopped);
    // 55 km/h at 0.5 g down to the 0.5 m/s stop threshold: 0.15 s of ramp offset + Δv/a.
    let expect = 0.15 + (55.0 / 3.6 - 0.5) / (0.5 * G);
    assert!(
        (e.duration_s() - expect).abs() < 0.1,
        "duration {}",
        e.duration_s()
    );
    assert!((e.quality.sample_hz - 100.0).abs() < 0.5);
    assert!((e.quality.quant_step_deg - 0.1).abs() < 1e-6);
    assert_eq!(e.quality.missing_samples, 0);
    assert!(!e.quality.decel_from_accel);
}

#[test]
fn decel_from_accel_signal_agrees_with_differentiated_speed() {
    let d = Drive {
        with_accel: true,
        decel_g: 0.7,
        ..Drive::default()
    };
    let (ev, _) = detect(&d, EventConfig::default());
    assert_eq!(ev.len(), 1);
    assert!(ev[0].quality.decel_from_accel);
    assert!((ev[0].decel_g - 0.7).abs() < 0.02, "{}", ev[0].decel_g);
}

#[test]
fn out_of_range_events_are_recorded_but_flagged_unused() {
    let cases = [
        (
            Drive {
                decel_g: 0.2,
                ..Drive::default()
            },
            Unused::DecelOutOfRange,
        ),
        (
            Drive {
                decel_g: 0.95,
                ..Drive::default()
            },
            Unused::DecelOutOfRange,
        ),
        (
            Drive {
                v0_kmh: 130.0,
                ..Drive::default()
            },
            Unused::SpeedOutOfRange,
        ),
        (
            Drive {
                v0_kmh: 15.0,
                ..Drive::default()
            },
            Unused::SpeedOutOfRange,
        ),
        (
            Drive {
                steer_offset_deg: 40.0,
                ..Drive::default()
            },
            Unused::NotStraight,
        ),
        (
            Drive {
                drop: 0.2,
                drop_run: 5,
                ..Drive::default()
            },
            Unused::MissingData,
        ),
    ];
    for (d, why) in cases {
        let (ev, _) = detect(&d, EventConfig::default());
        assert_eq!(ev.len(), 1, "expected one recorded event for {why:?}");
        assert!(!ev[0].used, "{why:?}: {:#?}", ev[0]);
        assert_eq!(ev[0].unused_reason, Some(why), "{:#?}", ev[0]);
    }
}

#[test]
fn a_wheel_turned_around_the_brake_onset_is_not_straight() {
    let turned = |rate: f64| {
        let d = Drive {
            steer_rate_deg_s: rate,
            ..Drive::default()
        };
        let (ev, _) = detect(&d, EventConfig::default());
        assert_eq!(ev.len(), 1);
        ev.into_iter().next().unwrap()
    };
    // Held (the shimmy's 0.6 deg peak to peak) and turned slowly: used.
    let held = turned(0.0);
    assert!(held.used && held.max_steer_change_deg < 1.0, "{held:#?}");
    let slow = turned(1.0);
    assert!(slow.used, "{slow:#?}");
    assert!((1.2..2.0).contains(&slow.max_steer_change_deg), "{slow:#?}");
    // 5 deg/s: about 5 deg within a second, beyond the 3 deg allowed.
    let fast = turned(5.0);
    assert_eq!(fast.unused_reason, Some(Unused::NotStraight), "{fast:#?}");
    assert!((5.0..6.0).contains(&fast.max_steer_change_deg), "{fast:#?}");
    // Configurable.
    let cfg = EventConfig {
        max_steer_change_deg: 8.0,
        ..EventConfig::default()
    };
    let d = Drive {
        steer_rate_deg_s: 5.0,
        ..Drive::default()
    };
    assert!(detect(&d, cfg).0[0].used);
}

#[test]
fn light_touches_and_short_partial_brakes_are_handled() {
    let (ev, det) = detect(
        &Drive {
            decel_g: 0.08,
            brake_s: 2.0,
            ..Drive::default()
        },
        EventConfig::default(),
    );
    assert!(ev.is_empty(), "a 0.08 g touch is not an event: {ev:#?}");
    assert_eq!(det.ignored, 1, "but it is counted");
    // A partial brake (released while moving) ends at the release.
    let (ev, _) = detect(
        &Drive {
            v0_kmh: 90.0,
            decel_g: 0.4,
            brake_s: 2.0,
            ..Drive::default()
        },
        EventConfig::default(),
    );
    assert_eq!(ev.len(), 1);
    assert!(!ev[0].stopped);
    assert!(ev[0].used);
    assert!(
        (ev[0].duration_s() - 2.0).abs() < 0.05,
        "{}",
        ev[0].duration_s()
    );
}

#[test]
fn thresholds_are_configurable() {
    let cfg = EventConfig {
        max_steer_deg: 50.0,
        ..EventConfig::default()
    };
    let (ev, _) = detect(
        &Drive {
            steer_offset_deg: 40.0,
            ..Drive::default()
        },
        cfg,
    );
    assert!(ev[0].used, "{:#?}", ev[0]);
}

#[test]
fn an_event_longer_than_the_ring_is_closed_and_flagged_truncated() {
    let cfg = EventConfig {
        max_samples: 300,
        ..EventConfig::default()
    };
    let (ev, _) = detect(&Drive::default(), cfg);
    assert_eq!(ev.len(), 1);
    assert_eq!(ev[0].unused_reason, Some(Unused::Truncated));
}

fn features(d: &Drive) -> shimmy::observer::features::Features {
    features_with(d, EventConfig::default())
}

fn features_with(d: &Drive, cfg: EventConfig) -> shimmy::observer::features::Features {
    let mut det = Detector::new(cfg);
    let mut got = None;
    for smp in samples(d) {
        if let Some(f) = det.push(&smp) {
            got = Some((f.samples.to_vec(), f.record));
            break;
        }
    }
    let (s, r) = got.unwrap_or_else(|| {
        let f = det.flush().expect("an event");
        (f.samples.to_vec(), f.record)
    });
    let t0 = (r.t_start_s * 1e9) as i64;
    let t1 = ((r.t_end_s + 0.3) * 1e9) as i64;
    Extractor::new()
        .extract(&s, t0, t1, SensorNoise::default(), r.quality.quant_step_deg)
        .unwrap()
}

#[test]
fn band_pass_peak_matches_a_large_sine() {
    let f = features(&Drive {
        amp_deg: 2.0,
        ..Drive::default()
    });
    // Zero-phase 3-25 Hz passes 6 Hz nearly unchanged; the window includes on/off edges.
    assert!((f.peak_deg - 2.0).abs() < 0.15, "peak {}", f.peak_deg);
    let rms_sine = 2.0 / 2f64.sqrt();
    assert!(
        (f.rms_deg - rms_sine).abs() < 0.1 * rms_sine,
        "rms {}",
        f.rms_deg
    );
    assert_eq!(f.fs_hz, 100.0);
}

#[test]
fn noise_corrected_amplitude_reads_closer_than_the_raw_peak_of_a_stepped_signal() {
    // A 0.1 deg sine on a 0.1 deg sensor: the raw band-passed peak reads high.
    let mut raw_err = 0.0;
    let mut cor_err = 0.0;
    for seed in 0..8 {
        let f = features(&Drive {
            amp_deg: 0.1,
            seed,
            ..Drive::default()
        });
        let corrected = f.excess_rms_deg * 2f64.sqrt();
        raw_err += (f.peak_deg - 0.1).abs();
        cor_err += (corrected - 0.1).abs();
        assert!(f.peak_deg > 0.1, "raw peak reads high: {}", f.peak_deg);
    }
    assert!(
        cor_err < 0.5 * raw_err,
        "corrected error {cor_err} vs raw {raw_err}"
    );
    assert!(
        cor_err / 8.0 < 0.03,
        "mean corrected error {}",
        cor_err / 8.0
    );
}

#[test]
fn no_shimmy_gives_only_the_quantisation_floor() {
    let f = features(&Drive {
        amp_deg: 0.0,
        ..Drive::default()
    });
    assert!(f.peak_deg < 0.05, "{f:?}");
    assert!(f.excess_rms_deg < 0.01, "{f:?}");
}

#[test]
fn the_cruise_feature_measures_the_steering_before_the_brake_only() {
    // Busy before the brake, quiet during it (tight joints, large unbalance) ...
    let f = features(&Drive {
        amp_deg: 0.0,
        cruise_amp_deg: 0.5,
        ..Drive::default()
    });
    let want = 0.5 / 2f64.sqrt();
    let cruise = f
        .cruise_rms_deg
        .expect("2 s pre-roll holds a cruise window");
    assert!(
        (cruise - want).abs() < 0.1 * want,
        "cruise rms {cruise}, want {want}"
    );
    assert!(
        f.rms_deg < 0.1 * want,
        "braking window leaks the cruise: {f:?}"
    );
    // ... and the other way round (a brake-induced rattle on worn joints).
    let g = features(&Drive {
        amp_deg: 0.5,
        cruise_amp_deg: 0.0,
        ..Drive::default()
    });
    assert!(g.cruise_rms_deg.unwrap() < 0.1 * want, "{g:?}");
    assert!((g.rms_deg - want).abs() < 0.15 * want, "{g:?}");
    // Too short a pre-roll: no cruise feature rather than a number from the filter's run-in.
    let short = features_with(
        &Drive {
            cruise_amp_deg: 0.5,
            ..Drive::default()
        },
        EventConfig {
            pre_roll_s: 0.5,
            ..EventConfig::default()
        },
    );
    assert_eq!(short.cruise_rms_deg, None, "{short:?}");
}

/// The steering torque travels beside the angle: samples of a 50 Hz torque (a 10 Hz shake of
/// 0.2 N·m while braking) come out of the finished event over the pre-roll and window, and its
/// features, in N·m on the 3–20 Hz band a 50 Hz signal can carry, read the shake.
#[test]
fn the_steering_torque_is_kept_with_the_event_and_measured_in_newton_metres() {
    use shimmy::observer::features::{band_hz, SteerSignal};
    let mut det = Detector::new(EventConfig::default());
    let mut ex = Extractor::new();
    let mut found = None;
    for (k, mut s) in samples(&Drive::default()).into_iter().enumerate() {
        // The angle comes every 10 ms; a torque with every other one (50 Hz).
        if s.steer_rad.is_some() && k % 2 == 0 {
            let t = s.t_ns as f64 * 1e-9;
            let braking = s.brake == Some(true);
            s.torque_nm = Some(
                if braking { 0.2 } else { 0.0 } * (2.0 * std::f64::consts::PI * 10.0 * t).sin(),
            );
        }
        if let Some(f) = det.push(&s) {
            let rec = f.record.clone();
            let torque = f.torque.to_vec();
            let t0 = (rec.t_start_s * 1e9) as i64;
            let t1 = ((rec.t_end_s + 0.3) * 1e9) as i64;
            let feats = ex
                .extract_signal(
                    SteerSignal::TorqueNm,
                    &torque,
                    t0,
                    t1,
                    SensorNoise {
                        quant_step_deg: 0.01,
                        noise_deg: 0.0,
                    },
                    0.01,
                )
                .unwrap();
            found = Some((rec, torque, feats));
        }
    }
    let (rec, torque, feats) = found.expect("one event");
    assert!(rec.used, "{rec:#?}");
    // Pre-roll before the onset, samples to the end of the tail.
    assert!(torque.first().unwrap().0 < (rec.t_start_s * 1e9) as i64 - 1_000_000_000);
    assert!(torque.last().unwrap().0 >= (rec.t_end_s * 1e9) as i64);
    assert!((feats.fs_hz - 50.0).abs() < 1.0, "{feats:?}");
    let (lo, hi) = band_hz(feats.fs_hz);
    assert!(lo == 3.0 && (hi - 20.0).abs() < 0.5, "{:?}", (lo, hi));
    // A 0.2 N·m sine: RMS 0.14 N·m, peak 0.2 N·m (not degrees of a radian signal).
    assert!(
        (feats.rms_deg - 0.2 / 2f64.sqrt()).abs() < 0.03,
        "{feats:?}"
    );
    assert!((feats.peak_deg - 0.2).abs() < 0.04, "{feats:?}");
    // The cruise before the brake carried no torque.
    assert!(feats.cruise_rms_deg.unwrap() < 0.01, "{feats:?}");
}
