"""The face gate through the real daemon and the CLI (issue 47): inputs
that cannot be redirected well are refused with a reason before any fit,
and the daemon goes on serving.

- normalized black, white, grey and noise frames: ERR_FACE_REFUSED with
  Error.refusal FLAT or NOISE, the reason in the message, the Python
  client's GazesplatError.refusal naming it; a synthetic face fits;
- photos: a photo with no face is ERR_NO_FACE; the astronaut fits; the
  astronaut shrunk until its eyes are 10 px wide is refused (SMALL_EYES);
- face_gate = no: the black frame fits (the gate is the only thing that
  refused it);
- the CLI: gazesplat fit of the black frame exits 3 naming the reason,
  --no-gate exits 0; gazesplat redirect of the small face exits 3;
- redirect quality: asked for, every gaze-only image of an inline
  REDIRECT carries Quality (not asked, none), a head change none, min_quality 1 drops every image (dropped,
  no pixels, STATS images_dropped), by key without a kept input none;
- gazesplat eval-photos: one face row, valid JSON of 25 images a mode;
- grey, CMYK and EXIF-rotated JPEGs find the face; a truncated one is a
  clear error.
usage: test_daemon_gate.py GAZESPLATD GAZESPLAT_CLI WORKDIR"""
import io
import json
import os
import shutil
import subprocess
import sys

import numpy as np
from PIL import Image

HERE = os.path.dirname(os.path.abspath(__file__))
sys.path.insert(0, HERE)
sys.path.insert(0, os.path.join(HERE, "..", "..", "clients", "python"))
from daemon_util import Checks, Daemon  # noqa: E402
from model_fixture import faces, tiny_model  # noqa: E402
from client_checks import expect_error, finish, wait_ready  # noqa: E402
import gazesplat_client as gc  # noqa: E402

ASTRONAUT = os.path.join(HERE, "..", "..", "samples", "astronaut.jpg")
FAST = 3


def png(a):
    b = io.BytesIO()
    Image.fromarray(np.asarray(a, dtype=np.uint8)).save(b, format="PNG")
    return b.getvalue()


def raw_fit(c, image, photo=False):
    """One FIT sent by hand: (frame type, message), to read Error.refusal."""
    req = gc.pb.FitRequest(max_iters=FAST)
    req.image.CopyFrom(gc.pb.Image(format=gc.pb.FORMAT_PNG, data=image,
                                   kind=gc.pb.KIND_PHOTO if photo else gc.pb.KIND_NORMALIZED_FACE))
    rid = c.new_id()
    c.send(gc.FT.FRAME_FIT, req, rid, gc.ZERO_KEY)
    while True:
        ftype, got, _, msg = c.recv()
        if got == rid:
            return ftype, msg


