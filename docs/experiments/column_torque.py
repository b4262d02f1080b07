"""Does the EPS column torque see the joints where the steering angle does not? (docs/ACCURACY.md)

Not part of the product. Reads `shimmy simulate --out` runs (1 kHz CSV) of one braking event
(55 km/h, 0.55 g) at kingpin damping c_s = 27 and 33 N*m*s/rad (nominal 30, the fleets'
+-10 %), six clearances, three seeds, twice: with the paper's 5 DOF (the fleets' and the
table's model) and with the MODEL.md §15 column as a sixth coordinate (what an EPS torque
sensor would read, `column_torque_nm`). Prints per (c_s, c) the model's own band-passed
(3-25 Hz) RMS over the braking window (t > 0.8 s, v > 2 m/s), no sensor:
  5-DOF steering-wheel angle | column-on angle | column torque | torque / angle | contact %

Usage (numpy; from the repository root, after `cargo build --release`):
  D=/tmp/ct; mkdir -p $D
  for cs in 27.0 33.0; do
    sed "s/^kingpin_damping_nms_per_rad = .*/kingpin_damping_nms_per_rad = $cs/" \
        config/vehicle/default.toml > $D/n$cs.toml
    sed '/^\\[column\\]/,/^\\[/ s/^enabled = false/enabled = true/' $D/n$cs.toml > $D/v$cs.toml
    for c in 0.03 0.07 0.1 0.17 0.32 0.44; do for s in 1 2 3; do for m in n v; do
      target/release/shimmy simulate --clearance-mm $c --v0-kmh 55 --decel-g 0.55 --seed $s \
          --vehicle $D/$m$cs.toml --out $D/${m}_${cs}_${c}_$s.csv
    done; done; done
  done
  python3 docs/experiments/column_torque.py $D
"""
import glob
import os
import sys

import numpy as np


def bandpass(x, fs=1000.0, lo=3.0, hi=25.0):
    spec = np.fft.rfft(x - x.mean())
    f = np.fft.rfftfreq(len(x), 1 / fs)
    spec[(f < lo) | (f > hi)] = 0
    return np.fft.irfft(spec, len(x))


def rms(x):
    return float(np.sqrt(np.mean(x**2)))


def run(path):
    d = np.genfromtxt(path, delimiter=",", names=True)
    m = (d["t_s"] > 0.8) & (d["speed_mps"] > 2.0)
    sw = rms(bandpass(d["delta_sw_deg"])[m])
    tq = rms(bandpass(d["column_torque_nm"])[m])
    contact = 100.0 * float(np.mean(d["penetration_l_m"][m] > 0))
    return sw, tq, contact


def main(folder):
    runs = {}
    for path in sorted(glob.glob(os.path.join(folder, "[nv]_*.csv"))):
        model, cs, c, seed = os.path.basename(path)[:-4].split("_")
        runs.setdefault((float(cs), float(c)), {}).setdefault(model, []).append(run(path))
    fmt = lambda xs: " ".join(f"{x:.3f}" for x in xs)  # noqa: E731
    print("c_s  c_mm | 5-DOF angle deg | column angle deg | torque N*m | torque/angle | contact %")
    for (cs, c), r in sorted(runs.items()):
        n = np.array(r.get("n", [])).reshape(-1, 3)
        v = np.array(r.get("v", [])).reshape(-1, 3)
        ratio = [t / a if a > 0 else float("nan") for a, t in v[:, :2]]
        print(
            f"{cs:4.0f} {c:5.2f} | {fmt(n[:, 0])} | {fmt(v[:, 0])} | {fmt(v[:, 1])} | "
            f"{fmt(ratio)} | {fmt(v[:, 2])}"
        )


if __name__ == "__main__":
    main(sys.argv[1] if len(sys.argv) > 1 else ".")
