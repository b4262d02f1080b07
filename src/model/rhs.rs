//! Right-hand side of the shimmy model: equations (1)–(5) of MODEL.md §3 with the joint forces
//! of §4, the tire forces and moments of §5, the braking/pitch states of §6, the excitation of
//! §7, and optionally the steering-column coordinate of §15.
//!
//! What it is: `Model::eval(t, y, ctx) -> ẏ` plus the auxiliary forces, on fixed-size arrays
//! (no allocation). What it is not: the integrator or the step-boundary bookkeeping of contact
//! flags, impact velocities and noise (`integrate`, `sim`).

use super::braking::{front_wheel_force, pitch_accel, Demand};
use super::geometry::{cross, Trapezoid};
use super::joint::{hertz_k, ClearanceJoint, IdealJoint, JointForce};
use super::params::{Hands, VehicleParams};
use super::tire::{MfTables, PureSlip};

/// Number of states: the 16 of MODEL.md §1 plus the two of the §15 column option (held at zero
/// when the option is off).
pub const N: usize = 18;
/// The state vector.
pub type State = [f64; N];

/// State indices (MODEL.md §1, §15).
pub mod ix {
    pub const TH1: usize = 0;
    pub const TH2: usize = 1;
    pub const TH3: usize = 2;
    pub const X: usize = 3;
    pub const TH4: usize = 4;
    pub const TH1D: usize = 5;
    pub const TH2D: usize = 6;
    pub const TH3D: usize = 7;
    pub const XD: usize = 8;
    pub const TH4D: usize = 9;
    /// Transient slips α_L, α_R (§5.2).
    pub const AL: usize = 10;
    pub const AR: usize = 11;
    /// Vehicle speed v and wheel spin angle φ_w (§6).
    pub const V: usize = 12;
    pub const PHI: usize = 13;
    /// Filtered deceleration a_f and its rate (§6).
    pub const AF: usize = 14;
    pub const AFD: usize = 15;
    /// §15 option: steering-wheel angle and rate.
    pub const SW: usize = 16;
    pub const SWD: usize = 17;
}

/// Which joints have clearance (MODEL.md §4).
#[derive(Debug, Clone, Copy, PartialEq, Eq, serde::Serialize, serde::Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum JointMode {
    /// Both joints with clearance c (the paper's dual case).
    Dual,
    /// Left joint with clearance, right joint ideal (`--single`).
    Single,
    /// Both joints ideal (penalty bushings); used for checks.
    Ideal,
}

/// Model switches used by checks (energy conservation, symmetry). All true in normal runs.
#[derive(Debug, Clone, Copy, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct Switches {
    /// Tire forces and moments (§5).
    pub tires: bool,
    /// Clearance-joint contact forces (§4); false leaves pins and bushings unconnected.
    pub contact: bool,
}

impl Default for Switches {
    fn default() -> Self {
        Self {
            tires: true,
            contact: true,
        }
    }
}

/// Values held constant over one integration step (MODEL.md §4, §7, §10).
#[derive(Debug, Clone, Copy)]
pub struct StepCtx {
    /// Held impact velocities δ'⁻ (None while the contact flag is not set).
    pub v_imp: [Option<f64>; 2],
    /// Road-noise moments n_L, n_R at v_n (§7).
    pub noise: [f64; 2],
    /// Longitudinal demand law (§6 or external).
    pub demand: Demand,
    /// Slip-inversion start values (used when `warm_slip`), unit slip.
    pub kappa_guess: [f64; 2],
    /// Warm-start the braking-slip Newton iteration and stop at convergence (faster
    /// integrator); false is MODEL.md §5.3's 8 cold Newton steps.
    pub warm_slip: bool,
    /// Evaluate the Magic Formula through these tables (relative error < 1e-8, see
    /// [`MfTables`]) instead of libm; implies the warm-started slip inversion. None is
    /// MODEL.md §5.3 as written.
    pub mf_table: Option<&'static MfTables>,
}

