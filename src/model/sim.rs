//! The simulator: a scenario (MODEL.md §6–§7) run through the model with the step-boundary
//! bookkeeping of §4/§10 (contact flags, held impact velocities, noise held over each step),
//! outputs per §8/§11, and a 1 kHz trace.
//!
//! What it is: the library entry point used by `shimmy simulate`, firmware-sim and the
//! observer. What it is not: signal analysis (see `crate::analysis`).

use super::braking::Demand;
use super::excitation::Excitation;
use super::integrate::{rk4_dense, rk4_step, rk4_step_shared, StageTires};
use super::params::{Hands, ParamError, VehicleParams};
use super::rhs::{ix, Aux, JointMode, Model, State, StepCtx, Switches, TireOut, Trig, N};
use serde::{Deserialize, Serialize};

/// One simulation case. `Default` is MODEL.md's reference case: dual clearance 0.1 mm,
/// 55 km/h, 0.5 g, seed 0, h = 1e-4 s, 10 s, unbalance and noise on.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct Scenario {
    /// c: radial clearance of the joints (§4); of the left joint when `clearance_right_m`
    /// is set.
    pub clearance_m: f64,
    /// Radial clearance of the right joint when it differs from the left (unequal wear);
    /// None = both joints have `clearance_m`. Ignored in the single-clearance variant.
    pub clearance_right_m: Option<f64>,
    /// Which joints have clearance.
    pub joints: JointMode,
    /// Seed of the unbalance phases and road noise (§7).
    pub seed: u64,
    /// Initial speed.
    pub v0_mps: f64,
    /// Peak deceleration of the §6 event in g.
    pub decel_g: f64,
    /// Simulated time.
    pub duration_s: f64,
    /// RK4 step.
    pub h_s: f64,
    /// Output rate of [`run`] (samples per second).
    pub output_hz: f64,
    /// Wheel unbalance on (§7, U from the vehicle file).
    pub unbalance: bool,
    /// Road noise on (§7).
    pub noise: bool,
    /// Initial kick θ1'(0); None takes the vehicle file's value (§7).
    pub kick_theta1_rad_s: Option<f64>,
    /// Initial θ2'(0) (0 in MODEL.md; used by symmetry checks).
    pub kick_theta2_rad_s: f64,
    /// Model switches (checks only).
    pub switches: Switches,
    /// Integration scheme.
    pub integrator: Integrator,
}

/// Integration scheme.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum Integrator {
    /// MODEL.md §10 as specified: RK4 with 8 cold Newton steps of the slip inversion per
    /// right-hand-side evaluation.
    Rk4,
    /// RK4 with the braking-slip Newton iteration warm-started from the previous stage and
    /// stopped at convergence (same solution to 1e-10 % slip, fewer transcendental calls).
    Rk4WarmSlip,
    /// RK4 on the same grid h, multirate: the tire outputs (§5: F_x, F_y, M_z, σ, κ) are
    /// evaluated exactly once per step, at its start, and extrapolated linearly in time over
    /// the stages through the previous step's values; the sines and cosines of the stage
    /// states are shifted from the step start by angle addition (exact to rounding). The
    /// joints, kinematics and everything else are evaluated at every stage as in `Rk4`. The
    /// Magic Formula goes through [`super::tire::MfTables`] (relative error < 1e-8).
    /// Not MODEL.md §10 to the last digit: its error is in docs/BENCHMARKS.md.
    Rk4Multirate,
    /// `Rk4Multirate` while a joint is in contact or was recently, and in free flight (no
    /// contact anywhere in the step, checked at every stage and by a cubic through the
    /// end-point penetrations) one RK4 step over up to [`ADAPTIVE_MAX_MERGE`] grid steps,
    /// with the tires evaluated at every stage (tabulated Magic Formula as in
    /// `Rk4Multirate`) and the §7 road noise averaged over the merged grid
    /// intervals. A step that would touch a contact is rejected and redone on the grid, so
    /// contact onsets are found on the grid as in `Rk4`. Merging happens only in
    /// [`Simulator::advance`] (and [`run`]); `Simulator::step` is one grid step. At
    /// standstill (below [`QUIET_SPEED_MPS`], §6 fade finished) the §7 noise moment, scaled by
    /// v/v_n ≈ 0, is left out (its draws are made up if the car moves again, so the
    /// realisation is unchanged), and merged steps grow to ≈ 2 ms ([`QUIET_H_LAMBDA`]), past
    /// the `advance` boundaries, which then see the step's RK4 dense output.
    Rk4Adaptive,
}

impl Integrator {
    /// The name used by `shimmy simulate --integrator` and in serde (snake_case).
    pub fn name(self) -> &'static str {
        match self {
            Integrator::Rk4 => "rk4",
            Integrator::Rk4WarmSlip => "rk4_warm_slip",
            Integrator::Rk4Multirate => "rk4_multirate",
            Integrator::Rk4Adaptive => "rk4_adaptive",
        }
    }

    /// All schemes.
    pub const ALL: [Integrator; 4] = [
        Integrator::Rk4,
        Integrator::Rk4WarmSlip,
        Integrator::Rk4Multirate,
        Integrator::Rk4Adaptive,
    ];

    /// Parses a name (snake_case as in serde, or with hyphens).
    pub fn from_name(name: &str) -> Option<Self> {
        let n = name.replace('-', "_");
        Self::ALL.into_iter().find(|i| i.name() == n)
    }

    fn shares_trig(self) -> bool {
        matches!(self, Integrator::Rk4Multirate | Integrator::Rk4Adaptive)
    }
}

