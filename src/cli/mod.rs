//! The `shimmy` command line: one module per subcommand. Each exposes an `Args` struct (clap) and
//! a `run` function. Help text here is the manual.

pub mod calibrate;
pub mod convert;
pub mod decode;
pub mod doctor;
pub mod estimate;
#[cfg(feature = "lake")]
pub mod export;
pub mod fleet_fit;
pub mod identify;
pub mod report;
pub mod reproduce;
pub mod simulate;

/// `--format` of the commands that print either a report for people or one JSON document
/// (`estimate`, `identify`, `doctor`).
#[derive(clap::ValueEnum, Clone, Copy, Debug, PartialEq, Eq)]
pub enum TextOrJson {
    Text,
    Json,
}
