#!/usr/bin/env python3
"""Checks that the system calls in an `strace -c -U name` summary are allowed by a systemd
SystemCallFilter: @system-service, minus the groups given with --deny (as `~@privileged`).
The groups come from this machine's `systemd-analyze syscall-filter`, expanded recursively.

    syscalls.py SUMMARY WHO [--deny @GROUP ...]     exit 0 if allowed, 1 (naming the calls) if not
"""
import argparse
import re
import subprocess
import sys


def groups():
    out, cur = {}, None
    text = subprocess.run(["systemd-analyze", "syscall-filter"], capture_output=True, text=True, check=True).stdout
    for line in text.splitlines():
        if line.startswith("@"):
            cur = out.setdefault(line.strip(), set())
        elif cur is not None and line.strip() and not line.strip().startswith("#"):
            cur.add(line.strip())
    return out


def expand(g, name):
    calls = set()
    for e in g[name]:
        calls |= expand(g, e) if e.startswith("@") else {e}
    return calls


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("summary")
    ap.add_argument("who")
    ap.add_argument("--deny", action="append", default=[])
    a = ap.parse_args()
    g = groups()
    allowed = expand(g, "@system-service")
    for d in a.deny:
        allowed -= expand(g, d)
    used = set()
    for line in open(a.summary):
        f = line.split()
        if f and re.fullmatch(r"[a-z_0-9]+", f[-1]) and f[-1] not in ("syscall", "total"):
            used.add(f[-1])
    if len(used) < 10:
        sys.exit(f"test-package: {a.who}: strace summary too short: {sorted(used)}")
    flt = " ".join(["@system-service"] + ["~" + d for d in a.deny])
    bad = sorted(used - allowed)
    if bad:
        print(f"test-package: {a.who}: system calls outside {flt}: {bad}")
        sys.exit(1)
    print(f"test-package: {a.who} made {len(used)} distinct system calls, all allowed by {flt}")


if __name__ == "__main__":
    main()
