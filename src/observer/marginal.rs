//! Clearance posterior with the vehicle's nuisances marginalised continuously (estimator
//! `method = "linear"`), on the response table's linear nuisance model ([`super::linear`]).
//!
//! What it is: for each clearance c_g of a fine grid (the table's clearances, each log step cut
//! into `grid_refine` parts, the model's coefficients interpolated linearly in ln c), the
//! evidence of all of a vehicle's events with its unknown nuisances integrated out. The
//! kingpin damping coordinate ξ₁, which the features depend on nonlinearly
//! ([`super::linear`]), is integrated on a grid of `damping_grid` points (the midpoints of
//! equal bins of its uniform prior on [−1, 1]). Given (c_g, ξ₁), the latent vector
//! x = (ξ_j≠1, η) ∈ R⁹ holds the other six coordinates (prior: the uniform [−1, 1] replaced by
//! the normal of the same variance 1/3) and the three features' per-vehicle misfit
//! η ~ N(0, T_c). Each event e gives
//!
//!   z_e = a_e(c, ξ₁) + H_e(c, ξ₁)·x + ε_e,   H_e = [B_e | I₃],   ε_e ~ N(0, k²·Σ_c),
//!
//! (a, B: the model at the event's speed and deceleration; Σ, T: its within- and
//! between-vehicle covariances; k = `std_inflation`), so x is shared by the events and
//! conjugate: the sufficient statistics P = Σ_e Hᵀ Σ⁻¹ H (9 × 9), h = Σ_e Hᵀ Σ⁻¹ r_e,
//! s = Σ_e r_eᵀ Σ⁻¹ r_e and Σ_e ln det Σ (r_e = z_e − a_e) give
//!
//!   ln p(z | c, ξ₁) = −½ (s − hᵀ A⁻¹ h) − ½ ln det A + ½ ln det Λ₀ − ½ Σ_e ln det Σ + const,
//!   A = Λ₀ + P,  Λ₀ = prior precision of x,
//!
//! and p(z | c) is the mean over the ξ₁ grid.
//!
//! Why: the nuisances are a vehicle's and are the same in all its events. The table's M drawn
//! vehicles sample them; a mixture over those points (method `"mixture"`) needs a likelihood
//! wide enough to cover the distance from the true vehicle to the nearest drawn one, which
//! blurs the clearance (docs/ACCURACY.md "What limits the estimate"). Marginalising over the
//! continuum keeps each event's own scatter.
//!
//! Wear: before each event all statistics are multiplied by 2^(−distance / half-life): old
//! evidence fades, so the estimate follows a clearance that grows with distance.
//!
//! What it is not: a nonlinear model (what the linear law misses for a vehicle is η, a
//! Gaussian) or robust to outlier events (the Gaussian has no outlier floor).
//!
//! Memory: the statistics are fixed-size per (clearance, damping) grid point (about 100
//! numbers), allocated in [`LinearPosterior::new`]; updates and summaries do not allocate.

use nalgebra::{Matrix3, SMatrix, SVector};

use super::estimator::EstimatorConfig;
use super::linear::{LinearModel, N_FEAT, N_LIN};
use super::table::{bracket, ResponseTable};

const NX: usize = N_LIN + N_FEAT;
type MatX = SMatrix<f64, NX, NX>;
type VecX = SVector<f64, NX>;

/// Variance of the uniform [−1, 1] prior of each nuisance coordinate.
const COORD_VAR: f64 = 1.0 / 3.0;

#[derive(Clone, Copy)]
struct Stats {
    p: MatX,
    h: VecX,
    s: f64,
    ld: f64,
}

impl Stats {
    fn zero() -> Stats {
        Stats {
            p: MatX::zeros(),
            h: VecX::zeros(),
            s: 0.0,
            ld: 0.0,
        }
    }
}

/// Which features enter: ln RMS, ln peak, cruise.
pub type FeatureMask = [bool; N_FEAT];

