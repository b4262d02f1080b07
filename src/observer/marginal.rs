//! Clearance posterior with the vehicle's nuisances marginalised (estimator `method =
//! "linear"`), on the response table's nuisance model ([`super::linear`]).
//!
//! What it is: for each clearance c_g of a fine grid (the table's clearances, each log step cut
//! into `grid_refine` parts, the model's coefficients interpolated linearly in ln c), the
//! evidence of all of a vehicle's events with its unknown nuisances integrated out.
//!
//! * The coordinates the features depend on nonlinearly are integrated on grids (the midpoints
//!   of equal bins of their uniform priors on [−1, 1]): the kingpin damping ξ₁ (`damping_grid`
//!   points), any other coordinate the table's model grids (`unbalance_grid` points), and the
//!   wheels' unbalance phase difference Δ (below).
//! * Given those, the latent vector x = (ξ_closed-form, η) ∈ R⁹ holds the other coordinates
//!   (prior: the uniform [−1, 1] replaced by the normal of the same variance 1/3; coordinates
//!   the model grids keep a zero column and their prior only) and the three features'
//!   per-vehicle misfit η ~ N(0, T_c). Each event e gives
//!
//!   z_e = a_e + H_e·x + ε_e,   H_e = [B_e | I₃],   ε_e ~ N(0, k²·Σ_c + V_e),
//!
//!   (a, B: the model at the event's speed and deceleration; Σ, T: its within- and
//!   between-vehicle covariances; k = `std_inflation`; V_e below), so x is shared by the events
//!   and conjugate: the sufficient statistics P = Σ_e Hᵀ S⁻¹ H (9 × 9), h = Σ_e Hᵀ S⁻¹ r_e,
//!   s = Σ_e r_eᵀ S⁻¹ r_e and Σ_e ln det S (r_e = z_e − a_e, S the event's covariance) give
//!
//!   ln p(z | c, grid point) = −½ (s − hᵀ A⁻¹ h) − ½ ln det A + ½ ln det Λ₀ − ½ Σ_e ln det S + const,
//!
//!   A = Λ₀ + P,  Λ₀ = prior precision of x,
//!
//!   and p(z | c) is the mean over the grid points.
//!
//! The unbalance phase difference Δ = φ_R − φ_L (ψ = cos Δ, MODEL.md §7): both wheels turn
//! with one spin angle, so Δ stays what it is while the wheels roll together and changes when
//! they do not (a turn, unequal rolling radii). `phase` says which:
//! * `"vehicle"`: Δ is the same for all of the vehicle's events, integrated on a grid of
//!   `phase_grid` points (Δ uniform on [0, π]; its sign does not matter, the vehicle is
//!   symmetric);
//! * `"event"`: Δ is new in every event. Its effect is averaged out of each event's prediction
//!   on a 16-point quadrature, a_e the mean and V_e the covariance of the prediction over Δ;
//! * `"either"` (the default): both hypotheses, each with prior weight ½, so that the events
//!   decide. On 80 held-out vehicles with 30 events each (docs/ACCURACY.md), P(fixed) was above
//!   ½ for 60 of 80 whose Δ was fixed and for 13 of 80 whose Δ changed at every stop: the
//!   events lean the right way, but not always.
//!
//! Wear: before each event all statistics are multiplied by 2^(−distance / half-life): old
//! evidence fades, so the estimate follows a clearance that grows with distance.
//!
//! Baseline ([`LinearPosterior::update_known`]): events of the same vehicle at a known
//! clearance c_b (its first events after the joints were replaced) share its x (nuisances and
//! misfit η) with the later events but not their clearance. Their statistics are kept apart,
//! computed once at c_b, and each clearance's evidence becomes the conditional one,
//!
//!   p(z | c, baseline) = Σ_q p(z, z_b | c, c_b, q) / Σ_q p(z_b | c_b, q)
//!
//! over the grid points q (numerator: the sum of both statistics), so what the baseline events
//! say about η (a transfer, sensor gain or noise floor the table's model misses, all of which
//! move ln RMS and ln peak by a constant) is subtracted from the later events instead of being
//! read as clearance. The baseline does not fade with distance (it describes the vehicle, not
//! its wear) and does not count in the goodness-of-fit's degrees of freedom.
//!
//! What it is not: robust to outlier events (the Gaussian has no outlier floor), or a model of
//! the physics (the table's model stands for it).
//!
//! Memory and cost: the statistics are sums over events, and most of them are shared between
//! grid points (`Grid`). A point's slopes B depend only on the gridded variables that share a
//! term with a closed-form coordinate (ξ₁ for the default laws), and its predicted means on the
//! other gridded variables only through a few monomials φ of them (for the torque law x5, ψ,
//! ψ², x5·ψ, x5²): a = α + M·φ. With Δ fixed per vehicle the events' covariance depends on the
//! clearance only, so per clearance and group of points that agree on ξ₁ the sums P (the upper
//! triangle of its live rows), Σ ln det S, h₀, G, s₀, u and Q are kept (`lin_len`), and each
//! point's h and s follow from its φ exactly: h = h₀ − G·φ, s = s₀ − 2uᵀφ + φᵀQφ. P is
//! factored once per group. With Δ new per event the covariance holds the spread over Δ, which
//! depends on every gridded variable, so those points keep their own. For the torque tables'
//! law (x5² gridded on 7 points: 9 × 7 × 8 points with Δ fixed, 9 × 7 without, 45 clearances)
//! that is 1.5 MB per table, of which 1.1 MB are the Δ-per-event points' (one P of every point
//! per clearance each would be 32 MB). P is summed in single precision, which halves the
//! largest part: it enters only through the factor of A = Λ₀ + P, whose prior block keeps it
//! conditioned, while h and s, whose difference is the deviance, stay in double. The result is
//! the per-point double-precision sums' within 3·10⁻⁶ relative after 12 events and the deviance
//! within 10⁻⁷ relative after 1000 (the unit tests below compare them; the RAV4 column fleet's
//! P(c > 0.1 mm) moves by 10⁻⁸). All of it and the scratch of one
//! event's terms are allocated in [`LinearPosterior::new`] (the baseline's at its first
//! event); updates and summaries do not allocate. The scratch (about 150 KB, most of it
//! fixed-size term arrays) lives only within one update, so the estimators of one vehicle share
//! one ([`LinearPosterior::share_scratch`]).

use std::sync::{Arc, Mutex};

use nalgebra::{Cholesky, Const, Matrix3, SMatrix, SVector, Vector3};

use super::emulate::{phase_quadrature, EVENT_PHASES};
use super::estimator::EstimatorConfig;
use super::linear::{Basis, Coefs, LinearModel, N_FEAT, N_LIN, N_VARS, PHASE};
use super::table::{bracket, ResponseTable};

const NX: usize = N_LIN + N_FEAT;
type MatX = SMatrix<f64, NX, NX>;
type VecX = SVector<f64, NX>;
type Factor = Cholesky<f64, Const<NX>>;
/// The slopes of the features in the closed-form coordinates at one event and grid point.
type Slopes = [[f64; N_LIN]; N_FEAT];

/// Variance of the uniform [−1, 1] prior of each nuisance coordinate.
const COORD_VAR: f64 = 1.0 / 3.0;

/// P += Hᵀ W H for one event with slopes `b` and inverse covariance `w` (masked), H = [B | I₃],
/// on the live indices `live` of x: P is stored as the upper triangle of its live rows and
/// columns, row by row (the others are 0: closed-form coordinates no term holds, and unused
/// slots).
fn quad_add(p: &mut [f32], live: &[usize], b: &Slopes, w: &Matrix3<f64>) {
    let mut hm = SMatrix::<f64, N_FEAT, NX>::zeros();
    for f in 0..N_FEAT {
        for j in 0..N_LIN {
            hm[(f, j)] = b[f][j];
        }
        hm[(f, N_LIN + f)] = 1.0;
    }
    let m = hm.transpose() * w * hm;
    let mut k = 0;
    for (a, &i) in live.iter().enumerate() {
        for &j in &live[a..] {
            p[k] = (f64::from(p[k]) + m[(i, j)]) as f32;
            k += 1;
        }
    }
}

