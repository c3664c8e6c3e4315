#!/usr/bin/env bash
# Remakes the committed evaluation report (experiments/eval/README.md): the shipped
# default model, the warp baseline and identity over the first 30 inputs of
# the committed pairing (two per test identity: every class) x 10 targets.
# Usage: [ESTIMATOR=FILE] experiments/eval/run.sh [BUILD_DIR] [OUT_DIR]
set -euo pipefail
root=$(cd "$(dirname "$0")/../.." && pwd)
build=${1:-$root/build}
out=${2:-$root/out/eval-default}
G=$build/clients/cli/gazesplat
# The committed report was scored with gaze-resnet; ESTIMATOR=FILE scores
# with another (gaze-resnet-white for these white-background images:
# docs/eval.md, "Reading the numbers").
est=()
if [ -n "${ESTIMATOR:-}" ]; then
  [ -f "$ESTIMATOR" ] || { echo "run.sh: ESTIMATOR=$ESTIMATOR: no such file" >&2; exit 2; }
  est=(--estimator "$ESTIMATOR")
elif [ -f "$root/models/gaze-resnet.safetensors" ]; then
  est=(--estimator "$root/models/gaze-resnet.safetensors")
fi
# The pairing is deterministic: regenerating it must give the committed file.
"$G" eval --make-pairs "$out.pairs.csv"
cmp "$out.pairs.csv" "$root/bench/eval/pairs.csv"
# --reuse-fits: a rerun (say with a new estimator) reuses the fits in $out/fits.
nice -n 10 "$G" eval --model "$root/models/gazegaussian-cpu.safetensors" \
  "${est[@]}" --pairs "$root/bench/eval/pairs.csv" \
  --method model,warp,identity --limit-inputs 30 --threads 2 --reuse-fits \
  --out "$out"
