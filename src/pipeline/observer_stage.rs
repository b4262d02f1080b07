//! The adapter between the pipeline's [`EventStage`] seam and the clearance observer
//! ([`crate::observer::Observer`]): feeds it the pipeline's samples, hands back each newly
//! finished braking event as an [`EventSummary`], and reports the clearance posterior as an
//! [`Estimate`]. shimmyd and `shimmy estimate` both run the observer through it
//! ([`super::Monitor`], [`super::finish_event`]), so the alert rules see the same events and
//! estimates in both.
//!
//! Persistence across restarts (shimmyd's state file): the observer runs caller-fed
//! ([`Observer::new_caller_fed`]): this adapter hands its estimator each used event's features,
//! placed at the caller's odometer at the event's brake onset (the distance the wear model
//! sees), and keeps them. [`EventStage::save`] returns that evidence, one [`Evidence`] per used
//! event, and [`EventStage::restore`] replays it into a fresh estimator, so an estimate
//! keeps accumulating across daemon runs: two runs over logs A then B end with the same
//! posterior as one run over A+B (replaying the evidence is exact). The observer's report and
//! the stage's [`Estimate`] read the same estimator. At most [`MAX_EVIDENCE`] events are kept; past
//! that the oldest are left out of the saved state, counted in [`Saved::evidence_dropped`] and
//! named in the log line at the next start (their weight is already small after the wear
//! model's diffusion over the distance since).
//!
//! A joint replacement ([`ObserverStage::joints_replaced`]): the evidence and the baseline,
//! which describe the old joints, are forgotten (the sensors' noise floor is kept), and the
//! next used events are collected, feeding nothing else, until there are as many as asked;
//! they then become the vehicle's baseline at the new joints' clearance
//! ([`ObserverStage::set_baseline`]) and estimation goes on from there. The collection and the
//! baseline it made are saved ([`Saved::collecting`], [`Saved::from_replacement`]), so a restart
//! in the middle resumes it, and such a baseline takes the place of one given at start
//! (`vehicle.baseline_logs`) unless the caller says the given one is newer
//! ([`ObserverStage::restore_with`]).
//!
//! What it is not: a detector, an estimator or an alert rule. Detection and the amplitude
//! estimate (MODEL.md §11) are the observer's; the alert rules are [`crate::alerts`]'.

use std::collections::VecDeque;

use anyhow::Context;
use serde::{Deserialize, Serialize};

use crate::monitor::{Estimate, EventStage, EventSummary, RejectionSummary, Sample};
use crate::observer::estimator::Estimator;
use crate::observer::table::ResponseTable;
use crate::observer::{EventOut, Observer, ObserverConfig};

/// Most used events whose evidence is kept for the posterior's restore.
pub const MAX_EVIDENCE: usize = 2000;

/// The response tables of one vehicle: the steering angle's and, where the car's bus carries
/// the EPS torque and its profile names one, the torque's. An `Option<ResponseTable>` converts
/// to the angle table alone.
#[derive(Clone, Debug, Default)]
pub struct Tables {
    pub angle: Option<ResponseTable>,
    pub torque: Option<ResponseTable>,
    /// Torque tables of structural alternatives of the chassis, by name
    /// ([`Observer::with_torque_alternative`]); used only beside `torque`.
    pub torque_alternatives: Vec<crate::observer::Alternative>,
    /// Angle tables of structural alternatives of the chassis, by name
    /// ([`Observer::with_angle_alternative`]); used only beside `angle`.
    pub angle_alternatives: Vec<crate::observer::Alternative>,
}

impl From<Option<ResponseTable>> for Tables {
    fn from(angle: Option<ResponseTable>) -> Tables {
        Tables {
            angle,
            ..Tables::default()
        }
    }
}

/// One used event as the estimator saw it.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub struct Evidence {
    /// MODEL.md §11 band-passed steering-wheel RMS and peak (deg); NaN (null in the state)
    /// for an event only the torque used.
    #[serde(deserialize_with = "nan_if_null")]
    pub rms_deg: f64,
    #[serde(deserialize_with = "nan_if_null")]
    pub peak_deg: f64,
    /// Pre-brake cruise RMS (deg), when measured (absent in states written before it existed).
    #[serde(default)]
    pub cruise_rms_deg: Option<f64>,
    /// The angle's wheel-order share (src/observer/wheel_order.rs), when measured (absent in
    /// states written before it existed).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub wheel_order_share: Option<f64>,
    pub v0_kmh: f64,
    pub decel_g: f64,
    /// Daemon odometer when the event finished (m).
    pub odometer_m: f64,
    /// With a torque table: the event's band-passed torque RMS, peak and pre-brake RMS (N·m)
    /// when the torque's estimator used it.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub torque_nm: Option<TorqueEvidence>,
}

