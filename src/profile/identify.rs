//! `shimmy identify`: which vehicle profile a CAN log comes from, with the evidence.
//!
//! Each profile expects certain messages on its bus: the messages its mapping reads and, when it
//! has a `bus.toml`, the messages listed there with their periods. For each of them a bounded
//! prefix of the log (the first [`Options::max_seconds`] of log time; [`fingerprint`]) shows
//! whether it is present, whether its payload has the DBC's length, whether its send period is
//! the expected one (from `bus.toml`, else the DBC's `GenMsgCycleTime`, where known), and, where
//! the mapping declares them, how often its checksum verifies and its rolling counter advances
//! by exactly one. The weight of the evidence follows how often it would hold by chance: an ID
//! or a length says little (other cars use the same IDs), a period a little more, a checksum
//! that verifies on every frame (1 in 256 per frame by chance) or a counter that steps by one
//! from frame to frame (1 in 16 for 4 bits) a great deal.
//!
//! A profile **fits** a log when, on one bus channel,
//! * every message its mapping reads is present, and at least 80 % of its `bus.toml` messages;
//! * every present message has the DBC's payload length in at least 90 % of its frames, and
//!   the expected period within a factor of 1.5 where one is known and measurable (at least
//!   five expected periods of frames seen: a slow message also sent on events looks fast in
//!   a window that holds only one or two of its cycles);
//! * every declared checksum verifies on at least 90 % of the frames, every declared counter
//!   advances by one in at least 80 % of the steps (where at least 5 frames were seen);
//! * and something strong confirms it: at least one checksum or counter verified, or, for a
//!   profile that declares none, at least three messages whose lengths and periods all match.
//!
//! The verdict: exactly one profile fits → identified; several fit with scores within 0.1 of
//! the best and as much evidence (points within 5 %) → ambiguous, naming them; otherwise the
//! best of them is identified (a profile whose `bus.toml` explains more of the log wins over
//! one that describes less); none fits → unknown, naming the closest profile and what did not
//! fit. The score (−1…1) weighs every expected message's evidence (present 1, length 2,
//! period 1, checksum 4, counter 3; contradicted evidence counts negative) against the most it
//! could have.
//!
//! What it is not: the decoding of signals ([`crate::signals`]) or a check that the mapping's
//! signs and scales are right (that is `shimmy doctor`). Profiles of cars that share a bus
//! layout (one maker's platform) fit each other's logs: the verdict is then ambiguous, or names
//! the one whose `bus.toml` matches better.

pub mod fingerprint;

use std::path::{Path, PathBuf};

use anyhow::Context;
use serde::Serialize;

use super::Profile;
use crate::dbc::{Database, Signal};
use crate::signals::checksum::ChecksumKind;
use crate::source::log::LogReader;
use crate::source::CanSource;
use crate::wire::Frame;
pub use fingerprint::Fingerprint;

/// Minimum share of a message's frames with the DBC's length.
pub const DLC_MIN_FRACTION: f64 = 0.9;
/// Minimum share of frames whose declared checksum verifies.
pub const CHECKSUM_MIN_FRACTION: f64 = 0.9;
/// Minimum share of counter steps of exactly one.
pub const COUNTER_MIN_FRACTION: f64 = 0.8;
/// Frames needed before a checksum or counter is judged.
pub const MIN_CHECKED: u64 = 5;
/// A period is compared only when the frames seen span at least this many expected periods.
const MIN_CYCLES_FOR_PERIOD: f64 = 5.0;
/// A measured period within this factor of the expected one matches.
pub const PERIOD_FACTOR: f64 = 1.5;
/// Minimum share of a `bus.toml`'s messages present.
pub const BUS_MIN_PRESENT: f64 = 0.8;
/// Profiles that fit with scores closer than this to the best are reported as ambiguous.
pub const AMBIGUITY_MARGIN: f64 = 0.1;

/// How much of a log to look at.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Options {
    /// Log time looked at per log, from its first frame (s).
    pub max_seconds: f64,
    /// Frames looked at in all.
    pub max_frames: u64,
}

