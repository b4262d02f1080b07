//! shimmy-monitor: watches a vehicle's CAN bus for brake-induced steering shimmy and estimates the
//! clearance of the steering (tie-rod / trapezoid-arm) joints with a 5-DOF shimmy model.
//!
//! Data flows one way, one folder per stage:
//!
//! | stage | module | may touch |
//! |---|---|---|
//! | wire formats (candump, ASC, BLF, MF4; parse/emit, no policy) | [`wire`] | bytes only |
//! | frame sources (log reader, live SocketCAN, fault injector, recorder) | [`source`] | [`wire`] |
//! | DBC loading and signal decoding | [`dbc`] | [`wire::Frame`] |
//! | vehicle signal mapping and validity (timeouts, counters, checksums) | [`signals`] | [`dbc`] |
//! | the shimmy model (MODEL.md) | [`model`] | nothing upstream |
//! | signal analysis (filters, PSD, CWT, Lyapunov) | [`analysis`] | plain slices |
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
pub mod model;
pub mod monitor;
pub mod observer;
pub mod profile;
pub mod report;
pub mod shared_data;
pub mod signals;
pub mod source;
pub mod wire;
