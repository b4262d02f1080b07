//! What `shimmy reproduce` runs: the grids of the article's §3 experiments, full or `--quick`.
//!
//! What it is: plain lists of parameter values and the expansion into [`Case`]s (deduplicated,
//! so a run shared by two experiments is simulated once). What it is not: the analysis of the
//! results (see `report`).

use super::runs::{Case, Variant};
use crate::model::JointMode;

/// Reference speed of the article's §3.2/§3.4 figures and of the 0.2° rule (km/h).
pub const V_REF: f64 = 55.0;

/// Grids of one reproduction.
#[derive(Debug, Clone)]
pub struct Plan {
    pub quick: bool,
    pub seeds: Vec<u64>,
    /// §3.1: (clearance mm, speed km/h) conditions, step sizes, simulated time.
    pub conv_conditions: Vec<(f64, f64)>,
    pub conv_h: Vec<f64>,
    pub conv_duration_s: f64,
    /// MODEL.md §13 grid: clearances × speeds, dual.
    pub grid_c: Vec<f64>,
    pub grid_v: Vec<f64>,
    /// Clearance sweep at V_REF, dual and single, with Lyapunov exponents.
    pub sweep_c: Vec<f64>,
    /// Clearances shown in the time/PSD/phase/Poincaré/CWT figures.
    pub plot_c: Vec<f64>,
    /// Speed sweep × clearances.
    pub speeds: Vec<f64>,
    pub speed_c: Vec<f64>,
    /// Stiffness sweeps at (0.1 mm, V_REF): tie rod k_t and restraint k_g (N/m).
    pub k_t: Vec<f64>,
    pub k_g: Vec<f64>,
    /// Braking intensities (g) at 0.2 mm, V_REF.
    pub decels: Vec<f64>,
    /// The article's recommended steering damping, tried as kingpin damping (N·m·s/rad).
    pub paper_damping: f64,
}

impl Plan {
    pub fn new(quick: bool, seeds: usize) -> Self {
        let seeds: Vec<u64> = (0..seeds.max(1) as u64).collect();
        if quick {
            Self {
                quick,
                seeds,
                conv_conditions: vec![(0.1, V_REF)],
                conv_h: vec![1e-4, 5e-5, 1e-5],
                conv_duration_s: 2.5,
                grid_c: vec![0.05, 0.4],
                grid_v: vec![25.0, V_REF],
                sweep_c: vec![0.05, 0.1, 0.4],
                plot_c: vec![0.05, 0.1, 0.4],
                speeds: vec![20.0, V_REF, 120.0],
                speed_c: vec![0.1],
                k_t: vec![2e6, 4e6, 8e6],
                k_g: vec![5e4, 2e5],
                decels: vec![0.3, 0.8],
                paper_damping: 5.0,
            }
        } else {
            Self {
                quick,
                seeds,
                conv_conditions: vec![(0.05, 40.0), (0.1, V_REF), (0.2, 75.0), (0.4, 100.0)],
                conv_h: vec![1e-4, 5e-5, 1e-5],
                conv_duration_s: 10.0,
                grid_c: vec![0.03, 0.05, 0.1, 0.2, 0.4],
                grid_v: vec![25.0, 40.0, V_REF, 75.0, 95.0],
                sweep_c: vec![0.03, 0.05, 0.07, 0.1, 0.15, 0.2, 0.3, 0.4],
                plot_c: vec![0.05, 0.1, 0.2, 0.4],
                speeds: (2..=12).map(|k| 10.0 * k as f64).collect(),
                speed_c: vec![0.05, 0.1, 0.2],
                k_t: vec![1e6, 2e6, 3e6, 3.5e6, 4e6, 4.5e6, 5e6, 6e6, 8e6],
                k_g: vec![2.5e4, 5e4, 1e5, 2e5, 4e5],
                decels: vec![0.3, 0.5, 0.8],
                paper_damping: 5.0,
            }
        }
    }

    /// Every case to simulate, deduplicated (flags of merged cases are OR-ed).
    pub fn cases(&self) -> Vec<Case> {
        let mut out: Vec<Case> = Vec::new();
        let mut add = |c: Case| {
            if let Some(e) = out.iter_mut().find(|e| e.same_physics(&c)) {
                e.lyapunov |= c.lyapunov;
                e.keep_trace |= c.keep_trace;
            } else {
                out.push(c);
            }
        };
        // §3.1 convergence: seed 0, full duration, each step size.
        for &(c, v) in &self.conv_conditions {
            for &h in &self.conv_h {
                let mut k = Case::new(c, v, JointMode::Dual, 0);
                k.h_s = h;
                k.duration_s = Some(self.conv_duration_s);
                k.keep_trace = c == 0.1 && v == V_REF;
                add(k);
            }
        }
        for &seed in &self.seeds {
            for &c in &self.grid_c {
                for &v in &self.grid_v {
                    add(Case::new(c, v, JointMode::Dual, seed));
                }
            }
            for &c in &self.sweep_c {
                for joints in [JointMode::Dual, JointMode::Single] {
                    let mut k = Case::new(c, V_REF, joints, seed);
                    k.lyapunov = true;
                    k.keep_trace = seed == 0 && self.plot_c.contains(&c);
                    add(k);
                }
            }
            for &c in &self.speed_c {
                for &v in &self.speeds {
                    add(Case::new(c, v, JointMode::Dual, seed));
                    // Dual vs single across speeds at the reference clearance only.
                    if c == 0.1 {
                        add(Case::new(c, v, JointMode::Single, seed));
                    }
                }
            }
            for &k_t in &self.k_t {
                let mut k = Case::new(0.1, V_REF, JointMode::Dual, seed);
                k.variant = Variant::TieRodStiffness(k_t);
                add(k);
            }
            for &k_g in &self.k_g {
                let mut k = Case::new(0.1, V_REF, JointMode::Dual, seed);
                k.variant = Variant::RestraintStiffness(k_g);
                add(k);
            }
            for &a in &self.decels {
                let mut k = Case::new(0.2, V_REF, JointMode::Dual, seed);
                k.decel_g = a;
                add(k);
            }
            // 0.5 g reference for the braking-intensity comparison.
            add(Case::new(0.2, V_REF, JointMode::Dual, seed));
        }
        let mut k = Case::new(0.1, V_REF, JointMode::Dual, 0);
        k.variant = Variant::KingpinDamping(self.paper_damping);
        add(k);
        out
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn cases_are_deduplicated_and_flags_merged() {
        let plan = Plan::new(false, 3);
        let cases = plan.cases();
        for (i, a) in cases.iter().enumerate() {
            assert!(
                !cases[i + 1..].iter().any(|b| a.same_physics(b)),
                "duplicate {a:?}"
            );
        }
        // The 0.1 mm / 55 km/h dual seed-0 run is in the grid, the sweep and the stiffness
        // default: it must carry the sweep's Lyapunov and plot flags.
        let k = cases
            .iter()
            .find(|c| {
                c.clearance_mm == 0.1
                    && c.v0_kmh == V_REF
                    && c.seed == 0
                    && c.joints == JointMode::Dual
                    && c.variant == Variant::Default
                    && c.duration_s.is_none()
                    && c.decel_g == 0.5
            })
            .unwrap();
        assert!(k.lyapunov && k.keep_trace);
        assert!(Plan::new(true, 1).cases().len() < cases.len() / 5);
    }
}
