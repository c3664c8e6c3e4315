#!/usr/bin/env bash
# gazesplat train --resume without FILE.opt, --fresh-optimizer and --cosine
# through the CLI on a tiny model: the refused resume names the way out and
# writes nothing, bad combinations are usage errors (exit 2), a fresh
# resume continues from its step with the learning rate ramping up, --lids
# adds lids by a fresh resume only, --eye-cover-loss refuses bad weights and
# models without an eye stream, --supersample is kept by the file and
# switched by a resume, --eye-weight refuses bad weights, reaches the loss
# and is 5 by default, --head-range refuses bad ranges, reaches the samples
# and is 40,25 by default, --sync-samples gives the bytes of the default
# (samples made ahead), --sample-threads 3 too and refuses bad counts,
# --clip-grad-norm refuses bad bounds and gives the
# default's bytes when it is never reached, and a cosine run's rate falls
# to lr / 20 at its last step.
set -euo pipefail
G=$1
T=$(mktemp -d); trap 'rm -rf "$T"' EXIT
cd "$T"
fail() { echo "FAIL: $*"; exit 1; }
# refused OPTION VALUE...: a new run with each value is a usage error (exit
# 2) whose message names the option, and it writes no model
refused() {
  local opt=$1 bad rc
  shift
  for bad in "$@"; do
    set +e
    "$G" train --preset tiny --identities 2 --steps 1 "$opt" "$bad" \
      --out refused.safetensors >/dev/null 2>err.txt
    rc=$?
    set -e
    [ $rc -eq 2 ] || fail "$opt '$bad': exit $rc, want 2"
    grep -q -- "$opt" err.txt || { cat err.txt; fail "$opt '$bad': no message"; }
    [ ! -e refused.safetensors ] || fail "$opt '$bad' wrote a model"
  done
}
"$G" train --preset tiny --identities 2 --steps 2 --checkpoint 100 --out m.safetensors >/dev/null 2>&1
rm m.safetensors.opt
cp m.safetensors orig.safetensors

set +e
"$G" train --resume --steps 5 --out m.safetensors >/dev/null 2>err.txt; rc=$?
set -e
[ $rc -eq 1 ] || fail "resume without .opt: exit $rc"
grep -q "optimizer state.*--fresh-optimizer STEP" err.txt || { cat err.txt; fail "no hint"; }
cmp m.safetensors orig.safetensors || fail "a refused resume changed the model"
[ ! -e m.safetensors.opt ] || fail "a refused resume wrote FILE.opt"

for bad in "--fresh-optimizer 2 --steps 5" "--resume --fresh-optimizer 5 --steps 5" \
           "--resume --fresh-optimizer -1 --steps 5" "--resume --fresh-optimizer x --steps 5"; do
  set +e
  # shellcheck disable=SC2086
  "$G" train $bad --out m.safetensors >/dev/null 2>err.txt; rc=$?
  set -e
  [ $rc -eq 2 ] || fail "'$bad': exit $rc, want 2"
  grep -q "fresh-optimizer" err.txt || { cat err.txt; fail "'$bad': message does not name the option"; }
done

"$G" train --resume --fresh-optimizer 2 --steps 8 --cosine --log-every 1 --checkpoint 100 \
  --out m.safetensors 2>log.txt >/dev/null
grep -q "step 3/8 " log.txt || { cat log.txt; fail "did not start at step 2"; }
! grep -q "step 2/8 " log.txt || fail "retrained step 2"
[ -s m.safetensors.opt ] || fail "no FILE.opt after the fresh resume"
! cmp -s m.safetensors orig.safetensors || fail "the weights did not change"
# the ramp (200 steps) starts at 1/200 of the curve's lr (1e-3 at its start)
grep -q "step 3/8 .* lr 5.00e-06 " log.txt || { cat log.txt; fail "the ramp's first step is not lr/200"; }

# lids (docs/model.md): added to a model without by a fresh resume only
# (the face stream is reordered, so FILE.opt would not fit), kept by the
# file, made by a new run with --lids, and a plain resume of that keeps them
cp orig.safetensors l.safetensors
set +e
"$G" train --resume --lids --steps 5 --out l.safetensors >/dev/null 2>err.txt; rc=$?
set -e
[ $rc -eq 2 ] || fail "--lids --resume without --fresh-optimizer: exit $rc, want 2"
grep -q "fresh-optimizer" err.txt || { cat err.txt; fail "--lids: no hint"; }
cmp l.safetensors orig.safetensors || fail "a refused --lids changed the model"
! grep -aq '"config.n_lid0":"[1-9]' l.safetensors || fail "lids before --lids"
"$G" train --resume --lids --fresh-optimizer 2 --steps 4 --checkpoint 100 \
  --out l.safetensors >/dev/null 2>&1 || fail "--lids --fresh-optimizer failed"
