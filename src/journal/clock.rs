//! The wall clock the journal stamps its lines with (`"wall_ns"`, the time a record was
//! written), as a trait so tests can make it jump.
//!
//! A gateway without a real-time clock boots at 1970 or 2000 and is set forward by years when
//! NTP answers, or backward by a bad time source. Nothing in the journal depends on the wall
//! clock: order is the sequence number's, fsync intervals and retries run on the monotonic
//! clock. The stamp is information for the reader (who can see and count the jumps,
//! [`super::Reader::wall_clock_jumps_back`]), never a key.
//!
//! Not here: the frame timestamps of live sources (the kernel's).

use std::sync::atomic::{AtomicI64, Ordering};
use std::sync::Arc;

/// A source of wall-clock time, ns since the Unix epoch.
pub trait WallClock: Send {
    fn now_ns(&self) -> i64;
}

/// The system's real-time clock.
#[derive(Clone, Copy, Debug, Default)]
pub struct SystemClock;

impl WallClock for SystemClock {
    fn now_ns(&self) -> i64 {
        match std::time::SystemTime::now().duration_since(std::time::UNIX_EPOCH) {
            Ok(d) => i64::try_from(d.as_nanos()).unwrap_or(i64::MAX),
            // Before 1970: negative, as it is.
            Err(e) => -i64::try_from(e.duration().as_nanos()).unwrap_or(i64::MAX),
        }
    }
}

/// A clock set by hand (tests): clones share one time, so a test keeps a clone and moves the
/// journal's clock forward or backward while it runs.
#[derive(Clone, Debug, Default)]
pub struct ManualClock(Arc<AtomicI64>);

impl ManualClock {
    pub fn new(now_ns: i64) -> ManualClock {
        ManualClock(Arc::new(AtomicI64::new(now_ns)))
    }

    pub fn set(&self, now_ns: i64) {
        self.0.store(now_ns, Ordering::Relaxed);
    }

    pub fn advance(&self, by_ns: i64) {
        self.0.fetch_add(by_ns, Ordering::Relaxed);
    }
}

impl WallClock for ManualClock {
    fn now_ns(&self) -> i64 {
        self.0.load(Ordering::Relaxed)
    }
}
