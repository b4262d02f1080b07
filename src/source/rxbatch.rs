//! Batched reads from a raw CAN socket: one `recvmmsg(2)` call takes up to [`BATCH`] queued
//! records, each with its own control messages, the kernel receive timestamp
//! (`SCM_TIMESTAMPNS`) and the socket's cumulative drop count (`SO_RXQ_OVFL`), exactly as
//! `recvmsg` would give them one at a time.
//!
//! What it is not: a parser of the records (see [`super::socketcan::frame_from_kernel`]) or a
//! waiting loop; [`RxBatch::fill`] never blocks (`MSG_DONTWAIT`), the caller polls.
//!
//! Why not `nix::sys::socket::recvmmsg`: its preallocated headers hold raw pointers (so a source
//! holding them could not move to its reader thread) and are reused without resetting
//! `msg_controllen`, which the kernel shrinks to what the previous call used; a record that
//! later carries one control message more (the drop count appears only after the first drop)
//! would come back with `MSG_CTRUNC`. Here the headers are rebuilt on the stack for every call.

use std::os::fd::RawFd;

use nix::errno::Errno;

/// Records read per call at most.
pub const BATCH: usize = 32;
/// Largest raw CAN record (`struct canfd_frame`).
const RECORD: usize = 72;
/// Control-message space per record: `CMSG_SPACE(struct timespec) + CMSG_SPACE(u32)` is 56 on
/// 64-bit Linux; checked by a test.
const CMSG_BYTES: usize = 64;

#[repr(C, align(8))]
#[derive(Clone, Copy)]
struct CmsgBuf([u8; CMSG_BYTES]);

/// What the kernel said about one record besides its bytes.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct RecordMeta {
    /// The record's real length (`MSG_TRUNC` asked for: may exceed the buffer).
    pub bytes: usize,
    /// `MSG_TRUNC` or `MSG_CTRUNC` set: record or control messages cut.
    pub truncated: bool,
    /// `SCM_TIMESTAMPNS`, ns since the Unix epoch.
    pub t_ns: Option<i64>,
    /// `SO_RXQ_OVFL`: frames this socket's queue dropped since it was opened (wraps at u32;
    /// absent until the first drop).
    pub drops: Option<u32>,
}

/// Up to [`BATCH`] records read by one call, handed out in order.
pub struct RxBatch {
    records: Box<[[u8; RECORD]; BATCH]>,
    cmsgs: Box<[CmsgBuf; BATCH]>,
    meta: [RecordMeta; BATCH],
    len: usize,
    next: usize,
}

impl Default for RxBatch {
    fn default() -> Self {
        RxBatch::new()
    }
}

impl RxBatch {
    pub fn new() -> RxBatch {
        RxBatch {
            records: Box::new([[0; RECORD]; BATCH]),
            cmsgs: Box::new([CmsgBuf([0; CMSG_BYTES]); BATCH]),
            meta: [RecordMeta::default(); BATCH],
            len: 0,
            next: 0,
        }
    }

    /// Records read but not yet handed out.
    pub fn pending(&self) -> usize {
        self.len - self.next
    }

    /// The next record read (its bytes, at most 72 of them, and what came with it).
    pub fn pop(&mut self) -> Option<(&[u8], RecordMeta)> {
        if self.next >= self.len {
            return None;
        }
        let i = self.next;
        self.next += 1;
        let m = self.meta[i];
        Some((&self.records[i][..m.bytes.min(RECORD)], m))
    }

    /// The drop count of the newest record read that carried one (the count is cumulative).
    pub fn last_drops(&self) -> Option<u32> {
        self.meta[..self.len].iter().rev().find_map(|m| m.drops)
    }

