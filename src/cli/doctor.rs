//! `shimmy doctor`: checks a signal mapping against a car's logs and says what to change.
//!
//! This module is the command line and the text output; the diagnosis is
//! [`crate::doctor`]'s.

use std::io::Write;
use std::path::PathBuf;

use anyhow::{bail, Context};

use crate::doctor::checks::Status;
use crate::doctor::{self, Diagnosis, Setup};
use crate::observer::ObserverConfig;
use crate::profile::identify::{self, Verdict};
use crate::profile::Profile;

/// The manual part of `shimmy doctor --help`.
const MANUAL: &str = "\
For a new car or a suspicious log: reads the LOGs (candump -L, Vector ASC, BLF, MF4 or PEAK
TRC) once through the mapping of --profile (or --mapping with its DBC; with neither, the
profile `shimmy identify` finds in the first 30 s of the logs) and reports

  signals      per mapped quantity: source, samples, rate, range
  messages     per mapped message: frames, accepted, checksum and counter errors, frames lost
               per the counter, short frames, timeouts (fails when most frames are rejected)
  checks       consistency between signals, on half-second means of the whole log:
               - accel against d(speed)/dt: sign and scale of the regression slope;
               - steer_angle against turning: the measured yaw rate against the kinematic
                 v * steer / (i_s * L) (steering ratio i_s and wheelbase L of the profile's
                 chassis, MODEL.md section 9), and the lateral acceleration against
                 v^2 * steer / (i_s * L), where the mapping has [yaw_rate] / [lat_accel];
               - yaw_rate / lat_accel against turning: the same relations, plus lateral
                 acceleration against v * yaw rate; when two relations disagree and the third
                 agrees, the signal the two share is the one named;
               - brake against deceleration: the car slows more with the brake applied.
               A slope of the wrong sign fails with `invert` to change; a slope off by more than
               a factor of 3.16 fails with the `scale` or `unit` to set (a car understeers, so
               yaw rates below the kinematic ones are expected). With too little turning,
               speed change or braking in the log a check says \"not enough data\" instead.
  braking      every brake application: recorded events (used, or why not, with the numbers)
               and the applications ignored before recording (too slow, too light, too short)
  verdict      the mapping changes the failed checks call for

The mapping keys named in fixes: `invert` and `scale` under [steer_angle], [accel],
[yaw_rate], [lat_accel]; `unit`; `checksum` / `counter_signal` under [messages.NAME].

Exit status: 0 when no check failed (passes, warnings and \"not enough data\" only), 1 when a
check failed or on an error.

Examples:
  shimmy doctor --profile toyota_rav4 rav4_2017_seg40_bus0.log
  shimmy doctor --mapping my_car.toml --dbc my_car.dbc --format json drive1.log drive2.log
  shimmy doctor drive.blf                      # the profile shimmy identify finds";

/// Arguments of `shimmy doctor`.
#[derive(clap::Args, Debug)]
#[command(after_long_help = MANUAL)]
pub struct Args {
    /// Vehicle profile (name, alias or folder): its mapping, DBC, chassis and table.
    #[arg(long, value_name = "NAME", conflicts_with = "mapping")]
    pub profile: Option<String>,

    /// Signal mapping to check (TOML), instead of a profile's.
    #[arg(long, value_name = "FILE")]
    pub mapping: Option<PathBuf>,

    /// DBC for --mapping. Default: the mapping's `dbc`, looked up as `shimmy estimate` does.
    #[arg(long, value_name = "FILE", requires = "mapping")]
    pub dbc: Option<PathBuf>,

    /// Chassis for --mapping (TOML, MODEL.md section 9 keys); its steering ratio and wheelbase
    /// set the kinematic turning relation. Default: MODEL.md section 9.
    #[arg(long, value_name = "FILE", requires = "mapping")]
    pub vehicle: Option<PathBuf>,

    /// Observer thresholds (TOML, as config/observer.toml) for the braking candidates.
    #[arg(long, value_name = "FILE")]
    pub config: Option<PathBuf>,

    /// Output format.
    #[arg(long, value_enum, default_value_t = Format::Text)]
    pub format: Format,

    /// The car's logs, in time order.
    #[arg(value_name = "LOG", required = true)]
    pub logs: Vec<PathBuf>,
}

pub use super::TextOrJson as Format;

/// The setup the arguments ask for (identifying the logs when neither a profile nor a mapping
/// is given).
pub fn setup(args: &Args) -> anyhow::Result<Setup> {
    let observer = match &args.config {
        Some(p) => ObserverConfig::load(p)?,
        None => ObserverConfig::default(),
    };
    if let Some(name) = &args.profile {
        let p = Profile::load(name)?;
        return Ok(doctor::setup_from_profile(
            &p,
            format!("--profile {name}"),
            observer,
        ));
    }
    if let Some(m) = &args.mapping {
        let mut s = doctor::setup_from_mapping(m, args.dbc.as_deref(), observer)?;
        if let Some(v) = &args.vehicle {
            s.vehicle = crate::cli::estimate::load_vehicle(Some(v))?;
            s.notes.retain(|n| !n.starts_with("chassis:"));
        }
        return Ok(s);
    }
    let id = identify::identify_logs(&args.logs, identify::Options::default().max_seconds)
        .context("identifying the logs (no --profile or --mapping given)")?;
    if id.verdict != Verdict::Identified {
        bail!(
            "no --profile or --mapping given, and the logs do not name one: {}; pass \
             --profile NAME or --mapping FILE",
            id.summary
        );
    }
    let name = id.profile.clone().expect("identified");
    let p = Profile::load(&name)?;
    Ok(doctor::setup_from_profile(
        &p,
        format!("identified as {name} by `shimmy identify`"),
        observer,
    ))
}

pub fn run(args: Args) -> anyhow::Result<()> {
    let setup = setup(&args)?;
    let d = doctor::diagnose(&setup, &args.logs)?;
    let mut out = std::io::stdout().lock();
    match args.format {
        Format::Json => {
            serde_json::to_writer_pretty(&mut out, &d)?;
            writeln!(out)?;
        }
        Format::Text => write_text(&mut out, &d)?,
    }
    out.flush().context("writing the output")?;
    if d.failed() {
        std::process::exit(1);
    }
    Ok(())
}

fn status_label(s: Status) -> &'static str {
    match s {
        Status::Pass => "PASS",
        Status::Warn => "WARN",
        Status::Fail => "FAIL",
        Status::NotEnoughData => "NOT ENOUGH DATA",
        Status::NotChecked => "NOT CHECKED",
    }
}