/// Forces and other by-products of one right-hand-side evaluation.
#[derive(Debug, Clone, Copy, Default)]
pub struct Aux {
    /// Joint forces on the pins, L and R.
    pub joint: [JointForce; 2],
    /// Tire forces per wheel: F_x (braking > 0), F_y, M_z, F_z.
    pub fx: [f64; 2],
    pub fy: [f64; 2],
    pub mz: [f64; 2],
    pub fz: [f64; 2],
    /// Braking slips κ.
    pub kappa: [f64; 2],
    /// Demanded deceleration.
    pub a_dem: f64,
    /// Column torque T_c (§15; 0 when the option is off).
    pub column_torque: f64,
}

/// Sines and cosines (sin, cos) of the angles of one state: θ1, θ2 (geometry §2 and the tire
/// terms of §3/§5.4), θ4 (§2) and the unbalance angles φ_w + φ_L, φ_w + φ_R (§7). Computed
/// once per state and shared, or shifted from a nearby state by angle addition.
#[derive(Debug, Clone, Copy, Default)]
pub struct Trig {
    pub th: [(f64, f64); 2],
    pub th4: (f64, f64),
    pub ph: [(f64, f64); 2],
}

/// sin and cos of a small angle increment d (|d| ≤ 0.05) by their Taylor series through d⁷
/// and d⁸: truncation below 6e-18, i.e. exact to f64 rounding.
#[inline(always)]
fn small_sin_cos(d: f64) -> (f64, f64) {
    let d2 = d * d;
    let s = d * (1.0 - d2 * (1.0 / 6.0) * (1.0 - d2 * (1.0 / 20.0) * (1.0 - d2 * (1.0 / 42.0))));
    let c = 1.0
        - d2 * 0.5
            * (1.0 - d2 * (1.0 / 12.0) * (1.0 - d2 * (1.0 / 30.0) * (1.0 - d2 * (1.0 / 56.0))));
    (s, c)
}

/// (sin, cos) of a + d from (sin a, cos a): angle addition with [`small_sin_cos`] when
/// |d| ≤ 0.05, libm otherwise.
#[inline(always)]
fn shift_sc((s, c): (f64, f64), a: f64, d: f64) -> (f64, f64) {
    if d.abs() <= 0.05 {
        let (sd, cd) = small_sin_cos(d);
        (s * cd + c * sd, c * cd - s * sd)
    } else {
        (a + d).sin_cos()
    }
}

impl Trig {
    /// All sines and cosines of `y` from libm.
    #[inline(always)]
    pub fn exact(m: &Model, y: &State) -> Self {
        Self {
            th: [y[ix::TH1].sin_cos(), y[ix::TH2].sin_cos()],
            th4: y[ix::TH4].sin_cos(),
            ph: [
                (y[ix::PHI] + m.phases[0]).sin_cos(),
                (y[ix::PHI] + m.phases[1]).sin_cos(),
            ],
        }
    }

    /// The sines and cosines of `y`, given `self` = those of a nearby state `y0` (an
    /// integrator stage): angle addition with the increments, exact to rounding (see
    /// [`small_sin_cos`]), and no libm call while the increments stay below 0.05 rad.
    #[inline(always)]
    pub fn shifted(&self, m: &Model, y0: &State, y: &State) -> Self {
        use ix::*;
        let dphi = y[PHI] - y0[PHI];
        Self {
            th: [
                shift_sc(self.th[0], y0[TH1], y[TH1] - y0[TH1]),
                shift_sc(self.th[1], y0[TH2], y[TH2] - y0[TH2]),
            ],
            th4: shift_sc(self.th4, y0[TH4], y[TH4] - y0[TH4]),
            ph: [
                shift_sc(self.ph[0], y0[PHI] + m.phases[0], dphi),
                shift_sc(self.ph[1], y0[PHI] + m.phases[1], dphi),
            ],
        }
    }
}

/// Tire outputs of both wheels at one state (MODEL.md §5): what a multirate integrator
/// evaluates once per step and extrapolates over the stages.
#[derive(Debug, Clone, Copy, Default, PartialEq)]
pub struct TireOut {
    /// F_x (braking > 0), F_y, M_z.
    pub fx: [f64; 2],
    pub fy: [f64; 2],
    pub mz: [f64; 2],
    /// Relaxation length σ = C_Fα(F_z)/k_ty (§5.2).
    pub sigma: [f64; 2],
    /// Braking slip κ (§5.3).
    pub kappa: [f64; 2],
}

