//! The per-frame half of `shimmy identify`: what a bounded prefix of a log shows about the
//! messages the profiles expect, per bus channel: frames, payload lengths, send intervals, and
//! for each profile that declares one on the message, how often its checksum verifies and its
//! rolling counter advances by one.
//!
//! Memory is bounded whatever the log's size: state is kept only for (channel, ID) pairs some
//! profile expects (at most [`MAX_CHANNELS`] channels), each with a fixed number of intervals;
//! other IDs are only counted (up to [`MAX_OTHER_IDS`] distinct ones). The prefix ends after
//! `max_seconds` of log time per log or `max_frames` frames in all.
//!
//! What it is not: the judgement (that is [`super::evaluate`]).

use std::collections::{HashMap, HashSet};

use crate::signals::checksum::ChecksumKind;
use crate::wire::{Frame, FrameKind, IfaceName};

use super::Candidate;

/// Bus channels (interfaces) told apart; frames of further channels are counted, not used.
pub const MAX_CHANNELS: usize = 8;
/// Distinct unexpected IDs counted (a bound on memory, not on the log).
pub const MAX_OTHER_IDS: usize = 4096;
/// Send intervals kept per expected (channel, ID) for the period estimate.
pub const MAX_INTERVALS: usize = 128;

/// A checksum or counter check one profile declares on one message.
#[derive(Clone, Debug)]
pub(super) struct Check {
    pub cand: usize,
    pub msg: usize,
    pub checksum: Option<ChecksumKind>,
    pub ck_checked: u64,
    pub ck_passed: u64,
    counter_prev: Option<u64>,
    pub ctr_steps: u64,
    pub ctr_ok: u64,
}

/// What one expected (channel, ID) showed.
#[derive(Clone, Debug)]
pub(super) struct Slot {
    pub frames: u64,
    /// Frames per payload length 0..=64.
    pub lens: [u64; 65],
    last_t: Option<i64>,
    pub intervals: Vec<i64>,
    pub checks: Vec<Check>,
}

/// The fingerprint of a log prefix.
pub struct Fingerprint<'a> {
    cands: &'a [Candidate],
    /// (id | extended << 31) → every (candidate, message) that expects it.
    expected: HashMap<u32, Vec<(usize, usize)>>,
    pub(super) channels: Vec<IfaceName>,
    pub(super) slots: HashMap<(usize, u32), Slot>,
    other_ids: HashSet<(usize, u32)>,
    pub(super) other_ids_overflow: bool,
    pub(super) untracked_channel_frames: u64,
    max_seconds: f64,
    max_frames: u64,
    /// Frames looked at (every kind), and data frames among them.
    pub(super) frames: u64,
    pub(super) data_frames: u64,
    /// Log time looked at, summed over the logs (s).
    pub(super) seconds: f64,
    log_start: Option<i64>,
    log_last: Option<i64>,
    full: bool,
}

fn key(id: u32, extended: bool) -> u32 {
    id | (extended as u32) << 31
}

impl<'a> Fingerprint<'a> {
    pub fn new(cands: &'a [Candidate], max_seconds: f64, max_frames: u64) -> Fingerprint<'a> {
        let mut expected: HashMap<u32, Vec<(usize, usize)>> = HashMap::new();
        for (ci, c) in cands.iter().enumerate() {
            for (mi, m) in c.messages.iter().enumerate() {
                expected
                    .entry(key(m.id, m.extended))
                    .or_default()
                    .push((ci, mi));
            }
        }
        Fingerprint {
            cands,
            expected,
            channels: Vec::new(),
            slots: HashMap::new(),
            other_ids: HashSet::new(),
            other_ids_overflow: false,
            untracked_channel_frames: 0,
            max_seconds,
            max_frames,
            frames: 0,
            data_frames: 0,
            seconds: 0.0,
            log_start: None,
            log_last: None,
            full: false,
        }
    }

    /// The candidates this fingerprint is taken for.
    pub fn candidates(&self) -> &'a [Candidate] {
        self.cands
    }

    /// Starts the next log: its own time window; intervals and counters do not span logs.
    pub fn start_log(&mut self) {
        self.close_log();
        for s in self.slots.values_mut() {
            s.last_t = None;
            for c in &mut s.checks {
                c.counter_prev = None;
            }
        }
        self.full = self.frames >= self.max_frames;
    }

    fn close_log(&mut self) {
        if let (Some(a), Some(b)) = (self.log_start, self.log_last) {
            self.seconds += (b - a).max(0) as f64 * 1e-9;
        }
        self.log_start = None;
        self.log_last = None;
    }

