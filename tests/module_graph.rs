//! The library's module graph and module docs, checked from the source text of every file under
//! src/ (no build tooling needed):
//!
//! * layering: data flows one way (frames → signals → braking events → estimate → alerts →
//!   outputs), so a module may use only modules of its own layer or of the layers below it
//!   ([`LAYERS`]). Every `crate::…` path and every `super::…` path that leaves its top-level
//!   module is checked, in code only (comments and string literals are not dependencies);
//! * every top-level module has a place in [`LAYERS`] (a new module must be placed deliberately);
//! * every .rs file opens with a `//!` doc (after optional inner attributes);
//! * no file cites tracker items ("issue 6 item 2"): docs say what is meant instead.
//!
//! Failures name the file and line.

use std::path::{Path, PathBuf};

/// Top-level modules of the library, lowest layer first. A module may reference modules in its
/// own layer or in an earlier one, never a later one. The last layer holds the applications
/// (the daemon, the CLI commands and what they render); they may use one another.
const LAYERS: &[(&str, &[&str])] = &[
    ("where the shared test material lives", &["shared_data"]),
    ("wire formats", &["wire"]),
    ("frame sources", &["source"]),
    ("DBC decoding", &["dbc"]),
    ("vehicle signals and their validity", &["signals"]),
    ("signal analysis", &["analysis"]),
    ("the shimmy model", &["model"]),
    ("braking-event detection", &["events"]),
    ("the clearance observer", &["observer"]),
    ("vehicle profiles", &["profile"]),
    ("the monitor pipeline's shared types", &["monitor"]),
    ("the alert rules", &["alerts"]),
    ("the monitor pipeline", &["pipeline"]),
    ("the journal", &["journal"]),
    ("the Parquet data lake", &["lake"]),
    (
        "applications: daemon, commands, reports",
        &["daemon", "cli", "report", "doctor"],
    ),
];

fn layer_of(module: &str) -> Option<usize> {
    LAYERS.iter().position(|(_, mods)| mods.contains(&module))
}

fn src_dir() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("src")
}

fn rs_files(dir: &Path, out: &mut Vec<PathBuf>) {
    let mut entries: Vec<_> = std::fs::read_dir(dir)
        .unwrap_or_else(|e| panic!("reading {}: {e}", dir.display()))
        .map(|e| e.expect("directory entry").path())
        .collect();
    entries.sort();
    for p in entries {
        if p.is_dir() {
            rs_files(&p, out);
        } else if p.extension().is_some_and(|x| x == "rs") {
            out.push(p);
        }
    }
}

/// The module path of a library file relative to src/: `alerts/mod.rs` → `[alerts]`,
/// `wire/mf4/read.rs` → `[wire, mf4, read]`, `lib.rs` → `[]`.
fn module_path(rel: &str) -> Vec<String> {
    let rel = rel.strip_suffix(".rs").unwrap_or(rel);
    let mut parts: Vec<String> = rel.split('/').map(str::to_string).collect();
    if parts.last().is_some_and(|p| p == "mod" || p == "lib") {
        parts.pop();
    }
    parts
}

