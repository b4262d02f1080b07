//! The clearance observer: from braking events in the mapped signal stream to a
//! clearance estimate with a credible interval.
//!
//! | module | job |
//! |---|---|
//! | [`features`] | per-event steering-wheel features (MODEL.md §11 band-pass peak, RMS, noise correction) |
//! | [`sensor`] | the steering angle sensor model applied to the model's output (MODEL.md §8) |
//! | [`table`] | the response table: predicted feature distributions over clearance × speed × decel |
//! | [`estimator`] | the posterior over clearance, accumulated across events with wear diffusion |
//! | [`alerts`] | `[alerts]`: the settings of the alert rules (the rules are `crate::alerts`') |
//! | `checks` | [`ObserverConfig::validate`]: the ranges and orderings serde cannot express, for every command |
//!
//! [`Observer`] wires them to [`crate::events::Detector`]: feed it [`Sample`]s, read a
//! [`Report`]. With a table of the EPS torsion-bar torque ([`Observer::with_torque_table`]) it
//! keeps a second estimator on the torque's features (MODEL.md §15: the torque sees the pinion
//! turn against the rim, whatever the driver's hands do to the rim), and reports from it once
//! an event with a live torque was used. Either channel can carry tables of structural
//! alternatives of the chassis (a scrub radius, uneven brake discs: MODEL.md §14), each with an
//! estimator fed every event; the channel's posterior is then their mixture, each table weighed
//! by its prior times how well the events fit it ([`posterior`]). Those estimators are built
//! when the channel first needs them, so a car pays only for the channel its estimate comes
//! from. What it is not: CAN decoding (that is [`crate::signals`]), the model, or the
//! alert rules: it raises no alert. The alerts of `shimmy estimate` and shimmyd are decided by
//! `crate::alerts::AlertBook` after each finished event, on the estimate the monitor pipeline
//! (`crate::pipeline`) reads from this observer; the report's
//! [`Report::p_clearance_above_threshold`] is the final posterior's P(c > `clearance_mm`).

pub mod alerts;
mod checks;
pub mod correction;
pub mod emulate;
pub mod estimator;
pub mod features;
pub mod fit;
pub mod linear;
pub mod marginal;
pub mod noise_floor;
pub mod posterior;
pub mod rejections;
pub mod sensor;
pub mod simulate;
pub mod table;
pub mod wheel_order;

use std::path::Path;

use anyhow::Context;
use serde::{Deserialize, Serialize};

use crate::events::{Detector, EventConfig, IgnoredApplication, Sample, Unused};
use alerts::AlertConfig;
use estimator::{Estimator, EstimatorConfig};
use features::{Extractor, Features, SensorNoise};
use rejections::{Rejections, UnusedCounts};
use table::ResponseTable;

/// config/observer.toml.
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct ObserverConfig {
    pub events: EventConfig,
    pub features: FeatureConfig,
    pub estimator: EstimatorConfig,
    pub alerts: AlertConfig,
}

/// `[features]`: the sensor noise assumed by the noise correction, and the crest factor used to
/// turn the noise-corrected RMS into an amplitude when no response table calibrates it.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct FeatureConfig {
    pub sensor: SensorNoise,
    pub crest_factor: f64,
    /// A steering sensor whose noise measured at standstill exceeds this many times (RMS) what
    /// the features assume makes "the model does not fit" (src/observer/noise_floor.rs); 0
    /// turns the check off.
    pub noise_floor_ratio: f64,
    /// The check for a shake locked to the wheels' rotation while braking (a disc thickness
    /// variation: src/observer/wheel_order.rs).
    pub wheel_order: wheel_order::WheelOrderConfig,
}

impl Default for FeatureConfig {
    fn default() -> Self {
        FeatureConfig {
            sensor: SensorNoise::default(),
            crest_factor: 2.2,
            noise_floor_ratio: 1.5,
            wheel_order: wheel_order::WheelOrderConfig::default(),
        }
    }
}

impl ObserverConfig {
    /// The `[estimator]` settings of the torsion-bar torque's estimator: the angle's with its
    /// own evidence power (`torque_evidence_power`).
    pub fn torque_estimator(&self) -> EstimatorConfig {
        EstimatorConfig {
            evidence_power: self.estimator.torque_evidence_power,
            ..self.estimator.clone()
        }
    }

    pub fn from_toml_str(text: &str) -> anyhow::Result<ObserverConfig> {
        Ok(Self::from_toml_str_with_warnings(text)?.0)
    }

    /// [`Self::from_toml_str`], also returning the deprecation warnings for what the text
    /// uses (old key names that are still accepted: [`alerts::DEPRECATED_KEYS`]).
    pub fn from_toml_str_with_warnings(
        text: &str,
    ) -> anyhow::Result<(ObserverConfig, Vec<String>)> {
        let cfg: ObserverConfig = toml::from_str(text)?;
        // It parsed, so it is a table and `[alerts]`, when present, is one too.
        let raw: toml::Table = toml::from_str(text)?;
        let warnings = match raw.get("alerts") {
            Some(toml::Value::Table(t)) => alerts::deprecations(t),
            _ => Vec::new(),
        };
        Ok((cfg, warnings))
    }

    /// Reads the file; prints each deprecation warning on stderr, naming the file and the key
    /// that replaces the old one ([`Self::load_with_warnings`] returns them instead).
    pub fn load(path: &Path) -> anyhow::Result<ObserverConfig> {
        let (cfg, warnings) = Self::load_with_warnings(path)?;
        for w in warnings {
            eprintln!("warning: {w}");
        }
        Ok(cfg)
    }

    /// [`Self::load`] without printing: the configuration and its deprecation warnings, each
    /// prefixed with the file's path.
    pub fn load_with_warnings(path: &Path) -> anyhow::Result<(ObserverConfig, Vec<String>)> {
        let text = std::fs::read_to_string(path)
            .with_context(|| format!("cannot read {}", path.display()))?;
        let (cfg, warnings) = Self::from_toml_str_with_warnings(&text)
            .with_context(|| format!("in {}", path.display()))?;
        cfg.validate("")
            .with_context(|| format!("in {}", path.display()))?;
        let warnings = warnings
            .into_iter()
            .map(|w| format!("{}: {w}", path.display()))
            .collect();
        Ok((cfg, warnings))
    }
}

/// One event in `shimmy estimate`'s report: when, initial speed, deceleration, the band-passed
/// steering-wheel peak and whether it was used (and why not), plus the features and the data
/// quality behind them.
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct EventOut {
    pub t_start: f64,
    pub t_end: f64,
    pub v0_kmh: f64,
    pub decel_g: f64,
    /// MODEL.md §11 raw peak of the band-passed steering-wheel angle (deg); null when the event
    /// had too few samples.
    pub peak_sw_bp_deg: Option<f64>,
    pub used: bool,
    pub unused_reason: Option<Unused>,
    pub rms_sw_bp_deg: Option<f64>,
    /// RMS of the band-passed steering-wheel angle before the brake onset (deg; null when the
    /// pre-roll was too short), see `features`.
    pub cruise_rms_sw_bp_deg: Option<f64>,
    /// Share of the braking band's power in a line at the wheels' rotation, beyond the one
    /// before the brake (src/observer/wheel_order.rs); null without a speed or when the wheel
    /// order stayed out of the band.
    pub wheel_order_share: Option<f64>,
    /// Estimated true steering-wheel amplitude (deg), noise- and quantisation-corrected.
    pub sw_amplitude_deg: Option<f64>,
    pub duration_s: f64,
    pub sample_hz: f64,
    pub quant_step_deg: f64,
    pub missing_samples: u32,
    pub invalid_updates: u32,
    /// With a torque table ([`Observer::with_torque_table`]): the band-passed torsion-bar
    /// torque's RMS, peak and pre-brake RMS (N·m, MODEL.md §15; band [`features::band_hz`] of
    /// its rate), and whether the torque estimator used the event.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub torque: Option<TorqueEventOut>,
}

