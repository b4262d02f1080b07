//! Workshop inspection report (`shimmy report`): what a mechanic needs to decide about the
//! steering joints, from shimmyd's journal, its state directory, or straight from logs (the CLI
//! replays them through the daemon's pipeline into a temporary journal first).
//!
//! [`ReportData`] is the machine form (`--format json`); [`html`] renders it as one
//! self-contained page: the verdict first (joint condition, estimated clearance with its
//! interval, the trend over distance with the 0.07 mm and 0.1 mm lines), then the evidence
//! (steering-wheel angle around the worst braking events, their spectra, the event table), then
//! the guidance and the data-quality counters. Plots are inline SVG ([`svg`]); there are no
//! scripts and no external assets. After a joint replacement journaled by shimmyd (its
//! `joints_replaced` record) the report is about the new joints: the trend and the evidence
//! start there (the event table still lists every event), and while the daemon collects the
//! new baseline the verdict says so.
//!
//! What it is not: an estimator. It shows what the daemon recorded and never recomputes or
//! invents an estimate.

pub mod svg;

use std::fmt::Write;
use std::path::Path;

use anyhow::{bail, Context};
use serde::Serialize;

use crate::alerts::AlertsSection;
use crate::alerts::{Alert, Kind};
use crate::monitor::{Estimate, EventSummary};

/// Steering-wheel trace of one event, as journaled (times relative to the brake onset).
#[derive(Clone, Debug, Default, PartialEq, Serialize, serde::Deserialize)]
pub struct Trace {
    pub t0: f64,
    pub t_s: Vec<f64>,
    pub angle_deg: Vec<f64>,
}

/// One point of the clearance trend.
#[cfg(test)]
mod tests {
    #[test]
    fn when_formats_epoch_and_relative_times() {
        assert_eq!(super::when(1_767_225_611.14), "2026-01-01 00:00:11.1 UTC");
        assert_eq!(
            super::when(1_078_012_800.0 + 86_399.0),
            "2004-02-29 23:59:59.0 UTC"
        );
        assert_eq!(super::when(12.5), "12.50 s");
    }

