//! One simulated braking event seen through the observer (the source of the response table's
//! feature distributions): the shimmy model is run through one braking event ([`EventShape`]:
//! MODEL.md §6's event from a kick, or the event as a vehicle on the road sees it — seconds of
//! cruising first, then firmware-sim's pedal law), its steering-wheel angle δ_sw (§8) goes
//! through the observer's sensor model ([`super::sensor`]) and its speed through a 50 Hz speed
//! signal, and the result
//! is fed to the same [`Detector`] and [`Extractor`] that process a real log. So the features
//! of a simulated event and of a measured one are computed by the same code.
//!
//! Also here: the nuisance draw of one vehicle ([`perturb`]: unbalance magnitude, ±10 % on the
//! steering stiffnesses and dampings, with the MODEL.md §15 column its rim inertia, torsion
//! bar stiffness and damping, and where the prior asks for them the brake discs' variation
//! (§14); [`perturb_vehicle`] adds the road-noise level; unbalance phase
//! and road-noise realisation come from each event's seed, MODEL.md §7), and the driver's
//! hands on the rim drawn per braking event ([`HandsPrior`], [`event_hands`]; docs/COLUMN.md).
//!
//! What it is not: the table builder (that is `shimmy calibrate`) or firmware-sim's drive cycle.

use anyhow::{bail, Context};
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;

use super::features::{Extractor, Features};
use super::sensor::SensorModel;
use super::ObserverConfig;
use crate::analysis::filter::Bandpass;
use crate::events::{Detector, Sample};
use crate::model::braking::driver::{CRUISE_TAU_S, CRUISE_TOL_MPS, JERK_MPS3, V_STANDSTILL_MPS};
use crate::model::excitation::Excitation;
use crate::model::rhs::ix;
use crate::model::{Hands, Integrator, Scenario, Simulator, VehicleParams};

/// Ranges of the nuisances drawn per simulated vehicle (the table's nuisance prior; recorded in
/// the table as `prior`).
#[derive(Clone, Copy, Debug, PartialEq, serde::Serialize, serde::Deserialize)]
#[serde(deny_unknown_fields)]
pub struct NuisanceRanges {
    /// Relative ± spread on stiffnesses and dampings (0.1 = ±10 %).
    pub stiffness_damping_rel: f64,
    /// Unbalance magnitude factor range (log-uniform).
    pub unbalance_factor: (f64, f64),
    /// Road-noise σ factor range (uniform), drawn by [`perturb_vehicle`] only.
    pub road_noise_factor: (f64, f64),
    /// Steering wheel and column of a vehicle with the MODEL.md §15 column (J_sw, k_tb, c_tb,
    /// uniform within these ranges; docs/COLUMN.md); `None`: the nominal column. Not drawn
    /// for a 5-DOF vehicle. Absent in tables written before it existed: the published ranges;
    /// not written when it is them (so a default-prior table is byte for byte as before).
    #[serde(
        default = "published_column",
        skip_serializing_if = "is_published_column"
    )]
    pub column: Option<ColumnRanges>,
    /// The driver's hands on the rim, drawn per braking event for a vehicle with the §15
    /// column ([`HandsPrior`]); `None`: the vehicle's own hands for every event. Absent in
    /// tables written before it existed: [`HandsPrior::default`]; not written when it is that.
    #[serde(default = "default_hands", skip_serializing_if = "is_default_hands")]
    pub hands: Option<HandsPrior>,
    /// A brake-torque variation (disc thickness variation, MODEL.md §14) drawn per vehicle:
    /// each front disc's ε uniform in `(low, high)` (relative to the brake force) and its
    /// thickest point uniform on the wheel, independently for the two discs. `None` (the
    /// default, and absent in every table written before it existed): the vehicle's own discs,
    /// even unless its file says otherwise. A chassis variant's table for cars with uneven
    /// discs is built with it (`shimmy calibrate --brake-torque-variation-rel`).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub brake_torque_variation_rel: Option<(f64, f64)>,
}

fn is_published_column(c: &Option<ColumnRanges>) -> bool {
    *c == published_column()
}

fn is_default_hands(h: &Option<HandsPrior>) -> bool {
    *h == default_hands()
}

fn published_column() -> Option<ColumnRanges> {
    Some(ColumnRanges::PUBLISHED)
}

fn default_hands() -> Option<HandsPrior> {
    Some(HandsPrior::default())
}

impl NuisanceRanges {
    /// No nuisance: every drawn vehicle is the nominal one (`shimmy calibrate --exact-vehicle`),
    /// its hands those of its vehicle file at every event.
    pub const NONE: NuisanceRanges = NuisanceRanges {
        stiffness_damping_rel: 0.0,
        unbalance_factor: (1.0, 1.0),
        road_noise_factor: (1.0, 1.0),
        column: None,
        hands: None,
        brake_torque_variation_rel: None,
    };
}

impl Default for NuisanceRanges {
    fn default() -> Self {
        NuisanceRanges {
            stiffness_damping_rel: 0.10,
            unbalance_factor: (0.5, 2.0),
            road_noise_factor: (0.7, 1.4),
            column: published_column(),
            hands: default_hands(),
            brake_torque_variation_rel: None,
        }
    }
}

