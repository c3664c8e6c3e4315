#!/usr/bin/python3
"""Whether averaging the evaluation estimator over small shifts of its
input (test-time augmentation) brings its gaze reading closer to the true
label: if its error were jitter (the reading moves 2-3 degrees under a
1 px shift, estimator_sensitivity.py), the average would be nearer.

Renders held-out (test-split) synthetic faces with `gazesplat synth`,
whitens them outside the head mask as the evaluation's targets are, keeps
those whose gaze is inside the evaluation's range (pitch +-50, yaw +-60
degrees) and compares, against the true gaze, `gazesplat estimate` on the
image alone, averaged (as unit gaze vectors) over the 5 shifts of at most
1 px along one axis, and over all 9 shifts of at most 1 px each way
(white fill). Prints the mean and median angle of each.

    experiments/eval/estimator_tta.py build/clients/cli/gazesplat \
        models/gaze-resnet-white.safetensors [--count 40]

Needs numpy and PIL (python3-numpy, python3-pil)."""
import os
import tempfile

import numpy as np

from estimator_sensitivity import (angle, direction, estimate, parse_args,
                                   test_faces)


def shifted(img, dx, dy):
    """img moved by (dx, dy) whole pixels, white where it uncovers."""
    out = np.full_like(img, 255)
    h, w = img.shape[:2]
    out[max(dy, 0):h + min(dy, 0), max(dx, 0):w + min(dx, 0)] = \
        img[max(-dy, 0):h + min(-dy, 0), max(-dx, 0):w + min(-dx, 0)]
    return out


def main():
    a = parse_args(__doc__, "estimator_tta")
    plus = [(0, 0), (1, 0), (-1, 0), (0, 1), (0, -1)]
    square = [(dx, dy) for dy in (-1, 0, 1) for dx in (-1, 0, 1)]
    err = {"alone": [], "5 shifts": [], "9 shifts": []}
    with tempfile.TemporaryDirectory() as tmp:
        probe = os.path.join(tmp, "probe.png")
        for img, lab in test_faces(a.gazesplat, tmp, a.count):
            p = np.degrees(lab["gaze_norm_pitch_rad"])
            y = np.degrees(lab["gaze_norm_yaw_rad"])
            if abs(p) > 50 or abs(y) > 60:
                continue
            truth = direction(p, y)
            v = {s: direction(*estimate(a.gazesplat, a.estimator, shifted(img, *s), probe))
                 for s in square}
            err["alone"].append(angle(v[(0, 0)], truth))
            err["5 shifts"].append(angle(sum(v[s] for s in plus), truth))
            err["9 shifts"].append(angle(sum(v[s] for s in square), truth))
    n = len(err["alone"])
    print(f"| reading ({n} test-split faces in range, 256 px) | mean° | median° |")
    print("|---|---:|---:|")
    for name, e in err.items():
        print(f"| {name} | {np.mean(e):.2f} | {np.median(e):.2f} |")


if __name__ == "__main__":
    main()
