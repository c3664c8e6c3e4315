#!/usr/bin/env bash
# Sets everything up on a fresh Debian 12 machine, builds the release tree and
# runs the main job: renders the demo Gaussian scene to out/demo.png.
set -euo pipefail
cd "$(dirname "$0")/.."
scripts/install-deps.sh
scripts/build.sh build -DCMAKE_BUILD_TYPE=Release
mkdir -p out
./build/clients/cli/gazesplat scene --out out/demo.ply
./build/clients/cli/gazesplat render --ply out/demo.ply \
  --intrinsics 300,300,128,128 --size 256x256 \
  --view 1,0,0,0,0,1,0,0,0,0,1,4 --out out/demo.png
echo "wrote out/demo.png"
