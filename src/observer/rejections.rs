//! Why braking produced no estimate: the detector's rejections counted per reason, and the
//! sentence that explains them.
//!
//! Two kinds of rejection are counted: brake applications ignored before they were recorded
//! ([`IgnoredCounts`]: too slow, too light, too short) and recorded events not used for the
//! estimate ([`UnusedCounts`], one field per [`Unused`] reason). [`Rejections::explain`] turns
//! them into the part of a verdict that says why nothing was estimated and points at the likely
//! cause (an inverted acceleration sign reads as a forward acceleration while braking).
//!
//! What it is not: the detection itself ([`crate::events`]) or the estimate; nothing here
//! allocates per frame (the counters are plain integers; text is built only on request).

use serde::Serialize;

use crate::events::{EventConfig, IgnoredCounts, Unused};

/// Recorded events not used, per reason (field names as [`Unused`] serialises them).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize)]
pub struct UnusedCounts {
    pub speed_out_of_range: u64,
    pub decel_out_of_range: u64,
    pub not_straight: u64,
    pub too_short: u64,
    pub low_sample_rate: u64,
    pub missing_data: u64,
    pub truncated: u64,
    pub sensor_mismatch: u64,
}

impl UnusedCounts {
    /// Counts one event not used for `why`.
    pub fn add(&mut self, why: Unused) {
        *self.slot(why) += 1;
    }

    fn slot(&mut self, why: Unused) -> &mut u64 {
        match why {
            Unused::SpeedOutOfRange => &mut self.speed_out_of_range,
            Unused::DecelOutOfRange => &mut self.decel_out_of_range,
            Unused::NotStraight => &mut self.not_straight,
            Unused::TooShort => &mut self.too_short,
            Unused::LowSampleRate => &mut self.low_sample_rate,
            Unused::MissingData => &mut self.missing_data,
            Unused::Truncated => &mut self.truncated,
            Unused::SensorMismatch => &mut self.sensor_mismatch,
        }
    }

    /// Every reason with its count, in a fixed order.
    pub fn iter(&self) -> [(Unused, u64); 8] {
        [
            (Unused::SpeedOutOfRange, self.speed_out_of_range),
            (Unused::DecelOutOfRange, self.decel_out_of_range),
            (Unused::NotStraight, self.not_straight),
            (Unused::TooShort, self.too_short),
            (Unused::LowSampleRate, self.low_sample_rate),
            (Unused::MissingData, self.missing_data),
            (Unused::Truncated, self.truncated),
            (Unused::SensorMismatch, self.sensor_mismatch),
        ]
    }

    pub fn total(&self) -> u64 {
        self.iter().iter().map(|x| x.1).sum()
    }
}

/// A short description of an unused reason with the thresholds that decided it.
pub fn describe_unused(why: Unused, cfg: &EventConfig) -> String {
    match why {
        Unused::SpeedOutOfRange => format!(
            "initial speed outside {}-{} km/h",
            cfg.min_speed_kmh, cfg.max_speed_kmh
        ),
        Unused::DecelOutOfRange => format!(
            "deceleration outside {}-{} g",
            cfg.min_decel_g, cfg.max_decel_g
        ),
        Unused::NotStraight => format!(
            "steering beyond {} deg or turned by more than {} deg within 1 s",
            cfg.max_steer_deg, cfg.max_steer_change_deg
        ),
        Unused::TooShort => format!("shorter than {} s", cfg.min_duration_s),
        Unused::LowSampleRate => format!("steering sampled below {} Hz", cfg.min_sample_hz),
        Unused::MissingData => format!(
            "more than {:.0} % of the steering samples missing or invalid",
            cfg.max_missing_fraction * 100.0
        ),
        Unused::Truncated => "longer than the sample buffer".into(),
        Unused::SensorMismatch => "steering angle sensor not the response table's".into(),
    }
}

/// What braking produced: applications ignored and events recorded, used or not.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize)]
pub struct Rejections {
    /// Brake applications ignored before recording.
    pub ignored: u64,
    pub ignored_by_reason: IgnoredCounts,
    /// Events recorded (used or not).
    pub recorded: u64,
    /// Recorded events used for the estimate.
    pub used: u64,
    pub unused_by_reason: UnusedCounts,
}

