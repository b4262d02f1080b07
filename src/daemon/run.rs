//! The shimmyd loop: opens the sources (live interfaces through
//! [`crate::source::socketcan::LiveSource`], read-only, one reader thread each; or replayed logs
//! at recorded timing or as fast as possible), feeds every frame to the
//! [`crate::signals::Mapper`], every accepted update to the [`EventStage`], every finished
//! event through the pipeline's shared step ([`crate::pipeline::finish_event`]: odometer,
//! estimate, the [`crate::alerts::AlertBook`]), and writes events, alerts and estimates to the
//! [`crate::journal`] and the [`super::state`].
//!
//! Signals: SIGTERM / SIGINT stop reading, close a braking event still open, journal it, fsync,
//! save the state and exit 0; SIGHUP re-reads the configuration and applies `[alerts]` and
//! `[log]` at once (a broken file is reported and the running configuration kept; `[input]`,
//! `[events]` and `[outputs]` changes need a restart, which is logged).
//! Disk faults: the journal is opened tolerant ([`crate::journal::Tolerance`]): when its disk
//! fills up or turns read-only, monitoring goes on, records wait in a bounded in-memory backlog
//! and are written when the disk takes them again; the change is logged both ways, counted
//! ([`Counters`]), kept in the state ([`State::journal`]) and, once over, journaled as a
//! `journal_outage` record. A state file that cannot be saved is logged and saved again
//! after the next event.
//! systemd: `READY=1` once the sources are open, `WATCHDOG=1` every second from the loop (so a
//! hung loop is restarted), `STOPPING=1` on the way out; all no-ops outside systemd.
//! Joint replacement: the workshop's marker `<state_dir>/joints_replaced` ([`super::joints`]) is
//! looked for at start, after every finished braking event and every [`MARKER_PERIOD`] (one
//! `stat(2)` each, never per frame). A marker is journaled (`joints_replaced`, with the estimate
//! before it), the alerts the old joints raised are cleared (reason `joints_replaced`), the
//! stage resets its estimate and collects the next `vehicle.baseline_events` used events as
//! the new baseline (the estimate records say so meanwhile; a `baseline` record when it is
//! complete); the marker is removed once the state recording the replacement is saved, and a
//! marker already recorded there is only removed. A bad marker is logged and renamed to
//! `joints_replaced.rejected`.
//!
//! What it is not: a network service (no listener), or the place where events are detected.

use std::collections::VecDeque;
use std::path::PathBuf;
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::{mpsc, Arc};
use std::time::{Duration, Instant};

use anyhow::{bail, Context};
use serde_json::json;

use super::config::Config;
use super::counters::Counters;
use super::joints::{self, MarkerId, Seen};
use super::stage::DaemonStage;
use super::state::{self, Replacement, State};
use crate::dbc::Database;
use crate::journal::{Journal, Setup, Tolerance};
use crate::monitor::{EventStage, EventSummary, Sample};
use crate::pipeline::{detector_sample, finish_event, Finished, SpeedIntegrator};
use crate::signals::mapping::MappingConfig;
use crate::signals::Mapper;
use crate::source::log::LogReader;
use crate::source::{CanSource, SourceStats};
use crate::wire::Frame;

/// Command-line overrides.
#[derive(Clone, Debug, Default)]
pub struct Options {
    pub config: PathBuf,
    /// Overrides the configuration's car (`input.profile`, `--profile`).
    pub profile: Option<String>,
    pub replay: Vec<PathBuf>,
    pub fast: bool,
    pub state_dir: Option<PathBuf>,
    /// Overrides outputs.journal_dir.
    pub journal_dir: Option<PathBuf>,
}

/// Builds the event stage for a configuration (the observer adapter, or [`crate::monitor::NoObserver`]).
/// [`run`] takes any factory of a [`DaemonStage`]: this one's stages cannot take a joint
/// replacement; shimmyd's ([`super::stage::for_daemon`]) can.
pub type StageFactory = dyn Fn(&Config) -> anyhow::Result<Box<dyn EventStage>>;

/// Longest time between two looks for the joint-replacement marker while running (besides the
/// look after every braking event).
pub const MARKER_PERIOD: Duration = Duration::from_secs(2);

/// Recorded-timing replay: once a frame is due, every frame due within this much after it is
/// handed over at once (at most this early), so the loop sleeps about once per slice.
const PACE_SLICE: Duration = Duration::from_millis(10);
/// Steering history kept for event traces (s) and its fixed capacity (samples).
const TRACE_HISTORY_S: f64 = 30.0;
const TRACE_CAP: usize = 8192;
/// Trace kept with an event: from this long before the onset to the end of the event (the
/// event is journaled when it ends, so nothing after it is known yet) (s).
const TRACE_PRE_S: f64 = 1.0;

fn log(msg: impl std::fmt::Display) {
    eprintln!("shimmyd: {msg}");
}

enum Feed {
    Frame(Frame),
    Idle,
    End,
}

/// Where frames come from.
enum Input {
    Replay {
        logs: VecDeque<PathBuf>,
        cur: Option<LogReader>,
        done: SourceStats,
        fast: bool,
        /// (first frame time, wall clock at it) for recorded-timing replay.
        anchor: Option<(i64, Instant)>,
        /// Frames due up to this offset from the anchor are released without a clock read.
        released: Duration,
    },
    Live {
        /// Frames read before the pipeline started (while the car was identified), handed
        /// over first.
        pending: VecDeque<Frame>,
        rx: mpsc::Receiver<Frame>,
        stats: Vec<Arc<std::sync::Mutex<SourceStats>>>,
        stops: Vec<Arc<AtomicBool>>,
        threads: Vec<std::thread::JoinHandle<()>>,
    },
}

