//! The CAN frame as every stage sees it: classic CAN (11/29-bit ID, RTR, DLC 0–8, and the raw
//! DLC codes 9–15 a classic controller may send), CAN FD (up to 64 bytes, BRS/ESI) and error
//! frames, each with a receive timestamp in nanoseconds and the name of its interface.
//!
//! A `Frame` is a fixed-size `Copy` value (no heap): it can be passed through the hot path
//! without allocation.

/// Largest payload (CAN FD).
pub const MAX_DATA: usize = 64;

/// Interface name (`can0`, `vcan0`, ...), stored inline: Linux limits these to 15 bytes.
#[derive(Clone, Copy, PartialEq, Eq, Hash, Default)]
pub struct IfaceName {
    buf: [u8; 15],
    len: u8,
}

/// The interface names `can0`..`can15` of log channels 1..16 (the number logs count from),
/// made once so a frame's name costs no formatting; higher channels are named on demand.
#[derive(Clone, Copy, Debug)]
pub(crate) struct ChannelNames([IfaceName; 16]);

impl ChannelNames {
    pub(crate) fn new() -> ChannelNames {
        let mut n = [IfaceName::new(); 16];
        for (i, x) in n.iter_mut().enumerate() {
            *x = IfaceName::from_str_truncated(&format!("can{i}"));
        }
        ChannelNames(n)
    }

    /// The name of channel `ch` (1-based): `can{ch-1}`; channel 0 is `can0` too.
    pub(crate) fn get(&self, ch: u32) -> IfaceName {
        let i = ch.saturating_sub(1) as usize;
        match self.0.get(i) {
            Some(n) => *n,
            None => IfaceName::from_str_truncated(&format!("can{i}")),
        }
    }
}

impl IfaceName {
    /// An empty name.
    pub const fn new() -> IfaceName {
        IfaceName {
            buf: [0; 15],
            len: 0,
        }
    }

    /// The name, truncated at a character boundary to at most 15 bytes.
    pub fn from_str_truncated(name: &str) -> IfaceName {
        let mut n = IfaceName::new();
        for ch in name.chars() {
            let w = ch.len_utf8();
            if n.len as usize + w > 15 {
                break;
            }
            ch.encode_utf8(&mut n.buf[n.len as usize..]);
            n.len += w as u8;
        }
        n
    }

    /// The name from raw bytes, if they are valid UTF-8 of at most 15 bytes (no truncation:
    /// log parsers use this to reject an over-long name rather than silently shorten it).
    pub fn from_bytes(name: &[u8]) -> Option<IfaceName> {
        if name.len() > 15 {
            return None;
        }
        std::str::from_utf8(name).ok()?;
        let mut n = IfaceName::new();
        n.buf[..name.len()].copy_from_slice(name);
        n.len = name.len() as u8;
        Some(n)
    }

    pub fn as_bytes(&self) -> &[u8] {
        &self.buf[..self.len as usize]
    }

    pub fn as_str(&self) -> &str {
        // Only ever filled from whole UTF-8 characters.
        std::str::from_utf8(&self.buf[..self.len as usize]).unwrap_or("")
    }

    pub fn len(&self) -> usize {
        self.len as usize
    }

    pub fn is_empty(&self) -> bool {
        self.len == 0
    }
}

impl std::fmt::Debug for IfaceName {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(f, "{:?}", self.as_str())
    }
}

impl std::fmt::Display for IfaceName {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(self.as_str())
    }
}

/// What one line of a text log (Vector ASC, PEAK TRC) holds.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum TextLine {
    Frame(Frame),
    /// A header, comment, block marker or empty line: no event.
    Header,
    /// A timestamped event that is not a CAN frame (bus status, statistics, error counters,
    /// J1939TP, ...): counted as skipped by the reader.
    OtherEvent,
}

/// What kind of frame this is.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub enum FrameKind {
    /// A data frame (classic or FD).
    Data,
    /// A remote transmission request (classic only). `len` holds the requested length.
    Remote,
    /// An error frame: `id` holds the SocketCAN error class bits (without the 0x20000000 flag)
    /// and `data` the 8 error detail bytes.
    Error,
}

