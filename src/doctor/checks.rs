//! `shimmy doctor`'s consistency checks between mapped signals, each a regression over the
//! log's half-second bins ([`super::series::Bin`]) judged for sign and scale, and the fix it
//! implies for the mapping:
//!
//! * **acceleration against d(speed)/dt**: the slope of `accel` on the speed's derivative
//!   should be positive and near 1 (an accelerometer also reads the road's grade, hence the
//!   tolerance);
//! * **steering against turning**: the kinematic yaw rate v·δ_sw/(i_s·L) (i_s the steering
//!   ratio and L the wheelbase of the profile's chassis, MODEL.md §9) against the measured yaw
//!   rate, and v²·δ_sw/(i_s·L) against the lateral acceleration; the lateral acceleration
//!   against v·yaw rate. Slopes below the kinematic 1 are expected (a car understeers at
//!   speed): a scale is called wrong only beyond a factor of √10 around a nominal 0.7
//!   ([`NOMINAL_STEER_GAIN`]) — a 10× error is far outside, a steering ratio between 12 and 20
//!   and any realistic understeer inside. With two
//!   relations disagreeing and the third agreeing, the signal the two share is the culprit;
//!   with only one relation, the steering angle is named first (the monitor's own signal);
//! * **brake against deceleration**: the car slows more while the brake reads applied.
//!
//! A relation is judged only when it is meaningful: at least [`MIN_BINS`] bins of driving,
//! enough variation (turning, speed changes, braking) and a correlation of at least
//! [`MIN_R`]; otherwise the check says "not enough data" rather than pass or fail.
//!
//! What it is not: the decoding (the mapper's) or the report (see [`super`]).

use serde::Serialize;
use serde_json::json;

use super::series::Bin;
use crate::signals::mapping::{AccelUnit, AngleUnit, MappingConfig, RateUnit};

/// Bins (of 0.5 s) of driving a relation needs at least.
pub const MIN_BINS: u64 = 20;
/// Smallest |correlation| for a relation to say anything.
pub const MIN_R: f64 = 0.5;
/// Speeds below this are not used for the turning relations (m/s).
pub const MIN_TURN_SPEED_MPS: f64 = 5.0;
/// Speeds below this are not used for the acceleration and brake relations (m/s).
pub const MIN_SPEED_MPS: f64 = 2.0;
/// Steering angles beyond this are left out of the (linear) turning relations (rad).
pub const MAX_STEER_RAD: f64 = std::f64::consts::FRAC_PI_2;
/// A slope within this factor of the expected one is the right scale.
pub const SCALE_FACTOR: f64 = 3.162_277_660_168_379_5;
/// The slopes expected of a right mapping: the turning relations from the steering angle read
/// below the kinematic 1 because a car understeers at speed (0.57 on the real RAV4 at
/// 30-73 km/h); an accelerometer reads a little less than d(speed)/dt on average (0.8 on the
/// RAV4). Scales are judged relative to these.
pub const NOMINAL_STEER_GAIN: f64 = 0.7;
pub const NOMINAL_ACCEL_GAIN: f64 = 0.9;
/// Variation needed to judge each relation (standard deviation over the bins used).
pub const MIN_STD_DV_MPS2: f64 = 0.2;
pub const MIN_STD_YAW_RADPS: f64 = 0.1 * std::f64::consts::PI / 180.0;
pub const MIN_STD_LAT_MPS2: f64 = 0.05;
/// Above this variation a relation that does not hold (|r| < [`MIN_R`]) fails rather than
/// being inconclusive.
pub const CLEAR_STD_DV_MPS2: f64 = 0.5;
pub const CLEAR_STD_YAW_RADPS: f64 = 1.0 * std::f64::consts::PI / 180.0;
pub const CLEAR_STD_LAT_MPS2: f64 = 0.5;
/// Braking needed to judge the brake signal: bins with the brake applied / released.
pub const MIN_BRAKE_BINS: u64 = 2;
pub const MIN_RELEASED_BINS: u64 = 10;
/// The car must slow at least this much more with the brake applied (m/s²).
pub const MIN_BRAKE_EFFECT_MPS2: f64 = 0.3;
/// A deceleration this strong with the brake released is worth a remark (m/s²).
pub const HARD_DECEL_MPS2: f64 = 0.25 * 9.806_65;