fn opt(x: Option<f64>, digits: usize) -> String {
    x.map_or("-".into(), |v| format!("{v:.digits$}"))
}

/// The text report.
pub fn write_text(out: &mut dyn Write, d: &Diagnosis) -> anyhow::Result<()> {
    writeln!(
        out,
        "shimmy doctor: {} ({}); mapping {}; DBC {}",
        d.profile.as_deref().unwrap_or("no profile"),
        d.chosen_by,
        d.mapping,
        d.dbc
    )?;
    writeln!(
        out,
        "{} frames ({} mapped) over {:.1} s; steering ratio {:.1}, wheelbase {:.2} m",
        d.frames, d.mapped_frames, d.seconds, d.steer_ratio, d.wheelbase_m
    )?;
    for n in &d.notes {
        writeln!(out, "note: {n}")?;
    }
    writeln!(out, "\nsignals:")?;
    for s in &d.signals {
        writeln!(
            out,
            "  {:<15} {:<42} {:>7} samples {:>7} Hz  {} .. {} {} (mean {})",
            s.quantity.key(),
            s.source,
            s.samples,
            opt(s.rate_hz, 1),
            opt(s.min, 2),
            opt(s.max, 2),
            s.unit,
            opt(s.mean, 2)
        )?;
    }
    writeln!(out, "\nchecks:")?;
    for c in &d.checks {
        writeln!(
            out,
            "  {:<5} {}: {}",
            status_label(c.status),
            c.name,
            c.summary
        )?;
        if let Some(f) = &c.fix {
            writeln!(out, "        fix: {f}")?;
        }
    }
    writeln!(
        out,
        "\nbraking candidates (time from the first frame, initial speed, deceleration, \
         duration):"
    )?;
    let t0 = d.log_start_s.unwrap_or(0.0);
    if d.braking.candidates.is_empty() {
        writeln!(out, "  none")?;
    }
    for c in &d.braking.candidates {
        writeln!(
            out,
            "  {:>8.2} s  {:>5.1} km/h  {:.2} g  {:.2} s  {}{}",
            c.t_start_s - t0,
            c.v0_kmh,
            c.decel_g,
            c.duration_s,
            c.outcome,
            if c.outcome == "used" {
                String::new()
            } else {
                format!(": {}", c.reason)
            }
        )?;
    }
    if d.braking.rejections.worth_reporting() {
        writeln!(out, "  {}", d.braking.summary)?;
    }
    writeln!(out, "\nverdict: {}", d.verdict.summary)?;
    Ok(())
}
