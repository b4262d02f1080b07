//! Every vehicle profile's bus, end to end: firmware-sim drives the shimmy model (the profile's
//! chassis) through a short drive with three stops and emulates the profile's `bus.toml` with its
//! DBC; the log must then
//!
//! * decode with the profile's DBC and mapping with no frame rejected (checksums and counters
//!   verify), the mapping verifying every checksum the bus carries on the messages it reads;
//! * hold every message's rate within 2 % of bus.toml, and every DLC equal to the DBC's;
//! * decode to the plant's values with the right signs: steering angle, speed, brake and
//!   longitudinal acceleration of each accepted frame against the plant state the ECU sampled
//!   for it, and the truth sidecar's braking events against the bus;
//! * give `shimmy estimate`'s chain (the profile's mapping, no table) the drive's braking events,
//!   seen by a steering angle sensor of the profile's rate and step.
//!
//! For the RAV4, the simulated bus is also held against the real drive
//! (`rav4_2017_seg40_bus0.log`): the same IDs and lengths, periods within 2 %, the Toyota checksum
//! on the same IDs, and ACCEL_X with the real car's sign (negative correlation with the
//! derivative of SPEED).
//!
//! The opendbc DBCs and the real log come from the shared data (`shimmy::shared_data`): without
//! it the non-reference profiles print SKIPPED, except under `CI=true`.

use std::collections::{BTreeMap, BTreeSet, HashMap};
use std::path::{Path, PathBuf};

use firmware_sim::bus::{profile_bus, Sample};
use firmware_sim::plant::ModelPlant;
use firmware_sim::truth::GroundTruth;
use firmware_sim::{FirmwareSim, RunInfo, Scenario};
use shimmy::dbc::{Database, Signal};
use shimmy::observer::ObserverConfig;
use shimmy::profile::bus::{BusSpec, Quantity};
use shimmy::profile::Profile;

/// The profiles shipped in config/vehicles.
const SHIPPED: [&str; 6] = [
    "shimmy_reference",
    "shimmy_reference_eps",
    "toyota_rav4",
    "vw_mqb",
    "honda_civic",
    "hyundai_kia",
];
use shimmy::signals::checksum::ChecksumKind;
use shimmy::signals::{Mapper, Outcome, Update};
use shimmy::source::log::LogReader;
use shimmy::source::CanSource;
use shimmy::wire::Frame;

/// A ~30 s drive: three stops from 40–60 km/h at 0.4–0.6 g, the driver holding the wheel 6° to
/// the left (so a sign error in the steering angle shows as a 12° miss).
const DRIVE: &str = r#"
seed = 31
[clearance]
left_mm = 0.2
[driver]
steer_offset_deg = 6.0
steer_rms_deg = 0.5
[drive]
start_speed_kmh = 60
accel_g = 0.3
[[drive.segment]]
kind = "cruise"
speed_kmh = 60
duration_s = 2.0
[[drive.segment]]
kind = "brake"
decel_g = 0.5
hold_s = 0.5
[[drive.segment]]
kind = "stand"
duration_s = 0.5
[[drive.segment]]
kind = "cruise"
speed_kmh = 50
duration_s = 2.0
[[drive.segment]]
kind = "brake"
decel_g = 0.6
hold_s = 0.5
[[drive.segment]]
kind = "stand"
duration_s = 0.5
[[drive.segment]]
kind = "cruise"
speed_kmh = 42
duration_s = 2.0
[[drive.segment]]
kind = "brake"
decel_g = 0.4
hold_s = 0.5
[[drive.segment]]
kind = "stand"
duration_s = 1.0
"#;

fn repo(rel: &str) -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR"))
        .join("..")
        .join(rel)
}

/// The profile, or `None` (after a SKIPPED notice) when its DBC is in the absent shared data.
fn profile(name: &str) -> Option<Profile> {
    if !name.starts_with("shimmy_reference")
        && shimmy::shared_data::require(&format!("the {name} bus (opendbc DBC)")).is_none()
    {
        return None;
    }
    Some(
        Profile::load_dir(&repo(&format!("config/vehicles/{name}")))
            .unwrap_or_else(|e| panic!("{name}: {e:#}")),
    )
}

