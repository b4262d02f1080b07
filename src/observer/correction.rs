//! A car model's correction to a response table, learned from many of its vehicles at new
//! joints (pooled baselines), and the fit that learns it.
//!
//! What it is: per steering signal (angle or torsion-bar torque), a gain per feature (braking
//! RMS, braking peak, pre-brake cruise RMS: [`super::features`]) by which this car model's
//! signal reads stronger than the table's model for the same wheel motion, with the fit's
//! standard errors, and a spread τ (ln units) of the vehicles about it. The estimator divides
//! each measured feature by its gain before it meets the table (as `[estimator]
//! transfer_gain` does for a known transfer) and widens the vehicle's misfit prior η of
//! src/observer/marginal.rs by τ² plus the gains' squared standard errors, so that the
//! correction's own uncertainty reaches the interval.
//!
//! Why from vehicles at new joints: a gain on the signal (a steering ratio or column transfer
//! the table does not have, MODEL.md §8 and §15, or a torque sensor's N·m per count) moves the
//! features along the direction a clearance change moves them, so one vehicle's events cannot
//! tell it from clearance, and a fleet of unknown clearances cannot either (docs/ACCURACY.md,
//! "a steering-wheel transfer learned from the fleet"). Drives at a known clearance can: each
//! vehicle's first drives when new (or after a joint replacement), the same events
//! `shimmy estimate --baseline` takes. One vehicle's baseline splits its offset between its own
//! nuisances (a rough road, a large unbalance: within the table's prior) and the model misfit;
//! over many vehicles the nuisances average to their prior while a gain shared by the car model
//! does not, so the pooled fit pins it.
//!
//! The fit (empirical Bayes): the gains g and the spread τ that maximise
//! Σ_v ln p(z_v | c_b, g, τ), each vehicle's baseline events z_v at the known clearance c_b
//! with its nuisances and misfit integrated out on the table's linear model (the estimator's
//! own marginal likelihood, [`super::marginal::LinearPosterior::baseline_ln_evidence`], with
//! the evidence power and the Jacobian of the gain, src/observer/features.rs
//! `ln_jacobian_gain`); the gains' standard errors from the curvature of that sum.
//!
//! What it is not: a model of where the mismatch comes from. A constant gain is exact for a
//! sensor scale or a transfer; a clearance-independent excitation the model lacks (a scrub
//! radius, a brake-torque variation) raises the signal at new joints more than on a rattle, and
//! the gain learned at new joints then over-corrects worn joints (docs/ACCURACY.md measures
//! both). It assumes the drives' clearance: new joints sit at about 0.02–0.06 mm, and a fleet
//! whose "new" joints are not new learns a gain that hides their wear.

use serde::{Deserialize, Serialize};

use super::estimator::{Estimator, EstimatorConfig};
use super::features::SteerSignal;
use super::table::ResponseTable;

/// Features per event (braking RMS, braking peak, pre-brake cruise RMS).
pub const N_FEAT: usize = 3;

/// One signal's correction ([`CorrectionFile`]).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Correction {
    /// By how much this car model's signal reads stronger than the table's model, per feature
    /// (braking RMS, braking peak, cruise RMS); 1 = the table's model.
    pub gain: [f64; N_FEAT],
    /// Standard error of ln gain per feature (0 where the feature was not observed and its gain
    /// left at 1).
    pub gain_se_ln: [f64; N_FEAT],
    /// The vehicles' spread about the car model's gains beyond the table's own (ln units).
    pub spread_ln: f64,
    /// Vehicles and baseline events the fit used, and their clearance (mm).
    pub vehicles: u32,
    pub events: u32,
    pub clearance_mm: f64,
    /// Fingerprint of the table the correction was fitted against
    /// ([`ResponseTable::fingerprint`]); a profile refuses it with another table.
    pub table_fingerprint: String,
    /// ln-likelihood gained over no correction (the fitted gains and spread against gains 1
    /// and spread 0), with the evidence power: how much the fleet says.
    #[serde(default)]
    pub ln_likelihood_gain: f64,
    /// Whether the features' gains agree with one gain shared by all: the p-value of a Wald
    /// test of their differences, with the fit's covariance ([`gains_agree_p`]). A small value
    /// says the car model differs from the table's by more than a signal gain (a scrub
    /// radius, a brake disc variation, another column), which the correction cannot make
    /// honest: below [`GAINS_DISAGREE_P`] every estimate with this correction says the model
    /// does not fit (src/observer/fit.rs). `None` where fewer than two gains were fitted (and
    /// in files written before it).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub gains_agree_p: Option<f64>,
}

