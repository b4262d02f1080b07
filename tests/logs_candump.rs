//! candump -L reading through `LogReader`: the real RAV4 log, every grammar feature, and the
//! counted, located reports for bad lines.

use shimmy::shared_data::require_file;
use shimmy::source::log::{LogFormat, LogReader};
use shimmy::source::CanSource;
use shimmy::wire::candump::write_frame;
use shimmy::wire::{Frame, FrameKind};

fn read_all(r: &mut LogReader) -> Vec<Frame> {
    let mut v = Vec::new();
    while let Some(f) = r.next_frame().unwrap() {
        v.push(f);
    }
    v
}

fn reader_for(text: &str, name: &str) -> LogReader {
    LogReader::from_reader(std::io::Cursor::new(text.as_bytes().to_vec()), name).unwrap()
}

#[test]
fn rav4_candump_log_reads_whole_and_rewrites_byte_identical() {
    let Some(path) = require_file("logs/comma2k19-rav4/rav4_2017_seg40_bus0.log") else {
        return;
    };
    let mut r = LogReader::open(&path).unwrap();
    assert_eq!(r.format(), LogFormat::Candump);
    let frames = read_all(&mut r);
    let st = r.stats();
    assert_eq!(frames.len(), 53_800);
    assert_eq!(st.frames, 53_800);
    assert_eq!(st.malformed, 0, "{:?}", r.take_skips());
    assert_eq!(st.skipped, 0);
    let f0 = frames[0];
    assert_eq!(f0.t_ns, 46_408_584_930_000);
    assert_eq!(
        (f0.id, f0.extended, f0.kind),
        (0x260, false, FrameKind::Data)
    );
    assert_eq!(
        f0.payload(),
        &[0x08, 0xFF, 0xFB, 0x00, 0x00, 0x00, 0x18, 0x84]
    );
    assert_eq!(f0.iface.as_str(), "can0");

    // The file is canonical candump -L, so the writer reproduces it byte for byte.
    let mut out = Vec::new();
    for f in &frames {
        write_frame(&mut out, f).unwrap();
    }
    let original = std::fs::read(&path).unwrap();
    assert!(
        out == original,
        "writer output differs from the original log"
    );
}

#[test]
fn every_grammar_feature_in_one_file() {
    let text = "# a comment\r\n\
                \r\n\
                (1.000000) can0 123#1122\r\n\
                (1.000001)\t\tcan0    12345678#   T\n\
                (1.000002000) can0 123#R\n\
                (1.000003) can0 123#R8_9 R\n\
                (1.000004) can0 7ff#11.22.33.44.55.66.77.88_F\n\
                (1.000005) can0 123##3aabbccdd\n\
                (1.000006) can0 20000004#0000080000000000\n\
                DROPCOUNT: dropped 5 CAN frames on 'can0' socket (total drops 5)\n\
                (1.000007) can0 123###80:00:00000000#AA\n\
                (0.500000) can1 000#\n";
    let mut r = reader_for(text, "mixed.log");
    let frames = read_all(&mut r);
    let st = r.stats();
    assert_eq!(frames.len(), 8);
    assert_eq!(st.malformed, 0, "{:?}", r.take_skips());
    assert_eq!(st.dropped, 5);
    assert_eq!(st.skipped, 1, "the CAN XL line");
    assert_eq!(st.error_frames, 1);
    assert_eq!(st.backwards_timestamps, 1);
    assert!(frames[1].extended);
    assert_eq!(frames[1].len, 0);
    assert_eq!(frames[2].t_ns, 1_000_002_000);
    assert_eq!(
        (frames[3].kind, frames[3].len, frames[3].dlc),
        (FrameKind::Remote, 8, 9)
    );
    assert_eq!((frames[4].id, frames[4].dlc), (0x7FF, 15));
    assert!(frames[5].fd && frames[5].brs && frames[5].esi);
    assert_eq!(frames[6].kind, FrameKind::Error);
    assert_eq!(frames[6].id, 4);
    assert_eq!(frames[7].iface.as_str(), "can1");
    let skips = r.take_skips();
    assert_eq!(skips.len(), 1);
    assert_eq!(skips[0].location, "mixed.log:11");
}

/// Drop counts a log states are added up without overflowing (a fuzzed log with two counts
/// near u64::MAX panicked a debug build): the total saturates.
#[test]
fn huge_drop_counts_saturate_instead_of_overflowing() {
    let text = "(1.000000) can0 123#11\n\
                DROPCOUNT: dropped 18446744073709551000 CAN frames on 'can0' socket\n\
                DROPCOUNT: dropped 99999999999999999999999 CAN frames on 'can0' socket\n\
                (1.000001) can0 123#22\n";
    let mut r = reader_for(text, "drops.log");
    let frames = read_all(&mut r);
    assert_eq!(frames.len(), 2);
    assert_eq!(r.stats().dropped, u64::MAX);
}

#[test]
fn malformed_lines_are_counted_located_and_replay_goes_on() {
    let text = "(1.000000) can0 123#11\n\
                (1.000001) can0 1234#11\n\
                garbage\n\
                (1.000002) can0 123#22\n\
                (1.000003) can0 123#3344";
    let mut r = reader_for(text, "bad.log");
    let frames = read_all(&mut r);
    assert_eq!(frames.len(), 3, "good lines around bad ones are delivered");
    let st = r.stats();
    assert_eq!(st.malformed, 2);
    let skips = r.take_skips();
    assert_eq!(skips[0].location, "bad.log:2");
    assert!(
        skips[0].reason.contains("CAN ID must be 3 hex digits"),
        "{}",
        skips[0].reason
    );
    assert_eq!(skips[1].location, "bad.log:3");
    assert!(
        skips[1].reason.contains("expected '('"),
        "{}",
        skips[1].reason
    );
    // A complete-looking last line without newline is still delivered.
    assert_eq!(frames[2].payload(), &[0x33, 0x44]);
}

#[test]
fn half_written_last_line_is_reported_as_such() {
    let mut r = reader_for("(1.000000) can0 123#11\n(1.000001) can0 12", "cut.log");
    assert_eq!(read_all(&mut r).len(), 1);
    assert_eq!(r.stats().malformed, 1);
    let s = r.take_skips();
    assert_eq!(s[0].location, "cut.log:2");
    assert!(
        s[0].reason.starts_with("half-written last line"),
        "{}",
        s[0].reason
    );
}

#[test]
fn reports_are_bounded_but_everything_is_counted() {
    let text = "x\n".repeat(500);
    let mut r = reader_for(&text, "many.log").with_max_reports(10);
    assert!(read_all(&mut r).is_empty());
    assert_eq!(r.stats().malformed, 500);
    assert_eq!(r.take_skips().len(), 10);
}

#[test]
fn an_overlong_line_is_one_located_skip() {
    // A line longer than the reader's 256 KiB bound (a corrupted or binary log) costs exactly
    // that line: it is reported with its line number and the lines around it still read.
    let long = "x".repeat(300 * 1024);
    let text = format!("(1.000000) can0 123#11\n{long}\n(1.000100) can0 124#22\n{long}");
    let mut r = reader_for(&text, "long.log");
    let frames = read_all(&mut r);
    assert_eq!(frames.len(), 2);
    assert_eq!(frames[1].id, 0x124);
    assert_eq!(r.stats().malformed, 2);
    let skips = r.take_skips();
    let at: Vec<&str> = skips.iter().map(|s| s.location.as_str()).collect();
    assert_eq!(at, ["long.log:2", "long.log:4"]);
    assert!(
        skips.iter().all(|s| s.reason.contains("256 KiB")),
        "{skips:?}"
    );
}