impl Input {
    fn stats(&self) -> SourceStats {
        match self {
            Input::Replay { cur, done, .. } => {
                let mut s = done.clone();
                if let Some(r) = cur {
                    s.add(&r.stats());
                }
                s
            }
            Input::Live { stats, .. } => {
                let mut s = SourceStats::default();
                for st in stats {
                    s.add(&st.lock().expect("stats lock"));
                }
                s
            }
        }
    }

    fn next(&mut self, stop: &AtomicBool) -> anyhow::Result<Feed> {
        match self {
            Input::Replay {
                logs,
                cur,
                done,
                fast,
                anchor,
                released,
            } => loop {
                if cur.is_none() {
                    let Some(p) = logs.pop_front() else {
                        return Ok(Feed::End);
                    };
                    let r = LogReader::open(&p)
                        .with_context(|| format!("cannot open replay log {}", p.display()))?;
                    log(format_args!("replaying {} ({:?})", p.display(), r.format()));
                    *cur = Some(r);
                }
                let r = cur.as_mut().expect("set above");
                for s in r.take_skips() {
                    log(format_args!("skipped {}: {}", s.location, s.reason));
                }
                match r.next_frame().context("reading replay log")? {
                    Some(f) => {
                        if !*fast {
                            let (t0, w0) = *anchor.get_or_insert((f.t_ns, Instant::now()));
                            let due = Duration::from_nanos((f.t_ns - t0).max(0) as u64);
                            // Batch pacing: frames due before `released` (the clock at the last
                            // look plus PACE_SLICE) are handed over at once, without reading
                            // the clock; at bus rate the loop looks at the clock and sleeps
                            // once per slice, not once per frame (a sleep per frame cost more
                            // CPU than the processing). Sleep in short steps so signals are
                            // seen promptly.
                            while due > *released && !stop.load(Ordering::Relaxed) {
                                let now = w0.elapsed();
                                if due > now {
                                    std::thread::sleep((due - now).min(Duration::from_millis(50)));
                                } else {
                                    *released = now + PACE_SLICE;
                                }
                            }
                        }
                        return Ok(Feed::Frame(f));
                    }
                    None => {
                        done.add(&r.stats());
                        *cur = None;
                    }
                }
            },
            Input::Live { pending, .. } if !pending.is_empty() => {
                Ok(Feed::Frame(pending.pop_front().expect("not empty")))
            }
            Input::Live { rx, .. } => match rx.recv_timeout(Duration::from_millis(200)) {
                Ok(f) => Ok(Feed::Frame(f)),
                Err(mpsc::RecvTimeoutError::Timeout) => Ok(Feed::Idle),
                Err(mpsc::RecvTimeoutError::Disconnected) => Ok(Feed::End),
            },
        }
    }

    /// Tells the reader threads to stop; they finish the read in progress and exit.
    fn stop(&mut self) {
        if let Input::Live { stops, .. } = self {
            stops.iter().for_each(|s| s.store(true, Ordering::Relaxed));
        }
    }

    /// After [`Input::stop`]: the next frame the reader threads had read from the kernel but
    /// the daemon had not yet processed, so a stop loses none of them; `None` once every
    /// reader has exited and the queue is empty. (Readers blocked on a full queue are
    /// unblocked by this draining.)
    fn queued(&mut self) -> Option<Frame> {
        match self {
            Input::Live { rx, threads, .. } => loop {
                match rx.recv_timeout(Duration::from_millis(50)) {
                    Ok(f) => return Some(f),
                    Err(mpsc::RecvTimeoutError::Disconnected) => return None,
                    Err(mpsc::RecvTimeoutError::Timeout) => {
                        if threads.iter().all(|t| t.is_finished()) {
                            return rx.try_recv().ok();
                        }
                    }
                }
            },
            Input::Replay { .. } => None,
        }
    }

    /// Waits for the reader threads after [`Input::stop`] and the drain.
    fn join(&mut self) {
        if let Input::Live { threads, .. } = self {
            for t in threads.drain(..) {
                let _ = t.join();
            }
        }
    }
}

#[cfg(target_os = "linux")]
/// Opens the interfaces for reading; `ids` the kernel filter (`None`: every frame).
fn open_live(ifaces: &[String], ids: Option<&[(u32, bool)]>) -> anyhow::Result<Input> {
    use crate::source::socketcan::{FilterId, LiveConfig, LiveSource};
    let (tx, rx) = mpsc::sync_channel::<Frame>(16_384);
    let (mut stats, mut stops, mut threads) = (Vec::new(), Vec::new(), Vec::new());
    for name in ifaces {
        let mut cfg = LiveConfig::new(name);
        cfg.ids = ids.map(|ids| {
            ids.iter()
                .map(|&(id, ext)| {
                    if ext {
                        FilterId::extended(id)
                    } else {
                        FilterId::standard(id)
                    }
                })
                .collect()
        });
        // Bind the socket now when the interface is up, so that no frame sent after the
        // daemon says it started is missed; an interface not there yet is waited for (the
        // first read connects, with backoff).
        let mut src = match LiveSource::open(cfg.clone()) {
            Ok(src) => src,
            Err(_) => LiveSource::open_waiting(cfg)
                .with_context(|| format!("input.interfaces: cannot open {name}"))?,
        };
        let st = Arc::new(std::sync::Mutex::new(SourceStats::default()));
        stops.push(src.stop_handle());
        stats.push(st.clone());
        let tx = tx.clone();
        let name = name.clone();
        threads.push(
            std::thread::Builder::new()
                .name(format!("rx-{name}"))
                .spawn(move || loop {
                    match src.next_frame() {
                        Ok(Some(f)) => {
                            *st.lock().expect("stats lock") = src.stats();
                            if tx.send(f).is_err() {
                                return;
                            }
                        }
                        Ok(None) => return,
                        Err(e) if e.kind() == std::io::ErrorKind::TimedOut => {
                            *st.lock().expect("stats lock") = src.stats();
                        }
                        Err(e) => {
                            log(format_args!("{name}: {e}"));
                            std::thread::sleep(Duration::from_millis(200));
                        }
                    }
                })?,
        );
    }
    Ok(Input::Live {
        pending: VecDeque::new(),
        rx,
        stats,
        stops,
        threads,
    })
}

