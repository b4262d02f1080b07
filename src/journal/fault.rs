//! [`DiskFaults`]: a layer between the journal and its files that fails operations the way a
//! full or read-only filesystem does, so the journal's outage handling
//! ([`super::Tolerance`]) can be tested on demand on any disk.
//!
//! What it models: a free-space budget (writes beyond it write what fits, then fail with
//! `ENOSPC`, leaving a torn line on disk as a real full disk does; truncation gives the space
//! back), a read-only switch (every write, fsync, create, rename and truncate fails with
//! `EROFS`) and failing fsyncs (`EIO`). The journal really does the part of each operation
//! that succeeds, on real files.
//!
//! Not here: the kernel's own behaviour on a full or read-only filesystem, which only a real
//! small filesystem shows (the VM suite's tmpfs step, `tests/vcan/suite.txt`).

use std::io;
use std::sync::{Arc, Mutex};

/// One I/O operation of the journal on its directory.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Op {
    /// Appending `len` bytes to `current.jsonl`.
    Write { len: usize },
    /// fdatasync of `current.jsonl`.
    Sync,
    /// Opening (creating) `current.jsonl` for appending.
    Create,
    /// Renaming `current.jsonl` to a segment (rotation).
    Rename,
    /// Cutting `freed` bytes off the end of `current.jsonl`.
    Truncate { freed: u64 },
}

/// What decides whether an operation fails.
pub trait IoFaults: Send {
    /// Called before the journal does `op`. `None`: it happens. `Some((done, error))`: only
    /// the first `done` bytes of a write are written, then the operation fails with `error`
    /// (`done` is 0 for anything but a write).
    fn inject(&mut self, op: Op) -> Option<(usize, io::Error)>;
}

#[derive(Debug, Default)]
struct Disk {
    /// Bytes that can still be written; `None`: unlimited.
    free: Option<u64>,
    read_only: bool,
    /// fsyncs still to fail with EIO.
    failing_syncs: u32,
    /// Operations failed so far.
    injected: u64,
}

/// A disk whose free space and writability a test sets while the journal runs. Clones share
/// one disk: the test keeps one, the journal gets another.
#[derive(Clone, Debug, Default)]
pub struct DiskFaults(Arc<Mutex<Disk>>);

impl DiskFaults {
    /// A healthy disk with unlimited space.
    pub fn new() -> DiskFaults {
        DiskFaults::default()
    }

    fn disk(&self) -> std::sync::MutexGuard<'_, Disk> {
        self.0.lock().unwrap_or_else(|p| p.into_inner())
    }

    /// `Some(n)`: `n` more bytes fit, then the disk is full. `None`: unlimited.
    pub fn set_free(&self, free: Option<u64>) {
        self.disk().free = free;
    }

    pub fn set_read_only(&self, ro: bool) {
        self.disk().read_only = ro;
    }

    /// The next `n` fsyncs fail with EIO.
    pub fn fail_syncs(&self, n: u32) {
        self.disk().failing_syncs = n;
    }

    /// Operations failed so far.
    pub fn injected(&self) -> u64 {
        self.disk().injected
    }
}

impl IoFaults for DiskFaults {
    fn inject(&mut self, op: Op) -> Option<(usize, io::Error)> {
        let mut d = self.disk();
        let erofs = || io::Error::from_raw_os_error(libc_errno::EROFS);
        let out = match op {
            _ if d.read_only => Some((0, erofs())),
            Op::Write { len } => match d.free {
                Some(free) if (len as u64) > free => {
                    d.free = Some(0);
                    Some((
                        free as usize,
                        io::Error::from_raw_os_error(libc_errno::ENOSPC),
                    ))
                }
                Some(free) => {
                    d.free = Some(free - len as u64);
                    None
                }
                None => None,
            },
            Op::Sync if d.failing_syncs > 0 => {
                d.failing_syncs -= 1;
                Some((0, io::Error::from_raw_os_error(libc_errno::EIO)))
            }
            Op::Truncate { freed } => {
                if let Some(f) = d.free.as_mut() {
                    *f += freed;
                }
                None
            }
            Op::Sync | Op::Create | Op::Rename => None,
        };
        if out.is_some() {
            d.injected += 1;
        }
        out
    }
}

/// The Linux error numbers used (the same on every Linux architecture).
mod libc_errno {
    pub const EIO: i32 = 5;
    pub const ENOSPC: i32 = 28;
    pub const EROFS: i32 = 30;
}
