//! The `firmware-sim` binary: runs one scenario and writes its frames to a `candump -L` log or
//! sends them on a SocketCAN interface, plus the ground-truth sidecar. See `--help`.

use std::io::Write;
use std::path::{Path, PathBuf};
use std::time::{Duration, Instant};

use anyhow::{bail, Context};
use clap::Parser;
use firmware_sim::plant::ModelPlant;
use firmware_sim::{FirmwareSim, RunInfo, Scenario};

/// Simulated vehicle ECUs: drive the shimmy model with a known steering-joint clearance and put
/// a vehicle's bus on a CAN interface or into a candump log.
///
/// firmware-sim reads a scenario (TOML, see config/scenarios/), runs the 5-DOF shimmy model of
/// MODEL.md as the plant through the scenario's drive cycle (cruise, braking events,
/// re-acceleration), and emulates the ECUs of a bus: by default our reference bus
/// (dbc/shimmy_reference.dbc, embedded in the binary): steering angle sensor at 100 Hz with 0.1°
/// resolution, brake pressure and switch at 50 Hz, wheel speeds at 50 Hz, vehicle speed and
/// longitudinal acceleration at 50 Hz, with rolling counters, checksums, sensor noise, send
/// jitter and optional faults.
///
/// With --profile NAME, the bus of a vehicle profile (config/vehicles/NAME: its DBC and
/// bus.toml) as on the real car: its messages, periods, checksums, counters, sign conventions and
/// background traffic; the profile's chassis is the vehicle unless the scenario names one.
///
/// Output (one of):
///   --out LOG        a candump -L log, written as fast as the model runs ("-" = stdout;
///                    LOG ending in .mf4, .asc or .blf: that format instead);
///   --iface IFACE    frames sent on a SocketCAN interface (e.g. vcan0) in real time, or at
///                    N× real time with --speed N (0 = as fast as possible); add --out LOG to
///                    also record what was sent.
///
/// Always written: a ground-truth sidecar (JSON) with the scenario name, file and seed, the true
/// clearance of each joint (start, end, and at each braking event's onset and end, with the
/// odometer), each braking event (t_start_s, t_end_s, v0_kmh, decel_g) with its true
/// steering-wheel shimmy amplitude (MODEL.md §11) and joint contact statistics, and per-message frame
/// counts (sent, dropped, bus-off, bad checksum). Times in it are seconds since the start of the
/// log; frame timestamps are start_unix_s + t.
///
/// Same scenario and seed => byte-identical log and sidecar.
///
/// Scenario file (every table rejects unknown keys; units are in the key names):
///   seed = 20                      name, description, vehicle = "file.toml" (VehicleParams,
///                                  relative to the scenario; default MODEL.md §9), step_s
///                                  (1e-4), integrator ("rk4_adaptive"; the model's
///                                  schemes, see `shimmy simulate --help`),
///                                  control_period_s (1e-3, the truth trace interval: driver
///                                  demand, ECU sampling and contact tally every 1 ms; = step_s
///                                  updates every model step), start_unix_s are optional
///   [clearance]  mode = "dual" (both joints worn) | "single" (left worn, right ideal);
///                left_mm (> 0, at the start of the run; both joints when right_mm is absent);
///                right_mm (dual only: unequal wear); wear: wear_mm_per_1000km (0; growth of
///                every worn joint with distance driven, applied every 0.1 s), max_mm (2.0; wear
///                stops there), odometer_km (0; odometer at the start, reported in the truth)
///   [drive]      start_speed_kmh, accel_g (0.15), coast_g (0.05), then segments in order:
///   [[drive.segment]] kind = "cruise": speed_kmh, duration_s (reached first at accel_g)
///   [[drive.segment]] kind = "brake":  decel_g, ramp_in_s (0.3), ramp_out_s (0.3),
///                duration_s (absent = brake to a stop), hold_s (1.0, pedal held at standstill)
///   [[drive.segment]] kind = "stand":  duration_s (car must be stopped)
///   [excitation] unbalance_kgm (2e-3), road_noise_nm (0.2)          (MODEL.md §7),
///                phase_change ("none": the wheels' unbalance phase difference is kept for the
///                drive; "per_stop": drawn anew at every stop, as after a turn)
///   [driver]     steer_rms_deg (1.0), steer_tau_s (2.0), steer_offset_deg (0)
///   [sensors]    steer_noise_deg, brake_pressure_noise_bar, brake_bar_per_g (90),
///                wheel_speed_noise_kmh, wheel_radius_tolerance_pct, accel_noise_mps2, jitter_ms
///   [faults]     drop_probability, bad_checksum_probability,
///                [[faults.stuck]] message, start_s, duration_s,
///                [[faults.bus_off]] message (absent = whole bus), start_s, duration_s
///
/// Examples:
///   firmware-sim --scenario config/scenarios/worn_0p2mm.toml --out worn.log
///   firmware-sim --scenario config/scenarios/worn_0p2mm.toml --profile toyota_rav4 --out rav4.log
///   firmware-sim --scenario config/scenarios/city.toml --seed 7 --out city.log --truth city.json
///   sudo modprobe vcan && sudo ip link add dev vcan0 type vcan && sudo ip link set up vcan0
///   firmware-sim --scenario config/scenarios/highway.toml --iface vcan0 --speed 10
///
/// Exit status: 0 on success, 1 on any error (bad scenario: the message names the key).
#[derive(Parser, Debug)]
#[command(name = "firmware-sim", version, verbatim_doc_comment)]
struct Cli {
    /// Scenario file (TOML), e.g. config/scenarios/worn_0p2mm.toml.
    #[arg(long, value_name = "FILE")]
    scenario: PathBuf,