/// Outcome of one check.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize)]
#[serde(rename_all = "snake_case")]
pub enum Status {
    Pass,
    /// Something is off, but not provably the mapping (or not provably anything).
    Warn,
    Fail,
    /// The log does not have what the check needs (turning, braking, variation).
    NotEnoughData,
    /// The mapping has nothing to check against.
    NotChecked,
}

/// One check's result.
#[derive(Clone, Debug, Serialize)]
pub struct Check {
    pub name: String,
    pub status: Status,
    pub summary: String,
    /// What to change in the mapping, when the check failed and the fix is known.
    pub fix: Option<String>,
    pub evidence: serde_json::Value,
}

impl Check {
    pub fn new(name: &str, status: Status, summary: String) -> Check {
        Check {
            name: name.into(),
            status,
            summary,
            fix: None,
            evidence: serde_json::Value::Null,
        }
    }
}

/// Sums for a least-squares line y = a + b·x.
#[derive(Clone, Copy, Debug, Default)]
pub struct Reg {
    pub n: u64,
    sx: f64,
    sy: f64,
    sxx: f64,
    syy: f64,
    sxy: f64,
}

impl Reg {
    pub fn add(&mut self, x: f64, y: f64) {
        if !(x.is_finite() && y.is_finite()) {
            return;
        }
        self.n += 1;
        self.sx += x;
        self.sy += y;
        self.sxx += x * x;
        self.syy += y * y;
        self.sxy += x * y;
    }

    fn cov(&self) -> (f64, f64, f64) {
        let n = self.n as f64;
        if n < 2.0 {
            return (0.0, 0.0, 0.0);
        }
        let vx = (self.sxx - self.sx * self.sx / n) / n;
        let vy = (self.syy - self.sy * self.sy / n) / n;
        let cxy = (self.sxy - self.sx * self.sy / n) / n;
        (vx.max(0.0), vy.max(0.0), cxy)
    }

    /// Slope of y on x.
    pub fn slope(&self) -> f64 {
        let (vx, _, c) = self.cov();
        if vx > 0.0 {
            c / vx
        } else {
            0.0
        }
    }

    /// Correlation coefficient.
    pub fn r(&self) -> f64 {
        let (vx, vy, c) = self.cov();
        if vx > 0.0 && vy > 0.0 {
            c / (vx * vy).sqrt()
        } else {
            0.0
        }
    }

    pub fn std_x(&self) -> f64 {
        self.cov().0.sqrt()
    }

    pub fn std_y(&self) -> f64 {
        self.cov().1.sqrt()
    }

    fn evidence(&self) -> serde_json::Value {
        json!({
            "bins": self.n,
            "seconds": self.n as f64 * super::series::BIN_S,
            "slope": self.slope(),
            "r": self.r(),
            "std_x": self.std_x(),
            "std_y": self.std_y(),
        })
    }
}

/// The factor a measured ratio most likely stands for: 1 within √10 of it, else the nearest
/// power of ten, or 57.3 / 1/57.3 (degrees against radians), in log space.
pub fn snap_factor(k: f64) -> f64 {
    let l = k.abs().log10();
    if !l.is_finite() || l.abs() <= SCALE_FACTOR.log10() {
        return 1.0;
    }
    let deg = (180.0 / std::f64::consts::PI).log10();
    let mut best = (f64::INFINITY, 1.0);
    for c in (-6..=6)
        .map(|p| p as f64)
        .chain([deg, -deg])
        .filter(|c| *c != 0.0)
    {
        let d = (l - c).abs();
        if d < best.0 {
            best = (d, 10f64.powf(c));
        }
    }
    best.1
}

/// A number for a TOML value: up to 6 significant digits, no trailing zeros.
pub fn fmt_num(x: f64) -> String {
    if x == 0.0 || !x.is_finite() {
        return format!("{x}");
    }
    let digits = (5 - x.abs().log10().floor() as i32).max(0) as usize;
    let s = format!("{x:.digits$}");
    if s.contains('.') {
        s.trim_end_matches('0').trim_end_matches('.').to_string()
    } else {
        s
    }
}

