#!/usr/bin/python3
"""Is the gaze the outputs show off in a direction, or scattered?

Reads an eval run's pairs.csv (with --readout; the target's true gaze and
head pose are columns) and, per method and for gaze-only and head-change
pairs apart, fits the gaze read on each output against the target's true
gaze and the head's turn from the input:

    read_pitch - true_pitch ~ a_p true_pitch + b_p dhead_pitch + c_p
    read_yaw   - true_yaw   ~ a_y true_yaw   + b_y dhead_yaw   + c_y

a < 0: the eyes turn less than asked (a slope of 1 + a); b: the eyes
follow (b > 0) or lag (b < 0) the head's turn; c: a constant offset. It
prints each fit, how much of the signed error's spread it explains, and
the mean angular error left if the fitted part were taken away (what a
correction of that form could at best reach on these very pairs: an upper
bound on its worth, not a held-out figure).

Usage: gaze_bias.py PAIRS_CSV [METHOD]
"""
import csv
import math
import sys

import numpy as np


def vec(p, y):
    p, y = math.radians(p), math.radians(y)
    return np.array([-math.cos(p) * math.sin(y), -math.sin(p),
                     -math.cos(p) * math.cos(y)])


def angle(p0, y0, p1, y1):
    d = float(np.dot(vec(p0, y0), vec(p1, y1)))
    return math.degrees(math.acos(max(-1.0, min(1.0, d))))


def main():
    if len(sys.argv) < 2:
        sys.exit(__doc__)
    rows = list(csv.DictReader(open(sys.argv[1])))
    if not rows or "target_pitch_deg" not in rows[0]:
        sys.exit("gaze_bias: %s has no target_pitch_deg column (an eval "
                 "run of this build, with --readout, writes it)" % sys.argv[1])
    methods = [sys.argv[2]] if len(sys.argv) > 2 else \
        sorted({r["method"] for r in rows})
    for m in methods:
        rs = [r for r in rows if r["method"] == m and r["read_pitch_deg"]]
        head = {}  # the input's head pose: any gaze-only target's
        for r in rs:
            if r["head_change"] == "0":
                head[r["input"]] = (float(r["target_head_pitch_deg"]),
                                    float(r["target_head_yaw_deg"]))
        for hc, name in (("0", "gaze only"), ("1", "head change")):
            sel = [r for r in rs if r["head_change"] == hc and r["input"] in head]
            if len(sel) < 8:
                continue
            tp = np.array([float(r["target_pitch_deg"]) for r in sel])
            ty = np.array([float(r["target_yaw_deg"]) for r in sel])
            rp = np.array([float(r["read_pitch_deg"]) for r in sel])
            ry = np.array([float(r["read_yaw_deg"]) for r in sel])
            dhp = np.array([float(r["target_head_pitch_deg"]) - head[r["input"]][0]
                            for r in sel])
            dhy = np.array([float(r["target_head_yaw_deg"]) - head[r["input"]][1]
                            for r in sel])
            err = [angle(a, b, c, d) for a, b, c, d in zip(rp, ry, tp, ty)]
            print("%s, %s: %d pairs, mean %.2f deg, median %.2f deg" %
                  (m, name, len(sel), np.mean(err), np.median(err)))
            fitted = {}
            for axis, t, rd, dh in (("pitch", tp, rp, dhp), ("yaw", ty, ry, dhy)):
                e = rd - t
                X = np.stack([t, dh, np.ones_like(t)], 1)
                coef, *_ = np.linalg.lstsq(X, e, rcond=None)
                res = e - X @ coef
                r2 = 1 - res.var() / e.var() if e.var() > 0 else 0.0
                fitted[axis] = X @ coef
                print("  %-5s signed error mean %+.2f sd %.2f; fit: %+.3f x true "
                      "%+.3f x head turn %+.2f, explains %.0f %%" %
                      (axis, e.mean(), e.std(), coef[0], coef[1], coef[2],
                       100 * r2))
            left = [angle(a - fp, b - fy, c, d) for a, b, c, d, fp, fy in
                    zip(rp, ry, tp, ty, fitted["pitch"], fitted["yaw"])]
            print("  with the fitted part taken away: mean %.2f deg, median %.2f "
                  "deg (an upper bound, on these pairs)" %
                  (np.mean(left), np.median(left)))


if __name__ == "__main__":
    main()
