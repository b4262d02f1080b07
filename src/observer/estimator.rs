//! Clearance estimation from the response table ([`super::table`]): a posterior over a
//! clearance grid, updated by each used braking event. Two methods (`[estimator] method`):
//!
//! * `"linear"` (the default): the vehicle's nuisances integrated out continuously on the
//!   table's linear nuisance model, on a grid 4× finer than the table's clearances, with
//!   tempered evidence (`evidence_power`) and fading evidence for wear; see
//!   [`super::marginal`], which does the work. This module then only keeps the grid marginal
//!   and its summaries.
//! * `"mixture"`: a mixture over the table's drawn nuisance vehicles, described below.
//!
//! Method "mixture":
//!
//! * Vehicle-level nuisances: stiffness, damping, unbalance and road-noise level are the same for
//!   all of a vehicle's events, so the events are NOT independent given the clearance. The
//!   posterior is kept jointly over (clearance c, nuisance vehicle θ_m) for the table's M
//!   nuisance vehicles ([`ResponseTable::n_vehicles`]); events multiply likelihoods within one
//!   θ_m and the clearance posterior is the mixture over m,
//!   p(c | events) ∝ p(c) · (1/M) Σ_m Π_e p(z_e | c, θ_m).
//!   Thirty events then pin down "which vehicle × which clearance", and clearances that some
//!   plausible vehicle explains equally well stay in the interval (the independent-event
//!   product of a pooled spread would exclude them and be overconfident).
//! * Prior: uniform in ln c over the grid (clearances span an order of magnitude), uniform over m.
//! * Event update: the log-likelihood of the event's z ([`super::features::z`]: floored logs of
//!   the band-passed RMS and peak) under each (c, θ_m)'s predicted bivariate normal
//!   ([`ResponseTable::predict`] at the event's speed and deceleration), with the predicted
//!   spread inflated by `std_inflation` (model mismatch) and a small outlier floor so one odd
//!   event cannot veto a clearance. With a v3 table and `cruise = true`, the event's pre-brake
//!   cruise statistic ([`super::features::z_cruise`]) adds an independent normal term: the
//!   same vehicle's unbalance response before the brake, which separates a large unbalance on
//!   tight joints from a rattle on worn ones.
//! * Between events: a random walk in ln c with variance `wear_var_per_km · distance`, so the
//!   estimate can follow slow growth (wear) and old events count less.
//! * Summary: posterior median and 5 %/95 % quantiles (piecewise log-linear CDF over the grid),
//!   `P(c > threshold)` for the clearance alert, and `detectable = q05 > detection_limit`: when
//!   the posterior cannot exclude the detection limit the estimate is reported as "below
//!   max(q95, detection limit)".
//!
//! Memory: vectors of length (clearances × M) for "mixture", the fixed-size statistics of
//! [`super::marginal`] for "linear", allocated in [`Estimator::new`]; updates do not allocate.

use serde::{Deserialize, Serialize};

use super::table::ResponseTable;

