//! Tolerant DBC loading. `can-dbc` parses a whole file or fails on its first bad statement; real
//! DBC files have quirks, so this module first splits the text into statements (a `BO_` header
//! with its `SG_` lines, a `CM_`, a `VAL_`, …), hands each statement to `can-dbc` on its own,
//! and, when a `BO_` block fails, retries its header and each `SG_` line separately. Whatever
//! cannot be used is recorded in the [`LoadReport`] with its line number and reason; the rest
//! of the file loads.
//!
//! Statements the decoder does not need (attribute definitions, environment variables, signal
//! groups, …) are counted by keyword but not parsed. Not here: bit extraction and decoding.

use std::collections::{BTreeMap, HashMap};

use can_dbc::{ByteOrder as CdByteOrder, MessageId, MultiplexIndicator, NumericValue, ValueType};

use super::bits::ByteOrder;
use super::message::Message;
use super::signal::{MuxCondition, Signal, ValueKind};
use super::Database;

/// Something in the DBC text that was not loaded (or loaded with a caveat).
#[derive(Clone, Debug, PartialEq, Eq, serde::Serialize)]
pub struct ReportItem {
    /// 1-based line in the DBC text.
    pub line: usize,
    /// What the item is, e.g. `SG_ STEER_ANGLE` or `VAL_ 1234 FOO`.
    pub item: String,
    pub reason: String,
}

/// What loading a DBC did.
#[derive(Clone, Debug, Default, PartialEq, Eq, serde::Serialize)]
pub struct LoadReport {
    /// Items dropped: the database does not contain them.
    pub skipped: Vec<ReportItem>,
    /// Items loaded with a caveat (overlapping signals, signals past the declared length, …).
    pub notes: Vec<ReportItem>,
    /// Statements deliberately not parsed because decoding does not use them, by keyword.
    pub ignored: BTreeMap<String, usize>,
    /// Text encoding the file was read with (`utf-8` or `windows-1252`).
    pub encoding: String,
    pub messages: usize,
    pub signals: usize,
}

impl LoadReport {
    fn skip(&mut self, line: usize, item: impl Into<String>, reason: impl Into<String>) {
        self.skipped.push(ReportItem {
            line,
            item: item.into(),
            reason: reason.into(),
        });
    }

    fn note(&mut self, line: usize, item: impl Into<String>, reason: impl Into<String>) {
        self.notes.push(ReportItem {
            line,
            item: item.into(),
            reason: reason.into(),
        });
    }
}

impl std::fmt::Display for LoadReport {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        writeln!(
            f,
            "loaded {} messages, {} signals ({}); skipped {}, notes {}",
            self.messages,
            self.signals,
            self.encoding,
            self.skipped.len(),
            self.notes.len()
        )?;
        for s in &self.skipped {
            writeln!(f, "  skipped line {}: {}: {}", s.line, s.item, s.reason)?;
        }
        for s in &self.notes {
            writeln!(f, "  note line {}: {}: {}", s.line, s.item, s.reason)?;
        }
        Ok(())
    }
}

/// Keywords that start a top-level statement. `SG_` belongs to the preceding `BO_`.
const KEYWORDS: &[&str] = &[
    "VERSION",
    "NS_",
    "BS_",
    "BU_",
    "BO_",
    "BO_TX_BU_",
    "CM_",
    "BA_DEF_",
    "BA_DEF_DEF_",
    "BA_",
    "BA_DEF_REL_",
    "BA_DEF_DEF_REL_",
    "BA_REL_",
    "BA_DEF_SGTYPE_",
    "BA_SGTYPE_",
    "VAL_",
    "VAL_TABLE_",
    "SIG_GROUP_",
    "SIG_VALTYPE_",
    "SIG_TYPE_REF_",
    "SGTYPE_",
    "SGTYPE_VAL_",
    "SG_MUL_VAL_",
    "EV_",
    "EV_DATA_",
    "ENVVAR_DATA_",
    "CAT_DEF_",
    "CAT_",
    "FILTER",
    "BU_SG_REL_",
    "BU_EV_REL_",
    "BU_BO_REL_",
];

