#!/usr/bin/env bash
# Speed against error for the model (method model), same pairs everywhere:
# the first INPUTS inputs of the committed pairing, 10 targets each.
#
# Two parts (docs/eval.md, "Speed against error"):
#  1. fit budget: fit iteration cap x threads ($FITS, iters:threads), with
#     the normal render settings; each run fits.
#  2. render settings: face Gaussians kept ($PRUNE, percent) x feature-map
#     scale ($SCALE) x incremental or full renders ($MODES) x threads
#     ($THREADS), all on the fits of the $BASE_ITERS-iteration run with the
#     same thread count (copied, --reuse-fits: the fit does not depend on
#     the render settings). Scales below 1 always render in full, so only
#     "full" runs there.
# Writes OUT/i<iters>_t<threads>_p<percent>_s<scale>_<inc|full>/ per run,
# then OUT/speed.md and OUT/speed.png (experiments/eval/speed_table.py).
#
# Usage: experiments/eval/speed.sh [BUILD_DIR] [OUT_DIR] [INPUTS]
# Environment (space-separated lists; the defaults are the full grid):
#   FITS="25:2 50:2 100:2 200:2 200:1"  BASE_ITERS=200
#   PRUNE="100 50 25 10"  SCALE="1 0.75 0.5"  MODES="inc full"
#   THREADS="2 1"  MODEL=models/gazegaussian-cpu.safetensors
#   ESTIMATOR=FILE (adds the gaze error; none by default)
# A small check of the script: FITS="200:2" PRUNE="100 25" SCALE="1 0.5"
#   MODES="inc full" THREADS=2 experiments/eval/speed.sh build out/speed-check 1
set -euo pipefail
root=$(cd "$(dirname "$0")/../.." && pwd)
build=${1:-$root/build}
out=${2:-$root/out/eval-speed}
inputs=${3:-1}
G=$build/clients/cli/gazesplat
model=${MODEL:-$root/models/gazegaussian-cpu.safetensors}
base=${BASE_ITERS:-200}
fits=${FITS:-25:2 50:2 100:2 200:2 200:1}
prunes=${PRUNE:-100 50 25 10}
scales=${SCALE:-1 0.75 0.5}
modes=${MODES:-inc full}
threads_list=${THREADS:-2 1}
est=()
[ -n "${ESTIMATOR:-}" ] && est=(--estimator "$ESTIMATOR")
mkdir -p "$out"

# run DIR ITERS THREADS PRUNE SCALE MODE [extra args]
run() {
  local dir=$1 iters=$2 threads=$3 prune=$4 scale=$5 mode=$6
  shift 6
  local full=()
  [ "$mode" = full ] && full=(--full-render)
  echo "== $dir" >&2
  nice -n 10 "$G" eval --model "$model" --pairs "$root/bench/eval/pairs.csv" \
    --method model --limit-inputs "$inputs" --iters "$iters" \
    --threads "$threads" --prune "$prune%" --feature-scale "$scale" \
    "${full[@]}" "${est[@]}" --out "$out/$dir" "$@"
}

name() { echo "i$1_t$2_p$3_s$4_$5"; }

# 1. fit budget (and the fits part 2 reuses)
for setting in $fits; do
  iters=${setting%:*} threads=${setting#*:}
  run "$(name "$iters" "$threads" 100 1 inc)" "$iters" "$threads" 100 1 inc
done

# 2. render settings on reused fits
for threads in $threads_list; do
  src=$out/$(name "$base" "$threads" 100 1 inc)
  if [ ! -d "$src/fits" ]; then # the fits for this thread count
    run "$(name "$base" "$threads" 100 1 inc)" "$base" "$threads" 100 1 inc
  fi
  for prune in $prunes; do
    for scale in $scales; do
      for mode in $modes; do
        if [ "$mode" = inc ] && [ "$scale" != 1 ]; then
          continue # renders in full anyway
        fi
        dir=$(name "$base" "$threads" "$prune" "$scale" "$mode")
        [ "$out/$dir" = "$src" ] && continue # the fitting run itself
        mkdir -p "$out/$dir/fits"
        cp "$src"/fits/*.bin "$out/$dir/fits/"
        echo "$(basename "$src")" > "$out/$dir/fits_from"
        run "$dir" "$base" "$threads" "$prune" "$scale" "$mode" --reuse-fits
      done
    done
  done
done
/usr/bin/python3 "$root/experiments/eval/speed_table.py" "$out"
