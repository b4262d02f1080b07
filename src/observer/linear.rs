//! The linear nuisance model of a response table: each event feature as a linear function of
//! the vehicle's nuisance coordinates, for the estimator's continuous marginalisation
//! ([`super::marginal`]).
//!
//! What it is: per clearance c of the table and initial speed v, and feature
//! f ∈ {ln RMS, ln peak, cruise} (the statistics of `features::z` / `features::z_cruise`,
//! MODEL.md §11), the least-squares fit on the table's simulated events
//!
//!   z_f = β₀ + β_d·(d − 0.55)/0.25 + Σ_j β_j·ξ_j + β₁₁·ξ₁² + β₁₁₁·ξ₁³ + Σ_{j≠1} β₁ⱼ·ξ₁·ξ_j
//!         + η_f + ε_f,
//!
//! with ξ ∈ [−1, 1]⁷ the nuisance coordinates of [`super::emulate::coords`] (the five steering
//! stiffnesses and dampings of MODEL.md §9, the unbalance and the road-noise level of §7).
//! ξ₁, the kingpin damping c_s, enters nonlinearly: the rattle exists because the free-play
//! modes are marginally unstable under braking (MODEL.md §12) and c_s supplies about ζ ≈ 0.37
//! of their damping, so +10 % on c_s can silence a 0.3 mm joint at the steering wheel while
//! −10 % raises it by half: a threshold, not a slope. Given ξ₁ the law is linear in the other
//! six coordinates, with slopes that depend on ξ₁ (the interaction terms); the estimator
//! therefore integrates ξ₁ on a grid and the rest in closed form ([`super::marginal`]). Two
//! residual terms are measured from the same fit:
//! * ε, the event-to-event scatter of one vehicle (unbalance phases, road-noise realisation,
//!   sensor offset, the rattle's chaos, §12): `within[c]`, the 3 × 3 covariance of the
//!   residuals about each vehicle's own mean residual;
//! * η, what the linear law misses for one vehicle, the same for all its events: `between[c]`,
//!   the covariance of the vehicles' mean residuals less the part ε explains.
//!
//! What it is not: a model of the physics (the shimmy model makes the data) or the estimator
//! (which uses [`LinearModel::predict`] only). The fit runs once, in `shimmy calibrate`; it
//! needs more vehicles than regressors.

use nalgebra::{DMatrix, DVector, Matrix3, SymmetricEigen};
use serde::{Deserialize, Serialize};

use super::emulate::{lstsq, RawEvent, N_COORDS};

/// Features of the model: ln RMS, ln peak, cruise.
pub const N_FEAT: usize = 3;
/// The coordinate that enters nonlinearly: the kingpin damping c_s.
pub const DAMPING: usize = 1;
/// Basis functions: intercept, deceleration, the seven coordinates, ξ₁², ξ₁³ and ξ₁·ξ_j for the
/// six j ≠ 1.
pub const N_BASIS: usize = 2 + N_COORDS + 2 + (N_COORDS - 1);
/// Coordinates integrated in closed form (all but [`DAMPING`]).
pub const N_LIN: usize = N_COORDS - 1;

/// The regressors of one event of a vehicle at `xi`, braking at `decel_g`.
pub fn basis(xi: &[f64; N_COORDS], decel_g: f64) -> [f64; N_BASIS] {
    let mut r = [0.0; N_BASIS];
    r[0] = 1.0;
    r[1] = (decel_g - 0.55) / 0.25;
    r[2..2 + N_COORDS].copy_from_slice(xi);
    let x1 = xi[DAMPING];
    r[2 + N_COORDS] = x1 * x1;
    r[3 + N_COORDS] = x1 * x1 * x1;
    for (k, j) in (0..N_COORDS).filter(|&j| j != DAMPING).enumerate() {
        r[4 + N_COORDS + k] = x1 * xi[j];
    }
    r
}