/// Ranges of the steering wheel and column drawn per vehicle (MODEL.md §15; the sources are in
/// docs/COLUMN.md). Each value is drawn uniformly in `(low, high)`.
#[derive(Clone, Copy, Debug, PartialEq, serde::Serialize, serde::Deserialize)]
#[serde(deny_unknown_fields)]
pub struct ColumnRanges {
    /// J_sw: rim + column inertia (kg·m²).
    pub inertia_kgm2: (f64, f64),
    /// k_tb: EPS torsion bar stiffness (N·m/rad).
    pub torsion_bar_nm_per_rad: (f64, f64),
    /// c_tb: torsion bar damping (N·m·s/rad).
    pub torsion_bar_damping_nms_per_rad: (f64, f64),
}

impl ColumnRanges {
    /// docs/COLUMN.md: J_sw 0.03–0.05 kg·m², k_tb 1–3 N·m/° (57.3–171.9 N·m/rad), c_tb
    /// 0.01–0.05 N·m·s/rad.
    pub const PUBLISHED: ColumnRanges = ColumnRanges {
        inertia_kgm2: (0.03, 0.05),
        torsion_bar_nm_per_rad: (57.3, 171.9),
        torsion_bar_damping_nms_per_rad: (0.01, 0.05),
    };

    /// Rejects ranges that cannot be drawn from; the message names the field.
    pub fn validate(&self) -> anyhow::Result<()> {
        for (key, (lo, hi), min) in [
            ("column.inertia_kgm2", self.inertia_kgm2, f64::MIN_POSITIVE),
            (
                "column.torsion_bar_nm_per_rad",
                self.torsion_bar_nm_per_rad,
                f64::MIN_POSITIVE,
            ),
            (
                "column.torsion_bar_damping_nms_per_rad",
                self.torsion_bar_damping_nms_per_rad,
                0.0,
            ),
        ] {
            check_range(key, lo, hi, min)?;
        }
        Ok(())
    }
}

fn check_range(key: &str, lo: f64, hi: f64, min: f64) -> anyhow::Result<()> {
    if !(lo.is_finite() && hi.is_finite() && lo >= min && hi >= lo) {
        bail!(
            "{key}: must be [low, high] with {} low <= high (got [{lo}, {hi}])",
            if min > 0.0 { "0 <" } else { "0 <=" }
        );
    }
    Ok(())
}

/// Checks a range of the brake discs' variation ([`NuisanceRanges::brake_torque_variation_rel`]):
/// 0 <= low <= high <= 0.3 (30 % of the brake force is far beyond a judder a driver tolerates).
pub fn check_brake_torque_variation(key: &str, (lo, hi): (f64, f64)) -> anyhow::Result<()> {
    check_range(key, lo, hi, 0.0)?;
    if hi > 0.3 {
        bail!("{key}: at most 0.3 of the brake force (got [{lo}, {hi}])");
    }
    Ok(())
}

/// How the driver holds the steering wheel during one braking event.
#[derive(Clone, Copy, Debug, PartialEq, Eq, serde::Serialize, serde::Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum HandsState {
    /// No hand on the rim: only the column's own damping.
    Off,
    /// A relaxed grip.
    Light,
    /// A firm, co-contracted grip (arms stiffened).
    Firm,
}

/// One hands state's probability and the ranges its values are drawn from (uniform).
#[derive(Clone, Copy, Debug, PartialEq, serde::Serialize, serde::Deserialize)]
#[serde(deny_unknown_fields)]
pub struct HandsRange {
    pub probability: f64,
    pub inertia_kgm2: (f64, f64),
    pub stiffness_nm_per_rad: (f64, f64),
    pub damping_nms_per_rad: (f64, f64),
}

/// The prior of the driver's hands per braking event: which state (off, light, firm grip)
/// with which probability, and the ranges of its inertia, stiffness and damping at the rim
/// (MODEL.md §15 eq. 6). Defaults and their reasons: docs/COLUMN.md.
#[derive(Clone, Copy, Debug, PartialEq, serde::Serialize, serde::Deserialize)]
#[serde(deny_unknown_fields)]
pub struct HandsPrior {
    pub off: HandsRange,
    pub light: HandsRange,
    pub firm: HandsRange,
}

impl Default for HandsPrior {
    fn default() -> Self {
        HandsPrior {
            off: HandsRange {
                probability: 0.15,
                inertia_kgm2: (0.0, 0.0),
                stiffness_nm_per_rad: (0.0, 0.0),
                damping_nms_per_rad: (0.03, 0.1),
            },
            light: HandsRange {
                probability: 0.60,
                inertia_kgm2: (0.01, 0.05),
                stiffness_nm_per_rad: (0.0, 5.0),
                damping_nms_per_rad: (0.2, 0.6),
            },
            firm: HandsRange {
                probability: 0.25,
                inertia_kgm2: (0.05, 0.12),
                stiffness_nm_per_rad: (10.0, 40.0),
                damping_nms_per_rad: (0.8, 2.0),
            },
        }
    }
}

impl HandsRange {
    /// The hands at the middle of each of the ranges (a typical driver in this state).
    pub fn midpoint(&self) -> Hands {
        let m = |(lo, hi): (f64, f64)| 0.5 * (lo + hi);
        Hands {
            inertia_kgm2: m(self.inertia_kgm2),
            stiffness_nm_per_rad: m(self.stiffness_nm_per_rad),
            damping_nms_per_rad: m(self.damping_nms_per_rad),
        }
    }
}

/// The hands of one braking event: the state drawn and its values.
#[derive(Clone, Copy, Debug, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct HandsDraw {
    pub state: HandsState,
    #[serde(flatten)]
    pub hands: Hands,
}

