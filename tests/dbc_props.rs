//! Property tests: encode/decode round trips for arbitrary layouts, no panic on arbitrary
//! payloads or arbitrary DBC text, and the short-frame policy.

use proptest::prelude::*;
use shimmy::dbc::{ByteOrder, Database, RawValue, Signal, ValueKind};

fn kind_strategy() -> impl Strategy<Value = (ValueKind, u64)> {
    prop_oneof![
        (1u64..=64).prop_map(|n| (ValueKind::Unsigned, n)),
        (1u64..=64).prop_map(|n| (ValueKind::Signed, n)),
        Just((ValueKind::Float32, 32)),
        Just((ValueKind::Float64, 64)),
    ]
}

fn raw_for(kind: ValueKind, size: u64, seed: u64) -> RawValue {
    let mask = if size == 64 {
        u64::MAX
    } else {
        (1 << size) - 1
    };
    match kind {
        ValueKind::Unsigned => RawValue::Unsigned(seed & mask),
        ValueKind::Signed => {
            let sh = 64 - size;
            RawValue::Signed(((seed << sh) as i64) >> sh)
        }
        ValueKind::Float32 => RawValue::F32(f32::from_bits(seed as u32)),
        ValueKind::Float64 => RawValue::F64(f64::from_bits(seed)),
    }
}

fn same(a: RawValue, b: RawValue) -> bool {
    match (a, b) {
        (RawValue::F32(x), RawValue::F32(y)) => x.to_bits() == y.to_bits(),
        (RawValue::F64(x), RawValue::F64(y)) => x.to_bits() == y.to_bits(),
        _ => a == b,
    }
}

proptest! {
    #![proptest_config(ProptestConfig::with_cases(2000))]

    /// encode_raw then raw gives the value back, and no other bit of the payload changes.
    #[test]
    fn encode_raw_round_trip(
        (kind, size) in kind_strategy(),
        start in 0u64..512,
        big in any::<bool>(),
        seed in any::<u64>(),
        base in proptest::collection::vec(any::<u8>(), 64),
    ) {
        let order = if big { ByteOrder::BigEndian } else { ByteOrder::LittleEndian };
        let Ok(sig) = Signal::new("s", start, size, order, kind, 1.0, 0.0) else {
            return Ok(()); // does not fit 64 bytes
        };
        let raw = raw_for(kind, size, seed);
        let mut data = base.clone();
        sig.encode_raw(raw, &mut data).unwrap();
        prop_assert!(same(sig.raw(&data).unwrap(), raw));
        // Writing the old bits back restores the original payload exactly.
        let old = raw_for(kind, size, sig.raw_bits(&base).unwrap());
        sig.encode_raw(old, &mut data).unwrap();
        prop_assert_eq!(&data, &base);
        // Too short a payload is reported, not a panic.
        if sig.needed_len() > 0 {
            let mut short = vec![0u8; sig.needed_len() - 1];
            prop_assert!(sig.encode_raw(raw, &mut short).is_err());
            prop_assert!(sig.raw(&short).is_none());
        }
    }

    /// encode_phys then phys returns the value to within half a scaling step, including
    /// negative factors.
    #[test]
    fn encode_phys_round_trip(
        size in 2u64..=32,
        signed in any::<bool>(),
        start in 0u64..32,
        big in any::<bool>(),
        factor in prop_oneof![0.001f64..10.0, -10.0f64..-0.001],
        offset in -100.0f64..100.0,
        frac in 0.0f64..1.0,
    ) {
        let order = if big { ByteOrder::BigEndian } else { ByteOrder::LittleEndian };
        let kind = if signed { ValueKind::Signed } else { ValueKind::Unsigned };
        let Ok(sig) = Signal::new("s", start, size, order, kind, factor, offset) else {
            return Ok(());
        };
        let (lo, hi) = if signed {
            (-(1i64 << (size - 1)) as f64, ((1i64 << (size - 1)) - 1) as f64)
        } else {
            (0.0, ((1u64 << size) - 1) as f64)
        };
        let raw = lo + (hi - lo) * frac;
        let value = raw * factor + offset;
        let mut data = [0u8; 8];
        sig.encode_phys(value, &mut data).unwrap();
        let back = sig.phys(&data).unwrap();
        prop_assert!((back - value).abs() <= factor.abs() * 0.5 + 1e-9 * value.abs());
        // Far outside the representable range is an error, not a wrapped value.
        prop_assert!(sig.encode_phys(offset + factor * (hi + 2.0), &mut data).is_err());
    }

}