/// The running posterior of method `"linear"`. It keeps its own copy of the table's linear
/// model and speed axis, so an update cannot be handed another table's model.
pub struct LinearPosterior {
    model: LinearModel,
    speed_kmh: Vec<f64>,
    /// The fine clearance grid's positions on the table's clearance axis ([`fine_grid`]).
    pos: Vec<(usize, f64)>,
    /// The damping coordinate's grid.
    xi1: Vec<f64>,
    /// Statistics, index `g · xi1.len() + k`.
    stats: Vec<Stats>,
    /// Scratch: ln p(z | c_g, ξ₁ₖ) of one clearance.
    scratch: Vec<f64>,
    /// ln det Λ₀ and Λ₀'s η block per grid point (T_c⁻¹ / k²).
    prior: Vec<(MatX, f64)>,
    inflation2: f64,
    half_life_km: f64,
    /// Power on the likelihood (tempering, 0 < power ≤ 1).
    power: f64,
}

/// Inverse and ln det of the masked block of `m` (unused features: zero rows and columns).
fn masked_inverse(m: &Matrix3<f64>, mask: &FeatureMask) -> Option<(Matrix3<f64>, f64)> {
    let mut a = *m;
    for i in 0..N_FEAT {
        if !mask[i] {
            for j in 0..N_FEAT {
                a[(i, j)] = 0.0;
                a[(j, i)] = 0.0;
            }
            a[(i, i)] = 1.0;
        }
    }
    let ch = a.cholesky()?;
    let ld = ch.ln_determinant();
    let mut inv = ch.inverse();
    for i in 0..N_FEAT {
        if !mask[i] {
            for j in 0..N_FEAT {
                inv[(i, j)] = 0.0;
                inv[(j, i)] = 0.0;
            }
        }
    }
    Some((inv, ld))
}

/// The fine clearance grid: each log step of `clearance_mm` cut into `refine` parts. Returns ln c
/// (mm) of each point and its position on the table's axis (index, weight of the next).
pub fn fine_grid(clearance_mm: &[f64], refine: usize) -> (Vec<f64>, Vec<(usize, f64)>) {
    let refine = refine.max(1);
    let n = clearance_mm.len();
    let mut ln_c = Vec::with_capacity((n - 1) * refine + 1);
    let mut pos = Vec::with_capacity(ln_c.capacity());
    for ic in 0..n - 1 {
        let (a, b) = (clearance_mm[ic].ln(), clearance_mm[ic + 1].ln());
        for j in 0..refine {
            let w = j as f64 / refine as f64;
            ln_c.push(a + w * (b - a));
            pos.push((ic, w));
        }
    }
    ln_c.push(clearance_mm[n - 1].ln());
    pos.push((n - 2, 1.0));
    (ln_c, pos)
}

impl LinearPosterior {
    /// A flat posterior over the grid points `pos` ([`fine_grid`]) of `table`, with the
    /// estimator settings `cfg` (checked by [`EstimatorConfig::validate`]).
    pub fn new(
        table: &ResponseTable,
        model: &LinearModel,
        pos: Vec<(usize, f64)>,
        cfg: &EstimatorConfig,
    ) -> anyhow::Result<LinearPosterior> {
        let nk = cfg.damping_grid.max(1);
        let xi1: Vec<f64> = (0..nk)
            .map(|k| -1.0 + (2 * k + 1) as f64 / nk as f64)
            .collect();
        let inflation2 = cfg.std_inflation * cfg.std_inflation;
        let mut prior = Vec::with_capacity(pos.len());
        for &p in &pos {
            // The configured vehicle-level misfit (measured vehicles against the model's), and a
            // small floor that keeps T invertible where the fit found none.
            let floor = 1e-4 + cfg.misfit_std * cfg.misfit_std;
            let t = (model.between_at(p) + Matrix3::identity() * floor) * inflation2;
            let ch = t
                .cholesky()
                .ok_or_else(|| anyhow::anyhow!("linear model: misfit covariance not positive"))?;
            let t_inv = ch.inverse();
            let mut lam = MatX::zeros();
            for i in 0..N_LIN {
                lam[(i, i)] = 1.0 / COORD_VAR;
            }
            for i in 0..N_FEAT {
                for j in 0..N_FEAT {
                    lam[(N_LIN + i, N_LIN + j)] = t_inv[(i, j)];
                }
            }
            let ld_lam = -(N_LIN as f64) * COORD_VAR.ln() - ch.ln_determinant();
            prior.push((lam, ld_lam));
        }
        Ok(LinearPosterior {
            model: model.clone(),
            speed_kmh: table.speed_kmh.clone(),
            stats: vec![Stats::zero(); pos.len() * nk],
            scratch: vec![0.0; nk],
            xi1,
            pos,
            prior,
            inflation2,
            half_life_km: cfg.evidence_half_life_km,
            power: cfg.evidence_power,
        })
    }

