//! The real RAV4 log decodes exactly as `expected_decoded_bus0.csv` says (all 59,688 rows), with
//! `toyota_new_mc_pt_generated.dbc`.
//!
//! The log is read with a minimal `candump -L` line split here (timestamp text, ID, hex data);
//! the full candump grammar is the log reader's business and tested there.

use shimmy::dbc::Database;

struct LogFrame<'a> {
    ts: &'a str,
    id: u32,
    data: Vec<u8>,
}

fn parse_line(line: &str) -> Option<LogFrame<'_>> {
    let mut it = line.split_whitespace();
    let ts = it.next()?.strip_prefix('(')?.strip_suffix(')')?;
    let _iface = it.next()?;
    let (id, hex) = it.next()?.split_once('#')?;
    let data = (0..hex.len() / 2)
        .map(|i| u8::from_str_radix(&hex[2 * i..2 * i + 2], 16).ok())
        .collect::<Option<Vec<u8>>>()?;
    Some(LogFrame {
        ts,
        id: u32::from_str_radix(id, 16).ok()?,
        data,
    })
}

#[test]
fn rav4_log_matches_expected_csv() {
    let (Some(log), Some(csv), Some(dbc)) = (
        shimmy::shared_data::require_file("logs/comma2k19-rav4/rav4_2017_seg40_bus0.log"),
        shimmy::shared_data::require_file("logs/comma2k19-rav4/expected_decoded_bus0.csv"),
        shimmy::shared_data::require_file("dbc/opendbc/toyota_new_mc_pt_generated.dbc"),
    ) else {
        return;
    };
    let (db, _) = Database::load(dbc).unwrap();
    let log = std::fs::read_to_string(log).unwrap();
    let csv = std::fs::read_to_string(csv).unwrap();

    // Rows grouped by frame, in file order: (timestamp, id, message, [(signal, value)]).
    type Group = (String, u32, String, Vec<(String, f64)>);
    let mut groups: Vec<Group> = Vec::new();
    for row in csv.lines().skip(1) {
        let f: Vec<&str> = row.split(',').collect();
        assert_eq!(f.len(), 5, "bad CSV row {row}");
        let id = u32::from_str_radix(f[1], 16).unwrap();
        let value: f64 = f[4].parse().unwrap();
        match groups.last_mut() {
            Some(g) if g.0 == f[0] && g.1 == id => g.3.push((f[3].to_string(), value)),
            _ => groups.push((
                f[0].to_string(),
                id,
                f[2].to_string(),
                vec![(f[3].to_string(), value)],
            )),
        }
    }
    let wanted_ids: Vec<u32> = {
        let mut v: Vec<u32> = groups.iter().map(|g| g.1).collect();
        v.sort_unstable();
        v.dedup();
        v
    };

    let mut next = 0usize;
    let mut rows = 0usize;
    for line in log.lines() {
        let Some(fr) = parse_line(line) else { continue };
        if !wanted_ids.contains(&fr.id) {
            continue;
        }
        let g = &groups[next];
        assert_eq!((fr.ts, fr.id), (g.0.as_str(), g.1), "frame order differs");
        next += 1;
        let msg = db.message(fr.id, false).expect("message in DBC");
        assert_eq!(msg.name, g.2);
        let mut decoded: Vec<(usize, f64)> = Vec::new();
        let sum = msg
            .decode(&fr.data, |i, _raw, phys| decoded.push((i, phys)))
            .unwrap();
        assert_eq!(sum.truncated, 0, "{line}");
        for (sig, want) in &g.3 {
            let idx = msg.signal_by_name(sig).unwrap();
            let got = decoded.iter().find(|(i, _)| *i == idx).unwrap().1;
            assert!(
                (got - want).abs() <= 1e-9 * want.abs().max(1.0),
                "{line}: {sig} = {got}, expected {want}"
            );
            rows += 1;
        }
    }
    assert_eq!(next, groups.len(), "every CSV frame found in the log");
    assert_eq!(rows, 59_688);
}
