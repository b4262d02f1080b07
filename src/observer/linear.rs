//! The nuisance model of a response table: each event feature as a polynomial in the vehicle's
//! nuisance coordinates and its wheels' unbalance phase difference, for the estimator's
//! marginalisation ([`super::marginal`]).
//!
//! What it is: per clearance c of the table and initial speed v, and feature
//! f ∈ {ln RMS, ln peak, cruise} (the statistics of `features::z` / `features::z_cruise`,
//! MODEL.md §11), the least-squares fit on the table's simulated events
//!
//!   z_f = Σ_t β_t · m_t(d, ξ, ψ) + η_f + ε_f,
//!
//! over monomials m_t ([`Term`], e.g. `x1^2`, `u*x5`, `d`) of the deceleration d (scaled as
//! (d − 0.55)/0.25), the nuisance coordinates ξ ∈ [−1, 1]¹⁰ of [`super::emulate::coords`] (x0
//! k_s, x1 c_s, x2 k_t, x3 k_g, x4 c_g of MODEL.md §9; x5 the unbalance, x6 the road-noise level
//! of §7; with the §15 column x7 J_sw, x8 k_tb, x9 c_tb, which only [`COLUMN_TERMS`] use) and
//! ψ = cos(φ_R − φ_L) (`u`), the cosine of the difference of the two wheels' unbalance phases
//! (§7).
//!
//! Why these coordinates enter as they do:
//! * ξ₁, the kingpin damping c_s, is a threshold, not a slope: the rattle exists because the
//!   free-play modes are marginally unstable under braking (MODEL.md §12) and c_s supplies about
//!   ζ ≈ 0.37 of their damping, so +10 % on c_s can silence a 0.3 mm joint at the steering
//!   wheel while −10 % raises it by half. It enters up to the cube and its products set the
//!   other coordinates' slopes.
//! * ψ: both wheels turn with the one spin angle φ of the model (§1, §7), so the phase
//!   difference is fixed for as long as the wheels roll together. It decides how the two
//!   unbalance moments add in the steering linkage, i.e. how much of the unbalance reaches the
//!   rack (the symmetric mode the sensor sees, §8, §14) and how much only twists the toe. At
//!   0.05–0.15 mm and 55 km/h it moves ln RMS by ±0.1–0.2 between ψ = 1 and ψ = −1, as much as
//!   the clearance does over a factor 1.5. A vehicle whose phases happen to cancel looks like
//!   worn joints; one whose phases add looks like tight ones. Given ψ and ξ₁ the law is linear
//!   in the other coordinates.
//!
//! The estimator integrates the *gridded* coordinates (always ξ₁ and ψ, and any other listed in
//! [`LinearModel::gridded`]) on grids and the rest in closed form, which needs the law to be
//! affine in each closed-form coordinate, with at most one of them per term: checked by
//! [`LinearModel::validate`]. Two residual terms are measured from the same fit:
//! * ε, the event-to-event scatter of one vehicle (road-noise realisation, sensor offset, the
//!   rattle's chaos, §12): `within[c]`, the 3 × 3 covariance of the residuals about each
//!   vehicle's own mean residual;
//! * η, what the law misses for one vehicle, the same for all its events: `between[c]`, the
//!   covariance of the vehicles' mean *leave-one-vehicle-out* residuals (the fit without the
//!   vehicle, so that it measures how the law predicts a new vehicle, not how well it fitted
//!   the ones it was made from) less the part ε explains.
//!
//! What it is not: a model of the physics (the shimmy model makes the data) or the estimator
//! (which uses [`LinearModel::predict`] only). The fit runs once, in `shimmy calibrate`; it
//! needs more events per clearance and speed than terms.

use std::fmt;

use nalgebra::{DMatrix, Matrix3, SymmetricEigen};
use serde::{Deserialize, Serialize};

use super::emulate::{RawEvent, N_COORDS};

/// Features of the model: ln RMS, ln peak, cruise.
pub const N_FEAT: usize = 3;
/// The coordinate that enters nonlinearly and is always gridded: the kingpin damping c_s.
pub const DAMPING: usize = 1;
/// The unbalance coordinate (gridded when a term is nonlinear in it).
pub const UNBALANCE: usize = 5;
/// Index of ψ = cos(φ_R − φ_L) among a term's variables (after the coordinates).
pub const PHASE: usize = N_COORDS;
/// Variables of a term: the coordinates and ψ.
pub const N_VARS: usize = N_COORDS + 1;
/// Most closed-form coordinates (all but ξ₁).
pub const N_LIN: usize = N_COORDS - 1;
/// Most terms of a model.
pub const MAX_TERMS: usize = 64;