/// Estimator settings (`[estimator]` of config/observer.toml).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct EstimatorConfig {
    /// Multiplies the table's predicted standard deviations (model mismatch, unmodelled sensor).
    pub std_inflation: f64,
    /// Probability floor of an outlier event (relative to the peak density).
    pub outlier_floor: f64,
    /// Random-walk variance of ln c per km driven (wear).
    pub wear_var_per_km: f64,
    /// Clearances below this are reported as "below …" (mm).
    pub detection_limit_mm: f64,
    /// Which features enter the likelihood: "rms", "peak" or "both".
    pub features: String,
    /// Use the pre-brake cruise statistic when the table has it.
    pub cruise: bool,
    /// "mixture": over the table's drawn nuisance vehicles (this module); "linear": the
    /// nuisances marginalised continuously on the table's linear model ([`super::marginal`]).
    pub method: String,
    /// Method "linear": grid points per step of the table's clearance axis.
    pub grid_refine: usize,
    /// Method "linear": distance (km) over which an event's evidence halves (wear); 0 = never.
    pub evidence_half_life_km: f64,
    /// Method "linear": standard deviation (ln units) of a vehicle's offset from the table's
    /// model in each feature, shared by all its events (model mismatch at vehicle level).
    pub misfit_std: f64,
    /// Method "linear": standard deviation (ln units) added to `misfit_std` once the vehicle
    /// has baseline events ([`Estimator::update_baseline`]): the events at a known clearance
    /// then say how far the vehicle sits from the table's model, which a car that is not the
    /// model (a sensor gain, a transfer the table does not have) may do by more than the
    /// table's own vehicles spread.
    pub baseline_misfit_std: f64,
    /// Method "linear": grid points of the kingpin-damping coordinate (1-64).
    pub damping_grid: usize,
    /// Method "linear": power on the events' joint likelihood (0 < p ≤ 1). Below 1 it widens
    /// the posterior without moving its peak: the events count as fewer than they are, for
    /// what the model misses that is shared between them.
    pub evidence_power: f64,
    /// Method "linear": `evidence_power` of the torsion-bar torque's estimator (a torque table
    /// misses other things than an angle table, so its events are tempered on their own).
    pub torque_evidence_power: f64,
    /// Method "linear": the wheels' unbalance phase difference is the same in all of the
    /// vehicle's events ("vehicle"), new in each ("event"), or either, as the events say
    /// ("either"); see [`super::marginal`].
    pub phase: String,
    /// Method "linear": grid points of the phase difference (hypothesis "vehicle", 1-64).
    pub phase_grid: usize,
    /// Method "linear": grid points of any further coordinate the table's model grids (e.g.
    /// the unbalance, 1-64).
    pub unbalance_grid: usize,
    /// The clearances (mm) the monitored vehicles are expected to have: the prior is uniform
    /// in ln c over [low, high] and falls off outside as a half-normal in ln c with
    /// `prior_tail` as its standard deviation. Unset: uniform in ln c over the table's whole
    /// clearance axis (which is what the estimator did before this key existed).
    pub prior_range_mm: Option<[f64; 2]>,
    /// Standard deviation (ln units) of the prior's fall-off outside `prior_range_mm`; 0 cuts
    /// it off there.
    pub prior_tail: f64,
    /// Method "linear": the goodness-of-fit score ([`super::fit`]) above which the report
    /// says the model does not fit the vehicle (its interval is not to be trusted).
    pub fit_z_max: f64,
    /// How much more the vehicle's steering-wheel signal moves than the table's vehicle's for
    /// the same wheel motion (the steering-wheel transfer, MODEL.md §8 and §15): the braking
    /// and cruise features are divided by it before they meet the table. 1 = the table's
    /// vehicle. For a car whose transfer is known to differ (its steering ratio against the
    /// table's); one vehicle's features cannot tell it from a clearance change, nor a fleet of
    /// unknown clearances (docs/ACCURACY.md, "self-calibration"); a car model's fleet at new
    /// joints can: the profile's correction ([`super::correction`]), whose gains multiply this.
    pub transfer_gain: f64,
}

impl Default for EstimatorConfig {
    /// Method "linear" with the settings chosen on dev fleet seeds 90000-90039
    /// (docs/ACCURACY.md).
    fn default() -> Self {
        EstimatorConfig {
            std_inflation: 1.0,
            outlier_floor: 1e-3,
            wear_var_per_km: 1e-4,
            detection_limit_mm: 0.08,
            features: "both".into(),
            cruise: true,
            method: "linear".into(),
            grid_refine: 4,
            evidence_half_life_km: 5000.0,
            misfit_std: 0.0,
            baseline_misfit_std: 0.5,
            damping_grid: 9,
            evidence_power: 0.275,
            torque_evidence_power: 0.2,
            phase: "either".into(),
            phase_grid: 8,
            unbalance_grid: 7,
            prior_range_mm: None,
            prior_tail: 0.0,
            fit_z_max: FIT_Z_MAX,
            transfer_gain: 1.0,
        }
    }
}

/// Default of [`EstimatorConfig::fit_z_max`].
pub const FIT_Z_MAX: f64 = 4.5;

