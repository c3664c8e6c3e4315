#!/usr/bin/env bash
# gazesplat fit / redirect of several images of one person, end to end on
# a tiny model trained for a few steps and held-out synthetic faces of one
# identity: one image is the plain fit (the same bytes); several make one
# subject (image --ref's, the identity shared: --ref 0 and 1 write the same
# identity and another expression), with per-image labels ('-' unknown), a
# fine-tune over all of them, and a redirect from --ref; two photos of one
# person go the photo path; bad lists are usage errors (exit 2) and a face
# of another size is a clear error naming its file.
set -euo pipefail
G=$1
ASSETS=${2:-}  # the face-api photos directory (GS_FACE_ASSETS)
T=$(mktemp -d); trap 'rm -rf "$T"' EXIT
cd "$T"
fail() { echo "FAIL: $*"; exit 1; }
"$G" train --preset tiny --identities 2 --steps 3 --checkpoint 100 --out m.safetensors >/dev/null 2>&1
"$G" synth --out ds --count 3 --seed-split test --identities 1 --size 128 --threads 2 >/dev/null 2>&1
"$G" synth --out small --count 1 --seed-split test --identities 1 --size 64 --threads 1 >/dev/null 2>&1
A=ds/images/00000000.png B=ds/images/00000001.png C=ds/images/00000002.png

# One image: the plain fit, with or without --ref 0.
"$G" fit --model m.safetensors --image $A --gaze-deg 5,0 --iters 4 --out one.bin 2>/dev/null
"$G" fit --model m.safetensors --image $A --gaze-deg 5,0 --iters 4 --ref 0 --out one_r.bin 2>/dev/null
cmp one.bin one_r.bin || fail "--ref 0 of one image changed the subject"

# Three images: one subject, per-image labels, the report names each image.
"$G" fit --model m.safetensors --image $A,$B,$C --gaze-deg "5,0;-;3,2" --head-deg "-;-;2,4" \
  --iters 4 --out multi.bin 2>multi.err
grep -q "fit 3 images, .* the subject is image 0's" multi.err || { cat multi.err; fail "no multi-image report"; }
grep -q "image 2 (ds/images/00000002.png): PSNR" multi.err || { cat multi.err; fail "no per-image line"; }
grep -q "gaze 5.0,0.0 deg" multi.err || { cat multi.err; fail "image 0's gaze label not kept"; }
"$G" fit --model m.safetensors --image $A,$B,$C --gaze-deg "5,0;-;3,2" --head-deg "-;-;2,4" \
  --iters 4 --ref 1 --out multi1.bin 2>/dev/null
! cmp -s multi.bin one.bin || fail "three images fitted as the first alone"
! cmp -s multi.bin multi1.bin || fail "--ref 1 wrote image 0's subject"
cmp -i 12 -n 4 multi.bin multi1.bin || fail "--ref 0 and 1 differ in the identity"
"$G" fit --model m.safetensors --image $A,$B --iters 3 --finetune 2 --out tuned.bin 2>ft.err
grep -q "fine-tuned face,geometry .* for 2 steps .* (mean over the images)" ft.err || { cat ft.err; fail "no fine-tune over the images"; }

# Redirect: from --ref's expression and head pose; --ref 1 renders otherwise.
"$G" redirect --model m.safetensors --image $A,$B,$C --image-gaze-deg "5,0;-;3,2" --iters 4 \
  --gaze-deg "0,0;10,-15" --out o0 >/dev/null 2>&1
"$G" redirect --model m.safetensors --image $A,$B,$C --image-gaze-deg "5,0;-;3,2" --iters 4 \
  --gaze-deg "0,0;10,-15" --ref 1 --out o1 >/dev/null 2>&1
[ -s o0/001.png ] && [ -s o1/001.png ] || fail "multi-image redirect wrote nothing"
! cmp -s o0/000.png o1/000.png || fail "--ref 1 rendered image 0's view"
"$G" redirect --model m.safetensors --subject multi.bin --gaze-deg "0,0;10,-15" --out os >/dev/null 2>&1
[ -s os/001.png ] || fail "the multi-image subject file does not render"

# Bad lists: usage errors before any work; a face of another size names it.
usage() { set +e; "$G" "$@" >/dev/null 2>u.err; rc=$?; set -e; [ $rc -eq 2 ] || { cat u.err; fail "exit $rc for: $*"; }; }
L=$A; for i in $(seq 16); do L=$L,$A; done
usage fit --model m.safetensors --image "$L" --out x.bin
grep -q "more than 16 images" u.err || { cat u.err; fail "17 images: no limit in the message"; }
usage fit --model m.safetensors --image $A,$B,$C --gaze-deg "5,0;1,1" --out x.bin
grep -q "2 items for 3 images" u.err || { cat u.err; fail "label count"; }
usage fit --model m.safetensors --image $A,$B --ref 2 --out x.bin
usage fit --model m.safetensors --image $A,,$B --out x.bin
usage fit --model m.safetensors --image $A,$B --mask $A --out x.bin
usage redirect --model m.safetensors --subject one.bin --ref 1 --gaze-deg 0,0 --out x
set +e; "$G" fit --model m.safetensors --image $A,small/images/00000000.png --out x.bin >/dev/null 2>s.err; rc=$?; set -e
[ $rc -eq 1 ] && grep -q "small/images/00000000.png: normalized face is 64x64" s.err || { cat s.err; fail "another size: exit $rc"; }
[ ! -e x.bin ] || fail "a refused fit wrote its output"

# Two photos of one person (the same photo twice): the photo path.
if [ -n "$ASSETS" ] && [ -f "$ASSETS/sample1.jpg" ]; then
  P=$ASSETS/sample1.jpg
  "$G" redirect --model m.safetensors --image $P,$P --iters 2 --gaze-deg "0,0" --out op 2>p.err >/dev/null ||
    { cat p.err; fail "two photos"; }
  grep -q "2 photos fitted as one subject" p.err || { cat p.err; fail "no multi-photo report"; }
  [ -s op/000.png ] || fail "two photos wrote nothing"
  usage redirect --model m.safetensors --image $P,$A --gaze-deg 0,0 --out x
fi
echo "multi_cli: ok"
