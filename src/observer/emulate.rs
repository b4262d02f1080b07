//! Emulated nuisance vehicles for the response table (`shimmy calibrate --emulate N`).
//!
//! What it is: a regression of each table feature on the vehicle's nuisance parameters, fitted
//! on the simulated events of the table's M drawn vehicles, and used to predict the features of
//! N new vehicles drawn from the same prior. What it is not: a model of the physics (the
//! shimmy model in `crate::model` makes the data) or part of the estimator (which only sees
//! the table's cells).
//!
//! Why: the drawn vehicles' cell means rest on one chaotic event each. The additive vehicle
//! model (`fit_additive`) de-noises them by giving each vehicle one offset for all speeds, and
//! moves the vehicle × speed interaction into the event spread: 0.24 (ln RMS) where one known
//! vehicle's events scatter by 0.11–0.23 around its own means (`shimmy calibrate
//! --exact-vehicle`, docs/ACCURACY.md "What limits the estimate"). A likelihood that wide cannot tell 0.15 mm from 0.1 mm.
//!
//! The fit is the table's linear nuisance model ([`super::linear`]): per clearance c, initial
//! speed v and feature f ∈ {ln RMS, ln peak, cruise}, z_f on the deceleration and the
//! nuisance coordinates ξ ∈ [−1, 1]⁷ of [`coords`]: the five steering stiffnesses and dampings
//! (k_s, c_s, k_t, k_g, c_g, MODEL.md §9) as (p/p₀ − 1)/rel, the unbalance as ln(u/u₀)/ln(√(hi/lo))
//! about the prior's geometric centre, and the road-noise factor mapped linearly. N vehicles
//! are then drawn uniformly in ξ (the prior of [`super::simulate::NuisanceRanges`] in these
//! coordinates, fixed seed) and their cells get the regression's predictions, with the fit's
//! total residual spread (pooled over speeds per clearance and feature; ln RMS and ln peak keep
//! their residual correlation).
//!
//! Memory and time: one small least-squares problem per (c, v, f); the table grows to
//! N × clearances × speeds × decelerations cells.

use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;

use super::linear::round5;
use super::simulate::NuisanceRanges;
use super::table::Cell;
use crate::model::VehicleParams;

/// Number of nuisance coordinates: the seven of every vehicle and the three of the §15 column.
pub const N_COORDS: usize = 10;
/// The coordinates every vehicle has (x0-x6); the column's (x7 J_sw, x8 k_tb, x9 c_tb) follow.
pub const N_BASE_COORDS: usize = 7;

/// The nuisance coordinates ξ ∈ [−1, 1]¹⁰ of vehicle `v` drawn around `nominal` with `r`:
/// x0-x4 the steering stiffnesses and dampings, x5 the unbalance, x6 the road-noise level, and,
/// for a vehicle with the MODEL.md §15 column whose prior draws it, x7-x9 its rim inertia J_sw,
/// torsion-bar stiffness k_tb and damping c_tb mapped linearly from their uniform ranges (0
/// otherwise, and for a 5-DOF vehicle, whose law then has no term in them).
pub fn coords(nominal: &VehicleParams, v: &VehicleParams, r: &NuisanceRanges) -> [f64; N_COORDS] {
    let (a, b) = (&nominal.steering, &v.steering);
    let rel = r.stiffness_damping_rel.max(1e-12);
    let f = |p0: f64, p: f64| (p / p0 - 1.0) / rel;
    let (ulo, uhi) = r.unbalance_factor;
    let u_half = 0.5 * (uhi / ulo).ln().max(1e-12);
    let u_mid = 0.5 * (uhi * ulo).ln();
    let (nlo, nhi) = r.road_noise_factor;
    let n_factor = v.excitation.noise_std_nm / nominal.excitation.noise_std_nm;
    let lin = |x: f64, (lo, hi): (f64, f64)| {
        if hi > lo {
            (2.0 * x - lo - hi) / (hi - lo)
        } else {
            0.0
        }
    };
    let col = match (&r.column, v.column.enabled) {
        (Some(c), true) => [
            lin(v.column.inertia_kgm2, c.inertia_kgm2),
            lin(v.column.torsion_bar_nm_per_rad, c.torsion_bar_nm_per_rad),
            lin(
                v.column.torsion_bar_damping_nms_per_rad,
                c.torsion_bar_damping_nms_per_rad,
            ),
        ],
        _ => [0.0; 3],
    };
    [
        f(
            a.kingpin_stiffness_nm_per_rad,
            b.kingpin_stiffness_nm_per_rad,
        ),
        f(a.kingpin_damping_nms_per_rad, b.kingpin_damping_nms_per_rad),
        f(a.tie_rod_stiffness_n_per_m, b.tie_rod_stiffness_n_per_m),
        f(a.restraint_stiffness_n_per_m, b.restraint_stiffness_n_per_m),
        f(a.restraint_damping_ns_per_m, b.restraint_damping_ns_per_m),
        ((v.excitation.unbalance_kgm / nominal.excitation.unbalance_kgm).ln() - u_mid) / u_half,
        (2.0 * n_factor - nlo - nhi) / (nhi - nlo).max(1e-12),
        col[0],
        col[1],
        col[2],
    ]
}