struct Stmt<'a> {
    keyword: &'a str,
    line: usize,
    /// Byte range of the statement (for `BO_`: the header line only).
    start: usize,
    end: usize,
    /// `SG_` lines of a `BO_` block: (line number, byte range).
    sg: Vec<(usize, usize, usize)>,
    /// End of the whole `BO_` block including its `SG_` lines.
    block_end: usize,
}

fn first_token(line: &str) -> &str {
    let t = line.trim_start();
    let end = t
        .find(|c: char| c.is_whitespace() || c == ':')
        .unwrap_or(t.len());
    &t[..end]
}

/// Update the in-string state with the quotes of one line (backslash escapes honoured).
fn scan_quotes(line: &str, mut in_string: bool) -> bool {
    let mut esc = false;
    for b in line.bytes() {
        if in_string {
            if esc {
                esc = false;
            } else if b == b'\\' {
                esc = true;
            } else if b == b'"' {
                in_string = false;
            }
        } else if b == b'"' {
            in_string = true;
        }
    }
    in_string
}

fn split<'a>(text: &'a str, report: &mut LoadReport) -> Vec<Stmt<'a>> {
    let mut out: Vec<Stmt> = Vec::new();
    let mut in_string = false;
    let mut pos = 0usize;
    for (n, line) in text.split_inclusive('\n').enumerate() {
        let lineno = n + 1;
        let start = pos;
        pos += line.len();
        let end = pos;
        if in_string {
            if let Some(cur) = out.last_mut() {
                cur.end = end;
                cur.block_end = end;
            }
            in_string = scan_quotes(line, in_string);
            continue;
        }
        let tok = first_token(line);
        let indented = line.starts_with([' ', '\t']);
        let cur_kw = out.last().map(|s| s.keyword);
        if tok.is_empty() || tok.starts_with("//") {
            // Blank or comment line: belongs to nothing.
        } else if (cur_kw == Some("NS_") || cur_kw == Some("BU_")) && indented && tok != "SG_" {
            let cur = out.last_mut().unwrap();
            cur.end = end;
            cur.block_end = end;
        } else if tok == "SG_" {
            match out.last_mut() {
                Some(cur) if cur.keyword == "BO_" => {
                    cur.sg.push((lineno, start, end));
                    cur.block_end = end;
                }
                _ => report.skip(lineno, "SG_", "signal outside a BO_ message block"),
            }
        } else if let Some(kw) = KEYWORDS.iter().find(|k| **k == tok) {
            out.push(Stmt {
                keyword: kw,
                line: lineno,
                start,
                end,
                sg: Vec::new(),
                block_end: end,
            });
        } else if let Some(cur) = out
            .last_mut()
            .filter(|c| c.keyword != "BO_" && !text[c.start..c.end].trim_end().ends_with(';'))
        {
            // Continuation of a multi-line statement (e.g. a VAL_ spread over lines).
            cur.end = end;
            cur.block_end = end;
        } else {
            report.skip(
                lineno,
                tok.chars().take(40).collect::<String>(),
                "unrecognised statement",
            );
        }
        in_string = scan_quotes(line, in_string);
    }
    out
}

/// A one-line reason from a `can-dbc` error (pest errors are multi-line with a caret); line
/// numbers are shifted to the file's (`base_line` is the file line of the chunk's first line).
fn reason(e: &can_dbc::DbcError, base_line: usize) -> String {
    let full = e.to_string();
    let Some(at) = full.find("--> ") else {
        return full;
    };
    let pos = full[at + 4..].split_whitespace().next().unwrap_or("");
    let mut lc = pos.split(':').map(|x| x.parse::<usize>().unwrap_or(1));
    let (l, c) = (lc.next().unwrap_or(1), lc.next().unwrap_or(1));
    let msg = full
        .lines()
        .rev()
        .find_map(|x| x.trim_start().strip_prefix("= "))
        .unwrap_or("syntax error");
    format!("line {} column {}: {}", base_line + l - 1, c, msg)
}

