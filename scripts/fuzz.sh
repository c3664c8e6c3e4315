#!/usr/bin/env bash
# Builds every libFuzzer target with clang (-fsanitize=fuzzer,address,
# undefined) in BUILD_DIR and runs each for SECONDS over a scratch copy of
# its seed corpus (the committed corpus is never modified). Exits non-zero
# when any target crashes, leaks, times out or fails to build; crashing
# inputs are kept under BUILD_DIR/artifacts/.
# Usage: scripts/fuzz.sh BUILD_DIR SECONDS
# Targets come from BUILD_DIR/fuzz_targets.txt, written by
# tests/fuzz/CMakeLists.txt (one gs_add_fuzz line per target).
set -euo pipefail
if [ $# -ne 2 ]; then
  echo "usage: $0 BUILD_DIR SECONDS" >&2
  exit 2
fi
dir=$1
secs=$2
root=$(cd "$(dirname "$0")/.." && pwd)

cmake -S "$root" -B "$dir" -G Ninja -DGS_FUZZ=ON -DGS_BUILD_TESTS=ON \
  -DCMAKE_BUILD_TYPE=Debug -DCMAKE_C_COMPILER=clang -DCMAKE_CXX_COMPILER=clang++ >/dev/null
mapfile -t lines < "$dir/fuzz_targets.txt"
if [ ${#lines[@]} -eq 0 ]; then
  echo "fuzz.sh: no fuzz targets" >&2
  exit 1
fi
targets=()
for line in "${lines[@]}"; do
  read -r name _ _ <<< "$line"
  targets+=("$name")
done
cmake --build "$dir" -j"${GS_JOBS:-2}" --target "${targets[@]}"

mkdir -p "$dir/artifacts"
status=0
for line in "${lines[@]}"; do
  read -r name exe corpus <<< "$line"
  work=$(mktemp -d)
  cp -R "$corpus"/. "$work"/
  echo "fuzz.sh: $name for ${secs}s over $(find "$work" -type f | wc -l) seeds"
  if ! "$exe" -max_total_time="$secs" -timeout=10 -rss_limit_mb=2048 \
       -artifact_prefix="$dir/artifacts/$name-" -print_final_stats=1 "$work" \
       > "$dir/artifacts/$name.log" 2>&1; then
    echo "fuzz.sh: $name FAILED; log: $dir/artifacts/$name.log" >&2
    tail -n 40 "$dir/artifacts/$name.log" >&2
    status=1
  else
    grep -E '^stat::number_of_executed_units|^stat::new_units_added' "$dir/artifacts/$name.log" || true
  fi
  rm -rf "$work"
done
exit $status