/// `n` vehicles drawn uniformly over [−1, 1]⁷ in the seven coordinates every vehicle has (the
/// prior in [`coords`]), from `seed`; the column's coordinates stay 0 (emulated vehicles do
/// not vary the column).
pub fn draw_coords(n: usize, seed: u64) -> Vec<[f64; N_COORDS]> {
    let mut rng = ChaCha8Rng::seed_from_u64(seed);
    rng.set_stream(13);
    (0..n)
        .map(|_| {
            let mut x = [0.0; N_COORDS];
            for v in x.iter_mut().take(N_BASE_COORDS) {
                *v = rng.random_range(-1.0..=1.0);
            }
            x
        })
        .collect()
}

/// One simulated table event: grid indices, its three statistics (ln RMS, ln peak, cruise) and
/// the cosine of its wheels' unbalance phase difference (MODEL.md §7).
#[derive(Clone, Copy, Debug, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct RawEvent {
    pub ic: usize,
    pub im: usize,
    pub iv: usize,
    pub decel_g: f64,
    pub z: [f64; 3],
    /// cos(φ_R − φ_L) of the run ([`super::simulate::SimulatedEvent::phase_cos`]).
    pub phase_cos: f64,
}

/// Quadrature points over Δ of one event whose phase difference is unknown: the emulated cells'
/// means and the estimator's hypothesis "event" ([`super::marginal`]).
pub const EVENT_PHASES: usize = 16;

/// Points of ψ = cos Δ for a phase difference Δ uniform over [0, π] (the midpoints of `n` equal
/// bins): averaging over them marginalises the phase of one event.
pub fn phase_quadrature(n: usize) -> impl Iterator<Item = f64> {
    let n = n.max(1);
    (0..n).map(move |q| ((q as f64 + 0.5) * std::f64::consts::PI / n as f64).cos())
}

