#!/usr/bin/python3
"""White patches inside the head at a head change.

Counts, for each head-change pair whose images an eval run saved
(`gazesplat eval --save-images N`), the output pixels that are near white
(every channel above 235) where the ground-truth target shows the head
well inside its outline (6 px in, and darker than 200 there). The
background is white, so these are holes or background-coloured patches
in the face, plus places where the model's outline falls more than 6 px
inside the target's.

Usage: white_inside_head.py METHOD EVAL_DIR...
"""
import csv
import sys

import numpy as np
from PIL import Image
from scipy import ndimage


def count(d, method):
    total, pairs, over = 0, 0, []
    for r in csv.DictReader(open(d + "/pairs.csv")):
        if r["method"] != method or r["head_change"] != "1":
            continue
        p = "%s/images/%05d_" % (d, int(r["pair"]))
        try:
            o = np.asarray(Image.open(p + method + ".png").convert("RGB"))
            t = np.asarray(Image.open(p + "target.png").convert("RGB"))
        except FileNotFoundError:
            continue
        inside = ndimage.binary_erosion(t.min(2) < 240, iterations=6)
        n = int(((o.min(2) > 235) & inside & (t.min(2) < 200)).sum())
        total += n
        pairs += 1
        if n > 30:
            over.append((int(r["pair"]), n))
    return total, pairs, over


def main():
    if len(sys.argv) < 3:
        sys.exit(__doc__)
    method = sys.argv[1]
    print("| run | head-change pairs | white px inside the head | pairs over 30 px |")
    print("|---|---:|---:|---:|")
    for d in sys.argv[2:]:
        total, pairs, over = count(d, method)
        print("| %s | %d | %d | %d |" % (d, pairs, total, len(over)))


if __name__ == "__main__":
    main()