    /// One non-blocking `recvmmsg` on `fd` into an emptied batch: `Ok(n)` records (n ≥ 1),
    /// `Err(EAGAIN)` when none is queued. Records still pending are discarded, so call it only
    /// when [`RxBatch::pending`] is 0.
    pub fn fill(&mut self, fd: RawFd) -> Result<usize, Errno> {
        self.len = 0;
        self.next = 0;
        // SAFETY: zeroed iovec/mmsghdr are valid values (null pointers, zero lengths).
        let mut iov: [libc::iovec; BATCH] = unsafe { std::mem::zeroed() };
        let mut hdrs: [libc::mmsghdr; BATCH] = unsafe { std::mem::zeroed() };
        for i in 0..BATCH {
            iov[i] = libc::iovec {
                iov_base: self.records[i].as_mut_ptr().cast(),
                iov_len: RECORD,
            };
            let h = &mut hdrs[i].msg_hdr;
            h.msg_iov = &mut iov[i];
            h.msg_iovlen = 1;
            h.msg_control = self.cmsgs[i].0.as_mut_ptr().cast();
            h.msg_controllen = CMSG_BYTES as _;
        }
        // SAFETY: every header points to one live iovec over a RECORD-byte buffer and to a
        // CMSG_BYTES-byte control buffer, all borrowed mutably for the duration of the call;
        // vlen is the length of `hdrs`; no timeout pointer.
        let n = unsafe {
            libc::recvmmsg(
                fd,
                hdrs.as_mut_ptr(),
                BATCH as _,
                libc::MSG_DONTWAIT | libc::MSG_TRUNC,
                std::ptr::null_mut(),
            )
        };
        let n = Errno::result(n)? as usize;
        for (i, h) in hdrs.iter().enumerate().take(n) {
            self.meta[i] = RecordMeta {
                bytes: h.msg_len as usize,
                truncated: h.msg_hdr.msg_flags & (libc::MSG_TRUNC | libc::MSG_CTRUNC) != 0,
                ..control_messages(&h.msg_hdr)
            };
        }
        self.len = n;
        Ok(n)
    }
}

/// The timestamp and drop count among a received header's control messages.
fn control_messages(h: &libc::msghdr) -> RecordMeta {
    let mut m = RecordMeta::default();
    // SAFETY: `h` was filled by the kernel; msg_control/msg_controllen describe the control
    // buffer it wrote, and the CMSG_* macros stay within msg_controllen. The payloads are read
    // unaligned and only when their length is the expected one.
    unsafe {
        let mut c = libc::CMSG_FIRSTHDR(h);
        while !c.is_null() {
            let data = libc::CMSG_DATA(c);
            let len = (*c).cmsg_len as usize - libc::CMSG_LEN(0) as usize;
            match ((*c).cmsg_level, (*c).cmsg_type) {
                (libc::SOL_SOCKET, libc::SCM_TIMESTAMPNS)
                    if len >= std::mem::size_of::<libc::timespec>() =>
                {
                    let t = std::ptr::read_unaligned(data as *const libc::timespec);
                    m.t_ns = Some(t.tv_sec as i64 * 1_000_000_000 + t.tv_nsec as i64);
                }
                (libc::SOL_SOCKET, libc::SO_RXQ_OVFL) if len >= 4 => {
                    m.drops = Some(std::ptr::read_unaligned(data as *const u32));
                }
                _ => {}
            }
            c = libc::CMSG_NXTHDR(h, c);
        }
    }
    m
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn control_space_fits_a_timestamp_and_a_drop_count() {
        // SAFETY: CMSG_SPACE is arithmetic.
        let need = unsafe {
            libc::CMSG_SPACE(std::mem::size_of::<libc::timespec>() as u32)
                + libc::CMSG_SPACE(std::mem::size_of::<u32>() as u32)
        } as usize;
        assert!(need <= CMSG_BYTES, "{need} > {CMSG_BYTES}");
    }

    #[test]
    fn an_empty_batch_pops_nothing_and_a_bad_fd_is_an_error() {
        let mut b = RxBatch::new();
        assert_eq!(b.pending(), 0);
        assert!(b.pop().is_none());
        assert_eq!(b.fill(-1), Err(Errno::EBADF));
        assert!(b.pop().is_none());
    }
}