/// ChaCha stream of the per-event hands draw of [`event_hands`].
const HANDS_STREAM: u64 = 13;
/// Added to the vehicle's stream for the column draw of [`perturb`].
const COLUMN_STREAM_OFFSET: u64 = 0xC01;
/// The stream offset of the brake discs' draws (as [`COLUMN_STREAM_OFFSET`]: a vehicle drawn
/// without them is drawn exactly as before they existed).
const DISC_STREAM_OFFSET: u64 = 0xD15C;

impl HandsPrior {
    /// Each state's range.
    pub fn range(&self, s: HandsState) -> &HandsRange {
        match s {
            HandsState::Off => &self.off,
            HandsState::Light => &self.light,
            HandsState::Firm => &self.firm,
        }
    }

    /// Rejects a prior that cannot be drawn from: probabilities finite, >= 0 and summing to 1
    /// (±1e-6), every range [low, high] with 0 <= low <= high. The message names the field.
    pub fn validate(&self) -> anyhow::Result<()> {
        let mut sum = 0.0;
        for (name, r) in [
            ("off", &self.off),
            ("light", &self.light),
            ("firm", &self.firm),
        ] {
            if !(r.probability.is_finite() && r.probability >= 0.0) {
                bail!(
                    "hands.{name}.probability: must be finite and >= 0 (got {})",
                    r.probability
                );
            }
            sum += r.probability;
            check_range(
                &format!("hands.{name}.inertia_kgm2"),
                r.inertia_kgm2.0,
                r.inertia_kgm2.1,
                0.0,
            )?;
            check_range(
                &format!("hands.{name}.stiffness_nm_per_rad"),
                r.stiffness_nm_per_rad.0,
                r.stiffness_nm_per_rad.1,
                0.0,
            )?;
            check_range(
                &format!("hands.{name}.damping_nms_per_rad"),
                r.damping_nms_per_rad.0,
                r.damping_nms_per_rad.1,
                0.0,
            )?;
        }
        if (sum - 1.0).abs() > 1e-6 {
            bail!("hands.*.probability: must sum to 1 (got {sum})");
        }
        Ok(())
    }

    /// Draws one event's hands: the state by its probability, then inertia, stiffness and
    /// damping uniformly within the state's ranges (always four draws from `rng`).
    pub fn draw<R: Rng>(&self, rng: &mut R) -> HandsDraw {
        let u: f64 = rng.random();
        let state = if u < self.off.probability {
            HandsState::Off
        } else if u < self.off.probability + self.light.probability {
            HandsState::Light
        } else {
            HandsState::Firm
        };
        let r = self.range(state);
        let mut pick = |(lo, hi): (f64, f64)| lo + rng.random::<f64>() * (hi - lo);
        HandsDraw {
            state,
            hands: Hands {
                inertia_kgm2: pick(r.inertia_kgm2),
                stiffness_nm_per_rad: pick(r.stiffness_nm_per_rad),
                damping_nms_per_rad: pick(r.damping_nms_per_rad),
            },
        }
    }
}

/// The hands of the braking event with `seed` (its own ChaCha stream of the seed, so the
/// event's other draws are unchanged): what `shimmy calibrate`'s model events use.
pub fn event_hands(prior: &HandsPrior, seed: u64) -> HandsDraw {
    let mut rng = ChaCha8Rng::seed_from_u64(seed);
    rng.set_stream(HANDS_STREAM);
    prior.draw(&mut rng)
}

/// One whole nuisance vehicle (the nuisances are properties of a vehicle, shared by
/// all its braking events): [`perturb`] followed by a uniform road-noise factor, in the order
/// firmware-sim's fleet draws them.
pub fn perturb_vehicle(
    nominal: &VehicleParams,
    r: &NuisanceRanges,
    rng: &mut ChaCha8Rng,
) -> VehicleParams {
    let mut p = perturb(nominal, r, rng);
    let (lo, hi) = r.road_noise_factor;
    if hi > lo {
        p.excitation.noise_std_nm *= rng.random_range(lo..hi);
    } else {
        p.excitation.noise_std_nm *= lo;
    }
    p
}

/// How the simulated braking event starts.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum EventShape {
    /// MODEL.md §6 as written: the steering system released with the initial kick θ1'(0) at
    /// t = 0, the brake ramp at `braking.onset_s`, the pedal held to the end.
    Single,
    /// The event as a vehicle on the road sees it (firmware-sim's drive cycle): no
    /// kick; with `accel_g > 0` the car pulls away from standstill at up to `accel_g` (the
    /// first-order speed approach and jerk limit of firmware-sim's driver, `drive.rs`), else
    /// it starts at the initial speed; then `cruise_s` of constant-speed driving (unbalance and
    /// road noise bring the steering system to its running state), then the pedal ramps in
    /// over `ramp_s` to the plateau, holds `hold_s` at standstill and ramps out over `ramp_s`.
    Drive {
        accel_g: f64,
        cruise_s: f64,
        hold_s: f64,
    },
}

impl EventShape {
    /// The shape the response table uses by default, firmware-sim's fleet drive (and that of
    /// the named scenarios): from a stop, pull away at 0.35 g, hold the speed for 1.5 s, brake
    /// to a stop, hold the pedal 0.5 s. The history matters: at large clearances the rattle
    /// needs seconds to build up after the car pulls away (0.3 mm, 55 km/h, nominal vehicle:
    /// pre-brake band RMS 0.025° after 1.5 s of cruising, 0.050° after 6 s; with 0.05 mm
    /// joints 0.055° either way), so the pre-brake cruise feature and, less, the braking
    /// features depend on it.
    pub const DRIVE: EventShape = EventShape::Drive {
        accel_g: 0.35,
        cruise_s: 1.5,
        hold_s: 0.5,
    };
}

