//! Revolute clearance joints (MODEL.md §4): Lankarani–Nikravesh normal force with Hertz
//! stiffness for conformal internal contact, regularised Coulomb friction, and the ideal
//! (zero-clearance penalty) joint of the single-clearance variant.
//!
//! What it is: the force on the pin (arm side) and the contact points used for the moments.
//! What it is not: the bookkeeping of contact flags and impact velocities at step boundaries
//! (that is `sim`, MODEL.md §10).

use super::geometry::{dot, V2};

/// Constants of one clearance joint (MODEL.md §4).
#[derive(Debug, Clone, Copy)]
pub struct ClearanceJoint {
    /// c: radial clearance.
    pub c: f64,
    /// R_p, R_b = R_p + c.
    pub r_p: f64,
    pub r_b: f64,
    /// K = (4/3)·E*·sqrt(R_p·R_b/(R_b − R_p)).
    pub k: f64,
    /// 3·(1 − c_r²)/4.
    pub ln_factor: f64,
    /// μ_j, v_ε, c_tan, v_imp,min.
    pub mu: f64,
    pub v_eps: f64,
    pub c_tan: f64,
    pub v_imp_min: f64,
}

/// Hertz stiffness of MODEL.md §4: E* = [(1 − ν²)/E + (1 − ν²)/E]⁻¹ for identical materials.
pub fn hertz_k(young_pa: f64, poisson: f64, r_p: f64, c: f64) -> f64 {
    let e_star = 1.0 / (2.0 * (1.0 - poisson * poisson) / young_pa);
    let r_b = r_p + c;
    4.0 / 3.0 * e_star * (r_p * r_b / (r_b - r_p)).sqrt()
}

/// Result of one joint evaluation.
#[derive(Debug, Clone, Copy, Default)]
pub struct JointForce {
    /// F_i: force on the pin (arm side), axle frame. The tie rod receives −F_i.
    pub f: V2,
    /// Lever points: Q_p (pin side) and Q_b (bushing side).
    pub q_p: V2,
    pub q_b: V2,
    /// δ = |e| − c (negative in free flight).
    pub delta: f64,
    /// Normal force F_N ≥ 0.
    pub f_n: f64,
}

impl ClearanceJoint {
    /// Force of the joint with pin at `p` (velocity `p_dot`) and bushing at `b` (`b_dot`).
    /// `arm_rate` is θ1' or θ2', `rod_rate` is θ4'. `v_imp` is the held impact velocity δ'⁻
    /// (None before the flag is set at a step boundary: then the current δ' floored is used).
    /// Exactly zero force while |e| ≤ c.
    #[inline(always)]
    #[allow(clippy::too_many_arguments)]
    pub fn force(
        &self,
        p: V2,
        p_dot: V2,
        b: V2,
        b_dot: V2,
        arm_rate: f64,
        rod_rate: f64,
        v_imp: Option<f64>,
    ) -> JointForce {
        let e = [p[0] - b[0], p[1] - b[1]];
        let e_abs = (e[0] * e[0] + e[1] * e[1]).sqrt();
        let delta = e_abs - self.c;
        if delta <= 0.0 {
            return JointForce {
                f: [0.0, 0.0],
                q_p: p,
                q_b: b,
                delta,
                f_n: 0.0,
            };
        }
        let n = [e[0] / e_abs, e[1] / e_abs];
        let t = [-n[1], n[0]];
        let v_rel = [p_dot[0] - b_dot[0], p_dot[1] - b_dot[1]];
        let delta_dot = dot(v_rel, n);
        let v_t = dot(v_rel, t) + self.r_p * arm_rate - self.r_b * rod_rate;
        let v_minus = match v_imp {
            Some(v) => v,
            None => delta_dot.max(self.v_imp_min),
        };
        let f_n =
            (self.k * delta * delta.sqrt() * (1.0 + self.ln_factor * delta_dot / v_minus)).max(0.0);
        let f_t = self.mu * f_n * (v_t / self.v_eps).tanh() + self.c_tan * v_t;
        JointForce {
            f: [-f_n * n[0] - f_t * t[0], -f_n * n[1] - f_t * t[1]],
            q_p: [p[0] + self.r_p * n[0], p[1] + self.r_p * n[1]],
            q_b: [b[0] + self.r_b * n[0], b[1] + self.r_b * n[1]],
            delta,
            f_n,
        }
    }

