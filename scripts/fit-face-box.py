#!/usr/bin/python3
"""Chooses the face cascade and fits the cascade -> dlib box affine.

For each test photo, runs dlib's HOG frontal face detector (tests/face
dlib_ref, one upsampling, as dlib's own examples do) and each OpenCV
cascade (`gazesplat face --list`), matches boxes by IoU, prints per-cascade
counts and matches, and fits, for the chosen cascade, the fixed affine of
face.h (GS_FACE_BOX_SCALE, GS_FACE_BOX_DX, GS_FACE_BOX_DY) by least squares:
  dlib side = SCALE * w,  dlib centre = cascade centre + (DX, DY) * w.

usage: scripts/fit-face-box.py BUILD_DIR [ASSETS_DIR]
(needs scripts/fetch-test-assets.sh first; takes about a minute)
"""
import json
import os
import subprocess
import sys
import tempfile

import numpy as np
import skimage.io

CASCADES = [
    "haarcascades/haarcascade_frontalface_default",
    "haarcascades/haarcascade_frontalface_alt",
    "haarcascades/haarcascade_frontalface_alt2",
    "lbpcascades/lbpcascade_frontalface",
    "lbpcascades/lbpcascade_frontalface_improved",
]
CHOSEN = "haarcascades/haarcascade_frontalface_alt2"
# Faces a person counts in each photo (frontal or not).
TRUE_FACES = {"astronaut": 1, "sample1": 3, "sample2": 3, "sample3": 3,
              "sample4": 4, "sample5": 5, "sample6": 4}


def photos(assets):
    skd = os.path.join(os.path.dirname(skimage.__file__), "data")
    yield "astronaut", os.path.join(skd, "astronaut.png")
    for i in range(1, 7):
        yield "sample%d" % i, os.path.join(assets, "sample%d.jpg" % i)


def hog_boxes(build, path):
    img = skimage.io.imread(path)[:, :, :3]
    with tempfile.NamedTemporaryFile(suffix=".ppm") as f:
        f.write(b"P6\n%d %d\n255\n" % (img.shape[1], img.shape[0]) + img.tobytes())
        f.flush()
        out = subprocess.run([os.path.join(build, "tests/face/dlib_ref"), "hog", f.name, "1"],
                             check=True, capture_output=True, text=True).stdout
    return [list(map(int, l.split())) for l in out.splitlines()]


def cascade_boxes(build, path, cascade):
    out = subprocess.run([os.path.join(build, "clients/cli/gazesplat"), "face", "--image", path,
                          "--list", "--json", "--cascade",
                          "/usr/share/opencv4/%s.xml" % cascade],
                         check=True, capture_output=True, text=True).stdout
    return [f["cascade"] for f in json.loads(out)["faces"]]


def iou(a, b):
    ix = min(a[2], b[2]) - max(a[0], b[0]) + 1
    iy = min(a[3], b[3]) - max(a[1], b[1]) + 1
    if ix <= 0 or iy <= 0:
        return 0.0
    inter = ix * iy
    area = lambda r: (r[2] - r[0] + 1) * (r[3] - r[1] + 1)
    return inter / (area(a) + area(b) - inter)


def match(cboxes, hboxes):
    pairs = []
    for h in hboxes:
        best = max(cboxes, key=lambda c: iou(c, h), default=None)
        if best is not None and iou(best, h) > 0.3:
            pairs.append((best, h))
    return pairs


def main():
    build = sys.argv[1]
    assets = sys.argv[2] if len(sys.argv) > 2 else os.path.join(
        os.path.dirname(os.path.abspath(__file__)), "..", "assets", "face-api")
    hog = {n: hog_boxes(build, p) for n, p in photos(assets)}
    print("dlib HOG faces:", {n: len(b) for n, b in hog.items()})
    print("true faces:    ", TRUE_FACES)
    pairs_of = {}
    for c in CASCADES:
        counts, matched, pairs = {}, 0, []
        for n, p in photos(assets):
            cb = cascade_boxes(build, p, c)
            counts[n] = len(cb)
            m = match(cb, hog[n])
            matched += len(m)
            pairs += m
        total = sum(counts.values())
        print("%-45s found %s total %d, %d match a HOG face" % (c, counts, total, matched))
        pairs_of[c] = pairs
    pairs = pairs_of[CHOSEN]
    w = np.array([c[2] - c[0] + 1 for c, _ in pairs], float)
    side = np.array([h[2] - h[0] + 1 for _, h in pairs], float)
    ccx = np.array([(c[0] + c[2]) / 2 for c, _ in pairs])
    ccy = np.array([(c[1] + c[3]) / 2 for c, _ in pairs])
    hcx = np.array([(h[0] + h[2]) / 2 for _, h in pairs])
    hcy = np.array([(h[1] + h[3]) / 2 for _, h in pairs])
    scale = float(side @ w / (w @ w))
    dx = float(np.mean((hcx - ccx) / w))
    dy = float(np.mean((hcy - ccy) / w))
    res = np.concatenate([(side - scale * w) / w, (hcx - ccx) / w - dx, (hcy - ccy) / w - dy])
    print("%s, %d pairs:" % (CHOSEN, len(pairs)))
    print("#define GS_FACE_BOX_SCALE %.4f" % scale)
    print("#define GS_FACE_BOX_DX %.4f" % dx)
    print("#define GS_FACE_BOX_DY %.4f" % dy)
    print("rms residual %.3f of the cascade width" % float(np.sqrt(np.mean(res ** 2))))


if __name__ == "__main__":
    main()
