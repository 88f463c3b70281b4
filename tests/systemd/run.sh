#!/usr/bin/env bash
# make test-systemd: bass under a real systemd (root). A minimal Debian root (debootstrap
# --variant=minbase with systemd, built once and kept in $BASS_SYSROOT_CACHE, default
# /var/tmp/bass-sysroot-cache) gets the package (broker/debian/build-deb.sh) with dpkg -i
# and a start-up acquisition in /etc/bass/bassd.conf, and is booted with systemd as PID 1 of
# its own pid namespace (unshare + chroot; systemd-nspawn -b cannot run here). In it:
#   1. bassd.service starts at boot and reaches READY (Type=notify): active, STATUS capturing;
#   2. a C reader (tests/systemd/ride.c, built against the installed header and library)
#      reads across `systemctl restart bassd` and `systemctl kill -s KILL bassd` (restarted by
#      Restart=on-failure): no error, no loss, the same epoch, every sample the pattern or a
#      zero of a gap, and the zeros it read = the port's gap_frames (counted exactly);
#   3. the watchdog fires when the capture stalls (bassd@stall on sim:stall: no WATCHDOG=1
#      after the stall, systemd kills it, "Watchdog timeout" in its journal, restarted);
#   4. powered off with SIGRTMIN+4.
# It prints the restart gaps (frames, ms of audio, restart to first new chunk).
# In `make test`: ~40 s, plus ~70 s of debootstrap (network) the first time on a machine.
set -euo pipefail
ROOT=$(cd "$(dirname "$0")/../.." && pwd)
T0=$SECONDS
say() { echo "test-systemd: $*"; }
fail() { echo "test-systemd: FAIL: $*" >&2; exit 1; }
[[ $(id -u) -eq 0 ]] || fail "needs root (chroot, unshare, dpkg in the root)"
for t in debootstrap unshare nsenter chroot cc timeout; do
  command -v "$t" >/dev/null || fail "$t missing (apt-get install debootstrap util-linux gcc)"
done

WORK=$(mktemp -d /var/tmp/bass-systemd.XXXXXX)
SYS=$WORK/root
UNSHARE_PID=
SD=
cleanup() {
  local rc=$?
  # systemd is the namespace's PID 1: killing it ends everything in the namespace.
  if [[ -n $SD ]]; then kill -9 "$SD" 2>/dev/null || true; fi
  if [[ -n $UNSHARE_PID ]]; then
    kill -9 "$UNSHARE_PID" 2>/dev/null || true
    wait "$UNSHARE_PID" 2>/dev/null || true
  fi
  rm -rf "$WORK"
  ((rc == 0)) || echo "test-systemd: failed after $((SECONDS - T0)) s" >&2
}
trap cleanup EXIT

DEB=$(timeout 300 "$ROOT/broker/debian/build-deb.sh" "$WORK/deb" | tail -1) || fail "build-deb.sh failed"
# The root holds systemd and what the package depends on (names of its Depends).
deps=$(dpkg-deb -f "$DEB" Depends | tr ',|' '\n\n' | sed 's/(.*//; s/ //g' | grep -v '^$' | sort -u | paste -sd, -)
INCLUDE=systemd,systemd-sysv,dbus,$deps
CACHE=${BASS_SYSROOT_CACHE:-/var/tmp/bass-sysroot-cache}
BASE=$CACHE/bookworm-$(echo "$INCLUDE" | md5sum | cut -c1-8)
if [[ ! -x $BASE/lib/systemd/systemd ]]; then
  say "building the Debian root in $BASE (debootstrap, about 2 minutes)"
  rm -rf "$BASE.tmp"
  mkdir -p "$CACHE"
  timeout 900 debootstrap --variant=minbase --include="$INCLUDE" bookworm "$BASE.tmp" http://deb.debian.org/debian \
    >"$CACHE/debootstrap.log" 2>&1 || { tail -20 "$CACHE/debootstrap.log" >&2; fail "debootstrap failed"; }
  mv "$BASE.tmp" "$BASE"
fi

cp -a "$BASE" "$SYS"
cp "$DEB" "$SYS/tmp/bass.deb"
chroot "$SYS" dpkg -i /tmp/bass.deb >"$WORK/dpkg.log" 2>&1 || { cat "$WORK/dpkg.log" >&2; fail "dpkg -i in the root"; }
say "installed $(basename "$DEB") in a booted-to-be Debian root ($((SECONDS - T0)) s)"
# The reader, against what the package installed (header, pkg-config's flags, the library).
cc -std=c11 -Wall -Wextra -Wpedantic -Werror -D_POSIX_C_SOURCE=200809L -I"$SYS/usr/include" \
  "$ROOT/tests/systemd/ride.c" -L"$SYS/usr/lib/x86_64-linux-gnu" -L"$SYS/usr/lib" -lbassclient \
  -o "$SYS/usr/local/bin/bass-ride"
# Start-up acquisitions: the default broker on the pattern, bassd@stall on a device that stalls.
# No SCHED_FIFO: this machine's container may refuse it, and the test is not about timing.
ACQ="--rate 48000 --frames 480 --chunks 400 --channels 2 --rt-priority 0"
echo "BASSD_ARGS=\"--acquire sim:pattern $ACQ\"" >"$SYS/etc/bass/bassd.conf"
echo "BASSD_ARGS=\"--acquire sim:stall $ACQ\"" >"$SYS/etc/bass/bassd-stall.conf"
chroot "$SYS" systemctl enable bassd.service bassd@stall.service >/dev/null 2>&1
# A quiet, quick boot: no gettys on this machine's terminals.
chroot "$SYS" systemctl mask getty@tty1.service console-getty.service serial-getty@.service \
  systemd-timesyncd.service apt-daily.timer apt-daily-upgrade.timer >/dev/null 2>&1 || true