impl Default for Options {
    fn default() -> Self {
        Options {
            max_seconds: 30.0,
            max_frames: 2_000_000,
        }
    }
}

/// One message a profile expects on its bus.
#[derive(Clone, Debug, Serialize)]
pub struct ExpectedMessage {
    pub name: String,
    pub id: u32,
    pub extended: bool,
    /// Payload length the DBC declares (bytes).
    pub dlc: usize,
    /// Nominal send period (ms), where known, and where it comes from ("bus.toml" or "DBC").
    pub period_ms: Option<f64>,
    pub period_from: Option<&'static str>,
    /// Read by the mapping / listed in `bus.toml`.
    pub mapped: bool,
    pub in_bus: bool,
    pub checksum: Option<ChecksumKind>,
    pub counter_signal: Option<String>,
    /// The counter's signal and modulus (2^bits).
    #[serde(skip)]
    pub counter: Option<(Signal, u64)>,
}

/// A profile prepared for identification: its expected messages resolved against its DBC.
#[derive(Clone, Debug)]
pub struct Candidate {
    pub name: String,
    pub label: String,
    pub messages: Vec<ExpectedMessage>,
}

impl Candidate {
    /// Resolves a profile's mapping and bus description against its DBC.
    pub fn from_profile(p: &Profile) -> anyhow::Result<Candidate> {
        let (db, _) = Database::load(&p.dbc_path)?;
        let mut messages: Vec<ExpectedMessage> = Vec::new();
        for name in p.mapping.used_messages() {
            let i = db
                .message_by_name(name)
                .with_context(|| format!("mapping message `{name}` is not in the DBC"))?;
            let m = &db.messages()[i];
            let rules = p.mapping.rules(name);
            let counter = match &rules.counter_signal {
                Some(c) => {
                    let s = m.signal_by_name(c).with_context(|| {
                        format!("messages.{name}.counter_signal `{c}` is not in the DBC")
                    })?;
                    let sig = m.signals[s].clone();
                    let modulus = if sig.size >= 64 {
                        u64::MAX
                    } else {
                        1u64 << sig.size
                    };
                    Some((sig, modulus))
                }
                None => None,
            };
            messages.push(ExpectedMessage {
                name: name.to_string(),
                id: m.id,
                extended: m.extended,
                dlc: m.size_bytes,
                period_ms: m.cycle_time_ms.filter(|&c| c > 0).map(f64::from),
                period_from: m.cycle_time_ms.filter(|&c| c > 0).map(|_| "DBC"),
                mapped: true,
                in_bus: false,
                checksum: rules.checksum,
                counter_signal: rules.counter_signal.clone(),
                counter,
            });
        }
        if let Some(bus) = p.load_bus()? {
            let resolved = bus.resolve(&db)?;
            for (bm, (id, extended, dlc, period)) in bus.messages.iter().zip(resolved) {
                match messages.iter_mut().find(|m| m.name == bm.name) {
                    Some(m) => {
                        m.in_bus = true;
                        m.period_ms = Some(period);
                        m.period_from = Some("bus.toml");
                    }
                    None => messages.push(ExpectedMessage {
                        name: bm.name.clone(),
                        id,
                        extended,
                        dlc,
                        period_ms: Some(period),
                        period_from: Some("bus.toml"),
                        mapped: false,
                        in_bus: true,
                        checksum: None,
                        counter_signal: None,
                        counter: None,
                    }),
                }
            }
        }
        Ok(Candidate {
            name: p.name.clone(),
            label: p.label(),
            messages,
        })
    }
}

/// A profile on the search path that could not be prepared.
#[derive(Clone, Debug, Serialize)]
pub struct NotLoaded {
    pub profile: String,
    pub error: String,
}

/// The profiles to compare a log with.
#[derive(Clone, Debug, Default)]
pub struct Catalogue {
    pub candidates: Vec<Candidate>,
    pub not_loaded: Vec<NotLoaded>,
}

