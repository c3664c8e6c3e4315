#!/usr/bin/python3
"""How far the evaluation estimator's gaze reading moves under small image
changes that do not change the gaze: the noise floor of the redirection
goals' "estimator on the output against estimator on the target" angle.

Renders held-out (test-split) synthetic faces with `gazesplat synth`,
whitens them outside the head mask as the evaluation's targets are, and
compares `gazesplat estimate` on each image with its reading on the same
image shifted by one pixel, blurred (Gaussian, radius 0.7 px), saved as
JPEG (quality 90) and with pixel noise (sigma 3 levels). Prints the mean,
median and largest angle per change.

    experiments/eval/estimator_sensitivity.py build/clients/cli/gazesplat \
        models/gaze-resnet.safetensors [--count 40]

Needs numpy and PIL (python3-numpy, python3-pil)."""
import argparse
import io
import json
import os
import subprocess
import sys
import tempfile

import numpy as np
from PIL import Image, ImageFilter


def estimate(gazesplat, model, img, path):
    Image.fromarray(img).save(path)
    out = subprocess.run([gazesplat, "estimate", "--model", model, "--image", path],
                         capture_output=True, text=True, check=True).stdout.split()
    d = dict(zip(out[0::2], map(float, out[1::2])))
    return d["gaze_pitch_deg"], d["gaze_yaw_deg"]


def direction(pitch_deg, yaw_deg):
    p, y = np.radians(pitch_deg), np.radians(yaw_deg)
    return np.array([-np.cos(p) * np.sin(y), -np.sin(p), -np.cos(p) * np.cos(y)])


def angle(a, b):
    """Degrees between two gaze vectors (any length)."""
    c = a @ b / (np.linalg.norm(a) * np.linalg.norm(b))
    return float(np.degrees(np.arccos(np.clip(c, -1.0, 1.0))))


def test_faces(gazesplat, tmp, count):
    """count held-out (test-split) synthetic faces at 256 px, white outside
    the head mask as the evaluation's targets are: (image, label) pairs,
    the label as `gazesplat synth` writes it (labels.jsonl)."""
    ds = os.path.join(tmp, "ds")
    subprocess.run([gazesplat, "synth", "--out", ds, "--count", str(count),
                    "--seed-split", "test", "--identities", "15", "--size", "256",
                    "--threads", "2"], check=True, capture_output=True)
    with open(os.path.join(ds, "labels.jsonl")) as f:
        for line in f:
            lab = json.loads(line)
            img = np.array(Image.open(os.path.join(ds, lab["image"])).convert("RGB"))
            head = np.array(Image.open(os.path.join(ds, lab["mask"])).convert("RGB"))
            yield np.where(head[..., :1] > 127, img, 255).astype(np.uint8), lab


def changes(img, seed):
    jpeg = io.BytesIO()
    Image.fromarray(img).save(jpeg, "JPEG", quality=90)
    rng = np.random.default_rng(seed)
    return {
        "shift 1 px": np.roll(img, 1, axis=1),
        "blur 0.7 px": np.array(Image.fromarray(img).filter(ImageFilter.GaussianBlur(0.7))),
        "JPEG q90": np.array(Image.open(jpeg).convert("RGB")),
        "noise 3 levels": np.clip(img + rng.normal(0, 3, img.shape), 0, 255).astype(np.uint8),
    }


def parse_args(doc, prog):
    """The scripts' common arguments: gazesplat, estimator, --count."""
    ap = argparse.ArgumentParser(description=doc.split("\n\n")[0])
    ap.add_argument("gazesplat")
    ap.add_argument("estimator")
    ap.add_argument("--count", type=int, default=40)
    a = ap.parse_args()
    if a.count < 1:
        sys.exit(f"{prog}: --count must be >= 1")
    return a


def main():
    a = parse_args(__doc__, "estimator_sensitivity")
    with tempfile.TemporaryDirectory() as tmp:
        probe = os.path.join(tmp, "probe.png")
        res = {}
        for i, (img, _) in enumerate(test_faces(a.gazesplat, tmp, a.count)):
            base = direction(*estimate(a.gazesplat, a.estimator, img, probe))
            for name, x in changes(img, i).items():
                res.setdefault(name, []).append(
                    angle(base, direction(*estimate(a.gazesplat, a.estimator, x, probe))))
    print(f"| change ({a.count} test-split faces, 256 px) | mean° | median° | max° |")
    print("|---|---:|---:|---:|")
    for name, v in res.items():
        v = np.array(v)
        print(f"| {name} | {v.mean():.2f} | {np.median(v):.2f} | {v.max():.2f} |")


if __name__ == "__main__":
    main()