impl Correction {
    /// Variance (ln units²) added to the vehicle's misfit prior: the spread and the gains'
    /// uncertainty.
    pub fn extra_var(&self) -> f64 {
        let se2 = self.gain_se_ln.iter().map(|s| s * s).sum::<f64>() / N_FEAT as f64;
        self.spread_ln * self.spread_ln + se2
    }

    /// Refuses values the estimator cannot use.
    pub fn validate(&self) -> anyhow::Result<()> {
        for (i, g) in self.gain.iter().enumerate() {
            anyhow::ensure!(
                g.is_finite() && (0.05..=20.0).contains(g),
                "gain[{i}] must be in [0.05, 20] (got {g})"
            );
        }
        for (i, s) in self.gain_se_ln.iter().enumerate() {
            anyhow::ensure!(
                s.is_finite() && *s >= 0.0,
                "gain_se_ln[{i}] must be ≥ 0 (got {s})"
            );
        }
        if let Some(p) = self.gains_agree_p {
            anyhow::ensure!(
                (0.0..=1.0).contains(&p),
                "gains_agree_p must be a probability (got {p})"
            );
        }
        anyhow::ensure!(
            self.spread_ln.is_finite() && (0.0..=2.0).contains(&self.spread_ln),
            "spread_ln must be in [0, 2] (got {})",
            self.spread_ln
        );
        Ok(())
    }
}

/// The file a profile names as `correction` (TOML): one section per signal whose table was
/// corrected.
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct CorrectionFile {
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub angle_deg: Option<Correction>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub torque_nm: Option<Correction>,
}

impl CorrectionFile {
    pub fn load(path: &std::path::Path) -> anyhow::Result<CorrectionFile> {
        use anyhow::Context;
        let text = std::fs::read_to_string(path)
            .with_context(|| format!("cannot read correction {}", path.display()))?;
        let f: CorrectionFile =
            toml::from_str(&text).with_context(|| format!("correction {}", path.display()))?;
        for (name, c) in [("angle_deg", &f.angle_deg), ("torque_nm", &f.torque_nm)] {
            if let Some(c) = c {
                c.validate()
                    .with_context(|| format!("correction {}: [{name}]", path.display()))?;
            }
        }
        Ok(f)
    }

    /// The section of `signal`.
    pub fn of(&self, signal: SteerSignal) -> Option<&Correction> {
        match signal {
            SteerSignal::AngleDeg => self.angle_deg.as_ref(),
            SteerSignal::TorqueNm => self.torque_nm.as_ref(),
        }
    }

    pub fn set(&mut self, signal: SteerSignal, c: Correction) {
        match signal {
            SteerSignal::AngleDeg => self.angle_deg = Some(c),
            SteerSignal::TorqueNm => self.torque_nm = Some(c),
        }
    }
}

/// One baseline event's features in the signal's unit and its conditions.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct FitEvent {
    pub rms: f64,
    pub peak: f64,
    pub cruise_rms: Option<f64>,
    pub v0_kmh: f64,
    pub decel_g: f64,
}

/// Bounds of the fit: ln gain within ±ln 5, spread within [0.005, 1].
const LN_GAIN_MAX: f64 = 1.609;
const SPREAD_MIN: f64 = 0.005;
const SPREAD_MAX: f64 = 1.0;

