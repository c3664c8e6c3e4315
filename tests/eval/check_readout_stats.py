#!/usr/bin/python3
"""bench/eval/readout_stats.py on made-up runs with known figures.

Gaze-only pairs read 1 degree off, head changes 4 (target head inside the
default 40,25 range) or 10 (outside). Head changes whose target looks down
(pitch -20) read 6 degrees higher than the truth, those looking up (+20)
2 lower, the middle ones (0) exactly; gaze-only pairs read 0.5 higher.
The tables must give those means, shares, splits and signs, over all
pairs and per input face; a file
without the target pose and gaze columns gets neither the split nor the
pitch table; a bad --head-range and a file without the readout are
refused."""
import csv
import os
import re
import subprocess
import sys
import tempfile

script = sys.argv[1]
BASE = ["method", "pair", "input", "head_change", "gaze_change_deg",
        "head_change_deg", "status", "read_gaze_err_deg",
        "read_floor_gaze_deg"]
TARGET = ["read_pitch_deg", "target_pitch_deg", "target_head_pitch_deg",
          "target_head_yaw_deg"]


def write(path, cols, rows):
    with open(path, "w", newline="") as f:
        w = csv.writer(f)
        w.writerow(cols)
        w.writerows([r[:len(cols)] for r in rows])


def run(*args):
    return subprocess.run([sys.executable, script, *args],
                          capture_output=True, text=True)


def fail(msg, out=""):
    print(out)
    sys.exit("check_readout_stats: " + msg)


def table_row(out, *cells):
    """The numbers after the named leading cells of a table row."""
    lead = r"\| " + r" \| ".join(re.escape(c) for c in cells) + r" \|"
    m = re.search(lead + r"((?: [^|]+ \|)+)", out)
    if not m:
        fail(f"no row {cells}", out)
    return [float(x.strip().rstrip("%").strip())
            for x in m.group(1).split("|") if x.strip()]


rows = []
for p in range(40):
    hc = p % 2
    pitch = (-20.0, 0.0, 20.0)[p % 3]
    if hc:
        outside = p % 4 == 3  # a quarter of the pairs: head yaw 45
        err = 10.0 if outside else 4.0
        dp = {-20.0: 6.0, 0.0: 0.0, 20.0: -2.0}[pitch]
        hy, hp = (45.0 if outside else 10.0), 5.0
    else:
        err, dp, hy, hp = 1.0, 0.5, 0.0, 0.0
    rows.append(["transfer", p, p // 10, hc, 10.0, 30.0 * hc, "ok", err,
                 0.05, pitch + dp, pitch, hp, hy])
rows.append(["transfer", 40, 4, 1, 10.0, 30.0, "diverged", "", "", "", "",
             "", ""])  # not read: left out

with tempfile.TemporaryDirectory() as d:
    full, old = os.path.join(d, "full.csv"), os.path.join(d, "old.csv")
    write(full, BASE + TARGET, rows)
    write(old, BASE, rows)
    r = run(full)
    if r.returncode:
        fail("the run failed: " + r.stderr)
    out = r.stdout
    print(out)
    n, mean, med, w2, w5 = table_row(out, "transfer", "gaze only")
    if (n, mean, med, w2, w5) != (20, 1.0, 1.0, 100, 100):
        fail(f"gaze only: {n} {mean} {med} {w2} {w5}", out)
    inside = [r for r in rows[:40] if r[3] == 1 and r[12] == 10.0]
    n_in = len(inside)
    n, mean, _, w2, w5 = table_row(out, "transfer",
                                   "head change, target inside 40,25")
    if (n, mean, w2, w5) != (n_in, 4.0, 0, 100):
        fail(f"inside: {n} {mean} {w2} {w5}, want {n_in} pairs", out)
    n, mean, _, _, w5 = table_row(out, "transfer",
                                  "head change, target outside 40,25")
    if (n, mean, w5) != (20 - n_in, 10.0, 0):
        fail(f"outside: {n} {mean} {w5}", out)
    n, mean, _, _, _ = table_row(out, "transfer", "head change")
    if n != 20 or abs(mean - (4.0 * n_in + 10.0 * (20 - n_in)) / 20) > 0.006:
        fail(f"head change: {n} {mean}", out)
    n, mean, _, _, _ = table_row(out, "transfer", "all pairs")
    want = (20 * 1.0 + 4.0 * n_in + 10.0 * (20 - n_in)) / 40
    if n != 40 or abs(mean - want) > 0.006:
        fail(f"all pairs: {n} {mean}, want 40 pairs, {want:.2f}", out)
    for face in range(4):  # per input face: its ten pairs
        v = [r[7] for r in rows[:40] if r[2] == face]
        got = table_row(out, "transfer", str(face))
        if (got[0] != 10 or abs(got[1] - sum(v) / 10) > 0.006 or
                got[3] != max(v)):
            fail(f"input {face}: {got}, want mean {sum(v) / 10:.2f}, "
                 f"largest {max(v)}", out)
    for pitch, want in (("< -15°", 6.0), ("-15-15°", 0.0), ("> 15°", -2.0)):
        v = table_row(out, "transfer", "head change", pitch)
        if v[1] != want:
            fail(f"head change, target pitch {pitch}: {v[1]}, want {want}", out)
        v = table_row(out, "transfer", "gaze only", pitch)
        if v[1] != 0.5 or v[2] != 1.0:
            fail(f"gaze only, target pitch {pitch}: {v}", out)
    # a wider range takes the yaw-45 heads inside
    r = run("--head-range", "50,30", full)
    n, mean, _, _, _ = table_row(r.stdout, "transfer",
                                 "head change, target inside 50,30")
    if r.returncode or n != 20 or "outside 50,30" in r.stdout:
        fail("--head-range 50,30 did not take every head inside", r.stdout)
    # an older file: the plain rows only
    r = run(old)
    if r.returncode or "target inside" in r.stdout or \
            "target pitch" in r.stdout or "| transfer | gaze only |" not in r.stdout:
        fail("a file without the target columns", r.stdout + r.stderr)
    # refusals
    for bad in ("x", "0,25", "40,91", "40"):
        r = run("--head-range", bad, full)
        if r.returncode == 0 or "--head-range" not in r.stderr:
            fail(f"--head-range {bad} was not refused", r.stdout + r.stderr)
    write(old, ["method", "pair", "head_change", "status"],
          [x[:4] for x in rows])
    r = run(old)
    if r.returncode == 0 or "readout" not in r.stderr:
        fail("a file without the readout was not refused", r.stderr)
print("check_readout_stats: ok")
