#!/bin/sh
# The served fit (25 iterations, then 15 fine-tuning steps at 0.004 with
# the mirror) timed with two gazesplat binaries, side by side: the rounds
# alternate A, B, A, B... on the same validation inputs, so that a busy
# moment of a shared machine hits both alike. Prints each round's mean fit
# time per face (fit and fine-tuning together, from the eval's summary),
# the medians and their ratio, and whether the two binaries gave the same
# figures pair for pair (a change that only makes the fit faster must).
#
#   bench/model/fit_ab.sh GAZESPLAT_A GAZESPLAT_B [ROUNDS] [INPUTS]
#
# ITERS_A, ITERS_B (environment, default 25 each): the fit's iterations
# for each binary, to time a larger budget against the old one; the figures
# then differ, and the last line says so. MODEL_A, MODEL_B (default the
# shipped model for both): the model each side fits, to time two models
# with one binary (the figures are then not compared either).
#
# GAZESPLAT_A is usually a build of the commit before a change (git
# worktree add ../before HEAD~1; cmake -S ../before -B ../before/build
# -DCMAKE_BUILD_TYPE=Release; cmake --build ../before/build -j2 --target
# gazesplat_cli), GAZESPLAT_B this tree's build/clients/cli/gazesplat.
set -eu
[ $# -ge 2 ] || { echo "usage: $0 GAZESPLAT_A GAZESPLAT_B [ROUNDS] [INPUTS]" >&2; exit 2; }
A=$1 B=$2 ROUNDS=${3:-3} INPUTS=${4:-2} ITERS_A=${ITERS_A:-25} ITERS_B=${ITERS_B:-25}
ROOT=$(cd "$(dirname "$0")/../.." && pwd)
MODEL_A=${MODEL_A:-$ROOT/models/gazegaussian-cpu.safetensors}
MODEL_B=${MODEL_B:-$ROOT/models/gazegaussian-cpu.safetensors}
WORK=$(mktemp -d)
trap 'rm -rf "$WORK"' EXIT
run() { # binary, out dir, iterations, model
    "$1" eval --model "$4" \
        --pairs "$ROOT/bench/eval/pairs-val.csv" --limit-inputs "$INPUTS" --iters "$3" \
        --finetune 15 --finetune-lr 0.004 --threads 2 --method model --out "$2" > /dev/null 2>&1
    sed -n 's/^- fit: .* mean \([0-9.]*\) s.*/\1/p' "$2/summary.md"
}
echo "fit iterations: A $ITERS_A, B $ITERS_B; models: A $(basename "$MODEL_A"), B $(basename "$MODEL_B")"
echo "round | A s/face | B s/face"
i=1
while [ "$i" -le "$ROUNDS" ]; do
    ta=$(run "$A" "$WORK/a$i" "$ITERS_A" "$MODEL_A")
    tb=$(run "$B" "$WORK/b$i" "$ITERS_B" "$MODEL_B")
    echo "$i | $ta | $tb"
    echo "$ta" >> "$WORK/ta"
    echo "$tb" >> "$WORK/tb"
    i=$((i + 1))
done
med() { sort -n "$1" | awk '{v[NR] = $1} END {print (NR % 2) ? v[(NR + 1) / 2] : (v[NR / 2] + v[NR / 2 + 1]) / 2}'; }
ma=$(med "$WORK/ta") mb=$(med "$WORK/tb")
echo "median | $ma | $mb"
awk -v a="$ma" -v b="$mb" 'BEGIN {printf "B takes %.3f of A'"'"'s time (%.2fx faster)\n", b / a, a / b}'
if [ "$ITERS_A" != "$ITERS_B" ] || [ "$MODEL_A" != "$MODEL_B" ]; then
    echo "figures: not compared (the iterations or the models differ)"
    exit 0
fi
# every column but the timings (fit_s, render_ms) must agree
cols() { awk -F, 'NR == 1 {for (i = 1; i <= NF; i++) if ($i != "fit_s" && $i != "render_ms") k[i] = 1}
                  {s = ""; for (i = 1; i <= NF; i++) if (i in k) s = s $i ","; print s}' "$1"; }
if cols "$WORK/a1/pairs.csv" > "$WORK/ca" && cols "$WORK/b1/pairs.csv" > "$WORK/cb" &&
    cmp -s "$WORK/ca" "$WORK/cb"; then
    echo "figures: identical (every column but the timings, $(($(wc -l < "$WORK/ca") - 1)) pairs)"
else
    echo "figures: DIFFER"
    diff "$WORK/ca" "$WORK/cb" | head -5
fi
