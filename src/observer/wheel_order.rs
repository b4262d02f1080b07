//! A shake locked to the wheels' rotation while braking: the check for a brake-torque
//! variation (disc thickness variation, "brake judder").
//!
//! What it is: per braking event, the share of the band-passed steering signal's power (angle
//! or torsion-bar torque, over the part of the braking window where the wheel order lies well
//! inside the band) carried by one line at the wheels' rotation frequency, beyond the line the
//! same signal carried before the brake:
//!
//! `x = max(A_b² − A_c², 0) / (2 · rms_b²)`
//!
//! with `A_b` and `A_c` the order-tracked amplitudes over the braking and the pre-brake cruise
//! windows (the signal demodulated by the wheel angle θ(t) = ∫ k·v/R dt, `v` the vehicle speed,
//! `R` [`WheelOrderConfig::wheel_radius_m`], `k` searched over
//! [`WheelOrderConfig::order_search`] for the rolling radius, tyre slip and the speed signal's
//! scale that `R` does not know) and `rms_b` the RMS over the braking part. Per vehicle the
//! median of `x` over the newest events the estimate used ([`WheelOrderConfig::window_events`])
//! is compared with [`WheelOrderConfig::share_max`].
//!
//! Why it tells a disc variation: a brake force that varies at wheel order (MODEL.md §14)
//! turns, through the kingpin scrub radius, into a steering moment at wheel order, present
//! only while braking and whatever the joints' clearance; to the estimator's features (a quiet
//! cruise, a busy braking) it looks like wear. The wheels' unbalance (MODEL.md §7) is also at
//! wheel order but is there before the brake as well, so the cruise line `A_c` takes it out;
//! a rattle in worn joints spreads over the band. Neither is all of it: passing through the
//! steering's own resonance as the wheel order sweeps down, the unbalance's line can grow while
//! braking, a rattle partly locks to the wheel, and with a kingpin scrub radius the brake force
//! loads worn joints so that the unbalance passes through them while braking and not before.
//! On the simulated plants a vehicle without a disc variation has a median share up to 0.51
//! without a scrub radius (450 vehicles) and 0.68 with one of 5-15 mm (160), and the default
//! limit sits above both (docs/ACCURACY.md, "A brake-torque variation").
//!
//! What it is not: an estimate of the disc variation, a correction of the clearance estimate,
//! or a check that works without a vehicle speed (no speed samples: no share).

use serde::{Deserialize, Serialize};

/// Settings of the check (`[features.wheel_order]` in config/observer.toml).
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct WheelOrderConfig {
    /// Median share above which the model is said not to fit the vehicle; 0 turns the check
    /// off.
    pub share_max: f64,
    /// Fewest events with a share before the check says anything.
    pub min_events: usize,
    /// The median is over this many of the newest such events: discs machined or replaced
    /// show within that many brakings.
    pub window_events: usize,
    /// Rolling radius the speed is turned into a wheel angle with (m).
    pub wheel_radius_m: f64,
    /// Range of the order searched (multiples of v/R).
    pub order_search: [f64; 2],
}

impl Default for WheelOrderConfig {
    fn default() -> Self {
        WheelOrderConfig {
            share_max: 0.7,
            min_events: 8,
            window_events: 30,
            wheel_radius_m: 0.30,
            order_search: [0.8, 1.25],
        }
    }
}

impl WheelOrderConfig {
    pub fn validate(&self) -> anyhow::Result<()> {
        anyhow::ensure!(
            self.share_max.is_finite() && (0.0..=1.0).contains(&self.share_max),
            "features.wheel_order.share_max: must be in [0, 1] (got {})",
            self.share_max
        );
        anyhow::ensure!(
            self.wheel_radius_m.is_finite() && self.wheel_radius_m > 0.05,
            "features.wheel_order.wheel_radius_m: must be above 0.05 m (got {})",
            self.wheel_radius_m
        );
        anyhow::ensure!(
            (1..=super::MAX_WHEEL_ORDER_KEPT).contains(&self.window_events)
                && self.min_events <= self.window_events,
            "features.wheel_order.window_events: must be 1..={} and at least min_events ({}) \
             (got {})",
            super::MAX_WHEEL_ORDER_KEPT,
            self.min_events,
            self.window_events
        );
        let [lo, hi] = self.order_search;
        anyhow::ensure!(
            lo.is_finite() && hi.is_finite() && 0.0 < lo && lo <= hi && hi < 1.9,
            "features.wheel_order.order_search: must be [low, high] with 0 < low <= high < 1.9 \
             (the second order stays out; got [{lo}, {hi}])"
        );
        Ok(())
    }
}

