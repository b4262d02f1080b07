"""Order-tracked forced response at the steering wheel: a first check (docs/ACCURACY.md).

Not part of the product. Reads `shimmy simulate --out` runs (1 kHz CSV), emulates the
reference bus's steering angle sensor (100 Hz, 0.01 deg white noise, 0.1 deg steps, plus the
driver's lane keeping of firmware-sim: 1 deg RMS through two 2 s lags), band-passes 3-25 Hz
and demodulates at the wheel's spin phase  int v/R_w dt  while the spin is above 3 Hz.
Prints per clearance and run, first what the model puts out while braking (1 kHz: band-passed
RMS of the steering-wheel angle, share of steps with the left joint in contact), then: the
broadband RMS of the measured signal, the lock-in amplitude of the
measured and of the true signal, and the true RMS; then the same for a run with the model's
steering-wheel angle set to zero (the noise floor).

Usage (numpy; from the repository root, after `cargo build --release`):
  sed 's/^kingpin_damping_nms_per_rad = .*/kingpin_damping_nms_per_rad = 33.0/' \
      config/vehicle/default.toml > /tmp/v33.toml
  for c in 0.03 0.07 0.1 0.17 0.32 0.44; do for s in 1 2 3; do
    target/release/shimmy simulate --clearance-mm $c --v0-kmh 55 --decel-g 0.55 --seed $s \
        --vehicle /tmp/v33.toml --out /tmp/c${c}_s$s.csv
  done; done
  python3 docs/experiments/order_tracking.py /tmp
"""
import glob
import os
import sys

import numpy as np

R_W = 0.30  # MODEL.md §9
FS = 100.0
rng = np.random.default_rng(0)


def lane(n, rms=1.0, tau=2.0):
    a = np.exp(-1 / (FS * tau))
    x = np.zeros(n)
    y = np.zeros(n)
    w = rng.standard_normal(n)
    for i in range(1, n):
        x[i] = a * x[i - 1] + (1 - a) * w[i]
        y[i] = a * y[i - 1] + (1 - a) * x[i]
    return y / y.std() * rms


def bandpass(x, lo=3.0, hi=25.0):
    spec = np.fft.rfft(x - x.mean())
    f = np.fft.rfftfreq(len(x), 1 / FS)
    spec[(f < lo) | (f > hi)] = 0
    return np.fft.irfft(spec, len(x))


def lock_in(y, phi, m):
    return 2 * np.hypot((y[m] * np.cos(phi[m])).mean(), (y[m] * np.sin(phi[m])).mean())


def model_side(path):
    d = np.genfromtxt(path, delimiter=",", names=True)
    t, v = d["t_s"], d["speed_mps"]
    m = (t > 0.8) & (v > 2.0)
    spec = np.fft.rfft(d["delta_sw_deg"] - d["delta_sw_deg"].mean())
    f = np.fft.rfftfreq(len(t), 1e-3)
    spec[(f < 3) | (f > 25)] = 0
    sw = np.fft.irfft(spec, len(t))
    return sw[m].std(), (d["penetration_l_m"][m] > 0).mean() * 100


def measure(path, zero=False):
    d = np.genfromtxt(path, delimiter=",", names=True)
    t, sw, v = d["t_s"][::10], d["delta_sw_deg"][::10], d["speed_mps"][::10]
    if zero:
        sw = sw * 0
    n = len(t)
    meas = np.round((sw + lane(n) + 0.01 * rng.standard_normal(n)) / 0.1) * 0.1
    y, yt = bandpass(meas), bandpass(sw)
    phi = np.cumsum(v / R_W) / FS
    m = (t > 0.8) & (v / (2 * np.pi * R_W) > 3.0)
    return y[m].std(), lock_in(y, phi, m), lock_in(yt, phi, m), yt[m].std()


def main(folder):
    fmt = lambda xs, k: " ".join(f"{x:.{k}f}" for x in xs)
    for c in ["0.03", "0.07", "0.1", "0.17", "0.32", "0.44"]:
        runs = sorted(glob.glob(os.path.join(folder, f"c{c}_s*.csv")))
        ms = np.array([model_side(p) for p in runs])
        print(f"c={c} mm  model: steering wheel RMS {fmt(ms[:, 0], 3)} deg, "
              f"joint in contact {fmt(ms[:, 1], 1)} %")
        r = np.array([measure(p) for p in runs])
        print(f"c={c} mm  measured RMS {fmt(r[:, 0], 3)}  lock-in measured {fmt(r[:, 1], 4)}  "
              f"lock-in true {fmt(r[:, 2], 4)}  true RMS {fmt(r[:, 3], 3)}")
    floor = np.array([measure(os.path.join(folder, "c0.44_s1.csv"), zero=True) for _ in range(5)])
    print(f"no signal: measured RMS {fmt(floor[:, 0], 3)}  lock-in {fmt(floor[:, 1], 4)}")


if __name__ == "__main__":
    main(sys.argv[1] if len(sys.argv) > 1 else ".")