/// Index of coordinate `j ≠ DAMPING` among the closed-form ones.
pub fn lin_index(j: usize) -> usize {
    if j < DAMPING {
        j
    } else {
        j - 1
    }
}

/// The fitted model (a field of [`super::table::ResponseTable`]).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct LinearModel {
    /// Drawn vehicles the fit used.
    pub vehicles: u32,
    /// Coefficients of [`basis`], index `(ic · n_speed + iv) · 3 + f`.
    pub coef: Vec<[f64; N_BASIS]>,
    /// Total residual standard deviation per clearance and feature (ε and η together).
    pub total_std: Vec<[f64; N_FEAT]>,
    /// Correlation of the total ln RMS and ln peak residuals per clearance.
    pub total_corr: Vec<f64>,
    /// Covariance of ε (one vehicle's event scatter) per clearance.
    pub within: Vec<[[f64; N_FEAT]; N_FEAT]>,
    /// Covariance of η (the per-vehicle misfit of the linear law) per clearance.
    pub between: Vec<[[f64; N_FEAT]; N_FEAT]>,
}

/// What the model predicts for one event at one clearance and damping coordinate ξ₁: the
/// feature means at ξ_j = 0 (j ≠ 1) and η = 0 (`a`) and their slopes in the six other
/// coordinates (`b`, in the order of [`lin_index`]). The covariances depend on the clearance
/// only: [`LinearModel::within_at`], [`LinearModel::between_at`].
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

fn dot(a: &[f64; N_BASIS], b: &[f64; N_BASIS]) -> f64 {
    a.iter().zip(b).map(|(x, y)| x * y).sum()
}

fn to_arr(m: &Matrix3<f64>) -> [[f64; 3]; 3] {
    std::array::from_fn(|i| std::array::from_fn(|j| round5(m[(i, j)])))
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

/// Fits the model on `raw` (the drawn vehicles' events; vehicle `im` has coordinates
/// `table_coords[im]`) for `n_clearance` × `n_speed` grid cells. `min_std` floors each
/// feature's spread.
pub fn fit(
    raw: &[RawEvent],
    table_coords: &[[f64; N_COORDS]],
    n_clearance: usize,
    n_speed: usize,
    min_std: f64,
) -> anyhow::Result<LinearModel> {
    let nm = table_coords.len();
    let mut coef = vec![[0.0; N_BASIS]; n_clearance * n_speed * N_FEAT];
    let mut total_std = Vec::with_capacity(n_clearance);
    let mut total_corr = Vec::with_capacity(n_clearance);
    let mut within = Vec::with_capacity(n_clearance);
    let mut between = Vec::with_capacity(n_clearance);
    for ic in 0..n_clearance {
        // Residuals of this clearance, with their vehicle.
        let mut res: Vec<(usize, [f64; N_FEAT])> = Vec::new();
        let mut n_params = 0usize;
        for iv in 0..n_speed {
            let rows: Vec<&RawEvent> = raw.iter().filter(|e| e.ic == ic && e.iv == iv).collect();
            if rows.len() <= N_BASIS {
                anyhow::bail!(
                    "the linear nuisance model needs more than {N_BASIS} events per \
                     clearance and speed (vehicles × decelerations × seeds), not {}",
                    rows.len()
                );
            }
            let x = DMatrix::from_fn(rows.len(), N_BASIS, |i, k| {
                basis(&table_coords[rows[i].im], rows[i].decel_g)[k]
            });
            let mut r_f: Vec<DVector<f64>> = Vec::with_capacity(N_FEAT);
            for f in 0..N_FEAT {
                let y = DVector::from_fn(rows.len(), |i, _| rows[i].z[f]);
                let (beta, r) = lstsq(&x, &y)?;
                let c = &mut coef[(ic * n_speed + iv) * N_FEAT + f];
                for (k, b) in beta.iter().enumerate() {
                    c[k] = round5(*b);
                }
                r_f.push(r);
            }
            for (i, e) in rows.iter().enumerate() {
                res.push((e.im, std::array::from_fn(|f| r_f[f][i])));
            }
            n_params += N_BASIS;
        }
        let n = res.len() as f64;
        // The regression used n_params degrees of freedom: scale the residual moments up.
        let dof_scale = n / (n - n_params as f64).max(1.0);
        let mut total = Matrix3::zeros();
        let mut sum_m = vec![[0.0f64; N_FEAT]; nm];
        let mut cnt_m = vec![0usize; nm];
        for (im, r) in &res {
            let v = nalgebra::Vector3::from(*r);
            total += v * v.transpose();
            for f in 0..N_FEAT {
                sum_m[*im][f] += r[f];
            }
            cnt_m[*im] += 1;
        }
        total *= dof_scale / n;
        // Each vehicle's mean residual (vehicles without events here stay at zero, unused).
        let mean_m: Vec<nalgebra::Vector3<f64>> = sum_m
            .iter()
            .zip(&cnt_m)
            .map(|(s, &k)| nalgebra::Vector3::from(s.map(|x| x / k.max(1) as f64)))
            .collect();
        let mut w = Matrix3::zeros();
        for (im, r) in &res {
            let d = nalgebra::Vector3::from(*r) - mean_m[*im];
            w += d * d.transpose();
        }
        let used = cnt_m.iter().filter(|&&k| k > 0).count();
        let per_vehicle = n / used.max(1) as f64;
        w *= dof_scale / (n - used as f64).max(1.0);
        let mut b = Matrix3::zeros();
        for (mu, _) in mean_m.iter().zip(&cnt_m).filter(|(_, &k)| k > 0) {
            b += mu * mu.transpose();
        }
        b *= dof_scale / used.max(1) as f64;
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
        coef,
        total_std,
        total_corr,
        within,
        between,
    })
}