/// The torque features of one event (see [`EventOut::torque`]).
#[derive(Clone, Copy, Debug, PartialEq, Serialize)]
pub struct TorqueEventOut {
    pub rms_bp_nm: Option<f64>,
    pub peak_bp_nm: Option<f64>,
    pub cruise_rms_bp_nm: Option<f64>,
    /// As [`EventOut::wheel_order_share`], of the torque.
    pub wheel_order_share: Option<f64>,
    pub sample_hz: Option<f64>,
    pub used: bool,
    /// Why not used: `"no_torque"` (none on the bus in the window, or a constant one),
    /// `"sensor_mismatch"` (rate not the torque table's), or the event's own reason.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub unused_reason: Option<&'static str>,
}

/// With a torque table: which signal the report's estimate comes from and how many events each
/// channel used.
#[derive(Clone, Copy, Debug, PartialEq, Serialize)]
pub struct SignalUse {
    /// `"torque_nm"` when the torque estimator used at least one event, else `"angle_deg"`.
    pub estimate_from: features::SteerSignal,
    pub events_used_torque: u64,
    /// Events usable for the angle but without a usable torque (no torque, a constant torque,
    /// a torque at another rate than the table's).
    pub events_without_torque: u64,
}

/// The whole answer of `shimmy estimate`.
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct Report {
    /// Posterior median (mm); null when not detectable.
    pub clearance_mm: Option<f64>,
    /// 90 % credible interval [5 %, 95 %] (mm); null without a table or without used events.
    pub interval_mm: Option<[f64; 2]>,
    pub detectable: bool,
    /// When not detectable: the clearance is below this (mm): the posterior's 95 % quantile, at
    /// least the detection limit.
    pub below_mm: Option<f64>,
    /// Posterior median (mm) whether or not detectable (for validation; null without estimate).
    pub median_mm: Option<f64>,
    /// Human-readable verdict.
    pub verdict: String,
    pub events: Vec<EventOut>,
    pub events_used: u32,
    /// Brake applications ignored as too light / too slow to record.
    pub brake_applications_ignored: u64,
    /// Brake applications ignored and events not used, counted per reason (an ignored
    /// application can count under several reasons), and how many ignored applications read a
    /// forward acceleration while the brake was applied.
    pub rejections: Rejections,
    /// The ignored applications themselves (at most [`MAX_IGNORED_KEPT`], the first ones).
    pub ignored_applications: Vec<IgnoredApplication>,
    /// Events not kept in `events` because the report's list was full.
    pub events_dropped: u64,
    /// Events not used because their steering angle sensor is not the table's
    /// ([`Unused::SensorMismatch`]).
    pub events_sensor_mismatch: u64,
    pub p_clearance_above_threshold: Option<f64>,
    /// With a torque table: the signal the estimate comes from, events per channel.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub signals: Option<SignalUse>,
    /// With torque tables for structural alternatives of the chassis
    /// ([`Observer::with_torque_alternative`]): each table's evidence, its weight and which
    /// one the estimate is read from; absent otherwise.
    #[serde(skip_serializing_if = "Vec::is_empty")]
    pub torque_tables: Vec<TableEvidence>,
    /// As [`Self::torque_tables`], for the angle's tables of chassis variants
    /// ([`Observer::with_angle_alternative`]); the estimate weighs them while it comes from
    /// the angle.
    #[serde(skip_serializing_if = "Vec::is_empty")]
    pub angle_tables: Vec<TableEvidence>,
    /// Method "linear", `phase = "either"`: posterior probability that the wheels' unbalance
    /// phase difference stayed the same over the events (src/observer/marginal.rs).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub p_wheel_phase_fixed: Option<f64>,
    /// Method "linear": whether the events fit the table's model (src/observer/fit.rs).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub model_fit: Option<fit::ModelFit>,
    /// The steering sensors' noise measured at standstill, per channel with a measurement
    /// (src/observer/noise_floor.rs).
    #[serde(skip_serializing_if = "Vec::is_empty")]
    pub sensor_noise: Vec<noise_floor::MeasuredNoise>,
    /// The car model's correction the estimate applied (its profile's, fitted by `shimmy
    /// fleet-fit`; src/observer/correction.rs), when there is one.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub correction: Option<correction::Correction>,
}

/// `verdict` with which of a channel's `tables` (its [`TableEvidence`], empty without chassis
/// variants) the estimate is read mostly with, when that is a variant's or the nominal's
/// without a clear lead.
fn read_with(verdict: String, tables: &[TableEvidence], channel: &str) -> String {
    match tables.iter().find(|e| e.chosen) {
        Some(e) if e.name != NOMINAL_TABLE => format!(
            "{verdict}, read mostly with the {channel} table for {} (probability {:.2} among the \
             profile's {} {channel} tables, by how well the events fit each; the estimate weighs \
             every table by it)",
            e.name,
            e.weight.unwrap_or(f64::NAN),
            tables.len()
        ),
        Some(e) if e.weight.is_some_and(|w| w < MIXED_WEIGHT) => format!(
            "{verdict}, read mostly with the profile's nominal {channel} table (probability \
             {:.2} among its {} {channel} tables, by how well the events fit each; the estimate \
             weighs every table by it)",
            e.weight.unwrap_or(f64::NAN),
            tables.len()
        ),
        _ => verdict,
    }
}

/// One used event's features into `est` (on `table`), placed on the detector's odometer.
fn feed_event(
    est: &mut Estimator,
    table: &ResponseTable,
    f: &Features,
    rec: &crate::events::EventRecord,
) {
    est.update_event(
        table,
        f.rms_deg,
        f.peak_deg,
        f.cruise_rms_deg,
        rec.v0_kmh,
        rec.decel_g,
        rec.odometer_m,
    );
}

/// [`Unused`]'s name as it serialises.
fn unused_name(u: Unused) -> &'static str {
    match u {
        Unused::SpeedOutOfRange => "speed_out_of_range",
        Unused::DecelOutOfRange => "decel_out_of_range",
        Unused::NotStraight => "not_straight",
        Unused::TooShort => "too_short",
        Unused::LowSampleRate => "low_sample_rate",
        Unused::MissingData => "missing_data",
        Unused::Truncated => "truncated",
        Unused::SensorMismatch => "sensor_mismatch",
    }
}

/// Most events kept in the report (memory bound).
pub const MAX_EVENTS_KEPT: usize = 10_000;

/// Most ignored brake applications kept in the report (memory bound; all are counted).
pub const MAX_IGNORED_KEPT: usize = 1_000;

/// Detector + features + estimator.
pub struct Observer {
    cfg: ObserverConfig,
    detector: Detector,
    extractor: Extractor,
    table: Option<ResponseTable>,
    estimator: Option<Estimator>,
    events: Vec<EventOut>,
    events_dropped: u64,
    /// The most recent event, kept even when `events` is full (streaming consumers).
    last_event: Option<EventOut>,
    /// The detector's odometer (m) at the most recent event's brake onset: the position the
    /// estimator's wear model measures the distance between events from.
    last_event_odometer_m: f64,
    /// Events whose sensor did not match the table's, and the last one's (rate Hz, step deg).
    sensor_mismatch: u64,
    last_mismatch: (f64, f64),
    /// Ignored brake applications kept (the first [`MAX_IGNORED_KEPT`]), and how many the
    /// detector had ignored when last looked at.
    ignored: Vec<IgnoredApplication>,
    ignored_seen: u64,
    unused: UnusedCounts,
    used_total: u64,
    /// Whether each used event goes into the estimator here (placed on the detector's
    /// odometer), or the caller feeds it ([`Self::new_caller_fed`]).
    feeds_estimator: bool,
    /// Angle tables of structural alternatives of the chassis
    /// ([`Self::with_angle_alternative`]), each with its estimator fed every event the angle's
    /// is; the angle's estimate weighs them as the torque channel weighs its own.
    angle_alternatives: Vec<TableAlternative>,
    /// The angle's alternatives added but not built yet: their estimators are built at the
    /// first angle event fed while the estimate does not come from the torque
    /// ([`Self::angle_estimators_mut`]).
    angle_deferred: Vec<CheckedAlternative>,
    /// Why a deferred alternative (the angle's or the torque's) could not be built (not
    /// expected: its table passed [`Estimator::check`] when it was added); the report's
    /// verdict says so.
    unbuilt: Vec<String>,
    /// The torsion-bar torque channel, with a torque table.
    torque: Option<TorqueChannel>,
    /// The steering sensors' noise measured at standstill ([`noise_floor`]).
    noise_floor: noise_floor::NoiseFloor,
    /// The wheel-order shares ([`wheel_order`]) of the events each estimator took: the
    /// angle's (0) and the torque's (1), the newest `features.wheel_order.window_events`.
    wheel_order: [std::collections::VecDeque<f64>; 2],
}