/// One simulated drive on a profile's bus.
struct Drive {
    profile: Profile,
    db: Database,
    bus: BusSpec,
    frames: Vec<Frame>,
    /// (frame ID, send time) → the plant state the ECU sampled for that frame.
    samples: HashMap<(u32, i64), Sample>,
    /// (ID, extended, length, period ms) of every emulated message.
    layout: Vec<(u32, bool, usize, f64)>,
    truth: GroundTruth,
    log: tempfile::TempPath,
    start_unix_s: f64,
}

fn drive(p: Profile) -> Drive {
    let (db, bus) = profile_bus(&p, None).unwrap_or_else(|e| panic!("{}: {e:#}", p.name));
    let sc = Scenario::parse(DRIVE, "profile_buses").unwrap();
    let plant = ModelPlant::with_params(&sc, p.vehicle.clone()).unwrap();
    let info = RunInfo {
        profile: Some(p.name.clone()),
        ..RunInfo::default()
    };
    let mut sim = FirmwareSim::with_bus(&sc, plant, db.clone(), &bus, info).unwrap();
    sim.bus_mut().record_values();
    let frames: Vec<Frame> = sim.by_ref().collect();
    assert!(sim.error().is_none(), "{:?}", sim.error());
    let truth = sim.ground_truth();
    let layout: Vec<_> = (0..sim.bus().len())
        .map(|i| sim.bus().message_frame(i))
        .collect();
    let samples = sim
        .bus()
        .recorded()
        .iter()
        .map(|r| ((layout[r.message].0, r.t_ns), r.sample))
        .collect();
    // A file of its own per drive, removed with it: two tests drive the same profile in
    // parallel (threads or, under a runner like nextest, processes), and one writing its log
    // while the other reads its own would read a torn file.
    let log = tempfile::Builder::new()
        .prefix(&format!("profile_bus_{}_", p.name))
        .suffix(".log")
        .tempfile_in(env!("CARGO_TARGET_TMPDIR"))
        .unwrap()
        .into_temp_path();
    let mut out = Vec::new();
    for f in &frames {
        shimmy::wire::candump::write_frame(&mut out, f).unwrap();
    }
    std::fs::write(&log, out).unwrap();
    Drive {
        start_unix_s: sc.start_unix_s,
        profile: p,
        db,
        bus,
        frames,
        samples,
        layout,
        truth,
        log,
    }
}

fn signal<'a>(db: &'a Database, msg: &str, sig: &str) -> &'a Signal {
    let m = &db.messages()[db.message_by_name(msg).unwrap()];
    &m.signals[m.signal_by_name(sig).unwrap()]
}