fn near(a: f64, b: f64) -> bool {
    (a.ln() - b.ln()).abs() < 0.05
}

const DEG: f64 = 180.0 / std::f64::consts::PI;

/// Which signal a turning relation involves.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
enum Sig {
    Steer,
    Yaw,
    Lat,
}

impl Sig {
    fn key(self) -> &'static str {
        match self {
            Sig::Steer => "steer_angle",
            Sig::Yaw => "yaw_rate",
            Sig::Lat => "lat_accel",
        }
    }
}

/// One turning relation: y (a measured signal) against x (predicted from another).
#[derive(Clone, Copy, Debug)]
struct Pair {
    /// The signal x is predicted from, and the signal y is.
    from: Sig,
    to: Sig,
    reg: Reg,
    /// Variation needed, and variation beyond which a missing relation fails (in y's and x's
    /// units).
    min_std: f64,
    clear_std: f64,
    /// The slope a right mapping gives.
    nominal: f64,
}

/// What a pair says, when it says anything.
#[derive(Clone, Copy, Debug, PartialEq)]
enum Said {
    /// Not enough driving or variation.
    Little,
    /// Enough variation but the two do not follow each other.
    Unrelated { clear: bool },
    /// The relation holds with this sign and snapped scale factor (y / prediction).
    Holds { negative: bool, factor: f64 },
}

impl Pair {
    fn said(&self) -> Said {
        let var = self.reg.std_x().max(self.reg.std_y());
        if self.reg.n < MIN_BINS || var < self.min_std {
            return Said::Little;
        }
        let r = self.reg.r();
        if r.abs() < MIN_R {
            return Said::Unrelated {
                clear: var >= self.clear_std,
            };
        }
        Said::Holds {
            negative: self.reg.slope() < 0.0,
            factor: snap_factor(self.reg.slope() / self.nominal),
        }
    }

    fn name(&self) -> String {
        match (self.from, self.to) {
            (Sig::Steer, Sig::Yaw) => "yaw rate against v*steer/(i_s*L)".into(),
            (Sig::Steer, Sig::Lat) => "lateral accel against v^2*steer/(i_s*L)".into(),
            _ => "lateral accel against v*yaw rate".into(),
        }
    }
}

/// The brake's effect.
#[derive(Clone, Copy, Debug, Default)]
struct BrakeAcc {
    on_bins: u64,
    on_decel: f64,
    off_bins: u64,
    off_decel: f64,
    hard_off_bins: u64,
}

/// Consumes bins, then judges.
pub struct Checker {
    mapping: MappingConfig,
    /// Steering ratio i_s and wheelbase L of the chassis.
    steer_ratio: f64,
    wheelbase_m: f64,
    accel: Reg,
    pairs: [Pair; 3],
    brake: BrakeAcc,
    brake_from_flag: bool,
}

impl Checker {
    pub fn new(mapping: &MappingConfig, steer_ratio: f64, wheelbase_m: f64) -> Checker {
        let pair = |from, to, min_std, clear_std| Pair {
            from,
            to,
            reg: Reg::default(),
            min_std,
            clear_std,
            nominal: if from == Sig::Steer {
                NOMINAL_STEER_GAIN
            } else {
                1.0
            },
        };
        Checker {
            mapping: mapping.clone(),
            steer_ratio,
            wheelbase_m,
            accel: Reg::default(),
            pairs: [
                pair(Sig::Steer, Sig::Yaw, MIN_STD_YAW_RADPS, CLEAR_STD_YAW_RADPS),
                pair(Sig::Steer, Sig::Lat, MIN_STD_LAT_MPS2, CLEAR_STD_LAT_MPS2),
                pair(Sig::Yaw, Sig::Lat, MIN_STD_LAT_MPS2, CLEAR_STD_LAT_MPS2),
            ],
            brake: BrakeAcc::default(),
            brake_from_flag: mapping.brake_pressed.is_some(),
        }
    }

