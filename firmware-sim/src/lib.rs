//! firmware-sim: simulated vehicle ECUs that drive the shimmy model (`shimmy::model`, MODEL.md)
//! with a known joint clearance and put the frames of a vehicle bus into a `candump -L` log or
//! onto a SocketCAN interface, together with a ground-truth sidecar saying what was really
//! simulated. The bus is our reference bus (`dbc/shimmy_reference.dbc`) by default, or a vehicle
//! profile's (`config/vehicles/<name>/`: its DBC and `bus.toml`), emulated as on the real car.
//!
//! One job per module:
//!
//! | module | job |
//! |---|---|
//! | [`scenario`] | the scenario TOML (`config/scenarios/*.toml`): parse and validate |
//! | [`drive`] | the drive cycle: longitudinal demand, brake pedal, braking events |
//! | [`plant`] | the plant interface, the model adapter, the driver's lane keeping |
//! | [`bus`] | ECUs of a bus described by a `bus.toml`: sensors, rates, jitter, sign conventions, split fields, counters, checksums, background traffic, faults |
//! | [`sim`] | one run: steps the plant, polls the ECUs, yields time-ordered frames |
//! | [`truth`] | the ground-truth sidecar (JSON) |
//! | [`fleet`] | `firmware-sim fleet`: the clearance observer validated on a simulated fleet |
//!
//! Live output uses `shimmy::source::socketcan::LiveSink`.
//!
//! Not here: reading frames back or judging them (that is the monitor's job, in `shimmy`).

pub mod bus;
pub mod drive;
pub mod fleet;
pub mod plant;
pub mod scenario;
pub mod sim;
pub mod truth;

pub use scenario::Scenario;
pub use sim::{FirmwareSim, RunInfo};
