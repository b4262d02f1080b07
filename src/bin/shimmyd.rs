//! `shimmyd`: the shimmy-monitor gateway daemon. See `shimmyd --help` and `shimmy::daemon`.

use std::path::PathBuf;

use clap::Parser;
use shimmy::daemon::config::Config;
use shimmy::daemon::run::{run, Options};
use shimmy::daemon::sandbox;

/// shimmyd watches a vehicle's CAN bus (SocketCAN, read-only) or replays CAN logs, detects
/// braking events, estimates steering-joint clearance, raises maintenance alerts and writes
/// them to a crash-safe journal.
///
/// Live: `shimmyd --config /etc/shimmyd/shimmyd.toml` reads the interfaces of `[input]`. Replay:
/// `shimmyd --config FILE --replay LOG...` plays the logs (candump -L, ASC, BLF, MF4, TRC) at their
/// recorded timing, or as fast as possible with `--fast`, then exits.
///
/// Outputs: the journal (`outputs.journal_dir`, JSON lines with sequence numbers and CRCs; read
/// it with `shimmy report --journal DIR`), the state (`outputs.state_dir`), counters on stderr
/// every `log.counters_interval_s`. SIGTERM stops cleanly, SIGHUP reloads `[alerts]` and `[log]`.
/// No network listener is opened; the bus is written only when `outputs.transmit = true`.
///
/// After a joint replacement: `shimmyd --config FILE --joints-replaced [MM]` tells the running
/// daemon (or the next one started) through the marker file `<state_dir>/joints_replaced`: it
/// clears the alerts, resets the estimate and takes the next `vehicle.baseline_events` braking
/// events as the car's baseline at MM mm (default `vehicle.baseline_clearance_mm`).
#[derive(Parser, Debug)]
#[command(name = "shimmyd", version, verbatim_doc_comment)]
struct Cli {
    /// The configuration file (config/shimmyd.toml is the documented default; every setting,
    /// of this file and of the monitor's settings file it names with `monitor`, is in
    /// docs/CONFIG.md).
    #[arg(long, value_name = "FILE", required_unless_present = "journal_stress")]
    config: Option<PathBuf>,
    /// The car, overriding the configuration's (`input.profile`, `input.dbc`, `input.mapping`,
    /// `vehicle.table`): a vehicle profile's name (config/vehicles/<NAME>) or folder.
    #[arg(long, value_name = "NAME")]
    profile: Option<String>,
    /// Replay these logs instead of reading the live interfaces, then exit.
    #[arg(long, value_name = "LOG", num_args = 1..)]
    replay: Vec<PathBuf>,
    /// With --replay: as fast as possible instead of at recorded timing.
    #[arg(long, requires = "replay")]
    fast: bool,
    /// Overrides outputs.state_dir.
    #[arg(long, value_name = "DIR")]
    state_dir: Option<PathBuf>,
    /// Check the configuration and exit. Prints the vehicle profile folder and DBC in use.
    /// Under the systemd unit (SHIMMYD_SANDBOX set) it also checks that the service's sandbox
    /// was made from this configuration (with [mqtt] enabled: the broker's drop-in).
    #[arg(long)]
    check: bool,
    /// Print the systemd drop-in this configuration needs beyond the unit's sandbox (nothing
    /// when [mqtt] is off: the unit allows no IP connection; with it, AF_INET/AF_INET6 and the
    /// broker's address) and exit. The Debian package's generator runs this at boot and at
    /// every `systemctl daemon-reload` (docs/GATEWAY.md).
    #[arg(long, conflicts_with_all = ["check", "replay"])]
    sandbox_dropin: bool,
    /// The steering joints were just replaced: write the marker `<state_dir>/joints_replaced`
    /// (with MM, the new joints' clearance in mm; without, `vehicle.baseline_clearance_mm`
    /// applies) for the daemon running with this configuration, and exit. The daemon takes it
    /// within seconds (or at its next start): it journals the replacement, clears the alerts,
    /// resets the clearance estimate and takes the next `vehicle.baseline_events` used braking
    /// events as the car's new baseline. Needs write access to the state directory
    /// (docs/GATEWAY.md).
    #[arg(
        long,
        value_name = "MM",
        num_args = 0..=1,
        default_missing_value = "",
        conflicts_with_all = ["check", "replay", "sandbox_dropin"]
    )]
    joints_replaced: Option<String>,
    /// Test helper (crash tests): append numbered records to the journal in DIR forever,
    /// printing each acknowledged (fsynced) sequence number on stdout.
    #[arg(long, value_name = "DIR", hide = true)]
    journal_stress: Option<PathBuf>,
}