impl Catalogue {
    /// Every profile on the search path ([`super::load_all`]); the ones that fail to load (a
    /// DBC not found, a bad file) are listed with their error, not fatal.
    pub fn search_path() -> Catalogue {
        let mut c = Catalogue::default();
        for dir in super::list() {
            match Profile::load_dir(&dir).and_then(|p| Candidate::from_profile(&p)) {
                Ok(cand) => c.candidates.push(cand),
                Err(e) => c.not_loaded.push(NotLoaded {
                    profile: dir.display().to_string(),
                    error: format!("{e:#}"),
                }),
            }
        }
        c
    }

    /// These profiles only.
    pub fn of(profiles: &[Profile]) -> anyhow::Result<Catalogue> {
        let candidates = profiles
            .iter()
            .map(|p| Candidate::from_profile(p).with_context(|| format!("profile {}", p.name)))
            .collect::<anyhow::Result<_>>()?;
        Ok(Catalogue {
            candidates,
            not_loaded: Vec::new(),
        })
    }
}

/// How one checksum or counter fared.
#[derive(Clone, Debug, Serialize)]
pub struct CheckEvidence {
    /// The checksum kind or the counter signal.
    pub what: String,
    /// Frames checked (checksum) or steps between frames (counter), and how many passed.
    pub checked: u64,
    pub passed: u64,
    /// Verified (enough frames, enough passed), contradicted (enough frames, too few passed),
    /// or neither (too few frames): `null`.
    pub verified: Option<bool>,
}

/// What the log showed about one expected message.
#[derive(Clone, Debug, Serialize)]
pub struct MessageEvidence {
    pub name: String,
    pub id: u32,
    pub extended: bool,
    pub mapped: bool,
    pub in_bus: bool,
    pub frames: u64,
    pub dlc_expected: usize,
    /// Share of frames with the DBC's length, and the most common length seen.
    pub dlc_match_fraction: Option<f64>,
    pub dlc_seen: Option<usize>,
    pub period_ms_expected: Option<f64>,
    pub period_from: Option<&'static str>,
    pub period_ms_measured: Option<f64>,
    pub period_ok: Option<bool>,
    pub checksum: Option<CheckEvidence>,
    pub counter: Option<CheckEvidence>,
    /// What does not fit (empty when everything that could be checked fits).
    pub problems: Vec<String>,
}

impl MessageEvidence {
    fn verified(&self) -> bool {
        [&self.checksum, &self.counter]
            .iter()
            .any(|c| c.as_ref().is_some_and(|c| c.verified == Some(true)))
    }
}

/// How strongly a profile is confirmed.
#[derive(Clone, Copy, Debug, PartialEq, Eq, PartialOrd, Ord, Serialize)]
#[serde(rename_all = "snake_case")]
pub enum Strength {
    /// Only IDs (and perhaps lengths): not enough to name a car.
    Weak,
    /// No checksum or counter declared, but three or more messages with matching lengths and
    /// periods.
    Timing,
    /// At least one checksum or counter verified.
    Strong,
}

/// One profile against the log.
#[derive(Clone, Debug, Serialize)]
pub struct ProfileEvidence {
    pub profile: String,
    pub label: String,
    /// The bus channel (interface) the evidence is from: the one where the profile fits best.
    pub channel: Option<String>,
    pub fits: bool,
    pub strength: Strength,
    pub score: f64,
    /// The score's points before normalising: how much of the log the profile explains.
    pub points: f64,
    pub messages: Vec<MessageEvidence>,
    /// What does not fit, one line each.
    pub problems: Vec<String>,
    /// One line: what confirms it, or what does not fit.
    pub summary: String,
}

/// The verdict.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize)]
#[serde(rename_all = "snake_case")]
pub enum Verdict {
    Identified,
    Ambiguous,
    Unknown,
}

