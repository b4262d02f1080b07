//! Vector ASC and BLF reading: the RAV4 drive in all three formats gives identical frames,
//! python-can's fixtures read as their text says, and a synthetic BLF exercises what the
//! real files do not (objects straddling containers, header v2, 10 µs timestamps, CAN FD,
//! remote frames, a corrupt container that must not stop the replay).

use shimmy::shared_data::require_file;
use shimmy::source::log::{LogFormat, LogReader};
use shimmy::source::{CanSource, SourceStats};
use shimmy::wire::{Frame, FrameKind};

fn read_all(r: &mut LogReader) -> Vec<Frame> {
    let mut v = Vec::new();
    while let Some(f) = r.next_frame().unwrap() {
        v.push(f);
    }
    v
}

fn open(rel: &str) -> Option<(Vec<Frame>, SourceStats, LogReader)> {
    let p = require_file(rel)?;
    let mut r = LogReader::open(p).unwrap();
    let f = read_all(&mut r);
    let s = r.stats();
    Some((f, s, r))
}

/// The candump, ASC and BLF versions of the RAV4 log hold the same 53,800 frames.
///
/// Timestamps: candump stores the logger's clock (46408.584930 s for the first frame); the
/// ASC header stores the start only to the millisecond ("12:53:28.584") with offsets from
/// there; the BLF header leaves its start empty (python-can writes no SYSTEMTIME before 1990),
/// so its times are offsets from an unstated epoch, stored in ns after a float conversion
/// (e.g. 12999 ns for 13 µs). So we compare each frame's time relative to the first frame,
/// rounded to the microsecond, the resolution all three share.
#[test]
fn rav4_candump_asc_blf_give_identical_frames() {
    let base = "logs/comma2k19-rav4/rav4_2017_seg40_bus0";
    let Some((cd, cd_st, _)) = open(&format!("{base}.log")) else {
        return;
    };
    let Some((asc, asc_st, asc_r)) = open(&format!("{base}.asc")) else {
        return;
    };
    let Some((blf, blf_st, blf_r)) = open(&format!("{base}.blf")) else {
        return;
    };
    assert_eq!(asc_r.format(), LogFormat::Asc);
    assert_eq!(blf_r.format(), LogFormat::Blf);
    for st in [&cd_st, &asc_st, &blf_st] {
        assert_eq!(st.frames, 53_800);
        assert_eq!(st.malformed, 0);
        assert_eq!(st.skipped, 0);
    }
    assert_eq!(asc_r.start_epoch_ns(), Some(46_408_584_000_000));
    let rel_us = |f: &Frame, first: &Frame| ((f.t_ns - first.t_ns) as f64 / 1000.0).round() as i64;
    for (i, ((a, b), c)) in cd.iter().zip(&asc).zip(&blf).enumerate() {
        for (name, other, first) in [("asc", b, &asc[0]), ("blf", c, &blf[0])] {
            let same = a.id == other.id
                && a.extended == other.extended
                && a.kind == other.kind
                && (a.fd, a.brs, a.esi) == (other.fd, other.brs, other.esi)
                && a.dlc == other.dlc
                && a.payload() == other.payload()
                && a.iface == other.iface;
            assert!(same, "frame {i}: candump {a:?} vs {name} {other:?}");
            assert_eq!(
                rel_us(a, &cd[0]),
                rel_us(other, first),
                "frame {i}: relative time differs in {name}"
            );
        }
    }
    // ASC keeps the absolute epoch to the ms: every frame is 930 µs earlier than candump's.
    assert!(cd.iter().zip(&asc).all(|(a, b)| a.t_ns - b.t_ns == 930_000));
}

