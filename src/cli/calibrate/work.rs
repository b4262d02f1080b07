//! The expensive half of `shimmy calibrate`: the model runs of a table build, on all cores, each
//! run measured through every steering angle sensor the build serves, one checkpoint file per
//! finished job in a work directory (so a killed build resumes where it stopped and ends with
//! the same table), and progress with an ETA on stderr.
//!
//! A job is one pull-away of one drawn vehicle at one clearance, branching into every speed
//! and deceleration of the grid ([`crate::observer::simulate::run_model_grid`]): the model's
//! output is sensor-independent, so the same run gives the events of every sensor
//! ([`crate::observer::simulate::measure_run`]), which is what lets one build serve several
//! vehicle profiles that share a chassis.
//!
//! What it is not: the statistics of the table (the parent module) or the model.

use std::io::{IsTerminal, Write};
use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicBool, AtomicUsize, Ordering};
use std::sync::Mutex;
use std::time::{Duration, Instant};

use anyhow::{bail, Context};
use serde::{Deserialize, Serialize};

use super::{Grid, TableEvent};
use crate::model::VehicleParams;
use crate::observer::emulate::RawEvent;
use crate::observer::features::{z, z_cruise};
use crate::observer::sensor::SensorModel;
use crate::observer::simulate::{measure_run, run_model_grid};
use crate::observer::ObserverConfig;

/// Format tag of a work directory's manifest.
pub const WORK_FORMAT: &str = "shimmy calibrate work v1";

/// What a work directory was started for: the chassis and the model runs
/// ([`super::model_fingerprint`]) must match; every part holds the events of `sensors`, which
/// a later build may use any subset of.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
struct Manifest {
    format: String,
    vehicle_hash: String,
    grid: String,
    sensors: Vec<SensorModel>,
}

/// One finished job: its events per sensor, in [`job_events`] order.
#[derive(Serialize, Deserialize)]
struct Part {
    job: Job,
    events: Vec<Vec<TableEvent>>,
}

/// One model job: the pull-away of drawn vehicle `im` at clearance `ic`, replicate `rep`.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
pub struct Job {
    pub ic: usize,
    pub im: usize,
    pub rep: usize,
}

/// The jobs of a build, in order.
pub fn jobs(grid: &Grid) -> Vec<Job> {
    let mut out = Vec::new();
    for ic in 0..grid.clearance_mm.len() {
        for im in 0..grid.vehicles as usize {
            for rep in 0..grid.seeds as usize {
                out.push(Job { ic, im, rep });
            }
        }
    }
    out
}

/// The seed of event (ic, im, iv, id, rep): the tuple in fixed radices past `seed_base +
/// 10 000`, so that an event's seed (and its vehicle's draw) does not depend on how many
/// vehicles or replicates the build has: a build of more vehicles reuses a smaller one's jobs
/// from the same work directory.
pub fn event_seed(grid: &Grid, ic: usize, im: usize, iv: usize, id: usize, rep: usize) -> u64 {
    let k = (((ic as u64 * 100_000 + im as u64) * 1_000 + iv as u64) * 100 + id as u64) * 100
        + rep as u64;
    grid.seed_base + 10_000 + k
}