impl Rejections {
    /// Whether anything was rejected or nothing was found: when the counts are worth printing.
    pub fn worth_reporting(&self) -> bool {
        self.ignored > 0 || self.used < self.recorded || self.recorded == 0
    }

    /// "30 brake applications ignored (peak deceleration below 0.15 g: 30); 2 events not used
    /// (deceleration outside 0.3-0.8 g: 2)", or "no brake application found".
    pub fn counts_text(&self, cfg: &EventConfig) -> String {
        if self.ignored == 0 && self.recorded == 0 {
            return "no brake application found".into();
        }
        let mut parts = Vec::new();
        if self.ignored > 0 {
            let c = &self.ignored_by_reason;
            let why: Vec<String> = [
                (
                    c.too_light,
                    format!("peak deceleration below {} g", cfg.record_min_decel_g),
                ),
                (
                    c.too_slow,
                    format!("initial speed below {} km/h", cfg.record_min_speed_kmh),
                ),
                (
                    c.too_short,
                    format!("shorter than {} s", 0.5 * cfg.min_duration_s),
                ),
            ]
            .into_iter()
            .filter(|x| x.0 > 0)
            .map(|(n, what)| format!("{what}: {n}"))
            .collect();
            parts.push(format!(
                "{} brake application{} ignored ({})",
                self.ignored,
                plural(self.ignored),
                why.join(", ")
            ));
        }
        let unused = self.recorded - self.used.min(self.recorded);
        if unused > 0 {
            let why: Vec<String> = self
                .unused_by_reason
                .iter()
                .into_iter()
                .filter(|x| x.1 > 0)
                .map(|(w, n)| format!("{}: {n}", describe_unused(w, cfg)))
                .collect();
            parts.push(format!(
                "{unused} event{} not used ({})",
                plural(unused),
                why.join(", ")
            ));
        }
        parts.join("; ")
    }

    /// The likely cause behind the counts, when one stands out; `accel_mapped` says whether the
    /// deceleration came from an acceleration signal (else from the speed's derivative).
    pub fn hint(&self, cfg: &EventConfig, accel_mapped: bool) -> Option<String> {
        let c = &self.ignored_by_reason;
        if self.ignored == 0 && self.recorded == 0 {
            return Some(
                "the brake never read applied while moving: no braking in the log, or a brake \
                 signal mapped wrong"
                    .into(),
            );
        }
        if c.accel_while_braking > 0 && 2 * c.accel_while_braking >= self.ignored {
            let src = if accel_mapped {
                "does the acceleration signal read positive while braking? (toggle `invert` \
                 under [accel])"
            } else {
                "does the speed signal rise while braking?"
            };
            return Some(format!(
                "in {} of them the car read a forward acceleration of at least {} g while the \
                 brake was applied: {src}",
                c.accel_while_braking, cfg.record_min_decel_g
            ));
        }
        if c.too_light > 0 && 2 * c.too_light >= self.ignored {
            return Some(format!(
                "the brake was applied, but the deceleration stayed below {} g: light braking \
                 only, or a deceleration signal with the wrong scale or sign",
                cfg.record_min_decel_g
            ));
        }
        let u = &self.unused_by_reason;
        if self.used == 0 && u.sensor_mismatch > 0 {
            return Some(
                "rebuild the response table for this car's steering angle sensor (`shimmy \
                 calibrate --profile NAME`)"
                    .into(),
            );
        }
        None
    }

    /// Counts and hint in one sentence (for a verdict); with `suggest_doctor`, a hint ends by
    /// pointing at `shimmy doctor`.
    pub fn explain(&self, cfg: &EventConfig, accel_mapped: bool, suggest_doctor: bool) -> String {
        let mut s = self.counts_text(cfg);
        if let Some(h) = self.hint(cfg, accel_mapped) {
            s += " - ";
            s += &h;
            if suggest_doctor {
                s += "; check the mapping with `shimmy doctor`";
            }
        }
        s
    }
}

fn plural(n: u64) -> &'static str {
    if n == 1 {
        ""
    } else {
        "s"
    }
}
