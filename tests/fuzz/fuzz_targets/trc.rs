//! The TRC log reader ([`shimmy::source::log::LogReader`]) on arbitrary bytes: no panic, every
//! delivered frame well-formed, every frame counted.
#![no_main]

#[path = "common.rs"]
mod common;

libfuzzer_sys::fuzz_target!(|data: &[u8]| {
    common::drain(data, shimmy::source::log::LogFormat::Trc);
});
