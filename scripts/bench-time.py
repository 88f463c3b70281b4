#!/usr/bin/env python3
"""Timestamp figures of the network bench (scripts/bench-network.sh, "Time" table).

    bench-time.py replica DIR_A SRC DIR_B REP STATUS SECS [LATE_S]
        Follows the replica port REP (runtime directory DIR_B) for SECS seconds and, for every
        chunk that arrives, compares its mapped CLOCK_MONOTONIC stamp with the source port's
        stamp of the same first frame (SRC in DIR_A). The two network namespaces share one
        CLOCK_MONOTONIC, so the source's stamp is the truth: error = replica - source. A chunk
        counts as covered when |error| is within the bound the replica chunk itself carries
        (port format 2.4: source bound + clock-map uncertainty). The status file STATUS gives
        the mirror's clock uncertainty beside it. With LATE_S, the chunks that arrive LATE_S
        seconds or more after the start are also summed up apart ("late": their error, and how
        far the replica's CLOCK_REALTIME stamps are from the source port's: a source whose
        clock runs fast, or whose wall clock was stepped, by bass-bridge-faults). Prints one
        JSON object.

    bench-time.py lsl-outlet NAME SECS      (in the source's namespace)
    bench-time.py lsl-inlet NAME SECS       (in the mirror's namespace)
        pylsl's clock offset between two processes, as LSL users get it: the inlet calls
        time_correction() five times a second for SECS seconds; the true offset is 0 (one
        CLOCK_MONOTONIC), so |value| is the error. The inlet prints one JSON object.
"""

import json
import os
import sys
import time


def quantiles(values):
    v = sorted(values)
    q = lambda p: v[round((len(v) - 1) * p)] if v else None
    return {"n": len(v), "p50": q(0.5), "p99": q(0.99), "p999": q(0.999), "max": v[-1] if v else None}


def open_port(directory, name, wait_s=15.0):
    """Port NAME of runtime directory DIRECTORY, waiting up to WAIT_S for it to exist."""
    import bass

    os.environ["BASS_RUNTIME_DIR"] = directory
    deadline = time.monotonic() + wait_s
    while True:
        try:
            return bass.Port(name)
        except bass.BassError:
            if time.monotonic() > deadline:
                raise
            time.sleep(0.1)


def live_replica(dir_b, rep_name, wait_s=15.0):
    """The replica once it holds the source's frames (the mirror replaces an idle replica by the
    source's geometry when the first chunk arrives)."""
    deadline = time.monotonic() + wait_s
    while True:
        rep = open_port(dir_b, rep_name, wait_s)
        i = rep.info()
        if i["state_name"] == "capturing" and i["last_frame_index"] > 0:
            return rep
        rep.close()
        if time.monotonic() > deadline:
            raise SystemExit(f"replica {rep_name} not capturing after {wait_s} s")
        time.sleep(0.1)