/// Byte range of the message-ID token of a statement that refers to a message, if any.
fn id_token(chunk: &str, keyword: &str) -> Option<(usize, usize)> {
    let mut i = keyword.len();
    let b = chunk.as_bytes();
    // For CM_ and BA_ the ID follows an object keyword (BO_/SG_); for CM_ it may be bare.
    let needs_object = keyword == "BA_";
    let mut seen_object = !needs_object;
    while i < b.len() {
        while i < b.len() && b[i].is_ascii_whitespace() {
            i += 1;
        }
        if i >= b.len() {
            return None;
        }
        if b[i] == b'"' {
            if keyword == "CM_" {
                return None; // plain bus comment
            }
            i += 1;
            while i < b.len() && b[i] != b'"' {
                i += if b[i] == b'\\' { 2 } else { 1 };
            }
            i += 1;
            continue;
        }
        let start = i;
        while i < b.len() && !b[i].is_ascii_whitespace() && b[i] != b'"' && b[i] != b';' {
            i += 1;
        }
        if i == start {
            // A ';' where a token would start: step over it (a BA_ scan would otherwise spin
            // on it forever; found by the dbc fuzz target).
            i += 1;
            continue;
        }
        let tok = &chunk[start..i];
        if tok == "BO_" || tok == "SG_" {
            seen_object = true;
            continue;
        }
        if seen_object && !tok.is_empty() && tok.bytes().all(|c| c.is_ascii_digit()) {
            return Some((start, i));
        }
        if keyword != "BA_" {
            return None;
        }
    }
    None
}

/// DBC files sometimes give a 29-bit ID without the bit-31 "extended" flag; `can-dbc` would
/// truncate it to 16 bits. Such IDs are rewritten with the flag set (and reported once, for the
/// `BO_`). Returns the text to parse and whether it was rewritten.
fn fix_id<'a>(chunk: &'a str, keyword: &str) -> (std::borrow::Cow<'a, str>, bool) {
    use std::borrow::Cow;
    let Some((a, b)) = id_token(chunk, keyword) else {
        return (Cow::Borrowed(chunk), false);
    };
    match chunk[a..b].parse::<u64>() {
        Ok(v) if v > 0x7FF && v < (1 << 29) => {
            let mut s = String::with_capacity(chunk.len() + 4);
            s.push_str(&chunk[..a]);
            s.push_str(&(v | 0x8000_0000).to_string());
            s.push_str(&chunk[b..]);
            (Cow::Owned(s), true)
        }
        _ => (Cow::Borrowed(chunk), false),
    }
}

fn parse_chunk(chunk: &str) -> Result<can_dbc::Dbc, can_dbc::DbcError> {
    if chunk.ends_with('\n') {
        can_dbc::Dbc::try_from(chunk)
    } else {
        let mut s = String::with_capacity(chunk.len() + 1);
        s.push_str(chunk);
        s.push('\n');
        can_dbc::Dbc::try_from(s.as_str())
    }
}

fn numeric(v: NumericValue) -> f64 {
    match v {
        NumericValue::Uint(u) => u as f64,
        NumericValue::Int(i) => i as f64,
        NumericValue::Double(d) => d,
    }
}

fn split_id(id: MessageId) -> (u32, bool) {
    match id {
        MessageId::Standard(s) => (s as u32, false),
        MessageId::Extended(e) => (e, true),
    }
}

/// Pending multiplexer indicator of a signal, resolved once all statements are read.
#[derive(Clone, Copy)]
enum PendingMux {
    None,
    Value(u64),
}

/// One `SG_MUL_VAL_` entry: signal name, switch name, inclusive ranges, line.
type ExtMux = (String, String, Vec<(u64, u64)>, usize);

