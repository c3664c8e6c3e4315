#!/usr/bin/env bash
# Sets everything up on a fresh Debian 12 machine, builds the release tree and
# runs the main job on the shipped default model: a synthetic test face is
# fitted and redirected to a 3x3 gaze grid (out/redirect/), next to the
# ground truth of the input (out/input.png). Also renders the demo Gaussian
# scene to out/demo.png.
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
echo "wrote out/input.png, out/subject.bin, out/redirect/*.png, out/demo.png"
