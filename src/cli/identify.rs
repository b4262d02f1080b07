//! `shimmy identify`: names the vehicle profile a CAN log comes from, with its evidence.
//!
//! This module is the command line and the output only; the fingerprint and the judgement are
//! [`crate::profile::identify`]'s.

use std::io::Write;
use std::path::PathBuf;

use anyhow::Context;

use crate::profile::identify::{
    self, Catalogue, Identification, MessageEvidence, Options, ProfileEvidence, Verdict,
};
use crate::profile::Profile;

/// The manual part of `shimmy identify --help`.
const MANUAL: &str = "\
Reads the first --seconds of each LOG (candump -L, Vector ASC, BLF, MF4 or PEAK TRC) and
compares what it sees with every vehicle profile (the folders <name>/profile.toml found in
$SHIMMY_PROFILES, ./config/vehicles, /etc/shimmyd/vehicles and the source tree's
config/vehicles, first of a name wins): for each message a profile expects (the messages its
mapping reads, and those of its bus.toml, when it has one),
  present        frames with its ID on one bus channel
  length         the share of frames whose payload has the DBC's length
  period         the measured send period against bus.toml's (or the DBC's GenMsgCycleTime)
  checksum       the share of frames whose checksum verifies, where the mapping declares one
  counter        the share of steps where the rolling counter advances by exactly one
IDs and lengths are weak evidence (other cars use the same IDs); checksums and counters are
strong (they hold by chance on 1 frame in 256, or 1 step in 16). A profile fits when every
message its mapping reads is there with its lengths, its declared checksums and counters
verify (90 % of frames, 80 % of counter steps), its periods match within a factor of 1.5, and
at least one checksum or counter verified.

Verdict per LOG:
  identified     exactly one profile fits (named, with its evidence)
  ambiguous      several fit equally well (they are named)
  unknown        none fits (the closest profile and what did not fit are named)

Text output (default): the verdict line, the evidence table of the chosen (or closest)
profile, one line per other profile. JSON (--format json): one object per LOG with verdict,
profile, candidates, closest, summary, frames_read, seconds_read, channels, other_ids,
malformed, and per profile (best first) fits, strength (strong, timing, weak), score (-1..1),
channel, problems and per message frames, dlc_match_fraction, period_ms_measured/_expected,
checksum and counter {what, checked, passed, verified}; an array when there are several LOGs.

Exit status: 0 when every LOG was identified, 3 when some LOG is unknown or ambiguous, 1 on
an error (a log that cannot be read, no profile that loads).

Examples:
  shimmy identify rav4_2017_seg40_bus0.log
  shimmy identify --format json --seconds 10 drive.blf
  shimmy identify --together --profile toyota_rav4 --profile vw_mqb part1.log part2.log";

/// Arguments of `shimmy identify`.
#[derive(clap::Args, Debug)]
#[command(after_long_help = MANUAL)]
pub struct Args {
    /// Log time looked at per LOG, from its first frame (s).
    #[arg(long, value_name = "S", default_value_t = 30.0)]
    pub seconds: f64,

    /// Compare with this profile only (name, alias or folder; repeatable). Default: every
    /// profile on the search path.
    #[arg(long, value_name = "NAME")]
    pub profile: Vec<String>,

    /// The LOGs are one vehicle's: one verdict for all of them together.
    #[arg(long)]
    pub together: bool,

    /// Output format.
    #[arg(long, value_enum, default_value_t = Format::Text)]
    pub format: Format,

    /// The logs to identify.
    #[arg(value_name = "LOG", required = true)]
    pub logs: Vec<PathBuf>,
}

pub use super::TextOrJson as Format;

/// One verdict with the logs it is about.
#[derive(serde::Serialize)]
struct Out<'a> {
    logs: Vec<String>,
    #[serde(flatten)]
    id: &'a Identification,
}

