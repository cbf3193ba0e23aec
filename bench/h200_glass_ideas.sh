#!/bin/bash
# Issue 32, session 43: the glass field's speed ideas one at a time on the lent H200, in
# one call (bench/gpu.sh), through the switches that keep the old code paths:
#   off      VOLRENDER_CL_OPTIONS=-DVR_ONE_PASS=0 -DVR_CELL_REUSE=0, VOLRENDER_ENTRY_SPHERES=0
#   onepass  + one walk of a cell's list for m and the sums (cl/sdf.h sdf_grid_sums)
#   reuse    + the march keeps its cell's list (VR_CELL_REUSE)
#   all      + the lists' spheres in list order (glass.entry_spheres): the default
#   nocap, cap64: the default under VOLRENDER_NV_MAX_REGISTERS=0 / 64 (now 40)
# then the registers and spills of the default's kernels (-cl-nv-verbose build logs).
# Writes bench/results/glass_speed_gpu-nvidiah200-$TAG-x-<variant>.json. Test here:
#   DEVICE=portable SIZE=32x18 REPEAT=1 CASES=3000 bash bench/h200_glass_ideas.sh
set -euo pipefail
cd "$(dirname "$0")/.."
DEVICE=${DEVICE:-nvidia}
SIZE=${SIZE:-1920x1080}
REPEAT=${REPEAT:-3}
TAG=${TAG:-s43}
CASES=${CASES:-3000,1000000,bunny}
CAP_CASES=${CAP_CASES:-3000,1000000}
PY=${PY:-python3}
dev=$([ "$DEVICE" = nvidia ] && echo gpu-nvidiah200 || echo "$DEVICE")
R=bench/results/glass_speed_$dev-$TAG-x
S="$PY bench/glass_speed.py --device $DEVICE --size $SIZE --repeat $REPEAT --models full,fast --bounces 2"
cmds=(
 "VOLRENDER_ENTRY_SPHERES=0 VOLRENDER_CL_OPTIONS='-DVR_ONE_PASS=0 -DVR_CELL_REUSE=0' $S --cases $CASES --label off --out $R-off.json"
 "VOLRENDER_ENTRY_SPHERES=0 VOLRENDER_CL_OPTIONS='-DVR_CELL_REUSE=0' $S --cases $CASES --label onepass --out $R-onepass.json"
 "VOLRENDER_ENTRY_SPHERES=0 $S --cases $CASES --label reuse --out $R-reuse.json"
 "$S --cases $CASES --label all --out $R-all.json"
 "VOLRENDER_NV_MAX_REGISTERS=0 $S --cases $CAP_CASES --label nocap --out $R-nocap.json"
 "VOLRENDER_NV_MAX_REGISTERS=64 $S --cases $CAP_CASES --label cap64 --out $R-cap64.json"
)
if [ "$DEVICE" = nvidia ]; then
    cmds+=("VOLRENDER_CL_OPTIONS=-cl-nv-verbose $PY -c \"import logging, runpy, sys; \
logging.basicConfig(level=logging.INFO); sys.argv = ['glass_speed', '--device', 'nvidia', \
'--size', '64x36', '--repeat', '1', '--cases', '3000', '--bounces', '2', '--out', '/tmp/regs.json']; \
runpy.run_path('bench/glass_speed.py', run_name='__main__')\" 2>&1 | grep -i -E 'registers|spill|stack|built|ptxas' | head -60")
    exec bash bench/gpu.sh "${cmds[@]}"
fi
export PYTHONPATH=$PWD
for cmd in "${cmds[@]}"; do
    echo "== $(date +%T) $cmd"
    (bash -c "$cmd")
done
