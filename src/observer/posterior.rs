//! The clearance posterior the report reads: one estimator's, or a weighted mixture of several.
//!
//! With a profile's chassis variants (`[[chassis.variants]]`) each steering channel (the
//! torque's, and the angle's where the variants name angle tables) keeps one estimator per
//! response table, each fed every event. Each table `k` is a model of the car
//! (MODEL.md §9 and §15 with its own scrub radius or kingpin damping, or with uneven brake
//! discs drawn per table vehicle, §14); its posterior weight is
//! its prior times the events' tempered marginal likelihood under it, normalised
//! (`w_k ∝ π_k · p(events | table k)^λ`). The clearance posterior is then
//!
//! ```text
//! p(c | events) = Σ_k w_k · p(c | events, table k)
//! ```
//!
//! (Bayesian model averaging): while the events cannot tell two tables apart, the interval
//! spans both tables' readings and the alert probability is their weighted mean, instead of
//! following whichever table leads by a hair. Once one table carries nearly all the weight the
//! mixture is that table's posterior.
//!
//! What this is not: a fit of a chassis parameter between the tables (a car at 7.5 mm scrub
//! is read as a mixture of the 0 and 10 mm tables, not with a 7.5 mm one), nor a check that
//! any table fits ([`super::fit`] does that for the most probable one).
//!
//! Allocation: a view borrows the estimators and holds their weights; it is built per report,
//! not per frame.

use super::estimator::{Estimator, Summary};

/// A posterior over the clearance: the estimators' marginal posteriors weighed by `weights`
/// (positive, summing to 1), the most probable first.
pub struct Posterior<'a> {
    parts: Vec<(f64, &'a Estimator)>,
}

/// Weights below this are left out of the mixture: they move no quantile by a visible amount
/// and would cost a CDF evaluation each.
const WEIGHT_FLOOR: f64 = 1e-6;

impl<'a> Posterior<'a> {
    /// One estimator's posterior.
    pub fn single(e: &'a Estimator) -> Posterior<'a> {
        Posterior {
            parts: vec![(1.0, e)],
        }
    }

    /// The mixture of `parts` (weight, estimator); weights that are not finite and positive
    /// are dropped, the rest normalised. `None` when no part is left.
    pub fn mixture(parts: impl IntoIterator<Item = (f64, &'a Estimator)>) -> Option<Posterior<'a>> {
        let mut parts: Vec<(f64, &Estimator)> = parts
            .into_iter()
            .filter(|(w, _)| w.is_finite() && *w > 0.0)
            .collect();
        let z: f64 = parts.iter().map(|p| p.0).sum();
        if parts.is_empty() || !(z > 0.0) {
            return None;
        }
        for p in &mut parts {
            p.0 /= z;
        }
        parts.retain(|p| p.0 >= WEIGHT_FLOOR);
        let z: f64 = parts.iter().map(|p| p.0).sum();
        for p in &mut parts {
            p.0 /= z;
        }
        parts.sort_by(|a, b| b.0.total_cmp(&a.0));
        Some(Posterior { parts })
    }

    /// The most probable estimator (its detection limit is the summary's).
    pub fn leading(&self) -> &'a Estimator {
        self.parts[0].1
    }

    /// How many estimators carry weight.
    pub fn len(&self) -> usize {
        self.parts.len()
    }

    pub fn is_empty(&self) -> bool {
        self.parts.is_empty()
    }

    /// Posterior probability that c exceeds `c_mm`: the weighted mean of the parts'.
    pub fn prob_above(&self, c_mm: f64) -> f64 {
        self.parts
            .iter()
            .map(|(w, e)| w * e.prob_above(c_mm))
            .sum::<f64>()
            .clamp(0.0, 1.0)
    }

    /// The `q`-quantile (mm) of the mixture: for one part its own; otherwise the clearance
    /// where the mixture's CDF reaches `q`, found by bisection in ln c over the parts'
    /// supports (each part's CDF is continuous and monotone, so is their mean).
    pub fn quantile_mm(&self, q: f64) -> f64 {
        if self.parts.len() == 1 {
            return self.parts[0].1.quantile_mm(q);
        }
        let (mut lo, mut hi) = self
            .parts
            .iter()
            .map(|(_, e)| e.support_mm())
            .fold((f64::INFINITY, f64::NEG_INFINITY), |(lo, hi), (a, b)| {
                (lo.min(a.ln()), hi.max(b.ln()))
            });
        let cdf = |x: f64| 1.0 - self.prob_above(x.exp());
        // 60 halvings of a range of a few units in ln c: far below the grid's resolution.
        for _ in 0..60 {
            let mid = 0.5 * (lo + hi);
            if cdf(mid) < q {
                lo = mid;
            } else {
                hi = mid;
            }
        }
        (0.5 * (lo + hi)).exp()
    }

    /// The summary the report and the alerts read: median and 90 % interval of the mixture,
    /// detectability by the leading estimator's detection limit.
    pub fn summary(&self) -> Summary {
        let lead = self.leading();
        if self.parts.len() == 1 {
            return lead.summary();
        }
        Summary::from_quantiles(
            self.quantile_mm(0.05),
            self.quantile_mm(0.5),
            self.quantile_mm(0.95),
            lead.config().detection_limit_mm,
            self.parts
                .iter()
                .map(|(_, e)| e.events_used())
                .max()
                .unwrap_or(0),
        )
    }
}