/// `Integrator::Rk4Multirate` evaluates the tires exactly every this many grid steps.
pub const MULTIRATE_TIRE_EVERY: u64 = 2;

/// Most grid steps `Integrator::Rk4Adaptive` merges into one free-flight step.
pub const ADAPTIVE_MAX_MERGE: u64 = 10;

/// Most grid steps `Integrator::Rk4Adaptive` merges into one free-flight step at standstill
/// (see [`QUIET_SPEED_MPS`]), at most; the vehicle's own bound is set by [`QUIET_H_LAMBDA`] (never
/// below [`ADAPTIVE_MAX_MERGE`]).
pub const ADAPTIVE_QUIET_MAX_MERGE: u64 = 25;

/// Standstill merged steps are at most this over the rate c_g/m_t of the fastest free mode,
/// the tie rod on its restraint damper (§3 eq. (4); a real eigenvalue ≈ −910 s⁻¹ at the §9
/// values, so ≈ 2 ms): inside RK4's real stability interval (−2.785, 0) with margin. That
/// mode is then damped by RK4's 0.29 per step instead of e^−1.8 = 0.17, which only shows in
/// the already decayed tie-rod position (sub-nanometre after a stop).
pub const QUIET_H_LAMBDA: f64 = 1.8;

/// `Integrator::Rk4Adaptive`: below this speed, with a demand that cannot speed the car up,
/// the vehicle is at standstill for the merging: the §7 road-noise moment (scaled by v/v_n,
/// here < 7·10⁻⁵·σ) is left out, and merged steps may be longer than 1 ms (see
/// [`QUIET_H_LAMBDA`]), past the caller's `advance` boundary (dense output).
pub const QUIET_SPEED_MPS: f64 = 1e-3;

/// `Integrator::Rk4Adaptive`: an accepted merged step that ends after the boundary of the
/// `advance` call that took it. The simulator shows the dense-output state at its boundaries
/// until the step's end is reached.
#[derive(Debug, Clone)]
struct Lookahead {
    /// Grid indices of the step's start and end.
    start: u64,
    end: u64,
    /// Step length, start state and stage slopes (for [`rk4_dense`]).
    h: f64,
    y0: State,
    k: [State; 4],
    /// End state, its sines/cosines and penetrations.
    y1: State,
    trig1: Trig,
    pen1: [(f64, f64); 2],
}

impl Default for Scenario {
    fn default() -> Self {
        Self {
            clearance_m: 0.1e-3,
            clearance_right_m: None,
            joints: JointMode::Dual,
            seed: 0,
            v0_mps: 55.0 / 3.6,
            decel_g: 0.5,
            duration_s: 10.0,
            h_s: 1e-4,
            output_hz: 1000.0,
            unbalance: true,
            noise: true,
            kick_theta1_rad_s: None,
            kick_theta2_rad_s: 0.0,
            switches: Switches::default(),
            integrator: Integrator::Rk4,
        }
    }
}

/// A scenario value that cannot be simulated.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
#[error("scenario `{key}` = {value}: {why}")]
pub struct ScenarioError {
    pub key: &'static str,
    pub value: f64,
    pub why: &'static str,
}

impl Scenario {
    /// Checks the scenario; errors name the field.
    pub fn validate(&self) -> Result<(), ScenarioError> {
        let err = |key, value, why| Err(ScenarioError { key, value, why });
        if !(self.clearance_m.is_finite() && self.clearance_m > 0.0) {
            return err("clearance_m", self.clearance_m, "must be finite and > 0");
        }
        if self.clearance_m > 5e-3 {
            return err("clearance_m", self.clearance_m, "must be <= 5 mm");
        }
        if let Some(c) = self.clearance_right_m {
            if !(c.is_finite() && c > 0.0 && c <= 5e-3) {
                return err("clearance_right_m", c, "must be finite and in (0, 5] mm");
            }
        }
        if !(self.v0_mps.is_finite() && self.v0_mps >= 0.0) {
            return err("v0_mps", self.v0_mps, "must be finite and >= 0");
        }
        if !(self.decel_g.is_finite() && (0.0..=1.2).contains(&self.decel_g)) {
            return err("decel_g", self.decel_g, "must lie in [0, 1.2] g");
        }
        if !(self.duration_s.is_finite() && self.duration_s > 0.0 && self.duration_s <= 3600.0) {
            return err("duration_s", self.duration_s, "must lie in (0, 3600] s");
        }
        if !(self.h_s.is_finite() && self.h_s > 0.0 && self.h_s <= 1e-3) {
            return err("h_s", self.h_s, "must lie in (0, 1e-3] s");
        }
        if !(self.output_hz.is_finite() && self.output_hz > 0.0 && self.output_hz <= 1.0 / self.h_s)
        {
            return err("output_hz", self.output_hz, "must lie in (0, 1/h_s]");
        }
        Ok(())
    }
}