/// A vehicle like `nominal` with nuisances drawn from `rng`: each steering stiffness and
/// damping (k_s, c_s, k_t, k_g, c_g) scaled by an independent uniform factor in ±rel, and the
/// unbalance scaled by a log-uniform factor. With the §15 column enabled, also J_sw, k_tb and
/// c_tb within `r.column` (from a copy of `rng` on another stream, so the draws of a 5-DOF
/// vehicle and whatever `rng` gives afterwards are the same with or without the column); with
/// `r.brake_torque_variation_rel`, the two discs' variation and phase (another stream again).
pub fn perturb(nominal: &VehicleParams, r: &NuisanceRanges, rng: &mut ChaCha8Rng) -> VehicleParams {
    let mut p = nominal.clone();
    let mut f = |x: &mut f64| *x *= 1.0 + rng.random_range(-1.0..=1.0) * r.stiffness_damping_rel;
    let s = &mut p.steering;
    f(&mut s.kingpin_stiffness_nm_per_rad);
    f(&mut s.kingpin_damping_nms_per_rad);
    f(&mut s.tie_rod_stiffness_n_per_m);
    f(&mut s.restraint_stiffness_n_per_m);
    f(&mut s.restraint_damping_ns_per_m);
    let (lo, hi) = r.unbalance_factor;
    let u = (lo.ln() + rng.random::<f64>() * (hi.ln() - lo.ln())).exp();
    p.excitation.unbalance_kgm *= u;
    if let (true, Some(cr)) = (p.column.enabled, &r.column) {
        // From a copy of `rng` on another stream: `rng` itself (and so whatever the caller
        // draws next) is left as for a vehicle without the column.
        let mut crng = rng.clone();
        crng.set_stream(rng.get_stream().wrapping_add(COLUMN_STREAM_OFFSET));
        let mut pick = |(lo, hi): (f64, f64)| lo + crng.random::<f64>() * (hi - lo);
        let c = &mut p.column;
        c.inertia_kgm2 = pick(cr.inertia_kgm2);
        c.torsion_bar_nm_per_rad = pick(cr.torsion_bar_nm_per_rad);
        c.torsion_bar_damping_nms_per_rad = pick(cr.torsion_bar_damping_nms_per_rad);
    }
    if let Some((lo, hi)) = r.brake_torque_variation_rel {
        let mut drng = rng.clone();
        drng.set_stream(rng.get_stream().wrapping_add(DISC_STREAM_OFFSET));
        let b = &mut p.braking;
        for i in 0..2 {
            b.torque_variation_rel[i] = lo + drng.random::<f64>() * (hi - lo);
            b.torque_variation_phase_deg[i] = drng.random::<f64>() * 360.0;
        }
    }
    p
}

/// What one simulated event gives.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct SimulatedEvent {
    /// Features of the sensor-sampled δ_sw, as measured.
    pub features: Features,
    /// MODEL.md §11 steering-wheel amplitude from the continuous 1 kHz δ_sw (deg).
    pub true_peak_deg: f64,
    /// What the detector measured.
    pub v0_kmh: f64,
    pub decel_g: f64,
    pub used: bool,
    /// cos(φ_R − φ_L) of the run's unbalance phases (MODEL.md §7): how the two wheels'
    /// unbalance excitations add in the steering linkage (1: in phase, −1: opposed).
    pub phase_cos: f64,
}

/// The model's output over one braking event, before any sensor: δ_sw (MODEL.md §8, or the
/// rim angle of §15 when the column is on), the speed and the brake pedal, sampled at `fs_hz`
/// from t = 0 (the start of the run) to a little after the detector's window closes.
#[derive(Clone, Debug, PartialEq)]
pub struct ModelRun {
    pub fs_hz: f64,
    pub sw_rad: Vec<f64>,
    /// The driver's torsion-bar torque (N·m, [`crate::model::rhs::Model::driver_torque_nm`]) at the
    /// same instants; empty for a vehicle without the §15 column.
    pub torque_nm: Vec<f64>,
    pub speed_mps: Vec<f64>,
    pub pedal: Vec<bool>,
    /// cos(φ_R − φ_L) of the run's unbalance phases (MODEL.md §7).
    pub phase_cos: f64,
    /// The driver's hands drawn for this run's speed ([`event_hands`] of its seed), when
    /// [`run_model_grid`] was given a hands prior and the vehicle has the §15 column.
    pub hands: Option<HandsDraw>,
}

/// Time the model keeps running after the speed falls below the detector's stop speed, beyond
/// the detector's tail ([`crate::events::EventConfig::tail_s`]): the detector closes the window
/// at the first steering sample after the first speed sample below the stop speed plus the
/// tail, at most 20 ms (one speed-signal period) plus one steering period later; the rest is
/// margin (s).
const RUN_OUT_S: f64 = 0.15;

/// firmware-sim's driver (drive.rs) as a control law over one event: pull away at `accel`
/// (jerk-limited, first-order approach to `v0`), cruise `cruise_s`, then brake at `a_max` with
/// the pedal ramp, hold at standstill, release.
#[derive(Clone, Debug)]
struct DriveLaw {
    v0_mps: f64,
    accel: f64,
    cruise_s: f64,
    hold_s: f64,
    ramp_s: f64,
    a_max: f64,
    onset: f64,
    cruise_from: Option<f64>,
    demand: f64,
    t_stop: Option<f64>,
    released_at: Option<f64>,
}