/// The answer for one log (or one vehicle's logs together).
#[derive(Clone, Debug, Serialize)]
pub struct Identification {
    pub verdict: Verdict,
    /// The profile identified.
    pub profile: Option<String>,
    /// Ambiguous: the profiles that fit equally.
    pub candidates: Vec<String>,
    /// Unknown: the closest profile, when any of its messages appear.
    pub closest: Option<String>,
    /// One line for a person.
    pub summary: String,
    pub frames_read: u64,
    pub seconds_read: f64,
    /// Channels (interfaces) seen.
    pub channels: Vec<String>,
    /// IDs seen that no profile expects (per channel; capped at 4096).
    pub other_ids: usize,
    /// Lines or records the log reader could not parse (a format it does not read shows here).
    pub malformed: u64,
    /// Every profile, best first.
    pub profiles: Vec<ProfileEvidence>,
    pub not_loaded: Vec<NotLoaded>,
}

impl Identification {
    /// The identified profile's evidence.
    pub fn chosen(&self) -> Option<&ProfileEvidence> {
        let name = self.profile.as_ref().or(self.closest.as_ref())?;
        self.profiles.iter().find(|p| &p.profile == name)
    }
}

fn pct(a: u64, b: u64) -> f64 {
    if b == 0 {
        0.0
    } else {
        100.0 * a as f64 / b as f64
    }
}

/// The checksum kind as the mapping names it ("toyota", "vw_mqb", "shimmy").
pub fn kind_name(kind: ChecksumKind) -> String {
    serde_json::to_value(kind)
        .ok()
        .and_then(|v| v.as_str().map(String::from))
        .unwrap_or_else(|| format!("{kind:?}"))
}

/// The evidence for one expected message on one channel.
fn message_evidence(fp: &Fingerprint, ch: usize, cand: usize, mi: usize) -> MessageEvidence {
    let m = &fp.candidates()[cand].messages[mi];
    let k = m.id | (m.extended as u32) << 31;
    let slot = fp.slots.get(&(ch, k));
    let frames = slot.map_or(0, |s| s.frames);
    let mut e = MessageEvidence {
        name: m.name.clone(),
        id: m.id,
        extended: m.extended,
        mapped: m.mapped,
        in_bus: m.in_bus,
        frames,
        dlc_expected: m.dlc,
        dlc_match_fraction: None,
        dlc_seen: None,
        period_ms_expected: m.period_ms,
        period_from: m.period_from,
        period_ms_measured: None,
        period_ok: None,
        checksum: None,
        counter: None,
        problems: Vec::new(),
    };
    let Some(s) = slot.filter(|s| s.frames > 0) else {
        e.problems.push("absent".into());
        return e;
    };
    let f = s.lens[m.dlc.min(64)] as f64 / s.frames as f64;
    e.dlc_match_fraction = Some(f);
    e.dlc_seen = Some(s.common_len());
    if f < DLC_MIN_FRACTION {
        e.problems.push(format!(
            "{} % of its frames have the DBC's {} bytes (most have {})",
            (100.0 * f).round(),
            m.dlc,
            s.common_len()
        ));
    }
    e.period_ms_measured = s.period_ms();
    // A period is judged only over several of its cycles: a slow message that is also sent on
    // events (a gear change) looks fast in a window that holds one or two of its cycles.
    let span_ms = s.intervals.iter().sum::<i64>() as f64 * 1e-6;
    let judged = m
        .period_ms
        .filter(|&want| span_ms >= MIN_CYCLES_FOR_PERIOD * want);
    if let (Some(want), Some(got)) = (judged, e.period_ms_measured) {
        let ok = got <= want * PERIOD_FACTOR && got >= want / PERIOD_FACTOR;
        e.period_ok = Some(ok);
        if !ok {
            e.problems.push(format!(
                "sent every {got:.1} ms, {} says {want} ms",
                m.period_from.unwrap_or("the profile")
            ));
        }
    }
    let check = s.checks.iter().find(|c| c.cand == cand && c.msg == mi);
    if let (Some(kind), Some(c)) = (m.checksum, check) {
        let verified = (c.ck_checked >= MIN_CHECKED)
            .then_some(c.ck_passed as f64 >= CHECKSUM_MIN_FRACTION * c.ck_checked as f64);
        if verified == Some(false) {
            e.problems.push(format!(
                "its {} checksum verifies on {:.0} % of {} frames",
                kind_name(kind),
                pct(c.ck_passed, c.ck_checked),
                c.ck_checked
            ));
        }
        e.checksum = Some(CheckEvidence {
            what: kind_name(kind),
            checked: c.ck_checked,
            passed: c.ck_passed,
            verified,
        });
    }
    if let (Some(name), Some(c)) = (&m.counter_signal, check) {
        let verified = (c.ctr_steps + 1 >= MIN_CHECKED)
            .then_some(c.ctr_ok as f64 >= COUNTER_MIN_FRACTION * c.ctr_steps as f64);
        if verified == Some(false) {
            e.problems.push(format!(
                "its counter {name} steps by one in {:.0} % of {} steps",
                pct(c.ctr_ok, c.ctr_steps),
                c.ctr_steps
            ));
        }
        e.counter = Some(CheckEvidence {
            what: name.clone(),
            checked: c.ctr_steps,
            passed: c.ctr_ok,
            verified,
        });
    }
    e
}

