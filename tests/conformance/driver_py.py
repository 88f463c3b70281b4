#!/usr/bin/env python3
"""Conformance driver in Python: replays vectors.txt through the `bass` package (ctypes over the
writer and reader C ABI) and prints the file back with the `read` results observed.
Usage: driver_py.py VECTORS > OUT   (ports in $BASS_RUNTIME_DIR)"""

import os
import sys

import numpy as np

sys.path.insert(0, os.path.join(os.path.dirname(os.path.abspath(__file__)), "..", "..", "python"))
import bass  # noqa: E402


def main(path):
    out = sys.stdout
    writer = port = None
    name = f"conf-py-{os.getpid()}"
    with open(path) as f:
        for line in f:
            tok = line.split()
            if not tok:
                continue
            if tok[0] == "case":
                channels, rate, fpc, cop = map(int, tok[2:6])
                writer = bass.Writer(name, rate, fpc, cop, channels, device="conformance")
                port = bass.Port(name)
                out.write(" ".join(tok) + "\n")
            elif tok[0] == "publish":
                samples = np.array([int(v) for v in tok[1:]], dtype=np.int32)
                writer.publish(samples)
                out.write(" ".join(["publish"] + [str(int(v)) for v in samples]) + "\n")
            elif tok[0] == "read":
                n_frames, nfr = int(tok[1]), int(tok[2])
                d = port.get_audio_data(n_frames, nfr)
                inter = np.empty(2 * d.n, dtype=np.int64)
                inter[0::2], inter[1::2] = d.left, d.right
                out.write(" ".join(map(str, ["read", n_frames, nfr, d.n, d.nfr, d.loss] + inter.tolist())) + "\n")
            elif tok[0] == "readm":
                n_frames, nfr = int(tok[1]), int(tok[2])
                data, nfr_out, n, loss = port.get_audio_data_multi(n_frames, nfr)
                inter = data.T.reshape(-1).astype(np.int64).tolist()
                out.write(" ".join(map(str, ["readm", n_frames, nfr, n, nfr_out, loss] + inter)) + "\n")
            elif tok[0] == "end":
                port.close()
                writer.close()
                out.write("end\n")
            else:
                out.write(" ".join(tok) + "\n")


if __name__ == "__main__":
    main(sys.argv[1])
