#!/usr/bin/python3
"""Writes a copy of a model with lids (gazesplat train --lids) whose lids'
share of the pitch, face.lid_k [2, 13, 7], is a hand-set field, or shows
the field a model has:

    lid_field.py IN OUT [--upper K] [--lower K] [--corner F] [--scale S]
    lid_field.py --show IN

Knots of elevation 15..75 degrees (above the eyeball's centre) get K upper
(0.85), of -75..-15 degrees K lower (0.3), the others 0; the outermost
azimuth columns (+-90 degrees) are multiplied by F (0.3); everything by S
(1; -1 negates the field, 0 zeroes it). docs/model.md, "Lids that follow
the gaze", and experiments/eval/README.md use it to ask whether placed lids help
when the training has not learned them.

--show prints each eye's knots (rows: elevation -90..90 degrees every 15,
columns: azimuth -90..90 every 30) and the mean of the inner columns
(azimuth -60..60) over the upper knots (elevation 15..45) and the lower
ones (-45..-15): the synthetic heads turn their lid margins by 0.85 and
0.3 of the pitch.
"""
import argparse
import json
import struct

import numpy as np

NV, NU, DV = 13, 7, 15.0


def lid_k(data, path):
    """The header length, the header and face.lid_k's entry of a model."""
    n = struct.unpack("<Q", data[:8])[0]
    head = json.loads(data[8:8 + n])
    if "face.lid_k" not in head:
        raise SystemExit(f"{path}: no lids (gazesplat train --lids)")
    e = head["face.lid_k"]
    if e["dtype"] != "F32" or e["shape"] != [2, NV, NU]:
        raise SystemExit(f"{path}: face.lid_k is {e['dtype']} {e['shape']}")
    return n, e


def show(path):
    data = open(path, "rb").read()
    n, e = lid_k(data, path)
    lo, hi = e["data_offsets"]
    k = np.frombuffer(data[8 + n + lo:8 + n + hi], dtype="<f4")
    k = k.reshape(2, NV, NU)
    el = [-90.0 + DV * v for v in range(NV)]
    for eye in range(2):
        print(f"eye {eye}: elevation (rows) x azimuth -90..90 every 30 (columns)")
        for v in range(NV - 1, -1, -1):
            print(f"  {el[v]:+5.0f}  " + " ".join(f"{x:+5.2f}" for x in k[eye, v]))
        up = [v for v in range(NV) if 15 <= el[v] <= 45]
        dn = [v for v in range(NV) if -45 <= el[v] <= -15]
        print(f"  upper knots (15..45, inner columns) mean {k[eye][up, 1:-1].mean():.2f}, "
              f"lower (-45..-15) {k[eye][dn, 1:-1].mean():.2f}")


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--show", action="store_true")
    ap.add_argument("src")
    ap.add_argument("dst", nargs="?")
    ap.add_argument("--upper", type=float, default=0.85)
    ap.add_argument("--lower", type=float, default=0.3)
    ap.add_argument("--corner", type=float, default=0.3)
    ap.add_argument("--scale", type=float, default=1.0)
    a = ap.parse_args()
    if a.show:
        show(a.src)
        return
    if a.dst is None:
        ap.error("OUT is needed unless --show")
    data = bytearray(open(a.src, "rb").read())
    n, e = lid_k(data, a.src)
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
