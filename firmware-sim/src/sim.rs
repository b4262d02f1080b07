//! One firmware-sim run: the drive cycle drives the plant step by step, the driver's lane keeping
//! is added at the steering wheel, the ECUs of the emulated bus (the reference bus, or a vehicle
//! profile's, [`crate::bus`]) sample the result, and frames come out in time order, as an
//! [`Iterator`] and as a [`CanSource`]. When the run ends, [`FirmwareSim::ground_truth`]
//! describes what was really simulated.
//!
//! The yaw rate and lateral acceleration some buses carry are kinematic (single track, no
//! slip): r = v·δ_sw/(i_s·L), a_y = v·r, from the total steering-wheel angle (model plus lane
//! keeping). MODEL.md has no lateral vehicle dynamics (§14); these signals only make the bus
//! look like the car's, the monitor does not use them.
//!
//! Deterministic given the scenario seed: every random choice draws from a ChaCha8 stream
//! seeded with it (one stream per purpose, so enabling a fault leaves the sensor noise alone).
//!
//! Not here: writing the frames anywhere (see the binary) or the sensor details
//! ([`crate::bus`]). A step allocates nothing, except that the 1 kHz δ_sw trace kept for the
//! ground truth grows (amortised; reserved up front from the scenario's length).

use rand::SeedableRng;
use rand_chacha::ChaCha8Rng;
use shimmy::source::{CanSource, SourceStats};
use shimmy::wire::Frame;

use crate::bus::{Bus, Sample, MAX_BATCH};
use crate::drive::{DriveCmd, Driver};
use crate::plant::{LaneKeeping, Plant};
use crate::scenario::{ClearanceMode, PhaseChange, Scenario, Segment};
use crate::truth::{self, GroundTruth};
use shimmy::dbc::Database;
use shimmy::observer::simulate::HandsDraw;
use shimmy::profile::bus::BusSpec;

/// Rate of the δ_sw trace kept for the ground truth (Hz), MODEL.md §10's output rate.
pub const TRACE_HZ: f64 = 1000.0;
/// Interval at which the wear law updates the plant's clearances (s of simulated time). At
/// 130 km/h and the largest accepted rate this is a step of 0.36 µm, far below what the model
/// resolves.
pub const WEAR_UPDATE_S: f64 = 0.1;
/// Safety limit on simulated time beyond the scenario's own estimate (s).
const EXTRA_TIME_S: f64 = 600.0;
/// Driving on (pedal released, demand zero) after the last segment so the MODEL.md §11 window
/// of a final braking event (its end + 0.3 s) and the band-pass around it are complete (s).
pub const TAIL_S: f64 = 0.5;

/// Scenario identity for the sidecar.
#[derive(Clone, Debug, Default)]
pub struct RunInfo {
    pub scenario_file: Option<String>,
    pub vehicle_file: Option<String>,
    /// The vehicle profile whose bus is emulated (`None`: the reference bus or a custom one).
    pub profile: Option<String>,
}

/// Clearances and contact of one braking event, accumulated while it decelerates.
#[derive(Clone, Copy, Debug)]
struct EventJoints {
    clearance_start_mm: (f64, f64),
    clearance_end_mm: (f64, f64),
    odometer_km: f64,
    steps: u64,
    contact_steps: [u64; 2],
    impacts: [u64; 2],
    /// cos(φ_R − φ_L) at brake onset (NaN for a plant without unbalance phases).
    phase_cos: f64,
    /// The driver's hands on the rim during the event (scenario `[hands]` on a plant with the
    /// §15 column).
    hands: Option<HandsDraw>,
}

