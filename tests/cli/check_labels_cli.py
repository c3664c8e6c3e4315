#!/usr/bin/env python3
"""gazesplat check-labels end to end, where the truth is known.

A synth dataset (test identities, default ranges) is checked as written,
then with a known tenth of its labels corrupted (yaw flipped). The exact
readout must flag exactly the corrupted labels whose flip moved them by
more than the threshold; the estimator alone is measured (recall and
precision printed) and held to what it was measured to do. Then: --max-
outliers' exit status, the JSON report, a kappa dataset, a folder of
augment-style labels, an HDF5 file, and bad inputs (each error names the
file and the line or row).
Usage: check_labels_cli.py GAZESPLAT ESTIMATOR"""
import json
import math
import os
import random
import subprocess
import sys
import tempfile

failures = []
N = 120
FLIP = 12


def check(cond, msg):
    if not cond:
        failures.append(msg)
        print("FAIL:", msg)


def run(exe, args, expect=None):
    r = subprocess.run([exe] + args, capture_output=True, text=True)
    if expect is not None:
        check(r.returncode == expect, "%s: exit %d, want %d: %s"
              % (" ".join(args), r.returncode, expect, r.stderr.strip()[-400:]))
    return r


def angle(p0, y0, p1, y1):
    def vec(p, y):
        return (-math.cos(p) * math.sin(y), -math.sin(p), -math.cos(p) * math.cos(y))
    a, b = vec(p0, y0), vec(p1, y1)
    d = max(-1.0, min(1.0, sum(x * y for x, y in zip(a, b))))
    return math.degrees(math.acos(d))


def corrupt(src, dst, rows):
    """Flips the yaw of the given rows in every gaze field; returns the
    label change (degrees) of each."""
    moved = {}
    with open(src) as f, open(dst, "w") as g:
        for i, line in enumerate(f):
            o = json.loads(line)
            if i in rows:
                for k in ("gaze_head_yaw_rad", "gaze_cam_yaw_rad", "gaze_norm_yaw_rad"):
                    o[k] = -o[k]
                for k in ("gaze_head", "gaze_cam"):
                    o[k][0] = -o[k][0]
                moved[o["index"]] = angle(o["gaze_norm_pitch_rad"], o["gaze_norm_yaw_rad"],
                                          o["gaze_norm_pitch_rad"], -o["gaze_norm_yaw_rad"])
            g.write(json.dumps(o) + "\n")
    return moved


def report(exe, est, ds, extra, expect=0):
    js = os.path.join(os.path.dirname(ds), "report.json")
    r = run(exe, ["check-labels", "--dir", ds, "--estimator", est, "--json", js] + extra,
            expect)
    return json.load(open(js)) if os.path.exists(js) and r.returncode in (0, 4) else None, r


def scores(rep, moved, key, thresh):
    flagged = {s["index"] for s in rep["per_sample"] if s["outlier"]}
    should = {i for i, m in moved.items() if m > thresh}
    tp = len(flagged & should)
    return flagged, should, tp


