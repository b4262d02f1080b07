//! What precedes a braking event: a coast instead of a steady cruise, a change of road
//! roughness at brake onset (MODEL.md §7's noise level scaled from the onset to the release),
//! and a curve the driver comes out of while braking (the steering-wheel angle turned in
//! before onset and unwound after it). Each changes only what it names.

use firmware_sim::bus::REFERENCE_DBC;
use firmware_sim::plant::ModelPlant;
use firmware_sim::truth::GroundTruth;
use firmware_sim::{FirmwareSim, RunInfo, Scenario};

/// One event from 60 km/h: a cruise, optionally a coast, then a 0.5 g stop with `brake_extra`
/// lines in its segment.
fn drive(coast: Option<(f64, f64)>, brake_extra: &str) -> String {
    let mut s = "seed = 5\n[clearance]\nleft_mm = 0.2\n[drive]\nstart_speed_kmh = 60\n\
                 [[drive.segment]]\nkind = \"cruise\"\nspeed_kmh = 60\nduration_s = 1.5\n"
        .to_string();
    if let Some((d, g)) = coast {
        s += &format!("[[drive.segment]]\nkind = \"coast\"\nduration_s = {d}\ndecel_g = {g}\n");
    }
    s + "[[drive.segment]]\nkind = \"brake\"\ndecel_g = 0.5\nhold_s = 0.5\n" + brake_extra
}

fn run(text: &str) -> (GroundTruth, Vec<f64>) {
    let sc = Scenario::parse(text, "test").unwrap();
    let plant = ModelPlant::new(&sc, None).unwrap();
    let mut sim = FirmwareSim::new(&sc, plant, REFERENCE_DBC, RunInfo::default()).unwrap();
    sim.run_to_end();
    (sim.ground_truth(), sim.sw_trace().to_vec())
}

fn rms(x: &[f64]) -> f64 {
    let m = x.iter().sum::<f64>() / x.len() as f64;
    (x.iter().map(|v| (v - m) * (v - m)).sum::<f64>() / x.len() as f64).sqrt()
}

#[test]
fn a_coast_slows_the_car_before_the_event_without_the_pedal() {
    let (steady, _) = run(&drive(None, ""));
    let (coast, _) = run(&drive(Some((2.0, 0.1)), ""));
    let (a, b) = (&steady.events[0].event, &coast.events[0].event);
    assert!((a.v0_kmh - 60.0).abs() < 0.5, "{a:?}");
    // 2 s at 0.1 g (eased in under the jerk limit): about 6–7 km/h less at onset.
    let lost = a.v0_kmh - b.v0_kmh;
    assert!((5.0..7.2).contains(&lost), "lost {lost} km/h");
    assert!((b.t_start_s - a.t_start_s - 2.0).abs() < 0.01);
    assert_eq!(coast.events.len(), 1);
}

#[test]
fn a_rougher_road_from_brake_onset_shakes_only_the_braking() {
    let (a, ta) = run(&drive(None, ""));
    let (b, tb) = run(&drive(None, "road_noise_scale = 4.0\n"));
    let onset_ms = (a.events[0].event.t_start_s * 1000.0) as usize;
    assert_eq!(onset_ms, (b.events[0].event.t_start_s * 1000.0) as usize);
    // The same road up to the onset, to the millisecond trace.
    assert_eq!(ta[..onset_ms - 1], tb[..onset_ms - 1]);
    // Four times the road noise while braking: a larger steering response in the first
    // second of the event (the 0.2 mm joints rattle more, the road shakes more).
    let w = onset_ms + 100..onset_ms + 1100;
    assert!(
        rms(&tb[w.clone()]) > 1.5 * rms(&ta[w.clone()]),
        "{} vs {}",
        rms(&tb[w.clone()]),
        rms(&ta[w])
    );
    // Smoother is allowed too; nonsense is refused by name.
    run(&drive(None, "road_noise_scale = 0.5\n"));
    let e = Scenario::parse(&drive(None, "road_noise_scale = 0\n"), "t").unwrap_err();
    assert!(format!("{e:#}").contains("road_noise_scale"), "{e:#}");
}

/// config/vehicle/default.toml with its MODEL.md §15 column (and so a torsion bar) enabled.
fn column_vehicle() -> std::path::PathBuf {
    let root = std::path::PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("..");
    let text = std::fs::read_to_string(root.join("config/vehicle/default.toml")).unwrap();
    let (head, tail) = text.split_once("[column]").unwrap();
    let dir = std::path::PathBuf::from(env!("CARGO_TARGET_TMPDIR"));
    let path = dir.join("pre_brake_column.toml");
    let tail = tail.replacen("enabled = false", "enabled = true", 1);
    std::fs::write(&path, format!("{head}[column]{tail}")).unwrap();
    path
}

/// (t − onset, steering-wheel angle deg, torsion-bar torque N·m) of every frame the bus sent.
fn sensed(text: &str, vehicle: Option<&std::path::Path>) -> Vec<(f64, f64, f64)> {
    let sc = Scenario::parse(text, "test").unwrap();
    let plant = ModelPlant::new(&sc, vehicle).unwrap();
    let mut sim = FirmwareSim::new(&sc, plant, REFERENCE_DBC, RunInfo::default()).unwrap();
    sim.bus_mut().record_values();
    sim.run_to_end();
    let onset = sim.ground_truth().events[0].event.t_start_s;
    sim.bus()
        .recorded()
        .iter()
        .map(|r| {
            let s = &r.sample;
            (s.t_s - onset, s.steer_rad.to_degrees(), s.steer_torque_nm)
        })
        .collect()
}

/// The mean of the angle and torque over the frames whose time since onset is in `w`.
fn mean_in(x: &[(f64, f64, f64)], w: std::ops::Range<f64>) -> (f64, f64) {
    let v: Vec<_> = x.iter().filter(|r| w.contains(&r.0)).collect();
    let n = v.len() as f64;
    (
        v.iter().map(|r| r.1).sum::<f64>() / n,
        v.iter().map(|r| r.2).sum::<f64>() / n,
    )
}

#[test]
fn a_curve_reaches_the_sensors_and_unwinds_after_onset() {
    let col = column_vehicle();
    let straight = sensed(&drive(None, ""), Some(&col));
    let curve = sensed(
        &drive(None, "turn_deg = 8.0\nturn_unwind_s = 1.0\n"),
        Some(&col),
    );
    let d = |w: std::ops::Range<f64>| {
        let (a, b) = (mean_in(&curve, w.clone()), mean_in(&straight, w));
        (a.0 - b.0, a.1 - b.1)
    };
    // Straight ahead 1.5 s before onset (the cruise's start), about half turned in at 0.75 s.
    let (a0, _) = d(-1.5..-1.4);
    assert!(a0.abs() < 0.6, "{a0}");
    let (a_half, _) = d(-0.8..-0.7);
    assert!((3.0..5.0).contains(&a_half), "{a_half}");
    // At onset: the whole curve on the angle, and the driver's holding torque (0.08 N·m/deg).
    let (a_on, t_on) = d(-0.05..0.05);
    assert!((7.0..8.6).contains(&a_on), "{a_on}");
    assert!((0.5..0.8).contains(&t_on), "{t_on}");
    // Unwound after 1 s.
    let (a_end, t_end) = d(1.2..1.5);
    assert!(a_end.abs() < 0.3 && t_end.abs() < 0.05, "{a_end} {t_end}");
    // A plant without a torsion bar sends no torque for the curve either.
    let flat = sensed(&drive(None, "turn_deg = 8.0\n"), None);
    assert!(flat.iter().all(|r| r.2 == 0.0));
}
