#!/usr/bin/env bash
# End to end on a real photo: a tiny model trained for a few steps, then
# `gazesplat redirect --image astronaut.png` (detect, landmarks, pose,
# normalize, fit, render, paste back). Checks every output exists, the
# pasted images have the photo's size and the crops the model's, and that
# bad input fails cleanly. (test_face_photos checks what paste-back leaves
# untouched.)
set -euo pipefail
G=$1; PHOTO=$2; PY=$3
[ -f "$PHOTO" ] || exit 77
T=$(mktemp -d); trap 'rm -rf "$T"' EXIT
"$G" train --preset tiny --identities 2 --steps 3 --checkpoint 100 --out "$T/m.safetensors" >/dev/null 2>&1
"$G" redirect --model "$T/m.safetensors" --image "$PHOTO" --iters 3 \
  --gaze-deg "0,0;10,-15" --out "$T/out" --out-norm
for f in 000.png 001.png norm_000.png norm_001.png; do
  [ -s "$T/out/$f" ] || { echo "missing $f"; exit 1; }
done
"$PY" - "$PHOTO" "$T/out/001.png" "$T/out/norm_001.png" <<'PYEOF'
import sys, struct, zlib
def size(p):
    with open(p, 'rb') as f:
        h = f.read(24)
    return struct.unpack('>II', h[16:24])
a, b, n = (size(p) for p in sys.argv[1:4])
assert a == b, f"pasted image {b} != photo {a}"
assert n == (128, 128), f"normalized crop {n}"
print("sizes ok:", a, n)
PYEOF
# bad input: out-of-range gaze, missing photo, no face
if "$G" redirect --model "$T/m.safetensors" --image "$PHOTO" --gaze-deg "80,0" --out "$T/x" 2>/dev/null; then
  echo "out-of-range gaze accepted"; exit 1; fi
if "$G" redirect --model "$T/m.safetensors" --image "$T/none.png" --gaze-deg "0,0" --out "$T/x" 2>/dev/null; then
  echo "missing photo accepted"; exit 1; fi
CAM=$(dirname "$PHOTO")/camera.png
if [ -f "$CAM" ]; then
  if "$G" redirect --model "$T/m.safetensors" --image "$CAM" --gaze-deg "0,0" --out "$T/x" 2>"$T/err"; then
    echo "a photo without a face was accepted"; exit 1; fi
  grep -q "no face" "$T/err" || { cat "$T/err"; exit 1; }
fi
echo "redirect_photo: ok"