/// Score points of one message: (got, max).
fn points(e: &MessageEvidence) -> (f64, f64) {
    let mut max = 3.0;
    let mut got = 0.0;
    if e.frames > 0 {
        got += 1.0;
        got += if e.dlc_match_fraction.unwrap_or(0.0) >= DLC_MIN_FRACTION {
            2.0
        } else {
            -2.0
        };
    }
    if e.period_ms_expected.is_some() {
        max += 1.0;
        got += match e.period_ok {
            Some(true) => 1.0,
            Some(false) => -1.0,
            None => 0.0,
        };
    }
    for (c, w) in [(&e.checksum, 4.0), (&e.counter, 3.0)] {
        if let Some(c) = c {
            max += w;
            got += match c.verified {
                Some(true) => w,
                Some(false) => -w,
                None => 0.0,
            };
        }
    }
    (got, max)
}

/// The evidence for a profile on one channel.
fn profile_on_channel(fp: &Fingerprint, ch: Option<usize>, cand: usize) -> ProfileEvidence {
    let c = &fp.candidates()[cand];
    let messages: Vec<MessageEvidence> = (0..c.messages.len())
        // No channel (no frames at all): every message reads absent.
        .map(|mi| message_evidence(fp, ch.unwrap_or(usize::MAX), cand, mi))
        .collect();
    let mut problems = Vec::new();
    for e in &messages {
        let absent = e.frames == 0;
        if absent && !e.mapped {
            continue;
        }
        for p in &e.problems {
            problems.push(format!("{} (0x{:X}): {p}", e.name, e.id));
        }
    }
    let bus: Vec<_> = messages.iter().filter(|e| e.in_bus && !e.mapped).collect();
    let bus_absent = bus.iter().filter(|e| e.frames == 0).count();
    if !bus.is_empty() && (bus.len() - bus_absent) as f64 / (bus.len() as f64) < BUS_MIN_PRESENT {
        problems.push(format!(
            "{bus_absent} of the {} further bus.toml messages are absent",
            bus.len()
        ));
    }
    let verified: Vec<&str> = messages
        .iter()
        .filter(|e| e.verified())
        .map(|e| e.name.as_str())
        .collect();
    let declares_checks = c
        .messages
        .iter()
        .any(|m| m.checksum.is_some() || m.counter.is_some());
    let timed = messages
        .iter()
        .filter(|e| e.frames > 0 && e.period_ok == Some(true))
        .count();
    let strength = if !verified.is_empty() {
        Strength::Strong
    } else if !declares_checks && timed >= 3 {
        Strength::Timing
    } else {
        Strength::Weak
    };
    let (got, max) = messages
        .iter()
        .map(points)
        .fold((0.0, 0.0), |a, b| (a.0 + b.0, a.1 + b.1));
    let score = if max > 0.0 { got / max } else { 0.0 };
    let fits = problems.is_empty() && strength > Strength::Weak;
    let present = messages.iter().filter(|e| e.frames > 0).count();
    let summary = if fits {
        let mapped = messages.iter().filter(|e| e.mapped).count();
        let mut s = format!("all {mapped} mapped messages present with the DBC's lengths");
        if !verified.is_empty() {
            s += &format!("; checksum or counter verified on {}", verified.join(", "));
        }
        let with_period = messages.iter().filter(|e| e.period_ok.is_some()).count();
        if with_period > 0 {
            s += &format!("; periods as expected on {timed} of {with_period}");
        }
        s
    } else if present == 0 {
        "none of its messages appear".into()
    } else if problems.is_empty() {
        format!(
            "{present} of its {} messages present and consistent, but nothing confirms them \
             (no checksum or counter verified)",
            messages.len()
        )
    } else {
        problems.join("; ")
    };
    ProfileEvidence {
        profile: c.name.clone(),
        label: c.label.clone(),
        channel: ch.and_then(|i| fp.channels.get(i)).map(|n| n.to_string()),
        fits,
        strength,
        score,
        points: got,
        messages,
        problems,
        summary,
    }
}

