#!/usr/bin/env bash
# Issue 35 on the lent GPU (../shared/GPU.md set-up done by the caller), one call:
#   1. the 10^5-sphere point sequence's frames/s one frame after another, as the
#      load/write pipeline with the set-up in the launching thread, and with render.prepare
#      setting up frame n+1 on the second queue (bench/sequence.py --unpiped);
#   2. the whole command's wall time of 1080p renders at defaults, a volume and the bunny,
#      in this checkout and a baseline one, interleaved (bench/latency.py --only
#      start,command[,png]): interpreter, imports, device choice and context, load, set-up,
#      program builds, kernel, write; for the volume also tone mapping and Pillow's PNG
#      encoding of a 1080p frame at every zlib level;
#   3. the volume's command again with compiled bytecode beside both checkouts' sources and
#      pyopencl's (bench/latency.py records which modules have it);
#   4. the viewer's frames/s moving and time to a converged still, a volume and the bunny
#      (bench/viewer.py). STEPS=sequence,volume,... picks steps; TAG is added to the
#      results' names.
# Each step's results are copied to $OUT as it ends. The wheels must include fileseq
# (sequence patterns; ../shared/GPU.md's `pip download` line plus fileseq): without it the
# sequence step fails at its first frame. Ran on the H200 in 147 s (the sequence step then
# failed so; it ran alone afterwards in 26 s with 10 frames).
# Session 43: STEPS=sequence,volume,bytecode TAG=s43 (the writer process; the bytecode), then
# STEPS=sequence,bytecode BYTECODE_PARTS=start,command,png REPEAT=7 TAG=s43b (its final code).
#   VOLRENDER_COMMIT=... bash bench/latency_gpu.sh BASELINE_DIR DATA_DIR
# (DATA_DIR: demo_cloud.npz and wdas_cloud_sixteenth.npz from `volrender convert`,
# bun_zipper.ply). A dry run on PoCL (a few minutes here):
#   PY=.venv/bin/python VOLRENDER_DEVICE=portable SIZE=48x32 POINTS=2000 FRAMES=3 SPP=4 \
#   ORBIT=2 FRAME=/tmp/f.npy VOLRENDER_BENCH_RESULTS=/tmp/r OUT=/tmp/o \
#   bash bench/latency_gpu.sh BASE DATA      (FRAME: any 1080p frame, else rendered at 1080p)
set -u
PY=${PY:-python3}
OUT=${OUT:-/tmp/out}
BASE=$(cd "${1:?baseline checkout}" && pwd)
DATA=$(cd "${2:?data folder}" && pwd)
mkdir -p "$OUT"
touch "$OUT/.start"                     # results newer than it are this call's
RESULTS=${VOLRENDER_BENCH_RESULTS:-bench/results}
export VOLRENDER_DEVICE=${VOLRENDER_DEVICE:-nvidia} PYTHONUNBUFFERED=1
SIZE=${SIZE:-1920x1080} POINTS=${POINTS:-100000} FRAMES=${FRAMES:-24}   # smaller: a dry run
SPP=${SPP:-64} ORBIT=${ORBIT:-20}
save() { find "$RESULTS" -newer "$OUT/.start" -type f -exec cp {} "$OUT/" \; ; }
step() { local limit=$1; shift; echo "== $(date +%T) $*"; timeout "$limit" "$@"; echo "== rc $?"; save; }
# STEPS: which of sequence, volume, bytecode, viewer, bunny run (default: all), in that order
STEPS=${STEPS:-sequence,volume,bytecode,viewer,bunny}
has() { [[ ",$STEPS," == *",$1,"* ]]; }
TAG=${TAG:+-$TAG}
# the sequence first (the split's measure), then the volume's command, the viewer, the bunny
has sequence && step "${T1:-75}" "$PY" bench/sequence.py --device "$VOLRENDER_DEVICE" --points "$POINTS" \
  --frames "$FRAMES" --size "$SIZE" --workers 0 --unpiped --format exr --tag "points-pipeline$TAG"
has volume && step "${T2:-60}" "$PY" bench/latency.py --only start,command,png --scene "$DATA/demo_cloud.npz" \
  --args "--size $SIZE" --baseline "$BASE" --repeat 3 --tag "volume-1080p$TAG" ${FRAME:+--frame "$FRAME"}
# the same command with compiled bytecode beside the sources (a pip install writes it; where
# PYTHONDONTWRITEBYTECODE is set and none is there, every command compiles volrender again)
if has bytecode; then
  SITE=$("$PY" -c "import pyopencl, pathlib; print(pathlib.Path(pyopencl.__file__).parents[1])")
  echo "== compileall volrender, the baseline's, and $SITE"
  "$PY" -m compileall -q -j 0 volrender "$BASE/volrender" "$SITE" > /dev/null
  step "${T3:-45}" "$PY" bench/latency.py --only "${BYTECODE_PARTS:-start,command}" \
    --scene "$DATA/demo_cloud.npz" --args "--size $SIZE" --baseline "$BASE" \
    --repeat "${REPEAT:-3}" --tag "volume-1080p$TAG-bytecode" ${FRAME:+--frame "$FRAME"}
fi
has viewer && step "${T4:-90}" "$PY" bench/viewer.py --device "$VOLRENDER_DEVICE" --size "$SIZE" --spp "$SPP" \
  --frames "$ORBIT" --volume "$DATA/wdas_cloud_sixteenth.npz" --points "$DATA/bun_zipper.ply"
has bunny && step "${T5:-75}" "$PY" bench/latency.py --only start,command --scene "$DATA/bun_zipper.ply" \
  --args "--size $SIZE" --baseline "$BASE" --repeat 2 --tag "bunny-1080p$TAG"
ls "$OUT"