grep -aq '"config.n_lid0":"[1-9]' l.safetensors || fail "no lids after --lids"
grep -aq '"face.lid_k"' l.safetensors || fail "no face.lid_k after --lids"
"$G" train --preset tiny --identities 2 --steps 2 --lids --checkpoint 100 \
  --out n.safetensors >/dev/null 2>&1 || fail "a new run with --lids failed"
grep -aq '"config.n_lid1":"[1-9]' n.safetensors || fail "a new --lids model has no lids"
"$G" train --resume --lids --steps 3 --checkpoint 100 --out n.safetensors >/dev/null 2>&1 ||
  fail "a plain resume of a model with lids failed"
grep -aq '"face.lid_uv"' n.safetensors || fail "the resumed model lost its lids"

# the eye-cover loss: bad weights are usage errors, and the single-stream
# ablation (no eye stream) is refused with a message
refused --eye-cover-loss -1 x 2000
set +e
"$G" train --preset tiny --identities 2 --steps 1 --single-stream --eye-cover-loss 1 \
  --out e.safetensors >/dev/null 2>err.txt; rc=$?
set -e
[ $rc -eq 1 ] || fail "--eye-cover-loss on a single stream: exit $rc, want 1"
grep -q "needs the eye stream" err.txt || { cat err.txt; fail "single stream: no message"; }
"$G" train --preset tiny --identities 2 --steps 2 --lids --eye-cover-loss 1 --checkpoint 100 \
  --out e.safetensors >/dev/null 2>&1 || fail "--lids --eye-cover-loss 1 failed"

# --supersample: 1..4, kept by the file and switched by a resume; not with
# the eye-cover loss
refused --supersample 0 5 2x
set +e
"$G" train --preset tiny --identities 2 --steps 1 --supersample 2 --eye-cover-loss 1 \
  --out s.safetensors >/dev/null 2>err.txt; rc=$?
set -e
[ $rc -eq 2 ] || fail "--supersample 2 --eye-cover-loss 1: exit $rc, want 2"
"$G" train --preset tiny --identities 2 --steps 2 --supersample 2 --checkpoint 100 \
  --out s.safetensors >/dev/null 2>&1 || fail "a new run with --supersample 2 failed"
grep -aq '"config.supersample":"2"' s.safetensors || fail "the file lost --supersample 2"
"$G" train --resume --steps 3 --checkpoint 100 --out s.safetensors >/dev/null 2>&1 ||
  fail "a plain resume of a supersampled model failed"
grep -aq '"config.supersample":"2"' s.safetensors || fail "a resume lost supersample 2"
"$G" train --resume --supersample 1 --steps 4 --checkpoint 100 --out s.safetensors \
  >/dev/null 2>&1 || fail "a resume with --supersample 1 failed"
grep -aq '"config.supersample":"1"' s.safetensors || fail "a resume did not switch to 1"

# --eye-weight: 1..100; 5 is the default (the same bytes as without it),
# another weight trains another model
refused --eye-weight 0 0.5 101 nan x ""
for w in default 5 20; do
  arg=(); [ "$w" = default ] || arg=(--eye-weight "$w")
  "$G" train --preset tiny --identities 2 --steps 3 --checkpoint 100 "${arg[@]}" \
    --out "w$w.safetensors" >/dev/null 2>&1 || fail "--eye-weight $w: the run failed"
done
cmp -s wdefault.safetensors w5.safetensors || fail "--eye-weight 5 is not the default"
cmp -s w5.safetensors w20.safetensors && fail "--eye-weight 20 trained the same model"

# --head-range YAW,PITCH: within 1..60 and 1..40 degrees; 40,25 is the
# default (the same bytes as without it), a wider range trains another model
refused --head-range 0,25 61,25 40,0 40,41 40 40, ,25 40,25,1 nan,25 x
"$G" train --preset tiny --identities 2 --steps 3 --checkpoint 100 --head-range 40,25 \
  --out h40.safetensors >/dev/null 2>&1 || fail "--head-range 40,25: the run failed"
"$G" train --preset tiny --identities 2 --steps 3 --checkpoint 100 --head-range 50,30 \
  --out h50.safetensors >/dev/null 2>&1 || fail "--head-range 50,30: the run failed"
cmp -s wdefault.safetensors h40.safetensors || fail "--head-range 40,25 is not the default"
cmp -s h40.safetensors h50.safetensors && fail "--head-range 50,30 trained the same model"

# --eye-direct 0|1: other values and the single-stream ablation refused; a
# new model keeps the key, a resume switches it (same tensors, so the
# optimizer state still fits)
refused --eye-direct 2 -1 yes ""
set +e
"$G" train --preset tiny --identities 2 --steps 1 --eye-direct 1 --single-stream \
  --out ed.safetensors >/dev/null 2>err.txt