/// A running simulation.
pub struct FirmwareSim<P: Plant> {
    scenario: Scenario,
    info: RunInfo,
    plant: P,
    driver: Driver,
    lane: LaneKeeping,
    lane_rng: ChaCha8Rng,
    lane_rad: f64,
    bus: Bus,
    /// Kinematic yaw gain 1/(i_s·L) (1/m), see the module docs.
    yaw_gain_per_m: f64,
    batch: heapless::Vec<Frame, MAX_BATCH>,
    batch_pos: usize,
    h_s: f64,
    steps: u64,
    /// Model steps per control update (`Scenario::control_steps`).
    chunk: u64,
    trace_every: u64,
    trace: Vec<f64>,
    distance_m: f64,
    clearance_mm: (f64, f64),
    /// Steps between wear updates (0: no wear).
    wear_every: u64,
    /// What happened to the joints during each braking event.
    event_joints: Vec<EventJoints>,
    /// Contact flags after the previous step (for counting impacts).
    contact_prev: [bool; 2],
    /// The plant refused a clearance (ends the run; see [`FirmwareSim::error`]).
    error: Option<String>,
    last_cmd: DriveCmd,
    /// When the drive cycle ended (the tail runs from there).
    t_cycle_end: Option<f64>,
    t_limit_s: f64,
    started: bool,
    done: bool,
    truncated: bool,
    frames_out: u64,
    /// Draws the right wheel's new unbalance phase at each stop (`phase_change = "per_stop"`).
    phase_rng: Option<ChaCha8Rng>,
    /// The car was moving at the previous control step (for `phase_rng`).
    moving: bool,
    /// Draws the driver's hands for each leg of the drive (scenario `[hands]`, plant with a
    /// rim): at the start and at every pull-away from a stop.
    hands_rng: Option<ChaCha8Rng>,
    /// The hands on the rim now (drawn from `hands_rng`).
    hands_now: Option<HandsDraw>,
    /// The road-noise scale the plant runs with now (a braking event's `road_noise_scale`).
    road_scale: f64,
    /// A braking event's curve (`turn_deg`) at the sensors now (deg).
    turn_deg: f64,
}

impl<P: Plant> FirmwareSim<P> {
    /// Start a run of `scenario` on `plant`, with the reference bus packed with the DBC in
    /// `dbc_text` (normally [`crate::bus::REFERENCE_DBC`]).
    pub fn new(
        scenario: &Scenario,
        plant: P,
        dbc_text: &str,
        info: RunInfo,
    ) -> anyhow::Result<FirmwareSim<P>> {
        let (db, _report) = Database::parse(dbc_text);
        FirmwareSim::with_bus(scenario, plant, db, &crate::bus::reference_bus()?, info)
    }