say "booting systemd in the root"
# The root a mount point of its own (systemd sets up the units' mount namespaces from it).
unshare --fork --kill-child --pid --mount --uts --ipc /bin/sh -c \
  'mount --bind "$0" "$0" && exec chroot "$0" /bin/sh -c "mount -t proc proc /proc; mount -t sysfs sys /sys;
   mount -t tmpfs tmpfs /run; mount -t tmpfs tmpfs /tmp; exec env container=unshare /lib/systemd/systemd --system"' \
  "$SYS" >"$WORK/boot.log" 2>&1 &
UNSHARE_PID=$!
for _ in $(seq 100); do
  SD=$(pgrep -P "$UNSHARE_PID" -x systemd || true)
  [[ -n $SD ]] && break
  sleep 0.1
done
[[ -n $SD ]] || { cat "$WORK/boot.log" >&2; fail "systemd did not start"; }
in_root() { timeout "${TMO:-30}" nsenter -t "$SD" -m -p -u -i -r -w "$@"; }
for _ in $(seq 300); do in_root test -S /run/systemd/private && break; sleep 0.1; done
state=$(TMO=90 in_root systemctl is-system-running --wait 2>/dev/null || true)
[[ $state =~ ^(running|degraded)$ ]] || { in_root systemctl --failed --no-pager || true; fail "boot ended $state"; }
say "booted ($state) in $((SECONDS - T0)) s"

# 1. Started at boot, READY (active), STATUS.
[[ $(in_root systemctl is-active bassd.service) == active ]] || { in_root journalctl -u bassd --no-pager | tail -20; fail "bassd not active"; }
for _ in $(seq 50); do
  status=$(in_root systemctl show -p StatusText --value bassd.service)
  [[ $status == capturing\ sim:pattern* ]] && break
  sleep 0.1
done
[[ $status == capturing\ sim:pattern* ]] || fail "STATUS: $status"
say "bassd.service active at boot; STATUS: $status"

# 2. A reader across a restart and a crash.
TMO=40 in_root /usr/local/bin/bass-ride 8 >"$WORK/ride.log" 2>&1 &
RIDE=$!
sleep 2
t=$(date +%s%N); in_root systemctl restart bassd.service; t=$((($(date +%s%N) - t) / 1000000))
say "systemctl restart bassd returned after $t ms"
sleep 2
in_root systemctl kill -s KILL bassd.service
sleep 2.5
rrc=0; wait "$RIDE" || rrc=$?
sed 's/^/  /' "$WORK/ride.log"
((rrc == 0)) || { in_root journalctl -u bassd --no-pager | tail -30; fail "the reader failed (exit $rrc)"; }
sum=$(grep '^ride: frames' "$WORK/ride.log")
read -r _ _ frames _ loss _ zero _ gaps _ epoch _ gapf _ errors <<<"$sum"
((errors == 0 && loss == 0)) || fail "$sum"
((gaps == 2)) || fail "expected 2 gaps (restart, kill): $sum"
((zero == gapf)) || fail "zeros read ($zero) != the port's gap_frames ($gapf)"
restarts=$(in_root systemctl show -p NRestarts --value bassd.service)
((restarts >= 1)) || fail "the killed bassd was not restarted (NRestarts $restarts)"
# The journal is taken whole before grep -q: with pipefail, grep quitting at its first match
# could end journalctl by SIGPIPE and fail the pipe (a long journal).
journal=$(in_root journalctl -u bassd --no-pager)
grep -q "resuming the acquisition" <<<"$journal" || { tail -40 <<<"$journal"; fail "no resume in bassd's journal"; }
say "the reader rode through: $frames frames, loss 0, epoch $epoch kept, $zero zero frames = gap_frames; NRestarts $restarts"

# 3. The watchdog fires when the capture stalls.
t=$SECONDS
until grep -q "Watchdog timeout" <<<"$(in_root journalctl -u bassd@stall --no-pager 2>/dev/null)"; do
  ((SECONDS - t < 30)) || { in_root journalctl -u bassd@stall --no-pager | tail -20; fail "no watchdog timeout for bassd@stall"; }
  sleep 0.5
done
t=$SECONDS
until (( $(in_root systemctl show -p NRestarts --value bassd@stall.service) >= 1 )); do
  ((SECONDS - t < 15)) || fail "bassd@stall not restarted after its watchdog timeout"
  sleep 0.5
done
say "bassd@stall: device stalled, watchdog timeout, restarted (NRestarts $(in_root systemctl show -p NRestarts --value bassd@stall.service))"

# 4. Power off.
kill -s RTMIN+4 "$SD"
for _ in $(seq 300); do kill -0 "$UNSHARE_PID" 2>/dev/null || break; sleep 0.1; done
kill -0 "$UNSHARE_PID" 2>/dev/null && fail "systemd did not power off within 30 s"
UNSHARE_PID= SD=
say "powered off; all passed in $((SECONDS - T0)) s"
