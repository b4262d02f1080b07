//! Scenario files: what one firmware-sim run simulates, as TOML (`config/scenarios/*.toml`).
//!
//! A scenario names the vehicle (a `VehicleParams` TOML file, MODEL.md §9 when absent), the true
//! joint clearance (left/right, single or dual, optionally growing with distance), the drive
//! cycle (cruise segments, braking events, re-acceleration), the excitation (MODEL.md §7 wheel
//! unbalance and road noise, driver steering), the sensors (noise, send-period jitter) and
//! optional faults. Every table rejects unknown keys, so a typo is an error that names the key
//! and its line instead of a silently ignored setting.
//!
//! This module only describes and validates; it does not simulate (see [`crate::sim`]).
//! Units follow the edge convention: names carry `_kmh`, `_mm`, `_g`, `_deg`, `_s`.

use std::path::{Path, PathBuf};

use anyhow::{bail, Context};
use serde::{Deserialize, Serialize};

/// One scenario file.
#[derive(Clone, Debug, Deserialize, Serialize, PartialEq)]
#[serde(deny_unknown_fields)]
pub struct Scenario {
    /// Short name (defaults to the file stem).
    #[serde(default)]
    pub name: String,
    /// One line for humans.
    #[serde(default)]
    pub description: String,
    /// Seed of every random choice (unbalance phases, road noise, sensor noise, jitter, faults).
    pub seed: u64,
    /// Vehicle parameters file (a `shimmy::model::VehicleParams` TOML), relative to the
    /// scenario file. Absent: the MODEL.md §9 defaults.
    #[serde(default)]
    pub vehicle: Option<PathBuf>,
    /// Model integration step (s); MODEL.md §10 uses 1e-4.
    #[serde(default = "default_step_s")]
    pub step_s: f64,
    /// Integration scheme of the model (`shimmy::model::Integrator`, snake_case name).
    /// Default `rk4_adaptive`: MODEL.md §10's RK4 on the `step_s` grid in and near joint
    /// contact, free-flight steps merged (as accurate as `rk4` against an h = 1e-5 s reference,
    /// docs/BENCHMARKS.md "Shimmy model"; 2–3× the real-time margin of issue 4's 100× target).
    /// `rk4_warm_slip` is MODEL.md §10 as written to 1e-10 slip. Any scheme is deterministic;
    /// logs are byte-identical only for the same scheme.
    #[serde(default = "default_integrator")]
    pub integrator: shimmy::model::Integrator,
    /// How often the driver updates the longitudinal demand, the ECUs sample the plant and
    /// joint contact is tallied (s); the plant advances this far per update in one
    /// `Plant::advance` call (so a model integrator that merges grid steps can). A multiple of
    /// `step_s` that divides the 1 ms ground-truth trace interval. Absent: the trace interval
    /// (1 ms with the default `step_s`; the fastest ECU, the 100 Hz steering angle sensor, is
    /// sampled at most 1 ms late). `control_period_s = step_s` updates every model step.
    #[serde(default)]
    pub control_period_s: Option<f64>,
    /// Start of the log as Unix time (s); frame timestamps are this plus simulated time.
    #[serde(default = "default_start_unix_s")]
    pub start_unix_s: f64,
    pub clearance: Clearance,
    pub drive: Drive,
    #[serde(default)]
    pub excitation: Excitation,
    #[serde(default)]
    pub driver: Driver,
    #[serde(default)]
    pub sensors: Sensors,
    #[serde(default)]
    pub faults: Faults,
    /// The driver's hands on the steering wheel (MODEL.md §15 column only): the prior from
    /// which each leg of the drive (from the start or a pull-away to the next stop, so each
    /// braking event) draws off / light / firm grip and its values (docs/COLUMN.md). Absent:
    /// the vehicle file's hands throughout.
    #[serde(default)]
    pub hands: Option<shimmy::observer::simulate::HandsPrior>,
}

fn default_step_s() -> f64 {
    1e-4
}
fn default_integrator() -> shimmy::model::Integrator {
    shimmy::model::Integrator::Rk4Adaptive
}
fn default_start_unix_s() -> f64 {
    // 2026-01-01T00:00:00Z: a fixed epoch so logs are reproducible.
    1_767_225_600.0
}

