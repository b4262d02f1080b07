"""Fleet estimate error by the vehicles' kingpin damping c_s (docs/ACCURACY.md).

Reads `firmware-sim fleet --json FLEET.json --work-dir DIR` outputs (each vehicle's c_s is in
DIR/vehicle_SEED.toml) and prints, for the vehicles with c >= 0.1 mm sorted by c_s and cut
into thirds, and for all of them: the c_s range, MAE, mean error, median absolute error and 90 %
interval coverage.

Usage: python3 docs/experiments/error_by_damping.py fleet6400.json fleet6400 [JSON DIR ...]
"""
import json
import os
import sys


def c_s(path):
    for line in open(path):
        if line.startswith("kingpin_damping_nms_per_rad ="):
            return float(line.split("=")[1].split("#")[0])
    raise ValueError(f"{path}: no kingpin_damping_nms_per_rad")


def main(args):
    rows = []
    for fleet, folder in zip(args[::2], args[1::2]):
        for v in json.load(open(fleet))["vehicles"]:
            c = v["clearance_true_mm"]
            if c < 0.1:
                continue
            lo, hi = v["interval_mm"]
            rows.append((c_s(os.path.join(folder, f"vehicle_{v['seed']}.toml")), c,
                         v["median_mm"], lo <= c <= hi))
    rows.sort()
    n = len(rows)
    print(f"{n} vehicles with c >= 0.1 mm")
    parts = [rows[k * n // 3:(k + 1) * n // 3] for k in range(3)] + [rows]
    for k, part in enumerate(parts):
        err = [m - c for _, c, m, _ in part]
        label = "all" if k == 3 else f"c_s {part[0][0]:.1f}-{part[-1][0]:.1f}"
        print(f"{label}: n {len(part)}, "
              f"MAE {sum(map(abs, err)) / len(err):.4f}, mean error {sum(err) / len(err):+.4f}, "
              f"median |error| {sorted(map(abs, err))[len(err) // 2]:.4f}, "
              f"coverage {sum(r[3] for r in part)}/{len(part)}")


if __name__ == "__main__":
    main(sys.argv[1:])
