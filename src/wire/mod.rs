//! Wire formats: the CAN frame value type and the log file formats (candump -L, Vector ASC and
//! BLF, ASAM MDF 4; parse and emit; PEAK TRC, parse only). No policy:
//! nothing here decides what to do with a bad line beyond describing what is wrong with it.

pub mod asc;
pub mod blf;
pub mod candump;
pub mod frame;
pub mod mf4;
pub mod trc;

pub use frame::{Frame, FrameKind, IfaceName, MAX_DATA};