/// True clearance of the two arm/tie-rod joints (MODEL.md §4), and how it grows with wear.
///
/// Wear law: every worn joint's clearance grows linearly with the distance driven,
/// `c(d) = min(max_mm, c_start + wear_mm_per_1000km · d / 1000 km)`, where `d` is the distance
/// since the start of the run. Real joints wear by roughly 0.001–0.01 mm per 1000 km; a short
/// test drive shows wear only with a much larger rate, which is allowed (up to
/// [`MAX_WEAR_MM_PER_1000KM`]). `odometer_km` places the run on the car's life (reported in the
/// ground truth with every clearance, so wear tracking can be scored against the odometer); the
/// clearance at that reading is `left_mm` / `right_mm`. For a car with new-joint clearance `c0`
/// at odometer 0, set `left_mm = c0 + rate · odometer_km / 1000`.
#[derive(Clone, Debug, Deserialize, Serialize, PartialEq)]
#[serde(deny_unknown_fields)]
pub struct Clearance {
    /// `dual` (both joints worn) or `single` (left joint worn, right joint ideal).
    #[serde(default)]
    pub mode: ClearanceMode,
    /// Radial clearance of the left joint (mm) at the start of the run. With `dual` and no
    /// `right_mm`, the clearance of both joints.
    pub left_mm: f64,
    /// Radial clearance of the right joint (mm) at the start, when it differs from the left
    /// (unequal wear). Default: `left_mm`. Not allowed with `single` (the right joint is ideal).
    #[serde(default)]
    pub right_mm: Option<f64>,
    /// Wear: clearance growth of every worn joint per 1000 km driven (mm). 0 = no wear.
    #[serde(default)]
    pub wear_mm_per_1000km: f64,
    /// Wear stops when a joint reaches this clearance (mm). Default [`MAX_CLEARANCE_MM`].
    #[serde(default)]
    pub max_mm: Option<f64>,
    /// Odometer reading at the start of the run (km).
    #[serde(default)]
    pub odometer_km: f64,
}

/// Largest clearance a scenario accepts (mm); also the default wear cap.
pub const MAX_CLEARANCE_MM: f64 = 2.0;
/// Largest wear rate a scenario accepts (mm per 1000 km): 0.1 mm per 1 km, enough for a short
/// test drive to double a worn joint's clearance.
pub const MAX_WEAR_MM_PER_1000KM: f64 = 100.0;

impl Clearance {
    /// Clearances (left, right) in mm after driving `distance_m` since the start (the wear law
    /// above). The right joint is 0 with `single` (ideal, no wear).
    pub fn at_distance_mm(&self, distance_m: f64) -> (f64, f64) {
        let cap = self.max_mm.unwrap_or(MAX_CLEARANCE_MM);
        let grow = self.wear_mm_per_1000km * distance_m.max(0.0) * 1e-6;
        let left = (self.left_mm + grow).min(cap).max(self.left_mm);
        let right = match self.mode {
            ClearanceMode::Single => 0.0,
            ClearanceMode::Dual => {
                let r0 = self.right_mm.unwrap_or(self.left_mm);
                (r0 + grow).min(cap).max(r0)
            }
        };
        (left, right)
    }
}

#[derive(Clone, Copy, Debug, Default, Deserialize, Serialize, PartialEq, Eq)]
#[serde(rename_all = "snake_case")]
pub enum ClearanceMode {
    #[default]
    Dual,
    Single,
}

/// The drive cycle: a start speed and a list of segments run in order.
#[derive(Clone, Debug, Deserialize, Serialize, PartialEq)]
#[serde(deny_unknown_fields)]
pub struct Drive {
    /// Speed at t = 0 (km/h).
    pub start_speed_kmh: f64,
    /// Acceleration used to reach a cruise speed above the current one (g). Drivers re-accelerate
    /// at 0.1–0.25 g.
    #[serde(default = "default_accel_g")]
    pub accel_g: f64,
    /// Deceleration used to reach a cruise speed below the current one without a braking event
    /// (engine braking / light pedal, g).
    #[serde(default = "default_coast_g")]
    pub coast_g: f64,
    #[serde(rename = "segment")]
    pub segments: Vec<Segment>,
}

fn default_accel_g() -> f64 {
    0.15
}
fn default_coast_g() -> f64 {
    0.05
}

/// One drive-cycle segment.
#[derive(Clone, Debug, Deserialize, Serialize, PartialEq)]
#[serde(tag = "kind", rename_all = "snake_case", deny_unknown_fields)]
pub enum Segment {
    /// Reach `speed_kmh` (accelerating at `drive.accel_g` or coasting at `drive.coast_g`), then
    /// hold it for `duration_s`.
    Cruise { speed_kmh: f64, duration_s: f64 },
    /// Lift off without braking: the car slows at `decel_g` (engine drag and rolling
    /// resistance, 0.02–0.15 g) for `duration_s`, brake pedal released. Before a braking event
    /// it replaces the steady cruise the event would otherwise follow.
    Coast { duration_s: f64, decel_g: f64 },
    /// A braking event from the current speed.
    Brake(Brake),
    /// Stand still for `duration_s` (only valid at zero speed).
    Stand { duration_s: f64 },
}

