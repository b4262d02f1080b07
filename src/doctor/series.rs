//! The mapped quantities of a log as `shimmy doctor` looks at them: per quantity its samples,
//! rate and range ([`SignalStats`]), and a stream of half-second bins ([`Bin`]: each quantity's
//! mean over the bin, the share of it with the brake applied, and the speed's derivative from
//! the neighbouring bins) that the consistency checks consume one at a time.
//!
//! Memory is constant whatever the log's length: three bins are kept, the statistics are sums.
//! What it is not: the checks themselves ([`super::checks`]).

use serde::Serialize;

/// Width of a bin (s): long enough to average sensor noise and the lag between steering and
/// yaw, short enough to follow a brake application.
pub const BIN_S: f64 = 0.5;

/// The quantities the doctor follows.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize)]
#[serde(rename_all = "snake_case")]
pub enum Quantity {
    SteerAngle,
    Speed,
    BrakePressure,
    BrakePressed,
    Accel,
    YawRate,
    LatAccel,
}

pub const QUANTITIES: [Quantity; 7] = [
    Quantity::SteerAngle,
    Quantity::Speed,
    Quantity::BrakePressure,
    Quantity::BrakePressed,
    Quantity::Accel,
    Quantity::YawRate,
    Quantity::LatAccel,
];

impl Quantity {
    /// The mapping's table for it.
    pub fn key(self) -> &'static str {
        match self {
            Quantity::SteerAngle => "steer_angle",
            Quantity::Speed => "speed",
            Quantity::BrakePressure => "brake_pressure",
            Quantity::BrakePressed => "brake_pressed",
            Quantity::Accel => "accel",
            Quantity::YawRate => "yaw_rate",
            Quantity::LatAccel => "lat_accel",
        }
    }

    /// The display unit and the factor from SI to it.
    pub fn display(self) -> (&'static str, f64) {
        match self {
            Quantity::SteerAngle => ("deg", 180.0 / std::f64::consts::PI),
            Quantity::Speed => ("km/h", 3.6),
            Quantity::BrakePressure => ("bar", 1e-5),
            Quantity::BrakePressed => ("", 1.0),
            Quantity::Accel | Quantity::LatAccel => ("m/s^2", 1.0),
            Quantity::YawRate => ("deg/s", 180.0 / std::f64::consts::PI),
        }
    }

    fn index(self) -> usize {
        QUANTITIES.iter().position(|q| *q == self).expect("listed")
    }
}

/// One quantity over the whole log (SI inside; see [`Quantity::display`] for the edges).
#[derive(Clone, Copy, Debug, Default)]
pub struct Stats {
    pub samples: u64,
    pub first_ns: Option<i64>,
    pub last_ns: Option<i64>,
    pub min: f64,
    pub max: f64,
    pub sum: f64,
}

impl Stats {
    fn add(&mut self, t_ns: i64, v: f64) {
        if self.samples == 0 {
            self.min = v;
            self.max = v;
        }
        self.samples += 1;
        self.min = self.min.min(v);
        self.max = self.max.max(v);
        self.sum += v;
        self.first_ns.get_or_insert(t_ns);
        self.last_ns = Some(t_ns);
    }

    /// Samples per second between the first and the last (None below two samples).
    pub fn rate_hz(&self) -> Option<f64> {
        let (a, b) = (self.first_ns?, self.last_ns?);
        (self.samples >= 2 && b > a).then(|| (self.samples - 1) as f64 / ((b - a) as f64 * 1e-9))
    }

    pub fn mean(&self) -> Option<f64> {
        (self.samples > 0).then(|| self.sum / self.samples as f64)
    }
}

/// A quantity's statistics as the report shows them (display units).
#[derive(Clone, Debug, Serialize)]
pub struct SignalStats {
    pub quantity: Quantity,
    /// "MESSAGE.SIGNAL" as the mapping names it.
    pub source: String,
    pub unit: &'static str,
    pub samples: u64,
    pub rate_hz: Option<f64>,
    pub min: Option<f64>,
    pub max: Option<f64>,
    pub mean: Option<f64>,
}

impl SignalStats {
    pub fn new(q: Quantity, source: String, s: &Stats) -> SignalStats {
        let (unit, k) = q.display();
        let has = s.samples > 0;
        SignalStats {
            quantity: q,
            source,
            unit,
            samples: s.samples,
            rate_hz: s.rate_hz(),
            min: has.then_some(s.min * k),
            max: has.then_some(s.max * k),
            mean: s.mean().map(|m| m * k),
        }
    }
}

/// One half-second of the log: each quantity's mean (SI) where it had samples.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct Bin {
    pub index: i64,
    pub steer_rad: Option<f64>,
    pub speed_mps: Option<f64>,
    pub accel_mps2: Option<f64>,
    pub yaw_radps: Option<f64>,
    pub lat_mps2: Option<f64>,
    /// Share of the brake-state updates with the brake applied.
    pub brake_share: Option<f64>,
    /// d(speed)/dt from the neighbouring bins (m/s²), when both have a speed.
    pub dv_mps2: Option<f64>,
}

#[derive(Clone, Copy, Debug, Default)]
struct Acc {
    sum: [f64; 7],
    n: [u32; 7],
    brake_on: u32,
    brake_n: u32,
}

