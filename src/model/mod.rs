//! The 5-DOF brake-induced shimmy model of MODEL.md: two Lankarani–Nikravesh clearance joints,
//! Magic Formula tires with relaxation, braking load transfer, and a fixed-step RK4 integrator
//! (plus faster multirate/adaptive variants, docs/BENCHMARKS.md "Shimmy model").
//!
//! One file per concern of MODEL.md: [`params`] §9, [`geometry`] §2, [`joint`] §4, [`tire`] §5,
//! [`braking`] §6, [`excitation`] §7, [`sensor`] §8, [`rhs`] §3 (+§15), [`integrate`] §10,
//! [`sim`] the stepping simulator and 1 kHz trace.
//!
//! What it is not: signal analysis (band-pass, PSD, Lyapunov: `crate::analysis`).

pub mod braking;
pub mod excitation;
pub mod features;
pub mod geometry;
pub mod integrate;
pub mod joint;
pub mod params;
pub mod rhs;
pub mod sensor;
pub mod sim;
pub mod tire;

pub use params::{Hands, VehicleParams};
pub use rhs::{JointMode, Switches};
pub use sim::{run, Integrator, Outputs, Scenario, Simulator, Trace};