/// Everything the module docs list but the RAV4's real-log comparison.
fn end_to_end(name: &str) -> Option<Drive> {
    let d = drive(profile(name)?);
    let p = &d.profile;
    let map = &p.mapping;
    assert!(d.frames.len() > 5_000, "{name}: {} frames", d.frames.len());
    assert_eq!(d.truth.events.len(), 3, "{name}: {:?}", d.truth.events);

    // The mapping verifies every checksum the bus puts on the messages it reads.
    for m in map.used_messages() {
        let on_bus = d
            .bus
            .messages
            .iter()
            .find(|b| b.name == m)
            .unwrap_or_else(|| panic!("{name}: the mapping reads {m}, which the bus lacks"));
        assert_eq!(
            map.rules(m).checksum,
            on_bus.checksum,
            "{name}: {m}: mapping and bus disagree on the checksum"
        );
    }

    // Decode: nothing rejected, no counter gaps.
    let mut mapper = Mapper::new(&d.db, map).unwrap();
    let (mut accepted, mut rejected) = (0u64, Vec::new());
    let accel_sig = map
        .accel
        .as_ref()
        .map(|a| (signal(&d.db, &a.message, &a.signal).phys_range(), a.invert));
    let step = p.sensor.step_deg;
    let sas_offset = d.truth.sensors.sas_offset_deg;
    let (mut n_steer, mut n_speed, mut n_accel, mut n_brake) = (0, 0, 0, 0);
    let mut n_torque = 0;
    let mut steer_sum = 0.0;
    for f in &d.frames {
        let Some(u) = mapper.on_frame(f) else {
            continue;
        };
        let ch = match u.outcome {
            Outcome::Accepted(ch) => ch,
            Outcome::Rejected(r) => {
                rejected.push(format!("0x{:X} at {}: {r}", f.id, f.t_ns));
                continue;
            }
        };
        accepted += 1;
        let s = d.samples[&(f.id, f.t_ns)];
        let snap = mapper.snapshot(f.t_ns);
        if ch.steer_angle {
            // Quantisation, the sub-LSB offset and 0.01° noise (5 σ).
            let got = snap.steer_angle_rad.value.unwrap().to_degrees();
            let want = s.steer_rad.to_degrees();
            let tol = step / 2.0 + sas_offset.abs() + 0.05 + 1e-6;
            assert!(
                (got - want).abs() <= tol,
                "{name}: steering {got:.3}° decoded, plant {want:.3}° (tol {tol:.3}) at {}",
                f.t_ns
            );
            steer_sum += got;
            n_steer += 1;
        }
        if ch.speed {
            // Radius errors (±0.3 %), braking slip (up to ~3 %), a bus's own speed scale (the
            // RAV4's SPEED reads 2.1 % high), noise and quantisation.
            let got = snap.speed_mps.value.unwrap();
            let tol = 0.045 * s.speed_mps + 0.15;
            assert!(
                (got - s.speed_mps).abs() <= tol,
                "{name}: speed {got:.3} m/s decoded, plant {:.3} at {}",
                s.speed_mps,
                f.t_ns
            );
            n_speed += 1;
        }
        if ch.accel {
            let got = snap.accel_mps2.value.unwrap();
            // What the wire can carry (Honda's LONG_ACCEL holds ±5.1 m/s²), in the monitor's sign.
            let ((lo, hi), invert) = accel_sig.unwrap();
            let (lo, hi) = if invert { (-hi, -lo) } else { (lo, hi) };
            let want = s.accel_mps2.clamp(lo, hi);
            assert!(
                (got - want).abs() <= 0.3,
                "{name}: acceleration {got:.3} m/s² decoded, plant {:.3} at {}",
                s.accel_mps2,
                f.t_ns
            );
            n_accel += 1;
        }
        if ch.brake_pressed {
            assert_eq!(
                snap.brake_pressed.value,
                Some(s.brake_pressed),
                "{name}: brake pedal at {}",
                f.t_ns
            );
            n_brake += 1;
        }
        if ch.steer_torque {
            // The mapping's torque is what the bus put on the wire: the plant's torsion-bar
            // torque, 0.02 N·m noise (5 σ) and the signal's step.
            let got = snap.steer_torque_nm.value.unwrap();
            assert!(
                (got - s.steer_torque_nm).abs() <= 0.11,
                "{name}: steering torque {got:.3} N·m decoded, plant {:.3} at {}",
                s.steer_torque_nm,
                f.t_ns
            );
            n_torque += 1;
        }
        if ch.brake_pressure {
            let got_bar = snap.brake_pressure_pa.value.unwrap() * 1e-5;
            let want = s.pedal_decel_mps2 / firmware_sim::drive::G * 90.0;
            assert!(
                (got_bar - want.max(0.0)).abs() <= 1.5,
                "{name}: brake pressure {got_bar:.2} bar decoded, {want:.2} at {}",
                f.t_ns
            );
        }
    }
    assert!(
        rejected.is_empty(),
        "{name}: {} rejected: {:?}",
        rejected.len(),
        &rejected[..rejected.len().min(5)]
    );
    for st in mapper.stats() {
        assert!(st.frames > 0, "{name}: no {} frames", st.name);
        assert_eq!(
            (st.rejected(), st.counter_gaps, st.timeouts),
            (0, 0, 0),
            "{name}: {st:?}"
        );
    }
    assert!(accepted > 1_000 && n_steer > 500 && n_speed > 200 && n_brake > 200);
    if map.accel.is_some() {
        assert!(n_accel > 200, "{name}: {n_accel} acceleration frames");
    }
    if map.steer_torque.is_some() {
        assert!(n_torque > 200, "{name}: {n_torque} steering torque frames");
    }
    // The driver holds 6° to the left: + left on the monitor's side.
    assert!(
        steer_sum / n_steer as f64 > 4.0,
        "{name}: mean steering angle"
    );

    // Rates within 2 % of bus.toml, DLCs the DBC's.
    let mut by_id: BTreeMap<(u32, bool), Vec<&Frame>> = BTreeMap::new();
    for f in &d.frames {
        by_id.entry((f.id, f.extended)).or_default().push(f);
    }
    assert_eq!(by_id.len(), d.layout.len(), "{name}: IDs on the bus");
    let span_s = (d.frames.last().unwrap().t_ns - d.frames[0].t_ns) as f64 * 1e-9;
    for &(id, ext, len, period_ms) in &d.layout {
        let fs = &by_id[&(id, ext)];
        if let Some(m) = d.db.message(id, ext) {
            assert_eq!(len, m.size_bytes, "{name}: 0x{id:X} length");
        }
        assert!(
            fs.iter().all(|f| usize::from(f.len) == len),
            "{name}: 0x{id:X} DLC"
        );
        if period_ms * 2.0 > span_s * 1e3 {
            continue; // fewer than two periods in the drive (not on any shipped bus)
        }
        let dt_ms = (fs[fs.len() - 1].t_ns - fs[0].t_ns) as f64 * 1e-6 / (fs.len() - 1) as f64;
        assert!(
            (dt_ms / period_ms - 1.0).abs() <= 0.02,
            "{name}: 0x{id:X} every {dt_ms:.3} ms, bus.toml {period_ms} ms"
        );
    }
    // Nothing is clamped to what a signal's bits hold, except an acceleration signal too
    // narrow for the drive's braking (Honda's KINEMATICS.LONG_ACCEL: ±5.1 m/s², which the
    // Honda mapping therefore does not read).
    let max_accel = d
        .samples
        .values()
        .map(|s| s.accel_mps2.abs())
        .fold(0.0, f64::max);
    let narrow_accel: Vec<&str> = d
        .bus
        .messages
        .iter()
        .filter(|m| {
            m.fields.iter().any(|f| {
                if f.quantity != Quantity::LongAccelMps2 {
                    return false;
                }
                let (lo, hi) = signal(&d.db, &m.name, &f.signal).phys_range();
                let reach = max_accel * f.scale.abs();
                lo > -reach || hi < reach
            })
        })
        .map(|m| m.name.as_str())
        .collect();
    for st in &d.truth.messages {
        if !narrow_accel.contains(&st.name.as_str()) {
            assert_eq!(st.encode_clamped, 0, "{name}: {st:?}");
        }
    }
    if name == "honda_civic" {
        assert_eq!(narrow_accel, ["KINEMATICS"], "{name}");
        assert!(map.accel.is_none(), "{name}: maps a clipping acceleration");
    }

    // The truth's braking events are on the bus: the pedal closes within a brake-message period
    // of the onset, at the truth's speed.
    let brake = map.brake_pressed.as_ref().unwrap();
    let brk_id = d.db.messages()[d.db.message_by_name(&brake.message).unwrap()].id;
    let brk_sig = signal(&d.db, &brake.message, &brake.signal);
    let brk_period = d
        .bus
        .messages
        .iter()
        .find(|m| m.name == brake.message)
        .unwrap()
        .period_ms;
    for e in &d.truth.events {
        let t0 = (d.start_unix_s + e.event.t_start_s) * 1e9;
        let first = d
            .frames
            .iter()
            .filter(|f| f.id == brk_id && f.t_ns as f64 >= t0 - 1e6)
            .find(|f| brk_sig.phys(f.payload()) == Some(1.0))
            .unwrap();
        assert!(
            (first.t_ns as f64 - t0) * 1e-6 <= brk_period * 1.3 + 1.0,
            "{name}: pedal {} ms after onset",
            (first.t_ns as f64 - t0) * 1e-6
        );
    }

    // `shimmy estimate`'s chain finds the three events, seen by the profile's sensor.
    let (report, _) = shimmy::cli::estimate::estimate_files(
        &p.mapping_path,
        Some(&p.dbc_path),
        None,
        ObserverConfig::default(),
        &[d.log.to_path_buf()],
    )
    .unwrap_or_else(|e| panic!("{name}: {e:#}"));
    assert_eq!(
        report.events.len(),
        d.truth.events.len(),
        "{name}: {:?}",
        report.events
    );
    for (got, want) in report.events.iter().zip(&d.truth.events) {
        assert!(
            (got.t_start - (d.start_unix_s + want.event.t_start_s)).abs() < 0.3,
            "{name}: event at {} vs truth {}",
            got.t_start - d.start_unix_s,
            want.event.t_start_s
        );
        assert!(
            (got.v0_kmh - want.event.v0_kmh).abs() < 0.05 * want.event.v0_kmh + 1.0,
            "{name}: v0 {} vs {}",
            got.v0_kmh,
            want.event.v0_kmh
        );
        assert!(
            (got.sample_hz / p.sensor.rate_hz - 1.0).abs() < 0.02,
            "{name}: events sampled at {} Hz, the profile's sensor is {} Hz",
            got.sample_hz,
            p.sensor.rate_hz
        );
        assert!(
            (got.quant_step_deg - p.sensor.step_deg).abs() < 1e-6,
            "{name}: events quantised at {} deg, the profile's sensor at {}",
            got.quant_step_deg,
            p.sensor.step_deg
        );
    }
    Some(d)
}