impl TireOut {
    /// Σ w_j·f_j (Lagrange extrapolation through earlier values; κ from the first).
    #[inline(always)]
    pub fn combine(f: &[TireOut; 3], w: [f64; 3]) -> TireOut {
        let c = |g: fn(&TireOut) -> [f64; 2]| {
            let (a, b, d) = (g(&f[0]), g(&f[1]), g(&f[2]));
            [
                w[0] * a[0] + w[1] * b[0] + w[2] * d[0],
                w[0] * a[1] + w[1] * b[1] + w[2] * d[1],
            ]
        };
        TireOut {
            fx: c(|t| t.fx),
            fy: c(|t| t.fy),
            mz: c(|t| t.mz),
            sigma: c(|t| t.sigma),
            kappa: f[0].kappa,
        }
    }

    /// `self + c·(self − prev)`: linear extrapolation by `c` steps from two step-start values.
    #[inline(always)]
    pub fn extrapolate(&self, prev: &TireOut, c: f64) -> TireOut {
        let f = |a: [f64; 2], b: [f64; 2]| [a[0] + c * (a[0] - b[0]), a[1] + c * (a[1] - b[1])];
        TireOut {
            fx: f(self.fx, prev.fx),
            fy: f(self.fy, prev.fy),
            mz: f(self.mz, prev.mz),
            sigma: f(self.sigma, prev.sigma),
            kappa: self.kappa,
        }
    }
}

/// One clearance joint of radial clearance `clearance_m` with the §9 joint constants.
pub fn clearance_joint(p: &VehicleParams, clearance_m: f64) -> ClearanceJoint {
    let j = &p.joint;
    ClearanceJoint {
        c: clearance_m,
        r_p: j.pin_radius_m,
        r_b: j.pin_radius_m + clearance_m,
        k: hertz_k(
            j.young_modulus_pa,
            j.poisson_ratio,
            j.pin_radius_m,
            clearance_m,
        ),
        ln_factor: 0.75 * (1.0 - j.restitution * j.restitution),
        mu: j.friction,
        v_eps: j.friction_reg_velocity_mps,
        c_tan: j.tangential_damping_ns_per_m,
        v_imp_min: j.min_impact_velocity_mps,
    }
}

/// Constants of the model for one vehicle and one scenario (derived from §9).
#[derive(Debug, Clone)]
pub struct Model {
    pub geo: Trapezoid,
    /// The two clearance joints, left (0) and right (1); each has its own clearance c.
    pub joint: [ClearanceJoint; 2],
    pub ideal: IdealJoint,
    pub mode: JointMode,
    pub sw: Switches,
    // Eq. (1)–(2)
    pub i_w: f64,
    pub c_s: f64,
    pub k_s: f64,
    pub j_p: f64,
    // Eq. (3)
    pub i_f: f64,
    pub c_roll: f64,
    pub k_roll: f64,
    pub r_w: f64,
    // Eq. (4)–(5)
    pub m_t: f64,
    pub k_eq: f64,
    pub k_g: f64,
    pub c_g: f64,
    pub i_t: f64,
    pub c_th4: f64,
    pub r_p: f64,
    // Tires (§5)
    pub fz0: f64,
    pub load_transfer_per_mps2: f64,
    pub k_tz_half_track: f64,
    pub k_ty: f64,
    pub mu: f64,
    pub trail: f64,
    pub scrub: f64,
    pub spindle: f64,
    pub fz_floor: f64,
    // §6, §7
    pub mass: f64,
    pub front_share: f64,
    pub v_stop: f64,
    pub omega_p: f64,
    pub zeta_p: f64,
    pub unbalance: f64,
    pub phases: [f64; 2],
    /// Brake-torque variation per wheel: (ε_i, cos(δ_i − φ_i), sin(δ_i − φ_i)) (params
    /// `braking.torque_variation_*`, φ_i the unbalance phase; ε = 0 leaves the brake force as
    /// §6 has it).
    pub torque_variation: [(f64, f64, f64); 2],
    pub noise_ref_speed: f64,
    // §15
    pub column: bool,
    pub j_sw: f64,
    pub k_c: f64,
    pub c_tb: f64,
    pub k_h: f64,
    pub c_h: f64,
    /// The driver's hands on the rim (added to J_sw and k_h in eq. 6) and the sums eq. (6)
    /// uses: J_sw + J_hands and k_h + k_hands (with no hands, exactly J_sw and k_h).
    pub j_hands: f64,
    pub k_hands: f64,
    pub j_rim: f64,
    pub k_rim: f64,
}