/// A = `lam` + P (+ the `other` statistics' P), from the packed triangles of [`quad_add`].
fn precision(lam: &MatX, live: &[usize], p: &[f32], other: Option<&[f32]>) -> MatX {
    let mut a = *lam;
    let mut k = 0;
    for (n, &i) in live.iter().enumerate() {
        for &j in &live[n..] {
            let v = f64::from(p[k]) + other.map_or(0.0, |o| f64::from(o[k]));
            a[(i, j)] += v;
            if j != i {
                a[(j, i)] += v;
            }
            k += 1;
        }
    }
    a
}

/// Length of a group's statistics that depend on the points' predictions a = α + M·φ (φ the
/// values of the group's `l` monomials at the point; [`Grid`]): h₀ = Σ Hᵀ S⁻¹ r₀ (r₀ = z − α),
/// G = Σ Hᵀ S⁻¹ M (NX × l, column by column), s₀ = Σ r₀ᵀ S⁻¹ r₀, u = Σ Mᵀ S⁻¹ r₀ and
/// Q = Σ Mᵀ S⁻¹ M (upper triangle), in that order. At a point, r = r₀ − M·φ gives
/// h = h₀ − G·φ and s = s₀ − 2 uᵀφ + φᵀQφ.
const fn lin_len(l: usize) -> usize {
    lin_offsets(l).2 + l * (l + 1) / 2
}

/// Where s₀, u and Q start in a group's statistics of [`lin_len`] with `l` monomials.
const fn lin_offsets(l: usize) -> (usize, usize, usize) {
    let s0 = NX + NX * l;
    (s0, s0 + 1, s0 + 1 + l)
}

/// h += Hᵀ v for H = [B | I₃].
fn add_ht(h: &mut [f64], b: &Slopes, v: &Vector3<f64>) {
    for (j, hj) in h.iter_mut().enumerate().take(N_LIN) {
        *hj += (0..N_FEAT).map(|f| b[f][j] * v[f]).sum::<f64>();
    }
    for f in 0..N_FEAT {
        h[N_LIN + f] += v[f];
    }
}

/// Adds one event to a group's statistics `lin` ([`lin_len`]): slopes `b`, residual at φ = 0
/// `r0` and the columns of M (`m`), both masked, inverse covariance `w`.
fn lin_add(lin: &mut [f64], b: &Slopes, r0: &Vector3<f64>, m: &[[f64; N_FEAT]], w: &Matrix3<f64>) {
    let (s0, u, q) = lin_offsets(m.len());
    let wr = w * r0;
    add_ht(&mut lin[..NX], b, &wr);
    lin[s0] += r0.dot(&wr);
    let mut k = q;
    for (i, mi) in m.iter().enumerate() {
        let mv = Vector3::from(*mi);
        let wm = w * mv;
        add_ht(&mut lin[NX + i * NX..NX + (i + 1) * NX], b, &wm);
        lin[u + i] += mv.dot(&wr);
        for mj in &m[i..] {
            lin[k] += wm.dot(&Vector3::from(*mj));
            k += 1;
        }
    }
}

/// h and s of a group's statistics `lin` at a point with monomial values `phi`.
fn lin_at(lin: &[f64], phi: &[f64]) -> (VecX, f64) {
    let l = phi.len();
    let (s0, u, q) = lin_offsets(l);
    let mut h = VecX::from_column_slice(&lin[..NX]);
    let mut s = lin[s0];
    let mut k = q;
    for i in 0..l {
        h -= VecX::from_column_slice(&lin[NX + i * NX..NX + (i + 1) * NX]) * phi[i];
        s -= 2.0 * phi[i] * lin[u + i];
        for j in i..l {
            let f = if i == j { 1.0 } else { 2.0 };
            s += f * phi[i] * phi[j] * lin[k];
            k += 1;
        }
    }
    (h, s)
}

/// ln p(events | grid point) up to a constant and the events' deviance at the point, from the
/// factor of A = Λ₀ + P (`fac`, with ln det A), h, s, Σ ln det S (`ld`) and ln det Λ₀
/// (`ld_lam`): s − hᵀA⁻¹h is, by the Woodbury identity, rᵀ(S + H Λ₀⁻¹ Hᵀ)⁻¹ r over all the
/// events' residuals r, i.e. χ² with as many degrees of freedom as features observed when the
/// events follow the model at this point.
fn evidence(fac: &Option<(Factor, f64)>, h: &VecX, s: f64, ld: f64, ld_lam: f64) -> (f64, f64) {
    match fac {
        Some((ch, ln_det_a)) => {
            let dev = s - h.dot(&ch.solve(h));
            (-0.5 * dev - 0.5 * ln_det_a + 0.5 * ld_lam - 0.5 * ld, dev)
        }
        None => (f64::NEG_INFINITY, f64::INFINITY),
    }
}

/// One phase hypothesis's grid points, in groups that share their statistics.
///
/// A point's slopes B depend only on the gridded variables that share a term with a
/// closed-form coordinate (the slope variables; for the default laws ξ₁, and ψ where the
/// unbalance is closed-form), and its predicted means a on the others only through the
/// monomials of them that the law's terms hold (for the torque tables' law x5, ψ, ψ², x5·ψ,
/// x5²): a = α + M·φ with α and M the same for all the points that agree on the slope
/// variables. With Δ fixed per vehicle the events' covariance depends on the clearance only, so
/// such points form one group: P, Σ ln det S and the statistics of [`lin_len`] are kept per
/// group, and each point holds its monomials' values φ. With Δ new per event (`per_point`), the
/// covariance holds the spread over Δ, which depends on every gridded variable, so each point
/// is a group of its own.
struct Grid {
    points: Vec<[f64; N_VARS]>,
    group: Vec<usize>,
    n_groups: usize,
    /// Per group: where the event's slopes and split means are evaluated (the group's slope
    /// variables, the other gridded variables at 1, the closed-form coordinates at 0); empty
    /// for a per-point grid, whose events are evaluated at the points themselves.
    rep: Vec<[f64; N_VARS]>,
    /// Class of each term for [`LinearModel::means_by_class`]: 0 constant within a group,
    /// 1 + m the m-th monomial, `n_mono + 1` (left out) for a term with a closed-form
    /// coordinate, which is 0 at every point.
    class: Vec<usize>,
    n_mono: usize,
    /// The monomials' values at each point (`n_mono` per point).
    phi: Vec<f64>,
    /// The indices of x whose rows of P can be other than 0: the closed-form coordinates
    /// that some term holds, and η.
    live: Vec<usize>,
}

