//! Integrators (MODEL.md §10): the classical fixed-step RK4 of the paper ([`rk4_step`]), and
//! the same RK4 with stage sines/cosines shifted from the step start and the tire outputs
//! taken from a [`StageTires`] policy ([`rk4_step_shared`], used by the multirate and
//! adaptive schemes of `sim::Integrator`). Works on the fixed-size state of `rhs`; nothing
//! here allocates.
//!
//! What it is: one step of a scheme, given the values held over the step. What it is not:
//! the step-boundary updates of contact flags, impact velocities and noise, or the choice of
//! step length (`sim`).

use super::rhs::{Aux, Model, State, StepCtx, TireOut, Trig, N};

/// One classical RK4 step of length `h` from (t, y), in place. Returns the by-products of the
/// last stage evaluation (at t + h), which `sim` uses to warm-start the slip inversion.
#[inline]
pub fn rk4_step(model: &Model, t: f64, y: &mut State, h: f64, ctx: &StepCtx) -> Aux {
    let mut aux = Aux::default();
    let mut k1 = [0.0; N];
    let mut k2 = [0.0; N];
    let mut k3 = [0.0; N];
    let mut k4 = [0.0; N];
    let mut tmp = [0.0; N];
    model.eval(t, y, ctx, &mut k1, &mut aux);
    for i in 0..N {
        tmp[i] = y[i] + 0.5 * h * k1[i];
    }
    model.eval(t + 0.5 * h, &tmp, ctx, &mut k2, &mut aux);
    for i in 0..N {
        tmp[i] = y[i] + 0.5 * h * k2[i];
    }
    model.eval(t + 0.5 * h, &tmp, ctx, &mut k3, &mut aux);
    for i in 0..N {
        tmp[i] = y[i] + h * k3[i];
    }
    model.eval(t + h, &tmp, ctx, &mut k4, &mut aux);
    let h6 = h / 6.0;
    for i in 0..N {
        y[i] += h6 * (k1[i] + 2.0 * (k2[i] + k3[i]) + k4[i]);
    }
    aux
}

/// Where the stages of [`rk4_step_shared`] take their tire outputs from.
#[derive(Debug, Clone, Copy)]
pub enum StageTires<'a> {
    /// Evaluated exactly at every stage (warm-started slip inversion, `ctx.warm_slip`).
    Exact,
    /// Multirate: `now` (exact at the step start) extrapolated linearly in time through
    /// `prev` (exact at the previous step start, `h_prev` earlier): stage time t + c·h gets
    /// `now + (c·h/h_prev)·(now − prev)`. With `prev == now` the outputs are held.
    Extrapolated {
        now: &'a TireOut,
        prev: &'a TireOut,
        h_prev: f64,
    },
    /// Multirate, Lagrange: the first `n` (1–3) of `f`, exact at the times `off` relative to
    /// the step start (≤ 0, distinct); stage time t + c·h gets the polynomial through them
    /// (held, linear or parabolic).
    Lagrange {
        f: &'a [TireOut; 3],
        off: [f64; 3],
        n: usize,
    },
}

/// Lagrange weights at `tau` of the first `n` nodes `off`.
#[inline(always)]
fn lagrange_weights(off: [f64; 3], n: usize, tau: f64) -> [f64; 3] {
    match n {
        1 => [1.0, 0.0, 0.0],
        2 => {
            let w1 = (tau - off[0]) / (off[1] - off[0]);
            [1.0 - w1, w1, 0.0]
        }
        _ => {
            let (a, b, c) = (off[0], off[1], off[2]);
            [
                (tau - b) * (tau - c) / ((a - b) * (a - c)),
                (tau - a) * (tau - c) / ((b - a) * (b - c)),
                (tau - a) * (tau - b) / ((c - a) * (c - b)),
            ]
        }
    }
}