/// Σ over the vehicles of ln p(baseline events | c_b, gains, spread) (with the evidence
/// power), `theta` = (ln gain per feature, ln spread); −∞ outside the bounds.
fn objective(
    table: &ResponseTable,
    cfg: &EstimatorConfig,
    vehicles: &[Vec<FitEvent>],
    clearance_mm: f64,
    theta: &[f64; N_FEAT + 1],
) -> anyhow::Result<f64> {
    if theta[..N_FEAT].iter().any(|t| t.abs() > LN_GAIN_MAX)
        || !(SPREAD_MIN.ln()..=SPREAD_MAX.ln()).contains(&theta[N_FEAT])
    {
        return Ok(f64::NEG_INFINITY);
    }
    let corr = Correction {
        gain: [theta[0].exp(), theta[1].exp(), theta[2].exp()],
        gain_se_ln: [0.0; N_FEAT],
        spread_ln: theta[N_FEAT].exp(),
        vehicles: 0,
        events: 0,
        clearance_mm,
        table_fingerprint: String::new(),
        ln_likelihood_gain: 0.0,
        gains_agree_p: None,
    };
    // Each vehicle's term on its own thread's share of the vehicles; summed in vehicle order,
    // so the result does not depend on the number of threads.
    let one = |events: &Vec<FitEvent>| -> anyhow::Result<f64> {
        let mut est = Estimator::for_baseline_fit(table, cfg.clone(), Some(&corr), clearance_mm)?;
        for e in events {
            est.push_baseline(
                table,
                e.rms,
                e.peak,
                e.cruise_rms,
                e.v0_kmh,
                e.decel_g,
                clearance_mm,
            );
        }
        Ok(est.baseline_ln_evidence().unwrap_or(0.0))
    };
    let threads = std::thread::available_parallelism()
        .map_or(1, |n| n.get())
        .min(vehicles.len())
        .max(1);
    let chunk = vehicles.len().div_ceil(threads);
    let parts: Vec<anyhow::Result<Vec<f64>>> = std::thread::scope(|sc| {
        let handles: Vec<_> = vehicles
            .chunks(chunk)
            .map(|vs| sc.spawn(move || vs.iter().map(one).collect::<anyhow::Result<Vec<f64>>>()))
            .collect();
        handles
            .into_iter()
            .map(|h| {
                h.join()
                    .unwrap_or_else(|_| Err(anyhow::anyhow!("a fit thread panicked")))
            })
            .collect()
    });
    let mut total = 0.0;
    for p in parts {
        total += p?.iter().sum::<f64>();
    }
    Ok(total)
}

/// Nelder–Mead maximisation of `f` from `x0` with initial steps `step`; dimensions whose step
/// is 0 stay fixed.
fn maximise<const N: usize>(
    mut f: impl FnMut(&[f64; N]) -> anyhow::Result<f64>,
    x0: [f64; N],
    step: [f64; N],
    iters: usize,
) -> anyhow::Result<([f64; N], f64)> {
    let free: Vec<usize> = (0..N).filter(|&i| step[i] != 0.0).collect();
    let mut simplex: Vec<([f64; N], f64)> = Vec::with_capacity(free.len() + 1);
    simplex.push((x0, f(&x0)?));
    for &i in &free {
        let mut x = x0;
        x[i] += step[i];
        simplex.push((x, f(&x)?));
    }
    let by_value = |a: &([f64; N], f64), b: &([f64; N], f64)| b.1.total_cmp(&a.1);
    for _ in 0..iters {
        simplex.sort_by(by_value);
        let n = simplex.len() - 1;
        let spread = simplex[0].1 - simplex[n].1;
        if spread.is_finite() && spread.abs() < 1e-4 {
            break;
        }
        let mut centroid = [0.0; N];
        for (x, _) in &simplex[..n] {
            for i in 0..N {
                centroid[i] += x[i] / n as f64;
            }
        }
        let along = |t: f64, worst: &[f64; N]| {
            let mut x = [0.0; N];
            for i in 0..N {
                x[i] = centroid[i] + t * (worst[i] - centroid[i]);
            }
            x
        };
        let worst = simplex[n].0;
        let xr = along(-1.0, &worst);
        let fr = f(&xr)?;
        if fr > simplex[0].1 {
            let xe = along(-2.0, &worst);
            let fe = f(&xe)?;
            simplex[n] = if fe > fr { (xe, fe) } else { (xr, fr) };
        } else if fr > simplex[n - 1].1 {
            simplex[n] = (xr, fr);
        } else {
            let xc = along(0.5, &worst);
            let fc = f(&xc)?;
            if fc > simplex[n].1 {
                simplex[n] = (xc, fc);
            } else {
                let best = simplex[0].0;
                for vertex in simplex.iter_mut().skip(1) {
                    let mut x = vertex.0;
                    for i in 0..N {
                        x[i] = best[i] + 0.5 * (x[i] - best[i]);
                    }
                    *vertex = (x, f(&x)?);
                }
            }
        }
    }
    simplex.sort_by(by_value);
    Ok(simplex[0])
}

