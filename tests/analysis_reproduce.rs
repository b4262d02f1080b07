//! End to end: `shimmy reproduce --quick --out <tmp>` writes REPRODUCTION.md with a row for
//! every claim of the article, a verdict in each, and every figure it links, all small.

use shimmy::cli::reproduce::CLAIM_IDS;
use std::process::Command;

#[test]
fn quick_reproduction_writes_every_claim_and_figure() {
    let tmp = tempfile::tempdir().unwrap();
    let out = tmp.path().to_path_buf();
    let status = Command::new(env!("CARGO_BIN_EXE_shimmy"))
        .args(["reproduce", "--quick", "--out"])
        .arg(&out)
        .status()
        .expect("running shimmy reproduce");
    assert!(
        status.success(),
        "shimmy reproduce --quick failed: {status}"
    );

    let doc = std::fs::read_to_string(out.join("REPRODUCTION.md")).expect("REPRODUCTION.md");
    for id in CLAIM_IDS {
        let row = doc
            .lines()
            .find(|l| l.starts_with(&format!("| {id} |")))
            .unwrap_or_else(|| panic!("no row for claim {id}"));
        // 7 columns: # | § | claim | article | ours | verdict | why.
        let cells: Vec<&str> = row.trim_matches('|').split(" | ").collect();
        assert_eq!(
            cells.len(),
            7,
            "claim {id} row has {} cells: {row}",
            cells.len()
        );
        let verdict = cells[5].trim();
        assert!(
            ["**holds**", "**partly**", "**not**", "not run"].contains(&verdict),
            "claim {id} verdict {verdict:?}"
        );
        assert!(
            !cells[4].trim().is_empty() && cells[4].trim() != "–" || verdict == "not run",
            "claim {id} has no number: {row}"
        );
    }
    for section in [
        "Time-step convergence",
        "Clearance sweep",
        "Dual versus single",
        "Speed sweep",
        "X versus Y",
        "Stiffness",
    ] {
        assert!(doc.contains(section), "missing section {section}");
    }

    // Every linked figure exists, is an SVG, and the set is small.
    let mut total = 0u64;
    let mut figures = 0;
    for part in doc.split("](reproduction/").skip(1) {
        let name = &part[..part.find(')').unwrap()];
        let path = out.join("reproduction").join(name);
        let text =
            std::fs::read_to_string(&path).unwrap_or_else(|_| panic!("missing figure {name}"));
        assert!(
            text.starts_with("<svg") && text.contains("</svg>"),
            "{name} is not an SVG"
        );
        total += text.len() as u64;
        figures += 1;
    }
    assert!(figures >= 10, "only {figures} figures linked");
    assert!(total < 2 * 1024 * 1024, "figures total {total} bytes");
}