/// A number, or NaN where the state holds null (serde_json writes NaN as null).
fn nan_if_null<'de, D: serde::Deserializer<'de>>(d: D) -> Result<f64, D::Error> {
    Ok(Option::<f64>::deserialize(d)?.unwrap_or(f64::NAN))
}

/// The torque features of one used event (N·m).
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub struct TorqueEvidence {
    pub rms: f64,
    pub peak: f64,
    #[serde(default)]
    pub cruise_rms: Option<f64>,
    /// The torque's wheel-order share, when measured.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub wheel_order_share: Option<f64>,
}

/// What [`ObserverStage`] saves in the daemon's state.
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
#[serde(default)]
pub struct Saved {
    pub evidence: Vec<Evidence>,
    /// Used events older than the kept evidence (not replayed at restore).
    pub evidence_dropped: u64,
    /// The vehicle's baseline (events at a known clearance), when it has one.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub baseline: Option<Baseline>,
    /// The steering sensors' noise measured at standstill so far (the stops kept).
    pub noise_floor: crate::observer::noise_floor::NoiseFloor,
    /// A baseline being collected after a joint replacement (absent otherwise).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub collecting: Option<Collecting>,
    /// `baseline` (or `collecting`) comes from a joint replacement the stage was told of while
    /// running ([`ObserverStage::joints_replaced`]), not from a baseline given at start.
    #[serde(default, skip_serializing_if = "std::ops::Not::not")]
    pub from_replacement: bool,
}

/// A baseline being collected after a joint replacement: the next `target` used events, driven
/// at `clearance_mm` (the new joints'), of which `evidence` holds those seen so far.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct Collecting {
    /// The new joints' clearance (mm).
    pub clearance_mm: f64,
    /// How many used events make the baseline (≥ 1).
    pub target: u32,
    pub evidence: Vec<Evidence>,
}

impl Collecting {
    /// Used events collected so far.
    pub fn collected(&self) -> u32 {
        u32::try_from(self.evidence.len()).unwrap_or(u32::MAX)
    }
}

/// Events of the vehicle at a known clearance (its first ones after the joints were
/// replaced): what they say about the vehicle conditions every later estimate
/// ([`crate::observer::estimator::Estimator::update_baseline`]).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct Baseline {
    /// The joints' clearance when the events were driven (mm).
    pub clearance_mm: f64,
    pub evidence: Vec<Evidence>,
}

/// How many baseline events each estimator took.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize)]
pub struct BaselineUse {
    pub angle_events: u32,
    pub torque_events: u32,
}

/// [`EventStage`] over the real observer.
pub struct ObserverStage {
    obs: Observer,
    /// Events already handed to the daemon (compared with `Observer::events_seen`, which keeps
    /// counting past the observer's bounded event list).
    seen: u64,
    has_table: bool,
    clearance_mm: f64,
    evidence: VecDeque<Evidence>,
    evidence_dropped: u64,
    odometer_km: f64,
    baseline: Option<Baseline>,
    /// The baseline being collected after a joint replacement.
    collecting: Option<Collecting>,
    /// `baseline` / `collecting` come from a joint replacement ([`Saved::from_replacement`]).
    from_replacement: bool,
    /// A collection completed since [`ObserverStage::take_completed_baseline`] last looked.
    completed: Option<BaselineUse>,
}

impl ObserverStage {
    /// Runs the observer on the monitor's settings (`settings`, config/observer.toml's schema;
    /// the estimate's `p_above` is for `settings.alerts.clearance_mm`); `table` is the response
    /// table (without it events and amplitudes still flow, no clearance estimate).
    pub fn new(
        settings: &ObserverConfig,
        table: Option<ResponseTable>,
    ) -> anyhow::Result<ObserverStage> {
        let oc = settings.clone();
        let has_table = table.is_some();
        Ok(ObserverStage {
            obs: Observer::new_caller_fed(oc.clone(), table).context("observer.estimator")?,
            seen: 0,
            has_table,
            clearance_mm: oc.alerts.clearance_mm,
            evidence: VecDeque::new(),
            evidence_dropped: 0,
            odometer_km: 0.0,
            baseline: None,
            collecting: None,
            from_replacement: false,
            completed: None,
        })
    }

    /// The used events kept (oldest first), as the estimators took them.
    pub fn evidence(&self) -> impl Iterator<Item = &Evidence> {
        self.evidence.iter()
    }

    /// Gives the estimators a baseline: `baseline`'s events, at its known clearance, condition
    /// every estimate from now on (and after a restore). Replaces an earlier baseline's
    /// evidence only at the next restore; call it before the first event. Returns how many
    /// events each estimator took (none without a table, or with the `"mixture"` method).
    pub fn set_baseline(&mut self, baseline: Baseline) -> BaselineUse {
        let used = self.apply_baseline(&baseline);
        self.baseline = Some(baseline);
        used
    }

    /// The baseline in use, when there is one.
    pub fn baseline(&self) -> Option<&Baseline> {
        self.baseline.as_ref()
    }