/// Step of the order search (multiples of v/R): finer than the order resolution of a braking
/// window (1 / the wheel's revolutions in it, about 0.05-0.1).
const ORDER_STEP: f64 = 0.005;
/// The wheel order must sit this many times above the band's lower edge to count.
const LOW_EDGE_MARGIN: f64 = 1.5;
/// ... and this fraction of its upper edge below.
const HIGH_EDGE_MARGIN: f64 = 0.8;
/// Shortest braking part with the wheel order inside the band (s).
const MIN_BRAKING_S: f64 = 0.5;

/// Where one event's windows sit on its uniform grid.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Grid {
    /// Time of grid point 0 (ns) and the grid's period (ns).
    pub t0_ns: i64,
    pub period_ns: f64,
    /// Braking window `[i0, i1)` and pre-brake cruise window `[c0, c1)` on the grid.
    pub braking: (usize, usize),
    pub cruise: (usize, usize),
    /// The band (Hz) the signal was passed through.
    pub band_hz: (f64, f64),
}

/// The band-passed steering signal of one event on its uniform grid and where its windows are.
pub struct Windowed<'a> {
    /// Band-passed signal, one value per grid point.
    pub y: &'a [f64],
    pub grid: Grid,
}

/// The event's share `x` (module docs), or `None` when the speed does not cover the windows or
/// the wheel order is inside the band for less than [`MIN_BRAKING_S`] of the braking window.
/// Allocates nothing.
pub fn share(w: &Windowed<'_>, speed: &[(i64, f64)], cfg: &WheelOrderConfig) -> Option<f64> {
    if speed.len() < 2 || w.y.is_empty() {
        return None;
    }
    let r = cfg.wheel_radius_m;
    let two_pi_r = 2.0 * std::f64::consts::PI * r;
    let v_lo = LOW_EDGE_MARGIN * w.grid.band_hz.0 * two_pi_r / cfg.order_search[0];
    let v_hi = HIGH_EDGE_MARGIN * w.grid.band_hz.1 * two_pi_r / cfg.order_search[1];
    let dt = w.grid.period_ns * 1e-9;
    // Braking part: grid points whose speed puts the wheel order well inside the band.
    let (b0, b1) = (w.grid.braking.0, w.grid.braking.1.min(w.y.len()));
    let (c0, c1) = (w.grid.cruise.0, w.grid.cruise.1.min(w.y.len()));
    let (n_b, power) = inside_power(w, speed, (b0, b1), (v_lo, v_hi));
    if (n_b as f64) * dt < MIN_BRAKING_S {
        return None;
    }
    let a_b = order_amplitude(w, speed, (b0, b1), (v_lo, v_hi), cfg)?;
    let rms2 = power / n_b as f64;
    if rms2 <= 0.0 {
        return None;
    }
    // Before the brake the speed is steady; a cruise window the speed does not reach counts as
    // no cruise line (A_c = 0).
    let a_c = if c1 > c0 + 4 {
        order_amplitude(w, speed, (c0, c1), (v_lo, v_hi), cfg).unwrap_or(0.0)
    } else {
        0.0
    };
    Some(((a_b * a_b - a_c * a_c).max(0.0) / (2.0 * rms2)).min(1.0))
}

/// Linear interpolation in the speed samples, for increasing times (a forward cursor).
struct SpeedAt<'a> {
    s: &'a [(i64, f64)],
    k: usize,
}

impl<'a> SpeedAt<'a> {
    fn new(s: &'a [(i64, f64)]) -> Self {
        SpeedAt { s, k: 0 }
    }