    /// Override the scenario's seed (unbalance phases, road and sensor noise, jitter, faults).
    #[arg(long, value_name = "S")]
    seed: Option<u64>,

    /// Write a candump -L log here ("-" for stdout; .mf4, .asc, .blf: that format). With
    /// --iface: also record what was sent.
    #[arg(long, value_name = "LOG")]
    out: Option<PathBuf>,

    /// Ground-truth sidecar (JSON). Default: the log path with its extension replaced by
    /// .truth.json, or <scenario name>.truth.json in the current directory with --iface or
    /// --out -.
    #[arg(long, value_name = "FILE.json")]
    truth: Option<PathBuf>,

    /// Send on this SocketCAN interface (Linux), e.g. vcan0 or can0.
    #[arg(long, value_name = "IFACE")]
    iface: Option<String>,

    /// With --iface: simulated seconds per wall-clock second (1 = real time, 10 = ten times
    /// faster, 0 = as fast as possible).
    #[arg(long, value_name = "N", default_value_t = 1.0, requires = "iface")]
    speed: f64,

    /// Emulate this vehicle profile's bus (name, alias or folder; see config/vehicles/): its
    /// DBC and bus.toml, its chassis as the vehicle when the scenario names none.
    #[arg(long, value_name = "NAME")]
    profile: Option<String>,

    /// Use this DBC instead of the embedded reference DBC, or of the profile's (it must define
    /// the same messages and signals).
    #[arg(long, value_name = "FILE")]
    dbc: Option<PathBuf>,

    /// Print nothing but errors.
    #[arg(long, short)]
    quiet: bool,
}

fn main() {
    // `firmware-sim fleet ...`: the observer's fleet validation (see `firmware-sim fleet --help`).
    if std::env::args_os().nth(1).is_some_and(|a| a == "fleet") {
        let args = firmware_sim::fleet::FleetArgs::parse_from(std::env::args_os().skip(1));
        if let Err(e) = firmware_sim::fleet::run(args) {
            eprintln!("firmware-sim fleet: error: {e:#}");
            std::process::exit(1);
        }
        return;
    }
    let cli = Cli::parse();
    if let Err(e) = run(cli) {
        eprintln!("firmware-sim: error: {e:#}");
        std::process::exit(1);
    }
}

fn default_truth_path(cli: &Cli, name: &str) -> PathBuf {
    match &cli.out {
        Some(p) if p.as_os_str() != "-" => p.with_extension("truth.json"),
        _ => PathBuf::from(format!("{name}.truth.json")),
    }
}