    /// Takes one finished bin.
    pub fn bin(&mut self, b: &Bin) {
        let Some(v) = b.speed_mps else {
            return;
        };
        if v >= MIN_SPEED_MPS {
            if let (Some(dv), Some(a)) = (b.dv_mps2, b.accel_mps2) {
                self.accel.add(dv, a);
            }
            if let (Some(dv), Some(share)) = (b.dv_mps2, b.brake_share) {
                let br = &mut self.brake;
                if share >= 0.5 {
                    br.on_bins += 1;
                    br.on_decel += -dv;
                } else {
                    br.off_bins += 1;
                    br.off_decel += -dv;
                    br.hard_off_bins += (-dv >= HARD_DECEL_MPS2) as u64;
                }
            }
        }
        if v >= MIN_TURN_SPEED_MPS {
            let k = self.steer_ratio * self.wheelbase_m;
            let steer = b.steer_rad.filter(|s| s.abs() <= MAX_STEER_RAD);
            if let (Some(d), Some(r)) = (steer, b.yaw_radps) {
                self.pairs[0].reg.add(v * d / k, r);
            }
            if let (Some(d), Some(a)) = (steer, b.lat_mps2) {
                self.pairs[1].reg.add(v * v * d / k, a);
            }
            if let (Some(r), Some(a)) = (b.yaw_radps, b.lat_mps2) {
                self.pairs[2].reg.add(v * r, a);
            }
        }
    }

    /// Every consistency check.
    pub fn finish(&self) -> Vec<Check> {
        let mut out = vec![self.accel_check()];
        out.extend(self.turning_checks());
        out.push(self.brake_check());
        out
    }

    fn accel_check(&self) -> Check {
        let name = "accel against d(speed)/dt";
        let Some(map) = &self.mapping.accel else {
            return Check::new(
                name,
                Status::NotChecked,
                "no [accel] in the mapping (the detector differentiates the speed)".into(),
            );
        };
        let reg = &self.accel;
        let mut c = Check::new(name, Status::Pass, String::new());
        c.evidence = reg.evidence();
        let std_dv = reg.std_x();
        if reg.n < MIN_BINS || std_dv < MIN_STD_DV_MPS2 {
            c.status = Status::NotEnoughData;
            c.summary = format!(
                "not enough data to check [accel]: {:.0} s of driving with d(speed)/dt \
                 varying by {std_dv:.2} m/s^2 (std); needs {} s and {MIN_STD_DV_MPS2}",
                reg.n as f64 * super::series::BIN_S,
                MIN_BINS as f64 * super::series::BIN_S
            );
            return c;
        }
        let (k, r) = (reg.slope(), reg.r());
        if r.abs() < MIN_R {
            c.status = if std_dv >= CLEAR_STD_DV_MPS2 {
                Status::Fail
            } else {
                Status::Warn
            };
            c.summary = format!(
                "the acceleration does not follow d(speed)/dt (r = {r:.2} over {:.0} s)",
                reg.n as f64 * super::series::BIN_S
            );
            if c.status == Status::Fail {
                c.fix = Some(format!(
                    "check [accel]: `{}.{}` does not behave like the longitudinal acceleration",
                    map.message, map.signal
                ));
            }
            return c;
        }
        let f = snap_factor(k / NOMINAL_ACCEL_GAIN);
        let mut fixes = Vec::new();
        if k < 0.0 {
            fixes.push(format!("set `invert = {}` under [accel]", !map.invert));
        }
        if f != 1.0 {
            fixes.push(accel_scale_fix("accel", map.unit, map.scale, f));
        }
        c.summary = format!(
            "acceleration = {k:.2} x d(speed)/dt (r = {r:.2} over {:.0} s){}",
            reg.n as f64 * super::series::BIN_S,
            match (k < 0.0, f != 1.0) {
                (false, false) => String::new(),
                (true, false) => ": it reads positive while the car slows".into(),
                (false, true) => format!(": it reads about {} times too large", fmt_num(f)),
                (true, true) => format!(": inverted, and about {} times too large", fmt_num(f)),
            }
        );
        if !fixes.is_empty() {
            c.status = Status::Fail;
            c.fix = Some(fixes.join(" and "));
        }
        c
    }