#[cfg(not(target_os = "linux"))]
fn open_live(_: &[String], _: Option<&[(u32, bool)]>) -> anyhow::Result<Input> {
    bail!("input.interfaces: live SocketCAN input needs Linux")
}

/// Steering samples of the last seconds, in a ring allocated once.
struct SteerHistory {
    buf: VecDeque<(i64, f64)>,
}

impl SteerHistory {
    fn push(&mut self, t_ns: i64, rad: f64) {
        if self.buf.len() == TRACE_CAP {
            self.buf.pop_front();
        }
        self.buf.push_back((t_ns, rad));
        let horizon = t_ns - (TRACE_HISTORY_S * 1e9) as i64;
        while self.buf.front().is_some_and(|&(t, _)| t < horizon) {
            self.buf.pop_front();
        }
    }

    /// `{t0, t_s: [...], angle_deg: [...]}` around an event (times relative to its onset).
    fn trace(&self, e: &EventSummary) -> serde_json::Value {
        let lo = e.t_start - TRACE_PRE_S;
        let hi = e.t_end;
        let (mut ts, mut xs) = (Vec::new(), Vec::new());
        for &(t, a) in &self.buf {
            let t = t as f64 * 1e-9;
            if t >= lo && t <= hi {
                ts.push(((t - e.t_start) * 1e4).round() / 1e4);
                xs.push((a.to_degrees() * 1e4).round() / 1e4);
            }
        }
        json!({ "t0": e.t_start, "t_s": ts, "angle_deg": xs })
    }
}

/// Everything the loop owns.
struct Daemon {
    cfg: Config,
    cfg_path: PathBuf,
    state_dir: PathBuf,
    journal: Journal,
    state: State,
    stage: Box<dyn DaemonStage>,
    mapper: Mapper,
    steer_msg: Option<usize>,
    history: SteerHistory,
    speed: SpeedIntegrator,
    events: u64,
    mqtt: Option<super::mqtt::Publisher>,
    /// The journal's writability when last looked at ([`Daemon::journal_health`]).
    journal_writable: bool,
    /// The last problem with the joint-replacement marker that was logged (each is logged
    /// once, not at every look).
    marker_problem: Option<String>,
}

impl Daemon {
    fn sample(&mut self, f: &Frame) -> Option<Sample> {
        let u = self.mapper.on_frame(f)?;
        let snap = self.mapper.snapshot(f.t_ns);
        let s = detector_sample(
            &u,
            &snap,
            self.steer_msg,
            self.cfg.settings.events.brake_on_bar * 1e5,
        );
        if let Some(a) = s.steer_rad {
            self.history.push(f.t_ns, a);
        }
        if let Some(v) = s.speed_mps {
            self.odometer(f.t_ns, v);
        }
        Some(s)
    }

    /// Integrates speed into the odometer ([`SpeedIntegrator`]).
    fn odometer(&mut self, t_ns: i64, v: f64) {
        self.state.odometer_km += self.speed.advance(t_ns, v) / 1000.0;
    }

    /// One finished event through the pipeline's shared step ([`finish_event`]: odometer,
    /// estimate, alert rules), then to the journal, MQTT and the state.
    fn on_event(&mut self, e: EventSummary) -> anyhow::Result<()> {
        let Finished {
            event: e,
            estimate: est,
            transitions,
        } = finish_event(
            self.stage.as_ref(),
            &mut self.state.alerts,
            &self.cfg.alerts,
            e,
            self.state.odometer_km,
        );
        self.events += 1;
        let trace = self.history.trace(&e);
        self.journal.append(&json!({
            "type": "event",
            "event": &e,
            "trace": trace,
        }))?;
        // The event completed a baseline collection: the estimate after it is conditioned on it.
        let completed = self.stage.take_completed_baseline();
        if let Some(done) = &completed {
            self.journal.append(&json!({
                "type": "baseline",
                "source": "joints_replaced",
                "t": e.t_end,
                "odometer_km": e.odometer_km,
                "baseline": done,
            }))?;
        }
        if let Some(est) = &est {
            self.journal_estimate(Some(e.t_end), e.odometer_km, est)?;
        }
        // The event first, then the alerts it raised or cleared.
        log(format_args!(
            "braking event at {:.2} s: {:.1} km/h, {:.2} g, amplitude {}, {}",
            e.t_start,
            e.v0_kmh,
            e.decel_g,
            e.sw_amplitude_deg
                .map_or("n/a".to_string(), |a| format!("{a:.3} deg")),
            if e.used { "used" } else { "not used" }
        ));
        if let Some(done) = &completed {
            log(format_args!(
                "baseline after the joint replacement complete: {} event(s) at {} mm (angle \
                 estimator took {}, torque {}); estimating from now on",
                done.events, done.clearance_mm, done.used.angle_events, done.used.torque_events
            ));
        } else if let Some(c) = self.stage.baseline_collection() {
            log(c.text());
        }
        for t in &transitions {
            let (what, a) = t.parts();
            log(format_args!(
                "alert {what}: #{} {}: {}",
                a.id,
                a.kind.as_str(),
                a.summary
            ));
            self.journal
                .append(&json!({ "type": "alert", "transition": what, "alert": a }))?;
        }
        self.state.estimate = est;
        self.state.push_event(e);
        self.journal.sync()?;
        self.journal_health();
        // MQTT sends from the journal: the event, estimate and alert records just made durable.
        if let Some(m) = &self.mqtt {
            m.journal_durable(self.journal.durable_seq());
        }
        // The state is a cache of what the journal holds: a disk that refuses it costs a
        // faster resume, not monitoring. Saved again after the next event.
        if let Err(e) = self.save_state() {
            log(format_args!(
                "state: {e:#}; kept in memory, saved again after the next event"
            ));
        }
        self.check_marker()
    }

