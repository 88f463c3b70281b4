#!/usr/bin/env bash
# Installs the systemd units, the example configurations and the service documentation
# (called by `make install`): packaging/systemd/install-units.sh INSTALL_ROOT PREFIX
#   INSTALL_ROOT  where files go ($DESTDIR$PREFIX)
#   PREFIX        where they will be at run time (the units name PREFIX/bin/bassd)
# Units go to INSTALL_ROOT/lib/systemd/system (for PREFIX /usr/local: /usr/local/lib/systemd/
# system, which systemd searches too). Generated from the two templates here:
#   bassd.service.in        -> bassd.service (broker "default"), bassd@.service (broker %i)
#   bass-bridge.service.in  -> bass-bridge-serve@.service, bass-bridge-mirror@.service
set -euo pipefail
[[ $# -eq 2 ]] || { echo "usage: $0 INSTALL_ROOT PREFIX" >&2; exit 2; }
root=$1 prefix=$2
here=$(cd "$(dirname "$0")" && pwd)
docs=$here/../../docs
units=$root/lib/systemd/system
install -d "$units" "$root/share/bass/examples" "$root/share/doc/bass"

gen() { # template output sed-expressions...
  local in=$1 out=$2; shift 2
  sed -e "s|@BINDIR@|$prefix/bin|g" -e "s|@DOCDIR@|$prefix/share/doc/bass|g" "$@" "$here/$in" > "$units/$out.tmp"
  if grep -n '@[A-Z_]*@' "$units/$out.tmp" >&2; then echo "install-units: $out: placeholder left" >&2; exit 1; fi
  chmod 0644 "$units/$out.tmp" && mv "$units/$out.tmp" "$units/$out"
}
gen bassd.service.in bassd.service -e 's|@WHAT@|broker "default"|' -e 's|@NAME_ARG@||' \
  -e 's|@CONF@|/etc/bass/bassd.conf|g'
gen bassd.service.in bassd@.service -e 's|@WHAT@|broker %i|' -e 's|@NAME_ARG@|--name %i |' \
  -e 's|@CONF@|/etc/bass/bassd-%i.conf|g'
gen bass-bridge.service.in bass-bridge-serve@.service -e 's|@MODE@|serve|g' \
  -e 's|@WHAT@|publish a local port on the network|' -e 's|@AFTER@|bassd.service bassd@%i.service|'
gen bass-bridge.service.in bass-bridge-mirror@.service -e 's|@MODE@|mirror|g' \
  -e 's|@WHAT@|a replica port of a remote source|' -e 's| @AFTER@||'

install -m 0644 "$here/bassd.conf" "$here/bridge-serve.conf" "$here/bridge-mirror.conf" "$root/share/bass/examples/"
install -m 0644 "$docs/broker.md" "$docs/network.md" "$root/share/doc/bass/"
