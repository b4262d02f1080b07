//! The counters shimmyd logs every `log.counters_interval_s` (per minute by default) and writes
//! to the journal at stop: totals and the increments of the last interval.
//!
//! Definitions:
//! * `frames`: frames the sources delivered;
//! * `decode_errors`: input the sources could not parse (malformed log lines / records) plus
//!   frames of mapped messages too short for their signals;
//! * `invalid_messages`: frames of mapped messages rejected by checksum or rolling counter, plus
//!   message timeouts;
//! * `events`: braking events finished.
//!
//! Beside them, whenever braking events are rejected or none has been found and the counts
//! changed since the last line, a `braking:` line gives the detector's rejections per reason
//! and the likely cause ([`crate::monitor::EventStage::rejections`]); the journal's `stop`
//! record holds the counts as `rejections`.

use serde::Serialize;

use crate::signals::MessageStats;
use crate::source::SourceStats;

#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize)]
pub struct Counters {
    pub frames: u64,
    pub decode_errors: u64,
    pub invalid_messages: u64,
    pub events: u64,
    /// Frames the kernel or the logger reported dropped.
    pub dropped: u64,
}

impl Counters {
    /// Totals from the sources' and the mapper's counters plus the events seen.
    pub fn from_stats(sources: &SourceStats, mapped: &[MessageStats], events: u64) -> Counters {
        let short: u64 = mapped.iter().map(|m| m.short_frames).sum();
        let invalid: u64 = mapped
            .iter()
            .map(|m| m.checksum_errors + m.counter_errors + m.timeouts)
            .sum();
        Counters {
            frames: sources.frames,
            decode_errors: sources.malformed + short,
            invalid_messages: invalid,
            events,
            dropped: sources.dropped,
        }
    }

    pub fn minus(&self, before: &Counters) -> Counters {
        Counters {
            frames: self.frames - before.frames,
            decode_errors: self.decode_errors - before.decode_errors,
            invalid_messages: self.invalid_messages - before.invalid_messages,
            events: self.events - before.events,
            dropped: self.dropped - before.dropped,
        }
    }
}

impl std::fmt::Display for Counters {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(
            f,
            "frames={} decode_errors={} invalid_messages={} events={} dropped={}",
            self.frames, self.decode_errors, self.invalid_messages, self.events, self.dropped
        )
    }
}

/// Adds two sources' counters.
pub fn add(a: &mut SourceStats, b: &SourceStats) {
    a.frames += b.frames;
    a.malformed += b.malformed;
    a.skipped += b.skipped;
    a.error_frames += b.error_frames;
    a.backwards_timestamps += b.backwards_timestamps;
    a.dropped += b.dropped;
}
