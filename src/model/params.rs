//! Vehicle parameters of the shimmy model (MODEL.md §9, plus the §15 steering-column option).
//!
//! What it is: a serde value loaded from `config/vehicle/*.toml`, whose `Default` is exactly the
//! §9 table, and a `validate` that rejects physically meaningless values with the TOML key in the
//! message. Units are SI except where a field name says otherwise (`trapezoid_angle_deg`).
//!
//! What it is not: the scenario (clearance, speed, deceleration, seed live in
//! [`crate::model::Scenario`]) nor the derived constants the right-hand side uses
//! (see [`crate::model::rhs::Model`]).

use serde::{Deserialize, Serialize};
use std::path::Path;

/// Whole-vehicle data (MODEL.md §9 first rows, §6).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct Vehicle {
    /// m: vehicle mass.
    pub mass_kg: f64,
    /// L: wheelbase.
    pub wheelbase_m: f64,
    /// l_r: CG to rear axle (front static share = l_r / L).
    pub cg_to_rear_axle_m: f64,
    /// h: CG height.
    pub cg_height_m: f64,
    /// g.
    pub gravity_mps2: f64,
}

impl Default for Vehicle {
    fn default() -> Self {
        Self {
            mass_kg: 1350.0,
            wheelbase_m: 2.60,
            cg_to_rear_axle_m: 1.56,
            cg_height_m: 0.55,
            gravity_mps2: 9.81,
        }
    }
}

/// Braking scenario and pitch/load-transfer data (MODEL.md §6).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct Braking {
    /// β_f: front brake share.
    pub front_share: f64,
    /// t_b: brake onset.
    pub onset_s: f64,
    /// t_r: ramp time to full deceleration.
    pub ramp_s: f64,
    /// v_stop: speed below which the deceleration fades to zero.
    pub v_stop_mps: f64,
    /// f_p: body pitch frequency.
    pub pitch_freq_hz: f64,
    /// ζ_p: body pitch damping ratio.
    pub pitch_damping_ratio: f64,
    /// ε_L, ε_R: brake-torque variation at wheel order per front wheel, relative to the brake
    /// force (a disc thickness variation): F_b,i·(1 + ε_i·cos(φ_w + δ_i)) while braking, φ_w
    /// the wheels' spin angle. Not in the 5-DOF spec: MODEL.md §14 names it as the
    /// clearance-independent shake a non-zero scrub radius turns into a steering moment. 0 (the
    /// default) is left out of the serialised form, so vehicle files and hashes written before
    /// it existed stay the same.
    #[serde(skip_serializing_if = "both_zero")]
    pub torque_variation_rel: [f64; 2],
    /// δ_L, δ_R: where each disc's thickest point sits on the wheel (deg). Variations in phase
    /// (equal δ) push the wheels toward toe-in and toe-out together, which the rack does not
    /// feel; 180° apart they steer both wheels one way, which it does.
    #[serde(skip_serializing_if = "both_zero")]
    pub torque_variation_phase_deg: [f64; 2],
}

fn both_zero(x: &[f64; 2]) -> bool {
    x[0] == 0.0 && x[1] == 0.0
}

impl Default for Braking {
    fn default() -> Self {
        Self {
            front_share: 0.70,
            onset_s: 0.5,
            ramp_s: 0.3,
            v_stop_mps: 0.5,
            pitch_freq_hz: 1.5,
            pitch_damping_ratio: 0.5,
            torque_variation_rel: [0.0; 2],
            torque_variation_phase_deg: [0.0; 2],
        }
    }
}