impl EstimatorConfig {
    /// Checks every setting; the error names the key as `estimator.<key>` (shimmyd prefixes
    /// its `observer.` table).
    pub fn validate(&self) -> anyhow::Result<()> {
        let positive = |key: &str, v: f64| {
            if v.is_finite() && v > 0.0 {
                Ok(())
            } else {
                Err(anyhow::anyhow!("estimator.{key}: must be > 0 (got {v})"))
            }
        };
        let non_negative = |key: &str, v: f64| {
            if v.is_finite() && v >= 0.0 {
                Ok(())
            } else {
                Err(anyhow::anyhow!("estimator.{key}: must be >= 0 (got {v})"))
            }
        };
        positive("std_inflation", self.std_inflation)?;
        if !(self.outlier_floor > 0.0 && self.outlier_floor < 1.0) {
            anyhow::bail!(
                "estimator.outlier_floor: must be a probability strictly between 0 and 1 (got {})",
                self.outlier_floor
            );
        }
        non_negative("wear_var_per_km", self.wear_var_per_km)?;
        positive("detection_limit_mm", self.detection_limit_mm)?;
        if !matches!(self.features.as_str(), "rms" | "peak" | "both") {
            anyhow::bail!(
                "estimator.features: must be \"rms\", \"peak\" or \"both\" (got \"{}\")",
                self.features
            );
        }
        if !matches!(self.method.as_str(), "linear" | "mixture") {
            anyhow::bail!(
                "estimator.method: must be mixture or linear (got \"{}\")",
                self.method
            );
        }
        for (key, p) in [
            ("evidence_power", self.evidence_power),
            ("torque_evidence_power", self.torque_evidence_power),
        ] {
            if !(p > 0.0 && p <= 1.0) {
                anyhow::bail!("estimator.{key}: must be in (0, 1] (got {p})");
            }
        }
        non_negative("misfit_std", self.misfit_std)?;
        non_negative("baseline_misfit_std", self.baseline_misfit_std)?;
        non_negative("evidence_half_life_km", self.evidence_half_life_km)?;
        if super::marginal::PhaseMode::parse(&self.phase).is_none() {
            anyhow::bail!(
                "estimator.phase: must be \"vehicle\", \"event\" or \"either\" (got \"{}\")",
                self.phase
            );
        }
        if let Some([lo, hi]) = self.prior_range_mm {
            if !(lo.is_finite() && hi.is_finite() && lo > 0.0 && hi > lo) {
                anyhow::bail!(
                    "estimator.prior_range_mm: must be [low, high] with 0 < low < high (got \
                     [{lo}, {hi}])"
                );
            }
        }
        non_negative("prior_tail", self.prior_tail)?;
        positive("fit_z_max", self.fit_z_max)?;
        if !(self.transfer_gain.is_finite() && (0.05..=20.0).contains(&self.transfer_gain)) {
            anyhow::bail!(
                "estimator.transfer_gain: must be in [0.05, 20] (got {})",
                self.transfer_gain
            );
        }
        for (key, v) in [
            ("grid_refine", self.grid_refine),
            ("damping_grid", self.damping_grid),
            ("phase_grid", self.phase_grid),
            ("unbalance_grid", self.unbalance_grid),
        ] {
            if !(1..=64).contains(&v) {
                anyhow::bail!("estimator.{key}: must be 1-64 (got {v})");
            }
        }
        Ok(())
    }

    /// Method "mixture" with its own tuned spread inflation (2.0, dev fleet seeds
    /// 90000-90013): for tables without the linear model.
    pub fn mixture() -> Self {
        EstimatorConfig {
            method: "mixture".into(),
            std_inflation: 2.0,
            ..EstimatorConfig::default()
        }
    }
}

/// ln of the clearance prior at each grid point `ln_c` (up to a constant; see
/// [`EstimatorConfig::prior_range_mm`]).
fn log_prior(ln_c: &[f64], cfg: &EstimatorConfig) -> anyhow::Result<Vec<f64>> {
    let Some([lo, hi]) = cfg.prior_range_mm else {
        return Ok(vec![0.0; ln_c.len()]);
    };
    let (a, b) = (lo.ln(), hi.ln());
    let lp: Vec<f64> = ln_c
        .iter()
        .map(|&x| {
            let d = if x < a { a - x } else { (x - b).max(0.0) };
            if d == 0.0 {
                0.0
            } else if cfg.prior_tail > 0.0 {
                -0.5 * (d / cfg.prior_tail).powi(2)
            } else {
                f64::NEG_INFINITY
            }
        })
        .collect();
    if lp.iter().all(|l| *l == f64::NEG_INFINITY) {
        anyhow::bail!(
            "estimator.prior_range_mm: [{lo}, {hi}] mm holds none of the table's clearances \
             ({:.3}-{:.3} mm) and prior_tail is 0",
            ln_c.first().map_or(0.0, |x| x.exp()),
            ln_c.last().map_or(0.0, |x| x.exp())
        );
    }
    Ok(lp)
}

