//! The decode path allocates nothing per frame: a counting global allocator sees no allocation
//! while message lookup + decode run over real frames (classic and multiplexed).

use shimmy::dbc::Database;

#[path = "support/counting_alloc.rs"]
mod counting_alloc;
use counting_alloc::allocations;

#[test]
fn decode_allocates_nothing() {
    let (Some(dbc), Some(mux), Some(log)) = (
        shimmy::shared_data::require_file("dbc/opendbc/toyota_new_mc_pt_generated.dbc"),
        shimmy::shared_data::require_file("dbc/cantools/multiplex_2.dbc"),
        shimmy::shared_data::require_file("logs/comma2k19-rav4/rav4_2017_seg40_bus0.log"),
    ) else {
        return;
    };
    let (db, _) = Database::load(dbc).unwrap();
    let (mdb, _) = Database::load(mux).unwrap();
    // Frames prepared up front: (id, payload).
    let frames: Vec<(u32, Vec<u8>)> = std::fs::read_to_string(log)
        .unwrap()
        .lines()
        .filter_map(|l| {
            let (id, hex) = l.split_whitespace().nth(2)?.split_once('#')?;
            let data = (0..hex.len() / 2)
                .map(|i| u8::from_str_radix(&hex[2 * i..2 * i + 2], 16).unwrap())
                .collect();
            Some((u32::from_str_radix(id, 16).ok()?, data))
        })
        .collect();
    let payloads: Vec<[u8; 8]> = (0u64..2000)
        .map(|i| (i.wrapping_mul(0x9E37_79B9_7F4A_7C15)).to_le_bytes())
        .collect();

    let before = allocations();
    let mut acc = 0.0;
    let mut decoded = 0u64;
    for (id, data) in &frames {
        if let Some(i) = db.message_index(*id, false) {
            let _ = db.messages()[i].decode(data, |_, _, p| acc += p);
            decoded += 1;
        }
    }
    for m in mdb.messages() {
        for p in &payloads {
            let _ = m.decode(&p[..m.size_bytes.min(8)], |_, _, v| acc += v);
        }
    }
    let after = allocations();
    assert!(decoded > 30_000);
    assert!(acc.is_finite() || acc.is_nan());
    assert_eq!(after - before, 0, "decode allocated");
}
