"""What the yaw rate, the lateral acceleration and the wheel speeds could carry about the joints'
clearance, beside the steering angle and the EPS torque (docs/ACCURACY.md, "The yaw rate, the
lateral acceleration and the wheel speeds").

Not part of the product. Two halves:

* The model (`shimmy simulate --out`, 1 kHz, the MODEL.md §15 column on): one braking event
  (55 km/h, 0.55 g) per kingpin damping c_s (27, 30, 33 N*m*s/rad), clearance (0.03, 0.1, 0.2,
  0.32 mm) and seed (1-3). Over the braking window (t > 0.8 s, v > 2 m/s), band-passed 3-25 Hz
  as the observer's features are: the rim angle and the column torque (what the product reads),
  and upper bounds of what the body and the wheels would show of the same motion. MODEL.md
  drops the vehicle's yaw (I_z about 2000 kg*m^2, inert at 7 Hz) and the wheels' spin (free
  rolling), so these are computed from the model's front tyre forces and kingpin angles as
  if nothing filtered them:
    lateral acceleration  a_y = (F_yL + F_yR) / m            (no suspension, sensor at the CG)
    yaw rate              r   = l_f (F_yL + F_yR) / (I_z i w)  (integrated in frequency)
    one wheel's speed     v_w = d_w * dtheta_1/dt            (the wheel centre's fore-aft
                                                              motion about the kingpin, d_w the
                                                              spindle offset)
* The real RAV4 log (comma2k19, bus 0, decoded with its opendbc DBC): each signal's message
  rate and step, and its band RMS (3 Hz to 0.4 x its rate) while the car drives above 30 km/h,
  over the whole drive and per 2.5 s window (about one braking window) with the spread of its ln:
  the floor any shimmy signature would have to rise above, and how much it moves.

Usage (numpy; from the repository root, after `cargo build --release`):
  python3 docs/experiments/other_signals.py /tmp/os \
      ../shared/data/dbc/opendbc/toyota_new_mc_pt_generated.dbc \
      ../shared/data/logs/comma2k19-rav4/rav4_2017_seg40_bus0.log
"""
import csv
import io
import os
import subprocess
import sys
import tomllib

import numpy as np

from column_torque import bandpass  # the features' 3-25 Hz band, by FFT

SHIMMY = "target/release/shimmy"
I_Z = 2000.0  # MODEL.md §1: the vehicle yaw inertia the model leaves out


def integrate_band(x, fs, lo=3.0, hi=25.0):
    """Band-passed time integral of x (divides the spectrum by i*omega)."""
    spec = np.fft.rfft(x - x.mean())
    f = np.fft.rfftfreq(len(x), 1 / fs)
    keep = (f >= lo) & (f <= hi)
    out = np.zeros_like(spec)
    out[keep] = spec[keep] / (2j * np.pi * f[keep])
    return np.fft.irfft(out, len(x))


def rms(x):
    return float(np.sqrt(np.mean(x**2))) if len(x) else float("nan")


def vehicle_files(out_dir):
    base = open("config/vehicle/default.toml").read()
    files = {}
    for cs in (27.0, 30.0, 33.0):
        lines = []
        in_column = False
        for line in base.splitlines():
            if line.startswith("["):
                in_column = line.startswith("[column]")
            if line.startswith("kingpin_damping_nms_per_rad"):
                line = f"kingpin_damping_nms_per_rad = {cs}"
            if in_column and line.startswith("enabled"):
                line = "enabled = true"
            lines.append(line)
        p = os.path.join(out_dir, f"col_cs{cs:g}.toml")
        open(p, "w").write("\n".join(lines) + "\n")
        files[cs] = p
    return files


def chassis(path):
    with open(path, "rb") as f:
        v = tomllib.load(f)
    return {**v["vehicle"], **v["steering"]}


