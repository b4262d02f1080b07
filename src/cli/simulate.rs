//! `shimmy simulate`: one braking event of the 5-DOF shimmy model (MODEL.md §6), written as a
//! CSV time history and/or summarised with the §11 features as one JSON object.
//!
//! What it is: argument checking at the edge (mm, km/h, g in; SI inside) and output formatting.
//! What it is not: the model (`shimmy::model`) or the analysis (`shimmy::analysis`).

use crate::model::features::{features, lyapunov_per_s};
use crate::model::{run as simulate_trace, Integrator, JointMode, Scenario, Trace, VehicleParams};
use anyhow::{bail, Context};
use std::io::Write;
use std::path::PathBuf;

/// Simulate one brake-induced shimmy event (MODEL.md §6: constant speed until 0.5 s, then a
/// 0.3 s ramp to the full deceleration, fading to a stop) with worn steering joints.
///
/// Writes the 1 kHz time history with --out and/or prints the MODEL.md §11 summary as one JSON
/// object with --summary (the default when --out is not given). Same seed, same result.
///
/// Example: shimmy simulate --clearance-mm 0.2 --v0-kmh 55 --decel-g 0.5 --seed 1 --summary
#[derive(clap::Args, Debug)]
pub struct Args {
    /// Radial clearance of the tie-rod joints in mm (MODEL.md §4). The studied range is
    /// 0.03–0.4 mm; up to 5 mm is accepted with a warning outside the range.
    #[arg(long, default_value_t = 0.1, allow_hyphen_values = true)]
    pub clearance_mm: f64,
    /// Initial speed in km/h (studied: 25–95).
    #[arg(long, default_value_t = 55.0, allow_hyphen_values = true)]
    pub v0_kmh: f64,
    /// Peak braking deceleration in g (studied: 0.3–0.8; 0 gives a constant-speed run).
    #[arg(long, default_value_t = 0.5, allow_hyphen_values = true)]
    pub decel_g: f64,
    /// Single-clearance variant: the right joint is ideal (MODEL.md §4).
    #[arg(long)]
    pub single: bool,
    /// Seed of the unbalance phases and road noise (MODEL.md §7).
    #[arg(long, default_value_t = 0)]
    pub seed: u64,
    /// RK4 step in seconds (MODEL.md §10; above 2e-4 s the contact impacts are unresolved).
    #[arg(long = "h", default_value_t = 1e-4, value_name = "STEP")]
    pub h_s: f64,
    /// Simulated time in seconds.
    #[arg(long = "duration", default_value_t = 10.0, value_name = "T")]
    pub duration_s: f64,
    /// Vehicle parameter file (TOML, MODEL.md §9; missing keys take the defaults).
    #[arg(long, value_name = "FILE")]
    pub vehicle: Option<PathBuf>,
    /// Write the 1 kHz time history to this CSV file: time, all coordinates and rates, speed,
    /// demand, contact forces L/R (x, y), penetrations, tire forces, delta_sw_deg and the column
    /// torque column_torque_nm (MODEL.md §15; 0 unless the vehicle's [column] is enabled).
    #[arg(long, value_name = "FILE.csv")]
    pub out: Option<PathBuf>,
    /// Print the MODEL.md §11 features as one JSON object on stdout.
    #[arg(long)]
    pub summary: bool,
    /// Also compute the finite-time largest Lyapunov exponent (a second, twin run; §11).
    #[arg(long)]
    pub lyapunov: bool,
    /// Turn the wheel unbalance off (MODEL.md §7).
    #[arg(long)]
    pub no_unbalance: bool,
    /// Turn the road noise off (MODEL.md §7).
    #[arg(long)]
    pub no_noise: bool,
    /// Integration scheme (docs/BENCHMARKS.md gives the CPU time and the error of each
    /// against an h = 1e-5 s reference): rk4 (MODEL.md §10 as specified); rk4-warm-slip (same
    /// result, braking-slip Newton iteration warm-started); rk4-multirate (RK4 on the same
    /// grid, tire forces once per step and extrapolated over the stages); rk4-adaptive
    /// (rk4-multirate in and near contact, merged steps of up to 10·h in free flight).
    /// Underscores are accepted for hyphens (rk4_adaptive, the serde name).
    #[arg(long, default_value = "rk4", value_parser = [
        "rk4", "rk4-warm-slip", "rk4-multirate", "rk4-adaptive",
        "rk4_warm_slip", "rk4_multirate", "rk4_adaptive",
    ])]
    pub integrator: String,
}