    /// The joints were just replaced; the new ones have `clearance_mm`. Forgets what the
    /// estimators learnt from the old joints (every used event's evidence, and the baseline),
    /// keeps the sensors' noise floor, and takes the next `events` used events as the
    /// vehicle's new baseline at that clearance: until there are that many they feed nothing
    /// but the collection (the estimate then has no event: no clearance is claimed), then
    /// [`Self::set_baseline`] is called with them and estimation goes on as usual. A
    /// collection in progress starts over. Errors, changing nothing, without a response table
    /// (nothing to reset or condition), on a clearance that is not above 0 or on `events` = 0.
    pub fn joints_replaced(&mut self, clearance_mm: f64, events: u32) -> anyhow::Result<()> {
        anyhow::ensure!(
            self.has_table,
            "no response table (vehicle.table): there is no clearance estimate to reset and no \
             baseline to collect"
        );
        anyhow::ensure!(
            clearance_mm.is_finite() && clearance_mm > 0.0,
            "the new joints' clearance must be above 0 mm (got {clearance_mm})"
        );
        anyhow::ensure!(events >= 1, "a baseline needs at least 1 event");
        self.obs.reset_estimator()?;
        self.evidence.clear();
        self.evidence_dropped = 0;
        self.baseline = None;
        self.completed = None;
        self.collecting = Some(Collecting {
            clearance_mm,
            target: events,
            evidence: Vec::with_capacity((events as usize).min(MAX_EVIDENCE)),
        });
        self.from_replacement = true;
        Ok(())
    }

    /// The baseline collection in progress after a joint replacement, if any.
    pub fn collecting(&self) -> Option<&Collecting> {
        self.collecting.as_ref()
    }

    /// Whether the baseline (or the collection) comes from a joint replacement.
    pub fn baseline_from_replacement(&self) -> bool {
        self.from_replacement
    }

    /// How many events each estimator took from a baseline whose collection completed since
    /// the last call (once per completion).
    pub fn take_completed_baseline(&mut self) -> Option<BaselineUse> {
        self.completed.take()
    }

    /// One used event into the collection; the last one turns it into the baseline.
    fn collect(&mut self, ev: Evidence) {
        let Some(c) = self.collecting.as_mut() else {
            return;
        };
        c.evidence.push(ev);
        if c.evidence.len() < c.target as usize {
            return;
        }
        if let Some(c) = self.collecting.take() {
            let used = self.set_baseline(Baseline {
                clearance_mm: c.clearance_mm,
                evidence: c.evidence,
            });
            self.completed = Some(used);
        }
    }

    /// Resumes from what [`EventStage::save`] returned in an earlier run; returns a line for
    /// the log. Which baseline conditions the estimate: one given now (set before this call,
    /// e.g. from `vehicle.baseline_logs`) takes the place of the saved one, except that a joint
    /// replacement's baseline or collection in the saved state ([`Saved::from_replacement`])
    /// is newer than a given one and takes its place, unless `given_is_newer` (the caller
    /// knows the given baseline changed since that replacement).
    pub fn restore_with(
        &mut self,
        saved: &serde_json::Value,
        given_is_newer: bool,
    ) -> anyhow::Result<Option<String>> {
        if !self.has_table {
            return Ok(Some(
                "the saved clearance posterior is not restored: no response table (vehicle.table)"
                    .into(),
            ));
        }
        let saved: Saved = serde_json::from_value(saved.clone())
            .context("the state's saved posterior does not parse")?;
        self.obs.reset_estimator()?;
        self.obs.set_noise_floor(saved.noise_floor.clone());
        self.evidence.clear();
        self.evidence_dropped = saved.evidence_dropped;
        let mut notes = Vec::new();
        let replacement = saved.from_replacement || saved.collecting.is_some();
        let given = self.baseline.is_some();
        if replacement && !(given && given_is_newer) {
            if given {
                notes.push(
                    "the baseline of the joint replacement takes the place of the one given at \
                     start (vehicle.baseline_logs): the replacement is newer"
                        .to_string(),
                );
            }
            self.baseline = saved.baseline.clone();
            self.collecting = saved.collecting.clone();
            self.from_replacement = true;
        } else {
            if replacement {
                notes.push(
                    "the baseline given at start (vehicle.baseline_logs) is newer than the joint \
                     replacement's, which is dropped"
                        .to_string(),
                );
            }
            // A baseline given now takes the place of the saved one.
            if self.baseline.is_none() {
                self.baseline = saved.baseline.clone();
            }
            self.collecting = None;
            self.from_replacement = false;
        }
        if let Some(c) = &self.collecting {
            if !(c.clearance_mm.is_finite() && c.clearance_mm > 0.0 && c.target >= 1) {
                notes.push(format!(
                    "the saved baseline collection (clearance {} mm, {} event(s)) is not \
                     valid and is dropped",
                    c.clearance_mm, c.target
                ));
                self.collecting = None;
            } else if c.evidence.len() >= c.target as usize {
                // Complete already (a state written by hand): it is the baseline.
                let c = self.collecting.take().expect("checked above");
                self.baseline = Some(Baseline {
                    clearance_mm: c.clearance_mm,
                    evidence: c.evidence,
                });
            }
        }
        if let Some(b) = self.baseline.clone() {
            self.apply_baseline(&b);
        }
        for ev in &saved.evidence {
            let angle_ok = ev.rms_deg.is_finite() && ev.peak_deg.is_finite();
            let torque_ok = ev
                .torque_nm
                .is_some_and(|t| t.rms.is_finite() && t.peak.is_finite());
            if (angle_ok || torque_ok)
                && [ev.v0_kmh, ev.decel_g, ev.odometer_m]
                    .iter()
                    .all(|x| x.is_finite())
            {
                self.apply(ev);
            } else {
                self.evidence_dropped += 1;
            }
        }
        let mut msg = format!(
            "clearance posterior restored from {} used event(s)",
            self.evidence.len()
        );
        if self.evidence_dropped > 0 {
            msg += &format!(
                " ({} older used event(s) not kept in the state and not replayed)",
                self.evidence_dropped
            );
        }
        if let Some(c) = &self.collecting {
            msg += &format!(
                "; collecting a baseline after a joint replacement: {} of {} events at {} mm",
                c.collected(),
                c.target,
                c.clearance_mm
            );
        } else if let (true, Some(b)) = (self.from_replacement, &self.baseline) {
            msg += &format!(
                "; baseline of the joint replacement: {} event(s) at {} mm",
                b.evidence.len(),
                b.clearance_mm
            );
        }
        for n in notes {
            msg += "; ";
            msg += &n;
        }
        Ok(Some(msg))
    }