/// What the posterior says now.
#[derive(Clone, Copy, Debug, PartialEq, Serialize)]
pub struct Summary {
    pub median_mm: f64,
    pub q05_mm: f64,
    pub q95_mm: f64,
    /// `q05 > detection_limit`.
    pub detectable: bool,
    /// What a clearance that is not detectable is reported to be below (mm): the 95 % quantile,
    /// but never less than the detection limit. Under the limit the posterior's shape rests on
    /// features that hardly change with clearance (MODEL.md §13: the steering wheel's floor from
    /// unbalance and road noise), so the estimator does not claim to resolve it.
    pub below_mm: f64,
    pub events_used: u32,
}

impl Summary {
    /// A posterior's summary from its 5 %, 50 % and 95 % quantiles (mm): detectable when the
    /// 5 % quantile is above `detection_limit_mm`, else "below" the 95 % quantile but never
    /// below the limit.
    pub fn from_quantiles(
        q05_mm: f64,
        median_mm: f64,
        q95_mm: f64,
        detection_limit_mm: f64,
        events_used: u32,
    ) -> Summary {
        Summary {
            median_mm,
            q05_mm,
            q95_mm,
            detectable: q05_mm > detection_limit_mm,
            below_mm: q95_mm.max(detection_limit_mm),
            events_used,
        }
    }
}

/// The running posterior.
pub struct Estimator {
    cfg: EstimatorConfig,
    /// Method "linear": the continuous marginalisation (then the mixture's `log_p` is empty).
    /// Boxed: its scratch holds fixed-size term arrays (tens of KB), which would otherwise
    /// make every move of an estimator, and of the observer holding several, that large on
    /// the stack.
    linear: Option<Box<super::marginal::LinearPosterior>>,
    ln_c: Vec<f64>,
    /// Nuisance vehicles M.
    n_m: usize,
    /// Joint log posterior, index `ic · M + im`.
    log_p: Vec<f64>,
    scratch: Vec<f64>,
    /// Marginal posterior probabilities over the clearance grid.
    marg: Vec<f64>,
    /// ln of the clearance prior at each grid point (up to a constant).
    log_prior: Vec<f64>,
    use_rms: bool,
    use_peak: bool,
    last_odometer_m: Option<f64>,
    events_used: u32,
    baseline_events: u32,
    /// What each feature (braking RMS, peak, cruise RMS) is divided by before it meets the
    /// table: the transfer gain times the correction's gain.
    gain: [f64; 3],
    /// The car model's correction applied, if any.
    correction: Option<super::correction::Correction>,
}

impl Estimator {
    /// An estimator on `table` with the settings `cfg`, applying the table's correction
    /// ([`ResponseTable::correction`], from the car model's profile) when it has one.
    pub fn new(table: &ResponseTable, cfg: EstimatorConfig) -> anyhow::Result<Estimator> {
        Self::with_correction(table, cfg, table.correction.as_ref())
    }

    /// [`Self::new`] with the car model's correction given ([`super::correction`]): each
    /// feature divided by its gain (and the transfer gain) before it meets the table, the
    /// vehicle's misfit prior widened by the correction's spread and uncertainty.
    pub fn with_correction(
        table: &ResponseTable,
        cfg: EstimatorConfig,
        correction: Option<&super::correction::Correction>,
    ) -> anyhow::Result<Estimator> {
        Self::build(table, cfg, correction, None)
    }

    /// An estimator whose clearance grid is the one clearance `clearance_mm`: for
    /// [`Self::push_baseline`] and [`Self::baseline_ln_evidence`] only (the correction's fit,
    /// which evaluates many of them), not for estimates.
    pub(crate) fn for_baseline_fit(
        table: &ResponseTable,
        cfg: EstimatorConfig,
        correction: Option<&super::correction::Correction>,
        clearance_mm: f64,
    ) -> anyhow::Result<Estimator> {
        anyhow::ensure!(
            cfg.method == "linear",
            "a baseline fit needs method \"linear\""
        );
        Self::build(table, cfg, correction, Some(clearance_mm))
    }

    /// Whether an estimator on `table` with `cfg` can be built ([`Self::new`]), without
    /// holding a whole one: with method "linear", built on one clearance of the table's axis
    /// (the same checks of the settings, the nuisance model and its prior, at a fraction of
    /// the memory); otherwise built whole and dropped.
    pub(crate) fn check(table: &ResponseTable, cfg: EstimatorConfig) -> anyhow::Result<()> {
        match table.clearance_mm.first() {
            Some(&c) if cfg.method == "linear" => {
                Self::build(table, cfg, table.correction.as_ref(), Some(c)).map(drop)
            }
            _ => Self::new(table, cfg).map(drop),
        }
    }

