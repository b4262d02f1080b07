//! Clearance posterior with the vehicle's nuisances marginalised (estimator `method =
//! "linear"`), on the response table's nuisance model ([`super::linear`]).
//!
//! What it is: for each clearance c_g of a fine grid (the table's clearances, each log step cut
//! into `grid_refine` parts, the model's coefficients interpolated linearly in ln c), the
//! evidence of all of a vehicle's events with its unknown nuisances integrated out.
//!
//! * The coordinates the features depend on nonlinearly are integrated on grids (the midpoints
//!   of equal bins of their uniform priors on [−1, 1]): the kingpin damping ξ₁ (`damping_grid`
//!   points), any other coordinate the table's model grids (`unbalance_grid` points), and the
//!   wheels' unbalance phase difference Δ (below).
//! * Given those, the latent vector x = (ξ_closed-form, η) ∈ R⁹ holds the other coordinates
//!   (prior: the uniform [−1, 1] replaced by the normal of the same variance 1/3; coordinates
//!   the model grids keep a zero column and their prior only) and the three features'
//!   per-vehicle misfit η ~ N(0, T_c). Each event e gives
//!
//!   z_e = a_e + H_e·x + ε_e,   H_e = [B_e | I₃],   ε_e ~ N(0, k²·Σ_c + V_e),
//!
//!   (a, B: the model at the event's speed and deceleration; Σ, T: its within- and
//!   between-vehicle covariances; k = `std_inflation`; V_e below), so x is shared by the events
//!   and conjugate: the sufficient statistics P = Σ_e Hᵀ S⁻¹ H (9 × 9), h = Σ_e Hᵀ S⁻¹ r_e,
//!   s = Σ_e r_eᵀ S⁻¹ r_e and Σ_e ln det S (r_e = z_e − a_e, S the event's covariance) give
//!
//!   ln p(z | c, grid point) = −½ (s − hᵀ A⁻¹ h) − ½ ln det A + ½ ln det Λ₀ − ½ Σ_e ln det S + const,
//!
//!   A = Λ₀ + P,  Λ₀ = prior precision of x,
//!
//!   and p(z | c) is the mean over the grid points.
//!
//! The unbalance phase difference Δ = φ_R − φ_L (ψ = cos Δ, MODEL.md §7): both wheels turn
//! with one spin angle, so Δ stays what it is while the wheels roll together and changes when
//! they do not (a turn, unequal rolling radii). `phase` says which:
//! * `"vehicle"`: Δ is the same for all of the vehicle's events, integrated on a grid of
//!   `phase_grid` points (Δ uniform on [0, π]; its sign does not matter, the vehicle is
//!   symmetric);
//! * `"event"`: Δ is new in every event. Its effect is averaged out of each event's prediction
//!   on a 16-point quadrature, a_e the mean and V_e the covariance of the prediction over Δ;
//! * `"either"` (the default): both hypotheses, each with prior weight ½, so that the events
//!   decide. On 80 held-out vehicles with 30 events each (docs/ACCURACY.md), P(fixed) was above
//!   ½ for 60 of 80 whose Δ was fixed and for 13 of 80 whose Δ changed at every stop: the
//!   events lean the right way, but not always.
//!
//! Wear: before each event all statistics are multiplied by 2^(−distance / half-life): old
//! evidence fades, so the estimate follows a clearance that grows with distance.
//!
//! Baseline ([`LinearPosterior::update_known`]): events of the same vehicle at a known
//! clearance c_b (its first events after the joints were replaced) share its x (nuisances and
//! misfit η) with the later events but not their clearance. Their statistics are kept apart,
//! computed once at c_b, and each clearance's evidence becomes the conditional one,
//!
//!   p(z | c, baseline) = Σ_q p(z, z_b | c, c_b, q) / Σ_q p(z_b | c_b, q)
//!
//! over the grid points q (numerator: the sum of both statistics), so what the baseline events
//! say about η (a transfer, sensor gain or noise floor the table's model misses, all of which
//! move ln RMS and ln peak by a constant) is subtracted from the later events instead of being
//! read as clearance. The baseline does not fade with distance (it describes the vehicle, not
//! its wear) and does not count in the goodness-of-fit's degrees of freedom.
//!
//! What it is not: robust to outlier events (the Gaussian has no outlier floor), or a model of
//! the physics (the table's model stands for it).
//!
//! Memory: the statistics are fixed-size per (clearance, grid point) (about 100 numbers),
//! allocated with the scratch of one event's term values in [`LinearPosterior::new`]; updates
//! and summaries do not allocate.

