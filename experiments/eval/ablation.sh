#!/usr/bin/env bash
# The ablation table (experiments/eval/ablation.md), like the GazeGaussian paper's
# Table 3: the full model against single stream, no explicit eye rotation and
# no expression guidance, each trained from scratch with the same budget and
# seed, then evaluated the same way on held-out identities.
# Usage: experiments/eval/ablation.sh [BUILD_DIR] [WORK_DIR] [STEPS] [INPUTS] [ITERS]
#   STEPS   training steps per model (default 1000)
#   INPUTS  first inputs of bench/eval/pairs.csv to fit (default 15: one per
#           test identity), each scored against its 10 targets
#   ITERS   fit iteration cap (default 100)
# Training resumes where a killed run stopped; evaluation reuses fits.
set -euo pipefail
root=$(cd "$(dirname "$0")/../.." && pwd)
build=${1:-$root/build}
work=${2:-$root/out/ablation}
steps=${3:-1000}
inputs=${4:-15}
iters=${5:-100}
G=$build/clients/cli/gazesplat
mkdir -p "$work"
common=(--preset cpu --identities 48 --steps "$steps" --seed 1 --threads 1
        --checkpoint 100 --log-every 25)
train() { # name, switches...
  local n=$1; shift
  local f=$work/$n.safetensors resume=()
  [ -f "$f" ] && [ -f "$f.opt" ] && resume=(--resume)
  "$G" train "${common[@]}" "$@" "${resume[@]}" --out "$f" >> "$work/$n.train.log" 2>&1
}
# Two models at a time, one thread each.
(train full; train noeye --no-eye-rotation) &
(train single --single-stream; train noguide --guidance none) &
wait
est=()
[ -f "$root/models/gaze-resnet.safetensors" ] &&
  est=(--estimator "$root/models/gaze-resnet.safetensors")
evaluate() {
  "$G" eval --model "$work/$1.safetensors" "${est[@]}" --pairs "$root/bench/eval/pairs.csv" \
    --method model --limit-inputs "$inputs" --iters "$iters" --threads 1 --reuse-fits \
    --out "$work/$1" > "$work/$1.eval.log" 2>&1
}
(evaluate full; evaluate noeye) &
(evaluate single; evaluate noguide) &
wait
/usr/bin/python3 "$root/experiments/eval/ablation_table.py" "$work" "$steps" "$inputs" "$iters" \
  > "$root/experiments/eval/ablation.md"