/// Where [`Observer`] keeps `signal`'s wheel-order shares.
fn wheel_order_slot(signal: features::SteerSignal) -> usize {
    usize::from(!signal.is_angle())
}

/// Largest `features.wheel_order.window_events`.
pub const MAX_WHEEL_ORDER_KEPT: usize = 2000;

/// The second steering channel: the torsion-bar torque's response table and its own
/// estimator. Its evidence is kept apart from the angle's (each estimator is consistent with
/// its own table's nuisance vehicles); the report takes the torque's posterior once it has
/// used an event, the angle's otherwise (a bus or a plant without a live torque degrades to
/// the angle instead of failing).
struct TorqueChannel {
    table: ResponseTable,
    estimator: Estimator,
    /// Torque tables of the same car under structural alternatives of its chassis (a scrub
    /// radius, say: [`Observer::with_torque_alternative`]), each with its own estimator fed the
    /// same events. The report weighs their posteriors by each table's probability
    /// ([`posterior`]).
    alternatives: Vec<TableAlternative>,
    /// The alternatives added but not built yet: their estimators are built at the channel's
    /// first event ([`Observer::torque_estimators_mut`]).
    deferred: Vec<CheckedAlternative>,
    /// Its own extractor: the torque comes at another rate than the angle, and one extractor
    /// would redesign its filter at every switch.
    extractor: Extractor,
    noise: features::SensorNoise,
    used: u64,
    without: u64,
}

/// A torque table for a structural alternative of the chassis
/// ([`Observer::with_torque_alternative`]).
#[derive(Clone, Debug)]
pub struct Alternative {
    /// How reports name it ("scrub radius 10 mm").
    pub name: String,
    /// Its prior probability, before any event: the nominal chassis has 1 minus the sum of
    /// its alternatives'.
    pub prior: f64,
    /// What a workshop should check on a car read with it (the profile's `inspect`); `None`
    /// for an alternative that is no fault (a car model's own damping, say).
    pub inspect: Option<String>,
    pub table: ResponseTable,
}

impl Alternative {
    /// The alternatives' names joined for a start-up line ("scrub radius 10 mm, ...").
    pub fn names(alternatives: &[Alternative]) -> String {
        let names: Vec<&str> = alternatives.iter().map(|a| a.name.as_str()).collect();
        names.join(", ")
    }
}

/// One structural alternative of the chassis inside a steering channel (the angle's or the
/// torque's), with its estimator.
struct TableAlternative {
    name: String,
    inspect: Option<String>,
    ln_prior: f64,
    table: ResponseTable,
    estimator: Estimator,
}

/// A chassis variant's table checked to go beside a channel's nominal table, without its
/// estimator yet: the observer builds it when the channel first needs it
/// ([`Observer::with_angle_alternative`], [`Observer::with_torque_alternative`]).
struct CheckedAlternative {
    name: String,
    inspect: Option<String>,
    ln_prior: f64,
    table: ResponseTable,
}

impl CheckedAlternative {
    /// `alt` beside the channel's `nominal` table and its alternatives, `built` and `deferred`:
    /// the same sensor, a name of its own, priors that leave the nominal some, and a table an
    /// estimator on `cfg` takes ([`Estimator::check`]).
    fn new(
        alt: Alternative,
        nominal: &ResponseTable,
        built: &[TableAlternative],
        deferred: &[CheckedAlternative],
        cfg: EstimatorConfig,
        channel: &str,
    ) -> anyhow::Result<CheckedAlternative> {
        let others = built
            .iter()
            .map(|a| (a.name.as_str(), a.ln_prior))
            .chain(deferred.iter().map(|a| (a.name.as_str(), a.ln_prior)));
        let Alternative {
            name,
            prior,
            inspect,
            table,
        } = alt;
        if table.sensor != nominal.sensor {
            anyhow::bail!(
                "{channel} table alternative `{name}`: built for another {channel} sensor ({:?}) \
                 than the nominal table ({:?})",
                table.sensor,
                nominal.sensor
            );
        }
        if name == NOMINAL_TABLE || others.clone().any(|(n, _)| n == name) {
            anyhow::bail!("{channel} table alternative `{name}`: the name is taken");
        }
        let sum: f64 = others.map(|(_, l)| l.exp()).sum();
        if !(prior > 0.0 && prior + sum < 1.0) {
            anyhow::bail!(
                "{channel} table alternative `{name}`: its prior probability {prior} must be \
                 above 0, and the alternatives' together ({}) below 1",
                prior + sum
            );
        }
        Estimator::check(&table, cfg)?;
        Ok(CheckedAlternative {
            name,
            inspect,
            ln_prior: prior.ln(),
            table,
        })
    }

    /// Builds every alternative of `deferred` into `built`, each with its estimator on `cfg`;
    /// why one could not be built goes to `unbuilt` (not expected: each passed
    /// [`Estimator::check`] when it was added).
    fn build_all(
        deferred: &mut Vec<CheckedAlternative>,
        built: &mut Vec<TableAlternative>,
        cfg: &EstimatorConfig,
        unbuilt: &mut Vec<String>,
    ) {
        for a in std::mem::take(deferred) {
            match a.build(cfg.clone()) {
                Ok(a) => built.push(a),
                Err(e) => unbuilt.push(format!("{e:#}")),
            }
        }
    }

    /// With its estimator on `cfg`.
    fn build(self, cfg: EstimatorConfig) -> anyhow::Result<TableAlternative> {
        let estimator = Estimator::new(&self.table, cfg)?;
        Ok(TableAlternative {
            name: self.name,
            inspect: self.inspect,
            ln_prior: self.ln_prior,
            table: self.table,
            estimator,
        })
    }
}

/// The name the report gives the torque table of the profile's own chassis when the channel
/// has alternatives.
pub const NOMINAL_TABLE: &str = "nominal";

/// Below this posterior probability of the uneven-discs table (every one, where a channel has
/// several), the events rule uneven discs out, and a steering that shakes at wheel order is
/// sent to its chassis (the wheels' offset and balance) instead of its discs
/// ([`fit::ModelFit::wheel_order_discs_ruled_out`]): odds of 1 to 100 against the discs
/// given the tables' priors, a decisive margin on the Jeffreys scale. On the disc fleets of
/// docs/ACCURACY.md the disc table held 0.24 or more on every car the check named, on cars
/// with a scrub radius alone 0.002 or less.
pub const DISCS_RULED_OUT: f64 = 0.01;

/// Below this probability of the nominal torque table the report says that the estimate
/// weighs the chassis variants' tables too.
const MIXED_WEIGHT: f64 = 0.95;

impl TorqueChannel {
    /// Whether the report's estimate comes from this channel: once it has used an event.
    fn active(&self) -> bool {
        self.estimator.events_used() > 0
    }

    /// Its tables: the nominal and the chassis variants'.
    fn mixture(&self) -> Mixture<'_> {
        Mixture {
            nominal: &self.estimator,
            alternatives: &self.alternatives,
        }
    }
}

/// One steering channel's tables, the nominal and its structural alternatives, each with its
/// estimator fed the same events: which one fits best, and the posterior weighed over them.
#[derive(Clone, Copy)]
struct Mixture<'a> {
    nominal: &'a Estimator,
    alternatives: &'a [TableAlternative],
}

impl<'a> Mixture<'a> {
    /// The estimators, the nominal first, with their names and ln prior probabilities.
    fn all(self) -> impl Iterator<Item = (&'a str, &'a Estimator, f64)> {
        let nominal = 1.0
            - self
                .alternatives
                .iter()
                .map(|a| a.ln_prior.exp())
                .sum::<f64>();
        std::iter::once((NOMINAL_TABLE, self.nominal, nominal.ln())).chain(
            self.alternatives
                .iter()
                .map(|a| (a.name.as_str(), &a.estimator, a.ln_prior)),
        )
    }