rc=$?
[ $rc -eq 2 ] || fail "--eye-direct 1 --single-stream: exit $rc, want 2"
[ ! -e ed.safetensors ] || fail "a refused --eye-direct wrote a model"
set -e
"$G" train --preset tiny --identities 2 --steps 2 --checkpoint 100 --eye-direct 1 \
  --out ed.safetensors >/dev/null 2>&1 || fail "--eye-direct 1: the run failed"
grep -aq '"config.eye_direct":"1"' ed.safetensors || fail "--eye-direct 1 not in the file"
"$G" train --resume --steps 3 --eye-direct 0 --out ed.safetensors >/dev/null 2>&1 \
  || fail "a resume with --eye-direct 0 failed"
grep -aq '"config.eye_direct":"0"' ed.safetensors || fail "a resume did not switch to 0"

# --identities on a resume: fewer is refused, more needs --fresh-optimizer
# and grows the codes (the file's codes.train has the new count), the same
# count is a plain resume
"$G" train --preset tiny --identities 2 --steps 2 --checkpoint 100 --out i.safetensors \
  >/dev/null 2>&1 || fail "the identities' base run failed"
set +e
"$G" train --resume --identities 1 --steps 3 --out i.safetensors >/dev/null 2>err.txt
rc=$?
[ $rc -eq 2 ] && grep -q "keeps every identity" err.txt || { cat err.txt; fail "--identities 1 on a resume: exit $rc"; }
"$G" train --resume --identities 4 --steps 3 --out i.safetensors >/dev/null 2>err.txt
rc=$?
[ $rc -eq 2 ] && grep -q "fresh-optimizer" err.txt || { cat err.txt; fail "--identities 4 without --fresh-optimizer: exit $rc"; }
set -e
"$G" train --resume --identities 2 --steps 3 --checkpoint 100 --out i.safetensors >/dev/null 2>&1 ||
  fail "a resume with the model's own count failed"
grep -aq '"codes.train":{"dtype":"F32","shape":\[2,' i.safetensors || fail "codes.train is not [2, ...]"
"$G" train --resume --fresh-optimizer 3 --identities 4 --steps 6 --checkpoint 100 \
  --out i.safetensors >/dev/null 2>&1 || fail "a fresh resume with --identities 4 failed"
grep -aq '"codes.train":{"dtype":"F32","shape":\[4,' i.safetensors || {
  head -c 3000 i.safetensors | tr -c '[:print:]' ' ' | grep -o '"codes.train[^}]*}'; fail "codes.train is not [4, ...]"; }
"$G" train --resume --steps 8 --checkpoint 100 --out i.safetensors >/dev/null 2>&1 ||
  fail "a plain resume of the grown model failed"

# samples made at their steps (--sync-samples) or ahead (the default): the
# same bytes; a gradient bound never reached changes nothing, a tight one
# does; bad bounds are usage errors
for v in ahead sync sthreads clip-huge clip-tight; do
  arg=()
  case $v in
    sync) arg=(--sync-samples) ;;
    sthreads) arg=(--sample-threads 3) ;;
    clip-huge) arg=(--clip-grad-norm 1e6) ;;
    clip-tight) arg=(--clip-grad-norm 1e-4) ;;
  esac
  "$G" train --preset tiny --identities 2 --steps 4 --checkpoint 100 "${arg[@]}" \
    --out "s-$v.safetensors" >/dev/null 2>&1 || fail "train ($v) failed"
done
cmp s-ahead.safetensors s-sync.safetensors || fail "--sync-samples trained another model"
cmp s-ahead.safetensors.opt s-sync.safetensors.opt || fail "--sync-samples: another FILE.opt"
cmp s-ahead.safetensors s-sthreads.safetensors || fail "--sample-threads 3 trained another model"
refused --sample-threads 0 65 x
cmp s-ahead.safetensors s-clip-huge.safetensors || fail "a bound never reached changed the run"
! cmp -s s-ahead.safetensors s-clip-tight.safetensors || fail "--clip-grad-norm 1e-4 changed nothing"
refused --clip-grad-norm -1 2e6 x nan

# a cosine run from scratch: lr at step 0, then falling towards lr / 20 at
# step 6, the end (step 5, the last run, has 0.05 + 0.475 (1 + cos(5 pi / 6)))
"$G" train --preset tiny --identities 2 --steps 6 --cosine --log-every 1 --checkpoint 100 \
  --out c.safetensors 2>log.txt >/dev/null
grep -q "step 1/6 .* lr 1.00e-03 " log.txt || { cat log.txt; fail "cosine does not start at lr"; }
grep -q "step 6/6 .* lr 1.14e-04 " log.txt || { cat log.txt; fail "cosine's last step"; }
echo "ok"
