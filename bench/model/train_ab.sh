#!/bin/sh
# Training steps timed with two gazesplat binaries, side by side: rounds
# alternate A, B. Each round runs two legs as the shipped model's
# commands do (models/README.md): STEPS steps of the cpu preset from
# scratch (image losses, 2 threads), and STEPS steps of a gaze-loss leg
# resumed from the shipped model (1 thread). Prints seconds per step
# (whole commands, start-up included) and the ratios of the medians.
#
#   bench/model/train_ab.sh GAZESPLAT_A GAZESPLAT_B [ROUNDS] [STEPS]
set -eu
[ $# -ge 2 ] || { echo "usage: $0 GAZESPLAT_A GAZESPLAT_B [ROUNDS] [STEPS]" >&2; exit 2; }
A=$1 B=$2 ROUNDS=${3:-2} STEPS=${4:-200}
ROOT=$(cd "$(dirname "$0")/../.." && pwd)
M=$ROOT/models/gazegaussian-cpu-48.safetensors
WORK=$(mktemp -d)
trap 'rm -rf "$WORK"' EXIT
now() { date +%s.%N; }
scratch() { # binary: seconds per step
    rm -f "$WORK/s.safetensors" "$WORK/s.safetensors.opt"
    t0=$(now)
    "$1" train --preset cpu --identities 48 --steps "$STEPS" --checkpoint 100000 \
        --log-every 100000 --out "$WORK/s.safetensors" > /dev/null 2>&1
    awk -v a="$t0" -v b="$(now)" -v n="$STEPS" 'BEGIN {printf "%.4f", (b - a) / n}'
}
gazeleg() { # binary: seconds per step
    cp "$M" "$WORK/g.safetensors"
    rm -f "$WORK/g.safetensors.opt"
    t0=$(now)
    "$1" train --preset cpu --identities 48 --steps $((44700 + STEPS)) --checkpoint 100000 \
        --log-every 100000 --resume --fresh-optimizer 44700 --lr 2e-4 --cosine --threads 1 \
        --gaze-loss "$ROOT/models/gaze-vgg-white.safetensors" --gaze-weight 0.1 \
        --out "$WORK/g.safetensors" > /dev/null 2>&1
    awk -v a="$t0" -v b="$(now)" -v n="$STEPS" 'BEGIN {printf "%.4f", (b - a) / n}'
}
echo "round | A scratch s/step | B scratch s/step | A gaze-loss s/step | B gaze-loss s/step"
i=1
while [ "$i" -le "$ROUNDS" ]; do
    sa=$(scratch "$A"); sb=$(scratch "$B"); ga=$(gazeleg "$A"); gb=$(gazeleg "$B")
    echo "$i | $sa | $sb | $ga | $gb"
    echo "$sa" >> "$WORK/sa"; echo "$sb" >> "$WORK/sb"; echo "$ga" >> "$WORK/ga"; echo "$gb" >> "$WORK/gb"
    i=$((i + 1))
done
med() { sort -n "$1" | awk '{v[NR] = $1} END {print (NR % 2) ? v[(NR + 1) / 2] : (v[NR / 2] + v[NR / 2 + 1]) / 2}'; }
msa=$(med "$WORK/sa") msb=$(med "$WORK/sb") mga=$(med "$WORK/ga") mgb=$(med "$WORK/gb")
echo "median | $msa | $msb | $mga | $mgb"
awk -v sa="$msa" -v sb="$msb" -v ga="$mga" -v gb="$mgb" \
    'BEGIN {printf "B takes %.3f of A'"'"'s time from scratch, %.3f in the gaze-loss leg\n", sb / sa, gb / ga}'
