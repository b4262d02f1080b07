//! The plant firmware-sim drives: anything that integrates a vehicle's steering and longitudinal
//! motion one fixed step at a time. [`ModelPlant`] wraps the project's 5-DOF shimmy model
//! (`shimmy::model`, MODEL.md); tests may substitute a simpler plant with known outputs.
//!
//! Also here: [`LaneKeeping`], the driver's slow steering corrections, which MODEL.md has no input
//! for. They are added kinematically at the steering wheel (see its docs).
//!
//! Not here: sensors, frames or the drive cycle.

use rand_chacha::ChaCha8Rng;
use rand_distr::{Distribution, StandardNormal};

/// One fixed-step vehicle simulation.
pub trait Plant {
    /// Simulated time (s).
    fn t_s(&self) -> f64;
    /// Advance one step. Must not allocate.
    fn step(&mut self);
    /// Advance `n` steps with the inputs held; afterwards `accel_mps2` is the mean over them.
    /// The same as `n` calls of [`Plant::step`] unless the plant has a faster way (a model
    /// integrator that merges steps). Must not allocate.
    fn advance(&mut self, n: u64) {
        for _ in 0..n {
            self.step();
        }
    }
    /// Longitudinal demand for the next steps (m/s², + = decelerating). The plant fades braking
    /// demand by `min(1, v/v_stop)` (MODEL.md §6) so the car stops rather than reverses.
    fn set_decel_demand(&mut self, a_mps2: f64);
    /// Set the joint clearances (m) from now on, for wear growth (MODEL.md §4). A plant
    /// without joints ignores it. Errors (changing nothing) on a value the plant cannot use.
    /// Must not allocate.
    fn set_clearance_m(&mut self, left_m: f64, right_m: f64) -> anyhow::Result<()>;
    /// The wheel-unbalance phases φ_L, φ_R (rad, MODEL.md §7); `None` for a plant without
    /// them.
    fn unbalance_phases(&self) -> Option<[f64; 2]> {
        None
    }
    /// Set the unbalance phases from now on (the wheels rolled different distances, e.g. in a
    /// turn). A plant without them ignores it. Must not allocate.
    fn set_unbalance_phases(&mut self, _phases: [f64; 2]) {}
    /// Whether the plant has a steering wheel that the driver's hands can hold (the MODEL.md
    /// §15 column); false by default.
    fn has_rim(&self) -> bool {
        false
    }
    /// Put the driver's hands `h` on the rim from now on (§15 eq. 6). A plant without a rim
    /// ignores it. Errors (changing nothing) on a value the plant cannot use. Must not
    /// allocate.
    fn set_hands(&mut self, _h: &shimmy::model::Hands) -> anyhow::Result<()> {
        Ok(())
    }
    /// Scales the road noise (MODEL.md §7) to `scale` times the scenario's level from now on: a
    /// stretch of rougher or smoother road. Nothing for a plant without road noise.
    fn set_road_noise_scale(&mut self, _scale: f64) {}
    /// Whether each joint (left, right) is in contact at the current step boundary (MODEL.md
    /// §4); `[false; 2]` for a plant without joints.
    fn in_contact(&self) -> [bool; 2] {
        [false; 2]
    }
    /// Vehicle speed (m/s).
    fn speed_mps(&self) -> f64;
    /// Longitudinal acceleration of the body (m/s², + = speeding up).
    fn accel_mps2(&self) -> f64;
    /// Steering-wheel (pinion) angle δ_sw (rad), MODEL.md §8.
    fn steering_wheel_rad(&self) -> f64;
    /// Column torque T_c (N·m) of MODEL.md §15: the torque the column puts on the rim (the
    /// torsion bar reads −T_c as the driver's torque). 0 for a plant without the column: the
    /// 5-DOF model lumps the rim and the driver's hands into the rack restraint k_g and has no
    /// torsion bar to measure. Must not allocate.
    fn column_torque_nm(&self) -> f64 {
        0.0
    }
    /// Whether the plant has the §15 column's torsion bar (its torque is measured).
    fn has_torsion_bar(&self) -> bool {
        false
    }
    /// Overall steering ratio i_s (steering-wheel angle per road-wheel angle, MODEL.md §8), for
    /// the kinematic yaw rate. Default: MODEL.md §9's vehicle.
    fn steering_ratio(&self) -> f64 {
        steering_ratio(&shimmy::model::VehicleParams::default())
    }
    /// Wheelbase L (m). Default: MODEL.md §9's vehicle.
    fn wheelbase_m(&self) -> f64 {
        shimmy::model::VehicleParams::default().vehicle.wheelbase_m
    }
}