def main():
    daemon, cli, work = (os.path.abspath(a) for a in sys.argv[1:4])
    os.makedirs(work, exist_ok=True)
    t = Checks()
    model = tiny_model(cli, work, seed=1)
    face = faces(cli, work, 128, 3)[0]
    rng = np.random.default_rng(47)
    frames = {"black": (np.zeros((128, 128, 3)), "REFUSAL_FLAT", "flat"),
              "white": (np.full((128, 128, 3), 255), "REFUSAL_FLAT", "flat"),
              "grey": (np.full((128, 128, 3), 128), "REFUSAL_FLAT", "flat"),
              "noise": (rng.integers(0, 256, (128, 128, 3)), "REFUSAL_NOISE", "noise")}
    astro = Image.open(ASTRONAUT).convert("RGB")
    small = Image.new("RGB", (640, 480), (90, 100, 110))
    small.paste(astro.resize((160, 160), Image.BILINEAR), (240, 160))
    sb = io.BytesIO()
    small.save(sb, format="PNG")
    small_png = sb.getvalue()
    small_path = os.path.join(work, "gate_small_face.png")
    with open(small_path, "wb") as f:
        f.write(small_png)
    astro_png = open(ASTRONAUT, "rb").read()
    no_face = png(np.full((480, 640, 3), 40))

    d = Daemon(daemon, ["--model", model]).start()
    try:
        addr = "unix:" + d.sock
        wait_ready(t, addr)
        with gc.Client(addr) as c:
            for name, (a, refusal, word) in frames.items():
                ftype, msg = raw_fit(c, png(a))
                t.check(ftype == gc.FT.FRAME_ERROR and msg.code == gc.pb.ERR_FACE_REFUSED and
                        msg.refusal == gc.pb.FaceRefusal.Value(refusal),
                        "%s frame: %s %s" % (name, gc.FT.Name(ftype), msg))
                if ftype == gc.FT.FRAME_ERROR:
                    t.check(msg.message.startswith("face refused (%s): " % word),
                            "%s frame: message %r" % (name, msg.message))
                e = expect_error(t, lambda: c.fit(png(a), max_iters=FAST), gc.pb.ERR_FACE_REFUSED,
                                 "%s frame (client)" % name)
                if e:
                    t.check(e.refusal == word, "%s: GazesplatError.refusal %r" % (name, e.refusal))
            r = c.fit(face, max_iters=FAST)
            t.check(len(r.subject_key) == 16, "a synthetic face fits")
            e = expect_error(t, lambda: c.fit(no_face, photo=True, max_iters=FAST),
                             gc.pb.ERR_NO_FACE, "photo without a face", "no face")
            t.check(e is None or e.refusal == "", "ERR_NO_FACE carries no gate refusal")
            ftype, msg = raw_fit(c, small_png, photo=True)
            t.check(ftype == gc.FT.FRAME_ERROR and msg.code == gc.pb.ERR_FACE_REFUSED and
                    msg.refusal == gc.pb.REFUSAL_SMALL_EYES and "eyes too small" in msg.message,
                    "10 px eyes: %s %s" % (gc.FT.Name(ftype), msg))
            r = c.fit(astro_png, photo=True, max_iters=FAST)
            t.check(len(r.subject_key) == 16, "the astronaut fits")
            # Asked for, every gaze-only image carries its quality (the input
            # is inline); not asked, none; a head change has none;
            # min_quality 1 drops them all.
            targets = [(0, 20), (10, 0)]
            got = list(c.redirect(targets, image=face, max_iters=FAST))
            t.check(len(got) == 2 and not any(g.HasField("quality") for g in got),
                    "not asked: no quality")
            got = list(c.redirect(targets, image=face, max_iters=FAST, quality=True))
            t.check(len(got) == 2 and all(g.HasField("quality") and g.HasField("image") and
                                          not g.dropped for g in got),
                    "inline REDIRECT: quality with every image")
            for g in got:
                q = g.quality
                t.check(0 <= q.score <= 1 and q.eye_speckle > 0 and
                        abs(q.asked.yaw_deg + q.asked.pitch_deg) > 5,
                        "quality fields: %s" % str(q).replace("\n", " "))
            got = list(c.redirect([(0, 20)], image=face, max_iters=FAST, head_deg=[(10, 10)],
                                  quality=True))
            t.check(len(got) == 1 and not got[0].HasField("quality"), "a head change has no quality")
            got = list(c.redirect(targets, image=face, max_iters=FAST, min_quality=1.0))
            t.check(len(got) == 2 and all(g.dropped and not g.HasField("image") for g in got),
                    "min_quality 1: every image dropped, its index and quality kept: %s" %
                    [(g.index, g.dropped, g.quality.score) for g in got])
            key = c.fit(face, max_iters=FAST).subject_key
            got = list(c.redirect(targets, subject=key, quality=True))
            t.check(len(got) == 2 and not any(g.HasField("quality") for g in got),
                    "by key without a kept input: no quality")
            expect_error(t, lambda: c.redirect(targets, image=face, min_quality=1.5),
                         gc.pb.ERR_INVALID_ARGUMENT, "min_quality 1.5", "min_quality")
            t.check(c.stats()["images_dropped"] == 2, "STATS images_dropped")
            st = c.stats()
            t.check(st["request_errors"] >= 7, "request_errors %d" % st["request_errors"])
    finally:
        rc = finish(t, d)
    d = Daemon(daemon, ["--model", model, "--set", "photo_input=no", "--set", "face_gate=no"]).start()
    try:
        addr = "unix:" + d.sock
        wait_ready(t, addr)
        with gc.Client(addr) as c:
            r = c.fit(png(frames["black"][0]), max_iters=FAST)
            t.check(len(r.subject_key) == 16, "face_gate = no: the black frame fits")
    finally:
        rc = finish(t, d) or rc

    black = os.path.join(work, "gate_black.png")
    with open(black, "wb") as f:
        f.write(png(frames["black"][0]))
    sub = os.path.join(work, "gate_black.bin")
    if os.path.exists(sub):
        os.remove(sub)
    p = subprocess.run([cli, "fit", "--model", model, "--image", black, "--out", sub,
                        "--iters", str(FAST)], capture_output=True, text=True)
    t.check(p.returncode == 3 and "face refused (flat)" in p.stderr,
            "gazesplat fit of a black frame: exit %d, %s" % (p.returncode, p.stderr.strip()))
    t.check(not os.path.exists(sub), "no subject file for a refused face")
    p = subprocess.run([cli, "fit", "--model", model, "--image", black, "--out", sub,
                        "--iters", str(FAST), "--no-gate"], capture_output=True, text=True)
    t.check(p.returncode == 0 and os.path.exists(sub), "--no-gate: exit %d %s" % (p.returncode, p.stderr))
    p = subprocess.run([cli, "redirect", "--model", model, "--image", small_path, "--gaze-deg", "0,10",
                        "--out", os.path.join(work, "gate_out"), "--iters", str(FAST)],
                       capture_output=True, text=True)
    t.check(p.returncode == 3 and "face refused (small_eyes)" in p.stderr,
            "gazesplat redirect of 10 px eyes: exit %d, %s" % (p.returncode, p.stderr.strip()))
    # The real-photo report on the astronaut and on a photo without a face:
    # one row per face and mode, valid JSON with 25 measured images a mode.
    rep = os.path.join(work, "gate_eval.json")
    nf = os.path.join(work, "gate_noface.png")
    with open(nf, "wb") as f:
        f.write(no_face)
    p = subprocess.run([cli, "eval-photos", "--model", model, "--photos", ASTRONAUT + "," + nf,
                        "--iters", str(FAST), "--finetune", "0", "--out-json", rep],
                       capture_output=True, text=True)
    t.check(p.returncode == 0 and "| astronaut.jpg | 0 | plain |" in p.stdout and
            "1 faces, 1 passed the gate" in p.stdout, "eval-photos: exit %d %s %s" %
            (p.returncode, p.stdout[-400:], p.stderr[-400:]))
    if p.returncode == 0:
        d = json.load(open(rep))
        f0 = d["faces"][0] if d["faces"] else {}
        t.check(len(d["faces"]) == 1 and f0.get("gate") == "usable" and len(f0.get("modes", [])) == 2 and
                all(len(m["images"]) == 25 for m in f0["modes"]), "eval-photos JSON: %s" % str(d)[:300])
    # augment --quality: each gaze-only label carries its quality; without
    # it, null.
    for flag in ([], ["--quality"]):
        out = os.path.join(work, "gate_aug%s" % ("_q" if flag else ""))
        shutil.rmtree(out, ignore_errors=True)
        p = subprocess.run([cli, "augment", "--model", model, "--input",
                            os.path.join(work, "faces128", "images"), "--out", out,
                            "--gaze-deg", "0,15;10,0", "--iters", str(FAST), "--finetune", "0",
                            "--format", "png"] + flag, capture_output=True, text=True)
        t.check(p.returncode == 0, "augment %s: exit %d %s" % (flag, p.returncode, p.stderr[-300:]))
        if p.returncode == 0:
            qs = [json.loads(x)["quality"] for x in open(os.path.join(out, "labels.jsonl"))]
            if flag:
                t.check(len(qs) == 6 and all(q and 0 <= q["score"] <= 1 and q["eye_speckle"] > 0
                                             for q in qs), "augment --quality: %s" % qs[:2])
            else:
                t.check(len(qs) == 6 and all(q is None for q in qs), "augment: quality null")
    # Photos in the forms phones and scanners write: grey and CMYK JPEGs and
    # an EXIF-rotated one find the face as the plain photo does (within a
    # few px); a truncated one is a clear error.
    variants = {"grey": astro.convert("L"), "cmyk": astro.convert("CMYK")}
    rot = astro.rotate(90, expand=True)
    ex = Image.Exif()
    ex[0x0112] = 6  # shown rotated 90 degrees clockwise
    for name, im in list(variants.items()) + [("exif", rot)]:
        path = os.path.join(work, "gate_%s.jpg" % name)
        im.save(path, quality=92, **({"exif": ex} if name == "exif" else {}))
        p = subprocess.run([cli, "face", "--image", path, "--json"], capture_output=True, text=True)
        ok = p.returncode == 0
        if ok:
            box = json.loads(p.stdout)["box"]
            ok = abs(box[0] - 173) <= 6 and abs(box[1] - 128) <= 6
        t.check(ok, "%s JPEG: exit %d %s %s" % (name, p.returncode, p.stdout[:120], p.stderr[-200:]))
    trunc = os.path.join(work, "gate_trunc.jpg")
    with open(trunc, "wb") as f:
        f.write(open(ASTRONAUT, "rb").read()[:5000])
    p = subprocess.run([cli, "face", "--image", trunc], capture_output=True, text=True)
    t.check(p.returncode == 1 and "truncated" in p.stderr, "truncated JPEG: exit %d %s" %
            (p.returncode, p.stderr.strip()))
    p = subprocess.run([cli, "eval-photos", "--model", model], capture_output=True, text=True)
    t.check(p.returncode == 2, "eval-photos without --photos: exit %d" % p.returncode)
    return t.status()


if __name__ == "__main__":
    sys.exit(main())
