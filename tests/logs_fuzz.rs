//! Property tests: no reader panics on any input (arbitrary bytes, and inputs built from each
//! format's own vocabulary so the fuzzing reaches deep into the parsers), every delivered
//! frame is well-formed, and the candump writer and parser round-trip every frame.

use proptest::prelude::*;
use shimmy::source::log::{LogFormat, LogReader};
use shimmy::source::CanSource;
use shimmy::wire::candump::{parse_line, write_frame, Parsed};
use shimmy::wire::frame::{fd_dlc_to_len, fd_len_to_dlc};
use shimmy::wire::{Frame, FrameKind};

/// Drain a reader over `bytes`; check what it delivers is well-formed and all is counted.
fn drain_checked(bytes: Vec<u8>, format: LogFormat) {
    let mut r = LogReader::with_format(Box::new(std::io::Cursor::new(bytes)), "fuzz", format);
    let mut n = 0u64;
    while let Some(f) = r.next_frame().expect("in-memory reads do not fail") {
        n += 1;
        if f.fd {
            assert!(f.len <= 64);
            assert_eq!(fd_dlc_to_len(fd_len_to_dlc(f.len as usize)), f.len as usize);
        } else {
            assert!(f.len <= 8, "{f:?}");
            assert!(f.dlc <= 15);
        }
        if !f.extended && f.kind != FrameKind::Error {
            assert!(f.id <= 0x7FF);
        }
        assert!(f.id <= 0x1FFF_FFFF);
    }
    let st = r.stats();
    assert_eq!(st.frames, n);
    assert!(r.take_skips().len() as u64 <= st.malformed + st.skipped);
}

fn candump_vocab() -> impl Strategy<Value = String> {
    let tok = prop_oneof![
        Just("(".to_string()),
        Just(")".to_string()),
        Just("#".to_string()),
        Just("##".to_string()),
        Just("###".to_string()),
        Just("R".to_string()),
        Just("_".to_string()),
        Just(".".to_string()),
        Just(" ".to_string()),
        Just("\t".to_string()),
        Just("\r\n".to_string()),
        Just("\n".to_string()),
        Just("can0".to_string()),
        Just("DROPCOUNT".to_string()),
        Just("20000080".to_string()),
        "[0-9]{1,13}",
        "[0-9a-fA-F]{1,9}",
        "[0-9a-fA-F]{0,140}",
        "\\PC{0,3}",
    ];
    prop::collection::vec(tok, 0..24).prop_map(|v| v.concat())
}

fn asc_vocab() -> impl Strategy<Value = String> {
    let tok = prop_oneof![
        Just("date Thu Jan 01 12:53:28.584 1970\n".to_string()),
        Just("base dec timestamps relative\n".to_string()),
        Just("base hex  timestamps absolute\n".to_string()),
        Just("Begin Triggerblock Sat Sep 30 10:06:13.191 PM 2017\n".to_string()),
        Just("End TriggerBlock\n".to_string()),
        Just("CANFD".to_string()),
        Just("ErrorFrame".to_string()),
        Just("Rx".to_string()),
        Just("Tx".to_string()),
        Just("d".to_string()),
        Just("r".to_string()),
        Just("x".to_string()),
        Just(" ".to_string()),
        Just("\n".to_string()),
        "[0-9]{1,14}(\\.[0-9]{0,10})?",
        "[0-9a-fA-F]{1,9}x?",
        "[0-9]{1,3}",
        "\\PC{0,4}",
    ];
    prop::collection::vec(tok, 0..40).prop_map(|v| v.join(" "))
}

fn trc_vocab() -> impl Strategy<Value = String> {
    let tok = prop_oneof![
        Just(";$FILEVERSION=1.1\n".to_string()),
        Just(";$FILEVERSION=1.3\n".to_string()),
        Just(";$FILEVERSION=2.0\n".to_string()),
        Just(";$FILEVERSION=2.1\n".to_string()),
        Just(";$STARTTIME=44548.6028595139\n".to_string()),
        Just(";$COLUMNS=N,O,T,B,I,d,R,L,D\n".to_string()),
        Just(";$COLUMNS=N,O,T,I,d,l,D\n".to_string()),
        Just(";$COLUMNS=D,O,T,I\n".to_string()),
        prop::sample::select(vec![
            "DT", "FD", "FB", "FE", "BI", "RR", "ER", "ST", "Rx", "Tx", "Warng", "RTR", "-", "--"
        ])
        .prop_map(str::to_string),
        Just(")".to_string()),
        Just(" ".to_string()),
        Just("\n".to_string()),
        "[0-9]{1,14}(\\.[0-9]{0,8})?\\)?",
        "[0-9a-fA-F]{1,9}",
        "[0-9]{1,3}",
        "\\PC{0,4}",
    ];
    prop::collection::vec(tok, 0..40).prop_map(|v| v.join(" "))
}

