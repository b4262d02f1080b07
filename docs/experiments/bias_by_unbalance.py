"""Fleet estimate bias by the vehicle's wheel unbalance (docs/ACCURACY.md, "The torque tables
mixed by their weights instead of the best one read").

Reads `firmware-sim fleet --json FLEET.json --work-dir DIR` outputs (DIR holds each vehicle's
scenario `fleet_SEED.toml`, whose `[excitation] unbalance_kgm` is the vehicle's draw) and prints,
per band of the unbalance as a factor of NOMINAL_KGM (MODEL.md §9's U), the median of
ln(estimate / truth) for the vehicles at c <= 0.1 mm and at c >= 0.15 mm and how many of the
first were alerted; then every clearance alert at c <= 0.07 mm with its unbalance factor; then,
per band of the unbalance and of the true clearance, the median ln width of the 90 % interval
(how much the events say) beside the median ln(estimate / truth).

Usage: python3 docs/experiments/bias_by_unbalance.py FLEET.json DIR [FLEET.json DIR ...]
"""
import json
import math
import os
import re
import statistics
import sys

NOMINAL_KGM = 2e-3
BANDS = [(0.5, 0.7), (0.7, 1.0), (1.0, 1.4), (1.4, 2.01)]


def main(args):
    rows = []
    for fleet, folder in zip(args[::2], args[1::2]):
        for v in json.load(open(fleet))["vehicles"]:
            text = open(os.path.join(folder, f"fleet_{v['seed']}.toml")).read()
            u = float(re.search(r"unbalance_kgm = ([0-9.eE+-]+)", text).group(1))
            lo, hi = v["interval_mm"]
            rows.append((u / NOMINAL_KGM, v["clearance_true_mm"], v["median_mm"],
                         v["clearance_alert"], math.log(hi / lo)))
    med = lambda part: statistics.median(math.log(r[2] / r[1]) for r in part) if part else float("nan")
    print("unbalance factor | c <= 0.1 mm: n, median ln(est/true), alerted | c >= 0.15 mm: n, median")
    for lo, hi in BANDS:
        small = [r for r in rows if lo <= r[0] < hi and r[1] <= 0.1]
        worn = [r for r in rows if lo <= r[0] < hi and r[1] >= 0.15]
        print(f"{lo:.1f}-{min(hi, 2.0):.1f} | {len(small)}, {med(small):+.2f}, "
              f"{sum(r[3] for r in small)} | {len(worn)}, {med(worn):+.2f}")
    false = sorted((round(r[0], 2), round(r[1], 3)) for r in rows if r[1] <= 0.07 and r[3])
    print("alerted at c <= 0.07 mm (unbalance factor, c):", false)
    print("unbalance factor | true c | n, median ln width of the 90 % interval, median ln(est/true)")
    for lo, hi in BANDS:
        for clo, chi in [(0.0, 0.07), (0.07, 0.1), (0.15, 10.0)]:
            part = [r for r in rows if lo <= r[0] < hi and clo < r[1] <= chi]
            if part:
                print(f"{lo:.1f}-{min(hi, 2.0):.1f} | {clo:.2f}-{min(chi, 1.0):.2f} mm | {len(part)}, "
                      f"{statistics.median(r[4] for r in part):.2f}, {med(part):+.2f}")


if __name__ == "__main__":
    if len(sys.argv) < 3 or len(sys.argv) % 2 == 0:
        sys.exit(__doc__)
    main(sys.argv[1:])
