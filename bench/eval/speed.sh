#!/usr/bin/env bash
# Speed against error for the model: fit iteration cap x threads, same pairs
# (the first --limit-inputs inputs of the committed pairing, 10 targets
# each). Writes OUT/iters<N>_t<T>/ per setting, then OUT/speed.md and
# OUT/speed.png (bench/eval/speed_table.py).
# Usage: bench/eval/speed.sh [BUILD_DIR] [OUT_DIR] [INPUTS]
set -euo pipefail
root=$(cd "$(dirname "$0")/../.." && pwd)
build=${1:-$root/build}
out=${2:-$root/out/eval-speed}
inputs=${3:-1}
G=$build/clients/cli/gazesplat
mkdir -p "$out"
for setting in 25:2 50:2 100:2 200:2 100:1; do
  iters=${setting%:*} threads=${setting#*:}
  nice -n 10 "$G" eval --model "$root/models/gazegaussian-cpu.safetensors" \
    --pairs "$root/bench/eval/pairs.csv" --method model \
    --limit-inputs "$inputs" --iters "$iters" --threads "$threads" \
    --out "$out/iters${iters}_t${threads}"
done
/usr/bin/python3 "$root/bench/eval/speed_table.py" "$out"
