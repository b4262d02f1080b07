//! Synthetic braking events of one vehicle for the estimator's tests, and the shipped
//! reference table they are estimated on.

use shimmy::observer::table::ResponseTable;

/// The shipped reference profile's response table.
pub fn reference_table() -> ResponseTable {
    let path = concat!(
        env!("CARGO_MANIFEST_DIR"),
        "/config/vehicles/shimmy_reference/table.json"
    );
    ResponseTable::load(std::path::Path::new(path)).expect("the shipped reference table loads")
}

/// `n` events of one worn vehicle, scaled by `level`, starting `shift` events into its
/// sequence: (rms, peak, cruise rms) in deg, initial speed (km/h), deceleration (g).
pub fn events(n: usize, level: f64, shift: usize) -> Vec<([f64; 3], f64, f64)> {
    (0..n)
        .map(|i| {
            let j = i + shift;
            let k = level * (1.0 + 0.15 * ((j * 7 % 11) as f64 / 10.0 - 0.5));
            let v = 35.0 + (j * 13 % 60) as f64;
            let d = 0.3 + 0.5 * ((j * 5 % 9) as f64 / 8.0);
            ([0.09 * k, 0.24 * k, 0.035 * k], v, d)
        })
        .collect()
}