/// A braking event: ramp-in to `decel_g`, hold, ramp-out; either for `duration_s` or to a stop.
#[derive(Clone, Debug, Deserialize, Serialize, PartialEq)]
#[serde(deny_unknown_fields)]
pub struct Brake {
    /// Plateau deceleration (g), 0.3–0.8 for the events the monitor analyses.
    pub decel_g: f64,
    /// Ramp-in time from 0 to the plateau (s); MODEL.md §6 uses 0.3 s.
    #[serde(default = "default_ramp_s")]
    pub ramp_in_s: f64,
    /// Ramp-out time from the plateau back to 0 (s), for events that do not stop.
    #[serde(default = "default_ramp_s")]
    pub ramp_out_s: f64,
    /// Total event length including ramps (s). Absent: brake to a stop.
    #[serde(default)]
    pub duration_s: Option<f64>,
    /// After a stop, how long the driver keeps the pedal pressed at standstill (s).
    #[serde(default = "default_hold_s")]
    pub hold_s: f64,
    /// The road's roughness from brake onset to the pedal's release, relative to the
    /// scenario's road noise (MODEL.md §7): a change of surface between the cruise and the
    /// braking. 1 = the same road.
    #[serde(default = "default_road_noise_scale")]
    pub road_noise_scale: f64,
    /// The driver comes out of a curve: the steering-wheel angle (deg, + = left) turned in
    /// over the segment before the event and held at brake onset, then returned to straight
    /// ahead over `turn_unwind_s`. It reaches the angle sensor and, on a car with a torsion
    /// bar, the torque sensor as the driver's holding torque (`driver.turn_torque_nm_per_deg`);
    /// the model itself runs straight (MODEL.md §14). 0 = straight.
    #[serde(default)]
    pub turn_deg: f64,
    /// Time to return the wheel from `turn_deg` to straight ahead after brake onset (s).
    #[serde(default = "default_turn_unwind_s")]
    pub turn_unwind_s: f64,
}

fn default_road_noise_scale() -> f64 {
    1.0
}
fn default_turn_unwind_s() -> f64 {
    1.0
}

fn default_ramp_s() -> f64 {
    0.3
}
fn default_hold_s() -> f64 {
    1.0
}

/// Excitation of the steering system (MODEL.md §7).
#[derive(Clone, Debug, Deserialize, Serialize, PartialEq)]
#[serde(deny_unknown_fields)]
pub struct Excitation {
    /// Residual wheel unbalance per front wheel (kg·m); MODEL.md §7 uses 2e-3.
    #[serde(default = "default_unbalance")]
    pub unbalance_kgm: f64,
    /// Road-noise steer moment σ at 55 km/h (N·m); MODEL.md §7 uses 0.2. 0 disables it.
    #[serde(default = "default_road_noise")]
    pub road_noise_nm: f64,
    /// What happens to the difference of the two wheels' unbalance phases between braking
    /// events: `"none"` keeps it for the whole drive (the model's wheels roll together, as on
    /// a straight road with equal tyres); `"per_stop"` draws the right wheel's phase anew at
    /// every stop, as a turn at a junction would change it.
    #[serde(default)]
    pub phase_change: PhaseChange,
}

/// See [`Excitation::phase_change`].
#[derive(Clone, Copy, Debug, Default, Deserialize, Serialize, PartialEq, Eq)]
#[serde(rename_all = "snake_case")]
pub enum PhaseChange {
    #[default]
    None,
    PerStop,
}

fn default_unbalance() -> f64 {
    2e-3
}
fn default_road_noise() -> f64 {
    0.2
}

impl Default for Excitation {
    fn default() -> Self {
        Excitation {
            unbalance_kgm: default_unbalance(),
            road_noise_nm: default_road_noise(),
            phase_change: PhaseChange::None,
        }
    }
}

/// Small, slow driver steering inputs (lane keeping), added at the steering wheel.
#[derive(Clone, Debug, Deserialize, Serialize, PartialEq)]
#[serde(deny_unknown_fields)]
pub struct Driver {
    /// RMS of the lane-keeping steering-wheel angle (deg).
    #[serde(default = "default_driver_rms")]
    pub steer_rms_deg: f64,
    /// Correlation time of the lane-keeping input (s): larger = slower corrections.
    #[serde(default = "default_driver_tau")]
    pub steer_tau_s: f64,
    /// Constant steering-wheel offset (deg): road crown, slight misalignment.
    #[serde(default)]
    pub steer_offset_deg: f64,
    /// The torque the driver holds a curve with, per degree of steering-wheel angle (N·m/deg),
    /// seen by the torsion bar's sensor during a braking event's `turn_deg`. Passenger cars
    /// need about 1–3 N·m at 0.1–0.3 g of lateral acceleration with EPS assist.
    #[serde(default = "default_turn_torque")]
    pub turn_torque_nm_per_deg: f64,
}

fn default_turn_torque() -> f64 {
    0.08
}

fn default_driver_rms() -> f64 {
    1.0
}
fn default_driver_tau() -> f64 {
    2.0
}