    /// Start a run of `scenario` on `plant`, emulating the bus `bus` (a vehicle profile's
    /// `bus.toml`) packed with `db`.
    pub fn with_bus(
        scenario: &Scenario,
        plant: P,
        db: Database,
        bus: &BusSpec,
        info: RunInfo,
    ) -> anyhow::Result<FirmwareSim<P>> {
        scenario.validate()?;
        let h = scenario.step_s;
        let t0_ns = (scenario.start_unix_s * 1e9).round() as i64;
        let bus = Bus::new(
            db,
            bus,
            &scenario.sensors,
            &scenario.faults,
            scenario.seed,
            t0_ns,
        )?;
        let plant_has_rim = plant.has_rim();
        let ratio_l = plant.steering_ratio() * plant.wheelbase_m();
        let yaw_gain_per_m = if ratio_l.is_finite() && ratio_l > 0.0 {
            1.0 / ratio_l
        } else {
            0.0
        };
        let trace_every = scenario.trace_steps();
        let chunk = scenario.control_steps();
        let mut lane_rng = ChaCha8Rng::seed_from_u64(scenario.seed);
        lane_rng.set_stream(1);
        let d = &scenario.driver;
        let mut lane = LaneKeeping::new(
            d.steer_rms_deg,
            d.steer_tau_s,
            d.steer_offset_deg,
            trace_every as f64 * h,
        );
        lane.warm_up(&mut lane_rng);
        let est = estimate_duration_s(scenario);
        let clearance_mm = scenario.clearance.at_distance_mm(0.0);
        let wear_every = if scenario.clearance.wear_mm_per_1000km > 0.0 {
            // On the trace grid, so every control period divides it.
            (WEAR_UPDATE_S * TRACE_HZ).round() as u64 * trace_every
        } else {
            0
        };
        let n_brakes = scenario
            .drive
            .segments
            .iter()
            .filter(|s| matches!(s, Segment::Brake(_)))
            .count();
        let mut sim = FirmwareSim {
            scenario: scenario.clone(),
            info,
            plant,
            driver: Driver::new(&scenario.drive, chunk as f64 * h),
            lane,
            lane_rng,
            lane_rad: 0.0,
            bus,
            yaw_gain_per_m,
            batch: heapless::Vec::new(),
            batch_pos: 0,
            h_s: h,
            steps: 0,
            chunk,
            trace_every,
            trace: Vec::with_capacity((est * TRACE_HZ * 1.2) as usize + 16),
            distance_m: 0.0,
            clearance_mm,
            wear_every,
            event_joints: Vec::with_capacity(n_brakes),
            contact_prev: [false; 2],
            error: None,
            last_cmd: DriveCmd::default(),
            t_cycle_end: None,
            t_limit_s: est * 2.0 + EXTRA_TIME_S,
            started: false,
            done: false,
            truncated: false,
            frames_out: 0,
            phase_rng: (scenario.excitation.phase_change == PhaseChange::PerStop).then(|| {
                let mut r = ChaCha8Rng::seed_from_u64(scenario.seed);
                r.set_stream(7);
                r
            }),
            moving: false,
            hands_rng: match &scenario.hands {
                Some(_) if plant_has_rim => {
                    let mut r = ChaCha8Rng::seed_from_u64(scenario.seed);
                    r.set_stream(9);
                    Some(r)
                }
                _ => None,
            },
            hands_now: None,
            road_scale: 1.0,
            turn_deg: 0.0,
        };
        sim.new_hands()?;
        sim.lane_rad = sim.lane.step(&mut sim.lane_rng);
        sim.trace.push(sim.plant.steering_wheel_rad());
        sim.contact_prev = sim.contact();
        Ok(sim)
    }

    /// The plant being driven.
    pub fn plant(&self) -> &P {
        &self.plant
    }

    /// The emulated bus (DBC, per-message counters, recorded values).
    pub fn bus(&self) -> &Bus {
        &self.bus
    }

    pub fn bus_mut(&mut self) -> &mut Bus {
        &mut self.bus
    }

    /// Set the interface name written into frames.
    pub fn set_iface(&mut self, name: &str) {
        self.bus.set_iface(name);
        for f in self.batch.iter_mut() {
            f.set_iface(name);
        }
    }

    /// Simulated time (s).
    pub fn t_s(&self) -> f64 {
        self.plant.t_s()
    }

    pub fn is_done(&self) -> bool {
        self.done && self.batch_pos >= self.batch.len()
    }

    fn sample(&self) -> Sample {
        let steer_rad =
            self.plant.steering_wheel_rad() + self.lane_rad + self.turn_deg.to_radians();
        let speed_mps = self.plant.speed_mps();
        let yaw_rate_rps = speed_mps * steer_rad * self.yaw_gain_per_m;
        Sample {
            t_s: self.plant.t_s(),
            steer_rad,
            speed_mps,
            accel_mps2: self.plant.accel_mps2(),
            pedal_decel_mps2: self.last_cmd.pedal_decel_mps2,
            brake_pressed: self.last_cmd.brake_pressed,
            yaw_rate_rps,
            lat_accel_mps2: speed_mps * yaw_rate_rps,
            steer_torque_nm: -self.plant.column_torque_nm()
                + if self.plant.has_torsion_bar() {
                    self.scenario.driver.turn_torque_nm_per_deg * self.turn_deg
                } else {
                    0.0
                },
            torsion_bar: self.plant.has_torsion_bar(),
        }
    }

