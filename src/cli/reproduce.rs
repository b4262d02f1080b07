//! `shimmy reproduce`: rerun the source article's numerical experiments on our model and write
//! docs/REPRODUCTION.md with its figures, reporting every claim of the article with our number
//! and a verdict.
//!
//! What it is: a deterministic batch (seeded runs, both cores via
//! `crate::analysis::sweep::par_map`) whose output is a Markdown report and SVG figures. What
//! it is not: a tuning loop — nothing here adjusts the model towards the article's numbers.

mod figures;
mod plan;
mod plot;
mod report;
mod runs;

use crate::analysis::sweep::{default_threads, par_map, MeanStd};
use anyhow::{Context, Result};
use std::path::PathBuf;

pub use plan::Plan;
pub use report::CLAIM_IDS;
pub use runs::{Case, Outcome, Variant};

/// Regenerate docs/REPRODUCTION.md and its figures (docs/reproduction/*.svg).
///
/// Runs the article's experiments on the MODEL.md model: the §3.1 time-step convergence study
/// (h = 1e-4, 5e-5, 1e-5 s), dual versus single clearance, the clearance sweep 0.03–0.4 mm
/// (time histories, PSD, phase portraits, Poincaré sections, CWT maps, Lyapunov exponents,
/// spectral concentration), the speed sweep 20–120 km/h, X versus Y contact forces, stiffness
/// sweeps, braking intensity and the article's damping value; then writes one table row per
/// claim of the article with our number and whether it holds. Results are means over seeds.
/// The full run takes a few minutes in release mode on two cores; `--quick` runs a reduced
/// grid with one seed (seconds) to check that the pipeline works — its verdicts are
/// indicative only.
#[derive(clap::Args, Debug)]
pub struct Args {
    /// Output folder: REPRODUCTION.md goes here, figures into <OUT>/reproduction/.
    #[arg(long, default_value = "docs")]
    pub out: PathBuf,
    /// Reduced grid, one seed (a smoke test of the whole pipeline).
    #[arg(long)]
    pub quick: bool,
    /// Seeds per case (unbalance phases and road noise differ per seed); default 3, 1 with --quick.
    #[arg(long)]
    pub seeds: Option<usize>,
    /// Worker threads (default: SHIMMY_THREADS or all cores).
    #[arg(long)]
    pub threads: Option<usize>,
}

/// All outcomes of a reproduction, with the cases that failed.
pub struct Results {
    pub plan: Plan,
    pub outcomes: Vec<Outcome>,
    pub failures: Vec<(Case, String)>,
    pub threads: usize,
    pub wall_s: f64,
}

impl Results {
    /// Outcomes whose case satisfies `f`.
    pub fn select(&self, f: impl Fn(&Case) -> bool) -> Vec<&Outcome> {
        self.outcomes.iter().filter(|o| f(&o.case)).collect()
    }

    /// Mean and std over the outcomes matching `f` of `g`.
    pub fn stat(&self, f: impl Fn(&Case) -> bool, g: impl Fn(&Outcome) -> f64) -> Option<MeanStd> {
        let v: Vec<f64> = self.select(f).into_iter().map(g).collect();
        MeanStd::of(&v)
    }
}

pub fn run(args: Args) -> Result<()> {
    let seeds = args.seeds.unwrap_or(if args.quick { 1 } else { 3 });
    let plan = Plan::new(args.quick, seeds);
    let threads = args.threads.unwrap_or_else(default_threads).max(1);
    let cases = plan.cases();
    eprintln!(
        "shimmy reproduce: {} runs ({} mode, {} seed(s)) on {} thread(s)…",
        cases.len(),
        if plan.quick { "quick" } else { "full" },
        plan.seeds.len(),
        threads
    );
    let t0 = std::time::Instant::now();
    // Longest runs first so the two threads finish together.
    let mut order: Vec<Case> = cases.clone();
    order.sort_by(|a, b| cost(b).total_cmp(&cost(a)));
    let results = par_map(&order, threads, |c| (*c, runs::run_case(c)));
    let mut outcomes = Vec::new();
    let mut failures = Vec::new();
    for (c, r) in results {
        match r {
            Ok(o) => outcomes.push(o),
            Err(e) => failures.push((c, format!("{e:#}"))),
        }
    }
    let res = Results {
        plan,
        outcomes,
        failures,
        threads,
        wall_s: t0.elapsed().as_secs_f64(),
    };
    eprintln!(
        "shimmy reproduce: simulated in {:.1} s ({} failed); writing {}",
        res.wall_s,
        res.failures.len(),
        args.out.display()
    );
    let fig_dir = args.out.join("reproduction");
    std::fs::create_dir_all(&fig_dir).with_context(|| format!("creating {}", fig_dir.display()))?;
    let figs = figures::write_all(&res, &fig_dir)?;
    let doc = report::markdown(&res, &figs);
    let path = args.out.join("REPRODUCTION.md");
    std::fs::write(&path, doc).with_context(|| format!("writing {}", path.display()))?;
    eprintln!(
        "shimmy reproduce: wrote {} and {} figures",
        path.display(),
        figs.len()
    );
    Ok(())
}

/// Rough relative cost of a case (steps × twin factor), for scheduling.
fn cost(c: &Case) -> f64 {
    let dur = c
        .duration_s
        .unwrap_or(0.65 + c.v0_kmh / 3.6 / (c.decel_g * 9.81) + 2.0);
    dur / c.h_s * if c.lyapunov { 2.0 } else { 1.0 }
}