/// Everything observable at one instant (SI; δ_sw in rad).
#[derive(Debug, Clone, Copy, Default, PartialEq, Serialize)]
pub struct Outputs {
    pub t_s: f64,
    pub theta1_rad: f64,
    pub theta2_rad: f64,
    pub theta3_rad: f64,
    pub x_m: f64,
    pub theta4_rad: f64,
    pub theta1_rate_rad_s: f64,
    pub theta2_rate_rad_s: f64,
    pub theta3_rate_rad_s: f64,
    pub x_rate_mps: f64,
    pub theta4_rate_rad_s: f64,
    /// Transient slips α_L, α_R (§5.2).
    pub alpha_t: [f64; 2],
    pub speed_mps: f64,
    pub wheel_angle_rad: f64,
    /// Filtered deceleration a_f (§6) and demanded deceleration.
    pub decel_filtered_mps2: f64,
    pub decel_demand_mps2: f64,
    /// Steering-wheel angle seen by the sensor (§8, or §15 rim angle).
    pub delta_sw_rad: f64,
    /// Column torque T_c (§15; 0 when off).
    pub column_torque_nm: f64,
    /// Contact forces on the pins, L/R, x (across the car) and y (forward) (§4).
    pub contact_fx_n: [f64; 2],
    pub contact_fy_n: [f64; 2],
    /// Penetration δ = |e| − c, L/R (negative in free flight; |e| for an ideal joint).
    pub penetration_m: [f64; 2],
    /// Tire forces L/R: F_x (braking > 0), F_y, M_z, F_z (§5).
    pub tire_fx_n: [f64; 2],
    pub tire_fy_n: [f64; 2],
    pub tire_mz_nm: [f64; 2],
    pub tire_fz_n: [f64; 2],
}

/// The stepping simulator. `step` allocates nothing.
#[derive(Debug, Clone)]
pub struct Simulator {
    model: Model,
    y: State,
    steps: u64,
    h: f64,
    ctx: StepCtx,
    exc: Excitation,
    noise_on: bool,
    noise_stride: u64,
    integrator: Integrator,
    /// Vehicle parameters (kept to rebuild the joint constants in `set_clearance`).
    params: VehicleParams,
    /// Sines and cosines of the current state (kept by the multirate integrators).
    trig: Trig,
    /// Penetration and rate of each joint at the current state ((−∞, 0) if ideal).
    pen: [(f64, f64); 2],
    /// Multirate: the last three exact tire outputs, their times, how many are valid (0 =
    /// restart), and the grid step of the newest.
    tire_hist: [TireOut; 3],
    tire_t: [f64; 3],
    tire_n: usize,
    tire_step: u64,
    /// Adaptive: grid steps before this index are taken on the grid (after a contact or a
    /// rejected merged step).
    fine_until: u64,
    /// Adaptive: exact tire outputs at the starts of the current and the previous merged
    /// steps of an unbroken run of merged steps, and how many of them are valid.
    merged_tires: [TireOut; 3],
    merged_t: [f64; 3],
    merged_valid: usize,
    /// Adaptive: merged steps taken and rejected (diagnostics).
    merged: u64,
    rejected: u64,
    /// Adaptive: a merged step that runs past the current time (see [`Lookahead`]); while it
    /// is pending, `y` is its dense output at `steps`.
    ahead: Option<Lookahead>,
    /// Adaptive: grid steps per merged step at standstill (from [`QUIET_H_LAMBDA`]).
    quiet_merge: u64,
    /// Adaptive: standstill steps skipped noise draws; the generator is caught up to the
    /// current step (same values as drawing them in turn) before the noise is used again.
    noise_behind: bool,
}

/// Hold time of the road noise (MODEL.md §7: held over each step of h = 1e-4 s).
pub const NOISE_HOLD_S: f64 = 1e-4;

