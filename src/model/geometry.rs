//! Steering-trapezoid kinematics (MODEL.md §2): pin centres on the arm tips, bushing centres on
//! the tie-rod ends, and their velocities, in the axle frame (x right, y forward, z up).
//!
//! What it is: pure functions of the coordinates. What it is not: forces (see `joint`, `tire`).

/// A 2-D vector in the axle frame.
pub type V2 = [f64; 2];

/// z-component of a × b (MODEL.md §3: [a × b]_z = a_x·b_y − a_y·b_x).
#[inline(always)]
pub fn cross(a: V2, b: V2) -> f64 {
    a[0] * b[1] - a[1] * b[0]
}

#[inline(always)]
pub fn dot(a: V2, b: V2) -> f64 {
    a[0] * b[0] + a[1] * b[1]
}

/// Constant trapezoid geometry derived from the parameters (MODEL.md §2).
#[derive(Debug, Clone, Copy)]
pub struct Trapezoid {
    /// b: half kingpin spacing.
    pub b: f64,
    /// l: arm length.
    pub l: f64,
    /// cos α, sin α.
    pub cos_a: f64,
    pub sin_a: f64,
    /// l_t = 2b − 2l·cos α.
    pub l_t: f64,
    /// y0 = −l·sin α: nominal tie-rod line.
    pub y0: f64,
}

/// Pin centres, bushing centres and their velocities at one state.
#[derive(Debug, Clone, Copy, Default)]
pub struct Points {
    /// P_L, P_R: pin centres (arm tips).
    pub p: [V2; 2],
    /// Ṗ_L, Ṗ_R.
    pub p_dot: [V2; 2],
    /// B_L, B_R: bushing centres (tie-rod ends).
    pub b: [V2; 2],
    /// Ḃ_L, Ḃ_R.
    pub b_dot: [V2; 2],
}

impl Trapezoid {
    pub fn new(b: f64, l: f64, alpha_rad: f64) -> Self {
        let (sin_a, cos_a) = alpha_rad.sin_cos();
        Self {
            b,
            l,
            cos_a,
            sin_a,
            l_t: 2.0 * b - 2.0 * l * cos_a,
            y0: -l * sin_a,
        }
    }

    /// Kingpin positions O_L = (−b, 0), O_R = (+b, 0).
    #[inline(always)]
    pub fn kingpin(&self, side: usize) -> V2 {
        if side == 0 {
            [-self.b, 0.0]
        } else {
            [self.b, 0.0]
        }
    }

    /// Tie-rod centre G = (X, y0).
    #[inline(always)]
    pub fn centre(&self, x: f64) -> V2 {
        [x, self.y0]
    }

    /// All joint points for (θ1, θ2, X, θ4) and their rates (MODEL.md §2).
    #[inline(always)]
    #[allow(clippy::too_many_arguments)]
    pub fn points(
        &self,
        th1: f64,
        th2: f64,
        x: f64,
        th4: f64,
        th1d: f64,
        th2d: f64,
        xd: f64,
        th4d: f64,
    ) -> Points {
        self.points_sc(
            th1.sin_cos(),
            th2.sin_cos(),
            th4.sin_cos(),
            x,
            th1d,
            th2d,
            xd,
            th4d,
        )
    }

    /// [`Self::points`] from the sines and cosines (sin, cos) of θ1, θ2, θ4 (computed once per
    /// state and shared with the tire terms, or shifted across integrator stages).
    #[inline(always)]
    #[allow(clippy::too_many_arguments)]
    pub fn points_sc(
        &self,
        (s1, c1): (f64, f64),
        (s2, c2): (f64, f64),
        (s4, c4): (f64, f64),
        x: f64,
        th1d: f64,
        th2d: f64,
        xd: f64,
        th4d: f64,
    ) -> Points {
        // cos(θ1 − α), sin(θ1 − α) and cos(θ2 + α), sin(θ2 + α) by angle addition.
        let cl = c1 * self.cos_a + s1 * self.sin_a; // cos(θ1 − α)
        let sl = s1 * self.cos_a - c1 * self.sin_a; // sin(θ1 − α)
        let cr = c2 * self.cos_a - s2 * self.sin_a; // cos(θ2 + α)
        let sr = s2 * self.cos_a + c2 * self.sin_a; // sin(θ2 + α)
        let l = self.l;
        let h = 0.5 * self.l_t;
        Points {
            p: [[-self.b + l * cl, l * sl], [self.b - l * cr, -l * sr]],
            p_dot: [
                [-l * th1d * sl, l * th1d * cl],
                [l * th2d * sr, -l * th2d * cr],
            ],
            b: [
                [x - h * c4, self.y0 - h * s4],
                [x + h * c4, self.y0 + h * s4],
            ],
            b_dot: [
                [xd + h * th4d * s4, -h * th4d * c4],
                [xd - h * th4d * s4, h * th4d * c4],
            ],
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn pins_start_centred_and_linear_kinematics_hold() {
        let g = Trapezoid::new(0.66, 0.13, 72f64.to_radians());
        let p = g.points(0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0);
        for i in 0..2 {
            assert!((p.p[i][0] - p.b[i][0]).abs() < 1e-15);
            assert!((p.p[i][1] - p.b[i][1]).abs() < 1e-15);
        }
        // §2: rigid-joint kinematics X = l sin α θ, θ4 = −(2 l cos α / l_t) θ keep e = 0 to 1st order.
        let th = 1e-6;
        let x = g.l * g.sin_a * th;
        let th4 = -(2.0 * g.l * g.cos_a / g.l_t) * th;
        let p = g.points(th, th, x, th4, 0.0, 0.0, 0.0, 0.0);
        for i in 0..2 {
            let e = [p.p[i][0] - p.b[i][0], p.p[i][1] - p.b[i][1]];
            assert!(e[0].abs() < 1e-10 && e[1].abs() < 1e-10, "{e:?}");
        }
    }

    #[test]
    fn velocities_are_derivatives_of_positions() {
        let g = Trapezoid::new(0.66, 0.13, 72f64.to_radians());
        let q = [0.01, -0.02, 1e-4, 0.003];
        let qd = [0.3, -0.2, 0.01, 0.05];
        let dt = 1e-7;
        let a = g.points(q[0], q[1], q[2], q[3], qd[0], qd[1], qd[2], qd[3]);
        let b = g.points(
            q[0] + dt * qd[0],
            q[1] + dt * qd[1],
            q[2] + dt * qd[2],
            q[3] + dt * qd[3],
            0.0,
            0.0,
            0.0,
            0.0,
        );
        for i in 0..2 {
            for k in 0..2 {
                assert!(((b.p[i][k] - a.p[i][k]) / dt - a.p_dot[i][k]).abs() < 1e-6);
                assert!(((b.b[i][k] - a.b[i][k]) / dt - a.b_dot[i][k]).abs() < 1e-6);
            }
        }
    }
}