fn run(cli: Cli) -> anyhow::Result<()> {
    if cli.out.is_none() && cli.iface.is_none() {
        bail!("nothing to do: give --out LOG or --iface IFACE (see --help)");
    }
    if !(cli.speed >= 0.0 && cli.speed.is_finite()) {
        bail!("--speed must be a number >= 0 (got {})", cli.speed);
    }
    let mut scenario = Scenario::load(&cli.scenario)?;
    if let Some(s) = cli.seed {
        scenario.seed = s;
    }
    let profile = match &cli.profile {
        Some(name) => Some(shimmy::profile::Profile::load(name)?),
        None => None,
    };
    let (db, bus) = match &profile {
        Some(p) => firmware_sim::bus::profile_bus(p, cli.dbc.as_deref())?,
        None => {
            let text = match &cli.dbc {
                Some(p) => shimmy_dbc_text(p)?,
                None => firmware_sim::bus::REFERENCE_DBC.to_string(),
            };
            (
                shimmy::dbc::Database::parse(&text).0,
                firmware_sim::bus::reference_bus()?,
            )
        }
    };
    let vehicle = scenario.vehicle_path(&cli.scenario);
    let (plant, vehicle_file) = match (&vehicle, &profile) {
        (None, Some(p)) => (
            ModelPlant::with_params(&scenario, p.vehicle.clone())?,
            Some(p.vehicle_source.clone()),
        ),
        _ => (
            ModelPlant::new(&scenario, vehicle.as_deref())?,
            vehicle.as_ref().map(|p| p.display().to_string()),
        ),
    };
    let info = RunInfo {
        scenario_file: Some(cli.scenario.display().to_string()),
        vehicle_file,
        profile: profile.as_ref().map(|p| p.name.clone()),
    };
    let mut sim = FirmwareSim::with_bus(&scenario, plant, db, &bus, info)?;
    let truth_path = cli
        .truth
        .clone()
        .unwrap_or_else(|| default_truth_path(&cli, &scenario.name));
    let wall = Instant::now();
    let mut log = match &cli.out {
        Some(out) => Some(LogOut::create(out)?),
        None => None,
    };
    if let Some(iface) = &cli.iface {
        sim.set_iface(iface);
        send_live(&mut sim, iface, cli.speed, log.as_mut())?;
    } else if let Some(log) = log.as_mut() {
        sim.set_iface("vcan0");
        for f in sim.by_ref() {
            log.write(&f)?;
        }
    }
    if let Some(log) = log {
        log.finish()?;
    }
    if let Some(e) = sim.error() {
        bail!("{e}");
    }
    let elapsed = wall.elapsed().as_secs_f64();
    let truth = sim.ground_truth();
    std::fs::write(&truth_path, truth.to_json() + "\n")
        .with_context(|| format!("cannot write ground truth {}", truth_path.display()))?;
    if !cli.quiet {
        if let Some(p) = &profile {
            eprintln!("firmware-sim: bus of vehicle profile {}", p.label());
        }
        eprintln!(
            "firmware-sim: {} ({}, seed {}): {:.1} s simulated in {:.2} s ({:.1}x real time), {:.2} km, {} frames",
            scenario.name,
            cli.scenario.display(),
            scenario.seed,
            truth.duration_s,
            elapsed,
            truth.duration_s / elapsed.max(1e-9),
            truth.distance_km,
            truth.frames_sent
        );
        let c = &truth.clearance;
        eprintln!(
            "  clearance L/R ({}): {:.4}/{:.4} mm at {:.3} km -> {:.4}/{:.4} mm at {:.3} km (wear {} mm per 1000 km, max {} mm)",
            c.mode,
            c.left_mm_start,
            c.right_mm_start,
            c.odometer_km_start,
            c.left_mm_end,
            c.right_mm_end,
            c.odometer_km_end,
            c.wear_mm_per_1000km,
            c.max_mm
        );
        for m in &truth.messages {
            eprintln!(
                "  {:<18} 0x{:03X}: sent {:>6}  dropped {}  bus-off {}  bad checksum {}  stuck {}",
                m.name, m.id, m.sent, m.dropped, m.bus_off, m.bad_checksum, m.stuck
            );
        }
        for e in &truth.events {
            eprintln!(
                "  brake #{}: t {:.2}–{:.2} s, {:.1} km/h at {:.2} g, clearance L/R {:.4}/{:.4} mm, contact L/R {:.0}/{:.0} %, steering-wheel shimmy {:.3}°",
                e.index,
                e.event.t_start_s,
                e.event.t_end_s,
                e.event.v0_kmh,
                e.event.decel_g,
                e.clearance_left_mm,
                e.clearance_right_mm,
                e.contact_fraction[0] * 100.0,
                e.contact_fraction[1] * 100.0,
                e.sw_amplitude_deg
            );
        }
        if truth.truncated {
            eprintln!("  WARNING: the run hit its time limit before the drive cycle ended");
        }
        eprintln!("  ground truth: {}", truth_path.display());
    }
    Ok(())
}