impl Simulator {
    /// Validates both inputs and sets the §7 initial conditions.
    pub fn new(p: &VehicleParams, sc: &Scenario) -> anyhow::Result<Self> {
        p.validate()?;
        sc.validate()?;
        let noise_std = if sc.noise {
            p.excitation.noise_std_nm
        } else {
            0.0
        };
        // §7: noise held over each step of the reference h = 1e-4 s. Smaller steps keep the
        // same 1e-4 s grid (so a step-size study compares the same noise realisation); larger
        // steps draw once per step.
        let noise_stride = (NOISE_HOLD_S / sc.h_s).round().max(1.0) as u64;
        let noise_dt = noise_stride as f64 * sc.h_s;
        let exc = Excitation::new(sc.seed, noise_std, p.excitation.noise_tau_s, noise_dt);
        let unbalance = if sc.unbalance {
            p.excitation.unbalance_kgm
        } else {
            0.0
        };
        let mut model = Model::new(
            p,
            sc.clearance_m,
            sc.joints,
            sc.switches,
            unbalance,
            exc.phases,
        );
        if let Some(right_m) = sc.clearance_right_m {
            model.set_clearance(p, sc.clearance_m, right_m);
        }
        let mut y = [0.0; N];
        y[ix::TH1D] = sc.kick_theta1_rad_s.unwrap_or(p.excitation.kick_rad_per_s);
        y[ix::TH2D] = sc.kick_theta2_rad_s;
        y[ix::V] = sc.v0_mps;
        let ctx = StepCtx {
            v_imp: [None; 2],
            noise: if sc.noise { exc.noise } else { [0.0; 2] },
            demand: Demand::Event {
                a_max_mps2: sc.decel_g * p.vehicle.gravity_mps2,
                onset_s: p.braking.onset_s,
                ramp_s: p.braking.ramp_s,
            },
            kappa_guess: [0.0; 2],
            warm_slip: sc.integrator != Integrator::Rk4,
            mf_table: if sc.integrator.shares_trig() {
                Some(super::tire::MfTables::get())
            } else {
                None
            },
        };
        let mut sim = Self {
            model,
            y,
            steps: 0,
            h: sc.h_s,
            ctx,
            exc,
            noise_on: sc.noise,
            noise_stride,
            integrator: sc.integrator,
            params: p.clone(),
            trig: Trig::default(),
            pen: [(f64::NEG_INFINITY, 0.0); 2],
            tire_hist: [TireOut::default(); 3],
            tire_t: [0.0; 3],
            tire_n: 0,
            tire_step: 0,
            fine_until: 0,
            merged_tires: [TireOut::default(); 3],
            merged_t: [0.0; 3],
            merged_valid: 0,
            merged: 0,
            rejected: 0,
            ahead: None,
            noise_behind: false,
            quiet_merge: {
                let h_max = QUIET_H_LAMBDA * p.steering.tie_rod_mass_kg
                    / p.steering.restraint_damping_ns_per_m;
                ((h_max / sc.h_s).floor() as u64)
                    .clamp(ADAPTIVE_MAX_MERGE, ADAPTIVE_QUIET_MAX_MERGE)
            },
        };
        sim.update_contact_flags();
        Ok(sim)
    }

    /// Current time (step count × h, no drift).
    #[inline]
    pub fn t(&self) -> f64 {
        self.steps as f64 * self.h
    }

    /// Step size.
    pub fn h(&self) -> f64 {
        self.h
    }

    /// The state vector (indices in [`ix`]).
    pub fn state(&self) -> &State {
        &self.y
    }

    /// The model constants.
    pub fn model(&self) -> &Model {
        &self.model
    }

    /// The wheel-unbalance phases φ_L, φ_R of this run (MODEL.md §7, drawn from the seed). Both
    /// wheels turn with the one spin angle φ, so their difference is fixed for the whole run.
    pub fn unbalance_phases(&self) -> [f64; 2] {
        self.exc.phases
    }

    /// Sets the wheel-unbalance phases φ_L, φ_R (rad) from now on: what happens to their
    /// difference when the two wheels do not roll the same distance (a turn, unequal rolling
    /// radii), which the model's one spin angle φ cannot do by itself (§1, §7). Non-finite
    /// values are ignored.
    pub fn set_unbalance_phases(&mut self, phases: [f64; 2]) {
        if !phases.iter().all(|p| p.is_finite()) || phases == self.model.phases {
            return;
        }
        // As for a new demand: no step taken ahead, no tire forces extrapolated across it.
        self.commit_lookahead();
        self.tire_n = 0;
        self.merged_valid = 0;
        self.model.phases = phases;
        self.exc.phases = phases;
        self.trig = Trig::exact(&self.model, &self.y);
    }

    /// Draws the road noise from `seed` from now on (§7; [`Excitation::reseed_noise`]): the
    /// same vehicle on another stretch of road. Used to branch one run into several
    /// independent continuations.
    pub fn reseed_noise(&mut self, seed: u64) {
        self.commit_lookahead();
        self.sync_noise();
        self.exc.reseed_noise(seed);
    }

    /// Sets the road noise's standard deviation (§7, N·m at v_n) from now on: a change of road
    /// roughness. Nothing changes when the run has no road noise, or for a value that is not
    /// finite and positive.
    pub fn set_road_noise_std(&mut self, sigma_nm: f64) {
        if !self.noise_on {
            return;
        }
        self.commit_lookahead();
        self.sync_noise();
        self.exc.set_sigma(sigma_nm);
    }

    /// Sets the radial clearances of the left and right joints from now on (§4): unequal
    /// wear, or clearance growing with distance (firmware-sim's wear option). A joint whose
    /// clearance grows while the pin presses into the bushing simply sees a smaller
    /// penetration at the next step; the contact flags are re-evaluated here (§10).
    /// Errors (and changes nothing) on a value that is not finite or not in (0, 5] mm.
    pub fn set_clearance(&mut self, left_m: f64, right_m: f64) -> Result<(), ScenarioError> {
        for (key, c) in [("clearance_left_m", left_m), ("clearance_right_m", right_m)] {
            if !(c.is_finite() && c > 0.0 && c <= 5e-3) {
                return Err(ScenarioError {
                    key,
                    value: c,
                    why: "must be finite and in (0, 5] mm",
                });
            }
        }
        self.commit_lookahead();
        self.model.set_clearance(&self.params, left_m, right_m);
        self.update_contact_flags();
        Ok(())
    }