    /// Normal penetration δ and its rate δ' (for the step-boundary bookkeeping of §4/§10).
    #[inline(always)]
    pub fn penetration(&self, p: V2, p_dot: V2, b: V2, b_dot: V2) -> (f64, f64) {
        let e = [p[0] - b[0], p[1] - b[1]];
        let e_abs = (e[0] * e[0] + e[1] * e[1]).sqrt();
        let delta = e_abs - self.c;
        if e_abs == 0.0 {
            return (delta, 0.0);
        }
        let n = [e[0] / e_abs, e[1] / e_abs];
        let v_rel = [p_dot[0] - b_dot[0], p_dot[1] - b_dot[1]];
        (delta, dot(v_rel, n))
    }
}

/// The ideal joint of the single-clearance variant (MODEL.md §4):
/// F = −k_id·e − c_id·(Ṗ − Ḃ), acting at the pin and bushing centres.
#[derive(Debug, Clone, Copy)]
pub struct IdealJoint {
    pub k: f64,
    pub c: f64,
}

impl IdealJoint {
    #[inline(always)]
    pub fn force(&self, p: V2, p_dot: V2, b: V2, b_dot: V2) -> JointForce {
        let e = [p[0] - b[0], p[1] - b[1]];
        let ed = [p_dot[0] - b_dot[0], p_dot[1] - b_dot[1]];
        let f = [
            -self.k * e[0] - self.c * ed[0],
            -self.k * e[1] - self.c * ed[1],
        ];
        JointForce {
            f,
            q_p: p,
            q_b: b,
            delta: (e[0] * e[0] + e[1] * e[1]).sqrt(),
            f_n: (f[0] * f[0] + f[1] * f[1]).sqrt(),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn hertz_stiffness_matches_model_md_values() {
        // MODEL.md §4 quotes 2.18e11 / 1.54e11 / 7.8e10 at c = 0.05 / 0.1 / 0.4 mm (to ~1.5 %).
        for (c, k_ref) in [(0.05e-3, 2.18e11), (0.1e-3, 1.54e11), (0.4e-3, 7.8e10)] {
            let k = hertz_k(207e9, 0.3, 0.010, c);
            assert!((k / k_ref - 1.0).abs() < 0.02, "c={c} K={k:e}");
        }
    }

    fn joint() -> ClearanceJoint {
        ClearanceJoint {
            c: 1e-4,
            r_p: 0.01,
            r_b: 0.0101,
            k: 1.5e11,
            ln_factor: 0.75 * (1.0 - 0.64),
            mu: 0.1,
            v_eps: 5e-3,
            c_tan: 0.0,
            v_imp_min: 0.01,
        }
    }

    #[test]
    fn force_is_exactly_zero_inside_clearance_and_restoring_outside() {
        let j = joint();
        let z = [0.0, 0.0];
        let inside = j.force([0.99e-4, 0.0], [1.0, 2.0], z, z, 3.0, 1.0, None);
        assert_eq!(inside.f, [0.0, 0.0]);
        let out = j.force([1.01e-4, 0.0], z, z, z, 0.0, 0.0, None);
        assert!(out.f[0] < 0.0 && out.f[1].abs() < 1e-12 * out.f_n.max(1.0));
        // Hertz: F = K δ^1.5 when δ' = 0 and no slip.
        let want = 1.5e11 * (1e-6f64).powf(1.5);
        assert!((out.f_n - want).abs() < 1e-9 * want);
    }
}
