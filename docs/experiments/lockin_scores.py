"""Figures of the order-tracking experiment (docs/ACCURACY.md, "tried, not kept").

Not part of the product. Three reports:

  bands FLEET.json [FLEET.json ...]
      Over the vehicles of `firmware-sim fleet --json` files, split at c = 0.1 mm: MAE of the
      posterior median, mean ln(q95/q05) of the 90 % interval, intervals holding the truth.
  law TABLE.json [SPEED_KMH]
      The intercept (ξ = 0, ψ = 0, d = 0.55 g) of each feature of a table's nuisance model at
      one grid speed (default 55), per clearance, and each feature's total event spread.
      Works for the shipped three-feature tables and the patch's five-feature ones.
  drift [V0_KMH DECEL_G]
      The share of a lock-in amplitude kept when the spin phase is off by a relative scale
      error (speed signal or R_w) of 1 % and 3 %, over a stop from V0 at DECEL (default 55 km/h,
      0.55 g; 100 Hz samples while the wheel spins at 3 Hz or more; R_w = 0.30 m).
"""
import json
import math
import sys


def bands(paths):
    rows = [v for p in paths for v in json.load(open(p))["vehicles"]]
    for name, keep in (("c < 0.1", lambda c: c < 0.1), ("c >= 0.1", lambda c: c >= 0.1)):
        r = [v for v in rows if keep(v["clearance_true_mm"])]
        mae = sum(abs(v["median_mm"] - v["clearance_true_mm"]) for v in r) / len(r)
        width = sum(math.log(v["interval_mm"][1] / v["interval_mm"][0]) for v in r) / len(r)
        held = sum(v["interval_mm"][0] <= v["clearance_true_mm"] <= v["interval_mm"][1] for v in r)
        print(f"{name}: n {len(r)}, MAE {mae:.4f} mm, mean ln(q95/q05) {width:.2f}, "
              f"covered {held}/{len(r)}")


def law(path, speed=55.0):
    t = json.load(open(path))
    lm, speeds = t["linear"], t["speed_kmh"]
    n_feat = len(lm["total_std"][0])
    nk, nv = len(lm["terms"]), len(speeds)
    iv = min(range(nv), key=lambda i: abs(speeds[i] - speed))
    print(f"speed {speeds[iv]} km/h, {n_feat} features; intercept per feature, then spread")
    for ic, c in enumerate(t["clearance_mm"]):
        a = [lm["coef"][((ic * nv + iv) * n_feat + f) * nk] for f in range(n_feat)]
        print(f"{c:.3f} mm  " + " ".join(f"{x:6.2f}" for x in a) + "   spread "
              + " ".join(f"{s:.2f}" for s in lm["total_std"][ic]))


def drift(v0_kmh=55.0, decel_g=0.55, r_w=0.30, fs=100.0):
    v, x, xs = v0_kmh / 3.6, 0.0, []
    while v > 0:
        if v / (2 * math.pi * r_w) >= 3.0:
            xs.append(x)
        x += v / fs
        v -= decel_g * 9.80665 / fs
    turns = (xs[-1] - xs[0]) / (2 * math.pi * r_w)
    for e in (0.01, 0.03):
        re = sum(math.cos(e * p / r_w) for p in xs)
        im = sum(math.sin(e * p / r_w) for p in xs)
        print(f"{v0_kmh} km/h, {decel_g} g: {turns:.1f} turns above 3 Hz; scale error "
              f"{e:.0%}: {math.hypot(re, im) / len(xs):.1%} of the amplitude kept")


if __name__ == "__main__":
    cmd, args = sys.argv[1], sys.argv[2:]
    if cmd == "bands":
        bands(args)
    elif cmd == "law":
        law(args[0], *map(float, args[1:]))
    elif cmd == "drift":
        drift(*map(float, args))
    else:
        sys.exit(__doc__)