use nalgebra::{Matrix3, SMatrix, SVector};

use super::emulate::{phase_quadrature, EVENT_PHASES};
use super::estimator::EstimatorConfig;
use super::linear::{Basis, Coefs, LinearModel, N_FEAT, N_LIN, N_VARS, PHASE};
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

    fn add(
        &mut self,
        pr: &super::linear::LinearPrediction,
        z: &[f64; N_FEAT],
        mask: &FeatureMask,
        w: &Matrix3<f64>,
        ld: f64,
    ) {
        let mut hm = SMatrix::<f64, N_FEAT, NX>::zeros();
        for f in 0..N_FEAT {
            for j in 0..N_LIN {
                hm[(f, j)] = pr.b[f][j];
            }
            hm[(f, N_LIN + f)] = 1.0;
        }
        let r = nalgebra::Vector3::from_fn(|f, _| if mask[f] { z[f] - pr.a[f] } else { 0.0 });
        let ht_w = hm.transpose() * w;
        self.p += ht_w * hm;
        self.h += ht_w * r;
        self.s += (r.transpose() * w * r)[(0, 0)];
        self.ld += ld;
    }

    /// The statistics of both sets of events.
    fn plus(&self, o: &Stats) -> Stats {
        Stats {
            p: self.p + o.p,
            h: self.h + o.h,
            s: self.s + o.s,
            ld: self.ld + o.ld,
        }
    }

    /// ln p(events | grid point) up to a constant, with prior precision `lam` (ln det `ld_lam`),
    /// and the events' deviance at the grid point: s − hᵀA⁻¹h, which by the Woodbury identity
    /// is rᵀ(S + H Λ₀⁻¹ Hᵀ)⁻¹ r over all the events' residuals r, i.e. χ² with as many degrees
    /// of freedom as features observed when the events follow the model at this point.
    fn evidence(&self, lam: &MatX, ld_lam: f64) -> (f64, f64) {
        let a = lam + self.p;
        match a.cholesky() {
            Some(ch) => {
                let q = self.h.dot(&ch.solve(&self.h));
                let dev = self.s - q;
                (
                    -0.5 * dev - 0.5 * ch.ln_determinant() + 0.5 * ld_lam - 0.5 * self.ld,
                    dev,
                )
            }
            None => (f64::NEG_INFINITY, f64::INFINITY),
        }
    }
}

/// Which features enter: ln RMS, ln peak, cruise.
pub type FeatureMask = [bool; N_FEAT];

/// How the unbalance phase difference is treated (`[estimator] phase`).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum PhaseMode {
    Vehicle,
    Event,
    Either,
}

impl PhaseMode {
    pub fn parse(s: &str) -> Option<PhaseMode> {
        match s {
            "vehicle" => Some(PhaseMode::Vehicle),
            "event" => Some(PhaseMode::Event),
            "either" => Some(PhaseMode::Either),
            _ => None,
        }
    }
}

