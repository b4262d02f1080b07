"""What the article's "0.2 deg at 55 km/h" corresponds to at the rim and on the column torque.

Not part of the product. The article's rule reads the 5-DOF steering-wheel angle, i.e. the
pinion angle (MODEL.md §8). A real car has a steering column (MODEL.md §15): the steering
angle sensor reads the rim, an EPS torque sensor the torsion bar. This runs `shimmy simulate`
(one braking event, 55 km/h, 0.5 g, MODEL.md §6) for clearances 0.03-0.4 mm and seeds 1-6,
with the 5-DOF model and with the column at three hands dampings c_h (0.05: hands nearly
off; 0.3: MODEL.md §15's light hands; 1.5: a firm grip -- a sensitivity span, not published
values), and prints per clearance the MODEL.md §11 metric (peak of the 3-25 Hz band-passed
signal over the braking window) of the angle and, with the column, of the torque:
mean and seed SD, and the fraction of seeds above the article's 0.2 deg.

Usage (numpy; from the repository root, after `cargo build --release`):
  python3 docs/experiments/shimmy_rule_column.py [WORK_DIR]
"""
import json
import os
import re
import subprocess
import sys

import numpy as np

CLEARANCES = [0.03, 0.05, 0.07, 0.1, 0.15, 0.2, 0.3, 0.4]
SEEDS = range(1, 7)
HANDS = [None, 0.05, 0.3, 1.5]  # None: the 5-DOF model (no column)
BIN = "target/release/shimmy"


def bandpass(x, fs=1000.0, lo=3.0, hi=25.0):
    spec = np.fft.rfft(x - x.mean())
    f = np.fft.rfftfreq(len(x), 1 / fs)
    spec[(f < lo) | (f > hi)] = 0
    return np.fft.irfft(spec, len(x))


def vehicle(work, c_h):
    text = open("config/vehicle/default.toml").read()
    if c_h is not None:
        block = re.search(r"^\[column\].*?(?=^\[)", text, re.S | re.M).group(0)
        new = block.replace("enabled = false", "enabled = true")
        new = re.sub(r"hands_damping_nms_per_rad = [0-9.]+", f"hands_damping_nms_per_rad = {c_h}", new)
        text = text.replace(block, new)
    path = os.path.join(work, f"v_{c_h}.toml")
    open(path, "w").write(text)
    return path


def run(work, veh, c, seed):
    csv = os.path.join(work, "run.csv")
    out = subprocess.run(
        [BIN, "simulate", "--clearance-mm", str(c), "--v0-kmh", "55", "--decel-g", "0.5",
         "--seed", str(seed), "--vehicle", veh, "--out", csv, "--summary"],
        check=True, capture_output=True, text=True).stdout
    s = json.loads(out.strip().splitlines()[-1])
    d = np.genfromtxt(csv, delimiter=",", names=True)
    m = (d["t_s"] >= s["window_start_s"]) & (d["t_s"] <= s["window_end_s"])
    sw = float(np.max(np.abs(bandpass(d["delta_sw_deg"])[m])))
    tq = float(np.max(np.abs(bandpass(d["column_torque_nm"])[m])))
    return sw, tq


def main(work):
    os.makedirs(work, exist_ok=True)
    print("model            c_mm | angle peak deg mean (SD) | > 0.2 deg | torque peak N*m mean (SD)")
    for c_h in HANDS:
        veh = vehicle(work, c_h)
        name = "5-DOF (pinion)" if c_h is None else f"column c_h={c_h}"
        for c in CLEARANCES:
            r = np.array([run(work, veh, c, s) for s in SEEDS])
            above = int(np.sum(r[:, 0] > 0.2))
            tq = "" if c_h is None else f"{r[:, 1].mean():.3f} ({r[:, 1].std(ddof=1):.3f})"
            print(f"{name:16s} {c:4.2f} | {r[:, 0].mean():.3f} ({r[:, 0].std(ddof=1):.3f})"
                  f"            | {above}/{len(r)}       | {tq}", flush=True)


if __name__ == "__main__":
    main(sys.argv[1] if len(sys.argv) > 1 else "/tmp/shimmy_rule_column")