    fn build(
        table: &ResponseTable,
        cfg: EstimatorConfig,
        correction: Option<&super::correction::Correction>,
        only_at_mm: Option<f64>,
    ) -> anyhow::Result<Estimator> {
        cfg.validate()?;
        let g = cfg.transfer_gain;
        let gain = match correction {
            Some(c) => {
                c.validate()?;
                [g * c.gain[0], g * c.gain[1], g * c.gain[2]]
            }
            None => [g; 3],
        };
        let mut lp_cfg = cfg.clone();
        if let Some(c) = correction {
            lp_cfg.misfit_std = (cfg.misfit_std * cfg.misfit_std + c.extra_var()).sqrt();
        }
        let (use_rms, use_peak) = (cfg.features != "peak", cfg.features != "rms");
        let (linear, ln_c, n_m) = if cfg.method == "linear" {
            let lm = table.linear.as_ref().ok_or_else(|| {
                anyhow::anyhow!(
                    "estimator.method = \"linear\" needs a response table with a linear \
                     nuisance model (rebuild it with `shimmy calibrate`)"
                )
            })?;
            let (ln_c, pos) = match only_at_mm {
                Some(c) => (
                    vec![c.ln()],
                    vec![super::marginal::axis_position(&table.clearance_mm, c)],
                ),
                None => super::marginal::fine_grid(&table.clearance_mm, cfg.grid_refine),
            };
            let lp = super::marginal::LinearPosterior::new(table, lm, pos, &lp_cfg)?;
            // The mixture's joint vectors stay empty.
            (Some(Box::new(lp)), ln_c, 0)
        } else {
            if table.n_vehicles() == 0 {
                anyhow::bail!(
                    "estimator.method = \"mixture\" needs a response table with drawn-vehicle \
                     cells (build one with `shimmy calibrate --mixture-vehicles N`)"
                );
            }
            let ln_c = table.clearance_mm.iter().map(|c| c.ln()).collect();
            (None, ln_c, table.n_vehicles())
        };
        let n = ln_c.len();
        let joint = n * n_m;
        let log_prior = log_prior(&ln_c, &cfg)?;
        let mut marg: Vec<f64> = log_prior.iter().map(|l| l.exp()).collect();
        let total: f64 = marg.iter().sum();
        marg.iter_mut().for_each(|m| *m /= total);
        let log_p = (0..joint)
            .map(|i| marg[i / n_m.max(1)].ln() - (n_m.max(1) as f64).ln())
            .collect();
        Ok(Estimator {
            linear,
            log_p,
            scratch: vec![0.0; joint],
            marg,
            log_prior,
            n_m,
            ln_c,
            use_rms,
            use_peak,
            last_odometer_m: None,
            events_used: 0,
            baseline_events: 0,
            gain,
            correction: correction.cloned(),
            cfg,
        })
    }

    pub fn config(&self) -> &EstimatorConfig {
        &self.cfg
    }

    /// Log-likelihood of z (and the cruise statistic `zc`, when given) under a prediction
    /// (bivariate or one marginal, times the cruise term). Allocates nothing.
    fn loglik(&self, z: [f64; 2], zc: Option<f64>, p: &super::table::Prediction) -> f64 {
        let k = self.cfg.std_inflation;
        let (s0, s1) = (p.std[0] * k, p.std[1] * k);
        let d0 = (z[0] - p.mean[0]) / s0;
        let d1 = (z[1] - p.mean[1]) / s1;
        let (mut q, mut log_norm) = match (self.use_rms, self.use_peak) {
            (true, true) => {
                let r = p.corr.clamp(-0.95, 0.95);
                let om = 1.0 - r * r;
                (
                    (d0 * d0 - 2.0 * r * d0 * d1 + d1 * d1) / om,
                    -(s0 * s1 * om.sqrt()).ln(),
                )
            }
            (true, false) => (d0 * d0, -s0.ln()),
            _ => (d1 * d1, -s1.ln()),
        };
        if let Some(zc) = zc {
            let sc = p.cruise[1] * k;
            let dc = (zc - p.cruise[0]) / sc;
            q += dc * dc;
            log_norm -= sc.ln();
        }
        let core = -0.5 * q;
        // Outlier floor: log(exp(core) + floor).
        let m = core.max(self.cfg.outlier_floor.ln());
        log_norm + m + ((core - m).exp() + (self.cfg.outlier_floor.ln() - m).exp()).ln()
    }