/// One monomial of the law: a product of the variables' powers and of a power (0-2) of the
/// scaled deceleration. Written as in the table file: `1`, `d`, `d^2`, `x1^2`, `u*x5`,
/// `d*x1`.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Term {
    pub exp: [u8; N_VARS],
    pub decel: u8,
}

impl Term {
    /// The term's value at variables `x` and scaled deceleration `dn`.
    #[inline]
    pub fn eval(&self, x: &[f64; N_VARS], dn: f64) -> f64 {
        let mut v = match self.decel {
            0 => 1.0,
            1 => dn,
            _ => dn * dn,
        };
        for (e, xi) in self.exp.iter().zip(x) {
            for _ in 0..*e {
                v *= xi;
            }
        }
        v
    }
}

impl std::str::FromStr for Term {
    type Err = anyhow::Error;

    fn from_str(s: &str) -> anyhow::Result<Term> {
        let mut t = Term {
            exp: [0; N_VARS],
            decel: 0,
        };
        let s = s.trim();
        if s == "1" {
            return Ok(t);
        }
        for f in s.split('*') {
            let (name, pow) = match f.split_once('^') {
                Some((n, p)) => (
                    n.trim(),
                    p.trim()
                        .parse::<u8>()
                        .map_err(|_| anyhow::anyhow!("term `{s}`: bad power in `{f}`"))?,
                ),
                None => (f.trim(), 1),
            };
            if name == "d" {
                if pow == 0 || t.decel + pow > 2 {
                    anyhow::bail!("term `{s}`: the deceleration enters up to its square");
                }
                t.decel += pow;
                continue;
            }
            let idx = if name == "u" {
                PHASE
            } else {
                name.strip_prefix('x')
                    .and_then(|k| k.parse::<usize>().ok())
                    .filter(|&k| k < N_COORDS)
                    .ok_or_else(|| {
                        anyhow::anyhow!("term `{s}`: unknown variable `{name}` (d, u, x0-x9)")
                    })?
            };
            if pow == 0 || pow > 4 || t.exp[idx] + pow > 4 {
                anyhow::bail!("term `{s}`: powers 1-4 only");
            }
            t.exp[idx] += pow;
        }
        Ok(t)
    }
}

impl fmt::Display for Term {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        let mut parts: Vec<String> = Vec::new();
        match self.decel {
            0 => {}
            1 => parts.push("d".into()),
            p => parts.push(format!("d^{p}")),
        }
        for (i, &e) in self.exp.iter().enumerate() {
            if e == 0 {
                continue;
            }
            let name = if i == PHASE {
                "u".to_string()
            } else {
                format!("x{i}")
            };
            parts.push(if e == 1 { name } else { format!("{name}^{e}") });
        }
        if parts.is_empty() {
            write!(f, "1")
        } else {
            write!(f, "{}", parts.join("*"))
        }
    }
}

impl Serialize for Term {
    fn serialize<S: serde::Serializer>(&self, s: S) -> Result<S::Ok, S::Error> {
        s.collect_str(self)
    }
}

impl<'de> Deserialize<'de> for Term {
    fn deserialize<D: serde::Deserializer<'de>>(d: D) -> Result<Term, D::Error> {
        let s = String::deserialize(d)?;
        s.parse().map_err(serde::de::Error::custom)
    }
}

/// Parses a comma-separated term list (`shimmy calibrate --terms`).
pub fn parse_terms(s: &str) -> anyhow::Result<Vec<Term>> {
    s.split(',')
        .filter(|t| !t.trim().is_empty())
        .map(|t| t.parse())
        .collect()
}

/// The terms a table of the torsion-bar torque adds to [`DEFAULT_TERMS`] (`shimmy calibrate
/// --signal torque`): the column's rim inertia, torsion-bar stiffness and damping (x7-x9). The
/// torque reads the torsion bar's twist times k_tb, so k_tb alone moves it by a factor 3 over
/// the published range (docs/COLUMN.md); with its slope set by the kingpin damping like the
/// others'. And the unbalance squared: near the rattle's onset (0.04-0.09 mm) the torque's
/// ln RMS bends in the unbalance, and a law straight in it leaves a between-vehicle misfit
/// that reads a quiet car as worn (docs/ACCURACY.md, "Quiet cars"). With `x5^2` the law is not
/// affine in the unbalance, so the estimator integrates it on a grid ([`LinearModel::gridded`]).
pub const COLUMN_TERMS: &str = "x7,x8,x9,x1*x8,x5^2";

/// The law `shimmy calibrate --signal torque` fits by default: [`DEFAULT_TERMS`], then
/// [`COLUMN_TERMS`].
pub fn torque_terms() -> anyhow::Result<Vec<Term>> {
    parse_terms(&format!("{DEFAULT_TERMS},{COLUMN_TERMS}"))
}

