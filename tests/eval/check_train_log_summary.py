#!/usr/bin/python3
"""bench/eval/train_log_summary.py on a made-up log of two legs: a first
leg of 20 progress lines whose PSNR climbs 10 -> 29 dB (other lines in
between), then a gaze leg whose gaze error falls 8.5 -> 4 deg and that
skipped 2 steps. The table must give
each leg's ends, its median ms per step and skipped steps; a file with no
progress lines is refused."""
import os
import re
import subprocess
import sys
import tempfile

script = sys.argv[1]
lines = ["gazesplat train: 20 identities, resuming nothing"]
for i in range(1, 21):
    lines.append(f"gazesplat train: step {100 * i}/2000 loss 0.2 psnr "
                 f"{9.0 + i:.2f} dB  lr 1e-3  {100 + i} ms/step  eta 9 s  skipped 0")
    if i == 10:
        lines.append("gazesplat train: resuming from step 1000")
for i in range(1, 11):
    lines.append(f"gazesplat train: step {2000 + 100 * i}/3000 loss 0.1 psnr "
                 f"30.00 dB  gaze {9.0 - 0.5 * i:.2f} deg  lr 2e-4  200 ms/step"
                 f"  eta 9 s  skipped {2 if i > 5 else 0}")
lines.append("done")
with tempfile.TemporaryDirectory() as d:
    log = os.path.join(d, "train.log")
    with open(log, "w") as f:
        f.write("\n".join(lines) + "\n")
    out = subprocess.run([sys.executable, script, log, "--lines", "2"],
                         capture_output=True, text=True, check=True).stdout
    print(out)
    want = ["| 1 | 100–2000 of 2000 | 20 | 10.50 → 28.50 | – | 110 | 0 |",
            "| 2 | 2100–3000 of 3000 | 10 | 30.00 → 30.00 | 8.25 → 4.25 | 200 | 2 |"]
    for w in want:
        if w not in out:
            sys.exit(f"check_train_log_summary: no row {w!r}")
    empty = os.path.join(d, "empty.log")
    open(empty, "w").write("nothing here\n")
    r = subprocess.run([sys.executable, script, empty], capture_output=True,
                       text=True)
    if r.returncode == 0 or "no progress lines" not in r.stderr:
        sys.exit("check_train_log_summary: an empty log was not refused")
print("check_train_log_summary: ok")
