//! The response table, what the estimator compares measurements with: for a grid of
//! clearance × nuisance vehicle × initial speed × deceleration, the distribution of the
//! per-event features ([`super::features`]) the model predicts after the sensor model.
//!
//! The nuisances (±10 % on stiffness and damping, unbalance magnitude, road-noise
//! level) belong to a vehicle and are shared by all its braking events, so they are not
//! averaged into one spread: the table holds `vehicles` nuisance vehicles θ_m drawn from that
//! prior, the same θ_m at every clearance, and each cell describes the event-to-event spread
//! of ONE such vehicle (unbalance phases, road-noise realisation, sensor offset). The estimator
//! mixes over them: p(events | c) = (1/M) Σ_m Π_e p(z_e | c, θ_m). A table with `vehicles = 1`
//! is the older format whose cells pooled all nuisances into each event's spread.
//!
//! Each cell keeps the mean, standard deviation and correlation of z (floored logs of the
//! band-passed RMS and peak, [`super::features::z`]) and, from format v3 on, the mean and
//! standard deviation of the pre-brake cruise statistic ([`super::features::z_cruise`],
//! independent of z within a cell); [`ResponseTable::predict`] interpolates them bilinearly in
//! (speed, decel). The
//! table also keeps a calibration of the steering-wheel amplitude: how the true (continuous,
//! 1 kHz) band-passed peak relates to the measured noise-corrected RMS, used by the
//! `shimmy_55kmh` alert.
//!
//! The table is versioned by a hash of the vehicle parameters it was built from
//! ([`vehicle_hash`]); [`ResponseTable::check_vehicle`] refuses a mismatch. Building it needs the
//! model and lives in `shimmy calibrate` ([`crate::cli::calibrate`]); this module is the data
//! structure, its file format (JSON) and its lookups only.

use anyhow::{bail, Context};
use serde::{Deserialize, Serialize};

use super::sensor::SensorModel;
use super::simulate::NuisanceRanges;

pub const FORMAT: &str = "shimmy response table v4";
/// The format before the nuisance model took a list of terms: its `linear` (17 fixed
/// regressors, no unbalance phase) is dropped on load.
pub const FORMAT_V3: &str = "shimmy response table v3";
/// Without the cruise statistic (`cruise = false`).
pub const FORMAT_V2: &str = "shimmy response table v2";
/// The older format (one pooled nuisance distribution per cell); loads as `vehicles = 1`.
pub const FORMAT_V1: &str = "shimmy response table v1";

fn one() -> u32 {
    1
}

/// Distribution of z = (ln rms_deg, ln peak_deg) in one grid cell, and of the cruise
/// statistic (mean, std; both 0 in tables without it).
#[derive(Clone, Copy, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct Cell {
    pub mean: [f64; 2],
    pub std: [f64; 2],
    pub corr: f64,
    #[serde(default)]
    pub cruise: [f64; 2],
}

impl Cell {
    /// Mean of feature `k`: 0 ln RMS, 1 ln peak, 2 the cruise statistic.
    pub fn feat_mean(&self, k: usize) -> f64 {
        if k < 2 {
            self.mean[k]
        } else {
            self.cruise[0]
        }
    }

    /// Spread of feature `k` (see [`Self::feat_mean`]).
    pub fn feat_std(&self, k: usize) -> f64 {
        if k < 2 {
            self.std[k]
        } else {
            self.cruise[1]
        }
    }

    /// Sets mean and spread of feature `k` (see [`Self::feat_mean`]).
    pub fn set_feat(&mut self, k: usize, mean: f64, std: f64) {
        if k < 2 {
            self.mean[k] = mean;
            self.std[k] = std;
        } else {
            self.cruise = [mean, std];
        }
    }
}

/// Mean and covariance of z predicted for one clearance, and the cruise statistic's (mean,
/// std).
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct Prediction {
    pub mean: [f64; 2],
    pub std: [f64; 2],
    pub corr: f64,
    pub cruise: [f64; 2],
}