/// Fits one signal's correction to `table` from each vehicle's baseline events at
/// `clearance_mm` (module doc), with the estimator settings `cfg` (their per-vehicle baseline
/// widening is not applied: the spread is what the fit estimates). `progress` is called after
/// each evaluation of the objective with their count.
pub fn fit(
    table: &ResponseTable,
    cfg: &EstimatorConfig,
    vehicles: &[Vec<FitEvent>],
    clearance_mm: f64,
    mut progress: impl FnMut(usize),
) -> anyhow::Result<Correction> {
    anyhow::ensure!(
        cfg.method == "linear",
        "a correction is fitted on the estimator's method \"linear\" (the config sets \"{}\")",
        cfg.method
    );
    anyhow::ensure!(
        table.linear.is_some(),
        "the table has no linear nuisance model (rebuild it with `shimmy calibrate`)"
    );
    anyhow::ensure!(
        clearance_mm.is_finite() && clearance_mm > 0.0,
        "the baseline clearance must be above 0 mm (got {clearance_mm})"
    );
    let vehicles: Vec<Vec<FitEvent>> = vehicles.iter().filter(|v| !v.is_empty()).cloned().collect();
    anyhow::ensure!(
        vehicles.len() >= 2,
        "a correction needs baseline events of at least 2 vehicles (got {})",
        vehicles.len()
    );
    let mut cfg = cfg.clone();
    cfg.baseline_misfit_std = 0.0;
    let events: usize = vehicles.iter().map(Vec::len).sum();
    let cruise_seen =
        cfg.cruise && table.cruise && vehicles.iter().flatten().any(|e| e.cruise_rms.is_some());
    let use_rms = cfg.features != "peak";
    let use_peak = cfg.features != "rms";
    let mut step = [0.1, 0.1, 0.1, 0.7];
    if !use_rms {
        step[0] = 0.0;
    }
    if !use_peak {
        step[1] = 0.0;
    }
    if !cruise_seen {
        step[2] = 0.0;
    }
    let mut evals = 0usize;
    let mut f = |th: &[f64; N_FEAT + 1]| {
        evals += 1;
        progress(evals);
        objective(table, &cfg, &vehicles, clearance_mm, th)
    };
    let start = [0.0, 0.0, 0.0, 0.05f64.ln()];
    let l0 = f(&[0.0, 0.0, 0.0, SPREAD_MIN.ln()])?;
    let (mut best, mut l_best) = maximise(&mut f, start, step, 400)?;
    // A restart from the optimum: Nelder–Mead can stall on a ridge.
    let (b2, l2) = maximise(&mut f, best, step.map(|s| s * 0.5), 400)?;
    if l2 > l_best {
        (best, l_best) = (b2, l2);
    }
    anyhow::ensure!(
        l_best.is_finite(),
        "the baseline events have no finite likelihood under the table's model at {clearance_mm} mm"
    );
    // Standard errors: the curvature of the objective in the free ln gains.
    let free: Vec<usize> = (0..N_FEAT).filter(|&i| step[i] != 0.0).collect();
    let h = 0.02;
    let k = free.len();
    let mut hess = nalgebra::DMatrix::<f64>::zeros(k, k);
    for (a, &i) in free.iter().enumerate() {
        for (b, &j) in free.iter().enumerate().skip(a) {
            let mut val = |di: f64, dj: f64| {
                let mut x = best;
                x[i] += di;
                x[j] += dj;
                f(&x)
            };
            let d = if i == j {
                (val(h, 0.0)? - 2.0 * l_best + val(-h, 0.0)?) / (h * h)
            } else {
                (val(h, h)? - val(h, -h)? - val(-h, h)? + val(-h, -h)?) / (4.0 * h * h)
            };
            hess[(a, b)] = d;
            hess[(b, a)] = d;
        }
    }
    let mut se = [0.0; N_FEAT];
    let mut agree_p = None;
    if k > 0 {
        let cov = (-hess)
            .try_inverse()
            .filter(|c| (0..k).all(|a| c[(a, a)].is_finite() && c[(a, a)] > 0.0));
        let Some(cov) = cov else {
            anyhow::bail!(
                "the fleet's baseline events do not pin the gains (the likelihood is flat or not \
                 at a maximum): more vehicles, or more events per vehicle"
            );
        };
        for (a, &i) in free.iter().enumerate() {
            se[i] = cov[(a, a)].sqrt();
        }
        let ln_g: Vec<f64> = free.iter().map(|&i| best[i]).collect();
        agree_p = gains_agree_p(&ln_g, &cov);
    }
    Ok(Correction {
        gain: [best[0].exp(), best[1].exp(), best[2].exp()],
        gain_se_ln: se,
        spread_ln: best[N_FEAT].exp(),
        vehicles: vehicles.len() as u32,
        events: events as u32,
        clearance_mm,
        table_fingerprint: table.fingerprint.clone(),
        ln_likelihood_gain: l_best - l0,
        gains_agree_p: agree_p,
    })
}

