#!/bin/sh
# The fitting budget screened with the readout: eight settings of fit
# iterations and fine-tuning steps (15 steps at 0.004 with the mirror is the
# served rate), run at once with 2 threads each, so a 16-core machine runs
# the screen in the time of one eval. Each setting's pairs.csv (written
# input by input: a run stopped early keeps what it reached) goes to
# OUTDIR/itN-ftM.csv; read them with bench/eval/readout_stats.py.
#
#   experiments/eval/budget_sweep.sh GAZESPLAT OUTDIR [INPUTS] [SECONDS]
#
# INPUTS: validation inputs (default 5: 50 pairs); SECONDS: a limit for each
# run (default none).
set -eu
[ $# -ge 2 ] || { echo "usage: $0 GAZESPLAT OUTDIR [INPUTS] [SECONDS]" >&2; exit 2; }
G=$1 OUT=$2 N=${3:-5} T=${4:-0}
ROOT=$(cd "$(dirname "$0")/../.." && pwd)
mkdir -p "$OUT"
WORK=$(mktemp -d)
trap 'rm -rf "$WORK"' EXIT
run() { # name, then eval options
    name=$1
    shift
    (timeout "$T" "$G" eval --model "$ROOT/models/gazegaussian-cpu.safetensors" \
        --estimator "$ROOT/models/gaze-resnet-white.safetensors" \
        --pairs "$ROOT/bench/eval/pairs-val.csv" --limit-inputs "$N" --threads 2 --readout \
        --method transfer --finetune-lr 0.004 "$@" --out "$WORK/$name" > "$WORK/$name.log" 2>&1 ||
        echo "$name: stopped ($?)" >&2) &
}
run it25-ft15 --iters 25 --finetune 15
run it35-ft15 --iters 35 --finetune 15
run it45-ft15 --iters 45 --finetune 15
run it60-ft15 --iters 60 --finetune 15
run it25-ft25 --iters 25 --finetune 25
run it35-ft25 --iters 35 --finetune 25
run it45-ft20 --iters 45 --finetune 20
run it45-ft25 --iters 45 --finetune 25
wait
for d in "$WORK"/it*/; do
    n=$(basename "$d")
    cp "$d/pairs.csv" "$OUT/$n.csv"
    echo "$n: $(($(wc -l < "$d/pairs.csv") - 1)) pairs"
done