    /// "OK" only when the posterior keeps the clearance below the replacement limit; an
    /// interval that includes it is "keep monitoring", whatever its median.
    #[test]
    fn verdict_says_ok_only_below_the_limit_and_keep_monitoring_across_it() {
        use crate::alerts::AlertsSection;
        use crate::monitor::Estimate;
        let cfg = AlertsSection::default();
        let est = |median: Option<f64>, lo: f64, hi: f64, detectable: bool| Estimate {
            clearance_mm: median,
            interval_mm: Some([lo, hi]),
            detectable,
            below_mm: (!detectable).then_some(hi),
            p_above: Some(0.5),
            events_used: 12,
            misfit: None,
            chassis_variant: None,
            chassis_variant_inspect: None,
            wheel_order_shake: false,
            wheel_order_discs_ruled_out: false,
            sensor_noisier: false,
        };
        let v = |e: Estimate| super::verdict(&[], Some(&e), 12, &cfg);
        let ok = v(est(Some(0.085), 0.081, 0.093, true));
        assert_eq!(ok.condition, "ok", "{ok:?}");
        assert!(ok.headline.contains("0.085"), "{ok:?}");
        assert_eq!(v(est(None, 0.02, 0.07, false)).condition, "ok");
        let wide = v(est(None, 0.04, 0.6, false));
        assert_eq!(wide.condition, "undecided", "{wide:?}");
        assert!(wide.headline.contains("0.04 and 0.60"), "{wide:?}");
        assert_eq!(v(est(Some(0.09), 0.082, 0.14, true)).condition, "undecided");
        let none = super::verdict(&[], None, 0, &cfg);
        assert_eq!(none.condition, "unknown");
        // An estimate the model does not fit is never "ok", however low.
        let misfit = Estimate {
            misfit: Some(
                "its steering torque sensor is noisier than the response table assumes".into(),
            ),
            ..est(Some(0.04), 0.03, 0.05, true)
        };
        let m = v(misfit);
        assert_eq!(m.condition, "undecided", "{m:?}");
        assert!(
            m.headline.contains("does not fit") && m.headline.contains("noisier"),
            "{m:?}"
        );
        // With a brake-disc shake an alert sends the mechanic to the discs first.
        let judder = Estimate {
            misfit: Some("its steering shakes at the wheels' rotation while braking".into()),
            wheel_order_shake: true,
            wheel_order_discs_ruled_out: false,
            ..est(Some(0.2), 0.15, 0.3, true)
        };
        let open = [crate::alerts::Alert {
            id: 1,
            kind: crate::alerts::Kind::Clearance,
            t_raised: 10.0,
            t_updated: 10.0,
            odometer_km_raised: 1.0,
            updates: 0,
            summary: String::new(),
            guidance: String::new(),
            evidence: crate::alerts::Evidence {
                events: Vec::new(),
                estimate: None,
                threshold: 0.1,
                hits: None,
            },
        }];
        let j = super::verdict(&open, Some(&judder), 12, &cfg);
        assert_eq!(j.condition, "inspect", "{j:?}");
        assert!(
            j.headline.contains("brake discs") && j.headline.contains("Replace"),
            "{j:?}"
        );
        // The same shake on a car whose events rule the discs out: the misfit names the
        // chassis, and the discs are not sent for.
        let chassis = Estimate {
            misfit: Some("its events rule uneven brake discs out; check the wheels' offset".into()),
            wheel_order_discs_ruled_out: true,
            ..judder.clone()
        };
        let c = super::verdict(&open, Some(&chassis), 12, &cfg);
        assert!(
            c.headline.contains("wheels' offset") && !c.headline.contains("check the front brake"),
            "{c:?}"
        );
        let plain = super::verdict(&open, Some(&est(Some(0.2), 0.15, 0.3, true)), 12, &cfg);
        assert_eq!(plain.condition, "replace", "{plain:?}");
        assert!(!plain.headline.contains("does not fit"), "{plain:?}");
        // Any other misfit keeps the alert and asks for the play to be confirmed by hand.
        let unfit = Estimate {
            misfit: Some(
                "its car model's correction finds the torque features' gains unequal".into(),
            ),
            ..est(Some(0.2), 0.15, 0.3, true)
        };
        let u = super::verdict(&open, Some(&unfit), 12, &cfg);
        assert_eq!(u.condition, "replace", "{u:?}");
        assert!(
            u.headline.contains("Replace")
                && u.headline
                    .contains("does not fit this vehicle: its car model's correction")
                && u.headline.contains("confirm the joints' play by hand"),
            "{u:?}"
        );
        // An estimate read with a chassis variant's table keeps its condition and says which
        // geometry it was read for and what to check.
        let variant = Estimate {
            chassis_variant: Some("scrub radius 10 mm".into()),
            chassis_variant_inspect: Some(
                "the wheels' offset (non-standard wheels or spacers change the scrub radius)"
                    .into(),
            ),
            ..est(Some(0.085), 0.081, 0.093, true)
        };
        let c = v(variant);
        assert_eq!(c.condition, "ok", "{c:?}");
        assert!(
            c.headline.contains("0.085")
                && c.headline.contains("scrub radius 10 mm")
                && c.headline.contains("wheels' offset"),
            "{c:?}"
        );
        // A variant that is no fault (the car model's own damping) names itself, checks nothing.
        let damping = v(Estimate {
            chassis_variant: Some("kingpin damping x1.2".into()),
            ..est(Some(0.3), 0.22, 0.4, true)
        });
        let own = v(est(Some(0.3), 0.22, 0.4, true));
        assert_eq!(damping.condition, own.condition, "{damping:?}");
        assert!(
            damping.headline.contains("kingpin damping x1.2")
                && !damping.headline.contains("check"),
            "{damping:?}"
        );
    }
}

#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct TrendPoint {
    pub odometer_km: f64,
    pub t: f64,
    pub estimate: Estimate,
}

#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct Verdict {
    /// `replace`, `inspect`, `ok` (the 90 % interval lies below the replacement limit),
    /// `undecided` (it includes the limit: keep monitoring), `unknown` (no estimate).
    pub condition: String,
    pub headline: String,
    pub estimate: Option<Estimate>,
}

#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct WorstEvent {
    pub event: EventSummary,
    pub trace: Option<Trace>,
}

/// Everything the report shows (the JSON format).
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct ReportData {
    pub source: String,
    pub verdict: Verdict,
    pub odometer_km: Option<f64>,
    pub trend: Vec<TrendPoint>,
    /// Alerts open at the end of the record.
    pub open_alerts: Vec<Alert>,
    /// Every alert transition, in order (`raised` / `updated` / `cleared`).
    pub alert_history: Vec<serde_json::Value>,
    pub events: Vec<EventSummary>,
    /// Up to three used events with the largest amplitude, with their traces when recorded.
    pub worst: Vec<WorstEvent>,
    /// Counters of the last daemon run (frames, decode errors, ...), when journaled.
    pub counters: Option<serde_json::Value>,
    pub journal_invalid_lines: u64,
    pub guidance: Vec<String>,
    /// The last joint replacement shimmyd recorded (its journal's `joints_replaced` record, or
    /// its state's `replacement`), when there is one.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub joints_replaced: Option<serde_json::Value>,
    /// While the daemon collects the new baseline after it: how far (`collected`, `events`,
    /// `clearance_mm`).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub baseline_collection: Option<serde_json::Value>,
}

