//! [`FaultInjector`]: a layer that degrades any [`CanSource`] the way a real bus or logger
//! can, reproducibly from a seed, so the monitor's validity checks (timeouts, counters,
//! checksums, short frames) can be tested on demand.
//!
//! Each incoming frame, in this order, may be: dropped; preceded by an injected error frame;
//! have one payload bit flipped (corruption); be cut short (truncation: fewer bytes than it
//! had, as a short frame); have its timestamp moved later (delay); or be held back and
//! delivered after the next frame (reorder). Every fault is counted in [`FaultCounts`].
//!
//! The injector does not tell the downstream stats about the faults (a monitor would not
//! know): `stats()` passes the source's counters through, with `frames`, `error_frames` and
//! `backwards_timestamps` counted on what the injector delivers.
//!
//! Not here: faults of the transport itself (I/O errors), which no layer can fake honestly.

use super::{CanSource, Skip, SourceStats};
use crate::wire::frame::{fd_dlc_to_len, fd_len_to_dlc};
use crate::wire::{Frame, FrameKind};
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use std::io;

/// SocketCAN `CAN_ERR_PROT` (protocol violation), the class of injected error frames.
const CAN_ERR_PROT: u32 = 0x08;

/// How often each fault happens (probabilities per frame, 0–1).
#[derive(Clone, Debug, Default, PartialEq, serde::Serialize, serde::Deserialize)]
#[serde(default)]
pub struct FaultConfig {
    pub seed: u64,
    pub drop_rate: f64,
    pub corrupt_rate: f64,
    pub truncate_rate: f64,
    pub delay_rate: f64,
    /// Largest timestamp delay, seconds.
    pub max_delay_s: f64,
    pub reorder_rate: f64,
    pub error_frame_rate: f64,
}

/// What the injector did.
#[derive(Clone, Debug, Default, PartialEq, Eq, serde::Serialize)]
pub struct FaultCounts {
    pub dropped: u64,
    pub corrupted: u64,
    pub truncated: u64,
    pub delayed: u64,
    pub reordered: u64,
    pub error_frames_injected: u64,
}

/// The fault-injecting layer.
pub struct FaultInjector<S> {
    inner: S,
    cfg: FaultConfig,
    rng: ChaCha8Rng,
    counts: FaultCounts,
    /// Frames ready to deliver before pulling from the source.
    ready: heapless::Deque<Frame, 4>,
    /// A frame held back for reordering.
    held: Option<Frame>,
    delivered: u64,
    delivered_errors: u64,
    backwards: u64,
    last_t: Option<i64>,
}

impl<S: CanSource> FaultInjector<S> {
    pub fn new(inner: S, cfg: FaultConfig) -> Self {
        FaultInjector {
            inner,
            rng: ChaCha8Rng::seed_from_u64(cfg.seed),
            cfg,
            counts: FaultCounts::default(),
            ready: heapless::Deque::new(),
            held: None,
            delivered: 0,
            delivered_errors: 0,
            backwards: 0,
            last_t: None,
        }
    }

    /// What was done so far.
    pub fn counts(&self) -> &FaultCounts {
        &self.counts
    }

    pub fn into_inner(self) -> S {
        self.inner
    }

    fn hit(&mut self, p: f64) -> bool {
        p > 0.0 && self.rng.random::<f64>() < p
    }

    /// Apply the per-frame faults; `None` if the frame was dropped.
    fn mangle(&mut self, mut f: Frame) -> Option<Frame> {
        if self.hit(self.cfg.drop_rate) {
            self.counts.dropped += 1;
            return None;
        }
        if f.kind == FrameKind::Data && f.len > 0 && self.hit(self.cfg.corrupt_rate) {
            let byte = self.rng.random_range(0..f.len as usize);
            let bit = self.rng.random_range(0..8u8);
            f.data[byte] ^= 1 << bit;
            self.counts.corrupted += 1;
        }
        if f.kind == FrameKind::Data && f.len > 0 && self.hit(self.cfg.truncate_rate) {
            let new_len = if f.fd {
                // Stay on a length CAN FD can carry.
                let dlc = fd_len_to_dlc(f.len as usize);
                fd_dlc_to_len(self.rng.random_range(0..dlc))
            } else {
                self.rng.random_range(0..f.len as usize)
            };
            for b in &mut f.data[new_len..f.len as usize] {
                *b = 0;
            }
            f.len = new_len as u8;
            f.dlc = if f.fd {
                fd_len_to_dlc(new_len)
            } else {
                new_len as u8
            };
            self.counts.truncated += 1;
        }
        if self.cfg.max_delay_s > 0.0 && self.hit(self.cfg.delay_rate) {
            let max_ns = (self.cfg.max_delay_s * 1e9).max(1.0) as i64;
            f.t_ns = f.t_ns.saturating_add(self.rng.random_range(1..=max_ns));
            self.counts.delayed += 1;
        }
        Some(f)
    }

    fn deliver(&mut self, f: Frame) -> Frame {
        self.delivered += 1;
        if f.kind == FrameKind::Error {
            self.delivered_errors += 1;
        }
        if let Some(last) = self.last_t {
            if f.t_ns < last {
                self.backwards += 1;
            }
        }
        self.last_t = Some(f.t_ns);
        f
    }
}

impl<S: CanSource> CanSource for FaultInjector<S> {
    fn next_frame(&mut self) -> io::Result<Option<Frame>> {
        loop {
            if let Some(f) = self.ready.pop_front() {
                return Ok(Some(self.deliver(f)));
            }
            let Some(f) = self.inner.next_frame()? else {
                // End of the source: release a held frame.
                return Ok(self.held.take().map(|f| self.deliver(f)));
            };
            let Some(f) = self.mangle(f) else {
                continue;
            };
            // At most three frames are queued (error frame, this frame, a held one) and the
            // queue is empty here, so these pushes cannot fail.
            if self.hit(self.cfg.error_frame_rate) {
                let mut e = Frame::empty(f.t_ns);
                e.kind = FrameKind::Error;
                e.id = CAN_ERR_PROT;
                e.len = 8;
                e.dlc = 8;
                e.iface = f.iface;
                self.counts.error_frames_injected += 1;
                let _ = self.ready.push_back(e);
            }
            if let Some(h) = self.held.take() {
                // The held frame goes out after this one.
                let _ = self.ready.push_back(f);
                let _ = self.ready.push_back(h);
                continue;
            }
            if self.hit(self.cfg.reorder_rate) {
                self.counts.reordered += 1;
                self.held = Some(f);
                continue;
            }
            let _ = self.ready.push_back(f);
        }
    }

    fn stats(&self) -> SourceStats {
        let mut s = self.inner.stats();
        s.frames = self.delivered;
        s.error_frames = self.delivered_errors;
        s.backwards_timestamps = self.backwards;
        s
    }

    fn take_skips(&mut self) -> Vec<Skip> {
        self.inner.take_skips()
    }
}
