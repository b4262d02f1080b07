//! The `shimmy` command line: one module per subcommand. Each exposes an `Args` struct (clap) and
//! a `run` function. Help text here is the manual.

pub mod calibrate;
pub mod convert;
pub mod decode;
pub mod doctor;
pub mod estimate;
pub mod identify;
pub mod report;
pub mod reproduce;
pub mod simulate;