/// A BLF built from object headers with arbitrary (often inconsistent) fields, inside
/// containers that are compressed, stored, or garbage.
fn blf_bytes() -> impl Strategy<Value = Vec<u8>> {
    let object = (
        prop::sample::select(vec![1u32, 2, 10, 65, 73, 86, 100, 101, 999]),
        prop::sample::select(vec![1u16, 2, 3]),
        0u32..300,
        prop::collection::vec(any::<u8>(), 0..200),
    )
        .prop_map(|(ty, ver, size, body)| {
            let mut v = b"LOBJ".to_vec();
            v.extend_from_slice(&32u16.to_le_bytes());
            v.extend_from_slice(&ver.to_le_bytes());
            v.extend_from_slice(&size.to_le_bytes());
            v.extend_from_slice(&ty.to_le_bytes());
            v.extend_from_slice(&body);
            v
        });
    let container = (prop::collection::vec(object, 0..6), 0u8..3, any::<u32>()).prop_map(
        |(objs, mode, bogus)| {
            use std::io::Write;
            let payload = objs.concat();
            let data = match mode {
                0 => payload.clone(),
                1 => {
                    let mut e =
                        flate2::write::ZlibEncoder::new(Vec::new(), flate2::Compression::fast());
                    e.write_all(&payload).unwrap();
                    e.finish().unwrap()
                }
                _ => payload.clone(), // claimed compressed, but stored
            };
            let method: u16 = if mode == 0 { 0 } else { 2 };
            let usize_ = if mode == 2 {
                bogus
            } else {
                payload.len() as u32
            };
            let size = 32 + data.len();
            let mut v = b"LOBJ".to_vec();
            v.extend_from_slice(&16u16.to_le_bytes());
            v.extend_from_slice(&1u16.to_le_bytes());
            v.extend_from_slice(&(size as u32).to_le_bytes());
            v.extend_from_slice(&10u32.to_le_bytes());
            v.extend_from_slice(&method.to_le_bytes());
            v.extend_from_slice(&[0; 6]);
            v.extend_from_slice(&usize_.to_le_bytes());
            v.extend_from_slice(&[0; 4]);
            v.extend_from_slice(&data);
            v.extend(std::iter::repeat_n(0u8, size % 4));
            v
        },
    );
    (
        prop::collection::vec(container, 0..4),
        prop::collection::vec(any::<u8>(), 0..40),
        any::<bool>(),
    )
        .prop_map(|(cs, junk, junk_first)| {
            let mut h = vec![0u8; 144];
            h[..4].copy_from_slice(b"LOGG");
            h[4..8].copy_from_slice(&144u32.to_le_bytes());
            if junk_first {
                h.extend_from_slice(&junk);
            }
            for c in cs {
                h.extend(c);
            }
            if !junk_first {
                h.extend_from_slice(&junk);
            }
            h
        })
}

/// Any frame the candump format can hold, in its canonical form.
fn frame() -> impl Strategy<Value = Frame> {
    let classic = (
        any::<bool>(),
        any::<u32>(),
        prop::collection::vec(any::<u8>(), 0..=8),
        9u8..=15,
        any::<bool>(),
    )
        .prop_map(|(ext, id, data, dlc, raw_dlc)| {
            let id = if ext { id & 0x1FFF_FFFF } else { id & 0x7FF };
            let mut f = Frame::classic(0, id, ext, &data).unwrap();
            if data.len() == 8 && raw_dlc {
                f.dlc = dlc;
            }
            f
        });
    let remote = (
        any::<bool>(),
        any::<u32>(),
        0u8..=8,
        9u8..=15,
        any::<bool>(),
    )
        .prop_map(|(ext, id, len, dlc, raw_dlc)| {
            let id = if ext { id & 0x1FFF_FFFF } else { id & 0x7FF };
            let mut f = Frame::classic(0, id, ext, &[]).unwrap();
            f.kind = FrameKind::Remote;
            f.len = len;
            f.dlc = if len == 8 && raw_dlc { dlc } else { len };
            f
        });
    let fd = (
        any::<bool>(),
        any::<u32>(),
        0u8..16,
        any::<bool>(),
        any::<bool>(),
        prop::collection::vec(any::<u8>(), 64),
    )
        .prop_map(|(ext, id, dlc, brs, esi, data)| {
            let id = if ext { id & 0x1FFF_FFFF } else { id & 0x7FF };
            let mut f = Frame::fd(0, id, ext, &data[..fd_dlc_to_len(dlc)]).unwrap();
            f.brs = brs;
            f.esi = esi;
            f
        });
    let error = (any::<u32>(), prop::collection::vec(any::<u8>(), 0..=8)).prop_map(|(id, d)| {
        let mut f = Frame::classic(0, id & 0x1FFF_FFFF, false, &d).unwrap();
        f.kind = FrameKind::Error;
        f
    });
    (
        prop_oneof![classic, remote, fd, error],
        0i64..=i64::MAX,
        any::<bool>(),
        "[a-z][a-z0-9_]{0,14}",
    )
        .prop_map(|(mut f, t, whole_us, iface)| {
            f.t_ns = if whole_us { t / 1000 * 1000 } else { t };
            f.set_iface(&iface);
            f
        })
}