/// Fits the nuisance model with `terms` on `raw` (the drawn vehicles' events, with their
/// coordinates `table_coords[im]`, [`super::linear::fit`]) and returns the cells of the
/// `synth` vehicles in the table's cell order (clearance, vehicle, speed, deceleration), for
/// `decels` grid decelerations. A cell describes any event of its vehicle, so its mean is the
/// law averaged over the unbalance phase difference; each cell's spread is the fit's total
/// residual spread at its clearance.
#[allow(clippy::too_many_arguments)]
pub fn emulate_cells(
    raw: &[RawEvent],
    table_coords: &[[f64; N_COORDS]],
    n_clearance: usize,
    n_speed: usize,
    decels: &[f64],
    synth: &[[f64; N_COORDS]],
    terms: &[super::linear::Term],
    min_std: f64,
) -> anyhow::Result<Vec<Cell>> {
    let lm = super::linear::fit(raw, table_coords, n_clearance, n_speed, terms, min_std)?;
    let phases: Vec<f64> = phase_quadrature(EVENT_PHASES).collect();
    let mut cells = Vec::with_capacity(n_clearance * synth.len() * n_speed * decels.len());
    for ic in 0..n_clearance {
        let s = lm.total_std[ic];
        for xi in synth {
            for iv in 0..n_speed {
                for &d in decels {
                    let m: [f64; 3] = std::array::from_fn(|f| {
                        let sum: f64 = phases
                            .iter()
                            .map(|&u| lm.mean_at(ic, iv, f, &super::linear::vars(xi, u), d))
                            .sum();
                        round5(sum / phases.len() as f64)
                    });
                    cells.push(Cell {
                        mean: [m[0], m[1]],
                        std: [s[0], s[1]],
                        corr: lm.total_corr[ic],
                        cruise: [m[2], s[2]],
                    });
                }
            }
        }
    }
    Ok(cells)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::observer::simulate::perturb_vehicle;

    #[test]
    fn coordinates_of_drawn_vehicles_fill_the_unit_cube() {
        let nom = VehicleParams::default();
        let r = NuisanceRanges::default();
        let mut rng = ChaCha8Rng::seed_from_u64(5);
        let mut lo = [f64::INFINITY; N_COORDS];
        let mut hi = [f64::NEG_INFINITY; N_COORDS];
        for _ in 0..400 {
            let v = perturb_vehicle(&nom, &r, &mut rng);
            for (k, x) in coords(&nom, &v, &r).into_iter().enumerate() {
                lo[k] = lo[k].min(x);
                hi[k] = hi[k].max(x);
            }
        }
        for k in 0..N_BASE_COORDS {
            assert!(
                lo[k] >= -1.0 - 1e-9 && hi[k] <= 1.0 + 1e-9,
                "coord {k}: {lo:?} {hi:?}"
            );
            assert!(
                lo[k] < -0.9 && hi[k] > 0.9,
                "coord {k} does not span the prior"
            );
        }
        assert_eq!(coords(&nom, &nom, &r)[1], 0.0);
    }

    /// Data made by a known linear law plus noise: the emulated cells carry the law's
    /// prediction for new vehicles and the noise's spread.
    #[test]
    fn the_fit_recovers_a_linear_law_and_its_noise() {
        let m = 200;
        let table = draw_coords(m, 1);
        let synth = draw_coords(5, 2);
        let decels = [0.3, 0.8];
        let law = |ic: usize, iv: usize, f: usize, xi: &[f64; N_COORDS], d: f64| {
            -3.0 + 0.4 * ic as f64 + 0.1 * iv as f64 - 0.3 * xi[1]
                + 0.2 * xi[5]
                + 0.05 * d
                + 0.1 * f as f64
        };
        let mut rng = ChaCha8Rng::seed_from_u64(3);
        let mut raw = Vec::new();
        for ic in 0..2 {
            for (im, xi) in table.iter().enumerate() {
                for iv in 0..3 {
                    for &d in &decels {
                        let z = std::array::from_fn(|f| {
                            let g: f64 = (0..12).map(|_| rng.random::<f64>()).sum::<f64>() - 6.0;
                            law(ic, iv, f, xi, d) + 0.1 * g
                        });
                        raw.push(RawEvent {
                            ic,
                            im,
                            iv,
                            decel_g: d,
                            z,
                            phase_cos: 0.0,
                        });
                    }
                }
            }
        }
        let terms = crate::observer::linear::parse_terms("1,d,x0,x1,x2,x3,x4,x5,x6").unwrap();
        let cells = emulate_cells(&raw, &table, 2, 3, &decels, &synth, &terms, 0.05).unwrap();
        assert_eq!(cells.len(), 2 * 5 * 3 * 2);
        let (nv, nd) = (3, 2);
        for ic in 0..2 {
            for (j, xi) in synth.iter().enumerate() {
                for iv in 0..3 {
                    for (id, &d) in decels.iter().enumerate() {
                        let c = &cells[((ic * 5 + j) * nv + iv) * nd + id];
                        for f in 0..3 {
                            let got = c.feat_mean(f);
                            assert!((got - law(ic, iv, f, xi, d)).abs() < 0.1, "{got}");
                        }
                        assert!((c.std[0] - 0.1).abs() < 0.02, "{:?}", c.std);
                        assert!((c.cruise[1] - 0.1).abs() < 0.02);
                    }
                }
            }
        }
    }

    #[test]
    fn too_few_events_is_an_error_not_a_fit() {
        let table = draw_coords(3, 1);
        let raw: Vec<RawEvent> = (0..3)
            .map(|im| RawEvent {
                ic: 0,
                im,
                iv: 0,
                decel_g: 0.3,
                z: [0.0; 3],
                phase_cos: 0.0,
            })
            .collect();
        let terms =
            crate::observer::linear::parse_terms(crate::observer::linear::DEFAULT_TERMS).unwrap();
        let e = emulate_cells(&raw, &table, 1, 1, &[0.3], &draw_coords(2, 2), &terms, 0.05)
            .unwrap_err();
        assert!(e.to_string().contains("needs more than"), "{e}");
    }
}