/// Steering trapezoid, knuckles and tie rod (MODEL.md §2, §3, §8).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct Steering {
    /// b: half kingpin spacing.
    pub kingpin_half_spacing_m: f64,
    /// l: trapezoid arm length.
    pub arm_length_m: f64,
    /// α: trapezoid base angle between arm and axle line.
    pub trapezoid_angle_deg: f64,
    /// e: mechanical (caster) trail.
    pub caster_trail_m: f64,
    /// r_s: scrub radius (+ = contact patch outboard of the kingpin).
    pub scrub_radius_m: f64,
    /// d_w: spindle offset (lever of the unbalance).
    pub spindle_offset_m: f64,
    /// I_w: wheel + knuckle inertia about the kingpin.
    pub kingpin_inertia_kgm2: f64,
    /// k_s: kingpin self-centring stiffness.
    pub kingpin_stiffness_nm_per_rad: f64,
    /// c_s: kingpin damping.
    pub kingpin_damping_nms_per_rad: f64,
    /// m_t: tie-rod mass.
    pub tie_rod_mass_kg: f64,
    /// k_t: tie-rod / rack connection stiffness.
    pub tie_rod_stiffness_n_per_m: f64,
    /// k_g: steering gear + column + driver restraint at the rack.
    pub restraint_stiffness_n_per_m: f64,
    /// c_g: EPS / column damping at the rack.
    pub restraint_damping_ns_per_m: f64,
    /// c_θ4: tie-rod yaw damping.
    pub tie_rod_yaw_damping_nms_per_rad: f64,
    /// r_p: rack travel per pinion radian.
    pub rack_travel_per_pinion_rad_m: f64,
}

impl Default for Steering {
    fn default() -> Self {
        Self {
            kingpin_half_spacing_m: 0.66,
            arm_length_m: 0.13,
            trapezoid_angle_deg: 72.0,
            caster_trail_m: 0.025,
            scrub_radius_m: 0.0,
            spindle_offset_m: 0.065,
            kingpin_inertia_kgm2: 1.00,
            kingpin_stiffness_nm_per_rad: 500.0,
            kingpin_damping_nms_per_rad: 30.0,
            tie_rod_mass_kg: 6.5,
            tie_rod_stiffness_n_per_m: 4.0e6,
            restraint_stiffness_n_per_m: 1.0e5,
            restraint_damping_ns_per_m: 6000.0,
            tie_rod_yaw_damping_nms_per_rad: 1.0,
            rack_travel_per_pinion_rad_m: 8e-3,
        }
    }
}

/// Front axle roll (MODEL.md §3 eq. 3) and wheels.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct Axle {
    /// I_f: axle roll inertia.
    pub roll_inertia_kgm2: f64,
    /// k_r: roll stiffness.
    pub roll_stiffness_nm_per_rad: f64,
    /// c_r: roll damping.
    pub roll_damping_nms_per_rad: f64,
    /// T: track.
    pub track_m: f64,
    /// R_w: wheel (rolling) radius.
    pub wheel_radius_m: f64,
    /// J_p: wheel spin inertia.
    pub wheel_spin_inertia_kgm2: f64,
}

impl Default for Axle {
    fn default() -> Self {
        Self {
            roll_inertia_kgm2: 31.0,
            roll_stiffness_nm_per_rad: 2.2e5,
            roll_damping_nms_per_rad: 1565.0,
            track_m: 1.45,
            wheel_radius_m: 0.30,
            wheel_spin_inertia_kgm2: 0.90,
        }
    }
}

/// Tire data beyond the fixed Magic Formula coefficients of MODEL.md §5.3.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct Tire {
    /// k_tz: vertical tire stiffness.
    pub vertical_stiffness_n_per_m: f64,
    /// k_ty: lateral tire stiffness (sets the relaxation length, §5.2).
    pub lateral_stiffness_n_per_m: f64,
    /// μ scale of the Magic Formula peak (1 = dry asphalt, §5.3).
    pub friction_scale: f64,
}

impl Default for Tire {
    fn default() -> Self {
        Self {
            vertical_stiffness_n_per_m: 2.0e5,
            lateral_stiffness_n_per_m: 1.4e5,
            friction_scale: 1.0,
        }
    }
}

