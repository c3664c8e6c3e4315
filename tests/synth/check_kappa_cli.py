#!/usr/bin/env python3
"""gazesplat synth --kappa end to end.

Default runs (no --kappa, and --kappa off) keep the bytes of the tree
before kappa existed: the digests below were computed from those files,
written by the same commands with the build before this option. With
--kappa the gaze labels stay the same numbers (the visual axis), the
pupils move, and the labels and README state kappa and the optical axes.
Usage: check_kappa_cli.py GAZESPLAT"""
import hashlib
import json
import os
import subprocess
import sys
import tempfile

GOLDEN = {
    # synth --out D --count 4 --size 64 --threads 1
    "a": "2aec494262205d685b155d958c3dd64c181651e444d226570e5d48e08403ee8b",
    # synth --out D --count 2 --size 48 --rig single --supersample 2 --seed 5
    #       --seed-split test --threads 1
    "b": "456064bcb9afce2cb6a6f594e88a72f00f7b30f1601c0ee12381c7c7c0705101",
}
ARGS = {
    "a": ["--count", "4", "--size", "64"],
    "b": ["--count", "2", "--size", "48", "--rig", "single", "--supersample", "2",
          "--seed", "5", "--seed-split", "test"],
}

failures = []


def check(cond, msg):
    if not cond:
        failures.append(msg)
        print("FAIL:", msg)


def digest(d):
    """sha256 over (relative name, NUL, bytes) of every file, sorted."""
    h = hashlib.sha256()
    per = {}
    for root, _, files in sorted(os.walk(d)):
        for f in sorted(files):
            p = os.path.join(root, f)
            rel = os.path.relpath(p, d)
            data = open(p, "rb").read()
            h.update(rel.encode() + b"\0" + data)
            per[rel] = hashlib.sha256(data).hexdigest()[:16]
    return h.hexdigest(), per


def synth(exe, out, args, expect=0):
    r = subprocess.run([exe, "synth", "--out", out, "--threads", "1"] + args,
                       capture_output=True, text=True)
    check(r.returncode == expect, "synth %s: exit %d (want %d): %s"
          % (" ".join(args), r.returncode, expect, r.stderr.strip()[-300:]))
    return r


def main():
    exe = sys.argv[1]
    with tempfile.TemporaryDirectory() as tmp:
        for key, args in ARGS.items():
            for extra in ([], ["--kappa", "off"]):
                d = os.path.join(tmp, key + "".join(extra))
                synth(exe, d, args + extra)
                got, per = digest(d)
                check(got == GOLDEN[key], "default run %s %s: digest %s, want %s "
                      "(per file: %s)" % (key, extra, got, GOLDEN[key], per))
        # With kappa: same gaze labels, moved pupils, stated fields.
        base = os.path.join(tmp, "a")
        kap = os.path.join(tmp, "kappa")
        synth(exe, kap, ARGS["a"] + ["--kappa", "literature"])
        la = [json.loads(s) for s in open(os.path.join(base, "labels.jsonl"))]
        lk = [json.loads(s) for s in open(os.path.join(kap, "labels.jsonl"))]
        check(len(la) == len(lk) == 4, "label lines %d %d" % (len(la), len(lk)))
        same = ["gaze_head", "gaze_cam", "gaze_norm_pitch_rad", "gaze_norm_yaw_rad",
                "head_R", "identity_seed", "eye_centre_mm", "face_centre_mm"]
        for a, k in zip(la, lk):
            for f in same:
                check(a[f] == k[f], "index %d: %s differs with kappa" % (a["index"], f))
            # Lid-margin landmarks (36-47) touch the eyeball; the rest stay.
            check(a["landmarks_head_mm"][:36] == k["landmarks_head_mm"][:36] and
                  a["landmarks_head_mm"][48:] == k["landmarks_head_mm"][48:],
                  "index %d: landmarks outside the eyes moved" % a["index"])
            check("gaze_axis" not in a and "kappa_h_rad" not in a,
                  "kappa fields without --kappa")
            check(k.get("gaze_axis") == "visual", "gaze_axis %r" % k.get("gaze_axis"))
            for f in ("kappa_h_rad", "kappa_v_rad"):
                check(isinstance(k.get(f), float) and abs(k[f]) < 0.3, "%s %r" % (f, k.get(f)))
            for f in ("gaze_optical_head", "gaze_optical_cam"):
                check(len(k.get(f, [])) == 2 and all(len(v) == 3 for v in k[f]), f)
            for f in ("gaze_optical_%s_%s_rad" % (fr, an) for fr in ("head", "cam", "norm")
                      for an in ("pitch", "yaw")):
                check(len(k.get(f, [])) == 2, f)
            # The right eye turns temporally (head yaw up), the left one down.
            dr = k["gaze_optical_head_yaw_rad"][0] - k["gaze_head_yaw_rad"]
            dl = k["gaze_optical_head_yaw_rad"][1] - k["gaze_head_yaw_rad"]
            check((dr > 0) == (k["kappa_h_rad"] > 0) and (dl < 0) == (k["kappa_h_rad"] > 0),
                  "index %d: optical yaw offsets %.4f %.4f for kappa_h %.4f"
                  % (k["index"], dr, dl, k["kappa_h_rad"]))
            check(a["pupil_centre_px"] != k["pupil_centre_px"], "pupils did not move")
        seeds = {}
        for k in lk:
            seeds.setdefault(k["identity_seed"], set()).add((k["kappa_h_rad"], k["kappa_v_rad"]))
        check(all(len(v) == 1 for v in seeds.values()), "kappa varies within an identity")
        readme = open(os.path.join(kap, "README.md")).read()
        check("Angle kappa per identity: horizontal 5 +- 1.3 deg, vertical 1.5 +- 1 deg"
              in readme and "## Angle kappa" in readme, "README lacks the kappa lines")
        # Explicit parameters and bad ones.
        synth(exe, os.path.join(tmp, "fixed"), ["--count", "1", "--size", "32",
                                               "--kappa", "4,0,-1,0"])
        k = json.loads(open(os.path.join(tmp, "fixed", "labels.jsonl")).readline())
        check(abs(k["kappa_h_rad"] - 4 * 3.141592653589793 / 180) < 1e-12 and
              abs(k["kappa_v_rad"] + 3.141592653589793 / 180) < 1e-12,
              "fixed kappa %r %r" % (k["kappa_h_rad"], k["kappa_v_rad"]))
        for bad, word in (("on", "--kappa"), ("5,1,1", "--kappa"), ("5,1,1,1,1", "--kappa"),
                          ("5,-1,1,1", "horizontal sd"), ("20,1,1,1", "horizontal mean"),
                          ("5,1,1,nan", "--kappa"), ("5,1,1,9", "vertical sd")):
            r = synth(exe, os.path.join(tmp, "bad"), ["--count", "1", "--kappa", bad], 2)
            check(word in r.stderr, "--kappa %s: message %r lacks %r" % (bad, r.stderr, word))
    if failures:
        print("%d failure(s)" % len(failures))
        return 1
    print("ok: default runs keep their bytes; kappa labels and signs")
    return 0


if __name__ == "__main__":
    sys.exit(main())
