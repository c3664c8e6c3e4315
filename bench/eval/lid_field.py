#!/usr/bin/python3
"""Writes a copy of a model with lids (gazesplat train --lids) whose lids'
share of the pitch, face.lid_k [2, 13, 7], is a hand-set field:

    lid_field.py IN OUT [--upper K] [--lower K] [--corner F] [--scale S]

Knots of elevation 15..75 degrees (above the eyeball's centre) get K upper
(0.85), of -75..-15 degrees K lower (0.3), the others 0; the outermost
azimuth columns (+-90 degrees) are multiplied by F (0.3); everything by S
(1; -1 negates the field, 0 zeroes it). docs/model.md, "Lids that follow
the gaze", and bench/eval/README.md use it to ask whether placed lids help
when the training has not learned them.
"""
import argparse
import json
import struct

import numpy as np

NV, NU, DV = 13, 7, 15.0


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("src")
    ap.add_argument("dst")
    ap.add_argument("--upper", type=float, default=0.85)
    ap.add_argument("--lower", type=float, default=0.3)
    ap.add_argument("--corner", type=float, default=0.3)
    ap.add_argument("--scale", type=float, default=1.0)
    a = ap.parse_args()
    data = bytearray(open(a.src, "rb").read())
    n = struct.unpack("<Q", data[:8])[0]
    head = json.loads(data[8:8 + n])
    if "face.lid_k" not in head:
        raise SystemExit(f"{a.src}: no lids (gazesplat train --lids)")
    e = head["face.lid_k"]
    if e["dtype"] != "F32" or e["shape"] != [2, NV, NU]:
        raise SystemExit(f"{a.src}: face.lid_k is {e['dtype']} {e['shape']}")
    k = np.zeros((2, NV, NU))
    for v in range(NV):
        el = -90.0 + DV * v
        if 0 < el <= 75:
            k[:, v, :] = a.upper
        elif -75 <= el < 0:
            k[:, v, :] = a.lower
    k[:, :, 0] *= a.corner
    k[:, :, -1] *= a.corner
    k *= a.scale
    lo, hi = e["data_offsets"]
    data[8 + n + lo:8 + n + hi] = k.astype("<f4").tobytes()
    open(a.dst, "wb").write(bytes(data))


if __name__ == "__main__":
    main()