impl Default for Driver {
    fn default() -> Self {
        Driver {
            steer_rms_deg: default_driver_rms(),
            steer_tau_s: default_driver_tau(),
            steer_offset_deg: 0.0,
            turn_torque_nm_per_deg: default_turn_torque(),
        }
    }
}

/// Sensor and ECU imperfections of the emulated bus.
#[derive(Clone, Debug, Deserialize, Serialize, PartialEq)]
#[serde(deny_unknown_fields)]
pub struct Sensors {
    /// White noise on the steering-wheel angle before quantisation (deg RMS).
    #[serde(default = "default_sas_noise")]
    pub steer_noise_deg: f64,
    /// White noise on the brake pressure (bar RMS).
    #[serde(default = "default_pressure_noise")]
    pub brake_pressure_noise_bar: f64,
    /// Master-cylinder pressure per unit of demanded deceleration (bar per g).
    #[serde(default = "default_bar_per_g")]
    pub brake_bar_per_g: f64,
    /// White noise on each wheel speed (km/h RMS).
    #[serde(default = "default_wheel_noise")]
    pub wheel_speed_noise_kmh: f64,
    /// Tyre rolling-radius tolerance: each wheel's scale error is drawn uniformly in ±this (%).
    #[serde(default = "default_radius_tol")]
    pub wheel_radius_tolerance_pct: f64,
    /// White noise on the longitudinal and lateral accelerations (m/s² RMS).
    #[serde(default = "default_accel_noise")]
    pub accel_noise_mps2: f64,
    /// White noise on the yaw rate (deg/s RMS), on buses that carry one.
    #[serde(default = "default_yaw_noise")]
    pub yaw_rate_noise_deg_s: f64,
    /// White noise on the steering (torsion-bar) torque (N·m RMS), on buses that carry one.
    #[serde(default = "default_torque_noise")]
    pub steer_torque_noise_nm: f64,
    /// Send-period jitter: each frame leaves at its nominal time plus a Gaussian offset with this
    /// standard deviation (ms), clipped to a quarter period. A bus description's per-message
    /// `jitter_ms` replaces it for that message.
    #[serde(default = "default_jitter_ms")]
    pub jitter_ms: f64,
}

fn default_sas_noise() -> f64 {
    0.01
}
fn default_pressure_noise() -> f64 {
    0.2
}
fn default_bar_per_g() -> f64 {
    90.0
}
fn default_wheel_noise() -> f64 {
    0.03
}
fn default_radius_tol() -> f64 {
    0.3
}
fn default_accel_noise() -> f64 {
    0.05
}
fn default_jitter_ms() -> f64 {
    0.2
}
fn default_yaw_noise() -> f64 {
    0.05
}
fn default_torque_noise() -> f64 {
    0.02
}

impl Default for Sensors {
    fn default() -> Self {
        Sensors {
            steer_noise_deg: default_sas_noise(),
            brake_pressure_noise_bar: default_pressure_noise(),
            brake_bar_per_g: default_bar_per_g(),
            wheel_speed_noise_kmh: default_wheel_noise(),
            wheel_radius_tolerance_pct: default_radius_tol(),
            accel_noise_mps2: default_accel_noise(),
            yaw_rate_noise_deg_s: default_yaw_noise(),
            steer_torque_noise_nm: default_torque_noise(),
            jitter_ms: default_jitter_ms(),
        }
    }
}

/// Optional faults for robustness tests. All off by default.
#[derive(Clone, Debug, Default, Deserialize, Serialize, PartialEq)]
#[serde(deny_unknown_fields)]
pub struct Faults {
    /// Probability that any one frame is lost (never reaches the bus).
    #[serde(default)]
    pub drop_probability: f64,
    /// Probability that a frame carrying a checksum is sent with a wrong one.
    #[serde(default)]
    pub bad_checksum_probability: f64,
    /// Stuck sensors: the message keeps being sent (counter and checksum valid) but its values
    /// freeze at what they were when the fault began.
    #[serde(default)]
    pub stuck: Vec<StuckFault>,
    /// Bus-off periods: the named ECU (or every ECU) sends nothing.
    #[serde(default)]
    pub bus_off: Vec<BusOffFault>,
}

#[derive(Clone, Debug, Deserialize, Serialize, PartialEq)]
#[serde(deny_unknown_fields)]
pub struct StuckFault {
    /// Message name on the emulated bus (its DBC name, or a raw message's label).
    pub message: String,
    pub start_s: f64,
    pub duration_s: f64,
}

#[derive(Clone, Debug, Deserialize, Serialize, PartialEq)]
#[serde(deny_unknown_fields)]
pub struct BusOffFault {
    /// Message name on the emulated bus; absent: the whole bus.
    #[serde(default)]
    pub message: Option<String>,
    pub start_s: f64,
    pub duration_s: f64,
}