/// The law `shimmy calibrate` fits by default: intercept and deceleration; the seven
/// coordinates; c_s to the cube and its products with the others; ψ and ψ² and ψ's products
/// with c_s and the unbalance (docs/ACCURACY.md says how this was chosen).
pub const DEFAULT_TERMS: &str = "1,d,x0,x1,x2,x3,x4,x5,x6,x1^2,x1^3,x0*x1,x1*x2,x1*x3,x1*x4,\
                                 x1*x5,x1*x6,u,u^2,x1*u,x5*u";

/// The fitted model (a field of [`super::table::ResponseTable`]).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct LinearModel {
    /// Drawn vehicles the fit used.
    pub vehicles: u32,
    /// The law's monomials.
    pub terms: Vec<Term>,
    /// Coordinates besides ξ₁ and ψ that the estimator integrates on a grid because the law is
    /// not affine in them (e.g. [`UNBALANCE`] when a term has `x5^2`).
    #[serde(default)]
    pub gridded: Vec<usize>,
    /// Coefficients of `terms`, index `((ic · n_speed + iv) · 3 + f) · n_terms + t`.
    pub coef: Vec<f64>,
    /// Total residual standard deviation per clearance and feature (ε and η together).
    pub total_std: Vec<[f64; N_FEAT]>,
    /// Correlation of the total ln RMS and ln peak residuals per clearance.
    pub total_corr: Vec<f64>,
    /// Covariance of ε (one vehicle's event scatter) per clearance.
    pub within: Vec<[[f64; N_FEAT]; N_FEAT]>,
    /// Covariance of η (the per-vehicle misfit of the law, leave-one-vehicle-out) per
    /// clearance.
    pub between: Vec<[[f64; N_FEAT]; N_FEAT]>,
}

/// What the model predicts for one event at one clearance and one point of the gridded
/// coordinates: the feature means with the closed-form coordinates at 0 and η = 0 (`a`) and
/// their slopes in the closed-form coordinates (`b`, in the order of
/// [`LinearModel::closed_form`]; unused slots 0). The covariances depend on the clearance only:
/// [`LinearModel::within_at`], [`LinearModel::between_at`].
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct LinearPrediction {
    pub a: [f64; N_FEAT],
    pub b: [[f64; N_LIN]; N_FEAT],
}

/// Five decimals of a ln-statistic (1e-5 relative in the feature) keep the table file small.
pub(crate) fn round5(x: f64) -> f64 {
    (x * 1e5).round() / 1e5
}

/// A stored 3 × 3 covariance as a matrix.
pub(crate) fn mat3(a: &[[f64; N_FEAT]; N_FEAT]) -> Matrix3<f64> {
    Matrix3::from_fn(|i, j| a[i][j])
}

fn to_arr(m: &Matrix3<f64>) -> [[f64; 3]; 3] {
    std::array::from_fn(|i| std::array::from_fn(|j| round5(m[(i, j)])))
}

/// The scaled deceleration of the terms.
#[inline]
pub fn decel_norm(decel_g: f64) -> f64 {
    (decel_g - 0.55) / 0.25
}

/// The variables of a table event: its vehicle's coordinates and its ψ.
pub fn vars(xi: &[f64; N_COORDS], phase_cos: f64) -> [f64; N_VARS] {
    let mut x = [0.0; N_VARS];
    x[..N_COORDS].copy_from_slice(xi);
    x[PHASE] = phase_cos;
    x
}

/// Nearest positive semi-definite matrix with eigenvalues at least `floor`.
fn clip_psd(m: Matrix3<f64>, floor: f64) -> Matrix3<f64> {
    let sym = 0.5 * (m + m.transpose());
    let mut e = SymmetricEigen::new(sym);
    for l in e.eigenvalues.iter_mut() {
        *l = l.max(floor);
    }
    e.recompose()
}

/// The coordinates a model with these terms must grid (besides ξ₁ and ψ): those some term is
/// not affine in, or that share a term with another non-gridded coordinate (then the later
/// one is gridded).
pub fn needs_grid(terms: &[Term]) -> Vec<usize> {
    let mut grid: Vec<usize> = (0..N_COORDS)
        .filter(|&j| j != DAMPING && terms.iter().any(|t| t.exp[j] > 1))
        .collect();
    for t in terms {
        let lin: Vec<usize> = (0..N_COORDS)
            .filter(|&j| j != DAMPING && t.exp[j] > 0 && !grid.contains(&j))
            .collect();
        for &j in lin.iter().skip(1) {
            grid.push(j);
        }
    }
    grid.sort_unstable();
    grid
}