proptest! {
    #![proptest_config(ProptestConfig::with_cases(300))]

    /// Arbitrary DBC-like text never panics the loader.
    #[test]
    fn parse_arbitrary_text_never_panics(text in "(BO_ 1 M: 8 A\n|SG_|\n SG_ S : 0\\|8@1\\+ \\(1,0\\) \\[0\\|0\\] \"\" A|M |m1 |m2M |CM_|VAL_|SG_MUL_VAL_ 1 S M 1-2;|SIG_VALTYPE_ 1 S : 1;|BA_|NS_|BU_|[ \\t\\n:;|@+\\-\"(),\\[\\]0-9a-zA-Z_]){0,300}") {
        let (db, report) = Database::parse(&text);
        prop_assert_eq!(report.messages, db.messages().len());
        // Whatever loaded also decodes any payload without panicking.
        for m in db.messages() {
            for len in [0usize, 3, 8, 64] {
                let _ = m.decode(&[0xA5u8; 64][..len], |_, _, _| {});
            }
        }
    }

    #[test]
    fn parse_arbitrary_unicode_never_panics(text in any::<String>()) {
        let _ = Database::parse(&text);
    }
}

/// A small database with simple and cascaded multiplexing, plain signals past the declared
/// length, a float and a 64-bit signal: arbitrary payloads of every length decode without
/// panicking, and the counts add up.
const MIXED: &str = "VERSION \"\"\n\
BO_ 100 MUXED: 8 A\n\
 SG_ SW M : 0|4@1+ (1,0) [0|0] \"\" B\n\
 SG_ INNER m1M : 4|4@1+ (1,0) [0|0] \"\" B\n\
 SG_ DEEP m3 : 8|8@1- (-0.5,1) [0|0] \"\" B\n\
 SG_ OTHER m2 : 23|16@0+ (1,0) [0|0] \"\" B\n\
 SG_ PLAIN : 40|24@1- (1,0) [0|0] \"\" B\n\
BO_ 2147483848 FD: 64 A\n\
 SG_ F : 7|32@0- (1,0) [0|0] \"\" B\n\
 SG_ D : 64|64@1- (1,0) [0|0] \"\" B\n\
 SG_ TAIL : 500|12@1+ (1,0) [0|0] \"\" B\n\
SIG_VALTYPE_ 2147483848 F : 1;\n\
SIG_VALTYPE_ 2147483848 D : 2;\n\
SG_MUL_VAL_ 100 DEEP INNER 3-3;\n\
SG_MUL_VAL_ 100 INNER SW 1-1;\n\
SG_MUL_VAL_ 100 OTHER SW 2-5;\n";

proptest! {
    /// The message decode loop (one-word fast path for classic frames) agrees with
    /// `Signal::raw` (byte-window path) for every layout, and flags exactly the signals that
    /// do not fit.
    #[test]
    fn message_decode_agrees_with_signal_raw(
        (kind, size) in kind_strategy(),
        start in 0u64..64,
        big in any::<bool>(),
        data in proptest::collection::vec(any::<u8>(), 0..=12),
    ) {
        let order = if big { ByteOrder::BigEndian } else { ByteOrder::LittleEndian };
        let Ok(sig) = Signal::new("s", start, size, order, kind, 0.5, -3.0) else {
            return Ok(());
        };
        let mut m = shimmy::dbc::Message::new("M", 1, false, 8);
        m.signals.push(sig.clone());
        let db = Database::from_messages(vec![m]).unwrap();
        let m = &db.messages()[0];
        let mut got = None;
        let s = m.decode(&data, |_, raw, phys| got = Some((raw, phys))).unwrap();
        match sig.raw(&data) {
            Some(want) => {
                let (raw, phys) = got.unwrap();
                prop_assert!(same(raw, want));
                let p = want.as_f64() * 0.5 - 3.0;
                prop_assert!(phys == p || (phys.is_nan() && p.is_nan()));
                prop_assert_eq!(s.decoded, 1);
            }
            None => {
                prop_assert!(got.is_none());
                prop_assert_eq!(s.truncated, 1);
            }
        }
    }

    /// Messages of several signals (the all-integer word path when every signal is an integer
    /// fitting an `i64` and the payload holds them all; the per-signal path otherwise) deliver,
    /// signal by signal, exactly what `Signal::raw` and the scaling give.
    #[test]
    fn multi_signal_decode_agrees_with_signal_raw(
        sigs in proptest::collection::vec(
            (kind_strategy(), 0u64..64, any::<bool>(), -4.0f64..4.0, -100.0f64..100.0),
            1..6,
        ),
        data in proptest::collection::vec(any::<u8>(), 0..=8),
    ) {
        let mut m = shimmy::dbc::Message::new("M", 1, false, 8);
        for (k, ((kind, size), start, big, factor, offset)) in sigs.iter().enumerate() {
            let order = if *big { ByteOrder::BigEndian } else { ByteOrder::LittleEndian };
            if let Ok(s) = Signal::new(&format!("s{k}"), *start, *size, order, *kind, *factor, *offset) {
                if s.needed_len() <= 8 {
                    m.signals.push(s);
                }
            }
        }
        let want: Vec<_> = m.signals.clone();
        let db = Database::from_messages(vec![m]).unwrap();
        let m = &db.messages()[0];
        let mut got = Vec::new();
        let s = m.decode(&data, |i, raw, phys| got.push((i, raw, phys))).unwrap();
        let mut k = 0;
        for (i, sig) in want.iter().enumerate() {
            if let Some(raw) = sig.raw(&data) {
                let (gi, graw, gphys) = got[k];
                k += 1;
                prop_assert_eq!(gi, i);
                prop_assert!(same(graw, raw));
                let p = sig.scale(raw);
                prop_assert!(gphys.to_bits() == p.to_bits() || (gphys.is_nan() && p.is_nan()));
            }
        }
        prop_assert_eq!(k, got.len());
        prop_assert_eq!(s.decoded as usize + s.truncated as usize, want.len());
    }

    #[test]
    fn decode_arbitrary_payload_never_panics(data in proptest::collection::vec(any::<u8>(), 0..=64)) {
        let (db, report) = Database::parse(MIXED);
        prop_assert!(report.skipped.is_empty(), "{}", report);
        for m in db.messages() {
            match m.decode(&data, |_, _, _| {}) {
                Ok(s) => prop_assert_eq!(
                    (s.decoded + s.truncated + s.not_selected) as usize,
                    m.signals.len()
                ),
                Err(_) => prop_assert!(m.is_multiplexed()),
            }
        }
    }
}

