//! Does the vehicle fit the table's model? A goodness-of-fit check on the clearance posterior.
//!
//! What it is: the events' deviance from the table's nuisance model at the posterior's best
//! clearance and nuisance grid point ([`super::marginal::LinearPosterior::fit`]). For a
//! vehicle the model describes, the deviance is χ²-distributed with about as many degrees of
//! freedom as features observed; [`ModelFit::z`] is its Wilson–Hilferty normal score (the cube
//! root of χ²/k is close to normal with mean 1 − 2/(9k) and variance 2/(9k)). A vehicle whose
//! events sit further from every clearance's prediction than the events' own scatter allows (a
//! steering that passes the wheels' motion on differently, a noise the table does not know)
//! has a large score, and its interval is then not to be trusted: the estimator says "the model
//! does not fit this vehicle" instead.
//!
//! What it is not: a test of the physics (a vehicle can fit the model's statistics and still
//! be estimated wrong), or meaningful with a handful of events (below [`MIN_DOF`] degrees of
//! freedom nothing is said).

use serde::Serialize;

/// Fewer observed features than this: no verdict.
pub const MIN_DOF: f64 = 12.0;

/// The fit check's result, in the report.
#[derive(Clone, Copy, Debug, PartialEq, Serialize)]
pub struct ModelFit {
    /// The events' deviance at the best clearance and grid point.
    pub deviance: f64,
    /// Its degrees of freedom (features observed, faded with the evidence).
    pub dof: f64,
    /// Wilson–Hilferty normal score of `deviance` under χ²(`dof`).
    pub z: f64,
    /// False when `z` exceeds the configured limit with at least [`MIN_DOF`] degrees of
    /// freedom, when the estimate's sensor is noisier than its table assumes, when the
    /// steering shakes at wheel order while braking ([`Self::wheel_order_shake`]), or when the
    /// car model's correction says the car model is not the table's
    /// ([`Self::correction_gains_disagree`]).
    pub fits: bool,
    /// The estimate's steering sensor measured noisier at standstill than its table assumes
    /// (src/observer/noise_floor.rs): the table does not describe this vehicle's sensor.
    #[serde(skip_serializing_if = "std::ops::Not::not")]
    pub sensor_noisier: bool,
    /// Median share of the braking band's power locked to the wheels' rotation beyond the
    /// cruise's (src/observer/wheel_order.rs), once enough events have one.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub wheel_order_share: Option<f64>,
    /// That share is above its limit: a shake at wheel order while braking (a disc thickness
    /// variation) the model does not have.
    #[serde(skip_serializing_if = "std::ops::Not::not")]
    pub wheel_order_shake: bool,
    /// The share is above its limit, but the events rule uneven discs out: the profile's
    /// uneven-discs table fits them far worse than another of its tables (its posterior
    /// probability below `DISCS_RULED_OUT`, src/observer/mod.rs), so the shake is the
    /// chassis's own (the unbalance through a scrub radius) and the verdict sends the car to
    /// its chassis, not its discs. `wheel_order_shake` stays true: the model still does not
    /// fit, and the alert's wheel-order pair still applies.
    #[serde(skip_serializing_if = "std::ops::Not::not")]
    pub wheel_order_discs_ruled_out: bool,
    /// The car model's correction the estimate applied found its features' gains unequal
    /// (`gains_agree_p` below `GAINS_DISAGREE_P`, src/observer/correction.rs): the car model
    /// passes the wheels' motion on to the steering otherwise than the table's model, by more
    /// than a gain, so no vehicle of it fits the table, whatever its own events' scatter.
    #[serde(skip_serializing_if = "std::ops::Not::not")]
    pub correction_gains_disagree: bool,
    /// ln of the events' marginal likelihood under the table's model (clearance prior and
    /// nuisances integrated out), with the evidence power: what a fleet-level fit of a
    /// per-car-model correction adds up over vehicles (`shimmy fleet-gain`).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub ln_evidence: Option<f64>,
    /// The same without the evidence power.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub ln_evidence_untempered: Option<f64>,
}

impl ModelFit {
    /// The check of `deviance` on `dof` degrees of freedom against the normal-score limit
    /// `z_max`.
    pub fn new(deviance: f64, dof: f64, z_max: f64) -> ModelFit {
        let z = wilson_hilferty(deviance, dof);
        ModelFit {
            deviance,
            dof,
            z,
            fits: !(dof >= MIN_DOF && z > z_max),
            sensor_noisier: false,
            wheel_order_share: None,
            wheel_order_shake: false,
            wheel_order_discs_ruled_out: false,
            correction_gains_disagree: false,
            ln_evidence: None,
            ln_evidence_untempered: None,
        }
    }
}

impl ModelFit {
    /// Marks the estimate's sensor as noisier than its table assumes (or not): the model then
    /// does not fit, whatever the deviance says.
    pub fn set_sensor_noisier(&mut self, noisier: bool) {
        self.sensor_noisier = noisier;
        if noisier {
            self.fits = false;
        }
    }

    /// Records the vehicle's median wheel-order share and whether it is past its limit: the
    /// model then does not fit, whatever the deviance says.
    pub fn set_wheel_order(&mut self, share: Option<f64>, shake: bool) {
        self.wheel_order_share = share;
        self.wheel_order_shake = shake;
        if shake {
            self.fits = false;
        }
    }

    /// Records whether the car model's correction found its features' gains unequal: the
    /// model then does not fit, whatever the deviance says.
    pub fn set_correction_gains_disagree(&mut self, disagree: bool) {
        self.correction_gains_disagree = disagree;
        if disagree {
            self.fits = false;
        }
    }
}

/// Normal score of `x` under χ²(`k`) (Wilson–Hilferty); 0 for k ≤ 0.
pub fn wilson_hilferty(x: f64, k: f64) -> f64 {
    if k <= 0.0 || !x.is_finite() {
        return 0.0;
    }
    let v = 2.0 / (9.0 * k);
    ((x.max(0.0) / k).cbrt() - (1.0 - v)) / v.sqrt()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_score_matches_chi_square_quantiles() {
        // χ²(60): median 59.33, 99.9 % quantile 99.61 (tables).
        assert!(wilson_hilferty(59.33, 60.0).abs() < 0.01);
        assert!((wilson_hilferty(99.61, 60.0) - 3.09).abs() < 0.02);
        // χ²(90): 95 % quantile 113.15.
        assert!((wilson_hilferty(113.15, 90.0) - 1.645).abs() < 0.02);
    }

    #[test]
    fn few_events_never_fail_the_check() {
        assert!(ModelFit::new(1e6, MIN_DOF - 1.0, 3.0).fits);
        assert!(!ModelFit::new(1e6, MIN_DOF, 3.0).fits);
        assert!(ModelFit::new(60.0, 60.0, 3.0).fits);
    }
}