#[test]
fn reference_bus_end_to_end() {
    end_to_end("shimmy_reference");
}

#[test]
fn reference_eps_bus_end_to_end() {
    end_to_end("shimmy_reference_eps");
}

#[test]
fn vw_mqb_bus_end_to_end() {
    end_to_end("vw_mqb");
}

#[test]
fn honda_civic_bus_end_to_end() {
    end_to_end("honda_civic");
}

#[test]
fn hyundai_kia_bus_end_to_end() {
    end_to_end("hyundai_kia");
}

/// Frames of a candump log.
fn read_log(path: &Path) -> Vec<Frame> {
    let mut r = LogReader::open(path).unwrap();
    let mut v = Vec::new();
    while let Some(f) = r.next_frame().unwrap() {
        v.push(f);
    }
    assert_eq!(r.stats().malformed, 0);
    v
}

/// Per ID: (length, mean period in ms, the Toyota checksum holds on every frame).
fn fingerprint(frames: &[Frame]) -> BTreeMap<u32, (u8, f64, bool)> {
    let mut by: BTreeMap<u32, Vec<&Frame>> = BTreeMap::new();
    for f in frames {
        by.entry(f.id).or_default().push(f);
    }
    by.into_iter()
        .map(|(id, fs)| {
            let lens: BTreeSet<u8> = fs.iter().map(|f| f.len).collect();
            assert_eq!(lens.len(), 1, "0x{id:X} has lengths {lens:?}");
            let period_ms = if fs.len() > 1 {
                (fs[fs.len() - 1].t_ns - fs[0].t_ns) as f64 * 1e-6 / (fs.len() - 1) as f64
            } else {
                f64::NAN
            };
            let ck = fs
                .iter()
                .all(|f| f.len > 0 && ChecksumKind::Toyota.verify(f.id, f.payload()).is_ok());
            (id, (fs[0].len, period_ms, ck))
        })
        .collect()
}