#[test]
fn cascaded_multiplexing_selects_by_path() {
    let (db, _) = Database::parse(MIXED);
    let m = db.message(100, false).unwrap();
    let names = |data: &[u8]| {
        let mut v = Vec::new();
        m.decode(data, |i, _, p| v.push((m.signals[i].name.clone(), p)))
            .map(|_| v)
    };
    // SW=1, INNER=3 -> DEEP present; raw 0xFE = -2 -> phys -2 * -0.5 + 1 = 2.
    let got = names(&[0x31, 0xFE, 0, 0, 0, 0, 0, 0]).unwrap();
    let n: Vec<&str> = got.iter().map(|(s, _)| s.as_str()).collect();
    assert_eq!(n, ["SW", "INNER", "DEEP", "PLAIN"]);
    assert_eq!(got[2].1, 2.0);
    // SW=4 -> OTHER (range 2-5), INNER absent.
    let n: Vec<String> = names(&[0x04, 0, 0, 0, 0, 0, 0, 0])
        .unwrap()
        .into_iter()
        .map(|x| x.0)
        .collect();
    assert_eq!(n, ["SW", "OTHER", "PLAIN"]);
    // SW=1 but INNER=2 selects nothing: refused, like cantools.
    assert!(names(&[0x21, 0, 0, 0, 0, 0, 0, 0]).is_err());
    // SW=9: refused.
    assert!(names(&[0x09, 0, 0, 0, 0, 0, 0, 0]).is_err());
}

#[test]
fn short_frame_decodes_what_fits_and_counts_the_rest() {
    let (db, _) = Database::parse(MIXED);
    let m = db.message(100, false).unwrap();
    // 2 bytes: SW and INNER and DEEP fit; PLAIN (bytes 5..8) does not.
    let mut seen = Vec::new();
    let s = m
        .decode(&[0x31, 0x02], |i, _, _| {
            seen.push(m.signals[i].name.clone())
        })
        .unwrap();
    assert_eq!(seen, ["SW", "INNER", "DEEP"]);
    assert_eq!((s.decoded, s.truncated, s.not_selected), (3, 1, 1));
    // Empty payload: nothing fits; the switch-dependent signals count as truncated too.
    let s = m.decode(&[], |_, _, _| panic!("nothing fits")).unwrap();
    assert_eq!(s.truncated as usize, m.signals.len());

    // CAN FD: a 64-byte message, float and double, and a signal at the very end.
    let fd = db.message(200, true).unwrap();
    let mut data = [0u8; 64];
    fd.signals[0].encode_phys(-1.25, &mut data).unwrap();
    fd.signals[1].encode_phys(1e300, &mut data).unwrap();
    fd.signals[2].encode_phys(4095.0, &mut data).unwrap();
    let mut got = Vec::new();
    fd.decode(&data, |_, _, p| got.push(p)).unwrap();
    assert_eq!(got, [-1.25, 1e300, 4095.0]);
    // Only 12 bytes (FD DLC 9): the double and the tail signal are flagged.
    let s = fd.decode(&data[..12], |_, _, _| {}).unwrap();
    assert_eq!((s.decoded, s.truncated), (1, 2));
}
