//! A synthetic reference-bus stream of one drive for the observer's tests and benches: the
//! samples the signal mapper would hand the observer, without a log or a DBC.

use shimmy::events::Sample;

/// `cruise_s` at `v0_kmh`, then (if `decel_g` > 0) a stop at `decel_g` and `hold_s` standing:
/// 100 Hz steering angle (0.1 deg steps, a 6.2 Hz shimmy) and 50 Hz speed on a 1 kHz time
/// base, the brake state on every sample as the mapper's snapshot carries it.
pub fn drive(t0_s: f64, cruise_s: f64, v0_kmh: f64, decel_g: f64, hold_s: f64) -> Vec<Sample> {
    let mut out = Vec::new();
    let mut v: f64 = v0_kmh / 3.6;
    let mut braking = false;
    let mut stopped_s = 0.0;
    let mut k = 0u64;
    loop {
        let t = k as f64 * 1e-3;
        if t >= cruise_s {
            if decel_g <= 0.0 {
                break;
            }
            braking = true;
        }
        if braking {
            v = (v - decel_g * 9.81 * 1e-3).max(0.0);
            if v == 0.0 {
                stopped_s += 1e-3;
                if stopped_s > hold_s {
                    break;
                }
            }
        }
        // Every sample carries the brake state, as the signal mapper's snapshot does.
        let mut s = Sample {
            t_ns: ((t0_s + t) * 1e9) as i64,
            brake: Some(braking && v > 0.0),
            ..Default::default()
        };
        if k.is_multiple_of(10) {
            let deg = 0.15 * (2.0 * std::f64::consts::PI * 6.2 * t).sin() + 0.03;
            s.steer_rad = Some(((deg / 0.1).round() * 0.1f64).to_radians());
        }
        if k % 20 == 5 {
            s.speed_mps = Some(v);
        }
        if s.steer_rad.is_some() || s.speed_mps.is_some() {
            out.push(s);
        }
        k += 1;
    }
    out
}