/// Below this [`Correction::gains_agree_p`] the features' gains are said to disagree.
pub const GAINS_DISAGREE_P: f64 = 0.05;

/// The p-value of the hypothesis that the ln gains `ln_g` (covariance `cov`) are one gain: a
/// Wald test of their differences from the first, χ² with one degree of freedom fewer than
/// gains. `None` with fewer than two gains or a singular covariance of the differences.
///
/// The covariance is the fit's: of the likelihood with the estimator's evidence power, so the
/// test is as lenient as the estimator is with the model's misfit.
pub fn gains_agree_p(ln_g: &[f64], cov: &nalgebra::DMatrix<f64>) -> Option<f64> {
    let k = ln_g.len();
    if k < 2 || cov.nrows() != k || cov.ncols() != k {
        return None;
    }
    let m = k - 1;
    let d = nalgebra::DVector::from_fn(m, |a, _| ln_g[a + 1] - ln_g[0]);
    let s = nalgebra::DMatrix::from_fn(m, m, |a, b| {
        cov[(a + 1, b + 1)] - cov[(a + 1, 0)] - cov[(0, b + 1)] + cov[(0, 0)]
    });
    let w = (d.transpose() * s.try_inverse()? * &d)[(0, 0)];
    if !w.is_finite() || w < 0.0 {
        return None;
    }
    Some(chi2_sf(w, m))
}

/// P(χ²_m > w) for m = 1 or 2 (the only degrees of freedom three features give).
fn chi2_sf(w: f64, m: usize) -> f64 {
    match m {
        1 => erfc((w / 2.0).sqrt()),
        2 => (-w / 2.0).exp(),
        _ => {
            // Wilson–Hilferty: the cube root of χ²/m is close to normal.
            let mf = m as f64;
            let z = ((w / mf).cbrt() - (1.0 - 2.0 / (9.0 * mf))) / (2.0 / (9.0 * mf)).sqrt();
            0.5 * erfc(z / std::f64::consts::SQRT_2)
        }
    }
}