/// Fits the model with `terms` on `raw` (the drawn vehicles' events; vehicle `im` has
/// coordinates `table_coords[im]`) for `n_clearance` × `n_speed` grid cells. `min_std` floors
/// each feature's spread.
pub fn fit(
    raw: &[RawEvent],
    table_coords: &[[f64; N_COORDS]],
    n_clearance: usize,
    n_speed: usize,
    terms: &[Term],
    min_std: f64,
) -> anyhow::Result<LinearModel> {
    let nk = terms.len();
    if nk == 0 || nk > MAX_TERMS {
        anyhow::bail!("the nuisance model needs 1-{MAX_TERMS} terms, not {nk}");
    }
    if terms[0] != "1".parse::<Term>()? {
        anyhow::bail!("the nuisance model's first term must be the intercept `1`");
    }
    let nm = table_coords.len();
    let mut coef = vec![0.0; n_clearance * n_speed * N_FEAT * nk];
    let mut total_std = Vec::with_capacity(n_clearance);
    let mut total_corr = Vec::with_capacity(n_clearance);
    let mut within = Vec::with_capacity(n_clearance);
    let mut between = Vec::with_capacity(n_clearance);
    for ic in 0..n_clearance {
        // Residuals of this clearance, and the leave-one-vehicle-out ones, with their vehicle.
        let mut res: Vec<(usize, [f64; N_FEAT])> = Vec::new();
        let mut loo: Vec<(usize, [f64; N_FEAT])> = Vec::new();
        let mut n_params = 0usize;
        for iv in 0..n_speed {
            let rows: Vec<&RawEvent> = raw.iter().filter(|e| e.ic == ic && e.iv == iv).collect();
            if rows.len() <= nk {
                anyhow::bail!(
                    "the nuisance model needs more than {nk} events per clearance and speed \
                     (vehicles × decelerations × seeds), not {}",
                    rows.len()
                );
            }
            let x = DMatrix::from_fn(rows.len(), nk, |i, k| {
                let e = rows[i];
                terms[k].eval(
                    &vars(&table_coords[e.im], e.phase_cos),
                    decel_norm(e.decel_g),
                )
            });
            let y = DMatrix::from_fn(rows.len(), N_FEAT, |i, f| rows[i].z[f]);
            // (XᵀX)⁻¹ through the SVD's pseudo-inverse: rank-deficient designs (too few
            // distinct vehicles) get the minimum-norm solution instead of a failure.
            let xtx = x.transpose() * &x;
            let g = xtx
                .pseudo_inverse(1e-10)
                .map_err(|e| anyhow::anyhow!("nuisance model least squares: {e}"))?;
            let beta = &g * (x.transpose() * &y);
            let r = &y - &x * &beta;
            for f in 0..N_FEAT {
                for k in 0..nk {
                    coef[((ic * n_speed + iv) * N_FEAT + f) * nk + k] = round5(beta[(k, f)]);
                }
            }
            // Leave-one-vehicle-out residuals: r_g / (I − H_gg) for each vehicle's rows g.
            let mut by_vehicle: Vec<(usize, Vec<usize>)> = Vec::new();
            for (i, e) in rows.iter().enumerate() {
                match by_vehicle.iter_mut().find(|(m, _)| *m == e.im) {
                    Some((_, v)) => v.push(i),
                    None => by_vehicle.push((e.im, vec![i])),
                }
            }
            for (im, idx) in &by_vehicle {
                let xg = DMatrix::from_fn(idx.len(), nk, |a, k| x[(idx[a], k)]);
                let h = &xg * &g * xg.transpose();
                let i_h = DMatrix::identity(idx.len(), idx.len()) - h;
                let rg = DMatrix::from_fn(idx.len(), N_FEAT, |a, f| r[(idx[a], f)]);
                let lg = i_h.lu().solve(&rg).unwrap_or(rg);
                for a in 0..idx.len() {
                    res.push((*im, std::array::from_fn(|f| r[(idx[a], f)])));
                    loo.push((*im, std::array::from_fn(|f| lg[(a, f)])));
                }
            }
            n_params += nk;
        }
        let n = res.len() as f64;
        // The regression used n_params degrees of freedom: scale the residual moments up.
        let dof_scale = n / (n - n_params as f64).max(1.0);
        let mut total = Matrix3::zeros();
        for (_, r) in &res {
            let v = nalgebra::Vector3::from(*r);
            total += v * v.transpose();
        }
        total *= dof_scale / n;
        let means = |rs: &[(usize, [f64; N_FEAT])]| {
            let mut sum = vec![[0.0f64; N_FEAT]; nm];
            let mut cnt = vec![0usize; nm];
            for (im, r) in rs {
                for f in 0..N_FEAT {
                    sum[*im][f] += r[f];
                }
                cnt[*im] += 1;
            }
            let mean: Vec<nalgebra::Vector3<f64>> = sum
                .iter()
                .zip(&cnt)
                .map(|(s, &k)| nalgebra::Vector3::from(s.map(|x| x / k.max(1) as f64)))
                .collect();
            (mean, cnt)
        };
        let (mean_m, cnt_m) = means(&res);
        let mut w = Matrix3::zeros();
        for (im, r) in &res {
            let d = nalgebra::Vector3::from(*r) - mean_m[*im];
            w += d * d.transpose();
        }
        let used = cnt_m.iter().filter(|&&k| k > 0).count();
        let per_vehicle = n / used.max(1) as f64;
        w *= dof_scale / (n - used as f64).max(1.0);
        // The vehicles' mean leave-one-out residuals: how the law misses a vehicle it has not
        // seen (no degrees-of-freedom correction: the held-out residuals are not shrunk).
        let (loo_m, _) = means(&loo);
        let mut b = Matrix3::zeros();
        for (mu, _) in loo_m.iter().zip(&cnt_m).filter(|(_, &k)| k > 0) {
            b += mu * mu.transpose();
        }
        b /= used.max(1) as f64;
        let floor = min_std * min_std;
        let w = clip_psd(w, floor);
        // Between-vehicle covariance of the means, less the within scatter they average.
        let t = clip_psd(b - w / per_vehicle, 1e-6);
        let s: [f64; N_FEAT] = std::array::from_fn(|f| total[(f, f)].sqrt().max(min_std));
        total_corr.push(round5((total[(0, 1)] / (s[0] * s[1])).clamp(-0.95, 0.95)));
        total_std.push(s.map(round5));
        within.push(to_arr(&w));
        between.push(to_arr(&t));
    }
    Ok(LinearModel {
        vehicles: nm as u32,
        terms: terms.to_vec(),
        gridded: needs_grid(terms),
        coef,
        total_std,
        total_corr,
        within,
        between,
    })
}

