//! Frame sources, in the manner of smoltcp's `phy`: one trait, [`CanSource`], implemented by the
//! real sources (log readers, live SocketCAN) and by layers that wrap any source (fault injector,
//! recorder). A source yields frames in arrival order and counts, rather than hides, everything
//! it had to skip.
//!
//! Not here: decoding (see [`crate::dbc`]) or any decision about what a frame means.

pub mod fault;
pub mod lines;
pub mod log;
pub mod recorder;
pub mod writer;

use crate::wire::Frame;

#[cfg(target_os = "linux")]
mod rxbatch;
#[cfg(target_os = "linux")]
pub mod socketcan;

/// Why a source skipped input (a counted, reported skip, never a panic).
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct Skip {
    /// Where: `file:line` for logs, the interface name for live sources.
    pub location: String,
    /// What was wrong, for a human.
    pub reason: String,
}

/// Counters every source keeps.
#[derive(Clone, Debug, Default, PartialEq, Eq, serde::Serialize)]
pub struct SourceStats {
    /// Frames delivered.
    pub frames: u64,
    /// Lines or records that could not be parsed.
    pub malformed: u64,
    /// Records deliberately not delivered (e.g. CAN XL, filtered IDs).
    pub skipped: u64,
    /// Error frames delivered.
    pub error_frames: u64,
    /// Timestamps earlier than the previous frame's.
    pub backwards_timestamps: u64,
    /// Frames the kernel or logger reported dropped (candump DROPCOUNT, socket overflow).
    pub dropped: u64,
    /// Frames delivered with data bytes the log did not hold, as 0 (BLF CAN FD objects
    /// shorter than their declared length, read as Vector's tools read them).
    pub zero_filled: u64,
}

impl SourceStats {
    /// Adds another source's counters (several logs, or a reader that restarted). A drop count
    /// is what a log states, so it saturates instead of overflowing.
    pub fn add(&mut self, b: &SourceStats) {
        self.frames += b.frames;
        self.malformed += b.malformed;
        self.skipped += b.skipped;
        self.error_frames += b.error_frames;
        self.backwards_timestamps += b.backwards_timestamps;
        self.dropped = self.dropped.saturating_add(b.dropped);
        self.zero_filled += b.zero_filled;
    }

    /// What a user should know about frames delivered with bytes the log did not hold, if any.
    pub fn zero_filled_note(&self) -> Option<String> {
        (self.zero_filled > 0).then(|| {
            format!(
                "{} frame(s) held fewer data bytes in the log than they declare (BLF CAN FD \
                 objects some loggers cut at 48 bytes); the missing bytes read as 0, as CANoe \
                 reads them: signals there are not measured",
                self.zero_filled
            )
        })
    }
}

/// Anything that yields CAN frames.
pub trait CanSource {
    /// The next frame; `Ok(None)` at the end of a finite source. Malformed input is not an
    /// error: it is counted in [`CanSource::stats`] and its first occurrences are available from
    /// [`CanSource::take_skips`]. `Err` is reserved for failures of the source itself (I/O).
    fn next_frame(&mut self) -> std::io::Result<Option<Frame>>;

    /// Like [`CanSource::next_frame`], but writes the frame into `out` and returns `Ok(true)`,
    /// or `Ok(false)` at the end (then `out` is unchanged or holds the last frame). Sources
    /// that can fill a reused frame in place (e.g. [`log::LogReader`] on candump logs) override
    /// this to avoid building and copying a frame per call; the default forwards to
    /// `next_frame`.
    fn read_frame(&mut self, out: &mut Frame) -> std::io::Result<bool> {
        match self.next_frame()? {
            Some(f) => {
                *out = f;
                Ok(true)
            }
            None => Ok(false),
        }
    }

    /// Counters so far.
    fn stats(&self) -> SourceStats;

    /// Skip reports collected since the last call (bounded: a source keeps at most a fixed number
    /// and counts the rest).
    fn take_skips(&mut self) -> Vec<Skip> {
        Vec::new()
    }
}
