#!/usr/bin/env bash
# The model runs of the feature oracle (docs/experiments/feature_oracle.py, docs/ACCURACY.md).
#
# Usage, from the repository root, after the dev fleets' logs exist (docs/ACCURACY.md):
#   docs/experiments/feature_oracle_runs.sh ORC DIR [DIR ...]
# For every vehicle of each fleet work dir DIR with a true clearance of 0.1 mm or more, it
# drives the same vehicle again at 10 clearances (0.03-0.4 mm, log-spaced) x 4 noise replicates
# (`firmware-sim fleet --clearance-mm C --replicate r`) and reads each drive's events back with
# `shimmy estimate` (no table) into ORC/cI_rR/ev_SEED.json; the vehicle's own log goes to
# ORC/obs/ev_SEED.json, and ORC/plan.json lists the grid and the vehicles. The 2720 drives of
# the two dev fleets (68 vehicles) took 56 min on two cores; the logs (4.9 MB each) are removed.
# Then:
#   python3 docs/experiments/feature_oracle.py ORC ORC/plan.json [FLEET.json DIR ...]
set -euo pipefail
orc=$1
shift
mkdir -p "$orc/obs"
python3 - "$orc" "$@" <<'EOF'
import glob, json, os, sys
orc, dirs = sys.argv[1], sys.argv[2:]
sel = []
for d in dirs:
    for f in sorted(glob.glob(os.path.join(d, "fleet_*.eval.json"))):
        e = json.load(open(f))
        if e["clearance_true_mm"] >= 0.1 and e.get("replicate", 0) == 0:
            sel.append([os.path.abspath(d), e["seed"]])
grid = [0.03 * (0.4 / 0.03) ** (i / 9) for i in range(10)]
json.dump({"grid": grid, "sel": sel}, open(os.path.join(orc, "plan.json"), "w"))
with open(os.path.join(orc, "jobs.txt"), "w") as f:
    for d, s in sel:
        for i, c in enumerate(grid):
            for r in range(1, 5):
                f.write(f"{s} {c:.6f} {r} c{i}_r{r}\n")
print(f"{len(sel)} vehicles, {len(sel) * 40} drives", file=sys.stderr)
EOF
# the vehicles' own drives
python3 -c 'import json,sys; [print(d, s) for d, s in json.load(open(sys.argv[1]))["sel"]]' \
    "$orc/plan.json" | while read -r d s; do
    target/release/shimmy estimate --mapping config/vehicles/shimmy_reference/mapping.toml \
        --config config/observer.toml "$d/fleet_$s.log" > "$orc/obs/ev_$s.json"
done
one() {  # SEED C R DIR
    local w="$ORC/$4"
    mkdir -p "$w"
    target/release/firmware-sim fleet --table config/vehicles/shimmy_reference/table.json \
        --config config/observer.toml --vehicles 1 --events 30 --seed-base "$1" \
        --clearance-mm "$2" --replicate "$3" --work-dir "$w" --logs-only --threads 1 > /dev/null
    target/release/shimmy estimate --mapping config/vehicles/shimmy_reference/mapping.toml \
        --config config/observer.toml "$w/fleet_$1.log" > "$w/ev_$1.json"
    rm -f "$w/fleet_$1.log"
}
export -f one
export ORC=$orc
xargs -P "$(nproc)" -L1 bash -c 'one "$@"' _ < "$orc/jobs.txt"
