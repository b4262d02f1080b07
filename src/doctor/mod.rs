//! `shimmy doctor`: is a signal mapping right for a car? One pass over its logs reports
//!
//! * per mapped quantity its samples, rate and range, and per mapped message its frames and
//!   checksum, counter and timeout errors ([`series`], the mapper's counters);
//! * the consistency checks between signals ([`checks`]): acceleration against the speed's
//!   derivative, steering angle against the yaw rate and lateral acceleration, brake against
//!   deceleration — each passed, failed with the mapping change that fixes it, or "not enough
//!   data" when the log has too little turning or braking;
//! * every braking candidate: the events the detector recorded (used or why not) and the brake
//!   applications it ignored (too slow, too light, too short, with what it measured);
//! * a verdict: the list of mapping changes, or that nothing failed.
//!
//! What it is not: the estimate (`shimmy estimate`) or the profile's identification (`shimmy
//! identify`). It changes no file: it says what to change.

pub mod checks;
pub mod series;

use std::path::{Path, PathBuf};

use anyhow::Context;
use serde::Serialize;

use crate::dbc::Database;
use crate::events::{EventConfig, IgnoredApplication, Unused};
use crate::model::VehicleParams;
use crate::observer::rejections::{describe_unused, Rejections};
use crate::observer::table::ResponseTable;
use crate::observer::{EventOut, Observer, ObserverConfig};
use crate::pipeline::feeder::Feeder;
use crate::signals::mapping::MappingConfig;
use crate::signals::{MessageStats, Outcome};
use crate::source::log::LogReader;
use crate::source::CanSource;
use checks::{Check, Checker, Status};
use series::{Quantity, Series, SignalStats, QUANTITIES};

/// What the doctor examines the logs with.
#[derive(Clone, Debug)]
pub struct Setup {
    /// How the mapping was chosen ("--profile toyota_rav4", "--mapping FILE", "identified as
    /// ...").
    pub chosen_by: String,
    pub profile: Option<String>,
    pub mapping_path: PathBuf,
    pub mapping: MappingConfig,
    pub dbc_path: PathBuf,
    /// The chassis: its steering ratio and wheelbase set the kinematic turning relation.
    pub vehicle: VehicleParams,
    pub observer: ObserverConfig,
    /// The response table, when there is one (events from another sensor are then refused).
    pub table: Option<ResponseTable>,
    /// Remarks about the setup (e.g. the profile's table could not be loaded).
    pub notes: Vec<String>,
}

impl Setup {
    /// The steering ratio i_s of the chassis: l·sin α / r_p (MODEL.md §8, ≈15.5 by default).
    pub fn steer_ratio(&self) -> f64 {
        let s = &self.vehicle.steering;
        s.arm_length_m * s.trapezoid_angle_deg.to_radians().sin() / s.rack_travel_per_pinion_rad_m
    }
}

/// A braking candidate and what became of it.
#[derive(Clone, Debug, Serialize)]
pub struct Candidate {
    pub t_start_s: f64,
    pub v0_kmh: f64,
    /// Plateau deceleration for recorded events, peak for ignored applications (g).
    pub decel_g: f64,
    pub duration_s: f64,
    /// "used", "not used", "ignored".
    pub outcome: &'static str,
    /// Why, with the numbers.
    pub reason: String,
}

/// The braking section.
#[derive(Clone, Debug, Serialize)]
pub struct Braking {
    pub candidates: Vec<Candidate>,
    pub rejections: Rejections,
    /// The rejections in one sentence, with the likely cause.
    pub summary: String,
}

/// The verdict.
#[derive(Clone, Debug, Serialize)]
pub struct Verdict {
    /// "ok" when no check failed, else "fix the mapping" (or "problems" when no fix is known).
    pub status: &'static str,
    pub failed: usize,
    pub warnings: usize,
    pub not_enough_data: usize,
    /// The mapping changes the failed checks call for, each once.
    pub fixes: Vec<String>,
    pub summary: String,
}