/// `v`, said of a baseline collection after a joint replacement when no alert stands: there
/// is no estimate to judge by yet, and why.
fn collecting_verdict(
    v: Verdict,
    open: &[Alert],
    collection: Option<&serde_json::Value>,
) -> Verdict {
    let Some(c) = collection.filter(|_| open.is_empty()) else {
        return v;
    };
    let n = |k: &str| c[k].as_f64().map_or("?".to_string(), |x| format!("{x}"));
    Verdict {
        condition: "unknown".into(),
        headline: format!(
            "The steering joints were replaced: the monitor is collecting the car's new baseline \
             (new joints at {} mm), {} of {} braking events. The clearance is estimated once it \
             is complete.",
            n("clearance_mm"),
            n("collected"),
            n("events")
        ),
        estimate: v.estimate,
    }
}

fn verdict(open: &[Alert], est: Option<&Estimate>, events: usize, cfg: &AlertsSection) -> Verdict {
    let has = |k| open.iter().any(|a: &Alert| a.kind == k);
    let (condition, headline) = if has(Kind::Clearance) {
        (
            "replace",
            format!(
                "Steering joints worn: estimated clearance above {:.2} mm. Replace the tie-rod / trapezoid-arm joints.",
                cfg.clearance_mm
            ),
        )
    } else if has(Kind::Shimmy55) {
        (
            "inspect",
            format!(
                "Steering-wheel shimmy above {:.2} deg when braking at {:.0}-{:.0} km/h: inspect the steering joint clearances now.",
                cfg.shimmy_deg, cfg.shimmy_speed_min_kmh, cfg.shimmy_speed_max_kmh
            ),
        )
    } else {
        match est {
            Some(Estimate {
                misfit: Some(why),
                events_used,
                ..
            }) if *events_used > 0 => (
                "undecided",
                format!(
                    "No alert, but the clearance estimate cannot be trusted: the model does not \
                     fit this vehicle ({why}). Inspect the steering joint clearances by hand."
                ),
            ),
            Some(e) if e.events_used > 0 => {
                let limit = cfg.clearance_mm;
                // The upper end of what the posterior allows: the 90 % interval's, or the
                // "below" bound of an estimate under the detection limit.
                let upper = e.interval_mm.map(|i| i[1]).or(e.below_mm);
                let lower = e.interval_mm.map(|i| i[0]);
                let p = e
                    .p_above
                    .map_or(String::new(), |p| format!(", probability above it {:.0} %", p * 100.0));
                match (upper, e.clearance_mm) {
                    (Some(u), Some(c)) if e.detectable && u < limit => (
                        "ok",
                        format!("No alert. Estimated clearance {c:.3} mm, below the {limit:.2} mm replacement limit."),
                    ),
                    (Some(u), _) if u < limit => (
                        "ok",
                        format!("No alert. Clearance below {u:.2} mm, within the {limit:.2} mm replacement limit."),
                    ),
                    (Some(u), _) => (
                        "undecided",
                        format!(
                            "No alert yet, not enough evidence: the clearance lies between {} and {u:.2} mm (90 %), \
                             which includes the {limit:.2} mm replacement limit{p}, from {} braking events. \
                             Keep monitoring: further braking events, best from above about 45 km/h, narrow it.",
                            lower.map_or("0".to_string(), |l| format!("{l:.2}")),
                            e.events_used
                        ),
                    ),
                    _ => ("ok", "No alert.".to_string()),
                }
            }
            _ if events == 0 => (
                "unknown",
                "No usable braking events recorded: the joints cannot be judged from this data.".into(),
            ),
            _ => (
                "unknown",
                "No alert, but no clearance estimate is available (no response table or no usable event).".into(),
            ),
        }
    };
    // A shake locked to the wheels' rotation while braking comes from the brakes, whatever the
    // joints: with an alert, the discs are checked before the joints are replaced (unless the
    // events rule the discs out: then it is a misfit like any other, which names the chassis).
    let (condition, headline) = match est {
        Some(e)
            if e.wheel_order_shake
                && !e.wheel_order_discs_ruled_out
                && (has(Kind::Clearance) || has(Kind::Shimmy55)) =>
        {
            (
                "inspect",
                format!(
                    "Steering shake while braking, locked to the wheels' rotation: check the \
                     front brake discs for thickness variation and run-out first, then the \
                     steering joints. The braking shake the alert rests on is not the joints' \
                     alone, so the clearance estimate is not to be trusted until the discs are \
                     fixed. (The alert: {})",
                    headline.trim_end_matches('.')
                ),
            )
        }
        // Any other misfit: the alert stands, and the mechanic confirms the play by hand.
        Some(Estimate {
            misfit: Some(why), ..
        }) if has(Kind::Clearance) => (
            condition,
            format!(
                "{headline} But the model does not fit this vehicle: {}. The clearance \
                 estimate is uncertain; confirm the joints' play by hand before replacing them.",
                why.trim_end_matches('.')
            ),
        ),
        _ => (condition, headline),
    };
    // A chassis variant is a finding of its own: the car's steering is not its model's (a
    // scrub radius the model does not have comes from the wheels' offset; a kingpin damping
    // beyond the prior is the car model's own and nothing to repair).
    let headline = match est.and_then(|e| e.chassis_variant.as_deref()) {
        Some(name) => {
            let check = est
                .and_then(|e| e.chassis_variant_inspect.as_deref())
                .map(|c| format!(": check {}", c.trim_end_matches('.')))
                .unwrap_or_default();
            format!(
                "{headline} The braking shake fits this car best as the chassis variant \
                 \"{name}\" (not the car model's own chassis), and the clearance was estimated \
                 for it{check}."
            )
        }
        None => headline,
    };
    Verdict {
        condition: condition.into(),
        headline,
        estimate: est.cloned(),
    }
}

