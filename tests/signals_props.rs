//! Property tests: the Mapper never panics on arbitrary frames (any mapped or unmapped ID, any
//! length, any bytes, any time order), and its counters always add up.

mod signals_common;

use proptest::prelude::*;
use shimmy::signals::{Mapper, Outcome, Validity};
use shimmy::wire::Frame;
use signals_common::{mapping, reference_db};

fn frame_strategy() -> impl Strategy<Value = (i64, u32, bool, Vec<u8>)> {
    (
        -1_000_000_000i64..1_000_000_000,
        prop_oneof![
            Just(0x0A0u32),
            Just(0x0B0),
            Just(0x0C0),
            Just(0x0D0),
            0u32..0x800
        ],
        any::<bool>(),
        proptest::collection::vec(any::<u8>(), 0..=8),
    )
}

proptest! {
    #![proptest_config(ProptestConfig::with_cases(256))]

    #[test]
    fn arbitrary_frames_never_panic_and_counters_add_up(
        frames in proptest::collection::vec(frame_strategy(), 1..200)
    ) {
        let db = reference_db();
        let mut m = Mapper::new(&db, &mapping("shimmy_reference")).unwrap();
        let (mut accepted, mut rejected, mut ignored) = (0u64, 0u64, 0u64);
        for (t, id, ext, data) in &frames {
            let f = Frame::classic(*t, *id, *ext, data).unwrap();
            match m.on_frame(&f) {
                Some(u) => match u.outcome {
                    Outcome::Accepted(_) => accepted += 1,
                    Outcome::Rejected(_) => rejected += 1,
                },
                None => ignored += 1,
            }
            let s = m.snapshot(*t);
            if let Some(v) = s.steer_angle_rad.valid() {
                prop_assert!(v.is_finite());
                prop_assert_eq!(s.steer_angle_rad.validity, Validity::Valid);
            }
        }
        let st = m.stats();
        prop_assert_eq!(st.iter().map(|s| s.accepted).sum::<u64>(), accepted);
        prop_assert_eq!(st.iter().map(|s| s.rejected()).sum::<u64>(), rejected);
        prop_assert_eq!(st.iter().map(|s| s.frames).sum::<u64>(), accepted + rejected);
        prop_assert_eq!(m.ignored_frames(), ignored);
    }
}
