//! Live CAN input from Linux SocketCAN (`can0`, `vcan0`, ...): [`LiveSource`] reads classic CAN
//! and CAN FD frames from an interface and implements [`CanSource`]; [`LiveSink`] writes frames
//! to one, for tests and the simulator.
//!
//! A thin wrapper over the `socketcan` crate, which opens the raw socket and sets its options
//! (FD mode, kernel ID filters, the error mask). It adds only what a monitor that must keep
//! running needs:
//!
//! - **Kernel filters** limited to the IDs the configuration needs ([`LiveConfig::ids`]), so the
//!   kernel, not this process, discards the rest of the bus.
//! - **Error frames** received (error mask, default all classes), delivered as
//!   [`FrameKind::Error`] and counted.
//! - **Kernel receive timestamps** (`SO_TIMESTAMPNS`, Unix epoch). If the kernel refuses the
//!   option or a frame arrives without one, the frame is stamped with the system clock instead,
//!   the event is reported once and every such frame is counted
//!   ([`LiveStats::clock_timestamps`]).
//! - **Kernel drop count** (`SO_RXQ_OVFL`): frames the kernel dropped because this socket's
//!   receive queue was full are added to [`SourceStats::dropped`], so loss is never silent. This
//!   is why frames are read with `recvmmsg` here ([`super::rxbatch`]) rather than through the
//!   crate's read calls, which parse the timestamp control message but not the drop counter.
//! - **Batched reads**: one `recvmmsg` call takes every queued frame (up to
//!   [`super::rxbatch::BATCH`]), each with its own timestamp and drop count, and on a busy bus
//!   reads are at least [`LiveConfig::read_interval`] apart, so the reading thread wakes about
//!   once per interval rather than once per frame. A frame waits at most that long in the
//!   kernel's queue; its timestamp is still the kernel's receive time.
//! - **Reconnection**: interface down, interface removed, or a bus-off error frame closes the
//!   socket and reopens it with exponential backoff ([`LiveConfig::backoff_initial`] doubling up
//!   to [`LiveConfig::backoff_max`]); every disconnect, failed retry and reconnect is reported
//!   through an event callback (by default one line on stderr). The source never gives up.
//! - **A read timeout** ([`LiveConfig::read_timeout`]): [`CanSource::next_frame`] returns
//!   `Err` of kind [`io::ErrorKind::TimedOut`] when no frame came in time, so the caller can run
//!   periodic work; setting the [`LiveSource::stop_handle`] flag makes the next call return
//!   `Ok(None)` (end of stream) within one timeout, once the frames already read from the
//!   socket have been delivered.
//!
//! Not here: decoding, any decision about what a frame means, and sending. A `LiveSource`
//! never writes to the bus; sending is the separate, explicit [`LiveSink`].
//!
//! Frames lost while disconnected (between a disconnect and the reconnect) are not counted: the
//! kernel cannot say how many there were. The disconnect itself is reported and counted.

use std::io;
use std::os::fd::{AsFd, AsRawFd};
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::Arc;
use std::time::{Duration, Instant, SystemTime};

use ::socketcan::errors::{CAN_ERR_BUSOFF, CAN_ERR_RESTARTED};
use ::socketcan::id::{
    CAN_EFF_FLAG, CAN_EFF_MASK, CAN_ERR_FLAG, CAN_ERR_MASK, CAN_RTR_FLAG, CAN_SFF_MASK,
};
use ::socketcan::socket::{CANFD_MTU, CAN_MTU, CAN_RAW_FD_FRAMES, SOL_CAN_RAW};
use ::socketcan::{
    CanDataFrame, CanErrorFrame, CanFdFrame, CanFdSocket, CanFilter, CanRemoteFrame, EmbeddedFrame,
    ExtendedId, Id, Socket, SocketOptions, StandardId,
};
use nix::errno::Errno;
use nix::poll::{poll, PollFd, PollFlags, PollTimeout};
use nix::sys::socket::{setsockopt, sockopt};

use super::rxbatch::{RxBatch, BATCH};
use super::{CanSource, Skip, SourceStats};
use crate::wire::frame::fd_len_to_dlc;
use crate::wire::{Frame, FrameKind, IfaceName, MAX_DATA};

/// The kernel accepts at most this many `CAN_RAW_FILTER` entries per socket.
pub const MAX_KERNEL_FILTERS: usize = 512;

/// At most this many skip reports are kept between [`CanSource::take_skips`] calls.
const MAX_SKIPS: usize = 32;

/// One arbitration ID to let through the kernel filter (data and remote frames with this ID).
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub struct FilterId {
    pub id: u32,
    pub extended: bool,
}

impl FilterId {
    pub fn standard(id: u32) -> FilterId {
        FilterId {
            id,
            extended: false,
        }
    }