impl LinearModel {
    /// Checks the shape against the table's axes, that the law is affine in its closed-form
    /// coordinates and that the covariances are usable.
    pub fn validate(&self, n_clearance: usize, n_speed: usize) -> anyhow::Result<()> {
        let nk = self.terms.len();
        if nk == 0 || nk > MAX_TERMS {
            anyhow::bail!("the table's nuisance model has {nk} terms (want 1-{MAX_TERMS})");
        }
        if self.coef.len() != n_clearance * n_speed * N_FEAT * nk
            || self.total_std.len() != n_clearance
            || self.total_corr.len() != n_clearance
            || self.within.len() != n_clearance
            || self.between.len() != n_clearance
        {
            anyhow::bail!("the table's nuisance model does not match its clearance × speed axes");
        }
        if self.gridded.iter().any(|&j| j >= N_COORDS || j == DAMPING) {
            anyhow::bail!(
                "the table's nuisance model grids unknown coordinates {:?}",
                self.gridded
            );
        }
        let missing: Vec<usize> = needs_grid(&self.terms)
            .into_iter()
            .filter(|j| !self.gridded.contains(j))
            .collect();
        if !missing.is_empty() {
            anyhow::bail!(
                "the table's nuisance model is not affine in coordinates {missing:?}, which it \
                 does not grid"
            );
        }
        let finite = self.coef.iter().all(|v| v.is_finite())
            && self
                .total_std
                .iter()
                .flatten()
                .all(|v| v.is_finite() && *v > 0.0);
        if !finite {
            anyhow::bail!("the table's nuisance model has non-finite coefficients or spreads");
        }
        for (ic, (w, b)) in self.within.iter().zip(&self.between).enumerate() {
            if mat3(w).cholesky().is_none() || !(0..N_FEAT).all(|i| b[i][i] >= 0.0) {
                anyhow::bail!(
                    "the table's nuisance model has an invalid covariance at clearance {ic}"
                );
            }
        }
        Ok(())
    }

    /// Speeds of the table the model was fitted on.
    fn n_speed(&self) -> usize {
        self.coef.len() / (self.within.len() * N_FEAT * self.terms.len()).max(1)
    }