/// One received or logged CAN frame.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Frame {
    /// Timestamp in nanoseconds (Unix epoch for live frames; whatever the log says for logs).
    pub t_ns: i64,
    /// Arbitration ID (11 or 29 bits), or error class bits for error frames.
    pub id: u32,
    /// 29-bit extended ID.
    pub extended: bool,
    pub kind: FrameKind,
    /// CAN FD frame.
    pub fd: bool,
    /// CAN FD bit-rate switch.
    pub brs: bool,
    /// CAN FD error state indicator.
    pub esi: bool,
    /// Classic CAN raw DLC code when it differs from `len` (9–15 with 8 data bytes); else `len`.
    pub dlc: u8,
    /// Number of valid bytes in `data` (0–8 classic, 0–64 FD).
    pub len: u8,
    pub data: [u8; MAX_DATA],
    pub iface: IfaceName,
}

impl Frame {
    /// A classic data frame; `data` longer than 8 bytes is an error (returns `None`).
    pub fn classic(t_ns: i64, id: u32, extended: bool, data: &[u8]) -> Option<Frame> {
        if data.len() > 8 {
            return None;
        }
        let mut f = Frame::empty(t_ns);
        f.id = id;
        f.extended = extended;
        f.len = data.len() as u8;
        f.dlc = f.len;
        f.data[..data.len()].copy_from_slice(data);
        Some(f)
    }

    /// A CAN FD data frame; `data` longer than 64 bytes is an error (returns `None`).
    pub fn fd(t_ns: i64, id: u32, extended: bool, data: &[u8]) -> Option<Frame> {
        if data.len() > MAX_DATA {
            return None;
        }
        let mut f = Frame::classic(t_ns, id, extended, &[])?;
        f.fd = true;
        f.len = data.len() as u8;
        f.dlc = fd_len_to_dlc(data.len());
        f.data[..data.len()].copy_from_slice(data);
        Some(f)
    }

    /// An all-zero classic data frame with ID 0 at `t_ns`.
    pub fn empty(t_ns: i64) -> Frame {
        Frame {
            t_ns,
            id: 0,
            extended: false,
            kind: FrameKind::Data,
            fd: false,
            brs: false,
            esi: false,
            dlc: 0,
            len: 0,
            data: [0; MAX_DATA],
            iface: IfaceName::new(),
        }
    }

    /// The valid payload bytes.
    pub fn payload(&self) -> &[u8] {
        &self.data[..self.len as usize]
    }

    /// Timestamp in seconds.
    pub fn t_s(&self) -> f64 {
        self.t_ns as f64 * 1e-9
    }

    /// Set the interface name, truncating to 15 bytes (the Linux limit).
    pub fn set_iface(&mut self, name: &str) {
        self.iface = IfaceName::from_str_truncated(name);
    }
}

/// CAN FD DLC code for a payload length (rounds up to the next valid FD length).
pub fn fd_len_to_dlc(len: usize) -> u8 {
    match len {
        0..=8 => len as u8,
        9..=12 => 9,
        13..=16 => 10,
        17..=20 => 11,
        21..=24 => 12,
        25..=32 => 13,
        33..=48 => 14,
        _ => 15,
    }
}

/// Payload length for a CAN FD DLC code (codes above 15 are treated as 15).
pub fn fd_dlc_to_len(dlc: u8) -> usize {
    const T: [usize; 16] = [0, 1, 2, 3, 4, 5, 6, 7, 8, 12, 16, 20, 24, 32, 48, 64];
    T[(dlc as usize).min(15)]
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn fd_dlc_round_trip() {
        for dlc in 0..16u8 {
            assert_eq!(fd_len_to_dlc(fd_dlc_to_len(dlc)), dlc);
        }
        assert_eq!(fd_len_to_dlc(9), 9);
        assert_eq!(fd_dlc_to_len(9), 12);
    }

    #[test]
    fn classic_rejects_long_payload() {
        assert!(Frame::classic(0, 0x123, false, &[0; 9]).is_none());
        let f = Frame::classic(5, 0x123, false, &[1, 2, 3]).unwrap();
        assert_eq!(f.payload(), &[1, 2, 3]);
    }

    #[test]
    fn iface_truncates_to_linux_limit() {
        let mut f = Frame::empty(0);
        f.set_iface("a_very_long_interface_name");
        assert_eq!(f.iface.len(), 15);
    }
}
