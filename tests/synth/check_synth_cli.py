"""End-to-end check of `gazesplat synth`: dataset files, labels.jsonl
fields and conventions, contact sheet, template PLY, the printed 6-point
face model, determinism across runs and thread counts, usage errors.

usage: check_synth_cli.py GAZESPLAT"""
import json
import math
import os
import struct
import subprocess
import sys
import tempfile

failures = []


def check(cond, what):
    if not cond:
        failures.append(what)
        print("FAIL:", what, file=sys.stderr)


def png_size(path):
    with open(path, "rb") as f:
        head = f.read(24)
    if head[:8] != b"\x89PNG\r\n\x1a\n" or head[12:16] != b"IHDR":
        return None
    return struct.unpack(">II", head[16:24])


def run(exe, args, want=0):
    p = subprocess.run([exe, "synth"] + args, capture_output=True, text=True)
    check(p.returncode == want, "synth %s: exit %d (want %d): %s" %
          (" ".join(args), p.returncode, want, p.stderr.strip()[-300:]))
    return p


def read(path):
    with open(path, "rb") as f:
        return f.read()


def main():
    exe = sys.argv[1]
    tmp = tempfile.mkdtemp(prefix="gs_synth_")
    a, b = os.path.join(tmp, "a"), os.path.join(tmp, "b")
    sheet, ply = os.path.join(tmp, "sheet.png"), os.path.join(tmp, "t.ply")
    n, size = 4, 48
    common = ["--count", str(n), "--size", str(size), "--seed-split", "val",
              "--rig", "ethx", "--supersample", "2", "--seed", "7"]
    run(exe, ["--out", a, "--threads", "1", "--sheet", sheet, "--rows", "2",
              "--template", ply, "--spacing", "6"] + common)
    run(exe, ["--out", b, "--threads", "2"] + common)

    # Files and determinism.
    lines = open(os.path.join(a, "labels.jsonl")).read().splitlines()
    check(len(lines) == n, "labels.jsonl has %d lines" % len(lines))
    check(read(os.path.join(a, "labels.jsonl")) == read(os.path.join(b, "labels.jsonl")),
          "labels differ between runs / thread counts")
    for i in range(n):
        for sub in ("images", "masks"):
            p = os.path.join(a, sub, "%08d.png" % i)
            check(png_size(p) == (size, size), "%s is not a %dx%d PNG" % (p, size, size))
            check(read(p) == read(os.path.join(b, sub, "%08d.png" % i)),
                  "%s differs between runs / thread counts" % p)
    readme = open(os.path.join(a, "README.md")).read()
    for word in ("gaze_norm_pitch_rad", "landmarks_px", "pitch > 0"):
        check(word in readme, "README.md lacks %r" % word)

    # Labels.
    for i, line in enumerate(lines):
        d = json.loads(line)
        check(d["index"] == i and d["image"] == "images/%08d.png" % i, "index/image")
        check(d["mask"] == "masks/%08d.png" % i, "mask name")
        check(d["split"] == "val" and 1000000000 <= d["identity_seed"] < 2000000000,
              "split of identity seed %d" % d["identity_seed"])
        check(len(d["landmarks_px"]) == 68 and len(d["landmarks_mm"]) == 68, "landmarks")
        # The ETH-XGaze convention, recomputed here.
        g = d["gaze_cam"]
        p = math.asin(-g[1])
        y = math.atan2(-g[0], -g[2])
        check(abs(p - d["gaze_cam_pitch_rad"]) < 1e-8 and abs(y - d["gaze_cam_yaw_rad"]) < 1e-8,
              "gaze_cam angles vs vector")
        R = d["head_R"]
        gh = d["gaze_head"]
        gc = [sum(R[3 * r + k] * gh[k] for k in range(3)) for r in range(3)]
        check(max(abs(gc[k] - g[k]) for k in range(3)) < 1e-8, "gaze_cam = head_R gaze_head")
        # 2D landmarks are projections of the 3D ones.
        K = d["K"]
        worst = 0.0
        for X, uv in zip(d["landmarks_mm"], d["landmarks_px"]):
            if uv[0] is None:
                continue
            u = K[0] * X[0] / X[2] + K[2]
            v = K[4] * X[1] / X[2] + K[5]
            worst = max(worst, abs(u - uv[0]), abs(v - uv[1]))
        check(worst < 1e-5, "landmark projection off by %g px" % worst)
        check(len(d["identity"]) >= 40 and "mouth_open" in d["expression"], "parameters")

    # Sheet and template.
    check(png_size(sheet) == (9 * size, 2 * size), "sheet size %s" % (png_size(sheet),))
    raw = read(ply)
    end = raw.index(b"end_header\n") + len(b"end_header\n")
    header = raw[:end].decode()
    nv = int(header.split("element vertex ")[1].split()[0])
    check("element landmark 68" in header, "template lacks landmarks")
    check(len(raw) == end + nv * 28 + 68 * 12, "template PLY size")
    check(nv > 1000, "template has %d points" % nv)

    # The face model printed for lib/geom equals the template's landmarks
    # 36, 39, 42, 45, 31, 35, then the nose 27-30, 32-34 (float32 in the PLY).
    out = run(exe, ["--face-model6"]).stdout
    rows = [[float(v) for v in line.strip().strip("{},;").replace("}", "").split(",")]
            for line in out.splitlines() if line.strip().startswith("{")]
    lm = struct.unpack("<%df" % (68 * 3), raw[len(raw) - 68 * 12:])
    check(len(rows) == 13 and all(len(r) == 3 for r in rows),
          "--face-model6 printed %r" % out)
    if len(rows) == 13:
        worst = max(abs(rows[i][j] - lm[3 * k + j])
                    for i, k in enumerate((36, 39, 42, 45, 31, 35, 27, 28, 29, 30, 32, 33, 34))
                    for j in range(3))
        check(worst < 1e-3, "--face-model6 vs template landmarks: %g mm" % worst)

    # Usage errors.
    run(exe, [], want=2)
    run(exe, ["--out", a, "--rig", "dome"], want=2)
    run(exe, ["--out", a, "--size", "5"], want=2)
    run(exe, ["--out", a, "--seed-split", "holdout"], want=2)
    run(exe, ["--out", os.path.join(tmp, "no", "such", "dir"), "--count", "1"], want=1)

    if failures:
        print("%d checks failed" % len(failures))
        return 1
    print("ok: synth CLI end to end")
    return 0


if __name__ == "__main__":
    sys.exit(main())