impl Acc {
    fn mean(&self, q: Quantity) -> Option<f64> {
        let i = q.index();
        (self.n[i] > 0).then(|| self.sum[i] / self.n[i] as f64)
    }
}

/// Statistics and bins of the whole log, fed one update at a time.
#[derive(Debug, Default)]
pub struct Series {
    stats: [Stats; 7],
    cur: Option<(i64, Acc)>,
    /// The last two finished bins (older first).
    prev: [Option<Bin>; 2],
    last_ns: Option<i64>,
    /// Bins ready for the checks.
    ready: Vec<Bin>,
}

impl Series {
    /// A fresh value of `q` at `t_ns` (SI).
    pub fn value(&mut self, q: Quantity, t_ns: i64, v: f64) {
        if !v.is_finite() {
            return;
        }
        self.stats[q.index()].add(t_ns, v);
        let acc = self.bin_at(t_ns);
        acc.sum[q.index()] += v;
        acc.n[q.index()] += 1;
    }

    /// The brake state at `t_ns` (from flag and/or pressure, as the detector sees it).
    pub fn brake(&mut self, t_ns: i64, on: bool) {
        let acc = self.bin_at(t_ns);
        acc.brake_n += 1;
        acc.brake_on += on as u32;
    }

    /// The accumulator of the bin holding `t_ns`, finishing the bins before it.
    fn bin_at(&mut self, t_ns: i64) -> &mut Acc {
        if self.last_ns.is_some_and(|l| t_ns < l) {
            // Time went back (another log): bins do not span it.
            self.close();
            self.prev = [None, None];
        }
        self.last_ns = Some(t_ns);
        let idx = (t_ns as f64 * 1e-9 / BIN_S).floor() as i64;
        if self.cur.is_some_and(|(i, _)| i != idx) {
            self.close();
        }
        &mut self.cur.get_or_insert((idx, Acc::default())).1
    }

    /// Finishes the current bin; the bin before it gets its speed derivative and is ready.
    fn close(&mut self) {
        let Some((idx, acc)) = self.cur.take() else {
            return;
        };
        let bin = Bin {
            index: idx,
            steer_rad: acc.mean(Quantity::SteerAngle),
            speed_mps: acc.mean(Quantity::Speed),
            accel_mps2: acc.mean(Quantity::Accel),
            yaw_radps: acc.mean(Quantity::YawRate),
            lat_mps2: acc.mean(Quantity::LatAccel),
            brake_share: (acc.brake_n > 0).then(|| acc.brake_on as f64 / acc.brake_n as f64),
            dv_mps2: None,
        };
        // A gap (bins without any update) breaks the derivative.
        let consecutive = |a: &Option<Bin>, b: i64| a.is_some_and(|a| a.index + 1 == b);
        if let [Some(before), Some(mut mid)] = self.prev {
            if consecutive(&Some(before), mid.index) && consecutive(&Some(mid), idx) {
                if let (Some(a), Some(b)) = (before.speed_mps, bin.speed_mps) {
                    mid.dv_mps2 = Some((b - a) / (2.0 * BIN_S));
                }
            }
            self.ready.push(mid);
        } else if let [None, Some(mid)] = self.prev {
            self.ready.push(mid);
        }
        self.prev = [self.prev[1], Some(bin)];
    }

    /// Bins finished since the last call.
    pub fn take_ready(&mut self) -> std::vec::Drain<'_, Bin> {
        self.ready.drain(..)
    }

    /// End of input: the remaining bins are ready (the last without a derivative).
    pub fn finish(&mut self) {
        self.close();
        if let Some(last) = self.prev[1].take() {
            self.ready.push(last);
        }
        self.prev = [None, None];
    }

    pub fn stats(&self, q: Quantity) -> &Stats {
        &self.stats[q.index()]
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn bins_average_and_differentiate_the_speed() {
        let mut s = Series::default();
        let mut bins = Vec::new();
        // 4 s at 100 Hz: speed 10 + 2 t (m/s), steering 0.01 rad, brake on after 2 s.
        for k in 0..400 {
            let t = k as f64 * 0.01;
            let t_ns = (t * 1e9) as i64;
            s.value(Quantity::Speed, t_ns, 10.0 + 2.0 * t);
            s.value(Quantity::SteerAngle, t_ns, 0.01);
            s.brake(t_ns, t >= 2.0);
            bins.extend(s.take_ready());
        }
        s.finish();
        bins.extend(s.take_ready());
        assert_eq!(bins.len(), 8, "{bins:#?}");
        for b in &bins[1..7] {
            assert!((b.dv_mps2.unwrap() - 2.0).abs() < 1e-9, "{b:?}");
            assert!((b.steer_rad.unwrap() - 0.01).abs() < 1e-12);
        }
        assert_eq!(bins[0].dv_mps2, None);
        assert_eq!(bins[3].brake_share, Some(0.0));
        assert_eq!(bins[4].brake_share, Some(1.0));
        let st = s.stats(Quantity::Speed);
        assert_eq!(st.samples, 400);
        assert!((st.rate_hz().unwrap() - 100.0).abs() < 1e-6);
        assert!((st.max - 17.98).abs() < 1e-9);
    }
}
