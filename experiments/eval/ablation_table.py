#!/usr/bin/python3
"""Writes the ablation table (Markdown) from experiments/eval/ablation.sh's work
directory: WORK/<name>/pairs.csv of `gazesplat eval` and WORK/<name>.train.log.
Usage: ablation_table.py WORK STEPS INPUTS ITERS"""
import csv
import math
import os
import re
import sys

MODELS = [("full", "Full model (two streams, eye rotation, guided renderer)"),
          ("single", "Single stream (gaze through the pose MLP)"),
          ("noeye", "No explicit eye rotation (eyes deformed like the face)"),
          ("noguide", "No expression guidance (plain renderer)")]
COLS = [("gaze_err_deg", "gaze°", 2), ("head_err_deg", "head°", 2),
        ("gaze_err_label_deg", "gaze° vs label", 2), ("psnr", "PSNR", 2),
        ("ssim", "SSIM", 4), ("eye_psnr", "eye PSNR", 2), ("eye_ssim", "eye SSIM", 4),
        ("id_psnr", "id PSNR", 2), ("id_ssim", "id SSIM", 4)]


def rows(path):
    with open(path, newline="") as f:
        return [r for r in csv.DictReader(f) if r["method"] == "model"]


def mean(rs, key):
    v = [float(r[key]) for r in rs if r["status"] == "ok" and r.get(key) not in (None, "", "nan")]
    v = [x for x in v if math.isfinite(x)]
    return sum(v) / len(v) if v else float("nan")


def train_psnr(log):
    """Mean training PSNR over the last 200 steps of the log."""
    if not os.path.exists(log):
        return float("nan"), 0, 0
    pts = []
    skipped = 0
    for line in open(log):
        m = re.search(r"step (\d+)/\d+ .*psnr ([\d.]+) dB.*skipped (\d+)", line)
        if m:
            pts.append((int(m.group(1)), float(m.group(2))))
            skipped = int(m.group(3))
    if not pts:
        return float("nan"), 0, 0
    last = pts[-1][0]
    tail = [p for s, p in pts if s > last - 200]
    return sum(tail) / len(tail), last, skipped


def main():
    work, steps, inputs, iters = sys.argv[1], sys.argv[2], sys.argv[3], sys.argv[4]
    out = ["# Ablation (like the GazeGaussian paper's Table 3)", "",
           "Made by `experiments/eval/ablation.sh build out/ablation %s %s %s`: each model trained "
           "from scratch by `gazesplat train --preset cpu --identities 48 --steps %s --seed 1` "
           "plus its switch, then `gazesplat eval --method model --limit-inputs %s --iters %s` "
           "on the committed pairing (held-out test identities) with the evaluation estimator "
           "`models/gaze-resnet.safetensors`. Columns as in docs/eval.md: gaze°/head° are the "
           "angles between the estimator on the output and on the ground-truth target; "
           "PSNR/SSIM against the ground-truth target; eye = eye region; id = the face "
           "without the eyes (identity consistency)." % (steps, inputs, iters, steps, inputs, iters),
           ""]
    head = "| model | train PSNR | n | " + " | ".join(c[1] for c in COLS) + " |"
    out += [head, "|---|---:|---:|" + "---:|" * len(COLS)]
    subsets = {}
    for name, label in MODELS:
        p = os.path.join(work, name, "pairs.csv")
        if not os.path.exists(p):
            out.append("| %s | (not run) |" % label)
            continue
        rs = rows(p)
        tp, last, skipped = train_psnr(os.path.join(work, name + ".train.log"))
        ok = [r for r in rs if r["status"] == "ok"]
        cells = ["%.*f" % (d, mean(rs, k)) for k, _, d in COLS]
        out.append("| %s | %.2f | %d | %s |" % (label, tp, len(ok), " | ".join(cells)))
        subsets[name] = (rs, len(rs) - len(ok), last, skipped)
    out += ["", "Gaze-only pairs (same head pose) and pairs with a head change:", "",
            "| model | pairs | n | gaze° | head° | PSNR | SSIM | eye PSNR |",
            "|---|---|---:|---:|---:|---:|---:|---:|"]
    for name, label in MODELS:
        if name not in subsets:
            continue
        rs = subsets[name][0]
        for flag, what in (("0", "gaze only"), ("1", "head change")):
            s = [r for r in rs if r["head_change"] == flag]
            out.append("| %s | %s | %d | %.2f | %.2f | %.2f | %.4f | %.2f |" % (
                name, what, len([r for r in s if r["status"] == "ok"]), mean(s, "gaze_err_deg"),
                mean(s, "head_err_deg"), mean(s, "psnr"), mean(s, "ssim"), mean(s, "eye_psnr")))
    out += ["", "Training: steps run, steps skipped by the guard; evaluation: pairs that "
            "failed (diverged fits, errors, non-finite outputs; goal zero):", ""]
    for name, label in MODELS:
        if name in subsets:
            rs, bad, last, skipped = subsets[name]
            out.append("- %s: %d steps, %d skipped; %d failed pairs" % (name, last, skipped, bad))
    print("\n".join(out))


if __name__ == "__main__":
    main()