/// MODEL.md §8's overall steering ratio i_s = l·sin α / r_p of a vehicle.
pub fn steering_ratio(p: &shimmy::model::VehicleParams) -> f64 {
    let s = &p.steering;
    s.arm_length_m * s.trapezoid_angle_deg.to_radians().sin() / s.rack_travel_per_pinion_rad_m
}

/// The driver's lane-keeping steering input at the steering wheel: white noise through two
/// first-order lags of time constant `tau/2` each, scaled to the requested RMS, plus a constant
/// offset. Its spectrum falls as f⁻⁴ above ~1/(π·tau), so at the 3–25 Hz shimmy band it is
/// several orders of magnitude below the shimmy signal (MODEL.md §11 removes it).
///
/// It is added to the model's δ_sw rather than fed into the model: MODEL.md has no driver input,
/// and at these frequencies (< 0.5 Hz) the steering system follows the wheel quasi-statically.
#[derive(Clone, Debug)]
pub struct LaneKeeping {
    a: f64,
    drive: f64,
    x1: f64,
    x2: f64,
    scale_rad: f64,
    offset_rad: f64,
}

impl LaneKeeping {
    /// `dt_s` is the update interval, `rms_deg` the RMS of the varying part.
    pub fn new(rms_deg: f64, tau_s: f64, offset_deg: f64, dt_s: f64) -> LaneKeeping {
        let tau1 = 0.5 * tau_s;
        let a = (-dt_s / tau1).exp();
        LaneKeeping {
            a,
            // Stage 1 is an exact-discretised OU process with unit variance.
            drive: (1.0 - a * a).sqrt(),
            x1: 0.0,
            x2: 0.0,
            // Two equal first-order stages halve the variance of the first (σ² → σ²/2).
            scale_rad: rms_deg.to_radians() * std::f64::consts::SQRT_2,
            offset_rad: offset_deg.to_radians(),
        }
    }

    /// Advance one interval; returns the steering-wheel angle to add (rad).
    pub fn step(&mut self, rng: &mut ChaCha8Rng) -> f64 {
        let w: f64 = StandardNormal.sample(rng);
        let x1_prev = self.x1;
        self.x1 = self.a * self.x1 + self.drive * w;
        self.x2 = self.a * self.x2 + (1.0 - self.a) * x1_prev;
        self.offset_rad + self.scale_rad * self.x2
    }

    /// Start from a random point of the stationary distribution (by running the filters for
    /// ten time constants) so short runs are not biased towards zero.
    pub fn warm_up(&mut self, rng: &mut ChaCha8Rng) {
        let n = (10.0 / (1.0 - self.a)).ceil().min(1e6) as usize;
        for _ in 0..n {
            self.step(rng);
        }
    }
}

/// A plant without steering dynamics, for testing the sensor and ground-truth pipeline against
/// known values: a point mass that follows the demand exactly (with the MODEL.md §6 fade near
/// standstill), whose
/// steering wheel oscillates as `amplitude·sin(2π·f·t)` throughout.
#[derive(Clone, Debug)]
pub struct PointMass {
    t: f64,
    h: f64,
    n: u64,
    v: f64,
    a_dem: f64,
    accel: f64,
    pub shimmy_amplitude_rad: f64,
    pub shimmy_hz: f64,
    steer: f64,
}