impl DriveLaw {
    /// The demand at time `t` and speed `v` (m/s², > 0 braking) and whether the pedal is
    /// pressed; `dt` is the control period.
    fn control(&mut self, t: f64, v: f64, dt: f64) -> (f64, bool) {
        if self.cruise_from.is_none() && (v - self.v0_mps).abs() <= CRUISE_TOL_MPS {
            self.cruise_from = Some(t);
        }
        if let Some(t_c) = self.cruise_from {
            if self.onset.is_infinite() && t - t_c >= self.cruise_s {
                self.onset = t;
            }
        }
        if t >= self.onset && self.t_stop.is_none() && v <= V_STANDSTILL_MPS {
            self.t_stop = Some(t);
        }
        let a = match self.t_stop {
            None if t < self.onset => {
                // firmware-sim's driver: first-order speed approach limited to the pull-away
                // acceleration, jerk-limited.
                let want = ((v - self.v0_mps) / CRUISE_TAU_S).clamp(-self.accel, 0.0);
                let step = JERK_MPS3 * dt;
                self.demand += (want - self.demand).clamp(-step, step);
                self.demand
            }
            None => self.a_max * ((t - self.onset) / self.ramp_s).clamp(0.0, 1.0),
            Some(ts) if t < ts + self.hold_s => self.a_max,
            Some(ts) => self.a_max * (1.0 - (t - ts - self.hold_s) / self.ramp_s).max(0.0),
        };
        if self
            .t_stop
            .is_some_and(|ts| t >= ts + self.hold_s + self.ramp_s)
        {
            self.released_at.get_or_insert(t);
        }
        (a, t >= self.onset && self.released_at.is_none())
    }
}

/// One run of the model and its recorded output, advanced in control periods.
#[derive(Clone)]
struct Branch {
    sim: Simulator,
    law: Option<DriveLaw>,
    out: ModelRun,
    /// Control periods recorded so far.
    k: usize,
    /// Time the speed first fell below the detector's stop speed after the onset.
    below_stop: Option<f64>,
}

/// What every branch of one grid run shares.
struct Runner {
    g: f64,
    stride: u64,
    dt_ctl: f64,
    /// Longest run (control periods).
    n_out: usize,
    /// The brake onset of `EventShape::Single` (s).
    onset_single: f64,
    stop_speed: f64,
    run_out: f64,
    /// Control periods simulated so far, over every branch.
    periods: std::cell::Cell<u64>,
}

impl Runner {
    /// One control period of `b`: the driver's demand, the recorded output, the model's
    /// advance. False when the run is complete.
    fn tick(&self, b: &mut Branch) -> bool {
        let t = b.sim.t();
        let v = b.sim.state()[ix::V];
        let pressed = match b.law.as_mut() {
            None => t >= self.onset_single,
            Some(law) => {
                let (a, pressed) = law.control(t, v, self.dt_ctl);
                b.sim.set_decel_demand(a);
                pressed
            }
        };
        let m = b.sim.model();
        b.out.sw_rad.push(m.delta_sw(b.sim.state()));
        if m.column {
            b.out.torque_nm.push(m.driver_torque_nm(b.sim.state()));
        }
        b.out.speed_mps.push(v);
        b.out.pedal.push(pressed);
        let onset = b.law.as_ref().map_or(self.onset_single, |l| l.onset);
        if t > onset && v < self.stop_speed {
            b.below_stop.get_or_insert(t);
        }
        if b.k >= self.n_out || b.below_stop.is_some_and(|ts| t >= ts + self.run_out) {
            return false;
        }
        b.sim.advance(self.stride);
        b.k += 1;
        self.periods.set(self.periods.get() + 1);
        true
    }

    /// Whether the next control period of `b` would set the brake onset (or has): where a run
    /// branches into its decelerations.
    fn at_onset(&self, b: &Branch) -> bool {
        match &b.law {
            None => true,
            Some(law) if law.onset.is_finite() => true,
            Some(law) => {
                let mut probe = law.clone();
                probe.control(b.sim.t(), b.sim.state()[ix::V], self.dt_ctl);
                probe.onset.is_finite()
            }
        }
    }

    /// Runs `b` to the brake onset, then one braking per deceleration (clones of `b`).
    fn brake_branches(
        &self,
        mut b: Branch,
        decels_g: &[f64],
        what: &dyn Fn() -> String,
    ) -> anyhow::Result<Vec<ModelRun>> {
        while !self.at_onset(&b) {
            if !self.tick(&mut b) {
                break;
            }
        }
        let mut branches: Vec<Branch> = (1..decels_g.len()).map(|_| b.clone()).collect();
        branches.push(b);
        let mut runs = Vec::with_capacity(decels_g.len());
        for (mut b, &d) in branches.into_iter().zip(decels_g) {
            if let Some(law) = b.law.as_mut() {
                law.a_max = d * self.g;
            }
            while self.tick(&mut b) {}
            if b.out.sw_rad.iter().any(|x| !x.is_finite()) {
                bail!("model diverged ({}, {d} g)", what());
            }
            runs.push(b.out);
        }
        Ok(runs)
    }
}

/// The runs of [`run_model_grid`] and what they cost.
#[derive(Clone, Debug)]
pub struct GridRuns {
    /// `[speed][decel]`.
    pub runs: Vec<Vec<ModelRun>>,
    /// Control periods the model was advanced, over all branches: the cost. Each run's own
    /// length (`sw_rad.len()`) is what it would have cost alone.
    pub control_periods: u64,
}

