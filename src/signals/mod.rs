//! Vehicle signal mapping: which DBC message/signal carries steering-wheel angle, brake, speed and
//! acceleration, how to compose them, and whether they are valid (timeouts, counters, checksums).

pub mod checksum;
pub mod mapping;
