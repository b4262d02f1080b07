//! DBC files: tolerant loading (statement by statement through `can-dbc`, see [`load`]) and
//! decoding of signals from frame payloads with our own bit extraction ([`bits`]), matching
//! cantools' conventions (start bits, multiplexing, unknown multiplexer values).
//!
//! Not here: which signal means what for the monitor (that is [`crate::signals`]), nor reading
//! frames (that is [`crate::source`]). Decoding a frame allocates nothing: look the message up
//! with [`Database::message_index`], then call [`Message::decode`] with a callback.
//!
//! ```
//! let text = "BO_ 291 STEER: 2 EPS\n SG_ ANGLE : 0|16@1- (0.1,0) [-3276.8|3276.7] \"deg\" X\n";
//! let (db, report) = shimmy::dbc::Database::parse(text);
//! assert!(report.skipped.is_empty());
//! let m = &db.messages()[db.message_index(0x123, false).unwrap()];
//! let phys = m.signals[0].phys(&[0x0A, 0x00]).unwrap();
//! assert!((phys - 1.0).abs() < 1e-12);
//! ```

pub mod bits;
pub mod load;
pub mod message;
pub mod signal;

pub use bits::{ByteOrder, Layout};
pub use load::{LoadReport, ReportItem};
pub use message::{DecodeError, DecodeSummary, Message};
pub use signal::{EncodeError, MuxCondition, RawValue, Signal, ValueKind};

use std::path::Path;

use anyhow::Context as _;

/// Sentinel in the standard-ID table.
const NONE: u16 = u16::MAX;

/// A loaded DBC: messages with their signals, and lookup tables.
#[derive(Clone, Debug, Default)]
pub struct Database {
    messages: Vec<Message>,
    /// Standard IDs 0..=0x7FF → message index (dense, one load per lookup).
    std_index: Vec<u16>,
    /// Other (extended, or out-of-range standard) keys `(id | ext << 31)` → index, sorted.
    other_index: Vec<(u32, u32)>,
    /// `BU_` node names.
    pub nodes: Vec<String>,
    /// `VERSION` string.
    pub version: String,
    /// Bus comment (`CM_ "…"`).
    pub comment: Option<String>,
    /// Global value tables (`VAL_TABLE_`).
    pub value_tables: Vec<(String, Vec<(i64, String)>)>,
}

impl Database {
    /// Parse DBC text tolerantly: never fails as a whole; what could not be used is in the
    /// report.
    pub fn parse(text: &str) -> (Database, LoadReport) {
        load::parse(text)
    }

    /// Read and parse a DBC file. UTF-8 is tried first; otherwise the text is read as
    /// Windows-1252 (common for DBC files written by Vector tools).
    pub fn load(path: impl AsRef<Path>) -> anyhow::Result<(Database, LoadReport)> {
        let path = path.as_ref();
        let bytes =
            std::fs::read(path).with_context(|| format!("reading DBC {}", path.display()))?;
        let (db, mut report, enc) = match std::str::from_utf8(&bytes) {
            Ok(text) => {
                let (db, r) = Database::parse(text);
                (db, r, "utf-8")
            }
            Err(_) => {
                let (text, _, _) = can_dbc::encodings::WINDOWS_1252.decode(&bytes);
                let (db, r) = Database::parse(&text);
                (db, r, "windows-1252")
            }
        };
        report.encoding = enc.to_string();
        Ok((db, report))
    }

    /// Build a database from messages made in code; finishes each message (multiplexer
    /// bookkeeping) and builds the index. Fails when a message's multiplexing is cyclic.
    pub fn from_messages(mut messages: Vec<Message>) -> Result<Database, String> {
        for m in &mut messages {
            m.finish()?;
        }
        let mut db = Database {
            messages,
            ..Database::default()
        };
        db.build_index();
        Ok(db)
    }

    pub(crate) fn build_index(&mut self) {
        self.std_index = vec![NONE; 0x800];
        self.other_index.clear();
        for (i, m) in self.messages.iter().enumerate() {
            if !m.extended && m.id < 0x800 && i < NONE as usize {
                if self.std_index[m.id as usize] == NONE {
                    self.std_index[m.id as usize] = i as u16;
                }
            } else {
                self.other_index
                    .push((m.id | (m.extended as u32) << 31, i as u32));
            }
        }
        self.other_index.sort_unstable();
        self.other_index.dedup_by_key(|e| e.0);
    }

    /// All messages, in file order.
    pub fn messages(&self) -> &[Message] {
        &self.messages
    }

    /// Index of the message with this ID (no allocation, O(1) for standard IDs).
    #[inline]
    pub fn message_index(&self, id: u32, extended: bool) -> Option<usize> {
        if !extended && id < 0x800 {
            if let Some(&i) = self.std_index.get(id as usize) {
                if i != NONE {
                    return Some(i as usize);
                }
                if self.messages.len() < NONE as usize {
                    return None;
                }
            }
        }
        let key = id | (extended as u32) << 31;
        self.other_index
            .binary_search_by_key(&key, |e| e.0)
            .ok()
            .map(|k| self.other_index[k].1 as usize)
    }

    /// The message with this ID.
    #[inline]
    pub fn message(&self, id: u32, extended: bool) -> Option<&Message> {
        self.message_index(id, extended).map(|i| &self.messages[i])
    }

    /// Index of a message by name.
    pub fn message_by_name(&self, name: &str) -> Option<usize> {
        self.messages.iter().position(|m| m.name == name)
    }
}