#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct ResponseTable {
    pub format: String,
    /// FNV-1a hash of the vehicle parameters' canonical JSON.
    pub vehicle_hash: String,
    /// The sensor the features were measured through; its `signal` says which steering
    /// signal the table describes (with `torque_nm`, the sensor's and the cells' `_deg`
    /// quantities are N·m of torsion-bar torque).
    pub sensor: SensorModel,
    /// Grid axes (increasing).
    pub clearance_mm: Vec<f64>,
    pub speed_kmh: Vec<f64>,
    pub decel_g: Vec<f64>,
    /// Nuisance vehicles per clearance in `cells` (M); the same M vehicles at every clearance.
    /// Format v4 may have none (M = 0, no cells): then only the nuisance model `linear`
    /// describes the vehicles, and method "mixture" cannot use the table.
    #[serde(default = "one")]
    pub vehicles: u32,
    /// Seeds per cell.
    pub seeds: u32,
    /// The cells carry the pre-brake cruise statistic (format v3).
    #[serde(default)]
    pub cruise: bool,
    /// Cells, index `((ic · vehicles + im) · n_speed + iv) · n_decel + id`.
    pub cells: Vec<Cell>,
    /// Amplitude calibration: increasing measured excess RMS (deg) → median true band-passed
    /// peak of δ_sw (deg), as pairs.
    pub amp_map: Vec<[f64; 2]>,
    /// How the table was built (free text: command, time, nuisances).
    #[serde(default)]
    pub provenance: String,
    /// The linear nuisance model fitted on the same events ([`super::linear`]), for the
    /// estimator's method `"linear"`; absent in tables of fewer drawn vehicles than it needs.
    /// Shared with the estimators built on the table.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub linear: Option<std::sync::Arc<super::linear::LinearModel>>,
    /// The nuisance prior the table's vehicles were drawn from and its nuisance model's
    /// coordinates are scaled to ([`super::emulate::coords`]); tables written before it was
    /// recorded were built with the default.
    #[serde(default)]
    pub prior: NuisanceRanges,
    /// FNV-1a of the file the table was loaded from (empty for a table built in memory): what
    /// a car model's correction names its table by ([`super::correction`]).
    #[serde(skip)]
    pub fingerprint: String,
    /// The car model's correction to this table, when its profile has one
    /// ([`super::correction`]); the estimator applies it.
    #[serde(skip)]
    pub correction: Option<super::correction::Correction>,
}

/// FNV-1a 64 of `bytes`, as 16 hex digits. Used for the vehicle-parameter version stamp (not a
/// security hash: it detects a wrong or edited vehicle file, not an adversary).
pub fn fnv1a_hex(bytes: &[u8]) -> String {
    let mut h: u64 = 0xcbf2_9ce4_8422_2325;
    for &b in bytes {
        h ^= b as u64;
        h = h.wrapping_mul(0x0000_0100_0000_01b3);
    }
    format!("{h:016x}")
}

/// Version stamp of a vehicle: the hash of its parameters serialised as JSON.
pub fn vehicle_hash<T: Serialize>(params: &T) -> anyhow::Result<String> {
    let json = serde_json::to_vec(params).context("cannot serialise vehicle parameters")?;
    Ok(fnv1a_hex(&json))
}

/// Index `i` and weight `w` such that `x ≈ (1−w)·axis[i] + w·axis[i+1]`, clamped to the ends.
pub(crate) fn bracket(axis: &[f64], x: f64) -> (usize, f64) {
    if axis.len() < 2 || x <= axis[0] {
        return (0, 0.0);
    }
    let n = axis.len();
    if x >= axis[n - 1] {
        return (n - 2, 1.0);
    }
    let i = axis.partition_point(|&a| a <= x) - 1;
    let w = (x - axis[i]) / (axis[i + 1] - axis[i]);
    (i, w)
}

impl ResponseTable {
    pub fn n_clearance(&self) -> usize {
        self.clearance_mm.len()
    }

    /// Features per cell: 2 (ln RMS, ln peak), 3 with the cruise statistic.
    pub fn n_features(&self) -> usize {
        2 + self.cruise as usize
    }

    /// Nuisance vehicles per clearance in the cells (M; 0 for a table without cells).
    pub fn n_vehicles(&self) -> usize {
        if self.format == FORMAT {
            self.vehicles as usize
        } else {
            self.vehicles.max(1) as usize
        }
    }

    fn idx(&self, ic: usize, im: usize, iv: usize, id: usize) -> usize {
        ((ic * self.n_vehicles() + im) * self.speed_kmh.len() + iv) * self.decel_g.len() + id
    }

    pub fn cell(&self, ic: usize, im: usize, iv: usize, id: usize) -> &Cell {
        &self.cells[self.idx(ic, im, iv, id)]
    }