/// Runs the model through one braking event per initial speed in `speeds_mps` and
/// deceleration in `decels_g` on vehicle `p` with clearance `clearance_m`, with as little
/// repeated model time as the events allow.
///
/// With `EventShape::Drive` (firmware-sim's driver) every event starts with the car pulling
/// away from a stop at the same acceleration, and the driver's demand does not depend on the
/// target speed until the speed comes within `accel · τ` of it. So one pull-away (the trunk,
/// seeded by `seeds[0]`) serves every speed: each speed's run branches off the trunk at the
/// last control period its driver would have shared, takes its own unbalance phases and road
/// noise from `seeds[i]` there (MODEL.md §7; the several seconds of approach and cruise that
/// follow are far longer than the steering system's memory), and itself branches at the brake
/// onset into one braking per deceleration. The decelerations of one speed therefore share
/// their pre-brake history, as consecutive stops of one car would not; the response table fits
/// each feature per speed and deceleration, so that costs it nothing. Each run stops
/// [`RUN_OUT_S`] after the speed falls below the detector's stop speed, after which nothing can
/// reach the features. `EventShape::Single` (MODEL.md §6's own event, whose deceleration is
/// part of the scenario) runs every event on its own, seeded by `seeds[i]`.
///
/// With a `hands` prior and the §15 column enabled on `p`, each speed's run puts the driver's
/// hands drawn from `seeds[i]` ([`event_hands`]) on the rim where it starts or branches off
/// the trunk, so they hold through its cruise and braking (and its decelerations share them,
/// as they share their pre-brake history). Without: the hands of `p` throughout.
#[allow(clippy::too_many_arguments)]
pub fn run_model_grid(
    p: &VehicleParams,
    clearance_m: f64,
    speeds_mps: &[f64],
    decels_g: &[f64],
    seeds: &[u64],
    shape: EventShape,
    cfg: &ObserverConfig,
    hands: Option<&HandsPrior>,
) -> anyhow::Result<GridRuns> {
    let hands = hands.filter(|_| p.column.enabled);
    if let Some(h) = hands {
        h.validate().context("hands prior")?;
    }
    // Puts the hands of `seed` on `b`'s rim and records them.
    let put_hands = |b: &mut Branch, seed: u64| -> anyhow::Result<()> {
        if let Some(prior) = hands {
            let d = event_hands(prior, seed);
            b.sim.set_hands(&d.hands).context("drawn hands")?;
            b.out.hands = Some(d);
        }
        Ok(())
    };
    if seeds.len() != speeds_mps.len() {
        bail!(
            "{} seeds for {} speeds: one per speed",
            seeds.len(),
            speeds_mps.len()
        );
    }
    if speeds_mps.is_empty() || decels_g.is_empty() {
        return Ok(GridRuns {
            runs: vec![Vec::new(); speeds_mps.len()],
            control_periods: 0,
        });
    }
    if speeds_mps
        .iter()
        .chain(decels_g)
        .any(|x| !(x.is_finite() && *x > 0.0))
    {
        bail!("speeds and decelerations must be positive");
    }
    let g = p.vehicle.gravity_mps2;
    let ramp = p.braking.ramp_s;
    let vmax = speeds_mps.iter().cloned().fold(0.0, f64::max);
    let slowest = decels_g.iter().cloned().fold(f64::INFINITY, f64::min);
    let (onset_est, kick, extra, accel, cruise_s, hold_s) = match shape {
        EventShape::Single => (p.braking.onset_s, None, 0.0, 0.0, 0.0, 0.0),
        EventShape::Drive {
            accel_g,
            cruise_s,
            hold_s,
        } => {
            let a = accel_g.max(0.0) * g;
            // Pull-away (jerk-limited ramp, first-order approach) plus the cruise.
            let pull = if a > 0.0 {
                vmax / a + a / JERK_MPS3 + 6.0 * CRUISE_TAU_S
            } else {
                0.0
            };
            (
                pull + cruise_s,
                Some(0.0),
                hold_s + ramp,
                a,
                cruise_s,
                hold_s,
            )
        }
    };
    let stop_s = onset_est + ramp / 2.0 + vmax / (slowest * g).max(0.1);
    let scenario = |v0_mps: f64, decel_g: f64, seed: u64| Scenario {
        clearance_m,
        seed,
        v0_mps: if accel > 0.0 { 0.0 } else { v0_mps },
        decel_g,
        // The §6 fade below v_stop makes the last 0.5 m/s take up to a second more.
        duration_s: (stop_s
            + extra
            + cfg.events.tail_s
            + 0.5
            + if extra > 0.0 { 1.0 } else { 0.0 })
        .min(3600.0),
        h_s: 1e-4,
        kick_theta1_rad_s: kick,
        integrator: Integrator::Rk4Adaptive,
        ..Scenario::default()
    };
    let sc0 = scenario(vmax, decels_g[0], seeds[0]);
    // 1 kHz output and control: the driver's pedal is updated and the state sampled every
    // `stride` grid steps, and the model advances `stride` steps at a time, merging free-flight
    // steps (`Integrator::Rk4Adaptive`) exactly as firmware-sim's plant does with its default
    // 1 ms control period.
    let stride = 10u64;
    let runner = Runner {
        g,
        stride,
        dt_ctl: sc0.h_s * stride as f64,
        n_out: ((sc0.duration_s / sc0.h_s).round() as u64 / stride) as usize,
        onset_single: onset_est,
        stop_speed: cfg.events.stop_speed_mps,
        run_out: cfg.events.tail_s + RUN_OUT_S,
        periods: std::cell::Cell::new(0),
    };
    let fs_hz = 1.0 / runner.dt_ctl;
    let start = |v0_mps: f64, seed: u64| -> anyhow::Result<Branch> {
        let sc = scenario(v0_mps, decels_g[0], seed);
        let sim = Simulator::new(p, &sc).context("model scenario")?;
        let [phi_l, phi_r] = sim.unbalance_phases();
        let n = runner.n_out + 1;
        Ok(Branch {
            sim,
            law: match shape {
                EventShape::Single => None,
                EventShape::Drive { .. } => Some(DriveLaw {
                    v0_mps,
                    accel,
                    cruise_s,
                    hold_s,
                    ramp_s: ramp,
                    a_max: decels_g[0] * g,
                    onset: if accel > 0.0 {
                        f64::INFINITY
                    } else {
                        onset_est
                    },
                    cruise_from: (accel <= 0.0).then_some(0.0),
                    demand: 0.0,
                    t_stop: None,
                    released_at: None,
                }),
            },
            out: ModelRun {
                fs_hz,
                sw_rad: Vec::with_capacity(n),
                torque_nm: Vec::with_capacity(if p.column.enabled { n } else { 0 }),
                speed_mps: Vec::with_capacity(n),
                pedal: Vec::with_capacity(n),
                phase_cos: (phi_r - phi_l).cos(),
                hands: None,
            },
            k: 0,
            below_stop: None,
        })
    };
    let what = |v0: f64| move || format!("c = {clearance_m} m, v0 = {v0} m/s, seed {}", seeds[0]);
    if shape == EventShape::Single || accel <= 0.0 || speeds_mps.len() == 1 {
        // No shared pull-away: every speed (and, for Single, every deceleration) on its own.
        let runs = speeds_mps
            .iter()
            .zip(seeds)
            .map(|(&v0, &seed)| {
                if shape == EventShape::Single {
                    decels_g
                        .iter()
                        .map(|&d| {
                            let mut b = start(v0, seed)?;
                            b.sim = Simulator::new(p, &scenario(v0, d, seed))?;
                            put_hands(&mut b, seed)?;
                            Ok(runner.brake_branches(b, &[d], &what(v0))?.remove(0))
                        })
                        .collect()
                } else {
                    let mut b = start(v0, seed)?;
                    put_hands(&mut b, seed)?;
                    runner.brake_branches(b, decels_g, &what(v0))
                }
            })
            .collect::<anyhow::Result<Vec<_>>>()?;
        return Ok(GridRuns {
            runs,
            control_periods: runner.periods.get(),
        });
    }
    // The trunk: a pull-away towards the highest speed; each speed branches off it.
    let mut order: Vec<usize> = (0..speeds_mps.len()).collect();
    order.sort_by(|&a, &b| speeds_mps[a].total_cmp(&speeds_mps[b]));
    let mut trunk = start(vmax, seeds[0])?;
    put_hands(&mut trunk, seeds[0])?;
    let mut out: Vec<Option<Vec<ModelRun>>> = vec![None; speeds_mps.len()];
    for &i in &order {
        let v0 = speeds_mps[i];
        // The driver's demand towards v0 equals the trunk's while v <= v0 − accel·τ.
        while trunk.sim.state()[ix::V] <= v0 - accel * CRUISE_TAU_S && runner.tick(&mut trunk) {}
        let mut b = trunk.clone();
        let law = b.law.as_mut().expect("drive shape");
        law.v0_mps = v0;
        b.sim.set_unbalance_phases(Excitation::phases_of(seeds[i]));
        b.sim.reseed_noise(seeds[i]);
        put_hands(&mut b, seeds[i])?;
        let [phi_l, phi_r] = b.sim.unbalance_phases();
        b.out.phase_cos = (phi_r - phi_l).cos();
        out[i] = Some(runner.brake_branches(b, decels_g, &what(v0))?);
    }
    Ok(GridRuns {
        runs: out
            .into_iter()
            .map(|r| r.expect("every speed ran"))
            .collect(),
        control_periods: runner.periods.get(),
    })
}