def main():
    exe, est = sys.argv[1], sys.argv[2]
    with tempfile.TemporaryDirectory() as tmp:
        ds = os.path.join(tmp, "ds")
        run(exe, ["synth", "--out", ds, "--count", str(N), "--seed-split", "test",
                  "--identities", "30", "--seed", "3", "--threads", "2"], 0)
        # 1. Correct labels: the exact readout agrees exactly.
        rep, r = report(exe, est, ds, [])
        check(rep is not None and rep["readout"] == "exact", "readout %r" % (rep and rep["readout"]))
        if rep is None:
            return finish()
        ro = rep["readout_error_deg"]
        check(ro["n"] == N and ro["max"] < 1e-3, "readout on correct labels: %r" % ro)
        check(rep["outliers"] == 0, "%d outliers among correct labels" % rep["outliers"])
        e = rep["estimator_error_deg"]
        print("estimator on correct labels: n %d mean %.2f median %.2f p90 %.2f max %.2f deg"
              % (e["n"], e["mean"], e["median"], e["p90"], e["max"]))
        check(e["n"] == N and e["median"] < 20, "estimator on correct labels: %r" % e)
        check(len(rep["subjects"]) > 1 and sum(s["samples"] for s in rep["subjects"]) == N,
              "per-subject summary %r" % rep["subjects"][:3])
        est_correct = {s["index"]: s["estimator_error_deg"] for s in rep["per_sample"]}
        # 2. A tenth of the labels with yaw flipped.
        rows = set(random.Random(7).sample(range(N), FLIP))
        bad = os.path.join(tmp, "bad.jsonl")
        moved = corrupt(os.path.join(ds, "labels.jsonl"), bad, rows)
        th = 2.0
        rep, r = report(exe, est, ds, ["--labels", bad, "--threshold", str(th)])
        flagged, should, tp = scores(rep, moved, "readout", th)
        print("exact readout, threshold %.0f deg: flagged %d, corrupted %d (%d moved > %.0f deg), "
              "true positives %d" % (th, len(flagged), FLIP, len(should), th, tp))
        check(flagged == should, "exact readout flagged %s, corrupted by > %.0f deg: %s"
              % (sorted(flagged), th, sorted(should)))
        check(len(should) >= FLIP - 2, "only %d flips moved a label by > %.0f deg"
              % (len(should), th))
        lst = rep["outlier_list"]
        check([s["error_deg"] for s in lst] == sorted((s["error_deg"] for s in lst), reverse=True),
              "outlier list not sorted by error")
        check({s["index"] for s in lst} == flagged, "outlier list != flagged samples")
        for s in lst:
            check(abs(s["readout_error_deg"] - moved[s["index"]]) < 1e-3,
                  "index %d: readout error %.4f, label moved %.4f"
                  % (s["index"], s["readout_error_deg"], moved[s["index"]]))
        # The table names them.
        for i in list(flagged)[:3]:
            check("images/%08d.png" % i in r.stdout, "table lacks sample %d" % i)
        # 3. The estimator alone on the same corrupted labels.
        th_est = 20.0
        rep, r = report(exe, est, ds, ["--labels", bad, "--readout", "off"])
        check(rep["readout"] is None and rep["threshold_deg"] == th_est, "estimator-only report")
        flagged = {s["index"] for s in rep["per_sample"] if s["outlier"]}
        big = {i for i, m in moved.items() if m > 2 * th_est}
        tp_all = len(flagged & set(moved))
        tp_big = len(flagged & big)
        fp = len(flagged - set(moved))
        false_rate = sum(1 for i, v in est_correct.items() if v > th_est and i not in moved)
        print("estimator alone, threshold %.0f deg: flagged %d; recall %d/%d of all flips, "
              "%d/%d of flips moving the label > %.0f deg; precision %d/%d; correct labels "
              "flagged %d/%d" % (th_est, len(flagged), tp_all, FLIP, tp_big, len(big),
                                 2 * th_est, tp_all, len(flagged), fp, N - FLIP))
        check(false_rate == fp, "estimator flags differ between runs (%d vs %d)" % (false_rate, fp))
        check(len(big) == 0 or tp_big >= 0.6 * len(big),
              "estimator found %d of the %d flips moving the label > %.0f deg"
              % (tp_big, len(big), 2 * th_est))
        check(len(flagged) > 0 and tp_all / len(flagged) > 2 * FLIP / N,
              "estimator precision %d/%d not above twice the base rate" % (tp_all, len(flagged)))
        # 4. --max-outliers.
        frac = len(should) / N
        run(exe, ["check-labels", "--dir", ds, "--labels", bad, "--estimator", "none",
                  "--threshold", str(th), "--max-outliers", "%.4f" % (frac / 2)], 4)
        run(exe, ["check-labels", "--dir", ds, "--labels", bad, "--estimator", "none",
                  "--threshold", str(th), "--max-outliers", "%.4f" % min(1, frac * 1.5)], 0)
        # 5. Kappa: the labels are the visual axis, the readout agrees.
        kd = os.path.join(tmp, "kappa", "ds")
        os.makedirs(os.path.dirname(kd))
        run(exe, ["synth", "--out", kd, "--count", "8", "--kappa", "literature",
                  "--threads", "2"], 0)
        rep, r = report(exe, est, kd, [])
        check(rep["readout_error_deg"]["max"] < 1e-3 and rep["outliers"] == 0,
              "kappa dataset: %r" % rep["readout_error_deg"])
        # 6. Augment-style labels (no README: estimator only), subjects.
        ad = os.path.join(tmp, "aug")
        os.makedirs(ad)
        os.symlink(os.path.join(ds, "images"), os.path.join(ad, "images"))
        with open(os.path.join(ds, "labels.jsonl")) as f, \
                open(os.path.join(ad, "labels.jsonl"), "w") as g:
            for i, line in enumerate(f):
                o = json.loads(line)
                g.write(json.dumps({"image": o["image"], "index": o["index"],
                                    "subject": "s%d" % (i % 3),
                                    "gaze_cam_pitch_rad": o["gaze_norm_pitch_rad"],
                                    "gaze_cam_yaw_rad": o["gaze_norm_yaw_rad"]}) + "\n")
                if i == 19:
                    break
        rep, r = report(exe, est, ad, [])
        check(rep["readout"] is None and rep["samples"] == 20 and len(rep["subjects"]) == 3,
              "augment-style folder: %r" % {k: rep[k] for k in ("readout", "samples")})
        for s in rep["per_sample"]:
            check(abs(s["estimator_error_deg"] - est_correct[s["index"]]) < 1e-9,
                  "augment-style: estimator error of %d differs" % s["index"])
        # 7. HDF5 (h5py, when there), BGR patches.
        try:
            import h5py
            import numpy
        except ImportError:
            h5py = None
        if h5py is not None:
            from_png = [json.loads(l) for l in open(os.path.join(ds, "labels.jsonl"))][:6]
            h5 = os.path.join(tmp, "subj.h5")
            # Pillow may be absent: a small decoder of gazesplat's PNGs.
            imgs = [read_png(os.path.join(ds, o["image"])) for o in from_png]
            with h5py.File(h5, "w") as f:
                f["face_patch"] = numpy.stack([im[:, :, ::-1] for im in imgs])
                f["face_gaze"] = numpy.array([[o["gaze_norm_pitch_rad"], o["gaze_norm_yaw_rad"]]
                                              for o in from_png], dtype=numpy.float32)
            js = os.path.join(tmp, "h5.json")
            run(exe, ["check-labels", "--h5", h5, "--estimator", est, "--json", js], 0)
            rep = json.load(open(js))
            check(rep["samples"] == 6 and rep["subjects"][0]["subject"] == "subj",
                  "h5 report %r" % rep["subjects"])
            for s, o in zip(rep["per_sample"], from_png):
                check(abs(s["estimator_error_deg"] - est_correct[o["index"]]) < 1e-4,
                      "h5 row %d: estimator error %.5f, from the PNG %.5f"
                      % (s["row"], s["estimator_error_deg"], est_correct[o["index"]]))
            with h5py.File(os.path.join(tmp, "shape.h5"), "w") as f:
                f["face_patch"] = numpy.zeros((2, 8, 8), numpy.uint8)
                f["face_gaze"] = numpy.zeros((2, 2), numpy.float32)
            r = run(exe, ["check-labels", "--h5", os.path.join(tmp, "shape.h5"),
                          "--estimator", est], 1)
            check("shape.h5" in r.stderr and "face_patch" in r.stderr, "h5 shape: %s" % r.stderr)
            with h5py.File(os.path.join(tmp, "nan.h5"), "w") as f:
                f["face_patch"] = numpy.zeros((3, 8, 8, 3), numpy.uint8)
                f["face_gaze"] = numpy.array([[0, 0], [0, float("nan")], [0, 0]], numpy.float32)
            r = run(exe, ["check-labels", "--h5", os.path.join(tmp, "nan.h5"),
                          "--estimator", est], 1)
            check("nan.h5" in r.stderr and "row 1" in r.stderr, "h5 NaN: %s" % r.stderr)
        # 8. Bad inputs name the file and line.
        lab = os.path.join(ds, "labels.jsonl")
        lines = open(lab).read().splitlines()

        def bad_labels(name, text, words):
            p = os.path.join(tmp, name)
            open(p, "w").write(text)
            r = run(exe, ["check-labels", "--dir", ds, "--labels", p, "--estimator", est], 1)
            for w in words:
                check(w in r.stderr, "%s: %r lacks %r" % (name, r.stderr.strip(), w))

        bad_labels("torn.jsonl", lines[0] + "\n" + lines[1][:200] + "\n",
                   ["torn.jsonl:2", "bad JSON"])
        bad_labels("junk.jsonl", lines[0] + "\n{\"image\": 1,}\n", ["junk.jsonl:2", "column"])
        o = json.loads(lines[2])
        o["gaze_norm_yaw_rad"] = None
        bad_labels("nan.jsonl", "\n".join(lines[:2] + [json.dumps(o)]) + "\n",
                   ["nan.jsonl:3", "gaze_norm_yaw_rad", "null"])
        o = json.loads(lines[0])
        o["image"] = "images/missing.png"
        bad_labels("missing.jsonl", json.dumps(o) + "\n", ["missing.jsonl:1", "missing.png"])
        o = json.loads(lines[0])
        del o["gaze_norm_pitch_rad"], o["gaze_cam_pitch_rad"]
        bad_labels("nolabel.jsonl", json.dumps(o) + "\n", ["nolabel.jsonl:1", "gaze"])
        o = json.loads(lines[0])
        o["image"] = "../x.png"
        bad_labels("escape.jsonl", json.dumps(o) + "\n", ["escape.jsonl:1", "relative"])
        bad_labels("empty.jsonl", "", ["empty.jsonl"])
        r = run(exe, ["check-labels", "--dir", os.path.join(tmp, "nowhere"), "--estimator", est], 1)
        check("nowhere/labels.jsonl" in r.stderr, "missing dir: %s" % r.stderr)
        r = run(exe, ["check-labels", "--dir", ds, "--estimator", os.path.join(tmp, "no.st")], 1)
        check("no.st" in r.stderr, "missing estimator: %s" % r.stderr)
        run(exe, ["check-labels"], 2)
        run(exe, ["check-labels", "--dir", ds, "--h5", "x.h5"], 2)
        run(exe, ["check-labels", "--dir", ds, "--threshold", "0"], 2)
        run(exe, ["check-labels", "--dir", ds, "--max-outliers", "1.5"], 2)
        run(exe, ["check-labels", "--dir", ds, "--readout", "maybe"], 2)
        run(exe, ["check-labels", "--dir", ad, "--readout", "exact", "--estimator", est], 1)
    return finish()


