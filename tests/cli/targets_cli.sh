#!/usr/bin/env bash
# gazesplat's target checks on a tiny real model (issue 49): a target
# outside the model's table is refused before any work (exit 2, the message
# names the field and the inclusive range, even with a model file that does
# not exist: nothing was loaded or fitted); an empty, malformed or
# overflowing list likewise; targets at exactly the limits render (the
# renderer agrees with the table).
set -euo pipefail
G=$1
T=$(mktemp -d); trap 'rm -rf "$T"' EXIT
cd "$T"
"$G" train --preset tiny --identities 2 --steps 2 --checkpoint 100 --out m.safetensors >/dev/null 2>&1
"$G" synth --out ds --count 1 --seed-split test --identities 1 --size 128 --no-masks >/dev/null 2>&1
IMG=ds/images/00000000.png
fail() { echo "FAIL: $*"; exit 1; }

# refused WANT ARGS...: exit 2, stderr has WANT, nothing written.
refused() {
  local want=$1; shift
  local st=0
  "$G" "$@" >out.txt 2>err.txt || st=$?
  [ "$st" -eq 2 ] || { cat err.txt; fail "$* exited $st, want 2"; }
  grep -qF -- "$want" err.txt || { cat err.txt; fail "$*: no '$want'"; }
  ! grep -q "fit [0-9]* iterations" err.txt || fail "$*: fitted before refusing"
  [ ! -e o ] || fail "$*: wrote o/"
}

# No such model file: a check after the model load would fail on it first.
R=(redirect --model missing.safetensors --image $IMG --out o)
refused "--gaze-deg: item 0: gaze pitch 200 deg outside [-50, 50] deg (inclusive)" "${R[@]}" --gaze-deg 200,0
refused "--gaze-deg: item 5: gaze yaw 60.0000001 deg outside [-60, 60] deg (inclusive)" \
  "${R[@]}" --gaze-deg "0,0;1,1;2,2;3,3;4,4;0,60.0000001"
refused "--gaze-deg: empty" "${R[@]}" --gaze-deg ''
refused "--gaze-deg: empty item 1" "${R[@]}" --gaze-deg '0,0;'
refused "--gaze-deg: empty item 1" "${R[@]}" --gaze-deg '0,0;;1,1'
refused "--gaze-deg: bad item 0 '0,0x'" "${R[@]}" --gaze-deg '0,0x'
refused "--gaze-deg: bad item 0 'nan,0'" "${R[@]}" --gaze-deg 'nan,0'
refused "--gaze-deg: bad item 0 '1e400,0'" "${R[@]}" --gaze-deg '1e400,0'
refused "--head-deg: head pitch 1e+30 deg outside [-70, 70] deg (inclusive)" \
  "${R[@]}" --gaze-deg 0,0 --head-deg 1e30,1e30
refused "--head-deg: head yaw -70.000000001 deg outside [-70, 70]" \
  "${R[@]}" --gaze-deg 0,0 --head-deg 0,-70.000000001
refused "--gaze-deg: gaze pitch -50.5 deg outside [-50, 50]" \
  fit --model missing.safetensors --image $IMG --gaze-deg -50.5,0 --out s.bin
[ ! -e s.bin ] || fail "fit wrote s.bin"
# The daemon client refuses before connecting (no server at this address).
refused "--head-deg: item 1: head pitch 70.5 deg outside [-70, 70]" client redirect \
  --addr "$T/none.sock" --subject 00000000000000000000000000000000 --gaze-deg "0,0;0,0" \
  --head-deg "0,0;70.5,0" --out o
refused "--gaze: gaze yaw 61 deg outside [-60, 60]" client fit --addr "$T/none.sock" \
  --image $IMG --gaze 0,61

# Exactly at the limits: accepted and rendered (the renderer once refused
# a head of exactly 70 deg, after the fit).
"$G" redirect --model m.safetensors --image $IMG --iters 2 --gaze-deg "50,60;-50,-60" \
  --head-deg 70,-70 --out o >/dev/null 2>err.txt || { cat err.txt; fail "targets at the limits refused"; }
[ -s o/000.png ] && [ -s o/001.png ] || fail "targets at the limits: images missing"
"$G" fit --model m.safetensors --image $IMG --iters 2 --gaze-deg -50,-60 --out s.bin 2>err.txt ||
  { cat err.txt; fail "fit --gaze-deg at the limits refused"; }
"$G" redirect --model m.safetensors --subject s.bin --gaze-deg "-50,60" --head-deg -70,70 \
  --out o2 >/dev/null 2>err.txt || { cat err.txt; fail "subject at the limits refused"; }
[ -s o2/000.png ] || fail "subject at the limits: image missing"
echo "targets_cli: ok"