    /// Puts the driver's hands `h` on the rim from now on (MODEL.md §15 eq. 6: inertia added to
    /// J_sw, stiffness to k_h, damping as c_h), e.g. at the start of a braking event. Without
    /// the column option the hands are kept but change nothing. Errors (and changes nothing)
    /// on a value that is not finite or negative. Allocates nothing.
    pub fn set_hands(&mut self, h: &Hands) -> Result<(), ParamError> {
        h.validate()?;
        if *h == self.model.hands() {
            return Ok(());
        }
        // No step taken ahead under the old hands.
        self.commit_lookahead();
        self.model.set_hands(h);
        self.params.column.set_hands(*h);
        Ok(())
    }

    /// The driver's hands on the rim in use (§15).
    pub fn hands(&self) -> Hands {
        self.model.hands()
    }

    /// Radial clearances (left, right) in use.
    pub fn clearance_m(&self) -> [f64; 2] {
        [self.model.joint[0].c, self.model.joint[1].c]
    }

    /// Switches the longitudinal input to an external demand (m/s², > 0 braking, < 0
    /// accelerating), held from now on until set again. Replaces the §6 event law.
    pub fn set_decel_demand(&mut self, a_mps2: f64) {
        let demand = Demand::External {
            a_mps2: if a_mps2.is_finite() { a_mps2 } else { 0.0 },
        };
        if demand != self.ctx.demand {
            // A jump in the demand: do not extrapolate the tire forces across it, nor keep a
            // step taken ahead under the old demand.
            self.commit_lookahead();
            self.tire_n = 0;
            self.merged_valid = 0;
        }
        self.ctx.demand = demand;
    }

    /// The integration scheme.
    pub fn integrator(&self) -> Integrator {
        self.integrator
    }

    /// `Integrator::Rk4Adaptive`: (merged free-flight steps taken, merged steps rejected).
    pub fn merge_stats(&self) -> (u64, u64) {
        (self.merged, self.rejected)
    }

    /// Advances one step h: RK4 with contact flags, impact velocities and noise held, then the
    /// step-boundary updates of MODEL.md §4/§10.
    #[inline]
    pub fn step(&mut self) {
        self.commit_lookahead();
        self.sync_noise();
        let t = self.t();
        match self.integrator {
            Integrator::Rk4 | Integrator::Rk4WarmSlip => {
                let aux = rk4_step(&self.model, t, &mut self.y, self.h, &self.ctx);
                self.ctx.kappa_guess = aux.kappa;
            }
            Integrator::Rk4Multirate | Integrator::Rk4Adaptive => self.multirate_step(t),
        }
        self.steps += 1;
        self.update_contact_flags();
        if self.noise_on && self.steps.is_multiple_of(self.noise_stride) {
            self.exc.advance();
            self.ctx.noise = self.exc.noise;
        }
    }

    /// Advances `n` grid steps (time n·h). The same as calling [`Self::step`] `n` times,
    /// except for `Integrator::Rk4Adaptive`, which merges free-flight grid steps here.
    #[inline]
    pub fn advance(&mut self, n: u64) {
        if self.integrator != Integrator::Rk4Adaptive {
            for _ in 0..n {
                self.step();
            }
            return;
        }
        let end = self.steps + n;
        while self.steps < end {
            if let Some(la) = &self.ahead {
                if la.end > end {
                    // Inside a step taken ahead: its dense output at this boundary.
                    let theta = (end - la.start) as f64 / (la.end - la.start) as f64;
                    self.y = rk4_dense(&la.y0, &la.k, la.h, theta);
                    self.steps = end;
                    return;
                }
                self.y = la.y1;
                self.trig = la.trig1;
                self.pen = la.pen1;
                self.steps = la.end;
                self.ahead = None;
                continue;
            }
            let quiet = self.quiet();
            let m = if quiet {
                self.quiet_merge
            } else {
                (end - self.steps).min(ADAPTIVE_MAX_MERGE)
            };
            let free = self.ctx.v_imp[0].is_none() && self.ctx.v_imp[1].is_none();
            if m >= 2 && free && self.steps >= self.fine_until && self.try_merged(m, quiet, end) {
                continue;
            }
            if !free {
                // Stay on the grid until ADAPTIVE_MAX_MERGE steps after the last contact.
                self.fine_until = self.steps + 1 + ADAPTIVE_MAX_MERGE;
            }
            self.merged_valid = 0;
            self.step();
        }
    }

