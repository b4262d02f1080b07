//! Seeded excitation (MODEL.md §7): the wheel-unbalance phases and the Ornstein–Uhlenbeck road
//! noise steer moments, both from one deterministic ChaCha stream per seed.
//!
//! What it is: a source of random numbers that does not depend on the vehicle state, so twin
//! runs with the same seed see identical noise (§11 Lyapunov). What it is not: the moments
//! themselves (`rhs` scales the noise by v/v_n and adds the unbalance terms).

use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use rand_distr::StandardNormal;

/// Road-noise generator: two independent OU processes with stationary std `sigma` and time
/// constant `tau`, sampled exactly at the step boundaries and held over each step (§7).
#[derive(Debug, Clone)]
pub struct Excitation {
    rng: ChaCha8Rng,
    /// Unbalance phases φ_L, φ_R, uniform in [0, 2π).
    pub phases: [f64; 2],
    /// Current noise values n_L, n_R (N·m at v_n).
    pub noise: [f64; 2],
    sigma: f64,
    decay: f64,
    innov: f64,
    /// How many times [`Self::advance`] has been called (the position of `noise` on the
    /// hold grid).
    advances: u64,
}

impl Excitation {
    /// The unbalance phases φ_L, φ_R that `seed` draws: the first two draws of its stream,
    /// whatever the noise settings ([`Self::new`] starts the same way).
    pub fn phases_of(seed: u64) -> [f64; 2] {
        Self::draw_phases(&mut ChaCha8Rng::seed_from_u64(seed))
    }

    fn draw_phases(rng: &mut ChaCha8Rng) -> [f64; 2] {
        let tau_2pi = std::f64::consts::TAU;
        [rng.random::<f64>() * tau_2pi, rng.random::<f64>() * tau_2pi]
    }

    /// Draws the phases and the initial (stationary) noise from `seed`.
    pub fn new(seed: u64, sigma: f64, tau: f64, h: f64) -> Self {
        let mut rng = ChaCha8Rng::seed_from_u64(seed);
        let phases = Self::draw_phases(&mut rng);
        let decay = (-h / tau).exp();
        let mut ex = Self {
            rng,
            phases,
            noise: [0.0; 2],
            sigma,
            decay,
            innov: sigma * (1.0 - decay * decay).sqrt(),
            advances: 0,
        };
        let z0: f64 = ex.rng.sample(StandardNormal);
        let z1: f64 = ex.rng.sample(StandardNormal);
        ex.noise = [sigma * z0, sigma * z1];
        ex
    }

    /// Draws the noise's innovations from `seed`'s stream from now on: a new realisation of the
    /// road ahead. The current noise values, the step count and the unbalance phases stay, so
    /// the noise does not jump.
    pub fn reseed_noise(&mut self, seed: u64) {
        let mut rng = ChaCha8Rng::seed_from_u64(seed);
        rng.set_stream(7);
        self.rng = rng;
    }

    /// Sets the stationary standard deviation of the road noise from now on (N·m at v_n): the
    /// road's roughness changes. The current values stay and relax to the new level within a
    /// few τ; the stream of innovations is unchanged. A generator made with `sigma = 0` draws
    /// nothing and stays silent.
    pub fn set_sigma(&mut self, sigma: f64) {
        if self.sigma == 0.0 || !(sigma.is_finite() && sigma > 0.0) {
            return;
        }
        self.innov *= sigma / self.sigma;
        self.sigma = sigma;
    }

    /// The stationary standard deviation of the road noise (N·m at v_n).
    pub fn sigma(&self) -> f64 {
        self.sigma
    }

    /// Advances the OU processes by one step h (exact discretisation).
    #[inline]
    pub fn advance(&mut self) {
        self.advances += 1;
        if self.sigma == 0.0 {
            return;
        }
        for n in &mut self.noise {
            let z: f64 = self.rng.sample(StandardNormal);
            *n = self.decay * *n + self.innov * z;
        }
    }

    /// Number of [`Self::advance`] calls so far: `noise` is the value after that many steps.
    #[inline]
    pub fn advances(&self) -> u64 {
        self.advances
    }

    /// Advances until `count` steps have been taken (a catch-up after steps in which the
    /// noise was not needed): the same values as `count` calls of [`Self::advance`] in a row.
    pub fn advance_to(&mut self, count: u64) {
        while self.advances < count {
            self.advance();
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn noise_has_the_stationary_std_and_time_constant() {
        let (sigma, tau, h) = (0.2, 0.01, 1e-4);
        let mut ex = Excitation::new(7, sigma, tau, h);
        let n = 400_000;
        let (mut s2, mut lag) = (0.0, 0.0);
        let lag_steps = (tau / h) as usize; // correlation e^-1 at one τ
        let mut hist = std::collections::VecDeque::new();
        for _ in 0..n {
            ex.advance();
            let x = ex.noise[0];
            s2 += x * x;
            hist.push_back(x);
            if hist.len() > lag_steps {
                lag += x * hist.pop_front().unwrap();
            }
        }
        let var = s2 / n as f64;
        assert!(
            (var.sqrt() / sigma - 1.0).abs() < 0.05,
            "std {}",
            var.sqrt()
        );
        let rho = lag / (n - lag_steps) as f64 / var;
        assert!((rho - (-1f64).exp()).abs() < 0.06, "rho {rho}");
    }

    #[test]
    fn same_seed_same_stream_different_seed_differs() {
        let a = Excitation::new(3, 0.2, 0.01, 1e-4);
        let b = Excitation::new(3, 0.2, 0.01, 1e-4);
        let c = Excitation::new(4, 0.2, 0.01, 1e-4);
        assert_eq!(a.phases, b.phases);
        assert_eq!(a.noise, b.noise);
        assert_ne!(a.phases, c.phases);
        // The phases do not depend on the noise settings.
        assert_eq!(Excitation::phases_of(3), a.phases);
        assert_eq!(Excitation::new(3, 0.0, 1.0, 1e-3).phases, a.phases);
    }

    #[test]
    fn a_new_roughness_takes_over_within_a_few_tau() {
        let (sigma, tau, h) = (0.2, 0.01, 1e-4);
        let mut ex = Excitation::new(11, sigma, tau, h);
        for _ in 0..1000 {
            ex.advance();
        }
        ex.set_sigma(2.5 * sigma);
        assert_eq!(ex.sigma(), 2.5 * sigma);
        // Five τ to settle, then the stationary std is the new one.
        for _ in 0..500 {
            ex.advance();
        }
        let n = 200_000;
        let s2: f64 = (0..n)
            .map(|_| {
                ex.advance();
                ex.noise[1] * ex.noise[1]
            })
            .sum();
        let std = (s2 / n as f64).sqrt();
        assert!((std / (2.5 * sigma) - 1.0).abs() < 0.05, "std {std}");
        // A silent generator stays silent; a bad value changes nothing.
        let mut quiet = Excitation::new(11, 0.0, tau, h);
        quiet.set_sigma(0.3);
        quiet.advance();
        assert_eq!((quiet.sigma(), quiet.noise), (0.0, [0.0; 2]));
        ex.set_sigma(f64::NAN);
        assert_eq!(ex.sigma(), 2.5 * sigma);
    }
}