    /// Checks shape, ordering and finiteness.
    pub fn validate(&self) -> anyhow::Result<()> {
        let known = [FORMAT, FORMAT_V3, FORMAT_V2, FORMAT_V1];
        if !known.contains(&self.format.as_str()) {
            bail!(
                "not a response table: format `{}` (want `{FORMAT}`)",
                self.format
            );
        }
        for (name, axis) in [
            ("clearance_mm", &self.clearance_mm),
            ("speed_kmh", &self.speed_kmh),
            ("decel_g", &self.decel_g),
        ] {
            if axis.is_empty() || axis.windows(2).any(|w| !(w[1] > w[0])) {
                bail!("table axis {name} must be non-empty and strictly increasing");
            }
        }
        if self.clearance_mm.len() < 2 {
            bail!("table needs at least 2 clearances");
        }
        let min_vehicles = if self.format == FORMAT { 0 } else { 1 };
        if self.vehicles < min_vehicles || self.vehicles > 4096 {
            bail!(
                "table has {} nuisance vehicles (want {min_vehicles}-4096)",
                self.vehicles
            );
        }
        if self.vehicles == 0 && self.linear.is_none() {
            bail!("a table without drawn-vehicle cells needs the nuisance model (`linear`)");
        }
        if self.format == FORMAT_V1 && self.vehicles != 1 {
            bail!("a {FORMAT_V1} has one pooled nuisance distribution (vehicles = 1)");
        }
        if self.cruise != (self.format == FORMAT || self.format == FORMAT_V3) {
            bail!(
                "a `{}` table must have cruise = {}",
                self.format,
                !self.cruise
            );
        }
        let want =
            self.clearance_mm.len() * self.n_vehicles() * self.speed_kmh.len() * self.decel_g.len();
        if self.cells.len() != want {
            bail!("table has {} cells, its axes need {want}", self.cells.len());
        }
        for (k, c) in self.cells.iter().enumerate() {
            let ok = c.mean.iter().chain(c.std.iter()).all(|v| v.is_finite())
                && c.std.iter().all(|&s| s > 0.0)
                && c.corr.abs() < 1.0
                && (!self.cruise || (c.cruise[0].is_finite() && c.cruise[1] > 0.0));
            if !ok {
                bail!("table cell {k} is not a valid distribution: {c:?}");
            }
        }
        if let Some(lm) = &self.linear {
            lm.validate(self.clearance_mm.len(), self.speed_kmh.len())?;
        }
        Ok(())
    }