/// Best first: fitting, then by score, then by the evidence behind it, then by name.
fn better(a: &ProfileEvidence, b: &ProfileEvidence) -> std::cmp::Ordering {
    b.fits
        .cmp(&a.fits)
        .then(b.score.total_cmp(&a.score))
        .then(b.points.total_cmp(&a.points))
        .then(b.strength.cmp(&a.strength))
        .then(a.profile.cmp(&b.profile))
}

/// Judges a fingerprint: every profile's evidence (on its best channel) and the verdict.
pub fn evaluate(fp: &Fingerprint) -> Identification {
    let mut profiles: Vec<ProfileEvidence> = (0..fp.candidates().len())
        .map(|ci| {
            let chans: Vec<Option<usize>> = if fp.channels.is_empty() {
                vec![None]
            } else {
                (0..fp.channels.len()).map(Some).collect()
            };
            chans
                .into_iter()
                .map(|ch| profile_on_channel(fp, ch, ci))
                .min_by(better)
                .expect("at least one channel")
        })
        .collect();
    profiles.sort_by(better);
    let fitting: Vec<&ProfileEvidence> = profiles.iter().filter(|p| p.fits).collect();
    let (verdict, profile, candidates, closest, summary) = match fitting.as_slice() {
        [] => {
            let closest = profiles
                .iter()
                .find(|p| p.messages.iter().any(|m| m.frames > 0));
            let summary = if fp.frames == 0 {
                "unknown: no frames read (is it a candump -L, Vector ASC, BLF, MF4 or PEAK TRC \
                 log?)"
                    .into()
            } else {
                match closest {
                    Some(c) => format!(
                        "unknown: no profile fits; closest {} (score {:.2}): {}",
                        c.label, c.score, c.summary
                    ),
                    None => format!(
                        "unknown: none of the {} profiles' messages appear in the log",
                        profiles.len()
                    ),
                }
            };
            (
                Verdict::Unknown,
                None,
                Vec::new(),
                closest.map(|c| c.profile.clone()),
                summary,
            )
        }
        [best, rest @ ..] => {
            // Equal: as good a score, and as much of the log explained (a profile whose
            // bus.toml describes more of what the log holds wins over one describing less).
            let tied: Vec<&ProfileEvidence> = rest
                .iter()
                .copied()
                .filter(|p| {
                    best.score - p.score < AMBIGUITY_MARGIN
                        && p.points >= (1.0 - AMBIGUITY_MARGIN / 2.0) * best.points
                })
                .collect();
            if tied.is_empty() {
                let mut s = format!("identified: {}: {}", best.label, best.summary);
                if let Some(ch) = &best.channel {
                    s += &format!(" (channel {ch})");
                }
                if !rest.is_empty() {
                    let others: Vec<&str> = rest.iter().map(|p| p.profile.as_str()).collect();
                    s += &format!(
                        "; also consistent, with less evidence: {}",
                        others.join(", ")
                    );
                }
                (
                    Verdict::Identified,
                    Some(best.profile.clone()),
                    Vec::new(),
                    None,
                    s,
                )
            } else {
                let names: Vec<String> = std::iter::once(*best)
                    .chain(tied)
                    .map(|p| p.profile.clone())
                    .collect();
                let s = format!(
                    "ambiguous: {} fit equally well (their buses look alike in this log)",
                    names.join(", ")
                );
                (Verdict::Ambiguous, None, names, None, s)
            }
        }
    };
    let (other_ids, _) = fp.other_ids();
    Identification {
        verdict,
        profile,
        candidates,
        closest,
        summary,
        frames_read: fp.frames,
        seconds_read: fp.seconds(),
        channels: fp.channels.iter().map(|c| c.to_string()).collect(),
        other_ids,
        malformed: 0,
        profiles,
        not_loaded: Vec::new(),
    }
}

