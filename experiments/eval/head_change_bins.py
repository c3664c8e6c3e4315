#!/usr/bin/env python3
"""Mean image and angle errors of `gazesplat eval` rows by the size of the
head change (0 = gaze only), per method: a markdown table.

usage: head_change_bins.py LABEL=DIR/pairs.csv [LABEL=FILE ...]
"""
import csv
import sys

BINS = [(0, 0), (0, 10), (10, 20), (20, 35), (35, 60), (60, 180)]


def mean(rows, key):
    v = [float(r[key]) for r in rows if r[key] not in ("", "nan")]
    return sum(v) / len(v) if v else float("nan")


def main(argv):
    if len(argv) < 2 or any("=" not in a for a in argv[1:]):
        sys.stderr.write(__doc__)
        return 2
    print("| run | method | head change | n | PSNR | SSIM | id PSNR | gaze° | head° |")
    print("|---|---|---|---:|---:|---:|---:|---:|---:|")
    for arg in argv[1:]:
        label, path = arg.split("=", 1)
        with open(path, newline="") as f:
            rows = [r for r in csv.DictReader(f) if r["status"] == "ok"]
        for method in dict.fromkeys(r["method"] for r in rows):
            for lo, hi in BINS:
                sel = [r for r in rows if r["method"] == method and
                       (float(r["head_change_deg"]) == 0 if hi == 0 else
                        lo < float(r["head_change_deg"]) <= hi and
                        r["head_change"] == "1")]
                if not sel:
                    continue
                name = "none" if hi == 0 else "%d-%d°" % (lo, hi)
                print("| %s | %s | %s | %d | %.2f | %.4f | %.2f | %.2f | %.2f |" % (
                    label, method, name, len(sel), mean(sel, "psnr"),
                    mean(sel, "ssim"), mean(sel, "id_psnr"),
                    mean(sel, "gaze_err_deg"), mean(sel, "head_err_deg")))
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv))