impl LinearModel {
    /// Checks the shape against the table's axes and that the covariances are usable.
    pub fn validate(&self, n_clearance: usize, n_speed: usize) -> anyhow::Result<()> {
        if self.coef.len() != n_clearance * n_speed * N_FEAT
            || self.total_std.len() != n_clearance
            || self.total_corr.len() != n_clearance
            || self.within.len() != n_clearance
            || self.between.len() != n_clearance
        {
            anyhow::bail!("the table's linear model does not match its clearance × speed axes");
        }
        let finite = self.coef.iter().flatten().all(|v| v.is_finite())
            && self
                .total_std
                .iter()
                .flatten()
                .all(|v| v.is_finite() && *v > 0.0);
        if !finite {
            anyhow::bail!("the table's linear model has non-finite coefficients or spreads");
        }
        for (ic, (w, b)) in self.within.iter().zip(&self.between).enumerate() {
            if mat3(w).cholesky().is_none() || !(0..N_FEAT).all(|i| b[i][i] >= 0.0) {
                anyhow::bail!(
                    "the table's linear model has an invalid covariance at clearance {ic}"
                );
            }
        }
        Ok(())
    }

    /// Speeds of the table the model was fitted on.
    fn n_speed(&self) -> usize {
        self.coef.len() / (self.within.len() * N_FEAT).max(1)
    }

    /// The coefficients of feature `f` at grid clearance `ic` and grid speed `iv`.
    pub fn coef_at(&self, ic: usize, iv: usize, f: usize) -> &[f64; N_BASIS] {
        &self.coef[(ic * self.n_speed() + iv) * N_FEAT + f]
    }

