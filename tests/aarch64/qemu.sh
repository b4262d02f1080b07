#!/usr/bin/env bash
# Cross-build a fixed subset of the test suite for aarch64-unknown-linux-gnu (the gateway's
# target: dynamically linked against Debian's arm64 glibc) and run it under QEMU user emulation.
# Called by tests/aarch64_qemu.rs and by .ci/run (--binfmt, --prepare).
#
# Not a test runner of its own: `cargo test --target aarch64-unknown-linux-gnu` runs the tests,
# through the runner of .cargo/config.toml; this script checks the tools, builds into its own
# target directory and prints cargo's output, then one line
#   AARCH64-SUMMARY rc=<cargo's exit status> build_s=<s> run_s=<s> tests=<names>
# Exit status 0 only if the build and every test passed.
set -euo pipefail

usage() {
    cat <<'EOF'
usage: tests/aarch64/qemu.sh [MODE]

Modes (default: --run):
  --run       build the subset for aarch64 (incrementally) and run it under QEMU
  --prepare   build only (CI does this before the tests, so the test itself mostly runs)
  --check     print what is missing to run (exit 1 if anything is), without side effects
  --binfmt    as root: mount binfmt_misc if needed and register Debian's qemu-aarch64 handler,
              so aarch64 executables that the tests start as processes run under QEMU too
  --list      print the test targets of the subset
  -h, --help  this text

Environment:
  SHIMMY_AARCH64_TARGET_DIR  cargo target dir (default <workspace>/target/aarch64)
  SHIMMY_AARCH64_SYSROOT     the arm64 loader and libc (default /usr/aarch64-linux-gnu)
EOF
}

ROOT=$(cd "$(dirname "${BASH_SOURCE[0]}")/../.." && pwd)
TRIPLE=aarch64-unknown-linux-gnu
TARGET_DIR=${SHIMMY_AARCH64_TARGET_DIR:-$ROOT/target/aarch64}
SYSROOT=${SHIMMY_AARCH64_SYSROOT:-/usr/aarch64-linux-gnu}
BINFMT_CONF=/usr/lib/binfmt.d/qemu-aarch64.conf # shipped by Debian's qemu-user-static
# The subset (why these: tests/aarch64_qemu.rs). Each is an integration test target in tests/.
TESTS=(dbc_vectors logs_candump logs_vector logs_mf4 daemon_replay journal_crash)
MODE=run
CARGO_BIN=${CARGO:-cargo} # the cargo that runs the calling test, else the one on the PATH

while [ $# -gt 0 ]; do
    case $1 in
        --run | --prepare | --check | --binfmt | --list) MODE=${1#--} ;;
        -h | --help) usage; exit 0 ;;
        *) echo "qemu.sh: unknown argument $1" >&2; usage >&2; exit 2 ;;
    esac
    shift
done

log() { echo "qemu.sh: $*" >&2; }
die() { echo "qemu.sh: error: $*" >&2; exit 1; }

qemu_bin() {
    command -v qemu-aarch64-static || command -v qemu-aarch64 || true
}