def read_png(path):
    """8-bit RGB, non-interlaced PNG (what gazesplat writes) to an array."""
    import struct
    import zlib
    import numpy
    data = open(path, "rb").read()
    pos, idat, w, h = 8, b"", 0, 0
    while pos < len(data):
        n, kind = struct.unpack(">I4s", data[pos:pos + 8])
        body = data[pos + 8:pos + 8 + n]
        if kind == b"IHDR":
            w, h, depth, ctype = struct.unpack(">IIBB", body[:10])
            assert depth == 8 and ctype == 2
        elif kind == b"IDAT":
            idat += body
        pos += 12 + n
    raw = zlib.decompress(idat)
    out = numpy.zeros((h, w * 3), numpy.int32)
    stride = w * 3
    prev = numpy.zeros(stride, numpy.int32)
    for y in range(h):
        f = raw[y * (stride + 1)]
        line = numpy.frombuffer(raw, numpy.uint8, stride, y * (stride + 1) + 1).astype(numpy.int32)
        cur = numpy.zeros(stride, numpy.int32)
        for x in range(stride):
            a = cur[x - 3] if x >= 3 else 0
            b = prev[x]
            c = prev[x - 3] if x >= 3 else 0
            if f == 0:
                p = 0
            elif f == 1:
                p = a
            elif f == 2:
                p = b
            elif f == 3:
                p = (a + b) // 2
            else:
                pa, pb, pc = abs(b - c), abs(a - c), abs(a + b - 2 * c)
                p = a if pa <= pb and pa <= pc else (b if pb <= pc else c)
            cur[x] = (line[x] + p) & 255
        out[y] = cur
        prev = cur
    return out.reshape(h, w, 3).astype(numpy.uint8)


def finish():
    if failures:
        print("%d failure(s)" % len(failures))
        return 1
    print("ok: check-labels")
    return 0


if __name__ == "__main__":
    sys.exit(main())
