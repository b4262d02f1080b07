#!/usr/bin/env bash
# Builds the Debian package of shimmy-monitor: shimmyd and shimmy built with the shipping
# profile `dist`, the configuration, the vehicle profiles with their DBCs, the systemd unit and
# its MQTT sandbox generator, and the maintainer scripts of this folder. docs/GATEWAY.md says
# what goes where.
#
# Usage: config/debian/build.sh [--target TRIPLE] [--no-build]
#   --target TRIPLE  cross-build (aarch64-unknown-linux-gnu -> arm64; default: this machine)
#   --no-build       pack the binaries already in target/[TRIPLE/]dist/
# Prints the path of the .deb: target/debian/shimmy-monitor_<version>_<arch>.deb
# ($CARGO_TARGET_DIR instead of target/ when set).
#
# The profiles' DBCs are looked up as the monitor does (src/profile: the profile folder, the
# repository's dbc/, $SHIMMY_DBC_PATH, the shared data's dbc/opendbc and dbc, $SHIMMY_DATA_DIR
# or ../shared/data) and copied into each profile's folder, so the installed profiles need
# nothing else. Needs cargo, dpkg-deb and readelf (binutils).
set -euo pipefail
umask 022
here=$(cd "$(dirname "${BASH_SOURCE[0]}")" && pwd)
repo=$(cd "$here/../.." && pwd)
cd "$repo"

triple=""
build=1
while [ $# -gt 0 ]; do
    case "$1" in
    --target)
        triple=${2:?--target needs a triple}
        shift 2
        ;;
    --no-build)
        build=0
        shift
        ;;
    -h | --help)
        sed -n '2,16p' "${BASH_SOURCE[0]}" | sed 's/^# \{0,1\}//'
        exit 0
        ;;
    *)
        echo "build.sh: unknown argument '$1' (see --help)" >&2
        exit 2
        ;;
    esac
done

die() {
    echo "build.sh: $*" >&2
    exit 1
}

target_dir=${CARGO_TARGET_DIR:-$repo/target}
case "$triple" in
"") arch=$(dpkg --print-architecture) bindir=$target_dir/dist ;;
x86_64-unknown-linux-gnu) arch=amd64 bindir=$target_dir/$triple/dist ;;
aarch64-unknown-linux-gnu) arch=arm64 bindir=$target_dir/$triple/dist ;;
*) die "no Debian architecture known for target '$triple'" ;;
esac

version=$(awk -F'"' '/^\[package\]/{p=1; next} /^\[/{p=0} p && /^version *=/{print $2; exit}' Cargo.toml)
[ -n "$version" ] || die "no version in Cargo.toml's [package]"

if [ "$build" = 1 ]; then
    cargo build --profile dist -p shimmy-monitor --bin shimmyd --bin shimmy \
        ${triple:+--target "$triple"} >&2
fi
for b in shimmyd shimmy; do
    [ -x "$bindir/$b" ] || die "$bindir/$b missing (build it, or drop --no-build)"
done

stage=$target_dir/debian/stage-$arch
out=$target_dir/debian/shimmy-monitor_${version}_${arch}.deb
rm -rf "$stage"
mkdir -p "$stage/DEBIAN"

# Binaries and the sandbox generator.
install -D -m 0755 "$bindir/shimmyd" "$stage/usr/bin/shimmyd"
install -D -m 0755 "$bindir/shimmy" "$stage/usr/bin/shimmy"
install -D -m 0755 "$here/shimmyd-sandbox-generator" \
    "$stage/usr/lib/systemd/system-generators/shimmyd-sandbox-generator"
install -D -m 0644 config/systemd/shimmyd.service "$stage/usr/lib/systemd/system/shimmyd.service"

# Configuration (conffiles): the daemon's file, the monitor's settings it names, the profiles.
install -D -m 0644 config/shimmyd.toml "$stage/etc/shimmyd/shimmyd.toml"
install -D -m 0644 config/observer.toml "$stage/etc/shimmyd/observer.toml"

# Finds DBC $2 for the profile folder $1, in the monitor's order (src/profile resolve_dbc).
find_dbc() {
    local dir=$1 name=$2 data=${SHIMMY_DATA_DIR:-$repo/../shared/data} c
    local -a cands=("$dir/$name" "$repo/dbc/$name")
    if [ -n "${SHIMMY_DBC_PATH:-}" ]; then
        local IFS=:
        for d in $SHIMMY_DBC_PATH; do cands+=("$d/$name"); done
    fi
    cands+=("$data/dbc/opendbc/$name" "$data/dbc/$name")
    for c in "${cands[@]}"; do
        if [ -f "$c" ]; then
            echo "$c"
            return 0
        fi
    done
    return 1
}