def model_half(out_dir):
    os.makedirs(out_dir, exist_ok=True)
    files = vehicle_files(out_dir)
    ch = chassis(files[30.0])
    m, l_f = ch["mass_kg"], ch["wheelbase_m"] - ch["cg_to_rear_axle_m"]
    d_w = ch["spindle_offset_m"]
    print(f"model: m = {m:g} kg, l_f = {l_f:.2f} m, I_z = {I_Z:g} kg*m^2, d_w = {d_w:g} m;"
          " braking window, 3-25 Hz band RMS, range over seeds 1-3")
    print("c_s  c (mm) | rim angle (deg) | column torque (N*m) | a_y (m/s^2) | yaw rate (deg/s)"
          " | wheel speed (km/h)")
    for cs, veh in files.items():
        for c in (0.03, 0.1, 0.2, 0.32):
            rows = []
            for seed in (1, 2, 3):
                out = os.path.join(out_dir, f"s_{cs:g}_{c}_{seed}.csv")
                if not os.path.exists(out):
                    subprocess.run([SHIMMY, "simulate", "--clearance-mm", str(c), "--v0-kmh", "55",
                                    "--decel-g", "0.55", "--seed", str(seed), "--vehicle", veh,
                                    "--out", out], check=True, stdout=subprocess.DEVNULL)
                d = np.genfromtxt(out, delimiter=",", names=True)
                fs = 1.0 / (d["t_s"][1] - d["t_s"][0])
                w = (d["t_s"] > 0.8) & (d["speed_mps"] > 2.0)
                fy = d["tire_fy_l_n"] + d["tire_fy_r_n"]
                rows.append([
                    rms(bandpass(d["delta_sw_deg"], fs)[w]),
                    rms(bandpass(d["column_torque_nm"], fs)[w]),
                    rms(bandpass(fy / m, fs)[w]),
                    rms(np.degrees(integrate_band(l_f * fy / I_Z, fs))[w]),
                    rms(bandpass(d_w * d["theta1_rate_rad_s"] * 3.6, fs)[w]),
                ])
            r = np.array(rows)
            cells = " | ".join(f"{r[:, k].min():.4f}-{r[:, k].max():.4f}" for k in range(5))
            print(f"{cs:4g} {c:5.2f}   | {cells}")


def log_half(dbc, log):
    out = subprocess.run([SHIMMY, "decode", "--dbc", dbc, "--format", "csv", log],
                         check=True, capture_output=True, text=True).stdout
    series = {}
    for row in csv.reader(io.StringIO(out)):
        if len(row) < 6:
            continue
        try:
            t, v = float(row[0]), float(row[5])
        except ValueError:
            continue
        series.setdefault((row[3], row[4]), []).append((t, v))
    want = [("KINEMATICS", "YAW_RATE", "deg/s"), ("KINEMATICS", "ACCEL_Y", "m/s^2"),
            ("WHEEL_SPEEDS", "WHEEL_SPEED_FL", "km/h"), ("WHEEL_SPEEDS", "WHEEL_SPEED_FR", "km/h")]
    speed = np.array(series[("SPEED", "SPEED")])
    print("real RAV4 log: signal | rate (Hz) | step | band RMS above 30 km/h (3 Hz to 0.4 x rate)")
    for msg, sig, unit in want:
        s = np.array(series.get((msg, sig), []))
        if len(s) < 100:
            print(f"{msg}.{sig}: not on this log")
            continue
        t, v = s[:, 0], s[:, 1]
        rate = (len(t) - 1) / (t[-1] - t[0])
        steps = np.diff(np.unique(np.round(v, 6)))
        step = float(np.min(steps[steps > 1e-9])) if np.any(steps > 1e-9) else float("nan")
        # a uniform grid at the message rate (the frames are nearly periodic)
        grid = np.arange(t[0], t[-1], 1.0 / rate)
        x = np.interp(grid, t, v)
        spd = np.interp(grid, speed[:, 0], speed[:, 1])
        y = bandpass(x, rate, 3.0, 0.4 * rate)
        fast = spd > 30.0
        # window to window: 2.5 s windows (a braking window from 55 km/h at 0.55 g is 2.8 s)
        n = int(2.5 * rate)
        win = [y[i:i + n] for i in range(0, len(y) - n + 1, n) if fast[i:i + n].all()]
        ln = np.log([rms(w) for w in win])
        print(f"{msg}.{sig} ({unit}) | {rate:.1f} | {step:.4g} | {rms(y[fast]):.4f}"
              f" ({fast.mean() * 100:.0f} % of {grid[-1] - grid[0]:.0f} s); 2.5 s windows:"
              f" {np.exp(ln.min()):.4f}-{np.exp(ln.max()):.4f}, ln RMS spread {ln.std():.2f}"
              f" ({len(win)} windows)")


if __name__ == "__main__":
    if len(sys.argv) != 4:
        sys.exit(__doc__)
    model_half(sys.argv[1])
    log_half(sys.argv[2], sys.argv[3])
