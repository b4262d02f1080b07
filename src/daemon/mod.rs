//! shimmyd, the gateway daemon: frames → [`crate::signals::Mapper`] → the monitor pipeline
//! ([`crate::pipeline`]: braking events and clearance estimate through
//! [`crate::monitor::EventStage`], then the alert rules of [`crate::alerts`]) →
//! [`crate::journal`], with the log on stderr, persisted [`state`], signals and systemd
//! notification. The pipeline's logic is the library's; the daemon wires it to its inputs,
//! its persisted state and its outputs.
//!
//! | module | job |
//! |---|---|
//! | [`config`] | the TOML file, validated with key-naming errors |
//! | [`counters`] | the per-interval counters line (frames, decode errors, invalid messages, events) |
//! | [`stage`] | the event stage for a configuration (the observer, with the configured table) |
//! | [`state`] | atomic persistence of estimate, event history, odometer, open alerts |
//! | [`run`] | the loop: sources, signals (SIGTERM, SIGHUP), sd_notify, outputs |
//! | [`transmit`] | SHIMMY_01 on the bus, only when the configuration enables it |
//! | [`mqtt`] | the optional outgoing MQTT client to a fleet backend |
//! | [`outbox`] | what MQTT still has to send: a cursor into the journal, which is the queue |
//! | [`sandbox`] | the systemd drop-in a configuration needs beyond the unit's sandbox (MQTT), and its check at start |
//! | [`tls`] | MQTT's TLS client configuration (CA, client certificate) and its errors explained |
//!
//! What it is not: a network service. shimmyd opens no listening socket; its only network use
//! is the outgoing MQTT connection, when `[mqtt] enabled = true`.

pub mod config;
pub mod counters;
pub mod mqtt;
pub mod outbox;
pub mod run;
pub mod sandbox;
pub mod stage;
pub mod state;
pub mod tls;
pub mod transmit;
