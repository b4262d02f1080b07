"""Scores behind docs/ACCURACY.md, "The torque tables mixed by their weights instead of the best
one read", from `firmware-sim fleet --json` outputs.

  widths BEFORE.json AFTER.json [...]
      per pair (the same fleet re-estimated): the median and mean ratio of the 90 % intervals'
      ln widths (after / before), and how many vehicles of AFTER have no torque table with
      95 % of the weight.
  bias FLEET.json [...]
      pooled: per band of true clearance, the median of ln(estimate / truth), the share with
      P(c > 0.1 mm) >= 0.7 at the end of the log, and the 90 % coverage.
  reliability FLEET.json [...]
      pooled: per band of the reported P(c > 0.1 mm), how many vehicles, their mean P and the
      share whose true clearance is above 0.1 mm (a calibrated P has the two equal).
  targets matched|mismatch FLEET.json [...] [-- matched|mismatch FLEET.json ...]
      pooled worn / false / band alerts per group, and the fleets that miss a target (matched:
      worn >= 95 %, false <= 2 %; mismatch: false <= 5 %, band <= 25 %).
"""
import json
import math
import statistics
import sys

BANDS = [0.02, 0.04, 0.06, 0.07, 0.08, 0.09, 0.1, 0.12, 0.15, 0.2, 0.3, 0.5]


def vehicles(path):
    return json.load(open(path))["vehicles"]


def ln_width(v):
    lo, hi = v["interval_mm"]
    return math.log(hi / lo)


def widths(paths):
    for before, after in zip(paths[::2], paths[1::2]):
        a, b = vehicles(before), vehicles(after)
        r = [ln_width(y) / ln_width(x) for x, y in zip(a, b)]
        mixed = sum(
            1
            for v in b
            if v.get("torque_tables") and max(t["weight"] or 0 for t in v["torque_tables"]) < 0.95
        )
        print(f"{after}: ln width ratio median {statistics.median(r):.3f} mean "
              f"{statistics.mean(r):.3f}; no table at 95 %: {mixed}/{len(b)}")


def bias(paths):
    rows = [v for p in paths for v in vehicles(p)]
    for lo, hi in zip(BANDS[:-1], BANDS[1:]):
        part = [v for v in rows if lo <= v["clearance_true_mm"] < hi]
        if not part:
            continue
        ln = [math.log(v["median_mm"] / v["clearance_true_mm"]) for v in part]
        alert = sum(v["p_clearance_above_threshold"] >= 0.7 for v in part) / len(part)
        cov = sum(v["interval_mm"][0] <= v["clearance_true_mm"] <= v["interval_mm"][1]
                  for v in part) / len(part)
        print(f"{lo:.2f}-{hi:.2f} mm: n {len(part)}, median ln(est/true) "
              f"{statistics.median(ln):+.3f}, P >= 0.7 {alert:.2f}, coverage {cov:.2f}")


def reliability(paths):
    rows = [(v["p_clearance_above_threshold"], v["clearance_true_mm"]) for p in paths for v in vehicles(p)]
    edges = [0.0, 0.05, 0.2, 0.4, 0.5, 0.6, 0.7, 0.8, 0.9, 0.97, 1.01]
    print("P(c > 0.1 mm) | vehicles | mean P | share with c > 0.1 mm | with c <= 0.07 mm")
    for lo, hi in zip(edges, edges[1:]):
        part = [r for r in rows if lo <= r[0] < hi]
        if part:
            print(f"{lo:.2f}-{min(hi, 1.0):.2f} | {len(part)} | {statistics.mean(r[0] for r in part):.2f} | "
                  f"{sum(r[1] > 0.1 for r in part) / len(part):.2f} | {sum(r[1] <= 0.07 for r in part)}")


def targets(args):
    groups, kind = {"matched": [], "mismatch": []}, None
    for a in args:
        if a in groups:
            kind = a
        elif a != "--":
            groups[kind].append(a)
    missing = []
    for kind, paths in groups.items():
        tot = [0] * 6
        for p in paths:
            vs = vehicles(p)
            worn = [v["clearance_alert"] for v in vs if v["clearance_true_mm"] >= 0.15]
            low = [v["clearance_alert"] for v in vs if v["clearance_true_mm"] <= 0.07]
            band = [v["clearance_alert"] for v in vs if 0.07 < v["clearance_true_mm"] < 0.1]
            for i, x in enumerate([sum(worn), len(worn), sum(low), len(low), sum(band), len(band)]):
                tot[i] += x
            if kind == "matched":
                bad = sum(worn) < 0.95 * len(worn) or sum(low) > 0.02 * len(low)
            else:
                bad = sum(low) > 0.05 * len(low) or sum(band) > 0.25 * len(band)
            if bad:
                missing.append(p)
        if paths:
            print(f"{kind}: {len(paths)} fleets; worn {tot[0]}/{tot[1]}, false {tot[2]}/{tot[3]}, "
                  f"band {tot[4]}/{tot[5]}")
    print(f"fleets missing a target: {len(missing)}: {' '.join(missing)}")


if __name__ == "__main__":
    if len(sys.argv) < 3 or sys.argv[1] not in ("widths", "bias", "reliability", "targets"):
        sys.exit(__doc__)
    {"widths": widths, "bias": bias, "reliability": reliability, "targets": targets}[sys.argv[1]](sys.argv[2:])