impl Grid {
    /// `points` grouped by the slope variables of `model` (`per_point`: every point a group of
    /// its own).
    fn new(points: Vec<[f64; N_VARS]>, model: &LinearModel, per_point: bool) -> Grid {
        let mut closed = [false; N_VARS];
        for j in model.closed_form() {
            closed[j] = true;
        }
        let has_closed = |t: &super::linear::Term| (0..N_VARS).any(|j| closed[j] && t.exp[j] > 0);
        // Gridded variables sharing a term with a closed-form coordinate; the others.
        let slope: Vec<usize> = (0..N_VARS)
            .filter(|&v| !closed[v] && model.terms.iter().any(|t| t.exp[v] > 0 && has_closed(t)))
            .collect();
        let other: Vec<usize> = (0..N_VARS)
            .filter(|&v| !closed[v] && !slope.contains(&v))
            .collect();
        let live: Vec<usize> = model
            .closed_form()
            .enumerate()
            .filter(|&(_, j)| model.terms.iter().any(|t| t.exp[j] > 0))
            .map(|(l, _)| l)
            .chain(N_LIN..NX)
            .collect();
        if per_point {
            let n = points.len();
            return Grid {
                rep: Vec::new(),
                points,
                group: (0..n).collect(),
                n_groups: n,
                class: Vec::new(),
                n_mono: 0,
                phi: Vec::new(),
                live,
            };
        }
        // The monomials of the other gridded variables (exponents), and each term's class.
        let mut monos: Vec<Vec<u8>> = Vec::new();
        let class: Vec<usize> = model
            .terms
            .iter()
            .map(|t| {
                if has_closed(t) {
                    return usize::MAX;
                }
                let e: Vec<u8> = other.iter().map(|&v| t.exp[v]).collect();
                if e.iter().all(|&x| x == 0) {
                    return 0;
                }
                1 + match monos.iter().position(|m| *m == e) {
                    Some(i) => i,
                    None => {
                        monos.push(e);
                        monos.len() - 1
                    }
                }
            })
            .collect();
        let n_mono = monos.len();
        let class = class.into_iter().map(|c| c.min(n_mono + 1)).collect();
        let key =
            |x: &[f64; N_VARS]| -> Vec<u64> { slope.iter().map(|&v| x[v].to_bits()).collect() };
        let mut keys: Vec<Vec<u64>> = Vec::new();
        let mut tagged: Vec<(usize, [f64; N_VARS])> = points
            .into_iter()
            .map(|x| {
                let k = key(&x);
                let g = match keys.iter().position(|q| *q == k) {
                    Some(g) => g,
                    None => {
                        keys.push(k);
                        keys.len() - 1
                    }
                };
                (g, x)
            })
            .collect();
        tagged.sort_by_key(|(g, _)| *g);
        let mut rep = vec![[0.0; N_VARS]; keys.len()];
        for (g, x) in tagged.iter().rev() {
            rep[*g] = *x;
        }
        for r in rep.iter_mut() {
            for &v in &other {
                r[v] = 1.0;
            }
        }
        let phi = tagged
            .iter()
            .flat_map(|(_, x)| {
                monos.iter().map(|m| {
                    other
                        .iter()
                        .zip(m)
                        .map(|(&v, &e)| x[v].powi(e as i32))
                        .product::<f64>()
                })
            })
            .collect();
        Grid {
            group: tagged.iter().map(|(g, _)| *g).collect(),
            points: tagged.into_iter().map(|(_, x)| x).collect(),
            n_groups: keys.len(),
            rep,
            class,
            n_mono,
            phi,
            live,
        }
    }

    fn len(&self) -> usize {
        self.points.len()
    }

    fn is_empty(&self) -> bool {
        self.points.is_empty()
    }

    /// The monomials' values at point `q`.
    fn phi(&self, q: usize) -> &[f64] {
        &self.phi[q * self.n_mono..(q + 1) * self.n_mono]
    }
}

/// One hypothesis's statistics at `rows` clearances, per (clearance, group): P (packed,
/// [`quad_add`], single precision: the module doc's "Memory and cost"), Σ ln det S, and the
/// statistics of [`lin_len`].
#[derive(Default)]
struct StatSet {
    p: Vec<f32>,
    ld: Vec<f64>,
    lin: Vec<f64>,
    np: usize,
    stride: usize,
}

impl StatSet {
    fn zero(rows: usize, grid: &Grid) -> StatSet {
        let (n, stride) = (grid.live.len(), lin_len(grid.n_mono));
        let np = n * (n + 1) / 2;
        let cells = rows * grid.n_groups;
        StatSet {
            p: vec![0.0; cells * np],
            ld: vec![0.0; cells],
            lin: vec![0.0; cells * stride],
            np,
            stride,
        }
    }

    fn p(&self, i: usize) -> &[f32] {
        &self.p[i * self.np..(i + 1) * self.np]
    }

    fn lin(&self, i: usize) -> &[f64] {
        &self.lin[i * self.stride..(i + 1) * self.stride]
    }

    /// Adds one event to cell `i`: P and ln det S ([`quad_add`]), then the statistics of
    /// [`lin_len`] ([`lin_add`]).
    #[allow(clippy::too_many_arguments)]
    fn add(
        &mut self,
        i: usize,
        live: &[usize],
        b: &Slopes,
        w: &Matrix3<f64>,
        ld: f64,
        r0: &Vector3<f64>,
        m: &[[f64; N_FEAT]],
    ) {
        quad_add(&mut self.p[i * self.np..(i + 1) * self.np], live, b, w);
        self.ld[i] += ld;
        lin_add(
            &mut self.lin[i * self.stride..(i + 1) * self.stride],
            b,
            r0,
            m,
            w,
        );
    }

    fn scale(&mut self, f: f64) {
        for v in &mut self.p {
            *v = (f64::from(*v) * f) as f32;
        }
        for v in self.ld.iter_mut().chain(&mut self.lin) {
            *v *= f;
        }
    }
}

/// Per-event scratch at each clearance of an update, allocated once. Its contents live only
/// within one [`accumulate`], so the estimators of one vehicle, which take an event one after
/// another, can share one ([`LinearPosterior::share_scratch`]): it is then as large as the
/// largest of them needs, and each uses its leading `rows`, `n_quad` and `n_mono + 1` entries.
#[derive(Default)]
struct EventScratch {
    coefs: Vec<Coefs>,
    sigma: Vec<Matrix3<f64>>,
    /// Hypothesis "vehicle": the masked inverse of Σ and its ln det (`None`: singular).
    w: Vec<Option<(Matrix3<f64>, f64)>>,
    /// A group's means split by class of term ([`LinearModel::means_by_class`]).
    split: Vec<[f64; N_FEAT]>,
    /// One point's term values; of hypothesis "event", at each quadrature phase and their mean.
    basis: Basis,
    basis_q: Vec<Basis>,
    basis_mean: Basis,
}

impl EventScratch {
    fn new(rows: usize, n_quad: usize, n_mono: usize) -> EventScratch {
        let mut s = EventScratch::default();
        s.reserve(rows, n_quad, n_mono);
        s
    }

    /// Grows the scratch to hold at least `rows` clearances, `n_quad` phases and `n_mono`
    /// monomials.
    fn reserve(&mut self, rows: usize, n_quad: usize, n_mono: usize) {
        if self.coefs.len() < rows {
            self.coefs.resize(rows, Coefs::default());
            self.sigma.resize(rows, Matrix3::zeros());
            self.w.resize(rows, None);
        }
        if self.split.len() < n_mono + 1 {
            self.split.resize(n_mono + 1, [0.0; N_FEAT]);
        }
        if self.basis_q.len() < n_quad {
            self.basis_q.resize(n_quad, Basis::default());
        }
    }
}

/// The residual z − a of the observed features (0 where masked).
fn residual(z: &[f64; N_FEAT], a: &[f64; N_FEAT], mask: &FeatureMask) -> Vector3<f64> {
    Vector3::from_fn(|f, _| if mask[f] { z[f] - a[f] } else { 0.0 })
}