fn journal_stress(dir: &std::path::Path) -> anyhow::Result<()> {
    use shimmy::journal::{FsyncPolicy, Journal, JournalConfig};
    use std::io::Write;
    let (mut j, rec) = Journal::open(
        dir,
        JournalConfig {
            fsync: FsyncPolicy::Always,
            rotate_bytes: 8 * 1024,
        },
    )?;
    let out = std::io::stdout();
    let mut out = out.lock();
    writeln!(out, "recovered {}", serde_json::to_string(&rec)?)?;
    let pad = "x".repeat(100);
    loop {
        let seq = j.next_seq();
        j.append(&serde_json::json!({"type": "stress", "n": seq, "pad": pad}))?;
        if j.durable_seq() == Some(seq) {
            writeln!(out, "ack {seq}")?;
            out.flush()?;
        }
    }
}

/// `--check`: loads and validates, says which car files are in use, checks the sandbox.
fn check(path: &std::path::Path, profile: Option<&str>) -> anyhow::Result<()> {
    let c = Config::load_with_profile(path, profile)?;
    c.print_warnings();
    let env = std::env::var(sandbox::ENV).ok();
    if let Some(w) = sandbox::check_env(&c, env.as_deref())? {
        eprintln!("warning: {w}");
    }
    if let Some(p) = &c.profile {
        eprintln!("shimmyd: vehicle profile {}", p.dir.display());
    }
    if let Some((dbc, mapping)) = c.bus_files() {
        eprintln!(
            "shimmyd: DBC {}, mapping {}",
            dbc.display(),
            mapping.display()
        );
    }
    eprintln!("shimmyd: {} is valid", path.display());
    Ok(())
}

/// `--sandbox-dropin`: the drop-in on stdout, nothing when none is needed.
fn sandbox_dropin(path: &std::path::Path) -> anyhow::Result<()> {
    let c = Config::load(path)?;
    if let Some(text) = sandbox::dropin(&c, &path.display().to_string())? {
        print!("{text}");
    }
    Ok(())
}

/// `--joints-replaced [MM]`: the marker in the configuration's state directory.
fn joints_replaced(
    path: &std::path::Path,
    profile: Option<&str>,
    state_dir: Option<PathBuf>,
    mm: &str,
) -> anyhow::Result<()> {
    let c = Config::load_with_profile(path, profile)?;
    let dir = state_dir.unwrap_or(c.outputs.state_dir);
    // Without MM the configuration's clearance is written, so the marker is never empty (the
    // daemon waits a moment before taking an empty one, which may be being written).
    let default = c.vehicle.baseline_clearance_mm.to_string();
    let (content, from) = match mm.trim() {
        "" => (default.as_str(), " (vehicle.baseline_clearance_mm)"),
        given => (given, ""),
    };
    let marker = shimmy::daemon::joints::write_marker(&dir, content)?;
    eprintln!(
        "shimmyd: wrote {} (new joints at {content} mm{from}); the daemon using {} takes it \
         within seconds, or at its next start, and collects the next {} used braking event(s) \
         as the car's baseline",
        marker.display(),
        dir.display(),
        c.vehicle.baseline_events
    );
    Ok(())
}

fn main() {
    let cli = Cli::parse();
    let result = if let Some(dir) = &cli.journal_stress {
        journal_stress(dir)
    } else {
        let config = cli.config.expect("clap requires --config");
        if let Some(mm) = &cli.joints_replaced {
            joints_replaced(&config, cli.profile.as_deref(), cli.state_dir, mm)
        } else if cli.sandbox_dropin {
            sandbox_dropin(&config)
        } else if cli.check {
            check(&config, cli.profile.as_deref())
        } else {
            run(
                Options {
                    config,
                    profile: cli.profile,
                    replay: cli.replay,
                    fast: cli.fast,
                    state_dir: cli.state_dir,
                    journal_dir: None,
                },
                &shimmy::daemon::stage::for_daemon,
            )
        }
    };
    if let Err(e) = result {
        eprintln!("shimmyd: error: {e:#}");
        std::process::exit(1);
    }
}
