"""Two looks at a table build's `shimmy calibrate --events-out` file (docs/ACCURACY.md, "Tried, not
kept: quiet events, table size and a finer sensor").

  subset EV.json N OUT.json  the events of the first N drawn vehicles, in job order, with their
                             seeds renumbered to the smaller grid's jobs, so that
                             `shimmy calibrate --events-in OUT.json --vehicles N` re-fits on them
  quiet EV.json              per table clearance, the share of events whose ln RMS statistic is
                             below the quiet bound 0.5 ln((1.5 * 0.01943)^2 + 0.02^2) (1.5 times
                             the reference sensor's noise RMS in the band), and how many drawn
                             vehicles are quiet in more than 90 % of their events there
"""
import json
import math
import sys

SEED_OFFSET = 10_000  # src/cli/calibrate.rs `jobs`: seed = seed_base + 10 000 + job index


def subset(path, n, out):
    e = json.load(open(path))
    m = e["grid"].split("vehicles ")[1].split(",")[0]
    base = int(e["grid"].split("seed_base ")[1].split(",")[0])
    e["grid"] = e["grid"].replace(f"vehicles {m},", f"vehicles {n},", 1)
    e["events"] = [x for x in e["events"] if x["raw"]["im"] < n]
    for k, x in enumerate(e["events"]):
        x["seed"] = base + SEED_OFFSET + k
    json.dump(e, open(out, "w"))
    print(f"{len(e['events'])} events of {n} vehicles -> {out}")


def quiet(path):
    bound = 0.5 * math.log((1.5 * 0.01943) ** 2 + 0.02 ** 2)
    ev = json.load(open(path))["events"]
    by = {}
    for x in ev:
        r = x["raw"]
        by.setdefault(r["ic"], {}).setdefault(r["im"], []).append(r["z"][0] < bound)
    print(f"quiet bound {bound:.3f}")
    for ic in sorted(by):
        flags = [f for v in by[ic].values() for f in v]
        mostly = sum(sum(v) / len(v) > 0.9 for v in by[ic].values())
        print(f"clearance index {ic}: quiet {sum(flags) / len(flags):.2f} of events, "
              f"{mostly} of {len(by[ic])} vehicles quiet in > 90 % of theirs")


if __name__ == "__main__":
    if sys.argv[1] == "subset":
        subset(sys.argv[2], int(sys.argv[3]), sys.argv[4])
    else:
        quiet(sys.argv[2])