    /// The coordinates integrated in closed form, in the order of [`LinearPrediction::b`].
    pub fn closed_form(&self) -> impl Iterator<Item = usize> + '_ {
        (0..N_COORDS).filter(move |&j| j != DAMPING && !self.gridded.contains(&j))
    }

    /// The coordinates integrated on grids, besides ψ: ξ₁ first, then [`Self::gridded`].
    pub fn grid_coords(&self) -> Vec<usize> {
        let mut g = vec![DAMPING];
        g.extend(self.gridded.iter().copied());
        g
    }

    /// Whether ψ enters the law.
    pub fn has_phase(&self) -> bool {
        self.terms.iter().any(|t| t.exp[PHASE] > 0)
    }

    /// The coefficients of feature `f` at grid clearance `ic` and grid speed `iv`.
    pub fn coef_at(&self, ic: usize, iv: usize, f: usize) -> &[f64] {
        let nk = self.terms.len();
        let i = ((ic * self.n_speed() + iv) * N_FEAT + f) * nk;
        &self.coef[i..i + nk]
    }

    /// The mean of feature `f` at grid clearance `ic` and speed `iv` for variables `x`
    /// ([`vars`]) and deceleration `decel_g`.
    pub fn mean_at(&self, ic: usize, iv: usize, f: usize, x: &[f64; N_VARS], decel_g: f64) -> f64 {
        let dn = decel_norm(decel_g);
        self.terms
            .iter()
            .zip(self.coef_at(ic, iv, f))
            .map(|(t, b)| t.eval(x, dn) * b)
            .sum()
    }

    /// A clearance-dependent covariance at clearance position `(ic, wc)`, linear in ln c.
    fn interp(cov: &[[[f64; N_FEAT]; N_FEAT]], (ic, wc): (usize, f64)) -> Matrix3<f64> {
        let jc = (ic + 1).min(cov.len() - 1);
        mat3(&cov[ic]) * (1.0 - wc) + mat3(&cov[jc]) * wc
    }

    /// Covariance of ε (one vehicle's event scatter) at clearance position `(ic, wc)`.
    pub fn within_at(&self, pos: (usize, f64)) -> Matrix3<f64> {
        Self::interp(&self.within, pos)
    }

    /// Covariance of η (the per-vehicle misfit) at clearance position `(ic, wc)`.
    pub fn between_at(&self, pos: (usize, f64)) -> Matrix3<f64> {
        Self::interp(&self.between, pos)
    }

    /// The term values of one event at one point of the gridded variables: `x` holds the
    /// gridded coordinates and ψ (the closed-form ones at 0). Writes each term's value and,
    /// for each closed-form coordinate, its derivative (the term with that coordinate's factor
    /// removed, 0 when the term lacks it) into `basis`. No allocation.
    pub fn basis_into(&self, x: &[f64; N_VARS], decel_g: f64, basis: &mut Basis) {
        let dn = decel_norm(decel_g);
        basis.n = self.terms.len();
        for (k, t) in self.terms.iter().enumerate() {
            basis.value[k] = t.eval(x, dn);
            for (l, j) in self.closed_form().enumerate() {
                basis.slope[l][k] = if t.exp[j] == 1 {
                    let mut u = *t;
                    u.exp[j] = 0;
                    u.eval(x, dn)
                } else {
                    0.0
                };
            }
        }
    }

    /// The coefficients at clearance position `(ic, wc)` (between grid clearances `ic` and
    /// `ic + 1`, weight `wc` on the second, linear in ln c) and speed position `(iv, wv)`
    /// (linear in speed), into `out`. No allocation.
    pub fn coef_interp(&self, (ic, wc): (usize, f64), (iv, wv): (usize, f64), out: &mut Coefs) {
        let (nc, nv, nk) = (self.within.len(), self.n_speed(), self.terms.len());
        out.n = nk;
        for row in out.c.iter_mut() {
            row[..nk].fill(0.0);
        }
        for (dc, fc) in [(0usize, 1.0 - wc), (1, wc)] {
            for (dv, fv) in [(0usize, 1.0 - wv), (1, wv)] {
                let f = fc * fv;
                if f == 0.0 {
                    continue;
                }
                let (jc, jv) = ((ic + dc).min(nc - 1), (iv + dv).min(nv - 1));
                for (k, row) in out.c.iter_mut().enumerate() {
                    for (o, b) in row[..nk].iter_mut().zip(self.coef_at(jc, jv, k)) {
                        *o += f * b;
                    }
                }
            }
        }
    }

    /// The prediction for an event whose term values are `basis` ([`Self::basis_into`]) with
    /// the coefficients `coefs` ([`Self::coef_interp`]). No allocation.
    pub fn predict_with(&self, coefs: &Coefs, basis: &Basis) -> LinearPrediction {
        let n_lin = self.closed_form().count();
        let n = basis.n;
        let mut p = LinearPrediction::default();
        for k in 0..N_FEAT {
            let b = &coefs.c[k][..n];
            p.a[k] = dot(&basis.value[..n], b);
            for l in 0..n_lin {
                p.b[k][l] = dot(&basis.slope[l][..n], b);
            }
        }
        p
    }

    /// The feature means only of [`Self::predict_with`].
    pub fn mean_with(&self, coefs: &Coefs, basis: &Basis) -> [f64; N_FEAT] {
        let n = basis.n;
        std::array::from_fn(|k| dot(&basis.value[..n], &coefs.c[k][..n]))
    }

    /// The feature means of [`Self::mean_with`] split by class of term: `out[m][f]` sums
    /// coefficient × term value over the terms t with `class[t] == m`; a term whose class is
    /// `out.len()` or more is left out. No allocation.
    pub fn means_by_class(
        &self,
        coefs: &Coefs,
        basis: &Basis,
        class: &[usize],
        out: &mut [[f64; N_FEAT]],
    ) {
        out.iter_mut().for_each(|o| *o = [0.0; N_FEAT]);
        for (t, &m) in class.iter().enumerate().take(basis.n) {
            if let Some(o) = out.get_mut(m) {
                for (f, of) in o.iter_mut().enumerate() {
                    *of += coefs.c[f][t] * basis.value[t];
                }
            }
        }
    }
}

