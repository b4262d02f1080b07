//! `shimmy report`: the workshop inspection report (HTML or JSON) from shimmyd's journal, its
//! state directory, or straight from CAN logs.

use std::path::PathBuf;

use anyhow::{bail, Context};
use clap::ValueEnum;

use crate::alerts::AlertsSection;
use crate::daemon::config::Config;
use crate::report::{from_journal, from_state, html};

#[derive(Clone, Copy, Debug, ValueEnum)]
pub enum Format {
    Html,
    Json,
}

/// Writes a workshop inspection report a mechanic can read without the tool: the verdict
/// first (joint condition, estimated clearance with its 90 % interval, trend over distance
/// against the 0.07 mm and 0.1 mm lines), then the evidence (steering-wheel angle and spectrum
/// of the worst braking events, the event table), the study's maintenance guidance and the
/// data-quality counters. HTML is one self-contained file (inline SVG, no scripts, no external
/// assets); JSON carries the same content for machines.
///
/// Sources (exactly one):
///   --journal DIR   shimmyd's journal directory (complete: traces, trend, alert history)
///   --state DIR     shimmyd's state directory (latest estimate and recent events only)
///   LOG...          CAN logs (candump -L, ASC, BLF, MF4, TRC) of one vehicle in time order,
///                   replayed through the daemon's pipeline with the car of --profile (its
///                   DBC, mapping and table; default thresholds) or with --config's car and
///                   thresholds
///
/// Examples:
///   shimmy report --journal /var/lib/shimmyd/journal --out report.html
///   shimmy report --profile toyota_rav4 drive1.log drive2.log --out report.html
///   shimmy report --config config/shimmyd.toml drive1.log drive2.log --format json
#[derive(clap::Args, Debug)]
#[command(verbatim_doc_comment)]
pub struct Args {
    /// shimmyd journal directory.
    #[arg(long, value_name = "DIR", conflicts_with_all = ["state", "logs"])]
    pub journal: Option<PathBuf>,
    /// shimmyd state directory.
    #[arg(long, value_name = "DIR", conflicts_with = "logs")]
    pub state: Option<PathBuf>,
    /// CAN logs to analyse directly.
    #[arg(value_name = "LOG")]
    pub logs: Vec<PathBuf>,
    /// shimmyd configuration: thresholds for the verdict and, with LOGs, the car.
    #[arg(long, value_name = "FILE")]
    pub config: Option<PathBuf>,
    /// With LOGs: the vehicle profile (config/vehicles/<NAME>) whose bus they carry.
    #[arg(
        long,
        value_name = "NAME",
        conflicts_with = "config",
        requires = "logs"
    )]
    pub profile: Option<String>,
    #[arg(long, value_enum, default_value = "html")]
    pub format: Format,
    /// Output file (default: stdout).
    #[arg(long, value_name = "FILE")]
    pub out: Option<PathBuf>,
}

pub fn run(args: Args) -> anyhow::Result<()> {
    let cfg = match &args.config {
        Some(p) => {
            let c = Config::load(p)?;
            c.print_warnings();
            Some(c)
        }
        None => None,
    };
    let alerts = cfg
        .as_ref()
        .map_or_else(AlertsSection::default, |c| c.alerts.clone());
    let data = if let Some(j) = &args.journal {
        from_journal(j, &alerts)?
    } else if let Some(s) = &args.state {
        from_state(s, &alerts)?
    } else if !args.logs.is_empty() {
        let tmp = std::env::temp_dir().join(format!("shimmy-report-{}", std::process::id()));
        let _ = std::fs::remove_dir_all(&tmp);
        let cfg_path = match (&args.config, &args.profile) {
            (Some(c), _) => c.clone(),
            (None, Some(name)) => {
                // The daemon's defaults for everything but the car.
                let dir = crate::profile::find(name)?;
                let dir = dir.canonicalize().unwrap_or(dir);
                std::fs::create_dir_all(&tmp)
                    .with_context(|| format!("cannot create {}", tmp.display()))?;
                let p = tmp.join("shimmyd.toml");
                let text = format!(
                    "[input]\nprofile = {:?}\n[outputs]\njournal_dir = {:?}\nstate_dir = {:?}\n",
                    dir.display().to_string(),
                    tmp.join("journal").display().to_string(),
                    tmp.join("state").display().to_string()
                );
                std::fs::write(&p, text)
                    .with_context(|| format!("cannot write {}", p.display()))?;
                p
            }
            (None, None) => bail!(
                "reading LOGs needs --profile NAME (the car) or --config FILE (car and thresholds)"
            ),
        };
        let cfg_path = &cfg_path;
        let opts = crate::daemon::run::Options {
            config: cfg_path.clone(),
            profile: None,
            replay: args.logs.clone(),
            fast: true,
            state_dir: Some(tmp.join("state")),
            journal_dir: Some(tmp.join("journal")),
        };
        let r = crate::daemon::run::run(opts, &crate::daemon::stage::for_config)
            .and_then(|_| from_journal(&tmp.join("journal"), &alerts));
        let _ = std::fs::remove_dir_all(&tmp);
        let mut d = r?;
        d.source = format!(
            "logs {}",
            args.logs
                .iter()
                .map(|p| p.display().to_string())
                .collect::<Vec<_>>()
                .join(", ")
        );
        d
    } else {
        bail!("give --journal DIR, --state DIR or LOG files");
    };
    let text = match args.format {
        Format::Html => html(&data),
        Format::Json => serde_json::to_string_pretty(&data)? + "\n",
    };
    match &args.out {
        Some(p) => {
            std::fs::write(p, text).with_context(|| format!("cannot write {}", p.display()))?
        }
        None => {
            use std::io::Write;
            std::io::stdout().write_all(text.as_bytes())?;
        }
    }
    Ok(())
}