struct Building {
    msg: Message,
    pending: Vec<PendingMux>,
    ext_mux: Vec<ExtMux>,
    /// `SystemMessageLongSymbol`: the full name, applied after all name-based references.
    long_name: Option<String>,
    /// `SystemSignalLongSymbol`: (short name, full name).
    long_signal_names: Vec<(String, String)>,
}

fn convert_signal(s: &can_dbc::Signal, line: usize) -> Result<(Signal, PendingMux, bool), String> {
    let order = match s.byte_order {
        CdByteOrder::LittleEndian => ByteOrder::LittleEndian,
        CdByteOrder::BigEndian => ByteOrder::BigEndian,
    };
    let kind = match s.value_type {
        ValueType::Signed => ValueKind::Signed,
        ValueType::Unsigned => ValueKind::Unsigned,
    };
    let mut sig = Signal::new(
        &s.name,
        s.start_bit,
        s.size,
        order,
        kind,
        s.factor,
        s.offset,
    )?;
    sig.min = numeric(s.min);
    sig.max = numeric(s.max);
    sig.unit = s.unit.clone();
    sig.receivers = s.receivers.clone();
    sig.line = line;
    let (pending, is_mux) = match s.multiplexer_indicator {
        MultiplexIndicator::Plain => (PendingMux::None, false),
        MultiplexIndicator::Multiplexor => (PendingMux::None, true),
        MultiplexIndicator::MultiplexedSignal(v) => (PendingMux::Value(v), false),
        MultiplexIndicator::MultiplexorAndMultiplexedSignal(v) => (PendingMux::Value(v), true),
    };
    sig.is_multiplexer = is_mux;
    Ok((sig, pending, is_mux))
}

fn add_signal(b: &mut Building, s: &can_dbc::Signal, line: usize, report: &mut LoadReport) {
    let what = format!("SG_ {} in {}", s.name, b.msg.name);
    if b.msg.signal_by_name(&s.name).is_some() {
        report.skip(line, what, "duplicate signal name in this message");
        return;
    }
    match convert_signal(s, line) {
        Ok((sig, pending, _)) => {
            b.msg.signals.push(sig);
            b.pending.push(pending);
        }
        Err(e) => report.skip(line, what, e),
    }
}

fn load_message(text: &str, st: &Stmt, report: &mut LoadReport) -> Option<Building> {
    let (block, fixed) = fix_id(&text[st.start..st.block_end], "BO_");
    let (header, _) = fix_id(&text[st.start..st.end], "BO_");
    let (block, header) = (block.as_ref(), header.as_ref());
    if fixed {
        report.note(
            st.line,
            format!("BO_ {}", header.trim()),
            "29-bit ID without the extended flag (bit 31); loaded as an extended ID",
        );
    }
    let (parsed, whole) = match parse_chunk(block) {
        Ok(d) => (d, true),
        Err(_) => match parse_chunk(header) {
            Ok(d) => (d, false),
            Err(e) => {
                report.skip(
                    st.line,
                    format!("BO_ {}", header.trim()),
                    format!(
                        "message header unreadable ({}); its {} signals are dropped",
                        reason(&e, st.line),
                        st.sg.len()
                    ),
                );
                return None;
            }
        },
    };
    let Some(m) = parsed.messages.into_iter().next() else {
        report.skip(st.line, "BO_", "no message found in statement");
        return None;
    };
    let (id, extended) = split_id(m.id);
    let mut msg = Message::new(&m.name, id, extended, m.size as usize);
    msg.transmitter = m.transmitter.clone();
    msg.line = st.line;
    let mut b = Building {
        msg,
        pending: Vec::new(),
        ext_mux: Vec::new(),
        long_name: None,
        long_signal_names: Vec::new(),
    };
    if whole {
        for (s, &(line, _, _)) in m.signals.iter().zip(st.sg.iter()) {
            add_signal(&mut b, s, line, report);
        }
    } else {
        for &(line, s0, s1) in &st.sg {
            let mut chunk = String::with_capacity(header.len() + (s1 - s0) + 2);
            chunk.push_str(header.trim_end());
            chunk.push('\n');
            chunk.push_str(&text[s0..s1]);
            match parse_chunk(&chunk) {
                Ok(d) => match d.messages.first().and_then(|m| m.signals.first()) {
                    Some(s) => add_signal(&mut b, s, line, report),
                    None => report.skip(line, "SG_", "no signal found"),
                },
                Err(e) => report.skip(
                    line,
                    format!("SG_ in {}", b.msg.name),
                    // The signal line is line 2 of the retried chunk.
                    reason(&e, line - 1),
                ),
            }
        }
    }
    Some(b)
}