/// Runs job `j` on `vehicle` (the drawn vehicle `j.im`) and measures it through each of
/// `sensors`: per sensor, the job's events ordered by speed, then deceleration.
pub fn run_job(
    vehicle: &VehicleParams,
    grid: &Grid,
    cfg: &ObserverConfig,
    sensors: &[SensorModel],
    j: Job,
) -> anyhow::Result<Vec<Vec<TableEvent>>> {
    let c_mm = grid.clearance_mm[j.ic];
    let speeds: Vec<f64> = grid.speed_kmh.iter().map(|v| v / 3.6).collect();
    // The model's seed for each speed: that of its first deceleration's event.
    let seeds: Vec<u64> = (0..speeds.len())
        .map(|iv| event_seed(grid, j.ic, j.im, iv, 0, j.rep))
        .collect();
    let runs = run_model_grid(
        vehicle,
        c_mm * 1e-3,
        &speeds,
        &grid.decel_g,
        &seeds,
        grid.shape,
        cfg,
        grid.ranges.hands.as_ref(),
    )
    .with_context(|| format!("model runs of vehicle {} at {c_mm} mm", j.im))?
    .runs;
    let mut out = vec![Vec::with_capacity(speeds.len() * grid.decel_g.len()); sensors.len()];
    for (iv, by_decel) in runs.iter().enumerate() {
        for (id, run) in by_decel.iter().enumerate() {
            let seed = event_seed(grid, j.ic, j.im, iv, id, j.rep);
            let (v, d) = (grid.speed_kmh[iv], grid.decel_g[id]);
            for (sensor, events) in sensors.iter().zip(&mut out) {
                let what = || {
                    format!(
                        "simulated event c = {c_mm} mm, vehicle {}, {v} km/h, {d} g, seed {seed}",
                        j.im
                    )
                };
                let e = measure_run(run, sensor, cfg, seed).with_context(what)?;
                let f = &e.features;
                let zz = z(f.rms_deg, f.peak_deg);
                let cruise = f.cruise_rms_deg.with_context(|| {
                    format!(
                        "{} has no pre-brake cruise window (events.pre_roll_s too short?)",
                        what()
                    )
                })?;
                events.push(TableEvent {
                    raw: RawEvent {
                        ic: j.ic,
                        im: j.im,
                        iv,
                        decel_g: d,
                        z: [zz[0], zz[1], z_cruise(cruise)],
                        phase_cos: e.phase_cos,
                    },
                    seed,
                    excess_rms_deg: f.excess_rms_deg,
                    true_peak_deg: e.true_peak_deg,
                });
            }
        }
    }
    Ok(out)
}

/// Progress of a build on stderr: a bar with an ETA on a terminal, otherwise a line every
/// `line_every` (and at the end), so that logs of unattended builds show it too.
pub struct Progress {
    total: usize,
    resumed: usize,
    done: AtomicUsize,
    started: Instant,
    bar: Option<indicatif::ProgressBar>,
    line_every: Duration,
    last_line: Mutex<Instant>,
    quiet: bool,
}

impl Progress {
    /// `total` jobs of `events_per_job` model events each, `resumed` of them already done.
    pub fn new(total: usize, resumed: usize, events_per_job: usize, quiet: bool) -> Progress {
        let tty = std::io::stderr().is_terminal();
        let bar = (tty && !quiet).then(|| {
            let b = indicatif::ProgressBar::new(total as u64);
            b.set_style(
                indicatif::ProgressStyle::with_template(
                    "shimmy calibrate {bar:40} {pos}/{len} jobs ({msg}) {elapsed} elapsed, ETA {eta}",
                )
                .expect("valid template"),
            );
            b.set_message(format!("{events_per_job} model events each"));
            b.set_position(resumed as u64);
            b
        });
        let line_every = std::env::var("SHIMMY_PROGRESS_EVERY_S")
            .ok()
            .and_then(|v| v.parse::<f64>().ok())
            .filter(|s| s.is_finite() && *s >= 0.0)
            .map_or(Duration::from_secs(30), Duration::from_secs_f64);
        Progress {
            total,
            resumed,
            done: AtomicUsize::new(resumed),
            started: Instant::now(),
            bar,
            line_every,
            last_line: Mutex::new(Instant::now()),
            quiet,
        }
    }

    /// One more job finished.
    pub fn tick(&self) {
        let done = self.done.fetch_add(1, Ordering::Relaxed) + 1;
        if let Some(b) = &self.bar {
            b.set_position(done as u64);
            return;
        }
        if self.quiet {
            return;
        }
        let mut last = self.last_line.lock().unwrap_or_else(|e| e.into_inner());
        if done == self.total || last.elapsed() >= self.line_every {
            *last = Instant::now();
            eprintln!("{}", self.line(done));
        }
    }

    /// "shimmy calibrate: 120/720 jobs (16.7 %), 2m 10s elapsed, ETA 10m 51s".
    fn line(&self, done: usize) -> String {
        let el = self.started.elapsed().as_secs_f64();
        let here = done.saturating_sub(self.resumed);
        let left = self.total.saturating_sub(done);
        let eta = if here > 0 {
            fmt_s(el / here as f64 * left as f64)
        } else {
            "unknown".into()
        };
        format!(
            "shimmy calibrate: {done}/{} jobs ({:.1} %), {} elapsed, ETA {eta}",
            self.total,
            100.0 * done as f64 / self.total.max(1) as f64,
            fmt_s(el)
        )
    }