/// The whole report.
#[derive(Clone, Debug, Serialize)]
pub struct Diagnosis {
    pub chosen_by: String,
    pub profile: Option<String>,
    pub mapping: String,
    pub dbc: String,
    pub logs: Vec<String>,
    pub frames: u64,
    pub mapped_frames: u64,
    pub seconds: f64,
    /// Log time of the first frame (s): the braking candidates' times are log times.
    pub log_start_s: Option<f64>,
    /// Steering ratio and wheelbase used for the turning relations.
    pub steer_ratio: f64,
    pub wheelbase_m: f64,
    pub notes: Vec<String>,
    pub signals: Vec<SignalStats>,
    pub messages: Vec<MessageStats>,
    pub checks: Vec<Check>,
    pub braking: Braking,
    pub verdict: Verdict,
}

impl Diagnosis {
    /// Whether any check failed (the command's exit status 1).
    pub fn failed(&self) -> bool {
        self.verdict.failed > 0
    }
}

/// "MESSAGE.SIGNAL" of a quantity, when mapped.
fn source_of(m: &MappingConfig, q: Quantity) -> Option<String> {
    let ms = |a: &str, b: &str| Some(format!("{a}.{b}"));
    match q {
        Quantity::SteerAngle => ms(&m.steer_angle.message, &m.steer_angle.signal),
        Quantity::Speed => match &m.speed.signal {
            Some(s) => ms(&m.speed.message, s),
            None => Some(format!(
                "{}.({})",
                m.speed.message,
                m.speed.wheel_signals.join(" + ")
            )),
        },
        Quantity::BrakePressure => m
            .brake_pressure
            .as_ref()
            .and_then(|b| ms(&b.message, &b.signal)),
        Quantity::BrakePressed => m
            .brake_pressed
            .as_ref()
            .and_then(|b| ms(&b.message, &b.signal)),
        Quantity::Accel => m.accel.as_ref().and_then(|b| ms(&b.message, &b.signal)),
        Quantity::YawRate => m.yaw_rate.as_ref().and_then(|b| ms(&b.message, &b.signal)),
        Quantity::LatAccel => m.lat_accel.as_ref().and_then(|b| ms(&b.message, &b.signal)),
    }
}

