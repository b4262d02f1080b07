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
        Self::with_fy_shape(fz, mu, (1.82 * (0.208 * fz).atan()).sin())
    }

    /// The §5.3 coefficients at load `fz` (kN), given sin(1.82·atan(0.208·fz)) of Fy0's BCD
    /// (computed by libm or read from the tables).
    #[inline(always)]
    fn with_fy_shape(fz: f64, mu: f64, fy_bcd_shape: f64) -> Self {
        let fz2 = fz * fz;
        let fy = Curve::new(
            1.30,
            mu * (-22.1 * fz2 + 1011.0 * fz),
            1078.0 * fy_bcd_shape,
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
        let x0 = match kappa0 {
            Some(k) => (k.abs() * 100.0).max(0.0),
            None => target / self.fx.slope0(),
        };
        let x = newton_fx(target, x0, max_iter, tol, |x| self.fx.eval_d(x));
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

/// Node spacing and range of the Magic Formula shape tables ([`MfTables`]).
const TAB_PER_UNIT: f64 = 128.0;
const TAB_MAX: f64 = 16.0;

/// Cubic-Hermite table of an odd function f through g(x) = f(x)/x (even, smooth, g(0) = f'(0)),
/// so the error is relative to |f| down to x = 0. Nodes every 1/128 on [0, 16]; beyond that the
/// caller falls back to libm.
pub struct OddTable {
    /// (g, g') at the nodes.
    gd: Box<[[f64; 2]]>,
}

impl OddTable {
    fn build(f: impl Fn(f64) -> f64, df: impl Fn(f64) -> f64) -> Self {
        let n = (TAB_MAX * TAB_PER_UNIT) as usize + 2;
        let gd = (0..n)
            .map(|i| {
                let x = i as f64 / TAB_PER_UNIT;
                if i == 0 {
                    [df(0.0), 0.0]
                } else {
                    let (fx, dfx) = (f(x), df(x));
                    [fx / x, (dfx * x - fx) / (x * x)]
                }
            })
            .collect();
        Self { gd }
    }

    /// f(x) and f'(x), or None for |x| ≥ 16 (or NaN).
    #[inline(always)]
    pub fn eval_d(&self, x: f64) -> Option<(f64, f64)> {
        let ax = x.abs();
        // NaN and |x| ≥ TAB_MAX go to the caller's libm fallback.
        if ax.is_nan() || ax >= TAB_MAX {
            return None;
        }
        let t = ax * TAB_PER_UNIT;
        let i = t as usize;
        let s = t - i as f64;
        let ([g0, d0], [g1, d1]) = (self.gd[i], self.gd[i + 1]);
        let dx = 1.0 / TAB_PER_UNIT;
        let (s2, s3) = (s * s, s * s * s);
        let g = (2.0 * s3 - 3.0 * s2 + 1.0) * g0
            + (s3 - 2.0 * s2 + s) * dx * d0
            + (3.0 * s2 - 2.0 * s3) * g1
            + (s3 - s2) * dx * d1;
        let dg = ((6.0 * s2 - 6.0 * s) * (g0 - g1)) * TAB_PER_UNIT
            + (3.0 * s2 - 4.0 * s + 1.0) * d0
            + (3.0 * s2 - 2.0 * s) * d1;
        // f = x·g (odd), f' = g + |x|·g'(|x|).
        Some((x * g, g + ax * dg))
    }
}

/// Tables of the Magic Formula shape functions (MODEL.md §5.3): atan, and sin(C·atan(z)) for
/// the C of the three curves (1.30, 1.65, 2.40) and of the B_yC_yD_y load law (1.82). With
/// u = B·x, y/D = sin(C·atan(u − E·(u − atan u))), so every curve is two lookups instead of
/// two atan and one sin. Error below 1e-8 of the value (of 1 % of the peak D where M_z crosses
/// zero), tested against libm over the range the model visits. Built once per process.
pub struct MfTables {
    atan: OddTable,
    sin_c_atan: [OddTable; 4],
}

impl std::fmt::Debug for MfTables {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str("MfTables")
    }
}

/// The C values tabulated in [`MfTables::sin_c_atan`].
const TAB_C: [f64; 4] = [1.30, 1.65, 2.40, 1.82];

impl MfTables {
    /// The process-wide tables (built on first use, 5 × 32 KB).
    pub fn get() -> &'static MfTables {
        static T: std::sync::OnceLock<MfTables> = std::sync::OnceLock::new();
        T.get_or_init(|| MfTables {
            atan: OddTable::build(f64::atan, |x| 1.0 / (1.0 + x * x)),
            sin_c_atan: TAB_C.map(|c| {
                OddTable::build(
                    move |z| (c * z.atan()).sin(),
                    move |z| c * (c * z.atan()).cos() / (1.0 + z * z),
                )
            }),
        })
    }

    /// atan(x).
    #[inline(always)]
    pub fn atan(&self, x: f64) -> f64 {
        match self.atan.eval_d(x) {
            Some((v, _)) => v,
            None => x.atan(),
        }
    }

    /// sin(C·atan(z)) and its derivative for tabulated C number `k`.
    #[inline(always)]
    fn sin_c_atan(&self, k: usize, z: f64) -> (f64, f64) {
        match self.sin_c_atan[k].eval_d(z) {
            Some(v) => v,
            None => {
                let c = TAB_C[k];
                let a = c * z.atan();
                (a.sin(), c * a.cos() / (1.0 + z * z))
            }
        }
    }

    /// [`Curve::eval_d`] through the tables; `k` is the index of the curve's C in `TAB_C`.
    #[inline(always)]
    fn curve_d(&self, cv: &Curve, k: usize, x: f64) -> (f64, f64) {
        let bx = cv.b * x;
        let z = (1.0 - cv.e) * bx + cv.e * self.atan(bx);
        let dz = cv.b * (1.0 - cv.e + cv.e / (1.0 + bx * bx));
        let (h, dh) = self.sin_c_atan(k, z);
        (cv.d * h, cv.d * dh * dz)
    }

    /// [`Curve::eval`] through the tables.
    #[inline(always)]
    fn curve(&self, cv: &Curve, k: usize, x: f64) -> f64 {
        let bx = cv.b * x;
        let z = (1.0 - cv.e) * bx + cv.e * self.atan(bx);
        cv.d * self.sin_c_atan(k, z).0
    }
}