    /// The mean of feature `f` at grid clearance `ic` and speed `iv` for the regressors `r`
    /// ([`basis`]).
    pub fn mean_at(&self, ic: usize, iv: usize, f: usize, r: &[f64; N_BASIS]) -> f64 {
        dot(r, self.coef_at(ic, iv, f))
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

    /// The prediction at clearance position `(ic, wc)` (between grid clearances `ic` and
    /// `ic + 1`, weight `wc` on the second, linear in ln c), speed position `(iv, wv)`,
    /// deceleration `decel_g` and damping coordinate `xi1`. No allocation.
    pub fn predict(
        &self,
        (ic, wc): (usize, f64),
        (iv, wv): (usize, f64),
        decel_g: f64,
        xi1: f64,
    ) -> LinearPrediction {
        let (nc, nv) = (self.within.len(), self.n_speed());
        let mut p = LinearPrediction::default();
        let mut at = [0.0; N_COORDS];
        at[DAMPING] = xi1;
        // The basis at ξ_j = 0 (j ≠ 1) gives the mean; its ξ₁-dependent slopes follow.
        let r = basis(&at, decel_g);
        for (dc, fc) in [(0usize, 1.0 - wc), (1, wc)] {
            for (dv, fv) in [(0usize, 1.0 - wv), (1, wv)] {
                let f = fc * fv;
                if f == 0.0 {
                    continue;
                }
                let (jc, jv) = ((ic + dc).min(nc - 1), (iv + dv).min(nv - 1));
                for k in 0..N_FEAT {
                    let b = self.coef_at(jc, jv, k);
                    p.a[k] += f * dot(&r, b);
                    for (l, j) in (0..N_COORDS).filter(|&j| j != DAMPING).enumerate() {
                        p.b[k][l] += f * (b[2 + j] + b[4 + N_COORDS + l] * xi1);
                    }
                }
            }
        }
        p
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

    /// Events from a known law, nonlinear in the damping coordinate ξ₁, with a per-vehicle
    /// offset (η, std 0.15) and event noise (ε, std 0.1): the fit recovers the law and tells the
    /// two spreads apart.
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
                        let base = -3.0 + 0.1 * iv as f64 + 0.5 * xi[1]
                            - 0.4 * xi[1].powi(3)
                            - 0.2 * xi[5]
                            + 0.3 * xi[1] * xi[5]
                            + eta[im];
                        let z =
                            std::array::from_fn(|f| base + 0.1 * f as f64 + 0.1 * gauss(&mut rng));
                        raw.push(RawEvent {
                            ic: 0,
                            im,
                            iv,
                            decel_g: d,
                            z,
                        });
                    }
                }
            }
        }
        let lm = fit(&raw, &coords, 1, 3, 0.02).unwrap();
        lm.validate(1, 3).unwrap();
        for iv in 0..3 {
            let b = &lm.coef[iv * 3];
            assert!((b[2 + 1] - 0.5).abs() < 0.06, "{b:?}");
            assert!((b[2 + 5] + 0.2).abs() < 0.06, "{b:?}");
            assert!(b[2].abs() < 0.06, "{b:?}");
        }
        let w = lm.within[0][0][0].sqrt();
        let t = lm.between[0][0][0].sqrt();
        assert!((w - 0.1).abs() < 0.02, "within {w}");
        assert!((t - 0.15).abs() < 0.05, "between {t}");
        // η is shared by the features: the between covariance says so.
        let r = lm.between[0][0][1] / (lm.between[0][0][0] * lm.between[0][1][1]).sqrt();
        assert!(r > 0.8, "between correlation {r}");
        // At ξ₁ = 0.8 the mean carries 0.5·ξ₁ − 0.4·ξ₁³ and the slope of ξ₅ is −0.2 + 0.3·ξ₁.
        let p = lm.predict((0, 0.0), (1, 0.5), 0.55, 0.8);
        let want = -3.0 + 0.15 + 0.4 - 0.4 * 0.512;
        assert!((p.a[0] - want).abs() < 0.08, "{:?} vs {want}", p.a);
        assert!(
            (p.b[0][lin_index(5)] - (-0.2 + 0.24)).abs() < 0.08,
            "{:?}",
            p.b
        );
    }
}
