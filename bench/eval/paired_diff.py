#!/usr/bin/python3
"""Two `gazesplat eval --readout` runs over the same pairs, side by side:
per pair set (all pairs, gaze only, head change) the mean readout gaze
error of each run, their mean difference (B - A) and its 95 % paired
bootstrap interval (pairs resampled with replacement, the same resample
for both runs; fixed seed, so the figures repeat), with the PSNR's mean
difference. A pair counts when both runs evaluated it ("ok" with a
readout); pairs only one run has are named and left out.

    bench/eval/paired_diff.py A/pairs.csv B/pairs.csv [--method M] [--reps N]

--method: the method compared (default transfer); --reps: bootstrap
resamples (default 10000). Standard library only.

The interval counts the pairs' spread, not the fits': a change in the
last digits of a fit's arithmetic moves a 15-input run's mean by about
0.1 deg (bench/eval/README.md, "A prior on the fit's expression and
lights"), so a difference that small is not an effect even when its
interval leaves zero."""
import argparse
import csv
import random
import statistics
import sys

SETS = (("all pairs", None), ("gaze only", "0"), ("head change", "1"))


def rows_of(path, method):
    with open(path) as f:
        out = {}
        for r in csv.DictReader(f):
            if (r["method"] == method and r["status"] == "ok" and
                    r.get("read_gaze_err_deg")):
                out[r["pair"]] = r
        return out


def interval(diffs, reps, rng):
    n = len(diffs)
    means = sorted(sum(diffs[rng.randrange(n)] for _ in range(n)) / n
                   for _ in range(reps))
    return means[int(0.025 * reps)], means[min(reps - 1, int(0.975 * reps))]


def main():
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("a")
    ap.add_argument("b")
    ap.add_argument("--method", default="transfer")
    ap.add_argument("--reps", type=int, default=10000)
    o = ap.parse_args()
    if o.reps < 100:
        sys.exit("--reps: want at least 100")
    A, B = rows_of(o.a, o.method), rows_of(o.b, o.method)
    if not A or not B:
        sys.exit(f"no '{o.method}' rows with a readout in "
                 f"{o.a if not A else o.b} (run eval with --readout)")
    common = sorted(set(A) & set(B), key=int)
    only = sorted(set(A) ^ set(B), key=int)
    if only:
        print(f"pairs in one run only (left out): {', '.join(only)}")
    for p in common:
        if (A[p]["input"], A[p]["head_change"]) != (B[p]["input"], B[p]["head_change"]):
            sys.exit(f"pair {p} is another pair in the two runs: not the "
                     "same pairs file")
    rng = random.Random(12345)
    print(f"\n`{o.a}` (A) against `{o.b}` (B), method {o.method}, "
          f"{o.reps} paired resamples\n")
    print("| pairs | n | A gaze° | B gaze° | B − A | 95 % interval | "
          "B − A PSNR dB |")
    print("|---|---:|---:|---:|---:|---|---:|")
    for name, hc in SETS:
        ps = [p for p in common if hc is None or A[p]["head_change"] == hc]
        if not ps:
            continue
        a = [float(A[p]["read_gaze_err_deg"]) for p in ps]
        b = [float(B[p]["read_gaze_err_deg"]) for p in ps]
        d = [y - x for x, y in zip(a, b)]
        lo, hi = interval(d, o.reps, rng)
        dp = statistics.mean(float(B[p]["psnr"]) - float(A[p]["psnr"])
                             for p in ps)
        print(f"| {name} | {len(ps)} | {statistics.mean(a):.2f} | "
              f"{statistics.mean(b):.2f} | {statistics.mean(d):+.2f} | "
              f"{lo:+.2f} to {hi:+.2f} | {dp:+.2f} |")


if __name__ == "__main__":
    main()