    fn apply_baseline(&mut self, b: &Baseline) -> BaselineUse {
        let mut used = BaselineUse::default();
        if !self.has_table {
            return used;
        }
        for ev in &b.evidence {
            let (angle, torque) = self.route(ev, |est, table, rms, peak, cruise| {
                est.update_baseline(
                    table,
                    rms,
                    peak,
                    cruise,
                    ev.v0_kmh,
                    ev.decel_g,
                    b.clearance_mm,
                )
            });
            used.angle_events += u32::from(angle);
            used.torque_events += u32::from(torque);
        }
        used
    }

    /// Hands one event's features to the estimators that can take them: the angle's when its
    /// angle features are finite, the torque's when it has torque features. `feed(estimator,
    /// table, rms, peak, cruise rms)` says whether it took them; returns (angle, torque).
    fn route(
        &mut self,
        ev: &Evidence,
        mut feed: impl FnMut(&mut Estimator, &ResponseTable, f64, f64, Option<f64>) -> bool,
    ) -> (bool, bool) {
        // Every table of a channel (the nominal and its structural alternatives) takes the
        // event; the nominal's answer is the channel's. The torque's first, as the observer
        // feeds its own: whether the torque has used an event decides whether the angle's
        // chassis variants are built ([`Observer::angle_estimators_mut`]).
        let mut torque = None;
        if let Some(t) = ev.torque_nm {
            self.obs.torque_takes_event();
            for (est, table) in self.obs.torque_estimators_mut() {
                let took = feed(est, table, t.rms, t.peak, t.cruise_rms);
                torque.get_or_insert(took);
            }
        }
        let torque = torque.unwrap_or(false);
        let mut angle = None;
        if ev.rms_deg.is_finite() && ev.peak_deg.is_finite() {
            for (est, table) in self.obs.angle_estimators_mut() {
                let took = feed(est, table, ev.rms_deg, ev.peak_deg, ev.cruise_rms_deg);
                angle.get_or_insert(took);
            }
        }
        let angle = angle.unwrap_or(false);
        (angle, torque)
    }

    /// Adds the torsion-bar torque's response table ([`Observer::with_torque_table`]) and
    /// the torque tables of structural alternatives of the chassis beside it
    /// ([`Observer::with_torque_alternative`]); without a torque table the alternatives have
    /// nothing to go beside and are not used ([`Tables::torque_alternatives`]).
    pub fn with_torque_tables(
        mut self,
        table: Option<ResponseTable>,
        alternatives: Vec<crate::observer::Alternative>,
    ) -> anyhow::Result<Self> {
        if let Some(t) = table {
            self.obs = self.obs.with_torque_table(t).context("torque table")?;
            self.has_table = true;
            for a in alternatives {
                self.obs = self.obs.with_torque_alternative(a)?;
            }
        }
        Ok(self)
    }