/// Interpolated coefficients of the three features ([`LinearModel::coef_interp`]).
#[derive(Clone, Copy, Debug)]
pub struct Coefs {
    n: usize,
    c: [[f64; MAX_TERMS]; N_FEAT],
}

impl Default for Coefs {
    fn default() -> Self {
        Coefs {
            n: 0,
            c: [[0.0; MAX_TERMS]; N_FEAT],
        }
    }
}

fn dot(a: &[f64], b: &[f64]) -> f64 {
    a.iter().zip(b).map(|(x, y)| x * y).sum()
}

/// Term values of one event at one grid point ([`LinearModel::basis_into`]).
#[derive(Clone, Copy, Debug)]
pub struct Basis {
    n: usize,
    value: [f64; MAX_TERMS],
    slope: [[f64; MAX_TERMS]; N_LIN],
}

impl Default for Basis {
    fn default() -> Self {
        Basis {
            n: 0,
            value: [0.0; MAX_TERMS],
            slope: [[0.0; MAX_TERMS]; N_LIN],
        }
    }
}

impl Basis {
    /// The mean of `items` (all of one model): the term values of the averaged event, for a
    /// law that is linear in its coefficients.
    pub fn mean_of(items: &[Basis], out: &mut Basis) {
        let n = items.first().map_or(0, |b| b.n);
        *out = Basis::default();
        out.n = n;
        let k = items.len().max(1) as f64;
        for b in items {
            for t in 0..n {
                out.value[t] += b.value[t] / k;
                for l in 0..N_LIN {
                    out.slope[l][t] += b.slope[l][t] / k;
                }
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::observer::emulate::draw_coords;
    use rand::{Rng, SeedableRng};
    use rand_chacha::ChaCha8Rng;

    fn gauss(rng: &mut ChaCha8Rng) -> f64 {
        (0..12).map(|_| rng.random::<f64>()).sum::<f64>() - 6.0
    }

    #[test]
    fn terms_read_and_write_as_in_the_table_file() {
        for s in ["1", "d", "d^2", "x1^2", "x5*u", "d*x1", "x0*x1", "u^2"] {
            let t: Term = s.parse().unwrap();
            assert_eq!(t.to_string(), s);
        }
        let t: Term = "x1*x1".parse().unwrap();
        assert_eq!(t.to_string(), "x1^2");
        assert_eq!("u*x5".parse::<Term>().unwrap().to_string(), "x5*u");
        assert_eq!("d*d".parse::<Term>().unwrap().to_string(), "d^2");
        for bad in ["x10", "y", "d^3", "x1^0", "x1^9", "d*d^2"] {
            assert!(bad.parse::<Term>().is_err(), "{bad}");
        }
        let x = [0.5, -0.5, 0.0, 0.0, 0.0, 2.0, 0.0, 0.0, 0.0, 0.0, 0.25];
        assert_eq!("x1^2*u".parse::<Term>().unwrap().eval(&x, 3.0), 0.0625);
        assert_eq!("d*x5".parse::<Term>().unwrap().eval(&x, 3.0), 6.0);
        let default = parse_terms(DEFAULT_TERMS).unwrap();
        assert_eq!(default.len(), 21);
        assert!(needs_grid(&default).is_empty());
        // A square in the unbalance, or two closed-form coordinates in one term, must be gridded.
        assert_eq!(needs_grid(&parse_terms("1,x5^2").unwrap()), vec![UNBALANCE]);
        assert_eq!(needs_grid(&parse_terms("1,x0*x6").unwrap()), vec![6]);
    }

    /// Events from a known law, nonlinear in the damping coordinate ξ₁ and in ψ, with a
    /// per-vehicle offset (η, std 0.15) and event noise (ε, std 0.1): the fit recovers the law
    /// and tells the two spreads apart.
    #[test]
    fn the_fit_recovers_slopes_and_separates_vehicle_misfit_from_event_scatter() {
        let m = 80;
        let coords = draw_coords(m, 1);
        let mut rng = ChaCha8Rng::seed_from_u64(4);
        let eta: Vec<f64> = (0..m).map(|_| 0.15 * gauss(&mut rng)).collect();
        let mut raw = Vec::new();
        for (im, xi) in coords.iter().enumerate() {
            for iv in 0..3 {
                for d in [0.3, 0.55, 0.8] {
                    for _ in 0..2 {
                        let u = (rng.random::<f64>() * std::f64::consts::TAU).cos();
                        let base = -3.0 + 0.1 * iv as f64 + 0.5 * xi[1]
                            - 0.4 * xi[1].powi(3)
                            - 0.2 * xi[5]
                            + 0.3 * xi[1] * xi[5]
                            - 0.15 * u
                            + 0.1 * u * xi[5]
                            + eta[im];
                        let z =
                            std::array::from_fn(|f| base + 0.1 * f as f64 + 0.1 * gauss(&mut rng));
                        raw.push(RawEvent {
                            ic: 0,
                            im,
                            iv,
                            decel_g: d,
                            z,
                            phase_cos: u,
                        });
                    }
                }
            }
        }
        let terms = parse_terms(DEFAULT_TERMS).unwrap();
        let lm = fit(&raw, &coords, 1, 3, &terms, 0.02).unwrap();
        lm.validate(1, 3).unwrap();
        let k = |s: &str| terms.iter().position(|t| *t == s.parse().unwrap()).unwrap();
        for iv in 0..3 {
            let b = lm.coef_at(0, iv, 0);
            assert!((b[k("x1")] - 0.5).abs() < 0.06, "{b:?}");
            assert!((b[k("x5")] + 0.2).abs() < 0.06, "{b:?}");
            assert!(b[k("x0")].abs() < 0.06, "{b:?}");
            assert!((b[k("u")] + 0.15).abs() < 0.06, "{b:?}");
            assert!((b[k("x5*u")] - 0.1).abs() < 0.08, "{b:?}");
        }
        let w = lm.within[0][0][0].sqrt();
        let t = lm.between[0][0][0].sqrt();
        assert!((w - 0.1).abs() < 0.02, "within {w}");
        assert!((t - 0.15).abs() < 0.05, "between {t}");
        // η is shared by the features: the between covariance says so.
        let r = lm.between[0][0][1] / (lm.between[0][0][0] * lm.between[0][1][1]).sqrt();
        assert!(r > 0.8, "between correlation {r}");
        // At ξ₁ = 0.8, ψ = −0.5 the mean carries 0.5·ξ₁ − 0.4·ξ₁³ − 0.15·ψ and the slope of ξ₅
        // is −0.2 + 0.3·ξ₁ + 0.1·ψ.
        let mut x = [0.0; N_VARS];
        x[DAMPING] = 0.8;
        x[PHASE] = -0.5;
        let mut basis = Basis::default();
        lm.basis_into(&x, 0.55, &mut basis);
        let mut coefs = Coefs::default();
        lm.coef_interp((0, 0.0), (1, 0.5), &mut coefs);
        let p = lm.predict_with(&coefs, &basis);
        let want = -3.0 + 0.15 + 0.4 - 0.4 * 0.512 + 0.075;
        assert!((p.a[0] - want).abs() < 0.08, "{:?} vs {want}", p.a);
        let l5 = lm.closed_form().position(|j| j == 5).unwrap();
        assert!(
            (p.b[0][l5] - (-0.2 + 0.24 - 0.05)).abs() < 0.08,
            "{:?}",
            p.b
        );
    }

    /// The leave-one-vehicle-out misfit sees what an overfitted law misses for a new vehicle:
    /// with few vehicles per term the in-sample residuals shrink, the held-out ones do not.
    #[test]
    fn the_misfit_is_measured_on_held_out_vehicles() {
        let m = 24;
        let coords = draw_coords(m, 3);
        let mut rng = ChaCha8Rng::seed_from_u64(9);
        let eta: Vec<f64> = (0..m).map(|_| 0.1 * gauss(&mut rng)).collect();
        let mut raw = Vec::new();
        for (im, _) in coords.iter().enumerate() {
            for d in [0.3, 0.8] {
                let z = std::array::from_fn(|_| -3.0 + eta[im] + 0.05 * gauss(&mut rng));
                raw.push(RawEvent {
                    ic: 0,
                    im,
                    iv: 0,
                    decel_g: d,
                    z,
                    phase_cos: 0.0,
                });
            }
        }
        let terms = parse_terms("1,d,x0,x1,x2,x3,x4,x5,x6,x1^2,x1^3,x0*x1,x1*x2,x1*x3").unwrap();
        let lm = fit(&raw, &coords, 1, 1, &terms, 0.02).unwrap();
        let t = lm.between[0][0][0].sqrt();
        // 13 terms on 24 vehicles absorb much of η in-sample; held out, η (0.1) is all there.
        assert!(t > 0.08, "between {t}");
    }
}