    /// One control update: the driver's demand, `chunk` model steps with it held (one, unless
    /// the scenario sets `control_period_s`), the bookkeeping, and the frames that became due.
    fn step(&mut self) {
        if !self.started {
            // Frames due at t = 0, before the first step.
            self.started = true;
            let s = self.sample();
            self.bus.poll(&s, &mut self.batch);
            return;
        }
        let t = self.plant.t_s();
        let v = self.plant.speed_mps();
        if t >= self.t_limit_s {
            self.done = true;
            self.truncated = true;
            return;
        }
        let n_events = self.driver.events().len();
        let cmd = self.driver.update(t, v);
        if self.driver.events().len() > n_events {
            self.event_joints.push(EventJoints {
                clearance_start_mm: self.clearance_mm,
                clearance_end_mm: self.clearance_mm,
                odometer_km: self.odometer_km(),
                steps: 0,
                contact_steps: [0; 2],
                impacts: [0; 2],
                phase_cos: self
                    .plant
                    .unbalance_phases()
                    .map_or(f64::NAN, |[l, r]| (r - l).cos()),
                hands: self.hands_now,
            });
        }
        let braking = self.driver.braking_event();
        let cmd = if cmd.done {
            let t_end = *self.t_cycle_end.get_or_insert(t);
            if t - t_end >= TAIL_S - 0.5 * self.h_s {
                self.done = true;
                return;
            }
            DriveCmd::default()
        } else {
            cmd
        };
        self.last_cmd = cmd;
        let road = self.driver.road_noise_scale();
        if road != self.road_scale {
            self.plant.set_road_noise_scale(road);
            self.road_scale = road;
        }
        self.turn_deg = self.driver.turn_deg(t);
        self.plant.set_decel_demand(cmd.decel_demand_mps2);
        if self.chunk == 1 {
            self.plant.step();
        } else {
            self.plant.advance(self.chunk);
        }
        self.steps += self.chunk;
        let v1 = self.plant.speed_mps();
        self.distance_m += 0.5 * (v + v1) * self.chunk as f64 * self.h_s;
        let moving = v1 > shimmy::model::braking::driver::V_STANDSTILL_MPS;
        if self.moving && !moving {
            self.new_phase_at_stop();
        }
        if !self.moving && moving && self.steps > self.chunk {
            // Pulling away from a stop: the next leg's hands.
            if let Err(e) = self.new_hands() {
                self.error = Some(format!("{e:#}"));
                self.done = true;
                return;
            }
        }
        self.moving = moving;
        if self.wear_every > 0 && self.steps.is_multiple_of(self.wear_every) {
            self.apply_wear();
        }
        let contact = self.contact();
        if let Some(ev) = braking.and_then(|i| self.event_joints.get_mut(i)) {
            ev.clearance_end_mm = self.clearance_mm;
            ev.steps += 1;
            for (j, (&now, &before)) in contact.iter().zip(&self.contact_prev).enumerate() {
                ev.contact_steps[j] += u64::from(now);
                ev.impacts[j] += u64::from(now && !before);
            }
        }
        self.contact_prev = contact;
        if self.steps.is_multiple_of(self.trace_every) {
            self.lane_rad = self.lane.step(&mut self.lane_rng);
            self.trace.push(self.plant.steering_wheel_rad());
        }
        let s = self.sample();
        self.bus.poll(&s, &mut self.batch);
    }

    /// `phase_change = "per_stop"`: the car stopped (at a junction, say) and will turn before
    /// its next event, so the right wheel's unbalance phase is drawn anew against the left's.
    fn new_phase_at_stop(&mut self) {
        use rand::Rng;
        let (Some(rng), Some([left, _])) = (self.phase_rng.as_mut(), self.plant.unbalance_phases())
        else {
            return;
        };
        let right = rng.random::<f64>() * std::f64::consts::TAU;
        self.plant.set_unbalance_phases([left, right]);
    }