impl Model {
    /// Builds the constants. `clearance_m` is c (§4); `phases` the unbalance phases (§7).
    pub fn new(
        p: &VehicleParams,
        clearance_m: f64,
        mode: JointMode,
        sw: Switches,
        unbalance_kgm: f64,
        phases: [f64; 2],
    ) -> Self {
        let s = &p.steering;
        let geo = Trapezoid::new(
            s.kingpin_half_spacing_m,
            s.arm_length_m,
            s.trapezoid_angle_deg.to_radians(),
        );
        let j = &p.joint;
        let joint = [clearance_joint(p, clearance_m); 2];
        let (k_t, k_g) = (s.tie_rod_stiffness_n_per_m, s.restraint_stiffness_n_per_m);
        let v = &p.vehicle;
        let a = &p.axle;
        let r_p = s.rack_travel_per_pinion_rad_m;
        let c = &p.column;
        let k_tb = c.torsion_bar_nm_per_rad;
        let k_h = 1.0 / (1.0 / (k_g * r_p * r_p) - 1.0 / k_tb);
        let mut m = Self {
            geo,
            joint,
            ideal: IdealJoint {
                k: j.ideal_stiffness_n_per_m,
                c: j.ideal_damping_ns_per_m,
            },
            mode,
            sw,
            i_w: s.kingpin_inertia_kgm2,
            c_s: s.kingpin_damping_nms_per_rad,
            k_s: s.kingpin_stiffness_nm_per_rad,
            j_p: a.wheel_spin_inertia_kgm2,
            i_f: a.roll_inertia_kgm2,
            c_roll: a.roll_damping_nms_per_rad,
            k_roll: a.roll_stiffness_nm_per_rad,
            r_w: a.wheel_radius_m,
            m_t: s.tie_rod_mass_kg,
            k_eq: k_t * k_g / (k_t + k_g),
            k_g,
            c_g: s.restraint_damping_ns_per_m,
            i_t: s.tie_rod_mass_kg * geo.l_t * geo.l_t / 12.0,
            c_th4: s.tie_rod_yaw_damping_nms_per_rad,
            r_p,
            fz0: v.mass_kg * v.gravity_mps2 * v.cg_to_rear_axle_m / (2.0 * v.wheelbase_m),
            load_transfer_per_mps2: v.mass_kg * v.cg_height_m / v.wheelbase_m,
            k_tz_half_track: p.tire.vertical_stiffness_n_per_m * a.track_m * 0.5,
            k_ty: p.tire.lateral_stiffness_n_per_m,
            mu: p.tire.friction_scale,
            trail: s.caster_trail_m,
            scrub: s.scrub_radius_m,
            spindle: s.spindle_offset_m,
            fz_floor: 200.0,
            mass: v.mass_kg,
            front_share: p.braking.front_share,
            v_stop: p.braking.v_stop_mps,
            omega_p: std::f64::consts::TAU * p.braking.pitch_freq_hz,
            zeta_p: p.braking.pitch_damping_ratio,
            unbalance: unbalance_kgm,
            phases,
            // cos(φ_w + δ_i) = cos((φ_w + φ_i) + (δ_i − φ_i)): the shift from the unbalance
            // angle the step already has.
            torque_variation: [0, 1].map(|i| {
                let d = p.braking.torque_variation_phase_deg[i].to_radians() - phases[i];
                let (sd, cd) = d.sin_cos();
                (p.braking.torque_variation_rel[i], cd, sd)
            }),
            noise_ref_speed: p.excitation.noise_ref_speed_mps,
            column: c.enabled,
            j_sw: c.inertia_kgm2,
            k_c: 1.0 / (1.0 / k_tb + 1.0 / (k_t * r_p * r_p)),
            c_tb: c.torsion_bar_damping_nms_per_rad,
            k_h,
            c_h: c.hands_damping_nms_per_rad,
            j_hands: 0.0,
            k_hands: 0.0,
            j_rim: c.inertia_kgm2,
            k_rim: k_h,
        };
        m.set_hands(&c.hands());
        m
    }