    pub fn extended(id: u32) -> FilterId {
        FilterId { id, extended: true }
    }

    /// The kernel filter matching exactly this ID and frame format (standard vs extended), with
    /// or without the RTR bit.
    fn kernel_filter(self) -> CanFilter {
        if self.extended {
            CanFilter::new(
                (self.id & CAN_EFF_MASK) | CAN_EFF_FLAG,
                CAN_EFF_MASK | CAN_EFF_FLAG,
            )
        } else {
            CanFilter::new(self.id & CAN_SFF_MASK, CAN_SFF_MASK | CAN_EFF_FLAG)
        }
    }
}

/// How to open and keep a live source.
#[derive(Clone, Debug)]
pub struct LiveConfig {
    /// Interface name, e.g. `can0` or `vcan0`.
    pub iface: String,
    /// Receive CAN FD frames too (`CAN_RAW_FD_FRAMES`). Default true.
    pub fd: bool,
    /// IDs to receive; `None` receives everything, `Some(empty)` only error frames. At most
    /// [`MAX_KERNEL_FILTERS`] entries.
    pub ids: Option<Vec<FilterId>>,
    /// SocketCAN error classes to receive as error frames (`CAN_ERR_*` bits); default all.
    pub error_mask: u32,
    /// Longest a [`CanSource::next_frame`] call blocks before returning `TimedOut`.
    pub read_timeout: Duration,
    /// First reconnect delay; doubles after every failed attempt.
    pub backoff_initial: Duration,
    /// Upper bound of the reconnect delay.
    pub backoff_max: Duration,
    /// Close and reopen the socket when a bus-off error frame arrives. Default true.
    pub reconnect_on_bus_off: bool,
    /// Requested socket receive buffer (`SO_RCVBUF`, capped by the kernel's `rmem_max`);
    /// `None` keeps the kernel default.
    pub rcvbuf_bytes: Option<usize>,
    /// Least time between two reads of the socket while frames keep coming: they gather in the
    /// kernel's queue meanwhile and one call reads them all. Zero reads every frame as soon as
    /// it arrives (a wake-up per frame). Keep it well below what the receive queue holds at the
    /// bus rate (the kernel default queue holds a few hundred frames).
    pub read_interval: Duration,
}

impl LiveConfig {
    /// Defaults for `iface`: FD on, all IDs, all error classes, 200 ms read timeout, backoff
    /// 100 ms doubling to 5 s, reconnect on bus-off, reads at least 5 ms apart.
    pub fn new(iface: &str) -> LiveConfig {
        LiveConfig {
            iface: iface.to_string(),
            fd: true,
            ids: None,
            error_mask: CAN_ERR_MASK,
            read_timeout: Duration::from_millis(200),
            backoff_initial: Duration::from_millis(100),
            backoff_max: Duration::from_secs(5),
            reconnect_on_bus_off: true,
            rcvbuf_bytes: None,
            read_interval: Duration::from_millis(5),
        }
    }
}

/// Something the source wants its operator to know. The default handler prints
/// `shimmy: live <iface>: <event>` on stderr.
#[derive(Debug)]
pub enum LiveEvent<'a> {
    /// The socket is open (first time or after a reconnect).
    Connected {
        iface: &'a str,
        /// Reconnect attempts it took (0 for the first connection).
        attempts: u32,
        /// How long the source was disconnected (zero for the first connection).
        down_for: Duration,
    },
    /// The socket failed or the bus went bus-off; a reconnect follows after `retry_in`.
    Disconnected {
        iface: &'a str,
        reason: &'a str,
        retry_in: Duration,
    },
    /// A reconnect attempt failed; the next one follows after `retry_in`.
    RetryFailed {
        iface: &'a str,
        attempt: u32,
        reason: &'a str,
        retry_in: Duration,
    },
    /// Kernel receive timestamps are not available; frames are stamped with the system clock.
    ClockTimestamps { iface: &'a str, reason: &'a str },
}

impl std::fmt::Display for LiveEvent<'_> {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self {
            LiveEvent::Connected {
                iface, attempts: 0, ..
            } => write!(f, "live {iface}: connected"),
            LiveEvent::Connected {
                iface,
                attempts,
                down_for,
            } => write!(
                f,
                "live {iface}: reconnected after {attempts} attempt(s), {:.3} s without input",
                down_for.as_secs_f64()
            ),
            LiveEvent::Disconnected {
                iface,
                reason,
                retry_in,
            } => write!(
                f,
                "live {iface}: disconnected ({reason}); reconnecting in {} ms",
                retry_in.as_millis()
            ),
            LiveEvent::RetryFailed {
                iface,
                attempt,
                reason,
                retry_in,
            } => write!(
                f,
                "live {iface}: reconnect attempt {attempt} failed ({reason}); next in {} ms",
                retry_in.as_millis()
            ),
            LiveEvent::ClockTimestamps { iface, reason } => write!(
                f,
                "live {iface}: no kernel receive timestamps ({reason}); using the system clock"
            ),
        }
    }
}

