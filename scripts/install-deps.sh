#!/usr/bin/env bash
# Installs what bass needs on a fresh Debian machine (idempotent; skips what is present).
# Usage: scripts/install-deps.sh [--with-octave] [--with-bench]
#   --with-octave: what make test needs on top; --with-bench: what make bench needs on top
#   (PipeWire, for its comparison with bass: scripts/bench.sh asks for it).
set -euo pipefail

need=()
have_pkg() { dpkg-query -W -f='${Status}' "$1" 2>/dev/null | grep -q 'install ok installed'; }

pkgs=(build-essential pkg-config libasound2-dev libasound2-plugins alsa-utils jackd2 procps util-linux cmake sox openssl iproute2
      libfontconfig1-dev libfreetype-dev fonts-dejavu-core)
# The Python client and its tests (tests/clients, python/tests, tests/conformance).
pkgs+=(python3 python3-numpy python3-pytest)
# The C ABI suite (make test-c, tests/c/run.sh): strace counts the library's opens of /proc,
# valgrind runs the C test programs and examples under memcheck.
pkgs+=(strace valgrind)
with_octave="" with_bench=""
for a in "$@"; do
  case "$a" in
    --with-octave) with_octave=1 ;;
    --with-bench) with_bench=1 ;;
    *) echo "install-deps: unknown option $a" >&2; exit 2 ;;
  esac
done
if [[ -n "$with_bench" ]]; then
  # make bench, part 7: the PipeWire daemon and pw-link, and libpipewire to build its C clients.
  pkgs+=(pipewire libpipewire-0.3-dev)
fi
if [[ -n "$with_octave" ]]; then
  # What make test needs on top (make deps): the package test (tests/package) lints the
  # package, verifies the systemd units (systemd-analyze) and traces bassd (strace: above);
  # the systemd test (tests/systemd) boots the package in a Debian root made by debootstrap.
  pkgs+=(lintian systemd adduser debootstrap)
  pkgs+=(octave liboctave-dev)
fi
for p in "${pkgs[@]}"; do have_pkg "$p" || need+=("$p"); done

if ((${#need[@]})); then
  sudo=""
  [[ $(id -u) -eq 0 ]] || sudo="sudo"
  export DEBIAN_FRONTEND=noninteractive
  echo "install-deps: installing ${need[*]}"
  $sudo apt-get update -q
  $sudo apt-get install -y -q --no-install-recommends "${need[@]}"
fi

if ! python3 -c 'import numpy, pytest' 2>/dev/null; then
  # A python3 other than Debian's (e.g. pyenv): pip; Debian's own pip refuses without the flag.
  python3 -m pip install -q numpy pytest 2>/dev/null || python3 -m pip install -q --break-system-packages numpy pytest
fi
# The iceoryx2 subscriber of the network suite (tests/bridge): the PyPI package of the same
# version as the bridge's iceoryx2 crate.
if ! python3 -c 'import iceoryx2, flatbuffers' 2>/dev/null; then
  python3 -m pip install -q iceoryx2==0.10.0 2>/dev/null || python3 -m pip install -q --break-system-packages iceoryx2==0.10.0
fi
# Real Zenoh peers written by others for the network suite (a hostile peer, an authenticated
# colleague): PyPI eclipse-zenoh, the version of the bridge's zenoh crate.
if ! python3 -c 'import importlib.metadata as m, zenoh; assert m.version("eclipse-zenoh") == "1.10.2"' 2>/dev/null; then
  python3 -m pip install -q eclipse-zenoh==1.10.2 2>/dev/null || python3 -m pip install -q --break-system-packages eclipse-zenoh==1.10.2
fi
# Readers of MCAP / rosbag2 that bass did not write, for the recording suite (tests/replay).
if ! python3 -c 'import importlib.metadata as m, mcap, mcap_ros2, rosbags; assert (m.version("mcap"), m.version("mcap-ros2-support"), m.version("rosbags")) == ("1.6.0", "0.6.0", "0.11.9")' 2>/dev/null; then
  python3 -m pip install -q mcap==1.6.0 mcap-ros2-support==0.6.0 rosbags==0.11.9 2>/dev/null || python3 -m pip install -q --break-system-packages mcap==1.6.0 mcap-ros2-support==0.6.0 rosbags==0.11.9
fi
# The XDF reader of the recording suite (tests/replay/xdf_check.py, cli/tests/record_xdf.rs).
if ! python3 -c 'import importlib.metadata as m, pyxdf; assert m.version("pyxdf") == "1.17.5"' 2>/dev/null; then
  python3 -m pip install -q pyxdf==1.17.5 2>/dev/null || python3 -m pip install -q --break-system-packages pyxdf==1.17.5
fi
# The Lab Streaming Layer inlet of the client suite (tests/clients/test_lsl.py) and the liblsl
# its wheel ships, which `bass lsl` loads at run time.
if ! python3 -c 'import importlib.metadata as m, pylsl; assert m.version("pylsl") == "1.18.6"' 2>/dev/null; then
  python3 -m pip install -q pylsl==1.18.6 2>/dev/null || python3 -m pip install -q --break-system-packages pylsl==1.18.6
fi
# make bench, part 8: PyPI soxr (libsoxr, VHQ), the ideal-clock floor the aligned follower's SNR
# is compared with (bench/align_bench.py).
if [[ -n "$with_bench" ]] && ! python3 -c 'import importlib.metadata as m, soxr; assert m.version("soxr") == "1.1.0"' 2>/dev/null; then
  python3 -m pip install -q soxr==1.1.0 2>/dev/null || python3 -m pip install -q --break-system-packages soxr==1.1.0
fi
# ROS's own parser of package.xml, for the bass_msgs package (tests/bridge/cases/ros2.sh).
if ! python3 -c 'import importlib.metadata as m, catkin_pkg; assert m.version("catkin_pkg") == "1.0.0"' 2>/dev/null; then
  python3 -m pip install -q catkin_pkg==1.0.0 2>/dev/null || python3 -m pip install -q --break-system-packages catkin_pkg==1.0.0
fi