/// Clearance joints (MODEL.md §4).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct Joint {
    /// R_p: pin radius (R_b = R_p + c).
    pub pin_radius_m: f64,
    /// E of both bodies.
    pub young_modulus_pa: f64,
    /// ν of both bodies.
    pub poisson_ratio: f64,
    /// c_r: coefficient of restitution (Lankarani–Nikravesh).
    pub restitution: f64,
    /// μ_j: joint friction.
    pub friction: f64,
    /// v_ε: friction regularisation velocity.
    pub friction_reg_velocity_mps: f64,
    /// c_tan: viscous tangential term.
    pub tangential_damping_ns_per_m: f64,
    /// v_imp,min: floor of the impact velocity.
    pub min_impact_velocity_mps: f64,
    /// k_id: ideal-joint penalty stiffness (single-clearance variant).
    pub ideal_stiffness_n_per_m: f64,
    /// c_id: ideal-joint penalty damping.
    pub ideal_damping_ns_per_m: f64,
}

impl Default for Joint {
    fn default() -> Self {
        Self {
            pin_radius_m: 0.010,
            young_modulus_pa: 207e9,
            poisson_ratio: 0.3,
            restitution: 0.8,
            friction: 0.10,
            friction_reg_velocity_mps: 5e-3,
            tangential_damping_ns_per_m: 0.0,
            min_impact_velocity_mps: 0.01,
            ideal_stiffness_n_per_m: 1e8,
            ideal_damping_ns_per_m: 2e3,
        }
    }
}

/// Excitation (MODEL.md §7).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct Excitation {
    /// U: residual unbalance per wheel.
    pub unbalance_kgm: f64,
    /// σ of the Ornstein–Uhlenbeck road-noise steer moment at v_n.
    pub noise_std_nm: f64,
    /// τ of the road noise.
    pub noise_tau_s: f64,
    /// v_n: speed at which the noise has std σ (scaled by v/v_n).
    pub noise_ref_speed_mps: f64,
    /// Initial kick θ1'(0).
    pub kick_rad_per_s: f64,
}

impl Default for Excitation {
    fn default() -> Self {
        Self {
            unbalance_kgm: 2e-3,
            noise_std_nm: 0.2,
            noise_tau_s: 0.01,
            noise_ref_speed_mps: 15.28,
            kick_rad_per_s: 0.02,
        }
    }
}

/// Optional sixth coordinate: steering wheel and column (MODEL.md §15). Off by default.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct Column {
    /// Enables the 6-DOF model of §15.
    pub enabled: bool,
    /// J_sw: rim + column inertia.
    pub inertia_kgm2: f64,
    /// k_tb: EPS torsion bar stiffness.
    pub torsion_bar_nm_per_rad: f64,
    /// c_tb: torsion bar damping.
    pub torsion_bar_damping_nms_per_rad: f64,
    /// c_h: hands-on-rim damping (the driver's hands and arms plus the column's own).
    pub hands_damping_nms_per_rad: f64,
    /// J_hands: inertia of the hands and arms coupled to the rim, added to J_sw in eq. (6).
    /// 0 (the default, §15's "light hands" as damping only) is left out of the serialised
    /// form, so vehicle files and hashes written before the field existed stay the same.
    #[serde(skip_serializing_if = "is_zero")]
    pub hands_inertia_kgm2: f64,
    /// k_hands: stiffness of the hands and arms on the rim, added to the restraint k_h of
    /// eq. (6). Default 0, left out of the serialised form like `hands_inertia_kgm2`.
    #[serde(skip_serializing_if = "is_zero")]
    pub hands_stiffness_nm_per_rad: f64,
}

fn is_zero(x: &f64) -> bool {
    *x == 0.0
}

impl Default for Column {
    fn default() -> Self {
        Self {
            enabled: false,
            inertia_kgm2: 0.04,
            torsion_bar_nm_per_rad: 114.6,
            torsion_bar_damping_nms_per_rad: 0.02,
            hands_damping_nms_per_rad: 0.3,
            hands_inertia_kgm2: 0.0,
            hands_stiffness_nm_per_rad: 0.0,
        }
    }
}