    /// An `estimate` record; while a baseline is being collected after a joint replacement it
    /// says so (`baseline_collection`), the estimate itself then having no event.
    fn journal_estimate(
        &mut self,
        t: Option<f64>,
        odometer_km: f64,
        est: &crate::monitor::Estimate,
    ) -> anyhow::Result<()> {
        let mut rec = json!({
            "type": "estimate",
            "t": t,
            "odometer_km": odometer_km,
            "estimate": est,
        });
        if let Some(c) = self.stage.baseline_collection() {
            rec["baseline_collection"] = json!({
                "collected": c.collected,
                "events": c.events,
                "clearance_mm": c.clearance_mm,
                "text": c.text(),
            });
        }
        self.journal.append(&rec)?;
        Ok(())
    }

    /// Logs a marker problem once (until another one, or none, is seen).
    fn marker_problem(&mut self, msg: String) {
        if self.marker_problem.as_deref() != Some(msg.as_str()) {
            log(&msg);
            self.marker_problem = Some(msg);
        }
    }

    /// Looks for the joint-replacement marker ([`joints::look`]) and acts on what it finds.
    fn check_marker(&mut self) -> anyhow::Result<()> {
        match joints::look(&self.state_dir) {
            Seen::Nothing | Seen::Settling => {
                self.marker_problem = None;
                Ok(())
            }
            Seen::Unreadable(e) => {
                self.marker_problem(format!("joints_replaced: {e}"));
                Ok(())
            }
            Seen::Bad { reason } => self.reject_marker(&reason),
            Seen::Marker { id, .. }
                if self.state.replacement.as_ref().map(|r| &r.marker) == Some(&id) =>
            {
                // Handled already; the daemon stopped (or the state could not be saved) before
                // the marker was removed. The state recording it is saved first.
                self.settle_marker(&id, "already handled; ");
                Ok(())
            }
            Seen::Marker { id, clearance_mm } => self.joints_replaced(id, clearance_mm),
        }
    }

    /// A marker that cannot be taken: an error in the log and the journal, the file renamed.
    fn reject_marker(&mut self, reason: &str) -> anyhow::Result<()> {
        let p = joints::path(&self.state_dir);
        let renamed = joints::reject(&self.state_dir);
        let msg = format!(
            "error: joints_replaced: {} rejected: {reason}; nothing was reset{}",
            p.display(),
            match &renamed {
                Ok(to) => format!(
                    "; renamed to {} (write a new marker: `shimmyd --joints-replaced [MM]`)",
                    to.display()
                ),
                Err(e) => format!("; {e:#}"),
            }
        );
        self.marker_problem(msg);
        if renamed.is_ok() {
            self.marker_problem = None;
            self.journal.append(&json!({
                "type": "joints_replaced_rejected",
                "marker": p.display().to_string(),
                "reason": reason,
                "renamed_to": renamed.as_ref().ok().map(|p| p.display().to_string()),
            }))?;
            self.journal.sync()?;
        }
        Ok(())
    }

    /// The joints were replaced (marker `id`, new clearance `clearance_mm` or the configured
    /// one): journal it, clear the old joints' alerts, reset the estimate and start the
    /// baseline collection, save the state, then remove the marker.
    fn joints_replaced(&mut self, id: MarkerId, clearance_mm: Option<f64>) -> anyhow::Result<()> {
        let clearance = clearance_mm.unwrap_or(self.cfg.vehicle.baseline_clearance_mm);
        let events = self.cfg.vehicle.baseline_events;
        let t = self.mapper.now_ns().map(|t| t as f64 * 1e-9);
        let before = self.state.estimate.clone();
        let collection = self.stage.joints_replaced(clearance, events);
        let wall = std::time::SystemTime::now()
            .duration_since(std::time::UNIX_EPOCH)
            .map_or(0.0, |d| d.as_secs_f64());
        let cleared = self
            .state
            .alerts
            .clear_all(t, "the steering joints were replaced (workshop marker)");
        let marker = joints::path(&self.state_dir);
        match &collection {
            Ok(()) => log(format_args!(
                "joints replaced ({}): new joints at {clearance} mm; clearance estimate reset \
                 (it was {}), {} alert(s) cleared; the next {events} used braking event(s) \
                 become the vehicle's baseline",
                marker.display(),
                estimate_words(before.as_ref()),
                cleared.len()
            )),
            Err(e) => log(format_args!(
                "joints replaced ({}): {} alert(s) cleared; no baseline is collected: {e:#}",
                marker.display(),
                cleared.len()
            )),
        }
        self.journal.append(&json!({
            "type": "joints_replaced",
            "t": t,
            "wall_unix_s": wall,
            "odometer_km": self.state.odometer_km,
            "clearance_mm": clearance,
            "clearance_from": if clearance_mm.is_some() { "marker" } else { "vehicle.baseline_clearance_mm" },
            "baseline_events": events,
            "estimate_before": before,
            "alerts_cleared": cleared.iter().map(|a| a.id).collect::<Vec<_>>(),
            "baseline": match &collection {
                Ok(()) => "collecting".to_string(),
                Err(e) => format!("not collected: {e:#}"),
            },
            "marker": {
                "path": marker.display().to_string(),
                "mtime_unix_s": id.mtime_unix_s(),
                "content": &id.content,
            },
        }))?;
        for a in &cleared {
            log(format_args!(
                "alert cleared: #{} {}: joints replaced",
                a.id,
                a.kind.as_str()
            ));
            self.journal.append(&json!({
                "type": "alert",
                "transition": "cleared",
                "reason": "joints_replaced",
                "alert": a,
            }))?;
        }
        // The estimate after the reset: no event yet, so no clearance is claimed.
        self.state.estimate = self.stage.estimate();
        if let Some(est) = self.state.estimate.clone() {
            self.journal_estimate(t, self.state.odometer_km, &est)?;
        }
        self.state.replacement = Some(Replacement {
            marker: id.clone(),
            t,
            wall_unix_s: wall,
            odometer_km: self.state.odometer_km,
            clearance_mm: clearance,
            baseline_events: events,
            baseline_logs: self.cfg.vehicle.baseline_logs.clone(),
            baseline_clearance_mm: self.cfg.vehicle.baseline_clearance_mm,
        });
        self.journal.sync()?;
        self.journal_health();
        if let Some(m) = &self.mqtt {
            m.journal_durable(self.journal.durable_seq());
        }
        self.settle_marker(&id, "");
        Ok(())
    }

