#!/usr/bin/python3
"""A training log's progress lines (`gazesplat train ... --log-every N`,
stderr), summarized per leg: the steps it ran, the training image's PSNR
and the loss estimator's gaze error (legs with the gaze loss) as means of
its first and last K progress lines, its median ms per step and the steps
skipped. A leg is a run of lines with the same final step (".../36700"):
a resume of the same leg continues it, a leg with another goal starts a
new one.

    bench/eval/train_log_summary.py LOG [--lines K]

K: progress lines averaged at each end (default 5: 500 steps at
--log-every 100). Standard library only."""
import argparse
import re
import statistics
import sys

LINE = re.compile(r"step (\d+)/(\d+) loss \S+ psnr ([\d.]+) dB"
                  r"(?:\s+gaze ([\d.]+) deg)?.*?\s(\d+) ms/step.*skipped (\d+)")


def legs_of(path):
    legs = []
    with open(path, errors="replace") as f:
        for line in f:
            m = LINE.search(line)
            if not m:
                continue
            step, goal = int(m[1]), int(m[2])
            row = (step, float(m[3]), float(m[4]) if m[4] else None,
                   int(m[5]), int(m[6]))
            if not legs or legs[-1][0] != goal:
                legs.append((goal, []))
            legs[-1][1].append(row)
    return legs


def ends(v, k):
    return statistics.mean(v[:k]), statistics.mean(v[-k:])


def main():
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("log")
    ap.add_argument("--lines", type=int, default=5)
    o = ap.parse_args()
    if o.lines < 1:
        sys.exit("--lines: want at least 1")
    legs = legs_of(o.log)
    if not legs:
        sys.exit(f"{o.log}: no progress lines of gazesplat train")
    print(f"\n`{o.log}`: means of the first and last {o.lines} progress "
          "lines of each leg\n")
    print("| leg | steps | lines | PSNR dB | gaze° | median ms/step | "
          "skipped |")
    print("|---:|---|---:|---|---|---:|---:|")
    for i, (goal, rows) in enumerate(legs):
        p0, p1 = ends([r[1] for r in rows], o.lines)
        g = [r[2] for r in rows if r[2] is not None]
        gz = "{:.2f} → {:.2f}".format(*ends(g, o.lines)) if g else "–"
        ms = statistics.median(r[3] for r in rows)
        print(f"| {i + 1} | {rows[0][0]}–{rows[-1][0]} of {goal} | "
              f"{len(rows)} | {p0:.2f} → {p1:.2f} | {gz} | {ms:.0f} | "
              f"{rows[-1][4]} |")


if __name__ == "__main__":
    main()