    /// Each table's ln posterior weight up to a constant (ln prior + tempered ln evidence),
    /// `None` before the table has a finite evidence.
    fn ln_weights(self) -> impl Iterator<Item = Option<f64>> + 'a {
        self.all().map(|(_, e, ln_prior)| {
            e.ln_evidence()
                .map(|l| l[0] + ln_prior)
                .filter(|l| l.is_finite())
        })
    }

    /// Index into [`Self::all`] of the most probable table (the one the report names and the
    /// fit check reads): the highest posterior weight, the nominal while none has one.
    fn chosen(self) -> usize {
        let mut best = (0, f64::NEG_INFINITY);
        for (i, l) in self.ln_weights().enumerate() {
            if let Some(l) = l.filter(|&l| l > best.1) {
                best = (i, l);
            }
        }
        best.0
    }

    fn chosen_estimator(self) -> &'a Estimator {
        self.chosen_alternative()
            .map_or(self.nominal, |a| &a.estimator)
    }

    /// Whether the events rule uneven brake discs out: the channel has a table whose vehicles'
    /// discs were drawn uneven (its prior's `brake_torque_variation_rel`) and its posterior
    /// probability among the tables is below [`DISCS_RULED_OUT`]. A shake at wheel order
    /// while braking is then the chassis's own, which another table (a scrub radius turning
    /// the unbalance's load variation into a kingpin moment) describes better.
    fn rules_out_discs(self) -> bool {
        let weights = self.weights();
        // weights[0] is the nominal's, weights[i] the (i-1)-th alternative's.
        let mut discs = self
            .alternatives
            .iter()
            .zip(weights.iter().skip(1))
            .filter(|(a, _)| a.table.prior.brake_torque_variation_rel.is_some())
            .peekable();
        discs.peek().is_some() && discs.all(|(_, w)| w.is_some_and(|w| w < DISCS_RULED_OUT))
    }

    /// The most probable table's alternative, `None` when it is the nominal.
    fn chosen_alternative(self) -> Option<&'a TableAlternative> {
        match self.chosen() {
            0 => None,
            i => Some(&self.alternatives[i - 1]),
        }
    }

    /// Each table's posterior probability (prior times tempered evidence, normalised over the
    /// tables that have an evidence), `None` for a table without one yet.
    fn weights(self) -> Vec<Option<f64>> {
        let lw: Vec<Option<f64>> = self.ln_weights().collect();
        let max = lw
            .iter()
            .flatten()
            .copied()
            .fold(f64::NEG_INFINITY, f64::max);
        let z: f64 = lw.iter().flatten().map(|l| (l - max).exp()).sum();
        lw.into_iter()
            .map(|l| l.map(|l| (l - max).exp() / z))
            .collect()
    }

    /// The clearance posterior over the tables: each table's posterior weighed by its
    /// posterior probability ([`posterior`]); the nominal's alone while no table has an
    /// evidence, and without alternatives.
    fn posterior(self) -> posterior::Posterior<'a> {
        if self.alternatives.is_empty() {
            return posterior::Posterior::single(self.nominal);
        }
        posterior::Posterior::mixture(
            self.all()
                .zip(self.weights())
                .filter_map(|((_, e, _), w)| Some((w?, e))),
        )
        .unwrap_or_else(|| posterior::Posterior::single(self.chosen_estimator()))
    }

    /// Every table's evidence and its weight (its posterior probability among the tables:
    /// prior times tempered evidence, normalised); empty without alternatives.
    fn evidence(self) -> Vec<TableEvidence> {
        if self.alternatives.is_empty() {
            return Vec::new();
        }
        let chosen = self.chosen();
        self.all()
            .zip(self.weights())
            .enumerate()
            .map(|(i, ((name, e, ln_prior), w))| TableEvidence {
                name: name.to_string(),
                prior: ln_prior.exp(),
                ln_evidence: e.ln_evidence().map(|l| l[0]).filter(|l| l.is_finite()),
                weight: w,
                chosen: i == chosen,
            })
            .collect()
    }
}

/// With torque tables for structural alternatives of the chassis: one table's evidence.
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct TableEvidence {
    /// [`NOMINAL_TABLE`] or the alternative's name (its profile's `[[chassis.variants]]`).
    pub name: String,
    /// Its prior probability ([`Alternative::prior`]).
    pub prior: f64,
    /// ln of the events' marginal likelihood under this table (with the evidence power);
    /// null before an event.
    pub ln_evidence: Option<f64>,
    /// Its posterior probability among the tables (prior times evidence, normalised).
    pub weight: Option<f64>,
    /// Whether it is the most probable table (the estimate weighs every table by `weight`).
    pub chosen: bool,
}

impl Observer {
    pub fn new(cfg: ObserverConfig, table: Option<ResponseTable>) -> anyhow::Result<Observer> {
        let estimator = match &table {
            Some(t) => Some(Estimator::new(t, cfg.estimator.clone())?),
            None => None,
        };
        Ok(Observer {
            detector: Detector::new(cfg.events.clone()),
            extractor: Extractor::new(),
            table,
            estimator,
            events: Vec::new(),
            events_dropped: 0,
            last_event: None,
            last_event_odometer_m: 0.0,
            sensor_mismatch: 0,
            last_mismatch: (0.0, 0.0),
            ignored: Vec::with_capacity(16),
            ignored_seen: 0,
            unused: UnusedCounts::default(),
            used_total: 0,
            feeds_estimator: true,
            angle_alternatives: Vec::new(),
            angle_deferred: Vec::new(),
            unbuilt: Vec::new(),
            torque: None,
            noise_floor: noise_floor::NoiseFloor::default(),
            wheel_order: Default::default(),
            cfg,
        })
    }

    /// Adds the torsion-bar torque channel: `table` must describe the torque
    /// ([`features::SteerSignal::TorqueNm`]). Events with a live torque at the table's rate
    /// then also feed the torque's estimator, and the report's estimate comes from it once it
    /// has used an event.
    pub fn with_torque_table(mut self, table: ResponseTable) -> anyhow::Result<Observer> {
        if table.sensor.signal != features::SteerSignal::TorqueNm {
            anyhow::bail!(
                "the torque table is a table of the steering angle (its signal is not \
                 `torque_nm`): build it with `shimmy calibrate --signal torque`"
            );
        }
        let estimator = Estimator::new(&table, self.torque_estimator_config())?;
        let noise = features::SensorNoise {
            quant_step_deg: table.sensor.step_deg,
            noise_deg: table.sensor.noise_deg,
        };
        self.torque = Some(TorqueChannel {
            table,
            estimator,
            alternatives: Vec::new(),
            deferred: Vec::new(),
            extractor: Extractor::new(),
            noise,
            used: 0,
            without: 0,
        });
        self.share_scratch();
        Ok(self)
    }

    /// Adds a torque table for a structural alternative of the chassis (built on the same
    /// chassis with, say, another scrub radius: MODEL.md §14), named `name`. Its estimator is
    /// fed every event the nominal torque table's is, and the report weighs each table's
    /// posterior by its probability (its prior times the events' marginal likelihood under
    /// it: [`posterior`], [`Report::torque_tables`]): a car whose chassis departs from the
    /// nominal one in that named way is read mostly with the table that describes it instead
    /// of a nominal table that reads its steady shake as wear. Needs
    /// [`Self::with_torque_table`] first, and a table of the same torque sensor.
    ///
    /// Its estimator (about 1.5 MB) is built at the channel's first event
    /// ([`Self::torque_estimators_mut`]), so that a car whose bus carries no live torque does
    /// not hold it beside the angle's; it is checked here (`Estimator::check`), so that a
    /// table the estimator refuses is refused now.
    pub fn with_torque_alternative(mut self, alt: Alternative) -> anyhow::Result<Observer> {
        let cfg = self.torque_estimator_config();
        let Some(ch) = self.torque.as_mut() else {
            anyhow::bail!(
                "torque table alternative `{}` without a nominal torque table",
                alt.name
            );
        };
        let a = CheckedAlternative::new(
            alt,
            &ch.table,
            &ch.alternatives,
            &ch.deferred,
            cfg,
            "torque",
        )?;
        ch.deferred.push(a);
        Ok(self)
    }