/// Parse DBC text (see the module documentation).
pub(crate) fn parse(text: &str) -> (Database, LoadReport) {
    let mut report = LoadReport {
        encoding: "utf-8".into(),
        ..LoadReport::default()
    };
    let text = text.strip_prefix('\u{feff}').unwrap_or(text);
    let stmts = split(text, &mut report);

    let mut building: Vec<Building> = Vec::new();
    let mut by_id: HashMap<(u32, bool), usize> = HashMap::new();
    let mut db = Database::default();
    // Vector's pseudo-message holding signals not sent in any frame: not loaded, and statements
    // about it are counted as ignored rather than reported as skipped.
    let mut independent: Option<(u32, bool)> = None;

    // Pass 1: messages and nodes.
    for st in &stmts {
        match st.keyword {
            "BO_" => {
                let Some(b) = load_message(text, st, &mut report) else {
                    continue;
                };
                if b.msg.name == "VECTOR__INDEPENDENT_SIG_MSG" {
                    independent = Some((b.msg.id, b.msg.extended));
                    *report
                        .ignored
                        .entry("BO_ VECTOR__INDEPENDENT_SIG_MSG".into())
                        .or_default() += 1;
                    continue;
                }
                let key = (b.msg.id, b.msg.extended);
                if let Some(&prev) = by_id.get(&key) {
                    report.skip(
                        st.line,
                        format!("BO_ {}", b.msg.name),
                        format!(
                            "duplicate ID 0x{:X} (already used by {} at line {})",
                            b.msg.id, building[prev].msg.name, building[prev].msg.line
                        ),
                    );
                    continue;
                }
                by_id.insert(key, building.len());
                building.push(b);
            }
            "BU_" | "VERSION" | "VAL_TABLE_" => match parse_chunk(&text[st.start..st.end]) {
                Ok(d) => {
                    db.nodes.extend(d.nodes.into_iter().map(|n| n.0));
                    if !d.version.0.is_empty() {
                        db.version = d.version.0;
                    }
                    for t in d.value_tables {
                        db.value_tables.push((
                            t.name,
                            t.descriptions
                                .into_iter()
                                .map(|v| (v.id, v.description))
                                .collect(),
                        ));
                    }
                }
                Err(e) => report.skip(st.line, st.keyword, reason(&e, st.line)),
            },
            _ => {}
        }
    }

    // Pass 2: statements that refer to messages and signals.
    let find = |id: MessageId| -> Option<usize> { by_id.get(&split_id(id)).copied() };
    for st in &stmts {
        let kw = st.keyword;
        let chunk = &text[st.start..st.end];
        match kw {
            "BO_" | "BU_" | "VERSION" | "VAL_TABLE_" => continue,
            "CM_" | "VAL_" | "SIG_VALTYPE_" | "SG_MUL_VAL_" => {}
            "BA_"
                if chunk.contains("\"GenMsgCycleTime\"")
                    || chunk.contains("\"SystemMessageLongSymbol\"")
                    || chunk.contains("\"SystemSignalLongSymbol\"") => {}
            other => {
                *report.ignored.entry(other.to_string()).or_default() += 1;
                continue;
            }
        }
        let short: String = chunk.trim().chars().take(60).collect();
        let (chunk, _) = fix_id(chunk, kw);
        let d = match parse_chunk(&chunk) {
            Ok(d) => d,
            Err(e) => {
                report.skip(st.line, short, reason(&e, st.line));
                continue;
            }
        };
        let about_independent = independent.is_some_and(|k| {
            let ids = d
                .comments
                .iter()
                .filter_map(|c| match c {
                    can_dbc::Comment::Message { id, .. } => Some(*id),
                    can_dbc::Comment::Signal { message_id, .. } => Some(*message_id),
                    _ => None,
                })
                .chain(d.value_descriptions.iter().filter_map(|v| match v {
                    can_dbc::ValueDescription::Signal { message_id, .. } => Some(*message_id),
                    _ => None,
                }))
                .chain(
                    d.signal_extended_value_type_list
                        .iter()
                        .map(|t| t.message_id),
                )
                .chain(d.extended_multiplex.iter().map(|x| x.message_id));
            let mut any = false;
            for id in ids {
                if split_id(id) != k {
                    return false;
                }
                any = true;
            }
            any
        });
        if about_independent {
            *report
                .ignored
                .entry(format!("{kw} about VECTOR__INDEPENDENT_SIG_MSG"))
                .or_default() += 1;
            continue;
        }
        for c in d.comments {
            match c {
                can_dbc::Comment::Message { id, comment } => match find(id) {
                    Some(i) => building[i].msg.comment = Some(comment),
                    None => report.skip(st.line, short.clone(), "comment for an unknown message"),
                },
                can_dbc::Comment::Signal {
                    message_id,
                    name,
                    comment,
                } => {
                    let target = find(message_id)
                        .and_then(|i| Some((i, building[i].msg.signal_by_name(&name)?)));
                    match target {
                        Some((i, j)) => building[i].msg.signals[j].comment = Some(comment),
                        None => {
                            report.skip(st.line, short.clone(), "comment for an unknown signal")
                        }
                    }
                }
                can_dbc::Comment::Plain { comment } => db.comment = Some(comment),
                can_dbc::Comment::Node { .. } | can_dbc::Comment::EnvVar { .. } => {}
            }
        }
        for v in d.value_descriptions {
            if let can_dbc::ValueDescription::Signal {
                message_id,
                name,
                value_descriptions,
            } = v
            {
                let target = find(message_id)
                    .and_then(|i| Some((i, building[i].msg.signal_by_name(&name)?)));
                match target {
                    Some((i, j)) => {
                        building[i].msg.signals[j].choices = value_descriptions
                            .into_iter()
                            .map(|v| (v.id, v.description))
                            .collect()
                    }
                    None => {
                        report.skip(st.line, short.clone(), "value table for an unknown signal")
                    }
                }
            }
        }
        for t in d.signal_extended_value_type_list {
            let target = find(t.message_id)
                .and_then(|i| Some((i, building[i].msg.signal_by_name(&t.signal_name)?)));
            let kind = match t.signal_extended_value_type {
                can_dbc::SignalExtendedValueType::SignedOrUnsignedInteger => None,
                can_dbc::SignalExtendedValueType::IEEEfloat32Bit => Some(ValueKind::Float32),
                can_dbc::SignalExtendedValueType::IEEEdouble64bit => Some(ValueKind::Float64),
            };
            match (target, kind) {
                (Some(_), None) => {}
                (Some((i, j)), Some(kind)) => {
                    if let Err(e) = building[i].msg.signals[j].set_kind(kind) {
                        report.skip(st.line, short.clone(), e);
                    }
                }
                (None, _) => {
                    report.skip(st.line, short.clone(), "value type for an unknown signal")
                }
            }
        }
        for x in d.extended_multiplex {
            match find(x.message_id) {
                Some(i) => building[i].ext_mux.push((
                    x.signal_name,
                    x.multiplexor_signal_name,
                    x.mappings
                        .iter()
                        .map(|m| (m.min_value, m.max_value))
                        .collect(),
                    st.line,
                )),
                None => report.skip(st.line, short.clone(), "SG_MUL_VAL_ for an unknown message"),
            }
        }
        for a in d.attribute_values_signal {
            // Vector tools cut names to 32 characters and keep the full one here.
            if let (true, can_dbc::AttributeValue::String(long)) =
                (a.name == "SystemSignalLongSymbol", a.value)
            {
                match find(a.message_id) {
                    Some(i) => building[i].long_signal_names.push((a.signal_name, long)),
                    None => report.skip(st.line, short.clone(), "long name for an unknown message"),
                }
            }
        }
        for a in d.attribute_values_message {
            if a.name == "SystemMessageLongSymbol" {
                if let (Some(i), can_dbc::AttributeValue::String(long)) =
                    (find(a.message_id), &a.value)
                {
                    building[i].long_name = Some(long.clone());
                }
                continue;
            }
            if a.name != "GenMsgCycleTime" {
                continue;
            }
            let ms = match a.value {
                can_dbc::AttributeValue::Uint(u) => u32::try_from(u).ok(),
                can_dbc::AttributeValue::Int(i) => u32::try_from(i).ok(),
                can_dbc::AttributeValue::Double(f) if (0.0..4e9).contains(&f) => Some(f as u32),
                _ => None,
            };
            if let (Some(i), Some(ms)) = (find(a.message_id), ms) {
                building[i].msg.cycle_time_ms = Some(ms);
            }
        }
    }

    // Pass 3: resolve multiplexing, check layouts, index.
    for mut b in building {
        resolve_mux(&mut b, &mut report);
        // Full names last: every statement above refers to the short ones.
        for (short, long) in std::mem::take(&mut b.long_signal_names) {
            if let Some(j) = b.msg.signal_by_name(&short) {
                b.msg.signals[j].name = long;
            }
        }
        if let Some(long) = b.long_name.take() {
            b.msg.name = long;
        }
        check_layout(&b.msg, &mut report);
        report.signals += b.msg.signals.len();
        db.messages.push(b.msg);
    }
    report.messages = db.messages.len();
    report.skipped.sort_by_key(|s| s.line);
    report.notes.sort_by_key(|s| s.line);
    db.build_index();
    (db, report)
}