    /// Speed at `t` (m/s); held at the ends within 0.5 s, `None` further out.
    fn at(&mut self, t: i64) -> Option<f64> {
        let s = self.s;
        let reach = 500_000_000;
        if t < s[0].0 {
            return (s[0].0 - t <= reach).then_some(s[0].1);
        }
        while self.k + 1 < s.len() && s[self.k + 1].0 <= t {
            self.k += 1;
        }
        if self.k + 1 >= s.len() {
            let last = s[s.len() - 1];
            return (t - last.0 <= reach).then_some(last.1);
        }
        let (a, b) = (s[self.k], s[self.k + 1]);
        let f = (t - a.0) as f64 / (b.0 - a.0).max(1) as f64;
        Some(a.1 + f * (b.1 - a.1))
    }
}

/// How many grid points of `[i0, i1)` have a speed in `(v_lo, v_hi)`, and their summed
/// squared signal.
fn inside_power(
    w: &Windowed<'_>,
    speed: &[(i64, f64)],
    (i0, i1): (usize, usize),
    (v_lo, v_hi): (f64, f64),
) -> (usize, f64) {
    let mut it = SpeedAt::new(speed);
    (i0..i1)
        .filter(|&i| {
            it.at(w.grid.t0_ns + (i as f64 * w.grid.period_ns) as i64)
                .is_some_and(|v| v > v_lo && v < v_hi)
        })
        .fold((0, 0.0), |(n, p), i| (n + 1, p + w.y[i] * w.y[i]))
}

/// Most orders the search can visit: `order_search` stays below 1.9 (validated).
const MAX_ORDERS: usize = (1.9 / ORDER_STEP) as usize + 2;

/// Largest order-tracked amplitude over the order search, on the grid points of `[i0, i1)`
/// whose speed lies in `(v_lo, v_hi)`; `None` when the speed does not reach them.
///
/// One pass over the grid: the wheel angle θ = ∫ v/R dt is integrated once and every searched
/// order k demodulates with e^{−ikθ}, stepped from order to order by a rotation.
fn order_amplitude(
    w: &Windowed<'_>,
    speed: &[(i64, f64)],
    (i0, i1): (usize, usize),
    (v_lo, v_hi): (f64, f64),
    cfg: &WheelOrderConfig,
) -> Option<f64> {
    let dt = w.grid.period_ns * 1e-9;
    let [lo, hi] = cfg.order_search;
    let orders = (((hi - lo) / ORDER_STEP).round() as usize + 1).min(MAX_ORDERS);
    let mut acc = [(0.0f64, 0.0f64); MAX_ORDERS];
    let mut it = SpeedAt::new(speed);
    let (mut n, mut theta) = (0usize, 0.0f64);
    for i in i0..i1 {
        let v = it.at(w.grid.t0_ns + (i as f64 * w.grid.period_ns) as i64)?;
        theta += v / cfg.wheel_radius_m * dt;
        if v > v_lo && v < v_hi {
            n += 1;
            let y = w.y[i];
            let (mut s, mut c) = (lo * theta).sin_cos();
            let (sd, cd) = (ORDER_STEP * theta).sin_cos();
            for a in &mut acc[..orders] {
                a.0 += y * c;
                a.1 -= y * s;
                (c, s) = (c * cd - s * sd, s * cd + c * sd);
            }
        }
    }
    (n > 0).then(|| {
        acc[..orders]
            .iter()
            .map(|(re, im)| 2.0 * (re * re + im * im).sqrt() / n as f64)
            .fold(0.0, f64::max)
    })
}

