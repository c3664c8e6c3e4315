"""Redirects one photo (or normalized face) to a grid of gazes through
gazesplatd and writes the results as ONE labelled PNG: rows are gaze
pitches (top: looking up), columns gaze yaws (left: toward image-left),
each cell the image the server returned for that (pitch, yaw).

    python3 clients/python/gazesplat_grid.py --addr unix:/run/gazesplat/gazesplatd.sock \
        --image samples/astronaut.jpg --out grid.png

The photo is sent inline in a single REDIRECT: the server finds the face,
fits a subject (at most --max-iters iterations), renders every target by
detail transfer (the photo's own face, its eyes turned; --no-transfer
shows the model's plain render instead) and pastes each back into the
photo. Needs Debian's python3-pil (and
python3-protobuf for the client).
"""
import argparse
import io
import os
import sys
import time

from PIL import Image, ImageDraw, ImageFont

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
import gazesplat_client as gc  # noqa: E402

# Layout: a LABEL_W-wide column of pitch labels on the left, a LABEL_H-high
# row of yaw labels on top, then rows x cols cells of CELL x CELL pixels
# separated by GAP pixels of background.
LABEL_W, LABEL_H, GAP = 96, 28, 4
BACKGROUND = (255, 255, 255)
INK = (0, 0, 0)


def grid_size(rows, cols, cell):
    """(width, height) of the grid image."""
    return LABEL_W + cols * (cell + GAP), LABEL_H + rows * (cell + GAP)


def cell_origin(row, col, cell):
    """Top-left pixel of cell (row, col)."""
    return LABEL_W + col * (cell + GAP), LABEL_H + row * (cell + GAP)


def parse_angles(text):
    vals = [float(v) for v in text.split(",") if v.strip()]
    if not vals:
        raise argparse.ArgumentTypeError("want comma-separated degrees, e.g. 20,0,-20")
    return vals


def compose(images, pitches, yaws, cell):
    """images[r][c]: PIL images; returns the labelled grid."""
    grid = Image.new("RGB", grid_size(len(pitches), len(yaws), cell), BACKGROUND)
    draw = ImageDraw.Draw(grid)
    font = ImageFont.load_default()
    for c, yaw in enumerate(yaws):
        x, _ = cell_origin(0, c, cell)
        draw.text((x + 4, 8), "yaw %+g" % yaw, fill=INK, font=font)
    for r, pitch in enumerate(pitches):
        _, y = cell_origin(r, 0, cell)
        draw.text((6, y + cell // 2 - 6), "pitch %+g" % pitch, fill=INK, font=font)
        for c in range(len(yaws)):
            grid.paste(images[r][c].convert("RGB").resize((cell, cell), Image.LANCZOS),
                       cell_origin(r, c, cell))
    return grid


def wait_ready(client, seconds):
    """Polls HEALTH while the model loads; raises unless READY in time."""
    end = time.time() + seconds
    while True:
        h = client.health()
        if h.state == gc.pb.Health.READY:
            return h
        if h.state != gc.pb.Health.LOADING or time.time() > end:
            raise RuntimeError("server is %s: %s" % (gc.pb.Health.State.Name(h.state), h.detail))
        time.sleep(0.2)


def redirect_grid(client, photo, pitches, yaws, is_photo=True, paste_back=True, max_iters=0,
                  deadline_ms=0, transfer=True):
    """Sends one REDIRECT with len(pitches) x len(yaws) targets (row-major);
    returns the decoded images as rows."""
    targets = [(p, y) for p in pitches for y in yaws]
    got = {}
    for res in client.redirect(targets, image=photo, photo=is_photo, paste_back=paste_back and is_photo,
                               max_iters=max_iters, deadline_ms=deadline_ms, fmt="png",
                               transfer=transfer):
        got[res.index] = Image.open(io.BytesIO(res.image.data))
    if sorted(got) != list(range(len(targets))):
        raise RuntimeError("server sent images %s for %d targets" % (sorted(got), len(targets)))
    return [[got[r * len(yaws) + c] for c in range(len(yaws))] for r in range(len(pitches))]


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0],
                                 formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--addr", default=None,
                    help="unix:PATH, PATH or tcp:HOST:PORT (default $GAZESPLAT_ADDR, "
                         "else /run/gazesplat/gazesplatd.sock)")
    ap.add_argument("--token", default=None, help="shared secret for TCP (default $GAZESPLAT_TOKEN)")
    ap.add_argument("--image", required=True, help="PNG or JPEG photo (or normalized face with --normalized)")
    ap.add_argument("--out", required=True, help="the grid PNG to write")
    ap.add_argument("--pitch", type=parse_angles, default=[20.0, 0.0, -20.0],
                    help="gaze pitches in degrees, one row each (default 20,0,-20)")
    ap.add_argument("--yaw", type=parse_angles, default=[25.0, 0.0, -25.0],
                    help="gaze yaws in degrees, one column each (default 25,0,-25)")
    ap.add_argument("--normalized", action="store_true",
                    help="the image is already a normalized face of the model's size")
    ap.add_argument("--no-paste-back", action="store_true",
                    help="cells show the normalized face instead of the photo")
    ap.add_argument("--no-transfer", action="store_true",
                    help="cells show the model's plain render instead of the photo's own face "
                         "redirected by detail transfer")
    ap.add_argument("--max-iters", type=int, default=100, help="fit iterations (default 100)")
    ap.add_argument("--deadline-ms", type=int, default=0, help="request deadline (0: the server's)")
    ap.add_argument("--cell", type=int, default=256, help="cell edge in pixels (default 256)")
    ap.add_argument("--wait-ready", type=float, default=120.0,
                    help="seconds to wait for the model to load (default 120)")
    a = ap.parse_args(argv)
    if not 16 <= a.cell <= 2048:
        ap.error("--cell wants 16..2048")
    with open(a.image, "rb") as f:
        photo = f.read()
    # The socket waits as long as the request may run.
    timeout = max(120.0, a.deadline_ms / 1000.0 + 30.0)
    with gc.Client(a.addr, token=a.token, timeout=timeout, client_name="gazesplat_grid") as c:
        wait_ready(c, a.wait_ready)
        images = redirect_grid(c, photo, a.pitch, a.yaw, is_photo=not a.normalized,
                               paste_back=not a.no_paste_back, max_iters=a.max_iters,
                               deadline_ms=a.deadline_ms, transfer=not a.no_transfer)
    grid = compose(images, a.pitch, a.yaw, a.cell)
    grid.save(a.out, "PNG")
    print("wrote %s: %d x %d gazes, %d x %d px" % (a.out, len(a.pitch), len(a.yaw), *grid.size))
    return 0


if __name__ == "__main__":
    try:
        sys.exit(main())
    except (gc.GazesplatError, gc.Busy, OSError, RuntimeError) as e:
        print("gazesplat_grid: %s" % e, file=sys.stderr)
        sys.exit(1)
