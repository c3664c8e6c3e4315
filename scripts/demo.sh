#!/usr/bin/env bash
# Sets everything up on a fresh Debian 12 machine, builds the release tree and
# runs the main job on the shipped default model: gazesplatd is started on
# it, a photo (skimage's astronaut) is sent over its socket and redirected
# to a 3x3 gaze grid pasted back into the photo (out/daemon/); a synthetic
# test face is fitted and redirected by the CLI (out/redirect/, input in
# out/input.png). Also renders the demo Gaussian scene to out/demo.png.
set -euo pipefail
cd "$(dirname "$0")/.."
scripts/install-deps.sh
scripts/build.sh build -DCMAKE_BUILD_TYPE=Release
G=./build/clients/cli/gazesplat
MODEL=models/gazegaussian-cpu.safetensors
mkdir -p out
$G synth --out out/input-set --count 1 --seed-split test --size 256
cp out/input-set/images/00000000.png out/input.png
$G fit --model "$MODEL" --image out/input.png --iters 100 --out out/subject.bin
$G redirect --model "$MODEL" --subject out/subject.bin --out out/redirect \
  --gaze-deg "20,25;20,0;20,-25;0,25;0,0;0,-25;-20,25;-20,0;-20,-25"
$G scene --out out/demo.ply
$G render --ply out/demo.ply --intrinsics 300,300,128,128 --size 256x256 \
  --view 1,0,0,0,0,1,0,0,0,0,1,4 --out out/demo.png
# The daemon on the shipped model, a photo through its socket.
PHOTO=/usr/lib/python3/dist-packages/skimage/data/astronaut.png
rm -rf out/daemon && mkdir -p out/daemon/state
./build/daemon/gazesplatd --socket out/daemon/gazesplatd.sock --model "$MODEL" \
  --state-dir out/daemon/state --set request_timeout_ms=600000 \
  2> out/daemon/gazesplatd.log &
pid=$!
trap 'kill $pid 2>/dev/null || true' EXIT
for _ in $(seq 300); do
  $G client health --addr out/daemon/gazesplatd.sock > /dev/null 2>&1 && break
  sleep 0.1
done
$G client redirect --addr out/daemon/gazesplatd.sock --image "$PHOTO" --photo \
  --paste-back --max-iters 100 --deadline-ms 600000 --out out/daemon \
  --gaze-deg "20,25;20,0;20,-25;0,25;0,0;0,-25;-20,25;-20,0;-20,-25"
kill -TERM $pid && wait $pid || true
echo "wrote out/daemon/*.png, out/input.png, out/subject.bin, out/redirect/*.png, out/demo.png"