    /// Whether the prefix is complete (the current log's window or the frame budget is used up).
    pub fn is_full(&self) -> bool {
        self.full
    }

    /// Takes one frame; returns whether more frames of this log are wanted.
    pub fn push(&mut self, f: &Frame) -> bool {
        if self.full {
            return false;
        }
        let start = *self.log_start.get_or_insert(f.t_ns);
        if (f.t_ns - start) as f64 * 1e-9 > self.max_seconds || self.frames >= self.max_frames {
            self.full = true;
            return false;
        }
        self.frames += 1;
        self.log_last = Some(self.log_last.map_or(f.t_ns, |l| l.max(f.t_ns)));
        if f.kind != FrameKind::Data {
            return true;
        }
        self.data_frames += 1;
        let ch = match self.channels.iter().position(|c| *c == f.iface) {
            Some(i) => i,
            None if self.channels.len() < MAX_CHANNELS => {
                self.channels.push(f.iface);
                self.channels.len() - 1
            }
            None => {
                self.untracked_channel_frames += 1;
                return true;
            }
        };
        let k = key(f.id, f.extended);
        let Some(exp) = self.expected.get(&k) else {
            if self.other_ids.len() < MAX_OTHER_IDS {
                self.other_ids.insert((ch, k));
            } else if !self.other_ids.contains(&(ch, k)) {
                self.other_ids_overflow = true;
            }
            return true;
        };
        let cands = self.cands;
        let slot = self.slots.entry((ch, k)).or_insert_with(|| Slot {
            frames: 0,
            lens: [0; 65],
            last_t: None,
            intervals: Vec::new(),
            checks: exp
                .iter()
                .filter(|&&(c, m)| {
                    let e = &cands[c].messages[m];
                    e.checksum.is_some() || e.counter.is_some()
                })
                .map(|&(c, m)| Check {
                    cand: c,
                    msg: m,
                    checksum: cands[c].messages[m].checksum,
                    ck_checked: 0,
                    ck_passed: 0,
                    counter_prev: None,
                    ctr_steps: 0,
                    ctr_ok: 0,
                })
                .collect(),
        });
        slot.frames += 1;
        slot.lens[(f.len as usize).min(64)] += 1;
        if let Some(prev) = slot.last_t {
            if slot.intervals.len() < MAX_INTERVALS && f.t_ns >= prev {
                slot.intervals.push(f.t_ns - prev);
            }
        }
        slot.last_t = Some(f.t_ns);
        let data = f.payload();
        for c in &mut slot.checks {
            if let Some(kind) = c.checksum {
                c.ck_checked += 1;
                c.ck_passed += kind.verify(f.id, data).is_ok() as u64;
            }
            let e = &cands[c.cand].messages[c.msg];
            if let Some((sig, modulus)) = &e.counter {
                match sig.raw_bits(data) {
                    Some(v) => {
                        if let Some(p) = c.counter_prev {
                            c.ctr_steps += 1;
                            c.ctr_ok += (v.wrapping_sub(p) % modulus == 1 % modulus) as u64;
                        }
                        c.counter_prev = Some(v);
                    }
                    None => {
                        // Too short to hold the counter: a failed step.
                        c.ctr_steps += c.counter_prev.is_some() as u64;
                        c.counter_prev = None;
                    }
                }
            }
        }
        true
    }

    /// Distinct IDs seen that no profile expects (per channel), and whether there were more
    /// than could be counted.
    pub fn other_ids(&self) -> (usize, bool) {
        (self.other_ids.len(), self.other_ids_overflow)
    }

    /// Log time looked at so far, summed over the logs (s).
    pub fn seconds(&self) -> f64 {
        let open = match (self.log_start, self.log_last) {
            (Some(a), Some(b)) => (b - a).max(0) as f64 * 1e-9,
            _ => 0.0,
        };
        self.seconds + open
    }
}

impl Slot {
    /// The period estimate (ms): the mean of the middle 80 % of the kept intervals, which
    /// ignores both frames batched under one timestamp and the odd gap. `None` below three
    /// intervals.
    pub fn period_ms(&self) -> Option<f64> {
        if self.intervals.len() < 3 {
            return None;
        }
        let mut v = self.intervals.clone();
        v.sort_unstable();
        let cut = v.len() / 10;
        let mid = &v[cut..v.len() - cut];
        Some(mid.iter().sum::<i64>() as f64 / mid.len() as f64 * 1e-6)
    }

    /// The most common payload length.
    pub fn common_len(&self) -> usize {
        (0..self.lens.len())
            .max_by_key(|&i| self.lens[i])
            .unwrap_or(0)
    }
}
