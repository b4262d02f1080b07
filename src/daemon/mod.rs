//! shimmyd, the gateway daemon: frames → [`crate::signals::Mapper`] → braking events and
//! clearance estimate ([`crate::monitor::EventStage`]) → [`crate::alerts`] → [`crate::journal`],
//! with the log on stderr, persisted [`state`], signals and systemd notification.
//!
//! | module | job |
//! |---|---|
//! | [`config`] | the TOML file, validated with key-naming errors |
//! | [`counters`] | the per-interval counters line (frames, decode errors, invalid messages, events) |
//! | [`state`] | atomic persistence of estimate, event history, odometer, open alerts |
//! | [`run`] | the loop: sources, signals (SIGTERM, SIGHUP), sd_notify, outputs |
//! | [`transmit`] | SHIMMY_01 on the bus, only when the configuration enables it |
//! | [`mqtt`] | the optional outgoing MQTT client to a fleet backend |
//! | [`outbox`] | MQTT's crash-safe on-disk queue while the broker is unreachable |
//!
//! What it is not: a network service. shimmyd opens no listening socket; its only network use
//! is the outgoing MQTT connection, when `[mqtt] enabled = true`.

pub mod config;
pub mod counters;
pub mod mqtt;
pub mod observer_stage;
pub mod outbox;
pub mod run;
pub mod stage;
pub mod state;
pub mod transmit;