fn worst(events: &[EventSummary], traces: &[(f64, Trace)]) -> Vec<WorstEvent> {
    let mut idx: Vec<usize> = (0..events.len())
        .filter(|&i| {
            events[i]
                .sw_amplitude_deg
                .or(events[i].peak_sw_bp_deg)
                .is_some()
        })
        .collect();
    let amp = |e: &EventSummary| e.sw_amplitude_deg.or(e.peak_sw_bp_deg).unwrap_or(0.0);
    idx.sort_by(|&a, &b| amp(&events[b]).total_cmp(&amp(&events[a])));
    idx.truncate(3);
    idx.into_iter()
        .map(|i| WorstEvent {
            event: events[i].clone(),
            trace: traces
                .iter()
                .find(|(t, _)| (*t - events[i].t_start).abs() < 1e-6)
                .map(|(_, tr)| tr.clone()),
        })
        .collect()
}

fn guidance_lines(cfg: &AlertsSection, odometer_km: Option<f64>) -> Vec<String> {
    crate::alerts::routine_guidance(cfg, odometer_km.unwrap_or(0.0))
}

/// Builds the report from a journal directory.
pub fn from_journal(dir: &Path, cfg: &AlertsSection) -> anyhow::Result<ReportData> {
    let mut r = crate::journal::Reader::open(dir)?;
    let mut events = Vec::new();
    let mut traces = Vec::new();
    let mut trend = Vec::new();
    let mut alert_history = Vec::new();
    let mut open: Vec<Alert> = Vec::new();
    let mut counters = None;
    let mut odometer = None;
    let mut last_est = None;
    let mut replaced = None;
    let mut collection = None;
    // Events before the last joint replacement are not the present joints' evidence.
    let mut since = 0;
    for e in &mut r {
        let e = e?;
        match e.rec.get("type").and_then(|t| t.as_str()) {
            Some("joints_replaced") => {
                let mut rec = e.rec.clone();
                if let (Some(w), Some(m)) = (e.wall_ns, rec.as_object_mut()) {
                    m.entry("wall_unix_s").or_insert(json_f64(w as f64 * 1e-9));
                }
                replaced = Some(rec);
                trend.clear();
                last_est = None;
                collection = None;
                since = events.len();
            }
            Some("event") => {
                let ev: EventSummary = serde_json::from_value(e.rec["event"].clone())
                    .with_context(|| format!("journal record {}: bad event", e.seq))?;
                if let Ok(t) = serde_json::from_value::<Trace>(e.rec["trace"].clone()) {
                    traces.push((ev.t_start, t));
                }
                odometer = Some(ev.odometer_km);
                events.push(ev);
            }
            Some("estimate") => {
                let est: Estimate = serde_json::from_value(e.rec["estimate"].clone())
                    .with_context(|| format!("journal record {}: bad estimate", e.seq))?;
                last_est = Some(est.clone());
                collection = e
                    .rec
                    .get("baseline_collection")
                    .filter(|c| c.is_object())
                    .cloned();
                trend.push(TrendPoint {
                    odometer_km: e.rec["odometer_km"].as_f64().unwrap_or(0.0),
                    t: e.rec["t"].as_f64().unwrap_or(0.0),
                    estimate: est,
                });
            }
            Some("alert") => {
                let a: Alert = serde_json::from_value(e.rec["alert"].clone())
                    .with_context(|| format!("journal record {}: bad alert", e.seq))?;
                let tr = e.rec["transition"].as_str().unwrap_or("");
                open.retain(|o| o.kind != a.kind);
                if tr != "cleared" {
                    open.push(a.clone());
                }
                alert_history.push(e.rec.clone());
            }
            Some("stop") => {
                counters = Some(e.rec["counters"].clone());
                if let Some(o) = e.rec["odometer_km"].as_f64() {
                    odometer = Some(o);
                }
            }
            _ => {}
        }
    }
    let v = verdict(&open, last_est.as_ref(), events.len() - since, cfg);
    Ok(ReportData {
        source: format!("journal {}", dir.display()),
        verdict: collecting_verdict(v, &open, collection.as_ref()),
        odometer_km: odometer,
        trend,
        open_alerts: open,
        alert_history,
        worst: worst(&events[since..], &traces),
        events,
        counters,
        journal_invalid_lines: r.invalid_lines(),
        guidance: guidance_lines(cfg, odometer),
        joints_replaced: replaced,
        baseline_collection: collection,
    })
}