    /// The steering, yaw rate and lateral acceleration checks from the three relations.
    fn turning_checks(&self) -> Vec<Check> {
        let mapped = |s: Sig| match s {
            Sig::Steer => true,
            Sig::Yaw => self.mapping.yaw_rate.is_some(),
            Sig::Lat => self.mapping.lat_accel.is_some(),
        };
        let said: Vec<(Pair, Said)> = self
            .pairs
            .iter()
            .filter(|p| mapped(p.from) && mapped(p.to))
            .map(|p| (*p, p.said()))
            .collect();
        let (sign_culprits, scale_culprit) = culprits(&said);
        let mut out = Vec::new();
        for sig in [Sig::Steer, Sig::Yaw, Sig::Lat] {
            if !mapped(sig) {
                continue;
            }
            let name = format!("{} against turning", sig.key());
            let mine: Vec<&(Pair, Said)> = said
                .iter()
                .filter(|(p, _)| p.from == sig || p.to == sig)
                .collect();
            let mut c = Check::new(&name, Status::Pass, String::new());
            c.evidence = json!(mine
                .iter()
                .map(|(p, s)| json!({
                    "relation": p.name(),
                    "fit": p.reg.evidence(),
                    "judged": !matches!(s, Said::Little),
                }))
                .collect::<Vec<_>>());
            if mine.is_empty() {
                c.status = Status::NotChecked;
                c.summary = "not checked: the mapping has no [yaw_rate] or [lat_accel] to \
                             compare the steering angle with"
                    .into();
                out.push(c);
                continue;
            }
            let holds: Vec<&&(Pair, Said)> = mine
                .iter()
                .filter(|(_, s)| matches!(s, Said::Holds { .. }))
                .collect();
            if holds.is_empty() {
                let clear = mine
                    .iter()
                    .any(|(_, s)| matches!(s, Said::Unrelated { clear: true }));
                let unrelated = mine
                    .iter()
                    .any(|(_, s)| matches!(s, Said::Unrelated { .. }));
                let (p, _) = mine[0];
                c.status = if clear {
                    Status::Fail
                } else if unrelated {
                    Status::Warn
                } else {
                    Status::NotEnoughData
                };
                c.summary = if unrelated {
                    format!(
                        "{}: the two do not follow each other (r = {:.2} over {:.0} s){}",
                        p.name(),
                        p.reg.r(),
                        p.reg.n as f64 * super::series::BIN_S,
                        if clear {
                            " although the car turned clearly"
                        } else {
                            ": too little turning to tell"
                        }
                    )
                } else {
                    format!(
                        "not enough turning to check {}: {:.0} s above {} km/h, variation \
                         {} (std); needs {} s and {}",
                        sig.key(),
                        p.reg.n as f64 * super::series::BIN_S,
                        MIN_TURN_SPEED_MPS * 3.6,
                        show_std(p),
                        MIN_BINS as f64 * super::series::BIN_S,
                        show_min(p)
                    )
                };
                if clear {
                    c.fix = Some(format!(
                        "check that [{}] maps the right signal",
                        if sig == Sig::Steer {
                            "steer_angle"
                        } else {
                            sig.key()
                        }
                    ));
                }
                out.push(c);
                continue;
            }
            let desc: Vec<String> = holds
                .iter()
                .map(|(p, _)| {
                    format!(
                        "{} = {:.2} (r = {:.2}, {:.0} s)",
                        p.name(),
                        p.reg.slope(),
                        p.reg.r(),
                        p.reg.n as f64 * super::series::BIN_S
                    )
                })
                .collect();
            let mut fixes = Vec::new();
            let mut what = Vec::new();
            let mut doubt = None;
            let negative = holds
                .iter()
                .any(|(_, s)| matches!(s, Said::Holds { negative: true, .. }));
            let off_scale = holds
                .iter()
                .any(|(_, s)| matches!(s, Said::Holds { factor, .. } if *factor != 1.0));
            if negative && sign_culprits.is_empty() {
                doubt = Some("the relations' signs contradict each other".to_string());
            } else if sign_culprits.iter().skip(1).any(|s| *s == sig) {
                doubt = Some(format!(
                    "its sign disagrees with [{}]'s; one of the two is inverted",
                    sign_culprits[0].key()
                ));
            }
            if off_scale && scale_culprit.is_none() {
                doubt = Some("the relations' scales contradict each other".to_string());
            }
            if sign_culprits.first() == Some(&sig) {
                what.push("its sign is inverted".to_string());
                let mut fx = format!(
                    "set `invert = {}` under [{}]",
                    !self.invert_of(sig),
                    sig.key()
                );
                if sign_culprits.len() > 1 {
                    let others: Vec<String> = sign_culprits[1..]
                        .iter()
                        .map(|s| format!("[{}]", s.key()))
                        .collect();
                    fx += &format!(
                        " (or under {}, if [{}] is known to be right: a left turn must read \
                         positive on both)",
                        others.join(" or "),
                        sig.key()
                    );
                }
                fixes.push(fx);
            }
            if let Some((s, f)) = scale_culprit {
                if s == sig {
                    what.push(format!("it reads about {} times too large", fmt_num(f)));
                    fixes.push(self.scale_fix(sig, f));
                }
            }
            c.summary = format!(
                "{}{}",
                desc.join("; "),
                if what.is_empty() {
                    String::new()
                } else {
                    format!(": {}", what.join(", and "))
                }
            );
            if !fixes.is_empty() {
                c.status = Status::Fail;
                c.fix = Some(fixes.join(" and "));
            } else if let Some(d) = doubt {
                c.status = Status::Warn;
                c.summary += &format!(": {d}");
            } else {
                let blamed: Vec<String> = sign_culprits
                    .first()
                    .filter(|_| negative)
                    .into_iter()
                    .chain(scale_culprit.as_ref().map(|s| &s.0).filter(|_| off_scale))
                    .map(|s| format!("[{}]", s.key()))
                    .collect();
                if !blamed.is_empty() {
                    c.summary += &format!(
                        ": consistent with the other signals; what disagrees is {}",
                        blamed.join(" and ")
                    );
                }
            }
            out.push(c);
        }
        out
    }

