#!/bin/bash
# Submits a sharded `gazesplat augment` run to Slurm: a job array of N
# shards, then the merge, which runs once every shard succeeded.
#   deploy/slurm/submit.sh N OUT [augment options: --model M --input I ...]
# OUT must be a folder every node sees. $GAZESPLAT names the program
# (default: gazesplat on PATH); sbatch's own settings come from its
# environment (SBATCH_PARTITION, SBATCH_ACCOUNT, ...). Prints the two job
# ids: the array's and the merge's.
set -euo pipefail
if [ $# -lt 2 ] || ! [[ $1 =~ ^[1-9][0-9]*$ ]]; then
  echo "usage: $0 SHARDS OUT [gazesplat augment options]" >&2
  exit 2
fi
n=$1 out=$2
shift 2
here=$(cd "$(dirname "$0")" && pwd)
mkdir -p "$out"
out=$(cd "$out" && pwd)
array=$(sbatch --parsable --array=0-$((n - 1)) --export=ALL,GS_OUT="$out" \
        "$here/augment.sbatch" "$@")
array=${array%%;*}
if [ "$n" -gt 1 ]; then
  merge=$(sbatch --parsable --dependency=afterok:"$array" --kill-on-invalid-dep=yes \
          --export=ALL,GS_OUT="$out",GS_SHARDS="$n" "$here/merge.sbatch")
  echo "$array ${merge%%;*}"
else
  echo "$array"
fi
