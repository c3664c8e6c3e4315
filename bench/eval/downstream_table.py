#!/usr/bin/python3
"""The table of an `gazesplat eval-downstream` run with intervals across
people: per k, the mean gaze error of each condition over the identities,
and the paired differences real+ours - real and real+ours - real+warp
(per identity, then the mean over identities) with their 95 % bootstrap
intervals (identities resampled with replacement, the same resample for
every column; fixed seed, so the figures repeat) and the relative change
of real+ours against real only.

    bench/eval/downstream_table.py DIR [DIR2 ...] [--reps N]

Several DIRs (runs over disjoint identities, e.g. --first-identity
slices) pool their rows; an identity in two runs is an error. Only
identities with every condition at a k count at that k. Standard library
only; prints Markdown."""
import argparse
import csv
import os
import random
import statistics
import sys

CONDS = ("real", "real+ours", "real+warp")


def load(dirs):
    rows = {}
    owner = {}
    for d in dirs:
        path = os.path.join(d, "downstream.csv")
        with open(path, newline="") as f:
            for r in csv.DictReader(f):
                ident, k = int(r["identity"]), int(r["k"])
                if owner.setdefault(ident, d) != d:
                    sys.exit(f"downstream_table.py: identity {ident} is in "
                             f"{owner[ident]} and {d}")
                rows[(ident, k, r["condition"])] = float(r["gaze_err_deg"])
    return rows


def interval(values, reps, rng):
    n = len(values)
    means = sorted(statistics.fmean(rng.choices(values, k=n))
                   for _ in range(reps))
    return means[int(0.025 * reps)], means[int(0.975 * reps) - 1]


def table(rows, reps):
    ks = sorted({k for (_, k, _) in rows})
    out = ["| k | people | real only | real + ours | real + warp | "
           "ours - real (95 %) | ours - warp (95 %) | ours vs real |",
           "|---:|---:|---:|---:|---:|---|---|---:|"]
    for k in ks:
        ids = sorted({i for (i, kk, _) in rows if kk == k and
                      all((i, k, c) in rows for c in CONDS)})
        if not ids:
            continue
        col = {c: [rows[(i, k, c)] for i in ids] for c in CONDS}
        d_real = [o - r for o, r in zip(col["real+ours"], col["real"])]
        d_warp = [o - w for o, w in zip(col["real+ours"], col["real+warp"])]
        rng = random.Random(12345 + k)
        lo1, hi1 = interval(d_real, reps, rng) if len(ids) > 1 else (0, 0)
        lo2, hi2 = interval(d_warp, reps, rng) if len(ids) > 1 else (0, 0)
        m = {c: statistics.fmean(v) for c, v in col.items()}
        rel = 100.0 * (m["real+ours"] - m["real"]) / m["real"]
        out.append(f"| {k} | {len(ids)} | {m['real']:.2f} | "
                   f"{m['real+ours']:.2f} | {m['real+warp']:.2f} | "
                   f"{statistics.fmean(d_real):+.2f} ({lo1:+.2f} to "
                   f"{hi1:+.2f}) | {statistics.fmean(d_warp):+.2f} "
                   f"({lo2:+.2f} to {hi2:+.2f}) | {rel:+.1f} % |")
    return "\n".join(out)


def main():
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("dirs", nargs="+")
    ap.add_argument("--reps", type=int, default=10000)
    a = ap.parse_args()
    print(table(load(a.dirs), a.reps))


if __name__ == "__main__":
    main()
