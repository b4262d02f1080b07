//! The ground-truth sidecar (JSON) written next to every firmware-sim log: what was really
//! simulated, so tests and accuracy figures can compare the monitor's conclusions with it.
//!
//! It holds the scenario identity (name, file, seed), the true clearance of each joint at the
//! start, at the end and during each braking event (wear grows it with distance; the odometer
//! reading goes with each value), every braking event (onset, end,
//! initial speed, plateau deceleration) with its true steering-wheel shimmy amplitude (MODEL.md
//! §11: the peak of the 3–25 Hz, 4th-order zero-phase band-passed δ_sw over
//! `[t_start, t_end + 0.3 s]`, taken from the model's continuous output at 1 kHz, not from the
//! quantised sensor), its per-joint contact statistics (MODEL.md §4) and, with the §15 column
//! and a scenario `[hands]` prior, the driver's hands on the rim (state and values), and
//! per-message frame counts.
//!
//! Not here: running the simulation. All times are seconds since the start of the log; add
//! `start_unix_s` for the frame timestamps.

use serde::Serialize;

use crate::bus::MessageStats;
use crate::drive::BrakeEvent;

/// Identifies the sidecar format.
pub const FORMAT: &str = "firmware-sim ground truth v1";

/// MODEL.md §11 shimmy band (Hz) and filter order.
pub const BAND_HZ: (f64, f64) = (3.0, 25.0);
pub const BAND_ORDER: usize = 4;
/// MODEL.md §11: the window ends this long after the stop (s).
pub const WINDOW_TAIL_S: f64 = 0.3;
/// Extra signal on each side of the window given to the zero-phase filter so its start-up
/// transients fall outside the window (s).
pub const FILTER_PAD_S: f64 = 2.0;

#[derive(Clone, Debug, Serialize, PartialEq)]
pub struct GroundTruth {
    pub format: &'static str,
    pub scenario: ScenarioId,
    pub start_unix_s: f64,
    pub duration_s: f64,
    pub distance_km: f64,
    pub clearance: ClearanceTruth,
    pub events: Vec<EventTruth>,
    pub sensors: SensorTruth,
    pub messages: Vec<MessageStats>,
    pub frames_sent: u64,
    /// True when the run hit the safety limit on simulated time before the drive cycle ended.
    pub truncated: bool,
}

#[derive(Clone, Debug, Serialize, PartialEq)]
pub struct ScenarioId {
    pub name: String,
    pub file: Option<String>,
    pub seed: u64,
    pub vehicle_file: Option<String>,
    /// The vehicle profile whose bus was emulated (absent: the reference bus or a custom DBC).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub profile: Option<String>,
    /// The model's integration scheme and step (s), and the control period (s, driver demand
    /// and ECU sampling), which the log's exact bytes depend on.
    pub integrator: shimmy::model::Integrator,
    pub step_s: f64,
    pub control_period_s: f64,
}

/// The true clearances (mm) of the run. With `single`, the right joint is ideal and reported
/// as 0. Wear (`wear_mm_per_1000km` > 0) grows each worn joint linearly with distance up to
/// `max_mm`; the simulation applies the law every [`crate::sim::WEAR_UPDATE_S`] of simulated
/// time.
#[derive(Clone, Debug, Serialize, PartialEq)]
pub struct ClearanceTruth {
    /// `dual` or `single`.
    pub mode: String,
    pub left_mm_start: f64,
    pub right_mm_start: f64,
    pub wear_mm_per_1000km: f64,
    /// Wear cap (mm).
    pub max_mm: f64,
    pub left_mm_end: f64,
    pub right_mm_end: f64,
    /// Odometer at the start and at the end of the run (km).
    pub odometer_km_start: f64,
    pub odometer_km_end: f64,
}

#[derive(Clone, Debug, Serialize, PartialEq)]
pub struct EventTruth {
    pub index: usize,
    #[serde(flatten)]
    pub event: BrakeEvent,
    /// Clearances in force at brake onset (mm).
    pub clearance_left_mm: f64,
    pub clearance_right_mm: f64,
    /// Clearances in force at the end of the deceleration, `t_end_s` (mm); equal to the onset
    /// values without wear.
    pub clearance_left_mm_end: f64,
    pub clearance_right_mm_end: f64,
    /// Odometer at brake onset (km).
    pub odometer_km: f64,
    /// Per joint (left, right): share of the model steps from onset to `t_end_s` with the pin
    /// in contact with its bushing (MODEL.md §4), and the number of impacts (free flight to
    /// contact). Sampled at every control update (`control_period_s`, 1 ms by default; a
    /// contact that starts and ends between two updates is not seen, so with the default
    /// these are lower bounds; `control_period_s = step_s` counts every model step). An ideal
    /// joint reports 0 and 0.
    pub contact_fraction: [f64; 2],
    pub impacts: [u64; 2],
    /// Analysis window `[t_start, t_end + 0.3]` (s).
    pub window_s: [f64; 2],
    /// MODEL.md §11 steering-wheel amplitude from the model's continuous δ_sw (deg).
    pub sw_amplitude_deg: f64,
    /// cos(φ_R − φ_L) of the wheels' unbalance phases at brake onset (MODEL.md §7; how the
    /// two unbalance moments add in the steering linkage). Absent for a plant without them.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub unbalance_phase_cos: Option<f64>,
    /// The driver's hands on the rim during the event (MODEL.md §15 column with a scenario
    /// `[hands]` prior): the state (`off`, `light`, `firm`) and its inertia, stiffness and
    /// damping. Absent otherwise.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub hands: Option<shimmy::observer::simulate::HandsDraw>,
}

#[derive(Clone, Debug, Serialize, PartialEq)]
pub struct SensorTruth {
    /// Zero-point offset of the steering angle sensor (deg), a fraction of one LSB.
    pub sas_offset_deg: f64,
    /// The steering angle sensor the bus carries (its message, rate and step).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub steer_sensor: Option<SteerSensorTruth>,
}

/// The emulated steering angle sensor.
#[derive(Clone, Debug, Serialize, PartialEq)]
pub struct SteerSensorTruth {
    pub message: String,
    pub rate_hz: f64,
    pub step_deg: f64,
}

/// The MODEL.md §11 steering-wheel amplitude (deg) of one event from δ_sw (rad) sampled at
/// `fs_hz` from t = 0. NaN when the window holds no samples or is too short to filter.
pub fn sw_amplitude_deg(delta_sw_rad: &[f64], fs_hz: f64, window_s: [f64; 2]) -> f64 {
    let idx = |t: f64| ((t * fs_hz).round().max(0.0) as usize).min(delta_sw_rad.len());
    let (w0, w1) = (idx(window_s[0]), idx(window_s[1]));
    if w1 <= w0 {
        return f64::NAN;
    }
    let (p0, p1) = (
        idx(window_s[0] - FILTER_PAD_S),
        idx(window_s[1] + FILTER_PAD_S),
    );
    match shimmy::analysis::filter::bandpass_zero_phase(
        &delta_sw_rad[p0..p1],
        fs_hz,
        BAND_HZ.0,
        BAND_HZ.1,
        BAND_ORDER,
    ) {
        Ok(filtered) => shimmy::analysis::peak_abs(&filtered[w0 - p0..w1 - p0]).to_degrees(),
        // Too short a record to filter (a run cut off right after onset).
        Err(_) => f64::NAN,
    }
}

impl GroundTruth {
    pub fn to_json(&self) -> String {
        serde_json::to_string_pretty(self).expect("ground truth is plain data")
    }
}
