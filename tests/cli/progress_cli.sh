#!/usr/bin/env bash
# Progress on stderr (issue 50): into a file or a pipe, whole lines only,
# never a carriage return or a terminal escape; on a terminal (script(1)
# gives one) the line is rewritten in place. synth and a fit with
# fine-tuning, on a tiny model.
set -euo pipefail
G=$1
T=$(mktemp -d); trap 'rm -rf "$T"' EXIT
cd "$T"
fail() { echo "FAIL: $*"; exit 1; }
"$G" train --preset tiny --identities 2 --steps 2 --checkpoint 100 --out m.safetensors >/dev/null 2>&1
"$G" synth --out ds --count 3 --seed-split test --identities 1 --size 128 --no-masks 2>synth.err >/dev/null
grep -q "gazesplat synth: 3/3 images" synth.err || { cat synth.err; fail "synth: no final progress line"; }
"$G" fit --model m.safetensors --image ds/images/00000000.png --iters 5 --finetune 2 --out s.bin 2>fit.err
grep -q "gazesplat fit: fit, iteration 1 of at most 5" fit.err || { cat fit.err; fail "fit: no progress"; }
grep -q "gazesplat fit: fine-tuning, iteration 1 of at most 2" fit.err || { cat fit.err; fail "fine-tune: no progress"; }
for f in synth.err fit.err; do
  if grep -q $'[\r\033]' "$f"; then cat -A "$f"; fail "$f: carriage return or escape outside a terminal"; fi
done
if command -v script >/dev/null 2>&1; then
  script -qc "'$G' fit --model m.safetensors --image ds/images/00000000.png --iters 5 --out s2.bin" \
    /dev/null >tty.out 2>&1 || true
  grep -q $'\r\033\\[Kgazesplat fit: fit, iteration' tty.out || { cat -A tty.out; fail "no in-place progress on a terminal"; }
fi
echo "progress_cli: ok"
