//! Shared by the log-reader targets: drain a [`LogReader`] over the fuzz input and check that
//! what it delivers is well-formed and that everything it did not deliver is counted.

use shimmy::source::log::{LogFormat, LogReader};
use shimmy::source::CanSource;
use shimmy::wire::frame::{fd_dlc_to_len, fd_len_to_dlc};
use shimmy::wire::FrameKind;

pub fn drain(data: &[u8], format: LogFormat) {
    let mut r = LogReader::with_format(
        Box::new(std::io::Cursor::new(data.to_vec())),
        "fuzz",
        format,
    );
    let mut n = 0u64;
    // An in-memory read cannot fail for I/O reasons; an error here is a reader bug.
    while let Some(f) = r.next_frame().expect("in-memory reads do not fail") {
        n += 1;
        if f.fd {
            assert!(f.len <= 64, "{f:?}");
            assert_eq!(fd_dlc_to_len(fd_len_to_dlc(f.len as usize)), f.len as usize);
        } else {
            assert!(f.len <= 8, "{f:?}");
            assert!(f.dlc <= 15, "{f:?}");
        }
        if !f.extended && f.kind != FrameKind::Error {
            assert!(f.id <= 0x7FF, "{f:?}");
        }
        assert!(f.id <= 0x1FFF_FFFF, "{f:?}");
    }
    let st = r.stats();
    assert_eq!(st.frames, n);
    assert!(r.take_skips().len() as u64 <= st.malformed + st.skipped);
}