    /// Adds an angle table for a structural alternative of the chassis: as
    /// [`Self::with_torque_alternative`], for the steering-angle estimator. Its estimator is
    /// fed every event the angle's is, and while the estimate comes from the angle (no torque
    /// table, or none of its events used yet) the report weighs the angle tables' posteriors by
    /// their probabilities ([`Report::angle_tables`]). Needs the observer's own angle table,
    /// and a table of the same angle sensor.
    ///
    /// Its estimator (about 1.5 MB) is built at the first angle event fed while the torque
    /// has used none ([`Self::angle_estimators_mut`]): once the estimate comes from the
    /// torque, the angle's variants can no longer move it, so a car whose torque is live from
    /// its first event never builds them, and lets their tables go at that event
    /// ([`Self::torque_takes_event`]; so does a baseline event with a live torque; after
    /// [`Self::reset_estimator`] the angle is then read with its own table alone until the
    /// torque takes an event again). It is checked here
    /// (`Estimator::check`), so that a table the estimator refuses is refused now.
    pub fn with_angle_alternative(mut self, alt: Alternative) -> anyhow::Result<Observer> {
        let Some(nominal) = self.table.as_ref() else {
            anyhow::bail!(
                "angle table alternative `{}` without a nominal angle table",
                alt.name
            );
        };
        let a = CheckedAlternative::new(
            alt,
            nominal,
            &self.angle_alternatives,
            &self.angle_deferred,
            self.cfg.estimator.clone(),
            "angle",
        )?;
        self.angle_deferred.push(a);
        Ok(self)
    }

    /// Builds the angle's deferred alternatives ([`Self::with_angle_alternative`]) once the
    /// estimate comes from the angle: without a torque channel, or before its first event.
    fn build_angle_alternatives(&mut self) {
        if self.angle_deferred.is_empty() || self.torque.as_ref().is_some_and(TorqueChannel::active)
        {
            return;
        }
        CheckedAlternative::build_all(
            &mut self.angle_deferred,
            &mut self.angle_alternatives,
            &self.cfg.estimator,
            &mut self.unbuilt,
        );
        self.share_scratch();
    }

    /// Says that the torque channel is about to take an event (of the drive, or of a baseline
    /// at known clearance): the bus carries a live torque, and the estimate comes from the
    /// torque from its first event of the drive on, so the angle's variants that are not built
    /// yet never will be, and their tables are let go before the torque's variants are built
    /// ([`Self::with_angle_alternative`]). A caller that feeds the estimators
    /// ([`Self::new_caller_fed`]) calls it before [`Self::torque_estimators_mut`].
    pub fn torque_takes_event(&mut self) {
        if self.torque.is_some() {
            self.angle_deferred = Vec::new();
        }
    }

    /// Builds the torque channel's deferred alternatives ([`Self::with_torque_alternative`]):
    /// at its first event.
    fn build_torque_alternatives(&mut self) {
        let cfg = self.torque_estimator_config();
        let Some(ch) = self.torque.as_mut().filter(|t| !t.deferred.is_empty()) else {
            return;
        };
        CheckedAlternative::build_all(
            &mut ch.deferred,
            &mut ch.alternatives,
            &cfg,
            &mut self.unbuilt,
        );
        self.share_scratch();
    }

    /// Lets the vehicle's estimators (the angle's, the torque's and its alternatives') use
    /// one per-event scratch ([`Estimator::share_scratch`]): they take an event one after
    /// another, and each table's estimator would otherwise keep its own copy (about 150 KB).
    fn share_scratch(&mut self) {
        if let Some(angle) = self.estimator.as_ref() {
            for a in &mut self.angle_alternatives {
                a.estimator.share_scratch(angle);
            }
        }
        let Some(t) = self.torque.as_mut() else {
            return;
        };
        if let Some(angle) = self.estimator.as_ref() {
            t.estimator.share_scratch(angle);
        }
        for a in &mut t.alternatives {
            a.estimator.share_scratch(&t.estimator);
        }
    }

    /// The chassis variant the estimate is read with ([`Self::with_torque_alternative`],
    /// [`Self::with_angle_alternative`]): its name when one of the alternatives of the channel
    /// the estimate comes from fits the events best, `None` otherwise (the nominal chassis, or
    /// no alternatives).
    pub fn chassis_variant(&self) -> Option<String> {
        self.chosen_alternative().map(|a| a.name.clone())
    }

    /// What to check on the car when [`Self::chassis_variant`] names a variant that has
    /// something to check ([`Alternative::inspect`]).
    pub fn chassis_variant_inspect(&self) -> Option<String> {
        self.chosen_alternative().and_then(|a| a.inspect.clone())
    }

    fn chosen_alternative(&self) -> Option<&TableAlternative> {
        self.mixture()?.chosen_alternative()
    }

