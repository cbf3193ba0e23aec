#!/bin/bash
# The support-cell measurements on the lent H200, in one unattended call (about 6-7 minutes):
# 1080p glass sweep 10^3..10^6 (lit/unlit, fragment/tiled, cells/tree, brute force up to
# the first count where one render takes over 0.5 s), the opaque sweep (fragment), and the
# two scans (the bunny at the issue's look-good settings and at the defaults, frag_115 at
# the defaults).
# Writes bench/results/spheres_gpu-nvidiah200-cells.json, -cells-opaque.json and
# -cells-scans.json (+ .png), and a log; with $OUT set (the device machine), copies of
# them under $OUT.
#
# Needs: .whl/ with pyopencl and its pure-Python dependencies (/work/shared/GPU.md), and
# bench/data/bun_zipper.ply, bench/data/frag_115.ply (copies of ../shared/data/points/;
# bench/data is git-ignored: carry it). scipy and numpy come with the machine.
# Test here on PoCL at a tiny size:
#   DEVICE=portable SIZE=64x36 REPEAT=1 COUNTS=1000,3000 TAG=pocl-h200test bash bench/h200_cells.sh
set -euo pipefail
cd "$(dirname "$0")/.."
DEVICE=${DEVICE:-nvidia}
SIZE=${SIZE:-1920x1080}
REPEAT=${REPEAT:-3}
TAG=${TAG:-gpu-nvidiah200-cells}
COUNTS=${COUNTS:-1000,3000,10000,100000,1000000}
LOG=${OUT:-/tmp}/h200_cells.log
if [ "$DEVICE" = nvidia ]; then
    python3 -m pip install -q --no-index --no-deps --no-compile --target /tmp/site .whl/*.whl
    export PYTHONPATH=/tmp/site:$PWD
    mkdir -p /tmp/icd
    echo /usr/local/nvidia/lib64/libnvidia-opencl.so.1 > /tmp/icd/nvidia.icd
    cp /etc/OpenCL/vendors/*.icd /tmp/icd/ 2>/dev/null || true
    export OCL_ICD_VENDORS=/tmp/icd
    PY=python3
else
    export PYTHONPATH=$PWD
    PY=${PY:-/work/main/.venv/bin/python}
fi
start=$(date +%s)
{
    $PY bench/spheres.py --device "$DEVICE" --size "$SIZE" --repeat "$REPEAT" \
        --counts "$COUNTS" --accel grid,tree,none --dispatch fragment,tiled \
        --tiled-accel grid,tree --brute-limit 0.5 --uber-count 3000 --tag "$TAG"
    echo "glass sweep done after $(( $(date +%s) - start )) s"
    $PY bench/spheres.py --device "$DEVICE" --size "$SIZE" --repeat "$REPEAT" --opaque \
        --counts "$COUNTS" --accel grid,tree,none --dispatch fragment \
        --brute-limit 0.3 --uber-count 0 --tag "$TAG"
    echo "opaque sweep done after $(( $(date +%s) - start )) s"
    $PY bench/spheres.py --device "$DEVICE" --size "$SIZE" --repeat "$REPEAT" --no-sweep \
        --scans bunny,bunny-default,frag --accel grid,tree --dispatch fragment,tiled \
        --tag "$TAG-scans"
    echo "scans done after $(( $(date +%s) - start )) s"
} 2>&1 | tee "$LOG"
if [ -n "${OUT:-}" ]; then           # the device machine returns only what is under $OUT
    cp bench/results/spheres_"$TAG"*.json bench/results/spheres_"$TAG"*.png "$OUT"/ 2>/dev/null || true
fi