/// One classical RK4 step like [`rk4_step`], but the sines and cosines of the stage states are
/// shifted from `tr0` (those of `y` at the step start) by angle addition (exact to rounding,
/// no libm call for small increments), and the tire outputs come from `tires`. Returns the
/// by-products of the last stage and the largest penetration δ of a clearance joint seen at
/// any stage (negative while no stage is in contact). With `stages`, the four stage slopes
/// k1–k4 are copied there for [`rk4_dense`].
#[inline]
#[allow(clippy::too_many_arguments)]
pub fn rk4_step_shared(
    model: &Model,
    t: f64,
    y: &mut State,
    h: f64,
    ctx: &StepCtx,
    tr0: &Trig,
    tires: StageTires,
    stages: Option<&mut [State; 4]>,
) -> (Aux, f64) {
    let mut aux = Aux::default();
    let mut k1 = [0.0; N];
    let mut k2 = [0.0; N];
    let mut k3 = [0.0; N];
    let mut k4 = [0.0; N];
    let mut tmp = [0.0; N];
    let y0 = *y;
    let mut max_delta = f64::NEG_INFINITY;
    let mut stage = |c: f64, ys: &State, tr: &Trig, k: &mut State, aux: &mut Aux| {
        match tires {
            StageTires::Exact => model.eval_with(t + c * h, ys, ctx, tr, None, k, aux),
            StageTires::Extrapolated { now, prev, h_prev } => {
                let held = now.extrapolate(prev, c * h / h_prev);
                model.eval_with(t + c * h, ys, ctx, tr, Some(&held), k, aux)
            }
            StageTires::Lagrange { f, off, n } => {
                let held = TireOut::combine(f, lagrange_weights(off, n, c * h));
                model.eval_with(t + c * h, ys, ctx, tr, Some(&held), k, aux)
            }
        }
        for i in 0..2 {
            if model.has_clearance(i) {
                max_delta = max_delta.max(aux.joint[i].delta);
            }
        }
    };
    stage(0.0, &y0, tr0, &mut k1, &mut aux);
    for i in 0..N {
        tmp[i] = y0[i] + 0.5 * h * k1[i];
    }
    stage(0.5, &tmp, &tr0.shifted(model, &y0, &tmp), &mut k2, &mut aux);
    for i in 0..N {
        tmp[i] = y0[i] + 0.5 * h * k2[i];
    }
    stage(0.5, &tmp, &tr0.shifted(model, &y0, &tmp), &mut k3, &mut aux);
    for i in 0..N {
        tmp[i] = y0[i] + h * k3[i];
    }
    stage(1.0, &tmp, &tr0.shifted(model, &y0, &tmp), &mut k4, &mut aux);
    let h6 = h / 6.0;
    for i in 0..N {
        y[i] += h6 * (k1[i] + 2.0 * (k2[i] + k3[i]) + k4[i]);
    }
    if let Some(k) = stages {
        *k = [k1, k2, k3, k4];
    }
    (aux, max_delta)
}

/// Dense output of a classical RK4 step of length `h` from `y0` with stage slopes `k`: the
/// state at t + θ·h (0 ≤ θ ≤ 1) by the third-order continuous extension of the classical
/// RK4 (Hairer, Nørsett & Wanner, *Solving ODEs I*, §II.6): y0 + h·Σ b_i(θ)·k_i with
/// b1 = θ − 3θ²/2 + 2θ³/3, b2 = b3 = θ² − 2θ³/3, b4 = −θ²/2 + 2θ³/3. It needs no extra
/// right-hand side, and at θ = 1 it is the step's end value.
#[inline]
pub fn rk4_dense(y0: &State, k: &[State; 4], h: f64, theta: f64) -> State {
    let (t2, t3) = (theta * theta, theta * theta * theta);
    let b1 = theta - 1.5 * t2 + t3 * (2.0 / 3.0);
    let b23 = t2 - t3 * (2.0 / 3.0);
    let b4 = -0.5 * t2 + t3 * (2.0 / 3.0);
    let mut y = *y0;
    for i in 0..N {
        y[i] += h * (b1 * k[0][i] + b23 * (k[1][i] + k[2][i]) + b4 * k[3][i]);
    }
    y
}
