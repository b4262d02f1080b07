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
//! | [`joints`] | the workshop's "joints replaced" marker file in the state directory: looked at, checked, renamed when bad, removed when handled, written by `shimmyd --joints-replaced` |
//! | [`stage`] | the event stage for a configuration (the observer, with the configured table), and what the daemon asks of it beyond the pipeline's seam (a joint replacement) |
//! | [`state`] | atomic persistence of estimate, event history, odometer, open alerts, the last joint replacement |
//! | [`run`] | the loop: sources, signals (SIGTERM, SIGHUP), sd_notify, outputs |
//! | [`transmit`] | SHIMMY_01 on the bus, only when the configuration enables it |
//! | [`mqtt`] | the optional outgoing MQTT client to a fleet backend |
//! | [`outbox`] | what MQTT still has to send: a cursor into the journal, which is the queue |
//! | [`sandbox`] | the systemd drop-in a configuration needs beyond the unit's sandbox (MQTT), and its check at start |
//! | [`tls`] | MQTT's TLS client configuration (CA, client certificate) and its errors explained |
//!
//! What it is not: a network service. shimmyd opens no listening socket; its only network use
//! is the outgoing MQTT connection, when `[mqtt] enabled = true`. The workshop tells it that the
//! joints were replaced with a file in its state directory, not over the network.

pub mod config;
pub mod counters;
pub mod joints;
pub mod mqtt;
pub mod outbox;
pub mod run;
pub mod sandbox;
pub mod stage;
pub mod state;
pub mod tls;
pub mod transmit;