/// The driver's hands and arms on the rim as eq. (6) of MODEL.md §15 sees them: an inertia
/// added to J_sw, a stiffness added to the restraint k_h, and the rim damping c_h. A state that
/// may change between braking events ([`crate::model::Simulator::set_hands`]); docs/COLUMN.md
/// gives the ranges of hands off, light and firm grip.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Hands {
    pub inertia_kgm2: f64,
    pub stiffness_nm_per_rad: f64,
    pub damping_nms_per_rad: f64,
}

impl Hands {
    /// Checks that every value is finite and >= 0; the error names the `column.hands_*` key.
    pub fn validate(&self) -> Result<(), ParamError> {
        for (key, v) in [
            ("column.hands_inertia_kgm2", self.inertia_kgm2),
            (
                "column.hands_stiffness_nm_per_rad",
                self.stiffness_nm_per_rad,
            ),
            ("column.hands_damping_nms_per_rad", self.damping_nms_per_rad),
        ] {
            if !(v.is_finite() && v >= 0.0) {
                return Err(ParamError {
                    key: key.into(),
                    value: v,
                    why: "must be finite and >= 0",
                });
            }
        }
        Ok(())
    }
}

impl Column {
    /// The hands on the rim this column's values describe.
    pub fn hands(&self) -> Hands {
        Hands {
            inertia_kgm2: self.hands_inertia_kgm2,
            stiffness_nm_per_rad: self.hands_stiffness_nm_per_rad,
            damping_nms_per_rad: self.hands_damping_nms_per_rad,
        }
    }

    /// Puts `h` on the rim (no validation; see [`Hands::validate`]).
    pub fn set_hands(&mut self, h: Hands) {
        self.hands_inertia_kgm2 = h.inertia_kgm2;
        self.hands_stiffness_nm_per_rad = h.stiffness_nm_per_rad;
        self.hands_damping_nms_per_rad = h.damping_nms_per_rad;
    }
}

/// Steering angle sensor (MODEL.md §8).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct Sensor {
    /// SAS sample rate.
    pub sample_hz: f64,
    /// SAS quantisation step.
    pub resolution_deg: f64,
}

impl Default for Sensor {
    fn default() -> Self {
        Self {
            sample_hz: 100.0,
            resolution_deg: 0.1,
        }
    }
}

/// All vehicle parameters. `Default` is MODEL.md §9 (and §15 with `column.enabled = false`).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize, Default)]
#[serde(default, deny_unknown_fields)]
pub struct VehicleParams {
    pub vehicle: Vehicle,
    pub braking: Braking,
    pub steering: Steering,
    pub axle: Axle,
    pub tire: Tire,
    pub joint: Joint,
    pub excitation: Excitation,
    pub column: Column,
    pub sensor: Sensor,
}

/// A parameter value that makes no physical sense; `key` is the dotted TOML key.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
#[error("vehicle parameter `{key}` = {value}: {why}")]
pub struct ParamError {
    pub key: String,
    pub value: f64,
    pub why: &'static str,
}

impl VehicleParams {
    /// Parses TOML text (missing keys take their §9 defaults) and validates it.
    pub fn from_toml_str(text: &str) -> anyhow::Result<Self> {
        let p: Self = toml::from_str(text)?;
        p.validate()?;
        Ok(p)
    }

    /// Loads and validates a vehicle file such as `config/vehicle/default.toml`.
    pub fn from_toml_file(path: impl AsRef<Path>) -> anyhow::Result<Self> {
        use anyhow::Context;
        let path = path.as_ref();
        let text = std::fs::read_to_string(path)
            .with_context(|| format!("reading vehicle file {}", path.display()))?;
        Self::from_toml_str(&text).with_context(|| format!("in vehicle file {}", path.display()))
    }