fn resolve_mux(b: &mut Building, report: &mut LoadReport) {
    let msg = &mut b.msg;
    let plain_switches: Vec<usize> = msg
        .signals
        .iter()
        .enumerate()
        .filter(|(i, s)| s.is_multiplexer && matches!(b.pending[*i], PendingMux::None))
        .map(|(i, _)| i)
        .collect();
    // Explicit SG_MUL_VAL_ conditions override the mN indicator.
    let mut explicit: HashMap<usize, MuxCondition> = HashMap::new();
    for (sig, sw, ranges, line) in &b.ext_mux {
        let what = format!("SG_MUL_VAL_ {} {} {}", msg.name, sig, sw);
        let (Some(i), Some(j)) = (msg.signal_by_name(sig), msg.signal_by_name(sw)) else {
            report.skip(*line, what, "names a signal the message does not have");
            continue;
        };
        if !msg.signals[j].is_multiplexer {
            report.note(
                *line,
                what.clone(),
                "switch is not marked M/mNM; treated as one",
            );
            msg.signals[j].is_multiplexer = true;
        }
        let e = explicit.entry(i).or_insert(MuxCondition {
            switch: j,
            ranges: Vec::new(),
        });
        if e.switch != j {
            report.skip(*line, what, "signal already has a different switch");
            continue;
        }
        e.ranges.extend(ranges.iter().copied());
    }
    for i in 0..msg.signals.len() {
        if let Some(c) = explicit.remove(&i) {
            msg.signals[i].multiplexer = Some(c);
            continue;
        }
        if let PendingMux::Value(v) = b.pending[i] {
            match plain_switches.as_slice() {
                [sw] => {
                    msg.signals[i].multiplexer = Some(MuxCondition {
                        switch: *sw,
                        ranges: vec![(v, v)],
                    })
                }
                [] => report.note(
                    msg.signals[i].line,
                    format!("SG_ {} in {}", msg.signals[i].name, msg.name),
                    "multiplexed signal but the message has no M signal; decoded as plain",
                ),
                _ => report.note(
                    msg.signals[i].line,
                    format!("SG_ {} in {}", msg.signals[i].name, msg.name),
                    "several M signals and no SG_MUL_VAL_; decoded as plain",
                ),
            }
        }
    }
    // Switches must be integers.
    let mut bad: Vec<usize> = Vec::new();
    for (i, s) in msg.signals.iter().enumerate() {
        if let Some(c) = &s.multiplexer {
            let sw = &msg.signals[c.switch];
            if matches!(sw.kind, ValueKind::Float32 | ValueKind::Float64) {
                bad.push(i);
            }
        }
    }
    for i in bad.into_iter().rev() {
        let s = &msg.signals[i];
        report.skip(
            s.line,
            format!("SG_ {} in {}", s.name, msg.name),
            "multiplexed by a floating-point switch",
        );
        remove_signal(msg, i);
    }
    while let Err(e) = msg.finish() {
        // Break a cycle by dropping the conditions of the first offending signal.
        let Some(i) = msg.signals.iter().position(|s| e.contains(&s.name)) else {
            report.skip(msg.line, format!("BO_ {}", msg.name), e);
            msg.signals.clear();
            let _ = msg.finish();
            break;
        };
        let s = &msg.signals[i];
        report.skip(s.line, format!("SG_ {} in {}", s.name, msg.name), e.clone());
        remove_signal(msg, i);
    }
}