#[test]
fn python_can_asc_fixtures() {
    let d = "logs/python-can/test_data";
    let Some((f, st, _)) = open(&format!("{d}/logfile.asc")) else {
        return;
    };
    // 3 ErrorFrame + 3 remote + 4+4 J1939 data + 2 classic + 3 CANFD frames + 1 CANFD error.
    assert_eq!(st.frames, 20);
    assert_eq!(st.error_frames, 4);
    assert_eq!(st.malformed, 0);
    // Skipped: 3 CAN status, 6 Statistic, 2 J1939TP lines.
    assert_eq!(st.skipped, 11);
    let e = &f[6];
    assert_eq!(
        (e.id, e.extended, e.iface.as_str()),
        (0x18EBFF00, true, "can0")
    );
    assert_eq!(
        e.payload(),
        &[0x01, 0xA0, 0x0F, 0xA6, 0x60, 0x3B, 0xD1, 0x40]
    );
    let r = &f[5];
    assert_eq!(
        (r.kind, r.id, r.len, r.iface.as_str()),
        (FrameKind::Remote, 0x300, 8, "can3")
    );
    let fd = &f[16];
    assert!(fd.fd && fd.brs && !fd.esi);
    assert_eq!((fd.id, fd.len), (0x300, 8));
    let fd64 = &f[18];
    assert_eq!((fd64.id, fd64.len, fd64.dlc), (0x4EE, 64, 15));

    let (f, _, _) = open(&format!("{d}/test_CanFdMessage.asc")).unwrap();
    assert_eq!(f.len(), 3);
    assert_eq!(
        (f[1].id, f[1].extended, f[1].esi, f[1].brs),
        (0x1C4D80A7, true, true, false)
    );
    assert_eq!(f[0].payload(), &[0x11, 0xC2, 3, 4, 5, 6, 7, 8]);
    assert_eq!(f[2].id, 0x30A, "symbolic name column is skipped");

    let (f, _, _) = open(&format!("{d}/test_CanMessage.asc")).unwrap();
    assert_eq!(f.len(), 2);
    assert_eq!((f[0].id, f[0].iface.as_str()), (0xC8, "can1"));
    // "2.5010" after "Sat Sep 30 10:06:13.191 PM 2017" (UTC).
    assert_eq!(f[0].t_ns, 1_506_809_173_191_000_000 + 2_501_000_000);

    // The gzip-compressed copy reads the same.
    let (g, _, gz) = open(&format!("{d}/test_CanMessage.asc.gz")).unwrap();
    assert_eq!(gz.format(), LogFormat::Asc);
    assert_eq!(g, f);

    let (f, _, _) = open(&format!("{d}/issue_1299.asc")).unwrap();
    assert_eq!(
        (f[2].id, f[2].len, f[2].dlc),
        (0x3FF, 8, 13),
        "DLC D with 8 bytes"
    );

    let (f, _, _) = open(&format!("{d}/single_frame.asc")).unwrap();
    assert!(f[0].fd && f[0].len == 64 && f[0].data[63] == 0x3F);

    let (f, st, _) = open(&format!("{d}/test_CanErrorFrames.asc")).unwrap();
    assert_eq!(st.error_frames, 4);
    assert!(f.iter().all(|x| x.kind == FrameKind::Error));

    let (f, _, _) = open(&format!("{d}/test_CanFdRemoteMessage.asc")).unwrap();
    assert_eq!(
        (f[0].kind, f[0].id, f[0].dlc),
        (FrameKind::Remote, 0x50005, 5)
    );

    let (f, st, _) = open(&format!("{d}/issue_1256.asc")).unwrap();
    assert_eq!(st.malformed, 0);
    assert_eq!(f.len(), 1457);
}