/// Runs the doctor over `logs`, in order.
pub fn diagnose(setup: &Setup, logs: &[PathBuf]) -> anyhow::Result<Diagnosis> {
    let (db, _) = Database::load(&setup.dbc_path)?;
    let mut feeder = Feeder::new(&db, &setup.mapping, &setup.observer).with_context(|| {
        format!(
            "mapping {} against {}",
            setup.mapping_path.display(),
            setup.dbc_path.display()
        )
    })?;
    let mut obs = Observer::new(setup.observer.clone(), setup.table.clone())?;
    let mut series = Series::default();
    let mut checker = Checker::new(
        &setup.mapping,
        setup.steer_ratio(),
        setup.vehicle.vehicle.wheelbase_m,
    );
    let mut notes = setup.notes.clone();
    for w in feeder.mapper().warnings() {
        notes.push(format!("mapping: {w}"));
    }
    let mut span = (None::<i64>, None::<i64>);
    let mut log_start = None;
    let mut seconds = 0.0;
    for log in logs {
        let mut src =
            LogReader::open(log).with_context(|| format!("cannot open log {}", log.display()))?;
        while let Some(f) = src
            .next_frame()
            .with_context(|| format!("reading log {}", log.display()))?
        {
            if span.0.is_none() {
                span.0 = Some(f.t_ns);
                log_start.get_or_insert(f.t_ns as f64 * 1e-9);
            }
            span.1 = Some(f.t_ns.max(span.1.unwrap_or(f.t_ns)));
            let Some((s, u)) = feeder.sample(&f) else {
                continue;
            };
            obs.push(&s);
            if let Some(b) = s.brake {
                series.brake(f.t_ns, b);
            }
            if let Outcome::Accepted(ch) = u.outcome {
                let snap = feeder.mapper().snapshot(f.t_ns);
                let fresh = [
                    (
                        ch.steer_angle,
                        Quantity::SteerAngle,
                        snap.steer_angle_rad.valid(),
                    ),
                    (ch.speed, Quantity::Speed, snap.speed_mps.valid()),
                    (
                        ch.brake_pressure,
                        Quantity::BrakePressure,
                        snap.brake_pressure_pa.valid(),
                    ),
                    (
                        ch.brake_pressed,
                        Quantity::BrakePressed,
                        snap.brake_pressed.valid().map(|b| b as u8 as f64),
                    ),
                    (ch.accel, Quantity::Accel, snap.accel_mps2.valid()),
                    (ch.yaw_rate, Quantity::YawRate, snap.yaw_rate_radps.valid()),
                    (
                        ch.lat_accel,
                        Quantity::LatAccel,
                        snap.lat_accel_mps2.valid(),
                    ),
                ];
                for (changed, q, v) in fresh {
                    if let (true, Some(v)) = (changed, v) {
                        series.value(q, f.t_ns, v);
                    }
                }
            }
            for b in series.take_ready() {
                checker.bin(&b);
            }
        }
        for s in src.take_skips() {
            notes.push(format!("log reader skipped {}: {}", s.location, s.reason));
        }
        if let (Some(a), Some(b)) = span {
            seconds += (b - a).max(0) as f64 * 1e-9;
        }
        span = (None, None);
    }
    obs.finish();
    series.finish();
    for b in series.take_ready() {
        checker.bin(&b);
    }

    let m = &setup.mapping;
    let signals: Vec<SignalStats> = QUANTITIES
        .iter()
        .filter_map(|&q| Some(SignalStats::new(q, source_of(m, q)?, series.stats(q))))
        .collect();
    let messages = feeder.mapper().stats();
    let mut all = message_checks(&messages);
    all.extend(range_checks(&signals));
    all.extend(checker.finish());
    let braking = braking(&obs, &setup.observer.events);
    let verdict = verdict(&all, &braking);
    Ok(Diagnosis {
        chosen_by: setup.chosen_by.clone(),
        profile: setup.profile.clone(),
        mapping: setup.mapping_path.display().to_string(),
        dbc: setup.dbc_path.display().to_string(),
        logs: logs.iter().map(|p| p.display().to_string()).collect(),
        frames: feeder.stats.frames,
        mapped_frames: feeder.stats.mapped_frames,
        seconds,
        log_start_s: log_start,
        steer_ratio: setup.steer_ratio(),
        wheelbase_m: setup.vehicle.vehicle.wheelbase_m,
        notes,
        signals,
        messages,
        checks: all,
        braking,
        verdict,
    })
}

fn share(a: u64, b: u64) -> f64 {
    if b == 0 {
        0.0
    } else {
        a as f64 / b as f64
    }
}

/// Presence and integrity of each mapped message.
fn message_checks(messages: &[MessageStats]) -> Vec<Check> {
    messages
        .iter()
        .map(|m| {
            let name = format!("message {} (0x{:03X})", m.name, m.id);
            let mut c = Check::new(&name, Status::Pass, String::new());
            c.evidence = serde_json::to_value(m).unwrap_or_default();
            if m.frames == 0 {
                c.status = Status::Fail;
                c.summary = "never appears in the log".into();
                c.fix = Some(format!(
                    "check that the log is from this car (`shimmy identify`) and that `{}` \
                     is the DBC message the car sends",
                    m.name
                ));
                return c;
            }
            let ck = share(m.checksum_errors, m.frames);
            let ctr = share(m.counter_errors, m.frames);
            let lost = share(m.frames_lost, m.frames + m.frames_lost);
            let short = share(m.short_frames, m.frames);
            c.summary = format!(
                "{} frames, {:.1} % accepted; checksum errors {:.1} %, repeated counters {:.1} \
                 %, frames lost per counter {:.1} %, short {:.1} %, timeouts {}",
                m.frames,
                100.0 * share(m.accepted, m.frames),
                100.0 * ck,
                100.0 * ctr,
                100.0 * lost,
                100.0 * short,
                m.timeouts
            );
            if ck > 0.5 {
                c.status = Status::Fail;
                c.fix = Some(format!(
                    "the checksum fails on most frames: remove `checksum` under [messages.{}] \
                     or name the kind this car uses",
                    m.name
                ));
            } else if ctr > 0.5 {
                c.status = Status::Fail;
                c.fix = Some(format!(
                    "the counter repeats on most frames: remove `counter_signal` under \
                     [messages.{}] or name the car's counter signal",
                    m.name
                ));
            } else if short > 0.5 {
                c.status = Status::Fail;
                c.fix = Some(format!(
                    "most frames are too short for the mapped signals: is `{}` the right \
                     message?",
                    m.name
                ));
            } else if ck > 0.01 || ctr > 0.01 || lost > 0.05 || short > 0.01 || m.timeouts > 0 {
                c.status = Status::Warn;
            }
            c
        })
        .collect()
}