/// Receives every [`LiveEvent`].
pub type EventHandler = Box<dyn FnMut(&LiveEvent<'_>) + Send>;

fn stderr_handler() -> EventHandler {
    Box::new(|e| eprintln!("shimmy: {e}"))
}

/// Counters specific to a live source (beyond [`SourceStats`]).
#[derive(Clone, Debug, Default, PartialEq, Eq, serde::Serialize)]
pub struct LiveStats {
    /// Times the socket was lost (error, interface down/removed, bus-off).
    pub disconnects: u64,
    /// Successful reconnects.
    pub reconnects: u64,
    /// Failed reconnect attempts.
    pub failed_attempts: u64,
    /// Bus-off error frames seen.
    pub bus_off: u64,
    /// Controller-restarted error frames seen.
    pub restarted: u64,
    /// Frames stamped with the system clock because the kernel gave no timestamp.
    pub clock_timestamps: u64,
    /// `next_frame` calls that timed out.
    pub timeouts: u64,
}

enum Conn {
    Up {
        sock: CanFdSocket,
        /// Last cumulative `SO_RXQ_OVFL` drop count seen on this socket.
        drops_seen: u32,
        kernel_ts: bool,
    },
    Down {
        since: Instant,
        next_try: Instant,
        /// Failed reconnect attempts so far.
        attempts: u32,
    },
}

/// A live SocketCAN interface as a [`CanSource`]. See the module docs.
pub struct LiveSource {
    cfg: LiveConfig,
    iface: IfaceName,
    conn: Conn,
    stats: SourceStats,
    live: LiveStats,
    skips: Vec<Skip>,
    stop: Arc<AtomicBool>,
    events: EventHandler,
    clock_ts_reported: bool,
    ever_connected: bool,
    /// Records read from the socket and not yet delivered.
    rx: RxBatch,
    /// Whether the batch's records carry kernel timestamps (the connection's setting).
    rx_kernel_ts: bool,
    /// When the socket was last read, and whether that read filled the batch.
    last_read: Option<Instant>,
    last_full: bool,
}

impl LiveSource {
    /// Open `cfg.iface` now. Fails (with the interface name in the message) if the interface
    /// does not exist or the options are rejected; use [`LiveSource::open_waiting`] to wait for
    /// an interface that is not there yet.
    pub fn open(cfg: LiveConfig) -> io::Result<LiveSource> {
        let mut s = LiveSource::new_down(cfg)?;
        let conn = s.connect().map_err(|e| annotate(&s.cfg.iface, e))?;
        s.conn = conn;
        s.emit_connected(0, Duration::ZERO);
        Ok(s)
    }

    /// Start disconnected and connect on the first [`CanSource::next_frame`] call, retrying with
    /// backoff until the interface exists and is up.
    pub fn open_waiting(cfg: LiveConfig) -> io::Result<LiveSource> {
        LiveSource::new_down(cfg)
    }

    fn new_down(cfg: LiveConfig) -> io::Result<LiveSource> {
        if let Some(ids) = &cfg.ids {
            if ids.len() > MAX_KERNEL_FILTERS {
                return Err(io::Error::new(
                    io::ErrorKind::InvalidInput,
                    format!(
                        "{} CAN IDs requested but the kernel accepts at most {MAX_KERNEL_FILTERS} filters per socket",
                        ids.len()
                    ),
                ));
            }
        }
        if cfg.iface.is_empty() || cfg.iface.len() > 15 {
            return Err(io::Error::new(
                io::ErrorKind::InvalidInput,
                format!("invalid interface name {:?} (1-15 bytes)", cfg.iface),
            ));
        }
        let now = Instant::now();
        Ok(LiveSource {
            iface: IfaceName::from_str_truncated(&cfg.iface),
            conn: Conn::Down {
                since: now,
                next_try: now,
                attempts: 0,
            },
            cfg,
            stats: SourceStats::default(),
            live: LiveStats::default(),
            skips: Vec::new(),
            stop: Arc::new(AtomicBool::new(false)),
            events: stderr_handler(),
            clock_ts_reported: false,
            ever_connected: false,
            rx: RxBatch::new(),
            rx_kernel_ts: false,
            last_read: None,
            last_full: false,
        })
    }

    /// Replace the event handler (default: one line per event on stderr).
    pub fn on_event(&mut self, handler: impl FnMut(&LiveEvent<'_>) + Send + 'static) {
        self.events = Box::new(handler);
    }

    /// A flag that, once set (from any thread or a signal handler), makes the next
    /// [`CanSource::next_frame`] call return `Ok(None)` within one read timeout.
    pub fn stop_handle(&self) -> Arc<AtomicBool> {
        self.stop.clone()
    }

    /// Live-specific counters.
    pub fn live_stats(&self) -> LiveStats {
        self.live.clone()
    }

    /// The interface this source reads.
    pub fn iface(&self) -> &str {
        &self.cfg.iface
    }

    /// True while the socket is open.
    pub fn is_connected(&self) -> bool {
        matches!(self.conn, Conn::Up { .. })
    }

    /// True when frames carry kernel receive timestamps (false while disconnected).
    pub fn kernel_timestamps(&self) -> bool {
        matches!(
            self.conn,
            Conn::Up {
                kernel_ts: true,
                ..
            }
        )
    }

    /// Open and configure a socket on the interface.
    fn connect(&mut self) -> io::Result<Conn> {
        let cfg = &self.cfg;
        let sock = CanFdSocket::open(&cfg.iface)?;
        if !cfg.fd {
            sock.set_socket_option_int(SOL_CAN_RAW, CAN_RAW_FD_FRAMES, 0)?;
        }
        match &cfg.ids {
            None => sock.set_filter_accept_all()?,
            Some(ids) if ids.is_empty() => sock.set_filter_drop_all()?,
            Some(ids) => {
                let filters: Vec<CanFilter> = ids.iter().map(|f| f.kernel_filter()).collect();
                sock.set_filters(&filters)?;
            }
        }
        sock.set_error_filter(cfg.error_mask & CAN_ERR_MASK)?;
        if let Some(n) = cfg.rcvbuf_bytes {
            setsockopt(&sock, sockopt::RcvBuf, &n).map_err(io::Error::from)?;
        }
        // Best effort: without it, dropped frames are still lost but no longer counted.
        let _ = setsockopt(&sock, sockopt::RxqOvfl, &1);
        let kernel_ts = match setsockopt(&sock, sockopt::ReceiveTimestampns, &true) {
            Ok(()) => true,
            Err(e) => {
                let reason = format!("SO_TIMESTAMPNS refused: {e}");
                self.report_clock_ts(&reason);
                false
            }
        };
        sock.set_nonblocking(true)?;
        // Binding succeeds on an interface that is down; it would then deliver nothing.
        if iface_is_up(&self.cfg.iface) == Some(false) {
            return Err(io::Error::new(
                io::ErrorKind::NotConnected,
                "interface is down",
            ));
        }
        Ok(Conn::Up {
            sock,
            drops_seen: 0,
            kernel_ts,
        })
    }

    fn report_clock_ts(&mut self, reason: &str) {
        if !self.clock_ts_reported {
            self.clock_ts_reported = true;
            (self.events)(&LiveEvent::ClockTimestamps {
                iface: &self.cfg.iface,
                reason,
            });
        }
    }

    /// Delay before reconnect attempt `failed + 1`: the initial delay doubled per failure.
    fn backoff(&self, failed: u32) -> Duration {
        self.cfg
            .backoff_initial
            .saturating_mul(1u32 << failed.min(20))
            .min(self.cfg.backoff_max)
    }

    fn emit_connected(&mut self, attempts: u32, down_for: Duration) {
        self.ever_connected = true;
        (self.events)(&LiveEvent::Connected {
            iface: &self.cfg.iface,
            attempts,
            down_for,
        });
    }

    /// Drop the socket and schedule the first reconnect attempt.
    fn disconnect(&mut self, reason: &str) {
        let now = Instant::now();
        let backoff = self.backoff(0);
        self.conn = Conn::Down {
            since: now,
            next_try: now + backoff,
            attempts: 0,
        };
        self.live.disconnects += 1;
        (self.events)(&LiveEvent::Disconnected {
            iface: &self.cfg.iface,
            reason,
            retry_in: backoff,
        });
    }

    /// While down: try to reconnect if it is time, else wait (at most until `deadline`).
    /// Returns true when connected.
    fn try_reconnect(&mut self, deadline: Instant) -> bool {
        let Conn::Down {
            since,
            next_try,
            attempts,
        } = self.conn
        else {
            return true;
        };
        let now = Instant::now();
        if now < next_try {
            std::thread::sleep(next_try.min(deadline).saturating_duration_since(now));
            if Instant::now() < next_try {
                return false;
            }
        }
        let attempt = attempts + 1;
        match self.connect() {
            Ok(conn) => {
                self.conn = conn;
                if self.ever_connected {
                    self.live.reconnects += 1;
                    self.emit_connected(attempt, since.elapsed());
                } else {
                    self.emit_connected(0, Duration::ZERO);
                }
                true
            }
            Err(e) => {
                self.live.failed_attempts += 1;
                let backoff = self.backoff(attempt);
                self.conn = Conn::Down {
                    since,
                    next_try: Instant::now() + backoff,
                    attempts: attempt,
                };
                let reason = e.to_string();
                (self.events)(&LiveEvent::RetryFailed {
                    iface: &self.cfg.iface,
                    attempt,
                    reason: &reason,
                    retry_in: backoff,
                });
                false
            }
        }
    }

    /// Reads every queued record of the open socket (up to [`BATCH`]) into the batch, waiting
    /// at most until `deadline` for the first. While the bus is busy, reads are at least
    /// [`LiveConfig::read_interval`] apart (unless the last one filled the batch). Returns with
    /// an empty batch on timeout, on a signal, or while that interval has not passed.
    fn fill(&mut self, deadline: Instant) -> io::Result<()> {
        let Conn::Up {
            sock,
            drops_seen,
            kernel_ts,
        } = &self.conn
        else {
            return Ok(());
        };
        let (fd, seen) = (sock.as_raw_fd(), *drops_seen);
        self.rx_kernel_ts = *kernel_ts;
        if let (Some(last), false) = (self.last_read, self.last_full) {
            let next = last + self.cfg.read_interval;
            let now = Instant::now();
            if now < next {
                std::thread::sleep(next.min(deadline) - now);
                if Instant::now() < next {
                    return Ok(());
                }
            }
        }
        let n = match self.rx.fill(fd) {
            Ok(n) => n,
            Err(Errno::EAGAIN) | Err(Errno::EINTR) => {
                let wait = deadline.saturating_duration_since(Instant::now());
                let mut fds = [PollFd::new(sock.as_fd(), PollFlags::POLLIN)];
                let timeout = PollTimeout::try_from(wait).unwrap_or(PollTimeout::MAX);
                match poll(&mut fds, timeout) {
                    Ok(0) | Err(Errno::EINTR) => return Ok(()),
                    Ok(_) => {}
                    Err(e) => return Err(e.into()),
                }
                match self.rx.fill(fd) {
                    Ok(n) => n,
                    Err(Errno::EAGAIN) | Err(Errno::EINTR) => return Ok(()),
                    Err(e) => return Err(e.into()),
                }
            }
            Err(e) => return Err(e.into()),
        };
        self.last_read = Some(Instant::now());
        self.last_full = n == BATCH;
        // The drop count is cumulative since the socket opened (wraps at u32) and travels with
        // the frames the kernel does queue: the batch's last one has the newest.
        if let Some(d) = self.rx.last_drops() {
            self.stats.dropped += d.wrapping_sub(seen) as u64;
            if let Conn::Up { drops_seen, .. } = &mut self.conn {
                *drops_seen = d;
            }
        }
        Ok(())
    }

    /// The next frame of the batch already read; malformed records are skipped and counted.
    fn next_read(&mut self) -> Option<Frame> {
        loop {
            let (record, meta) = self.rx.pop()?;
            let parsed = if meta.truncated || meta.bytes > CANFD_MTU {
                Err(format!(
                    "record of {} bytes is larger than a CAN FD frame",
                    meta.bytes
                ))
            } else {
                frame_from_kernel(record, 0, self.iface)
                    .map_err(|reason| format!("{reason} ({} bytes)", meta.bytes))
            };
            let mut f = match parsed {
                Ok(f) => f,
                Err(reason) => {
                    self.skip(reason);
                    continue;
                }
            };
            f.t_ns = match meta.t_ns {
                Some(t) if self.rx_kernel_ts => t,
                _ => {
                    self.live.clock_timestamps += 1;
                    self.report_clock_ts(if self.rx_kernel_ts {
                        "a frame arrived without SO_TIMESTAMPNS"
                    } else {
                        "SO_TIMESTAMPNS not enabled"
                    });
                    clock_ns()
                }
            };
            return Some(f);
        }
    }

    fn skip(&mut self, reason: String) {
        self.stats.malformed += 1;
        if self.skips.len() < MAX_SKIPS {
            self.skips.push(Skip {
                location: self.cfg.iface.clone(),
                reason,
            });
        }
    }
}

impl CanSource for LiveSource {
    /// The next frame, blocking at most [`LiveConfig::read_timeout`]: `Err(TimedOut)` when none
    /// came (also while reconnecting), `Ok(None)` once the stop flag is set (after the frames
    /// already read from the socket). Socket failures are not returned: they trigger a
    /// reconnect (see the module docs).
    fn next_frame(&mut self) -> io::Result<Option<Frame>> {
        let deadline = Instant::now() + self.cfg.read_timeout;
        loop {
            if let Some(f) = self.next_read() {
                self.stats.frames += 1;
                if f.kind == FrameKind::Error {
                    self.stats.error_frames += 1;
                    if f.id & CAN_ERR_RESTARTED != 0 {
                        self.live.restarted += 1;
                    }
                    if f.id & CAN_ERR_BUSOFF != 0 {
                        self.live.bus_off += 1;
                        if self.cfg.reconnect_on_bus_off {
                            self.disconnect("bus-off error frame");
                        }
                    }
                }
                return Ok(Some(f));
            }
            if self.stop.load(Ordering::Relaxed) {
                return Ok(None);
            }
            if !self.is_connected() && !self.try_reconnect(deadline) {
                if Instant::now() >= deadline {
                    self.live.timeouts += 1;
                    return Err(io::ErrorKind::TimedOut.into());
                }
                continue;
            }
            if let Err(e) = self.fill(deadline) {
                self.disconnect(&e.to_string());
            }
            if self.rx.pending() == 0 && Instant::now() >= deadline {
                self.live.timeouts += 1;
                return Err(io::ErrorKind::TimedOut.into());
            }
        }
    }

    fn stats(&self) -> SourceStats {
        self.stats.clone()
    }

    fn take_skips(&mut self) -> Vec<Skip> {
        std::mem::take(&mut self.skips)
    }
}

fn annotate(iface: &str, e: io::Error) -> io::Error {
    io::Error::new(e.kind(), format!("SocketCAN interface {iface}: {e}"))
}

fn clock_ns() -> i64 {
    SystemTime::now()
        .duration_since(SystemTime::UNIX_EPOCH)
        .map(|d| d.as_nanos() as i64)
        .unwrap_or(0)
}

/// `Some(up)` from `/sys/class/net/<iface>/flags` (IFF_UP), `None` when sysfs cannot say.
fn iface_is_up(iface: &str) -> Option<bool> {
    let text = std::fs::read_to_string(format!("/sys/class/net/{iface}/flags")).ok()?;
    let flags = u32::from_str_radix(text.trim().trim_start_matches("0x"), 16).ok()?;
    Some(flags & 1 != 0)
}

/// Decode one record as the kernel delivers it on a raw CAN socket (linux/can.h):
/// `struct can_frame` (16 bytes: `can_id` u32 in host order, `len`, pad, reserved,
/// `len8_dlc`, 8 data bytes) or `struct canfd_frame` (72 bytes: `can_id`, `len`, `flags`
/// with BRS/ESI, two reserved bytes, 64 data bytes). Pure function; the error says what is
/// wrong.
pub fn frame_from_kernel(buf: &[u8], t_ns: i64, iface: IfaceName) -> Result<Frame, &'static str> {
    let fd = match buf.len() {
        CAN_MTU => false,
        CANFD_MTU => true,
        _ => return Err("record is neither a CAN (16 bytes) nor a CAN FD (72 bytes) frame"),
    };
    let can_id = u32::from_ne_bytes([buf[0], buf[1], buf[2], buf[3]]);
    let len = buf[4] as usize;
    let mut f = Frame::empty(t_ns);
    f.iface = iface;
    if can_id & CAN_ERR_FLAG != 0 {
        f.kind = FrameKind::Error;
        f.id = can_id & CAN_ERR_MASK;
        f.len = 8;
        f.dlc = 8;
        f.data[..8].copy_from_slice(&buf[8..16]);
        return Ok(f);
    }
    f.extended = can_id & CAN_EFF_FLAG != 0;
    f.id = if f.extended {
        can_id & CAN_EFF_MASK
    } else {
        can_id & CAN_SFF_MASK
    };
    if fd {
        if len > MAX_DATA {
            return Err("CAN FD length above 64");
        }
        let flags = buf[5] as u32;
        f.fd = true;
        f.brs = flags & ::socketcan::id::CANFD_BRS as u32 != 0;
        f.esi = flags & ::socketcan::id::CANFD_ESI as u32 != 0;
        f.len = len as u8;
        f.dlc = fd_len_to_dlc(len);
        f.data[..len].copy_from_slice(&buf[8..8 + len]);
        return Ok(f);
    }
    if len > 8 {
        return Err("classic CAN length above 8");
    }
    f.len = len as u8;
    f.dlc = len as u8;
    let len8_dlc = buf[7];
    if len == 8 && (9..=15).contains(&len8_dlc) {
        f.dlc = len8_dlc;
    }
    if can_id & CAN_RTR_FLAG != 0 {
        f.kind = FrameKind::Remote;
    } else {
        f.data[..len].copy_from_slice(&buf[8..8 + len]);
    }
    Ok(f)
}

/// Sends frames on a SocketCAN interface. Separate from [`LiveSource`] on purpose: the monitor
/// reads only; a sender exists only where a test or the simulator opens one.
pub struct LiveSink {
    sock: CanFdSocket,
    iface: String,
    sent: u64,
}

impl LiveSink {
    /// Open `iface` for sending classic and FD frames. Other sockets on this host see the
    /// frames (kernel loopback, the default); this socket does not receive them back.
    pub fn open(iface: &str) -> io::Result<LiveSink> {
        let sock = CanFdSocket::open(iface).map_err(|e| annotate(iface, e))?;
        // Never read from this socket: let the kernel discard anything addressed to it.
        sock.set_filter_drop_all()?;
        Ok(LiveSink {
            sock,
            iface: iface.to_string(),
            sent: 0,
        })
    }

    /// Send one frame (data, remote, FD with BRS/ESI, or an error frame for tests). Waits and
    /// retries for up to one second while the kernel reports a full transmit queue
    /// (`ENOBUFS`). A classic raw DLC of 9–15 is sent as DLC 8 (the `socketcan` crate does not
    /// expose `len8_dlc`).
    pub fn send(&mut self, f: &Frame) -> io::Result<()> {
        let invalid = |what: &str| {
            io::Error::new(
                io::ErrorKind::InvalidInput,
                format!("cannot send {what}: id {:#x} len {}", f.id, f.len),
            )
        };
        let id: Id = if f.extended {
            ExtendedId::new(f.id)
                .ok_or_else(|| invalid("extended ID above 29 bits"))?
                .into()
        } else {
            StandardId::new(f.id as u16)
                .filter(|_| f.id <= CAN_SFF_MASK)
                .ok_or_else(|| invalid("standard ID above 11 bits"))?
                .into()
        };
        let started = Instant::now();
        loop {
            let r = match f.kind {
                FrameKind::Error => {
                    let fr = CanErrorFrame::new_error(f.id, &f.data[..8])
                        .map_err(|_| invalid("error frame"))?;
                    self.sock.write_frame(&fr)
                }
                FrameKind::Remote => {
                    let fr = CanRemoteFrame::new_remote(id, f.len.min(8) as usize)
                        .ok_or_else(|| invalid("remote frame"))?;
                    self.sock.write_frame(&fr)
                }
                FrameKind::Data if f.fd => {
                    let mut flags = ::socketcan::id::FdFlags::empty();
                    flags.set(::socketcan::id::FdFlags::BRS, f.brs);
                    flags.set(::socketcan::id::FdFlags::ESI, f.esi);
                    let fr = CanFdFrame::with_flags(id, f.payload(), flags)
                        .ok_or_else(|| invalid("CAN FD frame"))?;
                    self.sock.write_frame(&fr)
                }
                FrameKind::Data => {
                    let fr = CanDataFrame::new(id, f.payload())
                        .ok_or_else(|| invalid("classic frame longer than 8 bytes"))?;
                    self.sock.write_frame(&fr)
                }
            };
            match r {
                Ok(()) => {
                    self.sent += 1;
                    return Ok(());
                }
                Err(e)
                    if e.raw_os_error() == Some(nix::libc::ENOBUFS)
                        && started.elapsed() < Duration::from_secs(1) =>
                {
                    std::thread::sleep(Duration::from_micros(200));
                }
                Err(e) => return Err(annotate(&self.iface, e)),
            }
        }
    }

    /// Frames sent so far.
    pub fn sent(&self) -> u64 {
        self.sent
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn classic_record(can_id: u32, len: u8, len8_dlc: u8, data: &[u8]) -> [u8; CAN_MTU] {
        let mut b = [0u8; CAN_MTU];
        b[..4].copy_from_slice(&can_id.to_ne_bytes());
        b[4] = len;
        b[7] = len8_dlc;
        b[8..8 + data.len()].copy_from_slice(data);
        b
    }

    #[test]
    fn decodes_classic_standard_and_extended() {
        let name = IfaceName::from_str_truncated("vcan0");
        let f = frame_from_kernel(&classic_record(0x123, 3, 0, &[1, 2, 3]), 7, name).unwrap();
        assert_eq!(
            (f.id, f.extended, f.kind, f.fd),
            (0x123, false, FrameKind::Data, false)
        );
        assert_eq!(f.payload(), &[1, 2, 3]);
        assert_eq!((f.t_ns, f.iface.as_str()), (7, "vcan0"));

        let f = frame_from_kernel(
            &classic_record(0x1abc_def0 | CAN_EFF_FLAG, 8, 0, &[9; 8]),
            0,
            name,
        )
        .unwrap();
        assert_eq!((f.id, f.extended, f.len, f.dlc), (0x1abc_def0, true, 8, 8));
    }

    #[test]
    fn decodes_remote_error_and_raw_dlc() {
        let name = IfaceName::new();
        let f =
            frame_from_kernel(&classic_record(0x7ff | CAN_RTR_FLAG, 4, 0, &[]), 0, name).unwrap();
        assert_eq!((f.kind, f.id, f.len), (FrameKind::Remote, 0x7ff, 4));
        assert_eq!(f.payload(), &[0; 4]);

        let f = frame_from_kernel(
            &classic_record(
                CAN_ERR_FLAG | CAN_ERR_BUSOFF,
                8,
                0,
                &[0, 0, 0, 0, 0, 0, 1, 2],
            ),
            0,
            name,
        )
        .unwrap();
        assert_eq!((f.kind, f.id, f.len), (FrameKind::Error, CAN_ERR_BUSOFF, 8));
        assert_eq!(&f.payload()[6..], &[1, 2]);

        let f = frame_from_kernel(&classic_record(0x10, 8, 13, &[0; 8]), 0, name).unwrap();
        assert_eq!((f.len, f.dlc), (8, 13));
    }

    #[test]
    fn decodes_fd_with_flags() {
        let mut b = [0u8; CANFD_MTU];
        b[..4].copy_from_slice(&(0x1234_5678u32 | CAN_EFF_FLAG).to_ne_bytes());
        b[4] = 48;
        b[5] = (::socketcan::id::CANFD_BRS | ::socketcan::id::CANFD_FDF) as u8;
        for (i, x) in b[8..56].iter_mut().enumerate() {
            *x = i as u8;
        }
        let f = frame_from_kernel(&b, 0, IfaceName::new()).unwrap();
        assert!(f.fd && f.brs && !f.esi && f.extended);
        assert_eq!((f.id, f.len, f.dlc), (0x1234_5678, 48, 14));
        assert_eq!(f.payload()[47], 47);
    }

    #[test]
    fn rejects_bad_records() {
        let name = IfaceName::new();
        assert!(frame_from_kernel(&[0u8; 10], 0, name).is_err());
        assert!(frame_from_kernel(&classic_record(0x1, 9, 0, &[]), 0, name).is_err());
        let mut b = [0u8; CANFD_MTU];
        b[4] = 65;
        assert!(frame_from_kernel(&b, 0, name).is_err());
    }

    #[test]
    fn filter_separates_standard_from_extended() {
        let s = FilterId::standard(0x123).kernel_filter();
        let e = FilterId::extended(0x123).kernel_filter();
        let raw = |f: CanFilter| {
            let r: &nix::libc::can_filter = f.as_ref();
            (r.can_id, r.can_mask)
        };
        assert_eq!(raw(s), (0x123, CAN_SFF_MASK | CAN_EFF_FLAG));
        assert_eq!(raw(e), (0x123 | CAN_EFF_FLAG, CAN_EFF_MASK | CAN_EFF_FLAG));
    }

    #[test]
    fn too_many_filters_is_a_clear_error() {
        let mut cfg = LiveConfig::new("vcan0");
        cfg.ids = Some((0..600).map(FilterId::standard).collect());
        let err = LiveSource::open(cfg).err().unwrap();
        assert!(err.to_string().contains("at most 512"), "{err}");
    }

    #[test]
    fn backoff_doubles_up_to_the_cap() {
        let mut cfg = LiveConfig::new("vcan0");
        cfg.backoff_initial = Duration::from_millis(100);
        cfg.backoff_max = Duration::from_secs(1);
        let s = LiveSource::open_waiting(cfg).unwrap();
        let ms: Vec<u128> = [0, 1, 2, 3, 4, 40]
            .iter()
            .map(|&n| s.backoff(n).as_millis())
            .collect();
        assert_eq!(ms, [100, 200, 400, 800, 1000, 1000]);
    }

    #[test]
    fn waiting_source_retries_reports_and_times_out() {
        let mut cfg = LiveConfig::new("nosuchcan9");
        cfg.read_timeout = Duration::from_millis(60);
        cfg.backoff_initial = Duration::from_millis(5);
        cfg.backoff_max = Duration::from_millis(20);
        let mut s = LiveSource::open_waiting(cfg).unwrap();
        let log = Arc::new(std::sync::Mutex::new(Vec::new()));
        let log2 = log.clone();
        s.on_event(move |e| log2.lock().unwrap().push(e.to_string()));
        let t = Instant::now();
        let e = s.next_frame().unwrap_err();
        assert_eq!(e.kind(), io::ErrorKind::TimedOut);
        assert!(t.elapsed() < Duration::from_secs(1));
        assert!(!s.is_connected());
        let st = s.live_stats();
        assert!(st.failed_attempts >= 2, "{st:?}");
        assert_eq!((st.timeouts, st.reconnects), (1, 0));
        let log = log.lock().unwrap();
        assert!(
            log[0].contains("nosuchcan9: reconnect attempt 1 failed"),
            "{log:?}"
        );
        s.stop_handle().store(true, Ordering::Relaxed);
        assert!(s.next_frame().unwrap().is_none());
    }

    #[test]
    fn missing_interface_names_it() {
        let err = LiveSource::open(LiveConfig::new("nosuchcan9"))
            .err()
            .unwrap();
        assert!(err.to_string().contains("nosuchcan9"), "{err}");
    }
}
