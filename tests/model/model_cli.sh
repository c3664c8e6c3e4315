#!/usr/bin/env bash
# gazesplat model: describes a model file; --fit-code-prior W and/or
# --fit-code-rate R with --out OUT write a copy naming the fit's code
# prior and code rate (the same parameters, read back exactly), which
# gazesplat fit then uses by default (a weight of 0, or the library's
# own rate 0.12, gives the plain model's subject back, byte for byte); bad values are
# usage errors (exit 2) and a missing or damaged file a failure (exit 1),
# with nothing written either way.
set -euo pipefail
G=$1
T=$(mktemp -d); trap 'rm -rf "$T"' EXIT
cd "$T"
fail() { echo "FAIL: $*"; exit 1; }
"$G" train --preset tiny --identities 2 --steps 3 --checkpoint 100 --out m.safetensors >/dev/null 2>&1
"$G" synth --out ds --count 1 --seed-split test --identities 1 --size 128 --threads 2 >/dev/null 2>&1
IMG=ds/images/00000000.png

"$G" model --model m.safetensors > m.txt
for k in image_size feat_size supersample eye_direct lids gaussians_face gaussians_eye \
         code_dim train_identities focal_px distance_mm param_bytes param_id; do
  grep -q "^$k: " m.txt || { cat m.txt; fail "no $k"; }
done
grep -qx "fit_code_prior: 0" m.txt || { cat m.txt; fail "a new model names a prior"; }
grep -qx "fit_code_rate: 0" m.txt || { cat m.txt; fail "a new model names a code rate"; }
grep -qx "train_identities: 2" m.txt || fail "identities"

# The copy: only the prior differs; 0.0003 is kept as eval's --code-prior reads it.
"$G" model --model m.safetensors --fit-code-prior 0.0003 --out p.safetensors > p.txt
"$G" model --model p.safetensors > p2.txt
grep -qx "fit_code_prior: 0.00030000001424923539" p2.txt || { cat p2.txt; fail "prior not read back"; }
diff <(grep -v "^model:\|^fit_code_prior:" m.txt) <(grep -v "^model:\|^fit_code_prior:" p2.txt) ||
  fail "the copy differs in more than the prior"
diff <(grep -v "^model:" p.txt) <(grep -v "^model:" p2.txt) || fail "what was written is not what is read"

# In place, and back to none.
cp p.safetensors q.safetensors
"$G" model --model q.safetensors --fit-code-prior 1 --out q.safetensors >/dev/null
"$G" model --model q.safetensors | grep -qx "fit_code_prior: 1" || fail "in-place write"
"$G" model --model q.safetensors --fit-code-prior 0 --out z.safetensors >/dev/null

# The code rate: kept as eval's --fit-lr reads it (a double); alone, or with the prior.
"$G" model --model m.safetensors --fit-code-rate 0.24 --out r.safetensors > r.txt
grep -qx "fit_code_rate: 0.23999999999999999" r.txt || { cat r.txt; fail "rate not written"; }
diff <(grep -v "^model:\|^fit_code_rate:" m.txt) <(grep -v "^model:\|^fit_code_rate:" r.txt) ||
  fail "the copy differs in more than the rate"
"$G" model --model m.safetensors --fit-code-prior 1 --fit-code-rate 0.5 --out b.safetensors > b.txt
grep -qx "fit_code_prior: 1" b.txt && grep -qx "fit_code_rate: 0.5" b.txt || { cat b.txt; fail "both"; }
"$G" model --model m.safetensors --fit-code-rate 0.12 --out d.safetensors >/dev/null

# gazesplat fit follows the model's rate: 0.24 fits otherwise, the default's 0.12 as the plain model.
"$G" fit --model m.safetensors --image $IMG --iters 6 --out plain.bin 2>/dev/null
"$G" fit --model r.safetensors --image $IMG --iters 6 --out rate.bin 2>/dev/null
"$G" fit --model d.safetensors --image $IMG --iters 6 --out dflt.bin 2>/dev/null
! cmp -s plain.bin rate.bin || fail "the model's code rate changed nothing in the fit"
cmp plain.bin dflt.bin || fail "a model naming the default rate fits otherwise than the plain one"

# gazesplat fit follows the model's prior: weight 1 fits otherwise, 0 as the plain model.
"$G" fit --model m.safetensors --image $IMG --iters 6 --out plain.bin 2>/dev/null
"$G" fit --model q.safetensors --image $IMG --iters 6 --out prior.bin 2>/dev/null
"$G" fit --model z.safetensors --image $IMG --iters 6 --out zero.bin 2>/dev/null
! cmp -s plain.bin prior.bin || fail "the model's prior changed nothing in the fit"
cmp plain.bin zero.bin || fail "a model naming weight 0 fits otherwise than the plain one"

# Usage errors (2) and failures (1); nothing written.
expect() {
  local want=$1; shift
  set +e; "$G" model "$@" >out.txt 2>err.txt; local got=$?; set -e
  [ "$got" = "$want" ] || { cat err.txt; fail "model $*: exit $got, want $want"; }
  [ -s err.txt ] || fail "model $*: no message"
}
expect 2
expect 2 --model m.safetensors --fit-code-prior 0.1
expect 2 --model m.safetensors --out w.safetensors
for w in -0.1 10.5 nan inf strong ""; do
  expect 2 --model m.safetensors --fit-code-prior "$w" --out w.safetensors
  expect 2 --model m.safetensors --fit-code-rate "$w" --out w.safetensors
done
expect 2 --model m.safetensors --fit-code-rate 0.2
expect 2 --model m.safetensors --fit-code-rate 0.2x --out w.safetensors
expect 2 --model m.safetensors stray
expect 1 --model missing.safetensors
expect 1 --model missing.safetensors --fit-code-prior 0.1 --out w.safetensors
head -c 5000 m.safetensors > cut.safetensors
expect 1 --model cut.safetensors --fit-code-prior 0.1 --out w.safetensors
grep -q "cut.safetensors" err.txt || fail "the message does not name the file"
expect 1 --model m.safetensors --fit-code-prior 0.1 --out nodir/w.safetensors
[ ! -e w.safetensors ] && [ ! -e nodir ] || fail "a refused command wrote a file"
"$G" help model | grep -q "fit-code-prior" || fail "no help"
"$G" help model | grep -q "fit-code-rate" || fail "no help for the rate"
echo "model cli: ok"