/// Adds one event (features `z`, mask, speed position `sp`, deceleration) at the clearance
/// positions `pos` to the statistics `sv` (grid `gv`, hypothesis "vehicle") and `se` (grid
/// `ge`, "event"), row i of each for `pos[i]`, with `n_quad` phases for hypothesis "event".
/// No allocation.
#[allow(clippy::too_many_arguments)]
fn accumulate(
    model: &LinearModel,
    inflation2: f64,
    pos: &[(usize, f64)],
    sp: (usize, f64),
    z: &[f64; N_FEAT],
    mask: &FeatureMask,
    decel_g: f64,
    (gv, ge): (&Grid, &Grid),
    n_quad: usize,
    scr: &mut EventScratch,
    sv: &mut StatSet,
    se: &mut StatSet,
) {
    let rows = pos.len();
    for (i, &p) in pos.iter().enumerate() {
        model.coef_interp(p, sp, &mut scr.coefs[i]);
        // The event scatter depends on the clearance only: one inverse per clearance.
        scr.sigma[i] = model.within_at(p) * inflation2;
        scr.w[i] = masked_inverse(&scr.sigma[i], mask);
    }
    // With hypothesis "vehicle" in use, a scatter the mask leaves singular means the event
    // adds nothing at that clearance.
    let skip = |i: usize, w: &[Option<(Matrix3<f64>, f64)>]| !gv.is_empty() && w[i].is_none();
    let ngv = gv.n_groups;
    let n_split = gv.n_mono + 1;
    for k in 0..ngv {
        model.basis_into(&gv.rep[k], decel_g, &mut scr.basis);
        for i in 0..rows {
            let Some((w, ld)) = scr.w[i] else { continue };
            // The slopes (the same at every point of the group) and a = α + M·φ.
            let b = model.predict_with(&scr.coefs[i], &scr.basis).b;
            let split = &mut scr.split[..n_split];
            model.means_by_class(&scr.coefs[i], &scr.basis, &gv.class, split);
            for col in split.iter_mut() {
                for (f, v) in col.iter_mut().enumerate() {
                    if !mask[f] {
                        *v = 0.0;
                    }
                }
            }
            let r0 = residual(z, &split[0], mask);
            sv.add(i * ngv + k, &gv.live, &b, &w, ld, &r0, &split[1..]);
        }
    }
    let nge = ge.n_groups;
    for (q, x) in ge.points.iter().enumerate() {
        // Δ new in this event: the mean of the prediction over Δ (the law is linear in its
        // terms, so the mean event's terms give it) and its covariance.
        for (k, u) in phase_quadrature(n_quad).enumerate() {
            let mut y = *x;
            y[PHASE] = u;
            model.basis_into(&y, decel_g, &mut scr.basis_q[k]);
        }
        let basis_q = &scr.basis_q[..n_quad];
        Basis::mean_of(basis_q, &mut scr.basis_mean);
        let k = ge.group[q];
        for i in 0..rows {
            if skip(i, &scr.w) {
                continue;
            }
            let mean = model.predict_with(&scr.coefs[i], &scr.basis_mean);
            let am = Vector3::from(mean.a);
            let mut var = Matrix3::<f64>::zeros();
            for b in basis_q {
                let d = Vector3::from(model.mean_with(&scr.coefs[i], b)) - am;
                var += d * d.transpose();
            }
            var /= n_quad as f64;
            let Some((w, ld)) = masked_inverse(&(scr.sigma[i] + var), mask) else {
                continue;
            };
            let r = residual(z, &mean.a, mask);
            se.add(i * nge + k, &ge.live, &mean.b, &w, ld, &r, &[]);
        }
    }
}

/// ln p and the deviance of every point of `grid` at clearance row `g` of `stats` (plus row 0 of
/// `extra`, the baseline, when given), with prior precision `lam` (ln det `ld_lam`), into
/// `out_l` and `out_dev`; `fac` is scratch for one factor per group. No allocation.
#[allow(clippy::too_many_arguments)]
fn point_evidence(
    grid: &Grid,
    stats: &StatSet,
    g: usize,
    extra: Option<&StatSet>,
    lam: &MatX,
    ld_lam: f64,
    fac: &mut [Option<(Factor, f64)>],
    out_l: &mut [f64],
    out_dev: &mut [f64],
) {
    let ng = grid.n_groups;
    for (k, f) in fac.iter_mut().enumerate().take(ng) {
        let a = precision(lam, &grid.live, stats.p(g * ng + k), extra.map(|e| e.p(k)));
        *f = a.cholesky().map(|ch| {
            let l = ch.ln_determinant();
            (ch, l)
        });
    }
    for q in 0..grid.len() {
        let (k, phi) = (grid.group[q], grid.phi(q));
        let (mut h, mut s) = lin_at(stats.lin(g * ng + k), phi);
        let mut ld = stats.ld[g * ng + k];
        if let Some(e) = extra {
            let (hb, sb) = lin_at(e.lin(k), phi);
            h += hb;
            s += sb;
            ld += e.ld[k];
        }
        let (l, dev) = evidence(&fac[k], &h, s, ld, ld_lam);
        out_l[q] = l;
        out_dev[q] = dev;
    }
}

/// Which features enter: ln RMS, ln peak, cruise.
pub type FeatureMask = [bool; N_FEAT];

/// How the unbalance phase difference is treated (`[estimator] phase`).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum PhaseMode {
    Vehicle,
    Event,
    Either,
}

impl PhaseMode {
    pub fn parse(s: &str) -> Option<PhaseMode> {
        match s {
            "vehicle" => Some(PhaseMode::Vehicle),
            "event" => Some(PhaseMode::Event),
            "either" => Some(PhaseMode::Either),
            _ => None,
        }
    }
}

/// The running posterior of method `"linear"`. It holds the table's nuisance model (shared)
/// and its own copy of the speed axis, so an update cannot be handed another table's model.
pub struct LinearPosterior {
    model: Arc<LinearModel>,
    speed_kmh: Vec<f64>,
    /// The fine clearance grid's positions on the table's clearance axis ([`fine_grid`]).
    pos: Vec<(usize, f64)>,
    /// Grid points of the gridded coordinates with Δ fixed per vehicle (hypothesis "vehicle":
    /// ψ set), and without ψ (hypothesis "event").
    grid_v: Grid,
    grid_e: Grid,
    /// Statistics per hypothesis, a row per clearance of `pos`.
    stats_v: StatSet,
    stats_e: StatSet,
    /// Statistics of the baseline events (known clearance), one row per hypothesis; empty
    /// until the first one.
    base_v: StatSet,
    base_e: StatSet,
    has_baseline: bool,
    /// Scratch of one event's update at every clearance (shared with the other estimators of
    /// the vehicle: [`Self::share_scratch`]), and of a baseline event's; phases of hypothesis
    /// "event".
    scratch_event: Arc<Mutex<EventScratch>>,
    scratch_event_base: Option<EventScratch>,
    n_quad: usize,
    /// Scratch: one factor of A per group, ln p(z | c_g, point) and the deviance per point of
    /// one clearance (and, with a baseline, of the baseline alone).
    fac: Vec<Option<(Factor, f64)>>,
    scratch: Vec<f64>,
    scratch_dev: Vec<f64>,
    scratch_base: Vec<f64>,
    scratch_base_dev: Vec<f64>,
    baseline_obs: f64,
    /// Where on the table's clearance axis the baseline events were (the last one's).
    baseline_pos: (usize, f64),
    /// Σ over the baseline events of ln dz_table/dz_measured.
    baseline_ln_jacobian: f64,
    /// Variance added to the model's misfit covariance T (ln units²), and added on top of it
    /// once there is a baseline.
    misfit_var: f64,
    baseline_misfit_var: f64,
    /// Scratch: ln p(events | c_g) + ln prior(c_g), without the evidence power, per grid point.
    scratch_raw: Vec<f64>,
    /// Λ₀ and ln det Λ₀ per clearance grid point (η block T_c⁻¹ / k²).
    prior: Vec<(MatX, f64)>,
    inflation2: f64,
    half_life_km: f64,
    /// Power on the likelihood (tempering, 0 < power ≤ 1).
    power: f64,
    /// Scratch: the share of hypothesis "vehicle" in each clearance's evidence.
    share_v: Vec<f64>,
    /// Posterior probability of hypothesis "vehicle" (NaN when only one is in use).
    p_vehicle: f64,
    /// Features observed so far (faded with the evidence): the deviance's degrees of freedom.
    n_obs: f64,
    /// Smallest deviance over the clearances and grid points, after the last
    /// [`Self::probabilities_into`].
    min_deviance: f64,
    /// ln of the events' marginal likelihood under the table's model (over the clearance prior
    /// and the nuisances), with and without the evidence power, after the last
    /// [`Self::probabilities_into`].
    ln_evidence: [f64; 2],
    /// Σ over the events of ln dz_table/dz_measured (a transfer gain other than 1), faded
    /// with the evidence.
    ln_jacobian: f64,
}

/// Inverse and ln det of the masked block of `m` (unused features: zero rows and columns).
fn masked_inverse(m: &Matrix3<f64>, mask: &FeatureMask) -> Option<(Matrix3<f64>, f64)> {
    let mut a = *m;
    for i in 0..N_FEAT {
        if !mask[i] {
            for j in 0..N_FEAT {
                a[(i, j)] = 0.0;
                a[(j, i)] = 0.0;
            }
            a[(i, i)] = 1.0;
        }
    }
    let ch = a.cholesky()?;
    let ld = ch.ln_determinant();
    let mut inv = ch.inverse();
    for i in 0..N_FEAT {
        if !mask[i] {
            for j in 0..N_FEAT {
                inv[(i, j)] = 0.0;
                inv[(j, i)] = 0.0;
            }
        }
    }
    Some((inv, ld))
}