impl Scenario {
    /// Parse and validate scenario text. `origin` names the source in error messages.
    pub fn parse(text: &str, origin: &str) -> anyhow::Result<Scenario> {
        let sc: Scenario =
            toml::from_str(text).with_context(|| format!("invalid scenario {origin}"))?;
        sc.validate()
            .with_context(|| format!("invalid scenario {origin}"))?;
        Ok(sc)
    }

    /// Read, parse and validate a scenario file; the name defaults to the file stem.
    pub fn load(path: &Path) -> anyhow::Result<Scenario> {
        let text = std::fs::read_to_string(path)
            .with_context(|| format!("cannot read scenario {}", path.display()))?;
        let mut sc = Scenario::parse(&text, &path.display().to_string())?;
        if sc.name.is_empty() {
            sc.name = path
                .file_stem()
                .map(|s| s.to_string_lossy().into_owned())
                .unwrap_or_default();
        }
        Ok(sc)
    }

    /// The vehicle file resolved against the scenario file's directory.
    pub fn vehicle_path(&self, scenario_path: &Path) -> Option<PathBuf> {
        self.vehicle.as_ref().map(|v| {
            if v.is_absolute() {
                v.clone()
            } else {
                scenario_path
                    .parent()
                    .unwrap_or_else(|| Path::new("."))
                    .join(v)
            }
        })
    }

    /// Right clearance (mm) at the start: `right_mm`, else `left_mm`; 0 for `single`.
    pub fn right_clearance_mm(&self) -> f64 {
        self.clearance.at_distance_mm(0.0).1
    }

    /// Model steps per control update (see `control_period_s`): the trace interval's when the
    /// key is absent.
    pub fn control_steps(&self) -> u64 {
        match self.control_period_s {
            Some(cp) => (cp / self.step_s).round().max(1.0) as u64,
            None => self.trace_steps(),
        }
    }

    /// Model steps per sample of the 1 kHz ground-truth δ_sw trace.
    pub fn trace_steps(&self) -> u64 {
        ((1.0 / crate::sim::TRACE_HZ) / self.step_s)
            .round()
            .max(1.0) as u64
    }