    /// Saves the state (which records the replacement of marker `id`), then removes the
    /// marker; when the state cannot be saved the marker stays, to be tried again at the next
    /// look (or seen again at the next start).
    fn settle_marker(&mut self, id: &MarkerId, what: &str) {
        if let Err(e) = self.save_state() {
            self.marker_problem(format!(
                "joints_replaced: {what}state not saved ({e:#}); the marker is removed once it is"
            ));
            return;
        }
        match joints::remove(&self.state_dir, id) {
            Ok(true) => {
                self.marker_problem = None;
                log(format_args!(
                    "joints_replaced: {what}state saved, marker {} removed",
                    joints::path(&self.state_dir).display()
                ));
            }
            Ok(false) => self.marker_problem = None,
            Err(e) => self.marker_problem(format!("joints_replaced: {e:#}")),
        }
    }

    /// Logs the journal's changes between writing and refusing to write, and journals an
    /// outage once it is over.
    fn journal_health(&mut self) {
        let writable = self.journal.writable();
        if writable == self.journal_writable {
            return;
        }
        self.journal_writable = writable;
        let h = self.journal.health();
        if !writable {
            log(format_args!(
                "journal: the disk refuses writes ({}): monitoring goes on, records wait in memory (up to {} KiB, oldest dropped beyond) and are written when it takes them again",
                h.error.as_deref().unwrap_or("?"),
                Tolerance::default().backlog_bytes / 1024
            ));
        } else {
            log(format_args!(
                "journal: writing again; {} record(s) written late, {} dropped{} since start, {} failed write(s)",
                h.delayed_records,
                h.dropped_records,
                h.dropped_seqs
                    .map_or(String::new(), |(a, b)| format!(" (seq {a}..={b})")),
                h.write_errors
            ));
            let _ = self
                .journal
                .append(&json!({ "type": "journal_outage", "health": h }));
        }
    }

    fn save_state(&mut self) -> anyhow::Result<()> {
        self.state.journal = Some(self.journal.health());
        self.state.journal_seq = self.journal.durable_seq();
        self.state.stage = self.stage.save();
        self.state.last_speed = self.speed.last;
        state::save(&self.state_dir, &self.state)
    }

    fn reload(&mut self) {
        match Config::load(&self.cfg_path) {
            Err(e) => log(format_args!(
                "SIGHUP: configuration not reloaded, keeping the running one: {e:#}"
            )),
            Ok(new) => {
                if new.input != self.cfg.input
                    || new.events != self.cfg.events
                    || new.settings.events != self.cfg.settings.events
                    || new.outputs != self.cfg.outputs
                    || new.vehicle != self.cfg.vehicle
                    || new.observer != self.cfg.observer
                    || new.mqtt != self.cfg.mqtt
                {
                    log("SIGHUP: [input], [vehicle], [outputs], [mqtt] or the monitor's [events], [features] or [estimator] changed: these take effect after a restart");
                }
                self.cfg.alerts = new.alerts;
                self.cfg.log = new.log;
                log("SIGHUP: configuration reloaded ([alerts] and [log] applied)");
                let _ = self
                    .journal
                    .append(&json!({"type": "reload", "alerts": &self.cfg.alerts}));
            }
        }
    }
}

/// An estimate in words for the log.
fn estimate_words(est: Option<&crate::monitor::Estimate>) -> String {
    match est {
        None => "no estimate".into(),
        Some(e) if e.events_used == 0 => "no estimate yet".into(),
        Some(e) => {
            let what = match (e.clearance_mm, e.below_mm) {
                (Some(c), _) => format!("{c:.3} mm"),
                (None, Some(b)) => format!("below {b:.3} mm"),
                _ => "undecided".into(),
            };
            match e.p_above {
                Some(p) => format!(
                    "{what}, P(above the alert threshold) {:.0} %, over {} event(s)",
                    p * 100.0,
                    e.events_used
                ),
                None => format!("{what} over {} event(s)", e.events_used),
            }
        }
    }
}

/// Seconds of traffic looked at to identify the car when the configuration names none.
pub const IDENTIFY_SECONDS: f64 = 10.0;
/// Most frames kept while identifying a live bus (they are processed afterwards).
const IDENTIFY_MAX_FRAMES: usize = 200_000;