for p in config/vehicles/*/; do
    p=${p%/}
    name=$(basename "$p")
    [ -f "$p/profile.toml" ] || continue
    dest=$stage/etc/shimmyd/vehicles/$name
    install -d -m 0755 "$dest"
    for f in "$p"/*; do
        [ -f "$f" ] && install -m 0644 "$f" "$dest/"
    done
    dbc=$(sed -n 's/^dbc *= *"\(.*\)".*/\1/p' "$p/profile.toml" | head -n 1)
    [ -n "$dbc" ] || die "$p/profile.toml names no dbc"
    case "$dbc" in */*) die "$p/profile.toml: dbc '$dbc' is a path; the package copies a bare file name into the profile" ;; esac
    src=$(find_dbc "$p" "$dbc") ||
        die "DBC '$dbc' of profile $name not found (set SHIMMY_DATA_DIR to the shared data, or SHIMMY_DBC_PATH)"
    install -m 0644 "$src" "$dest/$(basename "$dbc")"
done

install -D -m 0644 "$here/copyright" "$stage/usr/share/doc/shimmy-monitor/copyright"

# Maintainer scripts.
for s in postinst prerm postrm; do
    install -m 0755 "$here/$s" "$stage/DEBIAN/$s"
done
(cd "$stage" && find etc -type f | sort | sed 's|^|/|') >"$stage/DEBIAN/conffiles"

# Depends, from the binaries' dynamic section: the libraries they need and the newest glibc
# symbol version they use.
depends=""
glibc=$(readelf --dyn-syms -W "$stage/usr/bin/shimmyd" "$stage/usr/bin/shimmy" |
    grep -o 'GLIBC_[0-9][0-9.]*' | sed 's/GLIBC_//' | sort -uV | tail -n 1)
[ -n "$glibc" ] || die "no GLIBC symbol versions in the binaries"
libs=$(readelf -d -W "$stage/usr/bin/shimmyd" "$stage/usr/bin/shimmy" |
    sed -n 's/.*(NEEDED).*\[\(.*\)\]/\1/p' | sort -u)
for l in $libs; do
    case "$l" in
    libc.so.6 | libm.so.6 | libpthread.so.0 | libdl.so.2 | librt.so.1 | ld-linux*) dep="libc6 (>= $glibc)" ;;
    libgcc_s.so.1) dep="libgcc-s1" ;;
    *) die "no Debian package known for $l (needed by the binaries)" ;;
    esac
    case ", $depends, " in *", $dep, "*) ;; *) depends=${depends:+$depends, }$dep ;; esac
done
depends="$depends, passwd"

installed_kib=$(du -sk --exclude=DEBIAN "$stage" | cut -f1)
cat >"$stage/DEBIAN/control" <<EOF
Package: shimmy-monitor
Version: $version
Architecture: $arch
Maintainer: shimmy-monitor developers <dev@shimmy>
Installed-Size: $installed_kib
Depends: $depends
Recommends: systemd
Section: misc
Priority: optional
Description: in-vehicle monitor for brake shimmy and steering-joint clearance
 shimmyd reads a vehicle's CAN bus (SocketCAN, read-only unless configured),
 detects braking events, estimates steering-joint clearance, raises maintenance
 alerts and writes them to a crash-safe journal under /var/lib/shimmyd; shimmy
 is the command-line tool (estimate, report, calibrate, decode, doctor).
 The systemd unit runs shimmyd as the system user shimmyd in a sandbox without
 IP sockets; enabling [mqtt] in /etc/shimmyd/shimmyd.toml adds the broker's
 address through a generated drop-in.
EOF
(cd "$stage" && find . -path ./DEBIAN -prune -o -type f -printf '%P\0' | sort -z |
    xargs -0 md5sum) >"$stage/DEBIAN/md5sums"
chmod 0644 "$stage/DEBIAN/control" "$stage/DEBIAN/conffiles" "$stage/DEBIAN/md5sums"

if [ -z "${SOURCE_DATE_EPOCH:-}" ] && git -C "$repo" rev-parse --git-dir >/dev/null 2>&1; then
    SOURCE_DATE_EPOCH=$(git -C "$repo" log -1 --format=%ct)
    export SOURCE_DATE_EPOCH
fi
dpkg-deb --root-owner-group -Zxz --build "$stage" "$out" >&2
echo "$out"
