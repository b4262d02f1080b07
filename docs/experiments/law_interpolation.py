"""How much does the law lose by interpolating in ln c between the table's clearances? (docs/ACCURACY.md)

Not part of the product. Reads a response table's `linear` model (coefficients per clearance,
speed, feature and term; src/observer/linear.rs), evaluates each feature's mean at 400 random
nuisance points (coordinates uniform on [-1, 1], the phase cosine uniform on [-1, 1],
deceleration -1/0/+1 scaled), and takes the second difference over neighbouring clearances:
linear interpolation at the middle of a step misses |second difference| / 8. Beside it, the
table's own per-vehicle misfit (sqrt of between[c][0][0]) and event scatter over 30 events
(sqrt of within[c][0][0] / 30), for ln RMS.

Usage (numpy): python3 docs/experiments/law_interpolation.py config/vehicles/shimmy_reference/table.json
"""
import json
import sys

import numpy as np


def basis(terms, x, u, d):
    v = {f"x{i}": x[i] for i in range(7)}
    v.update(u=u, d=d)
    out = []
    for term in terms:
        p = 1.0
        if term != "1":
            for factor in term.split("*"):
                name, _, power = factor.partition("^")
                p *= v[name] ** int(power or 1)
        out.append(p)
    return np.array(out)


def main(path):
    t = json.load(open(path))
    law = t["linear"]
    nc, nv, nk = len(t["clearance_mm"]), len(t["speed_kmh"]), len(law["terms"])
    coef = np.array(law["coef"]).reshape(nc, nv, 3, nk)
    rng = np.random.default_rng(1)
    b = np.array(
        [
            basis(law["terms"], rng.uniform(-1, 1, 7), rng.uniform(-1, 1), rng.choice([-1.0, 0.0, 1.0]))
            for _ in range(400)
        ]
    )
    mean = np.einsum("cvfk,nk->cvfn", coef, b)
    err = np.abs(mean[2:] - 2 * mean[1:-1] + mean[:-2]) / 8
    print("clearance (mm)          ", " ".join(f"{c:6.3f}" for c in t["clearance_mm"][1:-1]))
    for f, name in enumerate(["ln RMS", "ln peak", "cruise"]):
        med = np.median(err[:, :, f, :], axis=(1, 2))
        print(f"{name:<8} median |err|    ", " ".join(f"{x:6.4f}" for x in med))
    within = np.sqrt(np.array(law["within"])[1:-1, 0, 0] / 30)
    between = np.sqrt(np.array(law["between"])[1:-1, 0, 0])
    print("ln RMS misfit sd (eta)  ", " ".join(f"{x:6.3f}" for x in between))
    print("ln RMS event sd / sqrt30", " ".join(f"{x:6.3f}" for x in within))


if __name__ == "__main__":
    main(sys.argv[1])