/// Correlation of KINEMATICS.ACCEL_X with the derivative of SPEED.SPEED (over ±10 SPEED frames,
/// about ±0.24 s), ACCEL_X taken at each derivative's time.
fn accel_x_vs_dspeed(db: &Database, frames: &[Frame]) -> f64 {
    let ax = signal(db, "KINEMATICS", "ACCEL_X");
    let sp = signal(db, "SPEED", "SPEED");
    let a: Vec<(f64, f64)> = frames
        .iter()
        .filter(|f| f.id == 0x024)
        .map(|f| (f.t_s(), ax.phys(f.payload()).unwrap()))
        .collect();
    let v: Vec<(f64, f64)> = frames
        .iter()
        .filter(|f| f.id == 0x0B4)
        .map(|f| (f.t_s(), sp.phys(f.payload()).unwrap() / 3.6))
        .collect();
    let w = 10;
    let mut pairs = Vec::new();
    let mut k = 0;
    for i in w..v.len() - w {
        let dv = (v[i + w].1 - v[i - w].1) / (v[i + w].0 - v[i - w].0);
        let t = v[i].0;
        while k + 1 < a.len() && a[k + 1].0 <= t {
            k += 1;
        }
        pairs.push((a[k].1, dv));
    }
    let n = pairs.len() as f64;
    let (mx, my) = (
        pairs.iter().map(|p| p.0).sum::<f64>() / n,
        pairs.iter().map(|p| p.1).sum::<f64>() / n,
    );
    let (mut sxy, mut sxx, mut syy) = (0.0, 0.0, 0.0);
    for (x, y) in &pairs {
        sxy += (x - mx) * (y - my);
        sxx += (x - mx) * (x - mx);
        syy += (y - my) * (y - my);
    }
    sxy / (sxx * syy).sqrt()
}