    fn invert_of(&self, s: Sig) -> bool {
        let m = &self.mapping;
        match s {
            Sig::Steer => m.steer_angle.invert,
            Sig::Yaw => m.yaw_rate.as_ref().is_some_and(|y| y.invert),
            Sig::Lat => m.lat_accel.as_ref().is_some_and(|y| y.invert),
        }
    }

    /// The fix for signal `s` reading `f` times too large.
    fn scale_fix(&self, s: Sig, f: f64) -> String {
        let m = &self.mapping;
        match s {
            Sig::Steer => {
                let st = &m.steer_angle;
                match st.unit {
                    AngleUnit::Rad if near(f, DEG) => {
                        "set `unit = \"deg\"` under [steer_angle]".into()
                    }
                    AngleUnit::Deg if near(f, 1.0 / DEG) => {
                        "set `unit = \"rad\"` under [steer_angle]".into()
                    }
                    _ => scale_text("steer_angle", st.scale / f),
                }
            }
            Sig::Yaw => {
                let y = m.yaw_rate.as_ref().expect("mapped");
                match y.unit {
                    RateUnit::RadPerS if near(f, DEG) => {
                        "set `unit = \"deg/s\"` under [yaw_rate]".into()
                    }
                    RateUnit::DegPerS if near(f, 1.0 / DEG) => {
                        "set `unit = \"rad/s\"` under [yaw_rate]".into()
                    }
                    _ => scale_text("yaw_rate", y.scale / f),
                }
            }
            Sig::Lat => {
                let a = m.lat_accel.as_ref().expect("mapped");
                accel_scale_fix("lat_accel", a.unit, a.scale, f)
            }
        }
    }