impl PointMass {
    pub fn new(v0_mps: f64, h_s: f64, shimmy_amplitude_rad: f64, shimmy_hz: f64) -> PointMass {
        PointMass {
            t: 0.0,
            h: h_s,
            n: 0,
            v: v0_mps,
            a_dem: 0.0,
            accel: 0.0,
            shimmy_amplitude_rad,
            shimmy_hz,
            steer: 0.0,
        }
    }
}

impl Plant for PointMass {
    fn t_s(&self) -> f64 {
        self.t
    }
    fn step(&mut self) {
        let a = if self.a_dem > 0.0 {
            self.a_dem * (self.v / crate::drive::V_STOP_MPS).min(1.0)
        } else {
            self.a_dem
        };
        let v1 = (self.v - a * self.h).max(0.0);
        self.accel = (v1 - self.v) / self.h;
        self.v = v1;
        self.n += 1;
        self.t = self.n as f64 * self.h;
        self.steer = self.shimmy_amplitude_rad
            * (2.0 * std::f64::consts::PI * self.shimmy_hz * self.t).sin();
    }
    fn advance(&mut self, n: u64) {
        let v0 = self.v;
        for _ in 0..n {
            self.step();
        }
        self.accel = (self.v - v0) / (n.max(1) as f64 * self.h);
    }
    fn set_decel_demand(&mut self, a_mps2: f64) {
        self.a_dem = a_mps2;
    }
    fn set_clearance_m(&mut self, _left_m: f64, _right_m: f64) -> anyhow::Result<()> {
        Ok(())
    }
    fn speed_mps(&self) -> f64 {
        self.v
    }
    fn accel_mps2(&self) -> f64 {
        self.accel
    }
    fn steering_wheel_rad(&self) -> f64 {
        self.steer
    }
}

/// The project's 5-DOF shimmy model (`shimmy::model::Simulator`, MODEL.md) as the plant, with
/// the longitudinal demand as an external input each step (replacing MODEL.md §6's single event
/// law) so whole drive cycles can be run, and a clearance per joint that may change during the
/// run (unequal wear, wear growth: `Simulator::set_clearance`).
///
/// With `mode = "single"` the model's right joint is ideal (MODEL.md §4) and its clearance value
/// unused; the adapter gives it the left value so the model's range check passes.
pub struct ModelPlant {
    sim: shimmy::model::Simulator,
    single: bool,
    v_prev: f64,
    accel: f64,
    steering_ratio: f64,
    wheelbase_m: f64,
    /// The scenario's road-noise level (N·m at v_n), which `set_road_noise_scale` scales.
    road_noise_nm: f64,
}

impl ModelPlant {
    /// Build the model for `sc`, with vehicle parameters from `vehicle` (MODEL.md §9 defaults
    /// when `None`) and the scenario's excitation (§7) written into them.
    pub fn new(
        sc: &crate::scenario::Scenario,
        vehicle: Option<&std::path::Path>,
    ) -> anyhow::Result<ModelPlant> {
        use anyhow::Context;
        use shimmy::model::VehicleParams;
        let p = match vehicle {
            Some(path) => VehicleParams::from_toml_file(path)
                .with_context(|| format!("vehicle file {}", path.display()))?,
            None => VehicleParams::default(),
        };
        ModelPlant::with_params(sc, p)
    }

