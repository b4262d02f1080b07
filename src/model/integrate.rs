//! Integrators (MODEL.md §10): the classical fixed-step RK4 of the paper. Works on the
//! fixed-size state of `rhs`; nothing here allocates.
//!
//! What it is: one step of the scheme, given the values held over the step. What it is not:
//! the step-boundary updates of contact flags, impact velocities and noise (`sim`).

use super::rhs::{Aux, Model, State, StepCtx, N};

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