/// Builds the report from a state directory (no traces, no trend: the state keeps only the
/// latest estimate and recent events).
pub fn from_state(dir: &Path, cfg: &AlertsSection) -> anyhow::Result<ReportData> {
    let (st, problem) = crate::daemon::state::load(dir)?;
    let Some(st) = st else {
        bail!(
            "{}: no state.json{}",
            dir.display(),
            problem.map(|p| format!(" ({p})")).unwrap_or_default()
        );
    };
    let trend = st
        .estimate
        .iter()
        .map(|e| TrendPoint {
            odometer_km: st.odometer_km,
            t: st.events.last().map_or(0.0, |e| e.t_end),
            estimate: e.clone(),
        })
        .collect();
    // A baseline collection in progress is the event stage's (its saved `collecting`).
    let collection = st
        .stage
        .as_ref()
        .and_then(|s| s.get("collecting"))
        .filter(|c| c.is_object())
        .map(|c| {
            serde_json::json!({
                "collected": c["evidence"].as_array().map_or(0, |e| e.len()),
                "events": c["target"],
                "clearance_mm": c["clearance_mm"],
            })
        });
    let v = verdict(&st.alerts.open, st.estimate.as_ref(), st.events.len(), cfg);
    Ok(ReportData {
        source: format!("state {}", dir.display()),
        verdict: collecting_verdict(v, &st.alerts.open, collection.as_ref()),
        odometer_km: Some(st.odometer_km),
        trend,
        open_alerts: st.alerts.open.clone(),
        alert_history: Vec::new(),
        worst: worst(&st.events, &[]),
        events: st.events,
        counters: None,
        journal_invalid_lines: 0,
        guidance: guidance_lines(cfg, Some(st.odometer_km)),
        joints_replaced: st
            .replacement
            .as_ref()
            .and_then(|r| serde_json::to_value(r).ok()),
        baseline_collection: collection,
    })
}

/// A number as JSON (null when not finite).
fn json_f64(x: f64) -> serde_json::Value {
    serde_json::Number::from_f64(x).map_or(serde_json::Value::Null, serde_json::Value::Number)
}

fn esc(s: &str) -> String {
    s.replace('&', "&amp;")
        .replace('<', "&lt;")
        .replace('>', "&gt;")
        .replace('"', "&quot;")
}

