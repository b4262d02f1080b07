"""How far each profile's bus moves the detected event from firmware-sim's truth.

Not part of the product. For the first N vehicles of a profile's fleet (the work directory of
`firmware-sim fleet --profile P --work-dir DIR`, docs/ACCURACY.md "Tables per profile"), runs
`shimmy estimate --profile P` on each log and compares every event with the truth file:
initial speed, plateau deceleration and the steering-wheel amplitude, as mean +- SD of
(detected - true).

Usage (from the repository root, after `cargo build --release`):
  python3 docs/experiments/detector_bias.py PROFILE DIR SEED_BASE [N=5]
"""
import json
import statistics
import subprocess
import sys


def main(profile, folder, seed_base, n=5):
    dv, dd, da = [], [], []
    for seed in range(seed_base, seed_base + n):
        log = f"{folder}/fleet_{seed}.log"
        truth = json.load(open(f"{folder}/fleet_{seed}.truth.json"))["events"]
        out = subprocess.run(
            ["target/release/shimmy", "estimate", "--profile", profile, log],
            capture_output=True, text=True, check=True).stdout
        for a, t in zip(json.loads(out)["events"], truth):
            dv.append(a["v0_kmh"] - t["v0_kmh"])
            dd.append(a["decel_g"] - t["decel_g"])
            if a["sw_amplitude_deg"] is not None:
                da.append(a["sw_amplitude_deg"] - t["sw_amplitude_deg"])
    m = lambda x: f"{statistics.mean(x):+.3f} +- {statistics.pstdev(x):.3f}"  # noqa: E731
    print(f"{profile}: v0 {m(dv)} km/h, decel {m(dd)} g, amplitude {m(da)} deg ({len(dv)} events)")


if __name__ == "__main__":
    a = sys.argv[1:]
    main(a[0], a[1], int(a[2]), int(a[3]) if len(a) > 3 else 5)