    /// One grid step of the multirate scheme: the tire outputs are evaluated exactly at the
    /// start of every [`MULTIRATE_TIRE_EVERY`]-th grid step and extrapolated over the stages
    /// by the parabola through the last three such values (a line or a hold after a restart).
    #[inline]
    fn multirate_step(&mut self, t: f64) {
        if self.tire_n == 0 || self.steps - self.tire_step >= MULTIRATE_TIRE_EVERY {
            let now = self.model.tires(t, &self.y, &self.trig, &self.ctx);
            self.tire_hist = [now, self.tire_hist[0], self.tire_hist[1]];
            self.tire_t = [t, self.tire_t[0], self.tire_t[1]];
            self.tire_n = (self.tire_n + 1).min(3);
            self.tire_step = self.steps;
            self.ctx.kappa_guess = now.kappa;
        }
        let off = [self.tire_t[0] - t, self.tire_t[1] - t, self.tire_t[2] - t];
        let tires = StageTires::Lagrange {
            f: &self.tire_hist,
            off,
            n: self.tire_n,
        };
        rk4_step_shared(
            &self.model,
            t,
            &mut self.y,
            self.h,
            &self.ctx,
            &self.trig,
            tires,
            None,
        );
    }

    /// Whether the vehicle is at standstill for `Integrator::Rk4Adaptive` (below
    /// [`QUIET_SPEED_MPS`], and the demand brakes or holds, so it stays there).
    #[inline]
    fn quiet(&self) -> bool {
        let v = self.y[ix::V];
        v.abs() < QUIET_SPEED_MPS && self.ctx.demand.a_dem(self.t(), v, self.model.v_stop) >= 0.0
    }

    /// After standstill steps that skipped the noise draws: draws them now, in order, so the
    /// noise of the current grid step is the one the grid schemes see (§7).
    #[inline]
    fn sync_noise(&mut self) {
        if self.noise_behind {
            self.exc.advance_to(self.steps / self.noise_stride);
            self.ctx.noise = self.exc.noise;
            self.noise_behind = false;
        }
    }

    /// Drops a pending [`Lookahead`] step: its dense output at the current boundary (already
    /// in `y`) becomes the start of what follows. Used before a single grid step and when an
    /// input changes (demand, clearance), so that no step outlives the inputs it was taken
    /// with.
    #[inline]
    fn commit_lookahead(&mut self) {
        if self.ahead.is_some() {
            self.ahead = None;
            self.merged_valid = 0;
            self.tire_n = 0;
            self.update_contact_flags();
        }
    }

    /// Tries one RK4 step over `m` grid steps in free flight (`Integrator::Rk4Adaptive`).
    /// Accepted only if no clearance joint penetrates at any stage, at the end, or on the
    /// cubic Hermite interpolant of δ through the two ends; otherwise everything is restored,
    /// the next `m` grid steps are forced onto the grid, and false is returned. `quiet`: at
    /// standstill, without road noise. A step that ends after grid index `end` (the boundary
    /// of the current `advance`) is kept as a [`Lookahead`].
    fn try_merged(&mut self, m: u64, quiet: bool, end: u64) -> bool {
        if !quiet {
            self.sync_noise();
        }
        let t = self.t();
        let y0 = self.y;
        let exc0 = (!quiet).then(|| self.exc.clone());
        let noise0 = self.ctx.noise;
        let noise_end = if quiet {
            // §7: the noise moment is scaled by v/v_n ≈ 0; its draws are made up later by
            // `sync_noise` if the car moves again.
            self.noise_behind = self.noise_on;
            self.ctx.noise = [0.0; 2];
            [0.0; 2]
        } else {
            // §7 noise: the held grid values averaged over the merged intervals.
            let mut sum = [0.0; 2];
            let mut k = self.steps;
            for _ in 0..m {
                sum[0] += self.ctx.noise[0];
                sum[1] += self.ctx.noise[1];
                k += 1;
                if self.noise_on && k.is_multiple_of(self.noise_stride) {
                    self.exc.advance();
                    self.ctx.noise = self.exc.noise;
                }
            }
            let noise_end = self.ctx.noise;
            let inv_m = 1.0 / m as f64;
            self.ctx.noise = [sum[0] * inv_m, sum[1] * inv_m];
            noise_end
        };
        let lookahead = self.steps + m > end;
        let mut stages = [[0.0; N]; 4];
        let big_h = m as f64 * self.h;
        // Tires: after two merged steps in a row, exact once at the step start and
        // extrapolated over the stages by the parabola through the last three step starts;
        // otherwise exact at every stage.
        let now = self.model.tires(t, &self.y, &self.trig, &self.ctx);
        let f = [now, self.merged_tires[0], self.merged_tires[1]];
        let dt = [0.0, t - self.merged_t[0], t - self.merged_t[1]];
        let tires = if self.merged_valid >= 2 {
            StageTires::Lagrange {
                f: &f,
                off: [0.0, -dt[1], -dt[2]],
                n: 3,
            }
        } else {
            StageTires::Exact
        };
        let (aux, max_delta) = rk4_step_shared(
            &self.model,
            t,
            &mut self.y,
            big_h,
            &self.ctx,
            &self.trig,
            tires,
            lookahead.then_some(&mut stages),
        );
        let trig1 = Trig::exact(&self.model, &self.y);
        let pen1 = self.model.penetrations_trig(&self.y, &trig1);
        let mut ok = max_delta < 0.0 && self.y.iter().all(|v| v.is_finite());
        for (i, (&p0, &p1)) in self.pen.iter().zip(&pen1).enumerate() {
            if self.model.has_clearance(i) && ok {
                ok = hermite_stays_negative(p0, p1, big_h);
            }
        }
        if !ok {
            self.y = y0;
            if let Some(exc0) = exc0 {
                self.exc = exc0;
            }
            self.ctx.noise = noise0;
            self.fine_until = self.steps + m;
            self.rejected += 1;
            self.merged_valid = 0;
            return false;
        }
        self.merged_tires = f;
        self.merged_t = [t, self.merged_t[0], self.merged_t[1]];
        self.merged_valid = (self.merged_valid + 1).min(3);
        self.merged += 1;
        if lookahead {
            self.ahead = Some(Lookahead {
                start: self.steps,
                end: self.steps + m,
                h: big_h,
                y0,
                k: stages,
                y1: self.y,
                trig1,
                pen1,
            });
        } else {
            self.steps += m;
            self.trig = trig1;
            self.pen = pen1;
        }
        self.ctx.noise = noise_end;
        self.ctx.kappa_guess = if self.merged_valid >= 3 {
            now.kappa
        } else {
            aux.kappa
        };
        // The grid steps that follow hold the tires for their first step.
        self.tire_n = 0;
        true
    }

