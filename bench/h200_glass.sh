#!/bin/bash
# Issue 32's glass figures on the lent H200 in one unattended call, through bench/gpu.sh
# (wheels from .whl/, NVIDIA's ICD, results tarred into $OUT/results.tgz, log in
# $OUT/log.txt): bench/glass_speed.py at 1080p, one sun, --bounces 2 and 6, models full
# and fast, 3000 / 10^5 / 10^6 spheres and the bunny at its look-good settings,
#   1. of a baseline checkout beside this one (BASE=dir, measured as BASE_COMMIT), if any;
#   2. of this checkout (GPU_COMMIT);
#   3. this checkout's over-relaxation sweep (RELAX) at --bounces 2.
# Writes bench/results/glass_speed_gpu-nvidiah200-$TAG-{base,new,relax}.json. Needs
# bench/data/bun_zipper.ply (a copy of ../shared/data/points/; bench/data is git-ignored).
# Test here on PoCL at a tiny size (the same commands without gpu.sh):
#   DEVICE=portable SIZE=64x36 REPEAT=1 CASES=3000,bunny BOUNCES=2 bash bench/h200_glass.sh
set -euo pipefail
cd "$(dirname "$0")/.."
DEVICE=${DEVICE:-nvidia}
SIZE=${SIZE:-1920x1080}
REPEAT=${REPEAT:-3}
TAG=${TAG:-s42}
CASES=${CASES:-3000,100000,1000000,bunny}
BOUNCES=${BOUNCES:-2,6}
RELAX=${RELAX:-1.3,1.9}
PY=${PY:-python3}
res=$PWD/bench/results
dev=$([ "$DEVICE" = nvidia ] && echo gpu-nvidiah200 || echo "$DEVICE")
speed="bench/glass_speed.py --device $DEVICE --size $SIZE --repeat $REPEAT --models full,fast"
cmds=()
if [ -n "${BASE:-}" ]; then
    cmds+=("cd $BASE && PYTHONPATH=/tmp/site:\$PWD:\${PYTHONPATH:-} VOLRENDER_COMMIT=${BASE_COMMIT:-} \
$PY $speed --bounces $BOUNCES --cases $CASES --label base --out $res/glass_speed_$dev-$TAG-base.json")
fi
cmds+=("$PY $speed --bounces $BOUNCES --cases $CASES --label new --out $res/glass_speed_$dev-$TAG-new.json")
cmds+=("$PY $speed --bounces 2 --cases ${RELAX_CASES:-3000,1000000,bunny} --relax $RELAX --label relax \
--out $res/glass_speed_$dev-$TAG-relax.json")
DEVICE=$DEVICE exec bash bench/run_cmds.sh "${cmds[@]}"