#[test]
fn python_can_blf_fixtures() {
    let d = "logs/python-can/test_data";
    let Some((f, st, _)) = open(&format!("{d}/test_CanErrorFrameExt.blf")) else {
        return;
    };
    assert_eq!((st.frames, st.error_frames), (2, 2));
    assert_eq!(f[0].iface.as_str(), "can4368", "channel 0x1111");
    // These fixtures fill every field with a byte pattern (DLC 0x33, ID 0x44444444), which no
    // controller can produce: each object is reported, not turned into a made-up frame.
    for name in [
        "test_CanMessage.blf",
        "test_CanMessage2.blf",
        "test_CanFdMessage.blf",
    ] {
        let (f, st, mut r) = open(&format!("{d}/{name}")).unwrap();
        assert!(f.is_empty(), "{name}");
        assert_eq!(st.malformed, 2, "{name}");
        let s = r.take_skips();
        assert!(
            s[0].reason.contains("DLC 51 is out of range"),
            "{name}: {:?}",
            s[0]
        );
        assert!(s[0].location.ends_with(&format!("{name}:object 2")));
    }
    // issue 1905 (a TSMaster log): CAN_FD_MESSAGE_64 objects that declare 64 valid bytes but
    // hold 48. Read as CANoe and python-can read them: 64 bytes, the last 16 zero, counted.
    let (f, st, _) = open(&format!("{d}/issue_1905.blf")).unwrap();
    assert_eq!((st.frames, st.malformed, st.zero_filled), (22, 0, 22));
    let f0 = &f[0];
    assert_eq!(
        (f0.iface.as_str(), f0.id, f0.extended),
        ("can6", 0x6A9, false)
    );
    assert!(f0.fd && f0.brs);
    assert_eq!((f0.len, f0.dlc), (64, 15));
    assert!(f0.data[..48].iter().all(|&b| b == 0xFF));
    assert!(f0.data[48..64].iter().all(|&b| b == 0));
    assert_eq!(f0.t_ns / 1_000, 1_735_654_183_491_113);
    assert!(st.zero_filled_note().unwrap().starts_with("22 frame(s)"));
}

/// A CAN FD 64 object shorter than its valid bytes: the data it holds, then zeros, counted;
/// its data field ends at the extended data's offset when one is given; a complete one is
/// not counted.
#[test]
fn blf_fd64_object_short_of_its_valid_bytes_is_zero_filled() {
    // CAN_FD_MESSAGE_64 body: channel, dlc, valid bytes, tx count, id, frame length, flags
    // (0x1000 FD), 4 u32 (bit timing, offsets), bit count u16, dir, ext data offset, crc.
    let fd64 = |valid: u8, held: usize, ext: u8| {
        let mut b = vec![2, 15, valid, 0];
        b.extend_from_slice(&0x123u32.to_le_bytes());
        b.extend_from_slice(&[0; 4]);
        b.extend_from_slice(&0x1000u32.to_le_bytes());
        b.extend_from_slice(&[0; 16]);
        b.extend_from_slice(&[0, 0, 0, ext]);
        b.extend_from_slice(&[0; 4]);
        b.extend((0..held).map(|i| i as u8 + 1));
        obj(101, 1, 2, 1_000, &b)
    };
    let mut file = header(None);
    let objs = [
        fd64(64, 64, 0),            // complete
        fd64(64, 40, 0),            // 40 of 64 held
        fd64(64, 64, 32 + 40 + 24), // extended data after 24 data bytes
    ];
    file.extend(container(&objs.concat(), true));
    let mut r = LogReader::from_reader(std::io::Cursor::new(file), "fd64.blf").unwrap();
    let f = read_all(&mut r);
    assert_eq!(f.len(), 3);
    for (fr, held) in f.iter().zip([64usize, 40, 24]) {
        assert_eq!((fr.len, fr.dlc, fr.iface.as_str()), (64, 15, "can1"));
        assert!(fr.data[..held]
            .iter()
            .enumerate()
            .all(|(i, &b)| b == i as u8 + 1));
        assert!(fr.data[held..64].iter().all(|&b| b == 0), "{held}");
    }
    let st = r.stats();
    assert_eq!((st.frames, st.malformed, st.zero_filled), (3, 0, 2));
}

