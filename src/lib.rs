//! shimmy-monitor: watches a vehicle's CAN bus for brake-induced steering shimmy and estimates the
//! clearance of the steering (tie-rod / trapezoid-arm) joints with a 5-DOF shimmy model.
//!
//! Data flows one way, one folder per stage, lowest layer first; a module uses only the modules
//! of its own row or of the rows above it (tests/module_graph.rs checks this):
//!
//! | stage | module | may touch |
//! |---|---|---|
//! | where the shared test material lives | [`shared_data`] | nothing |
//! | wire formats (candump, ASC, BLF, MF4; parse/emit, no policy) | [`wire`] | bytes only |
//! | frame sources (log reader, live SocketCAN, fault injector, recorder) | [`source`] | [`wire`] |
//! | DBC loading and signal decoding | [`dbc`] | [`wire::Frame`] |
//! | vehicle signal mapping and validity (timeouts, counters, checksums) | [`signals`] | [`dbc`] |
//! | signal analysis (filters, PSD, CWT, Lyapunov) | [`analysis`] | plain slices |
//! | the shimmy model (MODEL.md) | [`model`] | [`analysis`] |
//! | braking-event detection | [`events`] | [`analysis`] |
//! | the clearance observer (features, response table, estimator) | [`observer`] | [`events`], [`model`] |
//! | vehicle profiles (DBC, mapping, chassis, table of one car) | [`profile`] | all of the above |
//! | the monitor pipeline's shared types (events, estimate, the stage trait) | [`monitor`] | [`events`], [`observer`] |
//! | the maintenance alert rules and their settings | [`alerts`] | [`monitor`] |
//! | the monitor pipeline (event stage → estimate → alert rules, for shimmyd and `shimmy estimate`) | [`pipeline`] | [`alerts`], [`monitor`], [`observer`] |
//! | the crash-safe journal | [`journal`] | nothing |
//! | the Parquet data lake (decoded signals, events, estimates, alerts; feature `lake`) | `lake` | [`pipeline`] and below |
//! | applications: shimmyd, the `shimmy` commands, reports, doctor | [`daemon`], [`cli`], [`report`], [`doctor`] | everything below |
//!
//! Units are SI inside; degrees, km/h, mm and bar appear only at the edges and names say so.

pub mod alerts;
pub mod analysis;
pub mod cli;
pub mod daemon;
pub mod dbc;
pub mod doctor;
pub mod events;
pub mod journal;
#[cfg(feature = "lake")]
pub mod lake;
pub mod model;
pub mod monitor;
pub mod observer;
pub mod pipeline;
pub mod profile;
pub mod report;
pub mod shared_data;
pub mod signals;
pub mod source;
pub mod wire;