    /// §4: the flag is set at the first boundary with δ > 0, recording δ'⁻ (floored), and
    /// cleared at separation.
    #[inline]
    fn update_contact_flags(&mut self) {
        let pen = if self.integrator.shares_trig() {
            self.trig = Trig::exact(&self.model, &self.y);
            self.model.penetrations_trig(&self.y, &self.trig)
        } else {
            self.model.penetrations(&self.y)
        };
        self.pen = pen;
        for (i, &(delta, delta_dot)) in pen.iter().enumerate() {
            if delta > 0.0 {
                if self.ctx.v_imp[i].is_none() {
                    self.ctx.v_imp[i] = Some(delta_dot.max(self.model.joint[i].v_imp_min));
                }
            } else {
                self.ctx.v_imp[i] = None;
            }
        }
    }

    /// Whether each joint is flagged in contact at the current step boundary.
    pub fn in_contact(&self) -> [bool; 2] {
        [self.ctx.v_imp[0].is_some(), self.ctx.v_imp[1].is_some()]
    }

    /// All outputs at the current instant (one extra right-hand-side evaluation).
    pub fn outputs(&self) -> Outputs {
        let mut dy = [0.0; N];
        let mut aux = Aux::default();
        self.model
            .eval(self.t(), &self.y, &self.ctx, &mut dy, &mut aux);
        let y = &self.y;
        Outputs {
            t_s: self.t(),
            theta1_rad: y[ix::TH1],
            theta2_rad: y[ix::TH2],
            theta3_rad: y[ix::TH3],
            x_m: y[ix::X],
            theta4_rad: y[ix::TH4],
            theta1_rate_rad_s: y[ix::TH1D],
            theta2_rate_rad_s: y[ix::TH2D],
            theta3_rate_rad_s: y[ix::TH3D],
            x_rate_mps: y[ix::XD],
            theta4_rate_rad_s: y[ix::TH4D],
            alpha_t: [y[ix::AL], y[ix::AR]],
            speed_mps: y[ix::V],
            wheel_angle_rad: y[ix::PHI],
            decel_filtered_mps2: y[ix::AF],
            decel_demand_mps2: aux.a_dem,
            delta_sw_rad: self.model.delta_sw(y),
            column_torque_nm: aux.column_torque,
            contact_fx_n: [aux.joint[0].f[0], aux.joint[1].f[0]],
            contact_fy_n: [aux.joint[0].f[1], aux.joint[1].f[1]],
            penetration_m: [aux.joint[0].delta, aux.joint[1].delta],
            tire_fx_n: aux.fx,
            tire_fy_n: aux.fy,
            tire_mz_nm: aux.mz,
            tire_fz_n: aux.fz,
        }
    }
}

/// A uniformly sampled run.
#[derive(Debug, Clone)]
pub struct Trace {
    /// Sample rate.
    pub fs_hz: f64,
    /// Samples, the first at t = 0.
    pub samples: Vec<Outputs>,
    /// Brake onset t_b (§6).
    pub brake_onset_s: f64,
}

impl Trace {
    /// One column, e.g. `trace.column(|o| o.theta1_rad)`.
    pub fn column(&self, f: impl Fn(&Outputs) -> f64) -> Vec<f64> {
        self.samples.iter().map(f).collect()
    }

    /// Time of the stop: first sample after the brake onset with speed below 0.1 m/s (§6);
    /// None if the vehicle never stops.
    pub fn t_stop_s(&self) -> Option<f64> {
        self.samples
            .iter()
            .find(|o| o.t_s > self.brake_onset_s && o.speed_mps < 0.1)
            .map(|o| o.t_s)
    }

    /// §11 braking window [t_b, t_stop + 0.3 s] as a sample index range (clipped to the
    /// trace; to its end if the car does not stop).
    pub fn braking_window(&self) -> std::ops::Range<usize> {
        let n = self.samples.len();
        let i0 = ((self.brake_onset_s * self.fs_hz).round() as usize).min(n);
        let i1 = match self.t_stop_s() {
            Some(ts) => (((ts + 0.3) * self.fs_hz).round() as usize + 1).min(n),
            None => n,
        };
        i0..i1.max(i0)
    }
}