    fn brake_check(&self) -> Check {
        let name = "brake against deceleration";
        let b = &self.brake;
        let key = if self.brake_from_flag {
            "brake_pressed"
        } else {
            "brake_pressure"
        };
        let mut c = Check::new(name, Status::Pass, String::new());
        let on = (b.on_bins > 0).then(|| b.on_decel / b.on_bins as f64);
        let off = (b.off_bins > 0).then(|| b.off_decel / b.off_bins as f64);
        let secs = |n: u64| n as f64 * super::series::BIN_S;
        let share_on = b.on_bins as f64 / (b.on_bins + b.off_bins).max(1) as f64;
        c.evidence = json!({
            "applied_s": secs(b.on_bins),
            "released_s": secs(b.off_bins),
            "mean_decel_applied_mps2": on,
            "mean_decel_released_mps2": off,
            "hard_decel_released_s": secs(b.hard_off_bins),
        });
        if b.on_bins + b.off_bins >= MIN_RELEASED_BINS && share_on > 0.7 {
            c.status = Status::Fail;
            c.summary = format!(
                "the brake reads applied for {:.0} % of the time the car moves",
                100.0 * share_on
            );
            c.fix = Some(if self.brake_from_flag {
                format!(
                    "set `invert = {}` under [brake_pressed]",
                    !self
                        .mapping
                        .brake_pressed
                        .as_ref()
                        .is_some_and(|f| f.invert)
                )
            } else {
                "check [brake_pressure]'s unit (bar, kPa, Pa) against the DBC".into()
            });
            return c;
        }
        if b.on_bins < MIN_BRAKE_BINS || b.off_bins < MIN_RELEASED_BINS {
            c.status = Status::NotEnoughData;
            c.summary = format!(
                "not enough braking to check [{key}]: the brake read applied for {:.1} s while \
                 moving (needs {} s)",
                secs(b.on_bins),
                secs(MIN_BRAKE_BINS)
            );
            if b.hard_off_bins >= 4 {
                c.status = Status::Warn;
                c.summary += &format!(
                    "; but the car slowed at 0.25 g or more for {:.1} s with the brake read \
                     released (automatic braking, or a brake signal that never reads applied)",
                    secs(b.hard_off_bins)
                );
            }
            return c;
        }
        let (on, off) = (on.unwrap_or(0.0), off.unwrap_or(0.0));
        c.summary = format!(
            "the car slows at {on:.2} m/s^2 on average with the brake applied ({:.1} s) and \
             {off:.2} m/s^2 with it released",
            secs(b.on_bins)
        );
        if on - off < MIN_BRAKE_EFFECT_MPS2 {
            c.status = Status::Fail;
            c.summary += ": the brake signal does not go with slowing down";
            c.fix = Some(format!(
                "check [{key}]: it should read applied when the car brakes{}",
                if self.brake_from_flag {
                    format!(
                        " (if it reads the opposite, set `invert = {}` under [brake_pressed])",
                        !self
                            .mapping
                            .brake_pressed
                            .as_ref()
                            .is_some_and(|f| f.invert)
                    )
                } else {
                    String::new()
                }
            ));
        }
        c
    }
}

fn show_std(p: &Pair) -> String {
    let s = p.reg.std_x().max(p.reg.std_y());
    if p.to == Sig::Yaw {
        format!("{:.3} deg/s", s * DEG)
    } else {
        format!("{s:.3} m/s^2")
    }
}

fn show_min(p: &Pair) -> String {
    if p.to == Sig::Yaw {
        format!("{} deg/s", p.min_std * DEG)
    } else {
        format!("{} m/s^2", p.min_std)
    }
}

fn scale_text(key: &str, new_scale: f64) -> String {
    if near(new_scale, 1.0) {
        format!("remove `scale` under [{key}] (or set `scale = 1`)")
    } else {
        format!("set `scale = {}` under [{key}]", fmt_num(new_scale))
    }
}

/// The fix for an acceleration reading `f` times too large.
fn accel_scale_fix(key: &str, unit: AccelUnit, scale: f64, f: f64) -> String {
    match unit {
        AccelUnit::G if near(f, 10.0) => format!(
            "set `unit = \"m/s^2\"` under [{key}] (or {})",
            scale_text(key, scale / f)
        ),
        AccelUnit::Mps2 if near(f, 0.1) => format!(
            "set `unit = \"g\"` under [{key}] if the signal is in g (or {})",
            scale_text(key, scale / f)
        ),
        _ => scale_text(key, scale / f),
    }
}

