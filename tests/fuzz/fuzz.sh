#!/usr/bin/env bash
# Build and run the coverage-guided fuzz targets of tests/fuzz (cargo-fuzz, libFuzzer) on the
# nightly toolchain. Called by tests/fuzz_targets.rs and by .ci/run (--install, --prepare).
#
# Not a test runner of its own: it runs one target for a time budget and prints libFuzzer's
# output, then one line
#   FUZZ-SUMMARY target=<name> rc=<exit status> runs=<executions> seconds=<budget>
# Exit status 0 only if the target ran its budget without a crash, leak, timeout or OOM.
# New inputs the fuzzer finds go to a scratch corpus under the target dir, never to the seeds
# in tests/fuzz/corpus; a crashing input is saved as target/fuzz/artifacts/<target>/crash-*.
set -euo pipefail

usage() {
    cat <<'USAGE'
usage: tests/fuzz/fuzz.sh [MODE]

Modes:
  --run TARGET SECONDS   run one target for SECONDS (builds it first, incrementally)
  --prepare              build every target (CI does this before the tests)
  --install              install nightly (minimal profile) and cargo-fuzz into target/ci-tools
                         when missing (needs the network once; cached afterwards)
  --check                print what is missing to run (exit 1 if anything is), no side effects
  --list                 print the targets
  -h, --help             this text

Environment:
  SHIMMY_FUZZ_TARGET_DIR  cargo target dir of the fuzz build (default <workspace>/target/fuzz)
USAGE
}

ROOT=$(cd "$(dirname "${BASH_SOURCE[0]}")/../.." && pwd)
FUZZ_DIR=$ROOT/tests/fuzz
TARGET_DIR=${SHIMMY_FUZZ_TARGET_DIR:-$ROOT/target/fuzz}
TOOLS=$ROOT/target/ci-tools
TARGETS=(candump asc trc blf dbc journal)
export PATH=$TOOLS/bin:$PATH

log() { echo "fuzz.sh: $*" >&2; }
die() { echo "fuzz.sh: error: $*" >&2; exit 1; }

# The calling `cargo test` exports its toolchain and flags; the fuzz build is its own.
unset RUSTUP_TOOLCHAIN RUSTC RUSTDOC RUSTC_WRAPPER RUSTFLAGS CARGO_ENCODED_RUSTFLAGS \
    CARGO_TARGET_DIR CARGO_BUILD_TARGET CARGO CARGO_MANIFEST_DIR OUT_DIR 2>/dev/null || true

missing() {
    local m=()
    command -v rustup >/dev/null || m+=("rustup")
    if command -v rustup >/dev/null && ! rustup run nightly rustc --version >/dev/null 2>&1; then
        m+=("the nightly toolchain (rustup toolchain install nightly --profile minimal)")
    fi
    command -v cargo-fuzz >/dev/null ||
        m+=("cargo-fuzz (cargo install --locked cargo-fuzz --root target/ci-tools)")
    local IFS=';'
    echo "${m[*]}"
}

fuzz() {
    (cd "$ROOT" && rustup run nightly cargo fuzz "$@")
}

MODE=${1:-}
case $MODE in
    --check)
        m=$(missing)
        [ -z "$m" ] || { echo "$m"; exit 1; }
        ;;
    --list) printf '%s\n' "${TARGETS[@]}" ;;
    --install)
        command -v rustup >/dev/null || die "rustup is needed"
        rustup run nightly rustc --version >/dev/null 2>&1 ||
            rustup toolchain install nightly --profile minimal
        command -v cargo-fuzz >/dev/null ||
            cargo install --locked cargo-fuzz --root "$TOOLS"
        ;;
    --prepare)
        m=$(missing)
        [ -z "$m" ] || die "missing: $m"
        t0=$(date +%s)
        fuzz build --fuzz-dir "$FUZZ_DIR" --target-dir "$TARGET_DIR"
        log "built ${#TARGETS[@]} targets in $(($(date +%s) - t0)) s"
        ;;
    --run)
        [ $# -eq 3 ] || { usage >&2; exit 2; }
        target=$2 secs=$3
        m=$(missing)
        [ -z "$m" ] || die "missing: $m"
        work=$TARGET_DIR/corpus/$target
        art=$TARGET_DIR/artifacts/$target
        mkdir -p "$work" "$art"
        out=$(mktemp)
        trap 'rm -f "$out"' EXIT
        rc=0
        # -rss_limit_mb and -timeout: an input using more than 1 GiB or taking more than
        # 10 s is a finding, not a slow run.
        fuzz run --fuzz-dir "$FUZZ_DIR" --target-dir "$TARGET_DIR" "$target" \
            "$work" "$FUZZ_DIR/corpus/$target" -- \
            -max_total_time="$secs" -timeout=10 -rss_limit_mb=1024 \
            -artifact_prefix="$art/" -print_final_stats=1 2>&1 | tee "$out" || rc=$?
        runs=$(sed -n 's/^stat::number_of_executed_units: *\([0-9]*\).*/\1/p' "$out" | tail -1)
        echo "FUZZ-SUMMARY target=$target rc=$rc runs=${runs:-0} seconds=$secs"
        exit "$rc"
        ;;
    -h | --help) usage ;;
    *) usage >&2; exit 2 ;;
esac