#[test]
fn toyota_rav4_bus_end_to_end_and_like_the_real_log() {
    let Some(d) = end_to_end("toyota_rav4") else {
        return;
    };
    let Some((real_log, _)) = shimmy::shared_data::require_rav4() else {
        return;
    };
    let real = read_log(&real_log);
    let (fr, fs) = (fingerprint(&real), fingerprint(&d.frames));
    let ids = |m: &BTreeMap<u32, (u8, f64, bool)>| m.keys().copied().collect::<Vec<_>>();
    assert_eq!(
        ids(&fs),
        ids(&fr),
        "the simulated bus's IDs are the real car's"
    );
    assert_eq!(fr.len(), 90);
    for (id, &(len_r, per_r, ck_r)) in &fr {
        let (len_s, per_s, ck_s) = fs[id];
        assert_eq!(len_s, len_r, "0x{id:X} length");
        // Periods: within 2 % (the real log's 10 s messages show 6 frames in the minute, the
        // simulated drive 2 or 3; both are means over whole intervals).
        assert!(
            (per_s / per_r - 1.0).abs() <= 0.02,
            "0x{id:X}: simulated every {per_s:.2} ms, real every {per_r:.2} ms"
        );
        assert_eq!(ck_s, ck_r, "0x{id:X}: Toyota checksum on every frame");
    }
    // ACCEL_X reads + when decelerating on the real car, and on the simulated one.
    let db = &d.db;
    let (c_real, c_sim) = (
        accel_x_vs_dspeed(db, &real),
        accel_x_vs_dspeed(db, &d.frames),
    );
    eprintln!("ACCEL_X vs d(SPEED)/dt: real {c_real:.3}, simulated {c_sim:.3}");
    assert!(
        c_real < -0.5 && c_sim < -0.5,
        "real {c_real}, simulated {c_sim}"
    );
}

/// Every shipped profile names a bus whose steering angle sensor is the profile's, and the bus
/// loads against its DBC (the static half of the checks above, for all five at once).
#[test]
fn every_shipped_profile_has_a_bus_matching_its_sensor() {
    for name in SHIPPED {
        let Some(p) = profile(name) else {
            continue;
        };
        assert!(p.bus_path.is_some(), "{name}: no bus = in profile.toml");
        let (db, bus) = profile_bus(&p, None).unwrap_or_else(|e| panic!("{name}: {e:#}"));
        let s = bus.steer_sensor(&db).unwrap().unwrap();
        assert!(
            (s.rate_hz / p.sensor.rate_hz - 1.0).abs() < 0.01,
            "{name}: {s:?}"
        );
        assert_eq!(s.step_deg, p.sensor.step_deg, "{name}");
        // The torque sensor the profile names is on the bus at its rate.
        if let Some(t) = &p.file.sensors.steer_torque {
            let m = bus.messages.iter().find(|m| m.name == t.message).unwrap();
            assert!(
                (1000.0 / m.period_ms / t.rate_hz - 1.0).abs() < 0.01,
                "{name}: {t:?}"
            );
            assert!(
                m.fields.iter().any(|f| f.signal == t.signal),
                "{name}: {t:?}"
            );
        }
    }
}

/// A profile whose bus disagrees with its sensor section is refused, naming both.
#[test]
fn a_bus_that_contradicts_the_profiles_sensor_is_refused() {
    let mut p = profile("shimmy_reference").unwrap();
    p.sensor.rate_hz = 82.9;
    let e = format!("{:#}", profile_bus(&p, None).unwrap_err());
    assert!(e.contains("SAS_01") && e.contains("82.9"), "{e}");
}

#[path = "../../tests/support/counting_alloc.rs"]
mod counting_alloc;