    /// Puts the driver's hands `h` on the rim (§15 eq. 6): J_sw + J_hands, k_h + k_hands, c_h.
    /// With zero hands inertia and stiffness the sums are exactly J_sw and k_h.
    pub fn set_hands(&mut self, h: &Hands) {
        self.j_hands = h.inertia_kgm2;
        self.k_hands = h.stiffness_nm_per_rad;
        self.c_h = h.damping_nms_per_rad;
        self.j_rim = self.j_sw + self.j_hands;
        self.k_rim = self.k_h + self.k_hands;
    }

    /// The hands on the rim.
    pub fn hands(&self) -> Hands {
        Hands {
            inertia_kgm2: self.j_hands,
            stiffness_nm_per_rad: self.k_hands,
            damping_nms_per_rad: self.c_h,
        }
    }

    /// Sets the radial clearances c_L, c_R of the two joints (§4), e.g. for unequal wear or
    /// clearance growing with distance. The Hertz stiffness K depends on c and is recomputed.
    /// In the single-clearance variant the right joint stays ideal whatever `right_m` says.
    pub fn set_clearance(&mut self, p: &VehicleParams, left_m: f64, right_m: f64) {
        self.joint = [clearance_joint(p, left_m), clearance_joint(p, right_m)];
    }

    /// Steering-wheel angle seen by the sensor (rad): §8 kinematic pinion angle, or the §15
    /// rim angle when the column option is on.
    #[inline]
    /// The driver's torque at the EPS torsion bar (N·m, + turning left, as a bus reports it):
    /// −T_c of §15, T_c = k_c·(X/r_p − δ_sw) + c_tb·(X'/r_p − δ_sw'); 0 without the column.
    pub fn driver_torque_nm(&self, y: &State) -> f64 {
        if !self.column {
            return 0.0;
        }
        -(self.k_c * (y[ix::X] / self.r_p - y[ix::SW])
            + self.c_tb * (y[ix::XD] / self.r_p - y[ix::SWD]))
    }

    pub fn delta_sw(&self, y: &State) -> f64 {
        if self.column {
            y[ix::SW]
        } else {
            super::sensor::steering_wheel_angle_rad(y[ix::X], self.k_eq, self.k_g, self.r_p)
        }
    }

    /// Whether joint `i` (0 = L, 1 = R) is a clearance joint in this variant (§4).
    #[inline(always)]
    pub fn has_clearance(&self, i: usize) -> bool {
        match self.mode {
            JointMode::Dual => true,
            JointMode::Single => i == 0,
            JointMode::Ideal => false,
        }
    }

    /// Joint forces at one state (§4).
    #[inline(always)]
    pub fn joints(&self, y: &State, ctx: &StepCtx) -> [JointForce; 2] {
        self.joints_trig(y, &Trig::exact(self, y), ctx)
    }

    /// [`Self::joints`] with the sines and cosines of `y` given.
    #[inline(always)]
    pub fn joints_trig(&self, y: &State, tr: &Trig, ctx: &StepCtx) -> [JointForce; 2] {
        use ix::*;
        let pts = self.geo.points_sc(
            tr.th[0], tr.th[1], tr.th4, y[X], y[TH1D], y[TH2D], y[XD], y[TH4D],
        );
        let rates = [y[TH1D], y[TH2D]];
        let mut out = [JointForce::default(); 2];
        for i in 0..2 {
            let ideal = match self.mode {
                JointMode::Dual => false,
                JointMode::Single => i == 1,
                JointMode::Ideal => true,
            };
            out[i] = if ideal {
                self.ideal
                    .force(pts.p[i], pts.p_dot[i], pts.b[i], pts.b_dot[i])
            } else {
                let f = self.joint[i].force(
                    pts.p[i],
                    pts.p_dot[i],
                    pts.b[i],
                    pts.b_dot[i],
                    rates[i],
                    y[TH4D],
                    ctx.v_imp[i],
                );
                if self.sw.contact {
                    f
                } else {
                    JointForce {
                        f: [0.0, 0.0],
                        f_n: 0.0,
                        ..f
                    }
                }
            };
        }
        out
    }

    /// Penetration δ and rate δ' of the clearance joints (for the step-boundary flags, §10).
    /// Ideal joints report (−∞, 0).
    pub fn penetrations(&self, y: &State) -> [(f64, f64); 2] {
        self.penetrations_trig(y, &Trig::exact(self, y))
    }