    /// Adds the angle tables of structural alternatives of the chassis beside the stage's angle
    /// table ([`Observer::with_angle_alternative`]); without an angle table they have nothing
    /// to go beside and are not used ([`Tables::angle_alternatives`]).
    pub fn with_angle_alternatives(
        mut self,
        alternatives: Vec<crate::observer::Alternative>,
    ) -> anyhow::Result<Self> {
        if self.obs.estimator().is_some() {
            for a in alternatives {
                self.obs = self.obs.with_angle_alternative(a)?;
            }
        }
        Ok(self)
    }

    /// The observer behind the stage (its report: events, rejections, its own estimate).
    pub fn observer(&self) -> &Observer {
        &self.obs
    }

    fn take_new(&mut self) -> Option<EventSummary> {
        let n = self.obs.events_seen();
        if n == self.seen {
            return None;
        }
        // The observer finishes at most one event per pushed sample, so `last_event` is it.
        self.seen = n;
        let e = self.obs.last_event()?;
        let torque_nm = e
            .torque
            .and_then(|t| match (t.used, t.rms_bp_nm, t.peak_bp_nm) {
                (true, Some(rms), Some(peak)) => Some(TorqueEvidence {
                    rms,
                    peak,
                    cruise_rms: t.cruise_rms_bp_nm,
                    wheel_order_share: t.wheel_order_share,
                }),
                _ => None,
            });
        let angle = match (e.used, e.rms_sw_bp_deg, e.peak_sw_bp_deg) {
            (true, Some(rms), Some(peak)) => Some((rms, peak)),
            _ => None,
        };
        if angle.is_some() || torque_nm.is_some() {
            // An event the torque used but the angle did not (its angle sensor is not the
            // angle table's) keeps NaN angle features: replayed into the torque only.
            let (rms_deg, peak_deg) = angle.unwrap_or((f64::NAN, f64::NAN));
            let ev = Evidence {
                rms_deg,
                peak_deg,
                cruise_rms_deg: e.cruise_rms_sw_bp_deg,
                wheel_order_share: angle.and(e.wheel_order_share),
                v0_kmh: e.v0_kmh,
                decel_g: e.decel_g,
                // The daemon's odometer at the brake onset, as the observer's own estimator
                // places the event: the same distances between events on both paths.
                odometer_m: self.odometer_km * 1000.0 - self.obs.distance_since_last_event_m(),
                torque_nm,
            };
            if self.collecting.is_some() {
                self.collect(ev);
            } else {
                self.apply(&ev);
            }
        }
        self.obs.last_event().map(summary)
    }

    /// Adds one used event to the posteriors (the angle's when its angle features are finite,
    /// the torque's when it has torque features) and to the kept evidence.
    fn apply(&mut self, ev: &Evidence) {
        if !self.has_table {
            return;
        }
        let (angle, torque) = self.route(ev, |est, table, rms, peak, cruise| {
            est.update_event(
                table,
                rms,
                peak,
                cruise,
                ev.v0_kmh,
                ev.decel_g,
                ev.odometer_m,
            );
            true
        });
        use crate::observer::features::SteerSignal;
        if let (true, Some(x)) = (angle, ev.wheel_order_share) {
            self.obs.note_wheel_order(SteerSignal::AngleDeg, x);
        }
        if let (true, Some(x)) = (torque, ev.torque_nm.and_then(|t| t.wheel_order_share)) {
            self.obs.note_wheel_order(SteerSignal::TorqueNm, x);
        }
        if self.evidence.len() >= MAX_EVIDENCE {
            self.evidence.pop_front();
            self.evidence_dropped += 1;
        }
        self.evidence.push_back(*ev);
    }
}

fn summary(e: &EventOut) -> EventSummary {
    EventSummary {
        t_start: e.t_start,
        t_end: e.t_end,
        v0_kmh: e.v0_kmh,
        decel_g: e.decel_g,
        peak_sw_bp_deg: e.peak_sw_bp_deg,
        sw_amplitude_deg: e.sw_amplitude_deg,
        used: e.used,
        unused_reason: e
            .unused_reason
            .and_then(|r| serde_json::to_value(r).ok())
            .and_then(|v| v.as_str().map(str::to_owned)),
        // Filled in by the pipeline from its odometer (`super::finish_event`).
        odometer_km: 0.0,
        peak_torque_bp_nm: e.torque.and_then(|t| t.peak_bp_nm),
        torque_used: e.torque.map(|t| t.used),
    }
}

impl EventStage for ObserverStage {
    fn describe(&self) -> String {
        if self.has_table {
            "clearance observer: braking events, shimmy amplitude and clearance estimate".into()
        } else {
            "clearance observer without a response table (vehicle.table unset): braking events \
             and shimmy amplitude, no clearance estimate"
                .into()
        }
    }

    fn push(&mut self, s: &Sample) -> Option<EventSummary> {
        self.obs.push(s);
        self.take_new()
    }

    fn finish(&mut self) -> Option<EventSummary> {
        self.obs.finish();
        self.take_new()
    }

    fn odometer_km(&mut self, km: f64) {
        self.odometer_km = km;
    }

