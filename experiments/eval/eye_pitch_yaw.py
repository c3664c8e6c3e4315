#!/usr/bin/python3
"""Does a pitch change cost the eye region more than a yaw change?

The synthetic heads' lids follow the gaze's pitch (the upper lid by 0.85 of
it), and the model's face stream does not see the gaze, so its lids stay
where the fit put them. If that were the main loss in the eye region,
gaze-only pairs would lose more eye PSNR per degree of pitch change than
per degree of yaw change. This reads both angles of each gaze-only pair's
input and target with an estimator (`gazesplat estimate` on the images an
eval run saved with --save-images) and fits

    eye_psnr ~ a |d pitch| + b |d yaw| + c     (and the same for psnr)

Usage: eye_pitch_yaw.py EVAL_DIR ESTIMATOR [GAZESPLAT] [METHOD]
EVAL_DIR holds pairs.csv and images/ from `gazesplat eval --save-images N`.
"""
import csv
import subprocess
import sys

import numpy as np


def estimate(gs, est, png):
    out = subprocess.run([gs, "estimate", "--model", est, "--image", png],
                         check=True, capture_output=True, text=True).stdout
    f = out.split()
    v = dict(zip(f[0::2], f[1::2]))
    return float(v["gaze_pitch_deg"]), float(v["gaze_yaw_deg"])


def main():
    if len(sys.argv) < 3:
        sys.exit(__doc__)
    d, est = sys.argv[1], sys.argv[2]
    gs = sys.argv[3] if len(sys.argv) > 3 else "gazesplat"
    method = sys.argv[4] if len(sys.argv) > 4 else "transfer"
    rows = [r for r in csv.DictReader(open(d + "/pairs.csv"))
            if r["method"] == method and r["head_change"] == "0"]
    dp, dy, eye, whole = [], [], [], []
    for r in rows:
        p = "%s/images/%05d_" % (d, int(r["pair"]))
        try:
            a = estimate(gs, est, p + "input.png")
            b = estimate(gs, est, p + "target.png")
        except (subprocess.CalledProcessError, FileNotFoundError):
            continue  # not saved (--save-images below the pair's index)
        dp.append(abs(b[0] - a[0]))
        dy.append(abs(b[1] - a[1]))
        eye.append(float(r["eye_psnr"]))
        whole.append(float(r["psnr"]))
    if len(dp) < 10:
        sys.exit("fewer than 10 gaze-only pairs with saved images")
    dp, dy = np.array(dp), np.array(dy)
    A = np.c_[dp, dy, np.ones(len(dp))]
    print("%s, %d gaze-only pairs; mean |d pitch| %.1f deg, |d yaw| %.1f deg"
          % (method, len(dp), dp.mean(), dy.mean()))
    for name, y in (("eye PSNR", np.array(eye)), ("PSNR", np.array(whole))):
        a, b, c = np.linalg.lstsq(A, y, rcond=None)[0]
        print("%-8s dB per degree: pitch %.3f, yaw %.3f (at no change %.2f)"
              % (name, a, b, c))
    print("| pitch change | pairs | eye PSNR | PSNR |")
    print("|---|---:|---:|---:|")
    for lo, hi in ((0, 5), (5, 10), (10, 20), (20, 90)):
        m = (dp >= lo) & (dp < hi)
        if m.any():
            print("| %d-%d deg | %d | %.2f | %.2f |"
                  % (lo, hi, m.sum(), np.array(eye)[m].mean(),
                     np.array(whole)[m].mean()))


if __name__ == "__main__":
    main()
