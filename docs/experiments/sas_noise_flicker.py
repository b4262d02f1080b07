"""The steering angle sensor's noise on the real RAV4 log, from how often its quantised angle
flickers (docs/ADDING_A_CAR.md, config/vehicles/toyota_rav4/profile.toml).

On a straight road the angle moves slowly, so a 0.1 deg sensor changes step rarely; white noise
before quantisation makes the value flicker back and forth where the angle sits near a step
boundary (A-B-A). The real minute's counts of changes and flickers are compared with the
observer's sensor model (src/observer/sensor.rs: the driver's lane keeping through two lags of
drift_tau_s / 2, white noise, a random sub-step offset, rounding to the step) at several noise
levels and drifts.

    python3 docs/experiments/sas_noise_flicker.py [../shared/data/logs/comma2k19-rav4/rav4_2017_seg40_bus0.log]
"""
import sys

import numpy as np

LOG = sys.argv[1] if len(sys.argv) > 1 else "../shared/data/logs/comma2k19-rav4/rav4_2017_seg40_bus0.log"
STEP = 0.1


def sgn(v, bits):
    return v - (1 << bits) if v & (1 << (bits - 1)) else v


def real_angles(path):
    out = []
    for line in open(path):
        p = line.split()
        ident, data = p[2].split("#")
        if ident == "025":  # STEER_ANGLE_SENSOR: 1.5 deg STEER_ANGLE + 0.1 deg STEER_FRACTION
            d = bytes.fromhex(data)
            coarse = sgn(((d[0] & 0x0F) << 8) | d[1], 12) * 1.5
            frac = sgn((d[4] >> 4) & 0x0F, 4) * 0.1
            out.append(round(coarse + frac, 3))
    return np.array(out)


def counts(a):
    changes = int((np.abs(np.diff(a)) > 1e-9).sum())
    flick = sum(1 for i in range(1, len(a) - 1)
                if a[i] != a[i - 1] and abs(a[i + 1] - a[i - 1]) < 1e-9)
    return changes, flick


def simulated(n, fs, noise, drift_rms, tau=2.0, rng=None):
    period = 1 / fs
    a = np.exp(-period / (0.5 * tau))
    drive = np.sqrt(1 - a * a)
    x1 = x2 = 0.0
    for _ in range(2000):
        w = rng.standard_normal()
        x1p = x1
        x1 = a * x1 + drive * w
        x2 = a * x2 + (1 - a) * x1p
    off = rng.uniform(-0.5, 0.5) * STEP
    out = np.empty(n)
    for k in range(n):
        w = rng.standard_normal()
        x1p = x1
        x1 = a * x1 + drive * w
        x2 = a * x2 + (1 - a) * x1p
        v = x2 * drift_rms * np.sqrt(2) + off + noise * rng.standard_normal()
        out[k] = round(v / STEP) * STEP
    return out


def main():
    real = real_angles(LOG)
    fs = len(real) / 60.0
    c, f = counts(real)
    print(f"real log: {len(real)} samples ({fs:.1f} Hz): {c} changes, {f} flickers ({f / c:.2f})")
    rng = np.random.default_rng(1)
    for drift in (1.0, 1.5):
        for noise in (0.0, 0.005, 0.01, 0.02, 0.03):
            runs = [counts(simulated(len(real), fs, noise, drift, rng=rng)) for _ in range(3)]
            ch = np.mean([r[0] for r in runs])
            fl = np.mean([r[1] for r in runs])
            print(f"model, drift {drift} deg, noise {noise} deg: {ch:.0f} changes, {fl:.0f} flickers ({fl / ch:.2f})")


if __name__ == "__main__":
    main()