/// The fine clearance grid: each log step of `clearance_mm` cut into `refine` parts. Returns ln c
/// (mm) of each point and its position on the table's axis (index, weight of the next).
pub fn fine_grid(clearance_mm: &[f64], refine: usize) -> (Vec<f64>, Vec<(usize, f64)>) {
    let refine = refine.max(1);
    let n = clearance_mm.len();
    let mut ln_c = Vec::with_capacity((n - 1) * refine + 1);
    let mut pos = Vec::with_capacity(ln_c.capacity());
    for ic in 0..n - 1 {
        let (a, b) = (clearance_mm[ic].ln(), clearance_mm[ic + 1].ln());
        for j in 0..refine {
            let w = j as f64 / refine as f64;
            ln_c.push(a + w * (b - a));
            pos.push((ic, w));
        }
    }
    ln_c.push(clearance_mm[n - 1].ln());
    pos.push((n - 2, 1.0));
    (ln_c, pos)
}

/// Λ₀ and ln det Λ₀ per clearance grid point: the coordinates' prior (variance 1/3 each) and
/// the misfit's, T_c (the model's between-vehicle covariance) plus `misfit_var` on its
/// diagonal, times `inflation2`.
fn build_prior(
    model: &LinearModel,
    pos: &[(usize, f64)],
    misfit_var: f64,
    inflation2: f64,
) -> anyhow::Result<Vec<(MatX, f64)>> {
    let mut prior = Vec::with_capacity(pos.len());
    for &p in pos {
        let t = (model.between_at(p) + Matrix3::identity() * misfit_var) * inflation2;
        let ch = t
            .cholesky()
            .ok_or_else(|| anyhow::anyhow!("nuisance model: misfit covariance not positive"))?;
        let t_inv = ch.inverse();
        let mut lam = MatX::zeros();
        for i in 0..N_LIN {
            lam[(i, i)] = 1.0 / COORD_VAR;
        }
        for i in 0..N_FEAT {
            for j in 0..N_FEAT {
                lam[(N_LIN + i, N_LIN + j)] = t_inv[(i, j)];
            }
        }
        let ld_lam = -(N_LIN as f64) * COORD_VAR.ln() - ch.ln_determinant();
        prior.push((lam, ld_lam));
    }
    Ok(prior)
}

/// The position of clearance `c_mm` on a clearance axis, as [`fine_grid`]'s positions are:
/// (interval, fraction in ln c), clamped to the axis.
pub fn axis_position(clearance_mm: &[f64], c_mm: f64) -> (usize, f64) {
    let n = clearance_mm.len();
    if n < 2 || c_mm <= clearance_mm[0] {
        return (0, 0.0);
    }
    for ic in 0..n - 1 {
        let (a, b) = (clearance_mm[ic], clearance_mm[ic + 1]);
        if c_mm <= b {
            return (ic, (c_mm / a).ln() / (b / a).ln());
        }
    }
    (n - 2, 1.0)
}

/// Midpoints of `n` equal bins of [−1, 1].
fn midpoints(n: usize) -> Vec<f64> {
    let n = n.max(1);
    (0..n)
        .map(|k| -1.0 + (2 * k + 1) as f64 / n as f64)
        .collect()
}

/// ln of the mean of exp over `xs` (−∞ when all are).
fn log_mean_exp(xs: &[f64]) -> f64 {
    let m = xs.iter().copied().fold(f64::NEG_INFINITY, f64::max);
    if !m.is_finite() {
        return f64::NEG_INFINITY;
    }
    m + (xs.iter().map(|x| (x - m).exp()).sum::<f64>() / xs.len() as f64).ln()
}

impl LinearPosterior {
    /// A flat posterior over the grid points `pos` ([`fine_grid`]) of `table`, with the
    /// estimator settings `cfg` (checked by [`EstimatorConfig::validate`]).
    pub fn new(
        table: &ResponseTable,
        model: &Arc<LinearModel>,
        pos: Vec<(usize, f64)>,
        cfg: &EstimatorConfig,
    ) -> anyhow::Result<LinearPosterior> {
        let mut mode = PhaseMode::parse(&cfg.phase)
            .ok_or_else(|| anyhow::anyhow!("estimator.phase: unknown `{}`", cfg.phase))?;
        if !model.has_phase() {
            // The table's model does not know Δ: its event scatter already holds it.
            mode = PhaseMode::Event;
        }
        // The gridded coordinates' points (ψ = 0).
        let mut points: Vec<[f64; N_VARS]> = vec![[0.0; N_VARS]];
        for (i, j) in model.grid_coords().into_iter().enumerate() {
            let values = midpoints(if i == 0 {
                cfg.damping_grid
            } else {
                cfg.unbalance_grid
            });
            points = points
                .iter()
                .flat_map(|p| {
                    values.iter().map(move |&v| {
                        let mut q = *p;
                        q[j] = v;
                        q
                    })
                })
                .collect();
        }
        let points_v: Vec<[f64; N_VARS]> = if mode == PhaseMode::Event {
            Vec::new()
        } else {
            points
                .iter()
                .flat_map(|p| {
                    phase_quadrature(cfg.phase_grid).map(move |u| {
                        let mut q = *p;
                        q[PHASE] = u;
                        q
                    })
                })
                .collect()
        };
        let points_e = if mode == PhaseMode::Vehicle {
            Vec::new()
        } else {
            points
        };
        // "vehicle": one event covariance per clearance, so points of one slope group share P;
        // "event": the covariance holds the spread over Δ, which depends on every gridded
        // variable, so each point is its own group.
        let grid_v = Grid::new(points_v, model, false);
        let grid_e = Grid::new(points_e, model, true);
        let n_quad = if model.has_phase() { EVENT_PHASES } else { 1 };
        let inflation2 = cfg.std_inflation * cfg.std_inflation;
        // The configured vehicle-level misfit (measured vehicles against the model's), and a
        // small floor that keeps T invertible where the fit found none.
        let misfit_var = 1e-4 + cfg.misfit_std * cfg.misfit_std;
        let prior = build_prior(model, &pos, misfit_var, inflation2)?;
        let ng = pos.len();
        let n_points = grid_v.len().max(grid_e.len());
        let n_groups = grid_v.n_groups.max(grid_e.n_groups);
        Ok(LinearPosterior {
            model: Arc::clone(model),
            speed_kmh: table.speed_kmh.clone(),
            stats_v: StatSet::zero(ng, &grid_v),
            stats_e: StatSet::zero(ng, &grid_e),
            base_v: StatSet::default(),
            base_e: StatSet::default(),
            has_baseline: false,
            scratch_event: Arc::new(Mutex::new(EventScratch::new(ng, n_quad, grid_v.n_mono))),
            scratch_event_base: None,
            n_quad,
            fac: vec![None; n_groups],
            scratch: vec![0.0; n_points],
            scratch_dev: vec![0.0; n_points],
            scratch_base: Vec::new(),
            scratch_base_dev: Vec::new(),
            baseline_obs: 0.0,
            baseline_pos: (0, 0.0),
            baseline_ln_jacobian: 0.0,
            misfit_var,
            baseline_misfit_var: cfg.baseline_misfit_std * cfg.baseline_misfit_std,
            grid_v,
            grid_e,
            pos,
            prior,
            inflation2,
            half_life_km: cfg.evidence_half_life_km,
            power: cfg.evidence_power,
            share_v: vec![0.0; ng],
            scratch_raw: vec![0.0; ng],
            p_vehicle: f64::NAN,
            n_obs: 0.0,
            min_deviance: f64::NAN,
            ln_evidence: [f64::NAN; 2],
            ln_jacobian: 0.0,
        })
    }

    /// Uses `other`'s event scratch from now on instead of its own, grown to fit both (see
    /// [`EventScratch`]): estimators that take their events one after another, the angle's and
    /// the torque tables' of one vehicle, need only one. Allocates; updates still do not.
    pub fn share_scratch(&mut self, other: &LinearPosterior) {
        if Arc::ptr_eq(&self.scratch_event, &other.scratch_event) {
            return;
        }
        other
            .scratch_event
            .lock()
            .unwrap_or_else(|e| e.into_inner())
            .reserve(self.pos.len(), self.n_quad, self.grid_v.n_mono);
        self.scratch_event = Arc::clone(&other.scratch_event);
    }