/// A log time for people: UTC date and time for Unix-epoch times, plain seconds otherwise
/// (logs with relative timestamps).
pub fn when(t: f64) -> String {
    if !(1.0e9..1.0e11).contains(&t) {
        return format!("{t:.2} s");
    }
    let secs = t.floor() as i64;
    let (days, sod) = (secs.div_euclid(86_400), secs.rem_euclid(86_400));
    // Civil date from days since 1970-01-01 (H. Hinnant's algorithm).
    let z = days + 719_468;
    let era = z.div_euclid(146_097);
    let doe = z - era * 146_097;
    let yoe = (doe - doe / 1460 + doe / 36_524 - doe / 146_096) / 365;
    let doy = doe - (365 * yoe + yoe / 4 - yoe / 100);
    let mp = (5 * doy + 2) / 153;
    let d = doy - (153 * mp + 2) / 5 + 1;
    let m = if mp < 10 { mp + 3 } else { mp - 9 };
    let y = yoe + era * 400 + i64::from(m <= 2);
    format!(
        "{y:04}-{m:02}-{d:02} {:02}:{:02}:{:02}.{:01} UTC",
        sod / 3600,
        sod / 60 % 60,
        sod % 60,
        ((t - t.floor()) * 10.0).floor() as u32
    )
}

fn opt(v: Option<f64>, digits: usize) -> String {
    v.map_or("–".into(), |x| format!("{x:.digits$}"))
}

fn trend_svg(d: &ReportData) -> String {
    let pts: Vec<&TrendPoint> = d.trend.iter().collect();
    let x0 = pts.first().map_or(0.0, |p| p.odometer_km);
    let x1 = pts.last().map_or(1.0, |p| p.odometer_km).max(x0 + 0.1);
    let mut ymax: f64 = 0.15;
    for p in &pts {
        if let Some([_, hi]) = p.estimate.interval_mm {
            ymax = ymax.max(hi * 1.1);
        }
    }
    let mut c = svg::Chart::new(
        "Joint clearance over distance (90 % interval shaded)",
        "odometer (km)",
        "clearance (mm)",
        (x0, x1),
        (0.0, ymax.min(1.0)),
    );
    let band: Vec<(f64, f64, f64)> = pts
        .iter()
        .filter_map(|p| {
            p.estimate
                .interval_mm
                .map(|[lo, hi]| (p.odometer_km, lo, hi))
        })
        .collect();
    c.band(&band, "#9ec5e8");
    let med: Vec<(f64, f64)> = pts
        .iter()
        .filter_map(|p| p.estimate.clearance_mm.map(|m| (p.odometer_km, m)))
        .collect();
    c.line(&med, "#1f5fa8", 2.0);
    c.points(&med, "#1f5fa8");
    c.hline_labelled(
        0.07,
        "#c98a00",
        "0.07 mm: new-joint limit / onset of chaotic shimmy",
        true,
    );
    c.hline(0.1, "#c0262d", "0.1 mm: replace");
    c.render()
}

fn trace_svgs(w: &WorstEvent, rank: usize) -> (String, String) {
    let e = &w.event;
    let Some(tr) = w.trace.as_ref().filter(|t| t.t_s.len() >= 16) else {
        return (String::new(), String::new());
    };
    let n = tr.t_s.len();
    let mut dts: Vec<f64> = tr
        .t_s
        .windows(2)
        .map(|p| p[1] - p[0])
        .filter(|d| *d > 0.0)
        .collect();
    dts.sort_by(f64::total_cmp);
    let fs = dts.get(dts.len() / 2).map_or(100.0, |d| 1.0 / d);
    let x = &tr.angle_deg;
    let mean = x.iter().sum::<f64>() / n as f64;
    let centered: Vec<f64> = x.iter().map(|v| v - mean).collect();
    let bp =
        crate::analysis::filter::bandpass_zero_phase(&centered, fs, 3.0, 25.0f64.min(0.45 * fs), 4)
            .ok();
    let lim = centered
        .iter()
        .chain(bp.iter().flatten())
        .fold(0.1f64, |m, v| m.max(v.abs()))
        * 1.1;
    let mut c = svg::Chart::new(
        &format!(
            "#{rank}: steering wheel, {:.0} km/h at {:.2} g",
            e.v0_kmh, e.decel_g
        ),
        "time from brake onset (s)",
        "angle minus mean (deg)",
        (tr.t_s[0], tr.t_s[n - 1]),
        (-lim, lim),
    );
    let raw: Vec<(f64, f64)> = tr
        .t_s
        .iter()
        .copied()
        .zip(centered.iter().copied())
        .collect();
    c.line(&raw, "#999999", 1.0);
    if let Some(bp) = &bp {
        let pts: Vec<(f64, f64)> = tr.t_s.iter().copied().zip(bp.iter().copied()).collect();
        c.line(&pts, "#c0262d", 1.5);
    }
    c.vline(0.0, "#333");
    c.vline(e.t_end - e.t_start, "#333");
    let time = c.render();
    let spec = match crate::analysis::spectrum::welch(
        &centered,
        fs,
        (n as f64 / fs / 2.0).clamp(0.5, 2.0),
    ) {
        Ok(psd) => {
            let pts: Vec<(f64, f64)> = psd
                .freqs_hz
                .iter()
                .zip(&psd.density)
                .filter(|(f, _)| **f <= 30.0f64.min(fs / 2.0))
                .map(|(f, p)| (*f, p.max(1e-12).log10() * 10.0))
                .collect();
            let (lo, hi) = pts
                .iter()
                .fold((f64::MAX, f64::MIN), |(a, b), p| (a.min(p.1), b.max(p.1)));
            let mut c = svg::Chart::new(
                &format!("#{rank}: spectrum of the steering-wheel angle (Welch)"),
                "frequency (Hz)",
                "PSD (dB re 1 deg²/Hz)",
                (0.0, 30.0f64.min(fs / 2.0)),
                (lo.floor(), hi.ceil()),
            );
            c.line(&pts, "#1f5fa8", 1.5);
            c.vline(3.0, "#999");
            c.vline(25.0f64.min(fs / 2.0), "#999");
            c.render()
        }
        Err(_) => String::new(),
    };
    (time, spec)
}

