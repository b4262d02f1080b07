#!/usr/bin/env bash
# Run the vcan test suite (tests/vcan/suite.txt) against a real kernel CAN bus: inside a small
# QEMU VM when this host's kernel has no CAN (the recipe of ../shared/vcan/README.md), or on the
# host itself with --host. Called by tests/vcan_vm.rs and by .ci/run (--prepare).
#
# Not a test runner of its own: it builds, boots, runs the suite's commands, and reports each
# command's exit status as a machine-readable line:
#   SHIMMY-VM-RESULT step=<n> rc=<exit status> cmd=<command>
# and finally `SHIMMY-VM-SUMMARY ...`. Exit status 0 only if every command exited 0.
set -euo pipefail

usage() {
    cat <<'EOF'
usage: tests/vcan/vm.sh [MODE] [--suite FILE] [--step 'SELECTOR | COMMAND']...

Modes (default: --vm):
  --vm        fetch the kernel if needed, build the suite's binaries, build the initramfs, boot QEMU
              and run the suite inside it (vcan0 is created there)
  --host      build the suite's binaries and run the suite on this host, which must have a CAN
              interface (SHIMMY_VCAN_IF, default vcan0)
  --fetch     only download Debian's kernel + CAN modules into the cache
  --prepare   fetch and build, without running anything (CI does this before the tests)
  --check     print what is missing to run --vm (exit 1 if anything is), without side effects

Options:
  --suite FILE   steps to run (default tests/vcan/suite.txt)
  --step LINE    a step in suite syntax; when given, replaces the suite file's steps
  -h, --help     this text

Environment:
  SHIMMY_VCAN_CACHE        kernel/initramfs cache (default <workspace>/target/vcan-vm)
  SHIMMY_VCAN_TARGET_DIR   cargo target dir of the build (default: cargo's, i.e. the workspace's)
  SHIMMY_VCAN_KERNEL_PKG   Debian kernel package (default: what linux-image-amd64 depends on)
  SHIMMY_VCAN_CMD_TIMEOUT  seconds per command inside the VM (default 300)
  SHIMMY_VCAN_VM_TIMEOUT   seconds for the whole VM run, host side (default 900)
  SHIMMY_VCAN_SMP          virtual CPUs of the VM (default 1; tests/vcan/live_cost.sh --smp 2
                           gives the load test's sender a CPU of its own, multi-threaded TCG)
  SHIMMY_VCAN_LOAD_S       passed into the VM (seconds of reference bus traffic in live_vcan)

Steps find the suite's firmware-sim through SHIMMY_FWSIM_BIN (set here when it is built).
EOF
}

ROOT=$(cd "$(dirname "${BASH_SOURCE[0]}")/../.." && pwd)
CACHE=${SHIMMY_VCAN_CACHE:-$ROOT/target/vcan-vm}
SUITE=$ROOT/tests/vcan/suite.txt
CMD_TIMEOUT=${SHIMMY_VCAN_CMD_TIMEOUT:-300}
VM_TIMEOUT=${SHIMMY_VCAN_VM_TIMEOUT:-900}
SMP=${SHIMMY_VCAN_SMP:-1}
TRIPLE=x86_64-unknown-linux-gnu
MODULES=(can can-raw can-dev vcan) # load order matters: vcan needs can-dev
MODE=vm
EXTRA_STEPS=()

while [ $# -gt 0 ]; do
    case $1 in
        --vm | --host | --fetch | --prepare | --check) MODE=${1#--} ;;
        --suite) SUITE=$2; shift ;;
        --step) EXTRA_STEPS+=("$2"); shift ;;
        -h | --help) usage; exit 0 ;;
        *) echo "vm.sh: unknown argument $1" >&2; usage >&2; exit 2 ;;
    esac
    shift
done