/// The car of a configuration that names none (no `input.profile`, no `dbc`/`mapping`): the
/// profile whose bus the replayed logs or the live interfaces carry ([`crate::profile::identify`],
/// the first [`IDENTIFY_SECONDS`] of traffic), said in the log. Live, the interfaces stay open
/// (unfiltered) and the frames read while identifying are returned with them, so none is lost.
fn identify_car(cfg: &Config, replay: &[PathBuf]) -> anyhow::Result<(PathBuf, Option<Input>)> {
    use crate::profile::identify::{identify_frames, identify_logs, Catalogue, Options, Verdict};
    let (id, input) = if !replay.is_empty() {
        (identify_logs(replay, IDENTIFY_SECONDS)?, None)
    } else {
        log(format_args!(
            "no car configured (input.profile): identifying it from {} s of traffic on {}",
            IDENTIFY_SECONDS,
            cfg.input.interfaces.join(", ")
        ));
        let mut input = open_live(&cfg.input.interfaces, None)?;
        let never = AtomicBool::new(false);
        let t0 = Instant::now();
        let mut frames = VecDeque::new();
        while t0.elapsed().as_secs_f64() < IDENTIFY_SECONDS && frames.len() < IDENTIFY_MAX_FRAMES {
            match input.next(&never)? {
                Feed::Frame(f) => frames.push_back(f),
                Feed::Idle => {}
                Feed::End => break,
            }
        }
        let cat = Catalogue::search_path();
        let opts = Options {
            max_seconds: IDENTIFY_SECONDS,
            ..Options::default()
        };
        let id = identify_frames(&cat, frames.iter().cloned(), opts);
        if let Input::Live { pending, .. } = &mut input {
            *pending = frames;
        }
        (id, Some(input))
    };
    match (id.verdict, &id.profile) {
        (Verdict::Identified, Some(name)) => {
            log(format_args!("car identified from its bus: {}", id.summary));
            Ok((crate::profile::find(name)?, input))
        }
        _ => bail!(
            "input.profile: no car configured, and none identified from its bus: {} (set \
             input.profile, or input.dbc and input.mapping; see `shimmy identify`)",
            id.summary
        ),
    }
}