    /// Checks every value for sign and range; the error names the offending key.
    pub fn validate(&self) -> Result<(), ParamError> {
        fn pos(key: &str, v: f64) -> Result<(), ParamError> {
            if v.is_finite() && v > 0.0 {
                Ok(())
            } else {
                Err(ParamError {
                    key: key.into(),
                    value: v,
                    why: "must be finite and > 0",
                })
            }
        }
        fn nonneg(key: &str, v: f64) -> Result<(), ParamError> {
            if v.is_finite() && v >= 0.0 {
                Ok(())
            } else {
                Err(ParamError {
                    key: key.into(),
                    value: v,
                    why: "must be finite and >= 0",
                })
            }
        }
        fn finite(key: &str, v: f64) -> Result<(), ParamError> {
            if v.is_finite() {
                Ok(())
            } else {
                Err(ParamError {
                    key: key.into(),
                    value: v,
                    why: "must be finite",
                })
            }
        }
        fn range(key: &str, v: f64, lo: f64, hi: f64, why: &'static str) -> Result<(), ParamError> {
            if v.is_finite() && v >= lo && v <= hi {
                Ok(())
            } else {
                Err(ParamError {
                    key: key.into(),
                    value: v,
                    why,
                })
            }
        }
        let v = &self.vehicle;
        pos("vehicle.mass_kg", v.mass_kg)?;
        pos("vehicle.wheelbase_m", v.wheelbase_m)?;
        range(
            "vehicle.cg_to_rear_axle_m",
            v.cg_to_rear_axle_m,
            f64::MIN_POSITIVE,
            v.wheelbase_m,
            "must lie in (0, wheelbase_m]",
        )?;
        nonneg("vehicle.cg_height_m", v.cg_height_m)?;
        pos("vehicle.gravity_mps2", v.gravity_mps2)?;

        let b = &self.braking;
        range(
            "braking.front_share",
            b.front_share,
            0.0,
            1.0,
            "must lie in [0, 1]",
        )?;
        nonneg("braking.onset_s", b.onset_s)?;
        pos("braking.ramp_s", b.ramp_s)?;
        pos("braking.v_stop_mps", b.v_stop_mps)?;
        pos("braking.pitch_freq_hz", b.pitch_freq_hz)?;
        pos("braking.pitch_damping_ratio", b.pitch_damping_ratio)?;
        for i in 0..2 {
            range(
                "braking.torque_variation_rel",
                b.torque_variation_rel[i],
                0.0,
                0.5,
                "must lie in [0, 0.5]",
            )?;
            finite(
                "braking.torque_variation_phase_deg",
                b.torque_variation_phase_deg[i],
            )?;
        }

        let s = &self.steering;
        pos("steering.kingpin_half_spacing_m", s.kingpin_half_spacing_m)?;
        pos("steering.arm_length_m", s.arm_length_m)?;
        range(
            "steering.trapezoid_angle_deg",
            s.trapezoid_angle_deg,
            1.0,
            89.0,
            "must lie in [1, 89] degrees",
        )?;
        nonneg("steering.caster_trail_m", s.caster_trail_m)?;
        finite("steering.scrub_radius_m", s.scrub_radius_m)?;
        nonneg("steering.spindle_offset_m", s.spindle_offset_m)?;
        pos("steering.kingpin_inertia_kgm2", s.kingpin_inertia_kgm2)?;
        nonneg(
            "steering.kingpin_stiffness_nm_per_rad",
            s.kingpin_stiffness_nm_per_rad,
        )?;
        nonneg(
            "steering.kingpin_damping_nms_per_rad",
            s.kingpin_damping_nms_per_rad,
        )?;
        pos("steering.tie_rod_mass_kg", s.tie_rod_mass_kg)?;
        pos(
            "steering.tie_rod_stiffness_n_per_m",
            s.tie_rod_stiffness_n_per_m,
        )?;
        pos(
            "steering.restraint_stiffness_n_per_m",
            s.restraint_stiffness_n_per_m,
        )?;
        nonneg(
            "steering.restraint_damping_ns_per_m",
            s.restraint_damping_ns_per_m,
        )?;
        nonneg(
            "steering.tie_rod_yaw_damping_nms_per_rad",
            s.tie_rod_yaw_damping_nms_per_rad,
        )?;
        pos(
            "steering.rack_travel_per_pinion_rad_m",
            s.rack_travel_per_pinion_rad_m,
        )?;
        let l_t = 2.0 * s.kingpin_half_spacing_m
            - 2.0 * s.arm_length_m * s.trapezoid_angle_deg.to_radians().cos();
        if l_t <= 0.0 {
            return Err(ParamError {
                key: "steering.arm_length_m".into(),
                value: s.arm_length_m,
                why: "tie-rod length 2b - 2 l cos(alpha) would be <= 0",
            });
        }

        let a = &self.axle;
        pos("axle.roll_inertia_kgm2", a.roll_inertia_kgm2)?;
        nonneg(
            "axle.roll_stiffness_nm_per_rad",
            a.roll_stiffness_nm_per_rad,
        )?;
        nonneg("axle.roll_damping_nms_per_rad", a.roll_damping_nms_per_rad)?;
        pos("axle.track_m", a.track_m)?;
        pos("axle.wheel_radius_m", a.wheel_radius_m)?;
        nonneg("axle.wheel_spin_inertia_kgm2", a.wheel_spin_inertia_kgm2)?;

        let t = &self.tire;
        nonneg(
            "tire.vertical_stiffness_n_per_m",
            t.vertical_stiffness_n_per_m,
        )?;
        pos(
            "tire.lateral_stiffness_n_per_m",
            t.lateral_stiffness_n_per_m,
        )?;
        pos("tire.friction_scale", t.friction_scale)?;

        let j = &self.joint;
        pos("joint.pin_radius_m", j.pin_radius_m)?;
        pos("joint.young_modulus_pa", j.young_modulus_pa)?;
        range(
            "joint.poisson_ratio",
            j.poisson_ratio,
            0.0,
            0.499,
            "must lie in [0, 0.5)",
        )?;
        range(
            "joint.restitution",
            j.restitution,
            0.0,
            1.0,
            "must lie in [0, 1]",
        )?;
        nonneg("joint.friction", j.friction)?;
        pos(
            "joint.friction_reg_velocity_mps",
            j.friction_reg_velocity_mps,
        )?;
        nonneg(
            "joint.tangential_damping_ns_per_m",
            j.tangential_damping_ns_per_m,
        )?;
        pos("joint.min_impact_velocity_mps", j.min_impact_velocity_mps)?;
        pos("joint.ideal_stiffness_n_per_m", j.ideal_stiffness_n_per_m)?;
        nonneg("joint.ideal_damping_ns_per_m", j.ideal_damping_ns_per_m)?;

        let e = &self.excitation;
        nonneg("excitation.unbalance_kgm", e.unbalance_kgm)?;
        nonneg("excitation.noise_std_nm", e.noise_std_nm)?;
        pos("excitation.noise_tau_s", e.noise_tau_s)?;
        pos("excitation.noise_ref_speed_mps", e.noise_ref_speed_mps)?;
        finite("excitation.kick_rad_per_s", e.kick_rad_per_s)?;

        let c = &self.column;
        pos("column.inertia_kgm2", c.inertia_kgm2)?;
        pos("column.torsion_bar_nm_per_rad", c.torsion_bar_nm_per_rad)?;
        nonneg(
            "column.torsion_bar_damping_nms_per_rad",
            c.torsion_bar_damping_nms_per_rad,
        )?;
        c.hands().validate()?;
        if c.enabled {
            let kg_rp2 = s.restraint_stiffness_n_per_m * s.rack_travel_per_pinion_rad_m.powi(2);
            if kg_rp2 >= c.torsion_bar_nm_per_rad {
                return Err(ParamError {
                    key: "column.torsion_bar_nm_per_rad".into(),
                    value: c.torsion_bar_nm_per_rad,
                    why: "must exceed k_g*r_p^2 so that the hands restraint k_h of §15 is positive",
                });
            }
        }

        let n = &self.sensor;
        pos("sensor.sample_hz", n.sample_hz)?;
        pos("sensor.resolution_deg", n.resolution_deg)?;
        Ok(())
    }
}