    pub fn finish(&self) {
        if let Some(b) = &self.bar {
            b.finish_and_clear();
        }
    }
}

fn fmt_s(s: f64) -> String {
    let s = s.max(0.0).round() as u64;
    match (s / 3600, (s / 60) % 60, s % 60) {
        (0, 0, sec) => format!("{sec}s"),
        (0, m, sec) => format!("{m}m {sec:02}s"),
        (h, m, _) => format!("{h}h {m:02}m"),
    }
}

/// A build's work directory: the manifest and one `part-*.json` per finished job.
pub struct WorkDir {
    dir: PathBuf,
}

impl WorkDir {
    /// Opens (creating it if needed) the work directory `dir` for a build of `manifest`; a
    /// directory started for another chassis or other model runs is refused, and one started
    /// for other sensors unless they include the build's. Returns the directory and the
    /// sensors its parts hold (the build's sensors are measured through all of them, so that
    /// every part stays complete).
    fn open(dir: &Path, manifest: &Manifest) -> anyhow::Result<(WorkDir, Vec<SensorModel>)> {
        std::fs::create_dir_all(dir)
            .with_context(|| format!("cannot create work directory {}", dir.display()))?;
        let mpath = dir.join("manifest.json");
        if mpath.exists() {
            let text = std::fs::read_to_string(&mpath)
                .with_context(|| format!("cannot read {}", mpath.display()))?;
            let old: Manifest = serde_json::from_str(&text)
                .with_context(|| format!("{} is not a calibrate manifest", mpath.display()))?;
            let same_runs = old.format == manifest.format
                && old.vehicle_hash == manifest.vehicle_hash
                && old.grid == manifest.grid;
            if !same_runs || !manifest.sensors.iter().all(|s| old.sensors.contains(s)) {
                bail!(
                    "work directory {} belongs to another build (other vehicle, grid, detector or \
                     sensors); remove it or pass another --work-dir",
                    dir.display()
                );
            }
            return Ok((
                WorkDir {
                    dir: dir.to_path_buf(),
                },
                old.sensors,
            ));
        }
        write_atomic(&mpath, serde_json::to_string_pretty(manifest)?.as_bytes())?;
        Ok((
            WorkDir {
                dir: dir.to_path_buf(),
            },
            manifest.sensors.clone(),
        ))
    }

    fn part_path(&self, j: Job) -> PathBuf {
        self.dir
            .join(format!("part-{:03}-{:05}-{:03}.json", j.ic, j.im, j.rep))
    }

    /// The events of job `j` if a complete part file for it is there.
    fn load(&self, j: Job, sensors: usize, per_sensor: usize) -> Option<Vec<Vec<TableEvent>>> {
        let text = std::fs::read_to_string(self.part_path(j)).ok()?;
        let part: Part = serde_json::from_str(&text).ok()?;
        (part.job == j
            && part.events.len() == sensors
            && part.events.iter().all(|e| e.len() == per_sensor))
        .then_some(part.events)
    }

    fn save(&self, j: Job, events: &[Vec<TableEvent>]) -> anyhow::Result<()> {
        let part = Part {
            job: j,
            events: events.to_vec(),
        };
        write_atomic(&self.part_path(j), serde_json::to_string(&part)?.as_bytes())
    }
}

/// Writes `bytes` to `path` through a temporary file and a rename, so that a reader (or a
/// resumed build) sees the whole file or none of it.
pub fn write_atomic(path: &Path, bytes: &[u8]) -> anyhow::Result<()> {
    let tmp = path.with_extension(format!("tmp{}", std::process::id()));
    let mut f =
        std::fs::File::create(&tmp).with_context(|| format!("cannot write {}", tmp.display()))?;
    f.write_all(bytes)
        .and_then(|_| f.sync_all())
        .with_context(|| format!("cannot write {}", tmp.display()))?;
    drop(f);
    std::fs::rename(&tmp, path)
        .with_context(|| format!("cannot rename {} to {}", tmp.display(), path.display()))
}

