//! Tire model (MODEL.md §5): vertical load, relaxation length, pure-slip Magic Formula of
//! Bakker, Nyborg & Pacejka (1987) with the coefficients of §5.3, braking-slip inversion by
//! Newton's method, and combined slip by the theoretical-slip method.
//!
//! What it is: force laws of one tire for a given load and slip. What it is not: the slip
//! kinematics or the relaxation ODE (those are in `rhs`), nor the moment about the kingpin.

const RAD2DEG: f64 = 180.0 / std::f64::consts::PI;

/// One Magic Formula curve y(x) = D·sin(C·atan(B·x − E·(B·x − atan(B·x)))).
#[derive(Debug, Clone, Copy, Default)]
pub struct Curve {
    pub b: f64,
    pub c: f64,
    pub d: f64,
    pub e: f64,
}

impl Curve {
    #[inline(always)]
    fn new(c: f64, d: f64, bcd: f64, e: f64) -> Self {
        Self {
            b: bcd / (c * d),
            c,
            d,
            e,
        }
    }

    #[inline(always)]
    pub fn eval(&self, x: f64) -> f64 {
        let bx = self.b * x;
        self.d * (self.c * (bx - self.e * (bx - bx.atan())).atan()).sin()
    }

    /// y(x) and dy/dx.
    #[inline(always)]
    pub fn eval_d(&self, x: f64) -> (f64, f64) {
        let bx = self.b * x;
        let u = bx - self.e * (bx - bx.atan());
        let du = self.b * (1.0 - self.e + self.e / (1.0 + bx * bx));
        let (s, c) = (self.c * u.atan()).sin_cos();
        (self.d * s, self.d * c * self.c / (1.0 + u * u) * du)
    }

    /// Slope at the origin, BCD.
    #[inline(always)]
    pub fn slope0(&self) -> f64 {
        self.b * self.c * self.d
    }
}

/// The three pure-slip curves at one vertical load (MODEL.md §5.3).
/// Inputs: Fy0 and Mz0 take the slip angle in degrees, Fx0 the slip ratio in percent.
#[derive(Debug, Clone, Copy, Default)]
pub struct PureSlip {
    pub fy: Curve,
    pub fx: Curve,
    pub mz: Curve,
}

impl PureSlip {
    /// Coefficients at load `fz_n` (N); `mu` scales the force peaks (§5.3).
    #[inline(always)]
    pub fn at_load(fz_n: f64, mu: f64) -> Self {
        let fz = fz_n * 1e-3;
        let fz2 = fz * fz;
        let fy = Curve::new(
            1.30,
            mu * (-22.1 * fz2 + 1011.0 * fz),
            1078.0 * (1.82 * (0.208 * fz).atan()).sin(),
            -0.354 * fz + 0.707,
        );
        let fx = Curve::new(
            1.65,
            mu * (-21.3 * fz2 + 1144.0 * fz),
            (49.6 * fz2 + 226.0 * fz) * (-0.069 * fz).exp(),
            -0.006 * fz2 + 0.056 * fz + 0.486,
        );
        let mz = Curve::new(
            2.40,
            2.72 * fz2 + 2.28 * fz,
            (1.86 * fz2 + 2.73 * fz) * (-0.110 * fz).exp(),
            -0.070 * fz2 + 0.643 * fz - 4.04,
        );
        Self { fy, fx, mz }
    }

    /// Cornering stiffness C_Fα in N/rad.
    #[inline(always)]
    pub fn cornering_stiffness(&self) -> f64 {
        self.fy.slope0() * RAD2DEG
    }

    /// Longitudinal slip stiffness C_Fκ in N per unit slip.
    #[inline(always)]
    pub fn slip_stiffness(&self) -> f64 {
        self.fx.slope0() * 100.0
    }

