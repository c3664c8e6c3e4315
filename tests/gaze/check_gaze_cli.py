#!/usr/bin/python3
"""The estimator commands end to end: usage errors exit 2 with the usage,
runtime failures exit 1 with a message, and a tiny train -> estimate ->
eval-estimator run works and prints what the docs say.

Usage: check_gaze_cli.py PATH_TO_GAZESPLAT"""
import os
import subprocess
import sys
import tempfile

exe = sys.argv[1]
failures = 0


def run(*args):
    p = subprocess.run([exe, *args], capture_output=True, text=True, timeout=120)
    return p.returncode, p.stdout, p.stderr


def expect(code, args, needle=None, where="stderr"):
    global failures
    rc, out, err = run(*args)
    text = out if where == "stdout" else err
    if rc != code or (needle and needle not in text):
        failures += 1
        print(f"FAIL gazesplat {' '.join(args)}: exit {rc} (want {code}), "
              f"{where} {text[:300]!r} (want {needle!r})")
    return out


with tempfile.TemporaryDirectory() as d:
    est = os.path.join(d, "tiny.safetensors")
    usage = "usage: gazesplat"
    for args in (["train-estimator"], ["train-estimator", "--out", est],
                 ["train-estimator", "--arch", "alexnet", "--out", est],
                 ["train-estimator", "--arch", "vgg"],
                 ["train-estimator", "--arch", "vgg", "--out", est, "--steps", "0"],
                 ["train-estimator", "--arch", "vgg", "--out", est, "--input", "40"],
                 ["train-estimator", "--arch", "vgg", "--out", est, "--widths", "1,2"],
                 ["train-estimator", "--arch", "vgg", "--out", est, "--lr", "-1"],
                 ["train-estimator", "--arch", "vgg", "--out", est, "--bogus"],
                 ["train-estimator", "--arch", "vgg", "--out", est, "--render-size", "600"],
                 ["train-estimator", "--arch", "vgg", "--out", est, "--render-size", "48"],
                 ["train-estimator", "--arch", "vgg", "--out", est, "--white", "1.5"],
                 ["train-estimator", "--arch", "vgg", "--out", est, "--blur", "x"],
                 ["train-estimator", "--arch", "vgg", "--out", est, "--shift", "17"],
                 ["eval-estimator", "--model", est, "--white", "1"],
                 ["estimate"], ["estimate", "--model", est],
                 ["estimate", "--model", est, "--image", "x.png", "extra"],
                 ["eval-estimator"], ["eval-estimator", "--model", est, "--split", "all"],
                 ["eval-estimator", "--model", est, "--count", "0"],
                 ["eval-estimator", "--model", est + ","]):
        expect(2, args, usage)
    expect(1, ["estimate", "--model", os.path.join(d, "missing.safetensors"),
               "--image", "x.png"], "gazesplat estimate:")
    expect(1, ["train-estimator", "--arch", "vgg", "--out", est, "--resume"],
           "gazesplat train-estimator:")
    expect(0, ["help", "train-estimator"], usage, "stdout")
    expect(0, ["train-estimator", "--arch", "resnet", "--out", est, "--input", "32",
               "--widths", "2,2,3,3", "--hidden", "4", "--steps", "3", "--batch", "2",
               "--cache", "4", "--fresh", "2", "--threads", "2", "--log-every", "1"],
           "step 3/3")
    expect(1, ["train-estimator", "--arch", "vgg", "--out", est, "--resume", "--steps", "4"],
           "not vgg")
    # the evaluation's image style and the gaze-neutral augmentations
    est2 = os.path.join(d, "white.safetensors")
    expect(0, ["train-estimator", "--arch", "resnet", "--out", est2, "--input", "32",
               "--widths", "2,2,3,3", "--hidden", "4", "--steps", "3", "--batch", "2",
               "--cache", "4", "--fresh", "2", "--threads", "2", "--log-every", "1",
               "--render-size", "48", "--white", "1", "--shift", "2", "--blur", "0.5"],
           "step 3/3")
    expect(1, ["train-estimator", "--arch", "resnet", "--out", est2, "--input", "32",
               "--steps", "4", "--batch", "2", "--cache", "4", "--fresh", "2", "--resume",
               "--render-size", "48", "--white", "1", "--shift", "2"], "blur")
    expect(0, ["synth", "--out", os.path.join(d, "ds"), "--count", "1", "--size", "48",
               "--seed-split", "test", "--no-masks", "--threads", "1"])
    png = os.path.join(d, "ds", "images", "00000000.png")
    out = expect(0, ["estimate", "--model", est, "--image", png], "gaze_pitch_deg", "stdout")
    if len(out.split("\n")) != 5:
        failures += 1
        print(f"FAIL estimate printed {out!r}")
    expect(0, ["eval-estimator", "--model", est + "," + est, "--count", "3", "--size", "48",
               "--csv", os.path.join(d, "e.csv")], "gaze error (deg): mean", "stdout")
    # on white backgrounds the readings change (the same images otherwise)
    expect(0, ["eval-estimator", "--model", est, "--count", "3", "--size", "48", "--white",
               "--csv", os.path.join(d, "w.csv")], "gaze error (deg): mean", "stdout")
    with open(os.path.join(d, "w.csv")) as f:
        white_rows = f.read().splitlines()
    with open(os.path.join(d, "e.csv")) as f:
        plain_rows = [r for r in f.read().splitlines() if r.startswith("0,") or
                      r.startswith("model")]
    if len(white_rows) != 4 or white_rows[0] != plain_rows[0] or white_rows[1:] == plain_rows[1:]:
        failures += 1
        print(f"FAIL eval-estimator --white: {white_rows[:2]} vs {plain_rows[:2]}")
    with open(os.path.join(d, "e.csv")) as f:
        rows = f.read().splitlines()
    if len(rows) != 7 or not rows[0].startswith("model,index,gaze_pitch_deg"):
        failures += 1
        print(f"FAIL eval-estimator csv: {rows[:2]}")

print("ok" if not failures else f"FAILED: {failures}")
sys.exit(1 if failures else 0)