/// Identifies a stream of frames (the first `opts.max_seconds` of it).
pub fn identify_frames(
    cat: &Catalogue,
    frames: impl IntoIterator<Item = Frame>,
    opts: Options,
) -> Identification {
    let mut fp = Fingerprint::new(&cat.candidates, opts.max_seconds, opts.max_frames);
    for f in frames {
        if !fp.push(&f) {
            break;
        }
    }
    let mut id = evaluate(&fp);
    id.not_loaded = cat.not_loaded.clone();
    id
}

/// Feeds the prefix of one source into `fp`; returns the reader's malformed-input count.
pub fn feed_source(fp: &mut Fingerprint, src: &mut dyn CanSource) -> anyhow::Result<u64> {
    fp.start_log();
    while let Some(f) = src.next_frame().context("reading log")? {
        if !fp.push(&f) {
            break;
        }
    }
    Ok(src.stats().malformed)
}

/// Identifies one vehicle's logs together (the first `opts.max_seconds` of each).
pub fn identify_logs_with(
    cat: &Catalogue,
    paths: &[PathBuf],
    opts: Options,
) -> anyhow::Result<Identification> {
    let mut fp = Fingerprint::new(&cat.candidates, opts.max_seconds, opts.max_frames);
    let mut malformed = 0;
    for p in paths {
        let mut src =
            LogReader::open(p).with_context(|| format!("cannot open log {}", p.display()))?;
        malformed +=
            feed_source(&mut fp, &mut src).with_context(|| format!("log {}", p.display()))?;
    }
    let mut id = evaluate(&fp);
    id.malformed = malformed;
    if id.frames_read == 0 && malformed > 0 {
        id.summary = format!(
            "unknown: no frames read; the log reader could not parse {malformed} line(s) or \
             record(s) (it reads candump -L, Vector ASC, BLF, MF4 and PEAK TRC)"
        );
    }
    id.not_loaded = cat.not_loaded.clone();
    Ok(id)
}

/// Identifies one vehicle's logs against every profile on the search path, looking at the first
/// `max_seconds` of each log.
pub fn identify_logs(paths: &[PathBuf], max_seconds: f64) -> anyhow::Result<Identification> {
    let cat = Catalogue::search_path();
    if cat.candidates.is_empty() {
        anyhow::bail!(
            "no vehicle profile could be loaded ({})",
            if cat.not_loaded.is_empty() {
                "none found on the search path".to_string()
            } else {
                cat.not_loaded
                    .iter()
                    .map(|n| format!("{}: {}", n.profile, n.error))
                    .collect::<Vec<_>>()
                    .join("; ")
            }
        );
    }
    identify_logs_with(
        &cat,
        paths,
        Options {
            max_seconds,
            ..Options::default()
        },
    )
}

/// [`identify_logs`] for one log.
pub fn identify_log(path: &Path, max_seconds: f64) -> anyhow::Result<Identification> {
    identify_logs(&[path.to_path_buf()], max_seconds)
}
