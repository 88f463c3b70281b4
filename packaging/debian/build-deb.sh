#!/usr/bin/env bash
# Builds the Debian package of bass from binaries already built (`make deb` builds them
# first): packaging/debian/build-deb.sh OUTDIR  ->  OUTDIR/bass_VERSION-1_ARCH.deb (path printed
# on the last line).
#
# A plain dpkg-deb layout, no debhelper or cargo-deb: `make install-files DESTDIR=STAGE
# PREFIX=/usr` puts every file in place (binaries, library with its SONAME links, headers,
# pkg-config, CMake, the MEX sources, the systemd units), this script adds the Python package
# (/usr/lib/python3/dist-packages/bass) and the Debian parts
# (DEBIAN/control with Depends computed by dpkg-shlibdeps, maintainer scripts, conffiles,
# the ldconfig trigger, shlibs, md5sums; copyright and changelog.Debian.gz) and strips the
# ELF files (their debug information stays in the build tree). docs/broker.md, "Running bass
# as a service".
set -euo pipefail
[[ $# -eq 1 ]] || { echo "usage: $0 OUTDIR" >&2; exit 2; }
ROOT=$(cd "$(dirname "$0")/../.." && pwd)
HERE=$ROOT/packaging/debian
mkdir -p "$1"
OUT=$(cd "$1" && pwd)
VERSION=$(sed -n 's/^version = "\(.*\)"/\1/p' "$ROOT/Cargo.toml" | head -1)
DEBVERSION=$VERSION-1
ARCH=$(dpkg --print-architecture)
WORK=$(mktemp -d)
trap 'rm -rf "$WORK"' EXIT
STAGE=$WORK/bass
BUILT=${CARGO_TARGET_DIR:-$ROOT/target}/release
for f in bassd bass bass-bridge libbassclient.so libbassclient.a; do
  [[ -f $BUILT/$f ]] || { echo "build-deb: $BUILT/$f missing: run make build-ship (or make deb)" >&2; exit 1; }
done

make -C "$ROOT" --no-print-directory install-files DESTDIR="$STAGE" PREFIX=/usr >"$WORK/install.log" 2>&1 \
  || { cat "$WORK/install.log" >&2; exit 1; }

# The Python package (pure Python over ctypes) where Debian keeps modules for every python3
# version; it loads /usr/lib/libbassclient.so.0 through the dynamic loader. No byte code is
# shipped: postinst compiles it (py3compile), prerm removes it (py3clean), as dh_python3 does.
install -d -m 0755 "$STAGE/usr/lib/python3/dist-packages/bass"
install -m 0644 "$ROOT"/python/bass/*.py "$STAGE/usr/lib/python3/dist-packages/bass/"

# The broker's configuration is a conffile in /etc/bass; the bridge's examples stay examples
# (a bridge instance needs a configuration written for its network).
install -d -m 0755 "$STAGE/etc/bass"
install -m 0644 "$STAGE/usr/share/bass/examples/bassd.conf" "$STAGE/etc/bass/bassd.conf"

# Debug information stays in the build tree; the package ships stripped files.
for f in usr/bin/bassd usr/bin/bass usr/bin/bass-bridge "usr/lib/libbassclient.so.$VERSION"; do
  strip --strip-unneeded --remove-section=.comment --remove-section=.note "$STAGE/$f"
done
strip --strip-debug --remove-section=.comment --enable-deterministic-archive "$STAGE/usr/lib/libbassclient.a"
chmod 0644 "$STAGE/usr/lib/libbassclient.so.$VERSION"

# /usr/share/doc/bass: copyright, the upstream changelog, the Debian changelog.
install -m 0644 "$HERE/copyright" "$STAGE/usr/share/doc/bass/copyright"
gzip -9n <"$ROOT/CHANGELOG.md" >"$STAGE/usr/share/doc/bass/changelog.gz"
DATE=$(git -C "$ROOT" log -1 --format=%cD 2>/dev/null || date -R)
sed -e "s|@DEBVERSION@|$DEBVERSION|" -e "s|@DATE@|$DATE|" "$HERE/changelog.in" | gzip -9n \
  >"$STAGE/usr/share/doc/bass/changelog.Debian.gz"
chmod 0644 "$STAGE"/usr/share/doc/bass/*
install -D -m 0644 "$HERE/lintian-overrides" "$STAGE/usr/share/lintian/overrides/bass"

# Depends: dpkg-shlibdeps on every ELF file, from a minimal debian/ directory.
mkdir -p "$WORK/src/debian"
printf 'Source: bass\n\nPackage: bass\nArchitecture: any\n' >"$WORK/src/debian/control"
shlibs=$(cd "$WORK/src" && dpkg-shlibdeps -O -l"$STAGE/usr/lib" \
  "$STAGE/usr/bin/bassd" "$STAGE/usr/bin/bass" "$STAGE/usr/bin/bass-bridge" \
  "$STAGE/usr/lib/libbassclient.so.$VERSION" 2>"$WORK/shlibdeps.log") \
  || { cat "$WORK/shlibdeps.log" >&2; exit 1; }
DEPENDS=${shlibs#shlibs:Depends=}
[[ -n $DEPENDS && $DEPENDS != "$shlibs" ]] || { echo "build-deb: dpkg-shlibdeps gave: $shlibs" >&2; exit 1; }

install -d -m 0755 "$STAGE/DEBIAN"
sed -e "s|@DEBVERSION@|$DEBVERSION|" -e "s|@ARCH@|$ARCH|" -e "s|@DEPENDS@|adduser, $DEPENDS|" \
    -e "s|@SIZE@|$(du -sk --exclude=DEBIAN "$STAGE" | cut -f1)|" "$HERE/control.in" >"$STAGE/DEBIAN/control"
install -m 0755 "$HERE/postinst" "$HERE/prerm" "$HERE/postrm" "$STAGE/DEBIAN/"
install -m 0644 "$HERE/triggers" "$STAGE/DEBIAN/triggers"
echo "libbassclient 0 bass (>= $VERSION)" >"$STAGE/DEBIAN/shlibs"
(cd "$STAGE" && find etc -type f | sed 's|^|/|' | sort) >"$STAGE/DEBIAN/conffiles"
(cd "$STAGE" && find usr -type f -print0 | sort -z | xargs -0 md5sum) >"$STAGE/DEBIAN/md5sums"
chmod 0644 "$STAGE"/DEBIAN/{shlibs,conffiles,md5sums}

DEB=$OUT/bass_${DEBVERSION}_$ARCH.deb
dpkg-deb --root-owner-group -Zxz -z6 --build "$STAGE" "$DEB" >/dev/null
echo "$DEB"
