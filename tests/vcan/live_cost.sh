#!/usr/bin/env bash
# The cost of shimmyd's live SocketCAN path, in one command: boots the vcan VM of vm.sh (or uses
# this host's vcan0 with --host), runs tests/shimmyd_load_vcan.rs there for SECONDS at FPS
# frames/s (the daemon's CPU share, RSS, wake-ups, kernel drops: its LIVE-COST lines), runs the
# same fixed CPU workload (shimmyd --replay --fast of the load as a log: LIVE-CALIBRATION) in
# the VM and on this host, and prints the VM's CPU numbers scaled to this host's speed.
#
# Not a test: it asserts nothing beyond what the load tests assert (every frame read, no kernel
# drop). The numbers go to docs/BENCHMARKS.md ("Live SocketCAN path").
set -euo pipefail

usage() {
    cat <<'EOF'
usage: tests/vcan/live_cost.sh [--seconds S] [--fps N] [--smp N] [--host]

  --seconds S   load duration per shape (default 60)
  --fps N       frames per second on the bus (default 8000)
  --smp N       virtual CPUs of the VM (default 1: sender and daemon share one; 2 lets the
                sender reach rates one emulated CPU cannot)
  --host        run on this host's vcan0 instead of the QEMU VM (no calibration needed:
                the scale is 1)

Prints the VM's console, then one summary block. Needs what tests/vcan/vm.sh --check lists.
EOF
}

ROOT=$(cd "$(dirname "${BASH_SOURCE[0]}")/../.." && pwd)
SECONDS_LOAD=60 FPS=8000 MODE=--vm
while [ $# -gt 0 ]; do
    case $1 in
        --seconds) SECONDS_LOAD=$2; shift ;;
        --fps) FPS=$2; shift ;;
        --smp) export SHIMMY_VCAN_SMP=$2; shift ;;
        --host) MODE=--host ;;
        -h | --help) usage; exit 0 ;;
        *) echo "live_cost.sh: unknown argument $1" >&2; usage >&2; exit 2 ;;
    esac
    shift
done

ENVS="SHIMMY_LIVE_LOAD_S=$SECONDS_LOAD SHIMMY_LIVE_LOAD_FPS=$FPS"
OUT=$(mktemp)
trap 'rm -f "$OUT"' EXIT
# Longer than the suite's defaults: two loads of SECONDS each, the catch-up, the calibration.
export SHIMMY_VCAN_CMD_TIMEOUT=$((SECONDS_LOAD * 4 + 300))
export SHIMMY_VCAN_VM_TIMEOUT=$((SECONDS_LOAD * 8 + 900))
bash "$ROOT/tests/vcan/vm.sh" "$MODE" \
    --step '-p firmware-sim --bin firmware-sim | -' \
    --step '--bin shimmyd | -' \
    --step "--test shimmyd_load_vcan | $ENVS shimmyd_load_vcan --test-threads=1 --nocapture" \
    --step "--test shimmyd_load_vcan | $ENVS shimmyd_load_vcan --ignored --exact replay_cpu_calibration --nocapture" \
    --step 'copy dbc/shimmy_reference.dbc' \
    --step 'copy config/vehicles/shimmy_reference/mapping.toml' \
    --step 'copy config/vehicles/shimmy_reference/table.json' \
    --step 'copy config/vehicle' \
    --step 'copy config/scenarios/vcan_0p4mm.toml' | tee "$OUT"

host_cal=""
if [ "$MODE" = --vm ]; then
    echo "live_cost.sh: the same calibration workload on this host" >&2
    host_cal=$(cd "$ROOT" && env $ENVS cargo test --release --test shimmyd_load_vcan -- \
        --ignored --exact replay_cpu_calibration --nocapture 2>/dev/null |
        grep -ao 'LIVE-CALIBRATION .*' || true)
fi

echo
echo "==== live SocketCAN path: $FPS frames/s for $SECONDS_LOAD s ($MODE) ===="
grep -ao 'LIVE-COST .*' "$OUT" || echo "no LIVE-COST line (see the console above)"
vm_cal=$(grep -ao 'LIVE-CALIBRATION .*' "$OUT" || true)
echo "calibration in the VM:   ${vm_cal:-none}"
if [ "$MODE" = --vm ]; then
    echo "calibration on the host: ${host_cal:-none}"
    best() { sed -n 's/.*replay_cpu_s_best=\([0-9.]*\).*/\1/p' <<<"$1"; }
    v=$(best "$vm_cal") h=$(best "$host_cal")
    if [ -n "$v" ] && [ -n "$h" ]; then
        grep -ao 'LIVE-COST .*' "$OUT" | while read -r line; do
            awk -v v="$v" -v h="$h" -v l="$line" 'BEGIN {
                match(l, /test=[^ ]*/); t = substr(l, RSTART + 5, RLENGTH - 5)
                match(l, /cpu_pct=[0-9.]*/); c = substr(l, RSTART + 8, RLENGTH - 8)
                printf "%s: %.2f %% of one emulated core in the VM; VM/host CPU ratio %.1f -> %.3f %% of one host core\n", t, c, v / h, c * h / v }'
        done
    fi
fi