/// The source with comments and the contents of string and char literals replaced by spaces
/// (newlines kept, so byte offsets map to the same lines).
fn code_only(src: &str) -> Vec<u8> {
    let b = src.as_bytes();
    let mut out = b.to_vec();
    let blank = |out: &mut Vec<u8>, from: usize, to: usize| {
        for c in &mut out[from..to] {
            if *c != b'\n' {
                *c = b' ';
            }
        }
    };
    let mut i = 0;
    while i < b.len() {
        let c = b[i];
        if c == b'/' && b.get(i + 1) == Some(&b'/') {
            let end = b[i..]
                .iter()
                .position(|&x| x == b'\n')
                .map_or(b.len(), |n| i + n);
            blank(&mut out, i, end);
            i = end;
        } else if c == b'/' && b.get(i + 1) == Some(&b'*') {
            let (mut depth, mut j) = (1, i + 2);
            while j < b.len() && depth > 0 {
                if b[j] == b'/' && b.get(j + 1) == Some(&b'*') {
                    depth += 1;
                    j += 2;
                } else if b[j] == b'*' && b.get(j + 1) == Some(&b'/') {
                    depth -= 1;
                    j += 2;
                } else {
                    j += 1;
                }
            }
            blank(&mut out, i, j);
            i = j;
        } else if c == b'r'
            && (b.get(i + 1) == Some(&b'"') || b.get(i + 1) == Some(&b'#'))
            && (i == 0
                || !is_ident(b[i - 1])
                || (b[i - 1] == b'b' && (i < 2 || !is_ident(b[i - 2]))))
        {
            // Raw string r"…" / r#"…"#.
            let mut j = i + 1;
            let mut hashes = 0;
            while b.get(j) == Some(&b'#') {
                hashes += 1;
                j += 1;
            }
            if b.get(j) != Some(&b'"') {
                i += 1;
                continue;
            }
            let start = j + 1;
            let mut k = start;
            let end = loop {
                if k >= b.len() {
                    break b.len();
                }
                if b[k] == b'"'
                    && b[k + 1..]
                        .iter()
                        .take(hashes)
                        .filter(|&&x| x == b'#')
                        .count()
                        == hashes
                {
                    break k;
                }
                k += 1;
            };
            blank(&mut out, start, end);
            i = end + 1 + hashes;
        } else if c == b'"' {
            let mut j = i + 1;
            while j < b.len() && b[j] != b'"' {
                j += if b[j] == b'\\' { 2 } else { 1 };
            }
            blank(&mut out, i + 1, j.min(b.len()));
            i = j + 1;
        } else if c == b'\'' {
            // A char literal ('x', '\n', '\u{..}') or a lifetime ('a).
            if b.get(i + 1) == Some(&b'\\') {
                let mut j = i + 2;
                while j < b.len() && b[j] != b'\'' {
                    j += 1;
                }
                blank(&mut out, i + 1, j);
                i = j + 1;
            } else if let Some(len) = src[i + 1..].chars().next().map(char::len_utf8) {
                if b.get(i + 1 + len) == Some(&b'\'') {
                    blank(&mut out, i + 1, i + 1 + len);
                    i += 2 + len;
                } else {
                    i += 1;
                }
            } else {
                i += 1;
            }
        } else {
            i += 1;
        }
    }
    out
}

fn is_ident(c: u8) -> bool {
    c.is_ascii_alphanumeric() || c == b'_'
}

fn skip_ws(b: &[u8], mut i: usize) -> usize {
    while i < b.len() && b[i].is_ascii_whitespace() {
        i += 1;
    }
    i
}

fn ident_at(b: &[u8], i: usize) -> Option<(String, usize)> {
    let mut j = i;
    while j < b.len() && is_ident(b[j]) {
        j += 1;
    }
    (j > i).then(|| (String::from_utf8_lossy(&b[i..j]).into_owned(), j))
}

/// After `::` at `i`: the first segment, or for a `{…}` group the first segment of each item.
fn first_segments(b: &[u8], i: usize) -> Vec<String> {
    let i = skip_ws(b, i);
    if b.get(i) == Some(&b'{') {
        let mut out = Vec::new();
        let (mut depth, mut j, mut at_item) = (0, i, true);
        while j < b.len() {
            match b[j] {
                b'{' => {
                    depth += 1;
                    at_item = depth == 1;
                    j += 1;
                }
                b'}' => {
                    depth -= 1;
                    j += 1;
                    if depth == 0 {
                        break;
                    }
                }
                b',' => {
                    at_item = depth == 1;
                    j += 1;
                }
                c if at_item && is_ident(c) => {
                    let (id, end) = ident_at(b, j).expect("identifier");
                    out.push(id);
                    at_item = false;
                    j = end;
                }
                _ => j += 1,
            }
        }
        out
    } else {
        ident_at(b, i).map(|(id, _)| vec![id]).unwrap_or_default()
    }
}

/// Expects `::` at `i` (whitespace allowed); returns the index after it.
fn path_sep(b: &[u8], i: usize) -> Option<usize> {
    let i = skip_ws(b, i);
    (b.get(i) == Some(&b':') && b.get(i + 1) == Some(&b':')).then_some(i + 2)
}