/// Plausible ranges of speed and steering angle (display units).
fn range_checks(signals: &[SignalStats]) -> Vec<Check> {
    let mut out = Vec::new();
    for s in signals {
        let (Some(lo), Some(hi)) = (s.min, s.max) else {
            if matches!(s.quantity, Quantity::SteerAngle | Quantity::Speed) {
                let mut c = Check::new(
                    &format!("range {}", s.quantity.key()),
                    Status::Fail,
                    format!(
                        "{} ({}) never had a valid value",
                        s.quantity.key(),
                        s.source
                    ),
                );
                c.fix = Some(format!(
                    "check [{}] (message, signal) and the message's protection",
                    s.quantity.key()
                ));
                out.push(c);
            }
            continue;
        };
        let (bad, fix) = match s.quantity {
            Quantity::Speed if hi > 360.0 => (
                true,
                "check [speed]'s unit: the car cannot go this fast (km/h read as m/s?)",
            ),
            Quantity::Speed if lo < -20.0 => (true, "check [speed]: large negative speeds"),
            Quantity::SteerAngle if lo.abs().max(hi.abs()) > 1000.0 => (
                true,
                "check [steer_angle]'s unit and scale: no steering wheel turns this far",
            ),
            _ => (false, ""),
        };
        if matches!(s.quantity, Quantity::Speed | Quantity::SteerAngle) {
            let mut c = Check::new(
                &format!("range {}", s.quantity.key()),
                if bad { Status::Fail } else { Status::Pass },
                format!("{lo:.1} to {hi:.1} {}", s.unit),
            );
            if bad {
                c.fix = Some(fix.into());
            }
            out.push(c);
        }
    }
    out
}

/// Why a recorded event was not used, with its numbers.
fn why_unused(e: &EventOut, cfg: &EventConfig) -> String {
    let Some(r) = e.unused_reason else {
        return "used".into();
    };
    let what = describe_unused(r, cfg);
    match r {
        Unused::SpeedOutOfRange => format!("{what} ({:.0} km/h)", e.v0_kmh),
        Unused::DecelOutOfRange => format!("{what} ({:.2} g)", e.decel_g),
        Unused::TooShort => format!("{what} ({:.2} s)", e.duration_s),
        Unused::LowSampleRate => format!("{what} ({:.0} Hz)", e.sample_hz),
        Unused::MissingData => format!(
            "{what} ({} missing, {} invalid)",
            e.missing_samples, e.invalid_updates
        ),
        Unused::SensorMismatch => format!(
            "{what} ({:.1} Hz, {} deg steps)",
            e.sample_hz, e.quant_step_deg
        ),
        _ => what,
    }
}

/// Why an application was ignored, with its numbers.
fn why_ignored(a: &IgnoredApplication, cfg: &EventConfig) -> String {
    let mut why = Vec::new();
    if a.too_slow {
        why.push(format!(
            "initial speed {:.0} km/h below {} km/h",
            a.v0_kmh, cfg.record_min_speed_kmh
        ));
    }
    if a.too_light {
        let mut s = format!(
            "peak deceleration {:.2} g below {} g",
            a.peak_decel_g, cfg.record_min_decel_g
        );
        if a.peak_accel_g >= cfg.record_min_decel_g {
            s += &format!(
                " (it read {:.2} g forward while braking: acceleration sign?)",
                a.peak_accel_g
            );
        }
        why.push(s);
    }
    if a.too_short {
        why.push(format!(
            "lasted {:.2} s, under {} s",
            a.t_end_s - a.t_start_s,
            0.5 * cfg.min_duration_s
        ));
    }
    why.join("; ")
}