/// The running posterior of method `"linear"`. It keeps its own copy of the table's nuisance
/// model and speed axis, so an update cannot be handed another table's model.
pub struct LinearPosterior {
    model: LinearModel,
    speed_kmh: Vec<f64>,
    /// The fine clearance grid's positions on the table's clearance axis ([`fine_grid`]).
    pos: Vec<(usize, f64)>,
    /// Grid points of the gridded coordinates with Δ fixed per vehicle (hypothesis "vehicle":
    /// ψ set), and without ψ (hypothesis "event").
    points_v: Vec<[f64; N_VARS]>,
    points_e: Vec<[f64; N_VARS]>,
    /// Statistics, index `g · points.len() + q`, per hypothesis.
    stats_v: Vec<Stats>,
    stats_e: Vec<Stats>,
    /// Scratch: one event's term values at each grid point of "vehicle", and at each grid
    /// point × quadrature phase of "event".
    basis_v: Vec<Basis>,
    basis_e: Vec<Basis>,
    /// Scratch: the mean over the quadrature phases of `basis_e`, per grid point of "event".
    basis_e_mean: Vec<Basis>,
    /// Scratch: ln p(z | c_g, point) of one clearance (and, with a baseline, of the baseline
    /// alone in `scratch_base`).
    scratch: Vec<f64>,
    scratch_base: Vec<f64>,
    /// Statistics of the baseline events (known clearance), per grid point of "vehicle" then
    /// of "event"; empty until the first one.
    baseline: Vec<Stats>,
    baseline_obs: f64,
    /// Where on the table's clearance axis the baseline events were (the last one's).
    baseline_pos: (usize, f64),
    /// Σ over the baseline events of ln dz_table/dz_measured.
    baseline_ln_jacobian: f64,
    /// Variance added to the model's misfit covariance T (ln units²), and added on top of it
    /// once there is a baseline.
    misfit_var: f64,
    baseline_misfit_var: f64,
    /// Scratch: ln p(events | c_g) + ln prior(c_g), without the evidence power, per grid point.
    scratch_raw: Vec<f64>,
    /// Λ₀ and ln det Λ₀ per clearance grid point (η block T_c⁻¹ / k²).
    prior: Vec<(MatX, f64)>,
    inflation2: f64,
    half_life_km: f64,
    /// Power on the likelihood (tempering, 0 < power ≤ 1).
    power: f64,
    /// Scratch: the share of hypothesis "vehicle" in each clearance's evidence.
    share_v: Vec<f64>,
    /// Posterior probability of hypothesis "vehicle" (NaN when only one is in use).
    p_vehicle: f64,
    /// Features observed so far (faded with the evidence): the deviance's degrees of freedom.
    n_obs: f64,
    /// Smallest deviance over the clearances and grid points, after the last
    /// [`Self::probabilities_into`].
    min_deviance: f64,
    /// ln of the events' marginal likelihood under the table's model (over the clearance prior
    /// and the nuisances), with and without the evidence power, after the last
    /// [`Self::probabilities_into`].
    ln_evidence: [f64; 2],
    /// Σ over the events of ln dz_table/dz_measured (a transfer gain other than 1), faded
    /// with the evidence.
    ln_jacobian: f64,
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

/// Λ₀ and ln det Λ₀ per clearance grid point: the coordinates' prior (variance 1/3 each) and
/// the misfit's, T_c (the model's between-vehicle covariance) plus `misfit_var` on its
/// diagonal, times `inflation2`.
fn build_prior(
    model: &LinearModel,
    pos: &[(usize, f64)],
    misfit_var: f64,
    inflation2: f64,
) -> anyhow::Result<Vec<(MatX, f64)>> {
    let mut prior = Vec::with_capacity(pos.len());
    for &p in pos {
        let t = (model.between_at(p) + Matrix3::identity() * misfit_var) * inflation2;
        let ch = t
            .cholesky()
            .ok_or_else(|| anyhow::anyhow!("nuisance model: misfit covariance not positive"))?;
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
    Ok(prior)
}

/// The position of clearance `c_mm` on a clearance axis, as [`fine_grid`]'s positions are:
/// (interval, fraction in ln c), clamped to the axis.
pub fn axis_position(clearance_mm: &[f64], c_mm: f64) -> (usize, f64) {
    let n = clearance_mm.len();
    if n < 2 || c_mm <= clearance_mm[0] {
        return (0, 0.0);
    }
    for ic in 0..n - 1 {
        let (a, b) = (clearance_mm[ic], clearance_mm[ic + 1]);
        if c_mm <= b {
            return (ic, (c_mm / a).ln() / (b / a).ln());
        }
    }
    (n - 2, 1.0)
}

/// Midpoints of `n` equal bins of [−1, 1].
fn midpoints(n: usize) -> Vec<f64> {
    let n = n.max(1);
    (0..n)
        .map(|k| -1.0 + (2 * k + 1) as f64 / n as f64)
        .collect()
}

/// ln of the mean of exp over `xs` (−∞ when all are).
fn log_mean_exp(xs: &[f64]) -> f64 {
    let m = xs.iter().copied().fold(f64::NEG_INFINITY, f64::max);
    if !m.is_finite() {
        return f64::NEG_INFINITY;
    }
    m + (xs.iter().map(|x| (x - m).exp()).sum::<f64>() / xs.len() as f64).ln()
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
        let mut mode = PhaseMode::parse(&cfg.phase)
            .ok_or_else(|| anyhow::anyhow!("estimator.phase: unknown `{}`", cfg.phase))?;
        if !model.has_phase() {
            // The table's model does not know Δ: its event scatter already holds it.
            mode = PhaseMode::Event;
        }
        // The gridded coordinates' points (ψ = 0).
        let mut points: Vec<[f64; N_VARS]> = vec![[0.0; N_VARS]];
        for (i, j) in model.grid_coords().into_iter().enumerate() {
            let values = midpoints(if i == 0 {
                cfg.damping_grid
            } else {
                cfg.unbalance_grid
            });
            points = points
                .iter()
                .flat_map(|p| {
                    values.iter().map(move |&v| {
                        let mut q = *p;
                        q[j] = v;
                        q
                    })
                })
                .collect();
        }
        let points_v: Vec<[f64; N_VARS]> = if mode == PhaseMode::Event {
            Vec::new()
        } else {
            points
                .iter()
                .flat_map(|p| {
                    phase_quadrature(cfg.phase_grid).map(move |u| {
                        let mut q = *p;
                        q[PHASE] = u;
                        q
                    })
                })
                .collect()
        };
        let points_e = if mode == PhaseMode::Vehicle {
            Vec::new()
        } else {
            points
        };
        let n_quad = if model.has_phase() { EVENT_PHASES } else { 1 };
        let inflation2 = cfg.std_inflation * cfg.std_inflation;
        // The configured vehicle-level misfit (measured vehicles against the model's), and a
        // small floor that keeps T invertible where the fit found none.
        let misfit_var = 1e-4 + cfg.misfit_std * cfg.misfit_std;
        let prior = build_prior(model, &pos, misfit_var, inflation2)?;
        let ng = pos.len();
        Ok(LinearPosterior {
            model: model.clone(),
            speed_kmh: table.speed_kmh.clone(),
            stats_v: vec![Stats::zero(); ng * points_v.len()],
            stats_e: vec![Stats::zero(); ng * points_e.len()],
            basis_v: vec![Basis::default(); points_v.len()],
            basis_e: vec![Basis::default(); points_e.len() * n_quad],
            basis_e_mean: vec![Basis::default(); points_e.len()],
            scratch: vec![0.0; points_v.len().max(points_e.len())],
            scratch_base: Vec::new(),
            baseline: Vec::new(),
            baseline_obs: 0.0,
            baseline_pos: (0, 0.0),
            baseline_ln_jacobian: 0.0,
            misfit_var,
            baseline_misfit_var: cfg.baseline_misfit_std * cfg.baseline_misfit_std,
            points_v,
            points_e,
            pos,
            prior,
            inflation2,
            half_life_km: cfg.evidence_half_life_km,
            power: cfg.evidence_power,
            share_v: vec![0.0; ng],
            scratch_raw: vec![0.0; ng],
            p_vehicle: f64::NAN,
            n_obs: 0.0,
            min_deviance: f64::NAN,
            ln_evidence: [f64::NAN; 2],
            ln_jacobian: 0.0,
        })
    }

    /// Grid points per clearance (both hypotheses).
    pub fn points(&self) -> usize {
        self.points_v.len() + self.points_e.len()
    }

    /// Fades the evidence over `dist_km` of driving.
    pub fn forget(&mut self, dist_km: f64) {
        let fades = self.half_life_km > 0.0 && dist_km > 0.0;
        if !fades {
            return;
        }
        let f = (-(dist_km / self.half_life_km) * std::f64::consts::LN_2).exp();
        for st in self.stats_v.iter_mut().chain(self.stats_e.iter_mut()) {
            st.p *= f;
            st.h *= f;
            st.s *= f;
            st.ld *= f;
        }
        self.n_obs *= f;
        self.ln_jacobian *= f;
    }

    /// Adds one event's ln dz_table/dz_measured ([`super::features::ln_jacobian_gain`]) to
    /// the evidence.
    pub fn add_ln_jacobian(&mut self, ln_jac: f64) {
        self.ln_jacobian += ln_jac;
    }

    /// Adds one event: features `z` (ln RMS, ln peak, cruise; masked ones ignored) at initial
    /// speed `v0_kmh` and deceleration `decel_g`.
    pub fn update(&mut self, z: [f64; N_FEAT], mask: &FeatureMask, v0_kmh: f64, decel_g: f64) {
        self.n_obs += mask.iter().filter(|&&m| m).count() as f64;
        let sp = bracket(&self.speed_kmh, v0_kmh);
        self.event_basis(decel_g);
        let (nv, ne) = (self.points_v.len(), self.points_e.len());
        let (mut stats_v, mut stats_e) = (
            std::mem::take(&mut self.stats_v),
            std::mem::take(&mut self.stats_e),
        );
        for (g, &pos) in self.pos.iter().enumerate() {
            let (sv, se) = (
                &mut stats_v[g * nv..(g + 1) * nv],
                &mut stats_e[g * ne..(g + 1) * ne],
            );
            self.add_at(pos, sp, &z, mask, sv, se);
        }
        (self.stats_v, self.stats_e) = (stats_v, stats_e);
    }

    /// Adds one event of the same vehicle at a known clearance, at `pos` on the table's
    /// clearance axis ([`axis_position`]): a baseline event (module doc). Allocates the
    /// baseline's statistics at the first one.
    pub fn update_known(
        &mut self,
        z: [f64; N_FEAT],
        mask: &FeatureMask,
        v0_kmh: f64,
        decel_g: f64,
        pos: (usize, f64),
    ) {
        let (nv, ne) = (self.points_v.len(), self.points_e.len());
        if self.baseline.is_empty() {
            self.baseline = vec![Stats::zero(); nv + ne];
            self.scratch_base = vec![0.0; nv.max(ne)];
            if self.baseline_misfit_var > 0.0 {
                let var = self.misfit_var + self.baseline_misfit_var;
                if let Ok(p) = build_prior(&self.model, &self.pos, var, self.inflation2) {
                    self.prior = p;
                }
            }
        }
        self.baseline_obs += mask.iter().filter(|&&m| m).count() as f64;
        self.baseline_pos = pos;
        let sp = bracket(&self.speed_kmh, v0_kmh);
        self.event_basis(decel_g);
        let mut base = std::mem::take(&mut self.baseline);
        let (bv, be) = base.split_at_mut(nv);
        self.add_at(pos, sp, &z, mask, bv, be);
        self.baseline = base;
    }

    /// Adds one baseline event's ln dz_table/dz_measured (a gain other than 1) to the
    /// baseline's evidence.
    pub fn add_baseline_ln_jacobian(&mut self, ln_jac: f64) {
        self.baseline_ln_jacobian += ln_jac;
    }

    /// ln of the baseline events' marginal likelihood at their clearance (the position of
    /// the last one), the vehicle's coordinates and misfit integrated out under the prior
    /// this posterior was built with, both phase hypotheses in use weighted ½, with the
    /// evidence power and the Jacobian of any gain; up to a constant that depends only on the
    /// number of features observed. `None` before a baseline event. Allocates (the prior at
    /// one position): for fits, not for the per-frame path.
    pub fn baseline_ln_evidence(&self) -> Option<f64> {
        if self.baseline.is_empty() {
            return None;
        }
        let var = self.misfit_var + self.baseline_misfit_var;
        let prior = build_prior(&self.model, &[self.baseline_pos], var, self.inflation2).ok()?;
        let (lam, ld_lam) = &prior[0];
        let nv = self.points_v.len();
        let (bv, be) = self.baseline.split_at(nv);
        let hyp = |stats: &[Stats]| -> f64 {
            if stats.is_empty() {
                return f64::NEG_INFINITY;
            }
            let ls: Vec<f64> = stats.iter().map(|st| st.evidence(lam, *ld_lam).0).collect();
            log_mean_exp(&ls)
        };
        let (l_v, l_e) = (hyp(bv), hyp(be));
        let l = match (bv.is_empty(), be.is_empty()) {
            (false, false) => log_mean_exp(&[l_v, l_e]),
            (false, true) => l_v,
            _ => l_e,
        };
        let l = self.power * (l + self.baseline_ln_jacobian);
        l.is_finite().then_some(l)
    }

    /// Baseline events added ([`Self::update_known`]), as features observed.
    pub fn baseline_features(&self) -> f64 {
        self.baseline_obs
    }

    /// The event's term values at every grid point (they do not depend on the clearance).
    fn event_basis(&mut self, decel_g: f64) {
        for (b, x) in self.basis_v.iter_mut().zip(&self.points_v) {
            self.model.basis_into(x, decel_g, b);
        }
        let n_quad = self.basis_e.len() / self.points_e.len().max(1);
        for (i, x) in self.points_e.iter().enumerate() {
            for (k, u) in phase_quadrature(n_quad).enumerate() {
                let mut y = *x;
                y[PHASE] = u;
                self.model
                    .basis_into(&y, decel_g, &mut self.basis_e[i * n_quad + k]);
            }
            Basis::mean_of(
                &self.basis_e[i * n_quad..(i + 1) * n_quad],
                &mut self.basis_e_mean[i],
            );
        }
    }

    /// Adds one event (its term values from [`Self::event_basis`]) at clearance position `pos`
    /// to the statistics `sv` (grid points of "vehicle") and `se` (of "event").
    fn add_at(
        &self,
        pos: (usize, f64),
        sp: (usize, f64),
        z: &[f64; N_FEAT],
        mask: &FeatureMask,
        sv: &mut [Stats],
        se: &mut [Stats],
    ) {
        let n_quad = self.basis_e.len() / self.points_e.len().max(1);
        let mut coefs = Coefs::default();
        self.model.coef_interp(pos, sp, &mut coefs);
        // The event scatter depends on the clearance only: one inverse per clearance.
        let sigma = self.model.within_at(pos) * self.inflation2;
        if !sv.is_empty() {
            // A scatter the mask leaves singular: the event adds nothing at this clearance.
            let Some((w, ld)) = masked_inverse(&sigma, mask) else {
                return;
            };
            for (st, b) in sv.iter_mut().zip(&self.basis_v) {
                let pr = self.model.predict_with(&coefs, b);
                st.add(&pr, z, mask, &w, ld);
            }
        }
        for (q, st) in se.iter_mut().enumerate() {
            // Δ new in this event: the mean of the prediction over Δ (the law is linear in
            // its terms, so the mean event's terms give it) and its covariance.
            let mean = self.model.predict_with(&coefs, &self.basis_e_mean[q]);
            let am = nalgebra::Vector3::from(mean.a);
            let mut var = Matrix3::<f64>::zeros();
            for b in &self.basis_e[q * n_quad..(q + 1) * n_quad] {
                let d = nalgebra::Vector3::from(self.model.mean_with(&coefs, b)) - am;
                var += d * d.transpose();
            }
            var /= n_quad as f64;
            let Some((w, ld)) = masked_inverse(&(sigma + var), mask) else {
                continue;
            };
            st.add(&mean, z, mask, &w, ld);
        }
    }

    /// Writes the normalised posterior probabilities of the grid points into `out` (one per
    /// point of [`fine_grid`]), with `log_prior` the ln of the clearance prior at each point
    /// (up to a constant; not raised to the evidence power).
    pub fn probabilities_into(&mut self, out: &mut [f64], log_prior: &[f64]) {
        let mut mx = f64::NEG_INFINITY;
        let mut mx_raw = f64::NEG_INFINITY;
        let mut min_dev = f64::INFINITY;
        let (nv, ne) = (self.points_v.len(), self.points_e.len());
        let has_base = !self.baseline.is_empty();
        for (g, o) in out.iter_mut().enumerate().take(self.pos.len()) {
            let (lam, ld_lam) = &self.prior[g];
            // ln p per grid point of the events (with the baseline's: joint), and of the
            // baseline alone; the deviance is the events' given the baseline.
            let mut hyp = |stats: &[Stats], base: &[Stats]| -> (f64, f64) {
                if stats.is_empty() {
                    return (f64::NEG_INFINITY, f64::NEG_INFINITY);
                }
                for (q, st) in stats.iter().enumerate() {
                    let (l, dev) = if has_base {
                        let (lb, devb) = base[q].evidence(lam, *ld_lam);
                        self.scratch_base[q] = lb;
                        let (l, dev) = st.plus(&base[q]).evidence(lam, *ld_lam);
                        (l, dev - devb)
                    } else {
                        st.evidence(lam, *ld_lam)
                    };
                    self.scratch[q] = l;
                    min_dev = min_dev.min(dev);
                }
                let n = stats.len();
                let lb = if has_base {
                    log_mean_exp(&self.scratch_base[..n])
                } else {
                    0.0
                };
                (log_mean_exp(&self.scratch[..n]), lb)
            };
            let (base_v, base_e) = if has_base {
                self.baseline.split_at(nv)
            } else {
                (&[][..], &[][..])
            };
            let (l_v, lb_v) = hyp(&self.stats_v[g * nv..(g + 1) * nv], base_v);
            let (l_e, lb_e) = hyp(&self.stats_e[g * ne..(g + 1) * ne], base_e);
            // Equal prior weight on the hypotheses that are in use; with a baseline, less the
            // baseline's own evidence (the conditional evidence, module doc).
            let (l, lb) = match (nv > 0, ne > 0) {
                (true, true) => (log_mean_exp(&[l_v, l_e]), log_mean_exp(&[lb_v, lb_e])),
                (true, false) => (l_v, lb_v),
                _ => (l_e, lb_e),
            };
            let l = if has_base { l - lb } else { l };
            self.share_v[g] = if l.is_finite() {
                0.5 * (l_v - lb - l).exp()
            } else {
                0.5
            };
            *o = self.power * l + log_prior[g];
            mx = mx.max(*o);
            self.scratch_raw[g] = l + log_prior[g];
            mx_raw = mx_raw.max(self.scratch_raw[g]);
        }
        // The prior's normaliser, so that the evidence is comparable between settings that
        // change the likelihood only (e.g. the transfer gain).
        let lp_max = log_prior.iter().copied().fold(f64::NEG_INFINITY, f64::max);
        let ln_prior_sum = lp_max
            + log_prior
                .iter()
                .map(|l| (l - lp_max).exp())
                .sum::<f64>()
                .ln();
        let n = self.pos.len().min(out.len());
        self.ln_evidence = if mx.is_finite() && mx_raw.is_finite() {
            [
                mx + out[..n].iter().map(|o| (o - mx).exp()).sum::<f64>().ln() - ln_prior_sum
                    + self.power * self.ln_jacobian,
                self.ln_jacobian
                    + mx_raw
                    + self.scratch_raw[..n]
                        .iter()
                        .map(|o| (o - mx_raw).exp())
                        .sum::<f64>()
                        .ln()
                    - ln_prior_sum,
            ]
        } else {
            [f64::NAN; 2]
        };
        self.min_deviance = if min_dev.is_finite() {
            min_dev
        } else {
            f64::NAN
        };
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
        self.p_vehicle = if nv > 0 && ne > 0 {
            out.iter().zip(&self.share_v).map(|(p, s)| p * s).sum()
        } else {
            f64::NAN
        };
    }

    /// How well the events fit the table's model at its best clearance and grid point, after
    /// the last [`Self::probabilities_into`]: `(deviance, degrees of freedom)`, the deviance
    /// being χ²-distributed with about that many degrees of freedom when the vehicle is one the
    /// model describes (a little less: the best point is chosen by the same events). `None`
    /// before any event.
    pub fn fit(&self) -> Option<(f64, f64)> {
        (self.n_obs > 0.0 && self.min_deviance.is_finite())
            .then_some((self.min_deviance, self.n_obs))
    }

    /// ln of the events' marginal likelihood under the table's model (the clearance prior
    /// normalised), `[with the evidence power, without]`, after the last
    /// [`Self::probabilities_into`]; `None` before any event.
    pub fn ln_evidence(&self) -> Option<[f64; 2]> {
        (self.n_obs > 0.0 && self.ln_evidence[0].is_finite()).then_some(self.ln_evidence)
    }

    /// Posterior probability that the wheels' unbalance phase difference was the same in all
    /// the events (hypothesis "vehicle" of `phase = "either"`), after the last
    /// [`Self::probabilities_into`]; `None` when only one hypothesis is in use.
    pub fn phase_fixed_probability(&self) -> Option<f64> {
        self.p_vehicle.is_finite().then_some(self.p_vehicle)
    }
}