    /// Draws the hands of the next leg of the drive and puts them on the rim (scenario
    /// `[hands]` on a plant with a rim; nothing otherwise).
    fn new_hands(&mut self) -> anyhow::Result<()> {
        let (Some(rng), Some(prior)) = (self.hands_rng.as_mut(), self.scenario.hands.as_ref())
        else {
            return Ok(());
        };
        let d = prior.draw(rng);
        self.plant.set_hands(&d.hands)?;
        self.hands_now = Some(d);
        Ok(())
    }

    /// Contact flags of the joints that have clearance (an ideal joint never reports contact).
    fn contact(&self) -> [bool; 2] {
        let c = self.plant.in_contact();
        match self.scenario.clearance.mode {
            ClearanceMode::Dual => c,
            ClearanceMode::Single => [c[0], false],
        }
    }

    fn odometer_km(&self) -> f64 {
        self.scenario.clearance.odometer_km + self.distance_m * 1e-3
    }

    /// The wear law (`Clearance::at_distance_mm`) at the distance driven so far, into the
    /// plant. Allocation-free unless the plant refuses the value, which the scenario's
    /// validation rules out (every value stays within the scenario's accepted range).
    fn apply_wear(&mut self) {
        let (left, right) = self.scenario.clearance.at_distance_mm(self.distance_m);
        if (left, right) == self.clearance_mm {
            return; // at the cap, or standing still
        }
        match self.plant.set_clearance_m(left * 1e-3, right * 1e-3) {
            Ok(()) => self.clearance_mm = (left, right),
            Err(e) => {
                self.error = Some(format!(
                    "the plant refused the worn clearance {left}/{right} mm at t = {:.3} s: {e:#}",
                    self.plant.t_s()
                ));
                self.done = true;
            }
        }
    }

    /// Why the run stopped early, if the plant refused a clearance set by the wear law or the
    /// hands drawn for a leg. The binary reports it as an error.
    pub fn error(&self) -> Option<&str> {
        self.error.as_deref()
    }

    /// Run to the end, discarding frames (the ground truth still fills).
    pub fn run_to_end(&mut self) {
        while self.next().is_some() {}
    }

    /// What was simulated. Meaningful once the run is done (before that it covers the run so
    /// far).
    pub fn ground_truth(&self) -> GroundTruth {
        let c = &self.scenario.clearance;
        let start = c.at_distance_mm(0.0);
        let mut events = Vec::with_capacity(self.driver.events().len());
        for (i, ev) in self.driver.events().iter().enumerate() {
            if !ev.t_end_s.is_finite() {
                continue; // unfinished (run truncated)
            }
            let window = [ev.t_start_s, ev.t_end_s + truth::WINDOW_TAIL_S];
            let j = self.event_joints.get(i).copied().unwrap_or(EventJoints {
                clearance_start_mm: self.clearance_mm,
                clearance_end_mm: self.clearance_mm,
                odometer_km: self.odometer_km(),
                steps: 0,
                contact_steps: [0; 2],
                impacts: [0; 2],
                phase_cos: f64::NAN,
                hands: None,
            });
            let frac = |n: u64| n as f64 / j.steps.max(1) as f64;
            events.push(truth::EventTruth {
                index: i,
                event: ev.clone(),
                clearance_left_mm: j.clearance_start_mm.0,
                clearance_right_mm: j.clearance_start_mm.1,
                clearance_left_mm_end: j.clearance_end_mm.0,
                clearance_right_mm_end: j.clearance_end_mm.1,
                odometer_km: j.odometer_km,
                contact_fraction: [frac(j.contact_steps[0]), frac(j.contact_steps[1])],
                impacts: j.impacts,
                window_s: window,
                sw_amplitude_deg: truth::sw_amplitude_deg(&self.trace, TRACE_HZ, window),
                unbalance_phase_cos: j.phase_cos.is_finite().then_some(j.phase_cos),
                hands: j.hands,
            });
        }
        let stats = self.bus.stats();
        GroundTruth {
            format: truth::FORMAT,
            scenario: truth::ScenarioId {
                name: self.scenario.name.clone(),
                file: self.info.scenario_file.clone(),
                seed: self.scenario.seed,
                vehicle_file: self.info.vehicle_file.clone(),
                profile: self.info.profile.clone(),
                integrator: self.scenario.integrator,
                control_period_s: self.scenario.control_steps() as f64 * self.scenario.step_s,
                step_s: self.scenario.step_s,
            },
            start_unix_s: self.scenario.start_unix_s,
            duration_s: self.plant.t_s(),
            distance_km: self.distance_m * 1e-3,
            clearance: truth::ClearanceTruth {
                mode: match c.mode {
                    ClearanceMode::Dual => "dual".into(),
                    ClearanceMode::Single => "single".into(),
                },
                left_mm_start: start.0,
                right_mm_start: start.1,
                wear_mm_per_1000km: c.wear_mm_per_1000km,
                max_mm: c.max_mm.unwrap_or(crate::scenario::MAX_CLEARANCE_MM),
                left_mm_end: self.clearance_mm.0,
                right_mm_end: self.clearance_mm.1,
                odometer_km_start: c.odometer_km,
                odometer_km_end: self.odometer_km(),
            },
            events,
            sensors: truth::SensorTruth {
                sas_offset_deg: self.bus.sas_offset_deg(),
                steer_sensor: self.bus.steer_sensor().map(|s| truth::SteerSensorTruth {
                    message: s.message.clone(),
                    rate_hz: s.rate_hz,
                    step_deg: s.step_deg,
                }),
            },
            frames_sent: stats.iter().map(|s| s.sent).sum(),
            messages: stats,
            truncated: self.truncated,
        }
    }

