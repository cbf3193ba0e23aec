#!/usr/bin/env bash
# Issue 35 on the lent GPU (../shared/GPU.md set-up done by the caller), one call: the
# whole command's wall time of 1080p renders at defaults (a volume, the bunny) in this
# checkout and a baseline one, interleaved (bench/latency.py --only command); the
# 10^5-sphere point sequence's frames/s as a pipeline and one frame after another
# (bench/sequence.py --unpiped), and the baseline's; tone mapping at 1080p.
#   VOLRENDER_COMMIT=... BASE_COMMIT=... bash bench/latency_gpu.sh BASELINE_DIR DATA_DIR
# (DATA_DIR: demo_cloud.npz from `volrender convert`, bun_zipper.ply). A dry run on PoCL:
#   PY=.venv/bin/python VOLRENDER_DEVICE=portable SIZE=48x32 POINTS=2000 FRAMES=3 \
#   VOLRENDER_BENCH_RESULTS=/tmp/r bash bench/latency_gpu.sh ...   (~90 s here)
set -u
PY=${PY:-python3}
OUT=${OUT:-/tmp/out}
BASE=$(cd "${1:?baseline checkout}" && pwd)
DATA=$(cd "${2:?data folder}" && pwd)
mkdir -p "$OUT"
touch "$OUT/.start"                     # results newer than it are this call's
export VOLRENDER_DEVICE=${VOLRENDER_DEVICE:-nvidia} PYTHONUNBUFFERED=1
SIZE=${SIZE:-1920x1080} POINTS=${POINTS:-100000} FRAMES=${FRAMES:-12}   # smaller: a dry run
step() { local limit=$1; shift; echo "== $(date +%T) $*"; timeout "$limit" "$@"; echo "== rc $?"; }
step 35 "$PY" bench/latency.py --only command --scene "$DATA/demo_cloud.npz" \
  --args "--size $SIZE" --baseline "$BASE" --repeat 3 --tag volume-1080p
step 45 "$PY" bench/latency.py --only command --scene "$DATA/bun_zipper.ply" \
  --args "--size $SIZE" --baseline "$BASE" --repeat 2 --tag bunny-1080p
step 35 "$PY" bench/sequence.py --device "$VOLRENDER_DEVICE" --points "$POINTS" --frames "$FRAMES" \
  --size "$SIZE" --workers 0 --unpiped --format exr --tag points-pipeline
(cd "$BASE" && VOLRENDER_COMMIT=${BASE_COMMIT:-baseline} step 20 "$PY" bench/sequence.py --device "$VOLRENDER_DEVICE" --points "$POINTS" --frames "$FRAMES" \
  --size "$SIZE" --workers 0 --format exr --tag points-before)
step 25 "$PY" bench/latency.py --only tone --scene "$DATA/demo_cloud.npz" --baseline "$BASE" \
  --repeat 3 --tag tone
find bench/results "$BASE/bench/results" -newer "$OUT/.start" -type f -exec cp {} "$OUT/" \;
ls "$OUT"