/// Remove a signal and every signal that depends on it; fix switch indices.
fn remove_signal(msg: &mut Message, idx: usize) {
    let mut doomed = vec![false; msg.signals.len()];
    doomed[idx] = true;
    let mut changed = true;
    while changed {
        changed = false;
        for (i, s) in msg.signals.iter().enumerate() {
            if let Some(c) = &s.multiplexer {
                if !doomed[i] && c.switch < doomed.len() && doomed[c.switch] {
                    doomed[i] = true;
                    changed = true;
                }
            }
        }
    }
    let mut new_index = vec![usize::MAX; msg.signals.len()];
    let mut n = 0;
    for (i, d) in doomed.iter().enumerate() {
        if !d {
            new_index[i] = n;
            n += 1;
        }
    }
    let old = std::mem::take(&mut msg.signals);
    for (i, mut s) in old.into_iter().enumerate() {
        if doomed[i] {
            continue;
        }
        if let Some(c) = &mut s.multiplexer {
            c.switch = new_index[c.switch];
        }
        msg.signals.push(s);
    }
}

/// Notes for signals past the declared length and for overlapping signals that can be present
/// together (same multiplexing condition).
fn check_layout(msg: &Message, report: &mut LoadReport) {
    let mut masks: Vec<[u64; 8]> = Vec::with_capacity(msg.signals.len());
    for s in &msg.signals {
        if s.needed_len() > msg.size_bytes {
            report.note(
                s.line,
                format!("SG_ {} in {}", s.name, msg.name),
                format!(
                    "needs {} bytes but the message declares {}; decoded only from long enough frames",
                    s.needed_len(),
                    msg.size_bytes
                ),
            );
        }
        let mut m = [0u64; 8];
        let mut buf = [0u8; 64];
        if s.layout.insert(u64::MAX, &mut buf) {
            for (k, chunk) in buf.chunks(8).enumerate() {
                m[k] = u64::from_le_bytes(chunk.try_into().unwrap());
            }
        }
        masks.push(m);
    }
    for i in 0..msg.signals.len() {
        for j in 0..i {
            let (a, b) = (&msg.signals[i], &msg.signals[j]);
            if a.multiplexer != b.multiplexer {
                continue;
            }
            if masks[i].iter().zip(&masks[j]).any(|(x, y)| x & y != 0) {
                report.note(
                    a.line,
                    format!("SG_ {} in {}", a.name, msg.name),
                    format!("overlaps signal {} (both decoded)", b.name),
                );
            }
        }
    }
}