/// Runs a scenario and samples it at `sc.output_hz` (1 kHz by default, §10).
pub fn run(p: &VehicleParams, sc: &Scenario) -> anyhow::Result<Trace> {
    let mut sim = Simulator::new(p, sc)?;
    let n_steps = (sc.duration_s / sc.h_s).round() as u64;
    let stride = ((1.0 / sc.output_hz) / sc.h_s).round().max(1.0) as u64;
    let mut samples = Vec::with_capacity((n_steps / stride + 1) as usize);
    samples.push(sim.outputs());
    for _ in 0..n_steps / stride {
        sim.advance(stride);
        samples.push(sim.outputs());
    }
    Ok(Trace {
        fs_hz: 1.0 / (stride as f64 * sc.h_s),
        samples,
        brake_onset_s: p.braking.onset_s,
    })
}

/// Whether the cubic Hermite interpolant of a penetration δ through (δ0, δ0') at the start and
/// (δ1, δ1') at the end of a step of length `h` stays negative (checked at eighths of the step).
fn hermite_stays_negative((d0, r0): (f64, f64), (d1, r1): (f64, f64), h: f64) -> bool {
    if !(d0 < 0.0 && d1 < 0.0) {
        return false;
    }
    if d0 == f64::NEG_INFINITY {
        return true;
    }
    (1..8).all(|j| {
        let s = j as f64 / 8.0;
        let (s2, s3) = (s * s, s * s * s);
        let d = (2.0 * s3 - 3.0 * s2 + 1.0) * d0
            + (s3 - 2.0 * s2 + s) * h * r0
            + (-2.0 * s3 + 3.0 * s2) * d1
            + (s3 - s2) * h * r1;
        d < 0.0
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    fn adaptive(sc: Scenario) -> Simulator {
        let sc = Scenario {
            integrator: Integrator::Rk4Adaptive,
            ..sc
        };
        Simulator::new(&VehicleParams::default(), &sc).unwrap()
    }

    #[test]
    fn standstill_steps_ahead_end_where_they_would_without_the_boundaries() {
        // Stopped (v < QUIET_SPEED_MPS from 4.35 s on): merged steps of ≈ 2 ms run past the
        // 1 ms boundaries and are shown by dense output there. Without road noise, so that
        // the grid steps see the same model (the standstill steps leave the noise out).
        let mut a = adaptive(Scenario {
            noise: false,
            ..Scenario::default()
        });
        a.advance(44_000);
        assert!(a.quiet());
        let mut b = a.clone();
        let mut fine = a.clone();
        a.advance(5_000);
        // Largest deviation and largest value of θ1, x, θ1' over the samples.
        let (mut dev, mut max) = ([0.0f64; 3], [0.0f64; 3]);
        for _ in 0..500 {
            b.advance(10);
            for _ in 0..10 {
                fine.step();
            }
            for (j, i) in [ix::TH1, ix::X, ix::TH1D].into_iter().enumerate() {
                dev[j] = dev[j].max((b.y[i] - fine.y[i]).abs());
                max[j] = max[j].max(fine.y[i].abs());
            }
        }
        let rel = [dev[0] / max[0], dev[1] / max[1], dev[2] / max[2]];
        // Same merged steps, whatever the chunking: identical end state.
        assert_eq!(a.y, b.y);
        assert_eq!(a.steps, b.steps);
        // The dense output at the boundaries agrees with grid steps.
        // θ1, θ1' to 1e-4 of their amplitude; the tie-rod position x (< 1 nm here) to 10 %:
        // RK4 damps its fast real mode less at 2 ms (QUIET_H_LAMBDA).
        assert!(
            rel[0] < 1e-4 && rel[2] < 1e-4 && rel[1] < 0.1,
            "dense output vs grid steps: {dev:?} of {max:?}"
        );
    }

    #[test]
    fn noise_draws_skipped_at_standstill_are_made_up_when_the_car_moves_again() {
        let mut sim = adaptive(Scenario {
            v0_mps: 3.0,
            ..Scenario::default()
        });
        sim.set_decel_demand(5.0);
        sim.advance(15_000); // stopped after ≈ 0.7 s, then standing
        assert!(sim.quiet());
        let (merged0, _) = sim.merge_stats();
        sim.advance(5_000);
        assert!(
            sim.merge_stats().0 > merged0 + 150,
            "{:?}",
            sim.merge_stats()
        );
        assert!(sim.noise_behind);
        sim.set_decel_demand(-2.0);
        sim.advance(3_000);
        assert!(!sim.noise_behind && sim.y[ix::V] > 0.5);
        // The noise of the current grid step is the grid schemes' value: the stream drawn
        // once per grid step in turn.
        let mut want = Excitation::new(
            0,
            VehicleParams::default().excitation.noise_std_nm,
            VehicleParams::default().excitation.noise_tau_s,
            NOISE_HOLD_S,
        );
        for _ in 0..sim.steps {
            want.advance();
        }
        assert_eq!(sim.exc.advances(), sim.steps);
        assert_eq!(sim.exc.noise, want.noise);
    }
}