/// Every reference to another top-level module in a library file: (line, top-level module).
/// `rel` is the file's path relative to src/ (it decides where `super::` leads).
fn references(rel: &str, src: &str) -> Vec<(usize, String)> {
    let file_path = module_path(rel);
    let b = code_only(src);
    let line_of = |pos: usize| b[..pos].iter().filter(|&&c| c == b'\n').count() + 1;
    // Inline modules (`mod tests { … }`): the brace depth each opened at.
    let mut inline: Vec<usize> = Vec::new();
    let mut depth = 0usize;
    let mut out = Vec::new();
    let mut i = 0;
    while i < b.len() {
        match b[i] {
            b'{' => {
                depth += 1;
                i += 1;
                continue;
            }
            b'}' => {
                depth = depth.saturating_sub(1);
                if inline.last() == Some(&depth) {
                    inline.pop();
                }
                i += 1;
                continue;
            }
            c if !is_ident(c) => {
                i += 1;
                continue;
            }
            _ => {}
        }
        if i > 0 && is_ident(b[i - 1]) {
            i += 1;
            continue;
        }
        let (word, end) = ident_at(&b, i).expect("identifier");
        match word.as_str() {
            "mod" => {
                // `mod name {` opens an inline module; `mod name;` is a file.
                let j = skip_ws(&b, end);
                if let Some((_, k)) = ident_at(&b, j) {
                    if b.get(skip_ws(&b, k)) == Some(&b'{') {
                        inline.push(depth);
                    }
                }
            }
            "crate" => {
                if let Some(j) = path_sep(&b, end) {
                    for m in first_segments(&b, j) {
                        out.push((line_of(i), m));
                    }
                }
            }
            "super" => {
                let mut n = 0;
                let mut j = i;
                loop {
                    match ident_at(&b, j) {
                        Some((w, e)) if w == "super" => match path_sep(&b, e) {
                            Some(k) => {
                                n += 1;
                                j = skip_ws(&b, k);
                            }
                            None => break,
                        },
                        _ => break,
                    }
                }
                let here = file_path.len() + inline.len();
                if n > 0 && n >= here && !file_path.is_empty() {
                    // `super::` leads to the crate root only when it climbs past every module
                    // (inline modules live inside the file's own top-level module anyway).
                    for m in first_segments(&b, j) {
                        out.push((line_of(i), m));
                    }
                }
                i = j.max(end);
                continue;
            }
            _ => {}
        }
        i = end;
    }
    out
}

/// Layering violations of one library file, as messages naming the file and line.
fn violations(rel: &str, src: &str) -> Vec<String> {
    let path = module_path(rel);
    let Some(own) = path.first() else {
        return Vec::new(); // lib.rs declares the modules
    };
    let Some(own_layer) = layer_of(own) else {
        return vec![format!(
            "src/{rel}: top-level module `{own}` has no layer in tests/module_graph.rs LAYERS"
        )];
    };
    references(rel, src)
        .into_iter()
        .filter(|(_, m)| m != own)
        .filter_map(|(line, m)| {
            let l = layer_of(&m)?;
            (l > own_layer).then(|| {
                format!(
                    "src/{rel}:{line}: `{own}` ({}) uses `crate::{m}` ({}), a layer above it",
                    LAYERS[own_layer].0, LAYERS[l].0
                )
            })
        })
        .collect()
}

/// (relative path, contents) of every library file (src/bin holds separate crates).
fn library_files() -> Vec<(String, String)> {
    let src = src_dir();
    let mut files = Vec::new();
    rs_files(&src, &mut files);
    files
        .into_iter()
        .map(|p| {
            let rel = p
                .strip_prefix(&src)
                .expect("under src")
                .to_string_lossy()
                .replace('\\', "/");
            let text = std::fs::read_to_string(&p)
                .unwrap_or_else(|e| panic!("reading {}: {e}", p.display()));
            (rel, text)
        })
        .collect()
}

#[test]
fn no_module_uses_a_layer_above_it() {
    let mut bad = Vec::new();
    let mut seen_any = false;
    for (rel, text) in library_files() {
        if rel.starts_with("bin/") {
            continue;
        }
        seen_any |= !references(&rel, &text).is_empty();
        bad.extend(violations(&rel, &text));
    }
    assert!(
        seen_any,
        "no crate:: path found under src/: the scan is broken"
    );
    assert!(
        bad.is_empty(),
        "module layering broken:\n{}",
        bad.join("\n")
    );
}

#[test]
fn every_top_level_module_has_a_layer() {
    let lib = std::fs::read_to_string(src_dir().join("lib.rs")).expect("src/lib.rs");
    let declared: Vec<&str> = lib
        .lines()
        .filter_map(|l| {
            l.trim()
                .strip_prefix("pub mod ")
                .or_else(|| l.trim().strip_prefix("mod "))
        })
        .filter_map(|l| l.strip_suffix(';'))
        .collect();
    assert!(
        declared.len() > 10,
        "src/lib.rs: module declarations not found"
    );
    let missing: Vec<_> = declared.iter().filter(|m| layer_of(m).is_none()).collect();
    assert!(
        missing.is_empty(),
        "src/lib.rs declares modules with no layer in tests/module_graph.rs LAYERS: {missing:?}"
    );
}

