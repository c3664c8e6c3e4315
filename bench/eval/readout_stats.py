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

# (label, head change 0|1, the column a range bins on, its range or None)
BINS = (("gaze only", "0", None, None),
        ("0-15°", "0", "gaze_change_deg", (0, 15)),
        ("15-30°", "0", "gaze_change_deg", (15, 30)),
        ("30-50°", "0", "gaze_change_deg", (30, 50)),
        ("head change", "1", None, None),
        ("head 0-20°", "1", "head_change_deg", (0, 20)),
        ("head 20-40°", "1", "head_change_deg", (20, 40)),
        ("head 40-60°", "1", "head_change_deg", (40, 60)),
        ("head 60°+", "1", "head_change_deg", (60, 360)))


def rows_of(path):
    with open(path) as f:
        return [r for r in csv.DictReader(f)
                if r["status"] == "ok" and r.get("read_gaze_err_deg")]


def group(rows, head_change, col, rng):
    return [r for r in rows if r["head_change"] == head_change and
            (rng is None or rng[0] <= float(r[col]) < rng[1])]


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
            for name, hc, col, rng in BINS:
                v = [float(r["read_gaze_err_deg"])
                     for r in group(mr, hc, col, rng)]
                if not v:
                    continue
                print(f"| {m} | {name} | {len(v)} | "
                      f"{statistics.mean(v):.2f} | {statistics.median(v):.2f} | "
                      f"{100 * sum(x <= 2 for x in v) / len(v):.0f} % | "
                      f"{100 * sum(x <= 5 for x in v) / len(v):.0f} % |")


if __name__ == "__main__":
    main()