    /// Braking slip κ (unit slip, sign of `force_n`) with Fx0(κ) = force_n, force capped at
    /// 0.98·D_x (MODEL.md §5.3). Newton's method from `kappa0` (a cold start uses the linear
    /// estimate); at most `max_iter` steps, stopping early when the update is below `tol`.
    #[inline(always)]
    pub fn invert_fx(&self, force_n: f64, kappa0: Option<f64>, max_iter: u32, tol: f64) -> f64 {
        let target = force_n.abs().min(0.98 * self.fx.d);
        if target <= 0.0 {
            return 0.0;
        }
        // x in percent.
        let mut x = match kappa0 {
            Some(k) => (k.abs() * 100.0).max(0.0),
            None => target / self.fx.slope0(),
        };
        for _ in 0..max_iter {
            let (y, dy) = self.fx.eval_d(x);
            if dy <= 0.0 {
                break;
            }
            let step = (y - target) / dy;
            x = (x - step).max(0.0);
            if step.abs() < tol {
                break;
            }
        }
        (x * 0.01).copysign(force_n)
    }

    /// Combined-slip forces (MODEL.md §5.3): κ (unit), α_t (tan of the slip angle).
    /// Returns (F_x, F_y, M_z); F_x > 0 is a braking force, F_y > 0 opposes α_t > 0,
    /// M_z > 0 for α_t > 0 (the moment on the wheel is −M_z).
    #[inline(always)]
    pub fn combined(&self, kappa: f64, alpha_t: f64) -> (f64, f64, f64) {
        let s = (kappa * kappa + alpha_t * alpha_t).sqrt();
        if s < 1e-9 {
            return (
                self.slip_stiffness() * kappa,
                self.cornering_stiffness() * alpha_t,
                self.mz.slope0() * RAD2DEG * alpha_t,
            );
        }
        let a_deg = s.atan() * RAD2DEG;
        let inv = 1.0 / s;
        // κ = 0 (no braking) gives F_x = 0 exactly; skip the curve evaluation.
        let fx = if kappa == 0.0 {
            0.0
        } else {
            self.fx.eval(s * 100.0) * kappa * inv
        };
        (
            fx,
            self.fy.eval(a_deg) * alpha_t * inv,
            self.mz.eval(a_deg) * alpha_t * inv,
        )
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn model_md_tire_figures_at_4_kn() {
        // MODEL.md §5.3: C_Fα ≈ 59 kN/rad, pneumatic trail ≈ 25 mm, peak μ ≈ 1.0 at 4 kN.
        let t = PureSlip::at_load(4000.0, 1.0);
        let cfa = t.cornering_stiffness();
        assert!((cfa - 59e3).abs() < 1e3, "C_Fα = {cfa}");
        let trail = t.mz.slope0() / t.fy.slope0();
        assert!((trail - 0.025).abs() < 0.002, "trail = {trail}");
        assert!(
            (t.fy.d / 4000.0 - 1.0).abs() < 0.1,
            "peak mu {}",
            t.fy.d / 4000.0
        );
        // §5.2: relaxation length σ = C_Fα / k_ty ≈ 0.42 m.
        assert!((cfa / 1.4e5 - 0.42).abs() < 0.01);
    }

    #[test]
    fn slip_inversion_reproduces_the_force_and_caps_at_98_percent() {
        let t = PureSlip::at_load(4673.0, 1.0);
        for f in [100.0, 1000.0, 2318.0, 4000.0] {
            let k = t.invert_fx(f, None, 8, 0.0);
            assert!(k > 0.0);
            assert!((t.fx.eval(k * 100.0) - f).abs() < 1e-6 * f, "f={f}");
        }
        let k = t.invert_fx(1e6, None, 50, 0.0);
        assert!((t.fx.eval(k * 100.0) - 0.98 * t.fx.d).abs() < 1e-3 * t.fx.d);
        // Warm start converges to the same slip.
        let cold = t.invert_fx(2318.0, None, 8, 0.0);
        let warm = t.invert_fx(2318.0, Some(cold * 1.01), 8, 1e-12);
        assert!((cold - warm).abs() < 1e-12);
    }

    #[test]
    fn combined_slip_is_continuous_at_zero() {
        let t = PureSlip::at_load(4000.0, 1.0);
        let (fx0, fy0, mz0) = t.combined(0.0, 1e-10);
        let (fx1, fy1, mz1) = t.combined(0.0, 2e-9);
        assert!(fx0 == 0.0 && fx1 == 0.0);
        assert!((fy1 / 2e-9 - fy0 / 1e-10).abs() < 1e-3 * fy0 / 1e-10);
        assert!((mz1 / 2e-9 - mz0 / 1e-10).abs() < 1e-3 * mz0 / 1e-10);
    }
}
