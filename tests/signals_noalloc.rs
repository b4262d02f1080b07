//! The per-frame path of the Mapper allocates nothing: counted with a global allocator wrapper
//! over a realistic mix of good, corrupted, repeated, short and unmapped frames.

mod signals_common;

use shimmy::signals::checksum::ChecksumKind;
use shimmy::signals::Mapper;
use shimmy::wire::Frame;
use signals_common::{mapping, reference_db};

#[path = "support/counting_alloc.rs"]
mod counting_alloc;
use counting_alloc::allocations;

#[test]
fn on_frame_and_snapshot_do_not_allocate() {
    let db = reference_db();
    let mut m = Mapper::new(&db, &mapping("shimmy_reference")).unwrap();
    let msg = |name: &str| db.messages()[db.message_by_name(name).unwrap()].clone();
    let (sas, veh, brk) = (msg("SAS_01"), msg("VEH_01"), msg("BRK_01"));
    // Pre-build every frame (building them allocates; interpreting them must not).
    let mut frames = Vec::new();
    for k in 0..5000i64 {
        let t = k * 10_000_000;
        for (m, every) in [(&sas, 1), (&veh, 2), (&brk, 2)] {
            if k % every != 0 {
                continue;
            }
            let mut d = [0u8; 8];
            let c = (k / every) as f64 % 16.0;
            let cs = m
                .signals
                .iter()
                .find(|s| s.name.ends_with("_Counter"))
                .unwrap();
            cs.encode_phys(c, &mut d).unwrap();
            m.signals[0]
                .encode_phys((k % 100) as f64 * 0.1, &mut d)
                .unwrap();
            ChecksumKind::Shimmy.apply(m.id, &mut d).unwrap();
            if k % 97 == 0 {
                d[3] ^= 0x20; // corrupted
            }
            let len = if k % 389 == 0 { 3 } else { 8 }; // short
            frames.push(Frame::classic(t, m.id, false, &d[..len]).unwrap());
        }
        frames.push(Frame::classic(t, 0x7DF, false, &[0; 8]).unwrap()); // unmapped
    }
    let mut accepted = 0u64;
    let before = allocations();
    for f in &frames {
        if let Some(u) = m.on_frame(f) {
            accepted += matches!(u.outcome, shimmy::signals::Outcome::Accepted(_)) as u64;
        }
        let s = m.snapshot(f.t_ns);
        std::hint::black_box(s);
    }
    m.advance(1_000_000_000_000);
    let after = allocations();
    assert_eq!(after - before, 0, "allocations on the per-frame path");
    assert!(accepted > 9000, "{accepted}");
    let st = m.stats();
    assert!(st.iter().map(|s| s.checksum_errors).sum::<u64>() > 0);
    assert!(st.iter().all(|s| s.timeouts == 1));
}