    /// Check ranges and cross-field rules; the error names the key.
    pub fn validate(&self) -> anyhow::Result<()> {
        fn range(key: &str, v: f64, lo: f64, hi: f64) -> anyhow::Result<()> {
            if !(v.is_finite() && v >= lo && v <= hi) {
                bail!("{key} = {v} is outside [{lo}, {hi}]");
            }
            Ok(())
        }
        fn positive(key: &str, v: f64, hi: f64) -> anyhow::Result<()> {
            if !(v.is_finite() && v > 0.0 && v <= hi) {
                bail!("{key} = {v} must be > 0 and <= {hi}");
            }
            Ok(())
        }
        range("step_s", self.step_s, 1e-6, 1e-3)?;
        range("start_unix_s", self.start_unix_s, 0.0, 4e9)?;
        if let Some(cp) = self.control_period_s {
            range("control_period_s", cp, self.step_s, 1e-3)?;
            let k = self.control_steps();
            if (k as f64 * self.step_s - cp).abs() > 1e-6 * cp
                || !self.trace_steps().is_multiple_of(k)
            {
                bail!(
                    "control_period_s = {cp} must be a whole number of model steps (step_s = {}) \
                     dividing the 1 ms trace interval, e.g. {} or {}",
                    self.step_s,
                    self.step_s,
                    self.trace_steps() as f64 * self.step_s
                );
            }
        }
        let c = &self.clearance;
        // The model needs a clearance > 0 (MODEL.md §4); a new joint has about 0.03 mm.
        positive("clearance.left_mm", c.left_mm, MAX_CLEARANCE_MM)?;
        if let Some(r) = c.right_mm {
            if c.mode == ClearanceMode::Single {
                bail!(
                    "clearance.right_mm = {r} with mode = \"single\": the right joint is ideal \
                     there; remove right_mm or use mode = \"dual\""
                );
            }
            positive("clearance.right_mm", r, MAX_CLEARANCE_MM)?;
        }
        range(
            "clearance.wear_mm_per_1000km",
            c.wear_mm_per_1000km,
            0.0,
            MAX_WEAR_MM_PER_1000KM,
        )?;
        range("clearance.odometer_km", c.odometer_km, 0.0, 5e6)?;
        if let Some(cap) = c.max_mm {
            positive("clearance.max_mm", cap, MAX_CLEARANCE_MM)?;
            let start = c.left_mm.max(self.right_clearance_mm());
            if cap < start {
                bail!(
                    "clearance.max_mm = {cap} is below the starting clearance {start} mm \
                     (left_mm / right_mm)"
                );
            }
        }
        let d = &self.drive;
        range("drive.start_speed_kmh", d.start_speed_kmh, 0.0, 250.0)?;
        range("drive.accel_g", d.accel_g, 0.01, 0.6)?;
        range("drive.coast_g", d.coast_g, 0.01, 0.3)?;
        if d.segments.is_empty() {
            bail!("drive.segment: at least one segment is needed");
        }
        let mut v_kmh = d.start_speed_kmh;
        for (i, s) in d.segments.iter().enumerate() {
            let key = |f: &str| format!("drive.segment[{i}].{f}");
            match s {
                Segment::Cruise {
                    speed_kmh,
                    duration_s,
                } => {
                    range(&key("speed_kmh"), *speed_kmh, 0.0, 250.0)?;
                    range(&key("duration_s"), *duration_s, 0.0, 3600.0)?;
                    v_kmh = *speed_kmh;
                }
                Segment::Brake(b) => {
                    range(&key("decel_g"), b.decel_g, 0.05, 1.0)?;
                    range(&key("ramp_in_s"), b.ramp_in_s, 0.0, 5.0)?;
                    range(&key("ramp_out_s"), b.ramp_out_s, 0.0, 5.0)?;
                    range(&key("hold_s"), b.hold_s, 0.0, 60.0)?;
                    range(&key("road_noise_scale"), b.road_noise_scale, 0.05, 20.0)?;
                    range(&key("turn_deg"), b.turn_deg, -180.0, 180.0)?;
                    range(&key("turn_unwind_s"), b.turn_unwind_s, 0.05, 30.0)?;
                    if let Some(dur) = b.duration_s {
                        range(&key("duration_s"), dur, 0.0, 600.0)?;
                        if dur < b.ramp_in_s + b.ramp_out_s {
                            bail!(
                                "{} = {dur} is shorter than ramp_in_s + ramp_out_s = {}",
                                key("duration_s"),
                                b.ramp_in_s + b.ramp_out_s
                            );
                        }
                    } else {
                        v_kmh = 0.0;
                    }
                    if v_kmh <= 0.0 && b.duration_s.is_some() {
                        // Braking at standstill is allowed (it just holds the car).
                    }
                }
                Segment::Coast {
                    duration_s,
                    decel_g,
                } => {
                    range(&key("duration_s"), *duration_s, 0.0, 3600.0)?;
                    range(&key("decel_g"), *decel_g, 0.0, 0.3)?;
                    v_kmh = (v_kmh - decel_g * crate::drive::G * duration_s * 3.6).max(0.0);
                }
                Segment::Stand { duration_s } => {
                    range(&key("duration_s"), *duration_s, 0.0, 3600.0)?;
                    if v_kmh > 0.0 {
                        bail!(
                            "{}: `stand` needs the car stopped, but the speed before it is {v_kmh} km/h \
                             (add a braking event to a stop, or a cruise at 0 km/h)",
                            key("kind")
                        );
                    }
                }
            }
        }
        let x = &self.excitation;
        range("excitation.unbalance_kgm", x.unbalance_kgm, 0.0, 0.05)?;
        range("excitation.road_noise_nm", x.road_noise_nm, 0.0, 20.0)?;
        range("driver.steer_rms_deg", self.driver.steer_rms_deg, 0.0, 30.0)?;
        range("driver.steer_tau_s", self.driver.steer_tau_s, 0.05, 100.0)?;
        range(
            "driver.turn_torque_nm_per_deg",
            self.driver.turn_torque_nm_per_deg,
            0.0,
            1.0,
        )?;
        range(
            "driver.steer_offset_deg",
            self.driver.steer_offset_deg,
            -90.0,
            90.0,
        )?;
        let s = &self.sensors;
        range("sensors.steer_noise_deg", s.steer_noise_deg, 0.0, 10.0)?;
        range(
            "sensors.brake_pressure_noise_bar",
            s.brake_pressure_noise_bar,
            0.0,
            50.0,
        )?;
        range("sensors.brake_bar_per_g", s.brake_bar_per_g, 1.0, 300.0)?;
        range(
            "sensors.wheel_speed_noise_kmh",
            s.wheel_speed_noise_kmh,
            0.0,
            10.0,
        )?;
        range(
            "sensors.wheel_radius_tolerance_pct",
            s.wheel_radius_tolerance_pct,
            0.0,
            5.0,
        )?;
        range("sensors.accel_noise_mps2", s.accel_noise_mps2, 0.0, 10.0)?;
        range(
            "sensors.yaw_rate_noise_deg_s",
            s.yaw_rate_noise_deg_s,
            0.0,
            10.0,
        )?;
        range(
            "sensors.steer_torque_noise_nm",
            s.steer_torque_noise_nm,
            0.0,
            10.0,
        )?;
        range("sensors.jitter_ms", s.jitter_ms, 0.0, 5.0)?;
        let f = &self.faults;
        range("faults.drop_probability", f.drop_probability, 0.0, 1.0)?;
        range(
            "faults.bad_checksum_probability",
            f.bad_checksum_probability,
            0.0,
            1.0,
        )?;
        for (i, st) in f.stuck.iter().enumerate() {
            range(&format!("faults.stuck[{i}].start_s"), st.start_s, 0.0, 1e6)?;
            range(
                &format!("faults.stuck[{i}].duration_s"),
                st.duration_s,
                0.0,
                1e6,
            )?;
        }
        for (i, b) in f.bus_off.iter().enumerate() {
            range(&format!("faults.bus_off[{i}].start_s"), b.start_s, 0.0, 1e6)?;
            range(
                &format!("faults.bus_off[{i}].duration_s"),
                b.duration_s,
                0.0,
                1e6,
            )?;
        }
        if let Some(h) = &self.hands {
            h.validate()?;
        }
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    const MINIMAL: &str = r#"
seed = 7
[clearance]
left_mm = 0.2
[drive]
start_speed_kmh = 55
[[drive.segment]]
kind = "cruise"
speed_kmh = 55
duration_s = 1.0
[[drive.segment]]
kind = "brake"
decel_g = 0.5
"#;

    #[test]
    fn minimal_scenario_gets_model_defaults() {
        let sc = Scenario::parse(MINIMAL, "test").unwrap();
        assert_eq!(sc.seed, 7);
        assert_eq!(sc.step_s, 1e-4);
        assert_eq!(sc.clearance.mode, ClearanceMode::Dual);
        assert_eq!(sc.right_clearance_mm(), 0.2);
        assert_eq!(sc.excitation.unbalance_kgm, 2e-3);
        match &sc.drive.segments[1] {
            Segment::Brake(b) => {
                assert_eq!(b.ramp_in_s, 0.3);
                assert!(b.duration_s.is_none());
            }
            other => panic!("expected brake, got {other:?}"),
        }
    }

    #[test]
    fn unknown_key_is_named() {
        let text = MINIMAL.replace("left_mm = 0.2", "left_mm = 0.2\nleft_mn = 0.3");
        let err = format!("{:#}", Scenario::parse(&text, "test").unwrap_err());
        assert!(err.contains("left_mn"), "{err}");
    }

    #[test]
    fn unknown_key_inside_segment_is_named() {
        let text = MINIMAL.replace("decel_g = 0.5", "decel_g = 0.5\ndecel = 0.4");
        let err = format!("{:#}", Scenario::parse(&text, "test").unwrap_err());
        assert!(err.contains("decel"), "{err}");
    }

    #[test]
    fn unknown_segment_kind_is_named() {
        let text = MINIMAL.replace("kind = \"brake\"", "kind = \"brak\"");
        let err = format!("{:#}", Scenario::parse(&text, "test").unwrap_err());
        assert!(err.contains("brak"), "{err}");
    }

    #[test]
    fn out_of_range_value_names_key() {
        let text = MINIMAL.replace("decel_g = 0.5", "decel_g = 3.0");
        let err = format!("{:#}", Scenario::parse(&text, "test").unwrap_err());
        assert!(err.contains("drive.segment[1].decel_g"), "{err}");
    }

    #[test]
    fn stand_while_moving_is_rejected() {
        let text = MINIMAL.replace(
            "kind = \"brake\"\ndecel_g = 0.5",
            "kind = \"stand\"\nduration_s = 1.0",
        );
        let err = format!("{:#}", Scenario::parse(&text, "test").unwrap_err());
        assert!(err.contains("stand"), "{err}");
    }

    fn err(text: &str) -> String {
        format!("{:#}", Scenario::parse(text, "test").unwrap_err())
    }

    /// The `[hands]` prior (docs/COLUMN.md) as `firmware-sim fleet` writes it parses back, and
    /// a prior that cannot be drawn from is refused with the field named.
    #[test]
    fn the_hands_prior_round_trips_and_bad_ones_name_their_field() {
        let prior = shimmy::observer::simulate::HandsPrior::default();
        let text = format!("{MINIMAL}{}", crate::fleet::hands_section(&prior).unwrap());
        assert_eq!(Scenario::parse(&text, "test").unwrap().hands, Some(prior));
        let mut bad = prior;
        bad.off.probability = 0.5;
        let text = format!("{MINIMAL}{}", crate::fleet::hands_section(&bad).unwrap());
        assert!(err(&text).contains("must sum to 1"), "{}", err(&text));
        let mut bad = prior;
        bad.firm.damping_nms_per_rad = (2.0, -1.0);
        let text = format!("{MINIMAL}{}", crate::fleet::hands_section(&bad).unwrap());
        assert!(
            err(&text).contains("hands.firm.damping_nms_per_rad"),
            "{}",
            err(&text)
        );
        assert!(err(&format!("{MINIMAL}\n[hands]\nsometimes = 1\n")).contains("sometimes"));
    }

    #[test]
    fn invalid_clearance_and_wear_values_name_their_key() {
        let with = |extra: &str| MINIMAL.replace("left_mm = 0.2", extra);
        let e = err(&with("left_mm = 0.2\nwear_mm_per_1000km = -1.0"));
        assert!(e.contains("clearance.wear_mm_per_1000km = -1"), "{e}");
        let e = err(&with("left_mm = 0.0"));
        assert!(
            e.contains("clearance.left_mm = 0") && e.contains("> 0"),
            "{e}"
        );
        let e = err(&with("left_mm = -0.1"));
        assert!(e.contains("clearance.left_mm"), "{e}");
        let e = err(&with("left_mm = 0.2\nright_mm = 0.0"));
        assert!(e.contains("clearance.right_mm = 0"), "{e}");
        let e = err(&with("left_mm = 0.2\nmax_mm = 0.0"));
        assert!(e.contains("clearance.max_mm"), "{e}");
        let e = err(&with("left_mm = 0.2\nright_mm = 0.3\nmax_mm = 0.25"));
        assert!(
            e.contains("clearance.max_mm = 0.25") && e.contains("0.3"),
            "{e}"
        );
        let e = err(&with("left_mm = 0.2\nodometer_km = -5.0"));
        assert!(e.contains("clearance.odometer_km"), "{e}");
        let e = err(&with("mode = \"single\"\nleft_mm = 0.2\nright_mm = 0.1"));
        assert!(
            e.contains("clearance.right_mm") && e.contains("single"),
            "{e}"
        );
        // The key of the old, always-refused wear option is now an unknown key, named as such.
        let e = err(&with("left_mm = 0.2\ngrowth_mm_per_km = 0.1"));
        assert!(e.contains("growth_mm_per_km"), "{e}");
    }

    #[test]
    fn wear_law_is_linear_in_distance_and_capped() {
        let text = MINIMAL.replace(
            "left_mm = 0.2",
            "left_mm = 0.1\nright_mm = 0.2\nwear_mm_per_1000km = 50.0\nmax_mm = 0.25",
        );
        let c = Scenario::parse(&text, "test").unwrap().clearance;
        assert_eq!(c.at_distance_mm(0.0), (0.1, 0.2));
        let (l, r) = c.at_distance_mm(500.0); // 0.5 km at 50 mm per 1000 km: +0.025 mm
        assert!(
            (l - 0.125).abs() < 1e-12 && (r - 0.225).abs() < 1e-12,
            "{l} {r}"
        );
        let (l, r) = c.at_distance_mm(2000.0);
        assert!((l - 0.2).abs() < 1e-12 && r == 0.25, "{l} {r}");
        // Single: only the (left) worn joint grows; the ideal right joint stays 0.
        let single = MINIMAL.replace(
            "left_mm = 0.2",
            "mode = \"single\"\nleft_mm = 0.1\nwear_mm_per_1000km = 50.0",
        );
        let c = Scenario::parse(&single, "test").unwrap().clearance;
        let (l, r) = c.at_distance_mm(1000.0);
        assert!((l - 0.15).abs() < 1e-12 && r == 0.0, "{l} {r}");
    }

    #[test]
    fn integrator_defaults_to_adaptive_rk4_and_unknown_names_are_named() {
        use shimmy::model::Integrator;
        let sc = Scenario::parse(MINIMAL, "test").unwrap();
        assert_eq!(sc.integrator, Integrator::Rk4Adaptive);
        let sc = Scenario::parse(&format!("integrator = \"rk4\"\n{MINIMAL}"), "test").unwrap();
        assert_eq!(sc.integrator, Integrator::Rk4);
        let e = err(&format!("integrator = \"rk5\"\n{MINIMAL}"));
        assert!(e.contains("rk5"), "{e}");
    }

    #[test]
    fn control_period_must_be_whole_steps_dividing_the_trace_interval() {
        let with = |cp: &str| format!("control_period_s = {cp}\n{MINIMAL}");
        let sc = Scenario::parse(&with("5e-4"), "test").unwrap();
        assert_eq!(sc.control_steps(), 5);
        // Absent: the 1 ms trace interval, 10 steps of the default 1e-4 s grid.
        assert_eq!(
            Scenario::parse(MINIMAL, "test").unwrap().control_steps(),
            10
        );
        let fine = format!("step_s = 1e-5\n{MINIMAL}");
        assert_eq!(Scenario::parse(&fine, "test").unwrap().control_steps(), 100);
        for bad in ["1.5e-4", "3e-4", "2e-3", "5e-5", "-1e-3"] {
            let e = err(&with(bad));
            assert!(e.contains("control_period_s"), "{bad}: {e}");
        }
    }

    #[test]
    fn single_clearance_has_ideal_right_joint() {
        let text = MINIMAL.replace("left_mm = 0.2", "mode = \"single\"\nleft_mm = 0.2");
        let sc = Scenario::parse(&text, "test").unwrap();
        assert_eq!(sc.right_clearance_mm(), 0.0);
    }
}
