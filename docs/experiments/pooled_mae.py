"""Pooled MAE (c >= 0.1 mm) over several fleets' `--json` files, with a bootstrap interval.

Not part of the product. Resamples the pooled vehicles (20 000 draws, seed 0) and prints the
MAE, the median absolute error, the 95 % bootstrap interval of the MAE and the share of draws
at or below 0.02 mm (the issue's target).

Usage (numpy): python3 docs/experiments/pooled_mae.py fleet6000.json fleet6100.json ...
"""
import json
import sys

import numpy as np

errors = []
for path in sys.argv[1:]:
    vehicles = json.load(open(path))["vehicles"]
    e = [
        abs(v["median_mm"] - v["clearance_true_mm"])
        for v in vehicles
        if v["clearance_true_mm"] >= 0.1 and v["median_mm"] is not None
    ]
    print(f"{path}: {len(e)} vehicles, MAE {np.mean(e):.4f}")
    errors += e
errors = np.array(errors)
rng = np.random.default_rng(0)
boot = np.array([rng.choice(errors, len(errors)).mean() for _ in range(20000)])
lo, hi = np.percentile(boot, [2.5, 97.5])
print(
    f"pooled: {len(errors)} vehicles, MAE {errors.mean():.4f}, median {np.median(errors):.4f}, "
    f"95 % bootstrap [{lo:.4f}, {hi:.4f}], share of draws <= 0.02: {np.mean(boot <= 0.02):.4f}"
)
