#!/usr/bin/env bash
# gazesplatd end to end on synthetic faces: trains a tiny model (seconds),
# renders two normalized faces, starts the daemon, fits both, writes a grid
# of redirected gazes to out/daemon-demo/, prints STATS, stops the daemon.
# Usage: scripts/daemon-demo.sh [BUILD_DIR]   (default build; built if absent)
set -euo pipefail
cd "$(dirname "$0")/.."
build=${1:-build}
[ -x "$build/daemon/gazesplatd" ] || scripts/build.sh "$build"
out=out/daemon-demo
rm -rf "$out" && mkdir -p "$out/state"
cli=$build/clients/cli/gazesplat
"$cli" train --out "$out/tiny.safetensors" --preset tiny --steps 200 --log-every 100
"$cli" synth --out "$out/faces" --count 2 --size 128 --seed-split test --identities 2 --no-masks
sock=$out/gazesplatd.sock
"$build/daemon/gazesplatd" --socket "$sock" --model "$out/tiny.safetensors" \
  --state-dir "$out/state" 2> "$out/gazesplatd.log" &
pid=$!
trap 'kill $pid 2>/dev/null || true' EXIT
for _ in $(seq 100); do
  "$cli" client health --addr "$sock" > /dev/null 2>&1 && break
  sleep 0.1
done
"$cli" client health --addr "$sock"
for face in "$out"/faces/images/*.png; do
  name=$(basename "$face" .png)
  key=$("$cli" client fit --addr "$sock" --image "$face" --max-iters 50 | awk '/^subject/ {print $2}')
  echo "$name: subject $key"
  "$cli" client redirect --addr "$sock" --subject "$key" --out "$out/$name" \
    --gaze-deg "20,-30;20,0;20,30;0,-30;0,0;0,30;-20,-30;-20,0;-20,30"
done
"$cli" client stats --addr "$sock" | grep -E '^(fits|images_out|jobs_done|cache_entries) '
kill -TERM $pid
wait $pid
echo "daemon-demo: images in $out/"
