#!/usr/bin/env bash
# Build the shimmy_monitor wheel and run its pytest suite (python/tests) in a virtual environment
# under target/. Called by tests/python_package.rs (--test) and by .ci/run (--prepare).
#
#   python/ci.sh --venv      create target/py-venv (reused when present) and pip-install the
#                            build and test needs (maturin, pytest, pyarrow, duckdb, pyspark,
#                            pandas); downloads cached in target/ci-tools/pip
#   python/ci.sh --wheel     build the abi3 wheel (maturin, release, in the workspace's target
#                            dir so that the dependencies its release build made are reused;
#                            SHIMMY_PY_TARGET_DIR overrides) into target/py-wheels and install
#                            it into the venv
#   python/ci.sh --prepare   --venv then --wheel (CI does this before the tests)
#   python/ci.sh --test      --venv, --wheel, then pytest python/tests (extra args go to pytest)
#   python/ci.sh --check     print what is missing (python3 with venv, java), exit 1 if anything
#
# Environment for --test (tests/python_package.rs sets them): SHIMMY_BIN, FIRMWARE_SIM_BIN,
# SHIMMY_DATA_DIR.
set -euo pipefail

ROOT=$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)
VENV=$ROOT/target/py-venv
PIP_CACHE=$ROOT/target/ci-tools/pip
WHEELS=$ROOT/target/py-wheels
PY=${PYTHON:-python3}
NEEDS=("maturin>=1.5,<2" pytest pyarrow duckdb "pyspark>=3.5" "pandas>=2,<3")

log() { echo "python/ci.sh: $*" >&2; }
die() { echo "python/ci.sh: error: $*" >&2; exit 1; }

check() {
    local missing=()
    command -v "$PY" >/dev/null || missing+=("$PY")
    "$PY" -c 'import venv, ensurepip' 2>/dev/null || missing+=("python3 venv/ensurepip (apt: python3-venv)")
    command -v java >/dev/null || missing+=("java (apt: default-jre-headless, OpenJDK 17 on Debian 12)")
    if ((${#missing[@]})); then
        echo "missing: ${missing[*]}"
        return 1
    fi
}

venv() {
    if [[ ! -x $VENV/bin/python ]]; then
        log "creating $VENV"
        rm -rf "$VENV"
        "$PY" -m venv "$VENV"
    fi
    if ! "$VENV/bin/python" -c 'import maturin, pytest, pyarrow, duckdb, pyspark, pandas' 2>/dev/null; then
        log "installing ${NEEDS[*]}"
        "$VENV/bin/python" -m pip install --quiet --cache-dir "$PIP_CACHE" "${NEEDS[@]}"
    fi
}

wheel() {
    rm -rf "$WHEELS"
    mkdir -p "$WHEELS"
    log "building the wheel"
    CARGO_TARGET_DIR=${SHIMMY_PY_TARGET_DIR:-$ROOT/target} "$VENV/bin/maturin" build --release \
        --manifest-path "$ROOT/python/Cargo.toml" --out "$WHEELS" --interpreter "$VENV/bin/python"
    local whl
    whl=$(ls "$WHEELS"/shimmy_monitor-*.whl)
    [[ $whl == *abi3* ]] || die "the wheel is not abi3: $whl"
    "$VENV/bin/python" -m pip install --quiet --no-deps --force-reinstall "$whl"
    log "installed $(basename "$whl")"
}

case ${1:-} in
    --check) check ;;
    --venv) venv ;;
    --wheel) venv; wheel ;;
    --prepare) venv; wheel ;;
    --test)
        shift
        venv
        wheel
        cd "$ROOT"
        exec "$VENV/bin/python" -m pytest python/tests -p no:cacheprovider "$@"
        ;;
    *) sed -n '2,19p' "${BASH_SOURCE[0]}"; exit 2 ;;
esac
