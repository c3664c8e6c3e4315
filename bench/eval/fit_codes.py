#!/usr/bin/python3
"""How far the fits' expression and lights are from the truth.

usage: fit_codes.py TRUTH_DIR DIR [DIR ...]

Each DIR is a `gazesplat eval --out DIR` folder (or its fits/ folder): its
fits/NNNNN.bin are the fitted subjects: the 8 bytes "GSFITC2\n", the
8-byte key of what made the fit, the 8-byte fit time, then
gs_subject_encode (magic, version, code_dim, the code as float32, ...).
Caches written before fits were keyed (no "GSFITC2\n", the fit time
first) are read too.
TRUTH_DIR is a run with `--true-code expr,light` on the same pairs, whose
codes hold each input's true expression and lights (gs_model_scene_code).
The code is [identity (code_dim - 18) | expression (6) | lights (12)].

For each DIR: how many expression slots lie outside the synthetic
sampler's range (mouth_open, smile, squint, blink from 0; brow_raise and
pupil from -1; squint up to 0.7, the others up to 1), how many sit on one
of its ends, the mean absolute error of each expression slot, and the
mean L1 error of the 12 light slots, over the inputs both runs fitted.
"""
import os
import struct
import sys

EXPR = ["mouth_open", "smile", "brow_raise", "squint", "blink", "pupil"]
LO = [0.0, 0.0, -1.0, 0.0, 0.0, -1.0]
HI = [1.0, 1.0, 1.0, 0.7, 1.0, 1.0]
NEXPR, NLIGHT = 6, 12
MAGIC = 0x42555347  # "GSUB", GS_SUBJECT_MAGIC
CACHE_MAGIC = b"GSFITC2\n"  # lib/eval/fit.c: magic, key, seconds (24 bytes)
EPS = 1e-6


def fail(msg):
    sys.exit(f"fit_codes.py: {msg}")


def fits_dir(d):
    sub = os.path.join(d, "fits")
    return sub if os.path.isdir(sub) else d


def read_code(path):
    with open(path, "rb") as f:
        b = f.read()
    head = 24 if b[:8] == CACHE_MAGIC else 8
    if len(b) < head + 12:
        fail(f"{path}: too short for a fit cache file")
    magic, _ver, dim = struct.unpack_from("<III", b, head)
    if magic != MAGIC:
        fail(f"{path}: not a fit cache file (magic {magic:#x})")
    if dim <= NEXPR + NLIGHT or len(b) < head + 12 + 4 * dim:
        fail(f"{path}: code of {dim} values does not fit the file")
    return list(struct.unpack_from(f"<{dim}f", b, head + 12))


def read_dir(d):
    fd = fits_dir(d)
    if not os.path.isdir(fd):
        fail(f"{d}: no fits folder")
    codes = {f: read_code(os.path.join(fd, f))
             for f in sorted(os.listdir(fd)) if f.endswith(".bin")}
    if not codes:
        fail(f"{d}: no fits")
    return codes


def main():
    if len(sys.argv) < 3:
        fail("usage: fit_codes.py TRUTH_DIR DIR [DIR ...]")
    truth = read_dir(sys.argv[1])
    print(f"truth: `{sys.argv[1]}` ({len(truth)} fits)\n")
    print("| fits | n | expression slots outside the range | on an end | "
          + " | ".join(f"{e} err" for e in EXPR) + " | lights L1 err |")
    print("|---|---:|---:|---:|" + "---:|" * NEXPR + "---:|")
    for d in sys.argv[2:]:
        codes = read_dir(d)
        common = [f for f in codes if f in truth]
        if not common:
            fail(f"{d}: no input in common with the truth run")
        outside = ends = 0
        err = [0.0] * NEXPR
        light = 0.0
        for f in common:
            a, t = codes[f], truth[f]
            if len(a) != len(t):
                fail(f"{d}/{f}: code of {len(a)} values, the truth's {len(t)}")
            e0 = len(a) - NEXPR - NLIGHT
            for k in range(NEXPR):
                v = a[e0 + k]
                outside += v < LO[k] - EPS or v > HI[k] + EPS
                ends += abs(v - LO[k]) <= EPS or abs(v - HI[k]) <= EPS
                err[k] += abs(v - t[e0 + k])
            light += sum(abs(x - y) for x, y in
                         zip(a[e0 + NEXPR:], t[e0 + NEXPR:]))
        n = len(common)
        print(f"| `{d}` | {n} | {outside} of {n * NEXPR} | {ends} | "
              + " | ".join(f"{e / n:.3f}" for e in err)
              + f" | {light / n:.2f} |")


if __name__ == "__main__":
    main()
