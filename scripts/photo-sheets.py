#!/usr/bin/python3
"""Contact sheets of redirected real faces: for every face the detector
finds in the test photos (samples/astronaut.jpg and the face-api demo
photos fetched by scripts/fetch-test-assets.sh), the input, then a 5 x 5
grid of gaze targets (pitch +20/+10/0/-10/-20 by yaw +25/+15/0/-15/-25,
head frame degrees), each tile the face with its eye region enlarged
below it; once with the model's render pasted back (plain) and once with
detail transfer (transfer). Faces the gate refuses get a sheet that says
why. Writes DIR/<photo>-<face>.jpg and DIR/index.md (default DIR:
docs/photos).

usage: scripts/photo-sheets.py [--cli BUILD/clients/cli/gazesplat]
                               [--model M] [--out DIR] [--only NAME]"""
import argparse
import json
import os
import subprocess
import sys
import tempfile

from PIL import Image, ImageDraw

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
PITCH = [20, 10, 0, -10, -20]
YAW = [25, 15, 0, -15, -25]
TILE = 140          # face tile side, px
EYE_H = 46          # eye strip height under each tile


def photos():
    out = [("astronaut", os.path.join(ROOT, "samples", "astronaut.jpg"))]
    for i in range(1, 7):
        out.append(("sample%d" % i, os.path.join(ROOT, "assets", "face-api", "sample%d.jpg" % i)))
    return [(n, p) for n, p in out if os.path.exists(p)]


def faces_of(cli, path):
    r = subprocess.run([cli, "face", "--image", path, "--list"], capture_output=True, text=True)
    head = r.stdout.split("\n", 1)[0]
    n = int(head.split(":")[1].split()[0]) if r.returncode == 0 and ":" in head else 0
    out = []
    for i in range(n):
        r = subprocess.run([cli, "face", "--image", path, "--index", str(i), "--json",
                            "--pose-model", "synth"], capture_output=True, text=True)
        if r.returncode == 0:
            out.append((i, json.loads(r.stdout)))
    return out


def crops(img, lm):
    """The face (square around the landmarks, 1.4x) and both eyes (a 3:1
    box around 36-47), resized to the tile."""
    xs = [p[0] for p in lm]
    ys = [p[1] for p in lm]
    cx, cy = (min(xs) + max(xs)) / 2, (min(ys) + max(ys)) / 2
    half = 0.7 * max(max(xs) - min(xs), max(ys) - min(ys))
    face = img.crop((int(cx - half), int(cy - half), int(cx + half), int(cy + half)))
    ex = [p[0] for p in lm[36:48]]
    ey = [p[1] for p in lm[36:48]]
    ecx, ecy = (min(ex) + max(ex)) / 2, (min(ey) + max(ey)) / 2
    ew = 1.25 * (max(ex) - min(ex))
    eh = ew * EYE_H / TILE
    eyes = img.crop((int(ecx - ew / 2), int(ecy - eh / 2), int(ecx + ew / 2), int(ecy + eh / 2)))
    return face.resize((TILE, TILE), Image.LANCZOS), eyes.resize((TILE, EYE_H), Image.LANCZOS)


def tile(img, lm, label):
    f, e = crops(img, lm)
    t = Image.new("RGB", (TILE, TILE + EYE_H + 14), (255, 255, 255))
    t.paste(f, (0, 0))
    t.paste(e, (0, TILE))
    ImageDraw.Draw(t).text((3, TILE + EYE_H + 1), label, fill=(0, 0, 0))
    return t