/// Checks the edge units and builds the scenario; warns (stderr) outside the studied ranges.
pub fn scenario(args: &Args) -> anyhow::Result<Scenario> {
    let c = args.clearance_mm;
    if !(c.is_finite() && c > 0.0) {
        bail!("--clearance-mm must be > 0 (got {c}); an ideal joint has no clearance to model");
    }
    if c > 5.0 {
        bail!("--clearance-mm {c} is beyond 5 mm, far outside any worn joint");
    }
    if !(0.03..=0.4).contains(&c) {
        eprintln!("shimmy: warning: --clearance-mm {c} is outside the studied 0.03–0.4 mm");
    }
    let v = args.v0_kmh;
    if !(v.is_finite() && (0.0..=250.0).contains(&v)) {
        bail!("--v0-kmh must lie in 0–250 km/h (got {v})");
    }
    if !(25.0..=95.0).contains(&v) {
        eprintln!("shimmy: warning: --v0-kmh {v} is outside the studied 25–95 km/h");
    }
    let a = args.decel_g;
    if !(a.is_finite() && (0.0..=1.2).contains(&a)) {
        bail!("--decel-g must lie in 0–1.2 g (got {a})");
    }
    if a != 0.0 && !(0.3..=0.8).contains(&a) {
        eprintln!("shimmy: warning: --decel-g {a} is outside the studied 0.3–0.8 g");
    }
    if !(args.h_s.is_finite() && args.h_s > 0.0 && args.h_s <= 1e-3) {
        bail!("--h must lie in (0, 1e-3] s (got {})", args.h_s);
    }
    if args.h_s > 2e-4 {
        eprintln!(
            "shimmy: warning: --h {} s exceeds 2e-4 s; RK4 does not resolve the contact impacts",
            args.h_s
        );
    }
    let sc = Scenario {
        clearance_m: c * 1e-3,
        joints: if args.single {
            JointMode::Single
        } else {
            JointMode::Dual
        },
        seed: args.seed,
        v0_mps: v / 3.6,
        decel_g: a,
        duration_s: args.duration_s,
        h_s: args.h_s,
        unbalance: !args.no_unbalance,
        noise: !args.no_noise,
        integrator: Integrator::from_name(&args.integrator)
            .with_context(|| format!("unknown --integrator {}", args.integrator))?,
        ..Scenario::default()
    };
    sc.validate()?;
    Ok(sc)
}

pub fn run(args: Args) -> anyhow::Result<()> {
    let p = match &args.vehicle {
        Some(f) => VehicleParams::from_toml_file(f)?,
        None => VehicleParams::default(),
    };
    let sc = scenario(&args)?;
    let cpu0 = thread_cpu_s();
    let trace = simulate_trace(&p, &sc)?;
    let cpu_s = thread_cpu_s() - cpu0;
    if let Some(bad) = trace
        .samples
        .iter()
        .find(|o| !(o.theta1_rad.is_finite() && o.x_m.is_finite()))
    {
        bail!(
            "the model diverged at t = {:.4} s (non-finite state)",
            bad.t_s
        );
    }
    if let Some(path) = &args.out {
        write_csv(path, &trace).with_context(|| format!("writing {}", path.display()))?;
    }
    if args.summary || args.out.is_none() {
        let f = features(&trace)?;
        let lyap = if args.lyapunov {
            Some(lyapunov_per_s(&p, &sc, &trace)?)
        } else {
            None
        };
        let mut obj = serde_json::to_value(f)?;
        let m = obj
            .as_object_mut()
            .expect("features serialise to an object");
        m.insert("lyapunov_per_s".into(), serde_json::json!(lyap));
        m.insert("cpu_s".into(), serde_json::json!(cpu_s));
        m.insert("t_stop_s".into(), serde_json::json!(trace.t_stop_s()));
        m.insert("clearance_mm".into(), serde_json::json!(args.clearance_mm));
        m.insert("v0_kmh".into(), serde_json::json!(args.v0_kmh));
        m.insert("decel_g".into(), serde_json::json!(args.decel_g));
        m.insert("single".into(), serde_json::json!(args.single));
        m.insert("seed".into(), serde_json::json!(args.seed));
        m.insert("h_s".into(), serde_json::json!(args.h_s));
        m.insert("integrator".into(), serde_json::json!(sc.integrator.name()));
        println!("{}", serde_json::to_string(&obj)?);
    }
    Ok(())
}