    /// Grid points per clearance (both hypotheses).
    pub fn points(&self) -> usize {
        self.grid_v.len() + self.grid_e.len()
    }

    /// Fades the evidence over `dist_km` of driving.
    pub fn forget(&mut self, dist_km: f64) {
        let fades = self.half_life_km > 0.0 && dist_km > 0.0;
        if !fades {
            return;
        }
        let f = (-(dist_km / self.half_life_km) * std::f64::consts::LN_2).exp();
        self.stats_v.scale(f);
        self.stats_e.scale(f);
        self.n_obs *= f;
        self.ln_jacobian *= f;
    }

    /// Adds one event's ln dz_table/dz_measured ([`super::features::ln_jacobian_gain`]) to
    /// the evidence.
    pub fn add_ln_jacobian(&mut self, ln_jac: f64) {
        self.ln_jacobian += ln_jac;
    }

    /// Adds one event: features `z` (ln RMS, ln peak, cruise; masked ones ignored) at initial
    /// speed `v0_kmh` and deceleration `decel_g`.
    pub fn update(&mut self, z: [f64; N_FEAT], mask: &FeatureMask, v0_kmh: f64, decel_g: f64) {
        self.n_obs += mask.iter().filter(|&&m| m).count() as f64;
        let sp = bracket(&self.speed_kmh, v0_kmh);
        // Nothing panics while the scratch is held, and its contents do not outlive one
        // update, so a poisoned lock is taken as it is.
        let mut scr = self.scratch_event.lock().unwrap_or_else(|e| e.into_inner());
        accumulate(
            &self.model,
            self.inflation2,
            &self.pos,
            sp,
            &z,
            mask,
            decel_g,
            (&self.grid_v, &self.grid_e),
            self.n_quad,
            &mut scr,
            &mut self.stats_v,
            &mut self.stats_e,
        );
    }

    /// Adds one event of the same vehicle at a known clearance, at `pos` on the table's
    /// clearance axis ([`axis_position`]): a baseline event (module doc). Allocates the
    /// baseline's statistics at the first one.
    pub fn update_known(
        &mut self,
        z: [f64; N_FEAT],
        mask: &FeatureMask,
        v0_kmh: f64,
        decel_g: f64,
        pos: (usize, f64),
    ) {
        if !self.has_baseline {
            self.has_baseline = true;
            self.base_v = StatSet::zero(1, &self.grid_v);
            self.base_e = StatSet::zero(1, &self.grid_e);
            self.scratch_event_base = Some(EventScratch::new(1, self.n_quad, self.grid_v.n_mono));
            let n = self.grid_v.len().max(self.grid_e.len());
            self.scratch_base = vec![0.0; n];
            self.scratch_base_dev = vec![0.0; n];
            if self.baseline_misfit_var > 0.0 {
                let var = self.misfit_var + self.baseline_misfit_var;
                if let Ok(p) = build_prior(&self.model, &self.pos, var, self.inflation2) {
                    self.prior = p;
                }
            }
        }
        self.baseline_obs += mask.iter().filter(|&&m| m).count() as f64;
        self.baseline_pos = pos;
        let sp = bracket(&self.speed_kmh, v0_kmh);
        if let Some(scr) = self.scratch_event_base.as_mut() {
            accumulate(
                &self.model,
                self.inflation2,
                &[pos],
                sp,
                &z,
                mask,
                decel_g,
                (&self.grid_v, &self.grid_e),
                self.n_quad,
                scr,
                &mut self.base_v,
                &mut self.base_e,
            );
        }
    }

    /// Adds one baseline event's ln dz_table/dz_measured (a gain other than 1) to the
    /// baseline's evidence.
    pub fn add_baseline_ln_jacobian(&mut self, ln_jac: f64) {
        self.baseline_ln_jacobian += ln_jac;
    }

    /// ln of the baseline events' marginal likelihood at their clearance (the position of
    /// the last one), the vehicle's coordinates and misfit integrated out under the prior
    /// this posterior was built with, both phase hypotheses in use weighted ½, with the
    /// evidence power and the Jacobian of any gain; up to a constant that depends only on the
    /// number of features observed. `None` before a baseline event. Allocates (the prior at
    /// one position and scratch): for fits, not for the per-frame path.
    pub fn baseline_ln_evidence(&self) -> Option<f64> {
        if !self.has_baseline {
            return None;
        }
        let var = self.misfit_var + self.baseline_misfit_var;
        let prior = build_prior(&self.model, &[self.baseline_pos], var, self.inflation2).ok()?;
        let (lam, ld_lam) = &prior[0];
        let hyp = |grid: &Grid, stats: &StatSet| -> f64 {
            if grid.is_empty() {
                return f64::NEG_INFINITY;
            }
            let mut fac = vec![None; grid.n_groups];
            let (mut l, mut dev) = (vec![0.0; grid.len()], vec![0.0; grid.len()]);
            point_evidence(
                grid, stats, 0, None, lam, *ld_lam, &mut fac, &mut l, &mut dev,
            );
            log_mean_exp(&l)
        };
        let (l_v, l_e) = (
            hyp(&self.grid_v, &self.base_v),
            hyp(&self.grid_e, &self.base_e),
        );
        let l = match (self.grid_v.is_empty(), self.grid_e.is_empty()) {
            (false, false) => log_mean_exp(&[l_v, l_e]),
            (false, true) => l_v,
            _ => l_e,
        };
        let l = self.power * (l + self.baseline_ln_jacobian);
        l.is_finite().then_some(l)
    }

    /// Baseline events added ([`Self::update_known`]), as features observed.
    pub fn baseline_features(&self) -> f64 {
        self.baseline_obs
    }

    /// ln p(events | c_g) of one hypothesis at clearance `g`, with the baseline's: the joint
    /// one and the baseline's alone (0 without a baseline), both as means over the grid
    /// points; updates the smallest deviance `min_dev` (the events' given the baseline).
    fn hypothesis_evidence(&mut self, hyp_v: bool, g: usize, min_dev: &mut f64) -> (f64, f64) {
        let (grid, stats, base) = if hyp_v {
            (&self.grid_v, &self.stats_v, &self.base_v)
        } else {
            (&self.grid_e, &self.stats_e, &self.base_e)
        };
        if grid.is_empty() {
            return (f64::NEG_INFINITY, f64::NEG_INFINITY);
        }
        let n = grid.len();
        let (lam, ld_lam) = &self.prior[g];
        let lb = if self.has_baseline {
            point_evidence(
                grid,
                base,
                0,
                None,
                lam,
                *ld_lam,
                &mut self.fac,
                &mut self.scratch_base,
                &mut self.scratch_base_dev,
            );
            point_evidence(
                grid,
                stats,
                g,
                Some(base),
                lam,
                *ld_lam,
                &mut self.fac,
                &mut self.scratch,
                &mut self.scratch_dev,
            );
            for (d, db) in self.scratch_dev[..n].iter_mut().zip(&self.scratch_base_dev) {
                *d -= db;
            }
            log_mean_exp(&self.scratch_base[..n])
        } else {
            point_evidence(
                grid,
                stats,
                g,
                None,
                lam,
                *ld_lam,
                &mut self.fac,
                &mut self.scratch,
                &mut self.scratch_dev,
            );
            0.0
        };
        for &d in &self.scratch_dev[..n] {
            *min_dev = min_dev.min(d);
        }
        (log_mean_exp(&self.scratch[..n]), lb)
    }