def redirect(cli, model, path, index, transfer, work):
    out = os.path.join(work, "t" if transfer else "p")
    targets = ";".join("%d,%d" % (p, y) for p in PITCH for y in YAW)
    cmd = [cli, "redirect", "--model", model, "--image", path, "--index", str(index),
           "--gaze-deg", targets, "--out", out]
    if transfer:
        cmd.append("--transfer")
    r = subprocess.run(cmd, capture_output=True, text=True)
    if r.returncode != 0:
        why = r.stderr.strip().splitlines()[-1] if r.stderr.strip() else "exit %d" % r.returncode
        return None, why.replace("gazesplat redirect: ", "").replace(path, os.path.basename(path))
    return [Image.open(os.path.join(out, "%03d.png" % k)).convert("RGB") for k in range(25)], ""


def sheet(cli, model, name, path, index, info, outdir):
    img = Image.open(path).convert("RGB")
    lm = info["landmarks"]
    with tempfile.TemporaryDirectory() as work:
        modes = [("plain", False), ("transfer", True)]
        got = {m: redirect(cli, model, path, index, t, work) for m, t in modes}
        th = TILE + EYE_H + 14
        W = (1 + 5) * TILE + 5 * 4 + 16
        H = 24 + len(modes) * (5 * th + 24)
        s = Image.new("RGB", (W, H), (255, 255, 255))
        d = ImageDraw.Draw(s)
        d.text((4, 4), "%s face %d: pitch %+.0f yaw %+.0f deg (head, photo camera)" %
               (name, index, info.get("head_pitch_deg", 0), info.get("head_yaw_deg", 0)),
               fill=(0, 0, 0))
        y = 24
        for m, _ in modes:
            imgs, why = got[m]
            d.text((4, y), m, fill=(0, 0, 0))
            s.paste(tile(img, lm, "input"), (0, y + 12))
            if imgs is None:
                d.text((TILE + 16, y + 40), "refused: " + why[:110], fill=(160, 0, 0))
            else:
                for k, out in enumerate(imgs):
                    r, c = divmod(k, 5)
                    s.paste(tile(out, lm, "%+d,%+d" % (PITCH[r], YAW[c])),
                            (TILE + 16 + c * (TILE + 4), y + 12 + r * th))
            y += 5 * th + 24
        fn = "%s-%d.jpg" % (name, index)
        s.save(os.path.join(outdir, fn), quality=72, optimize=True)
        why = got["plain"][1]
        return fn, why


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--cli", default=os.path.join(ROOT, "build", "clients", "cli", "gazesplat"))
    ap.add_argument("--model", default=os.path.join(ROOT, "models", "gazegaussian-cpu.safetensors"))
    ap.add_argument("--out", default=os.path.join(ROOT, "docs", "photos"))
    ap.add_argument("--only", default="")
    a = ap.parse_args()
    os.makedirs(a.out, exist_ok=True)
    rows = []
    for name, path in photos():
        if a.only and a.only != name:
            continue
        for index, info in faces_of(a.cli, path):
            fn, why = sheet(a.cli, a.model, name, path, index, info, a.out)
            rows.append("| [%s face %d](%s) | %s |" % (name, index, fn, why or "redirected"))
            print(rows[-1], flush=True)
    with open(os.path.join(a.out, "index.md"), "w") as f:
        f.write("# Redirected real faces\n\nRegenerated by `scripts/photo-sheets.py` with the "
                "default model: every face found in the test photos, a 5 x 5 gaze grid "
                "(pitch +20..-20 by yaw +25..-25, head frame), pasted back, without and with "
                "detail transfer; each tile shows the face and its eyes enlarged. Faces the gate "
                "refuses say why (docs/face.md, \"The gate\").\n\n"
                "Photos: `samples/astronaut.jpg` (NASA, public domain, as shipped by Debian's "
                "python3-skimage) and the demo photos `sample1.jpg`..`sample6.jpg` of the npm "
                "package @vladmandic/face-api 1.7.15 (the author's own photos, MIT licence: "
                "[LICENSE.face-api](LICENSE.face-api)).\n\n"
                "| face | result |\n|---|---|\n" + "\n".join(rows) + "\n")
    return 0


if __name__ == "__main__":
    sys.exit(main())