/// python-can's TRC fixtures: the same trace (PCAN-View 1.1, converted by PEAK-Converter to
/// 1.0, 1.3, 2.0 and 2.1) reads as the same 11 frames in every version, the status line
/// skipped; python-can 4.6's `TRCReader` reads the same frames and times.
#[test]
fn python_can_trc_fixtures() {
    let d = "logs/python-can/test_data";
    let Some((f21, st, r)) = open(&format!("{d}/test_CanMessage_V2_1.trc")) else {
        return;
    };
    assert_eq!(r.format(), LogFormat::Trc);
    assert_eq!((st.frames, st.skipped, st.malformed), (11, 1, 0));
    // $STARTTIME=44548.6028595139 (days since 1899-12-30): 2021-12-18 14:28:07.062001 UTC, the
    // "Start time: 18.12.2021 14:28:07.062.001" its comment states.
    assert_eq!(r.start_epoch_ns(), Some(1_639_837_687_062_001_000));
    let (first, last) = (&f21[0], &f21[10]);
    assert_eq!(first.t_ns, 1_639_837_687_062_001_000 + 17_535_400_000);
    assert_eq!((first.id, first.extended, first.len), (0x100, true, 8));
    assert_eq!(
        (first.iface.as_str(), first.kind),
        ("can0", FrameKind::Data)
    );
    assert_eq!(
        (f21[3].id, f21[3].extended),
        (0, false),
        "4 hex digits: standard"
    );
    assert_eq!(
        (last.id, last.kind, last.dlc),
        (0x704, FrameKind::Remote, 1)
    );
    for name in [
        "test_CanMessage_V1_1.trc",
        "test_CanMessage_V1_3.trc",
        "test_CanMessage_V2_0_BUS1.trc",
    ] {
        let (f, st, _) = open(&format!("{d}/{name}")).unwrap();
        assert_eq!((st.frames, st.malformed), (11, 0), "{name}");
        for (a, b) in f.iter().zip(&f21) {
            assert_eq!(
                (a.id, a.extended, a.kind, a.dlc, a.data),
                (b.id, b.extended, b.kind, b.dlc, b.data),
                "{name}"
            );
            assert!(
                (a.t_ns - b.t_ns).abs() <= 1_000,
                "{name}: {} vs {}",
                a.t_ns,
                b.t_ns
            );
        }
    }
    // 1.0: no start time, whole milliseconds.
    let (f10, st, r) = open(&format!("{d}/test_CanMessage_V1_0_BUS1.trc")).unwrap();
    assert_eq!((st.frames, st.skipped, r.start_epoch_ns()), (11, 1, None));
    assert_eq!(
        (f10[0].t_ns, f10[10].kind),
        (17_535_000_000, FrameKind::Remote)
    );
    // 2.1 with two buses.
    let (f, _, _) = open(&format!("{d}/test_CanMessage.trc")).unwrap();
    assert_eq!(f.len(), 2);
    assert_eq!(
        (f[0].iface.as_str(), f[0].id, f[0].data[0]),
        ("can1", 0xC8, 0x09)
    );
    assert_eq!((f[1].iface.as_str(), f[1].id), ("can0", 0x6F9));
}

// ---- synthetic BLF ----

fn obj(ty: u32, version: u16, flags: u32, ts: u64, body: &[u8]) -> Vec<u8> {
    let hdr = if version == 1 { 32 } else { 40 };
    let size = hdr + body.len();
    let mut v = Vec::new();
    v.extend_from_slice(b"LOBJ");
    v.extend_from_slice(&(hdr as u16).to_le_bytes());
    v.extend_from_slice(&version.to_le_bytes());
    v.extend_from_slice(&(size as u32).to_le_bytes());
    v.extend_from_slice(&ty.to_le_bytes());
    v.extend_from_slice(&flags.to_le_bytes());
    if version == 1 {
        v.extend_from_slice(&[0; 4]);
        v.extend_from_slice(&ts.to_le_bytes());
    } else {
        v.extend_from_slice(&[0; 4]);
        v.extend_from_slice(&ts.to_le_bytes());
        v.extend_from_slice(&[0; 8]);
    }
    v.extend_from_slice(body);
    v.extend(std::iter::repeat_n(0u8, size % 4));
    v
}