/// The per-step path (`Bus::poll`) allocates nothing on any profile's bus, split fields, split
/// counters, nibble checksums and faults included.
#[test]
fn polling_a_profile_bus_allocates_nothing() {
    use firmware_sim::bus::{Bus, MAX_BATCH};
    use firmware_sim::scenario::{Faults, Sensors};
    for name in SHIPPED {
        let Some(p) = profile(name) else {
            continue;
        };
        let (db, spec) = profile_bus(&p, None).unwrap();
        let faults = Faults {
            drop_probability: 0.01,
            bad_checksum_probability: 0.02,
            ..Faults::default()
        };
        let mut bus = Bus::new(db, &spec, &Sensors::default(), &faults, 3, 0).unwrap();
        let mut out: heapless::Vec<Frame, MAX_BATCH> = heapless::Vec::new();
        let (mut sent, before) = (0usize, counting_alloc::allocations());
        for k in 0..20_000 {
            let t = k as f64 * 1e-3;
            let s = Sample {
                t_s: t,
                steer_rad: (0.2 * (7.0 * t).sin() - 0.05).to_radians() * 20.0,
                speed_mps: 15.0 - 0.5 * t,
                accel_mps2: -0.5,
                pedal_decel_mps2: if k % 5000 < 2000 { 4.0 } else { 0.0 },
                brake_pressed: k % 5000 < 2000,
                yaw_rate_rps: 0.01,
                lat_accel_mps2: -0.2,
                steer_torque_nm: 0.3 * (3.0 * t).sin(),
                torsion_bar: true,
            };
            out.clear();
            bus.poll(&s, &mut out);
            sent += out.len();
        }
        let allocs = counting_alloc::allocations() - before;
        assert_eq!(allocs, 0, "{name}: allocations while polling");
        assert!(sent > 2_000, "{name}: {sent} frames");
        let st = bus.stats();
        assert!(st.iter().map(|m| m.bad_checksum).sum::<u64>() > 0, "{name}");
        assert!(st
            .iter()
            .all(|m| m.generated == m.sent + m.dropped + m.bus_off));
    }
}

/// `firmware-sim fleet --profile`: the profile's bus goes on the wire, its mapping decodes, its
/// table estimates; another table is used when given (and its sensor checked).
#[test]
fn a_fleet_runs_on_a_profiles_bus() {
    use clap::Parser;
    use firmware_sim::fleet::{run, FleetArgs};
    let base = PathBuf::from(env!("CARGO_TARGET_TMPDIR")).join("profile_bus_fleet");
    let _ = std::fs::remove_dir_all(&base);
    let fleet = |profile: &str, extra: &[&str]| {
        let dir = base.join(profile);
        let json = dir.join("fleet.json");
        let mut a = vec![
            "fleet".to_string(),
            "--profile".into(),
            profile.into(),
            "--vehicles".into(),
            "1".into(),
            "--events".into(),
            "2".into(),
            "--seed-base".into(),
            "4711".into(),
            "--threads".into(),
            "1".into(),
            "--work-dir".into(),
            dir.display().to_string(),
            "--json".into(),
            json.display().to_string(),
        ];
        a.extend(extra.iter().map(|s| s.to_string()));
        run(FleetArgs::parse_from(a)).map(|()| {
            let v: serde_json::Value =
                serde_json::from_str(&std::fs::read_to_string(&json).unwrap()).unwrap();
            let eval: serde_json::Value = serde_json::from_str(
                &std::fs::read_to_string(dir.join("fleet_4711.eval.json")).unwrap(),
            )
            .unwrap();
            (v["vehicles"][0].clone(), eval)
        })
    };
    // The reference profile with its own table: the events are found and used.
    let (v, eval) = fleet("shimmy_reference", &[]).unwrap();
    assert_eq!(eval["profile"], "shimmy_reference");
    assert_eq!(v["events_recorded"], v["events_true"], "{v}");
    assert!(v["events_used"].as_u64().unwrap() > 0, "{v}");

    if profile("toyota_rav4").is_none() {
        return;
    }
    // The RAV4 with its own table (82.9 Hz sensor): its events are found and used.
    let (v, eval) = fleet("toyota_rav4", &[]).unwrap();
    assert_eq!(eval["profile"], "toyota_rav4");
    assert_eq!(v["events_recorded"], v["events_true"], "{v}");
    assert!(v["events_used"].as_u64().unwrap() > 0, "{v}");
    // With the reference table (same chassis, a 100 Hz sensor): its bus decodes with its
    // mapping and every event is found, and refused for the table's other sensor.
    let table = repo("config/vehicles/shimmy_reference/table.json");
    let (v, eval) = fleet("toyota_rav4", &["--table", table.to_str().unwrap()]).unwrap();
    assert_eq!(eval["profile"], "toyota_rav4");
    assert_eq!(v["events_recorded"], v["events_true"], "{v}");
    assert_eq!(v["events_used"], 0, "{v}");
    let log = read_log(&base.join("toyota_rav4/fleet_4711.log"));
    assert!(log.iter().any(|f| f.id == 0x025) && log.iter().all(|f| f.id != 0x0A0));
}