proptest! {
    #![proptest_config(ProptestConfig { cases: 512, ..ProptestConfig::default() })]

    #[test]
    fn candump_parse_line_never_panics(bytes in prop::collection::vec(any::<u8>(), 0..300)) {
        let _ = parse_line(&bytes);
    }

    #[test]
    fn candump_parse_line_never_panics_on_near_valid_lines(s in candump_vocab()) {
        let _ = parse_line(s.as_bytes());
    }

    #[test]
    fn candump_writer_and_parser_round_trip(f in frame()) {
        let mut out = Vec::new();
        write_frame(&mut out, &f).unwrap();
        prop_assert_eq!(*out.last().unwrap(), b'\n');
        let back = parse_line(&out);
        prop_assert_eq!(back, Ok(Parsed::Frame(f)), "line {:?}", String::from_utf8_lossy(&out));
    }

    #[test]
    fn log_reader_survives_arbitrary_bytes(
        bytes in prop::collection::vec(any::<u8>(), 0..2000),
        which in 0u8..4,
    ) {
        let format =
            [LogFormat::Candump, LogFormat::Asc, LogFormat::Blf, LogFormat::Trc][which as usize];
        drain_checked(bytes, format);
    }

    #[test]
    fn candump_reader_survives_near_valid_files(s in candump_vocab()) {
        drain_checked(s.into_bytes(), LogFormat::Candump);
    }

    #[test]
    fn asc_reader_survives_near_valid_files(s in asc_vocab()) {
        drain_checked(s.into_bytes(), LogFormat::Asc);
    }

    #[test]
    fn trc_reader_survives_near_valid_files(s in trc_vocab()) {
        drain_checked(s.into_bytes(), LogFormat::Trc);
    }

    #[test]
    fn blf_reader_survives_inconsistent_objects(b in blf_bytes()) {
        drain_checked(b, LogFormat::Blf);
    }
}

#[test]
fn blf_reader_survives_every_truncation_and_bit_flip_of_a_real_file() {
    let Some(p) = shimmy::shared_data::require_file("logs/python-can/test_data/issue_1905.blf")
    else {
        return;
    };
    let bytes = std::fs::read(p).unwrap();
    for cut in 0..bytes.len() {
        drain_checked(bytes[..cut].to_vec(), LogFormat::Blf);
    }
    for i in 0..bytes.len() {
        let mut b = bytes.clone();
        b[i] ^= 0x5A;
        drain_checked(b, LogFormat::Blf);
    }
}

/// Found by the `asc` fuzz target (tests/fuzz): a `CANFD` line whose data length is not a
/// CAN FD length (here 60) was delivered as a frame of 60 bytes with the DLC of 64. It is
/// malformed: counted and reported, not delivered.
#[test]
fn asc_canfd_line_with_a_length_no_fd_frame_has_is_malformed() {
    let mut text =
        String::from("date Sat Sep 30 15:06:13.191 2017\nbase hex  timestamps absolute\n");
    text.push_str("Begin Triggerblock Sat Sep 30 15:06:13.191 2017\n");
    for len in [60usize, 64, 9, 12] {
        let bytes: Vec<String> = (0..len).map(|i| format!("{:02X}", i as u8)).collect();
        text.push_str(&format!(
            "   0.100000 CANFD   1 Rx        300                                   0 0 f {len} {}\n",
            bytes.join(" ")
        ));
    }
    text.push_str("End TriggerBlock\n");
    let mut r = LogReader::with_format(
        Box::new(std::io::Cursor::new(text.clone().into_bytes())),
        "fd.asc",
        LogFormat::Asc,
    );
    let mut lens = Vec::new();
    while let Some(f) = r.next_frame().unwrap() {
        assert!(f.fd);
        assert_eq!(fd_dlc_to_len(f.dlc), f.len as usize, "{f:?}");
        lens.push(f.len);
    }
    assert_eq!(lens, [64, 12], "only the lengths an FD frame can have");
    assert_eq!(r.stats().malformed, 2);
    let skips = r.take_skips();
    assert!(
        skips
            .iter()
            .any(|s| s.reason.contains("bad data length \"60\"")),
        "{skips:?}"
    );
    drain_checked(text.into_bytes(), LogFormat::Asc);
}
