//! ASAM MDF 4 (`.mf4`) bus logging files: CAN frames stored the way CANedge loggers, Vector
//! tools, asammdf and python-can store them (ASAM MDF 4.1 "bus logging": channel groups with a
//! `CAN_DataFrame`, `CAN_RemoteFrame` or `CAN_ErrorFrame` structure channel whose members are
//! `BusChannel`, `ID`, `IDE`, `DLC`, `DataLength`, `DataBytes`, `EDL`, `BRS`, `ESI`, `Dir`).
//!
//! [`read::Mf4Reader`] streams the frames out of a file ([`read`] says exactly which block and
//! channel layouts it understands); [`write::Mf4Writer`] writes them, sorted or unsorted, plain
//! or deflate-compressed. Both follow the block layouts of the public MDF 4.11 structure (as
//! documented by asammdf and python-can); no code was copied.
//!
//! Mapping between [`Frame`](super::Frame) and the bus logging channels:
//! - `BusChannel` N ≥ 1 is interface `can{N-1}` (as for ASC and BLF); 0, which python-can
//!   writes for `can0`, is also `can0`. A value-to-text conversion on `BusChannel` (what
//!   [`write::Mf4Writer`] writes) names the interface instead, so any name survives;
//! - times are the header's start time (ns since the Unix epoch, as the file states it) plus
//!   the master channel's seconds, rounded to the nanosecond;
//! - an error frame becomes [`FrameKind::Error`](super::FrameKind) whose class is the `ID`
//!   member when the group has one (what the writer stores) and `CAN_ERR_PROT` otherwise (a
//!   logger's `ErrorType` has no SocketCAN equivalent), with `DataBytes` as detail bytes;
//! - `Dir` (Rx/Tx) is not kept: a [`Frame`](super::Frame) has no direction.
//!
//! Not here: counting or reporting what was skipped ([`crate::source::log`]).

pub mod read;
pub mod write;

pub use read::{Mf4Error, Mf4Reader, Mf4Step};
pub use write::{Mf4Compression, Mf4Layout, Mf4Writer, Mf4WriterOptions};

/// File identification of a finalized file.
pub const ID_FINALIZED: &[u8; 8] = b"MDF     ";
/// File identification of an unfinalized file (a logger still writing, or cut by a power loss).
pub const ID_UNFINALIZED: &[u8; 8] = b"UnFinMF ";

/// Unfinalized flag: cycle counters of channel groups not updated.
pub const UNFIN_CG_COUNTERS: u16 = 1;
/// Unfinalized flag: length of the last DT block not updated.
pub const UNFIN_LAST_DT_LENGTH: u16 = 1 << 2;
/// Unfinalized flag: the last data list's link count not updated.
pub const UNFIN_LAST_DL: u16 = 1 << 4;
/// Unfinalized flag: `cg_data_bytes` of VLSD channel groups not updated.
pub const UNFIN_VLSD_BYTES: u16 = 1 << 5;

/// True when `head` (the first bytes of a file) is an MDF 4 identification block.
pub fn is_mdf4(head: &[u8]) -> bool {
    head.len() >= 8 && (&head[..8] == ID_FINALIZED || &head[..8] == ID_UNFINALIZED)
}
