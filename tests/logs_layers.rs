//! The source layers: Recorder (tee to a candump log) and FaultInjector (seeded faults).

use shimmy::shared_data::require_file;
use shimmy::source::fault::{FaultConfig, FaultInjector};
use shimmy::source::log::LogReader;
use shimmy::source::recorder::{CandumpWriter, Recorder};
use shimmy::source::{CanSource, SourceStats};
use shimmy::wire::{Frame, FrameKind};

/// A finite in-memory source.
struct VecSource {
    frames: std::vec::IntoIter<Frame>,
    n: u64,
}

impl VecSource {
    fn new(v: Vec<Frame>) -> Self {
        VecSource {
            frames: v.into_iter(),
            n: 0,
        }
    }
}

impl CanSource for VecSource {
    fn next_frame(&mut self) -> std::io::Result<Option<Frame>> {
        let f = self.frames.next();
        self.n += f.is_some() as u64;
        Ok(f)
    }
    fn stats(&self) -> SourceStats {
        SourceStats {
            frames: self.n,
            ..Default::default()
        }
    }
}

fn drain(s: &mut impl CanSource) -> Vec<Frame> {
    let mut v = Vec::new();
    while let Some(f) = s.next_frame().unwrap() {
        v.push(f);
    }
    v
}

fn rav4() -> Option<Vec<Frame>> {
    let p = require_file("logs/comma2k19-rav4/rav4_2017_seg40_bus0.log")?;
    Some(drain(&mut LogReader::open(p).unwrap()))
}

fn synthetic(n: usize) -> Vec<Frame> {
    (0..n)
        .map(|i| {
            let mut f = Frame::classic(
                i as i64 * 1_000_000,
                (i % 0x7FF) as u32,
                false,
                &(i as u64).to_le_bytes(),
            )
            .unwrap();
            f.set_iface("vcan0");
            f
        })
        .collect()
}

#[test]
fn recorder_tees_frames_unchanged_and_the_log_reads_back_identically() {
    let Some(frames) = rav4() else { return };
    let mut rec = Recorder::new(
        VecSource::new(frames.clone()),
        CandumpWriter::new(Vec::new()),
    );
    let passed = drain(&mut rec);
    assert_eq!(passed, frames);
    assert_eq!(rec.recorded(), 53_800);
    let (_, w) = rec.finish().unwrap();
    let log = w.into_inner().unwrap();
    let mut back = LogReader::from_reader(std::io::Cursor::new(log), "rec.log").unwrap();
    assert_eq!(drain(&mut back), frames);
    assert_eq!(back.stats().malformed, 0);
}

#[test]
fn recorder_passes_on_but_reports_frames_candump_cannot_hold() {
    let mut frames = synthetic(3);
    frames[1].iface = Default::default();
    let mut rec = Recorder::new(
        VecSource::new(frames.clone()),
        CandumpWriter::new(Vec::new()),
    );
    assert_eq!(drain(&mut rec), frames);
    assert_eq!((rec.recorded(), rec.not_recorded()), (2, 1));
    let s = rec.take_skips();
    assert_eq!(s.len(), 1);
    assert!(s[0].reason.contains("interface name"), "{}", s[0].reason);

    // With a default interface name the frame is recorded under it.
    let mut w = CandumpWriter::new(Vec::new()).with_default_iface("can9");
    w.write(&frames[1]).unwrap();
    let text = String::from_utf8(w.into_inner().unwrap()).unwrap();
    assert_eq!(text, "(0.001000) can9 001#0100000000000000\n");
}

fn inject(frames: &[Frame], cfg: FaultConfig) -> (Vec<Frame>, FaultInjector<VecSource>) {
    let mut fi = FaultInjector::new(VecSource::new(frames.to_vec()), cfg);
    let out = drain(&mut fi);
    (out, fi)
}

#[test]
fn no_faults_means_identity() {
    let frames = synthetic(1000);
    let (out, fi) = inject(&frames, FaultConfig::default());
    assert_eq!(out, frames);
    assert_eq!(fi.counts(), &Default::default());
}

#[test]
fn faults_are_reproducible_from_the_seed() {
    let frames = synthetic(2000);
    let cfg = |seed| FaultConfig {
        seed,
        drop_rate: 0.05,
        corrupt_rate: 0.05,
        truncate_rate: 0.05,
        delay_rate: 0.05,
        max_delay_s: 0.01,
        reorder_rate: 0.05,
        error_frame_rate: 0.05,
    };
    let (a, fa) = inject(&frames, cfg(7));
    let (b, fb) = inject(&frames, cfg(7));
    let (c, _) = inject(&frames, cfg(8));
    assert_eq!(a, b);
    assert_eq!(fa.counts(), fb.counts());
    assert_ne!(a, c);
    let n = fa.counts();
    for (what, k) in [
        ("dropped", n.dropped),
        ("corrupted", n.corrupted),
        ("truncated", n.truncated),
        ("delayed", n.delayed),
        ("reordered", n.reordered),
        ("errors", n.error_frames_injected),
    ] {
        // 5 % of ~2000 frames: 100 ± 10 sigma-ish bounds.
        assert!((40..=180).contains(&k), "{what}: {k}");
    }
    assert_eq!(
        a.len() as u64,
        2000 - n.dropped + n.error_frames_injected,
        "every frame is accounted for"
    );
}