    /// Random walk in ln c over `dist_km` (Gaussian kernel on the grid), for each nuisance
    /// vehicle (wear changes the joint, not the vehicle).
    fn diffuse(&mut self, dist_km: f64) {
        let var = self.cfg.wear_var_per_km * dist_km.max(0.0);
        if var <= 0.0 {
            return;
        }
        let n = self.ln_c.len();
        let nm = self.n_m;
        let mx = self.log_p.iter().copied().fold(f64::NEG_INFINITY, f64::max);
        for im in 0..nm {
            for i in 0..n {
                let mut s = 0.0;
                let mut wsum = 0.0;
                for j in 0..n {
                    let d = self.ln_c[i] - self.ln_c[j];
                    let w = (-0.5 * d * d / var).exp();
                    s += w * (self.log_p[j * nm + im] - mx).exp();
                    wsum += w;
                }
                self.scratch[i * nm + im] = (s / wsum.max(1e-300)).max(1e-300).ln() + mx;
            }
        }
        std::mem::swap(&mut self.log_p, &mut self.scratch);
        self.normalise();
    }

    /// Normalises the joint posterior and recomputes the clearance marginal.
    fn normalise(&mut self) {
        let mx = self.log_p.iter().copied().fold(f64::NEG_INFINITY, f64::max);
        let s: f64 = self.log_p.iter().map(|l| (l - mx).exp()).sum();
        let ln_s = s.ln() + mx;
        for l in &mut self.log_p {
            *l -= ln_s;
        }
        for (ic, m) in self.marg.iter_mut().enumerate() {
            *m = self.log_p[ic * self.n_m..(ic + 1) * self.n_m]
                .iter()
                .map(|l| l.exp())
                .sum();
        }
    }