/// The complementary error function (Chebyshev fit, relative error below 1.2e-7).
fn erfc(x: f64) -> f64 {
    let z = x.abs();
    let t = 1.0 / (1.0 + 0.5 * z);
    let c = [
        -1.265_512_23,
        1.000_023_68,
        0.374_091_96,
        0.096_784_18,
        -0.186_288_06,
        0.278_868_07,
        -1.135_203_98,
        1.488_515_87,
        -0.822_152_23,
        0.170_872_77,
    ];
    let poly = c.iter().rev().fold(0.0, |acc, &ci| acc * t + ci);
    let r = t * (-z * z + poly).exp();
    if x >= 0.0 {
        r
    } else {
        2.0 - r
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::observer::emulate::draw_coords;
    use crate::observer::features::{z_cruise, Z_FLOOR_DEG};
    use crate::observer::linear::{vars, N_FEAT as NF};
    use rand::{Rng, SeedableRng};
    use rand_distr::{Distribution, StandardNormal};

    fn reference_table() -> ResponseTable {
        let p = std::path::Path::new(env!("CARGO_MANIFEST_DIR"))
            .join("config/vehicles/shimmy_reference/table.json");
        ResponseTable::load(&p).expect("the shipped reference table")
    }

    /// A feature value whose floored log ([`crate::observer::features::z`]) is `z`.
    fn unfloor(z: f64, floor: f64) -> f64 {
        ((2.0 * z).exp() - floor * floor).max(1e-6).sqrt()
    }

    /// Baseline events of `n` vehicles drawn from the table's own nuisance model at its
    /// clearance grid point `ic` (coordinates uniform on the prior, a misfit η from the
    /// model's between-vehicle covariance, each event's scatter from its within covariance),
    /// every feature read `gain` times stronger.
    fn draw_fleet(
        t: &ResponseTable,
        ic: usize,
        n: usize,
        gain: [f64; 3],
        seed: u64,
    ) -> Vec<Vec<FitEvent>> {
        let lm = t.linear.as_ref().expect("linear model");
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(seed);
        let chol = |m: nalgebra::Matrix3<f64>| m.cholesky().expect("covariance").l();
        let (lb, lw) = (
            chol(lm.between_at((ic, 0.0))),
            chol(lm.within_at((ic, 0.0))),
        );
        let normal3 = |rng: &mut rand_chacha::ChaCha8Rng| {
            nalgebra::Vector3::from_fn(|_, _| StandardNormal.sample(rng))
        };
        draw_coords(n, seed)
            .into_iter()
            .map(|xi| {
                let x = vars(&xi, rng.random_range(-1.0..=1.0));
                let eta = lb * normal3(&mut rng);
                (0..10)
                    .map(|_| {
                        let iv = rng.random_range(0..t.speed_kmh.len());
                        let decel_g = t.decel_g[rng.random_range(0..t.decel_g.len())];
                        let eps = lw * normal3(&mut rng);
                        let z: Vec<f64> = (0..NF)
                            .map(|f| lm.mean_at(ic, iv, f, &x, decel_g) + eta[f] + eps[f])
                            .collect();
                        FitEvent {
                            rms: gain[0] * unfloor(z[0], Z_FLOOR_DEG[0]),
                            peak: gain[1] * unfloor(z[1], Z_FLOOR_DEG[1]),
                            cruise_rms: Some(gain[2] * unfloor(z[2], Z_FLOOR_DEG[0])),
                            v0_kmh: t.speed_kmh[iv],
                            decel_g,
                        }
                    })
                    .collect()
            })
            .collect()
    }

    #[test]
    fn the_unfloor_helper_inverts_the_features_log() {
        let x = 0.3;
        assert!((unfloor(z_cruise(x), Z_FLOOR_DEG[0]) - x).abs() < 1e-12);
    }

    /// The pooled fit finds a gain the fleet's signals share (a sensor read 30 % high or low)
    /// and finds none where there is none, each within its interval.
    #[test]
    fn the_fit_recovers_a_shared_gain_and_no_gain_where_there_is_none() {
        let t = reference_table();
        let cfg = EstimatorConfig::default();
        let ic = t
            .clearance_mm
            .iter()
            .position(|&c| c >= 0.03)
            .expect("a clearance at new joints");
        let c_mm = t.clearance_mm[ic];
        for (gain, seed) in [(1.0, 1u64), (1.3, 2), (0.7, 3)] {
            let fleet = draw_fleet(&t, ic, 30, [gain; 3], seed);
            let c = fit(&t, &cfg, &fleet, c_mm, |_| {}).expect("fit");
            for f in 0..2 {
                let err = (c.gain[f] / gain).ln();
                assert!(
                    err.abs() < 3.0 * c.gain_se_ln[f] + 0.03,
                    "gain {gain}: feature {f} fitted {} ± {} (ln)",
                    c.gain[f],
                    c.gain_se_ln[f]
                );
                assert!(c.gain_se_ln[f] > 0.0 && c.gain_se_ln[f] < 0.15);
            }
            assert_eq!((c.vehicles, c.events), (30, 300));
            let p = c.gains_agree_p.expect("three gains fitted");
            assert!(p > GAINS_DISAGREE_P, "gain {gain}: one gain, yet p = {p}");
            if gain != 1.0 {
                assert!(c.ln_likelihood_gain > 3.0, "gain {gain}: {c:?}");
            }
        }
    }

    /// A fleet whose peak reads 40 % stronger than its RMS and cruise (a shake the model does
    /// not have, not a gain on the signal) is told apart: its gains disagree.
    #[test]
    fn gains_that_differ_between_features_are_said_to_disagree() {
        let t = reference_table();
        let cfg = EstimatorConfig::default();
        let ic = t.clearance_mm.iter().position(|&c| c >= 0.03).unwrap();
        let fleet = draw_fleet(&t, ic, 30, [1.0, 1.4, 1.0], 6);
        let c = fit(&t, &cfg, &fleet, t.clearance_mm[ic], |_| {}).expect("fit");
        let p = c.gains_agree_p.expect("three gains fitted");
        assert!(p < GAINS_DISAGREE_P, "{c:?}");
        assert!(c.gain[1] / c.gain[0] > 1.2, "{c:?}");
    }

    #[test]
    fn the_tail_probabilities_are_right() {
        // erfc(0) = 1, erfc(1) = 0.157299207, χ²₁ at 3.841 and χ²₂ at 5.991: 0.05.
        assert!((erfc(0.0) - 1.0).abs() < 1e-7);
        assert!((erfc(1.0) - 0.157_299_207).abs() < 1e-7);
        assert!((erfc(-1.0) - 1.842_700_793).abs() < 1e-7);
        assert!((chi2_sf(3.841_459, 1) - 0.05).abs() < 1e-6);
        assert!((chi2_sf(5.991_465, 2) - 0.05).abs() < 1e-6);
        let d = nalgebra::DMatrix::from_row_slice(2, 2, &[0.01, 0.0, 0.0, 0.01]);
        // Differences of 0.1 with variance 0.02: W = 0.5, p = erfc(0.5) = 0.4795.
        let p = gains_agree_p(&[0.0, 0.1], &d).unwrap();
        assert!((p - 0.479_500_122).abs() < 1e-6, "{p}");
        assert_eq!(
            gains_agree_p(&[0.3], &nalgebra::DMatrix::from_element(1, 1, 0.01)),
            None
        );
    }

    #[test]
    fn too_few_vehicles_and_a_bad_clearance_are_refused() {
        let t = reference_table();
        let cfg = EstimatorConfig::default();
        let fleet = draw_fleet(&t, 2, 1, [1.0; 3], 4);
        let e = fit(&t, &cfg, &fleet, 0.03, |_| {}).unwrap_err();
        assert!(e.to_string().contains("at least 2 vehicles"), "{e}");
        let e = fit(&t, &cfg, &draw_fleet(&t, 2, 3, [1.0; 3], 5), 0.0, |_| {}).unwrap_err();
        assert!(e.to_string().contains("above 0 mm"), "{e}");
    }

    #[test]
    fn a_correction_outside_its_ranges_is_refused() {
        let mut c = Correction {
            gain: [1.0; 3],
            gain_se_ln: [0.0; 3],
            spread_ln: 0.0,
            vehicles: 2,
            events: 20,
            clearance_mm: 0.03,
            table_fingerprint: String::new(),
            ln_likelihood_gain: 0.0,
            gains_agree_p: None,
        };
        assert!(c.validate().is_ok());
        c.gain[1] = 0.0;
        assert!(c.validate().is_err());
        c.gain[1] = 1.0;
        c.spread_ln = f64::NAN;
        assert!(c.validate().is_err());
    }
}
