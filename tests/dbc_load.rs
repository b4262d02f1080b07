//! Tolerant loading: every DBC under `dbc/` loads, the report lists what was skipped (with line
//! numbers), and message/signal counts agree with an independent count of `BO_` / `SG_` lines.

use shimmy::dbc::Database;

fn all_dbc_files() -> Option<Vec<std::path::PathBuf>> {
    let dir = shimmy::shared_data::require("DBC corpus")?.join("dbc");
    let mut out = Vec::new();
    for sub in ["opendbc", "cantools"] {
        for e in std::fs::read_dir(dir.join(sub)).unwrap() {
            let p = e.unwrap().path();
            if p.extension().is_some_and(|x| x.eq_ignore_ascii_case("dbc")) {
                out.push(p);
            }
        }
    }
    out.sort();
    Some(out)
}

/// Independent count: lines whose first token is `BO_` (minus Vector's pseudo-message) and
/// `SG_` lines, by plain text matching.
fn grep_counts(text: &str) -> (usize, usize) {
    let mut bo = 0;
    let mut sg = 0;
    for l in text.lines() {
        let t = l.trim_start();
        if t.starts_with("BO_ ") && !t.contains("VECTOR__INDEPENDENT_SIG_MSG") {
            bo += 1;
        } else if t.starts_with("SG_ ") && l.starts_with(char::is_whitespace) {
            sg += 1;
        }
    }
    (bo, sg)
}

#[test]
fn every_dbc_loads_and_reports() {
    let Some(files) = all_dbc_files() else { return };
    assert!(
        files.len() >= 92,
        "the corpus has 92 DBC files, found {}",
        files.len()
    );
    let mut total_skipped = 0;
    for f in &files {
        let (db, report) = Database::load(f).unwrap();
        assert_eq!(report.messages, db.messages().len());
        let sigs: usize = db.messages().iter().map(|m| m.signals.len()).sum();
        assert_eq!(report.signals, sigs);
        for s in &report.skipped {
            assert!(
                s.line >= 1,
                "{}: skip without a line number: {s:?}",
                f.display()
            );
            assert!(!s.reason.is_empty());
        }
        total_skipped += report.skipped.len();
        // Every message can be looked up by its ID and by its name.
        for (i, m) in db.messages().iter().enumerate() {
            assert_eq!(db.message_index(m.id, m.extended), Some(i), "{}", m.name);
            assert!(db.message_by_name(&m.name).is_some());
        }
    }
    assert!(
        total_skipped > 0,
        "the opendbc quirks must show up in reports"
    );
}

fn load(rel: &str) -> Option<(Database, shimmy::dbc::LoadReport, String)> {
    let p = shimmy::shared_data::require_file(rel)?;
    let text = String::from_utf8_lossy(&std::fs::read(&p).unwrap()).into_owned();
    let (db, r) = Database::load(&p).unwrap();
    Some((db, r, text))
}

#[test]
fn counts_match_independent_grep() {
    for rel in [
        "dbc/opendbc/toyota_new_mc_pt_generated.dbc",
        "dbc/opendbc/ford_lincoln_base_pt.dbc",
        "dbc/opendbc/hyundai_can_generated.dbc",
        "dbc/opendbc/vw_mqb.dbc",
        "dbc/opendbc/honda_civic_touring_2016_can_generated.dbc",
        "dbc/cantools/vehicle.dbc",
        "dbc/cantools/multiplex_2.dbc",
    ] {
        let Some((db, report, text)) = load(rel) else {
            return;
        };
        let (bo, sg) = grep_counts(&text);
        assert!(report.skipped.iter().all(|s| !s.item.starts_with("SG_")));
        assert_eq!(db.messages().len(), bo, "{rel}: messages");
        assert_eq!(report.signals, sg, "{rel}: signals");
    }
}