/// The whole model half of a build: every job of `grid` on `vehicles` (the drawn nuisance
/// vehicles), each measured through every sensor, resumed from and checkpointed into
/// `work_dir` when given. Returns, per sensor, the events in the build's event order.
#[allow(clippy::too_many_arguments)]
pub fn run_all(
    vehicles: &[VehicleParams],
    vehicle_hash: &str,
    grid: &Grid,
    grid_fingerprint: &str,
    cfg: &ObserverConfig,
    sensors: &[SensorModel],
    threads: usize,
    work_dir: Option<&Path>,
    quiet: bool,
) -> anyhow::Result<Vec<Vec<TableEvent>>> {
    if grid.vehicles == 0 || grid.seeds == 0 {
        bail!("--vehicles and --seeds must be at least 1");
    }
    if sensors.is_empty() {
        bail!("no sensor to build a table for");
    }
    let jobs = jobs(grid);
    let per_job = grid.speed_kmh.len() * grid.decel_g.len();
    let (work, measured) = match work_dir {
        Some(d) => {
            let (w, s) = WorkDir::open(
                d,
                &Manifest {
                    format: WORK_FORMAT.into(),
                    vehicle_hash: vehicle_hash.into(),
                    grid: grid_fingerprint.into(),
                    sensors: sensors.to_vec(),
                },
            )?;
            (Some(w), s)
        }
        None => (None, sensors.to_vec()),
    };
    // Where each of the build's sensors sits among the measured ones.
    let pick: Vec<usize> = sensors
        .iter()
        .map(|s| measured.iter().position(|m| m == s).expect("a superset"))
        .collect();
    let sensors = &measured[..];
    let mut slots: Vec<Option<Vec<Vec<TableEvent>>>> = jobs
        .iter()
        .map(|&j| {
            work.as_ref()
                .and_then(|w| w.load(j, sensors.len(), per_job))
        })
        .collect();
    let resumed = slots.iter().filter(|s| s.is_some()).count();
    if resumed > 0 && !quiet {
        eprintln!(
            "shimmy calibrate: resuming: {resumed} of {} jobs already done in {}",
            jobs.len(),
            work_dir.map_or(String::new(), |d| d.display().to_string())
        );
    }
    let todo: Vec<usize> = (0..jobs.len()).filter(|&i| slots[i].is_none()).collect();
    let progress = Progress::new(jobs.len(), resumed, per_job, quiet);
    let next = AtomicUsize::new(0);
    let failed = AtomicBool::new(false);
    let results: Mutex<Vec<(usize, anyhow::Result<Vec<Vec<TableEvent>>>)>> = Mutex::new(Vec::new());
    let threads = threads.clamp(1, todo.len().max(1));
    std::thread::scope(|s| {
        for _ in 0..threads {
            s.spawn(|| loop {
                if failed.load(Ordering::Relaxed) {
                    break;
                }
                let k = next.fetch_add(1, Ordering::Relaxed);
                let Some(&i) = todo.get(k) else { break };
                let j = jobs[i];
                let r = run_job(&vehicles[j.im], grid, cfg, sensors, j).and_then(|ev| {
                    if let Some(w) = &work {
                        w.save(j, &ev)?;
                    }
                    Ok(ev)
                });
                if r.is_err() {
                    failed.store(true, Ordering::Relaxed);
                } else {
                    progress.tick();
                }
                results
                    .lock()
                    .unwrap_or_else(|e| e.into_inner())
                    .push((i, r));
            });
        }
    });
    progress.finish();
    let mut results = results.into_inner().unwrap_or_else(|e| e.into_inner());
    results.sort_by_key(|(i, _)| *i);
    for (i, r) in results {
        slots[i] = Some(r?);
    }
    // Per sensor, in event order: (ic, im, iv, id, rep) with rep innermost.
    let ns = grid.seeds as usize;
    let mut out: Vec<Vec<TableEvent>> = (0..sensors.len())
        .map(|_| Vec::with_capacity(jobs.len() * per_job))
        .collect();
    for chunk in slots.chunks(ns) {
        let by_rep: Vec<&Vec<Vec<TableEvent>>> = chunk
            .iter()
            .map(|s| s.as_ref().expect("every job ran or failed above"))
            .collect();
        for (k, o) in out.iter_mut().enumerate() {
            for e in 0..per_job {
                for rep in &by_rep {
                    o.push(rep[k][e]);
                }
            }
        }
    }
    // The build's sensors, in its order.
    Ok(pick.iter().map(|&k| std::mem::take(&mut out[k])).collect())
}