    fn rejections(&self) -> Option<RejectionSummary> {
        Some(RejectionSummary {
            counts: self.obs.rejections(),
            text: self.obs.explain_rejections(true),
        })
    }

    fn save(&self) -> Option<serde_json::Value> {
        if !self.has_table {
            return None;
        }
        serde_json::to_value(Saved {
            evidence: self.evidence.iter().copied().collect(),
            evidence_dropped: self.evidence_dropped,
            baseline: self.baseline.clone(),
            noise_floor: self.obs.noise_floor().clone(),
            collecting: self.collecting.clone(),
            from_replacement: self.from_replacement,
        })
        .ok()
    }

    /// [`ObserverStage::restore_with`]: a joint replacement's baseline (or collection) in the
    /// saved state is newer than a baseline given at start, and takes its place.
    fn restore(&mut self, saved: &serde_json::Value) -> anyhow::Result<Option<String>> {
        self.restore_with(saved, false)
    }

    fn estimate(&self) -> Option<Estimate> {
        let est = self.obs.posterior()?;
        let s = est.summary();
        let used = s.events_used > 0;
        let fit = if used {
            self.obs.fit_check()
        } else {
            (None, None)
        };
        Some(Estimate {
            clearance_mm: (used && s.detectable).then_some(s.median_mm),
            interval_mm: used.then_some([s.q05_mm, s.q95_mm]),
            detectable: used && s.detectable,
            below_mm: (used && !s.detectable).then_some(s.below_mm),
            p_above: used.then(|| est.prob_above(self.clearance_mm)),
            events_used: s.events_used,
            misfit: fit.1,
            chassis_variant: used.then(|| self.obs.chassis_variant()).flatten(),
            chassis_variant_inspect: used.then(|| self.obs.chassis_variant_inspect()).flatten(),
            wheel_order_shake: fit.0.is_some_and(|f| f.wheel_order_shake),
            wheel_order_discs_ruled_out: fit.0.is_some_and(|f| f.wheel_order_discs_ruled_out),
            sensor_noisier: fit.0.is_some_and(|f| f.sensor_noisier),
        })
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Brake applications of 0.8 s at 0.5 g at 72 km/h, one every 2 s, sampled at 10 Hz
    /// (too slow for estimation: cheap events that are still detected and reported).
    fn feed(stage: &mut ObserverStage, cycles: usize) -> usize {
        let mut found = 0;
        for k in 0..cycles * 20 {
            let t = k as f64 * 0.1;
            // Brake off first: the detector needs to see the onset.
            let braking = (k % 20) >= 12;
            let s = Sample {
                t_ns: (t * 1e9) as i64,
                steer_rad: Some(0.0),
                speed_mps: Some(20.0),
                accel_mps2: Some(if braking { -4.9 } else { 0.0 }),
                brake: Some(braking),
                steer_invalid: false,
                torque_nm: None,
            };
            found += stage.push(&s).is_some() as usize;
        }
        found + stage.finish().is_some() as usize
    }

    #[test]
    fn events_past_the_observers_report_cap_still_reach_the_daemon() {
        let mut stage = ObserverStage::new(&ObserverConfig::default(), None).unwrap();
        let cycles = crate::observer::MAX_EVENTS_KEPT + 5;
        assert_eq!(feed(&mut stage, cycles), cycles);
        assert_eq!(stage.obs.events().len(), crate::observer::MAX_EVENTS_KEPT);
        assert!(stage.estimate().is_none(), "no table: no estimate");
    }

    fn reference_table() -> ResponseTable {
        let path = concat!(
            env!("CARGO_MANIFEST_DIR"),
            "/config/vehicles/shimmy_reference/table.json"
        );
        ResponseTable::load(std::path::Path::new(path)).unwrap()
    }

    fn evidence(i: usize, level: f64) -> Evidence {
        let k = level * (1.0 + 0.1 * ((i * 7 % 11) as f64 / 10.0 - 0.5));
        Evidence {
            rms_deg: 0.09 * k,
            peak_deg: 0.24 * k,
            cruise_rms_deg: Some(0.035 * k),
            wheel_order_share: None,
            v0_kmh: 35.0 + (i * 13 % 60) as f64,
            decel_g: 0.3 + 0.5 * ((i * 5 % 9) as f64 / 8.0),
            odometer_m: 1000.0 * i as f64,
            torque_nm: None,
        }
    }

    /// A baseline conditions the estimate, is kept in the saved state and applied again at a
    /// restore: the restored stage estimates what the saved one did.
    #[test]
    fn a_baseline_survives_save_and_restore() {
        let table = reference_table();
        let cfg = ObserverConfig::default();
        let baseline = Baseline {
            clearance_mm: 0.03,
            evidence: (0..8).map(|i| evidence(i + 3, 0.6)).collect(),
        };
        let mut with = ObserverStage::new(&cfg, Some(table.clone())).unwrap();
        let used = with.set_baseline(baseline.clone());
        assert_eq!(used.angle_events, 8);
        let mut plain = ObserverStage::new(&cfg, Some(table.clone())).unwrap();
        for i in 0..20 {
            with.apply(&evidence(i, 1.0));
            plain.apply(&evidence(i, 1.0));
        }
        let (e_with, e_plain) = (with.estimate().unwrap(), plain.estimate().unwrap());
        assert_ne!(
            e_with.interval_mm, e_plain.interval_mm,
            "the baseline changed nothing"
        );
        let saved = with.save().unwrap();
        assert!(saved.get("baseline").is_some(), "{saved}");
        let mut restored = ObserverStage::new(&cfg, Some(table)).unwrap();
        restored.restore(&saved).unwrap();
        assert_eq!(restored.estimate().unwrap(), e_with);
        // A state without a baseline (written before there were baselines) restores as before.
        let mut old = saved.clone();
        old.as_object_mut().unwrap().remove("baseline");
        let mut r2 = ObserverStage::new(&cfg, Some(reference_table())).unwrap();
        r2.restore(&old).unwrap();
        assert_eq!(r2.estimate().unwrap(), e_plain);
    }

    /// The wheel-order check's verdict follows the tables' evidence: with an angle table of
    /// uneven discs beside the nominal one (here the same table, so each table's weight is its
    /// prior), a shake at wheel order sends the car to its brake discs while the discs' table
    /// keeps a weight of 0.3, and to its chassis, the discs ruled out, when it holds 0.001.
    /// Either way the model does not fit and the wheel-order alert pair applies.
    #[test]
    fn the_wheel_order_verdict_names_the_chassis_when_the_events_rule_the_discs_out() {
        let cfg = ObserverConfig::default();
        let limit = cfg.features.wheel_order.share_max;
        let fit_with = |prior: f64| {
            let mut discs = reference_table();
            discs.prior.brake_torque_variation_rel = Some((0.0, 0.05));
            let alt = crate::observer::Alternative {
                name: "uneven brake discs".into(),
                prior,
                inspect: None,
                table: discs,
            };
            let mut st = ObserverStage::new(&cfg, Some(reference_table()))
                .unwrap()
                .with_angle_alternatives(vec![alt])
                .unwrap();
            for i in 0..cfg.features.wheel_order.min_events + 2 {
                st.apply(&Evidence {
                    wheel_order_share: Some(limit + 0.2),
                    ..evidence(i, 1.0)
                });
            }
            let tables = st.observer().report().angle_tables;
            let w = tables[1].weight.unwrap();
            (st.observer().fit_check(), w)
        };
        let ((f, why), w) = fit_with(0.3);
        let f = f.unwrap();
        assert!((w - 0.3).abs() < 1e-9, "{w}");
        assert!(
            f.wheel_order_shake && !f.fits && !f.wheel_order_discs_ruled_out,
            "{f:?}"
        );
        assert!(why.unwrap().contains("brake discs"));
        let ((f, why), w) = fit_with(0.001);
        let f = f.unwrap();
        assert!(w < crate::observer::DISCS_RULED_OUT, "{w}");
        assert!(
            f.wheel_order_shake && !f.fits && f.wheel_order_discs_ruled_out,
            "{f:?}"
        );
        let why = why.unwrap();
        assert!(why.contains("rule uneven brake discs out"), "{why}");
        assert!(!why.contains("check the front brake discs"), "{why}");
    }

    /// The wheel-order shares of the events fed are saved with their evidence and replayed:
    /// a vehicle whose steering shook at wheel order while braking is still said not to fit
    /// after a restart, repaired discs clear it within the window, and a joint replacement
    /// forgets them with the old evidence.
    #[test]
    fn the_wheel_order_check_survives_a_restore_and_a_joint_replacement_resets_it() {
        let cfg = ObserverConfig::default();
        let limit = cfg.features.wheel_order.share_max;
        let mut st = ObserverStage::new(&cfg, Some(reference_table())).unwrap();
        let n = cfg.features.wheel_order.min_events;
        for i in 0..n {
            let share = if i + 1 == n { None } else { Some(limit + 0.2) };
            st.apply(&Evidence {
                wheel_order_share: share,
                ..evidence(i, 1.0)
            });
        }
        let fit = |st: &ObserverStage| st.observer().fit_check();
        // One event short of the count: nothing said yet.
        assert_eq!(fit(&st).0.unwrap().wheel_order_share, None);
        st.apply(&Evidence {
            wheel_order_share: Some(limit + 0.2),
            ..evidence(n, 1.0)
        });
        let (f, why) = fit(&st);
        let f = f.unwrap();
        assert!(f.wheel_order_shake && !f.fits, "{f:?}");
        assert!(why.unwrap().contains("brake discs"));
        let saved = st.save().unwrap();
        let mut r = ObserverStage::new(&cfg, Some(reference_table())).unwrap();
        r.restore(&saved).unwrap();
        assert_eq!(fit(&r).0.unwrap().wheel_order_share, f.wheel_order_share);
        assert!(!fit(&r).0.unwrap().fits);
        // Discs repaired: the newest `window_events` brakings decide.
        let mut fixed = ObserverStage::new(&cfg, Some(reference_table())).unwrap();
        fixed.restore(&saved).unwrap();
        for i in 0..cfg.features.wheel_order.window_events {
            fixed.apply(&Evidence {
                wheel_order_share: Some(0.05),
                ..evidence(40 + i, 1.0)
            });
        }
        let f2 = fit(&fixed).0.unwrap();
        assert!(
            !f2.wheel_order_shake && f2.wheel_order_share == Some(0.05),
            "{f2:?}"
        );
        r.joints_replaced(0.03, 1).unwrap();
        r.collect(evidence(30, 0.6));
        r.apply(&evidence(31, 0.6));
        assert_eq!(fit(&r).0.and_then(|f| f.wheel_order_share), None);
    }

    /// A joint replacement forgets the old joints' evidence and baseline, collects the next
    /// events (feeding nothing else: no estimate meanwhile), then makes them the baseline; the
    /// collection survives a save and restore in the middle, and its baseline is newer than
    /// one given at start unless the caller says otherwise.
    #[test]
    fn a_joint_replacement_collects_a_new_baseline_across_a_restore() {
        let cfg = ObserverConfig::default();
        let given = Baseline {
            clearance_mm: 0.05,
            evidence: (0..4).map(|i| evidence(i, 0.7)).collect(),
        };
        let mut st = ObserverStage::new(&cfg, Some(reference_table())).unwrap();
        st.set_baseline(given.clone());
        for i in 0..10 {
            st.apply(&evidence(i, 2.0));
        }
        assert_eq!(st.estimate().unwrap().events_used, 10);
        st.joints_replaced(0.03, 5).unwrap();
        assert!(st.baseline().is_none() && st.evidence().count() == 0);
        let e = st.estimate().unwrap();
        assert_eq!(e.events_used, 0);
        assert!(e.clearance_mm.is_none() && e.p_above.is_none() && e.interval_mm.is_none());
        for i in 0..3 {
            st.collect(evidence(20 + i, 0.6));
        }
        assert_eq!(st.collecting().unwrap().collected(), 3);
        assert_eq!(
            st.estimate().unwrap().events_used,
            0,
            "collected events fed the estimate"
        );
        // Restart in the middle, with a baseline given at start (configured logs).
        let saved = st.save().unwrap();
        let mut r = ObserverStage::new(&cfg, Some(reference_table())).unwrap();
        r.set_baseline(given.clone());
        let msg = r.restore(&saved).unwrap().unwrap();
        assert!(msg.contains("3 of 5 events"), "{msg}");
        assert!(msg.contains("replacement is newer"), "{msg}");
        assert!(r.baseline().is_none());
        for i in 3..5 {
            assert!(r.take_completed_baseline().is_none());
            r.collect(evidence(20 + i, 0.6));
        }
        let used = r.take_completed_baseline().expect("complete");
        assert_eq!(used.angle_events, 5);
        assert!(r.collecting().is_none());
        let b = r.baseline().unwrap();
        assert_eq!((b.clearance_mm, b.evidence.len()), (0.03, 5));
        // The same as a stage given those 5 events as its baseline before any event.
        let mut direct = ObserverStage::new(&cfg, Some(reference_table())).unwrap();
        direct.set_baseline(b.clone());
        for i in 0..4 {
            r.apply(&evidence(40 + i, 1.0));
            direct.apply(&evidence(40 + i, 1.0));
        }
        assert_eq!(r.estimate(), direct.estimate());
        // Saved and restored, the replacement's baseline stays; a given one said to be newer
        // takes its place.
        let saved = r.save().unwrap();
        assert_eq!(saved["from_replacement"], true);
        let mut again = ObserverStage::new(&cfg, Some(reference_table())).unwrap();
        again.set_baseline(given.clone());
        again.restore(&saved).unwrap();
        assert_eq!(again.baseline().unwrap().clearance_mm, 0.03);
        assert_eq!(again.estimate(), r.estimate());
        let mut newer = ObserverStage::new(&cfg, Some(reference_table())).unwrap();
        newer.set_baseline(given.clone());
        let msg = newer.restore_with(&saved, true).unwrap().unwrap();
        assert!(msg.contains("is newer than the joint"), "{msg}");
        assert_eq!(newer.baseline().unwrap().clearance_mm, 0.05);
        assert!(!newer.baseline_from_replacement());
        // Without a table there is nothing to reset.
        let mut none = ObserverStage::new(&cfg, None).unwrap();
        assert!(none.joints_replaced(0.03, 5).is_err());
        assert!(st.joints_replaced(0.0, 5).is_err() && st.joints_replaced(0.03, 0).is_err());
    }
}
