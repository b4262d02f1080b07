"""Does the wheel-order line grow with the deceleration (a brake disc) or with the speed (the
wheels' unbalance)? (docs/ACCURACY.md, "The wheel-order check".)

Not part of the product. A disc thickness variation varies the brake force, so its steering
line should grow with the deceleration (power ~ decel^2) whatever the speed; the unbalance's
force grows with the speed squared (power ~ v^4) whatever the braking. Per vehicle of a fleet,
over its used torque events with a wheel-order share above 0.02, this fits

    ln(share * rms_b^2) = a + b_decel * ln(decel_g) + b_v0 * ln(v0_kmh)

(share * rms_b^2: the line's power beyond the cruise's, approximately) and prints
S = b_decel - b_v0 / 2, which should be about +2 for a disc and -2 for an unbalance, beside the
vehicle's median share, whether it is worn (w, c >= 0.15 mm) and whether its 90 % interval
misses the truth (*).

Usage (from the repository root, after `cargo build --release`; each FLEET a `firmware-sim
fleet --work-dir`; the estimates are cached as FLEET/est_SEED.json):
  python3 docs/experiments/disc_line_scaling.py toyota_rav4 mm-91100 mm-91800 ...
"""
import glob
import json
import os
import re
import subprocess
import sys

import numpy as np


def estimate(profile, log):
    out = re.sub(r"fleet_(\d+)\.log$", r"est_\1.json", log)
    if not os.path.exists(out):
        r = subprocess.run(["target/release/shimmy", "estimate", "--profile", profile, log],
                           check=True, capture_output=True, text=True)
        open(out, "w").write(r.stdout)
    return json.load(open(out))


def vehicle(profile, log):
    r = estimate(profile, log)
    truth = json.load(open(log[:-4] + ".truth.json"))
    c = truth["clearance"]["left_mm_start"]
    ev = np.array([(e["decel_g"], e["v0_kmh"], e["torque"]["rms_bp_nm"],
                    e["torque"]["wheel_order_share"])
                   for e in r["events"]
                   if (e.get("torque") or {}).get("used")
                   and e["torque"].get("wheel_order_share") is not None])
    lo, hi = r["interval_mm"] or (0.0, 0.0)
    s = float("nan")
    med = float(np.median(ev[:, 3])) if len(ev) else float("nan")
    if len(ev):
        m = ev[:, 3] > 0.02
        if m.sum() >= 8:
            x = np.c_[np.ones(m.sum()), np.log(ev[m, 0]), np.log(ev[m, 1])]
            b, *_ = np.linalg.lstsq(x, np.log(ev[m, 3] * ev[m, 2] ** 2), rcond=None)
            s = b[1] - b[2] / 2
    return c, med, s, not (lo <= c <= hi)


def main():
    if len(sys.argv) < 3:
        sys.exit(__doc__)
    profile = sys.argv[1]
    for fleet in sys.argv[2:]:
        rows = [vehicle(profile, log) for log in sorted(glob.glob(f"{fleet}/fleet_*.log"))]
        rows.sort(key=lambda r: -np.nan_to_num(r[2], nan=-99.0))
        print(f"{fleet}: {len(rows)} vehicles, {sum(r[3] for r in rows)} intervals miss;"
              " S (median share), highest first")
        print("  " + " ".join(f"{s:+.1f}{'*' if miss else ''}{'w' if c >= 0.15 else ''}({med:.2f})"
                              for c, med, s, miss in rows if not np.isnan(s)))
        print(f"  no S (fewer than 8 events with a share above 0.02): "
              f"{sum(np.isnan(r[2]) for r in rows)}")


if __name__ == "__main__":
    main()
