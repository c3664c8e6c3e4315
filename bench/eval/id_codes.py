#!/usr/bin/python3
"""Where the fits' identity codes end, against the codes training learned.

usage: id_codes.py MODEL DIR [DIR ...]

MODEL is a model file (safetensors; its `codes.train` tensor holds one
learned identity code per training identity, `codes.mean` the mean code
every fit starts from). Each DIR is a `gazesplat eval --out DIR` folder:
its fits/NNNNN.bin are the fitted subjects (fit_codes.py reads the same
files), whose first id_dim code values are the identity.

Per DIR: the fits' distance from the mean identity code, and their
squared Mahalanobis norm under the learned codes' Gaussian (mean and
covariance over the training identities, with a ridge of 1 % of the
mean variance), beside the learned codes' own. A fit far outside the
learned codes has a norm well above theirs (about id_dim).

When DIR's pairs.csv is of training identities (its summary.md says
`--split train`), each
fit is also compared with its own face's learned code: the distance,
how many other learned codes are nearer the fit than that one (0: the
fit is nearest its own face), and how far the learned code lies from the
mean. Held-out pairs have no learned code, and those columns say so.
"""
import csv
import json
import math
import os
import struct
import sys

import numpy as np

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
from fit_codes import read_code  # noqa: E402  (the one reader of fit caches)


def fail(msg):
    sys.exit(f"id_codes.py: {msg}")


def load_codes(path):
    try:
        with open(path, "rb") as f:
            n = struct.unpack("<Q", f.read(8))[0]
            if n > 100_000_000:
                fail(f"{path}: header of {n} bytes")
            head = json.loads(f.read(n))
            base = 8 + n
            out = {}
            for k in ("codes.train", "codes.mean"):
                if k not in head:
                    fail(f"{path}: no {k} tensor (a model without training codes)")
                t = head[k]
                if t.get("dtype") != "F32":
                    fail(f"{path}: {k} is {t.get('dtype')}, want F32")
                a, b = t["data_offsets"]
                f.seek(base + a)
                raw = f.read(b - a)
                shape = t["shape"]
                if len(raw) != 4 * math.prod(shape):
                    fail(f"{path}: {k} is truncated")
                out[k] = np.frombuffer(raw, "<f4").reshape(shape).astype(np.float64)
    except (OSError, ValueError, KeyError, struct.error) as e:
        fail(f"{path}: not a model file ({e})")
    if out["codes.train"].ndim != 2 or out["codes.train"].shape[0] < 2:
        fail(f"{path}: codes.train of shape {list(out['codes.train'].shape)}")
    return out["codes.train"], out["codes.mean"]


def identities(d):
    """input -> training identity, or None for held-out pairs (the
    summary of a run on training pairs says `--split train`)."""
    p, md = os.path.join(d, "pairs.csv"), os.path.join(d, "summary.md")
    if not os.path.exists(p) or not os.path.exists(md):
        return None
    with open(md) as f:
        if "(`--split train`)" not in f.read():
            return None
    out = {}
    with open(p) as f:
        for r in csv.DictReader(f):
            out[int(r["input"])] = int(r["identity"])
    return out


def main():
    if len(sys.argv) < 3:
        fail("usage: id_codes.py MODEL DIR [DIR ...]")
    learned, mean_code = load_codes(sys.argv[1])
    n_ids, id_dim = learned.shape
    mu = learned.mean(axis=0)
    cov = np.cov(learned.T)
    cov += 0.01 * np.trace(cov) / id_dim * np.eye(id_dim)
    prec = np.linalg.inv(cov)

    def maha(x):
        d = x - mu
        return float(d @ prec @ d)

    own = [maha(c) for c in learned]
    start = mean_code[:id_dim]
    print(f"model `{os.path.basename(sys.argv[1])}`: {n_ids} learned identity codes of "
          f"{id_dim}; their distance from the mean code: mean "
          f"{np.mean(np.linalg.norm(learned - start, axis=1)):.2f}; squared "
          f"Mahalanobis norm: mean {np.mean(own):.1f}, median {np.median(own):.1f}\n")
    print("| fits | n | from the mean code | Mahalanobis² mean / median | training faces: "
          "from its own learned code | nearer learned codes (median) | nearest its own |")
    print("|---|---:|---:|---:|---:|---:|---:|")
    details = []
    for d in sys.argv[2:]:
        fd = os.path.join(d, "fits")
        if not os.path.isdir(fd):
            fail(f"{d}: no fits folder")
        files = sorted(x for x in os.listdir(fd) if x.endswith(".bin"))
        if not files:
            fail(f"{d}: no fits")
        codes = {int(x[:-4]): np.array(read_code(os.path.join(fd, x))) for x in files}
        for k, c in codes.items():
            if len(c) <= id_dim:
                fail(f"{d}: fit {k} has a code of {len(c)} values; the model's "
                     f"identity alone is {id_dim}")
        ids = identities(d)
        ms = [maha(c[:id_dim]) for c in codes.values()]
        far = np.mean([np.linalg.norm(c[:id_dim] - start) for c in codes.values()])
        train = ids is not None and all(k in ids and 0 <= ids[k] < n_ids for k in codes)
        own_cols = "– | – | –"
        if train:
            dist, ranks = [], []
            for k, c in sorted(codes.items()):
                x, t = c[:id_dim], learned[ids[k]]
                dd = np.linalg.norm(learned - x, axis=1)
                rank = int((dd < dd[ids[k]]).sum())
                dist.append(float(np.linalg.norm(x - t)))
                ranks.append(rank)
                details.append(f"| `{d}` | {k} | {ids[k]} | {dist[-1]:.2f} | {rank} | "
                               f"{np.linalg.norm(t - start):.2f} |")
            own_cols = (f"{np.mean(dist):.2f} | {np.median(ranks):.0f} | "
                        f"{sum(r == 0 for r in ranks)} of {len(ranks)}")
        print(f"| `{d}` | {len(codes)} | {far:.2f} | {np.mean(ms):.1f} / {np.median(ms):.1f} | "
              f"{own_cols} |")
    if details:
        print("\n| fits | input | identity | from its own learned code | nearer learned "
              "codes | its learned code from the mean |")
        print("|---|---:|---:|---:|---:|---:|")
        print("\n".join(details))


if __name__ == "__main__":
    main()