    /// The tables of the channel the estimate comes from: the torque's once it has used an
    /// event, else the angle's; `None` without an angle table and before the torque's first.
    fn mixture(&self) -> Option<Mixture<'_>> {
        match &self.torque {
            Some(t) if t.active() => Some(t.mixture()),
            _ => self.angle_mixture(),
        }
    }

    /// The angle's tables: its own and its chassis variants'.
    fn angle_mixture(&self) -> Option<Mixture<'_>> {
        Some(Mixture {
            nominal: self.estimator.as_ref()?,
            alternatives: &self.angle_alternatives,
        })
    }

    /// The torque channel's estimators with their tables (the nominal first, then each
    /// alternative), for a caller that feeds them ([`Self::new_caller_fed`]); empty without a
    /// torque table. Each takes every torque event. The alternatives' estimators are built
    /// here, at the first call ([`Self::with_torque_alternative`]).
    pub fn torque_estimators_mut(
        &mut self,
    ) -> impl Iterator<Item = (&mut Estimator, &ResponseTable)> + '_ {
        self.build_torque_alternatives();
        self.torque.iter_mut().flat_map(|t| {
            std::iter::once((&mut t.estimator, &t.table)).chain(
                t.alternatives
                    .iter_mut()
                    .map(|a| (&mut a.estimator, &a.table)),
            )
        })
    }

    /// The estimator the goodness-of-fit check reads: the torque's once it has used an event
    /// (of its tables, the most probable), else the angle's. The estimate itself is
    /// [`Self::posterior`].
    pub fn active_estimator(&self) -> Option<&Estimator> {
        Some(self.mixture()?.chosen_estimator())
    }

    /// The clearance posterior the report reads: the torque channel's once it has used an
    /// event, else the angle's (with chassis variants, the mixture over the channel's tables
    /// weighed by how well the events fit each: [`posterior`]).
    pub fn posterior(&self) -> Option<posterior::Posterior<'_>> {
        Some(self.mixture()?.posterior())
    }

    /// As [`Self::new`], but the used events do not reach the estimator by themselves: the
    /// caller adds them through [`Self::angle_estimators_mut`], placed on its own odometer, and can
    /// start the posterior afresh with [`Self::reset_estimator`] (a daemon that restores its
    /// posterior from saved evidence). [`Self::report`] then reports what the caller fed.
    pub fn new_caller_fed(
        cfg: ObserverConfig,
        table: Option<ResponseTable>,
    ) -> anyhow::Result<Observer> {
        let mut obs = Self::new(cfg, table)?;
        obs.feeds_estimator = false;
        Ok(obs)
    }

    /// The angle's estimators with their tables (its own first, then each chassis variant's),
    /// for a caller that feeds them ([`Self::new_caller_fed`]); empty without a response
    /// table. Each takes every angle event. A caller that also feeds the torque's
    /// ([`Self::torque_estimators_mut`]) feeds them first: the chassis variants' angle
    /// estimators are built here, at the first call while the torque has used no event
    /// ([`Self::with_angle_alternative`]).
    pub fn angle_estimators_mut(
        &mut self,
    ) -> impl Iterator<Item = (&mut Estimator, &ResponseTable)> + '_ {
        self.build_angle_alternatives();
        self.estimator
            .as_mut()
            .zip(self.table.as_ref())
            .into_iter()
            .chain(
                self.angle_alternatives
                    .iter_mut()
                    .map(|a| (&mut a.estimator, &a.table)),
            )
    }

    /// Notes the wheel-order share ([`wheel_order`]) of an event the caller fed to the
    /// estimator of `signal` ([`Self::new_caller_fed`]), for the fit check.
    pub fn note_wheel_order(&mut self, signal: features::SteerSignal, share: f64) {
        let keep = self
            .cfg
            .features
            .wheel_order
            .window_events
            .clamp(1, MAX_WHEEL_ORDER_KEPT);
        let w = &mut self.wheel_order[wheel_order_slot(signal)];
        while w.len() >= keep {
            w.pop_front();
        }
        w.push_back(share);
    }

    /// The median wheel-order share of the events `signal`'s estimator took, once there are
    /// enough ([`wheel_order::median_share`]).
    pub fn wheel_order_share(&self, signal: features::SteerSignal) -> Option<f64> {
        wheel_order::median_share(
            self.wheel_order[wheel_order_slot(signal)].iter().copied(),
            &self.cfg.features.wheel_order,
        )
    }

    /// Replaces the estimator with a fresh one (no evidence). No-op without a response table.
    pub fn reset_estimator(&mut self) -> anyhow::Result<()> {
        self.wheel_order.iter_mut().for_each(|w| w.clear());
        if let Some(t) = self.table.as_ref() {
            self.estimator = Some(Estimator::new(t, self.cfg.estimator.clone())?);
        }
        for a in &mut self.angle_alternatives {
            a.estimator = Estimator::new(&a.table, self.cfg.estimator.clone())?;
        }
        let tcfg = self.torque_estimator_config();
        if let Some(t) = self.torque.as_mut() {
            t.estimator = Estimator::new(&t.table, tcfg.clone())?;
            for a in &mut t.alternatives {
                a.estimator = Estimator::new(&a.table, tcfg.clone())?;
            }
        }
        self.share_scratch();
        Ok(())
    }

    /// The `[estimator]` settings of the torque's estimator ([`ObserverConfig::torque_estimator`]).
    fn torque_estimator_config(&self) -> EstimatorConfig {
        self.cfg.torque_estimator()
    }

    pub fn push(&mut self, s: &Sample) {
        self.noise_floor.push(s);
        let Some(fin) = self.detector.push(s) else {
            self.note_ignored();
            return;
        };
        let (rec, feats, tq) =
            Self::measure_event(&self.cfg, &mut self.extractor, &mut self.torque, fin);
        self.on_event(rec, feats, tq);
    }

    /// Closes an event still open at the end of the input.
    pub fn finish(&mut self) {
        self.noise_floor.end_of_input();
        let Some(fin) = self.detector.flush() else {
            self.note_ignored();
            return;
        };
        let (rec, feats, tq) =
            Self::measure_event(&self.cfg, &mut self.extractor, &mut self.torque, fin);
        self.on_event(rec, feats, tq);
    }

    /// The goodness-of-fit check of the estimate now (src/observer/fit.rs), the sensor-noise
    /// check ([`noise_floor`]) included, and, when the model does not fit, why (the clause
    /// the report's verdict and the clearance alert carry). `(None, None)` before the check
    /// has anything to judge.
    pub fn fit_check(&self) -> (Option<fit::ModelFit>, Option<String>) {
        self.fit_check_with(&self.measured_noise())
    }

    /// [`Self::fit_check`] on the noise already measured ([`Self::measured_noise`]).
    fn fit_check_with(
        &self,
        measured: &[noise_floor::MeasuredNoise],
    ) -> (Option<fit::ModelFit>, Option<String>) {
        let z_max = self.cfg.estimator.fit_z_max;
        let torque_active = self.torque.as_ref().is_some_and(TorqueChannel::active);
        let active_signal = if torque_active {
            features::SteerSignal::TorqueNm
        } else {
            features::SteerSignal::AngleDeg
        };
        let noisy = measured
            .iter()
            .find(|n| n.above_assumed && n.signal == active_signal);
        let wo_cfg = &self.cfg.features.wheel_order;
        let wheel_order = self.wheel_order_share(active_signal);
        let judder = wheel_order.filter(|&m| wo_cfg.share_max > 0.0 && m > wo_cfg.share_max);
        let discs_ruled_out =
            judder.is_some() && self.mixture().is_some_and(Mixture::rules_out_discs);
        let Some((e, (dev, dof))) = self.active_estimator().and_then(|e| Some((e, e.fit()?)))
        else {
            return (None, None);
        };
        // A correction whose features' gains disagree says the car model is not the table's.
        let disagreeing = e
            .correction()
            .and_then(|c| Some((c, c.gains_agree_p?)))
            .filter(|&(_, p)| p < correction::GAINS_DISAGREE_P);
        let mut f = fit::ModelFit::new(dev, dof, z_max);
        f.set_sensor_noisier(noisy.is_some());
        f.set_wheel_order(wheel_order, judder.is_some());
        f.wheel_order_discs_ruled_out = discs_ruled_out;
        f.set_correction_gains_disagree(disagreeing.is_some());
        f.ln_evidence = e.ln_evidence().map(|l| l[0]);
        f.ln_evidence_untempered = e.ln_evidence().map(|l| l[1]);
        let why = match (noisy, judder, disagreeing) {
            _ if f.fits => None,
            (Some(n), _, _) => Some(format!(
                "its steering {} sensor is noisier than the response table assumes ({:.3} {u} \
                 RMS measured at standstill over {} stops, {:.3} {u} assumed), so the interval \
                 is not to be trusted; rebuild the table for this sensor (`shimmy calibrate{} \
                 --sensor-noise-deg {:.3}`, see docs/ACCURACY.md)",
                if n.signal.is_angle() {
                    "angle"
                } else {
                    "torque"
                },
                n.measured_rms,
                n.stops,
                n.assumed_rms,
                if n.signal.is_angle() {
                    ""
                } else {
                    " --signal torque"
                },
                n.measured_rms,
                u = n.signal.unit()
            )),
            (None, Some(share), _) => {
                let shake = format!(
                    "its steering shakes at the wheels' rotation while braking, beyond what it \
                     does before the brake ({:.0} % of the braking band's power in that line, \
                     median over {} events; limit {:.0} %)",
                    100.0 * share,
                    self.wheel_order[wheel_order_slot(active_signal)].len(),
                    100.0 * wo_cfg.share_max
                );
                Some(if discs_ruled_out {
                    let read_with = self.chosen_alternative();
                    format!(
                        "{shake}, but its events rule uneven brake discs out (the profile's table \
                         for them fits them far worse than the one for {}): the shake is its \
                         chassis's own, which the table it is read with describes only in \
                         general, so the interval is not to be trusted; check {} and the wheels' \
                         balance first",
                        read_with.map_or(NOMINAL_TABLE, |a| a.name.as_str()),
                        read_with
                            .and_then(|a| a.inspect.as_deref())
                            .unwrap_or("the steering geometry (the wheels' offset)")
                    )
                } else {
                    format!(
                        "{shake}: a brake-torque variation (disc thickness variation, brake \
                         judder) shakes the steering whatever the joints, so the interval is not \
                         to be trusted; check the front brake discs' thickness variation and \
                         run-out first (docs/ACCURACY.md, \"A brake-torque variation\")"
                    )
                })
            }
            (None, None, Some((c, p))) => Some(format!(
                "its car model's correction (fitted by `shimmy fleet-fit` on {} vehicles at new \
                 joints) finds the {} features' gains unequal (braking RMS ×{:.2}, peak ×{:.2}, \
                 cruise ×{:.2}; p = {p:.3} that they are one gain, limit {}): this car model \
                 passes the wheels' motion on to the steering otherwise than the response \
                 table's model, by more than a gain (a scrub radius, brake discs, another \
                 steering column), so the interval is not to be trusted; build a table for its \
                 chassis (docs/ADDING_A_CAR.md, \"Chassis\")",
                c.vehicles,
                if active_signal.is_angle() {
                    "steering-angle"
                } else {
                    "torque"
                },
                c.gain[0],
                c.gain[1],
                c.gain[2],
                correction::GAINS_DISAGREE_P
            )),
            (None, None, None) => Some(format!(
                "its events scatter more about every clearance's prediction than the response \
                 table's vehicles do (goodness of fit z = {:.1} over {:.0} features, limit \
                 {z_max:.1}), so the interval is not to be trusted; see docs/ACCURACY.md",
                f.z, f.dof
            )),
        };
        (Some(f), why)
    }

    /// The steering sensors' noise measured at standstill so far: each channel with a
    /// measurement, against what its features assume.
    pub fn measured_noise(&self) -> Vec<noise_floor::MeasuredNoise> {
        use noise_floor::Channel;
        let ratio = self.cfg.features.noise_floor_ratio;
        let mut out = Vec::new();
        // What the tables' events were simulated with (MODEL.md §8 sensor model): white noise
        // and quantisation.
        let angle_assumed = self.table.as_ref().map_or_else(
            || {
                let n = self.cfg.features.sensor;
                n.quant_step_deg.powi(2) / 12.0 + n.noise_deg.powi(2)
            },
            |t| t.sensor.step_deg.powi(2) / 12.0 + t.sensor.noise_deg.powi(2),
        );
        let torque_assumed = self
            .torque
            .as_ref()
            .map(|t| t.noise.quant_step_deg.powi(2) / 12.0 + t.noise.noise_deg.powi(2));
        for (ch, signal, assumed) in [
            (
                Channel::Angle,
                features::SteerSignal::AngleDeg,
                Some(angle_assumed),
            ),
            (
                Channel::Torque,
                features::SteerSignal::TorqueNm,
                torque_assumed,
            ),
        ] {
            if let (Some(m), Some(a)) = (self.noise_floor.variance(ch), assumed) {
                out.push(noise_floor::MeasuredNoise {
                    signal,
                    measured_rms: m.sqrt(),
                    assumed_rms: a.sqrt(),
                    stops: self.noise_floor.stops(ch),
                    above_assumed: self.noise_floor.exceeds(ch, a, ratio),
                });
            }
        }
        out
    }

    /// The standstill noise meter, for a caller that saves it with its state.
    pub fn noise_floor(&self) -> &noise_floor::NoiseFloor {
        &self.noise_floor
    }

    /// Puts back a saved standstill noise meter (a daemon's restart).
    pub fn set_noise_floor(&mut self, n: noise_floor::NoiseFloor) {
        self.noise_floor = n;
    }

    /// The torque features of a finished event, with a torque channel: `None` without one,
    /// `Some(None)` when the event has no torque, too few samples or a torque that never moved.
    fn measure_torque(
        cfg: &ObserverConfig,
        torque: &mut Option<TorqueChannel>,
        fin: &crate::events::Finished<'_>,
    ) -> Option<Option<Features>> {
        let ch = torque.as_mut()?;
        Some(Self::torque_features(&mut ch.extractor, cfg, ch.noise, fin))
    }

    /// The torque features over the same window as [`Self::measure`]'s, in N·m; `None` when
    /// the torque is absent, too short, or constant (a bus sending a dead value).
    pub(crate) fn torque_features(
        extractor: &mut Extractor,
        cfg: &ObserverConfig,
        noise: features::SensorNoise,
        fin: &crate::events::Finished<'_>,
    ) -> Option<Features> {
        let tq = fin.torque;
        let first = tq.first()?.1;
        if tq.iter().all(|x| x.1 == first) {
            return None;
        }
        let rec = &fin.record;
        let t0 = (rec.t_start_s * 1e9).round() as i64;
        let t1 = ((rec.t_end_s + cfg.events.tail_s) * 1e9).round() as i64;
        extractor
            .extract_signal(
                features::SteerSignal::TorqueNm,
                tq,
                t0,
                t1,
                noise,
                noise.quant_step_deg,
            )
            .ok()
    }

    /// Keeps the application the detector just ignored, if it ignored one.
    fn note_ignored(&mut self) {
        if self.detector.ignored == self.ignored_seen {
            return;
        }
        self.ignored_seen = self.detector.ignored;
        if let (true, Some(a)) = (
            self.ignored.len() < MAX_IGNORED_KEPT,
            self.detector.last_ignored(),
        ) {
            self.ignored.push(*a);
        }
    }

    /// What braking produced so far: applications ignored, events recorded, used and not used
    /// per reason.
    pub fn rejections(&self) -> Rejections {
        Rejections {
            ignored: self.detector.ignored,
            ignored_by_reason: self.detector.ignored_by_reason,
            recorded: self.events_seen(),
            used: self.used_total,
            unused_by_reason: self.unused,
        }
    }

    /// [`Self::rejections`] as a sentence: the counts, then the likely cause when one stands out
    /// and, with `suggest_doctor`, a pointer to `shimmy doctor`.
    pub fn explain_rejections(&self, suggest_doctor: bool) -> String {
        self.rejections().explain(
            &self.cfg.events,
            self.detector.decel_from_accel(),
            suggest_doctor,
        )
    }

    /// The ignored brake applications kept (the first [`MAX_IGNORED_KEPT`]).
    pub fn ignored_applications(&self) -> &[IgnoredApplication] {
        &self.ignored
    }

    /// The observer's configuration.
    pub fn config(&self) -> &ObserverConfig {
        &self.cfg
    }

    /// The features of a finished event over its braking window plus the configured tail
    /// (MODEL.md §11). Takes the fields it needs, not `self`, because `fin` borrows the detector.
    /// The table builder (`simulate`) measures model events with this same function.
    pub(crate) fn measure(
        extractor: &mut Extractor,
        cfg: &ObserverConfig,
        fin: crate::events::Finished<'_>,
    ) -> (crate::events::EventRecord, Option<Features>) {
        let rec = fin.record;
        let t0 = (rec.t_start_s * 1e9).round() as i64;
        let t1 = ((rec.t_end_s + cfg.events.tail_s) * 1e9).round() as i64;
        let feats = extractor
            .extract(
                fin.samples,
                t0,
                t1,
                cfg.features.sensor,
                rec.quality.quant_step_deg,
            )
            .ok();
        (rec, feats)
    }

    /// A finished event's features as [`Self::measure`] and [`Self::measure_torque`] take
    /// them, each with its wheel-order share ([`wheel_order`]) from the signal its extractor
    /// just band-passed: the monitored vehicle's events, not the table builder's (which needs
    /// no share).
    fn measure_event(
        cfg: &ObserverConfig,
        extractor: &mut Extractor,
        torque: &mut Option<TorqueChannel>,
        fin: crate::events::Finished<'_>,
    ) -> (
        crate::events::EventRecord,
        Option<Features>,
        Option<Option<Features>>,
    ) {
        let speed = fin.speed;
        let with_share = |f: Features, ex: &Extractor| Features {
            wheel_order_share: ex
                .last_windowed()
                .and_then(|w| wheel_order::share(&w, speed, &cfg.features.wheel_order)),
            ..f
        };
        let tq = Self::measure_torque(cfg, torque, &fin).map(|tf| {
            let ex = &torque
                .as_ref()
                .expect("measured with a torque channel")
                .extractor;
            tf.map(|f| with_share(f, ex))
        });
        let (rec, feats) = Self::measure(extractor, cfg, fin);
        (rec, feats.map(|f| with_share(f, extractor)), tq)
    }

    /// The amplitude estimate for features `f` (deg).
    pub fn amplitude_deg(&self, f: &Features) -> f64 {
        match self
            .table
            .as_ref()
            .and_then(|t| t.amplitude_deg(f.excess_rms_deg))
        {
            Some(a) => a,
            None => self.cfg.features.crest_factor * f.excess_rms_deg,
        }
    }

    fn on_event(
        &mut self,
        rec: crate::events::EventRecord,
        feats: Option<Features>,
        torque_feats: Option<Option<Features>>,
    ) {
        let torque_out = torque_feats.map(|tf| self.on_torque(&rec, tf));
        let mut used = rec.used && feats.is_some();
        let mut reason = rec.unused_reason;
        if rec.used && feats.is_none() {
            reason = Some(Unused::MissingData);
            used = false;
        }
        if let (true, Some(t)) = (used, self.table.as_ref()) {
            let q = &rec.quality;
            if !t.sensor.matches(q.sample_hz, q.quant_step_deg) {
                reason = Some(Unused::SensorMismatch);
                used = false;
                self.sensor_mismatch += 1;
                self.last_mismatch = (q.sample_hz, q.quant_step_deg);
            }
        }
        match (used, reason) {
            (true, _) => self.used_total += 1,
            (false, Some(r)) => self.unused.add(r),
            (false, None) => {}
        }
        let amp = feats.as_ref().map(|f| self.amplitude_deg(f));
        if let (true, true, Some(f), true) = (
            self.feeds_estimator,
            used,
            feats.as_ref(),
            self.estimator.is_some(),
        ) {
            for (est, t) in self.angle_estimators_mut() {
                feed_event(est, t, f, &rec);
            }
            if let Some(x) = f.wheel_order_share {
                self.note_wheel_order(features::SteerSignal::AngleDeg, x);
            }
        }
        let out = EventOut {
            t_start: rec.t_start_s,
            t_end: rec.t_end_s,
            v0_kmh: rec.v0_kmh,
            decel_g: rec.decel_g,
            peak_sw_bp_deg: feats.map(|f| f.peak_deg),
            used,
            unused_reason: reason,
            rms_sw_bp_deg: feats.map(|f| f.rms_deg),
            cruise_rms_sw_bp_deg: feats.and_then(|f| f.cruise_rms_deg),
            wheel_order_share: feats.and_then(|f| f.wheel_order_share),
            sw_amplitude_deg: amp,
            duration_s: rec.duration_s(),
            sample_hz: rec.quality.sample_hz,
            quant_step_deg: rec.quality.quant_step_deg,
            missing_samples: rec.quality.missing_samples,
            invalid_updates: rec.quality.invalid_updates,
            torque: torque_out,
        };
        if self.events.len() >= MAX_EVENTS_KEPT {
            self.events_dropped += 1;
        } else {
            self.events.push(out.clone());
        }
        self.last_event = Some(out);
        self.last_event_odometer_m = rec.odometer_m;
    }

    /// The torque side of one finished event: whether its torque is usable, and (when this
    /// observer feeds its estimators) the torque estimator's update.
    fn on_torque(
        &mut self,
        rec: &crate::events::EventRecord,
        tf: Option<Features>,
    ) -> TorqueEventOut {
        let feeds = self.feeds_estimator;
        let ch = self.torque.as_mut().expect("called with a torque channel");
        let reason = match &tf {
            _ if !rec.used => rec.unused_reason.map(unused_name),
            None => Some("no_torque"),
            Some(f) if !ch.table.sensor.matches(f.fs_hz, 0.0) => Some("sensor_mismatch"),
            Some(_) => None,
        };
        let used = reason.is_none();
        if used {
            ch.used += 1;
        } else if rec.used {
            ch.without += 1;
        }
        if let (true, true, Some(f)) = (feeds, used, tf.as_ref()) {
            self.torque_takes_event();
            for (est, t) in self.torque_estimators_mut() {
                feed_event(est, t, f, rec);
            }
            if let Some(x) = f.wheel_order_share {
                self.note_wheel_order(features::SteerSignal::TorqueNm, x);
            }
        }
        TorqueEventOut {
            rms_bp_nm: tf.map(|f| f.rms_deg),
            peak_bp_nm: tf.map(|f| f.peak_deg),
            cruise_rms_bp_nm: tf.and_then(|f| f.cruise_rms_deg),
            wheel_order_share: tf.and_then(|f| f.wheel_order_share),
            sample_hz: tf.map(|f| f.fs_hz),
            used,
            unused_reason: reason,
        }
    }

    /// The events kept for the report (at most [`MAX_EVENTS_KEPT`]).
    pub fn events(&self) -> &[EventOut] {
        &self.events
    }

    /// Every event finished so far, kept in [`Self::events`] or not: a streaming consumer
    /// compares this with its own count to see that a new event finished.
    pub fn events_seen(&self) -> u64 {
        self.events.len() as u64 + self.events_dropped
    }

    /// The most recently finished event, also when the kept list is full.
    pub fn last_event(&self) -> Option<&EventOut> {
        self.last_event.as_ref()
    }

    /// Distance (m) driven since the most recent event's brake onset, on the detector's
    /// odometer: what a caller with its own odometer subtracts to place the event where the
    /// estimator of [`Self::report`] places it.
    pub fn distance_since_last_event_m(&self) -> f64 {
        (self.detector.odometer_m() - self.last_event_odometer_m).max(0.0)
    }

    pub fn estimator(&self) -> Option<&Estimator> {
        self.estimator.as_ref()
    }

    pub fn report(&self) -> Report {
        let a = &self.cfg.alerts;
        let active = self.active_estimator();
        let summary = self
            .posterior()
            .map(|p| (p.summary(), p.prob_above(a.clearance_mm)))
            .filter(|(s, _)| s.events_used > 0);
        let rej = self.rejections();
        let why = || self.explain_rejections(true);
        let (clearance_mm, interval_mm, detectable, below_mm, verdict) = match summary {
            None => (
                None,
                None,
                false,
                None,
                if self.table.is_none() {
                    if rej.worth_reporting() {
                        format!("no response table: clearance not estimated; {}", why())
                    } else {
                        "no response table: clearance not estimated".to_string()
                    }
                } else if let (true, Some(t)) = (self.sensor_mismatch > 0, self.table.as_ref()) {
                    format!(
                        "no usable braking events: {} came through a steering angle sensor \
                         other than the response table's (measured {:.1} Hz, {} deg steps; \
                         table {} Hz, {} deg): rebuild the table with `shimmy calibrate \
                         --sensor-rate-hz --sensor-step-deg`",
                        self.sensor_mismatch,
                        self.last_mismatch.0,
                        self.last_mismatch.1,
                        t.sensor.rate_hz,
                        t.sensor.step_deg
                    )
                } else {
                    format!(
                        "no usable braking events: clearance not estimated: {}",
                        why()
                    )
                },
            ),
            Some((s, _)) if s.detectable => (
                Some(s.median_mm),
                Some([s.q05_mm, s.q95_mm]),
                true,
                None,
                format!(
                    "clearance {:.3} mm (90 % interval {:.3}-{:.3} mm, {} events)",
                    s.median_mm, s.q05_mm, s.q95_mm, s.events_used
                ),
            ),
            Some((s, _)) => (
                None,
                Some([s.q05_mm, s.q95_mm]),
                false,
                Some(s.below_mm),
                format!("below {:.2} mm ({} events)", s.below_mm, s.events_used),
            ),
        };
        let torque_tables = self
            .torque
            .as_ref()
            .map(|t| t.mixture().evidence())
            .unwrap_or_default();
        let angle_tables = self
            .angle_mixture()
            .map(Mixture::evidence)
            .unwrap_or_default();
        let verdict = match &self.torque {
            Some(t) if t.active() => read_with(
                format!("{verdict} from the steering torque"),
                &torque_tables,
                "torque",
            ),
            _ if summary.is_some() => read_with(verdict, &angle_tables, "angle"),
            _ => verdict,
        };
        let sensor_noise = self.measured_noise();
        let (model_fit, misfit) = self.fit_check_with(&sensor_noise);
        let mut verdict = match misfit {
            Some(why) => format!("{verdict}; but the model does not fit this vehicle: {why}"),
            None => verdict,
        };
        for e in &self.unbuilt {
            verdict += &format!("; a chassis variant's table was left out: {e}");
        }
        Report {
            median_mm: summary.map(|s| s.0.median_mm),
            clearance_mm,
            interval_mm,
            detectable,
            below_mm,
            verdict,
            events: self.events.clone(),
            events_used: self.events.iter().filter(|e| e.used).count() as u32,
            brake_applications_ignored: self.detector.ignored,
            rejections: rej,
            ignored_applications: self.ignored.clone(),
            events_dropped: self.events_dropped,
            events_sensor_mismatch: self.sensor_mismatch,
            p_clearance_above_threshold: summary.map(|s| s.1),
            signals: self.torque.as_ref().map(|t| SignalUse {
                estimate_from: if t.active() {
                    features::SteerSignal::TorqueNm
                } else {
                    features::SteerSignal::AngleDeg
                },
                events_used_torque: t.used,
                events_without_torque: t.without,
            }),
            torque_tables,
            angle_tables,
            p_wheel_phase_fixed: active.and_then(|e| e.phase_fixed_probability()),
            model_fit,
            sensor_noise,
            correction: active.and_then(|e| e.correction().cloned()),
        }
    }
}
