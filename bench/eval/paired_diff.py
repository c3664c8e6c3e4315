#!/usr/bin/python3
"""Two `gazesplat eval --readout` runs over the same pairs, side by side:
per pair set (all pairs, gaze only, head change) the mean readout gaze
error of each run, their mean difference (B - A) and its 95 % paired
bootstrap interval (pairs resampled with replacement, the same resample
for both runs; fixed seed, so the figures repeat), with the PSNR's mean
difference. A pair counts when both runs evaluated it ("ok" with a
readout); pairs only one run has are named and left out.

    bench/eval/paired_diff.py A/pairs.csv B/pairs.csv [A2 B2 ...]
        [--method M] [--reps N] [--leave-out-input K:I ...]

More than one pairing (A2 against B2: another pairs file, such as the
test pairs beside the validation pairs) pools them: one table over all
their pairs, each pair resampled as one. --leave-out-input K:I leaves
out input I of the K-th pairing (0: the first), to read a difference
without one input's fits (repeatable). --method: the method compared
(default transfer); --reps: bootstrap resamples (default 10000).
Standard library only.

The interval counts the pairs' spread, not the fits': a change in the
last digits of a fit's arithmetic moves a 15-input run's mean by about
0.1 deg (experiments/eval/README.md, "A prior on the fit's expression and
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


def leave_outs(specs, npairings):
    out = set()
    for spec in specs:
        k, _, i = spec.partition(":")
        if not (k.isdigit() and i.isdigit()) or int(k) >= npairings:
            sys.exit(f"--leave-out-input {spec}: want K:I, K a pairing "
                     f"0..{npairings - 1} and I an input")
        out.add((int(k), i))
    return out


def main():
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("runs", nargs="+", metavar="A B")
    ap.add_argument("--method", default="transfer")
    ap.add_argument("--reps", type=int, default=10000)
    ap.add_argument("--leave-out-input", action="append", default=[])
    o = ap.parse_args()
    if o.reps < 100:
        sys.exit("--reps: want at least 100")
    if len(o.runs) < 2 or len(o.runs) % 2:
        sys.exit("want runs in pairs: A B [A2 B2 ...]")
    drop = leave_outs(o.leave_out_input, len(o.runs) // 2)
    A, B, common = {}, {}, []
    for k in range(len(o.runs) // 2):
        fa, fb = o.runs[2 * k], o.runs[2 * k + 1]
        a, b = rows_of(fa, o.method), rows_of(fb, o.method)
        if not a or not b:
            sys.exit(f"no '{o.method}' rows with a readout in "
                     f"{fa if not a else fb} (run eval with --readout)")
        only = sorted(set(a) ^ set(b), key=int)
        if only:
            print(f"pairs in one run only (left out){f' of pairing {k}' if k else ''}: "
                  f"{', '.join(only)}")
        for p in sorted(set(a) & set(b), key=int):
            if (a[p]["input"], a[p]["head_change"]) != (b[p]["input"], b[p]["head_change"]):
                sys.exit(f"pair {p} is another pair in {fa} and {fb}: not "
                         "the same pairs file")
            if (k, a[p]["input"]) in drop:
                continue
            A[(k, p)], B[(k, p)] = a[p], b[p]
            common.append((k, p))
    if not common:
        sys.exit("no pairs left to compare")
    rng = random.Random(12345)
    names = " + ".join(f"`{o.runs[2 * k]}`" for k in range(len(o.runs) // 2))
    namesb = " + ".join(f"`{o.runs[2 * k + 1]}`" for k in range(len(o.runs) // 2))
    left = (f", inputs left out: {', '.join(sorted(o.leave_out_input))}"
            if o.leave_out_input else "")
    print(f"\n{names} (A) against {namesb} (B), method {o.method}, "
          f"{o.reps} paired resamples{left}\n")
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