def replica(dir_a, src_name, dir_b, rep_name, status_path, secs, late_s=None):
    """Every replica chunk that carries a bound (port format 2.4; chunks stamped at arrival,
    before the mirror has a clock map, carry none and are counted apart) is compared with the
    source's stamp of the same frames, the truth (the source is sim:pattern, whose stamps are
    its frames' due times, and both namespaces share CLOCK_MONOTONIC): covered when |error|
    is within the chunk's own bound. The status file's uncertainty is reported beside it."""
    t0 = time.monotonic()
    src, rep = open_port(dir_a, src_name), live_replica(dir_b, rep_name)
    nfpc = rep.info()["frames_per_chunk"]
    errors, bounds, clock_parts, covered, unbounded, misses, replaced = [], [], [], 0, 0, {}, 0
    first_bound_s, first_narrow_s, unc_seen = None, None, []
    late_errors, late_shift, late_covered = [], [], 0
    next_status = 0.0
    nxt = rep.last_frame_index + 1
    while time.monotonic() - t0 < secs:
        now = time.monotonic() - t0
        if now >= next_status:
            next_status = now + 1.0
            try:
                unc = json.load(open(status_path)).get("clock_uncertainty_ns")
                if unc is not None:
                    unc_seen.append(unc)
            except (OSError, ValueError):
                pass
            if rep.info()["state_name"] != "capturing":
                # The mirror replaced the replica (a new source geometry or epoch): follow the new one.
                rep.close()
                rep = live_replica(dir_b, rep_name)
                nxt = rep.last_frame_index + 1
                replaced += 1
        lfi = rep.last_frame_index
        while nxt + nfpc - 1 <= lfi:
            try:
                r, s = rep.chunk_info(nxt), src.chunk_info(nxt)
            except Exception as e:  # the chunk left one of the windows: skip it, counted by reason
                why = f"{type(e).__name__}: {str(e)[:80]}"
                misses[why] = misses.get(why, 0) + 1
                nxt += nfpc
                continue
            gap = r.flags & 1  # GAP chunks are stamped by the mirror, not mapped
            if not gap and r.first_frame == s.first_frame:
                e = abs(r.mono_ns - s.mono_ns)
                if r.bound_ns is None:
                    unbounded += 1
                else:
                    seen = time.monotonic() - t0
                    first_bound_s = seen if first_bound_s is None else first_bound_s
                    if first_narrow_s is None and r.bound_ns <= 100_000:
                        first_narrow_s = seen
                    errors.append(e / 1e3)
                    bounds.append(r.bound_ns / 1e3)
                    if s.bound_ns is not None:
                        clock_parts.append((r.bound_ns - s.bound_ns) / 1e3)
                    covered += e <= r.bound_ns
                    if late_s is not None and seen >= late_s:
                        late_errors.append(e / 1e3)
                        late_covered += e <= r.bound_ns
                        if r.realtime_ns and s.realtime_ns:
                            late_shift.append((r.realtime_ns - s.realtime_ns) / 1e6)
            nxt = r.first_frame + r.frames
        time.sleep(0.002)
    out = {"error_us": quantiles(errors), "bound_us": quantiles(bounds), "clock_part_us": quantiles(clock_parts),
           "uncertainty_us": quantiles([u / 1e3 for u in unc_seen]), "covered": covered, "chunks": len(errors),
           "unbounded": unbounded, "first_bound_s": first_bound_s, "first_bound_100us_s": first_narrow_s,
           "skipped": misses, "replica_replaced": replaced}
    if late_s is not None:
        out["late"] = {"after_s": late_s, "error_us": quantiles(late_errors), "covered": late_covered,
                       "realtime_shift_ms": quantiles(late_shift)}
    print(json.dumps(out))


def lsl_outlet(name, secs):
    import pylsl

    info = pylsl.StreamInfo(name, "Bench", 1, 0, pylsl.cf_int32, name)
    outlet = pylsl.StreamOutlet(info)
    time.sleep(secs)
    del outlet


def lsl_inlet(name, secs):
    import pylsl

    streams = pylsl.resolve_byprop("name", name, timeout=10)
    if not streams:
        print(json.dumps({"error": f"no LSL stream {name!r} found in 10 s"}))
        return
    inlet = pylsl.StreamInlet(streams[0])
    values, t0, first = [], time.monotonic(), None
    while time.monotonic() - t0 < secs:
        try:
            values.append(abs(inlet.time_correction(timeout=2.0)) * 1e6)
            first = first if first is not None else time.monotonic() - t0
        except pylsl.TimeoutError:
            pass
        time.sleep(0.2)
    print(json.dumps({"error_us": quantiles(values), "first_s": first}))


if __name__ == "__main__":
    a = sys.argv[1:]
    if a[:1] == ["replica"] and len(a) in (7, 8):
        replica(a[1], a[2], a[3], a[4], a[5], float(a[6]), float(a[7]) if len(a) == 8 else None)
    elif a[:1] == ["lsl-outlet"] and len(a) == 3:
        lsl_outlet(a[1], float(a[2]))
    elif a[:1] == ["lsl-inlet"] and len(a) == 3:
        lsl_inlet(a[1], float(a[2]))
    else:
        sys.exit(__doc__)
