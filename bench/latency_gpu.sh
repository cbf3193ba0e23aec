#!/usr/bin/env bash
# Issue 35 on the lent GPU (../shared/GPU.md set-up done by the caller), one call: the
# whole command's wall time of 1080p renders at defaults (a volume, the bunny) in this
# checkout and a baseline one, interleaved (bench/latency.py --only command); the
# 10^5-sphere point sequence's frames/s as a pipeline and one frame after another
# (bench/sequence.py --unpiped), and the baseline's; tone mapping at 1080p.
#   VOLRENDER_COMMIT=... BASE_COMMIT=... bash bench/latency_gpu.sh BASELINE_DIR DATA_DIR
# (DATA_DIR: demo_cloud.npz from `volrender convert`, bun_zipper.ply)
set -u
OUT=${OUT:-/tmp/out}
BASE=$(cd "${1:?baseline checkout}" && pwd)
DATA=$(cd "${2:?data folder}" && pwd)
mkdir -p "$OUT"
touch "$OUT/.start"                     # results newer than it are this call's
export VOLRENDER_DEVICE=${VOLRENDER_DEVICE:-nvidia} PYTHONUNBUFFERED=1
step() { local limit=$1; shift; echo "== $(date +%T) $*"; timeout "$limit" "$@"; echo "== rc $?"; }
step 35 python3 bench/latency.py --only command --scene "$DATA/demo_cloud.npz" \
  --args "--size 1920x1080" --baseline "$BASE" --repeat 3 --tag volume-1080p
step 50 python3 bench/latency.py --only command --scene "$DATA/bun_zipper.ply" \
  --args "--size 1920x1080" --baseline "$BASE" --repeat 2 --tag bunny-1080p
step 35 python3 bench/sequence.py --device nvidia --points 100000 --frames 12 \
  --size 1920x1080 --workers 0 --unpiped --format exr --tag points-pipeline
(cd "$BASE" && VOLRENDER_COMMIT=${BASE_COMMIT:-baseline} step 20 python3 bench/sequence.py --device nvidia --points 100000 --frames 12 \
  --size 1920x1080 --workers 0 --format exr --tag points-before)
step 20 python3 bench/latency.py --only tone --scene "$DATA/demo_cloud.npz" --baseline "$BASE" \
  --repeat 3 --tag tone
find bench/results "$BASE/bench/results" -newer "$OUT/.start" -type f -exec cp {} "$OUT/" \;
ls "$OUT"