    /// Build the model for `sc` with the vehicle parameters `p` (e.g. a vehicle profile's
    /// chassis) and the scenario's excitation (§7) written into them.
    pub fn with_params(
        sc: &crate::scenario::Scenario,
        mut p: shimmy::model::VehicleParams,
    ) -> anyhow::Result<ModelPlant> {
        use anyhow::Context;
        use shimmy::model::{JointMode, Scenario as ModelScenario, Simulator};
        p.excitation.unbalance_kgm = sc.excitation.unbalance_kgm;
        p.excitation.noise_std_nm = sc.excitation.road_noise_nm;
        sc.validate()?;
        let c = &sc.clearance;
        let single = c.mode == crate::scenario::ClearanceMode::Single;
        let (left_mm, right_mm) = c.at_distance_mm(0.0);
        let msc = ModelScenario {
            clearance_m: left_mm * 1e-3,
            clearance_right_m: (!single && right_mm != left_mm).then_some(right_mm * 1e-3),
            joints: match c.mode {
                crate::scenario::ClearanceMode::Dual => JointMode::Dual,
                crate::scenario::ClearanceMode::Single => JointMode::Single,
            },
            seed: sc.seed,
            v0_mps: sc.drive.start_speed_kmh / 3.6,
            duration_s: crate::sim::estimate_duration_s(sc).clamp(1.0, 3600.0),
            h_s: sc.step_s,
            unbalance: sc.excitation.unbalance_kgm > 0.0,
            noise: sc.excitation.road_noise_nm > 0.0,
            integrator: sc.integrator,
            ..ModelScenario::default()
        };
        let sim = Simulator::new(&p, &msc).context("cannot set up the shimmy model")?;
        let v = sim.state()[shimmy::model::rhs::ix::V];
        Ok(ModelPlant {
            sim,
            single,
            v_prev: v,
            accel: 0.0,
            steering_ratio: steering_ratio(&p),
            wheelbase_m: p.vehicle.wheelbase_m,
            road_noise_nm: sc.excitation.road_noise_nm,
        })
    }

    /// The clearances (left, right) the model is using now (m).
    pub fn clearance_m(&self) -> [f64; 2] {
        self.sim.clearance_m()
    }
}

impl Plant for ModelPlant {
    fn t_s(&self) -> f64 {
        self.sim.t()
    }
    fn step(&mut self) {
        self.advance(1);
    }
    fn advance(&mut self, n: u64) {
        // n grid steps; `Integrator::Rk4Adaptive` may merge free-flight steps among them.
        self.sim.advance(n);
        let v = self.speed_mps();
        self.accel = (v - self.v_prev) / (n.max(1) as f64 * self.sim.h());
        self.v_prev = v;
    }
    fn set_decel_demand(&mut self, a_mps2: f64) {
        self.sim.set_decel_demand(a_mps2);
    }
    fn set_clearance_m(&mut self, left_m: f64, right_m: f64) -> anyhow::Result<()> {
        let right_m = if self.single { left_m } else { right_m };
        Ok(self.sim.set_clearance(left_m, right_m)?)
    }
    fn in_contact(&self) -> [bool; 2] {
        self.sim.in_contact()
    }
    fn unbalance_phases(&self) -> Option<[f64; 2]> {
        Some(self.sim.unbalance_phases())
    }
    fn set_unbalance_phases(&mut self, phases: [f64; 2]) {
        self.sim.set_unbalance_phases(phases);
    }
    fn has_rim(&self) -> bool {
        self.sim.model().column
    }
    fn set_hands(&mut self, h: &shimmy::model::Hands) -> anyhow::Result<()> {
        Ok(self.sim.set_hands(h)?)
    }
    fn set_road_noise_scale(&mut self, scale: f64) {
        self.sim.set_road_noise_std(self.road_noise_nm * scale);
    }
    fn speed_mps(&self) -> f64 {
        self.sim.state()[shimmy::model::rhs::ix::V]
    }
    fn accel_mps2(&self) -> f64 {
        self.accel
    }
    fn steering_wheel_rad(&self) -> f64 {
        self.sim.model().delta_sw(self.sim.state())
    }
    /// T_c = k_c·(X/r_p − δ_sw) + c_tb·(X'/r_p − δ_sw') (MODEL.md §15) from the state, when the
    /// vehicle's column is enabled; 0 otherwise.
    fn column_torque_nm(&self) -> f64 {
        -self.sim.model().driver_torque_nm(self.sim.state())
    }
    fn has_torsion_bar(&self) -> bool {
        self.sim.model().column
    }
    fn steering_ratio(&self) -> f64 {
        self.steering_ratio
    }
    fn wheelbase_m(&self) -> f64 {
        self.wheelbase_m
    }
}