    /// Loads and validates a table file. A format v3 table loads without its nuisance model,
    /// whose layout is gone (rebuild it with `shimmy calibrate` for method "linear").
    pub fn load(path: &std::path::Path) -> anyhow::Result<ResponseTable> {
        let text = std::fs::read_to_string(path)
            .with_context(|| format!("cannot read response table {}", path.display()))?;
        let not_a_table = || format!("{} is not a response table", path.display());
        // The format first (a scan that builds nothing): only a version 3 table goes through a
        // JSON tree, to drop its `linear` section; the others are read straight into the table
        // (building the tree cost as much as the rest of the start-up of an export).
        #[derive(serde::Deserialize)]
        struct Head<'a> {
            #[serde(borrow)]
            format: Option<std::borrow::Cow<'a, str>>,
        }
        let head: Head = serde_json::from_str(&text).with_context(not_a_table)?;
        let t: ResponseTable = if head.format.as_deref() == Some(FORMAT_V3) {
            let mut v: serde_json::Value = serde_json::from_str(&text).with_context(not_a_table)?;
            if let Some(o) = v.as_object_mut() {
                o.remove("linear");
            }
            serde_json::from_value(v).with_context(not_a_table)?
        } else {
            serde_json::from_str(&text).with_context(not_a_table)?
        };
        let mut t = t;
        if let Some(lm) = t.linear.as_mut().and_then(std::sync::Arc::get_mut) {
            lm.coef.shrink_to_fit();
        }
        t.validate()
            .with_context(|| format!("response table {}", path.display()))?;
        t.fingerprint = fnv1a_hex(text.as_bytes());
        Ok(t)
    }

    /// Refuses a table built for other vehicle parameters.
    pub fn check_vehicle(&self, hash: &str) -> anyhow::Result<()> {
        if self.vehicle_hash != hash {
            bail!(
                "response table was built for vehicle parameters {} but the vehicle given hashes to \
                 {hash}; rebuild it with `shimmy calibrate --vehicle FILE`",
                self.vehicle_hash
            );
        }
        Ok(())
    }

    /// Refuses a table that is not of the torsion-bar torque, or not built on `vehicle` with its
    /// MODEL.md §15 column enabled (a torque needs the column): what every command that takes
    /// a torque table checks.
    pub fn check_torque_vehicle(
        &self,
        vehicle: &crate::model::VehicleParams,
    ) -> anyhow::Result<()> {
        if self.sensor.signal != super::features::SteerSignal::TorqueNm {
            bail!("a table of the steering angle, not of the torque (`--signal torque`)");
        }
        let mut v = vehicle.clone();
        v.column.enabled = true;
        self.check_vehicle(&vehicle_hash(&v)?)
            .context("a torque table is built on the chassis with [column] enabled")
    }

    /// Predicted distribution of z for clearance index `ic` and nuisance vehicle `im` at
    /// (`v0_kmh`, `decel_g`), bilinear in speed and deceleration (clamped at the grid's edges).
    /// No allocation.
    pub fn predict(&self, ic: usize, im: usize, v0_kmh: f64, decel_g: f64) -> Prediction {
        let (iv, wv) = bracket(&self.speed_kmh, v0_kmh);
        let (id, wd) = bracket(&self.decel_g, decel_g);
        let nv = self.speed_kmh.len();
        let nd = self.decel_g.len();
        let mut p = Prediction::default();
        for (dv, fv) in [(0usize, 1.0 - wv), (1, wv)] {
            for (dd, fd) in [(0usize, 1.0 - wd), (1, wd)] {
                let f = fv * fd;
                if f == 0.0 {
                    continue;
                }
                let c = self.cell(ic, im, (iv + dv).min(nv - 1), (id + dd).min(nd - 1));
                for k in 0..2 {
                    p.mean[k] += f * c.mean[k];
                    p.std[k] += f * c.std[k];
                    p.cruise[k] += f * c.cruise[k];
                }
                p.corr += f * c.corr;
            }
        }
        p
    }

    /// Reduces the seed noise of the cell means: for each speed, the means are averaged over the
    /// deceleration axis (its effect is small next to the seed spread, MODEL.md §13 varies speed
    /// and clearance only) and then made non-decreasing in clearance by isotonic regression
    /// (pool-adjacent-violators; the shimmy amplitude grows with clearance, MODEL.md §12–13),
    /// separately for each nuisance vehicle (the same vehicle at every clearance). The cruise
    /// statistic is averaged over deceleration too (it is measured before the brake) but not
    /// made monotone: a wider free play hides more of the unbalance response, but not
    /// monotonically at every speed. Spreads and correlations are kept.
    pub fn smooth(&mut self) {
        let (nc, nm, nv, nd) = (
            self.clearance_mm.len(),
            self.n_vehicles(),
            self.speed_kmh.len(),
            self.decel_g.len(),
        );
        for k in 0..self.n_features() {
            for im in 0..nm {
                for iv in 0..nv {
                    let mut y: Vec<f64> = (0..nc)
                        .map(|ic| {
                            (0..nd)
                                .map(|id| self.cell(ic, im, iv, id).feat_mean(k))
                                .sum::<f64>()
                                / nd as f64
                        })
                        .collect();
                    // The cruise statistic (k = 2) is not monotone in clearance.
                    if k < 2 {
                        isotonic_in_place(&mut y);
                    }
                    for (ic, &m) in y.iter().enumerate() {
                        for id in 0..nd {
                            let i = self.idx(ic, im, iv, id);
                            let sd = self.cells[i].feat_std(k);
                            self.cells[i].set_feat(k, m, sd);
                        }
                    }
                }
            }
        }
    }

    /// The steering-wheel amplitude (deg) the amplitude calibration gives for a measured excess
    /// RMS; linear interpolation, proportional extrapolation beyond the ends.
    pub fn amplitude_deg(&self, excess_rms_deg: f64) -> Option<f64> {
        amp_from_map(&self.amp_map, excess_rms_deg)
    }
}

/// Least-squares non-decreasing fit of `y` (equal weights), in place: pool adjacent violators.
pub fn isotonic_in_place(y: &mut [f64]) {
    let mut blocks: Vec<(f64, usize)> = Vec::with_capacity(y.len());
    for &v in y.iter() {
        blocks.push((v, 1));
        while blocks.len() > 1 {
            let (b, nb) = blocks[blocks.len() - 1];
            let (a, na) = blocks[blocks.len() - 2];
            if a <= b {
                break;
            }
            blocks.pop();
            let last = blocks.len() - 1;
            blocks[last] = ((a * na as f64 + b * nb as f64) / (na + nb) as f64, na + nb);
        }
    }
    let mut i = 0;
    for (v, n) in blocks {
        for x in &mut y[i..i + n] {
            *x = v;
        }
        i += n;
    }
}

/// Interpolates an increasing `[x, y]` map; beyond its ends scales y proportionally to x.
pub fn amp_from_map(map: &[[f64; 2]], x: f64) -> Option<f64> {
    let first = map.first()?;
    let last = map.last()?;
    if x <= first[0] {
        return Some(if first[0] > 0.0 {
            first[1] * x / first[0]
        } else {
            first[1]
        });
    }
    if x >= last[0] {
        return Some(last[1] * x / last[0]);
    }
    let i = map.partition_point(|p| p[0] <= x) - 1;
    let (a, b) = (map[i], map[i + 1]);
    Some(a[1] + (b[1] - a[1]) * (x - a[0]) / (b[0] - a[0]))
}
