#!/usr/bin/python3
"""The spread of the synthesis readout's gaze errors in `gazesplat eval
--readout` runs: per method, for gaze-only pairs (all, and by gaze change
0-15, 15-30, 30-50 degrees) and for head-change pairs (all, and by the
head's turn 0-20, 20-40, 40-60, 60 degrees and more, and by whether the
target's head pose lies inside the training head range), the mean, the
median and the share of pairs within 2 and 5 degrees of the target's true
gaze, with the readout's floor (its error on the true targets). Means hide
a few gross misses; the median and the shares do not.

    bench/eval/readout_stats.py [--head-range Y,P] DIR/pairs.csv [MORE.csv ...]

--head-range names the training head range (yaw within +-Y, pitch within
+-P degrees; default 40,25, `gazesplat train`'s own): head-change pairs
whose target pose lies inside it and outside it get a row each. Files
written before the target pose columns existed get no such rows.

Files with the target's true gaze get a second table: by the target's
pitch (the normalized camera's; below -15, -15 to 15, above 15 degrees),
the mean signed pitch error (read minus true: negative reads lower) and
the mean gaze error, for gaze-only and head-change pairs. A model whose
lids do not follow the gaze reads strong upward and downward looks as
nearer the middle (docs/model.md, "Lids that follow the gaze").

A third table gives each input face's mean, median and largest error:
a mean pulled up by a few fits shows there.

Prints Markdown tables per file. Standard library only."""
import csv
import statistics
import sys

# (label, head change 0|1 or None for both, the column a range bins on,
# its range or None)
BINS = (("all pairs", None, None, None),
        ("gaze only", "0", None, None),
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
    return [r for r in rows if head_change in (None, r["head_change"]) and
            (rng is None or rng[0] <= float(r[col]) < rng[1])]


PITCH_BINS = (("< -15°", -90, -15),
              ("-15-15°", -15, 15),
              ("> 15°", 15, 90))


def pitch_table(rows):
    """Signed pitch error by the target's pitch, per method and pair kind."""
    print("\n| method | pairs | target pitch | n | read − true pitch° | "
          "gaze error° |")
    print("|---|---|---|---:|---:|---:|")
    for m in dict.fromkeys(r["method"] for r in rows):
        for kind, hc in (("gaze only", "0"), ("head change", "1")):
            for name, lo, hi in PITCH_BINS:
                g = [r for r in rows if r["method"] == m and
                     r["head_change"] == hc and
                     lo <= float(r["target_pitch_deg"]) < hi]
                if not g:
                    continue
                d = [float(r["read_pitch_deg"]) - float(r["target_pitch_deg"])
                     for r in g]
                e = [float(r["read_gaze_err_deg"]) for r in g]
                print(f"| {m} | {kind} | {name} | {len(g)} | "
                      f"{statistics.mean(d):+.2f} | {statistics.mean(e):.2f} |")


def input_table(rows):
    """Mean and median per input face: a few bad fits show up here."""
    print("\n| method | input | n | mean° | median° | largest° |")
    print("|---|---:|---:|---:|---:|---:|")
    for m in dict.fromkeys(r["method"] for r in rows):
        mr = [r for r in rows if r["method"] == m]
        for i in dict.fromkeys(r["input"] for r in mr):
            v = [float(r["read_gaze_err_deg"]) for r in mr if r["input"] == i]
            print(f"| {m} | {i} | {len(v)} | {statistics.mean(v):.2f} | "
                  f"{statistics.median(v):.2f} | {max(v):.2f} |")


def inside(r, head_range):
    """1 when the target's head pose lies within the training range."""
    return int(abs(float(r["target_head_yaw_deg"])) <= head_range[0] and
               abs(float(r["target_head_pitch_deg"])) <= head_range[1])


def parse_range(text):
    try:
        y, p = (float(v) for v in text.split(","))
    except ValueError:
        sys.exit(f"--head-range wants Y,P in degrees, got {text!r}")
    if not (0 < y <= 90 and 0 < p <= 90):
        sys.exit(f"--head-range {text}: each bound must be in (0, 90]")
    return y, p


def main():
    args = sys.argv[1:]
    head_range = (40.0, 25.0)
    if args[:1] == ["--head-range"]:
        if len(args) < 2:
            sys.exit(__doc__)
        head_range = parse_range(args[1])
        args = args[2:]
    if not args:
        sys.exit(__doc__)
    hr = f"{head_range[0]:g},{head_range[1]:g}"
    for path in args:
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
            bins = list(BINS)
            if "target_head_yaw_deg" in mr[0]:
                bins += [(f"head change, target inside {hr}", "1", "inside",
                          (1, 2)),
                         (f"head change, target outside {hr}", "1", "inside",
                          (0, 1))]
                for r in mr:
                    r["inside"] = inside(r, head_range)
            for name, hc, col, rng in bins:
                v = [float(r["read_gaze_err_deg"])
                     for r in group(mr, hc, col, rng)]
                if not v:
                    continue
                print(f"| {m} | {name} | {len(v)} | "
                      f"{statistics.mean(v):.2f} | {statistics.median(v):.2f} | "
                      f"{100 * sum(x <= 2 for x in v) / len(v):.0f} % | "
                      f"{100 * sum(x <= 5 for x in v) / len(v):.0f} % |")
        input_table(rows)
        if "target_pitch_deg" in rows[0] and "read_pitch_deg" in rows[0]:
            pitch_table(rows)


if __name__ == "__main__":
    main()