/// The steering torque on the bus is the plant's: −T_c of MODEL.md §15 when the vehicle's column
/// is enabled (here on the VW, whose LH_EPS_03 carries it in centi-N·m as magnitude and sign)
/// with the sensor's noise, and a steady 0 without the column.
#[test]
fn the_column_torque_reaches_the_bus() {
    let Some(mut p) = profile("vw_mqb") else {
        return;
    };
    let torque = |d: &Drive| -> Vec<(f64, f64)> {
        let mag = signal(&d.db, "LH_EPS_03", "EPS_Lenkmoment");
        let sign = signal(&d.db, "LH_EPS_03", "EPS_VZ_Lenkmoment");
        d.frames
            .iter()
            .filter(|f| f.id == 0x09F)
            .map(|f| {
                let m = mag.phys(f.payload()).unwrap() * 0.01;
                let got = if sign.phys(f.payload()) == Some(1.0) {
                    -m
                } else {
                    m
                };
                (got, d.samples[&(f.id, f.t_ns)].steer_torque_nm)
            })
            .collect()
    };
    let rms = |v: &[f64]| (v.iter().map(|x| x * x).sum::<f64>() / v.len() as f64).sqrt();

    // Without the column there is no torsion bar: a steady 0, no noise (the observer takes a
    // constant torque for none and estimates from the angle).
    let off = torque(&drive(p.clone()));
    assert!(!off.is_empty());
    assert!(off.iter().all(|&(got, want)| want == 0.0 && got == 0.0));

    p.vehicle.column.enabled = true;
    let on = torque(&drive(p.clone()));
    // 0.02 N·m noise, 0.01 N·m steps on top of the plant's torque.
    let noise = on.iter().map(|x| x.0 - x.1).collect::<Vec<_>>();
    let r = rms(&noise);
    assert!(r > 0.01 && r < 0.04, "column: noise rms {r} N·m");
    // §15's T_c: about 0.1 N·m of shimmy while braking at 0.2 mm, little in between.
    let peak = on.iter().map(|x| x.1.abs()).fold(0.0, f64::max);
    assert!(peak > 0.05, "column: plant torque peak {peak} N·m");
    for &(got, want) in &on {
        assert!(
            (got - want).abs() <= 0.11,
            "decoded {got} N·m, plant {want}"
        );
    }
    // The profile's mapping reads the same torque, in N·m and the monitor's sign.
    let d = drive(p);
    let mut mapper = Mapper::new(&d.db, &d.profile.mapping).unwrap();
    let mut n = 0;
    for f in &d.frames {
        if let Some(Update {
            outcome: Outcome::Accepted(ch),
            ..
        }) = mapper.on_frame(f)
        {
            if ch.steer_torque {
                let got = mapper.snapshot(f.t_ns).steer_torque_nm.value.unwrap();
                let want = d.samples[&(f.id, f.t_ns)].steer_torque_nm;
                assert!((got - want).abs() <= 0.11, "mapped {got} N·m, plant {want}");
                n += 1;
            }
        }
    }
    assert!(n > 1_000, "{n} torque frames mapped");
    // The sign too: the decoded torque follows the plant's.
    let dot: f64 = on.iter().map(|(g, w)| g * w).sum();
    let (rg, rw) = (
        rms(&on.iter().map(|x| x.0).collect::<Vec<_>>()),
        rms(&on.iter().map(|x| x.1).collect::<Vec<_>>()),
    );
    let c = dot / (rg * rw * on.len() as f64);
    assert!(c > 0.5, "decoded vs plant torque correlation {c}");
}
