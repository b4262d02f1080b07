//! Braking scenario (MODEL.md §6): demanded deceleration with onset ramp and fade to a stop,
//! brake force per front wheel, and the pitch filter that turns deceleration into load
//! transfer. Also the external-demand mode that firmware-sim uses for whole drive cycles.
//!
//! What it is: the longitudinal input law. What it is not: tire force generation (`tire`).

/// The reference driver of firmware-sim's drive cycles (firmware-sim/src/drive.rs). The
/// response table's events (`observer::simulate`) pull away and cruise by the same law, so
/// both read these constants from here.
pub mod driver {
    /// Speed regarded as standing still (m/s).
    pub const V_STANDSTILL_MPS: f64 = 0.02;
    /// Time constant of the approach to a cruise speed (s).
    pub const CRUISE_TAU_S: f64 = 0.6;
    /// Jerk limit on non-braking demand changes (m/s³).
    pub const JERK_MPS3: f64 = 3.0;
    /// Speed error below which a cruise speed counts as reached (m/s).
    pub const CRUISE_TOL_MPS: f64 = 0.1;
}

/// Where the longitudinal demand comes from.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum Demand {
    /// MODEL.md §6: a_max·clip((t − t_b)/t_r, 0, 1)·min(1, v/v_stop).
    Event {
        a_max_mps2: f64,
        onset_s: f64,
        ramp_s: f64,
    },
    /// Set from outside each step ([`crate::model::Simulator::set_decel_demand`]); positive is
    /// braking (faded by min(1, v/v_stop) so the car stops rather than reverses), negative is
    /// driving (front-wheel drive: the front tires carry the whole traction force).
    External { a_mps2: f64 },
}

impl Demand {
    /// Deceleration demand a_dem at time `t` and speed `v` (m/s²; > 0 brakes).
    #[inline(always)]
    pub fn a_dem(&self, t: f64, v: f64, v_stop: f64) -> f64 {
        match *self {
            Demand::Event {
                a_max_mps2,
                onset_s,
                ramp_s,
            } => {
                let ramp = ((t - onset_s) / ramp_s).clamp(0.0, 1.0);
                a_max_mps2 * ramp * (v / v_stop).clamp(0.0, 1.0)
            }
            Demand::External { a_mps2 } => {
                if a_mps2 >= 0.0 {
                    a_mps2 * (v / v_stop).clamp(0.0, 1.0)
                } else {
                    a_mps2
                }
            }
        }
    }
}

/// Longitudinal force on each front tire for demand `a_dem` (> 0 braking, MODEL.md §6:
/// F_b = β_f·m·a_dem/2; < 0 driving: F = m·a_dem/2, front-wheel drive).
#[inline(always)]
pub fn front_wheel_force(a_dem: f64, mass: f64, front_share: f64) -> f64 {
    if a_dem >= 0.0 {
        front_share * mass * a_dem * 0.5
    } else {
        mass * a_dem * 0.5
    }
}

/// Pitch filter (MODEL.md §6): a_f'' = ω_p²·(a_dem − a_f) − 2·ζ_p·ω_p·a_f'.
#[inline(always)]
pub fn pitch_accel(a_dem: f64, a_f: f64, a_f_dot: f64, omega_p: f64, zeta_p: f64) -> f64 {
    omega_p * omega_p * (a_dem - a_f) - 2.0 * zeta_p * omega_p * a_f_dot
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn event_ramp_and_fade() {
        let d = Demand::Event {
            a_max_mps2: 4.905,
            onset_s: 0.5,
            ramp_s: 0.3,
        };
        assert_eq!(d.a_dem(0.4, 15.0, 0.5), 0.0);
        assert!((d.a_dem(0.65, 15.0, 0.5) - 4.905 * 0.5).abs() < 1e-12);
        assert!((d.a_dem(2.0, 15.0, 0.5) - 4.905).abs() < 1e-12);
        assert!((d.a_dem(2.0, 0.25, 0.5) - 4.905 * 0.5).abs() < 1e-12);
        assert_eq!(d.a_dem(2.0, 0.0, 0.5), 0.0);
    }
}