#[test]
fn drop_rate_drops_that_share_of_the_real_log() {
    let Some(frames) = rav4() else { return };
    let (out, fi) = inject(
        &frames,
        FaultConfig {
            seed: 1,
            drop_rate: 0.1,
            ..Default::default()
        },
    );
    let d = fi.counts().dropped;
    // Binomial(53800, 0.1): mean 5380, sd 70.
    assert!((5030..=5730).contains(&d), "dropped {d}");
    assert_eq!(out.len() as u64, 53_800 - d);
    assert_eq!(fi.stats().frames, out.len() as u64);
    // What is left is the original sequence minus the dropped frames.
    let mut it = frames.iter();
    assert!(out.iter().all(|f| it.any(|g| g == f)));
}

#[test]
fn corruption_flips_exactly_one_bit() {
    let frames = synthetic(500);
    let (out, fi) = inject(
        &frames,
        FaultConfig {
            seed: 3,
            corrupt_rate: 1.0,
            ..Default::default()
        },
    );
    assert_eq!(fi.counts().corrupted, 500);
    for (a, b) in frames.iter().zip(&out) {
        let flipped: u32 = a
            .payload()
            .iter()
            .zip(b.payload())
            .map(|(x, y)| (x ^ y).count_ones())
            .sum();
        assert_eq!(flipped, 1);
    }
}

#[test]
fn truncation_makes_short_frames_and_fd_stays_valid() {
    let mut frames = synthetic(300);
    frames.push(Frame::fd(0, 0x100, false, &[7; 64]).unwrap());
    let (out, fi) = inject(
        &frames,
        FaultConfig {
            seed: 4,
            truncate_rate: 1.0,
            ..Default::default()
        },
    );
    assert_eq!(fi.counts().truncated, 301);
    for (a, b) in frames.iter().zip(&out) {
        assert!(b.len < a.len);
        assert_eq!(b.payload(), &a.payload()[..b.len as usize]);
    }
    let fd = out.last().unwrap();
    assert!([0, 1, 2, 3, 4, 5, 6, 7, 8, 12, 16, 20, 24, 32, 48].contains(&fd.len));
}

#[test]
fn delay_and_reorder_show_up_as_backwards_timestamps() {
    let frames = synthetic(1000);
    let (out, fi) = inject(
        &frames,
        FaultConfig {
            seed: 5,
            reorder_rate: 0.1,
            ..Default::default()
        },
    );
    let r = fi.counts().reordered;
    assert!(r > 50);
    assert_eq!(
        fi.stats().backwards_timestamps,
        r,
        "each swap steps back once"
    );
    let mut sorted = out.clone();
    sorted.sort_by_key(|f| f.t_ns);
    assert_eq!(sorted, frames, "nothing lost or altered by reordering");

    let (out, fi) = inject(
        &frames,
        FaultConfig {
            seed: 6,
            delay_rate: 0.2,
            max_delay_s: 0.005,
            ..Default::default()
        },
    );
    let moved = frames
        .iter()
        .zip(&out)
        .filter(|(a, b)| a.t_ns != b.t_ns)
        .count() as u64;
    assert_eq!(moved, fi.counts().delayed);
    assert!(frames
        .iter()
        .zip(&out)
        .all(|(a, b)| b.t_ns >= a.t_ns && b.t_ns - a.t_ns <= 5_000_000));
    assert!(fi.stats().backwards_timestamps > 0);
}

#[test]
fn injected_error_frames_precede_their_frame() {
    let frames = synthetic(1000);
    let (out, fi) = inject(
        &frames,
        FaultConfig {
            seed: 9,
            error_frame_rate: 0.1,
            ..Default::default()
        },
    );
    let n = fi.counts().error_frames_injected;
    assert!(n > 50);
    assert_eq!(fi.stats().error_frames, n);
    assert_eq!(out.len() as u64, 1000 + n);
    for w in out.windows(2) {
        if w[0].kind == FrameKind::Error {
            assert_eq!(w[1].kind, FrameKind::Data);
            assert_eq!(w[0].t_ns, w[1].t_ns);
            assert_eq!(w[0].iface, w[1].iface);
        }
    }
}
