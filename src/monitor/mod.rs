//! The monitor pipeline's shared vocabulary: frames → signals → braking events → estimate →
//! alerts, as both `shimmyd` and `shimmy estimate` run it. This module holds the seam
//! between the mapped signals and the clearance observer: the [`EventStage`] trait, fed one
//! [`Sample`] per accepted mapped update, handing back finished braking events
//! ([`EventSummary`]) and the current clearance estimate ([`Estimate`]).
//!
//! What it is: the contract the monitor pipeline (`crate::pipeline`, which shimmyd and
//! `shimmy estimate` both run), the alert rules ([`crate::alerts`]) and the report are written
//! against, plus [`NoObserver`] for configurations without an observer (it detects nothing and
//! estimates nothing — it never invents an estimate). The adapter for
//! [`crate::observer::Observer`] is `crate::pipeline::ObserverStage`.
//!
//! What it is not: a detector, an estimator, an alert rule, the pipeline's wiring or an
//! output. It sits below the alert rules, the pipeline and the daemon and depends on none of
//! them.

use serde::{Deserialize, Serialize};

/// One mapped update, SI units: the detector's own input type ([`crate::events::Sample`]),
/// re-exported so the daemon, the observer and the event detector share one definition.
pub use crate::events::Sample;

/// One finished braking event as the journal, the alerts and the report see it.
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct EventSummary {
    /// Brake onset / end, log time (s since the Unix epoch for live and candump logs).
    pub t_start: f64,
    pub t_end: f64,
    pub v0_kmh: f64,
    pub decel_g: f64,
    /// MODEL.md §11 raw peak of the 3–25 Hz band-passed steering-wheel angle (deg).
    pub peak_sw_bp_deg: Option<f64>,
    /// Estimated true steering-wheel shimmy amplitude (deg), sensor quantisation and noise
    /// accounted for; this is what the shimmy alert compares with its threshold.
    pub sw_amplitude_deg: Option<f64>,
    /// Used for estimation (inside the model's validity range, good data).
    pub used: bool,
    pub unused_reason: Option<String>,
    /// Odometer at the event (km), from the pipeline's speed integration
    /// (`crate::pipeline::SpeedIntegrator`; shimmyd's persists across restarts).
    #[serde(default)]
    pub odometer_km: f64,
    /// With a torque table: the peak of the band-passed torsion-bar torque (N·m) and whether
    /// the torque's estimator used the event (absent without a torque table).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub peak_torque_bp_nm: Option<f64>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub torque_used: Option<bool>,
}

/// The observer's clearance estimate.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct Estimate {
    /// Posterior median (mm) when detectable.
    pub clearance_mm: Option<f64>,
    /// 90 % credible interval (mm).
    pub interval_mm: Option<[f64; 2]>,
    pub detectable: bool,
    /// When not detectable: "below this" (mm).
    pub below_mm: Option<f64>,
    /// P(clearance > the alert threshold).
    pub p_above: Option<f64>,
    pub events_used: u32,
    /// Why the model does not fit this vehicle, when the goodness-of-fit check says so
    /// (src/observer/fit.rs, src/observer/noise_floor.rs): the interval is then not to be
    /// trusted.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub misfit: Option<String>,
    /// When the profile has chassis variants and the vehicle's events fit one better than the
    /// car model's own chassis: its name ("scrub radius 10 mm"), the estimate being read mostly
    /// with its table (every table weighed by its probability: [`crate::observer::posterior`]).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub chassis_variant: Option<String>,
    /// What to check on the car for that variant (the profile's `inspect`: "the wheels'
    /// offset ..."); absent when the variant is no fault.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub chassis_variant_inspect: Option<String>,
    /// The model does not fit because the steering shakes at the wheels' rotation while
    /// braking (src/observer/wheel_order.rs): a brake disc thickness variation, to be checked
    /// before the joints are judged.
    #[serde(default, skip_serializing_if = "std::ops::Not::not")]
    pub wheel_order_shake: bool,
    /// With `wheel_order_shake`: the events rule uneven brake discs out (the profile's table
    /// for them fits far worse than another), so the shake is the chassis's own and the car
    /// goes to its chassis (the `misfit` says what to check), not its discs.
    #[serde(default, skip_serializing_if = "std::ops::Not::not")]
    pub wheel_order_discs_ruled_out: bool,
    /// The model does not fit because the estimate's steering sensor measured noisier at
    /// standstill than its response table assumes (src/observer/noise_floor.rs): the monitor is
    /// not set up for this car's sensor, so no clearance alert is raised from the estimate
    /// (`crate::alerts::AlertBook`) until a table for it is built.
    #[serde(default, skip_serializing_if = "std::ops::Not::not")]
    pub sensor_noisier: bool,
}

/// [`EventStage::rejections`]: the counts and their explanation (counts, then the likely cause).
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct RejectionSummary {
    pub counts: crate::observer::rejections::Rejections,
    pub text: String,
}

/// The event/estimation stage of the pipeline.
pub trait EventStage {
    /// What it is, for the start-up log line.
    fn describe(&self) -> String;
    /// Feeds one update; returns a braking event that finished with it.
    fn push(&mut self, s: &Sample) -> Option<EventSummary>;
    /// End of input: closes an open event.
    fn finish(&mut self) -> Option<EventSummary>;
    /// The current clearance estimate (None when the stage cannot estimate).
    fn estimate(&self) -> Option<Estimate>;
    /// The odometer now (km), told before each [`Self::push`]: the distance between events
    /// drives the estimator's wear model across restarts. Default: ignored.
    fn odometer_km(&mut self, _km: f64) {}
    /// What the stage needs to resume after a restart (the posterior's evidence), saved in the
    /// daemon's state file. Default: nothing.
    fn save(&self) -> Option<serde_json::Value> {
        None
    }
    /// What braking produced so far: brake applications ignored and events not used, counted
    /// per reason, with the sentence that explains them. Default: nothing to say.
    fn rejections(&self) -> Option<RejectionSummary> {
        None
    }
    /// Resumes from what [`Self::save`] returned in an earlier run; returns a line for the log.
    /// Default: nothing to restore.
    fn restore(&mut self, _saved: &serde_json::Value) -> anyhow::Result<Option<String>> {
        Ok(None)
    }
}

/// No observer configured or built: nothing is detected, nothing is estimated.
pub struct NoObserver;

impl EventStage for NoObserver {
    fn describe(&self) -> String {
        "no observer: braking events are not detected and clearance is not estimated".into()
    }
    fn push(&mut self, _s: &Sample) -> Option<EventSummary> {
        None
    }
    fn finish(&mut self) -> Option<EventSummary> {
        None
    }
    fn estimate(&self) -> Option<Estimate> {
        None
    }
}
