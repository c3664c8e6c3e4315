"""Plot of `gazesplat eval-downstream`: gaze error against k.

usage: downstream_plot.py OUT_DIR
Reads OUT_DIR/downstream.csv (identity, identity_seed, k, condition,
gaze_err_deg) and writes OUT_DIR/downstream.png: the mean over identities
per k, one line per condition (real only, real + ours, real + warp), k = 0
being the estimator as given."""
import csv
import math
import os
import sys

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import matplotlib.ticker  # noqa: E402

LABELS = {"real": "real only", "real+ours": "real + ours (model)",
          "real+warp": "real + warp baseline"}


def means(path):
    sums = {}
    with open(path, newline="") as f:
        for r in csv.DictReader(f):
            e = float(r["gaze_err_deg"])
            if not math.isfinite(e):
                continue
            key = (r["condition"], int(r["k"]))
            s, n = sums.get(key, (0.0, 0))
            sums[key] = (s + e, n + 1)
    return {key: s / n for key, (s, n) in sums.items()}


def main():
    if len(sys.argv) != 2:
        sys.exit(__doc__)
    out = sys.argv[1]
    m = means(os.path.join(out, "downstream.csv"))
    if not m:
        sys.exit("downstream_plot.py: no finite rows in downstream.csv")
    fig, ax = plt.subplots(figsize=(6, 4))
    for cond, label in LABELS.items():
        ks = sorted(k for c, k in m if c == cond)
        ax.plot(ks, [m[(cond, k)] for k in ks], marker="o", label=label)
    ax.xaxis.set_major_locator(matplotlib.ticker.MaxNLocator(integer=True))
    ax.set_xlabel("k (real images of the test person)")
    ax.set_ylabel("gaze error on the test images (deg)")
    ax.set_title("Fine-tuning the gaze estimator per person")
    ax.grid(alpha=0.3)
    ax.legend()
    fig.tight_layout()
    fig.savefig(os.path.join(out, "downstream.png"), dpi=100)


if __name__ == "__main__":
    main()
