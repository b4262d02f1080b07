"""Fleet estimate error by true clearance, and how much of it sits in vehicles whose joints
hardly touch (docs/ACCURACY.md, "Tried, not kept: quiet events, table size and a finer sensor").

Reads `firmware-sim fleet --json FLEET.json --work-dir DIR` outputs (DIR holds each vehicle's
`fleet_SEED.truth.json`, whose events give the joints' contact fraction, MODEL.md §4) and prints:
per band of true clearance, the mean error, MAE and the mean and spread of ln(estimate/truth);
then, for the vehicles with c >= 0.1 mm, those whose joints were in contact at most 1 % / 3 % of
each braking window on average, and their share of the summed absolute error.

Usage: python3 docs/experiments/error_by_clearance.py FLEET.json DIR [FLEET.json DIR ...]
"""
import json
import math
import os
import sys

EDGES = [0.03, 0.05, 0.07, 0.1, 0.14, 0.2, 0.28, 0.41]


def main(args):
    rows = []
    for fleet, folder in zip(args[::2], args[1::2]):
        for v in json.load(open(fleet))["vehicles"]:
            truth = json.load(open(os.path.join(folder, f"fleet_{v['seed']}.truth.json")))
            cf = [max(e["contact_fraction"]) for e in truth["events"]]
            rows.append((v["clearance_true_mm"], v["median_mm"], sum(cf) / len(cf)))
    for lo, hi in zip(EDGES[:-1], EDGES[1:]):
        part = [r for r in rows if lo <= r[0] < hi]
        if not part:
            continue
        err = [m - c for c, m, _ in part]
        ln = [math.log(m / c) for c, m, _ in part]
        mu = sum(ln) / len(ln)
        sd = math.sqrt(sum((x - mu) ** 2 for x in ln) / len(ln))
        print(f"c {lo:.2f}-{hi:.2f}: n {len(part)}, mean error {sum(err) / len(err):+.4f}, "
              f"MAE {sum(map(abs, err)) / len(err):.4f}, ln ratio {mu:+.3f} +- {sd:.3f}")
    big = [r for r in rows if r[0] >= 0.1]
    total = sum(abs(m - c) for c, m, _ in big)
    for thr in (0.01, 0.03):
        q = [r for r in big if r[2] <= thr]
        share = sum(abs(m - c) for c, m, _ in q) / total
        mae = sum(abs(m - c) for c, m, _ in q) / max(len(q), 1)
        print(f"c >= 0.1 mm, joints in contact <= {thr:.0%} of the time: {len(q)} of {len(big)} "
              f"vehicles, MAE {mae:.3f}, share of the summed absolute error {share:.2f}")


if __name__ == "__main__":
    main(sys.argv[1:])
