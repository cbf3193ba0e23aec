#!/bin/bash
# The support-cell measurements on the lent H200 in one unattended call (about 6-7 minutes),
# through bench/gpu.sh (wheels from .whl/, NVIDIA's ICD, results tarred into
# $OUT/results.tgz, log in $OUT/log.txt):
#   1. 1080p glass sweep 10^3..10^6: lit/unlit, fragment/tiled, cells/tree, brute force up
#      to the first count where one render takes over 0.5 s, the uber-kernel at 3000;
#   2. the opaque sweep (fragment);
#   3. the two scans: the bunny at the issue's look-good settings and at the defaults,
#      frag_115 at the defaults.
# Writes bench/results/spheres_<device>-cells.json, -cells-opaque.json, -cells-scans.json
# (+ .png). Needs .whl/ (pyopencl and its pure-Python dependencies, /work/shared/GPU.md)
# and bench/data/bun_zipper.ply, bench/data/frag_115.ply (copies of
# ../shared/data/points/; bench/data is git-ignored: carry it); scipy and numpy come with
# the machine.
# Test here on PoCL at a tiny size (runs the same commands without gpu.sh):
#   DEVICE=portable SIZE=64x36 REPEAT=1 COUNTS=1000,3000 TAG=h200test bash bench/h200_cells.sh
set -euo pipefail
cd "$(dirname "$0")/.."
DEVICE=${DEVICE:-nvidia}
SIZE=${SIZE:-1920x1080}
REPEAT=${REPEAT:-3}
TAG=${TAG:-cells}
COUNTS=${COUNTS:-1000,3000,10000,100000,1000000}
PY=${PY:-python3}
common="--device $DEVICE --size $SIZE --repeat $REPEAT"
sweep="$PY bench/spheres.py $common --counts $COUNTS --accel grid,tree,none \
--dispatch fragment,tiled --tiled-accel grid,tree --brute-limit 0.5 --uber-count 3000 --tag $TAG"
opaque="$PY bench/spheres.py $common --opaque --counts $COUNTS --accel grid,tree,none \
--dispatch fragment --brute-limit 0.3 --uber-count 0 --tag $TAG"
scans="$PY bench/spheres.py $common --no-sweep --scans bunny,bunny-default,frag \
--accel grid,tree --dispatch fragment,tiled --tag $TAG-scans"
DEVICE=$DEVICE exec bash bench/run_cmds.sh "$sweep" "$opaque" "$scans"
