//! What a steering angle sensor sees (MODEL.md §8): the steering-wheel angle δ_sw from the rack
//! displacement, and the SAS sampling model (100 Hz decimation, 0.1° quantisation with a random
//! sub-LSB offset).
//!
//! What it is: output-side conversions. What it is not: a CAN encoder (firmware-sim packs
//! frames) nor the §15 column dynamics (`rhs`).

/// δ_sw = X_r / r_p with X_r = X·k_eq/k_g (MODEL.md §8), in rad.
#[inline(always)]
pub fn steering_wheel_angle_rad(x_m: f64, k_eq: f64, k_g: f64, r_p: f64) -> f64 {
    x_m * k_eq / k_g / r_p
}

/// A quantising steering angle sensor (MODEL.md §8).
#[derive(Debug, Clone, Copy)]
pub struct AngleSensor {
    pub resolution_deg: f64,
    /// Sub-LSB offset in [−0.5, 0.5) LSB.
    pub offset_lsb: f64,
}

impl AngleSensor {
    /// Offset drawn from `seed` (independent of the excitation stream).
    pub fn new(resolution_deg: f64, seed: u64) -> Self {
        use rand::{Rng, SeedableRng};
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(seed ^ 0x5a5_5e75_0c0f_fee5);
        Self {
            resolution_deg,
            offset_lsb: rng.random::<f64>() - 0.5,
        }
    }

    /// Reading in degrees for a true angle in radians.
    #[inline]
    pub fn read_deg(&self, angle_rad: f64) -> f64 {
        let lsb = angle_rad.to_degrees() / self.resolution_deg + self.offset_lsb;
        lsb.round() * self.resolution_deg
    }

    /// Decimates a uniformly sampled δ_sw (rad, at `fs_hz`) to `sample_hz` and quantises it.
    /// Returns (t_s, angle_deg) pairs starting at t0_s.
    pub fn sample_trace(
        &self,
        t0_s: f64,
        fs_hz: f64,
        angle_rad: &[f64],
        sample_hz: f64,
    ) -> Vec<(f64, f64)> {
        let stride = (fs_hz / sample_hz).round().max(1.0) as usize;
        angle_rad
            .iter()
            .enumerate()
            .step_by(stride)
            .map(|(i, &a)| (t0_s + i as f64 / fs_hz, self.read_deg(a)))
            .collect()
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn overall_ratio_is_about_15_5() {
        // §8: i_s = l sin α / r_p ≈ 15.5; δ_sw ≈ i_s·θ with rigid joints (X = l sin α θ).
        let (k_t, k_g) = (4e6, 1e5);
        let k_eq = k_t * k_g / (k_t + k_g);
        let theta = 1e-3;
        let x = 0.13 * 72f64.to_radians().sin() * theta * k_g / k_eq;
        let sw = steering_wheel_angle_rad(x, k_eq, k_g, 8e-3);
        assert!((sw / theta - 15.45).abs() < 0.1);
    }

    #[test]
    fn quantisation_steps_are_one_lsb() {
        let s = AngleSensor::new(0.1, 1);
        for k in -50..50 {
            let a = (k as f64 * 0.0137f64).to_radians();
            let r = s.read_deg(a);
            assert!((r / 0.1 - (r / 0.1).round()).abs() < 1e-9);
            assert!((r - a.to_degrees()).abs() <= 0.1 + 1e-12);
        }
        let tr = s.sample_trace(0.0, 1000.0, &[0.0; 1000], 100.0);
        assert_eq!(tr.len(), 100);
        assert!((tr[1].0 - 0.01).abs() < 1e-12);
    }
}