/// Runs the daemon until the input ends (replay) or SIGTERM/SIGINT, with the event stage
/// `make_stage` builds for the configuration (shimmyd: [`super::stage::for_daemon`]; a
/// [`StageFactory`]'s stage runs too, without joint replacements).
pub fn run<F, S>(opts: Options, make_stage: &F) -> anyhow::Result<()>
where
    F: Fn(&Config) -> anyhow::Result<Box<S>> + ?Sized,
    S: DaemonStage + ?Sized,
{
    let mut cfg = Config::load_with_profile(&opts.config, opts.profile.as_deref())?;
    cfg.print_warnings();
    let replay = if opts.replay.is_empty() {
        cfg.input.replay.clone()
    } else {
        opts.replay.clone()
    };
    if replay.is_empty() && cfg.input.interfaces.is_empty() {
        bail!("input.interfaces: no interface configured and nothing to replay (give --replay LOG or set input.interfaces)");
    }
    let live = replay.is_empty();
    // No car configured: identify it from its bus, then load the profile found.
    let mut opened = None;
    if cfg.bus_files().is_none() {
        let (dir, input) = identify_car(&cfg, &replay)?;
        cfg = Config::load_with_profile(&opts.config, Some(&dir.display().to_string()))?;
        opened = input;
    }
    if let Some(j) = &opts.journal_dir {
        cfg.outputs.journal_dir = j.clone();
    }
    if let Some(t) = &cfg.vehicle.torque_table {
        log(format_args!(
            "torque table {}: the estimate comes from the steering torque where the bus carries \
             a live one, from the angle otherwise",
            t.display()
        ));
    }
    if let Some(p) = &cfg.profile {
        log(format_args!("vehicle profile: {}", p.label()));
        if let Some(t) = p.table_path.as_ref().filter(|t| !t.is_file()) {
            log(format_args!(
                "profile {} has no response table yet ({} missing; build it with `shimmy \
                 calibrate --profile {}`): no clearance estimate",
                p.name,
                t.display(),
                p.name
            ));
        }
    }
    let Some((dbc_path, mapping_path)) = cfg.bus_files() else {
        bail!("input: no profile and no dbc/mapping configured (set input.profile, e.g. \"toyota_rav4\")");
    };
    let (dbc_path, mapping_path) = (dbc_path.to_path_buf(), mapping_path.to_path_buf());
    let (db, report) = Database::load(&dbc_path)
        .with_context(|| format!("input.dbc: cannot load {}", dbc_path.display()))?;
    if !report.skipped.is_empty() {
        log(format_args!(
            "{}: {} DBC item(s) skipped (first: line {} {}: {})",
            dbc_path.display(),
            report.skipped.len(),
            report.skipped[0].line,
            report.skipped[0].item,
            report.skipped[0].reason
        ));
    }
    let mapping = MappingConfig::from_toml_file(&mapping_path).context("input.mapping")?;
    let mapper = Mapper::new(&db, &mapping).with_context(|| {
        format!(
            "input.mapping: {} does not fit the DBC",
            mapping_path.display()
        )
    })?;
    for w in mapper.warnings() {
        log(format_args!("mapping: {w}"));
    }
    let steer_msg = mapper
        .stats()
        .iter()
        .position(|m| m.name == mapping.steer_angle.message);

    let state_dir = opts
        .state_dir
        .clone()
        .unwrap_or(cfg.outputs.state_dir.clone());
    let (journal, rec) = Journal::open_with(
        &cfg.outputs.journal_dir,
        cfg.journal(),
        Setup {
            tolerance: Some(Tolerance::default()),
            ..Setup::default()
        },
    )
    .context("outputs.journal_dir")?;
    if rec.truncated_bytes > 0 || rec.corrupt_lines > 0 {
        log(format_args!(
            "journal recovery: cut a torn/corrupt tail of {} bytes, {} corrupt line(s) skipped, last good record {:?}",
            rec.truncated_bytes, rec.corrupt_lines, rec.last_seq
        ));
    }
    let (loaded, problem) = state::load(&state_dir).context("outputs.state_dir")?;
    if let Some(p) = problem {
        log(p);
    }
    let resumed = loaded.is_some();
    let st = loaded.unwrap_or_else(|| State {
        version: 1,
        odometer_km: cfg.vehicle.initial_odometer_km,
        ..State::default()
    });

    let term = Arc::new(AtomicBool::new(false));
    let hup = Arc::new(AtomicBool::new(false));
    for sig in [signal_hook::consts::SIGTERM, signal_hook::consts::SIGINT] {
        signal_hook::flag::register(sig, term.clone()).context("cannot install signal handler")?;
    }
    signal_hook::flag::register(signal_hook::consts::SIGHUP, hup.clone())
        .context("cannot install SIGHUP handler")?;

    let mut stage = make_stage(&cfg)?.into_daemon_stage();
    log(format_args!("event stage: {}", stage.describe()));
    // A joint replacement is newer than the configured baseline logs, unless these changed
    // since it was marked.
    let given_is_newer = st.replacement.as_ref().is_some_and(|r| {
        r.configured_baseline_is_newer(
            &cfg.vehicle.baseline_logs,
            cfg.vehicle.baseline_clearance_mm,
        )
    });
    if let Some(saved) = &st.stage {
        match stage.restore_with(saved, given_is_newer) {
            Ok(Some(msg)) => log(msg),
            Ok(None) => {}
            // A posterior that cannot be restored is reported, and estimation starts afresh;
            // the journal still holds every event.
            Err(e) => log(format_args!(
                "state: {e:#}; the clearance estimate starts afresh"
            )),
        }
    }
    let last_speed = st.last_speed;

    let mut input = if let Some(input) = opened {
        // Opened unfiltered to identify the car; the frames read meanwhile come first.
        input
    } else if live {
        open_live(&cfg.input.interfaces, Some(mapper.needed_ids()))?
    } else {
        Input::Replay {
            logs: replay.iter().cloned().collect(),
            cur: None,
            done: SourceStats::default(),
            fast: opts.fast || cfg.input.fast,
            anchor: None,
            released: Duration::ZERO,
        }
    };
    let mut sink = open_sink(&cfg, &db, live)?;
    let mqtt = if cfg.mqtt.enabled {
        let cursor = cfg
            .mqtt
            .cursor_file
            .clone()
            .unwrap_or_else(|| state_dir.join("mqtt-cursor.json"));
        let (p, opened) = super::mqtt::Publisher::start(
            &cfg.mqtt,
            &cfg.outputs.journal_dir,
            journal.next_seq(),
            &cursor,
        )?;
        p.journal_durable(journal.durable_seq());
        let pending = p.queued();
        if let Some(problem) = &opened.problem {
            log(format_args!("mqtt: {problem}"));
        }
        log(format_args!(
            "mqtt: publishing to {}:{} over {} as {} of fleet {} (QoS {}), from the journal at record {} (cursor {}), {} message(s) queued from before",
            cfg.mqtt.host,
            cfg.mqtt.port(),
            match cfg.mqtt.transport() {
                Some(super::config::Transport::Tcp) => "plain TCP",
                _ => "TLS",
            },
            cfg.mqtt.client_id,
            cfg.mqtt.fleet,
            cfg.mqtt.qos,
            opened.from_seq,
            cursor.display(),
            pending,
        ));
        Some(p)
    } else {
        None
    };

    let mut d = Daemon {
        cfg,
        cfg_path: opts.config.clone(),
        state_dir,
        journal,
        state: st,
        stage,
        mapper,
        steer_msg,
        history: SteerHistory {
            buf: VecDeque::with_capacity(TRACE_CAP),
        },
        speed: SpeedIntegrator::resume(last_speed),
        events: 0,
        mqtt,
        journal_writable: true,
        marker_problem: None,
    };
    d.journal_health();
    d.journal.append(&json!({
        "type": "start",
        "pid": std::process::id(),
        "mode": if live { "live" } else { "replay" },
        "inputs": if live { d.cfg.input.interfaces.iter().map(|s| s.to_string()).collect::<Vec<_>>() }
                  else { replay.iter().map(|p| p.display().to_string()).collect() },
        "resumed_state": resumed,
        "odometer_km": d.state.odometer_km,
        "journal_recovery": rec,
    }))?;
    d.journal.sync()?;
    let _ = sd_notify::notify(&[sd_notify::NotifyState::Ready]);
    log(format_args!(
        "started ({}), journal {}, state {}",
        if live { "live, read-only" } else { "replay" },
        d.cfg.outputs.journal_dir.display(),
        d.state_dir.display()
    ));
    d.check_marker()?;

    let mut last_counters = Counters::default();
    let mut last_rejections = None;
    let mut last_log = Instant::now();
    let mut last_watchdog = Instant::now();
    let mut last_tx = Instant::now();
    let mut last_marker = Instant::now();
    let mut frames_since_check = 0u32;
    let result = loop {
        if term.load(Ordering::Relaxed) {
            log("SIGTERM: stopping");
            break Ok(());
        }
        if hup.swap(false, Ordering::Relaxed) {
            d.reload();
        }
        let feed = match input.next(&term) {
            Ok(f) => f,
            Err(e) => break Err(e),
        };
        match feed {
            Feed::End => break Ok(()),
            Feed::Idle => {}
            Feed::Frame(f) => {
                if let Err(e) = process_frame(&mut d, &f) {
                    break Err(e);
                }
            }
        }
        frames_since_check += 1;
        if frames_since_check < 256 && !matches!(feed, Feed::Idle) {
            continue;
        }
        frames_since_check = 0;
        if let Err(e) = d.journal.tick() {
            break Err(e);
        }
        d.journal_health();
        if last_marker.elapsed() >= MARKER_PERIOD {
            last_marker = Instant::now();
            if let Err(e) = d.check_marker() {
                break Err(e);
            }
        }
        if last_watchdog.elapsed() >= Duration::from_secs(1) {
            let _ = sd_notify::notify(&[sd_notify::NotifyState::Watchdog]);
            last_watchdog = Instant::now();
        }
        if let Some((enc, sink)) = sink.as_mut() {
            if last_tx.elapsed() >= Duration::from_millis(100) {
                last_tx = Instant::now();
                if let Err(e) = transmit(&d, enc, sink) {
                    log(format_args!("transmit: {e:#}"));
                }
            }
        }
        if last_log.elapsed() >= Duration::from_secs(d.cfg.log.counters_interval_s) {
            let now = Counters::from_stats(&input.stats(), &d.mapper.stats(), d.events)
                .with_journal(&d.journal.health());
            log(format_args!(
                "last {} s: {}",
                d.cfg.log.counters_interval_s,
                now.minus(&last_counters)
            ));
            last_counters = now;
            last_log = Instant::now();
            // Rejected or missing braking events, whenever their counts changed.
            if let Some(r) = d.stage.rejections() {
                if r.counts.worth_reporting() && last_rejections != Some(r.counts) {
                    log(format_args!("braking: {}", r.text));
                }
                last_rejections = Some(r.counts);
            }
        }
    };
    input.stop();
    let _ = sd_notify::notify(&[sd_notify::NotifyState::Stopping]);
    // Frames the reader threads queued before they stopped are still processed (SIGTERM
    // loses no frame that was read from the bus).
    // After an error they are drained unprocessed (the readers must not block on the queue).
    let mut drain_err = None;
    while let Some(f) = input.queued() {
        if result.is_ok() && drain_err.is_none() {
            drain_err = process_frame(&mut d, &f).err();
        }
    }
    input.join();
    if let Some(e) = drain_err {
        return Err(e);
    }
    // Close an event still open (end of replay or SIGTERM mid-braking) so it is not lost.
    d.stage.odometer_km(d.state.odometer_km);
    if let Some(e) = d.stage.finish() {
        d.on_event(e)?;
    }
    let totals = Counters::from_stats(&input.stats(), &d.mapper.stats(), d.events)
        .with_journal(&d.journal.health());
    let rejections = d.stage.rejections();
    let mqtt = d
        .mqtt
        .take()
        .map(|m| m.shutdown(Duration::from_secs_f64(d.cfg.mqtt.drain_timeout_s)));
    d.journal.append(&json!({
        "type": "stop",
        "reason": if result.is_ok() { "end" } else { "error" },
        "counters": totals,
        "messages": d.mapper.stats(),
        "rejections": rejections.as_ref().map(|r| r.counts),
        "odometer_km": d.state.odometer_km,
        "estimate": &d.state.estimate,
        "mqtt": mqtt,
    }))?;
    d.journal.sync()?;
    d.journal_health();
    let h = d.journal.health();
    if h.backlog_records > 0 {
        log(format_args!(
            "journal: {} record(s) ({} bytes) still refused by the disk at exit ({}): they are lost",
            h.backlog_records,
            h.backlog_bytes,
            h.error.as_deref().unwrap_or("?")
        ));
    }
    if let Err(e) = d.save_state() {
        log(format_args!("state: {e:#}; not saved at exit"));
    }
    if let Some(r) = rejections.filter(|r| r.counts.worth_reporting()) {
        log(format_args!("braking: {}", r.text));
    }
    log(format_args!("stopped: {totals}"));
    result
}

