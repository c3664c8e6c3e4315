#!/usr/bin/env bash
# The README's first command, on a fresh Debian 12 machine: installs the
# dependencies, builds the release tree, starts gazesplatd on the shipped
# default model and sends the bundled sample photo (samples/astronaut.jpg)
# through the Python client, which writes ONE image: a 3 x 3 grid of
# redirected gazes (rows pitch +20/0/-20 deg, columns yaw +25/0/-25 deg),
# each the photo's own face redirected by detail transfer and pasted back
# into the photo, at out/demo/gaze-grid.png.
# GS_DEMO_ITERS bounds the photo fit (default 100 iterations: a few
# minutes on a loaded 2-core machine).
set -euo pipefail
cd "$(dirname "$0")/.."
scripts/install-deps.sh
scripts/build.sh build -DCMAKE_BUILD_TYPE=Release
MODEL=models/gazegaussian-cpu.safetensors
OUT=out/demo
rm -rf "$OUT" && mkdir -p "$OUT/state"
./build/daemon/gazesplatd --socket "$OUT/gazesplatd.sock" --model "$MODEL" \
  --state-dir "$OUT/state" --set request_timeout_ms=900000 --set max_deadline_ms=900000 \
  2> "$OUT/gazesplatd.log" &
pid=$!
trap 'kill $pid 2>/dev/null || true' EXIT
for _ in $(seq 300); do
  [ -S "$OUT/gazesplatd.sock" ] && break
  sleep 0.1
done
echo "gazesplatd (pid $pid, log $OUT/gazesplatd.log): fitting the photo, then 9 renders"
PYTHONPATH=build/python /usr/bin/python3 -m gazesplat.grid \
  --addr "unix:$OUT/gazesplatd.sock" --image samples/astronaut.jpg --out "$OUT/gaze-grid.png" \
  --pitch 20,0,-20 --yaw 25,0,-25 --max-iters "${GS_DEMO_ITERS:-100}" --deadline-ms 900000
kill -TERM $pid && wait $pid || true
trap - EXIT
echo "gaze grid: $OUT/gaze-grid.png (rows: gaze pitch +20, 0, -20 deg; columns: yaw +25, 0, -25 deg)"
