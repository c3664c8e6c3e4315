#!/usr/bin/python3
"""The spread of the synthesis readout's gaze errors in `gazesplat eval
--readout` runs: per method, for gaze-only pairs (all, and by gaze change
0-15, 15-30, 30-50 degrees) and for head-change pairs (all, and by the
head's turn 0-20, 20-40, 40-60, 60 degrees and more), the mean, the
median and the share of pairs within 2 and 5 degrees of the target's true
gaze, with the readout's floor (its error on the true targets). Means hide
a few gross misses; the median and the shares do not.

    bench/eval/readout_stats.py DIR/pairs.csv [MORE.csv ...]

Prints a Markdown table per file. Standard library only."""
import csv
import statistics
import sys

BINS = (("gaze only", None), ("  0-15°", (0, 15)), ("  15-30°", (15, 30)),
        ("  30-50°", (30, 50)), ("head change", None),
        ("  head 0-20°", (0, 20)), ("  head 20-40°", (20, 40)),
        ("  head 40-60°", (40, 60)), ("  head 60°+", (60, 360)))


def rows_of(path):
    with open(path) as f:
        return [r for r in csv.DictReader(f)
                if r["status"] == "ok" and r.get("read_gaze_err_deg")]


def group(rows, name, rng):
    if name.startswith("head") or name.startswith("  head"):
        g = [r for r in rows if r["head_change"] == "1"]
        if rng:
            g = [r for r in g
                 if rng[0] <= float(r["head_change_deg"]) < rng[1]]
        return g
    g = [r for r in rows if r["head_change"] == "0"]
    if rng:
        g = [r for r in g if rng[0] <= float(r["gaze_change_deg"]) < rng[1]]
    return g


def main():
    if len(sys.argv) < 2:
        sys.exit(__doc__)
    for path in sys.argv[1:]:
        rows = rows_of(path)
        if not rows:
            sys.exit(f"{path}: no readout columns (run eval with --readout)")
        floor = [float(r["read_floor_gaze_deg"]) for r in rows]
        print(f"\n`{path}`: readout floor mean {statistics.mean(floor):.2f}°,"
              f" largest {max(floor):.2f}°\n")
        print("| method | pairs | n | mean° | median° | within 2° | within 5° |")
        print("|---|---|---:|---:|---:|---:|---:|")
        for m in dict.fromkeys(r["method"] for r in rows):
            mr = [r for r in rows if r["method"] == m]
            for name, rng in BINS:
                v = [float(r["read_gaze_err_deg"]) for r in group(mr, name, rng)]
                if not v:
                    continue
                print(f"| {m} | {name.strip()} | {len(v)} | "
                      f"{statistics.mean(v):.2f} | {statistics.median(v):.2f} | "
                      f"{100 * sum(x <= 2 for x in v) / len(v):.0f} % | "
                      f"{100 * sum(x <= 5 for x in v) / len(v):.0f} % |")


if __name__ == "__main__":
    main()
