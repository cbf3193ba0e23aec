#!/bin/bash
# Issue 32, session 43: the glass field's speed ideas one at a time on the lent H200, in
# one call (bench/gpu.sh), through the switches that keep the old code paths, at 1080p,
# --bounces 2, full and fast: for each VR_LIST_PREFETCH level in LEVELS (cl/sdf.h; the
# cells' list walk with its loads issued ahead; 0 = the plain walk) the kernel times and
# counters (and level 2 under the register caps CAPS, default 48; the glass kernel's is
# 40), then the glass kernel's registers, stack frame and spills per level and model
# (-cl-nv-verbose build logs, ptxas; levels PTX_LEVELS, default 0 1 2). Earlier ideas
# measured with this script (one walk for m and the sums, the march keeping its cell's
# list, the lists' spheres in list order) were slower and are gone (bench/results/glass_speed_gpu-nvidiah200-s43-x-*.json).
# Writes bench/results/glass_speed_gpu-nvidiah200-$TAG-p<level>.json. Test here:
#   DEVICE=portable SIZE=32x18 REPEAT=1 CASES=3000 bash bench/h200_glass_ideas.sh
set -euo pipefail
cd "$(dirname "$0")/.."
DEVICE=${DEVICE:-nvidia}
SIZE=${SIZE:-1920x1080}
REPEAT=${REPEAT:-3}
TAG=${TAG:-s43}
CASES=${CASES:-3000,1000000,bunny}
LEVELS=${LEVELS:-0,1,2}
PY=${PY:-python3}
dev=$([ "$DEVICE" = nvidia ] && echo gpu-nvidiah200 || echo "$DEVICE")
R=bench/results/glass_speed_$dev-$TAG
S="$PY bench/glass_speed.py --device $DEVICE --size $SIZE --repeat $REPEAT --models full,fast --bounces 2"
cmds=()
for lv in ${LEVELS//,/ }; do
    cmds+=("VOLRENDER_CL_OPTIONS=-DVR_LIST_PREFETCH=$lv $S --cases $CASES --label p$lv --out $R-p$lv.json")
done
for cap in ${CAPS:-48}; do
    cmds+=("VOLRENDER_NV_MAX_REGISTERS=$cap VOLRENDER_CL_OPTIONS=-DVR_LIST_PREFETCH=2 $S --cases ${CAP_CASES:-3000,1000000} \
--label p2-cap$cap --out $R-p2-cap$cap.json")
done
if [ "$DEVICE" = nvidia ]; then
    for lv in ${PTX_LEVELS:-0 1 2}; do
        cmds+=("echo ptxas level $lv; VOLRENDER_CL_OPTIONS='-cl-nv-verbose -DVR_LIST_PREFETCH=$lv' $PY -c \"import logging, runpy, sys; \
logging.basicConfig(level=logging.INFO); sys.argv = ['glass_speed', '--device', 'nvidia', \
'--size', '64x36', '--repeat', '1', '--cases', '3000', '--bounces', '2', '--out', '/tmp/regs.json']; \
runpy.run_path('bench/glass_speed.py', run_name='__main__')\" 2>&1 | grep -E 'render_glass|VR_FULL|registers|spill' \
| grep -A3 \"Function properties for render_glass\" | grep -E 'registers|spill' | head -8")
    done
fi
DEVICE=$DEVICE exec bash bench/run_cmds.sh "${cmds[@]}"