fn container(payload: &[u8], compress: bool) -> Vec<u8> {
    use std::io::Write;
    let data = if compress {
        let mut e = flate2::write::ZlibEncoder::new(Vec::new(), flate2::Compression::default());
        e.write_all(payload).unwrap();
        e.finish().unwrap()
    } else {
        payload.to_vec()
    };
    let mut body = Vec::new();
    body.extend_from_slice(&(if compress { 2u16 } else { 0 }).to_le_bytes());
    body.extend_from_slice(&[0; 6]);
    body.extend_from_slice(&(payload.len() as u32).to_le_bytes());
    body.extend_from_slice(&[0; 4]);
    body.extend_from_slice(&data);
    let size = 16 + body.len();
    let mut v = Vec::new();
    v.extend_from_slice(b"LOBJ");
    v.extend_from_slice(&16u16.to_le_bytes());
    v.extend_from_slice(&1u16.to_le_bytes());
    v.extend_from_slice(&(size as u32).to_le_bytes());
    v.extend_from_slice(&10u32.to_le_bytes());
    v.extend_from_slice(&body);
    v.extend(std::iter::repeat_n(0u8, size % 4));
    v
}

fn header(start: Option<[u16; 8]>) -> Vec<u8> {
    let mut h = vec![0u8; 144];
    h[..4].copy_from_slice(b"LOGG");
    h[4..8].copy_from_slice(&144u32.to_le_bytes());
    if let Some(st) = start {
        for (i, x) in st.iter().enumerate() {
            h[40 + 2 * i..42 + 2 * i].copy_from_slice(&x.to_le_bytes());
        }
    }
    h
}

#[test]
fn synthetic_blf_covers_every_can_object() {
    let mut objs = Vec::new();
    // CAN_MESSAGE, channel 1, 3 bytes, extended, 10 µs timestamp units.
    let mut b = vec![1, 0, 0, 3];
    b.extend_from_slice(&(0x8000_0000u32 | 0x1234567).to_le_bytes());
    b.extend_from_slice(&[0xAA, 0xBB, 0xCC, 0, 0, 0, 0, 0]);
    objs.push(obj(1, 1, 1, 100, &b));
    // CAN_MESSAGE2 remote, channel 2, header v2, ns.
    let mut b = vec![2, 0, 0x80, 4];
    b.extend_from_slice(&0x123u32.to_le_bytes());
    b.extend_from_slice(&[0; 8]);
    b.extend_from_slice(&[0; 8]);
    objs.push(obj(86, 2, 2, 2_000_000, &b));
    // CAN_FD_MESSAGE, 12 bytes, BRS.
    let mut b = vec![1, 0, 0, 9];
    b.extend_from_slice(&0x100u32.to_le_bytes());
    b.extend_from_slice(&[0; 4]);
    b.extend_from_slice(&[0, 0x3, 12, 0, 0, 0, 0, 0]);
    let mut d = [0u8; 64];
    d[..12].copy_from_slice(&[1, 2, 3, 4, 5, 6, 7, 8, 9, 10, 11, 12]);
    b.extend_from_slice(&d);
    objs.push(obj(100, 1, 2, 3_000_000, &b));
    // CAN_FD_MESSAGE_64, 64 bytes, ESI.
    let mut b = vec![1, 15, 64, 0];
    b.extend_from_slice(&0x7FFu32.to_le_bytes());
    b.extend_from_slice(&[0; 4]);
    b.extend_from_slice(&(0x1000u32 | 0x4000).to_le_bytes());
    b.extend_from_slice(&[0; 24]);
    b.extend((0..64).map(|i| i as u8));
    objs.push(obj(101, 1, 2, 4_000_000, &b));
    // An unrelated object (type 65, APP_TEXT) and a CAN_ERROR_EXT.
    objs.push(obj(65, 1, 2, 4_500_000, &[0; 16]));
    objs.push(obj(
        73,
        1,
        2,
        5_000_000,
        &[
            1, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0,
            0, 0, 0,
        ],
    ));
    let all: Vec<u8> = objs.concat();
    // Split the object stream mid-object over three containers, one of them uncompressed,
    // then add a corrupt container and a final good one.
    let (a, rest) = all.split_at(50);
    let (b2, c) = rest.split_at(rest.len() / 2);
    let mut file = header(Some([2024, 12, 2, 31, 14, 9, 40, 222]));
    file.extend(container(a, true));
    file.extend(container(b2, false));
    file.extend(container(c, true));
    let mut bad = container(
        &obj(
            1,
            1,
            2,
            6_000_000,
            &[1, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0],
        ),
        true,
    );
    let n = bad.len();
    bad[n - 8] ^= 0xFF; // corrupt the deflate stream
    file.extend(bad);
    let mut b = vec![1, 0, 0, 1];
    b.extend_from_slice(&0x42u32.to_le_bytes());
    b.extend_from_slice(&[0x99, 0, 0, 0, 0, 0, 0, 0]);
    file.extend(container(&obj(1, 1, 2, 7_000_000, &b), true));

    let mut r = LogReader::from_reader(std::io::Cursor::new(file), "synthetic.bin").unwrap();
    assert_eq!(r.format(), LogFormat::Blf, "detected by the LOGG signature");
    let f = read_all(&mut r);
    let st = r.stats();
    let start = r.start_epoch_ns().unwrap();
    assert_eq!(
        start, 1_735_654_180_222_000_000,
        "2024-12-31 14:09:40.222 UTC"
    );
    assert_eq!(f.len(), 6, "{:?}", r.take_skips());
    assert_eq!((st.malformed, st.skipped, st.error_frames), (1, 1, 1));
    assert_eq!(
        (f[0].id, f[0].extended, f[0].payload()),
        (0x1234567, true, &[0xAA, 0xBB, 0xCC][..])
    );
    assert_eq!(f[0].t_ns - start, 1_000_000, "100 × 10 µs");
    assert_eq!(
        (f[1].kind, f[1].len, f[1].iface.as_str()),
        (FrameKind::Remote, 4, "can1")
    );
    assert_eq!(f[1].t_ns - start, 2_000_000);
    assert!(f[2].fd && f[2].brs && !f[2].esi && f[2].len == 12 && f[2].dlc == 9);
    assert!(f[3].fd && !f[3].brs && f[3].esi && f[3].len == 64 && f[3].data[63] == 63);
    assert_eq!(f[4].kind, FrameKind::Error);
    assert_eq!(
        (f[5].id, f[5].payload()),
        (0x42, &[0x99][..]),
        "reading goes on after a corrupt container"
    );
}