impl PureSlip {
    /// [`Self::at_load`] with sin(1.82·atan(0.208·F_z)) from the tables.
    #[inline(always)]
    pub fn at_load_tab(fz_n: f64, mu: f64, tab: &MfTables) -> Self {
        let fz = fz_n * 1e-3;
        Self::with_fy_shape(fz, mu, tab.sin_c_atan(3, 0.208 * fz).0)
    }

    /// [`Self::invert_fx`] (warm start, stop at `tol`) through the tables.
    #[inline(always)]
    pub fn invert_fx_tab(&self, force_n: f64, kappa0: f64, tol: f64, tab: &MfTables) -> f64 {
        let target = force_n.abs().min(0.98 * self.fx.d);
        if target <= 0.0 {
            return 0.0;
        }
        let x0 = (kappa0.abs() * 100.0).max(0.0);
        let x = newton_fx(target, x0, 8, tol, |x| tab.curve_d(&self.fx, 1, x));
        (x * 0.01).copysign(force_n)
    }

    /// [`Self::combined`] through the tables.
    #[inline(always)]
    pub fn combined_tab(&self, kappa: f64, alpha_t: f64, tab: &MfTables) -> (f64, f64, f64) {
        let s = (kappa * kappa + alpha_t * alpha_t).sqrt();
        if s < 1e-9 {
            return self.combined(kappa, alpha_t);
        }
        let a_deg = tab.atan(s) * RAD2DEG;
        let inv = 1.0 / s;
        let fx = if kappa == 0.0 {
            0.0
        } else {
            tab.curve(&self.fx, 1, s * 100.0) * kappa * inv
        };
        (
            fx,
            tab.curve(&self.fy, 0, a_deg) * alpha_t * inv,
            tab.curve(&self.mz, 2, a_deg) * alpha_t * inv,
        )
    }
}