fn shimmy_dbc_text(p: &Path) -> anyhow::Result<String> {
    std::fs::read_to_string(p).with_context(|| format!("cannot read DBC {}", p.display()))
}

/// A candump -L log being written (or, for .mf4/.asc/.blf, shimmy's writer for that format).
struct LogOut {
    w: std::io::BufWriter<Box<dyn Write>>,
    path: PathBuf,
    other: Option<shimmy::source::writer::LogWriter>,
}

impl LogOut {
    fn create(out: &Path) -> anyhow::Result<LogOut> {
        use shimmy::source::writer::{LogWriter, OutFormat};
        if out.as_os_str() != "-" {
            if let Some(dir) = out.parent().filter(|d| !d.as_os_str().is_empty()) {
                std::fs::create_dir_all(dir)
                    .with_context(|| format!("cannot create directory {}", dir.display()))?;
            }
        }
        if out.as_os_str() != "-" && OutFormat::from_path(out)? != OutFormat::Candump {
            let w = LogWriter::create(out, Default::default())
                .with_context(|| format!("cannot create log {}", out.display()))?;
            return Ok(LogOut {
                w: std::io::BufWriter::new(Box::new(std::io::sink())),
                path: out.to_path_buf(),
                other: Some(w),
            });
        }
        let sink: Box<dyn Write> = if out.as_os_str() == "-" {
            Box::new(std::io::stdout().lock())
        } else {
            Box::new(
                std::fs::File::create(out)
                    .with_context(|| format!("cannot create log {}", out.display()))?,
            )
        };
        Ok(LogOut {
            w: std::io::BufWriter::with_capacity(1 << 16, sink),
            path: out.to_path_buf(),
            other: None,
        })
    }

    fn write(&mut self, f: &shimmy::wire::Frame) -> anyhow::Result<()> {
        if let Some(o) = &mut self.other {
            return o
                .write(f)
                .with_context(|| format!("cannot write log {}", self.path.display()));
        }
        shimmy::wire::candump::write_frame(&mut self.w, f)
            .with_context(|| format!("cannot write log {}", self.path.display()))
    }

    fn finish(mut self) -> anyhow::Result<()> {
        if let Some(o) = self.other.take() {
            o.finish()
                .with_context(|| format!("cannot write log {}", self.path.display()))?;
        }
        self.w
            .flush()
            .with_context(|| format!("cannot write log {}", self.path.display()))
    }
}

#[cfg(target_os = "linux")]
fn send_live<P: firmware_sim::plant::Plant>(
    sim: &mut FirmwareSim<P>,
    iface: &str,
    speed: f64,
    mut log: Option<&mut LogOut>,
) -> anyhow::Result<()> {
    let mut sink = shimmy::source::socketcan::LiveSink::open(iface)
        .with_context(|| format!("cannot open SocketCAN interface {iface}"))?;
    let start = Instant::now();
    let mut t_first: Option<i64> = None;
    for f in sim.by_ref() {
        let t0 = *t_first.get_or_insert(f.t_ns);
        if speed > 0.0 {
            let due = Duration::from_secs_f64((f.t_ns - t0) as f64 * 1e-9 / speed);
            let now = start.elapsed();
            if due > now {
                std::thread::sleep(due - now);
            }
        }
        sink.send(&f)
            .with_context(|| format!("cannot send on {iface}"))?;
        if let Some(log) = log.as_deref_mut() {
            log.write(&f)?;
        }
    }
    Ok(())
}

#[cfg(not(target_os = "linux"))]
fn send_live<P: firmware_sim::plant::Plant>(
    _sim: &mut FirmwareSim<P>,
    _iface: &str,
    _speed: f64,
    _log: Option<&mut LogOut>,
) -> anyhow::Result<()> {
    bail!("--iface needs Linux SocketCAN; use --out LOG on this system")
}