/// CSV header of `--out` (one row per 1 kHz sample).
pub const CSV_HEADER: &str = "t_s,theta1_rad,theta2_rad,theta3_rad,x_m,theta4_rad,\
theta1_rate_rad_s,theta2_rate_rad_s,theta3_rate_rad_s,x_rate_mps,theta4_rate_rad_s,\
alpha_l,alpha_r,speed_mps,decel_demand_mps2,\
contact_fx_l_n,contact_fy_l_n,contact_fx_r_n,contact_fy_r_n,penetration_l_m,penetration_r_m,\
tire_fx_l_n,tire_fy_l_n,tire_mz_l_nm,tire_fz_l_n,tire_fx_r_n,tire_fy_r_n,tire_mz_r_nm,tire_fz_r_n,\
delta_sw_deg,column_torque_nm";

fn write_csv(path: &std::path::Path, trace: &Trace) -> anyhow::Result<()> {
    let mut w = std::io::BufWriter::new(std::fs::File::create(path)?);
    writeln!(w, "{CSV_HEADER}")?;
    for o in &trace.samples {
        let row = [
            o.t_s,
            o.theta1_rad,
            o.theta2_rad,
            o.theta3_rad,
            o.x_m,
            o.theta4_rad,
            o.theta1_rate_rad_s,
            o.theta2_rate_rad_s,
            o.theta3_rate_rad_s,
            o.x_rate_mps,
            o.theta4_rate_rad_s,
            o.alpha_t[0],
            o.alpha_t[1],
            o.speed_mps,
            o.decel_demand_mps2,
            o.contact_fx_n[0],
            o.contact_fy_n[0],
            o.contact_fx_n[1],
            o.contact_fy_n[1],
            o.penetration_m[0],
            o.penetration_m[1],
            o.tire_fx_n[0],
            o.tire_fy_n[0],
            o.tire_mz_nm[0],
            o.tire_fz_n[0],
            o.tire_fx_n[1],
            o.tire_fy_n[1],
            o.tire_mz_nm[1],
            o.tire_fz_n[1],
            o.delta_sw_rad.to_degrees(),
            o.column_torque_nm,
        ];
        for (i, v) in row.iter().enumerate() {
            if i > 0 {
                w.write_all(b",")?;
            }
            write!(w, "{v:e}")?;
        }
        w.write_all(b"\n")?;
    }
    w.flush()?;
    Ok(())
}

/// CPU time of the calling thread in seconds (Linux: `clock_gettime(CLOCK_THREAD_CPUTIME_ID)`,
/// exact to the nanosecond; `/proc/thread-self/schedstat` advances only at scheduler ticks,
/// 4 ms on the benchmark machine); falls back to wall-clock time elsewhere.
pub fn thread_cpu_s() -> f64 {
    #[cfg(target_os = "linux")]
    {
        let mut ts = libc::timespec {
            tv_sec: 0,
            tv_nsec: 0,
        };
        // SAFETY: clock_gettime writes into the timespec we own; CLOCK_THREAD_CPUTIME_ID is
        // always available on Linux.
        let rc = unsafe { libc::clock_gettime(libc::CLOCK_THREAD_CPUTIME_ID, &mut ts) };
        if rc == 0 {
            return ts.tv_sec as f64 + ts.tv_nsec as f64 * 1e-9;
        }
    }
    use std::sync::OnceLock;
    static START: OnceLock<std::time::Instant> = OnceLock::new();
    START
        .get_or_init(std::time::Instant::now)
        .elapsed()
        .as_secs_f64()
}
