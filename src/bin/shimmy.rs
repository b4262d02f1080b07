//! `shimmy`: the command-line tool of shimmy-monitor.

use clap::{Parser, Subcommand};

/// Brake-induced steering shimmy monitor: decode CAN logs, simulate the 5-DOF shimmy model,
/// reproduce the source study, and (later) estimate steering-joint clearance.
#[derive(Parser, Debug)]
#[command(name = "shimmy", version, about, long_about = None)]
struct Cli {
    #[command(subcommand)]
    cmd: Cmd,
}

#[derive(Subcommand, Debug)]
enum Cmd {
    /// Decode CAN logs (candump -L, ASC, BLF, MF4, TRC) with a DBC file, like `cantools decode`.
    Decode(shimmy::cli::decode::Args),
    /// Convert a CAN log between candump -L, Vector ASC, BLF and ASAM MDF 4 (.mf4), or from PEAK
    /// TRC.
    Convert(shimmy::cli::convert::Args),
    /// Estimate steering-joint clearance from one vehicle's CAN logs (braking events, model table).
    Estimate(shimmy::cli::estimate::Args),
    /// Export one vehicle's CAN logs to a Parquet data lake (signals, events, estimates, alerts).
    #[cfg(feature = "lake")]
    Export(shimmy::cli::export::Args),
    /// Name the vehicle profile a CAN log comes from (IDs, lengths, rates, checksums), with evidence.
    Identify(shimmy::cli::identify::Args),
    /// Check a signal mapping against a car's logs (signal consistency, braking) and name what to change.
    Doctor(shimmy::cli::doctor::Args),
    /// Build the clearance estimator's response table from the shimmy model.
    Calibrate(shimmy::cli::calibrate::Args),
    /// Fit a car model's correction to its response tables from many vehicles at new joints.
    FleetFit(shimmy::cli::fleet_fit::Args),
    /// Workshop inspection report (HTML or JSON) from shimmyd's journal, state, or CAN logs.
    Report(shimmy::cli::report::Args),
    Simulate(shimmy::cli::simulate::Args),
    /// Rerun the source article's experiments on the model and regenerate docs/REPRODUCTION.md.
    Reproduce(shimmy::cli::reproduce::Args),
}

fn main() {
    let cli = Cli::parse();
    let result: anyhow::Result<()> = match cli.cmd {
        Cmd::Decode(a) => shimmy::cli::decode::run(a),
        Cmd::Convert(a) => shimmy::cli::convert::run(a),
        Cmd::Estimate(a) => shimmy::cli::estimate::run(a),
        #[cfg(feature = "lake")]
        Cmd::Export(a) => shimmy::cli::export::run(a),
        Cmd::Identify(a) => shimmy::cli::identify::run(a),
        Cmd::Doctor(a) => shimmy::cli::doctor::run(a),
        Cmd::Calibrate(a) => shimmy::cli::calibrate::run(a),
        Cmd::FleetFit(a) => shimmy::cli::fleet_fit::run(a),
        Cmd::Report(a) => shimmy::cli::report::run(a),
        Cmd::Simulate(a) => shimmy::cli::simulate::run(a),
        Cmd::Reproduce(a) => shimmy::cli::reproduce::run(a),
    };
    if let Err(e) = result {
        eprintln!("shimmy: error: {e:#}");
        std::process::exit(1);
    }
}