fn braking(obs: &Observer, cfg: &EventConfig) -> Braking {
    let mut candidates: Vec<Candidate> = obs
        .events()
        .iter()
        .map(|e| Candidate {
            t_start_s: e.t_start,
            v0_kmh: e.v0_kmh,
            decel_g: e.decel_g,
            duration_s: e.duration_s,
            outcome: if e.used { "used" } else { "not used" },
            reason: why_unused(e, cfg),
        })
        .collect();
    candidates.extend(obs.ignored_applications().iter().map(|a| Candidate {
        t_start_s: a.t_start_s,
        v0_kmh: a.v0_kmh,
        decel_g: a.peak_decel_g,
        duration_s: a.t_end_s - a.t_start_s,
        outcome: "ignored",
        reason: why_ignored(a, cfg),
    }));
    candidates.sort_by(|a, b| a.t_start_s.total_cmp(&b.t_start_s));
    let rejections = obs.rejections();
    Braking {
        candidates,
        rejections,
        summary: obs.explain_rejections(false),
    }
}

fn verdict(all: &[Check], braking: &Braking) -> Verdict {
    let count = |s: Status| all.iter().filter(|c| c.status == s).count();
    let failed = count(Status::Fail);
    let mut fixes: Vec<String> = Vec::new();
    for c in all.iter().filter(|c| c.status == Status::Fail) {
        if let Some(f) = &c.fix {
            if !fixes.contains(f) {
                fixes.push(f.clone());
            }
        }
    }
    let not_enough: Vec<&str> = all
        .iter()
        .filter(|c| c.status == Status::NotEnoughData)
        .map(|c| c.name.as_str())
        .collect();
    let mut summary = if failed == 0 {
        "no check failed".to_string()
    } else if fixes.is_empty() {
        format!("{failed} check(s) failed")
    } else {
        format!(
            "{failed} check(s) failed; change the mapping: {}",
            fixes.join("; ")
        )
    };
    if !not_enough.is_empty() {
        summary += &format!(
            "; not enough data in this log for: {} (a log with curves and firm braking \
             checks them)",
            not_enough.join(", ")
        );
    }
    if braking.rejections.used == 0 {
        summary += &format!("; braking: {}", braking.summary);
    }
    Verdict {
        status: match (failed, fixes.is_empty()) {
            (0, _) => "ok",
            (_, false) => "fix the mapping",
            (_, true) => "problems",
        },
        failed,
        warnings: count(Status::Warn),
        not_enough_data: not_enough.len(),
        fixes,
        summary,
    }
}

/// The mapping, DBC and chassis of a profile, or of a mapping file.
pub fn setup_from_profile(
    p: &crate::profile::Profile,
    chosen_by: String,
    observer: ObserverConfig,
) -> Setup {
    let mut notes = Vec::new();
    let table = match p.load_table() {
        Ok(t) => t,
        Err(e) => {
            notes.push(format!(
                "no response table ({e:#}): events are judged without the sensor check"
            ));
            None
        }
    };
    Setup {
        chosen_by,
        profile: Some(p.name.clone()),
        mapping_path: p.mapping_path.clone(),
        mapping: p.mapping.clone(),
        dbc_path: p.dbc_path.clone(),
        vehicle: p.vehicle.clone(),
        observer,
        table,
        notes,
    }
}

/// A mapping file with its DBC (given, or the one the mapping names), the default chassis.
pub fn setup_from_mapping(
    mapping_path: &Path,
    dbc: Option<&Path>,
    observer: ObserverConfig,
) -> anyhow::Result<Setup> {
    let mapping = MappingConfig::from_toml_file(mapping_path)?;
    let dbc_path = match dbc {
        Some(d) => d.to_path_buf(),
        None => crate::cli::estimate::resolve_dbc(mapping_path, &mapping)?,
    };
    Ok(Setup {
        chosen_by: format!("--mapping {}", mapping_path.display()),
        profile: None,
        mapping_path: mapping_path.to_path_buf(),
        mapping,
        dbc_path,
        vehicle: VehicleParams::default(),
        observer,
        table: None,
        notes: vec!["chassis: MODEL.md §9 defaults (steering ratio and wheelbase)".into()],
    })
}
