"""The README's first job at test scale (label slow): gazesplatd on a tiny
real model, the bundled sample photo sent through the Python grid client
(clients/python/gazesplat_grid.py) as a 2 x 3 gaze grid pasted back into
the photo, by detail transfer (the default) and plainly (--no-transfer).
Checks the PNG's size against the documented layout, that every cell holds
the photo (its corners untouched by the paste-back) with the rendered eyes
pasted in, that the cells are not all the same render, that the transfer
cells are nearer the photo than the plain ones (the photo's own face, its
eyes turned), and the client's error exit against a stopped daemon.
usage: test_grid_client.py GAZESPLATD GAZESPLAT_CLI WORKDIR"""
import os
import subprocess
import sys
import tempfile

import numpy as np
from PIL import Image

HERE = os.path.dirname(os.path.abspath(__file__))
ROOT = os.path.join(HERE, "..", "..")
sys.path.insert(0, HERE)
sys.path.insert(0, os.path.join(ROOT, "clients", "python"))
from daemon_util import Checks, Daemon  # noqa: E402
from model_fixture import tiny_model  # noqa: E402
import gazesplat_grid as grid  # noqa: E402

PHOTO = os.path.join(ROOT, "samples", "astronaut.jpg")
CELL = 128
PITCHES, YAWS = [20, -20], [30, 0, -30]


def run_grid(addr, out, *extra):
    cmd = [sys.executable, os.path.join(ROOT, "clients", "python", "gazesplat_grid.py"),
           "--addr", addr, "--image", PHOTO, "--out", out, "--max-iters", "2", "--cell", str(CELL),
           "--pitch", ",".join(map(str, PITCHES)), "--yaw", ",".join(map(str, YAWS))] + list(extra)
    return subprocess.run(cmd, capture_output=True, text=True, timeout=240)


def cells(img):
    a = np.asarray(img.convert("RGB"), dtype=np.float64)
    out = []
    for r in range(len(PITCHES)):
        for c in range(len(YAWS)):
            x, y = grid.cell_origin(r, c, CELL)
            out.append(a[y:y + CELL, x:x + CELL])
    return out


def check_grid(t, path, plain):
    """Checks one grid; returns the mean difference of its cells from the
    photo (None when the grid is unusable)."""
    img = Image.open(path)
    want = grid.grid_size(len(PITCHES), len(YAWS), CELL)
    t.check(img.size == want and img.mode in ("RGB", "RGBA"), "grid %s %s, want %s RGB" % (img.size, img.mode, want))
    if img.size != want:
        return None
    ref = np.asarray(Image.open(PHOTO).convert("RGB").resize((CELL, CELL), Image.LANCZOS), dtype=np.float64)
    cs = cells(img)
    corner = (slice(0, CELL // 5), slice(0, CELL // 5))
    for i, c in enumerate(cs):
        t.check(c.std() > 10, "cell %d is flat (std %.1f)" % (i, c.std()))
        d = np.abs(c[corner] - ref[corner]).mean()
        t.check(d < 4, "cell %d corner differs from the photo by %.2f on average" % (i, d))
        # The rendered eyes are pasted back: far from the photo somewhere
        # (a plain render; a transfer keeps the photo's own eyes, turned).
        t.check(np.abs(c - ref).max() > (40 if plain else 4), "cell %d: nothing pasted back (max "
                "difference %.1f)" % (i, np.abs(c - ref).max()))
    # Each target rendered on its own: some cell differs from the first (the
    # tiny 10-step model's eyes move little, hence the low bar).
    diff = max(np.abs(c - cs[0]).max() for c in cs[1:])
    t.check(diff >= 1, "all cells identical")
    # Label strips are background except for the text.
    a = np.asarray(img.convert("RGB"))
    t.check((a[:grid.LABEL_H, :] == 255).mean() > 0.8, "yaw label strip not mostly background")
    return float(np.mean([np.abs(c - ref).mean() for c in cs]))


def main():
    daemon, cli, work = (os.path.abspath(a) for a in sys.argv[1:4])
    os.makedirs(work, exist_ok=True)
    t = Checks()
    if not os.path.exists(PHOTO):
        print("sample photo missing: %s" % PHOTO)
        return 1
    model = tiny_model(cli, work, seed=1)
    state = tempfile.mkdtemp(prefix="gsd_grid_state_")
    d = Daemon(daemon, ["--model", model, "--state-dir", state, "--set", "request_timeout_ms=200000"]).start()
    out = os.path.join(tempfile.mkdtemp(prefix="gsd_grid_"), "grid.png")
    try:
        away = {}
        for plain, extra in ((False, ()), (True, ("--no-transfer",))):
            path = out.replace(".png", "-plain.png" if plain else ".png")
            r = run_grid("unix:" + d.sock, path, *extra)
            print(r.stdout, r.stderr)
            t.check(r.returncode == 0 and "wrote " + path in r.stdout, "grid client exit %d" % r.returncode)
            if os.path.exists(path):
                away[plain] = check_grid(t, path, plain)
            else:
                t.check(False, "no grid written")
        if None not in (away.get(False), away.get(True)):
            print("cells from the photo, mean: transfer %.2f, plain %.2f" % (away[False], away[True]))
            t.check(away[False] < away[True], "transfer cells nearer the photo than plain: %.2f vs %.2f"
                    % (away[False], away[True]))
    finally:
        rc = d.stop()
        if t.failures:
            print(d.log()[-5000:])
    t.check(rc == 0, "daemon exit %s" % rc)
    # No daemon: a one-line error and exit status 1, no traceback.
    r = run_grid("unix:" + d.sock, out + ".none")
    t.check(r.returncode == 1 and "gazesplat_grid:" in r.stderr and "Traceback" not in r.stderr,
            "without a daemon: exit %d, stderr %r" % (r.returncode, r.stderr[-300:]))
    return t.status()


if __name__ == "__main__":
    sys.exit(main())