    /// Posterior probability of each nuisance vehicle of the table (sums to 1).
    pub fn vehicle_probabilities(&self) -> impl Iterator<Item = f64> + '_ {
        (0..self.n_m).map(move |im| {
            (0..self.ln_c.len())
                .map(|ic| self.log_p[ic * self.n_m + im].exp())
                .sum()
        })
    }

    /// Uses `other`'s per-event scratch instead of its own (method "linear", both;
    /// [`super::marginal::LinearPosterior::share_scratch`]): for estimators of one vehicle,
    /// which take their events one after another. The estimates are unchanged.
    pub fn share_scratch(&mut self, other: &Estimator) {
        if let (Some(mine), Some(theirs)) = (self.linear.as_mut(), other.linear.as_ref()) {
            mine.share_scratch(theirs);
        }
    }

    /// Adds one used event: its braking features, speed, deceleration and odometer (m).
    pub fn update(
        &mut self,
        table: &ResponseTable,
        rms_deg: f64,
        peak_deg: f64,
        v0_kmh: f64,
        decel_g: f64,
        odometer_m: f64,
    ) {
        self.update_event(table, rms_deg, peak_deg, None, v0_kmh, decel_g, odometer_m);
    }

    /// [`Self::update`] with the event's pre-brake cruise RMS (deg), used when the table has the
    /// cruise statistic and the config enables it.
    #[allow(clippy::too_many_arguments)]
    pub fn update_event(
        &mut self,
        table: &ResponseTable,
        rms_deg: f64,
        peak_deg: f64,
        cruise_rms_deg: Option<f64>,
        v0_kmh: f64,
        decel_g: f64,
        odometer_m: f64,
    ) {
        let dist_km = self
            .last_odometer_m
            .map(|prev| (odometer_m - prev) / 1000.0);
        self.last_odometer_m = Some(odometer_m);
        let cruise_rms_deg = cruise_rms_deg.filter(|_| self.cfg.cruise && table.cruise);
        let ln_jac = self.ln_jacobian(rms_deg, peak_deg, cruise_rms_deg);
        let (z3, mask) = self.features(rms_deg, peak_deg, cruise_rms_deg);
        let (z, zc) = ([z3[0], z3[1]], mask[2].then_some(z3[2]));
        if let Some(lp) = self.linear.as_mut() {
            if let Some(d) = dist_km {
                lp.forget(d);
            }
            lp.update(z3, &mask, v0_kmh, decel_g);
            lp.add_ln_jacobian(ln_jac);
            lp.probabilities_into(&mut self.marg, &self.log_prior);
            self.events_used += 1;
            return;
        }
        if let Some(d) = dist_km {
            self.diffuse(d);
        }
        for ic in 0..self.ln_c.len() {
            for im in 0..self.n_m {
                let p = table.predict(ic, im, v0_kmh, decel_g);
                self.log_p[ic * self.n_m + im] += self.loglik(z, zc, &p);
            }
        }
        self.normalise();
        self.events_used += 1;
    }

    /// Adds one event of this vehicle at a known clearance `clearance_mm` (its joints' when
    /// the event was driven, e.g. new ones after a replacement): a baseline event. It tells the
    /// estimator about the vehicle (its nuisances and how far its features sit from the table's
    /// model), not about its clearance now; the estimate becomes the one given the baseline
    /// (src/observer/marginal.rs). Returns false, adding nothing, for the `"mixture"` method,
    /// which has no shared vehicle terms to condition.
    #[allow(clippy::too_many_arguments)]
    pub fn update_baseline(
        &mut self,
        table: &ResponseTable,
        rms_deg: f64,
        peak_deg: f64,
        cruise_rms_deg: Option<f64>,
        v0_kmh: f64,
        decel_g: f64,
        clearance_mm: f64,
    ) -> bool {
        if !self.push_baseline(
            table,
            rms_deg,
            peak_deg,
            cruise_rms_deg,
            v0_kmh,
            decel_g,
            clearance_mm,
        ) {
            return false;
        }
        if let Some(lp) = self.linear.as_mut() {
            lp.probabilities_into(&mut self.marg, &self.log_prior);
        }
        true
    }

    /// Σ ln dz_table/dz_measured of the features that enter, under the gains
    /// ([`super::features::ln_jacobian_gain`]); 0 at gains 1.
    fn ln_jacobian(&self, rms_deg: f64, peak_deg: f64, cruise_rms_deg: Option<f64>) -> f64 {
        use super::features::{ln_jacobian_gain as lj, Z_FLOOR_DEG as F};
        let g = self.gain;
        let mut j = 0.0;
        if self.use_rms && g[0] != 1.0 {
            j += lj(rms_deg, F[0], g[0]);
        }
        if self.use_peak && g[1] != 1.0 {
            j += lj(peak_deg, F[1], g[1]);
        }
        if let Some(c) = cruise_rms_deg.filter(|_| g[2] != 1.0) {
            j += lj(c, F[0], g[2]);
        }
        j
    }

    /// [`Self::update_baseline`] without refreshing the posterior: for a caller that adds many
    /// baseline events and then asks only [`Self::baseline_ln_evidence`] (the correction's
    /// fit). Returns false for the `"mixture"` method.
    #[allow(clippy::too_many_arguments)]
    pub fn push_baseline(
        &mut self,
        table: &ResponseTable,
        rms_deg: f64,
        peak_deg: f64,
        cruise_rms_deg: Option<f64>,
        v0_kmh: f64,
        decel_g: f64,
        clearance_mm: f64,
    ) -> bool {
        let cruise_rms_deg = cruise_rms_deg.filter(|_| self.cfg.cruise && table.cruise);
        let ln_jac = self.ln_jacobian(rms_deg, peak_deg, cruise_rms_deg);
        let (z3, mask) = self.features(rms_deg, peak_deg, cruise_rms_deg);
        let Some(lp) = self.linear.as_mut() else {
            return false;
        };
        let pos = super::marginal::axis_position(&table.clearance_mm, clearance_mm);
        lp.update_known(z3, &mask, v0_kmh, decel_g, pos);
        lp.add_baseline_ln_jacobian(ln_jac);
        self.baseline_events += 1;
        true
    }

    /// ln of the baseline events' marginal likelihood at their known clearance, the vehicle's
    /// nuisances and misfit integrated out, with the evidence power and the gains' Jacobian
    /// ([`super::marginal::LinearPosterior::baseline_ln_evidence`]); `None` without baseline
    /// events or for the `"mixture"` method.
    pub fn baseline_ln_evidence(&self) -> Option<f64> {
        self.linear.as_ref()?.baseline_ln_evidence()
    }

    /// The car model's correction applied ([`Self::with_correction`]), if any.
    pub fn correction(&self) -> Option<&super::correction::Correction> {
        self.correction.as_ref()
    }

    /// An event's features as the table reads them (ln RMS, ln peak, ln cruise RMS after the
    /// transfer gain and the correction's gains) and which of them enter (the cruise when
    /// measured).
    fn features(
        &self,
        rms_deg: f64,
        peak_deg: f64,
        cruise_rms_deg: Option<f64>,
    ) -> ([f64; 3], [bool; 3]) {
        let g = self.gain;
        let z = super::features::z(rms_deg / g[0], peak_deg / g[1]);
        let zc = cruise_rms_deg.map(|c| super::features::z_cruise(c / g[2]));
        (
            [z[0], z[1], zc.unwrap_or(0.0)],
            [self.use_rms, self.use_peak, zc.is_some()],
        )
    }

    /// Baseline events added ([`Self::update_baseline`]).
    pub fn baseline_events(&self) -> u32 {
        self.baseline_events
    }

    /// Posterior probabilities on the clearance grid (marginal over the nuisance vehicles).
    pub fn probabilities(&self) -> impl Iterator<Item = f64> + '_ {
        self.marg.iter().copied()
    }

    /// Grid cell edges in ln c: midpoints, with half-steps beyond the ends.
    fn edge(&self, k: usize) -> f64 {
        let n = self.ln_c.len();
        if k == 0 {
            self.ln_c[0] - 0.5 * (self.ln_c[1] - self.ln_c[0])
        } else if k == n {
            self.ln_c[n - 1] + 0.5 * (self.ln_c[n - 1] - self.ln_c[n - 2])
        } else {
            0.5 * (self.ln_c[k - 1] + self.ln_c[k])
        }
    }

    /// The `q`-quantile (mm), mass spread uniformly in ln c over each grid cell.
    pub fn quantile_mm(&self, q: f64) -> f64 {
        let mut acc = 0.0;
        let n = self.ln_c.len();
        for k in 0..n {
            let p = self.marg[k];
            if acc + p >= q && p > 0.0 {
                let f = ((q - acc) / p).clamp(0.0, 1.0);
                let (a, b) = (self.edge(k), self.edge(k + 1));
                return (a + f * (b - a)).exp();
            }
            acc += p;
        }
        self.edge(n).exp()
    }

    /// The clearances (mm) the posterior's mass lies between: the grid's outer cell edges.
    pub fn support_mm(&self) -> (f64, f64) {
        (self.edge(0).exp(), self.edge(self.ln_c.len()).exp())
    }

    /// Posterior probability that c exceeds `c_mm`.
    pub fn prob_above(&self, c_mm: f64) -> f64 {
        let x = c_mm.ln();
        let mut s = 0.0;
        for k in 0..self.ln_c.len() {
            let (a, b) = (self.edge(k), self.edge(k + 1));
            let frac = ((b - x) / (b - a)).clamp(0.0, 1.0);
            s += self.marg[k] * frac;
        }
        s.clamp(0.0, 1.0)
    }

    pub fn summary(&self) -> Summary {
        Summary::from_quantiles(
            self.quantile_mm(0.05),
            self.quantile_mm(0.5),
            self.quantile_mm(0.95),
            self.cfg.detection_limit_mm,
            self.events_used,
        )
    }

    pub fn events_used(&self) -> u32 {
        self.events_used
    }

    /// Method "linear": the events' deviance from the table's model at its best clearance and
    /// grid point, and its degrees of freedom ([`super::marginal::LinearPosterior::fit`]).
    pub fn fit(&self) -> Option<(f64, f64)> {
        self.linear.as_ref()?.fit()
    }

    /// Method "linear": ln of the events' marginal likelihood under the table's model,
    /// `[with the evidence power, without]` ([`super::marginal::LinearPosterior::ln_evidence`]).
    pub fn ln_evidence(&self) -> Option<[f64; 2]> {
        self.linear.as_ref()?.ln_evidence()
    }

    /// Method "linear" with `phase = "either"`: the posterior probability that the wheels'
    /// unbalance phase difference stayed the same over the events ([`super::marginal`]).
    pub fn phase_fixed_probability(&self) -> Option<f64> {
        if self.events_used == 0 {
            return None;
        }
        self.linear.as_ref()?.phase_fixed_probability()
    }
}