/// From the relations that hold, which signal has its sign inverted (the best explanation
/// first, alternatives after) and which reads a wrong scale (by what factor). Hypotheses: at
/// most one signal wrong; with one relation only, both of its signals explain it (steering
/// named first).
fn culprits(said: &[(Pair, Said)]) -> (Vec<Sig>, Option<(Sig, f64)>) {
    let holds: Vec<(Sig, Sig, bool, f64)> = said
        .iter()
        .filter_map(|(p, s)| match s {
            Said::Holds { negative, factor } => Some((p.from, p.to, *negative, *factor)),
            _ => None,
        })
        .collect();
    let order = [Sig::Steer, Sig::Yaw, Sig::Lat];
    // Signs: a relation reads negative when exactly one of its two signals is flipped.
    let mut sign = Vec::new();
    if holds.iter().any(|h| h.2) {
        for s in order {
            if holds
                .iter()
                .all(|&(a, b, neg, _)| neg == (a == s || b == s))
            {
                sign.push(s);
            }
        }
    }
    // Scales (log10): y / prediction = e_to / e_from.
    let mut scale = None;
    if holds.iter().any(|h| h.3 != 1.0) {
        for s in order {
            // The factor s would need, from every relation involving it.
            let mut e: Option<f64> = None;
            let ok = holds.iter().all(|&(a, b, _, f)| {
                let need = if a == s {
                    1.0 / f
                } else if b == s {
                    f
                } else {
                    return f == 1.0;
                };
                match e {
                    None => {
                        e = Some(need);
                        true
                    }
                    Some(x) => near(x, need),
                }
            });
            if let (true, Some(x)) = (ok, e) {
                if x != 1.0 {
                    scale = Some((s, x));
                    break;
                }
            }
        }
    }
    (sign, scale)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn factors_snap_to_powers_of_ten_and_degrees() {
        assert_eq!(snap_factor(0.57), 1.0);
        assert_eq!(snap_factor(-0.57), 1.0);
        assert_eq!(snap_factor(2.9), 1.0);
        assert_eq!(snap_factor(0.057), 0.1);
        assert_eq!(snap_factor(5.7), 10.0);
        assert!(near(
            snap_factor(0.57 / DEG / NOMINAL_STEER_GAIN),
            1.0 / DEG
        ));
        assert!(near(snap_factor(0.9 * DEG), DEG));
        assert_eq!(fmt_num(0.1 * 1.0), "0.1");
        assert_eq!(fmt_num(1.0 / 0.1), "10");
        assert_eq!(fmt_num(0.1 * 10.0000001), "1");
    }

    fn said(from: Sig, to: Sig, negative: bool, factor: f64) -> (Pair, Said) {
        (
            Pair {
                from,
                to,
                reg: Reg::default(),
                min_std: 0.0,
                clear_std: 0.0,
                nominal: 1.0,
            },
            Said::Holds { negative, factor },
        )
    }

    #[test]
    fn the_signal_two_relations_blame_is_the_culprit() {
        use Sig::*;
        // Steering inverted: steer-yaw and steer-lat negative, yaw-lat positive.
        let s = [
            said(Steer, Yaw, true, 1.0),
            said(Steer, Lat, true, 1.0),
            said(Yaw, Lat, false, 1.0),
        ];
        assert_eq!(culprits(&s), (vec![Steer], None));
        // Lateral inverted.
        let s = [
            said(Steer, Yaw, false, 1.0),
            said(Steer, Lat, true, 1.0),
            said(Yaw, Lat, true, 1.0),
        ];
        assert_eq!(culprits(&s).0, vec![Lat]);
        // One relation: both explain it, steering first.
        assert_eq!(culprits(&s[..1]).0, Vec::<Sig>::new());
        let one = [said(Steer, Yaw, true, 1.0)];
        assert_eq!(culprits(&one).0, vec![Steer, Yaw]);
        // Steering 10x too large: its relations read 0.1, yaw-lat 1.
        let s = [
            said(Steer, Yaw, false, 0.1),
            said(Steer, Lat, false, 0.1),
            said(Yaw, Lat, false, 1.0),
        ];
        assert_eq!(culprits(&s).1, Some((Steer, 10.0)));
        // Yaw 10x too large.
        let s = [
            said(Steer, Yaw, false, 10.0),
            said(Steer, Lat, false, 1.0),
            said(Yaw, Lat, false, 0.1),
        ];
        assert_eq!(culprits(&s).1, Some((Yaw, 10.0)));
    }
}