#[test]
fn truncated_blf_is_reported_not_fatal() {
    let mut b = vec![1, 0, 0, 1];
    b.extend_from_slice(&0x42u32.to_le_bytes());
    b.extend_from_slice(&[0x99, 0, 0, 0, 0, 0, 0, 0]);
    let mut file = header(None);
    file.extend(container(&obj(1, 1, 2, 7, &b), true));
    file.extend(container(&obj(1, 1, 2, 8, &b), true));
    file.truncate(file.len() - 10);
    let mut r = LogReader::from_reader(std::io::Cursor::new(file), "cut.blf").unwrap();
    let f = read_all(&mut r);
    assert_eq!(f.len(), 1);
    assert_eq!(r.stats().malformed, 1);
    assert!(r.take_skips()[0].reason.contains("truncated"));
}

/// A CAN FD object whose valid-byte count is not a CAN FD length (19) is an inconsistent
/// object: counted and reported as malformed, never delivered as a frame no bus can carry
/// (found by `logs_fuzz`, case saved in `logs_fuzz.proptest-regressions`).
#[test]
fn blf_fd_object_with_impossible_length_is_reported() {
    let fd = |valid: u8| {
        let mut b = vec![1, 0, 0, 11];
        b.extend_from_slice(&0x100u32.to_le_bytes());
        b.extend_from_slice(&[0; 4]);
        b.extend_from_slice(&[0, 0x1, valid, 0, 0, 0, 0, 0]);
        b.extend((0..64).map(|i| i as u8));
        obj(100, 1, 2, 1_000, &b)
    };
    let mut file = header(None);
    file.extend(container(&[fd(19), fd(20)].concat(), true));
    let mut r = LogReader::from_reader(std::io::Cursor::new(file), "fd.blf").unwrap();
    let f = read_all(&mut r);
    assert_eq!(f.len(), 1);
    assert_eq!((f[0].len, f[0].dlc, f[0].data[19]), (20, 11, 19));
    let st = r.stats();
    assert_eq!((st.frames, st.malformed), (1, 1));
    let skips = r.take_skips();
    assert!(skips[0].reason.contains("19 valid data bytes"), "{skips:?}");
}