#[cfg(target_os = "linux")]
type Sink = (super::transmit::Encoder, crate::source::socketcan::LiveSink);
#[cfg(not(target_os = "linux"))]
type Sink = (super::transmit::Encoder, ());

/// One frame through the pipeline: signals → braking events → observer → journal/alerts.
fn process_frame(d: &mut Daemon, f: &Frame) -> anyhow::Result<()> {
    if let Some(s) = d.sample(f) {
        d.stage.odometer_km(d.state.odometer_km);
        if let Some(e) = d.stage.push(&s) {
            d.on_event(e)?;
        }
    }
    Ok(())
}

fn open_sink(cfg: &Config, db: &Database, live: bool) -> anyhow::Result<Option<Sink>> {
    if !cfg.outputs.transmit {
        return Ok(None);
    }
    if !live {
        log("outputs.transmit is set but this is a replay: nothing is sent");
        return Ok(None);
    }
    let enc = super::transmit::Encoder::new(db)?;
    let iface = cfg
        .outputs
        .transmit_interface
        .as_deref()
        .unwrap_or_default();
    #[cfg(target_os = "linux")]
    {
        let sink = crate::source::socketcan::LiveSink::open(iface)
            .with_context(|| format!("outputs.transmit_interface: cannot open {iface}"))?;
        log(format_args!(
            "transmitting SHIMMY_01 on {iface} (outputs.transmit = true)"
        ));
        Ok(Some((enc, sink)))
    }
    #[cfg(not(target_os = "linux"))]
    {
        let _ = (enc, iface);
        bail!("outputs.transmit needs Linux SocketCAN")
    }
}

#[cfg(target_os = "linux")]
fn transmit(
    d: &Daemon,
    enc: &mut super::transmit::Encoder,
    sink: &mut crate::source::socketcan::LiveSink,
) -> anyhow::Result<()> {
    use super::transmit::AlertState;
    use crate::alerts::Kind;
    let a = &d.state.alerts;
    let st = if a.is_open(Kind::Clearance) {
        AlertState::Warning
    } else if a.is_open(Kind::Shimmy55) {
        AlertState::Advisory
    } else if d.state.events_total == 0 {
        AlertState::Init
    } else {
        AlertState::Ok
    };
    let est = d.state.estimate.as_ref();
    let f = enc.frame(
        d.mapper.now_ns().unwrap_or(0),
        st,
        d.state.events_total,
        est.and_then(|e| e.clearance_mm),
        d.state.events.last().and_then(|e| e.sw_amplitude_deg),
        est.and_then(|e| e.p_above).map_or(0.0, |p| p * 100.0),
    )?;
    sink.send(&f).context("sending SHIMMY_01")?;
    Ok(())
}

#[cfg(not(target_os = "linux"))]
fn transmit(_: &Daemon, _: &mut super::transmit::Encoder, _: &mut ()) -> anyhow::Result<()> {
    Ok(())
}