    /// [`Self::penetrations`] with the sines and cosines of `y` given.
    pub fn penetrations_trig(&self, y: &State, tr: &Trig) -> [(f64, f64); 2] {
        use ix::*;
        let pts = self.geo.points_sc(
            tr.th[0], tr.th[1], tr.th4, y[X], y[TH1D], y[TH2D], y[XD], y[TH4D],
        );
        let mut out = [(f64::NEG_INFINITY, 0.0); 2];
        for (i, o) in out.iter_mut().enumerate() {
            let ideal = match self.mode {
                JointMode::Dual => false,
                JointMode::Single => i == 1,
                JointMode::Ideal => true,
            };
            if !ideal {
                *o = self.joint[i].penetration(pts.p[i], pts.p_dot[i], pts.b[i], pts.b_dot[i]);
            }
        }
        out
    }

    /// ẏ = f(t, y) (MODEL.md §3–§7, §15), writing the by-products into `aux`.
    #[inline(always)]
    pub fn eval(&self, t: f64, y: &State, ctx: &StepCtx, dy: &mut State, aux: &mut Aux) {
        self.eval_with(t, y, ctx, &Trig::exact(self, y), None, dy, aux);
    }

    /// Wheel `i`'s brake force: §6's `f_long` while braking, times 1 + ε_i·cos(φ_w + δ_i)
    /// with a brake-torque variation (`ph` = (sin, cos) of φ_w + φ_i, [`Trig`]). Exactly
    /// `f_long` without one or while driving.
    #[inline(always)]
    fn brake_force(&self, i: usize, f_long: f64, a_dem: f64, (s_ph, c_ph): (f64, f64)) -> f64 {
        let (eps, cd, sd) = self.torque_variation[i];
        if eps == 0.0 || a_dem <= 0.0 {
            f_long
        } else {
            f_long * (1.0 + eps * (c_ph * cd - s_ph * sd))
        }
    }

    /// Vertical load F_z of wheel `i` (§5.1: static share, braking transfer through the
    /// filtered deceleration, roll, unbalance), floored at `fz_floor`.
    #[inline(always)]
    fn wheel_load(&self, i: usize, y: &State, s_ph: f64, u_om2: f64) -> f64 {
        let side = if i == 0 { -1.0 } else { 1.0 };
        let dfz_half = 0.5 * self.load_transfer_per_mps2 * y[ix::AF];
        (self.fz0 + dfz_half + side * self.k_tz_half_track * y[ix::TH3] + u_om2 * s_ph)
            .max(self.fz_floor)
    }

    /// Tire forces of one wheel (§5.3) at load `fz`, transient slip `alpha_t` and
    /// longitudinal force demand `f_long`: (F_x, F_y, M_z, σ, κ). With `warm`, the slip
    /// Newton iteration starts from `kappa_guess` and stops at convergence; otherwise it is
    /// MODEL.md's 8 cold steps.
    #[inline(always)]
    fn tire_forces(
        &self,
        fz: f64,
        alpha_t: f64,
        f_long: f64,
        kappa_guess: f64,
        warm: bool,
        table: Option<&MfTables>,
    ) -> (f64, f64, f64, f64, f64) {
        if let Some(tab) = table {
            let tire = PureSlip::at_load_tab(fz, self.mu, tab);
            let kappa = tire.invert_fx_tab(f_long, kappa_guess, 1e-10, tab);
            let (fx, fy, mz) = tire.combined_tab(kappa, alpha_t, tab);
            let sigma = tire.cornering_stiffness() / self.k_ty;
            return (fx, fy, mz, sigma, kappa);
        }
        let tire = PureSlip::at_load(fz, self.mu);
        let kappa = if warm {
            tire.invert_fx(f_long, Some(kappa_guess), 8, 1e-10)
        } else {
            tire.invert_fx(f_long, None, 8, 0.0)
        };
        let (fx, fy, mz) = tire.combined(kappa, alpha_t);
        let sigma = tire.cornering_stiffness() / self.k_ty;
        (fx, fy, mz, sigma, kappa)
    }