/// [`run_model_grid`] for one initial speed: one braking per deceleration in `decels_g`, all
/// from the same pull-away and cruise, seeded by `seed`, with the hands of `p` (no hands draw).
pub fn run_model(
    p: &VehicleParams,
    clearance_m: f64,
    v0_mps: f64,
    decels_g: &[f64],
    seed: u64,
    shape: EventShape,
    cfg: &ObserverConfig,
) -> anyhow::Result<Vec<ModelRun>> {
    Ok(run_model_grid(
        p,
        clearance_m,
        &[v0_mps],
        decels_g,
        &[seed],
        shape,
        cfg,
        None,
    )?
    .runs
    .remove(0))
}

/// Runs one braking event at (`clearance_m`, `v0_mps`, `decel_g`) with `seed` on vehicle `p`,
/// started as `shape` says, and measures it through `sensor` ([`run_model`], then
/// [`measure_run`] with the same seed).
#[allow(clippy::too_many_arguments)]
pub fn simulate_event(
    p: &VehicleParams,
    clearance_m: f64,
    v0_mps: f64,
    decel_g: f64,
    seed: u64,
    shape: EventShape,
    sensor: &SensorModel,
    cfg: &ObserverConfig,
) -> anyhow::Result<SimulatedEvent> {
    let run = run_model(p, clearance_m, v0_mps, &[decel_g], seed, shape, cfg)?.remove(0);
    measure_run(&run, sensor, cfg, seed)
}

