#!/bin/sh
# gazesplat augment's output rate: images per second at 224² and 256², by
# targets per subject, at the served setting (the defaults: the fit to its
# plateau, 15 fine-tuning steps, detail transfer). Run by hand; nothing
# asserts a speed.
#
#   bench/augment/augment_bench.sh [GAZESPLAT] [FACES] ["T1 T2 ..."]
#
# GAZESPLAT: the binary (build/clients/cli/gazesplat); FACES: synthetic
# normalized faces of the test split (2); targets per subject ("1 4 16
# 64": square grids, 1 = the frontal gaze). Environment: MODEL (the shipped
# model), THREADS (2), EXTRA (more augment options, e.g. "--finetune 0"),
# RUNS (1; with farm-bench installed and RUNS > 1, the median of RUNS
# runs of the whole process is printed beside it).
#
# Each row: images written, the loop's seconds (augment's own "in S s":
# fits, renders, encoding and the crash-safe writes, the model load and
# the final assembly excluded), images/s, seconds per subject, and the
# whole process's wall seconds (model load and HDF5 assembly included).
set -eu
ROOT=$(cd "$(dirname "$0")/../.." && pwd)
G=${1:-$ROOT/build/clients/cli/gazesplat}
FACES=${2:-2}
TARGETS=${3:-"1 4 16 64"}
MODEL=${MODEL:-$ROOT/models/gazegaussian-cpu.safetensors}
THREADS=${THREADS:-2}
EXTRA=${EXTRA:-}
RUNS=${RUNS:-1}
WORK=$(mktemp -d)
trap 'rm -rf "$WORK"' EXIT
"$G" synth --out "$WORK/faces" --count "$FACES" --size 256 --seed-split test \
    --identities "$FACES" --no-masks >/dev/null 2>&1
grid() { # targets -> --grid spec of a square grid (10° apart, centred)
  case $1 in
    1) echo "0:0:1,0:0:1" ;;
    4) echo "-5:5:10,-5:5:10" ;;
    9) echo "-10:10:10,-10:10:10" ;;
    16) echo "-15:15:10,-15:15:10" ;;
    25) echo "-20:20:10,-20:20:10" ;;
    36) echo "-25:25:10,-25:25:10" ;;
    49) echo "-30:30:10,-30:30:10" ;;
    64) echo "-35:35:10,-35:35:10" ;;
    *) echo "targets per subject: one of 1 4 9 16 25 36 49 64" >&2; exit 2 ;;
  esac
}
echo "# $(date -u +%Y-%m-%d) $(nproc) cores, load $(cut -d' ' -f1-3 /proc/loadavg); model $(basename "$MODEL"), $FACES faces, threads $THREADS${EXTRA:+, $EXTRA}"
echo "| size | targets/subject | images | loop s | images/s | s/subject | process s |"
echo "|---:|---:|---:|---:|---:|---:|---:|"
for size in 224 256; do
  for t in $TARGETS; do
    out="$WORK/out_${size}_$t"
    start=$(date +%s.%N)
    # shellcheck disable=SC2086
    line=$("$G" augment --model "$MODEL" --input "$WORK/faces/images" --out "$out" \
        --grid "$(grid "$t")" --size "$size" --threads "$THREADS" $EXTRA 2>/dev/null)
    end=$(date +%s.%N)
    n=$(echo "$line" | sed -n 's/.*: \([0-9]*\) images from.*/\1/p')
    s=$(echo "$line" | sed -n 's/.* in \([0-9.]*\) s$/\1/p')
    awk -v size="$size" -v t="$t" -v n="$n" -v s="$s" -v f="$FACES" -v w="$(echo "$end - $start" | bc)" \
      'BEGIN { printf "| %d² | %d | %d | %.1f | %.3f | %.1f | %.1f |\n", size, t, n, s, n / s, s / f, w }'
    if [ "$RUNS" -gt 1 ] && command -v farm-bench >/dev/null 2>&1; then
      # shellcheck disable=SC2086
      farm-bench -n "$RUNS" --warmup 0 --timeout 3600 -- sh -c "rm -rf '$out'; exec '$G' augment \
        --model '$MODEL' --input '$WORK/faces/images' --out '$out' --grid '$(grid "$t")' \
        --size $size --threads $THREADS $EXTRA" | grep -i "wall" || true
    fi
    rm -rf "$out"
  done
done