/// The self-contained HTML page.
pub fn html(d: &ReportData) -> String {
    let mut s = String::new();
    let color = match d.verdict.condition.as_str() {
        "replace" => "#c0262d",
        "inspect" => "#d9822b",
        "ok" => "#2e8540",
        "undecided" => "#3a6ea5",
        _ => "#666666",
    };
    let label = match d.verdict.condition.as_str() {
        "replace" => "REPLACE JOINTS",
        "inspect" => "INSPECT NOW",
        "ok" => "OK",
        "undecided" => "KEEP MONITORING",
        _ => "NOT ENOUGH DATA",
    };
    let _ = write!(
        s,
        r#"<!DOCTYPE html><html lang="en"><head><meta charset="utf-8"><title>Steering joint inspection report</title>
<style>
body{{font-family:sans-serif;max-width:980px;margin:24px auto;padding:0 16px;color:#222}}
h1{{font-size:22px;margin-bottom:4px}} h2{{font-size:18px;border-bottom:1px solid #ccc;padding-bottom:4px;margin-top:28px}}
.verdict{{border:3px solid {color};border-radius:8px;padding:14px 18px;margin:16px 0}}
.badge{{display:inline-block;background:{color};color:white;font-weight:bold;padding:4px 10px;border-radius:4px;font-size:18px}}
.headline{{font-size:18px;margin:10px 0 6px}}
table{{border-collapse:collapse;font-size:13px;width:100%}} th,td{{border:1px solid #ccc;padding:3px 6px;text-align:right}} th{{background:#f2f2f2}}
td.l,th.l{{text-align:left}} .small{{color:#555;font-size:13px}} .alert{{background:#fff4f0;border-left:4px solid {color};padding:8px 12px;margin:8px 0}}
.pair{{display:flex;flex-wrap:wrap;gap:8px}} svg{{max-width:100%;height:auto}}
</style></head><body>
<h1>Steering joint inspection report</h1><div class="small">shimmy-monitor · source: {src}{odo}</div>"#,
        src = esc(&d.source),
        odo = d.odometer_km.map_or(String::new(), |o| format!(
            " · distance recorded by the monitor: {o:.1} km"
        )),
    );
    // Verdict.
    let est = d.verdict.estimate.as_ref();
    let clearance = match est {
        Some(e) if e.detectable => format!(
            "<b>{}</b> mm (90 % interval {} – {} mm)",
            opt(e.clearance_mm, 3),
            opt(e.interval_mm.map(|i| i[0]), 3),
            opt(e.interval_mm.map(|i| i[1]), 3)
        ),
        Some(e) if e.below_mm.is_some() => format!(
            "<b>below {} mm</b> (90 % interval {} – {} mm; the lower end is under the detection limit, \
             so a new joint is not excluded)",
            opt(e.below_mm, 2),
            opt(e.interval_mm.map(|i| i[0]), 3),
            opt(e.interval_mm.map(|i| i[1]), 3)
        ),
        _ => "not estimated".into(),
    };
    let _ = write!(
        s,
        r#"<div class="verdict"><span class="badge">{label}</span><div class="headline">{h}</div>
<div>Estimated clearance: {clearance}{p}{n}</div></div>"#,
        h = esc(&d.verdict.headline),
        p = est
            .and_then(|e| e.p_above)
            .map_or(String::new(), |p| format!(
                " · probability above 0.1 mm: {:.0} %",
                p * 100.0
            )),
        n = est.map_or(String::new(), |e| format!(
            " · from {} braking events",
            e.events_used
        )),
    );
    for a in &d.open_alerts {
        let _ = write!(
            s,
            r#"<div class="alert"><b>Alert #{} {}</b> (raised {}, at {:.1} km; updated {} times): {}<br><span class="small">{}</span></div>"#,
            a.id,
            a.kind.as_str(),
            when(a.t_raised),
            a.odometer_km_raised,
            a.updates,
            esc(&a.summary),
            esc(&a.guidance)
        );
    }
    if let Some(r) = &d.joints_replaced {
        let at = r["t"]
            .as_f64()
            .or(r["wall_unix_s"].as_f64())
            .map_or("–".to_string(), when);
        let _ = write!(
            s,
            r#"<div class="small"><b>Joints replaced</b> {at}, at {} km: new joints at {} mm{}. The trend and the evidence below start there; the event table lists every event.</div>"#,
            opt(r["odometer_km"].as_f64(), 1),
            opt(r["clearance_mm"].as_f64(), 3),
            d.baseline_collection
                .as_ref()
                .map_or(String::new(), |c| format!(
                    "; baseline being collected: {} of {} braking events",
                    c["collected"], c["events"]
                )),
        );
    }
    s.push_str("<h2>Trend over distance</h2>");
    if d.trend.is_empty() {
        s.push_str("<p class=\"small\">No clearance estimates recorded.</p>");
    } else {
        s.push_str(&trend_svg(d));
    }
    s.push_str("<h2>Evidence: the braking events with the strongest shimmy</h2>");
    if d.worst.is_empty() {
        s.push_str("<p class=\"small\">No braking event with a measured amplitude.</p>");
    }
    for (i, w) in d.worst.iter().enumerate() {
        let e = &w.event;
        let _ = write!(
            s,
            r#"<p><b>#{}</b> {} for {:.1} s, from {:.1} km/h at {:.2} g: amplitude {} deg (band-passed peak {} deg){}</p>"#,
            i + 1,
            when(e.t_start),
            e.t_end - e.t_start,
            e.v0_kmh,
            e.decel_g,
            opt(e.sw_amplitude_deg, 3),
            opt(e.peak_sw_bp_deg, 3),
            if e.used {
                ""
            } else {
                " — not used for the estimate"
            }
        );
        let (t, f) = trace_svgs(w, i + 1);
        if t.is_empty() {
            s.push_str("<p class=\"small\">No steering trace recorded for this event.</p>");
        } else {
            let _ = write!(
                s,
                r#"<div class="pair">{t}{f}</div><p class="small">Grey: measured angle; red: 3–25 Hz band-pass (MODEL.md §11); dashed: brake onset and end of the event; the trace starts 1 s before the onset.</p>"#
            );
        }
    }
    s.push_str("<h2>All braking events</h2><table><tr><th>#</th><th class=\"l\">start</th><th>duration (s)</th><th>speed (km/h)</th><th>decel (g)</th><th>amplitude (deg)</th><th>peak 3–25 Hz (deg)</th><th>odometer (km)</th><th class=\"l\">used</th></tr>");
    for (i, e) in d.events.iter().enumerate() {
        let _ = write!(
            s,
            r#"<tr><td>{}</td><td class="l">{}</td><td>{:.2}</td><td>{:.1}</td><td>{:.2}</td><td>{}</td><td>{}</td><td>{:.2}</td><td class="l">{}</td></tr>"#,
            i + 1,
            when(e.t_start),
            e.t_end - e.t_start,
            e.v0_kmh,
            e.decel_g,
            opt(e.sw_amplitude_deg, 3),
            opt(e.peak_sw_bp_deg, 3),
            e.odometer_km,
            if e.used {
                "yes".to_string()
            } else {
                format!("no ({})", esc(e.unused_reason.as_deref().unwrap_or("")))
            }
        );
    }
    s.push_str("</table>");
    s.push_str("<h2>Maintenance guidance (source study's conclusions)</h2><ul>");
    for g in &d.guidance {
        let _ = write!(s, "<li>{}</li>", esc(g));
    }
    s.push_str("</ul><h2>Data quality</h2><p class=\"small\">");
    match &d.counters {
        Some(c) => {
            let _ = write!(s, "Last run: {}", esc(&c.to_string()));
        }
        None => s.push_str("No counters recorded."),
    }
    if d.journal_invalid_lines > 0 {
        let _ = write!(
            s,
            " · {} corrupt journal line(s) skipped",
            d.journal_invalid_lines
        );
    }
    s.push_str("</p></body></html>\n");
    s
}