/// Newton's method for Fx0(x) = `target` (x = slip in percent, kept ≥ 0) from `x0`, with
/// `eval_d` giving Fx0 and its slope: at most `max_iter` steps, stopping when the slope is not
/// positive or the update is below `tol` (MODEL.md §5.3's braking-slip inversion, for both the
/// libm and the tabulated curve).
#[inline(always)]
fn newton_fx(
    target: f64,
    mut x: f64,
    max_iter: u32,
    tol: f64,
    eval_d: impl Fn(f64) -> (f64, f64),
) -> f64 {
    for _ in 0..max_iter {
        let (y, dy) = eval_d(x);
        if dy <= 0.0 {
            break;
        }
        let step = (y - target) / dy;
        x = (x - step).max(0.0);
        if step.abs() < tol {
            break;
        }
    }
    x
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

#[cfg(test)]
mod table_tests {
    use super::*;

    /// Largest relative deviation of the tabulated tire from the exact Magic Formula over the
    /// loads and slips the model visits (F_z 0.2–9 kN: floor to twice the static load plus
    /// the full braking transfer; slip angle to ±10°, braking slip to 30 %).
    #[test]
    fn tabulated_tire_is_within_1e_8_of_the_exact_magic_formula() {
        let tab = MfTables::get();
        let mut worst: f64 = 0.0;
        let mut worst_at = (0.0, 0.0, 0.0);
        for i in 0..=60 {
            let fz = 200.0 + 8800.0 * i as f64 / 60.0;
            let exact = PureSlip::at_load(fz, 1.0);
            let t = PureSlip::at_load_tab(fz, 1.0, tab);
            for (a, b) in [
                (exact.fy.b, t.fy.b),
                (exact.fx.b, t.fx.b),
                (exact.mz.b, t.mz.b),
            ] {
                assert!((a - b).abs() <= 1e-8 * a.abs(), "B at {fz}: {a} vs {b}");
            }
            for j in 0..=200 {
                let alpha_t = (10f64.to_radians()).tan() * ((j as f64 / 100.0) - 1.0).powi(3);
                for kappa in [0.0, 1e-4, 3e-3, 0.02, 0.1, 0.3] {
                    let (x0, y0, m0) = exact.combined(kappa, alpha_t);
                    let (x1, y1, m1) = t.combined_tab(kappa, alpha_t, tab);
                    // Relative to the value (F_x, F_y vanish only at zero slip, where both
                    // are linear), for M_z to 1 % of its peak where it crosses zero at large
                    // slip (E < 0).
                    for (e, g, floor) in [(x0, x1, 0.0), (y0, y1, 0.0), (m0, m1, 1e-2 * exact.mz.d)]
                    {
                        let scale = e.abs().max(floor.abs()).max(f64::MIN_POSITIVE);
                        if e == 0.0 && g == 0.0 {
                            continue;
                        }
                        let r = (e - g).abs() / scale;
                        if r > worst {
                            worst = r;
                            worst_at = (fz, alpha_t, kappa);
                        }
                    }
                }
            }
            for f in [10.0, 500.0, 2000.0, 0.9 * exact.fx.d, 2.0 * exact.fx.d] {
                let k0 = exact.invert_fx(f, None, 50, 0.0);
                let k1 = t.invert_fx_tab(f, 0.5 * k0, 1e-10, tab);
                assert!(
                    (k0 - k1).abs() <= 1e-8 * k0.abs(),
                    "κ at {fz} N, {f} N: {k0} vs {k1}"
                );
            }
        }
        assert!(
            worst < 1e-8,
            "relative error {worst:e} at (Fz, α_t, κ) = {worst_at:?}"
        );
    }
}
