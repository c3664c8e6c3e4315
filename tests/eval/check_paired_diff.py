#!/usr/bin/python3
"""bench/eval/paired_diff.py on two runs with a known difference: run B
reads every head-change pair 1 degree worse than run A plus noise of
0.5 degrees, and gaze-only pairs the same as A. The table must give +1.00
at a head change with an interval about it that excludes 0, 0 on gaze-only
pairs with an interval of width 0, +0.50 over all pairs; a pair only one
run has is named and left out; pooled with a second pairing 3 degrees
apart, one table over both, and an input left out of it drops its pairs;
runs over different pairs, a file without the readout, an odd count of
runs and bad leave-out specs are refused."""
import csv
import os
import random
import re
import subprocess
import sys
import tempfile

script = sys.argv[1]
cols = ["method", "pair", "input", "head_change", "status", "psnr",
        "read_gaze_err_deg"]
rnd = random.Random(3)


def write(path, rows):
    with open(path, "w", newline="") as f:
        w = csv.writer(f)
        w.writerow(cols)
        w.writerows(rows)


def run(*args):
    return subprocess.run([sys.executable, script, *args],
                          capture_output=True, text=True)


def fail(msg, out=""):
    print(out)
    sys.exit("check_paired_diff: " + msg)


with tempfile.TemporaryDirectory() as d:
    a, b = [], []
    for p in range(120):
        hc, e = p % 2, rnd.uniform(1, 10)
        a.append(["transfer", p, p // 10, hc, "ok", 30.0, e])
        a.append(["model", p, p // 10, hc, "ok", 25.0, e + 5])
        worse = 1.0 + rnd.gauss(0, 0.5) if hc else 0.0
        b.append(["transfer", p, p // 10, hc, "ok", 29.0, e + worse])
    a.append(["transfer", 120, 12, 0, "ok", 30.0, 2.0])  # A only
    pa, pb = os.path.join(d, "a.csv"), os.path.join(d, "b.csv")
    write(pa, a)
    write(pb, b)
    r = run(pa, pb, "--reps", "2000")
    if r.returncode:
        fail("the run failed: " + r.stderr)
    out = r.stdout
    print(out)
    if "left out): 120" not in out:
        fail("the pair only A has was not named", out)

    def row(name):
        m = re.search(r"\| " + name + r" \| (\d+) \| ([\d.]+) \| ([\d.]+) \| "
                      r"([+-][\d.]+) \| ([+-][\d.]+) to ([+-][\d.]+) \| "
                      r"([+-][\d.]+) \|", out)
        if not m:
            fail(f"no '{name}' row", out)
        return [float(x) for x in m.groups()]

    n, _, _, dm, lo, hi, dp = row("head change")
    if n != 60 or abs(dm - 1.0) > 0.2 or not (0 < lo < dm < hi) or hi - lo > 0.6:
        fail(f"head change: {dm} ({lo} to {hi}), n {n}", out)
    if dp != -1.0:
        fail(f"PSNR difference {dp}, want -1.00", out)
    n, _, _, dm, lo, hi, _ = row("gaze only")
    if n != 60 or dm != 0 or lo != 0 or hi != 0:
        fail(f"gaze only: {dm} ({lo} to {hi}), n {n}", out)
    n, _, _, dm, _, _, _ = row("all pairs")
    if n != 120 or abs(dm - 0.5) > 0.1:
        fail(f"all pairs: {dm}, n {n}", out)
    # pooled with a second pairing in which B reads every pair 3 degrees
    # worse: one table over 240 pairs; leaving out input 0 of the second
    # pairing drops its 10 pairs
    a2 = [["transfer", p, p // 10, p % 2, "ok", 30.0, rnd.uniform(1, 10)]
          for p in range(120)]
    b2 = [x[:6] + [x[6] + 3.0] for x in a2]
    pa2, pb2 = os.path.join(d, "a2.csv"), os.path.join(d, "b2.csv")
    write(pa2, a2)
    write(pb2, b2)
    r = run(pa, pb, pa2, pb2, "--reps", "2000")
    out = r.stdout
    if r.returncode:
        fail("the pooled run failed: " + r.stderr)
    n, _, _, dm, _, _, _ = row("all pairs")
    if n != 240 or abs(dm - 1.75) > 0.06:
        fail(f"pooled all pairs: {dm}, n {n}", out)
    n, _, _, dm, lo, hi, _ = row("gaze only")
    if n != 120 or dm != 1.5 or not (lo < 1.5 < hi):
        fail(f"pooled gaze only: {dm} ({lo} to {hi}), n {n}", out)
    r = run(pa, pb, pa2, pb2, "--reps", "2000", "--leave-out-input", "1:0")
    out = r.stdout
    n, _, _, dm, _, _, _ = row("all pairs")
    if r.returncode or n != 230 or "inputs left out: 1:0" not in out:
        fail(f"leave-out: n {n}", out + r.stderr)
    for bad in (["--leave-out-input", "2:0"], ["--leave-out-input", "x"]):
        r = run(pa, pb, pa2, pb2, *bad)
        if r.returncode == 0 or "leave-out-input" not in r.stderr:
            fail(f"{bad} was not refused", r.stderr)
    r = run(pa, pb, pa2)
    if r.returncode == 0 or "in pairs" not in r.stderr:
        fail("an odd count of runs was not refused", r.stderr)
    # the same pairs numbers for other pairs: refused
    b[0][2] = 99
    write(pb, b)
    r = run(pa, pb)
    if r.returncode == 0 or "not the same pairs" not in r.stderr:
        fail("other pairs under the same numbers were not refused", r.stderr)
    # no readout: refused
    write(pb, [x[:6] + [""] for x in b])
    r = run(pa, pb)
    if r.returncode == 0 or "readout" not in r.stderr:
        fail("a run without the readout was not refused", r.stderr)
print("check_paired_diff: ok")