    /// The exact tire outputs of both wheels at (t, y) (warm-started slip inversion from
    /// `ctx.kappa_guess`), for integrators that hold them over a step.
    #[inline(always)]
    pub fn tires(&self, t: f64, y: &State, tr: &Trig, ctx: &StepCtx) -> TireOut {
        let v = y[ix::V];
        let omega = v / self.r_w;
        let a_dem = ctx.demand.a_dem(t, v, self.v_stop);
        let f_long = front_wheel_force(a_dem, self.mass, self.front_share);
        let u_om2 = self.unbalance * omega * omega;
        let mut out = TireOut::default();
        for i in 0..2 {
            let fz = self.wheel_load(i, y, tr.ph[i].0, u_om2);
            let (fx, fy, mz, sigma, kappa) = self.tire_forces(
                fz,
                y[ix::AL + i],
                self.brake_force(i, f_long, a_dem, tr.ph[i]),
                ctx.kappa_guess[i],
                true,
                ctx.mf_table,
            );
            out.fx[i] = fx;
            out.fy[i] = fy;
            out.mz[i] = mz;
            out.sigma[i] = sigma;
            out.kappa[i] = kappa;
        }
        out
    }

    /// [`Self::eval`] with the sines and cosines of `y` given, and optionally the tire outputs
    /// given (`held`, e.g. extrapolated over the stages of a step) instead of evaluated here.
    #[inline(always)]
    #[allow(clippy::too_many_arguments)]
    pub fn eval_with(
        &self,
        t: f64,
        y: &State,
        ctx: &StepCtx,
        tr: &Trig,
        held: Option<&TireOut>,
        dy: &mut State,
        aux: &mut Aux,
    ) {
        use ix::*;
        let v = y[V];
        let omega = v / self.r_w; // Ω = v/R_w (§1)
        let th = [y[TH1], y[TH2]];
        let thd = [y[TH1D], y[TH2D]];

        // §6: demand, speed, wheel spin, pitch filter.
        let a_dem = ctx.demand.a_dem(t, v, self.v_stop);
        aux.a_dem = a_dem;
        dy[V] = -a_dem;
        dy[PHI] = omega;
        dy[AF] = y[AFD];
        dy[AFD] = pitch_accel(a_dem, y[AF], y[AFD], self.omega_p, self.zeta_p);

        // §4: joint forces and moments.
        let jf = self.joints_trig(y, tr, ctx);
        aux.joint = jf;
        let g = self.geo.centre(y[X]);
        let mut m_joint = [0.0; 2];
        let mut m_rod = 0.0;
        for i in 0..2 {
            let o = self.geo.kingpin(i);
            let f = jf[i].f;
            m_joint[i] = cross([jf[i].q_p[0] - o[0], jf[i].q_p[1] - o[1]], f);
            m_rod += cross([jf[i].q_b[0] - g[0], jf[i].q_b[1] - g[1]], [-f[0], -f[1]]);
        }

        // §5, §7: tire and excitation moments about the kingpins, lateral forces for the roll.
        let u_om2 = self.unbalance * omega * omega;
        let f_long = front_wheel_force(a_dem, self.mass, self.front_share);
        let noise_scale = v / self.noise_ref_speed;
        let mut m_tire = [0.0; 2];
        let mut f_lat_sum = 0.0;
        for i in 0..2 {
            let side = if i == 0 { -1.0 } else { 1.0 }; // ∓ in §5.1, ± in §5.4
            let (s_ph, c_ph) = tr.ph[i];
            let fz = self.wheel_load(i, y, s_ph, u_om2);
            aux.fz[i] = fz;
            let (sin_t, cos_t) = tr.th[i];
            let alpha_t = y[AL + i];
            let mut m = side * self.spindle * u_om2 * c_ph + ctx.noise[i] * noise_scale;
            if self.sw.tires {
                let (fx, fy, mz, sigma, kappa) = match held {
                    Some(h) => (h.fx[i], h.fy[i], h.mz[i], h.sigma[i], h.kappa[i]),
                    None => self.tire_forces(
                        fz,
                        alpha_t,
                        self.brake_force(i, f_long, a_dem, (s_ph, c_ph)),
                        ctx.kappa_guess[i],
                        ctx.warm_slip,
                        ctx.mf_table,
                    ),
                };
                aux.kappa[i] = kappa;
                aux.fx[i] = fx;
                aux.fy[i] = fy;
                aux.mz[i] = mz;
                // §5.4: −e·F_y − M_z ± r_s·F_x (+ for L, − for R).
                m += -self.trail * fy - mz - side * self.scrub * fx;
                // §3: F_lat = −F_y cos θ + F_x sin θ.
                f_lat_sum += -fy * cos_t + fx * sin_t;
                // §5.2: σ α' = V_sy − |v| α, σ = C_Fα(F_z)/k_ty.
                let v_sy = v * sin_t + (self.trail * thd[i] - self.r_w * y[TH3D]) * cos_t;
                dy[AL + i] = (v_sy - v.abs() * alpha_t) / sigma;
            } else {
                dy[AL + i] = 0.0;
            }
            m_tire[i] = m;
        }

        // Eq. (1), (2).
        let gyro_w = -self.j_p * omega * y[TH3D];
        for i in 0..2 {
            dy[TH1 + i] = thd[i];
            dy[TH1D + i] =
                (-self.c_s * thd[i] - self.k_s * th[i] + gyro_w + m_tire[i] + m_joint[i])
                    / self.i_w;
        }
        // Eq. (3).
        dy[TH3] = y[TH3D];
        dy[TH3D] = (-self.c_roll * y[TH3D] - self.k_roll * y[TH3]
            + self.j_p * omega * (thd[0] + thd[1])
            - self.r_w * f_lat_sum)
            / self.i_f;
        // Eq. (4) or (4′) of §15.
        let pin_x = -jf[0].f[0] - jf[1].f[0];
        dy[X] = y[XD];
        if self.column {
            let tc = self.k_c * (y[X] / self.r_p - y[SW]) + self.c_tb * (y[XD] / self.r_p - y[SWD]);
            aux.column_torque = tc;
            dy[XD] = (-tc / self.r_p - self.c_g * y[XD] + pin_x) / self.m_t;
            dy[SW] = y[SWD];
            dy[SWD] = (tc - self.k_rim * y[SW] - self.c_h * y[SWD]) / self.j_rim;
        } else {
            aux.column_torque = 0.0;
            dy[XD] = (-self.k_eq * y[X] - self.c_g * y[XD] + pin_x) / self.m_t;
            dy[SW] = 0.0;
            dy[SWD] = 0.0;
        }
        // Eq. (5).
        dy[TH4] = y[TH4D];
        dy[TH4D] = (-self.c_th4 * y[TH4D] + m_rod) / self.i_t;
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn shifted_sines_and_cosines_equal_libm_to_rounding() {
        let p = VehicleParams::default();
        let m = Model::new(
            &p,
            1e-4,
            JointMode::Dual,
            Switches::default(),
            2e-3,
            [0.3, 5.9],
        );
        let mut y0 = [0.0; N];
        let mut worst: f64 = 0.0;
        for k in 0..2000 {
            let a = k as f64 * 0.0137;
            y0[ix::TH1] = 0.3 * a.sin();
            y0[ix::TH2] = -0.2 * a.cos();
            y0[ix::TH4] = 0.01 * (3.0 * a).sin();
            y0[ix::PHI] = a;
            // Increments across the 0.05 rad switch to libm and beyond.
            let d = 0.08 * ((k % 17) as f64 / 16.0 - 0.5) * (1.0 + (k % 3) as f64);
            let mut y = y0;
            y[ix::TH1] += d;
            y[ix::TH2] -= 0.5 * d;
            y[ix::TH4] += 0.1 * d;
            y[ix::PHI] += d;
            let t0 = Trig::exact(&m, &y0);
            let got = t0.shifted(&m, &y0, &y);
            let want = Trig::exact(&m, &y);
            let pairs = [
                (got.th[0], want.th[0]),
                (got.th[1], want.th[1]),
                (got.th4, want.th4),
                (got.ph[0], want.ph[0]),
                (got.ph[1], want.ph[1]),
            ];
            for (g, w) in pairs {
                worst = worst.max((g.0 - w.0).abs()).max((g.1 - w.1).abs());
            }
        }
        // φ reaches 27 rad here: its own rounding (ulp 3.6e-15) bounds the agreement.
        assert!(worst < 1e-14, "largest deviation {worst:e}");
    }
}