#[test]
fn the_checker_sees_an_arrow_running_back_up() {
    // The alert rules reaching into the daemon, in each form a path can take.
    let cases = [
        ("alerts/mod.rs", "use crate::daemon::config::X;\n", 1),
        (
            "alerts/config.rs",
            "//! doc\nuse crate::{monitor::A, daemon::B};\n",
            2,
        ),
        (
            "alerts/mod.rs",
            "fn f() {\n    let _ = super::daemon::run::go();\n}\n",
            2,
        ),
        (
            "alerts/config.rs",
            "fn f() -> crate :: report :: R { todo!() }\n",
            1,
        ),
        (
            "wire/mf4/read.rs",
            "use super::super::super::source::log;\n",
            1,
        ),
    ];
    for (rel, text, line) in cases {
        let v = violations(rel, text);
        assert_eq!(v.len(), 1, "{rel}: {text:?} gave {v:?}");
        assert!(v[0].starts_with(&format!("src/{rel}:{line}: ")), "{v:?}");
    }
    // Not dependencies: downward paths, comments, strings, paths inside the module, `super::`
    // from an inline test module.
    let fine = [
        (
            "alerts/mod.rs",
            "use crate::monitor::Estimate;\n// crate::daemon::x\n",
        ),
        (
            "alerts/mod.rs",
            "/// [`crate::daemon`]\nconst S: &str = \"crate::daemon::x\";\n",
        ),
        ("alerts/mod.rs", "mod tests {\n    use super::config;\n}\n"),
        (
            "alerts/config.rs",
            "use super::Kind;\nconst C: char = '{';\nuse crate::monitor::E;\n",
        ),
        (
            "daemon/run.rs",
            "use crate::cli::x;\nuse crate::alerts::y;\n",
        ),
    ];
    for (rel, text) in fine {
        let v = violations(rel, text);
        assert!(v.is_empty(), "{rel}: {text:?} gave {v:?}");
    }
}

/// "issue 6", "Issue 5 item 4", "issues 5–6", "issue #12": a tracker citation, (line, text).
fn tracker_citations(text: &str) -> Vec<(usize, String)> {
    let mut out = Vec::new();
    for (n, line) in text.lines().enumerate() {
        let lower = line.to_ascii_lowercase();
        let b = lower.as_bytes();
        let mut from = 0;
        while let Some(k) = lower[from..].find("issue") {
            let at = from + k;
            from = at + 5;
            if at > 0 && is_ident(b[at - 1]) {
                continue;
            }
            let mut j = at + 5;
            if b.get(j) == Some(&b's') {
                j += 1;
            }
            let j2 = skip_ws(b, j);
            let j2 = if b.get(j2) == Some(&b'#') { j2 + 1 } else { j2 };
            if (j2 > j || b.get(j) == Some(&b'#')) && b.get(j2).is_some_and(u8::is_ascii_digit) {
                out.push((n + 1, line.trim().to_string()));
                break;
            }
        }
    }
    out
}

/// Whether a file opens with a `//!` doc, after blank lines and inner attributes (`#![…]`).
fn opens_with_module_doc(text: &str) -> bool {
    text.lines()
        .map(str::trim_start)
        .find(|l| !l.is_empty() && !l.starts_with("#!["))
        .is_some_and(|l| l.starts_with("//!"))
}

fn all_files_under_src() -> Vec<(String, String)> {
    library_files() // includes src/bin
}

#[test]
fn no_file_cites_tracker_items() {
    let bad: Vec<String> = all_files_under_src()
        .iter()
        .flat_map(|(rel, text)| {
            tracker_citations(text)
                .into_iter()
                .map(move |(line, l)| format!("src/{rel}:{line}: {l}"))
        })
        .collect();
    assert!(
        bad.is_empty(),
        "say what is meant instead of citing a tracker item:\n{}",
        bad.join("\n")
    );
}

#[test]
fn every_file_opens_with_a_module_doc() {
    let files = all_files_under_src();
    assert!(
        files.len() > 50,
        "only {} files found under src/",
        files.len()
    );
    let bad: Vec<_> = files
        .iter()
        .filter(|(_, text)| !opens_with_module_doc(text))
        .map(|(rel, _)| format!("src/{rel}:1"))
        .collect();
    assert!(
        bad.is_empty(),
        "files without a leading `//!` doc saying what the module is and is not:\n{}",
        bad.join("\n")
    );
}

#[test]
fn the_doc_checks_can_fail() {
    for cite in [
        "//! Alerts (issue 6 item 2).",
        "// see Issue 5",
        "/// issues 5-6",
        "//! issue #12",
        "let s = \"issue 3\";",
    ] {
        assert_eq!(tracker_citations(cite).len(), 1, "{cite:?} not found");
    }
    for fine in [
        "//! no issues here",
        "// reissue 5 frames",
        "// the issue is 5 ms of lag",
    ] {
        assert!(tracker_citations(fine).is_empty(), "{fine:?} flagged");
    }
    assert!(opens_with_module_doc("#![allow(x)]\n\n//! Doc.\nuse a;"));
    assert!(!opens_with_module_doc("use a;\n//! Doc."));
    assert!(!opens_with_module_doc("/// Item doc.\nfn f() {}"));
    assert!(!opens_with_module_doc(""));
}
