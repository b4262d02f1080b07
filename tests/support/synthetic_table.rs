//! A validated synthetic response table from given cells, shared by the estimator tests
//! (tests/observer_estimator.rs) and the observer benchmark (benches/observer.rs, through
//! `#[path]`). What it is not: a model-built table (`shimmy calibrate`).

use shimmy::observer::sensor::SensorModel;
use shimmy::observer::table::{Cell, ResponseTable, FORMAT, FORMAT_V2};

/// A validated synthetic table over these axes: format v3 when the cells carry the cruise
/// statistic (non-zero spread), else the v2 layout of braking features only.
pub fn synthetic(
    clearance_mm: Vec<f64>,
    speed_kmh: Vec<f64>,
    decel_g: Vec<f64>,
    vehicles: u32,
    cells: Vec<Cell>,
) -> ResponseTable {
    let cruise = cells.iter().all(|c| c.cruise[1] > 0.0);
    let t = ResponseTable {
        format: if cruise { FORMAT } else { FORMAT_V2 }.into(),
        vehicle_hash: "0123456789abcdef".into(),
        sensor: SensorModel::default(),
        clearance_mm,
        speed_kmh,
        decel_g,
        vehicles,
        seeds: 1,
        cruise,
        cells,
        amp_map: vec![[0.01, 0.03], [0.1, 0.25]],
        provenance: "synthetic".into(),
        linear: None,
        prior: Default::default(),
        fingerprint: String::new(),
        correction: None,
    };
    t.validate().unwrap();
    t
}