pub fn run(args: Args) -> anyhow::Result<()> {
    if !(args.seconds.is_finite() && args.seconds > 0.0) {
        anyhow::bail!("--seconds must be a positive number (got {})", args.seconds);
    }
    let cat = if args.profile.is_empty() {
        Catalogue::search_path()
    } else {
        let ps = args
            .profile
            .iter()
            .map(|n| Profile::load(n))
            .collect::<anyhow::Result<Vec<_>>>()?;
        Catalogue::of(&ps)?
    };
    if cat.candidates.is_empty() {
        let why: Vec<String> = cat
            .not_loaded
            .iter()
            .map(|n| format!("{}: {}", n.profile, n.error))
            .collect();
        anyhow::bail!("no vehicle profile could be loaded: {}", why.join("; "));
    }
    let opts = Options {
        max_seconds: args.seconds,
        ..Options::default()
    };
    let groups: Vec<Vec<PathBuf>> = if args.together {
        vec![args.logs.clone()]
    } else {
        args.logs.iter().map(|l| vec![l.clone()]).collect()
    };
    let mut results = Vec::new();
    for g in &groups {
        let id = identify::identify_logs_with(&cat, g, opts)?;
        results.push((g, id));
    }
    let mut out = std::io::stdout().lock();
    match args.format {
        Format::Json => {
            let outs: Vec<Out> = results
                .iter()
                .map(|(g, id)| Out {
                    logs: g.iter().map(|p| p.display().to_string()).collect(),
                    id,
                })
                .collect();
            if outs.len() == 1 {
                serde_json::to_writer_pretty(&mut out, &outs[0])?;
            } else {
                serde_json::to_writer_pretty(&mut out, &outs)?;
            }
            writeln!(out)?;
        }
        Format::Text => {
            for (g, id) in &results {
                let name: Vec<String> = g.iter().map(|p| p.display().to_string()).collect();
                write_text(&mut out, &name.join(" + "), id)?;
            }
        }
    }
    out.flush().context("writing the output")?;
    if results
        .iter()
        .any(|(_, id)| id.verdict != Verdict::Identified)
    {
        std::process::exit(3);
    }
    Ok(())
}

/// One message's evidence as a table row.
pub fn message_line(e: &MessageEvidence) -> String {
    let id = if e.extended {
        format!("0x{:08X}", e.id)
    } else {
        format!("0x{:03X}", e.id)
    };
    let mut s = format!("{:<24} {id:<10} {:>6} frames", e.name, e.frames);
    if e.frames == 0 {
        s += "  absent";
        return s;
    }
    match e.dlc_match_fraction {
        Some(f) if f >= identify::DLC_MIN_FRACTION => s += &format!("  len {} ok", e.dlc_expected),
        _ => s += &format!("  len {} (DBC {})", e.dlc_seen.unwrap_or(0), e.dlc_expected),
    }
    match (e.period_ms_measured, e.period_ms_expected) {
        (Some(m), Some(x)) => s += &format!("  {m:.1} ms (expected {x})"),
        (Some(m), None) => s += &format!("  {m:.1} ms"),
        _ => {}
    }
    for (label, c) in [("checksum", &e.checksum), ("counter", &e.counter)] {
        if let Some(c) = c {
            let v = match c.verified {
                Some(true) => "verified",
                Some(false) => "FAILS",
                None => "too few frames",
            };
            s += &format!("  {label} {} {}/{} {v}", c.what, c.passed, c.checked);
        }
    }
    s
}

fn profile_line(p: &ProfileEvidence) -> String {
    format!(
        "  {:<18} {:>5.2}  {}{}",
        p.profile,
        p.score,
        if p.fits { "fits: " } else { "" },
        p.summary
    )
}

/// The text report of one verdict.
pub fn write_text(out: &mut dyn Write, log: &str, id: &Identification) -> anyhow::Result<()> {
    writeln!(out, "{log}: {}", id.summary)?;
    writeln!(
        out,
        "  read {} frames over {:.1} s on {} channel(s){}",
        id.frames_read,
        id.seconds_read,
        id.channels.len(),
        if id.malformed > 0 {
            format!(", {} malformed lines or records skipped", id.malformed)
        } else {
            String::new()
        }
    )?;
    let shown: Vec<&ProfileEvidence> = match id.verdict {
        Verdict::Ambiguous => id
            .profiles
            .iter()
            .filter(|p| id.candidates.contains(&p.profile))
            .collect(),
        _ => id.chosen().into_iter().collect(),
    };
    for p in &shown {
        writeln!(
            out,
            "  {} ({}) on channel {}:",
            p.profile,
            if p.fits { "fits" } else { "closest" },
            p.channel.as_deref().unwrap_or("-")
        )?;
        for m in &p.messages {
            writeln!(out, "    {}", message_line(m))?;
        }
    }
    let rest: Vec<&ProfileEvidence> = id
        .profiles
        .iter()
        .filter(|p| !shown.iter().any(|s| s.profile == p.profile))
        .collect();
    if !rest.is_empty() {
        writeln!(out, "  other profiles (score, what does not fit):")?;
        for p in rest {
            writeln!(out, "{}", profile_line(p))?;
        }
    }
    for n in &id.not_loaded {
        writeln!(out, "  not compared: {}: {}", n.profile, n.error)?;
    }
    Ok(())
}