# True when the kernel hands aarch64 ELF executables to an enabled binfmt_misc handler.
binfmt_ready() {
    local f
    for f in /proc/sys/fs/binfmt_misc/*; do
        [ -f "$f" ] && [ "$(basename "$f")" != register ] && [ "$(basename "$f")" != status ] ||
            continue
        head -n1 "$f" | grep -qx enabled || continue
        grep -q '^magic 7f454c460201010000000000000000000200b700' "$f" && return 0
    done
    return 1
}

# Prints one line per missing piece; returns 1 if anything is missing.
check() {
    local missing=() sysroot
    command -v "$CARGO_BIN" >/dev/null || missing+=("cargo")
    command -v aarch64-linux-gnu-gcc >/dev/null ||
        missing+=("the cross linker aarch64-linux-gnu-gcc (apt-get install gcc-aarch64-linux-gnu)")
    [ -e "$SYSROOT/lib/ld-linux-aarch64.so.1" ] && [ -e "$SYSROOT/lib/libc.so" ] ||
        missing+=("the arm64 glibc in $SYSROOT (apt-get install libc6-dev-arm64-cross)")
    sysroot=$("${RUSTC:-rustc}" --print sysroot 2>/dev/null || true)
    compgen -G "$sysroot/lib/rustlib/$TRIPLE/lib/libstd-*.rlib" >/dev/null ||
        missing+=("Rust's std for $TRIPLE (rustup target add $TRIPLE)")
    [ -n "$(qemu_bin)" ] ||
        missing+=("qemu-aarch64-static or qemu-aarch64 (apt-get install qemu-user-static)")
    binfmt_ready ||
        missing+=("no binfmt_misc handler for aarch64 executables (as root: tests/aarch64/qemu.sh --binfmt)")
    if [ ${#missing[@]} -gt 0 ]; then
        printf '%s\n' "${missing[@]}"
        return 1
    fi
}

register_binfmt() {
    if binfmt_ready; then
        log "binfmt_misc: aarch64 handler already enabled"
        return
    fi
    [ "$(id -u)" = 0 ] || die "--binfmt needs root"
    [ -f "$BINFMT_CONF" ] || die "$BINFMT_CONF not found (apt-get install qemu-user-static)"
    if [ ! -e /proc/sys/fs/binfmt_misc/register ]; then
        mount -t binfmt_misc binfmt_misc /proc/sys/fs/binfmt_misc ||
            die "cannot mount binfmt_misc (a container without the privilege?)"
    fi
    # A registered but disabled handler is re-enabled; a missing one is registered from the
    # Debian file (flags F: the interpreter is opened now, P: argv[0] is preserved).
    if [ -e /proc/sys/fs/binfmt_misc/qemu-aarch64 ]; then
        echo 1 >/proc/sys/fs/binfmt_misc/qemu-aarch64
    else
        grep -v '^#' "$BINFMT_CONF" | head -n1 >/proc/sys/fs/binfmt_misc/register
    fi
    binfmt_ready || die "registering $BINFMT_CONF did not enable an aarch64 handler"
    log "binfmt_misc: registered $(head -n1 "$BINFMT_CONF" | cut -d: -f2) -> $(cut -d: -f7 "$BINFMT_CONF")"
}

# The environment of both cargo commands: the same one, so --prepare's build is what --run uses.
cargo_env() {
    local qemu
    qemu=$(qemu_bin)
    # A cargo that runs us (cargo test) must not leak its flags into this separate build.
    unset CARGO_ENCODED_RUSTFLAGS CARGO_TARGET_DIR CARGO_BUILD_TARGET
    # No debug info: it only slows the link; the test binaries are not debugged here.
    export CARGO_PROFILE_RELEASE_DEBUG=0
    export CARGO_TARGET_AARCH64_UNKNOWN_LINUX_GNU_LINKER=aarch64-linux-gnu-gcc
    export CARGO_TARGET_AARCH64_UNKNOWN_LINUX_GNU_RUNNER="$qemu -L $SYSROOT"
    export CC_aarch64_unknown_linux_gnu=aarch64-linux-gnu-gcc
    # Processes the tests start (shimmyd) reach QEMU through binfmt_misc; this is their root.
    export QEMU_LD_PREFIX=$SYSROOT
}

# Seconds between two `date +%s%N` stamps, to 0.1 s.
secs() { local d=$((($2 - $1) / 100000000)); echo "$((d / 10)).$((d % 10))"; }

test_args() {
    local t
    for t in "${TESTS[@]}"; do printf -- '--test\n%s\n' "$t"; done
}

build() {
    local args
    mapfile -t args < <(test_args)
    log "building for $TRIPLE into $TARGET_DIR: ${TESTS[*]}"
    (cd "$ROOT" && "$CARGO_BIN" test --release --target "$TRIPLE" --target-dir "$TARGET_DIR" \
        --no-run "${args[@]}")
}

run() {
    local args t0 t1 t2 rc=0
    mapfile -t args < <(test_args)
    t0=$(date +%s%N)
    build || {
        echo "AARCH64-SUMMARY rc=build-failed build_s=? run_s=0 tests=${TESTS[*]}"
        return 1
    }
    t1=$(date +%s%N)
    log "running under $(qemu_bin) -L $SYSROOT"
    (cd "$ROOT" && "$CARGO_BIN" test --release --target "$TRIPLE" --target-dir "$TARGET_DIR" \
        --no-fail-fast "${args[@]}") 2>&1 || rc=$?
    t2=$(date +%s%N)
    echo "AARCH64-SUMMARY rc=$rc build_s=$(secs "$t0" "$t1") run_s=$(secs "$t1" "$t2") tests=${TESTS[*]}"
    return $rc
}

case $MODE in
    list) printf '%s\n' "${TESTS[@]}" ;;
    check) check ;;
    binfmt) register_binfmt ;;
    prepare)
        check >&2 || die "cannot build for $TRIPLE (see above)"
        cargo_env
        build
        ;;
    run)
        check >&2 || die "cannot run the $TRIPLE tests (see above)"
        cargo_env
        run
        ;;
esac