    /// Fades the evidence over `dist_km` of driving.
    pub fn forget(&mut self, dist_km: f64) {
        let fades = self.half_life_km > 0.0 && dist_km > 0.0;
        if !fades {
            return;
        }
        let f = (-(dist_km / self.half_life_km) * std::f64::consts::LN_2).exp();
        for st in &mut self.stats {
            st.p *= f;
            st.h *= f;
            st.s *= f;
            st.ld *= f;
        }
    }

    /// Adds one event: features `z` (ln RMS, ln peak, cruise; masked ones ignored) at initial
    /// speed `v0_kmh` and deceleration `decel_g`.
    pub fn update(&mut self, z: [f64; N_FEAT], mask: &FeatureMask, v0_kmh: f64, decel_g: f64) {
        let sp = bracket(&self.speed_kmh, v0_kmh);
        let nk = self.xi1.len();
        for (g, stats) in self.stats.chunks_mut(nk).enumerate() {
            // The event scatter depends on the clearance only: one inverse per grid clearance.
            let sigma = self.model.within_at(self.pos[g]) * self.inflation2;
            let Some((w, ld)) = masked_inverse(&sigma, mask) else {
                continue;
            };
            for (st, &xi1) in stats.iter_mut().zip(&self.xi1) {
                let pr = self.model.predict(self.pos[g], sp, decel_g, xi1);
                let mut hm = SMatrix::<f64, N_FEAT, NX>::zeros();
                for f in 0..N_FEAT {
                    for j in 0..N_LIN {
                        hm[(f, j)] = pr.b[f][j];
                    }
                    hm[(f, N_LIN + f)] = 1.0;
                }
                let r =
                    nalgebra::Vector3::from_fn(|f, _| if mask[f] { z[f] - pr.a[f] } else { 0.0 });
                let ht_w = hm.transpose() * w;
                st.p += ht_w * hm;
                st.h += ht_w * r;
                st.s += (r.transpose() * w * r)[(0, 0)];
                st.ld += ld;
            }
        }
    }

    /// Writes the normalised posterior probabilities of the grid points into `out` (one per
    /// point of [`fine_grid`]).
    pub fn probabilities_into(&mut self, out: &mut [f64]) {
        let mut mx = f64::NEG_INFINITY;
        let nk = self.xi1.len();
        for (g, o) in out.iter_mut().enumerate().take(self.pos.len()) {
            let (lam, ld_lam) = &self.prior[g];
            for k in 0..nk {
                let st = &self.stats[g * nk + k];
                let a = lam + st.p;
                self.scratch[k] = match a.cholesky() {
                    Some(ch) => {
                        let q = st.h.dot(&ch.solve(&st.h));
                        -0.5 * (st.s - q) - 0.5 * ch.ln_determinant() + 0.5 * ld_lam - 0.5 * st.ld
                    }
                    None => f64::NEG_INFINITY,
                };
            }
            // ln of the mean over the damping grid.
            let m = self
                .scratch
                .iter()
                .copied()
                .fold(f64::NEG_INFINITY, f64::max);
            let l = if m.is_finite() {
                m + (self.scratch.iter().map(|x| (x - m).exp()).sum::<f64>() / nk as f64).ln()
            } else {
                f64::NEG_INFINITY
            };
            *o = self.power * l;
            mx = mx.max(*o);
        }
        if !mx.is_finite() {
            out.fill(1.0 / out.len() as f64);
            return;
        }
        let mut sum = 0.0;
        for l in out.iter_mut() {
            *l = (*l - mx).exp();
            sum += *l;
        }
        for l in out.iter_mut() {
            *l /= sum;
        }
    }
}