log() { echo "vm.sh: $*" >&2; }
die() { echo "vm.sh: error: $*" >&2; exit 1; }
# True when the ELF file asks for a dynamic loader (has a PT_INTERP program header).
dynamic_elf() {
    local f=$1 phoff phentsize phnum i t
    phoff=$(od -An -t u8 -j 32 -N 8 "$f" | tr -d ' ')
    phentsize=$(od -An -t u2 -j 54 -N 2 "$f" | tr -d ' ')
    phnum=$(od -An -t u2 -j 56 -N 2 "$f" | tr -d ' ')
    for ((i = 0; i < phnum; i++)); do
        t=$(od -An -t u4 -j $((phoff + i * phentsize)) -N 4 "$f" | tr -d ' ')
        [ "$t" != 3 ] || return 0
    done
    return 1
}
trim() { local s=$1; s=${s#"${s%%[![:space:]]*}"}; s=${s%"${s##*[![:space:]]}"}; printf '%s' "$s"; }

# ---- suite ------------------------------------------------------------------------------------
SELECTORS=() COMMANDS=() COPIES=()
read_suite() {
    local lines=() line
    if [ ${#EXTRA_STEPS[@]} -gt 0 ]; then
        lines=("${EXTRA_STEPS[@]}")
    else
        [ -f "$SUITE" ] || die "suite file $SUITE not found"
        mapfile -t lines <"$SUITE"
    fi
    for line in "${lines[@]}"; do
        line=$(trim "${line%%#*}")
        [ -n "$line" ] || continue
        if [[ $line == copy\ * ]]; then
            COPIES+=("$(trim "${line#copy }")")
            continue
        fi
        [[ $line == *"|"* ]] || die "suite line without '|': $line"
        SELECTORS+=("$(trim "${line%%|*}")")
        COMMANDS+=("$(trim "${line#*|}")")
    done
    [ ${#SELECTORS[@]} -gt 0 ] || die "no steps in $SUITE"
}

# ---- kernel -------------------------------------------------------------------------------------
KDIR=$CACHE/kernel
kernel_ready() { [ -f "$KDIR/ready" ] && [ -f "$KDIR/vmlinuz" ]; }

fetch_kernel() {
    if kernel_ready; then
        log "kernel cached: $(cat "$KDIR/ready")"
        return
    fi
    command -v apt-get >/dev/null || die "apt-get not found: fetch needs a Debian-like host"
    command -v dpkg-deb >/dev/null || die "dpkg-deb not found"
    local pkg=${SHIMMY_VCAN_KERNEL_PKG:-}
    if [ -z "$pkg" ]; then
        # linux-image-amd64 is a metapackage: the real image is its versioned dependency.
        pkg=$(apt-cache depends linux-image-amd64 2>/dev/null |
            awk '/Depends: linux-image-[0-9]/ { print $2; exit }')
        [ -n "$pkg" ] || die "cannot resolve linux-image-amd64 (run apt-get update first)"
    fi
    [[ $pkg != *cloud* ]] || die "$pkg: the cloud kernel flavour has no CAN; use the plain amd64 one"
    log "fetching $pkg (Debian kernel with CAN modules)"
    local dl=$CACHE/download
    rm -rf "$dl" "$KDIR"
    mkdir -p "$dl" "$KDIR"
    (cd "$dl" && apt-get download "$pkg" >&2) || die "apt-get download $pkg failed"
    local deb
    deb=$(ls "$dl"/*.deb)
    mkdir -p "$dl/x"
    # Only the kernel image and the four CAN modules are needed, not the whole package.
    dpkg-deb --fsys-tarfile "$deb" |
        tar -x -C "$dl/x" --wildcards './boot/vmlinuz-*' '*/kernel/net/can/can.ko*' \
            '*/kernel/net/can/can-raw.ko*' '*/kernel/drivers/net/can/dev/can-dev.ko*' \
            '*/kernel/drivers/net/can/vcan.ko*'
    cp "$(ls "$dl"/x/boot/vmlinuz-* | head -n1)" "$KDIR/vmlinuz"
    local m f
    for m in "${MODULES[@]}"; do
        f=$(find "$dl/x" -name "$m.ko*" | head -n1)
        [ -n "$f" ] || die "$pkg has no $m module"
        case $f in
            *.ko) cp "$f" "$KDIR/$m.ko" ;;
            *.ko.xz) xz -dc "$f" >"$KDIR/$m.ko" ;;
            *.ko.zst) zstd -qdc "$f" >"$KDIR/$m.ko" ;;
            *.ko.gz) gzip -dc "$f" >"$KDIR/$m.ko" ;;
            *) die "unknown module format $f" ;;
        esac
    done
    echo "$pkg ($(basename "$deb"))" >"$KDIR/ready"
    rm -rf "$dl"
    log "kernel ready: $(cat "$KDIR/ready")"
}

# ---- binaries -------------------------------------------------------------------------------------
# The suite's executables come from the workspace's own release build, the one the test command
# (`cargo test --workspace --release`) makes: built here with exactly its arguments and `--no-run`,
# so under CI this build *is* the test command's build (prepared once, reused by it and by the VM
# test), and outside CI it is what `cargo test` would have built anyway. The executables are
# dynamically linked; the initramfs gets the loader and the shared libraries ldd names for them,
# copied from this host at the same paths, and the executables without their debug info.
BIN_NAMES=() BIN_PATHS=()
build_bins() {
    local cargo=${CARGO:-cargo} i json exe
    # A cargo that runs us (cargo test) must not leak its flags into this build.
    unset CARGO_ENCODED_RUSTFLAGS CARGO_BUILD_TARGET OUT_DIR
    [ -z "${SHIMMY_VCAN_TARGET_DIR:-}" ] || export CARGO_TARGET_DIR=$SHIMMY_VCAN_TARGET_DIR
    command -v python3 >/dev/null || die "python3 not found (it reads cargo's JSON messages)"
    log "build: cargo test --workspace --release --no-run"
    json=$(cd "$ROOT" && "$cargo" test --workspace --release --no-run \
        --message-format=json-render-diagnostics) || die "cargo build of the workspace failed"
    local sel out
    for i in "${!SELECTORS[@]}"; do
        sel=${SELECTORS[$i]}
        # Picks the one executable the selector names from cargo's compiler-artifact messages:
        # `--test NAME` an integration test, `--bin NAME` a binary (not its unit tests);
        # `-p PACKAGE` narrows to that package.
        out=$(python3 -c '
import json, sys
args = sys.argv[1].split()
pkg = kind = name = None
while args:
    a = args.pop(0)
    if a in ("-p", "--package"): pkg = args.pop(0)
    elif a in ("--test", "--bin"): kind, name = a[2:], args.pop(0)
    else: sys.exit(f"unknown selector argument {a!r}")
if name is None: sys.exit("selector names no --test or --bin")
found = set()
for line in sys.stdin:
    if not line.startswith("{"): continue
    m = json.loads(line)
    if m.get("reason") != "compiler-artifact" or not m.get("executable"): continue
    t = m["target"]
    if t["name"] != name or kind not in t["kind"]: continue
    if kind == "bin" and m["profile"]["test"]: continue
    pid = m["package_id"]
    if pkg and not (f"/{pkg}#" in pid or f"#{pkg}@" in pid or pid.startswith(f"{pkg} ")): continue
    found.add(m["executable"])
if len(found) != 1: sys.exit(f"{len(found)} executables match: {sorted(found)}")
print(found.pop())
' "$sel" <<<"$json") || die "selector '$sel': ${out:-no executable}"
        BIN_NAMES+=("$(sed 's/.*--\(test\|bin\) *\([^ ]*\).*/\2/' <<<"$sel")")
        BIN_PATHS+=("$out")
        log "built ${BIN_NAMES[$i]} <- $out"
    done
}

# Copies executable $1 to $2 without debug info, and the shared libraries it loads (with the
# dynamic loader) into the tree rooted at $3, at the paths they have on this host.
install_exe() {
    local src=$1 dst=$2 root=$3 lib
    if command -v objcopy >/dev/null; then
        objcopy --strip-debug "$src" "$dst"
    else
        cp "$src" "$dst"
    fi
    dynamic_elf "$src" || return 0
    command -v ldd >/dev/null || die "ldd not found: cannot put $src's shared libraries into the VM"
    while IFS= read -r lib; do
        [ -e "$root$lib" ] && continue
        mkdir -p "$root$(dirname "$lib")"
        cp -L "$lib" "$root$lib"
    done < <(ldd "$src" | grep -o '/[^ ]*' | sort -u)
}

# True when the suite built an executable named $1.
has_bin() {
    local n
    for n in "${BIN_NAMES[@]}"; do [ "$n" != "$1" ] || return 0; done
    return 1
}

# ---- VM ------------------------------------------------------------------------------------------
check_vm_tools() {
    local missing=()
    command -v qemu-system-x86_64 >/dev/null || missing+=("qemu-system-x86_64 (apt-get install qemu-system-x86)")
    local bb
    bb=$(command -v busybox || true)
    if [ -z "$bb" ]; then
        missing+=("busybox (apt-get install busybox-static)")
    elif dynamic_elf "$bb"; then
        missing+=("a static busybox: $bb is dynamically linked (apt-get install busybox-static)")
    fi
    command -v cpio >/dev/null || missing+=("cpio (apt-get install cpio)")
    command -v gzip >/dev/null || missing+=("gzip")
    if ! kernel_ready; then
        command -v apt-get >/dev/null || missing+=("the Debian kernel in $KDIR (needs apt-get)")
    fi
    if [ ${#missing[@]} -gt 0 ]; then
        printf 'missing: %s\n' "${missing[@]}"
        return 1
    fi
}

build_initramfs() {
    local w=$CACHE/initramfs i m
    rm -rf "$w"
    mkdir -p "$w"/{bin,proc,sys,dev,tmp,run,lib/modules}
    cp "$(command -v busybox)" "$w/bin/busybox"
    for m in "${MODULES[@]}"; do cp "$KDIR/$m.ko" "$w/lib/modules/"; done
    for i in "${!BIN_PATHS[@]}"; do install_exe "${BIN_PATHS[$i]}" "$w/bin/${BIN_NAMES[$i]}" "$w"; done
    for i in "${COPIES[@]}"; do
        [ -e "$ROOT/$i" ] || die "copy: $ROOT/$i does not exist"
        mkdir -p "$w$ROOT/$(dirname "$i")"
        cp -a "$ROOT/$i" "$w$ROOT/$(dirname "$i")/"
    done
    mkdir -p "$w$ROOT"
    : >"$w/steps"
    for i in "${!COMMANDS[@]}"; do
        [ "${COMMANDS[$i]}" = "-" ] || printf '%s\n' "${COMMANDS[$i]}" >>"$w/steps"
    done
    {
        echo "export SHIMMY_REQUIRE_VCAN=1 SHIMMY_VCAN_IF=vcan0 RUST_BACKTRACE=1"
        ! has_bin firmware-sim || echo "export SHIMMY_FWSIM_BIN=/bin/firmware-sim"
        [ -z "${SHIMMY_VCAN_LOAD_S:-}" ] || echo "export SHIMMY_VCAN_LOAD_S=$SHIMMY_VCAN_LOAD_S"
        echo "WORKDIR='$ROOT' CMD_TIMEOUT=$CMD_TIMEOUT"
    } >"$w/env"
    cat >"$w/init" <<'EOF'
#!/bin/busybox sh
/bin/busybox --install -s /bin
export PATH=/bin HOME=/tmp
mount -t proc proc /proc
mount -t sysfs sys /sys
mount -t devtmpfs dev /dev
# /tmp stays on the (RAM-backed, writable) initramfs root: a tmpfs mounted over it would hide
# the files copied to the checkout's path when the checkout itself lives under /tmp.
. /env
echo "SHIMMY-VM-BOOTED uptime_s=$(cut -d' ' -f1 /proc/uptime) kernel=$(uname -r)"
for m in can can-raw can-dev vcan; do
    insmod /lib/modules/$m.ko || echo "SHIMMY-VM: insmod $m failed"
done
ip link set lo up
ip link add dev vcan0 type vcan && ip link set up vcan0 || echo "SHIMMY-VM: vcan0 setup failed"
ip link show vcan0
cd "$WORKDIR"
n=0
while IFS= read -r cmd; do
    n=$((n + 1))
    echo "SHIMMY-VM-BEGIN step=$n cmd=$cmd"
    start=$(cut -d' ' -f1 /proc/uptime)
    timeout "$CMD_TIMEOUT" sh -c "$cmd" </dev/null 2>&1
    rc=$?
    end=$(cut -d' ' -f1 /proc/uptime)
    echo "SHIMMY-VM-RESULT step=$n rc=$rc start_s=$start end_s=$end cmd=$cmd"
done </steps
echo "SHIMMY-VM-DONE steps=$n uptime_s=$(cut -d' ' -f1 /proc/uptime)"
poweroff -f
EOF
    chmod +x "$w/init"
    (cd "$w" && find . -print0 | cpio --null -o -H newc --quiet) | gzip -1 >"$CACHE/initrd.gz"
    log "initramfs $(du -h "$CACHE/initrd.gz" | cut -f1) with ${#BIN_PATHS[@]} executable(s)"
}

# Reads a console log and prints the summary; returns 0 only if every step passed.
summarize() {
    local logf=$1 wall=$2 expected=$3
    local results failed done_line booted n
    # Markers are matched anywhere in a line: the firmware's terminal escapes can precede them.
    results=$(grep -ao 'SHIMMY-VM-RESULT .*' "$logf" || true)
    failed=$(grep -v ' rc=0 ' <<<"$results" | grep . || true)
    done_line=$(grep -ao 'SHIMMY-VM-DONE .*' "$logf" || true)
    booted=$(grep -ao 'SHIMMY-VM-BOOTED uptime_s=[0-9.]*' "$logf" | sed 's/.*=//' || true)
    n=$(grep -c . <<<"$results" || true)
    echo "SHIMMY-VM-SUMMARY steps=$n expected=$expected failed=$(grep -c . <<<"$failed" || true) guest_boot_s=${booted:-?} wall_s=$wall"
    [ -n "$results" ] && [ -z "$failed" ] && [ -n "$done_line" ] && [ "$n" = "$expected" ]
}

run_vm() {
    command -v qemu-system-x86_64 >/dev/null || die "qemu-system-x86_64 not found (apt-get install qemu-system-x86)"
    local logf=$CACHE/console.log expected=0 c
    for c in "${COMMANDS[@]}"; do [ "$c" = "-" ] || expected=$((expected + 1)); done
    log "booting QEMU (TCG; host-side timeout ${VM_TIMEOUT}s); console -> $logf"
    local t0 t1 rc=0
    t0=$(date +%s.%N)
    # KVM is not used: on the development machines guests hang or abort on an MSR under KVM.
    timeout --kill-after=10 "$VM_TIMEOUT" qemu-system-x86_64 -accel tcg -cpu max -m 512 -smp "$SMP" \
        -nographic -no-reboot -kernel "$KDIR/vmlinuz" -initrd "$CACHE/initrd.gz" \
        -append "console=ttyS0 quiet panic=-1" </dev/null 2>&1 | tr -d '\r' | tee "$logf" || rc=$?
    t1=$(date +%s.%N)
    local wall
    wall=$(awk -v a="$t0" -v b="$t1" 'BEGIN { printf "%.1f", b - a }')
    [ "$rc" = 0 ] || log "qemu exited with status $rc (124 = host-side timeout)"
    summarize "$logf" "$wall" "$expected"
}

run_host() {
    local iface=${SHIMMY_VCAN_IF:-vcan0}
    [ -e "/sys/class/net/$iface" ] || die "no $iface on this host (sudo modprobe vcan; sudo ip link add dev $iface type vcan; sudo ip link set up $iface)"
    local bindir=$CACHE/host-bin i rc n=0 failed=0 t0 t1
    rm -rf "$bindir"
    mkdir -p "$bindir"
    for i in "${!BIN_PATHS[@]}"; do ln -s "${BIN_PATHS[$i]}" "$bindir/${BIN_NAMES[$i]}"; done
    local fwsim=""
    ! has_bin firmware-sim || fwsim=$bindir/firmware-sim
    t0=$(date +%s.%N)
    for i in "${!COMMANDS[@]}"; do
        [ "${COMMANDS[$i]}" = "-" ] && continue
        n=$((n + 1))
        echo "SHIMMY-VM-BEGIN step=$n cmd=${COMMANDS[$i]}"
        rc=0
        (cd "$ROOT" && PATH="$bindir:$PATH" SHIMMY_REQUIRE_VCAN=1 SHIMMY_VCAN_IF=$iface \
            SHIMMY_FWSIM_BIN=$fwsim \
            timeout "$CMD_TIMEOUT" sh -c "${COMMANDS[$i]}" </dev/null 2>&1) || rc=$?
        echo "SHIMMY-VM-RESULT step=$n rc=$rc cmd=${COMMANDS[$i]}"
        [ $rc = 0 ] || failed=$((failed + 1))
    done
    t1=$(date +%s.%N)
    echo "SHIMMY-VM-SUMMARY steps=$n expected=$n failed=$failed host=$iface wall_s=$(awk -v a="$t0" -v b="$t1" 'BEGIN { printf "%.1f", b - a }')"
    [ $failed = 0 ]
}

mkdir -p "$CACHE"
case $MODE in
    check) check_vm_tools ;;
    fetch) fetch_kernel ;;
    prepare) read_suite; fetch_kernel; build_bins ;;
    host) read_suite; build_bins; run_host ;;
    vm)
        read_suite
        check_vm_tools >&2 || die "cannot run the VM (see above)"
        fetch_kernel
        build_bins
        build_initramfs
        run_vm
        ;;
esac
