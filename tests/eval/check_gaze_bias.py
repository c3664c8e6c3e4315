#!/usr/bin/python3
"""bench/eval/gaze_bias.py on pairs with a known error: the read pitch is
1.1 x the true pitch + 0.2 x the head's pitch turn + 2 deg, the read yaw the
true yaw + noise. The fit must find those slopes and that offset, explain
most of the pitch error, and leave about the noise once the fitted part is
taken away; a file without the truth columns is refused."""
import csv
import os
import random
import re
import subprocess
import sys
import tempfile

script = sys.argv[1]
cols = ["method", "pair", "input", "head_change", "read_pitch_deg",
        "read_yaw_deg", "target_pitch_deg", "target_yaw_deg",
        "target_head_pitch_deg", "target_head_yaw_deg", "read_gaze_err_deg"]
rnd = random.Random(7)
with tempfile.TemporaryDirectory() as d:
    path = os.path.join(d, "pairs.csv")
    with open(path, "w", newline="") as f:
        w = csv.writer(f)
        w.writerow(cols)
        pair = 0
        for inp in range(12):
            hp0, hy0 = rnd.uniform(-20, 20), rnd.uniform(-40, 40)
            for j in range(10):
                hc = j % 2
                hp = hp0 + (rnd.uniform(-25, 25) if hc else 0.0)
                hy = hy0 + (rnd.uniform(-40, 40) if hc else 0.0)
                tp, ty = rnd.uniform(-30, 30), rnd.uniform(-40, 40)
                rp = 1.1 * tp + 0.2 * (hp - hp0) + 2.0 + rnd.gauss(0, 0.3)
                ry = ty + rnd.gauss(0, 0.3)
                w.writerow(["transfer", pair, inp, hc, rp, ry, tp, ty, hp, hy, 1.0])
                pair += 1
    out = subprocess.run([sys.executable, script, path], capture_output=True,
                         text=True, check=True).stdout
    print(out)
    hc = out.split("head change")[1]
    m = re.search(r"pitch +signed error mean ([-+.\d]+) sd [.\d]+; fit: ([-+.\d]+) x true "
                  r"([-+.\d]+) x head turn ([-+.\d]+), explains (\d+) %", hc)
    assert m, hc
    a, b, c, r2 = float(m.group(2)), float(m.group(3)), float(m.group(4)), int(m.group(5))
    assert abs(a - 0.1) < 0.02 and abs(b - 0.2) < 0.02 and abs(c - 2.0) < 0.2 and r2 >= 95, m.groups()
    left = re.search(r"taken away: mean ([.\d]+) deg", hc)
    assert left and float(left.group(1)) < 1.0, hc
    # refused without the truth columns
    with open(path, "w") as f:
        f.write("method,pair,input,head_change,read_pitch_deg\n")
    r = subprocess.run([sys.executable, script, path], capture_output=True, text=True)
    assert r.returncode != 0 and "target_pitch_deg" in r.stderr, (r.returncode, r.stderr)
print("ok")
