"""Redirects one photo (or normalized face) to a grid of gazes through
gazesplatd and writes the results as ONE labelled PNG: rows are gaze
pitches (top: looking up), columns gaze yaws (left: toward image-left),
each cell the image the server returned for that (pitch, yaw).

    gazesplat-grid --addr unix:/run/gazesplat/gazesplatd.sock \
        --image samples/astronaut.jpg --out grid.png

The photo is sent inline in a single REDIRECT: the server finds the face,
fits a subject (at most --max-iters iterations), renders every target by
detail transfer (the photo's own face, its eyes turned; --no-transfer
shows the model's plain render instead) and pastes each back into the
photo. Needs Pillow (Debian's python3-pil; the extra [grid]).
"""
from __future__ import annotations

import argparse
import io
import sys
from typing import Any, Dict, List, Optional, Sequence, Tuple

from PIL import Image, ImageDraw, ImageFont

from .client import Client
from .errors import Busy, GazesplatError

__all__ = ["grid_size", "cell_origin", "compose", "redirect_grid", "wait_ready", "parse_angles", "main", "cli",
           "LABEL_W", "LABEL_H", "GAP", "BACKGROUND", "INK"]

# Layout: a LABEL_W-wide column of pitch labels on the left, a LABEL_H-high
# row of yaw labels on top, then rows x cols cells of CELL x CELL pixels
# separated by GAP pixels of background.
LABEL_W, LABEL_H, GAP = 96, 28, 4
BACKGROUND = (255, 255, 255)
INK = (0, 0, 0)


def grid_size(rows: int, cols: int, cell: int) -> Tuple[int, int]:
    """(width, height) of the grid image."""
    return LABEL_W + cols * (cell + GAP), LABEL_H + rows * (cell + GAP)


def cell_origin(row: int, col: int, cell: int) -> Tuple[int, int]:
    """Top-left pixel of cell (row, col)."""
    return LABEL_W + col * (cell + GAP), LABEL_H + row * (cell + GAP)


def parse_angles(text: str) -> List[float]:
    vals = [float(v) for v in text.split(",") if v.strip()]
    if not vals:
        raise argparse.ArgumentTypeError("want comma-separated degrees, e.g. 20,0,-20")
    return vals


def compose(images: Sequence[Sequence[Image.Image]], pitches: Sequence[float], yaws: Sequence[float],
            cell: int) -> Image.Image:
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


def wait_ready(client: Client, seconds: float) -> Any:
    """Polls HEALTH while the model loads; raises unless READY in time."""
    return client.wait_ready(seconds, poll=0.2)


def redirect_grid(client: Client, photo: bytes, pitches: Sequence[float], yaws: Sequence[float],
                  is_photo: bool = True, paste_back: bool = True, max_iters: int = 0,
                  deadline_ms: int = 0, transfer: bool = True) -> List[List[Image.Image]]:
    """Sends one REDIRECT with len(pitches) x len(yaws) targets (row-major);
    returns the decoded images as rows."""
    targets = [(p, y) for p in pitches for y in yaws]
    got: Dict[int, Image.Image] = {}
    for res in client.redirect(targets, image=photo, photo=is_photo, paste_back=paste_back and is_photo,
                               max_iters=max_iters, deadline_ms=deadline_ms, fmt="png",
                               transfer=transfer):
        got[res.index] = Image.open(io.BytesIO(res.image.data))
    if sorted(got) != list(range(len(targets))):
        raise RuntimeError("server sent images %s for %d targets" % (sorted(got), len(targets)))
    return [[got[r * len(yaws) + c] for c in range(len(yaws))] for r in range(len(pitches))]


def main(argv: Optional[Sequence[str]] = None, prog: Optional[str] = None) -> int:
    """The command line; returns the exit status (errors raise)."""
    ap = argparse.ArgumentParser(prog=prog, description=(__doc__ or "").split("\n\n")[0],
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
    with Client(a.addr, token=a.token, timeout=timeout, client_name="gazesplat-grid") as c:
        wait_ready(c, a.wait_ready)
        images = redirect_grid(c, photo, a.pitch, a.yaw, is_photo=not a.normalized,
                               paste_back=not a.no_paste_back, max_iters=a.max_iters,
                               deadline_ms=a.deadline_ms, transfer=not a.no_transfer)
    grid = compose(images, a.pitch, a.yaw, a.cell)
    grid.save(a.out, "PNG")
    print("wrote %s: %d x %d gazes, %d x %d px" % (a.out, len(a.pitch), len(a.yaw), *grid.size))
    return 0


def cli(argv: Optional[Sequence[str]] = None, prog: str = "gazesplat-grid") -> int:
    """The console script gazesplat-grid: main() with a one-line error
    (exit status 1) instead of a traceback."""
    try:
        return main(argv, prog)
    except (GazesplatError, Busy, OSError, RuntimeError, ValueError) as e:
        print("%s: %s" % (prog, e), file=sys.stderr)
        return 1


if __name__ == "__main__":
    sys.exit(cli())
