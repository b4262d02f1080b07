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
    Simulate(shimmy::cli::simulate::Args),
}

fn main() {
    let cli = Cli::parse();
    let result: anyhow::Result<()> = match cli.cmd {
        Cmd::Simulate(a) => shimmy::cli::simulate::run(a),
    };
    if let Err(e) = result {
        eprintln!("shimmy: error: {e:#}");
        std::process::exit(1);
    }
}