    /// Writes the normalised posterior probabilities of the grid points into `out` (one per
    /// point of [`fine_grid`]), with `log_prior` the ln of the clearance prior at each point
    /// (up to a constant; not raised to the evidence power).
    pub fn probabilities_into(&mut self, out: &mut [f64], log_prior: &[f64]) {
        let mut mx = f64::NEG_INFINITY;
        let mut mx_raw = f64::NEG_INFINITY;
        let mut min_dev = f64::INFINITY;
        let (nv, ne) = (self.grid_v.len(), self.grid_e.len());
        let has_base = self.has_baseline;
        for g in 0..self.pos.len().min(out.len()) {
            // ln p of the events (with the baseline's: joint) and of the baseline alone.
            let (l_v, lb_v) = self.hypothesis_evidence(true, g, &mut min_dev);
            let (l_e, lb_e) = self.hypothesis_evidence(false, g, &mut min_dev);
            // Equal prior weight on the hypotheses that are in use; with a baseline, less the
            // baseline's own evidence (the conditional evidence, module doc).
            let (l, lb) = match (nv > 0, ne > 0) {
                (true, true) => (log_mean_exp(&[l_v, l_e]), log_mean_exp(&[lb_v, lb_e])),
                (true, false) => (l_v, lb_v),
                _ => (l_e, lb_e),
            };
            let l = if has_base { l - lb } else { l };
            self.share_v[g] = if l.is_finite() {
                0.5 * (l_v - lb - l).exp()
            } else {
                0.5
            };
            out[g] = self.power * l + log_prior[g];
            mx = mx.max(out[g]);
            self.scratch_raw[g] = l + log_prior[g];
            mx_raw = mx_raw.max(self.scratch_raw[g]);
        }
        // The prior's normaliser, so that the evidence is comparable between settings that
        // change the likelihood only (e.g. the transfer gain).
        let lp_max = log_prior.iter().copied().fold(f64::NEG_INFINITY, f64::max);
        let ln_prior_sum = lp_max
            + log_prior
                .iter()
                .map(|l| (l - lp_max).exp())
                .sum::<f64>()
                .ln();
        let n = self.pos.len().min(out.len());
        self.ln_evidence = if mx.is_finite() && mx_raw.is_finite() {
            [
                mx + out[..n].iter().map(|o| (o - mx).exp()).sum::<f64>().ln() - ln_prior_sum
                    + self.power * self.ln_jacobian,
                self.ln_jacobian
                    + mx_raw
                    + self.scratch_raw[..n]
                        .iter()
                        .map(|o| (o - mx_raw).exp())
                        .sum::<f64>()
                        .ln()
                    - ln_prior_sum,
            ]
        } else {
            [f64::NAN; 2]
        };
        self.min_deviance = if min_dev.is_finite() {
            min_dev
        } else {
            f64::NAN
        };
        if !mx.is_finite() {
            out.fill(1.0 / out.len() as f64);
            return;
        }
        let mut sum = 0.0;
        for l in out.iter_mut() {
            *l = (*l - mx).exp();
            sum += *l;
        }
        for l in out.iter_mut() {
            *l /= sum;
        }
        self.p_vehicle = if nv > 0 && ne > 0 {
            out.iter().zip(&self.share_v).map(|(p, s)| p * s).sum()
        } else {
            f64::NAN
        };
    }

    /// How well the events fit the table's model at its best clearance and grid point, after
    /// the last [`Self::probabilities_into`]: `(deviance, degrees of freedom)`, the deviance
    /// being χ²-distributed with about that many degrees of freedom when the vehicle is one the
    /// model describes (a little less: the best point is chosen by the same events). `None`
    /// before any event.
    pub fn fit(&self) -> Option<(f64, f64)> {
        (self.n_obs > 0.0 && self.min_deviance.is_finite())
            .then_some((self.min_deviance, self.n_obs))
    }

    /// ln of the events' marginal likelihood under the table's model (the clearance prior
    /// normalised), `[with the evidence power, without]`, after the last
    /// [`Self::probabilities_into`]; `None` before any event.
    pub fn ln_evidence(&self) -> Option<[f64; 2]> {
        (self.n_obs > 0.0 && self.ln_evidence[0].is_finite()).then_some(self.ln_evidence)
    }