/// One model run seen through a steering angle sensor: δ_sw goes through `sensor` (its
/// sampling phase, offset and noise drawn from `seed`), the speed through a 50 Hz speed signal,
/// and both through the same [`Detector`] and [`Extractor`] that process a real log. Plus the
/// true amplitude of MODEL.md §11 from the continuous δ_sw over the detected window.
pub fn measure_run(
    run: &ModelRun,
    sensor: &SensorModel,
    cfg: &ObserverConfig,
    seed: u64,
) -> anyhow::Result<SimulatedEvent> {
    let (sw, speed, pedal, fs_true) = (&run.sw_rad, &run.speed_mps, &run.pedal, run.fs_hz);
    if sw.is_empty() {
        bail!("empty model run");
    }
    let mut rng = ChaCha8Rng::seed_from_u64(seed ^ 0x0b5e_77e5);
    let mut steer = Vec::with_capacity(sw.len() / 5);
    // A torque sensor's events are still found on the steering angle (the detector's
    // straightness and quality checks): an angle sensor as the reference bus has, drawn from
    // its own stream, beside the torque.
    let torque_sensor = !sensor.signal.is_angle();
    let mut torque = Vec::new();
    if torque_sensor {
        if run.torque_nm.len() != sw.len() {
            bail!(
                "a torque sensor needs the model's torsion-bar torque: the vehicle has no \
                 MODEL.md §15 column (enable [column] in its vehicle file)"
            );
        }
        sensor.sample_into(&run.torque_nm, fs_true, &mut rng, &mut torque);
        let mut rng_angle = ChaCha8Rng::seed_from_u64(seed ^ 0x0a4e_61e5);
        SensorModel::default().sample_into(sw, fs_true, &mut rng_angle, &mut steer);
    } else {
        sensor.sample_into(sw, fs_true, &mut rng, &mut steer);
    }
    let mut next_torque = 0usize;

    // Merge the steering samples with a 50 Hz speed signal into the detector's stream.
    let mut det = Detector::new(cfg.events.clone());
    let mut ex = Extractor::new();
    let speed_period_ns = 20_000_000i64;
    let mut next_speed_ns = 5_000_000i64;
    let mut found = None;
    let noise = super::features::SensorNoise {
        quant_step_deg: sensor.step_deg,
        noise_deg: sensor.noise_deg,
    };
    let mut ex_torque = Extractor::new();
    // A finished event's record and the features of the sensor's signal.
    let mut measure = |fin: crate::events::Finished<'_>| {
        let tf = torque_sensor
            .then(|| super::Observer::torque_features(&mut ex_torque, cfg, noise, &fin))
            .flatten();
        let (rec, f) = super::Observer::measure(&mut ex, cfg, fin);
        (rec, if torque_sensor { tf } else { f })
    };
    let mut feed = |s: Sample, det: &mut Detector| det.push(&s).map(&mut measure);
    let brake_at = |t_ns: i64| {
        let i = ((t_ns as f64 * 1e-9) * fs_true).round() as usize;
        pedal[i.min(pedal.len() - 1)]
    };
    for &(t_ns, a) in &steer {
        // The speed and torque samples up to this steering sample, in time order (the
        // detector takes its brake edges in the order it is fed).
        while found.is_none() {
            let tq = torque.get(next_torque).filter(|x| x.0 <= t_ns);
            let sp = (next_speed_ns <= t_ns).then_some(next_speed_ns);
            let s = match (tq, sp) {
                (Some(&(tt, m)), sp) if sp.is_none_or(|ts| tt < ts) => {
                    next_torque += 1;
                    Sample {
                        t_ns: tt,
                        torque_nm: Some(m),
                        brake: Some(brake_at(tt)),
                        ..Default::default()
                    }
                }
                (_, Some(ts)) => {
                    let i = ((ts as f64 * 1e-9) * fs_true).round() as usize;
                    next_speed_ns += speed_period_ns;
                    Sample {
                        t_ns: ts,
                        speed_mps: Some(speed[i.min(speed.len() - 1)]),
                        brake: Some(brake_at(ts)),
                        ..Default::default()
                    }
                }
                _ => break,
            };
            found = feed(s, &mut det);
        }
        if found.is_some() {
            break;
        }
        let s = Sample {
            t_ns,
            steer_rad: Some(a),
            brake: Some(brake_at(t_ns)),
            ..Default::default()
        };
        found = feed(s, &mut det);
        if found.is_some() {
            break;
        }
    }
    let (rec, feats) = match found {
        Some(x) => x,
        None => {
            let fin = det
                .flush()
                .context("the detector found no braking event in the simulated run")?;
            measure(fin)
        }
    };
    let features = feats.context("too few steering samples in the simulated event")?;
    // True amplitude: 1 kHz δ_sw, same band-pass, same window.
    let bp = Bandpass::new(fs_true, 3.0, 25.0, 4)?;
    let y = bp.filtfilt(sw);
    let i0 = (rec.t_start_s * fs_true).round() as usize;
    let i1 = (((rec.t_end_s + cfg.events.tail_s) * fs_true).round() as usize + 1).min(y.len());
    let true_peak_deg = crate::analysis::peak_abs(&y[i0.min(i1)..i1]).to_degrees();
    Ok(SimulatedEvent {
        features,
        true_peak_deg,
        v0_kmh: rec.v0_kmh,
        decel_g: rec.decel_g,
        used: rec.used,
        phase_cos: run.phase_cos,
    })
}
