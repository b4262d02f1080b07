//! The counters shimmyd logs every `log.counters_interval_s` (per minute by default) and writes
//! to the journal at stop: totals and the increments of the last interval.
//!
//! Definitions:
//! * `frames`: frames the sources delivered;
//! * `decode_errors`: input the sources could not parse (malformed log lines / records) plus
//!   frames of mapped messages too short for their signals;
//! * `invalid_messages`: frames of mapped messages rejected by checksum or rolling counter, plus
//!   message timeouts;
//! * `events`: braking events finished;
//! * `journal_errors`: journal writes, fsyncs or rotations the disk refused (a full or
//!   read-only disk; retries included); `journal_dropped`: records the journal dropped because
//!   its in-memory backlog was full during such an outage (they are a gap in its sequence
//!   numbers); `journal_backlog`: records waiting in memory for the disk now (a level, not a
//!   count: the interval line shows the current value). See [`crate::journal::Health`].
//!
//! Beside them, whenever braking events are rejected or none has been found and the counts
//! changed since the last line, a `braking:` line gives the detector's rejections per reason
//! and the likely cause ([`crate::monitor::EventStage::rejections`]); the journal's `stop`
//! record holds the counts as `rejections`.

use serde::Serialize;

use crate::journal::Health;
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
    pub journal_errors: u64,
    pub journal_dropped: u64,
    pub journal_backlog: u64,
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
            ..Counters::default()
        }
    }

    /// With the journal's counts ([`crate::journal::Journal::health`]).
    pub fn with_journal(mut self, h: &Health) -> Counters {
        self.journal_errors = h.write_errors;
        self.journal_dropped = h.dropped_records;
        self.journal_backlog = h.backlog_records;
        self
    }

    pub fn minus(&self, before: &Counters) -> Counters {
        Counters {
            frames: self.frames - before.frames,
            decode_errors: self.decode_errors - before.decode_errors,
            invalid_messages: self.invalid_messages - before.invalid_messages,
            events: self.events - before.events,
            dropped: self.dropped - before.dropped,
            journal_errors: self.journal_errors - before.journal_errors,
            journal_dropped: self.journal_dropped - before.journal_dropped,
            journal_backlog: self.journal_backlog,
        }
    }
}

impl std::fmt::Display for Counters {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(
            f,
            "frames={} decode_errors={} invalid_messages={} events={} dropped={}",
            self.frames, self.decode_errors, self.invalid_messages, self.events, self.dropped
        )?;
        // Only when something happened: a healthy journal keeps the line as it was.
        if self.journal_errors + self.journal_dropped + self.journal_backlog > 0 {
            write!(
                f,
                " journal_errors={} journal_dropped={} journal_backlog={}",
                self.journal_errors, self.journal_dropped, self.journal_backlog
            )?;
        }
        Ok(())
    }
}