    /// Posterior probability that the wheels' unbalance phase difference was the same in all
    /// the events (hypothesis "vehicle" of `phase = "either"`), after the last
    /// [`Self::probabilities_into`]; `None` when only one hypothesis is in use.
    pub fn phase_fixed_probability(&self) -> Option<f64> {
        self.p_vehicle.is_finite().then_some(self.p_vehicle)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use rand::{Rng, SeedableRng};
    use rand_chacha::ChaCha8Rng;

    /// One event as the estimator sees it: features, mask, initial speed, deceleration.
    type Ev = ([f64; N_FEAT], FeatureMask, f64, f64);

    fn table(name: &str) -> ResponseTable {
        let path = std::path::Path::new(env!("CARGO_MANIFEST_DIR"))
            .join("config/vehicles/toyota_rav4")
            .join(name);
        ResponseTable::load(&path).unwrap()
    }

    /// Events of one vehicle drawn from the table's model at clearance index `ic`, one
    /// coordinate vector and phase difference, with event scatter; every fourth without the
    /// cruise feature.
    fn events(t: &ResponseTable, ic: usize, n: usize, seed: u64) -> Vec<Ev> {
        let lm = t.linear.as_ref().unwrap();
        let mut rng = ChaCha8Rng::seed_from_u64(seed);
        let mut x = [0.0; N_VARS];
        for v in x.iter_mut() {
            *v = rng.random_range(-0.9..0.9);
        }
        (0..n)
            .map(|k| {
                let v0 = rng.random_range(32.0..95.0);
                let d = rng.random_range(0.3..0.8);
                let iv = bracket(&t.speed_kmh, v0).0;
                let z = std::array::from_fn(|f| {
                    lm.mean_at(ic, iv, f, &x, d) + 0.1 * rng.random_range(-1.0..1.0)
                });
                (z, [true, true, k % 4 != 3], v0, d)
            })
            .collect()
    }

    /// ln p(events | c_g, point) and the deviance of every point of one hypothesis, summed
    /// event by event at each point (no groups, no split means): what the grouped
    /// statistics must reproduce.
    fn naive(
        post: &LinearPosterior,
        grid: &Grid,
        per_event_phase: bool,
        g: usize,
        evs: &[Ev],
        base: &[(Ev, (usize, f64))],
    ) -> Vec<(f64, f64, f64)> {
        let m = &post.model;
        let (lam, ld_lam) = &post.prior[g];
        let n_quad = if m.has_phase() { EVENT_PHASES } else { 1 };
        let mut out = Vec::new();
        for x in &grid.points {
            // [events and baseline, baseline alone]: A, h, s, Σ ln det S.
            let mut acc = [(*lam, VecX::zeros(), 0.0, 0.0); 2];
            let all = evs
                .iter()
                .map(|e| (e, post.pos[g], false))
                .chain(base.iter().map(|(e, p)| (e, *p, true)));
            for (&(z, mask, v0, d), p, is_base) in all {
                let mut coefs = Coefs::default();
                m.coef_interp(p, bracket(&post.speed_kmh, v0), &mut coefs);
                let sigma = m.within_at(p) * post.inflation2;
                let mut basis = Basis::default();
                let (pr, var) = if per_event_phase {
                    let mut bq = vec![Basis::default(); n_quad];
                    for (k, u) in phase_quadrature(n_quad).enumerate() {
                        let mut y = *x;
                        y[PHASE] = u;
                        m.basis_into(&y, d, &mut bq[k]);
                    }
                    Basis::mean_of(&bq, &mut basis);
                    let pr = m.predict_with(&coefs, &basis);
                    let mut var = Matrix3::zeros();
                    for b in &bq {
                        let dv = Vector3::from(m.mean_with(&coefs, b)) - Vector3::from(pr.a);
                        var += dv * dv.transpose() / n_quad as f64;
                    }
                    (pr, var)
                } else {
                    m.basis_into(x, d, &mut basis);
                    (m.predict_with(&coefs, &basis), Matrix3::zeros())
                };
                let (w, ld) = masked_inverse(&(sigma + var), &mask).unwrap();
                let mut hm = SMatrix::<f64, N_FEAT, NX>::zeros();
                for f in 0..N_FEAT {
                    for j in 0..N_LIN {
                        hm[(f, j)] = pr.b[f][j];
                    }
                    hm[(f, N_LIN + f)] = 1.0;
                }
                let r = residual(&z, &pr.a, &mask);
                for (i, a) in acc.iter_mut().enumerate() {
                    if i == 1 && !is_base {
                        continue;
                    }
                    a.0 += hm.transpose() * w * hm;
                    a.1 += hm.transpose() * (w * r);
                    a.2 += r.dot(&(w * r));
                    a.3 += ld;
                }
            }
            let ev = |(a, h, s, ld): (MatX, VecX, f64, f64)| {
                let ch = a.cholesky().unwrap();
                let dev = s - h.dot(&ch.solve(&h));
                (
                    -0.5 * dev - 0.5 * ch.ln_determinant() + 0.5 * ld_lam - 0.5 * ld,
                    dev,
                )
            };
            let (l, dev) = ev(acc[0]);
            let (lb, devb) = if base.is_empty() {
                (0.0, 0.0)
            } else {
                ev(acc[1])
            };
            out.push((l, lb, dev - devb));
        }
        out
    }

    /// The posterior of `post` after `evs` (and the baseline events `base`), and the one of
    /// [`naive`] on the same grid points, with the smallest deviance of each.
    fn both(
        mut post: LinearPosterior,
        evs: &[Ev],
        base: &[(Ev, (usize, f64))],
    ) -> (Vec<f64>, Vec<f64>, f64, f64) {
        for &((z, mask, v0, d), p) in base {
            post.update_known(z, &mask, v0, d, p);
        }
        for &(z, mask, v0, d) in evs {
            post.update(z, &mask, v0, d);
        }
        let ng = post.pos.len();
        let mut got = vec![0.0; ng];
        post.probabilities_into(&mut got, &vec![0.0; ng]);
        let mut want = vec![0.0; ng];
        let mut min_dev = f64::INFINITY;
        for (g, w) in want.iter_mut().enumerate() {
            let mut hyp = |grid: &Grid, per_event: bool| -> (f64, f64) {
                if grid.is_empty() {
                    return (f64::NEG_INFINITY, f64::NEG_INFINITY);
                }
                let pts = naive(&post, grid, per_event, g, evs, base);
                min_dev = pts.iter().fold(min_dev, |m, p| m.min(p.2));
                let l: Vec<f64> = pts.iter().map(|p| p.0).collect();
                let lb: Vec<f64> = pts.iter().map(|p| p.1).collect();
                (log_mean_exp(&l), log_mean_exp(&lb))
            };
            let (l_v, lb_v) = hyp(&post.grid_v, false);
            let (l_e, lb_e) = hyp(&post.grid_e, true);
            let l = log_mean_exp(&[l_v, l_e]) - log_mean_exp(&[lb_v, lb_e]);
            *w = post.power * l;
        }
        let mx = want.iter().copied().fold(f64::NEG_INFINITY, f64::max);
        want.iter_mut().for_each(|w| *w = (*w - mx).exp());
        let sum: f64 = want.iter().sum();
        want.iter_mut().for_each(|w| *w /= sum);
        (got, want, post.fit().unwrap().0, min_dev)
    }

    /// The grouped posterior after `n` events against [`naive`]'s: equal within `tol` (relative),
    /// P being summed in single precision ([`StatSet`]).
    fn check(name: &str, baseline: bool, n: usize, tol: f64) {
        let t = table(name);
        let lm = t.linear.clone().unwrap();
        let cfg = EstimatorConfig {
            evidence_power: 0.3,
            ..EstimatorConfig::default()
        };
        let (_, pos) = fine_grid(&t.clearance_mm, 2);
        let post = LinearPosterior::new(&t, &lm, pos, &cfg).unwrap();
        let evs = events(&t, 6, n, 7);
        let base: Vec<(Ev, (usize, f64))> = if baseline {
            events(&t, 1, 4, 8)
                .into_iter()
                .map(|e| (e, axis_position(&t.clearance_mm, t.clearance_mm[1])))
                .collect()
        } else {
            Vec::new()
        };
        let (got, want, dev, want_dev) = both(post, &evs, &base);
        for (g, (a, b)) in got.iter().zip(&want).enumerate() {
            assert!(
                (a - b).abs() <= 1e-9 + tol * b,
                "{name}: clearance {g}: grouped {a}, per point {b}"
            );
        }
        assert!(
            (dev - want_dev).abs() <= tol * want_dev.abs().max(1.0),
            "{name}: deviance {dev} vs {want_dev}"
        );
        // The events were drawn at clearance index 6: the posterior must say so, or the
        // comparison above compared nothing.
        let best = got
            .iter()
            .enumerate()
            .fold(0, |b, (i, p)| if *p > got[b] { i } else { b });
        assert!(
            (10..=14).contains(&best),
            "{name}: peak at fine index {best}"
        );
    }

    #[test]
    fn grouped_statistics_equal_per_point_sums_on_the_torque_law() {
        // x5² gridded: 9 damping × 7 unbalance × 8 phase points share 9 groups.
        let t = table("table_torque.json");
        let lm = t.linear.clone().unwrap();
        assert_eq!(lm.gridded, vec![super::super::linear::UNBALANCE]);
        let (_, pos) = fine_grid(&t.clearance_mm, 2);
        let post = LinearPosterior::new(&t, &lm, pos, &EstimatorConfig::default()).unwrap();
        assert_eq!((post.grid_v.len(), post.grid_v.n_groups), (504, 9));
        assert_eq!(post.grid_v.n_mono, 5);
        check("table_torque.json", false, 12, 1e-5);
        check("table_torque.json", true, 12, 1e-5);
    }

    #[test]
    fn grouped_statistics_equal_per_point_sums_on_the_angle_law() {
        // The unbalance closed-form: ψ sets its slope, so every point is its own group.
        check("table.json", false, 12, 1e-5);
        check("table.json", true, 12, 1e-5);
    }

    #[test]
    fn estimators_sharing_one_scratch_estimate_as_alone() {
        // The angle's and the torque's laws need scratch of other shapes (monomials, and here
        // clearance rows): each of three estimators sharing one must read exactly what it reads
        // with its own, whichever of them made the scratch and in whatever order they update.
        let (ta, tt) = (table("table.json"), table("table_torque.json"));
        let (la, lt) = (ta.linear.clone().unwrap(), tt.linear.clone().unwrap());
        let cfg = EstimatorConfig::default();
        let make = |t: &ResponseTable, lm: &Arc<LinearModel>, refine: usize| {
            LinearPosterior::new(t, lm, fine_grid(&t.clearance_mm, refine).1, &cfg).unwrap()
        };
        let alone = [make(&ta, &la, 4), make(&tt, &lt, 2), make(&ta, &la, 2)];
        let mut shared = [make(&ta, &la, 4), make(&tt, &lt, 2), make(&ta, &la, 2)];
        assert_ne!(alone[0].grid_v.n_mono, alone[1].grid_v.n_mono);
        assert_ne!(alone[0].pos.len(), alone[2].pos.len());
        let (first, rest) = shared.split_at_mut(1);
        rest[0].share_scratch(&first[0]);
        let (mid, last) = rest.split_at_mut(1);
        last[0].share_scratch(&mid[0]);
        assert!(shared
            .iter()
            .all(|p| Arc::ptr_eq(&p.scratch_event, &shared[0].scratch_event)));
        let mut alone = alone;
        let evs = [
            events(&ta, 5, 10, 3),
            events(&tt, 5, 10, 4),
            events(&ta, 7, 10, 5),
        ];
        for k in 0..10 {
            for j in [2, 0, 1] {
                let (z, mask, v0, d) = evs[j][k];
                alone[j].update(z, &mask, v0, d);
                shared[j].update(z, &mask, v0, d);
            }
        }
        for (a, s) in alone.iter_mut().zip(shared.iter_mut()) {
            let n = a.pos.len();
            let (mut pa, mut ps) = (vec![0.0; n], vec![0.0; n]);
            a.probabilities_into(&mut pa, &vec![0.0; n]);
            s.probabilities_into(&mut ps, &vec![0.0; n]);
            assert_eq!(pa, ps);
            assert_eq!(a.fit(), s.fit());
            assert!(pa.iter().all(|p| p.is_finite()) && pa.iter().sum::<f64>() > 0.99);
        }
    }

    #[test]
    fn single_precision_sums_hold_over_a_long_life() {
        check("table.json", false, 1000, 1e-5);
    }
}