#[test]
fn known_quirks_are_reported_not_fatal() {
    // gm: VAL_ for a signal that does not exist.
    if let Some((db, r, _)) = load("dbc/opendbc/gm_global_a_powertrain_generated.dbc") {
        let s = r
            .skipped
            .iter()
            .find(|s| s.item.contains("GasRegenCmdActiveInv"))
            .expect("VAL_ for missing signal reported");
        assert_eq!(s.line, 348);
        assert!(s.reason.contains("unknown signal"));
        assert!(db.messages().len() > 40);
    }
    // honda: `CM_ SG_ 304 "..."` without a signal name is a message comment.
    if let Some((db, _r, _)) = load("dbc/opendbc/honda_civic_touring_2016_can_generated.dbc") {
        let m = db.message(304, false).unwrap();
        assert!(
            m.comment.is_some(),
            "CM_ SG_ without name attached to the message"
        );
    }
    // hyundai: `CM_ 145 "..."` without an object keyword.
    if let Some((db, _r, _)) = load("dbc/opendbc/hyundai_can_generated.dbc") {
        assert!(db.message(145, false).unwrap().comment.is_some());
    }
    // psa: signal names starting with a digit load.
    if let Some((db, r, text)) = load("dbc/opendbc/psa_aee2010_r3.dbc") {
        let digit_named = text
            .lines()
            .filter_map(|l| l.trim_start().strip_prefix("SG_ "))
            .filter(|l| l.starts_with(|c: char| c.is_ascii_digit()))
            .count();
        let loaded = db
            .messages()
            .iter()
            .flat_map(|m| &m.signals)
            .filter(|s| s.name.starts_with(|c: char| c.is_ascii_digit()))
            .count();
        assert!(digit_named > 0);
        assert_eq!(loaded, digit_named);
        assert!(r.ignored.keys().any(|k| k.contains("VECTOR__INDEPENDENT")));
    }
    // toyota: overlapping signals are kept and noted.
    if let Some((_db, r, _)) = load("dbc/opendbc/toyota_new_mc_pt_generated.dbc") {
        assert!(r.notes.iter().any(|n| n.reason.contains("overlaps")));
    }
    // cp1252 text.
    if let Some((_db, r, _)) = load("dbc/cantools/cp1252.dbc") {
        assert_eq!(r.encoding, "windows-1252");
    }
    // Names cut to 32 characters get their full names from SystemMessageLongSymbol /
    // SystemSignalLongSymbol (as cantools does), after VAL_ etc. resolved the short ones.
    if let Some((db, r, _)) = load("dbc/cantools/issue_784.dbc") {
        assert!(r.skipped.is_empty(), "{r}");
        assert!(db
            .message_by_name("Message_1_12345678901234567890123456789012")
            .is_some());
    }
    // 29-bit IDs written without the extended flag.
    if let Some((db, r, _)) = load("dbc/cantools/issue_199.dbc") {
        assert!(r.skipped.is_empty(), "{r}");
        assert!(db.message(274_923_520, true).is_some());
    }
}

#[test]
fn bad_statements_are_isolated() {
    let text = "VERSION \"\"\n\nBU_: A B\n\
BO_ 100 GOOD: 8 A\n SG_ X : 0|8@1+ (1,0) [0|255] \"\" B\n SG_ BAD : 8|8@1+ (1,0 [0|255] \"\" B\n SG_ Y : 16|8@1- (2,1) [0|0] \"\" B\n\n\
BO_ 101 NOSIG: 2 A\n\n\
CM_ SG_ 100 NOPE \"comment for nothing\";\n\
VAL_ 100 X 1 \"one\" 2 \"two\" ;\n\
VAL_ 100 Z 1 \"one\" ;\n\
SIG_VALTYPE_ 100 X : 1;\n\
garbage here\n";
    let (db, r) = Database::parse(text);
    assert_eq!(db.messages().len(), 2);
    let m = db.message(100, false).unwrap();
    let names: Vec<&str> = m.signals.iter().map(|s| s.name.as_str()).collect();
    assert_eq!(names, ["X", "Y"]);
    assert_eq!(m.signals[0].choices.len(), 2);
    let lines: Vec<usize> = r.skipped.iter().map(|s| s.line).collect();
    // BAD signal, comment for NOPE, VAL_ for Z, float type on an 8-bit signal, garbage.
    assert_eq!(lines, [6, 11, 13, 14, 15], "{r}");
}