/// The per-vehicle verdict: the median of `shares` (the used events'), when at least
/// [`WheelOrderConfig::min_events`] of them are finite.
pub fn median_share(shares: impl IntoIterator<Item = f64>, cfg: &WheelOrderConfig) -> Option<f64> {
    let mut v: Vec<f64> = shares.into_iter().filter(|x| x.is_finite()).collect();
    if v.len() < cfg.min_events.max(1) {
        return None;
    }
    v.sort_by(f64::total_cmp);
    let m = v.len() / 2;
    Some(if v.len() % 2 == 1 {
        v[m]
    } else {
        0.5 * (v[m - 1] + v[m])
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A 50 Hz grid over 1.2 s of cruise at `v0` then a braking at `decel` down to 2 m/s, with
    /// `f(t, v, θ)` as the signal (θ the true wheel angle at radius 0.3 m).
    fn event(
        v0: f64,
        decel: f64,
        f: impl Fn(f64, f64, f64) -> f64,
    ) -> (Vec<f64>, Vec<(i64, f64)>, (usize, usize), (usize, usize)) {
        let fs = 50.0;
        let t_brake = 1.25;
        let mut y = Vec::new();
        let mut speed = Vec::new();
        let (mut t, mut theta) = (0.0f64, 0.0f64);
        let mut i_brake = None;
        loop {
            let v = if t < t_brake {
                v0
            } else {
                v0 - decel * (t - t_brake)
            };
            if v < 2.0 {
                break;
            }
            if t >= t_brake && i_brake.is_none() {
                i_brake = Some(y.len());
            }
            y.push(f(t, v, theta));
            speed.push(((t * 1e9) as i64, v));
            theta += v / 0.3 / fs;
            t += 1.0 / fs;
        }
        let ib = i_brake.unwrap();
        let n = y.len();
        (y, speed, (ib, n), (ib - 60, ib - 3))
    }

    fn share_of(
        y: &[f64],
        speed: &[(i64, f64)],
        b: (usize, usize),
        c: (usize, usize),
    ) -> Option<f64> {
        let w = Windowed {
            y,
            grid: Grid {
                t0_ns: 0,
                period_ns: 2e7,
                braking: b,
                cruise: c,
                band_hz: (3.0, 20.0),
            },
        };
        share(&w, speed, &WheelOrderConfig::default())
    }

    #[test]
    fn a_line_that_appears_with_the_brake_is_told_from_one_already_there() {
        // A disc variation: a wheel-order line only while braking, on top of broadband noise.
        let mut rng = 12345u64;
        let mut noise = move || {
            rng = rng
                .wrapping_mul(6364136223846793005)
                .wrapping_add(1442695040888963407);
            ((rng >> 11) as f64 / (1u64 << 53) as f64 - 0.5) * 0.2
        };
        let noise_a: Vec<f64> = (0..2000).map(|_| noise()).collect();
        let judder = |t: f64, _v: f64, th: f64| {
            if t >= 1.25 {
                0.1 * (1.04 * th).cos()
            } else {
                0.0
            }
        };
        let (y, sp, b, c) = event(16.0, 5.0, |t, v, th| {
            judder(t, v, th) + noise_a[(t * 50.0).round() as usize]
        });
        let x = share_of(&y, &sp, b, c).unwrap();
        assert!(x > 0.5, "a line only while braking: share {x}");
        // An unbalance: the same line before and during the brake, falling with v².
        let (y, sp, b, c) = event(16.0, 5.0, |t, v, th| {
            0.1 * (v / 16.0).powi(2) * (1.04 * th).cos() + noise_a[(t * 50.0).round() as usize]
        });
        let x = share_of(&y, &sp, b, c).unwrap();
        assert!(
            x < 0.2,
            "an unbalance already there before the brake: share {x}"
        );
        // Broadband only (a rattle): a small share.
        let (y, sp, b, c) = event(16.0, 5.0, |t, _, _| {
            3.0 * noise_a[(t * 50.0).round() as usize]
        });
        let x = share_of(&y, &sp, b, c).unwrap();
        assert!(x < 0.15, "broadband: share {x}");
    }

    #[test]
    fn no_speed_or_too_slow_an_event_gives_no_share() {
        let (y, _, b, c) = event(16.0, 5.0, |_, _, th| th.cos());
        assert_eq!(share_of(&y, &[], b, c), None);
        // 20 km/h: the wheel order (2.9 Hz) is below the band.
        let (y, sp, b, c) = event(5.6, 1.0, |_, _, th| th.cos());
        assert_eq!(share_of(&y, &sp, b, c), None);
    }

    #[test]
    fn the_vehicle_median_waits_for_enough_events() {
        let cfg = WheelOrderConfig::default();
        assert_eq!(median_share([0.9; 7], &cfg), None);
        let v = [0.1, 0.2, 0.3, 0.5, 0.6, 0.7, 0.8, 0.9];
        assert!((median_share(v, &cfg).unwrap() - 0.55).abs() < 1e-12);
    }

    #[test]
    fn bad_settings_are_refused() {
        let mut c = WheelOrderConfig::default();
        c.order_search = [1.2, 1.0];
        assert!(c.validate().is_err());
        c = WheelOrderConfig::default();
        c.wheel_radius_m = 0.0;
        assert!(c.validate().is_err());
        assert!(WheelOrderConfig::default().validate().is_ok());
    }
}