    /// The 1 kHz model δ_sw trace (rad) kept for the ground truth.
    pub fn sw_trace(&self) -> &[f64] {
        &self.trace
    }
}

impl<P: Plant> Iterator for FirmwareSim<P> {
    type Item = Frame;

    fn next(&mut self) -> Option<Frame> {
        loop {
            if self.batch_pos < self.batch.len() {
                let f = self.batch[self.batch_pos];
                self.batch_pos += 1;
                self.frames_out += 1;
                return Some(f);
            }
            if self.done {
                return None;
            }
            self.batch.clear();
            self.batch_pos = 0;
            self.step();
        }
    }
}

impl<P: Plant> CanSource for FirmwareSim<P> {
    fn next_frame(&mut self) -> std::io::Result<Option<Frame>> {
        Ok(self.next())
    }

    fn stats(&self) -> SourceStats {
        SourceStats {
            frames: self.frames_out,
            ..SourceStats::default()
        }
    }
}

/// A generous estimate of the simulated length of a scenario (s), for reserving the trace and
/// bounding the run.
pub fn estimate_duration_s(sc: &Scenario) -> f64 {
    let g = crate::drive::G;
    let mut v = sc.drive.start_speed_kmh / 3.6;
    let mut t = 0.0;
    for s in &sc.drive.segments {
        match s {
            Segment::Cruise {
                speed_kmh,
                duration_s,
            } => {
                let target = speed_kmh / 3.6;
                let a = if target > v {
                    sc.drive.accel_g
                } else {
                    sc.drive.coast_g
                } * g;
                t += (target - v).abs() / a + 5.0 + duration_s;
                v = target;
            }
            Segment::Brake(b) => match b.duration_s {
                Some(d) => {
                    t += d;
                    v = (v - b.decel_g * g * d).max(0.0);
                }
                None => {
                    t += b.ramp_in_s + v / (b.decel_g * g) + 2.0 + b.hold_s + b.ramp_out_s;
                    v = 0.0;
                }
            },
            Segment::Coast {
                duration_s,
                decel_g,
            } => {
                t += duration_s;
                v = (v - decel_g * g * duration_s).max(0.0);
            }
            Segment::Stand { duration_s } => t += duration_s,
        }
    }
    t + TAIL_S
}
